//! A real one-node Slurm (Debian's slurm-wlm, installed by tools/setup-deps), started by our
//! own script in a temporary directory (tools/slurm/local-cluster): tools/slurm/render-passes.sbatch
//! as a 4-task array of sample ranges and a merge job depending on it, whose image must equal a
//! local render of the union. A Slurm that cannot start fails the test with its daemons' logs;
//! it never skips.

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
            let tasks: String = std::fs::read_dir(c.dir.parent().unwrap())
                .unwrap()
                .flatten()
                .filter(|e| e.path().extension().is_some_and(|x| x == "log"))
                .map(|e| {
                    format!("--- {}\n{}", e.path().display(), std::fs::read_to_string(e.path()).unwrap_or_default())
                })
                .collect();
            panic!("a pass failed, so the merge can never run:\n{queue}\n{tasks}\n{}", c.logs());
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
    let task_logs: String = std::fs::read_dir(tmp.path())
        .unwrap()
        .flatten()
        .filter(|e| e.path().extension().is_some_and(|x| x == "log"))
        .map(|e| format!("--- {}\n{}", e.path().display(), std::fs::read_to_string(e.path()).unwrap_or_default()))
        .collect();
    assert!(merged.is_file(), "no merged image:\n{task_logs}\n{}", cluster.logs());
    for (a, b) in [(0, 16), (16, 32), (32, 48), (48, 64)] {
        assert!(out.join(format!("pass-{a}-{b}.exr")).is_file(), "pass {a}..{b} missing:\n{task_logs}");
    }
    // The union, rendered here by one process.
    let all = tmp.path().join("all.exr");
    let mut args = vec!["render", scene_s, "--samples", "0..64", "--out", all.to_str().unwrap()];
    args.extend_from_slice(&flags);
    let st = Command::new(BIN).args(&args).status().unwrap();
    assert!(st.success());
    let (m, u) = (read_exr_layer(&merged, "").unwrap(), read_exr_layer(&all, "").unwrap());
    let peak = u.data.iter().cloned().fold(0f32, f32::max);
    assert!(peak > 0.0);
    let worst =
        m.data.iter().zip(&u.data).map(|(a, b)| ((a - b).abs() / b.abs().max(1e-6 * peak)) as f64).fold(0f64, f64::max);
    assert!(worst <= 1e-6, "the merged image differs from the union by {worst:.3e} relative");
}
