//! sh-single's Gaussian index: each sample's reach, the samples sorted in space and the
//! grid of cells listing the Gaussians a camera ray may meet (`sh-single.index`).

use super::*;

/// The truncation radius of a sample's Gaussian exp(-a r^2): the render pass skips it where
/// a h^2 > 14 (exp(-14) < 1e-6, the thesis's cut, 3.4.2), so it reaches sqrt(14 / a).
pub fn gaussian_reach(a: f32) -> f32 {
    (14.0 / a).sqrt()
}

/// Samples put in Morton order of their centres (10 bits per axis over `lo`..`hi`), so that a
/// render chunk of consecutive samples is a compact region whose box most camera rays miss
/// ([`GaussianIndex`]). The order is deterministic (a stable sort on the code).
pub fn sort_spatially(samples: &mut [Sample], lo: Vec3, hi: Vec3) {
    fn spread(v: u32) -> u64 {
        let mut x = v as u64 & 0x3ff;
        x = (x | (x << 16)) & 0x0300_00ff;
        x = (x | (x << 8)) & 0x0300_f00f;
        x = (x | (x << 4)) & 0x030c_30c3;
        (x | (x << 2)) & 0x0924_9249
    }
    let ext = (hi - lo).max(Vec3::splat(1e-30));
    samples.sort_by_cached_key(|s| {
        let q = ((s.position - lo) / ext * 1023.0).clamp(Vec3::ZERO, Vec3::splat(1023.0));
        spread(q.x as u32) | (spread(q.y as u32) << 1) | (spread(q.z as u32) << 2)
    });
}

/// A uniform grid over the samples' truncated Gaussians, so that the render pass visits only
/// the samples whose Gaussians a camera ray's segment passes through, instead of every sample
/// for every pixel (O(pixels x samples): 257 s at 64000 samples and 512^2 on lavapipe before).
/// Cell c lists, in increasing order, every sample whose ball of radius [`gaussian_reach`]
/// (padded by a thousandth of a cell against rounding) overlaps it: `items[starts[c] ..
/// starts[c + 1]]`. The render walks the cells along the segment (3D DDA) and counts a sample
/// in the one cell whose stretch of the segment holds the sample's closest point on it, so each
/// sample is integrated once, in closed form over the whole segment, as without the index.
#[derive(Clone, Debug)]
pub struct GaussianIndex {
    pub origin: Vec3,
    pub cell: f32,
    pub dims: [u32; 3],
    pub starts: Vec<u32>,
    pub items: Vec<u32>,
}

/// Cells per axis at most.
pub(super) const INDEX_MAX_DIM: u32 = 128;

impl GaussianIndex {
    /// The index of samples at `centres` with reaches `reach`, cells about one Gaussian across
    /// (the median diameter; at most [`INDEX_MAX_DIM`] per axis).
    pub fn build(centres: &[Vec3], reach: &[f32]) -> GaussianIndex {
        assert_eq!(centres.len(), reach.len());
        let (mut lo, mut hi) = chunk_box(centres, reach, 0, centres.len());
        if centres.is_empty() {
            lo = Vec3::ZERO;
            hi = Vec3::ONE;
        }
        let extent = (hi - lo).max(Vec3::splat(1e-6));
        let mut diam: Vec<f32> = reach.iter().map(|r| 2.0 * r).collect();
        let median = if diam.is_empty() {
            extent.max_element()
        } else {
            let mid = diam.len() / 2;
            *diam.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1
        };
        let cell = median.max(extent.max_element() / INDEX_MAX_DIM as f32).max(1e-6);
        let dims = [0, 1, 2].map(|a| ((extent[a] / cell).ceil() as u32).clamp(1, INDEX_MAX_DIM));
        let n_cells = dims.iter().map(|d| *d as usize).product::<usize>();
        let pad = 1e-3 * cell;
        // Every cell the (padded) ball of centre c and radius r overlaps, by linear index.
        let cells_of_ball = |c: Vec3, r: f32, visit: &mut dyn FnMut(usize)| {
            let [rx, ry, rz] = [0, 1, 2].map(|a| {
                let f = |v: f32| (((v - lo[a]) / cell).floor().max(0.0) as u32).min(dims[a] - 1);
                [f(c[a] - r - pad), f(c[a] + r + pad)]
            });
            for z in rz[0]..=rz[1] {
                for y in ry[0]..=ry[1] {
                    for x in rx[0]..=rx[1] {
                        visit((x + dims[0] * (y + dims[1] * z)) as usize);
                    }
                }
            }
        };
        // Counting sort: counts per cell, their prefix sums, then the items in sample order.
        let mut starts = vec![0u32; n_cells + 1];
        for (c, r) in centres.iter().zip(reach) {
            cells_of_ball(*c, *r, &mut |k| starts[k + 1] += 1);
        }
        for k in 0..n_cells {
            starts[k + 1] += starts[k];
        }
        let mut fill = starts.clone();
        let mut items = vec![0u32; starts[n_cells] as usize];
        for (i, (c, r)) in centres.iter().zip(reach).enumerate() {
            cells_of_ball(*c, *r, &mut |k| {
                items[fill[k] as usize] = i as u32;
                fill[k] += 1;
            });
        }
        if items.is_empty() {
            items.push(0); // a buffer cannot be empty; no cell's range reaches it
        }
        GaussianIndex { origin: lo, cell, dims, starts, items }
    }

    /// Device bytes of its two buffers.
    pub fn bytes(&self) -> u64 {
        4 * (self.starts.len() + self.items.len()) as u64
    }
}

/// The exponent a of a sample's Gaussian exp(-a r^2), whose full width at half maximum is
/// `width_scale` times the sample's Poisson radius (thesis 3.3.2): the FWHM is
/// 2 sqrt(ln 2 / a), so a = 4 ln 2 / FWHM^2.
pub(super) fn gaussian_a(s: &Sample, width_scale: f32) -> f32 {
    let fwhm = width_scale * s.radius;
    4.0 * std::f32::consts::LN_2 / (fwhm * fwhm)
}

/// The reach ([`gaussian_reach`]) of each sample's Gaussian.
pub fn sample_reach(samples: &[Sample], width_scale: f32) -> Vec<f32> {
    samples.iter().map(|s| gaussian_reach(gaussian_a(s, width_scale))).collect()
}

/// The box holding the balls of samples `first .. first + count` (a render chunk's: rays that
/// miss it skip the chunk).
pub fn chunk_box(centres: &[Vec3], reach: &[f32], first: usize, count: usize) -> (Vec3, Vec3) {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for (c, r) in centres[first..first + count].iter().zip(&reach[first..first + count]) {
        lo = lo.min(*c - Vec3::splat(*r));
        hi = hi.max(*c + Vec3::splat(*r));
    }
    (lo, hi)
}
