//! What a render models of its scene ("model only what a scene requires", docs/design.md):
//! the features the kernels are specialised on, the specialisation constants' ids and names
//! as the GLSL declares them, and the `modelled` line every render prints. Part of the
//! interface: a render's report carries it, and the parts and solvers build their kernels'
//! specialisation from it.

use serde::Serialize;

use crate::gpu::{Spec, SpecKind};
use crate::scene::{Density, Scene};

/// Specialisation constant ids shared by every kernel that includes scene.glsl (its
/// `constant_id`s; every kernel's declaration is checked against its SPIR-V).
pub const SPEC_DENSITY_KIND: u32 = 0;
pub const SPEC_CHROMATIC: u32 = 1;
pub const SPEC_ANISOTROPIC: u32 = 2;
/// scene.glsl's: the objects have several density fields.
pub const SPEC_FIELDS: u32 = 12;

/// glsl/include/mesh.glsl's: the scene has an [[object]] mesh; its boundary refracts.
pub const SPEC_HAS_MESH: u32 = 10;
pub const SPEC_REFRACTIVE: u32 = 11;

/// glsl/include/view.glsl's (and glsl/path/trace.comp's): the scene has an environment light.
pub const SPEC_ENVIRONMENT: u32 = 16;

/// scene.glsl's: what the medium emits (0 nothing, 1 a constant Le per material, 2 a grid).
pub const SPEC_EMISSION: u32 = 17;

/// glsl/include/batch.glsl's, in kernels that count their SIMD batches' loop back-edges: the
/// device ends loops past 65535 of them ([`crate::solvers::parts::resumable::loop_limited`],
/// llvmpipe), so count them; off elsewhere, where the counting would only cost.
pub const SPEC_LOOP_LIMITED: u32 = 18;

/// glsl/include/batch.glsl's, in kernels that pause on their SIMD batch's loop count: the count
/// past which a batch pauses at its next resumable point (`path.batch_pause`).
pub const SPEC_BATCH_PAUSE: u32 = 19;

/// The specialisation constants of [`Modelled::spec`], as a kernel declares them.
pub const SCENE_SPEC: &[(u32, SpecKind)] = &[
    (SPEC_DENSITY_KIND, SpecKind::U32),
    (SPEC_CHROMATIC, SpecKind::Bool),
    (SPEC_ANISOTROPIC, SpecKind::Bool),
    (SPEC_FIELDS, SpecKind::Bool),
    (SPEC_EMISSION, SpecKind::U32),
];

/// [`SCENE_SPEC`] and view.glsl's environment, for kernels whose light units it counts
/// ([`Modelled::view_spec`]).
pub const VIEW_SPEC: &[(u32, SpecKind)] = &[
    (SPEC_DENSITY_KIND, SpecKind::U32),
    (SPEC_CHROMATIC, SpecKind::Bool),
    (SPEC_ANISOTROPIC, SpecKind::Bool),
    (SPEC_FIELDS, SpecKind::Bool),
    (SPEC_EMISSION, SpecKind::U32),
    (SPEC_ENVIRONMENT, SpecKind::Bool),
];

/// [`SCENE_SPEC`] and mesh.glsl's, for kernels that trace the [[object]]'s mesh
/// ([`Modelled::mesh_spec`]).
pub const MESH_SPEC: &[(u32, SpecKind)] = &[
    (SPEC_DENSITY_KIND, SpecKind::U32),
    (SPEC_CHROMATIC, SpecKind::Bool),
    (SPEC_ANISOTROPIC, SpecKind::Bool),
    (SPEC_FIELDS, SpecKind::Bool),
    (SPEC_EMISSION, SpecKind::U32),
    (SPEC_HAS_MESH, SpecKind::Bool),
    (SPEC_REFRACTIVE, SpecKind::Bool),
];

/// Every specialisation constant's name, by id, as the GLSL declares it
/// (`layout(constant_id = N) const T NAME`): ids are unique across all shaders, so a render's
/// JSON can name the features each pipeline was built for. `registry_tests` checks the table
/// against every declaration in glsl/.
pub const SPEC_NAMES: &[(u32, &str)] = &[
    (SPEC_DENSITY_KIND, "DENSITY_KIND"),
    (SPEC_CHROMATIC, "CHROMATIC"),
    (SPEC_ANISOTROPIC, "ANISOTROPIC"),
    (3, "NCH"),
    (4, "B"),
    (5, "WG"),
    (6, "FIXED"),
    (7, "LINKS"),
    (8, "OCTAVES"),
    (9, "STEP_FIT"),
    (SPEC_HAS_MESH, "HAS_MESH"),
    (SPEC_REFRACTIVE, "REFRACTIVE"),
    (SPEC_FIELDS, "FIELDS"),
    (13, "MATS"),
    (14, "MNEE"),
    (15, "EQUIANGULAR"),
    (SPEC_ENVIRONMENT, "ENVIRONMENT"),
    (SPEC_EMISSION, "EMISSION"),
    (SPEC_LOOP_LIMITED, "LOOP_LIMITED"),
    (SPEC_BATCH_PAUSE, "BATCH_PAUSE"),
];

/// The name of specialisation constant `id` ([`SPEC_NAMES`]).
pub fn spec_name(id: u32) -> String {
    SPEC_NAMES.iter().find(|(i, _)| *i == id).map_or_else(|| format!("constant_{id}"), |(_, n)| n.to_string())
}

/// What a render modelled and what it skipped (docs/design.md: "model only what a scene requires").
#[derive(Clone, Debug, Serialize)]
pub struct Modelled {
    pub density: &'static str,
    pub chromatic: bool,
    pub anisotropic: bool,
    pub forced_full: bool,
    /// Triangles of the [[object]]'s mesh (0: a v1 scene, no mesh is traced).
    pub mesh_triangles: usize,
    /// The mesh's boundary refracts (ior != 1): Fresnel and Snell at its surface.
    pub refractive: bool,
    /// Density fields (several: the objects' densities differ, each looked up per field).
    pub fields: usize,
    /// The scene has an environment light: kernels that include view.glsl compile in its
    /// quadrature ([`SPEC_ENVIRONMENT`]).
    pub environment: bool,
    /// What the medium emits: "none", "constant" (a Le per material) or "grid"
    /// ([`SPEC_EMISSION`]); kernels that collect emission compile it in only when it is not
    /// "none".
    pub emission: &'static str,
}

impl Modelled {
    pub fn describe(&self) -> String {
        let mut skipped = Vec::new();
        if !self.chromatic {
            skipped.push("per-channel tracking (grey medium)");
        }
        if !self.anisotropic {
            skipped.push("HG phase (isotropic, g = 0)");
        }
        if self.mesh_triangles == 0 {
            skipped.push("mesh (no [[object]])");
        } else if !self.refractive {
            skipped.push("Fresnel and refraction (ior 1)");
        }
        if self.emission == "none" {
            skipped.push("emission (the medium emits nothing)");
        }
        let skipped = if skipped.is_empty() { "nothing".to_string() } else { skipped.join(", ") };
        let mesh = match (self.mesh_triangles, self.refractive) {
            (0, _) => String::new(),
            (n, false) => format!(", a mesh of {n} triangles (index-matched)"),
            (n, true) => format!(", a mesh of {n} triangles with a dielectric boundary"),
        };
        let emission = match self.emission {
            "constant" => ", constant emission",
            "grid" => ", emission from a grid",
            _ => "",
        };
        format!(
            "modelled: {} density, {} tracking, {} phase{mesh}{emission}{}; skipped: {}",
            self.density,
            if self.chromatic { "chromatic" } else { "grey" },
            if self.anisotropic { "Henyey-Greenstein" } else { "isotropic" },
            if self.forced_full { " (--model-all)" } else { "" },
            skipped
        )
    }

    pub fn spec(&self) -> Vec<(u32, Spec)> {
        let kind = match self.density {
            "constant" => 0,
            "sphere" => 1,
            _ => 2,
        };
        vec![
            (SPEC_DENSITY_KIND, Spec::U32(kind)),
            (SPEC_CHROMATIC, Spec::Bool(self.chromatic)),
            (SPEC_ANISOTROPIC, Spec::Bool(self.anisotropic)),
            (SPEC_FIELDS, Spec::Bool(self.fields > 1)),
            (SPEC_EMISSION, Spec::U32(self.emission_kind())),
        ]
    }

    /// [`SPEC_EMISSION`]'s value: 0 none, 1 constant, 2 grid.
    pub fn emission_kind(&self) -> u32 {
        match self.emission {
            "constant" => 1,
            "grid" => 2,
            _ => 0,
        }
    }

    /// [`Modelled::spec`] and the mesh's, as [`MESH_SPEC`] declares them.
    pub fn mesh_spec(&self) -> Vec<(u32, Spec)> {
        let mut spec = self.spec();
        spec.push((SPEC_HAS_MESH, Spec::Bool(self.mesh_triangles > 0)));
        spec.push((SPEC_REFRACTIVE, Spec::Bool(self.refractive)));
        spec
    }

    /// [`Modelled::spec`] and view.glsl's environment, as [`VIEW_SPEC`] declares them.
    pub fn view_spec(&self) -> Vec<(u32, Spec)> {
        let mut spec = self.spec();
        spec.push((SPEC_ENVIRONMENT, Spec::Bool(self.environment)));
        spec
    }
}

/// Decide what to model from the scene's features (or everything, with `force_full`).
pub fn modelled(scene: &Scene, force_full: bool) -> Modelled {
    let f = scene.features();
    // The most general kind among the density fields (the kernels branch per field below it).
    let kind = |d: &Density| match d {
        Density::Constant => 0,
        Density::Sphere { .. } => 1,
        Density::Grid(_) => 2,
    };
    let fields = scene.fields();
    let density = match fields.iter().map(|f| kind(f.density)).max().unwrap_or(0) {
        0 => "constant",
        1 => "sphere",
        _ => "grid",
    };
    Modelled {
        density,
        chromatic: f.chromatic || force_full,
        anisotropic: f.anisotropic || force_full,
        forced_full: force_full,
        mesh_triangles: scene.object.as_ref().map_or(0, |o| o.mesh.triangles.len()),
        refractive: scene.object.as_ref().is_some_and(|o| o.refractive()),
        fields: fields.len(),
        environment: force_full || scene.lights.iter().any(|l| matches!(l, crate::scene::Light::Environment { .. })),
        // --model-all compiles the emission code in (at the materials' Le, zero where none).
        emission: match (&scene.medium.emission, f.emissive || force_full) {
            (_, false) => "none",
            (crate::scene::Emission::Grid(_), true) => "grid",
            (_, true) => "constant",
        },
    }
}
