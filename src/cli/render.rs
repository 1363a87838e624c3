//! `scatterlab render`: flags to a checked request, the render, the outputs, the summary, as
//! named steps. Nothing here knows a solver: solver flags are shorthands for knobs the solver's
//! table declares.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{anyhow, bail, Result};
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::json;

use super::args::{check_output_path, check_validation, gpu_options, parse_bytes, parse_sets};
use super::RenderArgs;
use crate::gpu::{DeviceInfo, Gpu};
use crate::measure::timeline::{self, ScheduleComparison, TimelineSummary};
use crate::output::{self, Staging};
use crate::scene::{is_scene_key, LoadOptions, Scene};
use crate::solvers::{self, Progress, RenderOutput, RenderRequest, Settings, Solver};

pub fn render(a: RenderArgs) -> Result<()> {
    let started = Instant::now();
    let solver = solvers::find(&a.solver)?;
    let (overrides, scene_sets, settings) = settings_from_flags(&a, solver)?;
    check_outputs(&a)?;
    let budget = parse_bytes(&a.memory_budget)?;
    let scene = Scene::load(&a.scene, &scene_sets, &LoadOptions { memory_budget_bytes: budget })?;
    if let Some(why) = solver.scene_refusal(&scene) {
        bail!("{}: {why}", a.scene.display());
    }
    // What the discretisation is known to miss, said before any work (the render's report
    // carries the same lines; they are not printed twice).
    let early = solver.preflight(&scene, &settings.knobs(solver.name(), solver.knobs())?)?;
    for w in &early {
        eprintln!("warning: {w}");
    }
    let provenance = provenance(&a, solver, &scene, &overrides)?;
    let gpu = open_gpu(&a)?;
    let (out, comparison) = run(&gpu, solver, &scene, &settings, &a)?;
    check_validation(&gpu)?;
    // Saved now rather than when the device closes, so the JSON can say what the driver kept.
    if let (Some(w), _) = gpu.save_pipeline_cache() {
        eprintln!("warning: {w}");
    }
    // A pixel that overflowed is a wrong image whether it reached the image as NaN/Inf or was
    // set to 0 on the way (the solvers' guard): nothing is written either way.
    let nonfinite = out.image.nan_inf_count() + out.report.nonfinite_pixels as u64;
    if nonfinite > 0 {
        bail!(
            "solver {} produced {nonfinite} NaN/Inf values; nothing written (a scene value past what 32-bit floats \
             hold, such as sigma_t x density, emission x emission_scale or a light's power near 3.4e38, gives this; \
             otherwise it is a bug: please report the scene)",
            solver.name()
        );
    }
    let wall_s = started.elapsed().as_secs_f64();
    let timeline = timeline::summarize(&out.report.passes);
    let exposure = a.exposure.unwrap_or(scene.render.exposure);
    write_outputs(&a, &provenance, exposure, &gpu, &out, &timeline, comparison.as_ref(), wall_s)?;
    print_summary(&a, exposure, solver, gpu.info(), &out, &timeline, comparison.as_ref(), wall_s, &early);
    Ok(())
}

type Overrides = Vec<(String, String)>;

/// Every override as `key=value` in the order given (for provenance), then `--set` pairs
/// and solver flags split into scene overrides and solver knobs, the knobs checked against
/// the solver's table before any work (a typo costs nothing).
fn settings_from_flags(a: &RenderArgs, solver: &dyn Solver) -> Result<(Vec<String>, Overrides, Settings)> {
    let mut sets = parse_sets(&a.set)?;
    let sampling_only = |flag: &str| -> Result<()> {
        if solver.samples_pixels() {
            return Ok(());
        }
        let sampling: Vec<&str> = solvers::SOLVERS.iter().filter(|s| s.samples_pixels()).map(|s| s.name()).collect();
        bail!(
            "{flag} applies to solvers that sample pixels ({}); --solver {} computes each pixel without samples \
             (its quality knobs: scatterlab knobs {})",
            sampling.join(", "),
            solver.name(),
            solver.name()
        )
    };
    if let Some(spp) = a.spp {
        if spp == 0 {
            bail!("--spp 0: samples per pixel must be at least 1");
        }
        sampling_only("--spp")?;
        sets.push(("render.spp".into(), spp.to_string()));
    }
    if let Some(range) = &a.samples {
        let (first, end) = output::parse_range(range).map_err(|e| anyhow!("--samples {e}"))?;
        sampling_only("--samples")?;
        sets.push(("render.first_sample".into(), first.to_string()));
        sets.push(("render.spp".into(), (end - first).to_string()));
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
    if a.repeats.is_some() && !a.compare_schedules {
        bail!("--repeats counts the renders of --compare-schedules; add --compare-schedules or drop --repeats");
    }
    if a.compare_schedules {
        require(solver, "--compare-schedules", "queue schedules to compare", |s| s.schedules().is_some())?;
        if a.schedule.is_some() {
            bail!("--schedule and --compare-schedules exclude each other (the comparison runs both)");
        }
    }
    let given = sets.iter().map(|(k, v)| format!("{k}={v}")).collect();
    let (scene_sets, knob_sets): (Vec<_>, Vec<_>) = sets.into_iter().partition(|(k, _)| is_scene_key(k));
    let settings = Settings::new(&knob_sets);
    settings.knobs(solver.name(), solver.knobs())?;
    Ok((given, scene_sets, settings))
}

/// What made this image ([`output::Provenance`]): the scene's content digest is taken from
/// the file as loaded ([`super::args::scene_digest`]).
fn provenance(a: &RenderArgs, solver: &dyn Solver, scene: &Scene, overrides: &[String]) -> Result<output::Provenance> {
    Ok(output::Provenance {
        engine: output::engine(),
        scene: a.scene.display().to_string(),
        scene_hash: super::args::scene_digest(&a.scene, scene)?,
        overrides: overrides.to_vec(),
        solver: solver.name().to_string(),
        seed: scene.render.seed,
        spp: solver.samples_pixels().then_some(scene.render.spp),
        samples: solver
            .samples_pixels()
            .then_some((scene.render.first_sample, scene.render.first_sample + scene.render.spp)),
        estimators: Vec::new(),
        width: scene.render.width,
        height: scene.render.height,
    })
}

/// The image formats `--out` writes, chosen by the file's extension as pbrt and Mitsuba do.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum ImageFormat {
    /// Linear RGB f32, with a `variance` layer where the solver estimates one, and the
    /// provenance as header attributes.
    Exr,
    /// Tone-mapped 8-bit sRGB (`--exposure`), provenance as text chunks.
    Png,
    /// Linear RGB f32, no metadata.
    Pfm,
}

const OUT_EXTENSIONS: [&str; 3] = ["exr", "png", "pfm"];

impl ImageFormat {
    fn of(p: &Path) -> Option<ImageFormat> {
        match p.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
            Some("exr") => Some(ImageFormat::Exr),
            Some("png") => Some(ImageFormat::Png),
            Some("pfm") => Some(ImageFormat::Pfm),
            _ => None,
        }
    }
}

/// `flag` stands for `--set <solver>.<knob>`; an error naming the solvers that have it if
/// this one does not.
fn require_knob(solver: &dyn Solver, flag: &str, knob: &str) -> Result<()> {
    require(solver, flag, &format!("a {knob} knob"), |s| s.knobs().iter().any(|k| k.name == knob))
}

/// `flag` needs a solver with `what` (`has`): else one line naming the solvers that have it.
fn require(solver: &dyn Solver, flag: &str, what: &str, has: impl Fn(&dyn Solver) -> bool) -> Result<()> {
    if has(solver) {
        return Ok(());
    }
    let having: Vec<&str> = solvers::SOLVERS.iter().filter(|s| has(**s)).map(|s| s.name()).collect();
    bail!("{flag} applies to solvers with {what} ({}); --solver {} has none", having.join(", "), solver.name())
}

/// Every output path is checked before any work.
fn check_outputs(a: &RenderArgs) -> Result<()> {
    if a.out.is_none() && a.png.is_none() && a.json.is_none() && a.trace.is_none() {
        bail!(
            "no output requested; give --out image.exr and/or --png image.png (and --json metrics.json, --trace \
            trace.json)"
        );
    }
    if let Some(p) = &a.out {
        if ImageFormat::of(p).is_none() {
            let ext = p.extension().map(|e| format!(".{}", e.to_string_lossy())).unwrap_or("no extension".into());
            bail!(
                "--out {}: {ext} is not an image format scatterlab writes; use .exr (linear float, with the variance \
                 layer and provenance), .png (tone-mapped 8-bit) or .pfm (linear float)",
                p.display()
            );
        }
        check_output_path(p, "--out", &OUT_EXTENSIONS)?;
    }
    for (p, flag, ext) in [(&a.png, "--png", "png"), (&a.json, "--json", "json"), (&a.trace, "--trace", "json")] {
        if let Some(p) = p {
            check_output_path(p, flag, &[ext])?;
        }
    }
    // Two outputs on one name: the second would silently replace the first.
    let named: Vec<(&str, &PathBuf)> =
        [("--out", &a.out), ("--png", &a.png), ("--json", &a.json), ("--trace", &a.trace)]
            .into_iter()
            .filter_map(|(flag, p)| p.as_ref().map(|p| (flag, p)))
            .collect();
    for (i, (f1, p1)) in named.iter().enumerate() {
        if let Some((f2, _)) = named[i + 1..].iter().find(|(_, p2)| p2 == p1) {
            bail!("{f1} and {f2} both name {}; give each output its own file", p1.display());
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
    let name = format!("{} {}", solver.name(), a.scene.display());
    let work_style = ProgressStyle::with_template("{spinner} {msg} [{bar:30}] {pos}/{len} ({elapsed}, eta {eta})")
        .unwrap_or_else(|_| ProgressStyle::default_bar());
    // Before the first unit of a stage finishes there is no rate: no ETA rather than "eta 0s".
    let start_style = ProgressStyle::with_template("{spinner} {msg} [{bar:30}] {pos}/{len} ({elapsed})")
        .unwrap_or_else(|_| ProgressStyle::default_bar());
    // No total while iterating to a tolerance: a spinner with the convergence measure (and
    // the iterations left at its measured decay) rather than a bar that stands still.
    let spin_style = ProgressStyle::with_template("{spinner} {msg} ({elapsed})")
        .unwrap_or_else(|_| ProgressStyle::default_spinner());
    bar.set_style(start_style.clone());
    bar.set_message(name.clone());
    bar.enable_steady_tick(std::time::Duration::from_millis(150));
    let stage_now = std::cell::Cell::new("");
    // Where stderr is not a terminal indicatif draws nothing: a plain line at most every
    // --progress-every seconds there, so a render of minutes is not silent in a CI log or a
    // batch job's file (dom at g 0.999 ran 2 minutes on a 32^2 render without a line).
    let plain = super::args::PlainProgress::new(a.quiet, a.progress_every);
    let progress = |p: Progress| match p {
        Progress::Work { stage, done, total } => {
            plain.line(&|| format!("{name}: {stage} {done}/{total}"));
            if stage_now.replace(stage) != stage {
                // A new stage: its own rate, so the ETA is not one of the last stage's.
                bar.reset();
                bar.set_message(format!("{name}: {stage}"));
            }
            bar.set_style(if done == 0 { start_style.clone() } else { work_style.clone() });
            bar.set_length(total);
            bar.set_position(done);
        }
        Progress::Converging { stage, iteration, change, tol, remaining } => {
            if stage_now.replace(stage) != stage {
                bar.set_style(spin_style.clone());
            }
            let left = remaining.map(|r| format!(", about {r} more at the measured decay")).unwrap_or_default();
            let text = format!("{name}: {stage} {iteration}, change {change:.1e} (tolerance {tol:.0e}){left}");
            plain.line(&|| text.clone());
            bar.set_message(text);
            bar.tick();
        }
    };
    let req = RenderRequest { scene, settings, force_full: a.model_all, progress: &progress };
    let result = if a.compare_schedules {
        timeline::compare_schedules(gpu, solver, &req, a.repeats.unwrap_or(3)).map(|(out, c)| (out, Some(c)))
    } else {
        solver.render(gpu, &req).map(|out| (out, None))
    };
    bar.finish_and_clear();
    Ok(result?)
}

/// Every requested output, staged and then placed together ([`Staging`]): a failure leaves
/// none of them behind.
#[allow(clippy::too_many_arguments)]
fn write_outputs(
    a: &RenderArgs,
    provenance: &output::Provenance,
    exposure: f32,
    gpu: &Gpu,
    out: &RenderOutput,
    timeline: &TimelineSummary,
    comparison: Option<&ScheduleComparison>,
    wall_s: f64,
) -> Result<()> {
    let info = gpu.info();
    let r = &out.report;
    let mut provenance = provenance.clone();
    provenance.estimators = out.estimates.iter().map(|e| (e.name.to_string(), e.units)).collect();
    let provenance = &provenance;
    let header = provenance.header_pairs();
    // Every pixel of a sampled render holds the range's samples: the count as a layer too, for
    // tools that weight per pixel (exact in f32 up to 2^24 samples).
    let count = provenance.samples.map(|(a, b)| {
        let mut c = output::Image::new(out.image.width, out.image.height);
        c.data.fill((b - a) as f32);
        c
    });
    let estimate_names: Vec<(String, String)> =
        out.estimates.iter().map(|e| super::merge::estimator_layers(e.name, true)).collect();
    let mut staging = Staging::new();
    if let Some(p) = &a.out {
        match ImageFormat::of(p) {
            Some(ImageFormat::Exr) | None => {
                let mut layers: Vec<(&str, &output::Image)> = vec![("", &out.image)];
                if let Some(v) = &out.variance {
                    layers.push(("variance", v));
                }
                if let Some(c) = &count {
                    layers.push(("samples", c));
                }
                // Where camera and light paths both add to the image, each one's mean and
                // variance too: a merge combines each estimator's ranges on its own.
                for (e, (mean, var)) in out.estimates.iter().zip(&estimate_names) {
                    if let Some((m, v)) = &e.layers {
                        layers.push((mean, m));
                        layers.push((var, v));
                    }
                }
                staging.stage(p, |tmp| output::write_exr_with_metadata(tmp, &layers, &header))?;
            }
            Some(ImageFormat::Png) => staging
                .stage(p, |tmp| output::write_png_tonemapped_with_metadata(tmp, &out.image, exposure, &header))?,
            Some(ImageFormat::Pfm) => staging.stage(p, |tmp| output::write_pfm(tmp, &out.image))?,
        }
    }
    if let Some(p) = &a.png {
        staging.stage(p, |tmp| output::write_png_tonemapped_with_metadata(tmp, &out.image, exposure, &header))?;
    }
    if let Some(p) = &a.json {
        let mut doc = json!({
            "scatterlab": env!("CARGO_PKG_VERSION"),
            "provenance": provenance,
            "scene": a.scene.display().to_string(),
            "width": provenance.width,
            "height": provenance.height,
            "device": info,
            "solver": r.solver,
            "settings": r.settings,
            "modelled": r.modelled,
            "device_bytes": r.device_bytes,
            "gpu_ms": r.gpu_ms,
            "wall_s": wall_s,
            "host": r.host,
            "pipelines": r.pipelines,
            "pipeline_cache": gpu.pipeline_cache_status(),
            "passes": r.passes,
            "stats": r.stats,
            "warnings": r.warnings,
            "validation": { "enabled": gpu.validation_enabled(), "errors": gpu.validation_errors() },
            "image_mean": out.image.mean(),
            "timeline": timeline,
        });
        if let Some(c) = comparison {
            doc["sequential_timeline"] = serde_json::to_value(&c.sequential)?;
            doc["schedule_comparison"] = serde_json::to_value(c)?;
        }
        staging.stage(p, |tmp| output::write_json(tmp, &doc))?;
    }
    if let Some(p) = &a.trace {
        let meta = json!({ "scene": a.scene.display().to_string(), "solver": r.solver, "device": info.name, "mapping": info.mapping, "calibrated": info.calibrated_timestamps });
        staging.stage(p, |tmp| timeline::write_chrome_trace(tmp, &r.passes, meta))?;
    }
    staging.commit().map_err(|e| anyhow!("{e}; nothing was written"))
}

/// Warnings always (but those `printed` before the work); unless `--quiet`, what was modelled, times, the solver's own lines, the
/// queues where work ran on more than one role, and what was written.
#[allow(clippy::too_many_arguments)]
fn print_summary(
    a: &RenderArgs,
    exposure: f32,
    solver: &dyn Solver,
    info: &DeviceInfo,
    out: &RenderOutput,
    timeline: &TimelineSummary,
    comparison: Option<&ScheduleComparison>,
    wall_s: f64,
    printed: &[String],
) {
    let r = &out.report;
    for w in r.warnings.iter().filter(|w| !printed.contains(w)) {
        eprintln!("warning: {w}");
    }
    if a.quiet {
        return;
    }
    eprintln!("{}", r.modelled.describe());
    eprintln!("{} passes, GPU {:.1} ms, wall {:.2} s", r.passes.len(), r.gpu_ms, wall_s);
    if let Some(line) = r.host.summary() {
        eprintln!("{line}");
    }
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
        eprintln!("{}", c.describe());
    }
    let tonemapped = format!("tone-mapped with e = {exposure} stops: {}", output::TONEMAP_DESCRIPTION);
    let out_what = match a.out.as_deref().and_then(ImageFormat::of) {
        Some(ImageFormat::Png) => tonemapped.clone(),
        Some(ImageFormat::Pfm) => "linear RGB f32, PFM".to_string(),
        _ => format!(
            "linear RGB f32{}, provenance in the header",
            if out.variance.is_some() { ", + variance layer" } else { "" }
        ),
    };
    let written: [(&Option<PathBuf>, String); 4] = [
        (&a.out, out_what),
        (&a.png, tonemapped),
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
