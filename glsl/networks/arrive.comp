#version 460
// networks/arrive: the medium's emission arriving unscattered at each particle along each
// direction (issue 47): for particle p and direction of travel w_i, J[p][i] = the integral of
// T(s) sigma_a Le over the medium upstream of p along -w_i, by the view march's step rule
// (glsl/view/march.comp): per midpoint step of optical depth c, (1 - albedo) (1 - e^-c) Le,
// then T *= e^-c. The emitted light's first flight, exactly, as the direct term is the
// lights': the network then carries it from its first scattering on.
// A second dispatch (pc.mode 1) turns J into the paper's E array for it: E[p][i] =
// sum_d J[p][d] P[d][i], J scattered into each discrete direction by the balanced quadrature of
// the phase function (networks/iterate.comp's P), once per render, so an iteration reads one
// value per particle and direction for the emission instead of D.
#extension GL_GOOGLE_include_directive : require

#define SCENE_BINDING 0
#define DENSITY_BINDING 1
#define MAJORANT_BINDING 2
#define EMISSION_BINDING 15
#include "../include/scene.glsl"
#include "../include/budget.glsl"
#include "../include/one_minus_exp.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

layout(std430, binding = 3) readonly buffer Positions { vec4 positions[]; };
layout(std430, binding = 4) readonly buffer Dirs { vec4 dirs[]; };
// [p][i]: rgb J, w the march's loop count (written by mode 0, read by mode 1)
layout(std430, binding = 5) buffer Arriving { vec4 arriving[]; };
layout(std430, binding = 6) readonly buffer Phase { float phase[]; };        // P[d][i]
// [p][i]: rgb E, J scattered into direction i (mode 1)
layout(std430, binding = 7) writeonly buffer Scattered { vec4 scattered[]; };

layout(push_constant) uniform Push {
    float step;       // the midpoint rule's step, scene units
    uint particles;
    uint directions;
    uint mode;        // 0: march J; 1: scatter it into E
} pc;

void main() {
    uint p = gl_GlobalInvocationID.x, i = gl_GlobalInvocationID.y;
    if (p >= pc.particles || i >= pc.directions) return;
    if (pc.mode == 1u) {
        uint D = pc.directions;
        vec3 e = vec3(0.0);
        for (uint d = 0u; d < D; ++d) e += arriving[p * D + d].rgb * phase[d * D + i];
        scattered[p * D + i] = vec4(e, 0.0);
        return;
    }
    vec3 x = positions[p].xyz;
    // Upstream: against the direction of travel.
    vec3 w = -dirs[3u * i + 2u].xyz;
    vec2 iv = medium_interval(x, w);
    float a = max(iv.x, 0.0);
    float len = iv.y - a;
    vec3 L = vec3(0.0), T = vec3(1.0);
    if (len > 0.0) {
        uint n = max(1u, uint(ceil(len / pc.step)));
        float dt = len / float(n);
        vec3 sigma_t = scene.materials[0].sigma_t.rgb;
        vec3 absorbed = vec3(1.0) - scene.materials[0].albedo.rgb;
        for (uint k = 0u; k < n; ++k) {
            iters++;
            vec3 q = x + w * (a + (float(k) + 0.5) * dt);
            vec3 tau = sigma_t * density_at(q) * dt;
            vec3 seg_T = exp(-tau);
            L += T * absorbed * one_minus_exp3(tau) * emission_at(q);
            T *= seg_T;
        }
    }
    arriving[p * pc.directions + i] = vec4(L, float(iters));
}
