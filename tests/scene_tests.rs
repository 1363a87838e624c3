//! Scene parsing, validation, overrides, feature analysis and grids (pure Rust, no GPU).

use std::path::{Path, PathBuf};

use glam::Vec3;
use scatterlab::scene::{
    is_scene_key, write_vol, CameraKind, Density, Features, Grid, Light, LoadOptions, Scene, SceneError,
};

use crate::common::SceneText;

// ---------------------------------------------------------------------------- helpers

/// The shared base scene ([`SceneText::base`]): tests derive broken ones from it.
fn base() -> SceneText {
    SceneText::base()
}

fn scenes_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes")
}

fn parse_in(text: &str, dir: &Path, overrides: &[(&str, &str)], opts: &LoadOptions) -> Result<Scene, SceneError> {
    let overrides: Vec<(String, String)> = overrides.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect();
    Scene::from_str(text, "scene.toml", dir, &overrides, opts)
}

fn parse(text: &str) -> Result<Scene, SceneError> {
    parse_in(text, Path::new("."), &[], &LoadOptions::default())
}

/// The error message of a scene that must fail; checks it is one line naming the file.
fn message(result: Result<Scene, SceneError>) -> String {
    let err = match result {
        Ok(_) => panic!("scene loaded but should have failed"),
        Err(e) => e,
    };
    let msg = err.to_string();
    eprintln!("error message: {msg}"); // `--nocapture` shows every message a user could see
    assert!(!msg.contains('\n'), "error is not one line: {msg:?}");
    assert!(msg.starts_with("scene.toml"), "error does not name the file first: {msg}");
    msg
}

/// Assert the message contains every word (case-sensitive).
fn assert_mentions(msg: &str, words: &[&str]) {
    for w in words {
        assert!(msg.contains(w), "error {msg:?} does not mention {w:?}");
    }
}

fn err_of(text: &str) -> String {
    message(parse(text))
}

fn with_overrides(overrides: &[(&str, &str)]) -> Result<Scene, SceneError> {
    parse_in(&base(), Path::new("."), overrides, &LoadOptions::default())
}

fn write(dir: &Path, name: &str, bytes: &[u8]) {
    std::fs::write(dir.join(name), bytes).expect("write test file");
}

fn f32_bytes(data: &[f32]) -> Vec<u8> {
    data.iter().flat_map(|v| v.to_le_bytes()).collect()
}

fn ramp(n: usize) -> Vec<f32> {
    (0..n).map(|i| i as f32 * 0.25).collect()
}

fn vol(dims: [u32; 3], data: &[f32]) -> Vec<u8> {
    write_vol(dims, data, Vec3::ZERO, Vec3::ONE)
}

/// The error of `scene` loaded from a folder that holds `files`.
fn grid_error(files: &[(&str, Vec<u8>)], scene: &SceneText, opts: &LoadOptions) -> String {
    let dir = tempfile::tempdir().expect("tempdir");
    for (name, bytes) in files {
        write(dir.path(), name, bytes);
    }
    message(parse_in(scene, dir.path(), &[], opts))
}

// ---------------------------------------------------------------------------- the base

#[test]
fn scene_base_is_valid_and_typed() {
    let s = parse(&base()).expect("the base scene loads");
    assert_eq!(s.source, PathBuf::from("scene.toml"));
    assert_eq!((s.render.width, s.render.height, s.render.seed, s.render.spp), (32, 32, 7, 4));
    assert_eq!(s.camera.kind, CameraKind::Perspective { fov_deg: 30.0 });
    assert_eq!(s.medium.sigma_t, Vec3::splat(2.0));
    assert_eq!(s.medium.albedo, Vec3::splat(0.8));
    assert_eq!(s.medium.density, Density::Constant);
    assert_eq!(s.lights, vec![Light::Point { position: Vec3::ONE, intensity: Vec3::splat(10.0) }]);
}

#[test]
fn scene_defaults_for_optional_keys() {
    let text = base()
        .remove("render.seed")
        .remove("render.spp")
        .remove("medium.g")
        .remove("medium.density")
        .remove("camera.up");
    let s = parse(&text).expect("optional keys may be omitted");
    assert_eq!((s.render.seed, s.render.spp), (1, 256));
    assert_eq!(s.medium.g, 0.0);
    assert_eq!(s.medium.density, Density::Constant);
    assert_eq!(s.camera.up, Vec3::Y);
}

#[test]
fn scene_rgb_values_and_direction_normalised() {
    let text = base()
        .set("medium.sigma_t", "[1, 2, 3]")
        .prepend_light("kind = \"directional\"\ndirection = [0, 0, -2]\nirradiance = [1, 0.5, 0]");
    let s = parse(&text).expect("loads");
    assert_eq!(s.medium.sigma_t, Vec3::new(1.0, 2.0, 3.0));
    assert_eq!(
        s.lights[0],
        Light::Directional { direction: Vec3::new(0.0, 0.0, -1.0), irradiance: Vec3::new(1.0, 0.5, 0.0) }
    );
    assert!(s.features().chromatic);
}

#[test]
fn scene_camera_inside_medium_is_allowed() {
    let text = base().set("camera.origin", "[0.0, 0.0, 0.2]");
    parse(&text).expect("a camera inside the medium is fine");
}

#[test]
fn scene_camera_basis_matches_image_axes() {
    let s = parse(&base()).expect("loads");
    let (right, up, forward) = s.camera.basis();
    assert!((right - Vec3::X).length() < 1e-6);
    assert!((up - Vec3::Y).length() < 1e-6);
    assert!((forward + Vec3::Z).length() < 1e-6);
}

// ---------------------------------------------------------------------------- syntax & keys

#[test]
fn scene_error_malformed_toml_gives_line() {
    let msg = err_of(&base().set("render.spp", "= 4"));
    assert_mentions(&msg, &["malformed TOML", "scene.toml:6:"]);
}

#[test]
fn scene_error_unknown_key_names_key_line_and_suggestion() {
    let text = base().replace_line("medium.albedo", "albdo = 0.8");
    let line = text.lines().position(|l| l.starts_with("albdo")).unwrap() + 1;
    let msg = err_of(&text);
    assert_mentions(&msg, &["unknown key `medium.albdo`", &format!("scene.toml:{line}:"), "did you mean `albedo`"]);
}

#[test]
fn scene_error_unknown_key_in_sections_and_lights() {
    let msg = err_of(&base().replace("[render]", "[rendr]\nwidth = 1\n\n[render]"));
    assert_mentions(&msg, &["unknown key `rendr`", "render"]);
    let msg = err_of(&base().insert_after("light.intensity", "colour = 1"));
    assert_mentions(&msg, &["unknown key `light[0].colour`"]);
    let msg = err_of(&base().density(r#"{ kind = "sphere", center = [0, 0, 0], radius = 0.3, radios = 1 }"#));
    assert_mentions(&msg, &["unknown key `medium.density.radios`"]);
    let msg = err_of(&base().density(r#"{ kind = "constant", radius = 1 }"#));
    assert_mentions(&msg, &["unknown key `medium.density.radius`"]);
}

#[test]
fn scene_error_missing_required_key() {
    let msg = err_of(&base().remove("render.width"));
    assert_mentions(&msg, &["missing required key `render.width`"]);
    let msg = err_of(&base().remove("medium.sigma_t"));
    assert_mentions(&msg, &["missing required key `medium.sigma_t`"]);
    let msg = err_of(&base().remove("camera.fov"));
    assert_mentions(&msg, &["missing required key `camera.fov`", "perspective"]);
    let msg = err_of(&base().remove("light.kind"));
    assert_mentions(&msg, &["missing required key `light[0].kind`", "directional"]);
    let msg = err_of(&base().remove("camera"));
    assert_mentions(&msg, &["missing required key `camera`", "[camera]"]);
}

#[test]
fn scene_error_wrong_types_and_kinds() {
    let msg = err_of(&base().set("render.width", "\"wide\""));
    assert_mentions(&msg, &["render.width", "invalid type", "expected an integer"]);
    let msg = err_of(&base().set("medium.sigma_t", "[1, 2]"));
    assert_mentions(&msg, &["medium.sigma_t", "3 numbers"]);
    let msg = err_of(&base().set("light.kind", "\"spot\""));
    assert_mentions(&msg, &["scene.toml: light[0].kind: unknown kind `spot`", "directional"]);
    let msg = err_of(&base().set("camera.kind", "\"fisheye\""));
    assert_mentions(&msg, &["camera.kind", "fisheye", "orthographic"]);
    let msg = err_of(&base().replace("[[light]]", "[light]"));
    assert_mentions(&msg, &["light", "[[light]]"]);
}

// ---------------------------------------------------------------------------- values

#[test]
fn scene_error_albedo_each_channel() {
    for (value, channel) in
        [("[1.2, 0.5, 0.5]", "red"), ("[0.5, 1.2, 0.5]", "green"), ("[0.5, 0.5, -0.1]", "blue"), ("-0.5", "red")]
    {
        let msg = err_of(&base().set("medium.albedo", value));
        assert_mentions(&msg, &["medium.albedo", channel, "[0, 1]"]);
    }
}

#[test]
fn scene_error_g_out_of_range() {
    for (g, hint) in
        [("1.0", "0.99 for very forward"), ("-1.0", "-0.99 for very backward"), ("1.5", "0.99"), ("nan", "0.99")]
    {
        let msg = err_of(&base().set("medium.g", g));
        assert_mentions(&msg, &["medium.g", "(-1, 1)", hint]);
    }
}

#[test]
fn scene_error_sigma_t_negative_or_non_finite() {
    for (value, channel) in [("-1.0", "red"), ("nan", "red"), ("[1, inf, 1]", "green"), ("[1, 1, 1e300]", "blue")] {
        let msg = err_of(&base().set("medium.sigma_t", value));
        assert_mentions(&msg, &["medium.sigma_t", channel, "finite and >= 0"]);
        assert!(!msg.contains("00000"), "huge numbers are written compactly: {msg}");
    }
}

#[test]
fn scene_error_image_size_and_spp() {
    for (field, value) in
        [("render.width", "0"), ("render.height", "0"), ("render.width", "20000"), ("render.height", "-4")]
    {
        let msg = err_of(&base().set(field, value));
        assert_mentions(&msg, &[field, "16384"]);
    }
    let msg = err_of(&base().set("render.spp", "0"));
    assert_mentions(&msg, &["render.spp", "out of range"]);
    let msg = err_of(&base().set("render.seed", "-1"));
    assert_mentions(&msg, &["render.seed", ">= 0"]);
}

#[test]
fn scene_error_no_lights() {
    let msg = err_of(&base().without_light());
    assert_mentions(&msg, &["no lights", "[[light]]"]);
}

#[test]
fn scene_error_light_values() {
    let msg = err_of(&base().set("light.intensity", "-1.0"));
    assert_mentions(&msg, &["light[0].intensity", "finite and >= 0"]);
    let msg = err_of(&base().set("light.intensity", "[1, nan, 1]"));
    assert_mentions(&msg, &["light[0].intensity", "green"]);
    let msg = err_of(&base().set("light.position", "[1.0, inf, 1.0]"));
    assert_mentions(&msg, &["light[0].position", "non-finite"]);
    let directional = |body: &str| base().prepend_light(&format!("kind = \"directional\"\n{body}"));
    let msg = err_of(&directional("direction = [0, -1, 0]\nirradiance = -2"));
    assert_mentions(&msg, &["light[0].irradiance", "finite and >= 0"]);
    let msg = err_of(&directional("direction = [0, 0, 0]\nirradiance = 1"));
    assert_mentions(&msg, &["light[0].direction", "zero-length"]);
    let env = base().prepend_light("kind = \"environment\"\nradiance = [1, 1, -0.5]");
    assert_mentions(&err_of(&env), &["light[0].radiance", "blue", ">= 0"]);
}

#[test]
fn scene_error_camera_geometry() {
    let msg = err_of(&base().set("camera.target", "[0.0, 0.0, 4.0]"));
    assert_mentions(&msg, &["camera.target", "equals camera.origin"]);
    let msg = err_of(&base().set("camera.up", "[0.0, 0.0, 2.0]"));
    assert_mentions(&msg, &["camera.up", "parallel", "e.g. [0, 1, 0]"]);
    let msg = err_of(&base().set("camera.up", "[0.0, 0.0, 0.0]"));
    assert_mentions(&msg, &["camera.up", "zero-length"]);
    for fov in ["0.0", "180.0", "-5", "nan"] {
        let msg = err_of(&base().set("camera.fov", fov));
        assert_mentions(&msg, &["camera.fov", "(0, 180)"]);
    }
    for extent in ["0.0", "-1.0", "inf"] {
        let text =
            base().set("camera.kind", "\"orthographic\"").replace_line("camera.fov", &format!("extent = {extent}"));
        assert_mentions(&err_of(&text), &["camera.extent", "> 0"]);
    }
    let text = base().set("camera.kind", "\"orthographic\"");
    assert_mentions(&err_of(&text), &["missing required key `camera.extent`", "orthographic"]);
}

#[test]
fn scene_error_camera_sees_no_part_of_medium() {
    // Looking away from the box.
    let msg = err_of(&base().set("camera.target", "[0.0, 0.0, 8.0]"));
    assert_mentions(&msg, &["camera", "sees no part of the medium", "target = [0, 0, 0]"]);
    // Looking past it: narrow fov aimed well to the side.
    let msg = err_of(&base().set("camera.target", "[3.0, 0.0, 0.0]").set("camera.fov", "5.0"));
    assert_mentions(&msg, &["sees no part of the medium"]);
    // Orthographic, offset sideways by more than the view width.
    let ortho = base()
        .set("camera.kind", "\"orthographic\"")
        .replace_line("camera.fov", "extent = 1.0")
        .set("camera.origin", "[3.0, 0.0, 4.0]")
        .set("camera.target", "[3.0, 0.0, 0.0]");
    assert_mentions(&err_of(&ortho), &["sees no part of the medium"]);
    // Grazing the box with the edge of the view is still seeing it.
    let edge = base().set("camera.target", "[1.4, 0.0, 0.0]");
    parse(&edge).expect("a box at the edge of the view is visible");
}

#[test]
fn scene_error_bounds_and_sphere() {
    let msg = err_of(&base().set("medium.bounds", "[[-0.5, 0.5, -0.5], [0.5, 0.5, 0.5]]"));
    assert_mentions(&msg, &["medium.bounds", "on y"]);
    let msg = err_of(&base().set("medium.bounds", "[[1, 1, 1], [0, 0, 0]]"));
    assert_mentions(&msg, &["medium.bounds", "less than max"]);
    for radius in ["0.0", "-0.3", "nan"] {
        let msg = err_of(&base().density(&format!(r#"{{ kind = "sphere", center = [0, 0, 0], radius = {radius} }}"#)));
        assert_mentions(&msg, &["medium.density.radius", "> 0"]);
    }
    let msg = err_of(&base().density(r#"{ kind = "sphere", center = [3, 0, 0], radius = 1 }"#));
    assert_mentions(&msg, &["medium.density", "does not overlap"]);
}

// ---------------------------------------------------------------------------- grids

#[test]
fn scene_error_missing_grid_file() {
    let msg = grid_error(&[], &base().grid("nope.vol"), &LoadOptions::default());
    assert_mentions(&msg, &["medium.density.file", "nope.vol", "cannot open", "resolved against the scene file"]);
}

#[test]
fn scene_error_raw_grid_size_mismatch() {
    let msg = grid_error(
        &[("g.f32", f32_bytes(&[0.5; 25]))],
        &base().grid_with_dims("g.f32", [4, 4, 4]),
        &LoadOptions::default(),
    );
    assert_mentions(&msg, &["needs 256 bytes", "has 100 bytes", "truncated"]);
    let msg = grid_error(
        &[("g.f32", f32_bytes(&[0.5; 65]))],
        &base().grid_with_dims("g.f32", [4, 4, 4]),
        &LoadOptions::default(),
    );
    assert_mentions(&msg, &["needs 256 bytes", "has 260 bytes"]);
    let msg = grid_error(&[("g.f32", f32_bytes(&[0.5; 64]))], &base().grid("g.f32"), &LoadOptions::default());
    assert_mentions(&msg, &["no dims", "dims = [nx, ny, nz]"]);
    // OpenVDB's magic ("VDB " as a little-endian u32) given as kind "grid": named, with the kind
    // that reads it.
    let vdb = [&[0x20u8, 0x42, 0x44, 0x56][..], &[0u8; 60][..]].concat();
    let msg = grid_error(&[("c.vdb", vdb)], &base().grid("c.vdb"), &LoadOptions::default());
    assert_mentions(&msg, &["c.vdb", "OpenVDB", "kind = \"vdb\""]);
    let msg = grid_error(
        &[("g.f32", f32_bytes(&[0.5; 64]))],
        &base().grid_with_dims("g.f32", [4, 0, 16]),
        &LoadOptions::default(),
    );
    assert_mentions(&msg, &["dims[1] = 0", "positive"]);
}

#[test]
fn scene_error_vol_truncated_and_bad_headers() {
    let density = &base().grid("g.vol");
    let good = vol([2, 3, 4], &ramp(24));
    let opts = LoadOptions::default();

    let truncated = good[..good.len() - 8].to_vec();
    let msg = grid_error(&[("g.vol", truncated)], density, &opts);
    assert_mentions(&msg, &["2x3x4", "needs 144 bytes", "has 136 bytes", "truncated"]);

    let msg = grid_error(&[("g.vol", good[..20].to_vec())], density, &opts);
    assert_mentions(&msg, &["truncated .vol header", "48 bytes"]);

    let mut v2 = good.clone();
    v2[3] = 2;
    assert_mentions(&grid_error(&[("g.vol", v2)], density, &opts), &["version 2", "version 3"]);

    let mut half = good.clone();
    half[4..8].copy_from_slice(&2i32.to_le_bytes());
    assert_mentions(&grid_error(&[("g.vol", half)], density, &opts), &["encoding 2", "float32"]);

    let mut rgb = write_vol([2, 3, 4], &ramp(72), Vec3::ZERO, Vec3::ONE);
    rgb[20..24].copy_from_slice(&3i32.to_le_bytes());
    assert_mentions(&grid_error(&[("g.vol", rgb)], density, &opts), &["3 channels", "1-channel"]);

    let mut negative_res = good.clone();
    negative_res[12..16].copy_from_slice(&(-3i32).to_le_bytes());
    assert_mentions(&grid_error(&[("g.vol", negative_res)], density, &opts), &["resolution[1] = -3"]);

    let with_dims = &base().grid_with_dims("g.vol", [2, 3, 5]);
    assert_mentions(&grid_error(&[("g.vol", good)], with_dims, &opts), &["disagrees with the .vol header", "2x3x4"]);
}

#[test]
fn scene_error_bad_voxel_values_name_the_voxel() {
    let density = &base().grid("g.vol");
    for bad in [f32::NAN, f32::INFINITY, -0.25] {
        let mut data = ramp(24);
        data[1 + 2 * 2 + 3 * 6] = bad; // voxel (1, 2, 3) of 2x3x4
        let msg = grid_error(&[("g.vol", vol([2, 3, 4], &data))], density, &LoadOptions::default());
        assert_mentions(&msg, &["voxel (1, 2, 3)", &format!("is {bad}"), "finite and >= 0"]);
    }
}

#[test]
fn scene_error_grid_over_memory_budget_checked_before_reading() {
    // The header claims 2048^3 voxels (32 GiB) but the file has no data: the budget check
    // must come first, so the message is about memory, not the file size.
    let header_only = write_vol([2048, 2048, 2048], &[], Vec3::ZERO, Vec3::ONE);
    let msg = grid_error(&[("big.vol", header_only)], &base().grid("big.vol"), &LoadOptions::default());
    assert_mentions(&msg, &["2048x2048x2048", "32.0 GiB", "4.0 GiB", "resample the grid or raise --memory-budget"]);

    // Resolutions whose product overflows u64 are "too large", not a panic.
    let absurd = write_vol([i32::MAX as u32; 3], &[], Vec3::ZERO, Vec3::ONE);
    let msg = grid_error(&[("absurd.vol", absurd)], &base().grid("absurd.vol"), &LoadOptions::default());
    assert_mentions(&msg, &["2147483647x2147483647x2147483647", "resample the grid"]);

    let small_budget = LoadOptions { memory_budget_bytes: 1000 };
    let msg =
        grid_error(&[("g.f32", f32_bytes(&[0.5; 512]))], &base().grid_with_dims("g.f32", [8, 8, 8]), &small_budget);
    assert_mentions(&msg, &["8x8x8", "2048 bytes", "1000 B", "resample the grid or raise --memory-budget"]);
}

#[test]
fn scene_vol_round_trip() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = ramp(24);
    write(dir.path(), "g.vol", &vol([2, 3, 4], &data));
    let text = base().grid_with_dims("g.vol", [2, 3, 4]);
    let s = parse_in(&text, dir.path(), &[], &LoadOptions::default()).expect("vol loads");
    let Density::Grid(grid) = &s.medium.density else { panic!("not a grid") };
    assert_eq!(grid.dims, [2, 3, 4]);
    assert_eq!(grid.data, data);
    assert_eq!(grid.file, dir.path().join("g.vol"));
    assert_eq!(s.max_density(), 23.0 * 0.25);
    assert_eq!(s.features().grid_dims, Some([2, 3, 4]));
    assert!(!s.features().homogeneous);
}

#[test]
fn scene_raw_grid_round_trip_and_scene_file_relative_paths() {
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::create_dir(dir.path().join("grids")).unwrap();
    let data = ramp(24);
    write(&dir.path().join("grids"), "g.f32", &f32_bytes(&data));
    let scene_path = dir.path().join("s.toml");
    std::fs::write(&scene_path, base().grid_with_dims("grids/g.f32", [2, 3, 4]).as_bytes()).unwrap();
    let s = Scene::load(&scene_path, &[], &LoadOptions::default()).expect("raw grid loads");
    assert_eq!(s.source, scene_path);
    let Density::Grid(grid) = &s.medium.density else { panic!("not a grid") };
    assert_eq!(grid.data, data);
    assert_eq!(grid.at(1, 2, 3), data[1 + 2 * 2 + 3 * 6]);
}

#[test]
fn scene_load_missing_scene_file() {
    let err = Scene::load(Path::new("/nonexistent/scene.toml"), &[], &LoadOptions::default()).unwrap_err();
    let msg = err.to_string();
    assert!(!msg.contains('\n'));
    assert_mentions(&msg, &["/nonexistent/scene.toml", "cannot read scene file"]);
}

// ---------------------------------------------------------------------------- sampling

fn test_grid() -> Grid {
    // 3 x 2 x 4 with distinct values.
    let data = (0..24).map(|i| (i * 7 % 24) as f32).collect();
    Grid { dims: [3, 2, 4], data, file: PathBuf::from("test") }
}

#[test]
fn scene_grid_sample_at_voxel_centres_is_the_voxel() {
    let g = test_grid();
    for k in 0..4 {
        for j in 0..2 {
            for i in 0..3 {
                let u = Vec3::new((i as f32 + 0.5) / 3.0, (j as f32 + 0.5) / 2.0, (k as f32 + 0.5) / 4.0);
                assert!((g.sample(u) - g.at(i, j, k)).abs() < 1e-5, "voxel ({i}, {j}, {k})");
            }
        }
    }
}

#[test]
fn scene_grid_sample_is_trilinear_between_centres() {
    let g = test_grid();
    // Halfway between the centres of (0,0,0) and (1,0,0).
    let u = Vec3::new(1.0 / 3.0, 0.25, 0.125);
    assert!((g.sample(u) - 0.5 * (g.at(0, 0, 0) + g.at(1, 0, 0))).abs() < 1e-5);
    // The centre of the 8 voxels (0..1, 0..1, 0..1).
    let u = Vec3::new(1.0 / 3.0, 0.5, 0.25);
    let mut mean = 0.0;
    for (i, j, k) in [(0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0), (0, 0, 1), (1, 0, 1), (0, 1, 1), (1, 1, 1)] {
        mean += g.at(i, j, k) / 8.0;
    }
    assert!((g.sample(u) - mean).abs() < 1e-4);
}

#[test]
fn scene_grid_sample_clamps_at_faces() {
    let g = test_grid();
    let centre =
        |i: u32, j: u32, k: u32| Vec3::new((i as f32 + 0.5) / 3.0, (j as f32 + 0.5) / 2.0, (k as f32 + 0.5) / 4.0);
    // Between a face and the outermost centre the value is that voxel's.
    for (u, voxel) in [
        (Vec3::new(0.0, 0.25, 0.125), (0, 0, 0)),
        (Vec3::new(0.05, 0.25, 0.125), (0, 0, 0)),
        (Vec3::new(1.0, 0.75, 0.875), (2, 1, 3)),
        (Vec3::new(0.0, 0.0, 0.0), (0, 0, 0)),
        (Vec3::new(1.0, 1.0, 1.0), (2, 1, 3)),
        (Vec3::new(-3.0, 7.0, 0.125), (0, 1, 0)),
    ] {
        assert!((g.sample(u) - g.at(voxel.0, voxel.1, voxel.2)).abs() < 1e-5, "u = {u}");
    }
    // Along a face, interpolation continues in the other axes.
    let on_face = Vec3::new(0.0, centre(0, 0, 0).y, (centre(0, 0, 0).z + centre(0, 0, 1).z) / 2.0);
    assert!((g.sample(on_face) - 0.5 * (g.at(0, 0, 0) + g.at(0, 0, 1))).abs() < 1e-5);
    assert_eq!(g.at(9, 9, 9), g.at(2, 1, 3), "indices clamp");
    // A hand-built grid whose dims disagree with its data reads 0, never panics.
    let bad = Grid { dims: [u32::MAX; 3], data: vec![1.0; 8], file: PathBuf::new() };
    assert_eq!(bad.at(u32::MAX, u32::MAX, u32::MAX), 0.0);
    let _ = bad.sample(Vec3::splat(0.7));
}

#[test]
fn scene_density_at_maps_bounds_and_is_zero_outside() {
    let dir = tempfile::tempdir().expect("tempdir");
    let g = test_grid();
    write(dir.path(), "g.vol", &vol(g.dims, &g.data));
    let text = base()
        .grid("g.vol")
        .set("medium.bounds", "[[0, 0, 0], [3, 2, 4]]")
        .set("camera.target", "[1.5, 1.0, 2.0]")
        .set("camera.origin", "[1.5, 1.0, 12.0]");
    let s = parse_in(&text, dir.path(), &[], &LoadOptions::default()).expect("loads");
    // With bounds [0,3]x[0,2]x[0,4], voxel (i,j,k) is centred at (i,j,k) + 0.5.
    assert!((s.density_at(Vec3::new(2.5, 0.5, 1.5)) - g.at(2, 0, 1)).abs() < 1e-5);
    assert_eq!(s.density_at(Vec3::new(-0.01, 1.0, 1.0)), 0.0);
    assert_eq!(s.density_at(Vec3::new(1.0, 1.0, 4.01)), 0.0);
    assert_eq!(s.max_density(), 23.0);

    let sphere = parse(&base().density(r#"{ kind = "sphere", center = [0.1, 0, 0], radius = 0.3 }"#)).expect("loads");
    assert_eq!(sphere.density_at(Vec3::new(0.35, 0.0, 0.0)), 1.0);
    assert_eq!(sphere.density_at(Vec3::new(-0.25, 0.0, 0.0)), 0.0);
    assert_eq!(sphere.max_density(), 1.0);
    let constant = parse(&base()).expect("loads");
    assert_eq!(constant.density_at(Vec3::splat(0.49)), 1.0);
    assert_eq!(constant.density_at(Vec3::splat(0.51)), 0.0);
}

// ---------------------------------------------------------------------------- overrides

#[test]
fn scene_overrides_apply_before_validation() {
    let s = with_overrides(&[
        ("medium.albedo", "0.5"),
        ("render.width", "64"),
        ("medium.sigma_t", "[1, 2, 3]"),
        ("medium.g", "-0.3"),
        ("camera.kind", "\"orthographic\""),
        ("camera.extent", "2.5"),
        ("light.0.intensity", "5"),
        ("light[0].position", "[2, 2, 2]"),
    ])
    .expect("overrides apply");
    assert_eq!(s.medium.albedo, Vec3::splat(0.5));
    assert_eq!(s.render.width, 64);
    assert_eq!(s.medium.sigma_t, Vec3::new(1.0, 2.0, 3.0));
    assert_eq!(s.medium.g, -0.3);
    assert_eq!(s.camera.kind, CameraKind::Orthographic { extent: 2.5 });
    assert_eq!(s.lights[0], Light::Point { position: Vec3::splat(2.0), intensity: Vec3::splat(5.0) });

    // Whole tables, and bare words as strings.
    let s = with_overrides(&[
        ("medium.density", "{ kind = \"sphere\", center = [0, 0, 0], radius = 0.3 }"),
        ("camera.kind", "orthographic"),
        ("camera.extent", "2"),
    ])
    .expect("overrides apply");
    assert_eq!(s.medium.density, Density::Sphere { center: Vec3::ZERO, radius: 0.3 });
    assert!(matches!(s.camera.kind, CameraKind::Orthographic { .. }));
}

#[test]
fn scene_override_errors() {
    let msg = message(with_overrides(&[("medium.albdo", "0.5")]));
    assert_mentions(&msg, &["override `medium.albdo`", "unknown key", "did you mean `albedo`"]);
    let msg = message(with_overrides(&[("path.max_depth", "3")]));
    assert_mentions(&msg, &["override `path.max_depth`", "`path` is not a section of the scene"]);
    let msg = message(with_overrides(&[("medium.density.radius", "0.3")]));
    assert_mentions(&msg, &["override `medium.density.radius`", "unknown key"]);
    let msg = message(with_overrides(&[("medium.albedo", "[1, 2")]));
    assert_mentions(&msg, &["override `medium.albedo`", "not a TOML value"]);
    let msg = message(with_overrides(&[("medium.albedo", "1.5")]));
    assert_mentions(&msg, &["medium.albedo", "[0, 1]", "override medium.albedo=1.5"]);
    let msg = message(with_overrides(&[("light.3.intensity", "1")]));
    assert_mentions(&msg, &["override `light.3.intensity`", "there is 1 entry"]);
    let msg = message(with_overrides(&[("medium.g.x", "1")]));
    assert_mentions(&msg, &["override `medium.g.x`", "not a table"]);
    let msg = message(with_overrides(&[("medium..g", "1")]));
    assert_mentions(&msg, &["empty key segment"]);
    let msg = message(with_overrides(&[("medium.albedo", "0.5\nrender = 1")]));
    assert_mentions(&msg, &["override `medium.albedo`"]);
    // The override named is the one applied: the last of a repeated key.
    let msg = message(with_overrides(&[("render.width", "16"), ("render.width", "\"wide\"")]));
    assert_mentions(&msg, &["render.width", "(value from override render.width=\"wide\")"]);
    // An array indexed by a word: say it is an array, how many entries, and how to index it.
    for index in ["x", "-1", "1e3"] {
        let msg = message(with_overrides(&[(&format!("light.{index}.intensity"), "1")]));
        assert_mentions(
            &msg,
            &["`light` is an array (there is 1 entry)", &format!("not `{index}`"), "light.0.intensity"],
        );
    }
    let msg = message(with_overrides(&[("light.x", "{ kind = \"point\" }")]));
    assert_mentions(&msg, &["`light` is an array (there is 1 entry)", "not `x`", "e.g. light.0"]);
    // serde's own type names (RawLight, RawMedium, ...) never reach the user.
    for (key, value, expected) in [
        ("light.0", "5", "expected a table with a `kind` key"),
        ("medium.density", "3", "expected a table with a `kind` key"),
        ("medium", "4", "expected a table"),
        ("camera", "3", "expected a table"),
        ("render", "2", "expected a table"),
    ] {
        let msg = message(with_overrides(&[(key, value)]));
        assert_mentions(&msg, &[expected, &format!("override {key}={value}")]);
        assert!(!msg.contains("Raw") && !msg.contains("struct") && !msg.contains("enum"), "{msg}");
    }
}

#[test]
fn scene_is_scene_key_routes_set_flags() {
    for key in [
        "render.width",
        "camera.fov",
        "medium.albedo",
        "medium.density.radius",
        "light.0.intensity",
        "light[1].position",
    ] {
        assert!(is_scene_key(key), "{key}");
    }
    for key in ["path.max_depth", "lbl.k", "dom.M", "", "renderer.x", "width"] {
        assert!(!is_scene_key(key), "{key}");
    }
}

// ---------------------------------------------------------------------------- robustness

#[test]
fn scene_never_panics_on_odd_input() {
    let odd = [
        "",
        "\u{0}\u{1}\u{2}",
        "render = 5",
        "[render]\nwidth = 1e999",
        "[[light]]\nkind = 5",
        "[medium]\ndensity = []",
        "light = [1, 2]",
        "[camera]\norigin = [1, 2, 3, 4]",
        "[render]\nwidth = 18446744073709551615",
        "[render]\nwidth = 9223372036854775807\nheight = 1\nspp = 9223372036854775807",
    ];
    for text in odd {
        let msg = match parse(text) {
            Ok(_) => panic!("{text:?} loaded"),
            Err(e) => e.to_string(),
        };
        assert!(!msg.contains('\n'), "{text:?} gave a multi-line error: {msg:?}");
    }
    for text in
        [base().set("medium.sigma_t", "1e39"), base().set("medium.sigma_t", "[0, 0, 0]").set("medium.albedo", "0")]
    {
        let _ = parse(&text);
    }
}

// ---------------------------------------------------------------------------- shipped scenes

const SHIPPED: [&str; 15] = [
    "campfire.toml",
    "explosion.toml",
    "homogeneous-sphere.toml",
    "cloud-layer.toml",
    "anisotropic-cube.toml",
    "cloud.toml",
    "point-light-in-cloud.toml",
    "lightning-at-dusk.toml",
    "thick-slab.toml",
    "default.toml",
    "wax-blob.toml",
    "smoke-torus.toml",
    "jade-pair.toml",
    "milk-orb.toml",
    "jade-and-wax.toml",
];

fn load_shipped(name: &str) -> Scene {
    Scene::load(&scenes_dir().join(name), &[], &LoadOptions::default())
        .unwrap_or_else(|e| panic!("{name} does not load: {e}"))
}

#[test]
fn scene_every_shipped_scene_loads() {
    let mut found = Vec::new();
    for entry in std::fs::read_dir(scenes_dir()).expect("scenes/") {
        let path = entry.expect("dir entry").path();
        if path.extension().is_some_and(|e| e == "toml") {
            let scene = Scene::load(&path, &[], &LoadOptions::default())
                .unwrap_or_else(|e| panic!("{} does not load: {e}", path.display()));
            assert!(
                scene.render.width * scene.render.height <= 256 * 256,
                "{}: keep shipped scenes cheap",
                path.display()
            );
            found.push(path.file_name().unwrap().to_string_lossy().into_owned());
        }
    }
    for name in SHIPPED {
        assert!(found.iter().any(|f| f == name), "scenes/{name} missing");
    }
}

#[test]
fn scene_features_of_shipped_scenes() {
    let f = |name| load_shipped(name).features();
    assert_eq!(
        f("homogeneous-sphere.toml"),
        Features {
            anisotropic: false,
            chromatic: false,
            light_inside: false,
            homogeneous: false,
            has_environment: true,
            grid_dims: None,
            emissive: false
        }
    );
    assert_eq!(
        f("anisotropic-cube.toml"),
        Features {
            anisotropic: true,
            chromatic: false,
            light_inside: false,
            homogeneous: true,
            has_environment: false,
            grid_dims: None,
            emissive: false
        }
    );
    assert_eq!(
        f("cloud.toml"),
        Features {
            anisotropic: true,
            chromatic: false,
            light_inside: false,
            homogeneous: false,
            has_environment: true,
            grid_dims: Some([64, 64, 64]),
            emissive: false
        }
    );
    assert_eq!(
        f("point-light-in-cloud.toml"),
        Features {
            anisotropic: true,
            chromatic: false,
            light_inside: true,
            homogeneous: false,
            has_environment: false,
            grid_dims: Some([64, 64, 64]),
            emissive: false
        }
    );
    assert_eq!(
        f("thick-slab.toml"),
        Features {
            anisotropic: false,
            chromatic: false,
            light_inside: false,
            homogeneous: true,
            has_environment: true,
            grid_dims: None,
            emissive: false
        }
    );
    assert_eq!(
        f("default.toml"),
        Features {
            anisotropic: true,
            chromatic: false,
            light_inside: false,
            homogeneous: false,
            has_environment: true,
            grid_dims: Some([64, 64, 64]),
            emissive: false
        }
    );
}

#[test]
fn scene_shipped_scenes_are_what_they_say() {
    let sphere = load_shipped("homogeneous-sphere.toml");
    assert_eq!(sphere.medium.albedo, Vec3::splat(0.9));
    assert_eq!(sphere.render.width, 128);
    let slab = load_shipped("thick-slab.toml");
    let thickness = slab.medium.bounds_max.y - slab.medium.bounds_min.y;
    assert!((slab.medium.sigma_t.x * thickness - 50.0).abs() < 1e-3, "optical thickness 50");
    assert_eq!(slab.medium.albedo, Vec3::splat(0.99));
    assert_eq!(load_shipped("anisotropic-cube.toml").medium.g, 0.7);
    let cloud = load_shipped("cloud.toml");
    let Density::Grid(grid) = &cloud.medium.density else { panic!("cloud is a grid") };
    assert!(grid.file.ends_with("cloud64.vol"));
    let max = cloud.max_density();
    assert!((0.8..=1.05).contains(&max), "cloud density peaks near 1, got {max}");
    // Zero on the outermost voxel layer, so nothing is cut off at the bounds.
    let [n, _, _] = grid.dims;
    for a in 0..n {
        for b in 0..n {
            for (i, j, k) in [(0, a, b), (n - 1, a, b), (a, 0, b), (a, n - 1, b), (a, b, 0), (a, b, n - 1)] {
                assert_eq!(grid.at(i, j, k), 0.0);
            }
        }
    }
    let default = load_shipped("default.toml");
    assert_eq!((default.render.width, default.render.height), (128, 128));
    // Two materials: jade (ior 1.6) and wax (ior 1.45, g 0.7), one per object.
    let jw = load_shipped("jade-and-wax.toml");
    let o = jw.object.as_ref().unwrap();
    assert_eq!(o.materials.len(), 2);
    assert_eq!((o.material_of(0).ior, o.material_of(1).ior, o.material_of(1).g), (1.6, 1.45, 0.7));
}

#[test]
fn scene_make_cloud_regenerates_the_committed_grid() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("cloud64.vol");
    let status = std::process::Command::new("python3")
        .arg(root.join("tools/make-cloud"))
        .arg(&out)
        .stdout(std::process::Stdio::null())
        .status()
        .expect("python3 is needed to run tools/make-cloud");
    assert!(status.success(), "tools/make-cloud failed");
    let made = std::fs::read(&out).expect("make-cloud output");
    let committed = std::fs::read(root.join("scenes/cloud64.vol")).expect("scenes/cloud64.vol");
    assert!(made == committed, "tools/make-cloud no longer reproduces scenes/cloud64.vol byte for byte");
}

/// Deterministic xorshift for the mutation tests.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

#[test]
fn scene_mutated_inputs_never_panic_and_errors_stay_one_line() {
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let alphabet = b"[]{}=,.\"'#\n -+0123456789einfa_kxyz";
    let dir = tempfile::tempdir().expect("tempdir");
    let good_vol = vol([2, 3, 4], &ramp(24));
    let grid_text = base().grid("g.vol");
    for round in 0..10_000 {
        // Text: a few random byte edits of the base scene.
        let mut bytes = base().as_bytes().to_vec();
        for _ in 0..1 + rng.below(4) {
            let at = rng.below(bytes.len());
            let c = alphabet[rng.below(alphabet.len())];
            match rng.below(3) {
                0 => bytes[at] = c,
                1 => bytes.insert(at, c),
                _ => {
                    bytes.remove(at);
                }
            }
        }
        let text = String::from_utf8_lossy(&bytes);
        if let Err(e) = parse(&text) {
            assert!(!e.to_string().contains('\n'), "{text:?}: {e}");
        }
        // Grid: random header and size edits of a valid .vol.
        if round % 6 == 0 {
            let mut v = good_vol.clone();
            for _ in 0..1 + rng.below(3) {
                let at = rng.below(48);
                v[at] = rng.next() as u8;
            }
            v.truncate(rng.below(v.len() + 1).max(v.len() * (rng.below(2))));
            write(dir.path(), "g.vol", &v);
            let result = parse_in(&grid_text, dir.path(), &[], &LoadOptions::default());
            if let Err(e) = result {
                assert!(!e.to_string().contains('\n'), "{e}");
            }
        }
    }
    // Overrides: random keys and values.
    let keys = [
        "medium.albedo",
        "light.0",
        "light[0].kind",
        "camera",
        "render.width.x",
        "medium.density.kind",
        "x",
        "light[9]",
    ];
    let values = ["1", "[1, 2, 3]", "{ kind = \"sphere\" }", "\"grid\"", "nan", "-inf", "[]", "{}", "1e40", "foo bar"];
    for key in keys {
        for value in values {
            if let Err(e) = with_overrides(&[(key, value)]) {
                assert!(!e.to_string().contains('\n'), "{key}={value}: {e}");
            }
        }
    }
}

// ---------------------------------------------------------------------------- emission

/// A unit box of medium seen from +z, with `medium` keys appended and `lights` after it.
fn emissive(medium: &str, lights: &str) -> String {
    format!(
        "[render]\nwidth = 8\nheight = 8\n[camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov = 30.0\n\
         [medium]\nbounds = [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]\nsigma_t = 2.0\nalbedo = 0.5\n{medium}\n{lights}"
    )
}

/// Emission in every form it takes: a number, RGB, a grid times emission_scale, a temperature
/// grid (blackbody at the voxels, cut off at or below the cutoff), and a light-less scene that
/// its emission lights.
#[test]
fn scene_emission_forms_load() {
    use scatterlab::scene::Emission;
    let s = parse(&emissive("emission = 2.0", "")).expect("a light-less emitter loads");
    assert!(s.lights.is_empty() && s.emissive() && s.features().emissive);
    assert_eq!(s.medium.emission, Emission::Constant(Vec3::splat(2.0)));
    assert_eq!(s.emission_at(Vec3::ZERO), Vec3::splat(2.0));
    // sigma_a Le = 2 (1 - 0.5) * 2.
    assert_eq!(s.emission_source_at(Vec3::ZERO), Vec3::splat(2.0));
    assert_eq!(s.emission_at(Vec3::splat(2.0)), Vec3::ZERO, "nothing outside the box");
    let s = parse(&emissive("emission = [1.0, 0.5, 0.0]\nemission_scale = 3.0", "")).unwrap();
    assert_eq!(s.medium.emission, Emission::Constant(Vec3::new(3.0, 1.5, 0.0)));
    let dir = tempfile::tempdir().unwrap();
    // A 2 x 1 x 1 grid: voxel 0 is 0, voxel 1 is 4; temperatures 50 K and 3000 K.
    write(dir.path(), "e.f32", &f32_bytes(&[0.0, 4.0]));
    write(dir.path(), "t.f32", &f32_bytes(&[50.0, 3000.0]));
    let load = |medium: &str| parse_in(&emissive(medium, ""), dir.path(), &[], &LoadOptions::default());
    let s =
        load("emission = { kind = \"grid\", file = \"e.f32\", dims = [2, 1, 1] }\nemission_scale = [1.0, 0.5, 0.25]")
            .unwrap();
    let g = s.medium.emission.grid().expect("a grid");
    assert_eq!((g.planes.len(), g.dims()), (1, [2, 1, 1]));
    // At the second voxel's centre (x = 0.25): Le = 4 x scale.
    assert_eq!(s.emission_at(Vec3::new(0.25, 0.0, 0.0)), Vec3::new(4.0, 2.0, 1.0));
    assert_eq!(s.emission_at(Vec3::new(-0.25, 0.0, 0.0)), Vec3::ZERO);
    let s =
        load("temperature = { kind = \"grid\", file = \"t.f32\", dims = [2, 1, 1] }\nemission_scale = 1e-4").unwrap();
    let g = s.medium.emission.grid().unwrap();
    assert_eq!(g.planes.len(), 3);
    let hot = scatterlab::physics::blackbody::blackbody_rgb(3000.0) * 1e-4;
    assert!((s.emission_at(Vec3::new(0.25, 0.0, 0.0)) - hot).abs().max_element() < 1e-6 * hot.max_element());
    assert_eq!(s.emission_at(Vec3::new(-0.25, 0.0, 0.0)), Vec3::ZERO, "50 K is below the default 100 K cutoff");
    // (value - offset) * scale: (3000 - 1000) * 2 = 4000 K; 50 K maps below the cutoff.
    let s = load(
        "temperature = { kind = \"grid\", file = \"t.f32\", dims = [2, 1, 1] }\ntemperature_offset = 1000.0\n\
         temperature_scale = 2.0\ntemperature_cutoff = 0.0",
    )
    .unwrap();
    let want = scatterlab::physics::blackbody::blackbody_rgb(4000.0);
    assert!((s.emission_at(Vec3::new(0.25, 0.0, 0.0)) - want).abs().max_element() < 1e-6 * want.max_element());
    assert_eq!(s.emission_at(Vec3::new(-0.25, 0.0, 0.0)), Vec3::ZERO);
    // A scene with lights and no emission has none.
    let s = parse(&base()).unwrap();
    assert!(!s.emissive() && s.medium.emission == Emission::None);
}

/// Bad emission values and combinations: one line each, naming the field.
#[test]
fn scene_emission_errors_are_one_line() {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "e.f32", &f32_bytes(&[0.0, 4.0]));
    write(dir.path(), "bad.f32", &f32_bytes(&[1.0, -2.0]));
    write(dir.path(), "d.f32", &f32_bytes(&[1.0; 8]));
    let light = "[[light]]\nkind = \"point\"\nposition = [1.0, 1.0, 1.0]\nintensity = 1.0\n";
    let cases: &[(&str, &str, &[&str])] = &[
        ("emission = -1.0", light, &["medium.emission", "emitted radiance", ">= 0"]),
        ("emission = [1.0, nan, 1.0]", light, &["medium.emission", "green"]),
        ("emission = \"hot\"", light, &["medium.emission"]),
        ("emission = { kind = \"sphere\", file = \"e.f32\" }", light, &["medium.emission.kind", "sphere"]),
        (
            "emission = { kind = \"grid\", file = \"bad.f32\", dims = [2, 1, 1] }",
            light,
            &["medium.emission.file", "emission values", ">= 0"],
        ),
        (
            "emission = { kind = \"grid\", file = \"missing.f32\", dims = [2, 1, 1] }",
            light,
            &["medium.emission.file", "missing.f32"],
        ),
        (
            "temperature = { kind = \"grid\", file = \"missing.f32\", dims = [2, 1, 1] }",
            light,
            &["medium.temperature.file", "missing.f32", "cannot open"],
        ),
        ("emission = 1.0\nemission_scale = -2.0", light, &["medium.emission_scale"]),
        ("emission_scale = 2.0", light, &["medium.emission_scale", "neither"]),
        ("temperature_scale = 2.0", light, &["medium.temperature_scale", "no temperature"]),
        (
            "emission = 1.0\ntemperature = { kind = \"grid\", file = \"e.f32\", dims = [2, 1, 1] }",
            light,
            &["medium.temperature", "both"],
        ),
        (
            "temperature = { kind = \"grid\", file = \"e.f32\", dims = [2, 1, 1] }\ntemperature_scale = 0.0",
            light,
            &["medium.temperature_scale", "> 0"],
        ),
        (
            "temperature = { kind = \"grid\", file = \"e.f32\", dims = [2, 1, 1] }\ntemperature_cutoff = -5.0",
            light,
            &["medium.temperature_cutoff"],
        ),
        ("emission = 0.0", "", &["no lights", "emits nothing"]),
        ("", "", &["light", "no lights"]),
    ];
    for (medium, lights, words) in cases {
        let text = emissive(medium, lights);
        let msg = message(parse_in(&text, dir.path(), &[], &LoadOptions::default()));
        assert_mentions(&msg, words);
        // An emission or temperature grid's error names its own field, not the density's.
        assert!(!msg.contains("density"), "{msg}");
    }
    // Past the memory budget: the temperature grid's field (its three RGB planes counted).
    let text = emissive("temperature = { kind = \"grid\", file = \"e.f32\", dims = [2, 1, 1] }", light);
    let small = LoadOptions { memory_budget_bytes: 16 };
    assert_mentions(
        &message(parse_in(&text, dir.path(), &[], &small)),
        &["medium.temperature.file", "memory budget", "--memory-budget"],
    );
    // Albedo 1 absorbs nothing, so it cannot emit.
    let text = emissive("emission = 1.0", light).replace("albedo = 0.5", "albedo = 1.0");
    assert_mentions(&message(parse(&text)), &["medium.emission", "albedo 1", "sigma_a Le"]);
    // A temperature grid of another size than the density grid.
    let text = emissive(
        "density = { kind = \"grid\", file = \"d.f32\", dims = [2, 2, 2] }\n\
         temperature = { kind = \"grid\", file = \"e.f32\", dims = [2, 1, 1] }",
        light,
    );
    assert_mentions(
        &message(parse_in(&text, dir.path(), &[], &LoadOptions::default())),
        &["medium.temperature", "2 x 1 x 1", "2 x 2 x 2"],
    );
}

/// The shipped emissive scenes: the campfire's grids come from tools/make-campfire byte for
/// byte, its temperature field emits only in the flame (hot voxels above the cutoff), and its
/// Le peaks where the flame is hottest.
#[test]
fn scene_campfire_is_what_it_says() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = tempfile::tempdir().expect("tempdir");
    let status = std::process::Command::new("python3")
        .arg(root.join("tools/make-campfire"))
        .arg(dir.path())
        .stdout(std::process::Stdio::null())
        .status()
        .expect("python3 runs tools/make-campfire");
    assert!(status.success());
    for f in ["campfire-density.vol", "campfire-temperature.vol"] {
        let made = std::fs::read(dir.path().join(f)).unwrap();
        assert!(made == std::fs::read(root.join("scenes").join(f)).unwrap(), "tools/make-campfire no longer makes {f}");
    }
    let s = load_shipped("campfire.toml");
    assert!(s.lights.iter().all(|l| matches!(l, scatterlab::scene::Light::Environment { .. })));
    let g = s.medium.emission.grid().expect("a temperature grid");
    let t = g.temperature.expect("from a temperature");
    assert_eq!(t.cutoff, 600.0);
    let peak = g.max_le();
    // 1889 K at most: red above green, blue clipped (below ~1900 K the blackbody is outside sRGB).
    assert!(peak.x > 20.0 && peak.x < 30.0 && peak.y < peak.x && peak.z >= 0.0, "{peak}");
    let emitting = g.planes[0].data.iter().filter(|v| **v > 0.0).count();
    assert!((300..=900).contains(&emitting), "{emitting} voxels emit");
}

/// A `path` reference's key (tests/common.rs, `reference_key`) does not depend on where the
/// checkout lies: the campfire (a scene file and two grid files) loaded from the repository and
/// from a copy in a temporary folder has one key, so the references committed here serve CI's
/// checkout wherever it is; its grid data is in the key (another grid, another key).
#[test]
fn a_reference_key_is_the_same_in_any_checkout() {
    use crate::common::{reference_key, repo_scene};
    let dir = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    for f in ["campfire.toml", "campfire-density.vol", "campfire-temperature.vol"] {
        std::fs::copy(root.join(f), dir.path().join(f)).unwrap();
    }
    let sets = [("render.width", "24")];
    let here = repo_scene("scenes/campfire.toml", &sets);
    let owned: Vec<(String, String)> = sets.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect();
    let load = |d: &Path| Scene::load(&d.join("campfire.toml"), &owned, &LoadOptions::default()).unwrap();
    let there = load(dir.path());
    assert_ne!(here.source, there.source);
    assert_eq!(reference_key(&here, &[("render.spp", "64")]), reference_key(&there, &[("render.spp", "64")]));
    assert_ne!(reference_key(&here, &[("render.spp", "64")]), reference_key(&here, &[("render.spp", "65")]));
    // Another temperature grid (one voxel changed) is another key.
    let t = dir.path().join("campfire-temperature.vol");
    let mut bytes = std::fs::read(&t).unwrap();
    let n = bytes.len();
    bytes[n - 4..].copy_from_slice(&2000.0f32.to_le_bytes());
    std::fs::write(&t, bytes).unwrap();
    assert_ne!(reference_key(&here, &[]), reference_key(&load(dir.path()), &[]));
}
