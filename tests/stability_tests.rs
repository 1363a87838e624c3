//! `scatterlab stability` end to end on its tiny cases: the sweep runs, its outputs parse, and
//! the solvers meet the hard requirements (finite, non-negative; `path` and `single` never
//! brighter than the lossless bound and exact on the pure absorber).

use crate::common::{LBL, PATH, SINGLE, WAVEFRONT};
use scatterlab::measure::stability;

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
    // The pure absorber and the furnace were checked against their exact answers by both.
    assert_eq!(out.iter().filter(|o| o.exact_error.is_some()).count(), 4);
    // CSV: header plus one row per outcome, every row with the header's column count.
    let csv = stability::csv(&out);
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert!(header.contains(&"passed") && header.contains(&"max_over_bound") && header.contains(&"exact_rel_l2"));
    assert_eq!(csv.lines().count(), out.len() + 1);
    let table = stability::table(&out);
    assert!(table.contains("pass") && !table.contains("FAIL"));
    assert_clean(&gpu);
}

/// `lbl` on the same sweep: always finite and non-negative, the lattice always converges, and
/// its pure absorber is `single` exactly. (Its energy bound is reported, not asserted here:
/// at albedo >= 0.99 it exceeds the furnace bound by up to 14%; see docs/lbl.md.)
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
    let cases = stability::cases().iter().filter(|c| !c.slow).count();
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
    eprintln!("{}", stability::table(&out));
    assert!(failed.contains(&"light inside, tau 1e1, albedo 0"), "explicit failures: {failed:?}");
    assert!(!failed.contains(&"light inside, tau 1e-3, albedo 0.99"), "explicit failures: {failed:?}");
    assert!(stability::csv(&out).contains("wavefront/explicit"));
    assert_clean(&gpu);
}
