//! Statistical tests for sampling code: the regularized incomplete gamma function and a
//! chi-square goodness-of-fit test in the style of Mitsuba 3's `ChiSquareTest`.
//!
//! The test draws `sample_count` samples with a fixed seed, bins them on an odd-resolution
//! grid over a 2D domain, integrates the claimed density over every cell (adaptive Simpson),
//! pools cells whose expected count is below 5, and reports Pearson's statistic, its degrees
//! of freedom and the p-value `Q(dof / 2, statistic / 2)`. A family of tests shares one
//! significance level through the Sidak correction.
//!
//! For directions, use the domain `(cos_theta, phi)` over `[-1, 1] x [-pi, pi]`
//! ([`ChiSquareConfig::sphere`], [`spherical_coords`]): its area element equals the solid
//! angle element, so a solid-angle density (1/sr) is already the density on the domain.

use std::fmt;

use glam::Vec3;

use super::phase::orthonormal_basis;
use super::rng::Pcg32;

// ---------------------------------------------------------------------------------------
// Special functions
// ---------------------------------------------------------------------------------------

/// Natural log of the gamma function for `x > 0` (statrs: Lanczos approximation).
pub fn ln_gamma(x: f64) -> f64 {
    statrs::function::gamma::ln_gamma(x)
}

/// Regularized lower incomplete gamma function `P(a, x) = gamma(a, x) / Gamma(a)`,
/// for `a > 0`, `x >= 0`. NaN outside that domain.
pub fn gamma_p(a: f64, x: f64) -> f64 {
    statrs::function::gamma::checked_gamma_lr(a, x).unwrap_or(f64::NAN)
}

/// Regularized upper incomplete gamma function `Q(a, x) = 1 - P(a, x)`, for `a > 0`,
/// `x >= 0` (statrs computes it directly where it is small, so tail p-values keep their
/// relative precision). NaN outside that domain.
///
/// The p-value of a chi-square statistic `s` with `k` degrees of freedom is `Q(k/2, s/2)`.
pub fn gamma_q(a: f64, x: f64) -> f64 {
    statrs::function::gamma::checked_gamma_ur(a, x).unwrap_or(f64::NAN)
}

/// Upper-tail probability of the chi-square distribution: `P(X >= statistic)` for `dof`
/// degrees of freedom.
pub fn chi_square_p_value(statistic: f64, dof: usize) -> f64 {
    gamma_q(0.5 * dof as f64, 0.5 * statistic.max(0.0))
}

/// Per-test significance level that keeps the family-wise false-failure rate at `alpha`
/// over `test_count` independent tests (Sidak): `1 - (1 - alpha)^(1 / test_count)`.
pub fn sidak_alpha(alpha: f64, test_count: u32) -> f64 {
    1.0 - (1.0 - alpha).powf(1.0 / f64::from(test_count.max(1)))
}

// ---------------------------------------------------------------------------------------
// Numerical integration
// ---------------------------------------------------------------------------------------

/// Adaptive Simpson integration of `f` over `[a, b]` to absolute tolerance `tol`.
///
/// Every interval is split at least `min_depth` times before the error estimate is trusted
/// (so a narrow feature between the first five nodes is not missed), at most `max_depth`.
pub fn adaptive_simpson<F: Fn(f64) -> f64>(f: &F, a: f64, b: f64, tol: f64, min_depth: u32, max_depth: u32) -> f64 {
    let m = 0.5 * (a + b);
    let (fa, fm, fb) = (f(a), f(m), f(b));
    let whole = (b - a) / 6.0 * (fa + 4.0 * fm + fb);
    simpson_step(f, [a, m, b], [fa, fm, fb], whole, tol, 0, min_depth, max_depth)
}

#[allow(clippy::too_many_arguments)]
fn simpson_step<F: Fn(f64) -> f64>(
    f: &F,
    [a, m, b]: [f64; 3],
    [fa, fm, fb]: [f64; 3],
    whole: f64,
    tol: f64,
    depth: u32,
    min_depth: u32,
    max_depth: u32,
) -> f64 {
    let (lm, rm) = (0.5 * (a + m), 0.5 * (m + b));
    let (flm, frm) = (f(lm), f(rm));
    let left = (m - a) / 6.0 * (fa + 4.0 * flm + fm);
    let right = (b - m) / 6.0 * (fm + 4.0 * frm + fb);
    let delta = left + right - whole;
    if depth >= max_depth || (depth >= min_depth && delta.abs() <= 15.0 * tol) {
        // Richardson extrapolation of the two Simpson estimates.
        return left + right + delta / 15.0;
    }
    let next = depth + 1;
    simpson_step(f, [a, lm, m], [fa, flm, fm], left, 0.5 * tol, next, min_depth, max_depth)
        + simpson_step(f, [m, rm, b], [fm, frm, fb], right, 0.5 * tol, next, min_depth, max_depth)
}

/// Integral of `f(x, y)` over the rectangle `[x0, x1] x [y0, y1]` by nested adaptive
/// Simpson, to absolute tolerance about `tol`.
pub fn integrate_2d<F: Fn(f64, f64) -> f64>(f: &F, (x0, x1): (f64, f64), (y0, y1): (f64, f64), tol: f64) -> f64 {
    // An error e in every inner integral adds at most e * (x1 - x0) to the outer one.
    let inner_tol = 0.1 * tol / (x1 - x0).abs().max(f64::MIN_POSITIVE);
    let inner = |x: f64| adaptive_simpson(&|y| f(x, y), y0, y1, inner_tol, 1, 30);
    adaptive_simpson(&inner, x0, x1, tol, 1, 30)
}

// ---------------------------------------------------------------------------------------
// Chi-square test
// ---------------------------------------------------------------------------------------

/// Domain, histogram and sampling parameters of a [`chi_square_test`].
#[derive(Clone, Debug)]
pub struct ChiSquareConfig {
    /// Domain extent in x (e.g. `cos_theta` in [-1, 1]).
    pub x_range: (f64, f64),
    /// Domain extent in y (e.g. `phi` in [-pi, pi]).
    pub y_range: (f64, f64),
    /// Histogram cells in x; odd, so no cell edge sits on the domain's symmetry line.
    pub x_res: usize,
    /// Histogram cells in y; odd.
    pub y_res: usize,
    /// Samples drawn.
    pub sample_count: usize,
    /// Seed of the [`Pcg32`] handed to the sampler (stream 0).
    pub seed: u64,
    /// Cells expecting fewer samples than this are pooled (Pearson's rule of thumb: 5).
    pub min_expected: f64,
    /// How many tests share the family-wise significance level (Sidak correction).
    pub test_count: u32,
    /// Absolute tolerance of the integral of the density over one cell.
    pub integration_tolerance: f64,
}

impl ChiSquareConfig {
    /// Directions as `(cos_theta, phi)` over `[-1, 1] x [-pi, pi]`, 51 x 101 cells,
    /// one million samples, seed 1, a family of one test.
    pub fn sphere() -> Self {
        Self {
            x_range: (-1.0, 1.0),
            y_range: (-std::f64::consts::PI, std::f64::consts::PI),
            x_res: 51,
            y_res: 101,
            sample_count: 1_000_000,
            seed: 1,
            min_expected: 5.0,
            test_count: 1,
            integration_tolerance: 1e-9,
        }
    }
}

/// Outcome of a [`chi_square_test`].
#[derive(Clone, Debug)]
pub struct ChiSquareResult {
    /// Pearson's chi-square statistic after pooling.
    pub statistic: f64,
    /// Degrees of freedom: cells (after pooling) minus one.
    pub dof: usize,
    /// `P(chi^2_dof >= statistic)` under the hypothesis that the sampler draws from the pdf.
    pub p_value: f64,
    /// Tests in the family (copied from the config) for the Sidak correction.
    pub test_count: u32,
    /// Integral of the pdf over the whole domain (1 for a normalised density).
    pub pdf_integral: f64,
    /// Samples that were non-finite or fell outside the domain.
    pub invalid_samples: usize,
    /// Samples in cells where the pdf integrates to zero (beyond a 1e-5 fraction).
    pub zero_pdf_samples: usize,
    /// Observed counts per cell, row-major (`y * x_res + x`).
    pub observed: Vec<f64>,
    /// Expected counts per cell (`sample_count` times the pdf integral over the cell).
    pub expected: Vec<f64>,
}

impl ChiSquareResult {
    /// Whether the sampler is consistent with the pdf at family-wise significance `alpha`,
    /// i.e. `p_value >= 1 - (1 - alpha)^(1 / test_count)`, no sample was invalid and none
    /// landed where the pdf is zero.
    pub fn passed(&self, alpha: f64) -> bool {
        self.invalid_samples == 0
            && self.zero_pdf_samples == 0
            && self.dof >= 1
            && self.p_value >= sidak_alpha(alpha, self.test_count)
    }
}

impl fmt::Display for ChiSquareResult {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "chi^2 = {:.2}, dof = {}, p = {:.3e} (family of {}), pdf integral = {:.6}, \
             invalid samples = {}, samples where pdf = 0: {}",
            self.statistic,
            self.dof,
            self.p_value,
            self.test_count,
            self.pdf_integral,
            self.invalid_samples,
            self.zero_pdf_samples
        )
    }
}

/// Chi-square goodness-of-fit test of `sample` against `pdf` over the config's domain.
///
/// `sample` draws one point in domain coordinates from the given generator (seeded from
/// `config.seed`); `pdf` is the claimed density with respect to `dx dy` on the domain.
pub fn chi_square_test<S, P>(config: &ChiSquareConfig, mut sample: S, pdf: P) -> ChiSquareResult
where
    S: FnMut(&mut Pcg32) -> [f64; 2],
    P: Fn(f64, f64) -> f64,
{
    let (x0, x1) = config.x_range;
    let (y0, y1) = config.y_range;
    let (nx, ny) = (config.x_res, config.y_res);
    assert!(nx > 0 && ny > 0 && x1 > x0 && y1 > y0, "empty chi-square domain or histogram");

    // Histogram of the samples.
    let mut observed = vec![0.0f64; nx * ny];
    let mut invalid_samples = 0usize;
    let mut rng = Pcg32::new(config.seed, 0);
    for _ in 0..config.sample_count {
        let [x, y] = sample(&mut rng);
        let inside = x.is_finite() && y.is_finite() && (x0..=x1).contains(&x) && (y0..=y1).contains(&y);
        if !inside {
            invalid_samples += 1;
            continue;
        }
        let ix = (((x - x0) / (x1 - x0) * nx as f64) as usize).min(nx - 1);
        let iy = (((y - y0) / (y1 - y0) * ny as f64) as usize).min(ny - 1);
        observed[iy * nx + ix] += 1.0;
    }

    // Expected counts: the pdf integrated over every cell.
    let (dx, dy) = ((x1 - x0) / nx as f64, (y1 - y0) / ny as f64);
    let mut expected = vec![0.0f64; nx * ny];
    for iy in 0..ny {
        for ix in 0..nx {
            let cx = (x0 + ix as f64 * dx, x0 + (ix + 1) as f64 * dx);
            let cy = (y0 + iy as f64 * dy, y0 + (iy + 1) as f64 * dy);
            expected[iy * nx + ix] = integrate_2d(&pdf, cx, cy, config.integration_tolerance);
        }
    }
    let pdf_integral: f64 = expected.iter().sum();
    for e in &mut expected {
        *e *= config.sample_count as f64;
    }

    // Pearson's statistic, pooling low-expectation cells (as Mitsuba 3 does): visit cells
    // by increasing expectation; cells below `min_expected` join the pool, and so does the
    // next cell while the pool itself is still below it.
    let mut order: Vec<usize> = (0..nx * ny).collect();
    order.sort_by(|&a, &b| expected[a].total_cmp(&expected[b]));
    let zero_pdf_threshold = config.sample_count as f64 * 1e-5;
    let (mut statistic, mut cells) = (0.0f64, 0usize);
    let (mut pooled_observed, mut pooled_expected) = (0.0f64, 0.0f64);
    let mut zero_pdf_samples = 0usize;
    for &i in &order {
        let (o, e) = (observed[i], expected[i]);
        if e <= 0.0 {
            if o > zero_pdf_threshold {
                zero_pdf_samples += o as usize;
            }
        } else if e < config.min_expected || (pooled_expected > 0.0 && pooled_expected < config.min_expected) {
            pooled_observed += o;
            pooled_expected += e;
        } else {
            statistic += (o - e) * (o - e) / e;
            cells += 1;
        }
    }
    if pooled_expected > 0.0 {
        statistic += (pooled_observed - pooled_expected).powi(2) / pooled_expected;
        cells += 1;
    }
    // The total count is fixed, which removes one degree of freedom.
    let dof = cells.saturating_sub(1);
    let p_value = if dof >= 1 { chi_square_p_value(statistic, dof) } else { 0.0 };

    ChiSquareResult {
        statistic,
        dof,
        p_value,
        test_count: config.test_count,
        pdf_integral,
        invalid_samples,
        zero_pdf_samples,
        observed,
        expected,
    }
}

/// `(cos_theta, phi)` of the unit direction `w` about `axis`, in the frame of
/// [`orthonormal_basis`]: the coordinates of [`ChiSquareConfig::sphere`].
pub fn spherical_coords(w: Vec3, axis: Vec3) -> [f64; 2] {
    let (b1, b2) = orthonormal_basis(axis);
    let (x, y, z) = (f64::from(w.dot(b1)), f64::from(w.dot(b2)), f64::from(w.dot(axis)));
    // Normalise away the f32 rounding of w so cos_theta stays in [-1, 1].
    let len = (x * x + y * y + z * z).sqrt();
    [(z / len).clamp(-1.0, 1.0), y.atan2(x)]
}
