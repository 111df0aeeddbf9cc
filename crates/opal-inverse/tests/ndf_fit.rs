//! Fit of the NDF on the Mitsuba 3 reference curves and on synthetic data.

use opal::gonio::{Beam, DetectorGrid, DetectorLayout, Face, Gonio, GonioSetup, Plate, Scattering};
use opal_inverse::measured::Measured;
use opal_inverse::ndf_fit::{Family, FitOn, FitSetup, Problem, fit_families};
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
    }
}

fn reference(name: &str) -> Measured {
    let p =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../opal/tests/data/gonio").join(format!("{name}.csv"));
    Measured::read(&p).unwrap()
}

fn run_case(name: &str, family: Family, alpha: f64, photons: u64) {
    let rough_front = name.ends_with("_rough");
    let t0 = std::time::Instant::now();
    let problem = Problem::new(reference(name), setup(rough_front, photons)).unwrap();
    let fits = fit_families(&problem, &Family::ALL).unwrap();
    let best = &fits[0];
    let ev = problem.evaluate(problem.simulate(best.family.ndf(best.alpha), 99, photons).unwrap());
    eprintln!(
        "{name}: best {} α={:.4} (init {:.4}) obj {:.4} | others {:?} | indep rms {:.4} noise {:.4} ratio {:.3} | {} evals {:.1}s",
        best.family.name(),
        best.alpha,
        best.alpha_initial,
        best.objective,
        fits[1..].iter().map(|f| (f.family.name(), f.alpha, f.objective)).collect::<Vec<_>>(),
        ev.rms,
        ev.noise,
        ev.rms / ev.noise,
        problem.evaluations(),
        t0.elapsed().as_secs_f64()
    );
    assert_eq!(best.family, family, "{name}: wrong family");
    assert!((best.alpha / alpha - 1.0).abs() < 0.03, "{name}: α {} vs {alpha}", best.alpha);
    assert!(ev.rms <= 1.5 * ev.noise, "{name}: rms {} noise {}", ev.rms, ev.noise);
}

// Default tier: one case with few photons (~20–40 s on 2 busy cores). Tolerances are the
// acceptance bounds of the issue (α within 3 %, RMS ≤ 1.5 × the combined Monte-Carlo noise);
// the family must be the one that generated the data.
#[test]
fn reference_ggx_015_smooth() {
    run_case("ggx_a0.15_smooth", Family::Ggx, 0.15, 50_000);
}

// Full acceptance on every Mitsuba 3 reference case, 200 000 photons per incidence per
// evaluation (~1–2 min per case on 2 cores). Run:
// cargo test -p opal-inverse --test ndf_fit -- --ignored --nocapture
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
/// fit's seed 7).
fn synthetic(
    ndf: opal::bsdf::microfacet::Ndfs,
    scattering: Scattering,
    rough_front: bool,
    photons: u64,
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
// GGX α = 0.4 (where multiple scattering matters), rough entry, 400 000 photons; fit with
// 100 000 photons. Run: cargo test -p opal-inverse --test ndf_fit -- --ignored --nocapture
#[test]
#[ignore]
fn round_trip_multiple_scattering() {
    let m = synthetic(Family::Ggx.ndf(0.4), Scattering::Multiple, true, 400_000);
    let mut s = setup(true, 100_000);
    s.scattering = Scattering::Multiple;
    let t0 = std::time::Instant::now();
    let problem = Problem::new(m, s).unwrap();
    let fits = fit_families(&problem, &Family::ALL).unwrap();
    let best = &fits[0];
    let ev = problem.evaluate(problem.simulate(best.family.ndf(best.alpha), 99, 100_000).unwrap());
    eprintln!(
        "multiple: best {} α={:.4} obj {:.4} others {:?} rms {:.4} noise {:.4} {:.1}s",
        best.family.name(),
        best.alpha,
        best.objective,
        fits[1..].iter().map(|f| (f.family.name(), f.alpha, f.objective)).collect::<Vec<_>>(),
        ev.rms,
        ev.noise,
        t0.elapsed().as_secs_f64()
    );
    assert_eq!(best.family, Family::Ggx);
    assert!((best.alpha / 0.4 - 1.0).abs() < 0.03, "α {}", best.alpha);
    assert!(ev.rms <= 1.5 * ev.noise);
}
