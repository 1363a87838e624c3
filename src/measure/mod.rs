//! Measurement: what the GPU did and how long it took (timelines, overlap, serial baseline),
//! and the commands that walk solvers over scenes (`bench`, `stability`). Solvers are reached
//! only through [`crate::solvers::Solver`]: nothing here names one.

pub mod animate;
pub mod bench;
pub mod report;
pub mod stability;
pub mod timeline;

use crate::gpu::Gpu;
use crate::scene::{is_scene_key, Scene};
use crate::solvers::{RenderOutput, RenderRequest, Settings, Solver};

/// Render with `sets` applied, no progress, returning the output and the wall time in ms;
/// errors as text (the commands print them on one line). Scene keys among `sets` (a ladder's
/// `render.spp`) apply to a copy of the scene ([`Scene::with_overrides`]), the rest are the
/// solver's knobs.
pub fn render_with(
    gpu: &Gpu,
    scene: &Scene,
    solver: &dyn Solver,
    sets: &[(String, String)],
    force_full: bool,
) -> Result<(RenderOutput, f64), String> {
    let (scene_sets, knob_sets): (Vec<_>, Vec<_>) = sets.iter().cloned().partition(|(k, _)| is_scene_key(k));
    let scene = scene.with_overrides(&scene_sets).map_err(|e| e.to_string())?;
    let settings = Settings::new(&knob_sets);
    let req = RenderRequest { scene: &scene, settings: &settings, force_full, progress: &|_| {} };
    let t = std::time::Instant::now();
    let r = solver.render(gpu, &req).map_err(|e| e.to_string())?;
    Ok((r, t.elapsed().as_secs_f64() * 1e3))
}

/// The median of `v` (the mean of the middle two for an even count); NaN for none.
pub fn median(v: &[f64]) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    match n {
        0 => f64::NAN,
        _ if n % 2 == 1 => v[n / 2],
        _ => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

/// CSV text of `header` and `rows` (RFC 4180 quoting by the `csv` crate: a scene path with a
/// comma or a quote stays one field).
pub fn csv_text(header: &[&str], rows: impl IntoIterator<Item = Vec<String>>) -> Result<String, String> {
    let mut w = csv::Writer::from_writer(Vec::new());
    w.write_record(header).map_err(|e| format!("CSV: {e}"))?;
    for row in rows {
        w.write_record(&row).map_err(|e| format!("CSV: {e}"))?;
    }
    let bytes = w.into_inner().map_err(|e| format!("CSV: {e}"))?;
    String::from_utf8(bytes).map_err(|e| format!("CSV: {e}"))
}
