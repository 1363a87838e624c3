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

// The share of the voxel about `centre` (edge `lambda`) inside the box [lo, hi]: 1 for a voxel
// wholly inside (to a rounding margin, so a box a whole number of voxels across resamples
// exactly as at the centres alone), else the overlap's volume over the voxel's. A voxel the box
// ends inside (the grid counts voxels along the longest side; a thin side is rarely a whole
// number of them) holds the optical depth of the medium it covers: read at its centre alone it
// was all medium or all vacuum, and lbl's lattice, whose boundary treatment sits at the box's
// faces, lit a 2-mfp slab at 3.34 voxels across 1.63x as bright as path (issue 44).
float box_share(vec3 centre, float lambda, vec3 lo, vec3 hi) {
    float h = 0.5 * lambda;
    float eps = 1e-4 * lambda;
    if (all(greaterThanEqual(centre - h, lo - eps)) && all(lessThanEqual(centre + h, hi + eps))) return 1.0;
    vec3 w = clamp(min(centre + h, hi) - max(centre - h, lo), 0.0, lambda) / lambda;
    return w.x * w.y * w.z;
}

void main() {
    uvec3 id = gl_GlobalInvocationID;
    if (any(greaterThanEqual(id, pc.dims.xyz))) return;
    float lambda = pc.origin.w;
    vec3 centre = pc.origin.xyz + (vec3(id.x, id.y, id.z + pc.dims.w) + 0.5) * lambda;
    vec3 lo = scene.bounds_min.xyz;
    vec3 hi = scene.bounds_max.xyz;
    if (FIELDS) {
        DensityField f = scene.fields[medium_field()];
        lo = f.bounds_min.xyz;
        hi = f.bounds_max.xyz;
    }
    float share = box_share(centre, lambda, lo, hi);
    // A straddling voxel reads the density at the nearest point of the box to its centre.
    float d = share >= 1.0 ? medium_density(centre) : share * medium_density(clamp(centre, lo, hi));
    resampled[id.x + pc.dims.x * (id.y + pc.dims.y * id.z)] = d;
}
