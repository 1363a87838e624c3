//! Illumination networks (issue 15; Szirmay-Kalos, Sbert, Umenhoffer, "Real-time multiple
//! scattering in participating media with illumination networks", EGSR 2005): the particle
//! model (2.1) and the visibility network (3.1-3.2), built on the device. Not yet a solver:
//! the direct term, the iteration (3.3), the image and the moving lights are still to come
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

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use crate::gpu::{Gpu, Kernel, Pass, QueueRole};
use crate::physics::rng::Pcg32;
use crate::scene::Scene;

use super::SolverError;

pub const COUNT: Kernel =
    Kernel { shader: shader!("networks/count"), push_bytes: std::mem::size_of::<NetworkPush>(), spec: &[] };
pub const FILL: Kernel =
    Kernel { shader: shader!("networks/fill"), push_bytes: std::mem::size_of::<NetworkPush>(), spec: &[] };
pub const LINK: Kernel =
    Kernel { shader: shader!("networks/link"), push_bytes: std::mem::size_of::<NetworkPush>(), spec: &[] };

/// Every kernel of this part.
pub fn kernels() -> Vec<Kernel> {
    vec![COUNT, FILL, LINK]
}

/// No particle upstream: the sky is seen (V's value).
pub const NONE: u32 = u32::MAX;

/// The largest window resolution M (D M^2 buckets of three u32 each).
pub const MAX_WINDOW: u32 = 2048;

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

impl Window {
    /// The bounding sphere of the medium's bounds, and M set, or by the paper's rule (3.2):
    /// D (R tau)^2 / pi >= M^2, tau the mean extinction (mean over the channels of sigma_t) where
    /// the density is non-zero; at least 1 and at most [`MAX_WINDOW`].
    pub fn new(scene: &Scene, particles: &Particles, directions: u32, m: Option<u32>) -> Window {
        let med = &scene.medium;
        let centre = (med.bounds_min + med.bounds_max) * 0.5;
        let radius = (med.bounds_max - med.bounds_min).length() * 0.5;
        let m = m.unwrap_or_else(|| {
            let n = particles.positions.len() as f64;
            let sigma = med.sigma_t.dot(Vec3::ONE) as f64 / 3.0;
            let tau = sigma * particles.mass * n / particles.occupied.max(f64::MIN_POSITIVE);
            let rule = (directions as f64 / std::f64::consts::PI).sqrt() * radius as f64 * tau;
            rule.floor().clamp(1.0, MAX_WINDOW as f64) as u32
        });
        Window { centre, radius, m: m.clamp(1, MAX_WINDOW) }
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
}

impl Network {
    /// Opacity of a particle across one window pixel for extinction `sigma_t` (1/unit):
    /// 1 - exp(-sigma_t m / A).
    pub fn opacity(&self, sigma_t: f64) -> f64 {
        -(-sigma_t * self.particles.mass / self.window.pixel_area()).exp_m1()
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
        let positions: Vec<[f32; 4]> = self.particles.positions.iter().map(|p| [p.x, p.y, p.z, 0.0]).collect();
        let frames: Vec<[f32; 4]> =
            self.directions.frames.iter().flat_map(|f| f.map(|a| [a.x, a.y, a.z, 0.0])).collect();
        let positions = gpu.buffer_with("networks particles", &positions)?;
        let dirs = gpu.buffer_with("networks directions", &frames)?;
        let counts = gpu.buffer("networks bucket counts", buckets * 4)?;
        let offsets = gpu.buffer("networks bucket offsets", buckets * 4)?;
        let cursor = gpu.buffer("networks bucket cursors", buckets * 4)?;
        let entries = gpu.buffer("networks bucket entries", n as u64 * d as u64 * 4)?;
        let visible = gpu.buffer("networks visibility", n as u64 * d as u64 * 4)?;
        let count = gpu.pipeline(&COUNT, &[])?;
        let fill = gpu.pipeline(&FILL, &[])?;
        let link = gpu.pipeline(&LINK, &[])?;
        let pass = Pass::new("networks.count", QueueRole::Trace, &count)
            .read(0, &positions)
            .read(1, &dirs)
            .read_write(2, &counts)
            .push(&push)
            .cover([n, d, 1]);
        let point = gpu.submit(QueueRole::Trace, &[pass], &[])?;
        gpu.wait(point)?;
        // The buckets' offsets: an exclusive prefix sum of the counts (D M^2 of them; on the
        // host between the passes, a few milliseconds at the paper's sizes).
        let c: Vec<u32> = gpu.read_buffer_as(&counts)?;
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
                .read(0, &positions)
                .read(1, &dirs)
                .read(2, &offsets)
                .read_write(3, &cursor)
                .write(4, &entries)
                .push(&push)
                .cover([n, d, 1]),
            Pass::new("networks.link", QueueRole::Trace, &link)
                .read(0, &positions)
                .read(1, &dirs)
                .read(2, &counts)
                .read(3, &offsets)
                .read_write(4, &entries)
                .write(5, &visible)
                .push(&push)
                .cover([buckets as u32, 1, 1]),
        ];
        let point = gpu.submit(QueueRole::Trace, &passes, &[])?;
        gpu.wait(point)?;
        Ok(gpu.read_buffer_as(&visible)?)
    }
}
