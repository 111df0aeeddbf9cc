//! The grid of a tabulated BSDF: [`TableGrid`] (incidence rows, the warped half-vector cells
//! (u, v) and their Jacobian), its validation, and the mapping between the outgoing direction
//! `wi` and the generalised half vector `wm` that indexes the cells (conventions in the module
//! docs, `bsdf/tabulated/mod.rs`). Covered by the tests in `tabulated/tests.rs`.

use crate::math::{Vec3, reflect, refract};
use std::f32::consts::PI;

/// Grid of a table.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TableGrid {
    /// Incidence rows per side (θo at `(k + ½)·90°/n_theta_o`).
    pub n_theta_o: usize,
    /// Cells along the warped polar angle of the half vector.
    pub n_u: usize,
    /// Cells along the relative azimuth of the half vector, over [0, π].
    pub n_v: usize,
    /// Polar warp β (larger: finer near the lobe centre).
    pub beta: f32,
}

impl Default for TableGrid {
    /// 45 rows (2°), 96 × 48 cells, β = 12: 3.2 MB, resolves α ≈ 0.05…1.
    fn default() -> Self {
        TableGrid { n_theta_o: 45, n_u: 96, n_v: 48, beta: 12.0 }
    }
}

impl TableGrid {
    pub(super) fn cells_per_row(&self) -> usize {
        2 * self.n_u * self.n_v
    }
    pub(super) fn len(&self) -> usize {
        2 * self.n_theta_o * self.cells_per_row()
    }
    pub(super) fn a(&self) -> f32 {
        1.0 / (self.beta.exp() - 1.0)
    }
}

/// Outgoing direction for micro-normal `wm` (z > 0) and lobe; `None` when invalid.
#[inline]
pub(super) fn wi_from_wm(wo: Vec3, wm: Vec3, transmit: bool, eta: f32) -> Option<Vec3> {
    let cos_om = wo.dot(wm);
    if cos_om * wo.z <= 0.0 {
        return None;
    }
    let wi = if !transmit {
        let wi = reflect(wo, wm);
        if wi.z * wo.z <= 0.0 {
            return None;
        }
        wi
    } else {
        let (n, e) = if cos_om > 0.0 { (wm, eta) } else { (-wm, 1.0 / eta) };
        let wi = refract(wo, n, e)?;
        if wi.z * wo.z >= 0.0 {
            return None;
        }
        wi
    };
    if wi.dot(wm) * wi.z <= 0.0 || wi.z == 0.0 {
        return None;
    }
    Some(wi)
}

/// Generalised half vector (z > 0), η' (1 for reflection), and whether it is a transmission.
#[inline]
pub(super) fn half_vector(wo: Vec3, wi: Vec3, eta: f32) -> Option<(Vec3, f32, bool)> {
    crate::bsdf::rough_dielectric::half_vector(wo, wi, eta).map(|(wm, etap, reflect)| (wm, etap, !reflect))
}

/// |dωm/dωi| for the pair.
#[inline]
pub(super) fn dwm_dwi(wo: Vec3, wi: Vec3, wm: Vec3, etap: f32, transmit: bool) -> f32 {
    if !transmit {
        1.0 / (4.0 * wo.dot(wm).abs())
    } else {
        let den = wi.dot(wm) + wo.dot(wm) / etap;
        wi.dot(wm).abs() / (den * den)
    }
}

impl TableGrid {
    /// (u, v) of `wm` in the frame where `wo` has azimuth 0.
    #[inline]
    pub(super) fn uv_of(&self, wo: Vec3, wm: Vec3) -> (f32, f32) {
        let s2 = wm.x * wm.x + wm.y * wm.y;
        let w = s2 / (1.0 + wm.z); // 1 − cos θm without cancellation
        let u = (1.0 + w / self.a()).ln() / self.beta;
        let so = (wo.x * wo.x + wo.y * wo.y).sqrt();
        let (c, s) = if so > 0.0 { (wo.x / so, wo.y / so) } else { (1.0, 0.0) };
        let x = c * wm.x + s * wm.y;
        let y = -s * wm.x + c * wm.y;
        let v = if s2 > 0.0 { y.atan2(x).abs() / PI } else { 0.0 };
        (u.clamp(0.0, 1.0), v.clamp(0.0, 1.0))
    }

    /// Micro-normal of (u, v) and mirror sign, in the frame where `wo` has azimuth 0, rotated
    /// back to the frame of `wo`.
    #[inline]
    pub(super) fn wm_of(&self, wo: Vec3, u: f32, v: f32, sign: f32) -> Vec3 {
        let w = (self.a() * ((self.beta * u).exp() - 1.0)).min(1.0);
        let cz = 1.0 - w;
        let st = (w * (2.0 - w)).max(0.0).sqrt();
        let phi = sign * PI * v;
        let (x, y) = (st * phi.cos(), st * phi.sin());
        let so = (wo.x * wo.x + wo.y * wo.y).sqrt();
        let (c, s) = if so > 0.0 { (wo.x / so, wo.y / so) } else { (1.0, 0.0) };
        Vec3::new(c * x - s * y, s * x + c * y, cz)
    }

    /// Solid angle of the mirrored cell pair per unit (u, v) area at `u`: 2π dw/du.
    #[inline]
    pub(super) fn jac(&self, u: f32) -> f32 {
        let a = self.a();
        2.0 * PI * self.beta * a * (self.beta * u).exp()
    }

    #[inline]
    pub(super) fn cell(&self, u: f32, v: f32) -> (usize, usize) {
        (
            ((u * self.n_u as f32) as usize).min(self.n_u - 1),
            ((v * self.n_v as f32) as usize).min(self.n_v - 1),
        )
    }

    /// Bracketing rows and the weight of the upper one for incidence |cos θo|.
    #[inline]
    pub(super) fn rows(&self, cos_o: f32) -> (usize, usize, f32) {
        let th = cos_o.clamp(0.0, 1.0).acos();
        let x = th / (0.5 * PI) * self.n_theta_o as f32 - 0.5;
        if x <= 0.0 {
            return (0, 0, 0.0);
        }
        let i = x.floor() as usize;
        if i + 1 >= self.n_theta_o {
            return (self.n_theta_o - 1, self.n_theta_o - 1, 0.0);
        }
        (i, i + 1, x - i as f32)
    }

    pub(super) fn theta_o(&self, row: usize) -> f32 {
        (row as f32 + 0.5) / self.n_theta_o as f32 * 0.5 * PI
    }
}

pub(super) fn validate_grid(g: &TableGrid, eta: f32) -> std::result::Result<(), (String, String)> {
    if !(eta.is_finite() && eta > 0.0) || (eta - 1.0).abs() < 1e-4 {
        return Err(("eta".into(), format!("must be > 0 and ≠ 1, got {eta}")));
    }
    for (name, n, lo, hi) in
        [("n_theta_o", g.n_theta_o, 2, 1024), ("n_u", g.n_u, 2, 4096), ("n_v", g.n_v, 1, 4096)]
    {
        if !(lo..=hi).contains(&n) {
            return Err((name.into(), format!("must be in [{lo}, {hi}], got {n}")));
        }
    }
    if 2 * g.n_theta_o * 2 * g.n_u * g.n_v > 1 << 28 {
        return Err(("n_theta_o·n_u·n_v".into(), "table larger than 1 GiB".into()));
    }
    if !(g.beta.is_finite() && g.beta > 0.0 && g.beta <= 40.0) {
        return Err(("beta".into(), format!("must be in (0, 40], got {}", g.beta)));
    }
    Ok(())
}
