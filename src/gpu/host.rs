//! Where a render's host time goes between GPU passes: the Vulkan core counts and times what
//! it does on the host (pipelines built, buffers allocated, zero-filled, uploaded and read
//! back, command buffers recorded and submitted, waits). On a CPU driver the GPU work is the
//! host's, so these are small against it; on a real GPU they are what stands between the
//! passes (docs/devices/nvidia-h100-2026-11-25: 15 ms of GPU work in a 322 ms frame).

use serde::Serialize;
use std::time::Instant;

/// Count, bytes where they mean something, and host milliseconds of one kind of host work.
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq)]
pub struct HostCost {
    pub count: u64,
    pub bytes: u64,
    pub ms: f64,
}

impl HostCost {
    fn add(&mut self, bytes: u64, started: Instant) {
        self.add_n(1, bytes, started);
    }
    fn add_n(&mut self, n: u64, bytes: u64, started: Instant) {
        self.count += n;
        self.bytes += bytes;
        self.ms += started.elapsed().as_secs_f64() * 1e3;
    }
}

/// The host work of the Vulkan core since the last [`crate::gpu::Gpu::take_host_times`].
/// Inclusive: an upload's staging allocation, submission and wait count under `uploads` and
/// again under `allocations`, `submits` and `waits`; the kinds do not add up to the wall time.
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq)]
pub struct HostTimes {
    /// Compute pipelines built (SPIR-V compiled by the driver).
    pub pipelines: HostCost,
    /// Buffers created, their memory allocated and bound (bytes: their sizes).
    pub allocations: HostCost,
    /// Device buffers zero-filled (a memset where host-visible, else a fill recorded for the
    /// next submission: gpu/setup.rs).
    pub fills: HostCost,
    /// Host data written into buffers (through a staging buffer where not host-visible).
    pub uploads: HostCost,
    /// Buffers read back to the host.
    pub readbacks: HostCost,
    /// Command buffers recorded and submitted.
    pub submits: HostCost,
    /// Host waits for the GPU (timeline semaphores).
    pub waits: HostCost,
}

#[derive(Clone, Copy)]
pub(crate) enum HostKind {
    Pipelines,
    Allocations,
    Fills,
    Uploads,
    Readbacks,
    Submits,
    Waits,
}

impl HostTimes {
    pub(crate) fn add(&mut self, kind: HostKind, bytes: u64, started: Instant) {
        self.cost(kind).add(bytes, started);
    }

    /// `n` of `kind` done together since `started` (pipelines built in parallel: their count,
    /// and the wall time of the lot).
    pub(crate) fn add_count(&mut self, kind: HostKind, n: u64, started: Instant) {
        self.cost(kind).add_n(n, 0, started);
    }

    fn cost(&mut self, kind: HostKind) -> &mut HostCost {
        match kind {
            HostKind::Pipelines => &mut self.pipelines,
            HostKind::Allocations => &mut self.allocations,
            HostKind::Fills => &mut self.fills,
            HostKind::Uploads => &mut self.uploads,
            HostKind::Readbacks => &mut self.readbacks,
            HostKind::Submits => &mut self.submits,
            HostKind::Waits => &mut self.waits,
        }
    }

    /// One line for a render's summary: the kinds that took at least a millisecond.
    pub fn summary(&self) -> Option<String> {
        let kinds = [
            ("pipelines", &self.pipelines, false),
            ("allocations", &self.allocations, true),
            ("fills", &self.fills, false),
            ("uploads", &self.uploads, true),
            ("readbacks", &self.readbacks, true),
            ("submits", &self.submits, false),
            ("waits", &self.waits, false),
        ];
        let parts: Vec<String> = kinds
            .iter()
            .filter(|(_, c, _)| c.ms >= 1.0)
            .map(|(name, c, bytes)| {
                if *bytes {
                    format!("{name} {:.1} ms ({}, {:.1} MiB)", c.ms, c.count, c.bytes as f64 / 1048576.0)
                } else {
                    format!("{name} {:.1} ms ({})", c.ms, c.count)
                }
            })
            .collect();
        (!parts.is_empty()).then(|| format!("host: {} (inclusive)", parts.join(", ")))
    }
}
