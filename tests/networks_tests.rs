//! Illumination networks' particle model and visibility network (issue 15, paper 2.1 and
//! 3.1-3.2): particles follow the density and are deterministic; the directions are a unit,
//! orthonormal, balanced set; the visibility network built on the device equals the host's
//! construction exactly, and every window column is one chain from the sky down.

use glam::Vec3;
use scatterlab::solvers::networks::{Directions, Network, Particles, Window, NONE};

use crate::common::{assert_clean, gpu, repo_scene};

fn network(scene: &str, sets: &[(&str, &str)], n: u32, d: u32, m: Option<u32>) -> Network {
    let s = repo_scene(scene, sets);
    let particles = Particles::sample(&s, n, s.render.seed).expect("particles");
    let window = Window::new(&s, &particles, d, m);
    Network { particles, directions: Directions::new(d, s.render.seed), window }
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
