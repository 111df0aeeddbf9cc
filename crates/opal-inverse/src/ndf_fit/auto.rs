//! The whole fit ([`fit`]): the one-parameter families, Student-t from the better of them,
//! the dotted model (GGX or Beckmann dots on a polished land, each from a coarse grid start,
//! the better at the check seed kept), hybrid nodes on top of the kept model (each where the
//! residual is largest, `nodes`; then one joint refit of α and the multipliers; `auto` tries
//! them when the kept single-NDF or dotted model still misses the data by more than
//! [`HYBRID_TRIGGER`] × the noise), every candidate re-simulated with the
//! independent check seed and kept or rejected by the selection rule; what it fits
//! ([`FitOptions`]) and what it found ([`FitReport`]).
//!
//! Tests: `crates/opal-inverse/tests/ndf_fit.rs`; `crates/opal-cli/tests/fit_ndf.rs`.

use super::{Comparison, Evaluation, Family, FamilyFit, Model, Problem, check_seed, hybrid_spacing};
use opal::bsdf::microfacet::Ndfs;

/// `auto` fits the dotted model when the kept single-NDF model's check rms exceeds this many
/// times its noise.
pub const DOTTED_TRIGGER: f64 = 2.0;

/// `auto` adds hybrid nodes (up to [`FitOptions::hybrid_nodes`]) to the kept model when, after
/// the single-NDF and dotted models, its check rms still exceeds this many times its noise:
/// the bound of a fit that describes the data ([`super::FITS_WITHIN_NOISE`]), so a model that
/// fits is never given a table. Lower than [`DOTTED_TRIGGER`] because a shape error the families cannot follow
/// shows less in the RMS *relative* residual than a missing spike or lobe: the dim points'
/// large relative noise dilutes it (a GGX α 0.3 face with a hole at θm = 0, `auto_picks_hybrid`:
/// the best single NDF at rms/noise 1.69, χ² 6210).
pub const HYBRID_TRIGGER: f64 = super::FITS_WITHIN_NOISE;

/// Default of [`FitOptions::hybrid_nodes`] (also the CLI's `--hybrid-nodes`).
pub const DEFAULT_HYBRID_NODES: usize = 4;

/// What [`fit`] fits.
#[derive(Clone, Debug)]
pub struct FitOptions {
    /// `None` = auto (GGX, Beckmann, Student-t, dotted when they miss the data by more than
    /// [`DOTTED_TRIGGER`] × the noise, hybrid nodes on the kept model when it still misses by
    /// more than [`HYBRID_TRIGGER`] × the noise; the selection rule keeps one);
    /// `Some(Ggx | Beckmann)` = that family only; `Some(Student)` = GGX and Beckmann, then
    /// Student-t from the better one (kept whatever the rule says); `Some(Hybrid)` = auto
    /// without dotted, then hybrid nodes; `Some(Dotted)` = auto, the dotted model kept whatever
    /// the rule says.
    pub family: Option<Family>,
    /// Fit a peak shift δ in every family.
    pub shift: bool,
    /// Maximum number of hybrid nodes (free table values) of `Some(Hybrid)` and of `auto`'s
    /// hybrid step (0: `auto` never tries hybrid). Default [`DEFAULT_HYBRID_NODES`].
    pub hybrid_nodes: usize,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions { family: None, shift: false, hybrid_nodes: DEFAULT_HYBRID_NODES }
    }
}

/// One fitted candidate model and its re-simulation with the independent check seed.
#[derive(Clone, Debug)]
pub struct Candidate {
    /// The fit.
    pub fit: FamilyFit,
    /// Quality at the check seed (full photons).
    pub check: Evaluation,
}

/// One application of the selection rule.
#[derive(Clone, Debug)]
pub struct Decision {
    /// Index (in [`FitReport::candidates`]) of the simpler model.
    pub simple: usize,
    /// Index of the richer model.
    pub rich: usize,
    /// The comparison.
    pub comparison: Comparison,
}

/// Everything [`fit`] found.
#[derive(Clone, Debug)]
pub struct FitReport {
    /// Every fitted model, in fitting order.
    pub candidates: Vec<Candidate>,
    /// Index of the kept model.
    pub best: usize,
    /// The selection decisions (Student vs the best one-parameter family, the dotted model,
    /// each hybrid node, the final joint refit of a kept hybrid model).
    pub decisions: Vec<Decision>,
    /// The independent seed of the checks.
    pub check_seed: u64,
    /// Whether every optimiser stage of every candidate converged (rejected hybrid steps
    /// excepted).
    pub converged: bool,
}

impl FitReport {
    /// The kept candidate.
    pub fn best(&self) -> &Candidate {
        &self.candidates[self.best]
    }
    /// The fitted NDF of the kept model (what the exports and renders use).
    pub fn best_ndf(&self) -> opal::Result<Ndfs> {
        self.best().fit.model.ndf()
    }
}

/// Fits the NDF: the one-parameter families (Brent, or Nelder–Mead with `shift`), the
/// Student-t family from the better of them, the dotted model, hybrid nodes on top of the kept
/// model (see [`FitOptions::family`] for which of them each option tries);
/// every candidate is re-simulated with the independent check seed and the richer model is
/// kept only when [`Problem::compare`] accepts it.
pub fn fit(problem: &Problem, opts: &FitOptions) -> opal::Result<FitReport> {
    let mut cands: Vec<Candidate> = Vec::new();
    let mut decisions = Vec::new();
    let families: &[Family] = match opts.family {
        Some(Family::Ggx) => &[Family::Ggx],
        Some(Family::Beckmann) => &[Family::Beckmann],
        _ => &Family::ALL,
    };
    for &f in families {
        let fit = if opts.shift {
            let mut m = Model::new(f, problem.initial_alpha(f)?);
            m.delta = Some(0.0);
            problem.fit_model(&m, 1.0)?
        } else {
            problem.fit_family(f)?
        };
        let check = problem.check_fit(&fit)?;
        cands.push(Candidate { fit, check });
    }
    let mut best = (0..cands.len())
        .min_by(|&a, &b| cands[a].check.chi2.total_cmp(&cands[b].check.chi2))
        .expect("at least one family");
    if matches!(opts.family, None | Some(Family::Student) | Some(Family::Hybrid) | Some(Family::Dotted)) {
        let b = &cands[best].fit.model;
        let mut m = b.clone();
        m.family = Family::Student;
        m.base = Family::Student;
        // start on the family that fitted best (q = 2/γ: 1 = GGX, 0.01 ≈ Beckmann), so the
        // simplex holds the nested model and Nelder–Mead (which keeps its best vertex) can only
        // improve on it
        m.gamma = Some(if b.base == Family::Beckmann { 2.0 / 0.01 } else { 2.0 });
        let fit = problem.fit_model(&m, 0.5)?;
        let check = problem.check_fit(&fit)?;
        cands.push(Candidate { fit, check });
        let si = cands.len() - 1;
        let comparison = problem.compare(&cands[best].check, &cands[si].check, 1);
        let accepted = comparison.accepted;
        decisions.push(Decision { simple: best, rich: si, comparison });
        if accepted || opts.family == Some(Family::Student) {
            best = si;
        }
    }
    // auto tries the dotted model only when the kept model misses the data by more than twice
    // the noise (a face rough all over is fitted within noise by one NDF and keeps its fit and
    // its run time)
    let misfit = cands[best].check.rms > DOTTED_TRIGGER * cands[best].check.noise;
    if opts.family == Some(Family::Dotted) || (opts.family.is_none() && misfit) {
        // GGX and Beckmann dots, the better at the check seed goes on to the rule
        let mut dotted = Vec::new();
        for base in Family::ALL {
            let fit = problem.fit_model(&problem.dotted_start(base)?, 0.5)?;
            let check = problem.check_fit(&fit)?;
            cands.push(Candidate { fit, check });
            dotted.push(cands.len() - 1);
        }
        let di = *dotted
            .iter()
            .min_by(|&&a, &&b| cands[a].check.chi2.total_cmp(&cands[b].check.chi2))
            .expect("two dotted fits");
        // f → 1 is the GGX model: the dotted model nests GGX with one more parameter (f); a
        // kept Student-t model has as many parameters, and the rule still asks for one
        // parameter's worth of improvement
        let k = cands[di].fit.parameter_count().saturating_sub(cands[best].fit.parameter_count()).max(1);
        let comparison = problem.compare(&cands[best].check, &cands[di].check, k);
        let accepted = comparison.accepted;
        decisions.push(Decision { simple: best, rich: di, comparison });
        if accepted || opts.family == Some(Family::Dotted) {
            best = di;
        }
    }
    // auto adds hybrid nodes when the kept model (single-NDF or dotted) still misses the data
    // by more than the acceptance bound: a shape no family describes (a bump or shoulder in D); the
    // node-step rule then keeps each node only when it pays, so a misfit the table cannot mend
    // (spike + lobe without the dotted model) ends with the model it started from
    let misfit = cands[best].check.rms > HYBRID_TRIGGER * cands[best].check.noise;
    let auto_hybrid = opts.family.is_none() && misfit && opts.hybrid_nodes > 0;
    let hybrid_seed = best;
    let mut refit_kept = false;
    if opts.family == Some(Family::Hybrid) || auto_hybrid {
        // each node where the kept model misses the data most (in θm, at the check seed; see
        // `nodes`), on a grid of spacing h
        let h = hybrid_spacing(&cands[best].fit.model);
        for _ in 0..opts.hybrid_nodes {
            let pm = &cands[best].fit.model;
            let taken: Vec<f64> = pm.free_nodes().iter().map(|&i| pm.nodes[i].0).collect();
            let Some(theta) = problem.residual_peak(&cands[best].check, h, &taken) else { break };
            // incremental: only the new node is fitted, from the kept model's parameters
            let fit = problem.fit_hybrid_step(pm, theta, h)?;
            let check = problem.check_fit(&fit)?;
            cands.push(Candidate { fit, check });
            let hi = cands.len() - 1;
            // ΔX above the threshold and a lower fit objective at the check seed
            let comparison = problem.compare_step(&cands[best].check, &cands[hi].check, 1);
            let accepted = comparison.accepted;
            decisions.push(Decision { simple: best, rich: hi, comparison });
            if !accepted {
                break;
            }
            best = hi;
        }
        // the node steps fit one multiplier each with α and the earlier nodes held, so the
        // peak ends up shared between α and the nodes less well than a joint fit would (round
        // trip: multiplier 1.68 at 0° with α held at GGX's, against a true 3 at the true α);
        // one final refit of α and every node multiplier together, warm-started at the
        // incremental result, is kept when it passes the step rule with no extra parameter
        if cands[best].fit.model.family == Family::Hybrid {
            let fit = problem.fit_hybrid(&cands[best].fit.model)?;
            let check = problem.check_fit(&fit)?;
            cands.push(Candidate { fit, check });
            let ri = cands.len() - 1;
            let comparison = problem.compare_step(&cands[best].check, &cands[ri].check, 0);
            let accepted = comparison.accepted;
            decisions.push(Decision { simple: best, rich: ri, comparison });
            if accepted {
                best = ri;
                refit_kept = true;
            }
        }
    }
    // a rejected hybrid step that did not converge does not matter (the rule stopped there)
    // a kept dotted model needs its own convergence only: the single-NDF fits it replaced miss
    // the data by more than twice the noise (hence the dotted step), and on a spike + lobe their
    // one-parameter searches often end at the iteration limit without mattering
    // a hybrid kept by `auto` likewise replaced models that miss the data by more than the
    // acceptance bound: its own fit counts, and the model it started from unless the final joint refit
    // (α with the nodes) is the kept one
    let converged = if cands[best].fit.model.family == Family::Dotted {
        cands[best].fit.converged
    } else if auto_hybrid && cands[best].fit.model.family == Family::Hybrid {
        cands[best].fit.converged && (refit_kept || cands[hybrid_seed].fit.converged)
    } else {
        cands.iter().enumerate().all(|(i, c)| {
            c.fit.converged || (i != best && matches!(c.fit.model.family, Family::Hybrid | Family::Dotted))
        })
    };
    Ok(FitReport {
        candidates: cands,
        best,
        decisions,
        check_seed: check_seed(problem.setup.seed),
        converged,
    })
}
