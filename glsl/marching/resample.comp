#version 460
// marching/resample: the medium's density at the centre of every lattice voxel (the grid the lattice
// runs on, `lbl.grid` voxels along the longest side of the medium's box; 0 outside the box), for
// the layers z0 .. z0 + dims.z of the grid: the whole grid (z0 = 0), or one slab of it (dom's
// direct source out of core, src/solvers/dom.rs), stored from index 0 of the slab.
#extension GL_GOOGLE_include_directive : require

#define SCENE_BINDING 0
#define DENSITY_BINDING 1
#define MAJORANT_BINDING 2
#include "../include/scene.glsl"

layout(local_size_x = 4, local_size_y = 4, local_size_z = 4) in;
layout(std430, binding = 3) writeonly buffer Resampled { float resampled[]; };

layout(push_constant) uniform Push {
    uvec4 dims;     // lattice voxels x, y, the slab's layers z; w = its first layer z0
    vec4 origin;    // lattice min corner, w = lambda
} pc;

void main() {
    uvec3 id = gl_GlobalInvocationID;
    if (any(greaterThanEqual(id, pc.dims.xyz))) return;
    vec3 centre = pc.origin.xyz + (vec3(id.x, id.y, id.z + pc.dims.w) + 0.5) * pc.origin.w;
    resampled[id.x + pc.dims.x * (id.y + pc.dims.y * id.z)] = medium_density(centre);
}
