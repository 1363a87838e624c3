// view.glsl: what the view march (view/march.comp) and its shadow volume (view/shadow.comp)
// share: the density integral along a shadow ray, the environment quadrature's directions,
// and the light units (one per point or directional light, env_dirs per environment).
// Needs scene.glsl and budget.glsl (`iters`) first.
#ifndef SCATTERLAB_VIEW
#define SCATTERLAB_VIEW

// The scene has an environment light (the host's Modelled::environment; on with --model-all).
// Off, the environment's quadrature (its light units and the per-ray phase norm of the view
// march) is not compiled in: a scene without one would otherwise pay env_dirs phase
// evaluations per camera ray for a norm that it never uses. glsl/path/trace.comp declares the
// same constant (id 16) for its own environment code.
layout(constant_id = 16) const bool ENVIRONMENT = true;
bool is_environment(uint kind) { return ENVIRONMENT && kind == LIGHT_ENVIRONMENT; }

// Integral of the grid density from p along w over [0, t_far] inside the medium, midpoint
// rule in steps of at most `step` (piecewise-constant extinction, as everywhere in the view
// pass). Multiplied by sigma_t it is the optical depth.
float density_depth(vec3 p, vec3 w, float t_far, float step) {
    vec2 iv = medium_interval(p, w);
    float a = max(iv.x, 0.0);
    float b = min(iv.y, t_far);
    if (!(a < b)) return 0.0;
    float len = b - a;
    uint n = max(1u, uint(ceil(len / step)));
    float dt = len / float(n);
    float tau = 0.0;
    for (uint i = 0u; i < n; ++i) {
        iters++;
        tau += density_at(p + w * (a + (float(i) + 0.5) * dt));
    }
    return tau * dt;
}

// Spherical Fibonacci direction i of n (uniform quadrature weight 4 pi / n).
vec3 fibonacci_dir(uint i, uint n) {
    float golden = 2.39996322972865332;   // pi (3 - sqrt 5)
    float z = 1.0 - (2.0 * float(i) + 1.0) / float(n);
    float r = sqrt(max(0.0, 1.0 - z * z));
    float phi = golden * float(i);
    return vec3(r * cos(phi), r * sin(phi), z);
}

// Light unit j seen from p: the direction toward it and how far (INF for directional and
// environment units). False past the last unit.
bool unit_light(uint j, vec3 p, uint env_dirs, out vec3 wi, out float dist) {
    wi = vec3(0.0, 0.0, 1.0);
    dist = INF;
    for (uint i = 0u; i < scene.image.z; ++i) {
        iters++;
        Light li = scene.lights[i];
        uint kind = uint(li.pos_kind.w);
        uint n = is_environment(kind) ? env_dirs : 1u;
        if (j >= n) { j -= n; continue; }
        if (kind == LIGHT_POINT) {
            vec3 to = li.pos_kind.xyz - p;
            dist = length(to);
            wi = dist > 0.0 ? to / dist : wi;
        } else if (kind == LIGHT_DIRECTIONAL) {
            wi = -li.pos_kind.xyz;
        } else {
            wi = fibonacci_dir(j, env_dirs);
        }
        return true;
    }
    return false;
}
#endif
