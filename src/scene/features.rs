//! Feature analysis (what physics a scene needs) and the CPU reference density.

use glam::Vec3;

use super::{Density, Emission, Features, FieldRef, Light, Medium, Scene};

impl Scene {
    /// The environment lights' radiance summed in scene order (W/(m^2 sr) per channel): what a
    /// ray that leaves the medium sees. The same bits wherever it is used (path's camera rays
    /// that miss the medium, networks' sky).
    pub fn environment_radiance(&self) -> Vec3 {
        self.lights
            .iter()
            .map(|l| match l {
                Light::Environment { radiance } => *radiance,
                _ => Vec3::ZERO,
            })
            .sum()
    }

    /// What this scene requires of a solver.
    pub fn features(&self) -> Features {
        let m = &self.medium;
        // Every object's material counts (several entries may differ); object[0]'s is the medium's.
        let materials = self.object.as_ref().map_or(&[][..], |o| &o.materials[..]);
        Features {
            anisotropic: m.g != 0.0 || materials.iter().any(|x| x.g != 0.0),
            chromatic: !is_grey(m.sigma_t)
                || !is_grey(m.albedo)
                || materials.iter().any(|x| !is_grey(x.sigma_t) || !is_grey(x.albedo)),
            light_inside: self.lights.iter().any(|light| match *light {
                Light::Point { position, .. } => self.inside_medium(position),
                _ => false,
            }),
            homogeneous: self.fields().iter().all(|f| matches!(f.density, Density::Constant)),
            has_environment: self.lights.iter().any(|l| matches!(l, Light::Environment { .. })),
            // The first grid's (objects may have several fields).
            grid_dims: self.fields().iter().find_map(|f| match &f.density {
                Density::Grid(grid) => Some(grid.dims),
                _ => None,
            }),
            emissive: self.emissive(),
        }
    }

    /// Whether anything in the scene scatters: sigma_s = albedo sigma_t > 0 in some channel, in
    /// the medium or in an object's material. Where nothing does, a solver's image is the
    /// camera ray's transmittance and emission alone, exact in every solver: the trust lines of
    /// the fields that carry scattered light (a lattice's voxels, the particles' spacing) do not
    /// apply, and are not given.
    pub fn scatters(&self) -> bool {
        let sigma_s = |t: Vec3, a: Vec3| (t * a).max_element() > 0.0;
        let materials = self.object.as_ref().map_or(&[][..], |o| &o.materials[..]);
        sigma_s(self.medium.sigma_t, self.medium.albedo) || materials.iter().any(|x| sigma_s(x.sigma_t, x.albedo))
    }

    /// Whether anything in the scene emits: Le > 0 in a channel where sigma_a > 0 (the source
    /// is sigma_a Le), in the medium or in an object's material.
    pub fn emissive(&self) -> bool {
        let sigma_a = |t: Vec3, a: Vec3| t * (Vec3::ONE - a);
        let le_max = match &self.medium.emission {
            Emission::Grid(g) => g.max_le(),
            e => e.constant_part(),
        };
        let medium = self.medium.emission.is_some()
            && (sigma_a(self.medium.sigma_t, self.medium.albedo) * le_max).max_element() > 0.0;
        let materials = self.object.as_ref().map_or(&[][..], |o| &o.materials[..]);
        medium
            || materials.iter().any(|x| {
                let le = if x.emission_grid { le_max } else { x.emission };
                (x.sigma_a() * le).max_element() > 0.0
            })
    }

    /// Emitted radiance Le at `p`, W/(m^2 sr) per channel (CPU reference; 0 outside the
    /// medium's box and in objects' materials without emission). The source the medium adds
    /// is sigma_a(p) Le(p), sigma_a = sigma_t (1 - albedo) density(p).
    pub fn emission_at(&self, p: Vec3) -> Vec3 {
        let m = &self.medium;
        let grid = |p: Vec3| match &m.emission {
            Emission::Grid(g) if m.contains(p) => g.le((p - m.bounds_min) / (m.bounds_max - m.bounds_min)),
            _ => Vec3::ZERO,
        };
        match &self.object {
            Some(o) => match o.material_at(p) {
                None => Vec3::ZERO,
                Some(k) if o.materials[k].emission_grid => grid(p),
                Some(k) => o.materials[k].emission,
            },
            None if !m.contains(p) => Vec3::ZERO,
            None => match &m.emission {
                Emission::None => Vec3::ZERO,
                Emission::Constant(le) => *le,
                Emission::Grid(_) => grid(p),
            },
        }
    }

    /// The emission source sigma_a(p) Le(p) at `p`, W/(m^3 sr) per channel (CPU reference).
    pub fn emission_source_at(&self, p: Vec3) -> Vec3 {
        let le = self.emission_at(p);
        if le == Vec3::ZERO {
            return le;
        }
        let (t, a) = match &self.object {
            Some(o) => match o.material_at(p) {
                Some(k) => (o.materials[k].sigma_t, o.materials[k].albedo),
                None => return Vec3::ZERO,
            },
            None => (self.medium.sigma_t, self.medium.albedo),
        };
        t * (Vec3::ONE - a) * self.density_at(p) * le
    }

    /// True if `p` lies strictly inside the bounds on non-zero density: where a point light
    /// counts as inside the medium.
    pub fn inside_medium(&self, p: Vec3) -> bool {
        self.medium.strictly_inside(p) && self.density_at(p) > 0.0
    }

    /// Density multiplier at `p` (CPU reference): 1 for constant, 1 inside the sphere, the
    /// trilinearly interpolated grid; 0 outside the bounds. Multiply by `sigma_t` for
    /// extinction.
    pub fn density_at(&self, p: Vec3) -> f32 {
        match &self.object {
            Some(object) => match object.material_at(p) {
                None => 0.0,
                Some(k) => object.fields[object.materials[k].field].density_at(p),
            },
            None => self.medium.density_at(p),
        }
    }

    /// The density fields, borrowed: the objects' ([`super::Object::fields`]), or the v1
    /// medium's density over its box.
    pub fn fields(&self) -> Vec<FieldRef<'_>> {
        match &self.object {
            Some(o) => o.fields.iter().map(|f| f.as_ref()).collect(),
            None => vec![self.medium.field()],
        }
    }

    /// The largest extinction scale (1/unit, max over channels) of the medium and of every
    /// object's material.
    pub fn max_sigma_t(&self) -> f32 {
        let materials = self.object.as_ref().map_or(&[][..], |o| &o.materials[..]);
        materials.iter().map(|x| x.sigma_t.max_element()).fold(self.medium.sigma_t.max_element(), f32::max)
    }

    /// An upper bound of [`Scene::density_at`] (exact for every density kind: 1, or the
    /// largest voxel). Multiply by `sigma_t` for the majorant.
    pub fn max_density(&self) -> f32 {
        let max = |d: &Density| match d {
            Density::Constant | Density::Sphere { .. } => 1.0,
            Density::Grid(grid) => grid.max_value(),
        };
        match &self.object {
            Some(o) => o.fields.iter().map(|f| max(&f.density)).fold(0.0, f32::max),
            None => max(&self.medium.density),
        }
    }
}

/// True when the three channels of `v` are equal (grey).
pub fn is_grey(v: Vec3) -> bool {
    v.x == v.y && v.y == v.z
}

impl Light {
    /// The emitted quantity per channel: intensity (W/sr), irradiance (W/m^2) or radiance
    /// (W/(m^2 sr)) by kind.
    pub fn colour(&self) -> Vec3 {
        match *self {
            Light::Point { intensity, .. } => intensity,
            Light::Directional { irradiance, .. } => irradiance,
            Light::Environment { radiance } => radiance,
        }
    }

    /// Its `kind` in a scene file: "point", "directional" or "environment".
    pub fn kind_name(&self) -> &'static str {
        match self {
            Light::Point { .. } => "point",
            Light::Directional { .. } => "directional",
            Light::Environment { .. } => "environment",
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

    /// Its density over its bounds, borrowed.
    pub fn field(&self) -> FieldRef<'_> {
        FieldRef { density: &self.density, bounds_min: self.bounds_min, bounds_max: self.bounds_max }
    }

    /// Density multiplier at `p`; see [`Scene::density_at`].
    pub fn density_at(&self, p: Vec3) -> f32 {
        self.field().density_at(p)
    }
}

impl FieldRef<'_> {
    /// Density multiplier at `p` (CPU reference): 0 outside the box (faces included inside).
    pub fn density_at(&self, p: Vec3) -> f32 {
        if !(p.cmpge(self.bounds_min).all() && p.cmple(self.bounds_max).all()) {
            return 0.0;
        }
        match self.density {
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
