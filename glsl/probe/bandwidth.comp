#version 460
// probe/bandwidth: the device's own memory bandwidth for `scatterlab report`, as the kernels
// here see it: every invocation reads one vec4 and writes one (16 + 16 bytes), a grid-stride
// loop over `count` vec4s so a dispatch of a fixed size covers any buffer. The arithmetic is
// one multiply-add, so the time is the memory's, not the ALUs' (as vkpeak and STREAM's copy).
layout(local_size_x = 256, local_size_y = 1, local_size_z = 1) in;

layout(std430, binding = 0) readonly buffer Src { vec4 src[]; };
layout(std430, binding = 1) writeonly buffer Dst { vec4 dst[]; };

layout(push_constant) uniform Push {
    uint count;     // vec4s to move
    uint stride;    // invocations in the dispatch
    float scale;
    uint pad;
} pc;

void main() {
    for (uint i = gl_GlobalInvocationID.x; i < pc.count; i += pc.stride) dst[i] = src[i] * pc.scale + 1.0;
}
