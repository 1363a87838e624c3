//! Solver `octaves`: the production baseline. Multiple scattering approximated by octaves of
//! single scattering (Wrenninge, Kulla, Lundqvist, "Oz: the Great and Volumetric", SIGGRAPH
//! 2013 talk; Hillaire, "Physically based sky, atmosphere and cloud rendering in Frostbite",
//! SIGGRAPH 2016 course): at each camera-ray step the light reaching it through optical depth
//! tau is scattered as
//!   L_ms = sum_{i = 0}^{N-1} b^i sigma_s p(theta; g c^i) exp(-a^i tau) L_light,
//! octave 0 being exact single scattering. Later octaves see the light through less of the
//! medium (a < 1), contribute less (b < 1) and scatter less forward (c < 1): a cheap stand-in
//! for the light that reaches deep into a medium by many scattering events. It is what
//! production renderers ship for clouds; users ask whether a seed method beats it, and `bench`
//! answers on their scenes. It is a heuristic: it converges to nothing as N grows, and it
//! knows no albedo beyond the first scattering (sigma_s enters once per octave).
//!
//! Deviation (`form = bounded`, the default): the published sum creates energy in optically
//! thin media. Each octave is first order in the optical depth, like single scattering, so as
//! tau -> 0 the sum tends to (1 + b + ... + b^(N-1)) times single scattering (1.875x at the
//! defaults) where true multiple scattering vanishes as tau^2; `stability` measured it 89%
//! above the lossless bound with a light inside a medium of optical thickness 1e-3, and 6%
//! above the furnace's radiance at thickness 0.1. It also knows no albedo beyond the first
//! scattering: at albedo 0.5 it is 1.2-1.5x too bright. The bounded form weights octave i by
//! (albedo (1 - exp(-tau_chord)))^i, with tau_chord the optical depth of the chord through the
//! point along the light's direction: the chance that light crossing the medium there is
//! scattered, not absorbed, i more times. Of order (albedo tau)^i in thin media, as i + 1-fold
//! scattering is; albedo^i in thick ones. It costs one more shadow march per light per step
//! and passes the sweep; `form = published` keeps the formula as given, for comparison
//! (docs/octaves.md has both against `path` across thickness, albedo and g).
//!
//! Built on the shared view pass ([`crate::solvers::parts::view`], the sum in glsl/view/march.comp with
//! `OCTAVES` as a specialisation constant): no state beyond the view march. Knobs: `n`, `a`,
//! `b`, `c` and the view march's as `view_*` (`scatterlab knobs octaves`).

use crate::gpu::{Gpu, Kernel};
use crate::scene::Scene;

use crate::solvers::interface::{Knob, Knobs, Range, RenderOutput, RenderRequest, Rung, Solver, SolverError, Variant};
use crate::solvers::parts::gpu_scene;
use crate::solvers::parts::view::{self, Octaves, ViewSettings, MAX_OCTAVES};

pub struct OctavesSolver;

impl OctavesSolver {
    fn parse(k: &Knobs, scene: &Scene) -> Result<ViewSettings, SolverError> {
        let mut v = ViewSettings::parse(k, "view_", scene)?;
        let bounded = k.get::<String>("form")? == "bounded";
        v.octaves = Octaves { n: k.get("n")?, a: k.get("a")?, b: k.get("b")?, c: k.get("c")?, bounded };
        v.fit_shadow(k, scene)
    }
}

impl Solver for OctavesSolver {
    /// Emission along the camera ray (the zero-scattering term, glsl/view/march.comp); its
    /// octaves scatter the lights' light only, so emitted light that scatters is left out.
    fn renders_emission(&self) -> bool {
        true
    }

    fn name(&self) -> &'static str {
        "octaves"
    }

    fn about(&self) -> &'static str {
        "multiple scattering as octaves of single scattering (Wrenninge et al. 2013): the production baseline"
    }

    fn knobs(&self) -> Vec<Knob> {
        let mut k = vec![
            Knob::fixed(
                "n",
                "4",
                Range::int(1, MAX_OCTAVES as u64),
                "octaves N (1: single scattering; Hillaire 2016 uses 3 to 8)",
            ),
            Knob::fixed(
                "a",
                "0.5",
                Range::Real { min: 0.0, max: 1.0, min_open: false, max_open: false },
                "attenuation: octave i sees the light through a^i of the optical depth",
            ),
            Knob::fixed(
                "b",
                "0.5",
                Range::Real { min: 0.0, max: 1.0, min_open: false, max_open: false },
                "contribution: octave i is weighted b^i",
            ),
            Knob::fixed(
                "c",
                "0.5",
                Range::Real { min: 0.0, max: 1.0, min_open: false, max_open: false },
                "eccentricity: octave i scatters with Henyey-Greenstein g c^i",
            ),
            Knob::fixed(
                "form",
                "bounded",
                Range::Choice(&["bounded", "published"]),
                "bounded: octave i also weighted by (albedo (1 - exp(-tau_chord)))^i, so no energy is created; \
                 published: the sum as Wrenninge et al. give it (up to 1/(1-b) times too bright as tau -> 0)",
            ),
        ];
        k.extend(view::knobs().into_iter().map(|k| k.prefixed("view_")));
        k
    }

    fn kernels(&self) -> Vec<Kernel> {
        vec![view::MARCH, view::SHADOW]
    }

    fn render(&self, gpu: &Gpu, req: &RenderRequest) -> Result<RenderOutput, SolverError> {
        let scene = req.scene;
        let k = req.knobs(self)?;
        let v = Self::parse(&k, scene)?;
        k.finish()?;
        view::render_alone(gpu, self, req, &k, &v)
    }

    /// The view march's trust warning, before the device opens ([`view::ViewTrust`]).
    fn preflight(&self, scene: &Scene, knobs: &Knobs) -> Result<Vec<String>, SolverError> {
        let v = Self::parse(knobs, scene)?;
        let trust = view::ViewTrust::of(scene, &v).warning(self.name());
        Ok(trust.into_iter().chain(view::unscattered_emission_warning(self.name(), scene)).collect())
    }

    fn summary(&self, report: &crate::solvers::interface::RenderReport) -> Vec<String> {
        view::trust_summary(self.name(), report)
    }

    fn memory_estimate(&self, scene: &Scene, knobs: &Knobs) -> Result<u64, SolverError> {
        let v = Self::parse(knobs, scene)?;
        Ok(gpu_scene::scene_bytes(scene) + view::device_bytes(scene, &v))
    }

    fn ladder(&self, _scene: &Scene) -> Vec<Rung> {
        [1u32, 2, 3, 4, 6, 8].iter().map(|n| Rung::one("octaves.n", n)).collect()
    }

    fn stability(&self) -> Vec<Variant> {
        // The published sum, kept to compare against: it creates energy in optically thin
        // media, so it is expected to fail there.
        let mut published =
            Variant::new("published", &[("octaves.view_env_dirs", "16"), ("octaves.form", "published")]);
        published.comparison = true;
        vec![Variant::new("", &[("octaves.view_env_dirs", "16")]), published]
    }
}
