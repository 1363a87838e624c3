//! sh-single's preprocessing (issue 17, thesis 3.2-3.3; src/solvers/sh_single/mod.rs): the
//! Poisson-disk sample set (deterministic, inside the mesh, no two samples closer than their
//! radii allow, about the requested count, denser near the surface) and each sample's
//! parameters (the attenuation's spherical-harmonics coefficients against the projection of the
//! analytic attenuation in a box, chromatic extinction, the Gaussian's width, sigma_s).

use std::path::Path;

use glam::Vec3;
use scatterlab::physics::quadrature::Quadrature;
use scatterlab::physics::sh;
use scatterlab::solvers::parts::gpu_scene::{GpuScene, MAJORANT_CELL};
use scatterlab::solvers::sh_single::{
    depth_below_surface, device_params, optical_depth, poisson_draw, poisson_samples, poisson_samples_with,
    sample_params, Heuristic, Placement, LAYER_SPACING,
};

use crate::common::{assert_clean, gpu, scene};
use crate::refraction_tests::{mesh, write_box_named};

fn sphere_object(sigma_t: &str) -> scatterlab::scene::Scene {
    scene(&format!(
        "[render]\nwidth = 8\nheight = 8\n[camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov = 30.0\n\
         [[object]]\nmesh = \"{}\"\n[object.medium]\nsigma_t = {sigma_t}\nalbedo = 0.9\n\
         [[light]]\nkind = \"directional\"\ndirection = [0.0, 0.0, -1.0]\nirradiance = 1.0\n",
        mesh("icosphere.obj")
    ))
}

fn box_object(dir: &Path, lo: Vec3, hi: Vec3, medium: &str) -> scatterlab::scene::Scene {
    let f = write_box_named(dir, "box.obj", lo, hi);
    scene(&format!(
        "[render]\nwidth = 8\nheight = 8\n[camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov = 30.0\n\
         [[object]]\nmesh = \"{}\"\n[object.medium]\n{medium}\n\
         [[light]]\nkind = \"directional\"\ndirection = [0.0, 0.0, -1.0]\nirradiance = 1.0\n",
        f.display()
    ))
}

/// Box A (x in [-1, -0.2], sigma_t [1, 2, 3]) and box B (x in [0.3, 1], sigma_t 10), both y and
/// z in [-1, 1]: two materials.
fn two_boxes(dir: &Path) -> scatterlab::scene::Scene {
    let a = write_box_named(dir, "a.obj", Vec3::new(-1.0, -1.0, -1.0), Vec3::new(-0.2, 1.0, 1.0));
    let b = write_box_named(dir, "b.obj", Vec3::new(0.3, -1.0, -1.0), Vec3::new(1.0, 1.0, 1.0));
    scene(&format!(
        "[render]\nwidth = 8\nheight = 8\n[camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov = 30.0\n\
         [[object]]\nmesh = \"{}\"\n[object.medium]\nsigma_t = [1.0, 2.0, 3.0]\nalbedo = 0.5\n\
         [[object]]\nmesh = \"{}\"\n[object.medium]\nsigma_t = 10.0\nalbedo = 0.5\n\
         [[light]]\nkind = \"directional\"\ndirection = [0.0, 0.0, -1.0]\nirradiance = 1.0\n",
        a.display(),
        b.display()
    ))
}

#[test]
fn poisson_samples_are_deterministic_inside_spaced_and_denser_near_the_surface() {
    let s = sphere_object("8.0");
    let o = s.object.as_ref().unwrap();
    for count in [500u32, 2000] {
        let a = poisson_samples(o, count, 7);
        assert_eq!(a, poisson_samples(o, count, 7), "deterministic for a seed");
        assert_ne!(a, poisson_samples(o, count, 8), "another seed, another set");
        let n = a.len() as f64;
        eprintln!("requested {count}: {n} samples");
        assert!((n / count as f64 - 1.0).abs() < 0.15, "requested {count}, drew {n}");
        for (i, x) in a.iter().enumerate() {
            assert!(o.contains(x.position), "sample {i} outside the mesh");
            for y in &a[i + 1..] {
                let d = x.position.distance(y.position);
                assert!(
                    d >= 0.5 * (x.radius + y.radius) * (1.0 - 1e-6),
                    "samples {d} apart, radii {} {}",
                    x.radius,
                    y.radius
                );
            }
        }
        // Within one mean free path (1/8) of the surface the radius is half or less of the
        // deep samples' (r0/2 .. r0 against 2 r0), and the samples' number density is higher.
        let mfp = 1.0 / 8.0;
        let depths: Vec<f32> = a.iter().map(|x| depth_below_surface(o, x.position)).collect();
        let mean = |f: &dyn Fn(f32) -> bool| {
            let v: Vec<f32> = a.iter().zip(&depths).filter(|(_, d)| f(**d)).map(|(x, _)| x.radius).collect();
            (v.iter().sum::<f32>() / v.len() as f32, v.len())
        };
        let (near, n_near) = mean(&|d| d < mfp);
        let (deep, n_deep) = mean(&|d| d > 3.5 * mfp);
        eprintln!("radius near the surface {near:.4} ({n_near}), deep {deep:.4} ({n_deep})");
        assert!(n_near > 0 && n_deep > 0 && near < 0.5 * deep, "near {near}, deep {deep}");
        // Number density: samples per volume in the outer shell (radius 0.8 sphere: depth <
        // mfp is the shell r > 0.8 - 1/8) against the core (r < 0.8 - 3.5/8).
        let shell = (0.8f64.powi(3) - 0.675f64.powi(3)) * 4.0 / 3.0 * std::f64::consts::PI;
        let core = 0.4625f64.powi(3) * 4.0 / 3.0 * std::f64::consts::PI;
        let (rho_near, rho_deep) = (n_near as f64 / shell, n_deep as f64 / core);
        eprintln!("samples per unit volume: near {rho_near:.0}, deep {rho_deep:.0}");
        assert!(rho_near > 3.0 * rho_deep, "near {rho_near}, deep {rho_deep}");
    }
}

/// `sh-single.placement=layers` (thesis 3.2.1-3.2.2): every sample lies on an offset surface,
/// at a depth below the mesh within a quarter spacing of k delta (k >= 1, delta =
/// LAYER_SPACING r0), inside, Poisson-spaced, about the count requested, the same on any
/// number of threads; the volume placement's depths fill the gaps between layers.
#[test]
fn layered_samples_lie_on_offset_surfaces() {
    let s = sphere_object("8.0");
    let o = s.object.as_ref().unwrap();
    let depth_in_layers = |samples: &[scatterlab::solvers::sh_single::Sample], delta: f32| {
        let on = samples
            .iter()
            .filter(|x| {
                let d = o.bvh.closest_point(x.position).unwrap().1;
                let k = (d / delta).round();
                k >= 1.0 && (d - k * delta).abs() <= 0.25 * delta * (1.0 + 1e-3)
            })
            .count();
        on as f64 / samples.len() as f64
    };
    for heuristic in [Heuristic::Depth, Heuristic::Divergence] {
        let (a, r0) = poisson_draw(o, 2000, 5, heuristic, Placement::Layers);
        let delta = LAYER_SPACING * r0;
        let n = a.len() as f64;
        eprintln!("{heuristic:?}: {n} samples, r0 {r0:.4}, layers {delta:.4} apart");
        assert!((n / 2000.0 - 1.0).abs() < 0.15, "{heuristic:?}: drew {n}");
        assert_eq!(depth_in_layers(&a, delta), 1.0, "{heuristic:?}: a sample off its layer");
        for (i, x) in a.iter().enumerate() {
            assert!(o.contains(x.position), "sample {i} outside");
            for y in &a[i + 1..] {
                assert!(x.position.distance(y.position) >= 0.5 * (x.radius + y.radius) * (1.0 - 1e-6));
            }
        }
        let pool = rayon::ThreadPoolBuilder::new().num_threads(3).build().unwrap();
        let b = pool.install(|| poisson_draw(o, 2000, 5, heuristic, Placement::Layers).0);
        assert_eq!(a, b, "{heuristic:?}: threads");
        // Uniform in the volume, only about half the depths fall within a quarter spacing of a
        // layer (the bands cover half of each spacing).
        let (v, r0v) = poisson_draw(o, 2000, 5, heuristic, Placement::Volume);
        let share = depth_in_layers(&v, LAYER_SPACING * r0v);
        eprintln!("{heuristic:?}: volume placement, {share:.3} of the depths within the layers' bands");
        assert!(share < 0.75, "{heuristic:?}: {share}");
    }
}

/// The darts are tested in parallel batches and accepted in order (src/solvers/sh_single/mod.rs,
/// `dart_throw`): the set must be the same on one thread as on many, under both heuristics.
#[test]
fn poisson_samples_do_not_depend_on_the_threads() {
    let s = sphere_object("8.0");
    let o = s.object.as_ref().unwrap();
    let on = |threads: usize, heuristic: Heuristic| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| poisson_samples_with(o, 3000, 11, heuristic))
    };
    for heuristic in [Heuristic::Depth, Heuristic::Divergence] {
        let one = on(1, heuristic);
        assert!(one.len() > 2000, "{heuristic:?}: {} samples", one.len());
        for threads in [2, 5] {
            assert_eq!(one, on(threads, heuristic), "{heuristic:?}: {threads} threads against one");
        }
    }
}

/// The thesis's density heuristic (3.2.3, `sh-single.density=divergence`): |div T| of the
/// attenuation's first moment T = int psi w dw. Deterministic, inside, spaced as the radii
/// allow, about the requested count; denser near a sphere's surface than deep inside (where T
/// vanishes by symmetry); and in a sphere too thick for light to reach its core (sigma_t 40,
/// radius 0.8: int psi dw / 4 pi < 1e-4 below about 0.2), no samples there, where the depth
/// heuristic puts its sparsest ones.
#[test]
fn divergence_heuristic_samples_where_the_attenuation_changes() {
    let s = sphere_object("8.0");
    let o = s.object.as_ref().unwrap();
    let a = poisson_samples_with(o, 1500, 7, Heuristic::Divergence);
    assert_eq!(a, poisson_samples_with(o, 1500, 7, Heuristic::Divergence), "deterministic for a seed");
    let n = a.len() as f64;
    assert!((n / 1500.0 - 1.0).abs() < 0.15, "requested 1500, drew {n}");
    for (i, x) in a.iter().enumerate() {
        assert!(o.contains(x.position), "sample {i} outside the mesh");
        for y in &a[i + 1..] {
            assert!(x.position.distance(y.position) >= 0.5 * (x.radius + y.radius) * (1.0 - 1e-6));
        }
    }
    let mfp = 1.0 / 8.0;
    let radius_at = |f: &dyn Fn(f32) -> bool| {
        let v: Vec<f32> = a.iter().filter(|x| f(depth_below_surface(o, x.position))).map(|x| x.radius).collect();
        v.iter().sum::<f32>() / v.len().max(1) as f32
    };
    let (near, deep) = (radius_at(&|d| d < mfp), radius_at(&|d| d > 3.5 * mfp));
    eprintln!("divergence heuristic, sphere sigma_t 8: radius near the surface {near:.4}, deep {deep:.4}");
    assert!(near > 0.0 && near < 0.6 * deep, "near {near}, deep {deep}");

    let thick = sphere_object("40.0");
    let o = thick.object.as_ref().unwrap();
    let deepest = |h: Heuristic| {
        poisson_samples_with(o, 800, 3, h).iter().map(|x| depth_below_surface(o, x.position)).fold(0.0, f32::max)
    };
    let (div, depth) = (deepest(Heuristic::Divergence), deepest(Heuristic::Depth));
    eprintln!("sigma_t 40: deepest sample {div:.3} (divergence), {depth:.3} (depth)");
    assert!(div < 0.6 && depth > 0.65, "the unlit core: divergence's deepest {div}, depth's {depth}");
}

#[test]
fn sample_parameters_project_the_boxs_exact_attenuation() {
    // In a box the distance to the surface along w is the slab method's: the coefficients of
    // the parameters equal the projection of exp(-sigma_t d(w)) with the same quadrature, per
    // channel (chromatic extinction), at any order.
    let dir = tempfile::tempdir().unwrap();
    let (lo, hi) = (Vec3::new(-1.0, -0.5, -0.3), Vec3::new(0.7, 0.9, 0.4));
    let s = box_object(dir.path(), lo, hi, "sigma_t = [1.0, 4.0, 12.0]\nalbedo = [0.9, 0.5, 0.2]");
    let o = s.object.as_ref().unwrap();
    let samples = poisson_samples(o, 40, 3);
    let q = Quadrature::product(16, 32);
    for order in [1usize, 5, 8] {
        let params = sample_params(o, &samples, order, &q, 1.0, 0.01);
        for (x, p) in samples.iter().zip(&params) {
            let b = x.position;
            let exit = |w: [f64; 3]| {
                (0..3)
                    .map(|k| {
                        let v = w[k];
                        let (l, h) = (lo[k] as f64, hi[k] as f64);
                        if v > 0.0 {
                            (h - b[k] as f64) / v
                        } else if v < 0.0 {
                            (l - b[k] as f64) / v
                        } else {
                            f64::INFINITY
                        }
                    })
                    .fold(f64::INFINITY, f64::min)
            };
            for (c, sigma) in [1.0f64, 4.0, 12.0].iter().enumerate() {
                let want = sh::project(order, &q, |w| (-sigma * exit(w)).exp());
                for (k, (g, w)) in p.sh[c].iter().zip(&want).enumerate() {
                    assert!((*g as f64 - w).abs() < 2e-5, "order {order}, channel {c}, coefficient {k}: {g} vs {w}");
                }
            }
            // sigma_s = sigma_t albedo (density 1); the Gaussian's half maximum at half the
            // width (width_scale 1: the full width at half maximum is the Poisson radius).
            let want = [0.9f32, 2.0, 2.4];
            for (got, want) in p.sigma_s.iter().zip(want) {
                assert!((got - want).abs() < 1e-5, "{:?}", p.sigma_s);
            }
            assert!(((-p.a * (0.5 * x.radius).powi(2)).exp() - 0.5).abs() < 1e-5);
        }
    }
}

#[test]
fn optical_depth_integrates_a_grid_and_crosses_objects() {
    // A density ramp along x (a 2 x 1 x 1 grid from 0 to 1 over the box: trilinear between the
    // voxel centres, clamped beyond) crossed along +x from the centre: the midpoint rule of a
    // piecewise-linear density is exact per piece.
    let dir = tempfile::tempdir().unwrap();
    let vol = dir.path().join("ramp.vol");
    std::fs::write(&vol, scatterlab::scene::write_vol([2, 1, 1], &[0.0, 1.0], Vec3::splat(-1.0), Vec3::splat(1.0)))
        .unwrap();
    let medium = format!("sigma_t = 2.0\nalbedo = 0.5\ndensity = {{ kind = \"grid\", file = \"{}\" }}", vol.display());
    let s = box_object(dir.path(), Vec3::splat(-1.0), Vec3::splat(1.0), &medium);
    let o = s.object.as_ref().unwrap();
    // From x = 0 to 1: density 0.5 + (x - 0) ... the ramp rises from 0 at x = -0.5 to 1 at 0.5,
    // then stays 1: integral over [0, 0.5] of (x + 0.5) plus 0.5 = 0.375 + 0.5.
    let tau = optical_depth(o, Vec3::ZERO, Vec3::X, 0.001);
    assert!((tau[0] - 2.0 * 0.875).abs() < 1e-4, "{tau:?}");
    // Along -x: over [-1, -0.5] density 0, over [-0.5, 0] x + 0.5: 0.125.
    let tau = optical_depth(o, Vec3::ZERO, -Vec3::X, 0.001);
    assert!((tau[0] - 2.0 * 0.125).abs() < 1e-4, "{tau:?}");

    // Two boxes of different extinction: from inside A along +x the path crosses the rest of A,
    // the gap, then all of B (each at its own material's sigma_t).
    let two = two_boxes(dir.path());
    let o = two.object.as_ref().unwrap();
    let tau = optical_depth(o, Vec3::new(-0.6, 0.0, 0.0), Vec3::X, 0.01);
    for (c, sigma_a) in [1.0f64, 2.0, 3.0].iter().enumerate() {
        let want = sigma_a * 0.4 + 10.0 * 0.7;
        assert!((tau[c] - want).abs() < 1e-4, "channel {c}: {} against {want}", tau[c]);
    }
}

#[test]
fn device_depths_match_the_host() {
    // glsl/sh_single/depth.comp marches the same walk as optical_depth: the coefficients agree
    // on a faceted sphere, a grid ramp in a box, and two boxes of different materials.
    let gpu = gpu();
    let dir = tempfile::tempdir().unwrap();
    let vol = dir.path().join("ramp.vol");
    std::fs::write(&vol, scatterlab::scene::write_vol([2, 1, 1], &[0.0, 1.0], Vec3::splat(-1.0), Vec3::splat(1.0)))
        .unwrap();
    let ramp = format!(
        "sigma_t = [2.0, 3.0, 5.0]\nalbedo = 0.5\ndensity = {{ kind = \"grid\", file = \"{}\" }}",
        vol.display()
    );

    let q = Quadrature::product(8, 16);
    for (what, s) in [
        ("sphere", sphere_object("[3.0, 6.0, 9.0]")),
        ("ramp", box_object(dir.path(), Vec3::splat(-1.0), Vec3::splat(1.0), &ramp)),
        ("two boxes", two_boxes(dir.path())),
    ] {
        let o = s.object.as_ref().unwrap();
        let samples = poisson_samples(o, 120, 5);
        let gs = GpuScene::upload_with(&gpu, &s, false, MAJORANT_CELL).unwrap();
        let host = sample_params(o, &samples, 5, &q, 1.0, 0.01);
        let (dev, _) = device_params(&gpu, &gs, o, &samples, 5, &q, 1.0, 0.01).unwrap();
        let mut worst = 0.0f32;
        for (h, d) in host.iter().zip(&dev) {
            for c in 0..3 {
                for (x, y) in h.sh[c].iter().zip(&d.sh[c]) {
                    worst = worst.max((x - y).abs());
                }
            }
            assert_eq!((h.a, h.sigma_s), (d.a, d.sigma_s));
        }
        eprintln!("{what}: {} samples, worst coefficient difference {worst:.2e}", samples.len());
        assert!(worst < 1e-4, "{what}: device and host coefficients differ by {worst}");
    }
    assert_clean(&gpu);
}

fn sphere_scene(medium: &str, ior: f64, light: &str, size: u32) -> scatterlab::scene::Scene {
    scene(&format!(
        "[render]\nwidth = {size}\nheight = {size}\n[camera]\norigin = [0.0, 0.0, 3.2]\ntarget = [0.0, 0.0, 0.0]\nfov = 34.0\n\
         [[object]]\nmesh = \"{}\"\nior = {ior:?}\n[object.medium]\n{medium}\n{light}\n",
        mesh("icosphere.obj")
    ))
}

/// A 2 x 2 x 2 density grid over [-0.8, 0.8]^3 rising along x and y (0.3 to 1.0), written to
/// `dir`: the `density = ...` line that uses it.
fn rise_grid(dir: &Path) -> String {
    let vol = dir.join("rise.vol");
    let rise: Vec<f32> = (0..8).map(|i| 0.3 + 0.35 * ((i & 1) + ((i >> 1) & 1)) as f32).collect();
    std::fs::write(&vol, scatterlab::scene::write_vol([2, 2, 2], &rise, Vec3::splat(-0.8), Vec3::splat(0.8))).unwrap();
    format!("density = {{ kind = \"grid\", file = \"{}\" }}", vol.display())
}

#[test]
fn sh_single_approaches_single_as_order_and_samples_grow() {
    // The render pass (glsl/sh_single/render.comp) against `single`, its ground truth, on an
    // index-matched sphere, homogeneous and heterogeneous (a density grid rising along x and y),
    // and a glass one (refraction, Fresnel, the camera chain's internal reflections):
    // relL2 falls at every step of the ladder (order 2 / 250 samples, 4 / 1000, 6 / 4000).
    // Albedo 0 under a sun alone renders black.
    use scatterlab::solvers::sh_single::{render, SampleIndex, ShSettings};
    let gpu = gpu();
    let dir = tempfile::tempdir().unwrap();
    let grid = rise_grid(dir.path());
    let sun = "[[light]]\nkind = \"directional\"\ndirection = [0.6, -0.3, -0.74]\nirradiance = [1.0, 0.8, 0.6]";
    for (what, medium, ior) in [
        ("homogeneous: sigma_t 4, albedo 0.6, g 0.4", "sigma_t = 4.0\nalbedo = 0.6\ng = 0.4".to_string(), 1.0),
        (
            "grid: sigma_t [3, 6, 9], albedo 0.8, g -0.3",
            format!("sigma_t = [3.0, 6.0, 9.0]\nalbedo = 0.8\ng = -0.3\n{grid}"),
            1.0,
        ),
        (
            "glass: ior 1.4, sigma_t [2, 4, 8], albedo 0.5, g -0.3",
            "sigma_t = [2.0, 4.0, 8.0]\nalbedo = 0.5\ng = -0.3".to_string(),
            1.4,
        ),
    ] {
        let s = sphere_scene(&medium, ior, sun, 32);
        let reference = crate::common::render(&gpu, &s, crate::common::SINGLE, &[]);
        let mut last = f64::INFINITY;
        for (order, samples) in [(2usize, 250u32), (4, 1000), (6, 4000)] {
            // The density heuristic `auto` takes: the divergence for the grid, the depth else.
            let heuristic = if s.features().homogeneous { Heuristic::Depth } else { Heuristic::Divergence };
            let set = ShSettings {
                order,
                samples,
                width_scale: 1.5,
                seed: 1,
                directions: 288,
                heuristic,
                index: SampleIndex::Boxes,
                placement: Placement::Volume,
            };
            let (img, st, _, _) = render(&gpu, &s, &set, false, &|_| {}).unwrap();
            assert!(img.data.iter().all(|v| v.is_finite() && *v >= 0.0), "{what}: finite, non-negative");
            let m = scatterlab::output::compare(&img, &reference.image).unwrap();
            eprintln!(
                "{what}: order {order}, {} samples: relL2 {:.4}, energy {:.4}; preprocess {:.2} s, render {:.2} s, {} bytes",
                st.samples, m.rel_l2, m.energy_ratio, st.preprocess_s, st.render_s, st.sample_bytes
            );
            assert!(m.rel_l2 < last, "{what}: order {order}, {samples} samples: relL2 {} not below {last}", m.rel_l2);
            last = m.rel_l2;
        }
    }
    let black = sphere_scene("sigma_t = 4.0\nalbedo = 0.0", 1.0, sun, 16);
    let (img, _, _, _) = render(
        &gpu,
        &black,
        &ShSettings {
            order: 3,
            samples: 200,
            width_scale: 1.5,
            seed: 1,
            directions: 288,
            heuristic: Heuristic::Depth,
            index: SampleIndex::Boxes,
            placement: Placement::Volume,
        },
        false,
        &|_| {},
    )
    .unwrap();
    assert!(img.data.iter().all(|v| *v == 0.0), "albedo 0 under a sun: black");
    assert_clean(&gpu);
}

/// A unit cube (v1 `[medium]`, which sh-single samples as an index-matched box) of optical
/// thickness `tau` seen face on by an orthographic camera narrower than the cube: every camera
/// ray crosses one unit of medium.
fn thin_cube(tau: f32, albedo: &str, g: f32, light: &str) -> scatterlab::scene::Scene {
    scene(&format!(
        "[render]\nwidth = 16\nheight = 16\n\
         [camera]\nkind = \"orthographic\"\norigin = [0.0, 0.0, 3.0]\ntarget = [0.0, 0.0, 0.0]\nextent = 0.6\n\
         [medium]\nbounds = [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]\nsigma_t = {tau}\nalbedo = {albedo}\ng = {g}\n\
         density = {{ kind = \"constant\" }}\n{light}"
    ))
}

#[test]
fn sh_single_meets_the_optically_thin_limit() {
    // As tau -> 0 attenuation vanishes (psi = 1 at every sample and direction) and single
    // scattering toward the camera is sigma_s E p(theta) times the chord (1 here): what is left
    // to test is the Gaussians' partition of the volume (eq. 3.3) and the closed-form line
    // integrals. Suns in the xy plane, the camera along -z: theta = 90 degrees, p = (1 - g^2) /
    // (4 pi (1 + g^2)^1.5). Exact to O(tau) = 1e-3.
    let gpu = gpu();
    for (g, albedo, rgb) in
        [(-0.6f32, "1.0", [1.0f32; 3]), (0.0, "[1.0, 0.5, 0.2]", [1.0, 0.5, 0.2]), (0.8, "0.7", [0.7; 3])]
    {
        let tau = 1e-3f32;
        let s = thin_cube(
            tau,
            albedo,
            g,
            "[[light]]\nkind = \"directional\"\ndirection = [-1.0, 0.0, 0.0]\nirradiance = 1000.0",
        );
        let out = crate::common::render(&gpu, &s, crate::common::SH_SINGLE, &[("sh-single.samples", "1500")]);
        let p = (1.0 - g * g) / (4.0 * std::f32::consts::PI * (1.0 + g * g).powf(1.5));
        let mut exact = out.image.clone();
        for (px, v) in exact.data.iter_mut().enumerate() {
            *v = rgb[px % 3] * tau * 1000.0 * p;
        }
        let m = scatterlab::output::compare(&out.image, &exact).unwrap();
        eprintln!("g {g}, albedo {albedo}: relL2 {:.4}, energy {:.4}", m.rel_l2, m.energy_ratio);
        // Measured 0.999 / 0.0010 (before the coverage normalisation along the ray 0.998 /
        // 0.028; before the partition's volume weights 0.94 / 0.06).
        assert!((m.energy_ratio - 1.0).abs() < 0.005, "g {g}: energy {}", m.energy_ratio);
        assert!(m.rel_l2 < 0.01, "g {g}: relL2 {}", m.rel_l2);
    }
    assert_clean(&gpu);
}

#[test]
fn the_gaussian_mean_of_the_inverse_square_is_exact() {
    // E[1 / |x - l|^2] over an isotropic Gaussian (what a sample beside a point light takes
    // for the light's irradiance) against a direct quadrature in spherical coordinates about
    // the light: int exp(-|x - c|^2 / (2 s^2)) / r^2 dV / (2 pi s^2)^1.5, the angular part in
    // closed form.
    use scatterlab::solvers::sh_single::{dawson, gaussian_mean_inverse_square};
    assert_eq!(dawson(0.0), 0.0);
    // Dawson's maximum, F(0.9241) = 0.5410 (Abramowitz & Stegun table 7.5).
    assert!((dawson(0.924_138_6) - 0.541_044_2).abs() < 1e-5);
    assert!((dawson(10.0) - 0.050_253_6).abs() < 1e-6, "{}", dawson(10.0));
    for s in [0.05f64, 1.0] {
        for d in [0.0f64, 0.3, 1.0, 2.5, 7.0] {
            let d = d * s;
            let n = 200_000;
            let r_max = d + 12.0 * s;
            let h = r_max / n as f64;
            let norm = (2.0 * std::f64::consts::PI * s * s).powf(1.5);
            // The Gaussian over the sphere of radius r about the light, times r^2 dr / r^2:
            // exp(-(r^2 + d^2) / 2s^2) 2 pi int_-1^1 exp(k mu) dmu, k = r d / s^2,
            // = 2 pi / k (exp(-(r - d)^2 / 2s^2) - exp(-(r + d)^2 / 2s^2)).
            let q: f64 = (0..n)
                .map(|i| {
                    let r = (i as f64 + 0.5) * h;
                    let shell = if d == 0.0 {
                        4.0 * std::f64::consts::PI * (-(r * r) / (2.0 * s * s)).exp()
                    } else {
                        let k = r * d / (s * s);
                        2.0 * std::f64::consts::PI / k
                            * ((-(r - d).powi(2) / (2.0 * s * s)).exp() - (-(r + d).powi(2) / (2.0 * s * s)).exp())
                    };
                    shell * h
                })
                .sum::<f64>()
                / norm;
            let f = gaussian_mean_inverse_square(d, s);
            assert!((f / q - 1.0).abs() < 1e-4, "s {s}, d {d}: {f} against {q}");
        }
    }
}

#[test]
fn sh_single_agrees_with_single_across_thickness_albedo_and_g() {
    // The registered solver (defaults but 1500 samples) against `single` on the icosphere
    // (radius 0.8) under a sun and a sky, from thin to optical thickness 32 across, albedo 0 to
    // 0.99, g -0.9 to 0.9, index-matched and glass. relL2 and energy over the object's pixels
    // (the sky seen past it is exact in both). Albedo 0: black but for the surface terms, which
    // are exact. Measured (12 x 12): see the eprintln lines; the bounds leave a margin.
    let gpu = gpu();
    let sky = 0.25f32;
    let lights = format!(
        "[[light]]\nkind = \"directional\"\ndirection = [-0.6, -0.5, -0.62]\nirradiance = 3.0\n\
         [[light]]\nkind = \"environment\"\nradiance = {sky}"
    );
    // (sigma_t, albedo, g, ior, relL2 bound, energy bounds)
    for (st, albedo, g, ior, rel, lo, hi) in [
        (0.5f32, 0.99f32, -0.9f32, 1.0f32, 0.02, 0.99, 1.01),
        (0.5, 0.5, 0.9, 1.5, 0.15, 0.92, 1.03),
        (4.0, 0.99, 0.0, 1.0, 0.10, 0.90, 1.02),
        (4.0, 0.5, -0.9, 1.5, 0.17, 0.93, 1.04),
        // The method's weak spot (docs/sh-single.md): thick and forward scattering under a
        // sky. The sky's in-scattering varies across a Gaussian with the psi-weighted mean
        // gradient over all directions, where g 0.9 weights the directions behind the point,
        // through the sphere (measured 0.66 / 0.46 here; at 24 x 24 and 2000 samples 0.59 /
        // 0.56, the sun alone 0.21 / 0.79, the sky alone 0.62 / 0.48, g 0 under the sky 0.29 /
        // 0.71).
        (20.0, 0.99, 0.9, 1.0, 0.75, 0.42, 1.02),
        (20.0, 0.99, 0.0, 1.0, 0.35, 0.65, 1.02),
        (20.0, 0.0, 0.0, 1.5, 0.0, 1.0, 1.0),
    ] {
        let medium = format!("sigma_t = {st}\nalbedo = {albedo}\ng = {g}");
        let s = sphere_scene(&medium, ior as f64, &lights, 12);
        let reference = crate::common::render(&gpu, &s, crate::common::SINGLE, &[("single.env_dirs", "32")]);
        let sets = [("sh-single.samples", "1500")];
        let out = crate::common::try_render(&gpu, &s, crate::common::SH_SINGLE, &sets, false)
            .unwrap_or_else(|e| panic!("sigma_t {st}: {e}"));
        // The optically thick scattering media are outside what sh-single was validated for, and
        // each render says so (its samples 0.83 mean free paths apart at the surface: set
        // sh-single.samples; g 0.9 under the sky as well: use single); the rest carry no warning.
        // The early warning (before the device opens) is the same lines.
        let w = &out.report.warnings;
        let sparse = st == 20.0 && albedo > 0.0;
        let forward = sparse && g >= 0.8;
        assert_eq!(w.len(), sparse as usize + forward as usize, "sigma_t {st}, albedo {albedo}, g {g}: {w:?}");
        assert!(!sparse || w[0].contains("mean free paths apart") && w[0].contains("set sh-single.samples="), "{w:?}");
        assert!(!forward || w[1].contains("environment light") && w[1].contains("use single"), "{w:?}");
        let settings = scatterlab::solvers::Settings::new(&[("sh-single.samples".to_string(), "1500".to_string())]);
        let solver = crate::common::SH_SINGLE;
        let knobs = settings.knobs(solver.name(), solver.knobs()).expect("knobs");
        assert_eq!(&solver.preflight(&s, &knobs).expect("preflight"), w, "sigma_t {st}, g {g}: early warnings");
        // The object's pixels: where single's image is not the sky itself.
        let (mut num, mut den, mut sa, mut sb) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for (a, b) in out.image.data.chunks_exact(3).zip(reference.image.data.chunks_exact(3)) {
            if b.iter().all(|v| (v - sky).abs() < 1e-7) {
                continue;
            }
            for (x, y) in a.iter().zip(b) {
                num += ((x - y) as f64).powi(2);
                den += (*y as f64).powi(2);
                sa += *x as f64;
                sb += *y as f64;
            }
        }
        let (rel_l2, energy) = ((num / den).sqrt(), sa / sb);
        eprintln!("sigma_t {st}, albedo {albedo}, g {g}, ior {ior}: relL2 {rel_l2:.4}, energy {energy:.4}");
        assert!(out.image.data.iter().all(|v| v.is_finite() && *v >= 0.0));
        if albedo == 0.0 {
            // Nothing scatters: the surfaces' terms alone, as single's.
            assert!(rel_l2 < 1e-3 && (energy - 1.0).abs() < 1e-3, "albedo 0: relL2 {rel_l2}, energy {energy}");
        } else {
            assert!(rel_l2 < rel, "sigma_t {st}, albedo {albedo}, g {g}: relL2 {rel_l2} above {rel}");
            assert!(energy > lo && energy < hi, "sigma_t {st}, albedo {albedo}, g {g}: energy {energy}");
        }
    }
    assert_clean(&gpu);
}

#[test]
fn sh_single_converges_on_the_cloud_grid() {
    // A sparse, high-contrast grid (scenes/cloud.toml, 64^3 in a v1 box): each Gaussian spreads
    // its sample's sigma_s over features smaller than itself, so the error is the samples'.
    // An attenuation taken along the camera ray across the Gaussians instead of the sample's
    // own psi made this 1.20-1.33x `single` (and a light inside the cloud 1.42-1.54x); now the
    // energy converges to single's as the samples grow (32 x 32, depth heuristic: 1.13 / 1.04 /
    // 1.02 at 4000 / 16000 / 64000 samples; relL2 0.42 / 0.19 / 0.13; 20 x 20 here, divergence:
    // 0.192 / 0.131 at 2000 / 12000, depth 0.445 / 0.223; 8000 here, CI time).
    let gpu = gpu();
    let s = crate::common::repo_scene("scenes/cloud.toml", &[("render.width", "20"), ("render.height", "20")]);
    let reference = crate::common::render(&gpu, &s, crate::common::SINGLE, &[]);
    let mut last = f64::INFINITY;
    for samples in ["2000", "8000"] {
        // `auto` samples a grid by the thesis's divergence heuristic; the depth heuristic,
        // blind to the density's gradients, must do worse at the same count (96 x 96: relL2
        // 0.43 / 0.23 against 0.19 / 0.14 at 2000 / 8000 samples).
        let out = crate::common::render(&gpu, &s, crate::common::SH_SINGLE, &[("sh-single.samples", samples)]);
        let by_depth = crate::common::render(
            &gpu,
            &s,
            crate::common::SH_SINGLE,
            &[("sh-single.samples", samples), ("sh-single.density", "depth")],
        );
        let m = scatterlab::output::compare(&out.image, &reference.image).unwrap();
        let md = scatterlab::output::compare(&by_depth.image, &reference.image).unwrap();
        eprintln!(
            "cloud, {samples} samples: relL2 {:.4}, energy {:.4} (depth heuristic {:.4}, {:.4})",
            m.rel_l2, m.energy_ratio, md.rel_l2, md.energy_ratio
        );
        assert!(m.rel_l2 < md.rel_l2, "{samples} samples: divergence {} against depth {}", m.rel_l2, md.rel_l2);
        assert!(m.rel_l2 < last, "{samples} samples: relL2 {} not below {last}", m.rel_l2);
        last = m.rel_l2;
        if samples == "8000" {
            assert!((m.energy_ratio - 1.0).abs() < 0.08, "energy {}", m.energy_ratio);
            assert!(m.rel_l2 < 0.3, "relL2 {}", m.rel_l2);
        }
    }
    assert_clean(&gpu);
}

#[test]
fn the_sample_indexes_render_what_visiting_every_sample_renders() {
    // sh_single.index (src/solvers/sh_single/mod.rs; glsl/sh_single/render.comp). `boxes` skips a
    // chunk of (Morton-ordered) samples where the camera segment misses the chunk's box; `grid`
    // walks a grid of the truncated Gaussians along the segment and counts each sample once, in
    // the cell holding its closest point on the segment. Each must give the image of the loop
    // over every sample (`none`): the same samples past the same cut, summed in another order.
    // Several chunks (each with its own box), an environment and point and directional lights,
    // a grid density, a refracting sphere (the camera chain's internal reflections: several
    // segments per pixel), and an orthographic camera along an axis (direction components
    // exactly zero, where the walk never steps on those axes).
    let gpu = gpu();
    let dir = tempfile::tempdir().unwrap();
    let grid = rise_grid(dir.path());
    let lights = "[[light]]\nkind = \"directional\"\ndirection = [0.6, -0.3, -0.74]\nirradiance = [1.0, 0.8, 0.6]\n\
                  [[light]]\nkind = \"point\"\nposition = [1.5, 1.0, 1.2]\nintensity = 2.0\n\
                  [[light]]\nkind = \"environment\"\nradiance = 0.2";
    let cases = [
        ("sphere, sun, point light and sky", sphere_scene("sigma_t = 4.0\nalbedo = 0.8\ng = 0.4", 1.0, lights, 24)),
        (
            "grid density",
            sphere_scene(&format!("sigma_t = [3.0, 6.0, 9.0]\nalbedo = 0.8\ng = -0.3\n{grid}"), 1.0, lights, 24),
        ),
        ("glass, ior 1.4", sphere_scene("sigma_t = [2.0, 4.0, 8.0]\nalbedo = 0.5\ng = 0.3", 1.4, lights, 24)),
        ("orthographic along z, a v1 box", thin_cube(2.0, "0.9", 0.2, lights)),
    ];
    let stats = |o: &scatterlab::solvers::RenderOutput| {
        o.report.detail::<scatterlab::solvers::sh_single::ShStats>().expect("stats").clone()
    };
    for (what, s) in &cases {
        let with = |index| {
            // 2200 samples: two chunks (of at most 2048), and the samples' projection, not the
            // pixels, is the render's time (3000 took 48 s in all, CI time).
            let sets = [("sh-single.samples", "2200"), ("sh-single.order", "3"), ("sh-single.index", index)];
            crate::common::render(&gpu, s, crate::common::SH_SINGLE, &sets)
        };
        let brute = with("none");
        let peak = brute.image.data.iter().fold(0.0f32, |a, v| a.max(*v));
        assert!(peak > 0.0, "{what}: a lit image");
        for index in ["boxes", "grid"] {
            let indexed = with(index);
            let si = stats(&indexed);
            assert!(si.dispatches >= 2, "{what}, {index}: several chunks ({} dispatches)", si.dispatches);
            let m = scatterlab::output::compare(&indexed.image, &brute.image).unwrap();
            let worst = indexed.image.data.iter().zip(&brute.image.data).fold(0.0f32, |a, (x, y)| a.max((x - y).abs()));
            eprintln!(
                "{what}, {index}: relL2 {:.2e}, worst pixel {:.2e} of peak {:.3e}; render {:.2} s, every sample {:.2} s",
                m.rel_l2,
                worst,
                peak,
                si.render_s,
                stats(&brute).render_s
            );
            assert!(
                m.rel_l2 < 1e-5 && worst <= 1e-5 * peak,
                "{what}, {index}: relL2 {}, worst {worst} of {peak}",
                m.rel_l2
            );
        }
    }
    assert_clean(&gpu);
}

#[test]
fn sh_single_never_creates_energy_on_a_thick_slab_with_few_samples() {
    // The shipped thick slab (optical thickness 50, albedo 0.99, 4 x 0.5 x 4, sun and sky) with
    // few samples: their Gaussians are wide, and a sample many mean free paths under the top face
    // reaches past it. The light's optical depth is linear across a Gaussian; unfloored it went far
    // below zero there and the attenuation to exp(+tau^2 / 18): at 64 x 64 the image was 585x
    // path's energy at 250 samples and 3.9e7x at 1000 (image mean 8.8e6). Floored at zero depth
    // (glsl/sh_single/render.comp, lit_gaussian), a sample's light is at most its unattenuated
    // value: measured at 24 x 24, 0.53 (250) and 0.66 (1000) of single's energy, the dark bias
    // the warning states (0.56-0.78 of single's energy at 0.87-2.2 mean free paths apart).
    let gpu = gpu();
    let sets = [("render.width", "24"), ("render.height", "24")];
    let s = crate::common::repo_scene("scenes/thick-slab.toml", &sets);
    let reference = crate::common::render(&gpu, &s, crate::common::SINGLE, &[]);
    let max_ref = reference.image.data.iter().fold(0.0f32, |m, v| m.max(*v));
    let sum = |d: &[f32]| d.iter().map(|v| *v as f64).sum::<f64>();
    for samples in ["250", "1000"] {
        let out =
            crate::common::try_render(&gpu, &s, crate::common::SH_SINGLE, &[("sh-single.samples", samples)], false)
                .unwrap_or_else(|e| panic!("{samples} samples: {e}"));
        let w = &out.report.warnings;
        assert!(w.iter().any(|l| l.contains("mean free paths apart")), "{samples} samples: {w:?}");
        assert!(out.image.data.iter().all(|v| v.is_finite() && *v >= 0.0), "{samples} samples: NaN, Inf or negative");
        let energy = sum(&out.image.data) / sum(&reference.image.data);
        let max = out.image.data.iter().fold(0.0f32, |m, v| m.max(*v));
        eprintln!("thick slab, {samples} samples: energy {energy:.4} of single's, brightest pixel {max:.4} (single {max_ref:.4})");
        assert!(energy > 0.4 && energy < 1.0, "{samples} samples: energy {energy} of single's");
        assert!(max < 1.5 * max_ref, "{samples} samples: brightest pixel {max} against single's {max_ref}");
    }
    assert_clean(&gpu);
}

/// Gaussians narrower than a Poisson radius (sh-single.width_scale < 1) stop overlapping and
/// the image breaks into spots: such a render says so, before the device opens and in its
/// report, and the claim holds (its relL2 against single is well past the default width's).
/// The default and wider widths say nothing.
#[test]
fn a_width_scale_below_one_poisson_radius_is_named_and_is_wrong() {
    let gpu = gpu();
    let s =
        crate::common::repo_scene("scenes/homogeneous-sphere.toml", &[("render.width", "32"), ("render.height", "32")]);
    let reference = crate::common::render(&gpu, &s, crate::common::SINGLE, &[]);
    let solver = crate::common::SH_SINGLE;
    let mut errors = Vec::new();
    for (width, warned) in [("1.5", false), ("1", false), ("0.3", true), ("1e-30", true)] {
        let sets = [("sh-single.samples", "1500"), ("sh-single.width_scale", width)];
        let out = crate::common::try_render(&gpu, &s, solver, &sets, false).expect("render");
        let w: Vec<&String> = out.report.warnings.iter().filter(|w| w.contains("width_scale")).collect();
        assert_eq!(w.len(), warned as usize, "width {width}: {:?}", out.report.warnings);
        assert!(!warned || w[0].contains("set sh-single.width_scale=1.5"), "{w:?}");
        let owned: Vec<(String, String)> = sets.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect();
        let knobs = scatterlab::solvers::Settings::new(&owned).knobs(solver.name(), solver.knobs()).expect("knobs");
        let early = solver.preflight(&s, &knobs).expect("preflight");
        assert_eq!(early.iter().filter(|e| e.contains("width_scale")).count(), warned as usize, "{early:?}");
        assert!(out.image.data.iter().all(|v| v.is_finite() && *v >= 0.0), "width {width}: finite");
        let m = scatterlab::output::compare(&out.image, &reference.image).unwrap();
        eprintln!("width_scale {width}: relL2 {:.3}, energy {:.3}", m.rel_l2, m.energy_ratio);
        errors.push(m.rel_l2);
    }
    assert!(errors[2] > 2.0 * errors[0] && errors[3] > 2.0 * errors[0], "the narrow widths are wrong: {errors:?}");
    assert_clean(&gpu);
}

/// The sampler draws the requested count within 10% however thin the medium: where the
/// samples' disks are wider than the slab is thick the count goes as r0^-2, not r0^-3, and
/// rescaling r0 by the cube root of the count's ratio left a slab 1e-7 thick with 65261
/// samples for 4000 (16x: 31 MB of sample set, 4.9 s of preprocessing); the rescaling now
/// measures the exponent from its last two draws.
#[test]
fn poisson_draws_the_requested_count_on_thin_slabs() {
    let dir = tempfile::tempdir().unwrap();
    for thickness in [1e-7f32, 1e-5, 1e-3, 0.1, 1.0] {
        let s = box_object(
            dir.path(),
            Vec3::new(-0.5, -0.5, -0.5),
            Vec3::new(0.5, 0.5, -0.5 + thickness),
            "sigma_t = 10.0\nalbedo = 0.9",
        );
        let o = s.object.as_ref().unwrap();
        for heuristic in [Heuristic::Depth, Heuristic::Divergence] {
            let (samples, _) = poisson_draw(o, 4000, 1, heuristic, Placement::Volume);
            let ratio = samples.len() as f64 / 4000.0;
            eprintln!("thickness {thickness:e}, {heuristic:?}: {} samples", samples.len());
            assert!(
                (ratio - 1.0).abs() < 0.1,
                "thickness {thickness:e}, {heuristic:?}: {} samples for 4000",
                samples.len()
            );
        }
    }
}
