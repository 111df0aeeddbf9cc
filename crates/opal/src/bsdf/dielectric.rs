//! Smooth (polished) dielectric interface: Dirac-delta specular reflection and refraction
//! (Mitsuba's `dielectric`), light arriving from either side, [`TransportMode`]-correct.
//!
//! Parameters: `eta` = n_inside / n_outside, where "outside" is the side the local +z axis points
//! to (a closed glass object whose normals point outwards: `eta` = n_glass / n_air).
//!
//! Conventions: `eval` and `pdf` are zero (delta lobes); `sample` chooses reflection with the
//! unpolarised Fresnel probability `F(cos θo)` and refraction otherwise, returning
//! `pdf` = the discrete probability of the chosen lobe and `f` = its delta weight divided by
//! `|cos θi|`, so that the throughput weight `f |cos θi| / pdf` is 1 for reflection and, for
//! refraction, 1 in [`TransportMode::Importance`] (power is conserved) and `1/η'²` in
//! [`TransportMode::Radiance`] (radiance scales with n², η' = n(wi side)/n(wo side)).
//!
//! References: pbrt-v4 §9.5 (dielectric BSDF), Veach's thesis §5.2 (non-symmetric BSDFs due to
//! refraction).
//! Tests (below): energy (R + T = 1 per sample in importance mode), the refracted direction obeys
//! Snell's law, the radiance weight is 1/η'²; `tests/furnace.rs`: a lossless glass sphere in a
//! closed furnace leaves the furnace radiance unchanged.

use super::{BsdfSample, Bxdf, BxdfFlags, TransportMode};
use crate::math::{Vec2, Vec3, fresnel_dielectric, refract};
use crate::spectrum::Spectrum;

/// Smooth dielectric interface (delta reflection and refraction).
#[derive(Clone, Copy, Debug)]
pub struct SmoothDielectric {
    /// n_inside / n_outside (outside = +z side).
    pub eta: f32,
}

impl SmoothDielectric {
    /// New interface; error unless `eta` is finite, > 0 and ≠ 1.
    pub fn new(eta: f32) -> crate::Result<Self> {
        if !(eta.is_finite() && eta > 0.0) || (eta - 1.0).abs() < 1e-4 {
            return Err(crate::Error::invalid("eta", format!("must be > 0 and ≠ 1, got {eta}")));
        }
        Ok(SmoothDielectric { eta })
    }
}

impl Bxdf for SmoothDielectric {
    fn eval(&self, _wo: Vec3, _wi: Vec3, _mode: TransportMode) -> Spectrum {
        Spectrum::ZERO
    }

    fn pdf(&self, _wo: Vec3, _wi: Vec3, _mode: TransportMode) -> f32 {
        0.0
    }

    fn sample(&self, wo: Vec3, uc: f32, _u: Vec2, mode: TransportMode) -> Option<BsdfSample> {
        if wo.z == 0.0 {
            return None;
        }
        let (f, _) = fresnel_dielectric(wo.z, self.eta);
        if uc < f {
            let wi = Vec3::new(-wo.x, -wo.y, wo.z);
            return Some(BsdfSample {
                wi,
                f: Spectrum::splat(f / wi.z.abs()),
                pdf: f,
                flags: BxdfFlags { reflection: true, transmission: false, specular: true },
                eta: 1.0,
            });
        }
        let (n, etap) = if wo.z > 0.0 { (Vec3::Z, self.eta) } else { (-Vec3::Z, 1.0 / self.eta) };
        let wi = refract(wo, n, etap)?;
        if wi.z == 0.0 || wi.z * wo.z > 0.0 {
            return None;
        }
        let t = 1.0 - f;
        let mut v = t / wi.z.abs();
        if mode == TransportMode::Radiance {
            v /= etap * etap;
        }
        Some(BsdfSample {
            wi,
            f: Spectrum::splat(v),
            pdf: t,
            flags: BxdfFlags { reflection: false, transmission: true, specular: true },
            eta: etap,
        })
    }

    fn flags(&self) -> BxdfFlags {
        BxdfFlags { reflection: true, transmission: true, specular: true }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::spherical_direction;
    use crate::sampling::Rng;

    #[test]
    fn energy_snell_and_radiance_scaling() {
        let b = SmoothDielectric::new(1.5).unwrap();
        let mut rng = Rng::new(3, 0, 0);
        for k in 0..2000 {
            let theta = (k as f32 / 2000.0) * 1.55;
            for side in [1.0f32, -1.0] {
                let mut wo = spherical_direction(theta, 0.3 + k as f32);
                wo.z *= side;
                let (fr, _) = fresnel_dielectric(wo.z, b.eta);
                let mut e = 0.0;
                for (uc, expect_refl) in [(fr * 0.5, true), (fr + 0.5 * (1.0 - fr), false)] {
                    let Some(s) = b.sample(wo, uc, rng.next_2d(), TransportMode::Importance) else {
                        // only total internal reflection can refuse, and then F = 1
                        assert!(fr >= 1.0 - 1e-6 && !expect_refl, "θ={theta} side {side}");
                        continue;
                    };
                    assert_eq!(s.flags.reflection, expect_refl);
                    let w = s.weight()[0];
                    assert!((w - 1.0).abs() < 1e-5, "importance weight {w}");
                    e += s.pdf * w;
                    if !expect_refl {
                        // Snell: n_o sin θo = n_i sin θi; opposite side; same plane of incidence
                        let (no, ni) = if side > 0.0 { (1.0, 1.5) } else { (1.5, 1.0) };
                        let so = (1.0 - wo.z * wo.z).max(0.0).sqrt();
                        let si = (1.0 - s.wi.z * s.wi.z).max(0.0).sqrt();
                        assert!((no * so - ni * si).abs() < 1e-4, "Snell θ={theta}");
                        assert!(s.wi.z * wo.z < 0.0);
                        assert!((wo.x * s.wi.y - wo.y * s.wi.x).abs() < 1e-5);
                        let r = b.sample(wo, uc, rng.next_2d(), TransportMode::Radiance).unwrap();
                        let etap = ni / no;
                        assert!((r.weight()[0] - 1.0 / (etap * etap)).abs() < 1e-5);
                        assert!((r.eta - etap).abs() < 1e-6);
                    } else {
                        assert!((s.wi.z - wo.z).abs() < 1e-7 && (s.wi.x + wo.x).abs() < 1e-7);
                    }
                }
                // R + T = 1: the two lobes' probabilities times their (unit) weights
                assert!((e - 1.0).abs() < 1e-5, "θ={theta} side {side}: R+T = {e}");
            }
        }
        assert!(SmoothDielectric::new(1.0).is_err());
        assert!(SmoothDielectric::new(f32::NAN).is_err());
    }
}
