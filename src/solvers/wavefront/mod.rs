//! Solver `wavefront`: wavefront tracing of homogeneous spherical layers (Szirmay-Kalos,
//! Liktor, Umenhoffer, Toth, "Fast approximation of multiple scattering in inhomogeneous
//! participating media").
//!
//! Around every point light inside the medium the shared part [`crate::solvers::parts::wave_field`] marches a
//! spherical grid layer by layer (eq. 4-6) and gathers the multiply scattered fluence and
//! vector irradiance onto a Cartesian volume; the view pass ([`crate::solvers::parts::view`]) adds exact single
//! scattering and the two-term in-scattering from that volume (end of section 2.1). Point
//! lights outside the medium, directional and environment lights contribute their exact
//! single scattering only, and the render says so in a warning.
//!
//! Knobs: the wave field's (`nu`, `nv`, `layers`, `integrator`, `boundary`, `explicit_start`, `grid`) and
//! the view march's as `view_*` (`scatterlab knobs wavefront`).

mod trust;

use serde::Serialize;

use crate::gpu::{Gpu, Kernel};
use crate::scene::Scene;

use crate::solvers::interface::Progress;
use crate::solvers::interface::{
    Headline, Knob, Knobs, RenderOutput, RenderReport, RenderRequest, Rung, Solver, SolverError, Stats, Variant,
};
use crate::solvers::parts::gpu_scene::{self, GpuScene};
use crate::solvers::parts::lattice::LatticeGeom;
use crate::solvers::parts::view::{self, ViewSettings};
use crate::solvers::parts::wave_field::{self, wave_volume, WaveSettings, WaveVolume};

pub use trust::WaveTrust;

pub struct Wavefront;

/// `wavefront`'s own stats.
#[derive(Clone, Debug, Serialize)]
pub struct WavefrontStats {
    pub lights_traced: usize,
    pub channels: u32,
    /// The Cartesian volume the field was gathered onto.
    pub cartesian: LatticeGeom,
    /// Grid nodes where the integrator went negative or non-finite, the rays with either, and
    /// the voxels zeroed for it.
    pub negative_nodes: u64,
    pub nonfinite_nodes: u64,
    pub failed_rays: u64,
    pub nonfinite_voxels: u64,
    pub dispatches: u64,
    pub max_loop_iterations: u32,
    pub nonfinite_pixels: u32,
    /// How far to trust the render: its discretisation against what wavefront was validated at.
    pub trust: WaveTrust,
    /// How far to trust the view march that gathers the field toward the camera
    /// (`wavefront.view_step`, `wavefront.view_shadow_step`).
    pub view_trust: view::ViewTrust,
}

/// Warnings a wavefront result carries: lights the method does not trace, and where the
/// explicit integrator failed.
fn warnings(scene: &Scene, set: &WaveSettings, vol: &WaveVolume) -> Vec<String> {
    let mut w = Vec::new();
    let untraced = scene.lights.len() - vol.lights_traced;
    if untraced > 0 {
        w.push(format!(
            "wavefront: {untraced} light(s) are not point lights inside the medium (the method assumes the light \
                inside, paper section 2); they contribute single scattering only"
        ));
    }
    if vol.negative_nodes + vol.nonfinite_nodes > 0 {
        w.push(format!(
            "wavefront: the {:?} integrator went negative at {} and non-finite at {} grid nodes ({} rays); {} voxels \
                were zeroed; use wavefront.integrator=exponential or more wavefront.layers",
            set.integrator, vol.negative_nodes, vol.nonfinite_nodes, vol.failed_rays, vol.nonfinite_voxels
        ));
    }
    w
}

impl Solver for Wavefront {
    fn name(&self) -> &'static str {
        "wavefront"
    }

    fn about(&self) -> &'static str {
        "wavefront tracing of homogeneous spherical layers around point lights inside the medium (Szirmay-Kalos et al.)"
    }

    fn knobs(&self) -> Vec<Knob> {
        let mut k = wave_field::knobs();
        k.extend(view::knobs().into_iter().map(|k| k.prefixed("view_")));
        k
    }

    fn kernels(&self) -> Vec<Kernel> {
        let mut k = wave_field::kernels();
        k.extend([view::MARCH, view::SHADOW]);
        k
    }

    fn render(&self, gpu: &Gpu, req: &RenderRequest) -> Result<RenderOutput, SolverError> {
        let scene = req.scene;
        let k = req.knobs(self)?;
        let set = WaveSettings::parse(&k, "")?;
        let view = ViewSettings::parse(&k, "view_", scene)?;
        k.finish()?;
        let trust = WaveTrust::of(scene, &set);
        let view_trust = view::ViewTrust::of(scene, &view);
        let gs = GpuScene::upload(gpu, scene, req.force_full)?;
        (req.progress)(Progress::work("passes", 0, 2));
        let vol = wave_volume(gpu, scene, &gs, &set, None)?;
        (req.progress)(Progress::work("passes", 1, 2));
        let res = view::march(gpu, scene, &gs, &view, Some(&vol.ms()))?;
        (req.progress)(Progress::work("passes", 2, 2));
        let mut stats = Stats::new(WavefrontStats {
            lights_traced: vol.lights_traced,
            channels: vol.channels,
            cartesian: vol.geom,
            negative_nodes: vol.negative_nodes,
            nonfinite_nodes: vol.nonfinite_nodes,
            failed_rays: vol.failed_rays,
            nonfinite_voxels: vol.nonfinite_voxels,
            dispatches: res.dispatches,
            max_loop_iterations: res.max_loop_iterations,
            nonfinite_pixels: res.nonfinite_pixels,
            trust,
            view_trust,
        });
        // The march's own state went negative or non-finite (the gather clamps it, so the
        // image alone would not show it): a failure of the integrator.
        stats.faults = vol.negative_nodes + vol.nonfinite_nodes + res.nonfinite_pixels as u64;
        let bytes = gs.bytes + vol.device_bytes + res.device_bytes;
        let mut report = RenderReport::finish(gpu, self, &k, gs.modelled.clone(), bytes, stats);
        report.warnings = warnings(scene, &set, &vol);
        report.warnings.extend(trust.warnings());
        report.warnings.extend(view_trust.warning(self.name()));
        report.zeroed_nonfinite(res.nonfinite_pixels);
        Ok(RenderOutput { image: res.image, variance: None, report, estimates: Vec::new() })
    }

    fn memory_estimate(&self, scene: &Scene, knobs: &Knobs) -> Result<u64, SolverError> {
        let set = WaveSettings::parse(knobs, "")?;
        let geom = LatticeGeom::new(scene, set.grid);
        let chromatic = gpu_scene::modelled(scene, false).chromatic;
        let v = ViewSettings::parse(knobs, "view_", scene)?;
        Ok(gpu_scene::scene_bytes(scene) + set.device_bytes(scene, chromatic, &geom) + view::device_bytes(scene, &v))
    }

    /// The paper's headline: a 128 x 128 x 64 wave field (rays in azimuth and elevation, layers)
    /// in 30 ms.
    fn headline(&self, quick: bool) -> Option<Headline> {
        let (nu, layers, size) = if quick { ("16", "8", "64") } else { ("128", "64", "512") };
        Some(Headline::new(
            format!("wavefront cloud {nu} x {nu} x {layers}, {size}^2"),
            "cloud.toml",
            &[
                ("render.width", size),
                ("render.height", size),
                ("wavefront.nu", nu),
                ("wavefront.nv", nu),
                ("wavefront.layers", layers),
            ],
            if quick { "" } else { "wavefront paper: 128 x 128 x 64 in 30 ms (GeForce 6800 GT, 2005)" },
        ))
    }

    fn ladder(&self, _scene: &Scene) -> Vec<Rung> {
        // Angular and radial resolution grow together (nu = 2 nv = layers / 2): the knob is
        // the layer count, the rays follow it.
        [32u32, 64, 128, 256, 512]
            .iter()
            .map(|l| Rung {
                knob: "wavefront.layers".into(),
                value: l.to_string(),
                sets: vec![
                    ("wavefront.layers".into(), l.to_string()),
                    ("wavefront.nu".into(), (l / 2).to_string()),
                    ("wavefront.nv".into(), (l / 4).to_string()),
                ],
            })
            .collect()
    }

    fn stability(&self) -> Vec<Variant> {
        ["exponential", "explicit"]
            .iter()
            .map(|i| {
                let mut v = Variant::new(
                    i,
                    &[("wavefront.grid", "16"), ("wavefront.view_env_dirs", "16"), ("wavefront.integrator", i)],
                );
                // The paper's eq. 6, kept to compare against: it goes negative in optically
                // thick absorbing media (docs/decisions.md), so it is expected to fail there.
                v.comparison = *i == "explicit";
                v
            })
            .collect()
    }

    fn preflight(&self, scene: &Scene, knobs: &Knobs) -> Result<Vec<String>, SolverError> {
        let view = ViewSettings::parse(knobs, "view_", scene)?;
        let mut w = WaveTrust::of(scene, &WaveSettings::parse(knobs, "")?).warnings();
        w.extend(view::ViewTrust::of(scene, &view).warning(self.name()));
        Ok(w)
    }

    fn emission_refused_because(&self) -> Option<&'static str> {
        Some(
            "its spherical layers are centred on a point light and march that light's wavefronts outward; a source \
             spread through the volume has no centre to march from",
        )
    }

    fn inapplicable(&self, scene: &Scene) -> Option<String> {
        if let Some(why) = self.scene_refusal(scene) {
            return Some(why);
        }
        wave_field::traced_lights(scene).is_empty().then(|| {
            "no point light inside the medium: the method traces none, and renders single scattering only".to_string()
        })
    }

    fn summary(&self, report: &RenderReport) -> Vec<String> {
        let Some(s) = report.detail::<WavefrontStats>() else { return Vec::new() };
        let d = s.cartesian.dims;
        vec![
            format!(
                "wavefront: {} point light(s) traced, gathered onto {}x{}x{} voxels, {} channel(s)",
                s.lights_traced, d[0], d[1], d[2], s.channels
            ),
            format!("wavefront: {}", s.trust.line()),
            format!("wavefront: {}", s.view_trust.line()),
        ]
    }
}
