#version 460
// wave_field/resample: the medium resampled onto the spherical grid around the light (paper
// section 2.1): the density at the middle of shell n of ray (i, j), 0 outside the box.
#extension GL_GOOGLE_include_directive : require

#define SCENE_BINDING 0
#define DENSITY_BINDING 1
#define MAJORANT_BINDING 2
#include "../include/scene.glsl"
#include "../include/wave_field.glsl"

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;
layout(std430, binding = 3) writeonly buffer Shells { float shell_density[]; };   // [wf_node(ray, n)], n < layers

void main() {
    uvec3 id = gl_GlobalInvocationID;   // (i, j, n)
    if (id.x >= pc.dims.x || id.y >= pc.dims.y || id.z >= pc.dims.z) return;
    vec3 w = wf_dir((vec2(id.xy) + 0.5) / vec2(pc.dims.xy));
    float r = (float(id.z) + 0.5) * pc.light.w;
    shell_density[wf_node(wf_ray(id.x, id.y), id.z)] = medium_density(pc.light.xyz + w * r);
}
