//! Solver `path`: the ground truth. A volumetric path tracer on the GPU (glsl/path/trace.comp):
//! delta tracking against a majorant, next-event estimation with ratio tracking, MIS for the
//! environment, spectral tracking for chromatic media, Russian roulette; progressive
//! accumulation in batches, with the per-pixel variance of the mean beside the mean.
//!
//! Knobs (`--set path.KEY=VALUE`):
//! - `max_depth`: scattering events per path (default unbounded; 1 = single scattering);
//! - `batch`: samples per pixel between progress updates (default: about 2^20 pixel-samples);
//! - `budget`: loop iterations per invocation per dispatch (default 4096; the kernel is
//!   resumable, see glsl/include/budget.glsl: llvmpipe silently ends every loop of an
//!   invocation after 65535 iterations, and real GPUs' watchdogs dislike long dispatches);
//! - `collision_cap`: safety cap on tentative collisions per path (default 2^20); a path that
//!   hits it is dropped and counted, and the count is reported as a warning (it biases low).
//! - `equiangular`: `true` (default) samples every point light also by equiangular sampling
//!   along each ray segment in the medium (Kulla & Fajardo 2012, "Importance sampling
//!   techniques for path tracing in participating media"), combined by MIS (power heuristic)
//!   with next-event estimation from the distance-sampled scattering point; this tames the
//!   1/r^2 variance of a point light inside the medium. `false` is plain distance sampling.
//!   Both are unbiased; directional and environment lights are unaffected.

use bytemuck::{Pod, Zeroable};
use serde_json::json;

use crate::gpu::{Gpu, Pass, QueueRole};
use crate::output::Image;

use super::gpu_scene::GpuScene;
use super::{resumable, shaders, RenderOutput, RenderReport, RenderRequest, SolverError, SolverKind};

/// Per pixel: sum of L and the sample count, then sum of L^2 (two vec4), plus the path state.
pub const ACCUM_BYTES_PER_PIXEL: u64 = 32 + STATE_BYTES_PER_PIXEL;

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct PathPush {
    pub sample_end: u32,
    pub budget: u32,
    pub seed_lo: u32,
    pub seed_hi: u32,
    pub max_depth: u32,
    pub collision_cap: u32,
    pub slot: u32,
    /// 1: equiangular sampling of point lights combined with distance sampling by MIS.
    pub equiangular: u32,
}

/// Per-pixel resumable path state (`PathState` in glsl/path/trace.comp).
pub const STATE_BYTES_PER_PIXEL: u64 = 80;


/// `u32::MAX` is "unbounded" for `max_depth`.
pub const UNBOUNDED: u32 = u32::MAX;

/// The mean and the variance of the mean per pixel and channel, from sums of L and L^2.
pub fn mean_and_variance(sums: &[[f32; 4]], width: u32, height: u32) -> (Image, Image) {
    let mut mean = Image::new(width, height);
    let mut var = Image::new(width, height);
    for p in 0..(width * height) as usize {
        let s = sums[2 * p];
        let s2 = sums[2 * p + 1];
        let n = s[3] as f64;
        for c in 0..3 {
            let m = if n > 0.0 { s[c] as f64 / n } else { 0.0 };
            // Sample variance / n; clamped at 0 against round-off in sum2 - n m^2.
            let v = if n > 1.0 { ((s2[c] as f64 - n * m * m) / (n - 1.0)).max(0.0) / n } else { 0.0 };
            mean.data[3 * p + c] = m as f32;
            var.data[3 * p + c] = v as f32;
        }
    }
    (mean, var)
}

pub fn render(gpu: &Gpu, req: &RenderRequest) -> Result<RenderOutput, SolverError> {
    let scene = req.scene;
    let s = req.settings;
    let (w, h) = (scene.render.width, scene.render.height);
    let pixels = w as u64 * h as u64;
    let spp: u32 = s.get("path", "spp", scene.render.spp)?;
    let max_depth_raw: String = s.get("path", "max_depth", "unbounded".to_string())?;
    let max_depth = if max_depth_raw == "unbounded" {
        UNBOUNDED
    } else {
        max_depth_raw.parse::<u32>().map_err(|e| SolverError::Setting {
            key: "path.max_depth".into(),
            reason: format!("cannot parse {max_depth_raw:?}: {e}; give a count of scattering events or `unbounded`"),
        })?
    };
    let default_batch = ((1u64 << 20) / pixels.max(1)).clamp(1, 1024) as u32;
    let batch: u32 = s.get("path", "batch", default_batch)?;
    let budget: u32 = s.get("path", "budget", resumable::DEFAULT_BUDGET)?;
    let collision_cap: u32 = s.get("path", "collision_cap", 1u32 << 20)?;
    let equiangular: bool = s.get("path", "equiangular", true)?;
    s.check_all_used("path")?;
    if spp == 0 || batch == 0 {
        return Err(SolverError::Setting { key: "path.spp/path.batch".into(), reason: "must be at least 1".into() });
    }
    resumable::check_budget("path.budget", budget)?;

    let gs = GpuScene::upload(gpu, scene, req.force_full)?;
    let pipeline = gpu.pipeline(&shaders::PATH_TRACE, &gs.modelled.spec())?;
    let accum = gpu.buffer("path accumulation", pixels * 32)?;
    let state = gpu.buffer("path state", pixels * STATE_BYTES_PER_PIXEL)?;
    let stats = gpu.buffer("path stats", resumable::STATS_WORDS * 4)?;
    let seed = scene.render.seed;

    let mut sample_end = 0u32;
    let mut dispatches = 0u64;
    (req.progress)(0, spp as u64);
    while sample_end < spp {
        sample_end = sample_end.saturating_add(batch).min(spp);
        let (n, _) = resumable::run_until_done(gpu, "path", &stats, |slot| {
            let push = PathPush { sample_end, budget, seed_lo: seed as u32, seed_hi: (seed >> 32) as u32, max_depth, collision_cap, slot, equiangular: equiangular as u32 };
            gs.bind(Pass::new("path.trace", QueueRole::Trace, &pipeline))
                .read_write(3, &accum)
                .read_write(4, &stats)
                .read_write(5, &state)
                .push(&push)
                .cover([w, h, 1])
        })?;
        dispatches += n;
        (req.progress)(sample_end as u64, spp as u64);
    }
    let st: Vec<u32> = gpu.read_buffer_as(&stats)?;
    let truncated = st[0] as u64;
    let segments = st[1] as u64;
    let sums: Vec<[f32; 4]> = gpu.read_buffer_as(&accum)?;
    let (image, variance) = mean_and_variance(&sums, w, h);
    let passes = gpu.take_timings();
    let gpu_ms = super::gpu_ms(&passes);
    let mut warnings = Vec::new();
    if truncated > 0 {
        warnings.push(format!("{truncated} of {} paths hit the collision cap ({collision_cap}) and were dropped; the image is biased low there; raise path.collision_cap", pixels * spp as u64));
    }
    let report = RenderReport {
        solver: SolverKind::Path,
        settings: json!({ "spp": spp, "max_depth": if max_depth == UNBOUNDED { json!("unbounded") } else { json!(max_depth) }, "batch": batch, "budget": budget, "collision_cap": collision_cap, "equiangular": equiangular, "seed": seed }),
        modelled: gs.modelled.clone(),
        device_bytes: gs.bytes + accum.size() + state.size() + stats.size(),
        gpu_ms,
        passes,
        stats: json!({
            "truncated_paths": truncated,
            "dispatches": dispatches,
            "max_loop_iterations": st[2],
            // Counted in 32 bits on the GPU per render; wraps past 4e9 (reported as a lower bound).
            "tracking_steps": segments,
            "samples_per_second": if gpu_ms > 0.0 { (pixels * spp as u64) as f64 / (gpu_ms * 1e-3) } else { 0.0 },
        }),
        warnings,
    };
    Ok(RenderOutput { image, variance: Some(variance), report })
}
