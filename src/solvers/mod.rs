//! Solvers: each turns a scene into radiance toward the camera, in the same units as `path`,
//! by describing passes for the `gpu` layer. They never record barriers or semaphore waits.
//!
//! Three layers, each importing only the ones below it:
//! - [`interface`]: the [`Solver`] trait, the render request and report, stats, knob tables and
//!   what a render modelled; it imports no solver and no part.
//! - [`parts`]: what several solvers share, in a folder of its own: [`parts::gpu_scene`] (the
//!   scene on the device), [`parts::view`] (the camera-ray march), [`parts::marching`] (photon
//!   marching into voxel sums), [`parts::lattice`] (the Lattice-Boltzmann lattice),
//!   [`parts::wave_field`] (spherical-layer wavefront tracing), [`parts::resumable`] (kernels
//!   that yield under llvmpipe's loop limit), [`parts::feedback`] and [`parts::probes`]. A part
//!   never imports a solver.
//! - one folder per solver (`path/`, `single/`, ...) holding its private helpers (`path/mnee.rs`,
//!   `dom/{blocks,ordinates}.rs`), mirroring `glsl/`.
//!
//! This file is the registry above them: every solver is one line in [`SOLVERS`]. The CLI and
//! `measure` know solvers only through the interface and the registry.
//! `docs/architecture.md` has the checklist for adding a solver.

/// An embedded, compiled shader: `glsl/<folder>/<pass>.comp` as `spirv/<folder>/<pass>.spv`
/// (compiled by `tools/build-shaders`).
macro_rules! shader {
    ($name:literal) => {
        crate::gpu::ShaderSource {
            name: $name,
            spirv: include_bytes!(concat!(env!("CARGO_MANIFEST_DIR"), "/spirv/", $name, ".spv")),
        }
    };
}

pub mod interface;
pub mod parts;

pub mod dom;
pub mod lbl;
pub mod networks;
pub mod octaves;
pub mod path;
pub mod sh_single;
pub mod single;
pub mod wavefront;

use crate::gpu::Kernel;
use crate::scene::Scene;

// What the CLI, `measure` and the tests use of the interface, named from the registry.
pub use interface::knobs::{self, Knob, Knobs, Range, Settings};
pub use interface::modelled::Modelled;
pub use interface::{
    materials_unsupported, memory_estimate, meshes_unsupported, Animation, Convergence, Detail, Estimate, Figure,
    Headline, PipelineUse, Progress, RenderOutput, RenderReport, RenderRequest, Rung, Schedule, Solver, SolverError,
    Stats, Variant,
};

/// Every solver this build ships, in the order they are listed and benched. Adding a solver
/// is one line here (plus its own file and shader folder): `docs/architecture.md`.
pub static SOLVERS: &[&dyn Solver] = &[
    &path::Path,
    &single::Single,
    &lbl::Lbl,
    &wavefront::Wavefront,
    &octaves::OctavesSolver,
    &dom::Dom,
    &networks::Networks,
    &sh_single::ShSingle,
];

/// The registered solver called `name`.
pub fn find(name: &str) -> Result<&'static dyn Solver, SolverError> {
    SOLVERS.iter().copied().find(|s| s.name() == name).ok_or_else(|| {
        SolverError::Unsupported(format!("unknown solver {name:?}; this build has {}", names().join(", ")))
    })
}

/// The names of every registered solver.
pub fn names() -> Vec<&'static str> {
    SOLVERS.iter().map(|s| s.name()).collect()
}

/// Every kernel of every registered solver, of the test probes and of the view's tone map, each
/// shader once.
pub fn kernels() -> Vec<Kernel> {
    let mut out: Vec<Kernel> = Vec::new();
    // The view's tone map is the one kernel outside the solvers and their probes.
    for k in SOLVERS.iter().flat_map(|s| s.kernels()).chain(parts::probes::kernels()).chain([crate::gpu::TONEMAP]) {
        if !out.iter().any(|o| o.shader.name == k.shader.name) {
            out.push(k);
        }
    }
    out
}

/// The ground truth (`path`).
pub fn reference() -> &'static dyn Solver {
    *SOLVERS.iter().find(|s| s.is_reference()).expect("one registered solver is the reference")
}

/// The memory estimate of each of `solvers` for `scene` (`scene info`).
pub fn memory_table(
    scene: &Scene,
    solvers: &[&dyn Solver],
    settings: &Settings,
) -> Result<Vec<(&'static str, u64)>, SolverError> {
    solvers.iter().map(|s| Ok((s.name(), memory_estimate(*s, scene, settings)?))).collect()
}

/// Check knob settings for any of `solvers` before work starts: every key names one of them
/// and a knob of its table, with a value in range.
pub fn check_settings(settings: &Settings, solvers: &[&dyn Solver]) -> Result<(), SolverError> {
    for (key, _) in settings.pairs() {
        let owner = key.split('.').next().unwrap_or("");
        if !solvers.iter().any(|s| s.name() == owner) {
            let names: Vec<&str> = solvers.iter().map(|s| s.name()).collect();
            return Err(SolverError::Setting {
                key: key.to_string(),
                reason: format!(
                    "unknown key; scene keys start with render., camera., medium., object. or light., solver knobs with a \
                        solver name ({})",
                    names.join(", ")
                ),
            });
        }
    }
    for s in solvers {
        settings.only(s.name()).knobs(s.name(), s.knobs())?;
    }
    Ok(())
}
