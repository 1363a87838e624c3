#version 460
// wave_field/march: every ray of the spherical grid marched w-layer by w-layer (paper section
// 2.1), carrying the power measures psi0 = r^2 phi and psi1 = r^2 E (eq. 4) and, in the same
// pass, the optical depth tau of the direct term (direct fluence Phi e^-tau / r^2).
// Initial values from the homogeneous solution (eq. 5): psi0(0) = 0, psi1(0) = Phi. Shell n
// (nodes n -> n + 1) takes the material resampled at its middle: sigma_a = sigma_t (1 - albedo),
// reduced extinction sigma_t' = sigma_t - sigma_s g, sigma_e = sqrt(3 sigma_a sigma_t').
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
// Integrator 1, `exponential`: each shell advanced with the exact homogeneous solution of that
// shell's material (eq. 5 and its general form phi = (a e^{-sigma_e r} + b e^{sigma_e r}) / r,
// keeping the outgoing, decaying mode b = 0). The carried quantity is the power psi1 (4 pi psi1
// is the power crossing the sphere; eq. 4's second line is its conservation):
//   psi1(r1) = psi1(r0) e^{-sigma_e Delta} (sigma_e r1 + 1) / (sigma_e r0 + 1)   (from eq. 5)
//   psi0(r1) = 3 sigma_t' r1 psi1(r1) / (sigma_e r1 + 1)                        (eq. 5)
// Exact at every node for a homogeneous medium whatever Delta; the factor lies in (0, 1], so
// psi1 never grows (no energy is created), and psi0, psi1 stay finite and non-negative for any
// sigma Delta: no overflow, since only e^{-x} with x >= 0 is evaluated.
#extension GL_GOOGLE_include_directive : require

#define SCENE_BINDING 0
#define DENSITY_BINDING 1
#define MAJORANT_BINDING 2
#include "../include/scene.glsl"
#include "../include/wave_field.glsl"

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;
layout(std430, binding = 3) readonly buffer Shells { float shell_density[]; };
// Per node: psi0 rgb (w: r), psi1 rgb, tau rgb (optical depth from the light).
layout(std430, binding = 4) writeonly buffer Psi0 { vec4 psi0_out[]; };
layout(std430, binding = 5) writeonly buffer Psi1 { vec4 psi1_out[]; };
layout(std430, binding = 6) writeonly buffer Tau { vec4 tau_out[]; };
// [0] nodes with a negative psi0 or psi1 value, [1] nodes with a non-finite value,
// [2] rays with a negative or non-finite node, [3] shells marched in total.
layout(std430, binding = 7) buffer Stats { uint stats[]; };

void main() {
    uvec2 id = gl_GlobalInvocationID.xy;
    if (id.x >= pc.dims.x || id.y >= pc.dims.y) return;
    uint ray = wf_ray(id.x, id.y);
    float delta = pc.light.w;
    uint layers = pc.dims.z;
    bool expo = pc.dims.w == 1u;
    float g = scene.albedo.w;
    vec3 phi_src = pc.intensity.rgb;

    vec3 psi0 = vec3(0.0);
    vec3 psi1 = phi_src;
    float r_start = pc.intensity.w;
    // The material at the light, for the explicit scheme's homogeneous start.
    vec3 st_l = scene.sigma_t.xyz * shell_density[wf_node(ray, 0u)];
    vec3 str_l = st_l - st_l * scene.albedo.xyz * g;
    vec3 se_l = sqrt(max(vec3(0.0), 3.0 * (st_l - st_l * scene.albedo.xyz) * str_l));
    vec3 tau = vec3(0.0);
    psi0_out[wf_node(ray, 0u)] = vec4(psi0, 0.0);
    psi1_out[wf_node(ray, 0u)] = vec4(psi1, 0.0);
    tau_out[wf_node(ray, 0u)] = vec4(tau, 0.0);
    uint negative = 0u, nonfinite = 0u;
    for (uint n = 0u; n < layers; ++n) {
        float dens = shell_density[wf_node(ray, n)];
        vec3 st = scene.sigma_t.xyz * dens;
        vec3 ss = st * scene.albedo.xyz;
        vec3 sa = st - ss;
        vec3 str = st - ss * g;                       // sigma_t'
        float r0 = float(n) * delta;
        float r1 = float(n + 1u) * delta;
        if (expo) {
            vec3 se = sqrt(max(vec3(0.0), 3.0 * sa * str));
            psi1 *= exp(-se * delta) * (se * r1 + 1.0) / (se * r0 + 1.0);
            psi0 = 3.0 * str * r1 * psi1 / (se * r1 + 1.0);
        } else if (r1 <= r_start) {
            // eq. 5 with A = 3 sigma_t' Phi (psi0 = A r e^{-sigma_e r}, the form of its r -> 0 limit).
            psi0 = 3.0 * str_l * phi_src * r1 * exp(-se_l * r1);
            psi1 = phi_src * exp(-se_l * r1) * (se_l * r1 + 1.0);
        } else {
            // eq. 6; at r = 0 the limit of (2 / r) psi0 is 6 sigma_t' Phi (section 2.1).
            vec3 two_over_r = n == 0u ? 6.0 * str * phi_src : 2.0 * psi0 / r0;
            vec3 p0 = psi0 + two_over_r * delta - 3.0 * str * psi1 * delta;
            vec3 p1 = psi1 - sa * psi0 * delta;
            psi0 = p0;
            psi1 = p1;
        }
        tau += st * delta;
        if (any(lessThan(psi0, vec3(0.0))) || any(lessThan(psi1, vec3(0.0)))) negative++;
        if (any(isnan(psi0)) || any(isinf(psi0)) || any(isnan(psi1)) || any(isinf(psi1))) nonfinite++;
        uint node = wf_node(ray, n + 1u);
        psi0_out[node] = vec4(psi0, r1);
        psi1_out[node] = vec4(psi1, 0.0);
        tau_out[node] = vec4(tau, 0.0);
    }
    if (negative > 0u) atomicAdd(stats[0], negative);
    if (nonfinite > 0u) atomicAdd(stats[1], nonfinite);
    if (negative + nonfinite > 0u) atomicAdd(stats[2], 1u);
    atomicAdd(stats[3], layers);
}
