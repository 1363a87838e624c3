//! The solver interface: what every solver supplies ([`Solver`]) and what a render is asked
//! and answers ([`RenderRequest`], [`RenderOutput`], [`RenderReport`], [`Stats`]), the knob
//! tables ([`knobs`]) and what a render modelled ([`modelled`]). Below everything else in
//! `solvers/`: the shared parts (`solvers/parts/`) and the solvers import it; it imports
//! neither. The registry (`solvers/mod.rs`: `SOLVERS`, `find`) sits above them all.

pub mod knobs;
pub mod modelled;

use std::any::Any;
use std::sync::Arc;

use serde::Serialize;
use thiserror::Error;

use crate::gpu::{Gpu, GpuError, Kernel, PassTiming};
use crate::output::Image;
use crate::scene::Scene;

pub use knobs::{Knob, Knobs, Range, Settings};
pub use modelled::Modelled;

#[derive(Debug, Error)]
#[non_exhaustive]
pub enum SolverError {
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error("--set {key}: {reason}")]
    Setting { key: String, reason: String },
    #[error("{0}")]
    Unsupported(String),
}

/// A solver: a way of computing radiance toward the camera, with its own knobs and its own
/// idea of quality. Implementations are unit structs registered in [`SOLVERS`](super::SOLVERS).
pub trait Solver: Sync {
    /// Its name on the command line and the prefix of its knobs (`--solver lbl`,
    /// `--set lbl.grid=32`).
    fn name(&self) -> &'static str;
    /// One line: what it computes, and from which paper.
    fn about(&self) -> &'static str;
    /// The unbiased ground truth the others are measured against (exactly one solver).
    fn is_reference(&self) -> bool {
        false
    }
    /// Whether it samples pixels, so that `render.spp` (`--spp`) sets its quality; the
    /// others compute each pixel deterministically and refuse `--spp` rather than ignore it.
    fn samples_pixels(&self) -> bool {
        false
    }
    /// Every knob with its default, range and meaning: the one place they are written.
    fn knobs(&self) -> Vec<Knob>;
    /// Every compute kernel its passes may run (checked against SPIR-V reflection in tests).
    fn kernels(&self) -> Vec<Kernel>;
    /// Render the scene. Knobs come from `req.settings` through [`RenderRequest::knobs`].
    fn render(&self, gpu: &Gpu, req: &RenderRequest) -> Result<RenderOutput, SolverError>;
    /// Device bytes a render of `scene` with these knobs would allocate (`scene info`).
    fn memory_estimate(&self, scene: &Scene, knobs: &Knobs) -> Result<u64, SolverError>;
    /// Its quality ladder for `bench`, cheapest first (at least three rungs: `--quick` keeps
    /// three).
    fn ladder(&self, scene: &Scene) -> Vec<Rung>;
    /// How `stability` runs it: at least one variant; each judged separately.
    fn stability(&self) -> Vec<Variant>;
    /// The render's trust warnings that the scene and the knobs decide before any work: a
    /// discretisation outside what the solver was validated for, named with the knob that
    /// fixes it (a solver that cannot serve the scene says so before it runs). `render` prints
    /// them first; the render's report carries the same lines among its warnings.
    fn preflight(&self, _scene: &Scene, _knobs: &Knobs) -> Result<Vec<String>, SolverError> {
        Ok(Vec::new())
    }
    /// Why the method does not apply to this scene, if it does not (`bench` skips it there
    /// and says why, rather than plotting another solver's result under its name).
    fn inapplicable(&self, scene: &Scene) -> Option<String> {
        self.scene_refusal(scene)
    }
    /// Whether it renders scene format v2 [[object]] meshes (only `path` so far).
    fn renders_meshes(&self) -> bool {
        false
    }
    /// Whether it renders [[object]] entries of different materials (each object its own
    /// medium and index; only `path` so far).
    fn renders_materials(&self) -> bool {
        false
    }
    /// Whether it carries a medium's emission (the source sigma_a Le), as its docs say it does.
    fn renders_emission(&self) -> bool {
        false
    }
    /// Why its method cannot carry emission, where that is the method's nature rather than work
    /// not done yet: said in the refusal.
    fn emission_refused_because(&self) -> Option<&'static str> {
        None
    }
    /// Why it refuses `scene`: an [[object]] it cannot trace, objects of several materials
    /// where it holds one medium, or an emissive medium it would render as if dark (checked
    /// before any device work).
    fn scene_refusal(&self, scene: &Scene) -> Option<String> {
        if !self.renders_meshes() {
            if let Some(why) = meshes_unsupported(self.name(), scene) {
                return Some(why);
            }
        } else if !self.renders_materials() {
            if let Some(why) = materials_unsupported(self.name(), scene) {
                return Some(why);
            }
        }
        if !self.renders_emission() && scene.emissive() {
            let why = self.emission_refused_because().map(|w| format!(": {w}")).unwrap_or_default();
            return Some(format!(
                "{} does not carry a medium's emission (the scene's medium emits){why}; use --solver {}",
                self.name(),
                solvers_that(|s| s.renders_emission())
            ));
        }
        None
    }
    /// The seed paper's headline workload for `scatterlab report` (at CI size with `quick`),
    /// if the solver has one: each solver adds its own.
    fn headline(&self, _quick: bool) -> Option<Headline> {
        None
    }
    /// A workload whose passes run on more than one queue role, for `report`'s
    /// queue-concurrency matrix (the solver has [`Solver::schedules`]), if it has one.
    fn concurrency(&self, _quick: bool) -> Option<Headline> {
        None
    }
    /// The knob whose two values `--compare-schedules` and `report`'s queue matrix compare:
    /// (knob, its value with the roles' work one after the other, its value with the work
    /// free to overlap). By default the `schedule` knob (sequential, concurrent) where the
    /// solver has one.
    fn schedules(&self) -> Option<(&'static str, &'static str, &'static str)> {
        self.knobs().iter().any(|k| k.name == "schedule").then_some(("schedule", "sequential", "concurrent"))
    }
    /// Lines for the terminal after a render, beyond what every render prints.
    fn summary(&self, _report: &RenderReport) -> Vec<String> {
        Vec::new()
    }
    /// A sequence of frames in which the lights move (`scatterlab animate`), each frame warm
    /// started from the previous frame's solution, where the solver has a solution to start
    /// from: `None` where it has not. `converge`: every frame iterates to the solver's
    /// tolerance (the reference a warm sequence is measured against), else each frame after the
    /// first runs the solver's per-frame iterations. `req.scene` is the first frame.
    fn animation(&self, _req: &RenderRequest, _converge: bool) -> Result<Option<Box<dyn Animation>>, SolverError> {
        Ok(None)
    }
}

/// The state of a warm-started sequence ([`Solver::animation`]).
pub trait Animation {
    /// Render `scene`: the first frame's medium, camera and image size with its lights moved
    /// (same number and kinds). The first call iterates from a cold start to the tolerance.
    fn frame(&mut self, gpu: &Gpu, scene: &Scene, progress: &dyn Fn(Progress)) -> Result<RenderOutput, SolverError>;
}

/// A workload of `scatterlab report`: a scene of `scenes/` with keys set, and what the seed
/// paper reports for it.
#[derive(Clone, Debug)]
pub struct Headline {
    pub name: String,
    /// A file in the repository's `scenes/`.
    pub scene: &'static str,
    pub sets: Vec<(String, String)>,
    /// The seed's figure, its hardware and year (empty where no seed times it).
    pub seed: &'static str,
}

impl Headline {
    pub fn new(name: impl Into<String>, scene: &'static str, sets: &[(&str, &str)], seed: &'static str) -> Headline {
        Headline {
            name: name.into(),
            scene,
            sets: sets.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect(),
            seed,
        }
    }
}

/// One rung of a quality ladder: the knob it turns (a full key: `lbl.grid`, or the scene's
/// `render.spp`), its value, and every key it sets.
#[derive(Clone, Debug, Serialize)]
pub struct Rung {
    pub knob: String,
    pub value: String,
    pub sets: Vec<(String, String)>,
}

impl Rung {
    /// A rung that sets one key.
    pub fn one(knob: &str, value: impl ToString) -> Rung {
        let value = value.to_string();
        Rung { knob: knob.to_string(), value: value.clone(), sets: vec![(knob.to_string(), value)] }
    }
}

/// A way `stability` runs a solver.
#[derive(Clone, Debug)]
pub struct Variant {
    /// Empty for the solver as it is; else what this variant changes (`explicit`).
    pub name: String,
    /// Keys it sets: knobs that keep the sweep cheap on a CPU device, and what makes the
    /// variant (scene keys such as `render.spp` are allowed).
    pub sets: Vec<(String, String)>,
    /// Whether it runs on a scene (`path`'s camera-paths variant only where its default
    /// light-traces: elsewhere the two are the same render).
    pub applies: fn(&Scene) -> bool,
    /// A comparison variant: a scheme kept to compare against (`wavefront`'s explicit
    /// integrator, the paper's eq. 6), judged and shown like any other but expected to fail
    /// somewhere; its failures are marked expected and not counted against the sweep.
    pub comparison: bool,
}

impl Variant {
    pub fn new(name: &str, sets: &[(&str, &str)]) -> Variant {
        Variant {
            name: name.to_string(),
            sets: sets.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect(),
            applies: |_| true,
            comparison: false,
        }
    }
}

/// Whether a solver's work on two queue roles may overlap (docs/design.md, "Queues and schedule"):
/// a solver with concurrent work has a `schedule` knob taking these values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Schedule {
    /// Work on the two roles overlaps (thesis Fig. 4.1: tracing round n runs while diffusion
    /// of round n-1 runs).
    Concurrent,
    /// The same passes, each waiting for the other role: no overlap.
    Sequential,
}

impl Schedule {
    pub fn name(self) -> &'static str {
        match self {
            Schedule::Concurrent => "concurrent",
            Schedule::Sequential => "sequential",
        }
    }
}

impl std::str::FromStr for Schedule {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "concurrent" => Ok(Schedule::Concurrent),
            "sequential" => Ok(Schedule::Sequential),
            _ => Err(format!("unknown schedule {s:?}; use concurrent or sequential")),
        }
    }
}

/// Everything a render needs besides the scene.
pub struct RenderRequest<'a> {
    pub scene: &'a Scene,
    /// Solver knobs from `--set solver.key=value` (scene keys are applied to the scene itself).
    pub settings: &'a Settings,
    /// Model every feature even when the scene does not need it (to measure the slim path).
    pub force_full: bool,
    /// Called as the render progresses ([`Progress`]).
    pub progress: &'a dyn Fn(Progress),
}

/// How far a render has got, for a progress display that does not lie: work of a known size
/// counts units as they finish (not as they are submitted); an iteration to a tolerance has
/// no known total and reports its convergence measure instead.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Progress {
    /// `done` of `total` units of a stage (`stage` names a unit: "samples per pixel").
    Work { stage: &'static str, done: u64, total: u64 },
    /// Iterating to a tolerance: `change` is the convergence measure after `iteration`
    /// iterations, `tol` its target; `remaining` the iterations left at the measured rate of
    /// decay, once two measurements give one.
    Converging { stage: &'static str, iteration: u64, change: f64, tol: f64, remaining: Option<u64> },
}

impl Progress {
    /// Work units: `stage`, `done` of `total`.
    pub fn work(stage: &'static str, done: u64, total: u64) -> Progress {
        Progress::Work { stage, done, total }
    }

    /// An iteration's report, with the iterations left to `tol` at the geometric rate of decay
    /// measured since `earlier` (an earlier measure and its iteration), at most `cap`.
    pub fn converging(
        stage: &'static str,
        iteration: u64,
        change: f64,
        tol: f64,
        earlier: Option<(f64, u64)>,
        cap: u64,
    ) -> Progress {
        let remaining = earlier.and_then(|(c0, i0)| {
            let rate = (change / c0).powf(1.0 / iteration.saturating_sub(i0).max(1) as f64);
            (rate > 0.0 && rate < 1.0 && change > tol)
                .then(|| ((tol / change).ln() / rate.ln()).ceil().min(cap as f64) as u64)
        });
        Progress::Converging { stage, iteration, change, tol, remaining }
    }
}

impl RenderRequest<'_> {
    /// The solver's knob values, checked against its table.
    pub fn knobs(&self, solver: &dyn Solver) -> Result<Knobs, SolverError> {
        self.settings.knobs(solver.name(), solver.knobs())
    }
}

/// A finished render: the image, its per-pixel variance where the solver is Monte Carlo, and
/// what was done to make it.
pub struct RenderOutput {
    pub image: Image,
    pub variance: Option<Image>,
    pub report: RenderReport,
    /// The independent Monte Carlo estimators whose means and variances add up to `image` and
    /// `variance` (`path`: its camera paths, its light paths), each with what its variance was
    /// estimated from, so that renders of disjoint sample ranges merge exactly
    /// (`scatterlab merge`). Empty for deterministic solvers.
    pub estimates: Vec<Estimate>,
}

/// One Monte Carlo estimator of a render: the variance of its mean is M2 / ((units - 1) N),
/// with N its sample count (the range's length) and M2 the sum, over its `units` independent
/// units of weight n_u (one sample each for camera paths, a batch of rounds for light
/// paths), of n_u (m_u - m)^2. Knowing `units` is what lets a merge recover M2 from the
/// variance layer and combine ranges as one render of their union would (Chan et al. 1979).
#[derive(Clone, Debug)]
pub struct Estimate {
    /// A short name for the layer names (`camera`, `light`).
    pub name: &'static str,
    /// Independent units behind the variance (samples, or batches).
    pub units: u64,
    /// Its own mean and variance of the mean where the render has more than one estimator
    /// (they are then summed into the render's image); `None` where it is the only one.
    pub layers: Option<(Image, Image)>,
}

impl RenderOutput {
    /// The variance of the sum of every pixel value (all channels), for judging image totals:
    /// the per-pixel variances where pixels are independent (camera paths), plus the part
    /// whose pixels covary (`path`'s light-traced part, from its batches; counting its
    /// per-pixel variances too is conservative). 0 for deterministic solvers.
    pub fn total_variance(&self) -> f64 {
        let per_pixel: f64 = self.variance.as_ref().map_or(0.0, |v| v.data.iter().map(|x| *x as f64).sum());
        let n = self.image.data.len() as f64;
        per_pixel + (n * self.report.stats.correlated_mean_stderr).powi(2)
    }
}

/// What a render did, beside the image.
#[derive(Clone, Debug, Serialize)]
pub struct RenderReport {
    pub solver: &'static str,
    /// The knobs it ran with, defaults included (`Knobs::json`).
    pub settings: serde_json::Value,
    pub modelled: Modelled,
    pub device_bytes: u64,
    pub passes: Vec<PassTiming>,
    pub gpu_ms: f64,
    /// The Vulkan core's host work during the render (pipelines, allocations, copies, waits).
    pub host: crate::gpu::HostTimes,
    /// Every pipeline the render used, with the scene features it was specialised for.
    pub pipelines: Vec<PipelineUse>,
    pub stats: Stats,
    pub warnings: Vec<String>,
    /// Pixels that came out NaN or infinite and were set to 0 before the image was returned
    /// ([`RenderReport::zeroed_nonfinite`]): `scatterlab render` writes nothing then.
    pub nonfinite_pixels: u32,
}

/// A pipeline a render used: its shader, the specialisation constants it was built with (by
/// name: the features compiled in), the host milliseconds its build took, and whether this
/// process had built it before (`reused`, 0 ms).
#[derive(Clone, Debug, Serialize)]
pub struct PipelineUse {
    pub shader: &'static str,
    pub spec: std::collections::BTreeMap<String, crate::gpu::Spec>,
    pub ms: f64,
    pub reused: bool,
    /// Why the driver specialised it, not the host (`gpu::specialize`); absent where the host did.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub driver_specialized: Option<String>,
}

impl PipelineUse {
    fn of(r: crate::gpu::PipelineRecord) -> PipelineUse {
        PipelineUse {
            shader: r.shader,
            spec: r.spec.iter().map(|(id, v)| (modelled::spec_name(*id), *v)).collect(),
            ms: r.ms,
            reused: r.reused,
            driver_specialized: r.driver_specialized,
        }
    }
}

impl RenderReport {
    /// The report of a finished render: takes the GPU's pass timings.
    pub fn finish(
        gpu: &Gpu,
        solver: &dyn Solver,
        knobs: &Knobs,
        modelled: Modelled,
        device_bytes: u64,
        stats: Stats,
    ) -> RenderReport {
        let passes = gpu.take_timings();
        RenderReport {
            solver: solver.name(),
            settings: knobs.json(),
            modelled,
            device_bytes,
            gpu_ms: passes.iter().map(|p| p.duration_ms()).sum(),
            host: gpu.take_host_times(),
            pipelines: gpu.take_pipeline_records().into_iter().map(PipelineUse::of).collect(),
            passes,
            stats,
            warnings: Vec::new(),
            nonfinite_pixels: 0,
        }
    }

    /// `pixels` of the image were NaN or infinite and were set to 0: counted, and warned of.
    pub fn zeroed_nonfinite(&mut self, pixels: u32) {
        self.nonfinite_pixels += pixels;
        self.warnings.extend(nonfinite_warning(pixels));
    }

    /// The solver's own stats, typed (`report.detail::<lbl::LblStats>()`).
    pub fn detail<T: 'static>(&self) -> Option<&T> {
        // Through the trait object: `Arc<dyn Detail>` is itself a `Detail` (the blanket impl),
        // and method lookup on the Arc would downcast the Arc.
        let detail: &dyn Detail = self.stats.detail.as_ref();
        detail.as_any().downcast_ref::<T>()
    }
}

/// What every render reports, typed: `measure` reads these fields, never JSON.
#[derive(Clone, Debug, Serialize)]
pub struct Stats {
    /// Iterative solvers: how the iteration ended.
    pub convergence: Option<Convergence>,
    /// Monte Carlo solvers: samples per pixel.
    pub spp: Option<u32>,
    /// The standard error of the image mean (over pixels and channels) beyond what the
    /// per-pixel variances give: the part of a Monte Carlo image whose pixels covary
    /// (`path`'s light-traced part). 0 otherwise.
    pub correlated_mean_stderr: f64,
    /// Internal values that went negative or non-finite and were cleaned up before they reached
    /// the image (so the image alone does not show them): a failure for `stability`.
    pub faults: u64,
    /// Throughput figures of this render (samples/s, lattice voxel-updates/s, ...).
    pub throughput: Vec<Figure>,
    /// The solver's own stats (serialised as they are; typed via [`RenderReport::detail`]).
    pub detail: Arc<dyn Detail>,
}

impl Stats {
    pub fn new(detail: impl Detail) -> Stats {
        Stats {
            convergence: None,
            spp: None,
            correlated_mean_stderr: 0.0,
            faults: 0,
            throughput: Vec::new(),
            detail: Arc::new(detail),
        }
    }
}

/// How an iterative solve ended.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Convergence {
    pub iterations: u64,
    pub converged: bool,
    /// The change measure at the last check, beside the tolerance it was held to.
    pub final_change: f64,
    pub tolerance: f64,
}

/// A throughput figure: what, how much, in what unit.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Figure {
    pub figure: String,
    pub value: f64,
    pub unit: String,
}

/// A solver's own stats: any serialisable type (a struct per solver).
pub trait Detail: erased_serde::Serialize + Any + std::fmt::Debug + Send + Sync {
    fn as_any(&self) -> &dyn Any;
}

impl<T: Serialize + Any + std::fmt::Debug + Send + Sync> Detail for T {
    fn as_any(&self) -> &dyn Any {
        self
    }
}

erased_serde::serialize_trait_object!(Detail);

/// Device memory a solver would allocate for this scene with these knob settings (its own
/// among them; the others' are ignored), in bytes.
pub fn memory_estimate(solver: &dyn Solver, scene: &Scene, settings: &Settings) -> Result<u64, SolverError> {
    let knobs = settings.only(solver.name()).knobs(solver.name(), solver.knobs())?;
    solver.memory_estimate(scene, &knobs)
}

/// The warning every solver gives when its image had non-finite pixels zeroed.
pub(crate) fn nonfinite_warning(pixels: u32) -> Option<String> {
    (pixels > 0).then(|| format!("{pixels} pixels were not finite and were set to 0 (a bug: please report the scene)"))
}

/// The count of points (networks' particles, sh-single's samples) that brings their spacing,
/// `spacing` at `count` points, down to `validated`, never fewer than `count`: points spread
/// through a volume stand count^(-1/3) apart, so count (spacing / validated)^3 of them. None
/// past `max`, the knob's largest value (no count in range serves).
pub(crate) fn count_for_spacing(count: u32, spacing: f64, validated: f64, max: u32) -> Option<u32> {
    let want = (count as f64 * (spacing / validated).powi(3)).ceil();
    (want <= max as f64).then_some(want.max(count as f64) as u32)
}

/// The registered solvers (the registry's [`SOLVERS`](super::SOLVERS)): the one place the
/// interface reads the registry, for the messages that name the solvers that can do what
/// another cannot (a refusal, an unknown knob's owner).
pub fn registered() -> &'static [&'static dyn Solver] {
    super::SOLVERS
}

/// Why `solver`, which does not trace meshes, cannot render `scene`: it has an [[object]]
/// (scene format v2). `path`, `single` and `lbl` render meshes so far (issue 16).
pub fn meshes_unsupported(solver: &str, scene: &Scene) -> Option<String> {
    scene.object.as_ref().map(|o| {
        format!(
            "{solver} does not render [[object]] meshes yet (the scene's object is {}); use --solver {}, or a v1 [medium]",
            o.describe(),
            solvers_that(|s| s.renders_meshes())
        )
    })
}

/// The registered solvers for which `f` holds, as "a, b or c".
fn solvers_that(f: impl Fn(&dyn Solver) -> bool) -> String {
    let names: Vec<&str> = registered().iter().filter(|s| f(**s)).map(|s| s.name()).collect();
    match names.split_last() {
        Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
        Some((last, _)) => last.to_string(),
        None => String::new(),
    }
}

/// Why `solver`, which holds one medium, cannot render `scene`: its [[object]] entries differ
/// in material (sigma_t, albedo, g or ior). None for one material or no object.
pub fn materials_unsupported(solver: &str, scene: &Scene) -> Option<String> {
    scene.object.as_ref().filter(|o| o.several_materials()).map(|o| {
        let differ: Vec<String> =
            o.parts.iter().enumerate().filter(|(_, p)| p.material != 0).map(|(i, _)| format!("object[{i}]")).collect();
        format!(
            "{solver} holds one medium, and the scene's objects have {} materials (sigma_t, albedo, g or ior differ \
                from object[0]'s in {}); use --solver {}, or give every object the same material",
            o.materials.len(),
            differ.join(", "),
            solvers_that(|s| s.renders_materials())
        )
    })
}
