//! Fitting the micro-facet normal distribution of a plate's rough face to measured
//! goniophotometer curves (method A, inverse half).
//!
//! Model: the measured plate is simulated by [`opal::gonio::Gonio`] with the same beam,
//! detectors and incidence angles as the measurement; the rough face carries an NDF
//! ([`Model`]): an analytic shape ([`Family`]: Beckmann = Gauss-like slopes, GGX = Cauchy-like
//! slopes, Student-t = tail exponent γ between them, `Profile::StudentT`) of roughness α,
//! optionally shifted (`D(θ) ∝ base(|θ − δ|)`, `Profile::Shifted`) and optionally hybrid (a
//! piecewise-linear table of multipliers of the analytic part at nodes θk = k·h from θm = 0,
//! `Profile::Hybrid`), with single or multiple scattering on the micro-surface.
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
//! Smoothness: every evaluation uses the same seed (common random numbers: photon j of
//! incidence i always draws from `Rng::new(seed, i, j)`), so the objective varies smoothly with
//! the parameters instead of jumping by the Monte-Carlo noise (the numeric NDFs' rejection
//! sampler makes it piecewise smooth: a small step can change which proposal is accepted). The final quality (`rms`, `noise`) is reported
//! from an extra simulation with an *independent* seed, so it is not flattered by the
//! common-random-number optimum.
//!
//! Optimisers (argmin): Brent's method (`BrentOpt`) on ln α for GGX/Beckmann, bracket
//! ±ln 1.8 around the initial guess, moved when the optimum lands on an edge; Nelder–Mead
//! (`NelderMead`) for the multi-parameter models over bounded coordinates (ln α, q = 2/γ,
//! δ in degrees, ln multipliers; out-of-bounds points are clamped and penalised). Two stages:
//! coarse (`coarse_photons`) from the guess, fine (`photons`) from the coarse optimum. Initial
//! guess: the half width at half maximum (HWHM) of the measured transmitted lobe at the
//! smallest incidence; a facet tilted by θm deflects a ray refracted by the plate by about
//! (n − 1)·θm, so the NDF half width is about HWHM/(n − 1) (for n ≈ 1.5 the normals are about
//! two times *wider* than the BTDF in angle; the paper's "two times narrower" rule compares
//! slope spreads); α follows from the family's half-maximum slope; one probe simulation then
//! rescales α by the ratio of measured to probe HWHM. Student-t starts from the better of
//! GGX/Beckmann; hybrid from the model `auto` keeps, adding one node at a time.
//!
//! Model selection ([`fit`], [`Problem::compare`]): every candidate is re-simulated with an
//! independent check seed; a richer (nesting) model is kept only when its χ² improvement ΔX
//! exceeds c·χ²₀.₉₉(k) + 2.326·sd (k extra parameters, sd the noise of ΔX propagated from the
//! standard errors, c the correlation inflation of overlapping detectors); derivation in
//! docs/fit-ndf.md.
//!
//! Tests: `tests` below (models, coordinates, quantiles); `crates/opal-inverse/tests/ndf_fit.rs`
//! (one Mitsuba reference case in the default tier; all six and the Student-t, shift,
//! multiple-scattering and hybrid round trips `#[ignore]`d, commands in docs/testing.md).

use crate::measured::Measured;
use argmin::core::{CostFunction, Executor, State, TerminationReason, TerminationStatus};
use argmin::solver::brent::BrentOpt;
use argmin::solver::neldermead::NelderMead;
use opal::bsdf::microfacet::{Beckmann, Ggx, Ndf, Ndfs, Profile};
use opal::gonio::{
    Beam, DetectorGrid, DetectorLayout, Face, Gonio, GonioResult, GonioSetup, Plate, Scattering, Side,
};
use opal::math::Vec3;
use std::sync::Mutex;

/// NDF families.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Family {
    /// Beckmann (Gauss-like slopes), parameter α.
    Beckmann,
    /// GGX / Trowbridge–Reitz (Cauchy-like slopes), parameter α.
    Ggx,
    /// Generalised Student-t slopes (`Profile::StudentT`): α and the tail exponent γ ≥ 2
    /// (γ = 2 is GGX, γ → ∞ is Beckmann, with the same α).
    Student,
    /// The best analytic model plus a piecewise-linear table of D over θm ∈ [0, θK]
    /// (`Profile::Hybrid`).
    Hybrid,
}

/// Tail exponent γ a Student-t model starts from when nothing better is known.
pub const STUDENT_GAMMA_START: f64 = 4.0;

impl Family {
    /// The one-parameter analytic families.
    pub const ALL: [Family; 2] = [Family::Ggx, Family::Beckmann];
    /// What `auto` fits (then keeps one by the selection rule, see [`compare`]).
    pub const AUTO: [Family; 3] = [Family::Ggx, Family::Beckmann, Family::Student];

    /// Lower-case name (`ggx`, `beckmann`, `student`, `hybrid`).
    pub fn name(self) -> &'static str {
        match self {
            Family::Beckmann => "beckmann",
            Family::Ggx => "ggx",
            Family::Student => "student",
            Family::Hybrid => "hybrid",
        }
    }

    /// Parses a family name.
    pub fn parse(s: &str) -> Option<Family> {
        match s.to_ascii_lowercase().as_str() {
            "beckmann" | "gauss" => Some(Family::Beckmann),
            "ggx" | "cauchy" | "trowbridge-reitz" => Some(Family::Ggx),
            "student" | "student-t" => Some(Family::Student),
            "hybrid" => Some(Family::Hybrid),
            _ => None,
        }
    }

    /// The NDF of roughness `alpha` (> 0) with the family's default shape (Student:
    /// γ = [`STUDENT_GAMMA_START`]; Hybrid: GGX without table). Panics unless `alpha > 0`.
    pub fn ndf(self, alpha: f64) -> Ndfs {
        Model::new(self, alpha).ndf().expect("alpha > 0")
    }

    /// tan θ / α at which D(θ) falls to half its peak, small-α limit (GGX: (1 + t²)⁻² = 1/2,
    /// t = √(√2 − 1) ≈ 0.644; Beckmann: exp(−t²) = 1/2, t = √ln 2 ≈ 0.833; Student γ:
    /// t² = (γ − 1)(2^(1/γ) − 1)).
    fn half_max_slope(self) -> f64 {
        match self {
            Family::Ggx | Family::Hybrid => (2f64.sqrt() - 1.0).sqrt(),
            Family::Beckmann => 2f64.ln().sqrt(),
            Family::Student => {
                let g = STUDENT_GAMMA_START;
                ((g - 1.0) * (2f64.powf(1.0 / g) - 1.0)).sqrt()
            }
        }
    }
}

/// One NDF model with every parameter: an analytic base shape (Beckmann, GGX or Student-t),
/// optionally shifted (`D(θ) ∝ base(|θ − δ|)`), optionally with a hybrid table.
#[derive(Clone, Debug, PartialEq)]
pub struct Model {
    /// The family reported (Hybrid when `nodes` is not empty).
    pub family: Family,
    /// Shape of the analytic part: Beckmann, Ggx or Student.
    pub base: Family,
    /// Roughness α.
    pub alpha: f64,
    /// Student-t tail exponent γ (Student base only).
    pub gamma: Option<f64>,
    /// Peak shift δ in radians (`Some` when the shift is fitted).
    pub delta: Option<f64>,
    /// Hybrid table: (θ radians, multiplier of the normalised analytic part at θ). The last
    /// node is the anchor (multiplier 1, not fitted) that joins the table to the analytic part.
    pub nodes: Vec<(f64, f64)>,
}

impl Model {
    /// The family's default model of roughness `alpha` (no shift, no table).
    pub fn new(family: Family, alpha: f64) -> Model {
        let base = if family == Family::Hybrid { Family::Ggx } else { family };
        Model {
            family: if family == Family::Hybrid { base } else { family },
            base,
            alpha,
            gamma: (base == Family::Student).then_some(STUDENT_GAMMA_START),
            delta: None,
            nodes: Vec::new(),
        }
    }

    /// The analytic part (with its shift) as a numeric profile.
    pub fn base_profile(&self) -> Profile {
        let alpha = self.alpha;
        let b = match self.base {
            Family::Beckmann => Profile::Beckmann { alpha },
            Family::Ggx | Family::Hybrid => Profile::Ggx { alpha },
            Family::Student => Profile::StudentT { alpha, gamma: self.gamma.unwrap_or(STUDENT_GAMMA_START) },
        };
        match self.delta {
            Some(delta) => Profile::Shifted { base: Box::new(b), delta },
            None => b,
        }
    }

    fn base_ndf(&self) -> opal::Result<Ndfs> {
        match (self.base, self.delta) {
            (Family::Beckmann, None) => Ok(Ndfs::Beckmann(Beckmann::new(self.alpha as f32)?)),
            (Family::Ggx | Family::Hybrid, None) => Ok(Ndfs::Ggx(Ggx::new(self.alpha as f32)?)),
            _ => Ndfs::numeric(self.base_profile()),
        }
    }

    /// The NDF (analytic when possible, else tabulated by `opal::bsdf::microfacet::numeric`).
    pub fn ndf(&self) -> opal::Result<Ndfs> {
        let base = self.base_ndf()?;
        if self.nodes.is_empty() {
            return Ok(base);
        }
        let theta: Vec<f64> = self.nodes.iter().map(|n| n.0).collect();
        let d: Vec<f64> = self
            .nodes
            .iter()
            .map(|&(t, m)| m * base.d(Vec3::new(t.sin() as f32, 0.0, t.cos() as f32)) as f64)
            .collect();
        Ndfs::numeric(Profile::Hybrid { base: Box::new(self.base_profile()), theta, d })
    }

    /// Number of fitted parameters.
    pub fn parameter_count(&self) -> usize {
        1 + self.gamma.is_some() as usize + self.delta.is_some() as usize + self.nodes.len().saturating_sub(1)
    }

    /// Every parameter as JSON (`alpha`, `gamma`, `delta_deg`, `nodes` with θ in degrees, the
    /// multiplier and the tabulated D).
    pub fn params_json(&self) -> serde_json::Value {
        let mut m = serde_json::Map::new();
        m.insert("base".into(), self.base.name().into());
        m.insert("alpha".into(), self.alpha.into());
        if let Some(g) = self.gamma {
            m.insert("gamma".into(), g.into());
        }
        if let Some(d) = self.delta {
            m.insert("delta_deg".into(), d.to_degrees().into());
        }
        if !self.nodes.is_empty() {
            let base = self.base_ndf().ok();
            let nodes: Vec<serde_json::Value> = self
                .nodes
                .iter()
                .map(|&(t, k)| {
                    let d =
                        base.as_ref().map(|b| k * b.d(Vec3::new(t.sin() as f32, 0.0, t.cos() as f32)) as f64);
                    serde_json::json!({"theta_deg": t.to_degrees(), "scale": k, "d_unnormalised": d})
                })
                .collect();
            m.insert("hybrid_nodes".into(), nodes.into());
        }
        serde_json::Value::Object(m)
    }

    /// Short description (`student α=0.2013 γ=5.10 δ=9.8° nodes=2`).
    pub fn describe(&self) -> String {
        let mut s = format!("{} α={:.4}", self.family.name(), self.alpha);
        if self.family == Family::Hybrid {
            s.push_str(&format!(" base={}", self.base.name()));
        }
        if let Some(g) = self.gamma {
            s.push_str(&format!(" γ={g:.2}"));
        }
        if let Some(d) = self.delta {
            s.push_str(&format!(" δ={:.2}°", d.to_degrees()));
        }
        if !self.nodes.is_empty() {
            let k: Vec<String> =
                self.nodes.iter().map(|(t, k)| format!("{:.1}°×{k:.2}", t.to_degrees())).collect();
            s.push_str(&format!(" nodes=[{}]", k.join(", ")));
        }
        s
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
    /// Maximum number of optimiser iterations per family and stage (Nelder–Mead: per free
    /// coordinate).
    pub max_iters: u64,
    /// Photons per incidence of the coarse stage (`None`: one stage at `photons`). The coarse
    /// stage optimises from the initial guess; the fine stage (at `photons`) restarts from its
    /// optimum with smaller steps. With the same seed the coarse photons are the first ones of
    /// the fine run (one random stream per photon).
    pub coarse_photons: Option<u64>,
}

impl FitSetup {
    /// The default coarse stage: `photons / 8` when that is at least 10 000, else none.
    pub fn default_coarse(photons: u64) -> Option<u64> {
        (photons / 8 >= 10_000).then_some(photons / 8)
    }
}

#[derive(Clone, Copy, Debug)]
struct Point {
    inc: usize,
    det: usize,
    m: f64,
    sm: f64,
    /// Index of the measured curve (only points of one curve share overlapping detectors).
    curve: usize,
}

/// Which simulator an objective evaluation uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// `coarse_photons` per incidence.
    Coarse,
    /// `photons` per incidence.
    Fine,
}

/// The fitting problem: measurement + simulator.
pub struct Problem {
    /// The measured curves.
    pub measured: Measured,
    /// The setup.
    pub setup: FitSetup,
    gonio: Gonio,
    gonio_coarse: Option<Gonio>,
    points: Vec<Point>,
    /// (curve, detector index in the simulator) for every measured point, used or not.
    all: Vec<Vec<usize>>,
    incidences: Vec<f64>,
    /// Simulations run: (coarse, at `photons` or other).
    evals: Mutex<(u64, u64)>,
}

/// Quality of one simulation against the measurement.
#[derive(Clone, Debug)]
pub struct Evaluation {
    /// RMS relative residual over the used points.
    pub rms: f64,
    /// RMS combined relative standard error (simulation + measurement) over the same points.
    pub noise: f64,
    /// χ² = Σ (s − m)² / (σs² + σm²) over the used points.
    pub chi2: f64,
    /// Per incidence (degrees): (incidence_deg, rms, noise, points).
    pub per_incidence: Vec<(f64, f64, f64, usize)>,
    /// Number of points used.
    pub points: usize,
    /// The simulation.
    pub result: GonioResult,
}

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
    /// (parameters, objective) of every evaluation in order; parameters as in
    /// [`Model::param_values`], the stage is `coarse`/`fine`.
    pub history: Vec<(&'static str, Vec<f64>, f64)>,
}

/// The coordinates an optimiser moves (each bounded; out-of-bounds points are clamped and
/// penalised quadratically so the simplex walks back).
#[derive(Clone, Copy, Debug, PartialEq)]
enum Coord {
    /// ln α ∈ [ln 10⁻³, ln 3].
    LnAlpha,
    /// q = 2/γ ∈ [0.01, 1] (1 = GGX, → 0 Beckmann).
    Q,
    /// δ in degrees ∈ [0, 60].
    DeltaDeg,
    /// ln of the multiplier of hybrid node k ∈ [ln 0.02, ln 50].
    LnScale(usize),
}

impl Coord {
    fn bounds(self) -> (f64, f64) {
        match self {
            Coord::LnAlpha => (1e-3f64.ln(), 3f64.ln()),
            Coord::Q => (0.01, 1.0),
            Coord::DeltaDeg => (0.0, 60.0),
            Coord::LnScale(_) => (0.02f64.ln(), 50f64.ln()),
        }
    }
    /// Coarse initial simplex step.
    fn step(self) -> f64 {
        match self {
            Coord::LnAlpha => 0.15,
            Coord::Q => 0.3,
            Coord::DeltaDeg => 4.0,
            Coord::LnScale(_) => 0.4,
        }
    }
    fn get(self, m: &Model) -> f64 {
        match self {
            Coord::LnAlpha => m.alpha.ln(),
            Coord::Q => 2.0 / m.gamma.unwrap_or(STUDENT_GAMMA_START),
            Coord::DeltaDeg => m.delta.unwrap_or(0.0).to_degrees(),
            Coord::LnScale(k) => m.nodes[k].1.ln(),
        }
    }
    fn set(self, m: &mut Model, x: f64) {
        match self {
            Coord::LnAlpha => m.alpha = x.exp(),
            Coord::Q => m.gamma = Some(2.0 / x),
            Coord::DeltaDeg => m.delta = Some(x.to_radians()),
            Coord::LnScale(k) => m.nodes[k].1 = x.exp(),
        }
    }
}

/// The model at coordinates `x` (clamped into bounds) and the squared distance clamped away.
fn apply(start: &Model, coords: &[Coord], x: &[f64]) -> (Model, f64) {
    let mut m = start.clone();
    let mut pen = 0.0;
    for (c, &v) in coords.iter().zip(x) {
        let (lo, hi) = c.bounds();
        let vc = if v.is_finite() { v.clamp(lo, hi) } else { lo };
        pen += (v - vc).powi(2);
        c.set(&mut m, vc);
    }
    (m, pen)
}

impl Model {
    /// The parameter values in reporting units: α, then γ, δ (degrees) and the hybrid
    /// multipliers when present.
    pub fn param_values(&self) -> Vec<f64> {
        let mut v = vec![self.alpha];
        v.extend(self.gamma);
        v.extend(self.delta.map(f64::to_degrees));
        if self.nodes.len() > 1 {
            v.extend(self.nodes[..self.nodes.len() - 1].iter().map(|n| n.1));
        }
        v
    }
}

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
    /// Whether B is preferred (ΔX > threshold).
    pub accepted: bool,
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
        let gsetup = GonioSetup {
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
        };
        let gonio_coarse = match setup.coarse_photons {
            Some(n) if n < setup.photons => Some(Gonio::new(GonioSetup { photons: n, ..gsetup.clone() })?),
            _ => None,
        };
        let gonio = Gonio::new(gsetup)?;
        let na = angles.len();
        let mut points = Vec::new();
        let mut all = Vec::new();
        for (curve, c) in measured.curves.iter().enumerate() {
            let inc = incidences.iter().position(|&t| t == c.incidence).expect("incidence listed");
            let off = if c.side == Side::R { 0 } else { na };
            let floor = setup.floor_rel * c.max();
            let mut idx = Vec::new();
            for (k, &a) in c.detector.iter().enumerate() {
                let j = angles.iter().position(|&x| (x - a).abs() < 1e-9).expect("angle listed");
                idx.push(off + j);
                let m = c.value[k];
                if setup.fit_on.uses(c.side) && m > 0.0 && m >= floor {
                    points.push(Point { inc, det: off + j, m, sm: c.stderr[k], curve });
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
        Ok(Problem {
            measured,
            setup,
            gonio,
            gonio_coarse,
            points,
            all,
            incidences,
            evals: Mutex::new((0, 0)),
        })
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

    /// Number of simulations run so far (both stages and every check).
    pub fn evaluations(&self) -> u64 {
        let e = self.evals.lock().expect("no panic while counting");
        e.0 + e.1
    }

    /// Simulations run so far: (coarse stage, at full photons).
    pub fn evaluations_by_stage(&self) -> (u64, u64) {
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
        let plate = self.plate_with(ndf);
        let coarse = self.gonio_coarse.as_ref().filter(|g| g.setup().photons == photons);
        {
            let mut e = self.evals.lock().expect("no panic while counting");
            if coarse.is_some() { e.0 += 1 } else { e.1 += 1 }
        }
        if seed == self.setup.seed {
            if photons == self.setup.photons {
                return self.gonio.run_plate(&plate);
            }
            if let Some(g) = coarse {
                return g.run_plate(&plate);
            }
        }
        let mut s = self.gonio.setup().clone();
        s.seed = seed;
        s.photons = photons;
        Gonio::new(s)?.run_plate(&plate)
    }

    fn stage_photons(&self, stage: Stage) -> u64 {
        match (stage, &self.gonio_coarse) {
            (Stage::Coarse, Some(g)) => g.setup().photons,
            _ => self.setup.photons,
        }
    }

    /// Whether the setup has a separate coarse stage.
    pub fn has_coarse_stage(&self) -> bool {
        self.gonio_coarse.is_some()
    }

    /// Compares a simulation with the measurement.
    pub fn evaluate(&self, res: GonioResult) -> Evaluation {
        let mut se = 0.0;
        let mut sn = 0.0;
        let mut chi2 = 0.0;
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
            if n > 0.0 {
                chi2 += e * e / n;
            }
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
            chi2,
            per_incidence,
            points: self.points.len(),
            result: res,
        }
    }

    /// The selection rule: is the richer model B (`rich`, `extra_params` more parameters)
    /// better than A (`simple`) by more than noise explains? Both evaluations must come from
    /// the same independent check seed. ΔX = Σ d_p with d_p = ((sA − m)² − (sB − m)²)/v_p,
    /// v_p = σm² + (σsA² + σsB²)/2. Noise of ΔX: with U = sA − sB and W = sA + sB − 2m
    /// (d_p = U W / v_p), jointly Gaussian with Var U = σsA² + σsB², Var W = Var U + 4σm²,
    /// C = Cov(U, W) = σsA² − σsB²: `Var(UW) = E[U]² Var W + E[W]² Var U + 2 E[U] E[W] C +
    /// Var U Var W + C²`, with E[U]² ≈ U² − Var U and E[W]² ≈ W² − Var W from the observed
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
                let h = dist / (2.0 * r);
                let rho = (2.0 * h.acos() - 2.0 * h * (1.0 - h * h).sqrt()) / std::f64::consts::PI;
                var += 2.0 * rho * (a.3 * b.3).sqrt() + 2.0 * rho * rho * (a.4 * b.4).sqrt();
            }
        }
        let inflation = if var_indep > 0.0 { (var / var_indep).max(1.0) } else { 1.0 };
        let sd = var.max(0.0).sqrt();
        let threshold = inflation * chi2_q99(extra_params) + Z99 * sd;
        Comparison { delta_chi2: total, sd, inflation, extra_params, threshold, accepted: total > threshold }
    }

    /// The objective: `Σ ((s − m)² − σs²)/m / Σ m` over the used points, i.e. the squared
    /// relative residual `((s − m)/m)²` weighted by `m` (Pearson's χ² form). The weight is the
    /// inverse of the relative variance of a photon-count estimate (`Var s ∝ s`), so the
    /// dim, photon-starved points do not dominate the objective's noise; subtracting the
    /// simulation's own variance σs² makes it an unbiased estimate of the misfit of the
    /// *expected* simulation (plus a constant): without it the Monte-Carlo variance, which
    /// grows with the simulated value, pulls α towards dimmer lobes.
    fn objective(&self, ndf: Ndfs, stage: Stage) -> opal::Result<f64> {
        let res = self.simulate(ndf, self.setup.seed, self.stage_photons(stage))?;
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
        let history = Mutex::new(Vec::new());
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
            let (x, fx, ok) = self.brent(&model, stage, span.ln(), tol, &history)?;
            model.alpha = x.exp();
            objective = fx;
            converged &= ok;
        }
        Ok(FamilyFit {
            alpha_initial: a0,
            model,
            objective,
            evaluations: self.evaluations() - e0,
            converged,
            history: history.into_inner().expect("no panic while recording"),
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
        history: &Mutex<Vec<(&'static str, Vec<f64>, f64)>>,
    ) -> opal::Result<(f64, f64, bool)> {
        let mut center = start.alpha.ln();
        let mut best = (center, f64::INFINITY);
        let mut converged = false;
        for _round in 0..4 {
            let (lo, hi) = (center - span, center + span);
            let cost = Cost1 {
                inner: ParamCost { problem: self, start, coords: &[Coord::LnAlpha], stage, history },
            };
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
        history: &Mutex<Vec<(&'static str, Vec<f64>, f64)>>,
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
        let cost = ParamCost { problem: self, start, coords, stage, history };
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

    /// The natural unit of the objective at a simulation: Σ (σs² + σm²)/m / Σ m (the
    /// objective's value when every residual is one standard error).
    fn objective_noise(&self, res: &GonioResult) -> f64 {
        let (mut acc, mut wsum) = (0.0, 0.0);
        for p in &self.points {
            let ss = res.incidences[p.inc].value_stderr[p.det];
            acc += (ss * ss + p.sm * p.sm) / p.m;
            wsum += p.m;
        }
        acc / wsum
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
        for k in 0..start.nodes.len().saturating_sub(1) {
            coords.push(Coord::LnScale(k));
        }
        self.fit_coords(start, &coords, step_scale)
    }

    /// Refits a hybrid model: α and every free node multiplier (the shape parameters γ, δ of
    /// the analytic part stay as fitted before the nodes were added).
    pub fn fit_hybrid(&self, start: &Model) -> opal::Result<FamilyFit> {
        let mut coords = vec![Coord::LnAlpha];
        for k in 0..start.nodes.len().saturating_sub(1) {
            coords.push(Coord::LnScale(k));
        }
        self.fit_coords(start, &coords, 0.5)
    }

    fn fit_coords(&self, start: &Model, coords: &[Coord], step_scale: f64) -> opal::Result<FamilyFit> {
        let e0 = self.evaluations();
        let history = Mutex::new(Vec::new());
        let probe = self.simulate(start.ndf()?, self.setup.seed, self.stage_photons(Stage::Fine))?;
        let unit = self.objective_noise(&probe);
        let mut model = start.clone();
        let mut objective = f64::INFINITY;
        let mut converged = true;
        let stages: &[(Stage, f64, f64)] = if self.has_coarse_stage() {
            &[(Stage::Coarse, step_scale, 1e-2), (Stage::Fine, step_scale / 8.0, 1e-2)]
        } else {
            &[(Stage::Fine, step_scale, 1e-2)]
        };
        for &(stage, scale, tol) in stages {
            let (m, fx, ok) = self.nelder_mead(&model, coords, stage, scale, tol * unit, &history)?;
            model = m;
            objective = fx;
            converged &= ok;
        }
        Ok(FamilyFit {
            alpha_initial: start.alpha,
            model,
            objective,
            evaluations: self.evaluations() - e0,
            converged,
            history: history.into_inner().expect("no panic while recording"),
        })
    }

    /// Re-simulates `model` with the independent check seed at full photons.
    pub fn check(&self, model: &Model) -> opal::Result<Evaluation> {
        Ok(self.evaluate(self.simulate(model.ndf()?, check_seed(self.setup.seed), self.setup.photons)?))
    }
}

/// The independent seed of the quality check and of model selection.
pub fn check_seed(seed: u64) -> u64 {
    seed.wrapping_add(0x9E37_79B9)
}

struct ParamCost<'a> {
    problem: &'a Problem,
    start: &'a Model,
    coords: &'a [Coord],
    stage: Stage,
    history: &'a Mutex<Vec<(&'static str, Vec<f64>, f64)>>,
}

impl CostFunction for ParamCost<'_> {
    type Param = Vec<f64>;
    type Output = f64;
    fn cost(&self, x: &Vec<f64>) -> Result<f64, argmin::core::Error> {
        let (m, pen) = apply(self.start, self.coords, x);
        let f = m
            .ndf()
            .and_then(|ndf| self.problem.objective(ndf, self.stage))
            .map_err(|e| argmin::core::Error::msg(e.to_string()))?;
        let label = if self.stage == Stage::Coarse { "coarse" } else { "fine" };
        self.history.lock().expect("no panic while recording").push((label, m.param_values(), f));
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

/// What [`fit`] fits.
#[derive(Clone, Debug, Default)]
pub struct FitOptions {
    /// `None` = auto (GGX, Beckmann, Student-t; the selection rule keeps one); `Some(Ggx |
    /// Beckmann)` = that family only; `Some(Student)` = GGX and Beckmann, then Student-t from
    /// the better one (kept whatever the rule says); `Some(Hybrid)` = auto, then hybrid nodes.
    pub family: Option<Family>,
    /// Fit a peak shift δ in every family.
    pub shift: bool,
    /// Maximum number of hybrid nodes (free table values), `Some(Hybrid)` only.
    pub hybrid_nodes: usize,
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
    /// The selection decisions (Student vs the best one-parameter family, each hybrid node).
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

/// Angular spacing of the hybrid nodes: a third of the analytic part's half width at half
/// maximum in θm (measured on the NDF itself, from its peak outward), in [0.5°, 10°].
pub fn hybrid_spacing(model: &Model) -> f64 {
    let base = Model { nodes: Vec::new(), ..model.clone() };
    let Ok(ndf) = base.ndf() else { return 2f64.to_radians() };
    let d = |t: f64| ndf.d(Vec3::new(t.sin() as f32, 0.0, t.cos() as f32)) as f64;
    let step = 0.05f64.to_radians();
    let n = (89.0f64.to_radians() / step) as usize;
    let (ipk, dpk) =
        (0..n).map(|i| (i, d(i as f64 * step))).fold((0, 0.0), |a, b| if b.1 > a.1 { b } else { a });
    let ihalf = (ipk..n).find(|&i| d(i as f64 * step) < 0.5 * dpk).unwrap_or(n);
    (((ihalf - ipk) as f64 * step) / 3.0).clamp(0.5f64.to_radians(), 10f64.to_radians())
}

/// Fits the NDF: the one-parameter families (Brent, or Nelder–Mead with `shift`), the
/// Student-t family from the better of them, hybrid nodes on top of the kept analytic model;
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
        let check = problem.check(&fit.model)?;
        cands.push(Candidate { fit, check });
    }
    let mut best = (0..cands.len())
        .min_by(|&a, &b| cands[a].check.chi2.total_cmp(&cands[b].check.chi2))
        .expect("at least one family");
    if matches!(opts.family, None | Some(Family::Student) | Some(Family::Hybrid)) {
        let b = &cands[best].fit.model;
        let mut m = b.clone();
        m.family = Family::Student;
        m.base = Family::Student;
        // start on the family that fitted best (q = 2/γ: 1 = GGX, 0.01 ≈ Beckmann), so the
        // simplex holds the nested model and Nelder–Mead (which keeps its best vertex) can only
        // improve on it
        m.gamma = Some(if b.base == Family::Beckmann { 2.0 / 0.01 } else { 2.0 });
        let fit = problem.fit_model(&m, 0.5)?;
        let check = problem.check(&fit.model)?;
        cands.push(Candidate { fit, check });
        let si = cands.len() - 1;
        let comparison = problem.compare(&cands[best].check, &cands[si].check, 1);
        let accepted = comparison.accepted;
        decisions.push(Decision { simple: best, rich: si, comparison });
        if accepted || opts.family == Some(Family::Student) {
            best = si;
        }
    }
    if opts.family == Some(Family::Hybrid) {
        let h = hybrid_spacing(&cands[best].fit.model);
        for k in 1..=opts.hybrid_nodes {
            let pm = &cands[best].fit.model;
            let mut m = pm.clone();
            m.family = Family::Hybrid;
            let mut nodes: Vec<(f64, f64)> = pm.nodes[..pm.nodes.len().saturating_sub(1)].to_vec();
            nodes.push(((k - 1) as f64 * h, 1.0));
            nodes.push((k as f64 * h, 1.0));
            m.nodes = nodes;
            let fit = problem.fit_hybrid(&m)?;
            let check = problem.check(&fit.model)?;
            cands.push(Candidate { fit, check });
            let hi = cands.len() - 1;
            let comparison = problem.compare(&cands[best].check, &cands[hi].check, 1);
            let accepted = comparison.accepted;
            decisions.push(Decision { simple: best, rich: hi, comparison });
            if !accepted {
                break;
            }
            best = hi;
        }
    }
    // a rejected hybrid step that did not converge does not matter (the rule stopped there)
    let converged = cands
        .iter()
        .enumerate()
        .all(|(i, c)| c.fit.converged || (i != best && c.fit.model.family == Family::Hybrid));
    Ok(FitReport {
        candidates: cands,
        best,
        decisions,
        check_seed: check_seed(problem.setup.seed),
        converged,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
