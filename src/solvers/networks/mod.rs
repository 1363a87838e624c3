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
pub const ITERATE: Kernel =
    Kernel { shader: shader!("networks/iterate"), push_bytes: std::mem::size_of::<IteratePush>(), spec: &[] };
pub const GATHER: Kernel = Kernel {
    shader: shader!("networks/gather"),
    push_bytes: std::mem::size_of::<GatherPush>(),
    spec: crate::solvers::parts::gpu_scene::SCENE_SPEC,
};
pub const SPLAT: Kernel = Kernel {
    shader: shader!("networks/splat"),
    push_bytes: std::mem::size_of::<SplatPush>(),
    spec: crate::solvers::parts::gpu_scene::VIEW_SPEC,
};

/// Every kernel of this part.
pub fn kernels() -> Vec<Kernel> {
    vec![COUNT, FILL, LINK, DIRECT, ITERATE, GATHER, SPLAT]
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct GatherPush {
    particles: u32,
    directions: u32,
    units: u32,
    direct: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct SplatPush {
    sigma_m: [f32; 4],
    sky: [f32; 4],
    width: f32,
    particles: u32,
    /// Positive: each camera ray's splats scaled to the medium's optical depth along it, marched
    /// in steps of this (scene units); 0: the splats' own transmittance (the paper's).
    step: f32,
    pad: u32,
}

/// The image of the splats: pixels, and how many splats were left out where more than a
/// pixel holds overlapped it (the farthest go).
pub struct Splatted {
    pub image: crate::output::Image,
    pub dropped: u64,
    /// Pixels that came out non-finite and were set to 0.
    pub nonfinite: u32,
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
    albedo: [f32; 4],
    sky: [f32; 4],
    particles: u32,
    directions: u32,
    units: u32,
    slot: u32,
    /// 1: judge the previous slot against `tol` first (glsl/networks/iterate.comp).
    check: u32,
    tol: f32,
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

/// The sky's radiance: the environments' summed (W/(m^2 sr)).
pub fn sky(scene: &Scene) -> Vec3 {
    scene
        .lights
        .iter()
        .map(|l| match l {
            Light::Environment { radiance } => *radiance,
            _ => Vec3::ZERO,
        })
        .sum()
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

/// The direct term's light at one particle from one light unit: irradiance (per channel,
/// through the medium) and the light's direction of travel there.
#[derive(Clone, Copy, Debug)]
pub struct DirectLight {
    pub irradiance: [f64; 3],
    pub travel: Vec3,
}

/// No particle upstream: the sky is seen (V's value).
pub const NONE: u32 = u32::MAX;

/// The largest window resolution M (D M^2 buckets of three u32 each).
pub const MAX_WINDOW: u32 = 2048;

/// The most optical depth one particle holds across a window pixel, sigma_t m / A, where M is
/// left to [`Window::new`] (opacity 1 - e^-0.3 = 0.26).
pub const OPACITY_DEPTH: f64 = 0.3;

/// The most particles one window column may hold: link.comp sorts a column in one invocation,
/// k (k - 1) / 2 + 2k loop iterations, kept under the loop guard of glsl/include/budget.glsl.
pub const MAX_COLUMN: u32 = 340;
const _: () = assert!(MAX_COLUMN * (MAX_COLUMN - 1) / 2 + 2 * MAX_COLUMN <= LOOP_GUARD);

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct NetworkPush {
    centre_radius: [f32; 4],
    inv_pixel: f32,
    m: u32,
    particles: u32,
    directions: u32,
}

/// The particle model of the medium (paper 2.1).
#[derive(Clone, Debug)]
pub struct Particles {
    pub positions: Vec<Vec3>,
    /// Each particle's share of the integral of the density over the medium (scene units^3):
    /// times sigma_t, its extinction cross-section.
    pub mass: f64,
    /// The volume where the density is non-zero (scene units^3), estimated on the same lattice
    /// as the integral.
    pub occupied: f64,
}

impl Particles {
    /// `n` particles drawn with probability proportional to the density, by rejection from the
    /// medium's bounds (a stream of the scene's seed: deterministic). The density's integral is
    /// the midpoint rule on a 96^3 lattice of the bounds.
    pub fn sample(scene: &Scene, n: u32, seed: u64) -> Result<Particles, SolverError> {
        let m = &scene.medium;
        let (lo, size) = (m.bounds_min, m.bounds_max - m.bounds_min);
        const LATTICE: u32 = 96;
        let (mut sum, mut occupied) = (0f64, 0u64);
        for z in 0..LATTICE {
            for y in 0..LATTICE {
                for x in 0..LATTICE {
                    let u = (Vec3::new(x as f32, y as f32, z as f32) + 0.5) / LATTICE as f32;
                    let d = scene.density_at(lo + u * size) as f64;
                    sum += d;
                    occupied += (d > 0.0) as u64;
                }
            }
        }
        let cells = (LATTICE as f64).powi(3);
        let volume = size.x as f64 * size.y as f64 * size.z as f64;
        let integral = sum / cells * volume;
        let max = scene.max_density();
        if integral.is_nan() || integral <= 0.0 || max.is_nan() || max <= 0.0 {
            return Err(SolverError::Unsupported(
                "networks: the medium has no density to place particles in".to_string(),
            ));
        }
        let mut rng = Pcg32::new(seed, 0x6e65_7477);
        let mut positions = Vec::with_capacity(n as usize);
        // Rejection: a box point is kept with probability density / max. The expected number
        // of trials is n max V / integral; a medium that sparse (under one kept point in a
        // million) is refused rather than looped on.
        let limit = (n as u64).saturating_mul(1_000_000).max(1_000_000);
        let mut trials = 0u64;
        while positions.len() < n as usize {
            trials += 1;
            if trials > limit {
                return Err(SolverError::Unsupported(format!(
                    "networks: under one point in a million of the medium's bounds has density; \
                     tighten medium.bounds around it (kept {} of {n} particles)",
                    positions.len()
                )));
            }
            let p = lo + Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * size;
            if rng.next_f32() * max < scene.density_at(p) {
                positions.push(p);
            }
        }
        Ok(Particles { positions, mass: integral / n as f64, occupied: occupied as f64 / cells * volume })
    }
}

/// D directions of travel, uniform on the sphere, each with its window's axes.
#[derive(Clone, Debug)]
pub struct Directions {
    /// (u, v, w): the window's axes and the direction of travel w, orthonormal.
    pub frames: Vec<[Vec3; 3]>,
}

impl Directions {
    /// A Fibonacci lattice of `d` points (equal areas) turned by a random rotation of `seed`.
    pub fn new(d: u32, seed: u64) -> Directions {
        let mut rng = Pcg32::new(seed, 0x6469_7273);
        // A uniform random rotation (Shoemake's quaternion from three uniforms).
        let (u1, u2, u3) = (rng.next_f64(), rng.next_f64(), rng.next_f64());
        let tau = std::f64::consts::TAU;
        let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
        let q = glam::DQuat::from_xyzw(
            a * (tau * u2).sin(),
            a * (tau * u2).cos(),
            b * (tau * u3).sin(),
            b * (tau * u3).cos(),
        )
        .normalize();
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let frames = (0..d)
            .map(|k| {
                let z = 1.0 - (2.0 * k as f64 + 1.0) / d as f64;
                let r = (1.0 - z * z).max(0.0).sqrt();
                let phi = golden * k as f64;
                let w = q * glam::DVec3::new(r * phi.cos(), r * phi.sin(), z);
                // Any orthonormal pair across w (Duff et al. 2017's branchless basis).
                let s = 1f64.copysign(w.z);
                let aa = -1.0 / (s + w.z);
                let bb = w.x * w.y * aa;
                let u = glam::DVec3::new(1.0 + s * w.x * w.x * aa, s * bb, -s * w.x);
                let v = glam::DVec3::new(bb, s + w.y * w.y * aa, -w.y);
                [u.as_vec3(), v.as_vec3(), w.as_vec3()]
            })
            .collect();
        Directions { frames }
    }

    pub fn len(&self) -> usize {
        self.frames.len()
    }

    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }
}

/// The windows' geometry: the bounding sphere and the resolution.
#[derive(Clone, Copy, Debug)]
pub struct Window {
    pub centre: Vec3,
    pub radius: f32,
    /// M: pixels along each side.
    pub m: u32,
}

/// How M is chosen where `networks.window` is not set.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WindowRule {
    /// The finest M at which a particle's optical depth across a pixel stays at most
    /// [`OPACITY_DEPTH`] and the window's occupied columns hold [`COLUMN_PARTICLES`] particles
    /// on average (the default; docs/networks.md).
    Fit,
    /// The paper's rule (3.2), D (R tau)^2 / pi >= M^2, with the same opacity cap.
    Paper,
}

/// The mean number of particles in an occupied window column that [`WindowRule::Fit`] keeps.
pub const COLUMN_PARTICLES: f64 = 8.0;

impl Window {
    /// The bounding sphere of the medium's bounds, and M set, or chosen by `rule`, at least
    /// sqrt(N / 64) (so a thin medium's columns stay sortable) and at most [`MAX_WINDOW`].
    pub fn new(
        scene: &Scene,
        particles: &Particles,
        directions: &Directions,
        m: Option<u32>,
        rule: WindowRule,
    ) -> Window {
        let med = &scene.medium;
        let centre = (med.bounds_min + med.bounds_max) * 0.5;
        let radius = (med.bounds_max - med.bounds_min).length() * 0.5;
        let m = m.unwrap_or_else(|| {
            let n = particles.positions.len() as f64;
            // The particles' opacity bounds M from above. Every particle has the same,
            // 1 - exp(-sigma_t m / A): on a fine window few particles share a column, each nearly
            // opaque, and light leaks through the columns that happen to hold none (the
            // expected transmittance of a column is then about exp(-count), not exp(-optical
            // depth)). Measured on the sphere (1024 particles, D 128, against path): M 55
            // (alpha 0.98) energy 0.836, bias 0.340; M 32 (alpha 0.72) 0.903 / 0.257; M 16
            // (alpha 0.27) 0.951 / 0.205; M 8 (0.08) 0.949 / 0.205. So M keeps
            // sigma_t m / A <= OPACITY_DEPTH (alpha <= 0.26) in the most opaque channel.
            let sigma_max = med.sigma_t.max_element() as f64;
            let opacity = 2.0 * radius as f64 / (sigma_max * particles.mass / OPACITY_DEPTH).sqrt();
            let upper = match rule {
                // The paper's rule (an upper bound: a pixel seen from a mean free path away
                // subtends at least a direction's solid angle), tau the mean extinction where
                // the density is non-zero.
                WindowRule::Paper => {
                    let sigma = med.sigma_t.dot(Vec3::ONE) as f64 / 3.0;
                    let tau = sigma * particles.mass * n / particles.occupied.max(f64::MIN_POSITIVE);
                    ((directions.len() as f64 / std::f64::consts::PI).sqrt() * radius as f64 * tau).min(opacity)
                }
                // Coarse columns dilute: a particle's cross-section is spread over its whole
                // pixel, the empty part beside the medium included, so light crosses a column
                // more easily than the medium and the network loses multiple scattering. In a
                // thin medium the paper's rule asks for coarse windows (a unit cube of optical
                // thickness 1, albedo 0.99, 512 particles, D 64: M 3, energy 0.882, bias 0.122
                // against path); with about 8 particles to an occupied column (M 10) 0.976 /
                // 0.048, with 4 (M 16) 0.965 / 0.054.
                // The mean falls as M grows: bisect for the largest M that keeps it.
                WindowRule::Fit => {
                    let full =
                        |m: u32| Window { centre, radius, m }.mean_column(particles, directions) >= COLUMN_PARTICLES;
                    let (mut lo, mut hi) = (1u32, opacity.floor().clamp(1.0, MAX_WINDOW as f64) as u32);
                    if full(hi) {
                        lo = hi;
                    }
                    while hi - lo > 1 {
                        let mid = (lo + hi) / 2;
                        if full(mid) {
                            lo = mid;
                        } else {
                            hi = mid;
                        }
                    }
                    lo as f64
                }
            };
            // Not coarser than 64 particles a pixel on average over the window: a column
            // sorted by one invocation holds at most MAX_COLUMN particles.
            let crowding = (n / 64.0).sqrt().ceil();
            upper.floor().max(crowding).clamp(1.0, MAX_WINDOW as f64) as u32
        });
        Window { centre, radius, m: m.clamp(1, MAX_WINDOW) }
    }

    /// The mean number of particles in an occupied column of this window, over up to eight of
    /// the directions (evenly spaced in the list).
    pub fn mean_column(&self, particles: &Particles, directions: &Directions) -> f64 {
        let d = directions.len().max(1);
        let picks: Vec<usize> = (0..d.min(8)).map(|k| k * d / d.min(8)).collect();
        let mut occupied = 0usize;
        for &k in &picks {
            let mut keys: Vec<u32> =
                particles.positions.iter().map(|x| self.key(*x, &directions.frames[k]).0).collect();
            keys.sort_unstable();
            keys.dedup();
            occupied += keys.len();
        }
        particles.positions.len() as f64 * picks.len() as f64 / occupied.max(1) as f64
    }

    /// Pixels per scene unit: M / (2R), as the kernels take it.
    pub fn inv_pixel(&self) -> f32 {
        self.m as f32 / (2.0 * self.radius)
    }

    /// A pixel's area (scene units^2): the opacities' denominator.
    pub fn pixel_area(&self) -> f64 {
        let edge = 2.0 * self.radius as f64 / self.m as f64;
        edge * edge
    }

    /// Where `x` falls on the window of `frame` (pixel y M + x) and its depth along the
    /// direction of travel: glsl/networks/project.glsl's arithmetic, operation for operation
    /// (no fused multiply-adds), so host and device agree to the bit.
    pub fn key(&self, x: Vec3, frame: &[Vec3; 3]) -> (u32, f32) {
        let rel = [x.x - self.centre.x, x.y - self.centre.y, x.z - self.centre.z];
        let dot = |a: Vec3| rel[0] * a.x + rel[1] * a.y + rel[2] * a.z;
        let (a, b, d) = (dot(frame[0]), dot(frame[1]), dot(frame[2]));
        let inv = self.inv_pixel();
        let last = self.m as i32 - 1;
        let px = (((a + self.radius) * inv).floor() as i32).clamp(0, last);
        let py = (((b + self.radius) * inv).floor() as i32).clamp(0, last);
        (py as u32 * self.m + px as u32, d)
    }
}

/// A particle model with its directions and windows: what the networks are built over.
pub struct Network {
    pub particles: Particles,
    pub directions: Directions,
    pub window: Window,
    pub opacity: Opacity,
}

/// A particle's opacity across a window pixel, from its optical depth there c = sigma_t m / A.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Opacity {
    /// alpha = min(c, 1) (the default). The particles fall at random, so the number k in a
    /// stretch of column is Poisson with mean lambda, and the column lets through
    /// E[(1 - alpha)^k] = exp(-lambda alpha): with alpha = c that is exp(-lambda c), the medium's
    /// transmittance over the stretch, and a particle intercepts sigma_t m of the light, its
    /// cross-section. With the paper's alpha, each particle holds 1 - e^-c < c: the columns leak
    /// (at the window's cap c = 0.3, 13% of the optical depth) and the network loses multiply
    /// scattered light. 64 x 64 against path (1024 particles, D 128; bias / energy): cloud
    /// 0.109 / 0.951 -> 0.063 / 1.008, sphere 0.158 / 0.910 -> 0.112 / 0.943, anisotropic cube
    /// 0.081 / 0.944 -> 0.054 / 1.001.
    Linear,
    /// alpha = 1 - exp(-c), the paper's (2.1).
    Exponential,
}

impl Network {
    /// The particles' positions (vec4 each) and the directions' frames (u, v, w as three vec4
    /// each) on the device, as every networks kernel reads them.
    fn upload(&self, gpu: &Gpu) -> Result<(Buffer, Buffer), SolverError> {
        let positions: Vec<[f32; 4]> = self.particles.positions.iter().map(|p| [p.x, p.y, p.z, 0.0]).collect();
        let frames: Vec<[f32; 4]> =
            self.directions.frames.iter().flat_map(|f| f.map(|a| [a.x, a.y, a.z, 0.0])).collect();
        Ok((gpu.buffer_with("networks particles", &positions)?, gpu.buffer_with("networks directions", &frames)?))
    }

    /// Opacity of a particle across one window pixel for extinction `sigma_t` (1/unit), by
    /// [`Network::opacity`]'s model: min(c, 1) or 1 - exp(-c), c = sigma_t m / A.
    pub fn alpha(&self, sigma_t: f64) -> f64 {
        let c = sigma_t * self.particles.mass / self.window.pixel_area();
        match self.opacity {
            Opacity::Linear => c.min(1.0),
            Opacity::Exponential => -(-c).exp_m1(),
        }
    }

    /// The visibility network on the host ([p][i], [`NONE`] where the sky is seen): each
    /// direction's window columns sorted by (depth, index), each particle linked to the one
    /// before it. The oracle of [`Network::visibility`].
    pub fn visibility_cpu(&self) -> Vec<u32> {
        let n = self.particles.positions.len();
        let d = self.directions.len();
        let mut v = vec![NONE; n * d];
        let pixels = (self.window.m * self.window.m) as usize;
        for (i, frame) in self.directions.frames.iter().enumerate() {
            let keys: Vec<(u32, f32)> = self.particles.positions.iter().map(|x| self.window.key(*x, frame)).collect();
            let mut buckets: Vec<Vec<u32>> = vec![Vec::new(); pixels];
            for (p, k) in keys.iter().enumerate() {
                buckets[k.0 as usize].push(p as u32);
            }
            for b in &mut buckets {
                b.sort_by(|p, q| {
                    let (dp, dq) = (keys[*p as usize].1, keys[*q as usize].1);
                    dp.partial_cmp(&dq).expect("finite depths").then(p.cmp(q))
                });
                for w in b.windows(2) {
                    v[w[1] as usize * d + i] = w[0];
                }
            }
        }
        v
    }

    /// The visibility network built on the device ([p][i], [`NONE`] where the sky is seen):
    /// count, prefix sum (on the host, between two submissions), fill, link.
    pub fn visibility(&self, gpu: &Gpu) -> Result<Vec<u32>, SolverError> {
        let (positions, dirs) = self.upload(gpu)?;
        Ok(gpu.read_buffer_as(&self.visibility_on(gpu, &positions, &dirs)?)?)
    }

    /// [`Network::visibility`] left on the device, over uploaded positions and directions
    /// ([`Network::upload`]); the bucket buffers are freed on return.
    fn visibility_on(&self, gpu: &Gpu, positions: &Buffer, dirs: &Buffer) -> Result<Buffer, SolverError> {
        let n = self.particles.positions.len() as u32;
        let d = self.directions.len() as u32;
        let buckets = d as u64 * (self.window.m as u64).pow(2);
        let push = NetworkPush {
            centre_radius: [self.window.centre.x, self.window.centre.y, self.window.centre.z, self.window.radius],
            inv_pixel: self.window.inv_pixel(),
            m: self.window.m,
            particles: n,
            directions: d,
        };
        let counts = gpu.buffer("networks bucket counts", buckets * 4)?;
        let offsets = gpu.buffer("networks bucket offsets", buckets * 4)?;
        let cursor = gpu.buffer("networks bucket cursors", buckets * 4)?;
        let entries = gpu.buffer("networks bucket entries", n as u64 * d as u64 * 4)?;
        let visible = gpu.buffer("networks visibility", n as u64 * d as u64 * 4)?;
        let count = gpu.pipeline(&COUNT, &[])?;
        let fill = gpu.pipeline(&FILL, &[])?;
        let link = gpu.pipeline(&LINK, &[])?;
        let pass = Pass::new("networks.count", QueueRole::Trace, &count)
            .read(0, positions)
            .read(1, dirs)
            .read_write(2, &counts)
            .push(&push)
            .cover([n, d, 1]);
        let point = gpu.submit(QueueRole::Trace, &[pass], &[])?;
        gpu.wait(point)?;
        // The buckets' offsets: an exclusive prefix sum of the counts (D M^2 of them; on the
        // host between the passes, a few milliseconds at the paper's sizes).
        let c: Vec<u32> = gpu.read_buffer_as(&counts)?;
        // link.comp's loops for a bucket of k particles: the insertion sort's k (k - 1) / 2 moves
        // at most, and 2k for its outer loop and the links. llvmpipe ends every loop of an
        // invocation silently after 65535 iterations (glsl/include/budget.glsl), so a bucket
        // that could reach that is refused before it runs: at most MAX_COLUMN particles.
        let crowded = c.iter().copied().max().unwrap_or(0);
        if crowded > MAX_COLUMN {
            return Err(SolverError::Unsupported(format!(
                "networks: a window column holds {crowded} particles, more than one sort takes ({MAX_COLUMN}); \
                 set a finer networks.window (M = {} now) or fewer networks.particles",
                self.window.m
            )));
        }
        let mut sum = 0u32;
        let o: Vec<u32> = c
            .iter()
            .map(|x| {
                let s = sum;
                sum += x;
                s
            })
            .collect();
        gpu.write_buffer(&offsets, 0, bytemuck::cast_slice(&o))?;
        let passes = [
            Pass::new("networks.fill", QueueRole::Trace, &fill)
                .read(0, positions)
                .read(1, dirs)
                .read(2, &offsets)
                .read_write(3, &cursor)
                .write(4, &entries)
                .push(&push)
                .cover([n, d, 1]),
            Pass::new("networks.link", QueueRole::Trace, &link)
                .read(0, positions)
                .read(1, dirs)
                .read(2, &counts)
                .read(3, &offsets)
                .read_write(4, &entries)
                .write(5, &visible)
                .push(&push)
                .cover([buckets as u32, 1, 1]),
        ];
        let point = gpu.submit(QueueRole::Trace, &passes, &[])?;
        gpu.wait(point)?;
        Ok(visible)
    }

    /// Device bytes the visibility network's construction holds besides the network itself:
    /// three u32 per bucket (counts, offsets, cursors) and the bucket entries, one u32 per
    /// particle and direction.
    pub fn build_bytes(&self) -> u64 {
        let (n, d) = (self.particles.positions.len() as u64, self.directions.len() as u64);
        3 * 4 * d * (self.window.m as u64).pow(2) + 4 * n * d
    }
}

impl Network {
    /// A particle's radius b: the ball of its share of the occupied volume, (3 V / 4 pi N)^(1/3).
    pub fn particle_radius(&self) -> f64 {
        let n = self.particles.positions.len().max(1) as f64;
        (3.0 * self.particles.occupied / (4.0 * std::f64::consts::PI * n)).cbrt()
    }

    /// The least squared distance a point light is taken at: b^2 / 3, where the mean of
    /// 1 / r^2 over the particle's ball (3 / b^2) stands for a light inside it.
    pub fn min_r2(&self) -> f64 {
        self.particle_radius().powi(2) / 3.0
    }

    /// The direct term's light on the device (glsl/networks/direct.comp), [p][unit] as two vec4:
    /// (irradiance rgb through the medium, the march's loop count), (direction of travel, 0).
    /// `step`: the transmittance's midpoint step (scene units); `env_dirs`: directions per
    /// environment as units ([`unit_count`]; 0: none).
    #[allow(clippy::too_many_arguments)]
    pub fn direct(
        &self,
        gpu: &Gpu,
        scene: &Scene,
        gs: &GpuScene,
        positions: &Buffer,
        step: f32,
        env_dirs: u32,
        out: &Buffer,
    ) -> Result<(), SolverError> {
        let n = self.particles.positions.len() as u32;
        let units = unit_count(scene, env_dirs);
        if units > 0 {
            // The march's steps: at most the bounds' diagonal over `step`, kept under the
            // per-invocation loop guard (glsl/include/budget.glsl).
            let diagonal = (scene.medium.bounds_max - scene.medium.bounds_min).length();
            let steps = (diagonal / step).ceil() as u64 + scene.lights.len() as u64;
            if steps > LOOP_GUARD as u64 {
                return Err(SolverError::Unsupported(format!(
                    "networks: the transmittance step {step} takes {steps} steps across the medium; at most {LOOP_GUARD}"
                )));
            }
            let pipeline = gpu.pipeline(&DIRECT, &gs.modelled.view_spec())?;
            let pass = gs
                .bind(Pass::new("networks.direct", QueueRole::Trace, &pipeline))
                .read(3, positions)
                .write(4, out)
                .push(&DirectPush { step, min_r2: self.min_r2() as f32, particles: n, units, env_dirs, pad: [0; 3] })
                .cover([n, units, 1]);
            let point = gpu.submit(QueueRole::Trace, &[pass], &[])?;
            gpu.wait(point)?;
        }
        Ok(())
    }

    /// Bytes of the direct light buffer: two vec4 per particle and light unit.
    pub fn direct_bytes(&self, scene: &Scene, env_dirs: u32) -> u64 {
        32 * self.particles.positions.len().max(1) as u64 * unit_count(scene, env_dirs).max(1) as u64
    }

    /// The direct term's light on the host ([p][unit]), in double precision with the same
    /// midpoint rule: the oracle of [`Network::direct`].
    pub fn direct_cpu(&self, scene: &Scene, step: f64) -> Vec<DirectLight> {
        let units = light_units(scene);
        let sigma = scene.medium.sigma_t.as_dvec3();
        let min_r2 = self.min_r2();
        let mut out = Vec::with_capacity(self.particles.positions.len() * units.len());
        for x in &self.particles.positions {
            for l in &units {
                let (wi, dist, irradiance) = match **l {
                    Light::Point { position, intensity } => {
                        let to = (position - *x).as_dvec3();
                        let r2 = to.length_squared();
                        let d = r2.sqrt();
                        let wi = if d > 0.0 { to / d } else { glam::DVec3::Z };
                        (wi, d, intensity.as_dvec3() / r2.max(min_r2))
                    }
                    Light::Directional { direction, irradiance } => {
                        (-direction.as_dvec3(), f64::INFINITY, irradiance.as_dvec3())
                    }
                    Light::Environment { .. } => unreachable!("not a unit"),
                };
                let depth = density_depth(scene, x.as_dvec3(), wi, dist, step);
                let t = (-sigma * depth).exp();
                let e = irradiance * t;
                out.push(DirectLight { irradiance: e.to_array(), travel: (-wi).as_vec3() });
            }
        }
        out
    }

    /// `iterations` steps of the network's iteration on the device (glsl/networks/iterate.comp)
    /// from I = 0, over the device's visibility network: I [p][i] rgb.
    pub fn iterate(&self, gpu: &Gpu, scene: &Scene, iterations: u32, step: f32) -> Result<Vec<[f32; 4]>, SolverError> {
        let mut state = Illumination::new(gpu, self, scene, step, true, 0)?;
        state.step(gpu, iterations)?;
        state.radiance(gpu)
    }

    /// The same iteration on the host in double precision: the oracle of
    /// [`Network::iterate`].
    pub fn iterate_cpu(
        &self,
        scene: &Scene,
        visible: &[u32],
        direct: &[DirectLight],
        iterations: u32,
    ) -> Vec<[f64; 3]> {
        let n = self.particles.positions.len();
        let d = self.directions.len();
        let units = light_units(scene).len();
        let m = &scene.medium;
        let alpha = m.sigma_t.as_dvec3().map(|s| self.alpha(s));
        let albedo = m.albedo.as_dvec3();
        let g = m.g as f64;
        let sky = sky(scene).as_dvec3();
        let w: Vec<glam::DVec3> = self.directions.frames.iter().map(|f| f[2].as_dvec3()).collect();
        let phase = phase_matrix(&self.directions, g).0;
        let mut cur = vec![glam::DVec3::ZERO; n * d];
        for _ in 0..iterations {
            let mut next = vec![glam::DVec3::ZERO; n * d];
            for p in 0..n {
                for i in 0..d {
                    let vp = visible[p * d + i];
                    if vp == NONE {
                        next[p * d + i] = sky;
                        continue;
                    }
                    let vp = vp as usize;
                    let mut lit = glam::DVec3::ZERO;
                    for j in 0..units {
                        let e = direct[vp * units + j];
                        lit += glam::DVec3::from_array(e.irradiance) * hg(g, e.travel.as_dvec3().dot(w[i]));
                    }
                    let mut scattered = glam::DVec3::ZERO;
                    for k in 0..d {
                        scattered += cur[vp * d + k] * phase[k * d + i] as f64;
                    }
                    next[p * d + i] = (1.0 - alpha) * cur[vp * d + i] + alpha * albedo * (lit + scattered);
                }
            }
            cur = next;
        }
        cur.into_iter().map(|v| v.to_array()).collect()
    }
}

/// The density's integral from `x` along `w` over [0, t_far] inside the medium's support, by
/// the midpoint rule in steps of at most `step` (glsl/include/view.glsl's density_depth).
fn density_depth(scene: &Scene, x: glam::DVec3, w: glam::DVec3, t_far: f64, step: f64) -> f64 {
    let m = &scene.medium;
    let (xf, wf) = (x.as_vec3(), w.as_vec3());
    // The support: the box, and the sphere for sphere density (view.glsl's medium_interval).
    let Some((mut a, mut b)) = ray_box(xf, wf, m.bounds_min, m.bounds_max) else { return 0.0 };
    if let crate::scene::Density::Sphere { center, radius } = m.density {
        let Some((s0, s1)) = ray_sphere(xf, wf, center, radius) else { return 0.0 };
        (a, b) = (a.max(s0), b.min(s1));
    }
    let (a, b) = (a as f64, b as f64);
    let (a, b) = (a.max(0.0), b.min(t_far));
    if a >= b {
        return 0.0;
    }
    let len = b - a;
    let k = (len / step).ceil().max(1.0);
    let dt = len / k;
    (0..k as u64).map(|i| scene.density_at((x + w * (a + (i as f64 + 0.5) * dt)).as_vec3()) as f64).sum::<f64>() * dt
}

/// Fewest iterations per submission; each writes its change and peak into its own slot of
/// the stats buffer, read once per submission (so the host waits at most once per 8).
pub const BATCH: u32 = 8;
/// Most iterations per submission: where an iteration takes less than
/// [`BATCH_TARGET_MS`] / [`BATCH`], batches grow toward that much GPU work (a GPU runs an
/// iteration of the default network in about a millisecond: a batch of 8 left it waiting for
/// the host between batches).
pub const BATCH_MAX: u32 = 64;
/// The GPU work a submission aims at, milliseconds (issue 42: 5-20 ms).
pub const BATCH_TARGET_MS: f64 = 12.0;
/// Words of the stats buffer: verdict, dispatches run, then two per slot.
const STATS_WORDS: u64 = 2 + 2 * BATCH_MAX as u64;

/// How an iteration is judged ([`Illumination::solve`]; glsl/networks/iterate.comp's
/// `verdict` is the same rule in the same f32 arithmetic, so host and device agree bit for
/// bit): a negative or non-finite largest change or largest I is a fault; else converged where
/// the change is at most `tol` times the largest I (or nothing is lit).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    GoOn,
    Converged,
    Fault,
}

pub fn verdict(change: f32, peak: f32, tol: f32) -> Verdict {
    let bad = |x: f32| !x.is_finite() || x < 0.0;
    if bad(change) || bad(peak) {
        Verdict::Fault
    } else if peak <= 0.0 || change <= tol * peak {
        Verdict::Converged
    } else {
        Verdict::GoOn
    }
}

/// What one submitted batch of iterations did ([`Illumination::batch`]).
struct BatchRun {
    /// Per iteration that ran: its change relative to the largest I (NaN at a fault).
    changes: Vec<f64>,
    /// The verdict that stopped the batch on the device, if one did.
    stopped: Option<Verdict>,
}

/// The illumination network on the device, ready to iterate: the scene, particles, directions,
/// visibility network, phase matrix, direct light and the two radiance buffers (ping-pong).
/// It outlives a light's move: [`Illumination::set_lights`] recomputes the direct light and
/// keeps I, the paper's warm start (4: "we take the solution of the previous light position
/// as the initial value").
pub struct Illumination {
    gs: GpuScene,
    positions: Buffer,
    dirs: Buffer,
    visible: Buffer,
    phase: Buffer,
    direct: Buffer,
    field: [Buffer; 2],
    /// Per iteration of a submission: the largest change of I and the largest I (f32 bits),
    /// after the verdict and the count of iterations run (a device record and its host copy).
    stats: crate::solvers::parts::feedback::Feedback,
    /// Which of `field` holds the current I.
    current: usize,
    pipeline: crate::gpu::Pipeline,
    push: IteratePush,
    step: f32,
    /// Iterations the next batch submits (adapted to the measured iteration time).
    batch: u32,
    /// The image's size and a particle's extinction cross-section sigma_t m (rgb, units^2).
    size: [u32; 2],
    /// The camera's origin and, for an orthographic one, its axis: the splats' order.
    camera: (Vec3, Option<Vec3>),
    sigma_m: Vec3,
    /// Iterations run since the start (or the last light move).
    pub iterations: u32,
    /// Environment directions taken as direct units (`networks.single = view`), 0 where the
    /// environments are the network's sky.
    env_dirs: u32,
    /// The last iteration's change of I against I's largest value (infinite before one ran).
    pub change: f64,
    /// Iterations whose change or peak came back negative or not finite.
    pub faults: u64,
}

/// How an iteration to a tolerance ended.
#[derive(Clone, Copy, Debug)]
pub struct Converged {
    pub iterations: u32,
    pub converged: bool,
    /// The last step's largest change of I against I's largest value.
    pub change: f64,
}

impl Illumination {
    /// Upload the scene, build the visibility network on the device, compute the direct light
    /// (transmittance step `step`, scene units) and start from I = 0. `force_full`: model every
    /// scene feature (the kernels' specialisation), as `--force-full` asks. `env_dirs` > 0: the
    /// environments are direct units of that many directions each and the sky is 0, so the
    /// network carries scattered light only (`networks.single = view`); 0: the environments
    /// are the sky (the paper's).
    pub fn new(
        gpu: &Gpu,
        net: &Network,
        scene: &Scene,
        step: f32,
        force_full: bool,
        env_dirs: u32,
    ) -> Result<Illumination, SolverError> {
        let n = net.particles.positions.len() as u32;
        let d = net.directions.len() as u32;
        let m = &scene.medium;
        let gs = GpuScene::upload(gpu, scene, force_full)?;
        let (positions, dirs) = net.upload(gpu)?;
        let visible = net.visibility_on(gpu, &positions, &dirs)?;
        let direct = gpu.buffer("networks direct light", net.direct_bytes(scene, env_dirs))?;
        net.direct(gpu, scene, &gs, &positions, step, env_dirs, &direct)?;
        let alpha = m.sigma_t.as_dvec3().map(|s| net.alpha(s)).as_vec3();
        let sky = if env_dirs > 0 { Vec3::ZERO } else { sky(scene) };
        Ok(Illumination {
            phase: gpu.buffer_with("networks phase", &phase_matrix(&net.directions, m.g as f64).0)?,
            field: [
                gpu.buffer("networks radiance a", 16 * n as u64 * d as u64)?,
                gpu.buffer("networks radiance b", 16 * n as u64 * d as u64)?,
            ],
            stats: crate::solvers::parts::feedback::Feedback::new(gpu, "networks iteration stats", 4 * STATS_WORDS)?,
            batch: BATCH,
            current: 0,
            pipeline: gpu.pipeline(&ITERATE, &[])?,
            push: IteratePush {
                alpha: [alpha.x, alpha.y, alpha.z, 0.0],
                albedo: [m.albedo.x, m.albedo.y, m.albedo.z, m.g],
                sky: [sky.x, sky.y, sky.z, 0.0],
                particles: n,
                directions: d,
                units: unit_count(scene, env_dirs),
                slot: 0,
                check: 0,
                tol: 0.0,
            },
            env_dirs,
            step,
            size: [scene.render.width, scene.render.height],
            camera: (
                scene.camera.origin,
                match scene.camera.kind {
                    crate::scene::CameraKind::Orthographic { .. } => Some(scene.camera.basis().2),
                    _ => None,
                },
            ),
            sigma_m: m.sigma_t * net.particles.mass as f32,
            iterations: 0,
            change: f64::INFINITY,
            faults: 0,
            gs,
            positions,
            dirs,
            visible,
            direct,
        })
    }

    /// The most device bytes an [`Illumination`] and its image hold at once: the scene,
    /// particles, directions and visibility network throughout; then the larger of the
    /// construction's buckets (freed once the network is built) and the iteration's state with
    /// the image's buffers.
    /// `view`: the view pass's bytes, where it runs after the splats (`networks.single =
    /// view`; 0 otherwise).
    pub fn device_bytes(net: &Network, scene: &Scene, env_dirs: u32, view: u64) -> u64 {
        let (n, d) = (net.particles.positions.len() as u64, net.directions.len() as u64);
        let base = crate::solvers::parts::gpu_scene::scene_bytes(scene) + 16 * n + 48 * d + 4 * n * d;
        let state = 4 * d * d
            + net.direct_bytes(scene, env_dirs)
            + 2 * 16 * n * d
            + crate::solvers::parts::feedback::Feedback::bytes(4 * STATS_WORDS);
        let image = 20 * n + 16 * scene.render.width as u64 * scene.render.height as u64;
        base + net.build_bytes().max(state + image.max(view))
    }

    /// The lights moved (same medium, same lights of the same kinds): recompute the direct
    /// light and the sky, keep I as the next iteration's start.
    pub fn set_lights(&mut self, gpu: &Gpu, net: &Network, scene: &Scene) -> Result<(), SolverError> {
        // The scene block (header and lights), rewritten in place: same size, same layout.
        let (header, lights) = crate::solvers::parts::gpu_scene::scene_block(scene);
        let mut bytes = bytemuck::bytes_of(&header).to_vec();
        bytes.extend_from_slice(bytemuck::cast_slice(&lights));
        if unit_count(scene, self.env_dirs) != self.push.units || bytes.len() as u64 != self.gs.block.size() {
            return Err(SolverError::Unsupported("networks: a warm start keeps the number of lights".to_string()));
        }
        gpu.write_buffer(&self.gs.block, 0, &bytes)?;
        net.direct(gpu, scene, &self.gs, &self.positions, self.step, self.env_dirs, &self.direct)?;
        let sky = if self.env_dirs > 0 { Vec3::ZERO } else { sky(scene) };
        self.push.sky = [sky.x, sky.y, sky.z, 0.0];
        self.iterations = 0;
        self.change = f64::INFINITY;
        Ok(())
    }

    /// `k` iterations, [`BATCH`] to a submission: for each, the largest change of I against
    /// the largest I, measured on the device (non-finite where a value went negative or not
    /// finite, which also counts a fault).
    pub fn step(&mut self, gpu: &Gpu, k: u32) -> Result<Vec<f64>, SolverError> {
        let mut changes = Vec::with_capacity(k as usize);
        let mut left = k;
        while left > 0 {
            let b = left.min(BATCH_MAX);
            let run = self.batch(gpu, b, None)?;
            left -= b;
            changes.extend(run.changes);
        }
        if let Some(c) = changes.last() {
            self.change = *c;
        }
        Ok(changes)
    }

    /// Submit `b` iterations as one batch and wait for it once. With `tol`, each iteration
    /// after the first judges the one before it on the device and the batch stops at the first
    /// that converged or faulted (the rest return at once); the iterations that ran are
    /// counted on the device.
    fn batch(&mut self, gpu: &Gpu, b: u32, tol: Option<f32>) -> Result<BatchRun, SolverError> {
        let d = self.push.directions;
        let mut passes = vec![self.stats.clear_pass(QueueRole::Diffuse)];
        passes.extend((0..b as usize).map(|j| {
            let (from, to) = ((self.current + j) % 2, (self.current + j + 1) % 2);
            let push = IteratePush {
                slot: j as u32,
                check: (tol.is_some() && j > 0) as u32,
                tol: tol.unwrap_or(0.0),
                ..self.push
            };
            Pass::new("networks.iterate", QueueRole::Diffuse, &self.pipeline)
                .read(0, &self.visible)
                .read(1, &self.dirs)
                .read(2, &self.direct)
                .read(3, &self.field[from])
                .write(4, &self.field[to])
                .read(5, &self.phase)
                .read_write(6, self.stats.record())
                .push(&push)
                .cover([self.push.particles, d, 1])
        }));
        passes.push(self.stats.copy_pass(QueueRole::Diffuse));
        let point = gpu.submit(QueueRole::Diffuse, &passes, &[])?;
        gpu.wait(point)?;
        let raw: Vec<u32> = self.stats.read_words(gpu)?;
        let ran = raw[1];
        let mut changes = Vec::with_capacity(ran as usize);
        let mut stopped = None;
        for j in 0..ran as usize {
            let (change, peak) = (f32::from_bits(raw[2 + 2 * j]), f32::from_bits(raw[3 + 2 * j]));
            let v = verdict(change, peak, tol.unwrap_or(0.0));
            changes.push(match v {
                Verdict::Fault => {
                    self.faults += 1;
                    f64::NAN
                }
                _ if peak > 0.0 => change as f64 / peak as f64,
                _ => 0.0,
            });
            if tol.is_some() && v != Verdict::GoOn {
                stopped = Some(v);
                break;
            }
        }
        // The device's count and the host's reading of the same words must agree: a batch
        // stops right after the iteration that converged (or at its end).
        let expected = changes.len() as u32;
        if tol.is_some() && ran != expected && !(stopped.is_none() && ran == b) {
            return Err(SolverError::Unsupported(format!(
                "networks: the device ran {ran} iterations of a batch of {b} but judged convergence after {expected}; \
                 please report this"
            )));
        }
        if raw[0] != 0 && stopped.is_none() {
            return Err(SolverError::Unsupported(format!(
                "networks: the device stopped a batch (verdict {}) that the host judges unfinished; please report this",
                raw[0]
            )));
        }
        self.current = (self.current + ran as usize) % 2;
        self.iterations += ran;
        if let Some(c) = changes.last() {
            self.change = *c;
        }
        Ok(BatchRun { changes, stopped })
    }

    /// The scene on the device (for the view pass of `networks.single = view`).
    pub fn scene(&self) -> &GpuScene {
        &self.gs
    }

    /// I [p][i] (rgb, w unused) as it stands.
    pub fn radiance(&self, gpu: &Gpu) -> Result<Vec<[f32; 4]>, SolverError> {
        Ok(gpu.read_buffer_as(&self.field[self.current])?)
    }

    /// The image (paper 3.3's last paragraph) with the scene's camera: each particle's
    /// radiance toward the camera (glsl/networks/gather.comp), then the particles splatted
    /// front to back with alpha blending (glsl/networks/splat.comp), Gaussian footprints of the
    /// particle's radius b carrying its extinction cross-section sigma_t m.
    /// `width`: the footprint's width in particle radii. `medium_step`: > 0 scales each
    /// camera ray's splats so that their optical depths sum to the medium's along the ray
    /// (marched in steps of it, scene units; `networks.transmittance = medium`), 0 keeps the
    /// splats' own (the paper's).
    pub fn image(&self, gpu: &Gpu, net: &Network, width: f32, medium_step: f32) -> Result<Splatted, SolverError> {
        let gs = &self.gs;
        let n = self.push.particles;
        let colour = gpu.buffer("networks colours", 16 * n as u64)?;
        let [w, h] = self.size;
        let pixels = gpu.buffer("networks image", 16 * w as u64 * h as u64)?;
        // The particles nearest the camera first (distance from a perspective camera, depth
        // along an orthographic one's axis; ties by index): splat.comp appends in this order.
        let (origin, axis) = self.camera;
        let key = |x: &Vec3| match axis {
            Some(a) => (*x - origin).dot(a),
            None => (*x - origin).length(),
        };
        let keys: Vec<f32> = net.particles.positions.iter().map(key).collect();
        let mut order: Vec<u32> = (0..n).collect();
        order.sort_by(|a, b| keys[*a as usize].total_cmp(&keys[*b as usize]).then(a.cmp(b)));
        let order = gpu.buffer_with("networks splat order", &order)?;
        let gather = gpu.pipeline(&GATHER, &gs.modelled.spec())?;
        let splat = gpu.pipeline(&SPLAT, &gs.modelled.view_spec())?;
        let (sigma_m, sky) = (self.sigma_m, self.push.sky);
        let passes = [
            gs.bind(Pass::new("networks.gather", QueueRole::Trace, &gather))
                .read(3, &self.positions)
                .read(4, &self.dirs)
                .read(5, &self.direct)
                .read(6, &self.field[self.current])
                .write(7, &colour)
                .push(&GatherPush {
                    particles: n,
                    directions: self.push.directions,
                    units: self.push.units,
                    direct: (self.env_dirs == 0) as u32,
                })
                .cover([n, 1, 1]),
            gs.bind(Pass::new("networks.splat", QueueRole::Trace, &splat))
                .read(3, &self.positions)
                .read(4, &colour)
                .write(5, &pixels)
                .read(6, &order)
                .push(&SplatPush {
                    sigma_m: [sigma_m.x, sigma_m.y, sigma_m.z, 0.0],
                    sky,
                    width: net.particle_radius() as f32 * width,
                    particles: n,
                    step: medium_step,
                    pad: 0,
                })
                .cover([w, h, 1]),
        ];
        let point = gpu.submit(QueueRole::Trace, &passes, &[])?;
        gpu.wait(point)?;
        let px: Vec<[f32; 4]> = gpu.read_buffer_as(&pixels)?;
        if px.iter().any(|p| p[3] < 0.0) {
            return Err(SolverError::Unsupported(
                "networks: a pixel's splats ran past the per-invocation loop guard; use fewer networks.particles"
                    .to_string(),
            ));
        }
        let mut nonfinite = 0u32;
        let data = px
            .iter()
            .flat_map(|p| {
                let ok = p[..3].iter().all(|c| c.is_finite());
                nonfinite += (!ok) as u32;
                if ok {
                    [p[0], p[1], p[2]]
                } else {
                    [0.0; 3]
                }
            })
            .collect();
        Ok(Splatted {
            image: crate::output::Image { width: w, height: h, data },
            dropped: px.iter().map(|p| p[3] as u64).sum(),
            nonfinite,
        })
    }

    /// Iterate until a step changes I by at most `tol` of its largest value, or `max` steps,
    /// reporting progress. Batches of iterations are submitted whole and stopped on the device
    /// at the first converged (or faulted) iteration, so the host waits once per batch and I
    /// is the converged iteration's, not a later one's; a batch is at least [`BATCH`]
    /// iterations and grows toward [`BATCH_TARGET_MS`] of GPU work. Stops at the first fault
    /// (a negative or non-finite value).
    pub fn solve(
        &mut self,
        gpu: &Gpu,
        tol: f64,
        max: u32,
        progress: &dyn Fn(crate::solvers::interface::Progress),
    ) -> Result<Converged, SolverError> {
        let mut earlier: Option<(f64, u64)> = None;
        while self.iterations < max {
            let b = self.batch.min(max - self.iterations);
            let started = std::time::Instant::now();
            let run = self.batch(gpu, b, Some(tol as f32))?;
            // The batch's time per iteration run sets the next batch's size.
            let per = started.elapsed().as_secs_f64() * 1e3 / run.changes.len().max(1) as f64;
            self.batch = ((BATCH_TARGET_MS / per.max(1e-3)) as u32).clamp(BATCH, BATCH_MAX);
            let it = self.iterations as u64;
            match run.stopped {
                Some(Verdict::Converged) => {
                    return Ok(Converged { iterations: self.iterations, converged: true, change: self.change })
                }
                Some(_) => break,
                None => {}
            }
            progress(crate::solvers::interface::Progress::converging(
                "networks iteration",
                it,
                self.change,
                tol,
                earlier,
                max as u64,
            ));
            if earlier.is_none() {
                earlier = Some((self.change, it));
            }
        }
        Ok(Converged { iterations: self.iterations, converged: false, change: self.change })
    }
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
    /// b: a particle's radius (scene units), the splats' footprint width at networks.footprint 1.
    pub particle_radius: f64,
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
            particles: set.particles,
            directions: set.directions,
            window: net.window.m,
            opacity: scene.medium.sigma_t.as_dvec3().map(|s| net.alpha(s)).to_array(),
            particle_radius: net.particle_radius(),
            iterations: c.iterations,
            converged: c.converged,
            final_change: c.change,
            splats_dropped: img.dropped,
            nonfinite_pixels: img.nonfinite,
            build_ms,
            iterate_ms,
            image_ms,
        };
        let mut stats = Stats::new(detail);
        stats.convergence = Some(Convergence {
            iterations: c.iterations as u64,
            converged: c.converged,
            final_change: c.change,
            tolerance: set.tol,
        });
        stats.faults = st.faults + img.nonfinite as u64 + view_nonfinite as u64;
        let modelled = crate::solvers::parts::gpu_scene::modelled(scene, force_full);
        let bytes = Illumination::device_bytes(net, scene, set.env_dirs(), set.view_bytes(scene));
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
        report.warnings.extend(crate::solvers::interface::nonfinite_warning(img.nonfinite + view_nonfinite));
        Ok(RenderOutput { image: img.image, variance: None, report })
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
        let t = Instant::now();
        let first = self.state.is_none();
        let st = match &mut self.state {
            Some(st) => {
                st.set_lights(gpu, &self.net, scene)?;
                st
            }
            None => {
                self.state.insert(Illumination::new(gpu, &self.net, scene, set.step, self.force_full, set.env_dirs())?)
            }
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
                "1/128 of the medium's diagonal",
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
        let mut st = Illumination::new(gpu, &net, scene, set.step, req.force_full, set.env_dirs())?;
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
        Ok(Illumination::device_bytes(&set.network(scene)?, scene, set.env_dirs(), set.view_bytes(scene)))
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

    fn summary(&self, report: &RenderReport) -> Vec<String> {
        let Some(s) = report.detail::<NetworksStats>() else { return Vec::new() };
        vec![format!(
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
        )]
    }
}
