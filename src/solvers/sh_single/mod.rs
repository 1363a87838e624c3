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

mod index;
mod render;
mod sampling;
pub use index::*;
pub use render::*;
pub use sampling::*;

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

/// Gaussians narrower than a Poisson radius stop overlapping: the partition of unity that
/// spreads each sample's attenuation over its neighbourhood (thesis 3.3.2, eq. 3.3) turns
/// into spots about each sample. Homogeneous sphere, 64^2, 4000 samples, against `single`:
/// relL2 0.216 at the default 1.5, 0.209 at 3, 0.28 at 1, 0.51 at 0.6, 1.21 at 0.3, 1.18 at 0.1,
/// 0.63 (energy 0.66) at 1e-30.
pub const WIDTH_SCALE_MIN: f32 = 1.0;

fn width_warning(set: &ShSettings) -> Option<String> {
    (set.width_scale < WIDTH_SCALE_MIN).then(|| {
        format!(
            "sh-single: sh-single.width_scale = {} Poisson radii is below {WIDTH_SCALE_MIN}, where the samples' \
             Gaussians stop overlapping and the image breaks into spots about them (homogeneous sphere: relL2 against \
             single 0.22 at 1.5, 0.51 at 0.6, 1.2 at 0.3); set sh-single.width_scale=1.5",
            if set.width_scale >= 1e-4 { set.width_scale.to_string() } else { format!("{:e}", set.width_scale) }
        )
    })
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
    /// How far to trust the sample set: the surface's spacing in mean free paths.
    pub trust: SampleTrust,
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
        let (faults, nonfinite) = (st.nonfinite_pixels as u64, st.nonfinite_pixels);
        let trust_warnings = st.trust.warnings();
        let mut stats = Stats::new(st);
        stats.faults = faults;
        let mut report = RenderReport::finish(gpu, self, &k, modelled, bytes, stats);
        report.warnings.extend(trust_warnings);
        report.warnings.extend(width_warning(&set));
        report.warnings.extend(crate::solvers::parts::view::unscattered_emission_warning(self.name(), req.scene));
        report.zeroed_nonfinite(nonfinite);
        Ok(RenderOutput { image, variance: None, report, estimates: Vec::new() })
    }

    fn preflight(&self, scene: &Scene, knobs: &Knobs) -> Result<Vec<String>, SolverError> {
        let set = ShSettings::parse(knobs, scene)?;
        let os = object_scene(scene);
        let object = os.object.as_ref().expect("object scene");
        let mut w = SampleTrust::of(&os, object, set.samples, set.seed).warnings();
        w.extend(width_warning(&set));
        w.extend(crate::solvers::parts::view::unscattered_emission_warning(self.name(), scene));
        Ok(w)
    }

    fn memory_estimate(&self, scene: &Scene, knobs: &Knobs) -> Result<u64, SolverError> {
        let set = ShSettings::parse(knobs, scene)?;
        let os = object_scene(scene);
        // The sample count is the sampler's (deterministic for the seed): drawn here as the
        // render draws it.
        let object = os.object.as_ref().expect("object scene");
        // (in the sampler's order: the grid index's size does not depend on it)
        let samples = if scene.scatters() {
            poisson_draw(object, set.samples, set.seed, set.heuristic, set.placement).0
        } else {
            Vec::new() // (none drawn where nothing scatters: render.rs, `render`)
        };
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

    /// Emission along the camera ray's inside segments (the zero-scattering term,
    /// glsl/sh_single/render.comp `segment_emission`); the emitted light the medium scatters is
    /// not single scattering of a light, and is left out.
    fn renders_emission(&self) -> bool {
        true
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
        if s.samples == 0 {
            return vec![format!(
                "sh-single: nothing scatters: no samples drawn, the image is the camera ray's transmittance, emission \
                 and environment (exact); render {:.2} s",
                s.render_s
            )];
        }
        vec![
            format!(
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
            ),
            format!("sh-single: {}", s.trust.line()),
        ]
    }
}
