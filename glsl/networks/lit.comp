#version 460
// networks/lit: the direct light scattered at each particle into each direction (illumination
// networks 3.3), sum_j L_j(p) p(w_j . w_i), L_j the light unit j's irradiance at p through the
// medium (networks/direct.comp) and p the Henyey-Greenstein phase function (1/sr). It does not
// change while the lights stand still, yet iterate.comp summed it over every unit for every
// link on every iteration: with an environment (16 units of it) and the sun that is 17 units
// a link, the iteration's largest cost once an isotropic medium sums its in-scattering per
// particle (networks/inscatter.comp). Summed here once per render and per light move
// (src/solvers/networks/iteration.rs) where there is more than one unit, the iteration reads
// one value a link. The same loop as iterate.comp's (lights.glsl): the images are the same bit
// for bit (networks_tests checks it).
#extension GL_GOOGLE_include_directive : require
#include "../include/phase.glsl"
// The medium's g: the scene block's material table, entry 0.
#define SCENE_BINDING 3
#include "../include/scene_block.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

layout(std430, binding = 0) readonly buffer Dirs { vec4 dirs[]; };      // u, v, w per direction
layout(std430, binding = 1) readonly buffer Direct { vec4 direct[]; };  // networks/direct.comp
#include "lights.glsl"
layout(std430, binding = 2) writeonly buffer Lit { vec4 lit[]; };       // [p][i], rgb

layout(push_constant) uniform Push {
    uint particles;
    uint directions;
    uint units;
} pc;

void main() {
    uint p = gl_GlobalInvocationID.x, i = gl_GlobalInvocationID.y;
    if (p >= pc.particles || i >= pc.directions) return;
    vec3 wi = dirs[3u * i + 2u].xyz;
    float g = scene.materials[0].albedo.w;
    lit[p * pc.directions + i] = vec4(lights_scattered(p, pc.units, g, wi), 0.0);
}
