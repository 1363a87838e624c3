//! Solver `path`: the ground truth. A volumetric path tracer on the GPU (glsl/path/trace.comp):
//! delta tracking against a majorant, next-event estimation with ratio tracking, MIS for the
//! environment, spectral tracking for chromatic media, Russian roulette; progressive
//! accumulation in batches, with the per-pixel variance of the mean beside the mean.
//!
//! Samples per pixel are the scene's `render.spp` (`--spp N`). Knobs: `scatterlab knobs path`
//! (max depth, batch, budget, collision cap, equiangular sampling, light tracing).
//!
//! Equiangular sampling (`equiangular`, default on) samples every point light also along each
//! ray segment in the medium (Kulla & Fajardo 2012, "Importance sampling techniques for path
//! tracing in participating media"), combined by MIS (power heuristic) with next-event
//! estimation from the distance-sampled scattering point: it tames the 1/r^2 variance of a
//! point light inside the medium. Both are unbiased; directional and environment lights are
//! unaffected.
//!
//! Light tracing (`light_tracing`): which point lights are rendered by light paths
//! (glsl/path/light.comp) instead of camera paths: `auto` (default) those strictly inside the
//! medium, unless a pinhole camera is inside it too or the light is so deep in a nearly
//! lossless medium that its paths would not get out within the collision cap (then a warning
//! names it) or in optically thin surroundings (`THIN_DEPTH`); `on` every point light, `off`
//! none. A light-traced light is skipped by the camera paths, so the image is a partition of
//! the paths by light, and the two estimates add (means and variances) without MIS. A point
//! light deep inside a scattering medium is the case camera paths handle worst
//! (deep-penetration noise: they reach the light's neighbourhood only by rare long random
//! walks; equiangular sampling fixes the 1/r^2 spikes, not that) and light paths best:
//! measured in docs/measurements.md. At most 32 lights (the first 32) can be light traced.
//! "spp" is the same budget for both: `spp` light paths per pixel, split into `light_batches`
//! independent batches whose spread gives the per-pixel variance (one light path adds to many
//! pixels), traced `light_group` batches per host wait, each into a splat slice of its own.

pub mod mnee;

use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use serde::Serialize;

use crate::gpu::{Gpu, Kernel, Pass, QueueRole, Spec, SpecKind};
use crate::output::Image;
use crate::scene::{CameraKind, Light, Scene};

use crate::solvers::interface::Progress;
use crate::solvers::interface::{
    Estimate, Figure, Headline, Knob, Knobs, Range, RenderOutput, RenderReport, RenderRequest, Rung, Schedule, Solver,
    SolverError, Stats, Variant,
};
use crate::solvers::parts::gpu_scene::{self, GpuScene};
use crate::solvers::parts::resumable;

pub struct Path;

/// Per pixel: sum of L and the sample count, then the sum of squared deviations M2 (two vec4),
/// plus the path state.
pub const ACCUM_BYTES_PER_PIXEL: u64 = 32 + STATE_BYTES_PER_PIXEL;

/// The first eight words of both path kernels' push constants (`Push` in glsl/path/trace.comp
/// and glsl/path/light.comp begin alike).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct PathPushHead {
    /// Finish samples (camera) or paths per slot (light) [.., sample_end).
    pub sample_end: u32,
    pub budget: u32,
    pub seed_lo: u32,
    pub seed_hi: u32,
    pub max_depth: u32,
    pub collision_cap: u32,
    pub slot: u32,
    /// Bit i: light i is rendered by light paths, and camera paths skip it.
    pub light_traced: u32,
    /// Russian roulette from this many scattering events on ...
    pub rr_depth: u32,
    /// ... for throughput below this: survival probability max(beta) / rr_threshold.
    pub rr_threshold: f32,
    /// The first sample (camera) or path (light) index of every pixel or slot
    /// (`render.first_sample`): a range renders indices [sample_begin, sample_end).
    pub sample_begin: u32,
}

/// Push constants of glsl/path/trace.comp.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct PathPush {
    pub head: PathPushHead,
    /// Bit i: point light i also sampled by equiangular sampling, combined by MIS.
    pub equiangular: u32,
    /// Bit i: light i (point or directional) lies outside the refractive object and reaches
    /// its inside by manifold next-event estimation through its facets ([`refractive_lights`]).
    pub mnee: u32,
    /// What a camera ray that misses the medium sees: the environment lights' radiance summed
    /// in scene order (W m^-2 sr^-1 per channel), as the kernel once summed it itself, bit for
    /// bit. Summed here because the kernel's loop over every light could not pause: on
    /// llvmpipe it ran outside the dispatch's budget (glsl/include/budget.glsl).
    pub env_seen: [f32; 3],
}

/// Push constants of glsl/path/light.comp.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct LightPush {
    pub head: PathPushHead,
    /// Fixed-point quanta per unit of splat.
    pub inv_quantum: f32,
    /// Sum of the mean intensities (W/sr) of the light-traced lights.
    pub power_sum: f32,
    /// Paths per slot in a batch, spp / batches, one more in the first `batch_r` batches.
    pub batch_q: u32,
    pub batch_r: u32,
    /// The batch whose sums the first splat slice holds.
    pub group_first: u32,
}

pub const TRACE: Kernel =
    Kernel { shader: shader!("path/trace"), push_bytes: std::mem::size_of::<PathPush>(), spec: TRACE_SPEC };
/// glsl/path/trace.comp's own specialisation constants: some light is reached through
/// specular chains (manifold NEE), some point light is sampled by equiangular sampling, the
/// scene has an environment light. Code for what a scene lacks is not compiled in.
pub const SPEC_MNEE: u32 = 14;
pub const SPEC_EQUIANGULAR: u32 = 15;
pub const SPEC_ENVIRONMENT: u32 = crate::solvers::parts::gpu_scene::SPEC_ENVIRONMENT;
const TRACE_SPEC: &[(u32, SpecKind)] = &[
    (crate::solvers::parts::gpu_scene::SPEC_DENSITY_KIND, SpecKind::U32),
    (crate::solvers::parts::gpu_scene::SPEC_CHROMATIC, SpecKind::Bool),
    (crate::solvers::parts::gpu_scene::SPEC_ANISOTROPIC, SpecKind::Bool),
    (crate::solvers::parts::gpu_scene::SPEC_FIELDS, SpecKind::Bool),
    (crate::solvers::parts::gpu_scene::SPEC_EMISSION, SpecKind::U32),
    (crate::solvers::parts::gpu_scene::SPEC_HAS_MESH, SpecKind::Bool),
    (crate::solvers::parts::gpu_scene::SPEC_REFRACTIVE, SpecKind::Bool),
    (SPEC_MNEE, SpecKind::Bool),
    (SPEC_EQUIANGULAR, SpecKind::Bool),
    (SPEC_ENVIRONMENT, SpecKind::Bool),
    (crate::solvers::parts::gpu_scene::SPEC_LOOP_LIMITED, SpecKind::Bool),
    (crate::solvers::parts::gpu_scene::SPEC_BATCH_PAUSE, SpecKind::U32),
];

/// The trace kernel's specialisation: the scene's and the mesh's ([`GpuScene`]), and whether
/// any light takes manifold NEE (`mnee`, a bit per light) or equiangular sampling
/// (`equiangular`), and the environment as the scene's modelled features say (all on with
/// `--force-full`); on llvmpipe, counting its SIMD batches' loops and pausing a batch past
/// `batch_pause` of them (glsl/include/batch.glsl).
fn trace_spec(gpu: &Gpu, gs: &GpuScene, equiangular: u32, mnee: u32, batch_pause: u32) -> Vec<(u32, Spec)> {
    let full = gs.modelled.forced_full;
    let mut spec = gs.modelled.mesh_spec();
    spec.push((SPEC_MNEE, Spec::Bool(mnee != 0 || full)));
    spec.push((SPEC_EQUIANGULAR, Spec::Bool(equiangular != 0 || full)));
    spec.push((SPEC_ENVIRONMENT, Spec::Bool(gs.modelled.environment)));
    spec.extend(batch_spec(gpu, batch_pause));
    spec
}

/// Whether a path kernel counts its SIMD batches' loops (on llvmpipe), and where it pauses them.
fn batch_spec(gpu: &Gpu, batch_pause: u32) -> [(u32, Spec); 2] {
    [
        (gpu_scene::SPEC_LOOP_LIMITED, Spec::Bool(resumable::loop_limited(gpu))),
        (gpu_scene::SPEC_BATCH_PAUSE, Spec::U32(batch_pause)),
    ]
}
pub const LIGHT: Kernel =
    Kernel { shader: shader!("path/light"), push_bytes: std::mem::size_of::<LightPush>(), spec: LIGHT_SPEC };
/// The light kernel's: the scene's and the mesh's, and whether to count its SIMD batches' loops.
const LIGHT_SPEC: &[(u32, SpecKind)] = &[
    (gpu_scene::SPEC_DENSITY_KIND, SpecKind::U32),
    (gpu_scene::SPEC_CHROMATIC, SpecKind::Bool),
    (gpu_scene::SPEC_ANISOTROPIC, SpecKind::Bool),
    (gpu_scene::SPEC_FIELDS, SpecKind::Bool),
    (gpu_scene::SPEC_EMISSION, SpecKind::U32),
    (gpu_scene::SPEC_HAS_MESH, SpecKind::Bool),
    (gpu_scene::SPEC_REFRACTIVE, SpecKind::Bool),
    (gpu_scene::SPEC_LOOP_LIMITED, SpecKind::Bool),
    (gpu_scene::SPEC_BATCH_PAUSE, SpecKind::U32),
];
/// The light kernel's bindings of the [[object]]'s BVH nodes and triangles (6 holds its stats).
const LIGHT_MESH_NODES_BINDING: u32 = 7;
const LIGHT_MESH_TRIS_BINDING: u32 = 8;

/// One batch's slice of the light splats, per pixel: 3 channels x one 64-bit sum.
pub const LIGHT_SLICE_BYTES_PER_PIXEL: u64 = 24;
/// Light batches are traced in groups, one splat slice per batch of a group, so that the host
/// waits once per group rather than once per batch (issue 42): as many slices as fit in this
/// many bytes (10 at 1024^2: the default 16 batches in two groups of 8; all 16 at 512^2).
pub const LIGHT_GROUP_BYTES: u64 = 256 << 20;
/// Per path slot: the resumable light-path state (`LightState` in glsl/path/light.comp: the
/// path, and a tracking loop paused mid-flight, in a chained interval through a mesh too).
pub const LIGHT_STATE_BYTES: u64 = 128;
/// Splats of a typical size are this many fixed-point quanta (2^24): ~7 significant digits.
const QUANTA_PER_TYPICAL_SPLAT: f64 = 16_777_216.0;
/// Mean optical depth around a light below which `auto` leaves it to camera paths.
pub const THIN_DEPTH: f64 = 0.1;
/// Default of `path.collision_cap`.
pub const DEFAULT_COLLISION_CAP: u32 = 1 << 20;
/// Lights beyond this index are never light traced (the mask is one 32-bit word).
pub const MAX_LIGHT_TRACED: usize = 32;

/// Per-pixel resumable path state (`PathState` in glsl/path/trace.comp: the path, the progress
/// of its current event, and a tracking loop paused mid-flight).
pub const STATE_BYTES_PER_PIXEL: u64 = 160;
/// The kernels keep the index of the light an event is at in 16 bits.
pub const MAX_LIGHTS: usize = 1 << 16;
/// A paused tracking loop keeps its majorant cell along y and z in 14 bits each
/// (glsl/include/tracking.glsl); no device's 3D images reach that many voxels (4 per cell).
pub const MAX_MAJORANT_CELLS: u32 = 1 << 14;

/// `u32::MAX` is "unbounded" for `max_depth`.
pub const UNBOUNDED: u32 = u32::MAX;

/// The mean and the variance of the mean per pixel and channel, from the sum of L and the sum
/// of squared deviations from the mean, M2 (glsl/path/trace.comp, add_samples).
pub fn mean_and_variance(sums: &[[f32; 4]], width: u32, height: u32) -> (Image, Image) {
    let mut mean = Image::new(width, height);
    let mut var = Image::new(width, height);
    for p in 0..(width * height) as usize {
        let s = sums[2 * p];
        let m2 = sums[2 * p + 1];
        let n = s[3] as f64;
        for c in 0..3 {
            let m = if n > 0.0 { s[c] as f64 / n } else { 0.0 };
            // The sample variance M2 / (n - 1), over n: the variance of the mean.
            let v = if n > 1.0 { (m2[c] as f64 / (n - 1.0)).max(0.0) / n } else { 0.0 };
            mean.data[3 * p + c] = m as f32;
            var.data[3 * p + c] = v as f32;
        }
    }
    (mean, var)
}

/// How deep a light at `p` sits, for choosing a strategy (a CPU estimate): the mean over 26
/// directions of the extinction optical depth from `p` to the box boundary (grey: max
/// channel), and the expected scattering events of a light path before it escapes or is
/// absorbed: a diffusing walk needs about tau_tr^2 / 2 events to cover a transport optical depth tau_tr
/// (mean square displacement 2 free paths^2 per event), and absorption ends it after about
/// 1 / (1 - albedo). tau_tr = sigma_t (1 - albedo g) times the density integrated from `p` to
/// the box boundary, the smallest over 26 directions (the easiest way out).
pub fn light_depth(scene: &Scene, p: Vec3) -> (f64, f64) {
    let m = &scene.medium;
    let sigma_tr = (m.sigma_t * (Vec3::ONE - m.albedo * m.g)).max_element() as f64;
    let mut tau_min = f64::INFINITY;
    let mut depth_sum = 0.0;
    for dx in -1i32..=1 {
        for dy in -1i32..=1 {
            for dz in -1i32..=1 {
                if dx == 0 && dy == 0 && dz == 0 {
                    continue;
                }
                let d = Vec3::new(dx as f32, dy as f32, dz as f32).normalize();
                // Distance to the box along d, then a midpoint-rule integral of the density.
                let t_exit = (0..3)
                    .map(|a| {
                        if d[a] > 0.0 {
                            (m.bounds_max[a] - p[a]) / d[a]
                        } else if d[a] < 0.0 {
                            (m.bounds_min[a] - p[a]) / d[a]
                        } else {
                            f32::INFINITY
                        }
                    })
                    .fold(f32::INFINITY, f32::min)
                    .max(0.0);
                const STEPS: usize = 128;
                let dt = t_exit / STEPS as f32;
                let integral: f64 =
                    (0..STEPS).map(|i| scene.density_at(p + d * (dt * (i as f32 + 0.5))) as f64).sum::<f64>()
                        * dt as f64;
                tau_min = tau_min.min(integral * sigma_tr);
                depth_sum += integral * m.sigma_t.max_element() as f64;
            }
        }
    }
    let absorbed_after = 1.0 / (1.0 - m.albedo.max_element() as f64).max(1e-12);
    (depth_sum / 26.0, (0.5 * tau_min * tau_min).min(absorbed_after))
}

/// Free paths shorter than this many float32 steps of position (at the medium's largest
/// coordinate) are not resolved by the path vertices.
pub const RESOLVED_STEPS: f64 = 8.0;

/// A warning when the medium's shortest mean free path is below what 32-bit vertex positions
/// resolve (`RESOLVED_STEPS` float steps at the medium's largest coordinate), or None.
///
/// A vertex cannot move less than one float step, so a random walk whose free paths are
/// shorter stalls in place near the surface, where it leaves whenever its direction points
/// out: reflectance comes out too high (never above the lossless case, since energy is still
/// conserved per event). Measured on a unit cube at the origin (coordinates 0.5, float step
/// 6e-8), albedo 0.99, against Chandrasekhar's half-space value 0.753 (256 spp, +-0.009):
/// sigma_t 1e6 0.739, 4e6 0.744, 8e6 0.779, 1.6e7 0.847, 1e8 0.953. The free flights
/// themselves stay correct at any thickness (tracking.glsl accumulates sub-step flights).
pub fn position_resolution_note(scene: &Scene) -> Option<String> {
    let m = &scene.medium;
    let majorant = scene.max_sigma_t() as f64 * scene.max_density() as f64;
    // Also refuses a NaN majorant.
    if majorant.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return None;
    }
    let free_path = 1.0 / majorant;
    let extent = m.bounds_min.abs().max(m.bounds_max.abs()).max_element() as f64;
    let step = extent * f32::EPSILON as f64;
    if free_path >= RESOLVED_STEPS * step {
        return None;
    }
    Some(format!(
        "the mean free path ({free_path:.1e}) is shorter than {RESOLVED_STEPS} float32 steps of position at this \
            medium's coordinates ({step:.1e} each; an extinction beyond {:.1e} per unit here): path vertices cannot \
            resolve the random walk, so scattering near the surface is quantised and the image biased bright (at \
            most the lossless albedo-1 result; pure absorption stays exact); a float32 limit that scaling the \
            scene does not move: lower sigma_t (a medium this opaque looks the same at a lower one)",
        1.0 / (RESOLVED_STEPS * step)
    ))
}

/// Equiangular sampling pays where a point light's 1/r^2 varies strongly over the medium:
/// `auto` takes the lights whose farthest and nearest distances to the medium's box differ by
/// more than this factor (a light inside or touching the box always).
pub const EQUIANGULAR_RATIO: f32 = 4.0;

/// The point lights `path.equiangular` samples by equiangular sampling too, as a bit mask
/// (lights 0..32).
pub fn equiangular_lights(scene: &Scene, mode: &str) -> u32 {
    let m = &scene.medium;
    let mut mask = 0u32;
    for (i, l) in scene.lights.iter().enumerate().take(32) {
        let Light::Point { position, .. } = l else { continue };
        let take = match mode {
            "on" | "true" => true,
            "off" | "false" => false,
            _ => {
                let nearest = (position.clamp(m.bounds_min, m.bounds_max) - *position).length();
                let farthest = (0..8)
                    .map(|k| {
                        let c = Vec3::new(
                            if k & 1 == 0 { m.bounds_min.x } else { m.bounds_max.x },
                            if k & 2 == 0 { m.bounds_min.y } else { m.bounds_max.y },
                            if k & 4 == 0 { m.bounds_min.z } else { m.bounds_max.z },
                        );
                        (c - *position).length()
                    })
                    .fold(0.0f32, f32::max);
                farthest > EQUIANGULAR_RATIO * nearest
            }
        };
        if take {
            mask |= 1 << i;
        }
    }
    mask
}

/// Which delta lights (point, directional) path reaches through specular chains, as bit masks
/// (chains, and of those the lights inside an object): with a refractive object, every point
/// or directional light. One outside every object reaches the media only through their smooth
/// dielectric boundaries, along refracted and reflected paths that a straight shadow ray
/// cannot follow and a scattered path reaches with probability 0 (a delta light behind a delta
/// interface); one inside an object reaches its own medium straight too, and by chains the
/// light it reflects at the boundary and the light it sends into other objects or back into
/// another sheet of its own. Camera paths reach the chains by manifold next-event estimation
/// (Hanika et al. 2015) specialised to flat facets: every specular chain (the facets the light
/// refracts or reflects at, up to `path.mnee_depth`) that holds at the scattering point adds its
/// share (glsl/path/trace.comp `mnee_estimate`, the chains listed per cell by
/// src/solvers/path/mnee.rs). Refused, naming the reason: objects that refract beside index-matched
/// ones (a leg in vacuum would cross an index-matched medium, and a straight shadow ray a
/// refractive one), light 32 or later (the masks' width).
pub fn refractive_lights(scene: &Scene) -> Result<(u32, u32), SolverError> {
    let Some(object) = scene.object.as_ref().filter(|o| o.refractive()) else { return Ok((0, 0)) };
    // The objects' indices for messages ("1.5", or "1.5, 1.33" for objects of several materials).
    let iors = object.materials.iter().map(|m| m.ior.to_string()).collect::<Vec<_>>().join(", ");
    let (mut mask, mut inside) = (0u32, 0u32);
    for (i, light) in scene.lights.iter().enumerate() {
        if matches!(light, Light::Environment { .. }) {
            continue;
        }
        let outside = object.light_outside(light);
        let why = if object.materials.iter().any(|m| m.ior == 1.0) {
            Some(
                "some objects are index-matched (ior 1) beside refractive ones, and path's manifold next-event \
                    estimation takes no medium on the legs between objects"
                    .to_string(),
            )
        } else if i >= 32 {
            Some("only lights 0..31 can be reached through the boundary (a 32-bit mask)".to_string())
        } else {
            None
        };
        if let Some(why) = why {
            return Err(SolverError::Unsupported(format!(
                "path: light {i} ({}) lies {} {}, whose {} (ior {}); {why}: light the objects with an \
                    environment, or give every object an ior other than 1",
                light.kind_name(),
                if outside { "outside" } else { "inside one of" },
                if object.parts.len() == 1 { "the object" } else { "the objects" },
                if object.parts.len() == 1 { "boundary refracts" } else { "boundaries refract" },
                iors
            )));
        }
        mask |= 1 << i;
        if !outside {
            inside |= 1 << i;
        }
    }
    Ok((mask, inside))
}

/// The chain lists of manifold NEE for the lights in `mnee` (`inside`: those inside an object;
/// a header alone when none).
fn mnee_grid(scene: &Scene, (mnee, inside): (u32, u32), opts: mnee::ChainOptions) -> Vec<u32> {
    let bvh = scene.object.as_ref().filter(|_| mnee != 0).map(|o| o.bvh.as_ref());
    mnee::facet_grid(scene, bvh, mnee, inside, opts)
}

/// Below this optical thickness of the objects (the thinnest channel's sigma_t of any of their
/// materials times the bounds' shortest side), `auto` carries the light's beams reflected at
/// their surfaces (`path.mnee_reflections` 1); above it they are left out by default.
pub const REFLECTED_BEAMS_BELOW: f32 = 4.0;

/// The `path.mnee_*` knobs, `auto` resolved for the scene. Several objects or a mesh that is
/// not convex need chains of three facets (light through one object or sheet into another);
/// one convex object takes single refractions only (its image as before chains). Reflected
/// beams only where the objects are optically thin (below [`REFLECTED_BEAMS_BELOW`]), where the
/// beam reflected at a far face reaches much of the medium. Measured on lavapipe: on a glass
/// sphere of sigma_t 2 (optical thickness 3.2) they add 0.8% (light outside) and 1.0% (inside)
/// at 4.5x and 10-40x the time, and in a thin slab with the light inside 134% (total internal
/// reflection); on `scenes/wax-blob.toml` (7.2) 0.44% at 19x the time, and on
/// `scenes/milk-orb.toml` (11) path took over 25x the time with them.
fn chain_options(k: &Knobs, scene: &Scene) -> Result<mnee::ChainOptions, SolverError> {
    let several = match &scene.object {
        Some(o) => o.parts.len() > 1 || !o.convex,
        None => false,
    };
    let thin = scene.object.as_ref().is_some_and(|o| {
        let extent = (scene.medium.bounds_max - scene.medium.bounds_min).min_element();
        o.materials.iter().any(|m| m.sigma_t.min_element() * extent < REFLECTED_BEAMS_BELOW)
    });
    let raw: String = k.get("mnee_reflections")?;
    let reflections = if raw == "auto" {
        u32::from(thin)
    } else {
        raw.parse::<u32>().map_err(|e| k.invalid("mnee_reflections", e.to_string()))?
    };
    let raw: String = k.get("mnee_depth")?;
    let depth = if raw == "auto" {
        if several {
            3
        } else if reflections > 0 {
            2
        } else {
            1
        }
    } else {
        raw.parse::<u32>().map_err(|e| k.invalid("mnee_depth", e.to_string()))?
    };
    Ok(mnee::ChainOptions { cells: k.get("mnee_cells")?, depth, rays: k.get("mnee_rays")?, reflections })
}

/// Which lights `path.light_tracing` hands to light paths (indices into `scene.lights`), and a
/// note for each light `auto` declined although it is inside the medium.
pub fn light_traced(scene: &Scene, mode: &str, collision_cap: u32) -> Result<(Vec<usize>, Vec<String>), SolverError> {
    // A pinhole inside the medium gives light paths' camera connections the same 1/t^2
    // singularity at the camera that camera paths have at a point light (formally infinite
    // variance; measured: per-pixel errors far above camera paths'), so auto then leaves every
    // light to camera paths, which handle that case with equiangular sampling.
    let pinhole_inside =
        matches!(scene.camera.kind, CameraKind::Perspective { .. }) && scene.inside_medium(scene.camera.origin);
    if !matches!(mode, "auto" | "on" | "off") {
        return Err(SolverError::Setting {
            key: "path.light_tracing".into(),
            reason: format!(
                "unknown value {mode:?}; give auto (point lights inside the medium), on (every point light) or off"
            ),
        });
    }
    let mut notes = Vec::new();
    let mut traced = Vec::new();
    if let Some(o) = &scene.object {
        // Light paths (glsl/path/light.comp) cross index-matched surfaces; through a refractive
        // one no straight connection reaches the camera, so camera paths render every light.
        if o.refractive() {
            if mode == "on" {
                return Err(SolverError::Setting {
                    key: "path.light_tracing".into(),
                    reason: "light paths do not cross a refractive [[object]] boundary (ior != 1: no straight \
                        connection to the camera); use auto or off (camera paths render every light)"
                        .into(),
                });
            }
            return Ok((traced, notes));
        }
        // A light path starts inside the object that holds its light.
        if mode == "on" {
            if let Some(i) =
                scene.lights.iter().position(|l| matches!(l, Light::Point { position, .. } if !o.contains(*position)))
            {
                return Err(SolverError::Setting {
                    key: "path.light_tracing".into(),
                    reason: format!(
                        "light {i} lies outside every [[object]]: light paths start inside the object that holds \
                            their light; use auto (the lights inside) or off"
                    ),
                });
            }
        }
    }
    for (i, l) in scene.lights.iter().enumerate() {
        // A light with no power has nothing to trace; leave it to the (cheap) camera side.
        let Light::Point { position, intensity } = l else { continue };
        if i >= MAX_LIGHT_TRACED || intensity.max_element() <= 0.0 {
            continue;
        }
        let take = match mode {
            "on" => true,
            "auto" if scene.inside_medium(*position) && !pinhole_inside => {
                let (depth, events) = light_depth(scene, *position);
                if depth < THIN_DEPTH {
                    // Optically thin around the light: most light paths leave without
                    // scattering, while camera paths with equiangular sampling are near-ideal
                    // for the (mostly single) scattering. Measured crossover on the cloud
                    // (32x32, 64 spp, relL2): mean depth 0.05 (sigma_t 0.1): light 0.128 vs
                    // camera 0.103; 0.14 (sigma_t 0.3): 0.098 vs 0.140.
                    false
                } else if events > (collision_cap / 16) as f64 {
                    // Light paths that could not get out before the collision cap would be cut
                    // short (biased low) after costing the cap each: leave such a light to
                    // camera paths, and say so.
                    notes.push(format!(
                        "light {i} is too deep for light tracing (about {events:.0} scattering events to escape, past \
                            path.collision_cap / 16); camera paths render it, expect deep-penetration noise; --set \
                            path.light_tracing=on forces light paths"
                    ));
                    false
                } else {
                    true
                }
            }
            _ => false,
        };
        if take {
            traced.push(i);
        }
    }
    Ok((traced, notes))
}

/// `path`'s own stats.
#[derive(Clone, Debug, Serialize)]
pub struct PathStats {
    /// Lights rendered by light paths (indices into the scene's lights).
    pub light_traced: Vec<usize>,
    /// Lights outside a refractive object, reached by manifold next-event estimation through
    /// the facets of its mesh (indices into the scene's lights).
    pub manifold_nee: Vec<usize>,
    /// For each of those lights, how many chains a cell of its grid lists on average (what a
    /// next-event estimate tries; every chain with `path.mnee_cells=1`).
    pub manifold_nee_facets_per_cell: Vec<f64>,
    /// How many specular chains of 1, 2, ... facets the lights' grids hold in all.
    pub manifold_nee_chains: Vec<u64>,
    /// Camera paths, when any light was left to them.
    pub camera: Option<CameraStats>,
    /// Light paths, when any light was traced from the light side.
    pub light_paths: Option<LightStats>,
    pub samples_per_second: f64,
}

/// What the camera-path kernel did.
#[derive(Clone, Debug, Serialize)]
pub struct CameraStats {
    pub truncated_paths: u64,
    pub dispatches: u64,
    pub max_loop_iterations: u32,
    /// On llvmpipe, the most loop back-edges one SIMD batch ran in a dispatch as its loop
    /// limiter counts them (glsl/include/batch.glsl: the batch pauses past 32768); 0 elsewhere.
    pub max_batch_loop_iterations: u32,
    /// Counted in 32 bits on the GPU per render; wraps past 4e9 (a lower bound then).
    pub tracking_steps: u32,
}

/// What the light-path kernel did.
#[derive(Clone, Debug, Serialize)]
pub struct LightStats {
    pub paths: f64,
    pub batches: u32,
    /// The light-traced part's image mean (over pixels and channels), from the batches, and
    /// its standard error.
    pub image_mean: f64,
    pub image_mean_stderr: f64,
    pub truncated_paths: u32,
    pub clamped_splats: u32,
    pub splats: u32,
    pub dispatches: u64,
    pub max_loop_iterations: u32,
    /// As [`CameraStats::max_batch_loop_iterations`].
    pub max_batch_loop_iterations: u32,
    pub tracking_steps: u32,
}

/// `path.max_depth` as the kernels take it (`unbounded` is `UNBOUNDED`).
fn max_depth(k: &Knobs) -> Result<u32, SolverError> {
    let raw: String = k.get("max_depth")?;
    Ok(if raw == "unbounded" {
        UNBOUNDED
    } else {
        raw.parse::<u32>().map_err(|e| k.invalid("max_depth", e.to_string()))?
    })
}

impl Solver for Path {
    fn name(&self) -> &'static str {
        "path"
    }

    fn about(&self) -> &'static str {
        "volumetric path tracer with NEE, equiangular sampling and light tracing: the unbiased ground truth"
    }

    fn is_reference(&self) -> bool {
        true
    }
    fn samples_pixels(&self) -> bool {
        true
    }

    fn knobs(&self) -> Vec<Knob> {
        vec![
            Knob::fixed(
                "max_depth",
                "unbounded",
                Range::IntOr { min: 0, max: (UNBOUNDED - 1) as u64, word: "unbounded" },
                "scattering events per path (1: single scattering)",
            ),
            Knob::derived(
                "batch",
                "about 2^24 pixel-samples, 1 to 1024 spp",
                Range::int(1, u32::MAX as u64),
                "samples per pixel between progress updates",
            ),
            resumable::budget_knob(),
            Knob::fixed(
                "batch_pause",
                "32768",
                Range::int(1024, resumable::LOOP_GUARD as u64 - 1),
                "on llvmpipe, the loop back-edges of a SIMD batch of 8 lanes past which it pauses at its next resumable \
                    point: the driver ends every loop silently past 65535, and a dispatch whose batch passes 60000 is \
                    refused. Lower leaves more room for work that cannot pause (a BVH query through a mesh whose thin \
                    triangles share a vertex) at more dispatches; real GPUs ignore it",
            ),
            Knob::fixed(
                "majorant_cell",
                "16",
                Range::int(1, 4096),
                "voxels on a majorant cell's edge (grid densities): smaller cells, fewer null collisions but more \
                    cell crossings (16 measured best on llvmpipe for 64^3 clouds; docs/measurements.md)",
            ),
            Knob::fixed(
                "schedule",
                "concurrent",
                Range::Choice(&["concurrent", "sequential"]),
                "where both camera and light paths run (a point light traced from the light side beside others): \
                 concurrent runs the light paths on the diffuse role beside the camera paths on the trace role (at \
                 once where the device has two queues); sequential one after the other. The same image either way",
            ),
            Knob::fixed(
                "collision_cap",
                "1048576",
                Range::int(1, u32::MAX as u64),
                "tentative collisions per path at most; a path that hits it is dropped, counted and warned of (biases \
                    low)",
            ),
            Knob::fixed(
                "equiangular",
                "auto",
                Range::Choice(&["auto", "on", "off", "true", "false"]),
                "also sample point lights by equiangular sampling along each ray, combined by MIS (Kulla & Fajardo \
                 2012): auto where the light's 1/r^2 varies more than 16x over the medium (inside it or close to it), \
                 on (true) every point light, off (false) none",
            ),
            Knob::fixed(
                "rr_depth",
                "5",
                Range::int(1, u32::MAX as u64),
                "Russian roulette from this many scattering events on (5, as Mitsuba 3's volpath: on the issue-11 \
                 sphere 18% more efficient than 3)",
            ),
            Knob::fixed(
                "rr_threshold",
                "1",
                Range::Real { min: 0.0, max: 1.0, min_open: true, max_open: false },
                "Russian roulette only for throughput below this (survival max(beta) / rr_threshold)",
            ),
            Knob::fixed(
                "mnee_cells",
                "32",
                Range::int(1, 64),
                "cells per axis of the grid that lists, for a light outside the refractive objects, the specular \
                    chains (facets it refracts or reflects at) that may reach each cell (manifold next-event estimation \
                    tries only those); 1 tries every chain",
            ),
            Knob::fixed(
                "mnee_depth",
                "auto",
                Range::IntOr { min: 1, max: mnee::MAX_DEPTH as u64, word: "auto" },
                "facets per specular chain at most, for a delta light behind refractive boundaries: 1 single \
                    refractions (and an inside light's single reflections); 2 adds the light reflected once inside \
                    before it scatters; 3 light that crosses a whole object or sheet on its way in; auto: 3 for \
                    several objects or one that is not convex, 2 for one optically thin convex object (below 4), else \
                    1",
            ),
            Knob::fixed(
                "mnee_reflections",
                "auto",
                Range::IntOr { min: 0, max: mnee::MAX_DEPTH as u64, word: "auto" },
                "reflections per specular chain at most: 1 takes the light's beam reflected once at a boundary \
                    (Fresnel F: 4% at normal incidence in glass, up to 1 under total internal reflection), 0 none; \
                    beams reflected twice or more are left out unless raised (each one more multiplies the chains); \
                    auto: 1 where the objects are optically thin (sigma_t x the bounds' shortest side below 4), else 0 \
                    (measured: 0.4-1.0% of the image at 4.5-40x the time on a glass sphere and the wax blob)",
            ),
            Knob::fixed(
                "mnee_rays",
                "12",
                Range::int(1, 64),
                "rays per facet edge (rays^2 per facet) traced from the light to find the chains longer than one \
                    facet; a chain whose beam is narrower than their spacing can be missed",
            ),
            Knob::fixed(
                "light_tracing",
                "auto",
                Range::Choice(&["auto", "on", "off"]),
                "point lights rendered by light paths: auto (inside the medium, where it pays), on (all), off (none); with [[object]] meshes, index-matched ones only, the lights inside an object",
            ),
            Knob::fixed(
                "light_batches",
                "16",
                Range::int(1, u32::MAX as u64),
                "independent batches of light paths (at most spp), whose spread gives the variance",
            ),
            Knob::fixed(
                "light_group",
                "0",
                Range::int(0, u32::MAX as u64),
                "most light batches traced per host wait, each with a splat slice of 24 bytes a pixel, spread \
                    evenly over the waits; 0: as many as fit in 256 MiB (the default 16 at up to 512x512, two groups \
                    of 8 at 1024x1024); the image is the same bits whatever the grouping",
            ),
        ]
    }

    fn kernels(&self) -> Vec<Kernel> {
        vec![TRACE, LIGHT]
    }

    fn render(&self, gpu: &Gpu, req: &RenderRequest) -> Result<RenderOutput, SolverError> {
        let scene = req.scene;
        let k = req.knobs(self)?;
        let (w, h) = (scene.render.width, scene.render.height);
        let pixels = w as u64 * h as u64;
        let spp = scene.render.spp;
        let first_sample = scene.render.first_sample;
        let max_depth = max_depth(&k)?;
        // Large batches keep every invocation busy: a dispatch runs until each invocation has
        // used its budget or finished the batch's samples, so with few samples per batch most
        // lanes idle while the longest paths of their SIMD group finish (the 512 x 512 sphere at
        // 64 spp: 2^20 pixel-samples a batch, 16 dispatches, 6.0 s; 2^24, 1 dispatch, 3.9 s;
        // the same image, bit for bit, since samples are numbered per pixel).
        let default_batch = ((1u64 << 24) / pixels.max(1)).clamp(1, 1024) as u32;
        let batch: u32 = k.get_or("batch", default_batch)?;
        let budget: u32 = k.get("budget")?;
        let batch_pause: u32 = k.get("batch_pause")?;
        let collision_cap: u32 = k.get("collision_cap")?;
        let eq_mode: String = k.get("equiangular")?;
        let equiangular = equiangular_lights(scene, &eq_mode);
        let rr_depth: u32 = k.get("rr_depth")?;
        let rr_threshold: f32 = k.get("rr_threshold")?;
        let lt_mode: String = k.get("light_tracing")?;
        let light_batches: u32 = k.get("light_batches")?;
        let light_group: u32 = k.get("light_group")?;
        let majorant_cell: u32 = k.get("majorant_cell")?;
        let schedule: Schedule = k.get("schedule")?;
        let chain_opts = chain_options(&k, scene)?;
        k.finish()?;
        check_limits(scene, majorant_cell)?;
        let (mnee, mnee_inside) = refractive_lights(scene)?;
        // Equiangular sampling connects straight to the light: none through the boundary.
        let equiangular = equiangular & !(mnee & !mnee_inside);
        let mnee_grid = mnee_grid(scene, (mnee, mnee_inside), chain_opts);
        let (traced, lt_notes) = light_traced(scene, &lt_mode, collision_cap)?;
        let light_mask = traced.iter().fold(0u32, |m, &i| m | (1 << i));
        // Camera paths are needed for every light not traced from the light side.
        let camera_lights = scene.lights.len() - traced.len();

        let gs = GpuScene::upload_with(gpu, scene, req.force_full, majorant_cell)?;
        let seed = scene.render.seed;
        let kernels = (camera_lights > 0) as u64 + (!traced.is_empty()) as u64;
        let total = spp as u64 * kernels.max(1);
        // One batch (the default below 2^24 pixel-samples) is one step: say so, rather than
        // show a bar that cannot move until the end.
        let stage = if batch >= spp { "samples per pixel, in one batch (path.batch)" } else { "samples per pixel" };
        (req.progress)(Progress::work(stage, 0, total));

        let common = Common {
            gpu,
            gs: &gs,
            w,
            h,
            spp,
            first_sample,
            budget,
            batch_pause,
            seed,
            max_depth,
            collision_cap,
            light_mask,
            rr_depth,
            rr_threshold,
            mnee_grid: &mnee_grid,
            env_seen: scene.environment_radiance().to_array(),
        };
        let needs_camera = camera_lights > 0 || traced.is_empty();
        let batches = light_batches.min(spp);
        let group = light_group_size(pixels, batches, light_group);
        let kinds = Kernels {
            camera: needs_camera,
            traced: &traced,
            batch,
            batches: [batches, group],
            features: [equiangular, mnee],
        };
        let (camera, light) = run_kernels(&common, scene, &kinds, schedule, (stage, total), req.progress)?;
        (req.progress)(Progress::work(stage, total, total));

        let mut warnings: Vec<String> = position_resolution_note(scene).into_iter().collect();
        warnings.extend(lt_notes);
        let parts = [camera.as_ref().map(|c| &c.0), light.as_ref().map(|l| &l.0)];
        let (image, variance, device_bytes) = sum_parts(w, h, parts.into_iter().flatten(), &mut warnings, gs.bytes);
        let estimates = estimates(parts.into_iter().flatten());
        let mut report = RenderReport::finish(gpu, self, &k, gs.modelled.clone(), device_bytes, Stats::new(()));
        let seconds = report.gpu_ms * 1e-3;
        let per_second = |x: f64| if seconds > 0.0 { x / seconds } else { 0.0 };
        let samples = (pixels * spp as u64) as f64;
        let steps = camera.as_ref().map_or(0, |c| c.1.tracking_steps) as f64
            + light.as_ref().map_or(0, |l| l.1.tracking_steps) as f64;
        let mnee_lights: Vec<usize> = (0..32).filter(|i| mnee & (1 << i) != 0).collect();
        let mut stats = Stats::new(PathStats {
            light_traced: traced,
            manifold_nee_facets_per_cell: mnee_lights.iter().map(|&i| mnee::mean_list_length(&mnee_grid, i)).collect(),
            manifold_nee: mnee_lights,
            manifold_nee_chains: mnee::chain_counts(&mnee_grid),
            camera: camera.as_ref().map(|c| c.1.clone()),
            light_paths: light.as_ref().map(|l| l.1.clone()),
            samples_per_second: per_second(samples),
        });
        stats.spp = Some(spp);
        stats.correlated_mean_stderr = light.as_ref().map_or(0.0, |l| l.1.image_mean_stderr);
        stats.throughput = vec![
            Figure { figure: "samples/s".into(), value: per_second(samples), unit: "1/s".into() },
            Figure { figure: "path segments/s".into(), value: per_second(steps), unit: "1/s".into() },
        ];
        report.stats = stats;
        report.warnings = warnings;
        Ok(RenderOutput { image, variance: Some(variance), report, estimates })
    }

    fn memory_estimate(&self, scene: &Scene, knobs: &Knobs) -> Result<u64, SolverError> {
        let pixels = scene.render.width as u64 * scene.render.height as u64;
        let mode: String = knobs.get("light_tracing")?;
        let (traced, _) = light_traced(scene, &mode, knobs.get("collision_cap")?)?;
        let stats = resumable::STATS_WORDS * 4;
        let grid =
            mnee_grid(scene, refractive_lights(scene).unwrap_or((0, 0)), chain_options(knobs, scene)?).len() as u64 * 4;
        let camera = if traced.len() < scene.lights.len() || traced.is_empty() {
            pixels * (32 + STATE_BYTES_PER_PIXEL) + stats + grid
        } else {
            0
        };
        let batches = knobs.get::<u32>("light_batches")?.min(scene.render.spp);
        let slices = light_group_size(pixels, batches, knobs.get("light_group")?) as u64;
        let light = if traced.is_empty() {
            0
        } else {
            pixels * (LIGHT_STATE_BYTES + slices * LIGHT_SLICE_BYTES_PER_PIXEL) + stats + 16
        };
        Ok(gpu_scene::scene_bytes_with(scene, knobs.get("majorant_cell")?) + camera + light)
    }

    /// path traces [[object]] meshes (glsl/include/mesh.glsl).
    fn renders_emission(&self) -> bool {
        true
    }

    fn renders_meshes(&self) -> bool {
        true
    }

    /// path follows each path into the object it crosses, whose triangles name its material
    /// (glsl/path/trace.comp path_mat).
    fn renders_materials(&self) -> bool {
        true
    }

    /// The ground truth on the cloud, for scale (no seed times it).
    fn headline(&self, quick: bool) -> Option<Headline> {
        let (size, spp) = if quick { ("64", "4") } else { ("512", "16") };
        Some(Headline::new(
            format!("path cloud {size}^2, {spp} spp"),
            "cloud.toml",
            &[("render.width", size), ("render.height", size), ("render.spp", spp)],
            "",
        ))
    }

    /// The light-traced core light's paths on the diffuse role beside the sun's and sky's camera
    /// paths on the trace role (scenes/lightning-at-dusk.toml).
    fn concurrency(&self, quick: bool) -> Option<Headline> {
        let (size, spp) = if quick { ("32", "4") } else { ("256", "32") };
        Some(Headline::new(
            format!("path lightning at dusk {size}^2, {spp} spp"),
            "lightning-at-dusk.toml",
            &[("render.width", size), ("render.height", size), ("render.spp", spp)],
            "",
        ))
    }

    fn ladder(&self, _scene: &Scene) -> Vec<Rung> {
        [4u32, 16, 64, 256, 1024].iter().map(|s| Rung::one("render.spp", s)).collect()
    }

    fn stability(&self) -> Vec<Variant> {
        // Where the default light-traces (a point light inside the medium), camera paths alone
        // too, so both of its estimators meet the extremes.
        let mut camera = Variant::new("camera paths", &[("render.spp", "64"), ("path.light_tracing", "off")]);
        camera.applies = |scene| light_traced(scene, "auto", DEFAULT_COLLISION_CAP).is_ok_and(|(t, _)| !t.is_empty());
        vec![Variant::new("", &[("render.spp", "64")]), camera]
    }

    fn summary(&self, report: &RenderReport) -> Vec<String> {
        let Some(p) = report.detail::<PathStats>() else { return Vec::new() };
        if p.light_traced.is_empty() {
            return Vec::new();
        }
        let traced: Vec<String> = p.light_traced.iter().map(|i| i.to_string()).collect();
        let camera = if p.camera.is_some() { "; every other light by camera paths" } else { "" };
        vec![format!("path: light {} by light paths{camera}", traced.join(", "))]
    }
}

/// What both kernels share.
struct Common<'a> {
    gpu: &'a Gpu,
    gs: &'a GpuScene,
    w: u32,
    h: u32,
    spp: u32,
    /// Samples `first_sample .. first_sample + spp` of every pixel.
    first_sample: u32,
    budget: u32,
    /// `path.batch_pause` (glsl/include/batch.glsl).
    batch_pause: u32,
    seed: u64,
    max_depth: u32,
    collision_cap: u32,
    light_mask: u32,
    rr_depth: u32,
    rr_threshold: f32,
    /// The facet lists of manifold NEE (src/solvers/path/mnee.rs).
    mnee_grid: &'a [u32],
    /// [`PathPush::env_seen`].
    env_seen: [f32; 3],
}

impl Common<'_> {
    fn head(&self, sample_end: u32, slot: u32) -> PathPushHead {
        PathPushHead {
            sample_end,
            budget: self.budget,
            seed_lo: self.seed as u32,
            seed_hi: (self.seed >> 32) as u32,
            max_depth: self.max_depth,
            collision_cap: self.collision_cap,
            slot,
            light_traced: self.light_mask,
            rr_depth: self.rr_depth,
            rr_threshold: self.rr_threshold,
            sample_begin: self.first_sample,
        }
    }
}

/// One kernel's share of the image.
struct Part {
    image: Image,
    variance: Image,
    /// Its name and the independent units its variance comes from ([`Estimate`]).
    name: &'static str,
    units: u64,
    warnings: Vec<String>,
    device_bytes: u64,
}

/// The path kernels' limits: lights indexed in 20 bits, majorant cells counted in 10 along y
/// and z; a scene past them is one line naming the knob or what to change.
fn check_limits(scene: &Scene, majorant_cell: u32) -> Result<(), SolverError> {
    if scene.lights.len() >= MAX_LIGHTS {
        return Err(SolverError::Unsupported(format!(
            "path: {} lights; the path kernels index lights in 20 bits, so at most {} (merge lights or use \
                an environment)",
            scene.lights.len(),
            MAX_LIGHTS - 1
        )));
    }
    if let Some(g) = scene.features().grid_dims {
        let md = gpu_scene::majorant_dims(g, majorant_cell);
        if md[1] >= MAX_MAJORANT_CELLS || md[2] >= MAX_MAJORANT_CELLS {
            return Err(SolverError::Unsupported(format!(
                "path: a grid of {} x {} x {} voxels; with majorant cells of {majorant_cell} voxels the path \
                    kernels take at most {} voxels along y and z (raise path.majorant_cell)",
                g[0],
                g[1],
                g[2],
                (MAX_MAJORANT_CELLS - 1) * majorant_cell
            )));
        }
    }
    Ok(())
}

/// What the camera and the light kernels each give: their part of the image and their stats.
type CameraPart = (Part, CameraStats);
type LightPart = (Part, LightStats);

/// Which kernels a render runs: camera paths (for the lights not traced from their side), light
/// paths from `traced`, and their batches and sampling features ([equiangular, mnee] masks).
struct Kernels<'a> {
    camera: bool,
    traced: &'a [usize],
    batch: u32,
    /// Light batches, and how many are traced per host wait.
    batches: [u32; 2],
    features: [u32; 2],
}

/// Run the camera and light kernels, one after the other on the trace role, or (path.schedule
/// concurrent, both kernels) at once on the two compute roles; `(stage, total)` names the
/// progress bar's work.
fn run_kernels(
    common: &Common,
    scene: &Scene,
    kinds: &Kernels,
    schedule: Schedule,
    (stage, total): (&'static str, u64),
    progress: &dyn Fn(Progress),
) -> Result<(Option<CameraPart>, Option<LightPart>), SolverError> {
    let Kernels { camera: needs_camera, traced, batch, batches, features: [equiangular, mnee] } = *kinds;
    let spp = common.spp;
    let (camera, light) = if needs_camera && !traced.is_empty() && schedule == Schedule::Concurrent {
        // Both kernels, independent (they estimate disjoint sets of paths into buffers of
        // their own): the light paths on the diffuse role from a second host thread, the
        // camera paths on the trace role here, so a device with two queues runs them at
        // once. Each is the same computation as on one role: the same image, bit for bit.
        let (cam, lt) = std::thread::scope(|s| {
            let light = s.spawn(|| light_paths(common, scene, traced, batches, QueueRole::Diffuse, &|_| {}));
            let cam = camera_paths(common, batch, [equiangular, mnee], QueueRole::Trace, &|done| {
                progress(Progress::work("samples per pixel (camera paths)", done, total))
            });
            (cam, light.join())
        });
        let lt = lt.map_err(|_| SolverError::Unsupported("path: the light-path thread panicked".into()))?;
        (Some(cam?), Some(lt?))
    } else {
        let camera = if needs_camera {
            Some(camera_paths(common, batch, [equiangular, mnee], QueueRole::Trace, &|done| {
                progress(Progress::work("samples per pixel", done, total))
            })?)
        } else {
            None
        };
        let offset = if camera.is_some() { spp as u64 } else { 0 };
        let light = if traced.is_empty() {
            None
        } else {
            Some(light_paths(common, scene, traced, batches, QueueRole::Trace, &|done| {
                progress(Progress::work(stage, offset + done, total))
            })?)
        };
        (camera, light)
    };
    Ok((camera, light))
}

/// The image and variance of the kernels' parts, and the device bytes with `scene_bytes`: the
/// two kernels estimate disjoint sets of paths (partition by light), so means and variances
/// (independent estimates) add. The parts' warnings join `warnings`.
fn sum_parts<'a>(
    w: u32,
    h: u32,
    parts: impl Iterator<Item = &'a Part>,
    warnings: &mut Vec<String>,
    scene_bytes: u64,
) -> (Image, Image, u64) {
    let mut image = Image::new(w, h);
    let mut variance = Image::new(w, h);
    let mut device_bytes = scene_bytes;
    for part in parts {
        for (a, b) in image.data.iter_mut().zip(&part.image.data) {
            *a += b;
        }
        for (a, b) in variance.data.iter_mut().zip(&part.variance.data) {
            *a += b;
        }
        warnings.extend(part.warnings.iter().cloned());
        device_bytes += part.device_bytes;
    }
    (image, variance, device_bytes)
}

/// The estimators behind the image: each part with its units, and its own layers where
/// there are two (camera and light paths), for `scatterlab merge`.
fn estimates<'a>(parts: impl Iterator<Item = &'a Part> + Clone) -> Vec<Estimate> {
    let several = parts.clone().count() > 1;
    parts
        .map(|p| Estimate {
            name: p.name,
            units: p.units,
            layers: several.then(|| (p.image.clone(), p.variance.clone())),
        })
        .collect()
}

/// Camera paths (glsl/path/trace.comp) for every light not in `c.light_mask`.
fn camera_paths(
    c: &Common,
    batch: u32,
    [equiangular, mnee]: [u32; 2],
    role: QueueRole,
    progress: &dyn Fn(u64),
) -> Result<(Part, CameraStats), SolverError> {
    let (gpu, gs, w, h) = (c.gpu, c.gs, c.w, c.h);
    let pixels = w as u64 * h as u64;
    let pipeline = gpu.pipeline(&TRACE, &trace_spec(gpu, gs, equiangular, mnee, c.batch_pause))?;
    let grid = gpu.buffer_with("path manifold NEE facet grid", c.mnee_grid)?;
    let accum = gpu.buffer("path accumulation", pixels * 32)?;
    let state = gpu.buffer("path state", pixels * STATE_BYTES_PER_PIXEL)?;
    let stats = gpu.buffer("path stats", resumable::STATS_WORDS * 4)?;
    let end = c.first_sample + c.spp;
    let mut sample_end = c.first_sample;
    let mut dispatches = 0u64;
    let mut rounds = 1u32; // a batch usually ends in its first dispatch; learnt from the last one
    while sample_end < end {
        sample_end = sample_end.saturating_add(batch).min(end);
        let (n, _) = resumable::run_until_done(gpu, role, "path", &stats, &mut rounds, |slot| {
            let push = PathPush { head: c.head(sample_end, slot), equiangular, mnee, env_seen: c.env_seen };
            gs.bind_emission(gs.bind_mesh(Pass::new("path.trace", role, &pipeline)))
                .read_write(3, &accum)
                .read_write(4, &stats)
                .read_write(5, &state)
                .read(8, &grid)
                .push(&push)
                .cover([w, h, 1])
        })?;
        dispatches += n;
        progress((sample_end - c.first_sample) as u64);
    }
    let st: Vec<u32> = gpu.read_buffer_as(&stats)?;
    let truncated = st[0] as u64;
    let sums: Vec<[f32; 4]> = gpu.read_buffer_as(&accum)?;
    let (image, variance) = mean_and_variance(&sums, w, h);
    let mut warnings = Vec::new();
    if truncated > 0 {
        warnings.push(format!(
            "{truncated} of {} camera paths hit the collision cap ({}) and were dropped; the image is biased low \
                there; raise path.collision_cap",
            pixels * c.spp as u64,
            c.collision_cap
        ));
    }
    // Every pixel finishes every sample of the range (its sums count them: s[3]).
    let part = Part {
        image,
        variance,
        name: "camera",
        units: c.spp as u64,
        warnings,
        device_bytes: accum.size() + state.size() + stats.size() + grid.size(),
    };
    Ok((
        part,
        CameraStats {
            truncated_paths: truncated,
            dispatches,
            max_loop_iterations: st[2],
            max_batch_loop_iterations: st[resumable::BATCH_WORD],
            tracking_steps: st[1],
        },
    ))
}

/// The typical size of one camera connection of a light path, W/(m^2 sr) per path: the
/// emitted weight (4 pi times the traced lights' summed mean intensity) times an isotropic
/// phase (1 / 4 pi) times the camera importance at the medium's nearest point (`splat` in
/// glsl/path/light.comp). It only sets the fixed-point scale: splats up to 2^16 times this are
/// exact to ~7 digits, larger ones are clamped and counted.
fn typical_splat(scene: &Scene, power_sum: f64) -> f64 {
    let (header, _) = crate::solvers::parts::gpu_scene::scene_block(scene);
    let k = header.cam_forward[3] as f64;
    let (wd, ht) = (scene.render.width as f64, scene.render.height as f64);
    let a_pix = (2.0 * k / wd) * (2.0 * k * (ht / wd) / ht);
    let m = &scene.medium;
    match scene.camera.kind {
        CameraKind::Perspective { .. } => {
            let o = scene.camera.origin;
            let nearest = o.clamp(m.bounds_min, m.bounds_max);
            // A camera inside (or at) the box: the distance floor keeps the scale finite.
            let t = (nearest - o).length().max(0.05 * (m.bounds_max - m.bounds_min).length()) as f64;
            power_sum / (a_pix * t * t)
        }
        CameraKind::Orthographic { .. } => power_sum / a_pix,
    }
}

/// The light kernel's batches, folded on the host: per pixel and channel the sums over batches
/// of n_b m_b and of n_b m_b^2, with m_b the batch's estimate from its n_b rounds of `pixels`
/// paths; the same for the image mean (over pixels and channels), whose standard error cannot
/// be had from the per-pixel variances: one light path adds to many pixels, so they correlate.
struct BatchSums {
    s1: Vec<f64>,
    s2: Vec<f64>,
    t1: f64,
    t2: f64,
}

impl BatchSums {
    fn new(n: usize) -> BatchSums {
        BatchSums { s1: vec![0.0; n], s2: vec![0.0; n], t1: 0.0, t2: 0.0 }
    }

    /// Fold one batch of `rounds` rounds of `paths` paths: its 64-bit fixed-point sums (two words
    /// each, in quanta of 1 / `inv_quantum`), whose means are the estimates m_b.
    fn fold(&mut self, words: &[u32], inv_quantum: f64, paths: f64, rounds: u32) {
        let mut batch_total = 0f64;
        for (i, pair) in words.chunks_exact(2).enumerate() {
            let sum = (((pair[1] as u64) << 32) | pair[0] as u64) as f64 / inv_quantum;
            let m_b = sum / paths;
            self.s1[i] += rounds as f64 * m_b;
            self.s2[i] += rounds as f64 * m_b * m_b;
            batch_total += m_b;
        }
        let mean_b = batch_total / self.s1.len() as f64;
        self.t1 += rounds as f64 * mean_b;
        self.t2 += rounds as f64 * mean_b * mean_b;
    }

    /// The image, its per-pixel variance of the mean, the image mean and its standard error:
    /// Var(mean) = sum_b n_b (m_b - m)^2 / ((B - 1) N), with N = sum_b n_b = `spp` rounds.
    fn finish(&self, w: u32, h: u32, spp: u32, batches: u32) -> (Image, Image, f64, f64) {
        let mut image = Image::new(w, h);
        let mut variance = Image::new(w, h);
        let rounds_total = spp as f64;
        let var = |s1: f64, s2: f64| {
            let m = s1 / rounds_total;
            if batches > 1 {
                (s2 - rounds_total * m * m).max(0.0) / ((batches - 1) as f64 * rounds_total)
            } else {
                0.0
            }
        };
        for i in 0..self.s1.len() {
            image.data[i] = (self.s1[i] / rounds_total) as f32;
            variance.data[i] = var(self.s1[i], self.s2[i]) as f32;
        }
        (image, variance, self.t1 / rounds_total, var(self.t1, self.t2).sqrt())
    }
}

/// Batches of light paths traced together, one splat slice each: `asked` (`path.light_group`)
/// or, where it is 0, as many as fit in [`LIGHT_GROUP_BYTES`] (at least one); spread evenly
/// over the groups that `batches` needs.
pub fn light_group_size(pixels: u64, batches: u32, asked: u32) -> u32 {
    let fit = if asked > 0 {
        asked.min(batches.max(1))
    } else {
        (LIGHT_GROUP_BYTES / (pixels * LIGHT_SLICE_BYTES_PER_PIXEL).max(1)).clamp(1, batches.max(1) as u64) as u32
    };
    let groups = batches.div_ceil(fit).max(1);
    batches.div_ceil(groups).max(1)
}

/// Light paths (glsl/path/light.comp) from the lights in `traced`, `spp` per pixel, in
/// `batches` independent batches whose spread gives the per-pixel variance.
fn light_paths(
    c: &Common,
    scene: &Scene,
    traced: &[usize],
    [batches, group]: [u32; 2],
    role: QueueRole,
    progress: &dyn Fn(u64),
) -> Result<(Part, LightStats), SolverError> {
    let (gpu, gs, w, h) = (c.gpu, c.gs, c.w, c.h);
    let pixels = w as u64 * h as u64;
    let power_sum: f64 = traced
        .iter()
        .map(|&i| match &scene.lights[i] {
            Light::Point { intensity, .. } => (intensity.x + intensity.y + intensity.z) as f64 / 3.0,
            _ => 0.0,
        })
        .sum();
    let inv_quantum = QUANTA_PER_TYPICAL_SPLAT / typical_splat(scene, power_sum);
    let mut spec = gs.modelled.mesh_spec();
    spec.extend(batch_spec(gpu, c.batch_pause));
    let pipeline = gpu.pipeline(&LIGHT, &spec)?;
    let slice_words = (pixels * LIGHT_SLICE_BYTES_PER_PIXEL / 4) as usize;
    let splats = gpu.buffer("light splats", group as u64 * pixels * LIGHT_SLICE_BYTES_PER_PIXEL)?;
    let state = gpu.buffer("light path state", pixels * LIGHT_STATE_BYTES)?;
    let stats = gpu.buffer("light path stats", resumable::STATS_WORDS * 4)?;
    let lstats = gpu.buffer("light splat stats", 16)?;
    let n_total = c.spp as f64 * pixels as f64;
    let (batch_q, batch_r) = (c.spp / batches, c.spp % batches);
    // Paths per slot in batch b, and the path index that ends it.
    let rounds_of = |b: u32| batch_q + u32::from(b < batch_r);
    let end_of = |b: u32| (b + 1) * batch_q + (b + 1).min(batch_r);
    let mut dispatches = 0u64;
    let mut first_rounds = 1u32;
    // A group of batches is one resumable run over its path indices, each path splatting into
    // its batch's slice (glsl/path/light.comp, batch_of): the host waits once per few
    // dispatches of the group and once for its readback, not once or twice per batch, and the
    // slices' 64-bit integer sums are the same bits in whatever order the splats land.
    // Each group's sums are folded on another host thread while the next group runs on the
    // device (at 1024^2 a batch's fold is 3 M pixel-channels of f64 arithmetic the GPU would wait
    // for); the folds run in batch order, so the image is the same bits.
    let sums = std::thread::scope(|scope| -> Result<BatchSums, SolverError> {
        let mut folding: Option<std::thread::ScopedJoinHandle<BatchSums>> = None;
        let mut idle = Some(BatchSums::new(3 * pixels as usize));
        let mut first = 0u32;
        while first < batches {
            let last = (first + group).min(batches);
            let sample_end = c.first_sample + end_of(last - 1);
            // A fill, not an upload of zeros: no host buffer, and no staged copy waited for where
            // device memory is not mapped (splats of 24 MB a batch at 1024^2 are past the upload ring's).
            gpu.fill_zero(&splats)?;
            let (n, _) = resumable::run_until_done(gpu, role, "path", &stats, &mut first_rounds, |slot| {
                let push = LightPush {
                    head: c.head(sample_end, slot),
                    inv_quantum: inv_quantum as f32,
                    power_sum: power_sum as f32,
                    batch_q,
                    batch_r,
                    group_first: first,
                };
                gs.bind(Pass::new("path.light", role, &pipeline))
                    .read(LIGHT_MESH_NODES_BINDING, &gs.mesh_nodes)
                    .read(LIGHT_MESH_TRIS_BINDING, &gs.mesh_tris)
                    .read_write(3, &splats)
                    .read_write(4, &stats)
                    .read_write(5, &state)
                    .read_write(6, &lstats)
                    .push(&push)
                    .cover([w, h, 1])
            })?;
            dispatches += n;
            let words: Vec<u32> =
                gpu.read_buffer_prefix_as(&splats, (last - first) as u64 * pixels * LIGHT_SLICE_BYTES_PER_PIXEL)?;
            let mut sums = match folding.take() {
                Some(f) => f.join().expect("a batch fold does not panic"),
                None => idle.take().expect("the sums before the first fold"),
            };
            let group_first = first;
            folding = Some(scope.spawn(move || {
                for (i, slice) in words.chunks_exact(slice_words).enumerate() {
                    let rounds = rounds_of(group_first + i as u32);
                    sums.fold(slice, inv_quantum, rounds as f64 * pixels as f64, rounds);
                }
                sums
            }));
            first = last;
            progress((sample_end - c.first_sample) as u64);
        }
        Ok(match folding {
            Some(f) => f.join().expect("a batch fold does not panic"),
            None => idle.take().expect("no batch folded"),
        })
    })?;
    let st: Vec<u32> = gpu.read_buffer_as(&stats)?;
    let ls: Vec<u32> = gpu.read_buffer_as(&lstats)?;
    if ls[1] > 0 {
        return Err(SolverError::Unsupported(format!(
            "path: {} light-traced pixel sums overflowed their 64-bit fixed point within a batch; the image would be \
                wrong; raise path.light_batches (now {batches})",
            ls[1]
        )));
    }
    let (image, variance, image_mean, mean_stderr) = sums.finish(w, h, c.spp, batches);
    let mut warnings = Vec::new();
    if st[0] > 0 {
        warnings.push(format!(
            "{} of {n_total} light paths hit the collision cap ({}) or produced a non-finite splat and were cut \
                short; the image is biased low there; raise path.collision_cap",
            st[0], c.collision_cap
        ));
    }
    if ls[0] > 0 {
        warnings.push(format!(
            "{} light-path splats exceeded 2^16 times the typical splat and were clamped; the image \
            is biased low there",
            ls[0]
        ));
    }
    let part = Part {
        image,
        variance,
        name: "light",
        units: batches as u64,
        warnings,
        device_bytes: splats.size() + state.size() + stats.size() + lstats.size(),
    };
    Ok((
        part,
        LightStats {
            paths: n_total,
            batches,
            image_mean,
            image_mean_stderr: mean_stderr,
            truncated_paths: st[0],
            clamped_splats: ls[0],
            splats: ls[2],
            dispatches,
            max_loop_iterations: st[2],
            max_batch_loop_iterations: st[resumable::BATCH_WORD],
            tracking_steps: st[1],
        },
    ))
}
