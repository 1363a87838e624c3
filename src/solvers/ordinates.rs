//! Discrete-ordinates sweeps on the device (issue 13's propagation, thesis 5.3): the part the
//! `dom` solver will be built on, checked against the CPU oracle `physics::ordinates`.
//!
//! In-core and isotropic for now: the whole grid and one field per direction of an octant live
//! on the device; each octant is swept plane by plane (i + j + k = w in its own coordinates,
//! one dispatch per plane, glsl/ordinates/sweep.comp), all the octant's directions per
//! invocation, so the fluence sums in a fixed order (deterministic, no atomics). Source
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
    octant: [i32; 4],
    first_dir: u32,
    count: u32,
    h: f32,
    pad: u32,
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
    /// Per octant: its signs and its directions' range in `dirs`.
    octants: Vec<([i32; 3], u32, u32)>,
}

impl Sweeper {
    /// `sigma_t` per voxel (x fastest) of a `dims` grid of cubic voxels of edge `h`; `q` the
    /// directions.
    pub fn new(gpu: &Gpu, dims: [u32; 3], h: f32, sigma_t: &[f32], q: &Quadrature) -> Result<Sweeper, SolverError> {
        let v = dims.iter().map(|d| *d as u64).product::<u64>();
        let mut sorted: Vec<[f32; 4]> = Vec::with_capacity(q.len());
        let mut octants = Vec::new();
        for o in 0..8 {
            let signs = [0, 1, 2].map(|a| if o & (1 << a) != 0 { -1 } else { 1 });
            let first = sorted.len() as u32;
            for (d, w) in q.directions.iter().zip(&q.weights) {
                // A direction belongs to the octant of its components' signs (a zero component
                // to the positive side).
                if (0..3).all(|a| (d[a] >= 0.0) == (signs[a] > 0)) {
                    sorted.push([d[0] as f32, d[1] as f32, d[2] as f32, *w as f32]);
                }
            }
            let count = sorted.len() as u32 - first;
            if count > 0 {
                octants.push((signs, first, count));
            }
        }
        let most = octants.iter().map(|o| o.2 as u64).max().unwrap_or(1);
        Ok(Sweeper {
            pipeline: gpu.pipeline(&SWEEP, &[])?,
            dims,
            h,
            sigma_t: gpu.buffer_with("ordinates sigma_t", sigma_t)?,
            emission: gpu.buffer("ordinates emission", v * 4)?,
            dirs: gpu.buffer_with("ordinates directions", &sorted)?,
            field: gpu.buffer("ordinates field", most * v * 4)?,
            fluence: gpu.buffer("ordinates fluence", v * 4)?,
            octants,
        })
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
        gpu.write_buffer(&self.fluence, 0, bytemuck::cast_slice(&vec![0f32; v as usize]))?;
        let planes = (nx + ny + nz - 2) as i32;
        let mut passes = Vec::with_capacity(self.octants.len() * planes as usize);
        for &(signs, first, count) in &self.octants {
            for w in 0..planes {
                let push = SweepPush {
                    dims: [nx, ny, nz, v],
                    octant: [signs[0], signs[1], signs[2], w],
                    first_dir: first,
                    count,
                    h: self.h,
                    pad: 0,
                };
                passes.push(
                    Pass::new("ordinates.sweep", QueueRole::Diffuse, &self.pipeline)
                        .read(0, &self.sigma_t)
                        .read(1, &self.emission)
                        .read(2, &self.dirs)
                        .read_write(3, &self.field)
                        .read_write(4, &self.fluence)
                        .push(&push)
                        .cover([nx, ny, 1]),
                );
            }
        }
        let point = gpu.submit(QueueRole::Diffuse, &passes, &[])?;
        gpu.wait(point)?;
        Ok(gpu.read_buffer_as(&self.fluence)?)
    }
}
