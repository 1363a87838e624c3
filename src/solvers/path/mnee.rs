//! The chain lists of `path`'s manifold next-event estimation (glsl/path/trace.comp,
//! `mnee_estimate`): for each point or directional light outside every refractive object, a
//! grid over the medium's bounds whose cells list the specular chains (the facets, in order from
//! the light, at which the light's ray refracts or reflects) through which the light may reach
//! a point of the cell. A scattering point tries only its cell's chains instead of every facet
//! of the mesh (on the icosphere of `scenes/milk-orb.toml`, 11 single refractions of 1280 on
//! average over the cells at the default 32 per axis).
//!
//! **Single refractions** (light -> facet -> the point): every facet that faces the light is a
//! chain of one. Its beam is the light it refracts into the object: from a directional light,
//! the prism swept by the facet along the one refracted direction; from a point light, the rays
//! from the light through the facet's points, refracted. The beam is bounded by marching its
//! three corner rays through the bounds in steps of half a cell: the box of the corners at both
//! ends of each step, widened by [`POINT_PAD`] cells for a point light (inside a facet the
//! refracted rays of a point light are not exactly spanned by the corner rays; the pad covers
//! their departure, which on a facet of the icosphere is below a thousandth of a cell), marks
//! the cells it overlaps. Conservative, so no single refraction is ever missed.
//!
//! **Longer chains** (up to `path.mnee_depth` facets): the light reflected inside an object
//! before it reaches the point (Fresnel F, and 1 under total internal reflection), light that
//! crosses one object or one sheet of a non-convex mesh on its way into another, and any mix.
//! They are found by tracing the light's rays: at least `path.mnee_rays`^2 per facet that faces
//! the light (spread evenly over it; more on a facet many cells long, so that neighbouring rays
//! leave it at most half a cell apart), each followed exactly through every refraction and
//! reflection it meets (both branches) up to the depth; every sequence of facets that ends
//! inside an object is a chain, and the cells along the last leg of each of its rays, widened
//! by [`CHAIN_PAD`] cells and by how far a point light's rays part on the way, list it. Found
//! by sampling, so a chain whose beam leaves its first facet through a sliver narrower than
//! the rays' spacing can be missed.
//! The GPU solves each listed chain for the point (a Newton iteration on the first facet's
//! barycentric coordinates; at most one solution per chain of planes, Fermat's principle
//! being convex there), checks that every vertex lies in its facet and that no surface blocks a
//! leg in vacuum, and adds the irradiance the ray tube carries there.
//!
//! Lists are in chain order (a facet's single refraction, then the longer chains found from
//! it, facet by facet), as the full scan is, so the sums are the same: tests/mnee_tests.rs
//! renders both and compares them bit for bit.
//!
//! Buffer layout (u32 words): [0..3) bounds min, [3..6) bounds max (f32 bits), [6] cells per
//! axis n (`path.mnee_cells`; 1 lists every chain in one cell, the full scan), [7] flags (bit
//! 0: a leg in vacuum may be blocked, so the GPU tests it: several objects or a mesh that is not
//! convex), [8..40) per light index the word where its table starts (0: no table), [40..72) per light
//! flags (bit 0: the light lies inside an object: its chains start inside, and the straight
//! shadow ray is estimated too). Then the
//! chain records: word 0 the chain's length k | its reflection mask << 8 (bit v: the light
//! reflects at vertex v, else it refracts), then its k facet indices (BVH leaf order,
//! `Bvh::triangles`) from the light's side. Then each table: n^3 + 1 prefix offsets (relative to
//! the table's list, which follows), then the list: the word offsets of chain records.

use std::collections::HashMap;

use glam::DVec3;
use rayon::prelude::*;

use crate::physics::dielectric::refract;
use crate::scene::bvh::{Bvh, GpuTriangle};
use crate::scene::{Light, Scene};

/// Cells per axis by default (`path.mnee_cells`): on `scenes/milk-orb.toml` at 48 x 48, 256
/// spp, 8 / 16 / 32 / 64 cells list 55 / 22 / 11 / 6.9 facets per cell and render in 65 / 39 /
/// 29 / 26 s (the same image, bit for bit).
pub const CELLS: u32 = 32;
/// Facets per chain at most, by default (`path.mnee_depth`).
pub const DEPTH: u32 = 3;
/// The most `path.mnee_depth` may be (the GPU's state holds a leg index below 12).
pub const MAX_DEPTH: u32 = 8;
/// Reflections per chain at most, by default (`path.mnee_reflections`).
pub const REFLECTIONS: u32 = 1;
/// Rays per facet edge by default (`path.mnee_rays`): rays^2 rays per facet.
pub const RAYS: u32 = 12;
/// The widening of a point light's single-refraction beam boxes, in cells.
pub const POINT_PAD: f64 = 0.25;
/// The widening of a traced chain ray's boxes, in cells: the rays of one chain leave their
/// first facet at most half a cell apart (more rays per edge on a facet many cells long; on the
/// icosphere at 12 per edge, a sixth of a cell), so a cell that the chain's beam meets between
/// two traced rays is still listed. A point light's rays part further along the way; the pad
/// grows with that.
pub const CHAIN_PAD: f64 = 0.3;
/// Rays per facet edge at most (a facet many cells long).
pub const MAX_RAYS: usize = 256;
/// Words before the first chain record.
const HEADER: usize = 72;

fn v(a: [f32; 4]) -> DVec3 {
    DVec3::new(a[0] as f64, a[1] as f64, a[2] as f64)
}

/// How the chains are found and listed (the `path.mnee_*` knobs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChainOptions {
    /// Cells per axis.
    pub cells: u32,
    /// Facets per chain at most (1: single refractions only).
    pub depth: u32,
    /// Rays per facet edge of the search for longer chains.
    pub rays: u32,
    /// Reflections per chain at most.
    pub reflections: u32,
}

impl Default for ChainOptions {
    fn default() -> Self {
        ChainOptions { cells: CELLS, depth: DEPTH, rays: RAYS, reflections: REFLECTIONS }
    }
}

/// The cell grid over the bounds, and the cells a box overlaps.
struct Cells {
    lo: DVec3,
    hi: DVec3,
    n: usize,
    cell: DVec3,
}

impl Cells {
    /// Calls `f` with every cell index the box [blo, bhi] overlaps (none when it misses the bounds).
    fn each(&self, blo: DVec3, bhi: DVec3, mut f: impl FnMut(usize)) {
        if blo.cmpgt(self.hi).any() || bhi.cmplt(self.lo).any() {
            return;
        }
        let m = DVec3::splat(self.n as f64 - 1.0);
        let c0 = ((blo - self.lo) / self.cell).floor().max(DVec3::ZERO).min(m);
        let c1 = ((bhi - self.lo) / self.cell).floor().max(DVec3::ZERO).min(m);
        for z in c0.z as usize..=c1.z as usize {
            for y in c0.y as usize..=c1.y as usize {
                for x in c0.x as usize..=c1.x as usize {
                    f(x + self.n * (y + self.n * z));
                }
            }
        }
    }

    /// The cells a beam spanned by three rays (corner, unit direction) overlaps over [0,
    /// reach], in steps `step`: the box of the corners at both ends of each step (the beam between
    /// two cross-sections lies in their hull when its rays are straight lines), widened by `pad`
    /// cells. Unsorted, with repeats.
    fn beam(&self, rays: [(DVec3, DVec3); 3], reach: f64, step: f64, pad: f64) -> Vec<u32> {
        let mut cells = Vec::new();
        let mut s = 0.0;
        while s <= reach {
            let (mut blo, mut bhi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
            for (c, d) in rays {
                for ds in [s, s + step] {
                    blo = blo.min(c + d * ds);
                    bhi = bhi.max(c + d * ds);
                }
            }
            self.each(blo - self.cell * pad, bhi + self.cell * pad, |idx| cells.push(idx as u32));
            s += step;
        }
        cells
    }

    /// The cells along the segment c + d s, s in [0, len] (a ray's leg), in steps of half a
    /// cell, each step's box widened by `pad` cells and `pad_world` scene units.
    fn along(&self, c: DVec3, d: DVec3, len: f64, pad: f64, pad_world: f64, f: &mut impl FnMut(usize)) {
        let step = 0.5 * self.cell.min_element();
        let mut s = 0.0;
        loop {
            let s1 = (s + step).min(len);
            let (a, b) = (c + d * s, c + d * s1);
            let w = self.cell * pad + DVec3::splat(pad_world);
            self.each(a.min(b) - w, a.max(b) + w, &mut *f);
            if s1 >= len {
                break;
            }
            s = s1;
        }
    }
}

/// The index of the object facet `f` bounds (its material's, by the BVH's tag).
fn facet_ior(bvh: &Bvh, iors: &[f64], f: u32) -> f64 {
    iors[(bvh.tag(f) as usize).min(iors.len() - 1)]
}

/// One event of a traced ray at a facet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
struct Vertex {
    facet: u32,
    reflect: bool,
}

/// The search for longer chains from one facet: the rays' state and what they found.
struct Search<'a> {
    bvh: &'a Bvh,
    iors: &'a [f64],
    depth: usize,
    /// The fewest facets a chain has that is listed here (single refractions are listed apart).
    min_len: usize,
    /// Reflections per chain at most.
    reflections: usize,
    /// The chains found, in order of discovery, each with the last legs of the rays that follow
    /// it: start, unit direction, length, and the path length from the first facet to the start.
    found: Vec<(Vec<Vertex>, Vec<Leg>)>,
    index: HashMap<Vec<Vertex>, usize>,
}

/// The last leg of a ray that follows a chain: start, unit direction, length, and the path
/// length from the first facet to the start.
type Leg = (DVec3, DVec3, f64, f64);

impl Search<'_> {
    fn normal(&self, f: u32) -> DVec3 {
        let t = &self.bvh.triangles[f as usize];
        v(t.e1).cross(v(t.e2)).normalize()
    }

    fn ior(&self, f: u32) -> f64 {
        facet_ior(self.bvh, self.iors, f)
    }

    /// The next surface along p + t d (t > a small offset): facet, distance.
    fn next(&self, p: DVec3, d: DVec3) -> Option<(u32, f64)> {
        let eps = 1e-5 * p.abs().max_element().max(1.0);
        let o = p + d * eps;
        self.bvh.intersect(o.as_vec3(), d.as_vec3(), 0.0, f32::INFINITY).map(|h| (h.triangle, h.t as f64 + eps))
    }

    /// Follows a ray that meets facet `f` at `p` travelling along `d` (inside an object or not,
    /// before the event), with the vertices so far, through both events there.
    fn follow(&mut self, chain: &mut Vec<Vertex>, f: u32, p: DVec3, d: DVec3, inside: bool, acc: f64) {
        let n = self.normal(f);
        let entering = d.dot(n) < 0.0;
        let nf = if entering { n } else { -n };
        let ior = self.ior(f);
        let eta = if entering { 1.0 / ior } else { ior };
        let refracted = refract(d, nf, eta);
        let reflected = (d - 2.0 * d.dot(nf) * nf).normalize();
        let reflected_so_far = chain.iter().filter(|x| x.reflect).count();
        for (dir, reflect) in [(refracted, false), (Some(reflected), true)] {
            let Some(dir) = dir else { continue };
            if reflect && reflected_so_far >= self.reflections {
                continue;
            }
            // A refraction crosses to the other side; a reflection stays.
            let now_inside = if reflect { inside } else { !inside };
            chain.push(Vertex { facet: f, reflect });
            let hit = self.next(p, dir);
            if now_inside && chain.len() >= self.min_len {
                // The leg up to the next surface is where this chain can light a point.
                let len = hit.map_or(0.0, |h| h.1);
                let k = match self.index.get(chain.as_slice()) {
                    Some(&k) => k,
                    None => {
                        self.index.insert(chain.clone(), self.found.len());
                        self.found.push((chain.clone(), Vec::new()));
                        self.found.len() - 1
                    }
                };
                self.found[k].1.push((p, dir, len, acc));
            }
            if chain.len() < self.depth {
                if let Some((g, t)) = hit {
                    self.follow(chain, g, p + dir * t, dir, now_inside, acc + t);
                }
            }
            chain.pop();
        }
    }
}

/// The chain tables for the lights in `mask` (bit i: light i; set in `inside` where the light
/// lies inside an object, else it is outside every object), over the medium's bounds.
pub fn facet_grid(scene: &Scene, bvh: Option<&Bvh>, mask: u32, inside: u32, opts: ChainOptions) -> Vec<u32> {
    let mut out = vec![0u32; HEADER];
    let (lo, hi) = (scene.medium.bounds_min, scene.medium.bounds_max);
    for (k, x) in lo.to_array().iter().chain(hi.to_array().iter()).enumerate() {
        out[k] = x.to_bits();
    }
    out[6] = opts.cells;
    let (Some(bvh), Some(object)) = (bvh, scene.object.as_ref()) else { return out };
    if mask == 0 {
        return out;
    }
    out[7] = u32::from(object.parts.len() > 1 || !object.convex);
    let iors: Vec<f64> = object.materials.iter().map(|m| m.ior as f64).collect();
    let tris: &[GpuTriangle] = &bvh.triangles;
    let (lo, hi) = (lo.as_dvec3(), hi.as_dvec3());
    let n = opts.cells as usize;
    let grid = Cells { lo, hi, n, cell: (hi - lo) / n as f64 };
    let step = 0.5 * grid.cell.min_element();
    let reach = (hi - lo).length();
    let mut tables: Vec<(usize, Vec<Vec<u32>>)> = Vec::new();
    for (i, light) in scene.lights.iter().enumerate().take(32) {
        if mask & (1 << i) == 0 {
            continue;
        }
        // A point light's position, or a directional light's travel direction.
        let (point, travel) = match *light {
            Light::Point { position, .. } => (Some(position.as_dvec3()), DVec3::ZERO),
            Light::Directional { direction, .. } => (None, direction.as_dvec3().normalize()),
            Light::Environment { .. } => continue,
        };
        // Each facet's chains (its single refraction first) with the cells that list them, found
        // in parallel and laid out in facet order: the same buffer on any number of threads.
        let light_inside = inside & (1 << i) != 0;
        out[40 + i] = u32::from(light_inside);
        // The material of the object holding a light inside (the first surface any ray from it
        // meets is its own object's: the meshes are disjoint and none lies inside another).
        let own = match point {
            Some(l) if light_inside => bvh
                .intersect(l.as_vec3(), glam::Vec3::new(0.5773, 0.5774, 0.5773503), 0.0, f32::INFINITY)
                .map(|h| bvh.tag(h.triangle)),
            _ => None,
        };
        let per_facet: Vec<Vec<(Vec<u32>, Vec<u32>)>> = (0..tris.len())
            .into_par_iter()
            .map(|j| {
                if own.is_some_and(|m| bvh.tag(j as u32) != m) {
                    return Vec::new();
                }
                facet_chains(bvh, &iors, &grid, j, point, travel, light_inside, opts, reach, step)
            })
            .collect();
        let mut lists: Vec<Vec<u32>> = vec![Vec::new(); n * n * n];
        for chains in per_facet {
            for (words, cells) in chains {
                let record = out.len() as u32;
                out.extend_from_slice(&words);
                for c in cells {
                    lists[c as usize].push(record);
                }
            }
        }
        tables.push((i, lists));
    }
    for (i, lists) in tables {
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

/// The chains that start at facet `j` for a light at `point` (or travelling along `travel`):
/// each chain's record words and the sorted cells that list it. None when the facet does not
/// face the light.
#[allow(clippy::too_many_arguments)]
fn facet_chains(
    bvh: &Bvh,
    iors: &[f64],
    grid: &Cells,
    j: usize,
    point: Option<DVec3>,
    travel: DVec3,
    light_inside: bool,
    opts: ChainOptions,
    reach: f64,
    step: f64,
) -> Vec<(Vec<u32>, Vec<u32>)> {
    let t = &bvh.triangles[j];
    let a = v(t.v0);
    let corners = [a, a + v(t.e1), a + v(t.e2)];
    let normal = v(t.e1).cross(v(t.e2)).normalize_or_zero();
    // The light on the facet's outer side, or on its inner side for a light inside an object
    // (whether it is this facet's object, the rays' clear first legs decide).
    let lit = match point {
        Some(p) => ((p - a).dot(normal) > 0.0) != light_inside,
        None => travel.dot(normal) < 0.0,
    };
    if !lit {
        return Vec::new();
    }
    let finish = |mut cells: Vec<u32>| {
        cells.sort_unstable();
        cells.dedup();
        cells
    };
    let mut out = Vec::new();
    let ior = facet_ior(bvh, iors, j as u32);
    if light_inside {
        // From a light inside, the light reflected once at facet j: the cone from the light's
        // mirror image through the facet (a flat mirror keeps rays straight), marked by its
        // corner rays as a single refraction is; the longer chains the rays find follow.
        if let (Some(l), true) = (point, opts.reflections >= 1) {
            let image = l - 2.0 * (l - a).dot(normal) * normal;
            let cells = grid.beam(corners.map(|c| (c, (c - image).normalize())), reach, step, 1e-3);
            out.push((vec![1 | (1 << 8), j as u32], finish(cells)));
        }
    } else {
        // The single refraction through facet j.
        let pad = if point.is_some() { POINT_PAD } else { 1e-3 };
        let dirs = corners.map(|c| {
            let d = match point {
                Some(p) => (c - p).normalize(),
                None => travel,
            };
            refract(d, normal, 1.0 / ior)
        });
        let cells = if let [Some(d0), Some(d1), Some(d2)] = dirs {
            grid.beam([(corners[0], d0), (corners[1], d1), (corners[2], d2)], reach, step, pad)
        } else {
            // Total internal reflection at a corner (an object less dense than vacuum, ior < 1):
            // the beam's edge runs along the plane; list the facet everywhere.
            (0..(grid.n * grid.n * grid.n) as u32).collect()
        };
        out.push((vec![1, j as u32], finish(cells)));
    }
    if opts.depth >= 2 {
        let how = (point, travel, light_inside);
        trace_chains(bvh, iors, grid, j, how, opts, reach, &mut out);
    }
    out
}

/// Appends to `out` the chains of up to `depth` facets that rays from the light through facet
/// `j` follow (`light_inside`: they start inside the facet's object), with their cells.
#[allow(clippy::too_many_arguments)]
fn trace_chains(
    bvh: &Bvh,
    iors: &[f64],
    grid: &Cells,
    j: usize,
    (point, travel, light_inside): (Option<DVec3>, DVec3, bool),
    opts: ChainOptions,
    reach: f64,
    out: &mut Vec<(Vec<u32>, Vec<u32>)>,
) {
    let ChainOptions { depth, rays, reflections, .. } = opts;
    let t = &bvh.triangles[j];
    let a = v(t.v0);
    // Longer chains: rays over the facet, followed through both events at every surface.
    let mut search = Search {
        bvh,
        iors,
        depth: depth as usize,
        min_len: 2,
        reflections: reflections as usize,
        found: Vec::new(),
        index: HashMap::new(),
    };
    // At least `rays` per edge, and enough that neighbouring rays leave the facet less than
    // half a cell apart (a box's facets are many cells long).
    let edge = [v(t.e1).length(), v(t.e2).length(), (v(t.e2) - v(t.e1)).length()].into_iter().fold(0.0, f64::max);
    let r = (rays.max(1) as usize).max((2.0 * edge / grid.cell.min_element()).ceil() as usize).min(MAX_RAYS);
    let spacing = edge / r as f64;
    // How fast neighbouring rays part (radians): a point light's rays diverge by their spacing
    // over their distance from it; refraction and reflection at flat facets change the angle by
    // a bounded factor, allowed for twice over.
    let spread = match point {
        // The facet's nearest point to the light is no nearer than its plane.
        Some(l) => 2.0 * spacing / (a - l).dot(v(t.e1).cross(v(t.e2)).normalize_or_zero()).abs().max(1e-6),
        None => 0.0,
    };
    let mut chain = Vec::with_capacity(depth as usize);
    for ua in 0..r {
        for ub in 0..r - ua {
            // The centroids of the r^2 sub-triangles of the facet.
            let mut params = vec![((ua as f64 + 1.0 / 3.0) / r as f64, (ub as f64 + 1.0 / 3.0) / r as f64)];
            if ua + ub + 1 < r {
                params.push(((ua as f64 + 2.0 / 3.0) / r as f64, (ub as f64 + 2.0 / 3.0) / r as f64));
            }
            for (pa, pb) in params {
                let p = a + v(t.e1) * pa + v(t.e2) * pb;
                let d = match point {
                    Some(l) => (p - l).normalize(),
                    None => travel,
                };
                // The leg from the light must be clear (another object or sheet may shade the
                // facet here).
                let back = match point {
                    Some(l) => (l - p).length(),
                    None => f64::INFINITY,
                };
                if search.next(p, -d).is_some_and(|(_, t)| t < back) {
                    continue;
                }
                search.follow(&mut chain, j as u32, p, d, light_inside, 0.0);
            }
        }
    }
    // The last chain that listed each cell: a chain's rays overlap, and list a cell once.
    let mut stamp = vec![u32::MAX; grid.n * grid.n * grid.n];
    for (id, (vertices, legs)) in search.found.into_iter().enumerate() {
        let mask_bits = vertices.iter().enumerate().fold(0u32, |m, (k, x)| m | (u32::from(x.reflect) << k));
        let mut words = vec![vertices.len() as u32 | (mask_bits << 8)];
        words.extend(vertices.iter().map(|x| x.facet));
        let mut cells = Vec::new();
        for (c, d, len, acc) in legs {
            let len = if len > 0.0 { len } else { reach };
            // The gap to the neighbouring rays, in scene units: isotropic, so not scaled by a
            // cell's shortest side (a flat slab's cells are 24 times thinner than wide).
            grid.along(c, d, len, CHAIN_PAD, spread * (acc + len), &mut |idx| {
                if stamp[idx] != id as u32 {
                    stamp[idx] = id as u32;
                    cells.push(idx as u32);
                }
            });
        }
        cells.sort_unstable();
        out.push((words, cells));
    }
}

/// How many chains a cell lists on average, per light in the table (for the render's stats).
pub fn mean_list_length(grid: &[u32], light: usize) -> f64 {
    let start = grid[8 + light] as usize;
    if start == 0 {
        return 0.0;
    }
    let cells = (grid[6] as usize).pow(3);
    grid[start + cells] as f64 / cells as f64
}

/// How many chains of each length (index k - 1) the buffer's records hold, over every light.
pub fn chain_counts(grid: &[u32]) -> Vec<u64> {
    let first_table = (8..40).map(|k| grid[k] as usize).filter(|&s| s != 0).min().unwrap_or(grid.len());
    let mut counts = Vec::new();
    let mut w = HEADER;
    while w < first_table {
        let k = (grid[w] & 0xff) as usize;
        if counts.len() < k {
            counts.resize(k, 0);
        }
        counts[k - 1] += 1;
        w += 1 + k;
    }
    counts
}
