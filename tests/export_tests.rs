//! `scatterlab export --mitsuba`: the exported Mitsuba 3 XML parses and carries the scene's
//! values (a round trip of the mapping documented in `src/scene/mitsuba.rs`; no Mitsuba
//! needed), the `.vol` grid beside it reads back with the right size and values, and a
//! failed export leaves nothing behind.
//!
//! Numbers are written in Rust's shortest round-trip form, so every value is compared
//! exactly.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use glam::Vec3;
use roxmltree::{Document, Node};
use scatterlab::scene::mesh::{load_obj, MeshTransform};
use scatterlab::scene::mitsuba::export_mitsuba;
use scatterlab::scene::mitsuba::{
    export_warnings, obj_path_for, obj_path_for_material, sphere_fits, sphere_grid_dims, vol_path_for, SPHERE_GRID_RES,
};
use scatterlab::scene::{CameraKind, Density, Light, LoadOptions, Scene};

const BIN: &str = env!("CARGO_BIN_EXE_scatterlab");

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

fn load(rel: &str, sets: &[(&str, &str)]) -> Scene {
    let sets: Vec<(String, String)> = sets.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect();
    Scene::load(&repo(rel), &sets, &LoadOptions::default()).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

fn tempdir() -> tempfile::TempDir {
    tempfile::Builder::new().prefix("scatterlab-export-").tempdir().expect("temp dir")
}

/// Every entry under `dir`, relative, sorted (hidden temporary files included).
fn listing(dir: &Path) -> Vec<String> {
    let mut out: Vec<String> =
        fs::read_dir(dir).expect("read_dir").flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect();
    out.sort();
    out
}

// ----------------------------------------------------------------------------- XML access

fn parse_vec(s: &str) -> Vec3 {
    let v: Vec<f32> =
        s.split(',').map(|t| t.trim().parse().unwrap_or_else(|_| panic!("not a number list: {s:?}"))).collect();
    assert_eq!(v.len(), 3, "expected 3 numbers: {s:?}");
    Vec3::new(v[0], v[1], v[2])
}

fn attr<'a>(n: Node<'a, '_>, name: &str) -> &'a str {
    n.attribute(name).unwrap_or_else(|| panic!("<{}> lacks {name}=: {:?}", n.tag_name().name(), n))
}

fn num(n: Node, name: &str) -> f32 {
    attr(n, name).parse().unwrap_or_else(|_| panic!("{name} of <{}> is not a number", n.tag_name().name()))
}

fn elements<'a, 'i>(n: Node<'a, 'i>, tag: &str) -> Vec<Node<'a, 'i>> {
    n.children().filter(|c| c.is_element() && c.tag_name().name() == tag).collect()
}

#[track_caller]
fn only<'a, 'i>(n: Node<'a, 'i>, tag: &str) -> Node<'a, 'i> {
    let v = elements(n, tag);
    assert_eq!(v.len(), 1, "expected one <{tag}> in <{}>, found {}", n.tag_name().name(), v.len());
    v[0]
}

/// The child element with `name="..."`.
#[track_caller]
fn named<'a, 'i>(n: Node<'a, 'i>, name: &str) -> Node<'a, 'i> {
    let v: Vec<_> = n.children().filter(|c| c.is_element() && c.attribute("name") == Some(name)).collect();
    assert_eq!(v.len(), 1, "expected one child named {name:?} in <{}>, found {}", n.tag_name().name(), v.len());
    v[0]
}

#[track_caller]
fn value<'a>(n: Node<'a, '_>, tag: &str, name: &str) -> &'a str {
    let c = named(n, name);
    assert_eq!(c.tag_name().name(), tag, "{name} should be a <{tag}>");
    attr(c, "value")
}

/// A spectrum property: `<float>` for grey values, `<rgb>` for chromatic ones.
#[track_caller]
fn spectrum(n: Node, name: &str) -> Vec3 {
    let c = named(n, name);
    match c.tag_name().name() {
        "float" => Vec3::splat(num(c, "value")),
        "rgb" => parse_vec(attr(c, "value")),
        t => panic!("{name} is a <{t}>, expected <float> or <rgb>"),
    }
}

fn grey(v: Vec3) -> bool {
    v.x == v.y && v.y == v.z
}

/// The `<transform name="to_world">` operations in order: (tag, node).
fn to_world<'a, 'i>(n: Node<'a, 'i>) -> Vec<(String, Node<'a, 'i>)> {
    let t = named(n, "to_world");
    assert_eq!(t.tag_name().name(), "transform");
    t.children().filter(|c| c.is_element()).map(|c| (c.tag_name().name().to_string(), c)).collect()
}

fn xyz(n: Node) -> Vec3 {
    Vec3::new(num(n, "x"), num(n, "y"), num(n, "z"))
}

/// `scale` then `translate` (Mitsuba applies the operations in document order).
#[track_caller]
fn scale_translate(n: Node) -> (Vec3, Vec3) {
    let ops = to_world(n);
    let tags: Vec<&str> = ops.iter().map(|(t, _)| t.as_str()).collect();
    assert_eq!(tags, ["scale", "translate"]);
    (xyz(ops[0].1), xyz(ops[1].1))
}

// ----------------------------------------------------------------------------- .vol access

struct Vol {
    dims: [u32; 3],
    channels: u32,
    bbox: [f32; 6],
    data: Vec<f32>,
}

fn read_vol(path: &Path) -> Vol {
    let b = fs::read(path).unwrap_or_else(|e| panic!("read {}: {e}", path.display()));
    assert!(b.len() >= 48, "{} is shorter than a .vol header", path.display());
    assert_eq!(&b[..3], b"VOL");
    assert_eq!(b[3], 3, "version");
    let i = |o: usize| i32::from_le_bytes(b[o..o + 4].try_into().unwrap());
    let f = |o: usize| f32::from_le_bytes(b[o..o + 4].try_into().unwrap());
    assert_eq!(i(4), 1, "encoding float32");
    let dims = [i(8) as u32, i(12) as u32, i(16) as u32];
    let channels = i(20) as u32;
    let bbox = [f(24), f(28), f(32), f(36), f(40), f(44)];
    let n = dims.iter().map(|&d| d as usize).product::<usize>() * channels as usize;
    assert_eq!(b.len(), 48 + 4 * n, "{}: size does not match the header", path.display());
    let data = (0..n).map(|k| f(48 + 4 * k)).collect();
    Vol { dims, channels, bbox, data }
}

/// The density the exported medium should hold: the scene's grid, or nothing.
fn grid_density(scene: &Scene) -> Option<([u32; 3], Vec<f32>)> {
    match &scene.medium.density {
        Density::Grid(g) => Some((g.dims, g.data.clone())),
        _ => None,
    }
}

// ----------------------------------------------------------------------------- the check

/// Export `scene` into a fresh folder and check that the XML carries every value of the
/// scene. Returns the folder, the XML path and the files written.
fn export_and_check(scene: &Scene) -> (tempfile::TempDir, PathBuf, Vec<PathBuf>) {
    let dir = tempdir();
    let xml_path = dir.path().join("scene.xml");
    let files =
        export_mitsuba(scene, &xml_path).unwrap_or_else(|e| panic!("export of {}: {e}", scene.source.display()));
    assert_eq!(files[0], xml_path, "the XML is listed first");
    let text = fs::read_to_string(&xml_path).expect("read XML");
    let doc = Document::parse(&text).unwrap_or_else(|e| panic!("exported XML does not parse: {e}\n{text}"));
    check_xml(scene, &doc, dir.path(), &files);
    // Nothing else in the folder: no temporary files, no stray outputs.
    let mut expected: Vec<String> =
        files.iter().map(|p| p.file_name().unwrap().to_string_lossy().into_owned()).collect();
    expected.sort();
    assert_eq!(listing(dir.path()), expected);
    (dir, xml_path, files)
}

fn check_xml(scene: &Scene, doc: &Document, dir: &Path, files: &[PathBuf]) {
    let root = doc.root_element();
    assert_eq!(root.tag_name().name(), "scene");
    assert_eq!(attr(root, "version"), "3.0.0");

    // Integrator: volpath, unbounded depth.
    let integ = only(root, "integrator");
    assert_eq!(attr(integ, "type"), "volpath");
    assert_eq!(value(integ, "integer", "max_depth"), "-1");

    // Sensor.
    let cam = &scene.camera;
    let sensor = only(root, "sensor");
    let ops = to_world(sensor);
    let lookat = ops.last().expect("to_world is empty").1;
    assert_eq!(lookat.tag_name().name(), "lookat", "lookat is the last operation of the sensor's to_world");
    assert_eq!(parse_vec(attr(lookat, "origin")), cam.origin);
    assert_eq!(parse_vec(attr(lookat, "target")), cam.target);
    assert_eq!(parse_vec(attr(lookat, "up")), cam.up);
    match cam.kind {
        CameraKind::Perspective { fov_deg } => {
            assert_eq!(attr(sensor, "type"), "perspective");
            assert_eq!(value(sensor, "float", "fov").parse::<f32>().unwrap(), fov_deg);
            assert_eq!(value(sensor, "string", "fov_axis"), "x");
            assert_eq!(ops.len(), 1, "perspective to_world is the lookat alone");
        }
        CameraKind::Orthographic { extent } => {
            assert_eq!(attr(sensor, "type"), "orthographic");
            assert_eq!(ops.len(), 2, "orthographic to_world is scale then lookat");
            assert_eq!(ops[0].0, "scale");
            assert_eq!(xyz(ops[0].1), Vec3::new(0.5 * extent, 0.5 * extent, 1.0));
        }
    }
    // Clip planes: camera rays start (almost) at the camera, and reach past the medium.
    let near = value(sensor, "float", "near_clip").parse::<f32>().unwrap();
    let far = value(sensor, "float", "far_clip").parse::<f32>().unwrap();
    let m = &scene.medium;
    let corners =
        (0..8).map(|i| Vec3::select(glam::BVec3::new(i & 1 != 0, i & 2 != 0, i & 4 != 0), m.bounds_max, m.bounds_min));
    let farthest = corners.map(|c| c.distance(cam.origin)).fold(0.0f32, f32::max);
    assert!(
        near > 0.0 && near * m.sigma_t.max_element() < 1e-3,
        "near_clip {near} skips optical depth {}",
        near * m.sigma_t.max_element()
    );
    assert!(near <= 1e-5 * farthest, "near_clip {near} is not negligible against the scene size {farthest}");
    assert!(far >= farthest * (1.0 + 1e-6), "far_clip {far} cuts the medium (farthest corner at {farthest})");
    let sampler = only(sensor, "sampler");
    assert_eq!(attr(sampler, "type"), "independent");
    assert_eq!(value(sampler, "integer", "sample_count"), scene.render.spp.to_string());
    assert_eq!(value(sampler, "integer", "seed"), scene.render.seed.to_string());
    let film = only(sensor, "film");
    assert_eq!(attr(film, "type"), "hdrfilm");
    assert_eq!(value(film, "integer", "width"), scene.render.width.to_string());
    assert_eq!(value(film, "integer", "height"), scene.render.height.to_string());
    assert_eq!(value(film, "string", "pixel_format"), "rgb");
    assert_eq!(value(film, "string", "component_format"), "float32");
    assert_eq!(attr(only(film, "rfilter"), "type"), "box");

    // Objects of several materials: a medium and a shape per material.
    if let Some(o) = scene.object.as_ref().filter(|o| o.several_materials()) {
        check_materials_xml(o, root, dir, files);
        return;
    }

    // Medium.
    let medium = only(root, "medium");
    assert_eq!(attr(medium, "id"), "medium");
    let phase = only(medium, "phase");
    assert_eq!(attr(phase, "type"), "hg");
    assert_eq!(value(phase, "float", "g").parse::<f32>().unwrap(), m.g);
    assert_eq!(spectrum(medium, "albedo"), m.albedo);
    assert_eq!(named(medium, "albedo").tag_name().name(), if grey(m.albedo) { "float" } else { "rgb" });

    let shape = only(root, "shape");
    let bsdf = only(shape, "bsdf");
    match scene.object.as_ref().filter(|o| o.refractive()) {
        Some(o) => {
            assert_eq!(attr(bsdf, "type"), "dielectric", "a refractive object's boundary");
            assert_eq!(value(bsdf, "float", "int_ior").parse::<f32>().unwrap(), o.ior);
            assert_eq!(value(bsdf, "float", "ext_ior"), "1");
        }
        None => assert_eq!(attr(bsdf, "type"), "null", "index-matched boundary"),
    }
    // An object's mesh is written beside the XML in scene coordinates and reads back the same.
    let obj_path = obj_path_for(&files[0]);
    let files: Vec<PathBuf> = match &scene.object {
        Some(o) => {
            assert_eq!(attr(shape, "type"), "obj");
            assert_eq!(dir.join(value(shape, "string", "filename")), obj_path, "the mesh beside the XML");
            assert_eq!(value(shape, "boolean", "face_normals"), "true");
            assert!(files.contains(&obj_path), "{files:?}");
            let back = load_obj(&obj_path, &MeshTransform::identity()).expect("the exported mesh loads");
            assert_eq!(back.triangles, o.mesh.triangles);
            assert_eq!(back.positions, o.mesh.positions, "positions written exactly");
            files.iter().filter(|f| **f != obj_path).cloned().collect()
        }
        None => {
            assert!(!obj_path.exists());
            files.to_vec()
        }
    };
    let files = &files[..];
    let interior = named(shape, "interior");
    assert_eq!(interior.tag_name().name(), "ref");
    assert_eq!(attr(interior, "id"), "medium");
    let check_bounds_cube = || {
        if scene.object.is_some() {
            return; // the mesh is the shape
        }
        assert_eq!(attr(shape, "type"), "cube");
        let (scale, translate) = scale_translate(shape);
        assert_eq!(scale, 0.5 * (m.bounds_max - m.bounds_min), "cube [-1, 1]^3 scaled to half the bounds");
        assert_eq!(translate, 0.5 * (m.bounds_max + m.bounds_min), "cube centred on the bounds");
    };
    let sphere_fits_bounds = match m.density {
        Density::Sphere { center, radius } => scene.object.is_none() && sphere_fits(m, center, radius),
        _ => false,
    };
    let vol_path = vol_path_for(&files[0]);
    match &m.density {
        Density::Constant => {
            assert_eq!(attr(medium, "type"), "homogeneous");
            assert_homogeneous_sigma_t(medium, m.sigma_t);
            check_bounds_cube();
            assert_eq!(files.len(), 1, "a homogeneous medium writes the XML only");
        }
        Density::Sphere { center, radius } if sphere_fits_bounds => {
            assert_eq!(attr(medium, "type"), "homogeneous");
            assert_homogeneous_sigma_t(medium, m.sigma_t);
            assert_eq!(attr(shape, "type"), "sphere");
            assert_eq!(parse_vec(value(shape, "point", "center")), *center);
            assert_eq!(value(shape, "float", "radius").parse::<f32>().unwrap(), *radius);
            assert_eq!(files.len(), 1);
        }
        Density::Sphere { .. } | Density::Grid(_) => {
            assert_eq!(attr(medium, "type"), "heterogeneous");
            check_bounds_cube();
            let vol = named(medium, "sigma_t");
            assert_eq!(vol.tag_name().name(), "volume");
            assert_eq!(attr(vol, "type"), "gridvolume");
            let file = value(vol, "string", "filename");
            assert_eq!(dir.join(file), vol_path, "the grid is named relative to the XML, beside it");
            assert_eq!(files, [files[0].clone(), vol_path.clone()]);
            assert_eq!(value(vol, "string", "filter_type"), "trilinear");
            assert_eq!(value(vol, "string", "wrap_mode"), "clamp");
            let (scale, translate) = scale_translate(vol);
            assert_eq!(scale, m.bounds_max - m.bounds_min, "unit cube scaled to the bounds");
            assert_eq!(translate, m.bounds_min, "unit cube moved to the bounds' corner");
            let medium_scale = value(medium, "float", "scale").parse::<f32>().unwrap();
            let channels = if grey(m.sigma_t) {
                assert_eq!(medium_scale, m.sigma_t.x, "grey sigma_t is the medium's scale");
                1
            } else {
                assert_eq!(medium_scale, 1.0, "chromatic sigma_t lives in the grid");
                3
            };
            let v = read_vol(&vol_path);
            assert_eq!(v.channels, channels);
            assert_eq!(
                v.bbox,
                [m.bounds_min.x, m.bounds_min.y, m.bounds_min.z, m.bounds_max.x, m.bounds_max.y, m.bounds_max.z]
            );
            // The scene's grid, voxel for voxel; a clipped sphere's coverage is checked by
            // `sphere_clipped_by_bounds_is_rasterised`.
            match grid_density(scene) {
                None => assert_eq!(v.dims, sphere_grid_dims(m)),
                Some((dims, density)) => {
                    assert_eq!(v.dims, dims);
                    let s = m.sigma_t.to_array();
                    for (i, d) in density.iter().enumerate() {
                        if channels == 1 {
                            assert_eq!(v.data[i], *d, "voxel {i}");
                        } else {
                            for (c, sc) in s.iter().enumerate() {
                                assert_eq!(v.data[3 * i + c], d * sc, "voxel {i} channel {c}: density x sigma_t");
                            }
                        }
                    }
                }
            }
        }
    }
    assert!(!vol_path.exists() || files.len() == 2, "a grid file exists but was not reported");

    // A camera inside the medium's shape must say so (Mitsuba needs its starting medium).
    let cam_refs = elements(sensor, "ref");
    let cam_inside = match m.density {
        Density::Sphere { center, radius } if sphere_fits_bounds => {
            cam.origin.distance_squared(center) < radius * radius
        }
        _ => m.strictly_inside(cam.origin),
    };
    assert_eq!(cam_refs.len(), usize::from(cam_inside), "sensor medium reference");
    if cam_inside {
        assert_eq!(attr(cam_refs[0], "id"), "medium");
    }

    // Emitters: one per light, in order, with the scene's values.
    let emitters = elements(root, "emitter");
    assert_eq!(emitters.len(), scene.lights.len());
    for (e, light) in emitters.iter().zip(&scene.lights) {
        match *light {
            Light::Point { position, intensity } => {
                assert_eq!(attr(*e, "type"), "point");
                assert_eq!(parse_vec(value(*e, "point", "position")), position);
                assert_eq!(parse_vec(value(*e, "rgb", "intensity")), intensity);
            }
            Light::Directional { direction, irradiance } => {
                assert_eq!(attr(*e, "type"), "directional");
                assert_eq!(parse_vec(value(*e, "vector", "direction")), direction, "the direction the light travels");
                assert_eq!(parse_vec(value(*e, "rgb", "irradiance")), irradiance);
            }
            Light::Environment { radiance } => {
                assert_eq!(attr(*e, "type"), "constant");
                assert_eq!(parse_vec(value(*e, "rgb", "radiance")), radiance);
            }
        }
    }
}

// ----------------------------------------------------------------------------- tests

/// A homogeneous medium's extinction: a grey one as a float; a chromatic one as an <rgb> of at
/// most 1 (Mitsuba refuses an <rgb> above 1, reading it as a reflectance) times `scale`.
fn assert_homogeneous_sigma_t(medium: Node, sigma_t: Vec3) {
    if grey(sigma_t) {
        assert_eq!(named(medium, "sigma_t").tag_name().name(), "float");
        assert_eq!(spectrum(medium, "sigma_t"), sigma_t);
        return;
    }
    let colour = spectrum(medium, "sigma_t");
    assert!(colour.max_element() <= 1.0, "an <rgb> of at most 1: {colour}");
    let scale = value(medium, "float", "scale").parse::<f32>().unwrap();
    assert!((colour * scale - sigma_t).abs().max_element() <= 1e-6 * sigma_t.max_element(), "{colour} x {scale}");
}

/// A scene whose objects have several materials (constant density): medium k holds material
/// k's coefficients, shape k its parts' faces (OUT.mesh.obj, OUT.mesh1.obj, ...), its index
/// and medium k inside.
fn check_materials_xml(o: &scatterlab::scene::Object, root: Node, dir: &Path, files: &[PathBuf]) {
    let media = elements(root, "medium");
    let shapes = elements(root, "shape");
    assert_eq!((media.len(), shapes.len()), (o.materials.len(), o.materials.len()));
    let mut expected = vec![files[0].clone()];
    for (k, (x, (medium, shape))) in o.materials.iter().zip(media.iter().zip(&shapes)).enumerate() {
        let id = if k == 0 { "medium".to_string() } else { format!("medium{k}") };
        assert_eq!(attr(*medium, "id"), id);
        assert_eq!(attr(*medium, "type"), "homogeneous");
        assert_homogeneous_sigma_t(*medium, x.sigma_t);
        assert_eq!(spectrum(*medium, "albedo"), x.albedo);
        assert_eq!(value(only(*medium, "phase"), "float", "g").parse::<f32>().unwrap(), x.g);
        assert_eq!(attr(named(*shape, "interior"), "id"), id);
        let bsdf = only(*shape, "bsdf");
        if x.ior != 1.0 {
            assert_eq!(attr(bsdf, "type"), "dielectric");
            assert_eq!(value(bsdf, "float", "int_ior").parse::<f32>().unwrap(), x.ior);
        } else {
            assert_eq!(attr(bsdf, "type"), "null");
        }
        let obj = obj_path_for_material(&files[0], k);
        assert_eq!(dir.join(value(*shape, "string", "filename")), obj);
        let back = load_obj(&obj, &MeshTransform::identity()).expect("the exported mesh loads");
        let faces: usize = o.parts.iter().filter(|p| p.material == k).map(|p| p.triangles).sum();
        assert_eq!(back.triangles.len(), faces, "material {k}'s parts");
        expected.push(obj);
    }
    assert_eq!(files, &expected[..]);
}

#[test]
fn every_shipped_scene_round_trips() {
    let mut names: Vec<PathBuf> = fs::read_dir(repo("scenes"))
        .expect("scenes/")
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    names.sort();
    assert!(names.len() >= 6, "expected the shipped scenes, found {names:?}");
    for p in names {
        let rel = format!("scenes/{}", p.file_name().unwrap().to_string_lossy());
        let scene = load(&rel, &[]);
        // Mitsuba 3 has no emissive media: those scenes are refused, naming the field.
        if scene.emissive() {
            let why = scatterlab::scene::mitsuba::export_refusal(&scene).expect("an emissive scene is refused");
            assert!(
                why.contains("medium.temperature") && why.contains("Mitsuba 3 has no emissive media"),
                "{rel}: {why}"
            );
            let dir = tempfile::tempdir().unwrap();
            let xml = dir.path().join("x.xml");
            assert!(scatterlab::scene::mitsuba::export_mitsuba(&scene, &xml).is_err());
            assert!(fs::read_dir(dir.path()).unwrap().next().is_none(), "{rel}: a refused export wrote files");
            continue;
        }
        let (_dir, _xml, _files) = export_and_check(&scene);
        // milk-orb's lamp lies outside its glass, which Mitsuba cannot reach (the one warning).
        let warnings = export_warnings(&scene);
        if rel.ends_with("milk-orb.toml") {
            assert!(
                warnings.len() == 1 && warnings[0].contains("light 0") && warnings[0].contains("volpath"),
                "{warnings:?}"
            );
        } else {
            assert!(warnings.is_empty(), "{rel}: the shipped scenes export exactly");
        }
    }
}

#[test]
fn grid_reads_back_through_the_scene_loader() {
    let scene = load("scenes/cloud.toml", &[]);
    let (dir, _xml, files) = export_and_check(&scene);
    // Load the exported .vol as a density grid of the same bounds: it is the cloud's density.
    let text = format!(
        "[render]\nwidth = 8\nheight = 8\nseed = 1\nspp = 1\n\
         [camera]\nkind = \"perspective\"\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nup = [0.0, 1.0, 0.0]\nfov = 30.0\n\
         [medium]\nbounds = [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]\nsigma_t = 1.0\nalbedo = 0.5\ng = 0.0\n\
         density = {{ kind = \"grid\", file = \"{}\" }}\n\
         [[light]]\nkind = \"environment\"\nradiance = 1.0\n",
        files[1].file_name().unwrap().to_string_lossy()
    );
    let back =
        Scene::from_str(&text, "back.toml", dir.path(), &[], &LoadOptions::default()).expect("exported .vol loads");
    let (Density::Grid(a), Density::Grid(b)) = (&back.medium.density, &scene.medium.density) else {
        panic!("not grids")
    };
    assert_eq!(a.dims, b.dims);
    assert_eq!(a.data, b.data, "grey export writes the density; sigma_t is the medium's scale");
}

#[test]
fn chromatic_grid_writes_density_times_sigma_t() {
    let scene =
        load("scenes/cloud.toml", &[("medium.sigma_t", "[2.0, 6.0, 12.5]"), ("medium.albedo", "[0.9, 0.95, 0.99]")]);
    let (_dir, _xml, files) = export_and_check(&scene);
    let v = read_vol(&files[1]);
    assert_eq!((v.channels, v.dims), (3, [64, 64, 64]));
}

#[test]
fn chromatic_constant_medium_is_rgb() {
    let scene = load(
        "scenes/anisotropic-cube.toml",
        &[("medium.sigma_t", "[1.0, 3.0, 9.0]"), ("medium.albedo", "[0.5, 0.8, 1.0]")],
    );
    let (_dir, xml, _files) = export_and_check(&scene);
    let text = fs::read_to_string(xml).unwrap();
    // Mitsuba refuses an <rgb> above 1 here (a reflectance): the colour over its peak, times scale.
    assert!(text.contains(r#"<rgb name="sigma_t" value="0.11111111, 0.33333334, 1"/>"#), "{text}");
    assert!(text.contains(r#"<float name="scale" value="9"/>"#), "{text}");
}

#[test]
fn sphere_inside_bounds_is_an_exact_sphere_shape() {
    let scene = load("scenes/homogeneous-sphere.toml", &[]);
    let Density::Sphere { center, radius } = scene.medium.density else { panic!("sphere scene") };
    assert!(sphere_fits(&scene.medium, center, radius));
    export_and_check(&scene);
    // Touching the faces still fits.
    let touching = load("scenes/homogeneous-sphere.toml", &[("medium.density.radius", "0.5")]);
    assert!(export_warnings(&touching).is_empty());
    export_and_check(&touching);
}

#[test]
fn sphere_clipped_by_bounds_is_rasterised() {
    // Radius 0.7 in the box [-0.5, 0.5]^3: the sphere pokes out through all six faces in
    // caps of height 0.2 whose rims (radius 0.49) stay inside the faces, so the medium's
    // volume is the sphere's minus six caps: 4/3 pi r^3 - 6 pi h^2 (3r - h) / 3.
    let (r, h) = (0.7f64, 0.2f64);
    let exact = 4.0 / 3.0 * std::f64::consts::PI * r.powi(3) - 6.0 * std::f64::consts::PI * h * h * (3.0 * r - h) / 3.0;
    let scene = load("scenes/homogeneous-sphere.toml", &[("medium.density.radius", "0.7")]);
    let warnings = export_warnings(&scene);
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    assert!(warnings[0].contains("128x128x128 voxel grid"), "{}", warnings[0]);
    let (_dir, _xml, files) = export_and_check(&scene);
    let v = read_vol(&files[1]);
    assert_eq!(v.dims, [SPHERE_GRID_RES; 3]);
    assert_eq!(v.channels, 1);
    let n = SPHERE_GRID_RES as f32;
    let voxel = 1.0 / n;
    let half_diag = 0.5 * 3f32.sqrt() * voxel;
    let (mut sum, mut partial) = (0.0f64, 0usize);
    for (idx, &d) in v.data.iter().enumerate() {
        let (i, j, k) = (idx % 128, (idx / 128) % 128, idx / (128 * 128));
        let c = Vec3::new(i as f32 + 0.5, j as f32 + 0.5, k as f32 + 0.5) * voxel - 0.5;
        let dist = c.length();
        assert!((0.0..=1.0).contains(&d), "coverage {d} at voxel {idx}");
        if dist + half_diag <= 0.7 {
            assert_eq!(d, 1.0, "voxel {idx} lies inside the sphere");
        } else if dist - half_diag >= 0.7 {
            assert_eq!(d, 0.0, "voxel {idx} lies outside the sphere");
        } else {
            partial += 1;
        }
        sum += f64::from(d);
    }
    assert!(partial > 0);
    let volume = sum / f64::from(n).powi(3);
    assert!((volume - exact).abs() < 1e-3, "rasterised volume {volume} vs exact {exact}");

    // Non-cubic bounds: cubic voxels, 128 along the longest side.
    let slab = load(
        "scenes/thick-slab.toml",
        &[("medium.density", "{ kind = \"sphere\", center = [0.0, 0.0, 0.0], radius = 1.0 }")],
    );
    assert_eq!(sphere_grid_dims(&slab.medium), [128, 16, 128]);
    let (_dir, _xml, files) = export_and_check(&slab);
    assert_eq!(read_vol(&files[1]).dims, [128, 16, 128]);
}

#[test]
fn orthographic_camera_spans_extent_with_square_pixels() {
    let scene = load(
        "scenes/homogeneous-sphere.toml",
        &[
            ("camera.kind", "\"orthographic\""),
            ("camera.extent", "1.5"),
            ("render.width", "64"),
            ("render.height", "32"),
            ("camera.origin", "[0.3, 0.2, 4.0]"),
            ("camera.target", "[0.1, 0.0, 0.0]"),
        ],
    );
    let (_dir, xml, _files) = export_and_check(&scene);
    let text = fs::read_to_string(xml).unwrap();
    let doc = Document::parse(&text).unwrap();
    let ops = to_world(only(doc.root_element(), "sensor"));
    let s = xyz(ops[0].1);
    // Mitsuba (include/mitsuba/render/sensor.h, orthographic_projection): camera-space x in
    // [-1, 1] spans the film's width with +x at its left edge, y in [-1/a, 1/a] its height
    // (a = width / height), +y at the top. Its look_at frame is (left, up, forward) with
    // left = normalize(cross(up, forward)). Map the film's edges to world space.
    let cam = &scene.camera;
    let fwd = (cam.target - cam.origin).normalize();
    let left = cam.up.cross(fwd).normalize();
    let up = fwd.cross(left);
    let world = |x: f32, y: f32| cam.origin + s.x * x * left + s.y * y * up;
    let a = 64.0 / 32.0;
    let (right_edge, left_edge) = (world(-1.0, 0.0), world(1.0, 0.0));
    let (top, bottom) = (world(0.0, 1.0 / a), world(0.0, -1.0 / a));
    assert!((right_edge.distance(left_edge) - 1.5).abs() < 1e-5, "view width is the extent");
    assert!((top.distance(bottom) - 0.75).abs() < 1e-5, "view height is extent / aspect: square pixels");
    let (r, u, _) = cam.basis();
    assert!((right_edge - left_edge).normalize().dot(r) > 0.9999, "image +x is the camera's right");
    assert!((top - bottom).normalize().dot(u) > 0.9999, "image top is the camera's up");
}

#[test]
fn camera_and_point_light_inside_the_medium_reference_it() {
    let scene = load(
        "scenes/anisotropic-cube.toml",
        &[
            ("camera.origin", "[0.1, 0.2, 0.45]"),
            (
                "light",
                "[{ kind = \"point\", position = [0.0, 0.0, 0.0], intensity = [1.0, 2.0, 3.0] }, { kind = \
                \"point\", position = [2.0, 0.0, 0.0], intensity = 1.0 }]",
            ),
        ],
    );
    let (_dir, xml, _files) = export_and_check(&scene);
    let text = fs::read_to_string(xml).unwrap();
    let doc = Document::parse(&text).unwrap();
    let emitters = elements(doc.root_element(), "emitter");
    assert_eq!(attr(named(emitters[0], "medium"), "id"), "medium", "the light inside the cube");
    assert!(elements(emitters[1], "ref").is_empty(), "the light outside has no medium");
}

#[test]
fn large_seed_is_folded_with_a_warning() {
    let scene = load("scenes/thick-slab.toml", &[("render.seed", "8589934593")]);
    let w = export_warnings(&scene);
    assert_eq!(w.len(), 1, "{w:?}");
    assert!(w[0].contains("32-bit"), "{}", w[0]);
    let dir = tempdir();
    export_mitsuba(&scene, &dir.path().join("s.xml")).unwrap();
    let text = fs::read_to_string(dir.path().join("s.xml")).unwrap();
    let doc = Document::parse(&text).unwrap();
    let seed: u64 = value(only(only(doc.root_element(), "sensor"), "sampler"), "integer", "seed").parse().unwrap();
    assert!(seed <= u64::from(u32::MAX));
}

#[test]
fn missing_directory_writes_nothing() {
    let dir = tempdir();
    let scene = load("scenes/cloud.toml", &[]);
    let err = export_mitsuba(&scene, &dir.path().join("missing/out.xml")).expect_err("no such directory");
    let msg = err.to_string();
    assert!(!msg.contains('\n') && msg.contains("missing"), "{msg}");
    assert!(listing(dir.path()).is_empty(), "left behind: {:?}", listing(dir.path()));
}

#[test]
fn xml_failure_removes_the_grid_too() {
    // A directory where the XML should go: the grid is written first, then the XML's rename
    // fails, and the grid must go too (all files or none).
    let dir = tempdir();
    fs::create_dir(dir.path().join("out.xml")).unwrap();
    let scene = load("scenes/cloud.toml", &[]);
    export_mitsuba(&scene, &dir.path().join("out.xml")).expect_err("a directory is in the way");
    assert_eq!(listing(dir.path()), ["out.xml"]);
    assert!(listing(&dir.path().join("out.xml")).is_empty());
}

// ----------------------------------------------------------------------------- CLI

fn run(dir: &Path, args: &[&str]) -> Output {
    Command::new(BIN).args(args).current_dir(dir).env("NO_COLOR", "1").output().expect("run scatterlab")
}

#[track_caller]
fn one_error_line(out: &Output, needle: &str) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "expected exit 1; stderr:\n{stderr}");
    let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "expected one line on stderr:\n{stderr}");
    assert!(lines[0].starts_with("error: ") && lines[0].contains(needle), "{}", lines[0]);
}

#[test]
fn cli_exports_in_either_argument_order() {
    let dir = tempdir();
    let scene = repo("scenes/cloud.toml");
    let scene = scene.to_str().unwrap();
    // As in the issue: export --mitsuba SCENE OUT.xml.
    let out = run(dir.path(), &["export", "--mitsuba", scene, "a.xml"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("wrote a.xml") && stderr.contains("wrote a.sigma_t.vol"), "{stderr}");
    assert!(!stderr.contains("warning"), "{stderr}");
    // And with the flag before the output, plus overrides.
    let out = run(dir.path(), &["export", scene, "--mitsuba", "b.xml", "--set", "medium.albedo=0.5"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(listing(dir.path()), ["a.sigma_t.vol", "a.xml", "b.sigma_t.vol", "b.xml"]);
    let text = fs::read_to_string(dir.path().join("b.xml")).unwrap();
    assert!(text.contains(r#"<float name="albedo" value="0.5"/>"#), "{text}");
    let text = fs::read_to_string(dir.path().join("a.xml")).unwrap();
    check_xml(
        &load("scenes/cloud.toml", &[]),
        &Document::parse(&text).unwrap(),
        dir.path(),
        &[dir.path().join("a.xml"), dir.path().join("a.sigma_t.vol")],
    );
}

#[test]
fn cli_prints_the_approximation_warning() {
    let dir = tempdir();
    let scene = repo("scenes/homogeneous-sphere.toml");
    let out = run(
        dir.path(),
        &["export", "--mitsuba", scene.to_str().unwrap(), "s.xml", "--set", "medium.density.radius=0.7"],
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("warning: the sphere density is clipped"), "{stderr}");
}

#[test]
fn cli_failures_are_one_line_and_leave_nothing() {
    let dir = tempdir();
    let scene = repo("scenes/cloud.toml");
    let scene = scene.to_str().unwrap();
    one_error_line(&run(dir.path(), &["export", "--mitsuba", scene, "missing/out.xml"]), "does not exist");
    one_error_line(&run(dir.path(), &["export", scene, "out.xml"]), "--mitsuba");
    one_error_line(&run(dir.path(), &["export", "--mitsuba", scene, "out.txt"]), ".xml");
    one_error_line(
        &run(dir.path(), &["export", "--mitsuba", scene, "out.xml", "--set", "path.max_depth=1"]),
        "path.max_depth",
    );
    one_error_line(&run(dir.path(), &["export", "--mitsuba", scene, "out.xml", "--set", "medium.albedo=2"]), "albedo");
    assert!(listing(dir.path()).is_empty(), "left behind: {:?}", listing(dir.path()));
}
