//! Pure-Rust tests of `scatterlab::physics`: HG phase function (pbrt-style checks and
//! Mitsuba-style chi-square), the statistics that judge it, ray references, and the
//! Chandrasekhar H-function against published tables.

use glam::{Vec2, Vec3};
use scatterlab::physics::chandrasekhar::{
    h_function, h_function_integral_representation, semi_infinite_reflectance_uniform_env, HFunction,
    PUBLISHED_H_VALUES,
};
use scatterlab::physics::phase::{hg_eval, hg_sample, hg_sample_cos, orthonormal_basis, INV_FOUR_PI};
use scatterlab::physics::reference::{
    cauchy_mean_chord, chord_length_box, chord_length_sphere, ray_box, ray_sphere, sphere_chord_at_impact,
};
use scatterlab::physics::rng::Pcg32;
use scatterlab::physics::stats::{
    adaptive_simpson, chi_square_p_value, chi_square_test, gamma_p, gamma_q, ln_gamma, sidak_alpha, spherical_coords,
    ChiSquareConfig,
};

/// The asymmetry parameters every HG test runs over.
const G_VALUES: [f32; 6] = [-0.95, -0.5, 0.0, 0.3, 0.9, 0.95];

/// Family-wise significance level of the chi-square tests.
const ALPHA: f64 = 0.01;

fn assert_close(actual: f64, expected: f64, tol: f64, what: &str) {
    assert!(
        (actual - expected).abs() <= tol,
        "{what}: got {actual}, expected {expected} (tolerance {tol}, off by {:e})",
        (actual - expected).abs()
    );
}

/// An incoming direction off every axis, so the frame construction is exercised.
fn oblique_dir() -> Vec3 {
    Vec3::new(0.3, -0.5, 0.8).normalize()
}

// --- rng ---------------------------------------------------------------------------------

#[test]
fn physics_pcg32_matches_reference_sequence() {
    // pcg32-demo (O'Neill's reference C implementation), seed 42, stream 54.
    let mut rng = Pcg32::new(42, 54);
    let expected = [0xa15c_02b7u32, 0x7b47_f409, 0xba1d_3330, 0x83d2_f293, 0xbfa4_784b, 0xcbed_606e];
    for e in expected {
        assert_eq!(rng.next_u32(), e);
    }
}

#[test]
fn physics_pcg32_floats_in_unit_interval() {
    let mut rng = Pcg32::new(7, 0);
    let mut sum = 0.0f64;
    for _ in 0..100_000 {
        let (a, b) = (rng.next_f32(), rng.next_f64());
        assert!((0.0..1.0).contains(&a) && (0.0..1.0).contains(&b));
        sum += f64::from(a);
    }
    assert_close(sum / 100_000.0, 0.5, 0.005, "mean of next_f32");
}

// --- Henyey-Greenstein ---------------------------------------------------------------------

#[test]
fn physics_hg_isotropic_value() {
    for c in [-1.0, -0.3, 0.0, 0.7, 1.0] {
        assert_close(f64::from(hg_eval(0.0, c)), 1.0 / (4.0 * std::f64::consts::PI), 1e-8, "hg_eval(0, c)");
    }
    assert_eq!(hg_eval(0.0, 0.5), INV_FOUR_PI);
}

#[test]
fn physics_hg_normalised_over_sphere() {
    // int p domega = 2 pi int_{-1}^{1} p(c) dc (p does not depend on phi).
    for g in G_VALUES {
        let integral = 2.0
            * std::f64::consts::PI
            * adaptive_simpson(&|c: f64| f64::from(hg_eval(g, c as f32)), -1.0, 1.0, 1e-10, 4, 40);
        assert_close(integral, 1.0, 1e-5, &format!("integral of HG over the sphere, g = {g}"));
    }
}

#[test]
fn physics_hg_is_accurate_near_the_peak() {
    // Compare against the f64 formula where the naive f32 denominator 1 + g^2 - 2 g c loses
    // most of its digits.
    for g in [0.999f32, -0.999, 0.95, -0.95] {
        for c in [1.0f32, 0.999_999, 0.9999, -1.0, -0.999_999, -0.9999] {
            let (gd, cd) = (f64::from(g), f64::from(c));
            let exact = (1.0 - gd * gd) / (4.0 * std::f64::consts::PI * (1.0 + gd * gd - 2.0 * gd * cd).powf(1.5));
            let got = f64::from(hg_eval(g, c));
            assert!(got.is_finite() && got > 0.0);
            assert_close(got / exact, 1.0, 1e-5, &format!("hg_eval({g}, {c}) relative to f64"));
        }
    }
}

#[test]
fn physics_hg_sample_pdf_equals_eval() {
    let mut rng = Pcg32::new(3, 1);
    for g in G_VALUES {
        for dir in [oblique_dir(), Vec3::Z, -Vec3::Z, Vec3::X] {
            for _ in 0..2_000 {
                let u = Vec2::new(rng.next_f32(), rng.next_f32());
                let (wo, pdf) = hg_sample(g, dir, u);
                assert_close(f64::from(wo.length()), 1.0, 1e-5, "|wo|");
                let eval = hg_eval(g, dir.dot(wo));
                assert_close(f64::from(pdf / eval), 1.0, 1e-3, &format!("pdf / eval, g = {g}"));
                // The cosine the sampler drew is the one the direction has.
                assert_close(f64::from(dir.dot(wo)), f64::from(hg_sample_cos(g, u.x)), 1e-5, "cos");
            }
        }
    }
}

#[test]
fn physics_hg_sample_cos_endpoints_and_isotropic() {
    for g in G_VALUES {
        assert_close(f64::from(hg_sample_cos(g, 0.0)), -1.0, 1e-6, "c(u = 0)");
        assert_close(f64::from(hg_sample_cos(g, 1.0)), 1.0, 1e-6, "c(u = 1)");
    }
    // g = 0 is exactly the isotropic inverse, without any branch.
    let mut rng = Pcg32::new(11, 0);
    for _ in 0..1_000 {
        let u = rng.next_f32();
        assert_eq!(hg_sample_cos(0.0, u), 2.0 * u - 1.0);
    }
}

#[test]
fn physics_hg_mean_cosine_is_g() {
    const N: usize = 400_000;
    for g in G_VALUES {
        let mut rng = Pcg32::new(5, g.to_bits() as u64);
        let (mut sum, mut sum_sq) = (0.0f64, 0.0f64);
        for _ in 0..N {
            let u = Vec2::new(rng.next_f32(), rng.next_f32());
            let (wo, _) = hg_sample(g, oblique_dir(), u);
            let c = f64::from(oblique_dir().dot(wo));
            sum += c;
            sum_sq += c * c;
        }
        let mean = sum / N as f64;
        let std_err = ((sum_sq / N as f64 - mean * mean) / N as f64).sqrt();
        // 5 standard errors: a false failure about once in 3.5 million runs.
        assert_close(mean, f64::from(g), 5.0 * std_err + 1e-6, &format!("mean cosine for g = {g}"));
    }
}

#[test]
fn physics_hg_strong_g_sends_samples_forward() {
    const N: usize = 100_000;
    let dir = oblique_dir();
    for (g, forward_at_least) in [(0.9f32, 0.95), (0.5, 0.75)] {
        let mut rng = Pcg32::new(9, 0);
        let mut forward = 0usize;
        let mut backward_for_negative = 0usize;
        for _ in 0..N {
            let u = Vec2::new(rng.next_f32(), rng.next_f32());
            if hg_sample(g, dir, u).0.dot(dir) > 0.0 {
                forward += 1;
            }
            if hg_sample(-g, dir, u).0.dot(dir) < 0.0 {
                backward_for_negative += 1;
            }
        }
        let (f, b) = (forward as f64 / N as f64, backward_for_negative as f64 / N as f64);
        assert!(f > forward_at_least, "g = {g}: only {f} of samples forward");
        assert!(b > forward_at_least, "g = {}: only {b} of samples backward", -g);
    }
}

#[test]
fn physics_orthonormal_basis_is_orthonormal() {
    let mut rng = Pcg32::new(13, 0);
    let mut dirs = vec![Vec3::Z, -Vec3::Z, Vec3::X, -Vec3::Y, Vec3::new(0.0, 0.0, -0.0)];
    dirs.pop();
    for _ in 0..1000 {
        let v = Vec3::new(rng.next_f32() - 0.5, rng.next_f32() - 0.5, rng.next_f32() - 0.5);
        if v.length() > 1e-3 {
            dirs.push(v.normalize());
        }
    }
    for n in dirs {
        let (b1, b2) = orthonormal_basis(n);
        for (a, b, what) in [(b1, b1, "b1.b1"), (b2, b2, "b2.b2")] {
            assert_close(f64::from(a.dot(b)), 1.0, 1e-5, what);
        }
        for (a, b, what) in [(b1, b2, "b1.b2"), (b1, n, "b1.n"), (b2, n, "b2.n")] {
            assert_close(f64::from(a.dot(b)), 0.0, 1e-5, what);
        }
        // Right-handed: b1 x b2 = n.
        assert!((b1.cross(b2) - n).length() < 1e-5);
    }
}

// --- chi-square --------------------------------------------------------------------------

/// Chi-square test of an HG-like sampler against the HG pdf with parameter `g_pdf`.
fn hg_chi_square(
    g_pdf: f32,
    dir: Vec3,
    test_count: u32,
    mut sampler: impl FnMut(Vec2) -> Vec3,
) -> scatterlab::physics::stats::ChiSquareResult {
    let config = ChiSquareConfig { test_count, ..ChiSquareConfig::sphere() };
    chi_square_test(
        &config,
        |rng| {
            let u = Vec2::new(rng.next_f32(), rng.next_f32());
            spherical_coords(sampler(u), dir)
        },
        |cos_theta, _phi| f64::from(hg_eval(g_pdf, cos_theta as f32)),
    )
}

#[test]
fn physics_hg_chi_square_passes() {
    let dir = oblique_dir();
    for g in G_VALUES {
        let result = hg_chi_square(g, dir, G_VALUES.len() as u32, |u| hg_sample(g, dir, u).0);
        eprintln!("HG g = {g}: {result}");
        assert_close(result.pdf_integral, 1.0, 1e-6, "pdf integral over the histogram");
        assert!(result.passed(ALPHA), "HG sampler rejected for g = {g}: {result}");
    }
    // The branch of the frame for dir.z < 0.
    let down = Vec3::new(0.1, 0.2, -0.9).normalize();
    let result = hg_chi_square(0.5, down, 1, |u| hg_sample(0.5, down, u).0);
    assert!(result.passed(ALPHA), "HG sampler rejected for a downward direction: {result}");
}

#[test]
fn physics_chi_square_rejects_wrong_samplers() {
    let dir = oblique_dir();
    let tau = std::f32::consts::TAU;
    let frame = |c: f32, phi: f32| {
        let (b1, b2) = orthonormal_basis(dir);
        let s = (1.0 - c * c).max(0.0).sqrt();
        s * phi.cos() * b1 + s * phi.sin() * b2 + c * dir
    };
    type Sampler<'a> = Box<dyn FnMut(Vec2) -> Vec3 + 'a>;
    let wrong: [(&str, Sampler); 4] = [
        // The classic convention bug: the sign of g flipped.
        ("sign of g flipped", Box::new(|u: Vec2| hg_sample(-0.3, dir, u).0)),
        // A slightly wrong g.
        ("g = 0.33 instead of 0.3", Box::new(|u: Vec2| hg_sample(0.33, dir, u).0)),
        // Right cosine, azimuth not uniform.
        ("azimuth 2 pi u^1.1", Box::new(move |u: Vec2| frame(hg_sample_cos(0.3, u.x), tau * u.y.powf(1.1)))),
        // Isotropic samples claimed as HG.
        ("isotropic sampler", Box::new(move |u: Vec2| frame(2.0 * u.x - 1.0, tau * u.y))),
    ];
    for (name, sampler) in wrong {
        let result = hg_chi_square(0.3, dir, 4, sampler);
        eprintln!("wrong sampler ({name}): {result}");
        assert!(!result.passed(ALPHA), "chi-square accepted a wrong sampler ({name}): {result}");
    }
}

#[test]
fn physics_chi_square_flags_samples_where_pdf_is_zero() {
    // The pdf claims the lower half of the domain is empty; the sampler disagrees.
    let config = ChiSquareConfig { sample_count: 100_000, ..ChiSquareConfig::sphere() };
    let result = chi_square_test(
        &config,
        |rng| [2.0 * rng.next_f64() - 1.0, std::f64::consts::TAU * (rng.next_f64() - 0.5)],
        |x, _| {
            if x > 0.0 {
                1.0 / (2.0 * std::f64::consts::PI)
            } else {
                0.0
            }
        },
    );
    assert!(result.zero_pdf_samples > 0 && !result.passed(ALPHA), "{result}");
}

#[test]
fn physics_incomplete_gamma_known_values() {
    // ln Gamma: ln sqrt(pi), ln 9!, ln 99! (exact values).
    assert_close(ln_gamma(0.5), 0.572_364_942_924_700_1, 1e-13, "ln Gamma(0.5)");
    assert_close(ln_gamma(10.0), 362_880f64.ln(), 1e-12, "ln Gamma(10)");
    assert_close(ln_gamma(100.0), 359.134_205_369_575_4, 1e-10, "ln Gamma(100)");
    assert_close(ln_gamma(0.1), 2.252_712_651_734_206, 1e-12, "ln Gamma(0.1)");

    // Integer a: Q(n, x) = e^-x sum_{k<n} x^k / k! (Poisson tail), both branches.
    for (n, x) in [(1u32, 0.3f64), (1, 5.0), (5, 3.0), (5, 9.0), (20, 12.0), (20, 30.0)] {
        let mut term = 1.0f64;
        let mut sum = 0.0f64;
        for k in 0..n {
            if k > 0 {
                term *= x / f64::from(k);
            }
            sum += term;
        }
        let exact = (-x).exp() * sum;
        assert_close(gamma_q(f64::from(n), x) / exact, 1.0, 1e-12, &format!("Q({n}, {x})"));
        assert_close(gamma_p(f64::from(n), x) + gamma_q(f64::from(n), x), 1.0, 1e-14, "P + Q");
    }

    // Half-integer a: Q(1/2, x) = erfc(sqrt x); erfc(1) and erfc(2) from tables.
    assert_close(gamma_q(0.5, 1.0), 0.157_299_207_050_285_13, 1e-14, "Q(0.5, 1) = erfc(1)");
    assert_close(gamma_q(0.5, 4.0), 4.677_734_981_047_266e-3, 1e-15, "Q(0.5, 4) = erfc(2)");

    // Chi-square critical values at the 5 % level (any statistics table).
    assert_close(chi_square_p_value(3.841_458_820_694_124, 1), 0.05, 1e-12, "chi2(1) at 3.8415");
    assert_close(chi_square_p_value(18.307_038_053_275_146, 10), 0.05, 1e-12, "chi2(10) at 18.307");
    assert_close(chi_square_p_value(124.342_113_404_5, 100), 0.05, 1e-9, "chi2(100) at 124.342");

    // Large a, as with thousands of histogram cells: P(a, a) ~ 1/2 + 1/(3 sqrt(2 pi a)).
    let a = 2500.0f64;
    let asymptotic = 0.5 + 1.0 / (3.0 * (2.0 * std::f64::consts::PI * a).sqrt());
    assert_close(gamma_p(a, a), asymptotic, 1e-5, "P(2500, 2500)");

    // The series / continued-fraction switch at x = a + 1 is seamless.
    for a in [0.5, 3.0, 50.0, 2500.0] {
        let below = gamma_q(a, a + 1.0 - 1e-9);
        let above = gamma_q(a, a + 1.0 + 1e-9);
        assert_close(below, above, 1e-9, "Q continuous at x = a + 1");
    }
    assert!(gamma_q(-1.0, 1.0).is_nan() && gamma_q(1.0, -1.0).is_nan());
}

#[test]
fn physics_sidak_correction() {
    assert_close(sidak_alpha(0.01, 1), 0.01, 1e-15, "one test");
    let per_test = sidak_alpha(0.01, 6);
    assert_close(1.0 - (1.0 - per_test).powi(6), 0.01, 1e-14, "family-wise level");
    assert!(per_test < 0.01 / 6.0 + 1e-5 && per_test > 0.01 / 6.0);
}

// --- ray references ----------------------------------------------------------------------

#[test]
fn physics_ray_box_cases() {
    let (min, max) = (Vec3::splat(-1.0), Vec3::splat(1.0));
    // Straight through along x from outside.
    assert_eq!(ray_box(Vec3::new(-3.0, 0.0, 0.0), Vec3::X, min, max), Some((2.0, 4.0)));
    // From inside: t0 < 0.
    assert_eq!(ray_box(Vec3::ZERO, Vec3::X, min, max), Some((-1.0, 1.0)));
    // Behind the origin.
    assert_eq!(ray_box(Vec3::new(3.0, 0.0, 0.0), Vec3::X, min, max), None);
    // Parallel to a slab, outside it: miss; inside it: hit.
    assert_eq!(ray_box(Vec3::new(-3.0, 2.0, 0.0), Vec3::X, min, max), None);
    assert_eq!(ray_box(Vec3::new(-3.0, 1.0, 0.0), Vec3::X, min, max), Some((2.0, 4.0)));
    // Diagonal through the corners: chord = 2 sqrt(3).
    let d = Vec3::ONE.normalize();
    let (t0, t1) = ray_box(Vec3::splat(-2.0), d, min, max).unwrap();
    assert_close(f64::from(t1 - t0), 2.0 * 3f64.sqrt(), 1e-6, "diagonal chord");
    // Non-unit direction: t in units of |dir|, chord in scene units.
    assert_eq!(ray_box(Vec3::new(-3.0, 0.0, 0.0), 2.0 * Vec3::X, min, max), Some((1.0, 2.0)));
    assert_close(f64::from(chord_length_box(Vec3::new(-3.0, 0.0, 0.0), 2.0 * Vec3::X, min, max)), 2.0, 1e-6, "chord");
    assert_close(f64::from(chord_length_box(Vec3::new(0.5, 0.0, 0.0), Vec3::X, min, max)), 0.5, 1e-6, "inside chord");
    assert_eq!(chord_length_box(Vec3::new(5.0, 5.0, 0.0), Vec3::X, min, max), 0.0);
}

#[test]
fn physics_ray_sphere_cases() {
    let c = Vec3::new(1.0, 2.0, 3.0);
    // Through the centre from distance 10.
    let (t0, t1) = ray_sphere(c - 10.0 * Vec3::Z, Vec3::Z, c, 2.0).unwrap();
    assert_close(f64::from(t0), 8.0, 1e-6, "t0");
    assert_close(f64::from(t1), 12.0, 1e-6, "t1");
    // From inside.
    let (t0, t1) = ray_sphere(c, Vec3::X, c, 2.0).unwrap();
    assert_close(f64::from(t0), -2.0, 1e-6, "t0 inside");
    assert_close(f64::from(t1), 2.0, 1e-6, "t1 inside");
    assert_close(f64::from(chord_length_sphere(c, Vec3::X, c, 2.0)), 2.0, 1e-6, "chord from centre");
    // Miss, and sphere behind the ray.
    assert_eq!(ray_sphere(c + Vec3::new(0.0, 3.0, -10.0), Vec3::Z, c, 2.0), None);
    assert_eq!(ray_sphere(c + 10.0 * Vec3::Z, Vec3::Z, c, 2.0), None);
    // Off-centre chord at impact parameter b matches 2 sqrt(r^2 - b^2).
    let chord = chord_length_sphere(c + Vec3::new(1.2, 0.0, -10.0), Vec3::Z, c, 2.0);
    assert_close(f64::from(chord), sphere_chord_at_impact(2.0, 1.2), 1e-5, "chord at impact 1.2");
    // Far away and small: the stable formulas keep relative precision.
    let (t0, t1) = ray_sphere(Vec3::new(0.0, 0.0, -1.0e4), Vec3::Z, Vec3::ZERO, 1e-2).unwrap();
    assert_close(f64::from(t1 - t0), 0.02, 2e-3, "tiny far sphere chord");
    // Cauchy: mean chord of a sphere is 4r/3.
    let r = 2.0f64;
    let v = 4.0 / 3.0 * std::f64::consts::PI * r.powi(3);
    let s = 4.0 * std::f64::consts::PI * r * r;
    assert_close(cauchy_mean_chord(v, s), 4.0 * r / 3.0, 1e-12, "Cauchy mean chord");
}

// --- Chandrasekhar H-function ------------------------------------------------------------

#[test]
fn physics_h_function_moment_identity() {
    // int_0^1 H(mu) dmu = (2 / omega) (1 - sqrt(1 - omega)), exact for isotropic scattering.
    for omega in [0.1, 0.5, 0.8, 0.9, 0.99, 0.999, 1.0] {
        let h = HFunction::new(omega);
        let exact = 2.0 / omega * (1.0 - (1.0 - omega).sqrt());
        assert_close(h.moment(0), exact, 1e-10, &format!("zeroth moment, omega = {omega}"));
        assert_close(h.eval(0.0), 1.0, 1e-10, "H(0) = 1");
    }
    // Conservative case: first moment 2 / sqrt(3) (Chandrasekhar 1960, eq. V.(?)): the
    // flux-moment identity for omega = 1.
    assert_close(HFunction::new(1.0).moment(1), 2.0 / 3f64.sqrt(), 1e-9, "first moment, omega = 1");
}

#[test]
fn physics_h_function_is_monotone_and_bounded() {
    for omega in [0.3, 0.9, 1.0] {
        let h = HFunction::new(omega);
        let mut prev = h.eval(0.0);
        for i in 1..=100 {
            let v = h.eval(f64::from(i) / 100.0);
            assert!(v > prev, "H not increasing at omega = {omega}");
            prev = v;
        }
        // Plane albedo lies in [0, 1] and is 1 for omega = 1.
        for mu in [0.0, 0.3, 1.0] {
            let r = semi_infinite_reflectance_uniform_env(omega, mu);
            assert!((0.0..=1.0 + 1e-12).contains(&r));
        }
    }
    assert_close(semi_infinite_reflectance_uniform_env(1.0, 0.5), 1.0, 1e-12, "omega = 1 reflects all");
    assert_close(h_function(0.0, 0.7), 1.0, 1e-14, "H = 1 without scattering");
}

#[test]
fn physics_h_function_matches_published_values() {
    for &(omega, mu, published, decimals) in PUBLISHED_H_VALUES {
        let h = h_function(omega, mu);
        // To the printed precision: half a unit in the last printed decimal.
        let half_ulp = 0.5 * 10f64.powi(-(decimals as i32));
        assert_close(h, published, half_ulp, &format!("H(omega = {omega}, mu = {mu}) vs published"));
    }
}

#[test]
fn physics_h_function_matches_integral_representation() {
    // The iteration and the explicit integral share nothing but the answer.
    for omega in [0.2, 0.5, 0.9, 0.99, 1.0] {
        let h = HFunction::new(omega);
        for mu in [0.0, 0.01, 0.05, 0.1, 0.3, 0.5, 0.8, 1.0] {
            let reference = h_function_integral_representation(omega, mu);
            assert_close(h.eval(mu), reference, 2e-9, &format!("H(omega = {omega}, mu = {mu})"));
        }
    }
}

// ------------------------------------------------------------------ angular quadratures

/// sum_i w_i f(Omega_i).
fn integrate(q: &scatterlab::physics::quadrature::Quadrature, f: impl Fn([f64; 3]) -> f64) -> f64 {
    q.directions.iter().zip(&q.weights).map(|(d, w)| w * f(*d)).sum()
}

/// The discrete-ordinates direction sets (issue 13): unit directions, positive weights summing
/// to 4 pi, the thesis's 24 and 48 directions, and the sphere's moments: odd ones vanish,
/// <mu^2> = 1/3 on every axis, <mu^4> = 1/5 from S_4 on and <mu_x^2 mu_y^2> = 1/15 from S_6
/// on (what the tables' seven digits allow), the product set exact to its degree.
#[test]
fn quadratures_integrate_the_sphere_moments() {
    use scatterlab::physics::quadrature::{gauss_legendre, Quadrature};
    let four_pi = 4.0 * std::f64::consts::PI;
    for (name, count) in [("s2", 8), ("s4", 24), ("s6", 48), ("s8", 80), ("product-8x16", 128)] {
        let q = Quadrature::named(name).unwrap();
        assert_eq!(q.len(), count, "{name}");
        assert!(q.weights.iter().all(|w| *w > 0.0), "{name}: a non-positive weight");
        assert!(q.directions.iter().all(|d| (d[0] * d[0] + d[1] * d[1] + d[2] * d[2] - 1.0).abs() < 1e-6), "{name}");
        assert_close(q.weights.iter().sum::<f64>(), four_pi, 1e-12, name);
        for axis in 0..3 {
            assert!(integrate(&q, |d| d[axis]).abs() < 1e-12, "{name}: first moment on axis {axis}");
            assert!(integrate(&q, |d| d[axis].powi(3)).abs() < 1e-12, "{name}: third moment");
            assert_close(integrate(&q, |d| d[axis].powi(2)) / four_pi, 1.0 / 3.0, 2e-6, name);
        }
        if name != "s2" {
            for axis in 0..3 {
                assert_close(integrate(&q, |d| d[axis].powi(4)) / four_pi, 0.2, 2e-6, &format!("{name} mu^4"));
            }
        }
        if !matches!(name, "s2" | "s4") {
            assert_close(integrate(&q, |d| (d[0] * d[1]).powi(2)) / four_pi, 1.0 / 15.0, 2e-6, &format!("{name} x2y2"));
        }
    }
    // Level-symmetric sets favour no axis: the same cosines on every axis.
    let q = Quadrature::named("s6").unwrap();
    let mut per_axis: Vec<Vec<i64>> = (0..3)
        .map(|a| {
            let mut v: Vec<i64> = q.directions.iter().map(|d| (d[a] * 1e6).round() as i64).collect();
            v.sort_unstable();
            v
        })
        .collect();
    let x = per_axis.remove(0);
    assert!(per_axis.iter().all(|v| *v == x), "s6 is not symmetric under axis permutation");
    // Gauss-Legendre with n nodes: exact to degree 2n - 1, e.g. n = 8 integrates mu^14 to 2/15.
    let (mu, w) = gauss_legendre(8);
    assert_close(w.iter().sum::<f64>(), 2.0, 1e-14, "GL weights");
    assert_close(mu.iter().zip(&w).map(|(m, w)| w * m.powi(14)).sum::<f64>(), 2.0 / 15.0, 1e-13, "GL mu^14");
    // The product set normalises a strongly forward HG lobe: sum_i w_i p(Omega_i . z) = 1.
    let q = Quadrature::product(32, 8);
    let g: f64 = 0.6;
    let hg = |mu: f64| (1.0 - g * g) / (4.0 * std::f64::consts::PI * (1.0 + g * g - 2.0 * g * mu).powf(1.5));
    assert_close(integrate(&q, |d| hg(d[2])), 1.0, 1e-9, "HG g 0.6 on product-32x8");
    for bad in ["s3", "s12", "product-0x4", "lebedev", "product-8"] {
        let e = Quadrature::named(bad).unwrap_err();
        assert!(e.contains(bad) && e.contains("s4"), "{bad}: {e}");
    }
}

/// Blackbody chromaticity against the published CIE 1931 2-degree values (Mitchell Charity,
/// "Blackbody color datafile", bbr_color.txt, 2-degree observer), within 1e-3; luminance
/// monotone in temperature; nothing at 0 K; the colour-matching table integrates ybar to the
/// CIE's 106.857 nm.
#[test]
fn blackbody_chromaticity_matches_the_published_planckian_locus() {
    use scatterlab::physics::blackbody::*;
    for (t, x, y) in [(1000.0, 0.6528, 0.3444), (3000.0, 0.4369, 0.4041), (6500.0, 0.3135, 0.3237)] {
        let (cx, cy) = chromaticity(blackbody_xyz(t));
        assert!((cx - x).abs() < 1e-3 && (cy - y).abs() < 1e-3, "{t} K: ({cx:.4}, {cy:.4}) against ({x}, {y})");
    }
    let ybar: f64 = CIE_1931.iter().map(|r| r[1]).sum::<f64>() * CIE_STEP_NM;
    assert!((ybar - 106.856895).abs() < 0.01, "ybar integrates to {ybar}");
    let mut last = 0.0;
    for t in (500..=20000).step_by(250) {
        let xyz = blackbody_xyz(t as f64);
        let rgb = blackbody_rgb(t as f64);
        assert!(xyz.y > last, "{t} K is not brighter than {} K", t - 250);
        assert!(rgb.min_element() >= 0.0 && rgb.is_finite(), "{t} K: {rgb}");
        last = xyz.y;
    }
    assert_eq!(blackbody_xyz(0.0).length(), 0.0);
    assert_eq!(planck(550.0, -1.0), 0.0);
    // Wien's peak radiance, 4.0956e-15 T^5 W/(m^2 sr nm) (the factor docs compare with pbrt-v4).
    let t = 3000.0;
    let peak = planck(2.8977721e6 / t, t) * 1e-9;
    assert!((peak / (4.0956e-15 * t.powi(5)) - 1.0).abs() < 1e-3, "{peak}");
    // Near 6500 K the sRGB white point's neighbourhood: no channel far from the others.
    let w = blackbody_rgb(6500.0);
    assert!(w.max_element() / w.min_element() < 1.15, "{w}");
    // Red below 2000 K: red above green above blue.
    let r = blackbody_rgb(1500.0);
    assert!(r.x > r.y && r.y >= r.z, "{r}");
}
