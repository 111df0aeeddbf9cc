//! Joint Gauss–Newton step over the poses of all views ([`JointRows`], [`joint_step`]): the
//! per-view alignments of a round treat the leave-one-out maps as fixed, but each map is the
//! mean of the other views' photos projected at *their* poses. Along the modes in which the
//! views move consistently (their textures shift alike), each alignment is pulled back by the
//! others' textures and only the geometric edges move it, by a small fraction per round: the
//! views keep drifting along such modes round after round. The joint step linearises the
//! prediction in the other views' poses as well and solves all poses together.
//!
//! Model: pixel `p` of view `k` (blurred at σ, its hit `X` at `k`'s aligned pose) has the
//! residual `r = Y_k(p) − s_k · P_k(p)`, `P_k(p) ≈ (1/m) Σ_j Y_j(π_j(X))` over the `m` other views
//! `j` that see `X` on a pure pixel of the same shape at the depth of `X` (the views whose
//! pixels fed the map there). Its Jacobian: `∇Y_k · ∂π_k/∂θ_k` for view `k`'s own pose and
//! `−(s_k/m) ∇Y_j · ∂π_j/∂θ_j` for each such `j` (camera-frame steps, [`super::compose`]). Pixels
//! whose prediction no other view fed (inpainted bands at geometric edges, emitters) keep only
//! their own term: they are what pins the modes the textures cannot see. The maps were built at
//! the round's start poses; the residual is linearised about them (the moves of the other views
//! since the start enter as an offset), and the step solved with Huber weights (per view, scale
//! 1.4826 × median |r|) and a light Levenberg damping.
//!
//! Tests: `tests.rs` (`six_perturbed_views_refined_against_each_other`, `exact_views_stay`).

use super::render::{Prediction, blur};
use super::solve::{Level, huber, projection_jacobian};
use crate::delight::views::{MIXED, PureBuffer};
use opal::camera::Camera;
use opal::math::{DMat4, DVec3};
use opal::scene::Scene;
use rayon::prelude::*;

/// One residual of [`JointRows`]: value, Jacobian in the own pose, Jacobians in other views'
/// poses (view index, 6 columns, the factor `−s/m` included).
type Row = (f64, [f64; 6], Vec<(usize, [f64; 6])>);

/// What another view contributes to the cross terms: its camera at the round's start, its
/// blurred photo, its eroded pure buffer and the distance of its pixels' centre hits.
pub(super) struct Other<'a> {
    /// View index.
    pub(super) j: usize,
    /// Camera at the start of the round (the pose its map contribution was made at).
    pub(super) cam: &'a Camera,
    /// Blurred photo luminance.
    pub(super) level: &'a Level,
    /// Eroded pure buffer at that pose.
    pub(super) pure: &'a PureBuffer,
    /// Distance of each pixel's centre hit (NaN: none).
    pub(super) depth: &'a [f32],
}

/// The rows of one view for the joint step.
pub(super) struct JointRows {
    /// View index.
    pub(super) k: usize,
    /// Rows.
    rows: Vec<Row>,
}

/// Distance from the camera to each pixel's centre hit (NaN: none).
pub(super) fn depth_buffer(scene: &Scene, cam: &Camera) -> Vec<f32> {
    let (w, h) = (cam.width, cam.height);
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            let c = opal::math::Vec2::new((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
            scene.intersect(&cam.generate_ray(c)).map_or(f32::NAN, |si| (si.p - cam.origin()).length())
        })
        .collect()
}

/// Bilinear central-difference gradient of `lv` at film position `q` (pixel centres at +0.5).
fn grad_at(lv: &Level, qx: f64, qy: f64) -> Option<(f64, f64)> {
    let (x, y) = (qx - 0.5, qy - 0.5);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (mut gx, mut gy) = (0.0, 0.0);
    for (dx, dy, w) in
        [(0, 0, (1.0 - fx) * (1.0 - fy)), (1, 0, fx * (1.0 - fy)), (0, 1, (1.0 - fx) * fy), (1, 1, fx * fy)]
    {
        let (a, b) = lv.grad(x0 as i64 + dx, y0 as i64 + dy)?;
        gx += w * a;
        gy += w * b;
    }
    Some((gx, gy))
}

/// The rows of view `k` at camera `cam` (its aligned pose): blurred photo `lv`, prediction
/// `pr` rendered at `cam` (from the leave-one-out maps of the round), fitted scale `s`, blur
/// `sigma`; cross terms from `others`.
pub(super) fn view_rows(
    k: usize,
    cam: &Camera,
    lv: &Level,
    pr: &Prediction,
    s: f64,
    sigma: f64,
    others: &[Other],
) -> JointRows {
    let (w, h) = (cam.width, cam.height);
    let (pb, sup) = blur(&pr.p, w, h, sigma);
    let to_cam = cam.to_world.as_dmat4().inverse();
    let (tx, ty) = (cam.tan_half_x as f64, cam.tan_half_y as f64);
    let rows: Vec<Row> = (0..w * h)
        .into_par_iter()
        .filter_map(|i| {
            let (p, xw) = (pb[i], pr.hits[i]?);
            let (yv, own, _) = lv.pixel_row(i, p, sup[i], xw, &to_cam, (tx, ty))?;
            let shape = pr.keys[i].map(|(sh, _)| sh);
            let mut cross = Vec::new();
            if !pr.mixed[i] {
                for o in others {
                    if let Some(c) = cross_term(o, xw, shape) {
                        cross.push((o.j, c));
                    }
                }
            }
            let m = cross.len() as f64;
            for (_, c) in &mut cross {
                for v in c.iter_mut() {
                    *v *= -s / m;
                }
            }
            Some((yv as f64 - s * p as f64, own, cross))
        })
        .collect();
    JointRows { k, rows }
}

/// `∇Y_j · ∂π_j/∂θ_j` at surface point `xw` when view `j` sees it on a pure pixel of `shape`.
fn cross_term(o: &Other, xw: DVec3, shape: Option<u32>) -> Option<[f64; 6]> {
    let cam = o.cam;
    let q = cam.project(xw.as_vec3())?;
    let (w, h) = (cam.width, cam.height);
    let (ix, iy) = (q.x as usize, q.y as usize);
    if ix >= w || iy >= h {
        return None;
    }
    let idx = iy * w + ix;
    let sh = o.pure.shape(idx);
    if sh == MIXED || Some(sh) != shape {
        return None;
    }
    let eye = cam.origin().as_dvec3();
    let d = (xw - eye).length();
    let dj = o.depth[idx] as f64;
    if !dj.is_finite() || (d - dj).abs() > 0.05 * dj {
        return None;
    }
    let (gx, gy) = grad_at(o.level, q.x as f64, q.y as f64)?;
    let qc = cam.to_world.as_dmat4().inverse().transform_point3(xw);
    let jp = projection_jacobian(qc, cam.tan_half_x as f64, cam.tan_half_y as f64, w as f64, h as f64);
    let mut c = [0.0; 6];
    for col in 0..6 {
        c[col] = gx * jp[0][col] + gy * jp[1][col];
    }
    Some(c)
}

/// The camera-frame move `(ω, δ)` (6-vector) from pose `a` to pose `b` (`b = compose(a, ω, δ)`).
pub(super) fn camera_frame_move(a: DMat4, b: DMat4) -> [f64; 6] {
    let rel = a.inverse() * b;
    let q = glam::DQuat::from_mat4(&rel);
    let (axis, mut ang) = q.to_axis_angle();
    if ang > std::f64::consts::PI {
        ang -= 2.0 * std::f64::consts::PI;
    }
    let w = axis * ang;
    let t = rel.w_axis.truncate();
    [w.x, w.y, w.z, t.x, t.y, t.z]
}

/// The joint step: per view (index into `views`), the camera-frame move `(ω, δ)` to apply to its
/// aligned pose, or `None` when the system is singular. `moved[j]`: view `j`'s move since the
/// round's start ([`camera_frame_move`]); `npar` 3 (rotation) or 6.
pub(super) fn joint_step(
    all: &[JointRows],
    moved: &[[f64; 6]],
    n_views: usize,
    npar: usize,
) -> Option<Vec<[f64; 6]>> {
    use nalgebra::{DMatrix, DVector};
    let n = n_views * npar;
    let mut hm = DMatrix::<f64>::zeros(n, n);
    let mut g = DVector::<f64>::zeros(n);
    for jr in all {
        // residuals linearised about the round's start poses of the other views
        let lin: Vec<f64> = jr
            .rows
            .par_iter()
            .map(|(r, _, cross)| {
                r + cross.iter().map(|(j, c)| (0..6).map(|a| c[a] * moved[*j][a]).sum::<f64>()).sum::<f64>()
            })
            .collect();
        if lin.is_empty() {
            continue;
        }
        let mut a: Vec<f64> = lin.iter().map(|r| r.abs()).collect();
        let mid = a.len() / 2;
        let c = 1.345 * 1.4826 * *a.select_nth_unstable_by(mid, f64::total_cmp).1;
        let c = c.max(1e-12);
        for ((_, own, cross), &r) in jr.rows.iter().zip(&lin) {
            let wgt = huber(r, c);
            // sparse row: (column, value)
            let mut ent: Vec<(usize, f64)> = Vec::with_capacity(npar * (1 + cross.len()));
            for (a, &v) in own.iter().enumerate().take(npar) {
                ent.push((jr.k * npar + a, v));
            }
            for (j, cj) in cross {
                for (a, &v) in cj.iter().enumerate().take(npar) {
                    ent.push((j * npar + a, v));
                }
            }
            for &(ia, va) in &ent {
                g[ia] += wgt * va * r;
                for &(ib, vb) in &ent {
                    hm[(ia, ib)] += wgt * va * vb;
                }
            }
        }
    }
    let trace: f64 = (0..n).map(|i| hm[(i, i)]).sum();
    if trace.is_nan() || trace <= 0.0 {
        return None;
    }
    for i in 0..n {
        hm[(i, i)] += 1e-3 * hm[(i, i)] + 1e-9 * trace;
    }
    let x = hm.cholesky()?.solve(&(-g));
    if x.iter().any(|v| !v.is_finite()) {
        return None;
    }
    Some(
        (0..n_views)
            .map(|k| {
                let mut d = [0.0; 6];
                d[..npar].copy_from_slice(&x.as_slice()[k * npar..(k + 1) * npar]);
                d
            })
            .collect(),
    )
}
