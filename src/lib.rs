//! scatterlab: multiple scattering in heterogeneous participating media on any Vulkan device.
//!
//! Layers, each importing only those below it (see `docs/architecture.md`):
//! `measure` -> `solvers` -> `scene`, `physics` -> `gpu`, `output`.
//! `gpu` is the only module with `unsafe` Vulkan calls and knows nothing of scenes or physics.

pub mod cli;
pub mod gpu;
pub mod measure;
pub mod output;
pub mod physics;
pub mod scene;
pub mod solvers;
