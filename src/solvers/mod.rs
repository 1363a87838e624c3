//! Solvers: each turns a scene into radiance toward the camera, in the same units as `path`,
//! by describing passes for the `gpu` layer. They never record barriers or semaphore waits.

pub mod gpu_scene;
pub mod lbl;
pub mod path;
pub mod resumable;
pub mod settings;
pub mod shaders;
pub mod single;
pub mod wavefront;

use serde::Serialize;
use thiserror::Error;

use crate::gpu::{Gpu, GpuError, PassTiming};
use crate::output::Image;
use crate::scene::Scene;

pub use gpu_scene::Modelled;
pub use settings::Settings;

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

/// The solvers this build ships.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum SolverKind {
    /// Volumetric path tracer: the unbiased ground truth.
    Path,
    /// Single scattering by ray marching: the direct term.
    Single,
    /// Photon marching + Lattice-Boltzmann diffusion on concurrent queues (thesis ch. 4).
    Lbl,
    /// Wavefront tracing of homogeneous spherical layers around point lights (wavefront paper).
    Wavefront,
}

impl SolverKind {
    pub fn name(self) -> &'static str {
        match self {
            SolverKind::Path => "path",
            SolverKind::Single => "single",
            SolverKind::Lbl => "lbl",
            SolverKind::Wavefront => "wavefront",
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
    /// Called with (done, total) work units as the render progresses.
    pub progress: &'a dyn Fn(u64, u64),
}

/// A finished render: the image, its per-pixel variance where the solver is Monte Carlo, and
/// what was done to make it.
pub struct RenderOutput {
    pub image: Image,
    pub variance: Option<Image>,
    pub report: RenderReport,
}

impl RenderOutput {
    /// The variance of the sum of every pixel value (all channels), for judging image totals:
    /// the per-pixel variances where pixels are independent (camera paths), plus the
    /// light-traced part's own, from its batches (one light path adds to many pixels, so its
    /// pixels covary; counting its per-pixel variances too is conservative). 0 for
    /// deterministic solvers.
    pub fn total_variance(&self) -> f64 {
        let per_pixel: f64 = self.variance.as_ref().map_or(0.0, |v| v.data.iter().map(|x| *x as f64).sum());
        let n = self.image.data.len() as f64;
        per_pixel + (n * self.light_traced_mean_stderr()).powi(2)
    }

    /// The standard error of the image mean (over pixels and channels) of `path`'s
    /// light-traced part, from its batches; 0 when nothing was light traced.
    pub fn light_traced_mean_stderr(&self) -> f64 {
        self.report.stats.get("light_paths").and_then(|l| l["image_mean_stderr"].as_f64()).unwrap_or(0.0)
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct RenderReport {
    pub solver: SolverKind,
    pub settings: serde_json::Value,
    pub modelled: Modelled,
    pub device_bytes: u64,
    pub passes: Vec<PassTiming>,
    pub gpu_ms: f64,
    pub stats: serde_json::Value,
    pub warnings: Vec<String>,
}

/// Run `kind` on the scene.
pub fn render(gpu: &Gpu, kind: SolverKind, req: &RenderRequest) -> Result<RenderOutput, SolverError> {
    match kind {
        SolverKind::Path => path::render(gpu, req),
        SolverKind::Single => single::render(gpu, req),
        SolverKind::Lbl => lbl::render(gpu, req),
        SolverKind::Wavefront => wavefront::render(gpu, req),
    }
}

/// Device memory a solver would allocate for this scene, in bytes (for `scene info`).
pub fn memory_estimate(kind: SolverKind, scene: &Scene) -> u64 {
    let pixels = scene.render.width as u64 * scene.render.height as u64;
    gpu_scene::scene_bytes(scene)
        + match kind {
            SolverKind::Path => {
                pixels * (path::ACCUM_BYTES_PER_PIXEL + path::LIGHT_BYTES_PER_PIXEL)
                    + 2 * resumable::STATS_WORDS * 4
                    + 16
            }
            SolverKind::Single => pixels * (16 + single::STATE_BYTES_PER_PIXEL) + resumable::STATS_WORDS * 4,
            SolverKind::Lbl => {
                // Default knobs: 64 voxels along the longest side, 3 channels at most, 65536
                // rays per light with 16 history slots, plus the view march.
                let g = lbl::LatticeGeom::new(scene, 64).voxels();
                let rays = 65536 * scene.lights.len() as u64;
                g * 4 * (1 + 2 * 7 * 3 + 3 + 3) + rays * (48 + 16 * 16) + pixels * (16 + single::STATE_BYTES_PER_PIXEL)
            }
            SolverKind::Wavefront => {
                // Default knobs: 64 x 32 rays x 129 nodes x 3 vec4 + shells, a 64-voxel
                // Cartesian volume with 3 channels of fluence and flux, plus the view march.
                let g = lbl::LatticeGeom::new(scene, 64).voxels();
                64 * 32 * (129 * 48 + 128 * 4) + g * 4 * 12 + pixels * (16 + single::STATE_BYTES_PER_PIXEL)
            }
        }
}

pub(crate) fn gpu_ms(passes: &[PassTiming]) -> f64 {
    passes.iter().map(|p| p.duration_ms()).sum()
}
