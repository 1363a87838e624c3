#version 460
// marching/transfer_fixed: the deterministic transfer. Deposits are added as 32-bit fixed-point
// integers (integer addition is associative, so any order gives the same bits):
// q = deposit * scale quanta, rounded without bias (quantize.glsl), with scale = 2^30 / (largest
// total source power of a channel), so no voxel's sum can overflow within a round; resolution
// ~1e-9 of the total power. Slots (the dither's key): 32 per history entry, deposits 0.., fluxes
// 3.., the forward population's 12.. (transfer.glsl).
#extension GL_GOOGLE_include_directive : require
#include "../include/lattice.glsl"
#include "../include/transfer.glsl"
#include "../include/quantize.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;
// After the work group size: linear.glsl reads gl_WorkGroupSize.
#include "../include/linear.glsl"
// [c V + v] deposits; with pc.directed then [NCH V + (3 c + a) V + v] fluxes (lattice/inject).
layout(std430, binding = 1) buffer Accum { uint acc[]; };

void main() {
    uint e = linear_id();
    if (e >= pc.entries) return;
    uvec4 s = rhb[e];
    if (s.x == 0xffffffffu) return;
    vec3 dep = uintBitsToFloat(s.yzw);
    for (uint c = 0u; c < NCH; ++c) atomicAdd(acc[c * pc.voxels + s.x], quantize(dep[c] * pc.scale, 32u * e + c));
    if (pc.directed != 0u) {
        // Signed: two's-complement addition wraps the same way in any order.
        vec3 d = rays[e / pc.k].dir_alive.xyz;
        for (uint c = 0u; c < NCH; ++c)
            for (uint a = 0u; a < 3u; ++a)
                atomicAdd(acc[(NCH + 3u * c + a) * pc.voxels + s.x], quantize_signed(dep[c] * d[a] * pc.scale, 32u * e + 3u + 3u * c + a));
    }
    if (pc.forward != 0u) transfer_forward(e, s.x);
}
