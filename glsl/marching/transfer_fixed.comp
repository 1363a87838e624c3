#version 460
// marching/transfer_fixed: the deterministic transfer. Deposits are added as 32-bit fixed-point
// integers (integer addition is associative, so any order gives the same bits):
// q = round(deposit * scale), with scale = 2^30 / (largest total source power of a channel),
// so no voxel's sum can overflow within a round; resolution ~1e-9 of the total power.
#extension GL_GOOGLE_include_directive : require
#include "../include/lattice.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;
layout(std430, binding = 0) readonly buffer History { uvec4 rhb[]; };
// [c V + v] deposits; with pc.directed then [NCH V + (3 c + a) V + v] fluxes (lattice/inject).
layout(std430, binding = 1) buffer Accum { uint acc[]; };
// The rays' state (marching/march.comp): straight rays keep their direction.
struct Ray { vec4 pos_steps; vec4 dir_alive; vec4 power; vec4 fwd; vec4 fwd_absorbed; vec4 fwd_out; };
layout(std430, binding = 2) readonly buffer Rays { Ray rays[]; };
// With pc.forward: each slot's forward population, path-integrated (march.comp), and its sums
// per voxel in fixed point of pc.scale / 4 quanta: [c V + v] the fluence, then
// [NCH V + (3 c + a) V + v] the flux (times the ray's direction).
layout(std430, binding = 3) readonly buffer FwdHistory { vec4 fwh[]; };
layout(std430, binding = 4) buffer FwdSums { uint fwd[]; };

layout(push_constant) uniform Push {
    uint entries;    // rays * k
    uint voxels;     // V
    float scale;     // fixed-point quanta per W
    uint k;          // history slots per ray: entry e belongs to ray e / k
    uint directed;   // 1: also sum each deposit's flux (deposit times the ray's direction)
    uint forward;    // 1: also sum the forward population (above)
    uint pad1;
    uint pad2;
} pc;

void main() {
    uint e = gl_GlobalInvocationID.x;
    if (e >= pc.entries) return;
    uvec4 s = rhb[e];
    if (s.x == 0xffffffffu) return;
    vec3 dep = uintBitsToFloat(s.yzw);
    for (uint c = 0u; c < NCH; ++c) atomicAdd(acc[c * pc.voxels + s.x], uint(dep[c] * pc.scale + 0.5));
    if (pc.directed != 0u) {
        // Signed: two's-complement addition wraps the same way in any order.
        vec3 d = rays[e / pc.k].dir_alive.xyz;
        for (uint c = 0u; c < NCH; ++c)
            for (uint a = 0u; a < 3u; ++a)
                atomicAdd(acc[(NCH + 3u * c + a) * pc.voxels + s.x], uint(int(round(dep[c] * d[a] * pc.scale))));
    }
    if (pc.forward != 0u) {
        vec3 q = fwh[e].xyz;
        vec3 d = rays[e / pc.k].dir_alive.xyz;
        float sc = 0.25 * pc.scale;
        for (uint c = 0u; c < NCH; ++c) {
            atomicAdd(fwd[c * pc.voxels + s.x], uint(q[c] * sc + 0.5));
            for (uint a = 0u; a < 3u; ++a)
                atomicAdd(fwd[(NCH + 3u * c + a) * pc.voxels + s.x], uint(int(round(q[c] * d[a] * sc))));
        }
    }
}
