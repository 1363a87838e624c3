#version 460
// ordinates/deposit: dom's transfer of one marching round (thesis 5.2). Each Ray History
// Buffer entry's deposit (power scattered out of the beam in a voxel) is added to its voxel's
// sum for the ray's beam (raymap: src/solvers/marching.rs, `beams`), in 32-bit fixed point
// (marching/transfer_fixed.comp's scale: integer addition is associative, so the sums are the
// same bits in any order). Every deposit of one beam in one voxel travels the same way (or away
// from the same point), so ordinates/bin.comp can share each beam's sum among the storage
// directions afterwards, in float: binning each deposit here instead would quantise shares of a
// few quanta to nothing (issue 13 names the thesis's per-ray slots merged by sort-search-compact,
// which the thesis needed for want of atomics; docs/decisions.md).
// Out of core (dom.budget), the sums cover one slab of whole layers, voxels base .. base + voxels
// (z outermost: contiguous), and deposits elsewhere wait for their slab's pass; each voxel's sum
// is the same integer whichever slab plan it is made in. Each deposit is rounded without bias
// (quantize.glsl: nearest-quantum rounding dropped every deposit of a thin medium).

#extension GL_GOOGLE_include_directive : require

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;
// After the work group size: linear.glsl reads gl_WorkGroupSize.
#include "../include/linear.glsl"
#include "../include/quantize.glsl"
layout(std430, binding = 0) readonly buffer History { uvec4 rhb[]; };
layout(std430, binding = 1) buffer Accum { uint acc[]; };               // [c][beam][voxel]
layout(std430, binding = 2) readonly buffer RayBeam { uint ray_beam[]; }; // per ray

layout(push_constant) uniform Push {
    uint entries;    // rays * k, of the group of beams this pass sums
    uint voxels;     // voxels in the slab (V for the whole grid)
    uint k;          // history slots per ray: entry e belongs to ray e / k
    uint beams;      // B: the group's beams
    float scale;     // fixed-point quanta per W
    uint channels;   // 1 or 3
    uint base;       // the slab's first voxel
    uint first_entry; // the group's first entry (its first ray times k)
    uint beam0;      // the group's first beam
    uint pad0;
    uint pad1;
} pc;

void main() {
    if (linear_id() >= pc.entries) return;
    uint e = pc.first_entry + linear_id();
    uvec4 s = rhb[e];
    if (s.x == 0xffffffffu || s.x < pc.base || s.x - pc.base >= pc.voxels) return;
    vec3 dep = uintBitsToFloat(s.yzw);
    uint b = ray_beam[e / pc.k] - pc.beam0;
    for (uint c = 0u; c < pc.channels; ++c)
        atomicAdd(acc[(c * pc.beams + b) * pc.voxels + (s.x - pc.base)], quantize(dep[c] * pc.scale, 4u * e + c));
}
