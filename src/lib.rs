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

/// The identity of what a `path` render is a function of (`build.rs`): [`BUILD`] without the
/// other solvers, the shared parts `path` does not import ([`REFERENCE_PARTS`]), the CLI,
/// `measure` and the SPIR-V folders `path` never runs ([`REFERENCE_EXCLUDED_SPIRV`]). The key of a kept `path` reference: a fix to `lbl` leaves the
/// tests' references valid, a fix to the tracer, the scene code or the GPU layer does not.
pub const REFERENCE_BUILD: &str = env!("SCATTERLAB_REFERENCE_BUILD");

/// The folders of `spirv/` left out of [`REFERENCE_BUILD`], comma-separated: none holds a kernel
/// `path` runs (tests/registry_tests.rs).
pub const REFERENCE_EXCLUDED_SPIRV: &str = env!("SCATTERLAB_REFERENCE_EXCLUDED_SPIRV");

/// The files of `src/solvers/parts/` kept in [`REFERENCE_BUILD`], comma-separated: the parts
/// `path` imports, directly or through another part (tests/registry_tests.rs).
pub const REFERENCE_PARTS: &str = env!("SCATTERLAB_REFERENCE_PARTS");
