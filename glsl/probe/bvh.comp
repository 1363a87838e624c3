#version 460
// probe/bvh: runs glsl/include/mesh.glsl's BVH traversal on the device, one ray per
// invocation, so tests can check it against the host's `Bvh::intersect` (which mirrors it)
// and `scatterlab`'s docs can give its throughput in rays/s.
#extension GL_GOOGLE_include_directive : require
#define MESH_NODES_BINDING 0
#define MESH_TRIS_BINDING 1
#include "../include/common.glsl"
#include "../include/budget.glsl"
#include "../include/mesh.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

// Ray i: origin (xyz, w = t_min) and direction (xyz, w = t_max).
layout(std430, binding = 2) readonly buffer Rays { vec4 rays[]; };
// Ray i: (t of the closest hit or -1 on a miss, the unit normal), and the loop iterations it took.
layout(std430, binding = 3) writeonly buffer Hits { vec4 hits[]; };
layout(std430, binding = 4) writeonly buffer Iters { uint iters_out[]; };

layout(push_constant) uniform Push { uint count; } pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.count) return;
    vec4 o = rays[2u * i];
    vec4 d = rays[2u * i + 1u];
    float t;
    vec3 n;
    bool hit = mesh_hit(o.xyz, d.xyz, o.w, d.w, t, n);
    hits[i] = hit ? vec4(t, n) : vec4(-1.0, 0.0, 0.0, 0.0);
    iters_out[i] = iters;
}
