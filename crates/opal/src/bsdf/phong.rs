//! Phong's specular lobe (method B): `f(wo, wi) = k_s · c(n) · max(0, cos γ)^n` with
//! `cos γ = wi · r`, `r = reflect(wo) = 2(wo·n)n − wo` (Phong's `V·R`), on the upper hemisphere.
//!
//! Parameters: exponent `n ≥ 0` (shininess), normalisation `c(n)`, reflectance `k_s`.
//! Normalisations ([`Phong::normalised_factor`]):
//! * raw, `c = 1` — the classic shading formula read as a BRDF; its reflectance
//!   `R = ∫ f cos θ dω` is `2π/(n+2)` at normal incidence, far above 1 for small `n`;
//! * `(n+2)/(2π)` — the "modified Phong" normalisation (Lafortune & Willems 1994): it makes
//!   `R = 1` exactly at normal incidence (the cosine factor `cos θ_V` of the reflectance integral
//!   is *included* in the normalisation), and `R < 1` elsewhere (the lobe is cut by the horizon
//!   and `cos θ_V < cos γ`).
//!
//! The cosine-power shape [`CosPower`] is shared with [`super::blinn`]. Sampling: exact
//! inversion `t = (1 − u)^{1/(n+1)}` around `r` (see [`super::lobe`]).
//!
//! References: B. T. Phong, "Illumination for computer generated pictures", CACM 1975;
//! E. Lafortune, Y. Willems, "Using the modified Phong reflectance model for physically based
//! rendering", 1994.
//! Tests (below): χ² sampling vs pdf at four incidence angles, sample/eval/pdf consistency,
//! reciprocity, `R(0°) = 1` for the normalised lobe and `2π/(n+2)` for the raw one.

use super::lobe::{LobeBxdf, LobeForm, LobeShape, impl_lobe_bxdf};
use crate::spectrum::Spectrum;

/// The lobe `max(0, t)^n`.
#[derive(Clone, Copy, Debug)]
pub struct CosPower {
    /// Exponent `n ≥ 0`.
    pub n: f64,
    n32: f32,
}

impl CosPower {
    /// `max(0, t)^n`.
    pub fn new(n: f64) -> Self {
        CosPower { n, n32: n as f32 }
    }
}

impl LobeShape for CosPower {
    #[inline]
    fn value(&self, x: f32) -> f32 {
        // t^n = exp(n ln(1 − x))
        if x < 1.0 { (self.n32 * (-x).ln_1p()).exp() } else { 0.0 }
    }
    fn value_f64(&self, t: f64) -> f64 {
        if t > 0.0 { t.powf(self.n) } else { 0.0 }
    }
    fn t_min(&self) -> f64 {
        0.0
    }
    fn tail(&self, t: f64) -> f64 {
        let t = t.clamp(0.0, 1.0);
        // (1 − t^{n+1})/(n+1), written with exp_m1/ln for accuracy near t = 1
        let a = self.n + 1.0;
        if t == 0.0 { 1.0 / a } else { -(a * t.ln()).exp_m1() / a }
    }
    fn tail_inverse(&self, y: f64) -> f64 {
        let a = self.n + 1.0;
        let v = (1.0 - y * a).max(0.0);
        if v == 0.0 { 0.0 } else { (v.ln() / a).exp() }
    }
}

/// Phong lobe BRDF.
#[derive(Clone, Debug)]
pub struct Phong {
    /// The lobe (Phong form).
    pub lobe: LobeBxdf<CosPower>,
}

impl Phong {
    /// Phong lobe with exponent `n`, normalisation factor `scale` and reflectance `k_s`.
    pub fn new(n: f64, scale: f64, reflectance: Spectrum) -> Self {
        Phong { lobe: LobeBxdf::new(CosPower::new(n), LobeForm::Phong, scale, reflectance) }
    }
    /// The energy-conserving factor `(n+2)/(2π)`.
    pub fn normalised_factor(n: f64) -> f64 {
        (n + 2.0) / (2.0 * std::f64::consts::PI)
    }
}

impl_lobe_bxdf!(Phong);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsdf::lobe::test_util::*;
    use crate::bsdf::{Bxdf, TransportMode};
    use crate::math::DVec3;
    use crate::validate::quadrature::integrate_hemisphere;

    #[test]
    fn chi2_reciprocity_consistency() {
        for n in [1.0, 20.0, 120.0] {
            let b = Phong::new(n, 1.0, Spectrum::ONE);
            chi2_at(&format!("phong_n{n}"), &b, &[0.0, 0.9, 1.45], 9);
            sample_consistency(&b, 0.7);
            reciprocity(&b);
        }
    }

    #[test]
    fn normal_incidence_reflectance() {
        for n in [0.0, 1.0, 7.5, 40.0] {
            let raw = Phong::new(n, 1.0, Spectrum::ONE);
            // degree n+1 polynomial in cos θ (integer n): Gauss–Legendre is exact; 64 nodes
            // make the non-integer cases accurate to < 1e-6 as well
            let r = integrate_hemisphere(64, 8, |w: DVec3| {
                raw.eval(glam::Vec3::Z, w.as_vec3(), TransportMode::Radiance)[0] as f64 * w.z
            });
            let want = 2.0 * std::f64::consts::PI / (n + 2.0);
            assert!((r - want).abs() < 2e-6 * want, "n {n}: {r} vs {want}");
            let norm = Phong::new(n, Phong::normalised_factor(n), Spectrum::ONE);
            let r = integrate_hemisphere(64, 8, |w: DVec3| {
                norm.eval(glam::Vec3::Z, w.as_vec3(), TransportMode::Radiance)[0] as f64 * w.z
            });
            assert!((r - 1.0).abs() < 2e-6, "n {n}: {r}");
        }
    }
}
