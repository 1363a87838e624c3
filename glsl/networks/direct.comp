#version 460
// networks/direct: the direct term's light at each particle (illumination networks 3.1, the
// paper's E array before the phase function): for every particle p and every point or
// directional light j (environments reach the particles through the network's sky instead),
// the light's irradiance at p times the transmittance of the medium itself between them,
// exp(-sigma_t int density), by the midpoint rule the view pass and `single` use
// (view.glsl's density_depth): T Phi / r^2 for a point light of intensity Phi, T E for a
// directional light of irradiance E; and the light's direction of travel at p. The iteration
// (networks/iterate.comp) turns it into E[p][i] = alpha albedo T Phi / r^2 p(w_l . w_i).
// A point light closer than the particle's own radius b is taken at the mean of 1 / r^2 over
// the particle's ball, 3 / b^2, so a light inside the medium gives no singular particle.
// With `networks.single = view` the environments are units too (env_dirs directions each, the
// view pass's quadrature, L 4 pi / env_dirs T each): the network then carries only scattered
// light (its sky is 0), and the view pass adds the single scattering of every light.
#extension GL_GOOGLE_include_directive : require

#define SCENE_BINDING 0
#define DENSITY_BINDING 1
#define MAJORANT_BINDING 2
#include "../include/scene.glsl"
#include "../include/budget.glsl"
#include "../include/view.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

layout(std430, binding = 3) readonly buffer Positions { vec4 positions[]; };
// [particle][unit]: (irradiance rgb at the particle, loop iterations), (direction of travel, 0)
layout(std430, binding = 4) writeonly buffer Direct { vec4 direct[]; };

layout(push_constant) uniform Push {
    float step;       // the midpoint rule's step, scene units
    float min_r2;     // b^2 / 3: the least squared distance to a point light
    uint particles;
    uint units;       // point and directional lights, then env_dirs per environment
    uint env_dirs;    // 0: environments are not units (they reach the particles as the sky)
    uint pad0, pad1, pad2;
} pc;

void main() {
    uint p = gl_GlobalInvocationID.x, j = gl_GlobalInvocationID.y;
    if (p >= pc.particles || j >= pc.units) return;
    vec3 x = positions[p].xyz;
    vec3 wi;
    float dist;
    vec3 irradiance;
    // Unit j: the j-th point or directional light, then (with env_dirs) the environments'
    // quadrature directions (view.glsl's fibonacci_dir), each of weight 4 pi / env_dirs.
    uint k = 0u, light = 0xffffffffu;
    for (uint l = 0u; l < scene.image.z; ++l) {
        iters++;
        if (is_environment(uint(scene.lights[l].pos_kind.w))) continue;
        if (k == j) { light = l; break; }
        ++k;
    }
    if (light != 0xffffffffu) {
        Light li = scene.lights[light];
        if (uint(li.pos_kind.w) == LIGHT_POINT) {
            vec3 to = li.pos_kind.xyz - x;
            float r2 = dot(to, to);
            dist = sqrt(r2);
            wi = dist > 0.0 ? to / dist : vec3(0.0, 0.0, 1.0);
            irradiance = li.value.rgb / max(r2, pc.min_r2);
        } else {
            wi = -li.pos_kind.xyz;
            dist = INF;
            irradiance = li.value.rgb;
        }
    } else {
        // The (j - k)-th environment direction: which environment, and which direction.
        uint e = j - k, seen = 0u;
        irradiance = vec3(0.0);
        wi = vec3(0.0, 0.0, 1.0);
        for (uint l = 0u; l < scene.image.z; ++l) {
            iters++;
            if (!is_environment(uint(scene.lights[l].pos_kind.w))) continue;
            if (e < seen + pc.env_dirs) {
                wi = fibonacci_dir(e - seen, pc.env_dirs);
                irradiance = scene.lights[l].value.rgb * (4.0 * PI / float(pc.env_dirs));
                break;
            }
            seen += pc.env_dirs;
        }
        dist = INF;
    }
    float depth = density_depth(x, wi, dist, pc.step);
    vec3 t = exp(-scene.materials[0].sigma_t.rgb * depth);
    direct[2u * (p * pc.units + j)] = vec4(irradiance * t, float(iters));
    direct[2u * (p * pc.units + j) + 1u] = vec4(-wi, 0.0);
}
