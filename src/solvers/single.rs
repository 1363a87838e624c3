//! Solver `single`: the direct term by camera-ray marching (glsl/single/march.comp) with shadow
//! transmittance to each light and the exact phase function; it converges to
//! `path --set path.max_depth=1` as the step shrinks (tests/solvers.rs).
//!
//! Knobs (`--set single.KEY=VALUE`):
//! - `step`: camera-ray step in scene units (default: 1/128 of the medium's diagonal);
//! - `shadow_step`: shadow-ray step (default: `step`);
//! - `env_dirs`: quadrature directions for environment in-scattering (default 64);
//! - `supersample`: n x n subpixel rays, box filter (default 2);
//! - `jitter`: 1 to jitter step origins per pixel (noise instead of banding; default 0);
//! - `budget`: loop iterations per invocation per dispatch (resumable kernel, default 4096).

use bytemuck::{Pod, Zeroable};
use serde_json::json;

use crate::gpu::{Pass, QueueRole};
use crate::output::Image;

use super::gpu_scene::GpuScene;
use super::{resumable, shaders, RenderOutput, RenderReport, RenderRequest, SolverError, SolverKind};
use crate::gpu::Gpu;

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct SinglePush {
    pub step: f32,
    pub shadow_step: f32,
    pub env_dirs: u32,
    pub jitter: u32,
    pub seed_lo: u32,
    pub seed_hi: u32,
    pub supersample: u32,
    pub budget: u32,
    pub slot: u32,
    pub pad: [u32; 3],
}

/// Per-pixel resumable march state (`MarchState` in glsl/single/march.comp).
pub const STATE_BYTES_PER_PIXEL: u64 = 64;
/// Longest shadow march (steps across the medium's diagonal) a single loop may take.
pub const MAX_SHADOW_STEPS: f32 = 16384.0;

pub fn render(gpu: &Gpu, req: &RenderRequest) -> Result<RenderOutput, SolverError> {
    let scene = req.scene;
    let s = req.settings;
    let (w, h) = (scene.render.width, scene.render.height);
    let diag = (scene.medium.bounds_max - scene.medium.bounds_min).length();
    let step: f32 = s.get("single", "step", diag / 128.0)?;
    let shadow_step: f32 = s.get("single", "shadow_step", step)?;
    let env_dirs: u32 = s.get("single", "env_dirs", 64)?;
    let supersample: u32 = s.get("single", "supersample", 2)?;
    let jitter: u32 = s.get("single", "jitter", 0)?;
    let budget: u32 = s.get("single", "budget", resumable::DEFAULT_BUDGET)?;
    s.check_all_used("single")?;
    resumable::check_budget("single.budget", budget)?;
    for (key, v) in [("single.step", step), ("single.shadow_step", shadow_step)] {
        if !(v.is_finite() && v > 0.0) {
            return Err(SolverError::Setting { key: key.into(), reason: format!("{v} must be a positive length in scene units") });
        }
        // A shadow march runs in one loop (it cannot be split across dispatches), so its length
        // is bounded; camera-ray steps are resumable and only bounded for sanity.
        let max_steps = if key == "single.shadow_step" { MAX_SHADOW_STEPS } else { 1e7 };
        if diag / v > max_steps {
            return Err(SolverError::Setting { key: key.into(), reason: format!("{v} gives over {max_steps} steps across the medium's diagonal {diag}; use a larger step") });
        }
    }
    if env_dirs == 0 || supersample == 0 || supersample > 16 {
        return Err(SolverError::Setting { key: "single.env_dirs/single.supersample".into(), reason: "env_dirs must be >= 1 and supersample in 1..=16".into() });
    }

    let gs = GpuScene::upload(gpu, scene, req.force_full)?;
    let pipeline = gpu.pipeline(&shaders::SINGLE_MARCH, &gs.modelled.spec())?;
    let pixels = w as u64 * h as u64;
    let out = gpu.buffer("single radiance", pixels * 16)?;
    // Every pixel starts at subsample 0, step 0, with transmittance 1.
    let init: Vec<[f32; 16]> = vec![[1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]; pixels as usize];
    let state = gpu.buffer_with("single state", &init)?;
    let stats = gpu.buffer("single stats", resumable::STATS_WORDS * 4)?;
    let seed = scene.render.seed;
    (req.progress)(0, 1);
    let (dispatches, st) = resumable::run_until_done(gpu, "single", &stats, |slot| {
        let push = SinglePush { step, shadow_step, env_dirs, jitter, seed_lo: seed as u32, seed_hi: (seed >> 32) as u32, supersample, budget, slot, pad: [0; 3] };
        gs.bind(Pass::new("single.march", QueueRole::Trace, &pipeline))
            .write(3, &out)
            .read_write(4, &stats)
            .read_write(5, &state)
            .push(&push)
            .cover([w, h, 1])
    })?;
    (req.progress)(1, 1);
    let px: Vec<[f32; 4]> = gpu.read_buffer_as(&out)?;
    let mut image = Image::new(w, h);
    for (i, p) in px.iter().enumerate() {
        image.data[3 * i..3 * i + 3].copy_from_slice(&p[..3]);
    }
    let passes = gpu.take_timings();
    let report = RenderReport {
        solver: SolverKind::Single,
        settings: json!({ "step": step, "shadow_step": shadow_step, "env_dirs": env_dirs, "supersample": supersample, "jitter": jitter, "budget": budget }),
        modelled: gs.modelled.clone(),
        device_bytes: gs.bytes + out.size() + state.size() + stats.size(),
        gpu_ms: super::gpu_ms(&passes),
        passes,
        stats: json!({ "dispatches": dispatches, "max_loop_iterations": st[2], "nonfinite_pixels": st[0] }),
        warnings: if st[0] > 0 { vec![format!("{} pixels were not finite and were set to 0 (a bug: please report the scene)", st[0])] } else { Vec::new() },
    };
    Ok(RenderOutput { image, variance: None, report })
}
