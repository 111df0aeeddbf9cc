//! Where the simulations of `--family hybrid` forced on the dotted plate go (issue 18, item
//! "speed"): the Mitsuba dotted plate (35 % GGX α 0.3 dots, n 1.52, 3 mm, smooth entry, plane
//! layout), the CLI's defaults (200 000 photons, 4 nodes); prints every candidate's simulations
//! and the coarse/full split. Run:
//! cargo test -p opal-inverse --test hybrid_profile --release -- --ignored --nocapture

use opal_inverse::measured::Measured;
use opal_inverse::ndf_fit::{Family, FitOptions, Problem, fit};
use std::path::Path;

mod fit_setup;
use fit_setup::dotted_setup;

#[test]
#[ignore]
fn hybrid_forced_on_dotted_plate() {
    let name = "dotted_ggx_a0.3_f0.35_smooth";
    let p =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../opal/tests/data/gonio").join(format!("{name}.csv"));
    let problem = Problem::new(Measured::read(&p).unwrap(), dotted_setup(false, 200_000)).unwrap();
    let t0 = std::time::Instant::now();
    let r =
        fit(&problem, &FitOptions { family: Some(Family::Hybrid), shift: false, hybrid_nodes: 4 }).unwrap();
    for (i, c) in r.candidates.iter().enumerate() {
        eprintln!(
            "[{i}] {} | {} simulations, converged {} | objective {:.4e} | check rms/noise {:.3}, χ² {:.1} over {} points",
            c.fit.model.describe(),
            c.fit.evaluations,
            c.fit.converged,
            c.fit.objective,
            c.check.rms / c.check.noise,
            c.check.chi2,
            c.check.points
        );
    }
    for d in &r.decisions {
        let c = &d.comparison;
        eprintln!(
            "[{}] vs [{}]: ΔX {:.1}, sd {:.1}, threshold {:.1}, objectives at the check seed {:?}, accepted {}",
            d.simple, d.rich, c.delta_chi2, c.sd, c.threshold, c.objectives, c.accepted
        );
    }
    let (coarse, full) = problem.evaluations_by_stage();
    eprintln!(
        "kept [{}] {}; {coarse} coarse + {full} full simulations, {:.1} s",
        r.best,
        r.best().fit.model.describe(),
        t0.elapsed().as_secs_f64()
    );
}
