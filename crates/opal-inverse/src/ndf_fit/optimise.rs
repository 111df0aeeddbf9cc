//! Optimisers: the initial guess of α from the measured lobe width (one probe simulation),
//! Brent's method on ln α for the one-parameter families and Nelder–Mead over the bounded
//! coordinates of the multi-parameter models (Student-t, shift, hybrid), each in two stages
//! (coarse from the guess, fine from the coarse optimum); the argmin cost functions; the
//! per-model result ([`FamilyFit`]).
//!
//! Tests: `crates/opal-inverse/tests/ndf_fit.rs` (round trips).

use super::model::{Coord, apply};
use super::{Family, Model, Problem, ScaleFit, Stage};
use argmin::core::{CostFunction, Executor, State, TerminationReason, TerminationStatus};
use argmin::solver::brent::BrentOpt;
use argmin::solver::neldermead::NelderMead;
use opal::gonio::Side;
use std::sync::Mutex;

/// Result of fitting one model.
#[derive(Clone, Debug)]
pub struct FamilyFit {
    /// The fitted model (every parameter; `model.family`, `model.alpha`).
    pub model: Model,
    /// Initial α (from the lobe width, or from the fit this one started from).
    pub alpha_initial: f64,
    /// Objective at the optimum (fine stage; common random numbers;
    /// Σ((s − m)² − σs²)/m / Σm).
    pub objective: f64,
    /// Simulations run for this model (probe included), both stages.
    pub evaluations: u64,
    /// Whether every optimiser stage converged.
    pub converged: bool,
    /// Calibration factors of the measurement at the optimum (closed form for the fine
    /// stage's simulation of `model`; none when the values are absolute).
    pub scale: ScaleFit,
    /// (parameters, objective) of every evaluation in order; parameters as in
    /// [`Model::param_values`], the stage is `coarse`/`fine`.
    pub history: Vec<(&'static str, Vec<f64>, f64)>,
}

impl FamilyFit {
    /// Fitted parameters: the model's and the calibration factors (what the selection rule
    /// counts; two candidates of one fit have the same factors, so they cancel in its
    /// difference of parameter counts).
    pub fn parameter_count(&self) -> usize {
        self.model.parameter_count() + self.scale.factors.len()
    }
}

/// (stage, reported parameters, objective) of every evaluation.
type History = Vec<(&'static str, Vec<f64>, f64)>;

/// What the cost functions record: every evaluation (stage, reported parameters, objective)
/// and the calibration factors of every fine-stage evaluation (by reported parameters).
#[derive(Default)]
struct EvalLog {
    history: Mutex<History>,
    scales: Mutex<Vec<(Vec<f64>, ScaleFit)>>,
}

impl Problem {
    /// Half width at half maximum (radians) of the transmitted lobe of the smallest incidence,
    /// from the values `v` of curve `ci`'s detectors.
    fn lobe_hwhm(&self, ci: usize, v: &[f64]) -> Option<f64> {
        let c = &self.measured.curves[ci];
        if !self.measured.hemisphere {
            return hwhm(&c.detector, v);
        }
        // hemisphere: the plane-of-incidence detectors (azimuth 0 → +θ, 180° → −θ)
        let mut inplane: Vec<(f64, f64)> = Vec::new();
        for (k, (&t, &a)) in c.detector.iter().zip(&c.azimuth).enumerate() {
            let a = a.to_degrees();
            if t == 0.0 || a.abs() < 1e-6 {
                inplane.push((t, v[k]));
            } else if (a - 180.0).abs() < 1e-6 {
                inplane.push((-t, v[k]));
            }
        }
        inplane.sort_by(|x, y| x.0.total_cmp(&y.0));
        let (angles, vals): (Vec<f64>, Vec<f64>) = inplane.into_iter().unzip();
        hwhm(&angles, &vals)
    }

    fn initial_curve(&self) -> Option<usize> {
        // the transmitted curve of the smallest incidence, else the first curve
        self.measured.curves.iter().position(|c| c.side == Side::T).or(Some(0))
    }

    /// Initial α for `family` from the measured lobe width (one probe simulation, coarse
    /// stage).
    pub fn initial_alpha(&self, family: Family) -> opal::Result<f64> {
        let n = self.setup.plate.ior;
        let ci = self.initial_curve().expect("at least one curve");
        let Some(w) = self.lobe_hwhm(ci, &self.measured.curves[ci].value) else {
            return Ok(0.2);
        };
        // smooth-face geometry: deflection ≈ (n − 1) θm (see module docs)
        let theta_m = (w / (n - 1.0).abs().max(0.05)).min(1.2);
        let a_probe = (theta_m.tan() / family.half_max_slope()).clamp(0.01, 2.0);
        let res = self.simulate(
            Model::new(family, a_probe).ndf()?,
            self.setup.seed,
            self.stage_photons(Stage::Coarse),
        )?;
        let inc = self.incidence_index(ci);
        let sim: Vec<f64> = self.all[ci].iter().map(|&d| res.incidences[inc].value[d]).collect();
        Ok(match self.lobe_hwhm(ci, &sim) {
            Some(wp) if wp > 0.0 => (a_probe * w / wp).clamp(0.005, 2.0),
            _ => a_probe,
        })
    }

    /// Fits α of a one-parameter family (Beckmann or GGX; Brent on ln α, coarse then fine
    /// stage).
    pub fn fit_family(&self, family: Family) -> opal::Result<FamilyFit> {
        let e0 = self.evaluations();
        let a0 = self.initial_alpha(family)?;
        let log = EvalLog::default();
        let start = Model::new(family, a0);
        let mut model = start.clone();
        let mut converged = true;
        let mut objective = f64::INFINITY;
        let stages: &[(Stage, f64, f64)] = if self.has_coarse_stage() {
            &[(Stage::Coarse, 1.8, 1e-2), (Stage::Fine, 1.12, 1e-3)]
        } else {
            &[(Stage::Fine, 1.8, 1e-3)]
        };
        for &(stage, span, tol) in stages {
            let (x, fx, ok) = self.brent(&model, stage, span.ln(), tol, &log)?;
            model.alpha = x.exp();
            objective = fx;
            converged &= ok;
        }
        let (scale, history) = self.scale_at(&model, log)?;
        Ok(FamilyFit {
            alpha_initial: a0,
            model,
            objective,
            evaluations: self.evaluations() - e0,
            converged,
            scale,
            history,
        })
    }

    /// Brent on ln α around `start`'s α (bracket ±`span`, moved when the optimum lands on an
    /// edge). Returns (ln α, objective, converged).
    fn brent(
        &self,
        start: &Model,
        stage: Stage,
        span: f64,
        tol: f64,
        log: &EvalLog,
    ) -> opal::Result<(f64, f64, bool)> {
        let mut center = start.alpha.ln();
        let mut best = (center, f64::INFINITY);
        let mut converged = false;
        for _round in 0..4 {
            let (lo, hi) = (center - span, center + span);
            let cost =
                Cost1 { inner: ParamCost { problem: self, start, coords: &[Coord::LnAlpha], stage, log } };
            let solver = BrentOpt::new(lo, hi).set_tolerance(0.0, tol);
            let res = Executor::new(cost, solver)
                .configure(|s| s.max_iters(self.setup.max_iters))
                .run()
                .map_err(|e| opal::Error::invalid("optimiser", e.to_string()))?;
            let st = res.state();
            let x = *st.get_best_param().unwrap_or(&center);
            let fx = st.get_best_cost();
            if fx < best.1 {
                best = (x, fx);
            }
            let ok = matches!(
                st.get_termination_status(),
                TerminationStatus::Terminated(TerminationReason::SolverConverged)
            );
            let at_edge =
                (x - lo).abs() < 0.02 * span / 1.8f64.ln() || (hi - x).abs() < 0.02 * span / 1.8f64.ln();
            if ok && !at_edge {
                converged = true;
                break;
            }
            if !at_edge {
                break;
            }
            center = x;
        }
        Ok((best.0, best.1, converged))
    }

    /// Nelder–Mead over `coords` from `start` (initial simplex: `start` plus one step along
    /// each coordinate, `scale` × the coordinate's coarse step, towards the inside of its
    /// bounds). Returns (model, objective, converged).
    fn nelder_mead(
        &self,
        start: &Model,
        coords: &[Coord],
        stage: Stage,
        scale: f64,
        sd_tol: f64,
        log: &EvalLog,
    ) -> opal::Result<(Model, f64, bool)> {
        let x0: Vec<f64> = coords.iter().map(|c| c.get(start)).collect();
        let mut simplex = vec![x0.clone()];
        for (i, c) in coords.iter().enumerate() {
            let (lo, hi) = c.bounds();
            let s = c.step() * scale;
            let mut x = x0.clone();
            x[i] = if x0[i] + s <= hi { x0[i] + s } else { (x0[i] - s).max(lo) };
            simplex.push(x);
        }
        let cost = ParamCost { problem: self, start, coords, stage, log };
        let solver = NelderMead::new(simplex)
            .with_sd_tolerance(sd_tol.max(0.0))
            .map_err(|e| opal::Error::invalid("optimiser", e.to_string()))?;
        // the iteration budget is per free coordinate: Nelder–Mead needs more steps in more
        // dimensions (a 3-coordinate hybrid hit a flat 40-step cap before its tolerance)
        let iters = self.setup.max_iters.saturating_mul(coords.len().max(1) as u64);
        let res = Executor::new(cost, solver)
            .configure(|s| s.max_iters(iters))
            .run()
            .map_err(|e| opal::Error::invalid("optimiser", e.to_string()))?;
        let st = res.state();
        let x = st.get_best_param().cloned().unwrap_or(x0);
        let fx = st.get_best_cost();
        let ok = matches!(
            st.get_termination_status(),
            TerminationStatus::Terminated(TerminationReason::SolverConverged)
        );
        Ok((apply(start, coords, &x).0, fx, ok))
    }

    /// Fits a multi-parameter model (Student-t, shift, hybrid): Nelder–Mead over the model's
    /// free coordinates, coarse stage from `start` with the coordinates' steps × `step_scale`
    /// (1 from a rough guess, less from a fitted model), then a fine stage from its optimum with
    /// steps / 8. Termination: the standard deviation of the objective over the simplex below
    /// 1 % of the objective's noise unit.
    pub fn fit_model(&self, start: &Model, step_scale: f64) -> opal::Result<FamilyFit> {
        let mut coords = vec![Coord::LnAlpha];
        if start.gamma.is_some() {
            coords.push(Coord::Q);
        }
        if start.delta.is_some() {
            coords.push(Coord::DeltaDeg);
        }
        for k in start.free_nodes() {
            coords.push(Coord::LnScale(k));
        }
        if start.coverage.is_some() {
            coords.push(Coord::LogitCoverage);
        }
        self.fit_coords(start, &coords, step_scale)
    }

    /// A starting point for a dotted model whose dots have the NDF shape `base` (GGX or
    /// Beckmann): the best of a coarse grid (α ∈ {0.08, 0.15, 0.3, 0.6} × coverage ∈ {0.1, 0.3,
    /// 0.6}, objective at the coarse stage). The spike of the polished land dominates the
    /// measured lobe width, so the single-NDF guess from the HWHM says nothing about the dots;
    /// 12 coarse simulations bracket them.
    pub fn dotted_start(&self, base: Family) -> opal::Result<Model> {
        let mut best: Option<(f64, Model)> = None;
        for alpha in [0.08, 0.15, 0.3, 0.6] {
            for f in [0.1, 0.3, 0.6] {
                let mut m = Model::new(Family::Dotted, alpha);
                m.base = base;
                m.coverage = Some(f);
                let (o, _) = self.objective(&m, Stage::Coarse)?;
                if best.as_ref().is_none_or(|b| o < b.0) {
                    best = Some((o, m));
                }
            }
        }
        Ok(best.expect("grid not empty").1)
    }

    /// Refits a hybrid model: α and every free node multiplier together, from `start` (the
    /// final step of a hybrid fit, after the incremental node steps; the shape parameters γ,
    /// δ of the analytic part stay as fitted before the nodes were added).
    pub fn fit_hybrid(&self, start: &Model) -> opal::Result<FamilyFit> {
        let mut coords = vec![Coord::LnAlpha];
        for k in start.free_nodes() {
            coords.push(Coord::LnScale(k));
        }
        self.fit_coords(start, &coords, 0.5)
    }

    /// One incremental hybrid node step: `prev` (a fitted model) with one more node at
    /// `theta` (grid spacing `h`, [`with_node`](super::with_node)), only the new node's
    /// multiplier fitted (coarse then fine stage, warm-started at `prev`'s multiplier there,
    /// so the start is `prev`'s NDF); α and the nodes fitted before keep their values. Refitting
    /// α and every node from a fresh simplex at each step took 66 % of a forced hybrid fit's
    /// simulations (dotted plate, `tests/hybrid_profile.rs`).
    pub fn fit_hybrid_step(&self, prev: &Model, theta: f64, h: f64) -> opal::Result<FamilyFit> {
        let m = super::with_node(prev, theta, h);
        let t = (theta / h).round().max(0.0) * h;
        let k = m
            .free_nodes()
            .into_iter()
            .find(|&i| (m.nodes[i].0 - t).abs() < 1e-9 * h.max(1.0))
            .expect("with_node adds a free node at the snapped angle");
        let mut fit = self.fit_coords(&m, &[Coord::LnScale(k)], 0.5)?;
        fit.alpha_initial = prev.alpha;
        Ok(fit)
    }

    fn fit_coords(&self, start: &Model, coords: &[Coord], step_scale: f64) -> opal::Result<FamilyFit> {
        let e0 = self.evaluations();
        let log = EvalLog::default();
        let probe = self.simulate_model(start, self.setup.seed, self.stage_photons(Stage::Fine))?;
        let unit = self.objective_noise_for(&probe, start.coverage.is_some());
        let mut model = start.clone();
        let mut objective = f64::INFINITY;
        let mut converged = true;
        let stages: &[(Stage, f64, f64)] = if self.has_coarse_stage() {
            &[(Stage::Coarse, step_scale, 1e-2), (Stage::Fine, step_scale / 8.0, 1e-2)]
        } else {
            &[(Stage::Fine, step_scale, 1e-2)]
        };
        for &(stage, scale, tol) in stages {
            let (m, fx, ok) = self.nelder_mead(&model, coords, stage, scale, tol * unit, &log)?;
            model = m;
            objective = fx;
            converged &= ok;
        }
        let (scale, history) = self.scale_at(&model, log)?;
        Ok(FamilyFit {
            alpha_initial: start.alpha,
            model,
            objective,
            evaluations: self.evaluations() - e0,
            converged,
            scale,
            history,
        })
    }

    /// The calibration factors of the fine stage at `model` (from the log: the optimum was
    /// evaluated, else from one more simulation; none without factors) and the history.
    fn scale_at(&self, model: &Model, log: EvalLog) -> opal::Result<(ScaleFit, History)> {
        let history = log.history.into_inner().expect("no panic while recording");
        if self.groups.is_empty() {
            return Ok((ScaleFit::none(), history));
        }
        let x = model.param_values();
        let scales = log.scales.into_inner().expect("no panic while recording");
        if let Some((_, s)) = scales.into_iter().rev().find(|(p, _)| *p == x) {
            return Ok((s, history));
        }
        let res = self.simulate_model(model, self.setup.seed, self.stage_photons(Stage::Fine))?;
        Ok((self.fit_scale(&res), history))
    }
}

struct ParamCost<'a> {
    problem: &'a Problem,
    start: &'a Model,
    coords: &'a [Coord],
    stage: Stage,
    log: &'a EvalLog,
}

impl CostFunction for ParamCost<'_> {
    type Param = Vec<f64>;
    type Output = f64;
    fn cost(&self, x: &Vec<f64>) -> Result<f64, argmin::core::Error> {
        let (m, pen) = apply(self.start, self.coords, x);
        let (f, scale) =
            self.problem.objective(&m, self.stage).map_err(|e| argmin::core::Error::msg(e.to_string()))?;
        let label = if self.stage == Stage::Coarse { "coarse" } else { "fine" };
        if self.stage == Stage::Fine && !scale.factors.is_empty() {
            self.log.scales.lock().expect("no panic while recording").push((m.param_values(), scale));
        }
        self.log.history.lock().expect("no panic while recording").push((label, m.param_values(), f));
        Ok(f + pen)
    }
}

struct Cost1<'a> {
    inner: ParamCost<'a>,
}

impl CostFunction for Cost1<'_> {
    type Param = f64;
    type Output = f64;
    fn cost(&self, x: &f64) -> Result<f64, argmin::core::Error> {
        self.inner.cost(&vec![*x])
    }
}

/// Fits every one-parameter family in `families` and returns the fits sorted by objective
/// (best first).
pub fn fit_families(problem: &Problem, families: &[Family]) -> opal::Result<Vec<FamilyFit>> {
    let mut fits = Vec::new();
    for &f in families {
        fits.push(problem.fit_family(f)?);
    }
    fits.sort_by(|a, b| a.objective.total_cmp(&b.objective));
    Ok(fits)
}

/// Half width at half maximum (radians) of the lobe with values `v` at ascending signed
/// angles `angles`.
fn hwhm(angles: &[f64], v: &[f64]) -> Option<f64> {
    let (ipk, &vmax) = v.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1))?;
    if vmax <= 0.0 {
        return None;
    }
    let half = 0.5 * vmax;
    let mut widths = Vec::new();
    for dir in [-1i64, 1] {
        let mut k = ipk as i64;
        while k + dir >= 0 && ((k + dir) as usize) < v.len() {
            let k2 = (k + dir) as usize;
            if v[k2] < half {
                let (a0, a1) = (angles[k as usize], angles[k2]);
                let (v0, v1) = (v[k as usize], v[k2]);
                let f = (v0 - half) / (v0 - v1);
                widths.push((a0 + f * (a1 - a0) - angles[ipk]).abs());
                break;
            }
            k += dir;
        }
    }
    if widths.is_empty() { None } else { Some(widths.iter().sum::<f64>() / widths.len() as f64) }
}
