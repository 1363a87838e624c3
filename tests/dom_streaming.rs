//! `dom`'s block sweeps and out-of-core streaming (issue 13, thesis 5.3.3-5.3.4): the blocked
//! sweep reproduces the CPU oracle and the whole-grid sweeper; streaming through a pool a
//! fraction of the grid's size, or from a memory-mapped file, gives bit-identical results; the
//! device bytes never exceed `dom.budget`, and a budget below the working set is one clear error.

use scatterlab::gpu::QueueRole;
use scatterlab::physics::ordinates::{OrdinatesGrid, Scheme};
use scatterlab::physics::quadrature::Quadrature;
use scatterlab::physics::rng::Pcg32;
use scatterlab::solvers::dom::blocks::{BlockOptions, BlockSweeper, Evict, StoreKind};
use scatterlab::solvers::dom::ordinates::{Eye, SweepSetup, Sweeper};

use crate::common::{assert_clean, gpu};

const DOM: &dyn scatterlab::solvers::Solver = &scatterlab::solvers::dom::Dom;

struct Case {
    dims: [usize; 3],
    sigma_t: Vec<f32>,
    sigma_s: Vec<f32>,
    sigma_t64: Vec<f64>,
    albedo64: Vec<f64>,
}

fn case(dims: [usize; 3], seed: u64) -> Case {
    let voxels = dims.iter().product::<usize>();
    let mut rng = Pcg32::new(seed, 2);
    let sigma_t64: Vec<f64> = (0..voxels).map(|_| 0.5 + 15.0 * rng.next_f64()).collect();
    let albedo64: Vec<f64> = (0..voxels).map(|_| 0.5 + 0.49 * rng.next_f64()).collect();
    let sigma_t = sigma_t64.iter().map(|x| *x as f32).collect();
    let sigma_s = sigma_t64.iter().zip(&albedo64).map(|(t, a)| (t * a) as f32).collect();
    Case { dims, sigma_t, sigma_s, sigma_t64, albedo64 }
}

fn setup<'a>(c: &'a Case, q: &'a Quadrature, storage: &'a Quadrature, g: f64, scheme: Scheme) -> SweepSetup<'a> {
    SweepSetup {
        dims: c.dims.map(|d| d as u32),
        h: 0.1,
        origin: [0.0; 3],
        channels: 1,
        sigma_t: &c.sigma_t,
        sigma_s: &c.sigma_s,
        quadrature: q,
        storage,
        g,
        scatter_g: g,
        eye: Eye::Point([0.3, 0.2, 2.0]),
        scheme,
    }
}

fn first_source(m: usize, voxels: usize, seed: u64) -> Vec<f32> {
    let mut rng = Pcg32::new(seed, 5);
    (0..m * voxels).map(|_| if rng.next_f64() < 0.3 { rng.next_f64() as f32 } else { 0.0 }).collect()
}

/// Blocks of 3 voxels on a 7 x 5 x 6 grid (partial blocks on every axis): after 20 source
/// iterations the blocked sweep's fluence matches the CPU oracle (2e-6 of the largest) and the
/// whole-grid sweeper's fluence and light toward the camera (1e-5), for forward scattering
/// stored at the swept set with characteristics and backward scattering upsampled with the step
/// difference; streamed through the smallest pool (4 of 12 blocks) and from a file store, the
/// results are bit-identical to in-core.
#[test]
fn block_sweeps_match_the_oracle_and_stream_bit_identically() {
    let gpu = gpu();
    let c = case([7, 5, 6], 9);
    let voxels = c.sigma_t.len();
    let q = Quadrature::named("s4").unwrap();
    for (stored, g, scheme) in [("s4", 0.7, Scheme::Characteristics), ("s2", -0.5, Scheme::Step)] {
        let storage = Quadrature::named(stored).unwrap();
        let s = setup(&c, &q, &storage, g, scheme);
        let whole = Sweeper::new(&gpu, &s).expect("sweeper");
        let m = whole.storage.len();
        let first = first_source(m, voxels, 3);
        whole.set_first(&gpu, &first).expect("first");
        // Progressive iterations (thesis 5.3.3): each returns its bounce; the solution is their sum.
        let mut reference = vec![0f32; voxels];
        for _ in 0..20 {
            let bounce = whole.iterate(&gpu).expect("iterate");
            reference.iter_mut().zip(&bounce).for_each(|(r, b)| *r += b);
        }
        let reference_camera: Vec<f32> = gpu.read_buffer_as(&whole.camera).expect("camera");
        let grid = OrdinatesGrid {
            dims: c.dims,
            h: 0.1,
            sigma_t: c.sigma_t64.clone(),
            albedo: c.albedo64.clone(),
            periodic_xy: false,
            scheme,
        };
        let (swept, _, _) = q.by_octant();
        let first64: Vec<f64> = first.iter().map(|x| *x as f64).collect();
        let host = grid.solve_angular(&swept, &whole.storage, g, &first64, 0.0, 20);
        let scale = host.fluence.iter().fold(0.0f64, |a, x| a.max(*x));

        let run = |opts: BlockOptions| {
            let mut b = BlockSweeper::new(&gpu, &s, &opts).expect("block sweeper");
            b.set_first(&gpu, &first).expect("first");
            let mut phi = vec![0f32; voxels];
            for _ in 0..20 {
                let bounce = b.iterate(&gpu).expect("iterate");
                phi.iter_mut().zip(&bounce).for_each(|(p, b)| *p += b);
            }
            (phi, b.camera(), b.stats, b.device_bytes())
        };
        let (phi, camera, stats, _) = run(BlockOptions {
            block: 3,
            budget: None,
            store: StoreKind::Memory,
            copies: QueueRole::Transfer,
            evict: Evict::Overlap,
        });
        assert_eq!((stats.blocks, stats.pool_slots), (12, 12));
        assert_eq!(stats.uploads, 12, "in-core: every block loaded once");
        let worst = phi.iter().zip(&host.fluence).map(|(d, h)| (*d as f64 - h).abs() / scale).fold(0.0, f64::max);
        assert!(worst < 2e-6, "{stored}, g {g}: blocked vs oracle {worst:e}");
        let worst = phi.iter().zip(&reference).map(|(a, b)| (a - b).abs() as f64 / scale).fold(0.0, f64::max);
        assert!(worst < 1e-5, "{stored}, g {g}: blocked vs whole-grid {worst:e}");
        let cmax = reference_camera.iter().fold(0.0f32, |a, x| a.max(*x)) as f64;
        let worst = camera.iter().zip(&reference_camera).map(|(a, b)| (a - b).abs() as f64 / cmax).fold(0.0, f64::max);
        assert!(worst < 1e-5, "{stored}, g {g}: camera blocked vs whole-grid {worst:e}");

        // The smallest pool: a block and its three upwind neighbours.
        let record = stats.record_bytes;
        let (layout, fixed) = BlockSweeper::plan(s.dims, 1, &q, &storage, scheme, 3);
        let budget = fixed + 4 * record + 4 * layout.scratch();
        let (phi_s, camera_s, stats_s, bytes) = run(BlockOptions {
            block: 3,
            budget: Some(budget),
            store: StoreKind::Memory,
            copies: QueueRole::Transfer,
            evict: Evict::Overlap,
        });
        assert_eq!(stats_s.pool_slots, 4);
        assert!(stats_s.uploads > 20 * 12 && stats_s.write_backs > 0, "streamed: {stats_s:?}");
        assert!(bytes <= budget, "device bytes {bytes} above the budget {budget}");
        assert!(phi_s == phi, "{stored}, g {g}: streamed fluence differs from in-core");
        assert!(camera_s == camera, "{stored}, g {g}: streamed camera differs from in-core");
        let dir = tempfile::tempdir().unwrap();
        let (phi_f, camera_f, _, _) = run(BlockOptions {
            block: 3,
            budget: Some(fixed + 6 * record + 4 * 4 * layout.scratch()),
            store: StoreKind::File(dir.path().to_path_buf()),
            // The copies on a compute queue (dom.copies=compute) and Belady's eviction give the
            // same records.
            copies: QueueRole::Trace,
            evict: Evict::Belady,
        });
        assert!(phi_f == phi && camera_f == camera, "{stored}, g {g}: file store differs from in-core");
    }
    assert_clean(&gpu);
}

/// A budget below a block and its upwind neighbours is one error naming the smallest budget.
#[test]
fn a_budget_below_the_working_set_names_the_smallest() {
    let gpu = gpu();
    let c = case([8, 8, 8], 4);
    let q = Quadrature::named("s4").unwrap();
    let iso = Quadrature::isotropic();
    let s = setup(&c, &q, &iso, 0.0, Scheme::Characteristics);
    let err = BlockSweeper::new(
        &gpu,
        &s,
        &BlockOptions {
            block: 4,
            budget: Some(1000),
            store: StoreKind::Memory,
            copies: QueueRole::Transfer,
            evict: Evict::Overlap,
        },
    )
    .err()
    .expect("a 1000-byte budget cannot hold four blocks")
    .to_string();
    assert!(err.contains("dom.budget") && err.contains("at least"), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    let (layout, fixed) = BlockSweeper::plan(s.dims, 1, &q, &iso, Scheme::Characteristics, 4);
    let smallest = fixed + (layout.min_slots() as u64 * layout.record() + layout.scratch()) * 4;
    let ok = BlockSweeper::new(
        &gpu,
        &s,
        &BlockOptions {
            block: 4,
            budget: Some(smallest),
            store: StoreKind::Memory,
            copies: QueueRole::Transfer,
            evict: Evict::Overlap,
        },
    );
    assert!(ok.is_ok(), "the smallest budget works: {:?}", ok.err().map(|e| e.to_string()));
    assert_clean(&gpu);
}

/// `scatterlab render` of the anisotropic cube with dom into `dir/out` (and its report beside it
/// as `out.json`), with `base` and then `sets` as `--set` values.
fn cube_cli(dir: &std::path::Path, base: &[&str], sets: &[&str], out: &str) -> std::process::Output {
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/anisotropic-cube.toml");
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_scatterlab"));
    cmd.args(["render", scene, "--solver", "dom", "--out"]).arg(dir.join(out));
    cmd.arg("--json").arg(dir.join(format!("{out}.json")));
    for s in base.iter().chain(sets) {
        cmd.args(["--set", s]);
    }
    cmd.output().unwrap()
}

/// From the command line: a budget too small is one line on stderr naming the knob and the
/// smallest budget, a non-zero exit and no image; a streamed render's image equals the in-core
/// one bit for bit, and its report gives the pool within the budget.
#[test]
fn streamed_render_from_the_command_line_matches_in_core() {
    let dir = tempfile::tempdir().unwrap();
    let base = ["render.width=24", "render.height=24", "dom.grid=12", "dom.rays=4096", "dom.view_env_dirs=8"];
    let render = |sets: &[&str], out: &str| cube_cli(dir.path(), &base, sets, out);
    let small = render(&["dom.block=4", "dom.budget=0.01"], "small.exr");
    assert!(!small.status.success());
    let err = String::from_utf8_lossy(&small.stderr);
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error")).collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(lines[0].contains("dom.budget") && lines[0].contains("at least"), "{err}");
    assert!(!dir.path().join("small.exr").exists(), "no image after a refused budget");

    let whole = render(&["dom.block=4"], "whole.exr");
    assert!(whole.status.success(), "{}", String::from_utf8_lossy(&whole.stderr));
    let streamed = render(&["dom.block=4", "dom.budget=0.25"], "streamed.exr");
    assert!(streamed.status.success(), "{}", String::from_utf8_lossy(&streamed.stderr));
    let a = std::fs::read(dir.path().join("whole.exr.json")).unwrap();
    let b = std::fs::read(dir.path().join("streamed.exr.json")).unwrap();
    let a: serde_json::Value = serde_json::from_slice(&a).unwrap();
    let b: serde_json::Value = serde_json::from_slice(&b).unwrap();
    let stats = |v: &serde_json::Value| v.pointer("/stats/detail/streaming").cloned().unwrap_or_default();
    let (sa, sb) = (stats(&a), stats(&b));
    assert_eq!(sa["pool_slots"], sa["blocks"], "in-core: {sa}");
    assert!(sb["pool_slots"].as_u64().unwrap() < sb["blocks"].as_u64().unwrap(), "streamed: {sb}");
    let bytes = b.pointer("/stats/detail/sweep_device_bytes").and_then(|x| x.as_u64()).unwrap();
    assert!(bytes <= (0.25 * 1048576.0) as u64, "sweep device bytes {bytes} above dom.budget");
    // The EXR headers carry the settings; compare the pixels through the decoder.
    let pixels = |name: &str| {
        let path = dir.path().join(name);
        let image = exr::prelude::read_first_rgba_layer_from_file(
            &path,
            |r, _| vec![[0f32; 4]; r.width() * r.height()],
            |p: &mut Vec<[f32; 4]>, pos, (r, g, b, a): (f32, f32, f32, f32)| p[pos.y() * 24 + pos.x()] = [r, g, b, a],
        )
        .unwrap();
        image.layer_data.channel_data.pixels
    };
    assert!(pixels("whole.exr") == pixels("streamed.exr"), "streamed image differs from in-core");
}

/// Out of core end to end (issue 13, 5.2.2): under a small dom.budget the direct source is made
/// slab by slab (the density resampled, the light marched again and binned per slab) and the view
/// reads the light toward the camera slab by slab, so the grid-sized device buffers of every
/// phase stay within the budget. The first-scattering source is the same bits whatever the
/// slabs (each voxel's deposits are integer sums), so with the sweeps bit-identical too the image
/// differs from the in-core one only by the order the view's slabs add up in.
/// Two cases: the isotropic sphere under its sun and sky at 40^3 (15 beams: the deposit sums
/// are most of a layer, so the beams are summed in groups and the slabs are thicker; the light
/// toward the camera is larger than the budget, so the view runs in slabs), and a point light
/// inside a chromatic anisotropic cloud under a sky (rays marching both ways through the slabs,
/// 48 storage directions).
#[test]
fn direct_source_and_view_stream_slab_by_slab_within_the_budget() {
    let gpu = gpu();
    let sphere = crate::common::repo_scene("scenes/homogeneous-sphere.toml", &[]);
    let cloud = crate::common::repo_scene("scenes/point-light-in-cloud.toml", &[]);
    let cloud_sky = crate::common::repo_scene_plus(
        "scenes/point-light-in-cloud.toml",
        "\n[[light]]\nkind = \"environment\"\nradiance = [0.02, 0.03, 0.05]\n",
    );
    assert_eq!(cloud_sky.lights.len(), cloud.lights.len() + 1);
    // (name, scene, sets, budget MiB, view in slabs, beams summed in groups)
    type Case<'a> = (&'a str, &'a scatterlab::scene::Scene, &'a [(&'a str, &'a str)], f64, bool, bool);
    let cases: [Case; 2] = [
        (
            "sphere under a sun and a sky, 40^3",
            &sphere,
            &[
                ("dom.grid", "40"),
                ("dom.block", "8"),
                ("dom.directions", "s4"),
                ("render.width", "32"),
                ("render.height", "32"),
            ],
            0.12,
            true,
            true,
        ),
        (
            "point light in a cloud under a sky, 16^3",
            &cloud_sky,
            &[("dom.grid", "16"), ("dom.block", "4"), ("render.width", "24"), ("render.height", "24")],
            0.7,
            false,
            true,
        ),
    ];
    for (name, scene, sets, budget_mib, view_slabs, grouped) in cases {
        let common: Vec<(&str, &str)> = sets
            .iter()
            .copied()
            .chain([("dom.rays", "4096"), ("dom.max_iterations", "2"), ("dom.view_env_dirs", "8")])
            .collect();
        let whole = crate::common::try_render(&gpu, scene, DOM, &common, false).unwrap();
        let budget = budget_mib.to_string();
        let mut streamed_sets = common.clone();
        streamed_sets.push(("dom.budget", &budget));
        let streamed = crate::common::try_render(&gpu, scene, DOM, &streamed_sets, false).unwrap();
        let detail = |o: &scatterlab::solvers::RenderOutput| {
            o.report.detail::<scatterlab::solvers::dom::DomStats>().expect("dom's stats").clone()
        };
        let (w, s) = (detail(&whole), detail(&streamed));
        let bytes = (budget_mib * 1048576.0) as u64;
        eprintln!(
            "{name}: in-core 1 slab ({} B of source buffers), streamed {} source slabs of {} layers x {} groups of \
             beams ({} B), {} view slabs, pool {} B",
            w.source_device_bytes,
            s.source_slabs,
            s.source_layers,
            s.source_groups,
            s.source_device_bytes,
            s.view_slabs,
            s.sweep_device_bytes
        );
        assert_eq!((w.source_slabs, w.view_slabs), (1, 1), "{name}: in-core is one slab");
        assert!(w.source_device_bytes > bytes, "{name}: the case must need streaming");
        assert!(s.source_slabs > 1, "{name}: the direct source streamed");
        assert_eq!(s.view_slabs > 1, view_slabs, "{name}: view slabs {}", s.view_slabs);
        // Where the sums of the 15 beams are much of a layer (the sphere's: nearly all of it, one
        // storage direction; the cloud's: 45 of 189 floats per voxel, 48 storage directions),
        // summed in groups of beams the slabs are thicker than with all beams at once.
        assert_eq!(s.source_groups > 1, grouped, "{name}: beam groups {}", s.source_groups);
        assert!(s.source_device_bytes <= bytes && s.sweep_device_bytes <= bytes, "{name}: within the budget");
        // `scene info`'s estimate is what the streamed render allocates at its peak.
        let knobs: Vec<(String, String)> = streamed_sets
            .iter()
            .filter(|(k, _)| !scatterlab::scene::is_scene_key(k))
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
        let sized: Vec<(String, String)> = streamed_sets
            .iter()
            .filter(|(k, _)| scatterlab::scene::is_scene_key(k))
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
        let estimate = scatterlab::solvers::memory_estimate(
            DOM,
            &scene.with_overrides(&sized).unwrap(),
            &scatterlab::solvers::Settings::new(&knobs),
        )
        .unwrap();
        assert_eq!(estimate, streamed.report.device_bytes, "{name}: the memory estimate");
        let m = scatterlab::output::compare(&streamed.image, &whole.image).unwrap();
        let peak = whole.image.data.iter().fold(0f32, |a, b| a.max(*b));
        let diff = streamed.image.data.iter().zip(&whole.image.data).fold(0f32, |a, (x, y)| a.max((x - y).abs()));
        eprintln!("{name}: relMSE {:.2e}, max abs difference {diff:.2e} of peak {peak:.3}", m.rel_mse);
        if view_slabs {
            assert!(diff <= 1e-5 * peak && m.rel_mse < 1e-12, "{name}: streamed image differs: {diff} of {peak}");
        } else {
            assert_eq!(streamed.image.data, whole.image.data, "{name}: one view slab: bit-identical");
        }
    }
    assert_clean(&gpu);
}

/// dom's queue schedules (`Solver::schedules`) are its streaming copies' queue: on the compute
/// queue in order with the sweeps, or on the transfer role's. The comparison names them, and
/// both give the same image bit for bit (the same sweeps of the same blocks).
#[test]
fn schedule_comparison_runs_the_copies_on_either_queue() {
    use scatterlab::measure::timeline::compare_schedules;
    use scatterlab::solvers::{RenderRequest, Settings};
    let gpu = gpu();
    let h = DOM.concurrency(true).expect("dom has a concurrent workload");
    let (scene_sets, knobs): (Vec<_>, Vec<_>) =
        h.sets.iter().cloned().partition(|(k, _)| scatterlab::scene::is_scene_key(k));
    let scene_sets: Vec<(&str, &str)> = scene_sets.iter().map(|(k, v)| (k.as_str(), v.as_str())).collect();
    let scene = crate::common::repo_scene(&format!("scenes/{}", h.scene), &scene_sets);
    let settings = Settings::new(&knobs);
    let req = RenderRequest { scene: &scene, settings: &settings, force_full: false, progress: &|_| {} };
    let (out, c) = compare_schedules(&gpu, DOM, &req, 1).expect("comparison");
    assert_eq!(c.labels, ["dom.copies=compute".to_string(), "dom.copies=transfer".to_string()]);
    assert!(c.describe().contains("dom.copies=compute") && c.describe().contains("dom.copies=transfer"));
    assert_eq!(c.images_rel_l2, 0.0, "{c:?}");
    let s = out.report.detail::<scatterlab::solvers::dom::DomStats>().expect("dom's stats");
    let st = s.streaming.as_ref().expect("block sweeps");
    assert!(st.pool_slots < st.blocks && st.uploads > st.blocks as u64, "the blocks stream: {st:?}");
    assert_clean(&gpu);
}

/// `dom.evict=overlap` (auto's choice where the copies have a queue of their own) against
/// Belady's order (auto's where they share the sweeps' queue, as on lavapipe), the sphere's 512 blocks of 2^3
/// streamed through 36 slots: with Belady most loads evict a slot the sweeps submitted just
/// before use (their blocks are done until the next octant: the farthest next use), so those
/// copies cannot start before those sweeps end (5685 of 6892); with half-pool chunks and the
/// slots those sweeps use avoided, almost none (8 of 6321), in no more loads, and the image is
/// the same bits.
#[test]
fn overlap_eviction_frees_the_copies_from_the_sweep_before_them() {
    let gpu = gpu();
    let scene =
        crate::common::repo_scene("scenes/homogeneous-sphere.toml", &[("render.width", "16"), ("render.height", "16")]);
    let run = |evict: &'static str| {
        // One iteration: not converged, and warned so (try_render leaves the warning to us).
        let out = crate::common::try_render(
            &gpu,
            &scene,
            DOM,
            &[
                ("dom.grid", "16"),
                ("dom.block", "2"),
                ("dom.budget", "0.15"),
                ("dom.directions", "s4"),
                ("dom.max_iterations", "1"),
                ("dom.rays", "4096"),
                ("dom.evict", evict),
            ],
            false,
        )
        .expect("the render");
        assert_eq!(out.image.nan_inf_count(), 0, "{evict}: NaN/Inf in the image");
        let s = out.report.detail::<scatterlab::solvers::dom::DomStats>().expect("dom's stats");
        let st = s.streaming.expect("block sweeps");
        assert!(st.pool_slots * 4 < st.blocks, "{evict}: the blocks stream: {st:?}");
        (out.image, st)
    };
    let (belady_image, belady) = run("belady");
    let (overlap_image, overlap) = run("overlap");
    eprintln!(
        "belady: {} uploads, {} waiting for the sweep before them; overlap: {} uploads, {} waiting",
        belady.uploads, belady.serialised_loads, overlap.uploads, overlap.serialised_loads
    );
    assert!(belady.serialised_loads * 2 > belady.uploads, "Belady's copies mostly wait: {belady:?}");
    assert!(overlap.serialised_loads * 50 < overlap.uploads, "overlap's copies rarely wait: {overlap:?}");
    assert!(overlap.uploads <= belady.uploads, "no more loads: {overlap:?} against {belady:?}");
    assert!(overlap_image.data == belady_image.data, "the eviction order changes no bit of the image");
    assert_clean(&gpu);
}

/// The block sweep's loop budget on llvmpipe (an invocation's loops end silently past 65535
/// back-edges; `blocks::loop_iterations` counts them): a block of 16 at s8 lost 59% of the
/// image's energy. A set dom.block past the largest that fits is one line naming the knob and
/// that block, a non-zero exit and no image; auto's block is lowered to it (11 at s8), and the
/// blocked image is the plane sweeps' to float rounding (the two sum in different orders).
#[test]
fn block_sweeps_stay_within_the_loop_budget() {
    let dir = tempfile::tempdir().unwrap();
    let base = ["render.width=16", "render.height=16", "dom.grid=16", "dom.directions=s8", "dom.max_iterations=2"];
    let render = |sets: &[&str], out: &str| cube_cli(dir.path(), &base, sets, out);
    let large = render(&["dom.block=16"], "large.exr");
    let err = String::from_utf8_lossy(&large.stderr);
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error")).collect();
    assert!(!large.status.success() && lines.len() == 1, "{err}");
    assert!(lines[0].contains("dom.block") && lines[0].contains("dom.block=11 or less"), "{err}");
    assert!(!dir.path().join("large.exr").exists(), "no image after a refused block");

    let plane = render(&["dom.block=0"], "plane.exr");
    assert!(plane.status.success(), "{}", String::from_utf8_lossy(&plane.stderr));
    let auto = render(&["dom.budget=8"], "auto.exr");
    assert!(auto.status.success(), "{}", String::from_utf8_lossy(&auto.stderr));
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("auto.exr.json")).unwrap()).unwrap();
    assert_eq!(json.pointer("/stats/detail/block").and_then(|b| b.as_u64()), Some(11), "{json}");
    let image = |name: &str| scatterlab::output::read_exr(&dir.path().join(name)).unwrap();
    let m = scatterlab::output::compare(&image("auto.exr"), &image("plane.exr")).unwrap();
    assert!(m.rel_l2 < 1e-6, "blocks of 11 against the plane sweeps: relL2 {}", m.rel_l2);
}
