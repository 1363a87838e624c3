#version 460
// sh_single/render: `sh-single`'s render pass (issue 17, thesis 3.4, eq. 3.4). Per pixel, the
// camera ray meets the object (the mesh's BVH), refracts with the Fresnel transmittance into it
// (thesis 3.1.1; radiance scaled by (1 - F) / ior^2 on the way in, as `single`'s chain) and runs
// straight to the next surface. Along that segment every sample's Gaussian gamma_i(x) =
// exp(-a_i |x - b_i|^2) is integrated in closed form,
//   int_0^t1 gamma_i = exp(-a h^2) sqrt(pi / a) / 2 [erf(sqrt a (t1 - tc)) + erf(sqrt a tc)]
// (tc the sample's projection on the ray, h its distance from it), and weighted by
//   sigma_s(b_i) psi_i(-d) [ sum_j p(w_ij . d) E_ij + L_env f_env sum_lm g^l psi_lm Y_lm(d) ]:
// psi_i(-d) the sample's SH-reconstructed attenuation toward the camera, E_ij the light j's
// irradiance at the sample already attenuated by psi_i toward it and by `single`'s boundary
// factor of the surfaces crossed (Fresnel 1 - F and the ior^2 of the radiance entering;
// src/solvers/sh_single.rs, on the host), p the Henyey-Greenstein phase, and the constant
// environment's in-scattering by Funk-Hecke: HG's band-l coefficient is g^l, so the
// convolution of psi with p is sum g^l psi_lm Y_lm (with a refractive object, of psi times the
// boundary factor of each direction: a second coefficient set per sample).
// Samples come in chunks (one dispatch each, adding into the image); the first chunk also
// writes the surface's own terms: the environment reflected at the entry (F L_env) and seen
// through each exit ((1 - F_exit) e^-tau L_env, the chords' optical depths marched). The camera
// ray's chain reflects inside (F at each exit, all of it under total internal reflection), as
// `single`'s view march does, and crosses index-matched surfaces straight, up to MAX_EVENTS.
// Left out: light reaching a sample along a refracted path (as `single`).
// An emissive medium adds its emission along each inside segment (segment_emission), the
// zero-scattering term, with the surfaces' terms; the emitted light it scatters is left out.
#extension GL_GOOGLE_include_directive : require

#define SCENE_BINDING 0
#define DENSITY_BINDING 1
#define MAJORANT_BINDING 2
#define EMISSION_BINDING 15
#include "../include/scene.glsl"
#include "../include/budget.glsl"
#define MESH_NODES_BINDING 6
#define MESH_TRIS_BINDING 7
#include "../include/mesh.glsl"
#include "../include/dielectric.glsl"
#include "../include/phase.glsl"
#include "../include/one_minus_exp.glsl"
#include "../include/sh.glsl"

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

// Sample i, from SAMPLE_WORDS i: centre xyz, w = a; nu_i sigma_s rgb, w = g; x = nu_i (the
// partition weight); per channel the environment's mean gradient of the optical depth, w = its
// optical depth (src/solvers/sh_single.rs, environment_gradient).
const uint SAMPLE_WORDS = 6u;
layout(std430, binding = 3) readonly buffer Samples { vec4 samples[]; };
// Sample i's attenuation coefficients: [(i * 3 + c) * order^2 + k]; with env_coeffs each sample has
// six sets, psi's three then the environment's three: [(i * 6 + c) * order^2 + k], [(i * 6 + 3 + c) ...].
layout(std430, binding = 4) readonly buffer Coeffs { float coeffs[]; };
// Sample i, light j, from LIGHT_WORDS (i * lights + j): the irradiance before attenuation
// toward the light (the boundary factor's only) rgb; the unit direction toward the light; per channel the gradient of the optical
// depth toward the light with respect to the sample's position, w = that depth
// (src/solvers/sh_single.rs, tau_gradient).
layout(std430, binding = 5) readonly buffer LightTerms { vec4 lterms[]; };
// Per pixel, four words (main, at the end), accumulated over the chunks.
layout(std430, binding = 8) buffer Radiance { vec4 radiance[]; };
// [0]: the most loop back-edges any invocation counted (`iters`): past LOOP_GUARD llvmpipe's
// limiter may have cut a loop short, and the host renders again in smaller chunks.
layout(std430, binding = 9) buffer Stats { uint stats[]; };
// The spatial index of the Gaussians (src/solvers/sh_single.rs, GaussianIndex; with
// pc.grid_dims.w = 1): cell c lists the samples whose truncated Gaussians overlap it, in
// increasing order, at items[starts[c] .. starts[c + 1]].
layout(std430, binding = 10) readonly buffer IndexCells { uint starts[]; };
layout(std430, binding = 11) readonly buffer IndexItems { uint items[]; };

layout(push_constant) uniform Push {
    uint first;      // first sample of this chunk
    uint count;      // samples in this chunk
    uint order;      // spherical-harmonics order
    uint lights;     // point and directional lights (the light terms per sample)
    vec4 env;        // constant environment radiance rgb; w = 1 for the first chunk
    uint env_coeffs;  // 1: each sample has a second set for the environment (psi times the boundary factor)
    float step;      // chord marching step for grid densities, scene units
    uint pad0;
    uint pad1;
    vec4 grid;       // the index's origin xyz and cell edge w (scene units)
    uvec4 grid_dims; // its cells per axis, w = 1 where there is an index (else every sample is visited)
    vec4 box_lo;     // the box of this chunk's truncated Gaussians; w = 1: skip the chunk where the segment misses it
    vec4 box_hi;
} pc;

// Loop back-edges sh_basis takes at `order` (its zero fill, then the bands), counted
// generously toward llvmpipe's limiter.
uint sh_basis_iters(uint order) { return SH_MAX_COEFFS + order + order * order * order; }

// exp(c) erfc(x) for x >= 0 without forming exp(c) or erfc(x) alone: Abramowitz & Stegun
// 7.1.26, erfc(x) = t P(t) exp(-x^2), |error| < 1.5e-7.
float erfc_exp(float c, float x) {
    float t = 1.0 / (1.0 + 0.3275911 * x);
    return (((((1.061405429 * t - 1.453152027) * t) + 1.421413741) * t - 0.284496736) * t + 0.254829592) * t * exp(c - x * x);
}

// exp(c) int_{v0}^{v1} exp(-a v^2) dv = exp(c) sqrt(pi / a) / 2 (erf(sqrt a v1) - erf(sqrt a v0)),
// written with erfc on the side where both limits lie (no cancellation between two values near
// 1, no overflow where exp(c) alone would be large and the tail small).
float gauss_interval(float c, float a, float v0, float v1) {
    float sa = sqrt(a);
    float x0 = sa * v0, x1 = sa * v1;
    float d;
    if (x0 >= 0.0) d = erfc_exp(c, x0) - erfc_exp(c, x1);
    else if (x1 <= 0.0) d = erfc_exp(c, -x1) - erfc_exp(c, -x0);
    else d = 2.0 * exp(c) - erfc_exp(c, -x0) - erfc_exp(c, x1);
    return 0.5 * sqrt(PI / a) * max(d, 0.0);
}

const uint LIGHT_WORDS = 5u;

// Points of a segment's optical-depth table (grid densities): the camera's optical depth is
// interpolated linearly between them.
const uint CHORD_POINTS = 32u;

// exp(C) int_{u0}^{u1} exp(-a u^2 - S u) du, zero where u1 <= u0: a Gaussian times the exponential
// of a linear optical depth, in closed form by completing the square (the depth's slope S moves
// the peak by -S / 2a and raises it by S^2 / 4a).
float gauss_linear(float C, float a, float S, float u0, float u1) {
    if (u1 <= u0) return 0.0;
    float shift = S / (2.0 * a);
    return gauss_interval(C + S * shift * 0.5, a, u0 + shift, u1 + shift);
}

// The Gaussian's integral along the segment with the camera's optical depth (tau_c, slope s
// about t_c) and a light's absolute attenuation exp(-tau_l(x)), tau_l linear across the Gaussian:
// tau_l(b_i) + grad . (r_perp + d (t - t_c)), r_perp the ray's closest point less b_i; gr = (grad,
// tau_l(b_i)). The caller multiplies by the light's unattenuated value. grad is a first-order
// model of a surface that curves, so the linear depth is floored at zero: exp(-max(tau_l, 0)),
// in two closed-form pieces either side of its zero. Without the floor a steep gradient across
// a wide Gaussian (a sample many mean free paths under the surface of a thick slab, its Gaussian
// reaching past the surface) took the depth far below zero and the attenuation to exp(+tau^2/18):
// sh-single's thick slab came out 10^2-10^8 times `single`'s energy. With it the light factor is
// at most 1, so the Gaussian's part is at most its camera-attenuated coverage (energy is never
// created). The slope is also kept from taking the depth below zero within three standard
// deviations of t_c (back, ahead: the stretch of the segment there on either side), which flattens
// the model where the Gaussian has its weight.
float lit_gaussian(vec4 gr, vec3 rperp, vec3 d, float a, float h2, float tc, float t1, float tau_c, float s, float back, float ahead) {
    float tau_near = max(gr.w + dot(gr.xyz, rperp), 0.0);
    float sl = dot(gr.xyz, d);
    if (sl > 0.0 && back > 0.0) sl = min(sl, tau_near / back);
    if (sl < 0.0 && ahead > 0.0) sl = max(sl, -tau_near / ahead);
    float C = -a * h2 - tau_c;
    float u0 = -tc, u1 = t1 - tc;
    if (sl == 0.0) return gauss_linear(C - tau_near, a, s, u0, u1);
    // tau_l(u) = tau_near + sl u is zero at uz; below it on the side the slope falls to.
    float uz = -tau_near / sl;
    if (sl > 0.0)
        return gauss_linear(C, a, s, u0, min(uz, u1)) + gauss_linear(C - tau_near, a, s + sl, max(uz, u0), u1);
    return gauss_linear(C - tau_near, a, s + sl, u0, min(uz, u1)) + gauss_linear(C, a, s, max(uz, u0), u1);
}

// Per channel, sum_lm f^l c_lm Y_lm(d) over the coefficients of one set (from `base`, three
// channels of n_coeff each; y = Y(d)): with f = -1 the sample's psi(-d) (Y_lm(-d) = (-1)^l
// Y_lm(d)), with f = g psi's convolution with Henyey-Greenstein (Funk-Hecke: its band-l
// coefficient is g^l).
vec3 sh_weighted(uint base, uint n_coeff, float y[SH_MAX_COEFFS], float f) {
    vec3 sum = vec3(0.0);
    float fl = 1.0;
    uint l = 0u, next = 1u;
    for (uint k = 0u; k < n_coeff; ++k) {
        iters++;
        if (k == next) {
            ++l;
            next = (l + 1u) * (l + 1u);
            fl *= f;
        }
        sum += fl * vec3(coeffs[base + k], coeffs[base + n_coeff + k], coeffs[base + 2u * n_coeff + k]) * y[k];
    }
    return sum;
}

// Sample i's part of segment_light (below): its Gaussian's integral along the segment from x
// along d over [0, t1], weighted by its lights and environment, added to L and its coverage to
// cover. `constant`, st, n_coeff and env as segment_light sets them; the basis of d in sh_y.
float sh_y[SH_MAX_COEFFS];
void add_sample(uint i, vec3 x, vec3 d, float t1, bool constant, vec3 st, uint n_coeff, bool env, inout vec3 L, inout vec3 cover) {
    vec4 ba = samples[SAMPLE_WORDS * i];
    vec3 rel = ba.xyz - x;
    float tc = dot(rel, d);
    float h2 = max(0.0, dot(rel, rel) - tc * tc);
    float a = ba.w;
    if (a * h2 > 14.0) return;   // exp(-14) < 1e-6: the thesis's cut (3.4.2)
    if (tc < -sqrt(14.0 / a) || tc > t1 + sqrt(14.0 / a)) return;
    // The camera's optical depth about t_c: value and slope. For a grid density it is the
    // sample's own psi_i(-d) across the whole Gaussian, as the thesis (3.4): the Gaussian
    // spreads the sample's sigma_s over its width, and an attenuation taken along the ray
    // instead (the chord's at t_c, its slope, its exact piecewise depth) moved the light of
    // a dense core to the thin medium in front of it (the cloud 1.20-1.33x `single`).
    vec3 tau_c, slope;
    if (constant) {
        tau_c = st * tc;
        slope = st;
    } else {
        // psi_i(-d): the sample's own attenuation toward the camera.
        vec3 view = sh_weighted(i * (pc.env_coeffs == 1u ? 6u : 3u) * n_coeff, n_coeff, sh_y, -1.0);
        tau_c = -log(max(view, vec3(1e-30)));
        slope = vec3(0.0);
    }
    vec3 rperp = x + d * tc - ba.xyz;
    float sd = sqrt(0.5 / a);
    float back = min(tc, 3.0 * sd), ahead = min(t1 - tc, 3.0 * sd);
    // With the camera's attenuation alone: the coverage.
    vec3 G;
    for (uint c = 0u; c < 3u; ++c) {
        float sh = slope[c] / (2.0 * a);
        G[c] = gauss_interval(-a * h2 - tau_c[c] + slope[c] * sh * 0.5, a, -tc + sh, t1 - tc + sh);
    }
    if (max3(G) <= 0.0) return;
    vec4 sg = samples[SAMPLE_WORDS * i + 1u];
    float nu = samples[SAMPLE_WORDS * i + 2u].x;
    float g = sg.w;
    vec3 lit = vec3(0.0);
    for (uint j = 0u; j < pc.lights; ++j) {
        iters++;
        uint base = LIGHT_WORDS * (i * pc.lights + j);
        // The light's value at the sample before attenuation: the host's boundary factor
        // times the irradiance (the attenuation is lit_gaussian's, from gr.w).
        vec3 e = lterms[base].rgb;
        vec3 w = lterms[base + 1u].xyz;
        float p = hg_eval(g, dot(w, d));
        for (uint c = 0u; c < 3u; ++c) {
            iters++;
            lit[c] += p * e[c] * lit_gaussian(lterms[base + 2u + c], rperp, d, a, h2, tc, t1, tau_c[c], slope[c], back, ahead);
        }
    }
    if (env) {
        uint base = i * (pc.env_coeffs == 1u ? 6u : 3u) * n_coeff + (pc.env_coeffs == 1u ? 3u * n_coeff : 0u);
        vec3 envs = sh_weighted(base, n_coeff, sh_y, g);
        // The environment's attenuation varies across the Gaussian as the lights' does:
        // with the psi-weighted mean gradient over directions (sh_single.rs,
        // environment_gradient).
        // lit_gaussian gives the absolute attenuation, with the depth -ln(mean psi) at the
        // centre (gr.w): the environment's value before it is envs / mean psi. That ratio
        // is at most 4 pi max p = (1 + |g|) / (1 - |g|)^2 (envs = int psi p <= max p int psi),
        // which also keeps it finite; where mean psi underflows, the isotropic ratio 1.
        float ratio_max = (1.0 + abs(g)) / ((1.0 - abs(g)) * (1.0 - abs(g)));
        for (uint c = 0u; c < 3u; ++c) {
            iters++;
            vec4 gr = samples[SAMPLE_WORDS * i + 3u + c];
            float mean_psi = exp(-gr.w);
            float before = mean_psi > 1e-30 ? min(max(envs[c], 0.0) / mean_psi, ratio_max) : 1.0;
            lit[c] += pc.env[c] * before * lit_gaussian(gr, rperp, d, a, h2, tc, t1, tau_c[c], slope[c], back, ahead);
        }
    }
    L += sg.rgb * lit;
    if (constant) cover += nu * G;
    else cover += nu * gauss_interval(-a * h2, a, -tc, t1 - tc);
}

// What the samples of this chunk scatter toward the camera along the inside segment from x
// along d over [0, t1] in material mat, attenuated on the way to x exactly (the camera side):
//   sum_i nu_i sigma_s(b_i) [ lights + environment ]_i int_0^t1 gamma_i(t) exp(-tau_cam(t)) dt.
// tau_cam is the segment's own optical depth from x: sigma_t t for a constant density (exact),
// else linear about the sample's closest point t_c with the local slope from a table of
// CHORD_POINTS + 1 depths. With tau_cam(t) = tau_c + s (t - t_c) the integral is closed form:
//   exp(-a h^2 - tau_c + s^2 / 4a) int exp(-a (t - t_c + s / 2a)^2) dt.
// The thesis (3.4) weights each Gaussian by its centre's attenuation toward the camera; with the
// steep first mean free path under the surface that undercounts it (a medium of optical
// thickness 32 rendered 0.69x `single`). `tau_total` returns the segment's optical depth.
// The environment's in-scattering uses the sample's psi by Funk-Hecke: HG's band-l coefficient
// is g^l, so sum g^l psi_lm Y_lm(d); its loop runs only where the scene has an environment.
// A sample costs 1 + lights (+ order^2 with an environment) back-edges of llvmpipe's shared
// loop counter (budget.glsl), which the host keeps under the limiter by the chunk size.
vec3 segment_light(vec3 x, vec3 d, float t1, uint mat, out vec3 tau_total, out vec3 cover, out vec3 exact) {
    medium_mat = mat;
    vec3 st = scene.materials[mat].sigma_t.xyz;
    bool constant = DENSITY_KIND == DENSITY_CONSTANT;
    vec3 table[CHORD_POINTS + 1u];
    float dt = t1 / float(CHORD_POINTS);
    if (constant) {
        tau_total = st * t1;
        // int_0^t1 exp(-sigma t) dt = t1 (1 - exp(-k)) / k, k = sigma t1 (one_minus_exp.glsl:
        // the first-order form below 1e-4 and the subtraction above it were 6e-4 off there).
        for (uint c = 0u; c < 3u; ++c) exact[c] = t1 * one_minus_exp_over(st[c] * t1);
    } else {
        table[0] = vec3(0.0);
        uint sub = max(1u, uint(ceil(dt / pc.step)));
        float h = dt / float(sub);
        for (uint k = 0u; k < CHORD_POINTS; ++k) {
            float s = 0.0;
            for (uint j = 0u; j < sub; ++j) {
                iters++;
                s += density_at(x + d * ((float(k * sub + j) + 0.5) * h)) * h;
            }
            table[k + 1u] = table[k] + st * s;
        }
        tau_total = table[CHORD_POINTS];
        // The coverage of a grid density is the Gaussians' own (no attenuation): its length.
        exact = vec3(t1);
    }
    bool env = max3(pc.env.rgb) > 0.0;
    uint n_coeff = pc.order * pc.order;
    if (env || !constant) {
        sh_basis(d, pc.order, sh_y);
        iters += sh_basis_iters(pc.order);
    }
    vec3 L = vec3(0.0);
    cover = vec3(0.0);
    // The segment against this chunk's box (pc.box_lo.w = 1, always with the grid: the samples
    // are in Morton order, so a chunk is a compact region): a segment outside the box is outside
    // every sample's ball. (A zero direction component is replaced by a tiny one, whose slab
    // stays finite where 0 x inf would give NaN.)
    vec2 tb = ray_box(x, mix(d, vec3(1e-30), equal(d, vec3(0.0))), pc.box_lo.xyz, pc.box_hi.xyz);
    float t_lo = max(tb.x, 0.0), t_hi = min(tb.y, t1);
    if (pc.box_lo.w > 0.5 && !(t_lo < t_hi)) return L;
    if (pc.grid_dims.w == 0u) {
        for (uint s = 0u; s < pc.count; ++s) {
            iters++;
            add_sample(pc.first + s, x, d, t1, constant, st, n_coeff, env, L, cover);
        }
        return L;
    }
    // The index: the segment clipped to this chunk's box (a sample's ball lies inside it, and a
    // segment outside every ball gets under exp(-14) from it), then a 3D DDA (Amanatides and
    // Woo) over the grid's cells. A sample is counted in the cell whose stretch [t_in, t_out)
    // of the segment holds clamp(t_c, 0, t1), its closest point on the segment: the stretches
    // partition the segment, so each sample once; a sample whose closest point lies outside the
    // box lies outside its own ball there, and is skipped as the cut above would.
    ivec3 dims = ivec3(pc.grid_dims.xyz);
    float cell = pc.grid.w;
    vec3 p0 = (x + d * t_lo - pc.grid.xyz) / cell;
    ivec3 c = clamp(ivec3(floor(p0)), ivec3(0), dims - 1);
    ivec3 stp = ivec3(sign(d));
    // Parameter t at which the ray crosses the next cell boundary on each axis, and per cell.
    vec3 t_next, t_delta;
    for (int a = 0; a < 3; ++a) {
        if (stp[a] == 0) {
            t_next[a] = INF;
            t_delta[a] = INF;
        } else {
            float boundary = pc.grid[a] + cell * float(c[a] + (stp[a] > 0 ? 1 : 0));
            t_next[a] = (boundary - x[a]) / d[a];
            t_delta[a] = cell / abs(d[a]);
        }
    }
    uint last = pc.first + pc.count;
    float t_in = t_lo;
    while (true) {
        iters++;
        float t_out = min(min(min(t_next.x, t_next.y), t_next.z), t_hi);
        bool final_cell = t_out >= t_hi;
        uint k = uint(c.x) + uint(dims.x) * (uint(c.y) + uint(dims.y) * uint(c.z));
        for (uint e = starts[k]; e < starts[k + 1u]; ++e) {
            iters++;
            uint i = items[e];
            if (i < pc.first) continue;
            if (i >= last) break;
            float tc = dot(samples[SAMPLE_WORDS * i].xyz - x, d);
            float ts = clamp(tc, 0.0, t1);
            if (ts < t_in || (final_cell ? ts > t_hi : ts >= t_out)) continue;
            add_sample(i, x, d, t1, constant, st, n_coeff, env, L, cover);
        }
        if (final_cell) break;
        // Step to the neighbour across the nearest boundary; leaving the grid ends the walk.
        int a = t_next.x <= t_next.y ? (t_next.x <= t_next.z ? 0 : 2) : (t_next.y <= t_next.z ? 1 : 2);
        c[a] += stp[a];
        if (c[a] < 0 || c[a] >= dims[a]) break;
        t_in = t_out;
        t_next[a] += t_delta[a];
    }
    return L;
}

// Surface events of the camera ray's chain before it is cut (a refracting object's internal
// reflections end sooner, when their weight falls below 1e-4, as the view march's).
const uint MAX_EVENTS = 32u;

// The medium's emission along an inside segment [0, t1] from x toward the camera (material
// mat), as the view march adds it: steps of at most pc.step (one for a constant density and
// Le, whose step rule is then exact), each adding T (1 - albedo) (1 - e^{-sigma_t dt}) Le at its
// midpoint, so a thick step never emits more than Le. Emitted light the medium scatters is not
// single scattering of a light, and is left out.
vec3 segment_emission(vec3 x, vec3 d, float t1, uint mat) {
    medium_mat = mat;
    vec3 st = scene.materials[mat].sigma_t.xyz;
    vec3 k = vec3(1.0) - scene.materials[mat].albedo.xyz;
    bool uniform_le = DENSITY_KIND == DENSITY_CONSTANT && (EMISSION == EMISSION_CONSTANT || scene.materials[mat].emission.w == 0.0);
    uint n = uniform_le ? 1u : max(1u, uint(ceil(t1 / pc.step)));
    float dt = t1 / float(n);
    vec3 T = vec3(1.0), L = vec3(0.0);
    for (uint i = 0u; i < n; ++i) {
        iters++;
        vec3 p = x + d * ((float(i) + 0.5) * dt);
        vec3 tau = st * density_at(p) * dt;
        vec3 seg_T = exp(-tau);
        L += T * k * one_minus_exp3(tau) * emission_at(p);
        T *= seg_T;
    }
    return L;
}

void main() {
    uvec2 px = gl_GlobalInvocationID.xy;
    uvec2 res = scene.image.xy;
    if (px.x >= res.x || px.y >= res.y) return;
    uint pixel = px.y * res.x + px.x;
    bool first_chunk = pc.env.w > 0.5;
    vec3 x, d;
    camera_ray(vec2(px) + 0.5, x, d);
    // The camera path's weight: (1 - F) / ior^2 at a refracting entry, each internal
    // reflection's F, each inside chord's transmittance. Index-matched surfaces (ior 1, and a
    // v1 medium's box) are crossed straight: the ray goes on to any object behind. A crossing
    // that leaves an object closes the inside segment before it, so a camera inside the medium
    // is handled too.
    // L: the surfaces' own terms (the environment reflected and seen through); scat, cover and
    // exact: the samples' in-scattering, their coverage and the exact integral of the camera's
    // attenuation, over every inside segment, each times the camera path's weight there.
    vec3 w = vec3(1.0);
    vec3 L = vec3(0.0), scat = vec3(0.0), cover = vec3(0.0), exact = vec3(0.0);
    for (uint e = 0u; e < MAX_EVENTS; ++e) {
        iters++;
        float t;
        uint tri;
        if (!mesh_hit_tri(x, d, 0.0, INF, t, tri)) {
            if (first_chunk) L += w * pc.env.rgb;   // escapes: the environment behind
            break;
        }
        vec3 n = triangle_normal(tri);
        bool entering = dot(d, n) < 0.0;
        vec3 nf = entering ? n : -n;
        uint mat = triangle_material(tri);
        if (!entering) {
            vec3 tau, cv, ex;
            // The segment's own emission (once: with the surfaces' terms of the first chunk).
            if (EMISSION != EMISSION_NONE && first_chunk) L += w * segment_emission(x, d, t, mat);
            scat += w * segment_light(x, d, t, mat, tau, cv, ex);
            cover += w * cv;
            exact += w * ex;
            w *= exp(-tau);
        }
        vec3 p = x + d * t;
        float ior = scene.materials[mat].ior.x;
        if (!(REFRACTIVE && ior != 1.0)) {
            x = p - nf * surface_eps(p);   // straight through
            continue;
        }
        float n2 = ior * ior, eta = 1.0, cos_i = 1.0, cos_t = 1.0;
        float F = surface_fresnel(d, nf, entering, ior, eta, cos_i, cos_t);
        if (entering) {
            // The environment reflected at the entry; radiance refracted in, times 1 / ior^2.
            if (first_chunk) L += w * F * pc.env.rgb;
            w *= (1.0 - F) / n2;
            d = refract_dir(d, nf, eta, cos_i, cos_t);
            x = p - nf * surface_eps(p);
        } else {
            // Leaving: the environment seen through (radiance back to the vacuum's: times
            // ior^2); the reflected share goes on inside.
            if (first_chunk) L += w * (1.0 - F) * n2 * pc.env.rgb;
            w *= F;
            if (max3(w) * n2 < 1e-4) break;
            d = reflect(d, nf);
            x = p + nf * surface_eps(p);
        }
    }
    // Per pixel: [4 p] the surfaces' terms, [4 p + 1] the in-scattering, [4 p + 2] the
    // coverage, [4 p + 3] the exact integral; the host adds the in-scattering divided by the
    // coverage relative to the exact integral (src/solvers/sh_single.rs, `resolve`).
    if (first_chunk) {
        radiance[4u * pixel] = vec4(L, 1.0);
        radiance[4u * pixel + 1u] = vec4(scat, 0.0);
        radiance[4u * pixel + 2u] = vec4(cover, 0.0);
        radiance[4u * pixel + 3u] = vec4(exact, 0.0);
    } else {
        radiance[4u * pixel + 1u] += vec4(scat, 0.0);
        radiance[4u * pixel + 2u] += vec4(cover, 0.0);
    }
    atomicMax(stats[0], iters);
}
