//! Fit of the NDF on the Mitsuba 3 reference curves and round trips on synthetic data
//! (Student-t tail, shifted peak, multiple scattering, hybrid).

use opal::bsdf::microfacet::{Ndf, Ndfs, Profile};
use opal::gonio::{DetectorGrid, DetectorLayout, Face, Gonio, GonioSetup, Plate, Scattering, Side};
use opal::math::Vec3;
use opal_inverse::measured::Measured;
use opal_inverse::ndf_fit::{Family, FitOptions, FitReport, FitSetup, Problem, ScaleMode, ScaleSetup, fit};
use std::path::Path;

mod fit_setup;
use fit_setup::{dotted_setup, setup};

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
    // the absolute mode's calibration check of the kept model (k ≈ 1 on calibrated data)
    let sc = r.best().check.scale_check.map_or("none".to_string(), |c| {
        format!("k {:.4} ± {:.4}{}", c.k, c.stderr, if c.mismatch { " MISMATCH" } else { "" })
    });
    eprintln!(
        "{name}: kept [{}] {} | {} coarse + {} full simulations, {:.1} s | scale check {sc}",
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

// Dotted plate (issue 18): Mitsuba 3 curves of a plate (n 1.52, 3 mm) whose face is 35 %
// GGX α = 0.3 dots on a polished land (`blendbsdf`, bench/scripts/gonio_dotted.py, both
// entries, 10⁶ photons per incidence); `auto` with the default point selection (min_snr 3)
// must keep the dotted model, coverage within ±0.03, α within 5 %, rms/noise ≤ 1.5 over
// ≥ 150 points. 200 000 photons per evaluation; the fit time is printed (goal ≤ 60 s on 2
// cores). Run:
// cargo test -p opal-inverse --test ndf_fit --release -- --ignored --nocapture dotted_mitsuba
#[test]
#[ignore]
fn dotted_mitsuba_cases() {
    for name in ["dotted_ggx_a0.3_f0.35_smooth", "dotted_ggx_a0.3_f0.35_rough"] {
        let s = dotted_setup(name.ends_with("rough"), 200_000);
        let problem = Problem::new(reference(name), s).unwrap();
        let t0 = std::time::Instant::now();
        let r = fit(&problem, &FitOptions::default()).unwrap();
        show(name, &problem, &r, t0);
        let best = &r.best().fit.model;
        let ev = &r.best().check;
        assert_eq!(best.family, Family::Dotted, "{name}: {}", best.describe());
        let f = best.coverage.unwrap();
        assert!((f - 0.35).abs() <= 0.03, "{name}: coverage {f}");
        assert!((best.alpha / 0.3 - 1.0).abs() <= 0.05, "{name}: α {}", best.alpha);
        assert!(ev.points >= 150, "{name}: {} points", ev.points);
        assert!(ev.rms <= 1.5 * ev.noise, "{name}: rms {} noise {}", ev.rms, ev.noise);
        assert!(r.converged, "{name}: not converged");
    }
}

// Dotted plate over the full hemisphere (issue 18 acceptance, hemisphere layout): Mitsuba 3
// curves of 25 % GGX α = 0.4 dots (n 1.52, 3 mm, both entries, incidences 0–60° every 20°,
// polar 0–88° × azimuth every 15°, 10⁶ photons per incidence; bench/scripts/gonio_dotted.py
// --layout hemisphere); `auto` with its defaults must keep the dotted model, coverage within
// ±0.03, α within 5 %, rms/noise ≤ 1.5 over ≥ 150 points. Run:
// cargo test -p opal-inverse --test ndf_fit --release -- --ignored --nocapture dotted_mitsuba_hemisphere
#[test]
#[ignore]
fn dotted_mitsuba_hemisphere_cases() {
    for name in ["dotted_ggx_a0.4_f0.25_smooth_hemi", "dotted_ggx_a0.4_f0.25_rough_hemi"] {
        let s = dotted_setup(name.contains("rough"), 200_000);
        let problem = Problem::new(reference(name), s).unwrap();
        assert!(problem.measured.hemisphere);
        let t0 = std::time::Instant::now();
        let r = fit(&problem, &FitOptions::default()).unwrap();
        show(name, &problem, &r, t0);
        let best = &r.best().fit.model;
        let ev = &r.best().check;
        assert_eq!(best.family, Family::Dotted, "{name}: {}", best.describe());
        let f = best.coverage.unwrap();
        assert!((f - 0.25).abs() <= 0.03, "{name}: coverage {f}");
        assert!((best.alpha / 0.4 - 1.0).abs() <= 0.05, "{name}: α {}", best.alpha);
        assert!(ev.points >= 150, "{name}: {} points", ev.points);
        assert!(ev.rms <= 1.5 * ev.noise, "{name}: rms {} noise {}", ev.rms, ev.noise);
        assert!(r.converged, "{name}: not converged");
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
    // the fitted D against the true D (both normalised) at a few θm: the multiplier at 0 is
    // relative to the fitted α's analytic part, so it equals the true 3 only when α is the
    // true 0.3; the D values compare the shapes whatever α the fit settled on
    let (truth, fitted) = (ggx_with_peak(), best.fit.model.ndf().unwrap());
    let ratios: Vec<String> = [0.0f64, 2.0, 4.0, 6.0, 8.0, 10.0, 15.0, 20.0, 30.0, 45.0]
        .iter()
        .map(|&deg| {
            let t = deg.to_radians();
            let wm = Vec3::new(t.sin() as f32, 0.0, t.cos() as f32);
            format!("{deg}°: {:.3}", fitted.d(wm) / truth.d(wm))
        })
        .collect();
    eprintln!("hybrid: fitted D / true D at {}", ratios.join(", "));
    // the peak: the fitted D at 0 is well above the GGX part's (true ratio 3); the first node
    // goes where the residual is largest, which here is the peak
    assert!(best.fit.model.multiplier_at(0.0) > 1.5, "{}", best.fit.model.describe());
}

/// GGX α = 0.3 with a hole at the centre: D × (1 − 0.9 exp(−θ²/(2 (6°)²))) (tabulated every
/// 0.25°): a face with few flat facets (most tilted by ~5–15°), a shape no analytic family
/// (they all peak at θm = 0) or dotted mixture (its polished land adds to the centre)
/// describes.
fn ggx_with_hole() -> Ndfs {
    let ggx = Profile::Ggx { alpha: 0.3 };
    let w = 6f64.to_radians();
    let theta: Vec<f64> = (0..=360).map(|i| (i as f64 * 0.25).to_radians()).collect();
    let d: Vec<f64> =
        theta.iter().map(|&t| ggx.eval(t) * (1.0 - 0.9 * (-t * t / (2.0 * w * w)).exp())).collect();
    Ndfs::numeric(Profile::Table { theta, d }).unwrap()
}

// `auto` picks hybrid (issue 18, item 2): the GGX-with-a-hole NDF above, smooth entry, 400 000
// photons; `auto` with its defaults (fits at 100 000 photons). The single NDFs and the dotted
// model miss the hole by more than twice the noise, so auto adds hybrid nodes on the kept
// model; the kept model must be hybrid, with a fitted node within the hole (θm ≤ 8°) that
// lowers D there (multiplier < 0.5), preferred by the selection rule over every single-NDF and
// dotted candidate at the check seed, and closer to the data than they are (lower rms/noise).
// Run: cargo test --release -p opal-inverse --test ndf_fit -- --ignored --nocapture --exact auto_picks_hybrid
#[test]
#[ignore]
fn auto_picks_hybrid() {
    let m = synthetic(ggx_with_hole(), Scattering::Single, false, 400_000);
    let t0 = std::time::Instant::now();
    let problem = Problem::new(m, setup(false, 100_000)).unwrap();
    let r = fit(&problem, &FitOptions::default()).unwrap();
    show("auto hole", &problem, &r, t0);
    let best = r.best();
    let model = &best.fit.model;
    assert_eq!(model.family, Family::Hybrid, "{}", model.describe());
    let hole =
        model.free_nodes().iter().any(|&i| model.nodes[i].0.to_degrees() <= 8.0 && model.nodes[i].1 < 0.5);
    assert!(hole, "no fitted node lowers D in the hole: {}", model.describe());
    let ratio = best.check.rms / best.check.noise;
    for c in r.candidates.iter().filter(|c| c.fit.model.family != Family::Hybrid) {
        let extra = model.parameter_count().saturating_sub(c.fit.model.parameter_count()).max(1);
        let cmp = problem.compare(&c.check, &best.check, extra);
        assert!(cmp.accepted, "hybrid does not beat {}: {cmp:?}", c.fit.model.describe());
        assert!(ratio < c.check.rms / c.check.noise, "{ratio} vs {}", c.fit.model.describe());
    }
    eprintln!(
        "auto hole: RESULT {} rms/noise {ratio:.3} over {} points, converged {} ({:.1} s)",
        model.describe(),
        best.check.points,
        r.converged,
        t0.elapsed().as_secs_f64()
    );
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

/// Synthetic "measurement" of a plate (ior, thickness) with `ndf` on its rough face, 4
/// incidences (0°, 20°, 40°, 60°), detectors every 1°, simulated with `seed` (independent of the
/// fit's seed 7 and its check seed), every value and error of incidence i times `factors[i]`.
fn synthetic_scaled(
    ndf: Ndfs,
    rough_front: bool,
    (ior, thickness_mm): (f64, f64),
    photons: u64,
    seed: u64,
    factors: &[f64; 4],
) -> Measured {
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
        seed,
        max_interactions: 200,
    })
    .unwrap();
    let f = Face::Rough { ndf, scattering: Scattering::Single };
    let mut plate = Plate { ior, thickness_mm, ..s.plate.clone() };
    if rough_front {
        plate.front = f;
    } else {
        plate.back = f;
    }
    let mut m = Measured::from_gonio(&g, &g.run_plate(&plate).unwrap(), "synthetic");
    let incs = m.incidences();
    for c in &mut m.curves {
        let k = factors[incs.iter().position(|&t| t == c.incidence).unwrap()];
        c.value.iter_mut().for_each(|v| *v *= k);
        c.stderr.iter_mut().for_each(|v| *v *= k);
    }
    m
}

fn scaled_setup(
    rough_front: bool,
    (ior, thickness_mm): (f64, f64),
    photons: u64,
    mode: ScaleMode,
) -> FitSetup {
    let mut s = setup(rough_front, photons);
    s.plate.ior = ior;
    s.plate.thickness_mm = thickness_mm;
    s.scale = ScaleSetup { mode, prior: None };
    s
}

// Default tier (a few seconds): the objective with a global factor (normalised by Σ m) is
// invariant under m → c·m, so the fit of a measurement scaled by 1.6 is the fit of the unscaled
// one with the factor × 1.6: the same α (within the fine stage's tolerance 10⁻³ in ln α, the
// arithmetic differs by rounding) and factor ratio 1.6 (within 10⁻³). On the unscaled
// measurement the factor is 1 within 3 of its standard errors and α stays within 3 % of the
// absolute fit's; no fit runs a simulation beyond its optimiser's (the factor is closed-form).
#[test]
fn global_factor_absorbs_a_scaled_measurement() {
    let plate = (1.49, 2.0);
    let fit1 = |times: f64, mode: ScaleMode| {
        let m = synthetic_scaled(Ndfs::ggx(0.2), false, plate, 100_000, 1001, &[times; 4]);
        let p = Problem::new(m, scaled_setup(false, plate, 20_000, mode)).unwrap();
        let r = fit(&p, &FitOptions { family: Some(Family::Ggx), shift: false, hybrid_nodes: 0 }).unwrap();
        (r.best().clone(), p.evaluations())
    };
    let (abs, n_abs) = fit1(1.0, ScaleMode::Absolute);
    let (one, n_one) = fit1(1.0, ScaleMode::Global);
    let (glob, n_glob) = fit1(1.6, ScaleMode::Global);
    let (k1, e1, k) = (one.fit.scale.factors[0], one.fit.scale.stderr[0], glob.fit.scale.factors[0]);
    eprintln!(
        "absolute α {:.5} | global α {:.5} k {k1:.5} ± {e1:.5} | ×1.6 global α {:.5} k {k:.5} \
         | rms/noise {:.3} {:.3} {:.3} | {n_abs} {n_one} {n_glob} simulations",
        abs.fit.model.alpha,
        one.fit.model.alpha,
        glob.fit.model.alpha,
        abs.check.rms / abs.check.noise,
        one.check.rms / one.check.noise,
        glob.check.rms / glob.check.noise
    );
    assert!((glob.fit.model.alpha / one.fit.model.alpha - 1.0).abs() < 1e-3);
    assert!((k / k1 / 1.6 - 1.0).abs() < 1e-3, "k {k} vs {k1}");
    assert!((k1 - 1.0).abs() < 3.0 * e1 && e1 > 0.0 && e1 < 0.02, "k {k1} ± {e1}");
    assert!((one.fit.model.alpha / abs.fit.model.alpha - 1.0).abs() < 0.03);
    assert!(glob.check.rms <= 1.5 * glob.check.noise);
    // no simulation beyond the optimiser's (one per objective evaluation) and the probe of the
    // initial α: the factor is closed-form and the optimum's is found in the log
    assert_eq!(n_one, n_glob);
    for f in [&abs.fit, &one.fit, &glob.fit] {
        assert_eq!(f.evaluations, f.history.len() as u64 + 1);
    }
    assert!(abs.fit.scale.factors.is_empty());
}

/// One acceptance case of unknown calibration factors.
struct ScaledCase {
    name: &'static str,
    truth: (Ndfs, Family, f64),
    rough_front: bool,
    plate: (f64, f64),
    mode: ScaleMode,
    /// Factor of each incidence (0°, 20°, 40°, 60°).
    factors: [f64; 4],
    /// `Some(e)`: every curve normalised to 1 at its peak, no standard errors, a multiplicative
    /// Gaussian error of relative size e added (seeded) and fitted with `rel_error = e`.
    normalised: Option<f64>,
    seed: u64,
}

/// Photons of the synthetic curves and of the fit of the scaled acceptance cases.
const SCALED_PHOTONS: (u64, u64) = (4_000_000, 1_000_000);

/// Fits one case (`auto`) and checks the acceptance: the right family, α within 3 %,
/// every factor within 1 % (scaled cases), rms/noise ≤ 1.5. Returns a summary line.
fn scaled_case(c: &ScaledCase) -> String {
    let t0 = std::time::Instant::now();
    let (truth, family, alpha) = (c.truth.0.clone(), c.truth.1, c.truth.2);
    let mut m = synthetic_scaled(truth, c.rough_front, c.plate, SCALED_PHOTONS.0, c.seed, &c.factors);
    let incs: Vec<f64> = m.incidences().iter().map(|t| t.to_degrees()).collect();
    // true factor (measured / expected simulation) by (incidence, side)
    let mut truth_of: Vec<(f64, Side, f64)> = Vec::new();
    let mut s = scaled_setup(c.rough_front, c.plate, SCALED_PHOTONS.1, c.mode);
    for cv in &mut m.curves {
        let inc = cv.incidence.to_degrees();
        let mut k = c.factors[incs.iter().position(|&x| x == inc).unwrap()];
        if let Some(e) = c.normalised {
            let mut rng = opal::sampling::Rng::new(c.seed, (inc * 10.0) as u64, cv.side as u64);
            for v in &mut cv.value {
                // Box–Muller
                let (u1, u2) = (1.0 - rng.next_f64(), rng.next_f64());
                *v *= 1.0 + e * (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos();
            }
            let peak = cv.max();
            cv.value.iter_mut().for_each(|v| *v /= peak);
            cv.stderr.iter_mut().for_each(|v| *v = 0.0);
            k /= peak;
        }
        truth_of.push((inc, cv.side, k));
    }
    if let Some(e) = c.normalised {
        m.has_stderr = false;
        s.rel_error = e;
    }
    let problem = Problem::new(m, s).unwrap();
    let r = fit(&problem, &FitOptions::default()).unwrap();
    show(c.name, &problem, &r, t0);
    let best = r.best();
    let model = &best.fit.model;
    let mut worst: f64 = 0.0;
    let mut list = Vec::new();
    let sc = &best.fit.scale;
    for (g, (k, e)) in problem.scale_groups().iter().zip(sc.factors.iter().zip(&sc.stderr)) {
        // the groups' true factors (equal within a group by construction)
        let t = truth_of
            .iter()
            .find(|t| {
                g.incidence_deg.is_none_or(|d| (d - t.0).abs() < 1e-9) && g.side.is_none_or(|sd| sd == t.1)
            })
            .unwrap()
            .2;
        let err = k / t - 1.0;
        worst = if err.abs() > worst.abs() { err } else { worst };
        list.push(format!("{:+.2}±{:.2} %", 100.0 * err, 100.0 * e / k));
    }
    let ratio = best.check.rms / best.check.noise;
    let line = format!(
        "{}: RESULT {} α {:.4} ({:+.2} %) factor errors [{}] worst {:+.2} % rms/noise {ratio:.3} ({:.0} s)",
        c.name,
        model.family.name(),
        model.alpha,
        100.0 * (model.alpha / alpha - 1.0),
        list.join(", "),
        100.0 * worst,
        t0.elapsed().as_secs_f64()
    );
    eprintln!("{line}");
    assert_eq!(model.family, family, "{}: wrong family", c.name);
    assert!((model.alpha / alpha - 1.0).abs() < 0.03, "{}: α {}", c.name, model.alpha);
    if c.normalised.is_none() {
        // the bound for scaled curves; normalised noisy curves: the factors are only as
        // good as 2 % point noise and α allow (measured, not asserted: docs/fit-ndf.md)
        assert!(worst.abs() < 0.01, "{}: factor error {worst}", c.name);
    }
    assert!(ratio <= 1.5, "{}: rms/noise {ratio}", c.name);
    line
}

// Acceptance of unknown calibration factors: independent synthetic curves (Opal's gonio, seeds
// 1101…, 4 000 000 photons, plates other than the reference's 1.49 / 2 mm for most cases) of
// GGX and Beckmann plates, scaled by global factors in 0.5–2 and per-incidence factors in
// 0.8–1.25, and one set normalised to 1 at every curve's peak with 2 % noise and no standard
// errors (`per-curve`, `rel_error` 0.02: family, α, rms/noise asserted; its factors are
// limited by the point noise and α, 1–3 %); `auto` fits with 1 000 000 photons (the factors'
// standard errors must be well below the 1 % bound: at 400 000 they were 0.2–0.6 % and the
// worst error 0.97 %). Also the example fitted as absolute. Run:
// cargo test -p opal-inverse --test ndf_fit -- --ignored --nocapture scaled_round_trips
#[test]
#[ignore]
fn scaled_round_trips() {
    let (g, pi) = (ScaleMode::Global, ScaleMode::PerIncidence);
    let case = |name, truth, rough_front, plate, mode, factors, seed| ScaledCase {
        name,
        truth,
        rough_front,
        plate,
        mode,
        factors,
        normalised: None,
        seed,
    };
    let cases = [
        case(
            "ggx0.25 smooth ×0.8",
            (Ndfs::ggx(0.25), Family::Ggx, 0.25),
            false,
            (1.52, 3.0),
            g,
            [0.8; 4],
            1101,
        ),
        case(
            "ggx0.12 rough ×0.5",
            (Ndfs::ggx(0.12), Family::Ggx, 0.12),
            true,
            (1.49, 2.0),
            g,
            [0.5; 4],
            1102,
        ),
        case(
            "beckmann0.3 rough ×2",
            (Ndfs::beckmann(0.3), Family::Beckmann, 0.3),
            true,
            (1.52, 3.0),
            g,
            [2.0; 4],
            1103,
        ),
        case(
            "ggx0.35 smooth per-incidence",
            (Ndfs::ggx(0.35), Family::Ggx, 0.35),
            false,
            (1.59, 2.0),
            pi,
            [0.8, 1.25, 0.9, 1.1],
            1104,
        ),
        case(
            "beckmann0.2 smooth per-incidence",
            (Ndfs::beckmann(0.2), Family::Beckmann, 0.2),
            false,
            (1.49, 3.0),
            pi,
            [1.25, 0.85, 1.1, 0.8],
            1105,
        ),
        ScaledCase {
            normalised: Some(0.02),
            ..case(
                "ggx0.2 rough normalised per curve, 2 % noise",
                (Ndfs::ggx(0.2), Family::Ggx, 0.2),
                true,
                (1.52, 3.0),
                ScaleMode::PerCurve,
                [1.0; 4],
                1106,
            )
        },
    ];
    let lines: Vec<String> = cases.iter().map(scaled_case).collect();
    for l in lines {
        eprintln!("{l}");
    }
}

// Issue 24's example (GGX α 0.25, n 1.52, 3 mm, smooth entry, every value × 0.8) fitted as
// absolute values, as a user who does not know the calibration is off would: the fit must say
// so. rms/noise alone no longer does since the lobe points below the 1 % floor count
// (`min_snr` 3, issue 18): the NDF absorbs most of the 20 % into a wider lobe (α ≈ +12 %) and
// rms/noise is ≈ 1.2. The absolute mode's calibration check (`Evaluation::scale_check`: the one
// global factor k that best maps the check simulation onto the measurement) must flag it, with
// k below 1 (the measurement is low). Was the last part of `scaled_round_trips` (as
// "rms/noise > 1.5"); a test of its own so it can be run alone (one 1 000 000-photon fit). Run:
// cargo test --release -p opal-inverse --test ndf_fit -- --ignored --nocapture --exact scaled_data_fitted_as_absolute_is_flagged
#[test]
#[ignore]
fn scaled_data_fitted_as_absolute_is_flagged() {
    let t0 = std::time::Instant::now();
    let plate = (1.52, 3.0);
    let m = synthetic_scaled(Ndfs::ggx(0.25), false, plate, SCALED_PHOTONS.0, 1101, &[0.8; 4]);
    let p = Problem::new(m, scaled_setup(false, plate, SCALED_PHOTONS.1, ScaleMode::Absolute)).unwrap();
    let r = fit(&p, &FitOptions::default()).unwrap();
    show("ggx0.25 smooth ×0.8 as absolute", &p, &r, t0);
    let b = r.best();
    let sc = b.check.scale_check.expect("absolute fits carry the calibration check");
    eprintln!(
        "ggx0.25 smooth ×0.8 as absolute: RESULT {} α {:.4} ({:+.2} %) rms/noise {:.3} scale check k {:.4} ± {:.4} \
         mismatch {} ({:.0} s)",
        b.fit.model.family.name(),
        b.fit.model.alpha,
        100.0 * (b.fit.model.alpha / 0.25 - 1.0),
        b.check.rms / b.check.noise,
        sc.k,
        sc.stderr,
        sc.mismatch,
        t0.elapsed().as_secs_f64()
    );
    assert!(sc.mismatch && sc.k < 0.98, "a 20 % calibration error not flagged: {sc:?}");
}

/// `Problem::new` refuses a floor outside [0, 1) naming `floor_rel` (the CLI checks `--floor`
/// before; the points a floor keeps are counted in crates/opal-cli/tests/fit_ndf.rs). Its "no
/// point above the floor" error cannot be reached: every curve of a `Measured` has a positive
/// value, and a curve's maximum passes any floor < 1.
#[test]
fn floor_outside_unit_interval_is_refused() {
    let m = reference("ggx_a0.15_smooth");
    for bad in [1.0, 1.5, -0.1, f64::NAN] {
        let s = FitSetup { floor_rel: bad, ..setup(false, 1000) };
        let e = Problem::new(m.clone(), s).err().expect("refused").to_string();
        assert!(e.contains("floor_rel") && e.contains("[0, 1)"), "{bad}: {e}");
    }
    assert!(Problem::new(m, FitSetup { floor_rel: 0.0, ..setup(false, 1000) }).is_ok());
}
