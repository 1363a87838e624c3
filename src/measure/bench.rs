//! `scatterlab bench`: the error-versus-time trade of every solver on the user's scenes
//! (docs/design.md, "Measuring the trade").
//!
//! Per scene: the `path` reference at high spp, cached on disk under a key of the scene's
//! content (scene text, grid data, overrides), engine version, device and reference spp; then
//! each solver walks its own quality ladder ([`Solver::ladder`]: samples per pixel for `path`,
//! step for `single`, grid resolution for `lbl`...). Each point: GPU time (sum of pass timestamps) and wall time, medians over
//! repeats, and the metrics of `output::compare` against the reference. Results: CSV, JSON
//! (device, driver, queue mapping, versions, settings) and one SVG plot per scene of relL2
//! against GPU time on log-log axes, one line per solver, the Pareto front marked.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::gpu::{DeviceInfo, Gpu};
use crate::output::{self, Image, Metrics};
use crate::scene::Scene;
use crate::solvers::{self, RenderOutput, Rung, Solver};

use super::render_with as render;

/// Which rungs of each solver's ladder `bench` runs.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub enum Points {
    /// Every rung.
    All,
    /// The `n` cheapest (`--quick`: 3).
    Cheapest(usize),
    /// These rungs, numbered from 1 at the cheap end, ascending (`--points 1,3-5`).
    Rungs(Vec<usize>),
}

impl Points {
    /// `--points`: comma-separated rung numbers and ranges counted from 1 at the cheap end
    /// (`2`, `1,3-5`).
    pub fn parse(text: &str) -> Result<Points, String> {
        let bad = |part: &str| {
            format!("--points {text}: '{part}' is not a rung number or range; give e.g. 1,3-5 (rungs from 1, cheapest first)")
        };
        let mut v = Vec::new();
        for part in text.split(',').map(str::trim) {
            let num = |s: &str| s.trim().parse::<usize>().ok().filter(|n| *n >= 1).ok_or_else(|| bad(part));
            match part.split_once('-') {
                Some((a, b)) => {
                    let (a, b) = (num(a)?, num(b)?);
                    if a > b {
                        return Err(bad(part));
                    }
                    v.extend(a..=b);
                }
                None => v.push(num(part)?),
            }
        }
        v.sort_unstable();
        v.dedup();
        Ok(Points::Rungs(v))
    }

    /// The highest rung number asked for, if any is named.
    pub fn highest(&self) -> Option<usize> {
        match self {
            Points::Rungs(v) => v.last().copied(),
            _ => None,
        }
    }
}

/// A solver's quality ladder on `scene`, cheapest first, cut to `points` (numbers past the
/// ladder's end are not there: the CLI refuses them before any work).
pub fn ladder(solver: &dyn Solver, scene: &Scene, points: &Points) -> Vec<Rung> {
    let v = solver.ladder(scene);
    match points {
        Points::All => v,
        Points::Cheapest(n) => v.into_iter().take(*n).collect(),
        Points::Rungs(which) => {
            v.into_iter().enumerate().filter(|(i, _)| which.contains(&(i + 1))).map(|(_, r)| r).collect()
        }
    }
}

/// A measured point.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Point {
    pub scene: String,
    #[serde(deserialize_with = "solver_name")]
    pub solver: &'static str,
    pub knob: String,
    pub value: String,
    /// Medians of the warm renders (of the cold one where it ran alone).
    pub gpu_ms: f64,
    pub wall_ms: f64,
    /// The first render of the point in the process, reported apart (pipelines built; on a
    /// GPU, clocks possibly still low).
    #[serde(default)]
    pub cold_gpu_ms: f64,
    #[serde(default)]
    pub cold_wall_ms: f64,
    /// The warm renders' GPU times: how many, their spread, whether the last two agreed
    /// within 5%.
    #[serde(default)]
    pub warm: super::Spread,
    pub metrics: Metrics,
    pub iterations: Option<u64>,
    pub converged: Option<bool>,
    pub device_bytes: u64,
    pub pareto: bool,
    /// Monte Carlo solvers: samples per pixel of this render.
    pub spp: Option<u32>,
    /// relL2 with the reference's own noise removed: sqrt(max(relL2^2 - noise^2, 0)).
    pub rel_l2_denoised: f64,
    /// Approximate solvers: the reference solver's GPU time to the same (denoised) error,
    /// along its 1/sqrt(spp) curve, over this point's GPU time ([`speedups`]); None for the
    /// reference solver itself or an error below what its curve resolves.
    pub speedup: Option<f64>,
}

/// A registered solver's name from its text (a bench.json read back).
fn solver_name<'de, D: serde::Deserializer<'de>>(d: D) -> Result<&'static str, D::Error> {
    let name = String::deserialize(d)?;
    solvers::SOLVERS
        .iter()
        .map(|s| s.name())
        .find(|n| *n == name)
        .ok_or_else(|| serde::de::Error::custom(format!("unknown solver {name:?}")))
}

/// The plots of a bench run from its JSON document (`bench --replot`): per scene, its points
/// and its reference's noise floor, titled with the device the run measured.
pub fn replot(doc: &serde_json::Value) -> Result<Vec<(String, String)>, String> {
    let points = points_of(doc)?;
    let device = doc["device"]["name"].as_str().unwrap_or("an unnamed device");
    let mut scenes: Vec<&str> = Vec::new();
    for p in &points {
        if !scenes.contains(&p.scene.as_str()) {
            scenes.push(&p.scene);
        }
    }
    Ok(scenes
        .into_iter()
        .map(|name| {
            let here: Vec<Point> = points.iter().filter(|p| p.scene == name).cloned().collect();
            let noise = doc["references"]
                .as_array()
                .and_then(|r| r.iter().find(|r| r["scene"] == name))
                .and_then(|r| r["noise"].as_f64());
            (name.to_string(), svg(&format!("{name}: error vs GPU time on {device}"), &here, noise))
        })
        .collect())
}

/// Figures of merit a GPU engineer compares across devices.
#[derive(Clone, Debug, Serialize)]
pub struct Throughput {
    pub scene: String,
    pub solver: &'static str,
    pub figure: String,
    pub value: f64,
    pub unit: String,
}

/// Indices on the Pareto front of (time, error): points no other point beats on both.
pub fn pareto(points: &[(f64, f64)]) -> Vec<bool> {
    points.iter().map(|&(t, e)| !points.iter().any(|&(t2, e2)| t2 <= t && e2 <= e && (t2 < t || e2 < e))).collect()
}

/// Cache key of a reference: scene content (file text, overrides, grid data), engine
/// version and build (a change to the tracer must not find the old tracer's reference),
/// device and driver, reference spp.
pub fn reference_key(
    scene_text: &str,
    scene: &Scene,
    overrides: &[(String, String)],
    device: &DeviceInfo,
    spp: u32,
) -> String {
    let mut h = Sha256::new();
    h.update(crate::scene::content_hash(scene_text, scene).as_bytes());
    for (k, v) in overrides {
        h.update(format!("{k}={v};").as_bytes());
    }
    h.update(env!("CARGO_PKG_VERSION").as_bytes());
    h.update(crate::BUILD.as_bytes());
    h.update(
        format!("{}|{}|{}|{}|seed^{REFERENCE_SEED}", device.name, device.driver_name, device.driver_info, spp)
            .as_bytes(),
    );
    h.finalize().iter().take(12).map(|b| format!("{b:02x}")).collect()
}

/// XORed into the scene's seed for the reference render (independent of every rung).
const REFERENCE_SEED: u64 = 0x5eed_0f7e_f500;

/// A reference image and the variance of each of its pixel means.
pub struct Reference {
    pub image: Image,
    pub variance: Option<Image>,
}

impl Reference {
    /// The relL2 the reference's own noise adds to any comparison with it:
    /// sqrt(sum of pixel variances) / ||reference|| (the expected ||r - r_true|| / ||r||).
    pub fn noise(&self) -> f64 {
        self.variance.as_ref().map_or(0.0, |v| output::metrics::relative_noise(&self.image, v))
    }
}

/// The cached reference for a scene (the reference solver at `spp`), rendering it when
/// missing. Returns it and whether it came from the cache.
pub fn reference(gpu: &Gpu, scene: &Scene, key: &str, spp: u32, cache: &Path) -> Result<(Reference, bool), String> {
    let file = cache.join(format!("ref-{key}.exr"));
    if let Ok(img) = output::read_exr(&file) {
        if (img.width, img.height) == (scene.render.width, scene.render.height) {
            let variance = output::read_exr_layer(&file, "variance").ok();
            return Ok((Reference { image: img, variance }, true));
        }
    }
    // Its own seed: the reference solver's ladder renders the scene's seed, and a reference
    // sharing its random numbers would agree with those rungs more than chance allows (at
    // 1024 of 2048 spp the two shared half their samples: relL2 0.016 against the 0.028 two
    // independent renders give).
    let seed = scene.render.seed ^ REFERENCE_SEED;
    let sets = [("render.spp".to_string(), spp.to_string()), ("render.seed".to_string(), seed.to_string())];
    let (r, _) = render(gpu, scene, solvers::reference(), &sets, false)?;
    std::fs::create_dir_all(cache).map_err(|e| format!("cannot create cache {}: {e}", cache.display()))?;
    let mut layers: Vec<(&str, &Image)> = vec![("", &r.image)];
    if let Some(v) = &r.variance {
        layers.push(("variance", v));
    }
    output::write_exr(&file, &layers).map_err(|e| e.to_string())?;
    Ok((Reference { image: r.image, variance: r.variance }, false))
}

/// The speed-up at equal error of every approximate point of one scene against the reference
/// solver's points (docs/design.md, "Measuring the trade"). With `noise` the reference's own relL2
/// noise, a point's error is denoised as e = sqrt(max(relL2^2 - noise^2, 0)). The reference
/// solver's error falls as e(s)^2 = K / s with samples per pixel s (Monte Carlo), so K is
/// fitted from its points (median of s e(s)^2 over those above the noise), its GPU time is
/// t(s) = t1 s (least squares through the origin), and reaching error e takes it
/// t1 K / e^2. The speed-up of a point is that time over the point's GPU time. Points with
/// e = 0 (error below the reference's noise) get none: the comparison cannot resolve them.
pub fn speedups(points: &mut [Point], reference_solver: &str, noise: f64) {
    for p in points.iter_mut() {
        p.rel_l2_denoised = (p.metrics.rel_l2.powi(2) - noise * noise).max(0.0).sqrt();
    }
    let curve: Vec<(f64, f64, f64)> = points
        .iter()
        .filter(|p| p.solver == reference_solver)
        .filter_map(|p| p.spp.map(|s| (s as f64, p.gpu_ms, p.rel_l2_denoised)))
        .collect();
    let mut ks: Vec<f64> = curve.iter().filter(|c| c.2 > 0.0).map(|(s, _, e)| s * e * e).collect();
    let (sum_st, sum_ss) = curve.iter().fold((0.0, 0.0), |(a, b), (s, t, _)| (a + s * t, b + s * s));
    if ks.is_empty() || sum_ss <= 0.0 {
        return;
    }
    ks.sort_by(|a, b| a.total_cmp(b));
    let k = ks[ks.len() / 2];
    let t1 = sum_st / sum_ss;
    for p in points.iter_mut().filter(|p| p.solver != reference_solver) {
        if p.rel_l2_denoised > 0.0 && p.gpu_ms > 0.0 {
            p.speedup = Some(t1 * k / p.rel_l2_denoised.powi(2) / p.gpu_ms);
        }
    }
}

/// Walk every solver's ladder on one scene.
#[allow(clippy::too_many_arguments)]
pub fn bench_scene(
    gpu: &Gpu,
    name: &str,
    scene: &Scene,
    reference: &Image,
    solvers: &[&dyn Solver],
    points_: &Points,
    repeats: u32,
    progress: &dyn Fn(&str),
) -> Result<(Vec<Point>, Vec<Throughput>), String> {
    let mut points = Vec::new();
    let mut thr = Vec::new();
    for &solver in solvers {
        for rung in ladder(solver, scene, points_) {
            progress(&format!("{name}: {} {}={}", solver.name(), rung.knob, rung.value));
            // One cold render, then warm ones until two agree within 5% (at most repeats - 1).
            let runs = super::Runs::take(
                repeats.max(1) - 1,
                |(r, _): &(RenderOutput, f64)| r.report.gpu_ms,
                || render(gpu, scene, solver, &rung.sets, false),
            )?;
            let warm = runs.spread(|(r, _)| r.report.gpu_ms);
            let wall = runs.spread(|(_, w)| *w);
            let (cold_gpu_ms, cold_wall_ms) = (runs.cold.0.report.gpu_ms, runs.cold.1);
            let r = &runs.last().0;
            let metrics = output::compare(&r.image, reference).map_err(|e| e.to_string())?;
            let stats = &r.report.stats;
            for f in &stats.throughput {
                thr.push(Throughput {
                    scene: name.into(),
                    solver: solver.name(),
                    figure: format!("{} at {}={}", f.figure, rung.knob, rung.value),
                    value: f.value,
                    unit: f.unit.clone(),
                });
            }
            points.push(Point {
                scene: name.into(),
                solver: solver.name(),
                knob: rung.knob.clone(),
                value: rung.value.clone(),
                gpu_ms: warm.median,
                wall_ms: wall.median,
                cold_gpu_ms,
                cold_wall_ms,
                warm,
                metrics,
                iterations: stats.convergence.map(|c| c.iterations),
                converged: stats.convergence.map(|c| c.converged),
                device_bytes: r.report.device_bytes,
                pareto: false,
                spp: stats.spp,
                rel_l2_denoised: metrics.rel_l2,
                speedup: None,
            });
        }
    }
    let front = pareto(&points.iter().map(|p| (p.gpu_ms, p.metrics.rel_l2)).collect::<Vec<_>>());
    for (p, f) in points.iter_mut().zip(front) {
        p.pareto = f;
    }
    Ok((points, thr))
}

/// Slim against full modelling for one solver: the same scene with every optional feature
/// forced on (`--model-all`). Returns (slim bytes, full bytes, slim ms, full ms, relL2 between).
pub fn slim_vs_full(
    gpu: &Gpu,
    scene: &Scene,
    solver: &dyn Solver,
    sets: &[(String, String)],
) -> Result<(u64, u64, f64, f64, f64), String> {
    let (a, _) = render(gpu, scene, solver, sets, false)?;
    let (b, _) = render(gpu, scene, solver, sets, true)?;
    let d = output::compare(&a.image, &b.image).map_err(|e| e.to_string())?.rel_l2;
    Ok((a.report.device_bytes, b.report.device_bytes, a.report.gpu_ms, b.report.gpu_ms, d))
}

pub fn csv(points: &[Point]) -> Result<String, String> {
    let header = [
        "scene",
        "solver",
        "knob",
        "value",
        "gpu_ms",
        "wall_ms",
        "cold_gpu_ms",
        "cold_wall_ms",
        "warm_runs",
        "gpu_spread",
        "settled",
        "rel_l2",
        "rel_l2_denoised",
        "speedup",
        "rel_mse",
        "rmse",
        "energy_ratio",
        "max_abs_error",
        "nan_inf_count",
        "iterations",
        "converged",
        "device_bytes",
        "pareto",
    ];
    let rows = points.iter().map(|p| {
        let m = &p.metrics;
        vec![
            p.scene.clone(),
            p.solver.to_string(),
            p.knob.clone(),
            p.value.clone(),
            format!("{:.3}", p.gpu_ms),
            format!("{:.3}", p.wall_ms),
            format!("{:.3}", p.cold_gpu_ms),
            format!("{:.3}", p.cold_wall_ms),
            p.warm.runs.to_string(),
            format!("{:.4}", p.warm.spread),
            p.warm.settled.to_string(),
            format!("{:.6e}", m.rel_l2),
            format!("{:.6e}", p.rel_l2_denoised),
            p.speedup.map(|x| format!("{x:.4}")).unwrap_or_default(),
            format!("{:.6e}", m.rel_mse),
            format!("{:.6e}", m.rmse),
            format!("{:.6}", m.energy_ratio),
            format!("{:.6e}", m.max_abs_error),
            m.nan_inf_count.to_string(),
            p.iterations.map(|i| i.to_string()).unwrap_or_default(),
            p.converged.map(|c| c.to_string()).unwrap_or_default(),
            p.device_bytes.to_string(),
            p.pareto.to_string(),
        ]
    });
    super::csv_text(&header, rows)
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

/// A label's box: left, top, width, height (SVG units, y down).
pub type LabelBox = (f64, f64, f64, f64);

/// The box of a `chars`-character label at font size 9 whose baseline starts at (x, y).
fn label_box(x: f64, y: f64, chars: usize) -> LabelBox {
    (x, y - 9.0, 5.2 * chars as f64 + 2.0, 11.0)
}

fn overlaps(a: &LabelBox, b: &LabelBox) -> bool {
    a.0 < b.0 + b.2 && b.0 < a.0 + a.2 && a.1 < b.1 + b.3 && b.1 < a.1 + a.3
}

/// Baselines for labels of `chars` characters beside points at (x, y), in order, so that no
/// two labels overlap: each takes the first free spot of upper right, lower right, upper
/// left, lower left of its point, else the first free row stepping down (then up) from its
/// point. Points on one spot (equal time and error) get stacked labels.
pub fn place_labels(anchors: &[(f64, f64, usize)]) -> Vec<(f64, f64)> {
    let mut placed: Vec<LabelBox> = Vec::new();
    let mut out = Vec::with_capacity(anchors.len());
    for &(x, y, chars) in anchors {
        let w = label_box(0.0, 0.0, chars).2;
        let around = [(x + 6.0, y - 6.0), (x + 6.0, y + 14.0), (x - 6.0 - w, y - 6.0), (x - 6.0 - w, y + 14.0)];
        let rows = (1..).flat_map(|k| [(x + 6.0, y - 6.0 + 12.0 * k as f64), (x + 6.0, y - 6.0 - 12.0 * k as f64)]);
        let free = |&(bx, by): &(f64, f64)| !placed.iter().any(|p| overlaps(p, &label_box(bx, by, chars)));
        // Every label lies in a finite strip, so some row below them all is free.
        let spot = around.into_iter().chain(rows).find(free).expect("a free row exists");
        placed.push(label_box(spot.0, spot.1, chars));
        out.push(spot);
    }
    out
}

/// relL2 against GPU time, log-log, one polyline per solver, Pareto points ringed, readable
/// without the CSV (axis labels, decades, legend, knob values beside points, never
/// overlapping), and the reference's noise floor as a dashed line: below it a point's error
/// is the reference's, not the solver's.
pub fn svg(title: &str, points: &[Point], noise_floor: Option<f64>) -> String {
    let (w, h, ml, mr, mt, mb) = (720.0f64, 480.0f64, 70.0, 150.0, 40.0, 50.0);
    let finite: Vec<&Point> =
        points.iter().filter(|p| p.gpu_ms > 0.0 && p.metrics.rel_l2 > 0.0 && p.metrics.rel_l2.is_finite()).collect();
    let lx: Vec<f64> = finite.iter().map(|p| p.gpu_ms.log10()).collect();
    let ly: Vec<f64> = finite.iter().map(|p| p.metrics.rel_l2.log10()).collect();
    let (x0, x1) = (
        lx.iter().cloned().fold(f64::INFINITY, f64::min).floor(),
        lx.iter().cloned().fold(f64::NEG_INFINITY, f64::max).ceil(),
    );
    let floor = noise_floor.filter(|n| *n > 0.0 && n.is_finite());
    let (y0, y1) = (
        ly.iter().cloned().chain(floor.map(f64::log10)).fold(f64::INFINITY, f64::min).floor(),
        ly.iter().cloned().fold(f64::NEG_INFINITY, f64::max).ceil(),
    );
    let (x0, x1, y0, y1) =
        if finite.is_empty() { (0.0, 1.0, -1.0, 0.0) } else { (x0, x1.max(x0 + 1.0), y0, y1.max(y0 + 1.0)) };
    let px = |v: f64| ml + (v - x0) / (x1 - x0) * (w - ml - mr);
    let py = |v: f64| h - mb - (v - y0) / (y1 - y0) * (h - mt - mb);
    let mut s = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" viewBox=\"0 0 {w} {h}\" \
            font-family=\"sans-serif\" font-size=\"12\">\n<rect width=\"{w}\" height=\"{h}\" fill=\"white\"/>\n<text \
            x=\"{}\" y=\"22\" font-size=\"15\">{}</text>\n",
        ml,
        esc(title)
    );
    for d in (x0 as i32)..=(x1 as i32) {
        let x = px(d as f64);
        s.push_str(&format!(
            "<line x1=\"{x:.1}\" y1=\"{mt}\" x2=\"{x:.1}\" y2=\"{}\" stroke=\"#ddd\"/><text \
            x=\"{x:.1}\" y=\"{}\" text-anchor=\"middle\">1e{d}</text>\n",
            h - mb,
            h - mb + 16.0
        ));
    }
    for d in (y0 as i32)..=(y1 as i32) {
        let y = py(d as f64);
        s.push_str(&format!(
            "<line x1=\"{ml}\" y1=\"{y:.1}\" x2=\"{}\" y2=\"{y:.1}\" stroke=\"#ddd\"/><text x=\"{}\" \
            y=\"{:.1}\" text-anchor=\"end\">1e{d}</text>\n",
            w - mr,
            ml - 6.0,
            y + 4.0
        ));
    }
    s.push_str(&format!(
        "<text x=\"{:.1}\" y=\"{}\" text-anchor=\"middle\">GPU time (ms, log)</text>\n<text x=\"16\" y=\"{:.1}\" \
            transform=\"rotate(-90 16 {:.1})\" text-anchor=\"middle\">relL2 vs {} reference (log)</text>\n",
        (ml + w - mr) / 2.0,
        h - 10.0,
        (mt + h - mb) / 2.0,
        (mt + h - mb) / 2.0,
        solvers::reference().name()
    ));
    if let Some(n) = floor {
        let y = py(n.log10());
        s.push_str(&format!(
            "<line x1=\"{ml}\" y1=\"{y:.1}\" x2=\"{}\" y2=\"{y:.1}\" stroke=\"#888\" stroke-dasharray=\"6 4\"/>\n<text \
            x=\"{}\" y=\"{:.1}\" font-size=\"10\" fill=\"#666\" text-anchor=\"end\">reference noise floor {n:.4}</text>\n",
            w - mr,
            w - mr - 4.0,
            y + 12.0
        ));
    }
    let mut labels: Vec<(f64, f64, String)> = Vec::new();
    let colours = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e"];
    let mut kinds: Vec<&str> = Vec::new();
    for p in &finite {
        if !kinds.contains(&p.solver) {
            kinds.push(p.solver);
        }
    }
    for (i, kind) in kinds.iter().enumerate() {
        let c = colours[i % colours.len()];
        let pts: Vec<&&Point> = finite.iter().filter(|p| p.solver == *kind).collect();
        let path: Vec<String> =
            pts.iter().map(|p| format!("{:.1},{:.1}", px(p.gpu_ms.log10()), py(p.metrics.rel_l2.log10()))).collect();
        s.push_str(&format!(
            "<polyline points=\"{}\" fill=\"none\" stroke=\"{c}\" stroke-width=\"2\"/>\n",
            path.join(" ")
        ));
        for p in &pts {
            let (x, y) = (px(p.gpu_ms.log10()), py(p.metrics.rel_l2.log10()));
            s.push_str(&format!(
                "<circle cx=\"{x:.1}\" cy=\"{y:.1}\" r=\"3.5\" fill=\"{c}\"><title>{} {}={}: {:.1} \
                ms, relL2 {:.4}</title></circle>\n",
                kind, p.knob, p.value, p.gpu_ms, p.metrics.rel_l2
            ));
            if p.pareto {
                s.push_str(&format!("<circle cx=\"{x:.1}\" cy=\"{y:.1}\" r=\"7\" fill=\"none\" stroke=\"black\"/>\n"));
            }
            labels.push((x, y, p.value.chars().take(6).collect::<String>()));
        }
        let ly = mt + 20.0 + 20.0 * i as f64;
        s.push_str(&format!(
            "<line x1=\"{}\" y1=\"{ly:.1}\" x2=\"{}\" y2=\"{ly:.1}\" stroke=\"{c}\" \
            stroke-width=\"3\"/><text x=\"{}\" y=\"{:.1}\">{}</text>\n",
            w - mr + 10.0,
            w - mr + 34.0,
            w - mr + 40.0,
            ly + 4.0,
            kind
        ));
    }
    let anchors: Vec<(f64, f64, usize)> = labels.iter().map(|(x, y, t)| (*x, *y, t.chars().count())).collect();
    for ((bx, by), (_, _, text)) in place_labels(&anchors).into_iter().zip(&labels) {
        s.push_str(&format!("<text x=\"{bx:.1}\" y=\"{by:.1}\" font-size=\"9\" fill=\"#555\">{}</text>\n", esc(text)));
    }
    let ly = mt + 20.0 + 20.0 * kinds.len() as f64;
    s.push_str(&format!(
        "<circle cx=\"{}\" cy=\"{ly:.1}\" r=\"7\" fill=\"none\" stroke=\"black\"/><text x=\"{}\" \
        y=\"{:.1}\">Pareto front</text>\n",
        w - mr + 22.0,
        w - mr + 40.0,
        ly + 4.0
    ));
    s.push_str("</svg>\n");
    s
}

/// A scene to bench: its name (the file stem), its file text (part of the reference's cache
/// key) and the scene as loaded.
pub struct BenchScene {
    pub name: String,
    pub text: String,
    pub scene: Scene,
}

/// What `bench` runs.
pub struct BenchConfig<'a> {
    pub solvers: &'a [&'a dyn Solver],
    /// Samples per pixel of the reference.
    pub ref_spp: u32,
    /// Renders per point; times are medians.
    pub repeats: u32,
    /// The rungs of each ladder to run.
    pub points: Points,
    /// Scene overrides the scenes were loaded with (part of the cache key).
    pub overrides: &'a [(String, String)],
    /// Where references are cached.
    pub cache: &'a Path,
}

/// The reference a scene was measured against.
#[derive(Clone, Debug, Serialize)]
pub struct ReferenceInfo {
    pub scene: String,
    pub key: String,
    pub spp: u32,
    pub cached: bool,
    pub seconds: f64,
    /// The relL2 its own noise adds to every comparison ([`Reference::noise`]).
    pub noise: f64,
}

/// Slim against full modelling of one solver on one scene (`--model-all`).
#[derive(Clone, Debug, Serialize)]
pub struct SlimVsFull {
    pub scene: String,
    pub solver: &'static str,
    pub slim_bytes: u64,
    pub full_bytes: u64,
    pub slim_ms: f64,
    pub full_ms: f64,
    pub rel_l2_between: f64,
}

/// A solver `bench` left out of a scene, and why ([`Solver::inapplicable`]).
#[derive(Clone, Debug, Serialize)]
pub struct Skipped {
    pub scene: String,
    pub solver: &'static str,
    pub why: String,
}

/// Everything a bench run measured.
#[derive(Clone, Debug, Serialize)]
pub struct BenchResult {
    pub references: Vec<ReferenceInfo>,
    pub points: Vec<Point>,
    pub throughput: Vec<Throughput>,
    pub slim_vs_full: Vec<SlimVsFull>,
    /// Solvers left out of a scene because the method does not apply there.
    pub skipped: Vec<Skipped>,
    /// One SVG plot per scene: (scene name, SVG text).
    #[serde(skip)]
    pub plots: Vec<(String, String)>,
}

/// Bench every scene: its cached reference, every solver's ladder, the plot, and slim against
/// full modelling at each solver's third rung (for `path`, enough samples that the difference
/// is not all noise).
/// How many steps [`run`] takes (each announced by one `progress` call): per scene the
/// reference, every rung of every applicable solver, and each solver's slim-vs-full pair.
pub fn steps(scenes: &[BenchScene], cfg: &BenchConfig) -> usize {
    scenes
        .iter()
        .map(|s| {
            let here = cfg.solvers.iter().filter(|solver| solver.inapplicable(&s.scene).is_none());
            1 + here.map(|solver| ladder(*solver, &s.scene, &cfg.points).len() + 1).sum::<usize>()
        })
        .sum()
}

/// `progress` is called once as each of the [`steps`] steps starts, with what it is.
pub fn run(
    gpu: &Gpu,
    scenes: &[BenchScene],
    cfg: &BenchConfig,
    progress: &dyn Fn(&str),
) -> Result<BenchResult, String> {
    let info = gpu.info().clone();
    let mut out = BenchResult {
        references: Vec::new(),
        points: Vec::new(),
        throughput: Vec::new(),
        slim_vs_full: Vec::new(),
        skipped: Vec::new(),
        plots: Vec::new(),
    };
    for s in scenes {
        let key = reference_key(&s.text, &s.scene, cfg.overrides, &info, cfg.ref_spp);
        progress(&format!("{}: {} reference at {} spp", s.name, solvers::reference().name(), cfg.ref_spp));
        let t = std::time::Instant::now();
        let (reference, cached) = reference(gpu, &s.scene, &key, cfg.ref_spp, cfg.cache)?;
        let noise = reference.noise();
        out.references.push(ReferenceInfo {
            scene: s.name.clone(),
            key,
            spp: cfg.ref_spp,
            cached,
            seconds: t.elapsed().as_secs_f64(),
            noise,
        });
        let mut solvers_here: Vec<&dyn Solver> = Vec::new();
        for &solver in cfg.solvers {
            match solver.inapplicable(&s.scene) {
                Some(why) => out.skipped.push(Skipped { scene: s.name.clone(), solver: solver.name(), why }),
                None => solvers_here.push(solver),
            }
        }
        let (mut points, thr) =
            bench_scene(gpu, &s.name, &s.scene, &reference.image, &solvers_here, &cfg.points, cfg.repeats, progress)?;
        speedups(&mut points, solvers::reference().name(), noise);
        out.plots.push((
            s.name.clone(),
            svg(&format!("{}: error vs GPU time on {}", s.name, info.name), &points, Some(noise)),
        ));
        for &solver in &solvers_here {
            // A deterministic solver's slim and full renders differ or not at any rung: its
            // cheapest. A Monte Carlo one (the reference) at its third, so the difference is
            // not all noise.
            let rung = ladder(solver, &s.scene, &Points::Cheapest(3))
                .into_iter()
                .nth(if solver.is_reference() { 2 } else { 0 })
                .ok_or_else(|| format!("solver {}'s bench ladder has fewer than three rungs", solver.name()))?;
            progress(&format!("{}: {} slim vs full modelling", s.name, solver.name()));
            let (sb, fb, sm, fm, d) = slim_vs_full(gpu, &s.scene, solver, &rung.sets)?;
            out.slim_vs_full.push(SlimVsFull {
                scene: s.name.clone(),
                solver: solver.name(),
                slim_bytes: sb,
                full_bytes: fb,
                slim_ms: sm,
                full_ms: fm,
                rel_l2_between: d,
            });
        }
        out.points.extend(points);
        out.throughput.extend(thr);
    }
    Ok(out)
}

/// Default cache directory for references.
pub fn default_cache() -> PathBuf {
    PathBuf::from(".scatterlab-cache")
}

/// The fields of bench.json that runs combined into one document must share: the same engine
/// (version and build), the same device and driver, and the same settings, so that every
/// point of the combination was measured the same way. Paths into the document, `/`-separated.
const SHARED_FIELDS: &[&str] =
    &["scatterlab", "build", "device/name", "device/driver_name", "device/driver_info", "repeats", "quick", "rungs"];

/// Several bench runs' documents (bench.json, each named by where it was read from) as one
/// (`bench --replot DIR DIR...`; one Slurm task per scene, tools/slurm/bench.sbatch). The runs
/// must share [`SHARED_FIELDS`] and their references' samples per pixel, and no scene may be in
/// two of them: a scene's points, reference, speed-ups (each computed within its own scene) and
/// plot are then exactly what one run over every scene would have written. The error names the
/// two documents and the field.
pub fn combine(docs: &[(String, serde_json::Value)]) -> Result<serde_json::Value, String> {
    use serde_json::Value;
    let (first_name, first) = docs.first().ok_or("no bench runs to combine")?;
    let field = |doc: &Value, path: &str| -> Value {
        path.split('/').fold(doc, |v, k| v.get(k).unwrap_or(&Value::Null)).clone()
    };
    let ref_spp = |doc: &Value| -> Vec<Value> {
        let mut v: Vec<Value> =
            doc["references"].as_array().map(|r| r.iter().map(|r| r["spp"].clone()).collect()).unwrap_or_default();
        v.dedup();
        v
    };
    let mut scenes: Vec<(String, &str)> = Vec::new();
    for (name, doc) in docs {
        let points = doc["points"].as_array().ok_or_else(|| format!("{name}: it has no points"))?;
        for path in SHARED_FIELDS {
            let (a, b) = (field(first, path), field(doc, path));
            if a != b {
                return Err(format!(
                    "{first_name} and {name} differ in {path} ({a} against {b}); combine runs of one engine build, \
                     device and set of bench flags"
                ));
            }
        }
        let (a, b) = (ref_spp(first), ref_spp(doc));
        if a.len() > 1 || a != b {
            return Err(format!(
                "{first_name} and {name} differ in the references' spp ({} against {}); give every task the same \
                 --ref-spp",
                Value::from(a),
                Value::from(b)
            ));
        }
        let here = points
            .iter()
            .chain(doc["references"].as_array().into_iter().flatten())
            .filter_map(|p| p["scene"].as_str())
            .fold(Vec::new(), |mut v: Vec<&str>, s| {
                if !v.contains(&s) {
                    v.push(s);
                }
                v
            });
        for s in here {
            if let Some((other, _)) = scenes.iter().find(|(_, x)| *x == s) {
                return Err(format!(
                    "{other} and {name} both hold scene {s}; a scene is benched by one task (scenes are named by \
                     their file stem: rename one of two files with the same name)"
                ));
            }
            scenes.push((name.clone(), s));
        }
    }
    let concat = |key: &str| -> Value {
        Value::Array(docs.iter().flat_map(|(_, d)| d[key].as_array().cloned().unwrap_or_default()).collect())
    };
    let mut out = first.clone();
    for key in ["references", "points", "throughput", "slim_vs_full", "skipped"] {
        out[key] = concat(key);
    }
    // Each run's ladders are those of its own first scene: keep every solver's first listing.
    let mut ladders: Vec<Value> = Vec::new();
    for l in docs.iter().flat_map(|(_, d)| d["ladders"].as_array().cloned().unwrap_or_default()) {
        if !ladders.iter().any(|x| x["solver"] == l["solver"]) {
            ladders.push(l);
        }
    }
    out["ladders"] = Value::Array(ladders);
    out["combined_from"] = Value::Array(docs.iter().map(|(n, _)| Value::from(n.as_str())).collect());
    Ok(out)
}

/// The points of a bench.json document, read back.
pub fn points_of(doc: &serde_json::Value) -> Result<Vec<Point>, String> {
    let points = doc["points"].as_array().ok_or("it has no points")?;
    // Point by point from owned values: a point names its solver as a `&'static str` of the
    // registry, which ties the derive to a 'static deserializer.
    points
        .iter()
        .map(|v| Point::deserialize(v.clone()))
        .collect::<Result<_, _>>()
        .map_err(|e| format!("its points do not read back: {e}"))
}
