//! Parts that several solvers share. Each imports the interface (`crate::solvers::interface`)
//! and other parts, never a solver and never the registry.

pub mod feedback;
pub mod gpu_scene;
pub mod lattice;
pub mod marching;
pub mod probes;
pub mod resumable;
pub mod view;
pub mod wave_field;
