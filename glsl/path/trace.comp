#version 460
// path/trace: the ground truth. A volumetric path tracer with delta tracking against a
// majorant (analytic for constant/sphere media, a coarse majorant grid for grids), next-event
// estimation toward every light (shadow transmittance by ratio tracking; in closed form in
// constant media), a uniformly sampled (importance-sampled for a constant environment)
// environment combined with phase sampling by MIS, HG sampling,
// and unbiased Russian roulette. Chromatic media use spectral tracking (Kutz et al. 2017,
// "Spectral and decomposition tracking", sec. 5) with absorption folded into the weights,
// so no channel is shortcut. One invocation = one pixel. The kernel is resumable (budget.glsl):
// each dispatch advances the pixel's current path until its loop budget is spent, pausing
// inside an event where need be (within a free flight, a transmittance or a loop over the
// lights: one free flight through optical thickness 1e7 can take 1e7 tentative collisions),
// then saves the path state with the event's progress; the host re-dispatches until every pixel has
// finished samples [sample_begin, sample_end). Every finished sample adds to the pixel's sum of L
// and its sum of squared deviations (add_samples; mean and variance of the mean on the host),
// always in sample order: deterministic.
// An emissive medium (EMISSION) adds beta sigma_a Le / sigma_maj at every tentative collision of
// a free flight (tracking.glsl trk_emitted; pbrt-v4's estimator), unbiased, with or without a
// mesh around it.
// Point lights (with pc.equiangular) are also sampled by equiangular sampling along every
// ray segment (Kulla & Fajardo 2012, "Importance sampling techniques for path tracing in
// participating media"), combined with next-event estimation from the distance-sampled
// scattering point by MIS: see eq_* and advance().
// With an [[object]] (scene format v2, HAS_MESH) the medium lies inside a closed mesh and
// outside is vacuum: a path flies to the mesh's surface (BVH, mesh.glsl) and crosses it, or,
// where the boundary refracts (REFRACTIVE), meets a smooth dielectric there: reflection with
// the Fresnel probability, else refraction by Snell's law, total internal reflection
// included (surface_event). Both choices have weight 1; refraction scales the throughput by
// eta^2 (radiance compression, transport of radiance as pbrt-v4 and Mitsuba 3 do).
#extension GL_GOOGLE_include_directive : require
#extension GL_KHR_shader_subgroup_basic : require

// On llvmpipe the kernel counts its SIMD batches' loop back-edges as the driver's loop limiter
// does and pauses the batch before the limit (glsl/include/batch.glsl): a batch's lanes run
// different loops, and their sum, not one lane's count, is what the limiter ends.
#define SCATTERLAB_BATCH_LOOPS
#define SCATTERLAB_BATCH_PAUSE 64
#ifndef SCATTERLAB_LOOP_COUNTS   // tools/glsl-loop-counts reads the weights by name
#include "trace.loops.glsl"
#endif

#define SCENE_BINDING 0
#define DENSITY_BINDING 1
#define MAJORANT_BINDING 2
#define MESH_NODES_BINDING 6
#define MESH_TRIS_BINDING 7
#define EMISSION_BINDING 15
#include "../include/scene.glsl"
#include "../include/rng.glsl"
#include "../include/phase.glsl"
#include "../include/budget.glsl"
#include "../include/mesh.glsl"
#include "../include/tracking.glsl"

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

// Per pixel: sum of L (xyz) and sample count (w), then the sum of squared deviations from the
// mean, M2 (xyz).
layout(std430, binding = 3) buffer Accum { vec4 accum[]; };
// [0] paths truncated by the collision cap, [1] tracking steps (wraps; a throughput figure),
// [2] most own-counted loop iterations in one invocation (see budget.glsl),
// [3 + slot] invocations with work left after the dispatch of that slot.
layout(std430, binding = 4) buffer Stats { uint stats[]; };

struct PathState {
    vec4 o_pdf;        // ray origin, phase pdf of the ray direction (0 for a camera ray)
    vec4 d_depth;      // ray direction, scattering events so far (uint bits)
    vec4 beta_key;     // throughput, rng stream key (uint bits)
    vec4 L_coll;       // radiance gathered so far, tentative collisions so far (uint bits)
    uvec4 k_flight;    // next sample index, flags (FLAG_*, and the event's progress), ev_s (float bits), rng counter
    vec4 ev_v;         // the event's vector ev_v, unused
    vec4 trk_a;        // the paused tracking loop (tracking.glsl, track_save)
    vec4 trk_b;
    vec4 trk_c;
    vec4 trk_mesh;     // x, w: a paused tracker's chained interval (tracking.glsl, track_save_mesh); y, z: ev_t_surf, ev_surf_tri
};
// The flags word: bit 0 a path is in flight, 1 it was truncated, 2 a tracking loop paused,
// 3 ev_eq_on, 4-6 ev_step, 7 inside the mesh, 8-11 ev_sub, 12-15 path_mat (the material of the
// object the path is in), 16-31 ev_light (the host refuses 2^16 lights or more).
const uint FLAG_IN_FLIGHT = 1u;
const uint FLAG_TRUNCATED = 2u;
const uint FLAG_TRACKING = 4u;
const uint FLAG_EQ_ON = 8u;
const uint FLAG_INSIDE = 128u;   // bit 7: the ray starts inside the [[object]]'s mesh
layout(std430, binding = 5) buffer State { PathState state[]; };
// The facet lists of manifold next-event estimation (src/solvers/mnee.rs): a grid over the
// medium's bounds per light outside the refractive mesh; each cell lists, in facet order, the
// facets whose refracted beam meets it.
layout(std430, binding = 8) readonly buffer MneeCells { uint mnee_cells[]; };

// The range [begin, end) of mnee_cells holding the facets light i may reach x through.
void mnee_range(uint i, vec3 x, out uint begin, out uint end) {
    uint table = mnee_cells[8u + i];
    begin = 0u;
    end = 0u;
    if (table == 0u) return;
    vec3 lo = vec3(uintBitsToFloat(mnee_cells[0]), uintBitsToFloat(mnee_cells[1]), uintBitsToFloat(mnee_cells[2]));
    vec3 hi = vec3(uintBitsToFloat(mnee_cells[3]), uintBitsToFloat(mnee_cells[4]), uintBitsToFloat(mnee_cells[5]));
    uint n = mnee_cells[6];
    ivec3 c = clamp(ivec3(floor((x - lo) / (hi - lo) * float(n))), ivec3(0), ivec3(int(n) - 1));
    uint cell = uint(c.x) + n * (uint(c.y) + n * uint(c.z));
    uint list = table + n * n * n + 1u;
    begin = list + mnee_cells[table + cell];
    end = list + mnee_cells[table + cell + 1u];
}

layout(push_constant) uniform Push {
    uint sample_end;      // finish samples [.., sample_end) of every pixel
    uint budget;          // own-counted loop iterations per invocation per dispatch
    uint seed_lo;
    uint seed_hi;
    uint max_depth;       // scattering events; 1 = single scattering; 0xffffffff = unbounded
    uint collision_cap;   // safety cap on tentative collisions per path (reported, not silent)
    uint slot;            // which active counter this dispatch reports into
    uint light_traced;    // bit i: light i is rendered by light paths (path/light); camera paths skip it
    uint rr_depth;        // Russian roulette from this many scattering events on
    float rr_threshold;   // ... for throughput below this (survival max(beta) / threshold)
    uint sample_begin;    // the first sample index of every pixel (render.first_sample, --samples A..B)
    uint equiangular;     // bit i: point light i also sampled by equiangular sampling + MIS
    uint mnee;            // bit i: light i is outside the refractive mesh: reached by manifold NEE
    float env_r;          // what a camera ray that misses the medium sees: the environment
    float env_g;          // lights' radiance summed in scene order by the host (a loop over
    float env_b;          // every light here could not pause within the budget on llvmpipe)
} pc;

// What the scene needs, set by the host (src/solvers/path.rs, `trace_spec`): code for a feature
// the scene lacks is not compiled in (the defaults model everything). MNEE: some light is
// reached through specular chains; EQUIANGULAR: some point light is also sampled by
// equiangular sampling; ENVIRONMENT: the scene has an environment light.
layout(constant_id = 14) const bool MNEE = true;
layout(constant_id = 15) const bool EQUIANGULAR = true;
layout(constant_id = 16) const bool ENVIRONMENT = true;

// Whether light i (point or directional, outside every refractive object) reaches scattering
// points inside through their surfaces only: manifold next-event estimation through every
// specular chain that holds (mnee_estimate; the chains listed by src/solvers/mnee.rs).
bool mnee_light(uint i) { return MNEE && REFRACTIVE && i < 32u && ((pc.mnee >> i) & 1u) != 0u; }
// Whether chain light i lies inside an object: its own medium also sees it straight.
bool mnee_light_inside(uint i) { return i < 32u && (mnee_cells[40u + i] & 1u) != 0u; }

// Whether camera paths estimate light i (a light-traced light is left wholly to path/light,
// a partition of the image's paths by light, so the two kernels' sums add without MIS).
bool camera_side(uint i) { return i >= 32u || (pc.light_traced & (1u << i)) == 0u; }

// Equiangular sampling (Kulla & Fajardo 2012, sec. 4.1) of a point light at c along the ray
// o + t d, t in [t_in, t_out]: t is drawn with pdf proportional to 1/r^2 (r = |x(t) - c|),
// i.e. uniformly in the angle subtended at the light. Geometry per (ray, light):
// delta = dot(c - o, d) (foot of the perpendicular), D = distance of c from the ray's line,
// theta_a/b = atan((t_in/out - delta) / D); pdf(t) = D / ((theta_b - theta_a)(D^2 + (t - delta)^2)).
// `ok` is false when the interval is empty or D is too small for the angles to be computed
// reliably (light on the ray's line): then there is no equiangular sample for this ray and
// its pdf is 0 everywhere, a deterministic function of the ray, so the MIS weights below stay
// consistent (distance sampling then carries weight 1).
struct Equiangular { float delta; float D; float th_a; float th_b; bool ok; };

Equiangular eq_setup(vec3 o, vec3 d, float t_in, float t_out, vec3 c) {
    Equiangular e;
    vec3 oc = c - o;
    e.delta = dot(oc, d);
    e.D = length(oc - e.delta * d);
    e.th_a = 0.0; e.th_b = 0.0;
    e.ok = t_in < t_out && t_out < INF && e.D > 1e-5 * max(1.0, length(oc));
    if (e.ok) {
        e.th_a = atan((t_in - e.delta) / e.D);
        e.th_b = atan((t_out - e.delta) / e.D);
        e.ok = e.th_b > e.th_a;
    }
    return e;
}

float eq_pdf(Equiangular e, float t) {
    if (!e.ok) return 0.0;
    float x = t - e.delta;
    return e.D / ((e.th_b - e.th_a) * (e.D * e.D + x * x));
}

// MIS weight of the equiangular strategy at distance t on the ray (power heuristic). Both
// strategies estimate the same integral over t of T(o, x) sigma_s(x) f(x) with f the light's
// contribution at x: equiangular directly, distance (delta/spectral) tracking through the
// scattering point it samples. Any pair of weights w_eq(t) + w_d(t) = 1 that is a
// deterministic function of (ray, t) keeps the sum unbiased, each estimator estimating its
// weighted share exactly (Veach 1997). So the distance pdf used here needs only to be a good
// proxy, not the true tracking pdf (which depends on the whole path through a heterogeneous
// medium and on the chromatic tracking history): p_d(t) = s exp(-s (t - t_in)) with
// s = sigma_maj-scale (grey) times the density at x. It is evaluated identically for the
// equiangular sample and at the distance-sampled scattering point (w_d = 1 - w_eq).
float eq_weight(Equiangular e, vec3 o, vec3 d, float t_in, float t) {
    float pe = eq_pdf(e, t);
    if (pe <= 0.0) return 0.0;
    medium_mat = path_mat;
    float s = scene.materials[path_mat].sigma_t.w * density_at(o + d * t);
    float pd = s * exp(-s * max(0.0, t - t_in));
    if (!(pd > 0.0)) return 1.0;
    return mis_power(pe, pd);
}

// Progress of the event (advance) in flight, so that a paused event resumes where it stopped
// (the tracking loops pause when the budget is spent: tracking.glsl). Saved in the state.
const uint EV_START = 0u;    // nothing of the event done yet
const uint EV_EQ = 1u;       // equiangular sampling, at point light ev_light (sub-step ev_sub)
const uint EV_FLIGHT = 2u;   // the free flight (trk)
const uint EV_ESCAPE = 3u;   // the path escaped: environment lights from ev_light on
const uint EV_NEE = 4u;      // next-event estimation, at light ev_light (sub-step ev_sub)
uint ev_step = EV_START;
uint ev_light = 0u;
// 0: light ev_light not begun; EV_EQ: 1 camera-ray transmittance, 2 light transmittance in
// progress; EV_NEE: 1 shadow transmittance in progress.
uint ev_sub = 0u;
bool ev_eq_on = false;       // equiangular sampling is on for this event (fixed at its start)
float ev_s = 0.0;            // EV_EQ: the light's uniform u; EV_NEE: the scattering distance t_hit
vec3 ev_v = vec3(0.0);       // EV_EQ: the camera-ray transmittance; EV_NEE: the environment's direction

// Whether point light i is also sampled by equiangular sampling (the host decides per light:
// where its 1/r^2 varies strongly over the medium, path.equiangular).
bool eq_light(uint i) { return EQUIANGULAR && i < 32u && ((pc.equiangular >> i) & 1u) != 0u; }

// The equiangular estimate for every point light along the ray (o, d) over [t_in, t_out],
// added to L with throughput beta (the throughput at the ray's origin). Transmittances by
// ratio tracking, so unbiased per channel, chromatic media included. Returns false when it
// paused (resumes at ev_light, ev_sub).
bool equiangular_lights(vec3 o, vec3 d, float t_in, float t_out, vec3 beta, inout vec3 L, inout uvec2 rng) {
    uint light_count = scene.image.z;
    float g = scene.materials[path_mat].albedo.w;
    for (; ev_light < light_count; ev_light++, ev_sub = 0u) {
        BATCH_EDGE(W_EQ_LIGHTS);
        uint i = ev_light;
        if (ev_sub == 0u) {
            if (SPENT(iter_limit)) return false;
            iters++;
        }
        Light li = scene.lights[i];
        if (uint(li.pos_kind.w) != LIGHT_POINT || !camera_side(i) || !eq_light(i)) continue;
        vec3 c = li.pos_kind.xyz;
        Equiangular e = eq_setup(o, d, t_in, t_out, c);
        // Drawn for every point light, so the stream does not depend on e.ok.
        if (ev_sub == 0u) ev_s = rnd(rng);
        float u = ev_s;
        if (!e.ok) continue;
        float t = clamp(e.delta + e.D * tan(mix(e.th_a, e.th_b, u)), t_in, t_out);
        float pdf = eq_pdf(e, t);
        vec3 x = o + d * t;
        medium_mat = path_mat;   // a transmittance of the previous light may have moved it
        vec3 ss = scene.materials[path_mat].sigma_t.xyz * density_at(x) * scene.materials[path_mat].albedo.xyz;
        if (!(pdf > 0.0) || max3(ss) <= 0.0) continue;
        vec3 to = c - x;
        float dist2 = dot(to, to);
        if (dist2 <= 0.0) continue;
        float dist = sqrt(dist2);
        vec3 wi = to / dist;
        float w = eq_weight(e, o, d, t_in, t);
        if (w <= 0.0) continue;
        if (ev_sub <= 1u) {
            ev_sub = 1u;
            track_start(o, d, t, true);
            if (!transmittance_run(rng)) return false;
            ev_v = trk.T;
            if (max3(ev_v) <= 0.0) continue;
            ev_sub = 2u;
        }
        track_start(x, wi, dist, true);
        if (!transmittance_run(rng)) return false;
        vec3 Tcam = ev_v;
        vec3 Tl = trk.T;
        L += beta * Tcam * ss * phase_eval(g, dot(d, wi)) * Tl * li.value.rgb / dist2 * (w / pdf);
    }
    return true;
}

// Whether the ray (o, d) of the current event starts inside the mesh (FLAG_INSIDE), and the
// distance to its surface along it (INF: none), found at the event's start.
bool inside = false;
float ev_t_surf = INF;
uint ev_surf_tri = 0u;
// The product of the 1 / eta^2 of the path's refractions: beta * eta_scale is the throughput
// without radiance compression, what Russian roulette weighs (saved in the state's ev_v.w).
float eta_scale = 1.0;

// The path meets the mesh at o + t d (unit outward normal n): it crosses an index-matched
// boundary unchanged; a refractive one reflects with the Fresnel probability F and refracts
// with 1 - F (both at weight 1: F / F and (1 - F) / (1 - F)), total internal reflection where
// Snell's law has no solution (F = 1). A refraction from index n_i into n_t scales the throughput
// by (n_i / n_t)^2: camera paths carry importance, and radiance leaving a denser medium is
// compressed by that factor (Veach 1997, sec. 5.2; pbrt-v4 DielectricBxDF, Mitsuba 3
// dielectric in radiance mode). The new origin is moved off the surface to the side the ray
// leaves on, by a distance relative to the coordinates' magnitude (float rounding). The index
// is the object's whose triangle was hit (its material); a path that crosses into an object
// takes on its material (path_mat).
void surface_event(inout vec3 o, inout vec3 d, inout vec3 beta, inout float pdf_dir, inout uvec2 rng) {
    // The surface the event's start found (ev_t_surf, ev_surf_tri): no second traversal.
    vec3 n = triangle_normal(ev_surf_tri);
    vec3 p = o + d * ev_t_surf;
    bool entering = dot(d, n) < 0.0;
    vec3 nf = entering ? n : -n;   // facing the side the ray comes from
    bool crosses = true;
    uint mat = triangle_material(ev_surf_tri);
    if (REFRACTIVE) {
        float eta, cos_i, cos_t;
        float F = surface_fresnel(d, nf, entering, scene.materials[mat].ior.x, eta, cos_i, cos_t);
        if (rnd(rng) < F) {
            d = normalize(reflect(d, nf));
            crosses = false;
        } else {
            d = refract_dir(d, nf, eta, cos_i, cos_t);
            beta *= eta * eta;
            eta_scale /= eta * eta;
        }
        pdf_dir = -1.0;
    }
    inside = crosses ? entering : !entering;
    if (inside) path_mat = mat;
    o = p + (crosses ? -nf : nf) * surface_eps(p);
    // A path caught between surfaces (total internal reflection in a clear object) ends at the
    // collision cap, counted and reported as truncated, never loops for ever.
    collisions++;
    if (collisions > collision_cap) { truncated = true; beta = vec3(0.0); }
}

#include "../include/mnee.glsl"

// Outcomes of advance().
const int EVENT_NEXT = 0;     // the path goes on
const int EVENT_ENDED = 1;    // the path has ended
const int EVENT_PAUSED = 2;   // the budget is spent; the event resumes in the next dispatch

// One event of a path: free flight to the next scattering (next-event estimation and a new
// direction there) or to its escape. Resumable: o, d, beta, depth and pdf_dir change only
// where the event can no longer pause.
int advance(inout vec3 o, inout vec3 d, inout vec3 beta, inout vec3 L, inout uint depth, inout float pdf_dir, inout uvec2 rng) {
    uint light_count = scene.image.z;
    float g = scene.materials[path_mat].albedo.w;
    // The ray's segment in the medium, as the free flight sees it; kept for the MIS weights.
    medium_mat = path_mat;
    vec2 seg = medium_interval(o, d);
    seg.x = max(seg.x, 0.0);
    // With a mesh: the medium is inside it, so the segment ends at the next surface, and a ray
    // outside crosses vacuum to the surface (or escapes).
    // The surface is found once per event and kept in the state (ev_t_surf), not recomputed
    // when a paused event resumes: a traversal can cost more than a small budget, and an
    // event that paid it again on every resume would never progress.
    if (HAS_MESH && ev_step == EV_START) {
        if (!mesh_hit_tri(o, d, 0.0, INF, ev_t_surf, ev_surf_tri)) ev_t_surf = INF;
    }
    float t_surf = ev_t_surf;
    bool surf = HAS_MESH && t_surf < INF;
    if (HAS_MESH) {
        if (inside) seg.y = min(seg.y, t_surf);
        else seg = vec2(0.0, -1.0);
    }
    if (ev_step == EV_START) {
        // Equiangular sampling only where a scattering vertex here would be allowed
        // (depth + 1 <= max_depth), exactly where the distance-sampled NEE below happens.
        ev_eq_on = EQUIANGULAR && pc.equiangular != 0u && depth < pc.max_depth && seg.x < seg.y;
        ev_step = ev_eq_on && max3(beta) > 0.0 ? EV_EQ : EV_FLIGHT;
        ev_light = 0u;
        ev_sub = 0u;
    }
    if (EQUIANGULAR && ev_step == EV_EQ) {
        if (!equiangular_lights(o, d, seg.x, seg.y, beta, L, rng)) return EVENT_PAUSED;
        ev_step = EV_FLIGHT;
    }
    if (ev_step == EV_FLIGHT) {
        track_start_on(o, d, seg);
        float t_hit;
        int r = scatter_run(beta, rng, t_hit);
        // The medium's emission along the flight so far (also a paused flight's: L is saved
        // with the path), reaching the camera after `depth` scatterings.
        L += trk_emitted;
        trk_emitted = vec3(0.0);
        if (r == FLIGHT_PAUSED) return EVENT_PAUSED;
        ev_light = 0u;
        ev_sub = 0u;
        if (r == FLIGHT_ESCAPED) {
            if (HAS_MESH && surf && max3(beta) > 0.0 && !truncated) {
                surface_event(o, d, beta, pdf_dir, rng);
                return EVENT_NEXT;
            }
            ev_step = EV_ESCAPE;
        } else {
            depth++;
            if (depth > pc.max_depth) return EVENT_ENDED;
            ev_s = t_hit;
            ev_step = EV_NEE;
        }
    }
    if (ev_step == EV_ESCAPE) {
        if (max3(beta) > 0.0) {
            // The loop runs without an environment too: its iteration count decides where a
            // paused path resumes, and the image must not depend on ENVIRONMENT.
            for (; ev_light < light_count; ev_light++) {
                BATCH_EDGE(W_ESCAPE_LIGHTS);
                if (SPENT(iter_limit)) return EVENT_PAUSED;
                iters++;
                if (!ENVIRONMENT || uint(scene.lights[ev_light].pos_kind.w) != LIGHT_ENVIRONMENT) continue;
                // The camera ray sees the environment directly; later escapes share the
                // environment with its next-event estimate by MIS, except past a refraction or
                // reflection (pdf_dir < 0), which next-event estimation cannot reach.
                float w = depth == 0u || pdf_dir < 0.0 ? 1.0 : mis_power(pdf_dir, INV_4PI);
                L += beta * scene.lights[ev_light].value.rgb * w;
            }
        }
        return EVENT_ENDED;
    }

    // EV_NEE: next-event estimation toward every light from the scattering point, transmittance
    // by ratio tracking. The free flight's ray is still (o, d).
    float t_hit = ev_s;
    vec3 p = o + d * t_hit;
    for (; ev_light < light_count; ev_light++, ev_sub = 0u) {
        BATCH_EDGE(W_NEE_LIGHTS);
        uint i = ev_light;
        if (ev_sub == 0u) {
            if (SPENT(iter_limit)) return EVENT_PAUSED;
            iters++;
        }
        Light li = scene.lights[i];
        uint kind = uint(li.pos_kind.w);
        // A light inside an object with a refractive boundary: the straight shadow ray (ev_sub
        // 0-1), then its chains (mnee_estimate from ev_sub 0 again, on at 2 and up).
        bool chains = mnee_light(i) && kind != LIGHT_ENVIRONMENT;
        if (MNEE && chains && !mnee_light_inside(i)) {
            if (kind == LIGHT_POINT && !camera_side(i)) continue;
            if (!mnee_estimate(li, p, d, g, beta, L, rng)) return EVENT_PAUSED;
        } else if (kind == LIGHT_POINT) {
            if (!camera_side(i)) continue;
            if (ev_sub <= 1u) {
                vec3 to = li.pos_kind.xyz - p;
                float dist2 = dot(to, to);
                float dist = sqrt(dist2);
                vec3 wi = to / dist;
                // The distance-sampling share of the MIS with equiangular sampling (w_d = 1 - w_eq
                // for the same ray and t; 1 when equiangular sampling is off).
                float w = 1.0;
                if (dist2 > 0.0 && ev_eq_on && eq_light(i))
                    w = 1.0 - eq_weight(eq_setup(o, d, seg.x, seg.y, li.pos_kind.xyz), o, d, seg.x, t_hit);
                if (dist2 > 0.0 && w > 0.0) {
                    ev_sub = 1u;
                    track_start(p, wi, dist, true);
                    if (!transmittance_run(rng)) return EVENT_PAUSED;
                    vec3 T = trk.T;
                    L += beta * T * phase_eval(g, dot(d, wi)) * li.value.rgb / dist2 * w;
                }
                if (!chains) continue;
                ev_sub = 0u;
            }
            // (chains holds MNEE; the test says so where specialisation can see it: batch.glsl)
            if (MNEE) {
                if (!mnee_estimate(li, p, d, g, beta, L, rng)) return EVENT_PAUSED;
            }
        } else if (kind == LIGHT_DIRECTIONAL) {
            vec3 wi = -li.pos_kind.xyz;
            ev_sub = 1u;
            track_start(p, wi, INF, true);
            if (!transmittance_run(rng)) return EVENT_PAUSED;
            vec3 T = trk.T;
            L += beta * T * phase_eval(g, dot(d, wi)) * li.value.rgb;
        } else if (ENVIRONMENT) {
            // Uniform direction: the importance sampling of a constant environment.
            if (ev_sub == 0u) ev_v = uniform_sphere(rnd2(rng));
            vec3 wi = ev_v;
            float ph = phase_eval(g, dot(d, wi));
            ev_sub = 1u;
            track_start(p, wi, INF, true);
            if (!transmittance_run(rng)) return EVENT_PAUSED;
            vec3 T = trk.T;
            L += beta * T * ph * li.value.rgb / INV_4PI * mis_power(INV_4PI, ph);
        }
    }

    // Continue by phase sampling: the weight phase/pdf is exactly 1.
    vec3 wo = phase_sample(g, d, rnd2(rng));
    pdf_dir = phase_eval(g, dot(d, wo));
    o = p;
    d = wo;

    // Russian roulette on the throughput; dividing by the survival probability keeps it unbiased.
    if (depth >= pc.rr_depth) {
        // With a refractive mesh the throughput carries eta^2 factors that cancel when the path
        // leaves the object again; roulette on the throughput without them (pbrt-v4's
        // etaScale), else every path inside glass would be cut at 1 / eta^2 survival.
        float rr_beta = HAS_MESH ? max3(beta) * eta_scale : max3(beta);
        float q = min(1.0, rr_beta / pc.rr_threshold);
        if (rnd(rng) >= q) return EVENT_ENDED;
        beta /= q;
    }
    return EVENT_NEXT;
}

// n finished samples of radiance L each into the pixel's sums: the sum of L (n = 1 adds L
// exactly: L * 1.0 is L) and the sum of squared deviations from the mean, M2, by Chan et al.'s
// update for a group of n equal values joining n_old of mean m_old: M2 += (L - m_old)^2 n_old n
// / (n_old + n) (Welford's (L - m_old)(L - m_new) for n = 1). A sum of L^2, with the variance
// formed as S2 - n m^2 on the host, lost every digit where a pixel's samples nearly agree
// (s^2 << m^2 in f32); M2 keeps the variance's own relative precision.
void add_samples(uint pixel, vec3 L, float n) {
    vec4 s = accum[2u * pixel];
    float n_old = s.w;
    vec3 d = L - (n_old > 0.0 ? s.xyz / n_old : L);
    accum[2u * pixel] = s + vec4(L * n, n);
    accum[2u * pixel + 1u] += vec4(d * d * (n_old * n / (n_old + n)), 0.0);
}

void main() {
    BATCH_BEGIN(W_MAIN);
    uvec2 px = gl_GlobalInvocationID.xy;
    uvec2 res = scene.image.xy;
    if (px.x >= res.x || px.y >= res.y) return;
    uint pixel = px.y * res.x + px.x;
    collision_cap = pc.collision_cap;
    iter_limit = pc.budget;
    PathState st = state[pixel];
    vec3 o = st.o_pdf.xyz;
    float pdf_dir = st.o_pdf.w;
    vec3 d = st.d_depth.xyz;
    uint depth = floatBitsToUint(st.d_depth.w);
    vec3 beta = st.beta_key.xyz;
    uvec2 rng = uvec2(floatBitsToUint(st.beta_key.w), st.k_flight.w);
    vec3 L = st.L_coll.xyz;
    collisions = floatBitsToUint(st.L_coll.w);
    // A pixel not yet started holds k = 0 (the state buffer starts zeroed): it starts at the
    // range's first sample. The random numbers of sample k depend on (seed, pixel, k) only, so
    // a range A..B renders exactly the samples A..B-1 of the render 0..B.
    uint k = max(st.k_flight.x, pc.sample_begin);
    uint flags = st.k_flight.y;
    bool in_flight = (flags & FLAG_IN_FLIGHT) != 0u;
    truncated = (flags & FLAG_TRUNCATED) != 0u;
    trk_resume = (flags & FLAG_TRACKING) != 0u;
    ev_eq_on = (flags & FLAG_EQ_ON) != 0u;
    inside = (flags & FLAG_INSIDE) != 0u;
    trk_saved_mesh = st.trk_mesh;
    ev_t_surf = st.trk_mesh.y;
    ev_surf_tri = floatBitsToUint(st.trk_mesh.z);
    ev_step = (flags >> 4u) & 7u;
    ev_sub = (flags >> 8u) & 15u;
    path_mat = (flags >> 12u) & 15u;
    ev_light = flags >> 16u;
    ev_s = uintBitsToFloat(st.k_flight.z);
    ev_v = st.ev_v.xyz;
    eta_scale = HAS_MESH ? st.ev_v.w : 1.0;
    trk_saved[0] = st.trk_a;
    trk_saved[1] = st.trk_b;
    trk_saved[2] = st.trk_c;
    uint trunc_count = 0u;
    uint segs0 = collisions;
    uint segs = 0u;
    // Only a pixel between samples can be one no ray of which meets the medium.
    bool pixel_misses = !in_flight && pixel_misses_medium(px);
    vec3 env_seen = vec3(pc.env_r, pc.env_g, pc.env_b);   // what a camera ray that misses the medium sees

    while (!SPENT(pc.budget)) {
        BATCH_EDGE(W_EVENTS);
        if (!in_flight) {
            // Samples whose camera ray misses the medium see the environment and nothing else:
            // they end here, in a tight loop of their own, instead of running a whole event in
            // advance() each. Measured on llvmpipe with every pixel beside the medium: 86 ns
            // -> 38 ns per sample (Mitsuba 3: 22 ns); the homogeneous sphere, where 68% of
            // the pixels miss, 11% faster. The same samples, random numbers and sums as
            // advance() would give: bit-identical images.
            bool hits = false;
            if (pixel_misses && k < pc.sample_end) {
                // No ray through this pixel can meet the medium (a conservative test once per
                // dispatch): its remaining samples all see env_seen, added at once. The same
                // mean and variance as one at a time (the same sums exactly when env_seen is 0).
                add_samples(pixel, env_seen, float(pc.sample_end - k));
                segs += pc.sample_end - k;
                k = pc.sample_end;
            }
            while (k < pc.sample_end && !SPENT(pc.budget)) {
                BATCH_EDGE(W_MISSED_SAMPLES);
                rng = rng_init(pc.seed_lo, pc.seed_hi, pixel, k);
                vec2 jitter = rnd2(rng);   // box filter: uniform over the pixel's area
                camera_ray(vec2(px) + jitter, o, d);
                vec2 iv = scene_interval(o, d);
                if (max(iv.x, 0.0) < iv.y) { hits = true; break; }
                iters++;
                add_samples(pixel, env_seen, 1.0);
                segs += 1u;
                k++;
            }
            if (!hits) break;
            beta = vec3(1.0);
            L = vec3(0.0);
            depth = 0u;
            pdf_dir = 0.0;
            collisions = 0u;
            segs0 = 0u;
            truncated = false;
            in_flight = true;
            inside = false;   // the camera is outside the mesh (the scene loader checks its origin)
            path_mat = 0u;
            eta_scale = 1.0;
            ev_step = EV_START;
        }
        iters++;
        int r = advance(o, d, beta, L, depth, pdf_dir, rng);
        if (r == EVENT_PAUSED) break;
        ev_step = EV_START;
        bool ended = r == EVENT_ENDED || truncated;
        if (ended) {
            // Never let a NaN/Inf leave the pass; count it with the truncations so it is reported.
            if (any(isnan(L)) || any(isinf(L))) { L = vec3(0.0); truncated = true; }
            if (truncated) trunc_count++;
            add_samples(pixel, L, 1.0);
            segs += collisions - segs0 + 1u;
            segs0 = 0u;
            collisions = 0u;
            k++;
            in_flight = false;
        }
    }
    if (in_flight) segs += collisions - segs0;
    flags = (in_flight ? FLAG_IN_FLIGHT : 0u) | (truncated ? FLAG_TRUNCATED : 0u) | (trk_paused ? FLAG_TRACKING : 0u)
          | (ev_eq_on ? FLAG_EQ_ON : 0u) | (inside ? FLAG_INSIDE : 0u) | (ev_step << 4u) | (ev_sub << 8u)
          | (path_mat << 12u) | (ev_light << 16u);
    vec4 ta, tb, tc;
    track_save(ta, tb, tc);
    vec4 tm = track_save_mesh();
    tm.y = ev_t_surf;
    tm.z = uintBitsToFloat(ev_surf_tri);
    state[pixel] = PathState(vec4(o, pdf_dir), vec4(d, uintBitsToFloat(depth)), vec4(beta, uintBitsToFloat(rng.x)),
                             vec4(L, uintBitsToFloat(collisions)), uvec4(k, flags, floatBitsToUint(ev_s), rng.y),
                             vec4(ev_v, HAS_MESH ? eta_scale : 0.0), ta, tb, tc, tm);
    if (trunc_count > 0u) atomicAdd(stats[0], trunc_count);
    atomicAdd(stats[1], segs);
    atomicMax(stats[2], iters);
    if (LOOP_LIMITED) atomicMax(stats[STATS_BATCH_WORD], BATCH_COUNT);
    if (in_flight || k < pc.sample_end) atomicAdd(stats[3u + pc.slot], 1u);
}
