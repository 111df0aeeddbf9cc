//! Fast single-precision math for hot Monte-Carlo loops (the goniophotometer's photon loop):
//! polynomial `sincos(2πu)`, `exp`, `ln`, `erf`/`erfc`, `erfinv`, and an unpolarised dielectric
//! Fresnel term with precomputed constants.
//!
//! Every function is branch-light, allocation-free and written for f32 results; its accuracy
//! over its domain is stated in its documentation and checked against the f64 standard library
//! (or `statrs`) by the tests below (`fastmath::tests`). None of them is exact to the last ulp:
//! use them where a relative error of ~10⁻⁶ is far below the Monte-Carlo noise.
//!
//! References: Cody & Waite range reduction (exp, ln); M. Abramowitz and I. Stegun, *Handbook of
//! Mathematical Functions*, 7.1.26 (erf); M. Giles, "Approximating the erfinv function", GPU
//! Computing Gems Jade Edition, 2011 (erfinv).
//!
//! [`wide`]: the same functions on `N` lanes at once (SIMD), bit-identical to these.

pub mod wide;

/// Nearest integer (ties away from zero) for |x| < 2³¹, without a libm call (`f32::round` is
/// one on x86-64 without SSE4.1).
#[inline(always)]
fn round_i32(x: f32) -> i32 {
    (x + 0.5f32.copysign(x)) as i32
}

/// `(sin 2πu, cos 2πu)` for |u| ≲ 10⁴ (periodic), absolute error < 3·10⁻⁷.
///
/// Reduction to the nearest quarter turn and Taylor polynomials of degree 9 (sin) and 10 (cos)
/// on |a| ≤ π/4.
#[inline]
pub fn sincos_2pi(u: f32) -> (f32, f32) {
    let t = 4.0 * u;
    let q = round_i32(t);
    let a = (t - q as f32) * std::f32::consts::FRAC_PI_2;
    let a2 = a * a;
    let s =
        a * (1.0 + a2 * (-1.0 / 6.0 + a2 * (1.0 / 120.0 + a2 * (-1.0 / 5040.0 + a2 * (1.0 / 362_880.0)))));
    let c = 1.0
        + a2 * (-0.5
            + a2 * (1.0 / 24.0 + a2 * (-1.0 / 720.0 + a2 * (1.0 / 40_320.0 - a2 * (1.0 / 3_628_800.0)))));
    match q & 3 {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// `eˣ`, relative error < 4·10⁻⁷ for x ∈ [−87, 88]; 0 below −87.3, +∞ above 88.7.
#[inline]
pub fn exp(x: f32) -> f32 {
    if x < -87.3 {
        return 0.0;
    }
    if x > 88.7 {
        return f32::INFINITY;
    }
    // x = n ln2 + r, |r| ≤ ln2/2 (ln 2 split in two parts for an exact product n·ln2_hi)
    let ni = round_i32(x * std::f32::consts::LOG2_E);
    let n = ni as f32;
    let r = (x - n * 0.693_145_75) - n * 1.428_606_8e-6;
    // e^r, Taylor to degree 7 (|r| ≤ 0.347: truncation error < 3e-9)
    let p = 1.0
        + r * (1.0
            + r * (0.5
                + r * (1.0 / 6.0
                    + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0 + r * (1.0 / 5040.0)))))));
    // 2^n for n ∈ [−126, 127]; n = 128 (x close to 88.7) split into two factors
    if ni < -126 {
        return p * f32::from_bits(((ni + 126 + 127) as u32) << 23) * f32::from_bits(1 << 23);
    }
    if ni > 127 {
        return p * 2.0 * f32::from_bits(((ni - 1 + 127) as u32) << 23);
    }
    p * f32::from_bits(((ni + 127) as u32) << 23)
}

/// Natural logarithm for positive `x` (error < 3·10⁻⁷ relative to max(|ln x|, 1)); −∞ for 0, NaN for negative input.
#[inline]
pub fn ln(x: f32) -> f32 {
    if x <= 0.0 {
        return if x == 0.0 { f32::NEG_INFINITY } else { f32::NAN };
    }
    if !x.is_finite() {
        return x;
    }
    // subnormals: scale up by 2^24
    let (x, e0) = if x < f32::MIN_POSITIVE { (x * 16_777_216.0, -24) } else { (x, 0) };
    let bits = x.to_bits();
    let mut e = ((bits >> 23) & 0xff) as i32 - 127 + e0;
    let mut m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000); // [1, 2)
    if m > std::f32::consts::SQRT_2 {
        m *= 0.5;
        e += 1;
    }
    // ln m = 2 atanh(s), s = (m − 1)/(m + 1), |s| ≤ 0.1716
    let s = (m - 1.0) / (m + 1.0);
    let s2 = s * s;
    let lm = 2.0 * s * (1.0 + s2 * (1.0 / 3.0 + s2 * (1.0 / 5.0 + s2 * (1.0 / 7.0 + s2 * (1.0 / 9.0)))));
    e as f32 * std::f32::consts::LN_2 + lm
}

/// `erfc(x)` for x ≥ 0 given `e = exp(−x²)` (shared with a caller that needs it too):
/// Abramowitz & Stegun 7.1.26 (1.5·10⁻⁷) evaluated in f32: absolute error < 6·10⁻⁷ (no
/// relative accuracy in the far tail).
#[inline]
pub fn erfc_pos_with_exp(x: f32, e: f32) -> f32 {
    let t = 1.0 / (1.0 + 0.327_591_1 * x);
    (((((1.061_405_4 * t - 1.453_152) * t) + 1.421_413_7) * t - 0.284_496_74) * t + 0.254_829_6) * t * e
}

/// Error function, absolute error < 6·10⁻⁷ (A&S 7.1.26's 1.5·10⁻⁷ plus f32 round-off of its
/// polynomial, whose terms are ~1.4 and cancel).
#[inline]
pub fn erf(x: f32) -> f32 {
    let a = x.abs();
    let y = 1.0 - erfc_pos_with_exp(a, exp(-a * a));
    y.copysign(x)
}

/// Inverse error function on (−1, 1), relative error < 2·10⁻⁶ for |x| ≤ 1 − 10⁻⁷ (Giles'
/// single-precision polynomials with the fast [`ln`]); ±∞ at ±1.
#[inline]
pub fn erfinv(x: f32) -> f32 {
    let mut w = -ln((1.0 - x) * (1.0 + x));
    let p = if w < 5.0 {
        w -= 2.5;
        let mut p = 2.810_226_4e-8f32;
        p = 3.432_739_4e-7 + p * w;
        p = -3.523_387_7e-6 + p * w;
        p = -4.391_506_5e-6 + p * w;
        p = 2.185_808_7e-4 + p * w;
        p = -1.253_725e-3 + p * w;
        p = -4.177_681_6e-3 + p * w;
        p = 2.466_407_3e-1 + p * w;
        1.501_409_4 + p * w
    } else {
        w = w.sqrt() - 3.0;
        let mut p = -2.002_142_6e-4f32;
        p = 1.009_505_6e-4 + p * w;
        p = 1.349_343_2e-3 + p * w;
        p = -3.673_428_4e-3 + p * w;
        p = 5.739_507_7e-3 + p * w;
        p = -7.622_461_3e-3 + p * w;
        p = 9.438_870_5e-3 + p * w;
        p = 1.001_674 + p * w;
        2.832_976_8 + p * w
    };
    p * x
}

/// Unpolarised Fresnel reflectance of a dielectric interface with the constants of one index
/// ratio precomputed. `eta` = n_inside / n_outside, "outside" = the side a positive cosine is on
/// (same convention as [`crate::math::fresnel_dielectric`]).
#[derive(Clone, Copy, Debug)]
pub struct Fresnel {
    /// n_inside / n_outside.
    pub eta: f32,
    /// 1/eta.
    pub inv_eta: f32,
    inv_eta2: f32,
    eta2: f32,
}

impl Fresnel {
    /// Constants for `eta` (> 0).
    pub fn new(eta: f32) -> Self {
        Fresnel { eta, inv_eta: 1.0 / eta, inv_eta2: 1.0 / (eta * eta), eta2: eta * eta }
    }

    /// `(R, cos θt, η_rel)` for a cosine `c` ≥ 0 on the incident side; `inside` = the light
    /// arrives from the inside (the side of index n_inside). `η_rel` = n_incident /
    /// n_transmitted (what the refraction formula `wt = −η_rel wo + (η_rel c − cos θt) n`
    /// needs); R = 1 and cos θt = 0 under total internal reflection. Same values as
    /// [`crate::math::fresnel_dielectric`] up to f32 round-off (tested).
    #[inline]
    pub fn eval(&self, c: f32, inside: bool) -> (f32, f32, f32) {
        // sin²θt = (1 − c²) (n_i/n_t)²
        let (k2, eta_rel) = if inside { (self.eta2, self.eta) } else { (self.inv_eta2, self.inv_eta) };
        let sin2_t = (1.0 - c * c) * k2;
        if sin2_t >= 1.0 {
            return (1.0, 0.0, eta_rel);
        }
        let ct = (1.0 - sin2_t).sqrt();
        // with η_rel = n_i/n_t: rs = (η_rel c − ct)/(η_rel c + ct), rp = (c − η_rel ct)/(c + η_rel ct)
        let a = eta_rel * c;
        let b = eta_rel * ct;
        // one division for both ratios (p q > 0 outside total internal reflection)
        let (p, q) = (a + ct, c + b);
        let inv = 1.0 / (p * q);
        let rs = (a - ct) * q * inv;
        let rp = (c - b) * p * inv;
        (0.5 * (rs * rs + rp * rp), ct, eta_rel)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sincos_accuracy() {
        let mut worst = 0.0f64;
        for i in 0..=200_000 {
            let u = i as f32 / 100_000.0 - 0.5; // [−0.5, 1.5]
            let (s, c) = sincos_2pi(u);
            let a = 2.0 * std::f64::consts::PI * u as f64;
            worst = worst.max((s as f64 - a.sin()).abs()).max((c as f64 - a.cos()).abs());
        }
        assert!(worst < 3e-7, "sincos error {worst}");
    }

    #[test]
    fn exp_accuracy() {
        let mut worst = 0.0f64;
        for i in 0..=400_000 {
            let x = -87.0 + 175.0 * i as f32 / 400_000.0;
            let r = (exp(x) as f64 - (x as f64).exp()).abs() / (x as f64).exp();
            worst = worst.max(r);
        }
        assert!(worst < 4e-7, "exp relative error {worst}");
        assert_eq!(exp(-100.0), 0.0);
        assert_eq!(exp(0.0), 1.0);
        assert!(exp(100.0).is_infinite());
    }

    #[test]
    fn ln_accuracy() {
        let mut worst = 0.0f64;
        let mut x = 1e-30f32;
        while x < 1e30 {
            let e = (x as f64).ln();
            let err = (ln(x) as f64 - e).abs() / e.abs().max(1.0);
            worst = worst.max(err);
            x *= 1.000_37;
        }
        assert!(worst < 3e-7, "ln error {worst}");
        // subnormal input and specials
        assert!((ln(1e-40) as f64 - (1e-40f32 as f64).ln()).abs() < 1e-5);
        assert_eq!(ln(0.0), f32::NEG_INFINITY);
        assert!(ln(-1.0).is_nan());
    }

    #[test]
    fn erf_and_erfinv_accuracy() {
        use statrs::function::erf::{erf as erf64, erf_inv};
        let mut worst = 0.0f64;
        for i in -60_000..=60_000 {
            let x = i as f32 / 10_000.0;
            worst = worst.max((erf(x) as f64 - erf64(x as f64)).abs());
        }
        assert!(worst < 6e-7, "erf error {worst}");
        for i in 0..=90 {
            let x = i as f32 / 10.0;
            let e = statrs::function::erf::erfc(x as f64);
            let r = erfc_pos_with_exp(x, exp(-x * x)) as f64;
            assert!((r - e).abs() <= 6e-7, "erfc({x}) {r} vs {e}");
        }
        let mut worst = 0.0f64;
        for i in -99_999..=99_999 {
            let y = i as f32 / 100_000.0;
            let e = erf_inv(y as f64);
            worst = worst.max((erfinv(y) as f64 - e).abs() / e.abs().max(1e-30));
        }
        // near ±1 (the Gaussian tails drawn from u ∈ [2⁻²⁴, 1 − 2⁻²⁴])
        for k in 1..=40 {
            let y = 1.0 - k as f32 * 6e-8;
            let e = erf_inv(y as f64);
            worst = worst.max((erfinv(y) as f64 - e).abs() / e);
        }
        assert!(worst < 2e-6, "erfinv relative error {worst}");
    }

    #[test]
    fn fresnel_matches_reference() {
        for eta in [1.49f32, 1.0 / 1.49, 2.4, 1.05] {
            let f = Fresnel::new(eta);
            for i in 0..=10_000 {
                let c = i as f32 / 10_000.0;
                for inside in [false, true] {
                    let cos_i = if inside { -c } else { c };
                    let r64 = crate::math::fresnel_dielectric_f64(cos_i as f64, eta as f64);
                    let (r, ct, eta_rel) = f.eval(c, inside);
                    let s2 = (1.0 - (c as f64).powi(2))
                        * if inside { (eta as f64).powi(2) } else { (eta as f64).powi(-2) };
                    let ct64 = (1.0 - s2).max(0.0).sqrt();
                    // f32 round-off of 1 − c² and sin²θt (≲ 5e-7 relative) is amplified by
                    // 1/(2 cos θt) near the critical angle, and dR/d cos θt is ~4 there
                    let tol = 2e-6 + 1e-6 / ct64.max(1e-4);
                    assert!((r as f64 - r64).abs() < tol, "η {eta} c {c} inside {inside}: {r} vs {r64}");
                    assert!((ct as f64 - ct64).abs() < tol, "cos θt {ct} vs {ct64}");
                    let expect_rel = if inside { eta } else { 1.0 / eta };
                    assert_eq!(eta_rel, expect_rel);
                }
            }
        }
    }
}
