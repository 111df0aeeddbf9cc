//! Random numbers and warping functions.
//!
//! * [`Rng`]: a counter-based generator. Every random number in Opal comes from
//!   `Rng::new(seed, stream, index)` — a hash of (seed, stream, index) seeds a PCG32 — so a
//!   result depends on the seed only, never on the thread count or the order of work.
//! * Warps from the unit square with their pdfs (cosine hemisphere, uniform sphere/hemisphere,
//!   cone, triangle) and a piecewise-constant 1D distribution ([`Distribution1D`]).
//!
//! Tests: χ² goodness-of-fit of every warp against its pdf (`tests` below, via
//! [`crate::validate::chi2`]); moments of the generator.

mod distribution;
mod warp;

pub use distribution::{Distribution1D, SmallChoice};
pub use warp::*;

use crate::math::Vec2;

/// SplitMix64 finaliser: a good 64-bit mix.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Hash of (seed, stream, index) → 64 bits.
#[inline]
pub fn hash3(seed: u64, stream: u64, index: u64) -> u64 {
    mix64(mix64(mix64(seed ^ 0x9e37_79b9_7f4a_7c15).wrapping_add(stream)).wrapping_add(index))
}

/// The (seed, stream) part of [`Rng::new`] hashed once: `RngStream::new(seed, stream).rng(i)`
/// is the same generator as `Rng::new(seed, stream, i)`, two hash rounds cheaper (hot loops that
/// seed one generator per work item).
#[derive(Clone, Copy, Debug)]
pub struct RngStream {
    base: u64,
}

impl RngStream {
    /// Stream `stream` under `seed`.
    pub fn new(seed: u64, stream: u64) -> Self {
        RngStream { base: mix64(mix64(seed ^ 0x9e37_79b9_7f4a_7c15).wrapping_add(stream)) }
    }
    /// The hash base: `rng(index)` is seeded from `mix64(base + index)` (for SIMD copies of
    /// the seeding).
    #[inline]
    pub(crate) fn base(&self) -> u64 {
        self.base
    }
    /// The generator of work item `index` (= `Rng::new(seed, stream, index)`).
    #[inline]
    pub fn rng(&self, index: u64) -> Rng {
        Rng::from_hash(mix64(self.base.wrapping_add(index)))
    }
}

/// PCG32 (O'Neill 2014, XSH-RR) seeded from a hash of (seed, stream, index).
#[derive(Clone, Debug)]
pub struct Rng {
    pub(crate) state: u64,
    pub(crate) inc: u64,
}

impl Rng {
    /// The PCG multiplier (also used by SIMD copies of the generator).
    pub(crate) const MULT: u64 = 6_364_136_223_846_793_005;
    /// The key of the increment's hash in the seeding (also used by SIMD copies).
    pub(crate) const INC_KEY: u64 = 0xda3e_39cb_94b9_5bdb;

    /// Generator for work item `index` of stream `stream` under `seed`.
    pub fn new(seed: u64, stream: u64, index: u64) -> Self {
        Self::from_hash(hash3(seed, stream, index))
    }

    #[inline]
    fn from_hash(h: u64) -> Self {
        let mut r = Rng { state: 0, inc: (mix64(h ^ Self::INC_KEY) << 1) | 1 };
        r.next_u32();
        r.state = r.state.wrapping_add(h);
        r.next_u32();
        r
    }
    /// Next 32 random bits.
    #[inline]
    pub fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old.wrapping_mul(Self::MULT).wrapping_add(self.inc);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        let rot = (old >> 59) as u32;
        xorshifted.rotate_right(rot)
    }
    /// Uniform f32 in [0, 1).
    #[inline]
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u32() >> 8) as f32 * (1.0 / 16_777_216.0)
    }
    /// Uniform f64 in [0, 1).
    #[inline]
    pub fn next_f64(&mut self) -> f64 {
        let hi = (self.next_u32() as u64) << 21;
        let lo = (self.next_u32() >> 11) as u64;
        (hi | lo) as f64 * (1.0 / 9_007_199_254_740_992.0)
    }
    /// Two uniform f32 in [0, 1).
    #[inline]
    pub fn next_2d(&mut self) -> Vec2 {
        Vec2::new(self.next_f32(), self.next_f32())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Vec3;
    use crate::validate::chi2::{Chi2Test, SphereFn};

    #[test]
    fn rng_moments_and_determinism() {
        let mut r = Rng::new(7, 1, 2);
        let n = 200_000;
        let (mut s, mut s2) = (0.0f64, 0.0f64);
        for _ in 0..n {
            let x = r.next_f64();
            assert!((0.0..1.0).contains(&x));
            s += x;
            s2 += x * x;
        }
        let mean = s / n as f64;
        let var = s2 / n as f64 - mean * mean;
        // mean of U(0,1): 1/2 with std 1/sqrt(12 n) ≈ 6.5e-4; 5σ bound
        assert!((mean - 0.5).abs() < 5.0 * (1.0 / (12.0 * n as f64)).sqrt());
        assert!((var - 1.0 / 12.0).abs() < 2e-3);
        let mut a = Rng::new(1, 2, 3);
        let mut b = Rng::new(1, 2, 3);
        assert_eq!(a.next_u32(), b.next_u32());
        assert_ne!(Rng::new(1, 2, 3).next_u32(), Rng::new(1, 2, 4).next_u32());
        for (seed, stream, index) in [(1u64, 2u64, 3u64), (0, 0, 0), (u64::MAX, 7, 1 << 40)] {
            let (mut a, mut b) = (Rng::new(seed, stream, index), RngStream::new(seed, stream).rng(index));
            for _ in 0..4 {
                assert_eq!(a.next_u32(), b.next_u32());
            }
        }
    }

    fn run(name: &str, sample: impl Fn(Vec2) -> Option<Vec3> + Sync, pdf: impl Fn(Vec3) -> f64 + Sync) {
        let t = Chi2Test::new(name, 1_000_000, 10);
        let r = t.run(&SphereFn { sample: &sample, pdf: &pdf });
        assert!(r.passed, "{name}: {r:?}");
    }

    #[test]
    fn chi2_cosine_hemisphere() {
        run(
            "cosine",
            |u| Some(square_to_cosine_hemisphere(u)),
            |w| square_to_cosine_hemisphere_pdf(w) as f64,
        );
    }
    #[test]
    fn chi2_uniform_sphere_and_hemisphere() {
        run("sphere", |u| Some(square_to_uniform_sphere(u)), |w| square_to_uniform_sphere_pdf(w) as f64);
        run(
            "hemisphere",
            |u| Some(square_to_uniform_hemisphere(u)),
            |w| square_to_uniform_hemisphere_pdf(w) as f64,
        );
    }
    #[test]
    fn chi2_cone() {
        let cos_max = 0.6f32;
        run(
            "cone",
            move |u| Some(square_to_uniform_cone(u, cos_max)),
            move |w| square_to_uniform_cone_pdf(w, cos_max) as f64,
        );
    }

    #[test]
    fn triangle_is_uniform() {
        // χ² over a 16-cell grid in barycentric space of the unit right triangle
        let n = 400_000;
        let mut counts = [0u64; 16];
        let mut rng = Rng::new(3, 0, 0);
        for _ in 0..n {
            let b = square_to_uniform_triangle(rng.next_2d());
            assert!(b.x >= 0.0 && b.y >= 0.0 && b.x + b.y <= 1.0 + 1e-6);
            // split triangle into 16 congruent sub-triangles: 4 levels
            let (i, j) = ((b.x * 4.0).min(3.999) as usize, (b.y * 4.0).min(3.999) as usize);
            let fx = b.x * 4.0 - i as f32;
            let fy = b.y * 4.0 - j as f32;
            let upper = fx + fy > 1.0;
            let cell = (i * 4 + j) * 2 + upper as usize;
            // cells with i + j <= 3 exist; map to a dense index
            counts[cell_index(cell).min(15)] += 1;
        }
        fn cell_index(c: usize) -> usize {
            // enumerate valid (i,j,upper) triangles: i+j<3 both halves, i+j==3 lower only
            let (ij, upper) = (c / 2, c % 2 == 1);
            let (i, j) = (ij / 4, ij % 4);
            let mut k = 0;
            for a in 0..4 {
                for b in 0..4 {
                    for up in [false, true] {
                        if a + b < 3 || (a + b == 3 && !up) {
                            if a == i && b == j && up == upper {
                                return k;
                            }
                            k += 1;
                        }
                    }
                }
            }
            usize::MAX
        }
        let expected = n as f64 / 16.0;
        let chi2: f64 = counts.iter().map(|&c| (c as f64 - expected).powi(2) / expected).sum();
        // 15 dof: the 0.999 quantile is 37.7
        assert!(chi2 < 37.7, "chi2 = {chi2}, counts {counts:?}");
    }
}
