//! A real one-node Slurm (Debian's slurm-wlm, installed by tools/setup-deps), started by our
//! own script in a temporary directory (tools/slurm/local-cluster), running each template of
//! tools/slurm as an array with its merge job depending on it: render-passes.sbatch (sample
//! ranges; the merged image must equal a local render of the union), bench.sbatch (a scene per
//! task; the combined bench must equal one local bench of every scene) and animate-frames.sbatch
//! (frame ranges; each range's frames must equal a local render of that range). A Slurm that
//! cannot start fails the test with its daemons' logs; it never skips.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use scatterlab::output::read_exr_layer;

const BIN: &str = env!("CARGO_BIN_EXE_scatterlab");

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

/// The cluster's daemons, stopped by their recorded process ids when the test ends, also when
/// it fails.
struct Cluster {
    dir: PathBuf,
}

impl Cluster {
    fn start(dir: &Path) -> Cluster {
        let out = Command::new(repo("tools/slurm/local-cluster")).arg("start").arg(dir).output().unwrap();
        let cluster = Cluster { dir: dir.to_owned() };
        assert!(
            out.status.success(),
            "Slurm did not start:\n{}\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        cluster
    }

    fn conf(&self) -> PathBuf {
        self.dir.join("slurm.conf")
    }

    /// A Slurm client command with this cluster's configuration.
    fn client(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        // sbatch passes its environment to the job: the tasks run this build's binary.
        c.env("SLURM_CONF", self.conf()).env("SCATTERLAB", BIN);
        c
    }

    /// The logs, for a failure's message.
    fn logs(&self) -> String {
        let mut s = String::new();
        for e in std::fs::read_dir(&self.dir).unwrap().flatten() {
            let p = e.path();
            if p.extension().is_some_and(|x| x == "log") {
                s += &format!("--- {}\n{}\n", p.display(), std::fs::read_to_string(&p).unwrap_or_default());
            }
        }
        s
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let _ = Command::new(repo("tools/slurm/local-cluster")).arg("stop").arg(&self.dir).status();
    }
}

fn sbatch(c: &Cluster, args: &[&str]) -> String {
    let out = c.client("sbatch").arg("--parsable").args(args).output().unwrap();
    assert!(out.status.success(), "sbatch {args:?}: {}\n{}", String::from_utf8_lossy(&out.stderr), c.logs());
    String::from_utf8_lossy(&out.stdout).trim().split(';').next().unwrap().to_string()
}

/// Wait (at most `limit`) until no job of the cluster is pending or running.
fn wait_idle(c: &Cluster, limit: Duration) {
    let t0 = Instant::now();
    loop {
        let out = c.client("squeue").args(["--noheader", "--format=%i %T %r"]).output().unwrap();
        assert!(out.status.success(), "squeue: {}\n{}", String::from_utf8_lossy(&out.stderr), c.logs());
        let queue = String::from_utf8_lossy(&out.stdout).to_string();
        if queue.trim().is_empty() {
            return;
        }
        // A pass failed: the merge's afterok can never be met. Say so now, not at the limit.
        if queue.contains("DependencyNeverSatisfied") {
            let tasks = task_logs(c.dir.parent().unwrap());
            panic!("a task failed, so the merge can never run:\n{queue}\n{tasks}\n{}", c.logs());
        }
        assert!(
            t0.elapsed() < limit,
            "jobs still queued after {limit:?}:\n{}\n{}",
            String::from_utf8_lossy(&out.stdout),
            c.logs()
        );
        std::thread::sleep(Duration::from_millis(250));
    }
}

/// Every task's log under `dir`, for a failure's message.
fn task_logs(dir: &Path) -> String {
    std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .filter(|e| e.path().extension().is_some_and(|x| x == "log"))
        .map(|e| format!("--- {}\n{}", e.path().display(), std::fs::read_to_string(e.path()).unwrap_or_default()))
        .collect()
}

/// Run this build's binary here, failing with its output when it fails.
fn local(args: &[&str]) -> String {
    let out = Command::new(BIN).args(args).env_remove("SCATTERLAB_DEVICE").output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "scatterlab {args:?}: {stderr}");
    stderr
}

#[test]
fn a_slurm_array_of_sample_ranges_merges_into_the_render_of_their_union() {
    let tmp = tempfile::tempdir().unwrap();
    let cluster = Cluster::start(&tmp.path().join("slurm"));
    let out = tmp.path().join("passes");
    let scene = repo("scenes/homogeneous-sphere.toml");
    let flags = ["--validate", "-q", "--set", "render.width=24", "--set", "render.height=24"];
    let script = repo("tools/slurm/render-passes.sbatch");
    let (script, scene_s, out_s) = (script.to_str().unwrap(), scene.to_str().unwrap(), out.to_str().unwrap());
    let log = format!("--output={}/task-%A_%a.log", tmp.path().display());
    let mut pass_args = vec!["--array=0-3", &log, script, scene_s, out_s, "64"];
    pass_args.extend_from_slice(&flags);
    let t0 = Instant::now();
    let array = sbatch(&cluster, &pass_args);
    let after = format!("--dependency=afterok:{array}");
    let merge_log = format!("--output={}/merge-%j.log", tmp.path().display());
    let merge = sbatch(&cluster, &[&after, &merge_log, script, "--merge", scene_s, out_s, "64"]);
    wait_idle(&cluster, Duration::from_secs(600));
    eprintln!(
        "array {array} and merge {merge}: {:.1} s from submission to the merged image",
        t0.elapsed().as_secs_f64()
    );
    let merged = out.join("merged.exr");
    let task_logs = task_logs(tmp.path());
    assert!(merged.is_file(), "no merged image:\n{task_logs}\n{}", cluster.logs());
    for (a, b) in [(0, 16), (16, 32), (32, 48), (48, 64)] {
        assert!(out.join(format!("pass-{a}-{b}.exr")).is_file(), "pass {a}..{b} missing:\n{task_logs}");
    }
    // The union, rendered here by one process.
    let all = tmp.path().join("all.exr");
    let mut args = vec!["render", scene_s, "--samples", "0..64", "--out", all.to_str().unwrap()];
    args.extend_from_slice(&flags);
    local(&args);
    let (m, u) = (read_exr_layer(&merged, "").unwrap(), read_exr_layer(&all, "").unwrap());
    let peak = u.data.iter().cloned().fold(0f32, f32::max);
    assert!(peak > 0.0);
    let worst =
        m.data.iter().zip(&u.data).map(|(a, b)| ((a - b).abs() / b.abs().max(1e-6 * peak)) as f64).fold(0f64, f64::max);
    assert!(worst <= 1e-6, "the merged image differs from the union by {worst:.3e} relative");
}

fn read_json(p: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))).unwrap()
}

/// tools/slurm/bench.sbatch: one scene per task, then the merge job combines the runs with
/// `bench --replot DIR...`. The combination holds every scene's points, references and plots,
/// and its measured errors are those of one `scatterlab bench` of both scenes in one process
/// (against the same cached references; times differ, errors do not).
#[test]
fn a_slurm_array_of_scenes_benches_into_one_combined_run() {
    let tmp = tempfile::tempdir().unwrap();
    let cluster = Cluster::start(&tmp.path().join("slurm"));
    let out = tmp.path().join("bench");
    let scenes = [repo("scenes/homogeneous-sphere.toml"), repo("scenes/cloud.toml")];
    let scenes: Vec<&str> = scenes.iter().map(|p| p.to_str().unwrap()).collect();
    let flags = [
        "--solvers",
        "path,single",
        "--quick",
        "--ref-spp",
        "32",
        "--repeats",
        "1",
        "--validate",
        "--set",
        "render.width=12",
        "--set",
        "render.height=12",
    ];
    let script = repo("tools/slurm/bench.sbatch");
    let (script, out_s) = (script.to_str().unwrap(), out.to_str().unwrap());
    let log = format!("--output={}/task-%A_%a.log", tmp.path().display());
    let mut args = vec!["--array=0-1", &log, script, out_s];
    args.extend_from_slice(&scenes);
    args.push("--");
    args.extend_from_slice(&flags);
    let t0 = Instant::now();
    let array = sbatch(&cluster, &args);
    let after = format!("--dependency=afterok:{array}");
    let merge_log = format!("--output={}/merge-%j.log", tmp.path().display());
    let mut args = vec![after.as_str(), &merge_log, script, "--merge", out_s];
    args.extend_from_slice(&scenes);
    sbatch(&cluster, &args);
    wait_idle(&cluster, Duration::from_secs(600));
    eprintln!("2 bench tasks and their combination: {:.1} s from submission", t0.elapsed().as_secs_f64());
    let logs = task_logs(tmp.path());
    assert!(out.join("bench.json").is_file(), "no combined bench.json:\n{logs}\n{}", cluster.logs());
    let combined = read_json(&out.join("bench.json"));
    for (name, folder) in [("homogeneous-sphere", "0-homogeneous-sphere"), ("cloud", "1-cloud")] {
        assert!(out.join(format!("{name}.svg")).is_file(), "{name}.svg missing:\n{logs}");
        let own = read_json(&out.join(folder).join("bench.json"));
        let mine: Vec<&serde_json::Value> =
            combined["points"].as_array().unwrap().iter().filter(|p| p["scene"] == name).collect();
        assert_eq!(mine.len(), own["points"].as_array().unwrap().len(), "{name}");
        assert!(!mine.is_empty());
    }
    assert_eq!(combined["references"].as_array().unwrap().len(), 2);
    let csv = std::fs::read_to_string(out.join("bench.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + combined["points"].as_array().unwrap().len());

    // One process benching both scenes, against the references the tasks cached.
    let here = tmp.path().join("here");
    let cache = out.join("references");
    let mut args = vec!["bench"];
    args.extend_from_slice(&scenes);
    args.extend_from_slice(&flags);
    args.extend_from_slice(&["--out", here.to_str().unwrap(), "--cache", cache.to_str().unwrap()]);
    local(&args);
    let one = read_json(&here.join("bench.json"));
    assert!(one["references"].as_array().unwrap().iter().all(|r| r["cached"] == true), "{}", one["references"]);
    let key = |p: &serde_json::Value| format!("{} {} {}={}", p["scene"], p["solver"], p["knob"], p["value"]);
    let (a, b) = (combined["points"].as_array().unwrap(), one["points"].as_array().unwrap());
    assert_eq!(a.iter().map(key).collect::<Vec<_>>(), b.iter().map(key).collect::<Vec<_>>());
    for (x, y) in a.iter().zip(b) {
        for m in ["rel_l2", "energy_ratio", "max_abs_error"] {
            let (u, v) = (x["metrics"][m].as_f64().unwrap(), y["metrics"][m].as_f64().unwrap());
            assert!((u - v).abs() <= 1e-9 * v.abs().max(1e-30), "{} {m}: combined {u} against one process {v}", key(x));
        }
    }
}

/// tools/slurm/animate-frames.sbatch: 2 tasks of 2 frames of networks on the cloud, then the
/// merge job's `merge --csv`. frames.csv holds frames 0-3 in order; each range's frames equal
/// a local `animate --frame-range` of that range (its first frame starts cold, wherever it runs).
#[test]
fn a_slurm_array_of_frame_ranges_renders_each_range_as_one_process_would() {
    let tmp = tempfile::tempdir().unwrap();
    let cluster = Cluster::start(&tmp.path().join("slurm"));
    let out = tmp.path().join("frames");
    let scene = repo("scenes/cloud.toml");
    let flags = [
        "--solver",
        "networks",
        "--orbit-light",
        "10",
        "--no-reference",
        "--validate",
        "--set",
        "render.width=16",
        "--set",
        "render.height=16",
        "--set",
        "networks.particles=128",
        "--set",
        "networks.directions=16",
    ];
    let script = repo("tools/slurm/animate-frames.sbatch");
    let (script, scene_s, out_s) = (script.to_str().unwrap(), scene.to_str().unwrap(), out.to_str().unwrap());
    let log = format!("--output={}/task-%A_%a.log", tmp.path().display());
    let mut args = vec!["--array=0-1", &log, script, scene_s, out_s, "4"];
    args.extend_from_slice(&flags);
    let array = sbatch(&cluster, &args);
    let after = format!("--dependency=afterok:{array}");
    let merge_log = format!("--output={}/merge-%j.log", tmp.path().display());
    sbatch(&cluster, &[&after, &merge_log, script, "--merge", scene_s, out_s, "4"]);
    wait_idle(&cluster, Duration::from_secs(600));
    let logs = task_logs(tmp.path());
    assert!(out.join("frames.csv").is_file(), "no frames.csv:\n{logs}\n{}", cluster.logs());
    let mut csv = csv::Reader::from_path(out.join("frames.csv")).unwrap();
    let frame = csv.headers().unwrap().iter().position(|h| h == "frame").expect("a frame column");
    let frames: Vec<String> = csv.records().map(|r| r.unwrap()[frame].to_string()).collect();
    assert_eq!(frames, ["0", "1", "2", "3"]);
    for (a, b) in [(0, 2), (2, 4)] {
        let here = tmp.path().join(format!("here-{a}-{b}"));
        let range = format!("{a}..{b}");
        let mut args =
            vec!["animate", scene_s, "--frame-range", &range, "--out-dir", here.to_str().unwrap(), "--quiet"];
        args.extend_from_slice(&flags);
        local(&args);
        for f in a..b {
            let name = format!("frame-{f:04}.exr");
            let (x, y) =
                (read_exr_layer(&out.join(&name), "").unwrap(), read_exr_layer(&here.join(&name), "").unwrap());
            let peak = y.data.iter().cloned().fold(0f32, f32::max);
            assert!(peak > 0.0, "{name} is black");
            let worst = x
                .data
                .iter()
                .zip(&y.data)
                .map(|(p, q)| ((p - q).abs() / q.abs().max(1e-6 * peak)) as f64)
                .fold(0f64, f64::max);
            assert!(worst <= 1e-6, "{name}: the array's frame differs from a local render of {range} by {worst:.3e}");
        }
    }
}
