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
// One invocation per voxel and chunk of storage directions (y: chunk, `pc.chunk` directions each),
// directions in a fixed order: deterministic. The chunks keep an invocation's loop back-edges
// (about N + chunk (N + 19): src/solvers/dom/ordinates.rs, scatter_chunk) under
// glsl/include/budget.glsl's LOOP_GUARD: one invocation scattering a
// voxel into all M directions ran N M of them, and past 65535 llvmpipe ended its loops silently
// (product-16x16 stored at itself, N M = 65536: the second bounce's fluence 1.3x the CPU
// oracle's; product-16x32, 262144: 12.6x, the stale first source swept again each iteration).
// The first chunk also gathers the light toward the camera.
#extension GL_GOOGLE_include_directive : require
#include "../include/phase.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;
// After the work group size: linear.glsl reads gl_WorkGroupSize.
#include "../include/linear.glsl"

// Directions whose field a voxel keeps in a local array (s8 has 80).
const uint MAX_LOCAL = 96u;

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

void main() {
    if (ctrl_stopped != 0u) return;
    uint v = linear_id_z();
    uint V = pc.dims.w;
    if (v >= V) return;
    uint M = pc.storage;
    uint N = pc.directions;
    uint c = pc.channel;
    uint m0 = gl_GlobalInvocationID.y * pc.chunk;
    if (m0 >= M) return;
    uint m1 = min(M, m0 + pc.chunk);
    bool first_chunk = m0 == 0u;
    bool local = N <= MAX_LOCAL;
    float sigma = sigma_s[c * V + v];
    // The voxel's field, read once (in direction order) when it fits the local array.
    float local_field[MAX_LOCAL];
    if (first_chunk || (local && sigma > 0.0)) {
        ivec3 p = ivec3(v % pc.dims.x, (v / pc.dims.x) % pc.dims.y, v / (pc.dims.x * pc.dims.y));
        vec3 centre = pc.grid.xyz + (vec3(p) + 0.5) * pc.grid.w;
        vec3 to_eye = pc.eye.w != 0.0 ? pc.eye.xyz : normalize(pc.eye.xyz - centre);
        float gathered = 0.0, norm = 0.0;
        // With dom.delta_m the gather splits HG(g) at a cone about the camera's direction o, the
        // set's covering radius (peak_cos): its mass inside the cone, peak_share (HG's own
        // distribution), is the field interpolated at o from the directions inside it; outside,
        // where the set resolves the lobe, HG(g) weighs the field as before, normalised to the
        // rest of the mass. HG(g) normalised on the whole set weighs the far field by
        // 1 / sum w p too much wherever the lobe is narrower than the set's spacing and o falls
        // between directions: at g 0.99 on product-16x32 the light scattered more than once toward
        // a back-lit camera came out 1.9x path's energy.
        float peak = 0.0, peak_norm = 0.0;
        bool split = pc.peak_share > 0.0;
        for (uint o = 0u; o < 8u; ++o) {
            uint packed = pc.octants[o / 4u][o % 4u];
            uint first_dir = packed & 0xffffu, count = packed >> 16;
            for (uint k = 0u; k < count; ++k) {
                vec4 d = dirs[first_dir + k];
                float radiance = field[(o * pc.slots + k) * V + v];
                if (local) local_field[first_dir + k] = radiance;
                float cos_eye = dot(d.xyz, to_eye);
                if (split && cos_eye > pc.peak_cos) {
                    float wp = d.w * (cos_eye - pc.peak_cos);
                    peak += wp * radiance;
                    peak_norm += wp;
                } else {
                    float w = d.w * hg_eval(pc.g, cos_eye);
                    gathered += w * radiance;
                    norm += w;
                }
            }
        }
        // The gathered light is kept where nothing scatters too: the view pass interpolates
        // between voxel centres, and a medium's edge lies between an empty voxel and a full one.
        if (first_chunk && split && peak_norm > 0.0) {
            float rest = norm > 0.0 ? gathered / norm : peak / peak_norm;
            float light = pc.peak_share * peak / peak_norm + (1.0 - pc.peak_share) * rest;
            camera[c * V + v] += 4.0 * PI * light * pc.grid.w * pc.grid.w;
        } else if (first_chunk && norm > 0.0) {
            camera[c * V + v] += 4.0 * PI * gathered / norm * pc.grid.w * pc.grid.w;
        }
    }
    if (sigma <= 0.0) {
        // Nothing scatters here: no source for the next bounce.
        for (uint m = m0; m < m1; ++m) source[(c * M + m) * V + v] = 0.0;
        return;
    }
    for (uint m = m0; m < m1; ++m) {
        float scattered = 0.0;
        if (local) {
            for (uint s = 0u; s < N; ++s) scattered += scatter[s * M + m] * local_field[s];
        } else {
            for (uint o = 0u; o < 8u; ++o) {
                uint packed = pc.octants[o / 4u][o % 4u];
                uint first_dir = packed & 0xffffu, count = packed >> 16;
                for (uint k = 0u; k < count; ++k)
                    scattered += scatter[(first_dir + k) * M + m] * field[(o * pc.slots + k) * V + v];
            }
        }
        source[(c * M + m) * V + v] = sigma * scattered;
    }
}
