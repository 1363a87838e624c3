//! Real spherical harmonics (issue 17: the basis `sh-single` compresses each sample's
//! attenuation exp(-tau(b, w)) into, thesis 3.3.1 and appendix A.1): src/physics/sh.rs against
//! closed forms and its own defining properties (orthonormality, exact projection and
//! reconstruction of a band-limited function at its order, Parseval, rotation invariance of
//! each band's energy), the truncation error of a real attenuation falling with the order, and
//! glsl/include/sh.glsl on the device against the host.

use std::f64::consts::PI;

use scatterlab::gpu::{Pass, QueueRole};
use scatterlab::physics::quadrature::Quadrature;
use scatterlab::physics::rng::Pcg32;
use scatterlab::physics::sh::{self, MAX_ORDER};
use scatterlab::solvers::parts::probes::{ShPush, SH};

use crate::common::{assert_clean, gpu};

fn random_dir(rng: &mut Pcg32) -> [f64; 3] {
    let z = 2.0 * rng.next_f64() - 1.0;
    let phi = 2.0 * PI * rng.next_f64();
    let s = (1.0 - z * z).max(0.0).sqrt();
    [s * phi.cos(), s * phi.sin(), z]
}

#[test]
fn low_bands_are_the_closed_forms() {
    // The graphics convention (no Condon-Shortley phase), bands 0-2 written out.
    let mut rng = Pcg32::new(1, 1);
    for _ in 0..200 {
        let d = random_dir(&mut rng);
        let [x, y, z] = d;
        let c1 = (3.0 / (4.0 * PI)).sqrt();
        let c2 = 0.5 * (15.0 / PI).sqrt();
        let want = [
            0.5 / PI.sqrt(),
            c1 * y,
            c1 * z,
            c1 * x,
            c2 * x * y,
            c2 * y * z,
            0.25 * (5.0 / PI).sqrt() * (3.0 * z * z - 1.0),
            c2 * x * z,
            0.5 * c2 * (x * x - y * y),
        ];
        let got = sh::basis(3, d);
        for (i, (g, w)) in got.iter().zip(want).enumerate() {
            assert!((g - w).abs() < 1e-14, "coefficient {i} at {d:?}: {g} against {w}");
        }
    }
}

#[test]
fn the_basis_is_orthonormal_and_projection_is_exact_at_its_order() {
    let mut rng = Pcg32::new(2, 1);
    for order in 1..=MAX_ORDER {
        let q = sh::exact_quadrature(order);
        let n = sh::coefficients(order);
        // Gram matrix: the identity.
        let mut gram = vec![0.0; n * n];
        for (d, w) in q.directions.iter().zip(&q.weights) {
            let y = sh::basis(order, *d);
            for i in 0..n {
                for j in 0..n {
                    gram[i * n + j] += w * y[i] * y[j];
                }
            }
        }
        for i in 0..n {
            for j in 0..n {
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((gram[i * n + j] - want).abs() < 1e-12, "order {order}: <Y_{i}, Y_{j}> = {}", gram[i * n + j]);
            }
        }
        // A band-limited function: projected exactly, reconstructed exactly anywhere, and its
        // coefficients' squares sum to its integral square (Parseval).
        let c: Vec<f64> = (0..n).map(|_| 2.0 * rng.next_f64() - 1.0).collect();
        let f = |d: [f64; 3]| sh::eval(&c, d);
        let got = sh::project(order, &q, f);
        for (i, (g, w)) in got.iter().zip(&c).enumerate() {
            assert!((g - w).abs() < 1e-12, "order {order}, coefficient {i}: {g} against {w}");
        }
        for _ in 0..50 {
            let d = random_dir(&mut rng);
            assert!((sh::eval(&got, d) - f(d)).abs() < 1e-11);
        }
        let fine = Quadrature::product(2 * order as u32, 4 * order as u32);
        let integral: f64 = fine.directions.iter().zip(&fine.weights).map(|(d, w)| w * f(*d).powi(2)).sum();
        let parseval: f64 = c.iter().map(|x| x * x).sum();
        assert!((integral - parseval).abs() < 1e-11 * parseval.max(1.0), "order {order}: {integral} vs {parseval}");
        // Truncation: projecting it at a lower order keeps exactly its lower bands.
        if order > 1 {
            let low = sh::project(order - 1, &sh::exact_quadrature(order), f);
            for (i, (g, w)) in low.iter().zip(&c).enumerate() {
                assert!((g - w).abs() < 1e-12, "order {order} truncated, coefficient {i}");
            }
        }
    }
}

#[test]
fn each_bands_energy_is_rotation_invariant() {
    // Rotating a function mixes the m of a band and never the bands: sum_m c_lm^2 stays.
    let order = MAX_ORDER;
    let mut rng = Pcg32::new(3, 1);
    let c: Vec<f64> = (0..sh::coefficients(order)).map(|_| 2.0 * rng.next_f64() - 1.0).collect();
    let (a, b) = (0.7f64, -1.3f64);
    // R = Rz(b) Rx(a), applied to the argument: g(d) = f(R^T d).
    let rot = |d: [f64; 3]| {
        let (x, y, z) = (d[0] * b.cos() + d[1] * b.sin(), -d[0] * b.sin() + d[1] * b.cos(), d[2]);
        [x, y * a.cos() + z * a.sin(), -y * a.sin() + z * a.cos()]
    };
    let g = sh::project(order, &sh::exact_quadrature(order), |d| sh::eval(&c, rot(d)));
    for l in 0..order {
        let band = |v: &[f64]| (0..2 * l + 1).map(|k| v[l * l + k].powi(2)).sum::<f64>();
        let (e0, e1) = (band(&c), band(&g));
        assert!((e0 - e1).abs() < 1e-10 * e0.max(1.0), "band {l}: {e0} before, {e1} rotated");
    }
}

#[test]
fn attenuation_in_a_sphere_converges_with_the_order() {
    // What sh-single stores: psi(w) = exp(-sigma_t d(w)), d the distance from a point inside a
    // sphere of radius 1 to its surface along w. At the centre it is constant (band 0 alone);
    // off centre its truncation error (L2 over the sphere, a fine quadrature) falls with every
    // order, and more slowly the denser the medium (a sharper lobe toward the near surface).
    let fine = Quadrature::product(48, 96);
    let psi = |p: [f64; 3], sigma: f64| {
        move |w: [f64; 3]| {
            let b: f64 = p.iter().zip(&w).map(|(a, b)| a * b).sum();
            let c: f64 = p.iter().map(|a| a * a).sum::<f64>() - 1.0;
            (-sigma * (-b + (b * b - c).sqrt())).exp()
        }
    };
    let at_centre = sh::project(4, &fine, psi([0.0; 3], 3.0));
    assert!((at_centre[0] - (-3.0f64).exp() * (4.0 * PI).sqrt()).abs() < 1e-12);
    assert!(at_centre[1..].iter().all(|c| c.abs() < 1e-12), "{at_centre:?}");
    for sigma in [1.0, 4.0, 16.0] {
        let f = psi([0.3, -0.2, 0.5], sigma);
        let total: f64 = fine.directions.iter().zip(&fine.weights).map(|(d, w)| w * f(*d).powi(2)).sum();
        let mut last = f64::INFINITY;
        let mut errors = Vec::new();
        for order in 1..=MAX_ORDER {
            let c = sh::project(order, &fine, f);
            let err: f64 =
                fine.directions.iter().zip(&fine.weights).map(|(d, w)| w * (f(*d) - sh::eval(&c, *d)).powi(2)).sum();
            let rel = (err / total).sqrt();
            errors.push(rel);
            assert!(rel < last, "sigma_t {sigma}: order {order} error {rel} not below {last}");
            last = rel;
        }
        let shown: Vec<String> = errors.iter().map(|e| format!("{e:.2e}")).collect();
        eprintln!("sigma_t {sigma}: relative L2 error of orders 1..8 {shown:?}");
    }
}

#[test]
fn glsl_basis_matches_the_host() {
    let gpu = gpu();
    let pipeline = gpu.pipeline(&SH, &[]).unwrap();
    let mut rng = Pcg32::new(4, 1);
    let n = 4096usize;
    let mut dirs: Vec<[f32; 4]> = (0..n)
        .map(|_| {
            let d = random_dir(&mut rng);
            [d[0] as f32, d[1] as f32, d[2] as f32, 0.0]
        })
        .collect();
    // The poles and the axes, where the recurrence's sin(theta)^m vanish.
    for (i, d) in [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]].iter().enumerate() {
        dirs[i] = [d[0], d[1], d[2], 0.0];
    }
    for order in [1usize, 3, 5, MAX_ORDER] {
        let m = sh::coefficients(order);
        let dir_buf = gpu.buffer_with("sh dirs", &dirs).unwrap();
        let out = gpu.buffer("sh values", (n * m * 4) as u64).unwrap();
        let pass = Pass::new("probe.sh", QueueRole::Trace, &pipeline)
            .read(0, &dir_buf)
            .write(1, &out)
            .push(&ShPush { count: n as u32, order: order as u32 })
            .cover([n as u32, 1, 1]);
        let point = gpu.submit(QueueRole::Trace, &[pass], &[]).unwrap();
        gpu.wait(point).unwrap();
        let got: Vec<f32> = gpu.read_buffer_as(&out).unwrap();
        let mut worst = 0.0f64;
        for (i, d) in dirs.iter().enumerate() {
            // The host's basis at the same (f32) direction.
            let want = sh::basis(order, [d[0] as f64, d[1] as f64, d[2] as f64]);
            for k in 0..m {
                worst = worst.max((got[i * m + k] as f64 - want[k]).abs());
            }
        }
        // |Y| <= sqrt((2l + 1) / 4pi) < 1.1 up to band 7: f32 recurrences, 1.3e-6 at order 8 on
        // lavapipe; a wrong sign or index would be off by the size of Y itself.
        eprintln!("order {order}: worst |GPU - host| {worst:.2e}");
        assert!(worst < 5e-6, "order {order}: the device's basis is {worst} off the host's");
    }
    assert_clean(&gpu);
}
