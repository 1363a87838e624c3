// linear.glsl: the index of an invocation along a line of work the host dispatched with
// Pass::cover_linear (src/gpu/submit.rs): up to 65535 work groups along x (every device's
// maxComputeWorkGroupCount allows that many; lavapipe allows no more), further rows of them
// along y (linear_id), or along z where y indexes something else (linear_id_z). The last row
// runs past the line's end: every kernel checks the index against its count. Include it after
// the kernel's local_size layout: before it glslang takes gl_WorkGroupSize as (1, 1, 1), and
// the rows overlapped (lbl's transfer added 13.7% too much at 94494 groups; tested).
#ifndef SCATTERLAB_LINEAR
#define SCATTERLAB_LINEAR

// A folded line's rows are always LINEAR_ROW groups wide (the host's MAX_GROUPS_X); a line of
// one row has y = z = 0, so its width never enters.
const uint LINEAR_ROW = 65535u;
uint linear_id() { return gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * LINEAR_ROW * gl_WorkGroupSize.x; }
uint linear_id_z() { return gl_GlobalInvocationID.x + gl_GlobalInvocationID.z * LINEAR_ROW * gl_WorkGroupSize.x; }
// The work group's index along the line (a per-group partial's slot).
uint linear_group() { return gl_WorkGroupID.x + gl_WorkGroupID.y * LINEAR_ROW; }
#endif
