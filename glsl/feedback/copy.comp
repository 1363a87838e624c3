#version 460
// feedback/copy: the small records an iterative solver's convergence test keeps on the device
// (src/solvers/feedback.rs): cleared at the start of a batch (pc.clear), copied at its end into
// host-visible memory, which the host reads through its mapping after its one wait. The test's
// own atomics and every pass's read of its stop word stay in device memory; only these few
// words cross the bus.

#extension GL_GOOGLE_include_directive : require

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;
// After the work group size: linear.glsl reads gl_WorkGroupSize.
#include "../include/linear.glsl"

layout(std430, binding = 0) buffer Record { uint record[]; };       // device-local
layout(std430, binding = 1) writeonly buffer Host { uint host[]; }; // host-visible

layout(push_constant) uniform Push {
    uint words;
    uint clear;      // 1: zero the record (and its host copy); 0: copy it out
} pc;

void main() {
    uint i = linear_id();
    if (i >= pc.words) return;
    if (pc.clear != 0u) {
        record[i] = 0u;
        host[i] = 0u;
    } else {
        host[i] = record[i];
    }
}
