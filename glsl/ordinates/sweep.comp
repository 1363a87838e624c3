#version 460
// ordinates/sweep: one wavefront plane of one octant of a discrete-ordinates sweep (thesis
// 5.3.3: the voxels with i + j + k = w in the octant's own coordinates depend only on plane
// w - 1, so a plane is one dispatch). Each invocation is one voxel of the plane and takes every
// direction of the octant in turn, so the fluence is summed in a fixed order without atomics:
// deterministic. The per-voxel update is the step scheme of src/physics/ordinates.rs (the
// CPU oracle this mirrors): the voxel's balance with its outflow equal to its mean radiance,
//   I = (Q + sum_a |w_a| I_upwind,a / h) / (sigma_t + sum_a |w_a| / h),
// never negative and conservative. Faces of the box are vacuum (nothing enters).

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

layout(std430, binding = 0) readonly buffer SigmaT { float sigma_t[]; };   // 1/unit per voxel
layout(std430, binding = 1) readonly buffer Emission { float emission[]; }; // per unit volume and sr
layout(std430, binding = 2) readonly buffer Dirs { vec4 dirs[]; };         // xyz direction, w weight (sr)
layout(std430, binding = 3) buffer Field { float field[]; };               // [octant direction][voxel]
layout(std430, binding = 4) buffer Fluence { float fluence[]; };           // sum over directions of w I

layout(push_constant) uniform Push {
    uvec4 dims;       // voxels xyz, w = voxel count
    ivec4 octant;     // +1 / -1 per axis (the sweep's direction), w = the plane index
    uint first_dir;   // the octant's first direction in dirs[]
    uint count;       // its number of directions
    float h;          // voxel edge, scene units
    uint pad;
} pc;

uint voxel_index(ivec3 p) {
    return uint(p.x) + pc.dims.x * (uint(p.y) + pc.dims.y * uint(p.z));
}

void main() {
    ivec3 n = ivec3(pc.dims.xyz);
    ivec2 ab = ivec2(gl_GlobalInvocationID.xy);
    int c = pc.octant.w - ab.x - ab.y;
    if (ab.x >= n.x || ab.y >= n.y || c < 0 || c >= n.z) return;
    // Octant-local coordinates count from the upwind corner.
    ivec3 local = ivec3(ab, c);
    ivec3 p = ivec3(pc.octant.x > 0 ? local.x : n.x - 1 - local.x,
                    pc.octant.y > 0 ? local.y : n.y - 1 - local.y,
                    pc.octant.z > 0 ? local.z : n.z - 1 - local.z);
    uint v = voxel_index(p);
    uint V = pc.dims.w;
    float st = sigma_t[v];
    float q = emission[v];
    float phi = 0.0;
    for (uint k = 0u; k < pc.count; ++k) {
        vec4 d = dirs[pc.first_dir + k];
        vec3 a = abs(d.xyz);
        float inflow = 0.0;
        for (int axis = 0; axis < 3; ++axis) {
            // The upwind neighbour is one step against the sweep; none at the upwind face.
            if (local[axis] == 0) continue;
            ivec3 u = p;
            u[axis] -= pc.octant[axis];
            inflow += a[axis] * field[k * V + voxel_index(u)];
        }
        float radiance = (q + inflow / pc.h) / (st + (a.x + a.y + a.z) / pc.h);
        field[k * V + v] = radiance;
        phi += d.w * radiance;
    }
    fluence[v] += phi;
}
