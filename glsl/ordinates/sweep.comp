#version 460
// ordinates/sweep: one wavefront plane of all eight octants of a discrete-ordinates sweep
// (thesis 5.3.3: the voxels with i + j + k = w in an octant's own coordinates depend only on
// its plane w - 1, so a plane is one dispatch; the octants are independent, so they share it,
// gl_GlobalInvocationID.z being the octant). Each invocation is one voxel of one octant's plane
// and takes every direction of the octant in turn into the octant's own fluence slice, so the
// fluence is summed in a fixed order without atomics (the host adds the slices): deterministic. The per-voxel update is the step scheme of src/physics/ordinates.rs (the
// CPU oracle this mirrors): the voxel's balance with its outflow equal to its mean radiance,
//   I = (Q + sum_a |w_a| I_upwind,a / h) / (sigma_t + sum_a |w_a| / h),
// never negative and conservative. Faces of the box are vacuum (nothing enters).
// The emission along direction s comes from the source stored at M directions (thesis 5.1;
// src/physics/angular.rs): mode 0, M = 1 (isotropic); mode 1, the storage set is the swept
// set (Q_s itself); mode 2, upsampled, q_s = sum_m U[s][m] Q_m. Channel c of a chromatic medium
// has its own extinction, source and fluence slices.

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

layout(std430, binding = 0) readonly buffer SigmaT { float sigma_t[]; };   // [c][voxel], 1/unit
layout(std430, binding = 1) readonly buffer Source { float source[]; };    // [c][m][voxel], per unit volume and sr
layout(std430, binding = 2) readonly buffer Dirs { vec4 dirs[]; };         // xyz direction, w weight (sr)
layout(std430, binding = 3) buffer Field { float field[]; };               // [octant][its direction][voxel]
layout(std430, binding = 4) buffer Fluence { float fluence[]; };           // [c][octant][voxel]: sum of w I
layout(std430, binding = 5) readonly buffer Upsample { float upsample[]; }; // [s][m] (mode 2)

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
    uint pad0;
    uint pad1;
} pc;

uint voxel_index(ivec3 p) {
    return uint(p.x) + pc.dims.x * (uint(p.y) + pc.dims.y * uint(p.z));
}

void main() {
    ivec3 n = ivec3(pc.dims.xyz);
    ivec2 ab = ivec2(gl_GlobalInvocationID.xy);
    uint o = gl_GlobalInvocationID.z;
    int c = pc.plane - ab.x - ab.y;
    if (o >= 8u || ab.x >= n.x || ab.y >= n.y || c < 0 || c >= n.z) return;
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
        float inflow = 0.0;
        for (int axis = 0; axis < 3; ++axis) {
            // The upwind neighbour is one step against the sweep; none at the upwind face.
            if (local[axis] == 0) continue;
            ivec3 u = p;
            u[axis] -= sgn[axis];
            inflow += a[axis] * field[slot + voxel_index(u)];
        }
        float radiance = (q + inflow / pc.h) / (st + (a.x + a.y + a.z) / pc.h);
        field[slot + v] = radiance;
        phi += d.w * radiance;
    }
    fluence[(pc.channel * 8u + o) * V + v] = phi;
}
