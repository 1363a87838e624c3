#version 460
// networks/iterate: one step of the illumination network's iteration (illumination networks
// 3.3, with the paper's typo mended: the in-scattering factor is opacity x albedo, as its
// eq. 2 and its shader have it, not opacity x opacity). For every particle p and direction i
// (of travel), with vp = V[p][i] the particle upstream:
//   I'[p][i] = (1 - alpha) I[vp][i] + alpha albedo (sum_j L_j(vp) p(w_j . w_i)
//              + sum_d I[vp][d] P[d][i]),
// L_j the direct light j's irradiance at vp through the medium (networks/direct.comp), p the
// Henyey-Greenstein phase function (1/sr), P the paper's Monte Carlo quadrature of it,
// 4 pi / D p(w_d . w_i), balanced on the host so that every row and column sums to 1
// (src/solvers/networks.rs, `phase_matrix`: scattering conserves energy on the directions);
// and the sky's radiance where no particle is upstream. Every particle has the same opacity
// (each holds the same share of the extinction, src/solvers/networks.rs) and the medium's
// albedo and g. Ping-pong: reads I, writes I'.
//
// An emissive medium (issue 47; compiled in only where EMISSION is not 0) is a source beside
// the lights, by pc.emission (`networks.emission`):
// - EMIT_MARCHED (the default): J[vp][d], the emission arriving unscattered at vp along d
//   (networks/arrive.comp, marched through the medium itself as the direct term is toward the
//   lights), scattered with the rest of vp's incoming light: E[vp][i] = sum_d J[vp][d] P[d][i]
//   (the same quadrature, summed once per render by arrive.comp) joins the in-scattering sum.
//   The network carries the emitted light from its first scattering on.
// - EMIT_PARTICLES (the paper's E_p = Le ds, 2.1): + alpha (1 - albedo) Le(vp), what vp stops
//   of a column given back by its absorbing share as Le in every direction (the source
//   sigma_a Le over the particle's extinction; an opaque absorbing particle glows at Le),
//   carried by the columns like all other light.
// Deterministic: fixed order; the one atomic is a max (order-free).
//
// The in-scattering sums sum_d I[vp][d] P[d][i] come from networks/inscatter.comp, the same
// f32 sums bit for bit: an isotropic medium (ANISOTROPIC false: every g is 0, scene.glsl's
// constant) has one value in P, so the sum is the same for every direction out of vp and is
// summed once per particle per iteration, N D work instead of N D^2; an anisotropic one's
// (pc.summed) once per particle and direction, with the particle's I read once per block of
// directions instead of once per link. `--model-all` keeps the sum in the link. And where the
// lights are more than one unit (pc.lit), their light scattered at vp into i is read from
// networks/lit.comp's table, summed once per light position, instead of summed over the units
// on every iteration.
//
// Convergence is judged on the device: each workgroup reduces, in shared memory, the largest
// change |I' - I| and the largest I' over its invocations and channels, and one atomicMax per
// workgroup folds them into slot pc.slot of `stats` (as uint bits: for non-negative floats the
// order of the bits is the order of the values, and a NaN, 0x7fc00000, sorts above +inf, so a
// non-finite value cannot hide). The host reads 8 bytes per iteration instead of all of I.
//
// And the iteration stops on the device: a batch of iterations is one submission, and with
// pc.check each dispatch first judges the one before it (slot pc.slot - 1) by the tolerance:
// converged (largest change <= tol x largest I') or faulted (a negative or non-finite value),
// it writes its verdict to stats[0] and every later dispatch of the batch returns at once,
// leaving I as it stood. stats[1] counts the dispatches that ran, so the host knows which of
// the ping-pong buffers holds the result. The rule is exactly the host's
// (src/solvers/networks.rs, `verdict`), in f32 on both sides.
#extension GL_GOOGLE_include_directive : require
#include "../include/phase.glsl"
// The medium's albedo and g: the scene block's material table, entry 0.
#define SCENE_BINDING 7
#include "../include/scene_block.glsl"
// scene.glsl's specialisation of what the medium emits (SPEC_EMISSION: 0 none, 1 constant, 2
// grid); this kernel reads the block alone, so it declares the constant itself (checked
// against the Rust side's id and name by the kernel and registry tests).
layout(constant_id = 17) const uint EMISSION = 0u;
// scene.glsl's: some g is not 0 (else the in-scattering sum is inscatter.comp's, per particle).
layout(constant_id = 2) const bool ANISOTROPIC = true;

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

layout(std430, binding = 0) readonly buffer Visible { uint visible[]; };     // [p][i]
layout(std430, binding = 1) readonly buffer Dirs { vec4 dirs[]; };           // u, v, w per direction
layout(std430, binding = 2) readonly buffer Direct { vec4 direct[]; };       // networks/direct.comp
#include "lights.glsl"
layout(std430, binding = 3) readonly buffer Current { vec4 current[]; };     // I [p][i], rgb
layout(std430, binding = 4) writeonly buffer Next { vec4 next[]; };          // I' [p][i]
layout(std430, binding = 5) readonly buffer Phase { float phase[]; };        // P[d][i]
// [0] verdict that stopped the batch (0: none, 1 converged, 2 fault), [1] dispatches that ran,
// [2 + 2 slot], [3 + 2 slot]: the slot's max change and max I'.
layout(std430, binding = 6) buffer Stats { uint stats[]; };
// [p]: rgb (1 - albedo) Le at particle p, W/(m^2 sr) (src/solvers/networks/particles.rs,
// `Network::emitted`); a placeholder, never read, where EMISSION is 0.
layout(std430, binding = 8) readonly buffer Emitted { vec4 emitted[]; };
// [p][i]: rgb E, the emission arriving unscattered at p scattered into direction i
// (networks/arrive.comp); a placeholder, never read, unless pc.emission is EMIT_MARCHED.
layout(std430, binding = 9) readonly buffer Scattered { vec4 scattered_emission[]; };
// sum_d I[p][d] P[d][i] (networks/inscatter.comp): [p], the same for every i, where not
// ANISOTROPIC; [p][i] where pc.summed; else a placeholder, never read.
layout(std430, binding = 10) readonly buffer Inscattered { vec4 inscattered[]; };
// [p][i]: sum_j L_j(p) p(w_j . w_i) (networks/lit.comp); a placeholder, never read, unless pc.lit.
layout(std430, binding = 11) readonly buffer Lit { vec4 lit_table[]; };

layout(push_constant) uniform Push {
    vec4 alpha;      // rgb opacity of a particle
    vec4 sky;        // rgb: the environment's radiance
    uint particles;
    uint directions;
    uint units;
    uint slot;       // where this iteration's change and peak go in `stats`
    uint check;      // 1: first judge slot - 1 against tol, and stop where it converged or faulted
    float tol;       // largest change per iteration, relative to the largest I'
    uint emission;   // with EMISSION: EMIT_PARTICLES or EMIT_MARCHED
    uint lit;        // 1: the lights' scattered light from lit_table, not summed over the units
    uint summed;     // 1 (ANISOTROPIC): the in-scattering sums [p][i] from inscattered
} pc;

// How the medium's emission enters (`networks.emission`): each upstream particle's own
// alpha (1 - albedo) Le, carried by the columns from there (the paper's E_p), or the emission
// arriving unscattered at vp (J, marched through the medium itself), scattered at vp with the
// rest of its incoming light.
const uint EMIT_PARTICLES = 1u, EMIT_MARCHED = 2u;

const uint NONE = 0xffffffffu;

shared float change_max[64];
shared float peak_max[64];

// I'[p][i] (rgb) for an invocation inside the grid.
vec3 step_one(uint p, uint i) {
    uint D = pc.directions;
    uint vp = visible[p * D + i];
    if (vp == NONE) return pc.sky.rgb;
    vec3 wi = dirs[3u * i + 2u].xyz;
    float g = scene.materials[0].albedo.w;
    vec3 lit = pc.lit != 0u ? lit_table[vp * D + i].rgb : lights_scattered(vp, pc.units, g, wi);
    vec3 scattered = vec3(0.0);
    if (ANISOTROPIC && pc.summed != 0u) {
        scattered = inscattered[vp * D + i].rgb;
    } else if (ANISOTROPIC) {
        for (uint d = 0u; d < D; ++d) scattered += current[vp * D + d].rgb * phase[d * D + i];
    } else {
        scattered = inscattered[vp].rgb;
    }
    if (EMISSION != 0u && pc.emission == EMIT_MARCHED) scattered += scattered_emission[vp * D + i].rgb;
    vec3 a = pc.alpha.rgb;
    vec3 r = (1.0 - a) * current[vp * D + i].rgb + a * scene.materials[0].albedo.rgb * (lit + scattered);
    // vp's emission, alpha (1 - albedo) Le: light that has not scattered yet, which the next
    // iterations scatter on as they do the direct light.
    if (EMISSION != 0u && pc.emission == EMIT_PARTICLES) r += a * emitted[vp].rgb;
    return r;
}

const uint GO_ON = 0u, CONVERGED = 1u, FAULT = 2u;

// The host's rule (networks.rs `verdict`): a negative or non-finite change or peak is a fault;
// else converged where change <= tol x peak (or nothing is lit).
uint verdict(float change, float peak) {
    if (isnan(change) || isinf(change) || change < 0.0 || isnan(peak) || isinf(peak) || peak < 0.0) return FAULT;
    if (peak <= 0.0) return CONVERGED;
    return change <= pc.tol * peak ? CONVERGED : GO_ON;
}

void main() {
    uint p = gl_GlobalInvocationID.x, i = gl_GlobalInvocationID.y;
    uint l = gl_LocalInvocationIndex;
    bool first = p == 0u && i == 0u;
    // Every invocation reaches the same verdict from the same words: the return is uniform.
    if (pc.check != 0u) {
        if (stats[0] != GO_ON) return;
        // Slot - 1 sits at 2 + 2 (slot - 1) = 2 slot.
        uint v = verdict(uintBitsToFloat(stats[2u * pc.slot]), uintBitsToFloat(stats[2u * pc.slot + 1u]));
        if (v != GO_ON) {
            if (first) stats[0] = v;
            return;
        }
    }
    if (first) atomicAdd(stats[1], 1u);
    float change = 0.0, peak = 0.0;
    if (p < pc.particles && i < pc.directions) {
        uint k = p * pc.directions + i;
        vec3 r = step_one(p, i);
        next[k] = vec4(r, 0.0);
        vec3 dr = abs(r - current[k].rgb);
        // max() drops a NaN operand on most hardware: carry it through explicitly.
        change = any(isnan(dr)) ? uintBitsToFloat(0x7fc00000u) : max(dr.r, max(dr.g, dr.b));
        peak = any(isnan(r)) ? uintBitsToFloat(0x7fc00000u) : max(r.r, max(r.g, r.b));
    }
    change_max[l] = change;
    peak_max[l] = peak;
    barrier();
    for (uint s = 32u; s > 0u; s >>= 1) {
        if (l < s) {
            float c = change_max[l + s], q = peak_max[l + s];
            change_max[l] = (isnan(c) || c > change_max[l]) ? c : change_max[l];
            peak_max[l] = (isnan(q) || q > peak_max[l]) ? q : peak_max[l];
        }
        barrier();
    }
    if (l == 0u) {
        atomicMax(stats[2u * pc.slot + 2u], floatBitsToUint(change_max[0]));
        atomicMax(stats[2u * pc.slot + 3u], floatBitsToUint(peak_max[0]));
    }
}
