//! sh-single's render pass: the lights' and environment's terms per sample, the partition
//! weights and gradients, and the integral of every sample's Gaussian along each camera ray
//! in closed form (thesis 3.4; glsl/sh_single/render.comp).

use super::*;
use crate::gpu::Buffer;

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

/// glsl/sh_single/render.comp: the render pass (thesis 3.4).
pub const RENDER: Kernel =
    Kernel { shader: shader!("sh_single/render"), push_bytes: std::mem::size_of::<RenderPush>(), spec: MESH_SPEC };

/// Most samples per render dispatch.
pub(super) const CHUNK: u32 = 2048;

// glsl/include/budget.glsl's LOOP_GUARD: past it llvmpipe's loop limiter may have fired.
use crate::solvers::parts::resumable::LOOP_GUARD;

/// The directions psi is projected with: an n x 2n product rule (Gauss-Legendre in the cosine,
/// uniform in azimuth) of about `directions` directions, n = round(sqrt(directions / 2)), at
/// least 2 (the default 288 is 12 x 24, which integrates the product of two order-8 functions
/// exactly; the thesis projects with 128 to 2048 Monte Carlo directions, 3.3.1 and table 3.1).
pub(super) fn projection_quadrature(directions: u32) -> Quadrature {
    let n = ((directions as f64 / 2.0).sqrt().round() as usize).max(2);
    Quadrature::product(n as u32, 2 * n as u32)
}

/// The step of the chords' and optical depths' midpoint rule through grid densities: 1/256
/// of the object's box diagonal.
pub(super) fn density_step(object: &Object) -> f32 {
    let (lo, hi) = object.mesh.bounds();
    (hi - lo).length() / 256.0
}

/// The scene sh-single renders: the scene's [[object]]s, or a v1 medium's box as an
/// index-matched object ([`Object::box_of`]; the method samples an object's interior).
pub(super) fn object_scene(scene: &Scene) -> Scene {
    let mut s = scene.clone();
    if s.object.is_none() {
        s.object = Some(Object::box_of(&s.medium));
    }
    s
}

/// Point and directional lights as (position or travel direction, intensity or irradiance,
/// is a point light), and the constant environments' summed radiance.
pub(super) fn split_lights(scene: &Scene) -> (Vec<(Vec3, Vec3, bool)>, Vec3) {
    // The environment lights in one sum, in scene order (the one path and networks use).
    let lights = scene
        .lights
        .iter()
        .filter_map(|l| match l {
            Light::Point { position, intensity } => Some((*position, *intensity, true)),
            Light::Directional { direction, irradiance } => Some((*direction, *irradiance, false)),
            Light::Environment { .. } => None,
        })
        .collect();
    (lights, scene.environment_radiance())
}

/// Whether each sample holds a second coefficient set for the environment (psi times the
/// boundary factor): a refractive object under an environment.
pub(super) fn env_coefficients(os: &Scene) -> bool {
    os.object.as_ref().is_some_and(|o| o.refractive()) && split_lights(os).1.max_element() > 0.0
}

/// Device bytes of a render of `os` (the object scene) with `n` samples drawn: the scene with
/// its mesh, the depth pass's buffers, the sample set, the image. What [`render`] allocates.
pub(super) fn device_bytes(os: &Scene, samples: &[Sample], set: &ShSettings) -> u64 {
    let n = samples.len();
    let order = set.order;
    // The grid index's two buffers, or two 16-byte stand-ins.
    let index = match set.index {
        SampleIndex::Grid if n > 0 => {
            let centres: Vec<Vec3> = samples.iter().map(|s| s.position).collect();
            GaussianIndex::build(&centres, &sample_reach(samples, set.width_scale)).bytes()
        }
        _ => 32,
    };
    let (lights, _) = split_lights(os);
    let env_set = env_coefficients(os);
    let dirs = projection_quadrature(set.directions).directions.len();
    let b = |bytes: usize| (bytes as u64).max(4);
    // (no depth pass without samples, and a one-word sample buffer: `upload_samples`)
    let depth_pass = if n == 0 { 0 } else { b(n * 16) + b(dirs * 16) + b(n.min(depth_chunk(dirs)) * dirs * 16) };
    gpu_scene::scene_bytes(os)
        + depth_pass
        + (SAMPLE_WORDS * n * 16).max(16) as u64
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
pub(super) fn boundary_factor_within(object: &Object, p: Vec3, w: Vec3, t_max: f32) -> f64 {
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
pub(super) const PARTITION_POINTS_PER_SAMPLE: usize = 64;
pub(super) const PARTITION_POINTS_MAX: usize = 4_000_000;

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
    let mut h = (volume / points).cbrt() as f32;
    let dims_of = |h: f32| [0, 1, 2].map(|k| ((extent[k] / h).ceil() as usize).max(1));
    // The spacing from the volume fits a medium about as thick as it is wide; where one side is
    // far thinner than the spacing (a slab of thickness 1e-7 across a unit square asked for 2e8
    // columns, 30 GB), the box's other sides set the count: coarsen until it is within 2x.
    while dims_of(h).iter().map(|d| *d as f64).product::<f64>() > 2.0 * points {
        h *= 1.25;
    }
    let dims = dims_of(h);
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

/// Words per sample and light in the light-term buffer: the unattenuated irradiance, the unit
/// direction toward the light, and per channel the gradient of the optical depth toward it with
/// that depth ([`tau_gradient`]).
pub(super) const LIGHT_WORDS: usize = 5;

/// Grazing crossings: |cos| of the ray with a surface's normal is taken as at least this in the
/// optical depth's gradient, which grows as 1 / cos.
pub(super) const MIN_GRADIENT_COS: f32 = 0.2;

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
pub(super) fn reconstruct(coeffs: &[f32], y: &[f64]) -> f64 {
    coeffs.iter().zip(y).map(|(k, yk)| *k as f64 * yk).sum()
}

/// Words per sample in the sample buffer (glsl/sh_single/render.comp): centre and width,
/// nu sigma_s and g, nu, and per channel the environment's gradient ([`environment_gradient`]).
pub(super) const SAMPLE_WORDS: usize = 6;

/// The environment's attenuation at a sample, psi averaged over directions, as one optical depth
/// with a gradient, per channel ([gradient, depth]): the gradient is the psi-weighted mean of
/// [`tau_gradient`] over `dirs` (direction, quadrature weight, its basis), the depth -ln of the
/// mean of psi. Under a surface the environment's light falls off as steeply as a light's; the
/// render varies it across the Gaussian with this gradient, as it does a light's.
pub(super) fn environment_gradient(
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
pub(super) const MAX_COVERAGE_SCALE: f32 = 4.0;

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
pub(super) fn resolve(p: &[[f32; 4]]) -> [f32; 3] {
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

/// The image from the render pass's per-pixel sums ([`resolve`]), non-finite pixels set to 0
/// and counted.
fn resolve_image(px: &[[f32; 4]], w: u32, h: u32) -> (Image, u32) {
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
    (image, nonfinite)
}

/// One direction of the coarse rule the environment's gradient is averaged over: the direction,
/// its weight and its SH basis.
type EnvDirection = (Vec3, f64, Vec<f64>);

/// What the render pass reads of one sample (thesis 3.4): its two words (position and Gaussian
/// width, sigma_s times its partition weight nu and g), the environment's gradient, its SH
/// coefficients (and the environment's), and per light the irradiance at the sample attenuated
/// by psi toward the light (exactly, by the host's walk, toward a point light inside the
/// object, where psi's walk to infinity would overshoot it) times `single`'s boundary factor,
/// the unit direction toward the light and the gradient of the optical depth.
#[allow(clippy::too_many_arguments)]
fn sample_upload(
    object: &Object,
    (s, p, nu): (&Sample, &SampleParams, f32),
    (lights, inside): (&[(Vec3, Vec3, bool)], &[bool]),
    (env, env_set, env_dirs): (Vec3, bool, &[EnvDirection]),
    order: usize,
    step: f32,
) -> SampleUpload {
    let g = object.materials[s.material].g;
    let mut words = [[0.0f32; 4]; SAMPLE_WORDS];
    words[0] = [s.position.x, s.position.y, s.position.z, p.a];
    words[1] = [p.sigma_s[0] * nu, p.sigma_s[1] * nu, p.sigma_s[2] * nu, g];
    words[2] = [nu, 0.0, 0.0, 0.0];
    if env.max_element() > 0.0 {
        let sh = if env_set { p.sh_env.as_ref().unwrap_or(&p.sh) } else { &p.sh };
        words[3..6].copy_from_slice(&environment_gradient(object, s, sh, env_dirs));
    }
    let mut coeffs: Vec<f32> = p.sh.iter().flatten().copied().collect();
    if env_set {
        coeffs.extend(p.sh_env.iter().flatten().flatten().copied());
    }
    let mut lt = Vec::with_capacity(LIGHT_WORDS * lights.len());
    for ((pos, value, point), inside) in lights.iter().zip(inside) {
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
                let y = sh::basis(order, [w.x as f64, w.y as f64, w.z as f64]);
                std::array::from_fn(|c| -reconstruct(&p.sh[c], &y).max(1e-30).ln())
            }
        };
        let ft = boundary_factor_within(object, s.position, w, t_max);
        let grad = tau_gradient(object, s.position, s.material, w, t_max);
        // The light before its attenuation (boundary factor times irradiance): the render
        // attenuates it by exp(-tau_l) from the depth and gradient below, floored at zero depth
        // (glsl/sh_single/render.comp, lit_gaussian), so no product of a tiny attenuation and
        // its large inverse is ever formed.
        let unattenuated: [f32; 3] = std::array::from_fn(|c| ft as f32 * e[c]);
        lt.push([unattenuated[0], unattenuated[1], unattenuated[2], 0.0]);
        lt.push([w.x, w.y, w.z, 0.0]);
        for c in 0..3 {
            lt.push([grad[c].x, grad[c].y, grad[c].z, tau_l[c].min(1e30) as f32]);
        }
    }
    (words, coeffs, lt)
}

/// The samples on the device, and what the render pass needs of them on the host.
struct SampleBuffers {
    sample: Buffer,
    coeff: Buffer,
    light: Buffer,
    starts: Buffer,
    items: Buffer,
    n: u32,
    centres: Vec<Vec3>,
    reach: Vec<f32>,
    index: Option<GaussianIndex>,
    boxes: bool,
}

impl SampleBuffers {
    fn bytes(&self) -> u64 {
        self.sample.size() + self.coeff.size() + self.light.size() + self.starts.size() + self.items.size()
    }
}

/// The samples on the device ([`SampleBuffers`]): per sample its two words, its coefficients,
/// and per light its light term; the Gaussians' reach and the cell index where sh-single.index
/// asks for one.
fn upload_samples(
    gpu: &Gpu,
    (os, object): (&Scene, &Object),
    (samples, params, nu): (&[Sample], &[SampleParams], &[f32]),
    (lights, inside): (&[(Vec3, Vec3, bool)], &[bool]),
    set: &ShSettings,
    step: f32,
) -> Result<SampleBuffers, SolverError> {
    // Per sample: its two words, its coefficients, and per light the irradiance at the sample
    // attenuated by psi toward the light (exactly, by the host's walk, toward a point light
    // inside the object, where psi's walk to infinity would overshoot it) and `single`'s
    // boundary factor, and the unit direction toward the light.
    use rayon::prelude::*;
    let (env, env_set) = (split_lights(os).1, env_coefficients(os));
    // The environment's gradient is averaged over a coarse product rule (4 x 8 directions,
    // their basis once).
    let env_dirs: Vec<EnvDirection> = {
        let q = Quadrature::product(4, 8);
        q.directions
            .iter()
            .zip(&q.weights)
            .map(|(d, w)| (glam::DVec3::from_array(*d).as_vec3(), *w, sh::basis(set.order, *d)))
            .collect()
    };
    let per_sample: Vec<SampleUpload> = samples
        .par_iter()
        .zip(params)
        .zip(nu)
        .map(|((s, p), nu)| {
            sample_upload(object, (s, p, *nu), (lights, inside), (env, env_set, &env_dirs), set.order, step)
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
    // (no sample where nothing scatters: one zero word each, a buffer cannot be empty)
    if lterms.is_empty() {
        lterms.push([0.0; 4]);
    }
    if sample_words.is_empty() {
        sample_words.push([0.0; 4]);
        coeffs.push(0.0);
    }
    let sample_buf = gpu.buffer_with("sh-single samples", &sample_words)?;
    let coeff_buf = gpu.buffer_with("sh-single coefficients", &coeffs)?;
    let light_buf = gpu.buffer_with("sh-single light terms", &lterms)?;
    let centres: Vec<Vec3> = samples.iter().map(|s| s.position).collect();
    let reach = sample_reach(samples, set.width_scale);
    let index = (set.index == SampleIndex::Grid && !samples.is_empty()).then(|| GaussianIndex::build(&centres, &reach));
    let boxes = set.index != SampleIndex::None && !samples.is_empty();
    let (starts_buf, items_buf) = match &index {
        Some(ix) => (
            gpu.buffer_with("sh-single index cells", &ix.starts)?,
            gpu.buffer_with("sh-single index items", &ix.items)?,
        ),
        None => (gpu.buffer("sh-single index (none)", 16)?, gpu.buffer("sh-single index (none)", 16)?),
    };
    Ok(SampleBuffers {
        sample: sample_buf,
        coeff: coeff_buf,
        light: light_buf,
        starts: starts_buf,
        items: items_buf,
        n: samples.len() as u32,
        centres,
        reach,
        index,
        boxes,
    })
}

/// The render pass (glsl/sh_single/render.comp): every camera ray gathers the samples in chunks
/// of `chunk`, the passes of one image submitted together; where the kernel reports a chain past
/// the loop guard, the image is rendered again with half the chunk. Returns the chunk and the
/// dispatches.
fn render_pass(
    gpu: &Gpu,
    gs: &GpuScene,
    set: &ShSettings,
    up: &SampleBuffers,
    (lights, env, env_set, step): (usize, Vec3, bool, f32),
    (image_buf, stats_buf, w, h): (&Buffer, &Buffer, u32, u32),
) -> Result<(u32, u64), SolverError> {
    let pipeline = gpu.pipeline(&RENDER, &gs.modelled.mesh_spec())?;
    let (n, index, centres, reach) = (up.n, &up.index, &up.centres, &up.reach);
    // llvmpipe's loop limiter (glsl/include/budget.glsl) counts every back-edge of an
    // invocation: a sample the camera ray reaches costs 4 + 4 lights of them per inside segment
    // (glsl/sh_single/render.comp, segment_light), order^2 + 3 more with an environment and
    // order^2 more in a grid density (psi toward the camera). Chunks start where a ray reaching
    // every sample of one segment stays within the guard; where the kernel reports more (many
    // segments), the render is run again with half the chunk.
    let n_coeff = sh::coefficients(set.order);
    let per_sample = (4
        + 4 * lights
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
    loop {
        let mut passes = Vec::new();
        let mut first = 0u32;
        loop {
            let count = (n - first).min(chunk);
            let (bl, bh) = chunk_box(centres, reach, first as usize, count as usize);
            passes.push(
                gs.bind_emission(gs.bind_mesh(Pass::new("sh_single.render", QueueRole::Trace, &pipeline)))
                    .read(3, &up.sample)
                    .read(4, &up.coeff)
                    .read(5, &up.light)
                    .read_write(8, image_buf)
                    .read_write(9, stats_buf)
                    .read(10, &up.starts)
                    .read(11, &up.items)
                    .push(&RenderPush {
                        first,
                        count,
                        order: set.order as u32,
                        lights: lights as u32,
                        env: [env.x, env.y, env.z, if first == 0 { 1.0 } else { 0.0 }],
                        env_coeffs: env_set as u32,
                        step,
                        pad: [0; 2],
                        grid: index.as_ref().map_or([0.0; 4], |ix| [ix.origin.x, ix.origin.y, ix.origin.z, ix.cell]),
                        grid_dims: index.as_ref().map_or([0; 4], |ix| [ix.dims[0], ix.dims[1], ix.dims[2], 1]),
                        box_lo: [bl.x, bl.y, bl.z, if up.boxes { 1.0 } else { 0.0 }],
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
        let most: Vec<u32> = gpu.read_buffer_as(stats_buf)?;
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
        gpu.fill_zero(stats_buf)?;
    }
    Ok((chunk, dispatches))
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
    // Where nothing scatters the samples' in-scattering is zero: the image is the camera ray's
    // transmittance, emission and environment alone (the surfaces' terms of the render pass,
    // exact), so no sample is drawn, no optical depth marched and the pass runs once with none
    // (7.0 s -> 0.2 s on the default scene at albedo 0, 128^2).
    let scatters = scene.scatters();
    let mut samples =
        if scatters { poisson_draw(object, set.samples, set.seed, set.heuristic, set.placement).0 } else { Vec::new() };
    let (lo, hi) = object.mesh.bounds();
    sort_spatially(&mut samples, lo, hi);
    let sampling_s = clock.elapsed().as_secs_f64();
    progress(Progress::work("preprocessing: samples, optical depths, light terms", 1, 3));
    let gs = GpuScene::upload_with(gpu, &os, force_full, gpu_scene::MAJORANT_CELL)?;
    let q = projection_quadrature(set.directions);
    let step = density_step(object);
    let (params, depth_bytes) = if samples.is_empty() {
        (Vec::new(), 0)
    } else {
        device_params(gpu, &gs, object, &samples, set.order, &q, set.width_scale, step)?
    };
    let depths_s = clock.elapsed().as_secs_f64() - sampling_s;
    progress(Progress::work("preprocessing: samples, optical depths, light terms", 2, 3));
    let (lights, env) = split_lights(&os);
    // Which point lights lie inside the objects (their light terms walk to the light), once.
    let inside: Vec<bool> = lights.iter().map(|(pos, _, point)| *point && object.contains(*pos)).collect();
    let nu = partition_weights(object, &samples, &params);
    let weights_s = clock.elapsed().as_secs_f64() - sampling_s - depths_s;
    let up = upload_samples(gpu, (&os, object), (&samples, &params, &nu), (&lights, &inside), set, step)?;
    let preprocess_s = clock.elapsed().as_secs_f64();
    progress(Progress::work("preprocessing: samples, optical depths, light terms", 3, 3));
    let clock = std::time::Instant::now();
    let (w, h) = (os.render.width, os.render.height);
    let image_buf = gpu.buffer("sh-single radiance", w as u64 * h as u64 * 64)?;
    let stats_buf = gpu.buffer("sh-single stats", 16)?;
    progress(Progress::work("render pass", 0, 1));
    let (chunk, dispatches) = render_pass(
        gpu,
        &gs,
        set,
        &up,
        (lights.len(), env, env_coefficients(&os), step),
        (&image_buf, &stats_buf, w, h),
    )?;
    progress(Progress::work("render pass", 1, 1));
    let (image, nonfinite) = resolve_image(&gpu.read_buffer_as::<[f32; 4]>(&image_buf)?, w, h);
    let render_s = clock.elapsed().as_secs_f64();
    let sample_bytes = up.bytes();
    let bytes = gs.bytes + depth_bytes + sample_bytes + image_buf.size() + stats_buf.size();
    let stats = ShStats {
        requested: set.samples,
        samples: up.n as usize,
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
        trust: SampleTrust::of(&os, object, set.samples, set.seed),
    };
    Ok((image, stats, bytes, gs.modelled.clone()))
}
