//! Fitting the micro-facet normal distribution of a plate's rough face to measured
//! goniophotometer curves (method A, inverse half).
//!
//! Model: the measured plate is simulated by [`opal::gonio::Gonio`] with the same beam,
//! detectors and incidence angles as the measurement; the rough face carries an analytic NDF
//! ([`Family`]: Beckmann = Gauss-like slopes, GGX = Cauchy-like slopes) of roughness α, with
//! single or multiple scattering on the micro-surface.
//!
//! Objective: over the measured points whose value is at least `floor_rel` × the maximum of
//! their curve (the set is fixed by the measurement, so it does not change between evaluations),
//! `Σ ((s − m)² − σs²)/m / Σ m`: the squared relative residual `((s − m)/m)²` weighted by m
//! (Pearson's χ² form). Relative residuals weight a lobe's flanks as much as its peak (an
//! absolute RMS fits only the peaks); the weight m is the inverse relative variance of a
//! photon count (`Var s ∝ s`), so photon-starved dim points do not dominate the noise of the
//! objective; subtracting the simulation's variance σs² removes the Monte-Carlo bias
//! (`E (s − m)² = (E s − m)² + Var s`, and Var s grows with s). The quality reported beside it is
//! the plain RMS relative residual and the Monte-Carlo noise level, the RMS of the combined
//! relative standard error `sqrt(σs² + σm²)/m` over the same points, so `rms / noise ≈ 1` means
//! "fits within noise".
//!
//! Smoothness: every evaluation uses the same seed (common random numbers: batch b of
//! incidence i always draws from `Rng::new(seed, i, b)`), so the objective varies smoothly with
//! α instead of jumping by the Monte-Carlo noise. The final quality (`rms`, `noise`) is reported
//! from an extra simulation with an *independent* seed, so it is not flattered by the
//! common-random-number optimum.
//!
//! Optimiser: Brent's method (argmin's `BrentOpt`) on ln α, bracket ±ln 1.8 around the
//! initial guess, moved when the optimum lands on an edge. Initial guess: the half width at
//! half maximum (HWHM) of the measured transmitted lobe at the smallest incidence; a facet tilted
//! by θm deflects a ray refracted by the plate by about (n − 1)·θm, so the NDF half width is
//! about HWHM/(n − 1) (for n ≈ 1.5 the normals are about two times *wider* than the BTDF in angle;
//! the paper's "two times narrower" rule compares slope spreads); α follows from the family's
//! half-maximum slope; one probe simulation then rescales α by the ratio of measured to probe
//! HWHM.
//!
//! Tests: `crates/opal-inverse/tests/ndf_fit.rs` (synthetic round trips, one Mitsuba reference
//! case in the default tier, all six `#[ignore]`d).

use crate::measured::Measured;
use argmin::core::{CostFunction, Executor, State, TerminationReason, TerminationStatus};
use argmin::solver::brent::BrentOpt;
use opal::bsdf::microfacet::Ndfs;
use opal::gonio::{
    Beam, DetectorGrid, DetectorLayout, Face, Gonio, GonioResult, GonioSetup, Plate, Scattering, Side,
};
use std::sync::Mutex;

/// Analytic NDF families.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Family {
    /// Beckmann (Gauss-like).
    Beckmann,
    /// GGX / Trowbridge–Reitz (Cauchy-like).
    Ggx,
}

impl Family {
    /// Every analytic family (what `auto` tries).
    pub const ALL: [Family; 2] = [Family::Ggx, Family::Beckmann];

    /// Lower-case name (`ggx`, `beckmann`).
    pub fn name(self) -> &'static str {
        match self {
            Family::Beckmann => "beckmann",
            Family::Ggx => "ggx",
        }
    }

    /// Parses a family name.
    pub fn parse(s: &str) -> Option<Family> {
        match s.to_ascii_lowercase().as_str() {
            "beckmann" | "gauss" => Some(Family::Beckmann),
            "ggx" | "cauchy" | "trowbridge-reitz" => Some(Family::Ggx),
            _ => None,
        }
    }

    /// The NDF of roughness `alpha` (> 0).
    pub fn ndf(self, alpha: f64) -> Ndfs {
        match self {
            Family::Beckmann => Ndfs::beckmann(alpha as f32),
            Family::Ggx => Ndfs::ggx(alpha as f32),
        }
    }

    /// tan θ / α at which D(θ) falls to half its peak, small-α limit (GGX: (1 + t²)⁻² = 1/2,
    /// t = √(√2 − 1) ≈ 0.644; Beckmann: exp(−t²) = 1/2, t = √ln 2 ≈ 0.833).
    fn half_max_slope(self) -> f64 {
        match self {
            Family::Ggx => (2f64.sqrt() - 1.0).sqrt(),
            Family::Beckmann => 2f64.ln().sqrt(),
        }
    }
}

/// Which measured side the objective uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FitOn {
    /// Transmitted curves only.
    T,
    /// Reflected curves only.
    R,
    /// Both.
    Both,
}

impl FitOn {
    fn uses(self, s: Side) -> bool {
        matches!((self, s), (FitOn::Both, _) | (FitOn::T, Side::T) | (FitOn::R, Side::R))
    }
    /// "T", "R" or "both".
    pub fn label(self) -> &'static str {
        match self {
            FitOn::T => "T",
            FitOn::R => "R",
            FitOn::Both => "both",
        }
    }
}

/// The measured instrument and sample, except the unknown NDF.
#[derive(Clone, Debug)]
pub struct FitSetup {
    /// The plate; its rough face (`rough_front` says which) is replaced at every evaluation.
    pub plate: Plate,
    /// True when the lit (front) face is the rough one (`entry = rough`).
    pub rough_front: bool,
    /// Scattering model of the rough face.
    pub scattering: Scattering,
    /// The beam (the incidence angles come from the measurement).
    pub beam: Beam,
    /// Angular radius of the detectors (radians).
    pub detector_radius: f64,
    /// Distance of the detectors in mm (finite plates, `plate.radius_mm`); `None` = far field.
    pub detector_distance_mm: Option<f64>,
    /// Photons per incidence per evaluation.
    pub photons: u64,
    /// Seed of the common random numbers.
    pub seed: u64,
    /// Interaction limit per photon.
    pub max_interactions: u32,
    /// Which side the objective uses.
    pub fit_on: FitOn,
    /// Points below this fraction of their curve's maximum are left out of the objective.
    pub floor_rel: f64,
    /// Maximum number of optimiser iterations per family.
    pub max_iters: u64,
}

#[derive(Clone, Copy, Debug)]
struct Point {
    inc: usize,
    det: usize,
    m: f64,
    sm: f64,
}

/// The fitting problem: measurement + simulator.
pub struct Problem {
    /// The measured curves.
    pub measured: Measured,
    /// The setup.
    pub setup: FitSetup,
    gonio: Gonio,
    points: Vec<Point>,
    /// (curve, detector index in the simulator) for every measured point, used or not.
    all: Vec<Vec<usize>>,
    incidences: Vec<f64>,
    evals: Mutex<u64>,
}

/// Quality of one simulation against the measurement.
#[derive(Clone, Debug)]
pub struct Evaluation {
    /// RMS relative residual over the used points.
    pub rms: f64,
    /// RMS combined relative standard error (simulation + measurement) over the same points.
    pub noise: f64,
    /// Per incidence (degrees): (incidence_deg, rms, noise, points).
    pub per_incidence: Vec<(f64, f64, f64, usize)>,
    /// Number of points used.
    pub points: usize,
    /// The simulation.
    pub result: GonioResult,
}

/// Result of fitting one family.
#[derive(Clone, Debug)]
pub struct FamilyFit {
    /// The family.
    pub family: Family,
    /// Initial α (from the lobe width).
    pub alpha_initial: f64,
    /// Fitted α.
    pub alpha: f64,
    /// Objective at the optimum (common random numbers; Σ((s − m)² − σs²)/m / Σm).
    pub objective: f64,
    /// Simulations run for this family (probe included).
    pub evaluations: u64,
    /// Whether the optimiser converged inside its bracket.
    pub converged: bool,
    /// (α, objective) of every evaluation, in order.
    pub history: Vec<(f64, f64)>,
}

impl Problem {
    /// Builds the simulator for the measurement's incidences and detector angles.
    pub fn new(measured: Measured, setup: FitSetup) -> opal::Result<Self> {
        if !(setup.floor_rel.is_finite() && (0.0..1.0).contains(&setup.floor_rel)) {
            return Err(opal::Error::invalid(
                "floor_rel",
                format!("must be in [0, 1), got {}", setup.floor_rel),
            ));
        }
        for s in [Side::R, Side::T] {
            if setup.fit_on.uses(s) && setup.fit_on != FitOn::Both && !measured.has_side(s) {
                return Err(opal::Error::invalid(
                    "fit-on",
                    format!(
                        "side {} requested but {} has no point on it (empty side)",
                        s.label(),
                        measured.path.display()
                    ),
                ));
            }
        }
        if !measured.curves.iter().any(|c| setup.fit_on.uses(c.side)) {
            return Err(opal::Error::invalid("fit-on", "no measured curve on the requested side(s)"));
        }
        let incidences = measured.incidences();
        let angles = measured.detector_angles();
        let gonio = Gonio::new(GonioSetup {
            beam: setup.beam.clone(),
            incidences: incidences.clone(),
            detectors: DetectorLayout {
                grid: DetectorGrid::PlaneOfIncidence { angles: angles.clone() },
                radius: setup.detector_radius,
                distance_mm: setup.detector_distance_mm,
            },
            photons: setup.photons,
            seed: setup.seed,
            max_interactions: setup.max_interactions,
        })?;
        let na = angles.len();
        let mut points = Vec::new();
        let mut all = Vec::new();
        for c in measured.curves.iter() {
            let inc = incidences.iter().position(|&t| t == c.incidence).expect("incidence listed");
            let off = if c.side == Side::R { 0 } else { na };
            let floor = setup.floor_rel * c.max();
            let mut idx = Vec::new();
            for (k, &a) in c.detector.iter().enumerate() {
                let j = angles.iter().position(|&x| (x - a).abs() < 1e-9).expect("angle listed");
                idx.push(off + j);
                let m = c.value[k];
                if setup.fit_on.uses(c.side) && m > 0.0 && m >= floor {
                    points.push(Point { inc, det: off + j, m, sm: c.stderr[k] });
                }
            }
            all.push(idx);
        }
        if points.is_empty() {
            return Err(opal::Error::invalid(
                "measurement",
                "no point above the floor on the fitted side(s)",
            ));
        }
        Ok(Problem { measured, setup, gonio, points, all, incidences, evals: Mutex::new(0) })
    }

    /// The simulator.
    pub fn gonio(&self) -> &Gonio {
        &self.gonio
    }

    /// Simulator detector index of every point of measured curve `curve`.
    pub fn detector_indices(&self, curve: usize) -> &[usize] {
        &self.all[curve]
    }

    /// Index of the incidence of measured curve `curve` in the simulation result.
    pub fn incidence_index(&self, curve: usize) -> usize {
        let t = self.measured.curves[curve].incidence;
        self.incidences.iter().position(|&x| x == t).expect("incidence listed")
    }

    /// Number of simulations run so far.
    pub fn evaluations(&self) -> u64 {
        *self.evals.lock().expect("no panic while counting")
    }

    /// The plate with `ndf` on its rough face.
    pub fn plate_with(&self, ndf: Ndfs) -> Plate {
        let mut p = self.setup.plate.clone();
        let f = Face::Rough { ndf, scattering: self.setup.scattering };
        if self.setup.rough_front {
            p.front = f;
        } else {
            p.back = f;
        }
        p
    }

    /// Simulates with `ndf` using `seed` and `photons` (the setup's for the objective).
    pub fn simulate(&self, ndf: Ndfs, seed: u64, photons: u64) -> opal::Result<GonioResult> {
        *self.evals.lock().expect("no panic while counting") += 1;
        let plate = self.plate_with(ndf);
        if seed == self.setup.seed && photons == self.setup.photons {
            self.gonio.run_plate(&plate)
        } else {
            let mut s = self.gonio.setup().clone();
            s.seed = seed;
            s.photons = photons;
            Gonio::new(s)?.run_plate(&plate)
        }
    }

    /// Compares a simulation with the measurement.
    pub fn evaluate(&self, res: GonioResult) -> Evaluation {
        let mut se = 0.0;
        let mut sn = 0.0;
        let ni = self.incidences.len();
        let mut per = vec![(0.0f64, 0.0f64, 0usize); ni];
        for p in &self.points {
            let r = &res.incidences[p.inc];
            let s = r.value[p.det];
            let ss = r.value_stderr[p.det];
            let e = (s - p.m) / p.m;
            let n = (ss * ss + p.sm * p.sm) / (p.m * p.m);
            se += e * e;
            sn += n;
            per[p.inc].0 += e * e;
            per[p.inc].1 += n;
            per[p.inc].2 += 1;
        }
        let np = self.points.len() as f64;
        let per_incidence = per
            .iter()
            .enumerate()
            .map(|(i, &(e, n, c))| {
                let cf = (c as f64).max(1.0);
                (self.incidences[i].to_degrees(), (e / cf).sqrt(), (n / cf).sqrt(), c)
            })
            .collect();
        Evaluation {
            rms: (se / np).sqrt(),
            noise: (sn / np).sqrt(),
            per_incidence,
            points: self.points.len(),
            result: res,
        }
    }

    /// The objective: `Σ ((s − m)² − σs²)/m / Σ m` over the used points, i.e. the squared
    /// relative residual `((s − m)/m)²` weighted by `m` (Pearson's χ² form). The weight is the
    /// inverse of the relative variance of a photon-count estimate (`Var s ∝ s`), so the
    /// dim, photon-starved points do not dominate the objective's noise; subtracting the
    /// simulation's own variance σs² makes it an unbiased estimate of the misfit of the
    /// *expected* simulation (plus a constant): without it the Monte-Carlo variance, which
    /// grows with the simulated value, pulls α towards dimmer lobes.
    fn objective(&self, ndf: Ndfs) -> opal::Result<f64> {
        let res = self.simulate(ndf, self.setup.seed, self.setup.photons)?;
        let (mut acc, mut wsum) = (0.0, 0.0);
        for p in &self.points {
            let r = &res.incidences[p.inc];
            let (s, ss) = (r.value[p.det], r.value_stderr[p.det]);
            acc += ((s - p.m).powi(2) - ss * ss) / p.m;
            wsum += p.m;
        }
        Ok(acc / wsum)
    }

    /// Half width at half maximum (radians) of the transmitted lobe of the smallest incidence,
    /// from the values `v` of curve `ci`'s detectors.
    fn lobe_hwhm(&self, ci: usize, v: &[f64]) -> Option<f64> {
        let c = &self.measured.curves[ci];
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
                    let (a0, a1) = (c.detector[k as usize], c.detector[k2]);
                    let (v0, v1) = (v[k as usize], v[k2]);
                    let f = (v0 - half) / (v0 - v1);
                    widths.push((a0 + f * (a1 - a0) - c.detector[ipk]).abs());
                    break;
                }
                k += dir;
            }
        }
        if widths.is_empty() { None } else { Some(widths.iter().sum::<f64>() / widths.len() as f64) }
    }

    fn initial_curve(&self) -> Option<usize> {
        // the transmitted curve of the smallest incidence, else the first curve
        self.measured.curves.iter().position(|c| c.side == Side::T).or(Some(0))
    }

    /// Initial α for `family` from the measured lobe width (one probe simulation).
    pub fn initial_alpha(&self, family: Family) -> opal::Result<f64> {
        let n = self.setup.plate.ior;
        let ci = self.initial_curve().expect("at least one curve");
        let Some(w) = self.lobe_hwhm(ci, &self.measured.curves[ci].value) else {
            return Ok(0.2);
        };
        // smooth-face geometry: deflection ≈ (n − 1) θm (see module docs)
        let theta_m = (w / (n - 1.0).abs().max(0.05)).min(1.2);
        let a_probe = (theta_m.tan() / family.half_max_slope()).clamp(0.01, 2.0);
        let res = self.simulate(family.ndf(a_probe), self.setup.seed, self.setup.photons)?;
        let inc = self.incidence_index(ci);
        let sim: Vec<f64> = self.all[ci].iter().map(|&d| res.incidences[inc].value[d]).collect();
        Ok(match self.lobe_hwhm(ci, &sim) {
            Some(wp) if wp > 0.0 => (a_probe * w / wp).clamp(0.005, 2.0),
            _ => a_probe,
        })
    }

    /// Fits α of one family (Brent on ln α).
    pub fn fit_family(&self, family: Family) -> opal::Result<FamilyFit> {
        let e0 = self.evaluations();
        let a0 = self.initial_alpha(family)?;
        let history = Mutex::new(Vec::new());
        let span = 1.8f64.ln();
        let mut center = a0.ln();
        let mut best = (a0, f64::INFINITY);
        let mut converged = false;
        for _round in 0..4 {
            let (lo, hi) = (center - span, center + span);
            let cost = Cost { problem: self, family, history: &history };
            let solver = BrentOpt::new(lo, hi).set_tolerance(0.0, 1e-3);
            let res = Executor::new(cost, solver)
                .configure(|s| s.max_iters(self.setup.max_iters))
                .run()
                .map_err(|e| opal::Error::invalid("optimiser", e.to_string()))?;
            let st = res.state();
            let x = *st.get_best_param().unwrap_or(&center);
            let fx = st.get_best_cost();
            if fx < best.1 {
                best = (x.exp(), fx);
            }
            let ok = matches!(
                st.get_termination_status(),
                TerminationStatus::Terminated(TerminationReason::SolverConverged)
            );
            let at_edge = (x - lo).abs() < 0.02 || (hi - x).abs() < 0.02;
            if ok && !at_edge {
                converged = true;
                break;
            }
            if !at_edge {
                break;
            }
            center = x;
        }
        let history = history.into_inner().expect("no panic while recording");
        Ok(FamilyFit {
            family,
            alpha_initial: a0,
            alpha: best.0,
            objective: best.1,
            evaluations: self.evaluations() - e0,
            converged,
            history,
        })
    }
}

struct Cost<'a> {
    problem: &'a Problem,
    family: Family,
    history: &'a Mutex<Vec<(f64, f64)>>,
}

impl CostFunction for Cost<'_> {
    type Param = f64;
    type Output = f64;
    fn cost(&self, x: &f64) -> Result<f64, argmin::core::Error> {
        let a = x.exp().clamp(1e-4, 10.0);
        let f = self
            .problem
            .objective(self.family.ndf(a))
            .map_err(|e| argmin::core::Error::msg(e.to_string()))?;
        self.history.lock().expect("no panic while recording").push((a, f));
        Ok(f)
    }
}

/// Fits every family in `families` and returns the fits sorted by objective (best first).
pub fn fit_families(problem: &Problem, families: &[Family]) -> opal::Result<Vec<FamilyFit>> {
    let mut fits = Vec::new();
    for &f in families {
        fits.push(problem.fit_family(f)?);
    }
    fits.sort_by(|a, b| a.objective.total_cmp(&b.objective));
    Ok(fits)
}
