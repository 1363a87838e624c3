//! The embedded SPIR-V of every pass, compiled from `glsl/` by `tools/build-shaders`.

use crate::gpu::ShaderSource;

macro_rules! shader {
    ($name:literal) => {
        ShaderSource {
            name: $name,
            spirv: include_bytes!(concat!(env!("CARGO_MANIFEST_DIR"), "/spirv/", $name, ".spv")),
        }
    };
}

pub const PATH_TRACE: ShaderSource = shader!("path/trace");
pub const PATH_LIGHT: ShaderSource = shader!("path/light");
pub const SINGLE_MARCH: ShaderSource = shader!("single/march");
pub const PROBE_PHASE: ShaderSource = shader!("probe/phase");
pub const LBL_RESAMPLE: ShaderSource = shader!("lbl/resample");
pub const LBL_MARCH: ShaderSource = shader!("lbl/march");
pub const LBL_TRANSFER_FLOAT: ShaderSource = shader!("lbl/transfer_float");
pub const LBL_TRANSFER_FIXED: ShaderSource = shader!("lbl/transfer_fixed");
pub const LBL_INJECT: ShaderSource = shader!("lbl/inject");
pub const LBL_DIFFUSE: ShaderSource = shader!("lbl/diffuse");
pub const WAVEFRONT_RESAMPLE: ShaderSource = shader!("wavefront/resample");
pub const WAVEFRONT_MARCH: ShaderSource = shader!("wavefront/march");
pub const WAVEFRONT_GATHER: ShaderSource = shader!("wavefront/gather");

/// Every shader, for reflection tests.
pub const ALL: &[ShaderSource] = &[
    PATH_TRACE,
    PATH_LIGHT,
    SINGLE_MARCH,
    PROBE_PHASE,
    LBL_RESAMPLE,
    LBL_MARCH,
    LBL_TRANSFER_FLOAT,
    LBL_TRANSFER_FIXED,
    LBL_INJECT,
    LBL_DIFFUSE,
    WAVEFRONT_RESAMPLE,
    WAVEFRONT_MARCH,
    WAVEFRONT_GATHER,
];
