//! Export a scene as the equivalent Mitsuba 3 scene (XML, plus a `.vol` grid beside it when
//! the medium is heterogeneous), so that any result can be checked with Mitsuba itself:
//! `mitsuba -m scalar_rgb OUT.xml` (or `mi.load_file` from Python) renders it.
//!
//! # Mapping (scene format v1 -> Mitsuba 3)
//!
//! References are to the Mitsuba 3 sources (`mitsuba-renderer/mitsuba3`), whose plugin
//! docstrings are the plugin reference; every element below was also loaded and rendered
//! with Mitsuba 3.9.1 (`scalar_rgb`) when this exporter was written.
//!
//! * **Integrator**: `volpath` with `max_depth = -1` ("-1 corresponds to infinity",
//!   `src/integrators/volpath.cpp`): unbounded depth, as `path` by default. Mitsuba's
//!   Russian roulette (`rr_depth` 5) is unbiased, as is ours. For chromatic media `volpath`
//!   is unbiased but its own doc recommends `volpathmis` for spectrally varying extinction
//!   (change the type to try it; both showed fireflies on our chromatic cloud).
//! * **Sampler**: `independent`, `sample_count = render.spp`, `seed = render.seed` (a seed
//!   above 2^32 - 1 is folded to 32 bits, with a warning). The random sequences differ from
//!   ours, of course: compare converged images, not noise.
//! * **Sensor**: the camera's `to_world` is `lookat(origin, target, up)`. Mitsuba's look-at
//!   frame is (left, up, forward) with camera-space +x mapped to the image's left edge, so
//!   it puts `cross(forward, up)` at the image's right exactly as [`Camera::basis`] does.
//!   - `perspective`: `fov` = our `fov`, `fov_axis = "x"`: both are the full angle across
//!     the image width (`src/sensors/perspective.cpp`).
//!   - `orthographic`: Mitsuba's camera-space film is the region `[-1, 1] x [-1/a, 1/a]`
//!     (a = width / height): `orthographic_projection()` in
//!     `include/mitsuba/render/sensor.h` maps camera x in [-1, 1] to the film's width and
//!     camera y in [-1/a, 1/a] to its height, so pixels stay square (the plugin doc says
//!     "by default the region [-1, 1]^2", true only for a square film). Our `extent` is the
//!     view's width, its height `extent / a` (square pixels), so `to_world` is
//!     `lookat * scale(extent / 2, extent / 2, 1)`: one uniform scale. Scaling y by the
//!     aspect as well would apply the aspect twice.
//!   - `near_clip`, `far_clip`: Mitsuba starts camera rays `near_clip` (default 0.01) in
//!     front of the camera, which skips that much medium when the camera is inside it (a
//!     3.5% bias measured on a pure absorber with sigma_t = 3); ours start at the origin. So
//!     `near_clip = 1e-6 L` and `far_clip = 10 L`, where L is the distance from the camera to
//!     the farthest corner of the bounds (the default far clip, 1e4, would cut a large
//!     scene's medium). The skipped optical depth, `1e-6 L sigma_t`, is negligible.
//!   - film `hdrfilm`: `width`, `height`, `pixel_format = "rgb"`,
//!     `component_format = "float32"` (the default is float16), `rfilter = "box"`: Mitsuba's
//!     box filter of radius 0.5 pixel averages the radiance over each pixel's area, which is
//!     our pixel definition (`src/rfilters/box.cpp`; the film's default is `gaussian`).
//! * **Medium** (`albedo`, `sigma_t` in 1/unit, `hg` phase with our `g`: Mitsuba's
//!   `g > 0` is forward scattering too, `src/phase/hg.cpp`). The medium is declared once with
//!   `id="medium"` and attached as the `interior` of a shape with a `null` BSDF: an
//!   index-matched boundary, as in our format (`src/bsdfs/null.cpp`; a shape without a
//!   BSDF would get a diffuse one). Grey values are written as `<float>`, chromatic ones as
//!   `<rgb>`.
//!   - constant density: `homogeneous` medium (`sigma_t`, `albedo`) inside a `cube` shape.
//!     Mitsuba's `cube` spans [-1, 1]^3 (`src/shapes/cube.cpp`), so its `to_world` is
//!     `translate(centre) * scale(half extents)` of the bounds.
//!   - sphere density, sphere entirely inside the bounds (faces may touch): `homogeneous`
//!     medium inside a `sphere` shape (`center`, `radius`) - exact.
//!   - sphere density clipped by the bounds: there is no intersection-of-shapes in Mitsuba,
//!     so the sphere is rasterised into a grid over the bounds, [`SPHERE_GRID_RES`] voxels
//!     along the longest side (the others in proportion, cubic voxels), each voxel holding
//!     the fraction of it inside the sphere (4^3 sub-samples where the surface crosses it),
//!     exported like a grid below. The surface is smoothed over about one voxel; the
//!     exporter returns a warning saying so ([`export_warnings`]).
//!   - grid density: `heterogeneous` medium inside the bounds `cube`; its `sigma_t` is a
//!     `gridvolume` read from `OUT.sigma_t.vol` next to the XML (Mitsuba's `.vol`: version 3,
//!     float32, x fastest, `src/volumes/grid.cpp`). A grey `sigma_t` writes the density
//!     grid itself (1 channel) with the medium's `scale = sigma_t`; a chromatic one writes
//!     `density * sigma_t` as 3 channels with `scale = 1`. Mitsuba's volumes span [0, 1]^3 in
//!     local space (`Volume::update_bbox` in `include/mitsuba/render/volume.h`) and ignore the
//!     file's bounding box unless `use_grid_bbox` is set, so the gridvolume's `to_world` is
//!     `translate(bounds min) * scale(bounds extent)`; the header's bbox is the bounds as
//!     well, for tools that read it. `filter_type = "trilinear"` and `wrap_mode = "clamp"`:
//!     Dr.Jit's texture puts sample i at the voxel centre (i + 0.5) / n and clamps between
//!     the outermost centres and the faces, which is our grid convention exactly.
//!   - A camera, or a point light, inside the medium's shape gets `<ref name="medium">` so
//!     that Mitsuba knows the medium its rays start in (needed for the camera).
//! * **Objects** (format v2): the mesh is written beside the XML as `OUT.mesh.obj` in scene
//!   coordinates and loaded by an `obj` shape (`face_normals`, identity `to_world`) that
//!   carries the medium as its `interior`; its BSDF is `null` at ior 1 and `dielectric`
//!   (`int_ior` = ior, `ext_ior` = 1: smooth, Fresnel reflection and refraction,
//!   `src/bsdfs/dielectric.cpp`) otherwise. A sphere density inside an object is rasterised
//!   like a clipped sphere (the mesh, not a sphere shape, bounds the medium).
//! * **Emitters**: `point` (`position`, `intensity` in W/sr), `directional` (`direction` =
//!   the direction the light travels, `irradiance` in W/m^2), `environment` -> `constant`
//!   (`radiance`). Values are always `<rgb>`. Render with an RGB variant (`scalar_rgb`,
//!   `llvm_ad_rgb`) for a like-for-like comparison: spectral variants upsample RGB values.
//!
//! The XML and the grid are written atomically ([`write_atomically`]) and together: if the
//! second file cannot be written the first is removed, so a failure leaves neither.

use std::fmt::Write as _;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use glam::Vec3;

use super::mesh::TriangleMesh;
use super::{is_grey, Camera, CameraKind, Density, Light, Medium, Object, Scene};
use crate::output::{write_atomically, OutputError};

/// Voxels along the longest side of the bounds when a clipped sphere is rasterised.
pub const SPHERE_GRID_RES: u32 = 128;

/// Sub-samples per axis for a voxel that the sphere's surface crosses.
const SPHERE_SUBSAMPLES: u32 = 4;

/// The `.vol` file written beside `xml_path` for a heterogeneous medium:
/// `dir/NAME.xml` -> `dir/NAME.sigma_t.vol`.
pub fn vol_path_for(xml_path: &Path) -> PathBuf {
    vol_path_for_material(xml_path, 0)
}

/// The extinction grid of material `k`'s medium (`OUT.sigma_t.vol` for 0, `OUT.sigma_t1.vol`, ...).
pub fn vol_path_for_material(xml_path: &Path, k: usize) -> PathBuf {
    let stem = xml_path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "scene".to_owned());
    xml_path.with_file_name(format!("{stem}.sigma_t{}.vol", material_suffix(k)))
}

/// What names material `k`'s files and medium: nothing for the first (and a v1 scene's), so
/// they are named as before materials existed; `k` after.
fn material_suffix(k: usize) -> String {
    if k == 0 {
        String::new()
    } else {
        k.to_string()
    }
}

/// Grid resolution used for a clipped sphere over `medium`'s bounds: [`SPHERE_GRID_RES`]
/// along the longest side, the others in proportion (at least 1).
pub fn sphere_grid_dims(medium: &Medium) -> [u32; 3] {
    let ext = medium.bounds_max - medium.bounds_min;
    let longest = ext.max_element();
    let n = |e: f32| ((SPHERE_GRID_RES as f32 * e / longest).round() as u32).clamp(1, SPHERE_GRID_RES);
    [n(ext.x), n(ext.y), n(ext.z)]
}

/// True if the sphere lies entirely inside the bounds (touching a face counts as inside).
pub fn sphere_fits(medium: &Medium, center: Vec3, radius: f32) -> bool {
    (center - radius).cmpge(medium.bounds_min).all() && (center + radius).cmple(medium.bounds_max).all()
}

/// Why `scene` cannot be exported, naming its field, or None: an emissive medium (Mitsuba 3
/// has no emissive media: its pull request for them has not been merged), which the export
/// would silently drop with all of its light.
pub fn export_refusal(scene: &Scene) -> Option<String> {
    if !scene.emissive() {
        return None;
    }
    let medium_field = |e: &super::Emission| match e {
        super::Emission::Grid(g) if g.temperature.is_some() => "temperature",
        _ => "emission",
    };
    let field = match &scene.object {
        None => format!("medium.{}", medium_field(&scene.medium.emission)),
        Some(o) => {
            let part = o
                .parts
                .iter()
                .position(|p| {
                    let x = &o.materials[p.material];
                    (x.sigma_a() * x.emission).max_element() > 0.0
                })
                .unwrap_or(0);
            format!("object[{part}].medium.{}", medium_field(&scene.medium.emission))
        }
    };
    Some(format!(
        "{field}: Mitsuba 3 has no emissive media, so the export would drop this medium's emission and all the light \
            it gives; cross-check emission against scatterlab's path, or export the scene without {field}"
    ))
}

/// What the export approximates or changes for `scene` (empty when it is exact): one line
/// each, for the CLI to print as warnings.
pub fn export_warnings(scene: &Scene) -> Vec<String> {
    let mut w = Vec::new();
    if let Density::Sphere { center, radius } = scene.medium.density {
        if !sphere_fits(&scene.medium, center, radius) {
            let [nx, ny, nz] = sphere_grid_dims(&scene.medium);
            w.push(format!(
                "the sphere density is clipped by the medium bounds, which Mitsuba cannot express with shapes; it is \
                    exported as a {nx}x{ny}x{nz} voxel grid of the sphere's coverage, so its surface is smoothed over \
                    about one voxel"
            ));
        }
    }
    if let Some(object) = scene.object.as_ref().filter(|o| o.refractive()) {
        for (i, light) in scene.lights.iter().enumerate() {
            if object.light_outside(light) {
                w.push(format!(
                    "light {i} ({}) lies outside the refractive object: Mitsuba 3's volpath reaches a delta light behind \
                        a smooth dielectric with probability 0, so its image lacks that light's contribution inside the \
                        object, where scatterlab's path follows it through the refracting facets (manifold next-event \
                        estimation); compare the two without it",
                    light.kind_name()
                ));
            }
        }
    }
    if scene.render.seed > u64::from(u32::MAX) {
        w.push(format!(
            "render.seed = {} does not fit Mitsuba's 32-bit seed; exported as {}",
            scene.render.seed,
            mitsuba_seed(scene.render.seed)
        ));
    }
    w
}

/// Write the Mitsuba 3 equivalent of `scene` to `xml_path` (and, for a grid or a clipped
/// sphere, `vol_path_for(xml_path)`). Returns the files written, the XML first. On error
/// nothing is left behind.
pub fn export_mitsuba(scene: &Scene, xml_path: &Path) -> Result<Vec<PathBuf>, OutputError> {
    if let Some(why) = export_refusal(scene) {
        return Err(OutputError::Unsupported { path: xml_path.to_path_buf(), message: why });
    }
    // The media: the scene's one, or one per material of its objects (each its coefficients
    // over its density field), each with its plan.
    let media: Vec<Medium> = match &scene.object {
        Some(o) => (0..o.materials.len()).map(|k| o.material_medium(k)).collect(),
        None => vec![scene.medium.clone()],
    };
    let plans: Vec<Plan> = media.iter().map(|m| plan_medium(m, scene.object.is_some())).collect();
    let name_of = |p: &PathBuf| p.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    // One OBJ per material of the objects (the parts that share it), material 0's first.
    let materials = scene.object.as_ref().map_or(1, |o| o.materials.len());
    let obj_paths: Vec<PathBuf> = (0..materials).map(|k| obj_path_for_material(xml_path, k)).collect();
    let obj_names: Vec<String> = obj_paths.iter().map(name_of).collect();
    // A grid's extinction, one volume per material (each bakes its own sigma_t where chromatic).
    let vol_paths: Vec<PathBuf> = (0..materials).map(|k| vol_path_for_material(xml_path, k)).collect();
    let vol_names: Vec<String> = vol_paths.iter().map(name_of).collect();
    let xml_name = xml_path.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let xml = scene_xml(scene, &media, &plans, &xml_name, &vol_names, &obj_names);

    let mut written = Vec::new();
    let cleanup = |written: &[PathBuf]| {
        for p in written {
            let _ = std::fs::remove_file(p);
        }
    };
    for ((plan, medium), vol_path) in plans.iter().zip(&media).zip(&vol_paths) {
        if let Plan::Grid(grid) = plan {
            if let Err(e) = write_atomically(vol_path, |tmp| write_vol_file(tmp, grid, medium)) {
                cleanup(&written);
                return Err(e);
            }
            written.push(vol_path.clone());
        }
    }
    if let Some(object) = &scene.object {
        for (k, obj_path) in obj_paths.iter().enumerate() {
            if let Err(e) = write_atomically(obj_path, |tmp| write_obj_file(tmp, object, k)) {
                cleanup(&written);
                return Err(e);
            }
            written.push(obj_path.clone());
        }
    }
    let result = write_atomically(xml_path, |tmp| {
        std::fs::write(tmp, xml.as_bytes()).map_err(|source| OutputError::Io {
            path: tmp.to_owned(),
            action: "write",
            source,
        })
    });
    if let Err(e) = result {
        cleanup(&written);
        return Err(e);
    }
    written.insert(0, xml_path.to_owned());
    Ok(written)
}

/// Mitsuba's sampler seed is 32-bit: fold a larger one.
fn mitsuba_seed(seed: u64) -> u32 {
    if seed <= u64::from(u32::MAX) {
        seed as u32
    } else {
        (seed ^ (seed >> 32)) as u32
    }
}

/// How the medium is expressed in Mitsuba.
enum Plan<'a> {
    /// `homogeneous` inside the bounds cube.
    Box,
    /// `homogeneous` inside a sphere shape.
    Sphere { center: Vec3, radius: f32 },
    /// `heterogeneous` with a gridvolume over the bounds cube.
    Grid(GridPlan<'a>),
}

struct GridPlan<'a> {
    dims: [u32; 3],
    /// Density, x fastest (borrowed from the scene's grid, or a rasterised sphere).
    density: std::borrow::Cow<'a, [f32]>,
}

/// The mesh written beside `xml_path` for a scene with an [[object]]: `OUT.mesh.obj`, in
/// scene coordinates (the object's transform applied), so its shape's `to_world` is the identity.
/// With objects of several materials this holds material 0's ([`obj_path_for_material`]).
pub fn obj_path_for(xml_path: &Path) -> PathBuf {
    obj_path_for_material(xml_path, 0)
}

/// The mesh of the objects of material `k` (`OUT.mesh.obj` for 0, `OUT.mesh1.obj`, ... after):
/// each material is a shape of its own with its own interior medium and index.
pub fn obj_path_for_material(xml_path: &Path, k: usize) -> PathBuf {
    let mut name = xml_path.file_stem().map(|s| s.to_os_string()).unwrap_or_default();
    name.push(format!(".mesh{}.obj", material_suffix(k)));
    xml_path.with_file_name(name)
}

/// The transformed meshes of the parts of material `k` as OBJ: positions and faces only.
/// Without normals Mitsuba's `obj` shape uses each face's geometric normal (`face_normals` is
/// set as well), as `path` does. Every position of the union is written (unused ones are
/// harmless), the faces of those parts only.
fn write_obj_file(path: &Path, object: &Object, k: usize) -> Result<(), OutputError> {
    let mesh: &TriangleMesh = &object.mesh;
    let mut text = String::with_capacity(mesh.positions.len() * 40 + mesh.triangles.len() * 24);
    let files: Vec<String> =
        object.parts.iter().filter(|p| p.material == k).map(|p| p.file.display().to_string()).collect();
    let _ = writeln!(text, "# {} exported by scatterlab in scene coordinates", files.join(" + "));
    for p in &mesh.positions {
        let _ = writeln!(text, "v {} {} {}", p.x, p.y, p.z);
    }
    let mut first = 0;
    for part in &object.parts {
        if part.material == k {
            for t in &mesh.triangles[first..first + part.triangles] {
                let _ = writeln!(text, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
            }
        }
        first += part.triangles;
    }
    std::fs::write(path, text.as_bytes()).map_err(|source| OutputError::Io {
        path: path.to_owned(),
        action: "write",
        source,
    })
}

/// How medium `m` is written (`in_object`: the mesh is its shape).
fn plan_medium(m: &Medium, in_object: bool) -> Plan<'_> {
    match &m.density {
        // In an object the mesh is the shape: a homogeneous medium needs no other.
        Density::Constant => Plan::Box,
        Density::Sphere { center, radius } if !in_object && sphere_fits(m, *center, *radius) => {
            Plan::Sphere { center: *center, radius: *radius }
        }
        Density::Sphere { center, radius } => {
            let dims = sphere_grid_dims(m);
            Plan::Grid(GridPlan { dims, density: rasterise_sphere(m, dims, *center, *radius).into() })
        }
        Density::Grid(g) => Plan::Grid(GridPlan { dims: g.dims, density: std::borrow::Cow::Borrowed(&g.data) }),
    }
}

/// Fraction of each voxel of a `dims` grid over the bounds that lies inside the sphere.
fn rasterise_sphere(m: &Medium, dims: [u32; 3], center: Vec3, radius: f32) -> Vec<f32> {
    let size = (m.bounds_max - m.bounds_min) / Vec3::new(dims[0] as f32, dims[1] as f32, dims[2] as f32);
    let half_diag = 0.5 * size.length();
    let r2 = radius * radius;
    let s = SPHERE_SUBSAMPLES;
    let mut out = Vec::with_capacity(dims.iter().map(|&d| d as usize).product());
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let lo = m.bounds_min + size * Vec3::new(i as f32, j as f32, k as f32);
                let d = (lo + 0.5 * size).distance(center);
                let v = if d + half_diag <= radius {
                    1.0
                } else if d - half_diag >= radius {
                    0.0
                } else {
                    let mut inside = 0u32;
                    for c in 0..s {
                        for b in 0..s {
                            for a in 0..s {
                                let f = (Vec3::new(a as f32, b as f32, c as f32) + 0.5) / s as f32;
                                if (lo + f * size).distance_squared(center) <= r2 {
                                    inside += 1;
                                }
                            }
                        }
                    }
                    inside as f32 / (s * s * s) as f32
                };
                out.push(v);
            }
        }
    }
    out
}

/// Write the `.vol` (version 3, float32): 1 channel of density for a grey `sigma_t`, 3
/// channels of `density * sigma_t` for a chromatic one. Streams, so a large grid is not
/// copied in memory.
fn write_vol_file(path: &Path, grid: &GridPlan, m: &Medium) -> Result<(), OutputError> {
    let io = |source| OutputError::Io { path: path.to_owned(), action: "write", source };
    let file = File::create(path).map_err(io)?;
    let mut w = BufWriter::with_capacity(1 << 16, file);
    let channels: i32 = if is_grey(m.sigma_t) { 1 } else { 3 };
    let mut header = Vec::with_capacity(48);
    header.extend_from_slice(b"VOL");
    header.push(3);
    for v in [1i32, grid.dims[0] as i32, grid.dims[1] as i32, grid.dims[2] as i32, channels] {
        header.extend_from_slice(&v.to_le_bytes());
    }
    for v in m.bounds_min.to_array().into_iter().chain(m.bounds_max.to_array()) {
        header.extend_from_slice(&v.to_le_bytes());
    }
    w.write_all(&header).map_err(io)?;
    if channels == 1 {
        for &d in grid.density.iter() {
            w.write_all(&d.to_le_bytes()).map_err(io)?;
        }
    } else {
        let s = m.sigma_t.to_array();
        for &d in grid.density.iter() {
            for c in s {
                w.write_all(&(d * c).to_le_bytes()).map_err(io)?;
            }
        }
    }
    w.flush().map_err(io)
}

// ----------------------------------------------------------------------------- XML

/// A number as Mitsuba's parser reads it back exactly (Rust's shortest round-trip form).
fn num(v: f32) -> String {
    format!("{v}")
}

fn vec3(v: Vec3) -> String {
    format!("{}, {}, {}", num(v.x), num(v.y), num(v.z))
}

/// Escape text for a double-quoted XML attribute.
fn attr(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for ch in s.chars() {
        match ch {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            c => out.push(c),
        }
    }
    out
}

/// Text safe inside an XML comment (no `--`).
fn comment(s: &str) -> String {
    s.replace("--", "- -")
}

/// `<float>` for a grey value, `<rgb>` otherwise.
fn spectrum(name: &str, v: Vec3) -> String {
    if is_grey(v) {
        format!(r#"<float name="{name}" value="{}"/>"#, num(v.x))
    } else {
        format!(r#"<rgb name="{name}" value="{}"/>"#, vec3(v))
    }
}

fn rgb(name: &str, v: Vec3) -> String {
    format!(r#"<rgb name="{name}" value="{}"/>"#, vec3(v))
}

/// True if `p` is inside the shape that carries the medium (strictly, for the sphere).
fn in_medium_shape(scene: &Scene, plan: &Plan, m: &Medium, p: Vec3) -> bool {
    if let Some(object) = &scene.object {
        return object.contains(p);
    }
    match plan {
        Plan::Sphere { center, radius } => p.distance_squared(*center) < radius * radius,
        Plan::Box | Plan::Grid(_) => m.strictly_inside(p),
    }
}

/// The id of material `k`'s medium: `medium` for the first (and a v1 scene's), `medium1`, ...
fn medium_id(k: usize) -> String {
    format!("medium{}", material_suffix(k))
}

/// The medium `id` a point inside the medium at `p` is in: its object's material's, or the one
/// medium of a v1 scene.
fn medium_at(scene: &Scene, p: Vec3) -> String {
    medium_id(scene.object.as_ref().and_then(|o| o.material_at(p)).unwrap_or(0))
}

fn scene_xml(
    scene: &Scene,
    media: &[Medium],
    plans: &[Plan],
    xml_name: &str,
    vol_names: &[String],
    obj_names: &[String],
) -> String {
    let m = &scene.medium;
    let plan = &plans[0];
    let mut x = String::new();
    let mut line = |indent: usize, s: &str| {
        let _ = writeln!(x, "{:indent$}{s}", "", indent = 4 * indent);
    };
    line(0, r#"<?xml version="1.0" encoding="utf-8"?>"#);
    line(
        0,
        &format!(
            "<!-- Mitsuba 3 scene exported by scatterlab {} from {}; render it with: mitsuba -m scalar_rgb {} -->",
            env!("CARGO_PKG_VERSION"),
            comment(&scene.source.display().to_string()),
            comment(xml_name)
        ),
    );
    line(0, r#"<scene version="3.0.0">"#);

    line(1, r#"<integrator type="volpath">"#);
    line(2, r#"<integer name="max_depth" value="-1"/>"#);
    line(1, "</integrator>");

    // The media, each declared once and referenced by its shape (and the camera or lights in
    // it): the scene's one medium, or one per material of its objects (the density shared, the
    // coefficients each material's).
    for (k, (m, plan)) in media.iter().zip(plans).enumerate() {
        let id = medium_id(k);
        let phase = |line: &mut dyn FnMut(usize, &str)| {
            line(2, r#"<phase type="hg">"#);
            line(3, &format!(r#"<float name="g" value="{}"/>"#, num(m.g)));
            line(2, "</phase>");
        };
        match plan {
            Plan::Box | Plan::Sphere { .. } => {
                line(1, &format!(r#"<medium type="homogeneous" id="{id}">"#));
                // Mitsuba reads an <rgb> as a reflectance, refused above 1 ("Invalid RGB
                // reflectance value", Mitsuba 3.9.1): a chromatic extinction is written as its
                // colour over its largest channel, times `scale`.
                let peak = m.sigma_t.max_element();
                if is_grey(m.sigma_t) || peak <= 0.0 {
                    line(2, &spectrum("sigma_t", m.sigma_t));
                } else {
                    line(2, &rgb("sigma_t", m.sigma_t / peak));
                    line(2, &format!(r#"<float name="scale" value="{}"/>"#, num(peak)));
                }
                line(2, &spectrum("albedo", m.albedo));
                phase(&mut line);
                line(1, "</medium>");
            }
            Plan::Grid(_) => {
                let extent = m.bounds_max - m.bounds_min;
                line(1, &format!(r#"<medium type="heterogeneous" id="{id}">"#));
                line(2, r#"<volume type="gridvolume" name="sigma_t">"#);
                line(3, &format!(r#"<string name="filename" value="{}"/>"#, attr(&vol_names[k])));
                line(3, r#"<string name="filter_type" value="trilinear"/>"#);
                line(3, r#"<string name="wrap_mode" value="clamp"/>"#);
                line(3, r#"<transform name="to_world">"#);
                line(4, &format!(r#"<scale x="{}" y="{}" z="{}"/>"#, num(extent.x), num(extent.y), num(extent.z)));
                line(
                    4,
                    &format!(
                        r#"<translate x="{}" y="{}" z="{}"/>"#,
                        num(m.bounds_min.x),
                        num(m.bounds_min.y),
                        num(m.bounds_min.z)
                    ),
                );
                line(3, "</transform>");
                line(2, "</volume>");
                let scale = if is_grey(m.sigma_t) { m.sigma_t.x } else { 1.0 };
                line(2, &format!(r#"<float name="scale" value="{}"/>"#, num(scale)));
                line(2, &spectrum("albedo", m.albedo));
                phase(&mut line);
                line(1, "</medium>");
            }
        }
    }

    if let Some(object) = &scene.object {
        // One shape per material: the parts that share it, their boundary and their medium.
        for (k, material) in object.materials.iter().enumerate() {
            line(1, r#"<shape type="obj">"#);
            line(2, &format!(r#"<string name="filename" value="{}"/>"#, attr(&obj_names[k])));
            line(2, r#"<boolean name="face_normals" value="true"/>"#);
            if material.ior != 1.0 {
                // A smooth dielectric boundary: Fresnel reflection and refraction (src/bsdfs/dielectric.cpp).
                line(2, r#"<bsdf type="dielectric">"#);
                line(3, &format!(r#"<float name="int_ior" value="{}"/>"#, num(material.ior)));
                line(3, r#"<float name="ext_ior" value="1"/>"#);
                line(2, "</bsdf>");
            } else {
                line(2, r#"<bsdf type="null"/>"#);
            }
            line(2, &format!(r#"<ref name="interior" id="{}"/>"#, medium_id(k)));
            line(1, "</shape>");
        }
    } else {
        match plan {
            Plan::Sphere { center, radius } => {
                line(1, r#"<shape type="sphere">"#);
                line(2, &format!(r#"<point name="center" value="{}"/>"#, vec3(*center)));
                line(2, &format!(r#"<float name="radius" value="{}"/>"#, num(*radius)));
            }
            Plan::Box | Plan::Grid(_) => {
                let half = 0.5 * (m.bounds_max - m.bounds_min);
                let centre = 0.5 * (m.bounds_max + m.bounds_min);
                line(1, r#"<shape type="cube">"#);
                line(2, r#"<transform name="to_world">"#);
                line(3, &format!(r#"<scale x="{}" y="{}" z="{}"/>"#, num(half.x), num(half.y), num(half.z)));
                line(3, &format!(r#"<translate x="{}" y="{}" z="{}"/>"#, num(centre.x), num(centre.y), num(centre.z)));
                line(2, "</transform>");
            }
        }
        line(2, r#"<bsdf type="null"/>"#);
        line(2, r#"<ref name="interior" id="medium"/>"#);
        line(1, "</shape>");
    }

    sensor_xml(scene, &scene.camera, in_medium_shape(scene, plan, m, scene.camera.origin), &mut line);

    for light in &scene.lights {
        match *light {
            Light::Point { position, intensity } => {
                line(1, r#"<emitter type="point">"#);
                line(2, &format!(r#"<point name="position" value="{}"/>"#, vec3(position)));
                line(2, &rgb("intensity", intensity));
                if in_medium_shape(scene, plan, m, position) {
                    line(2, &format!(r#"<ref name="medium" id="{}"/>"#, medium_at(scene, position)));
                }
            }
            Light::Directional { direction, irradiance } => {
                line(1, r#"<emitter type="directional">"#);
                line(2, &format!(r#"<vector name="direction" value="{}"/>"#, vec3(direction)));
                line(2, &rgb("irradiance", irradiance));
            }
            Light::Environment { radiance } => {
                line(1, r#"<emitter type="constant">"#);
                line(2, &rgb("radiance", radiance));
            }
        }
        line(1, "</emitter>");
    }
    line(0, "</scene>");
    x
}

/// `(near_clip, far_clip)` for the sensor: see the module doc.
pub fn clip_planes(scene: &Scene) -> (f32, f32) {
    let m = &scene.medium;
    let o = scene.camera.origin;
    let far_corner = Vec3::select((o - m.bounds_min).abs().cmpgt((o - m.bounds_max).abs()), m.bounds_min, m.bounds_max);
    let l = o.distance(far_corner);
    (1e-6 * l, 10.0 * l)
}

fn sensor_xml(scene: &Scene, cam: &Camera, inside: bool, line: &mut dyn FnMut(usize, &str)) {
    let lookat =
        format!(r#"<lookat origin="{}" target="{}" up="{}"/>"#, vec3(cam.origin), vec3(cam.target), vec3(cam.up));
    match cam.kind {
        CameraKind::Perspective { fov_deg } => {
            line(1, r#"<sensor type="perspective">"#);
            line(2, &format!(r#"<float name="fov" value="{}"/>"#, num(fov_deg)));
            line(2, r#"<string name="fov_axis" value="x"/>"#);
            line(2, r#"<transform name="to_world">"#);
            line(3, &lookat);
            line(2, "</transform>");
        }
        CameraKind::Orthographic { extent } => {
            // Camera space spans [-1, 1] across the film's width and [-1/a, 1/a] across its
            // height (see the module doc): one uniform scale by extent / 2.
            let s = num(0.5 * extent);
            line(1, r#"<sensor type="orthographic">"#);
            line(2, r#"<transform name="to_world">"#);
            line(3, &format!(r#"<scale x="{s}" y="{s}" z="1"/>"#));
            line(3, &lookat);
            line(2, "</transform>");
        }
    }
    let (near, far) = clip_planes(scene);
    line(2, &format!(r#"<float name="near_clip" value="{}"/>"#, num(near)));
    line(2, &format!(r#"<float name="far_clip" value="{}"/>"#, num(far)));
    if inside {
        line(2, r#"<ref name="medium" id="medium"/>"#);
    }
    line(2, r#"<sampler type="independent">"#);
    line(2 + 1, &format!(r#"<integer name="sample_count" value="{}"/>"#, scene.render.spp));
    line(2 + 1, &format!(r#"<integer name="seed" value="{}"/>"#, mitsuba_seed(scene.render.seed)));
    line(2, "</sampler>");
    line(2, r#"<film type="hdrfilm">"#);
    line(3, &format!(r#"<integer name="width" value="{}"/>"#, scene.render.width));
    line(3, &format!(r#"<integer name="height" value="{}"/>"#, scene.render.height));
    line(3, r#"<string name="pixel_format" value="rgb"/>"#);
    line(3, r#"<string name="component_format" value="float32"/>"#);
    line(3, r#"<rfilter type="box"/>"#);
    line(2, "</film>");
    line(1, "</sensor>");
}
