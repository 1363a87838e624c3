//! Shared helpers for GPU tests: a validated device (never a skip), scenes from text, renders.

use std::path::Path;

use scatterlab::gpu::{Gpu, GpuOptions};
use scatterlab::output::Image;
use scatterlab::scene::{LoadOptions, Scene};
use scatterlab::solvers::{self, RenderOutput, RenderRequest, Settings, SolverError, SolverKind};

/// The device every GPU test uses, validation layer on. A missing device or layer fails the
/// test: a test never passes for want of a device.
pub fn gpu() -> Gpu {
    let opts = GpuOptions { validate: true, ..GpuOptions::default() };
    match Gpu::new(&opts) {
        Ok(g) => g,
        Err(e) => panic!("GPU tests need a Vulkan device with the validation layer (run tools/setup-deps): {e}"),
    }
}

/// Assert the validation layer reported nothing.
pub fn assert_clean(gpu: &Gpu) {
    assert_eq!(gpu.validation_errors(), 0, "validation errors: {:#?}", gpu.validation_messages());
}

pub fn scene(text: &str) -> Scene {
    Scene::from_str(text, "test.toml", Path::new("."), &[], &LoadOptions::default())
        .unwrap_or_else(|e| panic!("test scene invalid: {e}"))
}

/// A render with its error (or warnings) left to the caller.
pub fn try_render(
    gpu: &Gpu,
    scene: &Scene,
    kind: SolverKind,
    sets: &[(&str, &str)],
    force_full: bool,
) -> Result<RenderOutput, SolverError> {
    let pairs: Vec<(String, String)> = sets.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect();
    let settings = Settings::new(&pairs);
    let req = RenderRequest { scene, settings: &settings, force_full, progress: &|_, _| {} };
    solvers::render(gpu, kind, &req)
}

pub fn render_with(
    gpu: &Gpu,
    scene: &Scene,
    kind: SolverKind,
    sets: &[(&str, &str)],
    force_full: bool,
) -> RenderOutput {
    let out = try_render(gpu, scene, kind, sets, force_full).unwrap_or_else(|e| panic!("render failed: {e}"));
    assert_eq!(out.image.nan_inf_count(), 0, "NaN/Inf in the image");
    if let Some(v) = &out.variance {
        assert_eq!(v.nan_inf_count(), 0, "NaN/Inf in the variance");
    }
    assert!(out.image.data.iter().all(|v| *v >= 0.0), "negative radiance");
    assert!(out.report.warnings.is_empty(), "warnings: {:?}", out.report.warnings);
    out
}

pub fn render(gpu: &Gpu, scene: &Scene, kind: SolverKind, sets: &[(&str, &str)]) -> RenderOutput {
    render_with(gpu, scene, kind, sets, false)
}

/// Mean over all pixels and channels, and the standard error of that mean from the
/// per-pixel variance of the mean. Pixels are independent, but a pixel's three channels come
/// from the same paths (identical in a grey medium), so each pixel's channel mean gets the
/// Cauchy-Schwarz bound (mean_c sqrt(var_c))^2: exact for fully correlated channels,
/// conservative otherwise. (Treating the channels as independent underestimated the error by
/// sqrt(3) and made furnace tests fail at "4 sigma" one seed in three.)
pub fn mean_and_stderr(img: &Image, var: &Image) -> (f64, f64) {
    let pixels = img.data.len() / 3;
    let mean = img.data.iter().map(|v| *v as f64).sum::<f64>() / img.data.len() as f64;
    let var_sum: f64 =
        var.data.chunks(3).map(|c| (c.iter().map(|v| (*v as f64).sqrt()).sum::<f64>() / 3.0).powi(2)).sum();
    (mean, var_sum.sqrt() / pixels as f64)
}

/// Per-pixel, per-channel z-test of a Monte Carlo image against exact values: each value
/// within `k` standard errors (from the variance image) plus an absolute floor `eps` that
/// covers pixels whose sample variance happens to be 0. Returns the worst (|z|, index).
pub fn worst_z(img: &Image, var: &Image, exact: impl Fn(usize) -> f64, eps: f64) -> (f64, usize) {
    let mut worst = (0.0, 0);
    for i in 0..img.data.len() {
        let d = (img.data[i] as f64 - exact(i)).abs();
        let z = d / ((var.data[i] as f64).sqrt() + eps);
        if z > worst.0 {
            worst = (z, i);
        }
    }
    worst
}

/// Standard error of a render's image mean: from independent pixels for camera paths, plus a
/// light-traced part's own (from its batches; its pixels are correlated, one light path adding
/// to many). Counting the light part's per-pixel variance in both is conservative.
pub fn render_mean_and_stderr(out: &scatterlab::solvers::RenderOutput) -> (f64, f64) {
    let (m, se_cam) = mean_and_stderr(&out.image, out.variance.as_ref().unwrap());
    let se_lt = out.light_traced_mean_stderr();
    (m, (se_cam * se_cam + se_lt * se_lt).sqrt())
}

/// Two unbiased Monte Carlo estimates of one image (`a` by strategy `a_name`, `b` by `b_name`):
/// image means within 4 combined standard errors, and per value (pixel, channel) a z-test that
/// may fail only rarely (both variances are estimates, and heavy-tailed estimators understate
/// theirs).
pub fn assert_agree(
    what: &str,
    (a_name, a): (&str, &scatterlab::solvers::RenderOutput),
    (b_name, b): (&str, &scatterlab::solvers::RenderOutput),
) {
    let (ma, sea) = render_mean_and_stderr(a);
    let (mb, seb) = render_mean_and_stderr(b);
    let se = (sea * sea + seb * seb).sqrt();
    eprintln!("{what}: {a_name} mean {ma:.5} +- {sea:.5}, {b_name} {mb:.5} +- {seb:.5}, z = {:.2}", (ma - mb) / se);
    assert!(ma > 0.0, "{what}: black image");
    assert!((ma - mb).abs() < 4.0 * se, "{what}: {a_name} mean {ma} vs {b_name} {mb} (combined stderr {se})");
    let (va, vb) = (a.variance.as_ref().unwrap(), b.variance.as_ref().unwrap());
    let n = a.image.data.len();
    let bad = (0..n)
        .filter(|&i| {
            let sd = ((va.data[i] + vb.data[i]) as f64).sqrt() + 1e-4 * ma.min(mb);
            ((a.image.data[i] - b.image.data[i]) as f64).abs() > 4.0 * sd
        })
        .count();
    eprintln!("{what}: {bad} of {n} values beyond 4 sigma");
    assert!(bad * 100 <= 2 * n, "{what}: {bad} of {n} values differ by more than 4 sigma");
}
