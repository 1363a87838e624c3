//! Physics: phase functions, CPU reference kernels and the statistics that judge sampling code.
//!
//! Everything here is plain Rust with no GPU dependency. The GLSL kernels in `glsl/include`
//! restate `phase` with the same formulas; `geometry` serves solvers and tests alike; the rest
//! (`reference`, `chandrasekhar`, `stats`) are the exact answers and the tests that GPU
//! results are held to, and production code does not use them.

pub mod angular;
pub mod blackbody;
pub mod chandrasekhar;
pub mod dielectric;
pub mod geometry;
pub mod ordinates;
pub mod phase;
pub mod quadrature;
pub mod reference;
pub mod rng;
pub mod sh;
pub mod stats;
