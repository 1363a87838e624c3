#version 460
// networks/inscatter: the in-scattering sum of an isotropic medium, once per particle
// (illumination networks 3.3). With g = 0 the phase matrix P[d][i] is one value, 4 pi / D
// times 1 / (4 pi), for every pair (src/solvers/networks/mod.rs, `phase_matrix`: the
// balancing leaves a constant matrix constant), so iterate.comp's sum_d I[vp][d] P[d][i] is
// the same for every direction i of travel out of vp. Summed here once per particle q and
// read by each of the D lanes that need it, an iteration costs N D instead of N D^2
// (3922 particles x 128 directions on lavapipe: 1.13 s an iteration before). The sum runs over
// d in the order iterate.comp's does and with the same factors (P[d][0] = P[d][i]), so the
// images are the anisotropic kernel's bit for bit (networks_tests checks it against
// --model-all, which compiles the full sum in).
//
// Batched with the iterations (src/solvers/networks/iteration.rs): once an iteration has
// stopped the batch on the device (stats[0], iterate.comp's verdict), the later sums return
// at once as the iterations do.
layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

layout(std430, binding = 0) readonly buffer Current { vec4 current[]; };   // I [q][d], rgb
layout(std430, binding = 1) readonly buffer Phase { float phase[]; };      // P[d][i]
layout(std430, binding = 2) writeonly buffer Sum { vec4 inscattered[]; };  // [q]: sum_d I[q][d] P[d][0]
layout(std430, binding = 3) readonly buffer Stats { uint stats[]; };       // [0]: the batch's verdict

layout(push_constant) uniform Push {
    uint particles;
    uint directions;
    uint check;  // 1: return at once where stats[0] says the batch has stopped
} pc;

void main() {
    uint q = gl_GlobalInvocationID.x;
    if (q >= pc.particles || (pc.check != 0u && stats[0] != 0u)) return;
    uint D = pc.directions;
    vec3 s = vec3(0.0);
    for (uint d = 0u; d < D; ++d) s += current[q * D + d].rgb * phase[d * D];
    inscattered[q] = vec4(s, 0.0);
}
