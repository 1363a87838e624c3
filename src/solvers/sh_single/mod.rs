//! `sh-single` (issue 17; thesis chapter 3): single scattering from per-sample, spherical-
//! harmonics-compressed attenuation at Poisson-disk samples of an object's interior.
//!
//! A preprocessing pass draws the samples (thesis 3.2, simplified below) and each sample's
//! parameters (3.3): the attenuation psi_i(w) = exp(-tau(b_i, w)) to the boundary, marched on
//! the device and projected on real spherical harmonics of order L per channel (eq. 3.4,
//! src/physics/sh.rs), the Gaussian width from the sample's radius (3.3.2), sigma_s at the
//! sample, and the partition weight ([`partition_weights`]). A render pass (3.4,
//! glsl/sh_single/render.comp) integrates every Gaussian along each camera ray in closed form.
//! Where it departs from the thesis, and the measurements that decided each departure, are in
//! docs/sh-single.md: the loop-limiter budget of the render pass, partition weights that hold
//! in the mean over the object, the coverage normalisation along each ray ([`resolve`]), and
//! the camera's and lights' attenuation varying across each Gaussian ([`tau_gradient`]). A v1
//! `[medium]` is sampled as its box ([`Object::box_of`]). `single` is its exact ground truth.
//!
//! **Sampling, simplified.** The thesis samples layers (offset surfaces of the mesh) with a
//! density from the divergence of the light-transport field, then draws a Poisson-disk set whose
//! radius varies between r/2 and 2r with that density (3.2.2-3.2.4). Here darts are uniform in
//! the volume (no offset surfaces), and the density heuristic (`sh_single.density`) is the
//! thesis's divergence ([`DivergenceField`]) where a density varies, and for constant
//! densities the depth below the surface in mean free paths: a sample's radius is r0 (0.5 + 1.5
//! min(1, depth / (3 mean free paths))), so within a mean free path of the surface, where
//! single scattering is seen and varies fastest, samples are up to 4x closer than deep inside
//! (the thesis's r/2 .. 2r). The set is drawn by dart throwing (candidates uniform in the
//! mesh's box, kept inside the mesh, accepted where no kept sample lies closer than the mean of
//! the two radii; a hash grid finds the neighbours), deterministic for a seed. r0 is chosen so
//! that the expected count of such a packing is the requested count, and corrected (at most
//! twice) by the cube root of the count's ratio until within 10% of it.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use serde::Serialize;

use crate::gpu::{Gpu, Kernel, Pass, QueueRole};
use crate::output::Image;
use crate::physics::quadrature::Quadrature;
use crate::physics::rng::Pcg32;
use crate::physics::sh;
use crate::scene::{Density, Grid, Light, Object, Scene};
use crate::solvers::interface::{
    Knob, Knobs, Progress, Range, RenderOutput, RenderReport, RenderRequest, Rung, Solver, SolverError, Stats, Variant,
};
use crate::solvers::parts::gpu_scene::{self, GpuScene, MESH_SPEC};

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
fn crossings(object: &Object, p: Vec3, w: Vec3) -> impl Iterator<Item = crate::scene::bvh::Hit> + '_ {
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
fn dart(rng: &mut Pcg32, lo: Vec3, extent: Vec3) -> Vec3 {
    lo + Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * extent
}

/// The largest extinction (any channel, density 1) of the object's materials, 1/unit.
fn max_sigma_t(object: &Object) -> f32 {
    object.materials.iter().map(|m| m.sigma_t.max_element()).fold(0.0, f32::max)
}

/// Radius scale at depth `depth` below the surface (module docs): 0.5 at the surface, 2 from
/// 3 mean free paths on.
fn radius_scale(depth: f32, mfp: f32) -> f32 {
    0.5 + 1.5 * (depth / (3.0 * mfp)).clamp(0.0, 1.0)
}

/// Random sequential addition of hard spheres of diameter d fills about 30% of space when
/// darts run out well before the jamming limit (38%): what sizes r0 for a requested count.
const PACKING: f64 = 0.3;

/// Darts per requested sample before the set is taken as full.
const DARTS_PER_SAMPLE: u32 = 40;

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
enum Scale {
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
    let (lo, hi) = object.mesh.bounds();
    let extent = hi - lo;
    let st = max_sigma_t(object);
    let mfp = if st > 0.0 { 1.0 / st } else { extent.max_element() };
    let scale = match heuristic {
        Heuristic::Depth => Scale::Depth(mfp),
        Heuristic::Divergence => Scale::Divergence(DivergenceField::new(object)),
    };
    let mut rng = Pcg32::new(seed, 17);
    // r0 from the expected packing: count = PACKING sum over the volume of 1 / ((4/3) pi (r/2)^3)
    // with r = r0 s(x), estimated from darts inside the mesh.
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
    let mut r0 = (2.0 * (PACKING * integral / (count.max(1) as f64 * 4.0 / 3.0 * std::f64::consts::PI)).cbrt()) as f32;
    // The packing fraction varies with the shape (thin parts and corners fill less): up to
    // three draws, r0 rescaled by the cube root of the count's ratio, until within 10%.
    let mut out = Vec::new();
    for draw in 0..3 {
        out = dart_throw(object, count, seed, r0, &scale, placement);
        let ratio = out.len() as f64 / count.max(1) as f64;
        if (ratio - 1.0).abs() < 0.1 || draw == 2 {
            break;
        }
        r0 *= ratio.cbrt() as f32;
    }
    (out, r0)
}

/// One dart-throwing draw of radius scale `r0` (module docs).
fn dart_throw(object: &Object, count: u32, seed: u64, r0: f32, scale: &Scale, placement: Placement) -> Vec<Sample> {
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
fn onto_layer(object: &Object, p: Vec3, delta: f32) -> Option<Vec3> {
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
const DART_BATCH: u32 = 4096;

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
const DEPTH_PAIRS: usize = 4096 * 288;

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
fn project_params(
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

/// Push constants of glsl/sh_single/render.comp.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct RenderPush {
    pub first: u32,
    pub count: u32,
    pub order: u32,
    pub lights: u32,
    pub env: [f32; 4],
    /// 1 where each sample holds a second coefficient set for the environment (psi times the
    /// boundary factor: a refractive object under an environment).
    pub env_coeffs: u32,
    pub step: f32,
    pub pad: [u32; 2],
    /// With the index ([`GaussianIndex`]): its origin xyz and cell edge w (scene units), ...
    pub grid: [f32; 4],
    /// ... its cells per axis xyz, w = 1 (0: no index, every sample of the chunk visited) ...
    pub grid_dims: [u32; 4],
    /// ... and this chunk's box ([`chunk_box`]).
    pub box_lo: [f32; 4],
    pub box_hi: [f32; 4],
}

/// The truncation radius of a sample's Gaussian exp(-a r^2): the render pass skips it where
/// a h^2 > 14 (exp(-14) < 1e-6, the thesis's cut, 3.4.2), so it reaches sqrt(14 / a).
pub fn gaussian_reach(a: f32) -> f32 {
    (14.0 / a).sqrt()
}

/// Samples put in Morton order of their centres (10 bits per axis over `lo`..`hi`), so that a
/// render chunk of consecutive samples is a compact region whose box most camera rays miss
/// ([`GaussianIndex`]). The order is deterministic (a stable sort on the code).
pub fn sort_spatially(samples: &mut [Sample], lo: Vec3, hi: Vec3) {
    fn spread(v: u32) -> u64 {
        let mut x = v as u64 & 0x3ff;
        x = (x | (x << 16)) & 0x0300_00ff;
        x = (x | (x << 8)) & 0x0300_f00f;
        x = (x | (x << 4)) & 0x030c_30c3;
        (x | (x << 2)) & 0x0924_9249
    }
    let ext = (hi - lo).max(Vec3::splat(1e-30));
    samples.sort_by_cached_key(|s| {
        let q = ((s.position - lo) / ext * 1023.0).clamp(Vec3::ZERO, Vec3::splat(1023.0));
        spread(q.x as u32) | (spread(q.y as u32) << 1) | (spread(q.z as u32) << 2)
    });
}

/// A uniform grid over the samples' truncated Gaussians, so that the render pass visits only
/// the samples whose Gaussians a camera ray's segment passes through, instead of every sample
/// for every pixel (O(pixels x samples): 257 s at 64000 samples and 512^2 on lavapipe before).
/// Cell c lists, in increasing order, every sample whose ball of radius [`gaussian_reach`]
/// (padded by a thousandth of a cell against rounding) overlaps it: `items[starts[c] ..
/// starts[c + 1]]`. The render walks the cells along the segment (3D DDA) and counts a sample
/// in the one cell whose stretch of the segment holds the sample's closest point on it, so each
/// sample is integrated once, in closed form over the whole segment, as without the index.
#[derive(Clone, Debug)]
pub struct GaussianIndex {
    pub origin: Vec3,
    pub cell: f32,
    pub dims: [u32; 3],
    pub starts: Vec<u32>,
    pub items: Vec<u32>,
}

/// Cells per axis at most.
const INDEX_MAX_DIM: u32 = 128;

impl GaussianIndex {
    /// The index of samples at `centres` with reaches `reach`, cells about one Gaussian across
    /// (the median diameter; at most [`INDEX_MAX_DIM`] per axis).
    pub fn build(centres: &[Vec3], reach: &[f32]) -> GaussianIndex {
        assert_eq!(centres.len(), reach.len());
        let (mut lo, mut hi) = chunk_box(centres, reach, 0, centres.len());
        if centres.is_empty() {
            lo = Vec3::ZERO;
            hi = Vec3::ONE;
        }
        let extent = (hi - lo).max(Vec3::splat(1e-6));
        let mut diam: Vec<f32> = reach.iter().map(|r| 2.0 * r).collect();
        let median = if diam.is_empty() {
            extent.max_element()
        } else {
            let mid = diam.len() / 2;
            *diam.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1
        };
        let cell = median.max(extent.max_element() / INDEX_MAX_DIM as f32).max(1e-6);
        let dims = [0, 1, 2].map(|a| ((extent[a] / cell).ceil() as u32).clamp(1, INDEX_MAX_DIM));
        let n_cells = dims.iter().map(|d| *d as usize).product::<usize>();
        let pad = 1e-3 * cell;
        // Every cell the (padded) ball of centre c and radius r overlaps, by linear index.
        let cells_of_ball = |c: Vec3, r: f32, visit: &mut dyn FnMut(usize)| {
            let [rx, ry, rz] = [0, 1, 2].map(|a| {
                let f = |v: f32| (((v - lo[a]) / cell).floor().max(0.0) as u32).min(dims[a] - 1);
                [f(c[a] - r - pad), f(c[a] + r + pad)]
            });
            for z in rz[0]..=rz[1] {
                for y in ry[0]..=ry[1] {
                    for x in rx[0]..=rx[1] {
                        visit((x + dims[0] * (y + dims[1] * z)) as usize);
                    }
                }
            }
        };
        // Counting sort: counts per cell, their prefix sums, then the items in sample order.
        let mut starts = vec![0u32; n_cells + 1];
        for (c, r) in centres.iter().zip(reach) {
            cells_of_ball(*c, *r, &mut |k| starts[k + 1] += 1);
        }
        for k in 0..n_cells {
            starts[k + 1] += starts[k];
        }
        let mut fill = starts.clone();
        let mut items = vec![0u32; starts[n_cells] as usize];
        for (i, (c, r)) in centres.iter().zip(reach).enumerate() {
            cells_of_ball(*c, *r, &mut |k| {
                items[fill[k] as usize] = i as u32;
                fill[k] += 1;
            });
        }
        if items.is_empty() {
            items.push(0); // a buffer cannot be empty; no cell's range reaches it
        }
        GaussianIndex { origin: lo, cell, dims, starts, items }
    }

    /// Device bytes of its two buffers.
    pub fn bytes(&self) -> u64 {
        4 * (self.starts.len() + self.items.len()) as u64
    }
}

/// The exponent a of a sample's Gaussian exp(-a r^2), whose full width at half maximum is
/// `width_scale` times the sample's Poisson radius (thesis 3.3.2): the FWHM is
/// 2 sqrt(ln 2 / a), so a = 4 ln 2 / FWHM^2.
fn gaussian_a(s: &Sample, width_scale: f32) -> f32 {
    let fwhm = width_scale * s.radius;
    4.0 * std::f32::consts::LN_2 / (fwhm * fwhm)
}

/// The reach ([`gaussian_reach`]) of each sample's Gaussian.
pub fn sample_reach(samples: &[Sample], width_scale: f32) -> Vec<f32> {
    samples.iter().map(|s| gaussian_reach(gaussian_a(s, width_scale))).collect()
}

/// The box holding the balls of samples `first .. first + count` (a render chunk's: rays that
/// miss it skip the chunk).
pub fn chunk_box(centres: &[Vec3], reach: &[f32], first: usize, count: usize) -> (Vec3, Vec3) {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for (c, r) in centres[first..first + count].iter().zip(&reach[first..first + count]) {
        lo = lo.min(*c - Vec3::splat(*r));
        hi = hi.max(*c + Vec3::splat(*r));
    }
    (lo, hi)
}

/// glsl/sh_single/render.comp: the render pass (thesis 3.4).
pub const RENDER: Kernel =
    Kernel { shader: shader!("sh_single/render"), push_bytes: std::mem::size_of::<RenderPush>(), spec: MESH_SPEC };

/// Most samples per render dispatch.
const CHUNK: u32 = 2048;

// glsl/include/budget.glsl's LOOP_GUARD: past it llvmpipe's loop limiter may have fired.
use crate::solvers::parts::resumable::LOOP_GUARD;

/// How the render pass finds the samples whose Gaussians a camera segment passes through.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleIndex {
    /// Every sample of every chunk, for every pixel.
    None,
    /// Every sample of the chunks whose box ([`chunk_box`]) the segment crosses: the samples
    /// are in Morton order, so a chunk is a compact region.
    Boxes,
    /// [`GaussianIndex`]'s cells along the segment, within the chunks' boxes.
    Grid,
}

/// sh-single's settings (its knobs `order`, `samples`, `width_scale`, `seed`).
#[derive(Clone, Copy, Debug)]
pub struct ShSettings {
    /// Spherical-harmonics order L (bands 0 .. L - 1), 1 ..= 8.
    pub order: usize,
    /// Requested Poisson-disk samples.
    pub samples: u32,
    /// Gaussian full width at half maximum in Poisson radii.
    pub width_scale: f32,
    pub seed: u64,
    /// Directions psi is projected with (about; [`projection_quadrature`]).
    pub directions: u32,
    /// How the Poisson radius varies (`sh_single.density`).
    pub heuristic: Heuristic,
    /// How the render finds the samples a camera segment passes (`sh_single.index`).
    pub index: SampleIndex,
    pub placement: Placement,
}

impl ShSettings {
    fn parse(k: &Knobs, scene: &Scene) -> Result<ShSettings, SolverError> {
        Ok(ShSettings {
            order: k.get::<u32>("order")? as usize,
            samples: k.get("samples")?,
            width_scale: k.get("width_scale")?,
            seed: k.get_or("seed", scene.render.seed)?,
            directions: k.get("directions")?,
            index: match k.get::<String>("index")?.as_str() {
                "grid" => SampleIndex::Grid,
                "none" => SampleIndex::None,
                _ => SampleIndex::Boxes,
            },
            placement: match k.get::<String>("placement")?.as_str() {
                "layers" => Placement::Layers,
                _ => Placement::Volume,
            },
            heuristic: match k.get::<String>("density")?.as_str() {
                "divergence" => Heuristic::Divergence,
                "depth" => Heuristic::Depth,
                // auto: the divergence where a density varies (grids), whose gradients the
                // depth cannot see (cloud at 96^2: relL2 0.43 -> 0.19 at 2000 samples, 0.23 ->
                // 0.14 at 8000); the depth for constant densities, where it was as good or
                // slightly better (sphere sigma_t 4: 0.058 against 0.068 at 2000).
                _ => {
                    if !scene.features().homogeneous {
                        Heuristic::Divergence
                    } else {
                        Heuristic::Depth
                    }
                }
            },
        })
    }
}

/// What a render measured: samples requested and drawn, the order, bytes of the sample set on
/// the device (centres, widths, sigma_s, coefficients, light terms), the preprocessing
/// (sampling, optical depths, projection, light terms) and render times, wall clock.
#[derive(Clone, Debug, Serialize)]
pub struct ShStats {
    pub requested: u32,
    pub samples: usize,
    pub order: usize,
    /// Directions psi was projected with.
    pub directions: usize,
    pub sample_bytes: u64,
    pub preprocess_s: f64,
    pub render_s: f64,
    pub nonfinite_pixels: u32,
    /// Samples per render dispatch (halved from the first guess while a chain overflowed
    /// llvmpipe's loop guard) and the render dispatches run in all.
    pub chunk: u32,
    pub dispatches: u64,
    /// The preprocessing's parts: Poisson-disk sampling (host), optical depths (device) and
    /// their projection (host), the partition weights (host); the light terms are the rest.
    pub sampling_s: f64,
    pub depths_s: f64,
    pub weights_s: f64,
    /// The density heuristic the radii followed (`sh_single.density`: depth or divergence).
    pub density: &'static str,
}

/// The directions psi is projected with: an n x 2n product rule (Gauss-Legendre in the cosine,
/// uniform in azimuth) of about `directions` directions, n = round(sqrt(directions / 2)), at
/// least 2 (the default 288 is 12 x 24, which integrates the product of two order-8 functions
/// exactly; the thesis projects with 128 to 2048 Monte Carlo directions, 3.3.1 and table 3.1).
fn projection_quadrature(directions: u32) -> Quadrature {
    let n = ((directions as f64 / 2.0).sqrt().round() as usize).max(2);
    Quadrature::product(n as u32, 2 * n as u32)
}

/// The step of the chords' and optical depths' midpoint rule through grid densities: 1/256
/// of the object's box diagonal.
fn density_step(object: &Object) -> f32 {
    let (lo, hi) = object.mesh.bounds();
    (hi - lo).length() / 256.0
}

/// The scene sh-single renders: the scene's [[object]]s, or a v1 medium's box as an
/// index-matched object ([`Object::box_of`]; the method samples an object's interior).
fn object_scene(scene: &Scene) -> Scene {
    let mut s = scene.clone();
    if s.object.is_none() {
        s.object = Some(Object::box_of(&s.medium));
    }
    s
}

/// Point and directional lights as (position or travel direction, intensity or irradiance,
/// is a point light), and the constant environments' summed radiance.
fn split_lights(scene: &Scene) -> (Vec<(Vec3, Vec3, bool)>, Vec3) {
    let mut env = Vec3::ZERO;
    let mut lights = Vec::new();
    for l in &scene.lights {
        match l {
            Light::Point { position, intensity } => lights.push((*position, *intensity, true)),
            Light::Directional { direction, irradiance } => lights.push((*direction, *irradiance, false)),
            Light::Environment { radiance } => env += *radiance,
        }
    }
    (lights, env)
}

/// Whether each sample holds a second coefficient set for the environment (psi times the
/// boundary factor): a refractive object under an environment.
fn env_coefficients(os: &Scene) -> bool {
    os.object.as_ref().is_some_and(|o| o.refractive()) && split_lights(os).1.max_element() > 0.0
}

/// Device bytes of a render of `os` (the object scene) with `n` samples drawn: the scene with
/// its mesh, the depth pass's buffers, the sample set, the image. What [`render`] allocates.
fn device_bytes(os: &Scene, samples: &[Sample], set: &ShSettings) -> u64 {
    let n = samples.len();
    let order = set.order;
    // The grid index's two buffers, or two 16-byte stand-ins.
    let index = match set.index {
        SampleIndex::Grid => {
            let centres: Vec<Vec3> = samples.iter().map(|s| s.position).collect();
            GaussianIndex::build(&centres, &sample_reach(samples, set.width_scale)).bytes()
        }
        _ => 32,
    };
    let (lights, _) = split_lights(os);
    let env_set = env_coefficients(os);
    let dirs = projection_quadrature(set.directions).directions.len();
    let b = |bytes: usize| (bytes as u64).max(4);
    gpu_scene::scene_bytes(os)
        + b(n * 16)
        + b(dirs * 16)
        + b(n.min(depth_chunk(dirs)) * dirs * 16)
        + b(SAMPLE_WORDS * n * 16)
        + b(n * 3 * sh::coefficients(order) * 4 * if env_set { 2 } else { 1 })
        + b((LIGHT_WORDS * n * lights.len()).max(1) * 16)
        + os.render.width as u64 * os.render.height as u64 * 64
        + 16
        + index
}

/// The boundary factor of the straight ray from `p` (inside the object) along `w`, as `single`'s
/// shadow rays take it (glsl/view/march.comp, optical_depth; thesis 3.1.1): at each refracting
/// surface crossed, the Fresnel transmittance 1 - F at the ray's own angle (eta = ior where it
/// leaves an object, 1 / ior where it enters one; total internal reflection: 0) times the
/// radiance's change of index, ior^2 where the light enters an object (the ray leaves it) and
/// 1 / ior^2 where it leaves one; the camera's entry divides the ior^2 out again. Only the
/// crossings within `t_max` (toward a point light inside an object).
fn boundary_factor_within(object: &Object, p: Vec3, w: Vec3, t_max: f32) -> f64 {
    let mut inside = true;
    let mut factor = 1.0f64;
    for h in crossings(object, p, w).take_while(|h| h.t < t_max) {
        let ior = object.materials[object.bvh.tag(h.triangle) as usize].ior as f64;
        if ior != 1.0 {
            let cos = (h.normal.dot(w).abs() as f64).min(1.0);
            let f = crate::physics::dielectric::fresnel_dielectric(cos, if inside { ior } else { 1.0 / ior });
            if f >= 1.0 {
                return 0.0;
            }
            factor *= (1.0 - f) * if inside { ior * ior } else { 1.0 / (ior * ior) };
        }
        inside = !inside;
    }
    factor
}

/// Points per sample of the partition's volume quadrature ([`partition_weights`]), and the
/// most points in all.
const PARTITION_POINTS_PER_SAMPLE: usize = 64;
const PARTITION_POINTS_MAX: usize = 4_000_000;

/// Per-sample weights nu_i that make the Gaussians of eq. 3.3 a partition of unity in the mean
/// over the object. The thesis asks sum_i gamma_i = 1 inside the object and notes that
/// Gaussians cannot be one; unweighted, at a full width at half maximum of 1.5 Poisson radii,
/// they summed to about 2 and the first renders were 1.7-1.9x too bright.
///
/// Each Gaussian takes the share of the unit field it covers, Shepard's w_i(x) = gamma_i(x) /
/// sum_j gamma_j(x), integrated over the object, and is scaled so that its own integral over the
/// object is that share:
///   nu_i = int_V w_i dV / int_V gamma_i dV,
/// so int_V sum_i nu_i gamma_i dV = int_V sum_i w_i dV = V exactly: a field constant over the
/// object integrates to its value times the volume, whatever the widths and wherever the
/// object's surface cuts a Gaussian (the render integrates each Gaussian along the ray inside the
/// object only). Both integrals by the midpoint rule on a grid of cell-centred points (about
/// [`PARTITION_POINTS_PER_SAMPLE`] per sample), classified inside the mesh by the crossings of
/// one ray per column; each sample visits the box of points its Gaussian reaches, once to sum
/// the Gaussians at every point and once for its share and mass (at 64000 samples 45 s when
/// every point searched the samples around it, for the widest Gaussian's reach). Before (weights 1 / sum_j gamma_j(b_i), Shepard at the nodes alone) a
/// medium of optical thickness 1e-3 rendered 0.94x its single scattering at width 1.5, 0.60x at
/// width 1 and 0.67x at 2.5 (4000 samples): the nodes' sums say nothing about the gaps between
/// them and the layer under the surface.
pub fn partition_weights(object: &Object, samples: &[Sample], params: &[SampleParams]) -> Vec<f32> {
    use rayon::prelude::*;
    let n = samples.len();
    if n == 0 {
        return Vec::new();
    }
    let (lo, hi) = object.mesh.bounds();
    let extent = (hi - lo).max(Vec3::splat(1e-6));
    let volume = object.mesh.volume().max(1e-30);
    let points = (PARTITION_POINTS_PER_SAMPLE * n).min(PARTITION_POINTS_MAX) as f64;
    let h = (volume / points).cbrt() as f32;
    let dims = [0, 1, 2].map(|k| ((extent[k] / h).ceil() as usize).max(1));
    let step = Vec3::new(extent.x / dims[0] as f32, extent.y / dims[1] as f32, extent.z / dims[2] as f32);
    let at = |x: usize, y: usize, z: usize| lo + (Vec3::new(x as f32, y as f32, z as f32) + 0.5) * step;
    let index = |x: usize, y: usize, z: usize| (z * dims[1] + y) * dims[0] + x;
    // Which points lie inside: per column along +z, between odd and even crossings.
    let inside: Vec<Vec<bool>> = (0..dims[0] * dims[1])
        .into_par_iter()
        .map(|col| {
            let base = at(col % dims[0], col / dims[0], 0);
            let start = Vec3::new(base.x, base.y, lo.z - (0.01 * extent.z + 1e-4));
            let hits: Vec<f32> = crossings(object, start, Vec3::Z).map(|h| start.z + h.t).collect();
            (0..dims[2]).map(|z| hits.iter().take_while(|&&t| t < at(0, 0, z).z).count() % 2 == 1).collect()
        })
        .collect();
    let is_inside = |x: usize, y: usize, z: usize| inside[y * dims[0] + x][z];
    // Each sample's box of points within its reach (gamma < 1e-6 beyond sqrt(14 / a), the render
    // pass's cut), visited as (point index, gamma).
    let each = |i: usize, f: &mut dyn FnMut(usize, f64)| {
        let (b, a) = (samples[i].position, params[i].a);
        let reach = (14.0 / a).sqrt();
        let range = |k: usize| {
            let l = ((b[k] - reach - lo[k]) / step[k] - 0.5).ceil().max(0.0) as usize;
            let u = (((b[k] + reach - lo[k]) / step[k] - 0.5).floor().max(-1.0) + 1.0) as usize;
            l..u.min(dims[k])
        };
        for z in range(2) {
            for y in range(1) {
                for x in range(0) {
                    let e = a * at(x, y, z).distance_squared(b);
                    if e < 14.0 && is_inside(x, y, z) {
                        f(index(x, y, z), (-e as f64).exp());
                    }
                }
            }
        }
    };
    // Pass 1: the sum of the Gaussians at every point (one partial grid per thread).
    let threads = rayon::current_num_threads().max(1);
    let per = n.div_ceil(threads);
    let total: Vec<f64> = (0..threads)
        .into_par_iter()
        .map(|t| {
            let mut sum = vec![0.0f64; dims[0] * dims[1] * dims[2]];
            for i in t * per..((t + 1) * per).min(n) {
                each(i, &mut |k, g| sum[k] += g);
            }
            sum
        })
        .reduce_with(|mut a, b| {
            a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
            a
        })
        .unwrap_or_default();
    // Pass 2: each sample's share of the unit field and its mass, over the points inside.
    (0..n)
        .into_par_iter()
        .map(|i| {
            let (mut share, mut mass) = (0.0f64, 0.0f64);
            each(i, &mut |k, g| {
                share += g / total[k];
                mass += g;
            });
            if mass > 1e-9 {
                (share / mass) as f32
            } else {
                // A Gaussian narrower than the points' spacing that no point saw (none at the
                // default counts): Shepard at its own node.
                let b = samples[i].position;
                let sum: f64 = samples
                    .iter()
                    .zip(params)
                    .map(|(s, p)| p.a * s.position.distance_squared(b))
                    .filter(|e| *e < 14.0)
                    .map(|e| (-e as f64).exp())
                    .sum();
                (1.0 / sum.max(1.0)) as f32
            }
        })
        .collect()
}

/// Words per sample and light in the light-term buffer: the attenuated irradiance, the unit
/// direction toward the light, and per channel the gradient of the optical depth toward it with
/// that depth ([`tau_gradient`]).
const LIGHT_WORDS: usize = 5;

/// Grazing crossings: |cos| of the ray with a surface's normal is taken as at least this in the
/// optical depth's gradient, which grows as 1 / cos.
const MIN_GRADIENT_COS: f32 = 0.2;

/// The gradient with respect to the start point `p` of the optical depth toward `w` over the
/// first `t_max`, per channel. Moving p by delta moves each surface crossing k of the straight
/// ray by -(n_k . delta) / (n_k . w) along it, which lengthens or shortens the inside interval
/// the crossing ends or begins: grad tau = sum_k -s_k sigma_k n_k / (n_k . w), s_k = 1 where the
/// ray leaves an object, -1 where it enters one, sigma_k the extinction just inside (the
/// density's own gradient along the ray is left out: exact for constant densities). Along w it
/// is -sigma(p), whatever the surface. The render uses it to let the light's attenuation vary
/// across a sample's Gaussian, linearly: under a surface the attenuation falls by e^-1 per mean
/// free path, much faster than the samples are spaced, and its value at the centre alone misses
/// the light's steep first layer.
///
/// `mat` is the material `p` lies in. A grid density gets no gradient (the attenuation at the
/// centre across the Gaussian, as the thesis): the surface terms leave out the interior's own
/// gradient, and a linear model across a Gaussian wider than the density's features moves
/// light out of dense cores (the cloud's render brightened with either).
pub fn tau_gradient(object: &Object, p: Vec3, mat: usize, w: Vec3, t_max: f32) -> [Vec3; 3] {
    let mut grad = [Vec3::ZERO; 3];
    if !matches!(object.fields[object.materials[mat].field].density, Density::Constant) {
        return grad;
    }
    let mut mat = mat;
    let mut inside = true;
    for h in crossings(object, p, w).take_while(|h| h.t < t_max) {
        let leaving = h.normal.dot(w) > 0.0;
        // The medium on the inside of this crossing: the one the ray was in when it leaves,
        // the triangle's own when it enters.
        let m = if leaving && inside { mat } else { object.bvh.tag(h.triangle) as usize };
        let material = &object.materials[m];
        let x = p + w * (h.t + if leaving { -1e-4 } else { 1e-4 });
        let density = object.fields[material.field].density_at(x);
        let cos = h.normal.dot(w);
        let cos = cos.signum() * cos.abs().max(MIN_GRADIENT_COS);
        let sign = if leaving { 1.0 } else { -1.0 };
        for (c, g) in grad.iter_mut().enumerate() {
            *g -= sign * material.sigma_t[c] * density * h.normal / cos;
        }
        inside = !leaving;
        if !leaving {
            mat = m;
        }
    }
    grad
}

/// psi reconstructed from one channel's coefficients at a direction whose basis is `y`.
fn reconstruct(coeffs: &[f32], y: &[f64]) -> f64 {
    coeffs.iter().zip(y).map(|(k, yk)| *k as f64 * yk).sum()
}

/// Words per sample in the sample buffer (glsl/sh_single/render.comp): centre and width,
/// nu sigma_s and g, nu, and per channel the environment's gradient ([`environment_gradient`]).
const SAMPLE_WORDS: usize = 6;

/// The environment's attenuation at a sample, psi averaged over directions, as one optical depth
/// with a gradient, per channel ([gradient, depth]): the gradient is the psi-weighted mean of
/// [`tau_gradient`] over `dirs` (direction, quadrature weight, its basis), the depth -ln of the
/// mean of psi. Under a surface the environment's light falls off as steeply as a light's; the
/// render varies it across the Gaussian with this gradient, as it does a light's.
fn environment_gradient(
    object: &Object,
    s: &Sample,
    sh: &[Vec<f32>; 3],
    dirs: &[(Vec3, f64, Vec<f64>)],
) -> [[f32; 4]; 3] {
    let mut num = [glam::DVec3::ZERO; 3];
    let mut den = [0.0f64; 3];
    for (w, q, y) in dirs {
        let grad = tau_gradient(object, s.position, s.material, *w, f32::INFINITY);
        for c in 0..3 {
            let psi = reconstruct(&sh[c], y).max(0.0);
            num[c] += grad[c].as_dvec3() * (q * psi);
            den[c] += q * psi;
        }
    }
    std::array::from_fn(|c| {
        if den[c] <= 0.0 {
            return [0.0; 4];
        }
        let g = num[c] / den[c];
        let tau = -(den[c] / (4.0 * std::f64::consts::PI)).max(1e-30).ln();
        [g.x as f32, g.y as f32, g.z as f32, tau.max(0.0) as f32]
    })
}

/// Largest factor by which a ray's in-scattering is scaled to its coverage ([`resolve`]).
const MAX_COVERAGE_SCALE: f32 = 4.0;

/// A pixel's radiance from the render pass's four words (glsl/sh_single/render.comp): the
/// surfaces' own terms plus the samples' in-scattering scaled by exact / coverage, per channel.
///
/// **Coverage.** The Gaussians' partition of unity (eq. 3.3) holds in the mean over the
/// object ([`partition_weights`]), not along each ray: near the surface, where the samples
/// stop, their sum dips, and it ripples between samples. Along a camera ray the in-scattering
/// is int sum_i nu_i gamma_i(t) f_i(t) K(t) dt with K the camera's attenuation; the render also
/// sums int sum_i nu_i gamma_i(t) K(t) dt (the coverage the ray saw, weighted as the light is)
/// and the exact int K(t) dt, and the ratio of the two rescales the in-scattering: a Shepard
/// normalisation along the ray, weighted by K (Shepard's w_i(x) = gamma_i / sum_j gamma_j,
/// taken as its K-weighted mean over the ray). Where the first mean free path under the surface
/// holds the light, the coverage there is what counts, and no per-sample weight can set it for
/// every view. Capped at [`MAX_COVERAGE_SCALE`] where a ray grazes a part no Gaussian reaches.
fn resolve(p: &[[f32; 4]]) -> [f32; 3] {
    std::array::from_fn(|c| {
        let (surface, scat, cover, exact) = (p[0][c], p[1][c], p[2][c], p[3][c]);
        let scale = if cover > 0.0 { (exact / cover).min(MAX_COVERAGE_SCALE) } else { 0.0 };
        surface + scat * scale
    })
}

/// One sample's upload: its two words, its coefficients, its light terms.
type SampleUpload = ([[f32; 4]; SAMPLE_WORDS], Vec<f32>, Vec<[f32; 4]>);

/// Dawson's integral F(x) = exp(-x^2) int_0^x exp(t^2) dt, x >= 0. Written with u = x - t as
/// int_0^x exp(-u (2x - u)) du, whose integrand falls from 1 at least as fast as exp(-u x):
/// Simpson's rule in 512 steps over u up to min(x, 40 / x) (relative error below 1e-6) up to
/// x = 8, the asymptotic series 1/(2x) (1 + 1/(2x^2) + 3/(4x^4) + 15/(8x^6)) beyond.
pub fn dawson(x: f64) -> f64 {
    if x <= 0.0 {
        0.0
    } else if x > 8.0 {
        let u = 1.0 / (2.0 * x * x);
        (1.0 + u * (1.0 + u * (3.0 + 15.0 * u))) / (2.0 * x)
    } else {
        let n = 512;
        let h = x.min(40.0 / x) / n as f64;
        let f = |u: f64| (-u * (2.0 * x - u)).exp();
        let inner: f64 = (1..n).map(|i| f(i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 }).sum();
        (f(0.0) + inner + f(n as f64 * h)) * h / 3.0
    }
}

/// The mean of 1 / |x - l|^2 over an isotropic Gaussian of standard deviation `s` per axis
/// centred `d` from l: with x - l a non-central chi variable of 3 degrees of freedom,
///   E[1 / r^2] = sqrt(2) / (s d) F(d / (sqrt(2) s)),  F Dawson's integral,
/// which is 1 / s^2 at d = 0 and 1 / d^2 far away (checked against Monte Carlo to 1%).
pub fn gaussian_mean_inverse_square(d: f64, s: f64) -> f64 {
    if d < 1e-6 * s {
        1.0 / (s * s)
    } else {
        std::f64::consts::SQRT_2 / (s * d) * dawson(d / (std::f64::consts::SQRT_2 * s))
    }
}

/// Render `scene` (its [[object]]s, or a v1 medium's box; point, directional and constant
/// environment lights) by sh-single (`force_full`: model every feature): samples, their parameters (optical depths on the device),
/// the light terms on the host, the render pass in chunks of samples. Returns the image, the
/// stats, the device bytes allocated and what the scene on the device modelled.
pub fn render(
    gpu: &Gpu,
    scene: &Scene,
    set: &ShSettings,
    force_full: bool,
    progress: &dyn Fn(Progress),
) -> Result<(Image, ShStats, u64, gpu_scene::Modelled), SolverError> {
    let os = object_scene(scene);
    let object = os.object.as_ref().expect("object_scene gives an object");
    let clock = std::time::Instant::now();
    progress(Progress::work("preprocessing: samples, optical depths, light terms", 0, 3));
    let mut samples = poisson_draw(object, set.samples, set.seed, set.heuristic, set.placement).0;
    let (lo, hi) = object.mesh.bounds();
    sort_spatially(&mut samples, lo, hi);
    let sampling_s = clock.elapsed().as_secs_f64();
    progress(Progress::work("preprocessing: samples, optical depths, light terms", 1, 3));
    let gs = GpuScene::upload_with(gpu, &os, force_full, gpu_scene::MAJORANT_CELL)?;
    let q = projection_quadrature(set.directions);
    let step = density_step(object);
    let (params, depth_bytes) = device_params(gpu, &gs, object, &samples, set.order, &q, set.width_scale, step)?;
    let depths_s = clock.elapsed().as_secs_f64() - sampling_s;
    progress(Progress::work("preprocessing: samples, optical depths, light terms", 2, 3));
    let (lights, env) = split_lights(&os);
    // Which point lights lie inside the objects (their light terms walk to the light), once.
    let inside: Vec<bool> = lights.iter().map(|(pos, _, point)| *point && object.contains(*pos)).collect();
    let nu = partition_weights(object, &samples, &params);
    let weights_s = clock.elapsed().as_secs_f64() - sampling_s - depths_s;
    // Per sample: its two words, its coefficients, and per light the irradiance at the sample
    // attenuated by psi toward the light (exactly, by the host's walk, toward a point light
    // inside the object, where psi's walk to infinity would overshoot it) and `single`'s
    // boundary factor, and the unit direction toward the light.
    use rayon::prelude::*;
    let env_set = env_coefficients(&os);
    // The environment's gradient is averaged over a coarse product rule (4 x 8 directions,
    // their basis once).
    let env_dirs: Vec<(Vec3, f64, Vec<f64>)> = {
        let q = Quadrature::product(4, 8);
        q.directions
            .iter()
            .zip(&q.weights)
            .map(|(d, w)| (glam::DVec3::from_array(*d).as_vec3(), *w, sh::basis(set.order, *d)))
            .collect()
    };
    let per_sample: Vec<SampleUpload> = samples
        .par_iter()
        .zip(&params)
        .zip(&nu)
        .map(|((s, p), nu)| {
            let g = object.materials[s.material].g;
            let mut words = [[0.0f32; 4]; SAMPLE_WORDS];
            words[0] = [s.position.x, s.position.y, s.position.z, p.a];
            words[1] = [p.sigma_s[0] * nu, p.sigma_s[1] * nu, p.sigma_s[2] * nu, g];
            words[2] = [*nu, 0.0, 0.0, 0.0];
            if env.max_element() > 0.0 {
                let sh = if env_set { p.sh_env.as_ref().unwrap_or(&p.sh) } else { &p.sh };
                words[3..6].copy_from_slice(&environment_gradient(object, s, sh, &env_dirs));
            }
            let mut coeffs: Vec<f32> = p.sh.iter().flatten().copied().collect();
            if env_set {
                coeffs.extend(p.sh_env.iter().flatten().flatten().copied());
            }
            let mut lt = Vec::with_capacity(LIGHT_WORDS * lights.len());
            for ((pos, value, point), inside) in lights.iter().zip(&inside) {
                let (w, e, inside_to) = if *point {
                    let to = *pos - s.position;
                    // The irradiance I / r^2 averaged over the sample's Gaussian, not taken at
                    // its centre: beside a light inside the medium the centre's value is no
                    // measure of the Gaussian's (and is singular at the light).
                    let r2 = to.length_squared();
                    let w = if r2 > 0.0 { to / r2.sqrt() } else { Vec3::Z };
                    let mean = gaussian_mean_inverse_square(r2.sqrt() as f64, (0.5 / p.a as f64).sqrt());
                    (w, *value * mean as f32, inside.then_some(r2.sqrt()))
                } else {
                    (-*pos, *value, None)
                };
                let t_max = inside_to.unwrap_or(f32::INFINITY);
                let tau_l: [f64; 3] = match inside_to {
                    Some(r) => optical_depth_within(object, s.position, w, r, step),
                    None => {
                        let y = sh::basis(set.order, [w.x as f64, w.y as f64, w.z as f64]);
                        std::array::from_fn(|c| -reconstruct(&p.sh[c], &y).max(1e-30).ln())
                    }
                };
                let ft = boundary_factor_within(object, s.position, w, t_max);
                let grad = tau_gradient(object, s.position, s.material, w, t_max);
                let att: [f32; 3] = std::array::from_fn(|c| ((-tau_l[c]).exp() * ft) as f32 * e[c]);
                lt.push([att[0], att[1], att[2], 0.0]);
                lt.push([w.x, w.y, w.z, 0.0]);
                for c in 0..3 {
                    lt.push([grad[c].x, grad[c].y, grad[c].z, tau_l[c].min(1e30) as f32]);
                }
            }
            (words, coeffs, lt)
        })
        .collect();
    let mut sample_words: Vec<[f32; 4]> = Vec::with_capacity(SAMPLE_WORDS * samples.len());
    let mut coeffs: Vec<f32> = Vec::with_capacity(samples.len() * 3 * sh::coefficients(set.order));
    let mut lterms: Vec<[f32; 4]> = Vec::with_capacity(LIGHT_WORDS * samples.len() * lights.len());
    for (words, c, lt) in per_sample {
        sample_words.extend_from_slice(&words);
        coeffs.extend(c);
        lterms.extend(lt);
    }
    if lterms.is_empty() {
        lterms.push([0.0; 4]);
    }
    let sample_buf = gpu.buffer_with("sh-single samples", &sample_words)?;
    let coeff_buf = gpu.buffer_with("sh-single coefficients", &coeffs)?;
    let light_buf = gpu.buffer_with("sh-single light terms", &lterms)?;
    let centres: Vec<Vec3> = samples.iter().map(|s| s.position).collect();
    let reach = sample_reach(&samples, set.width_scale);
    let index = (set.index == SampleIndex::Grid).then(|| GaussianIndex::build(&centres, &reach));
    let boxes = set.index != SampleIndex::None;
    let (starts_buf, items_buf) = match &index {
        Some(ix) => (
            gpu.buffer_with("sh-single index cells", &ix.starts)?,
            gpu.buffer_with("sh-single index items", &ix.items)?,
        ),
        None => (gpu.buffer("sh-single index (none)", 16)?, gpu.buffer("sh-single index (none)", 16)?),
    };
    let sample_bytes = sample_buf.size() + coeff_buf.size() + light_buf.size() + starts_buf.size() + items_buf.size();
    let preprocess_s = clock.elapsed().as_secs_f64();
    progress(Progress::work("preprocessing: samples, optical depths, light terms", 3, 3));
    let clock = std::time::Instant::now();
    let (w, h) = (os.render.width, os.render.height);
    let image_buf = gpu.buffer("sh-single radiance", w as u64 * h as u64 * 64)?;
    let pipeline = gpu.pipeline(&RENDER, &gs.modelled.mesh_spec())?;
    let n = samples.len() as u32;
    // llvmpipe's loop limiter (glsl/include/budget.glsl) counts every back-edge of an
    // invocation: a sample the camera ray reaches costs 4 + 4 lights of them per inside segment
    // (glsl/sh_single/render.comp, segment_light), order^2 + 3 more with an environment and
    // order^2 more in a grid density (psi toward the camera). Chunks start where a ray reaching
    // every sample of one segment stays within the guard; where the kernel reports more (many
    // segments), the render is run again with half the chunk.
    let stats_buf = gpu.buffer("sh-single stats", 16)?;
    let n_coeff = sh::coefficients(set.order);
    let per_sample = (4
        + 4 * lights.len()
        + if env.max_element() > 0.0 { n_coeff + 3 } else { 0 }
        + if gs.modelled.density == "constant" { 0 } else { n_coeff }) as u32;
    // With the index a visited sample also costs its entries in the cells walked (a few), and
    // the walk its cells (at most the sum of the dimensions per segment).
    let (per_sample, walk) = match &index {
        Some(ix) => (per_sample + 4, ix.dims.iter().sum::<u32>() + 3),
        None => (per_sample, 0),
    };
    let mut chunk = ((LOOP_GUARD / 2).saturating_sub(walk) / per_sample).clamp(1, CHUNK);
    let mut dispatches = 0u64;
    progress(Progress::work("render pass", 0, 1));
    loop {
        let mut passes = Vec::new();
        let mut first = 0u32;
        loop {
            let count = (n - first).min(chunk);
            let (bl, bh) = chunk_box(&centres, &reach, first as usize, count as usize);
            passes.push(
                gs.bind_mesh(Pass::new("sh_single.render", QueueRole::Trace, &pipeline))
                    .read(3, &sample_buf)
                    .read(4, &coeff_buf)
                    .read(5, &light_buf)
                    .read_write(8, &image_buf)
                    .read_write(9, &stats_buf)
                    .read(10, &starts_buf)
                    .read(11, &items_buf)
                    .push(&RenderPush {
                        first,
                        count,
                        order: set.order as u32,
                        lights: lights.len() as u32,
                        env: [env.x, env.y, env.z, if first == 0 { 1.0 } else { 0.0 }],
                        env_coeffs: env_set as u32,
                        step,
                        pad: [0; 2],
                        grid: index.as_ref().map_or([0.0; 4], |ix| [ix.origin.x, ix.origin.y, ix.origin.z, ix.cell]),
                        grid_dims: index.as_ref().map_or([0; 4], |ix| [ix.dims[0], ix.dims[1], ix.dims[2], 1]),
                        box_lo: [bl.x, bl.y, bl.z, if boxes { 1.0 } else { 0.0 }],
                        box_hi: [bh.x, bh.y, bh.z, 0.0],
                    })
                    .cover([w, h, 1]),
            );
            first += count;
            if first >= n {
                break;
            }
        }
        dispatches += passes.len() as u64;
        let point = gpu.submit(QueueRole::Trace, &passes, &[])?;
        gpu.wait(point)?;
        let most: Vec<u32> = gpu.read_buffer_as(&stats_buf)?;
        if most[0] <= LOOP_GUARD {
            break;
        }
        if chunk == 1 {
            return Err(SolverError::Unsupported(format!(
                "sh-single: a camera ray's chain took {} loop iterations for one sample, past this device's loop \
                 limiter; lower sh-single.order",
                most[0]
            )));
        }
        chunk /= 2;
        gpu.fill_zero(&stats_buf)?;
    }
    progress(Progress::work("render pass", 1, 1));
    let px: Vec<[f32; 4]> = gpu.read_buffer_as(&image_buf)?;
    let mut image = Image::new(w, h);
    let mut nonfinite = 0u32;
    for (rgb, p) in image.data.chunks_exact_mut(3).zip(px.chunks_exact(4)) {
        let v = resolve(p);
        if !v.iter().all(|x| x.is_finite()) {
            nonfinite += 1;
        }
        for (o, x) in rgb.iter_mut().zip(v) {
            *o = if x.is_finite() { x } else { 0.0 };
        }
    }
    let render_s = clock.elapsed().as_secs_f64();
    let bytes = gs.bytes + depth_bytes + sample_bytes + image_buf.size() + stats_buf.size();
    let stats = ShStats {
        requested: set.samples,
        samples: samples.len(),
        order: set.order,
        directions: q.directions.len(),
        sample_bytes,
        preprocess_s,
        render_s,
        nonfinite_pixels: nonfinite,
        chunk,
        dispatches,
        sampling_s,
        depths_s,
        weights_s,
        density: set.heuristic.name(),
    };
    Ok((image, stats, bytes, gs.modelled.clone()))
}

/// The solver `sh-single` (module docs).
pub struct ShSingle;

impl Solver for ShSingle {
    fn name(&self) -> &'static str {
        "sh-single"
    }

    fn about(&self) -> &'static str {
        "single scattering from spherical-harmonics attenuation stored at Poisson-disk samples (Bernabei thesis ch. 3)"
    }

    fn knobs(&self) -> Vec<Knob> {
        vec![
            Knob::fixed(
                "order",
                "5",
                Range::int(1, sh::MAX_ORDER as u64),
                "spherical-harmonics order L of each sample's attenuation (bands 0..L-1, L^2 coefficients per channel; \
                 the thesis uses 5)",
            ),
            Knob::fixed(
                "samples",
                "4000",
                Range::int(1, 1 << 20),
                "Poisson-disk samples requested inside the object (drawn within about 10%; denser near the surface)",
            ),
            Knob::fixed(
                "width_scale",
                "1.5",
                Range::Real { min: 0.0, max: 8.0, min_open: true, max_open: false },
                "each sample's Gaussian full width at half maximum, in Poisson radii (thesis 3.3.2)",
            ),
            Knob::derived("seed", "render.seed", Range::int(0, u64::MAX), "seed of the Poisson-disk sampling"),
            Knob::fixed(
                "density",
                "auto",
                Range::Choice(&["auto", "depth", "divergence"]),
                "how the Poisson radius varies between r/2 and 2r (thesis 3.2.3): by the depth below the surface in \
                 mean free paths (depth), or by the thesis's divergence of the attenuation's first moment, which also \
                 densifies at corners, material boundaries and density gradients and leaves unlit depths unsampled \
                 (divergence); auto: divergence where a density varies (grids), depth for constant densities",
            ),
            Knob::fixed(
                "placement",
                "volume",
                Range::Choice(&["volume", "layers"]),
                "where the Poisson darts land: anywhere inside the object (volume), or on the thesis's offset \
                 surfaces (3.2.1-3.2.2), layers at depths of a quarter base radius below the mesh (layers)",
            ),
            Knob::fixed(
                "index",
                "boxes",
                Range::Choice(&["boxes", "grid", "none"]),
                "how the render finds the Gaussians a camera ray passes: boxes: every sample of each chunk whose box \
                 the ray crosses (samples in Morton order, chunks compact); grid: a uniform grid's cells along the ray \
                 (fewer samples visited, but its walk diverges across SIMD lanes: slower on lavapipe, docs/sh-single.md); \
                 none: every sample for every pixel. The same image",
            ),
            Knob::fixed(
                "directions",
                "288",
                Range::int(8, 8192),
                "directions each sample's optical depth is marched toward and projected from (an n x 2n product rule, \
                 n = round(sqrt(directions / 2)); the thesis uses 128 to 2048)",
            ),
        ]
    }

    fn kernels(&self) -> Vec<Kernel> {
        kernels()
    }

    fn render(&self, gpu: &Gpu, req: &RenderRequest) -> Result<RenderOutput, SolverError> {
        let k = req.knobs(self)?;
        let set = ShSettings::parse(&k, req.scene)?;
        k.finish()?;
        let (image, st, bytes, modelled) = render(gpu, req.scene, &set, req.force_full, req.progress)?;
        let faults = st.nonfinite_pixels as u64;
        let warning = crate::solvers::interface::nonfinite_warning(st.nonfinite_pixels);
        let mut stats = Stats::new(st);
        stats.faults = faults;
        let mut report = RenderReport::finish(gpu, self, &k, modelled, bytes, stats);
        report.warnings.extend(warning);
        Ok(RenderOutput { image, variance: None, report })
    }

    fn memory_estimate(&self, scene: &Scene, knobs: &Knobs) -> Result<u64, SolverError> {
        let set = ShSettings::parse(knobs, scene)?;
        let os = object_scene(scene);
        // The sample count is the sampler's (deterministic for the seed): drawn here as the
        // render draws it.
        let object = os.object.as_ref().expect("object scene");
        // (in the sampler's order: the grid index's size does not depend on it)
        let samples = poisson_draw(object, set.samples, set.seed, set.heuristic, set.placement).0;
        Ok(device_bytes(&os, &samples, &set))
    }

    fn ladder(&self, _scene: &Scene) -> Vec<Rung> {
        [(2u32, 250u32), (3, 1000), (4, 4000), (6, 16000), (8, 64000)]
            .iter()
            .map(|(order, samples)| Rung {
                knob: "sh-single.samples".into(),
                value: format!("{samples} (order {order})"),
                sets: vec![
                    ("sh-single.samples".into(), samples.to_string()),
                    ("sh-single.order".into(), order.to_string()),
                ],
            })
            .collect()
    }

    fn stability(&self) -> Vec<Variant> {
        vec![Variant::new("", &[("sh-single.samples", "500"), ("sh-single.order", "4")])]
    }

    /// Samples inside any [[object]] (a v1 medium as its box).
    fn renders_meshes(&self) -> bool {
        true
    }

    /// Each sample carries its object's material; psi and the boundary factors cross every
    /// object with its own.
    fn renders_materials(&self) -> bool {
        true
    }

    fn summary(&self, report: &RenderReport) -> Vec<String> {
        let Some(s) = report.detail::<ShStats>() else { return Vec::new() };
        vec![format!(
            "sh-single: {} samples ({} requested, {} heuristic), order {} ({} coefficients per channel), {} \
             directions, sample set {:.1} MB; \
             preprocessing {:.2} s (sampling {:.2}, optical depths {:.2}, weights {:.2}), render {:.2} s",
            s.samples,
            s.requested,
            s.density,
            s.order,
            sh::coefficients(s.order),
            s.directions,
            s.sample_bytes as f64 / 1e6,
            s.preprocess_s,
            s.sampling_s,
            s.depths_s,
            s.weights_s,
            s.render_s
        )]
    }
}
