//! Fit of the NDF on the Mitsuba 3 reference curves and round trips on synthetic data
//! (Student-t tail, shifted peak, multiple scattering, hybrid).

use opal::bsdf::microfacet::{Ndfs, Profile};
use opal::gonio::{Beam, DetectorGrid, DetectorLayout, Face, Gonio, GonioSetup, Plate, Scattering};
use opal_inverse::measured::Measured;
use opal_inverse::ndf_fit::{Family, FitOn, FitOptions, FitReport, FitSetup, Problem, ScaleSetup, fit};
use std::path::Path;

fn setup(rough_front: bool, photons: u64) -> FitSetup {
    let placeholder = Face::Polished;
    FitSetup {
        plate: Plate {
            ior: 1.49,
            thickness_mm: 2.0,
            absorption_per_mm: 0.0,
            front: placeholder.clone(),
            back: placeholder,
            radius_mm: None,
        },
        rough_front,
        scattering: Scattering::Single,
        beam: Beam { azimuth: 0.0, divergence: 0.5f64.to_radians(), aperture_radius_mm: 1.0 },
        detector_radius: 1f64.to_radians(),
        detector_distance_mm: None,
        photons,
        seed: 7,
        max_interactions: 200,
        fit_on: FitOn::Both,
        floor_rel: 1e-2,
        max_iters: 40,
        coarse_photons: FitSetup::default_coarse(photons),
        scale: ScaleSetup::default(),
        rel_error: 0.0,
    }
}

fn reference(name: &str) -> Measured {
    let p =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../opal/tests/data/gonio").join(format!("{name}.csv"));
    Measured::read(&p).unwrap()
}

/// Prints every candidate and decision of a fit.
fn show(name: &str, problem: &Problem, r: &FitReport, t0: std::time::Instant) {
    for (i, c) in r.candidates.iter().enumerate() {
        eprintln!(
            "{name}: [{i}] {} obj {:.5} | check rms {:.4} noise {:.4} ratio {:.3} χ² {:.1} | {} evals conv {}",
            c.fit.model.describe(),
            c.fit.objective,
            c.check.rms,
            c.check.noise,
            c.check.rms / c.check.noise,
            c.check.chi2,
            c.fit.evaluations,
            c.fit.converged
        );
    }
    for d in &r.decisions {
        let c = &d.comparison;
        eprintln!(
            "{name}: [{}] vs [{}]: Δχ² {:.1} threshold {:.1} (sd {:.1}, inflation {:.2}) → {}",
            d.simple,
            d.rich,
            c.delta_chi2,
            c.threshold,
            c.sd,
            c.inflation,
            if c.accepted { "richer" } else { "simpler" }
        );
    }
    let (ec, ef) = problem.evaluations_by_stage();
    eprintln!(
        "{name}: kept [{}] {} | {} coarse + {} full simulations, {:.1} s",
        r.best,
        r.best().fit.model.describe(),
        ec,
        ef,
        t0.elapsed().as_secs_f64()
    );
}

fn run_case(name: &str, family: Family, alpha: f64, photons: u64) {
    let rough_front = name.ends_with("_rough");
    let t0 = std::time::Instant::now();
    let problem = Problem::new(reference(name), setup(rough_front, photons)).unwrap();
    let r = fit(&problem, &FitOptions::default()).unwrap();
    show(name, &problem, &r, t0);
    let best = &r.best().fit.model;
    let ev = &r.best().check;
    eprintln!(
        "{name}: RESULT family {} α {:.4} (error {:+.2} %) rms/noise {:.3}",
        best.family.name(),
        best.alpha,
        100.0 * (best.alpha / alpha - 1.0),
        ev.rms / ev.noise
    );
    assert_eq!(best.family, family, "{name}: wrong family");
    assert!((best.alpha / alpha - 1.0).abs() < 0.03, "{name}: α {} vs {alpha}", best.alpha);
    assert!(ev.rms <= 1.5 * ev.noise, "{name}: rms {} noise {}", ev.rms, ev.noise);
}

// Default tier: one case, `--family auto` (GGX, Beckmann, Student-t + the selection rule) with
// few photons. Tolerances are the acceptance bounds of the issue (α within 3 %, RMS ≤ 1.5 × the
// combined Monte-Carlo noise); the family must be the one that generated the data.
#[test]
fn reference_ggx_015_smooth() {
    run_case("ggx_a0.15_smooth", Family::Ggx, 0.15, 50_000);
}

// Full acceptance on every Mitsuba 3 reference case, 200 000 photons per incidence per
// evaluation (coarse stage 25 000). Run:
// cargo test -p opal-inverse --test ndf_fit -- --ignored --nocapture reference_all_cases
#[test]
#[ignore]
fn reference_all_cases() {
    for (name, fam, a) in [
        ("ggx_a0.15_smooth", Family::Ggx, 0.15),
        ("ggx_a0.15_rough", Family::Ggx, 0.15),
        ("ggx_a0.35_smooth", Family::Ggx, 0.35),
        ("ggx_a0.35_rough", Family::Ggx, 0.35),
        ("beckmann_a0.25_smooth", Family::Beckmann, 0.25),
        ("beckmann_a0.25_rough", Family::Beckmann, 0.25),
    ] {
        run_case(name, fam, a, 200_000);
    }
}

/// Synthetic "measurement": the plate simulated with `ndf` (seed 1001, independent of the
/// fit's seed 7 and of its check seed).
fn synthetic(ndf: Ndfs, scattering: Scattering, rough_front: bool, photons: u64) -> Measured {
    let s = setup(rough_front, photons);
    let g = Gonio::new(GonioSetup {
        beam: s.beam.clone(),
        incidences: [0.0f64, 20.0, 40.0, 60.0].iter().map(|x| x.to_radians()).collect(),
        detectors: DetectorLayout {
            grid: DetectorGrid::PlaneOfIncidence {
                angles: (-89..=89).map(|x| (x as f64).to_radians()).collect(),
            },
            radius: s.detector_radius,
            distance_mm: None,
        },
        photons,
        seed: 1001,
        max_interactions: 200,
    })
    .unwrap();
    let f = Face::Rough { ndf, scattering };
    let mut plate = s.plate.clone();
    if rough_front {
        plate.front = f;
    } else {
        plate.back = f;
    }
    Measured::from_gonio(&g, &g.run_plate(&plate).unwrap(), "synthetic")
}

// Round trip with multiple scattering on the micro-surface (Heitz 2016 random walk): synthetic
// GGX α = 0.4 (where multiple scattering matters), rough entry, 400 000 photons; `auto` fit
// with 100 000 photons. Run:
// cargo test -p opal-inverse --test ndf_fit -- --ignored --nocapture round_trip_multiple
#[test]
#[ignore]
fn round_trip_multiple_scattering() {
    let m = synthetic(Ndfs::ggx(0.4), Scattering::Multiple, true, 400_000);
    let mut s = setup(true, 100_000);
    s.scattering = Scattering::Multiple;
    let t0 = std::time::Instant::now();
    let problem = Problem::new(m, s).unwrap();
    let r = fit(&problem, &FitOptions::default()).unwrap();
    show("multiple", &problem, &r, t0);
    let best = &r.best().fit.model;
    assert_eq!(best.family, Family::Ggx);
    assert!((best.alpha / 0.4 - 1.0).abs() < 0.03, "α {}", best.alpha);
    assert!(r.best().check.rms <= 1.5 * r.best().check.noise);
}

// Student-t with γ = 4 (tail between GGX's r⁻⁴ and Beckmann's Gaussian), α = 0.25, smooth
// entry, 400 000 photons; `auto` must keep the Student-t model (the selection rule accepts it
// over GGX and Beckmann) and recover α within 5 % and q = 2/γ within ±0.1 (γ ∈ [3.33, 5]).
// Run: cargo test -p opal-inverse --test ndf_fit -- --ignored --nocapture round_trip_student
#[test]
#[ignore]
fn round_trip_student() {
    let ndf = Ndfs::numeric(Profile::StudentT { alpha: 0.25, gamma: 4.0 }).unwrap();
    let m = synthetic(ndf, Scattering::Single, false, 400_000);
    let t0 = std::time::Instant::now();
    let problem = Problem::new(m, setup(false, 100_000)).unwrap();
    let r = fit(&problem, &FitOptions::default()).unwrap();
    show("student", &problem, &r, t0);
    let best = &r.best().fit.model;
    assert_eq!(best.family, Family::Student);
    assert!((best.alpha / 0.25 - 1.0).abs() < 0.05, "α {}", best.alpha);
    let q = 2.0 / best.gamma.unwrap();
    assert!((q - 0.5).abs() < 0.1, "γ {:?}", best.gamma);
    assert!(r.best().check.rms <= 1.5 * r.best().check.noise);
}

// Shifted peak: GGX α = 0.1 with the normals peaking on the cone θm = δ = 10°, rough entry,
// 400 000 photons; `--family ggx --shift` must recover δ within ±1° and α within 5 %.
// Run: cargo test -p opal-inverse --test ndf_fit -- --ignored --nocapture round_trip_shift
#[test]
#[ignore]
fn round_trip_shift() {
    let p = Profile::Shifted { base: Box::new(Profile::Ggx { alpha: 0.1 }), delta: 10f64.to_radians() };
    let m = synthetic(Ndfs::numeric(p).unwrap(), Scattering::Single, true, 400_000);
    let t0 = std::time::Instant::now();
    let problem = Problem::new(m, setup(true, 100_000)).unwrap();
    let r = fit(&problem, &FitOptions { family: Some(Family::Ggx), shift: true, hybrid_nodes: 0 }).unwrap();
    show("shift", &problem, &r, t0);
    let best = &r.best().fit.model;
    let d = best.delta.unwrap().to_degrees();
    assert!((d - 10.0).abs() < 1.0, "δ {d}°");
    assert!((best.alpha / 0.1 - 1.0).abs() < 0.05, "α {}", best.alpha);
    assert!(r.best().check.rms <= 1.5 * r.best().check.noise);
}

/// GGX α = 0.3 times (1 + 2 exp(−θ²/(2 (3°)²))): a Cauchy-like NDF with an extra narrow peak
/// at θm = 0 (tabulated every 0.25°).
fn ggx_with_peak() -> Ndfs {
    let ggx = Profile::Ggx { alpha: 0.3 };
    let w = 3f64.to_radians();
    let theta: Vec<f64> = (0..=360).map(|i| (i as f64 * 0.25).to_radians()).collect();
    let d: Vec<f64> =
        theta.iter().map(|&t| ggx.eval(t) * (1.0 + 2.0 * (-t * t / (2.0 * w * w)).exp())).collect();
    Ndfs::numeric(Profile::Table { theta, d }).unwrap()
}

// Hybrid: the GGX + narrow-peak NDF above, smooth entry, 400 000 photons; `--family hybrid`
// must add at least one node, and the kept hybrid must beat every analytic candidate at the
// independent check seed (lower χ², by more than the selection rule's threshold for the last
// accepted step).
// Run: cargo test -p opal-inverse --test ndf_fit -- --ignored --nocapture round_trip_hybrid
#[test]
#[ignore]
fn round_trip_hybrid() {
    let m = synthetic(ggx_with_peak(), Scattering::Single, false, 400_000);
    let t0 = std::time::Instant::now();
    let problem = Problem::new(m, setup(false, 100_000)).unwrap();
    let r =
        fit(&problem, &FitOptions { family: Some(Family::Hybrid), shift: false, hybrid_nodes: 4 }).unwrap();
    show("hybrid", &problem, &r, t0);
    let best = r.best();
    assert_eq!(best.fit.model.family, Family::Hybrid);
    assert!(best.fit.model.nodes.len() >= 2);
    for c in r.candidates.iter().filter(|c| c.fit.model.family != Family::Hybrid) {
        let extra = best.fit.model.parameter_count().saturating_sub(c.fit.model.parameter_count()).max(1);
        let cmp = problem.compare(&c.check, &best.check, extra);
        assert!(cmp.accepted, "hybrid does not beat {}: {cmp:?}", c.fit.model.describe());
    }
    // the peak: the fitted D at 0 is well above the GGX part's (true ratio 3)
    assert!(best.fit.model.nodes[0].1 > 1.5, "{}", best.fit.model.describe());
}

// The selection rule on a clear case (default tier, < 1 s): curves of GGX α = 0.2 (one
// incidence, 40 000 photons); candidates GGX 0.2 (the truth) and GGX 0.26 re-simulated with the
// check seed. The truth must be accepted over the wrong model, the wrong model never over the
// truth, and a model compared with itself never.
#[test]
fn selection_rule_prefers_the_truth_only() {
    let s = setup(true, 40_000);
    let g = Gonio::new(GonioSetup {
        beam: s.beam.clone(),
        incidences: vec![0.0],
        detectors: DetectorLayout {
            grid: DetectorGrid::PlaneOfIncidence {
                angles: (-89..=89).map(|x| (x as f64).to_radians()).collect(),
            },
            radius: s.detector_radius,
            distance_mm: None,
        },
        photons: 40_000,
        seed: 1001,
        max_interactions: 200,
    })
    .unwrap();
    let mut plate = s.plate.clone();
    plate.front = Face::Rough { ndf: Ndfs::ggx(0.2), scattering: Scattering::Single };
    let m = Measured::from_gonio(&g, &g.run_plate(&plate).unwrap(), "synthetic");
    let problem = Problem::new(m, s).unwrap();
    let truth = problem.check(&opal_inverse::ndf_fit::Model::new(Family::Ggx, 0.2)).unwrap();
    let wrong = problem.check(&opal_inverse::ndf_fit::Model::new(Family::Ggx, 0.26)).unwrap();
    let c = problem.compare(&wrong, &truth, 1);
    eprintln!("truth over wrong: {c:?}");
    assert!(c.accepted && c.delta_chi2 > 0.0, "{c:?}");
    let c = problem.compare(&truth, &wrong, 1);
    eprintln!("wrong over truth: {c:?}");
    assert!(!c.accepted && c.delta_chi2 < 0.0, "{c:?}");
    let c = problem.compare(&truth, &truth, 1);
    assert!(!c.accepted && c.delta_chi2 == 0.0 && c.threshold >= 6.63, "{c:?}");
}

// Calibration of the selection rule's noise estimate under "B is no better": A = analytic GGX
// α = 0.2, B = Student-t γ = 2 (the same NDF, tabulated, another visible-normal sampler),
// against 20 synthetic measurements (seeds 2000…2019, 2 incidences, 40 000 photons). The rule
// must not be anti-conservative: z = ΔX/sd must have mean square < 2.0 (a χ²(20)/20 exceeds
// 1.9 with 0.4 % probability when sd is right) and B must never be preferred. The estimate
// treats the two check simulations as independent; they share part of their random numbers
// (same per-photon streams), so it is conservative: measured mean z² 0.28 (docs/fit-ndf.md).
// Run: cargo test -p opal-inverse --test ndf_fit -- --ignored --nocapture selection_rule_calibration
#[test]
#[ignore]
fn selection_rule_calibration() {
    let mut z2 = 0.0;
    let mut preferred = 0;
    let n = 20;
    for k in 0..n {
        let s = setup(true, 40_000);
        let g = Gonio::new(GonioSetup {
            beam: s.beam.clone(),
            incidences: vec![0.0, 30f64.to_radians()],
            detectors: DetectorLayout {
                grid: DetectorGrid::PlaneOfIncidence {
                    angles: (-89..=89).map(|x| (x as f64).to_radians()).collect(),
                },
                radius: s.detector_radius,
                distance_mm: None,
            },
            photons: 40_000,
            seed: 2000 + k,
            max_interactions: 200,
        })
        .unwrap();
        let mut plate = s.plate.clone();
        plate.front = Face::Rough { ndf: Ndfs::ggx(0.2), scattering: Scattering::Single };
        let m = Measured::from_gonio(&g, &g.run_plate(&plate).unwrap(), "synthetic");
        let problem = Problem::new(m, s).unwrap();
        let a = problem.check(&opal_inverse::ndf_fit::Model::new(Family::Ggx, 0.2)).unwrap();
        let mut sm = opal_inverse::ndf_fit::Model::new(Family::Student, 0.2);
        sm.gamma = Some(2.0);
        let b = problem.check(&sm).unwrap();
        let c = problem.compare(&a, &b, 1);
        let z = c.delta_chi2 / c.sd;
        eprintln!(
            "seed {}: ΔX {:.1} sd {:.1} z {z:.2} inflation {:.2}",
            2000 + k,
            c.delta_chi2,
            c.sd,
            c.inflation
        );
        z2 += z * z;
        preferred += c.accepted as usize;
    }
    let ms = z2 / n as f64;
    eprintln!("mean z² {ms:.3}, preferred {preferred}/{n}");
    assert!(ms < 2.0, "mean z² {ms}");
    assert_eq!(preferred, 0);
}
