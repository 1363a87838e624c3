//! scatterlab: multiple scattering in heterogeneous participating media on any Vulkan device.
//!
//! Layers, each importing only those below it (`docs/architecture.md`):
//! `cli` -> `measure` -> `solvers` -> `scene`, `physics` -> `gpu`, `output`.
//! `gpu` is the only module with `unsafe` Vulkan calls and knows nothing of scenes or physics.
//! Solvers implement one interface (`solvers::Solver`) and are registered by one line in
//! `solvers::SOLVERS`; `cli` and `measure` know them only through it.

pub mod cli;
pub mod gpu;
pub mod measure;
pub mod output;
pub mod physics;
pub mod scene;
pub mod solvers;

/// The build's identity: 12 hex digits of a SHA-256 over the files it was built from (src/,
/// spirv/, Cargo.toml, Cargo.lock; `build.rs`). Recorded in every output's provenance beside
/// the version, and part of every cache key of a rendered reference.
pub const BUILD: &str = env!("SCATTERLAB_BUILD");
