//! The grid solvers' trust line (issue 44, item 2): a render whose grid puts fewer voxels
//! across the medium's thinnest side than the solver was validated at says so, in one warning
//! that names the knob and the value that fixes it, and in the JSON's `trust` block; at that
//! value the warning is gone.

use crate::common::{assert_clean, gpu, render, scene, try_render, LBL};
use scatterlab::solvers;
use scatterlab::solvers::dom::DomStats;
use scatterlab::solvers::lbl::LblStats;
use scatterlab::solvers::parts::lattice::{GridTrust, VALIDATED_ACROSS};

/// A slab 4 x 0.5 x 4 (y thin), sigma_t 4 (2 mean free paths thick), albedo 0.8, lit from
/// above, seen from above: the shape where a grid counted along the longest side starves the
/// thin one.
fn slab() -> scatterlab::scene::Scene {
    scene(
        "[render]\nwidth = 12\nheight = 12\nseed = 3\nspp = 16\n\
         [camera]\norigin = [0.0, 6.0, 0.0]\ntarget = [0.0, 0.0, 0.0]\nup = [0.0, 0.0, -1.0]\nfov = 30.0\n\
         [medium]\nbounds = [[-2.0, -0.25, -2.0], [2.0, 0.25, 2.0]]\nsigma_t = 4.0\nalbedo = 0.8\ng = 0.0\n\
         density = { kind = \"constant\" }\n\
         [[light]]\nkind = \"directional\"\ndirection = [0.0, -1.0, 0.0]\nirradiance = 3.0\n",
    )
}

fn check_trust(t: &GridTrust, across: [f32; 3], grid_for: u32, tau: f32) {
    for a in 0..3 {
        assert!((t.voxels_across[a] - across[a]).abs() < 1e-3, "voxels across {:?}, want {across:?}", t.voxels_across);
    }
    assert_eq!(t.thinnest_axis, 1, "the slab is thin along y");
    assert_eq!(t.validated_across, VALIDATED_ACROSS);
    assert_eq!(t.grid_for_validated, grid_for);
    assert!((t.voxel_optical_depth - tau).abs() < 1e-5, "voxel optical depth {} want {tau}", t.voxel_optical_depth);
}

/// dom and lbl on the slab at grid 16 (2 voxels across its 0.5 thickness) warn once, naming
/// `<solver>.grid=64`; at grid 64 (8 across) they render without a warning.
#[test]
fn a_grid_too_coarse_across_a_thin_slab_is_named_and_the_fix_clears_it() {
    let gpu = gpu();
    let s = slab();
    let dom = solvers::find("dom").expect("dom is registered");
    let small_dom = [("dom.rays", "4096"), ("dom.view_env_dirs", "16"), ("dom.directions", "s4")];
    for (solver, name) in [(dom, "dom"), (LBL, "lbl")] {
        let sets: Vec<(&str, &str)> = if name == "dom" { small_dom.to_vec() } else { Vec::new() };
        let grid = format!("{name}.grid");
        let coarse = [sets.as_slice(), &[(grid.as_str(), "16")]].concat();
        let out = try_render(&gpu, &s, solver, &coarse, false).unwrap_or_else(|e| panic!("{name}: {e}"));
        let trust = |o: &scatterlab::solvers::RenderOutput| match name {
            "dom" => o.report.detail::<DomStats>().expect("dom stats").trust,
            _ => o.report.detail::<LblStats>().expect("lbl stats").trust,
        };
        check_trust(&trust(&out), [16.0, 2.0, 16.0], 64, 4.0 * 0.25);
        let w = &out.report.warnings;
        assert_eq!(w.len(), 1, "{name}: one warning: {w:?}");
        // The error measured on the wide slab at 2 voxels across (SLAB_ENERGY).
        let measured = if name == "dom" { "at 2 voxels across gave 0.98x" } else { "at 2 voxels across gave 1.06x" };
        for part in ["thinnest side (y)", "spans 2.0 voxels", &format!("{name}.grid=64"), measured] {
            assert!(w[0].contains(part), "{name}: the warning names {part:?}: {}", w[0]);
        }
        assert!(solver.summary(&out.report).iter().any(|l| l.contains("OUTSIDE")), "{name}: the summary says so");
        // What the grid changes: the slab's brightness seen from the lit side.
        let fine = render(&gpu, &s, solver, &[sets.as_slice(), &[(grid.as_str(), "64")]].concat());
        check_trust(&trust(&fine), [64.0, 8.0, 64.0], 64, 4.0 * 0.0625);
        assert!(!solver.summary(&fine.report).iter().any(|l| l.contains("OUTSIDE")));
        let mean = |o: &scatterlab::solvers::RenderOutput| o.image.data.iter().map(|v| *v as f64).sum::<f64>();
        println!("{name}: slab 2 mfp thick, reflected radiance at grid 16 / grid 64 = {:.3}", mean(&out) / mean(&fine));
    }
    assert_clean(&gpu);
}

/// A cube at the solvers' test grids is within the validated range, and its trust line says
/// how far: 12 across at grid 12.
#[test]
fn a_cube_at_grid_twelve_is_within_the_validated_range() {
    let s = crate::common::issue_cube("0.0");
    let geom = scatterlab::solvers::parts::lattice::LatticeGeom::new(&s, 12);
    let t = geom.trust(&s);
    assert!(t.within(), "{t:?}");
    assert_eq!(t.warning("dom"), None);
    assert!((t.fewest() - 12.0).abs() < 1e-3);
    assert!(t.line().contains("12.0 x 12.0 x 12.0 voxels across"), "{}", t.line());
    let coarse = scatterlab::solvers::parts::lattice::LatticeGeom::new(&s, 6);
    assert!(coarse.trust(&s).warning("dom").is_some_and(|w| w.contains("dom.grid=8")));
}
