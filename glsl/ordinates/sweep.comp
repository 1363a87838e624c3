#version 460
// ordinates/sweep: one wavefront plane of all eight octants of a discrete-ordinates sweep
// (thesis 5.3.3: the voxels with i + j + k = w in an octant's own coordinates depend only on
// its plane w - 1, so a plane is one dispatch; the octants are independent, so they share it,
// gl_WorkGroupID.y being the octant). Each invocation is one voxel of one octant's plane, the
// plane's cells listed by the host (binding 11: only cells on the plane are launched; llvmpipe
// runs a SIMD batch whose lanes have all returned through the rest of the kernel, masked, so a
// square of (i, j) with k = w - i - j mostly off the grid cost nearly what the work did;
// docs/lavapipe.md), and takes every direction of the octant in turn into the octant's own
// fluence slice, so the fluence is summed in a fixed order without atomics (the host adds the
// slices): deterministic.
// The per-voxel update mirrors src/physics/ordinates.rs (the CPU oracle), by pc.scheme:
// 0, step difference: the voxel's balance with its outflow equal to its mean radiance,
//   I = (Q + sum_a |w_a| I_upwind,a / h) / (sigma_t + sum_a |w_a| / h);
// 1, step characteristics (thesis 5.3.1-5.3.2, `characteristic_update`): face-averaged
// radiances carried across the voxel with exact attenuation, each outgoing face
//   L_out,o = sum_i f_io (L_in,i e^-x_io + Q h s_io phi(x_io)),   x_io = sigma_t h s_io,
// and the voxel's mean from its balance,
//   L_V = sum_io |w_o| f_io s_io (L_in,i phi(x_io) + Q h s_io psi(x_io)),
// with f (the thesis's A_In,Out / A_Out) and s (its s_avg) per direction from the host.
// Both are never negative and conserve energy. Faces of the box are vacuum (nothing enters).
// The emission along direction s comes from the source stored at M directions (thesis 5.1;
// src/physics/angular.rs): mode 0, M = 1 (isotropic); mode 1, the storage set is the swept
// set (Q_s itself); mode 2, upsampled, q_s = sum_m U[s][m] Q_m. Channel c of a chromatic medium
// has its own extinction, source and fluence slices.

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

layout(std430, binding = 0) readonly buffer SigmaT { float sigma_t[]; };   // [c][voxel], 1/unit
layout(std430, binding = 1) readonly buffer Source { float source[]; };    // [c][m][voxel], per unit volume and sr
layout(std430, binding = 2) readonly buffer Dirs { vec4 dirs[]; };         // xyz direction, w weight (sr)
layout(std430, binding = 3) buffer Field { float field[]; };               // [octant][its direction][voxel]
layout(std430, binding = 4) buffer Fluence { float fluence[]; };           // [c][octant][voxel]: sum of w I
layout(std430, binding = 5) readonly buffer Upsample { float upsample[]; }; // [s][m] (mode 2)
// Scheme 1: per direction, f[i][o] then s[i][o] (18 floats, padded to 20), and the outgoing
// face radiances across x, y, z, laid out as the field.
// Binding 6: the characteristics' factors per direction (characteristics.glsl's uniform block).
#define GEOMETRY_BINDING 6
layout(std430, binding = 7) buffer FaceX { float face_x[]; };
layout(std430, binding = 8) buffer FaceY { float face_y[]; };
layout(std430, binding = 9) buffer FaceZ { float face_z[]; };

// dom's convergence test on the device (ordinates/converge.comp): word 0 set once the iteration
// has converged, after which the rest of a submitted batch returns at once.
layout(std430, binding = 10) readonly buffer Control { uint ctrl_stopped; };
// Every plane's cells in octant-local coordinates, i | j << 16, plane by plane (the same for
// every octant; src/solvers/dom/ordinates.rs `plane_cells`).
layout(std430, binding = 11) readonly buffer Cells { uint cells[]; };

layout(push_constant) uniform Push {
    uvec4 dims;       // voxels xyz, w = voxel count
    int plane;        // the plane index w
    float h;          // voxel edge, scene units
    uint slots;       // field slots per octant (its largest direction count)
    uint storage;     // M, source directions stored per voxel
    uvec4 first[2];   // per octant o (bit a set: negative along axis a): its first direction in dirs[]
    uvec4 count[2];   // and its number of directions
    uint channel;     // c
    uint mode;        // 0: M = 1; 1: storage = swept set; 2: upsampled
    uint scheme;      // 0: step difference; 1: step characteristics
    uint first_cell;  // the plane's first entry in cells[]
    uint plane_cells; // and its number of cells
    uint pad0, pad1, pad2;
} pc;

float read_face(int axis, uint i) {
    return axis == 0 ? face_x[i] : (axis == 1 ? face_y[i] : face_z[i]);
}

#extension GL_GOOGLE_include_directive : require
#include "../include/characteristics.glsl"

uint voxel_index(ivec3 p) {
    return uint(p.x) + pc.dims.x * (uint(p.y) + pc.dims.y * uint(p.z));
}

void main() {
    if (ctrl_stopped != 0u) return;
    ivec3 n = ivec3(pc.dims.xyz);
    uint id = gl_GlobalInvocationID.x;
    uint o = gl_WorkGroupID.y;
    if (o >= 8u || id >= pc.plane_cells) return;
    uint cell = cells[pc.first_cell + id];
    ivec2 ab = ivec2(int(cell & 0xffffu), int(cell >> 16u));
    int c = pc.plane - ab.x - ab.y;
    uint count = pc.count[o / 4u][o % 4u];
    if (count == 0u) return;
    uint first_dir = pc.first[o / 4u][o % 4u];
    ivec3 sgn = ivec3((o & 1u) != 0u ? -1 : 1, (o & 2u) != 0u ? -1 : 1, (o & 4u) != 0u ? -1 : 1);
    // Octant-local coordinates count from the upwind corner.
    ivec3 local = ivec3(ab, c);
    ivec3 p = ivec3(sgn.x > 0 ? local.x : n.x - 1 - local.x,
                    sgn.y > 0 ? local.y : n.y - 1 - local.y,
                    sgn.z > 0 ? local.z : n.z - 1 - local.z);
    uint v = voxel_index(p);
    uint V = pc.dims.w;
    uint M = pc.storage;
    float st = sigma_t[pc.channel * V + v];
    uint src = pc.channel * M * V + v;
    float phi = 0.0;
    for (uint k = 0u; k < count; ++k) {
        uint s = first_dir + k;
        vec4 d = dirs[s];
        float q;
        if (pc.mode == 0u) {
            q = source[src];
        } else if (pc.mode == 1u) {
            q = source[src + s * V];
        } else {
            q = 0.0;
            for (uint m = 0u; m < M; ++m) q += upsample[s * M + m] * source[src + m * V];
        }
        vec3 a = abs(d.xyz);
        uint slot = (o * pc.slots + k) * V;
        float radiance;
        if (pc.scheme == 0u) {
            float inflow = 0.0;
            for (int axis = 0; axis < 3; ++axis) {
                // The upwind neighbour is one step against the sweep; none at the upwind face.
                if (local[axis] == 0) continue;
                ivec3 u = p;
                u[axis] -= sgn[axis];
                inflow += a[axis] * field[slot + voxel_index(u)];
            }
            radiance = (q + inflow / pc.h) / (st + (a.x + a.y + a.z) / pc.h);
        } else {
            float l_in[3];
            for (int axis = 0; axis < 3; ++axis) {
                l_in[axis] = 0.0;
                if (local[axis] == 0 || a[axis] == 0.0) continue;
                ivec3 u = p;
                u[axis] -= sgn[axis];
                l_in[axis] = read_face(axis, slot + voxel_index(u));
            }
            uint gbase = s * 20u;
            float out_face[3] = float[3](0.0, 0.0, 0.0);
            radiance = 0.0;
            for (int i = 0; i < 3; ++i) {
                for (int oo = 0; oo < 3; ++oo) {
                    float f = geometry(gbase + uint(3 * i + oo));
                    if (f == 0.0) continue;
                    float sl = geometry(gbase + 9u + uint(3 * i + oo));
                    float x = st * pc.h * sl;
                    vec2 pp = phi_psi(x);
                    float qh = q * pc.h * sl;
                    out_face[oo] += f * (l_in[i] * exp(-x) + qh * pp.x);
                    radiance += a[oo] * f * sl * (l_in[i] * pp.x + qh * pp.y);
                }
            }
            face_x[slot + v] = out_face[0];
            face_y[slot + v] = out_face[1];
            face_z[slot + v] = out_face[2];
        }
        field[slot + v] = radiance;
        phi += d.w * radiance;
    }
    fluence[(pc.channel * 8u + o) * V + v] = phi;
}
