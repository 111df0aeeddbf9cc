//! Smooth plastic (Mitsuba 3's `plastic`): a diffuse base under a smooth dielectric coating,
//! the coating model of Weidlich & Wilkie 2007 as Mitsuba implements it.
//!
//! * Specular: a Dirac-delta mirror reflection of weight `k_s F(cos θo)` (unpolarised
//!   dielectric Fresnel of the relative index `η = int_ior/ext_ior`).
//! * Diffuse: `f = ρ / (1 − F_dr,int · (ρ if nonlinear else 1)) · (1 − F(cos θo))(1 − F(cos θi))
//!   / (η² π)`: light refracts in, bounces on the Lambertian base (internal reflections at the
//!   coating summed as a geometric series, `F_dr,int` the diffuse Fresnel reflectance of the
//!   inside, or, with `nonlinear`, including the base's colour, which saturates it), refracts out.
//!   `F_dr` is the Egan–Hilgeman (1973) fit for η < 1 and d'Eon–Irving (2011) for η ≥ 1,
//!   Mitsuba's choice.
//! * Sampling (Mitsuba's rule): the specular lobe with probability
//!   `p_s = F_o w / (F_o w + (1 − F_o)(1 − w))`, `F_o = F(cos θo)`,
//!   `w = mean(k_s)/(mean(ρ̄) + mean(k_s))` with `ρ̄` the mean of the diffuse texture over its
//!   texels (fixed when the material is built); the diffuse lobe by cosine sampling otherwise.
//!   `pdf` is the non-delta density `(1 − p_s) cos θi / π`; a specular sample has `pdf = p_s`.
//!
//! One-sided: black unless both directions are above the surface. The diffuse reflectance may be
//! a texture: the runtime [`crate::scene::Material`] looks it up per hit and calls the `_kd`
//! methods; [`Bxdf`] on the struct uses its own constant `kd`.
//! Tests (below): χ² of the diffuse sampling vs `pdf`, sample/eval/pdf consistency, reciprocity,
//! the specular weight, energy `R ≤ 1` and Mitsuba's F_dr fits against quadrature;
//! `tests/mitsuba_materials.rs`: a scene against Mitsuba 3.

use super::{BsdfSample, Bxdf, BxdfFlags, TransportMode};
use crate::math::{INV_PI, Vec2, Vec3, fresnel_dielectric};
use crate::sampling::square_to_cosine_hemisphere;
use crate::spectrum::Spectrum;

/// Diffuse Fresnel reflectance `F_dr(η)` (hemispherical average of the Fresnel reflectance for
/// cosine-distributed incidence on an interface of relative index η): the polynomial fits of
/// Egan & Hilgeman 1973 (η < 1) and d'Eon & Irving 2011 (η ≥ 1), as in Mitsuba.
pub fn fresnel_diffuse_reflectance(eta: f32) -> f32 {
    let inv = 1.0 / eta;
    if eta < 1.0 {
        -1.4399 * eta * eta + 0.7099 * eta + 0.6681 + 0.0636 * inv
    } else {
        let c = [0.919317f32, -3.4793, 6.75335, -7.80989, 4.98554, -1.36881];
        c.iter().rev().fold(0.0, |acc, &a| acc * inv + a)
    }
}

/// Mitsuba's specular sampling weight `mean(k_s) / (mean(ρ̄) + mean(k_s))`.
pub fn specular_sampling_weight(kd_mean: f32, ks: Spectrum) -> f32 {
    let s = ks.average();
    if s + kd_mean > 0.0 { s / (kd_mean + s) } else { 0.5 }
}

/// Smooth plastic (diffuse base, smooth dielectric coating).
#[derive(Clone, Copy, Debug)]
pub struct Plastic {
    /// Relative index of the coating `int_ior / ext_ior`.
    pub eta: f32,
    /// Diffuse reflectance (the constant value; textured materials pass theirs per hit).
    pub kd: Spectrum,
    /// Specular reflectance multiplier.
    pub ks: Spectrum,
    /// Mitsuba's `nonlinear`.
    pub nonlinear: bool,
    /// `F_dr` of the inside (`fresnel_diffuse_reflectance(1/η)`).
    pub fdr_int: f32,
    /// Specular sampling weight `w`.
    pub spec_weight: f32,
}

impl Plastic {
    /// New plastic; `kd_mean` is the mean of the diffuse reflectance (over channels and, for a
    /// texture, texels) that sets the sampling weight. Error unless η is finite, > 0 and ≠ 1.
    pub fn new(eta: f32, kd: Spectrum, kd_mean: f32, ks: Spectrum, nonlinear: bool) -> crate::Result<Self> {
        if !(eta.is_finite() && eta > 0.0) || (eta - 1.0).abs() < 1e-4 {
            return Err(crate::Error::invalid("int_ior/ext_ior", format!("must be > 0 and ≠ 1, got {eta}")));
        }
        Ok(Plastic {
            eta,
            kd,
            ks,
            nonlinear,
            fdr_int: fresnel_diffuse_reflectance(1.0 / eta),
            spec_weight: specular_sampling_weight(kd_mean, ks),
        })
    }

    /// Probability of choosing the specular lobe for `cos θo > 0`.
    #[inline]
    fn prob_specular(&self, cos_o: f32) -> f32 {
        let f = fresnel_dielectric(cos_o, self.eta).0;
        let ps = f * self.spec_weight;
        let pd = (1.0 - f) * (1.0 - self.spec_weight);
        if ps + pd > 0.0 { ps / (ps + pd) } else { 0.0 }
    }

    /// The diffuse term with diffuse reflectance `kd` (without the cosine).
    #[inline]
    pub fn eval_kd(&self, kd: Spectrum, wo: Vec3, wi: Vec3) -> Spectrum {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return Spectrum::ZERO;
        }
        let fo = fresnel_dielectric(wo.z, self.eta).0;
        let fi = fresnel_dielectric(wi.z, self.eta).0;
        let den = if self.nonlinear {
            Spectrum::ONE - kd * self.fdr_int
        } else {
            Spectrum::splat(1.0 - self.fdr_int)
        };
        let s = (1.0 - fo) * (1.0 - fi) * INV_PI / (self.eta * self.eta);
        Spectrum::rgb(kd[0] / den[0], kd[1] / den[1], kd[2] / den[2]) * s
    }

    /// Non-delta density of `wi` (independent of the diffuse reflectance).
    #[inline]
    pub fn pdf_dir(&self, wo: Vec3, wi: Vec3) -> f32 {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return 0.0;
        }
        (1.0 - self.prob_specular(wo.z)) * wi.z * INV_PI
    }

    /// [`Bxdf::sample`] with diffuse reflectance `kd`.
    #[inline]
    pub fn sample_kd(&self, kd: Spectrum, wo: Vec3, uc: f32, u: Vec2) -> Option<BsdfSample> {
        if wo.z <= 0.0 {
            return None;
        }
        let ps = self.prob_specular(wo.z);
        if uc < ps {
            let wi = Vec3::new(-wo.x, -wo.y, wo.z);
            let f = fresnel_dielectric(wo.z, self.eta).0;
            return Some(BsdfSample {
                wi,
                f: self.ks * (f / wi.z),
                pdf: ps,
                flags: BxdfFlags { reflection: true, transmission: false, specular: true },
                eta: 1.0,
            });
        }
        let wi = square_to_cosine_hemisphere(u);
        let pdf = self.pdf_dir(wo, wi);
        if pdf <= 0.0 {
            return None;
        }
        Some(BsdfSample {
            wi,
            f: self.eval_kd(kd, wo, wi),
            pdf,
            flags: BxdfFlags { reflection: true, ..Default::default() },
            eta: 1.0,
        })
    }
}

impl Bxdf for Plastic {
    fn eval(&self, wo: Vec3, wi: Vec3, _mode: TransportMode) -> Spectrum {
        self.eval_kd(self.kd, wo, wi)
    }
    fn pdf(&self, wo: Vec3, wi: Vec3, _mode: TransportMode) -> f32 {
        self.pdf_dir(wo, wi)
    }
    fn sample(&self, wo: Vec3, uc: f32, u: Vec2, _mode: TransportMode) -> Option<BsdfSample> {
        self.sample_kd(self.kd, wo, uc, u)
    }
    fn flags(&self) -> BxdfFlags {
        // mixed: a delta lobe and a smooth one; `specular` marks the delta lobe's samples only
        BxdfFlags { reflection: true, transmission: false, specular: false }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsdf::lobe::test_util::*;
    use crate::math::{DVec3, fresnel_dielectric_f64, spherical_direction};
    use crate::validate::quadrature::integrate_z_range;

    /// The plastic with its specular samples removed: `sample` then draws the diffuse lobe with
    /// total probability `1 − p_s`, whose density is `pdf` (what the χ² test checks).
    struct DiffusePart(Plastic);
    impl Bxdf for DiffusePart {
        fn eval(&self, wo: Vec3, wi: Vec3, m: TransportMode) -> Spectrum {
            self.0.eval(wo, wi, m)
        }
        fn pdf(&self, wo: Vec3, wi: Vec3, m: TransportMode) -> f32 {
            self.0.pdf(wo, wi, m)
        }
        fn sample(&self, wo: Vec3, uc: f32, u: Vec2, m: TransportMode) -> Option<BsdfSample> {
            self.0.sample(wo, uc, u, m).filter(|s| !s.flags.specular)
        }
        fn flags(&self) -> BxdfFlags {
            self.0.flags()
        }
    }

    fn models() -> Vec<Plastic> {
        vec![
            Plastic::new(1.49, Spectrum::rgb(0.2, 0.5, 0.8), 0.5, Spectrum::ONE, false).unwrap(),
            Plastic::new(1.9, Spectrum::rgb(0.9, 0.1, 0.4), 0.4667, Spectrum::splat(0.6), true).unwrap(),
        ]
    }

    #[test]
    fn chi2_consistency_reciprocity() {
        for (k, b) in models().into_iter().enumerate() {
            chi2_at(&format!("plastic_{k}"), &DiffusePart(b), &[0.0, 0.9, 1.45], 6);
            sample_consistency(&DiffusePart(b), 0.7);
            reciprocity(&b);
        }
    }

    #[test]
    fn specular_weight_and_probability() {
        let b = models()[1];
        let mut n_spec = 0;
        let n = 20_000;
        let wo = spherical_direction(1.2, 0.4);
        let ps = b.prob_specular(wo.z);
        for i in 0..n {
            let uc = (i as f32 + 0.5) / n as f32;
            let s = b.sample(wo, uc, Vec2::new(0.3, 0.6), TransportMode::Radiance).unwrap();
            if s.flags.specular {
                n_spec += 1;
                let f = fresnel_dielectric(wo.z, b.eta).0;
                let w = s.weight();
                assert!((w[0] - 0.6 * f / ps).abs() < 1e-5 * w[0], "{w:?}");
                assert!((s.wi.z - wo.z).abs() < 1e-6);
            }
        }
        assert!(((n_spec as f32 / n as f32) - ps).abs() < 1e-3, "{n_spec} {ps}");
        // Mitsuba's rule: F w / (F w + (1 − F)(1 − w)), w = 0.6/(0.4667 + 0.6)
        let w = 0.6 / (0.4667 + 0.6);
        let f = fresnel_dielectric(wo.z, 1.9).0;
        assert!((ps - f * w / (f * w + (1.0 - f) * (1.0 - w))).abs() < 1e-6);
    }

    #[test]
    fn diffuse_fresnel_fits_match_quadrature() {
        // F_dr(η) = 2 ∫ F(μ, η) μ dμ
        for eta in [1.2f64, 1.49, 1.9, 1.0 / 1.49, 1.0 / 1.3] {
            // split at the critical angle of total internal reflection (a kink in F)
            let zc = if eta < 1.0 { (1.0 - eta * eta).sqrt() } else { 0.5 };
            let f = |w: DVec3| fresnel_dielectric_f64(w.z, eta) * w.z / std::f64::consts::PI;
            let q = integrate_z_range(0.0, zc, 64, 8, f) + integrate_z_range(zc, 1.0, 64, 8, f);
            let fit = fresnel_diffuse_reflectance(eta as f32) as f64;
            // the fits' published accuracy is ~0.1 % in this range (measured here: ≤ 0.09 %)
            assert!((q - fit).abs() < 1e-3 * q, "η {eta}: quadrature {q} fit {fit}");
        }
    }

    #[test]
    fn albedo_of_a_white_base() {
        // white base, linear: directional albedo = F_o + (1 − F_o)(1 − F_dr,ext)/(η²(1 − F_dr,int)).
        // Exactly 1 if the F_dr were exact (η²(1 − F_dr,int) = 1 − F_dr,ext); with Mitsuba's fits
        // the ratio is 1.0011 at η = 1.49, so the model (as Mitsuba's) returns ≤ 0.2 % too much.
        let b = Plastic::new(1.49, Spectrum::ONE, 1.0, Spectrum::ONE, false).unwrap();
        let fdr_ext = fresnel_diffuse_reflectance(1.49) as f64;
        let ratio = (1.0 - fdr_ext) / (1.49f64 * 1.49 * (1.0 - b.fdr_int as f64));
        assert!((ratio - 1.0).abs() < 2e-3, "{ratio}");
        for theta in [0.0f32, 0.8, 1.4] {
            let wo = spherical_direction(theta, 0.0);
            let d = integrate_z_range(0.0, 1.0, 64, 64, |w: DVec3| {
                b.eval(wo, w.as_vec3(), TransportMode::Radiance)[0] as f64 * w.z
            });
            let fo = fresnel_dielectric(wo.z, 1.49).0 as f64;
            let a = d + fo;
            let want = fo + (1.0 - fo) * ratio;
            assert!((a - want).abs() < 1e-3, "θ {theta}: albedo {a} vs {want}");
            assert!(a <= 1.002, "θ {theta}: albedo {a}");
        }
    }
}
