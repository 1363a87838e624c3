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
// finished samples [0, sample_end). Every finished sample adds L and L^2 to the pixel's sums
// (mean and variance of the mean on the host), always in sample order: deterministic.
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

#define SCENE_BINDING 0
#define DENSITY_BINDING 1
#define MAJORANT_BINDING 2
#define MESH_NODES_BINDING 6
#define MESH_TRIS_BINDING 7
#include "../include/scene.glsl"
#include "../include/rng.glsl"
#include "../include/phase.glsl"
#include "../include/budget.glsl"
#include "../include/mesh.glsl"
#include "../include/tracking.glsl"

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

// Per pixel: sum of L (xyz) and sample count (w), then sum of L^2 (xyz).
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
    uint equiangular;     // bit i: point light i also sampled by equiangular sampling + MIS
    uint mnee;            // bit i: light i is outside the refractive mesh: reached by manifold NEE
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
        uint i = ev_light;
        if (ev_sub == 0u) {
            if (iters >= iter_limit) return false;
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

// ---- Specular chains of manifold next-event estimation (src/solvers/mnee.rs) -------------
// A chain is the sequence of facets, from the light's side, at which the light's ray refracts
// or reflects on its way to a scattering point x: one refraction into the object (mesh.glsl
// facet_refraction), or longer ones (light reflected inside before it scatters, light through
// another object or another sheet of a non-convex mesh). The record at word c of mnee_cells:
// k | reflection mask << 8, then the k facets.
const uint CHAIN_MAX = 8u;
// What one chain tried counts against the budget, beyond the loops it runs (which count
// themselves): measured, a full scan (path.mnee_cells=1) counting 1 per chain reached
// llvmpipe's loop limiter at budgets 2000 and up (energy lost: 6-8%), and agreed bit for bit
// with the grid at 1000 and below.
const uint CHAIN_TRY_ITERS = 8u;
vec3 ch_p[CHAIN_MAX];            // the solved chain's vertices, from the light's side
uint ch_mat[CHAIN_MAX + 1u];     // leg l's material where it lies inside an object (leg l ends at vertex l, leg k at x)
uint ch_inside = 0u;             // bit l: leg l lies inside an object (else in vacuum)

// The ray of the light (`point`: a point light at `light`; else travelling along `light`)
// through barycentric coordinates ab of the chain's first facet, followed through its k planes
// (Snell's law or the mirror law at each, as the mask says): the last vertex q, the direction w
// after it, their derivatives with respect to ab (qa, qb, wa, wb: the ray tube, a ray
// differential propagated exactly through flat interfaces), and the product of the Fresnel
// factors (1 - F at a refraction, F at a reflection). False where a refraction meets total
// internal reflection or a plane lies behind the ray.
bool chain_trace(uint c, vec2 ab, vec3 light, bool point, bool light_in, out vec3 q, out vec3 w, out vec3 qa,
                 out vec3 qb, out vec3 wa, out vec3 wb, out float fres) {
    uint head = mnee_cells[c];
    uint k = min(head & 0xffu, CHAIN_MAX), rmask = head >> 8u;
    uint f0 = mnee_cells[c + 1u];
    vec3 e1 = tris[f0].e1.xyz, e2 = tris[f0].e2.xyz;
    q = tris[f0].v0.xyz + ab.x * e1 + ab.y * e2;
    qa = e1;
    qb = e2;
    if (point) {
        vec3 r = q - light;
        float l = length(r);
        w = r / l;
        wa = (e1 - w * dot(w, e1)) / l;
        wb = (e2 - w * dot(w, e2)) / l;
    } else {
        w = light;
        wa = vec3(0.0);
        wb = vec3(0.0);
    }
    fres = 1.0;
    // A light inside an object: the first leg lies in the first facet's object.
    bool in_obj = light_in;
    ch_inside = light_in ? 1u : 0u;
    ch_mat[0] = triangle_material(f0);
    for (uint v = 0u; v < k; v++) {
        iters++;   // every loop's back-edges count (budget.glsl)
        uint f = mnee_cells[c + 1u + v];
        vec3 n = triangle_normal(f);
        if (v > 0u) {
            // On to facet f's plane: q + t w, t chosen per ray, so its derivative follows.
            float dn = dot(w, n);
            if (dn == 0.0) return false;
            float t = dot(tris[f].v0.xyz - q, n) / dn;
            if (!(t > 0.0)) return false;
            vec3 pa = qa + t * wa, pb = qb + t * wb;
            qa = pa - w * (dot(pa, n) / dn);
            qb = pb - w * (dot(pb, n) / dn);
            q += t * w;
        }
        ch_p[v] = q;
        bool entering = dot(w, n) < 0.0;
        vec3 nf = entering ? n : -n;
        float cos_i = -dot(w, nf);
        float ca = -dot(wa, nf), cb = -dot(wb, nf);
        uint mat = triangle_material(f);
        float ior = scene.materials[mat].ior.x;
        float eta = entering ? 1.0 / ior : ior;
        float cos_t;
        float F = fresnel_dielectric(cos_i, eta, cos_t);
        if (((rmask >> v) & 1u) != 0u) {
            // Mirror: w' = w + 2 cos_i nf.
            fres *= F;
            w += 2.0 * cos_i * nf;
            wa += 2.0 * ca * nf;
            wb += 2.0 * cb * nf;
        } else {
            if (F >= 1.0 || !(cos_t > 0.0)) return false;
            // Snell: w' = eta w + (eta cos_i - cos_t) nf, d cos_t = eta^2 cos_i d cos_i / cos_t.
            fres *= 1.0 - F;
            float s = eta * eta * cos_i / cos_t;
            w = eta * w + (eta * cos_i - cos_t) * nf;
            wa = eta * wa + (eta - s) * ca * nf;
            wb = eta * wb + (eta - s) * cb * nf;
            in_obj = !in_obj;
        }
        if (in_obj) ch_inside |= 1u << (v + 1u);
        ch_mat[v + 1u] = mat;
    }
    return true;
}

// Whether the leg from a to b (in vacuum) is clear of every surface but its ends'.
bool leg_clear(vec3 a, vec3 b) {
    vec3 to = b - a;
    float len = length(to);
    if (!(len > 0.0)) return true;
    float t;
    uint tri;
    float e = surface_eps(a) + surface_eps(b);
    return !mesh_hit_tri(a, to / len, e, len - e, t, tri);
}

// Solves the chain at record c for the point x: where it holds, the vertices (ch_p), the legs
// (ch_inside, ch_mat) and the irradiance E it delivers at x per unit of the light's intensity
// or irradiance (the Fresnel factors times the ray tube's cross-section at the light over its
// cross-section at x: point, dOmega / dA; directional, dA_0 / dA). `check`: the legs in vacuum
// are tested for blockers (the host's flag: several objects or a mesh that is not convex).
// Single refractions by mesh.glsl facet_refraction (bisection on the facet's plane); longer
// chains by Newton's method on the first facet's barycentric coordinates, from its centroid:
// the light's ray through them must pass through x, a 2 x 2 system on the residual
// perpendicular to the last leg (least squares through the ray tube). One solution per chain
// at most: on flat interfaces the optical path length is a convex function of the vertices
// (Fermat), so its stationary point is unique.
bool chain_at(uint c, vec3 x, vec3 light, bool point, bool light_in, bool check, out float E) {
    E = 0.0;
    uint head = mnee_cells[c];
    uint k = head & 0xffu;
    if (k == 0u || k > CHAIN_MAX) return false;
    if (k == 1u && light_in) {
        // A point light reflected once inside its object: the straight line from its mirror
        // image in the facet's plane (a flat mirror keeps the spherical wave: E = F / r^2).
        if ((head >> 8u) == 0u || !point) return false;
        uint f = mnee_cells[c + 1u];
        uint mat = triangle_material(f);
        if (mat != path_mat) return false;
        vec3 n = triangle_normal(f);
        vec3 v0 = tris[f].v0.xyz;
        float hl = dot(light - v0, n), hx = dot(x - v0, n);
        if (!(hl < 0.0 && hx < 0.0)) return false;
        vec3 image = light - 2.0 * hl * n;
        vec3 to = image - x;
        float r2 = dot(to, to);
        // Where x's line to the image crosses the plane.
        vec3 q = x + to * (hx / (hx - (-hl)));
        if (!point_in_triangle(f, q)) return false;
        float cos_i = abs(dot(to, n)) / sqrt(r2);
        float cos_t;
        E = fresnel_dielectric(cos_i, scene.materials[mat].ior.x, cos_t) / r2;
        ch_p[0] = q;
        ch_inside = 3u;
        ch_mat[0] = mat;
        ch_mat[1] = mat;
    } else if (k == 1u) {
        uint f = mnee_cells[c + 1u];
        uint mat = triangle_material(f);
        if (mat != path_mat) return false;
        vec3 ps;
        if (!facet_refraction(f, x, light, point, scene.materials[mat].ior.x, ps, E)) return false;
        ch_p[0] = ps;
        ch_inside = 2u;
        ch_mat[1] = mat;
    } else {
        // The start: where the straight line from the light to x (a directional light's line
        // through x) meets the first facet's plane, clamped onto the facet; its centroid where
        // the line runs along the plane. (From the centroid of a facet many times larger than
        // the light's distance, the first ray can meet total internal reflection.)
        uint f0 = mnee_cells[c + 1u];
        vec3 v0 = tris[f0].v0.xyz, e1 = tris[f0].e1.xyz, e2 = tris[f0].e2.xyz;
        vec2 ab = vec2(1.0 / 3.0);
        {
            vec3 n0 = cross(e1, e2);
            vec3 o0 = point ? light : x;
            vec3 d0 = point ? x - light : light;
            float den = dot(d0, n0);
            vec2 b;
            if (abs(den) > 1e-12 * length(d0) * length(n0) && triangle_coords(f0, o0 + d0 * (dot(v0 - o0, n0) / den), b))
                ab = onto_triangle(b);
        }
        vec3 q, w, qa, qb, wa, wb;
        float fres;
        bool done = false;
        // Converged when x lies within float rounding of the ray: relative to the coordinates'
        // magnitude and to the first facet's (its point is v0 + a e1 + b e2, rounded at that
        // scale: on a facet 17 units long, 1e-5 and more).
        float tol = 4e-6 * (1.0 + max3(abs(x)) + max3(abs(v0)) + length(e1) + length(e2));
        // Where that start's ray meets total internal reflection (x seen beyond the critical
        // angle of a light inside), the foot of a point light on the facet's plane: its ray
        // crosses the first plane along the normal, and most chains through it. A start that
        // went through keeps its trace for the first iteration (traced).
        bool traced = chain_trace(c, ab, light, point, light_in, q, w, qa, qb, wa, wb, fres);
        if (!traced && point) {
            iters++;
            vec3 n0 = normalize(cross(e1, e2));
            vec2 b;
            if (triangle_coords(f0, light - n0 * dot(light - v0, n0), b)) ab = onto_triangle(b);
        }
        // The last coordinates whose ray went through the whole chain: a step into total
        // internal reflection is halved back toward them (near the critical angle the map from
        // the coordinates to the last leg stretches without bound, and full steps overshoot).
        vec2 ab_good = ab;
        bool good = false;
        uint back = 0u;
        for (uint it = 0u; it < 40u; it++) {
            iters++;
            bool through = traced || chain_trace(c, ab, light, point, light_in, q, w, qa, qb, wa, wb, fres);
            traced = false;
            if (!through) {
                if (!good || back >= 12u) return false;
                ab = 0.5 * (ab + ab_good);
                back++;
                continue;
            }
            good = true;
            ab_good = ab;
            back = 0u;
            vec3 r = x - q;
            float s = dot(r, w);
            vec3 perp = r - s * w;
            vec3 ja = qa + s * wa, jb = qb + s * wb;
            ja -= w * dot(w, ja);
            jb -= w * dot(w, jb);
            if (dot(perp, perp) <= tol * tol) {
                if (!(s > 0.0)) return false;
                // The ray tube at x (perpendicular to w) and at the light.
                float dA = abs(dot(w, cross(ja, jb)));
                float src;
                if (point) {
                    vec3 r0 = ch_p[0] - light;
                    float l = length(r0);
                    vec3 w0 = r0 / l;
                    src = abs(dot(w0, cross(e1 - w0 * dot(w0, e1), e2 - w0 * dot(w0, e2)))) / (l * l);
                } else {
                    src = abs(dot(light, cross(e1, e2)));
                }
                if (!(dA > 0.0)) return false;
                E = fres * src / dA;
                done = true;
                break;
            }
            float aa = dot(ja, ja), ab2 = dot(ja, jb), bb = dot(jb, jb);
            float ra = dot(ja, perp), rb = dot(jb, perp);
            float det = aa * bb - ab2 * ab2;
            if (!(det > 0.0)) return false;
            vec2 delta = vec2(bb * ra - ab2 * rb, aa * rb - ab2 * ra) / det;
            // The map from ab to the last leg is affine for a directional light (a parallel beam
            // stays parallel through flat interfaces), so one step lands on the solution, and
            // nearly so for a point light over one facet: a full step that lands far outside the
            // facet (half its size beyond an edge) means no solution on it.
            vec2 to = ab + delta;
            if (to.x < -0.5 || to.y < -0.5 || to.x + to.y > 1.5) return false;
            // Damped, for where the beam folds (near a caustic) and a step overshoots.
            float m = max(abs(delta.x), abs(delta.y));
            if (m > 0.5) delta *= 0.5 / m;
            ab += delta;
        }
        if (!done) return false;
        if (!(ab.x >= 0.0 && ab.y >= 0.0 && ab.x + ab.y <= 1.0)) return false;
        for (uint v = 1u; v < k; v++) {
            iters++;
            if (!point_in_triangle(mnee_cells[c + 1u + v], ch_p[v])) return false;
        }
        // The last leg must end in the scattering point's object.
        if ((ch_inside & (1u << k)) == 0u || ch_mat[k] != path_mat) return false;
    }
    if (!(E > 0.0) || isinf(E)) return false;
    if (check) {
        // Legs in vacuum: the light's (leg 0, from a light outside) and any between objects or
        // sheets. Legs inside are tracked, and a surface across one blocks it (tracking.glsl).
        if (light_in) {
        } else if (point) {
            if (!leg_clear(light, ch_p[0])) return false;
        } else {
            float t;
            uint tri;
            if (mesh_hit_tri(ch_p[0], -light, surface_eps(ch_p[0]), INF, t, tri)) return false;
        }
        for (uint l = 1u; l < k; l++) {
            iters++;
            if ((ch_inside & (1u << l)) == 0u && !leg_clear(ch_p[l - 1u], ch_p[l])) return false;
        }
    }
    return true;
}

// Manifold next-event estimation from the scattering point p (the free flight's ray d) toward
// light li (point or directional, outside every object) through the objects' surfaces: every
// chain of p's cell that holds at p (chain_at) adds the transmittance of its legs inside
// objects, by ratio tracking in each leg's material, times the irradiance it delivers:
//   single refraction, point: E = I (1 - F) / [(l_o + l_i / eta) (l_o cos_i / cos_o + (l_i / eta) cos_o / cos_i)],
//   single refraction, directional: E (1 - F) cos_o / cos_i,
// with l_o, cos_o outside (vacuum) and l_i, cos_i inside (src/physics/dielectric.rs); longer
// chains: the ray tube's spreading, traced (chain_at).
// Physical irradiance: the camera path's throughput carries its own 1 / eta^2.
// Only the chains of p's cell in the light's grid are tried (mnee_range). Resumable: ev_sub 2
// scans the cell's list from position ev_surf_tri on; 3 + l tracks leg l (from k down to 1) of
// the chain at ev_surf_tri, solved again on resume (the same vertices), with the legs' product
// so far in ev_v. Returns false when it paused.
bool mnee_estimate(Light li, vec3 p, vec3 d, float g, vec3 beta, inout vec3 L, inout uvec2 rng) {
    bool point = uint(li.pos_kind.w) == LIGHT_POINT;
    bool check = (mnee_cells[7] & 1u) != 0u;
    bool light_in = mnee_light_inside(ev_light);
    uint begin, end;
    mnee_range(ev_light, p, begin, end);
    if (ev_sub == 0u) {
        ev_surf_tri = begin;
        ev_sub = 2u;
    }
    float E = 0.0;
    while (true) {
        if (ev_sub == 2u) {
            bool found = false;
            for (; ev_surf_tri < end; ev_surf_tri++) {
                if (iters >= iter_limit) return false;
                iters += CHAIN_TRY_ITERS;
                if (chain_at(mnee_cells[ev_surf_tri], p, li.pos_kind.xyz, point, light_in, check, E)) {
                    found = true;
                    break;
                }
            }
            if (!found) return true;
            ev_v = vec3(1.0);
            ev_sub = 3u + (mnee_cells[mnee_cells[ev_surf_tri]] & 0xffu);
        } else {
            // Resuming a paused leg: the same chain gives the same vertices and irradiance (its
            // vacuum legs were found clear before).
            chain_at(mnee_cells[ev_surf_tri], p, li.pos_kind.xyz, point, light_in, false, E);
        }
        uint k = mnee_cells[mnee_cells[ev_surf_tri]] & 0xffu;
        // Legs k down to 0 (leg 0 lies inside only from a light inside an object).
        for (; ev_sub >= 3u; ev_sub--) {
            iters++;
            uint l = ev_sub - 3u;
            if ((ch_inside & (1u << l)) != 0u) {
                // Tracked from the leg's far end (x, or just inside vertex l) back to vertex
                // l - 1 (or the light).
                vec3 a = l == 0u ? li.pos_kind.xyz : ch_p[l - 1u];
                vec3 b = l == k ? p : ch_p[l];
                vec3 to = a - b;
                float len = length(to);
                if (len > 0.0) {
                    vec3 wi = to / len;
                    float e = l == k ? 0.0 : surface_eps(b);
                    float ea = l == 0u ? 0.0 : e;
                    uint saved = path_mat;
                    path_mat = ch_mat[l];
                    track_start(b + wi * e, wi, len * (1.0 - 1e-4) - e - ea, true);
                    bool ok = transmittance_run(rng);
                    path_mat = saved;
                    if (!ok) return false;
                    ev_v *= trk.T;
                    if (max3(ev_v) <= 0.0) break;
                }
            }
            if (l == 0u) break;
        }
        if (max3(ev_v) > 0.0 && E > 0.0) {
            vec3 wi = normalize(ch_p[k - 1u] - p);
            L += beta * ev_v * phase_eval(g, dot(d, wi)) * li.value.rgb * E;
        }
        ev_surf_tri++;
        ev_sub = 2u;
    }
    return true;
}

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
    if (ev_step == EV_EQ) {
        if (!equiangular_lights(o, d, seg.x, seg.y, beta, L, rng)) return EVENT_PAUSED;
        ev_step = EV_FLIGHT;
    }
    if (ev_step == EV_FLIGHT) {
        track_start_on(o, d, seg);
        float t_hit;
        int r = scatter_run(beta, rng, t_hit);
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
                if (iters >= iter_limit) return EVENT_PAUSED;
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
        uint i = ev_light;
        if (ev_sub == 0u) {
            if (iters >= iter_limit) return EVENT_PAUSED;
            iters++;
        }
        Light li = scene.lights[i];
        uint kind = uint(li.pos_kind.w);
        // A light inside an object with a refractive boundary: the straight shadow ray (ev_sub
        // 0-1), then its chains (mnee_estimate from ev_sub 0 again, on at 2 and up).
        bool chains = mnee_light(i) && kind != LIGHT_ENVIRONMENT;
        if (chains && !mnee_light_inside(i)) {
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
            if (!mnee_estimate(li, p, d, g, beta, L, rng)) return EVENT_PAUSED;
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

// n finished samples of radiance L each into the pixel's sums (mean and variance of the mean).
// n = 1 adds L and L^2 exactly (L * 1.0 is L).
void add_samples(uint pixel, vec3 L, float n) {
    accum[2u * pixel] += vec4(L * n, n);
    accum[2u * pixel + 1u] += vec4(L * L * n, 0.0);
}

void main() {
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
    uint k = st.k_flight.x;
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
    vec3 env_seen = vec3(0.0);   // what a camera ray that misses the medium sees
    for (uint i = 0u; ENVIRONMENT && i < scene.image.z; i++)
        if (uint(scene.lights[i].pos_kind.w) == LIGHT_ENVIRONMENT) env_seen += scene.lights[i].value.rgb;

    while (iters < pc.budget) {
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
            while (k < pc.sample_end && iters < pc.budget) {
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
    if (in_flight || k < pc.sample_end) atomicAdd(stats[3u + pc.slot], 1u);
}
