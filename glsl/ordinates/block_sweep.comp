#version 460
// ordinates/block_sweep: one octant's sweep of a set of blocks of the grid (thesis 5.3.3-5.3.4:
// blocks as work groups, a wavefront of voxels inside each block). The host dispatches the
// blocks of one block plane (bx + by + bz = W in the octant's own block coordinates) at a time,
// so every block's upwind neighbours were swept by an earlier dispatch; their outgoing faces are
// the block's incoming ones. Each block lives in one slot of the pool (src/solvers/blocks.rs),
// a record of its extinction, stored source, accumulators and outgoing faces, so the same
// kernel runs whether the whole grid is resident or streams through a small pool: the image is
// bit-identical either way.
//
// Inside a block the voxels of plane i + j + k = w (block-local, counted from the upwind corner)
// depend only on plane w - 1: each column (i, j) keeps its last outgoing face radiances per
// direction in the work group's scratch, double-buffered by plane parity; a voxel takes all the
// octant's directions in turn, summing its accumulators in registers. The voxel update
// is sweep.comp's (and the CPU oracle's, src/physics/ordinates.rs): the step difference or step
// characteristics (thesis 5.3.1-5.3.2), both never negative and conservative.
//
// Per voxel the kernel adds, in a fixed order (octants in turn, directions in order, one
// invocation per voxel and octant): the fluence w I, the scattered source
// sum_s A[s][m] I_s at each storage direction (src/physics/angular.rs), and the light toward
// the camera sum_s w_s p(s . o) I_s. After the last octant (7) each block finishes its voxels
// as scatter.comp does (the thesis's progressive scheme, 5.3.3): the next sweep's source is
// this one's scattering, Q'_m = sigma_s sum_s A[s][m] I_s (its G' becoming G''), and
// 4 pi gathered / norm lambda^2 is added to the light toward the camera of the bounces before
// (what the view reads of G). Deterministic: no atomics.
#extension GL_GOOGLE_include_directive : require
#include "../include/phase.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;


layout(std430, binding = 0) buffer Pool { float pool[]; };                // slots x record
layout(std430, binding = 1) readonly buffer Dirs { vec4 dirs[]; };        // by octant: xyz, w weight (sr)
layout(std430, binding = 2) readonly buffer Upsample { float upsample[]; }; // [s][m] (mode 2)
// Binding 3: the characteristics' factors per direction (characteristics.glsl's uniform block).
#define GEOMETRY_BINDING 3
layout(std430, binding = 4) readonly buffer Scatter { float scatter[]; };   // A[s][m]
// Per work group: (slot, upwind slot along x, y, z or ~0u), (lower corner xyz, edges packed).
layout(std430, binding = 5) readonly buffer Work { uvec4 work[]; };
// Per work group of a dispatch: its columns' last outgoing faces, [2][3][S][B^2] (coherent: the
// work group's invocations read each other's through the barrier between planes).
layout(std430, binding = 6) coherent buffer Scratch { float scratch[]; };

layout(push_constant) uniform Push {
    uvec4 dims;       // grid voxels xyz, w = block edge B
    uvec4 layout_;    // record floats; channels C; storage M; slots S (directions per octant at most)
    uvec4 octant;     // x: octant o; y: its first direction; z: its count; w: first work item
    uvec4 modes;      // x: channel c; y: storage mode (0: M = 1, 1: swept set, 2: upsampled); z: scheme; w: directions N
    vec4 grid;        // xyz the grid's lower corner, w lambda (voxel edge)
    vec4 eye;         // xyz the camera's position (w = 0) or the direction toward it (w = 1)
    float g;          // Henyey-Greenstein asymmetry
    float pad0, pad1, pad2;
} pc;


#include "../include/characteristics.glsl"

// Record layout (floats, Bv = B^3 voxels, x fastest, F = B^2): sigma_t [C][Bv], sigma_s [C][Bv],
// source [C][M][Bv] (G''), scattered [C][M][Bv] (G'), fluence [C][Bv] (this bounce's),
// gathered [C][Bv], camera [C][Bv] (all bounces'), then the outgoing faces of the current
// channel and octant [3][S][F].
uint bv() { return pc.dims.w * pc.dims.w * pc.dims.w; }
uint off_sigma_t(uint c) { return c * bv(); }
uint off_sigma_s(uint c) { return (pc.layout_.y + c) * bv(); }
uint off_source(uint c, uint m) { return (2u * pc.layout_.y + c * pc.layout_.z + m) * bv(); }
uint off_scattered(uint c, uint m) { return ((2u + pc.layout_.z) * pc.layout_.y + c * pc.layout_.z + m) * bv(); }
uint off_fluence(uint c) { return ((2u + 2u * pc.layout_.z) * pc.layout_.y + c) * bv(); }
uint off_gathered(uint c) { return ((3u + 2u * pc.layout_.z) * pc.layout_.y + c) * bv(); }
uint off_camera(uint c) { return ((4u + 2u * pc.layout_.z) * pc.layout_.y + c) * bv(); }
uint off_faces(uint axis, uint k) { return (5u + 2u * pc.layout_.z) * pc.layout_.y * bv() + (axis * pc.layout_.w + k) * pc.dims.w * pc.dims.w; }

// A voxel's index on the face across `axis` (the two other block-local coordinates).
uint face_index(int axis, ivec3 l) {
    uint B = pc.dims.w;
    return axis == 0 ? uint(l.y) + B * uint(l.z) : (axis == 1 ? uint(l.x) + B * uint(l.z) : uint(l.x) + B * uint(l.y));
}

// The storage directions whose scattered source a voxel sums in a local array (product-8x16).
const uint MAX_LOCAL = 128u;

void main() {
    uint B = pc.dims.w;
    uvec4 w0 = work[2u * (pc.octant.w + gl_WorkGroupID.x)];
    uvec4 w1 = work[2u * (pc.octant.w + gl_WorkGroupID.x) + 1u];
    uint base = w0.x * pc.layout_.x;
    uint up[3] = uint[3](w0.y, w0.z, w0.w);
    ivec3 lo = ivec3(w1.xyz);
    ivec3 ext = ivec3(w1.w & 0xffu, (w1.w >> 8) & 0xffu, (w1.w >> 16) & 0xffu);
    uint o = pc.octant.x;
    uint first_dir = pc.octant.y, count = pc.octant.z;
    uint c = pc.modes.x, M = pc.layout_.z, mode = pc.modes.y, S = pc.layout_.w;
    ivec3 sgn = ivec3((o & 1u) != 0u ? -1 : 1, (o & 2u) != 0u ? -1 : 1, (o & 4u) != 0u ? -1 : 1);
    int planes = ext.x + ext.y + ext.z - 2;
    float h = pc.grid.w;
    // This work group's column faces: [parity][axis][direction][column].
    uint sbase = gl_WorkGroupID.x * 6u * S * B * B;
    bool start = o == 0u;
    for (int w = 0; w < planes; ++w) {
        uint cur = uint(w) & 1u, prev = cur ^ 1u;
        // The plane's voxels, enumerated row by row (x), so no invocation idles on a column the
        // plane misses.
        int a_lo = max(0, w - (ext.y - 1) - (ext.z - 1)), a_hi = min(ext.x - 1, w);
        for (uint idx = gl_LocalInvocationID.x;; idx += gl_WorkGroupSize.x) {
            ivec3 l = ivec3(-1);
            uint left = idx;
            for (int la = a_lo; la <= a_hi; ++la) {
                int b_lo = max(0, w - la - (ext.z - 1)), b_hi = min(ext.y - 1, w - la);
                uint n = uint(max(0, b_hi - b_lo + 1));
                if (left < n) {
                    l = ivec3(la, b_lo + int(left), 0);
                    break;
                }
                left -= n;
            }
            if (l.x < 0) break;
            l.z = w - l.x - l.y;
            // Block-local voxel (x fastest, stride B) from octant-local coordinates.
            ivec3 q = ivec3(sgn.x > 0 ? l.x : ext.x - 1 - l.x,
                            sgn.y > 0 ? l.y : ext.y - 1 - l.y,
                            sgn.z > 0 ? l.z : ext.z - 1 - l.z);
            uint vb = uint(q.x) + B * (uint(q.y) + B * uint(q.z));
            uint col = uint(l.x) + B * uint(l.y);
            float st = pool[base + off_sigma_t(c) + vb];
            vec3 centre = pc.grid.xyz + (vec3(lo + q) + 0.5) * h;
            vec3 to_eye = pc.eye.w != 0.0 ? pc.eye.xyz : normalize(pc.eye.xyz - centre);
            float fluence = 0.0, gathered = 0.0;
            float scattered[MAX_LOCAL];
            bool local_sum = M <= MAX_LOCAL;
            if (local_sum) for (uint m = 0u; m < M; ++m) scattered[m] = 0.0;
            for (uint k = 0u; k < count; ++k) {
                uint s = first_dir + k;
                vec4 d = dirs[s];
                vec3 a = abs(d.xyz);
                float src;
                if (mode == 0u) {
                    src = pool[base + off_source(c, 0u) + vb];
                } else if (mode == 1u) {
                    src = pool[base + off_source(c, s) + vb];
                } else {
                    src = 0.0;
                    for (uint m = 0u; m < M; ++m) src += upsample[s * M + m] * pool[base + off_source(c, m) + vb];
                }
                // Incoming radiances: the upwind column's last face inside the block, the upwind
                // block's outgoing face on its edge, nothing at the grid's faces (vacuum).
                float l_in[3];
                for (int axis = 0; axis < 3; ++axis) {
                    l_in[axis] = 0.0;
                    if (l[axis] > 0) {
                        ivec3 u = l;
                        u[axis] -= 1;
                        l_in[axis] = scratch[sbase + ((prev * 3u + uint(axis)) * S + k) * B * B + uint(u.x) + B * uint(u.y)];
                    } else if (up[axis] != 0xffffffffu) {
                        l_in[axis] = pool[up[axis] * pc.layout_.x + off_faces(uint(axis), k) + face_index(axis, l)];
                    }
                }
                float radiance;
                float out_face[3];
                if (pc.modes.z == 0u) {
                    // Step difference: the upwind voxels' mean radiances are the faces.
                    float inflow = 0.0;
                    for (int axis = 0; axis < 3; ++axis) inflow += a[axis] * l_in[axis];
                    radiance = (src + inflow / h) / (st + (a.x + a.y + a.z) / h);
                    out_face = float[3](radiance, radiance, radiance);
                } else {
                    for (int axis = 0; axis < 3; ++axis) if (a[axis] == 0.0) l_in[axis] = 0.0;
                    uint gbase = s * 20u;
                    out_face = float[3](0.0, 0.0, 0.0);
                    radiance = 0.0;
                    for (int i = 0; i < 3; ++i) {
                        for (int oo = 0; oo < 3; ++oo) {
                            float f = geometry(gbase + uint(3 * i + oo));
                            if (f == 0.0) continue;
                            float sl = geometry(gbase + 9u + uint(3 * i + oo));
                            float x = st * h * sl;
                            vec2 pp = phi_psi(x);
                            float qh = src * h * sl;
                            out_face[oo] += f * (l_in[i] * exp(-x) + qh * pp.x);
                            radiance += a[oo] * f * sl * (l_in[i] * pp.x + qh * pp.y);
                        }
                    }
                }
                for (int axis = 0; axis < 3; ++axis) {
                    scratch[sbase + ((cur * 3u + uint(axis)) * S + k) * B * B + col] = out_face[axis];
                    if (l[axis] == ext[axis] - 1)
                        pool[base + off_faces(uint(axis), k) + face_index(axis, l)] = out_face[axis];
                }
                fluence += d.w * radiance;
                gathered += d.w * hg_eval(pc.g, dot(d.xyz, to_eye)) * radiance;
                if (local_sum) {
                    for (uint m = 0u; m < M; ++m) scattered[m] += scatter[s * M + m] * radiance;
                } else {
                    for (uint m = 0u; m < M; ++m) {
                        uint sc = base + off_scattered(c, m) + vb;
                        pool[sc] = (start && k == 0u ? 0.0 : pool[sc]) + scatter[s * M + m] * radiance;
                    }
                }
            }
            // The voxel's accumulators, octant by octant; octant 0 starts them.
            uint fl = base + off_fluence(c) + vb;
            pool[fl] = (start ? 0.0 : pool[fl]) + fluence;
            uint ga = base + off_gathered(c) + vb;
            pool[ga] = (start ? 0.0 : pool[ga]) + gathered;
            if (local_sum) {
                for (uint m = 0u; m < M; ++m) {
                    uint sc = base + off_scattered(c, m) + vb;
                    pool[sc] = (start ? 0.0 : pool[sc]) + scattered[m];
                }
            }
        }
        memoryBarrierBuffer();
        barrier();
    }
    if (o != 7u) return;
    // The last octant: this channel's sweep of the block is complete. Finish its voxels.
    uint voxels = uint(ext.x * ext.y * ext.z);
    for (uint i = gl_LocalInvocationID.x; i < voxels; i += gl_WorkGroupSize.x) {
        ivec3 q = ivec3(int(i) % ext.x, (int(i) / ext.x) % ext.y, int(i) / (ext.x * ext.y));
        uint vb = uint(q.x) + B * (uint(q.y) + B * uint(q.z));
        vec3 centre = pc.grid.xyz + (vec3(lo + q) + 0.5) * h;
        vec3 to_eye = pc.eye.w != 0.0 ? pc.eye.xyz : normalize(pc.eye.xyz - centre);
        float norm = 0.0;
        for (uint s = 0u; s < pc.modes.w; ++s) {
            vec4 d = dirs[s];
            norm += d.w * hg_eval(pc.g, dot(d.xyz, to_eye));
        }
        float gathered = pool[base + off_gathered(c) + vb];
        if (norm > 0.0) pool[base + off_camera(c) + vb] += 4.0 * PI * gathered / norm * h * h;
        float sigma = pool[base + off_sigma_s(c) + vb];
        for (uint m = 0u; m < M; ++m)
            pool[base + off_source(c, m) + vb] = sigma > 0.0 ? sigma * pool[base + off_scattered(c, m) + vb] : 0.0;
    }
}
