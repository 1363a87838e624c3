//! `dom` (issue 13), first stage: isotropic, in-core. Against `single` where nothing scatters
//! twice, against `path` on the homogeneous sphere (and converging as the grid refines, which
//! the D3Q6 lattice does not near lit faces), deterministic, and a clear refusal where it does
//! not apply yet.

use crate::common::{assert_clean, gpu, render, repo_scene, scene, try_render, SceneText, PATH, SINGLE};
use scatterlab::output::compare;
use scatterlab::solvers;

fn dom() -> &'static dyn solvers::Solver {
    solvers::find("dom").expect("dom is registered")
}

const SMALL: [(&str, &str); 3] = [("dom.rays", "8192"), ("dom.view_env_dirs", "16"), ("dom.directions", "s4")];

/// Albedo 0: no light scatters twice, so dom's image is single scattering exactly.
#[test]
fn dom_at_albedo_zero_is_single() {
    let gpu = gpu();
    let s = scene(&SceneText::base().set("medium.albedo", "0.0"));
    let d = render(&gpu, &s, dom(), &[SMALL.as_slice(), &[("dom.grid", "12")]].concat());
    let one = render(&gpu, &s, SINGLE, &[]);
    let m = compare(&d.image, &one.image).unwrap();
    assert!(m.rel_l2 < 1e-5, "dom at albedo 0 vs single: relL2 {}", m.rel_l2);
    assert_clean(&gpu);
}

/// The sphere (sigma_t 10, albedo 0.9, isotropic) against path: the error falls and the energy
/// approaches path's as the grid refines (a convergent transport scheme), and two renders agree
/// bit for bit.
#[test]
fn dom_converges_toward_path_on_the_sphere() {
    let gpu = gpu();
    let size = [("render.width", "32"), ("render.height", "32")];
    let s = repo_scene("scenes/homogeneous-sphere.toml", &size);
    let reference = render(&gpu, &s, PATH, &[("render.spp", "2048")]).image;
    let mut last = (f64::INFINITY, 0.0);
    for grid in ["8", "16", "32"] {
        let out = render(&gpu, &s, dom(), &[SMALL.as_slice(), &[("dom.grid", grid)]].concat());
        let m = compare(&out.image, &reference).unwrap();
        assert!(m.rel_l2 < last.0, "grid {grid}: relL2 {} did not fall from {}", m.rel_l2, last.0);
        assert!(m.energy_ratio > last.1, "grid {grid}: energy {} did not rise from {}", m.energy_ratio, last.1);
        last = (m.rel_l2, m.energy_ratio);
        let c = out.report.stats.convergence.expect("convergence reported");
        assert!(c.converged && c.final_change <= c.tolerance, "grid {grid}: {c:?}");
    }
    assert!(last.0 < 0.08 && (last.1 - 1.0).abs() < 0.05, "grid 32: relL2 {}, energy {}", last.0, last.1);
    let a = render(&gpu, &s, dom(), &[SMALL.as_slice(), &[("dom.grid", "8")]].concat());
    let b = render(&gpu, &s, dom(), &[SMALL.as_slice(), &[("dom.grid", "8")]].concat());
    assert!(a.image.data == b.image.data, "dom is not deterministic");
    assert_clean(&gpu);
}

/// Anisotropic media are refused with the reason, not rendered isotropically.
#[test]
fn dom_refuses_anisotropic_media_for_now() {
    let gpu = gpu();
    let s = scene(&SceneText::base().set("medium.g", "0.6"));
    let e = try_render(&gpu, &s, dom(), &SMALL, false).err().expect("refused").to_string();
    assert!(e.contains("g = 0.6") && e.contains("storage directions"), "{e}");
    assert!(dom().inapplicable(&s).is_some());
    assert_clean(&gpu);
}
