//! Discrete-ordinates sweeps on the device (issue 13's propagation, thesis 5.3): the part the
//! `dom` solver will be built on, checked against the CPU oracle `physics::ordinates`.
//!
//! In-core and isotropic for now: the whole grid and one field per direction live on the
//! device; the eight octants are swept together plane by plane (i + j + k = w in each one's
//! own coordinates, one dispatch per plane, glsl/ordinates/sweep.comp), each octant's directions
//! in turn per invocation into its own fluence slice, so the fluence sums in a fixed order
//! (deterministic, no atomics). Source
//! iteration runs on the host between sweeps (the solver will move it to the device).

use bytemuck::{Pod, Zeroable};

use crate::gpu::{Buffer, Gpu, Kernel, Pass, Pipeline, QueueRole};
use crate::physics::quadrature::Quadrature;

use super::SolverError;

pub const SWEEP: Kernel =
    Kernel { shader: shader!("ordinates/sweep"), push_bytes: std::mem::size_of::<SweepPush>(), spec: &[] };

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct SweepPush {
    dims: [u32; 4],
    plane: i32,
    h: f32,
    slots: u32,
    pad: u32,
    first: [u32; 8],
    count: [u32; 8],
}

/// A grid ready to sweep: extinction and directions on the device, the directions grouped by
/// octant.
pub struct Sweeper {
    pipeline: Pipeline,
    dims: [u32; 3],
    h: f32,
    sigma_t: Buffer,
    emission: Buffer,
    dirs: Buffer,
    field: Buffer,
    fluence: Buffer,
    /// Per octant (bit a set: negative along axis a): its directions' first index in `dirs`
    /// and count.
    first: [u32; 8],
    count: [u32; 8],
    /// Field slots per octant: its largest direction count.
    slots: u32,
}

impl Sweeper {
    /// `sigma_t` per voxel (x fastest) of a `dims` grid of cubic voxels of edge `h`; `q` the
    /// directions.
    pub fn new(gpu: &Gpu, dims: [u32; 3], h: f32, sigma_t: &[f32], q: &Quadrature) -> Result<Sweeper, SolverError> {
        let v = dims.iter().map(|d| *d as u64).product::<u64>();
        let mut sorted: Vec<[f32; 4]> = Vec::with_capacity(q.len());
        let (mut first, mut count) = ([0u32; 8], [0u32; 8]);
        for o in 0..8 {
            let signs = [0, 1, 2].map(|a| if o & (1 << a) != 0 { -1 } else { 1 });
            first[o] = sorted.len() as u32;
            for (d, w) in q.directions.iter().zip(&q.weights) {
                // A direction belongs to the octant of its components' signs (a zero component
                // to the positive side).
                if (0..3).all(|a| (d[a] >= 0.0) == (signs[a] > 0)) {
                    sorted.push([d[0] as f32, d[1] as f32, d[2] as f32, *w as f32]);
                }
            }
            count[o] = sorted.len() as u32 - first[o];
        }
        let slots = count.iter().copied().max().unwrap_or(1).max(1);
        Ok(Sweeper {
            pipeline: gpu.pipeline(&SWEEP, &[])?,
            dims,
            h,
            sigma_t: gpu.buffer_with("ordinates sigma_t", sigma_t)?,
            emission: gpu.buffer("ordinates emission", v * 4)?,
            dirs: gpu.buffer_with("ordinates directions", &sorted)?,
            field: gpu.buffer("ordinates field", 8 * slots as u64 * v * 4)?,
            fluence: gpu.buffer("ordinates fluence", 8 * v * 4)?,
            first,
            count,
            slots,
        })
    }

    /// Field slots per octant that [`Sweeper::new`] allocates for `q`: its octants' largest
    /// direction count (the memory estimate's figure).
    pub fn slots(q: &Quadrature) -> u64 {
        (0..8usize)
            .map(|o| q.directions.iter().filter(|d| (0..3).all(|a| (d[a] >= 0.0) == (o & (1 << a) == 0))).count())
            .max()
            .unwrap_or(1)
            .max(1) as u64
    }

    /// Device bytes of its buffers.
    pub fn device_bytes(&self) -> u64 {
        [&self.sigma_t, &self.emission, &self.dirs, &self.field, &self.fluence].iter().map(|b| b.size()).sum()
    }

    /// One sweep of every direction for `emission` (per unit volume and solid angle, per
    /// voxel): the fluence sum_d w_d I_d per voxel.
    pub fn sweep(&self, gpu: &Gpu, emission: &[f32]) -> Result<Vec<f32>, SolverError> {
        let [nx, ny, nz] = self.dims;
        let v = nx * ny * nz;
        gpu.write_buffer(&self.emission, 0, bytemuck::cast_slice(emission))?;
        gpu.write_buffer(&self.fluence, 0, bytemuck::cast_slice(&vec![0f32; 8 * v as usize]))?;
        let planes = (nx + ny + nz - 2) as i32;
        let passes: Vec<Pass> = (0..planes)
            .map(|w| {
                let push = SweepPush {
                    dims: [nx, ny, nz, v],
                    plane: w,
                    h: self.h,
                    slots: self.slots,
                    pad: 0,
                    first: self.first,
                    count: self.count,
                };
                Pass::new("ordinates.sweep", QueueRole::Diffuse, &self.pipeline)
                    .read(0, &self.sigma_t)
                    .read(1, &self.emission)
                    .read(2, &self.dirs)
                    .read_write(3, &self.field)
                    .read_write(4, &self.fluence)
                    .push(&push)
                    .cover([nx, ny, 8])
            })
            .collect();
        let point = gpu.submit(QueueRole::Diffuse, &passes, &[])?;
        gpu.wait(point)?;
        // The octants' slices, added in a fixed order.
        let slices: Vec<f32> = gpu.read_buffer_as(&self.fluence)?;
        let v = v as usize;
        Ok((0..v).map(|i| (0..8).map(|o| slices[o * v + i]).sum()).collect())
    }
}
