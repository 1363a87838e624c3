//! A smooth dielectric boundary on the CPU: the Fresnel reflectance of glsl/include/dielectric.glsl
//! and its diffuse (hemispherical) mean, which `lbl`'s lattice reflects at a refractive object's
//! surface (glsl/lattice/diffuse.comp).

/// Unpolarised Fresnel reflectance (Born & Wolf 1.5.3) for light arriving at cosine `cos_i`
/// (> 0) on the side of index n_i, eta = n_i / n_t; 1 under total internal reflection. The
/// formula of glsl/include/dielectric.glsl's `fresnel_dielectric`, in f64.
pub fn fresnel_dielectric(cos_i: f64, eta: f64) -> f64 {
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let r_perp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let r_par = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    0.5 * (r_perp * r_perp + r_par * r_par)
}

/// The cosine-weighted hemispherical mean 2 int_0^1 F(mu) mu dmu of [`fresnel_dielectric`] for
/// light arriving on the side of index n_i, eta = n_i / n_t: the share of a diffuse (Lambertian)
/// flux the boundary reflects. 0 at eta 1; 0.596 from inside glass (eta 1.5; Egan and
/// Hilgeman's fit, which the dipole model uses, gives 0.596 there too). Midpoint rule on 4096
/// cosines.
pub fn diffuse_fresnel(eta: f64) -> f64 {
    let n = 4096;
    let sum: f64 = (0..n)
        .map(|k| {
            let mu = (k as f64 + 0.5) / n as f64;
            fresnel_dielectric(mu, eta) * mu
        })
        .sum();
    2.0 * sum / n as f64
}
