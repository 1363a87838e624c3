//! The facet lists of `path`'s manifold next-event estimation (glsl/path/trace.comp,
//! `mnee_estimate`): for each light outside a refractive object, a grid over the object's
//! bounds whose cells list the facets whose refracted beam meets the cell. A scattering point
//! tries only its cell's facets instead of every facet of the mesh (on the icosphere of
//! `scenes/milk-orb.toml`, 11 of 1280 on average over the cells at the default 32 per axis).
//!
//! A facet's beam is the light it refracts into the object: from a directional light, the prism
//! swept by the facet along the one refracted direction; from a point light, the rays from the
//! light through the facet's points, refracted. The beam is bounded by marching its three corner
//! rays through the bounds in steps of half a cell: the box of the corners at both ends of each
//! step, widened by [`POINT_PAD`] cells for a point light (inside a facet the refracted rays
//! of a point light are not exactly spanned by the corner rays; the pad covers their
//! departure, which on a facet of the icosphere is below a thousandth of a cell), marks the
//! cells it overlaps. Lists are in facet order, as the full scan is, so the sums are the same:
//! tests/mnee_tests.rs renders both and compares them bit for bit.
//!
//! Buffer layout (u32 words): [0..3) bounds min, [3..6) bounds max (f32 bits), [6] cells per
//! axis n (`path.mnee_cells`; 1 lists every lit facet in one cell, the full scan), [7] unused, [8..40) per light index the word where its table starts (0: no table);
//! a table is n^3 + 1 prefix offsets (relative to the table's facet list, which follows) then
//! the facet indices (BVH leaf order, `Bvh::triangles`).

use glam::DVec3;

use crate::physics::dielectric::refract;
use crate::scene::bvh::GpuTriangle;
use crate::scene::{Light, Scene};

/// Cells per axis by default (`path.mnee_cells`): on `scenes/milk-orb.toml` at 48 x 48, 256
/// spp, 8 / 16 / 32 / 64 cells list 55 / 22 / 11 / 6.9 facets per cell and render in 65 / 39 /
/// 29 / 26 s (the same image, bit for bit).
pub const CELLS: u32 = 32;
/// The widening of a point light's beam boxes, in cells.
pub const POINT_PAD: f64 = 0.25;
/// Words before the first table.
const HEADER: usize = 40;

fn v(a: [f32; 4]) -> DVec3 {
    DVec3::new(a[0] as f64, a[1] as f64, a[2] as f64)
}

/// The facet tables for the lights in `mask` (bit i: light i), over the medium's bounds.
pub fn facet_grid(scene: &Scene, tris: &[GpuTriangle], mask: u32, cells: u32) -> Vec<u32> {
    let mut out = vec![0u32; HEADER];
    let (lo, hi) = (scene.medium.bounds_min, scene.medium.bounds_max);
    for (k, x) in lo.to_array().iter().chain(hi.to_array().iter()).enumerate() {
        out[k] = x.to_bits();
    }
    out[6] = cells;
    if mask == 0 {
        return out;
    }
    let ior = scene.object.as_ref().map_or(1.0, |o| o.ior as f64);
    let (lo, hi) = (lo.as_dvec3(), hi.as_dvec3());
    let n = cells as usize;
    let cell = (hi - lo) / n as f64;
    let step = 0.5 * cell.min_element();
    let reach = (hi - lo).length();
    for (i, light) in scene.lights.iter().enumerate().take(32) {
        if mask & (1 << i) == 0 {
            continue;
        }
        // A point light's position, or a directional light's travel direction.
        let (point, travel, pad) = match *light {
            Light::Point { position, .. } => (Some(position.as_dvec3()), DVec3::ZERO, POINT_PAD),
            Light::Directional { direction, .. } => (None, direction.as_dvec3().normalize(), 1e-3),
            Light::Environment { .. } => continue,
        };
        let mut lists: Vec<Vec<u32>> = vec![Vec::new(); n * n * n];
        let mut stamp = vec![u32::MAX; n * n * n];
        for (j, t) in tris.iter().enumerate() {
            let a = v(t.v0);
            let corners = [a, a + v(t.e1), a + v(t.e2)];
            let normal = v(t.e1).cross(v(t.e2)).normalize_or_zero();
            let lit = match point {
                Some(p) => (p - a).dot(normal) > 0.0,
                None => travel.dot(normal) < 0.0,
            };
            if !lit {
                continue;
            }
            let dirs = corners.map(|c| {
                let d = match point {
                    Some(p) => (c - p).normalize(),
                    None => travel,
                };
                refract(d, normal, 1.0 / ior)
            });
            let [Some(d0), Some(d1), Some(d2)] = dirs else {
                // Total internal reflection at a corner (an object less dense than vacuum,
                // ior < 1): the beam's edge runs along the plane; list the facet everywhere.
                for (idx, l) in lists.iter_mut().enumerate() {
                    if stamp[idx] != j as u32 {
                        stamp[idx] = j as u32;
                        l.push(j as u32);
                    }
                }
                continue;
            };
            let rays = [(corners[0], d0), (corners[1], d1), (corners[2], d2)];
            let mut s = 0.0;
            while s <= reach {
                let (mut blo, mut bhi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
                for (c, d) in rays {
                    for ds in [s, s + step] {
                        blo = blo.min(c + d * ds);
                        bhi = bhi.max(c + d * ds);
                    }
                }
                let blo = blo - cell * pad;
                let bhi = bhi + cell * pad;
                if blo.cmpgt(hi).any() || bhi.cmplt(lo).any() {
                    s += step;
                    continue;
                }
                let c0 = ((blo - lo) / cell).floor().max(DVec3::ZERO).min(DVec3::splat(n as f64 - 1.0));
                let c1 = ((bhi - lo) / cell).floor().max(DVec3::ZERO).min(DVec3::splat(n as f64 - 1.0));
                for z in c0.z as usize..=c1.z as usize {
                    for y in c0.y as usize..=c1.y as usize {
                        for x in c0.x as usize..=c1.x as usize {
                            let idx = x + n * (y + n * z);
                            if stamp[idx] != j as u32 {
                                stamp[idx] = j as u32;
                                lists[idx].push(j as u32);
                            }
                        }
                    }
                }
                s += step;
            }
        }
        out[8 + i] = out.len() as u32;
        let mut offset = 0u32;
        for l in &lists {
            out.push(offset);
            offset += l.len() as u32;
        }
        out.push(offset);
        for l in &lists {
            out.extend_from_slice(l);
        }
    }
    out
}

/// How many facets a cell lists on average, per light in the table (for the render's stats).
pub fn mean_list_length(grid: &[u32], light: usize) -> f64 {
    let start = grid[8 + light] as usize;
    if start == 0 {
        return 0.0;
    }
    let cells = (grid[6] as usize).pow(3);
    grid[start + cells] as f64 / cells as f64
}
