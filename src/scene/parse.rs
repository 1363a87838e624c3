//! Scene parsing: TOML text -> `toml::Value` tree -> overrides -> typed raw structs (serde,
//! unknown keys rejected) -> validated [`Scene`].

use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::Vec3;
use serde::de::{self, Deserializer, SeqAccess, Visitor};
use serde::Deserialize;

use super::bvh::{first_overlap, Bvh};
use super::error::one_line;
use super::grid::{load_grid, GridRequest};
use super::mesh::{load_obj, MeshTransform, TriangleMesh};
use super::vdb::{load_vdb, VdbRequest};
use super::{
    Camera, CameraKind, Density, DensityField, Emission, EmissionGrid, Grid, Light, LoadOptions, Material, Medium,
    Object, ObjectPart, RenderSettings, Scene, SceneError, TemperatureMap, MAX_IMAGE_SIZE, MAX_IOR, MAX_MATERIALS,
};

// ---------------------------------------------------------------------------------------
// Raw file structure (serde). Only shape and types are checked here; ranges come later.
// ---------------------------------------------------------------------------------------

/// Top level of a scene file.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScene {
    render: RawRender,
    camera: RawCamera,
    /// Format v1's one box of medium; a scene has this or `[[object]]` entries.
    medium: Option<RawMedium>,
    /// `[[object]]` tables (format v2), deserialised one by one so errors name `object[i]`.
    #[serde(default)]
    object: Vec<toml::Value>,
    /// `[[light]]` tables, deserialised one by one so errors can name `light[i]`.
    #[serde(default)]
    light: Vec<toml::Value>,
}

/// `[render]`. Integers are read wide and range-checked with a readable message.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRender {
    width: i64,
    height: i64,
    #[serde(default = "default_seed")]
    seed: i64,
    #[serde(default = "default_spp")]
    spp: i64,
    #[serde(default)]
    first_sample: i64,
    #[serde(default)]
    exposure: f64,
}

fn default_seed() -> i64 {
    1
}

fn default_spp() -> i64 {
    256
}

/// `[camera]`. `kind` is a plain string so a wrong fov/extent combination gets its own message.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCamera {
    #[serde(default = "default_camera_kind")]
    kind: String,
    origin: [f32; 3],
    target: [f32; 3],
    #[serde(default = "default_up")]
    up: [f32; 3],
    fov: Option<f32>,
    extent: Option<f32>,
}

fn default_camera_kind() -> String {
    "perspective".to_owned()
}

fn default_up() -> [f32; 3] {
    [0.0, 1.0, 0.0]
}

/// `[medium]`.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMedium {
    /// Required in `[medium]`; in an object's medium it defaults to the mesh's bounds.
    bounds: Option<[[f32; 3]; 2]>,
    sigma_t: Rgb,
    albedo: Rgb,
    #[serde(default)]
    g: f32,
    #[serde(default = "default_density")]
    density: RawDensity,
    /// Emitted radiance Le, W/(m^2 sr): a number, `[r, g, b]`, or a grid table
    /// ([`RawGridFile`]); read by hand so each form gets its own message.
    emission: Option<toml::Value>,
    /// Multiplies `emission` or the blackbody radiance of `temperature` (number or RGB).
    emission_scale: Option<Rgb>,
    /// A temperature grid, kelvin after `temperature_scale` and `temperature_offset`: blackbody
    /// emission (physics::blackbody).
    temperature: Option<RawGridFile>,
    temperature_scale: Option<f64>,
    temperature_offset: Option<f64>,
    temperature_cutoff: Option<f64>,
}

/// A grid file an emission or temperature is read from (`{ kind = "grid", file, dims }` or
/// `{ kind = "vdb", file, grid }`), as the density's.
#[derive(Deserialize, PartialEq, Clone)]
#[serde(tag = "kind", rename_all = "lowercase", deny_unknown_fields)]
enum RawGridFile {
    Grid { file: String, dims: Option<[i64; 3]> },
    Vdb { file: String, grid: Option<String> },
}

fn default_density() -> RawDensity {
    RawDensity::Constant {}
}

/// `medium.density = { kind = ..., ... }`.
#[derive(Deserialize, PartialEq)]
#[serde(tag = "kind", rename_all = "lowercase", deny_unknown_fields)]
enum RawDensity {
    Constant {},
    Sphere {
        center: [f32; 3],
        radius: f32,
    },
    Grid {
        file: String,
        dims: Option<[i64; 3]>,
    },
    /// An OpenVDB file's float grid (`grid`, default "density").
    Vdb {
        file: String,
        grid: Option<String>,
    },
}

/// One `[[object]]` (format v2): a closed mesh with a medium inside.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawObject {
    mesh: String,
    #[serde(default)]
    translate: [f32; 3],
    /// Degrees, XYZ Euler angles (X applied first).
    #[serde(default)]
    rotate: [f32; 3],
    #[serde(default = "default_one")]
    scale: f32,
    #[serde(default = "default_one")]
    ior: f32,
    medium: RawMedium,
}

fn default_one() -> f32 {
    1.0
}

/// One `[[light]]`.
#[derive(Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase", deny_unknown_fields)]
enum RawLight {
    Point { position: [f32; 3], intensity: Rgb },
    Directional { direction: [f32; 3], irradiance: Rgb },
    Environment { radiance: Rgb },
}

/// A colour: a scalar (splat) or `[r, g, b]`.
#[derive(Clone, Copy, PartialEq)]
struct Rgb([f64; 3]);

impl<'de> Deserialize<'de> for Rgb {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct RgbVisitor;
        impl<'de> Visitor<'de> for RgbVisitor {
            type Value = Rgb;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a number or an array of 3 numbers [r, g, b]")
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> Result<Rgb, E> {
                Ok(Rgb([v; 3]))
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<Rgb, E> {
                Ok(Rgb([v as f64; 3]))
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> Result<Rgb, E> {
                Ok(Rgb([v as f64; 3]))
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Rgb, A::Error> {
                let mut out = [0.0; 3];
                for (i, slot) in out.iter_mut().enumerate() {
                    *slot = seq.next_element::<f64>()?.ok_or_else(|| de::Error::invalid_length(i, &self))?;
                }
                if seq.next_element::<de::IgnoredAny>()?.is_some() {
                    return Err(de::Error::invalid_length(4, &self));
                }
                Ok(Rgb(out))
            }
        }
        deserializer.deserialize_any(RgbVisitor)
    }
}

// ---------------------------------------------------------------------------------------
// Entry point
// ---------------------------------------------------------------------------------------

/// Parse, override, validate. `file` names the scene in messages; grids resolve against
/// `base_dir`.
pub(crate) fn parse_scene(
    text: &str,
    file: &Path,
    base_dir: &Path,
    overrides: &[(String, String)],
    opts: &LoadOptions,
) -> Result<Scene, SceneError> {
    let ctx = Ctx { file, text, overrides };
    ctx.parse(base_dir, opts).map_err(|e| ctx.attribute_to_override(e))
}

struct Ctx<'a> {
    file: &'a Path,
    text: &'a str,
    overrides: &'a [(String, String)],
}

impl Ctx<'_> {
    fn parse(&self, base_dir: &Path, opts: &LoadOptions) -> Result<Scene, SceneError> {
        // Syntax.
        let table: toml::Table = self.text.parse().map_err(|e| self.syntax_error(&e))?;
        let mut root = toml::Value::Table(table);

        // Overrides act on the tree, before any typing or validation.
        for (key, value) in self.overrides {
            apply_override(&mut root, key, value).map_err(|message| SceneError::Override {
                file: self.file.to_path_buf(),
                key: key.clone(),
                message,
            })?;
        }

        // Shape and types.
        let raw: RawScene = root.try_into().map_err(|e| self.serde_error("", &e))?;
        let mut raw_lights = Vec::with_capacity(raw.light.len());
        for (i, value) in raw.light.into_iter().enumerate() {
            let light: RawLight = value.try_into().map_err(|e| self.serde_error(&format!("light[{i}]"), &e))?;
            raw_lights.push(light);
        }

        // Values: cheap checks first, the mesh and grid files last.
        let render = self.render(&raw.render)?;
        let camera = self.camera(&raw.camera)?;
        let lights = self.lights(&raw_lights)?;

        let (medium, object) = match (raw.medium, raw.object.len()) {
            (Some(m), 0) => {
                let Some(b) = &m.bounds else {
                    return Err(SceneError::MissingKey {
                        file: self.file.to_path_buf(),
                        key: "medium.bounds".into(),
                        hint: "write bounds = [[min x, y, z], [max x, y, z]], the box that holds the medium".into(),
                    });
                };
                let (bounds_min, bounds_max) = self.bounds("medium.bounds", b)?;
                self.camera_sees_medium(&camera, &render, bounds_min, bounds_max)?;
                (self.medium("medium", &m, bounds_min, bounds_max, base_dir, opts)?, None)
            }
            (None, 0) => {
                return Err(SceneError::MissingKey {
                    file: self.file.to_path_buf(),
                    key: "medium".into(),
                    hint: "a scene needs a [medium] table (a box of medium) or an [[object]] (a mesh with a medium \
                        inside); see docs/scene-format.md"
                        .into(),
                })
            }
            (Some(_), _) => {
                return Err(self.invalid(
                    "object",
                    "a scene has a [medium] or [[object]] entries, not both (a v1 box beside meshes is not \
                        supported yet); put the box's medium in an object with a box mesh, or drop [medium]",
                ))
            }
            (None, _) => {
                let mut raws = Vec::with_capacity(raw.object.len());
                for (i, value) in raw.object.into_iter().enumerate() {
                    let o: RawObject = value.try_into().map_err(|e| self.serde_error(&format!("object[{i}]"), &e))?;
                    raws.push(o);
                }
                let (object, medium) = self.objects(&raws, base_dir, opts)?;
                let (bounds_min, bounds_max) = (medium.bounds_min, medium.bounds_max);
                self.camera_sees_medium(&camera, &render, bounds_min, bounds_max)?;
                if object.contains(camera.origin) {
                    return Err(self.invalid(
                        "camera.origin",
                        format!(
                            "the camera {} is inside an object's mesh; cameras inside an object are not supported yet, \
                                move it outside",
                            fmt3(camera.origin)
                        ),
                    ));
                }
                (medium, Some(object))
            }
        };
        let scene = Scene { source: self.file.to_path_buf(), render, camera, medium, object, lights };
        self.magnitudes(&scene)?;
        // A scene lit by its own emission needs no light; anything else would render black.
        if scene.lights.is_empty() && !scene.emissive() {
            return Err(self.invalid(
                "light",
                "the scene has no lights and its medium emits nothing; add at least one [[light]] table with kind = \
                    \"point\", \"directional\" or \"environment\", or give the medium an emission",
            ));
        }
        Ok(scene)
    }

    /// The `[[object]]` entries' meshes, transforms and materials joined into one [`Object`],
    /// and the scene's medium (object[0]'s coefficients). Entries that write the same density
    /// table share one density field over their given `medium.bounds` (the same in every one of
    /// them that gives them, containing their meshes), else the union of their transformed
    /// meshes' bounds; entries of different density tables have fields of their own. The
    /// medium's density and bounds are the field's when there is one, else the fields' union
    /// box (each material names its field). The meshes must be disjoint: no two intersect,
    /// none lies inside another.
    fn objects(&self, raws: &[RawObject], base_dir: &Path, opts: &LoadOptions) -> Result<(Object, Medium), SceneError> {
        let mut parts = Vec::with_capacity(raws.len());
        let mut meshes = Vec::with_capacity(raws.len());
        for (i, o) in raws.iter().enumerate() {
            let (mesh, part) = self.part(i, o, base_dir)?;
            meshes.push(mesh);
            parts.push(part);
        }
        if let Some(o) = first_overlap(&meshes) {
            let how = if o.nested { "and object[{a}]'s mesh {} nest" } else { "intersects object[{a}]'s mesh {}" };
            let how = how.replace("{a}", &o.a.to_string()).replacen("{}", &parts[o.a].file.display().to_string(), 1);
            return Err(self.invalid(
                &format!("object[{}].mesh", o.b),
                format!(
                    "{} {how} near {}: objects must be disjoint (overlapping or nested media are not supported \
                        yet); move or scale them apart",
                    parts[o.b].file.display(),
                    fmt3(o.at)
                ),
            ));
        }
        // The density fields: entries grouped by their density table, in order of first use.
        let mut groups: Vec<Vec<usize>> = Vec::new();
        for (i, o) in raws.iter().enumerate() {
            match groups.iter_mut().find(|g| raws[g[0]].medium.density == o.medium.density) {
                Some(g) => g.push(i),
                None => groups.push(vec![i]),
            }
        }
        let mut fields: Vec<DensityField> = Vec::with_capacity(groups.len());
        let mut field_of = vec![0usize; raws.len()];
        let mut media: Vec<Option<Medium>> = vec![None; raws.len()];
        for (f, group) in groups.iter().enumerate() {
            let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
            for &i in group {
                let (a, b) = meshes[i].bounds();
                lo = lo.min(a);
                hi = hi.max(b);
            }
            let mut given: Option<(usize, Vec3, Vec3)> = None;
            for &i in group {
                let Some(b) = &raws[i].medium.bounds else { continue };
                let key = format!("object[{i}].medium.bounds");
                let (blo, bhi) = self.bounds(&key, b)?;
                if let Some((k, glo, ghi)) = given {
                    if (blo, bhi) != (glo, ghi) {
                        return Err(self.invalid(
                            &key,
                            format!(
                                "{}..{} differ from object[{k}]'s {}..{}: objects of one density table share one \
                                    density, whose grid spans one box; give the same bounds or leave them out",
                                fmt3(blo),
                                fmt3(bhi),
                                fmt3(glo),
                                fmt3(ghi)
                            ),
                        ));
                    }
                    continue;
                }
                if !(blo.cmple(lo).all() && bhi.cmpge(hi).all()) {
                    let what = if group.len() == 1 {
                        "the transformed mesh's bounds"
                    } else {
                        "the transformed meshes' bounds"
                    };
                    return Err(self.invalid(
                        &key,
                        format!(
                            "{}..{} must contain {what} {}..{} (the medium fills the mesh); widen them, or leave \
                                bounds out to use the mesh's",
                            fmt3(blo),
                            fmt3(bhi),
                            fmt3(lo),
                            fmt3(hi)
                        ),
                    ));
                }
                given = Some((i, blo, bhi));
            }
            let (bounds_min, bounds_max) = match given {
                Some((_, a, b)) => (a, b),
                None => {
                    // A hair beyond the meshes, so the box never clips a triangle by float rounding.
                    let pad = (hi - lo).length() * 1e-5 + 1e-6;
                    (lo - pad, hi + pad)
                }
            };
            for &i in group {
                let at = format!("object[{i}].medium");
                media[i] = Some(self.medium(&at, &raws[i].medium, bounds_min, bounds_max, base_dir, opts)?);
                field_of[i] = f;
            }
            let m = media[group[0]].as_ref().expect("parsed above");
            fields.push(DensityField { density: m.density.clone(), bounds_min, bounds_max });
        }
        // The materials: coefficients, index and field, shared by equal entries.
        let mut materials: Vec<Material> = Vec::new();
        for (i, o) in raws.iter().enumerate() {
            let m = media[i].as_ref().expect("every entry is in a group");
            let material = Material::of(m, o.ior, field_of[i]);
            parts[i].material = match materials.iter().position(|x| *x == material) {
                Some(k) => k,
                None if materials.len() < MAX_MATERIALS => {
                    materials.push(material);
                    materials.len() - 1
                }
                None => {
                    return Err(self.invalid(
                        &format!("object[{i}].medium"),
                        format!(
                            "is the {}th distinct material (sigma_t, albedo, g, density and ior) among the objects; a \
                                scene holds at most {MAX_MATERIALS}: give some objects the same material",
                            MAX_MATERIALS + 1
                        ),
                    ))
                }
            };
        }
        let mut medium = media[0].take().expect("object[0]'s medium");
        if fields.len() > 1 {
            // Several fields: the medium's box holds them all (cameras, culling); each
            // material's density is its field's ([`Object::fields`]).
            for f in &fields {
                medium.bounds_min = medium.bounds_min.min(f.bounds_min);
                medium.bounds_max = medium.bounds_max.max(f.bounds_max);
            }
        }
        let mesh = TriangleMesh::union(meshes);
        // Each triangle carries its part's material, which a path inside the part meets there.
        let tags: Vec<u32> =
            parts.iter().flat_map(|p| std::iter::repeat(p.material as u32).take(p.triangles)).collect();
        let bvh = Bvh::build_tagged(&mesh, &tags);
        let convex = parts.len() == 1 && mesh.is_convex();
        let object =
            Object { mesh: Arc::new(mesh), bvh: Arc::new(bvh), parts, ior: raws[0].ior, materials, fields, convex };
        Ok((object, medium))
    }

    /// Entry `i`'s mesh, placed by its transform, with its index checked.
    fn part(&self, i: usize, o: &RawObject, base_dir: &Path) -> Result<(TriangleMesh, ObjectPart), SceneError> {
        let key = |name: &str| format!("object[{i}].{name}");
        let translate = self.vec3(&key("translate"), o.translate)?;
        let rotate_deg = self.vec3(&key("rotate"), o.rotate)?;
        if !(o.scale.is_finite() && o.scale > 0.0) {
            return Err(self.invalid(
                &key("scale"),
                format!("scale = {} must be a finite number > 0 (a uniform scale)", num32(o.scale)),
            ));
        }
        if !(o.ior.is_finite() && o.ior > 0.0 && o.ior <= MAX_IOR) {
            return Err(self.invalid(
                &key("ior"),
                format!(
                    "ior = {} must lie in (0, {MAX_IOR}] (the refractive index inside, relative to the vacuum \
                        outside; 1 = index-matched, glass 1.5, water 1.33)",
                    num32(o.ior)
                ),
            ));
        }
        let transform = MeshTransform { translate, rotate_deg, scale: o.scale };
        let written = PathBuf::from(&o.mesh);
        let resolved = if written.is_absolute() { written.clone() } else { base_dir.join(&written) };
        let mesh = load_obj(&resolved, &transform).map_err(|e| {
            let hint = if written.is_relative() && !resolved.exists() {
                " (relative paths are resolved against the scene file's folder)"
            } else {
                ""
            };
            self.invalid(&key("mesh"), format!("`{}`: {e}{hint}", written.display()))
        })?;
        let part = ObjectPart { file: resolved, transform, triangles: mesh.triangles.len(), material: 0 };
        Ok((mesh, part))
    }

    /// A medium (`[medium]` or an object's `medium`) over the given bounds; `at` names it.
    fn medium(
        &self,
        at: &str,
        m: &RawMedium,
        bounds_min: Vec3,
        bounds_max: Vec3,
        base_dir: &Path,
        opts: &LoadOptions,
    ) -> Result<Medium, SceneError> {
        let key = |name: &str| format!("{at}.{name}");
        let sigma_t = self.rgb_non_negative(&key("sigma_t"), m.sigma_t, "extinction")?;
        let albedo = self.albedo(&key("albedo"), m.albedo)?;
        if !m.g.is_finite() || m.g.abs() >= 1.0 {
            return Err(self.invalid(
                &key("g"),
                format!(
                    "g = {} must lie strictly inside (-1, 1) (Henyey-Greenstein mean cosine); use e.g. {}",
                    num32(m.g),
                    if m.g < 0.0 { "-0.99 for very backward scattering" } else { "0.99 for very forward scattering" }
                ),
            ));
        }
        let mut vdb_region = None;
        let density = match &m.density {
            RawDensity::Constant {} => Density::Constant,
            RawDensity::Sphere { center, radius } => {
                let center = self.vec3(&key("density.center"), *center)?;
                if !radius.is_finite() || *radius <= 0.0 {
                    return Err(self.invalid(
                        &key("density.radius"),
                        format!("radius = {} must be a finite number > 0", num32(*radius)),
                    ));
                }
                let closest = center.clamp(bounds_min, bounds_max);
                if closest.distance(center) >= *radius {
                    return Err(self.invalid(
                        &key("density"),
                        format!(
                            "the sphere (center {}, radius {}) does not overlap the bounds {}..{}, so the medium would be empty; move the sphere inside the bounds",
                            fmt3(center), num32(*radius), fmt3(bounds_min), fmt3(bounds_max)
                        ),
                    ));
                }
                Density::Sphere { center, radius: *radius }
            }
            RawDensity::Grid { file, dims } => {
                let written = PathBuf::from(file);
                let resolved = if written.is_absolute() { written.clone() } else { base_dir.join(&written) };
                let grid = load_grid(&GridRequest {
                    scene_file: self.file,
                    file_as_written: &written,
                    resolved,
                    dims: *dims,
                    opts,
                    what: "density",
                    key: &key("density"),
                })?;
                Density::Grid(grid)
            }
            RawDensity::Vdb { file, grid } => {
                let written = PathBuf::from(file);
                let resolved = if written.is_absolute() { written.clone() } else { base_dir.join(&written) };
                let (grid, lo) = load_vdb(&VdbRequest {
                    scene_file: self.file,
                    resolved,
                    file_as_written: &written,
                    grid: grid.as_deref().unwrap_or("density"),
                    opts,
                    what: "density",
                    key: &key("density"),
                    region: None,
                })?;
                vdb_region = Some((lo, grid.dims));
                Density::Grid(grid)
            }
        };
        let emission = self.emission(at, m, &density, vdb_region, albedo, base_dir, opts)?;
        Ok(Medium { bounds_min, bounds_max, sigma_t, albedo, g: m.g, density, emission })
    }

    /// A medium's emission (`emission`, `emission_scale`, `temperature` and its mapping), every
    /// value checked; `density` and `vdb_region` (its OpenVDB box) are the medium's, whose grid
    /// an emission grid must match voxel for voxel.
    #[allow(clippy::too_many_arguments)]
    fn emission(
        &self,
        at: &str,
        m: &RawMedium,
        density: &Density,
        vdb_region: Option<([i64; 3], [u32; 3])>,
        albedo: Vec3,
        base_dir: &Path,
        opts: &LoadOptions,
    ) -> Result<Emission, SceneError> {
        let key = |name: &str| format!("{at}.{name}");
        for (name, given) in [
            ("temperature_scale", m.temperature_scale.is_some()),
            ("temperature_offset", m.temperature_offset.is_some()),
            ("temperature_cutoff", m.temperature_cutoff.is_some()),
        ] {
            if given && m.temperature.is_none() {
                return Err(self.invalid(
                    &key(name),
                    format!("{name} maps a temperature grid to kelvin, and {at} has no temperature; add temperature = {{ kind = \"grid\" | \"vdb\", ... }} or remove {name}"),
                ));
            }
        }
        if m.emission_scale.is_some() && m.emission.is_none() && m.temperature.is_none() {
            return Err(self.invalid(
                &key("emission_scale"),
                format!("scales an emission or a temperature, and {at} has neither; add emission = ... or remove emission_scale"),
            ));
        }
        let scale = match m.emission_scale {
            Some(rgb) => self.rgb_non_negative(&key("emission_scale"), rgb, "an emission scale")?,
            None => Vec3::ONE,
        };
        let emission = match (&m.emission, &m.temperature) {
            (None, None) => return Ok(Emission::None),
            (Some(_), Some(_)) => {
                return Err(self.invalid(
                    &key("temperature"),
                    format!(
                    "{at} has both emission and temperature; give one: emission (radiance) or temperature (blackbody)"
                ),
                ))
            }
            (Some(toml::Value::Table(t)), None) => {
                let file: RawGridFile =
                    toml::Value::Table(t.clone()).try_into().map_err(|e| self.serde_error(&key("emission"), &e))?;
                let grid = self.aux_grid(&key("emission"), "emission", &file, density, vdb_region, base_dir, opts)?;
                Emission::Grid(EmissionGrid { planes: vec![grid], scale, temperature: None })
            }
            (Some(v), None) => {
                let rgb: Rgb = v.clone().try_into().map_err(|e| self.serde_error(&key("emission"), &e))?;
                let le = self.rgb_non_negative(&key("emission"), rgb, "emitted radiance")?;
                Emission::Constant(le * scale)
            }
            (None, Some(file)) => {
                let number = |name: &str, v: Option<f64>, default: f64, ok: fn(f64) -> bool, rule: &str| {
                    let v = v.unwrap_or(default);
                    if v.is_finite() && (v as f32).is_finite() && ok(v) {
                        Ok(v as f32)
                    } else {
                        Err(self.invalid(&key(name), format!("{name} = {} must be {rule}", num(v))))
                    }
                };
                let map = TemperatureMap {
                    scale: number("temperature_scale", m.temperature_scale, 1.0, |v| v > 0.0, "a finite number > 0")?,
                    offset: number("temperature_offset", m.temperature_offset, 0.0, |_| true, "a finite number")?,
                    cutoff: number(
                        "temperature_cutoff",
                        m.temperature_cutoff,
                        100.0,
                        |v| v >= 0.0,
                        "a finite number of kelvin >= 0",
                    )?,
                };
                let grid =
                    self.aux_grid(&key("temperature"), "temperature", file, density, vdb_region, base_dir, opts)?;
                // Three planes of f32 besides the temperature: the budget counts them.
                let needed = grid.data.len() as u64 * 4 * 3;
                if needed > opts.memory_budget_bytes {
                    return Err(SceneError::GridTooLarge {
                        file: self.file.to_path_buf(),
                        field: format!("{}.file", key("temperature")),
                        grid: grid.file.clone(),
                        dims: grid.dims.map(u64::from),
                        needed_bytes: needed,
                        budget_bytes: opts.memory_budget_bytes,
                    });
                }
                Emission::Grid(EmissionGrid { planes: blackbody_planes(&grid, &map), scale, temperature: Some(map) })
            }
        };
        if !emission.is_some() {
            return Ok(Emission::None);
        }
        if albedo.cmpge(Vec3::ONE).all() {
            return Err(self.invalid(
                &key("emission"),
                format!(
                    "{at} has albedo 1 in every channel: it absorbs nothing, so it emits nothing (the source is \
                        sigma_a Le); lower albedo, or remove the emission"
                ),
            ));
        }
        Ok(emission)
    }

    /// An emission or temperature grid (`key`, holding `what`) over the medium's bounds, of the
    /// density grid's voxels where the density is a grid.
    #[allow(clippy::too_many_arguments)]
    fn aux_grid(
        &self,
        key: &str,
        what: &'static str,
        file: &RawGridFile,
        density: &Density,
        vdb_region: Option<([i64; 3], [u32; 3])>,
        base_dir: &Path,
        opts: &LoadOptions,
    ) -> Result<Grid, SceneError> {
        let resolve = |f: &str| {
            let written = PathBuf::from(f);
            let resolved = if written.is_absolute() { written.clone() } else { base_dir.join(&written) };
            (written, resolved)
        };
        let grid = match file {
            RawGridFile::Grid { file, dims } => {
                let (written, resolved) = resolve(file);
                load_grid(&GridRequest {
                    scene_file: self.file,
                    file_as_written: &written,
                    resolved,
                    dims: *dims,
                    opts,
                    what,
                    key,
                })?
            }
            RawGridFile::Vdb { file, grid } => {
                let (written, resolved) = resolve(file);
                load_vdb(&VdbRequest {
                    scene_file: self.file,
                    resolved,
                    file_as_written: &written,
                    grid: grid.as_deref().unwrap_or(what),
                    opts,
                    what,
                    key,
                    // Over the density's box, voxel for voxel, when both come from OpenVDB.
                    region: vdb_region,
                })?
                .0
            }
        };
        if let Density::Grid(d) = density {
            if d.dims != grid.dims {
                let [a, b, c] = grid.dims;
                let [x, y, z] = d.dims;
                return Err(self.invalid(
                    key,
                    format!(
                        "the {what} grid {} is {a} x {b} x {c} voxels and the density grid {x} x {y} x {z}; a medium's \
                            grids share its voxels: resample one to the other's size",
                        grid.file.display()
                    ),
                ));
            }
        }
        Ok(grid)
    }

    // -------------------------------------------------------------------- sections

    fn render(&self, r: &RawRender) -> Result<RenderSettings, SceneError> {
        let size = |field: &str, v: i64| -> Result<u32, SceneError> {
            u32::try_from(v)
                .ok()
                .filter(|v| (1..=MAX_IMAGE_SIZE).contains(v))
                .ok_or_else(|| self.invalid(field, format!("{v} pixels is out of range; use 1 ..= {MAX_IMAGE_SIZE}")))
        };
        let width = size("render.width", r.width)?;
        let height = size("render.height", r.height)?;
        let seed = u64::try_from(r.seed)
            .map_err(|_| self.invalid("render.seed", format!("{} must be an integer >= 0", r.seed)))?;
        let spp = u32::try_from(r.spp).ok().filter(|&s| s >= 1).ok_or_else(|| {
            self.invalid("render.spp", format!("{} samples per pixel is out of range; use 1 ..= {}", r.spp, u32::MAX))
        })?;
        let first_sample = u32::try_from(r.first_sample)
            .ok()
            .filter(|&f| f as u64 + spp as u64 <= u32::MAX as u64)
            .ok_or_else(|| {
                self.invalid(
                    "render.first_sample",
                    format!(
                        "{} is out of range; sample indices first_sample .. first_sample + spp ({spp}) are 32-bit: \
                         use 0 ..= {}",
                        r.first_sample,
                        u32::MAX - spp
                    ),
                )
            })?;
        if !r.exposure.is_finite() || r.exposure.abs() > 64.0 {
            return Err(
                self.invalid("render.exposure", format!("{} stops is out of range; use -64 ..= 64", r.exposure))
            );
        }
        Ok(RenderSettings { width, height, seed, spp, first_sample, exposure: r.exposure as f32 })
    }

    fn camera(&self, c: &RawCamera) -> Result<Camera, SceneError> {
        // Both fov and extent may be present (so `--set camera.kind=...` can switch
        // projections); each is checked when present, and the kind's own one is required.
        if let Some(fov) = c.fov {
            if !(fov > 0.0 && fov < 180.0) {
                return Err(self
                    .invalid("camera.fov", format!("fov = {} degrees must lie strictly inside (0, 180)", num32(fov))));
            }
        }
        if let Some(extent) = c.extent {
            if !(extent.is_finite() && extent > 0.0) {
                return Err(self.invalid(
                    "camera.extent",
                    format!("extent = {} must be a finite width > 0 in scene units", num32(extent)),
                ));
            }
        }
        let kind = match (c.kind.as_str(), c.fov, c.extent) {
            ("perspective", Some(fov_deg), _) => CameraKind::Perspective { fov_deg },
            ("orthographic", _, Some(extent)) => CameraKind::Orthographic { extent },
            ("perspective", None, _) => return Err(SceneError::MissingKey {
                file: self.file.to_path_buf(),
                key: "camera.fov".into(),
                hint:
                    "a perspective camera needs fov = <full field of view along the image x axis, degrees in (0, 180)>"
                        .into(),
            }),
            ("orthographic", _, None) => return Err(SceneError::MissingKey {
                file: self.file.to_path_buf(),
                key: "camera.extent".into(),
                hint:
                    "an orthographic camera needs extent = <width of the view along the image x axis, scene units, > 0>"
                        .into(),
            }),
            (other, _, _) => {
                return Err(self.invalid(
                    "camera.kind",
                    format!("unknown kind `{other}`; expected \"perspective\" or \"orthographic\""),
                ))
            }
        };
        let origin = self.vec3("camera.origin", c.origin)?;
        let target = self.vec3("camera.target", c.target)?;
        let up = self.vec3("camera.up", c.up)?;
        let Some(forward) = (target - origin).try_normalize() else {
            return Err(self.invalid(
                "camera.target",
                format!(
                    "target {} equals camera.origin, so the camera has no view direction; move the target to the point the camera looks at",
                    fmt3(target)
                ),
            ));
        };
        let Some(up_n) = up.try_normalize() else {
            return Err(self.invalid(
                "camera.up",
                "up is zero-length; use the direction that should point up in the image, e.g. [0, 1, 0]",
            ));
        };
        if forward.cross(up_n).length() < 1e-4 {
            // Suggest the world axis least aligned with the view.
            let a = forward.abs();
            let suggestion = if a.y <= a.x && a.y <= a.z {
                "[0, 1, 0]"
            } else if a.z <= a.x {
                "[0, 0, 1]"
            } else {
                "[1, 0, 0]"
            };
            return Err(self.invalid(
                "camera.up",
                format!(
                    "up {} is parallel to the view direction {} (origin -> target); choose an up vector across the view, e.g. {suggestion}",
                    fmt3(up),
                    fmt3(forward)
                ),
            ));
        }
        Ok(Camera { kind, origin, target, up })
    }

    fn bounds(&self, field: &str, b: &[[f32; 3]; 2]) -> Result<(Vec3, Vec3), SceneError> {
        let min = self.vec3(&format!("{field}[0]"), b[0])?;
        let max = self.vec3(&format!("{field}[1]"), b[1])?;
        for (axis, name) in ["x", "y", "z"].iter().enumerate() {
            if min[axis] >= max[axis] {
                return Err(self.invalid(
                    field,
                    format!(
                        "min {} must be less than max {} on every axis, but on {name} {} >= {}; write bounds = [[min x, y, z], [max x, y, z]]",
                        fmt3(min), fmt3(max), num32(min[axis]), num32(max[axis])
                    ),
                ));
            }
        }
        Ok((min, max))
    }

    fn albedo(&self, field: &str, rgb: Rgb) -> Result<Vec3, SceneError> {
        for (c, &v) in rgb.0.iter().enumerate() {
            if !(0.0..=1.0).contains(&v) {
                return Err(self.invalid(
                    field,
                    format!(
                        "{} channel is {}, outside [0, 1]; albedo = sigma_s / sigma_t must lie in [0, 1]",
                        CHANNELS[c],
                        num(v)
                    ),
                ));
            }
        }
        Ok(Vec3::new(rgb.0[0] as f32, rgb.0[1] as f32, rgb.0[2] as f32))
    }

    fn lights(&self, raw: &[RawLight]) -> Result<Vec<Light>, SceneError> {
        raw.iter()
            .enumerate()
            .map(|(i, light)| {
                let f = |name: &str| format!("light[{i}].{name}");
                Ok(match *light {
                    RawLight::Point {
                        position,
                        intensity,
                    } => Light::Point {
                        position: self.vec3(&f("position"), position)?,
                        intensity: self.rgb_non_negative(&f("intensity"), intensity, "intensity")?,
                    },
                    RawLight::Directional {
                        direction,
                        irradiance,
                    } => {
                        let d = self.vec3(&f("direction"), direction)?;
                        let Some(direction) = d.try_normalize() else {
                            return Err(self.invalid(
                                &f("direction"),
                                format!(
                                    "direction {} is zero-length; give the direction the light travels, e.g. [0, -1, 0] for light from above",
                                    fmt3(d)
                                ),
                            ));
                        };
                        Light::Directional {
                            direction,
                            irradiance: self.rgb_non_negative(
                                &f("irradiance"),
                                irradiance,
                                "irradiance",
                            )?,
                        }
                    }
                    RawLight::Environment { radiance } => Light::Environment {
                        radiance: self.rgb_non_negative(&f("radiance"), radiance, "radiance")?,
                    },
                })
            })
            .collect()
    }

    /// Reject a camera whose view cannot contain any point of the bounds box: all eight
    /// corners outside one and the same side of the view volume (the box is convex, so this
    /// never rejects a camera that sees a part of it). A camera inside the box is fine.
    fn camera_sees_medium(
        &self,
        camera: &Camera,
        render: &RenderSettings,
        min: Vec3,
        max: Vec3,
    ) -> Result<(), SceneError> {
        let o = camera.origin;
        if o.cmpge(min).all() && o.cmple(max).all() {
            return Ok(());
        }
        let (right, up, forward) = camera.basis();
        let aspect = render.height as f32 / render.width as f32;
        let corners = (0..8).map(|i| {
            let c = Vec3::new(
                if i & 1 == 0 { min.x } else { max.x },
                if i & 2 == 0 { min.y } else { max.y },
                if i & 4 == 0 { min.z } else { max.z },
            ) - o;
            (c.dot(right), c.dot(up), c.dot(forward))
        });
        let corners: Vec<(f32, f32, f32)> = corners.collect();
        // Every corner outside the same half-space of the view volume?
        let all = |outside: &dyn Fn(f32, f32, f32) -> bool| corners.iter().all(|&(x, y, z)| outside(x, y, z));
        let hidden = match camera.kind {
            CameraKind::Perspective { fov_deg } => {
                let tx = (fov_deg.to_radians() * 0.5).tan();
                let ty = tx * aspect;
                all(&|_, _, z| z <= 0.0)
                    || all(&|x, _, z| x > tx * z)
                    || all(&|x, _, z| x < -tx * z)
                    || all(&|_, y, z| y > ty * z)
                    || all(&|_, y, z| y < -ty * z)
            }
            CameraKind::Orthographic { extent } => {
                let hx = extent * 0.5;
                let hy = hx * aspect;
                all(&|_, _, z| z < 0.0)
                    || all(&|x, _, _| x > hx)
                    || all(&|x, _, _| x < -hx)
                    || all(&|_, y, _| y > hy)
                    || all(&|_, y, _| y < -hy)
            }
        };
        if hidden {
            let centre = (min + max) * 0.5;
            return Err(self.invalid(
                "camera",
                format!(
                    "the camera (origin {}, target {}) sees no part of the medium bounds {}..{}; aim it at the medium, e.g. target = {} (the centre of the bounds), or widen the view",
                    fmt3(camera.origin), fmt3(camera.target), fmt3(min), fmt3(max), fmt3(centre)
                ),
            ));
        }
        Ok(())
    }

    // -------------------------------------------------------------------- value helpers

    fn vec3(&self, field: &str, v: [f32; 3]) -> Result<Vec3, SceneError> {
        let v = Vec3::from_array(v);
        if !v.is_finite() {
            return Err(self.invalid(field, format!("{} has a non-finite component; use finite numbers", fmt3(v))));
        }
        if v.abs().max_element() > COORDINATE_MAX {
            return Err(self.coordinate_too_large(field, v.abs().max_element()));
        }
        Ok(v)
    }

    fn coordinate_too_large(&self, field: &str, value: f32) -> SceneError {
        self.invalid(
            field,
            format!(
                "a component of {} is past +-{}: the solvers step through the scene in 32-bit floats, whose steps \
                 vanish against coordinates that large; express the scene in larger units",
                num32(value),
                num32(COORDINATE_MAX)
            ),
        )
    }

    /// Values within range one by one whose products would not be: every solver forms optical
    /// depths (sigma_t x density x length), sources (sigma_a x Le) and sums of them in 32-bit
    /// floats, which overflow past 3.4e38 (a density grid of 3e38 times sigma_t 10 gave NaN
    /// pixels in six solvers, set to 0 with exit 0; Le 1e30 times emission_scale 1e30 likewise).
    /// Each magnitude is held to [`MAGNITUDE_MAX`], so products of two or three stay finite.
    fn magnitudes(&self, scene: &Scene) -> Result<(), SceneError> {
        let (lo, hi) = (scene.medium.bounds_min, scene.medium.bounds_max);
        let farthest = lo.abs().max(hi.abs()).max_element();
        if farthest > COORDINATE_MAX {
            // (an object's mesh after its transform: each key was in range, their product not)
            return Err(self.coordinate_too_large("object (its meshes transformed)", farthest));
        }
        let materials = scene.object.as_ref().map_or(&[][..], |o| &o.materials[..]);
        let sigma =
            materials.iter().map(|m| m.sigma_t.max_element()).fold(scene.medium.sigma_t.max_element(), f32::max);
        let tau = sigma as f64 * scene.max_density() as f64 * (hi - lo).length() as f64;
        if tau.is_nan() || tau > MAGNITUDE_MAX {
            return Err(self.invalid(
                if scene.object.is_some() { "object.sigma_t" } else { "medium.sigma_t" },
                format!(
                    "sigma_t {} times the density's largest value {} across the medium ({} long) is an optical \
                     thickness of {}, past {}: the solvers' 32-bit optical depths and sums overflow; scale the \
                     density grid or sigma_t down",
                    num32(sigma),
                    num32(scene.max_density()),
                    num32((hi - lo).length()),
                    short(tau),
                    num(MAGNITUDE_MAX)
                ),
            ));
        }
        let le = match &scene.medium.emission {
            Emission::Grid(g) => g.max_le().max_element(),
            e => e.constant_part().max_element(),
        };
        let le = materials.iter().map(|m| m.emission.max_element()).fold(le, f32::max);
        if le.is_nan() || le as f64 > MAGNITUDE_MAX {
            return Err(self.invalid(
                "medium.emission",
                format!(
                    "the emitted radiance Le reaches {} W/(m^2 sr) (emission x emission_scale, or a temperature's \
                     blackbody), past {}: the solvers' 32-bit sources overflow; lower emission_scale or the grid",
                    num32(le),
                    num(MAGNITUDE_MAX)
                ),
            ));
        }
        for (i, l) in scene.lights.iter().enumerate() {
            let (key, v) = match l {
                Light::Point { intensity, .. } => ("intensity", intensity),
                Light::Directional { irradiance, .. } => ("irradiance", irradiance),
                Light::Environment { radiance } => ("radiance", radiance),
            };
            if v.is_nan() || v.max_element() as f64 > MAGNITUDE_MAX {
                return Err(self.invalid(
                    &format!("light[{i}].{key}"),
                    format!(
                        "{} is past {}: the solvers' 32-bit sums of light overflow; express the light in larger \
                         units (the image scales with it)",
                        num32(v.max_element()),
                        num(MAGNITUDE_MAX)
                    ),
                ));
            }
        }
        Ok(())
    }

    fn rgb_non_negative(&self, field: &str, rgb: Rgb, what: &str) -> Result<Vec3, SceneError> {
        for (c, &v) in rgb.0.iter().enumerate() {
            if !(v.is_finite() && (v as f32).is_finite()) || v < 0.0 {
                return Err(self
                    .invalid(field, format!("{} channel is {}; {what} must be finite and >= 0", CHANNELS[c], num(v))));
            }
        }
        Ok(Vec3::new(rgb.0[0] as f32, rgb.0[1] as f32, rgb.0[2] as f32))
    }

    // -------------------------------------------------------------------- errors

    fn invalid(&self, field: &str, message: impl Into<String>) -> SceneError {
        SceneError::Invalid { file: self.file.to_path_buf(), field: field.to_owned(), message: message.into() }
    }

    fn syntax_error(&self, e: &toml::de::Error) -> SceneError {
        let (line, column) = e.span().map(|span| line_col(self.text, span.start)).unwrap_or((1, 1));
        SceneError::Syntax { file: self.file.to_path_buf(), line, column, message: one_line(e.message()) }
    }

    /// Turn a serde error from a `toml::Value` into a scene error naming the field. `prefix`
    /// is the path of the value that was deserialised (`light[2]`), "" for the root.
    fn serde_error(&self, prefix: &str, e: &toml::de::Error) -> SceneError {
        let message = one_line(e.message());
        // toml appends "in `a.b`" (the keys it unwound through) to its Display, not to
        // message(); that is the only place the path is available.
        let display = e.to_string();
        let inner =
            display.lines().rev().find_map(|l| l.strip_prefix("in `").and_then(|r| r.strip_suffix('`'))).unwrap_or("");
        let path = join_path(prefix, inner);
        let file = self.file.to_path_buf();

        if let Some(rest) = message.strip_prefix("unknown field `") {
            let (name, tail) = rest.split_once('`').unwrap_or((rest, ""));
            let expected = tail.trim_start_matches(", ").to_owned();
            let candidates: Vec<&str> = expected.split('`').skip(1).step_by(2).collect();
            let expected = match did_you_mean(name, &candidates) {
                Some(best) => format!("did you mean `{best}`? {expected}"),
                None if expected == "there are no fields" => "this kind takes no other keys".to_owned(),
                None => expected,
            };
            return SceneError::UnknownKey {
                line: locate_key(self.text, &path, name),
                key: join_path(&path, name),
                expected,
                file,
            };
        }
        if let Some(rest) = message.strip_prefix("missing field `") {
            let name = rest.split('`').next().unwrap_or(rest);
            let key = join_path(&path, name);
            return SceneError::MissingKey { hint: missing_hint(&path, name), key, file };
        }
        if let Some(rest) = message.strip_prefix("unknown variant `") {
            let (name, tail) = rest.split_once('`').unwrap_or((rest, ""));
            return SceneError::Invalid {
                file,
                // The tag's own key is usually on the path already.
                field: if path == "kind" || path.ends_with(".kind") { path } else { join_path(&path, "kind") },
                message: format!("unknown kind `{name}`; {}", tail.trim_start_matches(", ")),
            };
        }
        // serde names Rust types; say what the file needs instead.
        let mut message = plain_types(&message)
            .replace("expected i64", "expected an integer")
            .replace("expected f32", "expected a number")
            .replace("expected a string", "expected a quoted string")
            .replace("expected a sequence", "expected an array");
        if path == "light" && message.contains("expected an array") {
            message.push_str("; write each light as a [[light]] table (double brackets)");
        }
        SceneError::Invalid { file, field: if path.is_empty() { "(top level)".into() } else { path }, message }
    }

    /// An error caused by a `--set` value should say so: unknown keys become override
    /// errors, and invalid values name the override they came from.
    fn attribute_to_override(&self, err: SceneError) -> SceneError {
        // The last override of a key is the one applied (`--set a=1 --set a=2` sets 2).
        let origin = |field: &str| {
            self.overrides.iter().rev().find(|(key, _)| {
                let key = normalise_key(key);
                related(&key, field)
            })
        };
        match err {
            SceneError::UnknownKey { file, key, line, expected } => match origin(&key) {
                Some((okey, _)) => SceneError::Override {
                    file,
                    key: okey.clone(),
                    message: format!("unknown key `{key}`; {expected}"),
                },
                None => SceneError::UnknownKey { file, key, line, expected },
            },
            SceneError::Invalid { file, field, message } => match origin(&field) {
                Some((okey, value)) => SceneError::Invalid {
                    file,
                    message: format!("{message} (value from override {okey}={})", one_line(value)),
                    field,
                },
                None => SceneError::Invalid { file, field, message },
            },
            other => other,
        }
    }
}

/// serde's "expected struct RawCamera" / "expected internally tagged enum RawLight" in the
/// words of the file: a table, and a table whose `kind` picks its form.
fn plain_types(message: &str) -> String {
    let mut out = message.to_owned();
    for (prefix, plain) in [
        ("internally tagged enum Raw", "a table with a `kind` key"),
        ("struct Raw", "a table"),
        ("enum Raw", "a table"),
    ] {
        while let Some(at) = out.find(prefix) {
            let rest = &out[at + prefix.len()..];
            let end = rest.find(|c: char| !c.is_ascii_alphanumeric()).unwrap_or(rest.len());
            out = format!("{}{plain}{}", &out[..at], &rest[end..]);
        }
    }
    out
}

const CHANNELS: [&str; 3] = ["red (0)", "green (1)", "blue (2)"];

/// `[1, 2.5, 3]`.
/// A magnitude in three significant figures (`num` gives every digit an f64 has).
fn short(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.2e}")
    } else {
        "inf".into()
    }
}

/// The largest coordinate a scene may use (any position, bound or translation), scene units.
pub(super) const COORDINATE_MAX: f32 = 1e9;

/// The largest optical thickness across the medium, emitted radiance and light value a scene
/// may have (`Ctx::magnitudes`): far past any physical scene (the sun's radiance is
/// 2e7 W/(m^2 sr)), far enough below f32's 3.4e38 that the solvers' products stay finite.
const MAGNITUDE_MAX: f64 = 1e15;

fn fmt3(v: Vec3) -> String {
    format!("[{}, {}, {}]", num32(v.x), num32(v.y), num32(v.z))
}

/// [`num`] for f32 (shortest digits of the f32, not of its f64 widening).
fn num32(v: f32) -> String {
    let a = v.abs();
    if v.is_finite() && a != 0.0 && !(1e-4..1e7).contains(&a) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

/// A number as a person would write it: `0.5`, `1e300` (not 301 digits), `NaN`, `inf`.
fn num(v: f64) -> String {
    let a = v.abs();
    if v.is_finite() && a != 0.0 && !(1e-4..1e7).contains(&a) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

fn join_path(a: &str, b: &str) -> String {
    match (a.is_empty(), b.is_empty()) {
        (true, _) => b.to_owned(),
        (_, true) => a.to_owned(),
        _ => format!("{a}.{b}"),
    }
}

/// True if one dotted path is the other or contains it (`medium.density` ~ `medium.density.radius`).
fn related(a: &str, b: &str) -> bool {
    let within = |long: &str, short: &str| {
        long == short
            || (long.starts_with(short) && matches!(long.as_bytes().get(short.len()), Some(b'.') | Some(b'[')))
    };
    within(a, b) || within(b, a)
}

fn missing_hint(section: &str, name: &str) -> String {
    if name == "kind" {
        return match section {
            "medium.density" => "add kind = \"constant\", \"sphere\" or \"grid\" to medium.density".into(),
            s if s.starts_with("light") => {
                format!("add kind = \"point\", \"directional\" or \"environment\" to {s}")
            }
            _ => format!("add kind = ... to {section}"),
        };
    }
    if section.is_empty() {
        let table = if name == "light" { "[[light]]" } else { name };
        return format!("add a [{table}] table (see docs/scene-format.md)");
    }
    let table = if section.contains(['.', '[']) { section.to_owned() } else { format!("[{section}]") };
    format!("add {name} = ... to {table} (see docs/scene-format.md)")
}

/// The closest candidate within edit distance 2 (optimal string alignment: a swap of two
/// neighbouring letters counts one), if any. Also names solver knobs (`solvers::knobs`).
pub fn did_you_mean<'a>(name: &str, candidates: &[&'a str]) -> Option<&'a str> {
    candidates
        .iter()
        .map(|c| (strsim::osa_distance(name, c), *c))
        .filter(|&(d, _)| d <= 2)
        .min_by_key(|&(d, _)| d)
        .map(|(_, c)| c)
}

/// 1-based line and column (in characters) of a byte offset.
fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let mut offset = offset.min(text.len());
    while !text.is_char_boundary(offset) {
        offset -= 1;
    }
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    (line, before[line_start..].chars().count() + 1)
}

/// Best-effort line of `key` inside the table at `section` (`medium`, `medium.density`,
/// `light[1]`, "" for the top level), found by scanning the text. `None` when not found
/// (e.g. the key came from an override).
fn locate_key(text: &str, section: &str, key: &str) -> Option<usize> {
    // Which `[header]` / `[[header]]` block to search, and which occurrence of it.
    let (top, index) = match section.split('.').next().unwrap_or("") {
        s if s.contains('[') => {
            let (name, rest) = s.split_once('[')?;
            (name, rest.trim_end_matches(']').parse::<usize>().ok())
        }
        s => (s, None),
    };
    let mut current: Option<String> = None; // header of the block a line is in
    let mut occurrence = 0usize;
    for (n, line) in text.lines().enumerate() {
        let trimmed = line.trim_start();
        if let Some(header) = trimmed.strip_prefix('[') {
            let is_array = header.starts_with('[');
            let name = header.trim_start_matches('[');
            let name = name.split(']').next().unwrap_or("").trim();
            if section.is_empty() && (name == key || name.starts_with(&format!("{key}."))) {
                return Some(n + 1);
            }
            let first = name.split('.').next().unwrap_or("").trim();
            if is_array && first == top && name == top {
                occurrence += 1;
            }
            current = Some(name.to_owned());
            continue;
        }
        let in_section = match (&current, index) {
            (None, _) => section.is_empty(),
            (Some(h), None) => !section.is_empty() && (h == top || h == section || h.starts_with(&format!("{top}."))),
            (Some(h), Some(i)) => h == top && occurrence == i + 1,
        };
        if in_section && contains_key_assignment(trimmed, key) {
            return Some(n + 1);
        }
    }
    None
}

/// `key = ...` at the start of the line or after `{`, `,` or whitespace (inline tables).
fn contains_key_assignment(line: &str, key: &str) -> bool {
    let line = line.split('#').next().unwrap_or("");
    line.match_indices(key).any(|(at, _)| {
        let before_ok = line[..at].chars().next_back().map_or(true, |c| c == '{' || c == ',' || c.is_whitespace());
        let after = line[at + key.len()..].trim_start();
        before_ok && after.starts_with('=')
    })
}

// ---------------------------------------------------------------------------------------
// Overrides
// ---------------------------------------------------------------------------------------

enum Segment {
    Key(String),
    Index(usize),
}

/// "there is 1 entry", "there are 3 entries".
fn count(len: usize) -> String {
    match len {
        1 => "there is 1 entry".into(),
        n => format!("there are {n} entries"),
    }
}

/// `light.0.intensity` and `light[0].intensity` -> `light[0].intensity` (the form errors use).
fn normalise_key(key: &str) -> String {
    match parse_key(key) {
        Ok(segments) => {
            let mut out = String::new();
            for s in segments {
                match s {
                    Segment::Key(k) => {
                        if !out.is_empty() {
                            out.push('.');
                        }
                        out.push_str(&k);
                    }
                    Segment::Index(i) => out.push_str(&format!("[{i}]")),
                }
            }
            out
        }
        Err(_) => key.to_owned(),
    }
}

fn parse_key(key: &str) -> Result<Vec<Segment>, String> {
    let mut segments = Vec::new();
    for part in key.trim().split('.') {
        let (name, mut rest) = match part.find('[') {
            Some(at) => (&part[..at], &part[at..]),
            None => (part, ""),
        };
        if name.is_empty() && rest.is_empty() {
            return Err("empty key segment; write a dotted path like medium.albedo".into());
        }
        if !name.is_empty() {
            match name.parse::<usize>() {
                Ok(i) if !segments.is_empty() => segments.push(Segment::Index(i)),
                _ => segments.push(Segment::Key(name.to_owned())),
            }
        }
        while let Some(r) = rest.strip_prefix('[') {
            let (index, after) = r.split_once(']').ok_or_else(|| format!("unclosed `[` in `{part}`"))?;
            let index = index.trim().parse::<usize>().map_err(|_| format!("`[{index}]` is not an array index"))?;
            segments.push(Segment::Index(index));
            rest = after;
        }
        if !rest.is_empty() {
            return Err(format!("unexpected `{rest}` in `{part}`"));
        }
    }
    Ok(segments)
}

/// The override value as TOML; a bare word (`orthographic`) is taken as a string.
fn parse_value(text: &str) -> Result<toml::Value, String> {
    let parsed = format!("v = {text}").parse::<toml::Table>();
    match parsed {
        Ok(mut table) if table.len() == 1 => {
            table.remove("v").ok_or_else(|| format!("`{}` is not a TOML value", one_line(text)))
        }
        Ok(_) => Err(format!("`{}` is not a single TOML value", one_line(text))),
        Err(e) => {
            let word = text.trim();
            let bare = !word.is_empty()
                && word.chars().next().is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
                && word.chars().all(|c| c.is_ascii_alphanumeric() || "-_./".contains(c));
            if bare {
                Ok(toml::Value::String(word.to_owned()))
            } else {
                Err(format!(
                    "`{}` is not a TOML value ({}); examples: 0.5, [1, 2, 3], \"orthographic\", {{ kind = \"constant\" }}",
                    one_line(text),
                    one_line(e.message())
                ))
            }
        }
    }
}

/// An array (`walked`, `len` entries) given the word `name` where its index goes, `rest` the
/// key's segments after it: `light.x.intensity` -> "e.g. light.0.intensity".
fn indexed_by_word(walked: &str, len: usize, name: &str, rest: &[Segment]) -> String {
    let example: String = rest
        .iter()
        .map(|s| match s {
            Segment::Key(k) => format!(".{k}"),
            Segment::Index(j) => format!(".{j}"),
        })
        .collect();
    format!(
        "`{walked}` is an array ({}), indexed by a number from 0, not `{name}`: e.g. {walked}.0{example}",
        count(len)
    )
}

/// Set `key` (dotted, with `[i]` or `.i` array indices) in the tree. Intermediate tables
/// must exist; the last key may be new (serde then rejects it if the format lacks it).
fn apply_override(root: &mut toml::Value, key: &str, value_text: &str) -> Result<(), String> {
    let segments = parse_key(key)?;
    let value = parse_value(value_text)?;
    let Some((last, parents)) = segments.split_last() else {
        return Err("empty key".into());
    };
    let mut current = root;
    let mut walked = String::new();
    for (i, segment) in parents.iter().enumerate() {
        current = match segment {
            Segment::Key(name) => {
                let here = join_path(&walked, name);
                let table = match current {
                    toml::Value::Table(t) => t,
                    // `light.x.intensity`: the segment after an array is its index.
                    toml::Value::Array(a) => return Err(indexed_by_word(&walked, a.len(), name, &segments[i + 1..])),
                    _ => return Err(format!("`{walked}` is not a table, so it has no key `{name}`")),
                };
                walked = here;
                table.get_mut(name).ok_or_else(|| {
                    if walked.contains('.') {
                        format!(
                            "`{walked}` is not in the scene; set the whole table instead, e.g. {walked}={{ kind = ..., ... }}"
                        )
                    } else {
                        format!(
                            "`{walked}` is not a section of the scene (render, camera, medium, object, light)"
                        )
                    }
                })?
            }
            Segment::Index(i) => {
                let array = current.as_array_mut().ok_or_else(|| format!("`{walked}` is not an array"))?;
                let len = array.len();
                walked = format!("{walked}[{i}]");
                array.get_mut(*i).ok_or_else(|| format!("`{walked}` does not exist ({})", count(len)))?
            }
        };
    }
    match last {
        Segment::Key(name) => {
            let table = match current {
                toml::Value::Table(t) => t,
                // `light.x=...`: an array's entries are set by index.
                toml::Value::Array(a) => return Err(indexed_by_word(&walked, a.len(), name, &[])),
                _ => return Err(format!("`{walked}` is not a table, so it has no key `{name}`")),
            };
            table.insert(name.clone(), value);
        }
        Segment::Index(i) => {
            let array = current.as_array_mut().ok_or_else(|| format!("`{walked}` is not an array"))?;
            let len = array.len();
            let slot = array.get_mut(*i).ok_or_else(|| format!("`{walked}[{i}]` does not exist ({})", count(len)))?;
            *slot = value;
        }
    }
    Ok(())
}

/// A temperature grid's blackbody radiance per channel at its voxel centres (linear sRGB,
/// physics::blackbody, times nothing: `emission_scale` is applied with the planes): T = (value -
/// offset) * scale kelvin, 0 at or below the cutoff. Voxels are converted, then interpolated:
/// where the temperature changes steeply within a voxel this differs from converting the
/// interpolated temperature (pbrt-v4), by the curvature of the blackbody over that step.
fn blackbody_planes(t: &Grid, map: &TemperatureMap) -> Vec<Grid> {
    use std::collections::HashMap;
    let mut planes: Vec<Grid> =
        (0..3).map(|_| Grid { dims: t.dims, data: Vec::with_capacity(t.data.len()), file: t.file.clone() }).collect();
    // Simulation grids repeat values (a background, quantised fields): each distinct value is
    // integrated once.
    let mut seen: HashMap<u32, Vec3> = HashMap::new();
    for &v in &t.data {
        let rgb = *seen.entry(v.to_bits()).or_insert_with(|| {
            let kelvin = (v as f64 - map.offset as f64) * map.scale as f64;
            if kelvin <= map.cutoff as f64 {
                Vec3::ZERO
            } else {
                crate::physics::blackbody::blackbody_rgb(kelvin)
            }
        });
        for (c, p) in planes.iter_mut().enumerate() {
            p.data.push(rgb[c]);
        }
    }
    planes
}
