#version 460
// wave_field/march: every ray of the spherical grid marched w-layer by w-layer (paper section
// 2.1), carrying the power measures psi0 = r^2 phi and psi1 = r^2 E (eq. 4) and, in the same
// pass, the optical depth tau of the direct term (direct fluence Phi e^-tau / r^2).
// Initial values from the homogeneous solution (eq. 5): psi0(0) = 0, psi1(0) = Phi. Shell n
// (nodes n -> n + 1) takes the material resampled at its middle: sigma_a = sigma_t (1 - albedo),
// reduced extinction sigma_t' = sigma_t - sigma_s g, sigma_e = sqrt(3 sigma_a sigma_t').
// pc.dims.w picks the integrator: 0 explicit, 1 exponential (infinite medium), 2 exponential
// with the extrapolated boundary (the default).
//
// Integrator 0, `explicit`: the paper's eq. 6, explicit Euler, with the 0/0 of 2 psi0 / r at
// r = 0 replaced by its limit 6 sigma_t' Phi. Measured (tests/wavefront_tests.rs): from r = 0
// it does not converge to eq. 5 as Delta -> 0 in an absorbing medium. r = 0 is a singular
// point where both solutions of eq. 4, r e^{-sigma_e r} and the growing r e^{+sigma_e r}, have
// psi0 = 0, the same psi1 and the same slope, so the initial values cannot tell them apart;
// Euler's first steps (where Delta / r ~ 1 whatever Delta) mix in the growing mode by an
// amount independent of Delta, and it outgrows the decaying one by e^{2 sigma_e r}: psi0
// turns negative, and past sigma_e Delta ~ 2 the iteration overflows. With a start radius
// r_s > 0 (`wavefront.explicit_start`) the nodes r <= r_s take the homogeneous solution of the
// material at the light (eq. 5, "in order to obtain the initial values, we take the solution
// for homogeneous material") and eq. 6 runs from there: first order in Delta.
//
// Integrator 1, `exponential` with `boundary = infinite`: each shell advanced with the exact
// homogeneous solution of that shell's material (eq. 5 and its general form
// phi = (a e^{-sigma_e r} + b e^{sigma_e r}) / r, keeping the outgoing, decaying mode b = 0).
// The carried quantity is the power psi1 (4 pi psi1 is the power crossing the sphere; eq. 4's
// second line is its conservation):
//   psi1(r1) = psi1(r0) e^{-sigma_e Delta} (sigma_e r1 + 1) / (sigma_e r0 + 1)   (from eq. 5)
//   psi0(r1) = 3 sigma_t' r1 psi1(r1) / (sigma_e r1 + 1)                        (eq. 5)
// Exact at every node for an infinite homogeneous medium whatever Delta; the factor lies in
// (0, 1], so psi1 never grows (no energy is created), and psi0, psi1 stay finite and
// non-negative for any sigma Delta: no overflow, since only e^{-x} with x >= 0 is evaluated.
// It ignores the medium's boundary: power that would leak out is kept (23% too bright on the
// light-inside cloud, 46% over the lossless bound in a cube of optical thickness 10).
//
// Integrator 2, `exponential` with `boundary = extrapolated` (default): the exact solution of
// eq. 3/4 for the ray's layer-wise homogeneous shells with both modes of each shell, phi and E
// continuous at every shell interface (diffusion theory's interface conditions: fluence and
// normal flux continuous), psi1(0) = Phi at the light (eq. 5's source condition), and a
// boundary where the ray leaves the medium instead of an infinite medium:
//  - the exit r_x: the outer end of the ray's last shell of non-zero density (beyond it the
//    density is 0 up to the box: nothing left to scatter).
//  - the extrapolated-boundary condition of diffusion theory for an index-matched boundary
//    (Farrell, Patterson & Wilson 1992; Haskell et al. 1994, "Boundary conditions for the
//    diffusion equation in radiative transfer"): phi = 0 a distance z_b = 2 D beyond the exit,
//    D = 1 / (3 sigma_t'). Taken across a plane-parallel extrapolation layer: its optical
//    thickness x_b = sigma_e 2 D = 2 sqrt((1 - albedo) / (3 (1 - albedo g))) does not depend on
//    the density, and r phi ~ sinh(sigma_e (r_x + 2 D - r)) gives at the exit
//      Z = psi0 / psi1 = phi / E = 2 tanh(x_b) / x_b
//    (Marshak's zero incoming partial current phi / 4 - E / 2 = 0, i.e. phi = 2 E, for a lossless
//    layer). Not the spherical form phi ~ sinh(sigma_e (r_x + 2 D - r)) / r, whose curvature
//    lowers Z by 1 / (1 + (2 D / r_x) tanh(x_b) / x_b): it needs the layer's length 2 D, i.e. D
//    at the exit, which a soft edge's vanishing density does not give, and measured it leaves
//    the light-inside cloud 13% too dark (docs/wavefront.md, docs/decisions.md).
//  - Z never above the infinite medium's outgoing mode Z = 3 sigma_t' r / (sigma_e r + 1)
//    (eq. 5) of the ray's mean outer material (a boundary only lets light out): this is what
//    bounds Z in an optically thin medium (-> 3 tau'), so there the multiply scattered light
//    vanishes with tau as it must. The mean outer material: sigma_t' averaged over the
//    distance z_b inward from the exit over which it integrates to 2/3 (exactly 2 D for a
//    homogeneous medium), or over the whole ray where it has less.
//  - backward sweep, exit -> light: per node the ratio U = u / p of u = r phi = psi0 / r and
//    p = psi1 (one solution of eq. 4 up to scale, so only ratios are kept), and per shell the
//    power transfer T = psi1(r1) / psi1(r0). In a shell of constant material, with
//    x = sigma_e Delta, the solution through (u1, p1) at r1 is
//      u(r) = u1 cosh(sigma_e (r1 - r)) + (3 sigma_t' p1 - u1) / r1 sinh(sigma_e (r1 - r)) / sigma_e
//    (phi = (a e^{-sigma_e r} + b e^{sigma_e r}) / r, both modes), psi1 = (u - r u') / (3 sigma_t')
//    (eq. 3's first line), and p0 = p1 + sigma_a int r u dr (its second line) in closed form:
//      e u0 = U1 C + (3 sigma_t' - U1) (Delta / r1) S
//      e p0 = (r0 C + Delta S) / r1 + U1 sigma_a Delta (r0 r1 S + Delta^2 K) / r1      (p1 = 1)
//    with e = e^{-x}, C = e cosh x, S = e sinh(x) / x, K = e (cosh x - sinh(x) / x) / x^2, all in
//    [0, 1] for any x (series near x = 0, where sigma_a -> 0 and the vacuum limit phi = const
//    are reached continuously): U0 = e u0 / e p0, T = e / e p0. U stays >= 0 and T in [0, 1].
//  - forward sweep, light -> exit: psi1(r_{n+1}) = psi1(r_n) T_n from psi1(0) = Phi, and
//    psi0 = r U psi1. psi1 never grows (no power is created), nothing is negative, and only
//    e^{-x}, x >= 0, is evaluated: no overflow at sigma_t 1e4. For a homogeneous sphere around
//    the light it is the closed form phi = (a e^{-sigma_e r} + b e^{sigma_e r}) / r with
//    psi1(0) = Phi and Z(r_x) as above (tests/wavefront_tests.rs checks it node by node).
//  - nodes beyond the exit (vacuum up to the box): psi1 kept (the power streams out), phi
//    falling linearly to 0 at r_x + z_b (the extrapolated boundary's meaning), 0 beyond; the
//    gather interpolates between them and the medium's nodes.
#extension GL_GOOGLE_include_directive : require

#define SCENE_BINDING 0
#define DENSITY_BINDING 1
#define MAJORANT_BINDING 2
#include "../include/scene.glsl"
#include "../include/wave_field.glsl"

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;
layout(std430, binding = 3) readonly buffer Shells { float shell_density[]; };
// Per node: psi0 rgb (w: r), psi1 rgb, tau rgb (optical depth from the light). The extrapolated
// boundary's backward sweep keeps U in psi0 and T in psi1 until the forward sweep replaces them.
layout(std430, binding = 4) buffer Psi0 { vec4 psi0_out[]; };
layout(std430, binding = 5) buffer Psi1 { vec4 psi1_out[]; };
layout(std430, binding = 6) writeonly buffer Tau { vec4 tau_out[]; };
// [0] nodes with a negative psi0 or psi1 value, [1] nodes with a non-finite value,
// [2] rays with a negative or non-finite node, [3] shells marched in total.
layout(std430, binding = 7) buffer Stats { uint stats[]; };

bvec3 both(bvec3 a, bvec3 b) { return bvec3(a.x && b.x, a.y && b.y, a.z && b.z); }

// A shell's material per channel: sigma_t, reduced extinction sigma_t', sigma_a, sigma_e.
struct Material { vec3 st; vec3 str; vec3 sa; vec3 se; };

Material material(float dens) {
    Material m;
    m.st = scene.materials[0].sigma_t.xyz * dens;
    vec3 ss = m.st * scene.materials[0].albedo.xyz;
    m.sa = m.st - ss;
    m.str = m.st - ss * scene.materials[0].albedo.w;   // g in albedo.w
    m.se = sqrt(max(vec3(0.0), 3.0 * m.sa * m.str));
    return m;
}

// e^{-x} cosh x, e^{-x} sinh(x) / x and e^{-x} (cosh x - sinh(x) / x) / x^2 for x >= 0: each in
// [0, 1], finite for any x (e^{-x} underflows to 0, the rest stays bounded); Taylor series
// below x = 0.5, where the closed forms cancel (truncation < 1e-8 there).
void scaled_hyperbolic(vec3 x, out vec3 c, out vec3 s, out vec3 k) {
    vec3 e = exp(-x);
    vec3 e2 = e * e;
    vec3 x2 = x * x;
    c = 0.5 * (1.0 + e2);
    vec3 s_series = e * (1.0 + x2 * (1.0 / 6.0 + x2 * (1.0 / 120.0 + x2 * (1.0 / 5040.0))));
    vec3 k_series = e * (1.0 / 3.0 + x2 * (1.0 / 30.0 + x2 * (1.0 / 840.0 + x2 * (1.0 / 45360.0))));
    bvec3 small = lessThan(x, vec3(0.5));
    vec3 xs = max(x, vec3(0.5));
    vec3 s_closed = (1.0 - e2) / (2.0 * xs);
    s = mix(s_closed, s_series, small);
    k = mix((c - s_closed) / (xs * xs), k_series, small);
}

// One shell [r0, r1] of constant material, walked inward (header, integrator 2): from the ratio
// U1 = u / p at r1 to U0 at r0, and the shell's power transfer T = psi1(r1) / psi1(r0).
void back_step(vec3 u1, float r0, float r1, Material m, out vec3 u0, out vec3 t) {
    float d = r1 - r0;
    vec3 x = m.se * d;
    vec3 c, s, k;
    scaled_hyperbolic(x, c, s, k);
    vec3 eu0 = u1 * c + (3.0 * m.str - u1) * (d / r1) * s;
    vec3 ep0 = (r0 * c + d * s) / r1 + u1 * m.sa * d * (r0 * r1 * s + d * d * k) / r1;
    u0 = eu0 / ep0;
    // T <= 1 exactly (p only grows inward); rounding in (r0 C + Delta S) / r1 = 1 of a lossless
    // shell could otherwise let psi1 creep above Phi by an ulp per shell.
    t = min(exp(-x) / ep0, vec3(1.0));
}

void main() {
    uvec2 id = gl_GlobalInvocationID.xy;
    if (id.x >= pc.dims.x || id.y >= pc.dims.y) return;
    uint ray = wf_ray(id.x, id.y);
    float delta = pc.light.w;
    uint layers = pc.dims.z;
    uint integrator = pc.dims.w;
    float g = scene.materials[0].albedo.w;
    vec3 phi_src = pc.intensity.rgb;

    if (integrator == 2u) {
        // Where the ray leaves the medium (the outer end of its last shell of non-zero density),
        // and z_b, the extrapolation distance: how far inward from there sigma_t' integrates to
        // 2/3 (= 2 D for a homogeneous medium), per channel; 2 D of the ray's mean sigma_t'
        // where it has less. One sweep from the outside in (it stops at 2/3), and the two below:
        // at most 3 layers loop iterations per invocation (llvmpipe's loop limit, 65535 in all;
        // MAX_LAYERS in wave_field.rs).
        int exit_shell = -1;
        float r_exit = 0.0;
        vec3 tau_r = vec3(0.0);
        vec3 zb = vec3(-1.0);
        for (int n = int(layers) - 1; n >= 0; --n) {
            float dens = shell_density[wf_node(ray, uint(n))];
            if (exit_shell < 0) {
                if (dens <= 0.0) continue;
                exit_shell = n;
                r_exit = float(n + 1) * delta;
            }
            vec3 dt = material(dens).str * delta;
            vec3 at = r_exit - float(n + 1) * delta + (2.0 / 3.0 - tau_r) / max(dt, vec3(1e-30)) * delta;
            zb = mix(zb, at, both(lessThan(zb, vec3(0.0)), greaterThanEqual(tau_r + dt, vec3(2.0 / 3.0))));
            tau_r += dt;
            if (all(greaterThanEqual(zb, vec3(0.0)))) break;
        }
        zb = mix(zb, 2.0 / 3.0 * r_exit / max(tau_r, vec3(1e-30)), lessThan(zb, vec3(0.0)));
        // Z = psi0 / psi1 at the exit (header): phi = 0 at the extrapolated boundary, across a
        // plane-parallel extrapolation layer of optical thickness x_b = sigma_e 2 D.
        vec3 a = scene.materials[0].albedo.xyz;
        vec3 xb = 2.0 * sqrt(max(vec3(0.0), (1.0 - a) / (3.0 * (1.0 - a * g))));
        vec3 cb, sb, kb;
        scaled_hyperbolic(xb, cb, sb, kb);
        // A boundary only lets light out: never above the infinite medium's outgoing mode
        // Z = 3 sigma_t' r / (sigma_e r + 1) (eq. 5) of the same mean material, which is what
        // bounds Z in an optically thin medium (-> 3 tau', so the multiply scattered light
        // vanishes with tau as it must, where 2 tanh(x_b) / x_b alone stays near 2).
        vec3 s_mean = 2.0 / (3.0 * zb);
        vec3 se_mean = sqrt(3.0 * s_mean * s_mean * (1.0 - a) / (1.0 - a * g));
        vec3 z_infinite = 3.0 * s_mean * r_exit / (se_mean * r_exit + 1.0);
        vec3 z_exit = exit_shell < 0 ? vec3(0.0) : min(2.0 * sb / cb, z_infinite);   // 2 tanh(x_b) / x_b
        z_exit = mix(z_exit, vec3(0.0), equal(tau_r, vec3(0.0)));  // no medium on the ray: phi = 0
        // Backward sweep: U per node in psi0_out, T per shell in psi1_out at its outer node.
        vec3 u = z_exit / max(r_exit, 1e-30);
        for (int n = int(layers) - 1; n >= 0; --n) {
            uint outer = wf_node(ray, uint(n + 1));
            if (n > exit_shell) {
                // Beyond the exit (vacuum up to the box): psi1 kept, and phi falling linearly
                // to 0 at the extrapolated boundary r_exit + z_b (the condition's meaning), 0
                // beyond; the gather interpolates between these nodes and the medium's.
                float r = float(n + 1) * delta;
                vec3 u_r = z_exit * r / (r_exit * r_exit) * max(vec3(0.0), 1.0 - (r - r_exit) / zb);
                psi0_out[outer] = vec4(exit_shell < 0 ? vec3(0.0) : u_r, 0.0);
                psi1_out[outer] = vec4(1.0);
                continue;
            }
            vec3 u0, t;
            back_step(u, float(n) * delta, float(n + 1) * delta, material(shell_density[wf_node(ray, uint(n))]), u0,
                      t);
            psi0_out[outer] = vec4(u, 0.0);
            psi1_out[outer] = vec4(t, 0.0);
            u = u0;
        }
    }

    vec3 psi0 = vec3(0.0);
    vec3 psi1 = phi_src;
    float r_start = pc.intensity.w;
    // The material at the light, for the explicit scheme's homogeneous start.
    Material at_light = material(shell_density[wf_node(ray, 0u)]);
    vec3 tau = vec3(0.0);
    psi0_out[wf_node(ray, 0u)] = vec4(psi0, 0.0);
    psi1_out[wf_node(ray, 0u)] = vec4(psi1, 0.0);
    tau_out[wf_node(ray, 0u)] = vec4(tau, 0.0);
    uint negative = 0u, nonfinite = 0u;
    for (uint n = 0u; n < layers; ++n) {
        Material m = material(shell_density[wf_node(ray, n)]);
        float r0 = float(n) * delta;
        float r1 = float(n + 1u) * delta;
        uint node = wf_node(ray, n + 1u);
        if (integrator == 2u) {
            // Forward sweep of the extrapolated-boundary solution: psi1 by the shell's
            // transfer, psi0 = r U psi1.
            psi1 *= psi1_out[node].rgb;
            psi0 = r1 * psi0_out[node].rgb * psi1;
        } else if (integrator == 1u) {
            psi1 *= exp(-m.se * delta) * (m.se * r1 + 1.0) / (m.se * r0 + 1.0);
            psi0 = 3.0 * m.str * r1 * psi1 / (m.se * r1 + 1.0);
        } else if (r1 <= r_start) {
            // eq. 5 with A = 3 sigma_t' Phi (psi0 = A r e^{-sigma_e r}, the form of its r -> 0 limit).
            psi0 = 3.0 * at_light.str * phi_src * r1 * exp(-at_light.se * r1);
            psi1 = phi_src * exp(-at_light.se * r1) * (at_light.se * r1 + 1.0);
        } else {
            // eq. 6; at r = 0 the limit of (2 / r) psi0 is 6 sigma_t' Phi (section 2.1).
            vec3 two_over_r = n == 0u ? 6.0 * m.str * phi_src : 2.0 * psi0 / r0;
            vec3 p0 = psi0 + two_over_r * delta - 3.0 * m.str * psi1 * delta;
            vec3 p1 = psi1 - m.sa * psi0 * delta;
            psi0 = p0;
            psi1 = p1;
        }
        tau += m.st * delta;
        if (any(lessThan(psi0, vec3(0.0))) || any(lessThan(psi1, vec3(0.0)))) negative++;
        if (any(isnan(psi0)) || any(isinf(psi0)) || any(isnan(psi1)) || any(isinf(psi1))) nonfinite++;
        psi0_out[node] = vec4(psi0, r1);
        psi1_out[node] = vec4(psi1, 0.0);
        tau_out[node] = vec4(tau, 0.0);
    }
    if (negative > 0u) atomicAdd(stats[0], negative);
    if (nonfinite > 0u) atomicAdd(stats[1], nonfinite);
    if (negative + nonfinite > 0u) atomicAdd(stats[2], 1u);
    atomicAdd(stats[3], layers);
}
