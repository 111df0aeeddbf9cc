//! Serialisable outcomes of the checker ([`CheckReport`]) and of the fitter ([`FitReport`]).
//!
//! Tests: `tests.rs`; the CLI's `opal brdf` tests check their JSON form.

use serde::Serialize;

/// Where the maximum is.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct Argmax {
    /// Parameter value.
    pub param: f64,
    /// Incidence angle, degrees.
    pub incidence_deg: f64,
}

/// A parameter range where `R > 1 + tolerance`.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct Violation {
    /// Lower end (parameter).
    pub from: f64,
    /// Upper end (parameter).
    pub to: f64,
    /// Largest R inside.
    pub max_reflectance: f64,
}

/// One point of the `R(param)` curve.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct CurvePoint {
    /// Parameter value.
    pub param: f64,
    /// max over incidence of R.
    pub max_reflectance: f64,
    /// Incidence of that maximum, degrees.
    pub incidence_deg: f64,
    /// R at the lowest incidence of the range (normal incidence by default).
    pub reflectance_first_incidence: f64,
}

/// Quadrature vs Monte Carlo at one point.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct McCheck {
    /// Parameter value.
    pub param: f64,
    /// Incidence, degrees.
    pub incidence_deg: f64,
    /// Quadrature R.
    pub quadrature: f64,
    /// Monte Carlo R.
    pub monte_carlo: f64,
    /// Its standard error.
    pub std_error: f64,
    /// (MC − quadrature) / std error.
    pub z: f64,
}

/// Outcome of [`check`](super::check).
#[derive(Clone, Debug, Serialize)]
pub struct CheckReport {
    /// Model label (name and normalisation).
    pub model: String,
    /// Name of the swept parameter.
    pub param_name: String,
    /// Swept range.
    pub range: (f64, f64),
    /// Incidence range, degrees.
    pub incidence_deg: (f64, f64),
    /// Largest R found.
    pub max_reflectance: f64,
    /// Where.
    pub argmax: Argmax,
    /// Largest relative reciprocity error over the sweep.
    pub reciprocity_error: f64,
    /// Ranges with `R > 1 + tolerance`.
    pub violations: Vec<Violation>,
    /// The tolerance used.
    pub tolerance: f64,
    /// `R_max(param)` on the grid (plus refined points), sorted by parameter.
    pub curve: Vec<CurvePoint>,
    /// Monte Carlo cross-checks.
    pub monte_carlo: Vec<McCheck>,
    /// Whether every MC cross-check agrees within 4 standard errors (or 1e-4 absolute).
    pub monte_carlo_consistent: bool,
    /// `max_reflectance ≤ 1 + tolerance`.
    pub energy_conserving: bool,
}

/// A pair of constants and what they give.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct FittedConstants {
    /// Constant `A`.
    #[serde(rename = "A")]
    pub a: f64,
    /// Constant `B`.
    #[serde(rename = "B")]
    pub b: f64,
    /// Largest `R` over the exponent range (continuous, refined) and incidence.
    pub max_reflectance: f64,
    /// Exponent of that maximum.
    pub argmax_param: f64,
    /// RMS of `c(n)·R₀(n) − 1` over the samples.
    pub rms_residual: f64,
}

/// Outcome of [`fit_norm`](super::fit_norm).
#[derive(Clone, Debug, Serialize)]
pub struct FitReport {
    /// Model label.
    pub model: String,
    /// The normalisation form.
    pub form: String,
    /// Exponent range.
    pub range: (f64, f64),
    /// Number of exponent samples.
    pub samples: usize,
    /// Least-squares constants (`c(n)·R₀(n) ≈ 1` in the mean-square sense).
    pub least_squares: FittedConstants,
    /// Tightest constants with `max R ≤ 1` (least squares under that constraint).
    pub bounded: FittedConstants,
}
