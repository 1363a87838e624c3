#version 460
// probe/extinction: runs glsl/include/one_minus_exp.glsl on the device so tests can check it
// against double precision across optical depths from 1e-9 to 80, beside the plain float forms
// it replaces (1 - exp(-x) and (1 - exp(-x)) / x), whose cancellation is what it is for.
#extension GL_GOOGLE_include_directive : require
#include "../include/one_minus_exp.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

layout(std430, binding = 0) readonly buffer Depths { float depths[]; };
// Depth i: one_minus_exp(|x|), one_minus_exp_over(x), 1 - exp(-|x|), (1 - exp(-x)) / x.
layout(std430, binding = 1) writeonly buffer Out { vec4 out_v[]; };

layout(push_constant) uniform Push { uint count; } pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.count) return;
    float x = depths[i];
    float a = abs(x);
    out_v[i] = vec4(one_minus_exp(a), one_minus_exp_over(x), 1.0 - exp(-a), (1.0 - exp(-x)) / x);
}
