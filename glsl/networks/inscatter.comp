#version 460
// networks/inscatter: the in-scattering sums of iterate.comp taken out of its links
// (illumination networks 3.3): S[q][i] = sum_d I[q][d] P[d][i], once per particle q and
// direction i of travel out of it, read by the link whose upstream particle is q.
// - An isotropic medium (pc.outputs = 1): with g = 0 the phase matrix P[d][i] is one value,
//   4 pi / D times 1 / (4 pi), for every pair (src/solvers/networks/mod.rs, `phase_matrix`: the
//   balancing leaves a constant matrix constant), so the sum is the same for every i: one sum
//   per particle, N D an iteration instead of N D^2 (3922 particles x 128 directions on
//   lavapipe: 1.13 s an iteration before).
// - An anisotropic one (pc.outputs = D): every i has its own sum, N D^2 an iteration either
//   way, but summed here a particle's I is read once per BLOCK directions i (register blocking;
//   the block's P[d][i] are the same for the whole work group), where each link read the D
//   values of its upstream particle itself: on lavapipe a buffer read is a loop over the SIMD
//   lanes, and it, not the multiply-add, was the iteration's cost (docs/networks.md, "Two sums
//   taken out of the iteration").
// Each sum runs over d in the order iterate.comp's did and with the same factors (P[d][0] =
// P[d][i] where isotropic), so the images are the full kernel's bit for bit (networks_tests
// checks it against --model-all, which keeps the sum in the links).
//
// Batched with the iterations (src/solvers/networks/iteration.rs): once an iteration has
// stopped the batch on the device (stats[0], iterate.comp's verdict), the later sums return
// at once as the iterations do.
layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

layout(std430, binding = 0) readonly buffer Current { vec4 current[]; };   // I [q][d], rgb
layout(std430, binding = 1) readonly buffer Phase { float phase[]; };      // P[d][i]
layout(std430, binding = 2) writeonly buffer Sum { vec4 inscattered[]; };  // [q][i < outputs]: sum_d I[q][d] P[d][i]
layout(std430, binding = 3) readonly buffer Stats { uint stats[]; };       // [0]: the batch's verdict

layout(push_constant) uniform Push {
    uint particles;
    uint directions;
    uint check;  // 1: return at once where stats[0] says the batch has stopped
    uint outputs; // directions i summed per particle: 1 (isotropic, i = 0 stands for all) or D
} pc;

// Directions i one invocation sums in a pass over its particle's I (work group y: which block).
const uint BLOCK = 8u;

// The block's direction k < BLOCK: its sum gets I[q][d] P[d][i_k] (i_k clamped to the last
// direction past the end, where the sum is not stored).
#define TERM(k, i) acc[k] += c * phase[row + (i)];

void main() {
    uint q = gl_GlobalInvocationID.x;
    if (q >= pc.particles || (pc.check != 0u && stats[0] != 0u)) return;
    uint D = pc.directions;
    if (pc.outputs == 1u) {
        vec3 s = vec3(0.0);
        for (uint d = 0u; d < D; ++d) s += current[q * D + d].rgb * phase[d * D];
        inscattered[q] = vec4(s, 0.0);
        return;
    }
    uint i0 = gl_WorkGroupID.y * BLOCK;
    if (i0 >= D) return;
    uvec4 lo = min(uvec4(i0) + uvec4(0u, 1u, 2u, 3u), uvec4(D - 1u));
    uvec4 hi = min(uvec4(i0) + uvec4(4u, 5u, 6u, 7u), uvec4(D - 1u));
    vec3 acc[BLOCK] = vec3[BLOCK](vec3(0.0), vec3(0.0), vec3(0.0), vec3(0.0), vec3(0.0), vec3(0.0), vec3(0.0), vec3(0.0));
    for (uint d = 0u; d < D; ++d) {
        vec3 c = current[q * D + d].rgb;
        uint row = d * D;
        TERM(0, lo.x) TERM(1, lo.y) TERM(2, lo.z) TERM(3, lo.w) TERM(4, hi.x) TERM(5, hi.y) TERM(6, hi.z) TERM(7, hi.w)
    }
#define STORE(k) if (i0 + k < D) inscattered[q * D + i0 + k] = vec4(acc[k], 0.0);
    STORE(0) STORE(1) STORE(2) STORE(3) STORE(4) STORE(5) STORE(6) STORE(7)
#undef STORE
}
