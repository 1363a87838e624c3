//! Linear HDR RGB image in memory.

/// Linear HDR RGB image: `data` holds `width * height` pixels of three `f32` each,
/// interleaved R, G, B, row-major, row 0 = top of the image. Radiance in W/(m^2 sr) when it
/// comes from a solver.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Pixels per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// `3 * width * height` values, RGB interleaved, row-major, top row first.
    pub data: Vec<f32>,
}

impl Image {
    /// Black image of the given size.
    pub fn new(width: u32, height: u32) -> Self {
        Self { width, height, data: vec![0.0; 3 * width as usize * height as usize] }
    }

    /// Image whose pixel `(x, y)` is `f(x, y)`.
    pub fn from_fn(width: u32, height: u32, mut f: impl FnMut(u32, u32) -> [f32; 3]) -> Self {
        let mut data = Vec::with_capacity(3 * width as usize * height as usize);
        for y in 0..height {
            for x in 0..width {
                data.extend_from_slice(&f(x, y));
            }
        }
        Self { width, height, data }
    }

    /// Number of pixels, `width * height`.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Whether `data` holds exactly `3 * width * height` values.
    pub fn is_consistent(&self) -> bool {
        self.data.len() == 3 * self.pixel_count()
    }

    fn index(&self, x: u32, y: u32) -> usize {
        assert!(x < self.width && y < self.height, "pixel ({x}, {y}) outside {}x{} image", self.width, self.height);
        3 * (y as usize * self.width as usize + x as usize)
    }

    /// RGB of pixel `(x, y)`, `y = 0` at the top.
    pub fn get(&self, x: u32, y: u32) -> [f32; 3] {
        let i = self.index(x, y);
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }

    /// Set pixel `(x, y)`.
    pub fn set(&mut self, x: u32, y: u32, rgb: [f32; 3]) {
        let i = self.index(x, y);
        self.data[i..i + 3].copy_from_slice(&rgb);
    }

    /// Pixels in row-major order, top row first.
    pub fn pixels(&self) -> impl ExactSizeIterator<Item = [f32; 3]> + '_ {
        self.data.chunks_exact(3).map(|p| [p[0], p[1], p[2]])
    }

    /// Number of pixels with at least one NaN or infinite channel.
    pub fn nan_inf_count(&self) -> u64 {
        self.pixels().filter(|p| p.iter().any(|v| !v.is_finite())).count() as u64
    }

    /// Mean of each channel over all pixels, accumulated in f64. A NaN or infinite pixel
    /// makes the mean non-finite, on purpose: it must not hide.
    pub fn mean(&self) -> [f64; 3] {
        let mut sum = [0.0f64; 3];
        for p in self.pixels() {
            for c in 0..3 {
                sum[c] += f64::from(p[c]);
            }
        }
        let n = self.pixel_count().max(1) as f64;
        sum.map(|s| s / n)
    }
}
