//! sh-single's samples: Poisson-disk placement inside the objects (darts, the depth and
//! divergence heuristics, the thesis's layers), optical depths on the host, and the SH
//! projection of each sample's attenuation on the device (thesis 3.2-3.3).

use super::*;

/// One sample of the interior: its centre b_i, its Poisson-disk radius (scene units) and the
/// material it lies in (an index into [`Object::materials`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    pub position: Vec3,
    pub radius: f32,
    pub material: usize,
}

/// Distance from `p` (inside) to the object's surface, the nearest of 26 directions (the cube's
/// faces, edges and corners): at most 1 / cos(the largest angle to the nearest direction) ~ 1.2
/// times the true distance. Called for every dart: the directions are formed in place.
pub fn depth_below_surface(object: &Object, p: Vec3) -> f32 {
    let mut nearest = f32::INFINITY;
    for k in 0..27 {
        let d = Vec3::new((k % 3) as f32 - 1.0, ((k / 3) % 3) as f32 - 1.0, (k / 9) as f32 - 1.0);
        if k != 13 {
            if let Some(h) = object.bvh.intersect(p, d.normalize(), 0.0, nearest) {
                nearest = h.t;
            }
        }
    }
    nearest
}

/// The successive surface crossings of the ray from `p` along `w`, each searched for past the
/// last by a rounding margin (so as not to find the same triangle again); a closed mesh is
/// crossed finitely often, and the count is capped against a degenerate loop.
pub(super) fn crossings(object: &Object, p: Vec3, w: Vec3) -> impl Iterator<Item = crate::scene::bvh::Hit> + '_ {
    let mut t_search = 0.0f32;
    let mut left = object.mesh.triangles.len() + 2;
    std::iter::from_fn(move || {
        left = left.checked_sub(1)?;
        let h = object.bvh.intersect(p, w, t_search, f32::INFINITY)?;
        t_search = h.t + 1e-5 * h.t.abs().max(1.0);
        Some(h)
    })
}

/// A uniform point of the box from `lo` spanning `extent`.
pub(super) fn dart(rng: &mut Pcg32, lo: Vec3, extent: Vec3) -> Vec3 {
    lo + Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * extent
}

/// The largest extinction (any channel, density 1) of the object's materials, 1/unit.
pub(super) fn max_sigma_t(object: &Object) -> f32 {
    object.materials.iter().map(|m| m.sigma_t.max_element()).fold(0.0, f32::max)
}

/// Radius scale at depth `depth` below the surface (module docs): 0.5 at the surface, 2 from
/// 3 mean free paths on.
pub(super) fn radius_scale(depth: f32, mfp: f32) -> f32 {
    0.5 + 1.5 * (depth / (3.0 * mfp)).clamp(0.0, 1.0)
}

/// Random sequential addition of hard spheres of diameter d fills about 30% of space when
/// darts run out well before the jamming limit (38%): what sizes r0 for a requested count.
pub(super) const PACKING: f64 = 0.3;

/// Darts per requested sample before the set is taken as full.
pub(super) const DARTS_PER_SAMPLE: u32 = 40;

/// How the Poisson radius varies over the object (`sh_single.density`): the thesis's r/2 .. 2r
/// by a density heuristic (3.2.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Heuristic {
    /// The depth below the surface in mean free paths ([`radius_scale`]).
    Depth,
    /// The thesis's: the divergence of the attenuation's first moment ([`DivergenceField`]).
    Divergence,
}

impl Heuristic {
    /// Its `sh_single.density` value.
    pub fn name(self) -> &'static str {
        match self {
            Heuristic::Depth => "depth",
            Heuristic::Divergence => "divergence",
        }
    }
}

/// Where the darts may land (`sh-single.placement`): anywhere inside the object, or on the
/// thesis's layers (3.2.1-3.2.2), offset surfaces at depths k delta below the mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Placement {
    Volume,
    Layers,
}

/// Spacing of the offset surfaces in base Poisson radii r0 (the thesis: "fractions of the
/// predicted mean distance between sampling points", 3.2.2). A quarter: the samples nearest
/// the surface (radius r0 / 2 under the depth heuristic) have two layers within their disk.
pub const LAYER_SPACING: f32 = 0.25;

/// The thesis's density heuristic (3.2.3), on a grid over the object's box: the first moment
/// of the attenuation, T(x) = int exp(-tau(x, w)) w dw (eq. 3.5), at every grid point (tau of
/// the most penetrating channel, [`DIVERGENCE_DIRECTIONS`] directions; 0 outside the object,
/// where psi is 1 everywhere and its first moment vanishes), its divergence by central
/// differences, rho = |div T|, normalised to [0, 1] between its minimum and its 95th
/// percentile over the points inside (the thesis takes the maximum; the points nearest the
/// surface, where T jumps to 0, would set it alone). A sample's radius is then r0 (2 - 1.5
/// rho): r/2 .. 2r as the thesis (3.2.4), with the grid's trilinear rho. The thesis computes rho
/// at the vertices of its offset surfaces and interpolates it too. Points whose light
/// int psi dw / 4 pi falls below [`DARK`] (deep in a thick object) get no samples, as the
/// thesis discards them.
pub struct DivergenceField {
    /// The grid's points are the [`Grid`]s' voxel centres: its box reaches half a spacing past
    /// the outer points, so [`Grid::sample`]'s trilinear interpolation between centres is the
    /// interpolation between the points.
    lo: Vec3,
    size: Vec3,
    rho: Grid,
    light: Grid,
}

/// Grid points along the object's box's longest side for [`DivergenceField`].
pub const DIVERGENCE_GRID: usize = 24;
/// Directions of T's quadrature (a 6 x 12 product rule: 72).
pub const DIVERGENCE_DIRECTIONS: (u32, u32) = (6, 12);
/// Below this mean attenuation over all directions a point receives nothing worth a sample.
pub const DARK: f32 = 1e-4;

impl DivergenceField {
    pub fn new(object: &Object) -> DivergenceField {
        use rayon::prelude::*;
        let (lo, hi) = object.mesh.bounds();
        let extent = hi - lo;
        let h = extent.max_element() / (DIVERGENCE_GRID - 1) as f32;
        let n = [0, 1, 2].map(|a| ((extent[a] / h).ceil() as usize + 1).max(2));
        let q = Quadrature::product(DIVERGENCE_DIRECTIONS.0, DIVERGENCE_DIRECTIONS.1);
        let step = density_step(object);
        let point = |i: usize| {
            let (x, y, z) = (i % n[0], (i / n[0]) % n[1], i / (n[0] * n[1]));
            lo + Vec3::new(x as f32, y as f32, z as f32) * h
        };
        // (T, int psi dw / 4 pi, inside) per grid point.
        let tl: Vec<(Vec3, f32, bool)> = (0..n[0] * n[1] * n[2])
            .into_par_iter()
            .map(|i| {
                let p = point(i);
                if !object.contains(p) {
                    return (Vec3::ZERO, 1.0, false);
                }
                let (mut t, mut l) = (Vec3::ZERO, 0.0f64);
                for (d, w) in q.directions.iter().zip(&q.weights) {
                    let dir = Vec3::new(d[0] as f32, d[1] as f32, d[2] as f32);
                    let tau = optical_depth(object, p, dir, step).into_iter().fold(f64::INFINITY, f64::min);
                    let psi = (-tau).exp();
                    t += dir * (psi * w) as f32;
                    l += psi * w;
                }
                (t, (l / (4.0 * std::f64::consts::PI)) as f32, true)
            })
            .collect();
        let at = |x: usize, y: usize, z: usize| tl[(z * n[1] + y) * n[0] + x].0;
        let mut rho = vec![0.0f32; tl.len()];
        for z in 0..n[2] {
            for y in 0..n[1] {
                for x in 0..n[0] {
                    // Central differences where both neighbours exist, one-sided at the box's faces.
                    let d = |c: usize, m: usize| -> (usize, usize, f32) {
                        let (a, b) = (c.saturating_sub(1), (c + 1).min(m - 1));
                        (a, b, (b - a) as f32 * h)
                    };
                    let (x0, x1, dx) = d(x, n[0]);
                    let (y0, y1, dy) = d(y, n[1]);
                    let (z0, z1, dz) = d(z, n[2]);
                    let div = (at(x1, y, z).x - at(x0, y, z).x) / dx
                        + (at(x, y1, z).y - at(x, y0, z).y) / dy
                        + (at(x, y, z1).z - at(x, y, z0).z) / dz;
                    rho[(z * n[1] + y) * n[0] + x] = div.abs();
                }
            }
        }
        let mut inside: Vec<f32> = rho.iter().zip(&tl).filter(|(_, t)| t.2).map(|(r, _)| *r).collect();
        inside.sort_by(|a, b| a.total_cmp(b));
        let (min, top) = match inside.len() {
            0 => (0.0, 1.0),
            k => (inside[0], inside[((k - 1) as f64 * 0.95) as usize]),
        };
        let span = (top - min).max(1e-12);
        let grid = |data: Vec<f32>| Grid { dims: n.map(|k| k as u32), data, file: Default::default() };
        DivergenceField {
            lo: lo - Vec3::splat(0.5 * h),
            size: Vec3::new(n[0] as f32, n[1] as f32, n[2] as f32) * h,
            rho: grid(rho.iter().map(|r| ((r - min) / span).clamp(0.0, 1.0)).collect()),
            light: grid(tl.iter().map(|t| t.1).collect()),
        }
    }

    /// The radius scale at p: 2 where rho is least, 1/2 where it is greatest.
    pub fn radius_scale(&self, p: Vec3) -> f32 {
        2.0 - 1.5 * self.rho.sample((p - self.lo) / self.size)
    }

    /// Whether p receives too little light for a sample (int psi dw / 4 pi < [`DARK`]).
    pub fn dark(&self, p: Vec3) -> bool {
        self.light.sample((p - self.lo) / self.size) < DARK
    }
}

/// The radius scale at p (None: no sample there) under a heuristic.
pub(super) enum Scale {
    Depth(f32),
    Divergence(DivergenceField),
}

impl Scale {
    fn at(&self, object: &Object, p: Vec3) -> Option<f32> {
        match self {
            Scale::Depth(mfp) => Some(radius_scale(depth_below_surface(object, p), *mfp)),
            Scale::Divergence(f) => (!f.dark(p)).then(|| f.radius_scale(p)),
        }
    }
}

/// A Poisson-disk set of about `count` samples inside `object` (module docs), deterministic for
/// `seed`, with the radius varying by the depth heuristic.
pub fn poisson_samples(object: &Object, count: u32, seed: u64) -> Vec<Sample> {
    poisson_samples_with(object, count, seed, Heuristic::Depth)
}

/// [`poisson_samples`] under either density heuristic.
pub fn poisson_samples_with(object: &Object, count: u32, seed: u64, heuristic: Heuristic) -> Vec<Sample> {
    poisson_draw(object, count, seed, heuristic, Placement::Volume).0
}

/// [`poisson_samples_with`] with the darts anywhere inside or on the offset surfaces, and the
/// base radius r0 its last draw used (unit: the mesh's); the offset surfaces of
/// [`Placement::Layers`] lie [`LAYER_SPACING`] r0 apart.
pub fn poisson_draw(
    object: &Object,
    count: u32,
    seed: u64,
    heuristic: Heuristic,
    placement: Placement,
) -> (Vec<Sample>, f32) {
    let scale = match heuristic {
        Heuristic::Depth => Scale::Depth(depth_mfp(object)),
        Heuristic::Divergence => Scale::Divergence(DivergenceField::new(object)),
    };
    let mut r0 = first_radius(object, count, seed, &scale);
    // The packing fraction varies with the shape (thin parts and corners fill less): up to
    // DRAWS draws until within 10%. The count goes as r0^-3 in a solid, but as r0^-2 where the
    // disks are wider than the medium is thick (a slab 1e-7 thick drew 65261 samples for 4000
    // when every step took the cube root), so after the first step the exponent is measured
    // from the last two draws (a secant in log-log), within [1, 3].
    const DRAWS: usize = 5;
    let mut out = Vec::new();
    let mut last: Option<(f64, f64)> = None;
    for draw in 0..DRAWS {
        out = dart_throw(object, count, seed, r0, &scale, placement);
        let n = out.len().max(1) as f64;
        let ratio = n / count.max(1) as f64;
        if (ratio - 1.0).abs() < 0.1 || draw == DRAWS - 1 {
            break;
        }
        let exponent = match last {
            Some((r_prev, n_prev)) if (r0 as f64 - r_prev).abs() > 1e-6 * r_prev && n != n_prev => {
                (-(n / n_prev).ln() / (r0 as f64 / r_prev).ln()).clamp(1.0, 3.0)
            }
            _ => 3.0,
        };
        last = Some((r0 as f64, n));
        r0 *= ratio.powf(1.0 / exponent) as f32;
    }
    (out, r0)
}

/// The mean free path the depth heuristic measures depth in: of the densest material at density
/// 1 (unit: the mesh's), or the box's longest side where nothing extinguishes.
fn depth_mfp(object: &Object) -> f32 {
    let st = max_sigma_t(object);
    let (lo, hi) = object.mesh.bounds();
    if st > 0.0 {
        1.0 / st
    } else {
        (hi - lo).max_element()
    }
}

/// The base radius r0 whose packing holds `count` samples: count = PACKING sum over the volume
/// of 1 / ((4/3) pi (r/2)^3) with r = r0 s(x), the sum estimated from 4096 darts inside the mesh
/// (a stream of `seed`: deterministic).
fn first_radius(object: &Object, count: u32, seed: u64, scale: &Scale) -> f32 {
    let (lo, hi) = object.mesh.bounds();
    let extent = hi - lo;
    let mut rng = Pcg32::new(seed, 17);
    let probes = 4096;
    let box_volume = (extent.x * extent.y * extent.z) as f64;
    let mut inv_cube = 0.0f64;
    for _ in 0..probes {
        let p = dart(&mut rng, lo, extent);
        if object.contains(p) {
            if let Some(s) = scale.at(object, p) {
                inv_cube += 1.0 / (s as f64).powi(3);
            }
        }
    }
    let integral = inv_cube * box_volume / probes as f64;
    (2.0 * (PACKING * integral / (count.max(1) as f64 * 4.0 / 3.0 * std::f64::consts::PI)).cbrt()) as f32
}

/// How far to trust a sample set, before it is drawn: the spacing of the samples nearest the
/// surface, where single scattering is seen and varies fastest, in mean free paths of the
/// densest material at its densest point. Both heuristics give the surface's samples radius
/// r0 / 2 (the thesis's r/2); r0 is the depth heuristic's first estimate for the count (the
/// draw corrects it by at most the cube root of the count's ratio, within 10%), so a render
/// and `scatterlab render`'s early warning state the same figure without drawing the set twice.
///
/// Measured (docs/sh-single.md, "How far to trust it"): on the icosphere of radius 0.8 under a
/// sun and a sky (albedo 0.99, g 0, 24 x 24 against `single`, the object's pixels), energy /
/// relL2 at a surface spacing of 0.11 mean free paths 0.983 / 0.030, 0.18 0.964 / 0.045, 0.29
/// 0.918 / 0.087, 0.38 0.879 / 0.134, 0.60 0.811 / 0.196, 0.87 0.780 / 0.227, 0.95 0.698 / 0.304,
/// 2.2 0.557 / 0.493, whatever sigma_t (4, 20, 60) and sample count gave the spacing (the sun alone
/// or the sky alone lose as much). The spacing is not the whole story: on the shipped scenes at
/// 32 x 32 the error hardly follows it (jade-and-wax 1.048 / 0.101 at 0.65 and at 0.41, the
/// networks paper's cloud 0.952 / 0.167 at 0.51, the cloud 0.953 / 0.171 at 0.36, the
/// homogeneous sphere 0.918 / 0.216 at 0.20), so only a spacing past where every measurement
/// was far off warns. Separately, a forward-peaked medium (g 0.9) under an environment light
/// loses more: 0.87-0.91 of the energy at optical radius 3.2 whatever the samples, 0.39-0.59 at
/// 16 (the sky's in-scattering varies across a Gaussian in a way its gradient term does not
/// follow); g 0.6 and -0.9, g 0.9 under the sun alone, or g 0.9 at optical radius 0.4 were
/// within 2% of g 0.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SampleTrust {
    pub requested: u32,
    /// The estimated base Poisson radius r0 (unit: the mesh's).
    pub r0: f64,
    /// Mean free paths between neighbouring samples at the surface: sigma_t,max x r0 / 2.
    pub surface_spacing: f64,
    /// The samples that bring the spacing to the validated one (None: past the knob's range).
    pub samples_needed: Option<u32>,
    /// Whether any material scatters (albedo > 0): where none does, sh-single draws the surfaces'
    /// terms alone, exactly, and the spacing does not matter.
    pub scatters: bool,
    /// The largest g of a scattering material at or past [`SampleTrust::FORWARD_G`] where an
    /// environment light shines on a medium at least [`SampleTrust::FORWARD_DEPTH`] optically
    /// thick from the middle of its box's thinnest side (the weak spot above), else None.
    pub forward_under_sky: Option<f32>,
}

impl SampleTrust {
    /// Mean free paths a surface spacing sh-single was validated at: 0.18 at its default 4000
    /// samples on the icosphere of sigma_t 4 (docs/sh-single.md: relL2 0.038-0.045, energy 0.96-0.97).
    pub const VALIDATED: f64 = 0.2;
    /// Past this, a warning: from 0.87 on the icosphere lost 22-30% of the energy at five times
    /// the validated relL2, where the shipped scenes at 0.36-0.65 were within 5% of the energy.
    pub const WARN: f64 = 0.75;
    /// The asymmetry from which forward scattering under a sky is warned of: between the
    /// measured 0.6 (as g 0) and 0.9 (9% to 60% dark); a guess between two measurements.
    pub const FORWARD_G: f32 = 0.8;
    /// The optical radius (half the box's thinnest side, in mean free paths at the densest)
    /// from which it is: between the measured 0.4 (as g 0) and 3.2 (9-13% dark); a guess.
    pub const FORWARD_DEPTH: f64 = 1.0;
    /// Mean free paths apart past which the image was measured too bright, not too dark.
    pub const BRIGHT: f64 = 4.0;
    /// `sh-single.samples`' largest value.
    pub const MAX_SAMPLES: u32 = 1 << 20;

    /// The trust of `count` samples requested in `object` of the object scene `os`, for `seed`.
    pub fn of(os: &Scene, object: &Object, count: u32, seed: u64) -> SampleTrust {
        let r0 = first_radius(object, count, seed, &Scale::Depth(depth_mfp(object))) as f64;
        let sigma = max_sigma_t(object) as f64 * os.max_density() as f64;
        let surface_spacing = sigma * r0 / 2.0;
        let scattering = || object.materials.iter().filter(|m| m.albedo.max_element() > 0.0);
        let sky = os.lights.iter().any(|l| matches!(l, Light::Environment { .. }));
        let g = scattering().map(|m| m.g).fold(f32::NEG_INFINITY, f32::max);
        let (lo, hi) = object.mesh.bounds();
        let optical_radius = sigma * (hi - lo).min_element() as f64 / 2.0;
        SampleTrust {
            requested: count,
            r0,
            surface_spacing,
            samples_needed: crate::solvers::interface::count_for_spacing(
                count,
                surface_spacing,
                Self::VALIDATED,
                Self::MAX_SAMPLES,
            ),
            scatters: scattering().next().is_some(),
            forward_under_sky: (sky && g >= Self::FORWARD_G && optical_radius >= Self::FORWARD_DEPTH).then_some(g),
        }
    }

    pub fn within(&self) -> bool {
        !self.scatters || (self.surface_spacing <= Self::VALIDATED * 1.001 && self.forward_under_sky.is_none())
    }

    /// The one-line figure for a render's summary.
    pub fn line(&self) -> String {
        format!(
            "sample trust: the samples nearest the surface stand {:.2} mean free paths apart at the densest ({} \
             requested, r0 {:.4}; validated at <= {}){}{}",
            self.surface_spacing,
            self.requested,
            self.r0,
            Self::VALIDATED,
            match self.forward_under_sky {
                Some(g) if self.scatters => format!(", g {g} under an environment light"),
                _ => String::new(),
            },
            if self.within() { "" } else { ": OUTSIDE" }
        )
    }

    /// The warnings a sample set too sparse for its medium, or a medium at the method's weak
    /// spot, carries: the figure, the error measured nearest it, and what fixes it.
    pub fn warnings(&self) -> Vec<String> {
        if !self.scatters {
            return Vec::new();
        }
        let mut out = Vec::new();
        if self.surface_spacing > Self::WARN || self.surface_spacing.is_nan() {
            let fix = match self.samples_needed {
                Some(n) => format!("set sh-single.samples={n}"),
                None => format!(
                    "no sh-single.samples up to {} serves (the medium is too dense for its Gaussians); use single",
                    Self::MAX_SAMPLES
                ),
            };
            // Far past it the bias turns: too bright, not too dark (the sphere of radius 0.45,
            // albedo 0.9, sun and sky, 4000 samples, against single: 0.91 of its energy at 0.7
            // and 1.8 apart, 1.06 at 4.6, 2.1 at 13.7, 14 at 131, 1430 at 1.4e4).
            let bright = if self.surface_spacing > Self::BRIGHT {
                "; this far apart it is too bright (on a sphere against single: 1.06x its energy at 4.6 apart, 2.1x at \
                 13.7, 1430x at 1.4e4)"
            } else {
                ""
            };
            out.push(format!(
                "sh-single: the samples nearest the surface stand {:.2} mean free paths apart, above the {} sh-single \
                 was validated at (measured against single on a dense sphere: 0.87-0.95 apart gave 0.70-0.78 of its \
                 energy and relL2 0.23-0.30, 2.2 apart 0.56 and 0.49){bright}; {fix}",
                self.surface_spacing,
                Self::VALIDATED
            ));
        }
        if let Some(g) = self.forward_under_sky {
            out.push(format!(
                "sh-single: g {g} under an environment light is the method's weak spot (measured against single at \
                 g 0.9: 0.87-0.91 of its energy at optical radius 3, 0.39-0.59 at 16, whatever the samples); use single"
            ));
        }
        out
    }
}

/// One dart-throwing draw of radius scale `r0` (module docs).
pub(super) fn dart_throw(
    object: &Object,
    count: u32,
    seed: u64,
    r0: f32,
    scale: &Scale,
    placement: Placement,
) -> Vec<Sample> {
    let (lo, hi) = object.mesh.bounds();
    let extent = hi - lo;
    let mut rng = Pcg32::new(seed, 18);
    // A dense grid of cell 2 r0 (the largest radius): two samples conflict within the mean of
    // their radii, at most 2 r0, so a candidate's conflicts lie in its own cell and the 26
    // around it.
    let cell = 2.0 * r0;
    let dims = (extent / cell).ceil().as_uvec3().max(glam::UVec3::ONE);
    let key = |p: Vec3| ((p - lo) / cell).floor().as_ivec3().clamp(glam::IVec3::ZERO, dims.as_ivec3() - 1);
    let index = |c: glam::IVec3| (c.z as usize * dims.y as usize + c.y as usize) * dims.x as usize + c.x as usize;
    let mut grid: Vec<Vec<u32>> = vec![Vec::new(); dims.x as usize * dims.y as usize * dims.z as usize];
    let mut out: Vec<Sample> = Vec::new();
    // Whether a sample of radius r at p would lie closer to a kept one than their mean radius.
    let conflicts = |grid: &Vec<Vec<u32>>, out: &Vec<Sample>, p: Vec3, r: f32| {
        let c = key(p);
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let n = c + glam::IVec3::new(dx, dy, dz);
                    if n.cmplt(glam::IVec3::ZERO).any() || n.cmpge(dims.as_ivec3()).any() {
                        continue;
                    }
                    for &j in &grid[index(n)] {
                        let s = &out[j as usize];
                        if s.position.distance_squared(p) < (0.5 * (r + s.radius)).powi(2) {
                            return true;
                        }
                    }
                }
            }
        }
        false
    };
    // The darts in batches: each batch's tests that do not depend on the darts before it in the
    // batch run in parallel, then the batch is accepted in order, so the set is the one a dart
    // at a time would draw, bit for bit (test `poisson_samples_do_not_depend_on_the_threads`).
    // In parallel, against the set as the batch starts: the cheap rejection (a conflict even at
    // the smallest radius r0 / 2, most darts once the set fills), the inside test and the radius
    // scale (the 26 rays of the depth, or the divergence grid), which are functions of the
    // point alone. The set only grows, so a conflict with it as the batch starts is a conflict
    // with it as the dart's turn comes; the dart's turn repeats the conflict tests against the
    // set as it is then.
    use rayon::prelude::*;
    let total = count.max(1) * DARTS_PER_SAMPLE;
    let mut thrown = 0;
    while thrown < total {
        let batch = DART_BATCH.min(total - thrown);
        thrown += batch;
        let darts: Vec<Vec3> = (0..batch).map(|_| dart(&mut rng, lo, extent)).collect();
        let placed: Vec<Option<(Vec3, f32)>> = darts
            .par_iter()
            .map(|&p| {
                let p = match placement {
                    Placement::Volume => p,
                    Placement::Layers => onto_layer(object, p, LAYER_SPACING * r0)?,
                };
                if conflicts(&grid, &out, p, 0.5 * r0) || !object.contains(p) {
                    return None;
                }
                Some((p, scale.at(object, p)?))
            })
            .collect();
        for (p, s) in placed.into_iter().flatten() {
            let r = r0 * s;
            if conflicts(&grid, &out, p, 0.5 * r0) || conflicts(&grid, &out, p, r) {
                continue;
            }
            grid[index(key(p))].push(out.len() as u32);
            let material = object.material_at(p).unwrap_or(0);
            out.push(Sample { position: p, radius: r, material });
        }
    }
    out
}

/// The dart `p` moved onto the nearest offset surface (thesis 3.2.2): the level set of the
/// distance to the mesh at depth k `delta`, k >= 1, reached along the line from `p`'s nearest
/// surface point through `p` (the distance's gradient). A volume-uniform dart so lands on
/// each layer with a density uniform in its area (the slab it comes from is delta thick). The
/// thesis builds each layer by marching cubes on the distance field; this samples the same
/// level sets without their meshes. `None` outside the mesh, or where the moved point's own
/// distance is not its layer's (within delta / 4: past a concave edge, where the line meets
/// another part of the surface first).
pub(super) fn onto_layer(object: &Object, p: Vec3, delta: f32) -> Option<Vec3> {
    if !object.contains(p) {
        return None;
    }
    let (c, d) = object.bvh.closest_point(p)?;
    if d <= 0.0 {
        return None;
    }
    let depth = (d / delta).round().max(1.0) * delta;
    let q = c + (p - c) * (depth / d);
    let (_, dq) = object.bvh.closest_point(q)?;
    ((dq - depth).abs() <= 0.25 * delta).then_some(q)
}

/// Darts tested in parallel before they are accepted in order ([`dart_throw`]): large enough
/// to keep every core busy, small against a set of thousands (each dart that passes the
/// parallel tests but meets a sample accepted earlier in its batch cost its depth for
/// nothing).
pub(super) const DART_BATCH: u32 = 4096;

/// Optical depth per channel from `p` (inside the object) along unit `w` to infinity: each
/// interval inside an object at its material's extinction times the density integral (exact
/// for constant density, the midpoint rule in steps of `step` otherwise), crossing every
/// surface straight (the attenuation psi of eq. 3.2 has no refraction).
pub fn optical_depth(object: &Object, p: Vec3, w: Vec3, step: f32) -> [f64; 3] {
    optical_depth_within(object, p, w, f32::INFINITY, step)
}

/// [`optical_depth`] over the first `t_max` of the ray only (toward a point light inside).
pub fn optical_depth_within(object: &Object, p: Vec3, w: Vec3, t_max: f32, step: f32) -> [f64; 3] {
    let mut tau = [0.0f64; 3];
    let Some(mut mat) = object.material_at(p) else { return tau };
    // The segment inside an object runs from the last crossing `t` to the next (or t_max).
    let (mut inside, mut t) = (true, 0.0f32);
    let mut add = |mat: usize, t0: f32, t1: f32| {
        let m = &object.materials[mat];
        let field = &object.fields[m.field];
        let integral = match field.density {
            Density::Constant => (t1 - t0) as f64,
            _ => {
                let n = ((t1 - t0) / step).ceil().max(1.0) as usize;
                let dt = (t1 - t0) / n as f32;
                (0..n).map(|i| field.density_at(p + w * (t0 + (i as f32 + 0.5) * dt)) as f64 * dt as f64).sum()
            }
        };
        for (t, sigma) in tau.iter_mut().zip(m.sigma_t.to_array()) {
            *t += sigma as f64 * integral;
        }
    };
    for h in crossings(object, p, w) {
        if h.t >= t_max {
            break;
        }
        if inside {
            add(mat, t, h.t);
        }
        inside = h.normal.dot(w) < 0.0;
        if inside {
            mat = object.bvh.tag(h.triangle) as usize;
        }
        t = h.t;
    }
    if inside && t_max.is_finite() && t < t_max {
        add(mat, t, t_max);
    }
    tau
}

/// A sample's parameters (thesis 3.3): psi's coefficients per channel ([c][k], order^2 each),
/// the Gaussian's a_i (gamma(x) = exp(-a_i |x - b_i|^2), full width at half maximum
/// `width_scale` times the Poisson radius, 3.3.2) and sigma_s at the sample, 1/unit.
#[derive(Clone, Debug)]
pub struct SampleParams {
    pub sh: [Vec<f32>; 3],
    /// With a refractive object: psi times the boundary factor of the straight ray (Fresnel
    /// and the radiance's change of index at each surface crossed), projected the same way:
    /// what the environment's in-scattering uses (a light's boundary factor is exact, per
    /// light, on the host).
    pub sh_env: Option<[Vec<f32>; 3]>,
    pub a: f32,
    pub sigma_s: [f32; 3],
}

/// [`SampleParams`] of each sample: psi projected with `q` (many directions; the thesis uses
/// 128-256, 3.3.1), optical depths by [`optical_depth`] with `step` on the host.
pub fn sample_params(
    object: &Object,
    samples: &[Sample],
    order: usize,
    q: &Quadrature,
    width_scale: f32,
    step: f32,
) -> Vec<SampleParams> {
    use rayon::prelude::*;
    let taus: Vec<Vec<[f64; 3]>> = samples
        .par_iter()
        .map(|s| {
            q.directions
                .iter()
                .map(|d| optical_depth(object, s.position, glam::DVec3::from_array(*d).as_vec3(), step))
                .collect()
        })
        .collect();
    let refractive = object.refractive();
    project_params(object, samples, order, q, width_scale, refractive, |i, k| {
        let d = q.directions[k];
        let ft = if refractive {
            boundary_factor_within(object, samples[i].position, glam::DVec3::from_array(d).as_vec3(), f32::INFINITY)
        } else {
            1.0
        };
        (taus[i][k], ft)
    })
}

/// Push constants of glsl/sh_single/depth.comp.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct DepthPush {
    pub samples: u32,
    pub dirs: u32,
    pub step: f32,
    pub first: u32,
}

/// glsl/sh_single/depth.comp: the optical depth per (sample, direction) on the device.
pub const DEPTH: Kernel =
    Kernel { shader: shader!("sh_single/depth"), push_bytes: std::mem::size_of::<DepthPush>(), spec: MESH_SPEC };

/// The kernels of sh-single built so far (the registry's reflection checks hold them too).
pub fn kernels() -> Vec<Kernel> {
    vec![DEPTH, RENDER]
}

/// (sample, direction) pairs per depth dispatch: the depth buffer holds one chunk's, 18 MB
/// whatever the sample count ([`depth_chunk`]).
pub(super) const DEPTH_PAIRS: usize = 4096 * 288;

/// Samples per depth dispatch with `dirs` directions: at most 4096.
pub fn depth_chunk(dirs: usize) -> usize {
    (DEPTH_PAIRS / dirs.max(1)).clamp(1, 4096)
}

/// [`sample_params`] with the optical depths marched on the device (glsl/sh_single/depth.comp,
/// one invocation per sample and direction, [`depth_chunk`] samples per dispatch; `gs` the
/// scene uploaded with its mesh), the projection on the host. Also returns the bytes of the
/// buffers it allocated.
#[allow(clippy::too_many_arguments)]
pub fn device_params(
    gpu: &Gpu,
    gs: &GpuScene,
    object: &Object,
    samples: &[Sample],
    order: usize,
    q: &Quadrature,
    width_scale: f32,
    step: f32,
) -> Result<(Vec<SampleParams>, u64), SolverError> {
    let pipeline = gpu.pipeline(&DEPTH, &gs.modelled.mesh_spec())?;
    let points: Vec<[f32; 4]> =
        samples.iter().map(|s| [s.position.x, s.position.y, s.position.z, f32::from_bits(s.material as u32)]).collect();
    let dirs: Vec<[f32; 4]> = q.directions.iter().map(|d| [d[0] as f32, d[1] as f32, d[2] as f32, 0.0]).collect();
    let n = dirs.len();
    let point_buf = gpu.buffer_with("sh-single samples", &points)?;
    let dir_buf = gpu.buffer_with("sh-single directions", &dirs)?;
    let chunk = depth_chunk(n);
    let depth_buf = gpu.buffer("sh-single depths", (samples.len().min(chunk) * n * 16) as u64)?;
    let bytes = point_buf.size() + dir_buf.size() + depth_buf.size();
    let mut depths: Vec<[f32; 4]> = Vec::with_capacity(samples.len() * n);
    for first in (0..samples.len()).step_by(chunk) {
        let count = (samples.len() - first).min(chunk);
        let pass = gs
            .bind_mesh(Pass::new("sh_single.depth", QueueRole::Trace, &pipeline))
            .read(3, &point_buf)
            .read(4, &dir_buf)
            .write(5, &depth_buf)
            .push(&DepthPush { samples: count as u32, dirs: n as u32, step, first: first as u32 })
            .cover([(count * n) as u32, 1, 1]);
        let point = gpu.submit(QueueRole::Trace, &[pass], &[])?;
        gpu.wait(point)?;
        let chunk: Vec<[f32; 4]> = gpu.read_buffer_as(&depth_buf)?;
        depths.extend_from_slice(&chunk[..count * n]);
    }
    let params = project_params(object, samples, order, q, width_scale, object.refractive(), |i, k| {
        let t = depths[i * n + k];
        ([t[0] as f64, t[1] as f64, t[2] as f64], t[3] as f64)
    });
    Ok((params, bytes))
}

/// The parameters from the optical depth and boundary factor `tau(i, k)` of sample i toward
/// direction k of `q` (the boundary factor projected only with a refractive object).
pub(super) fn project_params(
    object: &Object,
    samples: &[Sample],
    order: usize,
    q: &Quadrature,
    width_scale: f32,
    refractive: bool,
    tau: impl Fn(usize, usize) -> ([f64; 3], f64) + Sync,
) -> Vec<SampleParams> {
    use rayon::prelude::*;
    // The basis at every direction, once.
    let basis: Vec<Vec<f64>> = q.directions.iter().map(|d| sh::basis(order, *d)).collect();
    let project = |f: &dyn Fn(usize) -> f64| -> Vec<f32> {
        let mut coeffs = vec![0.0f64; sh::coefficients(order)];
        for (k, (y, w)) in basis.iter().zip(&q.weights).enumerate() {
            let v = f(k) * w;
            for (o, yk) in coeffs.iter_mut().zip(y) {
                *o += v * yk;
            }
        }
        coeffs.iter().map(|x| *x as f32).collect()
    };
    samples
        .par_iter()
        .enumerate()
        .map(|(i, s)| {
            let values: Vec<([f64; 3], f64)> = (0..q.directions.len()).map(|k| tau(i, k)).collect();
            let sh: [Vec<f32>; 3] = std::array::from_fn(|c| project(&|k| (-values[k].0[c]).exp()));
            let sh_env =
                refractive.then(|| std::array::from_fn(|c| project(&|k| (-values[k].0[c]).exp() * values[k].1)));
            let a = gaussian_a(s, width_scale);
            let mat = &object.materials[s.material];
            let dens = object.fields[mat.field].density_at(s.position);
            let sigma_s = std::array::from_fn(|c| mat.sigma_t[c] * mat.albedo[c] * dens);
            SampleParams { sh, sh_env, a, sigma_s }
        })
        .collect()
}
