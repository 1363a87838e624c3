//! Henyey-Greenstein phase function: evaluation and importance sampling.
//!
//! # Direction convention (the only place it is written)
//!
//! `cos_theta` is the cosine of the angle between the **incoming propagation direction** (the
//! way light travels before the scattering event) and the **outgoing propagation direction**
//! (the way it travels after). Both point along the flow of light. `cos_theta = 1` means
//! "straight on, undeflected"; `cos_theta = -1` means "sent back where it came from".
//! With this convention **g > 0 scatters forward**, g < 0 backward, g = 0 is isotropic, and
//! the mean of `cos_theta` over the phase function is exactly `g`.
//!
//! Note that pbrt-v4 passes `wo` pointing *away* from the camera (against the flow), so its
//! `HenyeyGreenstein(Dot(wo, wi), g)` differs in sign from `hg_eval(g, cos_theta)` here.
//!
//! # Formulas (the GLSL twin in `glsl/include/phase.glsl` uses the same ones)
//!
//! Henyey & Greenstein (1941), normalised over the sphere, in 1/sr:
//!
//! ```text
//! p(g, c) = (1 - g^2) / (4 pi (1 + g^2 - 2 g c)^(3/2))
//! ```
//!
//! The denominator is written as a sum of two non-negative terms so it never loses digits
//! to cancellation when `c` is near +-1 and `|g|` near 1:
//!
//! ```text
//! 1 + g^2 - 2 g c = (1 - g)^2 + 2 g (1 - c)      (g >= 0)
//!                 = (1 + g)^2 - 2 g (1 + c)      (g <  0)
//! ```
//!
//! Sampling inverts the CDF of `c` (monotone increasing in `u`). The textbook inverse
//!
//! ```text
//! c = (1 + g^2 - ((1 - g^2) / (1 - g + 2 g u))^2) / (2 g)
//! ```
//!
//! divides by `g` and cancels catastrophically near `c = 1` for large `g`. Factoring the
//! numerator gives, with `t = (1 - g^2) / (1 - g + 2 g u)`, the equivalent
//!
//! ```text
//! 1 - c = (1 - g) (1 - u) (t + 1 - g) / (1 - g + 2 g u)
//! ```
//!
//! whose factors are all non-negative for g >= 0: no division by `g`, no cancellation. At
//! g = 0 it is exactly the isotropic inverse `c = 2u - 1`. Negative `g` is sampled as the
//! mirror image, `c(g, u) = -c(-g, 1 - u)`, which is again the exact inverse CDF.

use glam::{Vec2, Vec3};

/// 1 / (4 pi): the isotropic phase function, in 1/sr.
pub const INV_FOUR_PI: f32 = 0.25 * std::f32::consts::FRAC_1_PI;

/// Henyey-Greenstein phase function value in 1/sr.
///
/// `cos_theta` follows the module's convention (incoming and outgoing *propagation*
/// directions; g > 0 forward). Integrates to 1 over the sphere; equals 1/(4 pi) at g = 0.
/// Accurate for |g| up to 0.999 and `cos_theta` arbitrarily close to +-1; `cos_theta` is
/// clamped to [-1, 1].
pub fn hg_eval(g: f32, cos_theta: f32) -> f32 {
    debug_assert!(g.abs() < 1.0, "asymmetry parameter g must lie in (-1, 1), got {g}");
    let c = cos_theta.clamp(-1.0, 1.0);
    // 1 + g^2 - 2 g c as a sum of non-negative terms (see module docs).
    let denom = if g >= 0.0 {
        (1.0 - g) * (1.0 - g) + 2.0 * g * (1.0 - c)
    } else {
        (1.0 + g) * (1.0 + g) - 2.0 * g * (1.0 + c)
    };
    INV_FOUR_PI * (1.0 - g) * (1.0 + g) / (denom * denom.sqrt())
}

/// Sample `cos_theta` from the Henyey-Greenstein distribution by inverting its CDF.
///
/// `u` in [0, 1]; the result is monotone increasing in `u`, from -1 at `u = 0` to 1 at
/// `u = 1`. Its density (per unit `cos_theta`, integrated over azimuth) is
/// `2 pi hg_eval(g, cos_theta)`.
///
/// There is no separate isotropic branch: the factored inverse has no division by `g` and
/// gives `2u - 1` exactly at g = 0. (A branch switching to isotropic below some small |g|
/// would make the sampled density differ from [`hg_eval`] by up to `3 |g|` relative.)
pub fn hg_sample_cos(g: f32, u: f32) -> f32 {
    hg_sample_cos_sin2(g, u).0
}

/// `(cos_theta, sin_theta^2)` of an HG sample; `sin^2 = (1 - c)(1 + c)` is formed from the
/// factored `1 - c` of the forward lobe, so it keeps its digits when `c` is near +-1.
fn hg_sample_cos_sin2(g: f32, u: f32) -> (f32, f32) {
    debug_assert!(g.abs() < 1.0, "asymmetry parameter g must lie in (-1, 1), got {g}");
    // Sample the forward lobe with |g| and mirror for g < 0: c(g, u) = -c(-g, 1 - u).
    let (ga, ua) = if g >= 0.0 { (g, u) } else { (-g, 1.0 - u) };
    let d = 1.0 - ga + 2.0 * ga * ua;
    let t = (1.0 - ga) * (1.0 + ga) / d;
    let one_minus_cos = ((1.0 - ga) * (1.0 - ua) * (t + 1.0 - ga) / d).clamp(0.0, 2.0);
    let c = 1.0 - one_minus_cos;
    let sin2 = one_minus_cos * (2.0 - one_minus_cos);
    if g >= 0.0 {
        (c, sin2)
    } else {
        (-c, sin2)
    }
}

/// Orthonormal basis `(b1, b2)` completing the unit vector `n` to a right-handed frame
/// `(b1, b2, n)`.
///
/// Duff, Burgess, Christensen, Hery, Kensler, Liani, Villemin, "Building an Orthonormal
/// Basis, Revisited", JCGT 6(1), 2017, listing 3: branchless, continuous except across
/// `n.z = 0` where the sign flips, and accurate for all unit `n`.
pub fn orthonormal_basis(n: Vec3) -> (Vec3, Vec3) {
    let sign = 1.0f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    let b1 = Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
    let b2 = Vec3::new(b, sign + n.y * n.y * a, -n.y);
    (b1, b2)
}

/// Sample an outgoing propagation direction around the incoming propagation direction
/// `dir` (unit length) from Henyey-Greenstein with asymmetry `g`.
///
/// `u.x` picks `cos_theta` (via [`hg_sample_cos`]), `u.y` the azimuth `phi = 2 pi u.y` in
/// the frame of [`orthonormal_basis`]. Returns the unit direction and its solid-angle
/// density in 1/sr, which equals `hg_eval(g, cos_theta)` (importance sampling is exact).
pub fn hg_sample(g: f32, dir: Vec3, u: Vec2) -> (Vec3, f32) {
    let (cos_theta, sin2_theta) = hg_sample_cos_sin2(g, u.x);
    let sin_theta = sin2_theta.sqrt();
    let phi = std::f32::consts::TAU * u.y;
    let (b1, b2) = orthonormal_basis(dir);
    let wo = sin_theta * phi.cos() * b1 + sin_theta * phi.sin() * b2 + cos_theta * dir;
    (wo, hg_eval(g, cos_theta))
}
