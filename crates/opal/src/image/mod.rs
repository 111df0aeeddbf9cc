//! Floating-point RGB images (films, textures, reference renders).

mod exr_chunks;
pub mod read;
pub mod write;

use crate::spectrum::Spectrum;

/// Linear RGB float image, row-major, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Pixels, `data[y * width + x]`.
    pub data: Vec<Spectrum>,
}

impl Image {
    /// Black image.
    pub fn new(width: usize, height: usize) -> Self {
        Image { width, height, data: vec![Spectrum::ZERO; width * height] }
    }
    /// Pixel (x, y).
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> Spectrum {
        self.data[y * self.width + x]
    }
    /// Set pixel (x, y).
    #[inline]
    pub fn set(&mut self, x: usize, y: usize, v: Spectrum) {
        self.data[y * self.width + x] = v;
    }
    /// Mean of every pixel, per channel (f64).
    pub fn mean(&self) -> [f64; 3] {
        let mut m = [0.0; 3];
        for p in &self.data {
            for c in 0..3 {
                m[c] += p[c] as f64;
            }
        }
        let n = self.data.len().max(1) as f64;
        m.map(|v| v / n)
    }
}
