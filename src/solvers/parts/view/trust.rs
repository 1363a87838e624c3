//! How far to trust the view march (issue 44, item 2): `single` and `octaves` are this pass
//! alone, so its discretisation is theirs, and their trust line is this one. The march's one
//! discretisation of the medium is its step (glsl/view/march.comp): along the camera ray the
//! extinction is held at its value in the step's middle, the in-scattering across a thick step
//! is fitted from the shadow depth at its two ends ([`super::STEP_FIT_TAU`]), and where shadows
//! are marched through a grid density, the shadow ray takes the same rule. Three figures judge
//! it: steps across the medium's thinnest extent (the geometry a step resolves), mean free
//! paths a step at the densest point (the fit's reach), and, in a grid density, the grid's
//! voxels a step spans (the midpoint's sample of a varying density).
//!
//! The limits are measured on lavapipe against the same render at a step 16 times finer
//! (48^2, `scatterlab compare`; docs/measurements.md, "How far to trust the view march"):
//! `single` on the cloud (sigma_t 6 and 60), the point light in the cloud, the cloud layer, the
//! homogeneous sphere (sigma_t 10 and 100) and the thick slab, the step from a quarter of the
//! default to 16 times it. Within the validated range every case was within 4% relL2 and 2% of
//! the energy.

use serde::Serialize;

use crate::scene::{Density, Scene};

use super::{Shadow, ViewSettings};

/// The figures of one view march ([`ViewTrust::of`]): the JSON `trust` block of `single` and
/// `octaves`, their summary line and, where outside the range by enough, their warnings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ViewTrust {
    /// The camera-ray step, scene units.
    pub step: f32,
    /// Steps across the medium's thinnest extent: the smallest side of a density's box, or a
    /// sphere density's diameter where smaller.
    pub steps_across: f32,
    /// Mean free paths across one camera-ray step at the densest point: sigma_t (max over
    /// channels and materials) times the largest density times the step.
    pub step_depth: f32,
    /// Density voxels one camera-ray step spans: the step over the grid's mean voxel edge (the
    /// geometric mean of its three edges; the finest grid where there are several). None: no
    /// grid density.
    pub step_voxels: Option<f32>,
    /// The shadow-ray step, where shadows are marched through a grid density (None: read from
    /// the shadow volume at the grid's own voxels, or exact chords of a constant or sphere
    /// medium, where the shadow ray takes no step).
    pub shadow_step: Option<f32>,
    /// Mean free paths across one shadow-ray step at the densest point, where it is marched.
    pub shadow_step_depth: Option<f32>,
    /// Density voxels one shadow-ray step spans, where it is marched.
    pub shadow_step_voxels: Option<f32>,
    /// The largest camera-ray step (scene units) within the validated range, where the step is
    /// past it (None: within).
    pub step_needed: Option<f32>,
    /// The largest shadow-ray step within it, where the shadow step is past it.
    pub shadow_step_needed: Option<f32>,
    /// The settings' knob prefix ([`ViewSettings::prefix`]), for the knob the warning names.
    #[serde(skip)]
    pub prefix: &'static str,
}

/// A warning limit of the march: past `warn` (below it for steps across, where fewer is worse).
struct Limit {
    warn: f32,
    below: bool,
}

impl Limit {
    fn warns(&self, x: f32) -> bool {
        if self.below {
            x < self.warn * 0.999
        } else {
            x > self.warn * 1.001
        }
    }
}

impl ViewTrust {
    /// Steps across the thinnest extent validated at (the default step's rule gives 16 or more).
    /// 16.6 across the sphere gave 1.8% relL2 and 0.8% energy; 8.3 gave 4.1% and 2.0%; 4.2 gave
    /// 8.4% and 4.4%; the thick slab at 8 across 0.7%, at 4 across 7.6% and 1.7%.
    pub const STEPS_ACROSS: f32 = 16.0;
    /// Below this a warning.
    pub const STEPS_ACROSS_WARN: f32 = 8.0;
    /// Mean free paths a step validated at: the sphere of sigma_t 100 at 2.7 gave 3.9% relL2 and
    /// 1.6% energy, the thick slab at 3.1 (its default) 0.55%, the cloud at sigma_t 60 at 3.2 2.4%.
    pub const STEP_DEPTH: f32 = 4.0;
    /// Past this a warning: the sphere of sigma_t 100 at 5.4 gave 6.3% and 2.9%, at 10.8 9.8%
    /// and 4.8%, at 21.7 15% and 7.8%.
    pub const STEP_DEPTH_WARN: f32 = 8.0;
    /// Density voxels a step validated at: at 1.7 the cloud gave 0.7% relL2, the cloud of
    /// sigma_t 60 2.4%, the point light in the cloud 3.6% (energy within 0.5%).
    pub const STEP_VOXELS: f32 = 2.0;
    /// Past this a warning: at 3.5 the point light in the cloud gave 16% relL2 and 0.95 of the
    /// energy, the cloud of sigma_t 60 10%, the cloud 2.4%; at 6.9 the cloud 9% and 1.03.
    pub const STEP_VOXELS_WARN: f32 = 3.0;

    const ACROSS: Limit = Limit { warn: Self::STEPS_ACROSS_WARN, below: true };
    const DEPTH: Limit = Limit { warn: Self::STEP_DEPTH_WARN, below: false };
    /// The shadow-ray step takes the same depth and voxel limits: marched through the cloud it
    /// gave 0.8% relL2 at 3.5 voxels and 4.1% at 6.9; through the cloud of sigma_t 60 1.6% at 1.7
    /// voxels (3.2 mean free paths) and 8.6% and 1.02 of the energy at 3.5 (6.5); the point light
    /// in the cloud 1.5% at 13.9.
    const VOXELS: Limit = Limit { warn: Self::STEP_VOXELS_WARN, below: false };

    /// The trust of the view march `v` of `scene`.
    pub fn of(scene: &Scene, v: &ViewSettings) -> ViewTrust {
        let sigma = scene.max_sigma_t() * scene.max_density();
        let thinnest = thinnest_extent(scene);
        let voxel = mean_voxel(scene);
        let marched = v.shadow == Shadow::March && voxel.is_some();
        // The largest step within every limit that applies to it.
        let fits = {
            let by_depth = if sigma > 0.0 { Self::STEP_DEPTH / sigma } else { f32::INFINITY };
            let by_voxels = voxel.map_or(f32::INFINITY, |e| Self::STEP_VOXELS * e);
            by_depth.min(by_voxels)
        };
        let step_fits = fits.min(thinnest / Self::STEPS_ACROSS);
        let shadow_step = marched.then_some(v.shadow_step);
        ViewTrust {
            step: v.step,
            steps_across: thinnest / v.step,
            step_depth: sigma * v.step,
            step_voxels: voxel.map(|e| v.step / e),
            shadow_step,
            shadow_step_depth: shadow_step.map(|s| sigma * s),
            shadow_step_voxels: shadow_step.zip(voxel).map(|(s, e)| s / e),
            step_needed: (v.step > step_fits * 1.001).then_some(step_fits),
            shadow_step_needed: shadow_step.filter(|s| *s > fits * 1.001).map(|_| fits),
            prefix: v.prefix,
        }
    }

    /// Within the range the march was validated at.
    pub fn within(&self) -> bool {
        self.step_needed.is_none() && self.shadow_step_needed.is_none()
    }

    /// The camera-ray step's parts past their warning limits, as words.
    fn step_past(&self) -> Vec<String> {
        let mut parts = Vec::new();
        if Self::ACROSS.warns(self.steps_across) {
            parts.push(format!(
                "{:.1} camera-ray steps across the medium's thinnest extent, below the {} (4 across: 7.6-8.4% relL2, \
                 up to 4.4% of the energy)",
                self.steps_across,
                Self::STEPS_ACROSS_WARN
            ));
        }
        if Self::DEPTH.warns(self.step_depth) {
            parts.push(format!(
                "a camera-ray step {:.2} mean free paths thick, above the {} (10.8: 9.8% relL2, 4.8% of the energy)",
                self.step_depth,
                Self::STEP_DEPTH_WARN
            ));
        }
        if let Some(n) = self.step_voxels.filter(|n| Self::VOXELS.warns(*n)) {
            parts.push(format!(
                "a camera-ray step across {n:.1} density voxels, above the {} (3.5: up to 16% relL2 and 0.95 of the \
                 energy, a point light in the cloud)",
                Self::STEP_VOXELS_WARN
            ));
        }
        parts
    }

    /// The shadow-ray step's parts past their warning limits, as words.
    fn shadow_past(&self) -> Vec<String> {
        let mut parts = Vec::new();
        if let Some(d) = self.shadow_step_depth.filter(|d| Self::DEPTH.warns(*d)) {
            parts.push(format!("a shadow-ray step {d:.2} mean free paths thick, above the {}", Self::STEP_DEPTH_WARN));
        }
        if let Some(n) = self.shadow_step_voxels.filter(|n| Self::VOXELS.warns(*n)) {
            parts.push(format!("a shadow-ray step across {n:.1} density voxels, above the {}", Self::STEP_VOXELS_WARN));
        }
        parts
    }

    /// Outside the range by enough to warn.
    pub fn warns(&self) -> bool {
        !self.step_past().is_empty() || !self.shadow_past().is_empty()
    }

    /// The one-line figure for a render's summary.
    pub fn line(&self) -> String {
        let voxels = |n: Option<f32>| n.map_or(String::new(), |n| format!(", {n:.2} density voxels"));
        let shadow = match (self.shadow_step, self.shadow_step_depth) {
            (Some(s), Some(d)) => {
                format!("; a shadow step {s:.4} units, {d:.3} mean free paths{}", voxels(self.shadow_step_voxels))
            }
            _ => String::new(),
        };
        let grid = if self.step_voxels.is_some() {
            format!(" and <= {} density voxels", Self::STEP_VOXELS)
        } else {
            String::new()
        };
        format!(
            "view trust: a camera step {:.4} units, {:.1} steps across the medium's thinnest extent, {:.3} mean free \
             paths at the densest{}{shadow} (validated at >= {} across, <= {} mean free paths{grid} a step){}",
            self.step,
            self.steps_across,
            self.step_depth,
            voxels(self.step_voxels),
            Self::STEPS_ACROSS,
            Self::STEP_DEPTH,
            if self.within() { "" } else { ": OUTSIDE" }
        )
    }

    /// The warning a march past the limits carries (None within them, or outside by less than
    /// the warning limits: the line says OUTSIDE then): what is past, what was measured there and
    /// the knob's value that brings it within, named as `solver` reads it (with the prefix its
    /// settings were parsed with).
    pub fn warning(&self, solver: &str) -> Option<String> {
        let prefix = self.prefix;
        let (step, shadow) = (self.step_past(), self.shadow_past());
        if step.is_empty() && shadow.is_empty() {
            return None;
        }
        let mut fixes = Vec::new();
        if let Some(s) = self.step_needed.filter(|_| !step.is_empty()) {
            fixes.push(format!("set {solver}.{prefix}step={}", three_digits_down(s)));
        }
        if let Some(s) = self.shadow_step_needed.filter(|_| !shadow.is_empty()) {
            fixes.push(format!("set {solver}.{prefix}shadow_step={}", three_digits_down(s)));
        }
        let parts: Vec<String> = step.into_iter().chain(shadow).collect();
        Some(format!(
            "{solver}: {}, against a step 16 times finer; within 4% relL2 and 2% of the energy at >= {} steps across, <= \
             {} mean free paths and <= {} density voxels a step: {}",
            parts.join(", and "),
            Self::STEPS_ACROSS,
            Self::STEP_DEPTH,
            Self::STEP_VOXELS,
            fixes.join(" and ")
        ))
    }
}

/// `x` rounded down to three significant digits (a knob value that stays within the limit it
/// came from), printed as f32 prints: 0.0135, not 1.35e-2.
fn three_digits_down(x: f32) -> f32 {
    if !(x > 0.0 && x.is_finite()) {
        return x;
    }
    let scale = 10f64.powi(2 - (x as f64).log10().floor() as i32);
    ((x as f64 * scale).floor() / scale) as f32
}

/// The medium's thinnest extent (scene units): the smallest side of each density's box, and of
/// a sphere density its diameter where smaller.
fn thinnest_extent(scene: &Scene) -> f32 {
    scene
        .fields()
        .iter()
        .map(|f| {
            let side = (f.bounds_max - f.bounds_min).min_element();
            match f.density {
                Density::Sphere { radius, .. } => side.min(2.0 * radius),
                _ => side,
            }
        })
        .fold(f32::INFINITY, f32::min)
}

/// The mean voxel edge (geometric mean of the three, scene units) of the finest of the medium's
/// grid densities (None: none is a grid). The geometric mean, not the smallest edge: the cloud
/// layer's grid, 10 times finer across than along, gave 0.6% relL2 at 8 of its thin edges a
/// step (1.7 mean edges) and 2.9% at 32 (6.9).
fn mean_voxel(scene: &Scene) -> Option<f32> {
    scene
        .fields()
        .iter()
        .filter_map(|f| match f.density {
            Density::Grid(g) => {
                let ext = f.bounds_max - f.bounds_min;
                Some((0..3).map(|a| ext[a] / g.dims[a].max(1) as f32).product::<f32>().cbrt())
            }
            _ => None,
        })
        .reduce(f32::min)
}
