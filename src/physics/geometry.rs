//! Ray geometry in f64 on the host: the intervals of a line inside a box or a sphere (used by
//! solvers to start rays where they enter the medium, and by tests as exact references).
//!
//! Conventions: a ray is `origin + t * dir` with `t >= 0`; `dir` need not be unit length
//! (`t` is then in units of `|dir|`). The functions return the interval of the whole *line*
//! inside the solid, `t0 <= t1`, so `t0 < 0` means the origin is inside; they return `None`
//! when the line misses or the solid lies entirely behind the origin (`t1 < 0`). Touching
//! (`t0 == t1`) counts as a hit.

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
