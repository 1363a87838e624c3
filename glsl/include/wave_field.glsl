// wave_field.glsl: the spherical grid of wavefront tracing (solvers/wave_field.rs) around one point light
// (Szirmay-Kalos et al., "Fast approximation of multiple scattering in inhomogeneous
// participating media", section 2.1). Ray (i, j) of nu x nv has direction
//   alpha = 2 pi u, theta = arccos(1 - 2 v), u = (i + 1/2) / nu, v = (j + 1/2) / nv,
// uniform in solid angle (each ray stands for 4 pi / (nu nv) sr); node n of a ray sits at
// radius r = n Delta, n = 0 .. layers, with Delta = R / layers and R the distance from the
// light to the farthest corner of the medium's box. Shell n lies between nodes n and n + 1.
#ifndef SCATTERLAB_WAVEFRONT
#define SCATTERLAB_WAVEFRONT
#include "common.glsl"

layout(push_constant) uniform Push {
    vec4 light;          // light position (scene units), w = Delta (radial step)
    vec4 intensity;      // rgb radiant intensity Phi (W/sr), w = explicit: start radius (see march)
    uvec4 dims;          // nu, nv, layers, integrator (0 explicit eq. 6, 1 exponential in an infinite
                         // medium, 2 exponential with the extrapolated boundary; march.comp)
    uvec4 cart_dims;     // gather: Cartesian voxels xyz, w = channels written
    vec4 cart_origin;    // gather: Cartesian min corner, w = voxel edge lambda
} pc;

vec3 wf_dir(vec2 uv) {
    float alpha = 2.0 * PI * uv.x;
    float ct = 1.0 - 2.0 * uv.y;
    float st = sqrt(max(0.0, 1.0 - ct * ct));
    return vec3(cos(alpha) * st, sin(alpha) * st, ct);
}

uint wf_ray(uint i, uint j) { return j * pc.dims.x + i; }
// Node n of ray `ray`, layer-major: one w-layer of every ray is contiguous (the wavefront).
uint wf_node(uint ray, uint n) { return n * (pc.dims.x * pc.dims.y) + ray; }
#endif
