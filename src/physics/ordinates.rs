//! A CPU reference of discrete-ordinates transport on a voxel grid (thesis 2.1 and 5.3; issue
//! 13): the oracle the GPU `dom` sweeps will be checked against, in double precision and
//! without any of their scheduling (no blocks, no wavefronts, no streaming).
//!
//! For each direction Omega of a [`Quadrature`] the grid is swept from the upwind corner, and
//! each voxel's radiance follows from its balance with the **step scheme** (the voxel's
//! outflow through each downwind face equals its mean radiance):
//!
//!   sum_a |Omega_a| (I - I_in,a) / h + sigma_t I = Q
//!   =>  I = (Q + sum_a |Omega_a| I_in,a / h) / (sigma_t + sum_a |Omega_a| / h)
//!
//! with I_in,a the upwind neighbour's radiance across the face normal to axis a (0 at a vacuum
//! face), h the voxel edge and Q the emission per unit volume and solid angle. It is first
//! order, never negative (a sum of non-negative terms over a positive denominator) and
//! conservative: summed over voxels and weighted over directions, what leaves through the
//! boundary plus what is absorbed equals what is emitted, exactly.
//!
//! [`OrdinatesGrid::solve`] scatters isotropically (the storage directions M = 1 that the issue
//! asks for isotropic media): the source of the next iteration is sigma_s phi / (4 pi),
//! phi = sum_d w_d I_d, iterated from the first-scattering source until the fluence changes by
//! less than a tolerance. [`OrdinatesGrid::solve_angular`] scatters by Henyey-Greenstein with
//! the source stored at M directions (`physics::angular`), as the device's `dom` does.

use super::quadrature::Quadrature;

/// A box of cubic voxels, x fastest.
#[derive(Clone, Debug)]
pub struct OrdinatesGrid {
    pub dims: [usize; 3],
    /// Voxel edge, scene units.
    pub h: f64,
    /// Extinction per voxel, 1/unit.
    pub sigma_t: Vec<f64>,
    /// Single-scattering albedo per voxel.
    pub albedo: Vec<f64>,
    /// Faces normal to x and y wrap around (a laterally infinite slab), else they are vacuum.
    pub periodic_xy: bool,
    pub scheme: Scheme,
}

/// How a voxel's outflow follows from its inflow and emission.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Scheme {
    /// Step (upwind) difference: the outflow through every face is the voxel's mean radiance,
    /// from the voxel's balance. First order, and diffusive where a voxel is optically thick.
    Step,
    /// Step characteristics (thesis 5.3.1-5.3.2; Lathrop's method): face-averaged radiances
    /// carried across the voxel along the direction with exact exponential attenuation, the
    /// emission flat in the voxel; [`characteristic_update`].
    Characteristics,
}

/// `f[i][o]` and `s[i][o]` of [`characteristic_geometry`].
pub type Geometry = ([[f64; 3]; 3], [[f64; 3]; 3]);

/// A direction's geometry across a unit cube (all components taken positive): `f[i][o]`, the
/// fraction of outgoing face o whose characteristics entered through face i (the thesis's
/// A_In,Out / A_Out, Fig. 5.3), and `s[i][o]` their mean length (its s_avg(In, Out)), in voxel
/// edges. Sampled on a 64 x 64 grid of each outgoing face, then made exact where exactness
/// matters: sum_i f[i][o] = 1, sum_o |w_o| f[i][o] = |w_i| (what enters through a face leaves
/// through the others), and sum_io |w_o| f[i][o] s[i][o] = 1 (the mean chord: the volume),
/// which is what makes [`characteristic_update`] conserve energy and never go negative.
pub fn characteristic_geometry(a: [f64; 3]) -> Geometry {
    const K: usize = 64;
    let (mut f, mut s) = ([[0.0f64; 3]; 3], [[0.0f64; 3]; 3]);
    for o in 0..3 {
        if a[o] == 0.0 {
            continue;
        }
        let (u_axis, v_axis) = ((o + 1) % 3, (o + 2) % 3);
        for ui in 0..K {
            for vi in 0..K {
                let mut p = [0.0; 3];
                p[o] = 1.0;
                p[u_axis] = (ui as f64 + 0.5) / K as f64;
                p[v_axis] = (vi as f64 + 0.5) / K as f64;
                // Back along the direction to the first plane x_i = 0 it meets.
                let (mut best, mut t_best) = (o, f64::INFINITY);
                for i in 0..3 {
                    if a[i] > 0.0 && p[i] / a[i] < t_best {
                        best = i;
                        t_best = p[i] / a[i];
                    }
                }
                f[best][o] += 1.0;
                s[best][o] += t_best;
            }
        }
        for i in 0..3 {
            if f[i][o] > 0.0 {
                s[i][o] /= f[i][o];
                f[i][o] /= (K * K) as f64;
            }
        }
    }
    // T[i][o] = |w_o| f[i][o]: balance its rows to |w_i| and columns to |w_o| (Sinkhorn on
    // 3 x 3; the sampled fractions are within 1/K of it already).
    for _ in 0..200 {
        for (fi, ai) in f.iter_mut().zip(a) {
            let row: f64 = fi.iter().zip(a).map(|(fio, ao)| ao * fio).sum();
            if row > 0.0 {
                fi.iter_mut().for_each(|fio| *fio *= ai / row);
            }
        }
        for o in 0..3 {
            let col: f64 = f.iter().map(|fi| fi[o]).sum();
            if col > 0.0 {
                f.iter_mut().for_each(|fi| fi[o] /= col);
            }
        }
    }
    let chord: f64 = (0..3).flat_map(|i| (0..3).map(move |o| (i, o))).map(|(i, o)| a[o] * f[i][o] * s[i][o]).sum();
    for row in s.iter_mut() {
        for x in row.iter_mut() {
            *x /= chord;
        }
    }
    (f, s)
}

/// (1 - e^-x) / x, and (x - 1 + e^-x) / x^2, both without cancellation near 0.
fn phi_psi(x: f64) -> (f64, f64) {
    if x < 1e-3 {
        (1.0 - x / 2.0 + x * x / 6.0 - x * x * x / 24.0, 0.5 - x / 6.0 + x * x / 24.0 - x * x * x / 120.0)
    } else {
        let em1 = (-x).exp_m1();
        (-em1 / x, (x + em1) / (x * x))
    }
}

/// One voxel of step characteristics (thesis 5.3.1-5.3.2): with s = S / sigma_t and
/// x = sigma_t h s_io, each outgoing face's mean radiance is
///   L_out,o = sum_i f_io (L_in,i e^-x_io + S h s_io phi(x_io))
/// (the thesis's S / kappa + sum_i f (L_in - S / kappa) e^-kappa s_avg, written so that it holds
/// at sigma_t = 0), and the voxel's mean radiance follows from its balance,
///   L_V = sum_i L_in,i sum_o |w_o| f_io s_io phi(x_io) + S h sum_io |w_o| f_io s_io^2 psi(x_io),
/// non-negative, and exactly conservative given the geometry's identities. `own[i]`: axis i is
/// periodic and one voxel wide, its inflow the voxel's own outflow (solved for). Returns L_V
/// and the three outgoing faces' radiances.
pub fn characteristic_update(
    geometry: &Geometry,
    a: [f64; 3],
    h: f64,
    sigma_t: f64,
    source: f64,
    inflow: [f64; 3],
    own: [bool; 3],
) -> (f64, [f64; 3]) {
    let (f, s) = geometry;
    let mut e = [[0.0; 3]; 3];
    let mut ph = [[0.0; 3]; 3];
    let mut ps = [[0.0; 3]; 3];
    for i in 0..3 {
        for o in 0..3 {
            let x = sigma_t * h * s[i][o];
            e[i][o] = (-x).exp();
            (ph[i][o], ps[i][o]) = phi_psi(x);
        }
    }
    let emitted = |o: usize| (0..3).map(|i| f[i][o] * source * h * s[i][o] * ph[i][o]).sum::<f64>();
    let mut l_in = inflow;
    // Own (periodic, one voxel wide) axes: L_out,p = L_in,p, a linear system of at most two.
    let owned: Vec<usize> = (0..3).filter(|k| own[*k]).collect();
    if !owned.is_empty() {
        let rhs =
            |o: usize| emitted(o) + (0..3).filter(|i| !own[*i]).map(|i| f[i][o] * e[i][o] * inflow[i]).sum::<f64>();
        match owned.as_slice() {
            [p] => l_in[*p] = rhs(*p) / (1.0 - f[*p][*p] * e[*p][*p]),
            [p, q] => {
                let (m00, m01) = (1.0 - f[*p][*p] * e[*p][*p], -f[*q][*p] * e[*q][*p]);
                let (m10, m11) = (-f[*p][*q] * e[*p][*q], 1.0 - f[*q][*q] * e[*q][*q]);
                let (b0, b1) = (rhs(*p), rhs(*q));
                let det = m00 * m11 - m01 * m10;
                l_in[*p] = (b0 * m11 - m01 * b1) / det;
                l_in[*q] = (m00 * b1 - m10 * b0) / det;
            }
            _ => unreachable!("three periodic axes one voxel wide"),
        }
    }
    let faces: [f64; 3] =
        std::array::from_fn(|o| emitted(o) + (0..3).map(|i| f[i][o] * e[i][o] * l_in[i]).sum::<f64>());
    let mut cell = 0.0;
    for i in 0..3 {
        for o in 0..3 {
            cell += a[o] * f[i][o] * s[i][o] * (l_in[i] * ph[i][o] + source * h * s[i][o] * ps[i][o]);
        }
    }
    (cell, faces)
}

/// The converged field and how it got there.
#[derive(Clone, Debug)]
pub struct OrdinatesSolution {
    /// Scalar fluence per voxel, sum_d w_d I_d (the first-scattering source's light and
    /// everything scattered after, not the unscattered light that made that source).
    pub fluence: Vec<f64>,
    /// Power leaving through the faces normal to +z and -z (W, per unit of the source's units
    /// times volume): sum over the face's voxels and the outgoing directions of w |Omega_z| I h^2.
    pub leaving_top: f64,
    pub leaving_bottom: f64,
    /// Power leaving through every vacuum face.
    pub leaving: f64,
    pub iterations: u32,
    pub converged: bool,
}

impl OrdinatesGrid {
    fn index(&self, [x, y, z]: [usize; 3]) -> usize {
        x + self.dims[0] * (y + self.dims[1] * z)
    }

    fn voxels(&self) -> usize {
        self.dims.iter().product()
    }

    /// One sweep per direction of `q` for the emission `emission(direction, voxel)` (per unit
    /// volume and solid angle): the fluence, and the power leaving through the top (+z) and
    /// bottom (-z) faces and through every vacuum face. `last[d]` holds direction d's cell
    /// radiances (`[0]`, what scattering reads) and outgoing face radiances across x, y, z
    /// (`[1..4]`); periodic x/y faces take their inflow from the opposite side's outflow of the
    /// previous sweep, which a converged iteration makes exact.
    fn sweep(
        &self,
        q: &Quadrature,
        geometry: &[Geometry],
        emission: &dyn Fn(usize, usize) -> f64,
        last: &mut [[Vec<f64>; 4]],
    ) -> (Vec<f64>, [f64; 3]) {
        let [nx, ny, nz] = self.dims;
        let v = self.voxels();
        let mut fluence = vec![0.0; v];
        let (mut top, mut bottom, mut leaving) = (0.0, 0.0, 0.0);
        for (d, (dir, w)) in q.directions.iter().zip(&q.weights).enumerate() {
            let a = dir.map(f64::abs);
            let order = |n: usize, positive: bool| -> Vec<usize> {
                if positive {
                    (0..n).collect()
                } else {
                    (0..n).rev().collect()
                }
            };
            let (xs, ys, zs) = (order(nx, dir[0] >= 0.0), order(ny, dir[1] >= 0.0), order(nz, dir[2] >= 0.0));
            let mut out: [Vec<f64>; 4] = std::array::from_fn(|_| vec![0.0; v]);
            for &z in &zs {
                for &y in &ys {
                    for &x in &xs {
                        let p = [x, y, z];
                        let i = self.index(p);
                        // Each axis's inflow: the upwind neighbour's outflow across it, the
                        // boundary's (0 at vacuum, the far side's last outflow where periodic),
                        // or, on a periodic axis one voxel wide, the voxel's own outflow (an
                        // unknown of this voxel's balance).
                        let mut inflow = [0.0; 3];
                        let mut own = [false; 3];
                        for axis in 0..3 {
                            if a[axis] == 0.0 {
                                continue;
                            }
                            let n = self.dims[axis];
                            if self.periodic_xy && axis < 2 && n == 1 {
                                own[axis] = true;
                                continue;
                            }
                            let back = if dir[axis] >= 0.0 {
                                p[axis].checked_sub(1)
                            } else {
                                Some(p[axis] + 1).filter(|u| *u < n)
                            };
                            inflow[axis] = match back {
                                Some(b) => {
                                    let mut u = p;
                                    u[axis] = b;
                                    out[1 + axis][self.index(u)]
                                }
                                None if self.periodic_xy && axis < 2 => {
                                    let mut u = p;
                                    u[axis] = if dir[axis] >= 0.0 { n - 1 } else { 0 };
                                    last[d][1 + axis][self.index(u)]
                                }
                                None => 0.0,
                            };
                        }
                        let (cell, faces) = match self.scheme {
                            Scheme::Step => {
                                // I = (Q + sum_a |w_a| I_in,a / h) / (sigma_t + sum_a |w_a| / h),
                                // an own inflow moved to the left-hand side.
                                let lean: f64 = (0..3).filter(|k| !own[*k]).map(|k| a[k]).sum::<f64>() / self.h;
                                let into: f64 = (0..3).map(|k| a[k] * inflow[k]).sum::<f64>() / self.h;
                                let r = (emission(d, i) + into) / (self.sigma_t[i] + lean);
                                (r, [r; 3])
                            }
                            Scheme::Characteristics => characteristic_update(
                                &geometry[d],
                                a,
                                self.h,
                                self.sigma_t[i],
                                emission(d, i),
                                inflow,
                                own,
                            ),
                        };
                        out[0][i] = cell;
                        for k in 0..3 {
                            out[1 + k][i] = faces[k];
                        }
                        fluence[i] += w * cell;
                        // What leaves through the box's vacuum faces, and the top and bottom.
                        for axis in 0..3 {
                            let last_layer = if dir[axis] >= 0.0 { self.dims[axis] - 1 } else { 0 };
                            if p[axis] == last_layer && !(self.periodic_xy && axis < 2) {
                                leaving += w * a[axis] * faces[axis] * self.h * self.h;
                            }
                        }
                        if dir[2] > 0.0 && z == nz - 1 {
                            top += w * dir[2] * faces[2] * self.h * self.h;
                        } else if dir[2] < 0.0 && z == 0 {
                            bottom += w * -dir[2] * faces[2] * self.h * self.h;
                        }
                    }
                }
            }
            last[d] = out;
        }
        (fluence, [top, bottom, leaving])
    }

    /// Each direction's characteristic geometry, computed once per solve (none for the step
    /// difference, which does not use it).
    fn geometries(&self, q: &Quadrature) -> Vec<Geometry> {
        match self.scheme {
            Scheme::Step => Vec::new(),
            Scheme::Characteristics => q.directions.iter().map(|d| characteristic_geometry(d.map(f64::abs))).collect(),
        }
    }

    fn fresh(&self, directions: usize) -> Vec<[Vec<f64>; 4]> {
        (0..directions).map(|_| std::array::from_fn(|_| vec![0.0; self.voxels()])).collect()
    }

    /// One sweep of every direction for the emission `emission` and no scattering: the
    /// fluence (what a GPU sweep must reproduce).
    pub fn sweep_once(&self, q: &Quadrature, emission: &[f64]) -> Vec<f64> {
        let mut last = self.fresh(q.len());
        self.sweep(q, &self.geometries(q), &|_, i| emission[i], &mut last).0
    }

    /// Source iteration from the first-scattering emission `first` (per unit volume and solid
    /// angle, isotropic) to a relative fluence change below `tol`, at most `max_iterations`
    /// sweeps of every direction.
    pub fn solve(&self, q: &Quadrature, first: &[f64], tol: f64, max_iterations: u32) -> OrdinatesSolution {
        // One storage direction: the scattered source is sigma_s phi / (4 pi).
        self.solve_angular(q, &Quadrature::isotropic(), 0.0, first, tol, max_iterations)
    }

    /// Source iteration with Henyey-Greenstein scattering of asymmetry `g`, the emission stored
    /// at the directions of `storage` (M) and swept along those of `q` (N), coupled by
    /// `physics::angular`'s maps: `first` is the first-scattering emission at the storage
    /// directions ([m * V + v], per unit volume and solid angle). The device's `dom` computes
    /// the same; with `storage` isotropic and g = 0 this is [`OrdinatesGrid::solve`].
    pub fn solve_angular(
        &self,
        q: &Quadrature,
        storage: &Quadrature,
        g: f64,
        first: &[f64],
        tol: f64,
        max_iterations: u32,
    ) -> OrdinatesSolution {
        let v = self.voxels();
        let (nn, mm) = (q.len(), storage.len());
        let map = super::angular::StorageMap::new(q, storage);
        let a = map.scatter_matrix(q, g);
        let up = map.upsample;
        let geometry = self.geometries(q);
        let mut last = self.fresh(nn);
        let mut stored = first.to_vec();
        let mut previous = vec![0.0; v];
        let mut out = OrdinatesSolution {
            fluence: previous.clone(),
            leaving_top: 0.0,
            leaving_bottom: 0.0,
            leaving: 0.0,
            iterations: 0,
            converged: false,
        };
        while out.iterations < max_iterations {
            let emission = |n: usize, i: usize| (0..mm).map(|m| up[n * mm + m] * stored[m * v + i]).sum::<f64>();
            let (fluence, [top, bottom, leaving]) = self.sweep(q, &geometry, &emission, &mut last);
            out.iterations += 1;
            let scale = fluence.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            let change = fluence.iter().zip(&previous).fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
            for i in 0..v {
                let sigma_s = self.albedo[i] * self.sigma_t[i];
                for m in 0..mm {
                    let scattered: f64 = (0..nn).map(|n| a[n * mm + m] * last[n][0][i]).sum();
                    stored[m * v + i] = first[m * v + i] + sigma_s * scattered;
                }
            }
            previous = fluence.clone();
            out.fluence = fluence;
            out.leaving_top = top;
            out.leaving_bottom = bottom;
            out.leaving = leaving;
            if change <= tol * scale {
                out.converged = true;
                break;
            }
        }
        out
    }
}
