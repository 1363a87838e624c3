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
#extension GL_GOOGLE_include_directive : require

#define SCENE_BINDING 0
#define DENSITY_BINDING 1
#define MAJORANT_BINDING 2
#include "../include/scene.glsl"
#include "../include/rng.glsl"
#include "../include/phase.glsl"
#include "../include/budget.glsl"
#include "../include/view.glsl"

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
    uint pad2;
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
vec3 ms_inscatter(vec3 p, vec3 d) {
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
                    e[c] *= 4.0 * PI * hg_eval(scene.albedo.w * k, dot(fh, -d));
                }
            } else {
                e[c] = max(0.0, e[c] + 3.0 * scene.albedo.w * dot(flux, -d));
            }
        }
    }
    if (C == 1u) e = vec3(e.x);
    return e * (INV_4PI / (pc.ms_origin.w * pc.ms_origin.w));
}

float phase_eval(float g, float c) { return ANISOTROPIC ? hg_eval(g, c) : INV_4PI; }

// Optical depth (per channel) from p along w over [0, t_far], by the same piecewise-constant
// rule; exact for constant and sphere media where the chord is integrated analytically.
vec3 optical_depth(vec3 p, vec3 w, float t_far) {
    if (DENSITY_KIND != DENSITY_GRID) {
        vec2 iv = medium_interval(p, w);
        float a = max(iv.x, 0.0);
        float b = min(iv.y, t_far);
        return a < b ? scene.sigma_t.xyz * (b - a) : vec3(0.0);
    }
    return scene.sigma_t.xyz * density_depth(p, w, t_far, pc.shadow_step);
}

// The optical depth from p toward light unit `unit` (side 0, up to `dist`) or away from it
// (side 1, to the medium's end): from the shadow volume, trilinear between voxel centres
// (clamped at the outer half voxel, as the density), or marched where there is none.
vec3 unit_depth(uint unit, uint side, vec3 p, vec3 w, float dist) {
    if (pc.shadow_dims.x == 0u) return optical_depth(p, side == 0u ? w : -w, side == 0u ? dist : INF);
    ivec3 n = ivec3(pc.shadow_dims.xyz);
    uint V = pc.shadow_dims.x * pc.shadow_dims.y * pc.shadow_dims.z;
    uint base = (pc.shadow_dims.w * unit + side) * V;
    ivec3 i0, i1;
    vec3 f;
    grid_corners(box_voxel_coord(p, n), n, i0, i1, f);
    iters++;
    return scene.sigma_t.xyz * TRILINEAR(sdepth, base, n, i0, i1, f);
}

// Light units per step: one per point or directional light, env_dirs per environment.
uint unit_count() {
    uint u = 0u;
    for (uint i = 0u; i < scene.image.z; ++i) {
        iters++;
        u += uint(scene.lights[i].pos_kind.w) == LIGHT_ENVIRONMENT ? pc.env_dirs : 1u;
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

float env_norm(vec3 d) { return env_norm_g(d, scene.albedo.w); }

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
    vec3 scattered = pc.octave.w != 0.0 ? scene.albedo.xyz * (vec3(1.0) - exp(-tau_chord)) : vec3(1.0);
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
vec3 octave_light(uint unit, float g, float c, vec3 p, vec3 wi, float dist, bool env, float onorm[8]) {
    vec3 tau = unit_depth(unit, 0u, p, wi, dist);
    vec3 chord = pc.octave.w != 0.0 ? tau + unit_depth(unit, 1u, p, wi, dist) : tau;
    return octave_sum(g, c, tau, chord, env, onorm);
}

// The environment quadrature norm of every octave's phase function (g c^i) for direction d.
void octave_norms(vec3 d, out float onorm[8]) {
    float gi = scene.albedo.w;
    for (uint i = 0u; i < 8u; ++i) {
        onorm[i] = (i < OCTAVES && ANISOTROPIC) ? env_norm_g(d, gi) : 1.0;
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
        num[c] = abs(x[c]) < 1e-4 ? e0[c] * (1.0 - 0.5 * x[c]) : (e0[c] - exp(-tau1[c] - b[c])) / x[c];
        fb[c] = b[c] < 1e-4 ? 1.0 - 0.5 * b[c] : (1.0 - exp(-b[c])) / b[c];
    }
    return num / fb;
}

// The depth toward light unit `unit` from q (point lights: toward `lpos`, each point its own
// direction; others along wi).
vec3 depth_from(uint unit, bool point, vec3 lpos, vec3 q, vec3 wi) {
    if (!point) return unit_depth(unit, 0u, q, wi, INF);
    vec3 to = lpos - q;
    float dq = length(to);
    return dq > 0.0 ? unit_depth(unit, 0u, q, to / dq, dq) : vec3(0.0);
}

// In-scattering toward -d at p per unit sigma_s from light unit j: p(cos) L_i T, for the step
// [t0, t1] of the camera ray o + d t that p samples, whose extinction is b = sigma_t dt.
vec3 unit_inscatter(vec3 o, vec3 d, vec3 p, float t0, float t1, vec3 b, uint j, float norm, float onorm[8]) {
    float g = scene.albedo.w;
    uint unit = j;
    for (uint i = 0u; i < scene.image.z; ++i) {
        iters++;
        Light li = scene.lights[i];
        uint kind = uint(li.pos_kind.w);
        uint n = kind == LIGHT_ENVIRONMENT ? pc.env_dirs : 1u;
        if (j >= n) { j -= n; continue; }
        vec3 wi;
        float dist = INF;
        float geo = 1.0;   // the point light's mean 1/r^2 over the step, the quadrature weight
        bool env = kind == LIGHT_ENVIRONMENT;
        if (kind == LIGHT_POINT) {
            vec3 to = li.pos_kind.xyz - p;
            float dist2 = dot(to, to);
            if (dist2 <= 0.0) return vec3(0.0);
            dist = sqrt(dist2);
            wi = to / dist;
            geo = mean_inv_r2(o, d, t0, t1, li.pos_kind.xyz);
        } else if (kind == LIGHT_DIRECTIONAL) {
            wi = -li.pos_kind.xyz;
        } else {
            wi = fibonacci_dir(j, pc.env_dirs);
            geo = 4.0 * PI / float(pc.env_dirs);
        }
        // Octaves: each octave's environment quadrature is normalised by its own phase sum.
        if (OCTAVES > 1u) return octave_light(unit, g, dot(d, wi), p, wi, dist, env, onorm) * li.value.rgb * geo;
        vec3 t;
        if (STEP_FIT) {
            bool point = kind == LIGHT_POINT;
            t = step_transmittance(depth_from(unit, point, li.pos_kind.xyz, o + d * t0, wi),
                                   depth_from(unit, point, li.pos_kind.xyz, o + d * t1, wi), b);
        } else {
            t = exp(-unit_depth(unit, 0u, p, wi, dist));
        }
        return phase_eval(g, dot(d, wi)) * li.value.rgb * geo * t / (env ? norm : 1.0);
    }
    return vec3(0.0);
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
        if (uint(scene.lights[l].pos_kind.w) == LIGHT_ENVIRONMENT) env += scene.lights[l].value.rgb;
    }
    // Light units per step; none when nothing scatters (a pure absorber needs no shadow rays).
    uint units = max3(scene.albedo.xyz) > 0.0 && pc.ms_only == 0u ? unit_count() : 0u;
    if (pc.ms_only != 0u) env = vec3(0.0);

    while (iters < pc.budget && k < total) {
        iters++;
        // The subsample ray k, recomputed on every step: cheaper than storing it.
        vec2 sub = (vec2(float(k % ss), float(k / ss)) + 0.5) / float(ss);
        vec3 o, d;
        camera_ray(vec2(px) + sub, o, d);
        uvec2 rng = rng_init(pc.seed_lo, pc.seed_hi, pixel, k);
        float offset = pc.jitter != 0u ? rnd(rng) : 0.5;
        vec2 iv = medium_interval(o, d);
        float a = max(iv.x, 0.0);
        float len = iv.y - a;
        uint n = len > 0.0 ? max(1u, uint(ceil(len / pc.step))) : 0u;
        if (i >= n) {
            // Ray done: what passed through the medium, plus what it scattered toward the camera.
            sum += L + T * env;
            norm = 0.0;
            k++; i = 0u; j = 0u;
            T = vec3(1.0); L = vec3(0.0); S = vec3(0.0);
            continue;
        }
        float dt = len / float(n);
        vec3 p = o + d * (a + (float(i) + offset) * dt);
        if (j < units) {
            if (norm == 0.0) norm = env_norm(d);
            if (OCTAVES > 1u && onorm_k != k) {
                octave_norms(d, onorm);
                onorm_k = k;
            }
            float t0 = a + float(i) * dt;
            // The step's extinction, which only the thick-step fit weighs.
            vec3 b = STEP_FIT ? scene.sigma_t.xyz * density_at(p) * dt : vec3(0.0);
            if (pc.shadow_dims.x == 0u) {
                // Marched shadows: one unit per loop iteration, so a dispatch can stop after any.
                S += unit_inscatter(o, d, p, t0, t0 + dt, b, j, norm, onorm);
                j++;
                continue;
            }
            // Shadow volume: a unit is a few reads, so every unit of the step in this iteration
            // (the per-iteration ray setup above had come to dominate), same order, same sum.
            // Within the budget: a large environment quadrature resumes where it stopped.
            for (; j < units && iters < pc.budget; ++j) S += unit_inscatter(o, d, p, t0, t0 + dt, b, j, norm, onorm);
            if (j < units) continue;
        }
        // Close the step: integral over it of T(s) sigma_s ds with sigma_t held constant is
        // albedo (1 - e^{-sigma_t dt}), so a thick step never scatters more than it extinguishes.
        vec3 st_ = scene.sigma_t.xyz * density_at(p);
        vec3 seg_T = exp(-st_ * dt);
        L += T * scene.albedo.xyz * (vec3(1.0) - seg_T) * (S + ms_inscatter(p, d));
        T *= seg_T;
        S = vec3(0.0);
        j = 0u;
        i++;
    }
    state[pixel] = MarchState(vec4(T, uintBitsToFloat(k)), vec4(L, uintBitsToFloat(i)), vec4(S, uintBitsToFloat(j)), vec4(sum, norm));
    if (k >= total) {
        vec3 Lp = sum / float(total);
        // Never let a NaN/Inf leave the pass; count it so the host reports it.
        if (any(isnan(Lp)) || any(isinf(Lp))) { Lp = vec3(0.0); atomicAdd(stats[0], 1u); }
        radiance[pixel] = vec4(Lp, 1.0);
    }
    atomicMax(stats[2], iters);
    if (k < total) atomicAdd(stats[3u + pc.slot], 1u);
}
