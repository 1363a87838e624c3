//! The medium as particles and the visibility network between them (illumination networks
//! 3.1-3.2): particles drawn in proportion to the density, the shared directions, the windows
//! whose columns link each particle to the one it sees upstream, and the direct light at
//! every particle.

use super::*;

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
pub(super) struct NetworkPush {
    pub(super) centre_radius: [f32; 4],
    pub(super) inv_pixel: f32,
    pub(super) m: u32,
    pub(super) particles: u32,
    pub(super) directions: u32,
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
    /// The mass-weighted mean of density^(2/3) and the largest density (both on the same
    /// lattice): what [`ParticleTrust`] turns into mean free paths per particle spacing.
    pub density_23: f64,
    pub density_max: f64,
}

/// The density's integral (scene units^3), the volume where it is non-zero, the mass-weighted
/// mean of density^(2/3) and the largest density, by the midpoint rule on a 96^3 lattice of the
/// medium's bounds.
fn measure(scene: &Scene) -> (f64, f64, f64, f64) {
    let m = &scene.medium;
    let (lo, size) = (m.bounds_min, m.bounds_max - m.bounds_min);
    const LATTICE: u32 = 96;
    let (mut sum, mut sum_53, mut occupied, mut max) = (0f64, 0f64, 0u64, 0f64);
    for z in 0..LATTICE {
        for y in 0..LATTICE {
            for x in 0..LATTICE {
                let u = (Vec3::new(x as f32, y as f32, z as f32) + 0.5) / LATTICE as f32;
                let d = scene.density_at(lo + u * size) as f64;
                sum += d;
                sum_53 += d * d.max(0.0).powf(2.0 / 3.0);
                occupied += (d > 0.0) as u64;
                max = max.max(d);
            }
        }
    }
    let cells = (LATTICE as f64).powi(3);
    let volume = size.x as f64 * size.y as f64 * size.z as f64;
    (sum / cells * volume, occupied as f64 / cells * volume, sum_53 / sum.max(f64::MIN_POSITIVE), max)
}

/// The particles' spacing against the medium's mean free path (issue 44, item 2: "particles
/// per mean free path for networks"): n particles drawn in proportion to the density stand
/// (m / density)^(1/3) apart where the density is `density` (m a particle's mass), so a spacing
/// is sigma_t density^(2/3) m^(1/3) mean free paths there. Where it is over about one, a
/// particle's neighbours lie beyond the light's reach and the network misses the light scattered
/// twice or more. Measured on the cube (optical thickness 1-20, docs/networks.md, energy / relL2
/// against path): 0.625 mean free paths a spacing 0.987 / 0.114, 0.99 0.926 / 0.181, 1.57
/// 0.78-0.99 / 0.26-0.31, 2.5 0.70-0.93 / 0.36-0.55, 4.0 0.70-0.87 / 0.44-0.66 (and the sphere of
/// sigma_t 1000 at 72: 0.45 of the energy); the shipped sphere at 0.72 0.943 / 0.112; the thin
/// spherical shell of tests/shape_tests.rs seen from above 0.37 0.994, 0.59 0.979, 0.94 0.934,
/// 1.49 0.849.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ParticleTrust {
    pub particles: u32,
    /// Mean free paths across a particle spacing where the particles are (mass-weighted: most
    /// particles sit there) and at the densest point, in the most opaque channel.
    pub spacing_depth: f64,
    pub spacing_depth_max: f64,
    /// The particles that bring `spacing_depth` to the validated depth (None: past the knob's
    /// range).
    pub particles_needed: Option<u32>,
}

impl ParticleTrust {
    /// Mean free paths a spacing networks was validated at: within 3% of path's energy there (the
    /// shell at 0.59: 0.979; the cube at 0.625: 0.987). It was 1.0 until the shell showed 0.934
    /// at 0.94 (the cube 0.926 at 0.99): within the range and 7% dark.
    pub const VALIDATED: f64 = 0.6;
    /// Past this, a warning: the first spacing measured more than 5% dark is the shipped sphere's
    /// 0.72 (0.943); 1.25 before, which let the shell's 0.934 and the cube's 0.926 pass unwarned.
    pub const WARN: f64 = 0.7;
    /// `networks.particles`' largest value.
    pub const MAX_PARTICLES: u32 = 16384;

    /// The trust of `p`, `n` particles drawn for `scene`.
    pub fn new(scene: &Scene, p: &Particles, n: u32) -> ParticleTrust {
        Self::from_density(scene, n, p.mass, p.density_23, p.density_max)
    }

    /// The trust of `n` particles in `scene` before any is drawn (the density's lattice only).
    pub fn of(scene: &Scene, n: u32) -> ParticleTrust {
        let (integral, _, density_23, density_max) = measure(scene);
        Self::from_density(scene, n, integral / n as f64, density_23, density_max)
    }

    /// From a particle's mass `mass` and the density's figures ([`Particles::density_23`]).
    fn from_density(scene: &Scene, n: u32, mass: f64, density_23: f64, density_max: f64) -> ParticleTrust {
        let sigma = scene.medium.sigma_t.max_element() as f64;
        let m13 = mass.max(0.0).cbrt();
        let spacing_depth = sigma * density_23 * m13;
        ParticleTrust {
            particles: n,
            spacing_depth,
            spacing_depth_max: sigma * density_max.max(0.0).powf(2.0 / 3.0) * m13,
            particles_needed: crate::solvers::interface::count_for_spacing(
                n,
                spacing_depth,
                Self::VALIDATED,
                Self::MAX_PARTICLES,
            ),
        }
    }

    pub fn within(&self) -> bool {
        self.spacing_depth <= Self::VALIDATED * 1.001
    }

    pub fn warns(&self) -> bool {
        // A NaN depth (a medium with no density never gets here) would warn too.
        self.spacing_depth > Self::WARN || self.spacing_depth.is_nan()
    }

    /// The one-line figure for a render's summary.
    pub fn line(&self) -> String {
        format!(
            "particle trust: a particle spacing is {:.2} mean free paths where the particles are ({:.2} at the densest), \
             {} particles (validated at <= {} a spacing){}",
            self.spacing_depth,
            self.spacing_depth_max,
            self.particles,
            Self::VALIDATED,
            if self.within() { "" } else { ": OUTSIDE" }
        )
    }

    /// The warning a render too coarse for its medium carries: the figure, the error measured
    /// nearest it, and the particle count that fixes it, or that none in range does.
    pub fn warning(&self) -> Option<String> {
        if !self.warns() {
            return None;
        }
        let fix = match self.particles_needed {
            Some(n) => format!("set networks.particles={n}"),
            None => format!(
                "no networks.particles up to {} serves (the medium is too dense for the particle model); use lbl, dom \
                 or path",
                Self::MAX_PARTICLES
            ),
        };
        Some(format!(
            "networks: a particle spacing is {:.2} mean free paths where the particles are ({} particles), above the {} \
             networks was validated at (0.72 gave the sphere 0.94 of path's energy, 0.94 a thin shell 0.93 and 1.0 a \
             cube 0.93; on the cube of optical thickness 20, 1.6 gave 0.78-0.99 and relL2 0.26-0.31, 2.5 gave \
             0.70-0.93 and 0.36-0.55); {fix}",
            self.spacing_depth,
            self.particles,
            Self::VALIDATED
        ))
    }
}

impl Particles {
    /// `n` particles drawn with probability proportional to the density, by rejection from the
    /// medium's bounds (a stream of the scene's seed: deterministic). The density's integral is
    /// the midpoint rule on a 96^3 lattice of the bounds.
    pub fn sample(scene: &Scene, n: u32, seed: u64) -> Result<Particles, SolverError> {
        let m = &scene.medium;
        let (lo, size) = (m.bounds_min, m.bounds_max - m.bounds_min);
        let (integral, occupied, density_23, density_max) = measure(scene);
        let max = scene.max_density();
        if max.is_nan() || max <= 0.0 {
            return Err(SolverError::Unsupported(
                "networks: the medium's density (medium.density) is 0 everywhere: no particle can be placed and the \
                 image would be the background alone; check the density grid's values"
                    .to_string(),
            ));
        }
        if integral.is_nan() || integral <= 0.0 {
            return Err(SolverError::Unsupported(
                "networks: the medium's density (medium.density) is 0 at every point of the 96^3 lattice that places \
                 the particles: its features are thinner than a 96th of the medium's bounds; tighten medium.bounds \
                 about them or use path"
                    .to_string(),
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
        Ok(Particles { positions, mass: integral / n as f64, occupied, density_23, density_max })
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
    pub(super) fn upload(&self, gpu: &Gpu) -> Result<(Buffer, Buffer), SolverError> {
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
    pub(super) fn visibility_on(&self, gpu: &Gpu, positions: &Buffer, dirs: &Buffer) -> Result<Buffer, SolverError> {
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
        // One count per window pixel and direction in one binding: past the device's largest,
        // the knobs that size it are named (the buffer's own error named neither).
        let range = gpu.info().max_storage_buffer_range;
        if buckets * 4 > range {
            let most = ((range / 4 / d.max(1) as u64) as f64).sqrt().floor() as u64;
            return Err(SolverError::Unsupported(format!(
                "networks: a window of {m} x {m} pixels for each of {d} directions needs {} MiB of bucket counts, past \
                 this device's largest binding ({} MiB); set networks.window={most} or less, or fewer \
                 networks.directions",
                (buckets * 4) >> 20,
                range >> 20,
                m = self.window.m
            )));
        }
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
            // An invocation's loops (glsl/networks/direct.comp), counted as llvmpipe counts them
            // (n iterations take n + 1 back-edges): the march, at most the bounds' diagonal over
            // `step`, and two loops over the lights (the unit's light, the environments'), all
            // kept under the per-invocation loop guard (glsl/include/budget.glsl).
            let diagonal = (scene.medium.bounds_max - scene.medium.bounds_min).length();
            let steps = (diagonal / step).ceil() as u64;
            let lights = scene.lights.len() as u64;
            let iterations = steps + 1 + 2 * (lights + 1);
            if iterations > LOOP_GUARD as u64 {
                return Err(SolverError::Unsupported(format!(
                    "networks.step = {step} takes {steps} steps across the medium, and with {lights} \
                     lights one invocation runs {iterations} loop iterations; at most {LOOP_GUARD} (raise \
                     networks.step or merge lights)"
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

    /// Each particle's emission per unit of its opacity, (1 - albedo) Le(x_p), W/(m^2 sr) rgb
    /// (issue 47; 0 where the medium emits nothing). A particle stands for its share of the
    /// medium's extinction, sigma_t m; of what it stops the share 1 - albedo is absorbed, and
    /// there the medium emits: the transfer equation's source sigma_a Le = sigma_t (1 - albedo)
    /// density Le integrated over the particle is (1 - albedo) Le times its optical depth, so a
    /// particle of opacity alpha (the optical depth it holds across a window pixel, linear
    /// opacity) adds alpha (1 - albedo) Le to the radiance crossing it, in every direction: the
    /// emission term of the paper's E array. With the exponential opacity it is the step rule
    /// of the view march (1 - albedo) (1 - e^-c) Le: a thick absorbing particle glows at Le.
    pub fn emitted(&self, scene: &Scene) -> Vec<Vec3> {
        let absorbed = Vec3::ONE - scene.medium.albedo;
        self.particles.positions.iter().map(|x| absorbed * scene.emission_at(*x)).collect()
    }

    /// The emission arriving unscattered at each particle along each direction of travel,
    /// J[p][i] (rgb, W/(m^2 sr); w: the march's loop count), on the device
    /// (glsl/networks/arrive.comp): the integral of T sigma_a Le over the medium upstream, by
    /// the view march's step rule in steps of at most `step` (scene units); and E[p][i] =
    /// sum_d J[p][d] P[d][i], J scattered into each direction by `phase` (the iteration's
    /// balanced quadrature). Over uploaded positions and directions ([`Network::upload`]).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn arriving(
        &self,
        gpu: &Gpu,
        scene: &Scene,
        gs: &GpuScene,
        positions: &Buffer,
        dirs: &Buffer,
        phase: &Buffer,
        step: f32,
    ) -> Result<(Buffer, Buffer), SolverError> {
        let (n, d) = (self.particles.positions.len() as u32, self.directions.len() as u32);
        // The march's steps: at most the bounds' diagonal over `step`, under the loop guard.
        let diagonal = (scene.medium.bounds_max - scene.medium.bounds_min).length();
        let steps = (diagonal / step).ceil() as u64 + 1;
        if steps > LOOP_GUARD as u64 {
            return Err(SolverError::Unsupported(format!(
                "networks: the emission's march step {step} takes {steps} steps across the medium; at most {LOOP_GUARD}"
            )));
        }
        let j = gpu.buffer("networks arriving emission", 16 * n as u64 * d as u64)?;
        let e = gpu.buffer("networks scattered emission", 16 * n as u64 * d as u64)?;
        let pipeline = gpu.pipeline(&ARRIVE, &gs.modelled.spec())?;
        let pass = |name, mode| {
            gs.bind_emission(gs.bind(Pass::new(name, QueueRole::Trace, &pipeline)))
                .read(3, positions)
                .read(4, dirs)
                .read_write(5, &j)
                .read(6, phase)
                .write(7, &e)
                .push(&ArrivePush { step, particles: n, directions: d, mode })
                .cover([n, d, 1])
        };
        let point =
            gpu.submit(QueueRole::Trace, &[pass("networks.arrive", 0), pass("networks.arrive_scatter", 1)], &[])?;
        gpu.wait(point)?;
        Ok((j, e))
    }

    /// [`Network::arriving`] on the host in double precision ([p][i], rgb): its oracle.
    pub fn arriving_cpu(&self, scene: &Scene, step: f64) -> Vec<[f64; 3]> {
        let m = &scene.medium;
        let sigma = m.sigma_t.as_dvec3();
        let absorbed = glam::DVec3::ONE - m.albedo.as_dvec3();
        let mut out = Vec::with_capacity(self.particles.positions.len() * self.directions.len());
        for x in &self.particles.positions {
            for f in &self.directions.frames {
                let (x, w) = (x.as_dvec3(), -f[2].as_dvec3());
                let (mut l, mut t) = (glam::DVec3::ZERO, glam::DVec3::ONE);
                if let Some((a, b)) = medium_interval(scene, x, w) {
                    let k = ((b - a) / step).ceil().max(1.0);
                    let dt = (b - a) / k;
                    for i in 0..k as u64 {
                        let q = (x + w * (a + (i as f64 + 0.5) * dt)).as_vec3();
                        let seg = (-sigma * scene.density_at(q) as f64 * dt).exp();
                        l += t * absorbed * (glam::DVec3::ONE - seg) * scene.emission_at(q).as_dvec3();
                        t *= seg;
                    }
                }
                out.push(l.to_array());
            }
        }
        out
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
    /// from I = 0, over the device's visibility network: I [p][i] rgb. `force_full`: the
    /// kernels model every feature (`--model-all`), so an isotropic medium's in-scattering is
    /// the full sum, not the per-particle one (glsl/networks/inscatter.comp).
    pub fn iterate(
        &self,
        gpu: &Gpu,
        scene: &Scene,
        iterations: u32,
        step: f32,
        force_full: bool,
    ) -> Result<Vec<[f32; 4]>, SolverError> {
        let mut state = Illumination::new(gpu, self, scene, step, force_full, 0)?;
        state.step(gpu, iterations)?;
        state.radiance(gpu)
    }

    /// `iterations` steps on the device with the emission entering by `emission`.
    pub fn iterate_with(
        &self,
        gpu: &Gpu,
        scene: &Scene,
        iterations: u32,
        step: f32,
        emission: EmissionModel,
    ) -> Result<Vec<[f32; 4]>, SolverError> {
        let mut state = Illumination::with_emission(gpu, self, scene, step, true, 0, emission)?;
        state.step(gpu, iterations)?;
        state.radiance(gpu)
    }

    /// The same iteration on the host in double precision: the oracle of
    /// [`Network::iterate`] where the medium does not emit (an emitting one's is
    /// [`Network::iterate_cpu_with`]: the device marches the emission's first flight).
    pub fn iterate_cpu(
        &self,
        scene: &Scene,
        visible: &[u32],
        direct: &[DirectLight],
        iterations: u32,
    ) -> Vec<[f64; 3]> {
        self.iterate_cpu_with(scene, visible, direct, None, iterations)
    }

    /// The host's iteration with the emission entering as the particles' own
    /// ([`Network::emitted`]; `arriving` None) or as J, the emission arriving unscattered
    /// ([`Network::arriving_cpu`]): the oracle of [`Network::iterate_with`].
    pub fn iterate_cpu_with(
        &self,
        scene: &Scene,
        visible: &[u32],
        direct: &[DirectLight],
        arriving: Option<&[[f64; 3]]>,
        iterations: u32,
    ) -> Vec<[f64; 3]> {
        let n = self.particles.positions.len();
        let d = self.directions.len();
        let units = light_units(scene).len();
        let m = &scene.medium;
        let alpha = m.sigma_t.as_dvec3().map(|s| self.alpha(s));
        let albedo = m.albedo.as_dvec3();
        let g = m.g as f64;
        let sky = scene.environment_radiance().as_dvec3();
        let w: Vec<glam::DVec3> = self.directions.frames.iter().map(|f| f[2].as_dvec3()).collect();
        let phase = phase_matrix(&self.directions, g).0;
        // The particles' own emission enters only where J does not carry it.
        let emitted: Vec<glam::DVec3> = match arriving {
            None => self.emitted(scene).iter().map(|e| e.as_dvec3()).collect(),
            Some(_) => vec![glam::DVec3::ZERO; n],
        };
        let arrive = |p: usize, k: usize| arriving.map_or(glam::DVec3::ZERO, |j| glam::DVec3::from_array(j[p * d + k]));
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
                        scattered += (cur[vp * d + k] + arrive(vp, k)) * phase[k * d + i] as f64;
                    }
                    next[p * d + i] =
                        (1.0 - alpha) * cur[vp * d + i] + alpha * albedo * (lit + scattered) + alpha * emitted[vp];
                }
            }
            cur = next;
        }
        cur.into_iter().map(|v| v.to_array()).collect()
    }
}

/// The density's integral from `x` along `w` over [0, t_far] inside the medium's support, by
/// the midpoint rule in steps of at most `step` (glsl/include/view.glsl's density_depth).
pub(super) fn density_depth(scene: &Scene, x: glam::DVec3, w: glam::DVec3, t_far: f64, step: f64) -> f64 {
    let Some((a, b)) = medium_interval(scene, x, w) else { return 0.0 };
    let b = b.min(t_far);
    if a >= b {
        return 0.0;
    }
    let len = b - a;
    let k = (len / step).ceil().max(1.0);
    let dt = len / k;
    (0..k as u64).map(|i| scene.density_at((x + w * (a + (i as f64 + 0.5) * dt)).as_vec3()) as f64).sum::<f64>() * dt
}

/// Where the ray from `x` along `w` (t >= 0) is inside the medium's support: the box, and the
/// sphere for sphere density (view.glsl's medium_interval); None where it misses.
fn medium_interval(scene: &Scene, x: glam::DVec3, w: glam::DVec3) -> Option<(f64, f64)> {
    let m = &scene.medium;
    let (xf, wf) = (x.as_vec3(), w.as_vec3());
    let (mut a, mut b) = ray_box(xf, wf, m.bounds_min, m.bounds_max)?;
    if let crate::scene::Density::Sphere { center, radius } = m.density {
        let (s0, s1) = ray_sphere(xf, wf, center, radius)?;
        (a, b) = (a.max(s0), b.min(s1));
    }
    let (a, b) = ((a as f64).max(0.0), b as f64);
    (a < b).then_some((a, b))
}
