//! `scatterlab animate`: a light orbiting the medium, each frame warm started from the last
//! (networks and lbl), measured against the same frame converged.

use std::path::Path;
use std::process::Command;

use scatterlab::measure::animate::{self, FrameRow, Orbit};
use scatterlab::scene::Light;
use scatterlab::solvers::{Settings, Solver};

use crate::common::{assert_clean, gpu, render, repo_scene, LBL, NETWORKS};

fn sets(pairs: &[(&str, &str)]) -> Settings {
    Settings::new(&pairs.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect::<Vec<_>>())
}

fn run(solver: &dyn Solver, scene: &scatterlab::scene::Scene, knobs: &[(&str, &str)], frames: u32) -> Vec<FrameRow> {
    let gpu = gpu();
    let o = Orbit { first: 0, frames, step_deg: 10.0, reference: true };
    let rows = animate::run(&gpu, solver, scene, &sets(knobs), &o, &|_| {}, &mut |_, _, _| Ok(())).expect("sequence");
    assert_clean(&gpu);
    rows
}

/// The orbit turns a directional light's direction and a point light's position about +y
/// through the medium's centre, and refuses an environment.
#[test]
fn the_orbit_turns_the_first_light_about_the_vertical() {
    let cloud = repo_scene("scenes/cloud.toml", &[]);
    let turned = animate::orbit(&cloud, 90.0).unwrap();
    let (Light::Directional { direction: a, .. }, Light::Directional { direction: b, .. }) =
        (&cloud.lights[0], &turned.lights[0])
    else {
        panic!("the cloud's first light is the sun")
    };
    // +90 degrees about +y: (x, y, z) -> (z, y, -x).
    assert!((*b - glam::Vec3::new(a.z, a.y, -a.x)).length() < 1e-5, "{a} -> {b}");
    let lit = repo_scene("scenes/point-light-in-cloud.toml", &[("light.0.position", "[0.3, 0.1, 0.0]")]);
    let centre = (lit.medium.bounds_min + lit.medium.bounds_max) * 0.5;
    let Light::Point { position, .. } = animate::orbit(&lit, 180.0).unwrap().lights[0] else { panic!("a point light") };
    let want = glam::Vec3::new(2.0 * centre.x - 0.3, 0.1, 2.0 * centre.z);
    assert!((position - want).length() < 1e-5, "{position} against {want}");
    let sky_first = crate::common::scene(
        "[render]\nwidth = 8\nheight = 8\n[camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov = 20.0\n\
         [medium]\nbounds = [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]\nsigma_t = 2.0\nalbedo = 0.5\n\
         density = { kind = \"constant\" }\n[[light]]\nkind = \"environment\"\nradiance = 1.0\n",
    );
    let err = animate::orbit(&sky_first, 5.0).expect_err("an environment has nothing to orbit");
    assert!(err.contains("environment"), "{err}");
}

/// networks on the cloud (256 particles, 32 directions, 24 x 24), the sun turning 10 degrees a
/// frame: the first frame converges from zero and equals its reference exactly (deterministic);
/// every later frame runs exactly the per-frame iterations from the previous frame's radiance;
/// eight iterations a frame stay closer to the converged frames than one does (measured mean
/// relL2 over frames 1-3: 1 iteration 0.062, 8 iterations 0.013), and the energy stays within
/// 10% of the converged frame's.
#[test]
fn networks_frames_start_from_the_last_and_more_iterations_come_closer() {
    let cloud = repo_scene("scenes/cloud.toml", &[("render.width", "24"), ("render.height", "24")]);
    let base = [("networks.particles", "256"), ("networks.directions", "32")];
    let mut mean = Vec::new();
    for per_frame in ["1", "8"] {
        let mut knobs = base.to_vec();
        knobs.push(("networks.iterations_per_frame", per_frame));
        let rows = run(NETWORKS, &cloud, &knobs, 4);
        assert_eq!(rows.len(), 4);
        let first = &rows[0];
        assert!(first.converged && first.iterations > 8, "{first:?}");
        assert_eq!(first.rel_l2, Some(0.0), "the first frame is its own converged reference: {first:?}");
        assert_eq!(Some(first.iterations), first.reference_iterations);
        for r in &rows[1..] {
            assert_eq!(r.iterations, per_frame.parse::<u64>().unwrap(), "{r:?}");
            let e = r.energy_ratio.unwrap();
            assert!((0.9..1.1).contains(&e), "{r:?}");
            assert!(r.rel_l2.unwrap() > 0.0 && r.time_ms > 0.0, "{r:?}");
            assert!(r.reference_iterations.unwrap() < first.iterations, "the reference is warm started too: {r:?}");
        }
        let m = rows[1..].iter().map(|r| r.rel_l2.unwrap()).sum::<f64>() / 3.0;
        eprintln!("networks, {per_frame} iteration(s) a frame: mean relL2 {m:.4}");
        mean.push(m);
    }
    assert!(mean[1] < 0.5 * mean[0], "8 iterations a frame {} against 1: {}", mean[1], mean[0]);
}

/// A dense, bright 1^3 cube lit by a point light outside it, 16^2 pixels.
fn lit_cube() -> scatterlab::scene::Scene {
    crate::common::scene(
        "[render]\nwidth = 16\nheight = 16\nseed = 1\n\
         [camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov = 20.0\n\
         [medium]\nbounds = [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]\nsigma_t = 6.0\nalbedo = 0.95\n\
         density = { kind = \"constant\" }\n\
         [[light]]\nkind = \"point\"\nposition = [1.0, 1.0, 1.0]\nintensity = 10.0\n",
    )
}

/// lbl on a small cube (grid 12), the point light outside turning 10 degrees: started from the
/// previous frame's field, the second frame's lattice reaches the tolerance in fewer iterations
/// than the same frame from zero, and to the same image, both with the geometric tail
/// extrapolated (the default: the sums of the increments' magnitudes decay from the previous
/// field too) and without it (both stop on the plain change; measured 129 iterations against
/// 152).
#[test]
fn lbl_frames_start_from_the_previous_lattice() {
    let cube = lit_cube();
    for extrapolate in ["true", "false"] {
        let knobs = [("lbl.grid", "12"), ("lbl.extrapolate", extrapolate), ("lbl.deterministic", "true")];
        let rows = run(LBL, &cube, &knobs, 2);
        let gpu = gpu();
        let second = animate::orbit(&cube, 10.0).unwrap();
        let kv: Vec<(&str, &str)> = knobs.to_vec();
        let cold = render(&gpu, &second, LBL, &kv);
        let cold_iterations = cold.report.stats.convergence.unwrap().iterations;
        eprintln!(
            "lbl (extrapolate {extrapolate}): frame 1 from the last {} iterations, from zero {cold_iterations}",
            rows[1].iterations
        );
        assert!(rows[1].converged, "{:?}", rows[1]);
        assert!(rows[1].iterations < cold_iterations, "warm {} against cold {cold_iterations}", rows[1].iterations);
        // Without lbl.iterations_per_frame every frame iterates to the tolerance, so the sequence
        // is its own reference.
        assert!(rows[1].rel_l2.unwrap() < 1e-6, "{:?}", rows[1]);
        let m = scatterlab::output::compare(&render_frame(&gpu, &cube, &knobs, 10.0), &cold.image).unwrap();
        eprintln!("lbl (extrapolate {extrapolate}): warm against cold frame relL2 {:.2e}", m.rel_l2);
        assert!(m.rel_l2 < 5e-3, "warm and cold frames differ by relL2 {}", m.rel_l2);
        assert!((m.energy_ratio - 1.0).abs() < 5e-3, "warm against cold energy {}", m.energy_ratio);
        assert_clean(&gpu);
    }
}

/// From the third frame on an lbl frame's guess also holds the source the previous frame
/// injected (`start` in src/solvers/lbl/mod.rs: the residual is then s_new - s_old, not
/// s_new - M s_old), on the links' own time integrals: frames 2 and 3 take no more iterations
/// than frame 1, and frame 3 is the cold render of its light (relL2 3.5e-5). Measured on the
/// 12^3 cube, 10 degrees a frame: 72 / 65 / 65 / 57.
#[test]
fn lbl_frames_after_the_second_start_from_the_previous_source_too() {
    let cube = lit_cube();
    let knobs = [("lbl.grid", "12"), ("lbl.deterministic", "true")];
    let rows = run(LBL, &cube, &knobs, 4);
    let its: Vec<u64> = rows.iter().map(|r| r.iterations).collect();
    eprintln!("lbl: iterations per frame {its:?}");
    assert!(rows.iter().all(|r| r.converged), "{rows:?}");
    assert!(its[2] <= its[1] && its[3] <= its[1], "{its:?}");
    let gpu = gpu();
    let kv: Vec<(&str, &str)> = knobs.to_vec();
    let cold = render(&gpu, &animate::orbit(&cube, 30.0).unwrap(), LBL, &kv);
    let m = scatterlab::output::compare(&sequence_frame(&gpu, &cube, &knobs, 10.0, 4), &cold.image).unwrap();
    eprintln!("lbl: frame 3 against its cold render relL2 {:.2e}, energy {:.6}", m.rel_l2, m.energy_ratio);
    assert!(m.rel_l2 < 5e-3, "frame 3 and its cold render differ by relL2 {}", m.rel_l2);
    assert!((m.energy_ratio - 1.0).abs() < 5e-3, "frame 3 against cold energy {}", m.energy_ratio);
    assert_clean(&gpu);
}

/// Frame `deg`'s image of an lbl sequence started at 0 degrees (two frames).
fn render_frame(
    gpu: &scatterlab::gpu::Gpu,
    scene: &scatterlab::scene::Scene,
    knobs: &[(&str, &str)],
    deg: f64,
) -> scatterlab::output::Image {
    sequence_frame(gpu, scene, knobs, deg, 2)
}

/// The last image of an lbl sequence of `frames` frames, `deg` degrees apart, from 0 degrees.
fn sequence_frame(
    gpu: &scatterlab::gpu::Gpu,
    scene: &scatterlab::scene::Scene,
    knobs: &[(&str, &str)],
    deg: f64,
    frames: u32,
) -> scatterlab::output::Image {
    let o = Orbit { first: 0, frames, step_deg: deg, reference: false };
    let mut last = None;
    animate::run(gpu, LBL, scene, &sets(knobs), &o, &|_| {}, &mut |img, _, _| {
        last = Some(img.clone());
        Ok(())
    })
    .expect("sequence");
    last.unwrap()
}

fn bin(dir: &Path, args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_scatterlab"))
        .args(args)
        .current_dir(dir)
        .env_remove("SCATTERLAB_DEVICE")
        .env("NO_COLOR", "1")
        .output()
        .expect("run scatterlab")
}

/// The command end to end: frames and frames.csv written, one row per frame; a solver
/// without a warm start, an environment to orbit and zero frames are one line of error each,
/// before anything is written.
#[test]
fn animate_writes_frames_and_a_csv_and_refuses_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/cloud.toml");
    // networks on the cloud, the light turning 15 degrees a frame, at a test's size.
    let orbit = |extra: &[&str]| {
        let mut args = vec!["animate", scene, "--solver", "networks", "--orbit-light", "15"];
        args.extend_from_slice(extra);
        for set in ["render.width=16", "render.height=16", "networks.particles=128", "networks.directions=16"] {
            args.extend(["--set", set]);
        }
        bin(dir.path(), &args)
    };
    let out = orbit(&["--frames", "2", "--out-dir", "seq", "--png", "--validate"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    // stderr is a pipe: no progress bar, and no plain progress line within 30 s (the default).
    assert!(!stderr.contains("progress:"), "{stderr}");
    for f in ["frame-0000.exr", "frame-0001.exr", "frame-0000.png", "frame-0001.png", "frames.csv"] {
        assert!(dir.path().join("seq").join(f).is_file(), "{f} missing; stderr:\n{stderr}");
    }
    let mut csv = csv::Reader::from_path(dir.path().join("seq/frames.csv")).unwrap();
    let rows: Vec<csv::StringRecord> = csv.records().map(|r| r.unwrap()).collect();
    assert_eq!(rows.len(), 2);
    let h = csv.headers().unwrap().clone();
    let col = |name: &str| h.iter().position(|x| x == name).unwrap_or_else(|| panic!("no column {name}"));
    assert_eq!(&rows[1][col("angle_deg")], "15.0");
    assert_eq!(&rows[1][col("iterations")], "1");
    assert!(rows[1][col("rel_l2")].parse::<f64>().unwrap() > 0.0);
    let img = scatterlab::output::read_exr(&dir.path().join("seq/frame-0001.exr")).unwrap();
    assert_eq!((img.width, img.height), (16, 16));

    // With --progress-every 0 the iterations within a frame show where no terminal is.
    let out = orbit(&["--frames", "1", "--no-reference", "--out-dir", "seq-progress", "--progress-every", "0"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    assert!(
        stderr
            .lines()
            .any(|l| l.starts_with("progress: networks ") && l.contains("iteration") && l.contains("tolerance")),
        "{stderr}"
    );

    let sky = dir.path().join("sky.toml");
    std::fs::write(
        &sky,
        "[render]\nwidth = 8\nheight = 8\n[camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov = 20.0\n\
         [medium]\nbounds = [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]\nsigma_t = 2.0\nalbedo = 0.5\n\
         density = { kind = \"constant\" }\n[[light]]\nkind = \"environment\"\nradiance = 1.0\n",
    )
    .unwrap();
    let cases: [(&[&str], &[&str]); 2] = [
        (&[scene, "--solver", "path", "--out-dir", "x"], &["--solver path", "animate takes"]),
        (&["sky.toml", "--solver", "networks", "--out-dir", "x"], &["sky.toml", "environment"]),
    ];
    for (args, needles) in cases {
        let mut all = vec!["animate"];
        all.extend_from_slice(args);
        let out = bin(dir.path(), &all);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.code().is_some_and(|c| c != 0 && c != 101), "{args:?}: {stderr}");
        let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
        assert_eq!(lines.len(), 1, "{args:?}: {stderr}");
        assert!(needles.iter().all(|n| lines[0].contains(n)), "{args:?}: {}", lines[0]);
        assert!(!dir.path().join("x").exists(), "{args:?}: nothing written");
    }
    // A usage error: clap's message and usage, exit code 2.
    let out = bin(dir.path(), &["animate", scene, "--solver", "networks", "--frames", "0", "--out-dir", "x"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--frames"));
    assert!(!dir.path().join("x").exists());
}

/// The last image and the rows of `solver`'s sequence of `frames` frames, `deg` degrees apart.
fn sequence_of(
    gpu: &scatterlab::gpu::Gpu,
    solver: &dyn Solver,
    scene: &scatterlab::scene::Scene,
    knobs: &[(&str, &str)],
    deg: f64,
    frames: u32,
) -> (scatterlab::output::Image, Vec<FrameRow>) {
    let o = Orbit { first: 0, frames, step_deg: deg, reference: false };
    let mut last = None;
    let rows = animate::run(gpu, solver, scene, &sets(knobs), &o, &|_| {}, &mut |img, _, _| {
        last = Some(img.clone());
        Ok(())
    })
    .expect("sequence");
    (last.unwrap(), rows)
}

/// A sphere of radius 0.48 in the unit box (16^2, seed 1) with `sigma_t`, `albedo`, `g` and
/// the light tables `lights`: the media of dom's warm-start tests.
fn sphere(sigma_t: &str, albedo: &str, g: &str, lights: &str) -> scatterlab::scene::Scene {
    crate::common::scene(&format!(
        "[render]\nwidth = 16\nheight = 16\nseed = 1\n\
         [camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov = 20.0\n\
         [medium]\nbounds = [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]\nsigma_t = {sigma_t}\nalbedo = {albedo}\ng = {g}\n\
         density = {{ kind = \"sphere\", center = [0.0, 0.0, 0.0], radius = 0.48 }}\n{lights}"
    ))
}

/// A sun and a blue sky.
const SUN_AND_SKY: &str = "[[light]]\nkind = \"directional\"\ndirection = [0.5, -0.7, 0.5]\nirradiance = 3.0\n\
     [[light]]\nkind = \"environment\"\nradiance = [0.03, 0.05, 0.09]\n";

/// A deep near-lossless cube (optical size 50, albedo 0.999, voxels of 4 mean free paths:
/// warned), lit by a sun: turned 30 degrees a frame, the signed bounces' sum cancels there, and
/// a decay taken from it (not from their magnitudes) put the frames 0.5% above the cold render.
fn deep_cube() -> scatterlab::scene::Scene {
    crate::common::scene(
        "[render]\nwidth = 16\nheight = 16\n\
         [camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov = 20.0\n\
         [medium]\nbounds = [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]\nsigma_t = 50.0\nalbedo = 0.999\n\
         density = { kind = \"constant\" }\n\
         [[light]]\nkind = \"directional\"\ndirection = [-0.57735, -0.57735, -0.57735]\nirradiance = 3.0\n",
    )
}

/// The deep cube's knobs: a coarse grid, s4, iterations enough for albedo 0.999.
const DEEP_KNOBS: [(&str, &str); 3] = [("dom.grid", "12"), ("dom.directions", "s4"), ("dom.max_iterations", "4000")];

/// dom's warm start with the convergence test on the host (a device without double precision,
/// as `--without-float64` opens it): the host keeps the bounces' summed fluence, the device its
/// pending source and light toward the camera, and the test takes the same magnitudes as
/// converge.comp. Its frames stop at the same iterations as the device test's and give the same
/// images (which `dom_frames_go_on_from_the_last_state` holds to their cold renders), with no
/// "starts from zero" warning. Measured (lavapipe, 16^2): the bright cube 21 / 13 / 14, the
/// chromatic forward medium 9 / 7 / 7, the deep cube 218 / 105 / 87 iterations both ways, images
/// bit for bit (relL2 0).
#[test]
fn dom_frames_go_on_without_double_precision() {
    let dom: &dyn Solver = &scatterlab::solvers::dom::Dom;
    let device = gpu();
    let host = crate::common::gpu_without_float64();
    assert!(device.info().float64 && !host.info().float64);
    type Case<'a> = (&'a str, scatterlab::scene::Scene, &'a [(&'a str, &'a str)], f64);
    let cases: [Case; 3] = [
        ("bright cube", lit_cube(), &[("dom.grid", "12")], 10.0),
        (
            "chromatic, forward",
            sphere("[2.0, 3.0, 4.0]", "[0.9, 0.8, 0.5]", "0.8", SUN_AND_SKY),
            &[("dom.grid", "12")],
            10.0,
        ),
        ("deep, near lossless", deep_cube(), &DEEP_KNOBS, 30.0),
    ];
    for (name, scene, knobs, deg) in &cases {
        let mut runs = Vec::new();
        for gpu in [&device, &host] {
            let o = Orbit { first: 0, frames: 3, step_deg: *deg, reference: false };
            let (mut last, mut warnings) = (None, Vec::new());
            let rows = animate::run(gpu, dom, scene, &sets(knobs), &o, &|_| {}, &mut |img, out, _| {
                last = Some(img.clone());
                warnings.extend(out.report.warnings.iter().cloned());
                Ok(())
            })
            .expect("sequence");
            assert!(warnings.iter().all(|w| !w.contains("starts from zero")), "{name}: {warnings:?}");
            let its: Vec<u64> = rows.iter().map(|r| r.iterations).collect();
            runs.push((its, last.unwrap()));
        }
        let m = scatterlab::output::compare(&runs[0].1, &runs[1].1).unwrap();
        eprintln!(
            "dom {name}: iterations per frame, test on the device {:?}, on the host {:?}; last frames relL2 {:.2e}, \
             energy {:.8}",
            runs[0].0, runs[1].0, m.rel_l2, m.energy_ratio
        );
        assert_eq!(runs[0].0, runs[1].0, "{name}: the host test stopped elsewhere");
        assert!(runs[1].0[1..].iter().all(|i| *i < runs[1].0[0]), "{name}: no warm start on the host: {:?}", runs[1].0);
        assert!(m.rel_l2 < 1e-5 && (m.energy_ratio - 1.0).abs() < 1e-5, "{name}: {m:?}");
    }
    assert_clean(&device);
    assert_clean(&host);
}

/// dom's frames go on from the last frame's state (`DomCarry`: the bounce series of the change
/// of the first-scattering source plus the last frame's pending bounce, by linearity), the light
/// turning 10 degrees a frame. Across the range: a thin backward-scattering medium (optical
/// size 1, albedo 0.3, g -0.5), the bright cube (6, 0.95, a point light), a thick near-lossless
/// sphere (8, 0.999), a chromatic forward-scattering one (2-4, albedo 0.5-0.9, g 0.8, the sun
/// and a sky) and a deep near-lossless cube (50, 0.999, 30 degrees a frame). Every frame after
/// the first takes fewer iterations than the same light from zero (the cold render), and the
/// last frame equals that cold render within the tolerance's reach, energy included. Measured
/// (lavapipe, grid 12-16, 16^2), iterations of frames 0 / 1 / 2 and frame 2's light from zero:
/// 5 / 4 / 4 and 5, 21 / 13 / 14 and 21, 27 / 16 / 13 and 27, 9 / 7 / 7 and 9, 218 / 105 / 87
/// and 210; relL2 of frame 2 to its cold render 8.2e-7, 2.5e-4, 2.0e-4, 1.2e-5 (the deep cube
/// against the converged solution below). With `dom.iterations_per_frame` a frame stops at its
/// budget (tests/view_tests.rs has the frames after it converging to the render).
#[test]
fn dom_frames_go_on_from_the_last_state() {
    let dom: &dyn Solver = &scatterlab::solvers::dom::Dom;
    let point = "[[light]]\nkind = \"point\"\nposition = [1.0, 1.0, 1.0]\nintensity = 10.0\n";
    let (deep, deep_knobs) = (deep_cube(), DEEP_KNOBS);
    // (name, scene, knobs, the warnings its cold render gives, degrees a frame)
    type Case<'a> = (&'a str, scatterlab::scene::Scene, &'a [(&'a str, &'a str)], &'a [&'a str], f64);
    let cases: [Case; 5] = [
        ("thin, backward", sphere("1.0", "0.3", "-0.5", point), &[("dom.grid", "12")], &[], 10.0),
        ("bright cube", lit_cube(), &[("dom.grid", "12")], &[], 10.0),
        ("thick, near lossless", sphere("8.0", "0.999", "0.0", point), &[("dom.grid", "16")], &[], 10.0),
        (
            "chromatic, forward",
            sphere("[2.0, 3.0, 4.0]", "[0.9, 0.8, 0.5]", "0.8", SUN_AND_SKY),
            &[("dom.grid", "12")],
            &[],
            10.0,
        ),
        ("deep, near lossless", deep, &deep_knobs, &["mean free paths thick"], 30.0),
    ];
    let gpu = gpu();
    for (name, scene, knobs, warned, deg) in &cases {
        let (image, rows) = sequence_of(&gpu, dom, scene, knobs, *deg, 3);
        let last = animate::orbit(scene, 2.0 * deg).unwrap();
        let cold = if warned.is_empty() {
            render(&gpu, &last, dom, knobs)
        } else {
            crate::common::render_warned(&gpu, &last, dom, knobs, warned)
        };
        let cold_iterations = cold.report.stats.convergence.unwrap().iterations;
        let m = scatterlab::output::compare(&image, &cold.image).unwrap();
        let its: Vec<u64> = rows.iter().map(|r| r.iterations).collect();
        eprintln!(
            "dom {name}: iterations per frame {its:?}, the last from zero {cold_iterations}; last frame against its \
             cold render relL2 {:.2e}, energy {:.6}",
            m.rel_l2, m.energy_ratio
        );
        assert!(rows.iter().all(|r| r.converged), "{name}: {rows:?}");
        assert!(its[1..].iter().all(|i| *i < cold_iterations), "{name}: {its:?} against {cold_iterations} from zero");
        assert!(image.data.iter().all(|v| v.is_finite() && *v >= 0.0), "{name}: a negative or non-finite pixel");
        if warned.is_empty() {
            assert!(m.rel_l2 < 2e-3, "{name}: the last frame against its cold render: relL2 {}", m.rel_l2);
            assert!((m.energy_ratio - 1.0).abs() < 2e-3, "{name}: energy {}", m.energy_ratio);
            continue;
        }
        // The deep cube's cold render is itself 2.5e-3 off the converged solution (its tail at
        // albedo 0.999): both are judged against the plain iteration to 1e-9 (warm 1.2e-3,
        // energy 0.9985; cold 2.5e-3, 0.9988; the signed-sum decay had the warm frame 0.45% over).
        let mut tight = knobs.to_vec();
        tight.extend([("dom.tol", "1e-9"), ("dom.extrapolate", "false"), ("dom.max_iterations", "100000")]);
        let truth = crate::common::render_warned(&gpu, &last, dom, &tight, warned);
        for (what, img) in [("warm", &image), ("cold", &cold.image)] {
            let m = scatterlab::output::compare(img, &truth.image).unwrap();
            eprintln!("dom {name}: {what} against converged relL2 {:.2e}, energy {:.6}", m.rel_l2, m.energy_ratio);
            assert!(m.rel_l2 < 3e-3, "{name}, {what}: against converged relL2 {}", m.rel_l2);
            assert!((m.energy_ratio - 1.0).abs() < 3e-3, "{name}, {what}: energy {}", m.energy_ratio);
        }
    }
    // A budget of 3 iterations a frame: the frames after the first stop at it, short of the
    // tolerance.
    let scene = &cases[1].1;
    let knobs = [("dom.grid", "12"), ("dom.iterations_per_frame", "3")];
    let (_, rows) = sequence_of(&gpu, dom, scene, &knobs, 10.0, 3);
    assert!(rows[1..].iter().all(|r| r.iterations == 3 && !r.converged), "{rows:?}");
    assert_clean(&gpu);
}
