// phase.glsl: Henyey-Greenstein phase function (thesis eq. 1.10; pbrt-v4 11.3.1).
// cos_theta is between propagation directions (common.glsl); g > 0 scatters forward.
// The Rust twin is src/physics/phase.rs; tests/phase_gpu.rs checks they agree.
#ifndef SCATTERLAB_PHASE
#define SCATTERLAB_PHASE
#include "common.glsl"

// p(cos_theta) = (1 - g^2) / (4 pi (1 + g^2 - 2 g cos_theta)^(3/2)), 1/sr.
float hg_eval(float g, float cos_theta) {
    float denom = 1.0 + g * g - 2.0 * g * cos_theta;
    return INV_4PI * (1.0 - g * g) / (denom * sqrt(max(denom, 1e-12)));
}

// Inverse-CDF sample of cos_theta; isotropic below |g| = 1e-3 where the closed form cancels.
float hg_sample_cos(float g, float u) {
    if (abs(g) < 1e-3) return 1.0 - 2.0 * u;
    float s = (1.0 - g * g) / (1.0 + g - 2.0 * g * u);
    return clamp((1.0 + g * g - s * s) / (2.0 * g), -1.0, 1.0);
}

// A direction around `dir` distributed as HG; its pdf is hg_eval(g, dot(dir, result)).
vec3 hg_sample(float g, vec3 dir, vec2 u) {
    float ct = hg_sample_cos(g, u.x);
    float st = sqrt(max(0.0, 1.0 - ct * ct));
    float phi = 2.0 * PI * u.y;
    vec3 t, b;
    onb(dir, t, b);
    return normalize(st * cos(phi) * t + st * sin(phi) * b + ct * dir);
}
#endif
