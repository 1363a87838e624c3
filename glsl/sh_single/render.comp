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
// `single`'s view march does, and crosses index-matched surfaces straight, up to MAX_EVENTS.
// Left out: light reaching a sample along a refracted path (as `single`).
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
// [0]: the most loop back-edges any invocation counted (`iters`): past LOOP_GUARD llvmpipe's
// limiter may have cut a loop short, and the host renders again in smaller chunks.
layout(std430, binding = 9) buffer Stats { uint stats[]; };

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
    iters += steps;
    for (uint k = 0u; k < steps; ++k) s += density_at(x + d * ((float(k) + 0.5) * dt)) * dt;
    return scene.materials[mat].sigma_t.xyz * s;
}

// Loop back-edges sh_basis takes at `order` (its zero fill, then the bands), counted
// generously toward llvmpipe's limiter.
uint sh_basis_iters(uint order) { return SH_MAX_COEFFS + order + order * order * order; }

// What the samples of this chunk scatter toward the camera along the inside segment from x
// along d over [0, t1]: sum_i nu_i sigma_s psi_i(-d) (lights + environment) int gamma_i.
// The three channels share one pass over the coefficients (Y_lm(-d) = (-1)^l Y_lm(d)), so a
// sample costs order^2 + lights back-edges of llvmpipe's shared loop counter (budget.glsl),
// which the host keeps under the limiter by the chunk size.
vec3 segment_light(vec3 x, vec3 d, float t1) {
    uint n_coeff = pc.order * pc.order;
    float y[SH_MAX_COEFFS];
    sh_basis(d, pc.order, y);
    iters += sh_basis_iters(pc.order);
    vec3 L = vec3(0.0);
    for (uint s = 0u; s < pc.count; ++s) {
        iters++;
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
            iters++;
            vec4 e = lterms[2u * (i * pc.lights + j)];
            vec3 w = lterms[2u * (i * pc.lights + j) + 1u].xyz;
            lit += hg_eval(g, dot(w, d)) * e.rgb;
        }
        // psi_i(-d) (view) and the environment's Funk-Hecke sum (envs), per channel.
        vec3 view = vec3(0.0), envs = vec3(0.0);
        float gl = 1.0, sign = 1.0;
        uint l = 0u, next = 1u;
        uint base = i * 3u * n_coeff;
        for (uint k = 0u; k < n_coeff; ++k) {
            iters++;
            if (k == next) {
                ++l;
                next = (l + 1u) * (l + 1u);
                gl *= g;
                sign = -sign;
            }
            vec3 c = vec3(coeffs[base + k], coeffs[base + n_coeff + k], coeffs[base + 2u * n_coeff + k]) * y[k];
            view += sign * c;
            envs += gl * c;
        }
        vec3 contrib = max(view, vec3(0.0)) * (lit + pc.env.rgb * pc.env_factor * max(envs, vec3(0.0)));
        L += sg.rgb * contrib * G;
    }
    return L;
}

// Surface events of the camera ray's chain before it is cut (a refracting object's internal
// reflections end sooner, when their weight falls below 1e-4, as the view march's).
const uint MAX_EVENTS = 32u;

void main() {
    uvec2 px = gl_GlobalInvocationID.xy;
    uvec2 res = scene.image.xy;
    if (px.x >= res.x || px.y >= res.y) return;
    uint pixel = px.y * res.x + px.x;
    bool first_chunk = pc.env.w > 0.5;
    vec3 x, d;
    camera_ray(vec2(px) + 0.5, x, d);
    // The camera path's weight: (1 - F) / ior^2 at a refracting entry, each internal
    // reflection's F, each inside chord's transmittance. Index-matched surfaces (ior 1, and a
    // v1 medium's box) are crossed straight: the ray goes on to any object behind. A crossing
    // that leaves an object closes the inside segment before it, so a camera inside the medium
    // is handled too.
    vec3 w = vec3(1.0);
    vec3 L = vec3(0.0);
    for (uint e = 0u; e < MAX_EVENTS; ++e) {
        iters++;
        float t;
        uint tri;
        if (!mesh_hit_tri(x, d, 0.0, INF, t, tri)) {
            if (first_chunk) L += w * pc.env.rgb;   // escapes: the environment behind
            break;
        }
        vec3 n = triangle_normal(tri);
        bool entering = dot(d, n) < 0.0;
        vec3 nf = entering ? n : -n;
        uint mat = triangle_material(tri);
        if (!entering) {
            L += w * segment_light(x, d, t);
            w *= exp(-chord_tau(x, d, t, mat));
        }
        vec3 p = x + d * t;
        float ior = scene.materials[mat].ior.x;
        if (!(REFRACTIVE && ior != 1.0)) {
            x = p - nf * surface_eps(p);   // straight through
            continue;
        }
        float n2 = ior * ior, eta = 1.0, cos_i = 1.0, cos_t = 1.0;
        float F = surface_fresnel(d, nf, entering, ior, eta, cos_i, cos_t);
        if (entering) {
            // The environment reflected at the entry; radiance refracted in, times 1 / ior^2.
            if (first_chunk) L += w * F * pc.env.rgb;
            w *= (1.0 - F) / n2;
            d = refract_dir(d, nf, eta, cos_i, cos_t);
            x = p - nf * surface_eps(p);
        } else {
            // Leaving: the environment seen through (radiance back to the vacuum's: times
            // ior^2); the reflected share goes on inside.
            if (first_chunk) L += w * (1.0 - F) * n2 * pc.env.rgb;
            w *= F;
            if (max3(w) * n2 < 1e-4) break;
            d = reflect(d, nf);
            x = p + nf * surface_eps(p);
        }
    }
    if (first_chunk) radiance[pixel] = vec4(L, 1.0);
    else radiance[pixel] += vec4(L, 0.0);
    atomicMax(stats[0], iters);
}
