//! `scatterlab animate`: a sequence in which the scene's first light orbits the medium, each
//! frame warm started from the previous frame's solution ([`Solver::animation`]; the
//! illumination-networks paper's section 4: "when the light sources move, we take the solution
//! of the previous light position as the initial value of the iteration"). Every frame is
//! measured against the same frame converged (a second sequence that iterates every frame to
//! the solver's tolerance, itself warm started): what a user trades by iterating less per
//! frame.
//!
//! The orbit: about the vertical axis (+y) through the centre of the medium's bounds, `step`
//! degrees per frame, counter-clockwise seen from above. A point light's position turns, a
//! directional light's direction turns; an environment has nothing to turn and is refused.

use std::time::Instant;

use glam::Quat;
use serde::Serialize;

use crate::gpu::Gpu;
use crate::output::{self, Image};
use crate::scene::{Light, Scene};
use crate::solvers::{Animation, Progress, RenderOutput, RenderRequest, Settings, Solver, SolverError};

/// One frame's figures (a row of `frames.csv`).
#[derive(Clone, Debug, Serialize)]
pub struct FrameRow {
    pub frame: u32,
    /// The first light's angle along the orbit (degrees from the scene's placement).
    pub angle_deg: f64,
    /// Host wall time of the frame (new light, iterations, image), ms.
    pub time_ms: f64,
    /// The GPU time of its passes, ms.
    pub gpu_ms: f64,
    /// Iterations run for this frame (from the previous frame's solution after the first).
    pub iterations: u64,
    /// The last iteration's change measure, and whether it met the tolerance.
    pub change: f64,
    pub converged: bool,
    /// Against the same frame iterated to the tolerance: relL2 of the image, and the ratio of
    /// the image totals (empty without a reference).
    pub rel_l2: Option<f64>,
    pub energy_ratio: Option<f64>,
    /// Iterations the converged frame took from its own previous frame.
    pub reference_iterations: Option<u64>,
    /// Host time writing the frame's files, ms (`scatterlab animate` writes them on a thread of
    /// their own while the next frame computes; empty where nothing was written).
    pub write_ms: Option<f64>,
    /// The solver, and what the sequence is: a digest of the engine, solver, scene (its content:
    /// [`crate::scene::content_hash`]), `--set` values in effect, `--orbit-light` and reference choice,
    /// the same for every frame range of one sequence (`merge --csv` refuses to join frames
    /// of different ones). Empty where the caller gave none.
    pub solver: String,
    pub sequence: String,
}

/// What a sequence asks for.
pub struct Orbit {
    /// The first frame's number (`animate --frame-range A..B`: A); it starts cold, as frame 0
    /// does, so a range computes its own frames without the ones before it.
    pub first: u32,
    pub frames: u32,
    /// Degrees per frame.
    pub step_deg: f64,
    /// Measure every frame against the same frame converged.
    pub reference: bool,
}

/// `scene` with its first light turned by `deg` degrees about the vertical axis through the
/// medium's centre.
pub fn orbit(scene: &Scene, deg: f64) -> Result<Scene, String> {
    let mut s = scene.clone();
    let centre = (s.medium.bounds_min + s.medium.bounds_max) * 0.5;
    let q = Quat::from_rotation_y(deg.to_radians() as f32);
    match s.lights.first_mut() {
        Some(Light::Point { position, .. }) => *position = centre + q * (*position - centre),
        Some(Light::Directional { direction, .. }) => *direction = q * *direction,
        Some(Light::Environment { .. }) => {
            return Err("animate: the first light is an environment, which has no position or direction to orbit; \
                        put a point or directional light first"
                .to_string())
        }
        None => return Err("animate: the scene has no light to orbit".to_string()),
    }
    Ok(s)
}

/// A warm-started sequence and its converged reference ([`sequences`]).
pub type Sequences = (Box<dyn Animation>, Option<Box<dyn Animation>>);

/// The solver's warm-started sequence for `scene` and, with `reference`, a second one that
/// iterates every frame to the tolerance. Host work only (no device): a solver without a warm
/// start, or knobs its sequence refuses, fail here before any rendering.
pub fn sequences(
    solver: &dyn Solver,
    scene: &Scene,
    settings: &Settings,
    reference: bool,
) -> Result<Sequences, String> {
    orbit(scene, 0.0)?;
    let req = RenderRequest { scene, settings, force_full: false, progress: &|_| {} };
    let make = |converge: bool| {
        solver.animation(&req, converge).map_err(|e| e.to_string())?.ok_or_else(|| {
            format!("animate: solver {} keeps no solution to warm start the next frame from", solver.name())
        })
    };
    Ok((make(false)?, if reference { Some(make(true)?) } else { None }))
}

/// Render the sequence: `on_frame` gets each frame's image and row as it is done (to write it
/// at once: nothing is lost to a later failure). Errors as one line.
pub fn run(
    gpu: &Gpu,
    solver: &dyn Solver,
    scene: &Scene,
    settings: &Settings,
    o: &Orbit,
    progress: &dyn Fn(Progress),
    on_frame: &mut dyn FnMut(&Image, &RenderOutput, &FrameRow) -> Result<(), String>,
) -> Result<Vec<FrameRow>, String> {
    let (seq, reference) = sequences(solver, scene, settings, o.reference)?;
    run_sequences(gpu, seq, reference, scene, o, progress, on_frame)
}

/// [`run`] with the sequences already made ([`sequences`]).
pub fn run_sequences(
    gpu: &Gpu,
    mut seq: Box<dyn Animation>,
    mut reference: Option<Box<dyn Animation>>,
    scene: &Scene,
    o: &Orbit,
    progress: &dyn Fn(Progress),
    on_frame: &mut dyn FnMut(&Image, &RenderOutput, &FrameRow) -> Result<(), String>,
) -> Result<Vec<FrameRow>, String> {
    let mut rows = Vec::with_capacity(o.frames as usize);
    for f in o.first..o.first + o.frames {
        let angle = f as f64 * o.step_deg;
        let s = orbit(scene, angle)?;
        let t = Instant::now();
        let out = seq.frame(gpu, &s, progress).map_err(|e: SolverError| e.to_string())?;
        let time_ms = t.elapsed().as_secs_f64() * 1e3;
        if out.image.nan_inf_count() > 0 {
            return Err(format!("animate: frame {f} has non-finite pixels (a bug: please report the scene)"));
        }
        let conv = out.report.stats.convergence;
        let mut row = FrameRow {
            frame: f,
            angle_deg: angle,
            time_ms,
            gpu_ms: out.report.gpu_ms,
            iterations: conv.map_or(0, |c| c.iterations),
            change: conv.map_or(0.0, |c| c.final_change),
            converged: conv.map_or(true, |c| c.converged),
            rel_l2: None,
            energy_ratio: None,
            reference_iterations: None,
            write_ms: None,
            solver: String::new(),
            sequence: String::new(),
        };
        if let Some(r) = &mut reference {
            let truth = r.frame(gpu, &s, &|_| {}).map_err(|e| e.to_string())?;
            let m = output::compare(&out.image, &truth.image).map_err(|e| e.to_string())?;
            row.rel_l2 = Some(m.rel_l2);
            let total = |i: &Image| i.data.iter().map(|x| *x as f64).sum::<f64>();
            let (a, b) = (total(&out.image), total(&truth.image));
            row.energy_ratio = Some(if b > 0.0 { a / b } else { 1.0 });
            row.reference_iterations = truth.report.stats.convergence.map(|c| c.iterations);
        }
        on_frame(&out.image, &out, &row)?;
        rows.push(row);
    }
    Ok(rows)
}

/// What identifies a sequence across its frame ranges ([`FrameRow::sequence`]): 12 hex
/// digits of SHA-256 over the engine, solver, scene digest, the `--set` values in effect
/// (`key=value`, the caller's order), the degrees per frame and whether frames are measured
/// against converged ones.
pub fn sequence_id(solver: &str, scene_hash: &str, sets: &[String], step_deg: f64, reference: bool) -> String {
    use sha2::{Digest, Sha256};
    let mut h = Sha256::new();
    for part in [crate::output::engine().as_str(), solver, scene_hash] {
        h.update((part.len() as u64).to_le_bytes());
        h.update(part.as_bytes());
    }
    h.update((sets.len() as u64).to_le_bytes());
    for s in sets {
        h.update((s.len() as u64).to_le_bytes());
        h.update(s.as_bytes());
    }
    h.update(step_deg.to_le_bytes());
    h.update([reference as u8]);
    h.finalize().iter().take(6).map(|b| format!("{b:02x}")).collect()
}

/// `frames.csv`: one row per frame.
pub fn csv(rows: &[FrameRow]) -> Result<String, String> {
    let mut w = csv::Writer::from_writer(Vec::new());
    for r in rows {
        w.serialize(r).map_err(|e| format!("CSV: {e}"))?;
    }
    let bytes = w.into_inner().map_err(|e| format!("CSV: {e}"))?;
    String::from_utf8(bytes).map_err(|e| format!("CSV: {e}"))
}
