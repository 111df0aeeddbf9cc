//! The normalisation fitter: least-squares constants of a normalisation expression `c(n; A, B)`
//! (the paper's curve fit, Levenberg–Marquardt) and the tightest constants with `max R ≤ 1`.
//!
//! Tests: `tests.rs` (fit recovers the paper's `A` and a bounded pair).

use super::sweep::{golden_max, grid, incidence_grid, max_over_incidence, validate_ranges};
use super::{EnergyError, FitReport, FittedConstants, Quadrature, Result, invalid};
use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{DMatrix, DVector, Dyn, Owned};
use opal::bsdf::normexpr::NormExpr;
use opal::bsdf::registry::{ModelSpec, NormSpec};
use rayon::prelude::*;

/// Settings of [`fit_norm`].
#[derive(Clone, Debug)]
pub struct FitConfig {
    /// Exponent range.
    pub range: (f64, f64),
    /// Incidence range, degrees: `R₀(n)` is the maximum over it.
    pub incidence_deg: (f64, f64),
    /// Incidence grid points before refinement.
    pub incidence_points: usize,
    /// Initial `A`, `B` of the least-squares fit (also the values of unused constants).
    pub start: (f64, f64),
    /// Quadrature resolution.
    pub quadrature: Quadrature,
    /// Largest number of exponent samples (integers are used when the range holds fewer).
    pub max_samples: usize,
}

impl Default for FitConfig {
    fn default() -> Self {
        FitConfig {
            range: (1.0, 1000.0),
            incidence_deg: (0.0, 89.0),
            incidence_points: 10,
            start: (6.0, 24.55),
            quadrature: Quadrature::default(),
            max_samples: 1000,
        }
    }
}

struct Lsq<'a> {
    form: &'a NormExpr,
    ns: &'a [f64],
    r0: &'a [f64],
    /// which constants are free: A, B
    free: (bool, bool),
    fixed: (f64, f64),
    p: DVector<f64>,
    /// B as a function of A for the bounded fit (A is then the only free constant)
    b_of_a: Option<&'a dyn Fn(f64) -> Option<f64>>,
}

impl Lsq<'_> {
    fn ab(&self, p: &DVector<f64>) -> Option<(f64, f64)> {
        let mut k = 0;
        let mut a = self.fixed.0;
        let mut b = self.fixed.1;
        if self.free.0 {
            a = p[k];
            k += 1;
        }
        if self.free.1 {
            b = p[k];
        }
        if let Some(f) = self.b_of_a {
            b = f(a)?;
        }
        Some((a, b))
    }
    fn res(&self, p: &DVector<f64>) -> Option<DVector<f64>> {
        let (a, b) = self.ab(p)?;
        let v = DVector::from_iterator(
            self.ns.len(),
            self.ns.iter().zip(self.r0).map(|(&n, &r)| self.form.eval(n, a, b) * r - 1.0),
        );
        v.iter().all(|x| x.is_finite()).then_some(v)
    }
}

impl LeastSquaresProblem<f64, Dyn, Dyn> for Lsq<'_> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;
    fn set_params(&mut self, x: &DVector<f64>) {
        self.p.copy_from(x);
    }
    fn params(&self) -> DVector<f64> {
        self.p.clone()
    }
    fn residuals(&self) -> Option<DVector<f64>> {
        self.res(&self.p)
    }
    fn jacobian(&self) -> Option<DMatrix<f64>> {
        // central differences; the residuals are smooth in the constants
        let m = self.ns.len();
        let k = self.p.len();
        let mut j = DMatrix::zeros(m, k);
        for c in 0..k {
            let h = 1e-6 * self.p[c].abs().max(1.0);
            let mut pp = self.p.clone();
            pp[c] += h;
            let rp = self.res(&pp)?;
            pp[c] -= 2.0 * h;
            let rm = self.res(&pp)?;
            j.set_column(c, &((rp - rm) / (2.0 * h)));
        }
        Some(j)
    }
}

fn run_lm(mut problem: Lsq<'_>) -> Result<DVector<f64>> {
    let start = problem.p.clone();
    if problem.res(&start).is_none() {
        return Err(EnergyError::Fit(format!(
            "the normalisation is not finite at the starting constants {:?}",
            start.as_slice()
        )));
    }
    problem.p = start;
    let (p, report) = LevenbergMarquardt::new().with_patience(200).minimize(problem);
    if !report.termination.was_successful() {
        return Err(EnergyError::Fit(format!("Levenberg–Marquardt stopped: {:?}", report.termination)));
    }
    Ok(p.p)
}

/// Fits the constants of `form` for `spec`'s raw lobe (the model's own normalisation is
/// replaced): least squares of `c(n)·R₀(n) − 1` over the exponent samples (Levenberg–Marquardt,
/// the paper's curve fit), and the tightest constants with `max R ≤ 1` — for each `A` the
/// smallest `B` keeping every sample's `R ≤ 1` (bisection; `c` must decrease in `B`), `A` then
/// chosen by least squares (LM again), and `B` finally raised to cover the continuous maximum
/// between samples. `R₀(n)` is the maximum over the incidence range of the raw lobe's `R`.
pub fn fit_norm(spec: &ModelSpec, form: &NormExpr, cfg: &FitConfig) -> Result<FitReport> {
    validate_ranges(cfg.range, cfg.incidence_deg)?;
    if !spec.info.accepts_norm() {
        return Err(invalid(
            format!("model '{}'", spec.info.name),
            "has no exponent n: nothing to normalise",
        ));
    }
    let free = form.uses();
    if !free.0 && !free.1 {
        return Err(invalid(
            format!("normalisation form \"{form}\""),
            "uses neither A nor B: nothing to fit",
        ));
    }
    let raw = spec.clone().with_norm(NormSpec { expr: NormExpr::parse("1")?, a: 0.0, b: 1.0 })?;
    let (lo, hi) = cfg.range;
    let nint = (hi.floor() - lo.ceil()) as i64 + 1;
    let ns: Vec<f64> = if nint >= 2 && (nint as usize) <= cfg.max_samples {
        (lo.ceil() as i64..=hi.floor() as i64).map(|i| i as f64).collect()
    } else {
        grid(lo, hi, cfg.max_samples.max(2), lo > 0.0)
    };
    let thetas = incidence_grid(cfg.incidence_deg, cfg.incidence_points);
    let q = cfg.quadrature;
    let r0_at = |n: f64| -> Result<f64> { Ok(max_over_incidence(&raw.build(n)?, &thetas, &q).0) };
    let r0: Vec<f64> = ns.par_iter().map(|&n| r0_at(n)).collect::<Result<_>>()?;

    let mut p0 = Vec::new();
    if free.0 {
        p0.push(cfg.start.0);
    }
    if free.1 {
        p0.push(cfg.start.1);
    }
    let ls = Lsq {
        form,
        ns: &ns,
        r0: &r0,
        free,
        fixed: cfg.start,
        p: DVector::from_vec(p0.clone()),
        b_of_a: None,
    };
    let p = run_lm(ls)?;
    let ls_ab = {
        let mut k = 0;
        let a = if free.0 {
            k += 1;
            p[0]
        } else {
            cfg.start.0
        };
        let b = if free.1 { p[k] } else { cfg.start.1 };
        (a, b)
    };

    // continuous maximum of c(n)·R₀(n): best sample, then golden-section refinement
    let max_of = |a: f64, b: f64| -> (f64, f64) {
        let vals: Vec<f64> = ns.iter().zip(&r0).map(|(&n, &r)| form.eval(n, a, b) * r).collect();
        let i = (0..vals.len()).fold(0, |m, i| if vals[i] > vals[m] { i } else { m });
        let (l, h) = (ns[i.saturating_sub(1)], ns[(i + 1).min(ns.len() - 1)]);
        let f = |n: f64| form.eval(n, a, b) * r0_at(n).unwrap_or(f64::NAN);
        let (n, v) = golden_max(&f, l, h, 1e-3 * (h - l).max(1e-9));
        if v > vals[i] { (v, n) } else { (vals[i], ns[i]) }
    };
    let rms = |a: f64, b: f64| -> f64 {
        (ns.iter().zip(&r0).map(|(&n, &r)| (form.eval(n, a, b) * r - 1.0).powi(2)).sum::<f64>()
            / ns.len() as f64)
            .sqrt()
    };
    let (m, am) = max_of(ls_ab.0, ls_ab.1);
    let least_squares = FittedConstants {
        a: ls_ab.0,
        b: ls_ab.1,
        max_reflectance: m,
        argmax_param: am,
        rms_residual: rms(ls_ab.0, ls_ab.1),
    };

    // bounded: the "scale" constant is B if the form uses it, else A
    let scale_is_b = free.1;
    let sample_max = |a: f64, b: f64, extra: &[(f64, f64)]| -> f64 {
        ns.iter()
            .zip(&r0)
            .chain(extra.iter().map(|(n, r)| (n, r)))
            .map(|(&n, &r)| form.eval(n, a, b) * r)
            .fold(f64::MIN, f64::max)
    };
    // the scale constant s closest to `start` with every sample's R ≤ 1 (and c ≥ 0), the other
    // constant fixed: bracket the sign change of g = max R − 1 by steps growing geometrically on
    // both sides of `start`, then bisect and keep the feasible end
    let tight = |other: f64, start: f64, extra: &[(f64, f64)]| -> Option<f64> {
        let g = |s: f64| {
            let (a, b) = if scale_is_b { (other, s) } else { (s, other) };
            let negative = ns.iter().any(|&n| form.eval(n, a, b) < 0.0);
            let v = sample_max(a, b, extra) - 1.0;
            if negative || !v.is_finite() { f64::INFINITY } else { v }
        };
        let g0 = g(start);
        let feasible0 = g0 <= 0.0;
        let step = start.abs().max(1.0) / 1024.0;
        let mut other_end = None;
        'search: for k in 0..50 {
            for sgn in [1.0, -1.0] {
                let s = start + sgn * step * 2f64.powi(k);
                if (g(s) <= 0.0) != feasible0 {
                    other_end = Some(s);
                    break 'search;
                }
            }
        }
        let s1 = other_end?;
        let (mut bad, mut ok) = if feasible0 { (s1, start) } else { (start, s1) };
        for _ in 0..200 {
            let m = 0.5 * (bad + ok);
            if g(m) > 0.0 {
                bad = m;
            } else {
                ok = m;
            }
            if (bad - ok).abs() <= 1e-13 * ok.abs().max(1e-12) {
                break;
            }
        }
        Some(ok)
    };
    let (other0, scale0) = if scale_is_b { (ls_ab.0, ls_ab.1) } else { (ls_ab.1, ls_ab.0) };
    let mut extra: Vec<(f64, f64)> = Vec::new();
    let fail = || {
        EnergyError::Fit(format!("cannot make max R ≤ 1 by changing {}", if scale_is_b { "B" } else { "A" }))
    };
    let mut other = other0;
    if free.0 && free.1 {
        // one free constant (A) left: least squares with B = B_tight(A)
        let b_of_a = |a: f64| tight(a, scale0, &[]);
        let prob = Lsq {
            form,
            ns: &ns,
            r0: &r0,
            free: (true, false),
            fixed: (ls_ab.0, ls_ab.1),
            p: DVector::from_vec(vec![ls_ab.0]),
            b_of_a: Some(&b_of_a),
        };
        other = run_lm(prob)?[0];
    }
    let mut scale = tight(other, scale0, &extra).ok_or_else(fail)?;
    // cover the continuous maximum between samples (a few rounds; each adds the refined point)
    for _ in 0..4 {
        let (a, b) = if scale_is_b { (other, scale) } else { (scale, other) };
        let (m, n) = max_of(a, b);
        if m <= 1.0 {
            break;
        }
        extra.push((n, r0_at(n)?));
        scale = tight(other, scale, &extra).ok_or_else(fail)?;
    }
    let (a, b) = if scale_is_b { (other, scale) } else { (scale, other) };
    let (m, am) = max_of(a, b);
    let bounded = FittedConstants { a, b, max_reflectance: m, argmax_param: am, rms_residual: rms(a, b) };
    Ok(FitReport {
        model: spec.info.name.to_string(),
        form: form.source().to_string(),
        range: cfg.range,
        samples: ns.len(),
        least_squares,
        bounded,
    })
}
