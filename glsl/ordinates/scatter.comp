#version 460
// ordinates/scatter: after a sweep of channel c, every voxel turns its swept field I_s (all N
// propagation directions) into
//  1. the source the next sweep propagates, Q'_m = sigma_s sum_s A[s][m] I_s, with A the
//     quadrature-normalised phase function of src/physics/angular.rs (sum_m w_m A[s][m] = w_s,
//     so what is stored carries sigma_s phi exactly). This is the thesis's progressive scheme
//     (5.3.3): a sweep propagates only the source the previous iteration scattered (its G''),
//     the sweep's scattering is the next one (its G'), and the solution is their sum (its G).
//     The first sweep propagates the first-scattering source (G'' = G_dir, glsl/ordinates/
//     bin.comp), so sweep n carries the light scattered n times and each iteration's fluence
//     is that bounce's alone: what convergence and the geometric tail measure (src/solvers/
//     dom.rs), exactly rather than as a difference of two nearly equal totals;
//  2. the light it scatters toward the camera (thesis 5.3.5's view gathering), as the fluence
//     the view pass scatters isotropically: 4 pi sum_s w_s p(s . o) I_s / sum_s w_s p(s . o),
//     o the direction from the voxel centre to the camera, times lambda^2 (the view pass reads
//     energy per voxel), added to what the bounces before gathered. The normalisation makes an
//     isotropic field gather to its own fluence. G itself is needed only for this view, so
//     the view's sum is kept (one float per voxel and channel) instead of the M of G.
// One invocation takes VOXELS consecutive voxels and sums BLOCK storage directions at a time in
// registers (register blocking): one read of the field feeds BLOCK accumulators, and one read of
// a matrix entry (the same for the whole work group) feeds VOXELS voxels. Each accumulator sums
// A[s][m] I_s over s in ascending order exactly as one accumulator per direction and voxel did,
// so the sums are the same bits whatever the block or chunk. On lavapipe a read from a buffer is
// a loop over the SIMD lanes, and it is what the blocks save: product-16x32 stored at itself on
// the 8^3 cube went from 1.10 s a pass (a direction at a time) to 0.13 s (docs/dom.md, "The
// scattering pass"). Consecutive voxels, so that where nothing scatters (a cloud's empty edges)
// whole invocations store zeros and return; up to s8 an invocation per voxel with its field in a
// local array was the layout until 2026-12-07, 1.5-2.7x slower (the same docs).
// Storage directions come in chunks of `pc.chunk` (work group y) that keep an invocation's loop
// back-edges under glsl/include/budget.glsl's LOOP_GUARD (src/solvers/dom/ordinates.rs,
// scatter_shape): one invocation scattering a voxel into all M directions ran N M of them, and
// past 65535 llvmpipe ended its loops silently (product-16x16 stored at itself, N M = 65536: the
// second bounce's fluence 1.3x the CPU oracle's; product-16x32, 262144: 12.6x, the stale first
// source swept again each iteration). The first chunk also gathers the light toward the camera.
// Directions in a fixed order: deterministic.
#extension GL_GOOGLE_include_directive : require
#include "../include/phase.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;
// After the work group size: linear.glsl reads gl_WorkGroupSize.
#include "../include/linear.glsl"

// Storage directions an invocation sums in one pass over the field.
const uint BLOCK = 8u;
// Consecutive voxels an invocation takes.
const uint VOXELS = 8u;

layout(std430, binding = 0) readonly buffer Field { float field[]; };     // [octant][its direction][voxel]
layout(std430, binding = 1) readonly buffer Dirs { vec4 dirs[]; };        // by octant: xyz, w weight (sr)
layout(std430, binding = 2) readonly buffer Scatter { float scatter[]; }; // A[s][m]
layout(std430, binding = 3) readonly buffer SigmaS { float sigma_s[]; };  // [c][voxel], 1/unit
layout(std430, binding = 4) writeonly buffer Source { float source[]; };  // [c][m][voxel]
layout(std430, binding = 5) buffer Camera { float camera[]; };            // [c][voxel], summed over bounces

// dom's convergence test on the device (ordinates/converge.comp): word 0 set once the iteration
// has converged, after which the rest of a submitted batch returns at once.
layout(std430, binding = 6) readonly buffer Control { uint ctrl_stopped; };

layout(push_constant) uniform Push {
    uvec4 dims;      // voxels xyz, w = voxel count
    uint storage;    // M
    uint channel;    // c
    uint slots;      // field slots per octant
    float g;         // Henyey-Greenstein asymmetry
    uvec4 octants[2]; // per octant: first direction | count << 16
    vec4 grid;       // xyz the grid's lower corner, w lambda (voxel edge)
    vec4 eye;        // xyz the camera's position (w = 0) or the direction toward it (w = 1)
    uint chunk;      // storage directions per invocation (dispatch y covers ceil(M / chunk))
    uint directions; // N
    float peak_share; // dom.delta_m: HG(g)'s mass within the cone of peak_cos (0: no split)
    float peak_cos;   // the cone about the camera's direction within which the field is interpolated
    float pad_f;
    uint pad0, pad1, pad2;
} pc;

// The direction from voxel v's centre toward the camera.
vec3 eye_direction(uint v) {
    ivec3 p = ivec3(v % pc.dims.x, (v / pc.dims.x) % pc.dims.y, v / (pc.dims.x * pc.dims.y));
    vec3 centre = pc.grid.xyz + (vec3(p) + 0.5) * pc.grid.w;
    return pc.eye.w != 0.0 ? pc.eye.xyz : normalize(pc.eye.xyz - centre);
}

// One direction d's radiance at a voxel into its gathered sums (`gather` below, per direction).
void gather_add(vec4 d, float radiance, vec3 to_eye, inout float gathered, inout float norm, inout float peak,
                inout float peak_norm) {
    // With dom.delta_m the gather splits HG(g) at a cone about the camera's direction o, the
    // set's covering radius (peak_cos): its mass inside the cone, peak_share (HG's own
    // distribution), is the field interpolated at o from the directions inside it; outside,
    // where the set resolves the lobe, HG(g) weighs the field as before, normalised to the
    // rest of the mass. HG(g) normalised on the whole set weighs the far field by
    // 1 / sum w p too much wherever the lobe is narrower than the set's spacing and o falls
    // between directions: at g 0.99 on product-16x32 the light scattered more than once toward
    // a back-lit camera came out 1.9x path's energy.
    float cos_eye = dot(d.xyz, to_eye);
    if (pc.peak_share > 0.0 && cos_eye > pc.peak_cos) {
        float wp = d.w * (cos_eye - pc.peak_cos);
        peak += wp * radiance;
        peak_norm += wp;
    } else {
        float w = d.w * hg_eval(pc.g, cos_eye);
        gathered += w * radiance;
        norm += w;
    }
}

// The gathered sums of voxel v added to its light toward the camera.
void gather_store(uint v, uint V, uint c, float gathered, float norm, float peak, float peak_norm) {
    // The gathered light is kept where nothing scatters too: the view pass interpolates
    // between voxel centres, and a medium's edge lies between an empty voxel and a full one.
    if (pc.peak_share > 0.0 && peak_norm > 0.0) {
        float rest = norm > 0.0 ? gathered / norm : peak / peak_norm;
        float light = pc.peak_share * peak / peak_norm + (1.0 - pc.peak_share) * rest;
        camera[c * V + v] += 4.0 * PI * light * pc.grid.w * pc.grid.w;
    } else if (norm > 0.0) {
        camera[c * V + v] += 4.0 * PI * gathered / norm * pc.grid.w * pc.grid.w;
    }
}

// Gather voxel v's light toward the camera on its own (the first chunk's invocations whose
// voxels scatter nothing; the others gather in their pass over the field, scatter_voxels).
void gather(uint v, uint V, uint c) {
    vec3 to_eye = eye_direction(v);
    float gathered = 0.0, norm = 0.0;
    float peak = 0.0, peak_norm = 0.0;
    for (uint o = 0u; o < 8u; ++o) {
        uint packed = pc.octants[o / 4u][o % 4u];
        uint first_dir = packed & 0xffffu, count = packed >> 16;
        for (uint k = 0u; k < count; ++k)
            gather_add(dirs[first_dir + k], field[(o * pc.slots + k) * V + v], to_eye, gathered, norm, peak, peak_norm);
    }
    gather_store(v, V, c, gathered, norm, peak, peak_norm);
}

// The block's columns of A from storage direction m; past the last direction (M not a multiple
// of BLOCK) they repeat it, and those sums are not stored.
void block_columns(uint m, uint M, out uvec4 lo, out uvec4 hi) {
    lo = min(uvec4(m) + uvec4(0u, 1u, 2u, 3u), uvec4(M - 1u));
    hi = min(uvec4(m) + uvec4(4u, 5u, 6u, 7u), uvec4(M - 1u));
}

// Source of storage direction `row` ([c][m]) at voxel v: sigma_s times its sum, and 0 where
// nothing scatters (no source for the next bounce).
void store(uint row, uint v, uint V, float sigma, float sum) {
    source[row * V + v] = sigma > 0.0 ? sigma * sum : 0.0;
}

// One storage direction's sums at the invocation's voxels (v0 + j, j < VOXELS), whose sigma_s
// are sigma_lo (voxels 0-3) and sigma_hi (4-7).
void store_voxels(uint row, uint v0, uint V, vec4 sigma_lo, vec4 sigma_hi, vec4 lo, vec4 hi) {
    for (uint j = 0u; j < VOXELS; ++j) {
        uint v = v0 + j;
        if (v >= V) return;
        store(row, v, V, j < 4u ? sigma_lo[j] : sigma_hi[j - 4u], j < 4u ? lo[j] : hi[j - 4u]);
    }
}

// Column i of the block (matrix entry a) times the field of the invocation's voxels
// (f_lo: voxels 0-3, f_hi: 4-7), into acc_lo[i] and acc_hi[i]. Every index constant, so the
// accumulators stay in registers (an array indexed at run time lives in memory, which llvmpipe
// reads lane by lane).
#define COLUMN(i, a) { float a_ = (a); acc_lo[i] += a_ * f_lo; acc_hi[i] += a_ * f_hi; }
#define STORE(i) if (m + i < m1) store_voxels(c * M + m + i, v0, V, sigma_lo, sigma_hi, acc_lo[i], acc_hi[i]);

// One direction's field at the invocation's voxels (f_lo: voxels 0-3, f_hi: 4-7) into the
// block's accumulators.
#define BLOCK_DIRECTION() \
    uint f = (o * pc.slots + k) * V; \
    vec4 f_lo = vec4(field[f + vox_lo.x], field[f + vox_lo.y], field[f + vox_lo.z], field[f + vox_lo.w]); \
    vec4 f_hi = vec4(field[f + vox_hi.x], field[f + vox_hi.y], field[f + vox_hi.z], field[f + vox_hi.w]); \
    uint row = (first_dir + k) * M; \
    COLUMN(0, scatter[row + lo.x]) COLUMN(1, scatter[row + lo.y]) COLUMN(2, scatter[row + lo.z]) COLUMN(3, scatter[row + lo.w]) \
    COLUMN(4, scatter[row + hi.x]) COLUMN(5, scatter[row + hi.y]) COLUMN(6, scatter[row + hi.z]) COLUMN(7, scatter[row + hi.w])

// Voxel j's gathered sums take direction d's radiance r (the field just read).
#define GATHER(j, r) gather_add(d, r, to_eye[j], g_sum[j], g_norm[j], g_peak[j], g_peak_norm[j]);

// VOXELS voxels an invocation, the field read from the buffer once per block. The first chunk
// (m0 = 0) also gathers its voxels' light toward the camera from the same reads of the field:
// per voxel the sums gather() takes, in the same order (the same bits), its direction to the
// eye and sums in registers. Gathering in a pass of its own read the field and the directions
// again for each voxel: at M = 1 (the deep cube of tests/animate_tests.rs) that was most of
// the pass.
void scatter_voxels(uint V, uint M, uint c, uint m0, uint m1) {
    uint id = linear_id_z();
    uint v0 = id * VOXELS;
    if (v0 >= V) return;
    // Voxels past the grid's end read the last one's field and store nothing.
    uvec4 vox_lo = min(uvec4(v0) + uvec4(0u, 1u, 2u, 3u), uvec4(V - 1u));
    uvec4 vox_hi = min(uvec4(v0) + uvec4(4u, 5u, 6u, 7u), uvec4(V - 1u));
    // Their sigma_s, read once for every block's stores.
    vec4 sigma_lo = vec4(sigma_s[c * V + vox_lo.x], sigma_s[c * V + vox_lo.y], sigma_s[c * V + vox_lo.z], sigma_s[c * V + vox_lo.w]);
    vec4 sigma_hi = vec4(sigma_s[c * V + vox_hi.x], sigma_s[c * V + vox_hi.y], sigma_s[c * V + vox_hi.z], sigma_s[c * V + vox_hi.w]);
    // Nothing scatters at any of them: the zeros the sums would store, without the sums (the
    // light toward the camera gathered on its own).
    if (all(lessThanEqual(max(sigma_lo, sigma_hi), vec4(0.0)))) {
        if (m0 == 0u) {
            for (uint j = 0u; j < VOXELS; ++j) {
                if (v0 + j >= V) break;
                gather(v0 + j, V, c);
            }
        }
        for (uint m = m0; m < m1; ++m) store_voxels(c * M + m, v0, V, sigma_lo, sigma_hi, vec4(0.0), vec4(0.0));
        return;
    }
    for (uint m = m0; m < m1; m += BLOCK) {
        uvec4 lo, hi;
        block_columns(m, M, lo, hi);
        vec4 acc_lo[BLOCK] = vec4[BLOCK](vec4(0.0), vec4(0.0), vec4(0.0), vec4(0.0), vec4(0.0), vec4(0.0), vec4(0.0), vec4(0.0));
        vec4 acc_hi[BLOCK] = acc_lo;
        // Two loops, not a test inside one: llvmpipe runs code its lanes have left, masked
        // (measured after a return, docs/lavapipe.md), so a test in the loop would likely have
        // every chunk pay for the gather at each direction.
        if (m == 0u) {
            vec3 to_eye[VOXELS];
            float g_sum[VOXELS], g_norm[VOXELS], g_peak[VOXELS], g_peak_norm[VOXELS];
            for (uint j = 0u; j < VOXELS; ++j) {
                to_eye[j] = eye_direction(min(v0 + j, V - 1u));
                g_sum[j] = 0.0; g_norm[j] = 0.0; g_peak[j] = 0.0; g_peak_norm[j] = 0.0;
            }
            for (uint o = 0u; o < 8u; ++o) {
                uint packed = pc.octants[o / 4u][o % 4u];
                uint first_dir = packed & 0xffffu, count = packed >> 16;
                for (uint k = 0u; k < count; ++k) {
                    BLOCK_DIRECTION()
                    vec4 d = dirs[first_dir + k];
                    GATHER(0, f_lo.x) GATHER(1, f_lo.y) GATHER(2, f_lo.z) GATHER(3, f_lo.w)
                    GATHER(4, f_hi.x) GATHER(5, f_hi.y) GATHER(6, f_hi.z) GATHER(7, f_hi.w)
                }
            }
            for (uint j = 0u; j < VOXELS; ++j) {
                if (v0 + j >= V) break;
                gather_store(v0 + j, V, c, g_sum[j], g_norm[j], g_peak[j], g_peak_norm[j]);
            }
        } else {
            for (uint o = 0u; o < 8u; ++o) {
                uint packed = pc.octants[o / 4u][o % 4u];
                uint first_dir = packed & 0xffffu, count = packed >> 16;
                for (uint k = 0u; k < count; ++k) {
                    BLOCK_DIRECTION()
                }
            }
        }
        STORE(0) STORE(1) STORE(2) STORE(3) STORE(4) STORE(5) STORE(6) STORE(7)
    }
}

void main() {
    if (ctrl_stopped != 0u) return;
    // The chunk is the work group's (gl_WorkGroupID.y, the same for all its invocations): the
    // matrix entries each pass reads are then the same for the whole group.
    uint M = pc.storage;
    uint m0 = gl_WorkGroupID.y * pc.chunk;
    if (m0 >= M) return;
    uint m1 = min(M, m0 + pc.chunk);
    scatter_voxels(pc.dims.w, M, pc.channel, m0, m1);
}
