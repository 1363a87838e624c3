//! Real spherical harmonics: the basis `sh-single` (issue 17; thesis chapter 3 and appendix
//! A.1) compresses each sample's attenuation psi_i(w) = exp(-tau(b_i, w)) into (eq. 3.4).
//!
//! **Convention.** Order `L` holds the bands l = 0 .. L - 1, `L^2` coefficients, coefficient
//! (l, m) at index `l (l + 1) + m`. The functions are orthonormal over the sphere,
//! int Y_i Y_j dw = delta_ij, so a function's coefficients are c_i = int f Y_i dw and
//! f ~ sum_i c_i Y_i (the least-squares fit of order L). They are
//!
//!   Y_l0 = K_l0 P_l^0(z),   Y_lm = sqrt 2 K_lm P_l^m(z) cos(m phi),
//!   Y_l,-m = sqrt 2 K_lm P_l^m(z) sin(m phi),   K_lm = sqrt((2l + 1) / 4pi (l - m)! / (l + m)!),
//!
//! with the associated Legendre functions *without* the Condon-Shortley phase (the graphics
//! convention: Y_1,-1, Y_10, Y_11 = sqrt(3 / 4pi) (y, z, x)). No trigonometry: P_l^m(z) is
//! sin(theta)^m times a polynomial in z, and sin(theta)^m (cos m phi, sin m phi) are the real
//! and imaginary parts of (x + i y)^m, so the basis is a polynomial in the direction's
//! components, evaluated by the three-term recurrences
//!
//!   Q_mm = (2m - 1)!!,   Q_m+1,m = (2m + 1) z Q_mm,
//!   Q_lm = ((2l - 1) z Q_l-1,m - (l + m - 1) Q_l-2,m) / (l - m),
//!
//! for Q_lm = P_l^m / sin(theta)^m. glsl/include/sh.glsl restates this for the device.

use std::f64::consts::PI;

use super::quadrature::Quadrature;

/// Largest order (bands 0 .. 7, 64 coefficients): the ladder goes to L = 8 and the
/// device arrays are sized for it.
pub const MAX_ORDER: usize = 8;

/// Coefficients of order `order` (bands 0 .. order - 1).
pub fn coefficients(order: usize) -> usize {
    order * order
}

/// Index of coefficient (l, m), -l <= m <= l.
pub fn index(l: usize, m: i64) -> usize {
    (l as i64 * (l as i64 + 1) + m) as usize
}

/// K_lm of the module docs: sqrt((2l + 1) / 4pi (l - m)! / (l + m)!).
fn norm(l: usize, m: usize) -> f64 {
    // (l - m)! / (l + m)! = 1 / ((l - m + 1) ... (l + m)).
    let ratio: f64 = ((l - m + 1)..=(l + m)).map(|k| 1.0 / k as f64).product();
    ((2 * l + 1) as f64 / (4.0 * PI) * ratio).sqrt()
}

/// The basis functions of order `order` at the unit direction `d`.
pub fn basis(order: usize, d: [f64; 3]) -> Vec<f64> {
    assert!((1..=MAX_ORDER).contains(&order), "spherical harmonics of order 1..={MAX_ORDER}, not {order}");
    let [x, y, z] = d;
    let mut out = vec![0.0; coefficients(order)];
    // (c, s) = (x + i y)^m, Q_mm = (2m - 1)!!
    let (mut c, mut s, mut q_mm) = (1.0f64, 0.0f64, 1.0f64);
    for m in 0..order {
        if m > 0 {
            (c, s) = (c * x - s * y, c * y + s * x);
            q_mm *= (2 * m - 1) as f64;
        }
        let (mut q_prev2, mut q_prev) = (0.0, 0.0);
        for l in m..order {
            let q = if l == m {
                q_mm
            } else if l == m + 1 {
                (2 * m + 1) as f64 * z * q_mm
            } else {
                ((2 * l - 1) as f64 * z * q_prev - (l + m - 1) as f64 * q_prev2) / (l - m) as f64
            };
            let k = norm(l, m);
            if m == 0 {
                out[index(l, 0)] = k * q;
            } else {
                out[index(l, m as i64)] = std::f64::consts::SQRT_2 * k * q * c;
                out[index(l, -(m as i64))] = std::f64::consts::SQRT_2 * k * q * s;
            }
            (q_prev2, q_prev) = (q_prev, q);
        }
    }
    out
}

/// The function of coefficients `coeffs` (order sqrt(len)) at direction `d`.
pub fn eval(coeffs: &[f64], d: [f64; 3]) -> f64 {
    let order = (coeffs.len() as f64).sqrt().round() as usize;
    assert_eq!(order * order, coeffs.len(), "a square number of coefficients");
    basis(order, d).iter().zip(coeffs).map(|(y, c)| y * c).sum()
}

/// A quadrature that integrates the product of any two functions of order `order` exactly:
/// Gauss-Legendre in z (exact to degree 2 order - 1 >= 2 (order - 1)) times 2 order equally
/// spaced azimuths (exact below trigonometric degree 2 order > 2 (order - 1)).
pub fn exact_quadrature(order: usize) -> Quadrature {
    Quadrature::product(order as u32, 2 * order as u32)
}

/// The coefficients of `f` of order `order`, c_i = sum_q w_q f(w_q) Y_i(w_q) over quadrature
/// `q`: exact for a function of that order with [`exact_quadrature`]; for others (the
/// attenuation exp(-tau), which is not band-limited) a quadrature of many directions (the
/// thesis uses 128 to 256, 3.3.1).
pub fn project(order: usize, q: &Quadrature, f: impl Fn([f64; 3]) -> f64) -> Vec<f64> {
    let mut out = vec![0.0; coefficients(order)];
    for (d, w) in q.directions.iter().zip(&q.weights) {
        let v = f(*d) * w;
        for (o, y) in out.iter_mut().zip(basis(order, *d)) {
            *o += v * y;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn index_orders_bands_then_m() {
        assert_eq!((index(0, 0), index(1, -1), index(1, 1), index(2, -2), index(7, 7)), (0, 1, 3, 4, 63));
    }
}
