//! `scatterlab animate`: flags to an orbit, the sequence ([`crate::measure::animate`]), each
//! frame written as it finishes (EXR, and PNG on request) and `frames.csv` rewritten after
//! every frame, so an interrupted run keeps what it finished. Nothing here knows a solver.

use anyhow::{anyhow, bail, Result};
use indicatif::{ProgressBar, ProgressStyle};

use super::args::{check_validation, gpu_options, parse_sets};
use super::AnimateArgs;
use crate::gpu::Gpu;
use crate::measure::animate::{self, Orbit};
use crate::output;
use crate::scene::{is_scene_key, LoadOptions, Scene};
use crate::solvers::{self, Progress, Settings};

pub fn animate(a: AnimateArgs) -> Result<()> {
    let solver = solvers::find(&a.solver)?;
    if !a.orbit_light.is_finite() {
        bail!("--orbit-light {}: degrees per frame must be a finite number", a.orbit_light);
    }
    // Frames A..B of the sequence (default all of --frames): frame f is the light turned by f
    // times --orbit-light, whichever range computes it.
    let (first, frames) = match &a.frame_range {
        Some(r) => {
            let (x, y) = output::parse_range(r).map_err(|e| anyhow!("--frame-range {e}"))?;
            (x, y - x)
        }
        None => (0, a.frames),
    };
    let sets = parse_sets(&a.set)?;
    // What the --set values make, for the sequence's identity: the last value of each key (the
    // one applied), in key order, so ranges given the same values in another order agree.
    let effective: Vec<String> = sets
        .iter()
        .map(|(k, v)| (k.clone(), v.clone()))
        .collect::<std::collections::BTreeMap<String, String>>()
        .into_iter()
        .map(|(k, v)| format!("{k}={v}"))
        .collect();
    let (scene_sets, knob_sets): (Vec<_>, Vec<_>) = sets.into_iter().partition(|(k, _)| is_scene_key(k));
    let settings = Settings::new(&knob_sets);
    solvers::check_settings(&settings, &[solver])?;
    let scene = Scene::load(&a.scene, &scene_sets, &LoadOptions::default())?;
    let sequence = animate::sequence_id(
        solver.name(),
        &super::args::scene_digest(&a.scene, &scene)?,
        &effective,
        a.orbit_light,
        !a.no_reference,
    );
    if let Some(why) = solver.scene_refusal(&scene) {
        bail!("{}: {why}", a.scene.display());
    }
    animate::orbit(&scene, 0.0).map_err(|e| anyhow!("{}: {e}", a.scene.display()))?;
    // Before any device work: the solver must keep a solution to start the next frame from,
    // and its knobs must make a sequence (a solver checks what its warm start needs).
    let req = solvers::RenderRequest { scene: &scene, settings: &settings, force_full: false, progress: &|_| {} };
    let Some(seq) = solver.animation(&req, false)? else {
        let able: Vec<&str> = solvers::SOLVERS
            .iter()
            .filter(|s| s.animation(&req, false).is_ok_and(|x| x.is_some()))
            .map(|s| s.name())
            .collect();
        bail!(
            "--solver {}: it keeps no solution to start the next frame from; animate takes {}",
            solver.name(),
            able.join(" or ")
        );
    };
    let reference = if a.no_reference { None } else { solver.animation(&req, true)? };
    if a.out_dir.is_file() {
        bail!("--out-dir {}: a file is in the way; choose a directory", a.out_dir.display());
    }
    std::fs::create_dir_all(&a.out_dir)
        .map_err(|e| anyhow!("--out-dir {}: cannot create the directory: {e}", a.out_dir.display()))?;
    let gpu = Gpu::new(&gpu_options(&a.gpu))?;
    if !a.quiet {
        let info = gpu.info();
        eprintln!("device: {} ({}), queues: {}", info.name, info.device_type, info.mapping.describe());
    }
    let bar = if a.quiet { ProgressBar::hidden() } else { ProgressBar::new(frames as u64) };
    bar.set_style(
        ProgressStyle::with_template("{spinner} {msg} [{bar:30}] {pos}/{len} frames ({elapsed}, eta {eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_message(format!("{} {}", solver.name(), a.scene.display()));
    bar.enable_steady_tick(std::time::Duration::from_millis(150));
    // A cold first frame can take minutes: plain lines where there is no terminal, as render's.
    let plain = super::args::PlainProgress::new(a.quiet, a.progress_every);
    let progress = |p: Progress| {
        if let Progress::Converging { iteration, change, tol, .. } = p {
            let text = format!(
                "{} {}: iteration {iteration}, change {change:.1e} (tolerance {tol:.0e})",
                solver.name(),
                a.scene.display()
            );
            plain.line(&|| text.clone());
            bar.set_message(text);
        }
    };
    let exposure = scene.render.exposure;
    // A range's own frames-A-B.csv, so that the tasks of an array can share one directory
    // (their frame-NNNN files are numbered in the whole sequence and do not collide).
    let csv_path = match &a.frame_range {
        Some(_) => a.out_dir.join(format!("frames-{first}-{}.csv", first + frames)),
        None => a.out_dir.join("frames.csv"),
    };
    // The files are written on a thread of their own while the next frame computes (a frame
    // of lbl at 1024^2 takes milliseconds of GPU; its EXR as long to write): two frames may
    // wait in the queue, then the sequence waits for the disk. frames.csv is rewritten after
    // every frame, with each frame's writing time, so an interrupted run keeps what it wrote.
    let (tx, rx) = std::sync::mpsc::sync_channel::<(output::Image, animate::FrameRow)>(2);
    let (out_dir, png) = (a.out_dir.clone(), a.png);
    let writer_csv = csv_path.clone();
    let writer = std::thread::spawn(move || -> Result<Vec<f64>, String> {
        let mut written = Vec::new();
        for (image, mut row) in rx {
            let t = std::time::Instant::now();
            let stem = out_dir.join(format!("frame-{:04}", row.frame));
            output::write_exr(&stem.with_extension("exr"), &[("", &image)]).map_err(|e| e.to_string())?;
            if png {
                output::write_png_tonemapped(&stem.with_extension("png"), &image, exposure)
                    .map_err(|e| e.to_string())?;
            }
            row.write_ms = Some(t.elapsed().as_secs_f64() * 1e3);
            written.push(row);
            output::write_text(&writer_csv, animate::csv(&written)?).map_err(|e| e.to_string())?;
        }
        Ok(written.iter().filter_map(|r| r.write_ms).collect())
    });
    // Each frame's warnings (a discretisation past what the solver was validated at, a frame that
    // keeps no state), each said once: a sequence says the same of every frame.
    let mut said = std::collections::HashSet::new();
    let mut on_frame = |image: &output::Image, out: &solvers::RenderOutput, row: &animate::FrameRow| {
        // A closed channel: the writer stopped on an error, reported after the join.
        let labelled =
            animate::FrameRow { solver: solver.name().to_string(), sequence: sequence.clone(), ..row.clone() };
        tx.send((image.clone(), labelled)).map_err(|_| "the frame writer stopped".to_string())?;
        bar.inc(1);
        for w in &out.report.warnings {
            if said.insert(w.clone()) {
                bar.suspend(|| eprintln!("warning: {w}"));
            }
        }
        if !a.quiet {
            bar.suspend(|| {
                eprintln!(
                    "frame {:4} at {:7.2} deg: {:8.1} ms, {:4} iterations{}",
                    row.frame,
                    row.angle_deg,
                    row.time_ms,
                    row.iterations,
                    row.rel_l2
                        .map(|r| format!(", relL2 {r:.2e} to the converged frame ({} iterations)", {
                            row.reference_iterations.unwrap_or(0)
                        }))
                        .unwrap_or_default()
                )
            });
        }
        Ok(())
    };
    let orbit = Orbit { first, frames, step_deg: a.orbit_light, reference: !a.no_reference };
    let result = animate::run_sequences(&gpu, seq, reference, &scene, &orbit, &progress, &mut on_frame);
    drop(tx);
    let written = writer.join().map_err(|_| anyhow!("the frame writer panicked"))?;
    bar.finish_and_clear();
    // The writer's error first: it is why the sequence stopped when it did.
    let write_ms = written.map_err(|e| anyhow!("--out-dir {}: {e}", a.out_dir.display()))?;
    let rows = result.map_err(|e| anyhow!(e))?;
    check_validation(&gpu)?;
    let later: Vec<&animate::FrameRow> = rows.iter().skip(1).collect();
    if !later.is_empty() {
        let mean_ms = later.iter().map(|r| r.time_ms).sum::<f64>() / later.len() as f64;
        let errors: Vec<f64> = later.iter().filter_map(|r| r.rel_l2).collect();
        let writing = write_ms.iter().skip(1).sum::<f64>() / later.len() as f64;
        eprintln!(
            "{} frames after the first: {:.1} ms a frame ({:.2} frames/s; the files {:.1} ms a frame on their own \
             thread){}",
            later.len(),
            mean_ms,
            1e3 / mean_ms,
            writing,
            if errors.is_empty() {
                String::new()
            } else {
                format!(
                    ", relL2 to the converged frames mean {:.2e}, largest {:.2e}",
                    errors.iter().sum::<f64>() / errors.len() as f64,
                    errors.iter().fold(0.0f64, |m, e| m.max(*e))
                )
            }
        );
    }
    eprintln!("wrote {} frames and {} in {}", rows.len(), csv_path.display(), a.out_dir.display());
    Ok(())
}
