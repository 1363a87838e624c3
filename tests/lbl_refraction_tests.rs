//! `lbl` on scene format v2 objects (issue 16, item 5): the lattice over the mesh's voxelised
//! occupancy (thesis 4.3), light rays refracted at the surface with the Fresnel split, the
//! lattice's links reflected back in at a refractive boundary, camera rays through the view
//! march's chain. Checked: the occupancy against the meshes' volumes; the diffuse Fresnel
//! reflectance against reciprocity; lbl against `path` (full multiple scattering) on a glass
//! sphere across optical thickness, albedo and g, with the energy, and against lbl with
//! refraction turned off.

use scatterlab::physics::dielectric::diffuse_fresnel;
use scatterlab::scene::voxelise;

use crate::common::{assert_clean, gpu, judge, render, scene, LBL};
use crate::refraction_tests::{fan_cone_obj, mesh, object_scene_seeded, ENV};

#[test]
fn occupancy_integrates_to_the_mesh_volume() {
    // The covered length along z is exact per column; the 8 x 8 columns per voxel sample the
    // footprint. Summed, the occupancy is the mesh's volume (divergence theorem) to the
    // sampling of the silhouette's edge.
    for file in ["icosphere.obj", "torus.obj", "blob.obj"] {
        let text = object_scene_seeded(
            1,
            &format!("mesh = \"{}\"\nscale = 0.8", mesh(file)),
            "sigma_t = 1.0\nalbedo = 0.5",
            ENV,
            8,
            1,
        );
        let s = scene(&text);
        let o = s.object.as_ref().unwrap();
        let exact = o.mesh.volume();
        let (lo, hi) = (s.medium.bounds_min, s.medium.bounds_max);
        for grid in [8u32, 32] {
            let lambda = (hi - lo).max_element() / grid as f32;
            let dims = [0, 1, 2].map(|a| ((hi[a] - lo[a]) / lambda - 1e-4).ceil().max(1.0) as u32);
            let occ = voxelise::occupancy(o, lo, lambda, dims, voxelise::SUPERSAMPLE);
            assert!(occ.iter().all(|v| (0.0..=1.0).contains(v)), "{file}: occupancy outside [0, 1]");
            let sum: f64 = occ.iter().map(|v| *v as f64).sum::<f64>() * (lambda as f64).powi(3);
            let full = occ.iter().filter(|v| **v == 1.0).count();
            eprintln!("{file} grid {grid}: occupied volume {sum:.5} against {exact:.5}; {full} voxels full");
            // Measured: 1e-4 (icosphere), 2.3e-3 (torus) at grid 8; 2.4e-5 at grid 32.
            let tol = if grid == 8 { 4e-3 } else { 1e-3 };
            assert!((sum / exact - 1.0).abs() < tol, "{file} grid {grid}: {sum} against {exact}");
            assert!(full > 0 && occ.contains(&0.0), "{file}: no full or no empty voxel");
        }
    }
}

#[test]
fn diffuse_fresnel_reflectance_obeys_reciprocity() {
    // A diffuse flux through a smooth boundary: what crosses from the dense side, 1 - R_in,
    // times n^2 is what crosses from the other, 1 - R_out (the radiance n^2 invariant over the
    // cosine-weighted hemisphere). Index-matched, nothing reflects.
    assert!(diffuse_fresnel(1.0).abs() < 1e-9);
    for n in [1.1f64, 1.33, 1.5, 2.0, 2.5] {
        let (r_in, r_out) = (diffuse_fresnel(n), diffuse_fresnel(1.0 / n));
        let lhs = (1.0 - r_in) * n * n;
        assert!((lhs - (1.0 - r_out)).abs() < 2e-4, "n {n}: (1 - {r_in}) n^2 = {lhs} against 1 - {r_out}");
        assert!(r_in > r_out && r_in < 1.0);
    }
    // Egan and Hilgeman's fit (the dipole model's) at 1.5, from inside: 0.596.
    assert!((diffuse_fresnel(1.5) - 0.596).abs() < 2e-3, "{}", diffuse_fresnel(1.5));
}

/// `path` and lbl (grid `grid`, camera steps of 0.05) with and without refraction on the scene
/// `text`: lbl's render with it, and [relL2, energy ratio] of each against path (printed).
fn with_and_without_refraction(
    gpu: &scatterlab::gpu::Gpu,
    text: &str,
    grid: &str,
    name: &str,
) -> (scatterlab::solvers::RenderOutput, [f64; 2], [f64; 2]) {
    let s = scene(text);
    // Without the light's beams reflected inside the glass before they scatter
    // (`path.mnee_reflections=0`), which lbl does not model either: on a glass sphere they add
    // about 1% of the image, and carrying them takes path 4-10x the time (tests/mnee_tests.rs).
    let reference = crate::common::path_reference(gpu, &s, &[("path.mnee_reflections", "0")]);
    let sets = [("lbl.grid", grid), ("lbl.view_step", "0.05")];
    let on = render(gpu, &s, LBL, &sets);
    let off = render(gpu, &s, LBL, &[sets[0], sets[1], ("lbl.refraction", "false")]);
    let (rel_on, e_on) = judge(&on.image, &reference);
    let (rel_off, e_off) = judge(&off.image, &reference);
    eprintln!("{name}: refraction relL2 {rel_on:.4} energy {e_on:.4}; off relL2 {rel_off:.4} energy {e_off:.4}");
    (on, [rel_on, e_on], [rel_off, e_off])
}

#[test]
fn lbl_with_refraction_agrees_with_path_across_the_range() {
    // A glass sphere (ior 1.5) with media from thin to optical radius 20, albedo 0 to 0.99,
    // g -0.9 to 0.9, under a uniform environment, against `path` (all orders, exact
    // dielectric): with refraction lbl is within 5% of path's energy and better than lbl with
    // the boundary index-matched at moderate thickness, forward scattering and albedo 0, and
    // within 8% elsewhere; the cases where it does not beat the index-matched lattice say why.
    let gpu = gpu();
    // (medium, name, max relL2 with refraction, refraction must beat off)
    let cases = [
        // Thin: under a uniform environment a nearly empty glass is nearly a furnace, and
        // refraction changes little (measured at 20 x 20: relL2 0.0435 with it, 0.0432 without;
        // energy 1.017 and 1.032).
        ("sigma_t = 0.5\nalbedo = 0.9\ng = 0.0", "thin", 0.08, false),
        ("sigma_t = 4.0\nalbedo = 0.95\ng = 0.9", "g 0.9", 0.08, true),
        ("sigma_t = 8.0\nalbedo = 0.95\ng = 0.0", "sigma_t 8", 0.08, true),
        // Thick and nearly lossless: the staircase surface lets the trapped light out over
        // about 1.5 times the sphere's area, so lbl is dark with refraction (20 x 20: energy
        // 0.944, relL2 0.089); without it, the index-matched lattice's own excess near a
        // surface happens to land near glass's trapping (1.033, 0.056).
        ("sigma_t = 20.0\nalbedo = 0.99\ng = 0.0", "thick", 0.12, false),
        ("sigma_t = 20.0\nalbedo = 0.0\ng = 0.0", "albedo 0", 0.1, true),
        // Strong back-scattering: the light scattered back leaves near the surface it entered,
        // peaked along the normal, where the glass reflects 4% of it; the diffuse reflectance
        // (60%) the lattice applies to every link traps too much (20 x 20: energy 1.022, relL2
        // 0.075; off 0.970, 0.050; at 32 x 32, grid 32: 1.046, 0.094; off 0.992, 0.030).
        ("sigma_t = 4.0\nalbedo = 0.99\ng = -0.9", "g -0.9", 0.15, false),
    ];
    for (medium, name, max_rel, beats_off) in cases {
        let text =
            object_scene_seeded(7, &format!("mesh = \"{}\"\nior = 1.5", mesh("icosphere.obj")), medium, ENV, 20, 256);
        let (on, [rel_on, e_on], [rel_off, _]) = with_and_without_refraction(&gpu, &text, "20", name);
        assert!(on.image.data.iter().all(|v| v.is_finite() && *v >= 0.0), "{name}: a pixel is not finite");
        assert!((e_on - 1.0).abs() < if beats_off { 0.05 } else { 0.08 }, "{name}: energy ratio {e_on}");
        assert!(rel_on < max_rel, "{name}: relL2 {rel_on}");
        if beats_off {
            assert!(rel_on < rel_off, "{name}: refraction {rel_on} vs off {rel_off}");
        }
    }
    assert_clean(&gpu);
}

#[test]
fn lbl_measures_its_marching_rounds_through_a_mesh_and_refuses_those_past_the_loop_limiter() {
    // A round of k steps costs what the mesh's BVH traversals cost, which the mesh sets: the
    // march counts its SIMD batches' loop back-edges as llvmpipe does (march.comp's Loops).
    let gpu = gpu();
    // An ordinary mesh takes the knob's whole range: the icosphere at k 256 took a few
    // thousand back-edges a round (milk-orb's at 64: 1886) and gives k 16's image.
    let text = object_scene_seeded(
        7,
        &format!("mesh = \"{}\"\nior = 1.5", mesh("icosphere.obj")),
        "sigma_t = 2.0\nalbedo = 0.9",
        ENV,
        8,
        1,
    );
    let sets = [("lbl.rays", "4096"), ("lbl.grid", "16"), ("lbl.deterministic", "true")];
    let with_k = |k: &str| {
        let s: Vec<(&str, &str)> = sets.iter().copied().chain([("lbl.k", k)]).collect();
        crate::common::try_render(&gpu, &scene(&text), LBL, &s, false)
    };
    let (long, short) = (with_k("256").expect("k 256 through the icosphere"), with_k("16").unwrap());
    let m = scatterlab::output::compare(&long.image, &short.image).unwrap();
    assert!(m.rel_l2 < 1e-3 && (m.energy_ratio - 1.0).abs() < 1e-3, "k 256 against 16: {m:?}");
    // lavapipe is loop-limited: the march was built to count its batches.
    let march = long.report.pipelines.iter().find(|p| p.shader == "marching/march").expect("the march kernel");
    assert!(matches!(march.spec.get("LOOP_LIMITED"), Some(scatterlab::gpu::Spec::Bool(true))), "{:?}", march.spec);

    // The fan cone of 8192: one step's query takes a SIMD batch about 25000 back-edges, so from
    // k 3 on a round passes the limiter, where lanes' own counts stayed below it (36721 at k
    // 64, the image 15% wrong at 64 and 1.6e-3 at 6 before this check). Refused in one line
    // naming the knob and the k that fits; that k renders what k 1 does.
    let dir = tempfile::tempdir().unwrap();
    let cone = dir.path().join("cone.obj");
    std::fs::write(&cone, fan_cone_obj(8192)).unwrap();
    let light = "kind = \"point\"\nposition = [1.6, 1.4, 1.2]\nintensity = 5.0";
    let text =
        object_scene_seeded(1, &format!("mesh = \"{}\"", cone.display()), "sigma_t = 4.0\nalbedo = 0.9", light, 16, 1);
    let with_k = |k: &str| {
        let s: Vec<(&str, &str)> = sets.iter().copied().chain([("lbl.k", k)]).collect();
        crate::common::try_render(&gpu, &scene(&text), LBL, &s, false)
    };
    let msg = with_k("16").err().expect("k 16 through the fan cone is refused").to_string();
    assert!(msg.contains("lbl.k: 16:") && msg.ends_with("use lbl.k <= 2") && !msg.contains('\n'), "{msg}");
    let (two, one) = (with_k("2").expect("the k it names"), with_k("1").unwrap());
    let m = scatterlab::output::compare(&two.image, &one.image).unwrap();
    assert!(m.rel_l2 < 1e-4 && (m.energy_ratio - 1.0).abs() < 1e-4, "k 2 against 1: {m:?}");
    assert!(one.image.data.iter().all(|v| v.is_finite()) && m.energy_ratio > 0.0);
    assert_clean(&gpu);
}

#[test]
fn lbl_with_a_light_inside_a_glass_agrees_with_path() {
    // A point light inside the glass: light rays start inside (no Fresnel on their side), the
    // lattice's boundary reflects, the camera's exit divides by ior^2. Measured at 32 x 32,
    // grid 32 against path at 2048 spp: relL2 0.192, energy 0.993 (index-matched 0.614, 0.986).
    let gpu = gpu();
    let text = object_scene_seeded(
        7,
        &format!("mesh = \"{}\"\nior = 1.5", mesh("icosphere.obj")),
        "sigma_t = 4.0\nalbedo = 0.95\ng = 0.3",
        "kind = \"point\"\nposition = [0.2, 0.1, 0.0]\nintensity = 1.0",
        16,
        1024,
    );
    let (_, [rel_on, e_on], [rel_off, _]) = with_and_without_refraction(&gpu, &text, "16", "light inside");
    assert!((e_on - 1.0).abs() < 0.1, "energy ratio {e_on}");
    assert!(rel_on < 0.3 && rel_on < rel_off, "refraction {rel_on} vs off {rel_off}");
    assert_clean(&gpu);
}

#[test]
fn lbl_with_a_point_light_outside_a_glass_agrees_with_path() {
    // The thesis' case: a translucent object lit by a point light outside it. lbl's light rays
    // refract into the glass with the Fresnel split; path reaches the light through every facet
    // that refracts it (manifold next-event estimation, tests/mnee_tests.rs). Across optical
    // thickness, albedo and g against path (all orders), 16 x 16, grid 16. Where refraction
    // helps, lbl must beat its index-matched self; the strongly anisotropic media show lbl's own
    // limit (docs/lbl.md, issue 11: a forward-peaked medium lit from the camera's side is too
    // bright in the lattice; glass traps the excess), bounded here so it cannot grow unseen.
    let gpu = gpu();
    let light = "kind = \"point\"\nposition = [1.5, 1.8, 1.6]\nintensity = 6.0";
    // (medium, name, energy ratio range, max relL2, refraction must beat off); measured
    // (energy, relL2; index-matched lbl's in brackets): thin 1.178, 0.290 (1.235, 0.416);
    // sigma_t 8 0.876, 0.207 (1.481, 0.493); thick 0.807, 0.231 (1.208, 0.275); albedo 0.3,
    // g 0.5 1.268, 0.644 (3.793, 2.628); g 0.9 2.771,
    // 1.875 (1.919, 1.331); g -0.9 1.559, 0.695 (1.355, 0.357).
    let cases = [
        ("sigma_t = 1.0\nalbedo = 0.9\ng = 0.0", "thin", (1.05, 1.3), 0.35, true),
        ("sigma_t = 8.0\nalbedo = 0.95\ng = 0.0", "sigma_t 8", (0.8, 1.0), 0.25, true),
        ("sigma_t = 20.0\nalbedo = 0.99\ng = 0.0", "thick", (0.72, 0.9), 0.28, true),
        ("sigma_t = 4.0\nalbedo = 0.3\ng = 0.5", "albedo 0.3", (1.1, 1.45), 0.75, true),
        ("sigma_t = 4.0\nalbedo = 0.95\ng = 0.9", "g 0.9", (2.4, 3.2), 2.2, false),
        ("sigma_t = 4.0\nalbedo = 0.95\ng = -0.9", "g -0.9", (1.35, 1.75), 0.85, false),
    ];
    for (medium, name, (e_lo, e_hi), max_rel, beats_off) in cases {
        let text =
            object_scene_seeded(7, &format!("mesh = \"{}\"\nior = 1.5", mesh("icosphere.obj")), medium, light, 16, 256);
        let (on, [rel_on, e_on], [rel_off, _]) = with_and_without_refraction(&gpu, &text, "16", name);
        assert!(on.image.data.iter().all(|v| v.is_finite() && *v >= 0.0), "{name}: a pixel is not finite");
        assert!((e_lo..e_hi).contains(&e_on), "{name}: energy ratio {e_on}");
        assert!(rel_on < max_rel, "{name}: relL2 {rel_on}");
        if beats_off {
            assert!(rel_on < rel_off, "{name}: refraction {rel_on} vs off {rel_off}");
        }
    }
    assert_clean(&gpu);
}
