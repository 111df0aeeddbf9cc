//! Unknown calibration factors of the measurement ([`ScaleMode`]): the measured curves are
//! modelled as `m ≈ k_g · s` (s the simulated value, k_g the factor of the point's group: one
//! for the whole file, one per incidence or one per curve) and every factor is fitted in closed
//! form for the current NDF, so it costs no simulation.
//!
//! Objective with factors: the absolute objective with `s → k s`, `σs → k σs`, plus a
//! correction of its weight's bias, `G(k) = Σ_p [((k s − m)² − k² σs²)/m − 2 (k s − m) r_p²]`
//! with `r_p = σm/m` the measured point's relative standard error. The weight 1/m is larger
//! where the measured value fluctuated low, so without the correction the expected objective
//! is minimised by a simulation low by ≈ r² at every point (E[(k s − m)²/m] has the term
//! `2 (k s − μ) r²`, μ the mean measurement; the harmonic-mean bias of a Neyman χ²): the
//! factors came out 0.15–0.9 % low on 400 000-photon synthetic curves. The correction's expectation
//! cancels that term, to first order in r². Per group `G(k) = A k² − 2 B k + const` with
//! `A = Σ (s² − σs²)/m` and `B = Σ s (1 + r²)`, so the best factor is `k̂ = B / A` (when
//! noise makes A ≤ 0, `A = Σ s²/m`). Absolute values keep today's objective (no correction). It is a linear estimate, `k̂ − k ≈ Σ c_p (m_p − k s_p)` with
//! `c_p = (s_p/m_p) / Σ s²/m`, so its variance is `σd² = Σ c_p² v_p` (v_p = σm² + k̂² σs²) plus
//! `2 ρ c_p c_q sd_p sd_q` for overlapping detectors of one curve (ρ their common area
//! fraction, as in the selection rule): the factor's uncertainty given the NDF (the NDF's own
//! uncertainty is not propagated).
//!
//! Known calibration uncertainty σk (a Gaussian prior k ~ N(1, σk²)): the penalty
//! `ν (k − 1)²` with `ν = A σd²/σk²` is added to G, so the minimum is still closed-form,
//! `k = (B + ν)/(A + ν)`, the precision-weighted mean of k̂ (precision 1/σd²) and 1 (precision
//! 1/σk²), with standard error `(1/σd² + 1/σk²)^(−1/2)`.
//!
//! With [`ScaleMode::Absolute`] every factor is exactly 1 and nothing else changes (the
//! arithmetic multiplies by 1.0, which is exact, so the absolute fit is bit for bit the one
//! without factors).
//!
//! Tests: `tests.rs` (the closed form is the minimum, equivariance under a scaled
//! measurement, the prior); `crates/opal-inverse/tests/ndf_fit.rs` (scaled round trips).

use super::Problem;
use opal::gonio::{GonioResult, Side};

/// Which calibration factors of the measurement are unknown.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ScaleMode {
    /// The values are absolute (intensity per unit incident power): no factor.
    #[default]
    Absolute,
    /// One unknown factor for the whole measurement (relative units, uncertain calibration).
    Global,
    /// One factor per incidence angle (R and T of one incidence share it: each scan
    /// normalised on its own).
    PerIncidence,
    /// One factor per measured curve (incidence and side: R and T normalised separately).
    PerCurve,
}

impl ScaleMode {
    /// `absolute`, `global`, `per-incidence` or `per-curve`.
    pub fn name(self) -> &'static str {
        match self {
            ScaleMode::Absolute => "absolute",
            ScaleMode::Global => "global",
            ScaleMode::PerIncidence => "per-incidence",
            ScaleMode::PerCurve => "per-curve",
        }
    }

    /// Parses [`ScaleMode::name`].
    pub fn parse(s: &str) -> Option<ScaleMode> {
        [ScaleMode::Absolute, ScaleMode::Global, ScaleMode::PerIncidence, ScaleMode::PerCurve]
            .into_iter()
            .find(|m| m.name() == s.to_ascii_lowercase())
    }
}

/// The calibration-factor settings of a fit.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ScaleSetup {
    /// Which factors are fitted.
    pub mode: ScaleMode,
    /// Known relative 1-σ uncertainty of every factor (a Gaussian prior centred on 1);
    /// `None` = the factors are free.
    pub prior: Option<f64>,
}

/// One group of measured points sharing a factor.
#[derive(Clone, Debug, PartialEq)]
pub struct ScaleGroup {
    /// Incidence angle in degrees (`None`: every incidence).
    pub incidence_deg: Option<f64>,
    /// Side (`None`: both sides).
    pub side: Option<Side>,
}

/// The fitted factors for one simulation.
#[derive(Clone, Debug, PartialEq)]
pub struct ScaleFit {
    /// Factor of every group (measured ≈ factor × simulated); empty for
    /// [`ScaleMode::Absolute`].
    pub factors: Vec<f64>,
    /// Standard error of every factor given the NDF (see the module docs).
    pub stderr: Vec<f64>,
    /// The prior's penalty Σ ν (k − 1)² (0 without a prior), in the units of Σ_p (…)/m.
    pub penalty: f64,
}

impl ScaleFit {
    /// No factor (absolute values).
    pub fn none() -> ScaleFit {
        ScaleFit { factors: Vec::new(), stderr: Vec::new(), penalty: 0.0 }
    }
}

/// Common area of two detector discs of angular radius `r` whose centres are `dist` apart,
/// as a fraction of one disc: the correlation of their photon counts (0 beyond 2r).
pub(super) fn overlap(dist: f64, r: f64) -> f64 {
    if dist >= 2.0 * r {
        return 0.0;
    }
    let h = dist / (2.0 * r);
    (2.0 * h.acos() - 2.0 * h * (1.0 - h * h).sqrt()) / std::f64::consts::PI
}

impl Problem {
    /// The groups of points that share a factor (empty for [`ScaleMode::Absolute`]).
    pub fn scale_groups(&self) -> &[ScaleGroup] {
        &self.groups
    }

    /// Factor of a point in group `g` (1 without factors).
    pub(super) fn factor(fit: &ScaleFit, g: Option<usize>) -> f64 {
        g.map_or(1.0, |g| fit.factors[g])
    }

    /// The best factors for simulation `res` (closed form, see the module docs).
    pub fn fit_scale(&self, res: &GonioResult) -> ScaleFit {
        let ng = self.groups.len();
        if ng == 0 {
            return ScaleFit::none();
        }
        // A = Σ (s² − σs²)/m, A₀ = Σ s²/m, B = Σ s (1 + σm²/m²) per group
        let (mut a, mut a0, mut b) = (vec![0.0; ng], vec![0.0; ng], vec![0.0; ng]);
        for p in &self.points {
            let g = p.group.expect("every point has a group when factors are fitted");
            let r = &res.incidences[p.inc];
            let (s, ss) = (r.value[p.det], r.value_stderr[p.det]);
            a[g] += (s * s - ss * ss) / p.m;
            a0[g] += s * s / p.m;
            b[g] += s * (1.0 + (p.sm / p.m).powi(2));
        }
        let mut fit = ScaleFit { factors: vec![1.0; ng], stderr: vec![f64::INFINITY; ng], penalty: 0.0 };
        for g in 0..ng {
            let ag = if a[g] > 0.0 { a[g] } else { a0[g] };
            if !(ag > 0.0 && b[g] > 0.0) {
                // the simulation sees nothing on this group's points: any factor fits equally
                continue;
            }
            let khat = b[g] / ag;
            let var_d = self.factor_variance(res, g, khat, a0[g]);
            match self.setup.scale.prior {
                Some(sk) if var_d > 0.0 => {
                    let nu = ag * var_d / (sk * sk);
                    let k = (b[g] + nu) / (ag + nu);
                    fit.factors[g] = k;
                    fit.stderr[g] = (1.0 / var_d + 1.0 / (sk * sk)).recip().sqrt();
                    fit.penalty += nu * (k - 1.0).powi(2);
                }
                _ => {
                    fit.factors[g] = khat;
                    fit.stderr[g] = var_d.sqrt();
                }
            }
        }
        fit
    }

    /// Variance of the closed-form factor of group `g`: `Σ c_p² v_p` + the overlap terms,
    /// `c_p = (s_p/m_p)/a0`, `v_p = σm² + k² σs²`.
    fn factor_variance(&self, res: &GonioResult, g: usize, k: f64, a0: f64) -> f64 {
        let dets = self.gonio.detectors().list();
        let r = self.setup.detector_radius;
        // (curve, detector angle, c_p · sd_p)
        let terms: Vec<(usize, f64, f64)> = self
            .points
            .iter()
            .filter(|p| p.group == Some(g))
            .map(|p| {
                let ri = &res.incidences[p.inc];
                let (s, ss) = (ri.value[p.det], ri.value_stderr[p.det]);
                let sd = (p.sm * p.sm + k * k * ss * ss).sqrt();
                (p.curve, dets[p.det].angle_deg.to_radians(), s / p.m / a0 * sd)
            })
            .collect();
        let mut var: f64 = terms.iter().map(|t| t.2 * t.2).sum();
        for (i, x) in terms.iter().enumerate() {
            for y in terms[i + 1..].iter().take_while(|y| y.0 == x.0) {
                var += 2.0 * overlap((y.1 - x.1).abs(), r) * x.2 * y.2;
            }
        }
        var
    }

    /// `res` with the values and standard errors of every group's detectors multiplied by its
    /// factor (what is compared with the measurement); detectors of a curve outside every group
    /// (a side not fitted with per-curve factors) keep factor 1.
    pub fn apply_scale(&self, mut res: GonioResult, fit: &ScaleFit) -> GonioResult {
        if fit.factors.is_empty() {
            return res;
        }
        let dets = self.gonio.detectors().list();
        for (i, r) in res.incidences.iter_mut().enumerate() {
            for (j, d) in dets.iter().enumerate() {
                let side = (d.side == Side::T) as usize;
                let k = Self::factor(fit, self.group_of[i][side]);
                r.value[j] *= k;
                r.value_stderr[j] *= k;
                r.bsdf[j] *= k;
            }
        }
        res
    }
}
