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

    /// One sweep per direction of `q` for the isotropic emission `emission` (per unit volume
    /// and solid angle, per voxel): the fluence, and the power leaving through the top (+z)
    /// and bottom (-z) faces. Periodic x/y faces take the inflow from the opposite side's
    /// outflow of `last` (the previous sweep's field for that direction), which a converged
    /// iteration makes exact.
    fn sweep(
        &self,
        q: &Quadrature,
        emission: &dyn Fn(usize, usize) -> f64,
        last: &mut [Vec<f64>],
    ) -> (Vec<f64>, [f64; 3]) {
        let [nx, ny, nz] = self.dims;
        let mut fluence = vec![0.0; self.voxels()];
        let (mut top, mut bottom, mut leaving) = (0.0, 0.0, 0.0);
        for (d, (dir, w)) in q.directions.iter().zip(&q.weights).enumerate() {
            let a = dir.map(f64::abs);
            let lean: f64 = a.iter().sum::<f64>() / self.h;
            let order = |n: usize, positive: bool| -> Vec<usize> {
                if positive {
                    (0..n).collect()
                } else {
                    (0..n).rev().collect()
                }
            };
            let (xs, ys, zs) = (order(nx, dir[0] >= 0.0), order(ny, dir[1] >= 0.0), order(nz, dir[2] >= 0.0));
            let mut field = vec![0.0; self.voxels()];
            for &z in &zs {
                for &y in &ys {
                    for &x in &xs {
                        let p = [x, y, z];
                        // The upwind neighbour across each axis, or the boundary. A periodic
                        // axis one voxel wide is its own upwind neighbour: that inflow is the
                        // unknown itself, moved to the left-hand side (else each sweep would
                        // pass it on lagged, and near-grazing directions converge a voxel
                        // thickness per iteration).
                        let mut inflow = 0.0;
                        let mut own = 0.0;
                        for axis in 0..3 {
                            if a[axis] == 0.0 {
                                continue;
                            }
                            let n = self.dims[axis];
                            if self.periodic_xy && axis < 2 && n == 1 {
                                own += a[axis] / self.h;
                                continue;
                            }
                            let back = if dir[axis] >= 0.0 {
                                p[axis].checked_sub(1)
                            } else {
                                Some(p[axis] + 1).filter(|v| *v < n)
                            };
                            let i_in = match back {
                                Some(b) => {
                                    let mut u = p;
                                    u[axis] = b;
                                    field[self.index(u)]
                                }
                                None if self.periodic_xy && axis < 2 => {
                                    let mut u = p;
                                    u[axis] = if dir[axis] >= 0.0 { n - 1 } else { 0 };
                                    last[d][self.index(u)]
                                }
                                None => 0.0,
                            };
                            inflow += a[axis] * i_in / self.h;
                        }
                        let i = self.index(p);
                        let radiance = (emission(d, i) + inflow) / (self.sigma_t[i] + lean - own);
                        field[i] = radiance;
                        fluence[i] += w * radiance;
                        // What leaves through the box's vacuum faces, and the top and bottom.
                        for axis in 0..3 {
                            let last_layer = if dir[axis] >= 0.0 { self.dims[axis] - 1 } else { 0 };
                            if p[axis] == last_layer && !(self.periodic_xy && axis < 2) {
                                leaving += w * a[axis] * radiance * self.h * self.h;
                            }
                        }
                        if dir[2] > 0.0 && z == nz - 1 {
                            top += w * dir[2] * radiance * self.h * self.h;
                        } else if dir[2] < 0.0 && z == 0 {
                            bottom += w * -dir[2] * radiance * self.h * self.h;
                        }
                    }
                }
            }
            last[d] = field;
        }
        (fluence, [top, bottom, leaving])
    }

    /// One sweep of every direction for the emission `emission` and no scattering: the
    /// fluence (what a GPU sweep must reproduce).
    pub fn sweep_once(&self, q: &Quadrature, emission: &[f64]) -> Vec<f64> {
        let mut last = vec![vec![0.0; self.voxels()]; q.len()];
        self.sweep(q, &|_, i| emission[i], &mut last).0
    }

    /// Source iteration from the first-scattering emission `first` (per unit volume and solid
    /// angle, isotropic) to a relative fluence change below `tol`, at most `max_iterations`
    /// sweeps of every direction.
    pub fn solve(&self, q: &Quadrature, first: &[f64], tol: f64, max_iterations: u32) -> OrdinatesSolution {
        let mut last = vec![vec![0.0; self.voxels()]; q.len()];
        let mut emission = first.to_vec();
        let mut previous = vec![0.0; self.voxels()];
        let mut out = OrdinatesSolution {
            fluence: previous.clone(),
            leaving_top: 0.0,
            leaving_bottom: 0.0,
            leaving: 0.0,
            iterations: 0,
            converged: false,
        };
        while out.iterations < max_iterations {
            let (fluence, [top, bottom, leaving]) = self.sweep(q, &|_, i| emission[i], &mut last);
            out.iterations += 1;
            let scale = fluence.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let change = fluence.iter().zip(&previous).fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
            for (i, e) in emission.iter_mut().enumerate() {
                *e = first[i] + self.albedo[i] * self.sigma_t[i] * fluence[i] / (4.0 * std::f64::consts::PI);
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
        let mut last = vec![vec![0.0; v]; nn];
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
            let (fluence, [top, bottom, leaving]) = self.sweep(q, &emission, &mut last);
            out.iterations += 1;
            let scale = fluence.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            let change = fluence.iter().zip(&previous).fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
            for i in 0..v {
                let sigma_s = self.albedo[i] * self.sigma_t[i];
                for m in 0..mm {
                    let scattered: f64 = (0..nn).map(|n| a[n * mm + m] * last[n][i]).sum();
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
