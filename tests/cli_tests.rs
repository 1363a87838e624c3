//! End-to-end tests of the `scatterlab` binary: bad input of every kind gets one clear line
//! on stderr (`error: ` + the file or flag + the field + what is wrong), a non-zero exit, no
//! panic, and no output file (or temporary file) left behind; good input renders, compares,
//! lists devices and describes scenes. Every render runs with `--validate` (any validation
//! error fails the command) and is tiny (16x16, 4 spp) so the whole module stays fast on a
//! CPU driver.
//!
//! Each test, and each row of the tables of renders that must fail, works in its own
//! temporary folder: inputs (scenes, grids, images) at its top, outputs under `out/`. A
//! failing command must leave the folder exactly as it found it. Scenes are variants of the
//! base scene shared with scene_tests ([`SceneText`] in common.rs).

use std::ffi::OsStr;
use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use scatterlab::output::{read_exr, read_exr_layer, read_exr_metadata, read_pfm, read_png_text, write_exr, Image};
use scatterlab::scene::write_vol;

use crate::common::SceneText;

const BIN: &str = env!("CARGO_BIN_EXE_scatterlab");

/// Flags that keep every render tiny (the base scene has 4 spp; `--spp` is `path`'s only).
const TINY: [&str; 4] = ["--set", "render.width=16", "--set", "render.height=16"];

/// The shared base scene ([`SceneText::base`]) at the size [`TINY`] renders: 16x16, seed 3.
/// Tests write broken variants of it.
fn base() -> SceneText {
    SceneText::base().set("render.width", "16").set("render.height", "16").set("render.seed", "3")
}

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

/// Raw little-endian f32 bytes.
fn f32_bytes(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// A `.vol` file of `n^3` voxels, all 0.5 except voxel `bad_at` (if any), which is `bad`.
fn vol_bytes(n: u32, bad: Option<(usize, f32)>) -> Vec<u8> {
    let mut data = vec![0.5f32; (n * n * n) as usize];
    if let Some((i, v)) = bad {
        data[i] = v;
    }
    write_vol([n, n, n], &data, glam::Vec3::splat(-0.5), glam::Vec3::splat(0.5))
}

/// An image with a smooth, non-zero gradient (so relative errors are defined).
fn gradient(width: u32, height: u32) -> Image {
    let mut img = Image::new(width, height);
    for (i, v) in img.data.iter_mut().enumerate() {
        *v = 0.25 + (i % 7) as f32 * 0.1;
    }
    img
}

/// One test's temporary folder.
struct Case {
    dir: tempfile::TempDir,
}

impl Case {
    fn new() -> Case {
        let dir = tempfile::Builder::new().prefix("scatterlab-cli-").tempdir().expect("temp dir");
        fs::create_dir(dir.path().join("out")).expect("out dir");
        Case { dir }
    }

    fn path(&self, rel: &str) -> PathBuf {
        self.dir.path().join(rel)
    }

    /// Write an input file at the top of the folder.
    fn write(&self, name: &str, bytes: impl AsRef<[u8]>) -> PathBuf {
        let p = self.path(name);
        fs::write(&p, bytes).expect("write input");
        p
    }

    /// Write `scene.toml`.
    fn scene(&self, text: &str) -> PathBuf {
        self.write("scene.toml", text)
    }

    /// Copy the shipped 64^3 cloud grid next to the scene.
    fn cloud_grid(&self) -> PathBuf {
        let p = self.path("cloud64.vol");
        fs::copy(repo("scenes/cloud64.vol"), &p).expect("copy cloud64.vol");
        p
    }

    /// Every file and folder under the temporary folder, relative and sorted.
    fn listing(&self) -> Vec<String> {
        fn walk(root: &Path, dir: &Path, out: &mut Vec<String>) {
            for e in fs::read_dir(dir).expect("read_dir").flatten() {
                let p = e.path();
                out.push(p.strip_prefix(root).unwrap().display().to_string());
                if p.is_dir() {
                    walk(root, &p, out);
                }
            }
        }
        let mut out = Vec::new();
        walk(self.dir.path(), self.dir.path(), &mut out);
        out.sort();
        out
    }

    /// Run the binary in this folder (no device or validation choice from the environment).
    fn run<I, S>(&self, args: I) -> Output
    where
        I: IntoIterator<Item = S>,
        S: AsRef<OsStr>,
    {
        Command::new(BIN)
            .args(args)
            .current_dir(self.dir.path())
            .env_remove("SCATTERLAB_DEVICE")
            .env_remove("SCATTERLAB_VALIDATE")
            .env_remove("SCATTERLAB_QUEUES")
            .env("NO_COLOR", "1")
            .output()
            .expect("run scatterlab")
    }

    /// `render SCENE --validate -q --out out/x.exr --png out/x.png --json out/x.json EXTRA...`.
    fn render(&self, scene: &Path, extra: &[&str]) -> Output {
        self.run(self.render_args(scene, extra))
    }

    /// The arguments of [`Case::render`].
    fn render_args(&self, scene: &Path, extra: &[&str]) -> Vec<String> {
        let mut args: Vec<String> =
            vec!["render".into(), scene.display().to_string(), "--validate".into(), "-q".into()];
        for (flag, name) in [("--out", "out/x.exr"), ("--png", "out/x.png"), ("--json", "out/x.json")] {
            args.push(flag.into());
            args.push(self.path(name).display().to_string());
        }
        args.extend(extra.iter().map(|s| s.to_string()));
        args
    }

    /// Run `args`, expect [`one_error_line`] with `needles`, and expect the folder to be
    /// exactly as before (no output, no temporary file, no created folder). Returns the line.
    #[track_caller]
    fn fails<I, S>(&self, args: I, needles: &[&str]) -> String
    where
        I: IntoIterator<Item = S>,
        S: AsRef<OsStr>,
    {
        self.fails_with(|| self.run(args), needles, Cause::Once)
    }

    /// [`Case::render`] of `scene` with `extra`, expected to fail like [`Case::fails`].
    #[track_caller]
    fn render_fails(&self, scene: &Path, extra: &[&str], needles: &[&str]) -> String {
        self.fails_with(|| self.render(scene, extra), needles, Cause::Once)
    }

    #[track_caller]
    fn fails_with(&self, run: impl FnOnce() -> Output, needles: &[&str], cause: Cause) -> String {
        let before = self.listing();
        let out = run();
        let line = error_line(&out, needles, cause);
        self.unchanged(&before, &line);
        line
    }

    #[track_caller]
    fn unchanged(&self, before: &[String], line: &str) {
        let after = self.listing();
        assert_eq!(
            before,
            after.as_slice(),
            "the failed command changed the folder (outputs or temporary files left behind); its error: {line}"
        );
        for name in ["out/x.exr", "out/x.png", "out/x.json"] {
            assert!(!self.path(name).exists(), "{name} exists after a failed command");
        }
    }
}

/// How often an error line may name its cause: once (`...: No such file or directory (os
/// error 2): No such file or directory (os error 2)` fails).
#[derive(Clone, Copy, PartialEq)]
enum Cause {
    Once,
}

/// A part of an error line (between `: ` / `; `) long enough to mean something that occurs
/// twice: the message repeats its cause.
fn repeated_part(line: &str) -> Option<String> {
    let joined = line.replace("; ", ": ");
    let parts: Vec<&str> = joined.split(": ").map(str::trim).filter(|p| p.len() >= 12).collect();
    parts.iter().enumerate().find(|(i, p)| parts[i + 1..].contains(p)).map(|(_, p)| p.to_string())
}

/// [`error_line`] with [`Cause::Once`].
#[track_caller]
fn one_error_line(out: &Output, needles: &[&str]) -> String {
    error_line(out, needles, Cause::Once)
}

/// The command failed cleanly: a normal non-zero exit (not a signal, not a panic's 101),
/// stderr is exactly one non-empty line, it starts with `error: `, contains every needle,
/// and (with [`Cause::Once`]) says each thing once.
#[track_caller]
fn error_line(out: &Output, needles: &[&str], cause: Cause) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let code = out.status.code();
    assert!(code.is_some(), "killed by a signal ({:?}); stderr:\n{stderr}", out.status);
    assert_ne!(code, Some(0), "the command succeeded but should have failed; stdout:\n{stdout}\nstderr:\n{stderr}");
    assert!(!stderr.contains("panicked") && !stderr.contains("RUST_BACKTRACE"), "panic:\n{stderr}");
    assert_ne!(code, Some(101), "exit code 101 (a Rust panic); stderr:\n{stderr}");
    let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "expected exactly one line on stderr, got {}:\n{stderr}", lines.len());
    let line = lines[0];
    assert!(line.starts_with("error: "), "the line does not start with `error: `: {line}");
    for n in needles {
        assert!(line.contains(n), "the error line lacks {n:?}: {line}");
    }
    if cause == Cause::Once {
        if let Some(part) = repeated_part(line) {
            panic!("the error line repeats {part:?}: {line}");
        }
    }
    line.to_string()
}

/// The command succeeded, did not panic, and the validation layer printed no error.
#[track_caller]
fn succeeded(out: &Output) -> (String, String) {
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(0), "the command failed; stdout:\n{stdout}\nstderr:\n{stderr}");
    assert!(!stderr.contains("panicked"), "panic:\n{stderr}");
    assert!(!stderr.contains("validation error"), "validation errors:\n{stderr}");
    (stdout, stderr)
}

fn read_json(p: &Path) -> serde_json::Value {
    let text = fs::read_to_string(p).unwrap_or_else(|e| panic!("read {}: {e}", p.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{} is not JSON: {e}\n{text}", p.display()))
}

// ------------------------------------------------------------------ renders that must fail

/// One `render` that must fail as [`Case::render_fails`] checks (one `error: ` line with
/// every needle, a clean non-zero exit, the folder left as it was): a row of the tables
/// below, run in a folder of its own.
struct Fails {
    /// `what is tested/variant`, reported when the row fails.
    name: String,
    /// Written as `scene.toml`; `None` renders `nope.toml`, which does not exist.
    scene: Option<SceneText>,
    /// Input files written next to the scene.
    files: Vec<(&'static str, Vec<u8>)>,
    /// Copy the shipped `cloud64.vol` next to the scene.
    cloud_grid: bool,
    /// The arguments after the outputs: [`TINY`] unless the row says otherwise.
    args: Vec<&'static str>,
    /// What the one error line must contain.
    needles: Vec<&'static str>,
}

/// A row rendering `scene` with [`TINY`]; its error line must contain every needle.
fn fails(name: impl Into<String>, scene: SceneText, needles: &[&'static str]) -> Fails {
    Fails {
        name: name.into(),
        scene: Some(scene),
        files: Vec::new(),
        cloud_grid: false,
        args: TINY.to_vec(),
        needles: needles.to_vec(),
    }
}

impl Fails {
    /// Also write `bytes` as the input file `name`.
    fn file(mut self, name: &'static str, bytes: impl Into<Vec<u8>>) -> Fails {
        self.files.push((name, bytes.into()));
        self
    }

    /// Also copy the shipped `cloud64.vol` next to the scene.
    fn cloud_grid(mut self) -> Fails {
        self.cloud_grid = true;
        self
    }

    /// [`TINY`] and then `extra`.
    fn and_args(mut self, extra: &[&'static str]) -> Fails {
        self.args.extend_from_slice(extra);
        self
    }

    /// `args` instead of [`TINY`].
    fn only_args(mut self, args: &[&'static str]) -> Fails {
        self.args = args.to_vec();
        self
    }

    /// Render `nope.toml`, which does not exist, instead of a scene.
    fn without_scene_file(mut self) -> Fails {
        self.scene = None;
        self
    }

    fn check(&self) {
        let c = Case::new();
        for (name, bytes) in &self.files {
            c.write(name, bytes);
        }
        if self.cloud_grid {
            c.cloud_grid();
        }
        let scene = match &self.scene {
            Some(text) => c.scene(text),
            None => c.path("nope.toml"),
        };
        c.render_fails(&scene, &self.args, &self.needles);
    }
}

/// Check every row, each in a fresh folder, then fail naming every row that failed (with its
/// message), not just the first.
fn check_all(rows: Vec<Fails>) {
    let mut names: Vec<&str> = rows.iter().map(|r| r.name.as_str()).collect();
    names.sort();
    if let Some(w) = names.windows(2).find(|w| w[0] == w[1]) {
        panic!("test bug: two rows are named {:?}", w[0]);
    }
    let mut failed = Vec::new();
    for row in &rows {
        if let Err(e) = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| row.check())) {
            let msg = match (e.downcast_ref::<String>(), e.downcast_ref::<&str>()) {
                (Some(s), _) => s.clone(),
                (None, Some(s)) => s.to_string(),
                (None, None) => "(a panic without a message)".to_string(),
            };
            failed.push(format!("{}: {msg}", row.name));
        }
    }
    eprintln!("{} rows checked, {} failed", rows.len(), failed.len());
    assert!(failed.is_empty(), "{} of {} rows failed:\n\n{}", failed.len(), rows.len(), failed.join("\n\n"));
}

/// Scene files that are not TOML, name keys or kinds that do not exist, lack a key, or are
/// not there at all.
#[test]
fn render_rejects_malformed_scene_files() {
    check_all(vec![
        // Line 3 of the base is `width = 16`.
        fails("malformed_toml/line 3", base().set("render.width", "= 16"), &["scene.toml:3:", "malformed TOML"]),
        // An unterminated string on line 9 (`kind = "perspective"`).
        fails(
            "malformed_toml/unterminated string on line 9",
            base().set("camera.kind", "\"perspective"),
            &["scene.toml:9:", "malformed TOML"],
        ),
        fails(
            "malformed_toml/key given twice",
            base().insert_after("medium.albedo", "albedo = 0.7"),
            &["scene.toml:", "malformed TOML", "albedo"],
        ),
        // The last needle is the did-you-mean.
        fails(
            "unknown_key/medium.albdo",
            base().replace_line("medium.albedo", "albdo = 0.8"),
            &["scene.toml", "medium.albdo", "unknown key", "albedo"],
        ),
        fails(
            "unknown_key/light[0].intensty",
            base().insert_after("light.intensity", "intensty = 3.0"),
            &["scene.toml", "light[0].intensty", "unknown key"],
        ),
        fails(
            "unknown_key/table extra",
            base().append("\n[extra]\nfoo = 1\n"),
            &["scene.toml", "extra", "unknown key"],
        ),
        fails("missing_key/medium.albedo", base().remove("medium.albedo"), &["scene.toml", "medium.albedo", "missing"]),
        fails(
            "wrong_type/medium.albedo",
            base().set("medium.albedo", "\"high\""),
            &["scene.toml", "medium.albedo", "expected"],
        ),
        fails(
            "unknown_kind/light spot",
            base().set("light.kind", "\"spot\""),
            &["scene.toml", "light[0].kind", "spot"],
        ),
        fails("scene_file_missing", base(), &["nope.toml", "cannot read scene file", "No such file"])
            .without_scene_file(),
    ]);
}

/// Grid files that are missing, cut short, empty, of the wrong size for their dims, hold
/// NaN, infinite or negative densities, or are too large for the memory budget.
#[test]
fn render_rejects_bad_grid_files() {
    let cloud = fs::read(repo("scenes/cloud64.vol")).expect("cloud64.vol");
    let mut rows = vec![
        fails(
            "grid_file_missing",
            base().grid("nope.vol"),
            &["scene.toml", "medium.density.file", "nope.vol", "cannot open"],
        ),
        fails(
            "grid_file_truncated/data",
            base().grid("cut.vol"),
            &["scene.toml", "medium.density.file", "cut.vol", "truncated"],
        )
        .file("cut.vol", &cloud[..cloud.len() / 2]),
        fails(
            "grid_file_truncated/header",
            base().grid("cut.vol"),
            &["scene.toml", "medium.density.file", "cut.vol", "truncated .vol header"],
        )
        .file("cut.vol", &cloud[..20]),
        fails("grid_file_truncated/empty", base().grid("cut.vol"), &["scene.toml", "medium.density.file", "cut.vol"])
            .file("cut.vol", b""),
        // An empty (fully truncated) grid file should be called empty, not "not a .vol file
        // ... add dims" (which sends the user after the wrong fix).
        fails(
            "empty_grid_file_is_called_empty/0 bytes",
            base().grid("cut.vol"),
            &["scene.toml", "medium.density.file", "cut.vol", "empty"],
        )
        .file("cut.vol", b""),
        fails(
            "empty_grid_file_is_called_empty/2 bytes",
            base().grid("cut.vol"),
            &["scene.toml", "medium.density.file", "cut.vol", "truncated"],
        )
        .file("cut.vol", b"VO"),
        // 4x4x4 raw f32 needs 256 bytes; give 100.
        fails(
            "grid_dims_do_not_match_file_size/too few bytes",
            base().grid_with_dims("raw.f32", [4, 4, 4]),
            &["scene.toml", "medium.density.file", "raw.f32", "dims", "256 bytes", "100 bytes"],
        )
        .file("raw.f32", vec![0u8; 100]),
        fails(
            "grid_dims_do_not_match_file_size/too many bytes",
            base().grid_with_dims("raw.f32", [4, 4, 4]),
            &["scene.toml", "medium.density.file", "raw.f32", "extra bytes"],
        )
        .file("raw.f32", f32_bytes(&[0.5; 65])),
        fails(
            "grid_dims_do_not_match_file_size/raw without dims",
            base().grid("raw.f32"),
            &["scene.toml", "medium.density.file", "raw.f32", "dims"],
        )
        .file("raw.f32", f32_bytes(&[0.5; 65])),
        fails(
            "grid_dims_do_not_match_file_size/a zero dimension",
            base().grid_with_dims("raw.f32", [4, 0, 4]),
            &["scene.toml", "medium.density.file", "dims[1]"],
        )
        .file("raw.f32", f32_bytes(&[0.5; 65])),
        fails(
            "grid_dims_do_not_match_file_size/dims contradict the .vol header",
            base().grid_with_dims("cloud64.vol", [32, 32, 32]),
            &["scene.toml", "medium.density.file", "cloud64.vol", "disagrees", "64x64x64"],
        )
        .cloud_grid(),
    ];
    for (value, text) in [(f32::NAN, "NaN"), (f32::INFINITY, "inf"), (-1.0, "-1")] {
        // Voxel #5 of a 4^3 grid is (1, 1, 0).
        rows.push(
            fails(
                format!("grid_nan_inf_negative_density/vol {text}"),
                base().grid("bad.vol"),
                &["scene.toml", "medium.density.file", "bad.vol", "voxel (1, 1, 0)", text, "finite and >= 0"],
            )
            .file("bad.vol", vol_bytes(4, Some((5, value)))),
        );
    }
    // The same in a raw grid.
    let mut data = vec![0.5f32; 8];
    data[7] = f32::NAN;
    rows.push(
        fails(
            "grid_nan_inf_negative_density/raw NaN",
            base().grid_with_dims("bad.f32", [2, 2, 2]),
            &["scene.toml", "medium.density.file", "bad.f32", "voxel (1, 1, 1)", "NaN"],
        )
        .file("bad.f32", f32_bytes(&data)),
    );
    rows.push(
        fails(
            "grid_beyond_memory_budget/cloud under 1K",
            base().grid("cloud64.vol"),
            &["scene.toml", "medium.density.file", "cloud64.vol", "64x64x64", "memory budget", "--memory-budget"],
        )
        .cloud_grid()
        .and_args(&["--memory-budget", "1K"]),
    );
    // A hostile header claiming 4096^3 voxels (256 GiB) is refused before any voxel is read,
    // under the default budget.
    let mut header = write_vol([4096, 4096, 4096], &[], glam::Vec3::splat(-0.5), glam::Vec3::splat(0.5));
    header.extend(f32_bytes(&[0.5; 16]));
    rows.push(
        fails(
            "grid_beyond_memory_budget/hostile header",
            base().grid("huge.vol"),
            &["scene.toml", "medium.density.file", "huge.vol", "4096x4096x4096", "memory budget"],
        )
        .file("huge.vol", header),
    );
    // A damaged OpenVDB file: the reader panics inside (caught), and its panic message must not
    // reach stderr before the one error line (one byte of the shipped explosion changed).
    let mut vdb = fs::read(repo("scenes/explosion.vdb")).expect("explosion.vdb");
    vdb[217] = 0xa7;
    rows.push(
        fails(
            "grid_vdb_damaged",
            base().density("{ kind = \"vdb\", file = \"bad.vdb\" }"),
            &["scene.toml", "medium.density.file", "bad.vdb", "damaged or unsupported OpenVDB"],
        )
        .file("bad.vdb", vdb),
    );
    check_all(rows);
}

/// Values out of range: albedo, g, sigma_t, light intensity, image size, spp, no lights, a
/// camera that sees nothing.
#[test]
fn render_rejects_bad_scene_values() {
    let mut rows = Vec::new();
    for (value, shown) in [("1.5", "1.5"), ("-0.1", "-0.1"), ("[0.5, 1.2, 0.5]", "1.2")] {
        rows.push(fails(
            format!("albedo_outside_unit_interval/{value}"),
            base().set("medium.albedo", value),
            &["scene.toml", "medium.albedo", shown, "outside [0, 1]"],
        ));
    }
    rows.push(fails(
        "albedo_outside_unit_interval/nan",
        base().set("medium.albedo", "nan"),
        &["scene.toml", "medium.albedo", "NaN"],
    ));
    for value in ["1.0", "-1.0", "1.5", "inf"] {
        rows.push(fails(
            format!("g_magnitude_one_or_more/{value}"),
            base().set("medium.g", value),
            &["scene.toml", "medium.g", "(-1, 1)"],
        ));
    }
    for value in ["-1.0", "[1.0, -2.0, 1.0]", "nan", "inf"] {
        rows.push(fails(
            format!("sigma_t_negative_or_not_finite/{value}"),
            base().set("medium.sigma_t", value),
            &["scene.toml", "medium.sigma_t", "finite and >= 0"],
        ));
    }
    // Each value finite and in range, their products past what 32-bit floats hold: refused at
    // load naming the value (six solvers wrote images of NaN pixels set to 0 and exited 0).
    let huge = write_vol([2, 2, 2], &[3e38; 8], glam::Vec3::splat(-0.5), glam::Vec3::splat(0.5));
    rows.extend([
        fails("magnitude/sigma_t", base().set("medium.sigma_t", "3e38"), &["medium.sigma_t", "optical thickness"]),
        fails("magnitude/density grid", base().grid("huge.vol"), &["medium.sigma_t", "3e38", "optical thickness"])
            .file("huge.vol", huge),
        fails(
            "magnitude/emission x scale",
            base().insert_after("medium.g", "emission = 1e30\nemission_scale = 1e30"),
            &["medium.emission", "emitted radiance"],
        ),
        fails("magnitude/light", base().set("light.intensity", "3e38"), &["light[0].intensity", "3e38", "past 1e15"]),
        fails(
            "magnitude/coordinates",
            base().set("camera.origin", "[0.0, 0.0, 1e30]"),
            &["camera.origin", "1e30", "larger units"],
        ),
    ]);
    rows.extend([
        fails(
            "negative_light_intensity",
            base().set("light.intensity", "-10.0"),
            &["scene.toml", "light[0].intensity", "finite and >= 0"],
        ),
        // In the file (no --set overriding it).
        fails(
            "zero_size_image/width = 0",
            base().set("render.width", "0"),
            &["scene.toml", "render.width", "out of range"],
        )
        .only_args(&["--spp", "4"]),
        fails(
            "zero_size_image/height = 0",
            base().set("render.height", "0"),
            &["scene.toml", "render.height", "out of range"],
        )
        .only_args(&["--spp", "4"]),
        fails(
            "zero_size_image/width = -5",
            base().set("render.width", "-5"),
            &["scene.toml", "render.width", "out of range"],
        )
        .only_args(&["--spp", "4"]),
        // From --set: the message says the value came from the override.
        fails(
            "zero_size_image/--set render.width=0",
            base(),
            &["scene.toml", "render.width", "out of range", "override"],
        )
        .only_args(&["--set", "render.width=0", "--spp", "4"]),
        // Zero samples per pixel: the message names the flag the user typed.
        fails("zero_size_image/--spp 0", base(), &["--spp 0", "at least 1"]).only_args(&["--spp", "0"]),
        fails("no_lights", base().without_light(), &["scene.toml", "light", "no lights"]),
        // Looking away from the medium.
        fails(
            "camera_that_sees_nothing/looking away",
            base().set("camera.target", "[0.0, 0.0, 8.0]"),
            &["scene.toml", "camera", "sees no part of the medium"],
        ),
        // Looking past it with a narrow view.
        fails(
            "camera_that_sees_nothing/looking past",
            base().set("camera.target", "[5.0, 0.0, 0.0]").set("camera.fov", "5.0"),
            &["scene.toml", "camera", "sees no part of the medium"],
        ),
        // No view direction at all.
        fails(
            "camera_that_sees_nothing/target at the origin",
            base().set("camera.target", "[0.0, 0.0, 4.0]"),
            &["scene.toml", "camera.target", "equals camera.origin"],
        ),
        // Up along the view.
        fails(
            "camera_that_sees_nothing/up along the view",
            base().set("camera.up", "[0.0, 0.0, 1.0]"),
            &["scene.toml", "camera.up", "parallel"],
        ),
        // Field of view out of range.
        fails(
            "camera_that_sees_nothing/fov 180",
            base().set("camera.fov", "180.0"),
            &["scene.toml", "camera.fov", "(0, 180)"],
        ),
    ]);
    check_all(rows);
}

/// Bad flags on a good scene: --memory-budget, --set (unknown keys, syntax, values, a knob of
/// the other solver), --device.
#[test]
fn render_rejects_bad_flags() {
    check_all(vec![
        fails("memory_budget_syntax/lots", base(), &["--memory-budget", "lots"]).and_args(&["--memory-budget", "lots"]),
        fails("memory_budget_syntax/0", base(), &["--memory-budget", "positive"]).and_args(&["--memory-budget", "0"]),
        // A camera-ray step whose shadow rays (their step defaults to it) would take too many:
        // the step is named, not a shadow_step nobody set.
        fails("view_step_too_fine/single", base(), &["single.step", "shadow rays"]).and_args(&[
            "--solver",
            "single",
            "--set",
            "single.step=1e-6",
        ]),
        // Knobs that size one binding past the device's largest: the knob is named with the
        // largest value that fits (the buffer's own line named neither).
        fails("binding_too_large/networks.window", base(), &["networks.window=", "or less", "largest binding"])
            .and_args(&["--solver", "networks", "--set", "networks.window=2048", "--set", "networks.particles=64"]),
        fails("binding_too_large/wavefront.grid", base(), &["wavefront.grid=", "or less", "largest binding"])
            .and_args(&["--solver", "wavefront", "--set", "wavefront.grid=1024"]),
        // A photon-marching step finer than a thousandth of a voxel (1e-9 marched for minutes).
        fails("march_step_too_fine/lbl", base(), &["lbl.step", "thousandth of a voxel"]).and_args(&[
            "--solver",
            "lbl",
            "--set",
            "lbl.step=1e-9",
        ]),
        fails("march_step_too_fine/dom", base(), &["dom.step", "thousandth of a voxel"]).and_args(&[
            "--solver",
            "dom",
            "--set",
            "dom.step=1e-9",
        ]),
        // The last needle is the did-you-mean.
        fails("unknown_set_keys/medium.albdo", base(), &["scene.toml", "medium.albdo", "unknown key", "albedo"])
            .and_args(&["--set", "medium.albdo=1"]),
        fails("unknown_set_keys/path.nope", base(), &["--set path.nope", "unknown knob", "path", "max_depth"])
            .and_args(&["--set", "path.nope=1"]),
        fails("unknown_set_keys/path.maxdepth", base(), &["--set path.maxdepth", "did you mean path.max_depth?"])
            .and_args(&["--set", "path.maxdepth=3"]),
        fails("unknown_set_keys/single.step", base(), &["--set single.step", "solver single", "solver path"])
            .and_args(&["--set", "single.step=0.01"]),
        fails("unknown_set_keys/nope", base(), &["--set nope", "unknown key"]).and_args(&["--set", "nope=1"]),
        fails("unknown_set_keys/mesh.file", base(), &["--set mesh.file", "unknown key"])
            .and_args(&["--set", "mesh.file=1"]),
        fails("unknown_set_keys/light[3]", base(), &["scene.toml", "light[3]", "does not exist"])
            .and_args(&["--set", "light[3].intensity=1"]),
        // The other way round: a path knob while rendering with single.
        fails(
            "unknown_set_keys/path knob with single",
            base(),
            &["--set path.max_depth", "solver path", "solver single"],
        )
        .and_args(&["--solver", "single", "--set", "path.max_depth=1"]),
        fails("bad_set_syntax/no =", base(), &["--set", "medium.albedo", "KEY=VALUE"])
            .and_args(&["--set", "medium.albedo"]),
        fails("bad_set_syntax/no key", base(), &["--set", "KEY=VALUE"]).and_args(&["--set", "=0.5"]),
        fails("bad_set_syntax/not a TOML value", base(), &["scene.toml", "medium.albedo", "not a TOML value"])
            .and_args(&["--set", "medium.albedo=[0.5,"]),
        fails(
            "bad_set_syntax/value out of range",
            base(),
            &["scene.toml", "medium.albedo", "outside [0, 1]", "override"],
        )
        .and_args(&["--set", "medium.albedo=2"]),
        fails("bad_set_syntax/path.max_depth=lots", base(), &["--set path.max_depth", "unbounded"])
            .and_args(&["--set", "path.max_depth=lots"]),
        fails("bad_set_syntax/path.batch=lots", base(), &["--set path.batch", "not an integer", "lots"])
            .and_args(&["--set", "path.batch=lots"]),
        // A solver knob that does not parse should show the value it got.
        fails("bad_solver_knob_value_is_shown", base(), &["--set path.max_depth", "lots", "unbounded"])
            .and_args(&["--set", "path.max_depth=lots"]),
        // Solver flags stand for knobs: a solver without the knob is told which have it.
        fails("solver_flags/max-depth with lbl", base(), &["--max-depth", "max_depth knob", "(path)", "lbl"])
            .and_args(&["--solver", "lbl", "--max-depth", "2"]),
        fails(
            "solver_flags/schedule with wavefront",
            base(),
            &["--schedule", "schedule knob", "(path, lbl)", "wavefront"],
        )
        .and_args(&["--solver", "wavefront", "--schedule", "sequential"]),
        fails("solver_flags/deterministic with single", base(), &["--deterministic", "(lbl)", "single"]).and_args(&[
            "--solver",
            "single",
            "--deterministic",
        ]),
        fails("solver_flags/compare-schedules with wavefront", base(), &["--compare-schedules", "(path, lbl, dom)"])
            .and_args(&["--solver", "wavefront", "--compare-schedules"]),
        // A knob out of its range, and one of a mode the render does not use.
        fails("knob_range/lbl.grid=1", base(), &["--set lbl.grid", "2..=512", "scatterlab knobs lbl"]).and_args(&[
            "--solver",
            "lbl",
            "--set",
            "lbl.grid=1",
        ]),
        fails("knob_unused/lbl.wavefront_nu", base(), &["--set lbl.wavefront_nu", "does not use", "warm_start"])
            .and_args(&["--solver", "lbl", "--set", "lbl.wavefront_nu=16", "--set", "lbl.grid=8"]),
        fails("knob_renamed/path.spp", base(), &["--set path.spp", "render.spp"]).and_args(&["--set", "path.spp=8"]),
        fails("device_that_does_not_exist/name", base(), &["--device", "nonexistent", "available"])
            .and_args(&["--device", "nonexistent"]),
        fails("device_that_does_not_exist/index", base(), &["--device", "99", "available"])
            .and_args(&["--device", "99"]),
    ]);
}

// ------------------------------------------------------------------ outputs and devices

#[test]
fn no_output_requested() {
    let c = Case::new();
    let s = c.scene(&base());
    c.fails(
        [&["render", s.to_str().unwrap(), "--validate", "-q"][..], &TINY[..]].concat(),
        &["no output requested", "--out"],
    );
}

#[test]
fn output_directory_missing() {
    let c = Case::new();
    let s = c.scene(&base());
    for (flag, name) in [("--out", "x.exr"), ("--png", "x.png"), ("--json", "x.json")] {
        let p = c.path(&format!("missing/{name}"));
        c.fails(
            [&["render", s.to_str().unwrap(), "--validate", "-q", flag, p.to_str().unwrap()][..], &TINY[..]].concat(),
            &[flag, "missing", "does not exist"],
        );
    }
    // With the other outputs valid, nothing is written either.
    let p = c.path("missing/x.json");
    let out = c.path("out/x.exr");
    c.fails(
        [
            &[
                "render",
                s.to_str().unwrap(),
                "--validate",
                "-q",
                "--out",
                out.to_str().unwrap(),
                "--json",
                p.to_str().unwrap(),
            ][..],
            &TINY[..],
        ]
        .concat(),
        &["--json", "missing", "does not exist"],
    );
}

/// The environment variables the GPU options read: a value one cannot take is one line naming
/// the variable (set long ago and forgotten, it is not the flag the user did not type), before
/// any work, and nothing is written. SCATTERLAB_VALIDATE=banana used to turn validation on,
/// SCATTERLAB_QUEUES=bogus and SCATTERLAB_DEVICE=bogus were reported as `--queues` and
/// `--device`, and a loader that finds no driver gave vkCreateInstance's code without advice.
#[test]
fn environment_values_are_checked_and_named() {
    let c = Case::new();
    let s = c.scene(&base());
    let with_env = |var: &str, value: &str, args: Vec<String>| {
        Command::new(BIN)
            .args(args)
            .current_dir(c.dir.path())
            .env_remove("SCATTERLAB_DEVICE")
            .env_remove("SCATTERLAB_VALIDATE")
            .env_remove("SCATTERLAB_QUEUES")
            .env(var, value)
            .env("NO_COLOR", "1")
            .output()
            .expect("run scatterlab")
    };
    for (var, value, needles) in [
        ("SCATTERLAB_VALIDATE", "banana", &["SCATTERLAB_VALIDATE=banana", "expected 1", "unset"][..]),
        ("SCATTERLAB_QUEUES", "bogus", &["SCATTERLAB_QUEUES=bogus", "not a queue mapping", "separate-families"]),
        ("SCATTERLAB_DEVICE", "bogus", &["no Vulkan device matches SCATTERLAB_DEVICE=bogus", "available: 0: "]),
        ("SCATTERLAB_GPU_TIMEOUT", "5m", &["SCATTERLAB_GPU_TIMEOUT=5m", "positive number of seconds"]),
        ("SCATTERLAB_SPECIALIZE", "drvier", &["SCATTERLAB_SPECIALIZE=drvier", "driver or host"]),
        (
            "VK_DRIVER_FILES",
            "/nonexistent/icd.json",
            &["no Vulkan driver found", "VK_DRIVER_FILES=/nonexistent/icd.json", "mesa-vulkan-drivers"],
        ),
    ] {
        let line = c.fails_with(|| with_env(var, value, c.render_args(&s, &TINY)), needles, Cause::Once);
        assert!(!line.contains("--queues") && !line.contains("--device"), "{var}: {line}");
    }
    // `devices` names the variable too.
    let out = with_env("SCATTERLAB_DEVICE", "bogus", vec!["devices".into()]);
    error_line(&out, &["no Vulkan device matches SCATTERLAB_DEVICE=bogus"], Cause::Once);
    // So does `--device auto` that resolves from a variable: the variable, not `--device bogus`
    // (which the user never typed).
    let mut args = c.render_args(&s, &TINY);
    args.extend(["--device".into(), "auto".into()]);
    let line = c.fails_with(
        || with_env("SCATTERLAB_DEVICE", "bogus", args.clone()),
        &["SCATTERLAB_DEVICE=bogus"],
        Cause::Once,
    );
    assert!(!line.contains("--device bogus"), "{line}");
    let line = c.fails_with(
        || with_env("CUDA_VISIBLE_DEVICES", "GPU-00000000-dead", args.clone()),
        &["no Vulkan device matches CUDA_VISIBLE_DEVICES=uuid:GPU-00000000-dead"],
        Cause::Once,
    );
    assert!(!line.contains("--device"), "{line}");
    // A mapping the device cannot give, asked for by the variable, names the variable.
    let gpu = crate::common::gpu();
    let fams = gpu.info().queue_families.clone();
    for choice in ["same-family", "separate-families"] {
        if scatterlab::gpu::map_roles_as(&fams, scatterlab::gpu::QueueChoice::parse(choice).unwrap()).is_err() {
            c.fails_with(
                || with_env("SCATTERLAB_QUEUES", choice, c.render_args(&s, &TINY)),
                &[&format!("SCATTERLAB_QUEUES={choice}: device"), "cannot"],
                Cause::Once,
            );
        }
    }
    // The values it takes still run: 0 and `true` (any case) for validation.
    for value in ["0", "TRUE"] {
        succeeded(&with_env("SCATTERLAB_VALIDATE", value, c.render_args(&s, &TINY)));
    }
}

/// Where stderr is not a terminal (here: a pipe) no progress bar is drawn: plain progress lines
/// at most every `--progress-every` seconds (0: every update) keep a long render from being
/// silent in a CI log or a batch job's file; the default (30 s) prints none on a quick render,
/// and `-q` none at all.
#[test]
fn progress_lines_where_stderr_is_not_a_terminal() {
    let c = Case::new();
    let s = c.scene(&base());
    let args = |extra: &[&str]| -> Vec<String> {
        let mut v: Vec<String> = c.render_args(&s, &TINY).into_iter().filter(|a| a != "-q").collect();
        v.extend(["--solver", "dom", "--set", "dom.grid=16"].iter().map(|x| x.to_string()));
        v.extend(extra.iter().map(|x| x.to_string()));
        v
    };
    let (_, stderr) = succeeded(&c.run(args(&["--progress-every", "0"])));
    let lines: Vec<&str> = stderr.lines().filter(|l| l.starts_with("progress: dom ")).collect();
    assert!(lines.len() >= 2, "{stderr}");
    assert!(lines.iter().any(|l| l.contains("scattering iterations") && l.contains("tolerance")), "{stderr}");
    assert!(lines.iter().all(|l| l.ends_with(" s)")), "{stderr}");
    let (_, stderr) = succeeded(&c.run(args(&[])));
    assert!(!stderr.contains("progress:"), "a quick render within 30 s: {stderr}");
    // `single` is one resumable pass: its lines count the pixels finished, submission by
    // submission (a budget of 16 loop iterations a dispatch takes several).
    let mut single: Vec<String> = c.render_args(&s, &TINY).into_iter().filter(|a| a != "-q").collect();
    single.extend(["--solver", "single", "--set", "single.budget=16", "--progress-every", "0"].map(String::from));
    let (_, stderr) = succeeded(&c.run(single));
    let counts: Vec<(u64, u64)> = stderr
        .lines()
        .filter_map(|l| l.strip_prefix("progress: single "))
        .filter_map(|l| l.split("view pass: pixels ").nth(1))
        .filter_map(|l| l.split(' ').next())
        .filter_map(|f| f.split_once('/'))
        .map(|(a, b)| (a.parse().unwrap(), b.parse().unwrap()))
        .collect();
    assert!(counts.iter().all(|(_, n)| *n == 256), "{stderr}");
    assert!(counts.windows(2).all(|w| w[0].0 <= w[1].0), "pixels done never fall: {counts:?}");
    assert!(counts.iter().any(|(k, n)| *k > 0 && k < n), "a line between the start and the end: {stderr}");
    assert_eq!(counts.last(), Some(&(256, 256)), "{stderr}");
    let (_, stderr) = succeeded(&c.run(args(&["--progress-every", "0", "-q"])));
    assert!(!stderr.contains("progress:"), "{stderr}");
    let out = c.run(args(&["--progress-every", "nan"]));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "a usage error: {stderr}");
    assert!(stderr.contains("--progress-every") && stderr.contains("seconds >= 0"), "{stderr}");
}

/// `--queues`: a mapping the device cannot give is one line naming the flag, the device and
/// its families, and nothing is written; one it can give is used and reported.
#[test]
fn queue_mapping_is_forced_or_refused_in_one_line() {
    let c = Case::new();
    let s = c.scene(&base());
    let gpu = crate::common::gpu();
    let fams = gpu.info().queue_families.clone();
    for choice in ["same-family", "separate-families"] {
        match scatterlab::gpu::map_roles_as(&fams, scatterlab::gpu::QueueChoice::parse(choice).unwrap()) {
            // lavapipe (one family, one queue): refused before any work.
            Err(_) => {
                c.render_fails(
                    &s,
                    &[&["--queues", choice][..], &TINY[..]].concat(),
                    &[&format!("--queues {choice}"), "cannot", "use --queues auto or shared"],
                );
            }
            Ok(m) => {
                let out = c.render(&s, &[&["--queues", choice][..], &TINY[..]].concat());
                succeeded(&out);
                let doc = read_json(&c.path("out/x.json"));
                assert_eq!(doc["device"]["mapping"]["diffuse"]["family"], m.diffuse.family, "{choice}");
            }
        }
    }
    // `devices` shows the asked mapping beside the automatic one, or why there is none.
    let (stdout, _) = succeeded(&c.run(["devices", "--queues", "same-family"]));
    assert!(stdout.contains("roles with --queues same-family: "), "{stdout}");
    let out = c.render(&s, &[&["--queues", "shared"][..], &TINY[..]].concat());
    succeeded(&out);
    let doc = read_json(&c.path("out/x.json"));
    assert_eq!(doc["device"]["mapping"]["kind"], "shared");
    assert_eq!(doc["device"]["mapping"]["trace"], doc["device"]["mapping"]["transfer"]);
}

#[test]
fn output_with_wrong_extension() {
    let c = Case::new();
    let s = c.scene(&base());
    for (flag, name, want) in [
        ("--out", "out/x.jpg", ".jpg is not an image format"),
        ("--png", "out/x.jpg", ".png"),
        ("--json", "out/x.txt", ".json"),
        ("--out", "out/x", "no extension"),
    ] {
        let p = c.path(name);
        c.fails(
            [&["render", s.to_str().unwrap(), "--validate", "-q", flag, p.to_str().unwrap()][..], &TINY[..]].concat(),
            &[flag, name, want],
        );
    }
}

/// `--out` picks the format by extension, as pbrt and Mitsuba do: EXR, PNG and PFM of one
/// deterministic render hold the same image (PFM bit-exact against EXR).
#[test]
fn out_format_follows_the_extension() {
    let c = Case::new();
    let s = c.scene(&base());
    for name in ["out/x.exr", "out/x.pfm", "out/y.png"] {
        let p = c.path(name);
        succeeded(
            &c.run(
                [&["render", s.to_str().unwrap(), "--validate", "-q", "--out", p.to_str().unwrap()][..], &TINY[..]]
                    .concat(),
            ),
        );
    }
    let exr = read_exr(&c.path("out/x.exr")).expect("EXR");
    let pfm = read_pfm(&c.path("out/x.pfm")).expect("PFM");
    assert_eq!((pfm.width, pfm.height), (16, 16));
    assert_eq!(exr.data, pfm.data, "PFM and EXR of one render differ");
    let png = image::open(c.path("out/y.png")).expect("PNG decodes").to_rgb8();
    assert_eq!(png.dimensions(), (16, 16));
    assert!(png.pixels().any(|p| p.0 != [0, 0, 0]), "PNG is black");
    // Two outputs on one name would overwrite each other.
    let c = Case::new();
    let s = c.scene(&base());
    let same = c.path("out/z.png");
    c.fails(
        [&["render", s.to_str().unwrap(), "-q", "--out", same.to_str().unwrap(), "--png", same.to_str().unwrap()][..],
            &TINY[..]]
            .concat(),
        &["--out", "--png", "z.png", "own file"],
    );
}

/// `--spp` sets the quality of solvers that sample pixels; the others refuse it (as they do
/// `--max-depth`) rather than ignore it.
#[test]
fn spp_is_refused_where_nothing_is_sampled() {
    let c = Case::new();
    let s = c.scene(&base());
    for solver in ["single", "lbl", "wavefront", "octaves"] {
        c.render_fails(&s, &[&TINY[..], &["--solver", solver, "--spp", "8"]].concat(), &["--spp", "(path)", solver]);
    }
}

/// Provenance: the JSON report, the EXR header and the PNG text chunks name the scene, its
/// content digest, every override as given, the solver, seed and spp. The digest follows the
/// scene's content: the same scene under other overrides keeps it, a changed grid file
/// changes it.
#[test]
fn outputs_carry_provenance() {
    let c = Case::new();
    c.write("g.vol", vol_bytes(4, None));
    let s = c.scene(&base().grid("g.vol"));
    let render = |extra: &[&str]| {
        succeeded(&c.render(&s, &[&TINY[..], extra].concat()));
        read_json(&c.path("out/x.json"))["provenance"].clone()
    };
    let p = render(&["--set", "medium.albedo=0.123", "--seed", "5", "--spp", "2"]);
    let overrides: Vec<&str> =
        p["overrides"].as_array().expect("overrides").iter().filter_map(|v| v.as_str()).collect();
    for want in ["render.width=16", "medium.albedo=0.123", "render.spp=2", "render.seed=5"] {
        assert!(overrides.contains(&want), "{want} missing from {overrides:?}");
    }
    assert_eq!((p["solver"].as_str(), p["seed"].as_u64(), p["spp"].as_u64()), (Some("path"), Some(5), Some(2)), "{p}");
    assert!(p["scene"].as_str().is_some_and(|n| n.ends_with("scene.toml")), "{p}");
    let hash = p["scene_hash"].as_str().expect("scene_hash").to_string();
    assert!(hash.len() == 64 && hash.chars().all(|ch| ch.is_ascii_hexdigit()), "{hash}");
    assert!(p["engine"].as_str().is_some_and(|e| e.starts_with("scatterlab ")), "{p}");

    let exr_meta = read_exr_metadata(&c.path("out/x.exr")).expect("EXR header");
    let png_text = read_png_text(&c.path("out/x.png")).expect("PNG text");
    for (what, pairs) in [("EXR", &exr_meta), ("PNG", &png_text)] {
        let get = |k: &str| pairs.iter().find(|(key, _)| key == k).map(|(_, v)| v.as_str());
        assert_eq!(get("scatterlab.scene_hash"), Some(hash.as_str()), "{what}: {pairs:?}");
        assert!(get("scatterlab.overrides").is_some_and(|o| o.lines().any(|l| l == "medium.albedo=0.123")), "{what}");
        assert_eq!(get("scatterlab.solver"), Some("path"), "{what}");
        assert_eq!(get("scatterlab.seed"), Some("5"), "{what}");
        assert_eq!(get("scatterlab.spp"), Some("2"), "{what}");
    }

    // Same content, other overrides: same digest. A solver without samples records none.
    let q = render(&["--solver", "single"]);
    assert_eq!(q["scene_hash"].as_str(), Some(hash.as_str()), "{q}");
    assert!(q["spp"].is_null(), "single records spp: {q}");
    // One voxel of the grid changed, scene text unchanged: another digest.
    c.write("g.vol", vol_bytes(4, Some((5, 0.25))));
    let r = render(&[]);
    assert_ne!(r["scene_hash"].as_str(), Some(hash.as_str()), "the digest ignores the grid data");
}

/// A write that fails at the filesystem names the user's file and the OS error, never a
/// temporary name of ours, and suggests what to check about the place, not the file's
/// format (/proc takes no new files, even from root).
#[test]
fn failed_writes_name_the_users_file() {
    let c = Case::new();
    let s = c.scene(&base());
    for (flag, name) in [
        ("--out", "/proc/scatterlab-x.exr"),
        ("--png", "/proc/scatterlab-x.png"),
        ("--json", "/proc/scatterlab-x.json"),
    ] {
        let line = c.fails(
            [&["render", s.to_str().unwrap(), "-q", flag, name][..], &TINY[..]].concat(),
            &[name, "os error", "writable"],
        );
        for bad in ["partial", ".tmp", "uncorrupted", "/proc/."] {
            assert!(!line.contains(bad), "{flag}: the error names a temporary file or the wrong cause: {line}");
        }
    }
}

/// Outputs are the user's files: created as `File::create` would (0666 less the umask), not
/// with the private 0600 of a temporary file (images came out unreadable to the group).
#[cfg(unix)]
#[test]
fn outputs_have_the_permissions_of_an_ordinary_file() {
    use std::os::unix::fs::PermissionsExt;
    let c = Case::new();
    let s = c.scene(&base());
    let (exr, png, json) = (c.path("out.exr"), c.path("out.png"), c.path("out.json"));
    let out = c.run(
        [
            &["render", s.to_str().unwrap(), "-q", "--out", exr.to_str().unwrap(), "--png", png.to_str().unwrap()][..],
            &["--json", json.to_str().unwrap()],
            &TINY[..],
        ]
        .concat(),
    );
    succeeded(&out);
    let ordinary = c.write("ordinary", b"x");
    let mode = |p: &Path| fs::metadata(p).unwrap().permissions().mode() & 0o777;
    for p in [&exr, &png, &json] {
        assert_eq!(mode(p), mode(&ordinary), "{}: mode {:o}", p.display(), mode(p));
    }
}

/// A scene's `render.exposure` is the tone-mapped outputs' default; `--exposure` overrides it;
/// a value outside -64 ..= 64 stops is the scene's error.
#[test]
fn scene_exposure_is_the_png_default() {
    let c = Case::new();
    let s = c.scene(&base().set("render.spp", "4\nexposure = -2.5"));
    let exposure_of = |extra: &[&str]| {
        succeeded(&c.render(&s, &[&TINY[..], extra].concat()));
        let text = read_png_text(&c.path("out/x.png")).expect("PNG text");
        text.iter().find(|(k, _)| k == "scatterlab.exposure").map(|(_, v)| v.clone()).expect("exposure chunk")
    };
    assert_eq!(exposure_of(&[]), "-2.5");
    assert_eq!(exposure_of(&["--exposure", "1"]), "1");
    let c = Case::new();
    let bad = c.scene(&base().set("render.spp", "4\nexposure = 100"));
    c.fails(
        [&["render", bad.to_str().unwrap(), "-q", "--png", c.path("out/y.png").to_str().unwrap()][..], &TINY[..]]
            .concat(),
        &["scene.toml", "render.exposure", "-64 ..= 64"],
    );
}

/// `bench --points` past a ladder's end, or malformed, is refused before any work (no
/// output folder, no device).
#[test]
fn bench_points_are_checked_first() {
    let c = Case::new();
    let s = c.scene(&base());
    let out = c.path("out/bench");
    let bench = |points: &str| {
        vec![
            "bench".to_string(),
            s.display().to_string(),
            "--solvers".into(),
            "path".into(),
            "--points".into(),
            points.into(),
            "--out".into(),
            out.display().to_string(),
        ]
    };
    c.fails(bench("2,9"), &["--points 2,9", "solver path", "5 rungs"]);
    c.fails(bench("0"), &["--points 0", "rung number"]);
}

/// Errors whose cause is an I/O or decoder error must say it once. Today the scene-file and
/// EXR errors embed their source in their own message and the CLI appends the source chain
/// (`{e:#}`) again, e.g. `nope.toml: cannot read scene file: No such file or directory (os
/// error 2): No such file or directory (os error 2)`.
#[test]
fn errors_name_their_cause_once() {
    let c = Case::new();
    let args = c.render_args(&c.path("nope.toml"), &TINY);
    c.fails(args, &["nope.toml", "cannot read scene file", "No such file"]);
    let missing = c.path("nope.toml");
    c.fails(["scene", "info", missing.to_str().unwrap()], &["nope.toml", "cannot read scene file"]);
    let a = c.path("a.exr");
    write_exr(&a, &[("", &gradient(8, 8))]).expect("write a.exr");
    let missing = c.path("missing.exr");
    c.fails(["compare", a.to_str().unwrap(), missing.to_str().unwrap()], &["missing.exr", "No such file"]);
    let junk = c.write("junk.exr", "this is not an image\n");
    c.fails(["compare", junk.to_str().unwrap(), a.to_str().unwrap()], &["junk.exr", "EXR"]);
}

/// An output that can only fail when written (a folder sits where the JSON should go): the
/// images written before it must not stay behind as if the render had succeeded.
#[test]
fn late_output_failure_leaves_nothing_behind() {
    let c = Case::new();
    let s = c.scene(&base());
    fs::create_dir(c.path("out/x.json")).expect("dir");
    let before = c.listing();
    let out = c.render(&s, &TINY);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(before, c.listing(), "outputs or temporary files left behind after: {stderr}");
    one_error_line(&out, &["x.json"]);
}

#[test]
fn devices_with_device_that_does_not_exist() {
    let c = Case::new();
    c.fails(["devices", "--device", "nonexistent"], &["--device", "nonexistent"]);
}

// ------------------------------------------------------------------ compare

#[test]
fn compare_missing_file() {
    let c = Case::new();
    let a = c.path("a.exr");
    write_exr(&a, &[("", &gradient(8, 8))]).expect("write a.exr");
    let missing = c.path("missing.exr");
    c.fails(["compare", a.to_str().unwrap(), missing.to_str().unwrap()], &["missing.exr", "No such file"]);
    c.fails(["compare", missing.to_str().unwrap(), a.to_str().unwrap()], &["missing.exr", "No such file"]);
    // Not an EXR at all.
    let junk = c.write("junk.exr", "this is not an image\n");
    c.fails(["compare", junk.to_str().unwrap(), a.to_str().unwrap()], &["junk.exr", "EXR"]);
}

#[test]
fn compare_images_of_different_sizes_names_the_files() {
    let c = Case::new();
    let a = c.path("a.exr");
    let b = c.path("b.exr");
    write_exr(&a, &[("", &gradient(16, 16))]).expect("write a.exr");
    write_exr(&b, &[("", &gradient(8, 8))]).expect("write b.exr");
    c.fails(["compare", a.to_str().unwrap(), b.to_str().unwrap()], &["a.exr", "b.exr", "16x16", "8x8"]);
}

#[test]
fn compare_images_of_different_sizes() {
    let c = Case::new();
    let a = c.path("a.exr");
    let b = c.path("b.exr");
    write_exr(&a, &[("", &gradient(16, 16))]).expect("write a.exr");
    write_exr(&b, &[("", &gradient(8, 8))]).expect("write b.exr");
    let err = c.path("out/err.png");
    c.fails(
        ["compare", a.to_str().unwrap(), b.to_str().unwrap(), "--error-png", err.to_str().unwrap()],
        &["16x16", "8x8", "same resolution"],
    );
}

#[test]
fn compare_error_png_bad_path() {
    let c = Case::new();
    let a = c.path("a.exr");
    write_exr(&a, &[("", &gradient(8, 8))]).expect("write a.exr");
    let wrong = c.path("out/err.jpg");
    c.fails(
        ["compare", a.to_str().unwrap(), a.to_str().unwrap(), "--error-png", wrong.to_str().unwrap()],
        &["--error-png", "err.jpg", ".png"],
    );
    let missing = c.path("missing/err.png");
    c.fails(
        ["compare", a.to_str().unwrap(), a.to_str().unwrap(), "--error-png", missing.to_str().unwrap()],
        &["--error-png", "missing", "does not exist"],
    );
}

#[test]
fn compare_identical_and_error_png() {
    let c = Case::new();
    let a = c.path("a.exr");
    let b = c.path("b.exr");
    write_exr(&a, &[("", &gradient(16, 16))]).expect("write a.exr");
    let mut other = gradient(16, 16);
    other.data[0] *= 2.0;
    write_exr(&b, &[("", &other)]).expect("write b.exr");

    let (stdout, _) = succeeded(&c.run(["compare", a.to_str().unwrap(), a.to_str().unwrap()]));
    let rel =
        stdout.lines().find_map(|l| l.strip_prefix("relL2")).unwrap_or_else(|| panic!("no relL2 line:\n{stdout}"));
    let rel = rel.split_whitespace().next().unwrap_or_default();
    assert_eq!(rel.parse::<f64>().expect("relL2 number"), 0.0, "{stdout}");
    assert!(stdout.contains("NaN/Inf"), "{stdout}");
    assert!(stdout.contains("noise floor unknown"), "no variance layer, no floor: {stdout}");

    let (stdout, _) = succeeded(&c.run(["compare", b.to_str().unwrap(), a.to_str().unwrap(), "--json"]));
    let m: serde_json::Value = serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("not JSON: {e}\n{stdout}"));
    assert!(m["rel_l2"].as_f64().expect("rel_l2") > 0.0, "{m}");
    assert_eq!(m["pixels"], 256, "{m}");

    let err = c.path("out/err.png");
    succeeded(&c.run(["compare", b.to_str().unwrap(), a.to_str().unwrap(), "--error-png", err.to_str().unwrap()]));
    let png = image::open(&err).expect("error PNG decodes");
    let (gap, bar) = scatterlab::output::metrics::error_map_legend_rows(16);
    assert_eq!((png.width(), png.height()), (16, 16 + gap + bar), "the image and its colour bar");
    assert_eq!(c.listing(), ["a.exr", "b.exr", "out", "out/err.png"], "stray files");
}

/// `compare` knows the noise: two independent `path` renders of one scene differ by their
/// noise alone, so the error with both variance layers removed is near zero (within what
/// the noise can resolve) though the raw relL2 is not; `single` against `path` lacks the
/// multiple scattering, a bias the noise cannot hide.
#[test]
fn compare_removes_both_images_noise() {
    let c = Case::new();
    let scene = repo("scenes/homogeneous-sphere.toml");
    let render = |name: &str, extra: &[&str]| {
        let out = c.path(name);
        let size = ["--set", "render.width=24", "--set", "render.height=24"];
        let args =
            [&["render", scene.to_str().unwrap(), "-q", "--out", out.to_str().unwrap()][..], &size, extra].concat();
        succeeded(&c.run(args));
        out
    };
    let (p1, p2) =
        (render("p1.exr", &["--spp", "64", "--seed", "1"]), render("p2.exr", &["--spp", "64", "--seed", "2"]));
    let s1 = render("s1.exr", &["--solver", "single"]);
    let compare = |a: &Path, b: &Path| -> serde_json::Value {
        let (stdout, _) = succeeded(&c.run(["compare", a.to_str().unwrap(), b.to_str().unwrap(), "--json"]));
        serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("not JSON: {e}\n{stdout}"))
    };
    let m = compare(&p1, &p2);
    let (raw, noise) = (m["rel_l2"].as_f64().unwrap(), &m["noise"]);
    let (bias, resolution) = (noise["rel_l2_corrected"].as_f64().unwrap(), noise["resolution"].as_f64().unwrap());
    let (floor_a, floor_r) = (noise["image"].as_f64().unwrap(), noise["reference"].as_f64().unwrap());
    // Independent images: relL2^2 is about the sum of the two floors squared.
    let expected = (floor_a * floor_a + floor_r * floor_r).sqrt();
    assert!((raw / expected - 1.0).abs() < 0.25, "raw {raw} vs the floors' {expected}: {m}");
    assert!(bias < 1.5 * resolution && bias < 0.5 * raw, "noise taken for bias: {m}");

    let m = compare(&s1, &p2);
    let (raw, noise) = (m["rel_l2"].as_f64().unwrap(), &m["noise"]);
    let bias = noise["rel_l2_corrected"].as_f64().unwrap();
    assert!(noise["image"].is_null(), "single has no variance layer: {m}");
    assert!(bias > 0.9 * raw && bias > 3.0 * noise["resolution"].as_f64().unwrap(), "bias hidden: {m}");
    let (stdout, _) = succeeded(&c.run(["compare", s1.to_str().unwrap(), p2.to_str().unwrap()]));
    assert!(stdout.contains("ref noise") && stdout.contains("bias relL2"), "{stdout}");
}

// ------------------------------------------------------------------ renders that succeed

/// Render the shipped sphere with `solver`, check all three outputs, and compare the EXR
/// with itself through the CLI.
fn render_sphere(solver: &str) -> serde_json::Value {
    let c = Case::new();
    let (exr, png, json) = (c.path("out/s.exr"), c.path("out/s.png"), c.path("out/s.json"));
    let scene = repo("scenes/homogeneous-sphere.toml");
    let out = c.run(
        [
            &["render", scene.to_str().unwrap(), "--solver", solver, "--validate"][..],
            &TINY[..],
            if solver == "path" { &["--spp", "4"][..] } else { &[][..] },
            &["--out", exr.to_str().unwrap(), "--png", png.to_str().unwrap(), "--json", json.to_str().unwrap()][..],
        ]
        .concat(),
    );
    let (_, stderr) = succeeded(&out);
    assert!(stderr.contains("wrote"), "no summary:\n{stderr}");
    assert_eq!(
        c.listing(),
        ["out", "out/s.exr", "out/s.json", "out/s.png"],
        "missing outputs or stray (temporary) files"
    );

    let img = read_exr(&exr).expect("EXR reads back");
    assert_eq!((img.width, img.height), (16, 16));
    assert_eq!(img.nan_inf_count(), 0);
    assert!(img.mean().iter().all(|m| *m > 0.0), "black image: {:?}", img.mean());
    if solver == "path" {
        let var = read_exr_layer(&exr, "variance").expect("path writes a variance layer");
        assert_eq!((var.width, var.height), (16, 16));
    }
    let p = image::open(&png).expect("PNG decodes");
    assert_eq!((p.width(), p.height()), (16, 16));

    let doc = read_json(&json);
    for key in ["device", "solver", "settings", "passes", "gpu_ms", "wall_s"] {
        assert!(doc.get(key).is_some(), "JSON lacks {key}: {doc}");
    }
    assert!(doc["device"].get("mapping").is_some(), "JSON lacks device.mapping: {doc}");
    assert_eq!(doc["solver"], solver, "{doc}");
    assert_eq!((doc["width"].as_u64(), doc["height"].as_u64()), (Some(16), Some(16)), "{doc}");
    assert!(doc["passes"].as_array().is_some_and(|p| !p.is_empty()), "no passes: {doc}");
    assert_eq!(doc["validation"]["enabled"], true, "{doc}");
    assert_eq!(doc["validation"]["errors"], 0, "{doc}");

    // The CLI's compare on its own output.
    let (stdout, _) = succeeded(&c.run(["compare", exr.to_str().unwrap(), exr.to_str().unwrap()]));
    let rel =
        stdout.lines().find_map(|l| l.strip_prefix("relL2")).unwrap_or_else(|| panic!("no relL2 line:\n{stdout}"));
    assert_eq!(
        rel.split_whitespace().next().unwrap_or_default().parse::<f64>().expect("relL2 number"),
        0.0,
        "{stdout}"
    );
    doc
}

#[test]
fn render_path_writes_exr_png_json() {
    let doc = render_sphere("path");
    assert_eq!(doc["stats"]["spp"], 4, "--spp not applied: {doc}");
}

#[test]
fn render_single_writes_exr_png_json() {
    render_sphere("single");
}

#[test]
fn render_over_existing_outputs_replaces_them() {
    let c = Case::new();
    let s = c.scene(&base());
    for name in ["out/x.exr", "out/x.png", "out/x.json"] {
        fs::write(c.path(name), "old").expect("old file");
    }
    succeeded(&c.render(&s, &TINY));
    assert_eq!(read_exr(&c.path("out/x.exr")).expect("new EXR").width, 16);
    read_json(&c.path("out/x.json"));
    assert_eq!(c.listing(), ["out", "out/x.exr", "out/x.json", "out/x.png", "scene.toml"], "stray files");
}

#[test]
fn render_grid_scene_within_budget() {
    let c = Case::new();
    c.cloud_grid();
    let s = c.scene(&base().grid("cloud64.vol"));
    succeeded(&c.render(&s, &[&TINY[..], &["--memory-budget", "2M"]].concat()));
    let doc = read_json(&c.path("out/x.json"));
    assert_eq!(doc["validation"]["errors"], 0, "{doc}");
}

// ------------------------------------------------------------------ devices, scene info, help

#[test]
fn devices_lists_a_device_and_its_roles() {
    let c = Case::new();
    let (stdout, _) = succeeded(&c.run(["devices"]));
    assert!(stdout.lines().any(|l| l.starts_with("[0] ")), "no device listed:\n{stdout}");
    assert!(stdout.contains("roles: "), "no role mapping:\n{stdout}");
    assert!(stdout.contains("family 0:"), "no queue families:\n{stdout}");
    assert!(stdout.contains("usable: yes"), "no usable device:\n{stdout}");
}

#[test]
fn devices_json_parses() {
    let c = Case::new();
    let (stdout, _) = succeeded(&c.run(["devices", "--json"]));
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("not JSON: {e}\n{stdout}"));
    let list = v.as_array().unwrap_or_else(|| panic!("not an array: {v}"));
    assert!(!list.is_empty(), "no devices: {v}");
    for key in ["index", "name", "device_type", "queue_families", "mapping", "missing"] {
        assert!(list[0].get(key).is_some(), "device lacks {key}: {v}");
    }
    assert!(list.iter().any(|d| d["mapping"].is_object()), "no device has a role mapping: {v}");
}

#[test]
fn scene_info_cloud() {
    let c = Case::new();
    let scene = repo("scenes/cloud.toml");
    let (stdout, _) = succeeded(&c.run(["scene", "info", scene.to_str().unwrap()]));
    assert!(stdout.contains("64 x 64 x 64"), "no grid dims:\n{stdout}");
    for solver in ["path", "single"] {
        assert!(
            stdout.lines().any(|l| l.trim_start().starts_with(solver) && l.contains("MiB")),
            "no memory for {solver}:\n{stdout}"
        );
    }
    assert!(stdout.contains("anisotropic  yes"), "{stdout}");
    assert!(stdout.contains("density      heterogeneous"), "{stdout}");
    // The sphere scene is homogeneous (constant inside its sphere), and says so.
    let sphere = repo("scenes/homogeneous-sphere.toml");
    let (out, _) = succeeded(&c.run(["scene", "info", sphere.to_str().unwrap()]));
    assert!(out.contains("density      homogeneous: constant inside a sphere"), "{out}");

    let (stdout, _) = succeeded(&c.run(["scene", "info", scene.to_str().unwrap(), "--json"]));
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("not JSON: {e}\n{stdout}"));
    assert_eq!(v["grid_dims"], serde_json::json!([64, 64, 64]), "{v}");
    for solver in ["path", "single"] {
        assert!(v["device_bytes"][solver].as_u64().is_some_and(|b| b > 1 << 20), "{v}");
    }
}

#[test]
fn scene_info_bad_scene() {
    let c = Case::new();
    let s = c.scene(&base().set("medium.g", "1.0"));
    c.fails(["scene", "info", s.to_str().unwrap()], &["scene.toml", "medium.g", "(-1, 1)"]);
    c.fails(["scene", "info", s.to_str().unwrap(), "--set", "medium.g"], &["--set", "KEY=VALUE"]);
    let missing = c.path("nope.toml");
    c.fails(["scene", "info", missing.to_str().unwrap()], &["nope.toml", "cannot read scene file"]);
}

#[test]
fn help_and_version() {
    let c = Case::new();
    let (stdout, _) = succeeded(&c.run(["--help"]));
    for word in ["render", "compare", "devices", "scene"] {
        assert!(stdout.contains(word), "--help lacks {word}:\n{stdout}");
    }
    let (stdout, _) = succeeded(&c.run(["render", "--help"]));
    for word in ["--solver", "--set", "--out", "--png", "--json", "--memory-budget", "--validate", "--device"] {
        assert!(stdout.contains(word), "render --help lacks {word}:\n{stdout}");
    }
    let (stdout, _) = succeeded(&c.run(["--version"]));
    assert!(stdout.contains(env!("CARGO_PKG_VERSION")), "{stdout}");
}

#[test]
fn usage_errors_exit_nonzero_without_panic() {
    let c = Case::new();
    // clap's own errors are several lines (usage); only check they fail cleanly with status 2.
    for args in [
        &["render"][..],
        &["render", "x.toml", "--solver", "nope"],
        &["frobnicate"],
        &["render", "x.toml", "--spp", "-1"],
        // An exposure past render.exposure's range (NaN wrote a black PNG with exit 0).
        &["render", "x.toml", "--png", "x.png", "--exposure", "nan"],
        &["render", "x.toml", "--png", "x.png", "--exposure", "1e9"],
        &[],
    ] {
        let out = c.run(args);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
        // No arguments at all prints the help (to stderr) rather than an error line.
        if !args.is_empty() {
            assert!(stderr.starts_with("error: "), "{args:?}: {stderr}");
        }
    }
}

#[test]
fn object_scenes_from_the_command_line() {
    // Scene format v2: `scene info` names the object and the solvers that refuse it; a solver
    // without meshes refuses in one line and writes nothing; a mesh error names the file.
    let c = Case::new();
    let wax = repo("scenes/wax-blob.toml");
    let (stdout, _) = succeeded(&c.run(["scene", "info", wax.to_str().unwrap()]));
    assert!(
        stdout.contains("object       ") && stdout.contains("5120 triangles") && stdout.contains("ior 1.45"),
        "{stdout}"
    );
    assert!(stdout.lines().any(|l| l.trim_start().starts_with("path") && l.contains("MiB")), "{stdout}");
    assert!(stdout.lines().any(|l| l.trim_start().starts_with("wavefront") && l.contains("refused")), "{stdout}");
    let (stdout, _) = succeeded(&c.run(["scene", "info", wax.to_str().unwrap(), "--json"]));
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("not JSON: {e}\n{stdout}"));
    assert_eq!(v["object"]["triangles"], 5120, "{v}");
    assert!(v["refused_by"]["wavefront"].is_string() && v["device_bytes"]["path"].as_u64().is_some(), "{v}");
    assert!(v["refused_by"]["lbl"].is_null() && v["device_bytes"]["lbl"].as_u64().is_some(), "{v}");
    assert!(v["refused_by"]["single"].is_null() && v["device_bytes"]["single"].as_u64().is_some(), "{v}");
    let out = c.path("out/x.exr");
    c.fails(
        ["render", wax.to_str().unwrap(), "--solver", "wavefront", "--out", out.to_str().unwrap()],
        &["wavefront does not render [[object]] meshes", "--solver path, single, lbl or sh-single"],
    );
    // An open mesh: the file and the edge.
    std::fs::write(c.path("open.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\n").unwrap();
    let text = std::fs::read_to_string(&wax).unwrap().replace("meshes/blob.obj", "open.obj");
    let s = c.path("open.toml");
    std::fs::write(&s, text).unwrap();
    c.fails(["scene", "info", s.to_str().unwrap()], &["open.toml", "object[0].mesh", "open.obj", "not closed"]);
}

#[test]
fn render_help_says_what_each_solver_is_for() {
    let out = Command::new(env!("CARGO_BIN_EXE_scatterlab")).args(["render", "--help"]).output().unwrap();
    let (stdout, _) = succeeded(&out);
    let text = stdout.split_whitespace().collect::<Vec<_>>().join(" ");
    for s in scatterlab::solvers::SOLVERS {
        let about = s.about().split_whitespace().collect::<Vec<_>>().join(" ");
        assert!(
            text.contains(&format!("- {}: {about}", s.name())),
            "render --help lacks {}'s line: {stdout}",
            s.name()
        );
    }
}

/// A trust warning the scene and knobs decide is said before the work (here before the device
/// opens: asking for a device that does not exist fails after it) and once only, and the JSON
/// carries it: networks with 64 particles in a cube 100 mean free paths across.
#[test]
fn trust_warnings_come_before_the_work_and_once() {
    let c = Case::new();
    let s = c.scene(&base().set("medium.sigma_t", "100.0"));
    let knobs = ["--solver", "networks", "--set", "networks.particles=64", "--set", "networks.directions=16"];
    let warned = |o: &Output| {
        String::from_utf8_lossy(&o.stderr)
            .lines()
            .filter(|l| l.starts_with("warning: networks: a particle spacing is") && l.contains("use lbl, dom or path"))
            .count()
    };
    let early = c.run([&c.render_args(&s, &knobs)[..], &["--device".to_string(), "99".to_string()][..]].concat());
    assert!(!early.status.success(), "the device does not exist");
    assert_eq!(warned(&early), 1, "{}", String::from_utf8_lossy(&early.stderr));
    let out = c.render(&s, &knobs);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(warned(&out), 1, "printed once: {}", String::from_utf8_lossy(&out.stderr));
    let json: serde_json::Value = serde_json::from_slice(&fs::read(c.path("out/x.json")).expect("x.json")).unwrap();
    let warnings = json["warnings"].as_array().expect("warnings").iter().filter_map(|w| w.as_str()).collect::<Vec<_>>();
    assert!(warnings.iter().any(|w| w.contains("particle spacing")), "{warnings:?}");
}
