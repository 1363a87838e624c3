//! Illumination networks' particle model and visibility network (issue 15, paper 2.1 and
//! 3.1-3.2): particles follow the density and are deterministic; the directions are a unit,
//! orthonormal, balanced set; the visibility network built on the device equals the host's
//! construction exactly, and every window column is one chain from the sky down.

use glam::Vec3;
use scatterlab::solvers::networks::{Directions, Network, Opacity, Particles, Window, WindowRule, MAX_COLUMN, NONE};

const _: () = assert!(400 > MAX_COLUMN, "the crowded test needs a column over the limit");

use crate::common::{assert_clean, gpu, judge, repo_scene};

fn network(scene: &str, sets: &[(&str, &str)], n: u32, d: u32, m: Option<u32>) -> Network {
    network_by(scene, sets, n, d, m, WindowRule::Fit)
}

fn network_by(scene: &str, sets: &[(&str, &str)], n: u32, d: u32, m: Option<u32>, rule: WindowRule) -> Network {
    network_of(&repo_scene(scene, sets), n, d, m, rule)
}

fn network_of(s: &scatterlab::scene::Scene, n: u32, d: u32, m: Option<u32>, rule: WindowRule) -> Network {
    let particles = Particles::sample(s, n, s.render.seed).expect("particles");
    let directions = Directions::new(d, s.render.seed);
    let window = Window::new(s, &particles, &directions, m, rule);
    Network { particles, directions, window, opacity: Opacity::Linear }
}

/// Particles land only where the density is (inside the sphere of the sphere scene, in
/// proportion to the grid on the cloud), the same for the same seed and not for another, and
/// their masses add up to the density's integral (the sphere's volume within 1%).
#[test]
fn particles_follow_the_density_and_the_seed() {
    let s = repo_scene("scenes/homogeneous-sphere.toml", &[]);
    let a = Particles::sample(&s, 2000, 7).unwrap();
    let b = Particles::sample(&s, 2000, 7).unwrap();
    let c = Particles::sample(&s, 2000, 8).unwrap();
    assert_eq!(a.positions, b.positions, "deterministic for a seed");
    assert_ne!(a.positions, c.positions, "another seed, other particles");
    assert!(a.positions.iter().all(|p| p.length() <= 0.45), "inside the sphere of radius 0.45");
    let sphere = 4.0 / 3.0 * std::f64::consts::PI * 0.45f64.powi(3);
    let total = a.mass * 2000.0;
    assert!((total / sphere - 1.0).abs() < 0.01, "masses add to {total}, the sphere's volume is {sphere}");
    // The cloud: the share of particles in each half of the box along x follows the density's
    // integral over that half (binomial noise at 4000 particles: sigma about 0.008).
    let cloud = repo_scene("scenes/cloud.toml", &[]);
    let p = Particles::sample(&cloud, 4000, 3).unwrap();
    let m = &cloud.medium;
    let mid = 0.5 * (m.bounds_min.x + m.bounds_max.x);
    let share = p.positions.iter().filter(|x| x.x < mid).count() as f64 / 4000.0;
    let (mut left, mut all) = (0f64, 0f64);
    let k = 64;
    for z in 0..k {
        for y in 0..k {
            for x in 0..k {
                let u = (Vec3::new(x as f32, y as f32, z as f32) + 0.5) / k as f32;
                let d = cloud.density_at(m.bounds_min + u * (m.bounds_max - m.bounds_min)) as f64;
                all += d;
                if x < k / 2 {
                    left += d;
                }
            }
        }
    }
    assert!((share - left / all).abs() < 0.03, "left half: {share} of the particles, {} of the density", left / all);
}

/// The directions: unit and orthonormal frames, balanced (their mean within 1e-3 of zero: the
/// equal-area lattice), the same for a seed.
#[test]
fn directions_are_an_orthonormal_balanced_set() {
    let d = Directions::new(128, 5);
    assert_eq!(d.len(), 128);
    for f in &d.frames {
        for a in f {
            assert!((a.length() - 1.0).abs() < 1e-5);
        }
        assert!(f[0].dot(f[1]).abs() < 1e-5 && f[0].dot(f[2]).abs() < 1e-5 && f[1].dot(f[2]).abs() < 1e-5);
    }
    let mean = d.frames.iter().map(|f| f[2]).sum::<Vec3>() / 128.0;
    assert!(mean.length() < 1e-3, "mean direction {mean}");
    assert_eq!(Directions::new(128, 5).frames, d.frames);
}

/// The device's visibility network (count, prefix sum, fill, link) equals the host's
/// construction entry for entry: on the cloud (heterogeneous, M by the paper's rule) and on
/// a uniform cube with a coarse window (crowded columns: long sorts). On the host network,
/// each direction's sky entries are its occupied pixels, and following the links from any
/// particle climbs its column in depth order to the sky, visiting each particle once.
#[test]
fn visibility_network_on_the_device_equals_the_host_construction() {
    let gpu = gpu();
    let cases = [
        network("scenes/cloud.toml", &[], 600, 32, None),
        network("scenes/anisotropic-cube.toml", &[], 500, 20, Some(4)),
    ];
    for (c, net) in cases.iter().enumerate() {
        let host = net.visibility_cpu();
        let device = net.visibility(&gpu).expect("device network");
        let n = net.particles.positions.len();
        let d = net.directions.len();
        eprintln!("case {c}: N {n}, D {d}, M {}", net.window.m);
        assert_eq!(device.len(), host.len());
        let differing = device.iter().zip(&host).filter(|(a, b)| a != b).count();
        assert_eq!(differing, 0, "case {c}: {differing} of {} entries differ", host.len());
        for (i, frame) in net.directions.frames.iter().enumerate() {
            let keys: Vec<(u32, f32)> = net.particles.positions.iter().map(|x| net.window.key(*x, frame)).collect();
            let mut pixels: Vec<u32> = keys.iter().map(|k| k.0).collect();
            pixels.sort_unstable();
            pixels.dedup();
            let sky = (0..n).filter(|p| host[p * d + i] == NONE).count();
            assert_eq!(sky, pixels.len(), "case {c}, direction {i}: one sky entry per occupied pixel");
            for p in 0..n {
                let (mut q, mut steps) = (p, 0);
                while host[q * d + i] != NONE {
                    let up = host[q * d + i] as usize;
                    assert_eq!(keys[up].0, keys[q].0, "linked within one column");
                    assert!(keys[up].1 <= keys[q].1, "upstream is not deeper");
                    q = up;
                    steps += 1;
                    assert!(steps < n, "case {c}: a cycle");
                }
            }
        }
    }
    assert_clean(&gpu);
}

/// A window column too crowded for one invocation's sort (llvmpipe's loop limiter would end
/// it silently) is one clear error naming the window, not a wrong network: 400 particles on a
/// 1 x 1 window; the same particles on the rule's window build.
#[test]
fn a_column_too_crowded_to_sort_is_refused() {
    let gpu = gpu();
    let net = network("scenes/homogeneous-sphere.toml", &[], 400, 4, Some(1));
    let err = net.visibility(&gpu).expect_err("a 400-particle column").to_string();
    assert!(err.contains("window column holds 400 particles") && err.contains("finer networks.window"), "{err}");
    let ok = network("scenes/homogeneous-sphere.toml", &[], 400, 4, None);
    assert!(ok.window.m > 1, "the rule's window: M {}", ok.window.m);
    assert_eq!(ok.visibility(&gpu).expect("the rule's window"), ok.visibility_cpu());
    assert_clean(&gpu);
}

/// The direct term and the iteration on the device (glsl/networks/direct.comp, iterate.comp)
/// against the host's double-precision oracles on the same network: the cloud under its sun
/// and sky (a directional light, an environment as the network's sky), and the cloud with a
/// point light inside it (its 1 / r^2 capped at the particle's ball) scattering backward
/// (g -0.4); the cloud made isotropic (g 0), whose in-scattering sum is taken once per
/// particle (glsl/networks/inscatter.comp), and the cloud with a lamp beside its sun, whose two
/// light units' scattered light is summed once into a table (glsl/networks/lit.comp),
/// isotropic and not. After 12 iterations I within 2e-5 of the host's (relative to the
/// largest); every entry finite and non-negative; the 12th step changes I by less than the
/// first. Where a shortcut was taken, I equals, bit for bit, the general kernel's
/// (`--model-all`, which sums every link's in-scattering and light units): the shortcuts are
/// the same f32 arithmetic, not approximations.
#[test]
fn direct_light_and_iteration_on_the_device_match_the_host() {
    use scatterlab::solvers::networks::{tabulates_lit, unit_count};
    let gpu = gpu();
    let lamp = "[[light]]\nkind = \"point\"\nposition = [0.3, 0.2, -0.1]\nintensity = 0.5\n";
    let cube_light = [("light.0.position", "[0.1, -0.05, 0.2]"), ("medium.g", "-0.4")];
    let cloud = "scenes/cloud.toml";
    let isotropic = |mut s: scatterlab::scene::Scene| {
        s.medium.g = 0.0;
        s
    };
    let cases = [
        ("cloud", repo_scene(cloud, &[]), 400u32, 24u32),
        ("point light inside, g -0.4", repo_scene("scenes/point-light-in-cloud.toml", &cube_light), 300, 16),
        ("cloud, g 0", isotropic(repo_scene(cloud, &[])), 400, 24),
        ("cloud and a lamp", crate::common::repo_scene_plus(cloud, lamp), 400, 24),
        ("cloud and a lamp, g 0", isotropic(crate::common::repo_scene_plus(cloud, lamp)), 400, 24),
    ];
    for (scene, s, n, d) in cases {
        let net = network_of(&s, n, d, None, WindowRule::Fit);
        let v = net.visibility_cpu();
        let step = 0.01f32;
        let host_direct = net.direct_cpu(&s, step as f64);
        let host = net.iterate_cpu(&s, &v, &host_direct, 12);
        let device = net.iterate(&gpu, &s, 12, step, false).expect("device iteration");
        let (worst, scale) = device_against_host(&device, &host);
        assert!(scale > 0.0, "{scene}: some light");
        eprintln!("{scene}: N {n}, D {d}, M {}: largest difference {worst:.2e} of the largest I", net.window.m);
        assert!(worst < 2e-5, "{scene}: device against host {worst:e}");
        let tabulated = tabulates_lit(unit_count(&s, 0), false);
        assert_eq!(tabulated, scene.contains("lamp"), "{scene}: two light units are tabulated, one is not");
        if s.medium.g == 0.0 || tabulated {
            let full = net.iterate(&gpu, &s, 12, step, true).expect("device iteration, every feature modelled");
            let differ = device.iter().zip(&full).filter(|(a, b)| a[..3] != b[..3]).count();
            assert_eq!(differ, 0, "{scene}: the shortcuts' I differs from the general kernel's in {differ} entries");
        }
        assert!(device.iter().all(|x| x[..3].iter().all(|c| c.is_finite() && *c >= 0.0)), "{scene}");
        let one = net.iterate_cpu(&s, &v, &host_direct, 1);
        let eleven = net.iterate_cpu(&s, &v, &host_direct, 11);
        let change = |a: &[[f64; 3]], b: &[[f64; 3]]| {
            a.iter().zip(b).flat_map(|(x, y)| (0..3).map(move |c| (x[c] - y[c]).abs())).fold(0.0f64, f64::max)
        };
        let first = one.iter().flat_map(|x| x.iter().copied()).fold(0.0f64, f64::max);
        let last = change(&host, &eleven);
        assert!(last < first, "{scene}: the 12th step changes I by {last:e}, the first by {first:e}");
    }
    assert_clean(&gpu);
}

/// The phase function's quadrature on the directions is balanced (`phase_matrix`): as the paper
/// gives it (4 pi / D p) a forward-peaked lobe's rows sum far from 1 (g 0.9, D 32), balanced
/// every row and column sums to 1 and the matrix stays symmetric. So the network's furnace
/// (albedo 1, nothing but a uniform sky of radiance 1, g 0.9) climbs from 0 toward 1 without
/// ever passing it (no energy created) and is within 1% of it after 200 iterations; its image
/// (the splats alpha-blended over the sky) is 1 everywhere to 1e-4.
#[test]
fn the_network_furnace_stays_at_the_sky() {
    use scatterlab::solvers::networks::phase_matrix;
    let gpu = gpu();
    let s = crate::common::scene(
        "[render]\nwidth = 8\nheight = 8\nseed = 3\n\
         [camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nfov = 20.0\n\
         [medium]\nbounds = [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]\nsigma_t = 6.0\nalbedo = 1.0\ng = 0.9\n\
         density = { kind = \"constant\" }\n\
         [[light]]\nkind = \"environment\"\nradiance = 1.0\n",
    );
    let particles = Particles::sample(&s, 300, 3).unwrap();
    let directions = Directions::new(32, 3);
    let window = Window::new(&s, &particles, &directions, None, WindowRule::Fit);
    let net = Network { particles, directions, window, opacity: Opacity::Linear };
    let (p, before) = phase_matrix(&net.directions, 0.9);
    eprintln!("rows of the unbalanced quadrature off 1 by up to {before:.3}");
    assert!(before > 0.1, "the quadrature as given misses 1 by {before}");
    for i in 0..32 {
        let row: f64 = (0..32).map(|k| p[i * 32 + k] as f64).sum();
        assert!((row - 1.0).abs() < 1e-5, "row {i} sums to {row}");
        for k in 0..32 {
            assert!((p[i * 32 + k] - p[k * 32 + i]).abs() <= 1e-6 * p[i * 32 + k].abs().max(1e-30), "symmetric");
        }
    }
    for (k, floor) in [(20u32, 0.0f64), (200, 0.99)] {
        let i = net.iterate(&gpu, &s, k, 0.01, false).expect("iteration");
        let (lo, hi) = i
            .iter()
            .flat_map(|x| x[..3].iter().map(|c| *c as f64))
            .fold((f64::MAX, 0.0f64), |(l, h), c| (l.min(c), h.max(c)));
        let mean = i.iter().map(|x| x[0] as f64).sum::<f64>() / i.len() as f64;
        eprintln!("furnace after {k} iterations: min {lo:.5}, mean {mean:.5}, max {hi:.7}");
        assert!(hi <= 1.0 + 1e-5, "{k} iterations: radiance {hi} above the sky's");
        assert!(mean >= floor, "{k} iterations: mean {mean}");
    }
    // The image of the converged furnace: every splat carries radiance 1 and the sky behind is
    // 1, so alpha blending gives 1 wherever the splats lie (as `path` gives in a furnace).
    let mut st = scatterlab::solvers::networks::Illumination::new(&gpu, &net, &s, 0.01, true, 0).unwrap();
    st.step(&gpu, 200).unwrap();
    let img = st.image(&gpu, &net, 1.0, 0.0).expect("image");
    let (lo, hi) = img.image.data.iter().fold((f32::MAX, 0f32), |(l, h), x| (l.min(*x), h.max(*x)));
    eprintln!("furnace image: {lo} .. {hi}, {} splats dropped", img.dropped);
    assert!(lo > 1.0 - 1e-4 && hi < 1.0 + 1e-4, "furnace image {lo} .. {hi}");
    assert_clean(&gpu);
}

/// A thin medium (optical radius 0.02): the paper's rule alone would give a 1 x 1 window, one
/// column holding every particle, past what one sort takes; the window is kept at 64
/// particles a pixel on average, and the network builds and equals the host's. The default
/// rule (`fit`) picks a finer window there, whose occupied columns hold 8 particles on average
/// (and twice as fine, fewer).
#[test]
fn a_thin_medium_keeps_its_columns_sortable() {
    let gpu = gpu();
    let thin = [("medium.sigma_t", "0.05")];
    let net = network_by("scenes/homogeneous-sphere.toml", &thin, 1024, 16, None, WindowRule::Paper);
    assert_eq!(net.window.m, 4, "sqrt(1024 / 64)");
    assert_eq!(net.visibility(&gpu).expect("a thin network"), net.visibility_cpu());
    let fit = network("scenes/homogeneous-sphere.toml", &thin, 1024, 16, None);
    let column = |m: u32| Window { m, ..fit.window }.mean_column(&fit.particles, &fit.directions);
    let m = fit.window.m;
    eprintln!("fit: M {m}, {:.1} particles to an occupied column ({:.1} at 2M)", column(m), column(2 * m));
    assert!(m > 4 && column(m) >= 8.0 && column(2 * m) < 8.0, "M {m}: {} / {}", column(m), column(2 * m));
    assert_eq!(fit.visibility(&gpu).expect("a thin network"), fit.visibility_cpu());
    assert_clean(&gpu);
}

/// The paper's warm start (4: each frame starts from the previous light position's solution):
/// on the cloud (800 particles, 32 directions) the sun turned by about 6 degrees, one iteration
/// from the old converged solution is closer to the new converged solution than ten iterations
/// from zero: relL2 0.104 against 0.324 (the default window rule, M 23), asserted at least
/// 2.5x. Both solves report convergence to 1e-6 (in 88 and 80 iterations).
#[test]
fn a_warm_start_after_a_small_light_move_beats_ten_cold_iterations() {
    use scatterlab::solvers::networks::Illumination;
    let gpu = gpu();
    let sun = |d: &str| repo_scene("scenes/cloud.toml", &[("light.0.direction", d)]);
    let (before, after) = (sun("[0.5, -0.7, 0.5]"), sun("[0.6, -0.7, 0.4]"));
    let particles = Particles::sample(&before, 800, 1).unwrap();
    let directions = Directions::new(32, 1);
    let window = Window::new(&before, &particles, &directions, None, WindowRule::Fit);
    let net = Network { particles, directions, window, opacity: Opacity::Linear };
    let step = 0.01;
    let mut warm = Illumination::new(&gpu, &net, &before, step, true, 0).expect("state");
    let c = warm.solve(&gpu, 1e-6, 2000, &|_| {}).expect("solve");
    assert!(c.converged, "{c:?}");
    warm.set_lights(&gpu, &net, &after).expect("moved sun");
    warm.step(&gpu, 1).expect("one warm iteration");
    let mut cold = Illumination::new(&gpu, &net, &after, step, true, 0).expect("state");
    cold.step(&gpu, 10).expect("ten cold iterations");
    let mut reference = Illumination::new(&gpu, &net, &after, step, true, 0).expect("state");
    let r = reference.solve(&gpu, 1e-6, 2000, &|_| {}).expect("solve");
    assert!(r.converged, "{r:?}");
    let truth = reference.radiance(&gpu).unwrap();
    let err = |s: &Illumination| {
        let i = s.radiance(&gpu).unwrap();
        let (mut num, mut den) = (0f64, 0f64);
        for (a, b) in i.iter().zip(&truth) {
            for c in 0..3 {
                num += (a[c] as f64 - b[c] as f64).powi(2);
                den += (b[c] as f64).powi(2);
            }
        }
        (num / den).sqrt()
    };
    let (e_warm, e_cold) = (err(&warm), err(&cold));
    eprintln!(
        "converged in {} and {} iterations; relL2 to the new solution: warm 1 iteration {e_warm:.4}, cold 10 \
         iterations {e_cold:.4} (ratio {:.2})",
        c.iterations,
        r.iterations,
        e_cold / e_warm
    );
    // Measured: 0.112 against 0.594 (5.3x); the margin leaves room for the particles' draw.
    assert!(e_cold > 2.5 * e_warm, "warm {e_warm} against cold {e_cold}");
    assert_clean(&gpu);
}

/// networks against path on the cube of `scenes/anisotropic-cube.toml` across the range a user
/// meets: optical thickness 1 to 20 across, albedo 0.5 to 0.99, g -0.9 to 0.9 (24 x 24, path
/// at 2048 spp). At 512 particles and 64 directions (measured energy / relL2): thin (sigma_t 1)
/// albedo 0.5 0.998 / 0.028, albedo 0.99 g -0.9 0.858 / 0.198, g 0.9 0.967 / 0.110; sigma_t 5,
/// albedo 0.9, g 0.6 0.987 / 0.114; thick (sigma_t 20: a mean free path of 0.05, the particles
/// 0.12 apart) albedo 0.5 g 0.9 0.730 / 0.361, albedo 0.99 g 0 0.930 / 0.368, g -0.5
/// 0.816 / 0.551. Each is held near its measurement; in every case the error falls from 128
/// particles and 32 directions to 512 and 64 (at 2048 and 64 it falls again: 0.026 ... 0.26,
/// docs/networks.md), and no case is brighter than path. At albedo 0 the image is `single`'s:
/// the view pass alone (nothing scatters twice).
#[test]
fn networks_approaches_path_across_thickness_albedo_and_g() {
    use crate::common::{render, NETWORKS, SINGLE};
    let gpu = gpu();
    let size = [("render.width", "24"), ("render.height", "24")];
    // sigma_t, albedo, g, energy range, relL2 bound at 512 x 64.
    for (sigma_t, albedo, g, energy, error) in [
        ("1", "0.5", "0", (0.97, 1.03), 0.05),
        ("1", "0.99", "-0.9", (0.8, 0.95), 0.25),
        ("1", "0.99", "0.9", (0.92, 1.02), 0.15),
        ("5", "0.9", "0.6", (0.95, 1.03), 0.15),
        ("20", "0.5", "0.9", (0.65, 0.8), 0.45),
        ("20", "0.99", "0", (0.85, 1.03), 0.45),
        ("20", "0.99", "-0.5", (0.75, 0.9), 0.65),
    ] {
        let case = format!("sigma_t {sigma_t}, albedo {albedo}, g {g}");
        let s = repo_scene(
            "scenes/anisotropic-cube.toml",
            &[&size[..], &[("medium.sigma_t", sigma_t), ("medium.albedo", albedo), ("medium.g", g)]].concat(),
        );
        let reference = crate::common::path_reference(&gpu, &s, &[("render.spp", "2048")]);
        // The thick cube (a mean free path of 0.05 against particles 0.12-0.2 apart) is outside
        // what networks was validated for, and each render says so, naming the particles it
        // would take; so is sigma_t 5 at 128 particles (0.99 mean free paths a spacing: 0.926 of
        // path's energy, the cube the rule was measured on); the others carry no warning.
        let networks = |n: &'static str, d: &'static str| {
            let out = crate::common::try_render(
                &gpu,
                &s,
                NETWORKS,
                &[("networks.particles", n), ("networks.directions", d)],
                false,
            )
            .unwrap_or_else(|e| panic!("{case}: {e}"));
            let w = &out.report.warnings;
            let outside = sigma_t == "20" || (sigma_t == "5" && n == "128");
            assert_eq!(w.len(), outside as usize, "{case}, {n} particles: {w:?}");
            // The count that fixes it, or (the thick cube at 128 particles: 3.97 mean free paths
            // a spacing would need 37000) that none up to the knob's largest does.
            assert!(
                w.iter().all(|w| w.contains("mean free paths where the particles are")
                    && (w.contains("set networks.particles=") || w.contains("no networks.particles up to 16384"))),
                "{case}: {w:?}"
            );
            out
        };
        let coarse = networks("128", "32");
        let fine = networks("512", "64");
        let (rc, ec) = judge(&coarse.image, &reference);
        let (rf, ef) = judge(&fine.image, &reference);
        eprintln!("{case}: 128 x 32 energy {ec:.3} relL2 {rc:.3}; 512 x 64 energy {ef:.3} relL2 {rf:.3}");
        assert!(fine.report.stats.convergence.unwrap().converged, "{case}");
        assert!(ef > energy.0 && ef < energy.1, "{case}: energy ratio {ef}");
        assert!(rf < error, "{case}: relL2 {rf}");
        assert!(rf < rc, "{case}: the error does not fall with the particles ({rc} -> {rf})");
    }
    let s = repo_scene("scenes/anisotropic-cube.toml", &[&size[..], &[("medium.albedo", "0")]].concat());
    let absorber = render(&gpu, &s, NETWORKS, &[("networks.particles", "128"), ("networks.directions", "32")]);
    let single = render(&gpu, &s, SINGLE, &[]);
    let m = scatterlab::output::compare(&absorber.image, &single.image).unwrap();
    assert!(m.rel_l2 < 1e-6, "albedo 0: relL2 {} against single", m.rel_l2);
    assert_clean(&gpu);
}

/// The cloud (a 64^3 grid, g 0.6, a sun and a blue sky) and the homogeneous sphere against
/// path at 24 x 24, networks at 512 particles and 64 directions beside lbl at its defaults:
/// measured energy / relL2 cloud 1.013 / 0.085 (lbl 0.958 / 0.098), sphere 0.914 / 0.167
/// (lbl 0.987 / 0.072: on the sphere's steep lit side 512 particles are too few, 0.91 mean free
/// paths apart, and its trust line says so).
#[test]
fn networks_on_the_cloud_and_the_sphere_beside_lbl() {
    use crate::common::{render, render_warned, LBL, NETWORKS};
    let gpu = gpu();
    for (scene, spp, energy, error, warned) in [
        ("scenes/cloud.toml", "1024", (0.95, 1.05), 0.15, false),
        ("scenes/homogeneous-sphere.toml", "2048", (0.88, 1.0), 0.2, true),
    ] {
        let s = repo_scene(scene, &[("render.width", "24"), ("render.height", "24")]);
        let reference = crate::common::path_reference(&gpu, &s, &[("render.spp", spp)]);
        let sets = [("networks.particles", "512"), ("networks.directions", "64")];
        let out = if warned {
            render_warned(&gpu, &s, NETWORKS, &sets, &["mean free paths where the particles are (512 particles)"])
        } else {
            render(&gpu, &s, NETWORKS, &sets)
        };
        let (rel, e) = judge(&out.image, &reference);
        let (lrel, le) = judge(&render(&gpu, &s, LBL, &[]).image, &reference);
        eprintln!("{scene}: networks energy {e:.3} relL2 {rel:.3}; lbl {le:.3} {lrel:.3}");
        assert!(e > energy.0 && e < energy.1, "{scene}: energy ratio {e}");
        assert!(rel < error, "{scene}: relL2 {rel}");
    }
    assert_clean(&gpu);
}

/// 16384 particles (the ladder's largest) render right: before the splats came in camera order
/// the per-pixel insertion sort's divergent lanes reached llvmpipe's loop limiter unseen and the
/// cloud came out at 0.67 of path's energy (bias 0.62 at 64 x 64, D 32; after: 0.992, 0.041).
/// Here (16 x 16, D 16) its energy is within 5% of 2048 particles' and both within 10% of path's.
#[test]
fn sixteen_thousand_particles_splat_in_order() {
    use crate::common::NETWORKS;
    let gpu = gpu();
    let s = repo_scene("scenes/cloud.toml", &[("render.width", "16"), ("render.height", "16")]);
    let reference = crate::common::path_reference(&gpu, &s, &[("render.spp", "256")]);
    let mut energy = Vec::new();
    for n in ["2048", "16384"] {
        // The farthest of over 256 splats on a pixel are left out, with a warning.
        let sets = [("networks.particles", n), ("networks.directions", "16")];
        let out = crate::common::try_render(&gpu, &s, NETWORKS, &sets, false).expect("render");
        assert!(out.report.warnings.iter().all(|w| w.contains("splats were left out")), "{:?}", out.report.warnings);
        let (rel, e) = judge(&out.image, &reference);
        eprintln!("{n} particles: energy {e:.3}, relL2 {rel:.3}");
        assert!((e - 1.0).abs() < 0.1, "{n} particles: energy ratio {e}");
        energy.push(e);
    }
    assert!((energy[1] / energy[0] - 1.0).abs() < 0.05, "{energy:?}");
    assert_clean(&gpu);
}

/// The network's radiance on the device against the host's (per particle and direction, rgb):
/// the largest difference over the largest host value, and that value.
pub fn device_against_host(device: &[[f32; 4]], host: &[[f64; 3]]) -> (f64, f64) {
    let scale = host.iter().flat_map(|x| x.iter().copied()).fold(0.0f64, f64::max);
    let worst = device
        .iter()
        .zip(host)
        .flat_map(|(a, b)| (0..3).map(move |c| (a[c] as f64 - b[c]).abs()))
        .fold(0.0f64, f64::max);
    (worst / scale, scale)
}

/// The splats' screen tiles (`SplatTiles`, glsl/networks/splat.comp) change the image's time,
/// not the image: on the cloud (perspective, 40 x 28 pixels so that the last tiles are partial),
/// the cloud seen from inside (particles beside and behind the eye, and reaches that hold it),
/// and a sphere seen by an orthographic camera, the image at the default tiles, at 7-pixel tiles
/// and at 1-pixel tiles equals, bit for bit, the image of one tile listing every particle (each
/// pixel testing all N, the kernel before the tiles). The lists are a superset of what a pixel
/// keeps, so the tiles hold at least every splat the image composited (counted), and fewer than
/// N per tile on average where the particles do not fill the view.
#[test]
fn screen_tiles_splat_the_image_of_every_particle_bit_for_bit() {
    use scatterlab::solvers::networks::{Illumination, SplatTiles, SPLAT_TILE};
    let gpu = gpu();
    let small = [("render.width", "40"), ("render.height", "28")];
    let inside = [("render.width", "24"), ("render.height", "24"), ("camera.origin", "[0.1, 0.05, 0.3]")];
    let ortho = crate::common::scene(
        "[render]\nwidth = 24\nheight = 20\nseed = 2\n\
         [camera]\nkind = \"orthographic\"\norigin = [0.3, 3.0, 0.2]\ntarget = [0.0, 0.0, 0.0]\nup = [0.0, 0.0, -1.0]\nextent = 1.4\n\
         [medium]\nbounds = [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]\nsigma_t = 4.0\nalbedo = 0.8\ng = 0.3\n\
         density = { kind = \"sphere\", center = [0.0, 0.0, 0.0], radius = 0.45 }\n\
         [[light]]\nkind = \"directional\"\ndirection = [0.0, -1.0, 0.0]\nirradiance = 1.0\n",
    );
    let cases = [
        ("cloud", repo_scene("scenes/cloud.toml", &small), 600u32),
        ("inside the cloud", repo_scene("scenes/cloud.toml", &inside), 600),
        ("orthographic sphere", ortho, 400),
    ];
    for (what, s, n) in cases {
        let net = network_of(&s, n, 32, None, WindowRule::Fit);
        let mut st = Illumination::new(&gpu, &net, &s, 0.01, false, 0).expect("network");
        st.step(&gpu, 6).expect("iterations");
        let width = 1.0f32;
        let all = st.image_tiled(&gpu, &net, width, 0.02, Some(1 << 20)).expect("one tile");
        let size = [s.render.width, s.render.height];
        for tile in [SPLAT_TILE, 7, 1] {
            let img = st.image_tiled(&gpu, &net, width, 0.02, Some(tile)).expect("tiles");
            let tiles = SplatTiles::of(&s.camera, size, &net, width, Some(tile), false);
            let per_tile = tiles.items.len() as f64 / (tiles.starts.len() - 1) as f64;
            let differ = img.image.data.iter().zip(&all.image.data).filter(|(a, b)| a.to_bits() != b.to_bits()).count();
            eprintln!("{what}, {tile}-pixel tiles: {per_tile:.1} of {n} particles a tile, {differ} values differ");
            assert_eq!(differ, 0, "{what}, {tile}-pixel tiles: the image differs from every particle's");
            assert_eq!(img.dropped, all.dropped, "{what}");
            assert!(all.image.data.iter().any(|v| *v > 0.0), "{what}: some light");
            if tile == 1 {
                assert!(per_tile < n as f64, "{what}: a pixel's tile lists every particle");
            }
        }
    }
    assert_clean(&gpu);
}
