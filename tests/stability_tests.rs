//! `scatterlab stability` end to end on its tiny cases: the sweep runs, its outputs parse, and
//! the solvers meet the hard requirements (finite, non-negative; `path` and `single` never
//! brighter than the lossless bound and exact on the pure absorber).

use crate::common::{LBL, NETWORKS, PATH, SINGLE, WAVEFRONT};
use scatterlab::measure::stability::{self, Outcome};
use scatterlab::solvers::SOLVERS;

use crate::common::{assert_clean, gpu};

#[test]
fn stability_sweep_path_and_single_pass_everything() {
    let gpu = gpu();
    let out = stability::run(&gpu, &[PATH, SINGLE], false, &|_| {}).unwrap();
    let cases = stability::cases().iter().filter(|c| !c.slow).count();
    // `path` also runs camera paths alone where its default light-traces: the lights at a voxel
    // centre and corner, and the light inside at tau 10 (not the light on the boundary, and not
    // at tau 1e-3, optically thin, where `auto` keeps camera paths).
    let camera: Vec<&str> = out.iter().filter(|o| o.variant == "camera paths").map(|o| o.case.as_str()).collect();
    assert_eq!(camera.len(), 4, "camera-path variants: {camera:?}");
    assert!(camera.iter().all(|c| !c.contains("tau 1e-3")), "{camera:?}");
    assert!(!camera.contains(&"light on the boundary") && !camera.contains(&"light outside"));
    assert_eq!(out.len(), 2 * cases + camera.len());
    for o in &out {
        assert!(o.passed, "{} / {}: {:?}", o.case, o.solver, o);
    }
    // The pure absorbers and the furnaces (the cube's and the slab's) and the pure absorbing
    // emitter were checked against their exact answers by both.
    assert_eq!(out.iter().filter(|o| o.exact_error.is_some()).count(), 10);
    // CSV: header plus one row per outcome, every row with the header's column count.
    let csv = stability::csv(&out).unwrap();
    let mut reader = csv::Reader::from_reader(csv.as_bytes());
    let header = reader.headers().unwrap().clone();
    assert!(["passed", "max_over_bound", "exact_rel_l2"].iter().all(|h| header.iter().any(|x| x == *h)), "{header:?}");
    let rows: Vec<csv::StringRecord> = reader.records().map(|r| r.expect("a CSV row")).collect();
    assert_eq!(rows.len(), out.len());
    // Case names hold commas ("light inside, tau 1e-3, albedo 0.99"): one field each.
    assert!(rows.iter().all(|r| r.len() == header.len()));
    assert_eq!(
        rows.iter().map(|r| r[0].to_string()).collect::<Vec<_>>(),
        out.iter().map(|o| o.case.clone()).collect::<Vec<_>>()
    );
    let table = stability::table(&out);
    assert!(table.contains("pass") && !table.contains("FAIL"));
    assert_clean(&gpu);
}

/// `lbl` on the same sweep: always finite and non-negative, the lattice always converges, its
/// pure absorber is `single` exactly, and every case passes the sweep's own judgement, the
/// energy bound included (before the escape weights and the surface drift of docs/lbl.md it
/// exceeded the furnace bound by up to 14% at albedo >= 0.99; with 4096 rays per light the
/// forward population's g 0.99 case drew pixels 30% over it, unasserted here until 2026-11-27),
/// but the thin slab's furnace (below).
#[test]
fn stability_sweep_lbl_hard_requirements() {
    let gpu = gpu();
    let out = stability::run(&gpu, &[LBL], false, &|_| {}).unwrap();
    for o in &out {
        assert!(o.finite && o.non_negative, "{}: {:?}", o.case, o);
        assert_eq!(o.converged, Some(true), "{}: lattice did not converge", o.case);
        if let (Some(e), true) = (o.exact_error, o.case == "albedo 0") {
            assert!(e < 1e-4, "{}: pure absorber error {e}", o.case);
        }
        // The thin slab (16:16:1 at the fitted grid), found by the sweep and not fixed
        // (docs/decisions.md): its furnace (albedo 1) draws pixels 1.8% over the environment's
        // radiance (dom: 1.7%) from its raymaps' noise (the largest pixel 0.989 at 4x the rays,
        // the mean 0.98), and forward-scattering (g 0.6, albedo 0.99) 17% over with the mean
        // over too (1.045), where the trust line warns of a thin layer. Held to that, so that a
        // fix, or a worse excess, shows here.
        if o.group == "shape" && (o.case.contains("albedo 1,") || o.case.contains("g 0.6")) {
            eprintln!("{}: passed {}, over the bound by {:.4}", o.case, o.passed, o.max_over_bound);
            let (limit, warned) = if o.case.contains("g 0.6") {
                (0.3, o.notes.iter().any(|n| n.contains("a layer")))
            } else {
                (0.03, true)
            };
            assert!(o.max_over_bound < limit && warned, "{}: {:?}", o.case, o);
            continue;
        }
        assert!(!o.counts_as_failure(), "{}: fails the sweep (over the bound by {})", o.case, o.max_over_bound);
    }
    let json = serde_json::to_value(&out).unwrap();
    assert!(json.as_array().unwrap().iter().all(|o| o["max_over_bound"].is_number()));
    assert_clean(&gpu);
}

/// `wavefront` on the sweep, both integrators: the exponential integrator's march never goes
/// negative or non-finite and its images are finite and non-negative everywhere, exact for the
/// pure absorber; the paper's explicit scheme fails where its march goes negative (the light
/// inside an absorbing, optically thick cube), which the table records. The exponential
/// integrator passes every case, the energy bound included: with the extrapolated boundary
/// (wavefront.boundary, the default) light leaks out of the cube, where the infinite-medium
/// diffusion kept it and came out 46% above the lossless bound at "light inside, tau 1e1,
/// albedo 0.99" (docs/wavefront.md).
#[test]
fn stability_sweep_wavefront_both_integrators() {
    let gpu = gpu();
    let out = stability::run(&gpu, &[WAVEFRONT], false, &|_| {}).unwrap();
    // wavefront refuses emission (its layers are centred on a point light): not run on emitters.
    let cases = stability::cases().iter().filter(|c| !c.slow && !c.emission).count();
    assert_eq!(out.len(), 2 * cases);
    for o in &out {
        assert!(o.finite && o.non_negative, "{}: {:?}", o.case, o);
        if o.variant == "exponential" {
            assert!(o.passed, "{}: {:?}", o.case, o);
            assert!(!o.notes.iter().any(|n| n.contains("went negative")), "{}: {:?}", o.case, o.notes);
            if o.case == "albedo 0" {
                assert!(o.exact_error.unwrap() < 1e-4, "{}: pure absorber error {:?}", o.case, o.exact_error);
            }
        }
    }
    let failed: Vec<&str> =
        out.iter().filter(|o| o.variant == "explicit" && !o.passed).map(|o| o.case.as_str()).collect();
    let table = stability::table(&out);
    eprintln!("{table}");
    assert!(failed.contains(&"light inside, tau 1e1, albedo 0"), "explicit failures: {failed:?}");
    assert!(!failed.contains(&"light inside, tau 1e-3, albedo 0.99"), "explicit failures: {failed:?}");
    assert!(stability::csv(&out).unwrap().contains("wavefront/explicit"));
    // The explicit scheme is a comparison variant: its failures are shown as expected and do
    // not fail the sweep; the exponential integrator's would.
    for o in &out {
        assert_eq!(o.comparison, o.variant == "explicit", "{}: {:?}", o.case, o);
    }
    assert!(out.iter().filter(|o| o.variant == "explicit").all(|o| !o.counts_as_failure()));
    assert!(table.contains("fail (expected)") && table.contains("wavefront/explicit"));
    assert_clean(&gpu);
}

/// `networks` on the sweep (256 particles, 32 directions, 16 environment directions): every
/// case passes and every iteration converges. Measured: the pure absorber is exact (relL2
/// 9.5e-6: the view pass computes it); the furnace's image is 11% under 1 (relL2 0.110), the
/// network's light scattered twice or more falling short with 256 particles (the paper's
/// image, `single = particles`, keeps the furnace at 1 to 1e-4: networks_tests); the
/// point-light cases 35-60% under the lossless bound. On the thin slab (16:16:1, 2 mean free
/// paths deep, 2.0 mean free paths a particle spacing at 256 particles: outside its range, and
/// warned where it scatters) networks creates energy: pixels over the environment's radiance at albedo 0.99 (by
/// 0.17 at 256 particles; the mean 1.056 at 1024, 0.967 at 4096 against path's 0.964), a bug
/// found by the sweep and not fixed (docs/networks.md): those cases fail the sweep, and this
/// test holds them to that (finite, non-negative, converged, over the bound by less than 0.3,
/// and warned) so that a fix shows here.
#[test]
fn stability_sweep_networks_passes() {
    let gpu = gpu();
    let out = stability::run(&gpu, &[NETWORKS], false, &|_| {}).unwrap();
    let cases = stability::cases().iter().filter(|c| !c.slow).count();
    assert_eq!(out.len(), cases);
    for o in &out {
        assert_eq!(o.converged, Some(true), "{}: {:?}", o.case, o);
        if o.group == "shape" {
            assert!(o.finite && o.non_negative && o.max_over_bound < 0.3, "{}: {:?}", o.case, o);
            // Warned where the slab scatters; at albedo 0 the particles make none of the image
            // (the view pass's march, exact): no warning.
            let warned = o.notes.iter().any(|n| n.contains("particle spacing"));
            assert_eq!(warned, !o.case.contains("albedo 0,"), "{}: the trust warning: {:?}", o.case, o);
            eprintln!("{}: passed {}, over the bound by {:.3}", o.case, o.passed, o.max_over_bound);
        } else {
            assert!(o.passed, "{}: {:?}", o.case, o);
        }
    }
    let exact = |case: &str| out.iter().find(|o| o.case == case).and_then(|o| o.exact_error).unwrap();
    assert!(exact("albedo 0") < 1e-4, "pure absorber {}", exact("albedo 0"));
    assert!(exact("albedo 1") < 0.15, "furnace {}", exact("albedo 1"));
    assert_clean(&gpu);
}

fn outcome(solver: &'static str, variant: &str, comparison: bool, passed: bool) -> Outcome {
    Outcome {
        case: "albedo 1".into(),
        group: "albedo",
        solver,
        variant: variant.into(),
        comparison,
        passed,
        finite: true,
        non_negative: true,
        energy_ok: passed,
        max_over_bound: if passed { 0.0 } else { 0.1 },
        exact_error: None,
        iterations: None,
        converged: None,
        gpu_ms: 1.0,
        notes: Vec::new(),
    }
}

/// Issue 11 item 7: `stability` exits 0 on its defaults while the paper's explicit wavefront
/// integrator, kept as a comparison variant, fails where it is known to. A comparison
/// variant's failure is judged and shown ("fail (expected)" in the table, `comparison` and
/// `counts_as_failure` in the CSV and JSON) but not counted (the command fails only on
/// `counts_as_failure`); a normal variant's failure is counted. Only `wavefront/explicit` is a
/// comparison variant, so no other solver's failure can hide behind the flag.
#[test]
fn a_comparison_variants_failure_is_shown_but_not_counted() {
    let normal_fails = outcome("wavefront", "exponential", false, false);
    let comparison_fails = outcome("wavefront", "explicit", true, false);
    let comparison_passes = outcome("wavefront", "explicit", true, true);
    assert!(normal_fails.counts_as_failure());
    assert!(!comparison_fails.counts_as_failure());
    assert!(!comparison_passes.counts_as_failure());
    let failed = |v: &[Outcome]| v.iter().filter(|o| o.counts_as_failure()).count();
    assert_eq!(failed(&[comparison_fails.clone(), comparison_passes.clone()]), 0);
    assert_eq!(failed(&[normal_fails.clone(), comparison_fails.clone()]), 1);

    let all = [normal_fails, comparison_fails, comparison_passes];
    let table = stability::table(&all);
    let rows: Vec<&str> = table.lines().collect();
    assert!(rows[1].contains("wavefront/exponential") && rows[1].contains("FAIL"), "{table}");
    assert!(rows[2].contains("wavefront/explicit") && rows[2].contains("fail (expected)"), "{table}");
    assert!(!rows[2].contains("FAIL"), "{table}");
    assert!(rows[3].contains(" pass "), "{table}");
    assert!(table.contains("1 check(s) of comparison variant(s) (wavefront/explicit)"), "{table}");

    let csv = stability::csv(&all).unwrap();
    let mut reader = csv::Reader::from_reader(csv.as_bytes());
    let header: Vec<String> = reader.headers().unwrap().iter().map(String::from).collect();
    let records: Vec<csv::StringRecord> = reader.records().map(|r| r.unwrap()).collect();
    let col = |name: &str| header.iter().position(|h| h == name).unwrap();
    let row = |i: usize| -> Vec<String> { records[i].iter().map(String::from).collect() };
    assert_eq!((row(0)[col("comparison")].as_str(), row(0)[col("counts_as_failure")].as_str()), ("false", "true"));
    assert_eq!((row(1)[col("comparison")].as_str(), row(1)[col("counts_as_failure")].as_str()), ("true", "false"));
    let json = serde_json::to_value(&all).unwrap();
    assert_eq!(json[1]["comparison"], true);
    assert_eq!(json[1]["passed"], false);
    assert_eq!(json[0]["comparison"], false);

    // Which variants are comparison variants: wavefront's explicit integrator (the paper's eq.
    // 6) and octaves' published sum (creates energy in thin media), and nothing else.
    let flagged: Vec<String> = SOLVERS
        .iter()
        .flat_map(|s| {
            s.stability().into_iter().filter(|v| v.comparison).map(move |v| format!("{}/{}", s.name(), v.name))
        })
        .collect();
    assert_eq!(flagged, ["wavefront/explicit", "octaves/published"]);
    assert!(WAVEFRONT.stability().iter().any(|v| v.name == "exponential" && !v.comparison));
}

/// sh-single (500 samples, order 4) passes every default case: finite, non-negative, never
/// above the lossless bound, the pure absorber exact (it is the chord's transmittance, as
/// `single`'s). Its single scattering is all of the image where the medium is optically thin:
/// with a point light inside at optical thickness 1e-3 and albedo 0.99 the lossless bound
/// (path, every order) is nearly single scattering, and sh-single must come within 10% of it
/// (measured 5.4% under; `single` 0.7% over, within path's noise).
#[test]
fn stability_sweep_sh_single_passes() {
    let gpu = gpu();
    let out = stability::run(&gpu, &[crate::common::SH_SINGLE], false, &|_| {}).unwrap();
    let cases = stability::cases().iter().filter(|c| !c.slow).count();
    assert_eq!(out.len(), cases);
    for o in &out {
        assert!(o.passed, "{}: {:?}", o.case, o);
    }
    let find = |case: &str| out.iter().find(|o| o.case == case).unwrap();
    let absorber = find("albedo 0").exact_error.unwrap();
    assert!(absorber < 1e-4, "pure absorber {absorber}");
    let thin = find("light inside, tau 1e-3, albedo 0.99").max_over_bound;
    assert!(thin > -0.1, "thin medium, light inside: {thin} under the lossless bound");
    assert_clean(&gpu);
}

/// A unit cube of constant density seen by an 8 x 8 orthographic camera, its lights' TOML after it.
const CUBE: &str = "[render]\nwidth = 8\nheight = 8\nspp = 1\n[camera]\nkind = \"orthographic\"\n\
     origin = [0.0, 0.0, 3.0]\ntarget = [0.0, 0.0, 0.0]\nextent = 2.0\n[medium]\n\
     bounds = [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]\nsigma_t = 2.0\nalbedo = 0.5\ndensity = { kind = \"constant\" }\n";

/// [`CUBE`] lit by `lights` point lights in a ring outside it.
fn many_lights(lights: usize) -> scatterlab::scene::Scene {
    let mut text = String::from(CUBE);
    for i in 0..lights {
        let a = i as f64 * std::f64::consts::TAU / lights as f64;
        text += &format!(
            "[[light]]\nkind = \"point\"\nposition = [{:.6}, {:.6}, 1.0]\nintensity = 1e-4\n",
            2.0 * a.cos(),
            2.0 * a.sin()
        );
    }
    crate::common::scene(&text)
}

#[test]
fn light_loops_that_cannot_pause_are_refused_past_the_loop_guard_by_name() {
    // A shadow invocation (glsl/view/shadow.comp) and a networks direct-light invocation
    // (glsl/networks/direct.comp) each loop over every light and march the medium in loops
    // that cannot pause; on llvmpipe n iterations take n + 1 of the 65535 back-edges, past
    // which every loop ends silently. Before these checks, networks counted steps + lights
    // (15001 lights at 30000 steps passed as 45001) and the shadow pass nothing.
    let gpu = gpu();
    let diag = 3f64.sqrt();
    // single: the unit cube's diagonal in 16384 shadow steps (the most allowed) takes
    // 2 x 16384 back-edges both ways, plus lights + 1: 27300 lights pass 60000.
    let step = format!("{}", diag / 16384.0 * 1.0001);
    let sets = [("single.shadow_step", step.as_str()), ("single.shadow", "march")];
    let err = crate::common::try_render(&gpu, &many_lights(27300), SINGLE, &sets, false).err().expect("refused");
    let err = err.to_string();
    assert!(err.contains("single.shadow_step") && err.contains("27300 lights") && !err.contains('\n'), "{err}");
    let ok = crate::common::try_render(&gpu, &many_lights(2), SINGLE, &sets, false).expect("two lights render");
    assert!(ok.image.data.iter().all(|v| v.is_finite()) && ok.image.mean()[0] > 0.0);
    // networks: 28998 steps and 15600 lights: 28999 + 2 x 15601 = 60201.
    let step = format!("{}", diag / 29000.0 * 1.0001);
    let sets = [("networks.step", step.as_str()), ("networks.particles", "64")];
    let err = crate::common::try_render(&gpu, &many_lights(15600), NETWORKS, &sets, false).err().expect("refused");
    let err = err.to_string();
    assert!(err.contains("networks.step") && err.contains("15600 lights") && !err.contains('\n'), "{err}");
    assert_clean(&gpu);
}

#[test]
fn light_rays_past_one_binding_are_refused_by_name_before_they_are_made() {
    // lbl and dom march `rays` rays per light: with many lights the rays and their history
    // pass one device binding. Counted before they are made, the render is one line naming the
    // knob (it was a binding error naming a buffer, after the host had built every ray: 2000
    // lights at 65536 rays each, 12.6 GB).
    let gpu = gpu();
    let per_ray = 16 * 16; // the history at the default k = 16 is the widest buffer
                           // (twice the lights whose every ray would fill one binding: some rays miss the box)
    let lights = 2 * (gpu.info().max_storage_buffer_range / (65536 * per_ray)) as usize + 2;
    let s = many_lights(lights);
    let dom: &dyn scatterlab::solvers::Solver = &scatterlab::solvers::dom::Dom;
    for (solver, key) in [(LBL, "lbl.rays"), (dom, "dom.rays")] {
        let err = crate::common::try_render(&gpu, &s, solver, &[], false).err().expect("refused").to_string();
        assert!(err.contains(key) && err.contains(&format!("{lights} lights")) && !err.contains('\n'), "{err}");
    }
    assert_clean(&gpu);
}

#[test]
fn a_line_of_work_past_65535_groups_folds_into_rows_and_sums_the_same() {
    // lbl's transfer adds every ray's history (rays x k entries, one invocation each, 64 to a
    // group): the rays of 10^6 that reach the cube at k = 16 make more than 65535 groups along
    // x, past what lavapipe dispatches; folded into rows (Pass::cover_linear) they must sum
    // what k = 8 (one row) sums. Fixed-point transfer: exact sums in any
    // order; k moves where the rounds fall against the lattice's iterations (1.2e-5 at 3 x 10^5
    // rays). A second row lost would lose its entries (percents of them), one run twice add as
    // much: the tolerance tells them apart.
    let gpu = gpu();
    let s = crate::common::scene(&format!(
        "{CUBE}[[light]]\nkind = \"directional\"\ndirection = [0.3, -1.0, 0.2]\nirradiance = 1.0\n"
    ));
    let common = [("lbl.rays", "1000000"), ("lbl.grid", "16"), ("lbl.deterministic", "true")];
    // The rays that reach the box (the beam's square is wider than the cube's shadow).
    let geom = scatterlab::solvers::parts::lattice::LatticeGeom::new(&s, 16);
    let (rays, _) = scatterlab::solvers::parts::marching::ray_count(&s, &geom, 1_000_000, 1, 0.01, s.render.seed);
    let groups = |k: u64| (rays * k).div_ceil(64);
    assert!(groups(16) > 65535 && groups(8) <= 65535, "{rays} rays: {} and {} groups", groups(16), groups(8));
    let run = |k: &str| {
        let sets: Vec<(&str, &str)> = common.iter().copied().chain([("lbl.k", k)]).collect();
        crate::common::try_render(&gpu, &s, LBL, &sets, false).expect("lbl renders")
    };
    let (folded, one_row) = (run("16"), run("8"));
    let (a, b) = (folded.image.mean()[0], one_row.image.mean()[0]);
    assert!(a > 0.0 && ((a - b) / b).abs() < 1e-3, "folded {a} vs one row {b}");
    assert_clean(&gpu);
}
