#version 460
// networks/fill: each (particle, direction) writes the particle into its pixel's bucket, at the
// bucket's offset (the prefix sum of networks/count's counts) plus a slot taken by an atomic
// cursor. The order within a bucket is the atomics' (not deterministic); networks/link sorts
// each bucket by (depth, particle), which is.
#extension GL_GOOGLE_include_directive : require

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

layout(std430, binding = 0) readonly buffer Positions { vec4 positions[]; };
layout(std430, binding = 1) readonly buffer Dirs { vec4 dirs[]; };
layout(std430, binding = 2) readonly buffer Offsets { uint offsets[]; };     // [direction][pixel]
layout(std430, binding = 3) buffer Cursor { uint cursor[]; };                // [direction][pixel], from 0
layout(std430, binding = 4) writeonly buffer Entries { uint entries[]; };    // N x D particle indices

layout(push_constant) uniform Push {
    vec4 centre_radius;
    float inv_pixel;
    uint m;
    uint particles;
    uint directions;
} pc;

#include "project.glsl"

void main() {
    uint p = gl_GlobalInvocationID.x, i = gl_GlobalInvocationID.y;
    if (p >= pc.particles || i >= pc.directions) return;
    Key k = project(positions[p].xyz, i, pc.centre_radius, pc.inv_pixel, pc.m);
    uint bucket = i * pc.m * pc.m + k.pixel;
    entries[offsets[bucket] + atomicAdd(cursor[bucket], 1u)] = p;
}
