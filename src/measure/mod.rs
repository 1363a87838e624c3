//! Measurement: what the GPU did and how long it took (timelines, overlap, serial baseline).

pub mod bench;
pub mod stability;
pub mod timeline;

use crate::gpu::Gpu;
use crate::scene::Scene;
use crate::solvers::{self, RenderOutput, RenderRequest, Settings, SolverKind};

/// Render with solver knobs given as pairs, no progress, returning the output and the wall
/// time in ms; errors as text (the commands print them on one line).
pub(crate) fn render_timed(
    gpu: &Gpu,
    scene: &Scene,
    kind: SolverKind,
    sets: &[(String, String)],
    force_full: bool,
) -> Result<(RenderOutput, f64), String> {
    let settings = Settings::new(sets);
    let req = RenderRequest { scene, settings: &settings, force_full, progress: &|_, _| {} };
    let t = std::time::Instant::now();
    let r = solvers::render(gpu, kind, &req).map_err(|e| e.to_string())?;
    Ok((r, t.elapsed().as_secs_f64() * 1e3))
}
