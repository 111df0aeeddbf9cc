//! Tabulated isotropic BSDF of a rough dielectric face, for both sides (light from the outside,
//! +z, and from the inside), reflection and transmission; built by integrating any source BSDF
//! (e.g. [`crate::bsdf::RoughDielectric`] with a fitted NDF) and stored in an `.obsdf` file
//! that Opal loads as a material (`<bsdf type="tabulated">`, format in `docs/formats.md`).
//!
//! # Parameterisation
//! Per side (wo.z > 0: side 0, wo.z < 0: side 1) and per incidence row (θo at the cell centres
//! `(k + ½)·90°/n_theta_o`), the outgoing direction `wi` is represented by the micro-facet
//! normal that connects it to `wo`: the generalised half vector `wm` (oriented to +z:
//! `wo + wi` for reflection, `wo + η'·wi` for transmission, η' = n(wi side)/n(wo side)). Its
//! polar angle is warped by `1 − cos θm = A·(e^{βu} − 1)`, `A = 1/(e^β − 1)`, `u ∈ [0, 1]`
//! (cells of roughly constant *relative* width β/(2 n_u) in θm near the pole, so a lobe of
//! α ≈ 0.05…1 is resolved by the same grid), and its azimuth relative to the plane of
//! incidence by `v = |φm − φo|/π ∈ [0, 1]` (isotropy: mirror symmetry). Both the specular
//! reflection and the refracted direction sit at `wm = +z`, so the grid is centred on both
//! lobes for every incidence.
//!
//! Stored per cell (side, row, lobe ∈ {R, T}, iu, iv): `Q` = the fraction of the incident
//! power scattered into the cell (both mirrored halves) per unit (u, v) area, i.e. the cell's
//! energy is `Q·Δu·Δv` and a row's albedo (R + T) is `Σ Q·Δu·Δv`. The source is integrated over
//! each cell with `s × s` midpoint sub-samples of
//! `f(wo, wi) |cos θi| |dωi/dωm| · 2π dw/du` (importance mode: power).
//!
//! # Evaluation and sampling
//! `eval` divides each cell value by the cell average of the *known* factor of the integrand,
//! `Fresnel(wo·wm)·|wo·wm|·2π dw/du` at the row's incidence (the rest, `D·G/|cos θo|`, is smooth
//! in θo and wm), interpolates that smooth part bilinearly over the cell centres in (u, v) and
//! linearly between the two bracketing θo rows, and multiplies by the exact known factor of the
//! actual `wo` — so the steep Fresnel change near the critical angle (light from inside) and the
//! facet-projection cut-off at grazing incidence are not interpolated. It then converts to a
//! BSDF value with the exact Jacobians (`dωm/dωi = 1/(4|wo·wm|)` for reflection,
//! `|wi·wm| / (wi·wm + wo·wm/η')²` for transmission) divided by `|cos θi|`; the radiance BTDF
//! is the importance one divided by η'² ([`TransportMode`](super::TransportMode)).
//! `sample` picks one of the two bracketing rows with the interpolation weight (using `uc`), a
//! cell from the row's marginal (over lobe × u) and conditional (over v) CDFs, the mirror half
//! with the rest of `uc`, and a uniform point in the cell; `pdf` is the same θo-interpolation of
//! the two rows' piecewise-constant normalised densities, so `sample` and `pdf` agree exactly
//! (`eval` is smoother than `pdf`, which only has to be proportional to it approximately). A
//! sample whose point maps to no valid direction (beyond a total-internal-reflection edge or
//! below the horizon inside a cell straddling it) fails (`None`).
//!
//! Accuracy (measured, `docs/formats.md`): the L1 error of the scattered power relative to the
//! lobe energy is 0.1–0.7 % below 80° incidence and ≤ 2.1 % at 88° (default grid, α = 0.1 and
//! 0.4, both sides); reciprocity holds up to that discretisation error (not enforced).
//!
//! Tests (`tests.rs`): χ² of `sample` vs `pdf` from both sides; eval vs the source BSDF (L1 error
//! relative to the lobe energy, off-grid incidences); albedo per incidence vs the source; the
//! file round trip; bad files (magic, header field, value, size) with errors naming file, field
//! and value.

mod build;
mod eval;
mod file;
mod grid;
#[cfg(test)]
mod tests;

pub use file::{Header, MAGIC, VERSION};
pub use grid::TableGrid;

use crate::math::Vec3;
use crate::sampling::Distribution1D;
use grid::validate_grid;
use rayon::prelude::*;
use std::sync::Arc;

#[derive(Debug)]
struct RowDist {
    marginal: Distribution1D,
    conditional: Vec<Option<Distribution1D>>,
    albedo: f32,
}

#[derive(Debug)]
struct Table {
    eta: f32,
    grid: TableGrid,
    q: Vec<f32>,
    /// 1 / (cell average of the known factor of the row's incidence × 2π dw/du), 0 where the
    /// factor is < 1e-4.
    inv_known: Vec<f32>,
    rows: Vec<Option<RowDist>>,
    source: String,
}

/// Tabulated rough-dielectric BSDF (cheap to clone: the table is shared).
#[derive(Clone, Debug)]
pub struct TabulatedBsdf {
    t: Arc<Table>,
}

impl TabulatedBsdf {
    fn from_data(
        eta: f32,
        grid: TableGrid,
        q: Vec<f32>,
        source: String,
    ) -> std::result::Result<Self, (String, String)> {
        validate_grid(&grid, eta)?;
        if q.len() != grid.len() {
            return Err(("data".into(), format!("{} values, expected {}", q.len(), grid.len())));
        }
        if let Some(k) = q.iter().position(|x| !(x.is_finite() && *x >= 0.0)) {
            return Err(("data".into(), format!("value {k} is {} (must be finite and ≥ 0)", q[k])));
        }
        let cpr = grid.cells_per_row();
        let cell_area = 1.0 / (grid.n_u * grid.n_v) as f64;
        let mut rows = Vec::with_capacity(2 * grid.n_theta_o);
        for (sr, row) in q.chunks(cpr).enumerate() {
            let albedo: f64 = row.iter().map(|&x| x as f64).sum::<f64>() * cell_area;
            // a lossless interface scatters at most all the power; allow 2 % of integration error
            if albedo > 1.02 {
                let (side, r) = (sr / grid.n_theta_o, sr % grid.n_theta_o);
                return Err((
                    "data".into(),
                    format!(
                        "side {side} row {r} (θo = {:.2}°) scatters {albedo:.4} of the incident power (> 1)",
                        grid.theta_o(r).to_degrees()
                    ),
                ));
            }
            let strips: Vec<f64> =
                row.chunks(grid.n_v).map(|s| s.iter().map(|&x| x as f64).sum::<f64>()).collect();
            let rd = Distribution1D::new(&strips).map(|marginal| RowDist {
                marginal,
                conditional: row
                    .chunks(grid.n_v)
                    .map(|s| Distribution1D::new(&s.iter().map(|&x| x as f64).collect::<Vec<_>>()))
                    .collect(),
                albedo: albedo as f32,
            });
            rows.push(rd);
        }
        let inv_known: Vec<f32> = (0..q.len())
            .into_par_iter()
            .map(|k| {
                let (sr, c) = (k / cpr, k % cpr);
                let (side, r) = (sr / grid.n_theta_o, sr % grid.n_theta_o);
                let (lobe, iu, iv) = (c / (grid.n_u * grid.n_v), (c / grid.n_v) % grid.n_u, c % grid.n_v);
                let th = grid.theta_o(r);
                let wo = Vec3::new(th.sin(), 0.0, if side == 0 { th.cos() } else { -th.cos() });
                // cell average of the known factor (4 × 4 midpoints): Q ≈ avg(factor)·smooth part
                let mut acc = 0.0f32;
                for a in 0..4 {
                    let u = (iu as f32 + (a as f32 + 0.5) / 4.0) / grid.n_u as f32;
                    let jac = grid.jac(u);
                    for b in 0..4 {
                        let v = (iv as f32 + (b as f32 + 0.5) / 4.0) / grid.n_v as f32;
                        acc += jac * Self::known_factor(wo, grid.wm_of(wo, u, v, 1.0), lobe == 1, eta);
                    }
                }
                let u = (iu as f32 + 0.5) / grid.n_u as f32;
                if acc / 16.0 > 1e-4 * grid.jac(u) { 16.0 / acc } else { 0.0 }
            })
            .collect();
        Ok(TabulatedBsdf { t: Arc::new(Table { eta, grid, q, inv_known, rows, source }) })
    }

    /// Relative index n_inside / n_outside.
    pub fn eta(&self) -> f32 {
        self.t.eta
    }

    /// The grid.
    pub fn grid(&self) -> TableGrid {
        self.t.grid
    }

    /// Albedo R + T (fraction of the incident power scattered) of the row bracketing `wo`,
    /// interpolated as `eval` is.
    pub fn albedo(&self, wo: Vec3) -> f32 {
        let g = &self.t.grid;
        let (i0, i1, t) = g.rows(wo.z.abs());
        let side = if wo.z > 0.0 { 0 } else { 1 };
        let al = |r: usize| self.t.rows[side * g.n_theta_o + r].as_ref().map_or(0.0, |d| d.albedo);
        (1.0 - t) * al(i0) + t * al(i1)
    }
}
