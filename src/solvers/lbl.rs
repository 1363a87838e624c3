//! Solver `lbl`: photon marching plus Lattice-Boltzmann diffusion (thesis ch. 4), with tracing
//! and diffusion on separate queue roles synchronised by timeline semaphores.
//!
//! Per round n (thesis Fig. 4.1): `march(n)` advances every light ray by `k` steps on the
//! `trace` role, writing deposits into the Ray History Buffer, while `diffuse(n-1)` runs
//! lattice iterations on the `diffuse` role; then `transfer(n)` (alone: it reads the history
//! and writes the lattice) adds the round's deposits to the lattice. After the last round the
//! lattice iterates until the relative change at sparse probe voxels falls under `tol`, and the
//! view pass marches camera rays: exact single scattering (as `single`) plus the multiply
//! scattered light gathered from the lattice's time-integrated field (thesis 4.6.2). The
//! deposits are the power scattered out of the light beams (the once-scattered source); what
//! they send straight to the camera is the single-scattering term, and the lattice carries the
//! rest, so no energy is counted twice.
//!
//! Knobs (`--set lbl.KEY=VALUE`): `rays` (per light, default 65536), `k` (history slots per
//! ray per round, default 16), `step` (marching step, scene units; default half a voxel),
//! `grid` (lattice voxels along the medium's longest side, default 64), `lattice` (`d3q6` or
//! `d3q18`),
//! `block` (block edge b: 2, 4 or 8; default 4), `block_steps` (lattice steps per dispatch in a
//! block; 1 = the global lattice; default b), `iters_per_round` (default 8), `tol` (default
//! 1e-4), `max_iters` (default 20000), `threshold` (default 1e-4), `env_lights` (directional
//! raymaps standing in for an environment, default 14), `deterministic` (fixed-point transfer),
//! `schedule` (`concurrent` | `sequential`), `warm_start` (`none` | `wavefront`: start the
//! lattice iteration from the wavefront solver's field, with its knobs as `lbl.wavefront_nu`,
//! `lbl.wavefront_nv`, `lbl.wavefront_layers`, `lbl.wavefront_integrator`; see `warm_start`),
//! and the view march's `view_step`,
//! `view_shadow_step`, `view_env_dirs`, `view_supersample`, `view_jitter`, `view_budget`.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use serde::Serialize;
use serde_json::json;

use crate::gpu::{Buffer, Gpu, Pass, QueueRole, Spec, SyncPoint};
use crate::physics::rng::Pcg32;
use crate::scene::{is_grey, Light, Scene};

use super::gpu_scene::GpuScene;
use super::single::{march_view, MsVolume, ViewSettings};
use super::wavefront::{wave_volume, WavefrontSettings};
use super::{shaders, RenderOutput, RenderReport, RenderRequest, SolverError, SolverKind};

const SPEC_NCH: u32 = 3;
const SPEC_BLOCK: u32 = 4;
const SPEC_WG: u32 = 5;
const SPEC_FIXED: u32 = 6;
const SPEC_LINKS: u32 = 7;

/// The lattice's links besides the rest (glsl/include/lattice.glsl).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Lattice {
    /// 6 axial links + rest (thesis 4.5).
    D3q6,
    /// Geist's 6 axial + 12 face-diagonal links + rest (section 2.2.3).
    D3q18,
}

impl Lattice {
    pub fn links(self) -> u32 {
        match self {
            Lattice::D3q6 => 6,
            Lattice::D3q18 => 18,
        }
    }

    /// Link vectors, index 0 the rest (same order as LATTICE_DIR in lattice.glsl).
    pub fn dirs(self) -> Vec<[i64; 3]> {
        let all: [[i64; 3]; 19] = [
            [0, 0, 0],
            [1, 0, 0],
            [-1, 0, 0],
            [0, 1, 0],
            [0, -1, 0],
            [0, 0, 1],
            [0, 0, -1],
            [1, 1, 0],
            [-1, -1, 0],
            [1, -1, 0],
            [-1, 1, 0],
            [1, 0, 1],
            [-1, 0, -1],
            [1, 0, -1],
            [-1, 0, 1],
            [0, 1, 1],
            [0, -1, -1],
            [0, 1, -1],
            [0, -1, 1],
        ];
        all[..=self.links() as usize].to_vec()
    }

    /// Mean path length of a step in voxels (the time a step stands for): 1 (D3Q6),
    /// (1 + sqrt 2) / 2 (D3Q18). The lattice's fluence weights each arrival by its link length.
    pub fn mean_link_length(self) -> f64 {
        match self {
            Lattice::D3q6 => 1.0,
            Lattice::D3q18 => (1.0 + std::f64::consts::SQRT_2) / 2.0,
        }
    }

    /// Mean square distance per step, in voxels^2: 1 (D3Q6), 1.5 (D3Q18, half its energy on
    /// sqrt 2 links).
    pub fn mean_square_step(self) -> f64 {
        match self {
            Lattice::D3q6 => 1.0,
            Lattice::D3q18 => 1.5,
        }
    }
}

impl std::str::FromStr for Lattice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "d3q6" => Ok(Lattice::D3q6),
            "d3q18" => Ok(Lattice::D3q18),
            _ => Err(format!("unknown lattice {s:?}; use d3q6 or d3q18")),
        }
    }
}

/// Whether marching of round n overlaps diffusion of round n-1.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Schedule {
    /// Thesis Fig. 4.1: tracing round n runs while diffusion of round n-1 runs.
    Concurrent,
    /// The same passes, each diffusion waiting for the tracing of the same round.
    Sequential,
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

/// One step of the round graph.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Step {
    March(u32),
    Transfer(u32),
    Diffuse(u32),
}

/// A submission of the plan: its role, what it runs, and the earlier submissions (by index)
/// it waits on. Indices always point backwards: the host-order rule by construction.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Planned {
    pub role: QueueRole,
    pub step: Step,
    pub waits: Vec<usize>,
}

/// The round graph for `rounds` marching rounds (thesis Fig. 4.1). Both schedules contain the
/// same steps on the same roles; `Sequential` only adds a wait of every diffusion on the
/// marching of the same round, removing the overlap.
pub fn plan(rounds: u32, schedule: Schedule) -> Vec<Planned> {
    let mut p: Vec<Planned> = Vec::new();
    if rounds == 0 {
        return p;
    }
    p.push(Planned { role: QueueRole::Trace, step: Step::March(0), waits: vec![] });
    p.push(Planned { role: QueueRole::Diffuse, step: Step::Transfer(0), waits: vec![0] });
    let mut transfer_prev = 1;
    for n in 1..rounds {
        // March n overwrites the history that transfer n-1 reads.
        p.push(Planned { role: QueueRole::Trace, step: Step::March(n), waits: vec![transfer_prev] });
        let march = p.len() - 1;
        // Diffuse n-1 follows transfer n-1 in its own queue's order.
        let waits = match schedule {
            Schedule::Concurrent => vec![],
            Schedule::Sequential => vec![march],
        };
        p.push(Planned { role: QueueRole::Diffuse, step: Step::Diffuse(n - 1), waits });
        p.push(Planned { role: QueueRole::Diffuse, step: Step::Transfer(n), waits: vec![march] });
        transfer_prev = p.len() - 1;
    }
    p.push(Planned { role: QueueRole::Diffuse, step: Step::Diffuse(rounds - 1), waits: vec![] });
    p
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct GeomPush {
    dims: [u32; 4],
    origin: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct MarchPush {
    dims: [u32; 4],
    origin: [f32; 4],
    step: f32,
    threshold: f32,
    k: u32,
    max_steps: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct TransferPush {
    entries: u32,
    voxels: u32,
    scale: f32,
    pad: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct InjectPush {
    voxels: u32,
    inv_scale: f32,
    pad: [u32; 2],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct DiffusePush {
    dims: [u32; 4],
    sigma_t: [f32; 4],
    albedo: [f32; 4],
    inner_steps: u32,
    pad: [u32; 3],
}

/// Push-constant sizes of the lbl kernels, for the reflection test.
pub fn push_sizes() -> [(crate::gpu::ShaderSource, usize); 6] {
    [
        (shaders::LBL_RESAMPLE, std::mem::size_of::<GeomPush>()),
        (shaders::LBL_MARCH, std::mem::size_of::<MarchPush>()),
        (shaders::LBL_TRANSFER_FLOAT, std::mem::size_of::<TransferPush>()),
        (shaders::LBL_TRANSFER_FIXED, std::mem::size_of::<TransferPush>()),
        (shaders::LBL_INJECT, std::mem::size_of::<InjectPush>()),
        (shaders::LBL_DIFFUSE, std::mem::size_of::<DiffusePush>()),
    ]
}

/// One light ray's start: position, unit direction, power per channel (W).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct RayInit {
    pub pos_steps: [f32; 4],
    pub dir_alive: [f32; 4],
    pub power: [f32; 4],
}

/// The lattice: `dims` cubic voxels of edge `lambda` from `origin` (the medium's min corner).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct LatticeGeom {
    pub dims: [u32; 3],
    pub origin: [f32; 3],
    pub lambda: f32,
}

impl LatticeGeom {
    pub fn new(scene: &Scene, grid: u32) -> LatticeGeom {
        let ext = scene.medium.bounds_max - scene.medium.bounds_min;
        let lambda = ext.max_element() / grid as f32;
        let dims = [0, 1, 2].map(|a| ((ext[a] / lambda) - 1e-4).ceil().max(1.0) as u32);
        LatticeGeom { dims, origin: scene.medium.bounds_min.to_array(), lambda }
    }
    pub fn voxels(&self) -> u64 {
        self.dims.iter().map(|d| *d as u64).product()
    }
    fn min(&self) -> Vec3 {
        Vec3::from(self.origin)
    }
    fn max(&self) -> Vec3 {
        self.min() + Vec3::new(self.dims[0] as f32, self.dims[1] as f32, self.dims[2] as f32) * self.lambda
    }
}

fn ray_box(o: Vec3, d: Vec3, min: Vec3, max: Vec3) -> Option<(f32, f32)> {
    crate::physics::reference::ray_box(o, d, min, max)
}

/// The raymaps of every light (thesis 4.4.1): `rays` rays per light, each carrying its share of
/// the light's power, started where it enters the lattice, backed off by a jitter of up to one
/// step against aliasing. Point lights cover the solid angle the lattice subtends (all
/// directions from inside); directional lights cover the lattice's projection; an environment
/// becomes `env_lights` directional lights of irradiance L 4 pi / K from a spherical Fibonacci
/// set (an approximation the note in `docs/lbl.md` quantifies).
pub fn raymaps(scene: &Scene, geom: &LatticeGeom, rays: u32, env_lights: u32, step: f32, seed: u64) -> Vec<RayInit> {
    let (lo, hi) = (geom.min(), geom.max());
    let centre = 0.5 * (lo + hi);
    let radius = 0.5 * (hi - lo).length();
    let mut rng = Pcg32::new(seed, 0x1b1);
    let m = (rays as f32).sqrt().ceil().max(1.0) as u32;
    let mut out = Vec::new();
    // Start a ray where it enters the lattice (or at its origin from inside), backed off by a
    // random fraction of a step.
    let push = |out: &mut Vec<RayInit>, o: Vec3, d: Vec3, power: Vec3, from_inside: bool, rng: &mut Pcg32| {
        let start = if from_inside {
            Some(o)
        } else {
            ray_box(o, d, lo, hi).filter(|(_, t1)| *t1 > 0.0).map(|(t0, _)| o + d * t0.max(0.0))
        };
        if let Some(s) = start {
            let s = s - d * (rng.next_f32() * step);
            out.push(RayInit {
                pos_steps: [s.x, s.y, s.z, 0.0],
                dir_alive: [d.x, d.y, d.z, 1.0],
                power: [power.x, power.y, power.z, power.max_element()],
            });
        }
    };
    let directional = |out: &mut Vec<RayInit>, dir: Vec3, e: Vec3, n: u32, rng: &mut Pcg32| {
        let (b1, b2) = crate::physics::phase::orthonormal_basis(dir);
        let side = 2.0 * radius;
        let per = e * (side * side / (n * n) as f32);
        for i in 0..n {
            for j in 0..n {
                let u = (i as f32 + rng.next_f32()) / n as f32 - 0.5;
                let v = (j as f32 + rng.next_f32()) / n as f32 - 0.5;
                let o = centre - dir * (radius * 1.01) + b1 * (u * side) + b2 * (v * side);
                push(out, o, dir, per, false, rng);
            }
        }
    };
    for light in &scene.lights {
        match light {
            Light::Point { position, intensity } => {
                let to_c = centre - *position;
                let dist = to_c.length();
                let inside = dist <= radius;
                // Solid angle covered: the whole sphere from inside, else the bounding cone.
                let cos_max = if inside { -1.0 } else { (1.0 - (radius / dist).powi(2)).max(0.0).sqrt() };
                let omega = 2.0 * std::f32::consts::PI * (1.0 - cos_max);
                let axis = if inside { Vec3::Z } else { to_c / dist };
                let (b1, b2) = crate::physics::phase::orthonormal_basis(axis);
                let per = *intensity * (omega / (m * m) as f32);
                let from_inside = position.cmpge(lo).all() && position.cmple(hi).all();
                for i in 0..m {
                    for j in 0..m {
                        // Stratified, uniform in solid angle over the cap cos_theta >= cos_max.
                        let u = (i as f32 + rng.next_f32()) / m as f32;
                        let v = (j as f32 + rng.next_f32()) / m as f32;
                        let ct = 1.0 - u * (1.0 - cos_max);
                        let st = (1.0 - ct * ct).max(0.0).sqrt();
                        let phi = 2.0 * std::f32::consts::PI * v;
                        let d = (b1 * (st * phi.cos()) + b2 * (st * phi.sin()) + axis * ct).normalize();
                        push(&mut out, *position, d, per, from_inside, &mut rng);
                    }
                }
            }
            Light::Directional { direction, irradiance } => {
                directional(&mut out, direction.normalize(), *irradiance, m, &mut rng)
            }
            Light::Environment { radiance } => {
                let k = env_lights.max(1);
                let n = ((m * m / k) as f32).sqrt().ceil().max(8.0) as u32;
                for i in 0..k {
                    let z = 1.0 - (2.0 * i as f32 + 1.0) / k as f32;
                    let r = (1.0 - z * z).max(0.0).sqrt();
                    let phi = 2.399_963_2 * i as f32;
                    let d = Vec3::new(r * phi.cos(), r * phi.sin(), z);
                    directional(&mut out, d, *radiance * (4.0 * std::f32::consts::PI / k as f32), n, &mut rng);
                }
            }
        }
    }
    out
}

/// Parsed knobs.
#[derive(Clone, Debug)]
pub struct LblSettings {
    pub rays: u32,
    pub k: u32,
    pub step: f32,
    pub grid: u32,
    pub block: u32,
    pub block_steps: u32,
    pub iters_per_round: u32,
    pub tol: f32,
    pub max_iters: u32,
    pub threshold: f32,
    pub env_lights: u32,
    pub lattice: Lattice,
    pub deterministic: bool,
    pub schedule: Schedule,
    pub view: ViewSettings,
    /// Initial guess of the lattice iteration: `None` (cold: from the deposits alone) or the
    /// wavefront solver's field (`lbl.warm_start=wavefront`, its knobs as `lbl.wavefront_*`).
    pub warm_start: Option<WavefrontSettings>,
}

impl LblSettings {
    pub fn parse(req: &RenderRequest) -> Result<LblSettings, SolverError> {
        let s = req.settings;
        let grid: u32 = s.get("lbl", "grid", 64)?;
        let bad = |key: &str, reason: String| SolverError::Setting { key: format!("lbl.{key}"), reason };
        if !(2..=512).contains(&grid) {
            return Err(bad("grid", format!("{grid} must lie in 2..=512")));
        }
        let geom = LatticeGeom::new(req.scene, grid);
        let lattice: Lattice = s.get("lbl", "lattice", Lattice::D3q6)?;
        let block: u32 = s.get("lbl", "block", 4)?;
        if ![2, 4, 8].contains(&block) {
            return Err(bad(
                "block",
                format!("{block}: block edge must be 2, 4 or 8 (a power of two for the workgroup reduction)"),
            ));
        }
        let out = LblSettings {
            rays: s.get("lbl", "rays", 65536)?,
            k: s.get("lbl", "k", 16)?,
            step: s.get("lbl", "step", geom.lambda * 0.5)?,
            grid,
            block,
            block_steps: s.get("lbl", "block_steps", block)?,
            iters_per_round: s.get("lbl", "iters_per_round", 8)?,
            tol: s.get("lbl", "tol", 1e-4)?,
            max_iters: s.get("lbl", "max_iters", 20000)?,
            threshold: s.get("lbl", "threshold", 1e-4)?,
            env_lights: s.get("lbl", "env_lights", 14)?,
            lattice,
            deterministic: s.get("lbl", "deterministic", false)?,
            schedule: s.get("lbl", "schedule", Schedule::Concurrent)?,
            view: ViewSettings::parse(s, "lbl", "view_", req.scene)?,
            warm_start: match s.get("lbl", "warm_start", "none".to_string())?.as_str() {
                "none" => None,
                "wavefront" => Some(WavefrontSettings::parse(s, "lbl", "wavefront_")?),
                other => return Err(bad("warm_start", format!("unknown warm start {other:?}; use none or wavefront"))),
            },
        };
        if out.warm_start.is_some() && out.lattice != Lattice::D3q6 {
            return Err(bad(
                "warm_start",
                "the wavefront warm start is built for the d3q6 lattice; use lbl.lattice=d3q6".into(),
            ));
        }
        if out.rays == 0 || out.rays > 1 << 22 {
            return Err(bad("rays", format!("{} must lie in 1..=4194304", out.rays)));
        }
        if !(1..=256).contains(&out.k) {
            return Err(bad("k", format!("{} must lie in 1..=256", out.k)));
        }
        if !(out.step.is_finite() && out.step > 0.0 && out.step <= 4.0 * geom.lambda) {
            return Err(bad(
                "step",
                format!("{} must be positive and at most 4 voxels ({})", out.step, 4.0 * geom.lambda),
            ));
        }
        if !(1..=64).contains(&out.block_steps) {
            return Err(bad("block_steps", format!("{} must lie in 1..=64", out.block_steps)));
        }
        if out.iters_per_round == 0 || out.max_iters == 0 {
            return Err(bad("iters_per_round/max_iters", "must be at least 1".into()));
        }
        if !(out.tol > 0.0 && out.tol < 1.0) || !(out.threshold > 0.0 && out.threshold < 1.0) {
            return Err(bad("tol/threshold", "must lie in (0, 1)".into()));
        }
        Ok(out)
    }
}

/// Energy bookkeeping of the lattice, per channel (W, summed in double precision).
#[derive(Clone, Debug, Default, Serialize)]
pub struct EnergyBook {
    pub injected: [f64; 3],
    pub absorbed: [f64; 3],
    pub leaked: [f64; 3],
    pub remaining: [f64; 3],
}

impl EnergyBook {
    /// |injected - absorbed - leaked - remaining| / injected, worst channel.
    pub fn imbalance(&self) -> f64 {
        (0..3)
            .map(|c| {
                let inj = self.injected[c];
                if inj <= 0.0 {
                    0.0
                } else {
                    (inj - self.absorbed[c] - self.leaked[c] - self.remaining[c]).abs() / inj
                }
            })
            .fold(0.0, f64::max)
    }
}

/// Everything `lbl` measured, beside the image.
#[derive(Clone, Debug, Serialize)]
pub struct LblStats {
    pub lattice: LatticeGeom,
    pub channels: u32,
    pub rays: u32,
    pub rounds: u32,
    pub iterations: u32,
    pub converged: bool,
    pub final_change: f64,
    pub energy: EnergyBook,
    pub schedule: Schedule,
    pub deterministic: bool,
    /// Bytes of every lattice, ray and history buffer (what grey media save by one channel).
    pub device_bytes: u64,
    /// GPU time of the lattice steps alone, for the voxel-update throughput.
    pub diffuse_ms: f64,
    /// The iteration started from the wavefront solution (the energy book then does not
    /// balance: the seeded residual is signed).
    pub warm_start: bool,
}

/// The lattice's time-integrated energy and stats, without the view pass (for tests of the
/// diffusion itself and for warm starts).
pub struct LatticeResult {
    pub irradiance: Vec<f32>,
    pub irradiance_buffer: Buffer,
    pub stats: LblStats,
}

/// The lattice and its diffusion passes: state ping-pong, time-integrated energy, tallies.
pub struct Diffuser {
    pipeline: crate::gpu::Pipeline,
    density: Buffer,
    states: [Buffer; 2],
    irr: Buffer,
    tally: Buffer,
    push: DiffusePush,
    groups: [u32; 3],
    block_steps: u32,
    dims: [u32; 3],
    nch: u32,
    lattice: Lattice,
    /// The state the next step reads (and injection adds to).
    pub cur: usize,
    pub iterations: u32,
}

impl Diffuser {
    /// A zero lattice over `density` (one value per voxel). `medium` = (sigma_t rgb, albedo
    /// rgb, g), `lambda` the voxel edge in scene units.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        gpu: &Gpu,
        spec: &[(u32, Spec)],
        density: Buffer,
        dims: [u32; 3],
        nch: u32,
        lattice: Lattice,
        medium: ([f32; 3], [f32; 3], f32),
        lambda: f32,
        block: u32,
        block_steps: u32,
    ) -> Result<Diffuser, SolverError> {
        let v: u64 = dims.iter().map(|d| *d as u64).product();
        let info = gpu.info();
        let block_voxels = (block as u64).pow(3);
        let shared_bytes = (lattice.links() as u64 + 2) * nch as u64 * block_voxels * 4;
        if shared_bytes > info.max_compute_shared_memory as u64
            || block_voxels > info.max_compute_workgroup_invocations as u64
        {
            return Err(SolverError::Setting {
                key: "lbl.block".into(),
                reason: format!(
                    "block {block} with {:?} and {nch} channel(s) needs {shared_bytes} bytes of shared memory and {block_voxels} invocations; this device offers {} and {}; use a smaller block",
                    lattice, info.max_compute_shared_memory, info.max_compute_workgroup_invocations
                ),
            });
        }
        let mut spec = spec.to_vec();
        spec.extend_from_slice(&[
            (SPEC_NCH, Spec::U32(nch)),
            (SPEC_BLOCK, Spec::U32(block)),
            (SPEC_WG, Spec::U32(block)),
            (SPEC_LINKS, Spec::U32(lattice.links())),
        ]);
        let pipeline = gpu.pipeline(&shaders::LBL_DIFFUSE, &spec)?;
        let state_bytes = (lattice.links() as u64 + 1) * nch as u64 * v * 4;
        let groups = [0, 1, 2].map(|a| dims[a].div_ceil(block));
        let n_wg = groups.iter().map(|x| *x as u64).product::<u64>();
        let (st, al, g) = medium;
        Ok(Diffuser {
            pipeline,
            density,
            states: [gpu.buffer("lbl lattice state A", state_bytes)?, gpu.buffer("lbl lattice state B", state_bytes)?],
            irr: gpu.buffer("lbl irradiance", nch as u64 * v * 4)?,
            tally: gpu.buffer("lbl diffuse tally", n_wg * nch as u64 * 16)?,
            push: DiffusePush {
                dims: [dims[0], dims[1], dims[2], v as u32],
                sigma_t: [st[0], st[1], st[2], lambda],
                albedo: [al[0], al[1], al[2], g],
                inner_steps: 1,
                pad: [0; 3],
            },
            groups,
            block_steps,
            dims,
            nch,
            lattice,
            cur: 0,
            iterations: 0,
        })
    }

    pub fn state(&self) -> &Buffer {
        &self.states[self.cur]
    }

    pub fn device_bytes(&self) -> u64 {
        self.states[0].size() + self.states[1].size() + self.irr.size() + self.tally.size()
    }

    pub fn irradiance(&self) -> &Buffer {
        &self.irr
    }

    /// Passes for `count` more lattice steps, `block_steps` per dispatch.
    pub fn passes(&mut self, count: u32) -> Vec<Pass> {
        let mut passes = Vec::new();
        let mut left = count;
        while left > 0 {
            let inner = left.min(self.block_steps);
            let push = DiffusePush { inner_steps: inner, ..self.push };
            passes.push(
                Pass::new("lbl.diffuse", QueueRole::Diffuse, &self.pipeline)
                    .read(0, &self.density)
                    .read(1, &self.states[self.cur])
                    .write(2, &self.states[1 - self.cur])
                    .read_write(3, &self.irr)
                    .read_write(4, &self.tally)
                    .push(&push)
                    .groups(self.groups),
            );
            self.cur = 1 - self.cur;
            self.iterations += inner;
            left -= inner;
        }
        passes
    }

    /// Absorbed and leaked energy so far, and what is still moving, per channel.
    pub fn book(&self, gpu: &Gpu) -> Result<EnergyBook, SolverError> {
        let mut book = EnergyBook::default();
        let dt: Vec<[f32; 4]> = gpu.read_buffer_as(&self.tally)?;
        for (i, t) in dt.iter().enumerate() {
            book.absorbed[i % self.nch as usize] += t[0] as f64 - t[1] as f64;
            book.leaked[i % self.nch as usize] += t[2] as f64 - t[3] as f64;
        }
        book.remaining = lattice_content(&read_f32(gpu, self.state())?, self.dims, self.nch, self.lattice);
        Ok(book)
    }
}

/// Test bench for the lattice alone: unit energy deposited at `source` in a homogeneous
/// medium filling the whole lattice, `iterations` steps; returns the time-integrated energy
/// per voxel (one channel) and the energy book.
#[allow(clippy::too_many_arguments)]
pub fn diffuse_impulse(
    gpu: &Gpu,
    lattice: Lattice,
    dims: [u32; 3],
    sigma_t: f32,
    albedo: f32,
    g: f32,
    lambda: f32,
    block: u32,
    block_steps: u32,
    source: [u32; 3],
    iterations: u32,
) -> Result<(Vec<f32>, EnergyBook), SolverError> {
    let v: u64 = dims.iter().map(|d| *d as u64).product();
    let density = gpu.buffer_with("impulse density", &vec![1f32; v as usize])?;
    let mut d =
        Diffuser::new(gpu, &[], density, dims, 1, lattice, ([sigma_t; 3], [albedo; 3], g), lambda, block, block_steps)?;
    let src = (source[0] + dims[0] * (source[1] + dims[1] * source[2])) as u64;
    gpu.write_buffer(d.state(), src * 4, bytemuck::bytes_of(&1f32))?;
    let mut left = iterations;
    while left > 0 {
        let n = left.min(256);
        let passes = d.passes(n);
        let p = gpu.submit(QueueRole::Diffuse, &passes, &[])?;
        gpu.wait(p)?;
        left -= n;
    }
    let mut book = d.book(gpu)?;
    book.injected = [1.0, 0.0, 0.0];
    Ok((read_f32(gpu, d.irradiance())?, book))
}

fn read_f32(gpu: &Gpu, b: &Buffer) -> Result<Vec<f32>, SolverError> {
    Ok(gpu.read_buffer_as(b)?)
}

/// Run marching, transfer and diffusion to convergence.
pub fn run_lattice(
    gpu: &Gpu,
    scene: &Scene,
    gs: &GpuScene,
    set: &LblSettings,
    progress: &dyn Fn(u64, u64),
) -> Result<LatticeResult, SolverError> {
    let geom = LatticeGeom::new(scene, set.grid);
    let v = geom.voxels();
    // Model only what the scene requires: one channel when the medium and every light are grey.
    let grey_lights = scene.lights.iter().all(|l| is_grey(l.colour()));
    let nch: u32 = if gs.modelled.chromatic || !grey_lights { 3 } else { 1 };
    let info = gpu.info().clone();
    let state_bytes = (set.lattice.links() as u64 + 1) * nch as u64 * v * 4;
    if state_bytes > info.max_storage_buffer_range {
        return Err(SolverError::Setting {
            key: "lbl.grid".into(),
            reason: format!("a {}x{}x{} lattice with {nch} channel(s) needs {state_bytes} bytes per state buffer, over this device's maxStorageBufferRange {}; lower lbl.grid", geom.dims[0], geom.dims[1], geom.dims[2], info.max_storage_buffer_range),
        });
    }
    // Float atomics are the fast path where the device has them; fixed point is deterministic.
    let fixed = set.deterministic || !info.float_atomics;

    let spec_lattice = |extra: &[(u32, Spec)]| {
        let mut s = gs.modelled.spec();
        s.push((SPEC_NCH, Spec::U32(nch)));
        s.extend_from_slice(extra);
        s
    };
    let p_resample = gpu.pipeline(&shaders::LBL_RESAMPLE, &gs.modelled.spec())?;
    let p_march = gpu.pipeline(&shaders::LBL_MARCH, &gs.modelled.spec())?;
    let p_transfer = gpu.pipeline(
        if fixed { &shaders::LBL_TRANSFER_FIXED } else { &shaders::LBL_TRANSFER_FLOAT },
        &spec_lattice(&[]),
    )?;
    let p_inject = gpu.pipeline(&shaders::LBL_INJECT, &spec_lattice(&[(SPEC_FIXED, Spec::Bool(fixed))]))?;
    let dims4 = [geom.dims[0], geom.dims[1], geom.dims[2], v as u32];
    let origin4 = [geom.origin[0], geom.origin[1], geom.origin[2], geom.lambda];
    let density = gpu.buffer("lbl density", v * 4)?;
    let p = gs
        .bind(Pass::new("lbl.resample", QueueRole::Trace, &p_resample))
        .write(3, &density)
        .push(&GeomPush { dims: dims4, origin: origin4 })
        .cover(geom.dims);
    let pt = gpu.submit(QueueRole::Trace, &[p], &[])?;
    gpu.wait(pt)?;

    let rays = raymaps(scene, &geom, set.rays, set.env_lights, set.step, scene.render.seed);
    let ray_count = rays.len() as u32;
    if ray_count == 0 {
        return Err(SolverError::Unsupported("lbl: no light ray reaches the medium's box; check the lights".into()));
    }
    let total_power: f64 = (0..3).map(|c| rays.iter().map(|r| r.power[c] as f64).sum::<f64>()).fold(0.0, f64::max);
    let ray_buf = gpu.buffer_with("lbl rays", &rays)?;
    let rhb = gpu.buffer("lbl ray history", ray_count as u64 * set.k as u64 * 16)?;
    let accum = gpu.buffer("lbl transfer sums", nch as u64 * v * 4)?;
    let m = &scene.medium;
    let mut lattice = Diffuser::new(
        gpu,
        &gs.modelled.spec(),
        density.clone(),
        geom.dims,
        nch,
        set.lattice,
        (m.sigma_t.to_array(), m.albedo.to_array(), m.g),
        geom.lambda,
        set.block,
        set.block_steps,
    )?;
    let inject_wg = v.div_ceil(64);
    let inject_tally = gpu.buffer("lbl inject tally", inject_wg * nch as u64 * 8)?;

    let diag = (geom.max() - geom.min()).length();
    let max_steps = (diag / set.step).ceil() as u32 + 2;
    let rounds = max_steps.div_ceil(set.k);
    // Scale of the fixed-point transfer: a voxel's sum within a round never exceeds the total.
    let scale = if total_power > 0.0 { ((1u64 << 30) as f64 / total_power) as f32 } else { 1.0 };
    let inject = |lattice: &Diffuser| {
        Pass::new("lbl.inject", QueueRole::Diffuse, &p_inject)
            .read_write(0, &accum)
            .read_write(1, lattice.state())
            .read_write(2, &inject_tally)
            .push(&InjectPush { voxels: v as u32, inv_scale: 1.0 / scale, pad: [0; 2] })
            .cover([v as u32, 1, 1])
    };

    let steps = plan(rounds, set.schedule);
    let mut points: Vec<SyncPoint> = Vec::with_capacity(steps.len());
    // A warm start needs the whole deposit s before the iteration starts from the guess, so
    // the rounds only march and transfer (the sums accumulate until one injection).
    let warm = set.warm_start.is_some();
    progress(0, rounds as u64 + 1);
    for st in &steps {
        let waits: Vec<SyncPoint> = st.waits.iter().map(|w| points[*w]).collect();
        if warm && matches!(st.step, Step::Diffuse(_)) {
            // Nothing waits on a diffusion step: keep the plan's indices with a stand-in.
            points.push(*points.last().expect("a diffusion step follows a transfer"));
            continue;
        }
        let passes = match st.step {
            Step::March(_) => vec![gs
                .bind(Pass::new("lbl.march", QueueRole::Trace, &p_march))
                .read_write(3, &ray_buf)
                .write(4, &rhb)
                .push(&MarchPush {
                    dims: [geom.dims[0], geom.dims[1], geom.dims[2], ray_count],
                    origin: origin4,
                    step: set.step,
                    threshold: set.threshold,
                    k: set.k,
                    max_steps,
                })
                .cover([ray_count, 1, 1])],
            Step::Transfer(_) => {
                let mut p = vec![Pass::new("lbl.transfer", QueueRole::Diffuse, &p_transfer)
                    .read(0, &rhb)
                    .read_write(1, &accum)
                    .push(&TransferPush { entries: ray_count * set.k, voxels: v as u32, scale, pad: 0 })
                    .cover([ray_count * set.k, 1, 1])];
                if !warm {
                    p.push(inject(&lattice));
                }
                p
            }
            Step::Diffuse(_) => lattice.passes(set.iters_per_round),
        };
        let point = gpu.submit(st.role, &passes, &waits)?;
        points.push(point);
        if let Step::Transfer(n) = st.step {
            progress(n as u64 + 1, rounds as u64 + 1);
        }
    }

    if let Some(ws) = &set.warm_start {
        warm_start(gpu, scene, gs, ws, &geom, nch, &mut lattice, &inject)?;
    }

    // Iterate to convergence: relative change of the time-integrated energy at sparse probes.
    let dens_host = read_f32(gpu, &density)?;
    let stride = 4usize.max((geom.dims.iter().copied().max().unwrap_or(1) / 8) as usize);
    let mut probes: Vec<usize> = Vec::new();
    for z in (stride / 2..geom.dims[2] as usize).step_by(stride) {
        for y in (stride / 2..geom.dims[1] as usize).step_by(stride) {
            for x in (stride / 2..geom.dims[0] as usize).step_by(stride) {
                let i = x + geom.dims[0] as usize * (y + geom.dims[1] as usize * z);
                if dens_host[i] > 0.0 {
                    probes.push(i);
                }
            }
        }
    }
    if probes.is_empty() {
        probes = (0..v as usize).filter(|i| dens_host[*i] > 0.0).collect();
    }
    let irr = lattice.irradiance().clone();
    let probe_sum = |irr_host: &[f32]| -> Vec<f64> {
        probes.iter().map(|p| (0..nch as usize).map(|c| irr_host[c * v as usize + p] as f64).sum()).collect()
    };
    let chunk = 8 * set.block_steps;
    let mut prev = probe_sum(&read_f32(gpu, &irr)?);
    let mut converged = false;
    let mut change = f64::INFINITY;
    while lattice.iterations < set.max_iters {
        let before = lattice.iterations;
        let passes = lattice.passes(chunk.min(set.max_iters - lattice.iterations));
        let point = gpu.submit(QueueRole::Diffuse, &passes, &[])?;
        gpu.wait(point)?;
        let now = probe_sum(&read_f32(gpu, &irr)?);
        let done = (lattice.iterations - before) as f64;
        // Largest relative change per iteration over the probes that hold energy.
        change =
            now.iter().zip(&prev).filter(|(n, _)| **n > 0.0).map(|(n, p)| (n - p).abs() / n / done).fold(0.0, f64::max);
        prev = now;
        if change < set.tol as f64 {
            converged = true;
            break;
        }
    }
    gpu.wait_idle_roles()?;
    progress(rounds as u64 + 1, rounds as u64 + 1);

    // Energy bookkeeping: injected = absorbed + leaked + what is still moving in the lattice.
    let mut book = lattice.book(gpu)?;
    let it: Vec<[f32; 2]> = gpu.read_buffer_as(&inject_tally)?;
    for (i, t) in it.iter().enumerate() {
        book.injected[i % nch as usize] += t[0] as f64 - t[1] as f64;
    }
    if nch == 1 {
        for b in [&mut book.injected, &mut book.absorbed, &mut book.leaked, &mut book.remaining] {
            b[1] = b[0];
            b[2] = b[0];
        }
    }
    let irradiance = read_f32(gpu, &irr)?;
    let device_bytes =
        density.size() + ray_buf.size() + rhb.size() + accum.size() + inject_tally.size() + lattice.device_bytes();
    Ok(LatticeResult {
        irradiance,
        irradiance_buffer: irr,
        stats: LblStats {
            lattice: geom,
            channels: nch,
            rays: ray_count,
            rounds,
            iterations: lattice.iterations,
            converged,
            final_change: change,
            energy: book,
            schedule: set.schedule,
            deterministic: fixed,
            device_bytes,
            diffuse_ms: 0.0,
            warm_start: warm,
        },
    })
}

/// Start the lattice iteration from the wavefront solution (wavefront paper, section 1.1:
/// "an initial guess for an iterative solver"). The lattice's time-integrated field F is the
/// fixed point of F = s + M F (s: all deposits, M: one lattice step), and running the lattice
/// from the deposits alone is the Jacobi iteration from F = 0. From a guess G instead,
///   F_n = sum_{t<n} M^t s + M^n G = G + sum_{t<n} M^t (s + M G - G),
/// so the lattice is seeded with the residual r = s + M G - G and its accumulated irradiance
/// with that of G (one lattice step on G produces both M G and G's irradiance). G comes from
/// the wavefront's multiply scattered fluence and flux on the same grid: per D3Q6 link i
/// (unit vector e_i) G_i = lambda^2 (phi / 6 + E.e_i / 2), which gives back phi lambda^2 as the
/// summed arrivals and E lambda^2 as their net flow; |E| <= phi / 3 keeps G_i >= 0. The
/// residual is signed, so the absorbed/leaked tallies no longer balance the deposits: the
/// energy book is not kept under a warm start.
#[allow(clippy::too_many_arguments)]
fn warm_start(
    gpu: &Gpu,
    scene: &Scene,
    gs: &GpuScene,
    ws: &WavefrontSettings,
    geom: &LatticeGeom,
    nch: u32,
    lattice: &mut Diffuser,
    inject: impl Fn(&Diffuser) -> Pass,
) -> Result<(), SolverError> {
    let vol = wave_volume(gpu, scene, gs, ws, Some(*geom))?;
    let wf: Vec<f32> = gpu.read_buffer_as(&vol.energy)?;
    let v = geom.voxels() as usize;
    let wc = vol.channels as usize;
    let links = Lattice::D3q6.dirs();
    let mut g = vec![0f32; 7 * nch as usize * v];
    for c in 0..nch as usize {
        let cw = c.min(wc - 1);
        for x in 0..v {
            let phi = wf[cw * v + x];
            let e = [0, 1, 2].map(|a| wf[wc * v + (3 * cw + a) * v + x]);
            for (i, d) in links.iter().enumerate().skip(1) {
                let flow = e[0] * d[0] as f32 + e[1] * d[1] as f32 + e[2] * d[2] as f32;
                g[(i * nch as usize + c) * v + x] = (phi / 6.0 + flow / 2.0).max(0.0);
            }
        }
    }
    gpu.write_buffer(lattice.state(), 0, bytemuck::cast_slice(&g))?;
    // One step on G: the state becomes M G, the irradiance that of G.
    let mut passes = lattice.passes(1);
    // Then the deposits s join the rest distribution.
    passes.push(inject(lattice));
    let point = gpu.submit(QueueRole::Diffuse, &passes, &[])?;
    gpu.wait(point)?;
    let mut st: Vec<f32> = gpu.read_buffer_as(lattice.state())?;
    for (a, b) in st.iter_mut().zip(&g) {
        *a -= b;
    }
    gpu.write_buffer(lattice.state(), 0, bytemuck::cast_slice(&st))?;
    Ok(())
}

/// Energy still moving in a lattice state: every rest value, and every outgoing link whose
/// destination is inside (links leaving the lattice were tallied as leaked when produced).
pub fn lattice_content(state: &[f32], dims: [u32; 3], nch: u32, lattice: Lattice) -> [f64; 3] {
    let [nx, ny, nz] = dims.map(|d| d as i64);
    let v = (nx * ny * nz) as usize;
    let dirs: Vec<(i64, i64, i64)> = lattice.dirs().iter().map(|d| (d[0], d[1], d[2])).collect();
    let mut out = [0f64; 3];
    for c in 0..nch as usize {
        for (i, d) in dirs.iter().enumerate() {
            let base = (i * nch as usize + c) * v;
            for z in 0..nz {
                for y in 0..ny {
                    for x in 0..nx {
                        let (tx, ty, tz) = (x + d.0, y + d.1, z + d.2);
                        if i == 0 || (0..nx).contains(&tx) && (0..ny).contains(&ty) && (0..nz).contains(&tz) {
                            out[c] += state[base + (x + nx * (y + ny * z)) as usize] as f64;
                        }
                    }
                }
            }
        }
    }
    out
}

pub fn render(gpu: &Gpu, req: &RenderRequest) -> Result<RenderOutput, SolverError> {
    let scene = req.scene;
    let set = LblSettings::parse(req)?;
    req.settings.check_all_used("lbl")?;
    let gs = GpuScene::upload(gpu, scene, req.force_full)?;
    let mut lat = run_lattice(gpu, scene, &gs, &set, req.progress)?;
    let g = &lat.stats.lattice;
    let ms = MsVolume {
        energy: &lat.irradiance_buffer,
        dims: g.dims,
        channels: lat.stats.channels,
        origin: g.origin,
        lambda: g.lambda,
        flux: false,
    };
    let view = march_view(gpu, scene, &gs, &set.view, Some(&ms))?;
    let passes = gpu.take_timings();
    lat.stats.diffuse_ms = passes.iter().filter(|p| p.name == "lbl.diffuse").map(|p| p.duration_ms()).sum();
    let mut warnings = Vec::new();
    if !lat.stats.converged {
        warnings.push(format!(
            "lbl: the lattice did not converge in {} iterations (relative change {:.2e} per iteration, tolerance {:.1e}); raise lbl.max_iters or lbl.tol",
            lat.stats.iterations, lat.stats.final_change, set.tol
        ));
    }
    if view.nonfinite_pixels > 0 {
        warnings.push(format!(
            "{} pixels were not finite and were set to 0 (a bug: please report the scene)",
            view.nonfinite_pixels
        ));
    }
    let report = RenderReport {
        solver: SolverKind::Lbl,
        settings: json!({
            "rays": set.rays, "k": set.k, "step": set.step, "grid": set.grid, "lattice": set.lattice, "block": set.block,
            "block_steps": set.block_steps, "iters_per_round": set.iters_per_round, "tol": set.tol, "max_iters": set.max_iters,
            "threshold": set.threshold, "env_lights": set.env_lights, "deterministic": lat.stats.deterministic,
            "schedule": set.schedule, "view": set.view.json(),
            "warm_start": set.warm_start.as_ref().map(|w| w.json()),
        }),
        modelled: gs.modelled.clone(),
        device_bytes: gs.bytes + view.device_bytes + lat.stats.device_bytes,
        gpu_ms: super::gpu_ms(&passes),
        passes,
        stats: json!({ "lbl": lat.stats, "view_dispatches": view.dispatches }),
        warnings,
    };
    Ok(RenderOutput { image: view.image, variance: None, report })
}
