//! First-flight escape of light scattered in a D3Q6 voxel through several open faces at once: the
//! quadrature behind glsl/lattice/diffuse.comp's `ESC_Q2` / `ESC_Q3` tables (`escape_union`).
//!
//! A voxel at the medium box's surface sends its isotropically scattered light toward vacuum
//! with the first-flight escape probability of its source instead of the lattice's 1/6 a link.
//! Through one face that is the slab integral (1/2 - E_3(tau)) / (2 tau) (tau the voxel's edge in
//! reduced mean free paths), and through opposite faces the sum, the two events being
//! disjoint. Through adjacent faces (an edge or a corner of the box) they are not: a photon
//! heading out through +x and +y leaves through whichever it meets first, and the sum
//! overcounts it (at tau 0.29 an edge voxel lost 0.67 of its scattered light for the 0.54 that
//! escapes, a corner 1.0 for 0.67).
//!
//! Split the directions into octants. In one whose signs meet `k` open faces (the faces on
//! the octant's side of k of the axes), a photon born uniformly in the voxel at distances s_a
//! from those faces, travelling along w, escapes uncollided with probability exp(-min_a s_a /
//! w_a): the octant's mean of that is q_k(tau), and the voxel's escape is the sum over its eight
//! octants of q_k / 8. With M = min_a s_a / w_a, P(M > t) = prod_a (1 - t w_a / tau) for t up to
//! tau / max_a w_a, so E[exp(-M)] = 1 - int_0^(tau / max w_a) e^-t prod_a (1 - t w_a / tau) dt;
//! that inner integral by Gauss-Legendre on t, the mean over the octant by Gauss-Legendre on
//! (cos theta, phi). q_1 is 2 (1/2 - E_3(tau)) / (2 tau): the slab formula (checked below).

use crate::physics::quadrature::gauss_legendre;

/// The optical edges (reduced mean free paths) of the table's nodes: 2^(j - 5), j = 0..=10.
pub fn table_tau(j: usize) -> f64 {
    2f64.powi(j as i32 - 5)
}

/// The escape of an octant's directions with `k` (1..=3) open faces, from a voxel of optical
/// edge `tau`: q_k(tau) of the module doc. `n` Gauss-Legendre nodes per direction coordinate.
pub fn octant_escape(tau: f64, k: usize, n: usize) -> f64 {
    assert!((1..=3).contains(&k) && tau > 0.0);
    let (x, w) = gauss_legendre(n);
    let (xt, wt) = gauss_legendre(64);
    let mut sum = 0.0;
    for (&xu, &wu) in x.iter().zip(&w) {
        // cos theta on (0, 1) and phi on (0, pi/2): the octant, area pi/2, with dw = du dphi.
        let u = (xu + 1.0) / 2.0;
        let s = (1.0 - u * u).sqrt();
        for (&xp, &wp) in x.iter().zip(&w) {
            let phi = (xp + 1.0) * std::f64::consts::FRAC_PI_4;
            let dir = [s * phi.cos(), s * phi.sin(), u];
            let wmax = dir[..k].iter().copied().fold(0.0, f64::max);
            // e^-t below e^-60 adds nothing at f64's precision.
            let t_end = (tau / wmax).min(60.0);
            let mut inner = 0.0;
            for (&x_t, &w_t) in xt.iter().zip(&wt) {
                let t = (x_t + 1.0) / 2.0 * t_end;
                let survive: f64 = dir[..k].iter().map(|&wa| (1.0 - t * wa / tau).max(0.0)).product();
                inner += w_t * t_end / 2.0 * (-t).exp() * survive;
            }
            // The weights: (1/2) du on (0, 1) and (pi/4) dphi, over the octant's area pi/2.
            sum += wu / 2.0 * wp * std::f64::consts::FRAC_PI_4 * (1.0 - inner);
        }
    }
    sum / std::f64::consts::FRAC_PI_2
}

#[cfg(test)]
mod tests {
    use super::*;

    /// E_3(x) = int_0^1 mu e^(-x / mu) dmu, by Gauss-Legendre on mu.
    fn e3(x: f64) -> f64 {
        let (n, w) = gauss_legendre(200);
        n.iter()
            .zip(&w)
            .map(|(&m, &wi)| {
                let mu = (m + 1.0) / 2.0;
                wi / 2.0 * mu * (-x / mu).exp()
            })
            .sum()
    }

    /// The table `name` (`ESC_Q2` or `ESC_Q3`) as glsl/lattice/diffuse.comp states it.
    fn shader_table(name: &str) -> Vec<f64> {
        let src = include_str!("../../../../glsl/lattice/diffuse.comp");
        let head = format!("const float {name}[11] = float[11](");
        let start = src.find(&head).unwrap_or_else(|| panic!("{name} not in diffuse.comp")) + head.len();
        let body = &src[start..start + src[start..].find(");").expect("the table ends")];
        body.split(',').map(|v| v.trim().parse().expect("a number")).collect()
    }

    #[test]
    fn one_open_face_is_the_slab_formula() {
        for tau in [0.03125, 0.25, 1.0, 4.0, 16.0] {
            let q1 = octant_escape(tau, 1, 200);
            let slab = (0.5 - e3(tau)) / tau;
            assert!((q1 / slab - 1.0).abs() < 2e-5, "tau {tau}: octant quadrature {q1}, slab formula {slab}");
        }
    }

    #[test]
    fn the_shader_tables_are_the_quadrature() {
        for (name, k) in [("ESC_Q2", 2), ("ESC_Q3", 3)] {
            let table = shader_table(name);
            assert_eq!(table.len(), 11, "{name}");
            for (j, &v) in table.iter().enumerate() {
                let tau = table_tau(j);
                let ratio = octant_escape(tau, k, 400) / octant_escape(tau, 1, 400);
                assert!((v - ratio).abs() < 2e-5, "{name}[{j}] (tau {tau}) is {v}, the quadrature gives {ratio:.5}");
            }
        }
    }

    #[test]
    fn adjacent_faces_overlap_in_thin_voxels_and_add_in_thick_ones() {
        // Thin: every direction of the octant leaves at once, whichever faces are open.
        for k in 1..=3 {
            assert!((octant_escape(1e-4, k, 200) - 1.0).abs() < 1e-3, "k {k}");
        }
        // Thick: escape happens within a mean free path of one face at a time.
        let t = 200.0;
        for k in 2..=3 {
            let r = octant_escape(t, k, 200) / octant_escape(t, 1, 200);
            assert!((r - k as f64).abs() < 0.02 * k as f64, "k {k}: ratio {r}");
        }
    }
}
