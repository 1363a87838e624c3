//! Analytic references for GPU tests: chord lengths through a box or a sphere (from the
//! intervals of [`super::geometry`]) and the transmittance of a homogeneous medium along them.
//! Chord helpers clip to `t >= 0` and return lengths in scene units. Arithmetic is in f64 so
//! the references are more exact than the f32 GPU code they check.

pub use super::geometry::{ray_box, ray_sphere};

use glam::Vec3;

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
