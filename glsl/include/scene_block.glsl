// scene_block.glsl: the scene block's layout alone (binding SCENE_BINDING), for kernels that read
// the material table and nothing else of the scene (the lattice's, glsl/include/lattice.glsl);
// scene.glsl includes it with the density, camera and tracking. Layout mirrors
// `solvers::parts::gpu_scene::SceneHeader` (std430, vec4-aligned members only).
//
// The material table (`materials`) is the one route by which a medium's coefficients reach a
// kernel: the medium's are entry 0 in every scene, an object's material is its index. (The
// header held a copy of entry 0's sigma_t, albedo and ior as well, and lbl's lattice kernels a third
// and fourth, in push constants and a table of their own.)
#ifndef SCATTERLAB_SCENE_BLOCK
#define SCATTERLAB_SCENE_BLOCK
#include "common.glsl"

#define LIGHT_POINT 0u
#define LIGHT_DIRECTIONAL 1u
#define LIGHT_ENVIRONMENT 2u

// One object's material: the medium's coefficients inside it, its refractive index and emission.
struct ObjectMaterial {
    vec4 sigma_t;    // rgb extinction scale, 1/unit; w = max over channels
    vec4 albedo;     // rgb sigma_s / sigma_t; w = g
    vec4 ior;        // x: refractive index inside, relative to the vacuum outside
    vec4 emission;   // rgb: emitted radiance Le, W/(m^2 sr), or the emission grid's scale;
                     // w: 1 = Le is rgb times the emission grid (scene.emission_dims)
};

// One density field (src/solvers/gpu_scene.rs GpuField): a density kind over a box; a grid's
// voxels lie in the density atlas from z slice bounds_max.w on, its majorant cells in maj[]
// from grid_dims.w on. Field 0 is the medium's in every scene (the header's box and density).
struct DensityField {
    vec4 bounds_min;   // xyz: the box; w: the density kind (uint bits)
    vec4 bounds_max;   // xyz: the box; w: the first z slice in the atlas (uint bits)
    vec4 sphere;       // sphere density: centre xyz, radius w
    uvec4 grid_dims;   // grid voxels xyz; w: the first majorant cell
    uvec4 maj_dims;    // majorant cells xyz; w: voxels per cell edge
};

struct Light {
    vec4 pos_kind;   // point: position; directional: travel direction (unit); w = kind
    vec4 value;      // rgb: intensity W/sr | irradiance W/m^2 | radiance W/(m^2 sr)
};

layout(std430, binding = SCENE_BINDING) readonly buffer SceneBlock {
    vec4 bounds_min;     // medium box, scene units
    vec4 bounds_max;
    vec4 sphere;         // sphere density: centre xyz, radius w
    uvec4 grid_dims;     // grid density: voxels xyz
    uvec4 maj_dims;      // majorant grid cells xyz; w = voxels per cell edge
    vec4 cam_origin;     // w: 0 perspective, 1 orthographic
    vec4 cam_forward;    // unit; w: tan(fov/2) (perspective) or extent/2 (orthographic)
    vec4 cam_right;      // unit
    vec4 cam_up;         // unit
    uvec4 image;         // width, height, light count, 0
    uvec4 emission_dims; // emission grid voxels xyz over the medium's box; w: its channels (1 or 3; 0: none)
    ObjectMaterial materials[MAX_MATERIALS];   // the material table; [0] is the medium's in every scene
    DensityField fields[MAX_MATERIALS];        // the materials' density fields (ior.y); [0] the medium's
    Light lights[];
} scene;
#endif
