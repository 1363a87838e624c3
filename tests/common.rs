//! Shared helpers for GPU tests: a validated device (never a skip), scenes from text, renders.

use std::path::Path;

use scatterlab::gpu::{Gpu, GpuOptions};
use scatterlab::output::Image;
use scatterlab::scene::{is_scene_key, LoadOptions, Scene};
use scatterlab::solvers::{RenderOutput, RenderRequest, Settings, Solver, SolverError};

/// The registered solvers, by name, for tests that run one.
pub const PATH: &dyn Solver = &scatterlab::solvers::path::Path;
pub const SINGLE: &dyn Solver = &scatterlab::solvers::single::Single;
pub const LBL: &dyn Solver = &scatterlab::solvers::lbl::Lbl;
pub const WAVEFRONT: &dyn Solver = &scatterlab::solvers::wavefront::Wavefront;
pub const NETWORKS: &dyn Solver = &scatterlab::solvers::networks::Networks;
pub const SH_SINGLE: &dyn Solver = &scatterlab::solvers::sh_single::ShSingle;

/// The device every GPU test uses, validation layer on. A missing device or layer fails the
/// test: a test never passes for want of a device.
pub fn gpu() -> Gpu {
    gpu_with(GpuOptions { validate: true, ..GpuOptions::default() })
}

/// [`gpu`] opened as a device without double precision (`--without-float64`): the solvers'
/// convergence tests then run on the host.
pub fn gpu_without_float64() -> Gpu {
    gpu_with(GpuOptions { validate: true, without_float64: true, ..GpuOptions::default() })
}

fn gpu_with(opts: GpuOptions) -> Gpu {
    match Gpu::new(&opts) {
        Ok(g) => g,
        Err(e) => panic!("GPU tests need a Vulkan device with the validation layer (run tools/setup-deps): {e}"),
    }
}

/// Assert the validation layer reported nothing.
pub fn assert_clean(gpu: &Gpu) {
    assert_eq!(gpu.validation_errors(), 0, "validation errors: {:#?}", gpu.validation_messages());
}

/// A scene file of the repository (`scenes/cloud.toml`), with `sets` applied as `--set` would.
pub fn repo_scene(rel: &str, sets: &[(&str, &str)]) -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(rel);
    let sets: Vec<(String, String)> = sets.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect();
    Scene::load(&path, &sets, &LoadOptions::default()).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

/// A scene file of the repository with `appended` added to its text (another `[[light]]`),
/// its grid files found beside it.
pub fn repo_scene_plus(rel: &str, appended: &str) -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(rel);
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{rel}: {e}")) + appended;
    let dir = path.parent().expect("a file in a folder");
    Scene::from_str(&text, rel, dir, &[], &LoadOptions::default())
        .unwrap_or_else(|e| panic!("{rel} + {appended:?}: {e}"))
}

pub fn scene(text: &str) -> Scene {
    Scene::from_str(text, "test.toml", Path::new("."), &[], &LoadOptions::default())
        .unwrap_or_else(|e| panic!("test scene invalid: {e}"))
}

/// Issue 11's cube at 24 x 24: [-0.5, 0.5]^3, sigma_t 20, albedo 0.95, asymmetry `g`, a point
/// light of 10 W/sr at (1, 1, 1) near its corner, the camera at (0, 0, 4), fov 20.
pub fn issue_cube(g: &str) -> Scene {
    scene(&format!(
        "[render]\nwidth = 24\nheight = 24\nseed = 1\nspp = 1024\n\
         [camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov = 20.0\n\
         [medium]\nbounds = [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]\nsigma_t = 20.0\nalbedo = 0.95\ng = {g}\n\
         density = {{ kind = \"constant\" }}\n\
         [[light]]\nkind = \"point\"\nposition = [1.0, 1.0, 1.0]\nintensity = 10.0\n"
    ))
}

// reference-identity: begin (what a path reference goes through: reference_identity hashes it)
/// A render with its error (or warnings) left to the caller. `sets` holds solver knobs
/// (`lbl.grid`) and `render.*` scene keys (`render.spp`), as a bench ladder does.
pub fn try_render(
    gpu: &Gpu,
    scene: &Scene,
    solver: &dyn Solver,
    sets: &[(&str, &str)],
    force_full: bool,
) -> Result<RenderOutput, SolverError> {
    let pairs: Vec<(String, String)> = sets.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect();
    let (scene_sets, knob_sets): (Vec<_>, Vec<_>) = pairs.into_iter().partition(|(k, _)| is_scene_key(k));
    let scene = scene.with_overrides(&scene_sets).unwrap_or_else(|e| panic!("test bug: {e}"));
    let settings = Settings::new(&knob_sets);
    let req = RenderRequest { scene: &scene, settings: &settings, force_full, progress: &|_| {} };
    let started = std::time::Instant::now();
    let out = solver.render(gpu, &req);
    // Where a test's time goes (`--no-capture`): the suite's budget is kept by reading it.
    eprintln!("[time] {} {sets:?}: {:.2} s", solver.name(), started.elapsed().as_secs_f64());
    out
}

pub fn render_with(
    gpu: &Gpu,
    scene: &Scene,
    solver: &dyn Solver,
    sets: &[(&str, &str)],
    force_full: bool,
) -> RenderOutput {
    let out = try_render(gpu, scene, solver, sets, force_full).unwrap_or_else(|e| panic!("render failed: {e}"));
    assert_eq!(out.image.nan_inf_count(), 0, "NaN/Inf in the image");
    if let Some(v) = &out.variance {
        assert_eq!(v.nan_inf_count(), 0, "NaN/Inf in the variance");
    }
    assert!(out.image.data.iter().all(|v| *v >= 0.0), "negative radiance");
    assert!(out.report.warnings.is_empty(), "warnings: {:?}", out.report.warnings);
    out
}

pub fn render(gpu: &Gpu, scene: &Scene, solver: &dyn Solver, sets: &[(&str, &str)]) -> RenderOutput {
    render_with(gpu, scene, solver, sets, false)
}
// reference-identity: end

/// A render outside the solver's validated range on purpose: finite and non-negative as
/// [`render`] asks, and carrying warnings, each containing one of `expected` (a fragment of the
/// trust line's warning), every one of them met.
pub fn render_warned(
    gpu: &Gpu,
    scene: &Scene,
    solver: &dyn Solver,
    sets: &[(&str, &str)],
    expected: &[&str],
) -> RenderOutput {
    let out = try_render(gpu, scene, solver, sets, false).unwrap_or_else(|e| panic!("render failed: {e}"));
    assert_eq!(out.image.nan_inf_count(), 0, "NaN/Inf in the image");
    assert!(out.image.data.iter().all(|v| *v >= 0.0), "negative radiance");
    let w = &out.report.warnings;
    assert!(w.iter().all(|w| expected.iter().any(|e| w.contains(e))), "warnings {w:?}, expected only {expected:?}");
    assert!(expected.iter().all(|e| w.iter().any(|w| w.contains(e))), "warnings {w:?}, expected each of {expected:?}");
    out
}

/// Mean over all pixels and channels, and the standard error of that mean from the
/// per-pixel variance of the mean. Pixels are independent, but a pixel's three channels come
/// from the same paths (identical in a grey medium), so each pixel's channel mean gets the
/// Cauchy-Schwarz bound (mean_c sqrt(var_c))^2: exact for fully correlated channels,
/// conservative otherwise. (Treating the channels as independent underestimated the error by
/// sqrt(3) and made furnace tests fail at "4 sigma" one seed in three.)
pub fn mean_and_stderr(img: &Image, var: &Image) -> (f64, f64) {
    let pixels = img.data.len() / 3;
    let mean = img.data.iter().map(|v| *v as f64).sum::<f64>() / img.data.len() as f64;
    let var_sum: f64 =
        var.data.chunks(3).map(|c| (c.iter().map(|v| (*v as f64).sqrt()).sum::<f64>() / 3.0).powi(2)).sum();
    (mean, var_sum.sqrt() / pixels as f64)
}

/// Per-pixel, per-channel z-test of a Monte Carlo image against exact values: each value
/// within `k` standard errors (from the variance image) plus an absolute floor `eps` that
/// covers pixels whose sample variance happens to be 0. Returns the worst (|z|, index).
pub fn worst_z(img: &Image, var: &Image, exact: impl Fn(usize) -> f64, eps: f64) -> (f64, usize) {
    let mut worst = (0.0, 0);
    for i in 0..img.data.len() {
        let d = (img.data[i] as f64 - exact(i)).abs();
        let z = d / ((var.data[i] as f64).sqrt() + eps);
        if z > worst.0 {
            worst = (z, i);
        }
    }
    worst
}

/// Standard error of a render's image mean: from independent pixels for camera paths, plus a
/// light-traced part's own (from its batches; its pixels are correlated, one light path adding
/// to many). Counting the light part's per-pixel variance in both is conservative.
pub fn render_mean_and_stderr(out: &scatterlab::solvers::RenderOutput) -> (f64, f64) {
    let (m, se_cam) = mean_and_stderr(&out.image, out.variance.as_ref().unwrap());
    let se_lt = out.report.stats.correlated_mean_stderr;
    (m, (se_cam * se_cam + se_lt * se_lt).sqrt())
}

/// Two unbiased Monte Carlo estimates of one image (`a` by strategy `a_name`, `b` by `b_name`):
/// image means within 4 combined standard errors, and per value (pixel, channel) a z-test that
/// may fail only rarely (both variances are estimates, and heavy-tailed estimators understate
/// theirs).
pub fn assert_agree(
    what: &str,
    (a_name, a): (&str, &scatterlab::solvers::RenderOutput),
    (b_name, b): (&str, &scatterlab::solvers::RenderOutput),
) {
    let (ma, sea) = render_mean_and_stderr(a);
    let (mb, seb) = render_mean_and_stderr(b);
    let se = (sea * sea + seb * seb).sqrt();
    eprintln!("{what}: {a_name} mean {ma:.5} +- {sea:.5}, {b_name} {mb:.5} +- {seb:.5}, z = {:.2}", (ma - mb) / se);
    assert!(ma > 0.0, "{what}: black image");
    assert!((ma - mb).abs() < 4.0 * se, "{what}: {a_name} mean {ma} vs {b_name} {mb} (combined stderr {se})");
    let (va, vb) = (a.variance.as_ref().unwrap(), b.variance.as_ref().unwrap());
    let n = a.image.data.len();
    let bad = (0..n)
        .filter(|&i| {
            let sd = ((va.data[i] + vb.data[i]) as f64).sqrt() + 1e-4 * ma.min(mb);
            ((a.image.data[i] - b.image.data[i]) as f64).abs() > 4.0 * sd
        })
        .count();
    eprintln!("{what}: {bad} of {n} values beyond 4 sigma");
    assert!(bad * 100 <= 2 * n, "{what}: {bad} of {n} values differ by more than 4 sigma");
}

// ---- Scene text builder shared by cli_tests and scene_tests ----

/// The base scene: a constant-density unit cube (sigma_t 2, albedo 0.8, isotropic) seen
/// head-on by a 30 degree perspective camera, lit by one point light. Line 1 is blank, so
/// `[render]` is line 2, `width` line 3, `spp` line 6 and the camera's `kind` line 9 (tests
/// quote these line numbers in expected errors).
const BASE_SCENE: &str = r#"
[render]
width = 32
height = 32
seed = 7
spp = 4

[camera]
kind = "perspective"
origin = [0.0, 0.0, 4.0]
target = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
fov = 30.0

[medium]
bounds = [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]
sigma_t = 2.0
albedo = 0.8
g = 0.0
density = { kind = "constant" }

[[light]]
kind = "point"
position = [1.0, 1.0, 1.0]
intensity = 10.0
"#;

/// A scene file's text: [`SceneText::base`] edited one key or table at a time, e.g.
/// `SceneText::base().set("medium.albedo", "1.5")` or `SceneText::base().without_light()`.
///
/// Keys are named as error messages name them: `render.width`, `camera.fov`,
/// `medium.density`, `light.kind` (the base's one `[[light]]`). Every edit must apply: a key
/// or text the scene lacks, or a key it has twice, is a bug in the test and panics. The text
/// derefs to `str`, so `&scene` goes wherever a `&str` does.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneText(String);

impl SceneText {
    /// The base scene (see [`BASE_SCENE`]): 32x32 pixels, seed 7, 4 spp.
    pub fn base() -> SceneText {
        SceneText(BASE_SCENE.to_string())
    }

    /// `key = value` in place of the key's line.
    #[track_caller]
    pub fn set(self, key: &str, value: &str) -> SceneText {
        let name = key.rsplit('.').next().unwrap_or(key);
        self.replace_line(key, &format!("{name} = {value}"))
    }

    /// `line` (one or more lines, without the final newline) in place of the key's line:
    /// a renamed key, broken syntax, another key instead.
    #[track_caller]
    pub fn replace_line(self, key: &str, line: &str) -> SceneText {
        let range = self.key_line(key);
        self.splice(range, &format!("{line}\n"))
    }

    /// `lines` (without the final newline) inserted after the key's line.
    #[track_caller]
    pub fn insert_after(self, key: &str, lines: &str) -> SceneText {
        let range = self.key_line(key);
        self.splice(range.end..range.end, &format!("{lines}\n"))
    }

    /// Remove a key's line (`medium.albedo`) or a whole table (`camera`, `light`): its header
    /// and keys, up to the blank line that follows it.
    #[track_caller]
    pub fn remove(self, key_or_table: &str) -> SceneText {
        let range = match self.table(key_or_table) {
            Some(range) => range,
            None => self.key_line(key_or_table),
        };
        self.splice(range, "")
    }

    /// The medium's density as the inline table `table`, e.g. `{ kind = "sphere", ... }`.
    #[track_caller]
    pub fn density(self, table: &str) -> SceneText {
        self.set("medium.density", table)
    }

    /// A grid density read from `file` (a `.vol` file, whose header gives the dims).
    #[track_caller]
    pub fn grid(self, file: &str) -> SceneText {
        self.density(&format!("{{ kind = \"grid\", file = \"{file}\" }}"))
    }

    /// A grid density read from `file` with explicit `dims` (a raw grid, or a `.vol` whose
    /// header they must match).
    #[track_caller]
    pub fn grid_with_dims(self, file: &str, [x, y, z]: [i64; 3]) -> SceneText {
        self.density(&format!("{{ kind = \"grid\", file = \"{file}\", dims = [{x}, {y}, {z}] }}"))
    }

    /// No `[[light]]` table at all.
    #[track_caller]
    pub fn without_light(self) -> SceneText {
        self.remove("light")
    }

    /// Another `[[light]]` table with the keys `body`, before the base's point light (so it
    /// is `light[0]` and the point light `light[1]`).
    #[track_caller]
    pub fn prepend_light(self, body: &str) -> SceneText {
        self.replace("[[light]]", &format!("[[light]]\n{body}\n\n[[light]]"))
    }

    /// `text` added at the end of the file.
    pub fn append(mut self, text: &str) -> SceneText {
        self.0.push_str(text);
        self
    }

    /// The first `from` replaced by `to`: for edits the other methods do not cover.
    #[track_caller]
    pub fn replace(self, from: &str, to: &str) -> SceneText {
        assert!(self.0.contains(from), "test bug: the scene has no {from:?}:\n{}", self.0);
        SceneText(self.0.replacen(from, to, 1))
    }

    fn splice(mut self, range: std::ops::Range<usize>, with: &str) -> SceneText {
        self.0.replace_range(range, with);
        self
    }

    /// The lines with their byte ranges (newline included) and the table each is in.
    fn lines(&self) -> Vec<(std::ops::Range<usize>, &str, String)> {
        let mut out = Vec::new();
        let (mut at, mut table) = (0, String::new());
        for line in self.0.split_inclusive('\n') {
            let t = line.trim();
            if t.starts_with('[') && t.ends_with(']') {
                table = t.trim_matches(|c| c == '[' || c == ']').to_string();
            }
            out.push((at..at + line.len(), t, table.clone()));
            at += line.len();
        }
        out
    }

    /// The byte range of the one line that sets `key` (`table.name`, or `name` before any table).
    #[track_caller]
    fn key_line(&self, key: &str) -> std::ops::Range<usize> {
        let found: Vec<_> = self
            .lines()
            .into_iter()
            .filter(|(_, t, table)| {
                let Some((name, _)) = t.split_once('=') else { return false };
                let full = if table.is_empty() { name.trim().to_string() } else { format!("{table}.{}", name.trim()) };
                !t.starts_with('[') && !t.starts_with('#') && full == key
            })
            .map(|(range, _, _)| range)
            .collect();
        match found.as_slice() {
            [one] => one.clone(),
            _ => panic!("test bug: the scene sets {key:?} {} times, not once:\n{}", found.len(), self.0),
        }
    }

    /// The byte range of the table `name`, header to last key, if the scene has it (once).
    #[track_caller]
    fn table(&self, name: &str) -> Option<std::ops::Range<usize>> {
        let lines = self.lines();
        let headers: Vec<usize> = (0..lines.len())
            .filter(|&i| lines[i].1.starts_with('[') && lines[i].1.trim_matches(|c| c == '[' || c == ']') == name)
            .collect();
        match headers.as_slice() {
            [] => None,
            [h] => {
                let end = (h + 1..lines.len())
                    .find(|&i| lines[i].1.is_empty() || lines[i].1.starts_with('['))
                    .map_or(self.0.len(), |i| lines[i].0.start);
                Some(lines[*h].0.start..end)
            }
            _ => panic!("test bug: the scene has {} tables {name:?}, not one:\n{}", headers.len(), self.0),
        }
    }
}

impl std::ops::Deref for SceneText {
    type Target = str;
    fn deref(&self) -> &str {
        &self.0
    }
}

/// What an extrapolated iteration (lbl's lattice, dom's source iteration) buys over its plain
/// stop, summed over a test's cases: relL2 to the converged image and iterations of each.
#[derive(Default)]
pub struct TailTally {
    pub err_ext: f64,
    pub err_plain: f64,
    pub it_ext: u32,
    pub it_plain: u32,
}

impl TailTally {
    pub fn add(&mut self, err_ext: f64, err_plain: f64, it_ext: u32, it_plain: u32) {
        self.err_ext += err_ext;
        self.err_plain += err_plain;
        self.it_ext += it_ext;
        self.it_plain += it_plain;
    }

    /// Print the sums and require a quarter fewer iterations in all.
    pub fn assert_a_quarter_fewer(&self) {
        let (e, p, ie, ip) = (self.err_ext, self.err_plain, self.it_ext, self.it_plain);
        eprintln!("summed relL2 plain {p:.2e} extrapolated {e:.2e}; iterations {ip} -> {ie}");
        assert!(4 * ie < 3 * ip, "iterations {ip} -> {ie}");
    }
}

/// relL2 of `out` against a `path` reference with the reference's own noise removed (its
/// variance layer), and the image's energy ratio: how the accuracy tests judge a solver.
pub fn judge(out: &scatterlab::output::Image, reference: &impl AsReference) -> (f64, f64) {
    let (image, variance) = reference.parts();
    let m = scatterlab::output::compare(out, image).unwrap();
    let floor = scatterlab::output::metrics::noise_floor(out, image, None, variance).unwrap();
    (floor.rel_l2_corrected.expect("path writes a variance layer"), m.energy_ratio)
}

/// A `path` reference: its image and the variance of each pixel's mean.
pub struct Reference {
    pub image: Image,
    pub variance: Option<Image>,
}

/// What [`judge`] reads of a reference: a render, or a [`path_reference`].
pub trait AsReference {
    fn parts(&self) -> (&Image, Option<&Image>);
}

impl AsReference for RenderOutput {
    fn parts(&self) -> (&Image, Option<&Image>) {
        (&self.image, self.variance.as_ref())
    }
}

impl AsReference for Reference {
    fn parts(&self) -> (&Image, Option<&Image>) {
        (&self.image, self.variance.as_ref())
    }
}

// reference-identity: begin
/// Where a [`path_reference`] came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReferenceSource {
    /// Committed in `tests/data/path-references/` (`tools/path-references keep` put it there).
    Committed,
    /// Kept in `target/tmp/path-references/` by an earlier test of this build.
    Kept,
    /// Rendered now (and kept).
    Rendered,
}

/// The committed store of `path` references: what a clean checkout (CI) finds without
/// rendering.
pub const COMMITTED_REFERENCES: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/path-references");

/// The identity every reference of this build on `gpu` shares, the first part of its file's
/// name: `scatterlab::REFERENCE_BUILD` (the code a `path` render is a function of: build.rs),
/// this file (the render helpers a reference goes through), the device and driver. A changed
/// tracer, scene loader or GPU layer gives a new identity, and no old image is found.
pub fn reference_identity(gpu: &Gpu) -> String {
    use sha2::{Digest, Sha256};
    let info = gpu.info();
    let mut h = Sha256::new();
    h.update(scatterlab::REFERENCE_BUILD.as_bytes());
    // The helpers a reference is rendered and kept through, between this file's markers.
    // (The markers are spelt in two pieces here, so that this code does not split its own block.)
    for block in include_str!("common.rs").split(concat!("// reference-", "identity: begin")).skip(1) {
        h.update(block.split(concat!("// reference-", "identity: end")).next().unwrap_or(block).as_bytes());
    }
    h.update(format!("|{}|{}|{}|", info.name, info.driver_name, info.driver_info).as_bytes());
    h.finalize().iter().take(6).map(|b| format!("{b:02x}")).collect()
}

/// `path`'s render of `scene` with `sets` (a reference at high spp), kept on disk for every other
/// test that asks for the same one: dom's, networks' and wavefront's across-the-range tests
/// judge themselves against the same anisotropic cubes at 2048 spp, minutes of lavapipe each,
/// and the refraction tests' references (manifold next-event estimation) are most of their time.
/// A render is a function of the scene, its seed, the device and the code it runs (the
/// Determinism rule), so the key is exactly those: [`reference_identity`] (the code, the
/// device), then the scene as loaded (every field, grid data included, through its `Debug`
/// form, which prints floats exactly, its paths relative to the checkout) and the sets
/// ([`reference_key`]). Found first among the committed references
/// (a clean checkout renders none that `tools/path-references keep` stored for its code), then
/// among this machine's kept ones; a fresh render is checked as `render` checks it (finite,
/// non-negative, no warning) before it is kept; a file that cannot be read is rendered again.
/// Every key asked for is listed in `target/tmp/path-references/used.txt`, which
/// `tools/path-references keep` copies from.
pub fn path_reference(gpu: &Gpu, scene: &Scene, sets: &[(&str, &str)]) -> Reference {
    path_reference_from(gpu, scene, sets).0
}

/// `text` (a scene's `Debug` form) without where this checkout and the tests' temporary folders
/// lie: the scene's source and its grid files are absolute paths, under the repository
/// (`repo_scene`) or a `tempfile` folder (`/tmp/.tmpXXXXXX`, random per run), and a reference's
/// key must be the same in any checkout (CI's is not this machine's) and every run. The grid
/// data itself stays in the key.
fn without_checkout_paths(text: &str) -> String {
    let text = text.replace(env!("CARGO_MANIFEST_DIR"), "<repo>");
    let tmp = std::env::temp_dir().join(".tmp");
    let tmp = tmp.to_string_lossy();
    let (mut out, mut rest) = (String::with_capacity(text.len()), text.as_str());
    while let Some(i) = rest.find(&*tmp) {
        out.push_str(&rest[..i]);
        out.push_str("<tmp>");
        rest = &rest[i + tmp.len()..];
        rest = rest.trim_start_matches(|c: char| c.is_ascii_alphanumeric());
    }
    out.push_str(rest);
    out
}

/// A reference's key: the scene as loaded (its `Debug` form, without the folder of its file,
/// the checkout's and the temporary folders' paths) and the sets.
pub fn reference_key(scene: &Scene, sets: &[(&str, &str)]) -> String {
    use sha2::{Digest, Sha256};
    let mut h = Sha256::new();
    let mut text = format!("{scene:?}");
    // The scene's own folder first: its grid files are found there.
    if let Some(dir) = scene.source.parent().filter(|d| d.is_absolute()) {
        text = text.replace(&*dir.to_string_lossy(), "<scene>");
    }
    h.update(without_checkout_paths(&text).as_bytes());
    h.update(format!("|{sets:?}|").as_bytes());
    h.finalize().iter().take(10).map(|b| format!("{b:02x}")).collect()
}

/// [`path_reference`], and where it came from.
pub fn path_reference_from(gpu: &Gpu, scene: &Scene, sets: &[(&str, &str)]) -> (Reference, ReferenceSource) {
    let name = format!("{}-{}.exr", reference_identity(gpu), reference_key(scene, sets));
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("path-references");
    std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    {
        // One short line per append: whole lines whatever other tests append meanwhile.
        use std::io::Write;
        let used = dir.join("used.txt");
        let mut f = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&used)
            .unwrap_or_else(|e| panic!("{}: {e}", used.display()));
        f.write_all(format!("{name}\n").as_bytes()).unwrap_or_else(|e| panic!("{}: {e}", used.display()));
    }
    for (store, source) in
        [(Path::new(COMMITTED_REFERENCES), ReferenceSource::Committed), (&dir, ReferenceSource::Kept)]
    {
        let file = store.join(&name);
        if let (Ok(image), Ok(variance)) =
            (scatterlab::output::read_exr(&file), scatterlab::output::read_exr_layer(&file, "variance"))
        {
            if (image.width, image.height) == (scene.render.width, scene.render.height) {
                eprintln!("[time] path reference {sets:?}: {source:?} ({name})");
                return (Reference { image, variance: Some(variance) }, source);
            }
        }
    }
    let out = render(gpu, scene, PATH, sets);
    let variance = out.variance.expect("path reports its variance");
    let file = dir.join(&name);
    // Written beside and renamed over: a test reading it meanwhile sees the whole file or none.
    let part = dir.join(format!("{name}.{}.part.exr", std::process::id()));
    scatterlab::output::write_exr(&part, &[("", &out.image), ("variance", &variance)])
        .unwrap_or_else(|e| panic!("{}: {e}", part.display()));
    std::fs::rename(&part, &file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
    (Reference { image: out.image, variance: Some(variance) }, ReferenceSource::Rendered)
}
// reference-identity: end
