#version 460
// marching/march: photon marching (thesis 4.4, Fig. 4.4): each invocation advances one light ray
// by `k` fixed steps of length `step` and writes what it deposits into its k slots of the Ray
// History Buffer. Deposit per step and channel (eq. 4.3 in its energy-conserving form):
//   deposit = P (1 - exp(-sigma_t(x_mid) step)) albedo,   P <- P exp(-sigma_t(x_mid) step)
// i.e. the power scattered out of the beam over the step, stored in the voxel holding the
// step's midpoint: the once-scattered source that the lattice diffuses. (What the beam scatters
// straight toward the camera is single scattering, computed exactly by the view pass, so no
// energy is counted twice.) A ray dies when its power falls below `threshold` of its start,
// when it leaves the lattice, or after `max_steps`.
//
// With an [[object]] (HAS_MESH) the medium is inside its mesh only: a ray knows which side it is
// on (dir_alive.w: 1 outside, 2 inside; set on the host where it starts), a step that crosses
// the surface ends there (its slot deposits what the part inside scattered), and the surface
// acts. Index-matched, the ray goes on. Refractive (REFRACTIVE), the thesis bends the ray
// through the smoothed gradient of the voxelised index (eqs. 4.1-4.2), which for an index
// constant inside a mesh is a blurred version of refraction at the surface: here the mesh
// refracts it exactly (Snell, the same surface path and the view march use) and the Fresnel
// equations split its power, which the eikonal update has no term for. Entering, the
// transmitted share (1 - F) goes on refracted (power, not radiance: no eta^2); the reflected
// share never enters the medium. Leaving, the internal reflection (share F, all of it under
// total internal reflection) goes on inside and the refracted share leaves the object: for a
// convex object it never comes back; in a non-convex one light that leaves and re-enters is
// dropped (what the marching then misses is light the lattice would have received).
//
// The forward population (pc.forward, lbl.inject=forward; docs/lbl.md). The lattice scatters
// isotropically with the reduced coefficient sigma_s (1 - g) (similarity), so the forward peak
// of the first scattering must be carried some other way. Split the once-scattered light as
// HG(g) ~ (1 - g) isotropic + g straight on (the delta-isotropic approximation: the same energy
// and mean cosine): the isotropic share is deposited here, and the share g joins the ray's
// forward population Q, which moves on along the ray (the beam's own direction, where a real
// forward-scattered photon goes on average) and collides at the reduced extinction
// sigma_t' = sigma_t (1 - albedo g), depositing the scattered share sigma_s (1 - g) / sigma_t'
// of what collides (the reduced medium's albedo) and absorbing the rest. Q refracts and
// reflects with the ray and leaves the medium with it. Per step the slot also records Q's path
// integral (W times voxels travelled, fwh[]), whose fluence and flux the view pass scatters
// toward the camera with the once-scattered light's own lobe (glsl/view/march.comp). Carried by
// the ray, Q goes deeper than a lattice's axial links can take it: the directed injection's
// links put light injected along a diagonal onto links parallel to a lit face, where it stays.
//
// Objects of several materials (scene.materials): a ray inside one carries its material in
// dir_alive.w = 2 + material (the host sets it where the ray starts; an entering crossing takes
// the triangle's), and its extinction, albedo, density field and index are that material's. A
// scene of one material reads materials[0], the medium's, as before.
#extension GL_GOOGLE_include_directive : require
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
// Count the SIMD batch's loop back-edges as llvmpipe does (batch.glsl, Loops below).
#define SCATTERLAB_BATCH_LOOPS

#define SCENE_BINDING 0
#define DENSITY_BINDING 1
#define MAJORANT_BINDING 2
#include "../include/scene.glsl"
#include "../include/budget.glsl"
#define MESH_NODES_BINDING 6
#define MESH_TRIS_BINDING 7
#include "../include/mesh.glsl"
#include "../include/phase.glsl"
#include "../include/one_minus_exp.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;
// After the work group size: linear.glsl reads gl_WorkGroupSize.
#include "../include/linear.glsl"

struct Ray {
    vec4 pos_steps;   // position (scene units), steps taken (float)
    vec4 dir_alive;   // unit direction, 1 while alive
    vec4 power;       // rgb power (W), w = the ray's starting max-channel power
    vec4 fwd;         // rgb power of the forward population (W; pc.forward), w unused
    vec4 fwd_absorbed;  // rgb: what Q's collisions absorbed so far (W; its energy book)
    vec4 fwd_out;       // rgb: what of Q left through a refractive surface or reflected off it (W)
};
layout(std430, binding = 3) buffer Rays { Ray rays[]; };
// k slots per ray: (voxel index or 0xffffffff, deposit rgb as float bits).
layout(std430, binding = 4) writeonly buffer History { uvec4 rhb[]; };
// With pc.forward, per slot: the forward population's path-integrated power over the step (W
// times voxels travelled), rgb, beside the slot's voxel.
layout(std430, binding = 5) writeonly buffer FwdHistory { vec4 fwh[]; };
// The most loop back-edges any SIMD batch (subgroup) took in one dispatch, as llvmpipe counts
// them (glsl/include/batch.glsl; 0 where the host leaves LOOP_LIMITED off): its k steps' BVH
// traversals and surface crossings are bounded by the mesh, not by k alone, and past
// LOOP_GUARD llvmpipe's loop limiter may have ended them silently; the host reads it after the
// rounds and fails loudly (Marcher::check_loops).
// And the most one step took (what k can be at most: the host's suggestion).
layout(std430, binding = 8) buffer Loops { uint loops_max; uint step_max; };

layout(push_constant) uniform Push {
    uvec4 dims;          // lattice voxels xyz, w = rays this dispatch marches
    vec4 origin;         // lattice min corner, w = lambda (voxel edge)
    float step;          // marching step, scene units
    float threshold;     // a ray dies below this fraction of its starting power
    uint k;              // Ray History Buffer slots per ray per round
    uint max_steps;
    uint first_ray;      // the first of them (dom marches one group of beams' rays at a time)
    uint forward;        // 1: carry the forward population (below)
    uint pad1;
    uint pad2;
} pc;

// The share of the forward population that a refractive surface reflects back in as it
// leaves: Q stands for light scattered forward about the ray's direction d, spread as HG(g)
// about it (the once-scattered lobe), not for the collimated ray itself, and of a spread beam
// more meets the surface beyond the critical angle than of the ray. Fresnel's reflectance
// from inside (index ior to 1) averaged over the outgoing hemisphere about n_out, weighted by
// the lobe and the cosine (the flux through the surface); a 16 x 32 product rule in (mu, phi).
// The loop constructs of one lobe_reflectance (batch.glsl's S): its rows and the loop in each.
const uint LOBE_LOOPS = 2u;
float lobe_reflectance(vec3 d, vec3 n_out, float g, float ior) {
    vec3 t = normalize(abs(n_out.x) < 0.9 ? cross(n_out, vec3(1.0, 0.0, 0.0)) : cross(n_out, vec3(0.0, 1.0, 0.0)));
    vec3 b = cross(n_out, t);
    float num = 0.0, den = 0.0;
    for (uint i = 0u; i < 16u; ++i) {
        LOOP_EDGE(LOBE_LOOPS);   // itself and the loop in it
        float mu = (float(i) + 0.5) / 16.0;
        float s = sqrt(1.0 - mu * mu);
        float ct;
        float F = fresnel_dielectric(mu, ior, ct);
        for (uint j = 0u; j < 32u; ++j) {
            LOOP_EDGE(1u);
            float phi = (float(j) + 0.5) * (2.0 * PI / 32.0);
            vec3 w = mu * n_out + s * (cos(phi) * t + sin(phi) * b);
            float wt = hg_eval(g, dot(w, d)) * mu;
            num += wt * F;
            den += wt;
        }
    }
    return den > 0.0 ? num / den : 1.0;
}

// The step loop's weight (batch.glsl): itself, the BVH query, lobe_reflectance and the forward
// population's channel loop; llvmpipe runs every one of them each step, whichever lanes enter.
const uint STEP_LOOPS = 1u + MESH_HIT_LOOPS + LOBE_LOOPS + 1u;

void main() {
    if (linear_id() >= pc.dims.w) return;
    uint r = pc.first_ray + linear_id();
    Ray ray = rays[r];
    vec3 x = ray.pos_steps.xyz;
    float steps = ray.pos_steps.w;
    vec3 d = ray.dir_alive.xyz;
    bool alive = ray.dir_alive.w > 0.5;
    bool inside = !HAS_MESH || ray.dir_alive.w > 1.5;   // in the object's medium (HAS_MESH)
    uint mat = HAS_MESH && inside ? uint(ray.dir_alive.w - 1.5) : 0u;   // its material
    vec3 P = ray.power.rgb;
    vec3 Q = ray.fwd.rgb;
    vec3 q_absorbed = ray.fwd_absorbed.rgb, q_out = ray.fwd_out.rgb;
    uvec3 n = pc.dims.xyz;
    float lambda = pc.origin.w;
    uint step_most = 0u;
    // The step loop's first run, prepaid (batch.glsl): it and every loop construct in it.
    BATCH_EDGE(STEP_LOOPS);
    uint before = batch_iters;   // the first step's count holds the prepayment too
    for (uint j = 0u; j < pc.k; ++j) {
        LOOP_EDGE(STEP_LOOPS);
        uvec4 slot = uvec4(0xffffffffu, 0u, 0u, 0u);
        vec3 q_len = vec3(0.0);
        if (alive) {
            // A step that meets the mesh ends on it (the rest of the way is the next step's).
            float len = pc.step;
            uint tri = 0xffffffffu;
            float t_hit;
            bool crosses = HAS_MESH && mesh_hit_tri(x, d, 0.0, pc.step, t_hit, tri);
            if (crosses) len = t_hit;
            vec3 mid = x + d * (0.5 * len);
            ivec3 vox = ivec3(floor((mid - pc.origin.xyz) / lambda));
            if (all(greaterThanEqual(vox, ivec3(0))) && all(lessThan(vox, ivec3(n)))) {
                medium_mat = mat;
                vec3 st = inside ? scene.materials[mat].sigma_t.xyz * medium_density(mid) : vec3(0.0);
                vec3 seg_T = exp(-st * len);
                vec3 a = scene.materials[mat].albedo.xyz;
                vec3 dep = P * one_minus_exp3(st * len) * a;
                P *= seg_T;
                if (pc.forward != 0u) {
                    // The forward population (header): of what the step scatters, the share g
                    // joins Q, the rest is deposited; Q then travels on with the ray, collides
                    // at the reduced extinction sigma_t' = sigma_t (1 - albedo g) and deposits
                    // the scattered share of that, sigma_s (1 - g) / sigma_t'. A medium with
                    // g <= 0 adds nothing to Q, and Q entering it collides at sigma_t.
                    float g = max(scene.materials[mat].albedo.w, 0.0);
                    vec3 red = max(vec3(1.0) - a * g, vec3(1e-6));
                    vec3 stp = st * red;
                    vec3 q0 = Q + g * dep;
                    vec3 q_T = exp(-stp * len);
                    // Q's path integral over the step, exact for its exponential decay.
                    // (len itself, taken below 1e-4 mean free paths, was x/2 of it off.)
                    vec3 path;
                    for (int c = 0; c < 3; ++c) {
                        LOOP_EDGE(1u);
                        path[c] = len * one_minus_exp_over(stp[c] * len);
                    }
                    q_len = q0 * path / lambda;
                    vec3 q_col = q0 * one_minus_exp3(stp * len);
                    vec3 q_dep = q_col * a * (1.0 - g) / red;
                    q_absorbed += q_col - q_dep;
                    dep = (1.0 - g) * dep + q_dep;
                    Q = q0 * q_T;
                }
                if (max3(dep) > 0.0 || max3(q_len) > 0.0) slot = uvec4(uint(vox.x) + n.x * (uint(vox.y) + n.y * uint(vox.z)), floatBitsToUint(dep));
            } else if (steps > 0.0) {
                alive = false;   // left the lattice (rays start on its boundary)
            }
            x += d * len;
            if (crosses) {
                vec3 nrm = triangle_normal(tri);
                bool entering = dot(d, nrm) < 0.0;
                vec3 nf = entering ? nrm : -nrm;   // facing the side the ray comes from
                if (entering) mat = triangle_material(tri);
                if (REFRACTIVE) {
                    float eta, cos_i, cos_t;
                    float F = surface_fresnel(d, nf, entering, scene.materials[mat].ior.x, eta, cos_i, cos_t);
                    if (entering) {
                        P *= 1.0 - F;
                        q_out += Q * F;
                        Q *= 1.0 - F;
                        d = refract_dir(d, nf, eta, cos_i, cos_t);
                        inside = true;
                    } else {
                        P *= F;
                        // (nf faces the inside here: the ray leaves along -nf)
                        if (pc.forward != 0u && max3(Q) > 0.0) {
                            float R = lobe_reflectance(d, -nf, max(scene.materials[mat].albedo.w, 0.0), scene.materials[mat].ior.x);
                            q_out += Q * (1.0 - R);
                            Q *= R;
                        }
                        d = reflect(d, nf);
                    }
                } else {
                    inside = entering;
                }
                // Off the surface, on the side the ray now goes.
                x += (dot(d, nf) < 0.0 ? -nf : nf) * surface_eps(x);
            }
            steps += 1.0;
            if (max3(P + Q) < pc.threshold * ray.power.w || steps >= float(pc.max_steps)) alive = false;
        }
        rhb[r * pc.k + j] = slot;
        if (pc.forward != 0u) fwh[r * pc.k + j] = vec4(q_len, 0.0);
        // The batch's back-edges in this step (every lane of it is here, k being uniform).
        if (LOOP_LIMITED) step_most = max(step_most, subgroupAdd(batch_iters - before));
        before = batch_iters;
    }
    // Every lane of the batch is here (those past the end of the rays returned at the start
    // and took no back-edge): one elected lane keeps the batch's sum.
    uint batch = LOOP_LIMITED ? subgroupAdd(batch_iters) : 0u;
    if (subgroupElect()) {
        atomicMax(loops_max, batch);
        atomicMax(step_max, step_most);
    }
    rays[r] = Ray(vec4(x, steps), vec4(d, alive ? (inside && HAS_MESH ? 2.0 + float(mat) : 1.0) : 0.0), vec4(P, ray.power.w), vec4(Q, 0.0), vec4(q_absorbed, 0.0), vec4(q_out, 0.0));
}
