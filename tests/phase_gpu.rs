//! The GLSL Henyey-Greenstein code (glsl/include/phase.glsl) run on the device through the
//! probe shader, checked against the Rust reference and statistically: the sampled pdf equals
//! the evaluated one, the mean cosine is g, and a chi-square test of the samples passes for
//! several g including +-0.95 (and fails when the pdf claimed is the wrong one).

use glam::Vec3;
use scatterlab::gpu::{Gpu, Pass, QueueRole};
use scatterlab::physics::phase::hg_eval;
use scatterlab::physics::stats::{chi_square_test, spherical_coords, ChiSquareConfig};
use scatterlab::solvers::parts::probes::{PhasePush as ProbePush, PHASE};

use crate::common::{assert_clean, gpu};

const G_VALUES: [f32; 6] = [-0.95, -0.5, 0.0, 0.3, 0.8, 0.95];

/// (samples as (direction, pdf), evaluations at `cos_in`) from the device.
fn probe(gpu: &Gpu, g: f32, count: u32, cos_in: &[f32]) -> (Vec<[f32; 4]>, Vec<f32>) {
    let p = gpu.pipeline(&PHASE, &[]).unwrap();
    let samples = gpu.buffer("phase samples", count as u64 * 16).unwrap();
    let cos_buf = gpu.buffer_with("cos in", cos_in).unwrap();
    let eval = gpu.buffer("phase eval", cos_in.len() as u64 * 4).unwrap();
    let n = count.max(cos_in.len() as u32);
    let pass = Pass::new("probe.phase", QueueRole::Trace, &p)
        .write(0, &samples)
        .read(1, &cos_buf)
        .write(2, &eval)
        .push(&ProbePush { g, count, eval_count: cos_in.len() as u32, seed: 7 })
        .cover([n, 1, 1]);
    let point = gpu.submit(QueueRole::Trace, &[pass], &[]).unwrap();
    gpu.wait(point).unwrap();
    (gpu.read_buffer_as(&samples).unwrap(), gpu.read_buffer_as(&eval).unwrap())
}

#[test]
fn glsl_hg_eval_matches_rust_and_is_normalised() {
    let gpu = gpu();
    let n = 20001usize;
    let cos: Vec<f32> = (0..n).map(|i| -1.0 + 2.0 * i as f32 / (n - 1) as f32).collect();
    for g in G_VALUES {
        let (_, eval) = probe(&gpu, g, 1, &cos);
        for (c, v) in cos.iter().zip(&eval) {
            let want = hg_eval(g, *c);
            // The same f32 formula as the Rust reference: agreement to a few ulps.
            assert!((v - want).abs() <= 2e-6 * want + 1e-9, "g {g} cos {c}: GLSL {v} vs Rust {want}");
        }
        // 2 pi * integral over cos of p (trapezoid on the device's values) = 1.
        let h = 2.0 / (n - 1) as f64;
        let integral: f64 =
            eval.windows(2).map(|w| 0.5 * (w[0] as f64 + w[1] as f64) * h).sum::<f64>() * 2.0 * std::f64::consts::PI;
        assert!((integral - 1.0).abs() < 2e-3, "g {g}: integral {integral}");
    }
    assert_clean(&gpu);
}

#[test]
fn glsl_hg_samples_pdf_mean_cosine_and_chi_square() {
    let gpu = gpu();
    let count = 1_000_000u32;
    for g in G_VALUES {
        let (samples, _) = probe(&gpu, g, count, &[0.0]);
        // Sampled direction's pdf (computed on the device) equals the reference pdf.
        let mut mean_cos = 0.0f64;
        for s in samples.iter().take(10_000) {
            let w = Vec3::new(s[0], s[1], s[2]);
            assert!((w.length() - 1.0).abs() < 1e-4, "g {g}: sample not unit length");
            let want = hg_eval(g, s[2]);
            assert!((s[3] - want).abs() <= 1e-4 * want + 1e-7, "g {g}: pdf {} vs {want}", s[3]);
        }
        for s in &samples {
            mean_cos += s[2] as f64;
        }
        mean_cos /= count as f64;
        // Var(cos) <= 1, so the standard error is at most 1e-3.
        assert!((mean_cos - g as f64).abs() < 5e-3, "g {g}: mean cosine {mean_cos}");

        let config = ChiSquareConfig {
            sample_count: count as usize,
            test_count: G_VALUES.len() as u32,
            ..ChiSquareConfig::sphere()
        };
        let mut it = samples.iter();
        let to_coords = |s: &[f32; 4]| spherical_coords(Vec3::new(s[0], s[1], s[2]), Vec3::Z);
        let result = chi_square_test(
            &config,
            |_| to_coords(it.next().expect("enough samples")),
            |c, _| hg_eval(g, c as f32) as f64,
        );
        eprintln!("GLSL HG g = {g}: {result}");
        assert!(result.passed(0.01), "GLSL HG sampler rejected for g = {g}: {result}");
        // The test has teeth: the same samples judged against a neighbouring g fail.
        let g_wrong = if g > 0.9 { g - 0.05 } else { g + 0.05 };
        let mut it = samples.iter();
        let wrong = chi_square_test(
            &config,
            |_| to_coords(it.next().expect("enough samples")),
            |c, _| hg_eval(g_wrong, c as f32) as f64,
        );
        assert!(!wrong.passed(0.01), "g {g}: samples also pass against g = {g_wrong}: {wrong}");
    }
    assert_clean(&gpu);
}
