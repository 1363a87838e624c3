#version 460
// marching/transfer_float: accumulate the Ray History Buffer into the per-voxel deposit sums with
// float atomics (thesis 4.4.4; VK_EXT_shader_atomic_float). Fast; the order of additions, and
// so the low bits of the result, may differ between runs. lbl/transfer_fixed is the
// deterministic alternative.
#extension GL_EXT_shader_atomic_float : require
#extension GL_GOOGLE_include_directive : require
#include "../include/lattice.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;
layout(std430, binding = 0) readonly buffer History { uvec4 rhb[]; };
// [c V + v] deposits; with pc.directed then [NCH V + (3 c + a) V + v] fluxes (lattice/inject).
layout(std430, binding = 1) buffer Accum { float acc[]; };
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
    float scale;     // unused here (fixed-point scale of the deterministic variant)
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
    if (NCH == 1u) {
        atomicAdd(acc[s.x], dep.x);
    } else {
        for (uint c = 0u; c < 3u; ++c) atomicAdd(acc[c * pc.voxels + s.x], dep[c]);
    }
    if (pc.directed != 0u) {
        vec3 d = rays[e / pc.k].dir_alive.xyz;
        for (uint c = 0u; c < NCH; ++c)
            for (uint a = 0u; a < 3u; ++a) atomicAdd(acc[(NCH + 3u * c + a) * pc.voxels + s.x], dep[c] * d[a]);
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
