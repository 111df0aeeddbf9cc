//! Thin dielectric sheet (Mitsuba 3's `thindielectric`): a window pane of negligible
//! thickness whose two parallel interfaces of relative index `η = int_ior/ext_ior` reflect and
//! transmit light; internal reflections summed: `R' = R + T²R/(1 − R²) = 2R/(1 + R)`, with
//! `R = F(|cos θo|)` the unpolarised Fresnel reflectance, and `T' = 1 − R'`. Transmitted light
//! leaves undeflected (`wi = −wo`), so the sheet is two-sided and symmetric.
//!
//! Conventions as [`super::dielectric`]: delta lobes, `eval` and `pdf` are zero; `sample` picks
//! reflection with probability `R'` and transmission otherwise, `pdf` = that probability and
//! `f = (prob · k) / |cos θi|` with `k` = `specular_reflectance` or `specular_transmittance`, so
//! the weight is `k` (the sheet conserves energy). No `1/η²` scaling: the medium is the same on
//! both sides. Tests (below): the probabilities `R'`, weights, directions from both sides.

use super::{BsdfSample, Bxdf, BxdfFlags, TransportMode};
use crate::math::{Vec2, Vec3, fresnel_dielectric};
use crate::spectrum::Spectrum;

/// Thin dielectric sheet (delta reflection and straight transmission).
#[derive(Clone, Copy, Debug)]
pub struct ThinDielectric {
    /// Relative index `int_ior / ext_ior` of the sheet.
    pub eta: f32,
    /// Reflection multiplier.
    pub reflectance: Spectrum,
    /// Transmission multiplier.
    pub transmittance: Spectrum,
}

impl ThinDielectric {
    /// New sheet; error unless `eta` is finite and > 0.
    pub fn new(eta: f32, reflectance: Spectrum, transmittance: Spectrum) -> crate::Result<Self> {
        if !(eta.is_finite() && eta > 0.0) {
            return Err(crate::Error::invalid("int_ior/ext_ior", format!("must be > 0, got {eta}")));
        }
        Ok(ThinDielectric { eta, reflectance, transmittance })
    }

    /// Reflectance `R' = 2R/(1 + R)` of the sheet at `|cos θ|`.
    #[inline]
    pub fn sheet_reflectance(&self, cos: f32) -> f32 {
        let r = fresnel_dielectric(cos.abs(), self.eta).0;
        2.0 * r / (1.0 + r)
    }
}

impl Bxdf for ThinDielectric {
    fn eval(&self, _wo: Vec3, _wi: Vec3, _mode: TransportMode) -> Spectrum {
        Spectrum::ZERO
    }
    fn pdf(&self, _wo: Vec3, _wi: Vec3, _mode: TransportMode) -> f32 {
        0.0
    }
    fn sample(&self, wo: Vec3, uc: f32, _u: Vec2, _mode: TransportMode) -> Option<BsdfSample> {
        if wo.z == 0.0 {
            return None;
        }
        let r = self.sheet_reflectance(wo.z);
        let c = wo.z.abs();
        let (wi, pdf, k, refl) = if uc <= r {
            (Vec3::new(-wo.x, -wo.y, wo.z), r, self.reflectance, true)
        } else {
            (-wo, 1.0 - r, self.transmittance, false)
        };
        if pdf <= 0.0 {
            return None;
        }
        Some(BsdfSample {
            wi,
            f: k * (pdf / c),
            pdf,
            flags: BxdfFlags { reflection: refl, transmission: !refl, specular: true },
            eta: 1.0,
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

    #[test]
    fn probabilities_weights_directions() {
        let b = ThinDielectric::new(1.5046, Spectrum::splat(0.9), Spectrum::rgb(1.0, 0.8, 0.6)).unwrap();
        for theta in [0.0f32, 0.7, 1.3] {
            for side in [1.0f32, -1.0] {
                let mut wo = spherical_direction(theta, 0.2);
                wo.z *= side;
                let r = b.sheet_reflectance(wo.z);
                let n = 10_000;
                let mut n_r = 0;
                for i in 0..n {
                    let uc = (i as f32 + 0.5) / n as f32;
                    let s = b.sample(wo, uc, Vec2::ZERO, TransportMode::Radiance).unwrap();
                    assert!(s.flags.specular);
                    let w = s.weight();
                    if s.flags.reflection {
                        n_r += 1;
                        assert!((s.wi.z - wo.z).abs() < 1e-6 && (w[1] - 0.9).abs() < 1e-6, "{w:?}");
                    } else {
                        assert!((s.wi + wo).length() < 1e-6);
                        assert!((w[2] - 0.6).abs() < 1e-6);
                    }
                }
                assert!((n_r as f32 / n as f32 - r).abs() < 2e-4, "{theta}: {n_r} vs {r}");
            }
        }
        // normal incidence, η = 1.5: R = 0.04, R' = 0.08/1.04
        let b = ThinDielectric::new(1.5, Spectrum::ONE, Spectrum::ONE).unwrap();
        assert!((b.sheet_reflectance(1.0) - 0.08 / 1.04).abs() < 1e-6);
    }
}
