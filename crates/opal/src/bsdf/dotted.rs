//! Dotted face: an **area mixture** of two interface models. A fraction `coverage` = f of the
//! face carries model A (the rough dots: a [`RoughDielectric`] or [`RoughDielectricMs`] with any
//! NDF), the rest 1 − f model B (polished: [`SmoothDielectric`], or a second rough interface,
//! which makes the face a mixture of two NDFs). Light-guide plates are made uniform this way.
//!
//! Model (see `docs/decisions/dotted-area-mixture.md` for why an area mixture and not an NDF
//! mixture): the dots are much larger than the micro-facets and than the wavelength, so a ray
//! meets either a dot or the land between them with probabilities f and 1 − f, and each area
//! keeps its own Smith masking:
//! `f(wo, wi) = f·f_A(wo, wi) + (1 − f)·f_B(wo, wi)`, `pdf = f·pdf_A + (1 − f)·pdf_B`.
//! Both components must share the refractive index (one material); their Fresnel terms are
//! then the same at the same micro-normal.
//!
//! Sampling: `uc < f` samples A with `uc/f`, else B with `(uc − f)/(1 − f)` (one-sample model,
//! the lobe choice reuses `uc`, so the number of random numbers per interaction is the
//! component's). A sample of a single-scattering or tabulated component returns the mixture's
//! `f` and `pdf` (its weight is the mixture's `f cos/pdf`, unbiased for the whole face, and
//! `pdf` agrees with [`Bxdf::pdf`] for MIS). A delta sample of a smooth component, and a sample
//! of a multiple-scattering component (whose `eval` is stochastic and `pdf` approximate),
//! return the component's `f` and `pdf` times its probability, so the throughput weight is the
//! component's (exact: 1 or 1/η'² for the random walk). `eval`/`pdf` of delta lobes
//! are zero as for [`SmoothDielectric`]. Transport modes: each component handles its mode; the
//! mixture is linear, so the adjoint relation `f(wo, wi, Radiance) = f(wi, wo, Importance)` and
//! generalised reciprocity carry over.
//!
//! Tests (below): χ² of `sample` vs `pdf` from both sides, both modes, rough + polished and
//! rough + rough (GGX + Beckmann, GGX + Student-t); sample weight = `eval·cos/pdf`; adjoint
//! and generalised reciprocity; energy (R + T ≤ 1, and = f·albedo_A + (1 − f)·1 with a
//! polished land); the furnace of a multiple-scattering dot (R + T = 1).

use super::{BsdfSample, Bxdf, BxdfFlags, Bxdfs, TransportMode};
use crate::math::{Vec2, Vec3};
use crate::spectrum::Spectrum;

/// Area mixture of two interface models (see the module documentation).
#[derive(Clone, Debug)]
pub struct Dotted {
    /// Fraction f ∈ [0, 1] of the face covered by model A.
    pub coverage: f32,
    /// Model of the covered fraction (the dots).
    pub a: Box<Bxdfs>,
    /// Model of the rest (the land between the dots; polished for a classic dotted face).
    pub b: Box<Bxdfs>,
}

impl Dotted {
    /// New dotted face; error unless `coverage` ∈ [0, 1] and both components are dielectric
    /// interfaces (rough, multiple-scattering, smooth or tabulated) of the same `eta`.
    pub fn new(coverage: f32, a: Bxdfs, b: Bxdfs) -> crate::Result<Self> {
        if !(coverage.is_finite() && (0.0..=1.0).contains(&coverage)) {
            return Err(crate::Error::invalid("coverage", format!("must be in [0, 1], got {coverage}")));
        }
        let (ea, eb) = (interface_eta(&a)?, interface_eta(&b)?);
        if (ea - eb).abs() > 1e-5 * ea {
            return Err(crate::Error::invalid(
                "dotted",
                format!("both areas must have the same index ratio, got {ea} and {eb}"),
            ));
        }
        Ok(Dotted { coverage, a: Box::new(a), b: Box::new(b) })
    }

    /// Relative index n_inside / n_outside of the face.
    pub fn eta(&self) -> f32 {
        interface_eta(&self.a).unwrap_or(1.0)
    }
}

/// η of a dielectric interface model; error for anything else.
fn interface_eta(b: &Bxdfs) -> crate::Result<f32> {
    match b {
        Bxdfs::RoughDielectric(r) => Ok(r.eta),
        Bxdfs::RoughDielectricMs(r) => Ok(r.single_scattering().eta),
        Bxdfs::SmoothDielectric(s) => Ok(s.eta),
        Bxdfs::Tabulated(t) => Ok(t.eta()),
        _ => Err(crate::Error::invalid(
            "dotted",
            "each area must be a dielectric interface (rough, smooth or tabulated)",
        )),
    }
}

impl Bxdf for Dotted {
    fn eval(&self, wo: Vec3, wi: Vec3, mode: TransportMode) -> Spectrum {
        let f = self.coverage;
        let mut v = Spectrum::ZERO;
        if f > 0.0 {
            v += self.a.eval(wo, wi, mode) * f;
        }
        if f < 1.0 {
            v += self.b.eval(wo, wi, mode) * (1.0 - f);
        }
        v
    }

    fn pdf(&self, wo: Vec3, wi: Vec3, mode: TransportMode) -> f32 {
        let f = self.coverage;
        let mut p = 0.0;
        if f > 0.0 {
            p += f * self.a.pdf(wo, wi, mode);
        }
        if f < 1.0 {
            p += (1.0 - f) * self.b.pdf(wo, wi, mode);
        }
        p
    }

    fn sample(&self, wo: Vec3, uc: f32, u: Vec2, mode: TransportMode) -> Option<BsdfSample> {
        let f = self.coverage;
        let (first, w, ucr) = if uc < f {
            (true, f, (uc / f).min(ONE_MINUS_EPS))
        } else {
            (false, 1.0 - f, ((uc - f) / (1.0 - f)).clamp(0.0, ONE_MINUS_EPS))
        };
        let comp = if first { &self.a } else { &self.b };
        let mut s = comp.sample(wo, ucr, u, mode)?;
        if s.flags.specular || matches!(**comp, Bxdfs::RoughDielectricMs(_)) {
            s.f *= w;
            s.pdf *= w;
        } else {
            s.f = self.eval(wo, s.wi, mode);
            s.pdf = self.pdf(wo, s.wi, mode);
            if s.pdf <= 0.0 {
                return None;
            }
        }
        Some(s)
    }

    fn flags(&self) -> BxdfFlags {
        let (fa, fb) = (self.a.flags(), self.b.flags());
        BxdfFlags {
            reflection: fa.reflection || fb.reflection,
            transmission: fa.transmission || fb.transmission,
            specular: (fa.specular && self.coverage > 0.0) || (fb.specular && self.coverage < 1.0),
        }
    }
}

/// Largest f32 below 1 (a rescaled `uc` must stay in [0, 1)).
const ONE_MINUS_EPS: f32 = 1.0 - f32::EPSILON / 2.0;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsdf::microfacet::{Ndfs, Profile};
    use crate::bsdf::rough_dielectric::Shadowing;
    use crate::bsdf::{RoughDielectric, RoughDielectricMs, SmoothDielectric};
    use crate::math::{DVec3, spherical_direction};
    use crate::validate::chi2::{Chi2Test, SphereFn3};
    use crate::validate::quadrature::integrate_z_range;

    fn rough(ndf: Ndfs, eta: f32) -> Bxdfs {
        Bxdfs::RoughDielectric(RoughDielectric::new(ndf, eta, Shadowing::Separable).unwrap())
    }

    fn models() -> Vec<(&'static str, Dotted)> {
        let eta = 1.52;
        let student = Ndfs::numeric(Profile::StudentT { alpha: 0.5, gamma: 3.0 }).unwrap();
        vec![
            (
                "ggx0.5+polished",
                Dotted::new(
                    0.3,
                    rough(Ndfs::ggx(0.5), eta),
                    Bxdfs::SmoothDielectric(SmoothDielectric::new(eta).unwrap()),
                )
                .unwrap(),
            ),
            (
                "ggx0.6+beckmann0.5",
                Dotted::new(0.4, rough(Ndfs::ggx(0.6), eta), rough(Ndfs::beckmann(0.5), eta)).unwrap(),
            ),
            ("student0.5+ggx0.7", Dotted::new(0.7, rough(student, eta), rough(Ndfs::ggx(0.7), eta)).unwrap()),
        ]
    }

    #[test]
    fn chi2_sample_vs_pdf_both_sides_both_modes() {
        let ms = models();
        let ntests = (ms.len() * 2 * 2 * 2) as u32;
        let mut k = 0;
        for (name, b) in &ms {
            // same angles and cell sizes as the rough dielectric's own test (α ≥ 0.5: the
            // transmitted lobes are wide enough for the harness's cells)
            for theta in [0.3f32, 1.25] {
                for side in [1.0f32, -1.0] {
                    for mode in [TransportMode::Radiance, TransportMode::Importance] {
                        let mut wo = spherical_direction(theta, 0.4);
                        wo.z *= side;
                        let mut t =
                            Chi2Test::new(&format!("dotted_{name}_{theta}_{side}_{mode:?}"), 120_000, 16);
                        t.num_tests = ntests;
                        t.seed = 300 + k;
                        t.quad_subdiv = 16;
                        k += 1;
                        // delta samples of a polished land are not part of the density: the
                        // harness counts them as failed samples
                        let r = t.run3(&SphereFn3 {
                            sample: &|u, uc| {
                                b.sample(wo, uc, u, mode).filter(|s| !s.flags.specular).map(|s| s.wi)
                            },
                            pdf: &|wi| b.pdf(wo, wi, mode) as f64,
                        });
                        assert!(r.passed, "{name} θ={theta} side {side} {mode:?}: {r:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn sample_weight_adjoint_and_reciprocity() {
        let mut rng = crate::sampling::Rng::new(11, 0, 0);
        for (name, b) in models() {
            let eta = b.eta();
            let (mut n_delta, mut n_rough) = (0, 0);
            for _ in 0..3000 {
                let wo = crate::sampling::square_to_uniform_sphere(rng.next_2d());
                let mode =
                    if rng.next_f32() < 0.5 { TransportMode::Radiance } else { TransportMode::Importance };
                let Some(s) = b.sample(wo, rng.next_f32(), rng.next_2d(), mode) else { continue };
                if s.flags.specular {
                    // a polished-land sample keeps the smooth interface's weight (1, or 1/η'²
                    // for radiance refraction) and its probability is scaled by 1 − f
                    let etap = s.eta;
                    let expect = if s.flags.transmission && mode == TransportMode::Radiance {
                        1.0 / (etap * etap)
                    } else {
                        1.0
                    };
                    assert!((s.weight()[0] - expect).abs() < 1e-4, "{name}: delta weight {:?}", s.weight());
                    assert!(s.pdf <= 1.0 - b.coverage + 1e-6);
                    n_delta += 1;
                    continue;
                }
                n_rough += 1;
                let f = b.eval(wo, s.wi, mode)[0];
                let p = b.pdf(wo, s.wi, mode);
                assert!((f - s.f[0]).abs() <= 1e-6 * f.max(1e-6) && (p - s.pdf).abs() <= 1e-6 * p);
                let fr = b.eval(wo, s.wi, TransportMode::Radiance)[0];
                let fi = b.eval(s.wi, wo, TransportMode::Importance)[0];
                assert!((fr - fi).abs() <= 1e-3 * fr.max(1e-6), "{name}: adjoint {fr} {fi}");
                let n = |w: Vec3| if w.z > 0.0 { 1.0 } else { eta };
                let a = fr / (n(wo) * n(wo));
                let c = b.eval(s.wi, wo, TransportMode::Radiance)[0] / (n(s.wi) * n(s.wi));
                assert!((a - c).abs() <= 1e-3 * a.max(1e-6), "{name}: reciprocity {a} {c}");
            }
            assert!(n_rough > 600, "{name}: {n_rough} rough samples");
            if name.contains("polished") {
                // the land is hit with probability 1 − f = 0.7
                assert!(
                    (n_delta as f64 / (n_delta + n_rough) as f64 - 0.7).abs() < 0.05,
                    "{name}: {n_delta}"
                );
            }
        }
    }

    /// R + T of the non-delta part by quadrature (importance mode = power).
    fn albedo(b: &impl Bxdf, wo: Vec3) -> f64 {
        let f = |w: DVec3| b.eval(wo, w.as_vec3(), TransportMode::Importance)[0] as f64 * w.z.abs();
        let edges = [-1.0, -0.999, -0.99, -0.95, -0.8, -0.5, 0.0, 0.5, 0.8, 0.95, 0.99, 0.999, 1.0];
        edges.windows(2).map(|e| integrate_z_range(e[0], e[1], 64, 256, f)).sum()
    }

    #[test]
    fn energy_is_the_area_weighted_sum() {
        let eta = 1.52;
        let dot = RoughDielectric::new(Ndfs::ggx(0.4), eta, Shadowing::Separable).unwrap();
        let b = Dotted::new(
            0.35,
            Bxdfs::RoughDielectric(dot.clone()),
            Bxdfs::SmoothDielectric(SmoothDielectric::new(eta).unwrap()),
        )
        .unwrap();
        for theta in [0.0f32, 0.7, 1.3] {
            for side in [1.0f32, -1.0] {
                let mut wo = spherical_direction(theta, 0.0);
                wo.z *= side;
                let (a_mix, a_dot) = (albedo(&b, wo), albedo(&dot, wo));
                // the polished land conserves energy (R + T = 1): its share is 1 − f exactly
                assert!((a_mix - 0.35 * a_dot).abs() < 1e-9 + 1e-6 * a_dot, "θ={theta}: {a_mix} vs {a_dot}");
                assert!(0.35 * a_dot + 0.65 <= 1.0 + 2e-3);
                // Monte-Carlo estimate of the total (delta + rough) power from `sample`
                let mut rng = crate::sampling::Rng::new(17, theta.to_bits() as u64, side.to_bits() as u64);
                let n = 200_000;
                let mut e = 0.0f64;
                for _ in 0..n {
                    if let Some(s) = b.sample(wo, rng.next_f32(), rng.next_2d(), TransportMode::Importance) {
                        e += s.weight()[0] as f64;
                    }
                }
                let e = e / n as f64;
                let expect = 0.35 * a_dot + 0.65;
                // σ of the estimate ≈ 0.5/√n ≈ 1.1e-3
                assert!((e - expect).abs() < 5e-3, "θ={theta} side {side}: MC {e} vs {expect}");
            }
        }
    }

    #[test]
    fn multiple_scattering_dots_keep_the_furnace() {
        // a multiple-scattering dot on a polished land loses no energy: R + T = 1 per photon
        // (Monte Carlo over `sample`, importance mode, weights 1 for both components)
        let eta = 1.52;
        let ms = RoughDielectricMs::new(Ndfs::ggx(0.6), eta).unwrap();
        let b = Dotted::new(
            0.4,
            Bxdfs::RoughDielectricMs(ms),
            Bxdfs::SmoothDielectric(SmoothDielectric::new(eta).unwrap()),
        )
        .unwrap();
        let mut rng = crate::sampling::Rng::new(23, 0, 0);
        for theta in [0.2f32, 1.0, 1.4] {
            for side in [1.0f32, -1.0] {
                let mut wo = spherical_direction(theta, 0.5);
                wo.z *= side;
                let n = 4000;
                let mut lost = 0;
                for _ in 0..n {
                    match b.sample(wo, rng.next_f32(), rng.next_2d(), TransportMode::Importance) {
                        Some(s) if s.flags.specular => {
                            assert!((s.weight()[0] - 1.0).abs() < 1e-5);
                        }
                        Some(s) => assert!(s.pdf > 0.0 && s.wi.is_finite()),
                        None => lost += 1,
                    }
                }
                assert_eq!(lost, 0, "θ={theta} side {side}");
            }
        }
    }

    #[test]
    fn refuses_bad_input() {
        let s = || Bxdfs::SmoothDielectric(SmoothDielectric::new(1.5).unwrap());
        assert!(Dotted::new(1.2, rough(Ndfs::ggx(0.3), 1.5), s()).is_err());
        assert!(Dotted::new(f32::NAN, rough(Ndfs::ggx(0.3), 1.5), s()).is_err());
        assert!(Dotted::new(0.3, rough(Ndfs::ggx(0.3), 1.4), s()).is_err());
        assert!(
            Dotted::new(0.3, Bxdfs::Lambert(crate::bsdf::Lambert::new(Spectrum::splat(0.5))), s()).is_err()
        );
    }
}
