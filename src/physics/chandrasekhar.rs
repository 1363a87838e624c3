//! Chandrasekhar's H-function for isotropic scattering and the exact reflectance of a
//! semi-infinite isotropically scattering half-space: an exact answer path tracers are
//! held to.
//!
//! S. Chandrasekhar, *Radiative Transfer* (Oxford 1950; Dover 1960), ch. V. For single
//! scattering albedo `omega` (`albedo` in scene files) the H-function on `mu in [0, 1]`
//! solves
//!
//! ```text
//! H(mu) = 1 + (omega / 2) mu H(mu) int_0^1 H(mu') / (mu + mu') dmu'
//! ```
//!
//! which, using the zeroth moment `int_0^1 H = (2 / omega) (1 - sqrt(1 - omega))`, is
//! equivalent to the form iterated here (Chandrasekhar's eq. V.(34) family; it converges
//! far faster than the one above as `omega -> 1`):
//!
//! ```text
//! 1 / H(mu) = sqrt(1 - omega) + (omega / 2) int_0^1 mu' H(mu') / (mu + mu') dmu'
//! ```
//!
//! The integral uses Gauss-Legendre quadrature on [0, 1]; values between the nodes come
//! from the same equation (Nystrom interpolation), so `H` is smooth in `mu`.
//!
//! Two independent checks keep this honest (`tests/physics_tests.rs`): the published values
//! in [`PUBLISHED_H_VALUES`], and [`h_function_integral_representation`], the explicit
//! closed-form integral for H, which shares no code or method with the iteration.

use super::stats::adaptive_simpson;

/// Published H-function values for isotropic scattering, as
/// `(omega, mu, H, decimals printed)`.
///
/// - `H(1) = 2.9078` for conservative scattering (`omega = 1`): S. Chandrasekhar,
///   *Radiative Transfer* (Oxford 1950; Dover 1960), ch. V, table of H(mu) for isotropic
///   scattering; the best-known number of the theory.
///
/// Fuller tables, for any albedo, are in K. Kawabata & S. S. Limaye, "Rational
/// approximation formula for Chandrasekhar's H-function for isotropic scattering",
/// Astrophys. Space Sci. 332, 365 (2011), <https://doi.org/10.1007/s10509-010-0512-x>,
/// arXiv:1010.4839 (11 digits); K. Kawabata, Astrophys. Space Sci. 363:1 (2018),
/// arXiv:1712.04790 (conservative case, 15 digits); R. N. Das & R. Bera,
/// arXiv:0711.3336; and H. C. van de Hulst, *Multiple Light Scattering* (1980), vol. 1.
pub const PUBLISHED_H_VALUES: &[(f64, f64, f64, u32)] = &[(1.0, 1.0, 2.9078, 4)];

/// Gauss-Legendre nodes used for the integral over `mu'`.
pub const QUADRATURE_NODES: usize = 128;

/// Convergence threshold of the fixed-point iteration (max change of H over the nodes).
pub const TOLERANCE: f64 = 1e-13;

const MAX_ITERATIONS: usize = 10_000;

/// Gauss-Legendre nodes and weights on [-1, 1] (Newton iteration on P_n).
pub fn gauss_legendre(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut nodes = Vec::with_capacity(n);
    let mut weights = Vec::with_capacity(n);
    for i in 1..=n {
        // Tricomi's initial guess for the i-th root.
        let mut x = (std::f64::consts::PI * (i as f64 - 0.25) / (n as f64 + 0.5)).cos();
        let mut dp = 1.0;
        for _ in 0..100 {
            let (mut p0, mut p1) = (1.0, x);
            for k in 2..=n {
                let kf = k as f64;
                let p2 = ((2.0 * kf - 1.0) * x * p1 - (kf - 1.0) * p0) / kf;
                p0 = p1;
                p1 = p2;
            }
            dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
            let step = p1 / dp;
            x -= step;
            if step.abs() < 1e-16 {
                break;
            }
        }
        nodes.push(x);
        weights.push(2.0 / ((1.0 - x * x) * dp * dp));
    }
    (nodes, weights)
}

/// The H-function for isotropic scattering with albedo `omega`, solved once and evaluated
/// at any `mu in [0, 1]`.
#[derive(Clone, Debug)]
pub struct HFunction {
    omega: f64,
    mu: Vec<f64>,
    /// Quadrature weight times mu' times H(mu'), the only combination the integral needs.
    weighted: Vec<f64>,
    iterations: usize,
}

impl HFunction {
    /// Solve for H with single scattering albedo `omega in [0, 1]`.
    ///
    /// # Panics
    /// If `omega` is outside [0, 1] or the iteration fails to converge.
    pub fn new(omega: f64) -> Self {
        assert!((0.0..=1.0).contains(&omega), "single scattering albedo omega must lie in [0, 1], got {omega}");
        let (x, w) = gauss_legendre(QUADRATURE_NODES);
        let mu: Vec<f64> = x.iter().map(|x| 0.5 * (x + 1.0)).collect();
        let wt: Vec<f64> = w.iter().map(|w| 0.5 * w).collect();
        let s = (1.0 - omega).sqrt();

        let mut h = vec![1.0f64; mu.len()];
        let mut weighted = vec![0.0f64; mu.len()];
        let mut iterations = 0;
        loop {
            for j in 0..mu.len() {
                weighted[j] = wt[j] * mu[j] * h[j];
            }
            let mut change = 0.0f64;
            for i in 0..mu.len() {
                let integral: f64 = (0..mu.len()).map(|j| weighted[j] / (mu[i] + mu[j])).sum();
                let next = 1.0 / (s + 0.5 * omega * integral);
                // Geometric-mean damping. The map H -> 1/(s + ...) sends c*H to H/c when
                // s = 0 (omega = 1), so the plain iteration oscillates in scale forever;
                // the geometric mean cancels that mode exactly and keeps the fixed point.
                let damped = (h[i] * next).sqrt();
                change = change.max((damped - h[i]).abs());
                h[i] = damped;
            }
            iterations += 1;
            if change < TOLERANCE {
                break;
            }
            assert!(
                iterations < MAX_ITERATIONS,
                "H-function iteration for omega = {omega} did not converge (last change {change:e})"
            );
        }
        for j in 0..mu.len() {
            weighted[j] = wt[j] * mu[j] * h[j];
        }
        Self { omega, mu, weighted, iterations }
    }

    /// Single scattering albedo this H was solved for.
    pub fn omega(&self) -> f64 {
        self.omega
    }

    /// Fixed-point iterations the solve took.
    pub fn iterations(&self) -> usize {
        self.iterations
    }

    /// H(mu) for `mu in [0, 1]` (clamped).
    pub fn eval(&self, mu: f64) -> f64 {
        let mu = mu.clamp(0.0, 1.0);
        let integral: f64 = self.mu.iter().zip(&self.weighted).map(|(m, w)| w / (mu + m)).sum();
        1.0 / ((1.0 - self.omega).sqrt() + 0.5 * self.omega * integral)
    }

    /// Moment `int_0^1 H(mu) mu^n dmu` by the same quadrature.
    pub fn moment(&self, n: i32) -> f64 {
        // weighted = w mu H, so divide one mu back out.
        self.mu.iter().zip(&self.weighted).map(|(m, w)| w * m.powi(n - 1)).sum()
    }

    /// Plane albedo `1 - H(mu) sqrt(1 - omega)`: see
    /// [`semi_infinite_reflectance_uniform_env`].
    pub fn plane_albedo(&self, mu: f64) -> f64 {
        1.0 - self.eval(mu) * (1.0 - self.omega).sqrt()
    }
}

/// Chandrasekhar's H(mu) for isotropic scattering with single scattering albedo `omega`.
///
/// Solves the integral equation on every call (about a millisecond); build an
/// [`HFunction`] once to evaluate many `mu`.
pub fn h_function(omega: f64, mu: f64) -> f64 {
    HFunction::new(omega).eval(mu)
}

/// Reflected radiance, per unit environment radiance, of a semi-infinite half-space of an
/// isotropically scattering medium with albedo `omega` (any `sigma_t`; the depth scale
/// drops out), lit by a uniform environment of radiance `L` over the whole sky and seen
/// from direction cosine `mu` to the surface normal. No refractive boundary (index 1).
///
/// By reciprocity the radiance reflected toward `mu` under uniform illumination equals
/// `L` times the plane albedo for light incident from `mu` (the fraction of a collimated
/// beam from `mu` that is ever reflected), which for isotropic scattering is
/// `r(mu) = 1 - H(mu) sqrt(1 - omega)` (Chandrasekhar 1960, ch. V; van de Hulst 1980,
/// *Multiple Light Scattering*, vol. 1, sec. 8). So the answer is `L * r(mu)`.
pub fn semi_infinite_reflectance_uniform_env(omega: f64, mu: f64) -> f64 {
    HFunction::new(omega).plane_albedo(mu)
}

/// H(mu) from the explicit integral representation for isotropic scattering,
///
/// ```text
/// H(mu) = exp( -(mu / pi) int_0^{pi/2} ln(1 - omega theta cot theta)
///                                      / (cos^2 theta + mu^2 sin^2 theta) dtheta )
/// ```
///
/// (Chandrasekhar 1960, ch. V; the "closed-form integral representation" Kawabata & Limaye
/// 2011 evaluate to 11 digits). Independent of [`HFunction`]: no iteration, a different
/// integral. Slower; meant as a test reference. The logarithmic singularity at
/// `theta = 0` when `omega = 1` is removed by substituting `theta = s^2`.
pub fn h_function_integral_representation(omega: f64, mu: f64) -> f64 {
    assert!(
        (0.0..=1.0).contains(&omega) && (0.0..=1.0).contains(&mu),
        "omega and mu must lie in [0, 1], got omega = {omega}, mu = {mu}"
    );
    if mu == 0.0 {
        // The prefactor mu vanishes (and the integrand alone diverges at pi/2).
        return 1.0;
    }
    // 1 - omega theta cot theta, without cancellation for small theta:
    // theta cot theta = 1 - t^2/3 - t^4/45 - 2 t^6/945 - t^8/4725 - ...
    let one_minus = |t: f64| -> f64 {
        if t < 0.1 {
            let t2 = t * t;
            (1.0 - omega) + omega * t2 * (1.0 / 3.0 + t2 * (1.0 / 45.0 + t2 * (2.0 / 945.0 + t2 / 4725.0)))
        } else {
            1.0 - omega * t / t.tan()
        }
    };
    let integrand = |s: f64| -> f64 {
        let t = s * s;
        if t <= 0.0 {
            return 0.0; // 2 s ln(...) -> 0 (as s ln s at omega = 1)
        }
        let (sin, cos) = t.sin_cos();
        2.0 * s * one_minus(t).ln() / (cos * cos + mu * mu * sin * sin)
    };
    let upper = std::f64::consts::FRAC_PI_2.sqrt();
    let integral = adaptive_simpson(&integrand, 0.0, upper, 1e-13, 6, 40);
    (-mu / std::f64::consts::PI * integral).exp()
}
