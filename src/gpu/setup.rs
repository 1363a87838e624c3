//! Set-up work that waits for the next submission: zero-fills of new device-local buffers,
//! uploads into buffers no submitted work uses, staged through one ring of host-visible memory,
//! and the uploads of new 3D images (each from a staging buffer of its own, kept until the copy
//! has run).
//!
//! Where device memory is not host-visible (a discrete GPU without resizable BAR), each fill
//! and each upload used to be a submission of its own and a host wait for it: a render's 20-40
//! buffers were as many round trips before its first pass (23-28 ms of allocations and 30-33 ms
//! of uploads per render on the H200, issue 42). Now they are recorded here and go to the GPU
//! in one command buffer, submitted just before the next submission, copy or readback that
//! could see them, on the queue that submission goes to: the host never waits for them. A
//! buffer made ready on one compute role and first used on another is waited for on the device
//! ([`Gpu::setup_waits`]).
//!
//! Uploads are copied into the ring at once (the caller's slice may go away), so the ring's
//! regions are reused only after the submission that read them has finished: a wrap that meets a
//! region still in flight waits for it (rare: the ring holds [`RING_BYTES`]), one that meets a
//! region not yet submitted submits the batch first. Larger uploads, and writes into buffers
//! that submitted work may still use, keep the old path (a copy waited for).

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use ash::vk;
use gpu_allocator::MemoryLocation;

use super::context::Gpu;
use super::error::Result;
use super::host::HostKind;
use super::memory::{Buffer, Image3d, WHOLE_VOLUME};
use super::queues::QueueRole;
use super::submit::{latest_per_role, memory_barrier, Resource, SyncPoint};

/// The upload ring's size: a render's scene, grids and tables (the 128^3 cloud's density is 8
/// MiB) fit several times over. Uploads above a quarter of it are copied on their own.
pub(crate) const RING_BYTES: u64 = 32 << 20;

enum Op {
    /// Zero the whole buffer.
    Fill(Buffer),
    /// Copy `size` bytes from the ring at `src` to `dst` at `offset`.
    Copy { src: u64, dst: Buffer, offset: u64, size: u64 },
    /// Copy the whole of `stage` into the new `image` and leave it in `GENERAL` layout.
    Image { stage: Buffer, image: Image3d },
}

impl Op {
    /// The buffer the op writes (an image is new: nothing else in the batch writes it).
    fn dst(&self) -> Option<&Buffer> {
        match self {
            Op::Fill(b) => Some(b),
            Op::Copy { dst, .. } => Some(dst),
            Op::Image { .. } => None,
        }
    }

    /// What the submission must keep alive until it has run.
    fn resources(&self) -> Vec<Resource> {
        match self {
            Op::Fill(b) | Op::Copy { dst: b, .. } => vec![Resource::from(b)],
            Op::Image { stage, image } => vec![Resource::from(stage), Resource::from(image)],
        }
    }
}

/// Record the upload of a whole 3D image from a buffer: UNDEFINED -> TRANSFER_DST, the copy,
/// TRANSFER_DST -> GENERAL (made visible to every later command).
///
/// # Safety
/// `cb` is a command buffer of `d` in the recording state.
unsafe fn record_image_upload(d: &ash::Device, cb: vk::CommandBuffer, src: vk::Buffer, image: &Image3d) {
    let (raw, dims, range) = (image.inner.raw, image.dims(), WHOLE_VOLUME);
    let barrier = |from: vk::ImageLayout, to: vk::ImageLayout| {
        vk::ImageMemoryBarrier2::default()
            .old_layout(from)
            .new_layout(to)
            .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
            .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
            .image(raw)
            .subresource_range(range)
    };
    let to_dst = barrier(vk::ImageLayout::UNDEFINED, vk::ImageLayout::TRANSFER_DST_OPTIMAL)
        .src_stage_mask(vk::PipelineStageFlags2::NONE)
        .dst_stage_mask(vk::PipelineStageFlags2::COPY)
        .dst_access_mask(vk::AccessFlags2::TRANSFER_WRITE);
    d.cmd_pipeline_barrier2(cb, &vk::DependencyInfo::default().image_memory_barriers(std::slice::from_ref(&to_dst)));
    let region = vk::BufferImageCopy::default()
        .image_subresource(vk::ImageSubresourceLayers {
            aspect_mask: vk::ImageAspectFlags::COLOR,
            mip_level: 0,
            base_array_layer: 0,
            layer_count: 1,
        })
        .image_extent(vk::Extent3D { width: dims[0], height: dims[1], depth: dims[2] });
    d.cmd_copy_buffer_to_image(cb, src, raw, vk::ImageLayout::TRANSFER_DST_OPTIMAL, &[region]);
    let to_general = barrier(vk::ImageLayout::TRANSFER_DST_OPTIMAL, vk::ImageLayout::GENERAL)
        .src_stage_mask(vk::PipelineStageFlags2::COPY)
        .src_access_mask(vk::AccessFlags2::TRANSFER_WRITE)
        .dst_stage_mask(vk::PipelineStageFlags2::ALL_COMMANDS)
        .dst_access_mask(vk::AccessFlags2::MEMORY_READ | vk::AccessFlags2::MEMORY_WRITE);
    d.cmd_pipeline_barrier2(
        cb,
        &vk::DependencyInfo::default().image_memory_barriers(std::slice::from_ref(&to_general)),
    );
}

/// A region of the ring and the submission that reads it (`None`: not submitted yet).
struct Region {
    start: u64,
    end: u64,
    point: Option<SyncPoint>,
}

struct Ring {
    buffer: Buffer,
    ptr: *mut u8,
    head: u64,
    regions: VecDeque<Region>,
}

// Safety: the mapping lives as long as the buffer, and is written under the set-up lock only.
unsafe impl Send for Ring {}

/// Recorded set-up work and the upload ring (one per device, behind `Gpu::setup`).
#[derive(Default)]
pub(crate) struct Setup {
    ops: Vec<Op>,
    ring: Option<Ring>,
    /// Submissions of set-up work so far (tests read it: a render's are a handful).
    pub flushes: u64,
}

/// What reserving ring space found.
enum Reserve {
    At(u64),
    /// The space is held by work not yet submitted: submit the batch, then try again.
    Flush,
    /// The space is held by a submission in flight: wait for it, then try again.
    Wait(SyncPoint),
}

impl Ring {
    fn reserve(&mut self, n: u64) -> Reserve {
        // 256-byte aligned starts: optimalBufferCopyOffsetAlignment is at most that anywhere.
        let n = n.next_multiple_of(256);
        let start = if self.head + n <= self.buffer.size() { self.head } else { 0 };
        let end = start + n;
        let overlaps = |r: &Region| r.start < end && start < r.end;
        if let Some(r) = self.regions.iter().find(|r| overlaps(r)) {
            return match r.point {
                None => Reserve::Flush,
                Some(p) => Reserve::Wait(p),
            };
        }
        self.head = end;
        self.regions.push_back(Region { start, end, point: None });
        Reserve::At(start)
    }

    /// Forget regions whose submissions have finished (`done` says which have).
    fn release(&mut self, done: impl Fn(SyncPoint) -> bool) {
        self.regions.retain(|r| r.point.map_or(true, |p| !done(p)));
    }
}

impl Gpu {
    /// Whether no submitted work can still touch `b` (every last use waited for).
    pub(crate) fn idle(&self, b: &Buffer) -> bool {
        b.last_uses().into_iter().all(|p| self.reached_known(p))
    }

    fn reached_known(&self, p: SyncPoint) -> bool {
        self.submit.lock().expect("submit lock").completed[p.role.index()] >= p.value
    }

    /// Zero `b` before its first use, without a submission of its own.
    pub(crate) fn defer_fill(&self, b: &Buffer) {
        let started = Instant::now();
        self.setup.lock().expect("setup lock").ops.push(Op::Fill(b.clone()));
        self.host_add(HostKind::Fills, b.size(), started);
    }

    /// Upload the new `image` from `stage` (host-visible, filled) with the next set-up batch.
    pub(crate) fn defer_image_upload(&self, stage: Buffer, image: &Image3d) {
        self.setup.lock().expect("setup lock").ops.push(Op::Image { stage, image: image.clone() });
    }

    /// Stage `bytes` for `b` at `offset` through the ring, without a submission of its own.
    /// `false`: too large for the ring; the caller copies it itself.
    pub(crate) fn defer_upload(&self, b: &Buffer, offset: u64, bytes: &[u8]) -> Result<bool> {
        let n = bytes.len() as u64;
        if n > RING_BYTES / 4 {
            return Ok(false);
        }
        let started = Instant::now();
        loop {
            let mut setup = self.setup.lock().expect("setup lock");
            if setup.ring.is_none() {
                let (buffer, ptr) = self.staging("staging upload ring", RING_BYTES, MemoryLocation::CpuToGpu, false)?;
                setup.ring = Some(Ring { buffer, ptr, head: 0, regions: VecDeque::new() });
            }
            let ring = setup.ring.as_mut().expect("made above");
            ring.release(|p| self.reached_known(p));
            match ring.reserve(n) {
                Reserve::At(src) => {
                    unsafe { std::ptr::copy_nonoverlapping(bytes.as_ptr(), ring.ptr.add(src as usize), bytes.len()) };
                    setup.ops.push(Op::Copy { src, dst: b.clone(), offset, size: n });
                    drop(setup);
                    self.host_add(HostKind::Uploads, n, started);
                    return Ok(true);
                }
                Reserve::Flush => {
                    drop(setup);
                    self.flush_setup(QueueRole::Trace)?;
                }
                Reserve::Wait(p) => {
                    drop(setup);
                    self.wait(p)?;
                }
            }
        }
    }

    /// Submit the recorded set-up work on `role` (a compute role: every buffer is shared with
    /// those), before a submission, copy or readback that may see it. No host wait.
    pub(crate) fn flush_setup(&self, role: QueueRole) -> Result<()> {
        let role = if role == QueueRole::Transfer { QueueRole::Trace } else { role };
        let mut setup = self.setup.lock().expect("setup lock");
        if setup.ops.is_empty() {
            return Ok(());
        }
        let ops = std::mem::take(&mut setup.ops);
        let ring = setup.ring.as_ref().map(|r| (r.buffer.clone(), r.buffer.raw()));
        let mut keep: Vec<Resource> = ops.iter().flat_map(Op::resources).collect();
        if let Some((b, _)) = &ring {
            keep.push(Resource::from(b));
        }
        let d = self.shared.device.clone();
        let ring_raw = ring.as_ref().map(|r| r.1);
        let point =
            self.record_and_submit(role, &[], vec!["setup".into()], keep, Vec::new(), None, |cb, _| unsafe {
                let written = (vk::PipelineStageFlags2::ALL_TRANSFER, vk::AccessFlags2::TRANSFER_WRITE);
                // In order; a barrier only before an op on a buffer an earlier op of this batch
                // wrote (a fill and then an upload into the same buffer).
                let mut touched = std::collections::HashSet::new();
                for op in &ops {
                    if let Some(dst) = op.dst().map(Buffer::raw) {
                        if !touched.insert(dst) {
                            memory_barrier(&d, cb, written, written);
                            touched.clear();
                            touched.insert(dst);
                        }
                    }
                    match op {
                        Op::Fill(b) => d.cmd_fill_buffer(cb, b.raw(), 0, b.size(), 0),
                        Op::Copy { src, dst, offset, size } => d.cmd_copy_buffer(
                            cb,
                            ring_raw.expect("a copy has a ring"),
                            dst.raw(),
                            &[vk::BufferCopy { src_offset: *src, dst_offset: *offset, size: *size }],
                        ),
                        Op::Image { stage, image } => record_image_upload(&d, cb, stage.raw(), image),
                    }
                }
                // Everything after reads or writes what the batch wrote.
                memory_barrier(
                    &d,
                    cb,
                    written,
                    (
                        vk::PipelineStageFlags2::ALL_COMMANDS,
                        vk::AccessFlags2::MEMORY_READ | vk::AccessFlags2::MEMORY_WRITE,
                    ),
                );
            })?;
        for op in &ops {
            match op {
                Op::Image { image, .. } => image.set_setup_point(point),
                _ => op.dst().expect("a buffer op writes a buffer").set_setup_point(point),
            }
        }
        if let Some(r) = setup.ring.as_mut() {
            for region in r.regions.iter_mut().filter(|r| r.point.is_none()) {
                region.point = Some(point);
            }
        }
        setup.flushes += 1;
        Ok(())
    }

    /// Device waits that a submission on `role` using `resources` needs for set-up work
    /// submitted on another role and not known to be done (one per role, its highest value).
    pub(crate) fn setup_waits<'a>(
        &self,
        role: QueueRole,
        resources: impl Iterator<Item = &'a Resource>,
    ) -> Vec<SyncPoint> {
        let points = resources.filter_map(|r| match r {
            Resource::Buffer(b) => b.setup_point(),
            Resource::Image(i) => i.setup_point(),
        });
        latest_per_role(points.filter(|p| p.role != role && !self.reached_known(*p)))
    }

    /// Submissions of set-up work since the device opened.
    pub fn setup_submissions(&self) -> u64 {
        self.setup.lock().expect("setup lock").flushes
    }
}

/// A set-up point kept in one word: value << 2 | role, 0 for none.
fn store_point(word: &AtomicU64, p: SyncPoint) {
    word.store(p.value << 2 | p.role.index() as u64, Ordering::SeqCst);
}

fn load_point(word: &AtomicU64) -> Option<SyncPoint> {
    let v = word.load(Ordering::SeqCst);
    (v != 0).then(|| SyncPoint { role: QueueRole::ALL[(v & 3) as usize], value: v >> 2 })
}

impl Buffer {
    pub(crate) fn set_setup_point(&self, p: SyncPoint) {
        store_point(&self.inner.setup_point, p);
    }
    /// The submission of the set-up work that last wrote this buffer, if any.
    pub(crate) fn setup_point(&self) -> Option<SyncPoint> {
        load_point(&self.inner.setup_point)
    }
}

impl Image3d {
    pub(crate) fn set_setup_point(&self, p: SyncPoint) {
        store_point(&self.inner.setup_point, p);
    }
    /// The submission of the set-up work that uploaded this image, if any.
    pub(crate) fn setup_point(&self) -> Option<SyncPoint> {
        load_point(&self.inner.setup_point)
    }
}
