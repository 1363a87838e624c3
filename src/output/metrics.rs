//! Error metrics of a render against a reference, and a false-colour error map.
//!
//! Definitions (docs/design.md, "Measuring the trade"), over all pixels and all three channels:
//!
//! | metric | definition |
//! | --- | --- |
//! | `rel_l2` | `\|\|a - r\|\| / \|\|r\|\|` (scale-free; the headline error) |
//! | `rel_mse` | `mean((a - r)^2 / (r^2 + 0.01))` (literature convention; needs radiance ~ 1) |
//! | `rmse` | `sqrt(mean((a - r)^2))` |
//! | `energy_ratio` | `sum(a) / sum(r)` |
//! | `max_abs_error` | `max \|a - r\|` |
//! | `nan_inf_count` | pixels of `a` with any NaN or infinite channel |
//!
//! Pixels counted in `nan_inf_count` are left out of every other metric (from `a` and from
//! the reference alike, so `energy_ratio` compares like with like). A reference with
//! non-finite pixels is an error: nothing could be measured against it.

use std::path::Path;

use serde::Serialize;

use super::png::{check_writable, write_rgb8, NON_FINITE_RGB8};
use super::{Image, OutputError};

/// Constant in the denominator of `rel_mse`: `(a - r)^2 / (r^2 + REL_MSE_EPSILON)`.
pub const REL_MSE_EPSILON: f64 = 0.01;

/// Errors of an image against a reference. Ratios with a zero denominator are `0` when the
/// numerator is also zero, else infinite (serialised as JSON `null`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct Metrics {
    /// `||a - r|| / ||r||` over all finite pixels and channels.
    pub rel_l2: f64,
    /// `mean((a - r)^2 / (r^2 + 0.01))`.
    pub rel_mse: f64,
    /// Root mean square error, in the image's units.
    pub rmse: f64,
    /// `sum(a) / sum(r)`: 1 when energy is conserved.
    pub energy_ratio: f64,
    /// Largest `|a - r|` over channels, in the image's units.
    pub max_abs_error: f64,
    /// Pixels of `a` with a NaN or infinite channel (excluded from the metrics above).
    pub nan_inf_count: u64,
    /// Pixels in the image, `width * height`.
    pub pixels: u64,
}

/// Compare `a` with `reference`, pixel by pixel. See the module docs for definitions.
pub fn compare(a: &Image, reference: &Image) -> Result<Metrics, OutputError> {
    check_same_size(a, reference, "comparison")?;
    let bad_reference = reference.nan_inf_count();
    if bad_reference > 0 {
        return Err(OutputError::NonFiniteReference { count: bad_reference });
    }

    let (mut sum_sq_diff, mut sum_sq_ref, mut sum_rel) = (0.0f64, 0.0f64, 0.0f64);
    let (mut sum_a, mut sum_r, mut max_abs) = (0.0f64, 0.0f64, 0.0f64);
    let (mut values, mut nan_inf_count) = (0u64, 0u64);
    for (pa, pr) in a.pixels().zip(reference.pixels()) {
        if pa.iter().any(|v| !v.is_finite()) {
            nan_inf_count += 1;
            continue;
        }
        for c in 0..3 {
            let (x, r) = (f64::from(pa[c]), f64::from(pr[c]));
            let d = x - r;
            sum_sq_diff += d * d;
            sum_sq_ref += r * r;
            sum_rel += d * d / (r * r + REL_MSE_EPSILON);
            sum_a += x;
            sum_r += r;
            max_abs = max_abs.max(d.abs());
            values += 1;
        }
    }
    let n = values as f64;
    Ok(Metrics {
        rel_l2: ratio(sum_sq_diff, sum_sq_ref).sqrt(),
        rel_mse: sum_rel / n,
        rmse: (sum_sq_diff / n).sqrt(),
        energy_ratio: ratio(sum_a, sum_r),
        max_abs_error: max_abs,
        nan_inf_count,
        pixels: a.pixel_count() as u64,
    })
}

/// What the images' own noise does to a comparison, from their per-pixel variance layers
/// (the variance of each pixel's mean, as `path` writes it). For independent images,
/// E[sum (a - r)^2] = sum bias^2 + sum var_a + sum var_r, so the bias alone is estimated by
/// subtracting both variances; the estimate itself fluctuates, with standard deviation
/// sqrt(2 sum (var_a + var_r)^2) where there is no bias (Gaussian pixel means).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct NoiseFloor {
    /// sqrt(sum var_r) / ||r||: the relL2 the reference's noise alone adds to any comparison
    /// (its expected distance from the noise-free image). `None` without a variance layer.
    pub reference: Option<f64>,
    /// sqrt(sum var_a) / ||r||: the same for the judged image; `None` without a layer (a
    /// deterministic solver's image has no noise).
    pub image: Option<f64>,
    /// sqrt(max(0, sum (a - r)^2 - sum var_a - sum var_r)) / ||r||: the relL2 with both
    /// images' noise removed. `None` when the reference's noise is unknown.
    pub rel_l2_corrected: Option<f64>,
    /// The smallest corrected relL2 that two standard deviations of the noise let one tell
    /// from zero: sqrt(2 sqrt(2 sum (var_a + var_r)^2)) / ||r||. A corrected error below it is
    /// consistent with none.
    pub resolution: Option<f64>,
}

/// [`NoiseFloor`] of `a` against `reference`, over the pixels [`compare`] uses (those where
/// `a` is finite). Variance layers must match the images' size.
pub fn noise_floor(
    a: &Image,
    reference: &Image,
    var_a: Option<&Image>,
    var_r: Option<&Image>,
) -> Result<NoiseFloor, OutputError> {
    check_same_size(a, reference, "comparison")?;
    for v in [var_a, var_r].into_iter().flatten() {
        check_same_size(v, reference, "variance layer")?;
    }
    let (mut sum_sq_diff, mut sum_sq_ref, mut sum_va, mut sum_vr, mut sum_v2) = (0f64, 0f64, 0f64, 0f64, 0f64);
    for i in 0..a.pixel_count() {
        let pa = &a.data[3 * i..3 * i + 3];
        if pa.iter().any(|v| !v.is_finite()) {
            continue;
        }
        for c in 0..3 {
            let k = 3 * i + c;
            let (x, r) = (f64::from(a.data[k]), f64::from(reference.data[k]));
            let va = var_a.map_or(0.0, |v| f64::from(v.data[k]).max(0.0));
            let vr = var_r.map_or(0.0, |v| f64::from(v.data[k]).max(0.0));
            sum_sq_diff += (x - r) * (x - r);
            sum_sq_ref += r * r;
            sum_va += va;
            sum_vr += vr;
            sum_v2 += (va + vr) * (va + vr);
        }
    }
    let rel = |x: f64| ratio(x, sum_sq_ref).sqrt();
    let known = var_r.is_some();
    Ok(NoiseFloor {
        reference: var_r.map(|_| rel(sum_vr)),
        image: var_a.map(|_| rel(sum_va)),
        rel_l2_corrected: known.then(|| rel((sum_sq_diff - sum_va - sum_vr).max(0.0))),
        resolution: known.then(|| rel(2.0 * (2.0 * sum_v2).sqrt())),
    })
}

/// sqrt(sum of `variance`) / ||`image`||: the relL2 an image's own noise stands for (the
/// expected distance of a Monte Carlo image from its noise-free mean).
pub fn relative_noise(image: &Image, variance: &Image) -> f64 {
    let norm2: f64 = image.data.iter().map(|v| f64::from(*v).powi(2)).sum();
    let var: f64 = variance.data.iter().map(|x| f64::from(*x).max(0.0)).sum();
    ratio(var, norm2).sqrt()
}

/// `num / den`, with `0 / 0 = 0` (identical all-black images agree perfectly).
fn ratio(num: f64, den: f64) -> f64 {
    if den == 0.0 && num == 0.0 {
        0.0
    } else {
        num / den
    }
}

fn check_same_size(a: &Image, reference: &Image, what: &str) -> Result<(), OutputError> {
    if (a.width, a.height) != (reference.width, reference.height) {
        return Err(OutputError::SizeMismatch {
            what: what.to_owned(),
            size: (a.width, a.height),
            reference_size: (reference.width, reference.height),
        });
    }
    Ok(())
}

/// Floor added to the reference in the relative error of [`error_png`].
pub const ERROR_MAP_EPSILON: f32 = 1e-3;
/// Relative error shown at the dark end of the [`error_png`] colour ramp.
pub const ERROR_MAP_MIN: f32 = 1e-4;
/// Relative error shown at the bright end of the [`error_png`] colour ramp.
pub const ERROR_MAP_MAX: f32 = 1.0;

/// How [`error_png`] maps error to colour, for captions and the CLI.
pub const ERROR_MAP_DESCRIPTION: &str = "per-pixel relative error e = mean_c|a - r| / (mean_c|r| + 1e-3), \
     log10 scale from 1e-4 (dark purple) to 1 (yellow), viridis ramp, clamped at both ends; \
     NaN/Inf pixels magenta; the bar below the image is the scale, 1e-4 at its left end to 1 at its right, \
     a black tick at each decade (1e-4, 1e-3, 1e-2, 1e-1, 1)";

/// Rows of white gap and of colour bar [`error_png`] adds below an image `height` rows tall.
pub fn error_map_legend_rows(height: u32) -> (u32, u32) {
    (2, (height / 10).max(6))
}

/// Viridis (matplotlib) sampled at nine evenly spaced points, 8-bit sRGB.
const VIRIDIS: [[f32; 3]; 9] = [
    [68.0, 1.0, 84.0],
    [71.0, 44.0, 122.0],
    [59.0, 81.0, 139.0],
    [44.0, 113.0, 142.0],
    [33.0, 144.0, 141.0],
    [39.0, 173.0, 129.0],
    [92.0, 200.0, 99.0],
    [170.0, 220.0, 50.0],
    [253.0, 231.0, 37.0],
];

/// Viridis colour at `t` in [0, 1] (piecewise linear between the nine stops).
pub fn viridis(t: f32) -> [u8; 3] {
    let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 };
    let s = t * (VIRIDIS.len() - 1) as f32;
    let i = (s.floor() as usize).min(VIRIDIS.len() - 2);
    let f = s - i as f32;
    let (lo, hi) = (VIRIDIS[i], VIRIDIS[i + 1]);
    [0, 1, 2].map(|c| (lo[c] + f * (hi[c] - lo[c])).round() as u8)
}

/// Write a false-colour PNG of the per-pixel relative error of `a` against `reference`.
///
/// `e = mean_c |a_c - r_c| / (mean_c |r_c| + 1e-3)`, shown on a log10 scale: `1e-4` and
/// below dark purple, `1` (100 %) and above yellow, viridis in between (one decade per
/// quarter of the ramp). Pixels where `a` or the reference is NaN/Inf are magenta.
/// See [`ERROR_MAP_DESCRIPTION`].
pub fn error_png(path: &Path, a: &Image, reference: &Image) -> Result<(), OutputError> {
    check_same_size(a, reference, &format!("error map '{}'", path.display()))?;
    check_writable(path, a)?;
    check_writable(path, reference)?;
    let (lo, hi) = (ERROR_MAP_MIN.log10(), ERROR_MAP_MAX.log10());
    let mut rgb8 = Vec::with_capacity(3 * a.pixel_count());
    for (pa, pr) in a.pixels().zip(reference.pixels()) {
        if pa.iter().chain(pr.iter()).any(|v| !v.is_finite()) {
            rgb8.extend_from_slice(&NON_FINITE_RGB8);
            continue;
        }
        let diff: f32 = (0..3).map(|c| (pa[c] - pr[c]).abs()).sum::<f32>() / 3.0;
        let scale: f32 = pr.iter().map(|v| v.abs()).sum::<f32>() / 3.0;
        let e = diff / (scale + ERROR_MAP_EPSILON);
        let t = if e > 0.0 { (e.log10() - lo) / (hi - lo) } else { 0.0 };
        rgb8.extend_from_slice(&viridis(t));
    }
    // The legend: a gap, then the ramp across the full width with a tick per decade.
    let (gap, bar) = error_map_legend_rows(a.height);
    let w = a.width as usize;
    rgb8.extend(std::iter::repeat(255u8).take(3 * w * gap as usize));
    let decades = (hi - lo).round() as usize;
    let tick = |x: usize| (0..=decades).any(|k| (k * (w - 1) + decades / 2) / decades.max(1) == x);
    for row in 0..bar {
        for x in 0..w {
            let t = if w > 1 { x as f32 / (w - 1) as f32 } else { 0.0 };
            // Ticks on the lower half of the bar, so the colour at each decade shows above.
            if row >= bar / 2 && tick(x) {
                rgb8.extend_from_slice(&[0, 0, 0]);
            } else {
                rgb8.extend_from_slice(&viridis(t));
            }
        }
    }
    write_rgb8(path, a.width, a.height + gap + bar, &rgb8)
}
