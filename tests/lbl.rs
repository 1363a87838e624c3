//! Solver `lbl`: the round graph against fake queues (no deadlock on a shared queue, overlap
//! on two), the lattice against the diffusion equation and conservation, schedules and
//! blocking against each other, and the image against `single` and `path`.

use std::collections::VecDeque;

use crate::common::{LBL, SINGLE};
use scatterlab::gpu::QueueRole;
use scatterlab::solvers::lbl::{plan, LblStats, Planned, Step};
use scatterlab::solvers::parts::lattice::{EnergyBook, Lattice, LatticeParams};
use scatterlab::solvers::{Schedule, SolverError};

use crate::common::{assert_clean, gpu, render, scene, SceneText};

/// Execute a plan on fake in-order queues. `shared`: one queue for both roles (lavapipe),
/// else one per role. Every submission takes `duration(step)` time units once it starts; a
/// submission starts when it is at the head of its queue and everything it waits on has
/// finished. Returns per-submission (start, end), or Err on a deadlock (a queue head waiting
/// on something that can never finish).
fn run_fake(plan: &[Planned], shared: bool, duration: impl Fn(&Step) -> u64) -> Result<Vec<(u64, u64)>, String> {
    let q_of = |r: QueueRole| if shared { 0 } else { r as usize };
    let mut queues: Vec<VecDeque<usize>> = vec![VecDeque::new(), VecDeque::new()];
    for (i, p) in plan.iter().enumerate() {
        // Host-order rule: a submission may only wait on earlier submissions.
        if p.waits.iter().any(|w| *w >= i) {
            return Err(format!("submission {i} waits on a later submission"));
        }
        queues[q_of(p.role)].push_back(i);
    }
    let mut done: Vec<Option<(u64, u64)>> = vec![None; plan.len()];
    let mut free_at = [0u64; 2];
    loop {
        let mut progressed = false;
        for q in 0..2 {
            while let Some(&head) = queues[q].front() {
                let ready = plan[head].waits.iter().map(|w| done[*w].map(|d| d.1)).collect::<Option<Vec<u64>>>();
                let Some(deps) = ready else { break };
                let start = deps.into_iter().chain([free_at[q]]).max().unwrap_or(0);
                let end = start + duration(&plan[head].step);
                done[head] = Some((start, end));
                free_at[q] = end;
                queues[q].pop_front();
                progressed = true;
            }
        }
        if queues.iter().all(|q| q.is_empty()) {
            return Ok(done.into_iter().map(|d| d.expect("all done")).collect());
        }
        if !progressed {
            return Err(format!("deadlock with {:?} still queued", queues));
        }
    }
}

fn dur(s: &Step) -> u64 {
    match s {
        Step::March(_) => 10,
        Step::Transfer(_) => 2,
        Step::Diffuse(_) => 8,
    }
}

#[test]
fn round_graph_never_deadlocks_and_overlaps_only_when_concurrent() {
    for rounds in [1u32, 2, 3, 7, 20] {
        for schedule in [Schedule::Concurrent, Schedule::Sequential] {
            let p = plan(rounds, schedule);
            // Same steps in both schedules: every round marched, transferred and diffused once.
            for n in 0..rounds {
                for want in [Step::March(n), Step::Transfer(n), Step::Diffuse(n)] {
                    assert_eq!(p.iter().filter(|s| s.step == want).count(), 1, "{schedule:?} {rounds}: {want:?}");
                }
            }
            assert!(p.iter().all(|s| matches!(s.step, Step::March(_)) == (s.role == QueueRole::Trace)));
            for shared in [true, false] {
                let t = run_fake(&p, shared, dur)
                    .unwrap_or_else(|e| panic!("{schedule:?}, {rounds} rounds, shared {shared}: {e}"));
                let idx = |st: Step| p.iter().position(|s| s.step == st).unwrap();
                for n in 0..rounds {
                    // Transfer n after march n; march n+1 after transfer n (it overwrites the history).
                    assert!(t[idx(Step::Transfer(n))].0 >= t[idx(Step::March(n))].1);
                    if n + 1 < rounds {
                        assert!(t[idx(Step::March(n + 1))].0 >= t[idx(Step::Transfer(n))].1);
                        let (m, d) = (t[idx(Step::March(n + 1))], t[idx(Step::Diffuse(n))]);
                        let overlap = m.0.max(d.0) < m.1.min(d.1);
                        match (schedule, shared) {
                            (_, true) | (Schedule::Sequential, _) => {
                                assert!(!overlap, "{schedule:?} shared {shared}: march {} overlaps diffuse {n}", n + 1)
                            }
                            (Schedule::Concurrent, false) => {
                                assert!(overlap, "concurrent on two queues: march {} should overlap diffuse {n}", n + 1)
                            }
                        }
                    }
                }
            }
        }
    }
}

/// The fake queue itself catches the hazard it guards against: a wait on a later submission
/// (which on one in-order queue can never be satisfied).
#[test]
fn fake_queue_detects_wait_before_signal() {
    let bad = vec![
        Planned { role: QueueRole::Diffuse, step: Step::Diffuse(0), waits: vec![1] },
        Planned { role: QueueRole::Trace, step: Step::March(0), waits: vec![] },
    ];
    assert!(run_fake(&bad, true, dur).is_err());
}

/// The lattice part's impulse bench with the medium as scalars.
#[allow(clippy::too_many_arguments)]
fn diffuse_impulse(
    gpu: &scatterlab::gpu::Gpu,
    lattice: Lattice,
    dims: [u32; 3],
    sigma_t: f32,
    albedo: f32,
    g: f32,
    lambda: f32,
    block: u32,
    block_steps: u32,
    source: [u32; 3],
    iterations: u32,
) -> Result<(Vec<f32>, EnergyBook), SolverError> {
    diffuse_impulse_reflecting(
        gpu,
        lattice,
        dims,
        [sigma_t, albedo, g, lambda],
        block,
        block_steps,
        source,
        iterations,
        0.0,
    )
}

/// [`diffuse_impulse`] with the medium as [sigma_t, albedo, g, lambda] and the lattice's
/// boundary reflecting `boundary_r` of what leaves (a refractive object's surface).
#[allow(clippy::too_many_arguments)]
fn diffuse_impulse_reflecting(
    gpu: &scatterlab::gpu::Gpu,
    lattice: Lattice,
    dims: [u32; 3],
    [sigma_t, albedo, g, lambda]: [f32; 4],
    block: u32,
    block_steps: u32,
    source: [u32; 3],
    iterations: u32,
    boundary_r: f32,
) -> Result<(Vec<f32>, EnergyBook), SolverError> {
    let p = LatticeParams {
        dims,
        nch: 1,
        lattice,
        lambda,
        block,
        block_steps,
        escape: scatterlab::solvers::parts::lattice::Escape::None,
        drift: false,
        near: None,
        directed: false,
        flux: false,
        links: false,
        extrapolate: false,
    };
    let medium = scatterlab::scene::Material {
        sigma_t: glam::Vec3::splat(sigma_t),
        albedo: glam::Vec3::splat(albedo),
        g,
        ior: 1.0,
        field: 0,
        emission: glam::Vec3::ZERO,
        emission_grid: false,
    };
    scatterlab::solvers::parts::lattice::diffuse_impulse(gpu, &p, (&medium, boundary_r), source, iterations)
}

/// Diffusion limit: an impulse in a large homogeneous lattice integrates in time to the Green's
/// function of de/dt = D lap e - mu e with the lattice's own coefficients, D = (1+c)/(6(1-c))
/// voxels^2 per step for the persistence c = (1 - kappa_t) / (1 - kappa_a) of a surviving
/// particle's direction, and mu = -ln(1 - kappa_a) per step:
///   G(r) = exp(-r sqrt(mu / D)) / (4 pi D r).
/// The diffusion regime needs r well beyond a mean free path (1.25 voxels here) and within a
/// few diffusion lengths L = sqrt(D / mu) (6 voxels here); farther out a lattice walk's tail is
/// anisotropic (large deviations prefer the axes), which the diffusion equation does not describe.
#[test]
fn lattice_matches_the_diffusion_green_function() {
    let gpu = gpu();
    // 40^3 with shells to r 10 (48^3 to r 12 before: 40% more time for the same check; the
    // boundary is 2 absorption lengths beyond the last shell either way).
    let n = 40u32;
    let c = n / 2;
    for lattice in [Lattice::D3q6, Lattice::D3q18] {
        // Lattice units (lambda = 1): kappa_t = 0.8; absorption chosen for L = 6 voxels.
        let kt = 0.8f64;
        let msq = lattice.mean_square_step();
        let d_guess = msq / 6.0 * 1.5;
        let ka = d_guess / 36.0;
        // Invert the kernel's coefficients (glsl/include/lattice.glsl) for sigma_t and albedo.
        let ell = lattice.mean_link_length();
        let (sigma_t, albedo) = match lattice {
            Lattice::D3q6 => {
                let st = -(1.0f64 - kt).ln();
                (st, 1.0 - (-(1.0f64 - ka).ln()) / st)
            }
            Lattice::D3q18 => {
                let st = -(1.0 - kt).ln() * ell / 1.5;
                let sa = -(1.0f64 - ka).ln() / ell;
                (st, 1.0 - sa / st)
            }
        };
        // Blocks of 8 (8 steps a dispatch, about half the time per step) where the device's
        // shared memory allows (D3Q6 on lavapipe), else 4: after convergence the blocked
        // lattice's field is the global one's (blocked_and_global_lattices_agree_after_convergence).
        let block = if (lattice.links() + 2) * 512 * 4 <= gpu.info().max_compute_shared_memory { 8 } else { 4 };
        let (irr, book) =
            diffuse_impulse(&gpu, lattice, [n; 3], sigma_t as f32, albedo as f32, 0.0, 1.0, block, block, [c; 3], 1200)
                .unwrap();
        // The coefficients the kernel used, from the f32 inputs.
        let ka = match lattice {
            Lattice::D3q6 => 1.0 - (-(sigma_t as f32 as f64) * (1.0 - albedo as f32 as f64)).exp(),
            Lattice::D3q18 => 1.0 - (-(sigma_t as f32 as f64) * (1.0 - albedo as f32 as f64) * ell).exp(),
        };
        let persist = (1.0 - kt) / (1.0 - ka);
        let d = msq / 6.0 * (1.0 + persist) / (1.0 - persist);
        let mu = -(1.0 - ka).ln();
        // The kernel weights each arrival by its link length: the time-integrated count times
        // the mean link length of the stationary mix of links.
        let green = |r: f64| ell * (-r * (mu / d).sqrt()).exp() / (4.0 * std::f64::consts::PI * d * r);
        // Shell averages: the lattice's anisotropic short-range corrections (cubic harmonics, of
        // relative order 1/r^2, largest along the axes) average out over a sphere, the diffusion
        // solution is what is left.
        let mut worst = 0.0f64;
        for r in 3..=10u32 {
            let (mut lat, mut ana, mut count) = (0.0f64, 0.0f64, 0u32);
            for z in 0..n {
                for y in 0..n {
                    for x in 0..n {
                        let dist = [x, y, z].iter().map(|q| (*q as f64 - c as f64).powi(2)).sum::<f64>().sqrt();
                        if dist >= r as f64 - 0.5 && dist < r as f64 + 0.5 {
                            lat += irr[(x + n * (y + n * z)) as usize] as f64;
                            ana += green(dist);
                            count += 1;
                        }
                    }
                }
            }
            let rel = (lat - ana).abs() / ana;
            eprintln!(
                "{lattice:?} shell r {r} ({count} voxels): lattice {:.4e}, diffusion {:.4e}, rel {rel:.4}",
                lat / count as f64,
                ana / count as f64
            );
            if r >= 4 {
                worst = worst.max(rel);
            }
        }
        assert!(
            worst < 0.03,
            "{lattice:?}: worst relative deviation of a shell average from the diffusion solution: {worst}"
        );
        // Every bit of the impulse is absorbed, leaked or still moving.
        assert!((book.absorbed[0] + book.leaked[0] + book.remaining[0] - 1.0).abs() < 1e-4, "{lattice:?}: {book:?}");
    }
    assert_clean(&gpu);
}

/// Without absorption energy is conserved: what was deposited either left through the boundary
/// or is still in the lattice, at every stage (tracked by the kernels' tallies).
#[test]
fn lossless_lattice_conserves_energy() {
    let gpu = gpu();
    for lattice in [Lattice::D3q6, Lattice::D3q18] {
        for (steps, block_steps) in [(7u32, 1u32), (40, 4), (300, 8)] {
            let (_, book) =
                diffuse_impulse(&gpu, lattice, [20, 16, 12], 3.0, 1.0, 0.0, 0.1, 4, block_steps, [9, 7, 5], steps)
                    .unwrap();
            assert!(book.absorbed[0].abs() < 1e-7, "{lattice:?}: albedo 1 absorbed {}", book.absorbed[0]);
            let total = book.leaked[0] + book.remaining[0];
            assert!(
                (total - 1.0).abs() < 1e-5,
                "{lattice:?} after {steps} steps: leaked {} + remaining {} = {total}",
                book.leaked[0],
                book.remaining[0]
            );
            assert!(book.leaked[0] > 0.0);
        }
    }
    assert_clean(&gpu);
}

#[test]
fn reflecting_boundary_keeps_energy_in_and_creates_none() {
    // A refractive object's surface gives the share boundary_r of each link leaving the
    // medium to the opposite link (glsl/lattice/diffuse.comp). Lossless medium: a perfect
    // mirror (r = 1) lets nothing out of D3Q6, whatever the blocking; r = 0.6 (glass's diffuse
    // reflectance) lets out less than none, and the book still closes. (D3Q18's mirror leaks
    // a little: in a voxel on an edge of the box a diagonal link and its opposite both leave,
    // so the reflected share leaves too.)
    let gpu = gpu();
    for lattice in [Lattice::D3q6, Lattice::D3q18] {
        let mut leaked = Vec::new();
        for r in [0.0f32, 0.6, 1.0] {
            for (steps, block_steps) in [(40u32, 1u32), (300, 4)] {
                let (_, book) = diffuse_impulse_reflecting(
                    &gpu,
                    lattice,
                    [20, 16, 12],
                    [3.0, 1.0, 0.0, 0.1],
                    4,
                    block_steps,
                    [9, 7, 5],
                    steps,
                    r,
                )
                .unwrap();
                let total = book.leaked[0] + book.remaining[0];
                assert!(
                    (total - 1.0).abs() < 1e-5,
                    "{lattice:?} r {r} after {steps} steps: leaked {} + remaining {} = {total}",
                    book.leaked[0],
                    book.remaining[0]
                );
                if r == 1.0 && lattice == Lattice::D3q6 {
                    assert!(book.leaked[0].abs() < 1e-6, "{lattice:?}: a mirror boundary leaked {}", book.leaked[0]);
                }
                if steps == 300 {
                    leaked.push(book.leaked[0]);
                }
            }
        }
        eprintln!("{lattice:?}: leaked after 300 steps at r = 0, 0.6, 1: {leaked:?}");
        assert!(leaked[0] > leaked[1] && leaked[1] > leaked[2], "{lattice:?}: {leaked:?}");
        assert!(leaked[1] > 0.05, "{lattice:?}: {leaked:?}");
    }
    assert_clean(&gpu);
}

/// Blocked lattice (b^3 blocks, several steps per dispatch, energy crossing block faces
/// delayed to the next dispatch) against the global lattice: same field after convergence
/// (thesis 4.7.2, Fig. 4.7).
#[test]
fn blocked_and_global_lattices_agree_after_convergence() {
    let gpu = gpu();
    let dims = [24u32, 20, 16];
    for lattice in [Lattice::D3q6, Lattice::D3q18] {
        let run = |block: u32, steps: u32| {
            diffuse_impulse(&gpu, lattice, dims, 0.4, 0.95, 0.3, 1.0, block, steps, [5, 9, 8], 1200).unwrap().0
        };
        let global = run(4, 1);
        for (block, steps) in [(4u32, 4u32), (2, 2), (8, 8)] {
            let shared = (lattice.links() + 2) * block.pow(3) * 4;
            if shared > gpu.info().max_compute_shared_memory {
                // Too big for this device: refused up front, naming the knob, not a validation error.
                let e = diffuse_impulse(&gpu, lattice, dims, 0.4, 0.95, 0.3, 1.0, block, steps, [5, 9, 8], 8)
                    .expect_err("refused");
                assert!(e.to_string().contains("block 8") && e.to_string().contains("shared memory"), "{e}");
                continue;
            }
            let blocked = run(block, steps);
            let num: f64 = global.iter().zip(&blocked).map(|(a, b)| ((a - b) as f64).powi(2)).sum();
            let den: f64 = global.iter().map(|a| (*a as f64).powi(2)).sum();
            let rel = (num / den).sqrt();
            eprintln!("{lattice:?} block {block}, {steps} steps per dispatch: relL2 vs global {rel:.2e}");
            assert!(rel < 1e-4, "{lattice:?} block {block}: relL2 {rel}");
        }
    }
    assert_clean(&gpu);
}

const SPHERE: &str = r#"
[render]
width = 32
height = 32
seed = 4
spp = 512
[camera]
origin = [0.0, 0.0, 4.0]
target = [0.0, 0.0, 0.0]
fov = 20.0
[medium]
bounds = [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]
sigma_t = 10.0
albedo = ALBEDO
density = { kind = "sphere", center = [0.0, 0.0, 0.0], radius = 0.45 }
[[light]]
kind = "directional"
direction = [-0.57735, -0.57735, -0.57735]
irradiance = 3.0
[[light]]
kind = "environment"
radiance = 0.1
"#;

const SMALL: [(&str, &str); 4] =
    [("lbl.grid", "24"), ("lbl.rays", "4096"), ("lbl.view_env_dirs", "16"), ("lbl.view_supersample", "1")];

fn with(extra: &[(&'static str, &'static str)]) -> Vec<(&'static str, &'static str)> {
    SMALL.iter().copied().chain(extra.iter().copied()).collect()
}

#[test]
fn concurrent_and_sequential_schedules_agree() {
    let gpu = gpu();
    let s = scene(&SPHERE.replace("ALBEDO", "0.9"));
    let a = render(&gpu, &s, LBL, &with(&[("lbl.deterministic", "true"), ("lbl.schedule", "concurrent")]));
    let b = render(&gpu, &s, LBL, &with(&[("lbl.deterministic", "true"), ("lbl.schedule", "sequential")]));
    assert!(a.image.data == b.image.data, "deterministic mode: schedules must give identical images");
    let c = render(&gpu, &s, LBL, &with(&[("lbl.deterministic", "true"), ("lbl.schedule", "concurrent")]));
    assert!(a.image.data == c.image.data, "deterministic mode: two runs must be identical");
    if gpu.info().float_atomics {
        let f = render(&gpu, &s, LBL, &with(&[("lbl.schedule", "sequential")]));
        let m = scatterlab::output::compare(&f.image, &a.image).unwrap();
        assert!(m.rel_l2 < 1e-4, "float-atomic transfer vs fixed point: relL2 {}", m.rel_l2);
    }
    assert_clean(&gpu);
}

/// `--compare-schedules` on the device: every repeat measured, the kept image agrees with the
/// sequential one, and a gain only where the device gives the roles separate queues.
#[test]
fn schedule_comparison_repeats_and_knows_a_shared_queue() {
    use scatterlab::measure::timeline::compare_schedules;
    use scatterlab::solvers::{RenderRequest, Settings};
    let gpu = gpu();
    let s = scene(&SPHERE.replace("ALBEDO", "0.9"));
    let pairs: Vec<(String, String)> =
        with(&[("lbl.deterministic", "true")]).iter().map(|(k, v)| (k.to_string(), v.to_string())).collect();
    let settings = Settings::new(&pairs);
    let req = RenderRequest { scene: &s, settings: &settings, force_full: false, progress: &|_| {} };
    let (_, c) = compare_schedules(&gpu, LBL, &req, 2).expect("comparison");
    assert_eq!((c.sequential_ms.len(), c.concurrent_ms.len()), (2, 2), "{c:?}");
    assert!(c.sequential_ms.iter().chain(&c.concurrent_ms).all(|t| *t > 0.0), "{c:?}");
    assert_eq!(c.images_rel_l2, 0.0, "deterministic schedules differ: {c:?}");
    assert_eq!(c.shared_queue, gpu.info().mapping.shared());
    assert_eq!(c.gain.is_none(), c.shared_queue, "{c:?}");
    assert_clean(&gpu);
}

/// Progress that does not lie: marching rounds counted as they finish (never ahead, never
/// back), up to their total,
/// then the lattice's iterations with their convergence measure, ending below the tolerance;
/// the estimate of the iterations left, where given, is within a factor of 3 of what was left.
#[test]
fn lbl_progress_counts_rounds_then_reports_convergence() {
    use scatterlab::solvers::{Progress, RenderRequest, Settings};
    use std::cell::RefCell;
    let gpu = gpu();
    let s = scene(&SPHERE.replace("ALBEDO", "0.9"));
    let pairs: Vec<(String, String)> = SMALL.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect();
    let settings = Settings::new(&pairs);
    let events = RefCell::new(Vec::new());
    let record = |p: Progress| events.borrow_mut().push(p);
    let req = RenderRequest { scene: &s, settings: &settings, force_full: false, progress: &record };
    LBL.render(&gpu, &req).expect("render");
    let events = events.into_inner();
    let rounds: Vec<(u64, u64)> = events
        .iter()
        .filter_map(|p| match p {
            Progress::Work { stage: "marching rounds", done, total } => Some((*done, *total)),
            _ => None,
        })
        .collect();
    let total = rounds.last().expect("round progress").1;
    assert!(total > 1 && rounds[0].0 == 0 && rounds.windows(2).all(|w| w[1].0 >= w[0].0), "rounds {rounds:?}");
    assert!(rounds.iter().all(|r| r.1 == total && r.0 <= total), "rounds {rounds:?}");
    assert_eq!(rounds.last().unwrap().0, total, "rounds end short: {rounds:?}");
    let iters: Vec<(u64, f64, f64, Option<u64>)> = events
        .iter()
        .filter_map(|p| match p {
            Progress::Converging { iteration, change, tol, remaining, .. } => {
                Some((*iteration, *change, *tol, *remaining))
            }
            _ => None,
        })
        .collect();
    assert!(iters.len() >= 3, "too few convergence reports: {iters:?}");
    assert!(iters.windows(2).all(|w| w[1].0 > w[0].0), "iterations not increasing: {iters:?}");
    let (last_iteration, last_change, tol, _) = *iters.last().unwrap();
    assert!(last_change < tol, "the last report is not converged: {iters:?}");
    // Each estimate against the iterations actually left (to the last report), over the
    // reports with at least a chunk left.
    let judged: Vec<f64> = iters
        .iter()
        .filter_map(|(i, _, _, r)| {
            r.filter(|_| last_iteration > *i + 8).map(|r| r as f64 / (last_iteration - i) as f64)
        })
        .collect();
    assert!(!judged.is_empty(), "no estimate of the iterations left: {iters:?}");
    assert!(judged.iter().all(|q| (1.0 / 3.0..=3.0).contains(q)), "estimate / actual {judged:?}: {iters:?}");
    assert_clean(&gpu);
}

#[test]
fn no_albedo_lbl_equals_single() {
    let gpu = gpu();
    let s = scene(&SPHERE.replace("ALBEDO", "0.0"));
    let l = render(&gpu, &s, LBL, &with(&[]));
    let v = render(&gpu, &s, SINGLE, &[("single.env_dirs", "16"), ("single.supersample", "1")]);
    assert!(l.image.data == v.image.data, "albedo 0: nothing to diffuse, lbl must be single");
    let s = scene(&SPHERE.replace("ALBEDO", "0.02"));
    let l = render(&gpu, &s, LBL, &with(&[]));
    let v = render(&gpu, &s, SINGLE, &[("single.env_dirs", "16"), ("single.supersample", "1")]);
    let m = scatterlab::output::compare(&l.image, &v.image).unwrap();
    assert!(m.rel_l2 < 2e-3, "albedo 0.02: lbl vs single relL2 {}", m.rel_l2);
    assert_clean(&gpu);
}

#[test]
fn lbl_beats_single_against_path_at_albedo_09() {
    let gpu = gpu();
    let s = scene(&SPHERE.replace("ALBEDO", "0.9"));
    let reference = crate::common::path_reference(&gpu, &s, &[]);
    let l = render(&gpu, &s, LBL, &with(&[("lbl.grid", "32"), ("lbl.rays", "16384")]));
    let v = render(&gpu, &s, SINGLE, &[]);
    let el = scatterlab::output::compare(&l.image, &reference.image).unwrap();
    let es = scatterlab::output::compare(&v.image, &reference.image).unwrap();
    eprintln!(
        "albedo 0.9 sphere vs path ({} spp): lbl relL2 {:.4} (energy {:.3}), single relL2 {:.4} (energy {:.3})",
        s.render.spp, el.rel_l2, el.energy_ratio, es.rel_l2, es.energy_ratio
    );
    assert!(el.rel_l2 < 0.5 * es.rel_l2, "lbl {} must be well closer to path than single {}", el.rel_l2, es.rel_l2);
    let stats = l.report.detail::<LblStats>().expect("lbl stats");
    assert!(stats.converged);
    assert!(stats.energy.injected[0] > 0.0);
    let c = l.report.stats.convergence.expect("lbl reports its convergence");
    assert!(c.converged && c.iterations == stats.iterations as u64 && c.final_change < c.tolerance);
    assert_clean(&gpu);
}

/// A unit cube (albedo 0.95) lit by a directional light travelling along `dir`, seen by a
/// perspective camera in front: the forward-peak cases of issue 11 (the shared base scene,
/// edited).
fn forward_cube(sigma_t: &str, g: &str, dir: &str) -> scatterlab::scene::Scene {
    cube(sigma_t, "0.95", g, dir)
}

/// [`forward_cube`] with any albedo.
fn cube(sigma_t: &str, albedo: &str, g: &str, dir: &str) -> scatterlab::scene::Scene {
    scene(
        &SceneText::base()
            .set("render.width", "24")
            .set("render.height", "24")
            .set("render.seed", "1")
            .set("render.spp", "512")
            .set("camera.origin", "[0.6, 0.8, 4.0]")
            .set("camera.fov", "24.0")
            .set("medium.sigma_t", sigma_t)
            .set("medium.albedo", albedo)
            .set("medium.g", g)
            .set("light.kind", "\"directional\"")
            .replace_line("light.position", &format!("direction = {dir}"))
            .replace_line("light.intensity", "irradiance = 3.0"),
    )
}

/// The forward peak, both ways of carrying it: the directed injection (the deposit fluxes enter
/// the energy book like the deposits: what is injected is absorbed, leaks or is still moving)
/// and the forward population (`lbl.inject=forward`, the default for g >= 0 outside glass;
/// its fixed-point sums are signed like the fluxes). Each keeps the deterministic mode
/// bit-identical across schedules, and float atomics agree with it. The forward population
/// hands the lattice the isotropic share (1 - g) of the once-scattered light and what it
/// collides itself, so the lattice receives between (1 - g) of the once-scattered energy and
/// all of it.
#[test]
fn forward_peak_keeps_the_energy_book_and_determinism() {
    let gpu = gpu();
    let s = forward_cube("5.0", "0.6", "[0.3, -0.4, 0.85]");
    let small = [("lbl.grid", "16"), ("lbl.rays", "4096")];
    let default = render(&gpu, &s, LBL, &small);
    let st = default.report.detail::<LblStats>().expect("lbl stats");
    assert!(st.forward && !st.directed && st.flux, "g 0.6 outside glass gets the forward population by default");
    let backward = render(&gpu, &forward_cube("5.0", "-0.6", "[0.3, -0.4, 0.85]"), LBL, &small);
    let st = backward.report.detail::<LblStats>().expect("lbl stats");
    assert!(st.directed && !st.forward && st.flux, "g < 0 gets the directed injection by default");
    let mut injected = Vec::new();
    let mut forward_book = None;
    for mode in ["directed", "forward", "isotropic"] {
        let mut sets = small.to_vec();
        sets.extend([("lbl.inject", mode), ("lbl.deterministic", "true"), ("lbl.schedule", "sequential")]);
        let a = render(&gpu, &s, LBL, &sets);
        let st = a.report.detail::<LblStats>().expect("lbl stats");
        assert!(st.directed == (mode == "directed") && st.forward == (mode == "forward"), "{mode}");
        assert!(st.energy.imbalance() < 1e-4, "energy book, {mode}: {:?}", st.energy);
        injected.push(st.energy.injected[0]);
        if mode == "forward" {
            forward_book = st.forward_book;
        } else {
            assert!(st.forward_book.is_none(), "{mode}");
        }
        sets.pop();
        sets.push(("lbl.schedule", "concurrent"));
        let b = render(&gpu, &s, LBL, &sets);
        assert!(a.image.data == b.image.data, "deterministic, {mode}: schedules must agree bit for bit");
        if gpu.info().float_atomics {
            let f = render(&gpu, &s, LBL, &[small[0], small[1], ("lbl.inject", mode)]);
            let m = scatterlab::output::compare(&f.image, &a.image).unwrap();
            assert!(m.rel_l2 < 1e-3, "float atomics vs fixed point, {mode}: relL2 {}", m.rel_l2);
        }
    }
    // directed and isotropic inject all the once-scattered light; forward between 0.4 and 1 of
    // it, and its own book closes: what the lattice got, what the population's collisions
    // absorbed and what left with it add up to the once-scattered light.
    assert!((injected[0] / injected[2] - 1.0).abs() < 1e-5, "{injected:?}");
    let share = injected[1] / injected[2];
    assert!(share > 0.4 && share < 1.0, "forward population: the lattice got {share} of the once-scattered light");
    let book = forward_book.expect("the forward population keeps its book");
    let total = injected[1] + book.absorbed[0] + book.left[0];
    eprintln!(
        "forward population: lattice {:.5}, absorbed {:.5}, left {:.5}; once-scattered {:.5}",
        injected[1], book.absorbed[0], book.left[0], injected[2]
    );
    assert!(book.absorbed[0] > 0.0 && book.left[0] > 0.0, "{book:?}");
    assert!((total / injected[2] - 1.0).abs() < 1e-4, "forward book: {total} against {}", injected[2]);
    // Isotropic media keep the thesis' lattice: no flux buffers, nothing directed or carried.
    let iso = forward_cube("5.0", "0.0", "[0.3, -0.4, 0.85]");
    let i = render(&gpu, &iso, LBL, &small);
    let st = i.report.detail::<LblStats>().expect("lbl stats");
    assert!(!st.directed && !st.flux && !st.forward);
    assert_clean(&gpu);
}

/// Across the range (sigma_t 1 and 20, g -0.6, 0.6 and 0.9, lit from the front and from
/// behind), against `path`: the forward-peak defaults keep lbl's image energy within 3x of
/// path's everywhere (the thesis' isotropic lattice is 7x too bright front-lit at g 0.9) and
/// halve the mean |ln energy ratio| of the isotropic lattice.
#[test]
fn forward_peak_brings_lbl_closer_to_path_across_g_and_thickness() {
    let gpu = gpu();
    let small = [("lbl.grid", "16"), ("lbl.rays", "4096")];
    let (mut sum_new, mut sum_old, mut n) = (0.0f64, 0.0f64, 0);
    for dir in ["[-0.3, -0.5, -0.8]", "[0.3, -0.4, 0.85]"] {
        for sigma_t in ["1.0", "20.0"] {
            for g in ["-0.6", "0.6", "0.9"] {
                let s = forward_cube(sigma_t, g, dir);
                let reference = crate::common::path_reference(&gpu, &s, &[]);
                // The cube 1 mean free path across with g 0.6 or 0.9 is too thin for lbl's
                // lattice (its reduced optical thickness 0.1-0.4: 2 voxels across are thinner
                // than 0.25 each): each of its renders says so, in its one warning; at g -0.6
                // (1.5 reduced) and on the thick cube they carry none.
                let lbl_render = |sets: &[(&str, &str)]| {
                    let out = crate::common::try_render(&gpu, &s, LBL, sets, false).expect("lbl renders");
                    let thin = sigma_t == "1.0" && g != "-0.6";
                    let w = &out.report.warnings;
                    assert_eq!(w.len(), thin as usize, "sigma_t {sigma_t} g {g}: {w:?}");
                    assert!(!thin || w[0].contains("too thin for lbl's lattice"), "{w:?}");
                    assert_eq!(out.image.nan_inf_count(), 0);
                    out
                };
                let new = lbl_render(&small);
                let mut old_sets = small.to_vec();
                old_sets.extend([("lbl.inject", "isotropic"), ("lbl.flux", "off")]);
                let old = lbl_render(&old_sets);
                let en = scatterlab::output::compare(&new.image, &reference.image).unwrap().energy_ratio;
                let eo = scatterlab::output::compare(&old.image, &reference.image).unwrap().energy_ratio;
                eprintln!("dir {dir} sigma_t {sigma_t} g {g}: energy ratio forward-peak {en:.3}, isotropic {eo:.3}");
                assert!(en.is_finite() && (1.0 / 3.0..3.0).contains(&en), "dir {dir} sigma_t {sigma_t} g {g}: {en}");
                sum_new += en.ln().abs();
                sum_old += eo.ln().abs();
                n += 1;
            }
        }
    }
    let (mean_new, mean_old) = (sum_new / n as f64, sum_old / n as f64);
    eprintln!("mean |ln energy ratio|: forward-peak {mean_new:.3}, isotropic {mean_old:.3}");
    assert!(mean_new < 0.5 * mean_old, "forward peak {mean_new} vs isotropic {mean_old}");
    assert_clean(&gpu);
}

/// The forward population (lbl.inject=forward, the default for g >= 0 outside glass) against
/// the directed injection across the range: a unit cube lit from the front, the side and
/// behind, sigma_t 20 (and 5 side-lit), g 0.6 and 0.9, against `path`. It must lower both the mean
/// |ln energy ratio| and the mean relL2 (measured at 48 x 48, grid 32, over 27 cases with g
/// 0.3 too and sigma_t 1: 0.168 -> 0.110 and 0.268 -> 0.196; docs/lbl.md), and bring the
/// side-lit g 0.9 cube, the directed injection's worst (2.0x path's energy), within 25%.
#[test]
fn forward_population_beats_the_directed_injection_across_the_range() {
    let gpu = gpu();
    let small = [("lbl.grid", "16"), ("lbl.rays", "4096")];
    let (mut ln_f, mut ln_d, mut rel_f, mut rel_d, mut n) = (0.0f64, 0.0f64, 0.0f64, 0.0f64, 0);
    for (name, dir) in [("front", "[-0.3, -0.5, -0.8]"), ("side", "[-0.95, -0.2, -0.1]"), ("back", "[0.3, -0.4, 0.85]")]
    {
        // sigma_t 20 for each light and g, and the directed injection's worst case, side-lit
        // g 0.9 at sigma_t 5 (7 cases: the suite's time).
        let cases: &[(&str, &str)] = if name == "side" {
            &[("20.0", "0.6"), ("20.0", "0.9"), ("5.0", "0.9")]
        } else {
            &[("20.0", "0.6"), ("20.0", "0.9")]
        };
        for &(sigma_t, g) in cases {
            {
                let s = forward_cube(sigma_t, g, dir);
                let reference = crate::common::path_reference(&gpu, &s, &[]);
                let fwd = render(&gpu, &s, LBL, &[small[0], small[1], ("lbl.inject", "forward")]);
                let dir_ = render(&gpu, &s, LBL, &[small[0], small[1], ("lbl.inject", "directed")]);
                let mf = scatterlab::output::compare(&fwd.image, &reference.image).unwrap();
                let md = scatterlab::output::compare(&dir_.image, &reference.image).unwrap();
                eprintln!(
                    "{name} sigma_t {sigma_t} g {g}: forward energy {:.3} relL2 {:.3}; directed {:.3} {:.3}",
                    mf.energy_ratio, mf.rel_l2, md.energy_ratio, md.rel_l2
                );
                assert!(fwd.image.data.iter().all(|v| v.is_finite() && *v >= 0.0), "{name} {sigma_t} {g}");
                if name == "side" && g == "0.9" {
                    assert!((mf.energy_ratio - 1.0).abs() < 0.25, "side-lit g 0.9: {}", mf.energy_ratio);
                }
                ln_f += mf.energy_ratio.ln().abs();
                ln_d += md.energy_ratio.ln().abs();
                rel_f += mf.rel_l2;
                rel_d += md.rel_l2;
                n += 1;
            }
        }
    }
    let k = n as f64;
    eprintln!(
        "mean |ln energy ratio| forward {:.3}, directed {:.3}; mean relL2 forward {:.3}, directed {:.3}",
        ln_f / k,
        ln_d / k,
        rel_f / k,
        rel_d / k
    );
    assert!(ln_f < ln_d && rel_f < rel_d, "forward {} {} vs directed {} {}", ln_f / k, rel_f / k, ln_d / k, rel_d / k);
    assert_clean(&gpu);
}

/// The tail extrapolation (lbl.extrapolate, the default) against the same lattice converged
/// plainly to 1e-7 per iteration, across optical thickness (1 to 40 over the cube), albedo
/// (0 to 0.99) and g (-0.9 to 0.9): the image within relL2 1e-3 and its energy not above the
/// converged one's (the tail stands for energy still in flight, never more), in no more
/// iterations than the plain criterion at the same tolerance per case and a quarter fewer in
/// all (measured: 928 -> 608, both stops 5e-5 from the converged image summed over the cases).
/// At albedo 0 nothing moves and nothing is extrapolated.
#[test]
fn extrapolated_tail_matches_the_converged_lattice_in_fewer_iterations() {
    let gpu = gpu();
    let small = [("lbl.grid", "16"), ("lbl.rays", "4096")];
    let mut tally = crate::common::TailTally::default();
    let cases = [
        ("1.0", "0.5", "0.0"),
        ("5.0", "0.9", "-0.9"),
        ("20.0", "0.95", "0.0"),
        ("20.0", "0.99", "0.9"),
        ("40.0", "0.99", "0.0"),
        ("5.0", "0.0", "0.0"),
    ];
    for (sigma_t, albedo, g) in cases {
        let s = cube(sigma_t, albedo, g, "[0.3, -0.4, 0.85]");
        let mut tight = small.to_vec();
        tight.extend([("lbl.extrapolate", "false"), ("lbl.tol", "1e-7"), ("lbl.max_iters", "100000")]);
        let reference = render(&gpu, &s, LBL, &tight);
        let mut plain_sets = small.to_vec();
        plain_sets.push(("lbl.extrapolate", "false"));
        let plain = render(&gpu, &s, LBL, &plain_sets);
        let ext = render(&gpu, &s, LBL, &small);
        let [sr, sp, se] =
            [&reference, &plain, &ext].map(|r| r.report.detail::<LblStats>().expect("lbl stats").clone());
        assert!(sr.converged && sp.converged && se.converged, "{sigma_t} {albedo} {g}: every run converges");
        let me = scatterlab::output::compare(&ext.image, &reference.image).unwrap();
        let mp = scatterlab::output::compare(&plain.image, &reference.image).unwrap();
        eprintln!(
            "sigma_t {sigma_t} albedo {albedo} g {g}: iterations converged {} plain {} extrapolated {} (tail {:?}); \
             relL2 to converged plain {:.2e} extrapolated {:.2e}, energy {:.5}",
            sr.iterations, sp.iterations, se.iterations, se.tail, mp.rel_l2, me.rel_l2, me.energy_ratio
        );
        assert!(me.rel_l2 < 1e-3, "{sigma_t} {albedo} {g}: extrapolated relL2 {}", me.rel_l2);
        assert!(me.energy_ratio < 1.0 + 1e-4, "{sigma_t} {albedo} {g}: extrapolated energy {}", me.energy_ratio);
        assert!(se.iterations <= sp.iterations, "{sigma_t} {albedo} {g}: {} > {}", se.iterations, sp.iterations);
        if albedo == "0.0" {
            assert!(se.tail.is_none() && me.rel_l2 == 0.0, "albedo 0: nothing to extrapolate");
        }
        assert!(se.energy.imbalance() < 1e-4, "the tally still balances: {:?}", se.energy);
        tally.add(me.rel_l2, mp.rel_l2, se.iterations, sp.iterations);
    }
    tally.assert_a_quarter_fewer();
    assert_clean(&gpu);
}

/// `lbl.block` derives the largest block (8, 4, 2) this device's shared memory and workgroup
/// size allow for the lattice, with as many steps per dispatch, and the stats say which ran
/// (lavapipe, 32 KiB: d3q6 at 8, d3q18 at 4); a block the user sets is checked as it is, and
/// refused naming the knob when the device cannot run it.
#[test]
fn derived_block_is_the_largest_the_device_runs() {
    use scatterlab::solvers::parts::lattice::check_block;
    let gpu = gpu();
    let s = scene(&SPHERE.replace("ALBEDO", "0.9"));
    for kind in [Lattice::D3q6, Lattice::D3q18] {
        let out = render(&gpu, &s, LBL, &with(&[("lbl.lattice", kind.name()), ("lbl.grid", "16")]));
        let st = out.report.detail::<LblStats>().expect("lbl stats");
        let want = [8, 4, 2].into_iter().find(|b| check_block(gpu.info(), kind, st.channels, *b).is_ok());
        assert_eq!(Some((st.block, st.block_steps)), want.map(|b| (b, b)), "{kind:?}");
        if check_block(gpu.info(), kind, st.channels, 8).is_err() {
            let sets = with(&[("lbl.lattice", kind.name()), ("lbl.grid", "16"), ("lbl.block", "8")]);
            let err = crate::common::try_render(&gpu, &s, LBL, &sets, false).err().expect("block 8 refused");
            assert!(err.to_string().contains("lbl.block"), "{err}");
        }
    }
    assert_clean(&gpu);
}

/// lbl.drift's constants are what their derivation says: the mean of max(0, -w_z) over the cone
/// of directions nearest +x (a link's cone), and of max(0, -w_y) max(0, -w_z) (what two open
/// faces of an edge count twice), by midpoint quadrature on the sphere; with the
/// outward cone's mean |w_z| the six cones let out exactly the partial current of an isotropic
/// population, 1/4 per voxel of path.
#[test]
fn cone_drift_is_the_mean_drift_of_a_link_cone() {
    let n = 2000;
    let (mut side, mut side_n, mut out, mut out_n, mut pair) = (0.0f64, 0u64, 0.0f64, 0u64, 0.0f64);
    for a in 0..n {
        let z = -1.0 + (a as f64 + 0.5) * 2.0 / n as f64;
        let r = (1.0 - z * z).sqrt();
        for b in 0..n {
            let phi = (b as f64 + 0.5) * std::f64::consts::TAU / n as f64;
            let (x, y) = (r * phi.cos(), r * phi.sin());
            if x >= y.abs() && x >= z.abs() {
                side += (-z).max(0.0);
                pair += (-z).max(0.0) * (-y).max(0.0);
                side_n += 1;
            }
            if -z >= x.abs() && -z >= y.abs() {
                out += -z;
                out_n += 1;
            }
        }
    }
    let (f, m, fp) = (side / side_n as f64, out / out_n as f64, pair / side_n as f64);
    eprintln!("drift over a side cone {f:.5}, outward cone mean {m:.5}, pair term {fp:.5}");
    let cp = scatterlab::solvers::parts::lattice::CONE_DRIFT_PAIR as f64;
    assert!((fp - cp).abs() < 2e-4, "quadrature {fp} vs CONE_DRIFT_PAIR {cp}");
    let c = scatterlab::solvers::parts::lattice::CONE_DRIFT as f64;
    assert!((f - c).abs() < 2e-4, "quadrature {f} vs CONE_DRIFT {c}");
    assert!(((m + 4.0 * c) / 6.0 - 0.25).abs() < 1e-3, "outward {m}: partial current {}", (m + 4.0 * c) / 6.0);
}

/// lbl.drift against `path` on cubes whose lit faces the camera sees (where the lattice's
/// trapped surface light showed): the issue's cube (sigma_t 20, albedo 0.95, point light of
/// 10 W/sr near a corner) at g 0 and 0.6, and a directional light from the front, the side and
/// behind at sigma_t 5 and 20 (g 0). With the drift, the energy ratio moves toward 1 on average
/// by more than half in log and relL2 falls; the issue's cube at g 0 within 5% of path (issue
/// 11's target; measured 0.958 here and 0.961 at 64 x 64 and grid 64 since the view pass
/// integrates thick steps exactly, 0.945 before that; 1.107 without the drift). At g 0.6 it
/// is 1.108 here, 1.22 at grid 64: not within 5% (docs/lbl.md says why).
#[test]
fn surface_drift_brings_lit_cubes_closer_to_path() {
    let gpu = gpu();
    let small = [("lbl.grid", "32"), ("lbl.rays", "4096"), ("lbl.view_supersample", "4")];
    let issue_cube = crate::common::issue_cube;
    let mut cases =
        vec![("issue cube g 0".to_string(), issue_cube("0.0")), ("issue cube g 0.6".to_string(), issue_cube("0.6"))];
    for (name, dir) in [("front", "[-0.3, -0.5, -0.8]"), ("side", "[-0.95, -0.2, -0.1]"), ("back", "[0.3, -0.4, 0.85]")]
    {
        for sigma_t in ["5.0", "20.0"] {
            cases.push((format!("{name}-lit sigma_t {sigma_t}"), cube(sigma_t, "0.95", "0.0", dir)));
        }
    }
    let (mut ln_on, mut ln_off, mut rel_on, mut rel_off) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for (name, s) in &cases {
        let reference = crate::common::path_reference(&gpu, s, &[]);
        let on = render(&gpu, s, LBL, &small);
        let mut off_sets = small.to_vec();
        off_sets.push(("lbl.drift", "false"));
        let off = render(&gpu, s, LBL, &off_sets);
        let mon = scatterlab::output::compare(&on.image, &reference.image).unwrap();
        let moff = scatterlab::output::compare(&off.image, &reference.image).unwrap();
        eprintln!(
            "{name}: energy ratio drift {:.3} (relL2 {:.3}), none {:.3} ({:.3})",
            mon.energy_ratio, mon.rel_l2, moff.energy_ratio, moff.rel_l2
        );
        assert!(mon.energy_ratio.is_finite() && mon.energy_ratio > 0.0, "{name}");
        if name == "issue cube g 0" {
            assert!((mon.energy_ratio - 1.0).abs() < 0.05, "{name}: energy ratio {}", mon.energy_ratio);
        }
        ln_on += mon.energy_ratio.ln().abs();
        ln_off += moff.energy_ratio.ln().abs();
        rel_on += mon.rel_l2;
        rel_off += moff.rel_l2;
    }
    let k = cases.len() as f64;
    eprintln!(
        "mean |ln energy ratio| drift {:.3}, none {:.3}; mean relL2 drift {:.3}, none {:.3}",
        ln_on / k,
        ln_off / k,
        rel_on / k,
        rel_off / k
    );
    assert!(ln_on < 0.5 * ln_off, "mean |ln energy ratio| drift {} vs none {}", ln_on / k, ln_off / k);
    assert!(rel_on < rel_off, "mean relL2 drift {} vs none {}", rel_on / k, rel_off / k);
    assert_clean(&gpu);
}

/// Issue 11: the issue's cubes at lbl's defaults. The default grid follows the medium's reduced
/// optical length T (sigma_t (1 - albedo g) times the longest side): 64 for g 0 (T = 20), 32 for
/// g 0.6 (T = 8.6), where the surface voxels keep the reduced optical thickness the boundary
/// treatment was calibrated for. At grid 64 the g 0.6 cube read 1.18 of path's energy (docs/lbl.md,
/// "the default grid"). Both within 5% of path's energy.
#[test]
fn issue_cubes_at_the_default_grid_keep_path_energy() {
    let gpu = gpu();
    for (g, grid) in [("0.0", 64u32), ("0.6", 32)] {
        let s = crate::common::issue_cube(g);
        assert_eq!(scatterlab::solvers::lbl::default_grid(&s), grid, "g {g}");
        let reference = crate::common::path_reference(&gpu, &s, &[]);
        // Supersampled view: at 24 x 24 the cube's edge pixels are a large share, and path
        // averages over each pixel (unsupersampled, the g 0.6 cube reads 1.072 here, 1.033 at
        // 64 x 64).
        let out = render(&gpu, &s, LBL, &[("lbl.rays", "16384"), ("lbl.view_supersample", "4")]);
        assert_eq!(out.report.settings["grid"], grid, "g {g}: the grid the render used");
        let m = scatterlab::output::compare(&out.image, &reference.image).unwrap();
        eprintln!("issue cube g {g}, default grid {grid}: energy ratio {:.3}, relL2 {:.3}", m.energy_ratio, m.rel_l2);
        assert!((m.energy_ratio - 1.0).abs() < 0.05, "g {g}: energy ratio {}", m.energy_ratio);
    }
    assert_clean(&gpu);
}

/// The default grid's rule on its own: T below 10 gives 32, T of 16 and more 64, multiples of 8
/// between; an object's materials count, the v1 medium's placeholder does not.
#[test]
fn default_grid_follows_the_reduced_optical_length() {
    let cube = |st: &str, albedo: &str, g: &str, density: &str| {
        scene(&format!(
            "[render]\nwidth = 8\nheight = 8\n[camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov = 30.0\n\
             [medium]\nbounds = [[-0.5, -0.5, -0.5], [1.5, 0.5, 0.5]]\nsigma_t = {st}\nalbedo = {albedo}\ng = {g}\n\
             density = {density}\n[[light]]\nkind = \"environment\"\nradiance = 1.0\n"
        ))
    };
    let constant = "{ kind = \"constant\" }";
    let grid = scatterlab::solvers::lbl::default_grid;
    // Longest side 2: T = 2 sigma_t (1 - albedo g).
    assert_eq!(grid(&cube("1.0", "0.9", "0.0", constant)), 32); // T 2
    assert_eq!(grid(&cube("4.9", "0.9", "0.0", constant)), 32); // T 9.8
    assert_eq!(grid(&cube("5.0", "0.9", "0.0", constant)), 40); // T 10
    assert_eq!(grid(&cube("7.0", "0.9", "0.0", constant)), 56); // T 14
    assert_eq!(grid(&cube("8.0", "0.9", "0.0", constant)), 64); // T 16
    assert_eq!(grid(&cube("1000.0", "0.9", "0.0", constant)), 64);
    // Forward scattering lowers the transport coefficient: sigma_t 10, albedo 0.9, g 0.8: T 5.6.
    assert_eq!(grid(&cube("10.0", "0.9", "0.8", constant)), 32);
    // Backward scattering raises it: sigma_t 4, albedo 0.9, g -0.5: T 11.6.
    assert_eq!(grid(&cube("4.0", "0.9", "-0.5", constant)), 40);
    // The largest channel decides.
    assert_eq!(grid(&cube("[1.0, 2.0, 8.0]", "0.9", "0.0", constant)), 64);
    // A sphere density is 1 inside: as constant.
    assert_eq!(grid(&cube("8.0", "0.9", "0.0", "{ kind = \"sphere\", center = [0, 0, 0], radius = 0.5 }")), 64);
    assert_eq!(grid(&cube("0.0", "0.9", "0.0", constant)), 32);
}

/// The default near ball is at most 1.5 mean free paths at the light: on a coarse lattice in a
/// dense medium three voxels held most of the light's first scattering, and the lumped image
/// lost a quarter of its energy (a sphere of sigma_t 8, albedo 0.95, grid 16, one voxel a mean
/// free path: 0.738 of path's; 1.079 with the cap).
#[test]
fn near_ball_stays_within_a_mean_free_path_or_two_on_coarse_lattices() {
    let gpu = gpu();
    let text = "[render]\nwidth = 16\nheight = 16\nseed = 1\nspp = 2048\n\
                [camera]\norigin = [0.0, 0.4, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov = 34.0\n\
                [medium]\nbounds = [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]\nsigma_t = 8.0\nalbedo = 0.95\ng = 0.0\n\
                density = { kind = \"sphere\", center = [0, 0, 0], radius = 1.0 }\n\
                [[light]]\nkind = \"point\"\nposition = [0.2, 0.1, 0.0]\nintensity = 1.0\n";
    let s = scene(text);
    let reference = crate::common::path_reference(&gpu, &s, &[]);
    let capped = render(&gpu, &s, LBL, &[("lbl.grid", "16")]);
    let three = render(&gpu, &s, LBL, &[("lbl.grid", "16"), ("lbl.near_light", "3")]);
    let (rel_c, e_c) = crate::common::judge(&capped.image, &reference);
    let (rel_3, e_3) = crate::common::judge(&three.image, &reference);
    eprintln!("default (capped) relL2 {rel_c:.4} energy {e_c:.4}; 3 voxels relL2 {rel_3:.4} energy {e_3:.4}");
    assert!((e_c - 1.0).abs() < 0.12 && rel_c < 0.25, "capped: energy {e_c}, relL2 {rel_c}");
    assert!(rel_c < rel_3 && (e_c - 1.0).abs() < (e_3 - 1.0).abs(), "{rel_c} {e_c} against {rel_3} {e_3}");
    assert_clean(&gpu);
}

/// lbl.near_light: about a point light inside the medium, the once-scattered light of a ball of
/// 3 voxels is lumped into the light instead of injected (src/solvers/lbl/mod.rs, NearLight). The
/// lattice then never sees the concentrated deposits whose six axial beams streamed along the
/// lattice's axes and drew a "+" through the light. Against `path` on a cube with a light
/// near its centre (sigma_t 2: a mean free path of 8 voxels, where the beams reach far): the
/// "+" (lbl / path along the light's row and column, against rows and columns 5 pixels away)
/// shrinks to a third or less, relL2 falls, the energy gets no further from path's; and the
/// share k of the light's power lumped lies between what balls of the radius less half a
/// voxel and plus half a voxel diagonal scatter, albedo (1 - exp(-sigma_t r lambda)), less
/// what the forward population carries out of the ball.
#[test]
fn near_light_ball_removes_the_plus_around_a_light_inside() {
    let gpu = gpu();
    let s = scene(
        "[render]\nwidth = 32\nheight = 32\nseed = 1\nspp = 1024\n\
         [camera]\norigin = [0.0, 0.0, 5.0]\ntarget = [0.0, 0.0, 0.0]\nfov = 30.0\n\
         [medium]\nbounds = [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]\nsigma_t = 2.0\nalbedo = 0.95\ng = 0.3\n\
         density = { kind = \"constant\" }\n\
         [[light]]\nkind = \"point\"\nposition = [0.03, -0.02, 0.01]\nintensity = 1.0\n",
    );
    let small = [("lbl.grid", "32"), ("lbl.rays", "16384")];
    let reference = crate::common::path_reference(&gpu, &s, &[]);
    let on = render(&gpu, &s, LBL, &small);
    let mut off_sets = small.to_vec();
    off_sets.push(("lbl.near_light", "0"));
    let off = render(&gpu, &s, LBL, &off_sets);
    // The light projects to pixel (16, 16): its x axis to row 16, its y axis to column 16.
    let lum = |img: &scatterlab::output::Image, x: usize, y: usize| {
        let i = 3 * (y * 32 + x);
        img.data[i] as f64 + img.data[i + 1] as f64 + img.data[i + 2] as f64
    };
    let plus = |img: &scatterlab::output::Image| {
        let q = |x: usize, y: usize| lum(img, x, y) / lum(&reference.image, x, y).max(1e-12);
        let (mut axis, mut beside, mut n) = (0.0, 0.0, 0);
        for t in (2..30usize).filter(|t| t.abs_diff(16) > 3) {
            axis += q(t, 16) + q(16, t);
            beside += 0.25 * (q(t, 11) + q(t, 21) + q(11, t) + q(21, t)) * 2.0;
            n += 2;
        }
        (axis - beside) / n as f64
    };
    let (p_on, p_off) = (plus(&on.image), plus(&off.image));
    let m_on = scatterlab::output::compare(&on.image, &reference.image).unwrap();
    let m_off = scatterlab::output::compare(&off.image, &reference.image).unwrap();
    let st = on.report.detail::<LblStats>().expect("lbl stats");
    let k = st.near_light.as_ref().expect("the near ball is on by default here").k[0];
    let lambda = 2.0 / 32.0;
    let ball = |r: f64| 0.95 * (1.0 - (-2.0 * r * lambda).exp());
    eprintln!(
        "'+' excess of lbl / path on the axes: near ball {p_on:.3}, none {p_off:.3}; relL2 {:.3} vs {:.3}; energy \
         {:.3} vs {:.3}; k {k:.4} (balls {:.4}..{:.4})",
        m_on.rel_l2,
        m_off.rel_l2,
        m_on.energy_ratio,
        m_off.energy_ratio,
        ball(2.5),
        ball(3.0 + 0.5 * 3f64.sqrt())
    );
    assert!(p_off > 0.1, "the test must show the '+' without the ball: {p_off}");
    assert!(p_on.abs() < p_off / 3.0, "'+' {p_on} with the ball, {p_off} without");
    assert!(m_on.rel_l2 < m_off.rel_l2, "relL2 {} vs {}", m_on.rel_l2, m_off.rel_l2);
    assert!((m_on.energy_ratio.ln()).abs() <= (m_off.energy_ratio.ln()).abs() + 0.01, "energy");
    // The forward population (the default here, g 0.3) carries the share g of the ball's
    // once-scattered light out before it collides: the ball keeps between 1 - g of what
    // scatters in the smaller ball and all of what scatters in the larger one.
    assert!((0.7 * ball(2.5)..ball(3.0 + 0.5 * 3f64.sqrt())).contains(&k), "k {k}");
    // A seeded start's guess holds the near deposits' field: the ball is refused with it.
    let err = crate::common::try_render(&gpu, &s, LBL, &[("lbl.near_light", "3"), ("lbl.cascade", "1")], false)
        .err()
        .expect("the near ball with a cascadic start must be refused")
        .to_string();
    assert!(err.contains("lbl.near_light"), "{err}");
    assert_clean(&gpu);
}

/// lbl.max_iters bounds the lattice's steps in all, the marching rounds' included: the sphere's
/// 9 rounds of 8 steps ran 72 at max_iters 1 (and a million a round ran on for minutes). At a
/// budget the rounds use up, the render stops there and says no convergence test ran.
#[test]
fn max_iters_bounds_the_rounds_steps_too() {
    let gpu = gpu();
    let s =
        crate::common::repo_scene("scenes/homogeneous-sphere.toml", &[("render.width", "16"), ("render.height", "16")]);
    for max in ["1", "5"] {
        let out = crate::common::try_render(&gpu, &s, LBL, &[("lbl.grid", "16"), ("lbl.max_iters", max)], false)
            .expect("render");
        let st = out.report.detail::<LblStats>().expect("lbl stats");
        assert_eq!(st.iterations.to_string(), max, "{:?}", out.report.warnings);
        assert!(!st.converged);
        assert!(out.report.warnings.iter().any(|w| w.contains("none tested")), "{:?}", out.report.warnings);
    }
    assert_clean(&gpu);
}

/// Power the homogeneous sphere of [`SPHERE`] (radius R = 0.45, `sigma_t` per unit) scatters
/// once with albedo `albedo` out of its two lights: the directional one of irradiance 3 and the
/// environment of radiance 0.1, which lbl marches as parallel beams of irradiance 4 pi 0.1 in all
/// (marching.rs), and which a sphere meets as one beam of that irradiance would. Per unit
/// irradiance, the integral over the shaded disk of 1 - exp(-sigma_t chord):
/// 2 pi (R^2 / 2 - (1 - e^{-x} (1 + x)) / (2 sigma_t)^2), x = 2 sigma_t R.
fn sphere_once_scattered(sigma_t: f64, albedo: f64) -> f64 {
    let r = 0.45f64;
    let e = 3.0 + 4.0 * std::f64::consts::PI * 0.1;
    let a = 2.0 * sigma_t;
    let x = a * r;
    // 1 - e^{-x} (1 + x) = x^2/2 - x^3/3 + x^4/8 - ...: the series where the closed form cancels.
    let q = if x < 1e-3 { x * x / 2.0 - x * x * x / 3.0 + x.powi(4) / 8.0 } else { 1.0 - (-x).exp() * (1.0 + x) };
    2.0 * std::f64::consts::PI * e * albedo * (r * r / 2.0 - q / (a * a))
}

/// The once-scattered power lbl's march deposits and its transfer sums (the energy book's
/// `injected`) against the analytic integral, from a sphere 4.5e-6 mean free paths across to
/// one of 45 (albedo 0.5 and 0.99), in both transfers; and the default transfer deterministic.
/// Before the fix, the fixed-point transfer rounded each deposit to the nearest quantum and lost
/// every one in a thin medium (the multiply scattered term of the sphere at sigma_t 1e-3 was 0
/// at the default 65536 rays), and the march's 1 - exp(-x) in float deposited 1.14x the power
/// at sigma_t 1e-5 (one_minus_exp.glsl), and the quantum, 1e-9 of the rays' whole power, left
/// the thinnest sphere 680 quanta in all (3.8% noise; marching::deposit_scale). Measured after:
/// within 3.7e-4 of the integral everywhere, both transfers alike (the thick end worst: the
/// steps' midpoint density against the sphere's edge).
#[test]
fn transfer_deposits_the_once_scattered_power_thin_to_thick() {
    let gpu = gpu();
    assert!(gpu.info().float_atomics, "lavapipe offers float atomics: the test compares both transfers");
    // lbl warns that media this thin or thick are outside its lattice's range at grid 24: the
    // image is not judged here, only what the march and the transfer hand the lattice.
    let thin = "too thin for lbl's lattice";
    let thick = "reduced mean free paths thick, above";
    let mut worst = 0.0f64;
    for (sigma_t, warned) in
        [("0.00001", Some(thin)), ("0.001", Some(thin)), ("0.1", Some(thin)), ("10.0", None), ("100.0", Some(thick))]
    {
        for albedo in ["0.5", "0.99"] {
            let s = scene(&SPHERE.replace("ALBEDO", albedo).replace("sigma_t = 10.0", &format!("sigma_t = {sigma_t}")));
            let exact = sphere_once_scattered(sigma_t.parse().unwrap(), albedo.parse().unwrap());
            for det in ["true", "false"] {
                let sets = with(&[("lbl.deterministic", det), ("lbl.rays", "65536")]);
                let out = if let Some(w) = warned {
                    crate::common::render_warned(&gpu, &s, LBL, &sets, &[w])
                } else {
                    render(&gpu, &s, LBL, &sets)
                };
                let st = out.report.detail::<LblStats>().expect("lbl stats");
                assert_eq!(st.deterministic, det == "true");
                let ratio = st.energy.injected[0] / exact;
                eprintln!("sigma_t {sigma_t}, albedo {albedo}, deterministic {det}: injected / exact {ratio:.6}");
                worst = worst.max((ratio - 1.0).abs());
                assert!((ratio - 1.0).abs() < 1e-3, "sigma_t {sigma_t}, albedo {albedo}, deterministic {det}: {ratio}");
            }
        }
    }
    eprintln!("worst |injected / exact - 1| {worst:.2e}");
    // The default is the fixed-point transfer, and it repeats bit for bit.
    let s = scene(&SPHERE.replace("ALBEDO", "0.9"));
    let a = render(&gpu, &s, LBL, &SMALL);
    let b = render(&gpu, &s, LBL, &SMALL);
    assert!(a.report.detail::<LblStats>().expect("lbl stats").deterministic);
    assert!(a.image.data == b.image.data, "lbl's default render is not deterministic");
    assert_clean(&gpu);
}
