//! The embedded SPIR-V of every pass, compiled from `glsl/` by `tools/build-shaders`.

use crate::gpu::ShaderSource;

macro_rules! shader {
    ($name:literal) => {
        ShaderSource { name: $name, spirv: include_bytes!(concat!(env!("CARGO_MANIFEST_DIR"), "/spirv/", $name, ".spv")) }
    };
}

pub const PATH_TRACE: ShaderSource = shader!("path/trace");
pub const SINGLE_MARCH: ShaderSource = shader!("single/march");
pub const PROBE_PHASE: ShaderSource = shader!("probe/phase");

/// Every shader, for reflection tests.
pub const ALL: &[ShaderSource] = &[PATH_TRACE, SINGLE_MARCH, PROBE_PHASE];
