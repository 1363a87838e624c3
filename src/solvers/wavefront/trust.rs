//! How far to trust a `wavefront` render (issue 44, item 2): its three discretisations (the
//! gather's Cartesian voxels, the spherical grid's shells and the angle between its rays), each
//! in mean free paths at the medium's densest, and the one limit of the method no knob lifts
//! (diffusion, eq. 4, for light that has crossed many mean free paths of an absorbing medium).
//!
//! The thresholds are measured on lavapipe against `path` (1024 spp, 32 x 32, bias and energy
//! from `scatterlab compare`) on a cube [-0.5, 0.5]^3 of constant density with a point light at
//! its centre, sigma_t 2 / 20 / 100, albedo 0.5-0.99, g 0, each knob swept with the others at
//! their defaults (docs/wavefront.md, "How far to trust it"). The energy quoted is against the
//! same case at the fine end of the knob, so the method's own bias (docs/wavefront.md: up to
//! 1.21x at albedo 0.99, optical radius 10) is kept apart from the discretisation's.

use glam::Vec3;
use serde::Serialize;

use crate::scene::Scene;
use crate::solvers::parts::lattice::LatticeGeom;
use crate::solvers::parts::wave_field::{farthest_corner, traced_lights, WaveSettings, MAX_LAYERS};

/// The figures of one render ([`WaveTrust::of`]): its JSON `trust` block, its summary line and,
/// where it falls outside the range by enough, its warnings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct WaveTrust {
    /// The point lights inside the medium the method traces: with none, nothing is gathered
    /// (the render is exact single scattering) and no figure below applies.
    pub lights_traced: usize,
    /// Mean free paths across a gather voxel's edge at the densest point (sigma_t max over
    /// channels times the largest density times the voxel edge).
    pub voxel_depth: f32,
    /// Mean free paths across one radial shell (radius / layers) at the densest point, the
    /// largest over the traced lights.
    pub shell_depth: f32,
    /// Mean free paths between neighbouring rays at the farthest corner of the box (radius
    /// times the rays' angular spacing sqrt(4 pi / (nu nv))) at the densest point, the largest
    /// over the traced lights.
    pub ray_gap: f32,
    /// The smallest albedo over channels.
    pub albedo: f32,
    /// The optical depth from a traced light to the box along the axis where it is least (the
    /// six axis directions, marched through the density; sigma_t max over channels), the largest
    /// over the traced lights: how far the light has diffused before the camera sees it.
    pub light_depth: f32,
    /// The least optical depth from a traced light out of the box over 262 directions (the
    /// axes and a spherical Fibonacci set: where light leaves a heterogeneous medium soonest),
    /// the least over the traced lights (0 with none): a light shallower than
    /// [`WaveTrust::SHALLOW`] is warned.
    pub shallow_depth: f32,
    /// The knobs' values that bring each figure to the validated one (None: within it already,
    /// or past the knob's range).
    pub grid_needed: Option<u32>,
    pub layers_needed: Option<u32>,
    pub rays_needed: Option<(u32, u32)>,
}

impl WaveTrust {
    /// Mean free paths a gather voxel was validated at: 0.5 gave within 2% of the energy at the
    /// finest grid (sigma_t 20, albedo 0.95 and 0.99), 1.0 +8%, 1.25 0 to +11%.
    pub const VOXEL: f32 = 0.5;
    /// Past this a warning: 2.5-3.1 gave +33-40%, 6.25 +114%; 1.56 (the default grid on the
    /// sigma_t 100 cube) +4%, so the line says OUTSIDE there without a warning.
    pub const VOXEL_WARN: f32 = 2.0;
    /// Mean free paths a shell was validated at (the default 128 layers on the sigma_t 100 cube,
    /// 2.7: within 1%). The shells sample where each ray leaves the medium for the extrapolated
    /// boundary, so the error past it is not monotone: 3.6 gave -17%, 5.4 +34%, 10.8 +48%.
    pub const SHELL: f32 = 3.0;
    /// Mean free paths between rays at the farthest corner validated at: up to 7 within 5%
    /// (sigma_t 20 at 128-2048 rays, 100 at 2048).
    pub const RAY_GAP: f32 = 7.0;
    /// Past this a warning: 11 gave +13-20%, 14 +16%, 18 +28%, 27 +38%, 54 +90%.
    pub const RAY_GAP_WARN: f32 = 10.0;
    /// Below this albedo, with the light deeper than [`WaveTrust::DEEP`], diffusion misses the
    /// light: at 10 mean free paths deep albedo 0.5 gave 0.69 of path's energy, 0.8 0.84, 0.9
    /// 1.00; at 2.5-5 deep albedo 0.5 and 0.8 gave 1.00-1.12.
    pub const ALBEDO: f32 = 0.9;
    /// Mean free paths from the light to the box past which the albedo limit applies.
    pub const DEEP: f32 = 8.0;
    /// Mean free paths from a light to the box below which a warning: light that leaves before
    /// it has diffused is left to single scattering (the wavefronts are the diffusion solution,
    /// eq. 4). Validated down to 1 deep (a cube with the light at its centre, 0.95-1.01 of path's
    /// energy); below it, measured against path (1024-2048 spp, albedo 0.95): the cube 0.5 deep
    /// 0.81, 0.25 deep 0.74; scenes/point-light-in-cloud.toml (depths along its thinnest
    /// direction; along the axes they are 1.15-1.2x) at sigma_t 3.5 (0.87 deep) 0.88, at 2 (0.50)
    /// 0.74, at 1 (0.25) 0.70, single scattering alone 0.68 there; at 6, its default (1.49),
    /// 0.97.
    pub const SHALLOW: f32 = 1.0;
    /// `wavefront.grid`'s largest value, and `nu`'s and `nv`'s.
    const MAX_GRID: u32 = 1024;
    const MAX_RAYS: u32 = 4096;

    /// The trust of a render of `scene` at `set`.
    pub fn of(scene: &Scene, set: &WaveSettings) -> WaveTrust {
        let sigma = scene.max_sigma_t() * scene.max_density();
        let lambda = LatticeGeom::new(scene, set.grid).lambda;
        let (lo, hi) = (scene.medium.bounds_min, scene.medium.bounds_max);
        let lights = traced_lights(scene);
        let radius = lights.iter().map(|(p, _)| farthest_corner(scene, *p)).fold(0.0f32, f32::max);
        let spacing = (4.0 * std::f32::consts::PI / (set.nu as f32 * set.nv as f32)).sqrt();
        let depths: Vec<f32> = lights.iter().map(|(p, _)| least_axis_depth(scene, *p)).collect();
        let light_depth = depths.iter().copied().fold(0.0f32, f32::max);
        let shallow_depth = if lights.is_empty() {
            0.0
        } else {
            lights.iter().zip(&depths).map(|((p, _), axes)| least_depth(scene, *p, *axes)).fold(f32::INFINITY, f32::min)
        };
        let voxel_depth = sigma * lambda;
        let shell_depth = sigma * radius / set.layers as f32;
        let ray_gap = sigma * radius * spacing;
        let longest = (hi - lo).max_element();
        let grid_needed = (voxel_depth > Self::VOXEL * 1.001)
            .then(|| (sigma * longest / Self::VOXEL).ceil())
            .filter(|g| *g <= Self::MAX_GRID as f32)
            .map(|g| g as u32);
        let layers_needed = (shell_depth > Self::SHELL * 1.001)
            .then(|| (sigma * radius / Self::SHELL).ceil())
            .filter(|l| *l <= MAX_LAYERS as f32)
            .map(|l| l as u32);
        // Rays nu x nv = 4 pi (sigma R / gap)^2, nu = 2 nv as the defaults (64 x 32).
        let rays_needed = (ray_gap > Self::RAY_GAP * 1.001)
            .then(|| {
                let n = 4.0 * std::f32::consts::PI * (sigma * radius / Self::RAY_GAP).powi(2);
                (n / 2.0).sqrt().ceil()
            })
            .filter(|nv| 2.0 * nv <= Self::MAX_RAYS as f32)
            .map(|nv| (2 * nv as u32, nv as u32));
        WaveTrust {
            lights_traced: lights.len(),
            voxel_depth,
            shell_depth,
            ray_gap,
            albedo: scene.medium.albedo.min_element(),
            light_depth,
            shallow_depth,
            grid_needed,
            layers_needed,
            rays_needed,
        }
    }

    fn diffusion_outside(&self) -> bool {
        self.albedo < Self::ALBEDO && self.light_depth > Self::DEEP
    }

    /// Every figure within what wavefront was validated at.
    pub fn within(&self) -> bool {
        self.lights_traced == 0
            || self.voxel_depth <= Self::VOXEL * 1.001
                && self.shell_depth <= Self::SHELL * 1.001
                && self.ray_gap <= Self::RAY_GAP * 1.001
                && !self.diffusion_outside()
                && self.shallow_depth >= Self::SHALLOW
    }

    /// The one-line figure for a render's summary.
    pub fn line(&self) -> String {
        if self.lights_traced == 0 {
            return "wave trust: no point light inside the medium, nothing gathered: exact single scattering only"
                .to_string();
        }
        format!(
            "wave trust: {:.2} mean free paths a gather voxel, {:.2} a shell, {:.2} between rays at the farthest corner \
             (validated at <= {}, {} and {}); albedo {:.2}, the light {:.1} mean free paths deep (validated at >= {}, and \
             at albedo >= {} where it is over {} deep){}",
            self.voxel_depth,
            self.shell_depth,
            self.ray_gap,
            Self::VOXEL,
            Self::SHELL,
            Self::RAY_GAP,
            self.albedo,
            // The shallowest light: where one is too shallow, the deepest says nothing of it.
            if self.shallow_depth < Self::SHALLOW { self.shallow_depth } else { self.light_depth },
            Self::SHALLOW,
            Self::ALBEDO,
            Self::DEEP,
            if self.within() { "" } else { ": OUTSIDE" }
        )
    }

    /// The warnings of a render outside the range by enough to matter: each figure with the
    /// error measured nearest it and the knob's value that fixes it.
    pub fn warnings(&self) -> Vec<String> {
        let mut w = Vec::new();
        if self.lights_traced == 0 {
            return w;
        }
        let fix = |needed: Option<String>, knob: &str| {
            needed.unwrap_or_else(|| format!("no {knob} in its range serves; expect the error above, or use path"))
        };
        if self.voxel_depth > Self::VOXEL_WARN || self.voxel_depth.is_nan() {
            w.push(format!(
                "wavefront: a gather voxel is {:.2} mean free paths across at the densest, above the {} wavefront was \
                 validated at (on a cube with the light inside, 2.5-3.1 gave 1.33-1.40x the energy of a fine grid, 6.25 \
                 2.1x); {}",
                self.voxel_depth,
                Self::VOXEL,
                fix(self.grid_needed.map(|g| format!("set wavefront.grid={g}")), "wavefront.grid")
            ));
        }
        if self.shell_depth > Self::SHELL * 1.001 {
            w.push(format!(
                "wavefront: a radial shell is {:.2} mean free paths thick at the densest, above the {} wavefront was \
                 validated at (on a cube with the light inside, 3.6-10.8 gave 0.83-1.48x the energy of fine shells); {}",
                self.shell_depth,
                Self::SHELL,
                fix(self.layers_needed.map(|l| format!("set wavefront.layers={l}")), "wavefront.layers")
            ));
        }
        if self.ray_gap > Self::RAY_GAP_WARN {
            w.push(format!(
                "wavefront: neighbouring rays stand {:.1} mean free paths apart at the farthest corner, above the {} \
                 wavefront was validated at (on a cube with the light inside, 11-18 gave 1.13-1.28x the energy of fine \
                 rays, 27-54 1.4-1.9x); {}",
                self.ray_gap,
                Self::RAY_GAP,
                fix(
                    self.rays_needed.map(|(nu, nv)| format!("set wavefront.nu={nu} wavefront.nv={nv}")),
                    "wavefront.nu x nv"
                )
            ));
        }
        if self.shallow_depth < Self::SHALLOW {
            w.push(format!(
                "wavefront: a light {:.2} mean free paths from the medium's edge, below the {} wavefront was validated \
                 at: light that leaves before it diffuses gets single scattering only (the wavefronts are the diffusion \
                 solution, eq. 4; a cube with the light 0.5 deep gave 0.81x path's energy, the cloud with it 0.25-0.87 \
                 deep 0.70-0.88x); no knob fixes it, use lbl, dom or path",
                self.shallow_depth,
                Self::SHALLOW
            ));
        }
        if self.diffusion_outside() {
            w.push(format!(
                "wavefront: albedo {:.2} with the light {:.1} mean free paths deep: outside what wavefront was validated \
                 for (its diffusion, eq. 4, needs little absorption once light has crossed many mean free paths: with the \
                 light 10 deep in a cube, albedo 0.5 gave 0.69x path's energy, 0.8 0.84x, 0.9 1.00x); no knob fixes it, \
                 use path or dom",
                self.albedo, self.light_depth
            ));
        }
        w
    }
}

/// The least optical depth (sigma_t max over channels) from `p` out of the medium's box over
/// 256 directions of a spherical Fibonacci set and `axes`, the least axis depth
/// ([`least_axis_depth`]): where light leaves a heterogeneous medium soonest. In a box of
/// constant density it is the least axis depth; in the cloud it is not: with its light 1.0 mean
/// free paths deep along the axes, light leaving along a thinner diagonal made the render 0.88x
/// path's energy.
fn least_depth(scene: &Scene, p: Vec3, axes: f32) -> f32 {
    const DIRECTIONS: u32 = 256;
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    (0..DIRECTIONS)
        .map(|k| {
            let z = 1.0 - (2.0 * k as f32 + 1.0) / DIRECTIONS as f32;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let phi = golden * k as f32;
            depth_to_box(scene, p, Vec3::new(r * phi.cos(), r * phi.sin(), z))
        })
        .fold(axes, f32::min)
}

/// The least optical depth (sigma_t max over channels) from `p` to the medium's box along the
/// six axis directions.
fn least_axis_depth(scene: &Scene, p: Vec3) -> f32 {
    [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z]
        .into_iter()
        .map(|w| depth_to_box(scene, p, w))
        .fold(f32::INFINITY, f32::min)
}

/// The optical depth (sigma_t max over channels) from `p` along the unit direction `w` to where
/// it leaves the medium's box, marched at 256 midpoints (0 where the ray misses the box).
fn depth_to_box(scene: &Scene, p: Vec3, w: Vec3) -> f32 {
    const STEPS: u32 = 256;
    let (lo, hi) = (scene.medium.bounds_min, scene.medium.bounds_max);
    let len = crate::physics::geometry::ray_box(p, w, lo, hi).map_or(0.0, |(_, t1)| t1.max(0.0));
    let h = len / STEPS as f32;
    (0..STEPS).map(|k| scene.density_at(p + w * ((k as f32 + 0.5) * h)) * h).sum::<f32>() * scene.max_sigma_t()
}
