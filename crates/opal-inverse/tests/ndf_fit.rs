//! Fit of the NDF on the Mitsuba 3 reference curves and on synthetic data.

use opal::gonio::{Beam, Face, Plate, Scattering};
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

#[test]
fn reference_ggx_015_smooth() {
    run_case("ggx_a0.15_smooth", Family::Ggx, 0.15, 100_000);
}
