//! Feature analysis (what physics a scene needs) and the CPU reference density.

use glam::Vec3;

use super::{Density, Features, Light, Medium, Scene};

impl Scene {
    /// What this scene requires of a solver.
    pub fn features(&self) -> Features {
        let m = &self.medium;
        let varies = |v: Vec3| v.x != v.y || v.y != v.z;
        Features {
            anisotropic: m.g != 0.0,
            chromatic: varies(m.sigma_t) || varies(m.albedo),
            light_inside: self.lights.iter().any(|light| match *light {
                Light::Point { position, .. } => {
                    m.strictly_inside(position) && self.density_at(position) > 0.0
                }
                _ => false,
            }),
            homogeneous: matches!(m.density, Density::Constant),
            has_environment: self
                .lights
                .iter()
                .any(|l| matches!(l, Light::Environment { .. })),
            grid_dims: match &m.density {
                Density::Grid(grid) => Some(grid.dims),
                _ => None,
            },
        }
    }

    /// Density multiplier at `p` (CPU reference): 1 for constant, 1 inside the sphere, the
    /// trilinearly interpolated grid; 0 outside the bounds. Multiply by `sigma_t` for
    /// extinction.
    pub fn density_at(&self, p: Vec3) -> f32 {
        self.medium.density_at(p)
    }

    /// An upper bound of [`Scene::density_at`] (exact for every density kind: 1, or the
    /// largest voxel). Multiply by `sigma_t` for the majorant.
    pub fn max_density(&self) -> f32 {
        match &self.medium.density {
            Density::Constant | Density::Sphere { .. } => 1.0,
            Density::Grid(grid) => grid.max_value(),
        }
    }
}

impl Medium {
    /// True if `p` lies inside the bounds box, faces included.
    pub fn contains(&self, p: Vec3) -> bool {
        p.cmpge(self.bounds_min).all() && p.cmple(self.bounds_max).all()
    }

    /// True if `p` lies inside the bounds box and not on a face.
    pub fn strictly_inside(&self, p: Vec3) -> bool {
        p.cmpgt(self.bounds_min).all() && p.cmplt(self.bounds_max).all()
    }

    /// Density multiplier at `p`; see [`Scene::density_at`].
    pub fn density_at(&self, p: Vec3) -> f32 {
        if !self.contains(p) {
            return 0.0;
        }
        match &self.density {
            Density::Constant => 1.0,
            Density::Sphere { center, radius } => {
                if p.distance_squared(*center) <= radius * radius {
                    1.0
                } else {
                    0.0
                }
            }
            Density::Grid(grid) => {
                let u = (p - self.bounds_min) / (self.bounds_max - self.bounds_min);
                grid.sample(u)
            }
        }
    }
}
