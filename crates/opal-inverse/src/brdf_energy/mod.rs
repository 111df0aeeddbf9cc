//! Method B: energy and reciprocity checks of BRDF models, and fitting of normalisation factors.
//!
//! * [`reflectance`]: directional–hemispherical reflectance `R(θi) = ∫ f(wo, wi) cos θ_wi dω`
//!   of any [`Bxdf`] by deterministic quadrature (the paper's `R(L)`; `wo` plays `L`, so the
//!   quantity is "how much of the light arriving from `wo` leaves the surface"; for reciprocal
//!   BRDFs the two readings coincide).
//! * [`reflectance_mc`]: the same by Monte Carlo with the model's own importance sampling —
//!   the independent cross-check (it exercises `sample` and `pdf`, the quadrature only `eval`).
//! * [`reciprocity_error`]: `max |f(a,b) − f(b,a)| / max(f)` over fixed direction pairs.
//! * [`check`]: sweeps a model's parameter and the incidence angle, finds `max R`, its argmax,
//!   the parameter ranges where `R > 1 + tolerance`, and the curve `R_max(param)` for plots.
//! * [`fit_norm`]: fits the constants of a normalisation expression `c(n; A, B)`: the least-squares
//!   fit of `c(n)·R₀(n) ≈ 1` (the paper's curve fit) and the tightest constants with
//!   `max R ≤ 1` over the range.
//!
//! ## Quadrature
//! Directions are parametrised around the mirror direction `r` of `wo` (where every specular
//! lobe peaks): polar angle `α ∈ [0, π/2 + θi]` on Gauss–Legendre panels graded geometrically
//! from `1e-3` rad (so lobes as narrow as n ≈ 10⁶ are resolved), with extra panel edges at the
//! kinks `α = π/2 − θi` (the cone starts crossing the horizon) and `α = π/2`; azimuth on
//! Gauss–Legendre nodes over exactly the part above the horizon, `|φ| < acos(−cot α cot θi)`,
//! using the mirror symmetry `φ → −φ` of isotropic models. No node straddles the horizon, so
//! the discontinuity there costs no accuracy. Accuracy (tests): Lambert `R = ρ` to 1e-7,
//! normalised Phong `R(0) = 1` to 1e-6, and agreement with the paper's one-dimensional integral
//! to better than 1e-6.
//!
//! Tests: `tests.rs` (table of the method page, Lambert albedo, MC vs quadrature, reciprocity,
//! violations of the paper's constants, fit round trip).
//!
//! Layout: `reflectance.rs` (quadrature, Monte Carlo and the paper's 1-D integral),
//! `reciprocity.rs`, `sweep.rs` (grids and maxima over incidence, shared by the checker and the
//! fitter), `check.rs` (the checker), `fit.rs` (the normalisation fitter), `report.rs` (the
//! serialisable outcomes), `tests.rs`.
//!
//! [`Bxdf`]: opal::bsdf::Bxdf

mod check;
mod fit;
mod reciprocity;
mod reflectance;
mod report;
mod sweep;

pub use check::{CheckConfig, check};
pub use fit::{FitConfig, fit_norm};
pub use reciprocity::reciprocity_error;
pub use reflectance::{Quadrature, pow16_paper_integral, reflectance, reflectance_mc};
pub use report::{Argmax, CheckReport, CurvePoint, FitReport, FittedConstants, McCheck, Violation};
pub use sweep::{grid, max_over_incidence};

use opal::Spectrum;

/// Errors of the checker and fitter (bad input or a fit that cannot be done).
#[derive(Debug, thiserror::Error)]
pub enum EnergyError {
    /// A model could not be built / a value is invalid.
    #[error(transparent)]
    Engine(#[from] opal::Error),
    /// A fit could not be carried out.
    #[error("fit failed: {0}")]
    Fit(String),
}

/// Result alias.
pub type Result<T> = std::result::Result<T, EnergyError>;

pub(super) fn invalid(what: impl Into<String>, why: impl Into<String>) -> EnergyError {
    EnergyError::Engine(opal::Error::invalid(what, why))
}

pub(super) fn scalar(s: Spectrum) -> f64 {
    s.max_component() as f64
}

#[cfg(test)]
mod tests;
