//! Model selection: the rule deciding whether a richer (nesting) model B fits better than a
//! simpler model A by more than noise explains ([`Problem::compare`], [`Comparison`]), with the
//! χ² 0.99 quantile ([`chi2_q99`]) and the one-sided normal quantile ([`Z99`]) it uses.
//! Derivation in docs/fit-ndf.md.
//!
//! Tests: `tests.rs` (χ² quantiles); the selection itself through `fit` in
//! `crates/opal-inverse/tests/ndf_fit.rs`.

use super::scale::overlap;
use super::{Evaluation, Problem};

/// The 0.99 quantile of the χ² distribution with `k` degrees of freedom (table for k ≤ 6,
/// Wilson–Hilferty beyond).
pub fn chi2_q99(k: usize) -> f64 {
    const T: [f64; 6] = [6.635, 9.210, 11.345, 13.277, 15.086, 16.812];
    match k {
        0 => 0.0,
        1..=6 => T[k - 1],
        _ => {
            let k = k as f64;
            let a = 2.0 / (9.0 * k);
            k * (1.0 - a + 2.326 * a.sqrt()).powi(3)
        }
    }
}

/// One-sided 99 % normal quantile.
pub const Z99: f64 = 2.326;

/// The selection rule applied to a simpler model A and a richer model B (B has `extra_params`
/// more parameters), both re-simulated with the same *independent* check seed (see `compare`
/// in docs/fit-ndf.md).
#[derive(Clone, Debug)]
pub struct Comparison {
    /// Improvement ΔX = Σ_p d_p, d_p = ((sA − m)² − (sB − m)²)/v_p,
    /// v_p = σm² + (σsA² + σsB²)/2.
    pub delta_chi2: f64,
    /// Standard deviation of ΔX from the simulation and measurement noise (overlapping
    /// detectors' correlation included).
    pub sd: f64,
    /// Correlation inflation c = Var ΔX / Σ Var d_p (≥ 1).
    pub inflation: f64,
    /// Extra parameters of B.
    pub extra_params: usize,
    /// Threshold: c · χ²₀.₉₉(k) + z₀.₉₉ · sd.
    pub threshold: f64,
    /// Whether B is preferred: ΔX > threshold, and for a hybrid node step
    /// ([`Problem::compare_step`]) also a lower fit objective and no larger RMS relative
    /// residual at the check seed ([`step_accepted`]).
    pub accepted: bool,
    /// The fit objective (the Pearson form the optimiser minimises) of A and of B at the
    /// check seed, when the comparison is a hybrid node step ([`Problem::compare_step`]).
    pub objectives: Option<(f64, f64)>,
}

/// The acceptance of a hybrid node step: ΔX above the threshold **and**, at the check seed,
/// a lower fit objective (the Pearson form the optimiser minimises; `objective` = (A, B)) and
/// no larger RMS relative residual (the reported quality; `rms` = (A, B)). ΔX weights every
/// point by its noise: when no model fits the data within noise (the dotted plate: spike and
/// lobe, χ² ≈ 10⁷ over 643 points) it is ruled by the few most precise points, and a node that
/// fits the spike better clears it while the fit as a whole gets worse (check rms/noise
/// 2.97 → 3.73 → 3.91 over two accepted nodes); such a step is not kept.
pub fn step_accepted(comparison: &Comparison, objective: (f64, f64), rms: (f64, f64)) -> bool {
    comparison.delta_chi2 > comparison.threshold && objective.1 < objective.0 && rms.1 <= rms.0
}

impl Problem {
    /// The selection rule: is the richer model B (`rich`, `extra_params` more parameters)
    /// better than A (`simple`) by more than noise explains? Both evaluations must come from
    /// the same independent check seed. ΔX = Σ d_p with d_p = ((sA − m)² − (sB − m)²)/v_p,
    /// v_p = σm² + (σsA² + σsB²)/2. Noise of ΔX: with U = sA − sB and W = sA + sB − 2m
    /// (d_p = U W / v_p), jointly Gaussian with Var U = σsA² + σsB², Var W = Var U + 4σm²,
    /// C = Cov(U, W) = σsA² − σsB²: `Var(UW) = E[U]² Var W + E[W]² Var U + 2 E[U] E[W] C +
    /// Var U Var W + C²`, with `E[U]² ≈ U² − Var U` and `E[W]² ≈ W² − Var W` from the observed
    /// values. Neighbouring detectors overlap, so points p, q of one curve closer than two
    /// detector radii are correlated by ρ = their common area fraction: the terms linear in
    /// the noise add 2 ρ sd_p sd_q, the product of noises 2 ρ² sd_p sd_q. The inflation
    /// c = Var ΔX / Σ Var d_p also scales the χ²(k) drop B's extra parameters buy by fitting
    /// the measurement's noise. B is kept when ΔX > c · χ²₀.₉₉(k) + z₀.₉₉ · sd (a 1 %
    /// false-preference level for each term). The two simulations are treated as independent;
    /// they share part of their random numbers, so sd is conservative.
    pub fn compare(&self, simple: &Evaluation, rich: &Evaluation, extra_params: usize) -> Comparison {
        let dets = self.gonio.detectors().list();
        let r = self.setup.detector_radius;
        // (curve, detector angle, d_p, Var d_p: part linear in the noise, product of noises)
        let mut terms: Vec<(usize, f64, f64, f64, f64)> = Vec::with_capacity(self.points.len());
        for p in &self.points {
            let (ra, rb) = (&simple.result.incidences[p.inc], &rich.result.incidences[p.inc]);
            let (sa, sb) = (ra.value[p.det], rb.value[p.det]);
            let (ea2, eb2) = (ra.value_stderr[p.det].powi(2), rb.value_stderr[p.det].powi(2));
            let sm2 = p.sm * p.sm;
            let v = sm2 + 0.5 * (ea2 + eb2);
            if v <= 0.0 {
                continue;
            }
            let (u, w) = (sa - sb, sa + sb - 2.0 * p.m);
            let (vu, vw, c) = (ea2 + eb2, ea2 + eb2 + 4.0 * sm2, ea2 - eb2);
            // means² estimated without the noise the observed values carry
            let (mu2, mw2) = ((u * u - vu).max(0.0), (w * w - vw).max(0.0));
            let muw = (u * w - c).signum() * (mu2 * mw2).sqrt();
            let lin = (mu2 * vw + mw2 * vu + 2.0 * muw * c).max(0.0) / (v * v);
            let quad = (vu * vw + c * c) / (v * v);
            terms.push((p.curve, dets[p.det].angle_deg.to_radians(), u * w / v, lin, quad));
        }
        let total: f64 = terms.iter().map(|t| t.2).sum();
        let var_indep: f64 = terms.iter().map(|t| t.3 + t.4).sum();
        let mut var = var_indep;
        for (i, a) in terms.iter().enumerate() {
            for b in terms[i + 1..].iter().take_while(|b| b.0 == a.0) {
                let dist = (b.1 - a.1).abs();
                if dist >= 2.0 * r {
                    continue;
                }
                // common area of two discs of radius r at distance `dist`, over π r²: the
                // correlation of their counts; the product-of-noises part correlates by ρ²
                let rho = overlap(dist, r);
                var += 2.0 * rho * (a.3 * b.3).sqrt() + 2.0 * rho * rho * (a.4 * b.4).sqrt();
            }
        }
        let inflation = if var_indep > 0.0 { (var / var_indep).max(1.0) } else { 1.0 };
        let sd = var.max(0.0).sqrt();
        let threshold = inflation * chi2_q99(extra_params) + Z99 * sd;
        Comparison {
            delta_chi2: total,
            sd,
            inflation,
            extra_params,
            threshold,
            accepted: total > threshold,
            objectives: None,
        }
    }

    /// The selection rule for a hybrid node step ([`Problem::compare`] plus
    /// [`step_accepted`]): B is kept only when it also lowers the fit objective at the check
    /// seed and does not raise its RMS relative residual (both evaluations from
    /// [`Problem::check_fit`]).
    pub fn compare_step(&self, simple: &Evaluation, rich: &Evaluation, extra_params: usize) -> Comparison {
        let mut c = self.compare(simple, rich, extra_params);
        let (oa, ob) = (self.objective_of(&simple.result).0, self.objective_of(&rich.result).0);
        c.accepted = step_accepted(&c, (oa, ob), (simple.rms, rich.rms));
        c.objectives = Some((oa, ob));
        c
    }
}
