//! `scatterlab report` (issue 14) on lavapipe with `--quick`, validation on: the bandwidth
//! probe's byte count is exact and its rate positive; every solver's headline workload ran and
//! its GB/s figures are read against the probe; the queue matrix runs the shared mapping with a
//! trace and a timeline SVG and records the mappings lavapipe lacks with their reason; report.json round-trips
//! through its type and holds its schema; `--compare` of a report with itself gives ratio 1; a
//! forced mapping the device lacks is one line of error and leaves no report.

use std::path::Path;
use std::process::Command;

use scatterlab::measure::report::{Report, SCHEMA};

const BIN: &str = env!("CARGO_BIN_EXE_scatterlab");

fn report(out: &Path, extra: &[&str]) -> std::process::Output {
    Command::new(BIN)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(["report", "--quick", "--validate", "--out"])
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn quick_report_measures_bandwidth_workloads_and_queues() {
    let dir = tempfile::tempdir().unwrap();
    let out = report(dir.path(), &[]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = std::fs::read_to_string(dir.path().join("report.json")).unwrap();
    let r: Report = serde_json::from_str(&text).expect("report.json parses as a Report");
    // Round trip: the type holds every field the file has.
    let again: serde_json::Value = serde_json::to_value(&r).unwrap();
    assert_eq!(again, serde_json::from_str::<serde_json::Value>(&text).unwrap(), "report.json round-trips");
    assert_eq!(r.schema, SCHEMA);
    // The published schema (docs/report.schema.json) holds the file: every field typed, none
    // missing, none unknown.
    let schema: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/report.schema.json")).unwrap(),
    )
    .unwrap();
    let validator = jsonschema::validator_for(&schema).expect("docs/report.schema.json is a valid schema");
    let instance: serde_json::Value = serde_json::from_str(&text).unwrap();
    let errors: Vec<String> =
        validator.iter_errors(&instance).map(|e| format!("{} at {}", e, e.instance_path())).collect();
    assert!(errors.is_empty(), "report.json against docs/report.schema.json: {errors:#?}");
    // ... and is strict: an unknown field, a missing one or a NaN written as null is refused.
    let mut extra = instance.clone();
    extra["workloads"][0]["fps"] = serde_json::json!(8.0);
    let mut missing = instance.clone();
    missing["bandwidth"][0].as_object_mut().unwrap().remove("gb_per_s");
    let mut nan = instance.clone();
    nan["queues"][0]["images_rel_l2"] = serde_json::Value::Null;
    for (what, bad) in [("unknown field", extra), ("missing field", missing), ("null number", nan)] {
        assert!(!validator.is_valid(&bad), "the schema lets a report with a {what} through");
    }
    assert!(r.quick);
    assert!(r.device.get("name").and_then(|n| n.as_str()).is_some_and(|n| !n.is_empty()), "device facts");

    // The probe: 16 MiB buffers, each run reads and writes all of it.
    assert_eq!(r.bandwidth.len(), 2);
    for b in &r.bandwidth {
        assert_eq!(b.buffer_bytes, 16 << 20, "{}", b.method);
        assert_eq!(b.bytes_moved, 2 * b.buffer_bytes, "{}", b.method);
        assert!(b.runs >= 1 && b.best_ms > 0.0 && b.best_ms <= b.median_ms, "{b:?}");
        let rate = b.bytes_moved as f64 / (b.best_ms * 1e-3) / 1e9;
        assert!((b.gb_per_s - rate).abs() <= 1e-9 * rate && rate > 0.0, "{b:?}");
    }
    let peak = r.peak_gb_per_s().unwrap();

    // Every solver with a headline workload ran it; GB/s figures are a share of the probe.
    let expected: Vec<String> = scatterlab::solvers::SOLVERS
        .iter()
        .filter(|s| s.headline(true).is_some())
        .map(|s| s.name().to_string())
        .collect();
    let ran: Vec<String> = r.workloads.iter().map(|w| w.solver.clone()).collect();
    assert_eq!(ran, expected);
    assert!(expected.len() >= 4, "lbl, wavefront, dom and path have headlines: {expected:?}");
    for w in &r.workloads {
        assert!(w.error.is_none(), "{}: {:?}", w.name, w.error);
        assert!(w.wall_ms > 0.0 && w.gpu_ms > 0.0 && w.device_bytes > 0, "{w:?}");
        for f in &w.figures {
            assert!(f.value.is_finite() && f.value > 0.0, "{}: {f:?}", w.name);
            match f.fraction_of_bandwidth {
                Some(x) => assert!(f.unit == "GB/s" && (x - f.value / peak).abs() < 1e-12, "{f:?}"),
                None => assert_ne!(f.unit, "GB/s", "{f:?}"),
            }
        }
    }

    // Every solver with a concurrent workload (lbl's marching beside its lattice, path's light
    // paths beside its camera paths, dom's streaming copies beside its sweeps) under each of
    // the three mappings. lavapipe has one queue:
    // shared runs (no gain to claim), the others are not offered.
    let concurrent: Vec<String> = scatterlab::solvers::SOLVERS
        .iter()
        .filter(|s| s.concurrency(true).is_some())
        .map(|s| s.name().to_string())
        .collect();
    assert!(["path", "lbl", "dom"].iter().all(|n| concurrent.iter().any(|c| c == n)), "{concurrent:?}");
    assert_eq!(r.queues.len(), 3 * concurrent.len());
    for q in &r.queues {
        if q.mapping == "shared" {
            assert!(q.unavailable.is_none() && q.gain.is_none(), "{q:?}");
            assert!(q.sequential_ms > 0.0 && q.concurrent_ms > 0.0 && q.images_rel_l2 < 1e-4, "{q:?}");
            if q.workload.starts_with("path") || q.workload.starts_with("dom") {
                // Both schedules compute the same paths, or the same sweeps of the same blocks:
                // the same image, bit for bit.
                assert_eq!(q.images_rel_l2, 0.0, "{q:?}");
            }
            let trace = dir.path().join(q.trace.as_ref().expect("a trace per mapping that ran"));
            let t: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(trace).unwrap()).unwrap();
            let events = t.get("traceEvents").and_then(|e| e.as_array()).expect("trace events");
            // The concurrent schedule's passes are on their roles (tid 1 trace, 2 diffuse, 3
            // transfer): path's and lbl's on trace and diffuse, dom's copies on transfer too.
            let mut tids: Vec<u64> =
                events.iter().filter(|e| e["ph"] == "X").filter_map(|e| e["tid"].as_u64()).collect();
            tids.sort();
            tids.dedup();
            let want: &[u64] = if q.workload.starts_with("dom") { &[1, 2, 3] } else { &[1, 2] };
            assert_eq!(tids, want, "{}: passes on their roles", q.workload);
            let svg =
                std::fs::read_to_string(dir.path().join(q.svg.as_ref().expect("a timeline per mapping"))).unwrap();
            assert!(svg.starts_with("<svg") && svg.contains("<rect x=") && svg.trim_end().ends_with("</svg>"), "{svg}");
        } else if offers(&q.mapping) {
            // A device with two compute queues (any discrete GPU) runs the mapping: a gain
            // measured, an image equal to the sequential one, passes on both roles.
            assert!(q.unavailable.is_none(), "{q:?}");
            assert!(q.gain.is_some_and(|g| g > 0.0) && q.sequential_ms > 0.0 && q.concurrent_ms > 0.0, "{q:?}");
            assert!(q.images_rel_l2 < 1e-4, "{q:?}");
        } else {
            // lavapipe: one queue, every other mapping refused with its reason.
            let why = q.unavailable.as_deref().expect("a mapping the device lacks says why");
            assert!(why.contains(&q.mapping) && why.contains("cannot"), "{why}");
        }
    }
    let md = std::fs::read_to_string(dir.path().join("report.md")).unwrap();
    assert!(md.contains("## Memory bandwidth") && md.contains("## Headline workloads") && md.contains("## Queue"));

    // Every figure has a name of its own (--compare matches them by name).
    let names: Vec<String> = scatterlab::measure::report::figures(&r).into_iter().map(|(n, _)| n).collect();
    let unique: std::collections::HashSet<&String> = names.iter().collect();
    assert_eq!(unique.len(), names.len(), "figure names repeat: {names:#?}");

    // The same report twice: every ratio is 1.
    let json = dir.path().join("report.json");
    let cmp = Command::new(BIN).args(["report", "--compare"]).arg(&json).arg(&json).output().unwrap();
    assert!(cmp.status.success(), "{}", String::from_utf8_lossy(&cmp.stderr));
    let table = String::from_utf8_lossy(&cmp.stdout);
    let rows: Vec<&str> = table.lines().filter(|l| l.contains("bandwidth") || l.contains(": wall ms")).collect();
    assert!(rows.len() >= 6, "{table}");
    assert!(rows.iter().all(|l| l.trim_end().ends_with("1.000")), "{table}");
}

/// Whether the device the CLI opens (the first usable, as `Gpu::new` chooses, or
/// SCATTERLAB_DEVICE's) offers the queue mapping `name`.
fn offers(name: &str) -> bool {
    let list = scatterlab::gpu::list_devices().expect("a Vulkan device");
    let wanted = std::env::var("SCATTERLAB_DEVICE").ok();
    let i = scatterlab::gpu::choose_device(&list, wanted.as_deref()).unwrap().expect("a usable device");
    scatterlab::gpu::map_roles_named(&list[i].queue_families, name).is_ok()
}

#[test]
fn a_mapping_the_device_lacks_is_one_line_and_no_report() {
    let dir = tempfile::tempdir().unwrap();
    // lavapipe lacks separate-families; a GPU that offers it (NVIDIA: compute-only and
    // graphics+compute families) must run the report under it instead.
    let out = report(&dir.path().join("r"), &["--queues", "separate-families"]);
    if offers("separate-families") {
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        assert!(dir.path().join("r").join("report.json").exists());
        return;
    }
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error")).collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(lines[0].contains("separate-families"), "{err}");
    assert!(!dir.path().join("r").join("report.json").exists(), "no partial report");
}
