//! What each subcommand does, in terms of the library's layers.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Result};
use indicatif::ProgressBar;
use serde_json::json;

use super::args::{check_output_path, check_validation, gpu_options, parse_sets};
use super::{Cli, Command, CompareArgs, ExportArgs, GpuArgs, SceneCommand};
use crate::gpu::{list_devices, Gpu};
use crate::output;
use crate::scene::{is_scene_key, LoadOptions, Scene};
use crate::solvers::{self, Settings, Solver};

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
    super::args::check_environment()?;
    match cli.command {
        Command::Render(a) => super::render::render(a),
        Command::Animate(a) => super::animate::animate(a),
        Command::View(a) => super::view::view(a),
        Command::Merge(a) => super::merge::merge(a),
        Command::Compare(a) => compare(a),
        Command::Export(a) => export(a),
        Command::Devices { gpu, json } => devices(&gpu, json),
        Command::Stability { solvers, slow, out, gpu } => stability(&solvers, slow, &out, &gpu),
        Command::Bench { replot: dirs, out, .. } if !dirs.is_empty() => replot(&dirs, out.as_deref()),
        Command::Bench {
            scenes, solvers, out, ref_spp, repeats, quick, points, throughput, set, cache, gpu, ..
        } => {
            let out = out.unwrap_or_else(|| PathBuf::from("bench"));
            bench(&BenchArgs { scenes, solvers, out, ref_spp, repeats, quick, points, throughput, set, cache }, &gpu)
        }
        Command::Scene { command: SceneCommand::Info { scene, set, json } } => scene_info(&scene, &set, json),
        Command::Knobs { solver, markdown } => knobs(solver.as_deref(), markdown),
        Command::Report { out, quick, scenes, compare, gpu } => report(out, quick, scenes, compare, &gpu),
    }
}

/// The registered solvers named (all of them when none is).
fn chosen_solvers(names: &[String]) -> Result<Vec<&'static dyn Solver>> {
    if names.is_empty() {
        return Ok(solvers::SOLVERS.to_vec());
    }
    Ok(names.iter().map(|n| solvers::find(n)).collect::<Result<Vec<_>, _>>()?)
}

fn is_pfm(p: &Path) -> bool {
    p.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("pfm"))
}

/// An image `render` writes: PFM by its extension, else EXR.
fn read_linear_image(p: &Path) -> Result<output::Image, output::OutputError> {
    if is_pfm(p) {
        output::read_pfm(p)
    } else {
        output::read_exr(p)
    }
}

fn compare(a: CompareArgs) -> Result<()> {
    let x = read_linear_image(&a.a)?;
    let r = read_linear_image(&a.b)?;
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
    // Against a black reference relL2 and the energy ratio divide by zero: say so, not "inf".
    if r.data.iter().all(|v| *v == 0.0) {
        if x.data.iter().all(|v| *v == 0.0) {
            outln!("both images are black (every pixel 0): identical");
            return Ok(());
        }
        bail!(
            "the reference {} is black (every pixel 0): relL2 and the energy ratio are undefined against it; \
             compare against a lit render",
            a.b.display()
        );
    }
    let m = output::compare(&x, &r)?;
    // The variance layers `path` writes (the variance of each pixel's mean): absent is not
    // an error (a deterministic solver has none), a broken one is.
    let variance = |p: &Path| match is_pfm(p) {
        true => Ok(None), // (a PFM has no layers)
        false => match output::read_exr_layer(p, "variance") {
            Ok(v) => Ok(Some(v)),
            Err(output::OutputError::MissingLayer { .. }) => Ok(None),
            Err(e) => Err(e),
        },
    };
    let (var_a, var_r) = (variance(&a.a)?, variance(&a.b)?);
    let noise = output::metrics::noise_floor(&x, &r, var_a.as_ref(), var_r.as_ref())?;
    if let Some(p) = &a.error_png {
        check_output_path(p, "--error-png", &["png"])?;
        output::error_png(p, &x, &r)?;
    }
    if a.json {
        let mut doc = serde_json::to_value(m)?;
        doc["noise"] = serde_json::to_value(noise)?;
        outln!("{}", serde_json::to_string_pretty(&doc)?);
    } else {
        outln!("relL2         {:.6}   ||a - ref|| / ||ref||, noise included", m.rel_l2);
        match (noise.reference, noise.rel_l2_corrected, noise.resolution) {
            (Some(floor), Some(corrected), Some(resolution)) => {
                outln!("ref noise     {floor:.6}   the relL2 the reference's own noise adds (its variance layer)");
                match noise.image {
                    Some(n) => outln!("image noise   {n:.6}   the same for the judged image"),
                    None => outln!("image noise   none       no variance layer: taken as noise-free (deterministic)"),
                }
                let verdict = if corrected <= resolution {
                    format!("consistent with zero: below the {resolution:.6} the noise can resolve")
                } else {
                    format!("the bias; the noise resolves errors above {resolution:.6}")
                };
                outln!("bias relL2    {corrected:.6}   relL2 with both images' noise removed: {verdict}");
            }
            _ => outln!("ref noise     unknown    the reference carries no variance layer: noise floor unknown"),
        }
        outln!("relMSE        {:.6e}", m.rel_mse);
        outln!("RMSE          {:.6e}", m.rmse);
        outln!("energy ratio  {:.6}", m.energy_ratio);
        outln!("max abs error {:.6e}", m.max_abs_error);
        outln!("NaN/Inf       {}", m.nan_inf_count);
    }
    if let Some(p) = &a.error_png {
        eprintln!("wrote {} ({})", p.display(), output::metrics::ERROR_MAP_DESCRIPTION);
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
        bail!(
            "--set {k}: export writes the scene only; keys start with render., camera., medium. or light. (solver \
            knobs do not apply)"
        );
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
    if let Some(why) = crate::scene::mitsuba::export_refusal(&scene) {
        bail!("{}: {why}", a.scene.display());
    }
    let files = crate::scene::mitsuba::export_mitsuba(&scene, &a.out)?;
    for w in crate::scene::mitsuba::export_warnings(&scene) {
        eprintln!("warning: {w}");
    }
    for f in &files {
        let what = if f == &a.out {
            "Mitsuba 3 scene"
        } else if f.extension().is_some_and(|e| e == "obj") {
            "the objects' mesh in scene coordinates, Wavefront OBJ"
        } else {
            "sigma_t grid, Mitsuba .vol"
        };
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
    let opts = gpu_options(gpu);
    let chosen = pick_device(&list, opts.device.as_deref(), opts.device_from)?;
    for d in &list {
        let mark = if Some(d.index) == chosen { "  <- scatterlab would use this one" } else { "" };
        outln!("[{}] {} ({}, Vulkan {}){mark}", d.index, d.name, d.device_type, d.api_version);
        outln!("    uuid: {} (--device uuid:{})", d.uuid, d.uuid);
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
        // The mapping `--queues` (or SCATTERLAB_QUEUES) asks for, where it is not `auto`.
        if let Some(q) = gpu_options(gpu).queues.filter(|q| q != "auto") {
            match crate::gpu::map_roles_named(&d.queue_families, &q) {
                Ok(m) => outln!("    roles with --queues {q}: {}", m.describe()),
                Err(e) => outln!("    roles with --queues {q}: not available ({e})"),
            }
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
fn pick_device(list: &[crate::gpu::DeviceSummary], wanted: Option<&str>, from: &'static str) -> Result<Option<usize>> {
    Ok(crate::gpu::choose_device(list, wanted).map_err(|e| e.named_by(from))?)
}

struct BenchArgs {
    scenes: Vec<PathBuf>,
    solvers: Vec<String>,
    out: PathBuf,
    ref_spp: u32,
    repeats: u32,
    quick: bool,
    points: Option<String>,
    throughput: bool,
    set: Vec<String>,
    cache: PathBuf,
}

/// `bench --replot DIR...`: one DIR's plots drawn again from its bench.json (beside it, or in
/// `out`); several DIRs' runs combined ([`crate::measure::bench::combine`]) into one bench.json,
/// bench.csv and plots in `out`. Every input is read and checked before anything is written.
fn replot(dirs: &[PathBuf], out: Option<&Path>) -> Result<()> {
    use crate::measure::bench as b;
    let mut docs = Vec::new();
    for dir in dirs {
        let json = dir.join("bench.json");
        let text = std::fs::read_to_string(&json)
            .map_err(|e| anyhow!("--replot {}: cannot read {}: {e}", dir.display(), json.display()))?;
        let doc: serde_json::Value = serde_json::from_str(&text)
            .map_err(|e| anyhow!("{}: not a bench.json ({e}); give the folder a bench run wrote", json.display()))?;
        docs.push((json.display().to_string(), doc));
    }
    let (doc, out) = match (docs.len(), out) {
        (1, out) => (docs.pop().map(|(_, d)| d).unwrap_or_default(), out.unwrap_or(&dirs[0]).to_path_buf()),
        (_, Some(out)) => {
            let out = out.to_path_buf();
            // The combination would replace an input's own results.
            if let Some(d) = dirs.iter().find(|d| same_dir(d, &out)) {
                bail!(
                    "--out {}: it is one of the runs combined ({}); write the combination elsewhere",
                    out.display(),
                    d.display()
                );
            }
            (b::combine(&docs).map_err(|e| anyhow!("--replot: {e}"))?, out)
        }
        (n, None) => bail!("--replot with {n} folders combines their runs: name the folder for the result with --out"),
    };
    let plots = b::replot(&doc).map_err(|e| anyhow!("{}: {e}", docs.first().map_or("--replot", |d| d.0.as_str())))?;
    std::fs::create_dir_all(&out).map_err(|e| anyhow!("--out {}: cannot create the directory: {e}", out.display()))?;
    if dirs.len() > 1 {
        let points = b::points_of(&doc).map_err(|e| anyhow!("--replot: {e}"))?;
        output::write_text(&out.join("bench.csv"), b::csv(&points).map_err(|e| anyhow!(e))?)?;
        output::write_json(&out.join("bench.json"), &doc)?;
        eprintln!(
            "combined {} runs ({} points) into {} and {}",
            dirs.len(),
            points.len(),
            out.join("bench.json").display(),
            out.join("bench.csv").display()
        );
    }
    for (name, svg) in &plots {
        let p = out.join(format!("{name}.svg"));
        output::write_text(&p, svg)?;
        eprintln!("wrote {}", p.display());
    }
    Ok(())
}

/// Whether two paths name one directory (both resolved where they exist).
fn same_dir(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(x), Ok(y)) => x == y,
        _ => a == b,
    }
}

fn bench(a: &BenchArgs, g: &GpuArgs) -> Result<()> {
    use crate::measure::bench as b;
    let solvers = chosen_solvers(&a.solvers)?;
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
        let name = p.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        scenes.push(b::BenchScene { name, text, scene: Scene::load(p, &sets, &LoadOptions::default())? });
    }
    let points = match (&a.points, a.quick) {
        (Some(p), _) => b::Points::parse(p).map_err(|e| anyhow!(e))?,
        (None, true) => b::Points::Cheapest(3),
        (None, false) => b::Points::All,
    };
    // A rung past a ladder's end is a typo: refuse it before any GPU work.
    if let Some(top) = points.highest() {
        for s in &scenes {
            for solver in solvers.iter().filter(|solver| solver.inapplicable(&s.scene).is_none()) {
                let n = solver.ladder(&s.scene).len();
                if top > n {
                    bail!(
                        "--points {}: solver {}'s ladder on {} has {n} rungs (1-{n}); pick rungs it has or narrow \
                         --solvers",
                        a.points.as_deref().unwrap_or_default(),
                        solver.name(),
                        s.name
                    );
                }
            }
        }
    }
    std::fs::create_dir_all(&a.out)
        .map_err(|e| anyhow!("--out {}: cannot create the directory: {e}", a.out.display()))?;
    let gpu = Gpu::new(&gpu_options(g))?;
    let info = gpu.info().clone();
    let cfg = b::BenchConfig {
        solvers: &solvers,
        ref_spp: a.ref_spp,
        repeats: a.repeats,
        points: points.clone(),
        overrides: &sets,
        cache: &a.cache,
    };
    let bar = counted_bar(b::steps(&scenes, &cfg));
    let result = b::run(&gpu, &scenes, &cfg, &|m| step(&bar, m)).map_err(|e| anyhow!(e))?;
    bar.finish_and_clear();
    check_validation(&gpu)?;
    for (name, svg) in &result.plots {
        output::write_text(&a.out.join(format!("{name}.svg")), svg)?;
    }
    let csv_path = a.out.join("bench.csv");
    output::write_text(&csv_path, b::csv(&result.points).map_err(|e| anyhow!(e))?)?;
    let ladders: Vec<_> = solvers
        .iter()
        .map(|s| json!({ "solver": s.name(), "rungs": scenes.first().map(|x| b::ladder(*s, &x.scene, &points)).unwrap_or_default() }))
        .collect();
    // `rungs`: the rungs asked for (--quick, --points); `points`: what was measured.
    let doc = json!({
        "scatterlab": env!("CARGO_PKG_VERSION"), "build": crate::BUILD, "device": info, "references": result.references,
        "quick": a.quick, "rungs": points, "repeats": a.repeats, "ladders": ladders, "points": result.points, "throughput": result.throughput,
        "slim_vs_full": result.slim_vs_full, "skipped": result.skipped,
    });
    output::write_json(&a.out.join("bench.json"), &doc)?;
    outln!(
        "{:<20} {:<9} {:<14} {:>10} {:>10} {:>10} {:>9} {:>8} {:>7}",
        "scene",
        "solver",
        "knob=value",
        "GPU ms",
        "relL2",
        "denoised",
        "energy",
        "speedup",
        "pareto"
    );
    for p in &result.points {
        let kv =
            format!("{}={}", p.knob.split('.').nth(1).unwrap_or(&p.knob), p.value.chars().take(7).collect::<String>());
        outln!(
            "{:<20} {:<9} {:<14} {:>10.1} {:>10.4} {:>10.4} {:>9.3} {:>8} {:>7}",
            p.scene,
            p.solver,
            kv,
            p.gpu_ms,
            p.metrics.rel_l2,
            p.rel_l2_denoised,
            p.metrics.energy_ratio,
            p.speedup.map(|x| format!("{x:.2}x")).unwrap_or_else(|| "-".into()),
            if p.pareto { "*" } else { "" }
        );
    }
    for k in &result.skipped {
        outln!("{} {}: skipped, {}", k.scene, k.solver, k.why);
    }
    for r in &result.references {
        outln!(
            "reference {}: {} spp, its own noise relL2 {:.4} (removed in `denoised`; speed-up = the reference solver's GPU time to that error / the point's)",
            r.scene,
            r.spp,
            r.noise
        );
    }
    if a.throughput {
        outln!("\nthroughput on {} ({}):", info.name, info.driver_name);
        for t in &result.throughput {
            outln!("  {:<20} {:<9} {:<48} {:>12.4e} {}", t.scene, t.solver, t.figure, t.value, t.unit);
        }
        outln!("  (nominal memory bandwidth of this device: not known to scatterlab)");
    }
    for s in &result.slim_vs_full {
        outln!(
            "model-only-what-is-needed {} {}: slim {} B / full {} B, {:.1} / {:.1} ms; relL2 of the slim image against \
             the full-model one (--model-all) {:.2e} (for path both are Monte Carlo: this includes their noise)",
            s.scene,
            s.solver,
            s.slim_bytes,
            s.full_bytes,
            s.slim_ms,
            s.full_ms,
            s.rel_l2_between
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

/// A bar over `total` steps of unequal cost (a reference render next to a 16-voxel lattice):
/// the count and the elapsed time, and no ETA, which a count of such steps cannot give.
fn counted_bar(total: usize) -> ProgressBar {
    let bar = ProgressBar::new(total as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{spinner} [{pos}/{len}] {msg} ({elapsed})")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner()),
    );
    bar.enable_steady_tick(std::time::Duration::from_millis(150));
    bar
}

/// A step starts: the steps before it are done.
fn step(bar: &ProgressBar, what: &str) {
    if bar.message().is_empty() {
        bar.set_position(0);
    } else {
        bar.inc(1);
    }
    bar.set_message(what.to_string());
}

fn stability(names: &[String], slow: bool, out: &Path, g: &GpuArgs) -> Result<()> {
    let solvers = chosen_solvers(names)?;
    std::fs::create_dir_all(out).map_err(|e| anyhow!("--out {}: cannot create the directory: {e}", out.display()))?;
    let gpu = Gpu::new(&gpu_options(g))?;
    let bar = counted_bar(crate::measure::stability::steps(&solvers, slow).map_err(|e| anyhow!(e))?);
    let outcomes = crate::measure::stability::run(&gpu, &solvers, slow, &|m| step(&bar, m)).map_err(|e| anyhow!(e))?;
    bar.finish_and_clear();
    check_validation(&gpu)?;
    outln!("{}", crate::measure::stability::table(&outcomes));
    let csv_path = out.join("stability.csv");
    output::write_text(&csv_path, crate::measure::stability::csv(&outcomes).map_err(|e| anyhow!(e))?)?;
    let doc = json!({ "scatterlab": env!("CARGO_PKG_VERSION"), "device": gpu.info(), "slow_included": slow, "outcomes": outcomes });
    output::write_json(&out.join("stability.json"), &doc)?;
    let failed = outcomes.iter().filter(|o| o.counts_as_failure()).count();
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
    let (scene_sets, knob_sets): (Vec<_>, Vec<_>) = sets.into_iter().partition(|(k, _)| is_scene_key(k));
    let settings = Settings::new(&knob_sets);
    solvers::check_settings(&settings, solvers::SOLVERS)?;
    let scene = Scene::load(path, &scene_sets, &LoadOptions::default())?;
    let f = scene.features();
    // Solvers that cannot render the scene at all (an [[object]] for those without meshes) are
    // listed with the reason instead of a memory figure for a render that would be refused.
    let refused: Vec<(&str, String)> =
        solvers::SOLVERS.iter().filter_map(|s| s.scene_refusal(&scene).map(|why| (s.name(), why))).collect();
    let memory: Vec<_> = solvers::memory_table(&scene, solvers::SOLVERS, &settings)?
        .into_iter()
        .filter(|(name, _)| !refused.iter().any(|(r, _)| r == name))
        .collect();
    if as_json {
        let mem: serde_json::Map<String, serde_json::Value> =
            memory.iter().map(|(k, b)| (k.to_string(), json!(b))).collect();
        outln!(
            "{}",
            serde_json::to_string_pretty(&json!({
                "scene": path.display().to_string(),
                "anisotropic": f.anisotropic, "chromatic": f.chromatic, "light_inside": f.light_inside,
                "homogeneous": f.grid_dims.is_none(), "density": density_label(&scene.medium.density), "has_environment": f.has_environment, "grid_dims": f.grid_dims,
                "emissive": f.emissive, "emission": emission_label(&scene),
                "object": scene.object.as_ref().map(|o| json!({
                    "mesh": o.describe(), "parts": o.parts.iter().map(|p| json!({"mesh": p.file.display().to_string(), "triangles": p.triangles, "material": p.material})).collect::<Vec<_>>(),
                    "materials": o.materials.iter().map(|x| json!({"sigma_t": x.sigma_t.to_array(), "albedo": x.albedo.to_array(), "g": x.g, "ior": x.ior, "density": density_label(&o.fields[x.field].density)})).collect::<Vec<_>>(), "triangles": o.mesh.triangles.len(), "ior": o.ior,
                    "bvh_nodes": o.bvh.nodes.len(), "bvh_depth": o.bvh.depth, "bvh_bytes": o.bvh.bytes(), "convex": o.convex,
                })),
                "refused_by": refused.iter().map(|(k, why)| (k.to_string(), json!(why))).collect::<serde_json::Map<_, _>>(),
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
    if scene.object.as_ref().is_some_and(|o| o.several_materials()) {
        outln!("anisotropic  {} (g per material, below)", yn(f.anisotropic));
    } else {
        outln!("anisotropic  {} (g = {})", yn(f.anisotropic), scene.medium.g);
    }
    outln!("chromatic    {}", yn(f.chromatic));
    match scene.object.as_ref().filter(|o| o.fields.len() > 1) {
        Some(o) => outln!("density      {} fields, one per material below", o.fields.len()),
        None => outln!("density      {}", density_label(&scene.medium.density)),
    }
    if let Some(o) = &scene.object {
        outln!(
            "object       {} ({} triangles{}), ior {}{}: the medium fills the mesh; BVH {} nodes, depth {}, {:.1} KiB",
            o.describe(),
            o.mesh.triangles.len(),
            if o.convex { ", convex" } else { "" },
            if o.several_materials() { "per material".to_string() } else { o.ior.to_string() },
            if o.refractive() { " (a smooth dielectric boundary)" } else { " (index-matched)" },
            o.bvh.nodes.len(),
            o.bvh.depth,
            o.bvh.bytes() as f64 / 1024.0
        );
        if o.several_materials() {
            for (k, x) in o.materials.iter().enumerate() {
                let parts: Vec<String> = o
                    .parts
                    .iter()
                    .enumerate()
                    .filter(|(_, p)| p.material == k)
                    .map(|(i, _)| format!("object[{i}]"))
                    .collect();
                let field = if o.fields.len() > 1 {
                    format!("; density {}", density_label(&o.fields[x.field].density))
                } else {
                    String::new()
                };
                outln!(
                    "material {k}   {}: sigma_t {}, albedo {}, g {}, ior {}{field}",
                    parts.join(", "),
                    fmt_rgb(x.sigma_t),
                    fmt_rgb(x.albedo),
                    x.g,
                    x.ior
                );
            }
        }
    }
    outln!("light inside {}", yn(f.light_inside));
    outln!("environment  {}", yn(f.has_environment));
    outln!("emission     {}", emission_label(&scene));
    outln!(
        "device memory each solver would allocate{}:",
        if knob_sets_empty(&settings) { " (default knobs)" } else { " (default knobs but those set)" }
    );
    for (name, b) in memory {
        outln!("  {:<10} {:>10.2} MiB", name, b as f64 / (1u64 << 20) as f64);
    }
    for (name, why) in &refused {
        outln!("  {:<10} refused: {}", name, why);
    }
    Ok(())
}

/// What the scene emits, as `scene info` says it: the source sigma_a Le and where Le comes from.
fn emission_label(scene: &Scene) -> String {
    use crate::scene::Emission;
    if !scene.emissive() {
        return if scene.medium.emission.is_some() {
            "given, but no channel both absorbs and emits (the source is sigma_a Le): nothing is emitted".into()
        } else {
            "no".into()
        };
    }
    let source = "modelled: the source sigma_a Le (the medium emits where it absorbs)";
    match &scene.medium.emission {
        Emission::Grid(g) => {
            let [x, y, z] = g.dims();
            let peak = g.max_le();
            match &g.temperature {
                Some(t) => format!(
                    "yes, blackbody from the temperature grid {} ({x} x {y} x {z}; T = (value - {}) x {} K, none at or below {} K), Le up to {} W/(m^2 sr) with emission_scale {}; {source}",
                    g.planes[0].file.display(),
                    t.offset,
                    t.scale,
                    t.cutoff,
                    fmt_rgb(peak),
                    fmt_rgb(g.scale)
                ),
                None => format!(
                    "yes, Le from the grid {} ({x} x {y} x {z}) times {}, up to {} W/(m^2 sr); {source}",
                    g.planes[0].file.display(),
                    fmt_rgb(g.scale),
                    fmt_rgb(peak)
                ),
            }
        }
        Emission::Constant(le) => format!("yes, Le {} W/(m^2 sr); {source}", fmt_rgb(*le)),
        Emission::None => format!("yes, in the objects' materials; {source}"),
    }
}

/// The medium's density as `scene info` names it: "homogeneous" for a constant medium whether
/// it fills the box or a sphere in it, so the sphere scene is not called inhomogeneous.
fn density_label(d: &crate::scene::Density) -> String {
    use crate::scene::Density;
    match d {
        Density::Constant => "homogeneous: constant, filling the medium's box (or the object's mesh)".into(),
        Density::Sphere { center, radius } => format!(
            "homogeneous: constant inside a sphere (centre [{}, {}, {}], radius {radius}), 0 outside",
            center.x, center.y, center.z
        ),
        Density::Grid(g) => format!("heterogeneous: a {} x {} x {} voxel grid", g.dims[0], g.dims[1], g.dims[2]),
    }
}

fn knob_sets_empty(s: &Settings) -> bool {
    s.pairs().next().is_none()
}

fn knobs(solver: Option<&str>, markdown: bool) -> Result<()> {
    let chosen: Vec<&dyn Solver> = match solver {
        Some(n) => vec![solvers::find(n)?],
        None => solvers::SOLVERS.to_vec(),
    };
    if markdown {
        outln!("{}", solvers::knobs::reference_markdown(&chosen).trim_end());
    } else {
        for s in chosen {
            outln!("{}", solvers::knobs::reference_text(s));
        }
    }
    Ok(())
}

/// `scatterlab report`: run it (report.json and report.md land together at the end, nothing on
/// a failure), or compare two.
fn report(
    out: Option<PathBuf>,
    quick: bool,
    scenes: PathBuf,
    compare: Option<Vec<PathBuf>>,
    gpu: &GpuArgs,
) -> Result<()> {
    use crate::measure::report;
    let load = |p: &Path| -> Result<report::Report> {
        let text = std::fs::read_to_string(p).map_err(|e| anyhow!("cannot read {}: {e}", p.display()))?;
        serde_json::from_str(&text).map_err(|e| anyhow!("{} is not a scatterlab report.json: {e}", p.display()))
    };
    if let Some(files) = compare {
        let (a, b) = (load(&files[0])?, load(&files[1])?);
        let name = |r: &report::Report| r.device.get("name").and_then(|v| v.as_str()).unwrap_or("?").to_string();
        outln!("A: {} ({})\nB: {} ({})", name(&a), a.engine, name(&b), b.engine);
        outln!("{:<70} {:>14} {:>14} {:>9}", "figure", "A", "B", "B / A");
        let cell = |x: Option<f64>| x.map_or("-".to_string(), |v| format!("{v:.4e}"));
        for c in report::compare(&a, &b) {
            let ratio = c.ratio.map_or("-".into(), |r| format!("{r:.3}"));
            outln!("{:<70} {:>14} {:>14} {:>9}", c.figure, cell(c.a), cell(c.b), ratio);
        }
        return Ok(());
    }
    let out = out.expect("clap requires --out without --compare");
    if !scenes.join("cloud.toml").exists() {
        bail!(
            "--scenes {}: no cloud.toml there; run from the repository root or pass --scenes PATH/TO/scenes",
            scenes.display()
        );
    }
    let g = Gpu::new(&gpu_options(gpu))?;
    std::fs::create_dir_all(&out).map_err(|e| anyhow!("cannot create {}: {e}", out.display()))?;
    eprintln!("device: {}, queues: {}", g.info().name, g.info().mapping.describe());
    let opts = report::ReportOptions { quick, scenes, out: out.clone(), gpu: gpu_options(gpu) };
    let r = report::run(&g, serde_json::to_value(g.info())?, &opts).map_err(|e| anyhow!("report: {e}"))?;
    check_validation(&g)?;
    let md = report::markdown(&r);
    // Both land together: staged, then moved into place.
    let mut staging = output::Staging::new();
    let write = |p: &Path, text: &[u8]| {
        std::fs::write(p, text).map_err(|source| output::OutputError::Io {
            path: p.to_owned(),
            action: "write",
            source,
        })
    };
    let json_text = serde_json::to_vec_pretty(&r)?;
    staging.stage(&out.join("report.json"), |p| write(p, &json_text))?;
    staging.stage(&out.join("report.md"), |p| write(p, md.as_bytes()))?;
    staging.commit()?;
    outln!("{md}");
    eprintln!("wrote {} and {}", out.join("report.json").display(), out.join("report.md").display());
    Ok(())
}

/// An RGB triple as a scene file writes it: one number when grey.
fn fmt_rgb(v: glam::Vec3) -> String {
    if crate::scene::is_grey(v) {
        format!("{}", v.x)
    } else {
        format!("[{}, {}, {}]", v.x, v.y, v.z)
    }
}
