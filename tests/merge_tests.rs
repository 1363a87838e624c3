//! Sample ranges and `scatterlab merge`: renders of disjoint ranges of sample indices merged
//! equal the render of their union (mean to float summation order, and the variance layer that
//! render computes, by Chan et al.'s pooled sums of squared deviations, not an average of
//! variances); a merge that would mix renders of different scenes, knobs or overlapping ranges
//! is refused with one line and writes nothing. Every render runs with `--validate`.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use scatterlab::output::{read_exr_layer, read_exr_metadata, Image};

const BIN: &str = env!("CARGO_BIN_EXE_scatterlab");

fn repo(rel: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel).display().to_string()
}

fn run(args: &[&str]) -> Output {
    Command::new(BIN).args(args).output().expect("the scatterlab binary runs")
}

fn ok(args: &[&str]) -> Output {
    let out = run(args);
    assert!(out.status.success(), "scatterlab {} failed:\n{}", args.join(" "), String::from_utf8_lossy(&out.stderr));
    out
}

/// `render SCENE --samples RANGE` at `size`^2 with `extra`, to `out`.
fn render(scene: &str, range: &str, size: u32, extra: &[&str], out: &Path) {
    let (w, h) = (format!("render.width={size}"), format!("render.height={size}"));
    let mut args = vec!["render", scene, "--validate", "-q", "--samples", range, "--set", &w, "--set", &h];
    args.extend_from_slice(extra);
    let o = out.to_str().unwrap();
    args.extend_from_slice(&["--out", o]);
    ok(&args);
}

/// The one line of a refused command, which must exit 1 (not 2: a clap usage error; not 101: a
/// panic) and leave `dir` as it was.
fn refused(args: &[&str], dir: &Path) -> String {
    let before = listing(dir);
    let out = run(args);
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(out.status.code(), Some(1), "scatterlab {} exit {:?}: {err}", args.join(" "), out.status.code());
    assert_eq!(err.trim().lines().count(), 1, "not one line: {err}");
    assert!(err.starts_with("error: ") && !err.contains("panicked"), "{err}");
    assert_eq!(listing(dir), before, "a refused merge left files behind: {err}");
    err
}

fn listing(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).collect();
    v.sort();
    v
}

/// The worst per-value relative difference of `a` from `b`, where b's value is above `floor`
/// (and the worst absolute difference below it).
fn worst_relative(a: &Image, b: &Image, floor: f32) -> (f64, f64) {
    assert_eq!((a.width, a.height), (b.width, b.height));
    let (mut rel, mut abs) = (0f64, 0f64);
    for (x, y) in a.data.iter().zip(&b.data) {
        let d = (x - y).abs() as f64;
        if y.abs() > floor {
            rel = rel.max(d / y.abs() as f64);
        } else {
            abs = abs.max(d);
        }
    }
    (rel, abs)
}

/// The worst relative difference of the merged variance of the mean `vm` from the union
/// render's `vu`, over values above 1e-6 of the layer's largest (the rest measured against that
/// floor). The union forms its variance from each pixel's f32 sum of squared deviations (M2,
/// glsl/path/trace.comp, add_samples), which keeps the variance's own relative precision even
/// where a pixel's samples nearly agree.
fn variance_agreement(vm: &Image, vu: &Image) -> f64 {
    let peak = vu.data.iter().cloned().fold(0f32, f32::max) as f64;
    assert!(peak > 0.0, "the variance layer is all zero: nothing tested");
    let mut worst = 0f64;
    for (a, b) in vm.data.iter().zip(&vu.data) {
        let (a, b) = (*a as f64, *b as f64);
        let d = (a - b).abs();
        worst = worst.max(if b > 1e-6 * peak { d / b } else { d / (1e-6 * peak) });
    }
    worst
}

fn header(p: &Path, key: &str) -> Option<String> {
    read_exr_metadata(p).unwrap().into_iter().find(|(k, _)| k == &format!("scatterlab.{key}")).map(|(_, v)| v)
}

/// Four ranges of `scene` merged against one render of their union: the mean within 1e-6 per
/// value and the variance layer within 1e-5 (relative, where the value is above 1e-6 of the
/// image's largest; the rest within that floor absolutely), and the same provenance.
fn four_ranges_merge_exactly(scene: &str, size: u32, ranges: [&str; 4], union: &str, extra: &[&str], tmp: &Path) {
    let parts: Vec<PathBuf> = (0..4).map(|i| tmp.join(format!("part{i}.exr"))).collect();
    for (r, p) in ranges.iter().zip(&parts) {
        render(scene, r, size, extra, p);
    }
    let all = tmp.join("all.exr");
    render(scene, union, size, extra, &all);
    let merged = tmp.join("merged.exr");
    // Given out of order: the merge sorts by range.
    let mut args = vec!["merge", "-q", merged.to_str().unwrap()];
    args.extend(parts.iter().rev().map(|p| p.to_str().unwrap()));
    ok(&args);
    let spp: f32 = {
        let (a, b) = union.split_once("..").unwrap();
        (b.parse::<u32>().unwrap() - a.parse::<u32>().unwrap()) as f32
    };
    let (m, u) = (read_exr_layer(&merged, "").unwrap(), read_exr_layer(&all, "").unwrap());
    let peak = u.data.iter().cloned().fold(0f32, f32::max);
    assert!(peak > 0.0, "{scene}: the image is all zero: nothing tested");
    let (rel, abs) = worst_relative(&m, &u, 1e-6 * peak);
    eprintln!("{scene} mean: worst relative {rel:.2e}, below the floor {abs:.2e}");
    assert!(rel <= 1e-6 && abs <= 1e-6 * peak as f64, "{scene} mean: worst relative {rel:.3e}, abs {abs:.3e}");
    let (vm, vu) = (read_exr_layer(&merged, "variance").unwrap(), read_exr_layer(&all, "variance").unwrap());
    let worst = variance_agreement(&vm, &vu);
    eprintln!("{scene} variance: worst relative {worst:.2e}");
    assert!(worst <= 1e-5, "{scene} variance: {worst:.3e} relative");
    let n = read_exr_layer(&merged, "samples").unwrap();
    assert!(n.data.iter().all(|&c| c == spp), "sample count layer is not {spp}");
    assert_eq!(header(&merged, "samples").as_deref(), Some(union));
    assert_eq!(header(&merged, "spp"), header(&all, "spp"));
    assert_eq!(header(&merged, "estimators"), header(&all, "estimators"));
    assert_eq!(header(&merged, "scene_hash"), header(&all, "scene_hash"));
    let reproduce = header(&merged, "reproduce").unwrap();
    assert!(reproduce.contains(&format!("--samples {union}")), "{reproduce}");
    let listed = header(&merged, "merged").unwrap();
    assert_eq!(listed.lines().count(), 4, "{listed}");
}

#[test]
fn four_sample_ranges_merge_into_the_render_of_their_union_on_the_sphere_and_the_cloud() {
    let tmp = tempfile::tempdir().unwrap();
    four_ranges_merge_exactly(
        &repo("scenes/homogeneous-sphere.toml"),
        24,
        ["0..16", "16..32", "32..40", "40..64"],
        "0..64",
        &[],
        tmp.path(),
    );
    // The cloud, from a range not starting at 0 (samples 8..40 of a render of 0..40).
    four_ranges_merge_exactly(
        &repo("scenes/cloud.toml"),
        20,
        ["8..16", "16..24", "24..32", "32..40"],
        "8..40",
        &["--set", "path.max_depth=8"],
        tmp.path(),
    );
}

/// Camera paths for the sun and sky, light paths (in batches) for the lightning's core light:
/// each estimator merges on its own, and with batches of one size the union render with as
/// many batches has the same batches: the same image and variance.
#[test]
fn camera_and_light_paths_merge_each_by_its_own_units() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = repo("scenes/lightning-at-dusk.toml");
    let parts: Vec<PathBuf> = (0..4).map(|i| tmp.path().join(format!("p{i}.exr"))).collect();
    for (i, p) in parts.iter().enumerate() {
        let r = format!("{}..{}", 8 * i, 8 * (i + 1));
        render(&scene, &r, 16, &["--set", "path.light_batches=2"], p);
    }
    assert_eq!(header(&parts[0], "estimators").as_deref(), Some("camera:8 light:2"), "the scene is not mixed");
    let all = tmp.path().join("all.exr");
    render(&scene, "0..32", 16, &["--set", "path.light_batches=8"], &all);
    let merged = tmp.path().join("merged.exr");
    let mut args = vec!["merge", "-q", merged.to_str().unwrap()];
    args.extend(parts.iter().map(|p| p.to_str().unwrap()));
    ok(&args);
    for (layer, limit) in [("", 1e-6), ("variance", 1e-5), ("camera", 1e-6), ("light", 1e-6), ("light_variance", 1e-5)]
    {
        let (m, u) = (read_exr_layer(&merged, layer).unwrap(), read_exr_layer(&all, layer).unwrap());
        let peak = u.data.iter().cloned().fold(0f32, f32::max);
        assert!(peak > 0.0, "layer {layer:?} is all zero");
        let (rel, abs) = worst_relative(&m, &u, 1e-6 * peak);
        eprintln!("lightning {layer:?}: worst relative {rel:.2e}, abs below floor {abs:.2e}");
        assert!(rel <= limit && abs <= 1e-6 * peak as f64, "layer {layer:?}: {rel:.3e} / {abs:.3e}");
    }
    let reproduce = header(&merged, "reproduce").unwrap();
    assert!(reproduce.contains("--set path.light_batches=8"), "{reproduce}");
    assert_eq!(header(&merged, "estimators").as_deref(), Some("camera:32 light:8"));
}

#[test]
fn a_merge_of_one_render_is_that_render() {
    let tmp = tempfile::tempdir().unwrap();
    let one = tmp.path().join("one.exr");
    render(&repo("scenes/homogeneous-sphere.toml"), "4..12", 16, &[], &one);
    let merged = tmp.path().join("merged.exr");
    ok(&["merge", "-q", merged.to_str().unwrap(), one.to_str().unwrap()]);
    for layer in ["", "variance", "samples"] {
        let (a, b) = (read_exr_layer(&merged, layer).unwrap(), read_exr_layer(&one, layer).unwrap());
        assert_eq!(a.data, b.data, "layer {layer:?} changed");
    }
    assert_eq!(header(&merged, "samples").as_deref(), Some("4..12"));
}

#[test]
fn merges_that_would_mix_renders_are_refused_with_one_line_and_write_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let sphere = repo("scenes/homogeneous-sphere.toml");
    let p = |n: &str| d.join(n).display().to_string();
    render(&sphere, "0..4", 8, &[], &d.join("a.exr"));
    render(&sphere, "4..8", 8, &[], &d.join("b.exr"));
    render(&sphere, "2..6", 8, &[], &d.join("overlap.exr"));
    render(&sphere, "8..12", 8, &["--set", "path.max_depth=2"], &d.join("knob.exr"));
    render(&sphere, "8..12", 8, &["--set", "medium.albedo=0.5"], &d.join("albedo.exr"));
    render(&repo("scenes/thick-slab.toml"), "8..12", 8, &[], &d.join("other.exr"));
    render(&sphere, "8..12", 8, &["--seed", "9"], &d.join("seed.exr"));
    let out = d.join("single.exr");
    ok(&[
        "render",
        &sphere,
        "--validate",
        "-q",
        "--solver",
        "single",
        "--set",
        "render.width=8",
        "--set",
        "render.height=8",
        "--out",
        out.to_str().unwrap(),
    ]);
    // A truncated copy of a good render.
    let bytes = std::fs::read(d.join("b.exr")).unwrap();
    std::fs::write(d.join("truncated.exr"), &bytes[..bytes.len() / 2]).unwrap();
    let m = p("m.exr");
    let cases: [(&str, &str, &[&str]); 8] = [
        ("overlap", "overlap in samples 2..4", &["a.exr", "overlap.exr"]),
        ("knobs", "differ in overrides", &["a.exr", "knob.exr"]),
        ("scene override", "differ in overrides", &["a.exr", "albedo.exr"]),
        ("scene hash", "differ in scene_hash", &["a.exr", "other.exr"]),
        ("seed", "differ in seed", &["a.exr", "seed.exr"]),
        ("no samples", "without samples", &["a.exr", "single.exr"]),
        ("truncated", "truncated.exr", &["a.exr", "truncated.exr"]),
        ("missing", "no such file", &["a.exr", "missing.exr"]),
    ];
    for (what, needle, inputs) in cases {
        let files: Vec<String> = inputs.iter().map(|i| p(i)).collect();
        let mut args = vec!["merge", m.as_str()];
        args.extend(files.iter().map(String::as_str));
        let err = refused(&args, d);
        assert!(err.contains(needle), "{what}: {err}");
        // Names both files where two disagree.
        if !["truncated", "missing", "no samples"].contains(&what) {
            assert!(err.contains(&files[0]) && err.contains(&files[1]), "{what} does not name both files: {err}");
        }
    }
    // The output may not be an input.
    let err = refused(&["merge", &p("a.exr"), &p("a.exr"), &p("b.exr")], d);
    assert!(err.contains("also an input"), "{err}");
    // And the good pair merges.
    ok(&["merge", "-q", &m, &p("a.exr"), &p("b.exr")]);
}

#[test]
fn sample_ranges_are_checked_and_recorded() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let sphere = repo("scenes/homogeneous-sphere.toml");
    let out = d.join("x.exr").display().to_string();
    let base = ["render", sphere.as_str(), "--validate", "-q", "--set", "render.width=8", "--set", "render.height=8"];
    for (range, needle) in
        [("5..5", "is empty"), ("9..3", "is empty"), ("a..4", "not an integer"), ("4", "not a range")]
    {
        let args = [&base[..], &["--samples", range, "--out", &out]].concat();
        let err = refused(&args, d);
        assert!(err.contains("--samples") && err.contains(needle), "{range}: {err}");
    }
    let args = [&base[..], &["--solver", "single", "--samples", "0..4", "--out", &out]].concat();
    assert!(refused(&args, d).contains("solvers that sample pixels"));
    // 2^32 - 1 is the last index: a range past it is the scene key's error.
    let args = [&base[..], &["--samples", "4294967290..4294967295", "--out", &out]].concat();
    ok(&args);
    assert_eq!(header(Path::new(&out), "samples").as_deref(), Some("4294967290..4294967295"));
    assert_eq!(header(Path::new(&out), "spp").as_deref(), Some("5"));
    let args = [&base[..], &["--set", "render.first_sample=4294967295", "--out", &out]].concat();
    std::fs::remove_file(&out).unwrap();
    assert!(refused(&args, d).contains("render.first_sample"));
    // --spp and --samples are one thing said twice.
    let conflict = run(&[&base[..], &["--spp", "4", "--samples", "0..4", "--out", &out]].concat());
    assert_eq!(conflict.status.code(), Some(2), "clap refuses the pair");
}

/// The samples of a range are those of the union render: 0..8 as two ranges equals 0..8 in
/// one render, and a range from A differs from one from 0 (different samples).
#[test]
fn a_range_renders_its_own_sample_indices() {
    let tmp = tempfile::tempdir().unwrap();
    let sphere = repo("scenes/homogeneous-sphere.toml");
    let (a, b) = (tmp.path().join("a.exr"), tmp.path().join("b.exr"));
    render(&sphere, "0..8", 12, &[], &a);
    render(&sphere, "8..16", 12, &[], &b);
    let (ia, ib) = (read_exr_layer(&a, "").unwrap(), read_exr_layer(&b, "").unwrap());
    assert_ne!(ia.data, ib.data, "ranges 0..8 and 8..16 gave the same image: the range is ignored");
    // --spp 8 is --samples 0..8, bit for bit.
    let c = tmp.path().join("c.exr");
    ok(&[
        "render",
        &sphere,
        "--validate",
        "-q",
        "--spp",
        "8",
        "--set",
        "render.width=12",
        "--set",
        "render.height=12",
        "--out",
        c.to_str().unwrap(),
    ]);
    assert_eq!(read_exr_layer(&c, "").unwrap().data, ia.data);
    assert_eq!(header(&c, "samples").as_deref(), Some("0..8"));
}

/// `--device uuid:` with the device's own UUID (from `scatterlab devices --json`) picks it; an
/// unknown one is one line listing the devices with their UUIDs.
#[test]
fn a_device_is_chosen_by_its_uuid() {
    let out = ok(&["devices", "--json"]);
    let list: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let first = &list[0];
    let (name, uuid) = (first["name"].as_str().unwrap(), first["uuid"].as_str().unwrap());
    assert!(uuid.starts_with("GPU-") && uuid.len() == 40, "{uuid}");
    let tmp = tempfile::tempdir().unwrap();
    let img = tmp.path().join("x.exr");
    let sphere = repo("scenes/homogeneous-sphere.toml");
    for wanted in [format!("uuid:{uuid}"), format!("uuid:{}", &uuid[..12].to_uppercase())] {
        let r = ok(&[
            "render",
            &sphere,
            "--validate",
            "--device",
            &wanted,
            "--spp",
            "1",
            "--set",
            "render.width=4",
            "--set",
            "render.height=4",
            "--out",
            img.to_str().unwrap(),
        ]);
        assert!(
            String::from_utf8_lossy(&r.stderr).contains(&format!("device: {name}")),
            "{wanted} did not pick {name}"
        );
    }
    let err = refused(
        &["render", &sphere, "--device", "uuid:GPU-00000000-dead", "--spp", "1", "--out", img.to_str().unwrap()],
        tmp.path(),
    );
    assert!(err.contains("uuid:GPU-00000000-dead") && err.contains(uuid), "{err}");
}

/// `--device auto`: SCATTERLAB_DEVICE first, then CUDA_VISIBLE_DEVICES, SLURM_STEP_GPUS and
/// SLURM_JOB_GPUS (a UUID, or an index among the physical GPUs); a disagreement is named.
#[test]
fn auto_follows_the_environment_in_its_documented_order() {
    use scatterlab::gpu::{auto_device, DeviceSummary};
    let dev = |index: usize, kind: &str, uuid: &str| DeviceSummary {
        index,
        name: format!("device {index}"),
        uuid: uuid.into(),
        device_type: kind.into(),
        api_version: "1.3.0".into(),
        queue_families: Vec::new(),
        mapping: None,
        missing: Vec::new(),
    };
    let list = vec![
        dev(0, "cpu", "GPU-00000000-0000-0000-0000-000000000000"),
        dev(1, "discrete", "GPU-11111111-1111-1111-1111-111111111111"),
        dev(2, "discrete", "GPU-22222222-2222-2222-2222-222222222222"),
    ];
    let with = |pairs: &'static [(&'static str, &'static str)]| {
        move |k: &str| pairs.iter().find(|(key, _)| *key == k).map(|(_, v)| v.to_string())
    };
    assert_eq!(auto_device(&list, &with(&[])), (None, None));
    assert_eq!(
        auto_device(&list, &with(&[("SCATTERLAB_DEVICE", "2"), ("CUDA_VISIBLE_DEVICES", "0")])).0.as_deref(),
        Some("2")
    );
    // Indices count GPUs, not the CPU driver: CUDA's 1 is the second discrete device.
    assert_eq!(auto_device(&list, &with(&[("CUDA_VISIBLE_DEVICES", "1,0")])).0.as_deref(), Some("2"));
    assert_eq!(
        auto_device(&list, &with(&[("CUDA_VISIBLE_DEVICES", "GPU-22222222")])).0.as_deref(),
        Some("uuid:GPU-22222222")
    );
    // Slurm's node-wide index past the GPUs a constrained task sees: its own first GPU.
    assert_eq!(auto_device(&list, &with(&[("SLURM_STEP_GPUS", "5")])).0.as_deref(), Some("1"));
    let (w, note) = auto_device(&list, &with(&[("CUDA_VISIBLE_DEVICES", "0"), ("SLURM_STEP_GPUS", "1")]));
    assert_eq!(w.as_deref(), Some("1"));
    let note = note.expect("the disagreement is named");
    assert!(note.contains("CUDA_VISIBLE_DEVICES") && note.contains("SLURM_STEP_GPUS"), "{note}");
    let (_, agree) = auto_device(&list, &with(&[("CUDA_VISIBLE_DEVICES", "0"), ("SLURM_STEP_GPUS", "0")]));
    assert_eq!(agree, None);
}

/// `animate --frame-range`: each range's first frame starts cold, its rows go to
/// frames-A-B.csv beside the others' in one directory, and `merge --csv` puts them in frame
/// order, refusing a repeated or a missing frame.
#[test]
fn frame_ranges_render_their_own_frames_and_their_csvs_merge_in_order() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let scene = repo("scenes/cloud.toml");
    let seq = d.join("seq");
    let animate_into = |range: &str, degrees: &str, dir: &std::path::Path| {
        ok(&[
            "animate",
            &scene,
            "--solver",
            "networks",
            "--orbit-light",
            degrees,
            "--frame-range",
            range,
            "--out-dir",
            dir.to_str().unwrap(),
            "--no-reference",
            "--validate",
            "--quiet",
            "--set",
            "render.width=12",
            "--set",
            "render.height=12",
            "--set",
            "networks.particles=128",
            "--set",
            "networks.directions=16",
        ]);
    };
    let animate = |range: &str| animate_into(range, "15", &seq);
    animate("2..4");
    animate("0..2");
    for f in
        ["frame-0000.exr", "frame-0001.exr", "frame-0002.exr", "frame-0003.exr", "frames-0-2.csv", "frames-2-4.csv"]
    {
        assert!(seq.join(f).is_file(), "{f} missing");
    }
    let csv = |n: &str| seq.join(n).display().to_string();
    // Frame 2 of its range starts cold: iterations from zero, as frame 0's.
    let rows = |n: &str| -> Vec<Vec<String>> {
        std::fs::read_to_string(seq.join(n))
            .unwrap()
            .lines()
            .skip(1)
            .map(|l| l.split(',').map(String::from).collect())
            .collect()
    };
    let (a, b) = (rows("frames-0-2.csv"), rows("frames-2-4.csv"));
    assert_eq!((a[0][0].as_str(), b[0][0].as_str()), ("0", "2"));
    assert_eq!(b[0][1].parse::<f64>().unwrap(), 30.0, "frame 2 is the light at 2 x 15 degrees");
    let merged = d.join("frames.csv");
    ok(&["merge", "--csv", "-q", merged.to_str().unwrap(), &csv("frames-2-4.csv"), &csv("frames-0-2.csv")]);
    let text = std::fs::read_to_string(&merged).unwrap();
    let frames: Vec<&str> = text.lines().skip(1).map(|l| l.split(',').next().unwrap()).collect();
    assert_eq!(frames, ["0", "1", "2", "3"]);
    assert!(text.starts_with("frame,"));
    let out = d.join("m.csv").display().to_string();
    let err = refused(&["merge", "--csv", &out, &csv("frames-0-2.csv"), &csv("frames-0-2.csv")], d);
    assert!(err.contains("both hold frame 0"), "{err}");
    std::fs::write(d.join("late.csv"), "frame,angle_deg\n7,105\n").unwrap();
    let late = d.join("late.csv").display().to_string();
    let err = refused(&["merge", "--csv", &out, &csv("frames-0-2.csv"), &late], d);
    assert!(err.contains("differ in their columns"), "{err}");
    let head = text.lines().next().unwrap();
    let row = text.lines().nth(1).unwrap().replacen('0', "9", 1);
    std::fs::write(d.join("gap.csv"), format!("{head}\n{row}\n")).unwrap();
    let err = refused(&["merge", "--csv", &out, &csv("frames-0-2.csv"), &d.join("gap.csv").display().to_string()], d);
    assert!(err.contains("gap: frame 2"), "{err}");

    // Frames of another sequence share the columns but not the `sequence` column: the same
    // solver with the light turning 20 degrees a frame, and (the file edited) another solver.
    let (solver_at, sequence_at) = {
        let cols: Vec<&str> = head.split(',').collect();
        (cols.iter().position(|c| *c == "solver").unwrap(), cols.iter().position(|c| *c == "sequence").unwrap())
    };
    let sequences: Vec<String> = [a.clone(), b.clone()].concat().iter().map(|r| r[sequence_at].clone()).collect();
    assert!(sequences.iter().all(|x| x.len() == 12 && *x == sequences[0]), "one sequence: {sequences:?}");
    assert!(a.iter().all(|r| r[solver_at] == "networks"));
    let other = d.join("other");
    animate_into("2..3", "20", &other);
    let err = refused(
        &["merge", "--csv", &out, &csv("frames-0-2.csv"), &other.join("frames-2-3.csv").display().to_string()],
        d,
    );
    assert!(err.contains("frames of different sequences") && err.contains("both networks"), "{err}");
    let edited: String = std::fs::read_to_string(seq.join("frames-2-4.csv"))
        .unwrap()
        .lines()
        .enumerate()
        .map(|(i, l)| {
            if i == 0 {
                return format!("{l}\n");
            }
            let mut cells: Vec<String> = l.split(',').map(String::from).collect();
            cells[solver_at] = "dom".into();
            cells[sequence_at] = "0123456789ab".into();
            cells.join(",") + "\n"
        })
        .collect();
    std::fs::write(d.join("dom.csv"), edited).unwrap();
    let err = refused(&["merge", "--csv", &out, &csv("frames-0-2.csv"), &d.join("dom.csv").display().to_string()], d);
    assert!(err.contains("solver networks against dom") && err.contains("0123456789ab"), "{err}");
}
