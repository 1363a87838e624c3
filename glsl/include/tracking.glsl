// tracking.glsl: free-flight sampling and transmittance shared by the path kernels
// (path/trace: camera paths; path/light: light paths): delta/spectral tracking to the next
// real scattering, ratio tracking of the transmittance, and the phase function as the scene's
// specialisation selects it. Needs scene.glsl, rng.glsl, phase.glsl and budget.glsl first.
#ifndef SCATTERLAB_TRACKING
#define SCATTERLAB_TRACKING

float phase_eval(float g, float c) { return ANISOTROPIC ? hg_eval(g, c) : INV_4PI; }
vec3 phase_sample(float g, vec3 d, vec2 u) { return ANISOTROPIC ? hg_sample(g, d, u) : uniform_sphere(u); }

// Tentative collisions of the current path, the cap past which it is dropped (set by the
// kernel from its push constants), and whether it was.
uint collisions;
uint collision_cap;
bool truncated;

// Ratio tracking (Novak et al. 2014) of the transmittance from p along w over [0, t_far]:
// T *= sigma_n / sigma_maj per tentative collision, per channel; unbiased for each channel
// since sigma_maj >= max channel sigma_t. Russian roulette on small T stays unbiased.
vec3 transmittance(vec3 p, vec3 w, float t_far, inout uvec2 rng) {
    vec2 iv = medium_interval(p, w);
    iv.x = max(iv.x, 0.0);
    iv.y = min(iv.y, t_far);
    vec3 T = vec3(1.0);
    Segments s = segments_begin(p, w, iv.x, iv.y);
    float t0, t1, smaj;
    while (segments_next(s, t0, t1, smaj)) {
        iters++;
        if (smaj <= 0.0) continue;
        float t = t0;
        while (true) {
            iters++;
            t -= log(1.0 - rnd(rng)) / smaj;
            if (t >= t1) break;
            collisions++;
            vec3 st = scene.sigma_t.xyz * density_at(p + w * t);
            T *= max(vec3(0.0), smaj - st) / smaj;
            float m = max3(T);
            if (m < 0.1) {
                if (rnd(rng) >= 0.5) return vec3(0.0);
                T *= 2.0;
            }
            if (collisions > collision_cap) { truncated = true; return vec3(0.0); }
        }
    }
    return T;
}

// Delta/spectral tracking to the next real scattering event. Returns true and sets `t_hit`
// on a scattering; false when the path escapes (beta then weights the escape) or dies (beta 0).
bool next_scatter(vec3 o, vec3 d, inout vec3 beta, inout uvec2 rng, out float t_hit) {
    vec2 iv = medium_interval(o, d);
    iv.x = max(iv.x, 0.0);
    Segments s = segments_begin(o, d, iv.x, iv.y);
    float t0, t1, smaj;
    while (segments_next(s, t0, t1, smaj)) {
        iters++;
        if (smaj <= 0.0) continue;
        float t = t0;
        while (true) {
            iters++;
            t -= log(1.0 - rnd(rng)) / smaj;
            if (t >= t1) break;
            collisions++;
            if (collisions > collision_cap) { truncated = true; beta = vec3(0.0); return false; }
            vec3 st = scene.sigma_t.xyz * density_at(o + d * t);
            vec3 ss = st * scene.albedo.xyz;
            vec3 sn = max(vec3(0.0), smaj - st);
            if (!CHROMATIC) {
                // Grey: scatter with probability sigma_s / (sigma_s + sigma_n); absorption is
                // carried by the weight (sigma_maj - sigma_a) / sigma_maj, the same on both branches.
                float denom = ss.x + sn.x;
                if (denom <= 0.0) { beta = vec3(0.0); return false; }
                beta *= denom / smaj;
                if (rnd(rng) * denom < ss.x) { t_hit = t; return true; }
            } else {
                // Spectral tracking, history-aware probabilities (Kutz 2017, eq. 15-16).
                float ws = avg3(beta * ss);
                float wn = avg3(beta * sn);
                if (ws + wn <= 0.0) { beta = vec3(0.0); return false; }
                float ps = ws / (ws + wn);
                if (rnd(rng) < ps) {
                    beta *= ss / (smaj * ps);
                    t_hit = t;
                    return true;
                }
                beta *= sn / (smaj * (1.0 - ps));
            }
        }
    }
    return false;
}

// Power heuristic (Veach 1997) for two strategies with one sample each.
float mis_power(float a, float b) { return a * a / (a * a + b * b); }
#endif
