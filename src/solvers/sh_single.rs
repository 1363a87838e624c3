//! `sh-single` (issue 17; thesis chapter 3): single scattering from per-sample, spherical-
//! harmonics-compressed attenuation at Poisson-disk samples of an object's interior.
//!
//! **Status: the preprocessing on the host; the solver is not registered yet.** Built so far:
//! the sample set (thesis 3.2, simplified below) and each sample's parameters (3.3): the
//! attenuation psi_i(w) = exp(-tau(b_i, w)) to the boundary projected on real spherical
//! harmonics of order L per channel (eq. 3.4, src/physics/sh.rs), the Gaussian width from the
//! sample's radius (3.3.2) and sigma_s at the sample. Not built: the projection marched on the
//! device, the render pass (3.4), knobs, ladder, `stability`.
//!
//! **Sampling, simplified.** The thesis samples layers (offset surfaces of the mesh) with a
//! density from the divergence of the light-transport field, then draws a Poisson-disk set whose
//! radius varies between r/2 and 2r with that density (3.2.2-3.2.4). Here the density heuristic
//! is the depth below the surface in mean free paths: a sample's radius is r0 (0.5 + 1.5
//! min(1, depth / (3 mean free paths))), so within a mean free path of the surface, where
//! single scattering is seen and varies fastest, samples are up to 4x closer than deep inside
//! (the thesis's r/2 .. 2r). The set is drawn by dart throwing (candidates uniform in the
//! mesh's box, kept inside the mesh, accepted where no kept sample lies closer than the mean of
//! the two radii; a hash grid finds the neighbours), deterministic for a seed. r0 is chosen so
//! that the expected count of such a packing is the requested count, and corrected (at most
//! twice) by the cube root of the count's ratio until within 10% of it.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use super::gpu_scene::{GpuScene, MESH_SPEC};
use super::SolverError;
use crate::gpu::{Gpu, Kernel, Pass, QueueRole};
use crate::physics::quadrature::Quadrature;
use crate::physics::rng::Pcg32;
use crate::physics::sh;
use crate::scene::{Density, Object};

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

/// A Poisson-disk set of about `count` samples inside `object` (module docs), deterministic for
/// `seed`.
pub fn poisson_samples(object: &Object, count: u32, seed: u64) -> Vec<Sample> {
    let (lo, hi) = object.mesh.bounds();
    let extent = hi - lo;
    let st = max_sigma_t(object);
    let mfp = if st > 0.0 { 1.0 / st } else { extent.max_element() };
    let mut rng = Pcg32::new(seed, 17);
    // r0 from the expected packing: count = PACKING sum over the volume of 1 / ((4/3) pi (r/2)^3)
    // with r = r0 s(x), estimated from darts inside the mesh.
    let probes = 4096;
    let box_volume = (extent.x * extent.y * extent.z) as f64;
    let mut inv_cube = 0.0f64;
    for _ in 0..probes {
        let p = dart(&mut rng, lo, extent);
        if object.contains(p) {
            inv_cube += 1.0 / (radius_scale(depth_below_surface(object, p), mfp) as f64).powi(3);
        }
    }
    let integral = inv_cube * box_volume / probes as f64;
    let mut r0 = (2.0 * (PACKING * integral / (count.max(1) as f64 * 4.0 / 3.0 * std::f64::consts::PI)).cbrt()) as f32;
    // The packing fraction varies with the shape (thin parts and corners fill less): up to
    // three draws, r0 rescaled by the cube root of the count's ratio, until within 10%.
    let mut out = Vec::new();
    for _ in 0..3 {
        out = dart_throw(object, count, seed, r0, mfp);
        let ratio = out.len() as f64 / count.max(1) as f64;
        if (ratio - 1.0).abs() < 0.1 {
            break;
        }
        r0 *= ratio.cbrt() as f32;
    }
    out
}

/// One dart-throwing draw of radius scale `r0` (module docs).
fn dart_throw(object: &Object, count: u32, seed: u64, r0: f32, mfp: f32) -> Vec<Sample> {
    let (lo, hi) = object.mesh.bounds();
    let extent = hi - lo;
    let mut rng = Pcg32::new(seed, 18);
    // Hash grid of cell r0 / 2 (the smallest radius): a sample's conflicts lie within
    // (r + 2 r0) / 2 <= 2 r0, four cells.
    let cell = 0.5 * r0;
    let dims = (extent / cell).ceil().as_uvec3().max(glam::UVec3::ONE);
    let key = |p: Vec3| ((p - lo) / cell).floor().as_ivec3().clamp(glam::IVec3::ZERO, dims.as_ivec3() - 1);
    let mut grid: std::collections::HashMap<glam::IVec3, Vec<u32>> = std::collections::HashMap::new();
    let mut out: Vec<Sample> = Vec::new();
    for _ in 0..count.max(1) * DARTS_PER_SAMPLE {
        let p = dart(&mut rng, lo, extent);
        if !object.contains(p) {
            continue;
        }
        let r = r0 * radius_scale(depth_below_surface(object, p), mfp);
        let c = key(p);
        let reach = ((r + 2.0 * r0) * 0.5 / cell).ceil() as i32;
        let mut free = true;
        'search: for dz in -reach..=reach {
            for dy in -reach..=reach {
                for dx in -reach..=reach {
                    if let Some(list) = grid.get(&(c + glam::IVec3::new(dx, dy, dz))) {
                        for &j in list {
                            let s = out[j as usize];
                            if s.position.distance(p) < 0.5 * (r + s.radius) {
                                free = false;
                                break 'search;
                            }
                        }
                    }
                }
            }
        }
        if free {
            grid.entry(c).or_default().push(out.len() as u32);
            let material = object.material_at(p).unwrap_or(0);
            out.push(Sample { position: p, radius: r, material });
        }
    }
    out
}

/// Optical depth per channel from `p` (inside the object) along unit `w` to infinity: each
/// interval inside an object at its material's extinction times the density integral (exact
/// for constant density, the midpoint rule in steps of `step` otherwise), crossing every
/// surface straight (the attenuation psi of eq. 3.2 has no refraction).
pub fn optical_depth(object: &Object, p: Vec3, w: Vec3, step: f32) -> [f64; 3] {
    let mut tau = [0.0f64; 3];
    let Some(mut mat) = object.material_at(p) else { return tau };
    // The segment inside an object runs from the last crossing `t` to the next.
    let (mut inside, mut t) = (true, 0.0f32);
    for h in crossings(object, p, w) {
        if inside {
            let m = &object.materials[mat];
            let field = &object.fields[m.field];
            let integral = match field.density {
                Density::Constant => (h.t - t) as f64,
                _ => {
                    let n = ((h.t - t) / step).ceil().max(1.0) as usize;
                    let dt = (h.t - t) / n as f32;
                    (0..n).map(|i| field.density_at(p + w * (t + (i as f32 + 0.5) * dt)) as f64 * dt as f64).sum()
                }
            };
            for (t, sigma) in tau.iter_mut().zip(m.sigma_t.to_array()) {
                *t += sigma as f64 * integral;
            }
        }
        inside = h.normal.dot(w) < 0.0;
        if inside {
            mat = object.bvh.tag(h.triangle) as usize;
        }
        t = h.t;
    }
    tau
}

/// A sample's parameters (thesis 3.3): psi's coefficients per channel ([c][k], order^2 each),
/// the Gaussian's a_i (gamma(x) = exp(-a_i |x - b_i|^2), full width at half maximum
/// `width_scale` times the Poisson radius, 3.3.2) and sigma_s at the sample, 1/unit.
#[derive(Clone, Debug)]
pub struct SampleParams {
    pub sh: [Vec<f32>; 3],
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
                .map(|d| optical_depth(object, s.position, Vec3::new(d[0] as f32, d[1] as f32, d[2] as f32), step))
                .collect()
        })
        .collect();
    project_params(object, samples, order, q, width_scale, |i, k| taus[i][k])
}

/// Push constants of glsl/sh_single/depth.comp.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct DepthPush {
    pub samples: u32,
    pub dirs: u32,
    pub step: f32,
    pub pad: u32,
}

/// glsl/sh_single/depth.comp: the optical depth per (sample, direction) on the device.
pub const DEPTH: Kernel =
    Kernel { shader: shader!("sh_single/depth"), push_bytes: std::mem::size_of::<DepthPush>(), spec: MESH_SPEC };

/// The kernels of sh-single built so far (the registry's reflection checks hold them too).
pub fn kernels() -> Vec<Kernel> {
    vec![DEPTH, RENDER]
}

/// [`sample_params`] with the optical depths marched on the device (glsl/sh_single/depth.comp,
/// one invocation per sample and direction; `gs` the scene uploaded with its mesh), the
/// projection on the host.
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
) -> Result<Vec<SampleParams>, SolverError> {
    let pipeline = gpu.pipeline(&DEPTH, &gs.modelled.mesh_spec())?;
    let points: Vec<[f32; 4]> =
        samples.iter().map(|s| [s.position.x, s.position.y, s.position.z, f32::from_bits(s.material as u32)]).collect();
    let dirs: Vec<[f32; 4]> = q.directions.iter().map(|d| [d[0] as f32, d[1] as f32, d[2] as f32, 0.0]).collect();
    let pairs = samples.len() as u64 * dirs.len() as u64;
    let point_buf = gpu.buffer_with("sh-single samples", &points)?;
    let dir_buf = gpu.buffer_with("sh-single directions", &dirs)?;
    let depth_buf = gpu.buffer("sh-single depths", pairs.max(1) * 16)?;
    let pass = gs
        .bind_mesh(Pass::new("sh_single.depth", QueueRole::Trace, &pipeline))
        .read(3, &point_buf)
        .read(4, &dir_buf)
        .write(5, &depth_buf)
        .push(&DepthPush { samples: samples.len() as u32, dirs: dirs.len() as u32, step, pad: 0 })
        .cover([pairs as u32, 1, 1]);
    let point = gpu.submit(QueueRole::Trace, &[pass], &[])?;
    gpu.wait(point)?;
    let depths: Vec<[f32; 4]> = gpu.read_buffer_as(&depth_buf)?;
    let n = dirs.len();
    Ok(project_params(object, samples, order, q, width_scale, |i, k| {
        let t = depths[i * n + k];
        [t[0] as f64, t[1] as f64, t[2] as f64]
    }))
}

/// The parameters from the optical depth `tau(i, k)` of sample i toward direction k of `q`.
fn project_params(
    object: &Object,
    samples: &[Sample],
    order: usize,
    q: &Quadrature,
    width_scale: f32,
    tau: impl Fn(usize, usize) -> [f64; 3] + Sync,
) -> Vec<SampleParams> {
    use rayon::prelude::*;
    // The basis at every direction, once.
    let basis: Vec<Vec<f64>> = q.directions.iter().map(|d| sh::basis(order, *d)).collect();
    samples
        .par_iter()
        .enumerate()
        .map(|(i, s)| {
            let sh: [Vec<f32>; 3] = std::array::from_fn(|c| {
                let mut coeffs = vec![0.0f64; sh::coefficients(order)];
                for (k, (y, w)) in basis.iter().zip(&q.weights).enumerate() {
                    let v = (-tau(i, k)[c]).exp() * w;
                    for (o, yk) in coeffs.iter_mut().zip(y) {
                        *o += v * yk;
                    }
                }
                coeffs.iter().map(|x| *x as f32).collect()
            });
            // FWHM of exp(-a r^2) is 2 sqrt(ln 2 / a): a = 4 ln 2 / fwhm^2.
            let fwhm = width_scale * s.radius;
            let a = 4.0 * std::f32::consts::LN_2 / (fwhm * fwhm);
            let mat = &object.materials[s.material];
            let dens = object.fields[mat.field].density_at(s.position);
            let sigma_s = std::array::from_fn(|c| mat.sigma_t[c] * mat.albedo[c] * dens);
            SampleParams { sh, a, sigma_s }
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
    pub env_factor: f32,
    pub step: f32,
    pub pad: [u32; 2],
}

/// glsl/sh_single/render.comp: the render pass (thesis 3.4).
pub const RENDER: Kernel =
    Kernel { shader: shader!("sh_single/render"), push_bytes: std::mem::size_of::<RenderPush>(), spec: MESH_SPEC };

/// Samples per render dispatch: each invocation's loop over them stays far below llvmpipe's
/// loop limiter.
const CHUNK: u32 = 2048;

/// sh-single's settings (the future solver's knobs `order`, `samples`, `width_scale`, `seed`).
#[derive(Clone, Copy, Debug)]
pub struct ShSettings {
    /// Spherical-harmonics order L (bands 0 .. L - 1), 1 ..= 8.
    pub order: usize,
    /// Requested Poisson-disk samples.
    pub samples: u32,
    /// Gaussian full width at half maximum in Poisson radii.
    pub width_scale: f32,
    pub seed: u64,
}

/// What a render measured: samples drawn, bytes of the sample set on the device, the
/// preprocessing and render times.
#[derive(Clone, Debug)]
pub struct ShStats {
    pub samples: usize,
    pub sample_bytes: u64,
    pub preprocess_s: f64,
    pub render_s: f64,
}

/// The boundary factor of the straight ray from `p` (inside the object) along `w`, as `single`'s
/// shadow rays take it (glsl/view/march.comp, optical_depth; thesis 3.1.1): at each refracting
/// surface crossed, the Fresnel transmittance 1 - F at the ray's own angle (eta = ior where it
/// leaves an object, 1 / ior where it enters one; total internal reflection: 0) times the
/// radiance's change of index, ior^2 where the light enters an object (the ray leaves it) and
/// 1 / ior^2 where it leaves one; the camera's entry divides the ior^2 out again.
fn boundary_factor(object: &Object, p: Vec3, w: Vec3) -> f64 {
    let mut inside = true;
    let mut factor = 1.0f64;
    for h in crossings(object, p, w) {
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

/// The mean of [`boundary_factor`] over the directions leaving a flat surface of index `ior`
/// from inside (uniform in the cosine): what the environment's in-scattering loses or gains at
/// the boundary, taken for every sample alike (1 for ior 1).
fn environment_factor(ior: f64) -> f64 {
    if ior == 1.0 {
        return 1.0;
    }
    let n = 4096;
    (0..n)
        .map(|k| {
            let mu = (k as f64 + 0.5) / n as f64;
            let f = crate::physics::dielectric::fresnel_dielectric(mu, ior);
            if f >= 1.0 {
                0.0
            } else {
                (1.0 - f) * ior * ior
            }
        })
        .sum::<f64>()
        / n as f64
}

/// Per-sample weights nu_i = 1 / sum_j gamma_j(b_i): the Gaussians of eq. 3.3 should sum to 1
/// inside the object (a partition of unity, which the thesis notes Gaussians cannot be), and
/// overlapping at a width of a Poisson radius or more they sum to about 2 at the centres, which
/// left a first render 1.7-1.9x too bright. Weighting each by the inverse of the sum at its own
/// centre makes sum_i nu_i gamma_i = 1 there (Shepard's normalisation at the nodes), which the
/// closed-form line integral keeps.
pub fn partition_weights(samples: &[Sample], params: &[SampleParams]) -> Vec<f32> {
    // Neighbours by a sweep along x: gamma_j < 1e-6 beyond sqrt(14 / a_j).
    let mut order: Vec<usize> = (0..samples.len()).collect();
    order.sort_by(|&i, &j| samples[i].position.x.total_cmp(&samples[j].position.x));
    let a_min = params.iter().map(|p| p.a).fold(f32::INFINITY, f32::min);
    let reach = (14.0 / a_min).sqrt();
    let mut sums = vec![0.0f64; samples.len()];
    for (k, &i) in order.iter().enumerate() {
        let b = samples[i].position;
        let mut total = 0.0f64;
        for &j in order[k..].iter().take_while(|&&j| samples[j].position.x - b.x <= reach) {
            total += (-(params[j].a * samples[j].position.distance_squared(b))).exp() as f64;
        }
        for &j in order[..k].iter().rev().take_while(|&&j| b.x - samples[j].position.x <= reach) {
            total += (-(params[j].a * samples[j].position.distance_squared(b))).exp() as f64;
        }
        sums[i] = total;
    }
    sums.iter().map(|t| (1.0 / t.max(1.0)) as f32).collect()
}

/// Render `scene` (one [[object]]; its point, directional and constant environment lights) by
/// sh-single: samples, their parameters (optical depths on the device), the light terms on the
/// host, the render pass in chunks of samples.
pub fn render(
    gpu: &Gpu,
    scene: &crate::scene::Scene,
    set: &ShSettings,
) -> Result<(crate::output::Image, ShStats), SolverError> {
    let object = scene.object.as_ref().ok_or_else(|| {
        SolverError::Unsupported(
            "sh-single renders [[object]] meshes (thesis ch. 3: translucent objects); the scene has none".into(),
        )
    })?;
    let clock = std::time::Instant::now();
    let samples = poisson_samples(object, set.samples, set.seed);
    let gs = GpuScene::upload_with(gpu, scene, false, super::gpu_scene::MAJORANT_CELL)?;
    let q = Quadrature::product(12, 24);
    let step = (object.mesh.bounds().1 - object.mesh.bounds().0).length() / 256.0;
    let params = device_params(gpu, &gs, object, &samples, set.order, &q, set.width_scale, step)?;
    // Light terms: each point or directional light's irradiance at the sample, attenuated by
    // the sample's reconstructed psi toward it and the Fresnel transmittance on the way.
    let mut env = Vec3::ZERO;
    let mut lights: Vec<(Vec3, Vec3, bool)> = Vec::new(); // (position or travel direction, value, point)
    for l in &scene.lights {
        match l {
            crate::scene::Light::Point { position, intensity } => lights.push((*position, *intensity, true)),
            crate::scene::Light::Directional { direction, irradiance } => lights.push((*direction, *irradiance, false)),
            crate::scene::Light::Environment { radiance } => env += *radiance,
        }
    }
    let nu = partition_weights(&samples, &params);
    let mut sample_words: Vec<[f32; 4]> = Vec::with_capacity(2 * samples.len());
    let mut coeffs: Vec<f32> = Vec::with_capacity(samples.len() * 3 * sh::coefficients(set.order));
    let mut lterms: Vec<[f32; 4]> = Vec::with_capacity(2 * samples.len() * lights.len().max(1));
    for ((s, p), nu) in samples.iter().zip(&params).zip(&nu) {
        let g = object.materials[s.material].g;
        sample_words.push([s.position.x, s.position.y, s.position.z, p.a]);
        sample_words.push([p.sigma_s[0] * nu, p.sigma_s[1] * nu, p.sigma_s[2] * nu, g]);
        for c in 0..3 {
            coeffs.extend_from_slice(&p.sh[c]);
        }
        for (pos, value, point) in &lights {
            let (w, e) = if *point {
                let to = *pos - s.position;
                let r2 = to.length_squared().max(1e-12);
                (to / r2.sqrt(), *value / r2)
            } else {
                (-*pos, *value)
            };
            let y = sh::basis(set.order, [w.x as f64, w.y as f64, w.z as f64]);
            let ft = boundary_factor(object, s.position, w);
            let att: [f32; 3] = std::array::from_fn(|c| {
                let psi: f64 = p.sh[c].iter().zip(&y).map(|(k, yk)| *k as f64 * yk).sum();
                (psi.max(0.0) * ft) as f32 * e[c]
            });
            lterms.push([att[0], att[1], att[2], 0.0]);
            lterms.push([w.x, w.y, w.z, 0.0]);
        }
    }
    if lterms.is_empty() {
        lterms.push([0.0; 4]);
    }
    let sample_buf = gpu.buffer_with("sh-single samples", &sample_words)?;
    let coeff_buf = gpu.buffer_with("sh-single coefficients", &coeffs)?;
    let light_buf = gpu.buffer_with("sh-single light terms", &lterms)?;
    let sample_bytes = sample_buf.size() + coeff_buf.size() + light_buf.size();
    let preprocess_s = clock.elapsed().as_secs_f64();
    let clock = std::time::Instant::now();
    let (w, h) = (scene.render.width, scene.render.height);
    let image_buf = gpu.buffer("sh-single radiance", w as u64 * h as u64 * 16)?;
    let pipeline = gpu.pipeline(&RENDER, &gs.modelled.mesh_spec())?;
    // The environment's mean boundary factor at the first object's index.
    let env_factor = environment_factor(object.materials[0].ior as f64) as f32;
    let n = samples.len() as u32;
    let mut passes = Vec::new();
    let mut first = 0u32;
    loop {
        let count = (n - first).min(CHUNK);
        passes.push(
            gs.bind_mesh(Pass::new("sh_single.render", QueueRole::Trace, &pipeline))
                .read(3, &sample_buf)
                .read(4, &coeff_buf)
                .read(5, &light_buf)
                .read_write(8, &image_buf)
                .push(&RenderPush {
                    first,
                    count,
                    order: set.order as u32,
                    lights: lights.len() as u32,
                    env: [env.x, env.y, env.z, if first == 0 { 1.0 } else { 0.0 }],
                    env_factor,
                    step,
                    pad: [0; 2],
                })
                .cover([w, h, 1]),
        );
        first += count;
        if first >= n {
            break;
        }
    }
    let point = gpu.submit(QueueRole::Trace, &passes, &[])?;
    gpu.wait(point)?;
    let px: Vec<[f32; 4]> = gpu.read_buffer_as(&image_buf)?;
    let mut image = crate::output::Image::new(w, h);
    for (rgb, p) in image.data.chunks_exact_mut(3).zip(&px) {
        for (o, v) in rgb.iter_mut().zip(p) {
            *o = if v.is_finite() { *v } else { 0.0 };
        }
    }
    let render_s = clock.elapsed().as_secs_f64();
    Ok((image, ShStats { samples: samples.len(), sample_bytes, preprocess_s, render_s }))
}
