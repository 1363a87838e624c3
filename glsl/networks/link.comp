#version 460
// networks/link: one invocation per bucket (direction i, window pixel): its particles sorted by
// (depth along the direction of travel, index), insertion sort in place (a bucket holds the
// particles of one window column: few), then each particle linked to the one before it, the
// nearest upstream in its column: V[p][i] = the particle whose radiance reaches p travelling
// along direction i (illumination networks 3.1-3.2); none (0xffffffff) for the first, which
// sees the sky. Deterministic whatever order networks/fill left.
#extension GL_GOOGLE_include_directive : require

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

layout(std430, binding = 0) readonly buffer Positions { vec4 positions[]; };
layout(std430, binding = 1) readonly buffer Dirs { vec4 dirs[]; };
layout(std430, binding = 2) readonly buffer Counts { uint counts[]; };
layout(std430, binding = 3) readonly buffer Offsets { uint offsets[]; };
layout(std430, binding = 4) buffer Entries { uint entries[]; };
layout(std430, binding = 5) writeonly buffer Visible { uint visible[]; };   // [particle][direction]

layout(push_constant) uniform Push {
    vec4 centre_radius;
    float inv_pixel;
    uint m;
    uint particles;
    uint directions;
} pc;

#include "project.glsl"

const uint NONE = 0xffffffffu;

float depth_of(uint p, uint i) {
    return project(positions[p].xyz, i, pc.centre_radius, pc.inv_pixel, pc.m).depth;
}

void main() {
    uint bucket = gl_GlobalInvocationID.x;
    uint pixels = pc.m * pc.m;
    if (bucket >= pc.directions * pixels) return;
    uint i = bucket / pixels;
    uint n = counts[bucket], start = offsets[bucket];
    for (uint j = 1u; j < n; ++j) {
        uint p = entries[start + j];
        float d = depth_of(p, i);
        uint k = j;
        while (k > 0u) {
            uint q = entries[start + k - 1u];
            float dq = depth_of(q, i);
            if (dq < d || (dq == d && q < p)) break;
            entries[start + k] = q;
            --k;
        }
        entries[start + k] = p;
    }
    for (uint j = 0u; j < n; ++j)
        visible[entries[start + j] * pc.directions + i] = j == 0u ? NONE : entries[start + j - 1u];
}
