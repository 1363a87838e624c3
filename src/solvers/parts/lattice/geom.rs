//! The voxel grid that the lattice, photon marching's voxel sums, dom's sweeps and the wave
//! field's Cartesian volume share: built once per render from the medium's box and the grid
//! knob, and handed to every pass that needs it.

use glam::Vec3;
use serde::Serialize;

use crate::scene::Scene;

/// A Cartesian voxel grid over the medium's box: `dims` cubic voxels of edge `lambda` from
/// `origin` (the medium's min corner), `grid` voxels along the box's longest side.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct LatticeGeom {
    pub dims: [u32; 3],
    pub origin: [f32; 3],
    pub lambda: f32,
}

impl LatticeGeom {
    pub fn new(scene: &Scene, grid: u32) -> LatticeGeom {
        let ext = scene.medium.bounds_max - scene.medium.bounds_min;
        let lambda = ext.max_element() / grid as f32;
        let dims = [0, 1, 2].map(|a| ((ext[a] / lambda) - 1e-4).ceil().max(1.0) as u32);
        LatticeGeom { dims, origin: scene.medium.bounds_min.to_array(), lambda }
    }
    pub fn voxels(&self) -> u64 {
        self.dims.iter().map(|d| *d as u64).product()
    }
    pub fn min(&self) -> Vec3 {
        Vec3::from(self.origin)
    }
    pub fn max(&self) -> Vec3 {
        self.min() + Vec3::new(self.dims[0] as f32, self.dims[1] as f32, self.dims[2] as f32) * self.lambda
    }
    /// `origin` with `lambda` as w (push-constant layout of the grid kernels).
    pub fn origin4(&self) -> [f32; 4] {
        [self.origin[0], self.origin[1], self.origin[2], self.lambda]
    }
}
