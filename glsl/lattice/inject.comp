#version 460
// lattice/inject: move the round's summed deposits into the lattice's rest distribution (emitted
// isotropically at the next lattice step) and clear the sums. Keeps a per-workgroup,
// Kahan-compensated tally of the energy injected, for the conservation check.
#extension GL_GOOGLE_include_directive : require
#include "../include/lattice.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;
layout(constant_id = 6) const bool FIXED = false;

layout(std430, binding = 0) buffer Accum { uint acc[]; };    // float bits, or fixed point
layout(std430, binding = 1) buffer State { float f[]; };     // the current lattice state
layout(std430, binding = 2) buffer Tally { vec2 tally[]; };  // per workgroup and channel: (sum, comp)

layout(push_constant) uniform Push {
    uint voxels;
    float inv_scale;   // 1 / fixed-point scale
    uint pad0;
    uint pad1;
} pc;

shared float sh[3 * 64];

void main() {
    uint v = gl_GlobalInvocationID.x;
    uint li = gl_LocalInvocationID.x;
    for (uint c = 0u; c < NCH; ++c) {
        float e = 0.0;
        if (v < pc.voxels) {
            uint a = acc[c * pc.voxels + v];
            e = FIXED ? float(a) * pc.inv_scale : uintBitsToFloat(a);
            acc[c * pc.voxels + v] = 0u;
            f[c * pc.voxels + v] += e;   // distribution 0 (rest) of channel c
        }
        sh[c * 64u + li] = e;
    }
    barrier();
    for (uint stride = 32u; stride > 0u; stride >>= 1u) {
        if (li < stride)
            for (uint c = 0u; c < NCH; ++c) sh[c * 64u + li] += sh[c * 64u + li + stride];
        barrier();
    }
    if (li == 0u) {
        for (uint c = 0u; c < NCH; ++c) {
            vec2 t = tally[gl_WorkGroupID.x * NCH + c];
            float y = sh[c * 64u] - t.y;
            float s = t.x + y;
            t.y = (s - t.x) - y;
            t.x = s;
            tally[gl_WorkGroupID.x * NCH + c] = t;
        }
    }
}
