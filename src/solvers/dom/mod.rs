//! Solver `dom`: modified discrete ordinates (thesis ch. 5; issue 13), in-core.
//!
//! 1. **Direct source (5.2).** Photon marching as in `lbl` (the shared `marching` part) moves
//!    the light; each deposit (power scattered out of a beam) is shared among M storage
//!    directions by the quadrature-normalised phase function and summed in fixed point
//!    (glsl/ordinates/deposit.comp: deterministic). The first-scattering emission at storage
//!    direction m is E_m / (w_m lambda^3) per unit volume and solid angle. Isotropic media
//!    store one direction (M = 1, thesis 5.1), grey media one channel.
//! 2. **Propagation (5.3).** Octant sweeps over the directions of a named quadrature
//!    (`physics::quadrature`; S_4 and S_6 are the thesis's 24 and 48), plane by plane, with step
//!    characteristics (5.3.1-5.3.2, the voxel mean from its balance) or the step difference
//!    (`dom.scheme`; `solvers::ordinates`, checked against the CPU oracle `physics::ordinates`):
//!    never negative, conservative. The swept emission is the stored one upsampled from M to N
//!    directions (`physics::angular`). The thesis's progressive iteration on the device
//!    (5.3.3, glsl/ordinates/scatter.comp): the first sweep propagates the first-scattering
//!    source (its G'' = G_dir), and each next sweep only what the previous one scattered,
//!    sigma_s sum_n A[n][m] I_n (its G' becoming G''), so iteration n's fluence is the n-th
//!    bounce's; the solution is their sum, its light toward the camera summed on the device.
//!    It stops when a bounce adds less than `dom.tol` of the summed fluence (relative, largest
//!    over voxels) or at `dom.max_iterations`; both are reported.
//! 3. **View gathering (5.3.5).** The shared view pass: exact single scattering of the direct
//!    light, plus the swept field (the light scattered once and more) scattered toward the
//!    camera by the phase function at each voxel (scatter.comp), trilinear between voxel
//!    centres; nothing is counted twice.
//! 4. **Emission (issue 47).** An emissive medium's source sigma_a Le (W/(m^3 sr), the units of
//!    the first-scattering source: per unit volume and sr, the sweep's Q per unit length) is
//!    isotropic, so it is the same at every storage direction; glsl/ordinates/emit.comp adds it
//!    to the first sweep's source (sigma_a from the voxel's own resampled density, Le at its
//!    centre). The swept field then holds the emitted light uncollided and, bounce by bounce,
//!    scattered; the view scatters it toward the camera like the rest of the field, and adds the
//!    unscattered emission along the camera ray itself. A scene lit by its emission alone
//!    marches nothing. docs/dom.md, "Emission".
//!

pub mod blocks;
pub mod directions;
pub mod ordinates;

use serde::Serialize;

use crate::gpu::{Buffer, Gpu, Kernel, Pass, Pipeline, QueueRole};
use crate::physics::ordinates::Scheme;
use crate::physics::quadrature::Quadrature;
use crate::scene::{is_grey, CameraKind, Emission, Medium, Scene};

use self::blocks::{BlockOptions, BlockSweeper, Evict, StoreKind, StreamStats, MAX_BLOCK};
use self::directions::DirectionsTrust;
use self::ordinates::{bin_group, BeamGroup, Eye, Slab, SweepSetup, Sweeper};
use crate::solvers::interface::{
    Animation, Convergence, Figure, Headline, Knob, Knobs, Progress, Range, RenderOutput, RenderReport, RenderRequest,
    Rung, Solver, SolverError, Stats, Variant,
};
use crate::solvers::parts::gpu_scene::{self, GpuScene};
use crate::solvers::parts::lattice::{GridTrust, LatticeGeom, DOM_GRID};
use crate::solvers::parts::marching::{self, Beam, MarchSettings, Marcher};
use crate::solvers::parts::view::{self, FluxUse, MsVolume, MsWindow, ViewSettings};

pub struct Dom;

/// Marching rounds (a march and a deposit pass each) per submission of the direct source.
const ROUNDS_PER_SUBMIT: u32 = 8;

/// `report`'s workloads on the homogeneous sphere: N 24 (s4), two iterations, `grid`^3 voxels,
/// `size`^2 pixels, and `more` settings.
fn sphere_workload(name: String, grid: &str, size: &str, more: &[(&str, &str)], seed: &'static str) -> Headline {
    let mut sets = vec![("render.width", size), ("render.height", size), ("dom.grid", grid), ("dom.directions", "s4")];
    sets.push(("dom.max_iterations", "2"));
    sets.extend_from_slice(more);
    Headline::new(name, "homogeneous-sphere.toml", &sets, seed)
}

/// `dom`'s own stats.
#[derive(Clone, Debug, Serialize)]
pub struct DomStats {
    pub grid: LatticeGeom,
    /// How finely the grid resolves the medium, against what dom was validated at.
    pub trust: GridTrust,
    /// How the swept and stored directions resolve the phase function, against what dom was
    /// validated with.
    pub directions_trust: DirectionsTrust,
    /// How far to trust the view march that gathers the swept field toward the camera
    /// (`dom.view_step`, `dom.view_shadow_step`).
    pub view_trust: view::ViewTrust,
    pub quadrature: String,
    pub directions: usize,
    /// The storage set (`1`: isotropic) and its size M.
    pub storage: String,
    pub storage_directions: usize,
    pub scheme: Scheme,
    pub channels: u32,
    /// The mean cosine the quadrature's normalised scattering carries (the medium's g on a
    /// fine set; a coarse one smears it toward 0).
    pub quadrature_g: f64,
    /// The forward peak truncated from the sweeps' scattering (`dom.delta_m`; f 0: none).
    pub truncation: Truncation,
    /// Whether the field was made (the direct source marched, the scattering iterations swept):
    /// false where nothing in the scene scatters (`Scene::scatters`). The view scatters the
    /// field toward the camera by sigma_s, so there it would carry nothing: the image is the
    /// view's camera-ray march alone, exactly as with the field.
    pub field: bool,
    /// A sequence's frame that went on from the last frame's state (`DomCarry`): its
    /// iterations are those after the change.
    pub warm_start: bool,
    pub iterations: u32,
    pub converged: bool,
    pub final_change: f64,
    /// With dom.extrapolate, where the extrapolated fluence converged: the increments' decay
    /// per iteration and the share of the fluence the added tail stands for.
    pub tail_ratio: Option<f64>,
    pub tail_share: Option<f64>,
    pub sweep_ms: f64,
    /// Block edge (0: whole-grid plane sweeps).
    pub block: u32,
    /// Blocks, pool slots, uploads and write-backs (block sweeps only).
    pub streaming: Option<StreamStats>,
    /// Device bytes of the block sweeps (pool and tables), within dom.budget.
    pub sweep_device_bytes: u64,
    /// The direct source was made in this many slabs of at most `source_layers` layers (one
    /// with plane sweeps; as many as dom.budget and one binding need with blocks).
    pub source_slabs: u32,
    pub source_layers: u32,
    /// Groups of beams per slab (each ray marches once per slab, in its group's pass).
    pub source_groups: u32,
    /// Device bytes of the direct source's grid-sized buffers and tables (the binning tables,
    /// one slab's deposit sums, sources and density), within dom.budget; the marcher's rays and
    /// history (`dom.rays`) come on top.
    pub source_device_bytes: u64,
    /// View runs: one, or one per slab of the light toward the camera under dom.budget.
    pub view_slabs: u32,
    /// Wall-clock ms of the render's stages, in order (setup, direct source, blocks,
    /// iterations, view): where the time goes when the GPU is not the bottleneck.
    pub stages_ms: Vec<(&'static str, f64)>,
}

impl DomStats {
    /// What the settings decide before anything runs (the grid and its trust, the directions,
    /// the storage, the scheme, the channels, the quadrature's g rounded to 1e-6), with nothing
    /// made: no field, no iteration, no sweep, one view. A render fills in what it did.
    fn of_settings(scene: &Scene, set: &DomSettings, nch: u32, quadrature_g: f64) -> DomStats {
        let geom = set.geom;
        DomStats {
            grid: geom,
            trust: geom.trust(scene, set.grid, &DOM_GRID),
            directions_trust: DirectionsTrust::new(
                scene.medium.g,
                &set.quadrature,
                &set.storage,
                set.truncation.f > 0.0,
            ),
            view_trust: view::ViewTrust::of(scene, &set.view),
            quadrature: set.quadrature.name.clone(),
            directions: set.quadrature.len(),
            storage: set.storage.name.clone(),
            storage_directions: set.storage.len(),
            scheme: set.scheme,
            channels: nch,
            quadrature_g: (quadrature_g * 1e6).round() / 1e6 + 0.0,
            truncation: set.truncation,
            field: false,
            warm_start: false,
            iterations: 0,
            converged: true,
            final_change: 0.0,
            tail_ratio: None,
            tail_share: None,
            sweep_ms: 0.0,
            block: 0,
            streaming: None,
            sweep_device_bytes: 0,
            view_slabs: 1,
            source_slabs: 0,
            source_layers: 0,
            source_groups: 0,
            source_device_bytes: 0,
            stages_ms: Vec::new(),
        }
    }
}

/// `dom.delta_m=auto` truncates the forward peak from this g up (docs/dom.md, "The forward peak
/// truncated"): where `dom.directions=auto` sweeps product-16x32 and the untruncated sweeps gave
/// 1.5-2.5x path's energy on the cube (truncated: 0.93-1.10x, in a quarter to a half of the
/// time). At g 0.9 it is mixed on thin media and worse on thick bright ones (0.85x path's energy
/// at sigma_t 20, albedo 0.99, where the full sweeps gave 0.98x), so there it stays off.
pub const DELTA_M_FROM: f32 = 0.95;

/// The forward peak truncated from the scattering between sweeps (`dom.delta_m`): HG(g) taken
/// as f delta(forward) + (1 - f) HG(g_rest), with f = g^2 and g_rest = g / (1 + g), the
/// delta-M split of Wiscombe (J. Atmos. Sci. 34, 1977) at M = 2 (Joseph, Wiscombe & Weinman's
/// delta-Eddington, J. Atmos. Sci. 33, 1976) with the rest kept a Henyey-Greenstein lobe. It keeps
/// the first moment, f + (1 - f) g_rest = g, and the similarity relation
/// sigma_s (1 - f) (1 - g_rest) = sigma_s (1 - g) (Wyman, Patterson & Buckner 1989) that fixes
/// the diffusion of multiply scattered light. The peak's share is exact transmission, so the
/// sweeps' sigma_t and sigma_s lose f sigma_s ([`extinction`]): the bounce series decays by
/// albedo (1 - f) / (1 - f albedo) instead of albedo (0.17 instead of 0.99 at g 0.999, albedo
/// 0.99), and the bounce-to-bounce scattering is a lobe of g_rest < 0.5 the directions resolve.
/// The direct source's shares (bin.comp) and the gather toward the camera (scatter.comp) keep the
/// medium's HG(g), split at the set's covering radius (peak interpolated, rest weighed by HG(g)):
/// normalised whole on a set that does not resolve it, HG(g) overweighted the far field.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Truncation {
    /// The share of the scattering in the forward peak (0: none).
    pub f: f64,
    /// The asymmetry of the rest (the medium's g where nothing is truncated).
    pub g_rest: f64,
}

impl Truncation {
    /// Nothing truncated: the sweeps scatter by HG(g) whole.
    pub fn none(g: f64) -> Truncation {
        Truncation { f: 0.0, g_rest: g }
    }

    /// The delta-M split for HG(g). Only a forward peak is truncated: a backward one (g < 0) is
    /// no transmission, so there nothing is.
    pub fn delta_m(g: f64) -> Truncation {
        if g <= 0.0 {
            return Truncation::none(g);
        }
        Truncation { f: g * g, g_rest: g / (1.0 + g) }
    }
}

#[derive(Clone)]
struct DomSettings {
    /// The voxel grid of the sweeps, the marching and the view's volume for `grid`, built once.
    geom: LatticeGeom,
    /// The grid knob's value `geom` was built for (voxels along the longest side).
    grid: u32,
    quadrature: Quadrature,
    storage: Quadrature,
    /// `dom.delta_m`: the forward peak truncated from the scattering between sweeps (f 0: off).
    truncation: Truncation,
    /// dom.delta_m was set to on (not auto): with block sweeps it is refused, where auto's is
    /// dropped.
    delta_m_set: bool,
    scheme: Scheme,
    tol: f64,
    max_iterations: u32,
    /// `dom.iterations_per_frame`: scattering iterations of each frame of a sequence after the
    /// first (None: to the tolerance).
    iterations_per_frame: Option<u32>,
    /// This frame stops at its budget by design (a sequence's): no "did not converge" warning.
    budgeted: bool,
    extrapolate: bool,
    /// Block edge (0: whole-grid plane sweeps; None: auto, decided by the device's binding
    /// limit), the device budget in bytes and the store.
    block: Option<u32>,
    /// dom.block was set to a number (not auto): past the device's loop limit it is refused,
    /// where auto's choice is lowered.
    block_set: bool,
    budget: Option<u64>,
    store: StoreKind,
    /// The queue role the streaming copies run on.
    copies: QueueRole,
    /// `dom.evict`; None: auto (overlap where the copies have a queue apart from the sweeps').
    evict: Option<Evict>,
    march: MarchSettings,
    view: ViewSettings,
}

impl DomSettings {
    fn parse(k: &Knobs, scene: &Scene) -> Result<DomSettings, SolverError> {
        // The default fitted to the medium (issue 44): 32 along the longest side, more for a thin
        // or optically thick medium, within DOM_GRID's budget.
        let grid: u32 = k.get_or("grid", DOM_GRID.fitted_grid(scene, 32, 512))?;
        let name: String = k.get("directions")?;
        // s6 resolves moderate anisotropy, a peaked phase function needs more directions
        // (directions::DIRECTIONS_FOR_G, the table the trust line judges by).
        let name = if name == "auto" { directions::auto_set(scene.medium.g).to_string() } else { name };
        let quadrature = Quadrature::named(&name).map_err(|e| k.invalid("directions", e))?;
        let stored: String = k.get("storage")?;
        // Model only what the scene needs: an isotropic medium scatters the same way into every
        // direction, so one storage direction holds its source exactly (thesis 5.1).
        let storage = match stored.as_str() {
            "auto" if scene.medium.g == 0.0 => Quadrature::isotropic(),
            "auto" | "directions" => quadrature.clone(),
            "1" => Quadrature::isotropic(),
            other => Quadrature::named(other).map_err(|e| k.invalid("storage", e))?,
        };
        let geom = LatticeGeom::new(scene, grid);
        let delta_m: String = k.get("delta_m")?;
        let truncate = match delta_m.as_str() {
            "on" => true,
            "auto" => scene.medium.g >= DELTA_M_FROM,
            _ => false,
        };
        let g = scene.medium.g as f64;
        let truncation = if truncate { Truncation::delta_m(g) } else { Truncation::none(g) };
        let scheme: String = k.get("scheme")?;
        let block: String = k.get("block")?;
        let budget: f64 = k.get("budget")?;
        let store: String = k.get("store")?;
        let streams = budget > 0.0 || k.is_set("store");
        if block == "0" && streams {
            return Err(k.invalid("budget", "dom.budget and dom.store stream blocks: set dom.block to 1..16 too"));
        }
        Ok(DomSettings {
            geom,
            grid,
            quadrature,
            storage,
            truncation,
            delta_m_set: delta_m == "on",
            scheme: if scheme == "step" { Scheme::Step } else { Scheme::Characteristics },
            tol: k.get("tol")?,
            max_iterations: k.get("max_iterations")?,
            iterations_per_frame: match k.is_set("iterations_per_frame") {
                true => Some(k.get("iterations_per_frame")?),
                false => None,
            },
            budgeted: false,
            extrapolate: k.get("extrapolate")?,
            block_set: block != "auto",
            block: match block.as_str() {
                "auto" if streams => Some(16),
                "auto" => None,
                n => Some(n.parse().map_err(|_| k.invalid("block", "not a whole number"))?),
            },
            budget: (budget > 0.0).then_some((budget * 1048576.0) as u64),
            store: match store.strip_prefix("file:") {
                Some(dir) => StoreKind::File(dir.into()),
                None => StoreKind::Memory,
            },
            copies: match k.get::<String>("copies")?.as_str() {
                "transfer" => QueueRole::Transfer,
                _ => QueueRole::Trace,
            },
            evict: match k.get::<String>("evict")?.as_str() {
                "belady" => Some(Evict::Belady),
                "overlap" => Some(Evict::Overlap),
                _ => None,
            },
            march: MarchSettings::parse(k, "dom", geom.lambda)?,
            view: ViewSettings::parse(k, "view_", scene)?,
        })
    }
}

fn sweep_setup<'a>(
    set: &'a DomSettings,
    geom: &LatticeGeom,
    nch: u32,
    g: f64,
    eye: Eye,
    sigma_t: &'a [f32],
    sigma_s: &'a [f32],
) -> SweepSetup<'a> {
    SweepSetup {
        dims: geom.dims,
        h: geom.lambda,
        origin: geom.origin,
        channels: nch,
        sigma_t,
        sigma_s,
        quadrature: &set.quadrature,
        storage: &set.storage,
        g,
        scatter_g: set.truncation.g_rest,
        eye,
        scheme: set.scheme,
    }
}

/// The view's slabs of the light toward the camera: the whole grid (None) where it fits
/// `budget` and one binding, else windows of whole layers, each holding one more layer each side
/// for the trilinear corners (so at least three held layers: [`SourcePlan::cut`] checks the
/// budget holds them), the first adding the direct light.
fn view_windows(plan: &SourcePlan, budget: Option<u64>, max_binding: u64) -> Vec<Option<MsWindow>> {
    let nz = plan.dims[2];
    let fits = budget.unwrap_or(u64::MAX).min(max_binding) / plan.view_layer().max(1);
    if fits >= nz as u64 {
        return vec![None];
    }
    let own = (fits.saturating_sub(2) as u32).max(1);
    (0..nz).step_by(own as usize).map(|lo| Some(MsWindow::new(lo, (lo + own).min(nz), nz, lo == 0))).collect()
}

/// The iteration's extrapolated tail (dom.extrapolate).
struct Tail {
    /// The bounces' decay per iteration, and the share of the fluence the tail stands for.
    ratio: f64,
    share: f64,
    /// The light toward the camera two iterations before the last, and the decay of its own
    /// pairs of bounces, rho^2 (at most the fluence's: its tail never counts more bounces).
    camera_before2: Vec<f32>,
    camera_ratio2: f64,
}

/// dom's light toward the camera (or a slab of it) as the view pass's volume.
fn ms_volume<'a>(energy: &'a Buffer, geom: &LatticeGeom, nch: u32, window: Option<MsWindow>) -> MsVolume<'a> {
    MsVolume {
        energy,
        dims: geom.dims,
        channels: nch,
        origin: geom.origin,
        lambda: geom.lambda,
        flux: FluxUse::None,
        window,
        forward: false,
    }
}

/// Plane sweeps keep the sweeper that made the direct source.
fn plane(s: &Option<Sweeper>) -> &Sweeper {
    s.as_ref().expect("plane sweeps keep their sweeper")
}

/// Channels dom's grids carry: one where the medium, every light and the emission are grey
/// (`gpu_scene::channels`, which counts the medium and the lights), else three: a grey medium
/// under white light still needs three when its Le is coloured (a blackbody grid always is).
fn channels(scene: &Scene, chromatic: bool) -> u32 {
    let grey_le = !scene.emissive()
        || match &scene.medium.emission {
            Emission::None => true,
            Emission::Constant(le) => is_grey(*le),
            Emission::Grid(g) => g.planes.len() == 1 && is_grey(g.scale),
        };
    gpu_scene::channels(scene, chromatic).max(if grey_le { 1 } else { 3 })
}

/// sigma_t and sigma_s (1/m) per voxel and channel, channel after channel, from the density, as
/// the sweeps take them: with a truncated forward peak (`t.f` > 0) the delta-M ones,
/// sigma_t (1 - f albedo) and sigma_s (1 - f) (Wiscombe 1977: the peak's share of the
/// scattering goes on as if unscattered), so sigma_a is unchanged and no energy is made.
fn extinction(m: &Medium, nch: u32, density: &[f32], t: Truncation) -> (Vec<f32>, Vec<f32>) {
    let (mut sigma_t, mut sigma_s) = (Vec::new(), Vec::new());
    for c in 0..nch as usize {
        let f = t.f as f32;
        let (st, a) = (m.sigma_t[c], m.albedo[c]);
        sigma_t.extend(density.iter().map(|d| st * d * (1.0 - f * a)));
        sigma_s.extend(density.iter().map(|d| a * st * d * (1.0 - f)));
    }
    (sigma_t, sigma_s)
}

/// `dom.block` auto: whole-grid plane sweeps (0) while their largest buffer (the field, or a
/// face array) fits one binding, else blocks of 16.
fn auto_block(gpu: &Gpu, set: &DomSettings) -> u32 {
    let slots = set.quadrature.by_octant().2.iter().copied().max().unwrap_or(1) as u64;
    let field = 8 * slots * set.geom.voxels() * 4;
    if field <= gpu.info().max_storage_buffer_range {
        0
    } else {
        16
    }
}

/// The block edge the sweeps can run on this device: on llvmpipe, where an invocation's loops end
/// silently past 65535 iterations, at most [`blocks::max_block`] for the directions: auto's
/// choice lowered to it, a set dom.block beyond it refused in one line naming the knob.
fn fit_block(gpu: &Gpu, k: &Knobs, set: &DomSettings, block: u32) -> Result<u32, SolverError> {
    // Real GPUs have no loop limiter, and there a larger block is the faster sweep.
    if block == 0 || !crate::solvers::parts::resumable::loop_limited(gpu) {
        return Ok(block);
    }
    let max = blocks::max_block(&set.quadrature, &set.storage, set.scheme);
    match (block <= max, set.block_set) {
        (true, _) => Ok(block),
        (false, false) => Ok(max),
        (false, true) => Err(k.invalid(
            "block",
            format!(
                "a block of {block}^3 at {} stored at {} runs {} loop iterations in one invocation of the block \
                 sweep, past the 65535 after which llvmpipe ends its loops silently: set dom.block={max} or less \
                 (or auto)",
                set.quadrature.name,
                set.storage.name,
                blocks::loop_iterations(block.min(MAX_BLOCK), &set.quadrature, &set.storage, set.scheme)
            ),
        )),
    }
}

/// What [`source_sweeper`] sets up: the density on the host (plane sweeps: read whole; blocks:
/// zeros, filled slab by slab), sigma_t and sigma_s where already made, the sweeper, the cut.
type SourceSweeper = (Vec<f32>, Option<(Vec<f32>, Vec<f32>)>, Sweeper, SourceCut);

/// The sweeper that receives the direct source, and how the source is cut. Plane sweeps take
/// the density whole (read back here: their sweeps need sigma_t and sigma_s from the start);
/// blocks get a density to fill slab by slab while the source is made.
fn source_sweeper(
    gpu: &Gpu,
    (gs, resampler): (&GpuScene, &Pipeline),
    set: &DomSettings,
    plan: &SourcePlan,
    (m, nch, eye): (&Medium, u32, Eye),
    block: u32,
) -> Result<SourceSweeper, SolverError> {
    let (geom, g) = (&set.geom, m.g as f64);
    if block == 0 {
        let d = marching::resample(gpu, gs, geom, resampler, 0, geom.dims[2])?;
        let density: Vec<f32> = gpu.read_buffer_as(&d)?;
        let (sigma_t, sigma_s) = extinction(m, nch, &density, set.truncation);
        let sweeper = Sweeper::new(gpu, &sweep_setup(set, geom, nch, g, eye, &sigma_t, &sigma_s))?;
        let cut = SourceCut { layers: geom.dims[2], group: plan.max_group() };
        Ok((density, Some((sigma_t, sigma_s)), sweeper, cut))
    } else {
        let cut = plan.cut(set, gpu.info().max_storage_buffer_range, block)?;
        let setup = sweep_setup(set, geom, nch, g, eye, &[], &[]);
        Ok((vec![0f32; geom.voxels() as usize], None, Sweeper::for_source(gpu, &setup, cut.layers)?, cut))
    }
}
/// The block sweeper (5.2.2's blocks streamed through dom.budget), holding the direct source.
fn block_sweeper(
    gpu: &Gpu,
    set: &DomSettings,
    setup: &SweepSetup,
    block: u32,
    first: Vec<f32>,
) -> Result<BlockSweeper, SolverError> {
    let opts = BlockOptions {
        block,
        budget: set.budget,
        store: set.store.clone(),
        copies: set.copies,
        evict: set.evict.unwrap_or({
            let m = gpu.info().mapping;
            if m.slot(set.copies) == m.slot(QueueRole::Diffuse) {
                Evict::Belady
            } else {
                Evict::Overlap
            }
        }),
    };
    let mut b = BlockSweeper::new(gpu, setup, &opts)?;
    b.set_first(gpu, &first)?;
    Ok(b)
}

/// The light toward the camera with the extrapolated tail: the last pair increment of the
/// gathered light times rho^2 / (1 - rho^2), added to the light the last iteration read (with a
/// tail, the iteration extrapolated, so it read it: no second readback or gather).
/// A warm-started frame's bounces are signed (`DomCarry`: where the light left, the light
/// toward the camera falls bounce by bounce): its tail is signed too, the sum kept non-negative.
fn with_tail(t: &Tail, cameras: &mut Vec<Vec<f32>>, signed: bool) -> Vec<f32> {
    let mut camera = cameras.pop().expect("an extrapolating iteration reads the light toward the camera");
    let f = (t.camera_ratio2 / (1.0 - t.camera_ratio2)) as f32;
    match signed {
        false => camera.iter_mut().zip(&t.camera_before2).for_each(|(c, p)| *c += (*c - p).max(0.0) * f),
        true => camera.iter_mut().zip(&t.camera_before2).for_each(|(c, p)| *c = (*c + (*c - p) * f).max(0.0)),
    }
    camera
}

/// What a frame of a sequence hands the next ([`DomAnimation`]): the state of its scattering
/// iterations. The transport equation is linear in its source: with L = T(q + K L) (T the
/// sweep, K the scattering, q the first-scattering and emitted source), the last frame left
/// C = its bounces summed and S = its pending source (what the next sweep would have propagated,
/// the series not yet summed), so this frame's solution is C plus the bounce series of the source
/// (q' - q) + S, q' this frame's own. A light move makes q' - q small where the light barely
/// moved: the series starts at the change, not at the whole light, and needs fewer bounces to
/// the tolerance. Its bounces are signed (where the light left they take light away): the
/// convergence test takes |bounce| (glsl/ordinates/converge.comp), the tail is signed, and the
/// light toward the camera is kept non-negative. Valid for the same grid, channels, storage
/// directions and eye (the light toward the camera is the eye's); a change of those starts from
/// zero.
struct DomCarry {
    shape: ([u32; 3], u32, usize, [f32; 4]),
    /// S - q ([c][m][v]): the source its next sweep would have propagated less the
    /// first-scattering source it swept first, so the next frame sweeps q' + (S - q) first (one
    /// grid of sources kept on the host, not two; where the light did not move the difference
    /// costs S a rounding of q's size, 1e-7 of q, against S of the tolerance's).
    offset: Vec<f32>,
    /// Its bounces' fluence summed, and their light toward the camera ([c][v]).
    accum: Vec<f32>,
    camera: Vec<f32>,
}

/// A `dom` sequence (`animate`, `view`): every frame marches its light anew and goes on from the
/// last frame's state ([`DomCarry`]), to the tolerance or `dom.iterations_per_frame` iterations
/// after the first frame. Block sweeps keep no state (their sweeps' state streams through host
/// memory or a file): there every frame starts from zero, said once.
struct DomAnimation {
    knobs: Knobs,
    set: DomSettings,
    converge: bool,
    force_full: bool,
    carry: Option<DomCarry>,
    said: bool,
}

impl Animation for DomAnimation {
    fn frame(&mut self, gpu: &Gpu, scene: &Scene, progress: &dyn Fn(Progress)) -> Result<RenderOutput, SolverError> {
        if !scene.scatters() {
            return Dom.render_unscattered(gpu, scene, self.force_full, &self.knobs, &self.set);
        }
        let mut set = self.set.clone();
        if let (false, Some(k), Some(_)) = (self.converge, set.iterations_per_frame, &self.carry) {
            set.max_iterations = k;
            set.budgeted = true;
        }
        let last = self.carry.take();
        let (mut out, carry) = Dom.render_with(gpu, scene, self.force_full, &self.knobs, &set, progress, Some(last))?;
        if carry.is_none() && !self.said {
            out.report.warnings.push(
                "dom: block sweeps (dom.block) keep no state between frames: every frame starts from zero".into(),
            );
            self.said = true;
        }
        self.carry = carry;
        Ok(out)
    }
}

/// dom's stats (its own, with the sweeps' time from the report's passes), the convergence and its
/// warning, the non-finite pixels, and the transport community's
/// figures (Kripke, SNAP): cell-direction updates per second of sweep time and the grind time,
/// ns per cell, direction and iteration. The bandwidth is modelled: an update reads sigma_t,
/// the source, three upwind radiances and writes one (24 bytes; an upsampled source reads M
/// more).
fn dom_stats(
    mut ds: DomStats,
    set: &DomSettings,
    report: &mut RenderReport,
    nonfinite: u32,
    (upsampled, storage_m): (bool, usize),
) -> Stats {
    let (iterations, converged, change) = (ds.iterations, ds.converged, ds.final_change);
    let sweeps = report.passes.iter().filter(|p| p.name == "ordinates.sweep" || p.name == "dom.block_sweep");
    ds.sweep_ms = sweeps.map(|p| p.duration_ms()).sum();
    if !converged && !set.budgeted {
        report.warnings.push(format!(
            "dom: the scattering iterations did not converge in {iterations} iterations (change {change:.2e}, tolerance \
             {:.1e}); raise dom.max_iterations or dom.tol",
            set.tol
        ));
    }
    // Where nothing scatters no field is made: the grid's and directions' trust does not apply.
    report.warnings.extend(ds.trust.warning().filter(|_| ds.field));
    report.warnings.extend(ds.directions_trust.warning().filter(|_| ds.field));
    report.warnings.extend(ds.view_trust.warning("dom"));
    report.zeroed_nonfinite(nonfinite);
    let updates = ds.grid.voxels() as f64 * set.quadrature.len() as f64 * ds.channels as f64 * iterations as f64;
    let sweep_ms = ds.sweep_ms;
    let mut stats = Stats::new(ds);
    stats.convergence =
        Some(Convergence { iterations: iterations as u64, converged, final_change: change, tolerance: set.tol });
    stats.faults = nonfinite as u64;
    if sweep_ms > 0.0 {
        let per_second = updates / (sweep_ms / 1e3);
        let bytes = 24.0 + if upsampled { 4.0 * storage_m as f64 } else { 0.0 };
        stats.throughput = vec![
            Figure { figure: "cell-direction updates/s".into(), value: per_second, unit: "1/s".into() },
            Figure { figure: "grind time".into(), value: 1e9 / per_second, unit: "ns".into() },
            Figure { figure: "sweep modelled bandwidth".into(), value: per_second * bytes / 1e9, unit: "GB/s".into() },
        ];
    }
    stats
}

/// Fewest scattering iterations per submission with the convergence test on the device: the
/// host waits at most once per 8.
pub const ITERATIONS_MIN: u32 = 8;
/// Most iterations per submission.
pub const ITERATIONS_MAX: u32 = 64;
/// The GPU work a submission aims at, milliseconds (issue 42: 5-20 ms); batches grow above
/// ITERATIONS_MIN only where iterations take less than this / ITERATIONS_MIN.
const BATCH_TARGET_MS: f64 = 12.0;

/// How the scattering iterations ended: iterations, converged, the last change, the tail,
/// and (with a tail) the light toward the camera after the last iteration.
type IterationEnd = (u32, bool, f64, Option<Tail>, Vec<Vec<f32>>);

/// What making the direct source left: the once-scattered source per storage direction (with
/// blocks; plane sweeps keep it on the device), the bytes it held, and how it was cut.
struct DirectSource {
    first: Vec<f32>,
    /// Device bytes within dom.budget (the sweeper, the binning, a slab's sums and density),
    /// and with the marcher's too.
    budgeted: u64,
    source_bytes: u64,
    slabs: u32,
    layers: u32,
    groups: u32,
}

/// The marched light's part of the direct source: the marcher, its beams in groups, and the
/// buffers the deposits are summed and binned through (the sums per beam of a group, each ray's
/// beam, the beam table).
struct Marched<'a> {
    marcher: &'a Marcher,
    groups: Vec<BeamGroup>,
    sums: Buffer,
    ray_beam: Buffer,
    table: Buffer,
}

/// The first-scattering source (thesis 5.2): the light marched, each voxel's deposits summed per
/// beam, slab by slab and group by group of beams, each ray marching from its start once per
/// slab in its group's pass (the same steps: each voxel's integer sum is the same whatever the
/// cut, and the groups are binned in beam order, so the source is the same bits). With blocks
/// the density is resampled slab by slab into `density` and the source read back per slab.
/// An emissive medium (`emit`, [`ordinates::EMIT`]'s pipeline) adds its own source sigma_a Le
/// to each slab's once all its beams are binned (glsl/ordinates/emit.comp): the first sweep
/// carries the emitted light beside the once-scattered direct light. A scene lit by its emission
/// alone has no marcher (no light, no beam): its source is the emission alone.
#[allow(clippy::too_many_arguments)]
fn direct_source(
    gpu: &Gpu,
    (gs, resampler, geom): (&GpuScene, &Pipeline, &LatticeGeom),
    marcher: Option<Marcher>,
    emit: Option<&Pipeline>,
    sweeper: &Sweeper,
    (cut, block, nch, g): (SourceCut, u32, u32, f64),
    density: &mut [f32],
    progress: &dyn Fn(Progress),
) -> Result<DirectSource, SolverError> {
    let v = geom.voxels() as usize;
    let layers = cut.layers;
    // The plan's group is within what one bin pass can share (SourcePlan::max_group).
    if let Some(m) = &marcher {
        debug_assert!(cut.group <= sweeper.bin_group(&m.beams));
    }
    let group = cut.group;
    let lit = match &marcher {
        Some(m) => Some(Marched {
            marcher: m,
            groups: BeamGroup::split(&m.ray_beam, m.beams.len() as u32, group),
            sums: sweeper.deposit_sums(gpu, group as usize)?,
            ray_beam: gpu.buffer_with("dom ray beams", &m.ray_beam)?,
            table: gpu.buffer_with("dom beams", &sweeper.beam_table(g, &m.beams))?,
        }),
        None => None,
    };
    let groups = lit.as_ref().map_or(0, |l| l.groups.len());
    let layer = geom.dims[0] * geom.dims[1];
    let slabs: Vec<Slab> = (0..geom.dims[2])
        .step_by(layers as usize)
        .map(|z0| Slab { z0, layers: layers.min(geom.dims[2] - z0), layer })
        .collect();
    let storage_m = sweeper.storage.len();
    let mut first = if block > 0 { vec![0f32; nch as usize * storage_m * v] } else { Vec::new() };
    let rounds = lit.as_ref().map_or(0, |l| l.marcher.rounds);
    let work = (rounds as usize * slabs.len() * groups) as u64;
    let mut density_bytes = 0;
    // Plane sweeps' emission reads the whole grid's density (resampled once, kept on the host).
    let whole_density = match emit {
        Some(_) if block == 0 => Some(gpu.buffer_with("dom density (emission)", density)?),
        _ => None,
    };
    for (si, slab) in slabs.iter().enumerate() {
        let slab = *slab;
        let slab_density = if block > 0 {
            let d = marching::resample(gpu, gs, geom, resampler, slab.z0, slab.layers)?;
            density_bytes = density_bytes.max(d.size());
            let base = slab.base() as usize;
            density[base..base + slab.voxels() as usize].copy_from_slice(&gpu.read_buffer_as::<f32>(&d)?);
            Some(d)
        } else {
            None
        };
        if let Some(Marched { marcher, groups, sums, ray_beam, table }) = &lit {
            for (gi, group) in groups.iter().enumerate() {
                let i = si * groups.len() + gi;
                if i > 0 {
                    if gi == 0 {
                        marcher.reset(gpu)?;
                    }
                    gpu.fill_zero(sums)?;
                }
                // The rounds in submissions of ROUNDS_PER_SUBMIT (march, deposit) pairs: one wait
                // per batch rather than per round (the passes' hazards put the barriers between
                // them).
                let k = marcher.history_slots();
                let mut round = 0;
                while round < marcher.rounds {
                    let done = (i * marcher.rounds as usize + round as usize) as u64;
                    progress(Progress::work("marching the direct source", done, work));
                    let batch = ROUNDS_PER_SUBMIT.min(marcher.rounds - round);
                    round += batch;
                    if group.rays.is_empty() {
                        continue;
                    }
                    let passes: Vec<Pass> = (0..batch)
                        .flat_map(|_| {
                            [
                                marcher.march_pass(gs, group.rays.clone()),
                                sweeper.deposit_pass(&marcher.history, ray_beam, k, group, marcher.scale, sums, slab),
                            ]
                        })
                        .collect();
                    let point = gpu.submit(QueueRole::Trace, &passes, &[])?;
                    gpu.wait(point)?;
                }
                // Each voxel's once-scattered power per beam, shared among the storage
                // directions: the first-scattering source (per unit volume and sr).
                let bin = sweeper.bin_pass(sums, table, group, marcher.scale, slab);
                let point = gpu.submit(QueueRole::Diffuse, &[bin], &[])?;
                gpu.wait(point)?;
            }
        }
        // The medium's own source sigma_a Le, isotropic, in the same units (issue 47); it starts
        // the source where no beam was binned.
        if let Some(emit) = emit {
            let d = slab_density.as_ref().or(whole_density.as_ref()).expect("a density for the emission");
            let pass = sweeper.emit_pass(emit, gs, d, slab, groups == 0);
            let point = gpu.submit(QueueRole::Diffuse, &[pass], &[])?;
            gpu.wait(point)?;
        }
        if block > 0 {
            let part = sweeper.read_first(gpu, slab)?;
            let (sv, base) = (slab.voxels() as usize, slab.base() as usize);
            for (cm, chunk) in part.chunks_exact(sv).enumerate() {
                first[cm * v + base..cm * v + base + sv].copy_from_slice(chunk);
            }
        }
    }
    progress(Progress::work("marching the direct source", work, work));
    if let Some(l) = &lit {
        // (dom marches no mesh: a round's cost is k steps and is far within the limiter;
        // read as lbl's is, so a change that broke that would be caught.)
        l.marcher.check_loops(gpu)?;
    }
    if block == 0 {
        density_bytes = geom.voxels() * 4;
    }
    // Device bytes while the direct source is made: the marcher, the binning and the slab's
    // sums and density (with plane sweeps the sweeper is all of the grid's buffers).
    let lit_bytes = lit.as_ref().map_or(0, |l| l.sums.size() + l.table.size());
    let budgeted = sweeper.device_bytes() + lit_bytes + density_bytes;
    let source_bytes = budgeted + lit.as_ref().map_or(0, |l| l.marcher.device_bytes() + l.ray_beam.size());
    drop(lit);
    drop(marcher);
    Ok(DirectSource { first, budgeted, source_bytes, slabs: slabs.len() as u32, layers, groups: groups as u32 })
}

/// The view pass over the light each voxel scatters toward the camera (as the energy per voxel
/// that the view scatters isotropically: fluence = energy / lambda^2, as lbl's lattice). Plane
/// sweeps hand it their camera buffer; with blocks the pool goes first, and the view takes the
/// volume in slabs of whole layers where it does not fit dom.budget (or one binding): one view
/// run per slab, the images added (view::MsWindow). Returns the view's result, the sweeps'
/// device bytes, the streaming stats, the pool's bytes and the number of view slabs.
#[allow(clippy::too_many_arguments)]
fn view_step(
    gpu: &Gpu,
    scene: &Scene,
    gs: &GpuScene,
    set: &DomSettings,
    plan: &SourcePlan,
    nch: u32,
    blocked: Option<BlockSweeper>,
    sweeper: &Option<Sweeper>,
    camera_with_tail: Option<Vec<f32>>,
) -> Result<(view::ViewResult, u64, Option<StreamStats>, u64, u32), SolverError> {
    let geom = &set.geom;
    let (v, layer) = (geom.voxels() as usize, geom.dims[0] * geom.dims[1]);
    Ok(match blocked {
        Some(b) => {
            let (stats, pool) = (b.stats, b.device_bytes());
            let camera = camera_with_tail.unwrap_or_else(|| b.camera());
            drop(b);
            let windows = view_windows(plan, set.budget, gpu.info().max_storage_buffer_range);
            let mut total: Option<view::ViewResult> = None;
            for w in &windows {
                let part = match w {
                    Some(w) => {
                        let (first, count) = ((w.held[0] * layer) as usize, (w.held[1] * layer) as usize);
                        let held: Vec<f32> =
                            camera.chunks_exact(v).flat_map(|c| &c[first..first + count]).copied().collect();
                        gpu.buffer_with("dom toward the camera (slab)", &held)?
                    }
                    None => gpu.buffer_with("dom toward the camera", &camera)?,
                };
                let mut r = view::march(gpu, scene, gs, &set.view, Some(&ms_volume(&part, geom, nch, *w)))?;
                r.device_bytes += part.size();
                total = Some(match total {
                    None => r,
                    Some(mut t) => {
                        t.image.data.iter_mut().zip(&r.image.data).for_each(|(a, b)| *a += b);
                        t.dispatches += r.dispatches;
                        t.max_loop_iterations = t.max_loop_iterations.max(r.max_loop_iterations);
                        t.nonfinite_pixels += r.nonfinite_pixels;
                        t.device_bytes = t.device_bytes.max(r.device_bytes);
                        t
                    }
                });
            }
            let res = total.expect("at least one view window");
            (res, pool, Some(stats), pool, windows.len() as u32)
        }
        None => {
            let res =
                view::march(gpu, scene, gs, &set.view, Some(&ms_volume(&plane(sweeper).camera, geom, nch, None)))?;
            (res, plane(sweeper).device_bytes(), None, 0, 1)
        }
    })
}

/// The iterations' progress line: iteration `iterations` changed the fluence by `shown` (the
/// extrapolated change where it is the smaller); `last` is the previous report, for the rate.
fn show_iteration(
    progress: &dyn Fn(Progress),
    set: &DomSettings,
    iterations: u32,
    shown: f64,
    last: &mut Option<(f64, u64)>,
) {
    let left = (set.max_iterations - iterations) as u64;
    progress(Progress::converging("scattering iterations", iterations as u64, shown, set.tol, *last, left));
    *last = Some((shown, iterations as u64));
}

/// The scattering iterations tested on the host (block streaming, or a device without double
/// precision): a wait and a readback of the fluence (and of the light toward the camera) per
/// iteration; the tail as [`iterate_on_device`] takes it (see `Dom::render`).
/// `fluence` ([c][v]) holds the bounces summed before (zeros from a cold start, a sequence's
/// carried sum where it goes on: `DomCarry`) and is left holding the sum after.
fn iterate_on_host(
    gpu: &Gpu,
    blocked: &mut Option<BlockSweeper>,
    sweeper: &Option<Sweeper>,
    set: &DomSettings,
    fluence: &mut [f32],
    progress: &dyn Fn(Progress),
) -> Result<IterationEnd, SolverError> {
    let read_camera = |blocked: &Option<BlockSweeper>, sweeper: &Option<Sweeper>| -> Result<Vec<f32>, SolverError> {
        Ok(match blocked {
            Some(b) => b.camera(),
            None => gpu.read_buffer_as(&plane(sweeper).camera)?,
        })
    };
    // Magnitudes, as glsl/ordinates/converge.comp takes them: a warm-started frame's bounces and
    // camera increments are signed (DomCarry), and summed signed they cancel; a cold start's are
    // never negative, so there these are the plain sums.
    let diff_sum = |a: &[f32], b: &[f32]| -> f64 { a.iter().zip(b).map(|(x, y)| (*x as f64 - *y as f64).abs()).sum() };
    let abs_sum = |a: &[f32]| -> f64 { a.iter().map(|x| (*x as f64).abs()).sum() };
    let sum = |a: &[f32]| -> f64 { a.iter().map(|x| *x as f64).sum() };
    let abs_peak = |a: &[f32]| -> f64 { a.iter().fold(0.0f64, |m, x| m.max((*x as f64).abs())) };
    let max_diff = |a: &[f32], b: &[f32]| -> f64 {
        a.iter().zip(b).fold(0.0f64, |m, (x, y)| m.max((*x as f64 - *y as f64).abs()))
    };
    let peak = |a: &[f32]| -> f64 { a.iter().fold(0.0f64, |m, x| m.max(*x as f64)) };
    // rho^2 from the sums of the pairs of bounces (newest last), when it is a decay.
    let decay2 = |s: &[f64]| -> Option<f64> {
        match s {
            [.., a, _, c] if *a > 0.0 && *c > 0.0 => Some(c / a).filter(|r| *r < 1.0),
            _ => None,
        }
    };
    // The fluence summed over the bounces, the last bounce's, and the light toward the camera
    // (summed on the device) after the last two iterations (newest last).
    let mut last_bounce = vec![0.0f32; fluence.len()];
    let mut cameras: Vec<Vec<f32>> = Vec::new();
    let (mut pair_sums, mut camera_pair_sums) = (Vec::<f64>::new(), Vec::<f64>::new());
    let mut previous_extrapolated = None::<Vec<f32>>;
    let (mut iterations, mut converged, mut change) = (0u32, false, f64::INFINITY);
    let mut last_change: Option<(f64, u64)> = None;
    let mut tail: Option<Tail> = None;
    while iterations < set.max_iterations {
        let bounce = match blocked.as_mut() {
            Some(b) => b.iterate(gpu)?,
            None => plane(sweeper).iterate(gpu)?,
        };
        iterations += 1;
        fluence.iter_mut().zip(&bounce).for_each(|(f, b)| *f += b);
        let scale = peak(fluence);
        // What this bounce added, against the summed fluence's largest value.
        change = abs_peak(&bounce) / if scale > 0.0 { scale } else { 1.0 };
        let mut extrapolated_change = None;
        let mut ratio = None;
        // The light toward the camera two iterations back.
        let mut camera_before2 = None;
        if set.extrapolate {
            let camera = read_camera(blocked, sweeper)?;
            if cameras.len() == 2 {
                let b2 = cameras.remove(0);
                camera_pair_sums.push(diff_sum(&camera, &b2));
                camera_before2 = Some(b2);
            }
            cameras.push(camera);
            if iterations >= 2 {
                pair_sums.push(abs_sum(&bounce) + abs_sum(&last_bounce));
            }
            ratio = decay2(&pair_sums);
            match ratio {
                Some(r2) => {
                    let f = (r2 / (1.0 - r2)) as f32;
                    let e: Vec<f32> =
                        fluence.iter().zip(&bounce).zip(&last_bounce).map(|((t, b), l)| t + (b + l) * f).collect();
                    if let Some(pe) = &previous_extrapolated {
                        extrapolated_change = Some(max_diff(&e, pe) / peak(&e).max(f64::MIN_POSITIVE));
                    }
                    previous_extrapolated = Some(e);
                }
                None => previous_extrapolated = None,
            }
        }
        let shown = extrapolated_change.map_or(change, |e| e.min(change));
        show_iteration(progress, set, iterations, shown, &mut last_change);
        if change <= set.tol {
            converged = true;
        } else if let (Some(e), Some(r2)) = (extrapolated_change, ratio) {
            if e <= set.tol {
                converged = true;
                change = e;
                // The pair the decay was taken from (pushed above), not summed again.
                let pair = *pair_sums.last().expect("a decay needs pairs");
                let total = sum(fluence);
                let added = pair * r2 / (1.0 - r2);
                tail = Some(Tail {
                    ratio: r2.sqrt(),
                    share: added / (total + added).max(f64::MIN_POSITIVE),
                    camera_ratio2: decay2(&camera_pair_sums)
                        .filter(|_| camera_before2.is_some())
                        .map_or(0.0, |c| c.min(r2)),
                    camera_before2: camera_before2.take().unwrap_or_default(),
                });
            }
        }
        last_bounce = bounce;
        if converged {
            break;
        }
    }
    Ok((iterations, converged, change, tail, cameras))
}

/// 5.3.3-5.3.4, the progressive scattering iterations, each sweeping every channel on the
/// device; the host reads the fluence of each bounce to judge convergence and sums them.
/// Iteration n sweeps the light scattered n - 1 times (the thesis's G''), so its fluence
/// is the n-th bounce's, computed as such rather than as the difference of two nearly
/// equal totals. Once the bounces decay geometrically, the bounces not yet swept add up to
/// a geometric tail. It is taken over pairs of iterations: a back-scattering medium's
/// slow modes alternate in sign (at g -0.9 the ratio of successive bounces swings
/// 0.73 / 0.76 / 0.74 ...), and the last bounce alone, times r / (1 - r), put the image
/// 1.6e-4 above the converged one. With the pair P_n = B_n + B_(n-1) and
/// rho^2 = sum P_n / sum P_(n-2), the tail is P_n rho^2 / (1 - rho^2): exact for the
/// slowest mode, the alternating ones damped. With dom.extrapolate the convergence is
/// tested on the extrapolated fluence (same tolerance, between successive iterations), and
/// at convergence the same tail (with the light toward the camera's own decay, at most the
/// fluence's) is added to that light.
/// With plane sweeps on a device with double precision the test runs on the device
/// (glsl/ordinates/converge.comp, the same arithmetic): batches of at least
/// ITERATIONS_MIN iterations are one submission each, stopped on the device at the
/// iteration that converged, and the host waits once per batch. Block streaming, and
/// devices without double precision, test on the host: a wait and a readback of the
/// fluence (and of the light toward the camera) per iteration.
///
/// The scattering iterations with the convergence test on the device
/// (glsl/ordinates/converge.comp; the criterion and tail as [`iterate_on_host`]'s).
fn iterate_on_device(
    gpu: &Gpu,
    sw: &Sweeper,
    set: &DomSettings,
    progress: &dyn Fn(Progress),
) -> Result<IterationEnd, SolverError> {
    let (mut iterations, mut converged, mut change) = (0u32, false, f64::INFINITY);
    let (mut tail, mut cameras) = (None, Vec::new());
    let mut batch = ITERATIONS_MIN;
    let mut last: Option<(f64, u64)> = None;
    while iterations < set.max_iterations {
        let b = batch.min(set.max_iterations - iterations);
        let mut passes: Vec<Pass> = if iterations == 0 { vec![sw.control_clear_pass()] } else { Vec::new() };
        passes.extend((1..=b).flat_map(|j| sw.iteration_passes(iterations + j, set.extrapolate, set.tol)));
        passes.push(sw.control_copy_pass());
        let started = std::time::Instant::now();
        let point = gpu.submit(QueueRole::Diffuse, &passes, &[])?;
        gpu.wait(point)?;
        let ctl = sw.control(gpu)?;
        let ran = ctl.iterations.wrapping_sub(iterations);
        if ran == 0 || ran > b || (ran < b && ctl.stopped == 0) {
            return Err(SolverError::Unsupported(format!(
                "dom: the device judged {ran} of a batch of {b} iterations; please report this"
            )));
        }
        iterations = ctl.iterations;
        let per = started.elapsed().as_secs_f64() * 1e3 / ran as f64;
        batch = ((BATCH_TARGET_MS / per.max(1e-3)) as u32).clamp(ITERATIONS_MIN, ITERATIONS_MAX);
        change = ctl.change;
        let shown = if ctl.ext_ok != 0 { ctl.ext_change.min(ctl.change) } else { ctl.change };
        show_iteration(progress, set, iterations, shown, &mut last);
        if ctl.stopped != 0 {
            converged = true;
            if ctl.tail != 0 {
                cameras.push(gpu.read_buffer_as(&sw.camera)?);
                tail = Some(Tail {
                    ratio: ctl.r2.sqrt(),
                    share: ctl.share,
                    camera_ratio2: ctl.camera_ratio2,
                    camera_before2: sw.camera_after(gpu, iterations.saturating_sub(2), iterations)?.unwrap_or_default(),
                });
            }
            break;
        }
    }
    Ok((iterations, converged, change, tail, cameras))
}

/// The direct source's device memory, slab by slab of whole layers (thesis 5.2.2 streams the
/// source by blocks; runs of layers are blocks as wide as the grid, which the marched rays and
/// the bin pass need no halo for), and group by group of beams. What a slab holds: per beam of
/// the group and channel the deposits' sums, per channel and storage direction the
/// first-scattering source (read back to the host, where the block sweeps take it), and the
/// resampled density. Beside
/// it the binning tables and the beam table; the marcher's rays and history are `dom.rays`'s,
/// not the grid's, and dom.budget leaves them out.
///
/// Every ray marches once per slab (in its group's pass), so the marching costs the number of
/// slabs; fewer beams per group make a layer smaller and the slabs thicker. The plan takes the
/// fewest slabs, and of those the largest groups (fewer, fuller dispatches).
struct SourcePlan {
    dims: [u32; 3],
    beams: u64,
    /// Bytes per layer: the sums of one beam, and the first-scattering source and density.
    layer_beam: u64,
    layer_rest: u64,
    /// Bytes per layer of one storage direction's source (with the sums, what one binding holds).
    layer_source: u64,
    /// The binning tables and the beam table.
    fixed: u64,
    channels: u32,
    /// The most beams one bin pass can share (`ordinates::bin_group`: bin.comp's loops).
    bin_group: u32,
}

/// How the direct source is made: slabs of at most `layers` layers, groups of at most `group`
/// beams.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct SourceCut {
    layers: u32,
    group: u32,
}

impl SourcePlan {
    fn new(set: &DomSettings, geom: &LatticeGeom, nch: u32, beams: &[Beam]) -> SourcePlan {
        let point = beams.iter().any(|b| matches!(b, Beam::FromPoint(_)));
        let beams = beams.len() as u64;
        let layer = geom.dims[0] as u64 * geom.dims[1] as u64;
        let (nch64, m) = (nch as u64, set.storage.len() as u64);
        SourcePlan {
            dims: geom.dims,
            beams,
            layer_beam: layer * 4 * nch64,
            layer_rest: layer * 4 * (nch64 * m + 1), // the slab's first-scattering source and density
            layer_source: layer * 4 * nch64 * m,
            fixed: Sweeper::bytes(geom.voxels(), nch64, &set.quadrature, &set.storage, set.scheme, false, 0)
                + beams * 32,
            channels: nch,
            bin_group: bin_group(m, nch64, point),
        }
    }

    /// The largest group of beams one bin pass takes: all of them where the loops allow.
    fn max_group(&self) -> u32 {
        (self.beams.max(1) as u32).min(self.bin_group)
    }

    /// Bytes of one layer of the light toward the camera (all channels) that the view reads.
    fn view_layer(&self) -> u64 {
        self.dims[0] as u64 * self.dims[1] as u64 * self.channels as u64 * 4
    }

    /// Bytes of one layer with groups of `group` beams.
    fn layer_bytes(&self, group: u32) -> u64 {
        group as u64 * self.layer_beam + self.layer_rest
    }

    /// Device bytes of a slab of `layers` layers with groups of `group` beams and the tables
    /// (the marcher's rays apart).
    fn bytes(&self, cut: SourceCut) -> u64 {
        self.fixed + cut.layers as u64 * self.layer_bytes(cut.group)
    }

    /// The cut: the whole grid and every beam at once unless `budget` (bytes) or one binding
    /// (`max_binding`) asks for less. A budget below one layer of one beam, the block sweeps'
    /// working set or three layers of the view's volume is one line naming the smallest that
    /// holds them all.
    fn cut(&self, set: &DomSettings, max_binding: u64, block: u32) -> Result<SourceCut, SolverError> {
        let nz = self.dims[2];
        let beams = self.max_group();
        if let Some(budget) = set.budget {
            let (layout, fixed) = BlockSweeper::plan(
                self.dims,
                self.channels,
                &set.quadrature,
                &set.storage,
                set.scheme,
                block.min(MAX_BLOCK),
            );
            let sweeps = blocks::working_set(&layout, fixed);
            let source = self.bytes(SourceCut { layers: 1, group: 1 });
            let view = self.view_layer() * nz.min(3) as u64;
            let need = sweeps.max(source).max(view);
            if budget < need {
                return Err(SolverError::Unsupported(format!(
                    "dom.budget = {:.2} MiB is below this render's working set (sweeps: {} blocks of {} KiB, {} KiB \
                     of scratch and {} KiB of tables; direct source: one layer of {} KiB and {} KiB of tables; view: \
                     {} layers of {} KiB): set dom.budget to at least {} (MiB) or a smaller dom.block",
                    budget as f64 / 1048576.0,
                    layout.min_slots(),
                    (layout.record() * 4) >> 10,
                    (layout.scratch() * 4) >> 10,
                    fixed >> 10,
                    self.layer_bytes(1) >> 10,
                    self.fixed >> 10,
                    nz.min(3),
                    self.view_layer() >> 10,
                    (need as f64 / 1048576.0 * 100.0).ceil() / 100.0
                )));
            }
        }
        // The most layers with groups of `group`: within the budget, and each buffer in one binding.
        let layers = |group: u32| -> u32 {
            let widest = (group as u64 * self.layer_beam).max(self.layer_source).max(1);
            let by_binding = max_binding / widest;
            let by_budget = set.budget.map_or(u64::MAX, |b| (b - self.fixed) / self.layer_bytes(group));
            by_binding.min(by_budget).min(nz as u64) as u32
        };
        let slabs = |group: u32| nz.div_ceil(layers(group).max(1));
        let best = (1..=beams).rev().filter(|g| layers(*g) > 0).min_by_key(|g| slabs(*g)).ok_or_else(|| {
            SolverError::Unsupported(format!(
                "one layer of dom's direct source ({} KiB of source per storage direction, {} KiB of deposit sums \
                     per beam) exceeds this device's largest binding ({} MiB): lower dom.grid or dom.storage",
                self.layer_source >> 10,
                self.layer_beam >> 10,
                max_binding >> 20
            ))
        })?;
        Ok(SourceCut { layers: layers(best), group: best })
    }
}

impl Dom {
    /// A render with parsed settings. `carry`: a sequence's frame (`DomAnimation`), with the last
    /// frame's state where there is one; the frame's own state is returned for the next (None
    /// where the sweeps cannot carry one: block sweeps).
    #[allow(clippy::too_many_arguments)]
    fn render_with(
        &self,
        gpu: &Gpu,
        scene: &Scene,
        force_full: bool,
        k: &Knobs,
        set: &DomSettings,
        progress: &dyn Fn(Progress),
        carry: Option<Option<DomCarry>>,
    ) -> Result<(RenderOutput, Option<DomCarry>), SolverError> {
        let mut stages: Vec<(&'static str, f64)> = Vec::new();
        // Block sweeps keep every block in host memory: refused before any work where the host
        // has not that much free (the marching and the direct source at grid 512 ran for
        // minutes before the store of 116 GiB was asked for).
        let block = fit_block(gpu, k, set, set.block.unwrap_or_else(|| auto_block(gpu, set)))?;
        let untruncated;
        let set = if block > 0 && set.truncation.f > 0.0 && !set.delta_m_set {
            // auto's truncation is for plane sweeps (below).
            untruncated = DomSettings { truncation: Truncation::none(scene.medium.g as f64), ..set.clone() };
            &untruncated
        } else {
            set
        };
        if block > 0 && set.truncation.f > 0.0 {
            // block_sweep.comp gathers toward the camera by HG(g) whole: not the split gather.
            return Err(k.invalid(
                "delta_m",
                format!(
                    "the truncated peak is built for plane sweeps only, and this render sweeps blocks of {block}^3 \
                     (dom.block, dom.budget or dom.store, or a grid too large for one binding): set dom.delta_m=off \
                     or dom.block=0"
                ),
            ));
        }
        if set.store == StoreKind::Memory && block > 0 {
            let nch = channels(scene, gpu_scene::modelled(scene, force_full).chromatic);
            let (q, storage) = (&set.quadrature, &set.storage);
            let (layout, _) = BlockSweeper::plan(set.geom.dims, nch, q, storage, set.scheme, block.min(MAX_BLOCK));
            blocks::check_host_store(layout.store_floats() * 4)?;
        }

        let mut t = std::time::Instant::now();
        let mut stage = |name: &'static str| {
            stages.push((name, t.elapsed().as_secs_f64() * 1e3));
            t = std::time::Instant::now();
        };
        let gs = GpuScene::upload(gpu, scene, force_full)?;
        // One channel when the medium, every light and the emission are grey (as lbl's lattice).
        let nch = channels(scene, gs.modelled.chromatic);
        let geom = set.geom;
        // A scene lit by its emission alone has no light to march (issue 47): no light, or none
        // whose rays reach the medium's box.
        let marcher = match scene.lights.is_empty() {
            true => None,
            false => Some(Marcher::new(gpu, scene, &gs, geom, &set.march, nch, true, false, false)?),
        }
        .filter(|m| !m.ray_beam.is_empty());
        // The emission source's kernel, built only for an emissive medium (specialised on it).
        let emit = match scene.emissive() {
            true => Some(gpu.pipeline(&ordinates::EMIT, &gs.modelled.spec())?),
            false => None,
        };
        let resampler = marching::resampler(gpu, &gs)?;
        let m = &scene.medium;
        let eye = match scene.camera.kind {
            CameraKind::Perspective { .. } => Eye::Point(scene.camera.origin.to_array()),
            CameraKind::Orthographic { .. } => Eye::Toward((-scene.camera.basis().2).to_array()),
        };
        // Plane sweeps hold the whole grid: the direct source is one slab, binned straight into
        // their buffers. Block sweeps make it slab by slab within dom.budget (and one binding),
        // the density resampled and the source read back per slab: nothing grid-sized stays on
        // the device but the sweeps' pool (5.2.2's blocks, here as runs of whole layers).
        let plan = SourcePlan::new(set, &geom, nch, marcher.as_ref().map_or(&[][..], |m| &m.beams[..]));
        let (mut density, plane_extinction, sweeper, cut) =
            source_sweeper(gpu, (&gs, &resampler), set, &plan, (m, nch, eye), block)?;
        stage("setup");
        let (quadrature_g, upsampled, storage_m) = (sweeper.quadrature_g, sweeper.upsampled(), sweeper.storage.len());
        let source = direct_source(
            gpu,
            (&gs, &resampler, &geom),
            marcher,
            emit.as_ref(),
            &sweeper,
            (cut, block, nch, m.g as f64),
            &mut density,
            progress,
        )?;
        let DirectSource { first, budgeted, source_bytes, .. } = source;
        stage("direct source");
        let (sigma_t, sigma_s) = plane_extinction.unwrap_or_else(|| extinction(m, nch, &density, set.truncation));
        drop(density);
        let setup = sweep_setup(set, &geom, nch, m.g as f64, eye, &sigma_t, &sigma_s);
        let (mut blocked, sweeper) = if block > 0 {
            // The direct source's buffers go before the pool comes: dom.budget bounds each phase.
            drop(sweeper);
            let b = block_sweeper(gpu, set, &setup, block, first)?;
            stage("block store");
            (Some(b), None)
        } else {
            (None, Some(sweeper))
        };

        // 5.3.3-5.3.4: the progressive scattering iterations (see iterate_on_device).
        let on_device = blocked.is_none() && plane(&sweeper).tests_on_device();
        // A sequence's frame goes on from the last frame's state (DomCarry) where the sweeps keep
        // it on the device: plane sweeps, with the test there or on the host (which keeps the
        // summed fluence itself: the device's sum is converge.comp's).
        let shape = (geom.dims, nch, storage_m, eye.packed());
        let mut warm = false;
        let mut host_fluence = vec![0.0f32; if on_device { 0 } else { nch as usize * geom.voxels() as usize }];
        let first_now = match (&carry, &sweeper) {
            (Some(last), Some(sw)) => {
                let first = sw.read_first(gpu, sw.whole())?;
                if let Some(c) = last.as_ref().filter(|c| c.shape == shape) {
                    let source: Vec<f32> = first.iter().zip(&c.offset).map(|(now, o)| now + o).collect();
                    sw.set_state(gpu, &source, &c.accum, &c.camera)?;
                    if !on_device {
                        host_fluence.copy_from_slice(&c.accum);
                    }
                    warm = true;
                }
                Some(first)
            }
            _ => None,
        };
        let (iterations, converged, change, tail, mut cameras) = if on_device {
            iterate_on_device(gpu, plane(&sweeper), set, progress)?
        } else {
            iterate_on_host(gpu, &mut blocked, &sweeper, set, &mut host_fluence, progress)?
        };
        // The state as the iterations left it, before any tail is added: the next frame's start.
        let carried = match first_now {
            Some(first) => {
                let (mut offset, accum, camera) = plane(&sweeper).read_state(gpu)?;
                offset.iter_mut().zip(&first).for_each(|(o, q)| *o -= q);
                let accum = if on_device { accum } else { host_fluence };
                Some(DomCarry { shape, offset, accum, camera })
            }
            None => None,
        };
        let tail_stats = tail.as_ref().map(|t| (t.ratio, t.share));
        let camera_with_tail = tail.map(|t| with_tail(&t, &mut cameras, warm));
        if let (Some(camera), None) = (&camera_with_tail, &blocked) {
            gpu.write_buffer(&plane(&sweeper).camera, 0, bytemuck::cast_slice(camera))?;
        }
        stage("iterations");
        // The light each voxel scatters toward the camera, as the energy per voxel that the view
        // pass scatters isotropically (fluence = energy / lambda^2, as lbl's lattice). With
        // blocks the pool goes before the view, which takes the volume in slabs of whole layers
        // where it does not fit dom.budget (or one binding): one view run per slab, the images
        // added (view::MsWindow).
        let (res, sweeps, streaming, sweep_device_bytes, view_slabs) =
            view_step(gpu, scene, &gs, set, &plan, nch, blocked, &sweeper, camera_with_tail)?;
        stage("view");
        // The largest of the phases: making the direct source, sweeping, viewing (plane sweeps
        // keep their sweeper through the view; blocks hand the view their camera volume).
        let device = gs.bytes
            + if block > 0 {
                source_bytes.max(sweeps).max(res.device_bytes)
            } else {
                source_bytes.max(sweeps + res.device_bytes)
            };
        let mut report = RenderReport::finish(gpu, self, k, gs.modelled.clone(), device, Stats::new(()));
        let ds = DomStats {
            field: true,
            warm_start: warm,
            iterations,
            converged,
            final_change: change,
            tail_ratio: tail_stats.map(|t| t.0),
            tail_share: tail_stats.map(|t| t.1),
            sweep_ms: 0.0,
            block,
            streaming,
            sweep_device_bytes,
            view_slabs,
            source_slabs: source.slabs,
            source_layers: source.layers,
            source_groups: source.groups,
            source_device_bytes: budgeted,
            stages_ms: stages,
            ..DomStats::of_settings(scene, set, nch, quadrature_g)
        };
        report.stats = dom_stats(ds, set, &mut report, res.nonfinite_pixels, (upsampled, storage_m));
        Ok((RenderOutput { image: res.image, variance: None, report, estimates: Vec::new() }, carried))
    }

    /// dom where nothing scatters (sigma_s 0 in every channel and material): no light marched,
    /// no emission binned, nothing swept. The view scatters the swept field toward the camera by
    /// sigma_s and the direct light by sigma_s too, so with the field the image is the view's
    /// camera-ray march alone (the unscattered emission, the background through the medium);
    /// without it the same march gives the same image (the added terms were exact zeros). An
    /// absorbing emitter of optical diameter 40 at the default grid (80) swept zeros for 9.5 s.
    fn render_unscattered(
        &self,
        gpu: &Gpu,
        scene: &Scene,
        force_full: bool,
        k: &Knobs,
        set: &DomSettings,
    ) -> Result<RenderOutput, SolverError> {
        let t = std::time::Instant::now();
        let gs = GpuScene::upload(gpu, scene, force_full)?;
        let setup_ms = t.elapsed().as_secs_f64() * 1e3;
        let res = view::march(gpu, scene, &gs, &set.view, None)?;
        let view_ms = t.elapsed().as_secs_f64() * 1e3 - setup_ms;
        let device = gs.bytes + res.device_bytes;
        let mut report = RenderReport::finish(gpu, self, k, gs.modelled.clone(), device, Stats::new(()));
        let (quadrature_g, upsampled) =
            ordinates::unswept_figures(&set.quadrature, &set.storage, set.truncation.g_rest);
        let nch = channels(scene, gs.modelled.chromatic);
        let ds = DomStats {
            stages_ms: vec![("setup", setup_ms), ("view", view_ms)],
            ..DomStats::of_settings(scene, set, nch, quadrature_g)
        };
        report.stats = dom_stats(ds, set, &mut report, res.nonfinite_pixels, (upsampled, set.storage.len()));
        Ok(RenderOutput { image: res.image, variance: None, report, estimates: Vec::new() })
    }
}

impl Solver for Dom {
    fn name(&self) -> &'static str {
        "dom"
    }

    fn about(&self) -> &'static str {
        "modified discrete ordinates: marched first-scattering source binned into storage directions, octant sweeps \
         with step characteristics, progressive scattering iterations on the device (thesis ch. 5; blocks stream from host memory or a file past dom.budget)"
    }

    fn knobs(&self) -> Vec<Knob> {
        let mut k = vec![
            Knob::derived(
                "grid",
                "fitted to the medium: 32, raised until the thinnest side spans 4 voxels and a voxel is at most 1 mean \
                 free path thick, within 64^3 voxels",
                Range::int(2, 512),
                "voxels along the medium's longest side (cubic voxels)",
            ),
            Knob::fixed(
                "directions",
                "auto",
                Range::Choice(&["auto", "s2", "s4", "s6", "s8", "product-8x16", "product-16x32"]),
                "the quadrature swept: level-symmetric s4 (24 directions, the thesis's), s6 (48), s8 (80), or a \
                 Gauss-Legendre x Chebyshev product set (product-PxA: P polar x A azimuthal); auto: s6, \
                 product-8x16 (128) where |g| >= 0.8, product-16x32 (512) where |g| >= 0.95",
            ),
            Knob::fixed(
                "delta_m",
                "auto",
                Range::Choice(&["auto", "on", "off"]),
                "truncate the forward peak from the scattering between sweeps (delta-M: a share g^2 goes on \
                 unscattered, the rest is HG(g / (1 + g))), and share the direct source and gather the field toward \
                 the camera split at the directions' spacing (the peak interpolated, the rest by HG(g)): the bounce \
                 series decays far faster and an unresolved peak no longer overweights the far field (at g 0.99 on \
                 the cube: 0.93-1.10x path's energy instead of 1.5-2.5x, 1.5-8x faster). auto: on where g >= 0.95 with \
                 plane sweeps; nothing is truncated where g <= 0; block sweeps refuse on (docs/dom.md)",
            ),
            Knob::fixed(
                "tol",
                "1e-4",
                Range::Real { min: 0.0, max: 1.0, min_open: true, max_open: true },
                "the iterations stop when a bounce adds less than this to the fluence, relative to its largest value",
            ),
            Knob::fixed(
                "max_iterations",
                "2000",
                Range::int(1, 1_000_000),
                "scattering iterations (bounces swept) at most",
            ),
            Knob::derived(
                "iterations_per_frame",
                "to the tolerance (dom.tol)",
                Range::int(1, 1_000_000),
                "scatterlab animate and view: scattering iterations of each frame after the first, going on from the \
                 previous frame's state (plane sweeps)",
            ),
            Knob::fixed(
                "extrapolate",
                "true",
                Range::Bool,
                "add the iteration's geometric tail (the last two bounces times rho^2 / (1 - rho^2), rho^2 the decay \
                 of such pairs: the light of the bounces not swept) and test convergence on the extrapolated fluence \
                 (docs/dom.md); false: stop when a bounce adds less than dom.tol",
            ),
            Knob::fixed(
                "scheme",
                "characteristics",
                Range::Choice(&["characteristics", "step"]),
                "the voxel update: step characteristics (thesis 5.3.1-5.3.2: face radiances carried across the voxel \
                 with exact attenuation) or the step difference (cheaper, diffusive in optically thick voxels); both \
                 conserve energy and are never negative",
            ),
            Knob::fixed(
                "storage",
                "auto",
                Range::Choice(&["auto", "directions", "1", "s2", "s4", "s6", "s8", "product-4x8", "product-8x16"]),
                "the M directions each voxel's source is stored at (thesis 5.1): auto is 1 for an isotropic medium \
                 (exact) and the swept set otherwise; directions is the swept set; a smaller set is upsampled to the \
                 swept one, conserving energy",
            ),
            Knob::fixed(
                "block",
                "auto",
                Range::IntOr { min: 0, max: MAX_BLOCK as u64, word: "auto" },
                "block edge in voxels: sweeps run a work group per block and stream blocks through the device pool \
                 (thesis 5.3.3-5.3.4); 0 sweeps whole-grid planes with one field per direction on the device (4x \
                 faster on lavapipe); auto: 0 while the field fits one device binding and no budget or store is \
                 set, else 16",
            ),
            Knob::fixed(
                "budget",
                "0",
                Range::non_negative(),
                "MiB of device memory for the grid in each phase: the direct source made slab by slab, the block \
                 sweeps' pool and tables (blocks beyond it stream from the host store), the view reading the light \
                 toward the camera slab by slab (the rays of dom.rays come on top); 0: the whole grid when one \
                 binding holds it",
            ),
            Knob::fixed(
                "store",
                "memory",
                Range::ChoiceOrPrefix(&["memory"], "file:"),
                "where the blocks live on the host: memory, or file:DIR for an unnamed memory-mapped file in DIR \
                 (volumes larger than host memory)",
            ),
            Knob::fixed(
                "copies",
                "compute",
                Range::Choice(&["compute", "transfer"]),
                "the queue the streaming copies run on: compute (the trace role's compute queue) or transfer (the \
                 transfer role: a transfer-only family, the copy engines, where the device has one). On the H100 \
                 compute-queue copies moved the blocks 1.9x faster and cost the sweeps 4-10%: iterations 20-23% \
                 shorter (docs/devices)",
            ),
            Knob::fixed(
                "evict",
                "auto",
                Range::Choice(&["auto", "overlap", "belady"]),
                "which pool slot a streamed block replaces: belady (the block needed again farthest ahead: the fewest \
                 loads, but 77-89% of them wait for the sweep before them) or overlap (double buffering: chunks of \
                 half the pool where it holds 16 blocks' working sets, loads avoiding the slots of the sweeps just \
                 submitted: 0-2% wait); auto: overlap where the copies' queue is not the sweeps' (dom.copies on the \
                 device's mapping), else belady (one queue: nothing to overlap; docs/dom.md)",
            ),
        ];
        k.extend(marching::knobs());
        k.extend(view::knobs().into_iter().map(|k| k.prefixed("view_")));
        k
    }

    /// The medium's emission sigma_a Le whole: an isotropic source added at every storage
    /// direction to the first sweep's (glsl/ordinates/emit.comp, per unit volume and sr like the
    /// binned first-scattering source), so the swept field carries the emitted light uncollided
    /// and, over the scattering iterations, every bounce of it; the view gathers what the medium
    /// scatters of it toward the camera, and adds the unscattered emission along the camera ray
    /// itself. A scene lit by its emission alone (no light) marches nothing.
    fn renders_emission(&self) -> bool {
        true
    }

    fn kernels(&self) -> Vec<Kernel> {
        let mut k = marching::kernels();
        k.extend(ordinates::kernels());
        k.push(blocks::BLOCK_SWEEP);
        k.extend([view::MARCH, view::SHADOW, crate::solvers::parts::feedback::COPY]);
        k
    }

    fn render(&self, gpu: &Gpu, req: &RenderRequest) -> Result<RenderOutput, SolverError> {
        let scene = req.scene;
        let k = req.knobs(self)?;
        let set = DomSettings::parse(&k, scene)?;
        k.finish()?;
        if !scene.scatters() {
            return self.render_unscattered(gpu, scene, req.force_full, &k, &set);
        }
        Ok(self.render_with(gpu, scene, req.force_full, &k, &set, req.progress, None)?.0)
    }

    fn animation(&self, req: &RenderRequest, converge: bool) -> Result<Option<Box<dyn Animation>>, SolverError> {
        let knobs = req.knobs(self)?;
        let set = DomSettings::parse(&knobs, req.scene)?;
        knobs.finish()?;
        Ok(Some(Box::new(DomAnimation { knobs, set, converge, force_full: req.force_full, carry: None, said: false })))
    }

    fn memory_estimate(&self, scene: &Scene, knobs: &Knobs) -> Result<u64, SolverError> {
        let set = DomSettings::parse(knobs, scene)?;
        if !scene.scatters() {
            // No field where nothing scatters (render_unscattered): the scene and the view.
            return Ok(gpu_scene::scene_bytes(scene) + view::device_bytes(scene, &set.view));
        }
        let geom = set.geom;
        let m = &set.march;
        let (rays, beam_list) = marching::ray_count(scene, &geom, m.rays, m.env_lights, m.step, scene.render.seed);
        let beams = beam_list.len() as u64;
        let v = geom.voxels();
        let nch = channels(scene, gpu_scene::modelled(scene, false).chromatic) as u64;
        // Block sweeps: the pool (the whole grid, or what dom.budget allows) and tables; then the
        // light toward the camera handed to the view pass (whole, or its largest slab).
        // (auto counts as plane sweeps: the binding limit is the device's)
        let block = set.block.unwrap_or(0);
        let plan = SourcePlan::new(&set, &geom, nch as u32, &beam_list);
        let (sweeps, source_voxels, group) = if block > 0 {
            let (layout, fixed) = BlockSweeper::plan(
                geom.dims,
                nch as u32,
                &set.quadrature,
                &set.storage,
                set.scheme,
                block.min(MAX_BLOCK),
            );
            let all = fixed
                + (layout.store_floats() + layout.blocks().min(layout.widest_plane()) as u64 * layout.scratch()) * 4;
            let cut = plan.cut(&set, u64::MAX, block)?;
            // Each view run: its slab of the light toward the camera and the view's buffers, the
            // shadow volume in the run that adds the direct light only.
            let (view, shadow) = (view::device_bytes(scene, &set.view), view::shadow_bytes(scene, &set.view));
            let viewing = view_windows(&plan, set.budget, u64::MAX)
                .iter()
                .map(|w| match w {
                    None => v * nch * 4 + view,
                    Some(w) => w.held[1] as u64 * plan.view_layer() + view - if w.direct { 0 } else { shadow },
                })
                .max()
                .unwrap_or(0);
            (
                Some((set.budget.map_or(all, |b| b.min(all)), viewing)),
                geom.dims[0] as u64 * geom.dims[1] as u64 * cut.layers as u64,
                cut.group as u64,
            )
        } else {
            (None, v, plan.max_group() as u64)
        };
        // Making the direct source: the marcher, the sweeper's buffers (all of them with plane
        // sweeps, the binning's and one slab's sources with blocks), the slab's deposit sums per
        // beam of a group and density, each ray's beam and the beam table. Then the sweeps and the view.
        // A scene lit by its emission alone marches nothing; an emissive one with plane sweeps
        // holds the whole grid's density for the emission pass (blocks hold the slab's anyway).
        let marching = match scene.lights.is_empty() {
            true => 0,
            false => m.device_bytes(&geom, rays, nch as u32, false, false) + nch * group * source_voxels * 4 + rays * 4,
        };
        let source = marching
            + Sweeper::bytes(v, nch, &set.quadrature, &set.storage, set.scheme, block == 0, source_voxels)
            + source_voxels * 4
            + beams * 32;
        Ok(gpu_scene::scene_bytes(scene)
            + match sweeps {
                // The pool, then the view runs.
                Some((pool, viewing)) => source.max(pool).max(viewing),
                None => source.max(
                    Sweeper::bytes(v, nch, &set.quadrature, &set.storage, set.scheme, true, v)
                        + view::device_bytes(scene, &set.view),
                ),
            })
    }

    /// The thesis's headline (5.4): 128^3, N 24 in 5.3 s per frame; two iterations, as its
    /// frames were rendered.
    fn headline(&self, quick: bool) -> Option<Headline> {
        let (grid, size) = if quick { ("16", "64") } else { ("128", "512") };
        Some(sphere_workload(
            format!("dom homogeneous sphere {grid}^3, N 24, two iterations, {size}^2"),
            grid,
            size,
            &[],
            if quick { "" } else { "thesis 5.4: 128^3, N 24 in 5.3 s per frame (GTX 580, 2011)" },
        ))
    }

    /// The sweeps on the trace role beside the blocks' streaming copies (5.2.2, 5.3.4), the
    /// pool holding under a tenth of the blocks (64^3: 39 slots for 512 blocks): the copies on
    /// the compute queue, in order with the sweeps, against the copies on the transfer role's
    /// queue (`dom.copies`).
    fn concurrency(&self, quick: bool) -> Option<Headline> {
        let (grid, size, block, budget) = if quick { ("16", "32", "4", "0.05") } else { ("64", "256", "8", "1") };
        Some(sphere_workload(
            format!("dom homogeneous sphere {grid}^3 streamed under {budget} MiB, N 24, two iterations, {size}^2"),
            grid,
            size,
            &[("dom.block", block), ("dom.budget", budget), ("dom.rays", "16384")],
            "",
        ))
    }

    fn schedules(&self) -> Option<(&'static str, &'static str, &'static str)> {
        Some(("copies", "compute", "transfer"))
    }

    fn preflight(&self, scene: &Scene, knobs: &Knobs) -> Result<Vec<String>, SolverError> {
        let set = DomSettings::parse(knobs, scene)?;
        // Where nothing scatters the sweeps carry nothing: the grid's and directions' trust does
        // not apply.
        let grid = set.geom.trust(scene, set.grid, &DOM_GRID).warning().filter(|_| scene.scatters());
        Ok(grid
            .into_iter()
            .chain(
                DirectionsTrust::new(scene.medium.g, &set.quadrature, &set.storage, set.truncation.f > 0.0)
                    .warning()
                    .filter(|_| scene.scatters()),
            )
            .chain(view::ViewTrust::of(scene, &set.view).warning(self.name()))
            .collect())
    }

    /// Over the grid and the number of directions N (issue 13's ladder), cheapest first: level-
    /// symmetric sets where s6 resolves the phase function, product sets where |g| >= 0.8
    /// (as `dom.directions=auto` picks).
    fn ladder(&self, scene: &Scene) -> Vec<Rung> {
        let rungs: &[(u32, &str)] = if scene.medium.g.abs() >= 0.8 {
            &[
                (16, "product-8x16"),
                (24, "product-8x16"),
                (32, "product-8x16"),
                (32, "product-16x32"),
                (48, "product-16x32"),
            ]
        } else {
            &[(16, "s4"), (24, "s4"), (32, "s4"), (32, "s6"), (48, "s6"), (48, "s8")]
        };
        rungs
            .iter()
            .map(|(g, n)| Rung {
                knob: "dom.grid".into(),
                value: format!("{g}/{}", n.trim_start_matches("product-")),
                sets: vec![("dom.grid".into(), g.to_string()), ("dom.directions".into(), n.to_string())],
            })
            .collect()
    }

    fn stability(&self) -> Vec<Variant> {
        vec![Variant::new(
            "",
            &[("dom.grid", "12"), ("dom.rays", "4096"), ("dom.view_env_dirs", "16"), ("dom.max_iterations", "4000")],
        )]
    }

    fn summary(&self, report: &RenderReport) -> Vec<String> {
        let Some(s) = report.detail::<DomStats>() else { return Vec::new() };
        let d = s.grid.dims;
        if !s.field {
            return vec![
                "dom: nothing scatters (sigma_s 0 in every channel and material): no field made, the image is the \
                 view's camera-ray march"
                    .into(),
                format!("dom: {}", s.view_trust.line()),
            ];
        }
        let mut lines = vec![format!(
            "dom: {}x{}x{} voxels, {:?}, {} ({} directions), source stored at {} ({} direction{}, g {:.3} on the \
             quadrature), {} channel{}, {} scattering iterations{} (change {:.1e}{}), sweeps {:.1} ms",
            d[0],
            d[1],
            d[2],
            s.scheme,
            s.quadrature,
            s.directions,
            s.storage,
            s.storage_directions,
            if s.storage_directions == 1 { "" } else { "s" },
            s.quadrature_g,
            s.channels,
            if s.channels == 1 { "" } else { "s" },
            s.iterations,
            if s.converged { "" } else { ", NOT converged" },
            s.final_change,
            match (s.tail_ratio, s.tail_share) {
                (Some(r), Some(share)) => format!("; tail of {:.2}% of the fluence added, decay {r:.4}", share * 100.0),
                _ => String::new(),
            },
            s.sweep_ms
        )];
        if s.truncation.f > 0.0 {
            lines.push(format!(
                "dom: forward peak truncated (dom.delta_m): {:.4} of the scattering between sweeps goes on unscattered, \
                 the rest scatters by HG({:.4}) (g {:.3} on the quadrature)",
                s.truncation.f, s.truncation.g_rest, s.quadrature_g
            ));
        }
        lines.push(format!("dom: {}", s.trust.line()));
        lines.push(format!("dom: {}", s.directions_trust.line()));
        lines.push(format!("dom: {}", s.view_trust.line()));
        if let Some(st) = &s.streaming {
            lines.push(format!(
                "dom: blocks of {}^3: {} blocks, pool {} slots of {} KiB ({}), {} uploads ({} waiting for the sweep \
                 before them), {} write-backs, sweep device bytes {:.1} MiB",
                s.block,
                st.blocks,
                st.pool_slots,
                st.record_bytes >> 10,
                if st.pool_slots >= st.blocks { "in-core" } else { "streamed" },
                st.uploads,
                st.serialised_loads,
                st.write_backs,
                s.sweep_device_bytes as f64 / 1048576.0
            ));
            lines.push(format!(
                "dom: direct source in {} slab{} of {} layer{} x {} group{} of beams, {:.1} MiB of grid buffers",
                s.source_slabs,
                if s.source_slabs == 1 { "" } else { "s" },
                s.source_layers,
                if s.source_layers == 1 { "" } else { "s" },
                s.source_groups,
                if s.source_groups == 1 { "" } else { "s" },
                s.source_device_bytes as f64 / 1048576.0
            ));
        }
        if !s.stages_ms.is_empty() {
            let parts: Vec<String> = s.stages_ms.iter().map(|(n, ms)| format!("{n} {:.0} ms", ms)).collect();
            let staging = match &s.streaming {
                Some(st) if st.staging_ms >= 1.0 => format!(" (staging copies on the host {:.0} ms)", st.staging_ms),
                _ => String::new(),
            };
            lines.push(format!("dom: wall {}{staging}", parts.join(", ")));
        }
        lines
    }
}

#[cfg(test)]
mod truncation_tests {
    use crate::scene::Scene;
    use crate::solvers::dom::{extinction, Truncation};

    /// The delta-M split keeps the first moment and the similarity relation, truncates nothing
    /// where g <= 0, and the truncated coefficients keep sigma_a and create nothing.
    #[test]
    fn delta_m_keeps_the_first_moment_similarity_and_absorption() {
        for g in [0.1, 0.5, 0.9, 0.99, 0.999] {
            let t = Truncation::delta_m(g);
            assert!((t.f + (1.0 - t.f) * t.g_rest - g).abs() < 1e-12, "g {g}: first moment");
            assert!(((1.0 - t.f) * (1.0 - t.g_rest) - (1.0 - g)).abs() < 1e-12, "g {g}: similarity");
            assert!(t.f > 0.0 && t.f < 1.0 && t.g_rest > 0.0 && t.g_rest < 0.5, "g {g}: {t:?}");
        }
        for g in [-0.9, 0.0] {
            assert_eq!(Truncation::delta_m(g), Truncation::none(g));
        }
        let text = include_str!("../../../scenes/anisotropic-cube.toml");
        let opts = crate::scene::LoadOptions::default();
        let mut m = Scene::from_str(text, "cube", std::path::Path::new("."), &[], &opts).expect("the cube").medium;
        m.albedo = glam::Vec3::splat(0.99);
        let density = [0.0f32, 0.5, 1.0, 3.0];
        let (t0, s0) = extinction(&m, 1, &density, Truncation::none(0.99));
        let (t1, s1) = extinction(&m, 1, &density, Truncation::delta_m(0.99));
        for i in 0..density.len() {
            let (a0, a1) = (t0[i] - s0[i], t1[i] - s1[i]);
            assert!((a0 - a1).abs() <= 1e-6 * t0[i].max(1.0), "sigma_a {a0} became {a1}");
            assert!(s1[i] >= 0.0 && s1[i] <= t1[i] && t1[i] <= t0[i]);
        }
        // The bounce series decays by albedo (1 - f) / (1 - f albedo): 0.66 at g 0.99.
        let a1 = s1[2] / t1[2];
        assert!((a1 - 0.99 * (1.0 - 0.9801) / (1.0 - 0.9801 * 0.99)).abs() < 1e-5, "albedo {a1}");
    }
}
