//! Solver `dom`: modified discrete ordinates (thesis ch. 5; issue 13), first stage: isotropic
//! media, in-core.
//!
//! 1. **Direct source (5.2).** Photon marching as in `lbl` (the shared `marching` part, its
//!    fixed-point transfer: deterministic) deposits each voxel's once-scattered power E; the
//!    first-scattering emission is E / (4 pi lambda^3) per unit volume and solid angle
//!    (isotropic media store one direction, M = 1: thesis 5.1).
//! 2. **Propagation (5.3).** Octant sweeps over the directions of a named quadrature
//!    (`physics::quadrature`; S_4 and S_6 are the thesis's 24 and 48), plane by plane, with the
//!    step scheme (`solvers::ordinates`, checked against the CPU oracle `physics::ordinates`):
//!    never negative, conservative. Source iteration: the emission of the next sweep is the
//!    first-scattering one plus sigma_s phi / (4 pi), until the fluence changes by less than
//!    `dom.tol` (relative, largest over voxels) or `dom.max_iterations`; both are reported.
//! 3. **View gathering (5.3.5).** The shared view pass: exact single scattering of the direct
//!    light, plus the swept fluence (the light scattered once and more) scattered toward the
//!    camera, trilinear between voxel centres; nothing is counted twice.
//!
//! Not yet (issue 13): anisotropic media (M storage directions and the sort-search-compact
//! merge), chromatic media, blocks and out-of-core streaming, the sweep's source update on the
//! device.

use serde::Serialize;

use crate::gpu::{Gpu, Kernel, QueueRole};
use crate::physics::quadrature::Quadrature;
use crate::scene::Scene;

use super::gpu_scene::{self, GpuScene};
use super::lattice::LatticeGeom;
use super::marching::{self, MarchSettings, Marcher};
use super::ordinates::{Sweeper, SWEEP};
use super::view::{self, FluxUse, MsVolume, ViewSettings};
use super::{
    Convergence, Knob, Knobs, Progress, Range, RenderOutput, RenderReport, RenderRequest, Rung, Solver, SolverError,
    Stats, Variant,
};

pub struct Dom;

/// `dom`'s own stats.
#[derive(Clone, Debug, Serialize)]
pub struct DomStats {
    pub grid: LatticeGeom,
    pub quadrature: String,
    pub directions: usize,
    pub iterations: u32,
    pub converged: bool,
    pub final_change: f64,
    pub sweep_ms: f64,
}

struct DomSettings {
    grid: u32,
    quadrature: Quadrature,
    tol: f64,
    max_iterations: u32,
    march: MarchSettings,
    view: ViewSettings,
}

impl DomSettings {
    fn parse(k: &Knobs, scene: &Scene) -> Result<DomSettings, SolverError> {
        let grid: u32 = k.get("grid")?;
        let name: String = k.get("directions")?;
        let quadrature = Quadrature::named(&name).map_err(|e| k.invalid("directions", e))?;
        let geom = LatticeGeom::new(scene, grid);
        Ok(DomSettings {
            grid,
            quadrature,
            tol: k.get("tol")?,
            max_iterations: k.get("max_iterations")?,
            march: MarchSettings::parse(k, geom.lambda)?,
            view: ViewSettings::parse(k, "view_", scene)?,
        })
    }
}

/// Why `dom` cannot render `scene` yet, if it cannot.
fn unsupported(scene: &Scene) -> Option<String> {
    let m = &scene.medium;
    if m.g != 0.0 {
        return Some(format!(
            "dom scatters isotropically so far (g = {}): anisotropic media need its M storage directions (issue 13)",
            m.g
        ));
    }
    if gpu_scene::modelled(scene, false).chromatic {
        return Some(
            "dom has one channel so far: a chromatic medium (per-channel sigma_t or albedo) needs three".into(),
        );
    }
    None
}

impl Solver for Dom {
    fn name(&self) -> &'static str {
        "dom"
    }

    fn about(&self) -> &'static str {
        "modified discrete ordinates: marched first-scattering source, octant sweeps with the step scheme, source \
         iteration (thesis ch. 5; isotropic, in-core so far)"
    }

    fn knobs(&self) -> Vec<Knob> {
        let mut k = vec![
            Knob::fixed("grid", "32", Range::int(2, 256), "voxels along the medium's longest side"),
            Knob::fixed(
                "directions",
                "s6",
                Range::Choice(&["s2", "s4", "s6", "s8", "product-8x16", "product-16x32"]),
                "the quadrature swept: level-symmetric s4 (24 directions, the thesis's), s6 (48), s8 (80), or a \
                 Gauss-Legendre x Chebyshev product set (product-PxA: P polar x A azimuthal)",
            ),
            Knob::fixed(
                "tol",
                "1e-4",
                Range::Real { min: 0.0, max: 1.0, min_open: true, max_open: true },
                "source iteration stops when the fluence changes by less than this, relative to its largest value",
            ),
            Knob::fixed("max_iterations", "2000", Range::int(1, 1_000_000), "source iterations at most"),
        ];
        k.extend(marching::knobs());
        k.extend(view::knobs().into_iter().map(|k| k.prefixed("view_")));
        k
    }

    fn kernels(&self) -> Vec<Kernel> {
        let mut k = marching::kernels();
        k.extend([SWEEP, view::MARCH, view::SHADOW]);
        k
    }

    fn render(&self, gpu: &Gpu, req: &RenderRequest) -> Result<RenderOutput, SolverError> {
        let scene = req.scene;
        let k = req.knobs(self)?;
        let set = DomSettings::parse(&k, scene)?;
        k.finish()?;
        if let Some(why) = unsupported(scene) {
            return Err(SolverError::Unsupported(why));
        }
        let gs = GpuScene::upload(gpu, scene, req.force_full)?;
        (req.progress)(Progress::work("marching the direct source", 0, 1));
        let geom = LatticeGeom::new(scene, set.grid);
        let marcher = Marcher::new(gpu, scene, &gs, geom, &set.march, 1, true, false)?;
        for _ in 0..marcher.rounds {
            let point =
                gpu.submit(QueueRole::Trace, &[marcher.march_pass(&gs), marcher.transfer_pass(QueueRole::Trace)], &[])?;
            gpu.wait(point)?;
        }
        (req.progress)(Progress::work("marching the direct source", 1, 1));
        let sums: Vec<u32> = gpu.read_buffer_as(&marcher.sums)?;
        let density: Vec<f32> = gpu.read_buffer_as(&marcher.density)?;
        let lambda = geom.lambda as f64;
        let four_pi = 4.0 * std::f64::consts::PI;
        // Once-scattered power per voxel (fixed point), as emission per unit volume and sr.
        let first: Vec<f64> =
            sums.iter().map(|s| *s as f64 / marcher.scale as f64 / (four_pi * lambda.powi(3))).collect();
        let sigma_t: Vec<f64> = density.iter().map(|d| scene.medium.sigma_t.x as f64 * *d as f64).collect();
        let albedo = scene.medium.albedo.x as f64;
        let to32 = |v: &[f64]| v.iter().map(|x| *x as f32).collect::<Vec<f32>>();
        let sweeper = Sweeper::new(gpu, geom.dims, geom.lambda, &to32(&sigma_t), &set.quadrature)?;

        // Source iteration (thesis 5.3.4's scattering iterations, with one storage direction).
        let mut emission = first.clone();
        let mut previous: Vec<f64> = vec![0.0; first.len()];
        let (mut iterations, mut converged, mut change) = (0u32, false, f64::INFINITY);
        let mut last_change: Option<(f64, u64)> = None;
        while iterations < set.max_iterations {
            let phi: Vec<f64> = sweeper.sweep(gpu, &to32(&emission))?.iter().map(|x| *x as f64).collect();
            iterations += 1;
            let scale = phi.iter().fold(0.0f64, |m, x| m.max(*x));
            change = phi.iter().zip(&previous).fold(0.0f64, |m, (a, b)| m.max((a - b).abs()))
                / if scale > 0.0 { scale } else { 1.0 };
            for (i, e) in emission.iter_mut().enumerate() {
                *e = first[i] + albedo * sigma_t[i] * phi[i] / four_pi;
            }
            previous = phi;
            (req.progress)(Progress::converging(
                "source iterations",
                iterations as u64,
                change,
                set.tol,
                last_change,
                (set.max_iterations - iterations) as u64,
            ));
            last_change = Some((change, iterations as u64));
            if change <= set.tol {
                converged = true;
                break;
            }
        }
        // The view pass reads energy per voxel, fluence = energy / lambda^2 (as lbl's lattice).
        let energy: Vec<f32> = previous.iter().map(|p| (p * lambda * lambda) as f32).collect();
        let energy_buf = gpu.buffer_with("dom fluence", &energy)?;
        let ms = MsVolume {
            energy: &energy_buf,
            dims: geom.dims,
            channels: 1,
            origin: geom.origin,
            lambda: geom.lambda,
            flux: FluxUse::None,
        };
        let res = view::march(gpu, scene, &gs, &set.view, Some(&ms))?;
        let device = gs.bytes + marcher.device_bytes() + sweeper.device_bytes() + res.device_bytes + energy_buf.size();
        let mut report = RenderReport::finish(gpu, self, &k, gs.modelled.clone(), device, Stats::new(()));
        let sweep_ms = report.passes.iter().filter(|p| p.name == "ordinates.sweep").map(|p| p.duration_ms()).sum();
        let ds = DomStats {
            grid: geom,
            quadrature: set.quadrature.name.clone(),
            directions: set.quadrature.len(),
            iterations,
            converged,
            final_change: change,
            sweep_ms,
        };
        if !converged {
            report.warnings.push(format!(
                "dom: source iteration did not converge in {iterations} iterations (change {change:.2e}, tolerance \
                 {:.1e}); raise dom.max_iterations or dom.tol",
                set.tol
            ));
        }
        report.warnings.extend(super::nonfinite_warning(res.nonfinite_pixels));
        let mut stats = Stats::new(ds);
        stats.convergence =
            Some(Convergence { iterations: iterations as u64, converged, final_change: change, tolerance: set.tol });
        stats.faults = res.nonfinite_pixels as u64;
        report.stats = stats;
        Ok(RenderOutput { image: res.image, variance: None, report })
    }

    fn memory_estimate(&self, scene: &Scene, knobs: &Knobs) -> Result<u64, SolverError> {
        let set = DomSettings::parse(knobs, scene)?;
        let geom = LatticeGeom::new(scene, set.grid);
        let m = &set.march;
        let rays = marching::raymaps(scene, &geom, m.rays, m.env_lights, m.step, scene.render.seed).len() as u64;
        let v = geom.voxels();
        // The sweeper: extinction, emission, the octants' fluence slices and a field per
        // direction slot of every octant; the fluence handed to the view pass.
        let slots = Sweeper::slots(&set.quadrature);
        Ok(gpu_scene::scene_bytes(scene)
            + m.device_bytes(&geom, rays, 1, false)
            + v * 4 * (3 + 8 + 8 * slots)
            + set.quadrature.len() as u64 * 16
            + view::device_bytes(scene, &set.view))
    }

    fn ladder(&self, _scene: &Scene) -> Vec<Rung> {
        [8u32, 16, 24, 32, 48].iter().map(|g| Rung::one("dom.grid", g)).collect()
    }

    fn stability(&self) -> Vec<Variant> {
        let mut v = Variant::new(
            "",
            &[("dom.grid", "12"), ("dom.rays", "4096"), ("dom.view_env_dirs", "16"), ("dom.max_iterations", "4000")],
        );
        v.applies = |s| unsupported(s).is_none();
        vec![v]
    }

    fn inapplicable(&self, scene: &Scene) -> Option<String> {
        unsupported(scene)
    }

    fn summary(&self, report: &RenderReport) -> Vec<String> {
        let Some(s) = report.detail::<DomStats>() else { return Vec::new() };
        let d = s.grid.dims;
        vec![format!(
            "dom: {}x{}x{} voxels, {} ({} directions), {} source iterations{} (change {:.1e}), sweeps {:.1} ms",
            d[0],
            d[1],
            d[2],
            s.quadrature,
            s.directions,
            s.iterations,
            if s.converged { "" } else { ", NOT converged" },
            s.final_change,
            s.sweep_ms
        )]
    }
}
