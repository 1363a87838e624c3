//! Angular quadratures on the unit sphere: the direction sets of a discrete-ordinates solver
//! (thesis 2.1 and 5.1.1: N propagation directions, weights summing to 4 pi, so that
//! sum_i w_i f(Omega_i) approximates the integral of f over the sphere).
//!
//! - **Level-symmetric** S_n (Lewis & Miller, *Computational Methods of Neutron Transport*,
//!   1984, table 4-1; the LQ_n sets): n (n + 2) directions, invariant under every 90-degree
//!   rotation about the axes and every reflection through the coordinate planes, so no axis is
//!   favoured. S_4 has the thesis's 24 directions, S_6 its 48, S_8 has 80. Positive weights up
//!   to S_8 (from S_12 on some are negative, which a transport sweep must not have).
//! - **Product** Gauss-Legendre x Chebyshev: `polar` Gauss-Legendre nodes in mu = cos(theta)
//!   times `azimuthal` equally spaced phi, any order, positive weights; exact for polynomials in
//!   mu up to degree 2 polar - 1 times trigonometric polynomials in phi below degree azimuthal.
//!   The higher orders beyond S_8.
//!
//! Directions and weights are `f64`: the tables are given to seven digits, and sums over them
//! (moments, normalised phase functions) must not lose more.

use std::f64::consts::PI;

/// A direction set with weights summing to 4 pi.
#[derive(Clone, Debug, PartialEq)]
pub struct Quadrature {
    /// What it is: `s4`, `s6`, `s8`, or `product-PxA`.
    pub name: String,
    /// Unit vectors.
    pub directions: Vec<[f64; 3]>,
    /// Solid angle of each direction, steradians; they sum to 4 pi.
    pub weights: Vec<f64>,
}

/// mu_1 and the octant weights of each point class of the LQ_n sets (Lewis & Miller table
/// 4-1), normalised to sum 1 over an octant.
const LQ: [(u32, f64, &[f64]); 4] = [
    (2, 0.577_350_3, &[1.0]),
    (4, 0.350_021_2, &[0.333_333_3]),
    (6, 0.266_635_5, &[0.176_126_3, 0.157_207_1]),
    (8, 0.218_217_9, &[0.120_987_7, 0.090_740_7, 0.092_592_6]),
];

impl Quadrature {
    /// The quadrature named `name`: `s2`, `s4`, `s6`, `s8` (level-symmetric) or `product-PxA`
    /// (P polar, A azimuthal nodes); or a one-line reason naming the choices.
    pub fn named(name: &str) -> Result<Quadrature, String> {
        let bad = || {
            format!(
                "unknown quadrature {name:?}: use s2, s4 (24 directions), s6 (48), s8 (80) or product-PxA (P polar x A \
                 azimuthal nodes, e.g. product-8x16)"
            )
        };
        if let Some(n) = name.strip_prefix('s').and_then(|n| n.parse::<u32>().ok()) {
            return Quadrature::level_symmetric(n).ok_or_else(bad);
        }
        let (p, a) = name.strip_prefix("product-").and_then(|pa| pa.split_once('x')).ok_or_else(bad)?;
        match (p.parse::<u32>(), a.parse::<u32>()) {
            (Ok(p), Ok(a)) if p >= 1 && a >= 1 && p * a <= 1 << 16 => Ok(Quadrature::product(p, a)),
            _ => Err(bad()),
        }
    }

    /// The level-symmetric set S_n, n in {2, 4, 6, 8}: n (n + 2) directions.
    ///
    /// In each octant the direction cosines take the values mu_i with mu_i^2 = mu_1^2 + (i - 1)
    /// 2 (1 - 3 mu_1^2) / (n - 2), and a direction is (mu_i, mu_j, mu_k) with i + j + k = n/2 + 2;
    /// its weight depends only on the multiset {i, j, k} (its point class).
    pub fn level_symmetric(n: u32) -> Option<Quadrature> {
        let &(_, mu1, class_weights) = LQ.iter().find(|(m, _, _)| *m == n)?;
        let half = (n / 2) as usize;
        let delta = if n > 2 { 2.0 * (1.0 - 3.0 * mu1 * mu1) / (n as f64 - 2.0) } else { 0.0 };
        let mu: Vec<f64> = (0..half).map(|i| (mu1 * mu1 + i as f64 * delta).sqrt()).collect();
        // Point classes in order of appearance when the triples are listed with i <= j <= k,
        // k descending from its largest value (the table's order).
        let mut classes: Vec<[usize; 3]> = Vec::new();
        let mut octant: Vec<([usize; 3], usize)> = Vec::new();
        for i in 1..=half {
            for j in 1..=half {
                // k = n/2 + 2 - i - j must lie in 1 ..= n/2.
                if i + j > half + 1 {
                    continue;
                }
                let k = half + 2 - i - j;
                let mut class = [i, j, k];
                class.sort_unstable();
                let c = match classes.iter().position(|c| *c == class) {
                    Some(c) => c,
                    None => {
                        classes.push(class);
                        classes.len() - 1
                    }
                };
                octant.push(([i, j, k], c));
            }
        }
        // Classes sorted as the table lists them: by their largest index, descending.
        let mut order: Vec<usize> = (0..classes.len()).collect();
        order.sort_by_key(|&c| std::cmp::Reverse((classes[c][2], classes[c][1])));
        let weight_of = |c: usize| class_weights[order.iter().position(|&o| o == c).expect("a class")];
        let mut q = Quadrature { name: format!("s{n}"), directions: Vec::new(), weights: Vec::new() };
        for signs in 0..8u32 {
            let s = |bit: u32| if signs & (1 << bit) != 0 { -1.0 } else { 1.0 };
            for &([i, j, k], c) in &octant {
                q.directions.push([s(0) * mu[i - 1], s(1) * mu[j - 1], s(2) * mu[k - 1]]);
                q.weights.push(weight_of(c) * PI / 2.0);
            }
        }
        q.normalise();
        Some(q)
    }

    /// The product set: `polar` Gauss-Legendre nodes in mu times `azimuthal` equally spaced phi
    /// (offset by half a step, so no direction lies in the x-z plane).
    pub fn product(polar: u32, azimuthal: u32) -> Quadrature {
        let (mus, ws) = gauss_legendre(polar as usize);
        let mut q =
            Quadrature { name: format!("product-{polar}x{azimuthal}"), directions: Vec::new(), weights: Vec::new() };
        let dphi = 2.0 * PI / azimuthal as f64;
        for (mu, w) in mus.iter().zip(&ws) {
            let s = (1.0 - mu * mu).max(0.0).sqrt();
            for a in 0..azimuthal {
                let phi = (a as f64 + 0.5) * dphi;
                q.directions.push([s * phi.cos(), s * phi.sin(), *mu]);
                q.weights.push(w * dphi);
            }
        }
        q
    }

    /// One direction of weight 4 pi: the storage set of an isotropic source (thesis 5.1,
    /// M = 1). Its direction is arbitrary; every map that uses it is isotropic.
    pub fn isotropic() -> Quadrature {
        Quadrature { name: "1".into(), directions: vec![[0.0, 0.0, 1.0]], weights: vec![4.0 * PI] }
    }

    /// The same set reordered by octant (bit a of the octant set when the direction is
    /// negative along axis a; a zero component counts as positive), with each octant's first
    /// index and count: the order the sweeps take directions in.
    pub fn by_octant(&self) -> (Quadrature, [u32; 8], [u32; 8]) {
        let mut q = Quadrature { name: self.name.clone(), directions: Vec::new(), weights: Vec::new() };
        let (mut first, mut count) = ([0u32; 8], [0u32; 8]);
        for o in 0..8 {
            first[o] = q.len() as u32;
            for (d, w) in self.directions.iter().zip(&self.weights) {
                if (0..3).all(|a| (d[a] < 0.0) == (o & (1 << a) != 0)) {
                    q.directions.push(*d);
                    q.weights.push(*w);
                }
            }
            count[o] = q.len() as u32 - first[o];
        }
        (q, first, count)
    }

    /// Number of directions.
    pub fn len(&self) -> usize {
        self.directions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.directions.is_empty()
    }

    /// The table's seven digits leave the weights summing to 4 pi within 1e-7: make it exact, so
    /// an isotropic source integrates to itself.
    fn normalise(&mut self) {
        let total: f64 = self.weights.iter().sum();
        let k = 4.0 * PI / total;
        self.weights.iter_mut().for_each(|w| *w *= k);
    }
}

/// Gauss-Legendre nodes and weights on [-1, 1], ascending: Newton's method on P_n from the
/// Chebyshev-like first guess cos(pi (i - 1/4) / (n + 1/2)) (Numerical Recipes `gauleg`).
/// A crate would bring nalgebra for this (gauss-quad 0.3 computes nodes by Golub-Welsch):
/// docs/decisions.md.
pub fn gauss_legendre(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut x = vec![0.0; n];
    let mut w = vec![0.0; n];
    for i in 0..n.div_ceil(2) {
        let mut z = (PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
        let mut dp = 1.0;
        for _ in 0..100 {
            // P_n(z) by the three-term recurrence, and its derivative.
            let (mut p0, mut p1) = (1.0, z);
            for k in 2..=n {
                let p2 = ((2 * k - 1) as f64 * z * p1 - (k - 1) as f64 * p0) / k as f64;
                p0 = p1;
                p1 = p2;
            }
            let pn = if n == 0 {
                1.0
            } else if n == 1 {
                z
            } else {
                p1
            };
            let pm = if n == 1 { 1.0 } else { p0 };
            dp = n as f64 * (z * pn - pm) / (z * z - 1.0);
            let dz = pn / dp;
            z -= dz;
            if dz.abs() < 1e-15 {
                break;
            }
        }
        x[i] = -z;
        x[n - 1 - i] = z;
        w[i] = 2.0 / ((1.0 - z * z) * dp * dp);
        w[n - 1 - i] = w[i];
    }
    (x, w)
}
