// dielectric.glsl: a smooth dielectric interface, Fresnel reflectance and Snell's law (the
// [[object]] boundary of path; glsl/probe/fresnel.comp checks it against the CPU formulas).
#ifndef SCATTERLAB_DIELECTRIC
#define SCATTERLAB_DIELECTRIC

// Unpolarised Fresnel reflectance of a smooth dielectric for light arriving at cosine
// cos_i (> 0) on the side of index n_i toward index n_t, eta = n_i / n_t; sets cos_t to the
// transmitted cosine (0 under total internal reflection, which returns 1). Born & Wolf 1.5.3;
// pbrt-v4's FrDielectric.
float fresnel_dielectric(float cos_i, float eta, out float cos_t) {
    float sin2_t = eta * eta * max(0.0, 1.0 - cos_i * cos_i);
    if (sin2_t >= 1.0) { cos_t = 0.0; return 1.0; }
    cos_t = sqrt(1.0 - sin2_t);
    float r_par = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);     // (n_t cos_i - n_i cos_t) / (...)
    float r_perp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);    // (n_i cos_i - n_t cos_t) / (...)
    return 0.5 * (r_par * r_par + r_perp * r_perp);
}

// The smooth dielectric where a ray along unit d meets an object of index `ior` (in vacuum),
// with unit normal nf facing the side the ray comes from, `entering` the object or leaving it:
// eta = n_i / n_t, the incident and transmitted cosines, and the Fresnel reflectance (1 under
// total internal reflection). Path's surface event and the view march's chain share it.
float surface_fresnel(vec3 d, vec3 nf, bool entering, float ior, out float eta, out float cos_i, out float cos_t) {
    eta = entering ? 1.0 / ior : ior;   // n_i / n_t
    cos_i = clamp(-dot(d, nf), 0.0, 1.0);
    return fresnel_dielectric(cos_i, eta, cos_t);
}

// Direction after refraction of unit d through a surface of unit normal nf facing the
// incoming side (dot(d, nf) < 0), eta = n_i / n_t, cos_t from fresnel_dielectric: Snell's law
// in vector form, t = eta d + (eta cos_i - cos_t) nf.
vec3 refract_dir(vec3 d, vec3 nf, float eta, float cos_i, float cos_t) {
    return normalize(eta * d + (eta * cos_i - cos_t) * nf);
}
#endif
