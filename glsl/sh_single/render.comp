#version 460
// sh_single/render: `sh-single`'s render pass (issue 17, thesis 3.4, eq. 3.4). Per pixel, the
// camera ray meets the object (the mesh's BVH), refracts with the Fresnel transmittance into it
// (thesis 3.1.1; radiance scaled by (1 - F) / ior^2 on the way in, as `single`'s chain) and runs
// straight to the next surface. Along that segment every sample's Gaussian gamma_i(x) =
// exp(-a_i |x - b_i|^2) is integrated in closed form,
//   int_0^t1 gamma_i = exp(-a h^2) sqrt(pi / a) / 2 [erf(sqrt a (t1 - tc)) + erf(sqrt a tc)]
// (tc the sample's projection on the ray, h its distance from it), and weighted by
//   sigma_s(b_i) psi_i(-d) [ sum_j p(w_ij . d) E_ij + L_env f_env sum_lm g^l psi_lm Y_lm(d) ]:
// psi_i(-d) the sample's SH-reconstructed attenuation toward the camera, E_ij the light j's
// irradiance at the sample already attenuated by psi_i toward it and by `single`'s boundary
// factor of the surfaces crossed (Fresnel 1 - F and the ior^2 of the radiance entering;
// src/solvers/sh_single.rs, on the host), p the Henyey-Greenstein phase, and the constant
// environment's in-scattering by Funk-Hecke: HG's band-l coefficient is g^l, so the
// convolution of psi with p is sum g^l psi_lm Y_lm (times the boundary factor's mean over the
// directions leaving the surface, env_factor).
// Samples come in chunks (one dispatch each, adding into the image); the first chunk also
// writes the surface's own terms: the environment reflected at the entry (F L_env) and seen
// through each exit ((1 - F_exit) e^-tau L_env, the chords' optical depths marched). The camera
// ray's chain reflects inside (F at each exit, all of it under total internal reflection), as
// `single`'s view march does, up to MAX_BOUNCES. Left out: light reaching a sample along a
// refracted path (as `single`).
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
#include "../include/phase.glsl"
#include "../include/sh.glsl"

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

// Sample i: [2 i] centre xyz, w = a; [2 i + 1] sigma_s rgb, w = g.
layout(std430, binding = 3) readonly buffer Samples { vec4 samples[]; };
// Sample i's attenuation coefficients: [(i * 3 + c) * order^2 + k].
layout(std430, binding = 4) readonly buffer Coeffs { float coeffs[]; };
// Sample i, light j: [2 (i * lights + j)] attenuated irradiance rgb; [... + 1] unit direction
// toward the light.
layout(std430, binding = 5) readonly buffer LightTerms { vec4 lterms[]; };
// Radiance per pixel (rgb), accumulated over the chunks.
layout(std430, binding = 8) buffer Radiance { vec4 radiance[]; };

layout(push_constant) uniform Push {
    uint first;      // first sample of this chunk
    uint count;      // samples in this chunk
    uint order;      // spherical-harmonics order
    uint lights;     // point and directional lights (the light terms per sample)
    vec4 env;        // constant environment radiance rgb; w = 1 for the first chunk
    float env_factor; // the environment's mean boundary factor (1 for ior 1; sh_single.rs)
    float step;      // chord marching step for grid densities, scene units
    uint pad0;
    uint pad1;
} pc;

// erf, Abramowitz & Stegun 7.1.26 (|error| < 1.5e-7).
float erf_as(float x) {
    float t = 1.0 / (1.0 + 0.3275911 * abs(x));
    float y = 1.0 - (((((1.061405429 * t - 1.453152027) * t) + 1.421413741) * t - 0.284496736) * t + 0.254829592) * t * exp(-x * x);
    return x >= 0.0 ? y : -y;
}

// Optical depth of the chord from x along d over [0, t1] in material mat.
vec3 chord_tau(vec3 x, vec3 d, float t1, uint mat) {
    medium_mat = mat;
    if (DENSITY_KIND == DENSITY_CONSTANT) return scene.materials[mat].sigma_t.xyz * t1;
    uint steps = max(1u, uint(ceil(t1 / pc.step)));
    float dt = t1 / float(steps), s = 0.0;
    for (uint k = 0u; k < steps; ++k) s += density_at(x + d * ((float(k) + 0.5) * dt)) * dt;
    return scene.materials[mat].sigma_t.xyz * s;
}

// What the samples of this chunk scatter toward the camera along the inside segment from x
// along d over [0, t1]: sum_i nu_i sigma_s psi_i(-d) (lights + environment) int gamma_i.
vec3 segment_light(vec3 x, vec3 d, float t1) {
    uint n_coeff = pc.order * pc.order;
    float y[SH_MAX_COEFFS];
    sh_basis(d, pc.order, y);
    vec3 L = vec3(0.0);
    for (uint s = 0u; s < pc.count; ++s) {
        uint i = pc.first + s;
        vec4 ba = samples[2u * i];
        vec3 rel = ba.xyz - x;
        float tc = dot(rel, d);
        float h2 = max(0.0, dot(rel, rel) - tc * tc);
        float a = ba.w;
        if (a * h2 > 14.0) continue;   // exp(-14) < 1e-6: the thesis's cut (3.4.2)
        float sa = sqrt(a);
        float G = exp(-a * h2) * 0.5 * sqrt(PI / a) * (erf_as(sa * (t1 - tc)) + erf_as(sa * tc));
        if (G <= 0.0) continue;
        vec4 sg = samples[2u * i + 1u];
        float g = sg.w;
        vec3 lit = vec3(0.0);
        for (uint j = 0u; j < pc.lights; ++j) {
            vec4 e = lterms[2u * (i * pc.lights + j)];
            vec3 w = lterms[2u * (i * pc.lights + j) + 1u].xyz;
            lit += hg_eval(g, dot(w, d)) * e.rgb;
        }
        vec3 contrib;
        for (uint c = 0u; c < 3u; ++c) {
            float view = 0.0, envs = 0.0, gl = 1.0;
            uint base = (i * 3u + c) * n_coeff;
            for (uint l = 0u; l < pc.order; ++l) {
                float sign = (l & 1u) == 0u ? 1.0 : -1.0;
                for (uint k = l * l; k < (l + 1u) * (l + 1u); ++k) {
                    float cy = coeffs[base + k] * y[k];
                    view += sign * cy;
                    envs += gl * cy;
                }
                gl *= g;
            }
            contrib[c] = max(view, 0.0) * (lit[c] + pc.env[c] * pc.env_factor * max(envs, 0.0));
        }
        L += sg.rgb * contrib * G;
    }
    return L;
}

// Surface events of the camera ray's chain inside the object before it is cut (its weight
// below 1e-4 ends it sooner), as the view march's.
const uint MAX_BOUNCES = 16u;

void main() {
    uvec2 px = gl_GlobalInvocationID.xy;
    uvec2 res = scene.image.xy;
    if (px.x >= res.x || px.y >= res.y) return;
    uint pixel = px.y * res.x + px.x;
    bool first_chunk = pc.env.w > 0.5;
    vec3 o, d;
    camera_ray(vec2(px) + 0.5, o, d);
    float t_hit;
    uint tri;
    if (!mesh_hit_tri(o, d, 0.0, INF, t_hit, tri)) {
        if (first_chunk) radiance[pixel] = vec4(pc.env.rgb, 1.0);
        return;
    }
    vec3 n = triangle_normal(tri);
    vec3 nf = dot(d, n) < 0.0 ? n : -n;
    uint mat = triangle_material(tri);
    float ior = scene.materials[mat].ior.x;
    bool refracts = REFRACTIVE && ior != 1.0;
    float F = 0.0, eta = 1.0, cos_i = 1.0, cos_t = 1.0;
    vec3 din = d;
    if (refracts) {
        F = surface_fresnel(d, nf, true, ior, eta, cos_i, cos_t);
        din = refract_dir(d, nf, eta, cos_i, cos_t);
    }
    vec3 L = first_chunk ? pc.env.rgb * F : vec3(0.0);
    // The camera path's weight inside: (1 - F) / ior^2 at the entry, then each internal
    // reflection's F and each chord's transmittance.
    float n2 = refracts ? ior * ior : 1.0;
    vec3 w_cam = vec3((1.0 - F) / n2);
    vec3 x = o + d * t_hit - nf * surface_eps(o + d * t_hit);
    for (uint bounce = 0u; bounce < MAX_BOUNCES; ++bounce) {
        float t1;
        uint tri1;
        if (!mesh_hit_tri(x, din, 0.0, INF, t1, tri1)) break;   // a leak through a crack: nothing more
        L += w_cam * segment_light(x, din, t1);
        vec3 T = exp(-chord_tau(x, din, t1, mat));
        vec3 n1 = triangle_normal(tri1);
        vec3 nf1 = dot(din, n1) < 0.0 ? n1 : -n1;
        float F2 = refracts ? surface_fresnel(din, nf1, false, ior, eta, cos_i, cos_t) : 0.0;
        // Leaving: the environment seen through (radiance back to the vacuum's: times ior^2).
        if (first_chunk) L += w_cam * T * (1.0 - F2) * n2 * pc.env.rgb;
        w_cam *= T * F2;
        if (!refracts || max3(w_cam) * n2 < 1e-4) break;
        vec3 p1 = x + din * t1;
        din = reflect(din, nf1);
        x = p1 + nf1 * surface_eps(p1);
    }
    if (first_chunk) radiance[pixel] = vec4(L, 1.0);
    else radiance[pixel] += vec4(L, 0.0);
}
