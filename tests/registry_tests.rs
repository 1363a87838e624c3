//! The solver interface: every registered solver supplies every entry of it, every kernel's
//! declared interface matches its SPIR-V, the knob reference is current, and a solver that is
//! not in the registry at all (a tiny CPU-only fake) is picked up by `bench`, `stability`,
//! the memory table and the knob reference with no code of its own there.

use std::collections::BTreeSet;
use std::path::Path;

use scatterlab::gpu::{reflect, Gpu, Kernel};
use scatterlab::measure::{bench, stability};
use scatterlab::output::Image;
use scatterlab::physics::reference::chord_length_box;
use scatterlab::scene::{is_scene_key, CameraKind, Light, Scene};
use scatterlab::solvers::parts::gpu_scene::modelled;
use scatterlab::solvers::{
    self, knobs, Knob, Knobs, Range, RenderOutput, RenderReport, RenderRequest, Rung, Settings, Solver, SolverError,
    Stats, Variant, SOLVERS,
};

use crate::common::{assert_clean, gpu, render, scene, PATH, SINGLE};

/// A constant-density cube under a uniform environment, seen face on: every camera ray crosses
/// one unit of medium (the stability sweep's geometry).
const CUBE: &str = r#"
[render]
width = 12
height = 12
seed = 5
spp = 16
[camera]
kind = "orthographic"
origin = [0.0, 0.0, 3.0]
target = [0.0, 0.0, 0.0]
extent = 0.6
[medium]
bounds = [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]
sigma_t = 2.0
albedo = 0.0
g = 0.0
density = { kind = "constant" }
[[light]]
kind = "environment"
radiance = 1.0
"#;

/// A solver that is in no registry: the pure absorber on the CPU. Each pixel is the
/// environment's radiance times the transmittance of its central camera ray,
/// exp(-sigma_t chord) (constant density only: exact for it, and it says so otherwise). It
/// ignores scattering and every other light, which is what `stability` must notice.
struct Absorber;

impl Solver for Absorber {
    fn name(&self) -> &'static str {
        "absorber"
    }
    fn about(&self) -> &'static str {
        "test fake: transmitted environment only, on the CPU"
    }
    fn knobs(&self) -> Vec<Knob> {
        vec![Knob::fixed("gain", "1", Range::positive(), "multiplies the image (1: the exact absorber)")]
    }
    fn kernels(&self) -> Vec<Kernel> {
        Vec::new()
    }
    fn render(&self, _gpu: &Gpu, req: &RenderRequest) -> Result<RenderOutput, SolverError> {
        let k = req.knobs(self)?;
        let gain: f32 = k.get("gain")?;
        k.finish()?;
        let s = req.scene;
        if !matches!(s.medium.density, scatterlab::scene::Density::Constant) {
            return Err(SolverError::Unsupported("absorber: constant density only".into()));
        }
        let env: f32 = s
            .lights
            .iter()
            .map(|l| match l {
                Light::Environment { radiance } => radiance.x,
                _ => 0.0,
            })
            .sum();
        let (w, h) = (s.render.width, s.render.height);
        let (right, up, forward) = s.camera.basis();
        let mut image = Image::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let u = (x as f32 + 0.5) / w as f32 * 2.0 - 1.0;
                let v = 1.0 - (y as f32 + 0.5) / h as f32 * 2.0;
                let aspect = h as f32 / w as f32;
                let (o, d) = match s.camera.kind {
                    CameraKind::Orthographic { extent } => {
                        (s.camera.origin + right * (u * extent / 2.0) + up * (v * aspect * extent / 2.0), forward)
                    }
                    CameraKind::Perspective { fov_deg } => {
                        let t = (fov_deg.to_radians() / 2.0).tan();
                        (s.camera.origin, (forward + right * (u * t) + up * (v * aspect * t)).normalize())
                    }
                };
                let chord = chord_length_box(o, d, s.medium.bounds_min, s.medium.bounds_max);
                let t = (-s.medium.sigma_t * chord).exp();
                let p = 3 * (y * w + x) as usize;
                image.data[p..p + 3].copy_from_slice(&(t * env * gain).to_array());
            }
        }
        let report = RenderReport {
            solver: self.name(),
            settings: k.json(),
            modelled: modelled(s, req.force_full),
            device_bytes: 0,
            passes: Vec::new(),
            gpu_ms: 0.0,
            host: Default::default(),
            pipelines: Vec::new(),
            stats: Stats::new(()),
            warnings: Vec::new(),
            nonfinite_pixels: 0,
        };
        Ok(RenderOutput { image, variance: None, report, estimates: Vec::new() })
    }
    fn memory_estimate(&self, _scene: &Scene, _knobs: &Knobs) -> Result<u64, SolverError> {
        Ok(0)
    }
    fn ladder(&self, _scene: &Scene) -> Vec<Rung> {
        ["0.25", "0.5", "1"].iter().map(|g| Rung::one("absorber.gain", g)).collect()
    }
    fn stability(&self) -> Vec<Variant> {
        vec![Variant::new("", &[]), Variant::new("half", &[("absorber.gain", "0.5")])]
    }
}

static FAKE: &dyn Solver = &Absorber;

/// Every registered solver supplies every entry of the interface, with values that hold up.
#[test]
fn every_registered_solver_supplies_the_whole_interface() {
    let s = scene(CUBE);
    let names: BTreeSet<&str> = SOLVERS.iter().map(|s| s.name()).collect();
    assert_eq!(names.len(), SOLVERS.len(), "solver names are unique");
    assert_eq!(SOLVERS.iter().filter(|s| s.is_reference()).count(), 1, "exactly one reference solver");
    assert!(solvers::reference().is_reference());
    for solver in SOLVERS {
        let name = solver.name();
        assert!(!solver.about().is_empty(), "{name}: about");
        assert_eq!(solvers::find(name).unwrap().name(), name);
        let table = solver.knobs();
        assert!(!table.is_empty(), "{name}: no knobs");
        let knob_names: BTreeSet<&str> = table.iter().map(|k| k.name.as_str()).collect();
        assert_eq!(knob_names.len(), table.len(), "{name}: knob names are unique");
        for k in &table {
            assert!(!k.doc.is_empty(), "{name}.{}: no doc", k.name);
            if let knobs::Default::Fixed(d) = &k.default {
                k.range.check(d).unwrap_or_else(|e| panic!("{name}.{}: default {d} out of its range: {e}", k.name));
            }
        }
        // Every knob at its default resolves for this scene, and a memory estimate follows.
        let defaults = Knobs::defaults(name, table.clone());
        let bytes = solver.memory_estimate(&s, &defaults).unwrap_or_else(|e| panic!("{name}: {e}"));
        // A solver with kernels allocates device memory; only a CPU-only one may estimate 0.
        assert!(bytes > 0 || solver.kernels().is_empty(), "{name}: runs kernels but estimates 0 bytes");
        let ladder = solver.ladder(&s);
        assert!(ladder.len() >= 3, "{name}: a ladder of {} rungs (bench --quick keeps three)", ladder.len());
        for rung in &ladder {
            assert!(rung.sets.iter().any(|(k, _)| k == &rung.knob), "{name}: rung {} does not set its knob", rung.knob);
            check_sets(*solver, &rung.sets);
        }
        let variants = solver.stability();
        assert!(!variants.is_empty(), "{name}: no stability variant");
        for v in &variants {
            check_sets(*solver, &v.sets);
        }
    }
}

/// Keys a ladder or variant sets are scene `render.*` keys the measurements can apply, or
/// knobs of this solver with values in range.
fn check_sets(solver: &dyn Solver, sets: &[(String, String)]) {
    let (scene_sets, knob_sets): (Vec<_>, Vec<_>) = sets.iter().cloned().partition(|(k, _)| is_scene_key(k));
    scene(CUBE).with_overrides(&scene_sets).unwrap_or_else(|e| panic!("{}: {e}", solver.name()));
    Settings::new(&knob_sets).knobs(solver.name(), solver.knobs()).unwrap_or_else(|e| panic!("{}: {e}", solver.name()));
}

/// Spec-constant ids and push-constant sizes of every kernel of every solver (and of the test
/// probes) agree with the SPIR-V, and every compiled shader belongs to some kernel.
#[test]
fn every_kernel_matches_its_spirv_and_every_shader_is_used() {
    let mut used = BTreeSet::new();
    for k in &solvers::kernels() {
        k.check().unwrap_or_else(|e| panic!("{e}"));
        let r = reflect(&k.shader).unwrap();
        assert!(r.workgroup_size.iter().all(|w| *w >= 1), "{}", k.shader.name);
        used.insert(k.shader.name.to_string());
    }
    let spirv = Path::new(env!("CARGO_MANIFEST_DIR")).join("spirv");
    let mut shipped = BTreeSet::new();
    for dir in std::fs::read_dir(&spirv).unwrap() {
        let dir = dir.unwrap().path();
        for f in std::fs::read_dir(&dir).unwrap() {
            let f = f.unwrap().path();
            let folder = dir.file_name().unwrap().to_string_lossy().into_owned();
            shipped.insert(format!("{folder}/{}", f.file_stem().unwrap().to_string_lossy()));
        }
    }
    assert_eq!(used, shipped, "kernels declared by solvers vs shaders in spirv/");
}

/// A declared interface that disagrees with the shader is caught, at the check and when a
/// pipeline is built.
#[test]
fn a_wrong_kernel_declaration_is_refused() {
    use scatterlab::gpu::{Spec, SpecKind};
    let mut k = solvers::parts::view::MARCH;
    k.push_bytes += 4;
    let e = k.check().unwrap_err().to_string();
    assert!(e.contains("view/march") && e.contains("push constants"), "{e}");
    let mut k = solvers::parts::view::MARCH;
    k.spec = &[(0, SpecKind::U32), (1, SpecKind::Bool)];
    let e = k.check().unwrap_err().to_string();
    assert!(e.contains("specialization constants"), "{e}");
    let gpu = gpu();
    // Built with an id the shader does not declare, or with a wrong type.
    let spec = [(0, Spec::U32(0)), (1, Spec::Bool(false)), (2, Spec::Bool(false)), (9, Spec::U32(1))];
    let e = gpu.pipeline(&solvers::parts::view::MARCH, &spec).err().expect("refused").to_string();
    assert!(e.contains("view/march") && e.contains("specialization"), "{e}");
    let spec = [(0, Spec::U32(0)), (1, Spec::U32(0)), (2, Spec::Bool(false))];
    assert!(gpu.pipeline(&solvers::parts::view::MARCH, &spec).is_err());
    assert_clean(&gpu);
}

/// `docs/knobs.md` is the knob reference generated from the tables (`scatterlab knobs
/// --markdown`): regenerate it when a knob changes.
#[test]
fn the_knob_reference_is_current() {
    let want = knobs::reference_markdown(SOLVERS);
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/knobs.md");
    let have = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        have.trim_end() == want.trim_end(),
        "docs/knobs.md is stale: run `tools/scatterlab knobs --markdown > docs/knobs.md`"
    );
    for s in SOLVERS {
        for k in s.knobs() {
            assert!(want.contains(&format!("`{}.{}`", s.name(), k.name)));
        }
    }
}

/// `--set` is checked against the tables: unknown knobs, other solvers' knobs, values out of
/// range, and knobs set but unused by the render, each with a message naming the key.
#[test]
fn knob_settings_are_checked_against_the_table() {
    let bad = |pairs: &[(&str, &str)], solver: &dyn Solver| {
        let p: Vec<(String, String)> = pairs.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect();
        Settings::new(&p).knobs(solver.name(), solver.knobs()).expect_err("refused").to_string()
    };
    let lbl = solvers::find("lbl").unwrap();
    let e = bad(&[("lbl.grd", "32")], lbl);
    assert!(e.contains("lbl.grd") && e.contains("unknown knob") && e.contains("grid"), "{e}");
    let e = bad(&[("path.max_depth", "1")], lbl);
    assert!(e.contains("path.max_depth") && e.contains("solver path") && e.contains("lbl"), "{e}");
    let e = bad(&[("lbl.grid", "1")], lbl);
    assert!(e.contains("lbl.grid") && e.contains("2..=512"), "{e}");
    let e = bad(&[("lbl.tol", "1")], lbl);
    assert!(e.contains("lbl.tol") && e.contains(", 1)"), "{e}");
    // Under 1e-12 (f32's test would hold 1e-300 as 0).
    let e = bad(&[("lbl.tol", "1e-300")], lbl);
    assert!(e.contains("lbl.tol") && e.contains("1e-300"), "{e}");
    let e = bad(&[("lbl.lattice", "d3q19")], lbl);
    assert!(e.contains("d3q6, d3q18"), "{e}");
    let e = bad(&[("path.spp", "64")], PATH);
    assert!(e.contains("path.spp") && e.contains("render.spp"), "{e}");
    let e = bad(&[("absorber.gain", "-1")], FAKE);
    assert!(e.contains("absorber.gain") && e.contains("(0, inf)"), "{e}");
    // Set, in range, but not used by this render: a knob of a mode not chosen.
    let gpu = gpu();
    let s = scene(CUBE);
    let sets = [("lbl.wavefront_nu", "16"), ("lbl.grid", "8"), ("lbl.rays", "256")];
    let e = crate::common::try_render(&gpu, &s, lbl, &sets, false).err().expect("refused").to_string();
    assert!(e.contains("lbl.wavefront_nu") && e.contains("does not use"), "{e}");
    // The report's settings are the knobs the render ran with, defaults included.
    let out = render(&gpu, &s, SINGLE, &[("single.env_dirs", "8")]);
    assert_eq!(out.report.settings["env_dirs"], 8);
    assert_eq!(out.report.settings["supersample"], 1);
    assert!(out.report.settings["step"].as_f64().unwrap() > 0.0, "the derived step is recorded");
    assert_clean(&gpu);
}

/// A solver in no registry is picked up by bench, stability, the memory table and the knob
/// reference: none of them has code of its own for any solver.
#[test]
fn a_fake_solver_is_picked_up_everywhere() {
    let gpu = gpu();
    let s = scene(CUBE);
    // Bench walks its ladder beside a real solver, against the reference.
    let reference = crate::common::path_reference(&gpu, &s, &[("render.spp", "4096")]).image;
    let (points, _) =
        bench::bench_scene(&gpu, "cube", &s, &reference, &[FAKE, SINGLE], &bench::Points::Cheapest(3), 1, &|_| {})
            .unwrap();
    let fake: Vec<_> = points.iter().filter(|p| p.solver == "absorber").collect();
    assert_eq!(fake.len(), 3);
    assert_eq!(fake.iter().map(|p| p.value.as_str()).collect::<Vec<_>>(), ["0.25", "0.5", "1"]);
    // At gain 1 it is exact here (a pure absorber): the error is the reference's noise alone
    // (each path sample is 0 or 1 with p = exp(-2): relL2 ~ 0.04, energy ~ 0.003 per sigma).
    let exact = fake.iter().find(|p| p.value == "1").unwrap();
    assert!(exact.metrics.rel_l2 < 0.1 && (exact.metrics.energy_ratio - 1.0).abs() < 0.015, "{:?}", exact.metrics);
    assert!((fake[0].metrics.energy_ratio - 0.25).abs() < 0.01, "{:?}", fake[0].metrics);
    // Stability runs both of its variants on every case and judges them like any solver:
    // exact on the pure absorber, caught at half gain there.
    let outcomes = stability::run(&gpu, &[FAKE], false, &|_| {}).unwrap();
    // The fake solver carries no emission: it refuses the emitter cases, and is not run on them.
    let cases = stability::cases().iter().filter(|c| !c.slow && !c.emission).count();
    assert_eq!(outcomes.len(), 2 * cases);
    let albedo0 = |variant: &str| {
        outcomes.iter().find(|o| o.case == "albedo 0" && o.variant == variant).expect("albedo 0 outcome").clone()
    };
    assert!(albedo0("").passed && albedo0("").exact_error.unwrap() < 1e-4, "{:?}", albedo0(""));
    assert!(!albedo0("half").passed && albedo0("half").notes.iter().any(|n| n.contains("exact")));
    assert!(outcomes.iter().all(|o| o.solver == "absorber"));
    // The memory table and the knob reference list it.
    let table = solvers::memory_table(&s, &[FAKE, SINGLE], &Settings::default()).unwrap();
    assert_eq!(table.iter().map(|t| t.0).collect::<Vec<_>>(), ["absorber", "single"]);
    assert!(knobs::reference_markdown(&[FAKE]).contains("| `absorber.gain` | `1` |"));
    assert_clean(&gpu);
}

/// Ladders may set `render.*` scene keys; nothing else can be applied to a loaded scene.
#[test]
fn render_keys_apply_to_a_loaded_scene() {
    let s = scene(CUBE);
    let o = |k: &str, v: &str| vec![(k.to_string(), v.to_string())];
    assert_eq!(s.with_overrides(&o("render.spp", "64")).unwrap().render.spp, 64);
    assert_eq!(s.with_overrides(&o("render.width", "7")).unwrap().render.width, 7);
    let e = s.with_overrides(&o("render.spp", "0")).unwrap_err().to_string();
    assert!(e.contains("render.spp") && e.contains("out of range"), "{e}");
    let e = s.with_overrides(&o("medium.albedo", "0.5")).unwrap_err().to_string();
    assert!(e.contains("medium.albedo") && e.contains("render.spp"), "{e}");
}

/// The layers of src/solvers/ hold (read from the sources): the interface (interface/)
/// imports no part and no solver, and reads the registry only through `registered()`; a
/// shared part (parts/) imports the interface and other parts, never a solver or the registry;
/// a solver's folder imports the interface, the parts and its own files, never another solver
/// or the registry. And the CLI and `measure` name no solver: everything goes through the
/// interface and the registry.
#[test]
fn no_code_outside_a_solver_names_it() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let names: Vec<&str> = SOLVERS.iter().map(|s| s.name()).collect();
    let modules: Vec<String> = names.iter().map(|n| n.replace('-', "_")).collect();
    let read = |dir: &str| -> Vec<(String, String)> {
        let mut out = Vec::new();
        for e in std::fs::read_dir(root.join(dir)).unwrap() {
            let p = e.unwrap().path();
            if p.extension().is_some_and(|x| x == "rs") {
                out.push((p.file_stem().unwrap().to_string_lossy().into_owned(), std::fs::read_to_string(&p).unwrap()));
            }
        }
        out
    };
    // Every file under src/solvers/, by its path below it, with its code lines (comments out).
    let mut files: Vec<(String, Vec<String>)> = Vec::new();
    for p in files_under(&root.join("solvers")) {
        if p.extension().is_some_and(|x| x == "rs") {
            let rel = p.strip_prefix(root.join("solvers")).unwrap().to_string_lossy().into_owned();
            let code = std::fs::read_to_string(&p)
                .unwrap()
                .lines()
                .filter(|l| !l.trim_start().starts_with("//"))
                .map(str::to_string)
                .collect();
            files.push((rel, code));
        }
    }
    let mut offences = Vec::new();
    for (rel, code) in &files {
        let top = rel.split('/').next().unwrap();
        let depth = rel.matches('/').count();
        // What `crate::solvers::<next>` may name from here.
        let allowed: Vec<&str> = match top {
            "mod.rs" => continue,
            "interface" => vec!["interface"],
            "parts" => vec!["interface", "parts"],
            own => vec!["interface", "parts", own],
        };
        for line in code {
            for rest in line.split("solvers::").skip(1) {
                let next: String = rest.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
                if !allowed.contains(&next.as_str()) {
                    offences.push(format!("src/solvers/{rel} imports solvers::{next}: {}", line.trim()));
                }
            }
            // `super` from a folder's mod.rs directly below solvers/ is the registry.
            let super_is_registry = depth == 1 && rel.ends_with("mod.rs");
            if super_is_registry && line.contains("super::") {
                let ok = rel == "interface/mod.rs" && line.trim() == "super::SOLVERS";
                if !ok {
                    offences.push(format!("src/solvers/{rel} reaches up into the registry: {}", line.trim()));
                }
            }
            // A part or the interface naming a solver's module through `super::`.
            if top == "parts" || top == "interface" {
                for m in &modules {
                    if line.contains(&format!("super::{m}")) {
                        offences.push(format!("src/solvers/{rel} imports solver {m}"));
                    }
                }
            }
        }
    }
    // Every solver has its folder.
    for m in &modules {
        if !root.join("solvers").join(m).join("mod.rs").is_file() {
            offences.push(format!("solver {m} has no folder src/solvers/{m}/"));
        }
    }
    for dir in ["cli", "measure"] {
        for (file, text) in read(dir) {
            for n in &names {
                // The module (`sh_single` for `sh-single`) by path or in a `solvers::{..}`
                // group, and the name as a literal or a knob prefix.
                let module = n.replace('-', "_");
                let in_group = text.split("solvers::{").skip(1).any(|rest| {
                    let group = &rest[..rest.find('}').unwrap_or(rest.len())];
                    group.split([',', ' ', '\n', ':']).any(|w| w == module)
                });
                if in_group
                    || text.contains(&format!("solvers::{module}::"))
                    || text.contains(&format!("solvers::{module};"))
                    || text.contains(&format!("\"{n}\""))
                    || text.contains(&format!("\"{n}."))
                {
                    offences.push(format!("src/{dir}/{file}.rs names solver {n}"));
                }
            }
        }
    }
    assert!(offences.is_empty(), "{offences:#?}");
}

/// `scene info`'s estimate is what a render allocates, byte for byte, for every registered
/// solver: on a grey scene under an environment and on a chromatic one with a point light
/// inside the medium (light tracing, a traced wave field, three lattice channels).
#[test]
fn memory_estimates_equal_what_renders_allocate() {
    let gpu = gpu();
    let inside =
        CUBE.replace("sigma_t = 2.0", "sigma_t = [2.0, 3.0, 4.0]").replace("albedo = 0.0", "albedo = 0.8").replace(
            "kind = \"environment\"\nradiance = 1.0",
            "kind = \"point\"\nposition = [0.1, 0.0, 0.0]\nintensity = 1.0",
        );
    let knobs: Vec<(String, String)> = [
        ("render.spp", "4"),
        ("lbl.grid", "8"),
        ("lbl.rays", "256"),
        ("lbl.max_iters", "64"),
        ("wavefront.grid", "8"),
        ("wavefront.nu", "8"),
        ("wavefront.nv", "4"),
        ("wavefront.layers", "16"),
        ("dom.grid", "8"),
        ("dom.rays", "256"),
        ("dom.directions", "s4"),
        // networks and sh-single were half the test's time at their defaults (1024 particles x
        // 128 directions, 4000 samples): CI time, and non-default sizes for the estimate too.
        ("networks.particles", "256"),
        ("networks.directions", "32"),
        ("sh-single.samples", "500"),
    ]
    .iter()
    .map(|(k, v)| (k.to_string(), v.to_string()))
    .collect();
    // The cloud: a grid density (the view pass's shadow volume), anisotropic (lbl's deposit
    // fluxes and lattice flux), a sun and a sky.
    let cloud = crate::common::repo_scene("scenes/cloud.toml", &[("render.width", "16"), ("render.height", "16")]);
    // A glass object (scene format v2): the BVH, lbl's marching through it; the solvers
    // without meshes refuse it and are skipped.
    let glass = scene(&crate::refraction_tests::object_scene_seeded(
        5,
        &format!("mesh = \"{}\"\nior = 1.5", crate::refraction_tests::mesh("icosphere.obj")),
        "sigma_t = 4.0\nalbedo = 0.9\ng = 0.3",
        crate::refraction_tests::ENV,
        8,
        4,
    ));
    for (what, s) in [
        ("grey, environment", scene(CUBE)),
        ("chromatic, light inside", scene(&inside)),
        ("cloud: grid, g 0.6", cloud),
        ("glass object", glass),
    ] {
        for solver in SOLVERS {
            let own: Vec<(String, String)> = knobs
                .iter()
                .filter(|(k, _)| k.starts_with(&format!("{}.", solver.name())) || k.starts_with("render."))
                .cloned()
                .collect();
            let (scene_sets, knob_sets): (Vec<_>, Vec<_>) = own.iter().cloned().partition(|(k, _)| is_scene_key(k));
            let estimate =
                solvers::memory_estimate(*solver, &s.with_overrides(&scene_sets).unwrap(), &Settings::new(&knob_sets))
                    .unwrap();
            let sets: Vec<(&str, &str)> = own.iter().map(|(k, v)| (k.as_str(), v.as_str())).collect();
            // A solver that refuses a scene it does not apply to (dom on anisotropic or
            // chromatic media, so far) allocates nothing there.
            let out = match crate::common::try_render(&gpu, &s, *solver, &sets, false) {
                Err(solvers::SolverError::Unsupported(_)) if solver.inapplicable(&s).is_some() => continue,
                r => r.unwrap(),
            };
            assert_eq!(
                estimate,
                out.report.device_bytes,
                "{what}: {} estimates {estimate} bytes, allocates {}",
                solver.name(),
                out.report.device_bytes
            );
        }
    }
    // sh-single's grid index (sh-single.index=grid): its buffers depend on where the samples lie.
    let s = scene(CUBE);
    let grid = vec![("sh-single.index".to_string(), "grid".to_string())];
    let estimate = solvers::memory_estimate(crate::common::SH_SINGLE, &s, &Settings::new(&grid)).unwrap();
    let out = crate::common::render(&gpu, &s, crate::common::SH_SINGLE, &[("sh-single.index", "grid")]);
    assert_eq!(estimate, out.report.device_bytes, "sh-single with its grid index");
    assert_clean(&gpu);
}

/// Every `layout(constant_id = N) const T NAME` in glsl/ names the same constant as
/// `gpu_scene::SPEC_NAMES` (the names a render's JSON gives each pipeline's features), and no
/// id means two things.
#[test]
fn specialisation_constant_names_match_the_glsl() {
    use scatterlab::solvers::parts::gpu_scene::SPEC_NAMES;
    let mut seen: std::collections::BTreeMap<u32, String> = Default::default();
    for p in files_under(&Path::new(env!("CARGO_MANIFEST_DIR")).join("glsl")) {
        {
            let text = std::fs::read_to_string(&p).unwrap();
            for line in text.lines() {
                let Some(rest) = line.trim().strip_prefix("layout(constant_id = ") else { continue };
                let (id, decl) = rest.split_once(')').expect("constant_id = N)");
                let id: u32 = id.trim().parse().expect("a numeric constant_id");
                // `const T NAME = ...;`
                let name = decl.split_whitespace().nth(2).expect("const T NAME").to_string();
                if let Some(before) = seen.insert(id, name.clone()) {
                    assert_eq!(before, name, "constant_id {id} names two constants ({})", p.display());
                }
            }
        }
    }
    let table: std::collections::BTreeMap<u32, String> = SPEC_NAMES.iter().map(|(i, n)| (*i, n.to_string())).collect();
    assert_eq!(seen, table, "gpu_scene::SPEC_NAMES differs from the GLSL declarations");
}

/// docs/architecture.md's row for meshes names exactly the solvers that render them.
#[test]
fn the_architecture_names_the_solvers_that_render_meshes() {
    let doc = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/architecture.md")).unwrap();
    let row = doc.lines().find(|l| l.starts_with("| an [[object]]'s mesh")).expect("the mesh row");
    let users = row.rsplit('|').nth(1).expect("the row's last column");
    for s in scatterlab::solvers::SOLVERS {
        let named = users.contains(&format!("`{}`", s.name()));
        assert_eq!(named, s.renders_meshes(), "docs/architecture.md's mesh row and {}: {users}", s.name());
    }
}

/// The modules of cli/ import one another without a circle (mod.rs, which declares them and
/// holds the argument types, aside): the shared helpers live in cli/args.rs, below the rest.
#[test]
fn cli_modules_import_without_a_circle() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/cli");
    let mut edges: Vec<(String, String)> = Vec::new();
    let mut files: Vec<String> = Vec::new();
    for e in std::fs::read_dir(&dir).unwrap() {
        let p = e.unwrap().path();
        let stem = p.file_stem().unwrap().to_string_lossy().into_owned();
        if p.extension().is_none_or(|x| x != "rs") || stem == "mod" {
            continue;
        }
        let text = std::fs::read_to_string(&p).unwrap();
        files.push(stem.clone());
        for part in text.split("super::").skip(1) {
            let name: String = part.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
            if !name.is_empty() && name != stem {
                edges.push((stem.clone(), name));
            }
        }
    }
    // Depth-first search for a back edge.
    fn visit(n: &str, edges: &[(String, String)], path: &mut Vec<String>, done: &mut Vec<String>) -> Option<String> {
        if let Some(i) = path.iter().position(|p| p == n) {
            return Some(format!("{} -> {n}", path[i..].join(" -> ")));
        }
        if done.iter().any(|d| d == n) {
            return None;
        }
        path.push(n.to_string());
        for (_, to) in edges.iter().filter(|(from, _)| from == n) {
            if let Some(c) = visit(to, edges, path, done) {
                return Some(c);
            }
        }
        path.pop();
        done.push(n.to_string());
        None
    }
    assert!(files.len() >= 3, "cli/ has {files:?}");
    let mut done = Vec::new();
    for f in &files {
        if let Some(circle) = visit(f, &edges, &mut Vec::new(), &mut done) {
            panic!("an import circle in src/cli: {circle}");
        }
    }
}

/// docs/architecture.md's shared-parts table is true: one row per file or folder of
/// src/solvers/parts/, and its "used by" column names exactly the solvers and parts whose
/// sources import that part (by `parts::<part>`, in a `parts::{..}` group, or as a sibling
/// part's `super::<part>`).
#[test]
fn the_shared_parts_table_is_true() {
    use std::collections::{BTreeMap, BTreeSet};
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let doc = std::fs::read_to_string(root.join("docs/architecture.md")).unwrap();
    let section = doc.split("## Shared parts").nth(1).expect("a shared parts section");
    // part -> the names in its row's last column (`path`, `parts/view`).
    let mut table: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for row in section.lines().take_while(|l| !l.starts_with("## ")).filter(|l| l.starts_with("| ")) {
        let cols: Vec<&str> = row.split(" | ").collect();
        let Some(file) = cols.get(1).and_then(|c| c.strip_prefix("`parts/")) else { continue };
        let part = file.trim_end_matches('`').trim_end_matches(".rs").trim_end_matches('/').to_string();
        let users = cols.last().unwrap().split('`').skip(1).step_by(2).map(str::to_string).collect();
        assert!(table.insert(part.clone(), users).is_none(), "two rows for parts/{part}");
    }
    // The parts on disk.
    let parts_dir = root.join("src/solvers/parts");
    let mut parts = BTreeSet::new();
    for e in std::fs::read_dir(&parts_dir).unwrap() {
        let p = e.unwrap().path();
        let stem = p.file_stem().unwrap().to_string_lossy().into_owned();
        if stem != "mod" {
            parts.insert(stem);
        }
    }
    assert_eq!(table.keys().cloned().collect::<BTreeSet<_>>(), parts, "the table's rows and src/solvers/parts/");
    // Who imports each part, from the sources (comments out).
    let mut found: BTreeMap<String, BTreeSet<String>> = parts.iter().map(|p| (p.clone(), BTreeSet::new())).collect();
    for p in files_under(&root.join("src/solvers")) {
        let rel = p.strip_prefix(root.join("src/solvers")).unwrap().to_string_lossy().into_owned();
        let mut segs = rel.split('/');
        let top = segs.next().unwrap().to_string();
        let who = match top.as_str() {
            "mod.rs" | "interface" => continue,
            "parts" => format!("parts/{}", segs.next().unwrap().trim_end_matches(".rs")),
            module => SOLVERS.iter().map(|s| s.name()).find(|n| n.replace('-', "_") == module).unwrap().to_string(),
        };
        let code: String = std::fs::read_to_string(&p)
            .unwrap()
            .lines()
            .filter(|l| !l.trim_start().starts_with("//"))
            .collect::<Vec<_>>()
            .join("\n");
        let groups: Vec<&str> = code.split("parts::{").skip(1).map(|r| &r[..r.find('}').unwrap_or(r.len())]).collect();
        for part in &parts {
            if who == format!("parts/{part}") {
                continue;
            }
            let word = |text: &str, prefix: &str| {
                text.match_indices(&format!("{prefix}{part}")).any(|(i, m)| {
                    let after = text[i + m.len()..].chars().next();
                    !after.is_some_and(|c| c.is_alphanumeric() || c == '_')
                })
            };
            let sibling = top == "parts" && word(&code, "super::");
            let in_group = groups.iter().any(|g| g.split([',', ' ', '\n', ':', '{']).any(|w| w == part));
            if word(&code, "parts::") || in_group || sibling {
                found.get_mut(part).unwrap().insert(who.clone());
            }
        }
    }
    for part in &parts {
        assert_eq!(table[part], found[part], "docs/architecture.md's row for parts/{part}: used by");
    }
}

/// A medium's coefficients reach the kernels by one route, the scene block's material table
/// (glsl/include/scene_block.glsl): no push-constant block in glsl/ carries sigma_t, albedo,
/// sigma_s, sigma_a or an index of refraction, and the scene block's header holds no copy of
/// the table's entries. g is left in two kinds of push constants, named here: the phase
/// function's probe (a test kernel over any g, no medium) and dom's sweeps, whose medium is
/// the voxel fields they sweep (sigma_t and sigma_s per voxel and channel, resampled on the
/// host and streamed out of core in blocks) with g beside them.
#[test]
fn material_coefficients_reach_kernels_by_the_material_table_only() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("glsl");
    let coefficient = ["sigma_t", "albedo", "sigma_s", "sigma_a", "ior", "eta"];
    let g_allowed = ["probe/phase.comp", "ordinates/bin.comp", "ordinates/scatter.comp", "ordinates/block_sweep.comp"];
    let members = |block: &str| -> Vec<String> {
        block
            .lines()
            .map(|l| l.split("//").next().unwrap().trim().to_string())
            .filter(|l| l.ends_with(';'))
            .flat_map(|l| {
                // `vec4 a, b;` or `uint x[3];`: the names after the type.
                let names = l.trim_end_matches(';').split_once(' ').map_or("", |(_, n)| n).to_string();
                names.split(',').map(|n| n.split('[').next().unwrap().trim().to_string()).collect::<Vec<_>>()
            })
            .collect()
    };
    let mut blocks = 0;
    for p in files_under(&root) {
        {
            let rel = p.strip_prefix(&root).unwrap().to_string_lossy().into_owned();
            let text = std::fs::read_to_string(&p).unwrap();
            let Some(start) = text.find("layout(push_constant)") else { continue };
            let body = &text[start..];
            let block = &body[body.find('{').unwrap() + 1..body.find("} pc;").expect("a push block ends `} pc;`")];
            blocks += 1;
            for m in members(block) {
                assert!(!coefficient.contains(&m.as_str()), "{rel}: push constant `{m}` is a material coefficient");
                assert!(m != "g" || g_allowed.contains(&rel.as_str()), "{rel}: push constant `g` (read the table)");
            }
        }
    }
    assert!(blocks >= 30, "only {blocks} push-constant blocks found");
    let block = std::fs::read_to_string(root.join("include/scene_block.glsl")).unwrap();
    let header = &block[block.find("buffer SceneBlock {").unwrap()..];
    let header = &header[..header.find("} scene;").unwrap()];
    let names = members(header);
    assert!(names.contains(&"materials".to_string()), "the scene block holds the table: {names:?}");
    for m in &names {
        assert!(!coefficient.contains(&m.as_str()) && m != "g" && m != "object", "the header copies `{m}`");
    }
}

/// Every file under `dir`, at any depth.
fn files_under(dir: &Path) -> Vec<std::path::PathBuf> {
    let (mut files, mut stack) = (Vec::new(), vec![dir.to_path_buf()]);
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                files.push(p);
            }
        }
    }
    files
}

/// The kept `path` references' key (`scatterlab::REFERENCE_BUILD`, build.rs) leaves out the
/// SPIR-V folders `path` never runs: none of them may hold a kernel it does, or a changed
/// kernel would keep an old tracer's references. (The source it leaves out, the other solvers,
/// is held apart by `no_code_outside_a_solver_names_it`.)
#[test]
fn the_reference_build_leaves_out_no_kernel_path_runs() {
    let reference = scatterlab::solvers::reference();
    let excluded: Vec<&str> = scatterlab::REFERENCE_EXCLUDED_SPIRV.split(',').collect();
    assert!(excluded.len() >= 4 && excluded.contains(&"lattice"), "{excluded:?}");
    let kernels = reference.kernels();
    assert!(kernels.len() >= 2, "{} runs {} kernels", reference.name(), kernels.len());
    for k in kernels {
        let folder = k.shader.name.split('/').next().unwrap_or_default();
        assert!(
            !excluded.contains(&folder),
            "{} runs {} but spirv/{folder} is left out of REFERENCE_BUILD",
            reference.name(),
            k.shader.name
        );
    }
    assert_ne!(scatterlab::REFERENCE_BUILD, scatterlab::BUILD);
}

/// The shared parts kept in the references' key (`scatterlab::REFERENCE_PARTS`) are every part
/// `path` imports, following the imports from its folder through the parts (`parts::<name>` and,
/// inside a part, `super::<name>`; comments skipped): a part it reached but the key left out
/// would keep an old tracer's references after a change to that part.
#[test]
fn the_reference_build_keeps_every_part_path_imports() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/solvers");
    let kept: BTreeSet<&str> = scatterlab::REFERENCE_PARTS.split(',').collect();
    assert!(kept.contains("mod.rs"), "{kept:?}");
    let parts: BTreeSet<String> = std::fs::read_dir(src.join("parts"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().trim_end_matches(".rs").to_string())
        .collect();
    // The part modules named in `text`'s code (not its comments).
    let named = |text: &str, inside_parts: bool| -> BTreeSet<String> {
        let mut out = BTreeSet::new();
        for line in text.lines().filter(|l| !l.trim_start().starts_with("//")) {
            let mut prefixes = vec!["parts::"];
            if inside_parts {
                prefixes.push("super::");
            }
            for prefix in prefixes {
                for (i, _) in line.match_indices(prefix) {
                    let rest = &line[i + prefix.len()..];
                    // `parts::name` or a group, `parts::{a, b::c}`.
                    let group = rest.strip_prefix('{').map(|g| g.split('}').next().unwrap_or(g));
                    for item in group.map_or(vec![rest], |g| g.split(',').collect()) {
                        let name: String =
                            item.trim_start().chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
                        if parts.contains(&name) {
                            out.insert(name);
                        }
                    }
                }
            }
        }
        out
    };
    let mut todo: Vec<String> = files_under(&src.join("path"))
        .iter()
        .flat_map(|p| named(&std::fs::read_to_string(p).unwrap(), false))
        .collect();
    let mut reached = BTreeSet::new();
    while let Some(part) = todo.pop() {
        if !reached.insert(part.clone()) {
            continue;
        }
        let dir = src.join("parts").join(&part);
        let files = if dir.is_dir() { files_under(&dir) } else { vec![src.join("parts").join(format!("{part}.rs"))] };
        for f in files {
            todo.extend(named(&std::fs::read_to_string(&f).unwrap(), true));
        }
    }
    assert!(reached.contains("gpu_scene") && reached.contains("resumable"), "{reached:?}");
    for part in &reached {
        assert!(
            kept.contains(format!("{part}.rs").as_str()),
            "path imports parts::{part}, which REFERENCE_BUILD leaves out (build.rs, REFERENCE_PARTS)"
        );
    }
}

/// Every kernel that counts its SIMD batches' loop back-edges (defines SCATTERLAB_BATCH_LOOPS,
/// glsl/include/batch.glsl) charges each loop reachable from main exactly the loop constructs
/// llvmpipe runs per body run, and prepays main's: tools/glsl-loop-counts derives them from
/// the preprocessed source and exits 1 on a weight that does not match (a loop added to the
/// BVH query without raising MESH_HIT_LOOPS would undercount every step of lbl's march), or on
/// a kernel's generated W_ weights (<kernel>.loops.glsl, specialisation-aware) that are stale.
#[test]
fn batch_counting_kernels_charge_what_llvmpipe_runs() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut kernels: Vec<_> = files_under(&root.join("glsl"))
        .into_iter()
        .filter(|p| {
            p.extension().is_some_and(|x| x == "comp")
                && std::fs::read_to_string(p).unwrap().contains("#define SCATTERLAB_BATCH_LOOPS")
        })
        .collect();
    kernels.sort();
    for k in ["marching/march.comp", "path/trace.comp", "path/light.comp"] {
        assert!(kernels.iter().any(|p| p.ends_with(k)), "{k} does not count its batches: {kernels:?}");
    }
    for k in &kernels {
        let out = std::process::Command::new(root.join("tools/glsl-loop-counts"))
            .arg("--check")
            .arg(k)
            .output()
            .expect("tools/glsl-loop-counts runs (python3, glslangValidator: tools/setup-deps)");
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(out.status.success(), "{}: {}{}", k.display(), text, String::from_utf8_lossy(&out.stderr));
        // The step loop of the march: itself, the BVH query's 3, lobe_reflectance's 2 and the
        // forward population's channel loop.
        if k.ends_with("marching/march.comp") {
            assert!(
                text.lines().any(|l| l.starts_with("loop main:") && l.contains(" S=7 ") && l.ends_with("charged=7")),
                "{text}"
            );
        }
        // The path kernels' event loop charges its generated, specialisation-aware weight.
        if k.ends_with("path/trace.comp") || k.ends_with("path/light.comp") {
            assert!(text.lines().any(|l| l.starts_with("loop main:") && l.ends_with("charged=W_EVENTS")), "{text}");
        }
    }
}
