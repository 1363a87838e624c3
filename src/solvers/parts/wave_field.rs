//! Shared part: wavefront tracing of homogeneous spherical layers (Szirmay-Kalos, Liktor,
//! Umenhoffer, Toth, "Fast approximation of multiple scattering in inhomogeneous participating
//! media").
//!
//! Per point light inside the medium: the medium is resampled onto a spherical grid around the
//! light (glsl/wave_field/resample.comp, section 2.1), every ray of the grid is marched
//! w-layer by w-layer carrying the power measures psi0 = r^2 phi and psi1 = r^2 E of the
//! diffusion equations in spherical symmetry (eq. 4) together with the optical depth of the
//! direct term (march.comp), and the result is gathered back onto a Cartesian grid as the
//! multiply scattered fluence and vector irradiance (gather.comp: the wavefront's total minus
//! its direct term). Used by the `wavefront` solver and by `lbl`'s warm start.
//!
//! What the method assumes: a point light *inside* scattering medium (section 2: "a single
//! point light source in the origin"). Its initial values are the homogeneous infinite-medium
//! solution at the light (eq. 5). A point light outside the medium, or in a spot of zero
//! density, would start a diffusion solution in vacuum (psi0 stays 0, then goes negative at
//! the medium's surface under eq. 6), so such lights are not traced ([`traced_lights`]).
//!
//! Integrators: `exponential` (default; stable and non-negative for any step) or `explicit`
//! (the paper's eq. 6: from r = 0 it does not converge to the homogeneous solution in an
//! absorbing medium, and it goes negative once sigma_e R passes about 2.5: reported; see
//! glsl/wave_field/march.comp). The exponential integrator solves each ray with diffusion
//! theory's extrapolated boundary where the ray leaves the medium (`boundary = extrapolated`,
//! default: both exponential modes per shell, a backward and a forward sweep) or, as the paper
//! does, in an infinite medium (`boundary = infinite`: each shell's decaying mode, 23% too
//! bright on the light-inside cloud because the light that leaks out is kept).

use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use serde::Serialize;

use crate::gpu::{Buffer, Gpu, Kernel, Pass, Pipeline, QueueRole};
use crate::scene::{is_grey, Light, Scene};

use super::gpu_scene::{GpuScene, SCENE_SPEC};
use super::lattice::LatticeGeom;
use super::view::MsVolume;
use crate::solvers::interface::{Knob, Knobs, Range, SolverError};

/// How psi0 and psi1 are advanced across a shell.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Integrator {
    /// The paper's eq. 6: explicit Euler, first order in Delta, unstable for stiff shells.
    Explicit,
    /// The shell's exact homogeneous solution (decaying mode), carrying the power psi1:
    /// exact for homogeneous media, finite and non-negative for any step.
    Exponential,
}

impl std::str::FromStr for Integrator {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "explicit" => Ok(Integrator::Explicit),
            "exponential" => Ok(Integrator::Exponential),
            _ => Err(format!("unknown integrator {s:?}; use exponential or explicit")),
        }
    }
}

/// What the exponential integrator assumes beyond the medium.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Boundary {
    /// Diffusion theory's extrapolated boundary: phi = 0 a distance 2 D beyond where each ray
    /// leaves the medium, solved exactly for the ray's layer-wise homogeneous shells (both
    /// exponential modes per shell; glsl/wave_field/march.comp). Light leaks out.
    Extrapolated,
    /// The paper's infinite medium: each shell's decaying mode alone (eq. 5); nothing leaks
    /// out, so a bounded medium comes out too bright.
    Infinite,
}

impl std::str::FromStr for Boundary {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "extrapolated" => Ok(Boundary::Extrapolated),
            "infinite" => Ok(Boundary::Infinite),
            _ => Err(format!("unknown boundary {s:?}; use extrapolated or infinite")),
        }
    }
}

/// Parsed knobs.
#[derive(Clone, Copy, Debug)]
pub struct WaveSettings {
    pub nu: u32,
    pub nv: u32,
    pub layers: u32,
    pub integrator: Integrator,
    /// `exponential` only: the medium's boundary (the explicit scheme is the paper's
    /// infinite-medium march).
    pub boundary: Boundary,
    pub grid: u32,
    /// `explicit` only: radius (scene units) over which the homogeneous solution at the light
    /// (eq. 5) stands in before eq. 6 takes over; 0 = the paper's start at r = 0.
    pub explicit_start: f32,
}

/// Most radial layers: the march walks each ray at most three times in one invocation (the
/// extrapolated boundary's exit search, backward and forward sweeps; llvmpipe ends every loop
/// of an invocation after 65535 iterations in all; docs/lavapipe.md).
pub const MAX_LAYERS: u32 = 16384;

/// The knobs of wavefront tracing (unprefixed; `lbl`'s warm start lists them as `wavefront_*`).
pub fn knobs() -> Vec<Knob> {
    vec![
        Knob::fixed("nu", "64", Range::int(4, 4096), "rays of the spherical grid in azimuth"),
        Knob::fixed(
            "nv",
            "32",
            Range::int(2, 4096),
            "rays of the spherical grid in cos(theta) (uniform in solid \
            angle)",
        ),
        Knob::fixed(
            "layers",
            "128",
            Range::int(2, MAX_LAYERS as u64),
            "radial steps from the light to the farthest corner of the box",
        ),
        Knob::fixed(
            "integrator",
            "exponential",
            Range::Choice(&["exponential", "explicit"]),
            "exponential: exact per shell, stable and non-negative; explicit: the paper's eq. 6",
        ),
        Knob::fixed(
            "boundary",
            "extrapolated",
            Range::Choice(&["extrapolated", "infinite"]),
            "exponential only: extrapolated: phi = 0 at 2 D beyond where each ray leaves the medium (light leaks out); \
                infinite: the paper's infinite medium (nothing leaks; too bright)",
        ),
        Knob::fixed(
            "explicit_start",
            "0",
            Range::non_negative(),
            "explicit only: radius (scene units) over which the homogeneous solution at the light (eq. 5) stands in; \
                0 = the paper's start at r = 0",
        ),
        Knob::fixed(
            "grid",
            "64",
            Range::int(2, 1024),
            "Cartesian voxels along the box's longest side for the \
            gathered volume",
        ),
    ]
}

impl WaveSettings {
    /// Read `<prefix>nu` etc.
    pub fn parse(k: &Knobs, prefix: &str) -> Result<WaveSettings, SolverError> {
        let key = |n: &str| format!("{prefix}{n}");
        Ok(WaveSettings {
            nu: k.get(&key("nu"))?,
            nv: k.get(&key("nv"))?,
            layers: k.get(&key("layers"))?,
            integrator: k.get(&key("integrator"))?,
            boundary: k.get(&key("boundary"))?,
            grid: k.get(&key("grid"))?,
            explicit_start: k.get(&key("explicit_start"))?,
        })
    }

    /// Device bytes of [`wave_volume`] on `geom`: the gathered volume (fluence and flux per
    /// channel) and, when any light is traced, one light's spherical grid at a time.
    pub fn device_bytes(&self, scene: &Scene, chromatic: bool, geom: &LatticeGeom) -> u64 {
        let lights = traced_lights(scene);
        // The volume and two 16-byte stats buffers (the gather's and the marches').
        let volume = geom.voxels() * 4 * volume_channels(&lights, chromatic) as u64 * 4 + 32;
        let rays = self.nu as u64 * self.nv as u64;
        let field = rays * ((self.layers as u64 + 1) * 48 + self.layers as u64 * 4);
        volume + if lights.is_empty() { 0 } else { field }
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct WavePush {
    light: [f32; 4],
    intensity: [f32; 4],
    dims: [u32; 4],
    cart_dims: [u32; 4],
    cart_origin: [f32; 4],
}

const PUSH_BYTES: usize = std::mem::size_of::<WavePush>();
pub const RESAMPLE: Kernel =
    Kernel { shader: shader!("wave_field/resample"), push_bytes: PUSH_BYTES, spec: SCENE_SPEC };
pub const MARCH: Kernel = Kernel { shader: shader!("wave_field/march"), push_bytes: PUSH_BYTES, spec: SCENE_SPEC };
pub const GATHER: Kernel = Kernel { shader: shader!("wave_field/gather"), push_bytes: PUSH_BYTES, spec: &[] };

/// Every kernel of this part.
pub fn kernels() -> Vec<Kernel> {
    vec![RESAMPLE, MARCH, GATHER]
}

/// The spherical grid of one light on the GPU.
pub struct WaveField {
    pub position: Vec3,
    pub intensity: Vec3,
    /// Distance from the light to the farthest corner of the medium's box (scene units).
    pub radius: f32,
    /// Radial step Delta = radius / layers.
    pub delta: f32,
    pub nu: u32,
    pub nv: u32,
    pub layers: u32,
    pub psi0: Buffer,
    pub psi1: Buffer,
    pub tau: Buffer,
    pub shells: Buffer,
    /// Nodes with a negative psi value, with a non-finite one, rays with either.
    pub negative_nodes: u64,
    pub nonfinite_nodes: u64,
    pub failed_rays: u64,
}

impl WaveField {
    /// Node index (layer-major, as `wf_node` in glsl/include/wave_field.glsl).
    pub fn node(&self, i: u32, j: u32, n: u32) -> usize {
        (n as usize * self.nv as usize + j as usize) * self.nu as usize + i as usize
    }
    /// Direction of ray (i, j): alpha = 2 pi u, theta = arccos(1 - 2 v) at the cell centre.
    pub fn direction(&self, i: u32, j: u32) -> Vec3 {
        let u = (i as f32 + 0.5) / self.nu as f32;
        let v = (j as f32 + 0.5) / self.nv as f32;
        let alpha = 2.0 * std::f32::consts::PI * u;
        let ct = 1.0 - 2.0 * v;
        let st = (1.0 - ct * ct).max(0.0).sqrt();
        Vec3::new(alpha.cos() * st, alpha.sin() * st, ct)
    }
    pub fn device_bytes(&self) -> u64 {
        self.psi0.size() + self.psi1.size() + self.tau.size() + self.shells.size()
    }
    fn push(&self, set: &WaveSettings) -> WavePush {
        // The march's integrator (glsl/wave_field/march.comp): 0 explicit eq. 6, 1 exponential
        // in an infinite medium, 2 exponential with the extrapolated boundary.
        let integrator = match (set.integrator, set.boundary) {
            (Integrator::Explicit, _) => 0,
            (Integrator::Exponential, Boundary::Infinite) => 1,
            (Integrator::Exponential, Boundary::Extrapolated) => 2,
        };
        WavePush {
            light: [self.position.x, self.position.y, self.position.z, self.delta],
            intensity: [self.intensity.x, self.intensity.y, self.intensity.z, set.explicit_start],
            dims: [self.nu, self.nv, self.layers, integrator],
            cart_dims: [0; 4],
            cart_origin: [0.0; 4],
        }
    }
}

/// Channels of the gathered volume: one for a grey medium under grey traced lights (model only
/// what the scene requires), else three.
fn volume_channels(lights: &[(Vec3, Vec3)], chromatic: bool) -> u32 {
    if chromatic || !lights.iter().all(|(_, c)| is_grey(*c)) {
        3
    } else {
        1
    }
}

/// Point lights the method applies to: inside the box, on non-zero density (section 2).
pub fn traced_lights(scene: &Scene) -> Vec<(Vec3, Vec3)> {
    scene
        .lights
        .iter()
        .filter_map(|l| match *l {
            Light::Point { position, intensity } if scene.inside_medium(position) => Some((position, intensity)),
            _ => None,
        })
        .collect()
}

/// The spherical grid's radius around a light at `position`: its distance to the farthest corner
/// of the medium's box (scene units).
pub fn farthest_corner(scene: &Scene, position: Vec3) -> f32 {
    let m = &scene.medium;
    (0..8)
        .map(|k| {
            let c = Vec3::new(
                if k & 1 == 0 { m.bounds_min.x } else { m.bounds_max.x },
                if k & 2 == 0 { m.bounds_min.y } else { m.bounds_max.y },
                if k & 4 == 0 { m.bounds_min.z } else { m.bounds_max.z },
            );
            c.distance(position)
        })
        .fold(0.0f32, f32::max)
}

/// The solver's three pipelines, built once per render and shared by every light.
pub struct WaveKernels {
    resample: Pipeline,
    march: Pipeline,
    gather: Pipeline,
}

impl WaveKernels {
    pub fn new(gpu: &Gpu, gs: &GpuScene) -> Result<WaveKernels, SolverError> {
        let spec = gs.modelled.spec();
        Ok(WaveKernels {
            resample: gpu.pipeline(&RESAMPLE, &spec)?,
            march: gpu.pipeline(&MARCH, &spec)?,
            gather: gpu.pipeline(&GATHER, &[])?,
        })
    }
}

/// The spherical grid of one point light and the passes that resample and march it (eq. 4-6),
/// not yet submitted: the caller adds the gather and submits the three at once, one host wait
/// per light. The march adds its counts of negative and non-finite nodes to `stats` (words
/// 0-2), which the caller reads after the last light.
#[allow(clippy::too_many_arguments)]
fn light_passes(
    gpu: &Gpu,
    scene: &Scene,
    gs: &GpuScene,
    kernels: &WaveKernels,
    set: &WaveSettings,
    position: Vec3,
    intensity: Vec3,
    stats: &Buffer,
) -> Result<(WaveField, Vec<Pass>), SolverError> {
    let radius = farthest_corner(scene, position);
    let rays = set.nu as u64 * set.nv as u64;
    let nodes = rays * (set.layers as u64 + 1);
    let max = gpu.info().max_storage_buffer_range;
    if nodes * 16 > max {
        return Err(SolverError::Unsupported(format!(
            "wavefront tracing: {} x {} rays x {} layers needs {} bytes per buffer, over this device's \
                maxStorageBufferRange {max}; use fewer rays (nu, nv) or layers",
            set.nu,
            set.nv,
            set.layers,
            nodes * 16
        )));
    }
    let f = WaveField {
        position,
        intensity,
        radius,
        delta: radius / set.layers as f32,
        nu: set.nu,
        nv: set.nv,
        layers: set.layers,
        psi0: gpu.buffer("wave field psi0", nodes * 16)?,
        psi1: gpu.buffer("wave field psi1", nodes * 16)?,
        tau: gpu.buffer("wave field tau", nodes * 16)?,
        shells: gpu.buffer("wave field shells", rays * set.layers as u64 * 4)?,
        negative_nodes: 0,
        nonfinite_nodes: 0,
        failed_rays: 0,
    };
    let push = f.push(set);
    let passes = vec![
        gs.bind(Pass::new("wave_field.resample", QueueRole::Trace, &kernels.resample))
            .write(3, &f.shells)
            .push(&push)
            .cover([set.nu, set.nv, set.layers]),
        gs.bind(Pass::new("wave_field.march", QueueRole::Trace, &kernels.march))
            .read(3, &f.shells)
            .read_write(4, &f.psi0)
            .read_write(5, &f.psi1)
            .write(6, &f.tau)
            .read_write(7, stats)
            .push(&push)
            .cover([set.nu, set.nv, 1]),
    ];
    Ok((f, passes))
}

/// Resample and march the spherical grid of one point light (eq. 4-6) and wait for it, with
/// its counts of negative and non-finite nodes (the tests read single fields).
#[allow(clippy::too_many_arguments)]
pub fn trace_light(
    gpu: &Gpu,
    scene: &Scene,
    gs: &GpuScene,
    kernels: &WaveKernels,
    set: &WaveSettings,
    position: Vec3,
    intensity: Vec3,
) -> Result<WaveField, SolverError> {
    let stats = gpu.buffer("wave field stats", 16)?;
    let (mut f, passes) = light_passes(gpu, scene, gs, kernels, set, position, intensity, &stats)?;
    let point = gpu.submit(QueueRole::Trace, &passes, &[])?;
    gpu.wait(point)?;
    let st: Vec<u32> = gpu.read_buffer_as(&stats)?;
    f.negative_nodes = st[0] as u64;
    f.nonfinite_nodes = st[1] as u64;
    f.failed_rays = st[2] as u64;
    Ok(f)
}

/// The multiply scattered volume gathered from every traced light, in `MsVolume`'s layout.
pub struct WaveVolume {
    pub energy: Buffer,
    pub geom: LatticeGeom,
    pub channels: u32,
    pub lights_traced: usize,
    pub negative_nodes: u64,
    pub nonfinite_nodes: u64,
    pub failed_rays: u64,
    pub nonfinite_voxels: u64,
    pub device_bytes: u64,
}

impl WaveVolume {
    pub fn ms(&self) -> MsVolume<'_> {
        MsVolume {
            energy: &self.energy,
            dims: self.geom.dims,
            channels: self.channels,
            origin: self.geom.origin,
            lambda: self.geom.lambda,
            flux: super::view::FluxUse::TwoTerm,
            window: None,
            forward: false,
        }
    }
}

/// Trace every point light inside the medium and gather onto a Cartesian grid of `set.grid`
/// voxels along the box's longest side (the same geometry as `lbl`'s lattice), or onto `geom`.
pub fn wave_volume(
    gpu: &Gpu,
    scene: &Scene,
    gs: &GpuScene,
    set: &WaveSettings,
    geom: Option<LatticeGeom>,
) -> Result<WaveVolume, SolverError> {
    // The grid's knob: wavefront's own (lbl's warm start gathers onto its lattice, lbl.grid).
    let knob = if geom.is_some() { "lbl.grid" } else { "wavefront.grid" };
    let geom = geom.unwrap_or_else(|| LatticeGeom::new(scene, set.grid));
    let v = geom.voxels();
    let lights = traced_lights(scene);
    let channels = volume_channels(&lights, gs.modelled.chromatic);
    let bytes = v * 4 * channels as u64 * 4;
    let range = gpu.info().max_storage_buffer_range;
    if bytes > range {
        // (16 bytes a voxel and channel in one binding: the grid scales as its cube)
        let most = geom.dims.iter().copied().max().unwrap_or(1) as f64 * (range as f64 / bytes as f64).cbrt();
        return Err(SolverError::Unsupported(format!(
            "wavefront: the wave field's volume ({} x {} x {} voxels, {channels} channel(s)) needs {} MiB, past this \
             device's largest binding ({} MiB); set {knob}={} or less",
            geom.dims[0],
            geom.dims[1],
            geom.dims[2],
            bytes >> 20,
            range >> 20,
            most.floor() as u64
        )));
    }
    let energy = gpu.buffer("wave field volume", bytes)?;
    // Gather stats (word 0: non-finite voxels), then the march's (words 0-2 of the second).
    let stats = gpu.buffer("wave field gather stats", 16)?;
    let march_stats = gpu.buffer("wave field stats", 16)?;
    let kernels = WaveKernels::new(gpu, gs)?;
    let mut out = WaveVolume {
        energy,
        geom,
        channels,
        lights_traced: lights.len(),
        negative_nodes: 0,
        nonfinite_nodes: 0,
        failed_rays: 0,
        nonfinite_voxels: 0,
        device_bytes: 0,
    };
    let mut field_bytes = 0;
    for (pos, intensity) in lights {
        let (f, mut passes) = light_passes(gpu, scene, gs, &kernels, set, pos, intensity, &march_stats)?;
        field_bytes = field_bytes.max(f.device_bytes());
        let mut push = f.push(set);
        push.cart_dims = [geom.dims[0], geom.dims[1], geom.dims[2], channels];
        push.cart_origin = [geom.origin[0], geom.origin[1], geom.origin[2], geom.lambda];
        passes.push(
            Pass::new("wave_field.gather", QueueRole::Trace, &kernels.gather)
                .read(0, &f.psi0)
                .read(1, &f.psi1)
                .read(2, &f.tau)
                .read_write(3, &out.energy)
                .read_write(4, &stats)
                .push(&push)
                .cover(geom.dims),
        );
        // One submission and one wait per light: the light's grid is freed before the next one
        // is made, so a scene's lights never hold more than one grid of device memory.
        let point = gpu.submit(QueueRole::Trace, &passes, &[])?;
        gpu.wait(point)?;
    }
    let st: Vec<u32> = gpu.read_buffer_as(&stats)?;
    out.nonfinite_voxels = st[0] as u64;
    let ms: Vec<u32> = gpu.read_buffer_as(&march_stats)?;
    out.negative_nodes = ms[0] as u64;
    out.nonfinite_nodes = ms[1] as u64;
    out.failed_rays = ms[2] as u64;
    out.device_bytes = out.energy.size() + stats.size() + march_stats.size() + field_bytes;
    Ok(out)
}
