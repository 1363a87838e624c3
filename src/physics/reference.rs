//! Analytic ray-geometry references for GPU tests: ray/box and ray/sphere intervals,
//! chord lengths, and the transmittance of a homogeneous medium along them.
//!
//! Conventions: a ray is `origin + t * dir` with `t >= 0`; `dir` need not be unit length
//! (`t` is then in units of `|dir|`). The intersection functions return the interval of the
//! whole *line* inside the solid, `t0 <= t1`, so `t0 < 0` means the origin is inside; they
//! return `None` when the line misses or the solid lies entirely behind the origin
//! (`t1 < 0`). Touching (`t0 == t1`) counts as a hit. Chord helpers clip to `t >= 0` and
//! return lengths in scene units. Arithmetic is in f64 so the references are more exact
//! than the f32 GPU code they check.

use glam::{DVec3, Vec3};

/// Interval `(t0, t1)` of the line `origin + t dir` inside the axis-aligned box
/// `[min, max]` (slab method), or `None` if the ray misses it.
///
/// Axes where `dir` is zero are handled exactly: the ray hits only if its origin lies
/// within that slab (boundary included).
pub fn ray_box(origin: Vec3, dir: Vec3, min: Vec3, max: Vec3) -> Option<(f32, f32)> {
    let (o, d) = (origin.as_dvec3(), dir.as_dvec3());
    let (lo, hi) = (min.as_dvec3(), max.as_dvec3());
    let mut t0 = f64::NEG_INFINITY;
    let mut t1 = f64::INFINITY;
    for axis in 0..3 {
        if d[axis] == 0.0 {
            if o[axis] < lo[axis] || o[axis] > hi[axis] {
                return None;
            }
            continue;
        }
        let inv = 1.0 / d[axis];
        let (a, b) = ((lo[axis] - o[axis]) * inv, (hi[axis] - o[axis]) * inv);
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    if t0 > t1 || t1 < 0.0 || !t0.is_finite() || !t1.is_finite() {
        return None;
    }
    Some((t0 as f32, t1 as f32))
}

/// Interval `(t0, t1)` of the line `origin + t dir` inside the sphere, or `None` if the ray
/// misses it.
///
/// Uses the cancellation-free discriminant of Haines et al., "Precision Improvements for
/// Ray/Sphere Intersection" (Ray Tracing Gems, ch. 7, 2019), and the stable root pair.
pub fn ray_sphere(origin: Vec3, dir: Vec3, center: Vec3, radius: f32) -> Option<(f32, f32)> {
    let (o, d, c) = (origin.as_dvec3(), dir.as_dvec3(), center.as_dvec3());
    let r = f64::from(radius);
    let a = d.length_squared();
    if a == 0.0 {
        return None;
    }
    let f = o - c;
    let b = -f.dot(d); // half of the usual -b
                       // r^2 - |f - (f.d / d.d) d|^2: distance of the line from the centre, without cancellation.
    let perp: DVec3 = f + (b / a) * d;
    let disc = a * (r * r - perp.length_squared());
    if disc < 0.0 {
        return None;
    }
    let q = b + b.signum() * disc.sqrt();
    let c_coef = f.length_squared() - r * r;
    let (mut t0, mut t1) = if q == 0.0 {
        // Origin at the centre of a zero-radius sphere, or similar degenerate case.
        (0.0, 0.0)
    } else {
        (c_coef / q, q / a)
    };
    if t0 > t1 {
        std::mem::swap(&mut t0, &mut t1);
    }
    if t1 < 0.0 {
        return None;
    }
    Some((t0 as f32, t1 as f32))
}

/// Length (scene units) of the part of the ray `t >= 0` inside the box; 0 if it misses.
pub fn chord_length_box(origin: Vec3, dir: Vec3, min: Vec3, max: Vec3) -> f32 {
    ray_box(origin, dir, min, max).map_or(0.0, |(t0, t1)| ((t1 - t0.max(0.0)) * dir.length()).max(0.0))
}

/// Length (scene units) of the part of the ray `t >= 0` inside the sphere; 0 if it misses.
pub fn chord_length_sphere(origin: Vec3, dir: Vec3, center: Vec3, radius: f32) -> f32 {
    ray_sphere(origin, dir, center, radius).map_or(0.0, |(t0, t1)| ((t1 - t0.max(0.0)) * dir.length()).max(0.0))
}

/// Chord of a sphere at distance `impact` from its centre: `2 sqrt(r^2 - b^2)`, 0 beyond.
pub fn sphere_chord_at_impact(radius: f64, impact: f64) -> f64 {
    2.0 * (radius * radius - impact * impact).max(0.0).sqrt()
}

/// Mean chord length of a convex body under uniform isotropic lines: `4 V / S`
/// (Cauchy's formula). For a sphere of radius r this is `4 r / 3`; for a box with sides
/// `a, b, c` it is `2 a b c / (a b + b c + c a)`.
pub fn cauchy_mean_chord(volume: f64, surface_area: f64) -> f64 {
    4.0 * volume / surface_area
}

/// Transmittance `exp(-sigma_t * length)` of a homogeneous medium (`sigma_t` in 1/unit).
pub fn transmittance(sigma_t: f64, length: f64) -> f64 {
    (-sigma_t * length).exp()
}
