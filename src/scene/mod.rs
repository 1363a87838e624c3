//! Scenes: parsing and validation of scene files (format v1, `docs/scene-format.md`), and
//! the feature analysis that tells solvers which physics a scene needs.
//!
//! A [`Scene`] is always valid: [`Scene::load`] rejects anything a solver could not render
//! with a one-line [`SceneError`] naming the file and the field. Units follow Mitsuba 3:
//! lengths in scene units, `sigma_t` in 1/unit, point-light intensity in W/sr, directional
//! irradiance in W/m^2, environment radiance in W/(m^2 sr).

pub mod bvh;
mod error;
mod features;
mod grid;
pub mod mesh;
pub mod mitsuba;
mod parse;
mod vdb;
pub mod voxelise;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::Vec3;

pub use error::SceneError;
pub use features::is_grey;
pub use grid::write_vol;
pub use parse::did_you_mean;

/// A validated scene.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// The scene file path (or the `name` given to [`Scene::from_str`], e.g. `"<string>"`).
    pub source: PathBuf,
    pub render: RenderSettings,
    pub camera: Camera,
    /// Format v1's `[medium]`, or the medium inside the `[[object]]`'s mesh (format v2), whose
    /// bounds are then the mesh's unless the file gives them.
    pub medium: Medium,
    /// The `[[object]]` entries (format v2): closed meshes bounding `medium`, with a refractive
    /// index, joined into one [`Object`] (they share the medium and the index). `None` for a
    /// v1 scene, whose medium's boundary is its box (and sphere) with index 1.
    pub object: Option<Object>,
    /// At least one, unless the medium emits (a scene lit by its own emission needs none).
    pub lights: Vec<Light>,
}

/// Largest accepted `object.ior`.
pub const MAX_IOR: f32 = 10.0;

/// The scene's `[[object]]` entries (format v2): watertight triangle meshes with the scene's
/// medium inside (the density is the medium's inside a mesh, 0 outside) and a smooth
/// dielectric boundary. Several entries are disjoint (checked on load: no two meshes
/// intersect or nest) and share one medium and index, so their union is one closed mesh whose
/// inside is the union of theirs: every solver sees one mesh, whatever the number of entries.
#[derive(Clone)]
pub struct Object {
    /// The union of the parts' meshes, transformed to scene units, in entry order (part k's
    /// triangles follow part k - 1's); each part closed and outward-wound (checked on load).
    pub mesh: Arc<mesh::TriangleMesh>,
    /// Over `mesh`'s triangles, built on load: `path` traverses it on the GPU.
    pub bvh: Arc<bvh::Bvh>,
    /// One per `[[object]]` entry, in file order; at least one.
    pub parts: Vec<ObjectPart>,
    /// Refractive index inside object[0] relative to the vacuum outside (eta); 1 =
    /// index-matched. Every part's when `materials` holds one; else see `materials`.
    pub ior: f32,
    /// The distinct materials of the entries, object[0]'s first (at most [`MAX_MATERIALS`]);
    /// one when every entry has the same medium coefficients, index and density table. Each
    /// part names its own ([`ObjectPart::material`]); the scene's `medium` holds object[0]'s
    /// coefficients.
    pub materials: Vec<Material>,
    /// The density fields of the entries (at most one per material): entries that write the
    /// same density table share one field over their given bounds or their meshes' union box;
    /// field 0 is object[0]'s. With one field it is the scene's `medium.density` over
    /// `medium.bounds`; with several, `medium.bounds` is their union and each material's
    /// density is its field's.
    pub fields: Vec<DensityField>,
    /// One entry whose mesh bounds a convex solid ([`mesh::TriangleMesh::is_convex`]): a
    /// straight path from inside to any point outside crosses the surface once, which `path`'s
    /// manifold next-event estimation (one refraction) needs for a light outside.
    pub convex: bool,
}

/// One `[[object]]` entry of an [`Object`]: where its mesh came from and where it was placed.
#[derive(Debug, Clone, PartialEq)]
pub struct ObjectPart {
    /// The OBJ file, as resolved against the scene file's folder.
    pub file: PathBuf,
    pub transform: mesh::MeshTransform,
    /// How many of the union's triangles are this part's.
    pub triangles: usize,
    /// Index of its material in [`Object::materials`].
    pub material: usize,
}

/// Most distinct materials the `[[object]]` entries of one scene may have (the scene block
/// holds a fixed table of them: glsl/include/scene.glsl).
pub const MAX_MATERIALS: usize = 16;

/// What fills one `[[object]]` and bounds it: the medium's coefficients, the refractive index
/// and the density field (constant, sphere or grid over a box, [`Object::fields`]), which
/// multiplies `sigma_t` as in a v1 medium.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Material {
    /// Extinction scale, 1/unit, RGB.
    pub sigma_t: Vec3,
    /// Single-scattering albedo sigma_s / sigma_t per channel.
    pub albedo: Vec3,
    /// Henyey-Greenstein mean cosine.
    pub g: f32,
    /// Refractive index inside relative to the vacuum outside (eta); 1 = index-matched.
    pub ior: f32,
    /// Its density field ([`Object::fields`]).
    pub field: usize,
    /// Emitted radiance Le, W/(m^2 sr) per channel ([`Emission::constant_part`]): the
    /// constant, or the scale of the scene's emission grid where `emission_grid` is set.
    pub emission: Vec3,
    /// Its emission is `emission` times the scene's emission grid ([`Emission::Grid`]).
    pub emission_grid: bool,
}

impl Material {
    /// The coefficients of `m` with index `ior` and density field `field`.
    pub fn of(m: &Medium, ior: f32, field: usize) -> Material {
        Material {
            sigma_t: m.sigma_t,
            albedo: m.albedo,
            g: m.g,
            ior,
            field,
            emission: m.emission.constant_part(),
            emission_grid: matches!(m.emission, Emission::Grid(_)),
        }
    }

    /// Absorption scale sigma_a = sigma_t (1 - albedo), 1/unit per channel.
    pub fn sigma_a(&self) -> Vec3 {
        self.sigma_t * (Vec3::ONE - self.albedo)
    }
}

/// One density field of the objects: a v1 density kind over a box (a grid spans it).
#[derive(Debug, Clone, PartialEq)]
pub struct DensityField {
    pub density: Density,
    pub bounds_min: Vec3,
    pub bounds_max: Vec3,
}

/// A density over a box, borrowed: an object's [`DensityField`] or a v1 medium's density and
/// bounds ([`Scene::fields`]).
#[derive(Debug, Clone, Copy)]
pub struct FieldRef<'a> {
    pub density: &'a Density,
    pub bounds_min: Vec3,
    pub bounds_max: Vec3,
}

impl DensityField {
    /// This field, borrowed.
    pub fn as_ref(&self) -> FieldRef<'_> {
        FieldRef { density: &self.density, bounds_min: self.bounds_min, bounds_max: self.bounds_max }
    }

    /// Density multiplier at `p` (CPU reference), as [`Medium::density_at`] over this box.
    pub fn density_at(&self, p: Vec3) -> f32 {
        self.as_ref().density_at(p)
    }

    /// A medium of this density and box with the given coefficients.
    pub fn medium_with(&self, sigma_t: Vec3, albedo: Vec3, g: f32) -> Medium {
        Medium {
            bounds_min: self.bounds_min,
            bounds_max: self.bounds_max,
            sigma_t,
            albedo,
            g,
            density: self.density.clone(),
            emission: Emission::None,
        }
    }
}

impl Object {
    /// A v1 `[medium]`'s box as an index-matched object (12 triangles, outward, its one
    /// material the medium's over its own density and bounds): for solvers whose method is
    /// built on an object's interior (`sh-single` samples it), so that a v1 scene means to
    /// them exactly what it means to the others (light crosses the box unchanged).
    pub fn box_of(medium: &Medium) -> Object {
        let (lo, hi) = (medium.bounds_min, medium.bounds_max);
        let positions: Vec<Vec3> = (0..8)
            .map(|i| {
                Vec3::new(
                    if i & 1 == 0 { lo.x } else { hi.x },
                    if i & 2 == 0 { lo.y } else { hi.y },
                    if i & 4 == 0 { lo.z } else { hi.z },
                )
            })
            .collect();
        let triangles = mesh::BOX_TRIANGLES.to_vec();
        let file = PathBuf::from("[medium] box");
        let mesh = mesh::TriangleMesh { positions, triangles, file: file.clone() };
        let bvh = bvh::Bvh::build(&mesh);
        let field = DensityField { density: medium.density.clone(), bounds_min: lo, bounds_max: hi };
        Object {
            mesh: Arc::new(mesh),
            bvh: Arc::new(bvh),
            parts: vec![ObjectPart { file, transform: mesh::MeshTransform::identity(), triangles: 12, material: 0 }],
            ior: 1.0,
            materials: vec![Material::of(medium, 1.0, 0)],
            fields: vec![field],
            convex: true,
        }
    }

    /// The meshes' files for messages: `meshes/a.obj`, or `meshes/a.obj + meshes/b.obj`.
    pub fn describe(&self) -> String {
        self.parts.iter().map(|p| p.file.display().to_string()).collect::<Vec<_>>().join(" + ")
    }

    /// Whether the boundary refracts and reflects (ior != 1): paths then meet a smooth
    /// dielectric there; at ior 1 light crosses it unchanged, as a v1 medium's box.
    pub fn refractive(&self) -> bool {
        self.materials.iter().any(|m| m.ior != 1.0)
    }

    /// Whether the entries differ in material (coefficients, index or density): a solver that
    /// holds one medium cannot render the scene.
    pub fn several_materials(&self) -> bool {
        self.materials.len() > 1
    }

    /// The medium inside the objects of material `k`: its coefficients over its field's
    /// density and box.
    pub fn material_medium(&self, k: usize) -> Medium {
        let x = &self.materials[k];
        let mut m = self.fields[x.field].medium_with(x.sigma_t, x.albedo, x.g);
        // A grid's emission is the scene's medium's (one material only: the loader checks).
        if !x.emission_grid && x.emission.max_element() > 0.0 {
            m.emission = Emission::Constant(x.emission);
        }
        m
    }

    /// The material of `part`.
    pub fn material_of(&self, part: usize) -> &Material {
        &self.materials[self.parts[part].material]
    }

    /// Whether `light` lies outside the mesh: a point light outside it, any directional light
    /// (never an environment, which surrounds everything). Behind a refractive boundary such a
    /// delta light reaches the medium only by refraction.
    pub fn light_outside(&self, light: &Light) -> bool {
        match *light {
            Light::Point { position, .. } => !self.contains(position),
            Light::Directional { .. } => true,
            Light::Environment { .. } => false,
        }
    }

    /// The material of the object `p` lies inside ([`Object::materials`]), or None outside every
    /// mesh. Objects are disjoint and none nests, so the nearest surface from a point inside
    /// one is its own; each triangle carries its object's material.
    pub fn material_at(&self, p: Vec3) -> Option<usize> {
        if !self.contains(p) {
            return None;
        }
        let d = Vec3::new(0.5773, 0.5774, 0.5773503).normalize();
        let hit = self.bvh.intersect(p, d, 0.0, f32::INFINITY)?;
        Some(self.bvh.tag(hit.triangle) as usize)
    }

    /// Whether `p` lies inside the mesh: the parity of a ray's crossings (the direction is
    /// fixed and irrational-looking so it does not run along an edge of a shipped mesh).
    pub fn contains(&self, p: Vec3) -> bool {
        bvh_contains(&self.bvh, self.mesh.triangles.len(), p)
    }
}

/// Whether `p` lies inside the closed mesh of `triangles` triangles under `bvh`: the parity of
/// a ray's crossings (the direction is fixed and irrational-looking so it does not run along an
/// edge of a shipped mesh).
pub(crate) fn bvh_contains(bvh: &bvh::Bvh, triangles: usize, p: Vec3) -> bool {
    let d = Vec3::new(0.5773, 0.5774, 0.5773503).normalize();
    let mut t = 0.0f32;
    let mut inside = false;
    // A closed mesh is crossed finitely often; the cap only guards against a degenerate loop.
    for _ in 0..triangles + 1 {
        match bvh.intersect(p, d, t, f32::INFINITY) {
            Some(hit) => {
                inside = !inside;
                t = hit.t;
            }
            None => break,
        }
    }
    inside
}

impl std::fmt::Debug for Object {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Object")
            .field("parts", &self.parts)
            .field("triangles", &self.mesh.triangles.len())
            .field("ior", &self.ior)
            .field("materials", &self.materials)
            .finish()
    }
}

impl PartialEq for Object {
    fn eq(&self, other: &Self) -> bool {
        self.ior == other.ior
            && self.materials == other.materials
            && self.fields == other.fields
            && self.parts == other.parts
            && self.mesh.positions == other.mesh.positions
            && self.mesh.triangles == other.mesh.triangles
    }
}

/// `[render]`: image size, the seed every random choice derives from, default samples/pixel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderSettings {
    /// Pixels, 1 ..= [`MAX_IMAGE_SIZE`].
    pub width: u32,
    /// Pixels, 1 ..= [`MAX_IMAGE_SIZE`].
    pub height: u32,
    pub seed: u64,
    /// Default samples per pixel for `path` (>= 1).
    pub spp: u32,
    /// The index of the first sample of every pixel (`--samples A..B` is `first_sample = A`,
    /// `spp = B - A`): a solver that samples pixels renders sample indices
    /// `first_sample .. first_sample + spp`, whose random numbers depend on (seed, pixel,
    /// index) only, so renders of disjoint ranges merge into the render of their union
    /// (`scatterlab merge`). 0 by default; `first_sample + spp` fits in 32 bits.
    pub first_sample: u32,
    /// Default exposure of tone-mapped outputs, in stops (`--exposure` overrides): a scene
    /// lit far above 1 W/(m^2 sr) (a light inside a cloud) says how it is best seen.
    pub exposure: f32,
}

/// Largest accepted `render.width` / `render.height`.
pub const MAX_IMAGE_SIZE: u32 = 16384;

/// Projection. Pixels are square; a pixel's value is the average radiance over its area.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CameraKind {
    /// Full field of view along the image x axis, degrees in (0, 180).
    Perspective { fov_deg: f32 },
    /// Width of the view along the image x axis, scene units (> 0).
    Orthographic { extent: f32 },
}

/// A look-at camera. `origin != target`, `up` not parallel to the view direction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    pub kind: CameraKind,
    pub origin: Vec3,
    pub target: Vec3,
    pub up: Vec3,
}

impl Camera {
    /// Orthonormal camera frame `(right, up, forward)`: `forward` points from origin to
    /// target, `right` is the image +x axis (columns increasing), `up` the image +y axis
    /// (rows decreasing). Same convention as Mitsuba's `look_at` sensor.
    pub fn basis(&self) -> (Vec3, Vec3, Vec3) {
        let forward = (self.target - self.origin).normalize_or_zero();
        let right = forward.cross(self.up).normalize_or_zero();
        let up = right.cross(forward);
        (right, up, forward)
    }
}

/// `[medium]`: one box of participating medium; outside it is vacuum.
/// `sigma_t(x) = sigma_t * density(x)`, `sigma_s = albedo * sigma_t`.
#[derive(Debug, Clone, PartialEq)]
pub struct Medium {
    pub bounds_min: Vec3,
    /// Strictly greater than `bounds_min` on every axis.
    pub bounds_max: Vec3,
    /// Extinction scale, 1/unit, RGB, finite and >= 0 (a scalar in the file becomes splat).
    pub sigma_t: Vec3,
    /// Single-scattering albedo sigma_s / sigma_t, each channel in [0, 1].
    pub albedo: Vec3,
    /// Henyey-Greenstein mean cosine in (-1, 1); g > 0 scatters forward.
    pub g: f32,
    pub density: Density,
    /// What the medium emits ([`Emission`]).
    pub emission: Emission,
}

/// What a medium emits: its emitted radiance Le(x), W/(m^2 sr) per channel. The transfer
/// equation's source is sigma_a(x) Le(x) (pbrt-v4's convention): the medium emits where it
/// absorbs, so an optically thick absorbing emitter glows with radiance Le, and a medium of
/// albedo 1 emits nothing.
#[derive(Debug, Clone, PartialEq, Default)]
pub enum Emission {
    /// No emission (the default).
    #[default]
    None,
    /// The same Le everywhere in the medium.
    Constant(Vec3),
    /// Le from a grid spanning the medium's bounds (voxel centres, trilinear, as the density).
    Grid(EmissionGrid),
}

/// An emission grid: `emission = { kind = "grid" | "vdb", ... }` (one channel, times
/// `emission_scale`), or a temperature field turned into blackbody radiance at its voxel
/// centres (three channels: linear sRGB of Planck's law, `physics::blackbody`, times
/// `emission_scale`).
#[derive(Debug, Clone, PartialEq)]
pub struct EmissionGrid {
    /// One grid per channel: one (grey, times `scale`) or three (r, g, b, times `scale`), of
    /// equal dims.
    pub planes: Vec<Grid>,
    /// `emission_scale`, per channel.
    pub scale: Vec3,
    /// Where the planes came from a temperature field, its mapping to kelvin.
    pub temperature: Option<TemperatureMap>,
}

/// How a temperature grid's values become kelvin (pbrt-v4's GridMedium and NanoVDBMedium):
/// T = (value - offset) * scale, and voxels at or below `cutoff` kelvin emit nothing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TemperatureMap {
    pub scale: f32,
    pub offset: f32,
    /// Kelvin; pbrt-v4 fixes it at 100.
    pub cutoff: f32,
}

impl Emission {
    /// Whether the medium emits anything (some Le > 0).
    pub fn is_some(&self) -> bool {
        match self {
            Emission::None => false,
            Emission::Constant(le) => le.max_element() > 0.0,
            Emission::Grid(g) => g.scale.max_element() > 0.0 && g.planes.iter().any(|p| p.max_value() > 0.0),
        }
    }

    /// The constant Le, or the grid's per-channel scale: what the material table carries.
    pub fn constant_part(&self) -> Vec3 {
        match self {
            Emission::None => Vec3::ZERO,
            Emission::Constant(le) => *le,
            Emission::Grid(g) => g.scale,
        }
    }

    /// The grid, if Le varies over the medium.
    pub fn grid(&self) -> Option<&EmissionGrid> {
        match self {
            Emission::Grid(g) => Some(g),
            _ => None,
        }
    }
}

impl EmissionGrid {
    /// Voxels per axis.
    pub fn dims(&self) -> [u32; 3] {
        self.planes[0].dims
    }

    /// Le at `u`, the position in the medium's box scaled to [0, 1]^3 (CPU reference;
    /// glsl/include/scene.glsl `emission_at`).
    pub fn le(&self, u: Vec3) -> Vec3 {
        let v = |c: usize| self.planes[c.min(self.planes.len() - 1)].sample(u);
        self.scale * Vec3::new(v(0), v(1), v(2))
    }

    /// Largest Le per channel over the voxels.
    pub fn max_le(&self) -> Vec3 {
        let m = |c: usize| self.planes[c.min(self.planes.len() - 1)].max_value();
        self.scale * Vec3::new(m(0), m(1), m(2))
    }

    /// Bytes of its planes as f32.
    pub fn bytes(&self) -> u64 {
        self.planes.iter().map(|p| p.data.len() as u64 * 4).sum()
    }
}

/// Density multiplier inside the medium bounds.
#[derive(Debug, Clone, PartialEq)]
pub enum Density {
    /// 1 everywhere inside the bounds.
    Constant,
    /// 1 inside the sphere (and the bounds), 0 outside.
    Sphere { center: Vec3, radius: f32 },
    /// A voxel grid spanning the bounds.
    Grid(Grid),
}

/// A density grid spanning the medium bounds. Sample `(i, j, k)` sits at the voxel centre
/// `((i, j, k) + 0.5) / dims`; values are finite and >= 0.
#[derive(Debug, Clone, PartialEq)]
pub struct Grid {
    pub dims: [u32; 3],
    /// `dims[0] * dims[1] * dims[2]` values, x fastest, then y, then z.
    pub data: Vec<f32>,
    /// The file it was loaded from (resolved against the scene file's folder).
    pub file: PathBuf,
}

/// An emitter (Mitsuba 3 `point`, `directional`, `constant`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Light {
    /// Radiant intensity, W/sr.
    Point { position: Vec3, intensity: Vec3 },
    /// `direction` is normalised and is the direction the light travels; irradiance in W/m^2
    /// on a plane perpendicular to it.
    Directional { direction: Vec3, irradiance: Vec3 },
    /// Uniform radiance arriving from every direction at infinity, W/(m^2 sr).
    Environment { radiance: Vec3 },
}

/// Limits applied while loading.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LoadOptions {
    /// Largest grid accepted (density, emission or temperature), in bytes of f32 data as held
    /// in memory (checked before reading it).
    pub memory_budget_bytes: u64,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions { memory_budget_bytes: 4 << 30 }
    }
}

/// What physics a scene needs; solvers compile in and allocate only these.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Features {
    /// `g != 0`.
    pub anisotropic: bool,
    /// `sigma_t` or `albedo` differ between channels.
    pub chromatic: bool,
    /// A point light lies strictly inside the bounds where the density is > 0.
    pub light_inside: bool,
    /// `Density::Constant`.
    pub homogeneous: bool,
    pub has_environment: bool,
    /// Grid resolution when the density is a grid.
    pub grid_dims: Option<[u32; 3]>,
    /// The medium (or an object's material) emits: some Le > 0 where sigma_a > 0.
    pub emissive: bool,
}

impl Scene {
    /// Load a scene file, apply `overrides` (dotted key, TOML value text: `("medium.albedo",
    /// "0.5")`, `("medium.sigma_t", "[1, 2, 3]")`, `("camera.kind", "\"orthographic\"")`) to
    /// the parsed TOML before validation, and validate. Relative grid paths resolve against
    /// the scene file's folder.
    pub fn load(path: &Path, overrides: &[(String, String)], opts: &LoadOptions) -> Result<Scene, SceneError> {
        let text =
            std::fs::read_to_string(path).map_err(|source| SceneError::Read { file: path.to_path_buf(), source })?;
        let base_dir = match path.parent() {
            Some(dir) if !dir.as_os_str().is_empty() => dir,
            _ => Path::new("."),
        };
        parse::parse_scene(&text, path, base_dir, overrides, opts)
    }

    /// [`Scene::load`] from a string: relative grid paths resolve against `base_dir`, and
    /// `name` stands for the file in messages and in [`Scene::source`].
    // Not `FromStr`: it needs a base directory, overrides and options.
    #[allow(clippy::should_implement_trait)]
    pub fn from_str(
        text: &str,
        name: &str,
        base_dir: &Path,
        overrides: &[(String, String)],
        opts: &LoadOptions,
    ) -> Result<Scene, SceneError> {
        parse::parse_scene(text, Path::new(name), base_dir, overrides, opts)
    }
}

impl Scene {
    /// This scene with `render.*` keys overridden (`render.spp`, `render.first_sample`, `render.width`,
    /// `render.height`, `render.seed`), validated as in a scene file: for measurements that
    /// vary them on a loaded scene (a bench ladder's samples per pixel). Other keys change
    /// what the scene is and must go through [`Scene::load`].
    pub fn with_overrides(&self, overrides: &[(String, String)]) -> Result<Scene, SceneError> {
        let mut out = self.clone();
        for (key, value) in overrides {
            let bad = |message: String| SceneError::Override { file: self.source.clone(), key: key.clone(), message };
            let int = |max: u64| -> Result<u64, SceneError> {
                value
                    .trim()
                    .parse::<u64>()
                    .ok()
                    .filter(|v| (1..=max).contains(v))
                    .ok_or_else(|| bad(format!("{value:?} is out of range; use an integer in 1 ..= {max}")))
            };
            match key.as_str() {
                "render.spp" => out.render.spp = int(u32::MAX as u64)? as u32,
                "render.first_sample" => {
                    out.render.first_sample = value
                        .trim()
                        .parse()
                        .map_err(|_| bad(format!("{value:?} must be an integer in 0 ..= {}", u32::MAX)))?
                }
                "render.width" => out.render.width = int(MAX_IMAGE_SIZE as u64)? as u32,
                "render.height" => out.render.height = int(MAX_IMAGE_SIZE as u64)? as u32,
                "render.seed" => {
                    out.render.seed =
                        value.trim().parse().map_err(|_| bad(format!("{value:?} must be an integer >= 0")))?
                }
                _ => {
                    return Err(bad(
                        "only render.spp, render.first_sample, render.width, render.height and render.seed can be \
                         applied to a loaded scene"
                            .into(),
                    ))
                }
            }
        }
        if out.render.first_sample as u64 + out.render.spp as u64 > u32::MAX as u64 {
            return Err(SceneError::Override {
                file: self.source.clone(),
                key: "render.first_sample".into(),
                message: format!(
                    "samples {} .. {} end past 2^32; sample indices are 32-bit",
                    out.render.first_sample,
                    out.render.first_sample as u64 + out.render.spp as u64
                ),
            });
        }
        Ok(out)
    }
}

/// A digest of what a scene is: its file text and, for a grid density, the grid's values
/// (the file the scene names can change without the scene text changing). Hex SHA-256. The
/// `--set` overrides are not in it: provenance records them beside it, as given.
pub fn content_hash(text: &str, scene: &Scene) -> String {
    use sha2::{Digest, Sha256};
    let mut h = Sha256::new();
    h.update((text.len() as u64).to_le_bytes());
    h.update(text.as_bytes());
    if let Density::Grid(g) = &scene.medium.density {
        h.update(bytemuck::cast_slice::<f32, u8>(&g.data));
    }
    if let Emission::Grid(e) = &scene.medium.emission {
        for p in &e.planes {
            h.update(bytemuck::cast_slice::<f32, u8>(&p.data));
        }
    }
    if let Some(object) = &scene.object {
        h.update(bytemuck::cast_slice::<Vec3, u8>(&object.mesh.positions));
        h.update(bytemuck::cast_slice::<[u32; 3], u8>(&object.mesh.triangles));
    }
    h.finalize().iter().map(|b| format!("{b:02x}")).collect()
}

/// True if a `--set` key belongs to the scene (first segment `render`, `camera`, `medium`,
/// `object` or `light`) rather than to a solver (`path.max_depth`).
pub fn is_scene_key(key: &str) -> bool {
    let first = key.split('.').next().unwrap_or("");
    // `light.0.intensity` and `light[0].intensity` both address the first light.
    let first = first.split('[').next().unwrap_or("");
    matches!(first, "render" | "camera" | "medium" | "object" | "light")
}
