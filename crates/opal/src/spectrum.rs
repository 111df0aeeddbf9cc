//! `Spectrum`: an RGB triple (linear, the renderer's working space). Every colour in Opal goes
//! through this type so that a spectral or monochrome build touches one module.

use serde::{Deserialize, Serialize};
use std::ops::{Add, AddAssign, Div, DivAssign, Index, IndexMut, Mul, MulAssign, Sub};

/// Linear RGB value (radiance, reflectance, throughput...). Channels are transported independently.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Spectrum(pub [f32; 3]);

impl Spectrum {
    /// All channels zero.
    pub const ZERO: Spectrum = Spectrum([0.0; 3]);
    /// All channels one.
    pub const ONE: Spectrum = Spectrum([1.0; 3]);
    /// From three channels.
    pub const fn rgb(r: f32, g: f32, b: f32) -> Self {
        Spectrum([r, g, b])
    }
    /// All channels equal to `v`.
    pub const fn splat(v: f32) -> Self {
        Spectrum([v, v, v])
    }
    /// True when every channel is exactly zero.
    pub fn is_black(&self) -> bool {
        self.0 == [0.0; 3]
    }
    /// Largest channel.
    pub fn max_component(&self) -> f32 {
        self.0[0].max(self.0[1]).max(self.0[2])
    }
    /// Mean of the channels.
    pub fn average(&self) -> f32 {
        (self.0[0] + self.0[1] + self.0[2]) / 3.0
    }
    /// Rec. 709 / sRGB luminance Y.
    pub fn luminance(&self) -> f32 {
        0.2126 * self.0[0] + 0.7152 * self.0[1] + 0.0722 * self.0[2]
    }
    /// True when every channel is finite.
    pub fn is_finite(&self) -> bool {
        self.0.iter().all(|c| c.is_finite())
    }
    /// Channel-wise map.
    pub fn map(self, f: impl Fn(f32) -> f32) -> Self {
        Spectrum([f(self.0[0]), f(self.0[1]), f(self.0[2])])
    }
    /// Channel-wise clamp to [lo, hi].
    pub fn clamp(self, lo: f32, hi: f32) -> Self {
        self.map(|c| c.clamp(lo, hi))
    }
    /// As f64 channels (for accumulators).
    pub fn to_f64(self) -> [f64; 3] {
        [self.0[0] as f64, self.0[1] as f64, self.0[2] as f64]
    }
}

impl Index<usize> for Spectrum {
    type Output = f32;
    fn index(&self, i: usize) -> &f32 {
        &self.0[i]
    }
}
impl IndexMut<usize> for Spectrum {
    fn index_mut(&mut self, i: usize) -> &mut f32 {
        &mut self.0[i]
    }
}
impl Add for Spectrum {
    type Output = Spectrum;
    fn add(self, o: Spectrum) -> Spectrum {
        Spectrum([self.0[0] + o.0[0], self.0[1] + o.0[1], self.0[2] + o.0[2]])
    }
}
impl AddAssign for Spectrum {
    fn add_assign(&mut self, o: Spectrum) {
        *self = *self + o;
    }
}
impl Sub for Spectrum {
    type Output = Spectrum;
    fn sub(self, o: Spectrum) -> Spectrum {
        Spectrum([self.0[0] - o.0[0], self.0[1] - o.0[1], self.0[2] - o.0[2]])
    }
}
impl Mul for Spectrum {
    type Output = Spectrum;
    fn mul(self, o: Spectrum) -> Spectrum {
        Spectrum([self.0[0] * o.0[0], self.0[1] * o.0[1], self.0[2] * o.0[2]])
    }
}
impl MulAssign for Spectrum {
    fn mul_assign(&mut self, o: Spectrum) {
        *self = *self * o;
    }
}
impl Mul<f32> for Spectrum {
    type Output = Spectrum;
    fn mul(self, s: f32) -> Spectrum {
        self.map(|c| c * s)
    }
}
impl Mul<Spectrum> for f32 {
    type Output = Spectrum;
    fn mul(self, s: Spectrum) -> Spectrum {
        s * self
    }
}
impl MulAssign<f32> for Spectrum {
    fn mul_assign(&mut self, s: f32) {
        *self = *self * s;
    }
}
impl Div<f32> for Spectrum {
    type Output = Spectrum;
    fn div(self, s: f32) -> Spectrum {
        let inv = 1.0 / s;
        self * inv
    }
}
impl DivAssign<f32> for Spectrum {
    fn div_assign(&mut self, s: f32) {
        *self = *self / s;
    }
}
impl Div for Spectrum {
    type Output = Spectrum;
    fn div(self, o: Spectrum) -> Spectrum {
        Spectrum([self.0[0] / o.0[0], self.0[1] / o.0[1], self.0[2] / o.0[2]])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    #[test]
    fn arithmetic() {
        let a = Spectrum::rgb(1.0, 2.0, 3.0);
        assert_eq!((a * 2.0).0, [2.0, 4.0, 6.0]);
        assert_eq!((a + a).0, [2.0, 4.0, 6.0]);
        assert_eq!(a.max_component(), 3.0);
        assert!((Spectrum::ONE.luminance() - 1.0).abs() < 1e-6);
    }
}
