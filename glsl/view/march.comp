#version 460
// view/march: the view pass shared by solvers (solvers/view.rs): the direct (single-scattering)
// term by camera-ray marching (thesis 1.3.6 and 2.5), plus, when a solver supplies one, the
// multiply scattered in-scattering from its volume. Along the camera ray, in steps of at most
// `step` (scene units):
//   L = T(0, t_far) L_env
//     + sum_steps T(0, t_i) albedo (1 - exp(-sigma_t dt)) sum_lights p(cos) L_i T_shadow
// i.e. the single-scattering integral of eq. 1.24 with the extinction held constant within a
// step (so a thick step never scatters more than it extinguishes: energy is not created), the
// exact phase function, and shadow transmittance marched toward each light with the same
// rule. Where a step can be thicker than 0.2 mean free paths, single scattering takes the
// shadow depth at both ends of the step and integrates its exponential exactly against the
// camera's (step_transmittance): a step can be many mean free paths thick. The environment's
// in-scattering is a fixed spherical Fibonacci quadrature of `env_dirs` directions. Deterministic: no random numbers unless `jitter` is set.
// Resumable (budget.glsl): the state of a pixel's march (subsample, step, light unit and the
// partial sums) lives in a buffer; each dispatch does one shadow march per loop iteration
// until its budget is spent, and the host re-dispatches until every pixel is done.
//
// Octaves (solver `octaves`, OCTAVES > 1): the production multiple-scattering approximation
// of Wrenninge, Kulla, Lundqvist ("Oz: the Great and Volumetric", SIGGRAPH 2013 talk;
// Hillaire 2016, Frostbite course): p(cos) T_shadow becomes
//   sum_{i < N} b^i p(cos; g c^i) T_shadow^(a^i),   T^(a^i) = exp(-a^i tau_light),
// octave 0 being exact single scattering. With OCTAVES = 1 (every other solver) the code is
// the single-scattering term unchanged.
//
// An emissive medium (EMISSION) adds its emission along the camera ray by the step rule below:
// the zero-scattering term. The light it emits and the medium scatters comes from the
// solver's volume where it has one (lbl, dom, networks), and is left out where it has none
// (single, octaves).
#extension GL_GOOGLE_include_directive : require

#define SCENE_BINDING 0
#define DENSITY_BINDING 1
#define MAJORANT_BINDING 2
#define EMISSION_BINDING 15
#include "../include/scene.glsl"
#include "../include/rng.glsl"
#include "../include/phase.glsl"
#include "../include/budget.glsl"
#include "../include/view.glsl"
#include "../include/one_minus_exp.glsl"
// The [[object]]'s mesh (scene format v2; `single` only, HAS_MESH false for every other
// solver): bindings after the view pass's own.
#define MESH_NODES_BINDING 8
#define MESH_TRIS_BINDING 9
#include "../include/mesh.glsl"

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

// Octaves of the multiple-scattering approximation (1: single scattering alone), at most 8.
layout(constant_id = 8) const uint OCTAVES = 1u;

layout(std430, binding = 3) buffer Radiance { vec4 radiance[]; };
// [0] pixels whose value was not finite (zeroed, reported), [2] most own-counted loop
// iterations in one invocation, [3 + slot] unfinished invocations.
layout(std430, binding = 4) buffer Stats { uint stats[]; };

struct MarchState {
    vec4 T_k;      // transmittance to the current step, subsample index k (uint bits)
    vec4 L_i;      // radiance of the current subsample ray so far, step index i (uint bits)
    vec4 S_j;      // in-scattering sum of the current step, light unit j (uint bits)
    vec4 sum;      // sum over finished subsamples
    // With a mesh (HAS_MESH), the camera ray's current straight segment (below, "the chain"):
    vec4 seg_o;    // its origin; w: where the medium starts along it (a)
    vec4 seg_d;    // its unit direction; w: the medium's length along it (len)
    vec4 seg_x;    // x: t of the surface that ends it; y: that triangle, z: surface events,
                   // w: phase (uint bits: CHAIN_CAMERA, CHAIN_INSIDE, CHAIN_OUTSIDE) and, from
                   // bit 4, the material of the object the chain is in (seg_mat)
};
layout(std430, binding = 5) buffer State { MarchState state[]; };
// The multiply scattered energy per voxel ([c * V + v]) of a solver's volume (`lbl`'s lattice,
// `wavefront`'s gathered field); the fluence is that over lambda^2 (thesis 4.6.2). With
// ms_flux = 1 the vector irradiance E lambda^2 follows at [C V + (3 c + a) V + v] for C
// channels (the two-term expansion). Unused (ms_dims.x = 0) for single scattering alone.
layout(std430, binding = 6) readonly buffer MsVolume { float ms_energy[]; };
// The shadow volume (view/shadow.comp; pc.shadow_dims.x = 0: none, march every shadow ray):
// per light unit j the density integral toward the light ([S j V + v]) and, for the bounded
// octaves (S = pc.shadow_dims.w = 2), away from it ([(2 j + 1) V + v]) at the density grid's
// voxel centres.
layout(std430, binding = 7) readonly buffer ShadowDepth { float sdepth[]; };

layout(push_constant) uniform Push {
    float step;          // camera-ray step, scene units
    float shadow_step;   // shadow-ray step, scene units
    uint env_dirs;       // quadrature directions for environment in-scattering
    uint jitter;         // 1: jitter the step origin per subsample ray (noise instead of banding)
    uint seed_lo;
    uint seed_hi;
    uint supersample;    // n x n pixel subsamples (box filter)
    uint budget;         // own-counted loop iterations per invocation per dispatch
    uint slot;           // which unfinished-counter this dispatch reports into
    uint ms_flux;        // 1: the volume carries the vector irradiance after the fluence (two-term); 2: a lattice's (HG lobe)
    uint ms_only;        // 1: this run adds the volume's light alone (no direct light, no background): a later slab
    uint ms_forward;     // F > 0: lbl's forward field follows at F C V (ms_inscatter); 0: none
    uvec4 ms_dims;       // volume voxels xyz (x = 0: no multiple-scattering volume), w = channels
    vec4 ms_origin;      // volume min corner, w = lambda (voxel edge)
    vec4 octave;         // octaves: attenuation a, contribution b, eccentricity c, w = 1: bounded
    uvec4 shadow_dims;   // shadow volume voxels xyz (the density grid's; x = 0: none), w = depths per unit
    uvec4 ms_window;     // the volume's layers held (x first, y count) and counted here (z first, w end)
} pc;

// Multiply scattered radiance scattered at p toward the camera (travelling along -d), per
// unit sigma_s, from the volume: the isotropic part fluence / (4 pi), with fluence = energy /
// lambda^2 (thesis 4.6.2), trilinear between voxel centres; with a flux volume also the
// phase-weighted first moment of the two-term expansion L = phi / 4pi + 3 E.w / 4pi
// (wavefront paper, end of section 2.1): integrated against Henyey-Greenstein it gives
// phi / 4pi + 3 g E.(-d) / 4pi, clamped at 0. With ms_flux = 2 (a lattice's flux, `lbl`) the
// field is instead taken as a Henyey-Greenstein lobe about E^ of mean cosine
// k = min(1, |E| |E^|_1 / phi) (a lattice carries a flow along E^ on its axial links, where
// |E| / phi is at most 1 / |E^|_1), and HG(g) scattering of an HG(k) field is phi HG(g k)
// exactly (Legendre coefficients g^l k^l): non-negative, and right for a collimated field
// (90-degree scattering of a g = 0.9 beam is 13x weaker than isotropic, which the two-term
// expansion cannot express).
// Trilinear interpolation of buffer array `buf` from element `base` on a grid of n voxels, at
// the corners i0, i1 with weights f of grid_corners. A macro: GLSL cannot pass a buffer, and
// both volumes (the solver's and the shadow volume) read this way.
#define GRID_AT(buf, base, n, ix, iy, iz) buf[(base) + uint((ix) + (n).x * ((iy) + (n).y * (iz)))]
#define TRILINEAR(buf, base, n, i0, i1, f)                                                             \
    mix(mix(mix(GRID_AT(buf, base, n, i0.x, i0.y, i0.z), GRID_AT(buf, base, n, i1.x, i0.y, i0.z), f.x),  \
            mix(GRID_AT(buf, base, n, i0.x, i1.y, i0.z), GRID_AT(buf, base, n, i1.x, i1.y, i0.z), f.x), f.y), \
        mix(mix(GRID_AT(buf, base, n, i0.x, i0.y, i1.z), GRID_AT(buf, base, n, i1.x, i0.y, i1.z), f.x),  \
            mix(GRID_AT(buf, base, n, i0.x, i1.y, i1.z), GRID_AT(buf, base, n, i1.x, i1.y, i1.z), f.x), f.y), f.z)

float ms_trilinear(uint base, ivec3 n, ivec3 i0, ivec3 i1, vec3 f) { return TRILINEAR(ms_energy, base, n, i0, i1, f); }

// Out of core (dom), the volume comes in slabs of whole layers, one view run each: a run holds
// layers ms_window.x .. + ms_window.y and counts the samples whose layer is in [ms_window.z,
// ms_window.w) (the held layers reach one beyond, for the trilinear corners), so each sample is
// counted in exactly one run; the whole grid is one window.
// g: the Henyey-Greenstein asymmetry of the medium at p (its material's).
vec3 ms_inscatter(vec3 p, vec3 d, float g_p) {
    if (pc.ms_dims.x == 0u) return vec3(0.0);
    ivec3 n = ivec3(pc.ms_dims.xyz);
    vec3 g = (p - pc.ms_origin.xyz) / pc.ms_origin.w;
    int layer = clamp(int(floor(g.z)), 0, n.z - 1);
    if (layer < int(pc.ms_window.z) || layer >= int(pc.ms_window.w)) return vec3(0.0);
    uint V = pc.ms_dims.x * pc.ms_dims.y * pc.ms_window.y;
    uint C = pc.ms_dims.w;
    ivec3 i0, i1;
    vec3 f;
    grid_corners(g - 0.5, n, i0, i1, f);
    // (the held layers from index 0; the grid's own dims clamp the corners)
    i0.z -= int(pc.ms_window.x);
    i1.z -= int(pc.ms_window.x);
    vec3 e = vec3(0.0);
    for (uint c = 0u; c < C; ++c) {
        iters++;
        e[c] = ms_trilinear(c * V, n, i0, i1, f);
        if (pc.ms_flux != 0u && ANISOTROPIC) {
            vec3 flux = vec3(ms_trilinear(C * V + (3u * c) * V, n, i0, i1, f),
                             ms_trilinear(C * V + (3u * c + 1u) * V, n, i0, i1, f),
                             ms_trilinear(C * V + (3u * c + 2u) * V, n, i0, i1, f));
            if (pc.ms_flux == 2u) {
                float fl = length(flux);
                if (fl > 0.0 && e[c] > 0.0) {
                    vec3 fh = flux / fl;
                    float k = min(1.0, fl * (abs(fh.x) + abs(fh.y) + abs(fh.z)) / e[c]);
                    e[c] *= 4.0 * PI * hg_eval(g_p * k, dot(fh, -d));
                }
            } else {
                e[c] = max(0.0, e[c] + 3.0 * g_p * dot(flux, -d));
            }
        }
        if (pc.ms_forward != 0u) {
            // lbl's forward population (lbl.inject=forward, glsl/marching/march.comp): the part
            // g of once-scattered light that the split HG(g) ~ (1 - g) isotropic + g forward
            // sends on along its beam, its fluence at [F C V + c V] and flux (fluence times
            // the beam's direction) at [(F + 1) C V + (3 c + a) V], F = pc.ms_forward. The
            // isotropic share went into the lattice, whose field the lines above scatter. Of
            // the once-scattered light itself the angular distribution is HG(g) about the
            // beam, and scattering it by HG(g) gives HG(g^2) (Legendre coefficients multiply):
            // the forward part scatters toward the camera what HG(g^2) gives less the
            // isotropic share already counted, [4 pi HG(g^2, mu) - (1 - g)] / g per unit
            // fluence, clamped at 0 (it is the full once-scattered lobe's remainder, and
            // 1 + 3 g mu, the two-term expansion, as g -> 0). mu: the beam's direction against
            // the way to the camera. Where several beams cross (an environment's raymaps), the
            // field is taken as an HG lobe of mean cosine k = |E| / phi about their mean
            // direction E^ (k = 1 for one beam), which HG(g^2) scattering makes HG(k g^2):
            // isotropic where beams from every side cancel (k -> 0), where HG(g^2) about the
            // mean direction drew each of the 14 raymaps' directions as a blotch.
            float q = ms_trilinear(pc.ms_forward * C * V + c * V, n, i0, i1, f);
            if (q > 0.0) {
                uint fb = (pc.ms_forward + 1u) * C * V + 3u * c * V;
                vec3 qf = vec3(ms_trilinear(fb, n, i0, i1, f), ms_trilinear(fb + V, n, i0, i1, f),
                               ms_trilinear(fb + 2u * V, n, i0, i1, f));
                float ql = length(qf);
                float mu = ql > 0.0 ? dot(qf / ql, -d) : 0.0;
                float k = min(1.0, ql / q);
                float share = 1.0;   // an isotropic medium here: the isotropic share
                if (g_p > 1e-3) share = max(0.0, (4.0 * PI * hg_eval(g_p * g_p * k, mu) - (1.0 - g_p)) / g_p);
                e[c] += q * share;
            }
        }
    }
    if (C == 1u) e = vec3(e.x);
    return e * (INV_4PI / (pc.ms_origin.w * pc.ms_origin.w));
}

float phase_eval(float g, float c) { return ANISOTROPIC ? hg_eval(g, c) : INV_4PI; }

// The material of the object the camera ray's chain is in (scene.materials; 0 outside, and in
// a scene of one material). Declared here for optical_depth; kept with the chain's state.
uint seg_mat = 0u;

// Optical depth (per channel) from p along w over [0, t_far] at extinction scale sigma_t, by
// the same piecewise-constant rule; exact for constant and sphere media where the chord is
// integrated analytically.
vec3 box_depth_of(vec3 sigma_t, vec3 p, vec3 w, float t_far) {
    if (DENSITY_KIND != DENSITY_GRID) {
        vec2 iv = medium_interval(p, w);
        float a = max(iv.x, 0.0);
        float b = min(iv.y, t_far);
        return a < b ? sigma_t * (b - a) : vec3(0.0);
    }
    return sigma_t * density_depth(p, w, t_far, pc.shadow_step);
}

vec3 box_depth(vec3 p, vec3 w, float t_far) { return box_depth_of(scene.materials[0].sigma_t.xyz, p, w, t_far); }

// Surface crossings a shadow ray follows through the mesh before it is taken as blocked.
const uint MAX_CROSSINGS = 16u;
// Depth standing for no transmittance at all (total internal reflection toward the light):
// exp(-80) is 2e-35, and it keeps step_transmittance's differences finite.
const float OPAQUE_DEPTH = 80.0;

// With a mesh: the medium is inside it, so a shadow ray from p (inside) toward the light
// gathers the optical depth of its inside intervals only, chaining each surface it crosses
// on the same ray (t_min = the last crossing, so the surface just crossed is not found
// again). The thesis' single scattering (3.1.1, eq. 3.2, L_t = F_t L_i) takes the light's
// path as straight inside and scales it by the Fresnel transmittance 1 - F where it crosses
// the boundary; radiance entering a denser medium is also scaled by (n_t / n_i)^2 (Veach 1997,
// 5.2), so light reaching p from outside gains ior^2, which the camera's exit divides out
// again. The Fresnel and index factors are returned as part of the depth (-ln of their
// product), so the thick-step fit (step_transmittance) weighs them as it weighs the depth.
// With objects of several materials, each inside interval takes the extinction of the object
// it crosses and each surface its object's index: the triangle that ends an inside interval is
// its object's (objects are disjoint and do not nest).
vec3 optical_depth(vec3 p, vec3 w, float t_far) {
    if (!HAS_MESH) return box_depth(p, w, t_far);
    vec3 tau = vec3(0.0);
    float factor = 1.0;
    bool inside = true;
    float t = 0.0;
    for (uint e = 0u; e < MAX_CROSSINGS; ++e) {
        iters++;
        float th;
        uint tri;
        bool hit = mesh_hit_tri(p, w, t, t_far, th, tri);
        float te = hit ? th : t_far;
        // The interval's object: p's (the chain's, seg_mat) up to the first surface, else the
        // one whose surface ends it.
        uint mat = e == 0u || !hit ? seg_mat : triangle_material(tri);
        medium_mat = mat;   // its density field (the callers set medium_mat again before reading it)
        if (inside) tau += box_depth_of(scene.materials[mat].sigma_t.xyz, p + w * t, w, te - t);
        if (!hit) return tau - vec3(log(max(factor, 1e-30)));
        if (REFRACTIVE) {
            float ior = scene.materials[triangle_material(tri)].ior.x;
            float cos_t;
            float F = fresnel_dielectric(abs(dot(w, triangle_normal(tri))), inside ? ior : 1.0 / ior, cos_t);
            if (F >= 1.0) return vec3(OPAQUE_DEPTH);
            // The light crosses this surface toward p: into the object where the ray leaves it.
            factor *= (1.0 - F) * (inside ? ior * ior : 1.0 / (ior * ior));
        }
        inside = !inside;
        t = th;
    }
    return vec3(OPAQUE_DEPTH);
}

// The optical depth from p toward a light (side 0, along w up to `dist`) or away from it (side
// 1, to the medium's end), marched: the marched shadows' (pc.shadow_dims.x = 0). The shadow
// volume's units read their depths in volume_units.
vec3 unit_depth(uint side, vec3 p, vec3 w, float dist) {
    return optical_depth(p, side == 0u ? w : -w, side == 0u ? dist : INF);
}

// Light units per step: one per point or directional light, env_dirs per environment.
uint unit_count() {
    uint u = 0u;
    for (uint i = 0u; i < scene.image.z; ++i) {
        iters++;
        u += is_environment(uint(scene.lights[i].pos_kind.w)) ? pc.env_dirs : 1u;
    }
    return u;
}

// Mean of 1 / |x(t) - l|^2 over the camera-ray segment t in [t0, t1] (x(t) = o + d t): the
// point light's 1/r^2 integrated exactly over the step instead of sampled at its midpoint,
// whose error is unbounded for a step passing near the light (light inside the medium).
// With h the light's distance from the line and tc its projection:
//   int dt / (h^2 + (t - tc)^2) = (atan((t1 - tc) / h) - atan((t0 - tc) / h)) / h.
float mean_inv_r2(vec3 o, vec3 d, float t0, float t1, vec3 l) {
    vec3 ol = l - o;
    float tc = dot(ol, d);
    float h = sqrt(max(dot(ol, ol) - tc * tc, 0.0));
    // A light exactly on the ray: the integral diverges; a floor at 1e-4 of the segment keeps
    // it finite (the true radiance is infinite there, like a point light seen through fog).
    h = max(h, 1e-4 * (t1 - t0));
    return (atan((t1 - tc) / h) - atan((t0 - tc) / h)) / (h * (t1 - t0));
}

// Sum over the environment quadrature of the phase function, times 4 pi / n: 1 for an exact
// quadrature. Dividing by it makes the quadrature conserve energy for any phase function; a
// strongly peaked HG (|g| near 1) otherwise lets one direction near the peak carry far more
// than the whole sphere does.
float env_norm_g(vec3 d, float g) {
    float s = 0.0;
    for (uint k = 0u; k < pc.env_dirs; ++k) {
        iters++;
        s += phase_eval(g, dot(d, fibonacci_dir(k, pc.env_dirs)));
    }
    return s * (4.0 * PI / float(pc.env_dirs));
}

float env_norm(vec3 d) { return env_norm_g(d, scene.materials[seg_mat].albedo.w); }

// Octaves: the phase-weighted transmittance toward a light at cosine `c` through optical
// depth `tau`, sum_{i < N} b^i p(c; g c^i) exp(-a^i tau) / n_i, where n_i is octave i's
// environment quadrature norm (`onorm`, as `norm` for single scattering; 1 for point and
// directional lights, whose phase is evaluated exactly).
//
// The published sum creates energy in optically thin media: every octave is first order in
// the optical depth like single scattering, so as tau -> 0 the sum tends to (1 + b + b^2 ...)
// times single scattering (1.875x at b = 0.5, N = 4) where true multiple scattering vanishes
// as tau^2. `bounded` (pc.octave.w = 1, the default) weights octave i also by
// (1 - exp(-albedo tau_chord))^i, with tau_chord the optical depth of the whole chord through
// p along the light's direction (toward the light and away from it): the chance that light
// crossing the medium there is scattered i more times. Deep in or behind a thick medium it is
// 1 (the published sum), in a thin medium of order (albedo tau)^i, as i + 1-fold scattering is.
vec3 octave_sum(float g, float c, vec3 tau, vec3 tau_chord, bool env, float onorm[8]) {
    vec3 s = vec3(0.0);
    float a = 1.0, b = 1.0, gi = g;
    vec3 w = vec3(1.0);
    vec3 scattered = pc.octave.w != 0.0 ? scene.materials[0].albedo.xyz * one_minus_exp3(tau_chord) : vec3(1.0);
    for (uint i = 0u; i < OCTAVES; ++i) {
        iters++;
        s += b * w * phase_eval(gi, c) * exp(-a * tau) / (env ? onorm[i] : 1.0);
        a *= pc.octave.x;
        b *= pc.octave.y;
        gi *= pc.octave.z;
        w *= scattered;
    }
    return s;
}

// Octaves: the optical depth toward the light (tau, up to `dist`) and of the whole chord
// through p along it (tau plus the depth from p away from the light), the latter only for the
// bounded form.
vec3 octave_light(float g, float c, vec3 p, vec3 wi, float dist, bool env, float onorm[8]) {
    vec3 tau = unit_depth(0u, p, wi, dist);
    vec3 chord = pc.octave.w != 0.0 ? tau + unit_depth(1u, p, wi, dist) : tau;
    return octave_sum(g, c, tau, chord, env, onorm);
}

// The environment quadrature norm of every octave's phase function (g c^i) for direction d.
void octave_norms(vec3 d, out float onorm[8]) {
    float gi = scene.materials[0].albedo.w;
    for (uint i = 0u; i < 8u; ++i) {
        onorm[i] = (i < OCTAVES && ANISOTROPIC && ENVIRONMENT) ? env_norm_g(d, gi) : 1.0;
        gi *= pc.octave.z;
    }
}

// The shadow transmittance over a step, weighted as the step weights in-scattering: with the
// depth toward the light tau0 and tau1 at the step's ends, taken linear in between (exact in a
// constant medium under a directional light), and the camera's transmittance exp(-b u) over
// the step (u in [0, 1], b = sigma_t dt),
//   int exp(-b u) exp(-tau0 - (tau1 - tau0) u) du / int exp(-b u) du
//     = (exp(-tau0) - exp(-tau1 - b)) / (b + tau1 - tau0) / f(b),  f(b) = (1 - exp(-b)) / b.
// A weighted mean of exp(-tau) over the step, so never above its larger end: no energy is
// created. The depth at the step's middle instead was 0.38x the converged single scattering on
// thick-slab.toml (4.4 mean free paths per step) and 3% low at 0.27 (docs/measurements.md).
// It costs a second shadow depth per light unit (1.25-1.8x the view pass on the sphere and the
// cloud; llvmpipe runs both sides of a branch that differs between lanes, so a per-step test
// would cost it everywhere), so the host turns it on per render (STEP_FIT) only where a step
// can be thicker than 0.2 mean free paths (src/solvers/view.rs, STEP_FIT_TAU); thinner, the
// midpoint's error is a few tenths of a percent (sphere, 0.135 per step: 0.25%; cloud, at most
// 0.16: 0.06%).
layout(constant_id = 9) const bool STEP_FIT = false;

vec3 step_transmittance(vec3 tau0, vec3 tau1, vec3 b) {
    vec3 x = b + tau1 - tau0;
    vec3 e0 = exp(-tau0);
    vec3 num;
    vec3 fb;
    for (uint c = 0u; c < 3u; ++c) {
        // exp(-tau1 - b) = exp(-tau0) exp(-x): for small |x| the quotient is one_minus_exp_over's
        // series, without the cancellation of a difference of nearly equal exponentials (6e-4 of
        // the step's transmittance where x or b was just over 1e-4: a first-order branch ended
        // there). Not for large |x|: exp(-x) overflows where the depth toward the light falls
        // steeply along the step (x < -88), and the difference itself is exact enough there.
        num[c] = abs(x[c]) < 0.1 ? e0[c] * one_minus_exp_over(x[c]) : (e0[c] - exp(-tau1[c] - b[c])) / x[c];
        fb[c] = one_minus_exp_over(b[c]);
    }
    return num / fb;
}

// The marched depth toward a light from q (point lights: toward `lpos`, each point its own
// direction; others along wi).
vec3 depth_from(bool point, vec3 lpos, vec3 q, vec3 wi) {
    if (!point) return unit_depth(0u, q, wi, INF);
    vec3 to = lpos - q;
    float dq = length(to);
    return dq > 0.0 ? unit_depth(0u, q, to / dq, dq) : vec3(0.0);
}

// Light li's unit e (its environment direction; 0 for the others) seen from p, which samples
// the step [t0, t1] of the camera ray o + d t: the direction wi toward it, its distance (INF but
// for a point light) and the unit's weight geo (the point light's mean 1/r^2 over the step, the
// environment quadrature's 4 pi / env_dirs, else 1). False for a point light at p itself (no
// direction: the unit adds nothing). unit_inscatter and volume_units share it.
bool light_unit(Light li, uint e, vec3 o, vec3 d, vec3 p, float t0, float t1, out vec3 wi, out float dist,
                out float geo) {
    uint kind = uint(li.pos_kind.w);
    wi = vec3(0.0);
    dist = INF;
    geo = 1.0;
    if (kind == LIGHT_POINT) {
        vec3 to = li.pos_kind.xyz - p;
        float dist2 = dot(to, to);
        if (dist2 <= 0.0) return false;
        dist = sqrt(dist2);
        wi = to / dist;
        geo = mean_inv_r2(o, d, t0, t1, li.pos_kind.xyz);
    } else if (kind == LIGHT_DIRECTIONAL) {
        wi = -li.pos_kind.xyz;
    } else {
        wi = fibonacci_dir(e, pc.env_dirs);
        geo = 4.0 * PI / float(pc.env_dirs);
    }
    return true;
}

// In-scattering toward -d at p per unit sigma_s from light unit j: p(cos) L_i T, for the step
// [t0, t1] of the camera ray o + d t that p samples, whose extinction is b = sigma_t dt; the
// shadow marched (with a shadow volume, volume_units sums the step's units instead).
vec3 unit_inscatter(vec3 o, vec3 d, vec3 p, float t0, float t1, vec3 b, uint j, float norm, float onorm[8]) {
    float g = scene.materials[seg_mat].albedo.w;
    for (uint i = 0u; i < scene.image.z; ++i) {
        iters++;
        Light li = scene.lights[i];
        uint kind = uint(li.pos_kind.w);
        uint n = is_environment(kind) ? pc.env_dirs : 1u;
        if (j >= n) { j -= n; continue; }
        vec3 wi;
        float dist, geo;
        bool env = is_environment(kind);
        if (!light_unit(li, j, o, d, p, t0, t1, wi, dist, geo)) return vec3(0.0);
        // Octaves: each octave's environment quadrature is normalised by its own phase sum.
        if (OCTAVES > 1u) return octave_light(g, dot(d, wi), p, wi, dist, env, onorm) * li.value.rgb * geo;
        vec3 t;
        if (STEP_FIT) {
            bool point = kind == LIGHT_POINT;
            // With a mesh the last step ends on the surface, where a shadow ray along a face (a
            // box lit along an axis) meets its edges and the inside/outside count breaks (9% too
            // bright on a side-lit box pair, tests/material_tests.rs): the ends are taken a
            // rounding distance inside the step.
            float e = HAS_MESH && t1 - t0 > 8.0 * surface_eps(p) ? 2.0 * surface_eps(p) : 0.0;
            t = step_transmittance(depth_from(point, li.pos_kind.xyz, o + d * (t0 + e), wi),
                                   depth_from(point, li.pos_kind.xyz, o + d * (t1 - e), wi), b);
        } else {
            t = exp(-unit_depth(0u, p, wi, dist));
        }
        return phase_eval(g, dot(d, wi)) * li.value.rgb * geo * t / (env ? norm : 1.0);
    }
    return vec3(0.0);
}

// One unit's optical depth toward its light from the shadow volume (its depths from `base`),
// trilinear at the corners i0, i1 with weights f: the medium's extinction times the stored
// density integral.
vec3 volume_depth(vec3 sigma_t0, uint base, ivec3 n, ivec3 i0, ivec3 i1, vec3 f) {
    return sigma_t0 * TRILINEAR(sdepth, base, n, i0, i1, f);
}

// The shadow volume's light units of one step, from unit j on while the loop budget lasts
// (pc.shadow_dims.x != 0): unit_inscatter's terms, summed into S in the same order, with what
// the step's units share taken once. The volume is read at the density grid's voxel centres
// whatever a unit's direction, so every unit of a step reads the same eight corners (at p, or
// at the step's two ends for the step fit); the extinction, g and each light are read once a
// step, not once a unit. On llvmpipe every storage-buffer read is a loop over the SIMD lanes
// (docs/lavapipe.md), and the per-unit reads of the scene block and the walk over the lights
// to find the unit's were most of the pass (the cloud's `single` at 256^2: 8.7 s, 4.9 s
// without them).
void volume_units(vec3 o, vec3 d, vec3 p, float t0, float t1, vec3 b, uint units, inout uint j, inout vec3 S,
                  float norm, float onorm[8]) {
    float g = scene.materials[seg_mat].albedo.w;
    vec3 sigma_t0 = scene.materials[0].sigma_t.xyz;
    ivec3 n = ivec3(pc.shadow_dims.xyz);
    uint V = pc.shadow_dims.x * pc.shadow_dims.y * pc.shadow_dims.z;
    bool fit = STEP_FIT && OCTAVES <= 1u;
    // The corners at p (the midpoint rule and the octaves), or at the step's two ends (the
    // step fit: unit_inscatter's ends, a rounding distance inside the step with a mesh).
    ivec3 i0, i1, k0, k1;
    vec3 f, fk;
    float e = HAS_MESH && t1 - t0 > 8.0 * surface_eps(p) ? 2.0 * surface_eps(p) : 0.0;
    vec3 qa = o + d * (t0 + e), qb = o + d * (t1 - e);
    grid_corners(box_voxel_coord(fit ? qa : p, n), n, i0, i1, f);
    if (fit) grid_corners(box_voxel_coord(qb, n), n, k0, k1, fk);
    // The walk to unit j's light starts at light 0 on every call, and its iterations count, so
    // the budget is checked only before a unit, and the call's first unit always runs: a call
    // that could run none would be repeated forever (the cloud with 6 lights at single.budget 16
    // did not end: the walk and the march's own loops used up the budget before a later light's
    // unit).
    bool first = true;
    uint u0 = 0u;   // the first unit of light i
    for (uint i = 0u; i < scene.image.z && j < units; ++i) {
        iters++;
        Light li = scene.lights[i];
        uint kind = uint(li.pos_kind.w);
        bool env = is_environment(kind);
        uint count = env ? pc.env_dirs : 1u;
        for (; j < u0 + count && (first || iters < pc.budget); ++j) {
            first = false;
            iters++;
            uint base = pc.shadow_dims.w * j * V;
            vec3 wi;
            float dist, geo;
            if (!light_unit(li, j - u0, o, d, p, t0, t1, wi, dist, geo)) continue;
            if (OCTAVES > 1u) {
                vec3 tau = volume_depth(sigma_t0, base, n, i0, i1, f);
                vec3 chord = pc.octave.w != 0.0 ? tau + volume_depth(sigma_t0, base + V, n, i0, i1, f) : tau;
                S += octave_sum(g, dot(d, wi), tau, chord, env, onorm) * li.value.rgb * geo;
                continue;
            }
            vec3 t;
            if (fit) {
                // depth_from: a point light at the end itself is no depth away.
                bool at_a = kind == LIGHT_POINT && !(length(li.pos_kind.xyz - qa) > 0.0);
                bool at_b = kind == LIGHT_POINT && !(length(li.pos_kind.xyz - qb) > 0.0);
                t = step_transmittance(at_a ? vec3(0.0) : volume_depth(sigma_t0, base, n, i0, i1, f),
                                       at_b ? vec3(0.0) : volume_depth(sigma_t0, base, n, k0, k1, fk), b);
            } else {
                t = exp(-volume_depth(sigma_t0, base, n, i0, i1, f));
            }
            S += phase_eval(g, dot(d, wi)) * li.value.rgb * geo * t / (env ? norm : 1.0);
        }
        if (j < u0 + count) return;   // the budget ran out within light i
        u0 += count;
    }
}

// The camera ray's chain through the [[object]]'s mesh (HAS_MESH; `single`): straight
// segments between surface events. The medium is inside the object; outside it there is
// vacuum. The segment (its origin, direction, the surface that ends it) is kept in the state,
// since a BVH traversal per camera step would cost more than the step.
const uint CHAIN_CAMERA = 0u;    // the subsample's camera ray is not traced yet
const uint CHAIN_INSIDE = 1u;    // a segment inside the object, marched step by step
const uint CHAIN_OUTSIDE = 2u;   // a segment outside it, to the next surface or escape
// A chain whose throughput (as it would leave the object) falls below this ends: at most
// this share of the environment's radiance is lost from the pixel.
const float CHAIN_CUTOFF = 1e-4;
// Surface events of one camera ray's chain before it is cut (its light lost). Total internal
// reflection keeps the whole throughput, and a faceted sphere traps rays near its rim by it
// for more than 64 reflections (measured: an empty icosphere lost up to 84% of a rim pixel at
// 64); a medium inside ends such chains at CHAIN_CUTOFF long before this (checked at every
// reflection inside, total ones included: without that check at total internal reflection the
// trapped rays of a thick medium marched up to MAX_EVENTS segments that added nothing, and the
// glass sphere of tests/single_refraction_tests.rs took 2088 dispatches instead of 60).
const uint MAX_EVENTS = 4096u;
vec3 seg_o = vec3(0.0), seg_d = vec3(0.0);
float seg_a = 0.0, seg_len = 0.0, seg_tend = 0.0;
uint seg_tri = 0u, seg_events = 0u, seg_phase = CHAIN_CAMERA;

// The current segment: from o along d to the surface (triangle tri) at t_end (INF: none).
void chain_set(vec3 o, vec3 d, float t_end, uint tri, bool inside) {
    seg_o = o;
    seg_d = d;
    seg_tend = t_end;
    seg_tri = tri;
    seg_phase = inside ? CHAIN_INSIDE : CHAIN_OUTSIDE;
}

// Start a segment from o along d, inside or outside the object: the surface that ends it
// (INF: none) and, inside, the part of it in the medium's box.
void chain_segment(vec3 o, vec3 d, bool inside) {
    float th;
    uint tri;
    bool hit = mesh_hit_tri(o, d, 0.0, INF, th, tri);
    // A ray inside a closed mesh must meet it; one that slips through where triangles share an
    // edge or vertex (Moller-Trumbore is not watertight, and rays in a symmetric mesh's planes
    // of symmetry meet edges exactly) is tried again a little to the side, twice. (On the
    // empty icosphere the retries did not recover the rim pixels such rays darkened;
    // chain_event's escape for a ray that still finds no surface did.)
    if (inside && !hit) {
        vec3 side = normalize(cross(d, abs(d.x) < 0.9 ? vec3(1.0, 0.0, 0.0) : vec3(0.0, 1.0, 0.0)));
        for (uint r = 0u; !hit && r < 2u; ++r) {
            iters++;
            o += (r == 0u ? side : cross(d, side)) * 64.0 * surface_eps(o);
            hit = mesh_hit_tri(o, d, 0.0, INF, th, tri);
        }
    }
    chain_set(o, d, hit ? th : INF, tri, inside);
    seg_a = 0.0;
    seg_len = 0.0;
    if (inside && hit) {
        medium_mat = seg_mat;
        vec2 iv = medium_interval(o, d);
        seg_a = max(iv.x, 0.0);
        seg_len = max(min(iv.y, th) - seg_a, 0.0);
    }
}

// The event at the current segment's end. False when the chain is done (what it saw of the
// environment added to L). Index-matched (ior 1): the ray crosses unchanged. Refractive: at a
// smooth dielectric (Fresnel F, Snell; dielectric.glsl) the ray splits; one branch goes on,
// the other is added where it escapes to the environment:
// - entering: the reflected share F sees the environment if the reflected ray escapes; the
//   refracted share goes on inside,
//   throughput x (1 - F) (n_i / n_t)^2: radiance seen across a surface from the less dense
//   side is compressed by (n_i / n_t)^2 (Veach 1997, 5.2; path's surface_event), and light
//   entering it from outside gains the inverse (optical_depth), so the two cancel for the
//   environment;
// - leaving: total internal reflection goes on at weight 1; otherwise the refracted share
//   (1 - F) (n_i / n_t)^2 sees the environment if it escapes, and the internal reflection F
//   goes on (every internal reflection of a convex object is kept).
// Where neither branch escapes (a non-convex mesh, or grazing on a faceted one) the heavier
// goes on and the other's light is dropped.
// The thesis' camera ray refracts once and goes straight inside (3.1.1); these branches add
// what a convex object reflects internally toward the camera.
bool chain_event(inout vec3 T, inout vec3 L, vec3 env) {
    bool inside = seg_phase == CHAIN_INSIDE;
    if (seg_tend == INF) {
        // Nothing ahead: escaped. Inside, a closed mesh must be met; where it is not (seen
        // after tens of grazing internal reflections on a faceted mesh: the ray slipped through
        // an edge, or rounding put it outside while the chain counts it inside) it is outside
        // now, and is taken to have left unrefracted, with the exit's (n_i / n_t)^2 and no
        // Fresnel loss. Dropping it instead lost up to 70% of a few rim pixels of the empty
        // icosphere.
        float n_in = scene.materials[seg_mat].ior.x;
        L += T * (inside && REFRACTIVE ? n_in * n_in : 1.0) * env;
        return false;
    }
    seg_events++;
    if (seg_events > MAX_EVENTS) return false;
    vec3 d = seg_d;
    vec3 q = seg_o + d * seg_tend;
    vec3 n = triangle_normal(seg_tri);
    float eps = surface_eps(q);
    bool entering = dot(d, n) < 0.0;
    vec3 nf = entering ? n : -n;   // facing the side the ray comes from
    // A chain that crosses into an object takes on its material (the triangle's).
    if (entering) seg_mat = triangle_material(seg_tri);
    if (!REFRACTIVE) {
        chain_segment(q - nf * eps, d, entering);
        return true;
    }
    float ior = scene.materials[triangle_material(seg_tri)].ior.x;
    float eta, cos_i, cos_t;
    float F = surface_fresnel(d, nf, entering, ior, eta, cos_i, cos_t);
    vec3 r = normalize(reflect(d, nf));
    vec3 o_r = q + nf * eps;
    vec3 o_t = q - nf * eps;
    if (F >= 1.0) {
        // Total internal reflection (only from inside) keeps the throughput, so the medium alone
        // brings it under the cutoff: checked here too, or a ray trapped near a faceted rim
        // marches its whole chain of reflections (up to MAX_EVENTS) through a thick medium that
        // let nothing through after the first.
        if (max3(T) * ior * ior < CHAIN_CUTOFF) return false;
        chain_segment(o_r, r, true);
        return true;
    }
    vec3 t = refract_dir(d, nf, eta, cos_i, cos_t);
    float w_t = (1.0 - F) * eta * eta;
    float th;
    uint tri;
    if (entering) {
        if (!mesh_hit_tri(o_r, r, 0.0, INF, th, tri)) {
            L += T * F * env;
        } else if (F > 0.5) {
            // Both branches meet the mesh again (grazing on a faceted or non-convex surface):
            // the heavier one goes on, the other is dropped.
            T *= F;
            chain_set(o_r, r, th, tri, false);
            return true;
        }
        T *= w_t;
        chain_segment(o_t, t, true);
        return true;
    }
    if (mesh_hit_tri(o_t, t, 0.0, INF, th, tri)) {
        // The refracted ray meets the mesh again (non-convex): the heavier branch goes on.
        if (F > 0.5) {
            T *= F;
            if (max3(T) * ior * ior < CHAIN_CUTOFF) return false;
            chain_segment(o_r, r, true);
            return true;
        }
        T *= w_t;
        chain_set(o_t, t, th, tri, false);
        return true;
    }
    L += T * w_t * env;
    T *= F;
    // Inside, T holds the 1 / ior^2 of the entry: what leaves is T ior^2.
    if (max3(T) * ior * ior < CHAIN_CUTOFF) return false;
    chain_segment(o_r, r, true);
    return true;
}

void main() {
    uvec2 px = gl_GlobalInvocationID.xy;
    uvec2 res = scene.image.xy;
    if (px.x >= res.x || px.y >= res.y) return;
    uint pixel = px.y * res.x + px.x;
    MarchState st = state[pixel];
    vec3 T = st.T_k.xyz;
    uint k = floatBitsToUint(st.T_k.w);
    vec3 L = st.L_i.xyz;
    uint i = floatBitsToUint(st.L_i.w);
    vec3 S = st.S_j.xyz;
    uint j = floatBitsToUint(st.S_j.w);
    vec3 sum = st.sum.xyz;
    float norm = st.sum.w;   // env_norm of the current subsample ray; 0 until computed
    uint ss = max(pc.supersample, 1u);
    uint total = ss * ss;
    // Octaves' environment quadrature norms of the current subsample ray, recomputed once per
    // ray and per dispatch (not kept in the state).
    float onorm[8] = float[8](1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0);
    uint onorm_k = 0xffffffffu;

    vec3 env = vec3(0.0);
    for (uint l = 0u; l < scene.image.z; ++l) {
        iters++;
        if (is_environment(uint(scene.lights[l].pos_kind.w))) env += scene.lights[l].value.rgb;
    }
    // Light units per step; none when nothing scatters (a pure absorber or an empty object needs
    // no shadow rays).
    bool scatters = false;
    for (uint m = 0u; m < uint(MAX_MATERIALS); ++m)
        scatters = scatters || (max3(scene.materials[m].albedo.xyz) > 0.0 && scene.materials[m].sigma_t.w > 0.0);
    uint units = scatters && pc.ms_only == 0u ? unit_count() : 0u;
    if (pc.ms_only != 0u) env = vec3(0.0);

    if (HAS_MESH) {
        seg_o = st.seg_o.xyz;
        seg_a = st.seg_o.w;
        seg_d = st.seg_d.xyz;
        seg_len = st.seg_d.w;
        seg_tend = st.seg_x.x;
        seg_tri = floatBitsToUint(st.seg_x.y);
        seg_events = floatBitsToUint(st.seg_x.z);
        seg_phase = floatBitsToUint(st.seg_x.w) & 15u;
        seg_mat = floatBitsToUint(st.seg_x.w) >> 4u;
    }

    while (iters < pc.budget && k < total) {
        iters++;
        // The subsample ray k, recomputed on every step: cheaper than storing it.
        vec2 sub = (vec2(float(k % ss), float(k / ss)) + 0.5) / float(ss);
        vec3 o, d;
        uvec2 rng = rng_init(pc.seed_lo, pc.seed_hi, pixel, k);
        float offset = pc.jitter != 0u ? rnd(rng) : 0.5;
        float a, len;
        bool done = false;
        if (HAS_MESH) {
            // One traversal or surface event per loop iteration; steps of an inside segment as
            // below.
            if (seg_phase == CHAIN_CAMERA) {
                camera_ray(vec2(px) + sub, o, d);
                seg_events = 0u;
                seg_mat = 0u;
                chain_segment(o, d, false);
                continue;
            }
            if (seg_phase == CHAIN_OUTSIDE) {
                done = !chain_event(T, L, env);
                norm = 0.0;
            }
            o = seg_o;
            d = seg_d;
            a = seg_a;
            len = seg_len;
        } else {
            camera_ray(vec2(px) + sub, o, d);
            vec2 iv = medium_interval(o, d);
            a = max(iv.x, 0.0);
            len = iv.y - a;
        }
        uint n = len > 0.0 ? max(1u, uint(ceil(len / pc.step))) : 0u;
        if (HAS_MESH && !done && seg_phase == CHAIN_INSIDE && i >= n) {
            // The inside segment is marched: its surface event, then the next segment.
            done = !chain_event(T, L, env);
            norm = 0.0;
            i = 0u;
            j = 0u;
            S = vec3(0.0);
            if (!done) continue;
        }
        if (HAS_MESH && !done && seg_phase != CHAIN_INSIDE) continue;
        if (done || (!HAS_MESH && i >= n)) {
            // Ray done: what passed through the medium, plus what it scattered toward the camera
            // (with a mesh, the chain's events added what it saw of the environment).
            sum += HAS_MESH ? L : L + T * env;
            norm = 0.0;
            k++; i = 0u; j = 0u;
            T = vec3(1.0); L = vec3(0.0); S = vec3(0.0);
            seg_phase = CHAIN_CAMERA;
            continue;
        }
        float dt = len / float(n);
        vec3 p = o + d * (a + (float(i) + offset) * dt);
        if (j < units) {
            // Only an environment unit divides by it (unit_inscatter): without one it is never computed.
            if (ENVIRONMENT && norm == 0.0) norm = env_norm(d);
            if (OCTAVES > 1u && onorm_k != k) {
                octave_norms(d, onorm);
                onorm_k = k;
            }
            float t0 = a + float(i) * dt;
            // The step's extinction, which only the thick-step fit weighs.
            medium_mat = seg_mat;
            vec3 b = STEP_FIT ? scene.materials[seg_mat].sigma_t.xyz * density_at(p) * dt : vec3(0.0);
            if (pc.shadow_dims.x == 0u) {
                // Marched shadows: one unit per loop iteration, so a dispatch can stop after any.
                S += unit_inscatter(o, d, p, t0, t0 + dt, b, j, norm, onorm);
                j++;
                continue;
            }
            // Shadow volume: a unit is a few reads, so every unit of the step in this iteration
            // (the per-iteration ray setup above had come to dominate), same order, same sum.
            // Within the budget: a large environment quadrature resumes where it stopped.
            volume_units(o, d, p, t0, t0 + dt, b, units, j, S, norm, onorm);
            if (j < units) continue;
        }
        // Close the step: integral over it of T(s) sigma_s ds with sigma_t held constant is
        // albedo (1 - e^{-sigma_t dt}), so a thick step never scatters more than it extinguishes.
        medium_mat = seg_mat;   // shadow rays' optical depths move it through other objects
        vec3 st_ = scene.materials[seg_mat].sigma_t.xyz * density_at(p);
        vec3 seg_T = exp(-st_ * dt);
        vec3 seg_ext = one_minus_exp3(st_ * dt);
        L += T * scene.materials[seg_mat].albedo.xyz * seg_ext * (S + ms_inscatter(p, d, scene.materials[seg_mat].albedo.w));
        // The medium's emission along the step, by the same rule: the integral of T(s) sigma_a
        // Le ds with sigma_t and Le held at the step's point is (1 - albedo) (1 - e^{-sigma_t
        // dt}) Le, so a thick step never emits more than Le (its equilibrium). Once per ray: a
        // later slab of an out-of-core volume (ms_only) adds its volume's light alone.
        if (EMISSION != EMISSION_NONE && pc.ms_only == 0u)
            L += T * (vec3(1.0) - scene.materials[seg_mat].albedo.xyz) * seg_ext * emission_at(p);
        T *= seg_T;
        S = vec3(0.0);
        j = 0u;
        i++;
    }
    state[pixel] = MarchState(vec4(T, uintBitsToFloat(k)), vec4(L, uintBitsToFloat(i)), vec4(S, uintBitsToFloat(j)), vec4(sum, norm),
                              vec4(seg_o, seg_a), vec4(seg_d, seg_len),
                              vec4(seg_tend, uintBitsToFloat(seg_tri), uintBitsToFloat(seg_events), uintBitsToFloat(seg_phase | (seg_mat << 4u))));
    if (k >= total) {
        vec3 Lp = sum / float(total);
        // Never let a NaN/Inf leave the pass; count it so the host reports it.
        if (any(isnan(Lp)) || any(isinf(Lp))) { Lp = vec3(0.0); atomicAdd(stats[0], 1u); }
        radiance[pixel] = vec4(Lp, 1.0);
    }
    atomicMax(stats[2], iters);
    if (k < total) atomicAdd(stats[3u + pc.slot], 1u);
}
