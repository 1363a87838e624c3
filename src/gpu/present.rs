//! Presentation to a window (`scatterlab view`): a `VK_KHR_swapchain` on a queue of the
//! device's roles that can present to the window's surface, and each frame's 8-bit sRGB
//! pixels copied into the acquired swapchain image. The window itself (winit) lives in the
//! CLI; here are only the Vulkan calls, as everywhere in this module.
//!
//! One frame in flight: a frame waits for the previous frame's copy (its fence) before it
//! writes the upload buffer again. The linear image is uploaded as it is and tone-mapped on the
//! device (glsl/view/tonemap.comp: the PNG writer's operator, sRGB-encoded, packed in the
//! swapchain's byte order) on the presenting role's queue; the copy into the swapchain image
//! waits for that pass on the role's timeline semaphore. A copy never converts, so the image
//! shows the bytes as a PNG viewer would, in a UNORM or an SRGB swapchain format alike (an SRGB
//! image's bytes are sRGB-encoded).

use std::ffi::CStr;

use ash::vk;
use gpu_allocator::MemoryLocation;
use raw_window_handle::{RawDisplayHandle, RawWindowHandle};

use super::context::Gpu;
use super::error::{GpuError, Result, VkContext};
use super::memory::Buffer;
use super::pipeline::{Kernel, Pipeline, ShaderSource};
use super::queues::QueueRole;
use super::submit::Pass;

/// The device tone map of a view frame (glsl/view/tonemap.comp).
pub const TONEMAP: Kernel = Kernel {
    shader: ShaderSource {
        name: "view/tonemap",
        spirv: include_bytes!(concat!(env!("CARGO_MANIFEST_DIR"), "/spirv/view/tonemap.spv")),
    },
    push_bytes: std::mem::size_of::<TonemapPush>(),
    spec: &[],
};

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct TonemapPush {
    pixels: u32,
    scale: f32,
    bgra: u32,
}

/// The instance extensions a surface on `display` needs (`VK_KHR_surface` and the platform's).
pub fn surface_extensions(display: RawDisplayHandle) -> Result<Vec<&'static CStr>> {
    let names = ash_window::enumerate_required_extensions(display).vk("vkEnumerateInstanceExtensionProperties")?;
    // Safety: ash-window hands out pointers to its own 'static extension-name constants.
    Ok(names.iter().map(|&p| unsafe { CStr::from_ptr(p) }).collect())
}

/// The device tone map on its own, without a window: `rgb` (linear, 3 floats a pixel) at
/// `exposure` stops as the 8-bit RGB bytes [`Presenter::show`] puts on screen, for checking it
/// against the PNG writer's operator.
pub fn tonemap_on_device(gpu: &Gpu, rgb: &[f32], exposure: f32) -> Result<Vec<u8>> {
    let pixels = (rgb.len() / 3) as u32;
    let linear = gpu.buffer_with("tonemap check: linear", rgb)?;
    let packed = gpu.buffer("tonemap check: packed", 4 * pixels as u64)?;
    let pipeline = gpu.pipeline(&TONEMAP, &[])?;
    let pass = Pass::new("view.tonemap", QueueRole::Trace, &pipeline)
        .read(0, &linear)
        .write(1, &packed)
        .push(&TonemapPush { pixels, scale: exposure.exp2(), bgra: 0 })
        .cover_linear(pixels);
    let point = gpu.submit(QueueRole::Trace, &[pass], &[])?;
    gpu.wait(point)?;
    let words: Vec<u32> = gpu.read_buffer_as(&packed)?;
    Ok(words.iter().flat_map(|w| [*w as u8, (*w >> 8) as u8, (*w >> 16) as u8]).collect())
}

/// A window's surface and swapchain on `gpu`, and what a frame needs to reach it.
pub struct Presenter {
    gpu: Gpu,
    surface_fn: ash::khr::surface::Instance,
    swapchain_fn: ash::khr::swapchain::Device,
    surface: vk::SurfaceKHR,
    queue: vk::Queue,
    family: u32,
    /// The role whose queue presents, where the tone map runs.
    role: QueueRole,
    tonemap: Pipeline,
    swapchain: vk::SwapchainKHR,
    images: Vec<vk::Image>,
    format: vk::SurfaceFormatKHR,
    extent: vk::Extent2D,
    /// Whether the swapchain images can be copied from (a screenshot of what was shown).
    readable: bool,
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    acquired: vk::Semaphore,
    /// One per swapchain image: presentation waits on the copy into that image.
    copied: Vec<vk::Semaphore>,
    fence: vk::Fence,
    /// The linear image uploaded (host-visible storage), and the tone map's packed pixels.
    staging: Option<(Buffer, *mut u8)>,
    packed: Option<Buffer>,
    readback: Option<(Buffer, *mut u8)>,
}

/// What [`Presenter::show`] did.
pub enum Shown {
    /// On screen; with the image's pixels read back when asked (RGB, 8-bit, rows top-down).
    Presented(Option<Vec<u8>>),
    /// The swapchain no longer matches the window (resized, or minimised): nothing shown;
    /// call [`Presenter::resize`] and draw again.
    OutOfDate,
}

impl Presenter {
    /// A surface for the window and a swapchain of `size` pixels (clamped to what the surface
    /// allows). `gpu` must have been opened with [`surface_extensions`] and the swapchain
    /// extension ([`super::GpuOptions::presentation`]).
    pub fn new(gpu: &Gpu, display: RawDisplayHandle, window: RawWindowHandle, size: [u32; 2]) -> Result<Presenter> {
        let s = &gpu.shared;
        if !s.presentation {
            return Err(GpuError::MissingFeature {
                device: s.info.name.clone(),
                feature: "VK_KHR_swapchain".into(),
                hint: "the device was opened without presentation; open it with GpuOptions::presentation".into(),
            });
        }
        let surface_fn = ash::khr::surface::Instance::new(&s._entry, &s.instance);
        // Safety: the handles come from a live winit window, which the caller keeps alive
        // longer than this presenter (it drops the presenter first).
        let surface = unsafe { ash_window::create_surface(&s._entry, &s.instance, display, window, None) }
            .vk("vkCreate*SurfaceKHR")?;
        let destroy_surface = |e| {
            unsafe { surface_fn.destroy_surface(surface, None) };
            e
        };
        // The first role (trace, diffuse, transfer) whose family can present to this surface.
        let mut present = None;
        for role in QueueRole::ALL {
            let q = s.role(role);
            let ok = unsafe { surface_fn.get_physical_device_surface_support(s.physical, q.family, surface) }
                .vk("vkGetPhysicalDeviceSurfaceSupportKHR")
                .map_err(destroy_surface)?;
            if ok {
                present = Some((q.queue, q.family, role));
                break;
            }
        }
        let Some((queue, family, role)) = present else {
            return Err(destroy_surface(GpuError::MissingFeature {
                device: s.info.name.clone(),
                feature: "a queue that presents to this window".into(),
                hint: "no family of the queue roles can present here; try --queues shared or another --device".into(),
            }));
        };
        let tonemap = gpu.pipeline(&TONEMAP, &[]).map_err(destroy_surface)?;
        let swapchain_fn = ash::khr::swapchain::Device::new(&s.instance, &s.device);
        let d = &s.device;
        let pool_info = vk::CommandPoolCreateInfo::default()
            .queue_family_index(family)
            .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER);
        let pool =
            unsafe { d.create_command_pool(&pool_info, None) }.vk("vkCreateCommandPool").map_err(destroy_surface)?;
        let mut p = Presenter {
            gpu: gpu.clone(),
            surface_fn,
            swapchain_fn,
            surface,
            queue,
            family,
            role,
            tonemap,
            swapchain: vk::SwapchainKHR::null(),
            images: Vec::new(),
            format: vk::SurfaceFormatKHR::default(),
            extent: vk::Extent2D::default(),
            readable: false,
            pool,
            cmd: vk::CommandBuffer::null(),
            acquired: vk::Semaphore::null(),
            copied: Vec::new(),
            fence: vk::Fence::null(),
            staging: None,
            packed: None,
            readback: None,
        };
        // From here `p`'s drop frees whatever was made.
        let alloc = vk::CommandBufferAllocateInfo::default().command_pool(pool).command_buffer_count(1);
        p.cmd = unsafe { d.allocate_command_buffers(&alloc) }.vk("vkAllocateCommandBuffers")?[0];
        p.acquired =
            unsafe { d.create_semaphore(&vk::SemaphoreCreateInfo::default(), None) }.vk("vkCreateSemaphore")?;
        let signalled = vk::FenceCreateInfo::default().flags(vk::FenceCreateFlags::SIGNALED);
        p.fence = unsafe { d.create_fence(&signalled, None) }.vk("vkCreateFence")?;
        p.resize(size)?;
        Ok(p)
    }

    /// The swapchain's size in pixels (0 x 0 while the window is minimised).
    pub fn extent(&self) -> [u32; 2] {
        [self.extent.width, self.extent.height]
    }

    /// The swapchain's pixel format, for the summary (`B8G8R8A8_UNORM` on lavapipe under X11).
    pub fn format(&self) -> String {
        format!("{:?}", self.format.format)
    }

    /// The queue family presenting.
    pub fn family(&self) -> u32 {
        self.family
    }

    /// A swapchain for the window's current `size` (the surface's own extent where it fixes
    /// one), replacing the old one. A minimised window (0 x 0) gets none until it is restored.
    pub fn resize(&mut self, size: [u32; 2]) -> Result<()> {
        let gpu = self.gpu.clone();
        let s = &gpu.shared;
        let d = &s.device;
        // The old swapchain's images may still be written by the last copy and read by the
        // presentation engine (its wait on the copy's semaphore): both done before it goes.
        unsafe { d.wait_for_fences(&[self.fence], true, u64::MAX) }.vk("vkWaitForFences")?;
        unsafe { d.queue_wait_idle(self.queue) }.vk("vkQueueWaitIdle")?;
        let caps = unsafe { self.surface_fn.get_physical_device_surface_capabilities(s.physical, self.surface) }
            .vk("vkGetPhysicalDeviceSurfaceCapabilitiesKHR")?;
        let extent = if caps.current_extent.width != u32::MAX {
            caps.current_extent
        } else {
            vk::Extent2D {
                width: size[0].clamp(caps.min_image_extent.width, caps.max_image_extent.width),
                height: size[1].clamp(caps.min_image_extent.height, caps.max_image_extent.height),
            }
        };
        self.destroy_swapchain();
        self.extent = extent;
        if extent.width == 0 || extent.height == 0 {
            return Ok(());
        }
        if !caps.supported_usage_flags.contains(vk::ImageUsageFlags::TRANSFER_DST) {
            return Err(GpuError::MissingFeature {
                device: s.info.name.clone(),
                feature: "swapchain images usable as copy destinations (TRANSFER_DST)".into(),
                hint: "this surface cannot be written by a copy; try another --device".into(),
            });
        }
        self.readable = caps.supported_usage_flags.contains(vk::ImageUsageFlags::TRANSFER_SRC);
        let formats = unsafe { self.surface_fn.get_physical_device_surface_formats(s.physical, self.surface) }
            .vk("vkGetPhysicalDeviceSurfaceFormatsKHR")?;
        // 8-bit BGRA or RGBA, UNORM first (the bytes are sRGB-encoded already; an SRGB format
        // holds the same bytes, so either shows them right).
        let rank = |f: &vk::SurfaceFormatKHR| match f.format {
            vk::Format::B8G8R8A8_UNORM | vk::Format::R8G8B8A8_UNORM => 0,
            vk::Format::B8G8R8A8_SRGB | vk::Format::R8G8B8A8_SRGB => 1,
            _ => 2,
        };
        let format = formats.iter().copied().filter(|f| rank(f) < 2).min_by_key(rank).ok_or_else(|| {
            GpuError::MissingFeature {
                device: s.info.name.clone(),
                feature: "an 8-bit RGBA or BGRA swapchain format".into(),
                hint: format!("the surface offers {:?}", formats.iter().map(|f| f.format).collect::<Vec<_>>()),
            }
        })?;
        let mut usage = vk::ImageUsageFlags::TRANSFER_DST;
        if self.readable {
            usage |= vk::ImageUsageFlags::TRANSFER_SRC;
        }
        let count = if caps.max_image_count == 0 {
            caps.min_image_count + 1
        } else {
            (caps.min_image_count + 1).min(caps.max_image_count)
        };
        let info = vk::SwapchainCreateInfoKHR::default()
            .surface(self.surface)
            .min_image_count(count)
            .image_format(format.format)
            .image_color_space(format.color_space)
            .image_extent(extent)
            .image_array_layers(1)
            .image_usage(usage)
            .image_sharing_mode(vk::SharingMode::EXCLUSIVE)
            .pre_transform(caps.current_transform)
            .composite_alpha(vk::CompositeAlphaFlagsKHR::OPAQUE)
            // FIFO: always supported, and a viewer need not outrun the display.
            .present_mode(vk::PresentModeKHR::FIFO)
            .clipped(true);
        self.swapchain = unsafe { self.swapchain_fn.create_swapchain(&info, None) }.vk("vkCreateSwapchainKHR")?;
        self.format = format;
        self.images =
            unsafe { self.swapchain_fn.get_swapchain_images(self.swapchain) }.vk("vkGetSwapchainImagesKHR")?;
        for _ in &self.images {
            let sem =
                unsafe { d.create_semaphore(&vk::SemaphoreCreateInfo::default(), None) }.vk("vkCreateSemaphore")?;
            self.copied.push(sem);
        }
        Ok(())
    }

    fn destroy_swapchain(&mut self) {
        let d = &self.gpu.shared.device;
        for sem in self.copied.drain(..) {
            unsafe { d.destroy_semaphore(sem, None) };
        }
        if self.swapchain != vk::SwapchainKHR::null() {
            unsafe { self.swapchain_fn.destroy_swapchain(self.swapchain, None) };
            self.swapchain = vk::SwapchainKHR::null();
        }
        self.images.clear();
    }

    /// Show `rgb` (linear RGB, 3 floats a pixel, rows top-down, exactly the swapchain's size)
    /// tone-mapped on the device at `exposure` stops, reading the shown image back when `read`
    /// is set (or the tone map's bytes, where the surface forbids reading its images:
    /// [`Presenter::reads_back`]).
    pub fn show(&mut self, rgb: &[f32], exposure: f32, read: bool) -> Result<Shown> {
        let [w, h] = self.extent();
        if self.swapchain == vk::SwapchainKHR::null() {
            return Ok(Shown::OutOfDate);
        }
        assert_eq!(rgb.len(), (w * h * 3) as usize, "pixels of the swapchain's size");
        let d = self.gpu.shared.device.clone();
        unsafe { d.wait_for_fences(&[self.fence], true, u64::MAX) }.vk("vkWaitForFences")?;
        let index = match unsafe {
            self.swapchain_fn.acquire_next_image(self.swapchain, u64::MAX, self.acquired, vk::Fence::null())
        } {
            Ok((i, false)) => i,
            Ok((_, true)) | Err(vk::Result::ERROR_OUT_OF_DATE_KHR) => {
                // Suboptimal images are also given up: the acquire signalled `acquired`, which
                // a fresh swapchain's first acquire must not find signalled, so wait it out.
                self.drain_acquired()?;
                return Ok(Shown::OutOfDate);
            }
            Err(e) => return Err(GpuError::Vk { call: "vkAcquireNextImageKHR", result: e }),
        };
        let bytes = (w * h * 4) as u64;
        let staging = self.buffer(false, 12 * (w * h) as u64)?;
        let bgra = matches!(self.format.format, vk::Format::B8G8R8A8_UNORM | vk::Format::B8G8R8A8_SRGB);
        // Safety: the mapping holds 12 bytes a pixel, and the fence above says that no pass of
        // the last frame reads it still (its tone map ran before its copy, which the fence ends).
        unsafe { std::ptr::copy_nonoverlapping(rgb.as_ptr() as *const u8, staging.1, rgb.len() * 4) };
        if self.packed.as_ref().map_or(true, |b| b.size() < bytes) {
            self.packed = None;
            self.packed = Some(self.gpu.buffer("view tone-mapped", bytes)?);
        }
        let packed = self.packed.clone().expect("made above");
        let pass = Pass::new("view.tonemap", self.role, &self.tonemap)
            .read(0, &staging.0)
            .write(1, &packed)
            .push(&TonemapPush { pixels: w * h, scale: exposure.exp2(), bgra: bgra as u32 })
            .cover_linear(w * h);
        let mapped = self.gpu.submit(self.role, &[pass], &[])?;
        let readback = if read { Some(self.buffer(true, bytes)?) } else { None };
        let image = self.images[index as usize];
        // Where the image cannot be read, the tone map's bytes are read instead.
        let read_from = if self.readable { None } else { Some(packed.raw()) };
        self.record(image, packed.raw(), readback.as_ref().map(|r| r.0.raw()), read_from)?;
        unsafe { d.reset_fences(&[self.fence]) }.vk("vkResetFences")?;
        // The copy waits for the tone map on its role's timeline (same queue or another).
        let waits = [
            vk::SemaphoreSubmitInfo::default()
                .semaphore(self.acquired)
                .stage_mask(vk::PipelineStageFlags2::ALL_TRANSFER),
            vk::SemaphoreSubmitInfo::default()
                .semaphore(self.gpu.shared.role(self.role).timeline)
                .value(mapped.value)
                .stage_mask(vk::PipelineStageFlags2::ALL_TRANSFER),
        ];
        let signals = [vk::SemaphoreSubmitInfo::default()
            .semaphore(self.copied[index as usize])
            .stage_mask(vk::PipelineStageFlags2::ALL_TRANSFER)];
        let cmds = [vk::CommandBufferSubmitInfo::default().command_buffer(self.cmd)];
        let submit = vk::SubmitInfo2::default()
            .wait_semaphore_infos(&waits)
            .command_buffer_infos(&cmds)
            .signal_semaphore_infos(&signals);
        unsafe { d.queue_submit2(self.queue, &[submit], self.fence) }.vk("vkQueueSubmit2")?;
        let swapchains = [self.swapchain];
        let indices = [index];
        let wait = [self.copied[index as usize]];
        let info = vk::PresentInfoKHR::default().wait_semaphores(&wait).swapchains(&swapchains).image_indices(&indices);
        let outdated = match unsafe { self.swapchain_fn.queue_present(self.queue, &info) } {
            Ok(suboptimal) => suboptimal,
            Err(vk::Result::ERROR_OUT_OF_DATE_KHR) => true,
            Err(e) => return Err(GpuError::Vk { call: "vkQueuePresentKHR", result: e }),
        };
        let pixels = if read {
            unsafe { d.wait_for_fences(&[self.fence], true, u64::MAX) }.vk("vkWaitForFences")?;
            let src = readback.as_ref().expect("asked for").1;
            let shown = unsafe { std::slice::from_raw_parts(src as *const u8, bytes as usize) };
            let mut rgb = Vec::with_capacity((w * h * 3) as usize);
            for p in shown.chunks_exact(4) {
                rgb.extend_from_slice(&if bgra { [p[2], p[1], p[0]] } else { [p[0], p[1], p[2]] });
            }
            Some(rgb)
        } else {
            None
        };
        if outdated {
            return Ok(Shown::OutOfDate);
        }
        Ok(Shown::Presented(pixels))
    }

    /// Whether [`Presenter::show`] reads the shown swapchain image back (else the tone map's
    /// bytes that were copied into it: a surface whose images cannot be copied from).
    pub fn reads_back(&self) -> bool {
        self.readable
    }

    /// Wait for the semaphore an abandoned acquire signalled, by a submission that only waits
    /// on it (so the next acquire may use it again).
    fn drain_acquired(&mut self) -> Result<()> {
        let d = &self.gpu.shared.device;
        unsafe { d.reset_fences(&[self.fence]) }.vk("vkResetFences")?;
        let waits = [vk::SemaphoreSubmitInfo::default()
            .semaphore(self.acquired)
            .stage_mask(vk::PipelineStageFlags2::ALL_COMMANDS)];
        let submit = vk::SubmitInfo2::default().wait_semaphore_infos(&waits);
        unsafe { d.queue_submit2(self.queue, &[submit], self.fence) }.vk("vkQueueSubmit2")?;
        unsafe { d.wait_for_fences(&[self.fence], true, u64::MAX) }.vk("vkWaitForFences")
    }

    /// The mapped upload (`readback` false: a storage buffer the tone map reads) or readback
    /// buffer of at least `bytes`, kept between frames.
    fn buffer(&mut self, readback: bool, bytes: u64) -> Result<(Buffer, *mut u8)> {
        let slot = if readback { &mut self.readback } else { &mut self.staging };
        if slot.as_ref().map_or(true, |(b, _)| b.size() < bytes) {
            *slot = None;
            *slot = Some(if readback {
                self.gpu.staging("view readback", bytes, MemoryLocation::GpuToCpu, false)?
            } else {
                self.gpu.mapped_storage("view upload", bytes, MemoryLocation::CpuToGpu)?
            });
        }
        let (b, p) = slot.as_ref().expect("made above");
        Ok((b.clone(), *p))
    }

    /// Record: the image to a copy destination, the tone map's bytes into it, (read back: the
    /// image, or `read_from` where the image cannot be read), and the image to presentation.
    fn record(
        &self,
        image: vk::Image,
        src: vk::Buffer,
        readback: Option<vk::Buffer>,
        read_from: Option<vk::Buffer>,
    ) -> Result<()> {
        let d = &self.gpu.shared.device;
        let c = self.cmd;
        let range =
            vk::ImageSubresourceRange::default().aspect_mask(vk::ImageAspectFlags::COLOR).level_count(1).layer_count(1);
        let barrier = |old, new, src_stage, src_access, dst_stage, dst_access| {
            vk::ImageMemoryBarrier2::default()
                .image(image)
                .subresource_range(range)
                .old_layout(old)
                .new_layout(new)
                .src_stage_mask(src_stage)
                .src_access_mask(src_access)
                .dst_stage_mask(dst_stage)
                .dst_access_mask(dst_access)
        };
        let region = vk::BufferImageCopy::default()
            .image_subresource(
                vk::ImageSubresourceLayers::default().aspect_mask(vk::ImageAspectFlags::COLOR).layer_count(1),
            )
            .image_extent(vk::Extent3D { width: self.extent.width, height: self.extent.height, depth: 1 });
        let t = vk::PipelineStageFlags2::ALL_TRANSFER;
        unsafe {
            d.reset_command_buffer(c, vk::CommandBufferResetFlags::empty()).vk("vkResetCommandBuffer")?;
            let begin = vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
            d.begin_command_buffer(c, &begin).vk("vkBeginCommandBuffer")?;
            // The acquire's semaphore wait is at the transfer stage: the layout change after it.
            let to_dst = [barrier(
                vk::ImageLayout::UNDEFINED,
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                t,
                vk::AccessFlags2::NONE,
                t,
                vk::AccessFlags2::TRANSFER_WRITE,
            )];
            d.cmd_pipeline_barrier2(c, &vk::DependencyInfo::default().image_memory_barriers(&to_dst));
            d.cmd_copy_buffer_to_image(c, src, image, vk::ImageLayout::TRANSFER_DST_OPTIMAL, &[region]);
            let mut last = vk::ImageLayout::TRANSFER_DST_OPTIMAL;
            if let (Some(dst), Some(from)) = (readback, read_from) {
                let size = 4 * self.extent.width as u64 * self.extent.height as u64;
                d.cmd_copy_buffer(c, from, dst, &[vk::BufferCopy::default().size(size)]);
            } else if let Some(dst) = readback {
                let to_src = [barrier(
                    last,
                    vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                    t,
                    vk::AccessFlags2::TRANSFER_WRITE,
                    t,
                    vk::AccessFlags2::TRANSFER_READ,
                )];
                d.cmd_pipeline_barrier2(c, &vk::DependencyInfo::default().image_memory_barriers(&to_src));
                d.cmd_copy_image_to_buffer(c, image, vk::ImageLayout::TRANSFER_SRC_OPTIMAL, dst, &[region]);
                last = vk::ImageLayout::TRANSFER_SRC_OPTIMAL;
            }
            if readback.is_some() {
                // The host reads the readback buffer after the fence.
                let host = [vk::MemoryBarrier2::default()
                    .src_stage_mask(t)
                    .src_access_mask(vk::AccessFlags2::TRANSFER_WRITE)
                    .dst_stage_mask(vk::PipelineStageFlags2::HOST)
                    .dst_access_mask(vk::AccessFlags2::HOST_READ)];
                d.cmd_pipeline_barrier2(c, &vk::DependencyInfo::default().memory_barriers(&host));
            }
            // Presentation needs no access mask: the semaphore it waits on makes the writes
            // visible (the spec's note on vkQueuePresentKHR).
            let to_present = [barrier(
                last,
                vk::ImageLayout::PRESENT_SRC_KHR,
                t,
                vk::AccessFlags2::TRANSFER_WRITE,
                vk::PipelineStageFlags2::NONE,
                vk::AccessFlags2::NONE,
            )];
            d.cmd_pipeline_barrier2(c, &vk::DependencyInfo::default().image_memory_barriers(&to_present));
            d.end_command_buffer(c).vk("vkEndCommandBuffer")?;
        }
        Ok(())
    }
}

impl Drop for Presenter {
    fn drop(&mut self) {
        let d = self.gpu.shared.device.clone();
        // Nothing of ours may be in use when it is destroyed: the last copy, and the present
        // engine's hold on the images (a queue wait covers the presentation's semaphore wait).
        unsafe {
            let _ = d.wait_for_fences(&[self.fence], true, u64::MAX);
            let _ = d.queue_wait_idle(self.queue);
        }
        self.destroy_swapchain();
        self.staging = None;
        self.packed = None;
        self.readback = None;
        unsafe {
            d.destroy_fence(self.fence, None);
            d.destroy_semaphore(self.acquired, None);
            d.destroy_command_pool(self.pool, None);
            self.surface_fn.destroy_surface(self.surface, None);
        }
    }
}
