#version 460
// marching/march: photon marching (thesis 4.4, Fig. 4.4): each invocation advances one light ray
// by `k` fixed steps of length `step` and writes what it deposits into its k slots of the Ray
// History Buffer. Deposit per step and channel (eq. 4.3 in its energy-conserving form):
//   deposit = P (1 - exp(-sigma_t(x_mid) step)) albedo,   P <- P exp(-sigma_t(x_mid) step)
// i.e. the power scattered out of the beam over the step, stored in the voxel holding the
// step's midpoint: the once-scattered source that the lattice diffuses. (What the beam scatters
// straight toward the camera is single scattering, computed exactly by the view pass, so no
// energy is counted twice.) A ray dies when its power falls below `threshold` of its start,
// when it leaves the lattice, or after `max_steps`. Straight rays: the eikonal update of
// eq. 4.1-4.2 (refraction) slots in where the position advances once meshes carry eta.
#extension GL_GOOGLE_include_directive : require

#define SCENE_BINDING 0
#define DENSITY_BINDING 1
#define MAJORANT_BINDING 2
#include "../include/scene.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

struct Ray {
    vec4 pos_steps;   // position (scene units), steps taken (float)
    vec4 dir_alive;   // unit direction, 1 while alive
    vec4 power;       // rgb power (W), w = the ray's starting max-channel power
};
layout(std430, binding = 3) buffer Rays { Ray rays[]; };
// k slots per ray: (voxel index or 0xffffffff, deposit rgb as float bits).
layout(std430, binding = 4) writeonly buffer History { uvec4 rhb[]; };

layout(push_constant) uniform Push {
    uvec4 dims;          // lattice voxels xyz, w = rays this dispatch marches
    vec4 origin;         // lattice min corner, w = lambda (voxel edge)
    float step;          // marching step, scene units
    float threshold;     // a ray dies below this fraction of its starting power
    uint k;              // Ray History Buffer slots per ray per round
    uint max_steps;
    uint first_ray;      // the first of them (dom marches one group of beams' rays at a time)
    uint pad0;
    uint pad1;
    uint pad2;
} pc;

void main() {
    if (gl_GlobalInvocationID.x >= pc.dims.w) return;
    uint r = pc.first_ray + gl_GlobalInvocationID.x;
    Ray ray = rays[r];
    vec3 x = ray.pos_steps.xyz;
    float steps = ray.pos_steps.w;
    vec3 d = ray.dir_alive.xyz;
    bool alive = ray.dir_alive.w > 0.5;
    vec3 P = ray.power.rgb;
    uvec3 n = pc.dims.xyz;
    float lambda = pc.origin.w;
    for (uint j = 0u; j < pc.k; ++j) {
        uvec4 slot = uvec4(0xffffffffu, 0u, 0u, 0u);
        if (alive) {
            vec3 mid = x + d * (0.5 * pc.step);
            ivec3 vox = ivec3(floor((mid - pc.origin.xyz) / lambda));
            if (all(greaterThanEqual(vox, ivec3(0))) && all(lessThan(vox, ivec3(n)))) {
                vec3 st = scene.sigma_t.xyz * medium_density(mid);
                vec3 seg_T = exp(-st * pc.step);
                vec3 dep = P * (vec3(1.0) - seg_T) * scene.albedo.xyz;
                P *= seg_T;
                if (max3(dep) > 0.0) slot = uvec4(uint(vox.x) + n.x * (uint(vox.y) + n.y * uint(vox.z)), floatBitsToUint(dep));
            } else if (steps > 0.0) {
                alive = false;   // left the lattice (rays start on its boundary)
            }
            x += d * pc.step;
            steps += 1.0;
            if (max3(P) < pc.threshold * ray.power.w || steps >= float(pc.max_steps)) alive = false;
        }
        rhb[r * pc.k + j] = slot;
    }
    rays[r] = Ray(vec4(x, steps), vec4(d, alive ? 1.0 : 0.0), vec4(P, ray.power.w));
}
