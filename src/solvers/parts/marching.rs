//! Shared part: photon marching (thesis 4.4). The medium's density is resampled onto a voxel
//! grid (glsl/marching/resample.comp); every light becomes a raymap of straight rays
//! ([`raymaps`], 4.4.1); each round advances every ray by `k` fixed steps and writes what it
//! deposits (the power scattered out of the beam: the once-scattered source) into its k slots
//! of the Ray History Buffer (glsl/marching/march.comp, Fig. 4.4); a transfer adds a round's
//! history into per-voxel sums, by float atomics or, deterministically, in fixed point
//! (glsl/marching/transfer_*.comp, 4.4.4). What consumes the sums is the caller's: `lbl`
//! injects them into its lattice.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use rayon::prelude::*;

use crate::gpu::{Buffer, Gpu, Kernel, Pass, Pipeline, QueueRole, Spec, SpecKind};
use crate::physics::geometry::ray_box;
use crate::physics::phase::orthonormal_basis;
use crate::physics::rng::Pcg32;
use crate::scene::{voxelise, Light, Scene};

use super::gpu_scene::{GpuScene, SCENE_SPEC};
use super::lattice::{LatticeGeom, LATTICE_SPEC, SPEC_LINKS, SPEC_NCH};
use super::resumable::{self, LOOP_GUARD};
use crate::solvers::interface::{Knob, Knobs, Range, SolverError};

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
    /// The first ray this dispatch marches (dims.w: how many).
    first_ray: u32,
    /// 1: carry the forward population (march.comp).
    forward: u32,
    pad: [u32; 2],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct TransferPush {
    entries: u32,
    voxels: u32,
    scale: f32,
    /// History slots per ray.
    k: u32,
    /// 1: also sum each deposit's flux (glsl/lattice/inject.comp).
    directed: u32,
    /// 1: also sum the forward population (march.comp).
    forward: u32,
    /// Quanta per W of the forward population's sums (glsl/include/transfer.glsl, times 1/4).
    fwd_scale: f32,
    pad: u32,
}

pub const RESAMPLE: Kernel =
    Kernel { shader: shader!("marching/resample"), push_bytes: std::mem::size_of::<GeomPush>(), spec: SCENE_SPEC };
pub const MARCH: Kernel =
    Kernel { shader: shader!("marching/march"), push_bytes: std::mem::size_of::<MarchPush>(), spec: MARCH_SPEC };
/// The march's: the scene's and the mesh's, and whether to count its SIMD batches' loop
/// back-edges (glsl/include/batch.glsl; [`Marcher::check_loops`]).
const MARCH_SPEC: &[(u32, SpecKind)] = &[
    (super::gpu_scene::SPEC_DENSITY_KIND, SpecKind::U32),
    (super::gpu_scene::SPEC_CHROMATIC, SpecKind::Bool),
    (super::gpu_scene::SPEC_ANISOTROPIC, SpecKind::Bool),
    (super::gpu_scene::SPEC_FIELDS, SpecKind::Bool),
    (super::gpu_scene::SPEC_EMISSION, SpecKind::U32),
    (super::gpu_scene::SPEC_HAS_MESH, SpecKind::Bool),
    (super::gpu_scene::SPEC_REFRACTIVE, SpecKind::Bool),
    (super::gpu_scene::SPEC_LOOP_LIMITED, SpecKind::Bool),
];
pub const TRANSFER_FLOAT: Kernel = Kernel {
    shader: shader!("marching/transfer_float"),
    push_bytes: std::mem::size_of::<TransferPush>(),
    spec: LATTICE_SPEC,
};
pub const TRANSFER_FIXED: Kernel = Kernel {
    shader: shader!("marching/transfer_fixed"),
    push_bytes: std::mem::size_of::<TransferPush>(),
    spec: LATTICE_SPEC,
};

/// Every kernel of this part.
pub fn kernels() -> Vec<Kernel> {
    vec![RESAMPLE, MARCH, TRANSFER_FLOAT, TRANSFER_FIXED]
}

/// Bytes of one ray's start and state (`Ray` in glsl/marching/march.comp).
const RAY_BYTES: u64 = std::mem::size_of::<RayInit>() as u64;

/// One light ray's start: position, unit direction, power per channel (W).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct RayInit {
    pub pos_steps: [f32; 4],
    pub dir_alive: [f32; 4],
    pub power: [f32; 4],
    /// The forward population's power per channel (march.comp), 0 at the start, and its book:
    /// what its collisions absorbed and what left it at refractive surfaces.
    pub fwd: [f32; 4],
    pub fwd_absorbed: [f32; 4],
    pub fwd_out: [f32; 4],
}

/// What became of the forward population's power (`lbl.inject=forward`), per channel (W): the
/// lattice received the rest of it (its collisions' scattered share).
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct ForwardBook {
    pub absorbed: [f64; 3],
    pub left: [f64; 3],
}

/// Marching's knobs (a solver lists them among its own).
pub fn knobs() -> Vec<Knob> {
    vec![
        Knob::fixed("rays", "65536", Range::int(1, 1 << 22), "light rays per light (raymap size, thesis 4.4.1)"),
        Knob::fixed("k", "16", Range::int(1, 256), "Ray History Buffer slots per ray per round (steps per round)"),
        Knob::derived(
            "step",
            "half a voxel",
            Range::positive(),
            "photon-marching step in scene units (at most 4 voxels)",
        ),
        Knob::fixed(
            "threshold",
            "1e-4",
            Range::open_unit(),
            "a ray dies when its power falls below this fraction of its start",
        ),
        Knob::fixed(
            "env_lights",
            "14",
            Range::int(1, 4096),
            "directional raymaps standing in for an environment light (spherical Fibonacci set)",
        ),
    ]
}

/// Marching's knobs, parsed.
#[derive(Clone, Copy, Debug)]
pub struct MarchSettings {
    /// The solver whose knobs these are (`lbl`, `dom`): what an error names.
    pub solver: &'static str,
    pub rays: u32,
    pub k: u32,
    pub step: f32,
    pub threshold: f32,
    pub env_lights: u32,
}

impl MarchSettings {
    /// Read the knobs for a grid of voxel edge `lambda` (the step's default and bound).
    pub fn parse(k: &Knobs, solver: &'static str, lambda: f32) -> Result<MarchSettings, SolverError> {
        let out = MarchSettings {
            solver,
            rays: k.get("rays")?,
            k: k.get("k")?,
            step: k.get_or("step", lambda * 0.5)?,
            threshold: k.get("threshold")?,
            env_lights: k.get("env_lights")?,
        };
        if out.step > 4.0 * lambda {
            return Err(k.invalid("step", format!("{} must be at most 4 voxels ({})", out.step, 4.0 * lambda)));
        }
        // The march deposits per voxel: steps finer than a thousandth of one add nothing but
        // time (1e-9 marched for minutes without a word).
        if out.step.is_nan() || out.step < 1e-3 * lambda {
            return Err(k.invalid(
                "step",
                format!("{} is under a thousandth of a voxel ({}); use at least that", out.step, 1e-3 * lambda),
            ));
        }
        Ok(out)
    }

    /// Device bytes of a [`Marcher`] on `geom` with `ray_count` rays (as [`raymaps`] makes
    /// them) and `nch` channels: rays, history, with `sums` the grid's deposit sums (with the
    /// deposits' fluxes when `directed`) and the resampled density (each a 4-byte stand-in
    /// without `sums`: see [`Marcher::new`]).
    pub fn device_bytes(&self, geom: &LatticeGeom, ray_count: u64, nch: u32, directed: bool, sums: bool) -> u64 {
        let grid_bytes = if sums { geom.voxels() * 4 * (sum_slots(nch, directed) + 1) } else { 8 };
        grid_bytes + ray_count * (RAY_BYTES + self.k as u64 * 16)
    }
}

/// The raymaps of every light (thesis 4.4.1): `rays` rays per light, each carrying its share of
/// the light's power, started where it enters the grid, backed off by a jitter of up to one
/// step against aliasing. Point lights cover the solid angle the grid subtends (all
/// directions from inside); directional lights cover the grid's projection; an environment
/// becomes `env_lights` directional lights of irradiance L 4 pi / K from a spherical Fibonacci
/// set (an approximation the note in `docs/lbl.md` quantifies).
pub fn raymaps(scene: &Scene, geom: &LatticeGeom, rays: u32, env_lights: u32, step: f32, seed: u64) -> Vec<RayInit> {
    beams(scene, geom, rays, env_lights, step, seed).0
}

/// Where a raymap's rays come from: the direction every ray of it shares, or the point they
/// all leave from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Beam {
    Parallel(Vec3),
    FromPoint(Vec3),
}

/// [`raymaps`], with the raymap (beam) each ray belongs to and the beams: a voxel's deposits
/// from one beam all travel the same way (or away from the same point), which is what `dom`
/// bins its anisotropic first scattering by.
pub fn beams(
    scene: &Scene,
    geom: &LatticeGeom,
    rays: u32,
    env_lights: u32,
    step: f32,
    seed: u64,
) -> (Vec<RayInit>, Vec<u32>, Vec<Beam>) {
    let (mut out, mut ray_beam) = (Vec::new(), Vec::new());
    let beams = each_ray(scene, geom, rays, env_lights, step, seed, &mut |beam, r| {
        out.push(r);
        ray_beam.push(beam);
    });
    (out, ray_beam, beams)
}

/// How many rays [`raymaps`] makes (those that reach the grid), and the beams, without holding
/// the rays: the memory estimates' and the size check's count. Rays per light times lights can
/// be far more than memory holds (2000 point lights at lbl's 65536 rays each: 131 million rays,
/// 12.6 GB, which `scatterlab scene info` once built to count them).
pub fn ray_count(
    scene: &Scene,
    geom: &LatticeGeom,
    rays: u32,
    env_lights: u32,
    step: f32,
    seed: u64,
) -> (u64, Vec<Beam>) {
    let mut n = 0u64;
    let beams = each_ray(scene, geom, rays, env_lights, step, seed, &mut |_, _| n += 1);
    (n, beams)
}

/// Every ray of [`beams`] in order, handed to `emit` with its beam; returns the beams.
fn each_ray(
    scene: &Scene,
    geom: &LatticeGeom,
    rays: u32,
    env_lights: u32,
    step: f32,
    seed: u64,
    emit: &mut dyn FnMut(u32, RayInit),
) -> Vec<Beam> {
    let (lo, hi) = (geom.min(), geom.max());
    let centre = 0.5 * (lo + hi);
    let radius = 0.5 * (hi - lo).length();
    let mut rng = Pcg32::new(seed, 0x1b1);
    let m = (rays as f32).sqrt().ceil().max(1.0) as u32;
    let mut beams: Vec<Beam> = Vec::new();
    // Start a ray where it enters the grid (or at its origin from inside), backed off by a
    // random fraction of a step.
    let push = |emit: &mut dyn FnMut(u32, RayInit),
                beam: u32,
                o: Vec3,
                d: Vec3,
                power: Vec3,
                from_inside: bool,
                rng: &mut Pcg32| {
        let start = if from_inside {
            Some(o)
        } else {
            ray_box(o, d, lo, hi).filter(|(_, t1)| *t1 > 0.0).map(|(t0, _)| o + d * t0.max(0.0))
        };
        if let Some(s) = start {
            let s = s - d * (rng.next_f32() * step);
            emit(
                beam,
                RayInit {
                    pos_steps: [s.x, s.y, s.z, 0.0],
                    dir_alive: [d.x, d.y, d.z, 1.0],
                    power: [power.x, power.y, power.z, power.max_element()],
                    fwd: [0.0; 4],
                    fwd_absorbed: [0.0; 4],
                    fwd_out: [0.0; 4],
                },
            );
        }
    };
    let directional =
        |emit: &mut dyn FnMut(u32, RayInit), beams: &mut Vec<Beam>, dir: Vec3, e: Vec3, n: u32, rng: &mut Pcg32| {
            let beam = beams.len() as u32;
            beams.push(Beam::Parallel(dir));
            let (b1, b2) = orthonormal_basis(dir);
            let side = 2.0 * radius;
            let per = e * (side * side / (n * n) as f32);
            for i in 0..n {
                for j in 0..n {
                    let u = (i as f32 + rng.next_f32()) / n as f32 - 0.5;
                    let v = (j as f32 + rng.next_f32()) / n as f32 - 0.5;
                    let o = centre - dir * (radius * 1.01) + b1 * (u * side) + b2 * (v * side);
                    push(emit, beam, o, dir, per, false, rng);
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
                let (b1, b2) = orthonormal_basis(axis);
                let per = *intensity * (omega / (m * m) as f32);
                let from_inside = position.cmpge(lo).all() && position.cmple(hi).all();
                let beam = beams.len() as u32;
                beams.push(Beam::FromPoint(*position));
                for i in 0..m {
                    for j in 0..m {
                        // Stratified, uniform in solid angle over the cap cos_theta >= cos_max.
                        let u = (i as f32 + rng.next_f32()) / m as f32;
                        let v = (j as f32 + rng.next_f32()) / m as f32;
                        let ct = 1.0 - u * (1.0 - cos_max);
                        let st = (1.0 - ct * ct).max(0.0).sqrt();
                        let phi = 2.0 * std::f32::consts::PI * v;
                        let d = (b1 * (st * phi.cos()) + b2 * (st * phi.sin()) + axis * ct).normalize();
                        push(emit, beam, *position, d, per, from_inside, &mut rng);
                    }
                }
            }
            Light::Directional { direction, irradiance } => {
                directional(emit, &mut beams, direction.normalize(), *irradiance, m, &mut rng)
            }
            Light::Environment { radiance } => {
                let k = env_lights.max(1);
                let n = ((m * m / k) as f32).sqrt().ceil().max(8.0) as u32;
                for i in 0..k {
                    let z = 1.0 - (2.0 * i as f32 + 1.0) / k as f32;
                    let r = (1.0 - z * z).max(0.0).sqrt();
                    let phi = 2.399_963_2 * i as f32;
                    let d = Vec3::new(r * phi.cos(), r * phi.sin(), z);
                    let e = *radiance * (4.0 * std::f32::consts::PI / k as f32);
                    directional(emit, &mut beams, d, e, n, &mut rng);
                }
            }
        }
    }
    beams
}

/// Fixed-point quanta per W of the deposit sums (glsl/marching/transfer_fixed.comp,
/// glsl/ordinates/deposit.comp): 2^30 over a bound of everything the rays can deposit, so no
/// voxel's sum (nor a signed flux's magnitude) can pass 2^30 however the deposits fall. A ray of
/// power P marches at most `rounds` x k steps of at most `step` through extinction at most the
/// majorant `sigma_max` (1/unit), so it deposits at most P (1 - exp(-tau)) with tau that
/// majorant times that length. The quantum follows the light that a thin medium scatters:
/// 2^30 over the rays' whole power left a sphere 4.5e-6 mean free paths across 680 quanta of
/// once-scattered light (3.8% noise in the dithered sums; measured with the test
/// transfer_deposits_the_once_scattered_power_thin_to_thick), against 1e-9 of what it
/// deposits now.
pub fn deposit_scale(total_power: f64, sigma_max: f64, rounds: u32, set: &MarchSettings) -> f32 {
    let length = rounds as f64 * set.k as f64 * set.step as f64;
    let share = -(-(sigma_max * length)).exp_m1();
    let bound = total_power * share;
    // f32 holds 2^30 / bound for any bound above 1e-28 W; a scene that deposits less than that
    // (no light, or no medium) keeps a unit scale: its sums are 0 either way.
    if bound > 1e-28 {
        ((1u64 << 30) as f64 / bound).min(f32::MAX as f64) as f32
    } else {
        1.0
    }
}

/// Floats per voxel of the deposit sums: one per channel, and with `directed` the deposit's flux
/// (three per channel) after them.
fn sum_slots(nch: u32, directed: bool) -> u64 {
    nch as u64 * if directed { 4 } else { 1 }
}

/// Photon marching on one voxel grid: the resampled density, the rays, the Ray History
/// Buffer and the per-voxel deposit sums, with the passes that advance and transfer them.
/// The resampling kernel for `gs`'s medium.
pub fn resampler(gpu: &Gpu, gs: &GpuScene) -> Result<Pipeline, SolverError> {
    Ok(gpu.pipeline(&RESAMPLE, &gs.modelled.spec())?)
}

/// The medium's density at the voxel centres of layers `z0 .. z0 + layers` of `geom` (0 outside
/// the medium), on the device, indexed from the slab's first voxel.
/// `pipeline` is [`resampler`]'s.
pub fn resample(
    gpu: &Gpu,
    gs: &GpuScene,
    geom: &LatticeGeom,
    pipeline: &Pipeline,
    z0: u32,
    layers: u32,
) -> Result<Buffer, SolverError> {
    let dims = [geom.dims[0], geom.dims[1], layers];
    let density = gpu.buffer("marching density", dims.iter().map(|d| *d as u64).product::<u64>() * 4)?;
    let p = gs
        .bind(Pass::new("marching.resample", QueueRole::Trace, pipeline))
        .write(3, &density)
        .push(&GeomPush { dims: [dims[0], dims[1], dims[2], z0], origin: geom.origin4() })
        .cover(dims);
    let pt = gpu.submit(QueueRole::Trace, &[p], &[])?;
    gpu.wait(pt)?;
    Ok(density)
}

/// The lattice's density and material per voxel for objects of several materials: each voxel
/// takes the material it holds most of (objects are disjoint, so only voxels where two objects
/// touch hold two), and its density is that material's field at the voxel's centre times the
/// material's occupancy. A surface voxel's centre can lie outside its object (and its field's
/// box, which may be the object's own bounds): the field is read at the nearest point of its
/// box, as one medium's box spanning every object gives it there.
fn material_voxels(o: &crate::scene::Object, geom: &LatticeGeom) -> (Vec<f32>, Vec<u32>) {
    let occ = voxelise::material_occupancy(o, geom.min(), geom.lambda, geom.dims, voxelise::SUPERSAMPLE);
    let [nx, ny, _] = geom.dims.map(|d| d as usize);
    let (origin, lambda) = (geom.min(), geom.lambda);
    (0..geom.voxels() as usize)
        .into_par_iter()
        .map(|i| {
            let (m, share) =
                occ.iter()
                    .enumerate()
                    .map(|(m, o)| (m, o[i]))
                    .fold((0, 0.0f32), |best, x| if x.1 > best.1 { x } else { best });
            if share <= 0.0 {
                return (0.0, 0);
            }
            let c = origin
                + Vec3::new((i % nx) as f32 + 0.5, ((i / nx) % ny) as f32 + 0.5, (i / (nx * ny)) as f32 + 0.5) * lambda;
            let f = &o.fields[o.materials[m].field];
            (share * f.density_at(c.clamp(f.bounds_min, f.bounds_max)), m as u32)
        })
        .unzip()
}

/// Why `<solver>.k` = `k` is refused on a device with llvmpipe's loop limiter, where the march's
/// SIMD batches took up to `n` loop back-edges in a round and `step` in one step; `None` within
/// `LOOP_GUARD`. A step's count is measured before the limiter can have cut it short (a round's
/// first steps), unlike a round's past it, so the most steps that fit come from it.
pub fn loop_refusal(solver: &str, k: u32, n: u32, step: u32) -> Option<String> {
    if n <= LOOP_GUARD {
        return None;
    }
    let fit = (LOOP_GUARD - 1) / step.max(1);
    Some(if fit == 0 {
        format!(
            "{k}: one marching step through the [[object]]'s mesh took {step} loop iterations (its BVH \
             traversal), past llvmpipe's loop limiter ({LOOP_GUARD}) even at {solver}.k = 1: the mesh's \
             triangles' boxes overlap too much along the rays (long thin triangles fanned about one vertex \
             are the usual cause); re-triangulate the mesh, or use a device without the limit"
        )
    } else {
        format!(
            "{k}: a light ray's {k} marching steps took {n} loop iterations in a round (the mesh's BVH \
             traversals and surface crossings, up to {step} a step), past llvmpipe's loop limiter \
             ({LOOP_GUARD}), so rays may have stopped short silently; use {solver}.k <= {fit}"
        )
    })
}

pub struct Marcher {
    pub geom: LatticeGeom,
    /// The medium's density at every voxel centre (0 outside the medium); a 4-byte stand-in
    /// without grid sums (dom resamples slab by slab, [`resample`]).
    pub density: Buffer,
    pub rays: Buffer,
    /// With objects of several materials, the material of every lattice voxel (the one it
    /// holds most of; [`Marcher::density`] is that material's density times its occupancy).
    pub voxel_materials: Option<Vec<u32>>,
    /// The rays as they start ([`Marcher::reset`]).
    start: Vec<RayInit>,
    pub history: Buffer,
    /// Deposit sums per channel and voxel ([c * V + v]): float bits, or fixed point of
    /// `scale` quanta per W when `fixed`; when `directed`, each voxel's deposit flux (deposit
    /// times beam direction, [nch V + (3 c + axis) V + v]) follows.
    pub sums: Buffer,
    pub directed: bool,
    pub ray_count: u32,
    /// The beam (raymap) of each ray, and the beams ([`beams`]).
    pub ray_beam: Vec<u32>,
    pub beams: Vec<Beam>,
    /// Rounds of `k` steps until every ray has crossed the grid's diagonal (0 without rays:
    /// a scene lit by its emission alone).
    pub rounds: u32,
    pub fixed: bool,
    /// Fixed-point quanta per W of the deposit sums ([`deposit_scale`]).
    pub scale: f32,
    /// Quanta per W of the forward population's sums (a quarter of it, in transfer.glsl): 2^30
    /// over the rays' total power.
    fwd_scale: f32,
    set: MarchSettings,
    /// Carry anisotropic media's forward-scattered light along each ray (march.comp):
    /// [`Marcher::enable_forward`].
    forward: bool,
    /// With `forward`: the forward population per history slot, and its sums per voxel.
    fwd_history: Buffer,
    fwd_sums: Buffer,
    max_steps: u32,
    march: Pipeline,
    /// The most loop back-edges one SIMD batch of the march took in a round and in a step
    /// (glsl's `Loops`, two u32): [`Marcher::check_loops`].
    loops: Buffer,
    /// The transfer kernel, where the marcher keeps grid sums.
    transfer: Option<Pipeline>,
}

impl Marcher {
    /// Resample the density onto `geom`, build the raymaps and the buffers for `nch` channels.
    /// `fixed`: deterministic fixed-point transfer instead of float atomics. `directed`: also
    /// sum the deposits' fluxes (the first moment of anisotropic media's once-scattered light).
    /// `sums`: keep the grid's deposit sums, the resampled density and the transfer pass (lbl);
    /// without them (dom, which sums its deposits per beam and resamples the density slab by
    /// slab itself) the marcher holds nothing per voxel: at 512^3 that is 512 MiB per channel
    /// and 512 MiB of density not allocated.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        gpu: &Gpu,
        scene: &Scene,
        gs: &GpuScene,
        geom: LatticeGeom,
        set: &MarchSettings,
        nch: u32,
        fixed: bool,
        directed: bool,
        sums: bool,
    ) -> Result<Marcher, SolverError> {
        let v = geom.voxels();
        // Transfer kernels include lattice.glsl for the channel count; they never read links.
        let links = super::lattice::Lattice::D3q6.links();
        let transfer_spec = [(SPEC_NCH, Spec::U32(nch)), (SPEC_LINKS, Spec::U32(links))];
        let mut march_spec = gs.modelled.mesh_spec();
        march_spec.push((super::gpu_scene::SPEC_LOOP_LIMITED, Spec::Bool(resumable::loop_limited(gpu))));
        let march = gpu.pipeline(&MARCH, &march_spec)?;
        let transfer = if sums {
            Some(gpu.pipeline(if fixed { &TRANSFER_FIXED } else { &TRANSFER_FLOAT }, &transfer_spec)?)
        } else {
            None
        };
        let mut voxel_materials = None;
        let density = if !sums {
            gpu.buffer("marching density (none kept)", 4)?
        } else if let Some(o) = scene.object.as_ref().filter(|o| o.several_materials()) {
            let (dens, mats) = material_voxels(o, &geom);
            voxel_materials = Some(mats);
            gpu.buffer_with("marching density", &dens)?
        } else {
            let density = resample(gpu, gs, &geom, &resampler(gpu, gs)?, 0, geom.dims[2])?;
            if let Some(o) = &scene.object {
                // The lattice's extinction premultiplied by the mesh's occupancy (thesis 4.3): the
                // resampled density is the medium's wherever its box reaches, inside the mesh or not.
                let occ = voxelise::occupancy(o, geom.min(), geom.lambda, geom.dims, voxelise::SUPERSAMPLE);
                let mut dens: Vec<f32> = gpu.read_buffer_as(&density)?;
                for (d, o) in dens.iter_mut().zip(&occ) {
                    *d *= o;
                }
                gpu.write_buffer(&density, 0, bytemuck::cast_slice(&dens))?;
            }
            density
        };

        // Rays per light times lights: counted before they are made, so a count past one binding
        // (or the host's memory) is one line naming the knob, not an allocation that fails or
        // takes the machine's memory.
        let (count, _) = ray_count(scene, &geom, set.rays, set.env_lights, set.step, scene.render.seed);
        let widest = RAY_BYTES.max(set.k as u64 * 16);
        let max_binding = gpu.info().max_storage_buffer_range;
        if count * widest > max_binding {
            return Err(SolverError::Setting {
                key: format!("{}.rays", set.solver),
                reason: format!(
                    "{} with {} lights makes {count} light rays, whose {} MiB exceed this device's largest binding \
                     ({} MiB): use at most {} rays per light",
                    set.rays,
                    scene.lights.len(),
                    (count * widest) >> 20,
                    max_binding >> 20,
                    (set.rays as u64 * max_binding / (count * widest)).max(1)
                ),
            });
        }
        let (mut rays, ray_beam, beam_list) =
            beams(scene, &geom, set.rays, set.env_lights, set.step, scene.render.seed);
        if let Some(o) = &scene.object {
            // Which side of the mesh each ray starts on (march.comp: dir_alive.w 2 + the
            // material inside).
            for r in rays.iter_mut() {
                if let Some(m) = o.material_at(Vec3::new(r.pos_steps[0], r.pos_steps[1], r.pos_steps[2])) {
                    r.dir_alive[3] = 2.0 + m as f32;
                }
            }
        }
        let ray_count = rays.len() as u32;
        // A scene lit by its emission alone (no light, or none that reaches the box) marches no
        // ray: no rounds, and one-element stand-ins for the ray buffers.
        if ray_count == 0 && !scene.emissive() {
            return Err(SolverError::Unsupported("no light ray reaches the medium's box; check the lights".into()));
        }
        let total_power: f64 = (0..3).map(|c| rays.iter().map(|r| r.power[c] as f64).sum::<f64>()).fold(0.0, f64::max);
        let ray_buf = if ray_count == 0 {
            gpu.buffer_with("marching rays (none)", &[RayInit::zeroed()])?
        } else {
            gpu.buffer_with("marching rays", &rays)?
        };
        let history = gpu.buffer("marching ray history", ray_count.max(1) as u64 * set.k as u64 * 16)?;
        let sums = if sums {
            gpu.buffer("marching deposit sums", sum_slots(nch, directed) * v * 4)?
        } else {
            gpu.buffer("marching deposit sums (none kept)", 4)?
        };
        let diag = (geom.max() - geom.min()).length();
        let max_steps = (diag / set.step).ceil() as u32 + 2;
        let rounds = if ray_count == 0 { 0 } else { max_steps.div_ceil(set.k) };
        let fwd_scale = if total_power > 0.0 { ((1u64 << 30) as f64 / total_power) as f32 } else { 1.0 };
        let scale = deposit_scale(total_power, scene.max_sigma_t() as f64 * scene.max_density() as f64, rounds, set);
        Ok(Marcher {
            geom,
            density,
            voxel_materials,
            rays: ray_buf,
            start: rays,
            history,
            sums,
            directed,
            ray_count,
            ray_beam,
            beams: beam_list,
            rounds,
            fixed,
            scale,
            fwd_scale,
            set: *set,
            forward: false,
            fwd_history: gpu.buffer("marching forward history (none)", 16)?,
            fwd_sums: gpu.buffer("marching forward sums (none)", 16)?,
            max_steps,
            march,
            loops: gpu.buffer_with("marching loop counts", &[0u32; 2])?,
            transfer,
        })
    }

    /// Every ray back at its start, to march the light again (dom's direct source, slab by
    /// slab: the same steps and deposits each time).
    pub fn reset(&self, gpu: &Gpu) -> Result<(), SolverError> {
        Ok(gpu.write_buffer(&self.rays, 0, bytemuck::cast_slice(&self.start))?)
    }

    /// One round: every ray in `rays` advances `k` steps, writing its deposits into the history.
    pub fn march_pass(&self, gs: &GpuScene, rays: std::ops::Range<u32>) -> Pass {
        let g = &self.geom;
        let count = rays.end - rays.start;
        gs.bind_mesh(Pass::new("marching.march", QueueRole::Trace, &self.march))
            .read_write(3, &self.rays)
            .write(4, &self.history)
            .write(5, &self.fwd_history)
            .read_write(8, &self.loops)
            .push(&MarchPush {
                dims: [g.dims[0], g.dims[1], g.dims[2], count],
                origin: g.origin4(),
                step: self.set.step,
                threshold: self.set.threshold,
                k: self.set.k,
                max_steps: self.max_steps,
                first_ray: rays.start,
                forward: self.forward as u32,
                pad: [0; 2],
            })
            .cover_linear(count)
    }

    /// Add the last round's history into the sums, on queue role `role`.
    pub fn transfer_pass(&self, role: QueueRole) -> Pass {
        let entries = self.ray_count * self.set.k;
        let transfer = self.transfer.as_ref().expect("a marcher made with sums (Marcher::new's `sums`)");
        Pass::new("marching.transfer", role, transfer)
            .read(0, &self.history)
            .read_write(1, &self.sums)
            .read(2, &self.rays)
            .read(3, &self.fwd_history)
            .read_write(4, &self.fwd_sums)
            .push(&TransferPush {
                entries,
                voxels: self.geom.voxels() as u32,
                scale: self.scale,
                k: self.set.k,
                directed: self.directed as u32,
                forward: self.forward as u32,
                fwd_scale: self.fwd_scale,
                pad: 0,
            })
            .cover_linear(entries)
    }

    /// Carry anisotropic media's forward-scattered light along each ray and sum its fluence and
    /// flux per voxel (glsl/marching/march.comp); `nch` channels.
    pub fn enable_forward(&mut self, gpu: &Gpu, nch: u32) -> Result<(), SolverError> {
        let slots = self.ray_count.max(1) as u64 * self.set.k as u64;
        self.fwd_history = gpu.buffer("marching forward history", slots * 16)?;
        self.fwd_sums = gpu.buffer("marching forward sums", nch as u64 * 4 * self.geom.voxels() * 4)?;
        self.forward = true;
        Ok(())
    }

    /// The forward population's time-integrated field in the lattice's irradiance layout
    /// (fluence [c V + v] in W voxels, then the flux [nch V + (3 c + a) V + v]); `None`
    /// without [`Marcher::enable_forward`].
    pub fn forward_field(&self, gpu: &Gpu, nch: u32) -> Result<Option<Vec<f32>>, SolverError> {
        if !self.forward {
            return Ok(None);
        }
        let raw: Vec<u32> = gpu.read_buffer_as(&self.fwd_sums)?;
        let inv = 4.0 / self.fwd_scale;
        let n = nch as usize * self.geom.voxels() as usize;
        Ok(Some(
            raw.iter().enumerate().map(|(i, &q)| if i < n { q as f32 * inv } else { q as i32 as f32 * inv }).collect(),
        ))
    }

    /// The forward population's energy book once every ray has finished, per channel (W):
    /// absorbed by its collisions, and left (through refractive surfaces, out of the lattice
    /// with its ray, or stranded where the ray died); `None` without it.
    pub fn forward_book(&self, gpu: &Gpu) -> Result<Option<ForwardBook>, SolverError> {
        if !self.forward {
            return Ok(None);
        }
        let rays: Vec<RayInit> = gpu.read_buffer_as(&self.rays)?;
        let mut book = ForwardBook::default();
        for r in &rays {
            for c in 0..3 {
                book.absorbed[c] += r.fwd_absorbed[c] as f64;
                book.left[c] += (r.fwd[c] + r.fwd_out[c]) as f64;
            }
        }
        Ok(Some(book))
    }

    /// The most loop back-edges one SIMD batch of the march took in a round, and in one step,
    /// in any round so far (glsl/marching/march.comp's `Loops`, counted as llvmpipe counts them).
    fn loops(&self, gpu: &Gpu) -> Result<(u32, u32), SolverError> {
        let n: Vec<u32> = gpu.read_buffer_as(&self.loops)?;
        Ok((n[0], n[1]))
    }

    /// Fail loudly where llvmpipe's loop limiter may have ended a march batch's loops
    /// ([`resumable::loop_limited`]), once the rounds have run (their passes waited for). A
    /// round's k steps each traverse the mesh's BVH to the step's end and may cross a surface,
    /// at a cost the mesh sets, not k: a cone whose sides are a fan of 8192 triangles about its
    /// apex puts thousands of boxes across every ray near its axis (the tests' case), and its
    /// batches took 25901 back-edges at k = 1 and past the limiter from k = 3 (images wrong by
    /// 1.6e-3 relL2 at k = 6, 15% at 64, from the same marching). The batch's count, not a
    /// lane's: there lanes counted 36721 at k = 64 (docs/lavapipe.md). Real GPUs have no
    /// limiter: there the kernel counts nothing (LOOP_LIMITED off) and this reads 0.
    pub fn check_loops(&self, gpu: &Gpu) -> Result<(), SolverError> {
        if !resumable::loop_limited(gpu) {
            return Ok(());
        }
        let (n, step) = self.loops(gpu)?;
        match loop_refusal(self.set.solver, self.set.k, n, step) {
            Some(reason) => Err(SolverError::Setting { key: format!("{}.k", self.set.solver), reason }),
            None => Ok(()),
        }
    }

    /// Ray History Buffer slots per ray and round (`k`): entry e belongs to ray e / k.
    pub fn history_slots(&self) -> u32 {
        self.set.k
    }

    pub fn device_bytes(&self) -> u64 {
        self.density.size()
            + self.rays.size()
            + self.history.size()
            + self.sums.size()
            + if self.forward { self.fwd_history.size() + self.fwd_sums.size() } else { 0 }
    }
}

#[cfg(test)]
mod count_tests {
    use super::*;
    use crate::scene::Scene;

    #[test]
    fn loop_refusal_names_the_knob_and_the_steps_that_fit() {
        assert_eq!(loop_refusal("lbl", 64, LOOP_GUARD, 900), None);
        // The cone of 8192 fan triangles at lbl.k 4: 74424 in a round, 25894 a step.
        let m = loop_refusal("lbl", 4, 74424, 25894).expect("past the guard");
        assert!(m.starts_with("4: ") && m.ends_with("use lbl.k <= 2") && !m.contains('\n'), "{m}");
        // One step past the guard on its own: no k fits, and the message says what to change.
        let m = loop_refusal("lbl", 1, 70000, 70000).expect("past the guard");
        assert!(m.contains("even at lbl.k = 1") && m.contains("re-triangulate"), "{m}");
        assert!(loop_refusal("lbl", 1, 70000, LOOP_GUARD).unwrap().contains("even at lbl.k = 1"));
        assert!(loop_refusal("lbl", 2, 70000, LOOP_GUARD - 1).unwrap().ends_with("use lbl.k <= 1"));
    }

    #[test]
    fn ray_count_counts_what_beams_makes_without_holding_it() {
        // A point light outside (its cone's corners miss the box: dropped), one inside, a
        // directional light and an environment: the count and the beams are [`beams`]'s.
        let text = r#"
[render]
width = 4
height = 4
[camera]
kind = "orthographic"
origin = [0.0, 0.0, 3.0]
target = [0.0, 0.0, 0.0]
extent = 2.0
[medium]
bounds = [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]
sigma_t = 2.0
albedo = 0.5
density = { kind = "constant" }
[[light]]
kind = "point"
position = [1.5, 0.7, 0.9]
intensity = 1.0
[[light]]
kind = "point"
position = [0.1, 0.0, 0.0]
intensity = 1.0
[[light]]
kind = "directional"
direction = [0.3, -1.0, 0.2]
irradiance = 1.0
[[light]]
kind = "environment"
radiance = 0.5
"#;
        let scene = Scene::from_str(text, "t.toml", std::path::Path::new("."), &[], &Default::default()).unwrap();
        let geom = LatticeGeom::new(&scene, 16);
        for (rays, env) in [(1u32, 1u32), (1000, 4), (4096, 16)] {
            let (made, ray_beam, beams_made) = beams(&scene, &geom, rays, env, 0.02, 7);
            let (n, beams_counted) = ray_count(&scene, &geom, rays, env, 0.02, 7);
            assert_eq!(n, made.len() as u64, "rays {rays}");
            assert_eq!(ray_beam.len(), made.len());
            assert_eq!(beams_counted, beams_made);
            // Made: m^2 per point or directional light, n_e^2 per environment direction; some
            // of the outside light's and the parallel beams' rays miss the box and are dropped.
            let m = (rays as f32).sqrt().ceil() as u64;
            let n_e = ((m * m / env as u64) as f32).sqrt().ceil().max(8.0) as u64;
            let made_all = 3 * m * m + env as u64 * n_e * n_e;
            assert!(n <= made_all && (rays < 1000 || n < made_all), "rays {rays}: {n} of {made_all}");
        }
    }
}
