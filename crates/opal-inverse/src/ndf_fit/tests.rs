//! Unit tests of the NDF fit: models build the right NDF, coordinates are clamped and
//! penalised, χ² quantiles, the closed-form calibration factors (minimum, equivariance, prior,
//! absolute mode unchanged), the acceptance rule of a hybrid node step.

use super::model::{Coord, apply};
use super::*;
use opal::bsdf::microfacet::Ndf;
use opal::gonio::{Face, GonioResult, Plate, Scattering};
use opal::math::Vec3;

fn d_at(n: &Ndfs, deg: f64) -> f64 {
    let t = deg.to_radians();
    n.d(Vec3::new(t.sin() as f32, 0.0, t.cos() as f32)) as f64
}

#[test]
fn models_build_the_right_ndf() {
    // Student-t with γ = 2 is GGX with the same α (tabulation error < 1 %)
    let mut m = Model::new(Family::Student, 0.2);
    m.gamma = Some(2.0);
    let (s, g) = (m.ndf().unwrap(), Model::new(Family::Ggx, 0.2).ndf().unwrap());
    for deg in [0.0, 5.0, 11.0, 20.0, 40.0] {
        assert!((d_at(&s, deg) / d_at(&g, deg) - 1.0).abs() < 0.01, "{deg}°");
    }
    // a shift moves the peak to δ
    let mut m = Model::new(Family::Ggx, 0.1);
    m.delta = Some(10f64.to_radians());
    let n = m.ndf().unwrap();
    assert!(d_at(&n, 10.0) > d_at(&n, 0.0) && d_at(&n, 10.0) > d_at(&n, 20.0));
    assert_eq!(m.parameter_count(), 2);
    // hybrid: multiplier 2 at θ = 0 doubles D(0) relative to the analytic part (before the
    // renormalisation, which changes both by the same factor at θ ≥ the anchor)
    let mut h = Model::new(Family::Ggx, 0.3);
    h.family = Family::Hybrid;
    h.nodes = vec![(0.0, 2.0), (4f64.to_radians(), 1.0)];
    let (hn, gn) = (h.ndf().unwrap(), Model::new(Family::Ggx, 0.3).ndf().unwrap());
    let r0 = d_at(&hn, 0.0) / d_at(&gn, 0.0);
    let r30 = d_at(&hn, 30.0) / d_at(&gn, 30.0);
    assert!((r0 / r30 - 2.0).abs() < 0.02, "{r0} {r30}");
    assert_eq!(h.parameter_count(), 2);
    assert_eq!(h.param_values(), vec![0.3, 2.0]);
    assert!(h.params_json()["hybrid_nodes"].as_array().unwrap().len() == 2);
}

#[test]
fn coordinates_are_clamped_and_penalised() {
    let m = Model::new(Family::Student, 0.2);
    let (a, pen) = apply(&m, &[Coord::LnAlpha, Coord::Q], &[0.1f64.ln(), 1.5]);
    assert!((a.alpha - 0.1).abs() < 1e-12 && a.gamma == Some(2.0));
    assert!((pen - 0.25).abs() < 1e-12);
    let (_, pen) = apply(&m, &[Coord::LnAlpha, Coord::Q], &[0.1f64.ln(), 0.5]);
    assert_eq!(pen, 0.0);
}

#[test]
fn dotted_model_face_and_coverage_coordinate() {
    let m = Model::new(Family::Dotted, 0.3);
    assert_eq!((m.base, m.coverage), (Family::Ggx, Some(DOTTED_COVERAGE_START)));
    assert_eq!(m.parameter_count(), 2);
    assert_eq!(Family::parse("dotted"), Some(Family::Dotted));
    match m.face(Scattering::Single).unwrap() {
        Face::Dotted { coverage, dots, land } => {
            assert_eq!(coverage, 0.5);
            assert!(matches!(*dots, Face::Rough { ndf: Ndfs::Ggx(_), .. }));
            assert!(matches!(*land, Face::Polished));
        }
        f => panic!("{f:?}"),
    }
    assert!(matches!(Model::new(Family::Ggx, 0.3).face(Scattering::Single).unwrap(), Face::Rough { .. }));
    // logit coordinate: 0 ↔ f = 0.5, clamped to [0.002, 0.998] with a penalty
    let (a, pen) = apply(&m, &[Coord::LnAlpha, Coord::LogitCoverage], &[0.2f64.ln(), (0.25f64 / 0.75).ln()]);
    assert!((a.coverage.unwrap() - 0.25).abs() < 1e-12 && pen == 0.0);
    let (a, pen) = apply(&m, &[Coord::LogitCoverage], &[10.0]);
    assert!((a.coverage.unwrap() - 0.998).abs() < 1e-9 && pen > 0.0);
    assert_eq!(a.param_values(), vec![0.3, a.coverage.unwrap()]);
    assert!(a.describe().contains("coverage=0.9980") && a.params_json()["coverage"].as_f64().is_some());
}

#[test]
fn chi2_quantiles() {
    assert_eq!(chi2_q99(1), 6.635);
    // Wilson–Hilferty beyond the table: χ²₀.₉₉(10) = 23.209
    assert!((chi2_q99(10) - 23.209).abs() < 0.1, "{}", chi2_q99(10));
}

/// A problem on synthetic curves (GGX α = 0.2, 2 incidences, 20 000 photons, seed 1001) with
/// calibration `scale`, and a simulation of GGX α = 0.23 at the fit's seed.
fn scaled_problem(scale: ScaleSetup, times: f64) -> (Problem, GonioResult) {
    use opal::gonio::{Beam, DetectorGrid, DetectorLayout, Gonio, GonioSetup};
    let mut plate = Plate {
        ior: 1.49,
        thickness_mm: 2.0,
        absorption_per_mm: 0.0,
        front: Face::Polished,
        back: Face::Polished,
        radius_mm: None,
    };
    let beam = Beam { azimuth: 0.0, divergence: 0.5f64.to_radians(), aperture_radius_mm: 1.0 };
    let g = Gonio::new(GonioSetup {
        beam: beam.clone(),
        incidences: vec![0.0, 40f64.to_radians()],
        detectors: DetectorLayout {
            grid: DetectorGrid::PlaneOfIncidence {
                angles: (-70..=70).map(|x| (x as f64).to_radians()).collect(),
            },
            radius: 1f64.to_radians(),
            distance_mm: None,
        },
        photons: 20_000,
        seed: 1001,
        max_interactions: 200,
    })
    .unwrap();
    plate.back = Face::Rough { ndf: Ndfs::ggx(0.2), scattering: Scattering::Single };
    let mut m = crate::measured::Measured::from_gonio(&g, &g.run_plate(&plate).unwrap(), "synthetic");
    for c in &mut m.curves {
        c.value.iter_mut().for_each(|v| *v *= times);
        c.stderr.iter_mut().for_each(|v| *v *= times);
    }
    let setup = FitSetup {
        plate: Plate { back: Face::Polished, ..plate },
        rough_front: false,
        scattering: Scattering::Single,
        beam,
        detector_radius: 1f64.to_radians(),
        detector_distance_mm: None,
        photons: 20_000,
        seed: 7,
        max_interactions: 200,
        fit_on: FitOn::Both,
        floor_rel: 0.01,
        max_iters: 40,
        coarse_photons: None,
        scale,
        rel_error: 0.0,
        min_snr: None,
    };
    let p = Problem::new(m, setup).unwrap();
    let res = p.simulate(Ndfs::ggx(0.23), 7, 20_000).unwrap();
    (p, res)
}

fn mode(mode: ScaleMode) -> ScaleSetup {
    ScaleSetup { mode, prior: None }
}

/// dG/dk of group g at the factors of `fit` (G = Σ ((k s − m)² − k² σs²)/m − 2 (k s − m) r²):
/// zero at the closed-form optimum.
fn gradient(p: &Problem, res: &GonioResult, fit: &ScaleFit, g: usize) -> (f64, f64) {
    let (mut d, mut norm) = (0.0, 0.0);
    for pt in p.points.iter().filter(|pt| pt.group == Some(g)) {
        let r = &res.incidences[pt.inc];
        let (s, ss, k) = (r.value[pt.det], r.value_stderr[pt.det], fit.factors[g]);
        d += 2.0 * ((k * s - pt.m) * s - k * ss * ss) / pt.m - 2.0 * s * (pt.sm / pt.m).powi(2);
        norm += 2.0 * s;
    }
    (d, norm)
}

#[test]
fn closed_form_factor_is_the_minimum() {
    for (m, groups) in [(ScaleMode::Global, 1), (ScaleMode::PerIncidence, 2), (ScaleMode::PerCurve, 4)] {
        let (p, res) = scaled_problem(mode(m), 1.0);
        assert_eq!(p.scale_groups().len(), groups, "{m:?}");
        let (obj, fit) = p.objective_of(&res);
        assert_eq!(fit.factors.len(), groups);
        for g in 0..groups {
            let (d, norm) = gradient(&p, &res, &fit, g);
            assert!(d.abs() < 1e-12 * norm, "{m:?} group {g}: dG/dk {d} (scale {norm})");
            // a wider α (0.23 vs the true 0.2) has a lower peak: the factor makes up for it
            assert!(fit.factors[g] > 1.0 && fit.stderr[g] > 0.0 && fit.stderr[g] < 0.05, "{fit:?}");
            // moving any factor raises the objective
            for h in [0.99, 1.01] {
                let mut f2 = fit.clone();
                f2.factors[g] *= h;
                let scaled = p.apply_scale(res.clone(), &f2);
                let (mut acc, mut w) = (0.0, 0.0);
                for pt in &p.points {
                    let r = &scaled.incidences[pt.inc];
                    let e = r.value[pt.det] - pt.m;
                    acc += (e * e - r.value_stderr[pt.det].powi(2)) / pt.m - 2.0 * e * (pt.sm / pt.m).powi(2);
                    w += pt.m;
                }
                assert!(acc / w > obj, "{m:?} group {g} ×{h}: {} ≤ {obj}", acc / w);
            }
        }
        // the simulation times its best factors needs no further factor
        let again = p.fit_scale(&p.apply_scale(res.clone(), &fit));
        assert!(again.factors.iter().all(|k| (k - 1.0).abs() < 1e-12), "{again:?}");
    }
}

#[test]
fn scaled_measurement_scales_the_factor_only() {
    // m → c m (values and errors): every factor × c, the objective (normalised by Σ m) and so
    // the fitted NDF unchanged
    for m in [ScaleMode::Global, ScaleMode::PerIncidence] {
        let (p1, res) = scaled_problem(mode(m), 1.0);
        let (p2, _) = scaled_problem(mode(m), 1.7);
        let (o1, f1) = p1.objective_of(&res);
        let (o2, f2) = p2.objective_of(&res);
        assert!((o2 / o1 - 1.0).abs() < 1e-12, "{o1} {o2}");
        for g in 0..f1.factors.len() {
            assert!((f2.factors[g] / f1.factors[g] / 1.7 - 1.0).abs() < 1e-12);
            assert!((f2.stderr[g] / f1.stderr[g] / 1.7 - 1.0).abs() < 1e-9);
        }
    }
}

#[test]
fn absolute_values_have_no_factor() {
    let (p, res) = scaled_problem(ScaleSetup::default(), 1.0);
    assert!(p.scale_groups().is_empty());
    let (obj, fit) = p.objective_of(&res);
    assert_eq!(fit, ScaleFit::none());
    let same = p.apply_scale(res.clone(), &fit);
    assert_eq!(same.incidences[1].value, res.incidences[1].value);
    // the objective is bit for bit the formula without factors
    let (mut acc, mut w) = (0.0, 0.0);
    for pt in &p.points {
        let r = &res.incidences[pt.inc];
        acc += ((r.value[pt.det] - pt.m).powi(2) - r.value_stderr[pt.det] * r.value_stderr[pt.det]) / pt.m;
        w += pt.m;
    }
    assert_eq!(obj.to_bits(), (acc / w).to_bits());
}

#[test]
fn prior_pulls_the_factor_towards_one() {
    let (p, res) = scaled_problem(mode(ScaleMode::Global), 1.3);
    let free = p.fit_scale(&res);
    let (kd, sd) = (free.factors[0], free.stderr[0]);
    let with = |sk: f64| {
        let (q, _) = scaled_problem(ScaleSetup { mode: ScaleMode::Global, prior: Some(sk) }, 1.3);
        q.fit_scale(&res)
    };
    // the precision-weighted mean of the data's factor and 1
    for sk in [0.01, 0.05, 0.2] {
        let f = with(sk);
        let expect = (kd / (sd * sd) + 1.0 / (sk * sk)) / (1.0 / (sd * sd) + 1.0 / (sk * sk));
        assert!((f.factors[0] - expect).abs() < 1e-9 * expect, "σk {sk}: {} vs {expect}", f.factors[0]);
        assert!(f.stderr[0] < sd.min(sk) && f.penalty > 0.0);
    }
    assert!((with(1e3).factors[0] - kd).abs() < 1e-6);
    assert!((with(1e-5).factors[0] - 1.0).abs() < 1e-3);
}

#[test]
fn scale_settings_are_checked() {
    let (p, _) = scaled_problem(mode(ScaleMode::Global), 1.0);
    let bad = |f: &dyn Fn(&mut FitSetup)| {
        let mut s = p.setup.clone();
        f(&mut s);
        Problem::new(p.measured.clone(), s).err().map(|e| e.to_string())
    };
    assert!(bad(&|s| s.scale.prior = Some(-0.1)).unwrap().contains("scale prior"));
    assert!(bad(&|s| s.scale = ScaleSetup { mode: ScaleMode::Absolute, prior: Some(0.05) }).is_some());
    assert!(bad(&|s| s.rel_error = f64::NAN).unwrap().contains("relative error"));
    assert!(bad(&|_| ()).is_none());
    // the relative error is added in quadrature to the file's
    let mut s = p.setup.clone();
    s.rel_error = 0.03;
    let q = Problem::new(p.measured.clone(), s).unwrap();
    let (c0, c1) = (&p.measured.curves[1], &q.measured.curves[1]);
    for k in 0..c0.value.len() {
        let want = c0.stderr[k].hypot(0.03 * c0.value[k]);
        assert!((c1.stderr[k] - want).abs() <= 1e-15 * want.max(1e-300));
    }
    assert_eq!(ScaleMode::parse("per-incidence"), Some(ScaleMode::PerIncidence));
    assert_eq!(ScaleMode::parse("relative"), None);
}

/// A set cancel flag stops the whole fit with `Interrupted` (every simulation checks it); an
/// unset one gives the same fit as no flag at all.
#[test]
fn cancel_flag_stops_the_fit_and_unset_changes_nothing() {
    let opts = FitOptions { family: Some(Family::Ggx), ..Default::default() };
    let (p, _) = scaled_problem(mode(ScaleMode::Absolute), 1.0);
    let plain = fit(&p, &opts).unwrap();
    let flag = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let (p, _) = scaled_problem(mode(ScaleMode::Absolute), 1.0);
    let p = p.with_cancel(Some(flag.clone()));
    let unset = fit(&p, &opts).unwrap();
    let (a, b) = (&plain.candidates[plain.best].fit, &unset.candidates[unset.best].fit);
    assert_eq!(a.model, b.model);
    assert_eq!(a.objective.to_bits(), b.objective.to_bits());
    flag.store(true, std::sync::atomic::Ordering::SeqCst);
    let e = fit(&p, &opts).unwrap_err();
    assert!(matches!(e, opal::Error::Interrupted { .. }), "{e}");
}

#[test]
fn node_step_that_worsens_the_objective_is_rejected() {
    // the rule itself: ΔX above the threshold is not enough when the objective got worse
    let c = Comparison {
        delta_chi2: 50.0,
        sd: 5.0,
        inflation: 1.0,
        extra_params: 1,
        threshold: 6.635 + Z99 * 5.0,
        accepted: true,
        objectives: None,
    };
    assert!(step_accepted(&c, (2.0, 1.5), (0.3, 0.2)));
    assert!(!step_accepted(&c, (2.0, 2.5), (0.3, 0.2)), "a worse objective must reject the step");
    assert!(!step_accepted(&c, (2.0, 2.0), (0.3, 0.2)));
    assert!(!step_accepted(&c, (2.0, 1.5), (0.3, 0.37)), "a worse rms must reject the step");
    assert!(!step_accepted(&Comparison { delta_chi2: 10.0, ..c.clone() }, (2.0, 1.5), (0.3, 0.2)));
    // through the problem: a node that triples D at θm = 0 on GGX α = 0.2 data (synthetic,
    // 20 000 photons) is worse than the truth at the check seed, and the step rule says so
    let (p, _) = scaled_problem(mode(ScaleMode::Absolute), 1.0);
    let truth = Model::new(Family::Ggx, 0.2);
    let mut peaked = with_node(&truth, 0.0, 2f64.to_radians());
    let k = peaked.free_nodes()[0];
    peaked.nodes[k].1 = 3.0;
    let (a, b) = (p.check(&truth).unwrap(), p.check(&peaked).unwrap());
    let c = p.compare_step(&a, &b, 1);
    let (oa, ob) = c.objectives.expect("a node step records both objectives");
    assert!(ob > oa && !c.accepted, "{c:?}");
    // the other way round the objective drops; whether ΔX clears the threshold decides
    let c = p.compare_step(&b, &a, 1);
    let (oa, ob) = c.objectives.unwrap();
    let rms_ok = a.rms <= b.rms;
    assert!(ob < oa && c.accepted == (c.delta_chi2 > c.threshold && rms_ok), "{c:?}");
}

/// The absolute-mode calibration check flags data scaled ×0.8 and passes unscaled data
/// (synthetic points with 5 % measurement and 3 % simulation noise, deterministic jitter).
#[test]
fn scale_check_flags_scaled_data() {
    let pts = |f: f64| {
        (0..40).map(move |i| {
            let s = 1.0 + 0.1 * i as f64;
            let jitter = 0.02 * ((i * 7 % 5) as f64 - 2.0) / 2.0;
            let m = f * s * (1.0 + jitter);
            (m, 0.05 * m, s, 0.03 * s)
        })
    };
    let ok = super::ScaleCheck::from_points(pts(1.0)).unwrap();
    assert!(!ok.mismatch, "{ok:?}");
    assert!((ok.k - 1.0).abs() < 3.0 * ok.stderr, "{ok:?}");
    let bad = super::ScaleCheck::from_points(pts(0.8)).unwrap();
    assert!(bad.mismatch, "{bad:?}");
    assert!((bad.k - 0.8).abs() < 3.0 * bad.stderr, "{bad:?}");
}
