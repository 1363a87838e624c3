#version 460
// ordinates/emit: an emissive medium's own source, added to the source the first sweep
// propagates (issue 47). The transfer equation's emission term is sigma_a Le (pbrt-v4's
// convention, glsl/include/scene.glsl `emission_source`), isotropic, in W/(m^3 sr): the units of
// the first-scattering source bin.comp stores (per unit volume and sr, the sweep's Q per unit
// length, glsl/ordinates/sweep.comp). So it is the same at every storage direction m (an
// isotropic source upsamples to itself: each row of U sums to 1), and the first sweep carries
// the emitted light uncollided beside the once-scattered direct light: the thesis's G''
// initialised with G_dir plus the emission (5.3.3's progressive scheme), after which scatter.comp
// turns it into its bounces like any other light. What the view march adds itself is only the
// emitted light that reaches the camera unscattered (glsl/view/march.comp), and the swept field
// reaches the camera only through a scattering (scatter.comp's gathering): nothing twice.
// sigma_a is the voxel's own, from the resampled density the sweeps' sigma_t and sigma_s come
// from (src/solvers/dom/mod.rs, `extinction`), so an optically thick voxel's equilibrium is Le
// exactly; Le is read at the voxel centre (the nearest point of the box for a voxel the box
// ends inside, as marching/resample.comp reads the density there). One slab of whole layers at
// a time, as bin.comp: voxel v of the slab is base + v of the grid. Only emissive scenes run it.
#extension GL_GOOGLE_include_directive : require

#define SCENE_BINDING 0
#define DENSITY_BINDING 1
#define MAJORANT_BINDING 2
#define EMISSION_BINDING 15
#include "../include/scene.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;
// After the work group size: linear.glsl reads gl_WorkGroupSize.
#include "../include/linear.glsl"
layout(std430, binding = 3) readonly buffer Resampled { float density[]; }; // the slab's, from its voxel 0
layout(std430, binding = 4) buffer Source { float source[]; };              // [c][m][voxel], per unit volume and sr

layout(push_constant) uniform Push {
    uvec4 dims;      // the grid's voxels xyz, w = the slab's voxels V
    vec4 grid;       // xyz the grid's lower corner, w lambda
    uint storage;    // M
    uint channels;   // 1 (grey medium, grey Le) or 3
    uint base;       // the slab's first voxel
    uint start;      // 1: the source holds nothing yet (no beams were binned): write, not add
} pc;

void main() {
    uint v = linear_id();
    uint V = pc.dims.w;
    if (v >= V) return;
    uint M = pc.storage;
    float d = density[v];
    vec3 q = vec3(0.0);
    if (d > 0.0) {
        uint gv = pc.base + v;
        ivec3 p = ivec3(gv % pc.dims.x, (gv / pc.dims.x) % pc.dims.y, gv / (pc.dims.x * pc.dims.y));
        vec3 centre = pc.grid.xyz + (vec3(p) + 0.5) * pc.grid.w;
        q = emission_source(clamp(centre, scene.bounds_min.xyz, scene.bounds_max.xyz), d);
    }
    for (uint c = 0u; c < pc.channels; ++c) {
        for (uint m = 0u; m < M; ++m) {
            uint i = (c * M + m) * V + v;
            source[i] = pc.start != 0u ? q[c] : source[i] + q[c];
        }
    }
}
