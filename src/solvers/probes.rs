//! Kernels that exist only to test shared GLSL headers on the device (glsl/probe/): they are
//! no solver's, but the reflection test holds them to the same checks.

use bytemuck::{Pod, Zeroable};

use crate::gpu::Kernel;

/// Push constants of glsl/probe/phase.comp.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct PhasePush {
    /// Henyey-Greenstein g.
    pub g: f32,
    /// Directions to sample.
    pub count: u32,
    /// Cosines to evaluate the phase function at.
    pub eval_count: u32,
    pub seed: u32,
}

/// glsl/probe/phase.comp: evaluates and samples the Henyey-Greenstein code of
/// glsl/include/phase.glsl for tests/phase_gpu.rs.
pub const PHASE: Kernel =
    Kernel { shader: shader!("probe/phase"), push_bytes: std::mem::size_of::<PhasePush>(), spec: &[] };

/// Every probe kernel.
pub fn kernels() -> Vec<Kernel> {
    vec![PHASE]
}
