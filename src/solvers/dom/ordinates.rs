//! Discrete-ordinates sweeps on the device (issue 13's propagation, thesis 5.2-5.3): the part
//! the `dom` solver is built on, checked against the CPU oracle `physics::ordinates`.
//!
//! In-core: the whole grid and one field per direction live on the device. The eight octants
//! are swept together plane by plane (i + j + k = w in each one's own coordinates, one dispatch
//! per plane, glsl/ordinates/sweep.comp), each octant's directions in turn per invocation into
//! its own fluence slice, so the fluence sums in a fixed order (deterministic, no atomics).
//! The emission is stored at M storage directions and upsampled to the N swept ones
//! (`physics::angular`); after each channel's sweep, glsl/ordinates/scatter.comp turns the
//! field into the source the next sweep propagates (what this one scattered: the thesis's
//! progressive scheme, 5.3.3) and adds the light it scatters toward the camera, on the device.
//! glsl/ordinates/deposit.comp bins the marched first-scattering deposits into the storage
//! directions.

use bytemuck::{Pod, Zeroable};

use crate::gpu::{Buffer, Gpu, Kernel, Pass, Pipeline, QueueRole};
use crate::physics::angular::StorageMap;
use crate::physics::ordinates::{characteristic_geometry, Scheme};
use crate::physics::quadrature::Quadrature;
use crate::solvers::parts::gpu_scene::GpuScene;
use crate::solvers::parts::marching::Beam;
use crate::solvers::parts::resumable::LOOP_GUARD;

use crate::solvers::interface::SolverError;

pub const SWEEP: Kernel =
    Kernel { shader: shader!("ordinates/sweep"), push_bytes: std::mem::size_of::<SweepPush>(), spec: &[] };
pub const SCATTER: Kernel =
    Kernel { shader: shader!("ordinates/scatter"), push_bytes: std::mem::size_of::<ScatterPush>(), spec: &[] };
pub const DEPOSIT: Kernel =
    Kernel { shader: shader!("ordinates/deposit"), push_bytes: std::mem::size_of::<DepositPush>(), spec: &[] };
pub const BIN: Kernel =
    Kernel { shader: shader!("ordinates/bin"), push_bytes: std::mem::size_of::<BinPush>(), spec: &[] };
/// An emissive medium's source sigma_a Le, added to the first sweep's (glsl/ordinates/emit.comp;
/// specialised on the scene: it reads the material table and the emission grid).
pub const EMIT: Kernel = Kernel {
    shader: shader!("ordinates/emit"),
    push_bytes: std::mem::size_of::<EmitPush>(),
    spec: crate::solvers::parts::gpu_scene::SCENE_SPEC,
};

/// dom's convergence test on the device (glsl/ordinates/converge.comp).
pub const CONVERGE: Kernel =
    Kernel { shader: shader!("ordinates/converge"), push_bytes: std::mem::size_of::<ConvergePush>(), spec: &[] };

/// Bytes of the uniform block the sweeps read the characteristics' factors from (glsl/ordinates/
/// sweep.comp and block_sweep.comp, `geometry4[4096]`): 20 floats a direction, 819 directions.
const GEOMETRY_BLOCK_BYTES: u64 = 4096 * 16;

/// The characteristics' factors (`geometry`, 20 floats a direction of `q`) fit the sweeps'
/// uniform block on this device, or one line naming the knob.
pub(crate) fn check_geometry(gpu: &Gpu, geometry: &[f32], q: &Quadrature) -> Result<(), SolverError> {
    let bytes = geometry.len() as u64 * 4;
    let max = gpu.info().max_uniform_buffer_range.min(GEOMETRY_BLOCK_BYTES);
    if bytes <= max {
        return Ok(());
    }
    Err(SolverError::Unsupported(format!(
        "dom.directions={}: the characteristics' factors of its {} directions take {bytes} bytes, past the {max} of a \
         uniform block on this device (maxUniformBufferRange): choose a set of at most {} directions (dom.directions) \
         or dom.scheme=step",
        q.name,
        q.len(),
        max / 80
    )))
}

/// Every kernel of this part.
pub fn kernels() -> Vec<Kernel> {
    vec![SWEEP, SCATTER, DEPOSIT, BIN, EMIT, CONVERGE]
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct ConvergePush {
    voxels: u32,
    elements: u32,
    mode: u32,
    n: u32,
    parts: u32,
    extrapolate: u32,
    /// The tolerance, an f64's two halves (low first).
    tol: [u32; 2],
}

/// dom's iteration state on the device (glsl/ordinates/converge.comp's `Control`), read once
/// per batch of iterations.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct DomControl {
    pub stopped: u32,
    /// Iterations judged since the start.
    pub iterations: u32,
    pub pairs: u32,
    pub cam_pairs: u32,
    pub have_e: u32,
    pub ratio_ok: u32,
    /// The last iteration had an extrapolated change.
    pub ext_ok: u32,
    /// Converged on the extrapolated fluence: the tail applies.
    pub tail: u32,
    pub f: f32,
    pub pad: [u32; 3],
    /// The last iteration's change (the extrapolated one where `tail`).
    pub change: f64,
    pub ext_change: f64,
    /// rho^2 of the fluence's pairs of bounces.
    pub r2: f64,
    pub prev_sum_b: f64,
    pub pair: [f64; 3],
    pub cam_pair: [f64; 3],
    pub total: f64,
    pub camera_ratio2: f64,
    /// The tail's share of the fluence.
    pub share: f64,
}

/// Threads of glsl/ordinates/converge.comp's workgroups; doubles per workgroup's figures.
const CONVERGE_WG: u64 = 256;
const CONVERGE_FIGURES: u64 = 8;

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct SweepPush {
    dims: [u32; 4],
    plane: i32,
    h: f32,
    slots: u32,
    storage: u32,
    first: [u32; 8],
    count: [u32; 8],
    channel: u32,
    mode: u32,
    scheme: u32,
    /// The plane's first entry in the cells list ([`plane_cells`]) and its number of cells.
    first_cell: u32,
    plane_cells: u32,
    pad: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct ScatterPush {
    dims: [u32; 4],
    storage: u32,
    channel: u32,
    slots: u32,
    g: f32,
    octants: [u32; 8],
    grid: [f32; 4],
    eye: [f32; 4],
    chunk: u32,
    directions: u32,
    /// HG(g)'s mass within the cone of `peak_cos` about the camera's direction, which gathers
    /// the field interpolated there (0: the gather by HG(g) over every direction).
    peak_share: f32,
    peak_cos: f32,
    pad_f: f32,
    pad: [u32; 3],
}

/// Henyey-Greenstein's mass within angle acos(`c0`) of its axis: the integral of
/// (1 - g^2) / (4 pi (1 + g^2 - 2 g mu)^(3/2)) over mu in [c0, 1], which is
/// (1 - g^2) / (2 g) (1 / (1 - g) - 1 / sqrt(1 + g^2 - 2 g c0)); (1 - c0) / 2 at g = 0.
pub(crate) fn hg_mass_within(g: f64, c0: f64) -> f64 {
    if g.abs() < 1e-6 {
        return (1.0 - c0) / 2.0;
    }
    ((1.0 - g * g) / (2.0 * g) * (1.0 / (1.0 - g) - 1.0 / (1.0 + g * g - 2.0 * g * c0).sqrt())).clamp(0.0, 1.0)
}

/// The cosine of the largest angle between any direction and the nearest of `q`'s (its covering
/// radius, sampled at 4096 Fibonacci points, widened by a tenth): every direction has a swept one
/// within it, so the truncated peak's gather (scatter.comp) always finds the field.
fn covering_cos(q: &Quadrature) -> f64 {
    let n = 4096;
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let worst = (0..n)
        .map(|i| {
            let z = 1.0 - (2.0 * i as f64 + 1.0) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let p = [r * (golden * i as f64).cos(), r * (golden * i as f64).sin(), z];
            q.directions.iter().map(|d| d[0] * p[0] + d[1] * p[1] + d[2] * p[2]).fold(-1.0, f64::max)
        })
        .fold(1.0, f64::min);
    (worst.clamp(-1.0, 1.0).acos() * 1.1).min(std::f64::consts::PI).cos()
}

/// How scatter.comp splits its sums for a swept set of `n` directions and `m` storage
/// directions: [`SCATTER_VOXELS`] consecutive voxels an invocation, the storage directions in
/// chunks (work group y).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct ScatterShape {
    /// Storage directions an invocation takes (work group y covers M in chunks).
    pub chunk: u32,
    /// Voxels an invocation takes.
    pub voxels: u32,
}

/// scatter.comp's `BLOCK`: storage directions summed in one pass over the field.
const SCATTER_BLOCK: u32 = 8;

/// scatter.comp's `VOXELS`: consecutive voxels an invocation takes. Up to s8 one voxel an
/// invocation with its field in a local array was 1.5-2.7x slower on lavapipe (s8 on a 24^3
/// cube 345 against 128 ms a pass, s6 on the 128 x 4 x 128 slab 489 against 225) and no faster
/// on the sparse cloud (76 against 74 ms, where whole invocations of empty voxels return;
/// docs/dom.md, "The scattering pass").
const SCATTER_VOXELS: u32 = 8;

/// The chunk: one block, each re-reading the field anyway, so the rows of work groups spread
/// over M / 8 (a GPU's parallelism on a small grid; lavapipe measured 0.13 s a pass at one
/// block against 0.15 at eight, product-16x32 on the 8^3 cube).
const SCATTER_CHUNK: u32 = SCATTER_BLOCK;

/// scatter.comp's shape for `n` swept and `m` storage directions: a chunk of one block
/// ([`SCATTER_CHUNK`]), fewer only if one block's loop back-edges did not fit within
/// `LOOP_GUARD` (glsl/include/budget.glsl: past 65535 llvmpipe ends every loop of an invocation
/// silently), which no directions set dom offers comes near. A loop that runs n times takes
/// n + 1 (the last pass only exits): the gather's voxels, octants and directions
/// VOXELS (N + 18) + 1 (where the voxels scatter nothing; elsewhere the first chunk gathers in its
/// block's pass over the field, fewer), then per block its octants and directions N + 17, its stores
/// BLOCK (VOXELS + 1) and its own (an invocation where nothing scatters stores instead: fewer).
/// The sets stop at 512 (product-16x32): 4241 + 602 = 4843 back-edges an invocation.
pub(crate) fn scatter_shape(n: u32, m: u32) -> ScatterShape {
    let m = m.max(1);
    let first = SCATTER_VOXELS * (n + 18) + 1;
    let block = n + 18 + SCATTER_BLOCK * (SCATTER_VOXELS + 1);
    let blocks = (LOOP_GUARD.saturating_sub(first) / block).max(1);
    ScatterShape { chunk: (blocks * SCATTER_BLOCK).min(SCATTER_CHUNK).min(m), voxels: SCATTER_VOXELS }
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct DepositPush {
    entries: u32,
    voxels: u32,
    k: u32,
    beams: u32,
    scale: f32,
    channels: u32,
    /// The slab's first voxel (`voxels` is its size).
    base: u32,
    /// The group of beams: its first history entry and first beam (`entries`, `beams`: its size).
    first_entry: u32,
    beam0: u32,
    pad: [u32; 2],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct BinPush {
    dims: [u32; 4],
    grid: [f32; 4],
    beams: u32,
    storage: u32,
    channels: u32,
    scale: f32,
    g: f32,
    /// The slab's first voxel (dims.w is its size).
    base: u32,
    /// The group's first beam (`beams` is its size).
    beam0: u32,
    /// dom.delta_m: HG(g)'s mass within the storage set's covering radius (0: the matched
    /// mean cosine instead), and that radius as a cosine.
    peak_share: f32,
    peak_cos: f32,
    pad: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct EmitPush {
    dims: [u32; 4],
    grid: [f32; 4],
    storage: u32,
    channels: u32,
    /// The slab's first voxel (dims.w is its size).
    base: u32,
    /// 1: no beam was binned into the source: the pass writes it rather than adds to it.
    start: u32,
}

/// Where the camera is, for the light each voxel scatters toward it.
#[derive(Clone, Copy, Debug)]
pub enum Eye {
    /// A pinhole at this point.
    Point([f32; 3]),
    /// An orthographic camera: the unit direction toward it.
    Toward([f32; 3]),
}

impl Eye {
    /// As the kernels read it: xyz the position (w = 0) or the direction toward it (w = 1).
    pub(crate) fn packed(self) -> [f32; 4] {
        match self {
            Eye::Point(p) => [p[0], p[1], p[2], 0.0],
            Eye::Toward(d) => [d[0], d[1], d[2], 1.0],
        }
    }
}

/// What a [`Sweeper`] sweeps: a grid of cubic voxels, per channel extinction and scattering,
/// the swept and the storage directions.
pub struct SweepSetup<'a> {
    pub dims: [u32; 3],
    /// Voxel edge, scene units.
    pub h: f32,
    /// The grid's lower corner.
    pub origin: [f32; 3],
    /// 1 (grey) or 3.
    pub channels: u32,
    /// sigma_t per channel and voxel ([c * V + v], x fastest), 1/unit.
    pub sigma_t: &'a [f32],
    /// sigma_s likewise.
    pub sigma_s: &'a [f32],
    /// The N propagation directions.
    pub quadrature: &'a Quadrature,
    /// The M storage directions; the quadrature itself (same name) stores at the swept ones.
    pub storage: &'a Quadrature,
    /// Henyey-Greenstein asymmetry of the medium's scattering: the direct source's binning and
    /// the light gathered toward the camera scatter by it.
    pub g: f64,
    /// The asymmetry the scattering between sweeps uses (the matrix A[s][m] of scatter.comp): `g`
    /// itself, or with `dom.delta_m` the asymmetry of the part left outside the truncated forward
    /// peak (`super::Truncation`), sigma_t and sigma_s then being the truncated ones.
    pub scatter_g: f64,
    pub eye: Eye,
    /// The voxel update.
    pub scheme: Scheme,
}

/// A sweeper's iteration state ([`Sweeper::read_state`]): the pending source, the fluence
/// summed, the light toward the camera.
pub type IterationState = (Vec<f32>, Vec<f32>, Vec<f32>);

/// How the sweep reads the stored source: one direction, the swept set itself, or upsampled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Storage {
    Isotropic = 0,
    Swept = 1,
    Upsampled = 2,
}

/// A grid ready to sweep: extinction, directions and the angular maps on the device, the
/// directions grouped by octant.
pub struct Sweeper {
    sweep: Pipeline,
    scatter: Pipeline,
    deposit: Pipeline,
    bin: Pipeline,
    dims: [u32; 3],
    h: f32,
    channels: u32,
    /// The storage directions, in the order the source is stored (by octant when they are the
    /// swept set), and how they couple to the swept ones.
    pub storage: Quadrature,
    map: StorageMap,
    /// The mean cosine the quadrature's scattering carries ([`StorageMap::scattering`]).
    pub quadrature_g: f64,
    mode: Storage,
    g: f32,
    grid: [f32; 4],
    eye: [f32; 4],
    sigma_t: Buffer,
    sigma_s: Buffer,
    /// The source the next sweep propagates [c][m][v], per unit volume and sr: the
    /// first-scattering source as the bin pass sums it, then the light the last sweep scattered
    /// (the thesis's G'', 5.3.3; glsl/ordinates/scatter.comp).
    source: Buffer,
    dirs: Buffer,
    storage_dirs: Buffer,
    footprint: Buffer,
    upsample: Buffer,
    scatter_matrix: Buffer,
    /// The gather's split toward the camera (`dom.delta_m`): HG(g)'s mass within the cone (0:
    /// no split) and the cone's cosine ([`covering_cos`]).
    gather_split: [f32; 2],
    /// The bin's split of the first-scattering shares (the same, at the storage set's radius).
    bin_split: [f32; 2],
    field: Buffer,
    /// Step characteristics: each direction's geometry (20 floats) and its outgoing face
    /// radiances across x, y, z (4-byte stand-ins for the step scheme).
    geometry: Buffer,
    faces: [Buffer; 3],
    scheme: Scheme,
    /// Every plane's cells in octant-local coordinates ([`plane_cells`]), and where each plane's
    /// begin (one more than the planes: the last is the voxel count).
    cells: Buffer,
    plane_starts: Vec<u32>,
    fluence: Buffer,
    /// Per channel and voxel: the energy (fluence times lambda^2) that scattered isotropically
    /// gives the light scattered toward the eye (glsl/ordinates/scatter.comp).
    pub camera: Buffer,
    /// Per octant (bit a set: negative along axis a): its directions' first index in `dirs`
    /// and count.
    first_dir: [u32; 8],
    count: [u32; 8],
    /// Field slots per octant: its largest direction count.
    slots: u32,
    /// Voxels the source holds: the grid's, or one slab's
    /// ([`Sweeper::for_source`]).
    source_voxels: u32,
    /// The convergence test on the device (glsl/ordinates/converge.comp): its kernel, control
    /// record (host-visible), the bounces summed, the last two bounces, the last extrapolated
    /// fluence, the light toward the camera of the last three iterations, per-workgroup figures.
    /// (No kernel where the device lacks double precision: the test runs on the host.)
    converge: Option<Pipeline>,
    control: crate::solvers::parts::feedback::Feedback,
    accum: Buffer,
    bounce: Buffer,
    extrap: Buffer,
    cam_hist: Buffer,
    partials: Buffer,
}

/// The cells (i, j) of every wavefront plane w = i + j + k of an `nx x ny x nz` grid in an
/// octant's own coordinates (k = w - i - j within the grid), packed `i | j << 16`, plane by plane
/// with j outer and i inner; and where each plane's cells begin (`nx + ny + nz - 1` entries, the
/// last the voxel count). glsl/ordinates/sweep.comp launches only these: a square of (i, j) per
/// plane, most of it off the grid, cost llvmpipe nearly as much as the cells on it (its masked
/// SIMD batches run the kernel through; docs/lavapipe.md). Every voxel is listed once.
fn plane_cells([nx, ny, nz]: [u32; 3]) -> (Vec<u32>, Vec<u32>) {
    assert!(nx <= 0xffff && ny <= 0xffff, "dom's grid is at most 512 a side");
    let planes = nx + ny + nz - 2;
    let mut cells = Vec::with_capacity(nx as usize * ny as usize * nz as usize);
    let mut starts = Vec::with_capacity(planes as usize + 1);
    for w in 0..planes {
        starts.push(cells.len() as u32);
        for j in 0..ny.min(w + 1) {
            // k = w - i - j in [0, nz): i from w - j - (nz - 1), to w - j, within [0, nx).
            let lo = (w - j).saturating_sub(nz - 1);
            let hi = (w - j).min(nx - 1);
            cells.extend((lo..=hi).map(|i| i | j << 16));
        }
    }
    starts.push(cells.len() as u32);
    (cells, starts)
}

/// A run of whole layers of the grid (z outermost, so its voxels are contiguous): the direct
/// source is made slab by slab when the whole grid's sums would not fit `dom.budget` or one
/// binding (src/solvers/dom/mod.rs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Slab {
    /// The first layer and the number of layers.
    pub z0: u32,
    pub layers: u32,
    /// Voxels per layer.
    pub layer: u32,
}

/// Beams whose deposits are summed and binned together, and their rays (the rays of a beam are
/// contiguous, beam after beam: `marching::beams`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BeamGroup {
    pub beams: std::ops::Range<u32>,
    pub rays: std::ops::Range<u32>,
}

impl BeamGroup {
    /// The beams cut into groups of at most `size`, with their rays (`ray_beam`: each ray's beam,
    /// non-decreasing).
    pub fn split(ray_beam: &[u32], beams: u32, size: u32) -> Vec<BeamGroup> {
        let first_ray = |b: u32| ray_beam.partition_point(|x| *x < b) as u32;
        (0..beams)
            .step_by(size.max(1) as usize)
            .map(|b0| {
                let b1 = (b0 + size.max(1)).min(beams);
                BeamGroup { beams: b0..b1, rays: first_ray(b0)..first_ray(b1) }
            })
            .collect()
    }
}

impl Slab {
    /// The slab's first voxel.
    pub fn base(&self) -> u32 {
        self.z0 * self.layer
    }
    pub fn voxels(&self) -> u32 {
        self.layers * self.layer
    }
}

/// The angular tables both sweepers upload: the swept directions by octant, the storage set
/// and how it maps to them, the scattering matrix and the characteristics' geometry.
pub(crate) struct Tables {
    pub swept: Quadrature,
    pub storage: Quadrature,
    pub mode: Storage,
    pub first_dir: [u32; 8],
    pub count: [u32; 8],
    pub map: StorageMap,
    pub footprint: Vec<[f32; 4]>,
    /// U[n][m] when upsampled, else one unused float.
    pub upsample: Vec<f32>,
    /// A[n][m].
    pub scatter: Vec<f32>,
    pub quadrature_g: f64,
    /// Per direction f[i][o], s[i][o] (20 floats) for step characteristics, else one float.
    pub geometry: Vec<f32>,
}

pub(crate) fn to_vec4(q: &Quadrature) -> Vec<[f32; 4]> {
    q.directions.iter().zip(&q.weights).map(|(d, w)| [d[0] as f32, d[1] as f32, d[2] as f32, *w as f32]).collect()
}

/// The storage directions and how the sweep reads them, for the swept set `swept` (the
/// quadrature in octant order).
fn storage_of(quadrature: &Quadrature, storage: &Quadrature, swept: &Quadrature) -> (Quadrature, Storage) {
    if storage.len() == 1 {
        (storage.clone(), Storage::Isotropic)
    } else if storage.name == quadrature.name {
        (swept.clone(), Storage::Swept)
    } else {
        (storage.clone(), Storage::Upsampled)
    }
}

/// What a sweeper would report of its tables without building one, for a render that sweeps
/// nothing (dom where nothing scatters): the mean cosine the quadrature's normalised scattering
/// carries for HG(`g`) ([`Tables::quadrature_g`]), and whether the source is upsampled
/// ([`Sweeper::upsampled`]).
pub fn unswept_figures(quadrature: &Quadrature, storage: &Quadrature, g: f64) -> (f64, bool) {
    let (swept, _, _) = quadrature.by_octant();
    let (storage, mode) = storage_of(quadrature, storage, &swept);
    (StorageMap::new(&swept, &storage).scattering(&swept, g).1, mode == Storage::Upsampled)
}

impl Tables {
    pub(crate) fn new(s: &SweepSetup) -> Result<Tables, SolverError> {
        let (swept, first_dir, count) = s.quadrature.by_octant();
        let (storage, mode) = storage_of(s.quadrature, s.storage, &swept);
        // scatter.comp gathers a voxel's N directions and scatters them into at least one
        // storage direction per invocation: 2 N + 37 loop back-edges within LOOP_GUARD.
        if 2 * swept.len() + 37 > LOOP_GUARD as usize {
            return Err(SolverError::Unsupported(format!(
                "{} has {} directions; dom sweeps at most {}",
                swept.name,
                swept.len(),
                (LOOP_GUARD as usize - 37) / 2
            )));
        }
        let to32 = |x: Vec<f64>| x.into_iter().map(|y| y as f32).collect::<Vec<f32>>();
        let map = StorageMap::new(&swept, &storage);
        let footprint: Vec<[f32; 4]> =
            map.footprint.iter().map(|f| [f[0] as f32, f[1] as f32, f[2] as f32, 0.0]).collect();
        let upsample = if mode == Storage::Upsampled { to32(map.upsample.clone()) } else { vec![0.0f32] };
        let (scatter, quadrature_g) = map.scattering(&swept, s.scatter_g);
        let scatter = to32(scatter);
        let geometry: Vec<f32> = if s.scheme == Scheme::Characteristics {
            swept
                .directions
                .iter()
                .flat_map(|d| {
                    let (f, sl) = characteristic_geometry(d.map(f64::abs));
                    let mut g = [0f32; 20];
                    for i in 0..3 {
                        for o in 0..3 {
                            g[3 * i + o] = f[i][o] as f32;
                            g[9 + 3 * i + o] = sl[i][o] as f32;
                        }
                    }
                    g
                })
                .collect()
        } else {
            vec![0.0]
        };
        Ok(Tables { swept, storage, mode, first_dir, count, map, footprint, upsample, scatter, quadrature_g, geometry })
    }
}

impl Sweeper {
    pub fn new(gpu: &Gpu, s: &SweepSetup) -> Result<Sweeper, SolverError> {
        Self::with_sweeps(gpu, s, true, s.dims[2])
    }

    /// A sweeper for the direct source only (deposits and binning, [`Sweeper::read_first`]),
    /// slabs of at most `layers` layers at a time: the extinction, field, faces and fluence that
    /// whole-grid sweeps need are left out, for when the block sweeper (`solvers::blocks`)
    /// sweeps.
    pub fn for_source(gpu: &Gpu, s: &SweepSetup, layers: u32) -> Result<Sweeper, SolverError> {
        Self::with_sweeps(gpu, s, false, layers)
    }

    fn with_sweeps(gpu: &Gpu, s: &SweepSetup, sweeps: bool, layers: u32) -> Result<Sweeper, SolverError> {
        let v = s.dims.iter().map(|d| *d as u64).product::<u64>();
        // Without sweeps the per-voxel buffers but the sources are one-float stand-ins.
        let sv = if sweeps { v } else { 0 };
        let source_voxels = s.dims[0] as u64 * s.dims[1] as u64 * layers.min(s.dims[2]) as u64;
        let Tables {
            swept,
            storage,
            mode,
            first_dir,
            count,
            map,
            footprint,
            upsample,
            scatter,
            quadrature_g,
            geometry,
        } = Tables::new(s)?;
        let m = storage.len() as u64;
        let slots = count.iter().copied().max().unwrap_or(1).max(1);
        // A truncated peak (dom.delta_m): the gather splits at the swept set's covering radius,
        // the bin at the storage set's (the same set, and so the same split, unless upsampled).
        let split = |q: &Quadrature| {
            let c0 = covering_cos(q);
            [hg_mass_within(s.g, c0) as f32, c0 as f32]
        };
        let (gather_split, bin_split) = match (s.scatter_g != s.g, mode) {
            (false, _) => ([0.0, 1.0], [0.0, 1.0]),
            (true, Storage::Swept) => {
                let both = split(&swept);
                (both, both)
            }
            (true, _) => (split(&swept), split(&storage)),
        };
        let nch = s.channels as u64;
        let characteristics = s.scheme == Scheme::Characteristics;
        let face_bytes = if characteristics { 8 * slots as u64 * sv * 4 } else { 4 };
        // The convergence test uses doubles: built only where the device has them.
        let mut wanted: Vec<(&Kernel, &[(u32, crate::gpu::Spec)])> =
            vec![(&SWEEP, &[]), (&SCATTER, &[]), (&DEPOSIT, &[]), (&BIN, &[])];
        if gpu.info().float64 {
            wanted.push((&CONVERGE, &[]));
        }
        let mut built = gpu.pipelines(&wanted)?.into_iter();
        let (cells, plane_starts) = if sweeps { plane_cells(s.dims) } else { (vec![0], vec![0]) };
        let (sweep, scatter_p, deposit, bin) = (
            built.next().expect("sweep"),
            built.next().expect("scatter"),
            built.next().expect("deposit"),
            built.next().expect("bin"),
        );
        let converge = built.next();
        // The convergence test's per-element buffers: one float each without sweeps.
        let per = |k: u64| 4 * if sweeps { k * nch * sv } else { 1 };
        Ok(Sweeper {
            sweep,
            scatter: scatter_p,
            deposit,
            bin,
            converge,
            control: crate::solvers::parts::feedback::Feedback::new(
                gpu,
                "ordinates convergence control",
                std::mem::size_of::<DomControl>() as u64,
            )?,
            accum: gpu.buffer("ordinates fluence summed", per(1))?,
            bounce: gpu.buffer("ordinates last bounces", per(2))?,
            extrap: gpu.buffer("ordinates extrapolated fluence", per(1))?,
            cam_hist: gpu.buffer("ordinates camera history", per(3))?,
            partials: gpu.buffer("ordinates convergence figures", Self::partial_bytes(nch * sv))?,
            dims: s.dims,
            h: s.h,
            channels: s.channels,
            storage: storage.clone(),
            map,
            quadrature_g,
            mode,
            g: s.g as f32,
            grid: [s.origin[0], s.origin[1], s.origin[2], s.h],
            eye: s.eye.packed(),
            sigma_t: gpu.buffer_with("ordinates sigma_t", if sweeps { s.sigma_t } else { &[0.0] })?,
            sigma_s: gpu.buffer_with("ordinates sigma_s", if sweeps { s.sigma_s } else { &[0.0] })?,
            // The bin pass sums the first-scattering source into it; without sweeps it is
            // read back slab by slab.
            source: gpu.buffer("ordinates source", nch * m * source_voxels * 4)?,
            dirs: gpu.buffer_with("ordinates directions", &to_vec4(&swept))?,
            storage_dirs: gpu.buffer_with("ordinates storage directions", &to_vec4(&storage))?,
            footprint: gpu.buffer_with("ordinates storage footprints", &footprint)?,
            upsample: gpu.buffer_with("ordinates upsampling", &upsample)?,
            scatter_matrix: gpu.buffer_with("ordinates scattering", &scatter)?,
            gather_split,
            bin_split,
            field: gpu.buffer("ordinates field", 8 * slots as u64 * sv * 4)?,
            geometry: {
                check_geometry(gpu, &geometry, s.quadrature)?;
                gpu.buffer_with("ordinates characteristics geometry", &geometry)?
            },
            faces: [
                gpu.buffer("ordinates faces x", face_bytes)?,
                gpu.buffer("ordinates faces y", face_bytes)?,
                gpu.buffer("ordinates faces z", face_bytes)?,
            ],
            scheme: s.scheme,
            cells: gpu.buffer_with("ordinates plane cells", &cells)?,
            plane_starts,
            fluence: gpu.buffer("ordinates fluence", nch * 8 * sv * 4)?,
            camera: gpu.buffer("ordinates toward the camera", nch * sv * 4)?,
            first_dir,
            count,
            slots,
            source_voxels: source_voxels as u32,
        })
    }

    /// Device bytes [`Sweeper::new`] allocates for `channels` channels of `voxels` voxels,
    /// `q` swept and `storage` stored (the memory estimate's figure).
    /// Without `sweeps` ([`Sweeper::for_source`], its sources `source_voxels` long) the
    /// extinction, field, faces, fluence and camera are left out.
    pub fn bytes(
        voxels: u64,
        channels: u64,
        q: &Quadrature,
        storage: &Quadrature,
        scheme: Scheme,
        sweeps: bool,
        source_voxels: u64,
    ) -> u64 {
        let slots = q.by_octant().2.iter().copied().max().unwrap_or(1).max(1) as u64;
        let (n, m) = (q.len() as u64, storage.len() as u64);
        let upsampled = m > 1 && storage.name != q.name;
        let sv = if sweeps { voxels } else { 0 };
        // A buffer the sweeps alone need is a one-float stand-in without them.
        let kept = |floats: u64| if sweeps { floats } else { 1 };
        let source_voxels = if sweeps { voxels } else { source_voxels };
        let floats = 2 * kept(voxels * channels) + source_voxels * channels * m // sigma_t, sigma_s, source
            + kept(sv * channels * 8) + kept(sv * channels)   // fluence, camera
            + kept(8 * slots * sv)                            // the field
            + n * 4 + m * 4 + m * 4                           // directions, storage directions, footprints
            + n * m                                           // the scattering matrix
            + if upsampled { n * m } else { 1 } // the upsampling (one float when unused)
            + if scheme == Scheme::Characteristics { 20 * n + 3 * kept(8 * slots * sv) } else { 1 + 3 }
            + kept(sv * channels) + kept(2 * sv * channels) + kept(sv * channels) + kept(3 * sv * channels) // the test's
            + kept(sv); // the planes' cells
        4 * floats
            + Self::partial_bytes(channels * sv)
            + crate::solvers::parts::feedback::Feedback::bytes(std::mem::size_of::<DomControl>() as u64)
    }

    /// Bytes of the convergence test's per-workgroup figures for `elements` channel-voxels.
    fn partial_bytes(elements: u64) -> u64 {
        (elements.div_ceil(CONVERGE_WG) * CONVERGE_FIGURES * 8).max(4)
    }

    /// Device bytes of its buffers.
    pub fn device_bytes(&self) -> u64 {
        [
            &self.sigma_t,
            &self.sigma_s,
            &self.source,
            &self.dirs,
            &self.storage_dirs,
            &self.footprint,
            &self.upsample,
            &self.scatter_matrix,
            &self.field,
            &self.geometry,
            &self.faces[0],
            &self.faces[1],
            &self.faces[2],
            &self.cells,
            &self.fluence,
            &self.camera,
            &self.accum,
            &self.bounce,
            &self.extrap,
            &self.cam_hist,
            &self.partials,
        ]
        .iter()
        .map(|b| b.size())
        .sum::<u64>()
            + self.control.device_bytes()
    }

    /// Whether the source is stored at fewer directions than swept (the sweep reads all M).
    pub fn upsampled(&self) -> bool {
        self.mode == Storage::Upsampled
    }

    fn voxels(&self) -> u32 {
        self.dims.iter().product()
    }

    /// A zeroed buffer for [`Sweeper::deposit_pass`]'s fixed-point sums ([c][beam][v]) of
    /// `beams` beams on a slab as large as the sources hold.
    pub fn deposit_sums(&self, gpu: &Gpu, beams: usize) -> Result<Buffer, SolverError> {
        Ok(gpu.buffer("ordinates deposits", self.channels as u64 * beams as u64 * self.source_voxels as u64 * 4)?)
    }

    /// The whole grid as one slab.
    pub fn whole(&self) -> Slab {
        Slab { z0: 0, layers: self.dims[2], layer: self.dims[0] * self.dims[1] }
    }

    #[allow(clippy::too_many_arguments)]
    /// One marching round's transfer into `sums`: each deposit of the rays of `group` that
    /// falls in `slab` added to its voxel's sum for its ray's beam (`ray_beam`), in fixed point
    /// of `scale` quanta per W.
    pub fn deposit_pass(
        &self,
        history: &Buffer,
        ray_beam: &Buffer,
        k: u32,
        group: &BeamGroup,
        scale: f32,
        sums: &Buffer,
        slab: Slab,
    ) -> Pass {
        let entries = (group.rays.end - group.rays.start) * k;
        assert!(slab.voxels() <= self.source_voxels, "a slab the sources hold");
        Pass::new("ordinates.deposit", QueueRole::Trace, &self.deposit)
            .read(0, history)
            .read_write(1, sums)
            .read(2, ray_beam)
            .push(&DepositPush {
                entries,
                voxels: slab.voxels(),
                k,
                beams: group.beams.end - group.beams.start,
                scale,
                channels: self.channels,
                base: slab.base(),
                first_entry: group.rays.start * k,
                beam0: group.beams.start,
                pad: [0; 2],
            })
            .cover_linear(entries)
    }

    /// The most beams one bin pass shares among the storage directions: bin.comp's invocation
    /// loops over every beam of its group, so a group is kept within `LOOP_GUARD`
    /// (glsl/include/budget.glsl). Counted as llvmpipe counts: a loop that runs n times takes
    /// n + 1 back-edges (the last pass only exits), so a parallel beam costs
    /// (C + 1) + 2 (M + 1) + M (C + 1) + 1 and a point light's matched asymmetry 34 mean-cosine
    /// sums of M + 1 more. Measured: 38 environment beams at M = 512 (grey), counted 1538 each
    /// without the exits and so kept in one group, left the isotropic medium's image 1.3% short of
    /// the same render stored at one direction; in groups of 28 it is exact.
    pub fn bin_group(&self, beams: &[Beam]) -> u32 {
        bin_group(
            self.storage.len() as u64,
            self.channels as u64,
            beams.iter().any(|b| matches!(b, Beam::FromPoint(_))),
        )
    }

    /// The beams as the bin pass reads them: two vec4 each, (direction or position, 0 parallel
    /// or 1 point) and (the matched asymmetry of a parallel beam, -, -, -).
    pub fn beam_table(&self, g: f64, beams: &[Beam]) -> Vec<[f32; 4]> {
        beams
            .iter()
            .flat_map(|b| match b {
                Beam::Parallel(d) => {
                    let gm = self.map.matched_g(g, &[d.x as f64, d.y as f64, d.z as f64]) as f32;
                    [[d.x, d.y, d.z, 0.0], [gm, 0.0, 0.0, 0.0]]
                }
                Beam::FromPoint(p) => [[p.x, p.y, p.z, 1.0], [0.0; 4]],
            })
            .collect()
    }

    /// Share the deposits' sums of `group` on `slab` (`sums`, [`Sweeper::deposit_pass`]) among
    /// the storage directions, added to the groups' before: the slab's first-scattering source
    /// (bin.comp), [c][m][v] over the slab's voxels, which the first sweep propagates.
    pub fn bin_pass(&self, sums: &Buffer, beam_table: &Buffer, group: &BeamGroup, scale: f32, slab: Slab) -> Pass {
        let [nx, ny, nz] = self.dims;
        let v = slab.voxels();
        Pass::new("ordinates.bin", QueueRole::Diffuse, &self.bin)
            .read(0, sums)
            .read(1, beam_table)
            .read(2, &self.storage_dirs)
            .read(3, &self.footprint)
            .read_write(4, &self.source)
            .push(&BinPush {
                dims: [nx, ny, nz, v],
                grid: self.grid,
                beams: group.beams.end - group.beams.start,
                storage: self.storage.len() as u32,
                channels: self.channels,
                scale,
                g: self.g,
                base: slab.base(),
                beam0: group.beams.start,
                peak_share: self.bin_split[0],
                peak_cos: self.bin_split[1],
                pad: [0; 3],
            })
            .cover_linear(v)
    }

    /// Add the medium's emission source sigma_a Le (isotropic: the same at every storage
    /// direction, per unit volume and sr, as the binned source) to the source on `slab`
    /// (emit.comp, `pipeline` built from [`EMIT`] on the scene's specialisation), from the slab's
    /// resampled `density` (sigma_a = sigma_t (1 - albedo) density, the voxel's own). With
    /// `start` the source holds nothing yet (no beam was binned) and the pass writes it.
    pub fn emit_pass(&self, pipeline: &Pipeline, gs: &GpuScene, density: &Buffer, slab: Slab, start: bool) -> Pass {
        let [nx, ny, nz] = self.dims;
        let v = slab.voxels();
        assert!(v <= self.source_voxels, "a slab the sources hold");
        gs.bind_emission(gs.bind(Pass::new("ordinates.emit", QueueRole::Diffuse, pipeline)))
            .read(3, density)
            .read_write(4, &self.source)
            .push(&EmitPush {
                dims: [nx, ny, nz, v],
                grid: self.grid,
                storage: self.storage.len() as u32,
                channels: self.channels,
                base: slab.base(),
                start: start as u32,
            })
            .cover_linear(v)
    }

    /// The first-scattering source the bin pass stored for `slab` ([c][m][v] over its voxels,
    /// per unit volume and sr).
    pub fn read_first(&self, gpu: &Gpu, slab: Slab) -> Result<Vec<f32>, SolverError> {
        let floats = self.channels as u64 * self.storage.len() as u64 * slab.voxels() as u64;
        Ok(bytemuck::pod_collect_to_vec(&gpu.read_buffer_prefix(&self.source, floats * 4)?))
    }

    /// Start the iteration from a first-scattering source ([c][m][v], per unit volume and sr):
    /// the first sweep propagates it, and nothing is gathered toward the camera yet.
    pub fn set_first(&self, gpu: &Gpu, first: &[f32]) -> Result<(), SolverError> {
        gpu.write_buffer(&self.source, 0, bytemuck::cast_slice(first))?;
        gpu.fill_zero(&self.camera)?;
        Ok(())
    }

    /// The iteration's state as it stands (dom's warm start, `dom::DomCarry`): the source the
    /// next sweep would propagate ([c][m][v]: the bounce not yet swept), the bounces' fluence
    /// summed ([c][v]) and the light they scattered toward the camera ([c][v]).
    pub fn read_state(&self, gpu: &Gpu) -> Result<IterationState, SolverError> {
        let source = self.read_first(gpu, self.whole())?;
        Ok((source, gpu.read_buffer_as(&self.accum)?, gpu.read_buffer_as(&self.camera)?))
    }

    /// Go on from a state ([`Sweeper::read_state`]'s three): the first sweep propagates `source`,
    /// and the fluence summed and the light toward the camera start from `accum` and `camera`.
    pub fn set_state(&self, gpu: &Gpu, source: &[f32], accum: &[f32], camera: &[f32]) -> Result<(), SolverError> {
        gpu.write_buffer(&self.source, 0, bytemuck::cast_slice(source))?;
        gpu.write_buffer(&self.accum, 0, bytemuck::cast_slice(accum))?;
        gpu.write_buffer(&self.camera, 0, bytemuck::cast_slice(camera))?;
        Ok(())
    }

    fn sweep_passes(&self, channel: u32) -> Vec<Pass> {
        let [nx, ny, nz] = self.dims;
        let v = nx * ny * nz;
        let planes = (nx + ny + nz - 2) as i32;
        assert_eq!(self.plane_starts.len(), planes as usize + 1, "a source-only sweeper (for_source) sweeps nothing");
        (0..planes)
            .map(|w| {
                let (first_cell, end) = (self.plane_starts[w as usize], self.plane_starts[w as usize + 1]);
                let push = SweepPush {
                    dims: [nx, ny, nz, v],
                    plane: w,
                    h: self.h,
                    slots: self.slots,
                    storage: self.storage.len() as u32,
                    first: self.first_dir,
                    count: self.count,
                    channel,
                    mode: self.mode as u32,
                    scheme: (self.scheme == Scheme::Characteristics) as u32,
                    first_cell,
                    plane_cells: end - first_cell,
                    pad: [0; 3],
                };
                Pass::new("ordinates.sweep", QueueRole::Diffuse, &self.sweep)
                    .read(0, &self.sigma_t)
                    .read(1, &self.source)
                    .read(2, &self.dirs)
                    .read_write(3, &self.field)
                    .write(4, &self.fluence)
                    .read(5, &self.upsample)
                    .read(6, &self.geometry)
                    .read_write(7, &self.faces[0])
                    .read_write(8, &self.faces[1])
                    .read_write(9, &self.faces[2])
                    .read(10, self.control.record())
                    .read(11, &self.cells)
                    .push(&push)
                    .cover([end - first_cell, 8, 1])
            })
            .collect()
    }

    fn scatter_pass(&self, channel: u32) -> Pass {
        let [nx, ny, nz] = self.dims;
        let v = nx * ny * nz;
        let octants: [u32; 8] = std::array::from_fn(|o| self.first_dir[o] | self.count[o] << 16);
        let shape = scatter_shape(self.swept_len(), self.storage.len() as u32);
        Pass::new("ordinates.scatter", QueueRole::Diffuse, &self.scatter)
            .read(0, &self.field)
            .read(1, &self.dirs)
            .read(2, &self.scatter_matrix)
            .read(3, &self.sigma_s)
            .write(4, &self.source)
            .read_write(5, &self.camera)
            .read(6, self.control.record())
            .push(&ScatterPush {
                dims: [nx, ny, nz, v],
                storage: self.storage.len() as u32,
                channel,
                slots: self.slots,
                g: self.g,
                octants,
                grid: self.grid,
                eye: self.eye,
                chunk: shape.chunk,
                directions: self.swept_len(),
                peak_share: self.gather_split[0],
                peak_cos: self.gather_split[1],
                pad_f: 0.0,
                pad: [0; 3],
            })
            .cover_linear_z([v.div_ceil(shape.voxels), (self.storage.len() as u32).div_ceil(shape.chunk)])
    }

    /// N, the directions swept.
    fn swept_len(&self) -> u32 {
        self.count.iter().sum()
    }

    /// The fluence per channel and voxel ([c][v]): the octants' slices added in a fixed order.
    fn read_fluence(&self, gpu: &Gpu) -> Result<Vec<f32>, SolverError> {
        let slices: Vec<f32> = gpu.read_buffer_as(&self.fluence)?;
        let v = self.voxels() as usize;
        Ok((0..self.channels as usize)
            .flat_map(|c| {
                let s = &slices;
                (0..v).map(move |i| (0..8).map(|o| s[(c * 8 + o) * v + i]).sum())
            })
            .collect())
    }

    /// One sweep of every direction of channel 0 for the isotropic emission `emission` (per
    /// unit volume and solid angle, per voxel), no scattering: the fluence sum_d w_d I_d per
    /// voxel. Needs one storage direction (what the CPU oracle's `sweep_once` computes).
    pub fn sweep(&self, gpu: &Gpu, emission: &[f32]) -> Result<Vec<f32>, SolverError> {
        assert_eq!(self.mode, Storage::Isotropic, "Sweeper::sweep takes an isotropic emission");
        gpu.write_buffer(&self.source, 0, bytemuck::cast_slice(emission))?;
        let point = gpu.submit(QueueRole::Diffuse, &self.sweep_passes(0), &[])?;
        gpu.wait(point)?;
        let mut phi = self.read_fluence(gpu)?;
        phi.truncate(self.voxels() as usize);
        Ok(phi)
    }

    /// One scattering iteration of every channel on the device (the thesis's progressive scheme,
    /// 5.3.3): sweep the source the last iteration scattered (the first-scattering source the
    /// first time), store what this sweep scatters as the next one, and add the light it
    /// scatters toward the camera to the bounces' before ([`Sweeper::camera`]). Returns this
    /// iteration's fluence per channel and voxel ([c][v]): the light of this bounce alone, so
    /// the solution after n iterations is the sum of the n returned.
    pub fn iterate(&self, gpu: &Gpu) -> Result<Vec<f32>, SolverError> {
        let mut passes = Vec::new();
        for c in 0..self.channels {
            passes.extend(self.sweep_passes(c));
            passes.push(self.scatter_pass(c));
        }
        let point = gpu.submit(QueueRole::Diffuse, &passes, &[])?;
        gpu.wait(point)?;
        self.read_fluence(gpu)
    }

    /// The passes of scattering iteration `n` (from 1) with its convergence test on the device
    /// (glsl/ordinates/converge.comp; src/solvers/dom/mod.rs has the criterion): once an
    /// iteration of a submission converges, the rest of it returns at once.
    pub fn iteration_passes(&self, n: u32, extrapolate: bool, tol: f64) -> Vec<Pass> {
        let mut passes = Vec::new();
        for c in 0..self.channels {
            passes.extend(self.sweep_passes(c));
            passes.push(self.scatter_pass(c));
        }
        let elements = self.channels as u64 * self.voxels() as u64;
        let parts = elements.div_ceil(CONVERGE_WG) as u32;
        let bits = tol.to_bits();
        for mode in [0u32, 1, 2, 3] {
            if mode == 2 && !extrapolate {
                continue;
            }
            let push = ConvergePush {
                voxels: self.voxels(),
                elements: elements as u32,
                mode,
                n,
                parts,
                extrapolate: extrapolate as u32,
                tol: [bits as u32, (bits >> 32) as u32],
            };
            let wide = mode == 0 || mode == 2;
            passes.push(
                Pass::new(
                    "ordinates.converge",
                    QueueRole::Diffuse,
                    self.converge.as_ref().expect("a device with double precision"),
                )
                .read(0, &self.fluence)
                .read(1, &self.camera)
                .read_write(2, &self.accum)
                .read_write(3, &self.bounce)
                .read_write(4, &self.extrap)
                .read_write(5, &self.cam_hist)
                .read_write(6, &self.partials)
                .read_write(7, self.control.record())
                .push(&push)
                .groups([if wide { parts } else { 1 }, 1, 1]),
            );
        }
        passes
    }

    /// Whether the convergence test can run on the device (it has double precision).
    pub fn tests_on_device(&self) -> bool {
        self.converge.is_some()
    }

    /// The device's convergence record as the last batch's final pass copied it (after the
    /// wait for that batch).
    pub fn control(&self, gpu: &Gpu) -> Result<DomControl, SolverError> {
        self.control.read(gpu)
    }

    /// The pass that copies the record out, a batch's last.
    pub fn control_copy_pass(&self) -> Pass {
        self.control.copy_pass(QueueRole::Diffuse)
    }

    /// The pass that zeroes the record, the first batch's first.
    pub fn control_clear_pass(&self) -> Pass {
        self.control.clear_pass(QueueRole::Diffuse)
    }

    /// The light toward the camera as it stood after iteration `n` (from 1), kept for the
    /// last three iterations by the test on the device; `None` before iteration 1 or for one
    /// no longer kept.
    pub fn camera_after(&self, gpu: &Gpu, n: u32, latest: u32) -> Result<Option<Vec<f32>>, SolverError> {
        if n == 0 || n > latest || latest - n >= 3 {
            return Ok(None);
        }
        let all: Vec<f32> = gpu.read_buffer_as(&self.cam_hist)?;
        let e = (self.channels as u64 * self.voxels() as u64) as usize;
        let slot = (n % 3) as usize;
        Ok(Some(all[slot * e..(slot + 1) * e].to_vec()))
    }
}

/// The most beams one bin pass shares among `m` storage directions in `channels` channels
/// (`point`: some beam leaves a point light): [`Sweeper::bin_group`]'s count, which the direct
/// source's plan (`SourcePlan::cut`) takes its groups within.
pub fn bin_group(m: u64, channels: u64, point: bool) -> u32 {
    let ch = channels;
    let per_beam = (ch + 1) + 2 * (m + 1) + m * (ch + 1) + 1 + if point { 34 * (m + 1) + 33 } else { 0 };
    let fixed = (ch + 1) + ch * (m + 1) + 1;
    ((LOOP_GUARD as u64).saturating_sub(fixed) / per_beam).clamp(1, u32::MAX as u64) as u32
}

#[cfg(test)]
mod tests {
    use super::plane_cells;

    /// Every voxel of a grid is listed once, on its own plane, and the planes are in order: the
    /// sweep launched over the lists updates what the square of (i, j) per plane updated.
    #[test]
    fn plane_cells_list_every_voxel_once_on_its_plane() {
        for dims in [[1, 1, 1], [12, 12, 12], [7, 3, 5], [2, 9, 4], [128, 4, 128], [5, 1, 1], [1, 6, 2]] {
            let [nx, ny, nz] = dims;
            let (cells, starts) = plane_cells(dims);
            assert_eq!(starts.len() as u32, nx + ny + nz - 1, "{dims:?}");
            assert_eq!(*starts.last().unwrap() as usize, cells.len(), "{dims:?}");
            let mut seen = vec![false; (nx * ny * nz) as usize];
            for w in 0..nx + ny + nz - 2 {
                let plane = &cells[starts[w as usize] as usize..starts[w as usize + 1] as usize];
                assert!(!plane.is_empty(), "{dims:?}: plane {w} has no cells");
                for &cell in plane {
                    let (i, j) = (cell & 0xffff, cell >> 16);
                    let k = w as i64 - i as i64 - j as i64;
                    assert!(i < nx && j < ny && (0..nz as i64).contains(&k), "{dims:?}: ({i}, {j}) off plane {w}");
                    let v = (i + nx * (j + ny * k as u32)) as usize;
                    assert!(!seen[v], "{dims:?}: ({i}, {j}, {k}) listed twice");
                    seen[v] = true;
                }
            }
            assert!(seen.iter().all(|s| *s), "{dims:?}: a voxel is on no plane");
        }
    }
}
