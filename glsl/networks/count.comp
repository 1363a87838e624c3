#version 460
// networks/count: the visibility network's first pass (illumination networks, Szirmay-Kalos et
// al. 2005, 3.1; the compute equivalent of its depth peeling is bin, sort, link). One
// invocation per (particle, direction): the particle's window pixel for the direction, counted
// into that pixel's bucket. The host turns the counts into bucket offsets (a prefix sum).
#extension GL_GOOGLE_include_directive : require

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

layout(std430, binding = 0) readonly buffer Positions { vec4 positions[]; }; // xyz per particle
layout(std430, binding = 1) readonly buffer Dirs { vec4 dirs[]; };           // u, v, w per direction
layout(std430, binding = 2) buffer Counts { uint counts[]; };                // [direction][pixel]

layout(push_constant) uniform Push {
    vec4 centre_radius; // the bounding sphere
    float inv_pixel;    // M / (2 R)
    uint m;             // window resolution M
    uint particles;     // N
    uint directions;    // D
} pc;

#include "project.glsl"

void main() {
    uint p = gl_GlobalInvocationID.x, i = gl_GlobalInvocationID.y;
    if (p >= pc.particles || i >= pc.directions) return;
    Key k = project(positions[p].xyz, i, pc.centre_radius, pc.inv_pixel, pc.m);
    atomicAdd(counts[i * pc.m * pc.m + k.pixel], 1u);
}
