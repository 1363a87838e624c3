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

/// The largest reduced extinction sigma_t (1 - albedo g) (1/unit, max over channels, the
/// lattice's transport coefficient: docs/lbl.md) of the medium and of every object's
/// material, times the largest density.
pub fn max_reduced_sigma_t(scene: &Scene) -> f32 {
    let reduced = |st: glam::Vec3, albedo: glam::Vec3, g: f32| (st * (glam::Vec3::ONE - albedo * g)).max_element();
    let medium = reduced(scene.medium.sigma_t, scene.medium.albedo, scene.medium.g);
    let materials = scene.object.as_ref().map_or(&[][..], |o| &o.materials[..]);
    let largest = materials
        .iter()
        .map(|m| reduced(m.sigma_t, m.albedo, m.g))
        .fold(if scene.object.is_some() { 0.0 } else { medium }, f32::max);
    largest * scene.max_density()
}

/// How a grid solver's default grid fits the medium, and the range it was validated in (issue
/// 44). The `grid` knob keeps its meaning (voxels along the medium box's longest side, cubic
/// voxels); only its default is fitted: the solver's own count for a compact medium, raised
/// until the thinnest side spans `min_across` voxels and (dom) a voxel is at most
/// `max_voxel_depth` mean free paths thick, but never past `max_voxels` voxels (the budget a
/// default may spend: set the knob to go past it). What the fit cannot reach, the trust line
/// says ([`GridTrust::warning`]).
///
/// The figures are measured on lavapipe against `path` (1024 spp) on wide slabs lit normally
/// (sigma_t 1, optical thickness 0.5 / 2 / 8, albedo 0.8 / 0.99, g 0 / 0.6, reflected and
/// diffusely transmitted radiance at the slab's centre; docs/decisions.md, "Grids fitted to the
/// medium"): the energy of the render over path's.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct GridRule {
    pub solver: &'static str,
    /// Voxels across the medium box's thinnest side that the default gives and the solver was
    /// validated at.
    pub min_across: f32,
    /// The largest optical depth of a voxel edge, in mean free paths (extinction; for lbl the
    /// reduced extinction sigma_t (1 - albedo g), its transport coefficient), the solver was
    /// validated at. Beyond it a thick medium's diffuse transmission grows with the voxel: dom
    /// on the 8-mfp slab transmits 1.32x path's at 1 mfp per voxel, 2.1x at 2, 5.0x at 4.
    pub max_voxel_depth: f32,
    /// The smallest (lbl: thin voxels make its lattice's boundary layer bright), if any. Judged
    /// only in media of constant density (a hard lit boundary); a grid density's soft edge
    /// keeps lbl flat in the grid (the cloud: 0.955 -> 0.983 of path's energy from grid 16 to
    /// 64, docs/lbl.md).
    pub min_voxel_depth: Option<f32>,
    /// Voxels thicker than this carry a warning (the trust line says OUTSIDE past
    /// `max_voxel_depth` already). dom 1.0: past it every measurement is more than 5% off
    /// ([`DOM_GRID`]).
    /// lbl 3.0: lit from outside, its lattice keeps the energy of cubes and glass within the
    /// suite's tolerances at 2.0-2.5 reduced mean free paths a voxel (tests/lbl_refraction_tests.rs,
    /// tests/lbl.rs), while the slab's transmission is 1.3-2.4x at 1-2 and the sphere of
    /// sigma_t 160 (2.5 a voxel) 0.90 of path's energy, of sigma_t 640 (10) 0.83.
    pub warn_voxel_depth: f32,
    /// Whether a voxel's depth is judged in reduced extinction sigma_t (1 - albedo g) (lbl: its
    /// lattice's transport coefficient) rather than extinction (dom).
    pub reduced: bool,
    /// The most voxels a default grid holds.
    pub max_voxels: u64,
    /// A layer (the medium's second-thinnest side at least [`LAYER_ASPECT`] times its
    /// thinnest) of a soft (grid) density at most this many reduced mean free paths thick at its
    /// densest, or of a forward-scattering (g >= [`LAYER_G`]) hard-edged medium at any
    /// thickness, falls outside the range at any grid (lbl: such layers came out 7-65% bright;
    /// None: no such limit).
    pub thin_layer: Option<f32>,
    /// Whether hard-edged media of the shapes [`ShapeLimit`] names fall outside the range at any
    /// grid (lbl: its boundary treatment, calibrated on cubes and wide slabs, leaves rods and thin
    /// bright layers 5-9% dark at every default; dom: no such limit).
    pub shape_limits: bool,
    /// What the solver gave at (voxels across, optical depth per voxel) on the slabs: the
    /// smallest and largest energy over the sweep's cases there, as (across, depth, lo, hi).
    pub measured: &'static [(f32, f32, f32, f32)],
}

/// dom: 4 voxels across and at most half a mean free path per voxel. At 2 across (1 mfp per
/// voxel) it gave 0.945-1.027 of path's energy on the 2-mfp slabs, at 4 across (0.5) 0.961-0.999;
/// at 1 mfp per voxel the 8-mfp slab transmits 1.32x path's and the cloud squashed to a layer
/// (tests/shape_tests.rs) is 0.948. It warns past 1 mean free path a voxel: past it every
/// measurement is more than 5% off (the 16-wide 8-mfp slab lit at 60 degrees, held to 64^3
/// voxels, 0.947 at 1.33 (193 x 7 x 193); the thick bright cube of tests/dom_tests.rs, sigma_t 20 and albedo
/// 0.99, 1.09-1.13x at 1.11 and 1.15-1.20x at 1.67; the 8-mfp slab's transmission 2.1x at 2).
pub const DOM_GRID: GridRule = GridRule {
    solver: "dom",
    min_across: 4.0,
    max_voxel_depth: 0.5,
    min_voxel_depth: None,
    warn_voxel_depth: 1.0,
    reduced: false,
    max_voxels: 64 * 64 * 64,
    thin_layer: None,
    shape_limits: false,
    measured: &[
        (0.64, 3.1, 0.829, 0.829),
        (2.0, 1.0, 0.945, 1.027),
        (2.0, 4.0, 0.845, 4.99),
        (4.0, 0.5, 0.961, 0.999),
        (4.0, 2.0, 0.954, 2.11),
        (6.0, 1.33, 0.947, 0.947),
        (8.0, 1.0, 0.987, 1.32),
    ],
};

/// lbl: 2 voxels across, voxels of reduced optical depth 0.25-0.6 (its lattice's boundary
/// treatment was calibrated there: docs/lbl.md, "the default grid"). Thin voxels make it
/// bright: on the 0.5-mfp slab 0.90-1.09 of path's energy at 0.25 per voxel, 1.14-2.13 at
/// 0.125, 1.28-2.74 at 0.0625. The lower bound is generous: on hard-edged media 0.25-0.31 per
/// voxel already gave 1.04-1.13 (the 2-mfp slab at 8 across, a 10:1:1 box at 6.4 across), 0.5
/// gave 0.967-1.047 (docs/decisions.md).
pub const LBL_GRID: GridRule = GridRule {
    solver: "lbl",
    min_across: 2.0,
    max_voxel_depth: 0.6,
    min_voxel_depth: Some(0.25),
    warn_voxel_depth: 3.0,
    reduced: true,
    max_voxels: 128 * 128 * 128,
    // The cloud squashed to a layer 2 x 0.2 x 2 (sigma_t 30, g 0.6, 2.6 reduced mean free
    // paths thick at its densest) gave 0.92 / 1.08 / 1.14 / 1.18 / 1.22 / 1.25 / 1.27 of path's
    // energy at 2 / 3 / 4 / 5 / 7 / 10 / 14 voxels across (1.17 at 7 with g 0), whatever the
    // injection (directed 1.48, isotropic 1.47 at 7); the 2-mfp slabs with g 0.6 0.98-1.15 at 2
    // across, 1.01-1.30 at 4, 1.02-1.65 at 8. Hard-edged isotropic layers are not caught here
    // (the 2-mfp slabs at g 0: 0.97-1.00 at 4 across): the thin-voxel bound judges them.
    thin_layer: Some(4.0),
    shape_limits: true,
    measured: &[
        (1.28, 1.56, 2.097, 2.097),
        (2.0, 0.25, 0.899, 1.093),
        (2.0, 1.0, 1.029, 1.068),
        (2.0, 4.0, 0.990, 8.84),
        (4.0, 0.125, 1.138, 2.132),
        (4.0, 0.5, 0.967, 1.047),
        (4.0, 2.0, 1.091, 2.44),
        (8.0, 0.0625, 1.277, 2.738),
        (8.0, 0.25, 1.022, 1.128),
        (8.0, 1.0, 1.066, 1.34),
        (16.0, 0.5, 1.000, 1.072),
    ],
};

/// How much wider than thick a medium's box must be to count as a layer ([`GridRule::thin_layer`]):
/// its second-thinnest side over its thinnest.
pub const LAYER_ASPECT: f32 = 4.0;
/// The asymmetry from which a medium counts as forward-scattering for [`GridRule::thin_layer`]
/// (measured at 0.6; below, only soft densities are judged).
pub const LAYER_G: f32 = 0.5;

/// The albedo from which a hard-edged medium counts as bright for [`ShapeLimit`]: lbl's
/// darkness there grows with albedo (the 2-mfp cube at 7^3: 0.967 / 0.920 / 0.857 at albedo
/// 0.3 / 0.6 / 0.9; the 10:1:1 rod at its defaults: 0.97-1.01 at albedo 0.5, 0.94-0.98 at 0.8,
/// 0.91-0.96 at 0.9-0.99).
pub const BRIGHT_ALBEDO: f32 = 0.8;
/// The longest side over the thinnest from which a hard-edged medium that is not a layer
/// counts as elongated for [`ShapeLimit::Elongated`] (measured at 4 and 10; the cube, 2:1:1 and
/// 3:3:1 boxes kept within 5% at lbl's defaults).
pub const ELONGATED_ASPECT: f32 = 4.0;
/// The reduced optical thickness across the thinnest side below which an elongated bright
/// hard-edged medium falls outside lbl's range (measured dark at 1-12; within 5% at 20).
pub const ELONGATED_DEPTH: f32 = 16.0;
/// The reduced optical thickness below which a hard-edged isotropic bright layer falls
/// outside lbl's range (slabs 0.5 mean free paths thick: 0.92-0.94 of path's energy at albedo
/// 0.8-0.99; 1 thick: 0.95-0.97 at 2 voxels across, 1.06-1.09 at 4; 2 thick: 0.99-1.02).
pub const THIN_HARD_LAYER_DEPTH: f32 = 1.5;

/// A hard-edged medium whose shape lbl's boundary treatment was not validated for, at any grid
/// ([`GridRule::shape_limits`]; measured on lavapipe against `path` at lbl's fitted defaults,
/// lit from above and seen from above, docs/lbl.md "Shapes outside the range"). Its escape
/// weights and drift were calibrated where they meet the light head on (cubes, wide slabs):
/// the side faces of a rod and the far face of a thin layer lose more of the multiply scattered
/// light than they should, and no grid in the range wins it back (the rod: 0.88-1.16 from 3.5 to
/// 32 voxels across, crossing path's value at a grid that moves with the medium).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum ShapeLimit {
    /// A box at least [`ELONGATED_ASPECT`] times longer than its thinnest side and not a layer,
    /// under [`ELONGATED_DEPTH`] reduced mean free paths across that side (`depth`), of albedo
    /// at least [`BRIGHT_ALBEDO`].
    Elongated { aspect: f32, depth: f32, albedo: f32 },
    /// A layer of isotropic medium under [`THIN_HARD_LAYER_DEPTH`] reduced mean free paths
    /// thick (`depth`), of albedo at least [`BRIGHT_ALBEDO`].
    ThinBrightLayer { depth: f32, albedo: f32 },
}

/// The largest single-scattering albedo over channels, of the medium and of every object's
/// material.
fn max_albedo(scene: &Scene) -> f32 {
    let materials = scene.object.as_ref().map_or(&[][..], |o| &o.materials[..]);
    materials
        .iter()
        .map(|m| m.albedo.max_element())
        .fold(if scene.object.is_some() { 0.0 } else { scene.medium.albedo.max_element() }, f32::max)
}

/// Where `rule` limits shapes and `scene`'s medium is a hard-edged one of such a shape
/// ([`ShapeLimit`]). Layers of soft or forward-scattering media are judged by
/// [`GridRule::thin_layer`] instead.
fn shape_limit(scene: &Scene, rule: &GridRule) -> Option<ShapeLimit> {
    if !rule.shape_limits || !hard_edged(scene) {
        return None;
    }
    let albedo = max_albedo(scene);
    if albedo < BRIGHT_ALBEDO {
        return None;
    }
    let (sides, depth) = sides_and_depth(scene);
    if sides[0].is_nan() || sides[0] <= 0.0 {
        return None;
    }
    let layer = sides[1] >= LAYER_ASPECT * sides[0];
    let aspect = sides[2] / sides[0];
    if layer {
        (largest_g(scene) < LAYER_G && depth < THIN_HARD_LAYER_DEPTH)
            .then_some(ShapeLimit::ThinBrightLayer { depth, albedo })
    } else {
        (aspect >= ELONGATED_ASPECT && depth < ELONGATED_DEPTH).then_some(ShapeLimit::Elongated {
            aspect,
            depth,
            albedo,
        })
    }
}

/// The measured point nearest a render's (voxels across, depth per voxel), in log space.
fn nearest(points: &[(f32, f32, f32, f32)], across: f32, depth: f32) -> Option<(f32, f32, f32, f32)> {
    let d = |p: &(f32, f32, f32, f32)| {
        (p.0.max(1e-3) / across.max(1e-3)).ln().powi(2) + (p.1.max(1e-6) / depth.max(1e-6)).ln().powi(2)
    };
    points.iter().copied().min_by(|a, b| d(a).total_cmp(&d(b)))
}

impl GridRule {
    /// The optical depth of a voxel edge of `lambda` this rule judges, in mean free paths: the
    /// largest extinction (lbl: reduced extinction) over channels and materials times the
    /// largest density.
    pub fn voxel_depth(&self, scene: &Scene, lambda: f32) -> f32 {
        let sigma = if self.reduced { max_reduced_sigma_t(scene) } else { scene.max_sigma_t() * scene.max_density() };
        sigma * lambda
    }

    /// The grid knob's value (voxels along the longest side) that puts `min_across` voxels
    /// across the medium box's thinnest side (unrounded past the ceiling: f32).
    fn grid_for_across(&self, scene: &Scene) -> f32 {
        let ext = scene.medium.bounds_max - scene.medium.bounds_min;
        (self.min_across * ext.max_element() / ext.min_element() - 1e-3).ceil()
    }

    /// The grid knob's value for voxels of `max_voxel_depth` at most.
    fn grid_for_depth(&self, scene: &Scene) -> f32 {
        let longest = (scene.medium.bounds_max - scene.medium.bounds_min).max_element();
        (self.voxel_depth(scene, longest) / self.max_voxel_depth - 1e-3).ceil()
    }

    /// The default grid (voxels along the longest side) for `scene`, from the solver's own
    /// default `base`: raised for `min_across` voxels across the thinnest side and voxels of at
    /// most `max_voxel_depth`, held to `max_voxels` and to `cap` (the knob's range), never below
    /// `base`.
    pub fn fitted_grid(&self, scene: &Scene, base: u32, cap: u32) -> u32 {
        let ext = scene.medium.bounds_max - scene.medium.bounds_min;
        let (longest, thinnest) = (ext.max_element(), ext.min_element());
        if !(thinnest > 0.0 && longest.is_finite()) {
            return base;
        }
        // f32 -> u32 saturates (and drops a NaN to 0).
        let want = (self.grid_for_across(scene).max(self.grid_for_depth(scene)).min(cap as f32) as u32).max(base);
        let fits = |g: u32| LatticeGeom::new(scene, g).voxels() <= self.max_voxels;
        let want = (base..=want).rev().find(|&g| fits(g)).unwrap_or(base);
        // Whole voxels across the thinnest side where a grid up to a quarter finer gives them
        // (within 5% of a voxel): the medium's boundary then lies on voxel faces, where the
        // lattice's boundary treatment sits (a slab 2 mfp thick, lbl at 3.1 / 3.3 voxels across:
        // 1.15 / 1.05 of path's energy, at 3 or 4 across 1.00 / 0.98).
        let ratio = thinnest / longest;
        let whole = |g: u32| {
            let n = g as f32 * ratio;
            (n - n.round()).abs() < 0.05 && n.round() >= 1.0
        };
        if whole(want) {
            return want;
        }
        (want..=(want + want / 4).min(cap)).find(|&g| whole(g) && fits(g)).unwrap_or(want)
    }
}

/// How finely a grid resolves the medium, against what the solver was validated at
/// ([`GridRule`]): the trust line of a grid solver's render (its JSON `trust` block, its
/// summary line, and the warnings of [`GridTrust::warning`] where it falls outside).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct GridTrust {
    /// The rule the render is judged by.
    pub rule: GridRule,
    /// The grid knob's value the render ran at (voxels along the longest side).
    pub grid: u32,
    /// Voxels across the medium's box along x, y and z (its extent over the voxel edge).
    pub voxels_across: [f32; 3],
    /// The axis with the fewest (0 x, 1 y, 2 z).
    pub thinnest_axis: usize,
    /// The largest optical depth of one voxel edge the rule judges, in mean free paths
    /// ([`GridRule::voxel_depth`]).
    pub voxel_depth: f32,
    /// The grid knob's value that puts `rule.min_across` voxels across the thinnest side.
    pub grid_for_across: u32,
    /// The grid knob's value for voxels of `rule.max_voxel_depth` at most.
    pub grid_for_depth: u32,
    /// The largest grid knob's value whose voxels are at least `rule.min_voxel_depth` thick
    /// (None: no lower bound, or a medium whose density is not constant).
    pub grid_for_min_depth: Option<u32>,
    /// The medium is a thin layer of a soft or forward-scattering medium
    /// ([`GridRule::thin_layer`]): its reduced optical thickness across the thinnest side at
    /// the densest point (None: not such a layer, or the rule sets no limit).
    pub thin_layer: Option<f32>,
    /// The medium is hard-edged and of a shape the solver was not validated on
    /// ([`ShapeLimit`]; None: it is not, or the rule sets no such limit).
    pub shape: Option<ShapeLimit>,
}

/// Where `rule` limits layers and `scene`'s medium is one it judges ([`GridRule::thin_layer`]):
/// its reduced optical thickness across the thinnest side at its densest.
fn thin_layer(scene: &Scene, rule: &GridRule) -> Option<f32> {
    let limit = rule.thin_layer?;
    let (sides, depth) = sides_and_depth(scene);
    if sides[1] < LAYER_ASPECT * sides[0] {
        return None;
    }
    // Soft layers up to `limit`; forward-scattering hard-edged ones at any thickness (slabs with
    // g 0.6: 1.07-1.27x path's energy at 5.5-16.8 reduced mean free paths, docs/lbl.md).
    let judged = if hard_edged(scene) { largest_g(scene) >= LAYER_G } else { depth <= limit };
    judged.then_some(depth)
}

/// The medium box's sides, thinnest first, and its reduced optical thickness across the
/// thinnest at its densest (what the layer and shape rules judge).
fn sides_and_depth(scene: &Scene) -> ([f32; 3], f32) {
    let mut sides = (scene.medium.bounds_max - scene.medium.bounds_min).to_array();
    sides.sort_by(f32::total_cmp);
    (sides, max_reduced_sigma_t(scene) * sides[0])
}

/// The largest asymmetry g of the medium, or of an object's materials.
fn largest_g(scene: &Scene) -> f32 {
    scene.object.as_ref().map_or(scene.medium.g, |o| o.materials.iter().map(|m| m.g).fold(f32::MIN, f32::max))
}

/// A medium of constant density (a box or a sphere of it, or mesh objects filled with one):
/// its lit boundary is a step, where lbl's thin-voxel brightness shows.
fn hard_edged(scene: &Scene) -> bool {
    use crate::scene::Density;
    let hard = |d: &Density| matches!(d, Density::Constant | Density::Sphere { .. });
    match &scene.object {
        Some(o) => o.fields.iter().all(|f| hard(&f.density)),
        None => hard(&scene.medium.density),
    }
}

impl LatticeGeom {
    /// How this grid (`grid` voxels along the longest side) resolves `scene`'s medium box,
    /// judged by `rule` ([`GridTrust`]).
    pub fn trust(&self, scene: &Scene, grid: u32, rule: &GridRule) -> GridTrust {
        let ext = scene.medium.bounds_max - scene.medium.bounds_min;
        let voxels_across = [0, 1, 2].map(|a| ext[a] / self.lambda);
        let thinnest_axis = (0..3).min_by(|&a, &b| voxels_across[a].total_cmp(&voxels_across[b])).unwrap_or(0);
        let sat = |v: f32| v.max(1.0).min(u32::MAX as f32) as u32;
        let unit_depth = rule.voxel_depth(scene, ext.max_element());
        GridTrust {
            rule: *rule,
            grid,
            voxels_across,
            thinnest_axis,
            voxel_depth: rule.voxel_depth(scene, self.lambda),
            grid_for_across: sat(rule.grid_for_across(scene)),
            grid_for_depth: sat(rule.grid_for_depth(scene)),
            grid_for_min_depth: rule
                .min_voxel_depth
                .filter(|_| hard_edged(scene))
                .map(|m| sat((unit_depth / m + 1e-3).floor())),
            thin_layer: thin_layer(scene, rule),
            shape: shape_limit(scene, rule),
        }
    }
}

impl GridTrust {
    /// The fewest voxels across a side.
    pub fn fewest(&self) -> f32 {
        self.voxels_across[self.thinnest_axis]
    }

    /// Enough voxels across every side (a rounding margin: a cube at grid 8 has 8 across).
    pub fn across_within(&self) -> bool {
        self.fewest() >= self.rule.min_across - 1e-3
    }

    /// Voxels thinner than the rule's smallest depth in a hard-edged medium.
    fn too_thin(&self) -> bool {
        self.grid_for_min_depth.is_some()
            && self.rule.min_voxel_depth.is_some_and(|m| self.voxel_depth < m * 0.999 && self.voxel_depth > 0.0)
    }

    /// Voxels within the validated optical depth.
    pub fn depth_within(&self) -> bool {
        self.voxel_depth <= self.rule.max_voxel_depth * 1.001 && !self.too_thin()
    }

    /// Outside the range by enough to warn: too few voxels across, voxels past
    /// `warn_voxel_depth`, or (lbl) a medium too thin for any grid to give both enough voxels
    /// across and voxels thick enough, or (lbl) a thin layer of a soft or forward-scattering
    /// medium, which no grid serves. A finer or coarser grid within the range only shows in
    /// the trust line (OUTSIDE).
    pub fn warns(&self) -> bool {
        self.grid_warns() || self.thin_layer.is_some() || self.shape.is_some()
    }

    /// The grid's part of [`GridTrust::warns`]: too few voxels across, voxels past
    /// `warn_voxel_depth`, or a medium too thin for any grid to give both.
    fn grid_warns(&self) -> bool {
        let thin_conflict = self.too_thin() && self.grid_for_min_depth.is_some_and(|m| m < self.grid_for_across);
        !self.across_within() || self.voxel_depth > self.rule.warn_voxel_depth * 1.001 || thin_conflict
    }

    /// The grid resolves the medium as the solver was validated.
    pub fn within(&self) -> bool {
        self.across_within() && self.depth_within() && self.thin_layer.is_none() && self.shape.is_none()
    }

    /// The one-line figure for a render's summary.
    pub fn line(&self) -> String {
        let [x, y, z] = self.voxels_across;
        let r = &self.rule;
        format!(
            "grid trust: {x:.1} x {y:.1} x {z:.1} voxels across the medium, {:.3} {}mean free paths per voxel at most \
             (validated at >= {} across every side and {}{} per voxel){}",
            self.voxel_depth,
            if r.reduced { "reduced " } else { "" },
            r.min_across,
            r.min_voxel_depth.map_or(String::new(), |m| format!("{m}-")),
            r.max_voxel_depth,
            if self.within() { "" } else { ": OUTSIDE" }
        )
    }

    /// The measured energy range nearest this render's discretisation, as words.
    fn measured(&self) -> String {
        let Some((across, depth, lo, hi)) = nearest(self.rule.measured, self.fewest(), self.voxel_depth) else {
            return String::new();
        };
        let range = if lo == hi { format!("{lo:.2}") } else { format!("{lo:.2}-{hi:.2}") };
        format!(
            "; on slabs, {} at {across} voxels across and {depth} mean free paths per voxel gave {range}x the energy of \
             path",
            self.rule.solver
        )
    }

    /// The warning a render outside the validated range carries (None within it): what falls
    /// outside, the error measured nearest it on the slabs, and the knob's value that fixes it,
    /// or that no grid can (a medium too thin for the lattice's voxels, one whose fix is past
    /// 512, or a thin layer of a soft or forward-scattering medium).
    pub fn warning(&self) -> Option<String> {
        let r = &self.rule;
        let s = r.solver;
        let axis = ["x", "y", "z"][self.thinnest_axis];
        let layer = self.thin_layer.map(|depth| {
            format!(
                "{s}: the medium is a layer {depth:.2} reduced mean free paths thick across its thinnest side ({axis}), \
                 of a soft density or forward-scattering (g >= {LAYER_G}): outside what {s} was validated for, bright \
                 at any grid (the cloud squashed to 2 x 0.2 x 2: 1.08-1.27x path's energy at 3-14 voxels across, 0.92 \
                 at 2; slabs with g 0.6: up to 1.30x 2 mean free paths thick, 1.07-1.27x 12-24 thick); use dom or path"
            )
        });
        let shape = self.shape.map(|shape| match shape {
            ShapeLimit::Elongated { aspect, depth, albedo } => format!(
                "{s}: the medium is a hard-edged box {aspect:.1} times longer than its thinnest side ({axis}), \
                 {depth:.2} reduced mean free paths across it, of albedo {albedo:.2}: outside what {s} was validated \
                 for, dark at its default grids (boxes 10:1:1 1-12 mean free paths across: 0.91-0.97x path's energy \
                 at albedo 0.9-0.99, 0.94-0.98x at 0.8; 4:1:1 and 4:2:1: 0.94-0.99x) and 0.88-1.25x as the grid \
                 moves; use dom or path"
            ),
            ShapeLimit::ThinBrightLayer { depth, albedo } => format!(
                "{s}: the medium is a hard-edged layer {depth:.2} reduced mean free paths thick across its thinnest \
                 side ({axis}), of albedo {albedo:.2}: outside what {s} was validated for, its energy moving with the \
                 grid (slabs 0.5 mean free paths thick at albedo 0.8-0.99: 0.92-0.94x path's at 2 voxels across, \
                 1.14-1.51x at 4-8; 1 thick: 0.95-0.97x at 2, 1.06-1.09x at 4); use dom or path"
            ),
        });
        let strip = |w: String| w.trim_start_matches(&format!("{s}: ")).to_string();
        let parts: Vec<String> = [layer, shape, self.grid_warning()].into_iter().flatten().collect();
        let mut parts = parts.into_iter();
        let first = parts.next()?;
        Some(parts.fold(first, |acc, w| format!("{acc}; and {}", strip(w))))
    }

    /// The grid's part of [`GridTrust::warning`].
    fn grid_warning(&self) -> Option<String> {
        let r = &self.rule;
        let s = r.solver;
        let axis = ["x", "y", "z"][self.thinnest_axis];
        if !self.grid_warns() {
            return None;
        }
        let mut parts = Vec::new();
        if !self.across_within() {
            parts.push(format!(
                "the medium's thinnest side ({axis}) spans {:.1} voxels, below the {} across",
                self.fewest(),
                r.min_across
            ));
        }
        if self.voxel_depth > r.max_voxel_depth * 1.001 {
            parts.push(format!(
                "a voxel is {:.3} {}mean free paths thick, above the {}",
                self.voxel_depth,
                if r.reduced { "reduced " } else { "" },
                r.max_voxel_depth
            ));
        }
        if let Some(m) = r.min_voxel_depth.filter(|_| self.too_thin()) {
            parts.push(format!("a voxel is {:.3} reduced mean free paths thick, below the {m}", self.voxel_depth));
        }
        // The grid that fixes every part, where one exists within the knob's range.
        let low = self.grid_for_across.max(self.grid_for_depth);
        let high = self.grid_for_min_depth.unwrap_or(u32::MAX).min(512);
        let fix = if low <= high {
            format!("set {s}.grid={low} (voxels along the longest side)")
        } else if self.grid_for_min_depth.is_some_and(|m| m < self.grid_for_across) {
            format!(
                "the medium is too thin for {s}'s lattice: no grid gives {} voxels across and voxels of at least {} \
                 reduced mean free paths; use dom or path",
                r.min_across,
                r.min_voxel_depth.unwrap_or(0.0)
            )
        } else {
            format!("no grid up to 512 serves ({s}.grid={low} would be needed, past 512); expect the error above, or use path")
        };
        Some(format!("{s}: {}, at which {s} was validated{}; {fix}", parts.join(", and "), self.measured()))
    }
}
