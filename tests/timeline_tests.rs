//! Pure-Rust tests of `scatterlab::measure::timeline`: busy time, overlap and serial baseline
//! on hand-built timelines with answers worked out by hand, and the Chrome-trace export.

use scatterlab::gpu::{PassTiming, QueueRole};
use scatterlab::measure::timeline::{chrome_trace, summarize, write_chrome_trace, TimelineSummary};
use serde_json::{json, Value};

const T: QueueRole = QueueRole::Trace;
const D: QueueRole = QueueRole::Diffuse;
const X: QueueRole = QueueRole::Transfer;

fn pass(role: QueueRole, start_ns: i128, end_ns: i128) -> PassTiming {
    PassTiming { name: format!("{}@{start_ns}", role.name()), role, submission: 0, start_ns, end_ns, host_clock: true }
}

fn timeline(passes: &[(QueueRole, i128, i128)]) -> Vec<PassTiming> {
    passes.iter().map(|&(r, s, e)| pass(r, s, e)).collect()
}

/// (busy trace, busy diffuse, passes trace, passes diffuse)
fn per_queue(s: &TimelineSummary) -> (i128, i128, usize, usize) {
    assert_eq!(s.per_queue.len(), 3);
    assert_eq!(s.per_queue[0].role, T);
    assert_eq!(s.per_queue[1].role, D);
    assert_eq!(s.per_queue[2].role, X);
    (s.per_queue[0].busy_ns, s.per_queue[1].busy_ns, s.per_queue[0].passes, s.per_queue[1].passes)
}

#[test]
fn empty_timeline_is_all_zero_and_not_nan() {
    let s = summarize(&[]);
    assert_eq!(per_queue(&s), (0, 0, 0, 0));
    assert_eq!((s.span_ns, s.union_busy_ns, s.overlap_ns, s.serial_ns), (0, 0, 0, 0));
    assert_eq!(s.overlap_fraction, 0.0);
}

#[test]
fn only_zero_length_passes_give_zero_fraction() {
    let s = summarize(&timeline(&[(T, 5, 5), (D, 5, 5), (D, 9, 9)]));
    assert_eq!(per_queue(&s), (0, 0, 1, 2));
    assert_eq!((s.span_ns, s.union_busy_ns, s.overlap_ns, s.serial_ns), (4, 0, 0, 0));
    assert_eq!(s.overlap_fraction, 0.0);
}

#[test]
fn one_queue_disjoint_nested_touching_identical() {
    // disjoint: [0,10) [20,25) -> 15
    let s = summarize(&timeline(&[(T, 0, 10), (T, 20, 25)]));
    assert_eq!(per_queue(&s).0, 15);
    assert_eq!((s.span_ns, s.union_busy_ns, s.serial_ns), (25, 15, 15));
    // nested: [0,100) contains [10,20) and [30,90) -> 100, serial 170
    let s = summarize(&timeline(&[(T, 0, 100), (T, 10, 20), (T, 30, 90)]));
    assert_eq!(per_queue(&s).0, 100);
    assert_eq!((s.span_ns, s.union_busy_ns, s.serial_ns), (100, 100, 170));
    // touching: [0,10) [10,30) [30,31) -> 31
    let s = summarize(&timeline(&[(D, 0, 10), (D, 10, 30), (D, 30, 31)]));
    assert_eq!(per_queue(&s), (0, 31, 0, 3));
    assert_eq!((s.span_ns, s.union_busy_ns, s.serial_ns), (31, 31, 31));
    // identical: three times [7,19) -> 12, serial 36
    let s = summarize(&timeline(&[(D, 7, 19), (D, 7, 19), (D, 7, 19)]));
    assert_eq!(per_queue(&s).1, 12);
    assert_eq!((s.span_ns, s.union_busy_ns, s.serial_ns), (12, 12, 36));
    // partially overlapping on one queue: [0,10) [5,15) -> 15, serial 20
    let s = summarize(&timeline(&[(T, 0, 10), (T, 5, 15)]));
    assert_eq!(per_queue(&s).0, 15);
    assert_eq!((s.union_busy_ns, s.serial_ns, s.overlap_ns), (15, 20, 0));
}

#[test]
fn sequential_roles_do_not_overlap() {
    // trace round, diffuse round, trace round, ... back to back (touching at the boundaries).
    let s = summarize(&timeline(&[(T, 0, 10), (D, 10, 25), (T, 25, 30), (D, 30, 50)]));
    assert_eq!(per_queue(&s), (15, 35, 2, 2));
    assert_eq!((s.span_ns, s.union_busy_ns, s.overlap_ns, s.serial_ns), (50, 50, 0, 50));
    assert_eq!(s.overlap_fraction, 0.0);
}

#[test]
fn fully_overlapping_roles_overlap_all_their_busy_time() {
    let s = summarize(&timeline(&[(T, 100, 200), (D, 100, 150), (D, 150, 200)]));
    assert_eq!(per_queue(&s), (100, 100, 1, 2));
    assert_eq!((s.span_ns, s.union_busy_ns, s.overlap_ns, s.serial_ns), (100, 100, 100, 200));
    assert_eq!(s.overlap_fraction, 1.0);
}

#[test]
fn partial_overlap_by_hand() {
    // trace: [0,40) and [60,100)      -> busy 80
    // diffuse: [30,70) and [90,120)   -> busy 70
    // both busy: [30,40) + [60,70) + [90,100) = 30
    // union: [0,120) = 120; serial 40+40+40+30 = 150; fraction 30/120 = 0.25
    let s = summarize(&timeline(&[(T, 0, 40), (T, 60, 100), (D, 30, 70), (D, 90, 120)]));
    assert_eq!(per_queue(&s), (80, 70, 2, 2));
    assert_eq!((s.span_ns, s.union_busy_ns, s.overlap_ns, s.serial_ns), (120, 120, 30, 150));
    assert_eq!(s.overlap_fraction, 0.25);
    // busy(T) + busy(D) = union + overlap (inclusion-exclusion)
    assert_eq!(80 + 70, s.union_busy_ns + s.overlap_ns);
}

#[test]
fn gaps_span_and_one_diffuse_interval_across_several_trace_intervals() {
    // trace: [0,10) [20,30) [40,50); diffuse: [5,45) plus a zero-length pass at 48.
    // overlap: [5,10) + [20,30) + [40,45) = 20; union [0,50) = 50; idle nowhere.
    let s = summarize(&timeline(&[(T, 0, 10), (T, 20, 30), (T, 40, 50), (D, 5, 45), (D, 48, 48)]));
    assert_eq!(per_queue(&s), (30, 40, 3, 2));
    assert_eq!((s.span_ns, s.union_busy_ns, s.overlap_ns, s.serial_ns), (50, 50, 20, 70));
    assert_eq!(s.overlap_fraction, 0.4);
    // With a gap: the span counts it, the union does not.
    let s = summarize(&timeline(&[(T, 0, 10), (D, 1000, 1010)]));
    assert_eq!((s.span_ns, s.union_busy_ns, s.overlap_ns), (1010, 20, 0));
}

#[test]
fn order_of_input_does_not_matter() {
    let sorted = timeline(&[(T, 0, 40), (D, 30, 70), (T, 60, 100), (D, 90, 120), (T, 100, 100), (D, 95, 110)]);
    let want = summarize(&sorted);
    let mut shuffled = sorted.clone();
    shuffled.reverse();
    assert_eq!(summarize(&shuffled), want);
    shuffled.swap(0, 3);
    shuffled.swap(1, 4);
    assert_eq!(summarize(&shuffled), want);
    assert_eq!(per_queue(&want), (80, 70, 3, 3));
    assert_eq!(want.overlap_ns, 30);
}

#[test]
fn large_host_clock_values_are_exact() {
    // CLOCK_MONOTONIC-sized values far beyond f64's exact range when summed as i128.
    let base: i128 = 1 << 70;
    let s = summarize(&timeline(&[(T, base, base + 3), (D, base + 1, base + 2)]));
    assert_eq!((s.span_ns, s.union_busy_ns, s.overlap_ns, s.serial_ns), (3, 3, 1, 4));
}

#[test]
fn reversed_pass_counts_as_zero_length() {
    let s = summarize(&timeline(&[(T, 10, 5), (D, 0, 20)]));
    assert_eq!(per_queue(&s), (0, 20, 1, 1));
    assert_eq!((s.span_ns, s.union_busy_ns, s.overlap_ns, s.serial_ns), (20, 20, 0, 20));
}

/// Copies on the transfer role overlap sweeps like any other role: the overlap is the time at
/// least two roles are busy, counted once where all three are.
#[test]
fn transfer_role_overlap_counts_two_or_more_busy() {
    // trace [0, 10), diffuse [5, 20), transfer [8, 30): two or more busy on [5, 20) = 15.
    let s = summarize(&timeline(&[(T, 0, 10), (D, 5, 20), (X, 8, 30)]));
    assert_eq!(per_queue(&s), (10, 15, 1, 1));
    assert_eq!((s.per_queue[2].busy_ns, s.per_queue[2].passes), (22, 1));
    assert_eq!((s.span_ns, s.union_busy_ns, s.overlap_ns, s.serial_ns), (30, 30, 15, 47));
    // Touching intervals do not overlap; a transfer inside a gap adds none.
    let s = summarize(&timeline(&[(T, 0, 10), (X, 10, 20), (D, 20, 30), (X, 25, 26)]));
    assert_eq!(s.overlap_ns, 1);
    assert!((s.overlap_fraction - 1.0 / 30.0).abs() < 1e-12);
}

fn trace_passes() -> Vec<PassTiming> {
    let t0: i128 = 1_700_000_000_123_456_789; // a host clock reading, in ns
    let mut v = timeline(&[(D, 2_500, 9_000), (T, 0, 3_000), (T, 3_000, 3_000), (T, 4_000, 12_345), (D, 9_000, 9_001)]);
    for (i, p) in v.iter_mut().enumerate() {
        p.start_ns += t0;
        p.end_ns += t0;
        p.submission = i as u64 + 1;
        p.host_clock = i % 2 == 0;
    }
    v
}

fn check_chrome_trace(v: &Value, passes: &[PassTiming], meta: &Value) {
    assert_eq!(v["displayTimeUnit"], "ms");
    assert_eq!(&v["otherData"], meta);
    let events = v["traceEvents"].as_array().expect("traceEvents array");
    let meta_events: Vec<&Value> = events.iter().filter(|e| e["ph"] == "M").collect();
    let process = meta_events.iter().find(|e| e["name"] == "process_name").expect("process_name");
    assert_eq!((&process["pid"], &process["args"]["name"]), (&json!(1), &json!("scatterlab GPU")));
    for (tid, name) in [(1, "trace"), (2, "diffuse"), (3, "transfer")] {
        assert!(
            meta_events
                .iter()
                .any(|e| e["name"] == "thread_name" && e["pid"] == 1 && e["tid"] == tid && e["args"]["name"] == name),
            "thread_name for tid {tid} = {name}"
        );
    }
    let xs: Vec<&Value> = events.iter().filter(|e| e["ph"] == "X").collect();
    assert_eq!(xs.len(), passes.len());
    assert_eq!(events.len(), xs.len() + meta_events.len(), "only X and M events");
    let t0 = passes.iter().map(|p| p.start_ns).min().unwrap_or(0);
    for p in passes {
        let e = xs
            .iter()
            .find(|e| e["name"] == p.name.as_str() && e["args"]["submission"] == p.submission)
            .unwrap_or_else(|| panic!("no X event for {}", p.name));
        let tid = if p.role == T { 1 } else { 2 };
        assert_eq!((&e["pid"], &e["tid"], &e["cat"]), (&json!(1), &json!(tid), &json!(p.role.name())));
        assert_eq!(e["args"]["host_clock"], p.host_clock);
        let ts = e["ts"].as_f64().expect("ts is a number");
        let dur = e["dur"].as_f64().expect("dur is a number");
        assert!(ts >= 0.0);
        assert_eq!(ts, (p.start_ns - t0) as f64 / 1000.0);
        assert_eq!(dur, (p.end_ns - p.start_ns) as f64 / 1000.0);
    }
    if !passes.is_empty() {
        assert!(xs.iter().any(|e| e["ts"] == 0.0), "times are relative to the earliest start");
    }
}

#[test]
fn chrome_trace_round_trip() {
    let passes = trace_passes();
    let meta = json!({ "device": "llvmpipe", "mapping": "shared", "schedule": "concurrent" });
    let v = chrome_trace(&passes, meta.clone());
    // Through text and back, as a viewer would read it.
    let text = serde_json::to_string(&v).unwrap();
    let parsed: Value = serde_json::from_str(&text).unwrap();
    check_chrome_trace(&parsed, &passes, &meta);
    // Specific numbers: the diffuse pass starting 2.5 us after the first one lasts 6.5 us.
    let d = parsed["traceEvents"].as_array().unwrap().iter().find(|e| e["args"]["submission"] == 1).unwrap();
    assert_eq!((d["ts"].as_f64(), d["dur"].as_f64()), (Some(2.5), Some(6.5)));
}

#[test]
fn chrome_trace_of_nothing_has_tracks_and_no_passes() {
    let v = chrome_trace(&[], Value::Null);
    check_chrome_trace(&v, &[], &Value::Null);
}

#[test]
fn write_chrome_trace_writes_the_same_json() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("timeline.json");
    let passes = trace_passes();
    let meta = json!({ "solver": "lbl" });
    write_chrome_trace(&path, &passes, meta.clone()).unwrap();
    let parsed: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    assert_eq!(parsed, chrome_trace(&passes, meta.clone()));
    check_chrome_trace(&parsed, &passes, &meta);
    // Nothing else left in the directory (the write is atomic).
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
}

/// `--compare-schedules` reports a gain only where the queues could overlap and it beats
/// the run-to-run noise: separate queues, spans 150 vs 100 ms +- 2%: a gain of 1.5x; 102 vs
/// 100 +- 5%: within the noise; one shared queue: no gain at all, whatever the spans say.
#[test]
fn schedule_gain_is_reported_only_above_noise_and_with_overlap_possible() {
    use scatterlab::measure::timeline::ScheduleComparison;
    let s = || summarize(&[]);
    let c = ScheduleComparison::from_spans(s(), s(), vec![147.0, 150.0, 153.0], vec![99.0, 100.0, 101.0], false, 0.0);
    assert!((c.gain.unwrap() - 1.5).abs() < 1e-12 && (c.noise - 0.02).abs() < 1e-12 && c.significant, "{c:?}");
    assert!(c.describe().contains("concurrency gain 1.500x;"), "{}", c.describe());
    assert!(c.describe().starts_with("schedules: sequential 150.0 ms, concurrent 100.0 ms"), "{}", c.describe());

    let c = ScheduleComparison::from_spans(s(), s(), vec![97.0, 102.0, 107.0], vec![100.0, 100.0, 100.0], false, 0.0);
    assert!(!c.significant && (c.noise - 5.0 / 102.0).abs() < 1e-12, "{c:?}");
    assert!(c.describe().contains("within the noise"), "{}", c.describe());

    let c = ScheduleComparison::from_spans(s(), s(), vec![103.1, 103.0], vec![100.0, 100.1], true, 0.0);
    assert!(c.gain.is_none() && !c.significant, "{c:?}");
    let line = c.describe();
    assert!(line.contains("no overlap possible") && !line.contains("gain 1."), "{line}");

    // One repeat: the noise is unknown, so no gain is called significant.
    let c = ScheduleComparison::from_spans(s(), s(), vec![150.0], vec![100.0], false, 0.0);
    assert!(!c.significant && c.describe().contains("unknown"), "{c:?}");
}
