//! Shared part: the Lattice-Boltzmann lighting lattice (thesis 4.5, eq. 4.4-4.5; Geist et al.
//! 2004; section 2.2.3 for D3Q18), on a Cartesian voxel grid over the medium's box
//! ([`LatticeGeom`], which other parts use for their volumes too). [`Diffuser`] holds the
//! lattice state and runs its steps (glsl/lattice/diffuse.comp, blockwise), [`Injector`] moves
//! summed deposits into its rest distribution (glsl/lattice/inject.comp), and
//! [`Diffuser::iterate`] runs it to convergence. Used by `lbl`.

pub mod emission;
pub mod escape;
mod geom;
pub use geom::{max_reduced_sigma_t, GridRule, GridTrust, LatticeGeom, ShapeLimit, DOM_GRID, LBL_GRID};

use bytemuck::{Pod, Zeroable};
use serde::Serialize;

use crate::gpu::{Buffer, DeviceInfo, Gpu, Kernel, Pass, Pipeline, QueueRole, Spec, SpecKind};

use crate::scene::{Material, MAX_MATERIALS};
use crate::solvers::interface::Progress;
use crate::solvers::interface::SolverError;
use crate::solvers::parts::gpu_scene::table_block;

/// Specialisation constant ids of glsl/include/lattice.glsl and the lattice kernels.
pub const SPEC_NCH: u32 = 3;
const SPEC_BLOCK: u32 = 4;
const SPEC_WG: u32 = 5;
const SPEC_FIXED: u32 = 6;
pub const SPEC_LINKS: u32 = 7;
/// glsl/include/lattice.glsl's MATS: the voxels name their materials (several media).
const SPEC_MATS: u32 = 13;

/// The lattice's media on the device. The coefficients (sigma_t, albedo, g) come from the
/// scene block's material table (glsl/include/scene_block.glsl), the one route by which they
/// reach any kernel; the lattice adds, in a buffer of its own, each material's boundary
/// reflectance and, with several materials, the material of every voxel
/// (glsl/include/lattice.glsl). Shared by the diffusion and injection kernels.
pub struct LatticeMaterials {
    /// The scene block (its material table; entry 0 the medium's).
    pub scene: Buffer,
    /// Per material the reflectance of its surface for the links leaving it, then with
    /// `several` one u32 per voxel naming its material.
    pub buffer: Buffer,
    /// The voxels name their materials (the kernels' MATS).
    pub several: bool,
}

impl LatticeMaterials {
    /// `scene`: the scene block; `boundary_r`: per material of its table, the reflectance of
    /// its object's surface from inside for the lattice's links
    /// ([`crate::physics::dielectric::diffuse_fresnel`] at its index; 0: index-matched or
    /// none); `voxels`: each voxel's material, None for one medium.
    pub fn new(
        gpu: &Gpu,
        scene: &Buffer,
        boundary_r: [f32; MAX_MATERIALS],
        voxels: Option<&[u32]>,
    ) -> Result<LatticeMaterials, SolverError> {
        let mut bytes = bytemuck::cast_slice::<f32, u8>(&boundary_r).to_vec();
        match voxels {
            Some(v) => bytes.extend_from_slice(bytemuck::cast_slice(v)),
            None => bytes.extend_from_slice(&[0u8; 4]),
        }
        debug_assert_eq!(bytes.len() as u64, Self::bytes(voxels.map_or(0, |v| v.len() as u64), voxels.is_some()));
        Ok(LatticeMaterials {
            scene: scene.clone(),
            buffer: gpu.buffer_with("lattice materials", &bytes)?,
            several: voxels.is_some(),
        })
    }

    /// Device bytes for `voxels` voxels, with several materials or the stand-in (the scene
    /// block is its owner's).
    pub fn bytes(voxels: u64, several: bool) -> u64 {
        4 * MAX_MATERIALS as u64 + if several { 4 * voxels } else { 4 }
    }
}

/// The specialisation constants of lattice.glsl (channels, links), as kernels declare them.
pub const LATTICE_SPEC: &[(u32, SpecKind)] = &[(SPEC_NCH, SpecKind::U32), (SPEC_LINKS, SpecKind::U32)];

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct InjectPush {
    dims: [u32; 4],
    inv_scale: f32,
    directed: u32,
    pad: [u32; 2],
    /// The near ball of a point light inside the medium ([`LatticeParams::near`]): centre in
    /// voxel units from the lattice's min corner, radius in voxels (0: none).
    near: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct DiffusePush {
    dims: [u32; 4],
    /// Voxel edge, scene units.
    lambda: f32,
    inner_steps: u32,
    /// First-flight escape weights (D3Q6): 0 none, 1 at the box's faces, 2 also at zero density.
    escape: u32,
    /// 1: also integrate the net flux (vector irradiance) after the energy.
    flux: u32,
    /// 1: copy the time-integrated field to the snapshot before adding to it.
    snapshot: u32,
    /// Fraction of a link's carried light that drifts out per open face parallel to it
    /// ([`CONE_DRIFT`]; 0: off).
    drift: f32,
    /// [`CONE_DRIFT_PAIR`] with the drift, else 0.
    drift_pair: f32,
    /// 1: also integrate every link's outgoing value, after the energy and flux.
    links: u32,
}

/// Mean drift toward a face of light in a D3Q6 link parallel to it, per voxel of path:
/// E[max(0, -w_z)] over the cone of directions nearest +x (|w_x| >= |w_y|, |w_z|), for a
/// photon at a uniform depth in the voxel. A link stands for that cone, but moves only along
/// its axis; in a voxel with an open face this is the share of its light that the cone would
/// carry out through the face in one step (glsl/lattice/diffuse.comp, docs/lbl.md). With the
/// outward link (mean |w_z| 0.8312 over its cone), the six cones let (0.8312 + 4 x 0.1672) / 6 =
/// 1/4 of an isotropic population out per voxel of path: the partial current u c / 4. The
/// value is checked by quadrature in tests/lbl.rs.
pub const CONE_DRIFT: f32 = 0.1672;

/// What [`CONE_DRIFT`] counts twice along an edge, where a link has open faces on both axes
/// perpendicular to it: E[max(0, -w_y) max(0, -w_z)] over the +x cone, the share that could
/// leave through either (inclusion-exclusion: the link loses 2 x 0.1672 - 0.0260 per step).
/// Checked by quadrature in tests/lbl.rs.
pub const CONE_DRIFT_PAIR: f32 = 0.0260;

pub const DIFFUSE: Kernel = Kernel {
    shader: shader!("lattice/diffuse"),
    push_bytes: std::mem::size_of::<DiffusePush>(),
    spec: &[
        (SPEC_NCH, SpecKind::U32),
        (SPEC_BLOCK, SpecKind::U32),
        (SPEC_WG, SpecKind::U32),
        (SPEC_LINKS, SpecKind::U32),
        (SPEC_MATS, SpecKind::Bool),
    ],
};
/// The chunk's increment per channel, per workgroup (glsl/lattice/reduce.comp).
pub const REDUCE: Kernel = Kernel {
    shader: shader!("lattice/reduce"),
    push_bytes: std::mem::size_of::<ReducePush>(),
    spec: &[(SPEC_NCH, SpecKind::U32)],
};
/// The convergence test on the device (glsl/lattice/check.comp).
pub const CHECK: Kernel = Kernel {
    shader: shader!("lattice/check"),
    push_bytes: std::mem::size_of::<CheckPush>(),
    spec: &[(SPEC_NCH, SpecKind::U32)],
};

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ReducePush {
    voxels: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct CheckPush {
    voxels: u32,
    probes: u32,
    parts: u32,
    steps: u32,
    extrapolate: u32,
    init: u32,
    tol: f32,
    pad: u32,
}

/// The iteration's state on the device (glsl/lattice/check.comp's `Control`), read by the host
/// once per batch of chunks.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct Control {
    stopped: u32,
    checks: u32,
    have_inc: u32,
    prev_n: u32,
    have_x: u32,
    tail: u32,
    measured: u32,
    prev_measured: u32,
    change: f64,
    x_change: f64,
    prev_measure: f64,
    prev_inc: [f64; 4],
    r: [f64; 4],
    q: [f64; 4],
}

/// Fewest chunks (of about 8 steps) a submission carries when the test runs on the device: the
/// host waits at most once per 16 steps.
pub const CHUNKS_MIN: u32 = 2;
/// Most chunks a submission carries.
pub const CHUNKS_MAX: u32 = 64;
/// The GPU work a submission of chunks aims at, milliseconds (issue 42: 5-20 ms).
pub const BATCH_TARGET_MS: f64 = 12.0;
/// Threads of glsl/lattice/reduce.comp's workgroups.
const REDUCE_WG: u64 = 256;

/// The probe voxels of a lattice of `dims`: every `max(4, largest/8)`-th voxel on each axis
/// (from half a stride in), those of positive density; where none is, every voxel of positive
/// density. At most [`probe_capacity`] (more are thinned evenly).
pub fn probe_voxels(dims: [u32; 3], density: &[f32]) -> Vec<u32> {
    let [nx, ny, nz] = dims.map(|d| d as usize);
    let stride = 4usize.max(nx.max(ny).max(nz) / 8);
    let mut probes: Vec<u32> = Vec::new();
    for z in (stride / 2..nz).step_by(stride) {
        for y in (stride / 2..ny).step_by(stride) {
            for x in (stride / 2..nx).step_by(stride) {
                let i = x + nx * (y + ny * z);
                if density[i] > 0.0 {
                    probes.push(i as u32);
                }
            }
        }
    }
    if probes.is_empty() {
        probes = (0..nx * ny * nz).filter(|i| density[*i] > 0.0).map(|i| i as u32).collect();
    }
    let cap = probe_capacity(dims) as usize;
    if probes.len() > cap {
        let n = probes.len();
        probes = (0..cap).map(|k| probes[k * n / cap]).collect();
    }
    probes
}

/// Most probes of a lattice of `dims`: the sparse set's size, or up to 4096 for the
/// every-voxel fallback (bounded so the device buffers are a function of the lattice alone).
pub fn probe_capacity(dims: [u32; 3]) -> u64 {
    let [nx, ny, nz] = dims.map(|d| d as u64);
    let stride = 4u64.max(nx.max(ny).max(nz) / 8);
    let along = |n: u64| if n > stride / 2 { (n - stride / 2).div_ceil(stride) } else { 0 };
    let sparse = along(nx) * along(ny) * along(nz);
    sparse.max((nx * ny * nz).min(4096))
}

pub const INJECT: Kernel = Kernel {
    shader: shader!("lattice/inject"),
    push_bytes: std::mem::size_of::<InjectPush>(),
    spec: &[
        (SPEC_NCH, SpecKind::U32),
        (SPEC_FIXED, SpecKind::Bool),
        (SPEC_LINKS, SpecKind::U32),
        (SPEC_MATS, SpecKind::Bool),
    ],
};

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
    pub fn name(self) -> &'static str {
        match self {
            Lattice::D3q6 => "d3q6",
            Lattice::D3q18 => "d3q18",
        }
    }

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

    /// Bytes of one state buffer: every link and the rest, per channel and voxel.
    pub fn state_bytes(self, nch: u32, voxels: u64) -> u64 {
        (self.links() as u64 + 1) * nch as u64 * voxels * 4
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

/// Where a D3Q6 lattice scatters toward vacuum with the voxel's first-flight escape
/// probability (glsl/lattice/diffuse.comp) instead of one sixth.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Escape {
    /// Nowhere: six equal beams everywhere.
    None,
    /// At the faces of the lattice's box, where the medium is cut by its flat bounds.
    Box,
    /// Also toward zero-density voxels (a voxelised surface's staircase: too much).
    All,
}

impl Escape {
    fn code(self) -> u32 {
        match self {
            Escape::None => 0,
            Escape::Box => 1,
            Escape::All => 2,
        }
    }
}

impl std::str::FromStr for Escape {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "none" => Ok(Escape::None),
            "box" => Ok(Escape::Box),
            "all" => Ok(Escape::All),
            _ => Err(format!("unknown escape {s:?}; use none, box or all")),
        }
    }
}

/// How [`Diffuser::iterate`] ended.
#[derive(Clone, Debug)]
pub struct Iterated {
    pub converged: bool,
    /// The last relative change per iteration at the probes (of the extrapolated field when
    /// `tail` is some).
    pub change: f64,
    pub tail: Option<Tail>,
}

/// The extrapolated tail of a lattice iteration.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Tail {
    /// Decay of the increments per step, per channel.
    pub rho: [f64; 3],
    /// Share of the final energy (fluence, all channels) the tail added.
    pub share: f64,
}

/// Energy bookkeeping of the lattice, per channel (W, summed in double precision).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
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

/// Whether a block of edge `block` fits this device's shared memory and workgroup size with
/// `nch` channels of `lattice`; why not otherwise.
pub fn check_block(info: &DeviceInfo, lattice: Lattice, nch: u32, block: u32) -> Result<(), String> {
    let block_voxels = (block as u64).pow(3);
    // One channel's links and two reduction values per voxel: the kernel runs the channels in
    // turn through the same shared memory.
    let shared_bytes = (lattice.links() as u64 + 2) * block_voxels * 4;
    if shared_bytes > info.max_compute_shared_memory as u64
        || block_voxels > info.max_compute_workgroup_invocations as u64
    {
        return Err(format!(
            "block {block} with {:?} and {nch} channel(s) needs {shared_bytes} bytes of shared memory and \
                {block_voxels} invocations; this device offers {} and {}; use a smaller block",
            lattice, info.max_compute_shared_memory, info.max_compute_workgroup_invocations
        ));
    }
    Ok(())
}

/// What a lattice diffuses through.
#[derive(Clone, Copy, Debug)]
pub struct LatticeParams {
    pub dims: [u32; 3],
    pub nch: u32,
    pub lattice: Lattice,
    /// Voxel edge, scene units.
    pub lambda: f32,
    /// Block edge b (2, 4 or 8) and lattice steps per dispatch within a block (1: global).
    pub block: u32,
    pub block_steps: u32,
    /// First-flight escape weights at the medium's boundary (D3Q6; glsl/lattice/diffuse.comp).
    pub escape: Escape,
    /// D3Q6 with `escape`: light carried parallel to an open face drifts out through it
    /// ([`CONE_DRIFT`] per voxel of path).
    pub drift: bool,
    /// Inject the once-scattered light with its first moment g F (glsl/lattice/inject.comp):
    /// the deposit sums carry fluxes. Only for anisotropic media.
    pub directed: bool,
    /// Integrate the net flux (vector irradiance) beside the energy (glsl/lattice/diffuse.comp),
    /// for the view pass's two-term expansion. Only for anisotropic media.
    pub flux: bool,
    /// Integrate every link's outgoing value too (the state's time integral after the first
    /// step: rows after the energy and flux), which a warm start's guess takes as it is.
    pub links: bool,
    /// Extrapolate the geometric tail of the iteration ([`Diffuser::iterate`]).
    pub extrapolate: bool,
    /// Deposits within this ball (centre in voxel units from the lattice's min corner, radius
    /// in voxels) are not injected but tallied apart ([`Injector::near_energy`]): the once-
    /// scattered light around a point light, which `lbl` lumps into the light
    /// (`lbl.near_light`). None: every deposit is injected.
    pub near: Option<([f32; 3], f32)>,
}

impl LatticeParams {
    pub fn voxels(&self) -> u64 {
        self.dims.iter().map(|d| *d as u64).product()
    }
    /// Workgroups (blocks) per axis.
    fn groups(&self) -> [u32; 3] {
        [0, 1, 2].map(|a| self.dims[a].div_ceil(self.block))
    }
    /// Device bytes of a [`Diffuser`]: two states, the irradiance (and its snapshot with
    /// `extrapolate`), the per-block tallies.
    pub fn diffuser_bytes(&self) -> u64 {
        let n_wg = self.groups().iter().map(|x| *x as u64).product::<u64>();
        2 * self.lattice.state_bytes(self.nch, self.voxels())
            + self.irradiance_floats() * 4
            + if self.extrapolate { self.irradiance_floats() * 4 } else { 16 }
            + n_wg * self.nch as u64 * 16
            + self.check_bytes()
    }
    /// Device bytes of the convergence test on the device: its control record, the
    /// reduction's per-workgroup sums, the probes and their state (allocated whether or not the
    /// device runs the test, so the estimate is the device's).
    pub fn check_bytes(&self) -> u64 {
        let cap = probe_capacity(self.dims);
        super::feedback::Feedback::bytes(std::mem::size_of::<Control>() as u64)
            + self.voxels().div_ceil(REDUCE_WG) * self.nch as u64 * 8
            + 4 * cap
            + 16 * self.nch as u64 * cap
    }
    /// Floats of the time-integrated field: energy per channel and voxel, then with `flux` the
    /// flux (three per channel and voxel), then with `links` each link's (links per channel
    /// and voxel).
    pub fn irradiance_floats(&self) -> u64 {
        let links = if self.links { self.lattice.dirs().len() as u64 - 1 } else { 0 };
        self.nch as u64 * self.voxels() * (if self.flux { 4 } else { 1 } + links)
    }
    /// Device bytes of an [`Injector`]: its per-workgroup tallies (injected, and near the
    /// light).
    pub fn injector_bytes(&self) -> u64 {
        2 * self.voxels().div_ceil(64) * self.nch as u64 * 8
    }
}

/// The lattice and its diffusion passes: state ping-pong, time-integrated energy, tallies.
pub struct Diffuser {
    pipeline: Pipeline,
    density: Buffer,
    /// [`LatticeMaterials`]'s buffers: the scene block and the lattice's own (counted by their
    /// owners, not in [`Diffuser::device_bytes`]).
    scene: Buffer,
    materials: Buffer,
    states: [Buffer; 2],
    irr: Buffer,
    tally: Buffer,
    /// The field at the start of the last chunk (with `extrapolate`; else a stand-in).
    snap: Buffer,
    extrapolate: bool,
    /// The convergence test on the device: its control record (host-visible), the reduction's
    /// per-workgroup sums, the probe voxels and their state, and the two kernels.
    control: super::feedback::Feedback,
    partials: Buffer,
    probes: Buffer,
    probe_state: Buffer,
    /// (None where the device lacks double precision: the test runs on the host.)
    reduce: Option<Pipeline>,
    check: Option<Pipeline>,
    /// Chunks the next batch submits (adapted to the measured chunk time).
    chunks: u32,
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
    /// A zero lattice over `density` (one value per voxel, multiplying the extinction), of
    /// one medium (the material table's first entry), or, where `materials` has several, of the
    /// material each voxel names.
    pub fn new(
        gpu: &Gpu,
        density: Buffer,
        p: &LatticeParams,
        materials: &LatticeMaterials,
    ) -> Result<Diffuser, SolverError> {
        let v: u64 = p.dims.iter().map(|d| *d as u64).product();
        check_block(gpu.info(), p.lattice, p.nch, p.block).map_err(SolverError::Unsupported)?;
        let spec = [
            (SPEC_NCH, Spec::U32(p.nch)),
            (SPEC_BLOCK, Spec::U32(p.block)),
            (SPEC_WG, Spec::U32(p.block)),
            (SPEC_LINKS, Spec::U32(p.lattice.links())),
            (SPEC_MATS, Spec::Bool(materials.several)),
        ];
        let (scene, materials) = (materials.scene.clone(), materials.buffer.clone());
        let nch_spec = [(SPEC_NCH, Spec::U32(p.nch))];
        // The test's kernels use doubles: built only where the device has them.
        let (pipeline, reduce, check) = if gpu.info().float64 {
            let mut built = gpu.pipelines(&[(&DIFFUSE, &spec), (&REDUCE, &nch_spec), (&CHECK, &nch_spec)])?.into_iter();
            let mut next = || built.next().expect("three pipelines");
            (next(), Some(next()), Some(next()))
        } else {
            (gpu.pipeline(&DIFFUSE, &spec)?, None, None)
        };
        let cap = probe_capacity(p.dims);
        let state_bytes = p.lattice.state_bytes(p.nch, v);
        let groups = p.groups();
        let n_wg = groups.iter().map(|x| *x as u64).product::<u64>();
        let drift_on = p.drift && p.escape != Escape::None;
        Ok(Diffuser {
            pipeline,
            density,
            scene,
            materials,
            states: [gpu.buffer("lattice state A", state_bytes)?, gpu.buffer("lattice state B", state_bytes)?],
            irr: gpu.buffer("lattice irradiance", p.irradiance_floats() * 4)?,
            tally: gpu.buffer("lattice diffuse tally", n_wg * p.nch as u64 * 16)?,
            snap: gpu.buffer("lattice snapshot", if p.extrapolate { p.irradiance_floats() * 4 } else { 16 })?,
            extrapolate: p.extrapolate,
            control: super::feedback::Feedback::new(
                gpu,
                "lattice convergence control",
                std::mem::size_of::<Control>() as u64,
            )?,
            partials: gpu.buffer("lattice increment sums", v.div_ceil(REDUCE_WG) * p.nch as u64 * 8)?,
            probes: gpu.buffer("lattice probes", 4 * cap)?,
            // Per channel and probe, two doubles: the field and its extrapolation at the last check.
            probe_state: gpu.buffer("lattice probe state", 16 * p.nch as u64 * cap)?,
            reduce,
            check,
            chunks: CHUNKS_MIN,
            push: DiffusePush {
                dims: [p.dims[0], p.dims[1], p.dims[2], v as u32],
                lambda: p.lambda,
                inner_steps: 1,
                escape: p.escape.code(),
                flux: p.flux as u32,
                snapshot: 0,
                // The drift acts only with the escape weights (at the same open faces).
                drift: if drift_on { CONE_DRIFT } else { 0.0 },
                drift_pair: if drift_on { CONE_DRIFT_PAIR } else { 0.0 },
                links: p.links as u32,
            },
            groups,
            block_steps: p.block_steps,
            dims: p.dims,
            nch: p.nch,
            lattice: p.lattice,
            cur: 0,
            iterations: 0,
        })
    }

    pub fn state(&self) -> &Buffer {
        &self.states[self.cur]
    }

    /// Turn the tail extrapolation off for this lattice (it stays off where its parameters did
    /// not ask for it): for the cascadic and wavefront starts, whose tails extrapolated from
    /// the signed sums of their increments were measured off (cloud with the cascadic start,
    /// relL2 5e-3); not measured again since the sums are of magnitudes.
    pub fn plain(&mut self) {
        self.extrapolate = false;
    }

    pub fn device_bytes(&self) -> u64 {
        self.states[0].size()
            + self.states[1].size()
            + self.irr.size()
            + self.tally.size()
            + self.snap.size()
            + self.control.device_bytes()
            + self.partials.size()
            + self.probes.size()
            + self.probe_state.size()
    }

    /// The time-integrated energy per voxel and channel ([c * V + v]), then with
    /// [`LatticeParams::flux`] the flux ([nch V + (3 c + axis) V + v]).
    pub fn irradiance(&self) -> &Buffer {
        &self.irr
    }

    /// Passes for `count` more lattice steps, `block_steps` per dispatch.
    pub fn passes(&mut self, count: u32) -> Vec<Pass> {
        self.passes_from(count, false)
    }

    /// [`Diffuser::passes`], the first dispatch copying the field to the snapshot first when
    /// `snapshot` (for the tail extrapolation).
    fn passes_from(&mut self, count: u32, snapshot: bool) -> Vec<Pass> {
        let mut passes = Vec::new();
        let mut left = count;
        while left > 0 {
            let inner = left.min(self.block_steps);
            let push =
                DiffusePush { inner_steps: inner, snapshot: (snapshot && passes.is_empty()) as u32, ..self.push };
            passes.push(
                Pass::new("lattice.diffuse", QueueRole::Diffuse, &self.pipeline)
                    .read(0, &self.density)
                    .read(1, &self.states[self.cur])
                    .write(2, &self.states[1 - self.cur])
                    .read_write(3, &self.irr)
                    .read_write(4, &self.tally)
                    .write(5, &self.snap)
                    .read(6, &self.materials)
                    .read(7, self.control.record())
                    .read(8, &self.scene)
                    .push(&push)
                    .groups(self.groups),
            );
            self.cur = 1 - self.cur;
            self.iterations += inner;
            left -= inner;
        }
        passes
    }

    /// Run to convergence, checked at sparse probe voxels (every `max(4, dims/8)`-th voxel
    /// where `density` is > 0, or every such voxel when none falls on the sparse set) every 8
    /// dispatches (plain) or every dispatch that makes up about 8 steps (extrapolated), or
    /// until `max_iters` iterations in all.
    ///
    /// Plain: converged when the largest relative change per iteration of the time-integrated
    /// field F at the probes falls under `tol`. That stops with about tol / (1 - rho) of F
    /// still to come, rho the slowest mode's decay per step (1 - kappa_a, the absorption per
    /// step, in a homogeneous medium: 0.6% of the fluence at grid 64 and albedo 0.9).
    ///
    /// With [`LatticeParams::extrapolate`]: the lattice is a linear iteration F_n = sum_{t<n}
    /// M^t s, whose increments decay geometrically once the slowest mode dominates the energy
    /// in flight, so the rest of the sum is the last chunk's increment D times r / (1 - r),
    /// r = rho^chunk the ratio of consecutive chunks' increments (per channel, their magnitudes
    /// summed over the lattice: from zero the increments are never negative, and from a
    /// previous frame's field, whose residual is signed, the magnitudes still decay at the
    /// slowest surviving mode's rate where a signed sum can cancel). The criterion is then the change per iteration of that extrapolated field
    /// F + D r / (1 - r) at the probes: it converges at the rate at which the slower modes
    /// die out relative to the slowest, not at the absorption rate. At convergence the
    /// extrapolation is applied to the whole field (energy and flux). Where the ratio is not
    /// yet a decay (0 < r < 1 in every channel that moves), the plain criterion applies and
    /// nothing is extrapolated.
    ///
    /// Where the device has double precision the test runs on it (glsl/lattice/check.comp,
    /// the same arithmetic in the same order): a batch of chunks is one submission, the device
    /// stops stepping at the chunk that converged, and the host waits once per batch (at least
    /// [`CHUNKS_MIN`] chunks, more where a chunk takes less than [`BATCH_TARGET_MS`] /
    /// [`CHUNKS_MIN`]). Elsewhere it runs on the host, a wait and a readback of the energies
    /// per chunk.
    pub fn iterate(
        &mut self,
        gpu: &Gpu,
        density: &[f32],
        tol: f32,
        max_iters: u32,
        progress: &dyn Fn(Progress),
    ) -> Result<Iterated, SolverError> {
        if self.check.is_some() {
            self.iterate_on_device(gpu, density, tol, max_iters, progress)
        } else {
            self.iterate_on_host(gpu, density, tol, max_iters, progress)
        }
    }

    /// Steps per chunk: about 8, whole dispatches.
    fn chunk_steps(&self) -> u32 {
        if self.extrapolate {
            8u32.div_ceil(self.block_steps).max(1) * self.block_steps
        } else {
            8 * self.block_steps
        }
    }

    fn check_pass(&self, probes: u32, steps: u32, init: bool, tol: f32) -> Pass {
        let push = CheckPush {
            voxels: self.voxels() as u32,
            probes,
            parts: self.voxels().div_ceil(REDUCE_WG) as u32,
            steps,
            extrapolate: self.extrapolate as u32,
            init: init as u32,
            tol,
            pad: 0,
        };
        Pass::new("lattice.check", QueueRole::Diffuse, self.check.as_ref().expect("a device with doubles"))
            .read(0, &self.irr)
            .read(1, &self.snap)
            .read(2, &self.partials)
            .read(3, &self.probes)
            .read_write(4, &self.probe_state)
            .read_write(5, self.control.record())
            .push(&push)
            .groups([1, 1, 1])
    }

    fn reduce_pass(&self) -> Pass {
        Pass::new("lattice.reduce", QueueRole::Diffuse, self.reduce.as_ref().expect("a device with doubles"))
            .read(0, &self.irr)
            .read(1, &self.snap)
            .read(2, self.control.record())
            .write(3, &self.partials)
            .push(&ReducePush { voxels: self.voxels() as u32 })
            .groups([self.voxels().div_ceil(REDUCE_WG) as u32, 1, 1])
    }

    fn voxels(&self) -> u64 {
        self.dims.iter().map(|d| *d as u64).product()
    }

    /// [`Diffuser::iterate`] with the test on the device.
    fn iterate_on_device(
        &mut self,
        gpu: &Gpu,
        density: &[f32],
        tol: f32,
        max_iters: u32,
        progress: &dyn Fn(Progress),
    ) -> Result<Iterated, SolverError> {
        let probes = probe_voxels(self.dims, density);
        gpu.write_buffer(&self.probes, 0, bytemuck::cast_slice(&probes))?;
        let n_probes = probes.len() as u32;
        let chunk = self.chunk_steps();
        let report = |iteration: u32, measure: f64, last: Option<(f64, u32)>| {
            progress(Progress::converging(
                "lattice iterations",
                iteration as u64,
                measure,
                tol as f64,
                last.map(|(m, i)| (m, i as u64)),
                (max_iters - iteration) as u64,
            ));
        };
        let mut last_measure: Option<(f64, u32)> = None;
        let mut ctl = Control::default();
        // The first submission opens the control and records the probes' field at the start.
        let mut passes = vec![self.control.clear_pass(QueueRole::Diffuse), self.check_pass(n_probes, 0, true, tol)];
        while self.iterations < max_iters {
            let (cur0, iterations0, checks0) = (self.cur, self.iterations, ctl.checks);
            // (steps, dispatches) of each chunk submitted.
            let mut plan: Vec<(u32, usize)> = Vec::new();
            for _ in 0..self.chunks {
                let n = chunk.min(max_iters - self.iterations);
                if n == 0 {
                    break;
                }
                let steps = self.passes_from(n, self.extrapolate);
                plan.push((n, steps.len()));
                passes.extend(steps);
                if self.extrapolate {
                    passes.push(self.reduce_pass());
                }
                passes.push(self.check_pass(n_probes, n, false, tol));
            }
            passes.push(self.control.copy_pass(QueueRole::Diffuse));
            let started = std::time::Instant::now();
            let point = gpu.submit(QueueRole::Diffuse, &std::mem::take(&mut passes), &[])?;
            gpu.wait(point)?;
            ctl = self.control.read(gpu)?;
            // The chunks the device ran: those it judged (a stop skips the rest whole).
            let ran = (ctl.checks - checks0) as usize;
            if ran == 0 || ran > plan.len() || (ran < plan.len() && ctl.stopped == 0) {
                return Err(SolverError::Unsupported(format!(
                    "lbl: the device judged {ran} of {} chunks of a lattice batch; please report this",
                    plan.len()
                )));
            }
            self.cur = cur0;
            self.iterations = iterations0;
            for (n, dispatches) in &plan[..ran] {
                self.iterations += n;
                self.cur = (self.cur + dispatches) % 2;
            }
            let per_chunk = started.elapsed().as_secs_f64() * 1e3 / ran as f64;
            self.chunks = ((BATCH_TARGET_MS / per_chunk.max(1e-3)) as u32).clamp(CHUNKS_MIN, CHUNKS_MAX);
            let measure = if ctl.measured != 0 { ctl.x_change } else { ctl.change };
            // The estimate of the iterations left pairs two measures of one kind (with the
            // tail extrapolation, of the extrapolated field): the check before this batch's
            // last where it is of the kind, else the last batch's.
            let kind = |measured: u32| (measured == 1) || !self.extrapolate;
            if ran >= 2 && kind(ctl.prev_measured) && ctl.prev_measured != 2 {
                last_measure = Some((ctl.prev_measure, self.iterations - plan[ran - 1].0));
            }
            if kind(ctl.measured) {
                report(self.iterations, measure, last_measure);
                last_measure = Some((measure, self.iterations));
            } else {
                report(self.iterations, measure, None);
            }
            if ctl.stopped != 0 {
                // Stepping again later (a warm start's frames) starts from an open control.
                let done = plan[ran - 1].0 as f64;
                let (r, q) = (ctl.r, ctl.q);
                gpu.submit(QueueRole::Diffuse, &[self.control.clear_pass(QueueRole::Diffuse)], &[])?;
                if ctl.tail != 0 {
                    let q3 = [q[0], q[1], q[2]];
                    let tail = self.extrapolate_tail(gpu, q3)?;
                    let rho = [r[0], r[1], r[2]].map(|r| r.powf(1.0 / done));
                    return Ok(Iterated {
                        converged: true,
                        change: ctl.x_change,
                        tail: Some(Tail { rho, share: tail }),
                    });
                }
                return Ok(Iterated { converged: true, change: ctl.change, tail: None });
            }
        }
        let change = if self.iterations == 0 { f64::INFINITY } else { ctl.change };
        Ok(Iterated { converged: false, change, tail: None })
    }

    /// [`Diffuser::iterate`] with the test on the host.
    fn iterate_on_host(
        &mut self,
        gpu: &Gpu,
        density: &[f32],
        tol: f32,
        max_iters: u32,
        progress: &dyn Fn(Progress),
    ) -> Result<Iterated, SolverError> {
        let v = self.voxels() as usize;
        let probes: Vec<usize> = probe_voxels(self.dims, density).into_iter().map(|p| p as usize).collect();
        let nch = self.nch as usize;
        // Per channel and probe ([c P + i]): the field extrapolated by q[c] from its value
        // `before` (with q = 0, the field itself). Each channel is judged on its own: summed, a
        // slow channel holding little of the sum stopped early (glsl/lattice/check.comp).
        let probe_extrapolated = |irr: &[f32], before: &[f32], q: &[f64; 3]| -> Vec<f64> {
            (0..nch)
                .flat_map(|c| {
                    probes.iter().map(move |p| {
                        let (now, was) = (irr[c * v + p] as f64, before[c * v + p] as f64);
                        now + (now - was) * q[c]
                    })
                })
                .collect()
        };
        let probe_sum = |irr: &[f32]| probe_extrapolated(irr, irr, &[0.0; 3]);
        // Largest relative change per iteration over the probes that hold energy.
        let largest_change = |now: &[f64], prev: &[f64], done: f64| -> f64 {
            now.iter().zip(prev).filter(|(n, _)| **n > 0.0).map(|(n, p)| (n - p).abs() / n / done).fold(0.0, f64::max)
        };
        // The energies only: the probes never look at the flux after them.
        let irr = self.irr.clone();
        let energies = |gpu: &Gpu| -> Result<Vec<f32>, SolverError> {
            Ok(bytemuck::pod_collect_to_vec(&gpu.read_buffer_prefix(&irr, (nch * v * 4) as u64)?))
        };
        // Plain: a check every 8 dispatches. Extrapolated: every dispatch that makes up about 8
        // steps, since the criterion can stop as soon as the extrapolation settles (each check
        // reads the energies back).
        let chunk = self.chunk_steps();
        let mut prev = energies(gpu)?;
        let mut prev_probes = probe_sum(&prev);
        // The previous chunk's increment per channel and length, and the previous extrapolation.
        let mut prev_inc: Option<([f64; 3], u32)> = None;
        let mut prev_x: Option<Vec<f64>> = None;
        let mut change = f64::INFINITY;
        // The measure the stop is decided on (the extrapolated field's change once it has one)
        // and the iteration it was taken at: two give the rate of decay, hence an estimate of
        // the iterations left (a geometric decay, as the tail extrapolation assumes).
        let mut last_measure: Option<(f64, u32)> = None;
        let report = |iteration: u32, measure: f64, last: Option<(f64, u32)>| {
            progress(Progress::converging(
                "lattice iterations",
                iteration as u64,
                measure,
                tol as f64,
                last.map(|(m, i)| (m, i as u64)),
                (max_iters - iteration) as u64,
            ));
        };
        while self.iterations < max_iters {
            let before = self.iterations;
            let passes = self.passes_from(chunk.min(max_iters - self.iterations), self.extrapolate);
            let point = gpu.submit(QueueRole::Diffuse, &passes, &[])?;
            gpu.wait(point)?;
            let now = energies(gpu)?;
            let n = self.iterations - before;
            let done = n as f64;
            let now_probes = probe_sum(&now);
            change = largest_change(&now_probes, &prev_probes, done);
            if self.extrapolate {
                let mut inc = [0f64; 3];
                for (c, total) in inc.iter_mut().enumerate().take(nch) {
                    *total = now[c * v..(c + 1) * v]
                        .iter()
                        .zip(&prev[c * v..(c + 1) * v])
                        .map(|(a, b)| (a - b).abs() as f64)
                        .sum();
                }
                // The chunk ratio per channel, where both chunks had the same length.
                let ratio = prev_inc.filter(|(_, m)| *m == n).and_then(|(p, _)| {
                    let mut r = [0f64; 3];
                    for c in 0..nch {
                        if inc[c] == 0.0 && p[c] == 0.0 {
                            continue;
                        }
                        r[c] = inc[c] / p[c];
                        if !(r[c] > 0.0 && r[c] < 1.0) {
                            return None;
                        }
                    }
                    Some(r)
                });
                prev_inc = Some((inc, n));
                if let Some(r) = ratio {
                    let q = r.map(|r| r / (1.0 - r));
                    let x = probe_extrapolated(&now, &prev, &q);
                    let x_change = prev_x.as_ref().map(|px| largest_change(&x, px, done));
                    prev_x = Some(x);
                    if let Some(xc) = x_change {
                        report(self.iterations, xc, last_measure);
                        last_measure = Some((xc, self.iterations));
                    }
                    if let Some(xc) = x_change.filter(|xc| *xc < tol as f64) {
                        let tail = self.extrapolate_tail(gpu, q)?;
                        let rho = r.map(|r| r.powf(1.0 / done));
                        return Ok(Iterated { converged: true, change: xc, tail: Some(Tail { rho, share: tail }) });
                    }
                } else {
                    prev_x = None;
                }
            }
            prev = now;
            prev_probes = now_probes;
            if prev_x.is_none() {
                report(self.iterations, change, last_measure.filter(|_| !self.extrapolate));
                if !self.extrapolate {
                    last_measure = Some((change, self.iterations));
                }
            }
            if change < tol as f64 {
                return Ok(Iterated { converged: true, change, tail: None });
            }
        }
        Ok(Iterated { converged: false, change, tail: None })
    }

    /// Add the tail D q[c] to the whole field (energy and flux), D its increment since the
    /// snapshot; returns the share of the final energy the tail makes.
    fn extrapolate_tail(&self, gpu: &Gpu, q: [f64; 3]) -> Result<f64, SolverError> {
        let mut field = read_f32(gpu, &self.irr)?;
        let snap: Vec<f32> = bytemuck::pod_collect_to_vec(&gpu.read_buffer_prefix(&self.snap, self.irr.size())?);
        let v: usize = self.dims.iter().map(|d| *d as usize).product();
        let nch = self.nch as usize;
        let (mut added, mut total) = (0f64, 0f64);
        // Rows: energy per channel, then the flux's three axes per channel, then the links.
        let flux_rows = if self.push.flux != 0 { 3 * nch } else { 0 };
        let links = self.lattice.dirs().len() - 1;
        for (k, (f, s)) in field.iter_mut().zip(&snap).enumerate() {
            let row = k / v;
            let c = if row < nch {
                row
            } else if row < nch + flux_rows {
                (row - nch) / 3
            } else {
                (row - nch - flux_rows) / links
            };
            let t = (*f - *s) as f64 * q[c];
            if row < nch {
                added += t;
                total += *f as f64 + t;
            }
            *f = (*f as f64 + t) as f32;
        }
        gpu.write_buffer(&self.irr, 0, bytemuck::cast_slice(&field))?;
        Ok(if total > 0.0 { added / total } else { 0.0 })
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

/// Moves summed deposits (per channel and voxel: floats, or fixed point of `scale` quanta per
/// unit) into the lattice's rest distribution, or with [`LatticeParams::directed`] partly into
/// its axial links (their first moment), clears the sums, and tallies what it injected.
pub struct Injector {
    pipeline: Pipeline,
    /// [`LatticeMaterials`]'s buffers (the voxels' g).
    scene: Buffer,
    materials: Buffer,
    tally: Buffer,
    near_tally: Buffer,
    nch: u32,
    /// Fixed by the lattice's parameters: every injection pushes the same constants.
    push: InjectPush,
}

impl Injector {
    /// `materials`: as [`Diffuser::new`]'s (each voxel's g for the directed injection).
    pub fn new(
        gpu: &Gpu,
        p: &LatticeParams,
        fixed: bool,
        scale: f32,
        materials: &LatticeMaterials,
    ) -> Result<Injector, SolverError> {
        let spec = [
            (SPEC_NCH, Spec::U32(p.nch)),
            (SPEC_FIXED, Spec::Bool(fixed)),
            (SPEC_LINKS, Spec::U32(p.lattice.links())),
            (SPEC_MATS, Spec::Bool(materials.several)),
        ];
        Ok(Injector {
            scene: materials.scene.clone(),
            materials: materials.buffer.clone(),
            pipeline: gpu.pipeline(&INJECT, &spec)?,
            tally: gpu.buffer("lattice inject tally", p.injector_bytes() / 2)?,
            near_tally: gpu.buffer("lattice near-light tally", p.injector_bytes() / 2)?,
            nch: p.nch,
            push: InjectPush {
                dims: [p.dims[0], p.dims[1], p.dims[2], p.voxels() as u32],
                inv_scale: 1.0 / scale,
                directed: p.directed as u32,
                pad: [0; 2],
                near: p.near.map_or([0.0; 4], |(c, r)| [c[0], c[1], c[2], r]),
            },
        })
    }

    /// Inject `sums` into the lattice's current state.
    pub fn pass(&self, sums: &Buffer, lattice: &Diffuser) -> Pass {
        Pass::new("lattice.inject", QueueRole::Diffuse, &self.pipeline)
            .read_write(0, sums)
            .read_write(1, lattice.state())
            .read_write(2, &self.tally)
            .read_write(3, &self.near_tally)
            .read(4, &self.materials)
            .read(5, &self.scene)
            .push(&self.push)
            .cover_linear(self.push.dims[3])
    }

    /// Energy injected so far, per channel.
    pub fn injected(&self, gpu: &Gpu) -> Result<[f64; 3], SolverError> {
        self.sum(gpu, &self.tally)
    }

    /// Energy deposited in the near ball ([`LatticeParams::near`]) and held back, per channel.
    pub fn near_energy(&self, gpu: &Gpu) -> Result<[f64; 3], SolverError> {
        self.sum(gpu, &self.near_tally)
    }

    fn sum(&self, gpu: &Gpu, tally: &Buffer) -> Result<[f64; 3], SolverError> {
        let mut out = [0f64; 3];
        let it: Vec<[f32; 2]> = gpu.read_buffer_as(tally)?;
        for (i, t) in it.iter().enumerate() {
            out[i % self.nch as usize] += t[0] as f64 - t[1] as f64;
        }
        Ok(out)
    }

    pub fn device_bytes(&self) -> u64 {
        self.tally.size() + self.near_tally.size()
    }
}

/// Energy still moving in a lattice state: every rest value, and every outgoing link whose
/// destination is inside (links leaving the lattice were tallied as leaked when produced).
pub fn lattice_content(state: &[f32], dims: [u32; 3], nch: u32, lattice: Lattice) -> [f64; 3] {
    let [nx, ny, nz] = dims.map(|d| d as i64);
    let v = (nx * ny * nz) as usize;
    let dirs: Vec<(i64, i64, i64)> = lattice.dirs().iter().map(|d| (d[0], d[1], d[2])).collect();
    let mut out = [0f64; 3];
    for (c, total) in out.iter_mut().enumerate().take(nch as usize) {
        for (i, d) in dirs.iter().enumerate() {
            let base = (i * nch as usize + c) * v;
            for z in 0..nz {
                for y in 0..ny {
                    for x in 0..nx {
                        let (tx, ty, tz) = (x + d.0, y + d.1, z + d.2);
                        if i == 0 || (0..nx).contains(&tx) && (0..ny).contains(&ty) && (0..nz).contains(&tz) {
                            *total += state[base + (x + nx * (y + ny * z)) as usize] as f64;
                        }
                    }
                }
            }
        }
    }
    out
}

/// Test bench for the lattice alone: unit energy deposited at `source` in a homogeneous
/// medium filling the whole lattice (`medium`'s first channel, one channel), its boundary
/// reflecting `boundary_r` of what leaves, `iterations` steps; returns the time-integrated
/// energy per voxel and the energy book.
pub fn diffuse_impulse(
    gpu: &Gpu,
    p: &LatticeParams,
    (medium, boundary_r): (&Material, f32),
    source: [u32; 3],
    iterations: u32,
) -> Result<(Vec<f32>, EnergyBook), SolverError> {
    let dims = p.dims;
    let v: u64 = dims.iter().map(|d| *d as u64).product();
    let density = gpu.buffer_with("impulse density", &vec![1f32; v as usize])?;
    let p = LatticeParams { nch: 1, ..*p };
    // The kernels read the medium from a scene block's material table, as in a render.
    let scene = gpu.buffer_with("impulse material table", bytemuck::bytes_of(&table_block(&[*medium])))?;
    let mut reflect = [0.0; MAX_MATERIALS];
    reflect[0] = boundary_r;
    let mut d = Diffuser::new(gpu, density, &p, &LatticeMaterials::new(gpu, &scene, reflect, None)?)?;
    let src = (source[0] + dims[0] * (source[1] + dims[1] * source[2])) as u64;
    gpu.write_buffer(d.state(), src * 4, bytemuck::bytes_of(&1f32))?;
    let mut left = iterations;
    while left > 0 {
        let n = left.min(256);
        let passes = d.passes(n);
        let point = gpu.submit(QueueRole::Diffuse, &passes, &[])?;
        gpu.wait(point)?;
        left -= n;
    }
    let mut book = d.book(gpu)?;
    book.injected = [1.0, 0.0, 0.0];
    Ok((read_f32(gpu, d.irradiance())?, book))
}

pub(crate) fn read_f32(gpu: &Gpu, b: &Buffer) -> Result<Vec<f32>, SolverError> {
    Ok(gpu.read_buffer_as(b)?)
}
