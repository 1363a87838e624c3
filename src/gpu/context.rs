//! Instance, validation, device choice and queue roles: everything created once per run.

use std::ffi::{c_void, CStr, CString};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use ash::vk;
use gpu_allocator::vulkan::{Allocator, AllocatorCreateDesc};
use serde::Serialize;

use super::error::{GpuError, Result, VkContext};
use super::queues::{map_roles, FamilyInfo, QueueRole, RoleMapping};

/// Environment variables, read when the corresponding option is not given.
pub const ENV_VALIDATE: &str = "SCATTERLAB_VALIDATE";
pub const ENV_DEVICE: &str = "SCATTERLAB_DEVICE";
pub const ENV_TIMEOUT: &str = "SCATTERLAB_GPU_TIMEOUT";
pub const ENV_QUEUES: &str = "SCATTERLAB_QUEUES";
/// `driver`: hand the driver every kernel as compiled, with specialization info
/// ([`GpuOptions::driver_specialization`]).
pub const ENV_SPECIALIZE: &str = "SCATTERLAB_SPECIALIZE";

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

/// How to open the GPU.
#[derive(Clone, Debug)]
pub struct GpuOptions {
    /// Khronos validation layer with synchronization validation and a messenger that counts errors.
    pub validate: bool,
    /// Device index or case-insensitive name substring; `None` picks the best device.
    pub device: Option<String>,
    /// Where `device` and `queues` came from, for messages: the flag (`--device`, `--queues`)
    /// or the environment variable ([`ENV_DEVICE`], [`ENV_QUEUES`]), the default's source.
    pub device_from: &'static str,
    pub queues_from: &'static str,
    /// Limit on every host wait; a wait that runs past it fails loudly instead of hanging.
    pub timeout: Duration,
    /// The queue mapping asked for (`auto`, `shared`, `same-family`, `separate-families`);
    /// `None` is `auto`. Checked when the device opens.
    pub queues: Option<String>,
    /// Directory of the persistent pipeline cache (super::cache); `None`: in memory only
    /// (`--no-cache`).
    pub cache_dir: Option<std::path::PathBuf>,
    /// Open the device as if it lacked `shaderFloat64`: the solvers then test convergence on
    /// the host, as on such devices (tests compare the two).
    pub without_float64: bool,
    /// Treat device-local memory as if the host could not map it (a discrete GPU without
    /// resizable BAR), so that lavapipe takes the staged uploads and device fills such GPUs
    /// take (tests compare the two).
    pub unmapped_device_memory: bool,
    /// Let the driver specialise each kernel (the SPIR-V as compiled plus specialization info)
    /// instead of the host (super::specialize: constants frozen, decided branches removed, the
    /// same program; lavapipe builds it 1.5-16x faster). A check on the host pass.
    pub driver_specialization: bool,
    /// Open for presentation to a window (`scatterlab view`): these instance extensions (the
    /// surface's: `gpu::surface_extensions`) and the device extension `VK_KHR_swapchain`.
    /// `None`: headless, as every other command.
    pub presentation: Option<Vec<&'static std::ffi::CStr>>,
}

impl Default for GpuOptions {
    /// Validation from `SCATTERLAB_VALIDATE=1`, device from `SCATTERLAB_DEVICE`, timeout from
    /// `SCATTERLAB_GPU_TIMEOUT` (seconds, default 300), queue mapping from `SCATTERLAB_QUEUES`,
    /// pipeline cache directory from `SCATTERLAB_CACHE_DIR` or the user's cache directory,
    /// driver specialization from `SCATTERLAB_SPECIALIZE=driver`.
    fn default() -> Self {
        // A value it cannot take (the CLI refuses it first) turns validation on: the safer side.
        let validate = std::env::var(ENV_VALIDATE).is_ok_and(|v| !v.is_empty() && validate_from_env(&v) != Some(false));
        let device = std::env::var(ENV_DEVICE).ok().filter(|s| !s.is_empty());
        let secs = std::env::var(ENV_TIMEOUT).ok().and_then(|s| timeout_from_env(&s)).unwrap_or(300.0);
        let queues = std::env::var(ENV_QUEUES).ok().filter(|s| !s.is_empty());
        let cache_dir = super::cache::default_cache_dir();
        GpuOptions {
            validate,
            device,
            device_from: ENV_DEVICE,
            queues_from: ENV_QUEUES,
            timeout: Duration::from_secs_f64(secs),
            queues,
            cache_dir,
            without_float64: false,
            unmapped_device_memory: false,
            driver_specialization: std::env::var(ENV_SPECIALIZE).is_ok_and(|v| v == "driver"),
            presentation: None,
        }
    }
}

/// `SCATTERLAB_VALIDATE`'s value: 1/true/yes/on or 0/false/no/off (any case); `None` for
/// anything else.
pub fn validate_from_env(v: &str) -> Option<bool> {
    match v.trim().to_ascii_lowercase().as_str() {
        "1" | "true" | "yes" | "on" => Some(true),
        "0" | "false" | "no" | "off" => Some(false),
        _ => None,
    }
}

/// `SCATTERLAB_GPU_TIMEOUT`'s value: a finite number of seconds > 0; `None` for anything else
/// (`inf` too, which `Duration::from_secs_f64` cannot hold).
pub fn timeout_from_env(v: &str) -> Option<f64> {
    v.trim().parse::<f64>().ok().filter(|s| s.is_finite() && *s > 0.0)
}

/// Counts validation messages; error-severity messages fail a test run.
#[derive(Default)]
pub struct ValidationLog {
    pub errors: AtomicU64,
    pub warnings: AtomicU64,
    pub first_errors: Mutex<Vec<String>>,
    /// While `Some`, messages are held here instead of printed: those vkCreateInstance gives
    /// are printed once it succeeds, and dropped where it fails (the loader's "Found no
    /// drivers!" lines would stand above the one error line that says what to do).
    pub held: Mutex<Option<Vec<String>>>,
}

/// What a result file records about the device.
#[derive(Clone, Debug, Serialize)]
pub struct DeviceInfo {
    pub index: usize,
    pub name: String,
    pub device_type: String,
    pub software: bool,
    pub vendor_id: u32,
    pub device_id: u32,
    pub api_version: String,
    pub driver_name: String,
    pub driver_info: String,
    pub max_storage_buffer_range: u64,
    /// The most bytes of a uniform block a binding reads (16 KiB guaranteed; lavapipe and
    /// NVIDIA 64 KiB).
    pub max_uniform_buffer_range: u64,
    pub max_image_dimension_3d: u32,
    pub max_compute_workgroup_count: [u32; 3],
    pub max_compute_workgroup_invocations: u32,
    pub max_compute_shared_memory: u32,
    pub timestamp_period_ns: f32,
    pub float_atomics: bool,
    /// `shaderFloat64`: double precision in shaders (the lattice's convergence test on the
    /// device needs it; without it that test runs on the host, a wait per chunk).
    pub float64: bool,
    pub calibrated_timestamps: bool,
    pub queue_families: Vec<FamilyInfo>,
    pub mapping: RoleMapping,
    pub device_local_bytes: u64,
}

/// Per-role queue state: the queue, its timeline semaphore, and the last value submitted.
pub(crate) struct RoleQueue {
    pub queue: vk::Queue,
    pub family: u32,
    pub timeline: vk::Semaphore,
    pub pool: vk::CommandPool,
}

/// The device and everything resources need to free themselves; shared by `Arc`.
pub(crate) struct Shared {
    /// Keeps the Vulkan loader loaded for as long as the device lives.
    pub _entry: ash::Entry,
    pub instance: ash::Instance,
    pub device: ash::Device,
    pub allocator: Mutex<Option<Allocator>>,
    pub debug_utils: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    pub debug_device: Option<ash::ext::debug_utils::Device>,
    pub push_descriptor: ash::khr::push_descriptor::Device,
    pub calibrated: Option<ash::ext::calibrated_timestamps::Device>,
    /// Query pools are reset from the host (Vulkan 1.2 hostQueryReset): a transfer-only queue
    /// cannot record vkCmdResetQueryPool, and its copies are timed like passes.
    pub host_query_reset: bool,
    /// [`GpuOptions::unmapped_device_memory`].
    pub unmapped_device_memory: bool,
    /// [`GpuOptions::driver_specialization`].
    pub driver_specialization: bool,
    /// The physical device (surface queries: super::present).
    pub physical: vk::PhysicalDevice,
    /// Opened with `VK_KHR_swapchain` ([`GpuOptions::presentation`]).
    pub presentation: bool,
    pub roles: [RoleQueue; 3],
    pub info: DeviceInfo,
    /// Families of the compute roles (ordinary buffers are shared among these).
    pub sharing_families: Vec<u32>,
    /// Every family in use, the transfer role's included (buffers the copies touch).
    pub copy_families: Vec<u32>,
    pub validation: Arc<ValidationLog>,
    _validation_box: Option<LogBox>,
    /// The pipeline cache, loaded from disk at open and saved back at drop (super::cache).
    pub pipeline_cache: Mutex<super::cache::DiskCache>,
}

impl Shared {
    pub fn role(&self, role: QueueRole) -> &RoleQueue {
        &self.roles[role.index()]
    }

    /// Give a Vulkan object a debug name (shows in validation messages and captures).
    pub fn name_object<H: vk::Handle>(&self, handle: H, name: &str) {
        if let Some(du) = &self.debug_device {
            if let Ok(cname) = CString::new(name) {
                let info = vk::DebugUtilsObjectNameInfoEXT::default().object_handle(handle).object_name(&cname);
                // Naming is best effort: a failure only loses a debug label.
                let _ = unsafe { du.set_debug_utils_object_name(&info) };
            }
        }
    }
}

/// What `Gpu::open_device` has made since the device: destroyed in reverse order by the drop
/// when a later step fails, handed to `Shared` by [`Opening::disarm`] when none does.
#[derive(Default)]
struct Opening {
    device: Option<ash::Device>,
    debug_utils: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    semaphores: Vec<vk::Semaphore>,
    pools: Vec<vk::CommandPool>,
    allocator: Option<Allocator>,
}

/// The allocator and messenger, handed over.
type Handover = (Option<Allocator>, Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>);

impl Opening {
    fn disarm(mut self) -> Handover {
        self.device = None;
        (self.allocator.take(), self.debug_utils.take())
    }
}

impl Drop for Opening {
    fn drop(&mut self) {
        let Some(device) = self.device.take() else { return };
        unsafe {
            // The allocator frees its memory through the device: first.
            drop(self.allocator.take());
            for p in &self.pools {
                device.destroy_command_pool(*p, None);
            }
            for s in &self.semaphores {
                device.destroy_semaphore(*s, None);
            }
            device.destroy_device(None);
            if let Some((du, m)) = self.debug_utils.take() {
                du.destroy_debug_utils_messenger(m, None);
            }
        }
    }
}

impl Drop for Shared {
    fn drop(&mut self) {
        if let Ok(mut c) = self.pipeline_cache.lock() {
            // At exit there is no caller left to hand a warning to.
            if let Some(w) = c.save(&self.device) {
                eprintln!("warning: {w}");
            }
            c.destroy(&self.device);
        }
        unsafe {
            let _ = self.device.device_wait_idle();
            // The allocator must go before the device it allocates from.
            if let Ok(mut a) = self.allocator.lock() {
                a.take();
            }
            for r in &self.roles {
                self.device.destroy_command_pool(r.pool, None);
                self.device.destroy_semaphore(r.timeline, None);
            }
            self.device.destroy_device(None);
            if let Some((du, messenger)) = self.debug_utils.take() {
                du.destroy_debug_utils_messenger(messenger, None);
            }
            self.instance.destroy_instance(None);
        }
    }
}

unsafe extern "system" fn debug_callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user: *mut c_void,
) -> vk::Bool32 {
    let log = &*(user as *const Arc<ValidationLog>);
    let msg = if data.is_null() || (*data).p_message.is_null() {
        String::from("(no message)")
    } else {
        CStr::from_ptr((*data).p_message).to_string_lossy().into_owned()
    };
    let print = |line: String| match log.held.lock().as_deref_mut() {
        Ok(Some(held)) => held.push(line),
        _ => eprintln!("{line}"),
    };
    if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR) {
        log.errors.fetch_add(1, Ordering::SeqCst);
        print(format!("[vulkan validation error] {msg}"));
        if let Ok(mut v) = log.first_errors.lock() {
            if v.len() < 16 {
                v.push(msg);
            }
        }
    } else if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::WARNING) {
        log.warnings.fetch_add(1, Ordering::SeqCst);
        print(format!("[vulkan validation warning] {msg}"));
    }
    vk::FALSE
}

fn cstr_array(raw: &[std::ffi::c_char]) -> String {
    let bytes: Vec<u8> = raw.iter().take_while(|c| **c != 0).map(|c| *c as u8).collect();
    String::from_utf8_lossy(&bytes).into_owned()
}

fn type_name(t: vk::PhysicalDeviceType) -> &'static str {
    match t {
        vk::PhysicalDeviceType::DISCRETE_GPU => "discrete",
        vk::PhysicalDeviceType::INTEGRATED_GPU => "integrated",
        vk::PhysicalDeviceType::VIRTUAL_GPU => "virtual",
        vk::PhysicalDeviceType::CPU => "cpu",
        _ => "other",
    }
}

/// One line per device, for `scatterlab devices` and error messages.
#[derive(Clone, Debug, Serialize)]
pub struct DeviceSummary {
    pub index: usize,
    pub name: String,
    /// VkPhysicalDeviceIDProperties::deviceUUID as `GPU-xxxxxxxx-xxxx-xxxx-xxxx-xxxxxxxxxxxx`,
    /// the form nvidia-smi and CUDA_VISIBLE_DEVICES give NVIDIA GPUs (`--device uuid:...`).
    pub uuid: String,
    pub device_type: String,
    pub api_version: String,
    pub queue_families: Vec<FamilyInfo>,
    pub mapping: Option<RoleMapping>,
    pub missing: Vec<String>,
}

/// The optional features this device has and scatterlab uses: float atomics (lbl's fast
/// transfer), calibrated timestamps (GPU times on the host clock), host query reset, and
/// float64 (dom's convergence test on the device; `--without-float64` turns it off).
struct Features {
    float_atomics: bool,
    calibrated: bool,
    host_query_reset: bool,
    float64: bool,
}

impl Features {
    fn of(instance: &ash::Instance, pd: vk::PhysicalDevice, opts: &GpuOptions) -> Features {
        let float_atomics = has_extension(instance, pd, ash::ext::shader_atomic_float::NAME) && {
            let mut fa = vk::PhysicalDeviceShaderAtomicFloatFeaturesEXT::default();
            let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut fa);
            unsafe { instance.get_physical_device_features2(pd, &mut f2) };
            fa.shader_buffer_float32_atomic_add == vk::TRUE
        };
        let calibrated = has_extension(instance, pd, ash::ext::calibrated_timestamps::NAME);
        let host_query_reset = {
            let mut q12 = vk::PhysicalDeviceVulkan12Features::default();
            let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut q12);
            unsafe { instance.get_physical_device_features2(pd, &mut f2) };
            q12.host_query_reset == vk::TRUE
        };
        let float64 =
            !opts.without_float64 && unsafe { instance.get_physical_device_features(pd) }.shader_float64 == vk::TRUE;
        Features { float_atomics, calibrated, host_query_reset, float64 }
    }
}

/// The logical device: the queues the roles map to, and the extensions and features it uses.
fn create_device(
    instance: &ash::Instance,
    pd: vk::PhysicalDevice,
    mapping: &RoleMapping,
    f: &Features,
    swapchain: bool,
) -> Result<ash::Device> {
    // Queues: clamp the count to what the family reports (lavapipe accepts more and only
    // the validation layer complains; vulkan-notes.md).
    let mut per_family: Vec<(u32, u32)> = Vec::new();
    for role in QueueRole::ALL {
        let slot = mapping.slot(role);
        match per_family.iter_mut().find(|(f, _)| *f == slot.family) {
            Some((_, n)) => *n = (*n).max(slot.index + 1),
            None => per_family.push((slot.family, slot.index + 1)),
        }
    }
    let priorities = [1.0f32; 2];
    let queue_infos: Vec<vk::DeviceQueueCreateInfo> = per_family
        .iter()
        .map(|(f, n)| {
            vk::DeviceQueueCreateInfo::default().queue_family_index(*f).queue_priorities(&priorities[..*n as usize])
        })
        .collect();
    let mut ext_names = vec![ash::khr::push_descriptor::NAME.as_ptr()];
    if f.float_atomics {
        ext_names.push(ash::ext::shader_atomic_float::NAME.as_ptr());
    }
    if f.calibrated {
        ext_names.push(ash::ext::calibrated_timestamps::NAME.as_ptr());
    }
    if swapchain {
        ext_names.push(ash::khr::swapchain::NAME.as_ptr());
    }
    let core = vk::PhysicalDeviceFeatures::default().shader_float64(f.float64);
    let mut f12 =
        vk::PhysicalDeviceVulkan12Features::default().timeline_semaphore(true).host_query_reset(f.host_query_reset);
    let mut f13 = vk::PhysicalDeviceVulkan13Features::default().synchronization2(true);
    let mut fa = vk::PhysicalDeviceShaderAtomicFloatFeaturesEXT::default()
        .shader_buffer_float32_atomics(f.float_atomics)
        .shader_buffer_float32_atomic_add(f.float_atomics);
    let mut info = vk::DeviceCreateInfo::default()
        .queue_create_infos(&queue_infos)
        .enabled_extension_names(&ext_names)
        .enabled_features(&core)
        .push_next(&mut f12)
        .push_next(&mut f13);
    if f.float_atomics {
        info = info.push_next(&mut fa);
    }
    unsafe { instance.create_device(pd, &info, None) }.vk("vkCreateDevice")
}

/// A role's queue, its timeline semaphore and its command pool, each handed to `made` as it
/// is created (destroyed there if a later step fails).
fn make_role(device: &ash::Device, mapping: &RoleMapping, role: QueueRole, made: &mut Opening) -> Result<RoleQueue> {
    let slot = mapping.slot(role);
    let queue = unsafe { device.get_device_queue(slot.family, slot.index) };
    let mut ty = vk::SemaphoreTypeCreateInfo::default().semaphore_type(vk::SemaphoreType::TIMELINE).initial_value(0);
    let timeline = unsafe { device.create_semaphore(&vk::SemaphoreCreateInfo::default().push_next(&mut ty), None) }
        .vk("vkCreateSemaphore")?;
    made.semaphores.push(timeline);
    let pool = unsafe {
        device.create_command_pool(
            &vk::CommandPoolCreateInfo::default()
                .queue_family_index(slot.family)
                .flags(vk::CommandPoolCreateFlags::TRANSIENT),
            None,
        )
    }
    .vk("vkCreateCommandPool")?;
    made.pools.push(pool);
    Ok(RoleQueue { queue, family: slot.family, timeline, pool })
}

/// What the render reports and the solvers size themselves by: the device's names, driver,
/// limits, optional features, queues and its largest device-local heap.
fn device_info(instance: &ash::Instance, chosen: &Candidate, f: &Features, mapping: RoleMapping) -> DeviceInfo {
    let (pd, props) = (chosen.physical, &chosen.props);
    let mut driver = vk::PhysicalDeviceDriverProperties::default();
    let mut p2 = vk::PhysicalDeviceProperties2::default().push_next(&mut driver);
    unsafe { instance.get_physical_device_properties2(pd, &mut p2) };
    let mem = unsafe { instance.get_physical_device_memory_properties(pd) };
    let device_local_bytes = mem.memory_heaps[..mem.memory_heap_count as usize]
        .iter()
        .filter(|h| h.flags.contains(vk::MemoryHeapFlags::DEVICE_LOCAL))
        .map(|h| h.size)
        .max()
        .unwrap_or(0);
    DeviceInfo {
        index: chosen.summary.index,
        name: chosen.summary.name.clone(),
        device_type: type_name(props.device_type).into(),
        software: props.device_type == vk::PhysicalDeviceType::CPU,
        vendor_id: props.vendor_id,
        device_id: props.device_id,
        api_version: version_string(props.api_version),
        driver_name: cstr_array(&driver.driver_name),
        driver_info: cstr_array(&driver.driver_info),
        max_storage_buffer_range: props.limits.max_storage_buffer_range as u64,
        max_uniform_buffer_range: props.limits.max_uniform_buffer_range as u64,
        max_image_dimension_3d: props.limits.max_image_dimension3_d,
        max_compute_workgroup_count: props.limits.max_compute_work_group_count,
        max_compute_workgroup_invocations: props.limits.max_compute_work_group_invocations,
        max_compute_shared_memory: props.limits.max_compute_shared_memory_size,
        timestamp_period_ns: props.limits.timestamp_period,
        float_atomics: f.float_atomics,
        float64: f.float64,
        calibrated_timestamps: f.calibrated,
        queue_families: chosen.summary.queue_families.clone(),
        mapping,
        device_local_bytes,
    }
}

struct Candidate {
    physical: vk::PhysicalDevice,
    summary: DeviceSummary,
    props: vk::PhysicalDeviceProperties,
}

fn version_string(v: u32) -> String {
    format!("{}.{}.{}", vk::api_version_major(v), vk::api_version_minor(v), vk::api_version_patch(v))
}

fn has_extension(instance: &ash::Instance, pd: vk::PhysicalDevice, name: &CStr) -> bool {
    unsafe { instance.enumerate_device_extension_properties(pd) }
        .map(|exts| exts.iter().any(|e| e.extension_name_as_c_str().map(|n| n == name).unwrap_or(false)))
        .unwrap_or(false)
}

/// The features every solver relies on; a device lacking one is refused up front.
fn missing_features(
    instance: &ash::Instance,
    pd: vk::PhysicalDevice,
    props: &vk::PhysicalDeviceProperties,
) -> Vec<String> {
    let mut missing = Vec::new();
    if props.api_version < vk::API_VERSION_1_3 {
        missing.push(format!("Vulkan 1.3 (device offers {})", version_string(props.api_version)));
        return missing;
    }
    let mut f12 = vk::PhysicalDeviceVulkan12Features::default();
    let mut f13 = vk::PhysicalDeviceVulkan13Features::default();
    let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut f12).push_next(&mut f13);
    unsafe { instance.get_physical_device_features2(pd, &mut f2) };
    if f12.timeline_semaphore == vk::FALSE {
        missing.push("timelineSemaphore".into());
    }
    if f13.synchronization2 == vk::FALSE {
        missing.push("synchronization2".into());
    }
    if !has_extension(instance, pd, ash::khr::push_descriptor::NAME) {
        missing.push("VK_KHR_push_descriptor".into());
    }
    let fmt = unsafe { instance.get_physical_device_format_properties(pd, vk::Format::R32_SFLOAT) };
    if !fmt.optimal_tiling_features.contains(vk::FormatFeatureFlags::STORAGE_IMAGE) {
        missing.push("R32_SFLOAT storage images".into());
    }
    missing
}

fn families_of(instance: &ash::Instance, pd: vk::PhysicalDevice) -> Vec<FamilyInfo> {
    unsafe { instance.get_physical_device_queue_family_properties(pd) }
        .iter()
        .enumerate()
        .map(|(i, q)| FamilyInfo {
            index: i as u32,
            queue_count: q.queue_count,
            graphics: q.queue_flags.contains(vk::QueueFlags::GRAPHICS),
            compute: q.queue_flags.contains(vk::QueueFlags::COMPUTE),
            transfer: q.queue_flags.contains(vk::QueueFlags::TRANSFER),
            timestamp_valid_bits: q.timestamp_valid_bits,
        })
        .collect()
}

fn load_entry() -> Result<ash::Entry> {
    unsafe { ash::Entry::load() }.map_err(|e| GpuError::Loader(e.to_string()))
}

/// The validation messengers' user data: a `Box` so that its address (handed to the layer as a
/// thin `*mut c_void`) stays put while the `Arc` inside is shared with the device.
#[allow(clippy::redundant_allocation)]
type LogBox = Box<Arc<ValidationLog>>;

fn create_instance(
    entry: &ash::Entry,
    validate: bool,
    surface: &[&'static CStr],
    log: &Arc<ValidationLog>,
) -> Result<(ash::Instance, Option<LogBox>, bool)> {
    let app = vk::ApplicationInfo::default()
        .application_name(c"scatterlab")
        .engine_name(c"scatterlab")
        .api_version(vk::API_VERSION_1_3);
    let mut layers: Vec<*const std::ffi::c_char> = Vec::new();
    let mut extensions: Vec<*const std::ffi::c_char> = surface.iter().map(|e| e.as_ptr()).collect();
    let mut boxed = None;
    let mut debug = false;
    if validate {
        let available =
            unsafe { entry.enumerate_instance_layer_properties() }.vk("vkEnumerateInstanceLayerProperties")?;
        if !available.iter().any(|l| l.layer_name_as_c_str().map(|n| n == VALIDATION_LAYER).unwrap_or(false)) {
            return Err(GpuError::NoValidationLayer);
        }
        layers.push(VALIDATION_LAYER.as_ptr());
        extensions.push(ash::ext::debug_utils::NAME.as_ptr());
        extensions.push(ash::ext::validation_features::NAME.as_ptr());
        boxed = Some(Box::new(log.clone()));
        debug = true;
    }
    // Synchronization validation on (the layer misses some hazards; a clean run is no proof).
    let enables = [vk::ValidationFeatureEnableEXT::SYNCHRONIZATION_VALIDATION];
    let mut features = vk::ValidationFeaturesEXT::default().enabled_validation_features(&enables);
    let mut messenger_info = messenger_create_info(boxed.as_deref());
    let mut info = vk::InstanceCreateInfo::default()
        .application_info(&app)
        .enabled_layer_names(&layers)
        .enabled_extension_names(&extensions);
    if debug {
        info = info.push_next(&mut features).push_next(&mut messenger_info);
    }
    if let Ok(mut held) = log.held.lock() {
        *held = Some(Vec::new());
    }
    let created = unsafe { entry.create_instance(&info, None) };
    let held = log.held.lock().ok().and_then(|mut h| h.take()).unwrap_or_default();
    if created.is_ok() {
        for line in held {
            eprintln!("{line}");
        }
    }
    let instance = created.map_err(|result| match result {
        // The loader found no driver (ICD) to create the instance on: say what to install.
        vk::Result::ERROR_INCOMPATIBLE_DRIVER => GpuError::NoDriver {
            listed: ["VK_DRIVER_FILES", "VK_ICD_FILENAMES"]
                .iter()
                .find_map(|v| std::env::var(v).ok().filter(|s| !s.is_empty()).map(|s| format!("{v}={s}")))
                .map(|v| format!("; {v} is set and may name no usable driver: unset it"))
                .unwrap_or_default(),
        },
        result => GpuError::Vk { call: "vkCreateInstance", result },
    })?;
    Ok((instance, boxed, debug))
}

fn messenger_create_info(log: Option<&Arc<ValidationLog>>) -> vk::DebugUtilsMessengerCreateInfoEXT<'static> {
    let mut info = vk::DebugUtilsMessengerCreateInfoEXT::default()
        .message_severity(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR | vk::DebugUtilsMessageSeverityFlagsEXT::WARNING)
        .message_type(
            vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
        )
        .pfn_user_callback(Some(debug_callback));
    if let Some(l) = log {
        info = info.user_data(l as *const Arc<ValidationLog> as *mut c_void);
    }
    info
}

fn candidates(instance: &ash::Instance) -> Result<Vec<Candidate>> {
    let pds = unsafe { instance.enumerate_physical_devices() }.vk("vkEnumeratePhysicalDevices")?;
    Ok(pds
        .into_iter()
        .enumerate()
        .map(|(index, pd)| {
            let props = unsafe { instance.get_physical_device_properties(pd) };
            let mut id = vk::PhysicalDeviceIDProperties::default();
            let mut p2 = vk::PhysicalDeviceProperties2::default().push_next(&mut id);
            unsafe { instance.get_physical_device_properties2(pd, &mut p2) };
            let uuid = format_uuid(&id.device_uuid);
            let queue_families = families_of(instance, pd);
            let mapping = map_roles(&queue_families);
            let mut missing = missing_features(instance, pd, &props);
            if mapping.is_none() {
                missing.push("a compute queue".into());
            }
            let summary = DeviceSummary {
                index,
                name: cstr_array(&props.device_name),
                uuid,
                device_type: type_name(props.device_type).into(),
                api_version: version_string(props.api_version),
                queue_families,
                mapping,
                missing,
            };
            Candidate { physical: pd, summary, props }
        })
        .collect())
}

/// List every Vulkan device with its queue families and the role mapping it would get.
pub fn list_devices() -> Result<Vec<DeviceSummary>> {
    let entry = load_entry()?;
    let log = Arc::new(ValidationLog::default());
    let (instance, _b, _) = create_instance(&entry, false, &[], &log)?;
    let list = candidates(&instance).map(|c| c.into_iter().map(|c| c.summary).collect());
    unsafe { instance.destroy_instance(None) };
    list
}

fn type_rank_name(t: &str) -> u32 {
    match t {
        "discrete" => 0,
        "integrated" => 1,
        "virtual" => 2,
        "cpu" => 3,
        _ => 4,
    }
}

/// `GPU-` and the 16 bytes in the 8-4-4-4-12 grouping of a UUID, lower-case hex.
fn format_uuid(b: &[u8; 16]) -> String {
    let hex: String = b.iter().map(|x| format!("{x:02x}")).collect();
    format!("GPU-{}-{}-{}-{}-{}", &hex[0..8], &hex[8..12], &hex[12..16], &hex[16..20], &hex[20..32])
}

/// A UUID as given (`GPU-...` or bare hex, any case, dashes anywhere) in canonical hex digits.
fn uuid_digits(u: &str) -> String {
    let u = u.trim();
    let u = u.strip_prefix("GPU-").or_else(|| u.strip_prefix("gpu-")).unwrap_or(u);
    u.chars().filter(|c| *c != '-').flat_map(char::to_lowercase).collect()
}

/// What `--device auto` resolves to, from the environment `env` (a lookup, so tests can give
/// one): `SCATTERLAB_DEVICE` where set (and not `auto`); else the first GPU in
/// `CUDA_VISIBLE_DEVICES`, then in `SLURM_STEP_GPUS` (then `SLURM_JOB_GPUS`), where Slurm
/// or a user put the task's GPUs: a UUID (`GPU-...`) is matched as `uuid:`; an index counts the
/// physical GPUs (not CPU drivers) in the order Vulkan lists them, and where the index is past
/// them (Slurm's device cgroup shows a task only its own GPUs, whose node-wide numbers it
/// keeps) the task's own first GPU is taken. `None`: nothing set, the default choice.
/// Where two of them are set and name different GPUs, the first in that order wins and the
/// second is named in the returned note.
pub fn auto_device(list: &[DeviceSummary], env: &dyn Fn(&str) -> Option<String>) -> (Option<String>, Option<String>) {
    let (chosen, note) = auto_choice(list, env);
    (chosen.map(|(wanted, _)| wanted), note)
}

/// [`auto_device`] and the variable its choice came from, which an error about it names (a
/// `SCATTERLAB_DEVICE=bogus` behind `--device auto` was reported as `--device bogus`).
fn auto_choice(
    list: &[DeviceSummary],
    env: &dyn Fn(&str) -> Option<String>,
) -> (Option<(String, &'static str)>, Option<String>) {
    let get = |k: &str| env(k).map(|v| v.trim().to_string()).filter(|v| !v.is_empty());
    if let Some(d) = get(ENV_DEVICE).filter(|d| d != "auto") {
        return (Some((d, ENV_DEVICE)), None);
    }
    let gpus: Vec<&DeviceSummary> = list.iter().filter(|d| d.device_type != "cpu").collect();
    let resolve = |var: &'static str| -> Option<(&'static str, String)> {
        let value = get(var)?;
        let first = value.split(',').next()?.trim().to_string();
        if first.starts_with("GPU-") || first.starts_with("MIG-") {
            return Some((var, format!("uuid:{first}")));
        }
        let i: usize = first.parse().ok()?;
        let d = gpus.get(i).or(gpus.first())?;
        Some((var, d.index.to_string()))
    };
    let found: Vec<(&'static str, String)> =
        ["CUDA_VISIBLE_DEVICES", "SLURM_STEP_GPUS", "SLURM_JOB_GPUS"].into_iter().filter_map(resolve).collect();
    let Some((var, wanted)) = found.first().cloned() else { return (None, None) };
    let same = |a: &str, b: &str| choose_device(list, Some(a)).ok() == choose_device(list, Some(b)).ok();
    let note =
        found.iter().skip(1).find(|(_, w)| !same(w, &wanted)).map(|(other, w)| {
            format!("--device auto: {var} names device {wanted} and {other} names {w}; using {var}'s")
        });
    (Some((wanted, var)), note)
}

/// The index of the device `Gpu::new` opens for `wanted` (an index, `uuid:GPU-...` (a unique
/// prefix will do, as CUDA_VISIBLE_DEVICES takes), `auto` (the environment's choice:
/// [`auto_device`]) or a case-insensitive name substring; `None`: the first with everything
/// needed, discrete > integrated > virtual > CPU). Errors when nothing matches or the match
/// lacks a required feature.
pub fn choose_device(list: &[DeviceSummary], wanted: Option<&str>) -> Result<Option<usize>> {
    if list.is_empty() {
        return Err(GpuError::NoDevice);
    }
    if wanted == Some("auto") {
        let (resolved, note) = auto_choice(list, &|k| std::env::var(k).ok());
        if let Some(n) = note {
            eprintln!("warning: {n}");
        }
        return match resolved {
            // Not found: said as the variable named it (kept by a caller's `named_by`).
            Some((w, var)) => choose_device(list, Some(&w)).map_err(|e| e.named_by(var)),
            None => choose_device(list, None),
        };
    }
    let available =
        || list.iter().map(|c| format!("{}: {} ({})", c.index, c.name, c.uuid)).collect::<Vec<_>>().join(", ");
    let chosen = match wanted {
        Some(w) if w.to_ascii_lowercase().starts_with("uuid:") => {
            let digits = uuid_digits(&w[5..]);
            let hits: Vec<&DeviceSummary> =
                list.iter().filter(|c| !digits.is_empty() && uuid_digits(&c.uuid).starts_with(&digits)).collect();
            match hits.as_slice() {
                [one] => *one,
                [] => {
                    return Err(GpuError::DeviceNotFound {
                        wanted: w.to_string(),
                        available: available(),
                        from: "--device",
                    })
                }
                _ => {
                    return Err(GpuError::DeviceNotFound {
                        wanted: format!("{w} (a prefix of {} devices' UUIDs: give more digits)", hits.len()),
                        available: available(),
                        from: "--device",
                    })
                }
            }
        }
        Some(w) => {
            let by_index = w.parse::<usize>().ok();
            let lw = w.to_lowercase();
            list.iter().find(|c| Some(c.index) == by_index || c.name.to_lowercase().contains(&lw)).ok_or_else(|| {
                GpuError::DeviceNotFound { wanted: w.to_string(), available: available(), from: "--device" }
            })?
        }
        None => list
            .iter()
            .min_by_key(|c| (!c.missing.is_empty(), type_rank_name(&c.device_type), c.index))
            .ok_or(GpuError::NoDevice)?,
    };
    if let Some(first) = chosen.missing.first() {
        return Err(GpuError::MissingFeature {
            device: chosen.name.clone(),
            feature: first.clone(),
            hint: "update the driver or pick another device with --device (see `scatterlab devices`)".into(),
        });
    }
    Ok(Some(chosen.index))
}

fn choose(cands: Vec<Candidate>, wanted: Option<&str>) -> Result<Candidate> {
    let summaries: Vec<DeviceSummary> = cands.iter().map(|c| c.summary.clone()).collect();
    let index = choose_device(&summaries, wanted)?;
    cands.into_iter().find(|c| Some(c.summary.index) == index).ok_or(GpuError::NoDevice)
}

/// How long the last handle to a device waits, as it goes, for work still in flight (after an
/// error returned mid-render or a timeout) before it gives up and leaks that work's resources.
pub(crate) const DROP_GRACE: Duration = Duration::from_secs(10);

/// The opened GPU: device, allocator, queue roles. Cheap to clone.
#[derive(Clone)]
pub struct Gpu {
    pub(crate) shared: Arc<Shared>,
    pub(crate) submit: Arc<Mutex<super::submit::SubmitState>>,
    pub(crate) host: Arc<Mutex<super::host::HostTimes>>,
    /// Staging buffers kept between uploads [0] and readbacks [1] (super::memory).
    pub(crate) staging_cache: Arc<Mutex<[Option<super::memory::Staging>; 2]>>,
    /// Fills and uploads waiting for the next submission, and the upload ring (super::setup).
    pub(crate) setup: Arc<Mutex<super::setup::Setup>>,
    /// Pipelines built in this process, and what each render asked for (super::pipeline).
    pub(crate) pipeline_memo: Arc<Mutex<super::pipeline::PipelineMemo>>,
    pub(crate) timeout: Duration,
}

impl Gpu {
    pub fn new(opts: &GpuOptions) -> Result<Gpu> {
        let entry = load_entry()?;
        let log = Arc::new(ValidationLog::default());
        let surface = opts.presentation.as_deref().unwrap_or(&[]);
        let (instance, mut boxed, debug) = create_instance(&entry, opts.validate, surface, &log)?;
        // From here on, any early return must destroy the instance, and only then free the
        // messengers' user data: the layer may report through the create-time messenger while
        // the instance is destroyed, and the callback would write through a freed pointer.
        let result = Self::open_device(entry.clone(), instance.clone(), &mut boxed, debug, log, opts);
        if result.is_err() {
            unsafe { instance.destroy_instance(None) };
        }
        drop(boxed);
        result
    }

    fn open_device(
        entry: ash::Entry,
        instance: ash::Instance,
        boxed: &mut Option<LogBox>,
        debug: bool,
        log: Arc<ValidationLog>,
        opts: &GpuOptions,
    ) -> Result<Gpu> {
        // Say where the name came from: the flag, or an environment variable set long ago.
        let chosen =
            choose(candidates(&instance)?, opts.device.as_deref()).map_err(|e| e.named_by(opts.device_from))?;
        let pd = chosen.physical;
        let mut mapping = chosen.summary.mapping.expect("checked by missing_features");
        if let Some(q) = opts.queues.as_deref() {
            mapping = super::queues::map_roles_named(&chosen.summary.queue_families, q).map_err(|reason| {
                GpuError::Queues {
                    choice: super::error::naming(opts.queues_from, q),
                    device: chosen.summary.name.clone(),
                    reason,
                }
            })?;
        }

        let features = Features::of(&instance, pd, opts);
        let device = create_device(&instance, pd, &mapping, &features, opts.presentation.is_some())?;
        // From here on a failure destroys what was made (the guard's drop), before the caller
        // destroys the instance.
        let mut made = Opening::default();
        made.device = Some(device.clone());

        if debug {
            let du = ash::ext::debug_utils::Instance::new(&entry, &instance);
            // A fresh create-info: reusing one that was chained trips the layer (vulkan-notes.md).
            let mi = messenger_create_info(boxed.as_deref());
            let m = unsafe { du.create_debug_utils_messenger(&mi, None) }.vk("vkCreateDebugUtilsMessengerEXT")?;
            made.debug_utils = Some((du, m));
        }
        let debug_device = debug.then(|| ash::ext::debug_utils::Device::new(&instance, &device));

        let roles = [
            make_role(&device, &mapping, QueueRole::Trace, &mut made)?,
            make_role(&device, &mapping, QueueRole::Diffuse, &mut made)?,
            make_role(&device, &mapping, QueueRole::Transfer, &mut made)?,
        ];

        let allocator = Allocator::new(&AllocatorCreateDesc {
            instance: instance.clone(),
            device: device.clone(),
            physical_device: pd,
            debug_settings: Default::default(),
            buffer_device_address: false,
            allocation_sizes: Default::default(),
        })
        .map_err(|e| GpuError::Alloc { name: "allocator".into(), bytes: 0, reason: e.to_string() })?;
        made.allocator = Some(allocator);

        let info = device_info(&instance, &chosen, &features, mapping);
        let (disk_cache, cache_warning) = super::cache::DiskCache::open(
            &device,
            opts.cache_dir.as_deref(),
            super::cache::CacheIdentity::of(&chosen.props),
        )?;
        // Everything made: Shared owns it from here (and destroys it in its drop).
        let (allocator, debug_utils) = made.disarm();
        if let Some(w) = &cache_warning {
            eprintln!("warning: {w}");
        }
        let shared = Shared {
            pipeline_cache: Mutex::new(disk_cache),
            push_descriptor: ash::khr::push_descriptor::Device::new(&instance, &device),
            calibrated: features.calibrated.then(|| ash::ext::calibrated_timestamps::Device::new(&instance, &device)),
            host_query_reset: features.host_query_reset,
            unmapped_device_memory: opts.unmapped_device_memory,
            driver_specialization: opts.driver_specialization,
            physical: pd,
            presentation: opts.presentation.is_some(),
            _entry: entry,
            instance,
            device,
            allocator: Mutex::new(allocator),
            debug_utils,
            debug_device,
            roles,
            sharing_families: mapping.compute_families(),
            copy_families: mapping.families(),
            info,
            validation: log,
            _validation_box: boxed.take(),
        };
        Ok(Gpu {
            shared: Arc::new(shared),
            submit: Arc::new(Mutex::new(super::submit::SubmitState::default())),
            host: Arc::new(Mutex::new(super::host::HostTimes::default())),
            staging_cache: Arc::new(Mutex::new([None, None])),
            setup: Arc::new(Mutex::new(Default::default())),
            pipeline_memo: Arc::new(Mutex::new(Default::default())),
            timeout: opts.timeout,
        })
    }

    /// Count `bytes` of host work of `kind` that began at `started` (super::host).
    pub(crate) fn host_add(&self, kind: super::host::HostKind, bytes: u64, started: std::time::Instant) {
        self.host.lock().expect("host times lock").add(kind, bytes, started);
    }

    /// Take the host work counted so far ([`super::HostTimes`]) and start again from zero.
    pub fn take_host_times(&self) -> super::HostTimes {
        std::mem::take(&mut *self.host.lock().expect("host times lock"))
    }

    pub fn info(&self) -> &DeviceInfo {
        &self.shared.info
    }

    /// How the pipeline cache file was found, and how much the driver keeps in it.
    pub fn pipeline_cache_status(&self) -> super::cache::PipelineCacheStatus {
        self.shared.pipeline_cache.lock().expect("pipeline cache lock").status.clone()
    }

    /// Save the pipeline cache now (it is saved when the device closes anyway): returns the
    /// warning where it cannot be written, and how many bytes the driver keeps in it.
    pub fn save_pipeline_cache(&self) -> (Option<String>, u64) {
        let mut c = self.shared.pipeline_cache.lock().expect("pipeline cache lock");
        let w = c.save(&self.shared.device);
        (w, c.status.saved_bytes)
    }

    /// The validation log itself, which outlives the device (a test of what happens as the
    /// device goes reads it after the drop).
    pub fn validation_log(&self) -> Arc<ValidationLog> {
        self.shared.validation.clone()
    }

    /// Validation errors seen so far (0 when validation is off).
    pub fn validation_errors(&self) -> u64 {
        self.shared.validation.errors.load(Ordering::SeqCst)
    }

    /// The first few validation error messages, for test failure output.
    pub fn validation_messages(&self) -> Vec<String> {
        self.shared.validation.first_errors.lock().map(|v| v.clone()).unwrap_or_default()
    }

    pub fn validation_enabled(&self) -> bool {
        self.shared.debug_utils.is_some()
    }

    /// Send an error-severity message through the debug messenger, as the validation layer
    /// would: lets a test prove that errors are counted (and so fail tests). Returns false when
    /// validation is off.
    #[doc(hidden)]
    pub fn inject_validation_error_for_test(&self, text: &str) -> bool {
        let Some((du, _)) = &self.shared.debug_utils else { return false };
        let Ok(msg) = CString::new(text) else { return false };
        let data = vk::DebugUtilsMessengerCallbackDataEXT::default().message(&msg);
        unsafe {
            du.submit_debug_utils_message(
                vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
                vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION,
                &data,
            )
        };
        true
    }
}
