//! Rough dielectric interface with every NDF family (issue 4, item 4): χ² of sampling vs pdf
//! of the single-scattering model (both sides, both transport modes, several α), generalised
//! reciprocity and sample weights, albedo ≤ 1, and energy conservation of the
//! multiple-scattering walk, for Beckmann, GGX and the numerical NDFs (Student-t, shifted,
//! tabulated, hybrid).
//!
//! Default tier: a representative subset (every NDF family once, alternating side and mode).
//! Full sweep (`#[ignore]`): `cargo test -p opal --release --test rough_dielectric_ndfs --
//! --ignored` (see docs/testing.md).

use opal::bsdf::microfacet::{Ndfs, Profile};
use opal::bsdf::rough_dielectric::{RoughDielectric, Shadowing};
use opal::bsdf::rough_dielectric_ms::RoughDielectricMs;
use opal::bsdf::{Bxdf, TransportMode};
use opal::math::{DVec3, Vec3, spherical_direction};
use opal::sampling::Rng;
use opal::validate::chi2::{Chi2Test, SphereFn3};
use opal::validate::quadrature::integrate_z_range;

/// A family at roughness `alpha` (the tabulated ones have a fixed shape, scaled by α where a
/// base has one).
fn ndf(family: &str, alpha: f64) -> Ndfs {
    let p = match family {
        "beckmann" => return Ndfs::beckmann(alpha as f32),
        "ggx" => return Ndfs::ggx(alpha as f32),
        "student3" => Profile::StudentT { alpha, gamma: 3.0 },
        "student8" => Profile::StudentT { alpha, gamma: 8.0 },
        "shifted" => Profile::Shifted { base: Box::new(Profile::Ggx { alpha }), delta: 0.25 },
        // a Gaussian-like table on 5° nodes, width ∝ α, with a small floor (heavy tail)
        "table" => {
            let w = (alpha * 50.0).to_radians().max(0.1);
            Profile::Table {
                theta: (0..=18).map(|i| (i as f64 * 5.0).to_radians()).collect(),
                d: (0..=18).map(|i| (-((i as f64 * 5.0).to_radians() / w).powi(2)).exp() + 0.02).collect(),
            }
        }
        "hybrid" => Profile::Hybrid {
            base: Box::new(Profile::Beckmann { alpha }),
            theta: vec![0.0, 0.1, 0.2],
            d: vec![1.0, 2.5, 1.6].into_iter().map(|v| v / (std::f64::consts::PI * alpha * alpha)).collect(),
        },
        _ => unreachable!(),
    };
    Ndfs::numeric(p).unwrap()
}

const FAMILIES: &[&str] = &["beckmann", "ggx", "student3", "student8", "shifted", "table", "hybrid"];

#[allow(clippy::too_many_arguments)]
fn chi2_case(
    fam: &str,
    alpha: f64,
    theta: f32,
    side: f32,
    mode: TransportMode,
    sh: Shadowing,
    num_tests: u32,
    seed: u64,
) {
    let b = RoughDielectric::new(ndf(fam, alpha), 1.49, sh).unwrap();
    let mut wo = spherical_direction(theta, 0.4);
    wo.z *= side;
    let name = format!("rdn_{fam}_{alpha}_{theta}_{side}_{mode:?}");
    let mut t = Chi2Test::new(&name, 120_000, 16);
    t.num_tests = num_tests;
    t.seed = seed;
    t.quad_subdiv = 16;
    let r = t.run3(&SphereFn3 {
        sample: &|u, uc| b.sample(wo, uc, u, mode).map(|s| s.wi),
        pdf: &|wi| b.pdf(wo, wi, mode) as f64,
    });
    assert!(r.passed, "{name}: {r:?}");
    // the pdf integrates to the probability that sampling succeeds
    assert!(r.pdf_integral <= 1.0 + 2e-3 && r.pdf_integral > 0.5, "{name}: ∫pdf = {}", r.pdf_integral);
}

/// Default tier: every family once at α = 0.5 (shifted: its base GGX 0.5), alternating the
/// side, the transport mode and the shadowing form; θo = 0.3 and 1.2.
#[test]
fn chi2_every_ndf_representative() {
    let mut k = 0u64;
    let n = (FAMILIES.len() * 2) as u32;
    for fam in FAMILIES {
        for theta in [0.3f32, 1.2] {
            let side = if k.is_multiple_of(2) { 1.0 } else { -1.0 };
            let mode =
                if (k / 2).is_multiple_of(2) { TransportMode::Radiance } else { TransportMode::Importance };
            let sh = if k.is_multiple_of(3) { Shadowing::HeightCorrelated } else { Shadowing::Separable };
            chi2_case(fam, 0.5, theta, side, mode, sh, n, 900 + k);
            k += 1;
        }
    }
}

/// Full sweep: every family × α ∈ {0.3, 0.6, 1.0} × θo ∈ {0.3, 0.9, 1.25} × both sides × both
/// modes (separable G).
#[test]
#[ignore]
fn chi2_every_ndf_full() {
    let mut cases = Vec::new();
    for fam in FAMILIES {
        for alpha in [0.3, 0.6, 1.0] {
            for theta in [0.3f32, 0.9, 1.25] {
                for side in [1.0f32, -1.0] {
                    for mode in [TransportMode::Radiance, TransportMode::Importance] {
                        cases.push((fam, alpha, theta, side, mode));
                    }
                }
            }
        }
    }
    let n = cases.len() as u32;
    for (k, (fam, alpha, theta, side, mode)) in cases.into_iter().enumerate() {
        chi2_case(fam, alpha, theta, side, mode, Shadowing::Separable, n, 5000 + k as u64);
    }
}

/// Generalised reciprocity `f(wo,wi)/n_o² = f(wi,wo)/n_i²`, the adjoint identity
/// `f(wo,wi,Radiance) = f(wi,wo,Importance)`, and `sample`'s weight = eval·|cos|/pdf, for
/// every family and both shadowing forms.
#[test]
fn reciprocity_and_weights_every_ndf() {
    let mut rng = Rng::new(77, 0, 0);
    for fam in FAMILIES {
        for sh in [Shadowing::Separable, Shadowing::HeightCorrelated] {
            let b = RoughDielectric::new(ndf(fam, 0.5), 1.49, sh).unwrap();
            let n = |w: Vec3| if w.z > 0.0 { 1.0 } else { b.eta };
            let mut checked = 0;
            for _ in 0..1500 {
                let wo = opal::sampling::square_to_uniform_sphere(rng.next_2d());
                let mode =
                    if rng.next_f32() < 0.5 { TransportMode::Radiance } else { TransportMode::Importance };
                let Some(s) = b.sample(wo, rng.next_f32(), rng.next_2d(), mode) else { continue };
                let w = b.eval(wo, s.wi, mode)[0] * s.wi.z.abs() / b.pdf(wo, s.wi, mode);
                assert!(
                    (w - s.weight()[0]).abs() <= 2e-3 * w.max(1e-3),
                    "{fam}: weight {w} {:?}",
                    s.weight()
                );
                let fr = b.eval(wo, s.wi, TransportMode::Radiance)[0];
                let fi = b.eval(s.wi, wo, TransportMode::Importance)[0];
                assert!((fr - fi).abs() <= 1e-3 * fr.max(1e-6), "{fam}: adjoint {fr} {fi}");
                let a = fr / (n(wo) * n(wo));
                let c = b.eval(s.wi, wo, TransportMode::Radiance)[0] / (n(s.wi) * n(s.wi));
                assert!((a - c).abs() <= 1e-3 * a.max(1e-6), "{fam}: reciprocity {a} {c}");
                checked += 1;
            }
            assert!(checked > 1000, "{fam}: only {checked} samples succeeded");
        }
    }
}

/// Single scattering only loses energy: R + T ≤ 1 (quadrature of eval·cos, importance mode),
/// for every family, from both sides.
#[test]
fn single_scattering_albedo_at_most_one_every_ndf() {
    for fam in FAMILIES {
        let b = RoughDielectric::new(ndf(fam, 0.5), 1.49, Shadowing::Separable).unwrap();
        for theta in [0.0f32, 0.8, 1.3] {
            for side in [1.0f32, -1.0] {
                let mut wo = spherical_direction(theta, 0.0);
                wo.z *= side;
                let f = |w: DVec3| b.eval(wo, w.as_vec3(), TransportMode::Importance)[0] as f64 * w.z.abs();
                let edges = [-1.0, -0.999, -0.99, -0.95, -0.8, -0.5, 0.0, 0.5, 0.8, 0.95, 0.99, 0.999, 1.0];
                let a: f64 = edges.windows(2).map(|e| integrate_z_range(e[0], e[1], 64, 256, f)).sum();
                assert!(a <= 1.0 + 3e-3 && a > 0.3, "{fam} θ={theta} side {side}: albedo {a}");
            }
        }
    }
}

/// The multiple-scattering walk keeps the energy (R + T ≥ 0.995) for the numerical NDFs too.
#[test]
fn multiple_scattering_conserves_energy_every_ndf() {
    for fam in ["student3", "shifted", "table", "hybrid"] {
        let b = RoughDielectricMs::new(ndf(fam, 0.8), 1.49).unwrap();
        for theta in [0.0f32, 0.8, 1.4] {
            for side in [1.0f32, -1.0] {
                let mut wo = spherical_direction(theta, 0.3);
                wo.z *= side;
                let mut rng = Rng::new(5, (theta * 100.0) as u64, side as u64);
                let n = 10_000;
                let ok = (0..n).filter(|_| b.sample_dir(wo, &mut rng).is_some()).count();
                let frac = ok as f64 / n as f64;
                assert!(frac >= 0.995, "{fam} θ={theta} side {side}: R+T = {frac}");
            }
        }
    }
}
