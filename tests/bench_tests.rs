//! `scatterlab bench` end to end on a tiny scene: every ladder point measured, CSV columns and
//! numbers sane, Pareto front right on a constructed example, SVG well formed.

use crate::common::{LBL, PATH, SINGLE};
use scatterlab::measure::bench;

use crate::common::{assert_clean, gpu, scene};

#[test]
fn pareto_front_on_a_constructed_example() {
    // (time, error): a dominates c (faster and better); b and d trade; e ties b on time but is worse.
    let pts = [(1.0, 0.5), (2.0, 0.2), (3.0, 0.6), (4.0, 0.1), (2.0, 0.3), (5.0, 0.1)];
    assert_eq!(bench::pareto(&pts), vec![true, true, false, true, false, false]);
    assert_eq!(bench::pareto(&[]), Vec::<bool>::new());
    // Identical points are both on the front (neither beats the other).
    assert_eq!(bench::pareto(&[(1.0, 1.0), (1.0, 1.0)]), vec![true, true]);
}

/// The speed-up at equal error on a constructed curve: the reference solver's error is exactly
/// sqrt(K / spp + noise^2) at GPU time t1 spp, so an approximate point of true error e in time
/// T must get t1 K / e^2 / T; the reference's own points get none, and a point below the
/// reference's noise gets none.
#[test]
fn speedup_at_equal_error_on_a_constructed_curve() {
    use scatterlab::output::Metrics;
    let (k, t1, noise) = (0.36f64, 2.5f64, 0.01f64);
    let point = |solver: &'static str, spp: Option<u32>, rel_l2: f64, gpu_ms: f64| bench::Point {
        scene: "s".into(),
        solver,
        knob: "k".into(),
        value: "v".into(),
        gpu_ms,
        wall_ms: gpu_ms,
        cold_gpu_ms: gpu_ms,
        cold_wall_ms: gpu_ms,
        warm: Default::default(),
        metrics: Metrics {
            rel_l2,
            rel_mse: 0.0,
            rmse: 0.0,
            energy_ratio: 1.0,
            max_abs_error: 0.0,
            nan_inf_count: 0,
            pixels: 1,
        },
        iterations: None,
        converged: None,
        device_bytes: 0,
        pareto: false,
        spp,
        rel_l2_denoised: 0.0,
        speedup: None,
    };
    let mut pts: Vec<bench::Point> = [4u32, 16, 64, 256, 1024]
        .iter()
        .map(|&s| point("path", Some(s), (k / s as f64 + noise * noise).sqrt(), t1 * s as f64))
        .collect();
    let e = 0.03f64;
    pts.push(point("lbl", None, (e * e + noise * noise).sqrt(), 40.0));
    pts.push(point("single", None, 0.5 * noise, 1.0));
    bench::speedups(&mut pts, "path", noise);
    assert!(pts[..5].iter().all(|p| p.speedup.is_none()));
    let want = t1 * k / (e * e) / 40.0;
    let got = pts[5].speedup.expect("a speed-up for lbl");
    assert!((got - want).abs() < 1e-9 * want, "{got} vs {want}");
    assert!((pts[5].rel_l2_denoised - e).abs() < 1e-12);
    assert!(pts[6].speedup.is_none() && pts[6].rel_l2_denoised == 0.0, "below the reference's noise");
}

const TINY: &str = r#"
[render]
width = 16
height = 16
seed = 2
spp = 64
[camera]
origin = [0.0, 0.0, 4.0]
target = [0.0, 0.0, 0.0]
fov = 20.0
[medium]
bounds = [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]
sigma_t = 8.0
albedo = 0.8
density = { kind = "sphere", center = [0.0, 0.0, 0.0], radius = 0.45 }
[[light]]
kind = "directional"
direction = [0.0, -0.6, -0.8]
irradiance = 2.0
"#;

#[test]
fn bench_walks_every_ladder_and_writes_sane_outputs() {
    let gpu = gpu();
    let s = scene(TINY);
    let reference = crate::common::path_reference(&gpu, &s, &[("render.spp", "512")]).image;
    let kinds = [PATH, SINGLE, LBL];
    let (points, thr) =
        bench::bench_scene(&gpu, "tiny", &s, &reference, &kinds, &bench::Points::Cheapest(3), 1, &|_| {}).unwrap();
    assert_eq!(points.len(), 9, "three quick rungs per solver");
    for p in &points {
        assert!(p.gpu_ms > 0.0 && p.gpu_ms.is_finite(), "{p:?}");
        assert!(p.metrics.rel_l2.is_finite() && p.metrics.nan_inf_count == 0, "{p:?}");
    }
    // path's error falls with spp; the front holds at least the cheapest and the best point.
    let path: Vec<f64> = points.iter().filter(|p| p.solver == "path").map(|p| p.metrics.rel_l2).collect();
    assert!(path[2] < path[0], "{path:?}");
    assert!(points.iter().any(|p| p.pareto));
    let best = points.iter().min_by(|a, b| a.metrics.rel_l2.total_cmp(&b.metrics.rel_l2)).unwrap();
    assert!(best.pareto);
    assert!(thr.iter().any(|t| t.figure.starts_with("lattice voxel-updates/s") && t.value > 0.0));
    assert!(thr.iter().any(|t| t.figure.starts_with("samples/s") && t.value > 0.0));

    let csv = bench::csv(&points).unwrap();
    let mut reader = csv::Reader::from_reader(csv.as_bytes());
    let header: Vec<String> = reader.headers().unwrap().iter().map(String::from).collect();
    let header: Vec<&str> = header.iter().map(String::as_str).collect();
    for col in [
        "scene",
        "solver",
        "knob",
        "value",
        "gpu_ms",
        "wall_ms",
        "cold_gpu_ms",
        "cold_wall_ms",
        "warm_runs",
        "gpu_spread",
        "settled",
        "rel_l2",
        "rel_mse",
        "rmse",
        "energy_ratio",
        "max_abs_error",
        "nan_inf_count",
        "iterations",
        "converged",
        "pareto",
    ] {
        assert!(header.contains(&col), "CSV lacks column {col}");
    }
    let rows: Vec<csv::StringRecord> = reader.records().map(|r| r.expect("a CSV row")).collect();
    assert_eq!(rows.len(), points.len());
    assert!(rows.iter().all(|r| r.len() == header.len()));

    // A scene name with a comma and a quote stays one field and reads back as written.
    let mut odd = points[0].clone();
    odd.scene = "my \"best\", cloud".into();
    let text = bench::csv(&[odd.clone()]).unwrap();
    let mut reader = csv::Reader::from_reader(text.as_bytes());
    let row = reader.records().next().expect("one row").expect("parses");
    assert_eq!((&row[0], &row[1], row.len()), (odd.scene.as_str(), odd.solver, header.len()), "{text}");

    let svg = bench::svg("tiny <&> \"quoted\"", &points, Some(1e-3));
    let doc = roxmltree::Document::parse(&svg).unwrap_or_else(|e| panic!("SVG is not well-formed XML: {e}"));
    assert_eq!(doc.root_element().tag_name().name(), "svg");
    let count = |tag: &str| doc.descendants().filter(|n| n.has_tag_name(tag)).count();
    assert_eq!(count("polyline"), 3, "one line per solver");
    let ringed = doc.descendants().filter(|n| n.has_tag_name("circle") && n.attribute("fill") == Some("none")).count();
    assert_eq!(ringed, points.iter().filter(|p| p.pareto).count() + 1, "a ring per Pareto point, plus the legend's");
    assert!(doc.descendants().any(|n| n.text() == Some("Pareto front")));
    assert!(
        doc.descendants().any(|n| n.attribute("stroke-dasharray").is_some())
            && doc.descendants().any(|n| n.text().is_some_and(|t| t.starts_with("reference noise floor"))),
        "no noise floor line"
    );
    assert_clean(&gpu);
}

/// Labels never overlap: points on one spot (three wavefront rungs at one time and error)
/// and crowded neighbours each get their own box, near their point.
#[test]
fn plot_labels_never_overlap() {
    let mut anchors = vec![(300.0, 200.0, 6); 4];
    anchors.extend((0..12).map(|i| (100.0 + 3.0 * i as f64, 150.0 + 2.0 * i as f64, 5)));
    anchors.push((640.0, 40.0, 6));
    let spots = bench::place_labels(&anchors);
    let boxes: Vec<(f64, f64, f64, f64)> =
        spots.iter().zip(&anchors).map(|((x, y), (_, _, n))| (*x, y - 9.0, 5.2 * *n as f64 + 2.0, 11.0)).collect();
    for (i, a) in boxes.iter().enumerate() {
        for b in &boxes[i + 1..] {
            let overlap = a.0 < b.0 + b.2 && b.0 < a.0 + a.2 && a.1 < b.1 + b.3 && b.1 < a.1 + a.3;
            assert!(!overlap, "labels overlap: {a:?} {b:?}");
        }
    }
    for ((x, y), (ax, ay, _)) in spots.iter().zip(&anchors) {
        assert!((x - ax).abs() < 60.0 && (y - ay).abs() < 120.0, "label far from its point: {x},{y} vs {ax},{ay}");
    }
}

/// Model only what the scene requires, measured: `lbl` on a grey scene allocates less with one
/// channel than with three (`--model-all`), and the images agree.
#[test]
fn slim_lbl_allocates_less_and_agrees() {
    let gpu = gpu();
    let s = scene(TINY);
    let sets = vec![("lbl.grid".to_string(), "16".to_string()), ("lbl.rays".to_string(), "4096".to_string())];
    let (slim, full, _, _, diff) = bench::slim_vs_full(&gpu, &s, LBL, &sets).unwrap();
    assert!(slim < full, "slim {slim} bytes, full {full}");
    assert!(diff < 1e-5, "slim and full images differ by relL2 {diff}");
    assert_clean(&gpu);
}

/// The commands themselves, end to end through the binary, outputs parsed.
#[test]
fn bench_and_stability_commands_end_to_end() {
    let dir = tempfile::tempdir().unwrap();
    let scene_path = dir.path().join("tiny.toml");
    std::fs::write(&scene_path, TINY).unwrap();
    let out = dir.path().join("bench");
    let cache = dir.path().join("cache");
    let run = |args: &[&str]| {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_scatterlab")).args(args).output().unwrap();
        (
            o.status.success(),
            String::from_utf8_lossy(&o.stdout).into_owned(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };
    let args = [
        "bench",
        scene_path.to_str().unwrap(),
        "--quick",
        "--ref-spp",
        "128",
        "--solvers",
        "path,single",
        "--throughput",
        "--validate",
        "--out",
        out.to_str().unwrap(),
        "--cache",
        cache.to_str().unwrap(),
        "--repeats",
        "2",
    ];
    let (ok, stdout, stderr) = run(&args);
    assert!(ok, "bench failed: {stderr}");
    assert!(stdout.contains("samples/s"), "{stdout}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("bench.json")).unwrap()).unwrap();
    assert_eq!(json["points"].as_array().unwrap().len(), 6);
    // One cold render apart, then one warm (--repeats 2): both timed.
    for p in json["points"].as_array().unwrap() {
        assert_eq!(p["warm"]["runs"], 1, "{p}");
        assert!(p["cold_gpu_ms"].as_f64().unwrap() > 0.0 && p["gpu_ms"].as_f64().unwrap() > 0.0, "{p}");
    }
    assert!(json["device"]["mapping"].is_object() && json["references"][0]["cached"] == false);
    assert!(json["points"]
        .as_array()
        .unwrap()
        .iter()
        .all(|p| p["metrics"]["rel_l2"].as_f64().is_some_and(f64::is_finite)));
    let csv = std::fs::read_to_string(out.join("bench.csv")).unwrap();
    assert_eq!(csv.lines().count(), 7);
    let svg = std::fs::read_to_string(out.join("tiny.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("polyline"));
    // --replot draws the same plot again from bench.json alone.
    std::fs::remove_file(out.join("tiny.svg")).unwrap();
    let (ok, _, stderr) = run(&["bench", "--replot", out.to_str().unwrap()]);
    assert!(ok, "replot failed: {stderr}");
    assert_eq!(std::fs::read_to_string(out.join("tiny.svg")).unwrap(), svg, "the replot differs");
    // Several runs combine into --out only, never over one of them; each refusal is one line.
    let o = out.to_str().unwrap();
    let elsewhere = dir.path().join("elsewhere");
    for (args, needle) in [
        (vec!["bench", "--replot", o, o], "--out"),
        (vec!["bench", "--replot", o, o, "--out", o], "one of the runs combined"),
        (vec!["bench", "--replot", o, o, "--out", elsewhere.to_str().unwrap()], "both hold scene tiny"),
    ] {
        let (ok, _, stderr) = run(&args);
        assert!(!ok && stderr.lines().count() == 1 && stderr.contains(needle), "{args:?}: {stderr}");
    }
    assert!(!elsewhere.exists(), "a refused combination wrote {}", elsewhere.display());
    // A second run finds the reference in the cache.
    let (ok, _, stderr) = run(&args);
    assert!(ok, "{stderr}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("bench.json")).unwrap()).unwrap();
    assert_eq!(json["references"][0]["cached"], true);

    let stab = dir.path().join("stab");
    let (ok, stdout, stderr) =
        run(&["stability", "--solvers", "path,single", "--validate", "--out", stab.to_str().unwrap()]);
    assert!(ok, "stability failed: {stderr}\n{stdout}");
    assert!(stdout.contains("pass") && !stdout.contains("FAIL"));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(stab.join("stability.json")).unwrap()).unwrap();
    assert!(json["outcomes"].as_array().unwrap().iter().all(|o| o["passed"] == true));
}

#[test]
fn points_parse_rung_lists() {
    use bench::Points;
    assert_eq!(Points::parse("1,3-5"), Ok(Points::Rungs(vec![1, 3, 4, 5])));
    assert_eq!(Points::parse(" 2 , 2,1"), Ok(Points::Rungs(vec![1, 2])));
    assert_eq!(Points::parse("4").unwrap().highest(), Some(4));
    for bad in ["0", "3-1", "a", "", "1,,2", "-2"] {
        let e = Points::parse(bad).expect_err(bad);
        assert!(e.contains("--points") && e.contains("1,3-5"), "{bad}: {e}");
    }
}

/// The progress count is the work: `bench` announces exactly [`bench::steps`] steps and
/// `stability` exactly [`stability::steps`] renders, so "[k/N]" reaches N and never passes it;
/// `--points` picks rungs by number.
#[test]
fn bench_and_stability_announce_the_steps_they_count() {
    use scatterlab::measure::stability;
    use std::cell::Cell;
    let gpu = gpu();
    let cache = tempfile::tempdir().unwrap();
    let scenes = vec![bench::BenchScene { name: "tiny".into(), text: TINY.into(), scene: scene(TINY) }];
    let solvers = [PATH, SINGLE];
    let cfg = bench::BenchConfig {
        solvers: &solvers,
        ref_spp: 16,
        repeats: 1,
        points: bench::Points::parse("2,4").unwrap(),
        overrides: &[],
        cache: cache.path(),
    };
    let calls = Cell::new(0usize);
    let result = bench::run(&gpu, &scenes, &cfg, &|_| calls.set(calls.get() + 1)).expect("bench");
    // Reference, two rungs each of two solvers, two slim-vs-full pairs.
    assert_eq!((calls.get(), bench::steps(&scenes, &cfg)), (7, 7));
    let rungs: Vec<(&str, &str)> = result.points.iter().map(|p| (p.solver, p.value.as_str())).collect();
    let want_path: Vec<String> = PATH.ladder(&scenes[0].scene).iter().map(|r| r.value.clone()).collect();
    assert_eq!(
        rungs.iter().filter(|(s, _)| *s == "path").map(|(_, v)| *v).collect::<Vec<_>>(),
        [&want_path[1], &want_path[3]]
    );

    let calls = Cell::new(0usize);
    stability::run(&gpu, &[SINGLE], false, &|_| calls.set(calls.get() + 1)).expect("stability");
    assert_eq!(calls.get(), stability::steps(&[SINGLE], false).unwrap());
    assert!(calls.get() > 10, "{}", calls.get());
    assert_clean(&gpu);
}

/// `bench --replot DIR DIR...`'s combination: scenes' points, references and the rest
/// concatenated in the order given; runs of another build, device, flags or reference spp, and
/// a scene in two runs, each refused with the two documents and the field named.
#[test]
fn combined_runs_are_concatenated_and_mismatches_refused() {
    use serde_json::{json, Value};
    let point = |scene: &str, solver: &str, value: &str| {
        json!({ "scene": scene, "solver": solver, "knob": "single.step", "value": value, "gpu_ms": 1.5,
                "wall_ms": 2.0, "metrics": { "rel_l2": 0.1, "rel_mse": 0.01, "rmse": 0.02, "energy_ratio": 0.9,
                "max_abs_error": 0.3, "nan_inf_count": 0, "pixels": 144 }, "iterations": null, "converged": null,
                "device_bytes": 10, "pareto": true, "spp": null, "rel_l2_denoised": 0.1, "speedup": null })
    };
    let run = |scene: &str| {
        json!({ "scatterlab": "0.1.0", "build": "abc", "device": { "name": "llvmpipe", "driver_name": "llvmpipe",
                "driver_info": "Mesa" }, "repeats": 4, "quick": true, "rungs": { "Cheapest": 3 },
                "references": [{ "scene": scene, "spp": 64, "noise": 0.01 }],
                "ladders": [{ "solver": "single", "rungs": [] }],
                "points": [point(scene, "single", "0.1"), point(scene, "single", "0.05")],
                "throughput": [], "slim_vs_full": [{ "scene": scene }], "skipped": [] })
    };
    let docs = vec![("a/bench.json".to_string(), run("cloud")), ("b/bench.json".to_string(), run("sphere"))];
    let c = bench::combine(&docs).expect("combine");
    let scenes: Vec<&str> = c["points"].as_array().unwrap().iter().map(|p| p["scene"].as_str().unwrap()).collect();
    assert_eq!(scenes, ["cloud", "cloud", "sphere", "sphere"]);
    assert_eq!(c["references"].as_array().unwrap().len(), 2);
    assert_eq!(c["slim_vs_full"].as_array().unwrap().len(), 2);
    assert_eq!(c["ladders"].as_array().unwrap().len(), 1);
    assert_eq!(c["combined_from"], json!(["a/bench.json", "b/bench.json"]));
    assert_eq!(bench::points_of(&c).unwrap().len(), 4);
    let plots = bench::replot(&c).unwrap();
    assert_eq!(plots.iter().map(|p| p.0.as_str()).collect::<Vec<_>>(), ["cloud", "sphere"]);

    let edit = |f: &dyn Fn(&mut Value)| {
        let mut b = run("sphere");
        f(&mut b);
        bench::combine(&[("a/bench.json".into(), run("cloud")), ("b/bench.json".into(), b)]).unwrap_err()
    };
    for (e, field) in [
        (edit(&|b| b["build"] = json!("def")), "build"),
        (edit(&|b| b["device"]["name"] = json!("NVIDIA H100")), "device/name"),
        (edit(&|b| b["device"]["driver_info"] = json!("Mesa 24")), "device/driver_info"),
        (edit(&|b| b["repeats"] = json!(2)), "repeats"),
        (edit(&|b| b["rungs"] = json!({ "Rungs": [1] })), "rungs"),
        (edit(&|b| b["references"][0]["spp"] = json!(128)), "spp"),
        (edit(&|b| b["points"][0]["scene"] = json!("cloud")), "scene cloud"),
    ] {
        assert!(e.contains("a/bench.json") && e.contains("b/bench.json") && e.contains(field), "{field}: {e}");
        assert_eq!(e.lines().count(), 1, "{e}");
    }
    assert!(bench::combine(&[]).is_err());
}
