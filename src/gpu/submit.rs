//! Passes as data, and their submission on queue roles ordered by timeline semaphores.
//!
//! A solver describes a pass (name, role, pipeline, bindings with access, push constants,
//! workgroups) and hands a list of them to [`Gpu::submit`] with the `(role, value)` points it
//! waits on. This module records the barriers, semaphore waits and timestamps; solvers never do.
//!
//! Host-order rule (vulkan-notes.md): a submission is made only after every submission it waits
//! on has been submitted, since on a shared queue (lavapipe) a wait placed before its signal
//! deadlocks. [`Gpu::submit`] refuses such a submission with an error instead of hanging.

use std::collections::HashSet;
use std::sync::Arc;
use std::time::Instant;

use ash::vk;
use serde::Serialize;

use super::context::Gpu;
use super::error::{GpuError, Result, VkContext};
use super::memory::{Buffer, Image3d};
use super::pipeline::{BindingKind, Pipeline};
use super::queues::QueueRole;

/// How a pass uses a binding.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Access {
    Read,
    Write,
    ReadWrite,
}

impl Access {
    fn writes(self) -> bool {
        !matches!(self, Access::Read)
    }
}

/// A resource a pass binds; holding it keeps the resource alive while the GPU uses it.
#[derive(Clone)]
pub enum Resource {
    Buffer(Buffer),
    Image(Image3d),
}

impl Resource {
    fn key(&self) -> u64 {
        use ash::vk::Handle;
        match self {
            Resource::Buffer(b) => b.raw().as_raw(),
            Resource::Image(i) => i.inner.raw.as_raw(),
        }
    }
    fn kind(&self) -> BindingKind {
        match self {
            Resource::Buffer(_) => BindingKind::StorageBuffer,
            Resource::Image(_) => BindingKind::StorageImage,
        }
    }
    fn name(&self) -> &str {
        match self {
            Resource::Buffer(b) => b.name(),
            Resource::Image(i) => i.name(),
        }
    }
    fn mark_use(&self, role: QueueRole, value: u64) {
        if let Resource::Buffer(b) = self {
            b.mark_use(role, value);
        }
    }
}

impl From<&Buffer> for Resource {
    fn from(b: &Buffer) -> Self {
        Resource::Buffer(b.clone())
    }
}
impl From<&Image3d> for Resource {
    fn from(i: &Image3d) -> Self {
        Resource::Image(i.clone())
    }
}

#[derive(Clone)]
pub struct Bind {
    pub binding: u32,
    pub access: Access,
    pub resource: Resource,
}

/// One buffer-to-buffer copy ([`Gpu::submit_copies`]), byte offsets and size.
#[derive(Clone)]
pub struct Copy {
    pub src: Buffer,
    pub src_offset: u64,
    pub dst: Buffer,
    pub dst_offset: u64,
    pub size: u64,
}

/// Work groups along x that every Vulkan device dispatches (the spec's minimum
/// maxComputeWorkGroupCount, and lavapipe's limit): [`Pass::cover_linear`] folds past it, in
/// rows of exactly this many (glsl/include/linear.glsl's LINEAR_ROW).
pub const MAX_GROUPS_X: u32 = 65535;

/// One compute dispatch, described as data.
#[derive(Clone)]
pub struct Pass {
    pub name: String,
    pub role: QueueRole,
    pub pipeline: Pipeline,
    pub bindings: Vec<Bind>,
    pub push: Vec<u8>,
    pub groups: [u32; 3],
}

impl Pass {
    pub fn new(name: impl Into<String>, role: QueueRole, pipeline: &Pipeline) -> Pass {
        Pass {
            name: name.into(),
            role,
            pipeline: pipeline.clone(),
            bindings: Vec::new(),
            push: Vec::new(),
            groups: [1, 1, 1],
        }
    }
    pub fn read(mut self, binding: u32, r: impl Into<Resource>) -> Pass {
        self.bindings.push(Bind { binding, access: Access::Read, resource: r.into() });
        self
    }
    pub fn write(mut self, binding: u32, r: impl Into<Resource>) -> Pass {
        self.bindings.push(Bind { binding, access: Access::Write, resource: r.into() });
        self
    }
    pub fn read_write(mut self, binding: u32, r: impl Into<Resource>) -> Pass {
        self.bindings.push(Bind { binding, access: Access::ReadWrite, resource: r.into() });
        self
    }
    pub fn push<T: bytemuck::Pod>(mut self, constants: &T) -> Pass {
        self.push = bytemuck::bytes_of(constants).to_vec();
        self
    }
    /// Dispatch enough workgroups to cover `n` invocations (workgroup size from reflection).
    pub fn cover(mut self, n: [u32; 3]) -> Pass {
        self.groups = self.pipeline.groups_for(n);
        self
    }
    /// Cover a line of `n` invocations for a kernel that indexes it by `linear_id()`
    /// (glsl/include/linear.glsl): at most [`MAX_GROUPS_X`] groups along x, further rows of them
    /// along y. A line of more than 65535 groups is common (the march's history at 7 lights of
    /// 65536 rays, dom's voxels past 162^3, a 2048^2 frame) and past lavapipe's limit.
    pub fn cover_linear(self, n: u32) -> Pass {
        let (x, rows) = self.fold(n);
        self.groups([x, rows, 1])
    }

    /// [`Pass::cover_linear`] for a kernel whose y indexes something else (`rows` of it) and
    /// whose line folds along z (`linear_id_z()`).
    pub fn cover_linear_z(self, [n, rows]: [u32; 2]) -> Pass {
        let (x, folds) = self.fold(n);
        let y = self.pipeline.groups_for([1, rows, 1])[1];
        self.groups([x, y, folds])
    }

    /// Groups along x and the rows of them that cover `n` invocations.
    fn fold(&self, n: u32) -> (u32, u32) {
        let groups = self.pipeline.groups_for([n, 1, 1])[0];
        if groups <= MAX_GROUPS_X {
            (groups, 1)
        } else {
            (MAX_GROUPS_X, groups.div_ceil(MAX_GROUPS_X))
        }
    }

    pub fn groups(mut self, g: [u32; 3]) -> Pass {
        self.groups = g;
        self
    }

    /// Check bindings and push constants against the shader's reflected interface.
    pub fn check(&self) -> Result<()> {
        let refl = &self.pipeline.reflection;
        let mut seen = HashSet::new();
        for b in &self.bindings {
            let err = |reason: String| GpuError::Binding { pass: self.name.clone(), binding: b.binding, reason };
            if !seen.insert(b.binding) {
                return Err(err("bound twice".into()));
            }
            match refl.bindings.get(&b.binding) {
                None => {
                    return Err(err(format!(
                        "{:?} is bound but shader {} declares no such binding",
                        b.resource.name(),
                        self.pipeline.name
                    )))
                }
                // A buffer binds as a storage buffer or a uniform block alike.
                Some((kind, decl))
                    if *kind != b.resource.kind()
                        && !(*kind == BindingKind::UniformBuffer
                            && b.resource.kind() == BindingKind::StorageBuffer) =>
                {
                    return Err(err(format!(
                        "shader declares `{decl}` as {kind:?} but the pass binds {:?}, a {:?}",
                        b.resource.name(),
                        b.resource.kind()
                    )))
                }
                _ => {}
            }
        }
        for (index, (kind, decl)) in &refl.bindings {
            if !seen.contains(index) {
                return Err(GpuError::Binding {
                    pass: self.name.clone(),
                    binding: *index,
                    reason: format!("shader declares `{decl}` ({kind:?}) but the pass binds nothing there"),
                });
            }
        }
        if self.push.len() != refl.push_constant_bytes {
            return Err(GpuError::PushConstants {
                pass: self.name.clone(),
                given: self.push.len(),
                expected: refl.push_constant_bytes,
            });
        }
        Ok(())
    }
}

/// A point on a role's timeline: "the role's work up to `value` is done".
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct SyncPoint {
    pub role: QueueRole,
    pub value: u64,
}

/// GPU time of one pass, from timestamps on its queue. Times are nanoseconds on the host's
/// CLOCK_MONOTONIC where the device offers calibrated timestamps, else on the device clock.
#[derive(Clone, Debug, Serialize)]
pub struct PassTiming {
    pub name: String,
    pub role: QueueRole,
    pub submission: u64,
    pub start_ns: i128,
    pub end_ns: i128,
    pub host_clock: bool,
}

impl PassTiming {
    pub fn duration_ms(&self) -> f64 {
        (self.end_ns - self.start_ns) as f64 * 1e-6
    }
}

struct InFlight {
    point: SyncPoint,
    cb: vk::CommandBuffer,
    queries: Option<vk::QueryPool>,
    names: Vec<String>,
    // Resources and pipelines stay alive until the GPU is done with them.
    _keep: Vec<Resource>,
    _pipelines: Vec<Pipeline>,
    /// (device ticks, host ns) pair taken at submission, to place timestamps on the host clock.
    calibration: Option<(u64, i128)>,
}

#[derive(Default)]
pub(crate) struct SubmitState {
    submitted: [u64; 3],
    /// Per role, the highest value a host wait has waited for: a wait for no more returns at
    /// once and is not counted as a round trip. Only waits raise it (not a poll of the
    /// timeline): the count of host waits is then the code's own, the same on a CPU driver,
    /// which finishes work while it is submitted, as on a GPU, which runs behind the host.
    pub(crate) completed: [u64; 3],
    /// When the first submission of passes since the last [`Gpu::take_first_submit`] was
    /// made: a render's start-up is the time before it (pipelines, allocations, uploads).
    first_submit: Option<Instant>,
    in_flight: Vec<InFlight>,
    timings: Vec<PassTiming>,
}

/// Record one global memory barrier: what `src_stage` did through `src_access` is made visible
/// to `dst_access` in `dst_stage`. Every barrier of the core is one of these.
///
/// # Safety
/// `cb` is a command buffer of `d` in the recording state.
pub(crate) unsafe fn memory_barrier(
    d: &ash::Device,
    cb: vk::CommandBuffer,
    (src_stage, src_access): (vk::PipelineStageFlags2, vk::AccessFlags2),
    (dst_stage, dst_access): (vk::PipelineStageFlags2, vk::AccessFlags2),
) {
    let mb = vk::MemoryBarrier2::default()
        .src_stage_mask(src_stage)
        .src_access_mask(src_access)
        .dst_stage_mask(dst_stage)
        .dst_access_mask(dst_access);
    d.cmd_pipeline_barrier2(cb, &vk::DependencyInfo::default().memory_barriers(std::slice::from_ref(&mb)));
}

/// One point per role, its highest value: what waiting for all of `points` takes.
pub(crate) fn latest_per_role(points: impl IntoIterator<Item = SyncPoint>) -> Vec<SyncPoint> {
    let mut merged: Vec<SyncPoint> = Vec::new();
    for p in points {
        match merged.iter_mut().find(|m| m.role == p.role) {
            Some(m) => m.value = m.value.max(p.value),
            None => merged.push(p),
        }
    }
    merged
}

/// The last handle to a device waits for the work still in flight before the submissions'
/// resources (buffers, images, pipelines, command buffers, query pools) go: dropped at once,
/// they were destroyed while the device still used them (the validation layer's
/// VUID-vkDestroyBuffer-buffer-00922 after a timeout; on lavapipe, whose threads then write
/// freed memory, a heap corruption such as glibc's "malloc_consolidate(): unaligned fastbin
/// chunk" or a segfault). Work that does not finish within [`super::context::DROP_GRACE`] (a hung
/// device) keeps its resources forever: leaked, never freed under the device.
impl Drop for Gpu {
    fn drop(&mut self) {
        if Arc::strong_count(&self.submit) > 1 {
            return;
        }
        // One lock, held to the end, never taken again here (a lock that cannot be had is left
        // alone: the records go as they did before).
        let Ok(mut st) = self.submit.try_lock() else { return };
        if st.in_flight.is_empty() {
            return;
        }
        let points: Vec<SyncPoint> = QueueRole::ALL
            .iter()
            .map(|r| SyncPoint { role: *r, value: st.submitted[r.index()] })
            .filter(|p| p.value > st.completed[p.role.index()])
            .collect();
        let s = &self.shared;
        let sems: Vec<vk::Semaphore> = points.iter().map(|p| s.role(p.role).timeline).collect();
        let values: Vec<u64> = points.iter().map(|p| p.value).collect();
        let info = vk::SemaphoreWaitInfo::default().semaphores(&sems).values(&values);
        let grace = super::context::DROP_GRACE.as_nanos() as u64;
        let in_flight = std::mem::take(&mut st.in_flight);
        if points.is_empty() || unsafe { s.device.wait_semaphores(&info, grace) }.is_ok() {
            // Finished: each record's query pool and command buffer go, then its resources.
            for f in in_flight {
                unsafe {
                    if let Some(pool) = f.queries {
                        s.device.destroy_query_pool(pool, None);
                    }
                    s.device.free_command_buffers(s.role(f.point.role).pool, &[f.cb]);
                }
            }
        } else {
            eprintln!(
                "warning: the device did not finish its work within {} s of being closed; its resources are left \
                 allocated rather than freed under it",
                super::context::DROP_GRACE.as_secs()
            );
            std::mem::forget(in_flight);
        }
    }
}

impl Gpu {
    /// The last value submitted on a role's timeline.
    pub fn submitted(&self, role: QueueRole) -> SyncPoint {
        let st = self.submit.lock().expect("submit lock");
        SyncPoint { role, value: st.submitted[role.index()] }
    }

    fn calibration(&self) -> Option<(u64, i128)> {
        let cal = self.shared.calibrated.as_ref()?;
        let infos = [
            vk::CalibratedTimestampInfoEXT::default().time_domain(vk::TimeDomainEXT::DEVICE),
            vk::CalibratedTimestampInfoEXT::default().time_domain(vk::TimeDomainEXT::CLOCK_MONOTONIC),
        ];
        let (ts, _dev) = unsafe { cal.get_calibrated_timestamps(&infos) }.ok()?;
        Some((ts[0], ts[1] as i128))
    }

    /// Record `passes` into one command buffer on `role`'s queue, waiting on `waits`, and
    /// signal the role's next timeline value, which is returned.
    pub fn submit(&self, role: QueueRole, passes: &[Pass], waits: &[SyncPoint]) -> Result<SyncPoint> {
        self.submit.lock().expect("submit lock").first_submit.get_or_insert_with(Instant::now);
        let max = self.shared.info.max_compute_workgroup_count;
        for p in passes {
            p.check()?;
            // Past the limit the validation layer reports it and a driver may run anything
            // (lavapipe: 65535 per dimension; lbl's march at 7 lights of 65536 rays asked 104192).
            if p.groups.iter().zip(&max).any(|(g, m)| g > m) {
                return Err(GpuError::TooManyGroups { pass: p.name.clone(), groups: p.groups, max });
            }
            if p.role != role {
                return Err(GpuError::Binding {
                    pass: p.name.clone(),
                    binding: 0,
                    reason: format!("pass is for role {} but was submitted on {role}", p.role),
                });
            }
        }
        // Set-up work recorded since the last submission goes first, on this queue; what
        // another role set up is waited for on the device (super::setup).
        self.flush_setup(role)?;
        let mut waits = waits.to_vec();
        waits.extend(self.setup_waits(role, passes.iter().flat_map(|p| p.bindings.iter()).map(|b| &b.resource)));
        let waits = &waits[..];
        let passes_owned = passes.to_vec();
        let names: Vec<String> = passes.iter().map(|p| p.name.clone()).collect();
        let s = self.shared.clone();
        let d = &s.device;
        let push = &s.push_descriptor;
        let with_queries = self.timed(role) && !passes.is_empty();
        self.record_and_submit(
            role,
            waits,
            names,
            passes_owned.iter().flat_map(|p| p.bindings.iter().map(|b| b.resource.clone())).collect(),
            passes_owned.iter().map(|p| p.pipeline.clone()).collect(),
            with_queries.then_some(passes.len() as u32 * 2),
            |cb, pool| unsafe {
                let mut written: HashSet<u64> = HashSet::new();
                let mut read: HashSet<u64> = HashSet::new();
                for (i, p) in passes.iter().enumerate() {
                    // Barrier only where this pass touches what an earlier pass wrote (RAW, WAW) or
                    // writes what an earlier one read (WAR).
                    let hazard = p.bindings.iter().any(|b| {
                        written.contains(&b.resource.key()) || (b.access.writes() && read.contains(&b.resource.key()))
                    });
                    if hazard {
                        memory_barrier(
                            d,
                            cb,
                            (
                                vk::PipelineStageFlags2::COMPUTE_SHADER,
                                vk::AccessFlags2::SHADER_STORAGE_WRITE | vk::AccessFlags2::SHADER_STORAGE_READ,
                            ),
                            (
                                vk::PipelineStageFlags2::COMPUTE_SHADER,
                                vk::AccessFlags2::SHADER_STORAGE_READ
                                    | vk::AccessFlags2::SHADER_STORAGE_WRITE
                                    | vk::AccessFlags2::UNIFORM_READ,
                            ),
                        );
                        written.clear();
                        read.clear();
                    }
                    for b in &p.bindings {
                        if b.access.writes() {
                            written.insert(b.resource.key());
                        } else {
                            read.insert(b.resource.key());
                        }
                    }
                    if let Some(du) = &s.debug_device {
                        if let Ok(label) = std::ffi::CString::new(p.name.as_str()) {
                            du.cmd_begin_debug_utils_label(cb, &vk::DebugUtilsLabelEXT::default().label_name(&label));
                        }
                    }
                    if let Some(pool) = pool {
                        d.cmd_write_timestamp2(cb, vk::PipelineStageFlags2::COMPUTE_SHADER, pool, 2 * i as u32);
                    }
                    d.cmd_bind_pipeline(cb, vk::PipelineBindPoint::COMPUTE, p.pipeline.inner.pipeline);
                    let buffer_infos: Vec<[vk::DescriptorBufferInfo; 1]> = p
                        .bindings
                        .iter()
                        .map(|b| match &b.resource {
                            Resource::Buffer(buf) => {
                                [vk::DescriptorBufferInfo { buffer: buf.raw(), offset: 0, range: vk::WHOLE_SIZE }]
                            }
                            Resource::Image(_) => [vk::DescriptorBufferInfo::default()],
                        })
                        .collect();
                    let image_infos: Vec<[vk::DescriptorImageInfo; 1]> = p
                        .bindings
                        .iter()
                        .map(|b| match &b.resource {
                            Resource::Image(img) => [vk::DescriptorImageInfo {
                                sampler: vk::Sampler::null(),
                                image_view: img.inner.view,
                                image_layout: vk::ImageLayout::GENERAL,
                            }],
                            Resource::Buffer(_) => [vk::DescriptorImageInfo::default()],
                        })
                        .collect();
                    let writes: Vec<vk::WriteDescriptorSet> = p
                        .bindings
                        .iter()
                        .enumerate()
                        .map(|(j, b)| {
                            let w = vk::WriteDescriptorSet::default().dst_binding(b.binding);
                            match &b.resource {
                                Resource::Buffer(_) => {
                                    let ty = match p.pipeline.reflection.bindings.get(&b.binding) {
                                        Some((BindingKind::UniformBuffer, _)) => vk::DescriptorType::UNIFORM_BUFFER,
                                        _ => vk::DescriptorType::STORAGE_BUFFER,
                                    };
                                    w.descriptor_type(ty).buffer_info(&buffer_infos[j])
                                }
                                Resource::Image(_) => {
                                    w.descriptor_type(vk::DescriptorType::STORAGE_IMAGE).image_info(&image_infos[j])
                                }
                            }
                        })
                        .collect();
                    if !writes.is_empty() {
                        push.cmd_push_descriptor_set(
                            cb,
                            vk::PipelineBindPoint::COMPUTE,
                            p.pipeline.inner.layout,
                            0,
                            &writes,
                        );
                    }
                    if !p.push.is_empty() {
                        d.cmd_push_constants(cb, p.pipeline.inner.layout, vk::ShaderStageFlags::COMPUTE, 0, &p.push);
                    }
                    d.cmd_dispatch(cb, p.groups[0], p.groups[1], p.groups[2]);
                    if let Some(pool) = pool {
                        d.cmd_write_timestamp2(cb, vk::PipelineStageFlags2::COMPUTE_SHADER, pool, 2 * i as u32 + 1);
                    }
                    if let Some(du) = &s.debug_device {
                        du.cmd_end_debug_utils_label(cb);
                    }
                }
                // What the passes wrote is visible to the host once the submission's point is
                // reached (feedback records read through their mapping).
                memory_barrier(
                    d,
                    cb,
                    (vk::PipelineStageFlags2::COMPUTE_SHADER, vk::AccessFlags2::SHADER_STORAGE_WRITE),
                    (vk::PipelineStageFlags2::HOST, vk::AccessFlags2::HOST_READ),
                );
            },
        )
    }

    /// Record buffer copies on `role`'s queue, waiting on `waits`: the stages run in order (a
    /// transfer barrier between them), and a last barrier makes what they wrote visible to the
    /// host once the returned point is reached. Streaming (src/solvers/dom/blocks.rs) uses it.
    pub fn submit_copies(&self, role: QueueRole, stages: &[Vec<Copy>], waits: &[SyncPoint]) -> Result<SyncPoint> {
        // A buffer the transfer family was not given (Gpu::transfer_buffer, Gpu::host_buffer)
        // cannot be touched from its queue: refused here, not left to the validation layer.
        if role == QueueRole::Transfer {
            if let Some(b) = stages.iter().flatten().flat_map(|c| [&c.src, &c.dst]).find(|b| !b.inner.transfer) {
                return Err(GpuError::Binding {
                    pass: "copies".into(),
                    binding: 0,
                    reason: format!(
                        "buffer \"{}\" is copied on the transfer role but was not made with Gpu::transfer_buffer or \
                         Gpu::host_buffer",
                        b.name()
                    ),
                });
            }
        }
        self.flush_setup(QueueRole::Trace)?;
        let mut waits = waits.to_vec();
        let copied: Vec<Resource> =
            stages.iter().flatten().flat_map(|c| [Resource::from(&c.src), Resource::from(&c.dst)]).collect();
        waits.extend(self.setup_waits(role, copied.iter()));
        let waits = &waits[..];
        let keep: Vec<Resource> =
            stages.iter().flatten().flat_map(|c| [Resource::from(&c.src), Resource::from(&c.dst)]).collect();
        let d = self.shared.device.clone();
        // Timed like a pass (one "copies" entry on the role's timeline), so streaming shows in
        // the overlap figures and the Perfetto trace beside the sweeps it feeds.
        let timed = self.timed(role);
        self.record_and_submit(
            role,
            waits,
            vec!["copies".into()],
            keep,
            Vec::new(),
            timed.then_some(2),
            |cb, pool| unsafe {
                if let Some(p) = pool {
                    d.cmd_write_timestamp2(cb, vk::PipelineStageFlags2::ALL_TRANSFER, p, 0);
                }
                for (i, stage) in stages.iter().enumerate() {
                    if i > 0 {
                        let transfer = (
                            vk::PipelineStageFlags2::ALL_TRANSFER,
                            vk::AccessFlags2::TRANSFER_WRITE | vk::AccessFlags2::TRANSFER_READ,
                        );
                        memory_barrier(&d, cb, transfer, transfer);
                    }
                    for c in stage {
                        d.cmd_copy_buffer(
                            cb,
                            c.src.raw(),
                            c.dst.raw(),
                            &[vk::BufferCopy { src_offset: c.src_offset, dst_offset: c.dst_offset, size: c.size }],
                        );
                    }
                }
                memory_barrier(
                    &d,
                    cb,
                    (vk::PipelineStageFlags2::ALL_TRANSFER, vk::AccessFlags2::TRANSFER_WRITE),
                    (vk::PipelineStageFlags2::HOST, vk::AccessFlags2::HOST_READ),
                );
                if let Some(p) = pool {
                    d.cmd_write_timestamp2(cb, vk::PipelineStageFlags2::ALL_TRANSFER, p, 1);
                }
            },
        )
    }

    /// Whether work on `role` can be timed: its family has valid timestamps, and its query pools
    /// can be reset (from the host, or by the queue: a transfer-only queue cannot).
    fn timed(&self, role: QueueRole) -> bool {
        let s = &self.shared;
        s.info.queue_families.iter().any(|f| {
            f.index == s.role(role).family
                && f.timestamp_valid_bits > 0
                && (s.host_query_reset || f.compute || f.graphics)
        })
    }

    /// Record a command buffer with `record` and submit it on `role` with waits and a signal.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn record_and_submit(
        &self,
        role: QueueRole,
        waits: &[SyncPoint],
        names: Vec<String>,
        keep: Vec<Resource>,
        pipelines: Vec<Pipeline>,
        query_count: Option<u32>,
        record: impl FnOnce(vk::CommandBuffer, Option<vk::QueryPool>),
    ) -> Result<SyncPoint> {
        let started = Instant::now();
        let s = self.shared.clone();
        let d = &s.device;
        let rq = s.role(role);
        let mut st = self.submit.lock().expect("submit lock");
        for w in waits {
            let submitted = st.submitted[w.role.index()];
            if w.value > submitted {
                return Err(GpuError::WaitBeforeSignal {
                    role: role.to_string(),
                    wait_role: w.role.to_string(),
                    value: w.value,
                    submitted,
                });
            }
        }
        let cb = unsafe {
            d.allocate_command_buffers(
                &vk::CommandBufferAllocateInfo::default().command_pool(rq.pool).command_buffer_count(1),
            )
        }
        .vk("vkAllocateCommandBuffers")?[0];
        let pool = match query_count {
            Some(n) => Some(
                unsafe {
                    d.create_query_pool(
                        &vk::QueryPoolCreateInfo::default().query_type(vk::QueryType::TIMESTAMP).query_count(n),
                        None,
                    )
                }
                .vk("vkCreateQueryPool")?,
            ),
            None => None,
        };
        unsafe {
            d.begin_command_buffer(
                cb,
                &vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT),
            )
            .vk("vkBeginCommandBuffer")?;
            if let (Some(p), Some(n)) = (pool, query_count) {
                if s.host_query_reset {
                    d.reset_query_pool(p, 0, n);
                } else {
                    d.cmd_reset_query_pool(cb, p, 0, n);
                }
            }
            // Earlier submissions on the same queue are ordered but not made visible without a
            // barrier or semaphore: one global barrier at the start covers that.
            memory_barrier(
                d,
                cb,
                (vk::PipelineStageFlags2::ALL_COMMANDS, vk::AccessFlags2::MEMORY_WRITE),
                (vk::PipelineStageFlags2::ALL_COMMANDS, vk::AccessFlags2::MEMORY_READ | vk::AccessFlags2::MEMORY_WRITE),
            );
            record(cb, pool);
            d.end_command_buffer(cb).vk("vkEndCommandBuffer")?;
        }
        let value = st.submitted[role.index()] + 1;
        let wait_infos: Vec<vk::SemaphoreSubmitInfo> = waits
            .iter()
            .map(|w| {
                vk::SemaphoreSubmitInfo::default()
                    .semaphore(s.role(w.role).timeline)
                    .value(w.value)
                    .stage_mask(vk::PipelineStageFlags2::ALL_COMMANDS)
            })
            .collect();
        let signal = [vk::SemaphoreSubmitInfo::default()
            .semaphore(rq.timeline)
            .value(value)
            .stage_mask(vk::PipelineStageFlags2::ALL_COMMANDS)];
        let cbs = [vk::CommandBufferSubmitInfo::default().command_buffer(cb)];
        let submit = vk::SubmitInfo2::default()
            .wait_semaphore_infos(&wait_infos)
            .command_buffer_infos(&cbs)
            .signal_semaphore_infos(&signal);
        let calibration = if pool.is_some() { self.calibration() } else { None };
        unsafe { d.queue_submit2(rq.queue, &[submit], vk::Fence::null()) }.map_err(|e| match e {
            vk::Result::ERROR_DEVICE_LOST => GpuError::DeviceLost { passes: names.join(", ") },
            e => GpuError::Vk { call: "vkQueueSubmit2", result: e },
        })?;
        st.submitted[role.index()] = value;
        for r in &keep {
            r.mark_use(role, value);
        }
        let point = SyncPoint { role, value };
        st.in_flight.push(InFlight {
            point,
            cb,
            queries: pool,
            names,
            _keep: keep,
            _pipelines: pipelines,
            calibration,
        });
        drop(st);
        self.host_add(super::host::HostKind::Submits, 0, started);
        Ok(point)
    }

    /// Run a one-off command buffer (uploads, readbacks, fills) and wait for it. It waits on
    /// the device for the work that last used `buffers`, and goes on the role that used them where that is one compute role, so a readback of one
    /// role's results queues behind neither another role's work nor a host wait for it.
    pub(crate) fn one_shot(
        &self,
        buffers: &[Buffer],
        record: impl FnOnce(&ash::Device, vk::CommandBuffer),
    ) -> Result<()> {
        // Set-up work recorded before this copy is submitted first: the copy may read or write
        // what it writes, and its point becomes a last use the copy waits for.
        self.flush_setup(QueueRole::Trace)?;
        let keep: Vec<Resource> = buffers.iter().map(Resource::from).collect();
        let waits: Vec<SyncPoint> = buffers.iter().flat_map(|b| b.last_uses()).collect();
        let roles: HashSet<QueueRole> = waits.iter().map(|w| w.role).collect();
        let role = match roles.iter().next() {
            Some(r) if roles.len() == 1 && *r != QueueRole::Transfer => *r,
            _ => QueueRole::Trace,
        };
        // One wait per role, for its highest value.
        let merged = latest_per_role(waits);
        let d = self.shared.device.clone();
        let p = self.record_and_submit(role, &merged, vec!["transfer".into()], keep, Vec::new(), None, |cb, _| {
            record(&d, cb)
        })?;
        self.wait(p)
    }

    /// Whether `point` has been reached, without blocking (progress displays).
    pub fn reached(&self, point: SyncPoint) -> Result<bool> {
        let s = &self.shared;
        let value = unsafe { s.device.get_semaphore_counter_value(s.role(point.role).timeline) }
            .map_err(|e| GpuError::Vk { call: "vkGetSemaphoreCounterValue", result: e })?;
        Ok(value >= point.value)
    }

    /// Block until `point` is reached, or fail after the configured timeout.
    pub fn wait(&self, point: SyncPoint) -> Result<()> {
        self.wait_points(&[point])
    }

    /// [`Gpu::wait`] that calls `tick` every `every` while it waits (to show progress of the
    /// work in flight: `tick` may poll [`Gpu::reached`]): one host wait, counted once.
    pub fn wait_ticking(&self, point: SyncPoint, every: std::time::Duration, mut tick: impl FnMut()) -> Result<()> {
        let s = &self.shared;
        let started = Instant::now();
        loop {
            if self.submit.lock().expect("submit lock").completed[point.role.index()] >= point.value {
                return Ok(());
            }
            let sems = [s.role(point.role).timeline];
            let values = [point.value];
            let info = vk::SemaphoreWaitInfo::default().semaphores(&sems).values(&values);
            match unsafe { s.device.wait_semaphores(&info, every.as_nanos() as u64) } {
                Err(vk::Result::TIMEOUT) if started.elapsed() < self.timeout => tick(),
                // Reached (or failed, or past the limit): the counted wait finishes the job
                // and reports any failure as every wait does.
                _ => return self.wait(point),
            }
        }
    }

    /// Block until every point is reached: one host wait (counted once in the host times), none
    /// where a wait before saw them all reached already.
    pub fn wait_points(&self, points: &[SyncPoint]) -> Result<()> {
        let s = &self.shared;
        let pending: Vec<SyncPoint> = {
            let st = self.submit.lock().expect("submit lock");
            points.iter().copied().filter(|p| p.value > st.completed[p.role.index()]).collect()
        };
        if pending.is_empty() {
            return Ok(());
        }
        let sems: Vec<vk::Semaphore> = pending.iter().map(|p| s.role(p.role).timeline).collect();
        let values: Vec<u64> = pending.iter().map(|p| p.value).collect();
        let info = vk::SemaphoreWaitInfo::default().semaphores(&sems).values(&values);
        let started = Instant::now();
        let r = unsafe { s.device.wait_semaphores(&info, self.timeout.as_nanos().min(u64::MAX as u128) as u64) };
        self.host_add(super::host::HostKind::Waits, 0, started);
        let names = |st: &SubmitState| st.in_flight.iter().flat_map(|f| f.names.iter().cloned()).collect::<Vec<_>>();
        match r {
            Ok(()) => {
                let mut st = self.submit.lock().expect("submit lock");
                for p in &pending {
                    let c = &mut st.completed[p.role.index()];
                    *c = (*c).max(p.value);
                }
                drop(st);
                self.collect()
            }
            Err(vk::Result::TIMEOUT) => {
                let st = self.submit.lock().expect("submit lock");
                let first = pending[0];
                Err(GpuError::Timeout {
                    role: first.role.to_string(),
                    value: first.value,
                    seconds: started.elapsed().as_secs_f64(),
                    passes: names(&st).join(", "),
                })
            }
            Err(vk::Result::ERROR_DEVICE_LOST) => {
                let st = self.submit.lock().expect("submit lock");
                Err(GpuError::DeviceLost { passes: names(&st).join(", ") })
            }
            Err(e) => Err(GpuError::Vk { call: "vkWaitSemaphores", result: e }),
        }
    }

    /// Wait until everything submitted on every role has finished (one host wait).
    pub fn wait_idle_roles(&self) -> Result<()> {
        self.flush_setup(QueueRole::Trace)?;
        let points: Vec<SyncPoint> =
            QueueRole::ALL.iter().map(|r| self.submitted(*r)).filter(|p| p.value > 0).collect();
        self.wait_points(&points)
    }

    /// Free finished submissions and turn their timestamps into [`PassTiming`]s.
    fn collect(&self) -> Result<()> {
        let s = &self.shared;
        let d = &s.device;
        let mut st = self.submit.lock().expect("submit lock");
        let mut reached = [0u64; 3];
        for role in QueueRole::ALL {
            reached[role.index()] =
                unsafe { d.get_semaphore_counter_value(s.role(role).timeline) }.vk("vkGetSemaphoreCounterValue")?;
        }
        let period = s.info.timestamp_period_ns as f64;
        let (done, pending): (Vec<InFlight>, Vec<InFlight>) =
            std::mem::take(&mut st.in_flight).into_iter().partition(|f| f.point.value <= reached[f.point.role.index()]);
        st.in_flight = pending;
        for f in done {
            if let Some(pool) = f.queries {
                let mut ticks = vec![0u64; f.names.len() * 2];
                unsafe {
                    d.get_query_pool_results(
                        pool,
                        0,
                        &mut ticks,
                        vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
                    )
                }
                .vk("vkGetQueryPoolResults")?;
                for (i, name) in f.names.iter().enumerate() {
                    let to_ns = |t: u64| -> i128 {
                        match f.calibration {
                            Some((dev0, host0)) => host0 + ((t as i128 - dev0 as i128) as f64 * period) as i128,
                            None => (t as f64 * period) as i128,
                        }
                    };
                    st.timings.push(PassTiming {
                        name: name.clone(),
                        role: f.point.role,
                        submission: f.point.value,
                        start_ns: to_ns(ticks[2 * i]),
                        end_ns: to_ns(ticks[2 * i + 1]),
                        host_clock: f.calibration.is_some(),
                    });
                }
                unsafe { d.destroy_query_pool(pool, None) };
            }
            unsafe { d.free_command_buffers(s.role(f.point.role).pool, &[f.cb]) };
        }
        Ok(())
    }

    /// When the first submission since the last call was made (and start again).
    pub fn take_first_submit(&self) -> Option<Instant> {
        self.submit.lock().expect("submit lock").first_submit.take()
    }

    /// Take the pass timings collected so far.
    pub fn take_timings(&self) -> Vec<PassTiming> {
        std::mem::take(&mut self.submit.lock().expect("submit lock").timings)
    }
}
