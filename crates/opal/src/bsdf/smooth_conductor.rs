//! Smooth conductor (Mitsuba's `conductor`): a Dirac-delta mirror reflection weighted by the
//! conductor Fresnel term of a complex index `η + iκ` per RGB channel (or `F = 1`, Mitsuba's
//! `material="none"`), times `specular_reflectance`. One-sided: black when `wo` is below the
//! surface.
//!
//! Conventions as [`super::dielectric`]: `eval` and `pdf` are zero; `sample` returns the mirror
//! direction with `pdf = 1` (the discrete probability of the only lobe) and
//! `f = k_s F(cos θo) / cos θi`, so that the weight `f cos θi / pdf = k_s F`. Reciprocal (the
//! mirror pair has equal angles). Fresnel formula: [`super::conductor::fresnel_conductor`].
//! Tests (below): weight = k_s·F, mirror direction, back side black; the furnace catalogue in
//! `tests/furnace.rs` (a mirror `F = 1` box keeps the furnace radiance).

use super::conductor::ConductorFresnel;
use super::{BsdfSample, Bxdf, BxdfFlags, TransportMode};
use crate::math::{Vec2, Vec3};
use crate::spectrum::Spectrum;

/// Smooth conductor (delta reflection).
#[derive(Clone, Copy, Debug)]
pub struct SmoothConductor {
    /// Fresnel term.
    pub fresnel: ConductorFresnel,
    /// Specular reflectance multiplier `k_s`.
    pub reflectance: Spectrum,
}

impl SmoothConductor {
    /// New smooth conductor.
    pub fn new(fresnel: ConductorFresnel, reflectance: Spectrum) -> Self {
        SmoothConductor { fresnel, reflectance }
    }
}

/// The Fresnel reflectance of `fresnel` at `cos_i` per channel (shared with the rough model).
#[inline]
pub fn conductor_reflectance(fresnel: &ConductorFresnel, cos_i: f32) -> Spectrum {
    use super::conductor::fresnel_conductor;
    match *fresnel {
        ConductorFresnel::Mirror => Spectrum::ONE,
        ConductorFresnel::Complex { eta, k } => Spectrum::rgb(
            fresnel_conductor(cos_i, eta[0], k[0]),
            fresnel_conductor(cos_i, eta[1], k[1]),
            fresnel_conductor(cos_i, eta[2], k[2]),
        ),
    }
}

impl Bxdf for SmoothConductor {
    fn eval(&self, _wo: Vec3, _wi: Vec3, _mode: TransportMode) -> Spectrum {
        Spectrum::ZERO
    }
    fn pdf(&self, _wo: Vec3, _wi: Vec3, _mode: TransportMode) -> f32 {
        0.0
    }
    fn sample(&self, wo: Vec3, _uc: f32, _u: Vec2, _mode: TransportMode) -> Option<BsdfSample> {
        if wo.z <= 0.0 {
            return None;
        }
        let wi = Vec3::new(-wo.x, -wo.y, wo.z);
        let f = self.reflectance * conductor_reflectance(&self.fresnel, wo.z) * (1.0 / wi.z);
        Some(BsdfSample {
            wi,
            f,
            pdf: 1.0,
            flags: BxdfFlags { reflection: true, transmission: false, specular: true },
            eta: 1.0,
        })
    }
    fn flags(&self) -> BxdfFlags {
        BxdfFlags { reflection: true, transmission: false, specular: true }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsdf::conductor::fresnel_conductor;
    use crate::math::spherical_direction;

    #[test]
    fn weight_is_fresnel_times_reflectance() {
        let (eta, k) = crate::bsdf::ior::conductor_ior("Au").unwrap();
        let b = SmoothConductor::new(
            ConductorFresnel::Complex { eta: Spectrum(eta), k: Spectrum(k) },
            Spectrum::splat(0.9),
        );
        for theta in [0.0f32, 0.5, 1.2, 1.5] {
            let wo = spherical_direction(theta, 0.3);
            let s = b.sample(wo, 0.5, Vec2::new(0.2, 0.7), TransportMode::Radiance).unwrap();
            assert!((s.wi - Vec3::new(-wo.x, -wo.y, wo.z)).length() < 1e-6);
            assert!(s.flags.specular && s.flags.reflection && s.pdf == 1.0);
            let w = s.weight();
            for c in 0..3 {
                let want = 0.9 * fresnel_conductor(wo.z, eta[c], k[c]);
                assert!((w[c] - want).abs() < 1e-5, "{theta} c{c}: {} vs {want}", w[c]);
            }
            assert!(b.eval(wo, s.wi, TransportMode::Radiance).is_black());
            assert_eq!(b.pdf(wo, s.wi, TransportMode::Radiance), 0.0);
        }
        let m = SmoothConductor::new(ConductorFresnel::Mirror, Spectrum::ONE);
        let s = m.sample(spherical_direction(0.7, 1.0), 0.1, Vec2::ZERO, TransportMode::Importance).unwrap();
        assert!((s.weight() - Spectrum::ONE).max_component().abs() < 1e-6);
        assert!(m.sample(Vec3::new(0.0, 0.6, -0.8), 0.1, Vec2::ZERO, TransportMode::Radiance).is_none());
    }
}
