//! Several `[[object]]` entries in one scene (issue 16, item 1): disjoint meshes that share one
//! medium and one index, joined into one closed mesh, so every solver that renders an object
//! renders several. Checked: the union's triangles, volume and inside; the refusals (meshes
//! that intersect or nest, entries of different materials or bounds, a camera inside any of
//! them, a point light inside one refractive object that the others would see only through
//! refraction); two entries render bit for bit as the one mesh that joins them (path, single,
//! lbl); the furnace with two glass objects; lbl against path on a pair.

use glam::Vec3;
use scatterlab::scene::mitsuba::{export_mitsuba, obj_path_for};
use scatterlab::scene::MAX_MATERIALS;

use crate::common::{assert_clean, gpu, judge, render, scene, LBL, PATH, SINGLE};
use crate::refraction_tests::{assert_furnace, load_err, mesh, ENV};

const SPHERE: &str = "icosphere.obj";
const BLOB: &str = "blob.obj";

/// The `[[object]]` keys of an entry: `file` scaled by `scale` at `at`, with index `ior`.
fn entry(file: &str, scale: f32, at: [f32; 3], ior: &str) -> String {
    format!(
        "mesh = \"{}\"\nscale = {scale}\ntranslate = [{}, {}, {}]\nrotate = [20.0, 30.0, 0.0]\nior = {ior}",
        mesh(file),
        at[0],
        at[1],
        at[2]
    )
}

/// A scene of the `[[object]]` entries `objects` (keys, medium keys) under `light`, seen from +z.
fn objects_scene(objects: &[(String, &str)], light: &str, size: u32, spp: u32) -> String {
    let mut text = format!(
        "[render]\nwidth = {size}\nheight = {size}\nseed = 5\nspp = {spp}\n\
         [camera]\norigin = [0.0, 0.4, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov = 40.0\n"
    );
    for (keys, medium) in objects {
        text += &format!("[[object]]\n{keys}\n[object.medium]\n{medium}\n");
    }
    text + &format!("[[light]]\n{light}\n")
}

/// The glass sphere on the left and the blob on the right, sharing `medium` and `ior`.
fn pair(medium: &str, ior: &str, light: &str, size: u32, spp: u32) -> String {
    objects_scene(
        &[(entry(SPHERE, 0.5, [-0.6, 0.0, 0.0], ior), medium), (entry(BLOB, 0.45, [0.6, 0.0, 0.0], ior), medium)],
        light,
        size,
        spp,
    )
}

#[test]
fn several_objects_join_into_one_closed_mesh() {
    let medium = "sigma_t = 2.0\nalbedo = 0.8";
    let s = scene(&pair(medium, "1.5", ENV, 8, 1));
    let o = s.object.as_ref().expect("an object");
    assert_eq!(o.parts.len(), 2);
    let alone = |file: &str, scale: f32, at: [f32; 3]| {
        let one = scene(&objects_scene(&[(entry(file, scale, at, "1.5"), medium)], ENV, 8, 1));
        one.object.unwrap()
    };
    let (a, b) = (alone(SPHERE, 0.5, [-0.6, 0.0, 0.0]), alone(BLOB, 0.45, [0.6, 0.0, 0.0]));
    assert_eq!(o.parts[0].triangles, a.mesh.triangles.len());
    assert_eq!(o.parts[1].triangles, b.mesh.triangles.len());
    assert_eq!(o.mesh.triangles.len(), a.mesh.triangles.len() + b.mesh.triangles.len());
    o.mesh.check_closed().expect("the union of closed meshes is closed");
    // Volumes add (divergence theorem over the union; each part's own sum about its own centre).
    let (va, vb, v) = (a.mesh.volume(), b.mesh.volume(), o.mesh.volume());
    assert!((v - (va + vb)).abs() < 1e-6 * v, "union volume {v} against {va} + {vb}");
    // Inside is either mesh's inside; between them is vacuum.
    assert!(o.contains(Vec3::new(-0.6, 0.0, 0.0)) && o.contains(Vec3::new(0.6, 0.0, 0.0)));
    assert!(!o.contains(Vec3::new(0.0, 0.0, 0.0)));
    assert_eq!(s.density_at(Vec3::new(0.0, 0.0, 0.0)), 0.0);
    assert_eq!(s.density_at(Vec3::new(-0.6, 0.05, 0.0)), 1.0);
    // The shared medium spans both meshes' bounds.
    let (alo, ahi) = a.mesh.bounds();
    let (blo, bhi) = b.mesh.bounds();
    assert!(s.medium.bounds_min.cmple(alo.min(blo)).all() && s.medium.bounds_max.cmpge(ahi.max(bhi)).all());
    assert!((s.medium.bounds_min - alo.min(blo)).abs().max_element() < 1e-4);
    assert_eq!(o.describe(), format!("{} + {}", mesh(SPHERE), mesh(BLOB)));
}

#[test]
fn several_objects_errors_are_one_line_and_name_the_entry() {
    let medium = "sigma_t = 2.0\nalbedo = 0.8";
    let sphere = entry(SPHERE, 0.5, [-0.6, 0.0, 0.0], "1.5");
    let with = |second: String, second_medium: &str| {
        objects_scene(&[(sphere.clone(), medium), (second, second_medium)], ENV, 8, 1)
    };
    // The blob moved into the sphere: the surfaces cross.
    let e = load_err(&with(entry(BLOB, 0.45, [-0.2, 0.0, 0.0], "1.5"), medium));
    assert!(e.contains("object[1].mesh") && e.contains("intersects object[0]") && e.contains("disjoint"), "{e}");
    // A small blob inside the sphere, and the sphere inside a large blob (either order).
    let e = load_err(&with(entry(BLOB, 0.1, [-0.6, 0.0, 0.0], "1.5"), medium));
    assert!(e.contains("object[1].mesh") && e.contains("nest"), "{e}");
    let big = objects_scene(
        &[(entry(BLOB, 0.05, [-0.6, 0.0, 0.0], "1.5"), medium), (entry(SPHERE, 0.5, [-0.6, 0.0, 0.0], "1.5"), medium)],
        ENV,
        8,
        1,
    );
    let e = load_err(&big);
    assert!(e.contains("object[1].mesh") && e.contains("nest"), "{e}");
    // Materials may differ, density included: an entry of another density table has a field
    // of its own over its own mesh's bounds.
    let sphere_density =
        "sigma_t = 2.0\nalbedo = 0.8\ndensity = { kind = \"sphere\", center = [0.6, 0.0, 0.0], radius = 0.3 }";
    let s = scene(&with(entry(BLOB, 0.45, [0.6, 0.0, 0.0], "1.5"), sphere_density));
    let o = s.object.as_ref().unwrap();
    assert_eq!((o.materials.len(), o.fields.len()), (2, 2));
    assert!(o.fields[1].bounds_min.x > 0.0 && o.fields[0].bounds_max.x < 0.0, "each field spans its own mesh");
    assert!(matches!(o.fields[1].density, scatterlab::scene::Density::Sphere { .. }));
    // At most MAX_MATERIALS distinct materials: the 17th is refused, naming it; repeats share.
    let many: Vec<(String, String)> = (0..=MAX_MATERIALS)
        .map(|i| {
            (
                entry(SPHERE, 0.04, [-1.5 + 0.1 * i as f32, 0.0, 0.0], "1.5"),
                format!("sigma_t = {}.0\nalbedo = 0.5", i + 1),
            )
        })
        .collect();
    let refs: Vec<(String, &str)> = many.iter().map(|(k, m)| (k.clone(), m.as_str())).collect();
    let e = load_err(&objects_scene(&refs, ENV, 8, 1));
    assert!(e.contains(&format!("object[{MAX_MATERIALS}].medium")) && e.contains("at most 16"), "{e}");
    let repeated: Vec<(String, &str)> = many
        .iter()
        .enumerate()
        .map(|(i, (k, _))| {
            (k.clone(), if i % 2 == 0 { "sigma_t = 1.0\nalbedo = 0.5" } else { "sigma_t = 2.0\nalbedo = 0.5" })
        })
        .collect();
    let s = scene(&objects_scene(&repeated, ENV, 8, 1));
    let o = s.object.as_ref().unwrap();
    assert_eq!(o.materials.len(), 2);
    assert!(o.parts.iter().enumerate().all(|(i, p)| p.material == i % 2));
    // Bounds: every entry that gives them gives the same box, and it holds every mesh.
    let blob = entry(BLOB, 0.45, [0.6, 0.0, 0.0], "1.5");
    let box_a = format!("{medium}\nbounds = [[-1.5, -1.0, -1.0], [1.5, 1.0, 1.0]]");
    let box_b = format!("{medium}\nbounds = [[-1.5, -1.0, -1.0], [1.5, 1.0, 1.1]]");
    let e = load_err(&objects_scene(&[(sphere.clone(), box_a.as_str()), (blob.clone(), box_b.as_str())], ENV, 8, 1));
    assert!(e.contains("object[1].medium.bounds") && e.contains("differ"), "{e}");
    let left_only = format!("{medium}\nbounds = [[-1.5, -1.0, -1.0], [0.0, 1.0, 1.0]]");
    let e = load_err(&objects_scene(&[(sphere.clone(), left_only.as_str()), (blob.clone(), medium)], ENV, 8, 1));
    assert!(e.contains("object[0].medium.bounds") && e.contains("meshes' bounds"), "{e}");
    // One box given by one entry is the shared medium's.
    let s = scene(&objects_scene(&[(sphere.clone(), medium), (blob.clone(), box_a.as_str())], ENV, 8, 1));
    assert_eq!(s.medium.bounds_max, Vec3::new(1.5, 1.0, 1.0));
    // The second entry's own fields are named as its.
    let e = load_err(&with(blob.replace("scale = 0.45", "scale = -1.0"), medium));
    assert!(e.contains("object[1].scale"), "{e}");
    let e = load_err(&with(format!("{blob}\nshininess = 2"), medium));
    assert!(e.contains("object[1].shininess"), "{e}");
    let e = load_err(&with(entry("no-such.obj", 0.45, [0.6, 0.0, 0.0], "1.5"), medium));
    assert!(e.contains("object[1].mesh") && e.contains("no-such.obj"), "{e}");
    // A camera inside the second object.
    let inside = with(entry(BLOB, 0.45, [0.0, 0.4, 4.0], "1.5"), medium)
        .replace("target = [0.0, 0.0, 0.0]", "target = [-0.6, 0.0, 0.0]");
    let e = load_err(&inside);
    assert!(e.contains("camera.origin") && e.contains("inside"), "{e}");
}

#[test]
fn a_point_light_inside_one_of_several_objects_lights_the_others() {
    // Index-matched, the other object's medium sees the light through straight shadow rays; in
    // glass only through two refractions (out of the sphere, into the blob), which path's
    // specular chains carry (tests/mnee_tests.rs checks them against a closed form).
    let gpu = gpu();
    let light = "kind = \"point\"\nposition = [-0.6, 0.05, 0.0]\nintensity = 1.0";
    let medium = "sigma_t = 2.0\nalbedo = 0.8";
    for ior in ["1.0", "1.5"] {
        let out = render(&gpu, &scene(&pair(medium, ior, light, 8, 4)), PATH, &[]);
        // Light reaches the right-hand object (the blob) through the vacuum between them.
        let w = out.image.width as usize;
        let right: f64 = (0..out.image.height as usize)
            .flat_map(|y| (3 * w / 4..w).map(move |x| (x, y)))
            .map(|(x, y)| out.image.data[(y * w + x) * 3] as f64)
            .sum();
        assert!(right > 0.0, "ior {ior}: the blob got no light from the sphere's light");
    }
    assert_clean(&gpu);
}

#[test]
fn two_entries_render_as_the_one_mesh_that_joins_them() {
    // The union is the solvers' whole view of several entries: the exported mesh (the union in
    // scene coordinates, written with round-trip precision) as one entry renders the same
    // image, bit for bit, in every solver that renders objects.
    let gpu = gpu();
    let medium = "sigma_t = 6.0\nalbedo = 0.95\ng = 0.3";
    let text = pair(medium, "1.5", ENV, 16, 16);
    let two = scene(&text);
    let dir = tempfile::tempdir().unwrap();
    let xml = dir.path().join("pair.xml");
    export_mitsuba(&two, &xml).expect("export");
    let joined = obj_path_for(&xml);
    let one_text = objects_scene(&[(format!("mesh = \"{}\"\nior = 1.5", joined.display()), medium)], ENV, 16, 16);
    let one = scene(&one_text);
    assert_eq!(one.object.as_ref().unwrap().mesh.triangles, two.object.as_ref().unwrap().mesh.triangles);
    assert_eq!(one.medium.bounds_min, two.medium.bounds_min);
    assert_eq!(one.object.as_ref().unwrap().mesh.positions, two.object.as_ref().unwrap().mesh.positions);
    for (solver, sets) in [
        (PATH, vec![]),
        (SINGLE, vec![("single.env_dirs", "16")]),
        // Fixed-point transfer: float atomics sum in whatever order the threads run.
        (LBL, vec![("lbl.grid", "18"), ("lbl.view_step", "0.05"), ("lbl.deterministic", "true")]),
    ] {
        let a = render(&gpu, &two, solver, &sets);
        let b = render(&gpu, &one, solver, &sets);
        assert!(a.image.data.iter().any(|v| *v != 1.0), "{}: a blank image", solver.name());
        assert!(a.image.data == b.image.data, "{}: two entries and their joined mesh differ", solver.name());
    }
    assert_clean(&gpu);
}

#[test]
fn lossless_media_in_two_glass_objects_hold_the_furnace() {
    // Light leaving one object may enter the other (refracted twice more): with albedo 1 the
    // image is still the environment's radiance, within noise.
    let gpu = gpu();
    let s = scene(&pair("sigma_t = 4.0\nalbedo = 1.0\ng = 0.5", "1.5", ENV, 16, 256));
    let out = render(&gpu, &s, PATH, &[]);
    assert_furnace(&out, "two glass objects");
    assert_clean(&gpu);
}

#[test]
fn lbl_matches_path_on_a_pair_of_glass_objects() {
    // Measured (48 x 48, default grid, path at 4096 spp): relL2 0.043, energy 1.016.
    let gpu = gpu();
    let s = scene(&pair("sigma_t = 6.0\nalbedo = 0.95", "1.5", ENV, 32, 512));
    let reference = crate::common::path_reference(&gpu, &s, &[]);
    let out = render(&gpu, &s, LBL, &[("lbl.grid", "32"), ("lbl.view_step", "0.05")]);
    let (rel, energy) = judge(&out.image, &reference);
    eprintln!("pair: lbl relL2 {rel:.4} energy {energy:.4}");
    assert!((energy - 1.0).abs() < 0.05, "energy ratio {energy}");
    assert!(rel < 0.1, "relL2 {rel}");
    assert_clean(&gpu);
}
