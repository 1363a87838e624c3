#version 460
// probe/sh: evaluates glsl/include/sh.glsl's basis on the device for tests/sh_tests.rs, which
// holds it to src/physics/sh.rs.
#extension GL_GOOGLE_include_directive : require
#include "../include/sh.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

layout(std430, binding = 0) readonly buffer Dirs { vec4 dirs[]; };
// For direction i: its order^2 basis values from [i * order^2].
layout(std430, binding = 1) writeonly buffer Values { float values[]; };

layout(push_constant) uniform Push {
    uint count;
    uint order;
} pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.count) return;
    float y[SH_MAX_COEFFS];
    sh_basis(dirs[i].xyz, pc.order, y);
    uint n = pc.order * pc.order;
    for (uint k = 0u; k < n; ++k) values[i * n + k] = y[k];
}
