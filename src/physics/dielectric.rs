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

/// Snell's law in vector form (glsl/include/dielectric.glsl `refract_dir`): the direction of
/// unit `d` after it crosses a surface of unit normal `n` facing the side it comes from,
/// eta = n_i / n_t; None under total internal reflection.
pub fn refract(d: glam::DVec3, n: glam::DVec3, eta: f64) -> Option<glam::DVec3> {
    let cos_i = -d.dot(n);
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i);
    (sin2_t < 1.0).then(|| (eta * d + (eta * cos_i - (1.0 - sin2_t).sqrt()) * n).normalize())
}

/// Where light from a point `light` outside a plane (point `q` on it, unit normal `n` toward
/// the light's side) refracts on its way to a point `x` on the other side, inside a medium of
/// index `ior` (vacuum outside): the point of the plane where Snell's law
/// sin(theta_o) = ior sin(theta_i) holds along light -> p -> x. None when the light and `x` are
/// not on opposite sides. The manifold next-event estimation of glsl/path/trace.comp solves
/// the same equation, per flat facet (`refraction_point` in glsl/include/mesh.glsl).
///
/// The point lies on the segment between the two feet in the plane, at the fraction s of it
/// where f(s) = (1 - s) D / |((1 - s) D, h)| - ior s D / |(s D, d)| vanishes (h, d the light's
/// and x's distances to the plane, D the feet's distance): f falls from > 0 to < 0 over
/// [0, 1], so bisection finds the one root.
pub fn refraction_point(
    light: glam::DVec3,
    x: glam::DVec3,
    q: glam::DVec3,
    n: glam::DVec3,
    ior: f64,
) -> Option<glam::DVec3> {
    let h = (light - q).dot(n);
    let d = (q - x).dot(n);
    if !(h > 0.0 && d > 0.0) {
        return None;
    }
    let (lf, xf) = (light - h * n, x + d * n);
    let dd = lf.distance(xf);
    let f = |s: f64| (1.0 - s) * dd / ((1.0 - s) * dd).hypot(h) - ior * s * dd / (s * dd).hypot(d);
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if f(mid) > 0.0 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Some(xf + (lf - xf) * (0.5 * (lo + hi)))
}

/// Irradiance (W/m^2 on a surface facing the ray) at a point inside a medium of index `ior`
/// from a point light of intensity `intensity` (W/sr) in the vacuum outside, through a flat
/// smooth boundary: the light travels `l_o` to the boundary, arriving at cosine `cos_o` to the
/// normal, and refracts to travel `l_i` inside at cosine `cos_i`.
///
/// E = I (1 - F) / [(l_o + l_i / ior) (l_o cos_i / cos_o + (l_i / ior) cos_o / cos_i)].
///
/// Derivation (flux conservation in a thin tube of rays): the light's solid angle
/// sin(theta_o) dtheta_o dphi lands inside on a patch of width R dphi across the plane of
/// incidence (R = l_o sin(theta_o) + l_i sin(theta_i), the lateral distance) and
/// cos(theta_i) dR along it, with dtheta_i / dtheta_o = cos(theta_o) / (ior cos(theta_i)) from
/// Snell's law; sin(theta_o) / R = 1 / (l_o + l_i / ior) and cos(theta_i) dR / dtheta_o is the
/// second factor. At ior 1 it is I / (l_o + l_i)^2; at normal incidence
/// I (1 - F) / (l_o + l_i / ior)^2, the apparent depth. The radiance this irradiance scatters
/// inside is physical radiance; path's camera paths carry the 1 / ior^2 of their own entry.
pub fn refracted_point_irradiance(intensity: f64, l_o: f64, cos_o: f64, l_i: f64, cos_i: f64, ior: f64) -> f64 {
    let t = 1.0 - fresnel_dielectric(cos_o, 1.0 / ior);
    let li_n = l_i / ior;
    intensity * t / ((l_o + li_n) * (l_o * cos_i / cos_o + li_n * cos_o / cos_i))
}

/// Irradiance on a surface facing the ray inside a medium of index `ior` from a directional
/// light of irradiance `irradiance` (W/m^2, on a surface facing it) in the vacuum outside,
/// refracted through a flat boundary it meets at cosine `cos_o`, going on at cosine `cos_i`:
/// E (1 - F) cos_o / cos_i (a beam's cross-section grows from cos_o to cos_i per unit of
/// boundary area).
pub fn refracted_directional_irradiance(irradiance: f64, cos_o: f64, cos_i: f64, ior: f64) -> f64 {
    irradiance * (1.0 - fresnel_dielectric(cos_o, 1.0 / ior)) * cos_o / cos_i
}

/// Every way a light outside a convex object of flat facets (index `ior`, vacuum outside)
/// reaches the point `x` inside by one refraction: for each facet (`v0`, `e1 = v1 - v0`,
/// `e2 = v2 - v0`, wound outward) whose plane's refraction point lies on the facet, that point
/// and the irradiance it delivers at x ([`refracted_point_irradiance`] per unit intensity for
/// a point light at `light`; [`refracted_directional_irradiance`] per unit irradiance for a
/// directional light travelling along `light` when `point` is false). The CPU reference of
/// glsl/include/mesh.glsl `facet_refraction` summed over the facets, as `path`'s manifold
/// next-event estimation does.
pub fn facet_irradiance(
    facets: &[[glam::DVec3; 3]],
    x: glam::DVec3,
    light: glam::DVec3,
    point: bool,
    ior: f64,
) -> Vec<(glam::DVec3, f64)> {
    let mut out = Vec::new();
    for &[v0, e1, e2] in facets {
        let n = e1.cross(e2).normalize();
        let ps = if point {
            // The point lies on the segment between the feet of the light and x in the plane:
            // skip facets whose bounding circle that segment misses (most of them).
            let (h, dx) = ((light - v0).dot(n), (v0 - x).dot(n));
            if !(h > 0.0 && dx > 0.0) {
                continue;
            }
            let (lf, xf) = (light - h * n, x + dx * n);
            let m = v0 + (e1 + e2) / 3.0;
            let r2 = (v0 - m).length_squared().max((v0 + e1 - m).length_squared()).max((v0 + e2 - m).length_squared());
            let seg = lf - xf;
            let s = if seg.length_squared() > 0.0 {
                ((m - xf).dot(seg) / seg.length_squared()).clamp(0.0, 1.0)
            } else {
                0.0
            };
            if (xf + seg * s - m).length_squared() > r2 * 1.0001 {
                continue;
            }
            let Some(ps) = refraction_point(light, x, v0, n, ior) else { continue };
            ps
        } else {
            let cos_o = -light.dot(n);
            if cos_o.is_nan() || cos_o <= 0.0 {
                continue;
            }
            let Some(wt) = refract(light, n, 1.0 / ior) else { continue };
            let cos_i = -wt.dot(n);
            let dx = (v0 - x).dot(n);
            if !(cos_i > 0.0 && dx > 0.0) {
                continue;
            }
            x - wt * (dx / cos_i)
        };
        // On the facet (barycentric coordinates).
        let w = ps - v0;
        let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
        let (w1, w2) = (w.dot(e1), w.dot(e2));
        let den = d11 * d22 - d12 * d12;
        let u = (d22 * w1 - d12 * w2) / den;
        let v = (d11 * w2 - d12 * w1) / den;
        if !(u >= 0.0 && v >= 0.0 && u + v <= 1.0) {
            continue;
        }
        let to = ps - x;
        let (l_i, cos_i) = (to.length(), to.normalize().dot(n));
        let e = if point {
            let out_dir = light - ps;
            let l_o = out_dir.length();
            let cos_o = out_dir.dot(n) / l_o;
            if !(cos_o > 0.0 && cos_i > 0.0) {
                continue;
            }
            refracted_point_irradiance(1.0, l_o, cos_o, l_i, cos_i, ior)
        } else {
            refracted_directional_irradiance(1.0, -light.dot(n), cos_i, ior)
        };
        out.push((ps, e));
    }
    out
}
