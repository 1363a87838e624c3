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

/// Consecutive warm runs that agree within this share have settled (issue 42).
pub const SETTLE: f64 = 0.05;

/// Runs of one measurement as `bench` and `report` take them: the first apart as the cold
/// start (on a GPU the driver compiling pipelines and the clocks still low: 3-5x the warm GPU
/// time on the H200), then warm runs until two consecutive ones agree within [`SETTLE`] on
/// `key` or `max_warm` have run.
pub struct Runs<R> {
    pub cold: R,
    pub warm: Vec<R>,
}

impl<R> Runs<R> {
    pub fn take<E>(max_warm: u32, key: impl Fn(&R) -> f64, mut run: impl FnMut() -> Result<R, E>) -> Result<Self, E> {
        let cold = run()?;
        let mut warm: Vec<R> = Vec::new();
        while (warm.len() as u32) < max_warm {
            warm.push(run()?);
            if let [.., a, b] = warm.as_slice() {
                if settled(key(a), key(b)) {
                    break;
                }
            }
        }
        Ok(Runs { cold, warm })
    }

    /// The warm runs' figure `f`, or the cold run's where none ran warm.
    pub fn spread(&self, f: impl Fn(&R) -> f64) -> Spread {
        let v: Vec<f64> = if self.warm.is_empty() { vec![f(&self.cold)] } else { self.warm.iter().map(&f).collect() };
        Spread::of(&v, !self.warm.is_empty() && self.settled(&f))
    }

    fn settled(&self, f: impl Fn(&R) -> f64) -> bool {
        matches!(self.warm.as_slice(), [.., a, b] if settled(f(a), f(b)))
    }

    /// The run to take results from: the last warm one, else the cold one.
    pub fn last(&self) -> &R {
        self.warm.last().unwrap_or(&self.cold)
    }
}

/// Whether two timings agree within [`SETTLE`].
pub fn settled(a: f64, b: f64) -> bool {
    (a - b).abs() <= SETTLE * a.abs().max(b.abs())
}

/// Timings of repeated runs: how many, median, least and most, and their spread (most - least)
/// over the median; `settled` where the last two agreed within [`SETTLE`].
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize, PartialEq)]
pub struct Spread {
    pub runs: u32,
    pub median: f64,
    pub min: f64,
    pub max: f64,
    pub spread: f64,
    pub settled: bool,
}

impl Spread {
    pub fn of(v: &[f64], settled: bool) -> Spread {
        let median = median(v);
        let min = v.iter().copied().fold(f64::INFINITY, f64::min);
        let max = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let spread = if median > 0.0 { (max - min) / median } else { 0.0 };
        Spread { runs: v.len() as u32, median, min, max, spread, settled }
    }
}
