//! Shared part: the view pass (glsl/view/march.comp). Camera rays march through the medium and
//! collect exact single scattering (shadow transmittance to each light, the exact phase
//! function; thesis 1.3.6 and 2.5) plus, when a solver supplies one, the multiply scattered
//! in-scattering from its volume ([`MsVolume`]: `lbl`'s lattice, `wavefront`'s gathered
//! field). `single` is this pass alone.
//!
//! Knobs ([`knobs`]): `single` reads them as they are (`single.step`), solvers with knobs of
//! their own under the prefix `view_` (`lbl.view_step`).

use bytemuck::{Pod, Zeroable};

pub mod trust;
pub use trust::ViewTrust;

use crate::gpu::{Buffer, Gpu, Kernel, Pass, QueueRole, Spec, SpecKind};
use crate::output::Image;
use crate::scene::Scene;

use serde::Serialize;

use super::gpu_scene::GpuScene;
use super::resumable;
use crate::solvers::interface::Progress;
use crate::solvers::interface::{
    Knob, Knobs, Range, RenderOutput, RenderReport, RenderRequest, Solver, SolverError, Stats,
};

/// Push constants of glsl/view/march.comp.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct ViewPush {
    pub step: f32,
    pub shadow_step: f32,
    pub env_dirs: u32,
    pub jitter: u32,
    pub seed_lo: u32,
    pub seed_hi: u32,
    pub supersample: u32,
    pub budget: u32,
    pub slot: u32,
    /// 1: the multiple-scattering volume carries the vector irradiance after the fluence.
    pub ms_flux: u32,
    /// 1: the volume's light alone (a later slab of an out-of-core volume, [`MsWindow`]).
    pub ms_only: u32,
    /// Where lbl's forward field starts (fields of C V floats; 0: none).
    pub ms_forward: u32,
    /// Volume voxels xyz and channels (x = 0: no multiple-scattering volume).
    pub ms_dims: [u32; 4],
    /// Volume min corner and voxel edge lambda.
    pub ms_origin: [f32; 4],
    /// Octaves: attenuation a, contribution b, eccentricity c, unused.
    pub octave: [f32; 4],
    /// Shadow volume voxels xyz (x = 0: none; every shadow ray is marched), w = depths per
    /// unit and voxel (1 or 2).
    pub shadow_dims: [u32; 4],
    /// The volume's layers held (first, count) and counted (first, end): [`MsWindow`].
    pub ms_window: [u32; 4],
}

/// Push constants of glsl/view/shadow.comp.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct ShadowPush {
    shadow_step: f32,
    env_dirs: u32,
    units: u32,
    /// 2: also the depth away from each unit (the bounded octaves' chord); 1: toward it only.
    sides: u32,
}

pub const SHADOW: Kernel = Kernel {
    shader: shader!("view/shadow"),
    push_bytes: std::mem::size_of::<ShadowPush>(),
    spec: super::gpu_scene::VIEW_SPEC,
};

/// How the view pass finds the optical depth toward each light unit (`view_shadow`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shadow {
    /// A shadow march per camera-ray step and light unit (exact to the midpoint rule).
    March,
    /// The shadow volume: the depth toward each unit precomputed at the density grid's voxel
    /// centres (glsl/view/shadow.comp) and read trilinearly. Grid densities only (constant and
    /// sphere media integrate their chords analytically already).
    Volume,
}

impl Shadow {
    /// The mode `auto` / `volume` / `march` resolves to for `scene`: the volume for grid
    /// densities, where it replaces ~(light units x camera steps) shadow marches per pixel by
    /// two per unit and voxel.
    fn resolve(mode: &str, scene: &Scene) -> Shadow {
        let grid = matches!(scene.medium.density, crate::scene::Density::Grid(_));
        // Through a mesh the shadow depth needs the surfaces: always marched.
        if mode != "march" && grid && scene.object.is_none() {
            Shadow::Volume
        } else {
            Shadow::March
        }
    }
}

/// Largest shadow volume `auto` builds: 2^27 bytes, what every Vulkan device can bind.
const MAX_SHADOW_VOLUME_BYTES: u64 = 1 << 27;

/// Light units of the view pass: one per point or directional light, `env_dirs` per
/// environment (glsl/include/view.glsl, `unit_light`).
pub fn light_units(scene: &Scene, env_dirs: u32) -> u32 {
    scene.lights.iter().map(|l| if matches!(l, crate::scene::Light::Environment { .. }) { env_dirs } else { 1 }).sum()
}

/// Depths stored per unit and voxel: toward the unit, and away from it where the bounded
/// octaves need the whole chord.
fn shadow_sides(v: &ViewSettings) -> u32 {
    if v.octaves.n > 1 && v.octaves.bounded {
        2
    } else {
        1
    }
}

/// The density grid the shadow volume is built on, when `v` builds one.
fn shadow_grid<'a>(scene: &'a Scene, v: &ViewSettings) -> Option<&'a crate::scene::Grid> {
    match (&scene.medium.density, v.shadow) {
        (crate::scene::Density::Grid(g), Shadow::Volume) => Some(g),
        _ => None,
    }
}

/// Device bytes of the shadow volume for `v` on `scene` (0 when it marches; a run of a later
/// [`MsWindow`] builds none).
pub fn shadow_bytes(scene: &Scene, v: &ViewSettings) -> u64 {
    shadow_grid(scene, v).map_or(0, |g| {
        shadow_sides(v) as u64
            * light_units(scene, v.env_dirs) as u64
            * g.dims.iter().map(|d| *d as u64).product::<u64>()
            * 4
    })
}

/// Specialisation constant: octaves of the multiple-scattering approximation (1: none).
const SPEC_OCTAVES: u32 = 8;
const SPEC_STEP_FIT: u32 = 9;

/// Optical thickness of a camera-ray step above which single scattering integrates the shadow
/// transmittance between the step's ends (glsl/view/march.comp, `step_transmittance`) instead
/// of sampling it at the middle: the midpoint was 3% low at 0.27 per step and 0.38x the
/// converged value at 4.4 (thick-slab.toml), and costs a second shadow depth per light unit.
pub const STEP_FIT_TAU: f32 = 0.2;

/// Whether a step of `step` scene units can be thicker than [`STEP_FIT_TAU`] in this medium.
pub fn step_fit(scene: &Scene, step: f32) -> bool {
    scene.max_sigma_t() * scene.max_density() * step > STEP_FIT_TAU
}
/// Most octaves the kernel sums.
pub const MAX_OCTAVES: u32 = 8;

pub const MARCH: Kernel = Kernel {
    shader: shader!("view/march"),
    push_bytes: std::mem::size_of::<ViewPush>(),
    spec: &[
        (super::gpu_scene::SPEC_DENSITY_KIND, SpecKind::U32),
        (super::gpu_scene::SPEC_CHROMATIC, SpecKind::Bool),
        (super::gpu_scene::SPEC_ANISOTROPIC, SpecKind::Bool),
        (super::gpu_scene::SPEC_FIELDS, SpecKind::Bool),
        (super::gpu_scene::SPEC_EMISSION, SpecKind::U32),
        (SPEC_OCTAVES, SpecKind::U32),
        (SPEC_STEP_FIT, SpecKind::Bool),
        (super::gpu_scene::SPEC_HAS_MESH, SpecKind::Bool),
        (super::gpu_scene::SPEC_REFRACTIVE, SpecKind::Bool),
        (super::gpu_scene::SPEC_ENVIRONMENT, SpecKind::Bool),
    ],
};

/// Bindings of the [[object]]'s BVH nodes and triangles in glsl/view/march.comp (after the
/// view pass's own 0-7).
const VIEW_MESH_NODES_BINDING: u32 = 8;
const VIEW_MESH_TRIS_BINDING: u32 = 9;

/// The octave approximation of multiple scattering in the view pass (Wrenninge et al. 2013):
/// light i's phase-weighted transmittance p(cos; g) T becomes
/// sum_{k < n} b^k p(cos; g c^k) T^(a^k) (times (albedo (1 - T_chord))^k when `bounded`).
/// `SINGLE` (n = 1) is single scattering.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Octaves {
    pub n: u32,
    /// Attenuation: octave k sees the light through a^k of the optical depth.
    pub a: f32,
    /// Contribution: octave k is weighted b^k.
    pub b: f32,
    /// Eccentricity: octave k scatters with g c^k.
    pub c: f32,
    /// Octave k also weighted by (albedo (1 - exp(-tau_chord)))^k, so that no energy is created
    /// (glsl/view/march.comp, `octave_sum`); false: the published sum.
    pub bounded: bool,
}

impl Octaves {
    pub const SINGLE: Octaves = Octaves { n: 1, a: 1.0, b: 1.0, c: 1.0, bounded: false };
}

/// Per-pixel resumable march state (`MarchState` in glsl/view/march.comp): 4 vec4 of the
/// march, 3 of a camera ray's segment through a mesh.
pub const STATE_BYTES_PER_PIXEL: u64 = 112;
/// Longest shadow march (steps across the medium's diagonal) a single loop may take.
pub const MAX_SHADOW_STEPS: f32 = 16384.0;

/// Device bytes of the view pass at this image size, with its shadow volume.
pub fn device_bytes(scene: &Scene, v: &ViewSettings) -> u64 {
    let pixels = scene.render.width as u64 * scene.render.height as u64;
    pixels * (16 + STATE_BYTES_PER_PIXEL) + resumable::STATS_WORDS * 4 + shadow_bytes(scene, v)
}

/// The view march's knobs (unprefixed; solvers add `view_`).
pub fn knobs() -> Vec<Knob> {
    vec![
        Knob::derived(
            "step",
            "1/128 of the medium's diagonal, at most 1/16 of its thinnest side",
            Range::positive(),
            "camera-ray step in scene units (at most 1e7 steps across the medium)",
        ),
        Knob::derived(
            "shadow_step",
            "the camera-ray step",
            Range::positive(),
            "shadow-ray step in scene units (at most 16384 steps across the medium: one loop)",
        ),
        Knob::fixed(
            "env_dirs",
            "16",
            Range::int(1, 4096),
            "quadrature directions for environment in-scattering (each costs a shadow march per camera step)",
        ),
        Knob::fixed(
            "shadow",
            "auto",
            Range::Choice(&["auto", "volume", "march"]),
            "optical depth toward each light unit: precomputed at the density grid's voxel centres and read \
             trilinearly (volume), or marched per camera step (march); auto: volume for grid densities",
        ),
        Knob::fixed("supersample", "1", Range::int(1, 16), "n x n subpixel rays per pixel, box filter"),
        Knob::fixed("jitter", "0", Range::int(0, 1), "1 jitters step origins per pixel (noise instead of banding)"),
        resumable::budget_knob(),
    ]
}

/// The camera-ray march's knobs, parsed.
#[derive(Clone, Copy, Debug)]
pub struct ViewSettings {
    pub step: f32,
    pub shadow_step: f32,
    pub env_dirs: u32,
    pub supersample: u32,
    pub jitter: u32,
    pub budget: u32,
    /// Single scattering unless a solver sets octaves (`octaves`).
    pub octaves: Octaves,
    pub shadow: Shadow,
    /// With a refractive [[object]]: Fresnel and Snell at its surface (`single.refraction`);
    /// false renders it as if index-matched, for measuring what refraction buys.
    pub refraction: bool,
    /// Where the solver's knobs keep these: "" for single's own, "view_" for a solver that
    /// prefixes the view march's. Kept from [`ViewSettings::parse`], so that what names a knob
    /// (the trust warning, the shadow volume's refusal) names the one that was read.
    pub prefix: &'static str,
}

impl ViewSettings {
    /// The default camera-ray step: 1/128 of the medium's diagonal, and at most 1/16 of its
    /// thinnest side (fitted on every axis, as the grids: issue 44), but never under 1/8192 of
    /// the diagonal (half what one shadow loop may take). On a wide slab the diagonal alone gave
    /// steps of many mean free paths through a thin medium: the 8 x 0.5 x 8 slab 8 mean free
    /// paths thick (sigma_t 16, albedo 0.99, lit and seen normally) came out 1.17x path's energy
    /// with lbl at 1/128 of the diagonal (0.088, 1.4 mean free paths), 1.04x at half that and
    /// 1.03x at 0.02; dom on the 16 x 0.5 x 16 slab lit at 60 degrees 0.90 -> 0.95 at 1/16 of the
    /// thickness. Boxes within about 4.6:1 keep 1/128 of the diagonal.
    pub fn default_step(scene: &Scene) -> f32 {
        let ext = scene.medium.bounds_max - scene.medium.bounds_min;
        let diag = ext.length();
        (diag / 128.0).min(ext.min_element() / 16.0).max(diag / 8192.0)
    }

    /// Read `<prefix>step` etc., with defaults scaled to the medium.
    pub fn parse(k: &Knobs, prefix: &'static str, scene: &Scene) -> Result<ViewSettings, SolverError> {
        let diag = (scene.medium.bounds_max - scene.medium.bounds_min).length();
        let key = |n: &str| format!("{prefix}{n}");
        let step: f32 = k.get_or(&key("step"), Self::default_step(scene))?;
        let shadow_mode: String = k.get(&key("shadow"))?;
        let v = ViewSettings {
            step,
            shadow_step: k.get_or(&key("shadow_step"), step)?,
            env_dirs: k.get(&key("env_dirs"))?,
            supersample: k.get(&key("supersample"))?,
            jitter: k.get(&key("jitter"))?,
            budget: k.get(&key("budget"))?,
            octaves: Octaves::SINGLE,
            shadow: Shadow::resolve(&shadow_mode, scene),
            refraction: true,
            prefix,
        };
        if scene.object.is_some() && shadow_mode == "volume" {
            // The shadow volume holds the density integral alone; through a mesh the depth
            // also needs the surfaces crossed (Fresnel) and the inside intervals.
            return Err(k.invalid(
                &key("shadow"),
                "the shadow volume does not trace the [[object]]'s mesh; use march or auto (which marches with a mesh)",
            ));
        }
        resumable::check_mesh_budget(k, &key("budget"), v.budget, scene.object.is_some())?;
        let v = v.fit_shadow(k, scene)?;
        for (name, x) in [("step", v.step), ("shadow_step", v.shadow_step)] {
            // A shadow march runs in one loop (it cannot be split across dispatches), so its
            // length is bounded; camera-ray steps are resumable and only bounded for sanity.
            let max_steps = if name == "shadow_step" { MAX_SHADOW_STEPS } else { 1e7 };
            if diag / x > max_steps {
                // The shadow step defaults to the step: where it was not set, the step is the
                // knob to name (single.step=1e-6 had blamed a shadow_step nobody set).
                let derived = name == "shadow_step" && !k.is_set(&key(name));
                let (name, whose) =
                    if derived { ("step", " for the shadow rays (their step defaults to it)") } else { (name, "") };
                return Err(k.invalid(
                    &key(name),
                    format!(
                        "{x} gives over {max_steps} steps{whose} across the medium's diagonal {diag}; use a larger step"
                    ),
                ));
            }
        }
        // One shadow invocation (glsl/view/shadow.comp) finds its light among all of them, then
        // marches both sides in one loop each, none of which can pause: with n iterations
        // taking n + 1 back-edges on llvmpipe, kept under the loop guard (glsl/include/budget.glsl).
        let shadow_steps = (diag / v.shadow_step).ceil() as u64;
        let lights = scene.lights.len() as u64;
        let iterations = lights + 1 + 2 * (shadow_steps + 1);
        if iterations > resumable::LOOP_GUARD as u64 {
            return Err(k.invalid(
                &key("shadow_step"),
                format!(
                    "{} gives {shadow_steps} steps across the medium's diagonal {diag}, and with {lights} lights one \
                     shadow invocation runs {iterations} loop iterations, past {}; use a larger step or merge lights",
                    v.shadow_step,
                    resumable::LOOP_GUARD
                ),
            ));
        }
        Ok(v)
    }

    /// Every Vulkan device binds 2^27 bytes (the spec's minimum maxStorageBufferRange): where
    /// the shadow volume would be larger, `auto` marches instead and `volume` says what to
    /// change. Solvers that change the settings after [`ViewSettings::parse`] (octaves: both
    /// chord directions) call it again.
    pub fn fit_shadow(self, k: &Knobs, scene: &Scene) -> Result<ViewSettings, SolverError> {
        let prefix = self.prefix;
        let bytes = shadow_bytes(scene, &self);
        if bytes <= MAX_SHADOW_VOLUME_BYTES {
            return Ok(self);
        }
        if k.get::<String>(&format!("{prefix}shadow"))? == "volume" {
            return Err(k.invalid(
                &format!("{prefix}shadow"),
                format!(
                    "the shadow volume needs {bytes} bytes ({} light units x the density grid), over the {} every \
                     device can bind; set it to march, or lower {prefix}env_dirs",
                    light_units(scene, self.env_dirs),
                    MAX_SHADOW_VOLUME_BYTES
                ),
            ));
        }
        Ok(ViewSettings { shadow: Shadow::March, ..self })
    }
}

/// A multiply scattered energy volume for the view pass (glsl/view/march.comp's `MsVolume`).
pub struct MsVolume<'a> {
    pub energy: &'a Buffer,
    pub dims: [u32; 3],
    pub channels: u32,
    pub origin: [f32; 3],
    pub lambda: f32,
    /// What follows the fluence, and how the view pass scatters it.
    pub flux: FluxUse,
    /// `lbl`'s forward population (`lbl.inject=forward`): its fluence and flux follow the
    /// volume's own field in the same buffer (glsl/view/march.comp, `ms_forward`).
    pub forward: bool,
    /// One slab of the volume (None: all of it).
    pub window: Option<MsWindow>,
}

/// A slab of whole layers of a volume too large for the device at once (`dom`'s light toward the
/// camera under dom.budget): the view runs once per slab and the images add up. The run counts
/// the samples whose layer is in `own` and holds the layers `held` (one more each side, where
/// the grid has them, for the trilinear corners); the run with `direct` also adds the direct
/// light and the background, so nothing is counted twice.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MsWindow {
    /// First layer held and how many.
    pub held: [u32; 2],
    /// First layer counted and one past the last.
    pub own: [u32; 2],
    pub direct: bool,
}

impl MsWindow {
    /// The window counting layers `lo .. hi` of a grid of `nz` layers.
    pub fn new(lo: u32, hi: u32, nz: u32, direct: bool) -> MsWindow {
        let first = lo.saturating_sub(1);
        MsWindow { held: [first, (hi + 1).min(nz) - first], own: [lo, hi], direct }
    }
}

/// How the view pass scatters a volume's multiply scattered light toward the camera
/// (glsl/view/march.comp, `ms_inscatter`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FluxUse {
    /// The fluence alone, isotropically: phi / 4 pi.
    None,
    /// The vector irradiance E follows; the two-term expansion phi / 4pi + 3 g E.w / 4pi,
    /// clamped at 0 (`wavefront`).
    TwoTerm,
    /// The vector irradiance of a D3Q6/D3Q18 lattice follows; the field is taken as a
    /// Henyey-Greenstein lobe about E of mean cosine k = |E| |E^|_1 / phi (the lattice's
    /// links carry a flow along E^ with |E| / phi = 1 / |E^|_1 at most), so scattering it by
    /// HG(g) gives phi HG(g k) exactly (HG's Legendre coefficients multiply), non-negative for
    /// any field (`lbl`).
    Lobe,
}

/// What one view march did.
pub struct ViewResult {
    pub image: Image,
    pub dispatches: u64,
    pub max_loop_iterations: u32,
    pub nonfinite_pixels: u32,
    pub device_bytes: u64,
}

/// March camera rays through the medium: single scattering with the exact phase function,
/// plus, when `ms` is given, the multiply scattered in-scattering from it.
pub fn march(
    gpu: &Gpu,
    scene: &Scene,
    gs: &GpuScene,
    v: &ViewSettings,
    ms: Option<&MsVolume>,
) -> Result<ViewResult, SolverError> {
    march_reporting(gpu, scene, gs, v, ms, &|_| {})
}

/// [`march`], reporting the pixels done after each submission of its resumable march (stage
/// "view pass: pixels"): a `single` render with heavy knobs (supersampling, many environment
/// directions, a shadow march) spends minutes in this one pass.
pub fn march_reporting(
    gpu: &Gpu,
    scene: &Scene,
    gs: &GpuScene,
    v: &ViewSettings,
    ms: Option<&MsVolume>,
    progress: &dyn Fn(Progress),
) -> Result<ViewResult, SolverError> {
    let (w, h) = (scene.render.width, scene.render.height);
    // The mesh's constants from what the scene modelled (render_alone has taken
    // `refraction=false` into it).
    let mut spec = gs.modelled.mesh_spec();
    spec.push((SPEC_OCTAVES, Spec::U32(v.octaves.n.clamp(1, MAX_OCTAVES))));
    spec.push((SPEC_STEP_FIT, Spec::Bool(step_fit(scene, v.step))));
    spec.push((super::gpu_scene::SPEC_ENVIRONMENT, Spec::Bool(gs.modelled.environment)));
    let pipeline = gpu.pipeline(&MARCH, &spec)?;
    let o = v.octaves;
    let pixels = w as u64 * h as u64;
    let out = gpu.buffer("view radiance", pixels * 16)?;
    // Every pixel starts at subsample 0, step 0, with transmittance 1.
    let mut init = [0f32; (STATE_BYTES_PER_PIXEL / 4) as usize];
    init[..3].copy_from_slice(&[1.0; 3]);
    let state = gpu.buffer_with("view state", &vec![init; pixels as usize])?;
    let stats = gpu.buffer("view stats", resumable::STATS_WORDS * 4)?;
    // The shadow volume, when the settings ask for one: every unit's depth at every voxel
    // centre (both ways for the bounded octaves), in one dispatch before the march.
    let window = ms.and_then(|m| m.window);
    let direct = window.map_or(true, |w| w.direct);
    let (shadow_buf, shadow_dims) = match shadow_grid(scene, v).filter(|_| direct) {
        Some(g) => {
            let units = light_units(scene, v.env_dirs);
            let voxels = g.dims.iter().map(|d| *d as u64).product::<u64>();
            let buf = gpu.buffer("view shadow volume", shadow_bytes(scene, v))?;
            let sp = gpu.pipeline(&SHADOW, &gs.modelled.view_spec())?;
            let p = gs
                .bind(Pass::new("view.shadow", QueueRole::Trace, &sp))
                .write(3, &buf)
                .push(&ShadowPush { shadow_step: v.shadow_step, env_dirs: v.env_dirs, units, sides: shadow_sides(v) })
                .cover_linear_z([voxels as u32, units]);
            let point = gpu.submit(QueueRole::Trace, &[p], &[])?;
            gpu.wait(point)?;
            (Some(buf), [g.dims[0], g.dims[1], g.dims[2], shadow_sides(v)])
        }
        None => (None, [0; 4]),
    };
    // One stand-in for whichever volume binding this render leaves unused.
    let unused = if ms.is_none() || shadow_buf.is_none() { Some(gpu.buffer("unused view volume", 4)?) } else { None };
    let ms_window = match (ms, window) {
        (_, Some(w)) => [w.held[0], w.held[1], w.own[0], w.own[1]],
        (Some(m), None) => [0, m.dims[2], 0, m.dims[2]],
        (None, None) => [0; 4],
    };
    let (ms_buf, ms_dims, ms_origin, ms_flux) = match ms {
        Some(m) => (
            m.energy,
            [m.dims[0], m.dims[1], m.dims[2], m.channels],
            [m.origin[0], m.origin[1], m.origin[2], m.lambda],
            m.flux as u32,
        ),
        None => (unused.as_ref().expect("made when ms is none"), [0; 4], [0.0; 4], 0),
    };
    // Where the forward field starts, in fields of C V floats: after the fluence, and the flux
    // where one follows it.
    let ms_forward = match ms {
        Some(m) if m.forward => {
            if m.flux == FluxUse::None {
                1
            } else {
                4
            }
        }
        _ => 0,
    };
    let shadow_ref = shadow_buf.as_ref().or(unused.as_ref()).expect("made when there is no shadow volume");
    let seed = scene.render.seed;
    let mut rounds = resumable::ROUNDS_PER_SUBMIT; // one run: nothing to learn from
    let left = |n: u64| progress(Progress::work(VIEW_STAGE, pixels.saturating_sub(n), pixels));
    let (dispatches, st) = resumable::run_until_done_reporting(
        gpu,
        QueueRole::Trace,
        "view",
        &stats,
        &mut rounds,
        |slot| {
            let push = ViewPush {
                step: v.step,
                shadow_step: v.shadow_step,
                env_dirs: v.env_dirs,
                jitter: v.jitter,
                seed_lo: seed as u32,
                seed_hi: (seed >> 32) as u32,
                supersample: v.supersample,
                budget: v.budget,
                slot,
                ms_flux,
                ms_only: !direct as u32,
                ms_forward,
                ms_dims,
                ms_origin,
                octave: [o.a, o.b, o.c, if o.bounded { 1.0 } else { 0.0 }],
                shadow_dims,
                ms_window,
            };
            gs.bind_emission(gs.bind(Pass::new("view.march", QueueRole::Trace, &pipeline)))
                .write(3, &out)
                .read_write(4, &stats)
                .read_write(5, &state)
                .read(6, ms_buf)
                .read(7, shadow_ref)
                .read(VIEW_MESH_NODES_BINDING, &gs.mesh_nodes)
                .read(VIEW_MESH_TRIS_BINDING, &gs.mesh_tris)
                .push(&push)
                .cover([w, h, 1])
        },
        &left,
    )?;
    let px: Vec<[f32; 4]> = gpu.read_buffer_as(&out)?;
    let mut image = Image::new(w, h);
    for (i, p) in px.iter().enumerate() {
        image.data[3 * i..3 * i + 3].copy_from_slice(&p[..3]);
    }
    Ok(ViewResult {
        image,
        dispatches,
        max_loop_iterations: st[2],
        nonfinite_pixels: st[0],
        device_bytes: out.size() + state.size() + stats.size() + shadow_buf.as_ref().map_or(0, |b| b.size()),
    })
}

/// What a solver that is the view pass alone reports (`single`, `octaves`).
#[derive(Clone, Debug, Serialize)]
pub struct ViewStats {
    /// Octaves of the multiple-scattering approximation (1: single scattering).
    pub octaves: u32,
    pub dispatches: u64,
    pub max_loop_iterations: u32,
    pub nonfinite_pixels: u32,
    /// How far to trust the march's step ([`ViewTrust`]).
    pub trust: ViewTrust,
}

/// The summary line of a solver that is the view pass alone (`single`, `octaves`): its trust.
pub fn trust_summary(solver: &str, report: &RenderReport) -> Vec<String> {
    report.detail::<ViewStats>().map(|s| vec![format!("{solver}: {}", s.trust.line())]).unwrap_or_default()
}

/// The progress stage of the view pass (its unit: pixels finished).
const VIEW_STAGE: &str = "view pass: pixels";

/// A render that is the view pass alone, with settings `v` read from `k` (`single`,
/// `octaves`): upload the scene, march, report.
pub fn render_alone(
    gpu: &Gpu,
    solver: &dyn Solver,
    req: &RenderRequest,
    k: &Knobs,
    v: &ViewSettings,
) -> Result<RenderOutput, SolverError> {
    let scene = req.scene;
    // The library's guard (the command line refuses earlier): a solver that holds one medium.
    if let Some(why) =
        crate::solvers::interface::materials_unsupported(solver.name(), scene).filter(|_| !solver.renders_materials())
    {
        return Err(SolverError::Unsupported(why));
    }
    let mut gs = if solver.renders_meshes() {
        GpuScene::upload_with(gpu, scene, req.force_full, super::gpu_scene::MAJORANT_CELL)?
    } else {
        GpuScene::upload(gpu, scene, req.force_full)?
    };
    // Refraction turned off: the march's kernel is specialised without it (march reads the
    // modelled set), and the report says the boundary was taken as index-matched.
    gs.modelled.refractive &= v.refraction;
    let pixels = scene.render.width as u64 * scene.render.height as u64;
    (req.progress)(Progress::work(VIEW_STAGE, 0, pixels));
    let view = march_reporting(gpu, scene, &gs, v, None, req.progress)?;
    (req.progress)(Progress::work(VIEW_STAGE, pixels, pixels));
    let trust = ViewTrust::of(scene, v);
    let mut stats = Stats::new(ViewStats {
        octaves: v.octaves.n,
        dispatches: view.dispatches,
        max_loop_iterations: view.max_loop_iterations,
        nonfinite_pixels: view.nonfinite_pixels,
        trust,
    });
    stats.faults = view.nonfinite_pixels as u64;
    let mut report = RenderReport::finish(gpu, solver, k, gs.modelled.clone(), gs.bytes + view.device_bytes, stats);
    report.warnings.extend(trust.warning(solver.name()));
    report.warnings.extend(unscattered_emission_warning(solver.name(), scene));
    report.zeroed_nonfinite(view.nonfinite_pixels);
    Ok(RenderOutput { image: view.image, variance: None, report, estimates: Vec::new() })
}

/// The warning of a solver that carries a medium's emission along the camera ray only (the
/// view pass alone: `single`, `octaves`; `sh-single`'s segments) where the medium also scatters:
/// the emitted light it scatters is missing, not a small error (tests/emission_tests.rs: an
/// emitting slab of optical thickness 2 at 62% of its radiance with albedo 0.5 and 31% with 0.9;
/// the campfire at 93% of its energy, bias relL2 0.10). None where nothing emits or nothing
/// scatters (albedo 0: then the camera ray's emission is all there is).
pub fn unscattered_emission_warning(solver: &str, scene: &Scene) -> Option<String> {
    let materials = scene.object.as_ref().map_or(&[][..], |o| &o.materials[..]);
    let albedo = materials.iter().map(|m| m.albedo.max_element()).fold(scene.medium.albedo.max_element(), f32::max);
    (scene.emissive() && albedo > 0.0).then(|| {
        format!(
            "{solver}: the medium emits and scatters (albedo up to {albedo}), and {solver} carries its emission along \
             the camera ray only: the emitted light the medium scatters is left out (an emitting slab of optical \
             thickness 2 renders at 62% of its radiance at albedo 0.5, 31% at 0.9); path, lbl, dom and networks \
             carry it (docs/solvers.md, \"Emission\")"
        )
    })
}
