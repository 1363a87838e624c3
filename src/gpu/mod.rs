//! The Vulkan core: the only module with `unsafe` ash calls. It knows nothing of scenes,
//! physics or solvers: it opens a device, maps queue roles, allocates buffers and 3D images,
//! builds pipelines from reflected SPIR-V, and submits passes described as data.

mod cache;
mod context;
mod error;
mod host;
mod memory;
mod pipeline;
mod present;
mod queues;
mod setup;
pub mod specialize;
mod submit;

pub use cache::{default_cache_dir, PipelineCacheStatus, ENV_CACHE_DIR};
pub use context::{
    auto_device, choose_device, list_devices, timeout_from_env, validate_from_env, DeviceInfo, DeviceSummary, Gpu,
    GpuOptions, ENV_DEVICE, ENV_QUEUES, ENV_SPECIALIZE, ENV_TIMEOUT, ENV_VALIDATE,
};
pub use error::{GpuError, Result};
pub use host::{HostCost, HostTimes};
pub use memory::{Buffer, Image3d, VolumeFormat};
pub use pipeline::{reflect, BindingKind, Kernel, Pipeline, PipelineRecord, Reflection, ShaderSource, Spec, SpecKind};
pub use present::{surface_extensions, tonemap_on_device, Presenter, Shown, TONEMAP};
pub use queues::{
    map_roles, map_roles_as, map_roles_named, FamilyInfo, MappingKind, QueueChoice, QueueRole, QueueSlot, RoleMapping,
};
pub use submit::{Access, Bind, Copy, Pass, PassTiming, Resource, SyncPoint};
