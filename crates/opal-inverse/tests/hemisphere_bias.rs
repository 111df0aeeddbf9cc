//! Diagnosis of the hemisphere smooth-entry α bias of the dotted fit (issue 18): the χ² profile
//! in α (coverage fixed at the truth) of the Mitsuba 3 curves against the same profile of Opal
//! curves of the same plate and detectors (synthetic, 10⁶ photons), and the fit of both.
//! If the Mitsuba profile's minimum is shifted and the Opal one's is not, the bias is a model
//! difference between the two simulators, not the fit. Measured (docs/fit-ndf.md): at 200 000
//! photons both data sets fit to α 0.4097 (the fit's own noise dominates); at 800 000 Opal's
//! −1.3 %, Mitsuba's +2.1 %. Run:
//! cargo test -p opal-inverse --test hemisphere_bias --release -- --ignored --nocapture

use opal_inverse::measured::Measured;
use opal_inverse::ndf_fit::{Family, FitOptions, Model, Problem, fit};
use std::path::Path;

mod fit_setup;
use fit_setup::dotted_setup;

fn truth(alpha: f64, f: f64) -> Model {
    let mut m = Model::new(Family::Dotted, alpha);
    m.coverage = Some(f);
    m
}

/// The Mitsuba problem and the Opal-synthetic problem of the same plate, fitted with
/// `photons` per simulation.
fn problems(photons: u64) -> (Problem, Problem) {
    let name = "dotted_ggx_a0.4_f0.25_smooth_hemi";
    let p =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../opal/tests/data/gonio").join(format!("{name}.csv"));
    let mitsuba = Problem::new(Measured::read(&p).unwrap(), dotted_setup(false, photons)).unwrap();
    let res = mitsuba.simulate_model(&truth(0.4, 0.25), 1001, 1_000_000).unwrap();
    let synth = Measured::from_gonio(mitsuba.gonio(), &res, "opal-synthetic");
    let opal = Problem::new(synth, dotted_setup(false, photons)).unwrap();
    (mitsuba, opal)
}

fn fit_800k(label: &str, pr: &Problem) {
    let t0 = std::time::Instant::now();
    let r = fit(pr, &FitOptions::default()).unwrap();
    let b = r.best();
    eprintln!(
        "{label} 800k fit: {} rms/noise {:.3} ({:.1} s)",
        b.fit.model.describe(),
        b.check.rms / b.check.noise,
        t0.elapsed().as_secs_f64()
    );
}

/// The Opal-synthetic data fitted with 4× the photons (800 000): if the error of the
/// 200 000-photon fit is the fit's own Monte-Carlo noise or a finite-photon bias of the
/// objective, it changes here. Measured: α 0.3947 (−1.3 %), coverage 0.2492.
#[test]
#[ignore]
fn hemisphere_smooth_entry_bias_more_photons_opal() {
    fit_800k("opal", &problems(800_000).1);
}

/// The Mitsuba curves fitted with 800 000 photons. Measured: α 0.4085 (+2.1 %), coverage
/// 0.2596 (the 200 000-photon fit of both data sets: α 0.4097; docs/fit-ndf.md).
#[test]
#[ignore]
fn hemisphere_smooth_entry_bias_more_photons_mitsuba() {
    fit_800k("mitsuba", &problems(800_000).0);
}

#[test]
#[ignore]
fn hemisphere_smooth_entry_bias() {
    let (mitsuba, opal) = problems(200_000);
    for (label, pr) in [("mitsuba", &mitsuba), ("opal", &opal)] {
        for a in [0.38, 0.39, 0.40, 0.41, 0.42, 0.43] {
            let e = pr.check(&truth(a, 0.25)).unwrap();
            let per: Vec<String> = e
                .per_incidence
                .iter()
                .map(|(i, r, n, c)| format!("{:.0}°:{:.2}({c})", i.to_degrees(), r / n))
                .collect();
            eprintln!(
                "{label} α {a}: χ² {:.1} rms/noise {:.3} points {} | {}",
                e.chi2,
                e.rms / e.noise,
                e.points,
                per.join(" ")
            );
        }
        let t0 = std::time::Instant::now();
        let r = fit(pr, &FitOptions::default()).unwrap();
        let b = r.best();
        eprintln!(
            "{label} fit: {} rms/noise {:.3} ({:.1} s)",
            b.fit.model.describe(),
            b.check.rms / b.check.noise,
            t0.elapsed().as_secs_f64()
        );
    }
}
