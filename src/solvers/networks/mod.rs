//! Illumination networks (issue 15; Szirmay-Kalos, Sbert, Umenhoffer, "Real-time multiple
//! scattering in participating media with illumination networks", EGSR 2005): the particle
//! model (2.1), the visibility network (3.1-3.2), the direct term, the iteration (3.3) with
//! warm starts and the splatted image, built on the device. Not yet a solver: its knobs and
//! registration, `scatterlab animate` and the measurements are still to come
//! (docs/networks.md says what is built and what is not).
//!
//! **Particles (2.1).** N points sampled with probability proportional to the density (so to
//! sigma_t, the paper's "collision density") by rejection in the medium's bounds, from the
//! scene's seed: deterministic. Every particle stands for the same share of the medium's
//! extinction: its *mass* m = (integral of the density over the bounds) / N (scene units^3; times
//! sigma_t it is an area, the particle's extinction cross-section).
//!
//! **Directions.** D directions of travel, uniform on the sphere and shared by all particles:
//! a Fibonacci lattice (equal areas, so the paper's Monte Carlo weight 4 pi / D is the
//! quadrature weight of each) turned by a rotation drawn from the seed.
//!
//! **Windows (3.1).** For each direction an M x M window on the plane through the bounding
//! sphere's centre perpendicular to it, covering the sphere (2R x 2R). A particle falls on one
//! pixel; its opacity there is alpha = 1 - exp(-sigma_t m / A), A = (2R / M)^2 the pixel's
//! area: the particles of a window column then hold, in expectation, the column's optical depth.
//! M follows the paper's rule (3.2), D (R tau)^2 / pi >= M^2, with tau the mean extinction
//! where the medium has density, unless set.
//!
//! **Visibility network (3.1).** V[p][i]: the particle nearest p upstream along direction i in
//! p's window column (the one whose radiance reaches p travelling along i), or none (the sky).
//! The paper peels depth layers with a z-buffer and reads them back; here three compute passes:
//! count each pixel's particles (glsl/networks/count.comp), prefix-sum the counts into bucket
//! offsets, fill the buckets (fill.comp), sort each bucket by (depth, index) and link each
//! particle to its predecessor (link.comp). [`Network::visibility_cpu`] is the same
//! construction on the host, operation for operation, which the tests compare bit for bit.
//!
//! **Emission (issue 47; 2.1's E_p).** An emissive medium is a source beside the lights,
//! compiled in only where the scene emits (EMISSION): by default (`networks.emission = march`)
//! the emission arriving unscattered at each particle along each direction, J, is marched
//! through the medium (glsl/networks/arrive.comp) and scattered by the iteration like the
//! direct light; `particles` is the paper's, alpha (1 - albedo) Le at each particle carried by
//! the columns ([`Network::emitted`]). docs/networks.md, "Emission", has the measurements.

use std::time::Instant;

use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use serde::Serialize;

use crate::gpu::{Buffer, Gpu, Kernel, Pass, QueueRole};
use crate::physics::angular::hg;
use crate::physics::geometry::{ray_box, ray_sphere};
use crate::physics::rng::Pcg32;
use crate::scene::{Light, Scene};

use crate::solvers::interface::{
    Convergence, Figure, Headline, Knob, Knobs, Progress, Range, RenderOutput, RenderReport, RenderRequest, Rung,
    Solver, SolverError, Stats, Variant,
};
use crate::solvers::parts::gpu_scene::GpuScene;
use crate::solvers::parts::resumable::LOOP_GUARD;

mod image;
mod iteration;
mod particles;
pub use image::*;
pub use iteration::*;
pub use particles::*;

pub const COUNT: Kernel =
    Kernel { shader: shader!("networks/count"), push_bytes: std::mem::size_of::<NetworkPush>(), spec: &[] };
pub const FILL: Kernel =
    Kernel { shader: shader!("networks/fill"), push_bytes: std::mem::size_of::<NetworkPush>(), spec: &[] };
pub const LINK: Kernel =
    Kernel { shader: shader!("networks/link"), push_bytes: std::mem::size_of::<NetworkPush>(), spec: &[] };
pub const DIRECT: Kernel = Kernel {
    shader: shader!("networks/direct"),
    push_bytes: std::mem::size_of::<DirectPush>(),
    spec: crate::solvers::parts::gpu_scene::VIEW_SPEC,
};
/// iterate.comp reads the scene block alone and declares scene.glsl's emission and
/// anisotropy constants itself.
pub const ITERATE: Kernel = Kernel {
    shader: shader!("networks/iterate"),
    push_bytes: std::mem::size_of::<IteratePush>(),
    spec: &[
        (crate::solvers::parts::gpu_scene::SPEC_EMISSION, crate::gpu::SpecKind::U32),
        (crate::solvers::parts::gpu_scene::SPEC_ANISOTROPIC, crate::gpu::SpecKind::Bool),
    ],
};
/// The lights' light scattered at each particle into each direction, once per light position.
pub const LIT: Kernel =
    Kernel { shader: shader!("networks/lit"), push_bytes: std::mem::size_of::<LitPush>(), spec: &[] };
/// An isotropic medium's in-scattering sum, once per particle per iteration.
pub const INSCATTER: Kernel =
    Kernel { shader: shader!("networks/inscatter"), push_bytes: std::mem::size_of::<InscatterPush>(), spec: &[] };
pub const GATHER: Kernel = Kernel {
    shader: shader!("networks/gather"),
    push_bytes: std::mem::size_of::<GatherPush>(),
    spec: crate::solvers::parts::gpu_scene::SCENE_SPEC,
};
pub const ARRIVE: Kernel = Kernel {
    shader: shader!("networks/arrive"),
    push_bytes: std::mem::size_of::<ArrivePush>(),
    spec: crate::solvers::parts::gpu_scene::SCENE_SPEC,
};
pub const SPLAT: Kernel = Kernel {
    shader: shader!("networks/splat"),
    push_bytes: std::mem::size_of::<SplatPush>(),
    spec: crate::solvers::parts::gpu_scene::VIEW_SPEC,
};

/// Every kernel of this part.
pub fn kernels() -> Vec<Kernel> {
    vec![COUNT, FILL, LINK, DIRECT, ARRIVE, LIT, INSCATTER, ITERATE, GATHER, SPLAT]
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct GatherPush {
    particles: u32,
    directions: u32,
    units: u32,
    direct: u32,
    /// [`EmissionModel::code`] (read only where the kernels model emission).
    emission: u32,
}

/// glsl/networks/lit.comp's push constants.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct LitPush {
    particles: u32,
    directions: u32,
    units: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct ArrivePush {
    step: f32,
    particles: u32,
    directions: u32,
    /// 0: march J; 1: scatter it into E (glsl/networks/arrive.comp).
    mode: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct SplatPush {
    sigma_m: [f32; 4],
    sky: [f32; 4],
    width: f32,
    /// Pixels along a screen tile's side ([`SplatTiles`]).
    tile: u32,
    /// Positive: each camera ray's splats scaled to the medium's optical depth along it, marched
    /// in steps of this (scene units); 0: the splats' own transmittance (the paper's).
    step: f32,
    /// Tiles along the image's width.
    tiles_x: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct DirectPush {
    step: f32,
    min_r2: f32,
    particles: u32,
    units: u32,
    env_dirs: u32,
    pad: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct IteratePush {
    alpha: [f32; 4],
    sky: [f32; 4],
    particles: u32,
    directions: u32,
    units: u32,
    slot: u32,
    /// 1: judge the previous slot against `tol` first (glsl/networks/iterate.comp).
    check: u32,
    tol: f32,
    /// [`EmissionModel::code`] (read only where the kernels model emission).
    emission: u32,
    /// 1: the lights' scattered light comes from the table glsl/networks/lit.comp made.
    lit: u32,
    /// 1: an anisotropic medium's in-scattering sums come from glsl/networks/inscatter.comp's
    /// table [p][i].
    summed: u32,
}

/// glsl/networks/inscatter.comp's push constants.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct InscatterPush {
    particles: u32,
    directions: u32,
    /// 1: return at once where the batch has stopped on the device.
    check: u32,
    /// Directions summed per particle: 1 (isotropic) or D ([`inscatter_outputs`]).
    outputs: u32,
}

/// How the medium's emission enters the network (`networks.emission`, issue 47).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EmissionModel {
    /// The emission arriving unscattered at each particle along each direction, J[p][i],
    /// marched through the medium itself (glsl/networks/arrive.comp) as the direct term is
    /// toward the lights: the network carries the emitted light from its first scattering on
    /// (the default: the particles' columns let light through more easily than the medium where
    /// they are partly empty, and emitted light's first flight is most of what it scatters).
    Marched,
    /// Each particle's own alpha (1 - albedo) Le in the paper's E array (2.1, E_p = Le ds),
    /// carried by the columns like every other radiance.
    Particles,
}

impl EmissionModel {
    /// The kernels' code for it (glsl/networks/iterate.comp's EMIT_PARTICLES, EMIT_MARCHED).
    pub fn code(self) -> u32 {
        match self {
            EmissionModel::Particles => 1,
            EmissionModel::Marched => 2,
        }
    }
}

/// The lights the direct term takes (point and directional; environments reach the particles
/// through the network's sky), in scene order.
pub fn light_units(scene: &Scene) -> Vec<&Light> {
    scene.lights.iter().filter(|l| !matches!(l, Light::Environment { .. })).collect()
}

/// The direct term's units: one per point or directional light, then `env_dirs` per
/// environment (0: environments reach the particles as the network's sky instead).
/// (The view pass's count, `view::light_units`; direct.comp orders them lights first.)
pub fn unit_count(scene: &Scene, env_dirs: u32) -> u32 {
    crate::solvers::parts::view::light_units(scene, env_dirs)
}

/// The paper's quadrature of the phase function on the directions, P[d][i] ~ 4 pi / D
/// p(w_d . w_i) ([d * D + i]), scaled symmetrically (P' = S P S, S diagonal: Sinkhorn's
/// balancing of a symmetric matrix) until every row and column sums to 1 within 1e-7. As
/// given, a row's sum is the quadrature's estimate of the phase function's integral, 1 only
/// on average: a forward-peaked lobe falls between the directions and the sums scatter, so at
/// albedo 1 some directions would gain energy on every scattering. Balanced, scattering
/// conserves it on the directions exactly and the network's furnace (albedo 1 under a uniform
/// sky) stays at the sky's radiance. Returns the matrix and the largest |row sum - 1| before
/// balancing.
pub fn phase_matrix(directions: &Directions, g: f64) -> (Vec<f32>, f64) {
    let w: Vec<glam::DVec3> = directions.frames.iter().map(|f| f[2].as_dvec3()).collect();
    let d = w.len();
    let weight = 4.0 * std::f64::consts::PI / d as f64;
    let p: Vec<f64> = (0..d * d).map(|k| weight * hg(g, w[k / d].dot(w[k % d]))).collect();
    let sums = |s: &[f64]| -> Vec<f64> { (0..d).map(|i| (0..d).map(|k| s[i] * p[i * d + k] * s[k]).sum()).collect() };
    let before = sums(&vec![1.0; d]).iter().map(|r| (r - 1.0).abs()).fold(0.0, f64::max);
    let mut s = vec![1.0f64; d];
    for _ in 0..10_000 {
        if sums(&s).iter().map(|r| (r - 1.0).abs()).fold(0.0, f64::max) < 1e-7 {
            break;
        }
        // s_i <- sqrt(s_i / (P s)_i): its fixed point makes S P S doubly stochastic (a
        // positive symmetric matrix has one).
        let ps: Vec<f64> = (0..d).map(|i| (0..d).map(|k| p[i * d + k] * s[k]).sum()).collect();
        s = (0..d).map(|i| (s[i] / ps[i]).sqrt()).collect();
    }
    ((0..d * d).map(|k| (s[k / d] * p[k] * s[k % d]) as f32).collect(), before)
}

/// The solver `networks`: the particle model, visibility network, iteration to a tolerance and
/// splatted image above, with its knobs.
pub struct Networks;

/// `networks`' own stats.
#[derive(Clone, Debug, Serialize)]
pub struct NetworksStats {
    pub particles: u32,
    pub directions: u32,
    /// M: the windows' resolution.
    pub window: u32,
    /// A particle's opacity across a window pixel (rgb).
    pub opacity: [f64; 3],
    /// The particles' spacing against the mean free path, against what networks was validated at.
    pub trust: ParticleTrust,
    /// With `networks.single=view`: how far to trust the view march that adds every light's
    /// single scattering (`networks.view_step`, `networks.view_shadow_step`).
    pub view_trust: Option<crate::solvers::parts::view::ViewTrust>,
    /// b: a particle's radius (scene units), the splats' footprint width at networks.footprint 1.
    pub particle_radius: f64,
    /// Whether the network was built and iterated: false where the particles make none of the
    /// image (nothing scatters and `networks.single = view`: the view pass's camera-ray march is
    /// the image, exactly as with them). The particles' counts above are what a scattering
    /// medium would have used.
    pub network: bool,
    pub iterations: u32,
    pub converged: bool,
    pub final_change: f64,
    pub splats_dropped: u64,
    pub nonfinite_pixels: u32,
    /// Host wall time of each stage: particles, visibility network and direct light; the
    /// iteration; the image.
    pub build_ms: f64,
    pub iterate_ms: f64,
    pub image_ms: f64,
}

impl NetworksStats {
    /// What the settings and the particle model decide (counts, windows, opacity, the particles'
    /// and the view's trust, the radius), with nothing run: no network built, no iteration, no
    /// splat. A render fills in what it did.
    fn of_network(scene: &Scene, set: &NetworksSettings, net: &Network) -> NetworksStats {
        NetworksStats {
            particles: set.particles,
            directions: set.directions,
            window: net.window.m,
            opacity: scene.medium.sigma_t.as_dvec3().map(|s| net.alpha(s)).to_array(),
            trust: ParticleTrust::new(scene, &net.particles, set.particles),
            view_trust: set.view.as_ref().map(|v| crate::solvers::parts::view::ViewTrust::of(scene, v)),
            particle_radius: net.particle_radius(),
            network: false,
            iterations: 0,
            converged: true,
            final_change: 0.0,
            splats_dropped: 0,
            nonfinite_pixels: 0,
            build_ms: 0.0,
            iterate_ms: 0.0,
            image_ms: 0.0,
        }
    }
}

/// `networks`' knob values, checked.
#[derive(Clone, Copy, Debug)]
pub struct NetworksSettings {
    pub particles: u32,
    pub directions: u32,
    pub window: Option<u32>,
    pub window_rule: WindowRule,
    pub opacity: Opacity,
    pub tol: f64,
    pub max_iterations: u32,
    pub iterations_per_frame: u32,
    /// The direct light's (and the image's medium transmittance's) march step, scene units.
    pub step: f32,
    /// The splats' footprint width in particle radii.
    pub footprint: f32,
    /// Scale each camera ray's splats to the medium's optical depth along it.
    pub medium_transmittance: bool,
    /// `networks.single = view`: the view pass computes every light's single scattering and
    /// the particles carry the light scattered at least twice; `None`: the particles carry
    /// everything (the paper's image).
    pub view: Option<crate::solvers::parts::view::ViewSettings>,
    /// How an emissive medium's emission enters the network.
    pub emission: EmissionModel,
}

impl NetworksSettings {
    pub fn parse(k: &Knobs, scene: &Scene) -> Result<NetworksSettings, SolverError> {
        let step: f32 = k.get_or("step", crate::solvers::parts::view::ViewSettings::default_step(scene))?;
        let diagonal = (scene.medium.bounds_max - scene.medium.bounds_min).length();
        if diagonal / step > (LOOP_GUARD / 2) as f32 {
            return Err(k.invalid(
                "step",
                format!("{step} takes over {} steps across the medium's diagonal {diagonal}", LOOP_GUARD / 2),
            ));
        }
        Ok(NetworksSettings {
            particles: k.get("particles")?,
            directions: k.get("directions")?,
            window: if k.is_set("window") { Some(k.get("window")?) } else { None },
            window_rule: if k.get::<String>("window_rule")? == "paper" { WindowRule::Paper } else { WindowRule::Fit },
            opacity: if k.get::<String>("opacity")? == "exponential" { Opacity::Exponential } else { Opacity::Linear },
            tol: k.get("tol")?,
            max_iterations: k.get("max_iterations")?,
            iterations_per_frame: k.get("iterations_per_frame")?,
            step,
            footprint: k.get("footprint")?,
            medium_transmittance: k.get::<String>("transmittance")? == "medium",
            emission: if k.get::<String>("emission")? == "particles" {
                EmissionModel::Particles
            } else {
                EmissionModel::Marched
            },
            view: if k.get::<String>("single")? == "view" {
                Some(crate::solvers::parts::view::ViewSettings::parse(k, "view_", scene)?)
            } else {
                None
            },
        })
    }

    /// Environment directions the direct term takes as units (0: the environments are the
    /// network's sky).
    pub fn env_dirs(&self) -> u32 {
        self.view.as_ref().map_or(0, |v| v.env_dirs.max(1))
    }

    /// Device bytes of the view pass (0 without it).
    pub fn view_bytes(&self, scene: &Scene) -> u64 {
        self.view.as_ref().map_or(0, |v| crate::solvers::parts::view::device_bytes(scene, v))
    }

    /// The particle model, directions and windows of these settings for `scene` (its seed).
    pub fn network(&self, scene: &Scene) -> Result<Network, SolverError> {
        let seed = scene.render.seed;
        let particles = Particles::sample(scene, self.particles, seed)?;
        let directions = Directions::new(self.directions, seed);
        let window = Window::new(scene, &particles, &directions, self.window, self.window_rule);
        Ok(Network { particles, directions, window, opacity: self.opacity })
    }

    /// The image's medium-transmittance step (0: the splats' own).
    pub fn image_step(&self) -> f32 {
        if self.medium_transmittance {
            self.step
        } else {
            0.0
        }
    }
}

impl Networks {
    /// The image and report of an [`Illumination`] after its iteration (`c`, in `iterate_ms`
    /// of host wall time; `build_ms` before it).
    /// networks where its particles make none of the image ([`particles_matter`] false: nothing
    /// scatters and the view pass gives the single scattering): no network built, nothing
    /// iterated or splatted. The particles' image there is zero (they carry scattered light
    /// only), so the view's camera-ray march alone is the image, bit for bit. At 16384
    /// particles x 256 directions an absorbing emitter took 6.1 s at 128^2 to splat zeros.
    fn render_unscattered(
        &self,
        gpu: &Gpu,
        scene: &Scene,
        force_full: bool,
        k: &Knobs,
        set: &NetworksSettings,
        net: &Network,
    ) -> Result<RenderOutput, SolverError> {
        let Some(v) = &set.view else {
            return Err(SolverError::Unsupported(
                "networks: the particles make the image (networks.single=particles)".into(),
            ));
        };
        let t = Instant::now();
        let gs = crate::solvers::parts::gpu_scene::GpuScene::upload(gpu, scene, force_full)?;
        let view = crate::solvers::parts::view::march(gpu, scene, &gs, v, None)?;
        let image_ms = t.elapsed().as_secs_f64() * 1e3;
        let detail = NetworksStats { image_ms, ..NetworksStats::of_network(scene, set, net) };
        let view_trust = detail.view_trust;
        let mut stats = Stats::new(detail);
        stats.convergence = Some(Convergence { iterations: 0, converged: true, final_change: 0.0, tolerance: set.tol });
        stats.faults = view.nonfinite_pixels as u64;
        let bytes = gs.bytes + view.device_bytes;
        let mut report = RenderReport::finish(gpu, self, k, gs.modelled.clone(), bytes, stats);
        report.warnings.extend(view_trust.and_then(|v| v.warning(self.name())));
        report.zeroed_nonfinite(view.nonfinite_pixels);
        Ok(RenderOutput { image: view.image, variance: None, report, estimates: Vec::new() })
    }

    #[allow(clippy::too_many_arguments)]
    fn finish(
        &self,
        gpu: &Gpu,
        scene: &Scene,
        force_full: bool,
        k: &Knobs,
        set: &NetworksSettings,
        net: &Network,
        st: &Illumination,
        c: Converged,
        build_ms: f64,
        iterate_ms: f64,
    ) -> Result<RenderOutput, SolverError> {
        let t = Instant::now();
        let mut img = st.image(gpu, net, set.footprint, set.image_step())?;
        let mut view_nonfinite = 0;
        if let Some(v) = &set.view {
            // Every light's single scattering and the background, exactly (the view pass),
            // beside the particles' light scattered at least twice.
            let view = crate::solvers::parts::view::march(gpu, scene, st.scene(), v, None)?;
            view_nonfinite = view.nonfinite_pixels;
            for (a, b) in img.image.data.iter_mut().zip(&view.image.data) {
                *a += *b;
            }
        }
        let image_ms = t.elapsed().as_secs_f64() * 1e3;
        let detail = NetworksStats {
            network: true,
            iterations: c.iterations,
            converged: c.converged,
            final_change: c.change,
            splats_dropped: img.dropped,
            nonfinite_pixels: img.nonfinite,
            build_ms,
            iterate_ms,
            image_ms,
            ..NetworksStats::of_network(scene, set, net)
        };
        let (trust, view_trust) = (detail.trust, detail.view_trust);
        let mut stats = Stats::new(detail);
        stats.convergence = Some(Convergence {
            iterations: c.iterations as u64,
            converged: c.converged,
            final_change: c.change,
            tolerance: set.tol,
        });
        stats.faults = st.faults + img.nonfinite as u64 + view_nonfinite as u64;
        let modelled = crate::solvers::parts::gpu_scene::modelled(scene, force_full);
        let bytes = Illumination::device_bytes(
            net,
            scene,
            force_full,
            set.emission,
            set.env_dirs(),
            set.view_bytes(scene),
            set.footprint,
        );
        let mut report = RenderReport::finish(gpu, self, k, modelled, bytes, stats);
        let iterate_gpu_ms: f64 =
            report.passes.iter().filter(|p| p.name == "networks.iterate").map(|p| p.duration_ms()).sum();
        if c.iterations > 0 && iterate_gpu_ms > 0.0 {
            let updates = set.particles as f64 * set.directions as f64 * c.iterations as f64;
            report.stats.throughput = vec![Figure {
                figure: "network updates/s (particle x direction)".into(),
                value: updates / (iterate_gpu_ms * 1e-3),
                unit: "1/s".into(),
            }];
        }
        // Only a solve that ran out of iterations: an animation frame's fixed iterations after
        // the first are meant to stop short of the tolerance.
        if !c.converged && c.iterations >= set.max_iterations {
            report.warnings.push(format!(
                "networks: the iteration did not converge in {} iterations (change {:.2e} of the largest radiance, \
                 tolerance {:.1e}); raise networks.max_iterations or networks.tol",
                c.iterations, c.change, set.tol
            ));
        }
        if st.faults > 0 {
            report.warnings.push(format!(
                "networks: the iteration went negative or non-finite ({} iterations); the image is of the last state",
                st.faults
            ));
        }
        if img.dropped > 0 {
            report.warnings.push(format!(
                "networks: {} splats were left out where over {MAX_SPLATS} overlapped a pixel (the farthest); use fewer \
                 networks.particles or a smaller networks.footprint",
                img.dropped
            ));
        }
        report.warnings.extend(trust.warning());
        report.warnings.extend(view_trust.and_then(|v| v.warning(self.name())));
        report.zeroed_nonfinite(img.nonfinite + view_nonfinite);
        Ok(RenderOutput { image: img.image, variance: None, report, estimates: Vec::new() })
    }
}

/// A `networks` sequence: the network is built once (the medium does not move); each frame
/// recomputes the direct light and iterates from the previous frame's radiance (paper 4).
struct NetworksAnimation {
    knobs: Knobs,
    set: NetworksSettings,
    net: Network,
    state: Option<Illumination>,
    converge: bool,
    force_full: bool,
}

impl crate::solvers::interface::Animation for NetworksAnimation {
    fn frame(&mut self, gpu: &Gpu, scene: &Scene, progress: &dyn Fn(Progress)) -> Result<RenderOutput, SolverError> {
        let set = self.set;
        if !particles_matter(scene, &set) {
            return Networks.render_unscattered(gpu, scene, self.force_full, &self.knobs, &set, &self.net);
        }
        let t = Instant::now();
        let first = self.state.is_none();
        let st = match &mut self.state {
            Some(st) => {
                st.set_lights(gpu, &self.net, scene)?;
                st
            }
            None => self.state.insert(Illumination::with_emission(
                gpu,
                &self.net,
                scene,
                set.step,
                self.force_full,
                set.env_dirs(),
                set.emission,
            )?),
        };
        let build_ms = t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        let c = if first || self.converge {
            st.solve(gpu, set.tol, set.max_iterations, progress)?
        } else {
            st.step(gpu, set.iterations_per_frame)?;
            Converged { iterations: st.iterations, converged: st.change <= set.tol, change: st.change }
        };
        let iterate_ms = t.elapsed().as_secs_f64() * 1e3;
        Networks.finish(gpu, scene, self.force_full, &self.knobs, &set, &self.net, st, c, build_ms, iterate_ms)
    }
}

/// The most splats a pixel composites (glsl/networks/splat.comp's MAX_SPLATS).
pub const MAX_SPLATS: u32 = 256;

impl Solver for Networks {
    fn name(&self) -> &'static str {
        "networks"
    }

    fn about(&self) -> &'static str {
        "illumination networks over a particle model, iterated on the GPU (Szirmay-Kalos, Sbert, Umenhoffer 2005)"
    }

    fn knobs(&self) -> Vec<Knob> {
        let mut k = vec![
            Knob::fixed(
                "particles",
                "1024",
                Range::int(16, 16384),
                "particles N, drawn in proportion to the density (the paper's 1024-particle cloud)",
            ),
            Knob::fixed(
                "directions",
                "128",
                Range::int(4, 1024),
                "discrete directions D shared by all particles (the paper's 128); an iteration costs N D^2",
            ),
            Knob::derived(
                "window",
                "by networks.window_rule, at least sqrt(N / 64)",
                Range::int(1, MAX_WINDOW as u64),
                "window resolution M (M x M pixels per direction)",
            ),
            Knob::fixed(
                "window_rule",
                "fit",
                Range::Choice(&["fit", "paper"]),
                "fit: the finest M with a particle's optical depth across a pixel at most 0.3 and 8 particles to an \
                 occupied column on average; paper: D (R tau)^2 / pi >= M^2 (3.2) with the same opacity cap",
            ),
            Knob::fixed(
                "tol",
                "1e-4",
                Range::open_unit(),
                "convergence: largest change of the radiance in one iteration, relative to its largest value",
            ),
            Knob::fixed(
                "opacity",
                "linear",
                Range::Choice(&["linear", "exponential"]),
                "a particle's opacity across a window pixel from its optical depth c there: linear min(c, 1), the \
                 medium's expected column transmittance for randomly placed particles; exponential 1 - exp(-c), the \
                 paper's",
            ),
            Knob::fixed("max_iterations", "2000", Range::int(1, 1 << 20), "iterations at most"),
            Knob::fixed(
                "iterations_per_frame",
                "1",
                Range::int(1, 1 << 20),
                "scatterlab animate: iterations per frame after a light move, from the previous frame's solution \
                 (the paper uses 1)",
            ),
            Knob::derived(
                "step",
                "1/128 of the medium's diagonal, at most 1/16 of its thinnest side",
                Range::positive(),
                "transmittance march step (scene units) of the direct light and the image's medium transmittance",
            ),
            Knob::fixed(
                "footprint",
                "1",
                Range::Real { min: 0.1, max: 4.0, min_open: false, max_open: false },
                "splat width in particle radii (Gaussian; cut at three widths)",
            ),
            Knob::fixed(
                "transmittance",
                "medium",
                Range::Choice(&["medium", "splats"]),
                "medium: each camera ray's splats scaled to the medium's optical depth along it (exact \
                 transmittance); splats: the splats' own opacity (the paper's)",
            ),
            Knob::fixed(
                "emission",
                "march",
                Range::Choice(&["march", "particles"]),
                "an emissive medium's emission: march, the emission arriving unscattered at each particle along each \
                 direction marched through the medium (as the direct light is), the network carrying it from its first \
                 scattering on; particles, each particle's own alpha (1 - albedo) Le carried by the columns (the \
                 paper's E)",
            ),
            Knob::fixed(
                "single",
                "view",
                Range::Choice(&["view", "particles"]),
                "view: every light's single scattering by the view pass (exact, as `single`), the particles carrying \
                 the light scattered at least twice; particles: the particles carry all of it, direct term included \
                 (the paper's image)",
            ),
        ];
        k.extend(
            crate::solvers::parts::view::knobs().into_iter().map(|k| k.prefixed("view_").only_with("single=view")),
        );
        k
    }

    /// Emission (issue 47) as a source of the network beside the lights: by default
    /// (`networks.emission = march`) the emission arriving unscattered at each particle along
    /// each direction is marched through the medium (glsl/networks/arrive.comp), as the direct
    /// term is toward the lights, and the network scatters it on; with `particles` each particle
    /// of opacity alpha emits alpha (1 - albedo) Le in every direction (the paper's E_p), carried
    /// by its columns. The image: with `networks.single = view` the view pass adds the emission
    /// along the camera ray exactly and the splats the emitted light scattered at least once;
    /// with `particles` the splats carry both. A scene lit by its emission alone needs no light.
    fn renders_emission(&self) -> bool {
        true
    }

    fn kernels(&self) -> Vec<Kernel> {
        let mut k = kernels();
        k.extend([
            crate::solvers::parts::view::MARCH,
            crate::solvers::parts::view::SHADOW,
            crate::solvers::parts::feedback::COPY,
        ]);
        k
    }

    fn render(&self, gpu: &Gpu, req: &RenderRequest) -> Result<RenderOutput, SolverError> {
        let scene = req.scene;
        let k = req.knobs(self)?;
        let set = NetworksSettings::parse(&k, scene)?;
        k.finish()?;
        let t = Instant::now();
        (req.progress)(Progress::work("network", 0, 1));
        let net = set.network(scene)?;
        if !particles_matter(scene, &set) {
            return self.render_unscattered(gpu, scene, req.force_full, &k, &set, &net);
        }
        let mut st =
            Illumination::with_emission(gpu, &net, scene, set.step, req.force_full, set.env_dirs(), set.emission)?;
        (req.progress)(Progress::work("network", 1, 1));
        let build_ms = t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        let c = st.solve(gpu, set.tol, set.max_iterations, req.progress)?;
        let iterate_ms = t.elapsed().as_secs_f64() * 1e3;
        self.finish(gpu, scene, req.force_full, &k, &set, &net, &st, c, build_ms, iterate_ms)
    }

    fn animation(
        &self,
        req: &RenderRequest,
        converge: bool,
    ) -> Result<Option<Box<dyn crate::solvers::interface::Animation>>, SolverError> {
        let knobs = req.knobs(self)?;
        let set = NetworksSettings::parse(&knobs, req.scene)?;
        knobs.finish()?;
        let net = set.network(req.scene)?;
        Ok(Some(Box::new(NetworksAnimation { knobs, set, net, state: None, converge, force_full: req.force_full })))
    }

    fn memory_estimate(&self, scene: &Scene, knobs: &Knobs) -> Result<u64, SolverError> {
        let set = NetworksSettings::parse(knobs, scene)?;
        if !particles_matter(scene, &set) {
            // No network where the particles make none of the image (render_unscattered).
            return Ok(crate::solvers::parts::gpu_scene::scene_bytes(scene) + set.view_bytes(scene));
        }
        let net = set.network(scene)?;
        Ok(Illumination::device_bytes(
            &net,
            scene,
            false,
            set.emission,
            set.env_dirs(),
            set.view_bytes(scene),
            set.footprint,
        ))
    }

    fn ladder(&self, _scene: &Scene) -> Vec<Rung> {
        // Particles and directions grow together (an iteration costs N D^2), then each alone
        // past the paper's setting (1024 x 128, the third rung).
        [(256u32, 32u32), (1024, 64), (1024, 128), (4096, 128), (1024, 512), (16384, 128)]
            .iter()
            .map(|(n, d)| Rung {
                knob: "networks.particles".into(),
                value: format!("{n}/{d}"),
                sets: vec![("networks.particles".into(), n.to_string()), ("networks.directions".into(), d.to_string())],
            })
            .collect()
    }

    fn stability(&self) -> Vec<Variant> {
        vec![Variant::new(
            "",
            &[("networks.particles", "256"), ("networks.directions", "32"), ("networks.view_env_dirs", "16")],
        )]
    }

    fn headline(&self, quick: bool) -> Option<Headline> {
        let (n, d, size) = if quick { ("256", "32", "64") } else { ("1024", "128", "512") };
        Some(Headline::new(
            format!("networks cloud {n} particles x {d} directions, {size}^2"),
            "cloud.toml",
            &[("render.width", size), ("render.height", size), ("networks.particles", n), ("networks.directions", d)],
            if quick { "" } else { "networks paper: 1024 particles x 128 directions at 26 fps (NV6800GT, 2005)" },
        ))
    }

    fn preflight(&self, scene: &Scene, knobs: &Knobs) -> Result<Vec<String>, SolverError> {
        // The density's lattice alone: the particles themselves are drawn by the render.
        let set = NetworksSettings::parse(knobs, scene)?;
        let particles =
            ParticleTrust::of(scene, knobs.get("particles")?).warning().filter(|_| particles_matter(scene, &set));
        let view =
            set.view.as_ref().and_then(|v| crate::solvers::parts::view::ViewTrust::of(scene, v).warning(self.name()));
        Ok(particles.into_iter().chain(view).collect())
    }

    fn summary(&self, report: &RenderReport) -> Vec<String> {
        let Some(s) = report.detail::<NetworksStats>() else { return Vec::new() };
        let trust = format!("networks: {}", s.trust.line());
        let view = s.view_trust.map(|v| format!("networks: {}", v.line()));
        if !s.network {
            let line = "networks: nothing scatters (sigma_s 0 in every channel and material): no network built, the \
                        image is the view's camera-ray march";
            return std::iter::once(line.to_string()).chain(view).collect();
        }
        let mut lines = vec![
            format!(
            "networks: {} particles x {} directions, {}x{} windows (particle opacity {:.2}), {} iterations ({}, change \
             {:.1e}); network {:.0} ms, iteration {:.0} ms, image {:.0} ms",
            s.particles,
            s.directions,
            s.window,
            s.window,
            s.opacity.iter().fold(0.0f64, |a, b| a.max(*b)),
            s.iterations,
            if s.converged { "converged" } else { "NOT converged" },
            s.final_change,
            s.build_ms,
            s.iterate_ms,
            s.image_ms
        ),
            trust,
        ];
        lines.extend(view);
        lines
    }
}

/// Whether the particles make any of the image, so that their trust line applies: where
/// something scatters (the network carries it), or where the particles' splats make the image
/// (`networks.single = particles`: they composite the emission and the transmittance). With the
/// view pass and nothing scattering (`Scene::scatters`) the image is the camera ray's march,
/// exact, and the particles' spacing says nothing of it.
fn particles_matter(scene: &Scene, set: &NetworksSettings) -> bool {
    scene.scatters() || set.view.is_none()
}
