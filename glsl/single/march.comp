#version 460
// single/march: the direct (single-scattering) term by camera-ray marching (thesis 1.3.6 and
// 2.5). Along the camera ray, in steps of at most `step` (scene units):
//   L = T(0, t_far) L_env
//     + sum_steps T(0, t_i) albedo (1 - exp(-sigma_t dt)) sum_lights p(cos) L_i T_shadow
// i.e. the single-scattering integral of eq. 1.24 with the extinction held constant within a
// step (so a thick step never scatters more than it extinguishes: energy is not created), the
// exact phase function, and shadow transmittance marched toward each light with the same
// rule. The environment's in-scattering is a fixed spherical Fibonacci quadrature of
// `env_dirs` directions. Deterministic: no random numbers unless `jitter` is set.
#extension GL_GOOGLE_include_directive : require

#define SCENE_BINDING 0
#define DENSITY_BINDING 1
#define MAJORANT_BINDING 2
#include "../include/scene.glsl"
#include "../include/rng.glsl"
#include "../include/phase.glsl"

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

layout(std430, binding = 3) writeonly buffer Radiance { vec4 radiance[]; };

layout(push_constant) uniform Push {
    float step;          // camera-ray step, scene units
    float shadow_step;   // shadow-ray step, scene units
    uint env_dirs;       // quadrature directions for environment in-scattering
    uint jitter;         // 1: jitter the step origin per pixel (trades banding for noise)
    uint seed_lo;
    uint seed_hi;
    uint supersample;    // n x n pixel subsamples (box filter)
    uint pad;
} pc;

float phase_eval(float g, float c) { return ANISOTROPIC ? hg_eval(g, c) : INV_4PI; }

// Optical depth (per channel) from p along w over [0, t_far], by the same piecewise-constant
// rule; exact for constant and sphere media where the chord is integrated analytically.
vec3 optical_depth(vec3 p, vec3 w, float t_far) {
    vec2 iv = medium_interval(p, w);
    float a = max(iv.x, 0.0);
    float b = min(iv.y, t_far);
    if (!(a < b)) return vec3(0.0);
    if (DENSITY_KIND != DENSITY_GRID) return scene.sigma_t.xyz * (b - a);
    float len = b - a;
    uint n = max(1u, uint(ceil(len / pc.shadow_step)));
    float dt = len / float(n);
    float tau = 0.0;
    for (uint i = 0u; i < n; ++i) tau += density_at(p + w * (a + (float(i) + 0.5) * dt));
    return scene.sigma_t.xyz * (tau * dt);
}

// Spherical Fibonacci direction i of n (uniform quadrature weight 4 pi / n).
vec3 fibonacci_dir(uint i, uint n) {
    float golden = 2.39996322972865332;   // pi (3 - sqrt 5)
    float z = 1.0 - (2.0 * float(i) + 1.0) / float(n);
    float r = sqrt(max(0.0, 1.0 - z * z));
    float phi = golden * float(i);
    return vec3(r * cos(phi), r * sin(phi), z);
}

// In-scattered radiance toward -d at p per unit sigma_s, from all lights: sum p(cos) L_i T.
vec3 inscatter(vec3 p, vec3 d) {
    vec3 S = vec3(0.0);
    float g = scene.albedo.w;
    for (uint i = 0u; i < scene.image.z; ++i) {
        Light li = scene.lights[i];
        uint kind = uint(li.pos_kind.w);
        if (kind == LIGHT_POINT) {
            vec3 to = li.pos_kind.xyz - p;
            float dist2 = dot(to, to);
            if (dist2 <= 0.0) continue;
            float dist = sqrt(dist2);
            vec3 wi = to / dist;
            S += phase_eval(g, dot(d, wi)) * li.value.rgb / dist2 * exp(-optical_depth(p, wi, dist));
        } else if (kind == LIGHT_DIRECTIONAL) {
            vec3 wi = -li.pos_kind.xyz;
            S += phase_eval(g, dot(d, wi)) * li.value.rgb * exp(-optical_depth(p, wi, INF));
        } else {
            vec3 acc = vec3(0.0);
            for (uint k = 0u; k < pc.env_dirs; ++k) {
                vec3 wi = fibonacci_dir(k, pc.env_dirs);
                acc += phase_eval(g, dot(d, wi)) * exp(-optical_depth(p, wi, INF));
            }
            S += li.value.rgb * acc * (4.0 * PI / float(pc.env_dirs));
        }
    }
    return S;
}

vec3 render_ray(vec3 o, vec3 d, float offset) {
    vec3 env = vec3(0.0);
    for (uint i = 0u; i < scene.image.z; ++i)
        if (uint(scene.lights[i].pos_kind.w) == LIGHT_ENVIRONMENT) env += scene.lights[i].value.rgb;
    vec2 iv = medium_interval(o, d);
    float a = max(iv.x, 0.0);
    float b = iv.y;
    if (!(a < b)) return env;
    float len = b - a;
    uint n = max(1u, uint(ceil(len / pc.step)));
    float dt = len / float(n);
    vec3 T = vec3(1.0);
    vec3 L = vec3(0.0);
    for (uint i = 0u; i < n; ++i) {
        float tm = a + (float(i) + offset) * dt;
        vec3 p = o + d * tm;
        vec3 st = scene.sigma_t.xyz * density_at(p);
        vec3 seg_T = exp(-st * dt);
        // integral over the step of T(s) sigma_s ds with sigma_t constant = albedo (1 - e^{-sigma_t dt})
        L += T * scene.albedo.xyz * (vec3(1.0) - seg_T) * inscatter(p, d);
        T *= seg_T;
    }
    return L + T * env;
}

void main() {
    uvec2 px = gl_GlobalInvocationID.xy;
    uvec2 res = scene.image.xy;
    if (px.x >= res.x || px.y >= res.y) return;
    uint pixel = px.y * res.x + px.x;
    uint rng = rng_init(pc.seed_lo, pc.seed_hi, pixel, 0u);
    uint ss = max(pc.supersample, 1u);
    vec3 sum = vec3(0.0);
    for (uint sy = 0u; sy < ss; ++sy) {
        for (uint sx = 0u; sx < ss; ++sx) {
            vec2 sub = (vec2(sx, sy) + 0.5) / float(ss);
            vec3 o, d;
            camera_ray(vec2(px) + sub, o, d);
            float offset = pc.jitter != 0u ? rnd(rng) : 0.5;
            sum += render_ray(o, d, offset);
        }
    }
    vec3 L = sum / float(ss * ss);
    if (any(isnan(L)) || any(isinf(L))) L = vec3(0.0);
    radiance[pixel] = vec4(L, 1.0);
}
