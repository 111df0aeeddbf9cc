//! Beckmann distribution: Gaussian distribution of micro-facet slopes (the "Gauss-like" NDF of
//! method A), `D(wm) = exp(-tan²θm/α²) / (π α² cos⁴θm)`.
//!
//! Parameters: isotropic roughness `alpha` > 0 (RMS slope `alpha/√2`).
//! Smith Λ in closed form: with `a = 1/(α tan θ)`, `Λ = (erf(a) − 1)/2 + exp(−a²)/(2a√π)`.
//! Visible normals (Heitz & d'Eon 2014): the slope along the incident azimuth has the marginal
//! density `∝ (1 − x tan θ)⁺ exp(−x²)` (unit roughness), inverted here by safeguarded Newton
//! iteration on its closed-form CDF in f64; the orthogonal slope is an independent Gaussian.
//! The sample is then scaled by α and rotated to the azimuth of `w`.
//! Tests: `microfacet::tests::check_ndf` (normalisation, weak furnace, χ² from both sides).

use super::{Ndf, slopes_to_normal};
use crate::math::{Vec2, Vec3};

/// erf with |error| < 1.5e-7 (Abramowitz & Stegun 7.1.26): one `exp`, far cheaper than a
/// full-precision erf and exact enough for f32 results.
#[inline]
pub fn erf_fast(x: f64) -> f64 {
    let t = 1.0 / (1.0 + 0.327_591_1 * x.abs());
    let y = 1.0
        - (((((1.061_405_429 * t - 1.453_152_027) * t) + 1.421_413_741) * t - 0.284_496_736) * t
            + 0.254_829_592)
            * t
            * (-x * x).exp();
    y.copysign(x)
}

/// Inverse error function, single-precision accuracy (M. Giles, "Approximating the erfinv
/// function", GPU Computing Gems 2010); used as the start of Newton's iteration and for the
/// Gaussian slope orthogonal to the incident plane.
#[inline]
pub fn erf_inv_fast(x: f64) -> f64 {
    let mut w = -((1.0 - x) * (1.0 + x)).ln();
    let p = if w < 5.0 {
        w -= 2.5;
        let mut p = 2.810_226_36e-08;
        for c in [
            3.432_739_39e-07,
            -3.523_387_7e-06,
            -4.391_506_54e-06,
            2.185_808_7e-04,
            -1.253_725_03e-03,
            -4.177_681_64e-03,
            2.466_407_27e-01,
            1.501_409_41,
        ] {
            p = c + p * w;
        }
        p
    } else {
        w = w.sqrt() - 3.0;
        let mut p = -2.002_142_57e-04;
        for c in [
            1.009_505_58e-04,
            1.349_343_22e-03,
            -3.673_428_44e-03,
            5.739_507_73e-03,
            -7.622_461_3e-03,
            9.438_870_47e-03,
            1.001_674_06,
            2.832_976_82,
        ] {
            p = c + p * w;
        }
        p
    };
    p * x
}

const INV_SQRT_PI: f64 = 0.564_189_583_547_756_3;

/// Isotropic Beckmann NDF.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Beckmann {
    /// Roughness α (> 0).
    pub alpha: f32,
}

impl Beckmann {
    /// Beckmann NDF with roughness `alpha`; error unless `alpha` is finite and > 0.
    pub fn new(alpha: f32) -> crate::Result<Self> {
        if !(alpha.is_finite() && alpha > 0.0) {
            return Err(crate::Error::invalid("alpha", format!("must be > 0, got {alpha}")));
        }
        Ok(Beckmann { alpha })
    }

    /// Visible slope sample for unit roughness and an incident direction at `cos θ` in the x–z
    /// plane (x towards the direction).
    fn sample_slopes_unit(cos_t: f64, u: Vec2) -> (f64, f64) {
        let u1 = (u.x as f64).clamp(1e-9, 1.0 - 1e-9);
        let u2 = (u.y as f64).clamp(1e-9, 1.0 - 1e-9);
        let y = erf_inv_fast(2.0 * u2 - 1.0);
        if cos_t > 0.999_999 {
            // normal incidence: isotropic Gaussian, x by inversion of the same marginal
            return (erf_inv_fast(2.0 * u1 - 1.0), y);
        }
        let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
        let tan_t = sin_t / cos_t;
        let cot_t = cos_t / sin_t;
        // unnormalised CDF F(x) = (1 + erf x)/2 + tan θ exp(−x²)/(2√π), for x ≤ cot θ
        let cdf = |x: f64| 0.5 * (1.0 + erf_fast(x)) + 0.5 * tan_t * INV_SQRT_PI * (-x * x).exp();
        let total = cdf(cot_t);
        let target = u1 * total;
        let (mut lo, mut hi) = (-8.0f64.max(-cot_t - 8.0), cot_t);
        // Gaussian tail: F(-8) < 1e-28, negligible
        // start from the unconditioned Gaussian quantile (exact at normal incidence)
        let mut x = erf_inv_fast(2.0 * u1 - 1.0);
        if !x.is_finite() {
            x = 0.0;
        }
        x = x.clamp(lo, hi);
        for _ in 0..40 {
            let f = cdf(x) - target;
            if f > 0.0 {
                hi = x;
            } else {
                lo = x;
            }
            let dens = (1.0 - x * tan_t) * INV_SQRT_PI * (-x * x).exp();
            let mut xn = x - f / dens;
            if !(xn > lo && xn < hi && dens.is_finite() && dens > 0.0) {
                xn = 0.5 * (lo + hi);
            }
            if (xn - x).abs() < 1e-9 * (1.0 + x.abs()) || hi - lo < 1e-12 {
                x = xn;
                break;
            }
            x = xn;
        }
        (x, y)
    }
}

impl Ndf for Beckmann {
    #[inline]
    fn d(&self, wm: Vec3) -> f32 {
        if wm.z <= 0.0 {
            return 0.0;
        }
        let c2 = wm.z * wm.z;
        let t2 = (1.0 - c2).max(0.0) / c2;
        let a2 = self.alpha * self.alpha;
        (-t2 / a2).exp() / (std::f32::consts::PI * a2 * c2 * c2)
    }
    #[inline]
    fn lambda(&self, w: Vec3) -> f32 {
        let c = w.z.abs() as f64;
        let s = (1.0 - c * c).max(0.0).sqrt();
        if s == 0.0 {
            return 0.0;
        }
        if c == 0.0 {
            return f32::INFINITY;
        }
        let a = c / (self.alpha as f64 * s);
        (0.5 * (erf_fast(a) - 1.0) + 0.5 * INV_SQRT_PI * (-a * a).exp() / a) as f32
    }
    fn sample_visible(&self, w: Vec3, u: Vec2) -> Vec3 {
        let w = if w.z < 0.0 { -w } else { w };
        // stretch to unit roughness
        let ws = Vec3::new(w.x * self.alpha, w.y * self.alpha, w.z).normalize();
        let (x, y) = Self::sample_slopes_unit(ws.z as f64, u);
        slopes_to_normal(ws, self.alpha * x as f32, self.alpha * y as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsdf::microfacet::tests::check_ndf;

    #[test]
    fn beckmann_invariants() {
        for alpha in [0.1f32, 0.3, 0.6, 1.0] {
            // χ² for one α per family in the default tier (the quadrature of the harness is
            // the cost); `ndf_chi2_all_alphas` (ignored) runs it for every α ≥ 0.3
            // weak-furnace tolerance: quadrature error of the banded Gauss rule, < 1e-3 here
            check_ndf(
                &format!("beckmann_{alpha}"),
                &Beckmann::new(alpha).unwrap(),
                2e-3,
                if alpha == 0.3 || alpha == 0.35 { &[0.0, 0.9, 1.3][..] } else { &[][..] },
            );
        }
    }

    /// Heavy tier: `cargo test -p opal --lib ndf_chi2_all_alphas -- --ignored`.
    #[test]
    #[ignore]
    fn ndf_chi2_all_alphas() {
        for alpha in [0.3f32, 0.6, 1.0] {
            check_ndf(&format!("beckmann_{alpha}"), &Beckmann::new(alpha).unwrap(), 2e-3, &[0.0, 0.9, 1.3]);
        }
    }

    #[test]
    fn fast_erf_and_erfinv_are_accurate() {
        use statrs::function::erf::{erf, erf_inv};
        for i in -400..=400 {
            let x = i as f64 / 100.0;
            assert!((erf_fast(x) - erf(x)).abs() < 2e-7, "erf({x})");
        }
        for i in -999..=999 {
            let y = i as f64 / 1000.0;
            let (a, b) = (erf_inv_fast(y), erf_inv(y));
            assert!((a - b).abs() < 1e-5 * (1.0 + b.abs()), "erfinv({y}) {a} vs {b}");
        }
    }

    #[test]
    fn rejects_bad_alpha() {
        assert!(Beckmann::new(0.0).is_err());
        assert!(Beckmann::new(-0.1).is_err());
        assert!(Beckmann::new(f32::NAN).is_err());
    }
}
