#version 460
// view/shadow: the view pass's shadow volume (solvers/view.rs, `view_shadow=volume`). For every
// light unit j (one per point or directional light, env_dirs per environment) and every voxel
// centre x of the density grid, the density integral toward the light, D_j(x) =
// int_0^dist density(x + w_j s) ds, and away from it to the medium's end (the chord the
// bounded octaves need), by the same midpoint rule the view march uses. The march then reads
// sigma_t D_j trilinearly at each step instead of marching a shadow ray per step and unit:
// on the 64^3 cloud with 17 units that is ~17 x 64^3 x 2 marches once instead of ~17 per
// camera step and pixel.
#extension GL_GOOGLE_include_directive : require

#define SCENE_BINDING 0
#define DENSITY_BINDING 1
#define MAJORANT_BINDING 2
#include "../include/scene.glsl"
#include "../include/budget.glsl"
#include "../include/view.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;
// After the work group size: linear.glsl reads gl_WorkGroupSize.
#include "../include/linear.glsl"

// [(S j + s) V + v] for S = pc.sides: s = 0 toward the light, 1 away from it (only when the
// bounded octaves need the whole chord).
layout(std430, binding = 3) writeonly buffer Depth { float depth[]; };

layout(push_constant) uniform Push {
    float shadow_step;   // scene units, as the march's
    uint env_dirs;
    uint units;
    uint sides;          // 1: toward the light only; 2: also away from it
} pc;

void main() {
    uint v = linear_id_z();
    uint j = gl_GlobalInvocationID.y;
    uvec3 n = scene.grid_dims.xyz;
    uint V = n.x * n.y * n.z;
    if (v >= V || j >= pc.units) return;
    uvec3 c = uvec3(v % n.x, (v / n.x) % n.y, v / (n.x * n.y));
    vec3 cell = (scene.bounds_max.xyz - scene.bounds_min.xyz) / vec3(n);
    vec3 x = scene.bounds_min.xyz + (vec3(c) + 0.5) * cell;
    vec3 wi;
    float dist;
    if (!unit_light(j, x, pc.env_dirs, wi, dist)) return;
    depth[(pc.sides * j) * V + v] = density_depth(x, wi, dist, pc.shadow_step);
    if (pc.sides == 2u) depth[(pc.sides * j + 1u) * V + v] = density_depth(x, -wi, INF, pc.shadow_step);
}
