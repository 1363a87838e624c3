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
layout(std430, binding = 1) buffer Accum { float acc[]; };   // [c * V + v]

layout(push_constant) uniform Push {
    uint entries;   // rays * k
    uint voxels;    // V
    float scale;    // unused here (fixed-point scale of the deterministic variant)
    uint pad;
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
}
