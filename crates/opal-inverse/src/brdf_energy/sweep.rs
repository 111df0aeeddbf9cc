//! Sweeps shared by the checker and the fitter: parameter / incidence grids, golden-section
//! refinement, the maximum of `R` over incidence and validation of the ranges.
//!
//! Tests: `tests.rs` (through [`check`](super::check) and [`fit_norm`](super::fit_norm)).

use super::{Quadrature, Result, invalid, reflectance};
use opal::bsdf::Bxdf;

/// Golden-section search for the maximum of `f` on `[a, b]` (unimodal near the bracket);
/// returns (argmax, max) including the end points.
pub(super) fn golden_max(f: &dyn Fn(f64) -> f64, mut a: f64, mut b: f64, tol: f64) -> (f64, f64) {
    let g = (5f64.sqrt() - 1.0) / 2.0;
    let (fa0, fb0, a0, b0) = (f(a), f(b), a, b);
    let mut c = b - g * (b - a);
    let mut d = a + g * (b - a);
    let (mut fc, mut fd) = (f(c), f(d));
    while (b - a).abs() > tol {
        if fc > fd {
            b = d;
            d = c;
            fd = fc;
            c = b - g * (b - a);
            fc = f(c);
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + g * (b - a);
            fd = f(d);
        }
    }
    let mut best = if fc > fd { (c, fc) } else { (d, fd) };
    if fa0 > best.1 {
        best = (a0, fa0);
    }
    if fb0 > best.1 {
        best = (b0, fb0);
    }
    best
}

/// Linear or logarithmic grid of `n ≥ 2` points on `[lo, hi]`.
pub fn grid(lo: f64, hi: f64, n: usize, log: bool) -> Vec<f64> {
    let n = n.max(2);
    (0..n)
        .map(|i| {
            let t = i as f64 / (n - 1) as f64;
            if log && lo > 0.0 { (lo.ln() + t * (hi.ln() - lo.ln())).exp() } else { lo + t * (hi - lo) }
        })
        .collect()
}

/// Maximum over incidence of `R(θ)` for one model: grid then golden-section refinement in the
/// bracket of the best grid point. Returns (R_max, θ at max in radians, R at the first grid angle).
pub fn max_over_incidence(b: &impl Bxdf, thetas: &[f64], q: &Quadrature) -> (f64, f64, f64) {
    let rs: Vec<f64> = thetas.iter().map(|&t| reflectance(b, t, q)).collect();
    let (i, _) = rs.iter().enumerate().fold((0, f64::MIN), |m, (i, &r)| if r > m.1 { (i, r) } else { m });
    if thetas.len() < 2 {
        return (rs[0], thetas[0], rs[0]);
    }
    // best at an end of the range and R falling towards the neighbour's midpoint: the end is
    // the maximum (saves the golden-section search in the common normal-incidence case)
    if i == 0 || i == thetas.len() - 1 {
        let j = if i == 0 { 1 } else { i - 1 };
        let m = 0.5 * (thetas[i] + thetas[j]);
        if reflectance(b, m, q) <= rs[i] {
            return (rs[i], thetas[i], rs[0]);
        }
    }
    let lo = thetas[i.saturating_sub(1)];
    let hi = thetas[(i + 1).min(thetas.len() - 1)];
    let (t, r) = golden_max(&|t| reflectance(b, t, q), lo, hi, 1e-4);
    // prefer the grid point unless the refinement found a clearly larger value (R is flat at
    // its maximum; differences of 1e-12 are rounding)
    if r > rs[i] * (1.0 + 1e-12) { (r, t, rs[0]) } else { (rs[i], thetas[i], rs[0]) }
}

pub(super) fn validate_ranges(range: (f64, f64), inc: (f64, f64)) -> Result<()> {
    let (lo, hi) = range;
    if !(lo.is_finite() && hi.is_finite()) || lo >= hi {
        return Err(invalid(
            "parameter range",
            format!("must be a non-empty increasing range lo:hi, got {lo}:{hi}"),
        ));
    }
    let (a, b) = inc;
    if !(a.is_finite() && b.is_finite()) || a > b || a < 0.0 || b >= 90.0 {
        return Err(invalid(
            "incidence range (degrees)",
            format!("must satisfy 0 ≤ from ≤ to < 90, got {a}:{b}"),
        ));
    }
    Ok(())
}

pub(super) fn incidence_grid(inc: (f64, f64), n: usize) -> Vec<f64> {
    if inc.1 - inc.0 < 1e-9 {
        vec![inc.0.to_radians()]
    } else {
        grid(inc.0, inc.1, n, false).into_iter().map(f64::to_radians).collect()
    }
}
