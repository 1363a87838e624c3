//! `scatterlab stability`: every solver at the extremes (docs/design.md, "Measuring the trade").
//!
//! Sweeps albedo {0, 0.5, 0.9, 0.99, 0.999, 1}, optical thickness of the medium from 1e-3 to
//! 1e4, g from -0.99 to 0.99, and a point light at a voxel centre, on a voxel corner, on the
//! medium's boundary and outside it. Every case is lit so that a cheap exact bound or answer
//! exists:
//! - under a uniform environment of radiance L alone, no pixel may exceed L (energy is never
//!   created: the lossless medium returns exactly L, thesis furnace argument), and a pure
//!   absorber (albedo 0) must equal L exp(-tau(ray)) on every pixel, which `single` computes
//!   exactly (the error against it is reported);
//! - with a point light, output must be finite and non-negative, and its total not brighter
//!   than the total of the same case with albedo 1 (the lossless bound, by `path`) beyond the
//!   statistical error of both;
//! - an emitter (Le = 1) lit by nothing else: no pixel may exceed Le, the equilibrium radiance
//!   (energy is never created beyond the source), and a pure absorber's every pixel is exactly
//!   1 - exp(-tau). Only the solvers that carry emission run these (the others refuse them).
//!
//! Monte Carlo solvers (`path`) are judged with its variance image (a pixel fails only beyond 5 standard errors plus
//! a small absolute floor). Cases marked `slow` are run by the command, not by the test suite.

use glam::Vec3;
use serde::Serialize;

use crate::gpu::Gpu;
use crate::output::Image;
use crate::scene::{LoadOptions, Scene};
use crate::solvers::{self, Solver};

/// One sweep case: a scene text and what it checks.
#[derive(Clone, Debug, Serialize)]
pub struct Case {
    pub name: String,
    pub group: &'static str,
    pub albedo: f32,
    pub tau: f32,
    pub g: f32,
    /// Point light position, or None for the uniform environment.
    pub light: Option<[f32; 3]>,
    /// The medium's shape; `tau` is its optical thickness along the camera's axis.
    pub shape: Shape,
    /// Too slow for the test suite on a CPU device (run by the command only).
    pub slow: bool,
    /// The medium emits Le = 1 and nothing else lights it (no light at all): no pixel may
    /// exceed Le (the equilibrium radiance: energy is never created beyond the source), and
    /// the pure absorber is exactly 1 - exp(-tau).
    pub emission: bool,
}

/// The medium of a case, seen face on along -z by the orthographic camera (0.6 wide), so every
/// camera ray crosses the medium's depth along z once.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Shape {
    /// A unit cube.
    Cube,
    /// A slab 4 x 4 wide and 0.25 deep along the camera's axis (16:16:1, issue 44: where the
    /// grid solvers' grids must fit the medium's thin side). The solvers run at their fitted
    /// default grids here: a variant's `.grid` is left out.
    Slab,
}

impl Shape {
    /// The medium's bounds (scene units).
    fn bounds(self) -> ([f32; 3], [f32; 3]) {
        match self {
            Shape::Cube => ([-0.5; 3], [0.5; 3]),
            Shape::Slab => ([-2.0, -2.0, -0.125], [2.0, 2.0, 0.125]),
        }
    }

    /// Its depth along the camera's axis (z).
    fn depth(self) -> f32 {
        let (lo, hi) = self.bounds();
        hi[2] - lo[2]
    }
}

/// What one solver did on one case.
#[derive(Clone, Debug, Serialize)]
pub struct Outcome {
    pub case: String,
    pub group: &'static str,
    pub solver: &'static str,
    /// Which variant of the solver ([`Solver::stability`]: the wavefront integrator), empty
    /// for the solver as it is.
    pub variant: String,
    /// The variant is a comparison variant ([`solvers::Variant::comparison`]): its failure is
    /// expected and not counted ([`Outcome::counts_as_failure`]).
    pub comparison: bool,
    pub passed: bool,
    pub finite: bool,
    pub non_negative: bool,
    pub energy_ok: bool,
    /// Environment cases: largest pixel excess over the bound 1; point-light cases: the
    /// image total over the lossless total, minus 1. Negative or 0 is within the bound.
    pub max_over_bound: f64,
    pub exact_error: Option<f64>,
    pub iterations: Option<u64>,
    pub converged: Option<bool>,
    pub gpu_ms: f64,
    pub notes: Vec<String>,
}

const RES: u32 = 16;
/// The medium: a cube of edge 1 made of 8^3 voxels (so "voxel centre" and "corner" mean
/// something for every solver's grid), seen face on by an orthographic camera narrower than
/// the cube, so every camera ray crosses exactly one unit of medium (no silhouette pixels:
/// exact answers hold for every pixel whatever the pixel filter).
const GRID: u32 = 8;

fn scene_text(c: &Case) -> String {
    let sigma_t = c.tau / c.shape.depth();
    let (lo, hi) = c.shape.bounds();
    let light = match (c.light, c.emission) {
        (_, true) => "emission = 1.0\n".to_string(),
        (None, false) => "[[light]]\nkind = \"environment\"\nradiance = 1.0\n".to_string(),
        (Some(p), false) => {
            format!("[[light]]\nkind = \"point\"\nposition = [{}, {}, {}]\nintensity = 1.0\n", p[0], p[1], p[2])
        }
    };
    format!(
        "[render]\nwidth = {RES}\nheight = {RES}\nseed = 9\nspp = 64\n\
         [camera]\nkind = \"orthographic\"\norigin = [0.0, 0.0, 3.0]\ntarget = [0.0, 0.0, 0.0]\nextent = 0.6\n\
         [medium]\nbounds = [{lo:?}, {hi:?}]\nsigma_t = {sigma_t}\nalbedo = {}\ng = {}\ndensity = {{ kind = \"constant\" \
             }}\n{light}",
        c.albedo, c.g
    )
}

/// The sweep (docs/design.md "stability").
pub fn cases() -> Vec<Case> {
    let mut v = Vec::new();
    let mk = |name: String, group, albedo, tau, g, light, slow| Case {
        name,
        group,
        albedo,
        tau,
        g,
        light,
        shape: Shape::Cube,
        slow,
        emission: false,
    };
    for a in [0.0f32, 0.5, 0.9, 0.99, 0.999, 1.0] {
        v.push(mk(format!("albedo {a}"), "albedo", a, 4.0, 0.0, None, false));
    }
    for tau in [1e-3f32, 1e-1, 10.0, 1e3, 1e4] {
        // Lossless at extreme thickness: path lengths grow as tau^2 (slow), so albedo 0.9 there.
        let slow = tau >= 1e3;
        v.push(mk(format!("tau {tau:e}"), "thickness", 0.9, tau, 0.0, None, slow));
    }
    for g in [-0.99f32, -0.5, 0.0, 0.5, 0.99] {
        v.push(mk(format!("g {g}"), "anisotropy", 0.9, 4.0, g, None, false));
    }
    let h = 1.0 / GRID as f32;
    let lights = [
        ("light at a voxel centre", [0.5 * h, 0.5 * h, 0.5 * h]),
        ("light on a voxel corner", [0.0, 0.0, 0.0]),
        ("light on the boundary", [0.5, 0.0, 0.0]),
        ("light outside", [1.5, 0.7, 0.9]),
    ];
    for (name, p) in lights {
        v.push(mk(name.to_string(), "point light", 0.9, 4.0, 0.0, Some(p), false));
    }
    // A point light inside the medium from optically thin to very thick, absorbing and not:
    // where the wavefront solver's integrators (and every 1/r^2 near-light estimate) are
    // stressed. Thick lossless bounds take `path` long, so those cases are slow.
    for tau in [1e-3f32, 10.0, 1e3, 1e4] {
        for albedo in [0.0f32, 0.99] {
            v.push(mk(
                format!("light inside, tau {tau:e}, albedo {albedo}"),
                "light inside",
                albedo,
                tau,
                0.0,
                Some([0.5 * h, 0.5 * h, 0.5 * h]),
                tau >= 1e3,
            ));
        }
    }
    // A thin slab, 2 mean free paths deep: the pure absorber and the furnace (exact), and
    // the lossless bound at albedo 0.99 isotropic and forward-scattering (lbl's thin layers
    // came out bright: docs/lbl.md).
    for (albedo, g) in [(0.0f32, 0.0f32), (0.99, 0.0), (1.0, 0.0), (0.99, 0.6)] {
        let mut c = mk(format!("slab 16:16:1, albedo {albedo}, g {g}"), "shape", albedo, 2.0, g, None, false);
        c.shape = Shape::Slab;
        v.push(c);
    }
    // An emitter lit by nothing else (issue 47), from a pure absorber (exact: 1 - exp(-tau)) to
    // nearly lossless, optically thin to very thick: no pixel above the source's Le = 1. (Albedo
    // 1 absorbs, and so emits, nothing: the scene loader refuses it.) Thick near-lossless cases
    // take `path` long: slow.
    for a in [0.0f32, 0.5, 0.9, 0.99, 0.999] {
        let mut c = mk(format!("emitter, albedo {a}"), "emission", a, 4.0, 0.0, None, false);
        c.emission = true;
        v.push(c);
    }
    for tau in [1e-3f32, 1e-1, 10.0, 1e3, 1e4] {
        let mut c = mk(format!("emitter, tau {tau:e}"), "emission", 0.9, tau, 0.0, None, tau >= 1e3);
        c.emission = true;
        v.push(c);
    }
    for g in [-0.9f32, 0.9] {
        let mut c = mk(format!("emitter, g {g}"), "emission", 0.9, 4.0, g, None, false);
        c.emission = true;
        v.push(c);
    }
    v
}

/// The variants of `solver` that run on `scene`: none where the solver refuses the scene (an
/// emission it does not carry would render dark and pass every bound for nothing).
fn variants_on(solver: &dyn Solver, scene: &Scene) -> Vec<solvers::Variant> {
    if solver.scene_refusal(scene).is_some() {
        return Vec::new();
    }
    solver.stability().into_iter().filter(|v| (v.applies)(scene)).collect()
}

fn render(
    gpu: &Gpu,
    scene: &Scene,
    solver: &dyn Solver,
    sets: &[(String, String)],
) -> Result<solvers::RenderOutput, String> {
    super::render_with(gpu, scene, solver, sets, false).map(|(r, _)| r)
}

/// How many renders [`run`] judges (each announced by one `progress` call): every variant
/// of every solver that applies to each case run.
pub fn steps(solvers_: &[&dyn Solver], include_slow: bool) -> Result<usize, String> {
    let mut n = 0;
    for case in cases().into_iter().filter(|c| include_slow || !c.slow) {
        let scene =
            Scene::from_str(&scene_text(&case), &case.name, std::path::Path::new("."), &[], &LoadOptions::default())
                .map_err(|e| e.to_string())?;
        n += solvers_.iter().map(|s| variants_on(*s, &scene).len()).sum::<usize>();
    }
    Ok(n)
}

/// Run every case (skipping slow ones unless `include_slow`) for every solver; `progress` is
/// called as each of the [`steps`] renders starts.
pub fn run(
    gpu: &Gpu,
    solvers_: &[&dyn Solver],
    include_slow: bool,
    progress: &dyn Fn(&str),
) -> Result<Vec<Outcome>, String> {
    let mut out = Vec::new();
    for case in cases() {
        if case.slow && !include_slow {
            continue;
        }
        let scene =
            Scene::from_str(&scene_text(&case), &case.name, std::path::Path::new("."), &[], &LoadOptions::default())
                .map_err(|e| e.to_string())?;
        // The lossless bound for point-light cases: the same scene with albedo 1, by the
        // reference solver.
        let bound: Option<(Image, f64)> = match case.light {
            Some(_) => {
                let mut lossless = scene.clone();
                lossless.medium.albedo = Vec3::ONE;
                let r = render(gpu, &lossless, solvers::reference(), &[("render.spp".into(), "256".into())])?;
                let v = r.total_variance();
                Some((r.image, v))
            }
            None => None,
        };
        // Exact answers under the environment: the pure absorber (every camera ray crosses one
        // unit: L exp(-sigma_t)) and the furnace (albedo 1: L everywhere).
        let exact_value = match (case.light, case.albedo, case.emission) {
            // tau is the optical depth along the camera's axis whatever the shape.
            (None, 0.0, false) => Some((-(case.tau as f64)).exp() as f32),
            (None, 1.0, false) => Some(1.0),
            // What a pure absorber emits toward the camera: Le (1 - exp(-tau)).
            (None, 0.0, true) => Some(-(-(case.tau as f64)).exp_m1() as f32),
            _ => None,
        };
        let exact = exact_value.map(|x| {
            let mut e = Image::new(RES, RES);
            e.data.iter_mut().for_each(|v| *v = x);
            e
        });
        for &solver in solvers_ {
            for variant in variants_on(solver, &scene) {
                progress(&format!("{} / {}", case.name, solver.name()));
                // Shapes other than the cube are measured at the fitted default grids, with the
                // default light rays to fill them (a variant's few rays, sized to the cube's
                // small grid, leave a slab's voxels unevenly lit: lbl at 16384 rays drew pixels
                // 6% over the bound on the slab of albedo 0.99, at its default 65536 none).
                let sets: Vec<(String, String)> = variant
                    .sets
                    .iter()
                    .filter(|(k, _)| case.shape == Shape::Cube || !(k.ends_with(".grid") || k.ends_with(".rays")))
                    .cloned()
                    .collect();
                let r = match render(gpu, &scene, solver, &sets) {
                    Ok(r) => r,
                    Err(e) => {
                        out.push(Outcome {
                            case: case.name.clone(),
                            group: case.group,
                            solver: solver.name(),
                            variant: variant.name.clone(),
                            comparison: variant.comparison,
                            passed: false,
                            finite: false,
                            non_negative: false,
                            energy_ok: false,
                            max_over_bound: f64::NAN,
                            exact_error: None,
                            iterations: None,
                            converged: None,
                            gpu_ms: 0.0,
                            notes: vec![format!("error: {e}")],
                        });
                        continue;
                    }
                };
                let mut o = judge(&case, &r, bound.as_ref(), exact.as_ref());
                o.variant = variant.name;
                o.comparison = variant.comparison;
                out.push(o);
            }
        }
    }
    Ok(out)
}

fn judge(case: &Case, r: &solvers::RenderOutput, bound: Option<&(Image, f64)>, exact: Option<&Image>) -> Outcome {
    let img = &r.image;
    let finite = img.nan_inf_count() == 0;
    let non_negative = img.data.iter().all(|v| *v >= 0.0);
    let var = |i: usize| r.variance.as_ref().map(|v| v.data[i] as f64).unwrap_or(0.0);
    let (energy_ok, max_over) = match bound {
        // Uniform environment of radiance 1: no pixel may exceed 1 (beyond 5 standard errors).
        None => {
            let mut ok = true;
            let mut over = 0.0f64;
            for i in 0..img.data.len() {
                let x = img.data[i] as f64;
                if x > 1.0 + 5.0 * var(i).sqrt() + 1e-4 {
                    ok = false;
                }
                over = over.max(x - 1.0);
            }
            (ok, over)
        }
        // Point light: the image's total against the lossless (albedo 1) `path` render's total.
        // Per pixel the bound is too noisy near a light inside the medium (next-event estimates
        // of 1/r^2 are heavy-tailed), the total is not.
        Some((bi, bv)) => {
            let sx: f64 = img.data.iter().map(|v| *v as f64).sum();
            let sb: f64 = bi.data.iter().map(|v| *v as f64).sum();
            // Plus an absolute 1e-12 per pixel: where the medium is thousands of mean free paths
            // thick, path's lossless paths end at their depth limit before leaving, its bound is
            // exactly 0, and a deterministic solver's leakage of 1e-19 (dom, tau 1e4) would fail
            // a check that no image file can resolve (docs/devices/nvidia-h100-2026-11-25).
            let floor = 1e-12 * img.data.len() as f64;
            let ok = sx <= sb + 5.0 * (r.total_variance() + bv).sqrt() + 1e-6 * sb.abs() + floor;
            (ok, if sb > 0.0 { sx / sb - 1.0 } else { 0.0 })
        }
    };
    let exact_error = exact.and_then(|e| crate::output::compare(img, e).ok()).map(|m| m.rel_l2);
    let mut notes = r.report.warnings.clone();
    let stats = &r.report.stats;
    let (iterations, converged) = (stats.convergence.map(|c| c.iterations), stats.convergence.map(|c| c.converged));
    // Against an exact answer: a Monte Carlo solver within 5 standard errors on every pixel;
    // the pure absorber is exact for the deterministic solvers; the furnace is reported for
    // them (single scattering alone is not meant to reach it), not judged. In a pure absorber
    // of constant density under a radiance-1 environment each path sample is 1 or 0 (it
    // escapes or not), so its variance is exactly e (1 - e) per sample: used where the sample
    // variance is 0 (all samples alike).
    let exact_ok = match (exact, stats.spp) {
        (Some(e), Some(spp)) => (0..img.data.len()).all(|i| {
            let ev = e.data[i] as f64;
            let sd = var(i).max(ev * (1.0 - ev) / spp.max(1) as f64).sqrt();
            (img.data[i] as f64 - ev).abs() <= 5.0 * sd + 1e-3
        }),
        (Some(_), None) if case.albedo == 0.0 => exact_error.is_some_and(|e| e < 1e-4),
        (Some(_), None) => true,
        (None, _) => true,
    };
    if !exact_ok {
        notes.push("differs from the exact answer".into());
    }
    if converged == Some(false) {
        notes.push("did not converge".into());
    }
    // The solver's own state went negative or non-finite (cleaned before the image, so the
    // image alone would not show it: the wavefront integrator's nodes): a failure.
    if stats.faults > 0 {
        notes.push(format!("{} internal values went negative or non-finite", stats.faults));
    }
    Outcome {
        case: case.name.clone(),
        group: case.group,
        solver: r.report.solver,
        variant: String::new(),
        comparison: false,
        passed: finite && non_negative && energy_ok && exact_ok && stats.faults == 0,
        finite,
        non_negative,
        energy_ok,
        max_over_bound: max_over,
        exact_error,
        iterations,
        converged,
        gpu_ms: r.report.gpu_ms,
        notes,
    }
}

impl Outcome {
    /// Whether this outcome fails the sweep: a failed check of anything but a comparison
    /// variant (whose failures are expected, shown as "fail (expected)").
    pub fn counts_as_failure(&self) -> bool {
        !self.passed && !self.comparison
    }

    /// "pass", "FAIL", or "fail (expected)" for a comparison variant.
    pub fn verdict(&self) -> &'static str {
        match (self.passed, self.comparison) {
            (true, _) => "pass",
            (false, false) => "FAIL",
            (false, true) => "fail (expected)",
        }
    }

    /// `solver` or `solver/variant`.
    pub fn label(&self) -> String {
        if self.variant.is_empty() {
            self.solver.to_string()
        } else {
            format!("{}/{}", self.solver, self.variant)
        }
    }
}

/// CSV of the outcomes (one row per case and solver).
pub fn csv(outcomes: &[Outcome]) -> Result<String, String> {
    let header = [
        "case",
        "group",
        "solver",
        "comparison",
        "passed",
        "counts_as_failure",
        "finite",
        "non_negative",
        "energy_ok",
        "max_over_bound",
        "exact_rel_l2",
        "iterations",
        "converged",
        "gpu_ms",
        "notes",
    ];
    let rows = outcomes.iter().map(|o| {
        vec![
            o.case.clone(),
            o.group.to_string(),
            o.label(),
            o.comparison.to_string(),
            o.passed.to_string(),
            o.counts_as_failure().to_string(),
            o.finite.to_string(),
            o.non_negative.to_string(),
            o.energy_ok.to_string(),
            format!("{:.4e}", o.max_over_bound),
            o.exact_error.map(|e| format!("{e:.3e}")).unwrap_or_default(),
            o.iterations.map(|i| i.to_string()).unwrap_or_default(),
            o.converged.map(|c| c.to_string()).unwrap_or_default(),
            format!("{:.1}", o.gpu_ms),
            o.notes.join("; "),
        ]
    });
    super::csv_text(&header, rows)
}

/// The pass/fail table printed by the command: "fail (expected)" for a comparison variant's
/// failure, with a closing line that counts those apart.
pub fn table(outcomes: &[Outcome]) -> String {
    let mut s = format!(
        "{:<36} {:<21} {:<15} {:>8} {:>11} {:>6} {}\n",
        "case", "solver", "ok", "over", "exact relL2", "iters", "notes"
    );
    for o in outcomes {
        s.push_str(&format!(
            "{:<36} {:<21} {:<15} {:>8.1e} {:>11} {:>6} {}\n",
            o.case,
            o.label(),
            o.verdict(),
            o.max_over_bound,
            o.exact_error.map(|e| format!("{e:.1e}")).unwrap_or_else(|| "-".into()),
            o.iterations.map(|i| i.to_string()).unwrap_or_else(|| "-".into()),
            o.notes.join("; ")
        ));
    }
    s.push_str(
        "over: how far the image's total exceeds the lossless bound (the same scene at albedo 1, by path), relative; \
         > 0 creates energy.\nexact relL2: against the closed-form image where the case has one (pure absorber: \
         exp(-tau); furnace: 1). Deterministic solvers must match the absorber to 1e-4; Monte Carlo ones are judged \
         per pixel within 5 standard errors, so their relL2 can be large where the exact image is nearly black \
         and still pass.\niters: lattice or sweep iterations to converge.\n",
    );
    let expected = outcomes.iter().filter(|o| o.comparison && !o.passed).count();
    if expected > 0 {
        let mut names: Vec<String> = outcomes.iter().filter(|o| o.comparison).map(|o| o.label()).collect();
        names.sort();
        names.dedup();
        s.push_str(&format!(
            "fail (expected): {expected} check(s) of comparison variant(s) ({}), kept to compare against and not \
                counted as failures\n",
            names.join(", ")
        ));
    }
    s
}
