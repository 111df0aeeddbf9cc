//! The geometric-edge normal equations of one view ([`edge_system`]): the part of the
//! alignment residual that only the geometry (changes of shape or plane) constrains, used for
//! the common motion of all views (`super::common_motion`).
//!
//! Tests: `tests.rs` (`common_motion_of_all_views_recovered`).

use super::render::{Prediction, SurfaceKey, blur};
use super::solve::{Level, huber, projection_jacobian};
use opal::camera::Camera;
use rayon::prelude::*;

/// Gauss–Newton normal equations of the *geometric edges* of one view (camera frame: rotation
/// vector, translation; residuals relative to the mean prediction). See [`edge_system`].
#[derive(Clone, Debug)]
pub struct EdgeSystem {
    /// `Σ w eᵀe` (6 × 6).
    pub h: [[f64; 6]; 6],
    /// `Σ w r eᵀ`.
    pub g: [f64; 6],
    /// Pixels with a geometric edge in their blur window.
    pub pixels: usize,
}

/// Gradient of `p` (NaN = undefined) from neighbours on the same surface only (central
/// difference, one-sided where one neighbour is on another surface; NaN where none is, and at
/// the `mixed` pixels, which see two).
fn within_surface_gradient(
    p: &[f32],
    keys: &[SurfaceKey],
    mixed: &[bool],
    w: usize,
    h: usize,
) -> (Vec<f32>, Vec<f32>) {
    let same = |i: usize, j: usize| match (keys[i], keys[j]) {
        (Some((a, na)), Some((b, nb))) => a == b && na.dot(nb) > 0.999 && p[j].is_finite() && !mixed[j],
        _ => false,
    };
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            if !p[i].is_finite() || mixed[i] {
                return (f32::NAN, f32::NAN);
            }
            let (x, y) = (i % w, i / w);
            let d = |lo: Option<usize>, hi: Option<usize>| {
                let lo = lo.filter(|&j| same(i, j));
                let hi = hi.filter(|&j| same(i, j));
                match (lo, hi) {
                    (Some(l), Some(r)) => 0.5 * (p[r] - p[l]),
                    (Some(l), None) => p[i] - p[l],
                    (None, Some(r)) => p[r] - p[i],
                    (None, None) => f32::NAN,
                }
            };
            let gx = d((x > 0).then(|| i - 1), (x + 1 < w).then_some(i + 1));
            let gy = d((y > 0).then(|| i - w), (y + 1 < h).then_some(i + w));
            (gx, gy)
        })
        .unzip()
}

/// Normal equations of the residual of view `cam` (its prediction `pr`, blurred photo `lv` at
/// `sigma`, scale `s`)
/// for a motion under which the *textures* of the prediction move with the view and only its
/// geometric edges (changes of shape or plane) stay: the Jacobian of a pixel is
/// `s · ∇P_edge · ∂p/∂θ`, with `∇P_edge` the gradient of the blurred prediction minus the blur
/// of its gradient within each surface. This is the motion of all views together (their
/// textures shift alike), which only the geometry constrains.
pub(super) fn edge_system(lv: &Level, cam: &Camera, pr: &Prediction, sigma: f64, scale: f64) -> EdgeSystem {
    let (w, h) = (lv.w, lv.h);
    let Prediction { p, hits, keys, mixed } = pr;
    let (pb, sup) = blur(p, w, h, sigma);
    let (gx0, gy0) = within_surface_gradient(p, keys, mixed, w, h);
    let (gxt, gyt) = (blur(&gx0, w, h, sigma).0, blur(&gy0, w, h, sigma).0);
    let pl = Level { w, h, y: pb };
    let to_cam = cam.to_world.as_dmat4().inverse();
    let (tx, ty) = (cam.tan_half_x as f64, cam.tan_half_y as f64);
    let rows: Vec<(f64, [f64; 6], f64, bool)> = (0..w * h)
        .into_par_iter()
        .filter_map(|i| {
            let (pv, xw) = (pl.y[i], hits[i]?);
            if !pv.is_finite() || sup[i] < 0.99 {
                return None;
            }
            let (x, y) = ((i % w) as i64, (i / w) as i64);
            let yv = lv.at(x, y);
            if !yv.is_finite() {
                return None;
            }
            let (px, py) = pl.grad(x, y)?;
            let t = |g: f32| if g.is_finite() { g as f64 } else { 0.0 };
            let (ex, ey) = (px - t(gxt[i]), py - t(gyt[i]));
            let q = to_cam.transform_point3(xw);
            if q.z <= 0.0 {
                return None;
            }
            let jp = projection_jacobian(q, tx, ty, w as f64, h as f64);
            let mut e = [0.0; 6];
            for c in 0..6 {
                e[c] = scale * (ex * jp[0][c] + ey * jp[1][c]);
            }
            let edge = ex.hypot(ey) > 1e-3 * (pv as f64).abs();
            Some((yv as f64 - scale * pv as f64, e, pv as f64, edge))
        })
        .collect();
    let mut out = EdgeSystem { h: [[0.0; 6]; 6], g: [0.0; 6], pixels: 0 };
    if rows.is_empty() {
        return out;
    }
    let mean = rows.iter().map(|r| r.2).sum::<f64>() / rows.len() as f64;
    // Huber scale from all pixels, as in the alignment (from the edge pixels alone, the exact
    // views of the synthetic room drifted by 0.03°: the predictions extended over the edge
    // bands carry errors of their own there)
    let mut a: Vec<f64> = rows.iter().map(|r| r.0.abs()).collect();
    let k = a.len() / 2;
    let c = 1.345 * 1.4826 * *a.select_nth_unstable_by(k, f64::total_cmp).1;
    let norm = 1.0 / (mean * mean).max(1e-60);
    for (r, e, _, edge) in &rows {
        let wgt = huber(*r, c.max(1e-12)) * norm;
        for a in 0..6 {
            out.g[a] += wgt * e[a] * r;
            for b in 0..6 {
                out.h[a][b] += wgt * e[a] * e[b];
            }
        }
        out.pixels += *edge as usize;
    }
    out
}
