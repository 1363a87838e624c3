#version 460
// marching/transfer_float: accumulate the Ray History Buffer into the per-voxel deposit sums with
// float atomics (thesis 4.4.4; VK_EXT_shader_atomic_float). Fast; the order of additions, and
// so the low bits of the result, may differ between runs. lbl/transfer_fixed is the
// deterministic alternative.
#extension GL_EXT_shader_atomic_float : require
#extension GL_GOOGLE_include_directive : require
#include "../include/lattice.glsl"
#include "../include/transfer.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;
// After the work group size: linear.glsl reads gl_WorkGroupSize.
#include "../include/linear.glsl"
// [c V + v] deposits; with pc.directed then [NCH V + (3 c + a) V + v] fluxes (lattice/inject).
layout(std430, binding = 1) buffer Accum { float acc[]; };

void main() {
    uint e = linear_id();
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
    if (pc.forward != 0u) transfer_forward(e, s.x);
}
