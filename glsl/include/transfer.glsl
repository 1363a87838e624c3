// transfer.glsl: what marching/transfer_float and marching/transfer_fixed share (src/solvers/
// marching.rs, Marcher::transfer_pass): the Ray History Buffer, the rays' state, the forward
// population's history and sums, the push constants, and the forward population's transfer,
// which is fixed point in both (its sums are few and signed). Each shader declares its own
// deposit sums (Accum: float or fixed point) at binding 1.
#ifndef SCATTERLAB_TRANSFER
#define SCATTERLAB_TRANSFER
#include "quantize.glsl"

layout(std430, binding = 0) readonly buffer History { uvec4 rhb[]; };
// The rays' state (marching/march.comp): straight rays keep their direction.
struct Ray { vec4 pos_steps; vec4 dir_alive; vec4 power; vec4 fwd; vec4 fwd_absorbed; vec4 fwd_out; };
layout(std430, binding = 2) readonly buffer Rays { Ray rays[]; };
// With pc.forward: each slot's forward population, path-integrated (march.comp), and its sums
// per voxel in fixed point of pc.fwd_scale / 4 quanta: [c V + v] the fluence, then
// [NCH V + (3 c + a) V + v] the flux (times the ray's direction).
layout(std430, binding = 3) readonly buffer FwdHistory { vec4 fwh[]; };
layout(std430, binding = 4) buffer FwdSums { uint fwd[]; };

layout(push_constant) uniform Push {
    uint entries;    // rays * k
    uint voxels;     // V
    float scale;     // fixed-point quanta per W of transfer_fixed's deposits
    uint k;          // history slots per ray: entry e belongs to ray e / k
    uint directed;   // 1: also sum each deposit's flux (deposit times the ray's direction)
    uint forward;    // 1: also sum the forward population (above)
    float fwd_scale; // its fixed-point quanta per W (times 1/4 below)
    uint pad2;
} pc;

// Add history entry e's forward population to the sums of its voxel v (pc.forward), rounded
// without bias (quantize.glsl; slots 12.. of the entry's 32).
void transfer_forward(uint e, uint v) {
    vec3 q = fwh[e].xyz;
    vec3 d = rays[e / pc.k].dir_alive.xyz;
    float sc = 0.25 * pc.fwd_scale;
    for (uint c = 0u; c < NCH; ++c) {
        atomicAdd(fwd[c * pc.voxels + v], quantize(q[c] * sc, 32u * e + 12u + c));
        for (uint a = 0u; a < 3u; ++a)
            atomicAdd(fwd[(NCH + 3u * c + a) * pc.voxels + v], quantize_signed(q[c] * d[a] * sc, 32u * e + 15u + 3u * c + a));
    }
}
#endif
