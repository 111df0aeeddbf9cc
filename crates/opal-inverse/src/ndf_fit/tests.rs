//! Unit tests of the NDF fit: models build the right NDF, coordinates are clamped and
//! penalised, χ² quantiles.

use super::model::{Coord, apply};
use super::*;
use opal::bsdf::microfacet::Ndf;
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
fn chi2_quantiles() {
    assert_eq!(chi2_q99(1), 6.635);
    // Wilson–Hilferty beyond the table: χ²₀.₉₉(10) = 23.209
    assert!((chi2_q99(10) - 23.209).abs() < 0.1, "{}", chi2_q99(10));
}
