//! Kernels that exist only to test shared GLSL headers on the device (glsl/probe/): they are
//! no solver's, but the reflection test holds them to the same checks.

use bytemuck::{Pod, Zeroable};

use crate::gpu::{Kernel, SpecKind};

use super::gpu_scene::{SPEC_HAS_MESH, SPEC_REFRACTIVE};

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

/// Push constants of glsl/probe/bandwidth.comp.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct BandwidthPush {
    /// vec4s to move.
    pub count: u32,
    /// Invocations in the dispatch (the grid-stride loop's step).
    pub stride: u32,
    pub scale: f32,
    pub pad: u32,
}

/// glsl/probe/bandwidth.comp: the memory bandwidth probe of `scatterlab report`.
pub const BANDWIDTH: Kernel =
    Kernel { shader: shader!("probe/bandwidth"), push_bytes: std::mem::size_of::<BandwidthPush>(), spec: &[] };

/// Push constants of glsl/probe/fresnel.comp.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct FresnelPush {
    /// Cases (cos_i, eta) to evaluate.
    pub count: u32,
}

/// glsl/probe/fresnel.comp: Fresnel reflectance, Snell's law and total internal reflection of
/// glsl/include/dielectric.glsl for tests/refraction_tests.rs.
pub const FRESNEL: Kernel =
    Kernel { shader: shader!("probe/fresnel"), push_bytes: std::mem::size_of::<FresnelPush>(), spec: &[] };

/// Push constants of glsl/probe/bvh.comp.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct BvhPush {
    /// Rays to trace.
    pub count: u32,
}

/// glsl/probe/bvh.comp: the GLSL BVH traversal (glsl/include/mesh.glsl), one ray per
/// invocation, against `Bvh::intersect` in tests/refraction_tests.rs.
pub const BVH: Kernel = Kernel {
    shader: shader!("probe/bvh"),
    push_bytes: std::mem::size_of::<BvhPush>(),
    spec: &[(SPEC_HAS_MESH, SpecKind::Bool), (SPEC_REFRACTIVE, SpecKind::Bool)],
};

/// Push constants of glsl/probe/sh.comp.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct ShPush {
    /// Directions to evaluate.
    pub count: u32,
    /// Spherical-harmonics order (bands 0 .. order - 1).
    pub order: u32,
}

/// glsl/probe/sh.comp: the real spherical harmonics of glsl/include/sh.glsl, against
/// src/physics/sh.rs in tests/sh_tests.rs.
pub const SH: Kernel = Kernel { shader: shader!("probe/sh"), push_bytes: std::mem::size_of::<ShPush>(), spec: &[] };

/// Push constants of glsl/probe/extinction.comp.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct ExtinctionPush {
    /// Optical depths to evaluate.
    pub count: u32,
}

/// glsl/probe/extinction.comp: 1 - exp(-x) and (1 - exp(-x)) / x of
/// glsl/include/one_minus_exp.glsl, against double precision in tests/extinction_gpu.rs.
pub const EXTINCTION: Kernel =
    Kernel { shader: shader!("probe/extinction"), push_bytes: std::mem::size_of::<ExtinctionPush>(), spec: &[] };

/// Every probe kernel.
pub fn kernels() -> Vec<Kernel> {
    vec![PHASE, BANDWIDTH, FRESNEL, BVH, SH, EXTINCTION]
}
