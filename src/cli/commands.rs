//! What each subcommand does, in terms of the library's layers.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{anyhow, bail, Result};
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::json;

use super::{Cli, Command, CompareArgs, ExportArgs, GpuArgs, RenderArgs, SceneCommand};
use crate::gpu::{list_devices, Gpu, GpuOptions};
use crate::output;
use crate::scene::{is_scene_key, LoadOptions, Scene};
use crate::solvers::{self, RenderRequest, Settings, SolverKind};

/// `println!` that treats a closed stdout (`scatterlab compare ... | head -1`) as the reader
/// being done: exit quietly with success instead of panicking on EPIPE.
macro_rules! outln {
    ($($arg:tt)*) => {{
        use std::io::Write;
        let mut out = std::io::stdout().lock();
        if let Err(e) = writeln!(out, $($arg)*) {
            if e.kind() == std::io::ErrorKind::BrokenPipe {
                std::process::exit(0);
            }
            return Err(anyhow!("cannot write to stdout: {e}"));
        }
    }};
}

pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Render(a) => render(a),
        Command::Compare(a) => compare(a),
        Command::Export(a) => export(a),
        Command::Devices { gpu, json } => devices(&gpu, json),
        Command::Stability { solvers, slow, out, gpu } => stability(&solvers, slow, &out, &gpu),
        Command::Bench { scenes, solvers, out, ref_spp, repeats, quick, throughput, set, cache, gpu } => {
            bench(&BenchArgs { scenes, solvers, out, ref_spp, repeats, quick, throughput, set, cache }, &gpu)
        }
        Command::Scene { command: SceneCommand::Info { scene, set, json } } => scene_info(&scene, &set, json),
    }
}

/// `KEY=VALUE` pairs, each split once at the first `=`.
fn parse_sets(sets: &[String]) -> Result<Vec<(String, String)>> {
    sets.iter()
        .map(|s| match s.split_once('=') {
            Some((k, v)) if !k.trim().is_empty() => Ok((k.trim().to_string(), v.trim().to_string())),
            _ => Err(anyhow!("--set {s:?}: expected KEY=VALUE, e.g. medium.albedo=0.5 or path.max_depth=1")),
        })
        .collect()
}

/// "4G", "512M", "1024" -> bytes.
fn parse_bytes(s: &str) -> Result<u64> {
    let t = s.trim();
    let (num, mult) = match t.chars().last() {
        Some('K' | 'k') => (&t[..t.len() - 1], 1u64 << 10),
        Some('M' | 'm') => (&t[..t.len() - 1], 1 << 20),
        Some('G' | 'g') => (&t[..t.len() - 1], 1 << 30),
        _ => (t, 1),
    };
    let v: f64 = num.parse().map_err(|_| anyhow!("--memory-budget {s:?}: expected a size such as 512M or 4G"))?;
    if !(v.is_finite() && v > 0.0) {
        bail!("--memory-budget {s:?}: must be positive");
    }
    Ok((v * mult as f64) as u64)
}

fn gpu_options(a: &GpuArgs) -> GpuOptions {
    let mut o = GpuOptions::default();
    if a.validate {
        o.validate = true;
    }
    if a.device.is_some() {
        o.device = a.device.clone();
    }
    o
}

/// Fail when the validation layer reported errors: a clean run is the contract of every test.
fn check_validation(gpu: &Gpu) -> Result<()> {
    let n = gpu.validation_errors();
    if n > 0 {
        bail!(
            "the Vulkan validation layer reported {n} error(s), first: {}",
            gpu.validation_messages().first().cloned().unwrap_or_default()
        );
    }
    Ok(())
}

fn check_output_path(p: &Path, what: &str, ext: &[&str]) -> Result<()> {
    let e = p.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase()).unwrap_or_default();
    if !ext.contains(&e.as_str()) {
        bail!("{what} {}: expected a .{} file", p.display(), ext.join(" or ."));
    }
    if let Some(dir) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
        if !dir.is_dir() {
            bail!("{what} {}: directory {} does not exist; create it first", p.display(), dir.display());
        }
    }
    if p.is_dir() {
        bail!("{what} {}: a directory is in the way; choose another file name", p.display());
    }
    Ok(())
}

fn render(a: RenderArgs) -> Result<()> {
    let started = Instant::now();
    let mut sets = parse_sets(&a.set)?;
    if let Some(spp) = a.spp {
        if spp == 0 {
            bail!("--spp 0: samples per pixel must be at least 1");
        }
        sets.push(("render.spp".into(), spp.to_string()));
    }
    if let Some(d) = a.max_depth {
        if a.solver != SolverKind::Path {
            bail!("--max-depth applies to --solver path only");
        }
        sets.push(("path.max_depth".into(), d.to_string()));
    }
    if a.solver != SolverKind::Lbl && (a.schedule.is_some() || a.compare_schedules || a.deterministic) {
        bail!("--schedule, --compare-schedules and --deterministic apply to --solver lbl only");
    }
    if let Some(sch) = a.schedule {
        if a.compare_schedules {
            bail!("--schedule and --compare-schedules exclude each other (the comparison runs both)");
        }
        sets.push(("lbl.schedule".into(), format!("{sch:?}").to_lowercase()));
    }
    if a.deterministic {
        sets.push(("lbl.deterministic".into(), "true".into()));
    }
    if let Some(seed) = a.seed {
        sets.push(("render.seed".into(), seed.to_string()));
    }
    let (scene_sets, solver_sets): (Vec<_>, Vec<_>) = sets.into_iter().partition(|(k, _)| is_scene_key(k));
    for (k, _) in &solver_sets {
        let prefix = k.split('.').next().unwrap_or("");
        if !["path", "single", "lbl", "wavefront"].contains(&prefix) || !k.contains('.') {
            bail!("--set {k}: unknown key; scene keys start with render., camera., medium. or light., solver knobs with path., single., lbl. or wavefront.");
        }
    }
    // Check outputs before any work, so a typo costs nothing.
    if a.out.is_none() && a.png.is_none() && a.json.is_none() && a.trace.is_none() {
        bail!("no output requested; give --out image.exr and/or --png image.png (and --json metrics.json, --trace trace.json)");
    }
    if let Some(p) = &a.out {
        check_output_path(p, "--out", &["exr"])?;
    }
    if let Some(p) = &a.png {
        check_output_path(p, "--png", &["png"])?;
    }
    if let Some(p) = &a.json {
        check_output_path(p, "--json", &["json"])?;
    }
    if let Some(p) = &a.trace {
        check_output_path(p, "--trace", &["json"])?;
    }
    let budget = parse_bytes(&a.memory_budget)?;
    let scene = Scene::load(&a.scene, &scene_sets, &LoadOptions { memory_budget_bytes: budget })?;
    let settings = Settings::new(&solver_sets);

    let gpu = Gpu::new(&gpu_options(&a.gpu))?;
    let info = gpu.info().clone();
    if !a.quiet {
        eprintln!(
            "device: {} ({}{}), queues: {}",
            info.name,
            info.device_type,
            if info.software { ", software" } else { "" },
            info.mapping.describe()
        );
    }
    let bar = if a.quiet { ProgressBar::hidden() } else { ProgressBar::new(1) };
    bar.set_style(
        ProgressStyle::with_template("{spinner} {msg} [{bar:30}] {pos}/{len} ({elapsed}, eta {eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_message(format!("{} {}", a.solver.name(), a.scene.display()));
    let progress = |done: u64, total: u64| {
        bar.set_length(total);
        bar.set_position(done);
    };
    let req = RenderRequest { scene: &scene, settings: &settings, force_full: a.model_all, progress: &progress };
    // --compare-schedules: the sequential baseline first, then the concurrent run kept as output.
    let sequential = if a.compare_schedules {
        let mut seq_sets = solver_sets.clone();
        seq_sets.push(("lbl.schedule".into(), "sequential".into()));
        let seq_settings = Settings::new(&seq_sets);
        let seq_req =
            RenderRequest { scene: &scene, settings: &seq_settings, force_full: a.model_all, progress: &progress };
        let seq = solvers::render(&gpu, a.solver, &seq_req)?;
        Some((crate::measure::timeline::summarize(&seq.report.passes), seq.image))
    } else {
        None
    };
    let out = solvers::render(&gpu, a.solver, &req)?;
    bar.finish_and_clear();
    check_validation(&gpu)?;
    let wall_s = started.elapsed().as_secs_f64();
    let nonfinite = out.image.nan_inf_count();
    if nonfinite > 0 {
        bail!(
            "solver {} produced {nonfinite} NaN/Inf values; nothing written (this is a bug: please report the scene)",
            a.solver.name()
        );
    }

    // Every output is first written under a staging name beside its final one; only when all
    // of them are written are they renamed into place, so a failure (disk full, a directory in
    // the way) never leaves some outputs behind as if the render had succeeded.
    let timeline = crate::measure::timeline::summarize(&out.report.passes);
    let mut staged: Vec<(PathBuf, PathBuf)> = Vec::new();
    let result = (|| -> Result<()> {
        let r = &out.report;
        if let Some(p) = &a.out {
            let tmp = staging_path(p);
            staged.push((tmp.clone(), p.clone()));
            let mut layers: Vec<(&str, &output::Image)> = vec![("", &out.image)];
            if let Some(v) = &out.variance {
                layers.push(("variance", v));
            }
            output::write_exr(&tmp, &layers)?;
        }
        if let Some(p) = &a.png {
            let tmp = staging_path(p);
            staged.push((tmp.clone(), p.clone()));
            output::write_png_tonemapped(&tmp, &out.image, a.exposure)?;
        }
        if let Some(p) = &a.json {
            let tmp = staging_path(p);
            staged.push((tmp.clone(), p.clone()));
            let doc = json!({
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
            });
            let mut doc = doc;
            doc["timeline"] = serde_json::to_value(&timeline)?;
            if let Some((seq, _)) = &sequential {
                doc["sequential_timeline"] = serde_json::to_value(seq)?;
            }
            output::write_json(&tmp, &doc)?;
        }
        if let Some(p) = &a.trace {
            let tmp = staging_path(p);
            staged.push((tmp.clone(), p.clone()));
            let meta = json!({ "scene": a.scene.display().to_string(), "solver": a.solver, "device": info.name, "mapping": info.mapping, "calibrated": info.calibrated_timestamps });
            crate::measure::timeline::write_chrome_trace(&tmp, &out.report.passes, meta)?;
        }
        let mut placed: Vec<&PathBuf> = Vec::new();
        for (tmp, fin) in &staged {
            if let Err(e) = std::fs::rename(tmp, fin) {
                for p in placed {
                    let _ = std::fs::remove_file(p);
                }
                bail!("cannot move the finished output into place as {}: {e}; nothing was written", fin.display());
            }
            placed.push(fin);
        }
        Ok(())
    })();
    if let Err(e) = result {
        for (tmp, _) in &staged {
            let _ = std::fs::remove_file(tmp);
        }
        return Err(e);
    }
    let r = &out.report;
    for w in &r.warnings {
        eprintln!("warning: {w}");
    }
    if !a.quiet {
        eprintln!("{}", r.modelled.describe());
        eprintln!("{} passes, GPU {:.1} ms, wall {:.2} s", r.passes.len(), r.gpu_ms, wall_s);
        if a.solver == SolverKind::Lbl {
            let l = &r.stats["lbl"];
            let dims = &l["lattice"]["dims"];
            eprintln!(
                "lbl: {}x{}x{} {} lattice, {} channel(s){}, {} rays, {} rounds, {} iterations ({})",
                dims[0],
                dims[1],
                dims[2],
                r.settings["lattice"].as_str().unwrap_or("?"),
                l["channels"],
                if l["channels"] == 1 { " (grey medium and lights)" } else { "" },
                l["rays"],
                l["rounds"],
                l["iterations"],
                if l["converged"] == true { "converged" } else { "NOT converged" }
            );
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
            if let Some((seq, seq_img)) = &sequential {
                let ratio = seq.span_ns as f64 / timeline.span_ns.max(1) as f64;
                let diff = output::compare(&out.image, seq_img).map(|m| m.rel_l2).unwrap_or(f64::NAN);
                eprintln!(
                    "schedules: sequential {:.1} ms, concurrent {:.1} ms (GPU span): concurrency gain {ratio:.3}x; images differ by relL2 {diff:.2e}",
                    seq.span_ns as f64 * 1e-6,
                    timeline.span_ns as f64 * 1e-6
                );
            }
        }
        if let Some(p) = &a.out {
            eprintln!(
                "wrote {} (linear RGB f32{})",
                p.display(),
                if out.variance.is_some() { ", + variance layer" } else { "" }
            );
        }
        if let Some(p) = &a.png {
            eprintln!("wrote {} (tone-mapped: {})", p.display(), output::TONEMAP_DESCRIPTION);
        }
        if let Some(p) = &a.json {
            eprintln!("wrote {}", p.display());
        }
        if let Some(p) = &a.trace {
            eprintln!("wrote {} (Chrome trace: one track per queue role)", p.display());
        }
    }
    Ok(())
}

/// `dir/.name.partial.ext`: same directory (so the final rename is atomic), same extension
/// (so writers that look at it still work), hidden.
fn staging_path(p: &Path) -> PathBuf {
    let name = p.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let ext = p.extension().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    p.with_file_name(format!(".{name}.partial.{ext}"))
}

fn compare(a: CompareArgs) -> Result<()> {
    let x = output::read_exr(&a.a)?;
    let r = output::read_exr(&a.b)?;
    if (x.width, x.height) != (r.width, r.height) {
        bail!(
            "{} is {}x{} but the reference {} is {}x{}; render both at the same resolution",
            a.a.display(),
            x.width,
            x.height,
            a.b.display(),
            r.width,
            r.height
        );
    }
    let m = output::compare(&x, &r)?;
    if let Some(p) = &a.error_png {
        check_output_path(p, "--error-png", &["png"])?;
        output::error_png(p, &x, &r)?;
    }
    if a.json {
        outln!("{}", serde_json::to_string_pretty(&m)?);
    } else {
        outln!("relL2         {:.6}", m.rel_l2);
        outln!("relMSE        {:.6e}", m.rel_mse);
        outln!("RMSE          {:.6e}", m.rmse);
        outln!("energy ratio  {:.6}", m.energy_ratio);
        outln!("max abs error {:.6e}", m.max_abs_error);
        outln!("NaN/Inf       {}", m.nan_inf_count);
    }
    Ok(())
}

fn export(a: ExportArgs) -> Result<()> {
    if !a.mitsuba {
        bail!(
            "export: name the format: --mitsuba (the only one for now), e.g. scatterlab export --mitsuba {} {}",
            a.scene.display(),
            a.out.display()
        );
    }
    let sets = parse_sets(&a.set)?;
    if let Some((k, _)) = sets.iter().find(|(k, _)| !is_scene_key(k)) {
        bail!("--set {k}: export writes the scene only; keys start with render., camera., medium. or light. (solver knobs do not apply)");
    }
    check_output_path(&a.out, "--mitsuba", &["xml"])?;
    let vol = crate::scene::mitsuba::vol_path_for(&a.out);
    if vol.is_dir() {
        bail!(
            "--mitsuba {}: the grid's file name {} is taken by a directory; choose another name",
            a.out.display(),
            vol.display()
        );
    }
    let scene = Scene::load(&a.scene, &sets, &LoadOptions::default())?;
    let files = crate::scene::mitsuba::export_mitsuba(&scene, &a.out)?;
    for w in crate::scene::mitsuba::export_warnings(&scene) {
        eprintln!("warning: {w}");
    }
    for f in &files {
        let what = if f == &a.out { "Mitsuba 3 scene" } else { "sigma_t grid, Mitsuba .vol" };
        eprintln!("wrote {} ({what})", f.display());
    }
    eprintln!("render it with: mitsuba -m scalar_rgb {}", a.out.display());
    Ok(())
}

fn devices(gpu: &GpuArgs, as_json: bool) -> Result<()> {
    let list = list_devices()?;
    if list.is_empty() {
        bail!("no Vulkan device found; run tools/setup-deps (installs lavapipe, the CPU driver)");
    }
    if as_json {
        outln!("{}", serde_json::to_string_pretty(&list)?);
        return Ok(());
    }
    let chosen = pick_device(
        &list,
        gpu.device.as_deref().or(std::env::var(crate::gpu::ENV_DEVICE).ok().as_deref()).filter(|s| !s.is_empty()),
    )?;
    for d in &list {
        let mark = if Some(d.index) == chosen { "  <- scatterlab would use this one" } else { "" };
        outln!("[{}] {} ({}, Vulkan {}){mark}", d.index, d.name, d.device_type, d.api_version);
        for f in &d.queue_families {
            let mut caps = Vec::new();
            if f.graphics {
                caps.push("graphics");
            }
            if f.compute {
                caps.push("compute");
            }
            if f.transfer {
                caps.push("transfer");
            }
            outln!(
                "    family {}: {} queue(s), {}, timestamps {} bits",
                f.index,
                f.queue_count,
                caps.join("+"),
                f.timestamp_valid_bits
            );
        }
        match &d.mapping {
            Some(m) => outln!("    roles: {}", m.describe()),
            None => outln!("    roles: none (no compute queue)"),
        }
        if d.missing.is_empty() {
            outln!("    usable: yes");
        } else {
            outln!("    usable: no, lacks {}", d.missing.join(", "));
        }
    }
    Ok(())
}

/// The device `Gpu::new` would open for `wanted` (same rule), or an error if none matches.
fn pick_device(list: &[crate::gpu::DeviceSummary], wanted: Option<&str>) -> Result<Option<usize>> {
    Ok(crate::gpu::choose_device(list, wanted)?)
}

struct BenchArgs {
    scenes: Vec<PathBuf>,
    solvers: Vec<SolverKind>,
    out: PathBuf,
    ref_spp: u32,
    repeats: u32,
    quick: bool,
    throughput: bool,
    set: Vec<String>,
    cache: PathBuf,
}

fn bench(a: &BenchArgs, g: &GpuArgs) -> Result<()> {
    use crate::measure::bench as b;
    let sets = parse_sets(&a.set)?;
    if let Some((k, _)) = sets.iter().find(|(k, _)| !is_scene_key(k)) {
        bail!("--set {k}: bench takes scene keys only (solver knobs are what its ladders vary)");
    }
    if a.ref_spp == 0 {
        bail!("--ref-spp must be at least 1");
    }
    // Load every scene before any GPU work, so a typo in the last one costs nothing.
    let mut scenes = Vec::new();
    for p in &a.scenes {
        let text = std::fs::read_to_string(p).map_err(|e| anyhow!("{}: cannot read scene file: {e}", p.display()))?;
        scenes.push((p.clone(), text, Scene::load(p, &sets, &LoadOptions::default())?));
    }
    std::fs::create_dir_all(&a.out)
        .map_err(|e| anyhow!("--out {}: cannot create the directory: {e}", a.out.display()))?;
    let gpu = Gpu::new(&gpu_options(g))?;
    let info = gpu.info().clone();
    let bar = ProgressBar::new_spinner();
    let mut all_points = Vec::new();
    let mut all_thr = Vec::new();
    let mut refs = Vec::new();
    let mut slim = Vec::new();
    for (path, text, scene) in &scenes {
        let name = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        let key = b::reference_key(text, scene, &sets, &info, a.ref_spp);
        bar.set_message(format!("{name}: path reference at {} spp", a.ref_spp));
        let t = Instant::now();
        let (reference, cached) = b::reference(&gpu, scene, &key, a.ref_spp, &a.cache).map_err(|e| anyhow!(e))?;
        refs.push(json!({ "scene": name, "key": key, "spp": a.ref_spp, "cached": cached, "seconds": t.elapsed().as_secs_f64() }));
        let (points, thr) = b::bench_scene(&gpu, &name, scene, &reference, &a.solvers, a.quick, a.repeats, &|m| {
            bar.set_message(m.to_string())
        })
        .map_err(|e| anyhow!(e))?;
        let svg_path = a.out.join(format!("{name}.svg"));
        output::write_text(&svg_path, b::svg(&format!("{name}: error vs GPU time on {}", info.name), &points))?;
        for k in &a.solvers {
            // The third rung: for `path`, enough samples that the difference is not all noise.
            let (sb, fb, sm, fm, d) =
                b::slim_vs_full(&gpu, scene, *k, &b::ladder(*k, scene, true)[2].sets).map_err(|e| anyhow!(e))?;
            slim.push(json!({ "scene": name, "solver": k, "slim_bytes": sb, "full_bytes": fb, "slim_ms": sm, "full_ms": fm, "rel_l2_between": d }));
        }
        all_points.extend(points);
        all_thr.extend(thr);
    }
    bar.finish_and_clear();
    check_validation(&gpu)?;
    let csv_path = a.out.join("bench.csv");
    output::write_text(&csv_path, b::csv(&all_points))?;
    let doc = json!({
        "scatterlab": env!("CARGO_PKG_VERSION"), "device": info, "references": refs, "quick": a.quick, "repeats": a.repeats,
        "ladders": a.solvers.iter().map(|k| json!({ "solver": k, "rungs": scenes.first().map(|s| b::ladder(*k, &s.2, a.quick)).unwrap_or_default() })).collect::<Vec<_>>(),
        "points": all_points, "throughput": all_thr, "slim_vs_full": slim,
    });
    output::write_json(&a.out.join("bench.json"), &doc)?;
    outln!(
        "{:<20} {:<7} {:<14} {:>10} {:>10} {:>9} {:>7}",
        "scene",
        "solver",
        "knob=value",
        "GPU ms",
        "relL2",
        "energy",
        "pareto"
    );
    for p in &all_points {
        let kv =
            format!("{}={}", p.knob.split('.').nth(1).unwrap_or(&p.knob), p.value.chars().take(7).collect::<String>());
        outln!(
            "{:<20} {:<7} {:<14} {:>10.1} {:>10.4} {:>9.3} {:>7}",
            p.scene,
            p.solver.name(),
            kv,
            p.gpu_ms,
            p.metrics.rel_l2,
            p.metrics.energy_ratio,
            if p.pareto { "*" } else { "" }
        );
    }
    if a.throughput {
        outln!("\nthroughput on {} ({}):", info.name, info.driver_name);
        for t in &all_thr {
            outln!("  {:<20} {:<7} {:<48} {:>12.4e} {}", t.scene, t.solver.name(), t.figure, t.value, t.unit);
        }
        outln!("  (nominal memory bandwidth of this device: not known to scatterlab)");
    }
    for s_ in &slim {
        outln!(
            "model-only-what-is-needed {} {}: slim {} B / full {} B, {:.1} / {:.1} ms, images differ by relL2 {:.2e}",
            s_["scene"],
            s_["solver"],
            s_["slim_bytes"],
            s_["full_bytes"],
            s_["slim_ms"].as_f64().unwrap_or(0.0),
            s_["full_ms"].as_f64().unwrap_or(0.0),
            s_["rel_l2_between"].as_f64().unwrap_or(0.0)
        );
    }
    eprintln!(
        "wrote {}, {} and one SVG per scene in {}",
        csv_path.display(),
        a.out.join("bench.json").display(),
        a.out.display()
    );
    Ok(())
}

fn stability(kinds: &[SolverKind], slow: bool, out: &Path, g: &GpuArgs) -> Result<()> {
    std::fs::create_dir_all(out).map_err(|e| anyhow!("--out {}: cannot create the directory: {e}", out.display()))?;
    let gpu = Gpu::new(&gpu_options(g))?;
    let bar = ProgressBar::new_spinner();
    let outcomes = crate::measure::stability::run(&gpu, kinds, slow, &|m| bar.set_message(m.to_string()))
        .map_err(|e| anyhow!(e))?;
    bar.finish_and_clear();
    check_validation(&gpu)?;
    outln!("{}", crate::measure::stability::table(&outcomes));
    let csv_path = out.join("stability.csv");
    output::write_text(&csv_path, crate::measure::stability::csv(&outcomes))?;
    let doc = json!({ "scatterlab": env!("CARGO_PKG_VERSION"), "device": gpu.info(), "slow_included": slow, "outcomes": outcomes });
    output::write_json(&out.join("stability.json"), &doc)?;
    let failed = outcomes.iter().filter(|o| !o.passed).count();
    eprintln!("wrote {} and {}", csv_path.display(), out.join("stability.json").display());
    if failed > 0 {
        bail!("{failed} of {} stability checks failed (see the table)", outcomes.len());
    }
    eprintln!(
        "all {} stability checks passed{}",
        outcomes.len(),
        if slow { "" } else { " (slow cases skipped: --slow runs them)" }
    );
    Ok(())
}

fn scene_info(path: &Path, sets: &[String], as_json: bool) -> Result<()> {
    let sets = parse_sets(sets)?;
    let scene = Scene::load(path, &sets, &LoadOptions::default())?;
    let f = scene.features();
    let solvers: Vec<(SolverKind, u64)> =
        [SolverKind::Path, SolverKind::Single, SolverKind::Lbl, SolverKind::Wavefront]
            .iter()
            .map(|k| (*k, solvers::memory_estimate(*k, &scene)))
            .collect();
    if as_json {
        let mem: serde_json::Map<String, serde_json::Value> =
            solvers.iter().map(|(k, b)| (k.name().to_string(), json!(b))).collect();
        outln!(
            "{}",
            serde_json::to_string_pretty(&json!({
                "scene": path.display().to_string(),
                "anisotropic": f.anisotropic, "chromatic": f.chromatic, "light_inside": f.light_inside,
                "homogeneous": f.homogeneous, "has_environment": f.has_environment, "grid_dims": f.grid_dims,
                "device_bytes": mem,
            }))?
        );
        return Ok(());
    }
    let yn = |b: bool| if b { "yes" } else { "no" };
    outln!("scene        {}", path.display());
    outln!(
        "image        {} x {}, {} spp, seed {}",
        scene.render.width,
        scene.render.height,
        scene.render.spp,
        scene.render.seed
    );
    outln!("anisotropic  {} (g = {})", yn(f.anisotropic), scene.medium.g);
    outln!("chromatic    {}", yn(f.chromatic));
    outln!("homogeneous  {}", yn(f.homogeneous));
    outln!("light inside {}", yn(f.light_inside));
    outln!("environment  {}", yn(f.has_environment));
    match f.grid_dims {
        Some(d) => outln!("grid         {} x {} x {}", d[0], d[1], d[2]),
        None => outln!("grid         none"),
    }
    outln!("device memory each solver would allocate:");
    for (k, b) in solvers {
        outln!("  {:<8} {:>10.2} MiB", k.name(), b as f64 / (1u64 << 20) as f64);
    }
    Ok(())
}
