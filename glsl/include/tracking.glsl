// tracking.glsl: free-flight sampling and transmittance shared by the path kernels
// (path/trace: camera paths; path/light: light paths): delta/spectral tracking to the next
// real scattering, ratio tracking of the transmittance, and the phase function as the scene's
// specialisation selects it. Needs scene.glsl, rng.glsl, phase.glsl and budget.glsl first.
//
// Both tracking loops are resumable (budget.glsl): one free flight or one transmittance can
// need any number of tentative collisions (about sigma_maj times the distance: 1e7 through a
// medium of optical thickness 1e7), far more than llvmpipe lets one invocation run in a
// dispatch (65535 loop iterations). So the loop in progress lives in `trk`, checks the budget
// before every iteration, and when it is spent returns "paused" with `trk_paused` set; the
// kernel saves `trk` (track_save) with the rest of its state, and the next dispatch, having
// reached the same tracking call again, resumes it exactly where it stopped (track_start with
// `trk_resume` set loads the saved words instead of starting afresh). Every value is restored
// bit for bit, so an image does not depend on where the dispatches split the work.
#ifndef SCATTERLAB_TRACKING
#define SCATTERLAB_TRACKING

float phase_eval(float g, float c) { return ANISOTROPIC ? hg_eval(g, c) : INV_4PI; }
vec3 phase_sample(float g, vec3 d, vec2 u) { return ANISOTROPIC ? hg_sample(g, d, u) : uniform_sphere(u); }

// Tentative collisions of the current path, the cap past which it is dropped (set by the
// kernel from its push constants), and whether it was.
uint collisions;
uint collision_cap;
bool truncated;

// Own-counted loop iterations (budget.glsl `iters`) past which a tracking loop pauses: the
// kernel's budget.
uint iter_limit;

// The material of the medium the path is in (scene.materials; with several [[object]]
// materials, the object it is inside): every tracked ray starts in it (medium_mat, which a
// transmittance through index-matched objects moves along as it enters each). The kernel sets
// it; 0, the medium's, by default.
uint path_mat = 0u;

// The current medium's extinction (rgb; w = max), albedo (rgb; w = g).
vec4 mat_sigma_t() { return scene.materials[medium_mat].sigma_t; }
vec4 mat_albedo() { return scene.materials[medium_mat].albedo; }

// The tracking loop in progress along the ray s.org + t s.dir.
struct Tracker {
    Segments s;    // the majorant segments still ahead
    float t;       // distance of the current tentative collision
    float t1;      // end of the current segment
    float smaj;    // the current segment's majorant
    bool in_seg;   // within a segment (t, t1, smaj valid); else the next segment is fetched
    float r;       // free-flight distance sampled but too short to move t (see track_next)
    vec3 T;        // ratio tracking: the transmittance so far
};
Tracker trk;

// The saved word with the flags: majorant cells y and z in 14 bits each (the host refuses
// grids of 16384 majorant cells or more along y or z: path::MAX_MAJORANT_CELLS), then the flags.
const uint CELL_MASK = 0x3fffu;
const uint IN_SEG_BIT = 1u << 30u;
const uint DONE_BIT = 1u << 31u;

// The kernel loads a paused tracker's saved words here and sets trk_resume; the next
// track_start resumes it. trk_paused: the tracker paused in this dispatch (save it).
vec4 trk_saved[3];
bool trk_resume = false;
bool trk_paused = false;
// With a mesh, a resumed tracker takes at least one step before it may pause again, whatever
// the work that preceded it in this dispatch (a mesh traversal can cost more than a small
// budget): every dispatch makes progress.
bool trk_step_due = false;

// Begin tracking along p + t w over the medium's interval (clipped to t_far when `clip`), or,
// when a paused tracker is waiting (trk_resume), resume it: the caller reaches the same call
// with the same ray, so the parts of the tracker that follow from the ray (segments_begin's
// steps) are recomputed identically and only its progress is loaded.
void track_start_on(vec3 p, vec3 w, vec2 iv);
#ifdef MESH_NODES_BINDING
// With an [[object]] (mesh.glsl), a tracked ray starts inside the mesh (a scattering point, or
// a point just past a surface the path crossed inward): its first interval ends at the first
// surface. A transmittance (clip) goes on through further inside intervals up to t_far when
// the boundary is index-matched (trk_chain); a refractive one blocks it (trk_blocked): a
// delta light or direction cannot be reached through a smooth dielectric by a straight ray.
bool trk_chain = false;
bool trk_blocked = false;
float trk_far = INF;
// The current inside interval's end, saved with the tracker (track_save_mesh) since a
// chained interval is not the one track_start recomputes.
vec4 trk_saved_mesh = vec4(0.0);

// The next crossing of the mesh along p + t w with t in (t_min, t_max) whose facing is
// `entering` (dot(w, n) < 0) or leaving: crossings of the other facing are stepped over, so
// a ray through an edge shared by two triangles is not counted twice.
bool mesh_crossing_tri(vec3 p, vec3 w, float t_min, float t_max, bool entering, out float t, out uint tri) {
    t = t_min;
    tri = 0u;
    // A closed mesh alternates entries and exits; a few extra steps cover edge double hits.
    for (uint k = 0u; k < 8u; k++) {
        LOOP_EDGE(W_CROSSING);
        if (!mesh_hit_tri(p, w, t, t_max, t, tri)) return false;
        if ((dot(w, triangle_normal(tri)) < 0.0) == entering) return true;
    }
    return false;
}

bool mesh_crossing(vec3 p, vec3 w, float t_min, float t_max, bool entering, out float t) {
    uint tri;
    return mesh_crossing_tri(p, w, t_min, t_max, entering, t, tri);
}

// The next inside interval of the ray after t_end (an exit), within the box and t_far: false
// when there is none. Sets medium_mat to the material of the object it enters.
bool next_inside_interval(vec3 p, vec3 w, float t_end, float t_far, out vec2 iv) {
    float t_in, t_out;
    uint tri;
    iv = vec2(INF, -INF);
    if (!(t_end < t_far) || !mesh_crossing_tri(p, w, t_end, t_far, true, t_in, tri)) return false;
    medium_mat = triangle_material(tri);
    if (!mesh_crossing(p, w, t_in, INF, false, t_out)) t_out = INF;
    vec2 box = medium_interval(p, w);
    iv = vec2(max(t_in, box.x), min(min(t_out, t_far), box.y));
    return iv.x < iv.y;
}
#endif

void track_start(vec3 p, vec3 w, float t_far, bool clip) {
    medium_mat = path_mat;   // the ray starts in the path's medium (its density field's box)
    vec2 iv = medium_interval(p, w);
    iv.x = max(iv.x, 0.0);
#ifdef MESH_NODES_BINDING
    bool chain = false, blocked = false;
    if (HAS_MESH) {
        float t_exit;
        if (!mesh_crossing(p, w, 0.0, INF, false, t_exit)) t_exit = INF;
        iv.y = min(iv.y, t_exit);
        if (clip && t_exit < t_far) {
            if (REFRACTIVE) blocked = true;
            else chain = true;
        }
    }
#endif
    if (clip) iv.y = min(iv.y, t_far);
    track_start_on(p, w, iv);
#ifdef MESH_NODES_BINDING
    // After track_start_on, which clears them: a free flight never chains (it ends at the
    // surface, where the path meets the boundary).
    trk_chain = chain;
    trk_blocked = blocked;
    trk_far = clip ? t_far : INF;
#endif
}

// track_start over an interval [iv.x, iv.y] of the ray the caller has already found (the
// medium's, from t >= 0): saves the caller's second ray-medium intersection.
void track_start_on(vec3 p, vec3 w, vec2 iv) {
    medium_mat = path_mat;
#ifdef MESH_NODES_BINDING
    trk_chain = false;
    trk_blocked = false;
    trk_far = INF;
#endif
    trk.s = segments_begin(p, w, iv.x, iv.y);
    trk.t = 0.0;
    trk.t1 = 0.0;
    trk.smaj = 0.0;
    trk.in_seg = false;
    trk.r = 0.0;
    trk.T = vec3(1.0);
    if (trk_resume) {
        trk_resume = false;
#ifdef MESH_NODES_BINDING
        trk_step_due = HAS_MESH;
#endif
        vec4 a = trk_saved[0], b = trk_saved[1], c = trk_saved[2];
        uint bits = floatBitsToUint(c.w);
        trk.t = a.x;
        trk.in_seg = (bits & IN_SEG_BIT) != 0u;
        trk.smaj = a.z;
        trk.r = a.w;
        // Within a grid segment the DDA's t_min equals the segment's end; outside one, the
        // slot holds t_min (segments_next in scene.glsl advances them together).
        if (trk.in_seg) {
            trk.t1 = a.y;
            trk.s.t_min = a.y;
        } else {
            trk.s.t_min = a.y;
        }
        trk.s.done = (bits & DONE_BIT) != 0u;
        trk.s.next_t = b.xyz;
        trk.s.cell = ivec3(floatBitsToInt(b.w), int(bits & CELL_MASK), int((bits >> 14u) & CELL_MASK));
        trk.T = c.xyz;
#ifdef MESH_NODES_BINDING
        // A chained interval: its end (the DDA's steps follow from the direction alone) and
        // the material of the object it crosses.
        if (HAS_MESH && trk_saved_mesh.w != 0.0) {
            trk.s.t_max = trk_saved_mesh.x;
            medium_mat = uint(trk_saved_mesh.w) - 1u;
        }
#endif
    }
}

#ifdef MESH_NODES_BINDING
// What track_start needs beyond track_save's words to resume a paused tracker in a chained
// interval: its end, and 1 + the material of its object (zeros when none paused).
vec4 track_save_mesh() {
    return trk_paused && HAS_MESH ? vec4(trk.s.t_max, 0.0, 0.0, float(medium_mat + 1u)) : vec4(0.0);
}

#endif

// The words that track_start loads to resume `trk` (zeros when no tracking loop paused).
void track_save(out vec4 a, out vec4 b, out vec4 c) {
    a = vec4(0.0);
    b = vec4(0.0);
    c = vec4(0.0);
    if (!trk_paused) return;
    // A cell index outside the grid only ever comes with `done`, when it is not read again.
    uint bits = (trk.in_seg ? IN_SEG_BIT : 0u) | (trk.s.done ? DONE_BIT : 0u) | (uint(trk.s.cell.y) & CELL_MASK)
              | ((uint(trk.s.cell.z) & CELL_MASK) << 14u);
    a = vec4(trk.t, trk.in_seg ? trk.t1 : trk.s.t_min, trk.smaj, trk.r);
    b = vec4(trk.s.next_t, intBitsToFloat(trk.s.cell.x));
    c = vec4(trk.T, uintBitsToFloat(bits));
}

// Fetch the next tentative collision of `trk`: returns 1 with trk.t set, 0 when the ray has
// left the medium, -1 when the budget is spent (paused before drawing anything).
int track_next(inout uvec2 rng) {
    float t0;
    while (true) {
        BATCH_EDGE(W_TRACK_STEP);
        if (SPENT(iter_limit) && !trk_step_due) {
            trk_paused = true;
            return -1;
        }
        trk_step_due = false;
        if (!trk.in_seg) {
            if (!segments_next(trk.s, t0, trk.t1, trk.smaj)) {
#ifdef MESH_NODES_BINDING
                // A transmittance through an index-matched mesh: on into the next inside interval.
                vec2 iv;
                // (trk_chain holds HAS_MESH; the test says so where specialisation sees it.)
                if (HAS_MESH && trk_chain && next_inside_interval(trk.s.org, trk.s.dir, trk.s.t_max, trk_far, iv)) {
                    iters++;
                    trk.s = segments_begin(trk.s.org, trk.s.dir, iv.x, iv.y);
                    continue;
                }
#endif
                return 0;
            }
            iters++;
            if (trk.smaj <= 0.0) continue;
            trk.t = t0;
            trk.r = 0.0;
            trk.in_seg = true;
        }
        iters++;
        float dt = log(1.0 - rnd(rng)) / trk.smaj;
        float tn = trk.t - dt;
        if (tn == trk.t) {
            // The free path is below half an ulp of t (sigma_maj t beyond ~1e7): t would stall
            // at the same point for ever. Such steps add up in r until they move t.
            trk.r -= dt;
            tn = trk.t + trk.r;
            if (tn != trk.t) trk.r = 0.0;
        } else {
            trk.r = 0.0;
        }
        trk.t = tn;
        if (trk.t < trk.t1) return 1;
        trk.in_seg = false;
    }
    return 0;
}

// Ratio tracking (Novak et al. 2014) of the transmittance along the ray track_start began, up
// to its t_far: T *= sigma_n / sigma_maj per tentative collision, per channel; unbiased for
// each channel since sigma_maj >= max channel sigma_t. Russian roulette on small T stays
// unbiased. Returns false when it paused; true when trk.T is the transmittance.
bool transmittance_run(inout uvec2 rng) {
    // A constant medium (constant or sphere density, whose density is 1 on the whole interval):
    // T = exp(-sigma_t d) per channel, exactly, at no variance and one exp. Ratio tracking
    // against the majorant sigma_t is binary there (sigma_n = 0: T is 1 with probability
    // exp(-sigma_t d), else 0), as it is in pbrt-v4 and Mitsuba 3; its variance T (1 - T) is
    // what next-event estimation deep in an optically thick medium is made of.
#ifdef MESH_NODES_BINDING
    if (trk_blocked) {
        trk.T = vec3(0.0);
        trk.s.done = true;
        return true;
    }
#endif
    if (DENSITY_KIND != DENSITY_GRID) {
        float d = trk.s.done ? 0.0 : max(trk.s.t_max - trk.s.t_min, 0.0);
        vec3 tau = mat_sigma_t().xyz * d;
#ifdef MESH_NODES_BINDING
        // Every inside interval up to t_far: their optical depths add, each in its object's
        // material.
        vec2 iv;
        float t_end = trk.s.t_max;
        if (HAS_MESH) {
            while (trk_chain && next_inside_interval(trk.s.org, trk.s.dir, t_end, trk_far, iv)) {
                LOOP_EDGE(W_CHAIN_INTERVAL);
                tau += mat_sigma_t().xyz * (iv.y - iv.x);
                t_end = iv.y;
            }
        }
#endif
        trk.T = exp(-tau);
        trk.s.done = true;
        return true;
    }
    while (true) {
        BATCH_EDGE(W_TRANSMITTANCE);
        int r = track_next(rng);
        if (r < 0) return false;
        if (r == 0) return true;
        collisions++;
        vec3 st = mat_sigma_t().xyz * density_at(trk.s.org + trk.s.dir * trk.t);
        trk.T *= max(vec3(0.0), trk.smaj - st) / trk.smaj;
        float m = max3(trk.T);
        if (m < 0.1) {
            if (rnd(rng) >= 0.5) {
                trk.T = vec3(0.0);
                return true;
            }
            trk.T *= 2.0;
        }
        if (collisions > collision_cap) {
            truncated = true;
            trk.T = vec3(0.0);
            return true;
        }
    }
    return true;
}

// Outcomes of scatter_run.
const int FLIGHT_PAUSED = -1;
const int FLIGHT_ESCAPED = 0;     // left the medium (beta weights the escape) or died (beta 0)
const int FLIGHT_SCATTERED = 1;   // a real scattering at t_hit

#ifdef EMISSION_BINDING
// Emission the free flight in progress collected (scatter_run): beta sigma_a Le / sigma_maj at
// every tentative collision, before its outcome is drawn (pbrt-v4's volumetric path tracer;
// the expected sum over a flight is the integral of T sigma_a Le along it). The caller adds it
// to the path's radiance and zeroes it after every scatter_run, paused or not.
vec3 trk_emitted = vec3(0.0);
#endif

// Delta/spectral tracking to the next real scattering event along the ray track_start began
// (with clip false). Sets `t_hit` on a scattering.
int scatter_run(inout vec3 beta, inout uvec2 rng, out float t_hit) {
    t_hit = 0.0;
    while (true) {
        BATCH_EDGE(W_FLIGHT);
        int r = track_next(rng);
        if (r < 0) return FLIGHT_PAUSED;
        if (r == 0) return FLIGHT_ESCAPED;
        float t = trk.t;
        float smaj = trk.smaj;
        collisions++;
        if (collisions > collision_cap) { truncated = true; beta = vec3(0.0); return FLIGHT_ESCAPED; }
        vec3 x = trk.s.org + trk.s.dir * t;
        float dens = density_at(x);
        vec3 st = mat_sigma_t().xyz * dens;
#ifdef EMISSION_BINDING
        if (EMISSION != EMISSION_NONE) trk_emitted += beta * emission_source(x, dens) / smaj;
#endif
        vec3 ss = st * mat_albedo().xyz;
        vec3 sn = max(vec3(0.0), smaj - st);
        if (!CHROMATIC) {
            // Grey: scatter with probability sigma_s / (sigma_s + sigma_n); absorption is
            // carried by the weight (sigma_maj - sigma_a) / sigma_maj, the same on both branches.
            float denom = ss.x + sn.x;
            if (denom <= 0.0) { beta = vec3(0.0); return FLIGHT_ESCAPED; }
            beta *= denom / smaj;
            if (rnd(rng) * denom < ss.x) { t_hit = t; return FLIGHT_SCATTERED; }
        } else {
            // Spectral tracking, history-aware probabilities (Kutz 2017, eq. 15-16).
            float ws = avg3(beta * ss);
            float wn = avg3(beta * sn);
            if (ws + wn <= 0.0) { beta = vec3(0.0); return FLIGHT_ESCAPED; }
            float ps = ws / (ws + wn);
            if (rnd(rng) < ps) {
                beta *= ss / (smaj * ps);
                t_hit = t;
                return FLIGHT_SCATTERED;
            }
            beta *= sn / (smaj * (1.0 - ps));
        }
    }
    return FLIGHT_ESCAPED;
}

// Power heuristic (Veach 1997) for two strategies with one sample each.
float mis_power(float a, float b) { return a * a / (a * a + b * b); }
#endif
