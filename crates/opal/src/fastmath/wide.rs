//! Lane-parallel (SIMD) versions of the [`crate::fastmath`] functions, for loops that process
//! `N` independent samples at once (the goniophotometer's photon wavefront).
//!
//! [`F`] is `[f32; N]` with element-wise arithmetic, [`M`] a lane mask (all bits set = true)
//! and [`I`] `[i32; N]`. Every operation is a plain loop over the lanes marked
//! `#[inline(always)]`: LLVM's SLP vectoriser turns each into one or a few vector instructions
//! of whatever width the enclosing function is compiled for (SSE2 by default, AVX2 or AVX-512
//! inside a `#[target_feature]` function selected at run time). No fused multiply-add is ever
//! formed (Rust does not contract `a * b + c`), so the results do not depend on the instruction
//! set: every function here returns, lane by lane, **the same bits as its scalar counterpart**
//! in [`crate::fastmath`] on the domain stated in its documentation (branches become selects
//! with the same operations on each side), tested in `tests` below.

#![allow(clippy::needless_range_loop)]

use std::ops::{Add, BitAnd, BitOr, Div, Mul, Neg, Not, Sub};

/// `N` lanes of f32.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct F<const N: usize>(pub [f32; N]);

/// `N` lanes of i32.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct I<const N: usize>(pub [i32; N]);

/// Lane mask: `u32::MAX` = true, 0 = false.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct M<const N: usize>(pub [u32; N]);

macro_rules! lanes {
    ($n:ident, |$i:ident| $e:expr) => {{
        let mut o = [Default::default(); $n];
        for $i in 0..$n {
            o[$i] = $e;
        }
        o
    }};
}

impl<const N: usize> F<N> {
    /// Every lane `x`.
    #[inline(always)]
    pub fn splat(x: f32) -> Self {
        F([x; N])
    }
    /// Lanes `s[0..N]` (panics if `s` is shorter).
    #[inline(always)]
    pub fn load(s: &[f32]) -> Self {
        let s = &s[..N];
        F(lanes!(N, |i| s[i]))
    }
    /// Writes the lanes to `s[0..N]`.
    #[inline(always)]
    pub fn store(self, s: &mut [f32]) {
        s[..N].copy_from_slice(&self.0);
    }
    /// Square root.
    #[inline(always)]
    pub fn sqrt(self) -> Self {
        F(lanes!(N, |i| self.0[i].sqrt()))
    }
    /// |x|.
    #[inline(always)]
    pub fn abs(self) -> Self {
        F(lanes!(N, |i| f32::from_bits(self.0[i].to_bits() & 0x7fff_ffff)))
    }
    /// x with the sign bit of `s`.
    #[inline(always)]
    pub fn copysign(self, s: Self) -> Self {
        F(lanes!(N, |i| f32::from_bits(
            (self.0[i].to_bits() & 0x7fff_ffff) | (s.0[i].to_bits() & 0x8000_0000)
        )))
    }
    /// `if x > y { x } else { y }` (equals `f32::max` for non-NaN lanes).
    #[inline(always)]
    pub fn max(self, y: Self) -> Self {
        F(lanes!(N, |i| if self.0[i] > y.0[i] { self.0[i] } else { y.0[i] }))
    }
    /// `if x < y { x } else { y }` (equals `f32::min` for non-NaN lanes).
    #[inline(always)]
    pub fn min(self, y: Self) -> Self {
        F(lanes!(N, |i| if self.0[i] < y.0[i] { self.0[i] } else { y.0[i] }))
    }
    /// Lane-wise `f32::clamp` (NaN stays NaN).
    #[inline(always)]
    pub fn clamp(self, lo: Self, hi: Self) -> Self {
        F(lanes!(N, |i| {
            let x = self.0[i];
            let x = if x < lo.0[i] { lo.0[i] } else { x };
            if x > hi.0[i] { hi.0[i] } else { x }
        }))
    }
    /// `x < y`.
    #[inline(always)]
    pub fn lt(self, y: Self) -> M<N> {
        M(lanes!(N, |i| if self.0[i] < y.0[i] { u32::MAX } else { 0 }))
    }
    /// `x <= y`.
    #[inline(always)]
    pub fn le(self, y: Self) -> M<N> {
        M(lanes!(N, |i| if self.0[i] <= y.0[i] { u32::MAX } else { 0 }))
    }
    /// `x > y`.
    #[inline(always)]
    pub fn gt(self, y: Self) -> M<N> {
        y.lt(self)
    }
    /// `x >= y`.
    #[inline(always)]
    pub fn ge(self, y: Self) -> M<N> {
        y.le(self)
    }
    /// `x == y`.
    #[inline(always)]
    pub fn eq(self, y: Self) -> M<N> {
        M(lanes!(N, |i| if self.0[i] == y.0[i] { u32::MAX } else { 0 }))
    }
    /// `x.is_nan()`.
    #[inline(always)]
    pub fn is_nan(self) -> M<N> {
        self.eq(self).not()
    }
    /// `x as i32` (truncation, saturating; NaN → 0). Written with selects around an unchecked
    /// conversion so that it vectorises (`vcvttps2dq` plus two blends) where the saturating
    /// `as` would be converted lane by lane.
    #[inline(always)]
    pub fn to_i32(self) -> I<N> {
        I(lanes!(N, |i| {
            let x = self.0[i];
            // clamped into the range; `f32::clamp` would keep a NaN, `max` turns it into −2³¹
            // here (0 below), so the conversion is always defined
            #[allow(clippy::manual_clamp)]
            let c = x.max(-2_147_483_648.0).min(2_147_483_520.0);
            // SAFETY: `c` is finite and within [−2³¹, 2³¹ − 128], so its truncation is an i32.
            let t = unsafe { c.to_int_unchecked::<i32>() };
            let t = if x >= 2_147_483_648.0 { i32::MAX } else { t };
            if x.is_nan() { 0 } else { t }
        }))
    }
    /// Nearest integer, ties away from zero (`fastmath`'s `round_i32`).
    #[inline(always)]
    pub fn round_i32(self) -> I<N> {
        (self + F::splat(0.5).copysign(self)).to_i32()
    }
}

impl<const N: usize> I<N> {
    /// Every lane `x`.
    #[inline(always)]
    pub fn splat(x: i32) -> Self {
        I([x; N])
    }
    /// `x as f32`.
    #[inline(always)]
    pub fn to_f32(self) -> F<N> {
        F(lanes!(N, |i| self.0[i] as f32))
    }
    /// Wrapping `x + y`.
    #[inline(always)]
    pub fn wrapping_add(self, y: Self) -> Self {
        I(lanes!(N, |i| self.0[i].wrapping_add(y.0[i])))
    }
    /// `x & y`.
    #[inline(always)]
    pub fn and(self, y: Self) -> Self {
        I(lanes!(N, |i| self.0[i] & y.0[i]))
    }
    /// `x != 0`.
    #[inline(always)]
    pub fn nonzero(self) -> M<N> {
        M(lanes!(N, |i| if self.0[i] != 0 { u32::MAX } else { 0 }))
    }
    /// `x < y`.
    #[inline(always)]
    pub fn lt(self, y: Self) -> M<N> {
        M(lanes!(N, |i| if self.0[i] < y.0[i] { u32::MAX } else { 0 }))
    }
    /// The f32 with bits `(x << 23)` (2^(x − 127) for x in 1..=254).
    #[inline(always)]
    pub fn shl23_as_f32(self) -> F<N> {
        F(lanes!(N, |i| f32::from_bits((self.0[i] as u32) << 23)))
    }
    /// Lane-wise min.
    #[inline(always)]
    pub fn min(self, y: Self) -> Self {
        I(lanes!(N, |i| if self.0[i] < y.0[i] { self.0[i] } else { y.0[i] }))
    }
    /// Lane-wise max.
    #[inline(always)]
    pub fn max(self, y: Self) -> Self {
        I(lanes!(N, |i| if self.0[i] > y.0[i] { self.0[i] } else { y.0[i] }))
    }
}

impl<const N: usize> M<N> {
    /// `m ? a : b`, lane by lane (bitwise).
    #[inline(always)]
    pub fn select(self, a: F<N>, b: F<N>) -> F<N> {
        F(lanes!(N, |i| f32::from_bits((a.0[i].to_bits() & self.0[i]) | (b.0[i].to_bits() & !self.0[i]))))
    }
    /// `m ? a : b` for i32 lanes.
    #[inline(always)]
    pub fn select_i(self, a: I<N>, b: I<N>) -> I<N> {
        I(lanes!(N, |i| ((a.0[i] as u32 & self.0[i]) | (b.0[i] as u32 & !self.0[i])) as i32))
    }
    /// Flips the sign of the lanes of `x` where the mask is set (= `m ? −x : x`).
    #[inline(always)]
    pub fn neg_where(self, x: F<N>) -> F<N> {
        F(lanes!(N, |i| f32::from_bits(x.0[i].to_bits() ^ (self.0[i] & 0x8000_0000))))
    }
    /// Lane-wise equality of two masks.
    #[inline(always)]
    pub fn eq(self, o: Self) -> Self {
        M(lanes!(N, |i| !(self.0[i] ^ o.0[i])))
    }
    /// True in lane `i`.
    #[inline(always)]
    pub fn get(self, i: usize) -> bool {
        self.0[i] != 0
    }
    /// Any lane true.
    #[inline(always)]
    pub fn any(self) -> bool {
        self.0.iter().fold(0, |a, &m| a | m) != 0
    }
}

impl<const N: usize> Not for M<N> {
    type Output = Self;
    #[inline(always)]
    fn not(self) -> Self {
        M(lanes!(N, |i| !self.0[i]))
    }
}
impl<const N: usize> BitAnd for M<N> {
    type Output = Self;
    #[inline(always)]
    fn bitand(self, y: Self) -> Self {
        M(lanes!(N, |i| self.0[i] & y.0[i]))
    }
}
impl<const N: usize> BitOr for M<N> {
    type Output = Self;
    #[inline(always)]
    fn bitor(self, y: Self) -> Self {
        M(lanes!(N, |i| self.0[i] | y.0[i]))
    }
}

macro_rules! binop {
    ($tr:ident, $f:ident, $op:tt) => {
        impl<const N: usize> $tr for F<N> {
            type Output = Self;
            #[inline(always)]
            fn $f(self, y: Self) -> Self {
                F(lanes!(N, |i| self.0[i] $op y.0[i]))
            }
        }
        impl<const N: usize> $tr<f32> for F<N> {
            type Output = Self;
            #[inline(always)]
            fn $f(self, y: f32) -> Self {
                F(lanes!(N, |i| self.0[i] $op y))
            }
        }
        impl<const N: usize> $tr<F<N>> for f32 {
            type Output = F<N>;
            #[inline(always)]
            fn $f(self, y: F<N>) -> F<N> {
                F(lanes!(N, |i| self $op y.0[i]))
            }
        }
    };
}
binop!(Add, add, +);
binop!(Sub, sub, -);
binop!(Mul, mul, *);
binop!(Div, div, /);

impl<const N: usize> Neg for F<N> {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        F(lanes!(N, |i| -self.0[i]))
    }
}

/// [`crate::sampling::square_to_uniform_triangle`] (Heitz 2019), lane by lane (same bits: the
/// branch becomes a select of both sides): the barycentrics (b0, b1) of the second and third
/// corner. Used by the path tracer's wide vertex and the light tracer's path starts.
#[inline(always)]
pub fn square_to_uniform_triangle<const N: usize>(ux: F<N>, uy: F<N>) -> (F<N>, F<N>) {
    let lt = ux.lt(uy);
    let half_x = ux / 2.0;
    let half_y = uy / 2.0;
    (lt.select(half_x, ux - half_y), lt.select(uy - half_x, half_y))
}

/// [`crate::fastmath::sincos_2pi`], lane by lane (same bits).
#[inline(always)]
pub fn sincos_2pi<const N: usize>(u: F<N>) -> (F<N>, F<N>) {
    let t = 4.0 * u;
    let q = t.round_i32();
    let a = (t - q.to_f32()) * std::f32::consts::FRAC_PI_2;
    let a2 = a * a;
    let s =
        a * (1.0 + a2 * (-1.0 / 6.0 + a2 * (1.0 / 120.0 + a2 * (-1.0 / 5040.0 + a2 * (1.0 / 362_880.0)))));
    let c = 1.0
        + a2 * (-0.5
            + a2 * (1.0 / 24.0 + a2 * (-1.0 / 720.0 + a2 * (1.0 / 40_320.0 - a2 * (1.0 / 3_628_800.0)))));
    // q mod 4: 0 → (s, c), 1 → (c, −s), 2 → (−s, −c), 3 → (−c, s)
    let swap = q.and(I::splat(1)).nonzero();
    let sin_neg = q.and(I::splat(2)).nonzero();
    let cos_neg = I(lanes!(N, |i| (q.0[i] ^ (q.0[i] >> 1)) & 1)).nonzero();
    let sn = swap.select(c, s);
    let cs = swap.select(s, c);
    (sin_neg.neg_where(sn), cos_neg.neg_where(cs))
}

/// [`crate::fastmath::exp`] for x ≤ 88 (same bits; 0 below −87.3).
#[inline(always)]
pub fn exp<const N: usize>(x: F<N>) -> F<N> {
    let ni = (x * std::f32::consts::LOG2_E).round_i32();
    let n = ni.to_f32();
    let r = (x - n * 0.693_145_75) - n * 1.428_606_8e-6;
    let p = 1.0
        + r * (1.0
            + r * (0.5
                + r * (1.0 / 6.0
                    + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0 + r * (1.0 / 5040.0)))))));
    // x ≥ −87.3 ⇒ n ≥ −126; the clamp only keeps the discarded lanes' bits harmless
    let e = ni.max(I::splat(-126)).min(I::splat(127)).wrapping_add(I::splat(127)).shl23_as_f32();
    x.lt(F::splat(-87.3)).select(F::splat(0.0), p * e)
}

/// [`crate::fastmath::ln`] for positive normal finite x (same bits).
#[inline(always)]
pub fn ln<const N: usize>(x: F<N>) -> F<N> {
    let bits = I(lanes!(N, |i| x.0[i].to_bits() as i32));
    let e = I(lanes!(N, |i| ((bits.0[i] as u32 >> 23) & 0xff) as i32 - 127));
    let m = F(lanes!(N, |i| f32::from_bits((bits.0[i] as u32 & 0x007f_ffff) | 0x3f80_0000)));
    let big = m.gt(F::splat(std::f32::consts::SQRT_2));
    let m = big.select(m * 0.5, m);
    let e = e.wrapping_add(big.select_i(I::splat(1), I::splat(0)));
    let s = (m - 1.0) / (m + 1.0);
    let s2 = s * s;
    let lm = 2.0 * s * (1.0 + s2 * (1.0 / 3.0 + s2 * (1.0 / 5.0 + s2 * (1.0 / 7.0 + s2 * (1.0 / 9.0)))));
    e.to_f32() * std::f32::consts::LN_2 + lm
}

/// [`crate::fastmath::erfc_pos_with_exp`] (same bits).
#[inline(always)]
pub fn erfc_pos_with_exp<const N: usize>(x: F<N>, e: F<N>) -> F<N> {
    let t = 1.0 / (1.0 + 0.327_591_1 * x);
    (((((1.061_405_4 * t - 1.453_152) * t) + 1.421_413_7) * t - 0.284_496_74) * t + 0.254_829_6) * t * e
}

/// [`crate::fastmath::erfinv`] for |x| ≤ 1 − 6·10⁻⁸ (same bits): both of Giles' branches as
/// one polynomial with per-lane coefficients.
#[inline(always)]
pub fn erfinv<const N: usize>(x: F<N>) -> F<N> {
    const A: [f32; 9] = [
        2.810_226_4e-8,
        3.432_739_4e-7,
        -3.523_387_7e-6,
        -4.391_506_5e-6,
        2.185_808_7e-4,
        -1.253_725e-3,
        -4.177_681_6e-3,
        2.466_407_3e-1,
        1.501_409_4,
    ];
    const B: [f32; 9] = [
        -2.002_142_6e-4,
        1.009_505_6e-4,
        1.349_343_2e-3,
        -3.673_428_4e-3,
        5.739_507_7e-3,
        -7.622_461_3e-3,
        9.438_870_5e-3,
        1.001_674,
        2.832_976_8,
    ];
    let w = -ln((1.0 - x) * (1.0 + x));
    let central = w.lt(F::splat(5.0));
    let w = central.select(w - 2.5, w.sqrt() - 3.0);
    let mut p = central.select(F::splat(A[0]), F::splat(B[0]));
    for k in 1..9 {
        p = central.select(F::splat(A[k]), F::splat(B[k])) + p * w;
    }
    p * x
}

/// [`crate::fastmath::Fresnel::eval`], lane by lane (same bits): `(R, cos θt, η_rel)`.
#[inline(always)]
pub fn fresnel<const N: usize>(fr: &crate::fastmath::Fresnel, c: F<N>, inside: M<N>) -> (F<N>, F<N>, F<N>) {
    // the constants of `Fresnel::new`
    let k2 = inside.select(F::splat(fr.eta * fr.eta), F::splat(1.0 / (fr.eta * fr.eta)));
    let eta_rel = inside.select(F::splat(fr.eta), F::splat(fr.inv_eta));
    let sin2_t = (1.0 - c * c) * k2;
    let tir = sin2_t.ge(F::splat(1.0));
    let ct = (1.0 - sin2_t).max(F::splat(0.0)).sqrt();
    let a = eta_rel * c;
    let b = eta_rel * ct;
    let (p, q) = (a + ct, c + b);
    let inv = 1.0 / (p * q);
    let rs = (a - ct) * q * inv;
    let rp = (c - b) * p * inv;
    let r = 0.5 * (rs * rs + rp * rp);
    (tir.select(F::splat(1.0), r), tir.select(F::splat(0.0), ct), eta_rel)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fastmath as s;

    const N: usize = 8;

    /// Applies a wide function to `xs` in blocks of N and checks every lane against the scalar
    /// one bit for bit.
    fn same_bits(xs: &[f32], wide: impl Fn(F<N>) -> F<N>, scalar: impl Fn(f32) -> f32, what: &str) {
        for c in xs.chunks(N) {
            let mut b = [c[0]; N];
            b[..c.len()].copy_from_slice(c);
            let o = wide(F(b));
            for (i, &x) in c.iter().enumerate() {
                let e = scalar(x);
                assert!(
                    o.0[i].to_bits() == e.to_bits() || (o.0[i].is_nan() && e.is_nan()),
                    "{what}({x}): wide {} vs scalar {e}",
                    o.0[i]
                );
            }
        }
    }

    fn grid(lo: f32, hi: f32, n: usize) -> Vec<f32> {
        (0..=n).map(|i| lo + (hi - lo) * i as f32 / n as f32).collect()
    }

    #[test]
    fn wide_math_matches_scalar_bit_for_bit() {
        let u = grid(-0.5, 1.5, 100_003);
        same_bits(&u, |x| sincos_2pi(x).0, |x| s::sincos_2pi(x).0, "sin");
        same_bits(&u, |x| sincos_2pi(x).1, |x| s::sincos_2pi(x).1, "cos");
        let mut xs = grid(-100.0, 88.0, 200_001);
        xs.extend([0.0, -0.0, -87.3, -87.299_995, f32::NEG_INFINITY]);
        same_bits(&xs, exp, s::exp, "exp");
        let mut xs = Vec::new();
        let mut x = f32::MIN_POSITIVE;
        while x < 1e30 {
            xs.push(x);
            x *= 1.000_37;
        }
        same_bits(&xs, ln, s::ln, "ln");
        same_bits(
            &grid(0.0, 9.0, 20_000),
            |x| erfc_pos_with_exp(x, exp(-x * x)),
            |x| s::erfc_pos_with_exp(x, s::exp(-x * x)),
            "erfc",
        );
        let mut xs = grid(-0.999_999_9, 0.999_999_9, 200_001);
        xs.extend((1..=40).map(|k| 1.0 - k as f32 * 6e-8));
        xs.extend((1..=40).map(|k| -1.0 + k as f32 * 6e-8));
        same_bits(&xs, erfinv, s::erfinv, "erfinv");
    }

    #[test]
    fn to_i32_saturates_like_as() {
        let xs = [
            0.0f32,
            -0.0,
            0.4,
            -0.6,
            1.5,
            -1.5,
            2_147_483_520.0,
            2_147_483_648.0,
            -2_147_483_648.0,
            -2_147_483_904.0,
            3e9,
            -3e9,
            1e30,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            -f32::NAN,
        ];
        for x in xs {
            assert_eq!(F::<N>::splat(x).to_i32().0[0], x as i32, "{x}");
        }
    }

    #[test]
    fn wide_fresnel_matches_scalar_bit_for_bit() {
        for eta in [1.49f32, 1.0 / 1.49, 2.4] {
            let fr = s::Fresnel::new(eta);
            for inside in [false, true] {
                let m = M([if inside { u32::MAX } else { 0 }; N]);
                for c in grid(0.0, 1.0, 20_000).chunks(N) {
                    let mut b = [c[0]; N];
                    b[..c.len()].copy_from_slice(c);
                    let (r, ct, er) = fresnel(&fr, F(b), m);
                    for (i, &x) in c.iter().enumerate() {
                        let (r0, ct0, er0) = fr.eval(x, inside);
                        assert_eq!(
                            (r.0[i].to_bits(), ct.0[i].to_bits(), er.0[i].to_bits()),
                            (r0.to_bits(), ct0.to_bits(), er0.to_bits()),
                            "η {eta} c {x} inside {inside}"
                        );
                    }
                }
            }
        }
    }
}
