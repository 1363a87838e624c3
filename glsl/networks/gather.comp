#version 460
// networks/gather: each particle's radiance toward the camera, per unit of its opacity
// (illumination networks 3.3, last paragraph: "the reflection from the sampled incoming
// directions to the viewing direction", plus the direct term of the lights): for outgoing
// direction o (from the particle toward the eye),
//   c = albedo (sum_j L_j p(w_j . o) + sum_d I[d] p(w_d . o) / sum_d p(w_d . o)),
// the incoming samples' phase weights normalised over the directions (as the balanced matrix
// does among them: a uniform I gives I back), L_j the direct light (networks/direct.comp).
// networks/splat composites c alpha in depth order. With pc.direct = 0 (`networks.single =
// view`) the direct term is left to the view pass, which computes every light's single
// scattering exactly: c is then the light scattered at least twice.
// An emissive medium (EMISSION): the incoming light is I plus, with pc.emission 2
// (`networks.emission = march`), J, the emission arriving unscattered (networks/arrive.comp;
// with 1 the particles' emission is in I already), so c holds the emitted light scattered at
// least once; with pc.direct = 1 (the paper's image) c also carries the particle's own emission
// per unit of its opacity, (1 - albedo) Le, which the splats composite as alpha (1 - albedo) Le;
// with pc.direct = 0 the view pass adds that along the camera ray instead
// (glsl/view/march.comp), so it is not counted twice.
#extension GL_GOOGLE_include_directive : require

#define SCENE_BINDING 0
#define DENSITY_BINDING 1
#define MAJORANT_BINDING 2
#include "../include/scene.glsl"
#include "../include/phase.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

layout(std430, binding = 3) readonly buffer Positions { vec4 positions[]; };
layout(std430, binding = 4) readonly buffer Dirs { vec4 dirs[]; };
layout(std430, binding = 5) readonly buffer Direct { vec4 direct[]; };
#include "lights.glsl"
layout(std430, binding = 6) readonly buffer Radiance { vec4 radiance[]; };   // I [p][i]
layout(std430, binding = 7) writeonly buffer Colour { vec4 colour[]; };     // [p]: rgb
// [p]: rgb (1 - albedo) Le (`Network::emitted`); a placeholder, never read, where EMISSION is 0.
layout(std430, binding = 8) readonly buffer Emitted { vec4 emitted[]; };
// [p][d]: rgb J, the emission arriving unscattered (networks/arrive.comp), with pc.emission 2.
layout(std430, binding = 9) readonly buffer Arriving { vec4 arriving[]; };

layout(push_constant) uniform Push {
    uint particles;
    uint directions;
    uint units;
    uint direct;      // 1: the direct term too (the paper's image); 0: the scattered light only
    uint emission;    // with EMISSION: 1 the particles' own emission in I, 2 J beside I
} pc;

void main() {
    uint p = gl_GlobalInvocationID.x;
    if (p >= pc.particles) return;
    vec3 x = positions[p].xyz;
    vec3 o = scene.cam_origin.w < 0.5 ? normalize(scene.cam_origin.xyz - x) : -scene.cam_forward.xyz;
    float g = scene.materials[0].albedo.w;
    vec3 lit = pc.direct == 1u ? lights_scattered(p, pc.units, g, o) : vec3(0.0);
    vec3 sum = vec3(0.0);
    float norm = 0.0;
    for (uint d = 0u; d < pc.directions; ++d) {
        float w = hg_eval(g, dot(dirs[3u * d + 2u].xyz, o));
        vec3 incoming = radiance[p * pc.directions + d].rgb;
        if (EMISSION != EMISSION_NONE && pc.emission == 2u) incoming += arriving[p * pc.directions + d].rgb;
        sum += incoming * w;
        norm += w;
    }
    vec3 c = scene.materials[0].albedo.rgb * (lit + (norm > 0.0 ? sum / norm : vec3(0.0)));
    if (EMISSION != EMISSION_NONE && pc.direct == 1u) c += emitted[p].rgb;
    colour[p] = vec4(c, 0.0);
}
