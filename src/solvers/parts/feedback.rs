//! Shared part: the record an iterative solver's convergence test keeps on the device, and its
//! way to the host (glsl/feedback/copy.comp). The record lives in device memory, where the test
//! writes it and every pass of a batch reads its stop word; a pass at the batch's start clears
//! it, one at its end copies it into a small host-visible buffer that the host reads through
//! its mapping after its one wait per batch (no copy submitted and waited for afterwards).
//! Used by `lbl`'s lattice, `dom`'s iterations and `networks`.

use bytemuck::{Pod, Zeroable};

use crate::gpu::{Buffer, Gpu, Kernel, Pass, Pipeline, QueueRole};

use crate::solvers::interface::SolverError;

pub const COPY: Kernel =
    Kernel { shader: shader!("feedback/copy"), push_bytes: std::mem::size_of::<CopyPush>(), spec: &[] };

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct CopyPush {
    words: u32,
    clear: u32,
}

/// A device record of `bytes` (a multiple of 4) and its host-visible copy.
pub struct Feedback {
    device: Buffer,
    host: Buffer,
    pipeline: Pipeline,
    words: u32,
}

impl Feedback {
    pub fn new(gpu: &Gpu, name: &str, bytes: u64) -> Result<Feedback, SolverError> {
        let words = bytes.div_ceil(4).max(1);
        Ok(Feedback {
            device: gpu.buffer(name, 4 * words)?,
            host: gpu.feedback_buffer(&format!("{name} (host copy)"), 4 * words)?,
            pipeline: gpu.pipeline(&COPY, &[])?,
            words: words as u32,
        })
    }

    /// The device record, which the test's passes bind.
    pub fn record(&self) -> &Buffer {
        &self.device
    }

    fn pass(&self, clear: bool, role: QueueRole) -> Pass {
        Pass::new(if clear { "feedback.clear" } else { "feedback.copy" }, role, &self.pipeline)
            .read_write(0, &self.device)
            .write(1, &self.host)
            .push(&CopyPush { words: self.words, clear: clear as u32 })
            .cover_linear(self.words)
    }

    /// Zero the record (before the first batch of a run of iterations).
    pub fn clear_pass(&self, role: QueueRole) -> Pass {
        self.pass(true, role)
    }

    /// Copy the record to the host (a batch's last pass).
    pub fn copy_pass(&self, role: QueueRole) -> Pass {
        self.pass(false, role)
    }

    /// The record as the last copy left it (after the wait for its batch).
    pub fn read<T: Pod>(&self, gpu: &Gpu) -> Result<T, SolverError> {
        let bytes = gpu.read_buffer_prefix(&self.host, std::mem::size_of::<T>() as u64)?;
        Ok(bytemuck::pod_read_unaligned(&bytes))
    }

    /// The record's words as the last copy left it.
    pub fn read_words(&self, gpu: &Gpu) -> Result<Vec<u32>, SolverError> {
        Ok(gpu.read_buffer_as(&self.host)?)
    }

    /// Device bytes of the record and its copy.
    pub fn bytes(record_bytes: u64) -> u64 {
        2 * 4 * record_bytes.div_ceil(4).max(1)
    }

    pub fn device_bytes(&self) -> u64 {
        self.device.size() + self.host.size()
    }
}
