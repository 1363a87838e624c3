//! `scatterlab render`: flags to a checked request, the render, the outputs, the summary, as
//! named steps. Nothing here knows a solver: solver flags are shorthands for knobs the solver's
//! table declares.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{anyhow, bail, Result};
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::json;

use super::commands::{check_output_path, check_validation, gpu_options, parse_bytes, parse_sets};
use super::RenderArgs;
use crate::gpu::{DeviceInfo, Gpu};
use crate::measure::timeline::{self, ScheduleComparison, TimelineSummary};
use crate::output::{self, Staging};
use crate::scene::{is_scene_key, LoadOptions, Scene};
use crate::solvers::{self, RenderOutput, RenderRequest, Settings, Solver};

pub fn render(a: RenderArgs) -> Result<()> {
    let started = Instant::now();
    let solver = solvers::find(&a.solver)?;
    let (scene_sets, settings) = settings_from_flags(&a, solver)?;
    check_outputs(&a)?;
    let budget = parse_bytes(&a.memory_budget)?;
    let scene = Scene::load(&a.scene, &scene_sets, &LoadOptions { memory_budget_bytes: budget })?;
    let gpu = open_gpu(&a)?;
    let (out, comparison) = run(&gpu, solver, &scene, &settings, &a)?;
    check_validation(&gpu)?;
    let nonfinite = out.image.nan_inf_count();
    if nonfinite > 0 {
        bail!(
            "solver {} produced {nonfinite} NaN/Inf values; nothing written (this is a bug: please report the scene)",
            solver.name()
        );
    }
    let wall_s = started.elapsed().as_secs_f64();
    let timeline = timeline::summarize(&out.report.passes);
    write_outputs(&a, &scene, &gpu, &out, &timeline, comparison.as_ref(), wall_s)?;
    print_summary(&a, solver, gpu.info(), &out, &timeline, comparison.as_ref(), wall_s);
    Ok(())
}

/// `--set` pairs and solver flags, split into scene overrides and solver knobs, the knobs
/// checked against the solver's table before any work (a typo costs nothing).
fn settings_from_flags(a: &RenderArgs, solver: &dyn Solver) -> Result<(Vec<(String, String)>, Settings)> {
    let mut sets = parse_sets(&a.set)?;
    if let Some(spp) = a.spp {
        if spp == 0 {
            bail!("--spp 0: samples per pixel must be at least 1");
        }
        sets.push(("render.spp".into(), spp.to_string()));
    }
    if let Some(seed) = a.seed {
        sets.push(("render.seed".into(), seed.to_string()));
    }
    // Flags that are shorthands for a knob: the solver must have that knob.
    let shorthand = [
        ("--max-depth", "max_depth", a.max_depth.map(|d| d.to_string())),
        ("--schedule", "schedule", a.schedule.map(|s| s.name().to_string())),
        ("--deterministic", "deterministic", a.deterministic.then(|| "true".to_string())),
    ];
    for (flag, knob, value) in shorthand {
        if let Some(v) = value {
            require_knob(solver, flag, knob)?;
            sets.push((format!("{}.{knob}", solver.name()), v));
        }
    }
    if a.compare_schedules {
        require_knob(solver, "--compare-schedules", "schedule")?;
        if a.schedule.is_some() {
            bail!("--schedule and --compare-schedules exclude each other (the comparison runs both)");
        }
    }
    let (scene_sets, knob_sets): (Vec<_>, Vec<_>) = sets.into_iter().partition(|(k, _)| is_scene_key(k));
    let settings = Settings::new(&knob_sets);
    settings.knobs(solver.name(), solver.knobs())?;
    Ok((scene_sets, settings))
}

/// `flag` stands for `--set <solver>.<knob>`; an error naming the solvers that have it if
/// this one does not.
fn require_knob(solver: &dyn Solver, flag: &str, knob: &str) -> Result<()> {
    if solver.knobs().iter().any(|k| k.name == knob) {
        return Ok(());
    }
    let having: Vec<&str> =
        solvers::SOLVERS.iter().filter(|s| s.knobs().iter().any(|k| k.name == knob)).map(|s| s.name()).collect();
    bail!("{flag} applies to solvers with a {knob} knob ({}); --solver {} has none", having.join(", "), solver.name())
}

/// Every output path is checked before any work.
fn check_outputs(a: &RenderArgs) -> Result<()> {
    if a.out.is_none() && a.png.is_none() && a.json.is_none() && a.trace.is_none() {
        bail!(
            "no output requested; give --out image.exr and/or --png image.png (and --json metrics.json, --trace \
            trace.json)"
        );
    }
    for (p, flag, ext) in
        [(&a.out, "--out", "exr"), (&a.png, "--png", "png"), (&a.json, "--json", "json"), (&a.trace, "--trace", "json")]
    {
        if let Some(p) = p {
            check_output_path(p, flag, &[ext])?;
        }
    }
    Ok(())
}

fn open_gpu(a: &RenderArgs) -> Result<Gpu> {
    let gpu = Gpu::new(&gpu_options(&a.gpu))?;
    if !a.quiet {
        let info = gpu.info();
        eprintln!(
            "device: {} ({}{}), queues: {}",
            info.name,
            info.device_type,
            if info.software { ", software" } else { "" },
            info.mapping.describe()
        );
    }
    Ok(gpu)
}

/// The render, with a progress bar; under `--compare-schedules` both schedules (the
/// concurrent render is kept).
fn run(
    gpu: &Gpu,
    solver: &dyn Solver,
    scene: &Scene,
    settings: &Settings,
    a: &RenderArgs,
) -> Result<(RenderOutput, Option<ScheduleComparison>)> {
    let bar = if a.quiet { ProgressBar::hidden() } else { ProgressBar::new(1) };
    bar.set_style(
        ProgressStyle::with_template("{spinner} {msg} [{bar:30}] {pos}/{len} ({elapsed}, eta {eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_message(format!("{} {}", solver.name(), a.scene.display()));
    let progress = |done: u64, total: u64| {
        bar.set_length(total);
        bar.set_position(done);
    };
    let req = RenderRequest { scene, settings, force_full: a.model_all, progress: &progress };
    let result = if a.compare_schedules {
        timeline::compare_schedules(gpu, solver, &req).map(|(out, c)| (out, Some(c)))
    } else {
        solver.render(gpu, &req).map(|out| (out, None))
    };
    bar.finish_and_clear();
    Ok(result?)
}

/// Every requested output, staged and then placed together ([`Staging`]): a failure leaves
/// none of them behind.
fn write_outputs(
    a: &RenderArgs,
    scene: &Scene,
    gpu: &Gpu,
    out: &RenderOutput,
    timeline: &TimelineSummary,
    comparison: Option<&ScheduleComparison>,
    wall_s: f64,
) -> Result<()> {
    let info = gpu.info();
    let r = &out.report;
    let mut staging = Staging::new();
    if let Some(p) = &a.out {
        let mut layers: Vec<(&str, &output::Image)> = vec![("", &out.image)];
        if let Some(v) = &out.variance {
            layers.push(("variance", v));
        }
        staging.stage(p, |tmp| output::write_exr(tmp, &layers))?;
    }
    if let Some(p) = &a.png {
        staging.stage(p, |tmp| output::write_png_tonemapped(tmp, &out.image, a.exposure))?;
    }
    if let Some(p) = &a.json {
        let mut doc = json!({
            "scatterlab": env!("CARGO_PKG_VERSION"),
            "scene": a.scene.display().to_string(),
            "width": scene.render.width,
            "height": scene.render.height,
            "device": info,
            "solver": r.solver,
            "settings": r.settings,
            "modelled": r.modelled,
            "device_bytes": r.device_bytes,
            "gpu_ms": r.gpu_ms,
            "wall_s": wall_s,
            "passes": r.passes,
            "stats": r.stats,
            "warnings": r.warnings,
            "validation": { "enabled": gpu.validation_enabled(), "errors": gpu.validation_errors() },
            "image_mean": out.image.mean(),
            "timeline": timeline,
        });
        if let Some(c) = comparison {
            doc["sequential_timeline"] = serde_json::to_value(&c.sequential)?;
        }
        staging.stage(p, |tmp| output::write_json(tmp, &doc))?;
    }
    if let Some(p) = &a.trace {
        let meta = json!({ "scene": a.scene.display().to_string(), "solver": r.solver, "device": info.name, "mapping": info.mapping, "calibrated": info.calibrated_timestamps });
        staging.stage(p, |tmp| timeline::write_chrome_trace(tmp, &r.passes, meta))?;
    }
    staging.commit().map_err(|e| anyhow!("{e}; nothing was written"))
}

/// Warnings always; unless `--quiet`, what was modelled, times, the solver's own lines, the
/// queues where work ran on more than one role, and what was written.
fn print_summary(
    a: &RenderArgs,
    solver: &dyn Solver,
    info: &DeviceInfo,
    out: &RenderOutput,
    timeline: &TimelineSummary,
    comparison: Option<&ScheduleComparison>,
    wall_s: f64,
) {
    let r = &out.report;
    for w in &r.warnings {
        eprintln!("warning: {w}");
    }
    if a.quiet {
        return;
    }
    eprintln!("{}", r.modelled.describe());
    eprintln!("{} passes, GPU {:.1} ms, wall {:.2} s", r.passes.len(), r.gpu_ms, wall_s);
    for line in solver.summary(r) {
        eprintln!("{line}");
    }
    if timeline.per_queue.iter().filter(|q| q.passes > 0).count() > 1 {
        let busy: Vec<String> = timeline
            .per_queue
            .iter()
            .map(|q| format!("{} {:.1} ms ({} passes)", q.role, q.busy_ns as f64 * 1e-6, q.passes))
            .collect();
        eprintln!(
            "queues: busy {}; overlap {:.1}% of busy time{}",
            busy.join(", "),
            100.0 * timeline.overlap_fraction,
            if info.mapping.shared() { " (one shared queue: no overlap possible)" } else { "" }
        );
    }
    if let Some(c) = comparison {
        eprintln!(
            "schedules: sequential {:.1} ms, concurrent {:.1} ms (GPU span): concurrency gain {:.3}x{}; images differ \
                by relL2 {:.2e}",
            c.sequential.span_ns as f64 * 1e-6,
            c.concurrent.span_ns as f64 * 1e-6,
            c.gain,
            if info.mapping.shared() { " (one shared queue: the difference is noise, not overlap)" } else { "" },
            c.images_rel_l2
        );
    }
    let written: [(&Option<PathBuf>, String); 4] = [
        (&a.out, format!("linear RGB f32{}", if out.variance.is_some() { ", + variance layer" } else { "" })),
        (&a.png, format!("tone-mapped: {}", output::TONEMAP_DESCRIPTION)),
        (&a.json, String::new()),
        (&a.trace, "Chrome trace: one track per queue role".into()),
    ];
    for (p, what) in written {
        if let Some(p) = p.as_deref().map(Path::display) {
            if what.is_empty() {
                eprintln!("wrote {p}");
            } else {
                eprintln!("wrote {p} ({what})");
            }
        }
    }
}
