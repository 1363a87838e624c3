//! Solver `path` with equiangular sampling of point lights (Kulla & Fajardo 2012) combined by
//! MIS with distance sampling (`path.equiangular`, default on): it must stay unbiased (agree
//! with plain distance sampling) and tame the variance of a point light inside the medium.

use crate::common::PATH;
use scatterlab::output::Image;
use scatterlab::solvers::path::PathStats;
use scatterlab::solvers::RenderOutput;

use crate::common::{assert_agree, assert_clean, gpu, render, scene};

/// A small sphere of medium with a point light inside it (off-centre), lit by nothing else.
fn light_inside_sphere(sigma_t: &str, albedo: &str, g: f32, seed: u32) -> String {
    format!(
        r#"
[render]
width = 16
height = 16
seed = {seed}
spp = 64
[camera]
origin = [0.0, 0.3, 3.0]
target = [0.0, 0.0, 0.0]
fov = 28.0
[medium]
bounds = [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]
sigma_t = {sigma_t}
albedo = {albedo}
g = {g}
density = {{ kind = "sphere", center = [0.0, 0.0, 0.0], radius = 0.5 }}
[[light]]
kind = "point"
position = [0.12, -0.08, 0.1]
intensity = [1.0, 0.8, 0.6]
"#
    )
}

/// Equiangular + MIS against plain distance sampling (common::assert_agree; distance sampling
/// of a light inside the medium has a heavy-tailed, formally infinite-variance NEE, so its
/// per-pixel variance estimates are themselves noisy, hence the rare-failure allowance).
fn assert_eq_agrees(what: &str, eq: &RenderOutput, dist: &RenderOutput) {
    assert_agree(what, ("equiangular", eq), ("distance", dist));
}

fn with_eq(gpu: &scatterlab::gpu::Gpu, text: &str, eq: bool, spp: &str, extra: &[(&str, &str)]) -> RenderOutput {
    // Camera paths only: these tests are about equiangular sampling, which light tracing
    // (path.light_tracing, tests/light_tracing_tests.rs) would otherwise take over.
    let mut sets =
        vec![("render.spp", spp), ("path.equiangular", if eq { "on" } else { "off" }), ("path.light_tracing", "off")];
    sets.extend_from_slice(extra);
    let out = render(gpu, &scene(text), PATH, &sets);
    assert_eq!(out.report.settings["equiangular"], if eq { "on" } else { "off" });
    out
}

#[test]
fn equiangular_agrees_with_distance_sampling_grey() {
    let gpu = gpu();
    let text = light_inside_sphere("3.0", "0.8", 0.3, 7);
    let eq = with_eq(&gpu, &text, true, "512", &[]);
    let dist = with_eq(&gpu, &text, false, "2048", &[]);
    assert_eq_agrees("grey", &eq, &dist);
    assert_clean(&gpu);
}

#[test]
fn equiangular_agrees_with_distance_sampling_chromatic_and_single_scattering() {
    let gpu = gpu();
    let text = light_inside_sphere("[2.0, 4.0, 8.0]", "[0.9, 0.7, 0.5]", 0.5, 9);
    let eq = with_eq(&gpu, &text, true, "512", &[]);
    assert!(eq.report.modelled.chromatic);
    let dist = with_eq(&gpu, &text, false, "2048", &[]);
    assert_eq_agrees("chromatic", &eq, &dist);
    let eq1 = with_eq(&gpu, &text, true, "512", &[("path.max_depth", "1")]);
    let dist1 = with_eq(&gpu, &text, false, "2048", &[("path.max_depth", "1")]);
    assert_eq_agrees("chromatic, max_depth 1", &eq1, &dist1);
    assert_clean(&gpu);
}

/// Mean over pixels (those brighter than 2% of the image mean) of the per-pixel relative
/// standard error sqrt(var)/mean, luminance-weighted channels averaged.
fn relative_error(img: &Image, var: &Image) -> f64 {
    let pixels = img.data.len() / 3;
    let lum = |p: usize, d: &Image| (0..3).map(|c| d.data[3 * p + c] as f64).sum::<f64>() / 3.0;
    let image_mean = (0..pixels).map(|p| lum(p, img)).sum::<f64>() / pixels as f64;
    let floor = 0.02 * image_mean;
    let (mut sum, mut n) = (0.0, 0usize);
    for p in 0..pixels {
        let m = lum(p, img);
        if m > floor {
            sum += lum(p, var).sqrt() / m;
            n += 1;
        }
    }
    assert!(n > pixels / 4, "too few lit pixels: {n} of {pixels}");
    sum / n as f64
}

/// The issue's target: at equal spp, the per-pixel error with the point light inside the
/// cloud is within 2x of the error with the light outside; without equiangular sampling the
/// light-inside error is worse. Asserted on the cloud grid at sigma_t = 1.5 (optical depth
/// ~1.5 from the light to the surface), where the light's 1/r^2 singularity dominates the
/// noise. At the shipped sigma_t = 6 (printed only) the noise is dominated by the rarity of
/// paths that random-walk into the dense core, which equiangular sampling does not address:
/// measured against an 8192-spp reference, the true per-pixel error there is ~1.0 inside vs
/// ~0.34 outside with or without equiangular sampling, and the sample-variance estimate used
/// here understates the inside error (heavy tails), so asserting on it would be misleading.
/// At sigma_t = 6 the target is met by light tracing (`path.light_tracing`, on by default for
/// a point light inside the medium): tests/light_tracing_tests.rs.
#[test]
fn equiangular_light_inside_cloud_error_close_to_light_outside() {
    let gpu = gpu();
    let base = std::fs::read_to_string("scenes/point-light-in-cloud.toml").unwrap();
    let small = base
        .replace("width  = 128", "width  = 24")
        .replace("height = 128", "height = 24")
        .replace("file = \"cloud64.vol\"", "file = \"scenes/cloud64.vol\"");
    assert!(small.contains("width  = 24") && small.contains("scenes/cloud64.vol") && small.contains("sigma_t = 6.0"));
    let spp = "128";
    for sigma_t in ["1.5", "6.0"] {
        let inside = small.replace("sigma_t = 6.0", &format!("sigma_t = {sigma_t}"));
        let outside = inside
            .replace("position  = [0.0, -0.05, 0.0]", "position  = [0.0, 2.5, 0.0]")
            .replace("intensity = [4.0, 3.6, 3.0]", "intensity = [40.0, 36.0, 30.0]");
        assert!(outside.contains("[0.0, 2.5, 0.0]"));
        let run = |text: &str, eq: bool| {
            let out = with_eq(&gpu, text, eq, spp, &[]);
            let e = relative_error(&out.image, out.variance.as_ref().unwrap());
            (
                e,
                out.image.mean().iter().sum::<f64>() / 3.0,
                out.report.detail::<PathStats>().unwrap().samples_per_second,
            )
        };
        let (in_eq, m_in, sps_eq) = run(&inside, true);
        let (out_eq, m_out, _) = run(&outside, true);
        let (in_d, _, sps_d) = run(&inside, false);
        let (out_d, _, _) = run(&outside, false);
        eprintln!(
            "cloud sigma_t {sigma_t}, 24x24 at {spp} spp, per-pixel relative error (sample variance): light inside {in_eq:.4} (equiangular) / {in_d:.4} (distance only); \
             light outside {out_eq:.4} (equiangular) / {out_d:.4} (distance only); image means inside {m_in:.4}, outside {m_out:.4}; \
             samples/s inside {sps_eq:.0} (equiangular) vs {sps_d:.0}"
        );
        if sigma_t == "1.5" {
            assert!(
                in_eq <= 2.0 * out_eq,
                "light inside error {in_eq} is more than 2x the light outside error {out_eq}"
            );
            assert!(in_d > in_eq, "equiangular did not reduce the light-inside error: {in_eq} vs {in_d} without");
        }
    }
    assert_clean(&gpu);
}

/// `path.equiangular=auto` samples a point light by equiangular sampling where its 1/r^2 varies
/// by more than 16x over the medium's box: inside it or close to it, not far outside.
#[test]
fn equiangular_auto_takes_the_lights_near_the_medium() {
    use scatterlab::solvers::path::equiangular_lights;
    let text = |p: &str| {
        format!(
            "[render]\nwidth = 8\nheight = 8\n[camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov = \
                30.0\n[medium]\nbounds = [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]\nsigma_t = 4.0\nalbedo = 0.9\ndensity \
                = {{ kind = \"constant\" }}\n[[light]]\nkind = \"point\"\nposition = {p}\nintensity = \
                1.0\n[[light]]\nkind = \"directional\"\ndirection = [0.0, -1.0, 0.0]\nirradiance = \
                1.0\n[[light]]\nkind = \"point\"\nposition = [0.0, 0.0, 0.0]\nintensity = 1.0\n"
        )
    };
    // Far outside (nearest 0.87, farthest 2.6: 3x) -> off; just outside a face -> on; inside -> on.
    assert_eq!(equiangular_lights(&scene(&text("[1.0, 1.0, 1.0]")), "auto"), 0b100);
    assert_eq!(equiangular_lights(&scene(&text("[0.0, 0.55, 0.0]")), "auto"), 0b101);
    assert_eq!(equiangular_lights(&scene(&text("[1.0, 1.0, 1.0]")), "on"), 0b101);
    assert_eq!(equiangular_lights(&scene(&text("[1.0, 1.0, 1.0]")), "false"), 0);
}
