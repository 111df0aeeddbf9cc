//! Validation tools — product code, used by the tests and by `opal brdf check`.
//!
//! * [`chi2`]: χ² goodness-of-fit of a direction sampler against its pdf (Mitsuba's method:
//!   equal-solid-angle cells, pdf integrated over each cell, pooling of cells with expected
//!   count < 5, Šidák correction for multiple tests, heat maps dumped on failure).
//! * [`quadrature`]: deterministic integration over the sphere / hemisphere (Gauss–Legendre in
//!   cos θ × uniform in φ), used for albedo, furnace and normalisation checks.

pub mod chi2;
pub mod quadrature;
