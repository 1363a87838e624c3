//! The argument helpers every subcommand shares: `--set` pairs, sizes, the device options,
//! output paths and the validation verdict. Below commands, render and animate, which import it
//! (and not one another's helpers: no import circle in cli/).

use std::path::Path;

use anyhow::{anyhow, bail, Result};

use super::GpuArgs;
use crate::gpu::{Gpu, GpuOptions};

/// `KEY=VALUE` pairs, each split once at the first `=`.
pub(super) fn parse_sets(sets: &[String]) -> Result<Vec<(String, String)>> {
    sets.iter()
        .map(|s| match s.split_once('=') {
            Some((k, v)) if !k.trim().is_empty() => Ok((k.trim().to_string(), v.trim().to_string())),
            _ => Err(anyhow!("--set {s:?}: expected KEY=VALUE, e.g. medium.albedo=0.5 or path.max_depth=1")),
        })
        .collect()
}

/// "4G", "512M", "1024" -> bytes.
pub(super) fn parse_bytes(s: &str) -> Result<u64> {
    let t = s.trim();
    let (num, mult) = match t.chars().last() {
        Some('K' | 'k') => (&t[..t.len() - 1], 1u64 << 10),
        Some('M' | 'm') => (&t[..t.len() - 1], 1 << 20),
        Some('G' | 'g') => (&t[..t.len() - 1], 1 << 30),
        _ => (t, 1),
    };
    let v: f64 = num.parse().map_err(|_| anyhow!("--memory-budget {s:?}: expected a size such as 512M or 4G"))?;
    if !(v.is_finite() && v > 0.0) {
        bail!("--memory-budget {s:?}: must be positive");
    }
    Ok((v * mult as f64) as u64)
}

pub(super) fn gpu_options(a: &GpuArgs) -> GpuOptions {
    let mut o = GpuOptions::default();
    if a.validate {
        o.validate = true;
    }
    if a.device.is_some() {
        o.device = a.device.clone();
        o.device_from = "--device";
    }
    if a.queues.is_some() {
        o.queues = a.queues.clone();
        o.queues_from = "--queues";
    }
    if a.no_cache {
        o.cache_dir = None;
    }
    o
}

/// The digest of the scene file `path` as loaded into `scene` ([`crate::scene::content_hash`]):
/// the file is read again, since `Scene` keeps its values, not its text.
pub(super) fn scene_digest(path: &Path, scene: &crate::scene::Scene) -> Result<String> {
    let text = std::fs::read_to_string(path).map_err(|e| anyhow!("{}: {e}", path.display()))?;
    Ok(crate::scene::content_hash(&text, scene))
}

/// Plain progress lines where stderr is not a terminal (a CI log, a batch job's file), where
/// indicatif draws nothing: at most one every `every`, the first after `every`, so a long run
/// is not silent there. Inactive with `quiet` or on a terminal (the bar shows progress there).
pub(super) struct PlainProgress {
    active: bool,
    every: std::time::Duration,
    started: std::time::Instant,
    last: std::cell::Cell<std::time::Instant>,
}

impl PlainProgress {
    pub(super) fn new(quiet: bool, every_s: f64) -> PlainProgress {
        use std::io::IsTerminal;
        let started = std::time::Instant::now();
        PlainProgress {
            active: !quiet && !std::io::stderr().is_terminal(),
            every: std::time::Duration::from_secs_f64(every_s),
            started,
            last: std::cell::Cell::new(started),
        }
    }

    /// Print `text()` as a `progress:` line with the time since the start, if one is due.
    pub(super) fn line(&self, text: &dyn Fn() -> String) {
        if self.active && self.last.get().elapsed() >= self.every {
            self.last.set(std::time::Instant::now());
            eprintln!("progress: {} ({:.1} s)", text(), self.started.elapsed().as_secs_f64());
        }
    }
}

/// The environment variables the GPU options read, checked before any command runs: a value
/// one cannot take is an error naming the variable (set long ago and forgotten, or misspelt),
/// never silently read as something else (SCATTERLAB_VALIDATE=banana turned validation on,
/// SCATTERLAB_GPU_TIMEOUT=5m gave 300 s, SCATTERLAB_SPECIALIZE=drvier specialised on the host).
pub(super) fn check_environment() -> Result<()> {
    use crate::gpu::{QueueChoice, ENV_QUEUES, ENV_SPECIALIZE, ENV_TIMEOUT, ENV_VALIDATE};
    let get = |k: &str| std::env::var(k).ok().filter(|v| !v.is_empty());
    if let Some(v) = get(ENV_VALIDATE) {
        if crate::gpu::validate_from_env(&v).is_none() {
            bail!("{ENV_VALIDATE}={v}: expected 1 (validation layer on) or 0 (off); fix or unset it");
        }
    }
    if let Some(v) = get(ENV_QUEUES) {
        if QueueChoice::parse(&v).is_none() {
            bail!("{ENV_QUEUES}={v}: not a queue mapping; one of {}; fix or unset it", QueueChoice::NAMES.join(", "));
        }
    }
    if let Some(v) = get(ENV_TIMEOUT) {
        if crate::gpu::timeout_from_env(&v).is_none() {
            bail!("{ENV_TIMEOUT}={v}: expected a positive number of seconds (the default is 300); fix or unset it");
        }
    }
    if let Some(v) = get(ENV_SPECIALIZE) {
        if v != "driver" && v != "host" {
            bail!("{ENV_SPECIALIZE}={v}: expected driver or host (the default); fix or unset it");
        }
    }
    Ok(())
}

/// Fail when the validation layer reported errors: a clean run is the contract of every test.
pub(super) fn check_validation(gpu: &Gpu) -> Result<()> {
    let n = gpu.validation_errors();
    if n > 0 {
        bail!(
            "the Vulkan validation layer reported {n} error(s), first: {}",
            gpu.validation_messages().first().cloned().unwrap_or_default()
        );
    }
    Ok(())
}

pub(super) fn check_output_path(p: &Path, what: &str, ext: &[&str]) -> Result<()> {
    let e = p.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase()).unwrap_or_default();
    if !ext.contains(&e.as_str()) {
        bail!("{what} {}: expected a .{} file", p.display(), ext.join(" or ."));
    }
    if let Some(dir) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
        if !dir.is_dir() {
            bail!("{what} {}: directory {} does not exist; create it first", p.display(), dir.display());
        }
    }
    if p.is_dir() {
        bail!("{what} {}: a directory is in the way; choose another file name", p.display());
    }
    Ok(())
}
