#version 460
// path/trace: the ground truth. A volumetric path tracer with delta tracking against a
// majorant (analytic for constant/sphere media, a coarse majorant grid for grids), next-event
// estimation with ratio tracking toward every light, a uniformly sampled (importance-sampled
// for a constant environment) environment combined with phase sampling by MIS, HG sampling,
// and unbiased Russian roulette. Chromatic media use spectral tracking (Kutz et al. 2017,
// "Spectral and decomposition tracking", sec. 5) with absorption folded into the weights,
// so no channel is shortcut. One invocation = one pixel. The kernel is resumable (budget.glsl):
// each dispatch advances the pixel's current path by whole scattering events until its loop
// budget is spent, then saves the path state; the host re-dispatches until every pixel has
// finished samples [0, sample_end). Every finished sample adds L and L^2 to the pixel's sums
// (mean and variance of the mean on the host), always in sample order: deterministic.
#extension GL_GOOGLE_include_directive : require

#define SCENE_BINDING 0
#define DENSITY_BINDING 1
#define MAJORANT_BINDING 2
#include "../include/scene.glsl"
#include "../include/rng.glsl"
#include "../include/phase.glsl"
#include "../include/budget.glsl"

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
    uvec4 k_flight;    // next sample index, 1 while a path is in flight, truncated flag, rng counter
};
layout(std430, binding = 5) buffer State { PathState state[]; };

layout(push_constant) uniform Push {
    uint sample_end;      // finish samples [.., sample_end) of every pixel
    uint budget;          // own-counted loop iterations per invocation per dispatch
    uint seed_lo;
    uint seed_hi;
    uint max_depth;       // scattering events; 1 = single scattering; 0xffffffff = unbounded
    uint collision_cap;   // safety cap on tentative collisions per path (reported, not silent)
    uint slot;            // which active counter this dispatch reports into
    uint pad;
} pc;

float phase_eval(float g, float c) { return ANISOTROPIC ? hg_eval(g, c) : INV_4PI; }
vec3 phase_sample(float g, vec3 d, vec2 u) { return ANISOTROPIC ? hg_sample(g, d, u) : uniform_sphere(u); }

uint collisions;
bool truncated;

// Ratio tracking (Novak et al. 2014) of the transmittance from p along w over [0, t_far]:
// T *= sigma_n / sigma_maj per tentative collision, per channel; unbiased for each channel
// since sigma_maj >= max channel sigma_t. Russian roulette on small T stays unbiased.
vec3 transmittance(vec3 p, vec3 w, float t_far, inout uvec2 rng) {
    vec2 iv = medium_interval(p, w);
    iv.x = max(iv.x, 0.0);
    iv.y = min(iv.y, t_far);
    vec3 T = vec3(1.0);
    Segments s = segments_begin(p, w, iv.x, iv.y);
    float t0, t1, smaj;
    while (segments_next(s, t0, t1, smaj)) {
        iters++;
        if (smaj <= 0.0) continue;
        float t = t0;
        while (true) {
            iters++;
            t -= log(1.0 - rnd(rng)) / smaj;
            if (t >= t1) break;
            collisions++;
            vec3 st = scene.sigma_t.xyz * density_at(p + w * t);
            T *= max(vec3(0.0), smaj - st) / smaj;
            float m = max3(T);
            if (m < 0.1) {
                if (rnd(rng) >= 0.5) return vec3(0.0);
                T *= 2.0;
            }
            if (collisions > pc.collision_cap) { truncated = true; return vec3(0.0); }
        }
    }
    return T;
}

// Delta/spectral tracking to the next real scattering event. Returns true and sets `t_hit`
// on a scattering; false when the path escapes (beta then weights the escape) or dies (beta 0).
bool next_scatter(vec3 o, vec3 d, inout vec3 beta, inout uvec2 rng, out float t_hit) {
    vec2 iv = medium_interval(o, d);
    iv.x = max(iv.x, 0.0);
    Segments s = segments_begin(o, d, iv.x, iv.y);
    float t0, t1, smaj;
    while (segments_next(s, t0, t1, smaj)) {
        iters++;
        if (smaj <= 0.0) continue;
        float t = t0;
        while (true) {
            iters++;
            t -= log(1.0 - rnd(rng)) / smaj;
            if (t >= t1) break;
            collisions++;
            if (collisions > pc.collision_cap) { truncated = true; beta = vec3(0.0); return false; }
            vec3 st = scene.sigma_t.xyz * density_at(o + d * t);
            vec3 ss = st * scene.albedo.xyz;
            vec3 sn = max(vec3(0.0), smaj - st);
            if (!CHROMATIC) {
                // Grey: scatter with probability sigma_s / (sigma_s + sigma_n); absorption is
                // carried by the weight (sigma_maj - sigma_a) / sigma_maj, the same on both branches.
                float denom = ss.x + sn.x;
                if (denom <= 0.0) { beta = vec3(0.0); return false; }
                beta *= denom / smaj;
                if (rnd(rng) * denom < ss.x) { t_hit = t; return true; }
            } else {
                // Spectral tracking, history-aware probabilities (Kutz 2017, eq. 15-16).
                float ws = avg3(beta * ss);
                float wn = avg3(beta * sn);
                if (ws + wn <= 0.0) { beta = vec3(0.0); return false; }
                float ps = ws / (ws + wn);
                if (rnd(rng) < ps) {
                    beta *= ss / (smaj * ps);
                    t_hit = t;
                    return true;
                }
                beta *= sn / (smaj * (1.0 - ps));
            }
        }
    }
    return false;
}

// Power heuristic (Veach 1997) for two strategies with one sample each.
float mis_power(float a, float b) { return a * a / (a * a + b * b); }

// One event of a path: free flight to the next scattering (next-event estimation and a new
// direction there) or to its escape. Returns true when the path has ended.
bool advance(inout vec3 o, inout vec3 d, inout vec3 beta, inout vec3 L, inout uint depth, inout float pdf_dir, inout uvec2 rng) {
    uint light_count = scene.image.z;
    float g = scene.albedo.w;
    float t_hit;
    bool scattered = next_scatter(o, d, beta, rng, t_hit);
    if (!scattered) {
        if (max3(beta) > 0.0) {
            for (uint i = 0u; i < light_count; ++i) {
                iters++;
                if (uint(scene.lights[i].pos_kind.w) != LIGHT_ENVIRONMENT) continue;
                // The camera ray sees the environment directly; later escapes share the
                // environment with its next-event estimate by MIS.
                float w = depth == 0u ? 1.0 : mis_power(pdf_dir, INV_4PI);
                L += beta * scene.lights[i].value.rgb * w;
            }
        }
        return true;
    }
    depth++;
    if (depth > pc.max_depth) return true;
    vec3 p = o + d * t_hit;

    // Next-event estimation toward every light, transmittance by ratio tracking.
    for (uint i = 0u; i < light_count; ++i) {
        iters++;
        Light li = scene.lights[i];
        uint kind = uint(li.pos_kind.w);
        if (kind == LIGHT_POINT) {
            vec3 to = li.pos_kind.xyz - p;
            float dist2 = dot(to, to);
            if (dist2 <= 0.0) continue;
            float dist = sqrt(dist2);
            vec3 wi = to / dist;
            vec3 T = transmittance(p, wi, dist, rng);
            L += beta * T * phase_eval(g, dot(d, wi)) * li.value.rgb / dist2;
        } else if (kind == LIGHT_DIRECTIONAL) {
            vec3 wi = -li.pos_kind.xyz;
            vec3 T = transmittance(p, wi, INF, rng);
            L += beta * T * phase_eval(g, dot(d, wi)) * li.value.rgb;
        } else {
            // Uniform direction: the importance sampling of a constant environment.
            vec3 wi = uniform_sphere(rnd2(rng));
            float ph = phase_eval(g, dot(d, wi));
            vec3 T = transmittance(p, wi, INF, rng);
            L += beta * T * ph * li.value.rgb / INV_4PI * mis_power(INV_4PI, ph);
        }
    }

    // Continue by phase sampling: the weight phase/pdf is exactly 1.
    vec3 wo = phase_sample(g, d, rnd2(rng));
    pdf_dir = phase_eval(g, dot(d, wo));
    o = p;
    d = wo;

    // Russian roulette on the throughput; dividing by the survival probability keeps it unbiased.
    if (depth >= 3u) {
        float q = min(1.0, max3(beta));
        if (rnd(rng) >= q) return true;
        beta /= q;
    }
    return false;
}

void main() {
    uvec2 px = gl_GlobalInvocationID.xy;
    uvec2 res = scene.image.xy;
    if (px.x >= res.x || px.y >= res.y) return;
    uint pixel = px.y * res.x + px.x;
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
    bool in_flight = st.k_flight.y != 0u;
    truncated = st.k_flight.z != 0u;
    uint trunc_count = 0u;
    uint segs0 = collisions;
    uint segs = 0u;

    while (iters < pc.budget) {
        if (!in_flight) {
            if (k >= pc.sample_end) break;
            rng = rng_init(pc.seed_lo, pc.seed_hi, pixel, k);
            vec2 jitter = rnd2(rng);   // box filter: uniform over the pixel's area
            camera_ray(vec2(px) + jitter, o, d);
            beta = vec3(1.0);
            L = vec3(0.0);
            depth = 0u;
            pdf_dir = 0.0;
            collisions = 0u;
            segs0 = 0u;
            truncated = false;
            in_flight = true;
        }
        iters++;
        bool ended = advance(o, d, beta, L, depth, pdf_dir, rng);
        if (truncated) ended = true;
        if (ended) {
            // Never let a NaN/Inf leave the pass; count it with the truncations so it is reported.
            if (any(isnan(L)) || any(isinf(L))) { L = vec3(0.0); truncated = true; }
            if (truncated) trunc_count++;
            accum[2u * pixel] += vec4(L, 1.0);
            accum[2u * pixel + 1u] += vec4(L * L, 0.0);
            segs += collisions - segs0 + 1u;
            segs0 = 0u;
            collisions = 0u;
            k++;
            in_flight = false;
        }
    }
    if (in_flight) segs += collisions - segs0;
    state[pixel] = PathState(vec4(o, pdf_dir), vec4(d, uintBitsToFloat(depth)), vec4(beta, uintBitsToFloat(rng.x)),
                             vec4(L, uintBitsToFloat(collisions)), uvec4(k, in_flight ? 1u : 0u, truncated ? 1u : 0u, rng.y));
    if (trunc_count > 0u) atomicAdd(stats[0], trunc_count);
    atomicAdd(stats[1], segs);
    atomicMax(stats[2], iters);
    if (in_flight || k < pc.sample_end) atomicAdd(stats[3u + pc.slot], 1u);
}
