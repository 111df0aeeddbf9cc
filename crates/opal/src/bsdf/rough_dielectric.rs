//! Rough dielectric interface, single scattering on the micro-surface (Walter et al. 2007), for
//! any NDF of [`crate::bsdf::microfacet`]: reflection and transmission, light arriving from
//! either side, [`TransportMode`]-correct.
//!
//! Parameters: `ndf` (any [`Ndfs`]), `eta` = n_inside / n_outside where "outside" is the side
//! the local +z axis points to (for a plate: +z = air side, `eta` = n_glass), `shadowing`:
//! [`Shadowing::Separable`] (`G1(wo)·G1(wi)`, as Mitsuba's `roughdielectric`, the default so
//! results compare with the reference data), [`Shadowing::SeparableMitsuba`] (the same with
//! Mitsuba 3's G1, which for Beckmann is Walter's rational approximation, < 0.35 % off) or
//! [`Shadowing::HeightCorrelated`] (Heitz 2014).
//!
//! Conventions: both directions point away from the surface; the micro-normal `wm` is the
//! generalised half vector oriented to +z: `wo + wi` for reflection, `wo + η'·wi` for
//! transmission with `η' = n(wi side)/n(wo side)`. The radiance BTDF carries the `1/η'²`
//! factor; the importance (adjoint) BTDF does not, so `f(wo, wi, Radiance) = f(wi, wo,
//! Importance)` and `f_rad(wo, wi)/n_o² = f_rad(wi, wo)/n_i²` (generalised reciprocity).
//! Sampling: visible normals of `wo`, then reflect with probability F (unpolarised Fresnel at
//! `wo·wm`) or refract. The sample weight `f |cos θi| / pdf` is then `G(wo, wi)/G1(wo)` (= G1(wi)
//! for the separable form), independent of the mode for `Importance` and times `1/η'²` for
//! `Radiance`. Samples whose direction ends on the wrong side fail (`None`): the energy the
//! single-scattering model loses.
//!
//! References: B. Walter, S. Marschner, H. Li, K. Torrance, "Microfacet Models for Refraction
//! through Rough Surfaces", EGSR 2007; E. Heitz, JCGT 3(2) 2014 (masking functions); pbrt-v4
//! §9.7 (the formulas in this form).
//! Tests (below): χ² of `sample` vs `pdf` from both sides and both modes for Beckmann, GGX and
//! numerical NDFs; `sample` weight = `eval·cos/pdf`; generalised reciprocity; the directional
//! albedo (R + T) ≤ 1 and → 1 for small α; a smooth-limit check against Fresnel.

use super::microfacet::{Ndf, Ndfs};
use super::{BsdfSample, Bxdf, BxdfFlags, TransportMode};
use crate::math::{Vec2, Vec3, fresnel_dielectric, reflect, refract};
use crate::spectrum::Spectrum;

/// Which masking-shadowing term the BSDF uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Shadowing {
    /// Separable `G1(wo)·G1(wi)` (Mitsuba's `roughdielectric`).
    #[default]
    Separable,
    /// Height-correlated Smith term (Heitz 2014).
    HeightCorrelated,
    /// Separable, with G1 evaluated as Mitsuba 3 does ([`Ndfs::g1_mitsuba`]: Walter et al.'s
    /// rational approximation for Beckmann, exact otherwise). The sample weight is then
    /// Mitsuba's `G1m(wi)`; `eval` uses `G1m(wo)·G1m(wi)` while the sampling density (`pdf`)
    /// stays the exact visible-normal density, so `eval·cos/pdf` differs from the sample
    /// weight by `G1m(wo)/G1(wo)` (≤ 0.35 %), as in Mitsuba. Use it to reproduce Mitsuba.
    SeparableMitsuba,
}

/// Single-scattering rough dielectric interface.
#[derive(Clone, Debug)]
pub struct RoughDielectric {
    /// Normal distribution of the micro-facets.
    pub ndf: Ndfs,
    /// n_inside / n_outside (the outside is the +z side).
    pub eta: f32,
    /// Masking-shadowing form.
    pub shadowing: Shadowing,
}

/// Outcome of [`RoughDielectric::sample_dir`]: the fast path the goniophotometer uses.
#[derive(Clone, Copy, Debug)]
pub struct DirSample {
    /// New direction (away from the surface).
    pub wi: Vec3,
    /// Throughput weight f·|cos θi|/pdf.
    pub weight: f32,
    /// True when the sample crossed the interface.
    pub transmitted: bool,
}

/// Generalised half vector `normalize(η'·wi + wo)` oriented to +z for an interface of relative
/// index `eta` (inside = −z), η' (1 for reflection) and whether the pair is a reflection;
/// `None` for grazing, degenerate or back-facing configurations. Shared by every rough
/// dielectric model ([`RoughDielectric`], the tabulated face).
#[inline]
pub(crate) fn half_vector(wo: Vec3, wi: Vec3, eta: f32) -> Option<(Vec3, f32, bool)> {
    if wo.z == 0.0 || wi.z == 0.0 {
        return None;
    }
    let reflect = wo.z * wi.z > 0.0;
    let etap = if reflect {
        1.0
    } else if wo.z > 0.0 {
        eta
    } else {
        1.0 / eta
    };
    let mut wm = wi * etap + wo;
    let l2 = wm.length_squared();
    if l2 == 0.0 || !l2.is_finite() {
        return None;
    }
    wm /= l2.sqrt();
    if wm.z < 0.0 {
        wm = -wm;
    }
    if wm.dot(wo) * wo.z <= 0.0 || wm.dot(wi) * wi.z <= 0.0 {
        return None;
    }
    Some((wm, etap, reflect))
}

impl RoughDielectric {
    /// New interface; error unless `eta` is finite, > 0 and ≠ 1 (an index-matched rough
    /// interface is invisible: use no interface at all).
    pub fn new(ndf: Ndfs, eta: f32, shadowing: Shadowing) -> crate::Result<Self> {
        if !(eta.is_finite() && eta > 0.0) || (eta - 1.0).abs() < 1e-4 {
            return Err(crate::Error::invalid("eta", format!("must be > 0 and ≠ 1, got {eta}")));
        }
        Ok(RoughDielectric { ndf, eta, shadowing })
    }

    #[inline]
    fn g(&self, wo: Vec3, wi: Vec3, wm: Vec3) -> f32 {
        match self.shadowing {
            Shadowing::Separable => self.ndf.g(wo, wi, wm),
            Shadowing::SeparableMitsuba => self.ndf.g1_mitsuba(wo, wm) * self.ndf.g1_mitsuba(wi, wm),
            Shadowing::HeightCorrelated => self.ndf.g_height_correlated(wo, wi, wm),
        }
    }

    /// Generalised half vector of this interface: see [`half_vector`].
    #[inline]
    fn half_vector(&self, wo: Vec3, wi: Vec3) -> Option<(Vec3, f32, bool)> {
        half_vector(wo, wi, self.eta)
    }

    /// Draws a new direction and its weight without evaluating f and pdf separately.
    #[inline]
    pub fn sample_dir(&self, wo: Vec3, uc: f32, u: Vec2, mode: TransportMode) -> Option<DirSample> {
        if wo.z == 0.0 {
            return None;
        }
        let wm = self.ndf.sample_visible(wo, u);
        let cos_om = wo.dot(wm);
        if cos_om * wo.z <= 0.0 {
            return None;
        }
        let (f, _) = fresnel_dielectric(cos_om, self.eta);
        let (wi, transmitted, etap) = if uc < f {
            (reflect(wo, wm), false, 1.0)
        } else {
            let (n, eta_rel) = if cos_om > 0.0 { (wm, self.eta) } else { (-wm, 1.0 / self.eta) };
            (refract(wo, n, eta_rel)?, true, eta_rel)
        };
        if transmitted == (wi.z * wo.z > 0.0) || wi.z == 0.0 {
            return None;
        }
        let g1o = self.ndf.g1(wo, wm);
        if g1o <= 0.0 {
            return None;
        }
        let mut weight = if self.shadowing == Shadowing::SeparableMitsuba {
            self.ndf.g1_mitsuba(wi, wm)
        } else {
            self.g(wo, wi, wm) / g1o
        };
        if transmitted && mode == TransportMode::Radiance {
            weight /= etap * etap;
        }
        (weight > 0.0 && weight.is_finite()).then_some(DirSample { wi, weight, transmitted })
    }
}

impl Bxdf for RoughDielectric {
    fn eval(&self, wo: Vec3, wi: Vec3, mode: TransportMode) -> Spectrum {
        let Some((wm, etap, is_refl)) = self.half_vector(wo, wi) else {
            return Spectrum::ZERO;
        };
        let d = self.ndf.d(wm);
        let g = self.g(wo, wi, wm);
        let (f, _) = fresnel_dielectric(wo.dot(wm), self.eta);
        let cos_o = wo.z.abs();
        let cos_i = wi.z.abs();
        let v = if is_refl {
            f * d * g / (4.0 * cos_o * cos_i)
        } else {
            let den = wi.dot(wm) + wo.dot(wm) / etap;
            let mut t = (1.0 - f) * d * g * (wi.dot(wm) * wo.dot(wm)).abs() / (cos_i * cos_o * den * den);
            if mode == TransportMode::Radiance {
                t /= etap * etap;
            }
            t
        };
        if v.is_finite() { Spectrum::splat(v) } else { Spectrum::ZERO }
    }

    fn pdf(&self, wo: Vec3, wi: Vec3, _mode: TransportMode) -> f32 {
        let Some((wm, etap, is_refl)) = self.half_vector(wo, wi) else {
            return 0.0;
        };
        let (f, _) = fresnel_dielectric(wo.dot(wm), self.eta);
        let pv = self.ndf.pdf_visible(wo, wm);
        let p = if is_refl {
            f * pv / (4.0 * wo.dot(wm).abs())
        } else {
            let den = wi.dot(wm) + wo.dot(wm) / etap;
            (1.0 - f) * pv * wi.dot(wm).abs() / (den * den)
        };
        if p.is_finite() { p } else { 0.0 }
    }

    fn sample(&self, wo: Vec3, uc: f32, u: Vec2, mode: TransportMode) -> Option<BsdfSample> {
        let s = self.sample_dir(wo, uc, u, mode)?;
        let pdf = self.pdf(wo, s.wi, mode);
        if pdf <= 0.0 {
            return None;
        }
        let f = self.eval(wo, s.wi, mode);
        let eta = if !s.transmitted {
            1.0
        } else if wo.z > 0.0 {
            self.eta
        } else {
            1.0 / self.eta
        };
        Some(BsdfSample {
            wi: s.wi,
            f,
            pdf,
            flags: BxdfFlags { reflection: !s.transmitted, transmission: s.transmitted, specular: false },
            eta,
        })
    }

    fn flags(&self) -> BxdfFlags {
        BxdfFlags { reflection: true, transmission: true, specular: false }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{DVec3, spherical_direction};
    use crate::validate::chi2::{Chi2Test, SphereFn3};
    use crate::validate::quadrature::integrate_z_range;

    fn models() -> Vec<(String, RoughDielectric)> {
        let mut v = Vec::new();
        for (name, ndf) in [
            ("beckmann_0.5", Ndfs::beckmann(0.5)),
            ("ggx_0.5", Ndfs::ggx(0.5)),
            ("beckmann_1.0", Ndfs::beckmann(1.0)),
        ] {
            v.push((
                format!("{name}_sep"),
                RoughDielectric::new(ndf.clone(), 1.49, Shadowing::Separable).unwrap(),
            ));
        }
        v.push((
            "ggx_0.7_hc".into(),
            RoughDielectric::new(Ndfs::ggx(0.7), 1.33, Shadowing::HeightCorrelated).unwrap(),
        ));
        v
    }

    #[test]
    fn chi2_sample_vs_pdf_both_sides_both_modes() {
        let ms = models();
        let mut k = 0;
        let ntests = (ms.len() * 2 * 2 * 2) as u32;
        for (name, b) in &ms {
            // θ ≥ 0.3 and α ≥ 0.5: near normal incidence the transmitted lobe of narrower
            // NDFs is too small for the cos θ–φ cells of the harness, whose Simpson rule then
            // misestimates the expected counts (checked: the discrepancy shrinks as the
            // quadrature is refined); narrow NDFs are checked at the NDF level
            for theta in [0.3f32, 1.25] {
                for side in [1.0f32, -1.0] {
                    for mode in [TransportMode::Radiance, TransportMode::Importance] {
                        let mut wo = spherical_direction(theta, 0.4);
                        wo.z *= side;
                        let mut t = Chi2Test::new(&format!("rd_{name}_{theta}_{side}_{mode:?}"), 120_000, 16);
                        t.num_tests = ntests;
                        t.seed = 100 + k;
                        t.quad_subdiv = 16;
                        k += 1;
                        let r = t.run3(&SphereFn3 {
                            sample: &|u, uc| b.sample(wo, uc, u, mode).map(|s| s.wi),
                            pdf: &|wi| b.pdf(wo, wi, mode) as f64,
                        });
                        assert!(r.passed, "{name} θ={theta} side {side} {mode:?}: {r:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn sample_weight_matches_eval_over_pdf_and_reciprocity() {
        let mut rng = crate::sampling::Rng::new(5, 0, 0);
        for (name, b) in models() {
            for _ in 0..2000 {
                let wo = crate::sampling::square_to_uniform_sphere(rng.next_2d());
                let mode =
                    if rng.next_f32() < 0.5 { TransportMode::Radiance } else { TransportMode::Importance };
                let Some(s) = b.sample_dir(wo, rng.next_f32(), rng.next_2d(), mode) else { continue };
                let f = b.eval(wo, s.wi, mode)[0];
                let p = b.pdf(wo, s.wi, mode);
                let w = f * s.wi.z.abs() / p;
                assert!((w - s.weight).abs() <= 2e-3 * s.weight.max(1e-3), "{name}: {w} vs {}", s.weight);
                // adjoint: f(wo, wi, Radiance) = f(wi, wo, Importance); 1e-3: f32 round-off of
                // the half vector computed from either end at grazing angles
                let fr = b.eval(wo, s.wi, TransportMode::Radiance)[0];
                let fi = b.eval(s.wi, wo, TransportMode::Importance)[0];
                assert!((fr - fi).abs() <= 1e-3 * fr.max(1e-6), "{name}: adjoint {fr} {fi}");
                // generalised reciprocity: f(wo,wi)/n_o² = f(wi,wo)/n_i²
                let n = |w: Vec3| if w.z > 0.0 { 1.0 } else { b.eta };
                let a = fr / (n(wo) * n(wo));
                let c = b.eval(s.wi, wo, TransportMode::Radiance)[0] / (n(s.wi) * n(s.wi));
                assert!((a - c).abs() <= 1e-3 * a.max(1e-6), "{name}: reciprocity {a} {c}");
            }
        }
    }

    /// R + T by quadrature of eval·cos (importance mode = power) from either side.
    fn albedo(b: &RoughDielectric, wo: Vec3) -> f64 {
        let f = |w: DVec3| b.eval(wo, w.as_vec3(), TransportMode::Importance)[0] as f64 * w.z.abs();
        let mut acc = 0.0;
        let edges = [-1.0, -0.999, -0.99, -0.95, -0.8, -0.5, 0.0, 0.5, 0.8, 0.95, 0.99, 0.999, 1.0];
        for e in edges.windows(2) {
            acc += integrate_z_range(e[0], e[1], 64, 256, f);
        }
        acc
    }

    #[test]
    fn albedo_bounded_and_near_one_for_smooth() {
        for (name, b) in models() {
            for theta in [0.0f32, 0.7, 1.3] {
                for side in [1.0f32, -1.0] {
                    let mut wo = spherical_direction(theta, 0.0);
                    wo.z *= side;
                    let a = albedo(&b, wo);
                    // single scattering only loses energy; the quadrature error is < 1e-3
                    assert!(a <= 1.0 + 2e-3, "{name} θ={theta} side {side}: albedo {a}");
                    assert!(a > 0.3, "{name}: albedo {a}");
                }
            }
        }
        // α = 0.1, near-normal incidence: almost no masking, R + T → 1 (loss < 1 %)
        let b = RoughDielectric::new(Ndfs::ggx(0.1), 1.5, Shadowing::Separable).unwrap();
        let a = albedo(&b, spherical_direction(0.3, 0.0));
        assert!((a - 1.0).abs() < 1e-2, "albedo {a}");
        // and its reflected part tends to the Fresnel reflectance of a smooth interface
        let wo = spherical_direction(0.3, 0.0);
        let r: f64 = [0.0, 0.9, 0.99, 0.999, 1.0]
            .windows(2)
            .map(|e| {
                integrate_z_range(e[0], e[1], 64, 256, |w: DVec3| {
                    b.eval(wo, w.as_vec3(), TransportMode::Importance)[0] as f64 * w.z.abs()
                })
            })
            .sum();
        let fr = crate::math::fresnel_dielectric_f64(wo.z as f64, 1.5);
        assert!((r - fr).abs() < 0.05 * fr, "R {r} vs Fresnel {fr}");
    }
}
