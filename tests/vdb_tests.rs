//! OpenVDB density grids (`density = { kind = "vdb", ... }`, issue 16), read with `vdb-rs`
//! against a file written by OpenVDB's own Python bindings (tools/make-test-vdb, committed as
//! tests/data/ramp.vdb): every voxel's value, the dense box, grid selection, errors, and a
//! render identical to the same grid given as a Mitsuba .vol.

use std::path::{Path, PathBuf};

use glam::Vec3;
use scatterlab::scene::{write_vol, Density, LoadOptions, Scene};

use crate::common::{assert_clean, gpu, render, PATH};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data").join(name)
}

fn vdb_scene(density: &str) -> String {
    format!(
        "[render]\nwidth = 16\nheight = 16\nspp = 8\n\
         [camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov = 30.0\n\
         [medium]\nbounds = [[-0.8, -0.5, -0.3], [0.8, 0.5, 0.3]]\nsigma_t = 6.0\nalbedo = 0.9\n\
         density = {density}\n[[light]]\nkind = \"directional\"\ndirection = [0.3, -1.0, -0.5]\nirradiance = 2.0\n"
    )
}

fn load(text: &str) -> Result<Scene, String> {
    Scene::from_str(text, "vdb.toml", Path::new("."), &[], &LoadOptions::default()).map_err(|e| e.to_string())
}

/// tools/make-test-vdb's values: 0.25 + 0.01 i + 0.02 j + 0.04 k on the active voxels of
/// [-3, 12] x [0, 9] x [2, 7], inactive (0) where i + j + k is a multiple of 7.
fn expected(i: i32, j: i32, k: i32) -> f32 {
    if (i + j + k).rem_euclid(7) == 0 {
        0.0
    } else {
        (0.25 + 0.01 * i as f64 + 0.02 * j as f64 + 0.04 * k as f64) as f32
    }
}

#[test]
fn vdb_grid_reads_every_voxel_written_by_openvdb() {
    let s = load(&vdb_scene(&format!("{{ kind = \"vdb\", file = \"{}\" }}", data("ramp.vdb").display()))).unwrap();
    let Density::Grid(g) = &s.medium.density else { panic!("a grid") };
    assert_eq!(g.dims, [16, 10, 6], "the active voxels' bounding box");
    let mut active = 0;
    for k in 0..6 {
        for j in 0..10 {
            for i in 0..16 {
                let want = expected(i as i32 - 3, j as i32, k as i32 + 2);
                let got = g.at(i, j, k);
                assert!((got - want).abs() <= 1e-7, "voxel ({i}, {j}, {k}): {got} vs {want}");
                active += (want != 0.0) as usize;
            }
        }
    }
    assert_eq!(active, 824, "the file's active voxel count (tools/make-test-vdb prints it)");
    // The other grid of the file, by name.
    let t = load(&vdb_scene(&format!(
        "{{ kind = \"vdb\", file = \"{}\", grid = \"temperature\" }}",
        data("ramp.vdb").display()
    )))
    .unwrap();
    let Density::Grid(t) = &t.medium.density else { panic!("a grid") };
    assert_eq!((t.dims, t.data.as_slice()), ([1, 1, 1], &[500.0f32][..]));
}

#[test]
fn vdb_errors_are_one_line() {
    let e =
        load(&vdb_scene(&format!("{{ kind = \"vdb\", file = \"{}\", grid = \"smoke\" }}", data("ramp.vdb").display())))
            .unwrap_err();
    assert!(
        !e.contains('\n') && e.contains("\"smoke\"") && e.contains("\"density\"") && e.contains("\"temperature\""),
        "{e}"
    );
    let e = load(&vdb_scene("{ kind = \"vdb\", file = \"no-such.vdb\" }")).unwrap_err();
    assert!(!e.contains('\n') && e.contains("no-such.vdb") && e.contains("cannot open"), "{e}");
    // A truncated file: an error, never a panic or a hang.
    let dir = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(data("ramp.vdb")).unwrap();
    for cut in [8usize, 64, 300, bytes.len() / 2, bytes.len() - 10] {
        let p = dir.path().join(format!("cut{cut}.vdb"));
        std::fs::write(&p, &bytes[..cut]).unwrap();
        let e = load(&vdb_scene(&format!("{{ kind = \"vdb\", file = \"{}\" }}", p.display()))).unwrap_err();
        assert!(!e.contains('\n') && e.contains("medium.density.file"), "cut at {cut}: {e}");
    }
    // A tiny memory budget refuses the dense copy before allocating it.
    let opts = LoadOptions { memory_budget_bytes: 1000 };
    let text = vdb_scene(&format!("{{ kind = \"vdb\", file = \"{}\" }}", data("ramp.vdb").display()));
    let e = Scene::from_str(&text, "vdb.toml", Path::new("."), &[], &opts).unwrap_err().to_string();
    assert!(e.contains("memory budget") && e.contains("16 x 10 x 6"), "{e}");
}

#[test]
fn vdb_renders_as_the_same_grid_given_as_a_vol() {
    let gpu = gpu();
    let s = load(&vdb_scene(&format!("{{ kind = \"vdb\", file = \"{}\" }}", data("ramp.vdb").display()))).unwrap();
    let Density::Grid(g) = &s.medium.density else { panic!("a grid") };
    let dir = tempfile::tempdir().unwrap();
    let vol = dir.path().join("ramp.vol");
    std::fs::write(&vol, write_vol(g.dims, &g.data, Vec3::splat(-1.0), Vec3::ONE)).unwrap();
    let v = load(&vdb_scene(&format!("{{ kind = \"grid\", file = \"{}\" }}", vol.display()))).unwrap();
    let a = render(&gpu, &s, PATH, &[]);
    let b = render(&gpu, &v, PATH, &[]);
    assert!(a.image.data.iter().any(|x| *x > 0.0), "a black image");
    assert!(a.image.data == b.image.data, "the .vdb and the .vol of the same values render differently");
    assert_clean(&gpu);
}

/// scenes/explosion.vdb (tools/make-explosion, OpenVDB's own writer): its temperature grid's
/// active box is the hot core only, smaller than the density's and offset from it; read over
/// the density's voxels, every hot voxel holds the blackbody of 1000 + 1500 density at the
/// same voxel (the tool's formula), and the others emit nothing.
#[test]
fn vdb_temperature_lands_on_the_density_voxels() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/explosion.toml");
    let s = Scene::load(&path, &[], &LoadOptions::default()).unwrap();
    let Density::Grid(d) = &s.medium.density else { panic!("a grid density") };
    let g = s.medium.emission.grid().expect("a temperature grid");
    assert_eq!(g.dims(), d.dims);
    assert_eq!(d.dims, [28, 25, 27]);
    let mut hot = 0;
    for (v, &density) in d.data.iter().enumerate() {
        let rgb = Vec3::new(g.planes[0].data[v], g.planes[1].data[v], g.planes[2].data[v]);
        if rgb == Vec3::ZERO {
            continue;
        }
        hot += 1;
        let want = scatterlab::physics::blackbody::blackbody_rgb(1000.0 + 1500.0 * density as f64);
        assert!((rgb - want).abs().max_element() <= 1e-5 * want.max_element(), "voxel {v}: {rgb} against {want}");
    }
    // Every active temperature voxel (1732, tools/make-explosion) is above the 100 K cutoff.
    assert_eq!(hot, 1732);
}
