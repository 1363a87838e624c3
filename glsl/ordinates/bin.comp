#version 460
// ordinates/bin: each voxel's first-scattering source at the M storage directions (thesis
// 5.2), from its once-scattered power per beam (ordinates/deposit.comp). The light of beam b
// travels along d (a parallel beam's direction, or away from a point light through the voxel
// centre) and is shared as
//   share_m = w_m p'(d . m) / sum_m' w_m' p'(d . m'),   sum_m share_m = 1,
// p' Henyey-Greenstein of the asymmetry g' whose shares have mean cosine g as swept (the
// storage directions' footprints f_m): src/physics/angular.rs, StorageMap::shares, which the
// host computes for parallel beams; for a point light's beam it is found here by the same
// bisection. Emission per unit volume and sr: F_m = sum_b E_b share_m / (w_m lambda^3).
// One slab of whole layers at a time (deposit.comp): voxel v of the slab is base + v of the grid;
// and one group of beams at a time, beam0 .. beam0 + beam_count, added in order to what the
// groups before left (the same additions in the same order as one pass over all the beams).
// The sums are the source the first sweep propagates: the thesis's G'' initialised with G_dir
// (5.3.3's progressive scheme; glsl/ordinates/scatter.comp).
#extension GL_GOOGLE_include_directive : require
#include "../include/phase.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;
// After the work group size: linear.glsl reads gl_WorkGroupSize.
#include "../include/linear.glsl"
layout(std430, binding = 0) readonly buffer Accum { uint acc[]; };          // [c][beam][voxel], fixed point
layout(std430, binding = 1) readonly buffer Beams { vec4 beams[]; };        // 2 per beam: (xyz, 0 parallel / 1 point), (g', -, -, -)
layout(std430, binding = 2) readonly buffer Storage { vec4 storage_dirs[]; }; // xyz, w weight (sr)
layout(std430, binding = 3) readonly buffer Footprint { vec4 footprint[]; }; // xyz per storage direction
layout(std430, binding = 4) buffer Source { float source[]; };              // [c][m][voxel]

layout(push_constant) uniform Push {
    uvec4 dims;      // the grid's voxels xyz, w = the slab's voxels V (the grid's when whole)
    vec4 grid;       // xyz the grid's lower corner, w lambda
    uint beam_count; // B: the group's beams
    uint storage;    // M
    uint channels;
    float scale;     // fixed-point quanta per W
    float g;         // the medium's asymmetry
    uint base;       // the slab's first voxel
    uint beam0;      // the group's first beam (0: the first group, which starts the sums)
    float peak_share; // dom.delta_m: HG(g)'s mass within the cone of peak_cos (0: no split)
    float peak_cos;   // the storage set's covering radius, as a cosine
    uint pad0, pad1, pad2;
} pc;

const float G_LIMIT = 0.9999;

float mean_cosine(vec3 d, float g) {
    float norm = 0.0, mc = 0.0;
    for (uint m = 0u; m < pc.storage; ++m) {
        float s = storage_dirs[m].w * hg_eval(g, dot(d, storage_dirs[m].xyz));
        norm += s;
        mc += s * dot(d, footprint[m].xyz);
    }
    return mc / norm;
}

float matched_g(vec3 d) {
    if (pc.g == 0.0 || pc.storage == 1u) return pc.g;
    float lo = -G_LIMIT, hi = G_LIMIT;
    if (mean_cosine(d, hi) <= pc.g) return hi;
    if (mean_cosine(d, lo) >= pc.g) return lo;
    for (int i = 0; i < 32; ++i) {
        float mid = 0.5 * (lo + hi);
        if (mean_cosine(d, mid) < pc.g) lo = mid; else hi = mid;
    }
    return 0.5 * (lo + hi);
}

void main() {
    uint v = linear_id();
    uint V = pc.dims.w;
    if (v >= V) return;
    uint M = pc.storage;
    uint gv = pc.base + v;
    ivec3 p = ivec3(gv % pc.dims.x, (gv / pc.dims.x) % pc.dims.y, gv / (pc.dims.x * pc.dims.y));
    vec3 centre = pc.grid.xyz + (vec3(p) + 0.5) * pc.grid.w;
    float per_volume = 1.0 / (pc.scale * pc.grid.w * pc.grid.w * pc.grid.w);
    if (pc.beam0 == 0u)
        for (uint c = 0u; c < pc.channels; ++c)
            for (uint m = 0u; m < M; ++m) source[(c * M + m) * V + v] = 0.0;
    for (uint b = 0u; b < pc.beam_count; ++b) {
        vec3 e = vec3(0.0);
        bool any_light = false;
        for (uint c = 0u; c < pc.channels; ++c) {
            e[c] = float(acc[(c * pc.beam_count + b) * V + v]) * per_volume;
            any_light = any_light || e[c] > 0.0;
        }
        if (!any_light) continue;
        vec4 a = beams[2u * (pc.beam0 + b)];
        vec3 away = centre - a.xyz;
        // A point light at the voxel centre lights it from every side: isotropic shares.
        bool at_light = a.w != 0.0 && dot(away, away) < 1e-12 * pc.grid.w * pc.grid.w;
        vec3 d = a.w == 0.0 ? a.xyz : (at_light ? vec3(0.0, 0.0, 1.0) : normalize(away));
        if (pc.peak_share > 0.0 && !at_light) {
            // With dom.delta_m the shares split HG(g) at a cone about d of the storage set's
            // covering radius, as scatter.comp's gather does: HG's mass inside the cone goes to
            // the directions inside it (weighted by their closeness), the rest by HG(g) itself,
            // normalised to the rest of the mass. The mean-cosine match below spreads a peak the
            // set does not resolve by lowering g', and so thickens the tail that the light
            // scattered back toward a back-lit camera comes from.
            float pn = 0.0, tn = 0.0;
            for (uint m = 0u; m < M; ++m) {
                float cm = dot(d, storage_dirs[m].xyz);
                if (cm > pc.peak_cos) pn += storage_dirs[m].w * (cm - pc.peak_cos);
                else tn += storage_dirs[m].w * hg_eval(pc.g, cm);
            }
            float ps = tn > 0.0 ? pc.peak_share : 1.0;
            if (pn > 0.0) {
                for (uint m = 0u; m < M; ++m) {
                    float cm = dot(d, storage_dirs[m].xyz);
                    float per_sr = cm > pc.peak_cos ? ps * (cm - pc.peak_cos) / pn : (1.0 - ps) * hg_eval(pc.g, cm) / tn;
                    for (uint c = 0u; c < pc.channels; ++c) source[(c * M + m) * V + v] += e[c] * per_sr;
                }
                continue;
            }
        }
        float g = a.w == 0.0 ? beams[2u * (pc.beam0 + b) + 1u].x : (at_light ? 0.0 : matched_g(d));
        float norm = 0.0;
        for (uint m = 0u; m < M; ++m) norm += storage_dirs[m].w * hg_eval(g, dot(d, storage_dirs[m].xyz));
        for (uint m = 0u; m < M; ++m) {
            // share_m / w_m: the emission per sr.
            float per_sr = hg_eval(g, dot(d, storage_dirs[m].xyz)) / norm;
            for (uint c = 0u; c < pc.channels; ++c) source[(c * M + m) * V + v] += e[c] * per_sr;
        }
    }
}
