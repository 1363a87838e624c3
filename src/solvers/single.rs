//! Solver `single`: the direct term by camera-ray marching (glsl/single/march.comp) with shadow
//! transmittance to each light and the exact phase function; it converges to
//! `path --set path.max_depth=1` as the step shrinks (tests/solvers.rs). The same march is the
//! view pass of `lbl`, which adds the multiply scattered part from its lattice.
//!
//! Knobs (`--set single.KEY=VALUE`; `lbl` reads the same ones as `lbl.KEY`):
//! - `step`: camera-ray step in scene units (default: 1/128 of the medium's diagonal);
//! - `shadow_step`: shadow-ray step (default: `step`);
//! - `env_dirs`: quadrature directions for environment in-scattering (default 16: each costs a
//!   shadow march per camera step, the dominant cost on grids);
//! - `supersample`: n x n subpixel rays, box filter (default 1);
//! - `jitter`: 1 to jitter step origins per pixel (noise instead of banding; default 0);
//! - `budget`: loop iterations per invocation per dispatch (resumable kernel, default 4096).

use bytemuck::{Pod, Zeroable};
use serde_json::json;

use crate::gpu::{Buffer, Gpu, Pass, QueueRole};
use crate::output::Image;
use crate::scene::Scene;

use super::gpu_scene::GpuScene;
use super::{resumable, shaders, RenderOutput, RenderReport, RenderRequest, Settings, SolverError, SolverKind};

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
    /// 1: the multiple-scattering volume carries the vector irradiance after the fluence.
    pub ms_flux: u32,
    pub pad: [u32; 2],
    /// `lbl`: lattice voxels xyz and channels (x = 0: no multiple-scattering volume).
    pub ms_dims: [u32; 4],
    /// `lbl`: lattice min corner and voxel edge lambda.
    pub ms_origin: [f32; 4],
}

/// Per-pixel resumable march state (`MarchState` in glsl/single/march.comp).
pub const STATE_BYTES_PER_PIXEL: u64 = 64;
/// Longest shadow march (steps across the medium's diagonal) a single loop may take.
pub const MAX_SHADOW_STEPS: f32 = 16384.0;

/// The camera-ray march's knobs.
#[derive(Clone, Copy, Debug)]
pub struct ViewSettings {
    pub step: f32,
    pub shadow_step: f32,
    pub env_dirs: u32,
    pub supersample: u32,
    pub jitter: u32,
    pub budget: u32,
}

impl ViewSettings {
    /// Read `<solver>.<prefix>step` etc., with defaults scaled to the medium (`single` uses no
    /// prefix, `lbl` uses `view_`, its own `step` being the photon-marching step).
    pub fn parse(s: &Settings, solver: &str, prefix: &str, scene: &Scene) -> Result<ViewSettings, SolverError> {
        let diag = (scene.medium.bounds_max - scene.medium.bounds_min).length();
        let key = |k: &str| format!("{prefix}{k}");
        let step: f32 = s.get(solver, &key("step"), diag / 128.0)?;
        let v = ViewSettings {
            step,
            shadow_step: s.get(solver, &key("shadow_step"), step)?,
            env_dirs: s.get(solver, &key("env_dirs"), 16)?,
            supersample: s.get(solver, &key("supersample"), 1)?,
            jitter: s.get(solver, &key("jitter"), 0)?,
            budget: s.get(solver, &key("budget"), resumable::DEFAULT_BUDGET)?,
        };
        resumable::check_budget(&format!("{solver}.{}", key("budget")), v.budget)?;
        for (k, x) in [("step", v.step), ("shadow_step", v.shadow_step)] {
            let key = key(k);
            if !(x.is_finite() && x > 0.0) {
                return Err(SolverError::Setting {
                    key: format!("{solver}.{key}"),
                    reason: format!("{x} must be a positive length in scene units"),
                });
            }
            // A shadow march runs in one loop (it cannot be split across dispatches), so its
            // length is bounded; camera-ray steps are resumable and only bounded for sanity.
            let max_steps = if k == "shadow_step" { MAX_SHADOW_STEPS } else { 1e7 };
            if diag / x > max_steps {
                return Err(SolverError::Setting {
                    key: format!("{solver}.{key}"),
                    reason: format!(
                        "{x} gives over {max_steps} steps across the medium's diagonal {diag}; use a larger step"
                    ),
                });
            }
        }
        if v.env_dirs == 0 || v.supersample == 0 || v.supersample > 16 {
            return Err(SolverError::Setting {
                key: format!("{solver}.{}/{solver}.{}", key("env_dirs"), key("supersample")),
                reason: "env_dirs must be >= 1 and supersample in 1..=16".into(),
            });
        }
        Ok(v)
    }

    pub fn json(&self) -> serde_json::Value {
        json!({ "step": self.step, "shadow_step": self.shadow_step, "env_dirs": self.env_dirs, "supersample": self.supersample, "jitter": self.jitter, "budget": self.budget })
    }
}

/// A multiply scattered energy volume for the view pass (`lbl`'s lattice result).
pub struct MsVolume<'a> {
    pub energy: &'a Buffer,
    pub dims: [u32; 3],
    pub channels: u32,
    pub origin: [f32; 3],
    pub lambda: f32,
    /// The vector irradiance follows the fluence (`wavefront`'s two-term expansion).
    pub flux: bool,
}

/// What one view march did.
pub struct ViewResult {
    pub image: Image,
    pub dispatches: u64,
    pub max_loop_iterations: u32,
    pub nonfinite_pixels: u32,
    pub device_bytes: u64,
}

/// March camera rays through the medium: single scattering with the exact phase function,
/// plus, when `ms` is given, the multiply scattered in-scattering from it.
pub fn march_view(
    gpu: &Gpu,
    scene: &Scene,
    gs: &GpuScene,
    v: &ViewSettings,
    ms: Option<&MsVolume>,
) -> Result<ViewResult, SolverError> {
    let (w, h) = (scene.render.width, scene.render.height);
    let pipeline = gpu.pipeline(&shaders::SINGLE_MARCH, &gs.modelled.spec())?;
    let pixels = w as u64 * h as u64;
    let out = gpu.buffer("view radiance", pixels * 16)?;
    // Every pixel starts at subsample 0, step 0, with transmittance 1.
    let mut init = [0f32; 16];
    init[..3].copy_from_slice(&[1.0; 3]);
    let state = gpu.buffer_with("view state", &vec![init; pixels as usize])?;
    let stats = gpu.buffer("view stats", resumable::STATS_WORDS * 4)?;
    let dummy;
    let (ms_buf, ms_dims, ms_origin, ms_flux) = match ms {
        Some(m) => (
            m.energy,
            [m.dims[0], m.dims[1], m.dims[2], m.channels],
            [m.origin[0], m.origin[1], m.origin[2], m.lambda],
            m.flux as u32,
        ),
        None => {
            dummy = gpu.buffer("no ms volume", 4)?;
            (&dummy, [0; 4], [0.0; 4], 0)
        }
    };
    let seed = scene.render.seed;
    let (dispatches, st) = resumable::run_until_done(gpu, "view", &stats, |slot| {
        let push = SinglePush {
            step: v.step,
            shadow_step: v.shadow_step,
            env_dirs: v.env_dirs,
            jitter: v.jitter,
            seed_lo: seed as u32,
            seed_hi: (seed >> 32) as u32,
            supersample: v.supersample,
            budget: v.budget,
            slot,
            ms_flux,
            pad: [0; 2],
            ms_dims,
            ms_origin,
        };
        gs.bind(Pass::new("view.march", QueueRole::Trace, &pipeline))
            .write(3, &out)
            .read_write(4, &stats)
            .read_write(5, &state)
            .read(6, ms_buf)
            .push(&push)
            .cover([w, h, 1])
    })?;
    let px: Vec<[f32; 4]> = gpu.read_buffer_as(&out)?;
    let mut image = Image::new(w, h);
    for (i, p) in px.iter().enumerate() {
        image.data[3 * i..3 * i + 3].copy_from_slice(&p[..3]);
    }
    Ok(ViewResult {
        image,
        dispatches,
        max_loop_iterations: st[2],
        nonfinite_pixels: st[0],
        device_bytes: out.size() + state.size() + stats.size(),
    })
}

pub fn render(gpu: &Gpu, req: &RenderRequest) -> Result<RenderOutput, SolverError> {
    let scene = req.scene;
    let v = ViewSettings::parse(req.settings, "single", "", scene)?;
    req.settings.check_all_used("single")?;
    let gs = GpuScene::upload(gpu, scene, req.force_full)?;
    (req.progress)(0, 1);
    let view = march_view(gpu, scene, &gs, &v, None)?;
    (req.progress)(1, 1);
    let passes = gpu.take_timings();
    let report = RenderReport {
        solver: SolverKind::Single,
        settings: v.json(),
        modelled: gs.modelled.clone(),
        device_bytes: gs.bytes + view.device_bytes,
        gpu_ms: super::gpu_ms(&passes),
        passes,
        stats: json!({ "dispatches": view.dispatches, "max_loop_iterations": view.max_loop_iterations, "nonfinite_pixels": view.nonfinite_pixels }),
        warnings: if view.nonfinite_pixels > 0 {
            vec![format!(
                "{} pixels were not finite and were set to 0 (a bug: please report the scene)",
                view.nonfinite_pixels
            )]
        } else {
            Vec::new()
        },
    };
    Ok(RenderOutput { image: view.image, variance: None, report })
}
