//! The medium's emission as a volume source of the lattice (issue 47): the power an emitting
//! medium puts into each voxel, in the units of the once-scattered deposits the photon march
//! injects (W per voxel; the lattice's time-integrated arrivals over lambda^2 are the fluence,
//! thesis 4.6.2).
//!
//! The transfer equation's source is sigma_a Le (pbrt-v4's convention, W/(m^3 sr)); emitted
//! isotropically, a voxel of edge lambda puts out the power 4 pi sigma_a Le lambda^3. The
//! lattice gets that power in the form that keeps its own balance of emission and absorption
//! exact (Kirchhoff's law on the lattice): a step absorbs kappa_a = 1 - exp(-sigma_a lambda l)
//! of what arrives (glsl/include/lattice.glsl, `lattice_kappa`; l the mean link length, 1 for
//! D3Q6) and counts each arrival as l voxels of path, so a field of radiance Le everywhere
//! (fluence 4 pi Le, arrivals 4 pi Le lambda^2 / l per voxel and step) loses
//! kappa_a 4 pi Le lambda^2 / l per voxel and step. That is the source:
//!
//!   Q = 4 pi Le lambda^2 kappa_a / l   (-> 4 pi sigma_a Le lambda^3 for optically thin voxels)
//!
//! so deep inside a large emitter the lattice's fluence is exactly 4 pi Le whatever the voxel's
//! optical thickness; 4 pi sigma_a Le lambda^3 itself would make it sigma_a lambda l / kappa_a
//! times that (1.17x at sigma_a lambda = 0.31), brighter than the equilibrium bound.
//!
//! Computed on the host, once per render, from the lattice's own density (the resampled
//! medium times an object's occupancy) and each voxel's material: no kernel carries emission
//! code, so a scene without emission runs the lattice's kernels unchanged.

use glam::Vec3;

use super::{Lattice, LatticeGeom};
use crate::scene::{is_grey, Emission, Scene};

/// Whether the scene's emitted radiance differs between channels somewhere (a chromatic Le, a
/// chromatic grid scale, or a three-plane grid such as a blackbody temperature field): the
/// lattice then needs three channels even where the medium and the lights are grey.
pub fn chromatic_emission(scene: &Scene) -> bool {
    let grid = match &scene.medium.emission {
        Emission::Grid(g) => g.planes.len() > 1 || !is_grey(g.scale),
        Emission::Constant(le) => !is_grey(*le),
        Emission::None => false,
    };
    let materials = scene.object.as_ref().map_or(&[][..], |o| &o.materials[..]);
    grid || materials.iter().any(|m| !is_grey(m.emission))
}

/// The emission source of every voxel of `geom`, W per voxel, [c V + v] for `nch` channels
/// (channel 0 alone where `nch` is 1: the scene's emission is then grey), or `None` where the
/// scene does not emit. `density` is the lattice's (per voxel, multiplying the extinction);
/// `voxel_materials` each voxel's material where the objects have several (else every voxel
/// holds the medium's, or the only object material's).
pub fn emission_source(
    scene: &Scene,
    geom: &LatticeGeom,
    lattice: Lattice,
    density: &[f32],
    voxel_materials: Option<&[u32]>,
    nch: u32,
) -> Option<Vec<f32>> {
    if !scene.emissive() {
        return None;
    }
    let v = geom.voxels() as usize;
    debug_assert_eq!(density.len(), v);
    let [nx, ny, _] = geom.dims.map(|d| d as usize);
    let (lambda, l) = (geom.lambda as f64, lattice.mean_link_length());
    let m = &scene.medium;
    // The emission grid's planes at p, before its scale (0 outside the medium's box): Le is
    // the material's `emission` (the grid's scale, or an object material's own) times them, as
    // glsl/include/scene.glsl's emission_at takes it.
    let planes = |p: Vec3| match &m.emission {
        Emission::Grid(g) if m.contains(p) => {
            let u = (p - m.bounds_min) / (m.bounds_max - m.bounds_min);
            let at = |c: usize| g.planes[c.min(g.planes.len() - 1)].sample(u);
            Vec3::new(at(0), at(1), at(2))
        }
        _ => Vec3::ZERO,
    };
    // (sigma_t, albedo, Le at p) of material k: the object's where there is one, else the medium's.
    let medium_of = |k: usize, p: Vec3| -> (Vec3, Vec3, Vec3) {
        let (sigma_t, albedo, le, grid) = match &scene.object {
            Some(o) => {
                let x = &o.materials[k.min(o.materials.len() - 1)];
                (x.sigma_t, x.albedo, x.emission, x.emission_grid)
            }
            None => (m.sigma_t, m.albedo, m.emission.constant_part(), m.emission.grid().is_some()),
        };
        (sigma_t, albedo, if grid { le * planes(p) } else { le })
    };
    let origin = geom.min();
    let mut out = vec![0f32; nch as usize * v];
    let four_pi = 4.0 * std::f64::consts::PI;
    for (i, &rho) in density.iter().enumerate() {
        if rho <= 0.0 {
            continue;
        }
        let p = origin
            + Vec3::new((i % nx) as f32 + 0.5, ((i / nx) % ny) as f32 + 0.5, (i / (nx * ny)) as f32 + 0.5)
                * geom.lambda;
        let k = voxel_materials.map_or(0, |vm| vm[i] as usize);
        let (sigma_t, albedo, le) = medium_of(k, p);
        for c in 0..nch as usize {
            let sigma_a = sigma_t[c] as f64 * (1.0 - albedo[c] as f64) * rho as f64;
            // kappa_a as the lattice's step takes it (lattice_kappa): -expm1 keeps thin voxels exact.
            let kappa_a = -(-sigma_a * lambda * l).exp_m1();
            out[c * v + i] = (four_pi * le[c] as f64 * lambda * lambda * kappa_a / l) as f32;
        }
    }
    Some(out)
}

/// The source's power per channel, W (for the lattice's energy book).
pub fn source_power(source: &[f32], nch: u32) -> [f64; 3] {
    let v = source.len() / nch.max(1) as usize;
    let mut out = [0f64; 3];
    for (c, o) in out.iter_mut().enumerate().take(nch as usize) {
        *o = source[c * v..(c + 1) * v].iter().map(|x| *x as f64).sum();
    }
    out
}
