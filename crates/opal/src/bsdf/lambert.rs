//! One-sided Lambertian reflector, Mitsuba's `diffuse`: f = ρ/π when both directions are on the
//! front side (local z > 0), zero otherwise (black from the back). Cosine-weighted sampling.
//! Parameters: reflectance ρ ∈ \[0,1\]³ (texture lookups happen before the Bxdf is built).
//! Tests: χ² of sampling vs pdf, reciprocity, directional albedo = ρ (below).

use super::{BsdfSample, Bxdf, BxdfFlags, TransportMode};
use crate::math::{INV_PI, Vec2, Vec3};
use crate::sampling::{square_to_cosine_hemisphere, square_to_cosine_hemisphere_pdf};
use crate::spectrum::Spectrum;

/// Lambertian reflector with reflectance `r`.
#[derive(Clone, Copy, Debug)]
pub struct Lambert {
    /// Reflectance ρ (albedo).
    pub r: Spectrum,
}

impl Lambert {
    /// New Lambertian reflector.
    pub fn new(r: Spectrum) -> Self {
        Lambert { r }
    }
}

impl Bxdf for Lambert {
    #[inline]
    fn eval(&self, wo: Vec3, wi: Vec3, _mode: TransportMode) -> Spectrum {
        if wo.z > 0.0 && wi.z > 0.0 { self.r * INV_PI } else { Spectrum::ZERO }
    }
    #[inline]
    fn pdf(&self, wo: Vec3, wi: Vec3, _mode: TransportMode) -> f32 {
        if wo.z > 0.0 { square_to_cosine_hemisphere_pdf(wi) } else { 0.0 }
    }
    #[inline]
    fn sample(&self, wo: Vec3, _uc: f32, u: Vec2, _mode: TransportMode) -> Option<BsdfSample> {
        if wo.z <= 0.0 {
            return None;
        }
        let wi = square_to_cosine_hemisphere(u);
        let pdf = square_to_cosine_hemisphere_pdf(wi);
        if pdf <= 0.0 {
            return None;
        }
        Some(BsdfSample {
            wi,
            f: self.r * INV_PI,
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
    use crate::math::{DVec3, spherical_direction};
    use crate::validate::chi2::{Chi2Test, SphereFn3};
    use crate::validate::quadrature::integrate_hemisphere;

    #[test]
    fn chi2_and_albedo_and_reciprocity() {
        let b = Lambert::new(Spectrum::rgb(0.2, 0.5, 0.9));
        for theta in [0.1f32, 0.8, 1.4] {
            let wo = spherical_direction(theta, 0.3);
            let t = Chi2Test::new("lambert", 400_000, 10);
            let r = t.run3(&SphereFn3 {
                sample: &|u, uc| b.sample(wo, uc, u, TransportMode::Radiance).map(|s| s.wi),
                pdf: &|wi| b.pdf(wo, wi, TransportMode::Radiance) as f64,
            });
            assert!(r.passed, "{r:?}");
            let albedo = integrate_hemisphere(16, 16, |wi: DVec3| {
                b.eval(wo, wi.as_vec3(), TransportMode::Radiance)[1] as f64 * wi.z
            });
            assert!((albedo - 0.5).abs() < 1e-5, "albedo {albedo}");
            let wi = spherical_direction(0.6, 2.0);
            assert_eq!(b.eval(wo, wi, TransportMode::Radiance), b.eval(wi, wo, TransportMode::Radiance));
        }
        // black from the back
        assert!(b.eval(-Vec3::Z, Vec3::Z, TransportMode::Radiance).is_black());
    }
}
