//! Fitting the micro-facet normal distribution of a plate's rough face to measured
//! goniophotometer curves (method A, inverse half).
//!
//! Model: the measured plate is simulated by [`opal::gonio::Gonio`] with the same beam,
//! detectors and incidence angles as the measurement (plane-of-incidence curves: the plane
//! layout at the measured signed angles; full-hemisphere measurements: the hemisphere layout on
//! the measured polar angles × azimuths, tested in `hemisphere_tests`); the rough face carries an NDF
//! ([`Model`]): an analytic shape ([`Family`]: Beckmann = Gauss-like slopes, GGX = Cauchy-like
//! slopes, Student-t = tail exponent γ between them, `Profile::StudentT`) of roughness α,
//! optionally shifted (`D(θ) ∝ base(|θ − δ|)`, `Profile::Shifted`) and optionally hybrid (a
//! piecewise-linear table of multipliers of the analytic part at nodes on a grid θk = k·h,
//! each placed where the kept model misses the data most (module `nodes`), `Profile::Hybrid`),
//! with single or multiple scattering on the micro-surface.
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
//! Calibration ([`ScaleMode`], module `scale`): measured values in relative units or with an
//! uncertain calibration are modelled as factor × simulated, one factor for the file, per
//! incidence or per curve; for given NDF parameters the best factors are closed-form, so every
//! evaluation profiles them out without extra simulations (optionally with a Gaussian prior
//! around 1). `FitSetup::rel_error` is the noise model of files without standard errors.
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
//! GGX/Beckmann; hybrid from the model `auto` keeps, adding one node at a time at the θm bin
//! of the largest excess χ² (`nodes`).
//!
//! Model selection ([`fit`], [`Problem::compare`]): every candidate is re-simulated with an
//! independent check seed; a richer (nesting) model is kept only when its χ² improvement ΔX
//! exceeds c·χ²₀.₉₉(k) + 2.326·sd (k extra parameters, sd the noise of ΔX propagated from the
//! standard errors, c the correlation inflation of overlapping detectors); derivation in
//! docs/fit-ndf.md.
//!
//! Tests: `tests.rs` (models, coordinates, quantiles, calibration factors);
//! `crates/opal-inverse/tests/ndf_fit.rs` (one Mitsuba reference case and a scaled measurement
//! in the default tier; all six and the Student-t, shift, multiple-scattering, hybrid and
//! scaled round trips `#[ignore]`d, commands in docs/testing.md).

mod auto;
mod model;
mod nodes;
mod optimise;
mod scale;
mod selection;

pub use auto::{
    Candidate, DEFAULT_HYBRID_NODES, DOTTED_TRIGGER, Decision, FitOptions, FitReport, HYBRID_TRIGGER, fit,
};
pub use model::{DOTTED_COVERAGE_START, Family, Model, STUDENT_GAMMA_START, hybrid_spacing};
pub use nodes::with_node;
pub use optimise::{FamilyFit, fit_families};
pub use scale::{ScaleFit, ScaleGroup, ScaleMode, ScaleSetup};
pub use selection::{Comparison, Z99, chi2_q99, step_accepted};

use crate::measured::Measured;
use opal::bsdf::microfacet::Ndfs;
use opal::gonio::{
    Beam, DetectorGrid, DetectorLayout, Face, Gonio, GonioResult, GonioSetup, Plate, Scattering, Side,
};
use std::sync::Mutex;

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
    /// Unknown calibration factors of the measurement (fitted in closed form; see
    /// [`ScaleMode`]).
    pub scale: ScaleSetup,
    /// Relative standard error of every measured value (noise model of files without standard
    /// errors, e.g. normalised to 1 at the peak): [`Problem::new`] replaces each point's
    /// standard error σ by `sqrt(σ² + (rel_error · value)²)`. 0 = the file's errors only.
    pub rel_error: f64,
    /// Noise-based point selection: when `Some(z)`, a point below `floor_rel` of its curve's
    /// maximum is still used when its value is at least z of its standard errors (a dim
    /// diffuse lobe measured well above its noise, beside a bright specular spike). `None`:
    /// `floor_rel` alone. Default of the CLI: [`DEFAULT_MIN_SNR`].
    pub min_snr: Option<f64>,
}

/// The default of [`FitSetup::min_snr`] (what `opal fit-ndf` uses): a point below the floor is
/// used when its value is at least 3 standard errors. Why 3: a point that is pure noise passes
/// with probability ≈ 0.13 % (one-sided Gaussian), so the lobe points are real signal, while a
/// lobe 100× below a spike measured with 10⁶ photons clears it over most of its width (the
/// Mitsuba dotted plate: 643 and 880 points instead of ~36). Selecting by the measured value
/// favours upward fluctuations only for points whose true value is within ~1 σ of the
/// threshold (the lobe's far edge); a lower z would add more such points and noise-only ones.
pub const DEFAULT_MIN_SNR: f64 = 3.0;

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
    /// Calibration-factor group (`None` without factors).
    group: Option<usize>,
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
    /// Groups of points sharing a calibration factor (empty: absolute values).
    groups: Vec<ScaleGroup>,
    /// Factor group of every (incidence, side R/T), `None` when no fitted point is there.
    group_of: Vec<[Option<usize>; 2]>,
    /// Simulations run: (coarse, at `photons` or other).
    evals: Mutex<(u64, u64)>,
    /// Stops every simulation early when set ([`Problem::with_cancel`]).
    cancel: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>,
    /// Processes sharing every simulation's photon batches ([`Problem::with_comm`]).
    comm: Option<std::sync::Arc<dyn opal::dist::Comm>>,
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
    /// Absolute values only (`None` with calibration factors): the global factor between
    /// measured and simulated values ([`ScaleCheck`]), a check of the calibration.
    pub scale_check: Option<ScaleCheck>,
}

/// One global factor `k` with `m ≈ k s` over the used points, fitted after an absolute fit
/// by weighted least squares (weights `1/(σm² + σs²)`):
/// `k = Σ w m s / Σ w s²`, `σk = (Σ w s²)^(−1/2)`. [`Problem`]'s check passes the
/// measurement's standard error scaled to the simulated value (`σm √(s/m)`, the variance of a
/// count at the model's value), so the weights do not favour points that fluctuated low. A calibration error shows as `k ≠ 1`
/// even when the NDF absorbed part of it and the residuals stay near the noise.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScaleCheck {
    /// The factor (measured ≈ k × simulated).
    pub k: f64,
    /// Its standard error.
    pub stderr: f64,
    /// `|k − 1| > 3 σk` and `|k − 1| > 2 %`: the measurement's scale does not match.
    pub mismatch: bool,
    /// rms/noise of the fit with the free scale: √(Σ ((k s − m)/m)² / Σ (k² σs² + σm²)/m²)
    /// over the same points. Near 1 when the shape fits and only the scale is off (a
    /// calibration error); well above 1 when the model's shape is wrong, whatever k says.
    pub scaled_ratio: f64,
}

/// The bound of a fit that describes the data: check rms ≤ this many times the noise (the
/// acceptance bound of method A's fits). Shared by [`SCALED_FIT_MAX_RATIO`] and
/// [`HYBRID_TRIGGER`].
pub const FITS_WITHIN_NOISE: f64 = 1.5;

/// Largest [`ScaleCheck::scaled_ratio`] at which a flagged check is put down to the
/// calibration (the model with the free factor fits within [`FITS_WITHIN_NOISE`]); above it
/// the shape does not match and k follows the wrong shape.
pub const SCALED_FIT_MAX_RATIO: f64 = FITS_WITHIN_NOISE;

impl ScaleCheck {
    /// The check from (measured, its standard error, simulated, its standard error) points.
    pub fn from_points(points: impl IntoIterator<Item = (f64, f64, f64, f64)>) -> Option<ScaleCheck> {
        let points: Vec<(f64, f64, f64, f64)> = points.into_iter().collect();
        let (mut ms, mut ss) = (0.0, 0.0);
        for &(m, sm, s, sds) in &points {
            let v = sm * sm + sds * sds;
            if v > 0.0 && v.is_finite() {
                ms += m * s / v;
                ss += s * s / v;
            }
        }
        // none usable (also a NaN sum)
        if ss.is_nan() || ss <= 0.0 {
            return None;
        }
        let k = ms / ss;
        let stderr = ss.sqrt().recip();
        let d = (k - 1.0).abs();
        let (mut e2, mut n2) = (0.0, 0.0);
        for &(m, sm, s, sds) in points.iter().filter(|p| p.0 > 0.0) {
            e2 += ((k * s - m) / m).powi(2);
            n2 += (k * k * sds * sds + sm * sm) / (m * m);
        }
        let scaled_ratio = if n2 > 0.0 { (e2 / n2).sqrt() } else { f64::NAN };
        Some(ScaleCheck { k, stderr, mismatch: d > 3.0 * stderr && d > 0.02, scaled_ratio })
    }
}

/// Index of the hemisphere detector at polar `theta`, azimuth `phi` (radians) on `side`.
fn hemisphere_index(gonio: &Gonio, side: Side, theta: f64, phi: f64) -> usize {
    let (t, p) = (theta.to_degrees(), phi.to_degrees());
    gonio
        .detectors()
        .list()
        .iter()
        .position(|d| {
            d.side == side && (d.angle_deg - t).abs() < 1e-6 && (t == 0.0 || (d.azimuth_deg - p).abs() < 1e-6)
        })
        .expect("every measured (polar, azimuth) is a detector of the grid built from them")
}

impl Problem {
    /// Builds the simulator for the measurement's incidences and detector angles; folds
    /// `setup.rel_error` into the measured standard errors (`measured.curves[].stderr`).
    pub fn new(mut measured: Measured, setup: FitSetup) -> opal::Result<Self> {
        if !(setup.floor_rel.is_finite() && (0.0..1.0).contains(&setup.floor_rel)) {
            return Err(opal::Error::invalid(
                "floor_rel",
                format!("must be in [0, 1), got {}", setup.floor_rel),
            ));
        }
        if !(setup.rel_error.is_finite() && setup.rel_error >= 0.0) {
            return Err(opal::Error::invalid(
                "relative error",
                format!("must be finite and ≥ 0, got {}", setup.rel_error),
            ));
        }
        if let Some(sk) = setup.scale.prior {
            if !(sk.is_finite() && sk > 0.0) {
                return Err(opal::Error::invalid(
                    "scale prior",
                    format!("the factors' relative uncertainty must be finite and > 0, got {sk}"),
                ));
            }
            if setup.scale.mode == ScaleMode::Absolute {
                return Err(opal::Error::invalid(
                    "scale prior",
                    "a prior on the calibration factors needs fitted factors (the values are absolute)",
                ));
            }
        }
        if setup.rel_error > 0.0 {
            for c in &mut measured.curves {
                for (se, &v) in c.stderr.iter_mut().zip(&c.value) {
                    *se = se.hypot(setup.rel_error * v);
                }
            }
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
        let grid = if measured.hemisphere {
            // the simulator's hemisphere layout on the measured polar × azimuth values
            DetectorGrid::Hemisphere { polar: angles.clone(), azimuth: measured.detector_azimuths() }
        } else {
            DetectorGrid::PlaneOfIncidence { angles: angles.clone() }
        };
        let gsetup = GonioSetup {
            beam: setup.beam.clone(),
            incidences: incidences.clone(),
            detectors: DetectorLayout {
                grid,
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
                let det = if measured.hemisphere {
                    hemisphere_index(&gonio, c.side, a, c.azimuth[k])
                } else {
                    off + angles.iter().position(|&x| (x - a).abs() < 1e-9).expect("angle listed")
                };
                idx.push(det);
                let m = c.value[k];
                let significant = setup.min_snr.is_some_and(|z| c.stderr[k] > 0.0 && m >= z * c.stderr[k]);
                if setup.fit_on.uses(c.side) && m > 0.0 && (m >= floor || significant) {
                    points.push(Point { inc, det, m, sm: c.stderr[k], curve, group: None });
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
        let mut groups = Vec::new();
        let mut group_of = vec![[None; 2]; incidences.len()];
        if setup.scale.mode != ScaleMode::Absolute {
            for p in &mut points {
                let side = measured.curves[p.curve].side;
                let si = (side == Side::T) as usize;
                let key = match setup.scale.mode {
                    ScaleMode::Global => ScaleGroup { incidence_deg: None, side: None },
                    ScaleMode::PerIncidence => {
                        ScaleGroup { incidence_deg: Some(incidences[p.inc].to_degrees()), side: None }
                    }
                    _ => ScaleGroup { incidence_deg: Some(incidences[p.inc].to_degrees()), side: Some(side) },
                };
                let g = match groups.iter().position(|x| *x == key) {
                    Some(g) => g,
                    None => {
                        groups.push(key);
                        groups.len() - 1
                    }
                };
                p.group = Some(g);
                group_of[p.inc][si] = Some(g);
            }
            // a side without fitted points shares its incidence's (or the global) factor
            if setup.scale.mode != ScaleMode::PerCurve {
                for gi in &mut group_of {
                    let g = gi[0].or(gi[1]);
                    gi[0] = gi[0].or(g);
                    gi[1] = gi[1].or(g);
                }
                if setup.scale.mode == ScaleMode::Global {
                    group_of = vec![[Some(0); 2]; incidences.len()];
                }
            }
        }
        Ok(Problem {
            measured,
            setup,
            gonio,
            gonio_coarse,
            points,
            all,
            incidences,
            groups,
            group_of,
            evals: Mutex::new((0, 0)),
            cancel: None,
            comm: None,
        })
    }

    /// A flag that stops the fit early when set (e.g. by Ctrl-C): every simulation then returns
    /// [`opal::Error::Interrupted`] at its next group of batches ([`Gonio::with_cancel`]), which
    /// the fit passes on. Unset, results are unchanged.
    pub fn with_cancel(mut self, cancel: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>) -> Self {
        self.gonio = self.gonio.with_cancel(cancel.clone());
        self.gonio_coarse = self.gonio_coarse.map(|g| g.with_cancel(cancel.clone()));
        self.cancel = cancel;
        self
    }

    /// Splits the photon batches of every simulation (each objective evaluation) across the
    /// processes of `comm` ([`Gonio::with_comm`]): every rank gets the one-process result bit
    /// for bit, so every rank runs the same fit. Every rank must make the same calls.
    pub fn with_comm(mut self, comm: Option<std::sync::Arc<dyn opal::dist::Comm>>) -> Self {
        self.gonio = self.gonio.with_comm(comm.clone());
        self.gonio_coarse = self.gonio_coarse.map(|g| g.with_comm(comm.clone()));
        self.comm = comm;
        self
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

    /// The plate with `model`'s face (rough, or dotted) as its rough face.
    pub fn plate_with_model(&self, model: &Model) -> opal::Result<Plate> {
        let mut p = self.setup.plate.clone();
        let f = model.face(self.setup.scattering)?;
        if self.setup.rough_front {
            p.front = f;
        } else {
            p.back = f;
        }
        Ok(p)
    }

    /// Simulates with `ndf` using `seed` and `photons` (the setup's for the objective).
    pub fn simulate(&self, ndf: Ndfs, seed: u64, photons: u64) -> opal::Result<GonioResult> {
        self.run(&self.plate_with(ndf), seed, photons)
    }

    /// Simulates `model` (its NDF, and its coverage for a dotted face) using `seed` and
    /// `photons`.
    pub fn simulate_model(&self, model: &Model, seed: u64, photons: u64) -> opal::Result<GonioResult> {
        self.run(&self.plate_with_model(model)?, seed, photons)
    }

    fn run(&self, plate: &Plate, seed: u64, photons: u64) -> opal::Result<GonioResult> {
        let coarse = self.gonio_coarse.as_ref().filter(|g| g.setup().photons == photons);
        {
            let mut e = self.evals.lock().expect("no panic while counting");
            if coarse.is_some() { e.0 += 1 } else { e.1 += 1 }
        }
        if seed == self.setup.seed {
            if photons == self.setup.photons {
                return self.gonio.run_plate(plate);
            }
            if let Some(g) = coarse {
                return g.run_plate(plate);
            }
        }
        let mut s = self.gonio.setup().clone();
        s.seed = seed;
        s.photons = photons;
        Gonio::new(s)?.with_cancel(self.cancel.clone()).with_comm(self.comm.clone()).run_plate(plate)
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

    /// Compares a simulation with the measurement (calibration factors already applied: see
    /// [`Problem::apply_scale`]).
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
        let scale_check = if self.setup.scale.mode == ScaleMode::Absolute {
            // the measurement's variance at the simulated value (a count's variance is
            // proportional to its value: σm² s/m): weights from the measured value itself are
            // larger where it fluctuated low, a bias of k of the order of the points' relative
            // variance (measured: +0.1 to +0.2 % of k on the ×0.8 and hybrid round trips)
            ScaleCheck::from_points(self.points.iter().map(|p| {
                let r = &res.incidences[p.inc];
                let s = r.value[p.det];
                let sm = if p.m > 0.0 && s > 0.0 { p.sm * (s / p.m).sqrt() } else { p.sm };
                (p.m, sm, s, r.value_stderr[p.det])
            }))
        } else {
            None
        };
        Evaluation {
            rms: (se / np).sqrt(),
            noise: (sn / np).sqrt(),
            chi2,
            per_incidence,
            points: self.points.len(),
            result: res,
            scale_check,
        }
    }

    /// The objective: `Σ ((s − m)² − σs²)/m / Σ m` over the used points, i.e. the squared
    /// relative residual `((s − m)/m)²` weighted by `m` (Pearson's χ² form). The weight is the
    /// inverse of the relative variance of a photon-count estimate (`Var s ∝ s`), so the
    /// dim, photon-starved points do not dominate the objective's noise; subtracting the
    /// simulation's own variance σs² makes it an unbiased estimate of the misfit of the
    /// *expected* simulation (plus a constant): without it the Monte-Carlo variance, which
    /// grows with the simulated value, pulls α towards dimmer lobes.
    ///
    /// With calibration factors ([`ScaleMode`]) s and σs are the simulated value and error
    /// times the point's factor, each factor the closed-form best one for this simulation
    /// (returned beside the objective), plus the prior's penalty when there is one.
    ///
    /// A dotted model (coverage fitted) uses the noise-weighted form instead, see
    /// [`Problem::objective_chi2`].
    fn objective(&self, model: &Model, stage: Stage) -> opal::Result<(f64, ScaleFit)> {
        let res = self.simulate_model(model, self.setup.seed, self.stage_photons(stage))?;
        if model.coverage.is_some() && self.groups.is_empty() {
            return Ok((self.objective_chi2(&res), ScaleFit::none()));
        }
        Ok(self.objective_of(&res))
    }

    /// Noise-weighted objective (a Gaussian log-likelihood of the measured values given their
    /// standard errors): `Σ ((s − m)² − σs²)/σm² / N` over the used points, with σm the
    /// measured standard error (floored at 10⁻³ m so exact data do not divide by zero). Every
    /// point counts by its own precision, so a specular spike and a lobe 100× dimmer both
    /// weigh in (the Pearson form weights by m and ignores the lobe); subtracting σs² removes
    /// the simulation's noise bias as in the Pearson form.
    fn objective_chi2(&self, res: &GonioResult) -> f64 {
        let mut acc = 0.0;
        for p in &self.points {
            let r = &res.incidences[p.inc];
            let (s, ss) = (r.value[p.det], r.value_stderr[p.det]);
            let sm = p.sm.max(1e-3 * p.m);
            acc += ((s - p.m).powi(2) - ss * ss) / (sm * sm);
        }
        acc / self.points.len() as f64
    }

    /// The objective of simulation `res` and its calibration factors (see `objective`).
    fn objective_of(&self, res: &GonioResult) -> (f64, ScaleFit) {
        let fit = self.fit_scale(res);
        let (mut acc, mut wsum) = (0.0, 0.0);
        for p in &self.points {
            let r = &res.incidences[p.inc];
            let k = Self::factor(&fit, p.group);
            let (s, ss) = (k * r.value[p.det], k * r.value_stderr[p.det]);
            acc += ((s - p.m).powi(2) - ss * ss) / p.m;
            if p.group.is_some() {
                // the 1/m weight's bias (see `scale`): without it the factors come out low by
                // the mean relative variance of the measured points
                acc -= 2.0 * (s - p.m) * (p.sm / p.m).powi(2);
            }
            wsum += p.m;
        }
        if fit.penalty > 0.0 {
            acc += fit.penalty;
        }
        (acc / wsum, fit)
    }

    /// The natural unit of the objective at a simulation: Σ (σs² + σm²)/m / Σ m (the
    /// objective's value when every residual is one standard error; σs times the point's
    /// best factor), or for a dotted model (`dotted`, absolute values) the noise-weighted
    /// form's, `Σ (σs² + σm²)/σm² / N`.
    pub(super) fn objective_noise_for(&self, res: &GonioResult, dotted: bool) -> f64 {
        if dotted && self.groups.is_empty() {
            let mut acc = 0.0;
            for p in &self.points {
                let ss = res.incidences[p.inc].value_stderr[p.det];
                let sm = p.sm.max(1e-3 * p.m);
                acc += (ss * ss + sm * sm) / (sm * sm);
            }
            return acc / self.points.len() as f64;
        }
        let fit = self.fit_scale(res);
        let (mut acc, mut wsum) = (0.0, 0.0);
        for p in &self.points {
            let ss = Self::factor(&fit, p.group) * res.incidences[p.inc].value_stderr[p.det];
            acc += (ss * ss + p.sm * p.sm) / p.m;
            wsum += p.m;
        }
        acc / wsum
    }

    /// Re-simulates `model` with the independent check seed at full photons (with calibration
    /// factors: the best ones for this simulation).
    pub fn check(&self, model: &Model) -> opal::Result<Evaluation> {
        let res = self.simulate_model(model, check_seed(self.setup.seed), self.setup.photons)?;
        let fit = self.fit_scale(&res);
        Ok(self.evaluate(self.apply_scale(res, &fit)))
    }

    /// Re-simulates a fitted model with the independent check seed at full photons, its
    /// simulated values times the factors found by the fit (`fit.scale`).
    pub fn check_fit(&self, fit: &FamilyFit) -> opal::Result<Evaluation> {
        let res = self.simulate_model(&fit.model, check_seed(self.setup.seed), self.setup.photons)?;
        Ok(self.evaluate(self.apply_scale(res, &fit.scale)))
    }
}

/// The independent seed of the quality check and of model selection.
pub fn check_seed(seed: u64) -> u64 {
    seed.wrapping_add(0x9E37_79B9)
}

#[cfg(test)]
mod hemisphere_tests;
#[cfg(test)]
mod tests;
