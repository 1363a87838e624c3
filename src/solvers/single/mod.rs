//! Solver `single`: the direct term by camera-ray marching with shadow transmittance to each
//! light and the exact phase function: the shared view pass ([`crate::solvers::parts::view`]) with no
//! multiple-scattering volume. It converges to `path --set path.max_depth=1` as the step
//! shrinks (tests/solvers.rs). Knobs: the view march's, unprefixed (`scatterlab knobs single`),
//! and `refraction`.
//!
//! Scene format v2 [[object]] meshes: the medium is inside the mesh, and with ior != 1 the
//! camera ray refracts where it enters (Fresnel F reflected, 1 - F refracted) and goes straight
//! inside; shadow rays go straight toward each light, scaled by the Fresnel transmittance of
//! every surface they cross (thesis 3.1.1, eq. 3.2 with L_t = F_t L_i). What it leaves out
//! against `path --set path.max_depth=1`: light reaching a point along a refracted path (a
//! point light outside is seen along the straight line, so its caustics and the focusing of
//! the surface are missing) and internal reflections on the light's side (docs/measurements.md, "Objects in `single`").

use crate::gpu::{Gpu, Kernel};
use crate::scene::Scene;

use crate::solvers::interface::{Knob, Knobs, RenderOutput, RenderRequest, Rung, Solver, SolverError, Variant};
use crate::solvers::parts::gpu_scene;
use crate::solvers::parts::view::{self, ViewSettings};

pub struct Single;

impl Solver for Single {
    fn name(&self) -> &'static str {
        "single"
    }

    fn about(&self) -> &'static str {
        "single scattering by camera-ray marching with shadow rays: the direct term (thesis 1.3.6, 2.5)"
    }

    fn knobs(&self) -> Vec<Knob> {
        let mut k = view::knobs();
        k.push(Knob::fixed(
            "refraction",
            "true",
            crate::solvers::interface::Range::Bool,
            "with a refractive [[object]] (ior != 1): Fresnel and Snell at its surface; false renders its boundary \
             as index-matched (what refraction changes)",
        ));
        k
    }

    fn kernels(&self) -> Vec<Kernel> {
        vec![view::MARCH, view::SHADOW]
    }

    fn render(&self, gpu: &Gpu, req: &RenderRequest) -> Result<RenderOutput, SolverError> {
        let scene = req.scene;
        let k = req.knobs(self)?;
        let mut v = ViewSettings::parse(&k, "", scene)?;
        v.refraction = k.get::<bool>("refraction")?;
        k.finish()?;
        view::render_alone(gpu, self, req, &k, &v)
    }

    /// The view march's trust warning, before the device opens ([`view::ViewTrust`]).
    fn preflight(&self, scene: &Scene, knobs: &Knobs) -> Result<Vec<String>, SolverError> {
        let v = ViewSettings::parse(knobs, "", scene)?;
        let trust = view::ViewTrust::of(scene, &v).warning(self.name());
        Ok(trust.into_iter().chain(view::unscattered_emission_warning(self.name(), scene)).collect())
    }

    fn summary(&self, report: &crate::solvers::interface::RenderReport) -> Vec<String> {
        view::trust_summary(self.name(), report)
    }

    fn memory_estimate(&self, scene: &Scene, knobs: &Knobs) -> Result<u64, SolverError> {
        let v = ViewSettings::parse(knobs, "", scene)?;
        Ok(gpu_scene::scene_bytes(scene) + view::device_bytes(scene, &v))
    }

    fn ladder(&self, scene: &Scene) -> Vec<Rung> {
        let diag = (scene.medium.bounds_max - scene.medium.bounds_min).length();
        [16.0f32, 32.0, 64.0, 128.0, 256.0].iter().map(|d| Rung::one("single.step", diag / d)).collect()
    }

    /// single traces [[object]] meshes (glsl/view/march.comp's chain, glsl/include/mesh.glsl).
    /// Emission along the camera ray (the zero-scattering term, glsl/view/march.comp); the
    /// emitted light the medium scatters is not single scattering of a light and is left out.
    fn renders_emission(&self) -> bool {
        true
    }

    fn renders_meshes(&self) -> bool {
        true
    }

    /// The view march follows the camera ray's chain into each object with its material, and
    /// a shadow ray through each object it crosses with that object's (glsl/view/march.comp
    /// seg_mat, optical_depth).
    fn renders_materials(&self) -> bool {
        true
    }

    fn stability(&self) -> Vec<Variant> {
        vec![Variant::new("", &[("single.env_dirs", "16")])]
    }
}
