#version 460
// lattice/reduce: the increment of the lattice's time-integrated energy over the last chunk of
// steps, per channel, summed per workgroup in double precision (lattice/check.comp adds the
// workgroups' sums in a fixed order). The increment of a voxel is taken in f32 and widened, as
// the host took it (src/solvers/lattice.rs, Diffuser::iterate): the sums differ from a
// sequential sum only in the last bits of a double. Stopped chunks (control word 0 set by
// lattice/check.comp) return at once.
//
// Used by the tail extrapolation: the ratio of two chunks' increments is the decay of the
// slowest mode over a chunk. The increments are summed as magnitudes: from zero they are never
// negative (the sum is the plain one, to the bit), and from a previous frame's field (a seeded
// start: the residual s + M G - G is signed) their signs cancel in a plain sum, while the sum of
// magnitudes still decays at the slowest surviving mode's rate.

layout(local_size_x = 256, local_size_y = 1, local_size_z = 1) in;

// Channels carried (lattice.glsl's constant).
layout(constant_id = 3) const uint NCH = 3u;

layout(std430, binding = 0) readonly buffer Irradiance { float irr[]; };   // [c * V + v] first
layout(std430, binding = 1) readonly buffer Snapshot { float snap[]; };    // the field at the chunk's start
layout(std430, binding = 2) readonly buffer Control { uint ctrl[]; };      // [0]: stopped
layout(std430, binding = 3) writeonly buffer Partials { double partial[]; }; // [workgroup * NCH + c]

layout(push_constant) uniform Push {
    uint voxels;     // V
} pc;

shared double red[256];

void main() {
    if (ctrl[0] != 0u) return;
    uint l = gl_LocalInvocationIndex;
    uint v = gl_GlobalInvocationID.x;
    for (uint c = 0u; c < NCH; ++c) {
        // f32 difference, widened: the host's |a - b| as f64.
        red[l] = v < pc.voxels ? double(abs(irr[c * pc.voxels + v] - snap[c * pc.voxels + v])) : 0.0lf;
        barrier();
        for (uint s = 128u; s > 0u; s >>= 1) {
            if (l < s) red[l] += red[l + s];
            barrier();
        }
        if (l == 0u) partial[gl_WorkGroupID.x * NCH + c] = red[0];
        barrier();
    }
}
