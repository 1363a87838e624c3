//! `scatterlab report` (issue 14): one run that characterises a Vulkan device for scattering
//! workloads. What it measures, in order:
//! 1. the device's own memory bandwidth (a buffer copy on the compute queue and a read/write
//!    compute kernel, glsl/probe/bandwidth.comp), so every other figure can be read as a
//!    fraction of what this device moves;
//! 2. the seeds' headline workloads for every solver that has one (`Solver::headline`: lbl 128^3 + 1024^2; the
//!    wavefront 128 x 128 x 64; dom 128^3 N = 24, two iterations as the thesis times a frame;
//!    path on the cloud for scale), each with its time, the throughput figures its render reports
//!    and the fraction of the probed bandwidth its modelled traffic reaches; a workload the
//!    device refuses (a binding limit, memory) is recorded with its one-line reason;
//! 3. the queue-concurrency matrix: each solver's concurrent workload (`Solver::concurrency`:
//!    lbl's marching beside its lattice), sequential against concurrent, under every
//!    mapping the device offers (shared, same-family, separate-families), with the overlap and a
//!    Perfetto trace per mapping; a mapping the device lacks is recorded as such.
//!
//! `--quick` shrinks every size (CI runs it on lavapipe). `report --compare A B` prints two
//! reports' figures side by side with their ratio.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::gpu::{Copy, Gpu, GpuOptions, Pass, QueueRole};
use crate::scene::{LoadOptions, Scene};
use crate::solvers::parts::probes::{BandwidthPush, BANDWIDTH};
use crate::solvers::{self, Headline, RenderRequest, Settings, Solver};

/// The JSON's layout version: bump it when a field changes meaning.
pub const SCHEMA: u32 = 1;

/// Invocations of one bandwidth dispatch (a grid-stride loop covers the rest).
const PROBE_INVOCATIONS: u32 = 256 * 1024;

/// One bandwidth measurement: bytes moved per run (read + written), the best and median of
/// `runs` GPU times, and the rate at the best time.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Bandwidth {
    /// `copy` (vkCmdCopyBuffer on the compute queue) or `compute` (probe/bandwidth.comp).
    pub method: String,
    pub buffer_bytes: u64,
    pub bytes_moved: u64,
    pub runs: u32,
    pub best_ms: f64,
    pub median_ms: f64,
    pub gb_per_s: f64,
}

/// A throughput figure of a workload, with its share of the probed bandwidth where it is one.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Figure {
    pub figure: String,
    pub value: f64,
    pub unit: String,
    /// value / the best probed GB/s, for figures in GB/s.
    pub fraction_of_bandwidth: Option<f64>,
}

/// One headline workload. Its times are the warm runs' medians: the first run is reported
/// apart as the cold start ([`super::Runs`]).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Workload {
    pub name: String,
    pub solver: String,
    pub scene: String,
    pub sets: Vec<(String, String)>,
    /// What the seed paper reports for the same workload (its hardware, its year).
    pub seed: String,
    /// None when it ran; else the one-line reason the device refused it.
    pub error: Option<String>,
    pub wall_ms: f64,
    /// GPU time summed over passes, and first start to last end.
    pub gpu_ms: f64,
    pub span_ms: f64,
    pub device_bytes: u64,
    pub figures: Vec<Figure>,
    /// The warm runs' wall times (median, spread, whether the last two agreed within 5%).
    #[serde(default)]
    pub wall: super::Spread,
    /// GPU time over span: below 80% the host kept the GPU waiting.
    #[serde(default)]
    pub gpu_busy: f64,
    /// From the render's start to its first submission of passes (pipelines, allocations,
    /// uploads), and the wall time outside the GPU's span (start-up, waits between batches,
    /// readbacks, the image), warm medians.
    #[serde(default)]
    pub startup_ms: f64,
    #[serde(default)]
    pub overhead_ms: f64,
    /// Host milliseconds building pipelines: cold (the first run, nothing built in this process)
    /// and warm (built again through the pipeline cache the cold run filled).
    #[serde(default)]
    pub pipelines_cold_ms: f64,
    #[serde(default)]
    pub pipelines_warm_ms: f64,
    /// Host waits and submissions of a warm run, the solver's iterations, waits per iteration.
    #[serde(default)]
    pub waits: u64,
    #[serde(default)]
    pub submits: u64,
    #[serde(default)]
    pub iterations: Option<u64>,
    #[serde(default)]
    pub waits_per_iteration: Option<f64>,
    /// The cold run: wall, GPU and span ms.
    #[serde(default)]
    pub cold: Option<ColdRun>,
}

/// The first run of a workload in the process: pipelines built, clocks possibly still low.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct ColdRun {
    pub wall_ms: f64,
    pub gpu_ms: f64,
    pub span_ms: f64,
}

/// A concurrent workload (`Solver::concurrency`: lbl, path) under one queue mapping.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct QueueRun {
    pub mapping: String,
    /// None when the device offers the mapping; else why not.
    pub unavailable: Option<String>,
    /// The roles' queues as mapped.
    pub roles: Option<String>,
    pub workload: String,
    /// Median GPU spans of the sequential and concurrent schedules, ms.
    pub sequential_ms: f64,
    pub concurrent_ms: f64,
    /// sequential / concurrent where the roles have queues of their own.
    pub gain: Option<f64>,
    /// Time both roles were busy over the time either was, in the concurrent schedule.
    pub overlap_fraction: f64,
    pub images_rel_l2: f64,
    /// The Perfetto (Chrome JSON) trace of the concurrent schedule, beside the report.
    pub trace: Option<String>,
    /// Its timeline drawn as an SVG (a row per role, a bar per pass), beside the report.
    pub svg: Option<String>,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Report {
    pub schema: u32,
    pub engine: String,
    pub quick: bool,
    /// `devices --json`'s entry for the device.
    pub device: serde_json::Value,
    pub bandwidth: Vec<Bandwidth>,
    pub workloads: Vec<Workload>,
    pub queues: Vec<QueueRun>,
    pub wall_s: f64,
}

impl Report {
    /// The best probed bandwidth, GB/s.
    pub fn peak_gb_per_s(&self) -> Option<f64> {
        self.bandwidth.iter().map(|b| b.gb_per_s).reduce(f64::max)
    }
}

/// What the report needs besides the device: where the scenes are, and how small to run.
pub struct ReportOptions {
    pub quick: bool,
    pub scenes: PathBuf,
    pub out: PathBuf,
    pub gpu: GpuOptions,
}

type Error = Box<dyn std::error::Error + Send + Sync>;

/// The bandwidth probe: `bytes` per buffer (rounded down to vec4s and to one binding), `runs`
/// times each method; the bytes moved are twice the buffer (read and written).
pub fn probe_bandwidth(gpu: &Gpu, bytes: u64, runs: u32) -> Result<Vec<Bandwidth>, Error> {
    let bytes = (bytes.min(gpu.info().max_storage_buffer_range) / 16 * 16).max(16);
    let src = gpu.buffer("report bandwidth source", bytes)?;
    let dst = gpu.buffer("report bandwidth destination", bytes)?;
    let pipeline = gpu.pipeline(&BANDWIDTH, &[])?;
    let count = (bytes / 16) as u32;
    let stride = PROBE_INVOCATIONS.min(count.div_ceil(256) * 256);
    let mut out = Vec::new();
    for method in ["copy", "compute"] {
        let mut times = Vec::new();
        // One run unmeasured first: the first touch of the pages and the pipeline's.
        for run in 0..=runs {
            gpu.take_timings();
            let point = if method == "copy" {
                let c = Copy { src: src.clone(), src_offset: 0, dst: dst.clone(), dst_offset: 0, size: bytes };
                gpu.submit_copies(QueueRole::Trace, &[vec![c]], &[])?
            } else {
                let p = Pass::new("report.bandwidth", QueueRole::Trace, &pipeline)
                    .read(0, &src)
                    .write(1, &dst)
                    .push(&BandwidthPush { count, stride, scale: 1.0001, pad: 0 })
                    .cover([stride, 1, 1]);
                gpu.submit(QueueRole::Trace, &[p], &[])?
            };
            gpu.wait(point)?;
            let ms: f64 = gpu.take_timings().iter().map(|t| t.duration_ms()).sum();
            if run > 0 && ms > 0.0 {
                times.push(ms);
            }
        }
        if times.is_empty() {
            return Err(format!("the {method} probe took no measurable GPU time (no timestamps on the queue?)").into());
        }
        let best = times.iter().copied().fold(f64::INFINITY, f64::min);
        let n = times.len() as u32;
        out.push(Bandwidth {
            method: method.into(),
            buffer_bytes: bytes,
            bytes_moved: 2 * bytes,
            runs: n,
            best_ms: best,
            median_ms: super::median(&times),
            gb_per_s: 2.0 * bytes as f64 / (best * 1e-3) / 1e9,
        });
    }
    Ok(out)
}

fn load_scene(dir: &Path, h: &Headline) -> Result<(Scene, Settings), Error> {
    let path = dir.join(h.scene);
    let (scene_sets, knob_sets): (Vec<_>, Vec<_>) =
        h.sets.iter().cloned().partition(|(k, _)| crate::scene::is_scene_key(k));
    let scene = Scene::load(&path, &scene_sets, &LoadOptions::default())?;
    Ok((scene, Settings::new(&knob_sets)))
}

/// What one run of a workload gave.
struct Run {
    out: crate::solvers::RenderOutput,
    wall_ms: f64,
    span_ms: f64,
    startup_ms: f64,
}

fn run_once(gpu: &Gpu, s: &dyn Solver, req: &RenderRequest) -> Result<Run, crate::solvers::SolverError> {
    gpu.take_timings();
    gpu.take_first_submit();
    let started = Instant::now();
    let out = s.render(gpu, req)?;
    let wall_ms = started.elapsed().as_secs_f64() * 1e3;
    let startup_ms = gpu.take_first_submit().map_or(wall_ms, |t| t.duration_since(started).as_secs_f64() * 1e3);
    let span_ms = super::timeline::summarize(&out.report.passes).span_ns as f64 * 1e-6;
    Ok(Run { out, wall_ms, span_ms, startup_ms })
}

fn run_workload(
    gpu: &Gpu,
    dir: &Path,
    peak: Option<f64>,
    s: &dyn Solver,
    h: &Headline,
    max_warm: u32,
) -> Result<Workload, Error> {
    let mut w = Workload {
        name: h.name.clone(),
        solver: s.name().into(),
        scene: h.scene.into(),
        sets: h.sets.clone(),
        seed: h.seed.into(),
        error: None,
        wall_ms: 0.0,
        gpu_ms: 0.0,
        span_ms: 0.0,
        device_bytes: 0,
        figures: Vec::new(),
        wall: Default::default(),
        gpu_busy: 0.0,
        startup_ms: 0.0,
        overhead_ms: 0.0,
        pipelines_cold_ms: 0.0,
        pipelines_warm_ms: 0.0,
        waits: 0,
        submits: 0,
        iterations: None,
        waits_per_iteration: None,
        cold: None,
    };
    let (scene, settings) = load_scene(dir, h)?;
    let req = RenderRequest { scene: &scene, settings: &settings, force_full: false, progress: &|_| {} };
    // Cold: nothing built in this process. The first warm run builds its pipelines again
    // through the pipeline cache the cold run filled (the driver's compile skipped where it
    // keeps code there); later runs reuse them, as a process that stays up does.
    gpu.forget_pipelines();
    let mut count = 0u32;
    let runs = super::Runs::take(
        max_warm,
        |r: &Run| r.wall_ms,
        || {
            if count == 1 {
                gpu.forget_pipelines();
            }
            count += 1;
            run_once(gpu, s, &req)
        },
    );
    let runs = match runs {
        Err(e) => {
            w.error = Some(e.to_string());
            return Ok(w);
        }
        Ok(r) => r,
    };
    let c = &runs.cold;
    w.cold = Some(ColdRun { wall_ms: c.wall_ms, gpu_ms: c.out.report.gpu_ms, span_ms: c.span_ms });
    w.pipelines_cold_ms = c.out.report.host.pipelines.ms;
    w.pipelines_warm_ms = runs.warm.first().map_or(0.0, |r| r.out.report.host.pipelines.ms);
    w.wall = runs.spread(|r| r.wall_ms);
    w.wall_ms = w.wall.median;
    w.gpu_ms = runs.spread(|r| r.out.report.gpu_ms).median;
    w.span_ms = runs.spread(|r| r.span_ms).median;
    w.startup_ms = runs.spread(|r| r.startup_ms).median;
    w.overhead_ms = runs.spread(|r| r.wall_ms - r.span_ms).median;
    w.gpu_busy = if w.span_ms > 0.0 { w.gpu_ms / w.span_ms } else { 0.0 };
    let r = &runs.last().out.report;
    w.waits = r.host.waits.count;
    w.submits = r.host.submits.count;
    w.iterations = r.stats.convergence.map(|c| c.iterations);
    w.waits_per_iteration = w.iterations.filter(|n| *n > 0).map(|n| w.waits as f64 / n as f64);
    w.device_bytes = r.device_bytes;
    w.figures = r
        .stats
        .throughput
        .iter()
        .map(|f| Figure {
            figure: f.figure.clone(),
            value: f.value,
            unit: f.unit.clone(),
            fraction_of_bandwidth: (f.unit == "GB/s").then_some(()).and(peak).map(|p| f.value / p),
        })
        .collect();
    Ok(w)
}

/// The queue matrix: each concurrent workload's schedules under each mapping.
fn queue_matrix(opts: &ReportOptions, dir: &Path) -> Result<Vec<QueueRun>, Error> {
    let repeats = if opts.quick { 1 } else { 3 };
    let mut out = Vec::new();
    for (s, h) in solvers::SOLVERS.iter().filter_map(|s| Some((*s, s.concurrency(opts.quick)?))) {
        out.extend(queue_runs(opts, dir, s, &h, repeats)?);
    }
    Ok(out)
}

fn queue_runs(
    opts: &ReportOptions,
    dir: &Path,
    solver: &dyn Solver,
    h: &Headline,
    repeats: u32,
) -> Result<Vec<QueueRun>, Error> {
    let name = h.name.clone();
    let mut out = Vec::new();
    for mapping in ["shared", "same-family", "separate-families"] {
        let mut run = QueueRun {
            mapping: mapping.into(),
            unavailable: None,
            roles: None,
            workload: name.clone(),
            sequential_ms: 0.0,
            concurrent_ms: 0.0,
            gain: None,
            overlap_fraction: 0.0,
            images_rel_l2: 0.0,
            trace: None,
            svg: None,
        };
        let gopts = GpuOptions { queues: Some(mapping.into()), ..opts.gpu.clone() };
        let gpu = match Gpu::new(&gopts) {
            Ok(g) => g,
            Err(e) => {
                run.unavailable = Some(e.to_string());
                out.push(run);
                continue;
            }
        };
        run.roles = Some(gpu.info().mapping.describe());
        let (scene, settings) = load_scene(dir, h)?;
        let req = RenderRequest { scene: &scene, settings: &settings, force_full: false, progress: &|_| {} };
        let (rendered, c) = super::timeline::compare_schedules(&gpu, solver, &req, repeats)?;
        run.sequential_ms = super::median(&c.sequential_ms);
        run.concurrent_ms = super::median(&c.concurrent_ms);
        run.gain = c.gain;
        run.overlap_fraction = c.concurrent.overlap_fraction;
        run.images_rel_l2 = c.images_rel_l2;
        let trace = format!("trace-{}-{mapping}.json", solver.name());
        super::timeline::write_chrome_trace(
            &opts.out.join(&trace),
            &rendered.report.passes,
            serde_json::json!({ "mapping": mapping, "workload": name }),
        )?;
        run.trace = Some(trace);
        let svg = format!("overlap-{}-{mapping}.svg", solver.name());
        let title = format!(
            "{} under {mapping}: {:.1}% of the busy time with two roles busy",
            name,
            100.0 * c.concurrent.overlap_fraction
        );
        crate::output::write_text(&opts.out.join(&svg), timeline_svg(&rendered.report.passes, &title))?;
        run.svg = Some(svg);
        if gpu.validation_errors() > 0 {
            return Err(format!("the validation layer reported errors under {mapping}").into());
        }
        out.push(run);
    }
    Ok(out)
}

/// A timeline as an SVG: a row per queue role, a bar per pass (time from the first start), so
/// the overlap of the roles shows at a glance.
pub fn timeline_svg(passes: &[crate::gpu::PassTiming], title: &str) -> String {
    let (w, row, left, top) = (960.0f64, 28.0f64, 90.0f64, 40.0f64);
    let t0 = passes.iter().map(|p| p.start_ns).min().unwrap_or(0);
    let t1 = passes.iter().map(|p| p.end_ns).max().unwrap_or(1).max(t0 + 1);
    let x = |t: i128| left + (t - t0) as f64 / (t1 - t0) as f64 * (w - left - 10.0);
    let roles = QueueRole::ALL;
    let h = top + row * roles.len() as f64 + 30.0;
    let mut s = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" font-family=\"sans-serif\" \
         font-size=\"12\">\n<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n<text x=\"10\" y=\"20\">{}</text>\n",
        title.replace('&', "&amp;").replace('<', "&lt;")
    );
    let colours = ["#4477aa", "#ee6677", "#228833"];
    for (i, role) in roles.iter().enumerate() {
        let y = top + row * i as f64;
        s += &format!("<text x=\"10\" y=\"{:.1}\">{}</text>\n", y + row * 0.65, role.name());
        for p in passes.iter().filter(|p| p.role == *role) {
            let (a, b) = (x(p.start_ns), x(p.end_ns.max(p.start_ns)));
            s += &format!(
                "<rect x=\"{a:.2}\" y=\"{:.1}\" width=\"{:.2}\" height=\"{:.1}\" fill=\"{}\"><title>{} {:.3} ms</title></rect>\n",
                y + 4.0,
                (b - a).max(0.5),
                row - 8.0,
                colours[i % colours.len()],
                p.name,
                p.duration_ms()
            );
        }
    }
    s += &format!(
        "<text x=\"{left}\" y=\"{:.1}\">0</text><text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\">{:.1} ms</text>\n</svg>\n",
        h - 8.0,
        w - 10.0,
        h - 8.0,
        (t1 - t0) as f64 * 1e-6
    );
    s
}

/// Run the whole report on `gpu` (the device, with the mapping the user asked for).
pub fn run(gpu: &Gpu, device: serde_json::Value, opts: &ReportOptions) -> Result<Report, Error> {
    let started = Instant::now();
    let (bytes, runs) = if opts.quick { (16u64 << 20, 3) } else { (256u64 << 20, 10) };
    let bandwidth = probe_bandwidth(gpu, bytes, runs)?;
    let mut report = Report {
        schema: SCHEMA,
        engine: crate::output::engine(),
        quick: opts.quick,
        device,
        bandwidth,
        workloads: Vec::new(),
        queues: Vec::new(),
        wall_s: 0.0,
    };
    let peak = report.peak_gb_per_s();
    for (s, h) in solvers::SOLVERS.iter().filter_map(|s| Some((*s, s.headline(opts.quick)?))) {
        // Warm runs until two agree within 5% (at most 6; with --quick one, which shows the
        // split but cannot say whether the times settled).
        let max_warm = if opts.quick { 1 } else { 6 };
        report.workloads.push(run_workload(gpu, &opts.scenes, peak, s, &h, max_warm)?);
    }
    report.queues = queue_matrix(opts, &opts.scenes)?;
    report.wall_s = started.elapsed().as_secs_f64();
    Ok(report)
}

/// The report as tables a person reads.
pub fn markdown(r: &Report) -> String {
    let mut s = String::new();
    let name = r.device.get("name").and_then(|v| v.as_str()).unwrap_or("?");
    s += &format!(
        "# scatterlab report: {name}\n\n{}{}; {:.0} s.\n\n",
        r.engine,
        if r.quick { ", --quick" } else { "" },
        r.wall_s
    );
    s += "## Memory bandwidth (the device's own)\n\n| method | buffer | moved per run | runs | best ms | median ms | GB/s |\n| --- | --- | --- | --- | --- | --- | --- |\n";
    for b in &r.bandwidth {
        s += &format!(
            "| {} | {:.1} MiB | {:.1} MiB | {} | {:.3} | {:.3} | {:.1} |\n",
            b.method,
            b.buffer_bytes as f64 / 1048576.0,
            b.bytes_moved as f64 / 1048576.0,
            b.runs,
            b.best_ms,
            b.median_ms,
            b.gb_per_s
        );
    }
    s += "\n## Headline workloads\n\nWarm runs (after one cold run, until two agree within 5%): median wall ms with the \
          spread of the runs, GPU ms summed over passes, span ms from the first pass's start to the last's end, GPU busy = \
          GPU / span (below 80% the host keeps the GPU waiting), start-up = render start to the first submission, \
          overhead = wall - span; pipelines built cold (first run) and warm (again, through the pipeline cache); host \
          waits per iteration of an iterative solver; the cold run's wall, GPU and span apart.\n\n| workload | wall ms \
          | GPU ms | span ms | GPU busy | start-up ms | overhead ms | pipelines cold / warm ms | waits (per iteration) \
          | cold wall / GPU / span ms | device MiB | throughput | seed |\n| --- | --- | --- | --- | --- | --- | --- | --- \
          | --- | --- | --- | --- | --- |\n";
    for w in &r.workloads {
        if let Some(e) = &w.error {
            s += &format!("| {} | refused: {} | | | | | {} |\n", w.name, e.replace('|', "/"), w.seed);
            continue;
        }
        let figs: Vec<String> = w
            .figures
            .iter()
            .map(|f| {
                let frac =
                    f.fraction_of_bandwidth.map(|x| format!(" ({:.1}% of the probe)", 100.0 * x)).unwrap_or_default();
                format!("{} {:.3e} {}{frac}", f.figure, f.value, f.unit)
            })
            .collect();
        let waits = match w.waits_per_iteration {
            Some(x) => format!("{} ({x:.2})", w.waits),
            None => w.waits.to_string(),
        };
        let cold = w.cold.map_or(String::new(), |c| format!("{:.1} / {:.1} / {:.1}", c.wall_ms, c.gpu_ms, c.span_ms));
        s += &format!(
            "| {} | {:.1} ±{:.0}%{} | {:.1} | {:.1} | {:.0}% | {:.1} | {:.1} | {:.0} / {:.0} | {} | {} | {:.1} | {} | {} |\n",
            w.name,
            w.wall_ms,
            100.0 * w.wall.spread,
            if w.wall.settled { "" } else { " (not settled)" },
            w.gpu_ms,
            w.span_ms,
            100.0 * w.gpu_busy,
            w.startup_ms,
            w.overhead_ms,
            w.pipelines_cold_ms,
            w.pipelines_warm_ms,
            waits,
            cold,
            w.device_bytes as f64 / 1048576.0,
            figs.join("; "),
            w.seed
        );
    }
    s += "\n## Queue concurrency (each solver's concurrent workload under each mapping)\n\n| workload | mapping | roles | sequential ms | concurrent ms | gain | overlap | trace, timeline |\n| --- | --- | --- | --- | --- | --- | --- | --- |\n";
    for q in &r.queues {
        match &q.unavailable {
            Some(e) => {
                s += &format!("| {} | {} | not offered: {} | | | | | |\n", q.workload, q.mapping, e.replace('|', "/"))
            }
            None => {
                s += &format!(
                    "| {} | {} | {} | {:.1} | {:.1} | {} | {:.1}% | {} {} |\n",
                    q.workload,
                    q.mapping,
                    q.roles.as_deref().unwrap_or(""),
                    q.sequential_ms,
                    q.concurrent_ms,
                    q.gain.map_or("- (one queue)".into(), |g| format!("{g:.2}x")),
                    100.0 * q.overlap_fraction,
                    q.trace.as_deref().unwrap_or(""),
                    q.svg.as_deref().unwrap_or("")
                )
            }
        }
    }
    s
}

/// Every numeric figure of a report, by a stable name (for `--compare`).
pub fn figures(r: &Report) -> Vec<(String, f64)> {
    let mut out = Vec::new();
    for b in &r.bandwidth {
        out.push((format!("bandwidth {} GB/s", b.method), b.gb_per_s));
    }
    for w in r.workloads.iter().filter(|w| w.error.is_none()) {
        out.push((format!("{}: wall ms", w.name), w.wall_ms));
        out.push((format!("{}: GPU ms", w.name), w.gpu_ms));
        out.push((format!("{}: span ms", w.name), w.span_ms));
        out.push((format!("{}: GPU busy", w.name), w.gpu_busy));
        out.push((format!("{}: start-up ms", w.name), w.startup_ms));
        out.push((format!("{}: host waits", w.name), w.waits as f64));
        if let Some(c) = w.cold {
            out.push((format!("{}: cold wall ms", w.name), c.wall_ms));
        }
        for f in &w.figures {
            out.push((format!("{}: {} {}", w.name, f.figure, f.unit), f.value));
        }
    }
    for q in r.queues.iter().filter(|q| q.unavailable.is_none()) {
        out.push((format!("queues {} under {}: sequential ms", q.workload, q.mapping), q.sequential_ms));
        out.push((format!("queues {} under {}: concurrent ms", q.workload, q.mapping), q.concurrent_ms));
    }
    out
}

/// One figure of two reports: its value in each (None where one lacks it) and b / a.
pub struct Compared {
    pub figure: String,
    pub a: Option<f64>,
    pub b: Option<f64>,
    pub ratio: Option<f64>,
}

/// Two reports side by side, the figures of both in a's order.
pub fn compare(a: &Report, b: &Report) -> Vec<Compared> {
    let (fa, fb) = (figures(a), figures(b));
    let mut names: Vec<String> = fa.iter().map(|(n, _)| n.clone()).collect();
    for (n, _) in &fb {
        if !names.contains(n) {
            names.push(n.clone());
        }
    }
    names
        .into_iter()
        .map(|n| {
            let x = fa.iter().find(|(m, _)| *m == n).map(|(_, v)| *v);
            let y = fb.iter().find(|(m, _)| *m == n).map(|(_, v)| *v);
            let ratio = match (x, y) {
                (Some(x), Some(y)) if x != 0.0 => Some(y / x),
                _ => None,
            };
            Compared { figure: n, a: x, b: y, ratio }
        })
        .collect()
}
