// phase.glsl: Henyey-Greenstein phase function (thesis eq. 1.10; pbrt-v4 11.3.1).
// cos_theta is between propagation directions (common.glsl); g > 0 scatters forward.
// The Rust twin is src/physics/phase.rs; tests/phase_gpu.rs checks they agree.
#ifndef SCATTERLAB_PHASE
#define SCATTERLAB_PHASE
#include "common.glsl"

// p(cos_theta) = (1 - g^2) / (4 pi (1 + g^2 - 2 g cos_theta)^(3/2)), 1/sr. The denominator
// is formed as a sum of non-negative terms so it keeps its digits for |g| up to 0.999 with
// cos_theta near +-1 (same form as src/physics/phase.rs).
float hg_eval(float g, float cos_theta) {
    float c = clamp(cos_theta, -1.0, 1.0);
    float denom = g >= 0.0 ? (1.0 - g) * (1.0 - g) + 2.0 * g * (1.0 - c)
                           : (1.0 + g) * (1.0 + g) - 2.0 * g * (1.0 + c);
    return INV_4PI * (1.0 - g) * (1.0 + g) / (denom * sqrt(max(denom, 1e-30)));
}

// Inverse-CDF sample of cos_theta, increasing in u, with 1 - cos_theta formed without
// cancellation; the forward lobe with |g|, mirrored for g < 0. Exactly 2u - 1 at g = 0, so no
// isotropic branch is needed (one would bias the density by up to 3|g|). Returns
// (cos_theta, sin_theta^2).
vec2 hg_sample_cos_sin2(float g, float u) {
    float ga = abs(g);
    float ua = g >= 0.0 ? u : 1.0 - u;
    float d = 1.0 - ga + 2.0 * ga * ua;
    float t = (1.0 - ga) * (1.0 + ga) / d;
    float omc = clamp((1.0 - ga) * (1.0 - ua) * (t + 1.0 - ga) / d, 0.0, 2.0);
    float sin2 = omc * (2.0 - omc);
    return vec2(g >= 0.0 ? 1.0 - omc : omc - 1.0, sin2);
}

float hg_sample_cos(float g, float u) { return hg_sample_cos_sin2(g, u).x; }

// A direction around `dir` distributed as HG; its pdf is hg_eval(g, dot(dir, result)).
vec3 hg_sample(float g, vec3 dir, vec2 u) {
    vec2 cs = hg_sample_cos_sin2(g, u.x);
    float ct = cs.x;
    float st = sqrt(max(0.0, cs.y));
    float phi = 2.0 * PI * u.y;
    vec3 t, b;
    onb(dir, t, b);
    return normalize(st * cos(phi) * t + st * sin(phi) * b + ct * dir);
}
#endif
