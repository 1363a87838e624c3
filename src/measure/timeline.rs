//! Per-queue GPU timelines from pass timestamps: busy time per queue role, how much of it the
//! two roles overlapped, the one-queue serial baseline, and a Chrome-trace / Perfetto export.
//!
//! Definitions (docs/design.md, "Vulkan facts", "Real GPUs"): a role is *busy* over the union of
//! its passes' intervals; *overlap* is the time both roles were busy, `|U(trace) ∩ U(diffuse)|`;
//! the overlap fraction is overlap over `|U(all passes)|`; the *serial* baseline is the sum of
//! all pass durations (what one queue running the same passes back to back would need).
//!
//! All arithmetic is exact on `i128` nanoseconds. Input may be in any order; zero-length passes
//! are allowed (they count as passes but add no time). A pass whose end precedes its start
//! (a broken timestamp) is treated as zero-length at its start.

use std::path::Path;

use serde::Serialize;
use serde_json::{json, Value};

use crate::gpu::{PassTiming, QueueRole};
use crate::output::{write_json, OutputError};

/// Busy time of one queue role.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct QueueStats {
    pub role: QueueRole,
    /// Length of the union of this role's pass intervals, in nanoseconds.
    pub busy_ns: i128,
    /// Number of passes on this role (zero-length ones included).
    pub passes: usize,
}

/// Summary of a set of pass timings. All times in nanoseconds.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TimelineSummary {
    /// One entry per role, in [`QueueRole::ALL`] order (trace, diffuse, transfer), present even when the
    /// role ran no pass.
    pub per_queue: Vec<QueueStats>,
    /// Earliest start to latest end over all passes; 0 when there are none.
    pub span_ns: i128,
    /// Length of the union of all pass intervals (time at least one role was busy).
    pub union_busy_ns: i128,
    /// Time at least two roles were busy at once (with two roles: `|U(trace) ∩ U(diffuse)|`).
    pub overlap_ns: i128,
    /// `overlap_ns / union_busy_ns` in [0, 1]; 0 when `union_busy_ns` is 0 (never NaN).
    pub overlap_fraction: f64,
    /// Sum of all pass durations: what one queue running every pass back to back would need.
    pub serial_ns: i128,
}

/// A pass's interval `[start, end)` in ns, with a reversed one collapsed to its start.
fn interval(t: &PassTiming) -> (i128, i128) {
    (t.start_ns, t.end_ns.max(t.start_ns))
}

/// Union of intervals as sorted, disjoint, non-empty intervals (touching ones merged).
fn union(mut v: Vec<(i128, i128)>) -> Vec<(i128, i128)> {
    v.retain(|&(s, e)| e > s);
    v.sort_unstable();
    let mut out: Vec<(i128, i128)> = Vec::with_capacity(v.len());
    for (s, e) in v {
        match out.last_mut() {
            Some(last) if s <= last.1 => last.1 = last.1.max(e),
            _ => out.push((s, e)),
        }
    }
    out
}

/// Total length of a list of disjoint intervals.
fn length(v: &[(i128, i128)]) -> i128 {
    v.iter().map(|&(s, e)| e - s).sum()
}

/// Total time at least two of the lists are busy at once (each list sorted and disjoint): a
/// sweep over the boundaries counting the busy lists.
fn multi_busy_length(lists: &[Vec<(i128, i128)>]) -> i128 {
    let mut edges: Vec<(i128, i32)> = lists.iter().flatten().flat_map(|&(s, e)| [(s, 1), (e, -1)]).collect();
    // Ends before starts at the same instant: touching intervals do not overlap.
    edges.sort_unstable();
    let (mut busy, mut since, mut total) = (0i32, 0i128, 0i128);
    for (t, d) in edges {
        if busy >= 2 {
            total += t - since;
        }
        busy += d;
        since = t;
    }
    total
}

/// Busy time per role, overlap between the roles and the serial baseline of `timings`.
pub fn summarize(timings: &[PassTiming]) -> TimelineSummary {
    let role_union = |role: QueueRole| union(timings.iter().filter(|t| t.role == role).map(interval).collect());
    let unions: Vec<_> = QueueRole::ALL.iter().map(|&r| role_union(r)).collect();
    let per_queue = QueueRole::ALL
        .iter()
        .zip(&unions)
        .map(|(&role, u)| QueueStats {
            role,
            busy_ns: length(u),
            passes: timings.iter().filter(|t| t.role == role).count(),
        })
        .collect();
    let span_ns = match (timings.iter().map(|t| interval(t).0).min(), timings.iter().map(|t| interval(t).1).max()) {
        (Some(first), Some(last)) => last - first,
        _ => 0,
    };
    let union_busy_ns = length(&union(timings.iter().map(interval).collect()));
    let overlap_ns = multi_busy_length(&unions);
    let overlap_fraction = if union_busy_ns > 0 { overlap_ns as f64 / union_busy_ns as f64 } else { 0.0 };
    let serial_ns = timings
        .iter()
        .map(|t| {
            let (s, e) = interval(t);
            e - s
        })
        .sum();
    TimelineSummary { per_queue, span_ns, union_busy_ns, overlap_ns, overlap_fraction, serial_ns }
}

/// Process id of the GPU in the Chrome trace.
pub const TRACE_PID: u32 = 1;
/// Name of the GPU process in the Chrome trace.
pub const TRACE_PROCESS_NAME: &str = "scatterlab GPU";

/// Thread id of a role's track in the Chrome trace: 1 = trace, 2 = diffuse, 3 = transfer.
pub fn trace_tid(role: QueueRole) -> u32 {
    match role {
        QueueRole::Trace => 1,
        QueueRole::Diffuse => 2,
        QueueRole::Transfer => 3,
    }
}

/// Nanoseconds to the trace format's microseconds.
fn us(ns: i128) -> f64 {
    ns as f64 / 1000.0
}

/// `timings` as Chrome-trace / Perfetto JSON (the Trace Event Format, JSON object form):
/// `{"traceEvents": [...], "displayTimeUnit": "ms", "otherData": meta}`.
///
/// One process `"scatterlab GPU"` (pid 1) with one track per role: tid 1 = `trace`,
/// tid 2 = `diffuse`, named by `"ph": "M"` metadata events (`process_name`, `thread_name`,
/// plus `thread_sort_index` so trace is drawn above diffuse). Each pass is a complete event
/// (`"ph": "X"`) with `name`, `cat` = role name, `ts` = start minus the earliest start and
/// `dur` = duration, both in microseconds as floats, and `args` = `{submission, host_clock}`.
/// Passes are emitted in start order. Viewers expect slices on one track to nest; passes on
/// one queue whose timestamps partially overlap may be flagged by the viewer.
pub fn chrome_trace(timings: &[PassTiming], meta: Value) -> Value {
    let mut events = vec![json!({
        "name": "process_name", "ph": "M", "pid": TRACE_PID, "args": { "name": TRACE_PROCESS_NAME },
    })];
    for role in QueueRole::ALL {
        let tid = trace_tid(role);
        events.push(
            json!({ "name": "thread_name", "ph": "M", "pid": TRACE_PID, "tid": tid, "args": { "name": role.name() } }),
        );
        events.push(json!({ "name": "thread_sort_index", "ph": "M", "pid": TRACE_PID, "tid": tid, "args": { "sort_index": tid } }));
    }
    let t0 = timings.iter().map(|t| t.start_ns).min().unwrap_or(0);
    let mut order: Vec<&PassTiming> = timings.iter().collect();
    order.sort_by_key(|t| (t.start_ns, trace_tid(t.role), t.submission));
    for t in order {
        let (s, e) = interval(t);
        events.push(json!({
            "name": t.name, "cat": t.role.name(), "ph": "X", "pid": TRACE_PID, "tid": trace_tid(t.role),
            "ts": us(s - t0), "dur": us(e - s),
            "args": { "submission": t.submission, "host_clock": t.host_clock },
        }));
    }
    json!({ "traceEvents": events, "displayTimeUnit": "ms", "otherData": meta })
}

/// Write [`chrome_trace`] of `timings` to `path` atomically (open it in ui.perfetto.dev or
/// chrome://tracing).
pub fn write_chrome_trace(path: &Path, timings: &[PassTiming], meta: Value) -> Result<(), OutputError> {
    write_json(path, &chrome_trace(timings, meta))
}

/// The same render under both schedules of a solver with concurrent work (a `schedule` knob),
/// repeated: their timelines, each schedule's span per repeat, the concurrency gain with its
/// run-to-run noise, and how far apart the images are. A gain is reported only where the
/// device could overlap the two roles' work: on one shared queue the spans differ by noise
/// alone (lavapipe printed "gain 1.031x" with 0.0% overlap), and the comparison says so.
#[derive(Clone, Debug, Serialize)]
pub struct ScheduleComparison {
    /// Timelines of the last repeat.
    pub sequential: TimelineSummary,
    pub concurrent: TimelineSummary,
    /// GPU span of each repeat, ms, in run order (sequential and concurrent interleaved).
    pub sequential_ms: Vec<f64>,
    pub concurrent_ms: Vec<f64>,
    /// Median sequential span over median concurrent span, where the roles run on separate
    /// queues; `None` on one shared queue (no overlap possible).
    pub gain: Option<f64>,
    /// The run-to-run noise of a span: the larger of the two schedules' relative half-ranges
    /// ((max - min) / (2 median)); 0 with one repeat (unknown).
    pub noise: f64,
    /// Whether |gain - 1| exceeds twice the noise (with at least two repeats).
    pub significant: bool,
    /// The roles shared one queue.
    pub shared_queue: bool,
    /// relL2 between the two images (the schedules must agree to floating-point tolerance).
    pub images_rel_l2: f64,
    /// What the two schedules are: `sequential` and `concurrent`, or the knob settings where
    /// the solver's schedules are another knob's values (dom: `copies=compute`,
    /// `copies=transfer`).
    pub labels: [String; 2],
}

impl ScheduleComparison {
    /// The comparison of measured spans (ms per repeat): the gain as the ratio of medians,
    /// unless the roles shared one queue; the noise as the larger relative half-range; the gain
    /// significant when it is more than twice the noise away from 1.
    pub fn from_spans(
        sequential: TimelineSummary,
        concurrent: TimelineSummary,
        sequential_ms: Vec<f64>,
        concurrent_ms: Vec<f64>,
        shared_queue: bool,
        images_rel_l2: f64,
    ) -> ScheduleComparison {
        let med = |v: &[f64]| crate::measure::median(v);
        let half_range = |v: &[f64]| {
            let (lo, hi) = v.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| (lo.min(*x), hi.max(*x)));
            if v.len() > 1 && med(v) > 0.0 {
                (hi - lo) / (2.0 * med(v))
            } else {
                0.0
            }
        };
        let noise = half_range(&sequential_ms).max(half_range(&concurrent_ms));
        let ratio = med(&sequential_ms) / med(&concurrent_ms).max(1e-9);
        let gain = (!shared_queue).then_some(ratio);
        let significant = gain.is_some() && sequential_ms.len() > 1 && (ratio - 1.0).abs() > 2.0 * noise;
        ScheduleComparison {
            sequential,
            concurrent,
            sequential_ms,
            concurrent_ms,
            gain,
            noise,
            significant,
            shared_queue,
            images_rel_l2,
            labels: ["sequential".into(), "concurrent".into()],
        }
    }

    /// One line for the terminal.
    pub fn describe(&self) -> String {
        let med = |v: &[f64]| crate::measure::median(v);
        let spans = format!(
            "{} {:.1} ms, {} {:.1} ms (GPU span, median of {})",
            self.labels[0],
            med(&self.sequential_ms),
            self.labels[1],
            med(&self.concurrent_ms),
            self.sequential_ms.len()
        );
        let noise = if self.sequential_ms.len() > 1 {
            format!("run-to-run noise {:.1}%", 100.0 * self.noise)
        } else {
            "run-to-run noise unknown (one repeat)".to_string()
        };
        let verdict = match self.gain {
            None => "one shared queue: no overlap possible, so no concurrency gain to measure".to_string(),
            Some(g) if self.significant => format!("concurrency gain {g:.3}x"),
            Some(g) => format!("concurrency gain {g:.3}x is within the noise: no measurable gain"),
        };
        format!(
            "schedules: {spans}, {noise}; {verdict}; the two images differ by relL2 {:.2e} (must be rounding only)",
            self.images_rel_l2
        )
    }
}

/// Render `req` with `solver` under its two schedules ([`Solver::schedules`]: by default
/// `schedule=sequential` and then `schedule=concurrent`; dom's streaming copies on the
/// compute queue and then on the transfer role's), `repeats` times in turn; returns the last
/// concurrent render (the one kept) and the comparison. The request must not set the knob.
///
/// [`Solver::schedules`]: crate::solvers::Solver::schedules
pub fn compare_schedules(
    gpu: &crate::gpu::Gpu,
    solver: &dyn crate::solvers::Solver,
    req: &crate::solvers::RenderRequest,
    repeats: u32,
) -> Result<(crate::solvers::RenderOutput, ScheduleComparison), crate::solvers::SolverError> {
    use crate::solvers::{RenderRequest, SolverError};
    let Some((knob, apart, overlapped)) = solver.schedules() else {
        return Err(SolverError::Unsupported(format!(
            "solver {} has no queue schedule to compare (no {}.schedule knob)",
            solver.name(),
            solver.name()
        )));
    };
    let key = format!("{}.{knob}", solver.name());
    let run = |value: &str| {
        let settings = req.settings.with(&key, value);
        let r = RenderRequest { settings: &settings, ..*req };
        solver.render(gpu, &r)
    };
    let (mut sequential_ms, mut concurrent_ms) = (Vec::new(), Vec::new());
    let mut last = None;
    for _ in 0..repeats.max(1) {
        let seq = run(apart)?;
        let out = run(overlapped)?;
        let (s, c) = (summarize(&seq.report.passes), summarize(&out.report.passes));
        sequential_ms.push(s.span_ns as f64 * 1e-6);
        concurrent_ms.push(c.span_ns as f64 * 1e-6);
        last = Some((seq, out, s, c));
    }
    let (seq, out, sequential, concurrent) = last.expect("at least one repeat");
    let images_rel_l2 = crate::output::compare(&out.image, &seq.image).map(|m| m.rel_l2).unwrap_or(f64::NAN);
    let shared_queue = gpu.info().mapping.shared();
    let mut c = ScheduleComparison::from_spans(
        sequential,
        concurrent,
        sequential_ms,
        concurrent_ms,
        shared_queue,
        images_rel_l2,
    );
    if knob != "schedule" {
        c.labels = [format!("{key}={apart}"), format!("{key}={overlapped}")];
    }
    Ok((out, c))
}
