#version 460
// sh_single/depth: the optical depth tau(b_i, w_k) per channel from every sample b_i of
// `sh-single` toward every direction w_k of its projection quadrature (thesis 3.3.1: the
// attenuation psi_i(w) = exp(-tau(b_i, w)) is projected on spherical harmonics, eq. 3.4), on the
// device: one invocation per (sample, direction), walking the ray's crossings of the objects
// (the mesh's BVH) to infinity. Each interval inside an object counts at its material's
// extinction times its density: the length for a constant density, else the midpoint rule in
// steps of at most pc.step. Surfaces are crossed straight (psi has no refraction). The host
// (src/solvers/sh_single.rs, device_depths) projects exp(-tau) and keeps the coefficients;
// optical_depth there is the same walk on the host, which the tests hold this to.
#extension GL_GOOGLE_include_directive : require

#define SCENE_BINDING 0
#define DENSITY_BINDING 1
#define MAJORANT_BINDING 2
#include "../include/scene.glsl"
#include "../include/budget.glsl"
#define MESH_NODES_BINDING 6
#define MESH_TRIS_BINDING 7
#include "../include/mesh.glsl"
#include "../include/dielectric.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

// Sample i: its centre (xyz) and, in w, its material (uint bits).
layout(std430, binding = 3) readonly buffer Samples { vec4 samples[]; };
// Direction k: unit vector.
layout(std430, binding = 4) readonly buffer Dirs { vec4 dirs[]; };
// [i * dirs + k]: tau per channel (xyz).
layout(std430, binding = 5) writeonly buffer Depths { vec4 depths[]; };

layout(push_constant) uniform Push {
    uint samples;   // samples in this chunk
    uint dirs;
    float step;     // density marching step, scene units
    uint first;     // this chunk's first sample
} pc;

void main() {
    uint id = gl_GlobalInvocationID.x;
    if (id >= pc.samples * pc.dirs) return;
    uint i = pc.first + id / pc.dirs, k = id % pc.dirs;
    vec3 p = samples[i].xyz;
    vec3 w = dirs[k].xyz;
    uint mat = floatBitsToUint(samples[i].w);
    bool inside = true;
    vec3 tau = vec3(0.0);
    // The boundary factor of the straight ray (as `single`'s shadow rays take it, thesis
    // 3.1.1): at each refracting surface crossed, 1 - F at the ray's own angle (0 under total
    // internal reflection) times the radiance's change of index, ior^2 where it leaves an
    // object (light entering it) and 1 / ior^2 where it enters one.
    float ft = 1.0;
    float t = 0.0, t_search = 0.0;
    // A few crossings per ray in any scene we ship; the cap guards a degenerate loop.
    for (uint e = 0u; e < 64u; ++e) {
        float t_hit;
        uint tri;
        bool hit = mesh_hit_tri(p, w, t_search, INF, t_hit, tri);
        if (inside && hit) {
            medium_mat = mat;
            float integral;
            if (DENSITY_KIND == DENSITY_CONSTANT) {
                integral = t_hit - t;
            } else {
                uint n = max(1u, uint(ceil((t_hit - t) / pc.step)));
                float dt = (t_hit - t) / float(n);
                integral = 0.0;
                for (uint s = 0u; s < n; ++s) integral += density_at(p + w * (t + (float(s) + 0.5) * dt)) * dt;
            }
            tau += scene.materials[mat].sigma_t.xyz * integral;
        }
        if (!hit) break;
        vec3 n = triangle_normal(tri);
        bool entering = dot(n, w) < 0.0;
        float ior = scene.materials[triangle_material(tri)].ior.x;
        if (REFRACTIVE && ior != 1.0 && ft > 0.0) {
            float cos_t;
            float F = fresnel_dielectric(abs(dot(n, w)), entering ? 1.0 / ior : ior, cos_t);
            ft = F >= 1.0 ? 0.0 : ft * (1.0 - F) * (entering ? 1.0 / (ior * ior) : ior * ior);
        }
        inside = entering;
        if (entering) mat = triangle_material(tri);
        t = t_hit;
        t_search = t_hit + 1e-5 * max(abs(t_hit), 1.0);
    }
    depths[id] = vec4(tau, ft);
}
