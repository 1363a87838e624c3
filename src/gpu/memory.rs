//! Buffers and 3D images through gpu-allocator, each with a debug name; they free themselves
//! when the last reference (including an in-flight submission's) is dropped.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Instant;

use ash::vk;
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme};
use gpu_allocator::MemoryLocation;

use super::context::{Gpu, Shared};
use super::error::{GpuError, Result, VkContext};
use super::host::HostKind;
use super::queues::QueueRole;
use super::submit::SyncPoint;

pub(crate) struct BufferInner {
    pub shared: Arc<Shared>,
    pub raw: vk::Buffer,
    pub allocation: Option<Allocation>,
    pub size: u64,
    pub name: String,
    /// Shared with the transfer role's family too (`Gpu::transfer_buffer`, `Gpu::host_buffer`).
    pub transfer: bool,
    /// Per queue role, the last timeline value of a submission that used it (0: none): a
    /// readback or a host write waits for these only, not for every queue, so a thread reading
    /// back its own results does not wait for another role's work (path's light paths beside
    /// its camera paths).
    pub last_use: [AtomicU64; 3],
    /// The submission of set-up work (super::setup) that last wrote it: value << 2 | role, 0
    /// for none.
    pub setup_point: AtomicU64,
    /// In memory the solvers meant for the device alone (`MemoryLocation::GpuOnly`).
    pub device_local: bool,
}

/// Return an allocation to gpu-allocator (after its Vulkan object is destroyed). A failure
/// here can only leak memory until the device goes, so it is not propagated from `drop`.
fn free_allocation(shared: &Shared, allocation: Option<Allocation>) {
    if let (Some(a), Ok(mut alloc)) = (allocation, shared.allocator.lock()) {
        if let Some(alloc) = alloc.as_mut() {
            let _ = alloc.free(a);
        }
    }
}

impl Drop for BufferInner {
    fn drop(&mut self) {
        unsafe { self.shared.device.destroy_buffer(self.raw, None) };
        free_allocation(&self.shared, self.allocation.take());
    }
}

/// A storage buffer. Cloning shares it.
#[derive(Clone)]
pub struct Buffer {
    pub(crate) inner: Arc<BufferInner>,
}

impl Buffer {
    pub fn size(&self) -> u64 {
        self.inner.size
    }
    pub fn name(&self) -> &str {
        &self.inner.name
    }
    pub(crate) fn raw(&self) -> vk::Buffer {
        self.inner.raw
    }
    /// Record that the submission reaching `value` on `role` uses this buffer.
    pub(crate) fn mark_use(&self, role: QueueRole, value: u64) {
        self.inner.last_use[role.index()].fetch_max(value, Ordering::SeqCst);
    }
    /// The points after which no submitted work touches this buffer.
    pub(crate) fn last_uses(&self) -> Vec<SyncPoint> {
        QueueRole::ALL
            .iter()
            .map(|r| SyncPoint { role: *r, value: self.inner.last_use[r.index()].load(Ordering::SeqCst) })
            .filter(|p| p.value > 0)
            .collect()
    }
    /// Host pointer when the memory is host-visible and coherent (lavapipe, ReBAR), else None.
    fn mapped(&self) -> Option<*mut u8> {
        let a = self.inner.allocation.as_ref()?;
        if !a.memory_properties().contains(vk::MemoryPropertyFlags::HOST_COHERENT)
            || (self.inner.device_local && self.inner.shared.unmapped_device_memory)
        {
            return None;
        }
        a.mapped_ptr().map(|p| p.as_ptr() as *mut u8)
    }
}

pub(crate) struct ImageInner {
    pub shared: Arc<Shared>,
    pub raw: vk::Image,
    pub view: vk::ImageView,
    pub allocation: Option<Allocation>,
    pub dims: [u32; 3],
    pub name: String,
    /// The submission of set-up work that uploaded it (super::setup), as `Buffer`'s.
    pub setup_point: AtomicU64,
}

impl Drop for ImageInner {
    fn drop(&mut self) {
        unsafe {
            self.shared.device.destroy_image_view(self.view, None);
            self.shared.device.destroy_image(self.raw, None);
        }
        free_allocation(&self.shared, self.allocation.take());
    }
}

/// A 3D storage image (always in `GENERAL` layout once created), for volumes larger than a
/// storage buffer binding may be (`maxStorageBufferRange`, 128 MiB on lavapipe).
#[derive(Clone)]
pub struct Image3d {
    pub(crate) inner: Arc<ImageInner>,
}

impl Image3d {
    pub fn dims(&self) -> [u32; 3] {
        self.inner.dims
    }
    pub fn name(&self) -> &str {
        &self.inner.name
    }
    pub fn bytes(&self) -> u64 {
        self.inner.dims.iter().map(|d| *d as u64).product::<u64>() * 4
    }
}

/// The whole of a 3D image: its one colour mip level and layer (views and layout changes).
pub(crate) const WHOLE_VOLUME: vk::ImageSubresourceRange = vk::ImageSubresourceRange {
    aspect_mask: vk::ImageAspectFlags::COLOR,
    base_mip_level: 0,
    level_count: 1,
    base_array_layer: 0,
    layer_count: 1,
};

/// Supported 3D image formats.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VolumeFormat {
    /// One f32 per voxel (`r32f` in GLSL).
    R32F,
}

impl VolumeFormat {
    fn vk(self) -> vk::Format {
        match self {
            VolumeFormat::R32F => vk::Format::R32_SFLOAT,
        }
    }
}

/// A host-visible staging buffer kept for the next upload or readback, with its mapping.
pub(crate) struct Staging {
    buffer: Buffer,
    ptr: *mut u8,
}

// Safety: the mapping lives as long as the buffer; it is used under the cache's lock only.
unsafe impl Send for Staging {}

/// Staging buffers up to this size are kept for reuse (one for uploads, one for readbacks);
/// larger ones are made for the copy and freed after it.
const STAGING_KEEP: u64 = 256 << 20;

impl Gpu {
    /// Run `f` with a staging buffer of at least `n` bytes for uploads (`readback` false) or
    /// readbacks, reusing the one kept from the last copy of that kind. Making and mapping a
    /// fresh one per copy cost ~6 ms per 8 MB readback on the H100 (mostly first-touch faults
    /// of the new mapping), 121-153 ms of lbl's 128^3 frame.
    fn with_staging<R>(&self, n: u64, readback: bool, f: impl FnOnce(&Buffer, *mut u8) -> Result<R>) -> Result<R> {
        let (location, name) = if readback {
            (MemoryLocation::GpuToCpu, "staging readback")
        } else {
            (MemoryLocation::CpuToGpu, "staging upload")
        };
        if n > STAGING_KEEP {
            let (b, p) = self.staging(name, n, location, false)?;
            return f(&b, p);
        }
        let mut cache = self.staging_cache.lock().expect("staging cache lock");
        let slot = &mut cache[readback as usize];
        if slot.as_ref().map_or(true, |s| s.buffer.size() < n) {
            *slot = None;
            let size = n.next_power_of_two().clamp(1 << 20, STAGING_KEEP);
            let (buffer, ptr) = self.staging(name, size, location, false)?;
            *slot = Some(Staging { buffer, ptr });
        }
        let st = slot.as_ref().expect("made above");
        f(&st.buffer, st.ptr)
    }

    fn sharing<'a>(&'a self, families: &'a [u32]) -> (vk::SharingMode, &'a [u32]) {
        // Roles on different families share resources concurrently rather than by ownership
        // transfers: small and obvious, and lavapipe can never exercise the transfer path.
        if families.len() > 1 {
            (vk::SharingMode::CONCURRENT, families)
        } else {
            (vk::SharingMode::EXCLUSIVE, &[])
        }
    }

    /// A storage buffer of `size` bytes in device memory, zero-filled.
    pub fn buffer(&self, name: &str, size: u64) -> Result<Buffer> {
        self.storage_buffer(name, size, false)
    }

    /// A storage buffer that the `transfer` role may also copy to and from (dom's block pool):
    /// shared with the transfer-only family where the device has one. Ordinary buffers are not:
    /// concurrent sharing may cost a driver its per-family optimisations, and the copies' reach
    /// stays explicit (a copy on the transfer role of any other buffer is refused). (On the H100
    /// a marching pass that ran 2x longer once every buffer was shared three ways stayed so
    /// when they were not: the cause was the queues' overlap, docs/devices.)
    pub fn transfer_buffer(&self, name: &str, size: u64) -> Result<Buffer> {
        self.storage_buffer(name, size, true)
    }

    fn storage_buffer(&self, name: &str, size: u64, transfer: bool) -> Result<Buffer> {
        let max = self.shared.info.max_storage_buffer_range;
        if size > max {
            return Err(GpuError::BindingTooLarge { name: name.into(), bytes: size, max });
        }
        let b = self.raw_buffer(
            name,
            size.max(4),
            // Any of them may be bound as a uniform block too (a table read at uniform addresses).
            vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::UNIFORM_BUFFER,
            MemoryLocation::GpuOnly,
            transfer,
        )?;
        // A new buffer: no submitted work can touch it yet, so no wait before the memset.
        self.zero(&b, false)?;
        Ok(b)
    }

    /// A small storage buffer in host-visible memory, zero-filled, for what the device tells the
    /// host once per batch (convergence records, stop flags): the host reads it through its
    /// mapping after one wait, with no copy submitted and waited for. Keep it small: on a
    /// discrete GPU shaders reach it across the bus.
    pub fn feedback_buffer(&self, name: &str, size: u64) -> Result<Buffer> {
        let b =
            self.raw_buffer(name, size.max(4), vk::BufferUsageFlags::STORAGE_BUFFER, MemoryLocation::GpuToCpu, false)?;
        self.zero(&b, false)?;
        Ok(b)
    }

    /// A storage buffer holding `data`.
    pub fn buffer_with<T: bytemuck::Pod>(&self, name: &str, data: &[T]) -> Result<Buffer> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let b = self.buffer(name, bytes.len() as u64)?;
        self.write_buffer(&b, 0, bytes)?;
        Ok(b)
    }

    fn raw_buffer(
        &self,
        name: &str,
        size: u64,
        usage: vk::BufferUsageFlags,
        location: MemoryLocation,
        transfer: bool,
    ) -> Result<Buffer> {
        let started = Instant::now();
        let s = &self.shared;
        let (mode, fams) = self.sharing(if transfer { &s.copy_families } else { &s.sharing_families });
        let info = vk::BufferCreateInfo::default()
            .size(size)
            .usage(usage | vk::BufferUsageFlags::TRANSFER_SRC | vk::BufferUsageFlags::TRANSFER_DST)
            .sharing_mode(mode)
            .queue_family_indices(fams);
        let raw = unsafe { s.device.create_buffer(&info, None) }.vk("vkCreateBuffer")?;
        let requirements = unsafe { s.device.get_buffer_memory_requirements(raw) };
        let allocation = {
            let mut guard = s.allocator.lock().expect("allocator lock");
            let alloc = guard.as_mut().expect("allocator alive");
            alloc.allocate(&AllocationCreateDesc {
                name,
                requirements,
                location,
                linear: true,
                allocation_scheme: AllocationScheme::GpuAllocatorManaged,
            })
        };
        let allocation = match allocation {
            Ok(a) => a,
            Err(e) => {
                unsafe { s.device.destroy_buffer(raw, None) };
                return Err(GpuError::Alloc { name: name.into(), bytes: size, reason: e.to_string() });
            }
        };
        unsafe { s.device.bind_buffer_memory(raw, allocation.memory(), allocation.offset()) }
            .vk("vkBindBufferMemory")?;
        s.name_object(raw, name);
        self.host_add(HostKind::Allocations, size, started);
        Ok(Buffer {
            inner: Arc::new(BufferInner {
                shared: s.clone(),
                raw,
                allocation: Some(allocation),
                size,
                name: name.into(),
                transfer,
                last_use: Default::default(),
                setup_point: Default::default(),
                device_local: location == MemoryLocation::GpuOnly,
            }),
        })
    }

    /// A host-visible buffer of `size` bytes for copies to and from device buffers
    /// ([`Gpu::submit_copies`]), with its mapped pointer (valid while the buffer lives).
    pub fn host_buffer(&self, name: &str, size: u64) -> Result<(Buffer, *mut u8)> {
        self.staging(name, size, MemoryLocation::GpuToCpu, true)
    }

    pub(crate) fn staging(
        &self,
        name: &str,
        size: u64,
        location: MemoryLocation,
        transfer: bool,
    ) -> Result<(Buffer, *mut u8)> {
        self.mapped(name, size, vk::BufferUsageFlags::empty(), location, transfer)
    }

    /// A host-visible buffer of `usage` (besides copies) and its mapping.
    fn mapped(
        &self,
        name: &str,
        size: u64,
        usage: vk::BufferUsageFlags,
        location: MemoryLocation,
        transfer: bool,
    ) -> Result<(Buffer, *mut u8)> {
        let b = self.raw_buffer(name, size.max(4), usage, location, transfer)?;
        let a = b.inner.allocation.as_ref().expect("allocated");
        let p = a.mapped_ptr().ok_or_else(|| GpuError::Alloc {
            name: name.into(),
            bytes: size,
            reason: "the memory is not host-visible".into(),
        })?;
        Ok((b, p.as_ptr() as *mut u8))
    }

    /// A host-visible storage buffer and its mapping: data the host writes each frame and a
    /// pass reads where it lies (`scatterlab view`'s linear image, read by its tone map).
    pub(crate) fn mapped_storage(&self, name: &str, size: u64, location: MemoryLocation) -> Result<(Buffer, *mut u8)> {
        self.mapped(name, size, vk::BufferUsageFlags::STORAGE_BUFFER, location, false)
    }

    /// Zero every byte of `b` (a fill on the device, or a memset where it is host-visible).
    pub fn fill_zero(&self, b: &Buffer) -> Result<()> {
        self.zero(b, true)
    }

    /// [`Gpu::fill_zero`]; `in_use`: work already submitted may still read or write `b`, so a
    /// memset waits for it (as [`Gpu::write_buffer`] does).
    fn zero(&self, b: &Buffer, in_use: bool) -> Result<()> {
        let started = Instant::now();
        if let Some(p) = b.mapped() {
            if in_use {
                self.wait_points(&b.last_uses())?;
            }
            unsafe { std::ptr::write_bytes(p, 0, b.size() as usize) };
            self.host_add(HostKind::Fills, b.size(), started);
            return Ok(());
        }
        // A buffer no submitted work uses is zeroed by the next submission (super::setup).
        if !in_use || self.idle(b) {
            self.defer_fill(b);
            return Ok(());
        }
        let raw = b.raw();
        let size = b.size();
        self.one_shot(std::slice::from_ref(b), |d, cb| unsafe { d.cmd_fill_buffer(cb, raw, 0, size, 0) })?;
        self.host_add(HostKind::Fills, size, started);
        Ok(())
    }

    /// Write `bytes` at `offset` (direct when the memory is host-visible, else via staging).
    pub fn write_buffer(&self, b: &Buffer, offset: u64, bytes: &[u8]) -> Result<()> {
        let end = offset + bytes.len() as u64;
        if end > b.size() {
            return Err(GpuError::OutOfRange {
                name: b.name().into(),
                offset,
                wanted: bytes.len() as u64,
                size: b.size(),
            });
        }
        if bytes.is_empty() {
            return Ok(());
        }
        let started = Instant::now();
        if let Some(p) = b.mapped() {
            // Host writes to coherent memory are made visible by the next queue submission;
            // work still using the buffer must be done first.
            self.wait_points(&b.last_uses())?;
            unsafe { std::ptr::copy_nonoverlapping(bytes.as_ptr(), p.add(offset as usize), bytes.len()) };
            self.host_add(HostKind::Uploads, bytes.len() as u64, started);
            return Ok(());
        }
        let n = bytes.len() as u64;
        // Into a buffer no submitted work uses: staged in the ring and copied by the next
        // submission (super::setup), with no submission and wait of its own.
        if self.idle(b) && self.defer_upload(b, offset, bytes)? {
            return Ok(());
        }
        self.with_staging(n, false, |stage, p| {
            unsafe { std::ptr::copy_nonoverlapping(bytes.as_ptr(), p, bytes.len()) };
            let (src, dst) = (stage.raw(), b.raw());
            self.one_shot(&[stage.clone(), b.clone()], |d, cb| unsafe {
                d.cmd_copy_buffer(cb, src, dst, &[vk::BufferCopy { src_offset: 0, dst_offset: offset, size: n }])
            })
        })?;
        self.host_add(HostKind::Uploads, n, started);
        Ok(())
    }

    /// Read the whole buffer back to the host, after all submitted work has finished.
    pub fn read_buffer(&self, b: &Buffer) -> Result<Vec<u8>> {
        self.read_buffer_prefix(b, b.size())
    }

    /// Read the first `bytes` bytes of a buffer (at most its size) back to the host, after all
    /// submitted work has finished.
    pub fn read_buffer_prefix(&self, b: &Buffer, bytes: u64) -> Result<Vec<u8>> {
        let n = bytes.min(b.size());
        let started = Instant::now();
        // Set-up work is never recorded for a mapped buffer, and one_shot submits what is
        // recorded before its copy.
        if let Some(p) = b.mapped() {
            // Only the work that used this buffer: another role's work goes on meanwhile.
            self.wait_points(&b.last_uses())?;
            let mut out = vec![0u8; n as usize];
            unsafe { std::ptr::copy_nonoverlapping(p, out.as_mut_ptr(), out.len()) };
            self.host_add(HostKind::Readbacks, n, started);
            return Ok(out);
        }
        // The copy waits on the device for the work that used the buffer, the host for the copy.
        let out = self.with_staging(n, true, |stage, p| {
            let (src, dst) = (b.raw(), stage.raw());
            self.one_shot(&[stage.clone(), b.clone()], |d, cb| unsafe {
                d.cmd_copy_buffer(cb, src, dst, &[vk::BufferCopy { src_offset: 0, dst_offset: 0, size: n }])
            })?;
            let mut out = vec![0u8; n as usize];
            unsafe { std::ptr::copy_nonoverlapping(p, out.as_mut_ptr(), out.len()) };
            Ok(out)
        })?;
        self.host_add(HostKind::Readbacks, n, started);
        Ok(out)
    }

    /// Read a buffer as a typed vector.
    pub fn read_buffer_as<T: bytemuck::Pod>(&self, b: &Buffer) -> Result<Vec<T>> {
        self.read_buffer_prefix_as(b, b.size())
    }

    /// Read the first `bytes` bytes of a buffer as a typed vector ([`Gpu::read_buffer_prefix`]).
    pub fn read_buffer_prefix_as<T: bytemuck::Pod>(&self, b: &Buffer, bytes: u64) -> Result<Vec<T>> {
        Ok(bytemuck::pod_collect_to_vec(&self.read_buffer_prefix(b, bytes)?))
    }

    /// A 3D storage image holding `data` (x fastest), left in `GENERAL` layout.
    pub fn image3d_with(&self, name: &str, dims: [u32; 3], format: VolumeFormat, data: &[f32]) -> Result<Image3d> {
        let s = &self.shared;
        let maxd = s.info.max_image_dimension_3d;
        if dims.iter().any(|d| *d == 0 || *d > maxd) {
            return Err(GpuError::Alloc {
                name: name.into(),
                bytes: 0,
                reason: format!("dims {dims:?} outside 1..={maxd} (maxImageDimension3D)"),
            });
        }
        let voxels: u64 = dims.iter().map(|d| *d as u64).product();
        if data.len() as u64 != voxels {
            return Err(GpuError::OutOfRange {
                name: name.into(),
                offset: 0,
                wanted: data.len() as u64 * 4,
                size: voxels * 4,
            });
        }
        let (mode, fams) = self.sharing(&s.sharing_families);
        let info = vk::ImageCreateInfo::default()
            .image_type(vk::ImageType::TYPE_3D)
            .format(format.vk())
            .extent(vk::Extent3D { width: dims[0], height: dims[1], depth: dims[2] })
            .mip_levels(1)
            .array_layers(1)
            .samples(vk::SampleCountFlags::TYPE_1)
            .tiling(vk::ImageTiling::OPTIMAL)
            .usage(vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::TRANSFER_DST | vk::ImageUsageFlags::TRANSFER_SRC)
            .sharing_mode(mode)
            .queue_family_indices(fams)
            .initial_layout(vk::ImageLayout::UNDEFINED);
        let raw = unsafe { s.device.create_image(&info, None) }.vk("vkCreateImage")?;
        let requirements = unsafe { s.device.get_image_memory_requirements(raw) };
        let allocation = {
            let mut guard = s.allocator.lock().expect("allocator lock");
            guard.as_mut().expect("allocator alive").allocate(&AllocationCreateDesc {
                name,
                requirements,
                location: MemoryLocation::GpuOnly,
                linear: false,
                allocation_scheme: AllocationScheme::GpuAllocatorManaged,
            })
        };
        let allocation = match allocation {
            Ok(a) => a,
            Err(e) => {
                unsafe { s.device.destroy_image(raw, None) };
                return Err(GpuError::Alloc { name: name.into(), bytes: requirements.size, reason: e.to_string() });
            }
        };
        unsafe { s.device.bind_image_memory(raw, allocation.memory(), allocation.offset()) }.vk("vkBindImageMemory")?;
        let range = WHOLE_VOLUME;
        let view = unsafe {
            s.device.create_image_view(
                &vk::ImageViewCreateInfo::default()
                    .image(raw)
                    .view_type(vk::ImageViewType::TYPE_3D)
                    .format(format.vk())
                    .subresource_range(range),
                None,
            )
        }
        .vk("vkCreateImageView")?;
        s.name_object(raw, name);
        let image = Image3d {
            inner: Arc::new(ImageInner {
                shared: s.clone(),
                raw,
                view,
                allocation: Some(allocation),
                dims,
                name: name.into(),
                setup_point: Default::default(),
            }),
        };

        // Staged now (the caller's slice may go away) and copied by the next submission's set-up
        // work (super::setup): no submission and host wait of its own.
        let started = Instant::now();
        let (stage, p) = self.staging("staging volume upload", voxels * 4, MemoryLocation::CpuToGpu, false)?;
        unsafe { std::ptr::copy_nonoverlapping(data.as_ptr() as *const u8, p, data.len() * 4) };
        self.defer_image_upload(stage, &image);
        self.host_add(HostKind::Uploads, voxels * 4, started);
        Ok(image)
    }
}
