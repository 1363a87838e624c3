//! GPU errors: one line each, naming the device, feature, pass or binding and what to do.

use thiserror::Error;

#[derive(Debug, Error)]
#[non_exhaustive]
pub enum GpuError {
    #[error(
        "cannot load the Vulkan loader ({0}); install it with `tools/setup-deps` (Debian: apt-get install \
        libvulkan1 mesa-vulkan-drivers)"
    )]
    Loader(String),
    #[error(
        "no Vulkan device found; install a driver (CPU fallback: apt-get install mesa-vulkan-drivers) or run \
        `tools/setup-deps`"
    )]
    NoDevice,
    #[error(
        "no Vulkan driver found (vkCreateInstance: ERROR_INCOMPATIBLE_DRIVER){listed}; install one (CPU fallback: \
        apt-get install mesa-vulkan-drivers) or run `tools/setup-deps`"
    )]
    NoDriver { listed: String },
    /// `from`: the flag (`--device`) or environment variable (`SCATTERLAB_DEVICE`) that named it.
    #[error("no Vulkan device matches {}; available: {available}", naming(from, wanted))]
    DeviceNotFound { wanted: String, available: String, from: &'static str },
    #[error("device {device:?} lacks required feature {feature}; {hint}")]
    MissingFeature { device: String, feature: String, hint: String },
    #[error(
        "validation layer VK_LAYER_KHRONOS_validation requested but not installed; install it with `apt-get \
        install vulkan-validationlayers` or run without --validate"
    )]
    NoValidationLayer,
    #[error("Vulkan call {call} failed: {result:?}")]
    Vk { call: &'static str, result: ash::vk::Result },
    #[error(
        "GPU memory allocation for {name:?} ({bytes} bytes) failed: {reason}; lower the grid or image size or \
        --memory-budget"
    )]
    Alloc { name: String, bytes: u64, reason: String },
    #[error(
        "buffer {name:?} of {bytes} bytes exceeds this device's maxStorageBufferRange of {max} bytes; split the \
        data or lower the resolution"
    )]
    BindingTooLarge { name: String, bytes: u64, max: u64 },
    #[error("shader {shader:?}: {reason}")]
    Shader { shader: String, reason: String },
    #[error("pass {pass:?}, binding {binding}: {reason}")]
    Binding { pass: String, binding: u32, reason: String },
    #[error(
        "pass {pass:?} dispatches {groups:?} work groups, past this device's maxComputeWorkGroupCount {max:?}; \
        lower the work per pass (a bug where the solver should have split it: please report the scene)"
    )]
    TooManyGroups { pass: String, groups: [u32; 3], max: [u32; 3] },
    #[error("pass {pass:?}: push constants are {given} bytes but the shader declares {expected}")]
    PushConstants { pass: String, given: usize, expected: usize },
    #[error(
        "host-order rule broken: a submission on role {role} waits on {wait_role} value {value}, but only \
        {submitted} was submitted; submitting it would deadlock a shared queue"
    )]
    WaitBeforeSignal { role: String, wait_role: String, value: u64, submitted: u64 },
    #[error(
        "GPU wait on role {role} for value {value} timed out after {seconds:.0} s (last passes: {passes}); the \
        work may be too large per batch or the device hung; raise SCATTERLAB_GPU_TIMEOUT or lower the batch size"
    )]
    Timeout { role: String, value: u64, seconds: f64, passes: String },
    #[error(
        "device lost while running passes {passes}; the driver reset the GPU (work too long per batch, or a \
        shader fault)"
    )]
    DeviceLost { passes: String },
    /// `choice` as named: `--queues X` or `SCATTERLAB_QUEUES=X` ([`naming`]).
    #[error("{choice}: device {device:?} cannot: {reason}; use --queues auto or shared")]
    Queues { choice: String, device: String, reason: String },
    #[error("buffer {name:?}: read of {wanted} bytes at offset {offset} is outside its {size} bytes")]
    OutOfRange { name: String, offset: u64, wanted: u64, size: u64 },
}

/// A value as the user gave it: `--device x` (quoted where it has spaces) for a flag, `SCATTERLAB_DEVICE=x` for an
/// environment variable (which a user may have set long ago and forgotten).
pub fn naming(from: &str, value: &str) -> String {
    if from.starts_with("--") {
        if value.is_empty() || value.contains(char::is_whitespace) {
            format!("{from} {value:?}")
        } else {
            format!("{from} {value}")
        }
    } else {
        format!("{from}={value}")
    }
}

impl GpuError {
    /// A device not found, said as named by `from` (`--device` or `SCATTERLAB_DEVICE`), where
    /// `choose_device` left it as `--device`; one `--device auto` resolved from a variable
    /// already names that variable, and keeps it.
    pub fn named_by(self, from: &'static str) -> GpuError {
        match self {
            GpuError::DeviceNotFound { wanted, available, from: "--device" } => {
                GpuError::DeviceNotFound { wanted, available, from }
            }
            e => e,
        }
    }
}

pub type Result<T, E = GpuError> = std::result::Result<T, E>;

/// Turn a raw `vk::Result` into a `GpuError` naming the call.
pub(crate) trait VkContext<T> {
    fn vk(self, call: &'static str) -> Result<T>;
}

impl<T> VkContext<T> for std::result::Result<T, ash::vk::Result> {
    fn vk(self, call: &'static str) -> Result<T> {
        self.map_err(|result| GpuError::Vk { call, result })
    }
}
