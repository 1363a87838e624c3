#version 460
// path/light: light tracing (particle tracing) for the point lights `path` leaves to light
// paths (pc.light_traced), the strategy that suits a point light deep inside a scattering
// medium: camera paths reach the light's neighbourhood only by rare deep random walks
// (deep-penetration noise that equiangular sampling does not touch), while paths started at
// the light diffuse outward on their own and are connected to the camera at every scattering
// event (particle tracing, Arvo & Kirk 1990; the t = 1 strategy of bidirectional path tracing,
// Veach 1997 ch. 10). The camera kernel skips these lights, so the image is a partition of
// the paths by light and the two kernels' sums add without MIS.
//
// Per light path: pick a light-traced point light with probability proportional to its
// intensity, a uniform direction, then delta/spectral tracking (tracking.glsl) exactly as the
// camera kernel. At each real scattering x with throughput beta (power units, W per path),
// the connection to the camera adds to the pixel j that x projects into
//     beta * p(d_in . w_cam) * T(x, camera) * W_j(x),
// the measurement I_j = (1/A_pix) int_pixel L dp rewritten over the volume with
// dp = dw / cos^3(theta) and dw dt = dV / t^2:  W_j = 1 / (A_pix t^2 cos^3 theta) for the
// perspective camera (A_pix: a pixel's area on the image plane at distance 1), and 1 / A_pix
// for the orthographic one (dp dt = dV). The host divides the sums by the number of paths.
//
// Determinism: splats are added as 64-bit fixed-point integers (two 32-bit words with an
// explicit carry), so the order in which invocations add them does not change a bit; the
// rounding to the quantum is dithered with the path's own random numbers, so it is unbiased.
// One invocation = one path slot; resumable like path/trace (budget.glsl): a path's state, and
// a free flight or camera connection in progress, is saved when the loop budget is spent
// (tracking.glsl) and the host re-dispatches until every slot has traced
// its paths [sample_begin, sample_end).
// With an index-matched [[object]] (HAS_MESH, not REFRACTIVE: the host refuses light paths
// through a refractive boundary, where no straight connection reaches the camera), a path
// starts in the object holding its light, takes on the material of each object it flies into,
// crosses surfaces unchanged, and its camera connection takes the optical depth of every
// object it crosses (tracking.glsl's chained intervals).
#extension GL_GOOGLE_include_directive : require
#extension GL_KHR_shader_subgroup_basic : require

// On llvmpipe the kernel counts its SIMD batches' loop back-edges as the driver's loop limiter
// does and pauses the batch before the limit (glsl/include/batch.glsl): a batch's lanes run
// different loops, and their sum, not one lane's count, is what the limiter ends.
#define SCATTERLAB_BATCH_LOOPS
#define SCATTERLAB_BATCH_PAUSE 64
#ifndef SCATTERLAB_LOOP_COUNTS   // tools/glsl-loop-counts reads the weights by name
#include "light.loops.glsl"
#endif

#define SCENE_BINDING 0
#define DENSITY_BINDING 1
#define MAJORANT_BINDING 2
// Binding 6 is the light statistics (below): the mesh's BVH follows at 7 and 8.
#define MESH_NODES_BINDING 7
#define MESH_TRIS_BINDING 8
#include "../include/scene.glsl"
#include "../include/rng.glsl"
#include "../include/phase.glsl"
#include "../include/budget.glsl"
#include "../include/mesh.glsl"
#include "../include/tracking.glsl"

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

// Per pixel and channel: the low and the high word of the 64-bit fixed-point sum of splats.
layout(std430, binding = 3) buffer Splats { uint splats[]; };
// The resumable kernels' layout (solvers/resumable.rs): [0] paths truncated by the collision
// cap, [1] tracking steps, [2] most loop iterations in one invocation, [3 + slot] active.
layout(std430, binding = 4) buffer Stats { uint stats[]; };

struct LightState {
    vec4 o_light;      // position, index of the path's light (uint bits)
    vec4 d_depth;      // direction, scattering events so far (uint bits)
    vec4 beta_key;     // throughput relative to the emitted weight, rng stream key (uint bits)
    uvec4 k_flags;     // next path index, flags (FLAG_*, and the event's step), collisions, rng counter
    vec4 trk_a;        // the paused tracking loop (tracking.glsl, track_save)
    vec4 trk_b;
    vec4 trk_c;
    vec4 trk_mesh;     // a paused tracker's chained interval (tracking.glsl, track_save_mesh)
};
const uint FLAG_IN_FLIGHT = 1u;
const uint FLAG_TRUNCATED = 2u;
const uint FLAG_TRACKING = 4u;   // a tracking loop paused (resume it)
const uint FLAG_SPLAT = 8u;      // the event's free flight is done: o is the scattering point, splat from there
// Bits 8-11 of the flags: path_mat, the material of the object the path is in (with a mesh).
layout(std430, binding = 5) buffer State { LightState state[]; };
// [0] splats clamped to the fixed-point range, [1] 64-bit sums that overflowed, [2] splats.
layout(std430, binding = 6) buffer LightStats { uint lstats[]; };

layout(push_constant) uniform Push {
    uint sample_end;      // trace paths [.., sample_end) of every slot
    uint budget;          // own-counted loop iterations per invocation per dispatch
    uint seed_lo;
    uint seed_hi;
    uint max_depth;       // scattering events; 1 = single scattering; 0xffffffff = unbounded
    uint collision_cap;   // safety cap on tentative collisions per path (reported, not silent)
    uint slot;            // which active counter this dispatch reports into
    uint light_traced;    // bit i: light i is traced from here
    uint rr_depth;        // Russian roulette from this many scattering events on
    float rr_threshold;   // ... for throughput below this (survival max(beta) / threshold)
    uint sample_begin;    // the first path index of every slot (render.first_sample, --samples A..B)
    float inv_quantum;    // fixed-point quanta per unit of splat (W/(m^2 sr) per path)
    float power_sum;      // sum over light-traced lights of their mean intensity (W/sr)
    uint batch_q;         // paths per slot in a batch: spp / batches ...
    uint batch_r;         // ... plus one in the first spp % batches batches
    uint group_first;     // the first batch whose sums this submission's splat slices hold
} pc;

// 2^40 quanta: a splat larger than that is clamped (and counted, so the host warns).
const float SPLAT_MAX = 1099511627776.0;
const float TWO32 = 4294967296.0;

// Word offset of the splat slice of the batch the path in flight belongs to: batches are
// ranges of path indices per slot, and a group of them is traced in one resumable run, each
// path splatting into its own batch's slice (64-bit integer sums: the same bits in any order).
uint slice_words = 0u;

// The batch that path index k of a slot belongs to (batch b holds batch_q paths, one more when
// b < batch_r: the host's split), counted from the range's first path: the batches of a range
// A..B are those a render of B - A paths would have, shifted by A.
uint batch_of(uint k) {
    k -= pc.sample_begin;
    uint big = pc.batch_r * (pc.batch_q + 1u);
    return k < big ? k / (pc.batch_q + 1u) : pc.batch_r + (k - big) / pc.batch_q;
}

// The word offset of path index k's batch slice in this group's splats.
uint slice_of(uint k, uvec2 res) {
    return 6u * res.x * res.y * (batch_of(k) - pc.group_first);
}

uint splat_clamped = 0u;
uint sum_overflow = 0u;
uint splat_count = 0u;

// Add v >= 0 (in quanta; below 2^40) to the 64-bit sum at word w, dithered by u in [0, 1).
void add_fixed(uint w, float v, float u) {
    float hi_f = floor(v / TWO32);
    float lo_f = floor(v - hi_f * TWO32 + u);
    if (lo_f >= TWO32) { lo_f -= TWO32; hi_f += 1.0; }
    uint lo = uint(lo_f);
    uint hi = uint(hi_f);
    uint old = atomicAdd(splats[w], lo);
    if (old > 0xffffffffu - lo) hi += 1u;   // the low word wrapped: carry
    if (hi != 0u) {
        uint old_hi = atomicAdd(splats[w + 1u], hi);
        if (old_hi > 0xffffffffu - hi) sum_overflow++;
    }
}

// Connect the scattering point x (reached along d_in, throughput beta in W per path) to the
// camera and add the contribution to the pixel x projects into. Returns false when the
// transmittance to the camera paused (the call is repeated with the same arguments to resume).
bool splat(vec3 x, vec3 d_in, vec3 beta, inout uvec2 rng) {
    vec3 F = scene.cam_forward.xyz;
    vec3 R = scene.cam_right.xyz;
    vec3 U = scene.cam_up.xyz;
    float k = scene.cam_forward.w;
    uvec2 res = scene.image.xy;
    float aspect = float(res.y) / float(res.x);
    vec3 v = x - scene.cam_origin.xyz;
    float z = dot(v, F);
    if (!(z > 0.0)) return true;
    vec2 plane;
    vec3 w_cam;          // propagation direction from x toward the camera
    float t_cam;         // distance to the camera (pinhole) or its plane (orthographic)
    float W;             // importance W_j(x) per unit pixel measurement (header)
    // A pixel's area on the image plane (at distance 1 for the pinhole).
    float a_pix = (2.0 * k / float(res.x)) * (2.0 * k * aspect / float(res.y));
    if (scene.cam_origin.w < 0.5) {
        plane = vec2(dot(v, R), dot(v, U)) / z;
        t_cam = length(v);
        w_cam = -v / t_cam;
        // 1 / (A_pix t^2 cos^3) with cos = z / t.
        W = t_cam / (a_pix * z * z * z);
    } else {
        plane = vec2(dot(v, R), dot(v, U));
        t_cam = z;
        w_cam = -F;
        W = 1.0 / a_pix;
    }
    vec2 ndc = vec2(plane.x / k, plane.y / (k * aspect));
    // Pixel coordinates as camera_ray maps them: px.x = (ndc.x + 1) / 2 * width, row 0 at the top.
    vec2 pxf = vec2((ndc.x + 1.0) * 0.5 * float(res.x), (1.0 - ndc.y) * 0.5 * float(res.y));
    if (!(pxf.x >= 0.0 && pxf.y >= 0.0 && pxf.x < float(res.x) && pxf.y < float(res.y))) return true;
    uvec2 px = min(uvec2(pxf), res - 1u);
    track_start(x, w_cam, t_cam, true);
    if (!transmittance_run(rng)) return false;
    vec3 T = trk.T;
    if (max3(T) <= 0.0) return true;
    vec3 c = beta * T * (phase_eval(scene.materials[path_mat].albedo.w, dot(d_in, w_cam)) * W) * pc.inv_quantum;
    if (any(isnan(c)) || any(isinf(c))) { truncated = true; return true; }
    uint base = slice_words + 6u * (px.y * res.x + px.x);
    splat_count++;
    for (uint ch = 0u; ch < 3u; ++ch) {
        BATCH_EDGE(W_SPLAT_CHANNELS);
        float q = c[ch];
        if (q > SPLAT_MAX) { q = SPLAT_MAX; splat_clamped++; }
        if (q > 0.0) add_fixed(base + 2u * ch, q, rnd(rng));
    }
    return true;
}

// Outcomes of advance().
const int EVENT_NEXT = 0;     // the path goes on
const int EVENT_ENDED = 1;    // the path has ended
const int EVENT_PAUSED = 2;   // the budget is spent; the event resumes in the next dispatch

// Whether the event in flight has done its free flight (o is then the scattering point).
bool ev_splat = false;

// One event of a light path: free flight to the next scattering, the camera connection
// there and a new direction. Resumable (tracking.glsl): a paused free flight resumes from the
// same ray (o, d); once it has scattered, o moves to the scattering point and a paused camera
// connection resumes from there.
int advance(inout vec3 o, inout vec3 d, inout vec3 beta, vec3 emitted, inout uint depth, inout uvec2 rng) {
    if (!ev_splat) {
        float t_hit;
        track_start(o, d, INF, false);
        int r = scatter_run(beta, rng, t_hit);
        if (r == FLIGHT_PAUSED) return EVENT_PAUSED;
        if (r == FLIGHT_ESCAPED) {
            // With a mesh the flight ended at the surface (or the box): the path flies on
            // through the vacuum into the next object its ray enters (a torus's other side, or
            // another object), whose material it takes on; else it has left.
            if (!HAS_MESH) return EVENT_ENDED;
            if (max3(beta) <= 0.0 || truncated) return EVENT_ENDED;
            float t_in;
            uint tri;
            if (!mesh_crossing_tri(o, d, trk.s.t_max, INF, true, t_in, tri)) return EVENT_ENDED;
            vec3 q = o + d * t_in;
            o = q - triangle_normal(tri) * surface_eps(q);
            path_mat = triangle_material(tri);
            // Counted as a collision, so a ray caught between surfaces ends at the cap.
            collisions++;
            if (collisions > collision_cap) { truncated = true; return EVENT_ENDED; }
            return EVENT_NEXT;
        }
        depth++;
        if (depth > pc.max_depth) return EVENT_ENDED;
        o = o + d * t_hit;
        ev_splat = true;
    }
    if (!splat(o, d, beta * emitted, rng)) return EVENT_PAUSED;
    ev_splat = false;
    d = phase_sample(scene.materials[path_mat].albedo.w, d, rnd2(rng));
    // Russian roulette as in path/trace; beta is relative to the emitted weight, so it starts at 1.
    if (depth >= pc.rr_depth) {
        float q = min(1.0, max3(beta) / pc.rr_threshold);
        if (rnd(rng) >= q) return EVENT_ENDED;
        beta /= q;
    }
    return EVENT_NEXT;
}

// The emitted weight of a path from light i: intensity / (pdf of the light * pdf of the
// direction) = I_i * 4 pi / P_i, with P_i = mean(I_i) / power_sum.
vec3 emitted_weight(uint i) {
    vec3 I = scene.lights[i].value.rgb;
    return I * (4.0 * PI * pc.power_sum / avg3(I));
}

void main() {
    BATCH_BEGIN(W_MAIN);
    uvec2 px = gl_GlobalInvocationID.xy;
    uvec2 res = scene.image.xy;
    if (px.x >= res.x || px.y >= res.y) return;
    uint slot_index = px.y * res.x + px.x;
    collision_cap = pc.collision_cap;
    iter_limit = pc.budget;
    LightState st = state[slot_index];
    vec3 o = st.o_light.xyz;
    uint light = floatBitsToUint(st.o_light.w);
    vec3 d = st.d_depth.xyz;
    uint depth = floatBitsToUint(st.d_depth.w);
    vec3 beta = st.beta_key.xyz;
    uvec2 rng = uvec2(floatBitsToUint(st.beta_key.w), st.k_flags.w);
    // A slot not yet started holds k = 0: it starts at the range's first path index.
    uint k = max(st.k_flags.x, pc.sample_begin);
    // A path resumed in flight splats into its batch's slice; a new path sets its own below.
    slice_words = slice_of(k, res);
    bool in_flight = (st.k_flags.y & FLAG_IN_FLIGHT) != 0u;
    truncated = (st.k_flags.y & FLAG_TRUNCATED) != 0u;
    trk_resume = (st.k_flags.y & FLAG_TRACKING) != 0u;
    ev_splat = (st.k_flags.y & FLAG_SPLAT) != 0u;
    trk_saved[0] = st.trk_a;
    trk_saved[1] = st.trk_b;
    trk_saved[2] = st.trk_c;
    trk_saved_mesh = st.trk_mesh;
    path_mat = (st.k_flags.y >> 8u) & 15u;
    collisions = st.k_flags.z;
    uint trunc_count = 0u;
    uint segs0 = collisions;
    uint segs = 0u;
    uint light_count = scene.image.z;

    while (!SPENT(pc.budget)) {
        BATCH_EDGE(W_EVENTS);
        if (!in_flight) {
            if (k >= pc.sample_end) break;
            slice_words = slice_of(k, res);
            // Streams keyed apart from the camera kernel's (seed_hi is mixed differently).
            rng = rng_init(pc.seed_lo, pc.seed_hi ^ 0x6c8e9cf5u, slot_index, k);
            // The light, with probability proportional to its mean intensity (inverse CDF).
            float u = rnd(rng) * pc.power_sum;
            light = 0xffffffffu;
            float acc = 0.0;
            for (uint i = 0u; i < min(light_count, 32u); ++i) {
                LOOP_EDGE(W_LIGHT_PICK);
                if ((pc.light_traced & (1u << i)) == 0u) continue;
                float p = avg3(scene.lights[i].value.rgb);
                if (p <= 0.0) continue;
                light = i;            // the last eligible light absorbs round-off at the top
                acc += p;
                if (u < acc) break;
            }
            o = light == 0xffffffffu ? vec3(0.0) : scene.lights[light].pos_kind.xyz;
            d = uniform_sphere(rnd2(rng));
            beta = light == 0xffffffffu ? vec3(0.0) : vec3(1.0);
            depth = 0u;
            collisions = 0u;
            segs0 = 0u;
            truncated = false;
            in_flight = true;
            ev_splat = false;
            // The material of the object holding the light (the nearest surface from inside an
            // object is its own: objects are disjoint and do not nest).
            path_mat = 0u;
            if (HAS_MESH && light != 0xffffffffu) {
                float th;
                uint tri;
                if (mesh_hit_tri(o, normalize(vec3(0.5773, 0.5774, 0.5773503)), 0.0, INF, th, tri)) path_mat = triangle_material(tri);
            }
        }
        iters++;
        // A paused event (a free flight or a camera connection) is resumed whatever beta is.
        bool fresh = !ev_splat && !trk_resume;
        int r = fresh && max3(beta) <= 0.0 ? EVENT_ENDED : advance(o, d, beta, emitted_weight(light), depth, rng);
        if (r == EVENT_PAUSED) break;
        ev_splat = false;
        bool ended = r == EVENT_ENDED || truncated;
        if (ended) {
            if (truncated) trunc_count++;
            segs += collisions - segs0 + 1u;
            segs0 = 0u;
            collisions = 0u;
            k++;
            in_flight = false;
        }
    }
    if (in_flight) segs += collisions - segs0;
    uint flags = (in_flight ? FLAG_IN_FLIGHT : 0u) | (truncated ? FLAG_TRUNCATED : 0u)
               | (trk_paused ? FLAG_TRACKING : 0u) | (ev_splat ? FLAG_SPLAT : 0u) | (path_mat << 8u);
    vec4 ta, tb, tc;
    track_save(ta, tb, tc);
    state[slot_index] = LightState(vec4(o, uintBitsToFloat(light)), vec4(d, uintBitsToFloat(depth)),
                                   vec4(beta, uintBitsToFloat(rng.x)), uvec4(k, flags, collisions, rng.y), ta, tb, tc,
                                   track_save_mesh());
    if (trunc_count > 0u) atomicAdd(stats[0], trunc_count);
    atomicAdd(stats[1], segs);
    atomicMax(stats[2], iters);
    if (LOOP_LIMITED) atomicMax(stats[STATS_BATCH_WORD], BATCH_COUNT);
    if (in_flight || k < pc.sample_end) atomicAdd(stats[3u + pc.slot], 1u);
    if (splat_clamped > 0u) atomicAdd(lstats[0], splat_clamped);
    if (sum_overflow > 0u) atomicAdd(lstats[1], sum_overflow);
    if (splat_count > 0u) atomicAdd(lstats[2], splat_count);
}
