//! Direct photometric alignment of one view ([`align_view`]): Levenberg–Marquardt on the
//! luminance residual between the photo and the image the model predicts from the current pose,
//! coarse to fine over Gaussian blurs of both images.
//!
//! Model: at pose `θ` the model predicts an image `P_θ` (one ray per pixel centre; the
//! prediction of the hit from the caller, or none: emitters, unrecovered shapes, unseen
//! texels). Residual per pixel `p` of the blurred images:
//! `r_p(Δ) = Y_σ(π_{θ⊕Δ}(X_p)) − s · P_σ(p)`, with `X_p` the surface point the pixel's centre
//! ray hits at `θ` (so `π_θ(X_p) = p`), `Δ = (ω, δ)` a rotation vector and a translation in the
//! camera's frame (`to_world ← to_world · [R(ω) | δ]`) and `s` a free scale (the exposure of the
//! photo against the prediction). The Jacobian is the photo's gradient times the projection's
//! derivative; each step tried renders `P` at its pose (the occlusion edges move with it), and
//! the render of the accepted one serves the next iteration, the next level and the edge system
//! (each pose is rendered once). A level stops when a step, accepted or rejected, moves the
//! image by less than [`AlignSettings::step_tolerance_px`] (scaled by the level's blur over the
//! finest one's): a damped step only shrinks from there. Robust weights: Huber with the scale
//! 1.4826 × median |r| (re-estimated per iteration). Pixels are used where the blurred prediction is supported by defined pixels over
//! ≥ 99 % of its Gaussian weight (a prediction cut at an undefined neighbour is not the blur of
//! the photo).
//!
//! Parameters: with 6 of them the step rotates about a point on the optical axis at the mean
//! depth of the used pixels ([`AlignSettings::pivot_at_scene`], [`compose_about`]): the
//! Jacobian's rotation columns become `J_ω + J_δ·[c]×`, so the rotation moves the image of the
//! scene and the translation mostly its parallax (the optimum is the same; the damped steps are
//! better conditioned along the orbit). An optional Gaussian prior toward the given pose
//! ([`PosePrior`]) adds its normal equations (central differences of its residual), the
//! photo's residuals counted as independent per blur footprint `4πσ²` with the robust scale
//! as their noise. The prediction is rendered in `render.rs`, the geometric-edge system for the
//! common motion is in `edges.rs`.
//!
//! Conventions: Mitsuba's camera (`opal::camera`): local +z forward, +x image left;
//! `px = (1 − x/(z·tan_x))·W/2`, `py = (1 − y/(z·tan_y))·H/2`.
//!
//! Tests: below — a textured room (floor, wall, box) ray-cast with 4×4 supersampling, cameras
//! perturbed by 0.05–0.5° and 0.1–1 % of the scene size, refined back to within 0.02° and
//! 0.05 %; rotation-only mode; the pose composition and the projection Jacobian against finite
//! differences.

pub use super::edges::EdgeSystem;
use super::edges::edge_system;
pub use super::render::blur;
use super::render::{Prediction, render_prediction};
use opal::camera::Camera;
use opal::math::{DMat4, DVec3};
use opal::scene::{Scene, SurfaceInteraction};
use rayon::prelude::*;

/// Which pose parameters an alignment estimates.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PoseDof {
    /// Rotation only (3 parameters).
    Rotation,
    /// Rotation and translation (6 parameters).
    Full,
}

/// Settings of one view's alignment.
#[derive(Clone, Debug)]
pub struct AlignSettings {
    /// Parameters to estimate.
    pub dof: PoseDof,
    /// Gaussian blurs (pixels, standard deviation) of the levels, coarse to fine.
    pub sigmas: Vec<f64>,
    /// Maximum LM iterations per level.
    pub max_iterations: usize,
    /// Stop the finest level when a step moves the image by less than this many pixels: it
    /// rotates by less than this × the pixel angle and moves the camera by less than this × the
    /// pixel footprint at the mean depth — accepted, or rejected (the damped steps only shrink
    /// from there). The coarser levels scale it by their blur over the finest one's (they only
    /// bring the pose within the next level's reach).
    pub step_tolerance_px: f64,
    /// Also return the geometric-edge normal equations at the refined pose
    /// ([`Alignment::edges`]).
    pub edge_system: bool,
    /// In [`PoseDof::Full`], rotate about a point on the optical axis at the mean depth of the
    /// view's pixels instead of about the camera centre: the rotation then moves the scene's
    /// image and the translation mostly its parallax, so the two no longer trade against each
    /// other along the orbit and the damped steps follow that valley. The optimum is the same.
    /// Default off (bit for bit the camera-centre steps).
    pub pivot_at_scene: bool,
    /// A prior toward a pose (the given one) as strong as its stated uncertainty.
    pub prior: Option<PosePrior>,
}

/// Gaussian prior on the pose: the camera's rotation within `sigma_px` pixel angles of
/// `to_world`'s and its position within `sigma_px` pixel footprints at the view's mean depth.
/// The photo's residuals are weighed against it as independent per blur footprint
/// (`4πσ²` pixels at blur `σ`, at least one) with the robust residual scale as their noise.
#[derive(Clone, Copy, Debug)]
pub struct PosePrior {
    /// Mean of the prior (the given camera-to-world matrix).
    pub to_world: DMat4,
    /// Standard deviation in pixels (reprojection at the view's mean depth).
    pub sigma_px: f64,
}

impl Default for AlignSettings {
    fn default() -> Self {
        AlignSettings {
            dof: PoseDof::Full,
            sigmas: vec![4.0, 2.0, 1.0],
            max_iterations: 12,
            step_tolerance_px: 0.005,
            edge_system: false,
            pivot_at_scene: false,
            prior: None,
        }
    }
}

/// Result of [`align_view`].
#[derive(Clone, Debug)]
pub struct Alignment {
    /// Refined camera-to-world matrix (Mitsuba axes).
    pub to_world: DMat4,
    /// LM iterations over all levels.
    pub iterations: usize,
    /// The last level stopped on a small step (not on the iteration limit or a failed step).
    pub converged: bool,
    /// Pixels used at the finest level.
    pub pixels: usize,
    /// Robust RMS of the residual on the finest level at the start pose and at the refined pose,
    /// relative to the mean predicted luminance.
    pub rms_before: f64,
    /// See `rms_before`.
    pub rms_after: f64,
    /// Fitted scale `s` of the prediction (photo ≈ s · prediction).
    pub scale: f64,
    /// The geometric-edge normal equations at the refined pose (finest level; see
    /// [`edge_system`]), when [`AlignSettings::edge_system`] asked for them.
    pub edges: Option<EdgeSystem>,
}

/// Camera with a new `to_world` (the other parameters of `cam`).
pub fn camera_with(cam: &Camera, to_world: DMat4) -> Camera {
    let d = opal::scene::desc::SensorDesc {
        id: cam.id.clone(),
        to_world: to_world.as_mat4(),
        fov_x_deg: (2.0 * cam.tan_half_x.atan()).to_degrees(),
        width: cam.width,
        height: cam.height,
        near_clip: cam.near_clip,
        far_clip: cam.far_clip,
        spp: cam.spp,
    };
    let mut c = Camera::new(&d);
    // keep the exact tangents (the degree round trip loses bits)
    c.tan_half_x = cam.tan_half_x;
    c.tan_half_y = cam.tan_half_y;
    c
}

/// `to_world · [R(ω) | δ]`: the pose moved by a rotation vector `ω` and a translation `δ`, both
/// in the camera's own frame.
pub fn compose(to_world: DMat4, omega: DVec3, delta: DVec3) -> DMat4 {
    let angle = omega.length();
    let r = if angle > 0.0 { DMat4::from_axis_angle(omega / angle, angle) } else { DMat4::IDENTITY };
    to_world * DMat4::from_translation(delta) * r
}

/// `to_world · T(δ) · T(c) · R(ω) · T(−c)`: the pose rotated by `ω` about the camera-frame point
/// `c` and moved by `δ` (camera frame); [`compose`] when `c` is the origin.
pub fn compose_about(to_world: DMat4, omega: DVec3, delta: DVec3, pivot: DVec3) -> DMat4 {
    let angle = omega.length();
    let r = if angle > 0.0 { DMat4::from_axis_angle(omega / angle, angle) } else { DMat4::IDENTITY };
    to_world * DMat4::from_translation(delta + pivot) * r * DMat4::from_translation(-pivot)
}

/// A Jacobian row over ([`compose`]'s ω, δ, …) turned into one over [`compose_about`]'s with
/// pivot `c`: the rotation columns become `J_ω + J_δ·[c]×` (the other columns unchanged).
pub fn pivot_columns<const N: usize>(j: &[f64; N], c: DVec3) -> [f64; N] {
    let mut o = *j;
    o[0] += c.z * j[4] - c.y * j[5];
    o[1] += c.x * j[5] - c.z * j[3];
    o[2] += c.y * j[3] - c.x * j[4];
    o
}

/// The prior's residual at `pose` (rotation vector of the change in pixel angles, camera
/// displacement in the prior's frame in pixel footprints).
fn prior_residual(p: &PosePrior, pose: DMat4, angle_px: f64, foot_px: f64) -> [f64; 6] {
    let rel = p.to_world.inverse() * pose;
    let q = glam::DQuat::from_mat4(&rel);
    let (axis, mut ang) = q.to_axis_angle();
    if ang > std::f64::consts::PI {
        ang -= 2.0 * std::f64::consts::PI;
    }
    let w = axis * ang / (angle_px * p.sigma_px);
    let t = rel.w_axis.truncate() / (foot_px * p.sigma_px);
    [w.x, w.y, w.z, t.x, t.y, t.z]
}

/// Normal equations of the prior over the first `n` step parameters at `pose` (step applied
/// with [`compose_about`] about `pivot`), by central differences: `(JᵀJ, Jᵀr)`.
fn prior_system(
    p: &PosePrior,
    pose: DMat4,
    pivot: DVec3,
    n: usize,
    angle_px: f64,
    foot_px: f64,
) -> (Vec<Vec<f64>>, Vec<f64>) {
    let r0 = prior_residual(p, pose, angle_px, foot_px);
    let cols: Vec<[f64; 6]> = (0..n)
        .map(|c| {
            // 1e-6 rad, or as far as that angle moves the camera at the mean depth
            let eps = if c < 3 { 1e-6 } else { 1e-6 * foot_px / angle_px };
            let step = |sgn: f64| {
                let mut v = [0.0; 6];
                v[c] = sgn * eps;
                let m =
                    compose_about(pose, DVec3::new(v[0], v[1], v[2]), DVec3::new(v[3], v[4], v[5]), pivot);
                prior_residual(p, m, angle_px, foot_px)
            };
            let (a, b) = (step(1.0), step(-1.0));
            let mut col = [0.0; 6];
            for i in 0..6 {
                col[i] = (a[i] - b[i]) / (2.0 * eps);
            }
            col
        })
        .collect();
    let h = (0..n).map(|a| (0..n).map(|b| (0..6).map(|i| cols[a][i] * cols[b][i]).sum()).collect()).collect();
    let g = (0..n).map(|a| (0..6).map(|i| cols[a][i] * r0[i]).sum()).collect();
    (h, g)
}

/// Derivative of the film position of camera-space point `q` with respect to the camera-frame
/// pose change `(ω, δ)`: rows px, py; columns ω (3), δ (3).
pub fn projection_jacobian(q: DVec3, tan_x: f64, tan_y: f64, w: f64, h: f64) -> [[f64; 6]; 2] {
    let (x, y, z) = (q.x, q.y, q.z);
    // d(px)/d(q), d(py)/d(q)
    let dpx = [-w / (2.0 * tan_x * z), 0.0, w * x / (2.0 * tan_x * z * z)];
    let dpy = [0.0, -h / (2.0 * tan_y * z), h * y / (2.0 * tan_y * z * z)];
    // dq/dω = [q]_×, dq/dδ = −I
    let qx = [[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]];
    let mut j = [[0.0; 6]; 2];
    for (row, d) in [dpx, dpy].iter().enumerate() {
        for c in 0..3 {
            j[row][c] = (0..3).map(|k| d[k] * qx[k][c]).sum();
            j[row][3 + c] = -d[c];
        }
    }
    j
}

/// One coarse-to-fine level: the blurred photo (or prediction) luminance.
pub(super) struct Level {
    /// Width.
    pub(super) w: usize,
    /// Height.
    pub(super) h: usize,
    /// Luminance per pixel (NaN = undefined).
    pub(super) y: Vec<f32>,
}

impl Level {
    /// Pixel `i`'s observed value, its derivatives with respect to the six pose parameters
    /// through the projection of the world point `xw`, and `xw` in camera space (`to_cam`,
    /// tangents `tan`) — `None` where the pixel cannot enter a step: a prediction `p` that is not
    /// finite or supported (`support < 0.99`), an unobserved pixel, no gradient, or a point
    /// behind the camera. Shared by the per-view ([`linearise`]) and the joint linearisation.
    pub(super) fn pixel_row(
        &self,
        i: usize,
        p: f32,
        support: f32,
        xw: DVec3,
        to_cam: &DMat4,
        tan: (f64, f64),
    ) -> Option<(f32, [f64; 6], DVec3)> {
        if !p.is_finite() || support < 0.99 {
            return None;
        }
        let (x, y) = ((i % self.w) as i64, (i / self.w) as i64);
        let yv = self.at(x, y);
        if !yv.is_finite() {
            return None;
        }
        let (gx, gy) = self.grad(x, y)?;
        let q = to_cam.transform_point3(xw);
        if q.z <= 0.0 {
            return None;
        }
        let jp = projection_jacobian(q, tan.0, tan.1, self.w as f64, self.h as f64);
        Some((yv, std::array::from_fn(|c| gx * jp[0][c] + gy * jp[1][c]), q))
    }

    pub(super) fn at(&self, x: i64, y: i64) -> f32 {
        if x < 0 || y < 0 || x >= self.w as i64 || y >= self.h as i64 {
            return f32::NAN;
        }
        self.y[y as usize * self.w + x as usize]
    }
    /// Central-difference gradient at pixel (x, y).
    pub(super) fn grad(&self, x: i64, y: i64) -> Option<(f64, f64)> {
        let gx = 0.5 * (self.at(x + 1, y) - self.at(x - 1, y));
        let gy = 0.5 * (self.at(x, y + 1) - self.at(x, y - 1));
        (gx.is_finite() && gy.is_finite()).then_some((gx as f64, gy as f64))
    }
}

/// Per pixel: residual, its Jacobian (6 pose columns + the scale column).
struct Linearised {
    rows: Vec<(f64, [f64; 7])>,
    mean_pred: f64,
    /// Mean depth (camera z) of the used pixels.
    depth: f64,
}

fn linearise(
    lv: &Level,
    pred: &[f32],
    support: &[f32],
    hits: &[Option<DVec3>],
    cam: &Camera,
    wtw: DMat4,
    scale: f64,
) -> Linearised {
    let to_cam = wtw.inverse();
    let (w, h) = (lv.w, lv.h);
    let (tx, ty) = (cam.tan_half_x as f64, cam.tan_half_y as f64);
    let rows: Vec<(f64, [f64; 7], f64)> = (0..w * h)
        .into_par_iter()
        .filter_map(|i| {
            let p = pred[i];
            let (yv, own, q) = lv.pixel_row(i, p, support[i], hits[i]?, &to_cam, (tx, ty))?;
            let mut row = [0.0; 7];
            row[..6].copy_from_slice(&own);
            row[6] = -(p as f64);
            Some((yv as f64 - scale * p as f64, row, q.z))
        })
        .collect();
    let depth = rows.iter().map(|r| r.2).sum::<f64>() / rows.len().max(1) as f64;
    let rows: Vec<(f64, [f64; 7])> = rows.into_iter().map(|(r, j, _)| (r, j)).collect();
    let mean_pred = {
        let (s, n) = pred
            .iter()
            .zip(support)
            .filter(|(p, m)| p.is_finite() && **m >= 0.99)
            .fold((0.0, 0usize), |(s, n), (p, _)| (s + *p as f64, n + 1));
        s / n.max(1) as f64
    };
    Linearised { rows, mean_pred, depth }
}

fn robust_scale(rows: &[(f64, [f64; 7])]) -> f64 {
    let mut a: Vec<f64> = rows.iter().map(|r| r.0.abs()).collect();
    if a.is_empty() {
        return 0.0;
    }
    let k = a.len() / 2;
    let (_, m, _) = a.select_nth_unstable_by(k, f64::total_cmp);
    1.4826 * *m
}

pub(super) fn huber(r: f64, c: f64) -> f64 {
    if r.abs() <= c { 1.0 } else { c / r.abs() }
}

/// Huber cost of the residuals at scale `c`.
fn cost(rows: &[(f64, [f64; 7])], c: f64) -> f64 {
    rows.iter().map(|&(r, _)| if r.abs() <= c { 0.5 * r * r } else { c * (r.abs() - 0.5 * c) }).sum::<f64>()
        / rows.len().max(1) as f64
}

/// Aligns the photo luminance `photo` (row-major, `cam.width × cam.height`, NaN = unusable) to
/// the model's prediction, starting from `cam`'s pose.
pub fn align_view(
    scene: &Scene,
    cam: &Camera,
    photo: &[f32],
    predict: &(dyn Fn(&SurfaceInteraction) -> Option<f32> + Sync),
    s: &AlignSettings,
) -> Alignment {
    align_view_rendered(scene, cam, photo, predict, s).0
}

/// [`align_view`], also returning the prediction rendered at the aligned pose (`None` when no
/// level ran). Each pose's prediction is rendered once: the next level, the edge system (and
/// the caller's joint rows) reuse the render of the accepted step.
pub(super) fn align_view_rendered(
    scene: &Scene,
    cam: &Camera,
    photo: &[f32],
    predict: &(dyn Fn(&SurfaceInteraction) -> Option<f32> + Sync),
    s: &AlignSettings,
) -> (Alignment, Option<Prediction>) {
    let (w, h) = (cam.width, cam.height);
    let mut pose = cam.to_world.as_dmat4();
    let mut scale = 1.0f64;
    let mut iterations = 0;
    let mut converged = false;
    let (mut rms_before, mut rms_after, mut pixels) = (f64::NAN, f64::NAN, 0);
    let mut edges = None;
    // the prediction at `pose` (camera `camera_with(cam, pose)`), once rendered
    let mut current: Option<Prediction> = None;
    let n_par = if s.dof == PoseDof::Full { 6 } else { 3 };
    let (mut pivot, mut angle_px, mut foot_px): (Option<DVec3>, f64, f64) = (None, 1.0, 1.0);
    let rel = |rows: &[(f64, [f64; 7])], mean: f64| {
        let c = robust_scale(rows);
        (rows.iter().map(|r| r.0 * r.0 * huber(r.0, 1.345 * c)).sum::<f64>() / rows.len().max(1) as f64)
            .sqrt()
            / mean.abs().max(1e-30)
    };
    // the residual at the start pose on the finest level (the scale fitted there)
    if let Some(&sigma) = s.sigmas.last() {
        let lv = Level { w, h, y: blur(photo, w, h, sigma).0 };
        let pr = render_prediction(scene, cam, predict);
        let (pb, sup) = blur(&pr.p, w, h, sigma);
        let lin = linearise(&lv, &pb, &sup, &pr.hits, cam, pose, 0.0);
        let (num, den) = lin.rows.iter().fold((0.0, 0.0), |(a, b), (r, j)| (a + r * -j[6], b + j[6] * j[6]));
        let s0 = if den > 0.0 { num / den } else { 1.0 };
        let rows: Vec<_> = lin.rows.iter().map(|(r, j)| (r + s0 * j[6], *j)).collect();
        rms_before = rel(&rows, lin.mean_pred);
    }
    for (li, &sigma) in s.sigmas.iter().enumerate() {
        let last = li + 1 == s.sigmas.len();
        let lv = Level { w, h, y: blur(photo, w, h, sigma).0 };
        let lin_at = |pr: &Prediction, pose: DMat4, scale: f64| {
            let (pb, sup) = blur(&pr.p, w, h, sigma);
            linearise(&lv, &pb, &sup, &pr.hits, &camera_with(cam, pose), pose, scale)
        };
        let render = |pose: DMat4| render_prediction(scene, &camera_with(cam, pose), predict);
        let pr = current.take().unwrap_or_else(|| render(pose));
        let mut lin = lin_at(&pr, pose, scale);
        current = Some(pr);
        if lin.rows.len() < 50 {
            converged = false;
            break;
        }
        // initial scale: least squares of photo on prediction
        if li == 0 {
            let (num, den) = lin.rows.iter().fold((0.0, 0.0), |(a, b), (r, j)| {
                let p = -j[6];
                (a + (r + scale * p) * p, b + p * p)
            });
            if den > 0.0 {
                let s1 = num / den;
                for row in &mut lin.rows {
                    row.0 += (scale - s1) * -row.1[6];
                }
                scale = s1;
            }
        }
        if pivot.is_none() {
            // the pivot and the pixel scales from the first level's mean depth
            let d = lin.depth.max(1e-9);
            angle_px = 2.0 * cam.tan_half_x as f64 / w as f64;
            foot_px = angle_px * d;
            pivot = Some(if n_par == 6 && s.pivot_at_scene { DVec3::new(0.0, 0.0, d) } else { DVec3::ZERO });
        }
        let c_piv = pivot.unwrap_or_default();
        let jrow = |j: &[f64; 7]| pivot_columns(j, c_piv);
        // the photo's residuals are independent per blur footprint
        let kappa = (4.0 * std::f64::consts::PI * sigma * sigma).max(1.0);
        let prior_cost = |pose: DMat4, rows: &[(f64, [f64; 7])], noise: f64| {
            s.prior.map_or(0.0, |p| {
                let r = prior_residual(&p, pose, angle_px, foot_px);
                0.5 * noise * noise * kappa * r.iter().map(|x| x * x).sum::<f64>() / rows.len().max(1) as f64
            })
        };
        // this level's step tolerance (rotation, radians; translation over the depth)
        let tol =
            s.step_tolerance_px * angle_px * sigma / s.sigmas.last().copied().unwrap_or(sigma).max(1e-9);
        let mut lambda = 1e-3;
        converged = false;
        let mut it = 0;
        while it < s.max_iterations {
            it += 1;
            iterations += 1;
            let noise = robust_scale(&lin.rows).max(1e-12);
            let c = 1.345 * noise;
            // normal equations over the active parameters (pose + scale)
            let idx: Vec<usize> = (0..n_par).chain(std::iter::once(6)).collect();
            let k = idx.len();
            let mut jtj = nalgebra::DMatrix::<f64>::zeros(k, k);
            let mut jtr = nalgebra::DVector::<f64>::zeros(k);
            for (r, j) in &lin.rows {
                let j = &jrow(j);
                let wgt = huber(*r, c);
                for a in 0..k {
                    let ja = j[idx[a]];
                    jtr[a] += wgt * ja * r;
                    for b in a..k {
                        jtj[(a, b)] += wgt * ja * j[idx[b]];
                    }
                }
            }
            for a in 0..k {
                for b in 0..a {
                    jtj[(a, b)] = jtj[(b, a)];
                }
            }
            if let Some(p) = &s.prior {
                let (hp, gp) = prior_system(p, pose, c_piv, n_par, angle_px, foot_px);
                let wp = noise * noise * kappa;
                for a in 0..n_par {
                    jtr[a] += wp * gp[a];
                    for b in 0..n_par {
                        jtj[(a, b)] += wp * hp[a][b];
                    }
                }
            }
            let c0 = cost(&lin.rows, c) + prior_cost(pose, &lin.rows, noise);
            let mut accepted = false;
            for _ in 0..8 {
                let mut m = jtj.clone();
                for a in 0..k {
                    m[(a, a)] *= 1.0 + lambda;
                }
                let Some(ch) = m.cholesky() else {
                    lambda *= 10.0;
                    continue;
                };
                let d = ch.solve(&(-&jtr));
                let omega = DVec3::new(d[0], d[1], d[2]);
                let delta = if n_par == 6 { DVec3::new(d[3], d[4], d[5]) } else { DVec3::ZERO };
                let new_pose = compose_about(pose, omega, delta, c_piv);
                let new_scale = scale + d[k - 1];
                let pr = render(new_pose);
                let cand = lin_at(&pr, new_pose, new_scale);
                let ok = cand.rows.len() >= 50
                    && cost(&cand.rows, c) + prior_cost(new_pose, &cand.rows, noise) <= c0;
                if ok {
                    pose = new_pose;
                    scale = new_scale;
                    lin = cand;
                    current = Some(pr);
                    lambda = (lambda * 0.3).max(1e-7);
                    accepted = true;
                    if omega.length() < tol && delta.length() < tol * lin.depth {
                        converged = true;
                    }
                    break;
                }
                if omega.length() < tol && delta.length() < tol * lin.depth {
                    // a rejected step below the tolerance: at the minimum to that precision
                    break;
                }
                lambda *= 10.0;
            }
            if !accepted {
                // no descent at any damping: at the minimum to the precision of the residual
                converged = true;
            }
            if converged {
                break;
            }
        }
        if last {
            rms_after = rel(&lin.rows, lin.mean_pred);
            pixels = lin.rows.len();
            if s.edge_system
                && let Some(pr) = &current
            {
                edges = Some(edge_system(&lv, &camera_with(cam, pose), pr, sigma, scale));
            }
        }
    }
    (
        Alignment { to_world: pose, iterations, converged, pixels, rms_before, rms_after, scale, edges },
        current,
    )
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use opal::geometry::TriangleMesh;
    use opal::math::{Mat4, Vec2, Vec3};
    use opal::scene::desc::{BsdfDesc, SceneDesc, SensorDesc, ShapeDesc, TextureDesc};
    use opal::spectrum::Spectrum;

    /// Quad `o + [0,1]·a + [0,1]·b` facing `a × b`.
    fn quad(o: Vec3, a: Vec3, b: Vec3) -> [[Vec3; 3]; 2] {
        [[o, o + a, o + a + b], [o, o + a + b, o + b]]
    }

    fn mesh(tris: &[[Vec3; 3]]) -> TriangleMesh {
        TriangleMesh {
            positions: tris.iter().flatten().copied().collect(),
            normals: vec![],
            uvs: vec![],
            indices: (0..tris.len() as u32).map(|k| [3 * k, 3 * k + 1, 3 * k + 2]).collect(),
        }
    }

    /// A room: floor 4 × 4 m at y = 0, back wall at z = −2, a 0.8 m box; shapes 0, 1, 2.
    pub(crate) fn room() -> SceneDesc {
        let floor = quad(Vec3::new(-2.0, 0.0, -2.0), Vec3::new(0.0, 0.0, 4.0), Vec3::new(4.0, 0.0, 0.0));
        let wall = quad(Vec3::new(-2.0, 0.0, -2.0), Vec3::new(4.0, 0.0, 0.0), Vec3::new(0.0, 3.0, 0.0));
        let (o, s) = (Vec3::new(-0.2, 0.0, -0.6), 0.8);
        let (x, y, z) = (Vec3::X * s, Vec3::Y * s, Vec3::Z * s);
        let mut cube = Vec::new();
        for q in [quad(o, y, x), quad(o + z, x, y), quad(o, z, y), quad(o + x, y, z), quad(o + y, z, x)] {
            cube.extend(q);
        }
        let shape = |id: &str, tris: &[[Vec3; 3]]| ShapeDesc {
            id: id.into(),
            mesh: mesh(tris),
            bsdf: BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(Spectrum::splat(0.5)) },
            emitter: None,
            origin: None,
        };
        SceneDesc {
            shapes: vec![shape("floor", &floor), shape("wall", &wall), shape("box", &cube)],
            ..Default::default()
        }
    }

    /// Radiance of the synthetic room: textured floor and wall, constant faces of the box.
    pub(crate) fn texture(si: &SurfaceInteraction) -> f32 {
        let p = si.p;
        match si.shape {
            0 => {
                0.5 + 0.2 * (3.1 * p.x + 0.7 * p.z).sin() * (2.3 * p.z).cos()
                    + 0.1 * (9.0 * p.x - 5.0 * p.z).sin()
            }
            1 => {
                0.4 + 0.25 * (4.0 * p.x).sin() * (3.3 * p.y + 0.5).sin()
                    + 0.1 * (11.0 * p.y + 2.0 * p.x).cos()
            }
            _ => 0.3 + 0.5 * si.ng.x.abs() + 0.2 * si.ng.y.abs(),
        }
    }

    pub(crate) fn camera(eye: Vec3, target: Vec3, res: usize) -> Camera {
        let m =
            Mat4::look_at_rh(eye, target, Vec3::Y).inverse() * Mat4::from_scale(Vec3::new(-1.0, 1.0, -1.0));
        Camera::new(&SensorDesc {
            id: "v".into(),
            to_world: m,
            fov_x_deg: 50.0,
            width: res,
            height: res,
            near_clip: 1e-3,
            far_clip: 1e3,
            spp: None,
        })
    }

    /// The photo: `texture` box-filtered over each pixel (n × n samples).
    pub(crate) fn photo(scene: &Scene, cam: &Camera, n: usize) -> Vec<f32> {
        let (w, h) = (cam.width, cam.height);
        (0..w * h)
            .into_par_iter()
            .map(|i| {
                let mut acc = 0.0;
                for k in 0..n * n {
                    let c = Vec2::new(
                        (i % w) as f32 + ((k % n) as f32 + 0.5) / n as f32,
                        (i / w) as f32 + ((k / n) as f32 + 0.5) / n as f32,
                    );
                    acc += scene.intersect(&cam.generate_ray(c)).map_or(0.0, |si| texture(&si));
                }
                acc / (n * n) as f32
            })
            .collect()
    }

    /// Rotation angle (degrees) and camera distance between two poses.
    pub(crate) fn pose_error(a: DMat4, b: DMat4) -> (f64, f64) {
        let r = a.inverse() * b;
        let tr = r.x_axis.x + r.y_axis.y + r.z_axis.z;
        let ang = ((tr - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees();
        (ang, (a.w_axis.truncate() - b.w_axis.truncate()).length())
    }

    /// Deterministic perturbation: rotation `deg` about a direction from `k`, translation `t`
    /// along another.
    pub(crate) fn perturb(m: DMat4, k: u64, deg: f64, t: f64) -> DMat4 {
        let h = |s: u64| {
            let x = (s.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 11) as f64 / (1u64 << 53) as f64;
            2.0 * x - 1.0
        };
        let a = DVec3::new(h(k * 7 + 1), h(k * 7 + 2), h(k * 7 + 3)).normalize();
        let d = DVec3::new(h(k * 7 + 4), h(k * 7 + 5), h(k * 7 + 6)).normalize();
        compose(m, a * deg.to_radians(), d * t)
    }

    #[test]
    fn projection_jacobian_matches_finite_differences() {
        let cam = camera(Vec3::new(1.0, 2.0, 3.0), Vec3::new(0.0, 0.3, -1.0), 64);
        let x = DVec3::new(0.3, 0.2, -0.9);
        let m = cam.to_world.as_dmat4();
        let proj = |m: DMat4| {
            let q = m.inverse().transform_point3(x);
            let (tx, ty) = (cam.tan_half_x as f64, cam.tan_half_y as f64);
            [(1.0 - q.x / q.z / tx) * 32.0, (1.0 - q.y / q.z / ty) * 32.0]
        };
        let q = m.inverse().transform_point3(x);
        let j = projection_jacobian(q, cam.tan_half_x as f64, cam.tan_half_y as f64, 64.0, 64.0);
        let e = 1e-6;
        for c in 0..6 {
            let mut v = [0.0; 6];
            v[c] = e;
            let p1 = proj(compose(m, DVec3::new(v[0], v[1], v[2]), DVec3::new(v[3], v[4], v[5])));
            let p0 = proj(compose(m, DVec3::new(-v[0], -v[1], -v[2]), DVec3::new(-v[3], -v[4], -v[5])));
            for r in 0..2 {
                let fd = (p1[r] - p0[r]) / (2.0 * e);
                assert!(
                    (fd - j[r][c]).abs() < 1e-4 * (1.0 + fd.abs()),
                    "row {r} col {c}: {fd} vs {}",
                    j[r][c]
                );
            }
        }
    }

    #[test]
    fn pivot_jacobian_matches_finite_differences() {
        let cam = camera(Vec3::new(1.0, 2.0, 3.0), Vec3::new(0.0, 0.3, -1.0), 64);
        let x = DVec3::new(0.3, 0.2, -0.9);
        let m = cam.to_world.as_dmat4();
        let c = DVec3::new(0.1, -0.2, 3.5);
        let (tx, ty) = (cam.tan_half_x as f64, cam.tan_half_y as f64);
        let proj = |m: DMat4| {
            let q = m.inverse().transform_point3(x);
            [(1.0 - q.x / q.z / tx) * 32.0, (1.0 - q.y / q.z / ty) * 32.0]
        };
        let q = m.inverse().transform_point3(x);
        let j = projection_jacobian(q, tx, ty, 64.0, 64.0).map(|r| pivot_columns(&r, c));
        let e = 1e-6;
        for col in 0..6 {
            let mut v = [0.0; 6];
            v[col] = e;
            let at = |s: f64| {
                let (w, d) = (DVec3::new(v[0], v[1], v[2]) * s, DVec3::new(v[3], v[4], v[5]) * s);
                proj(compose_about(m, w, d, c))
            };
            let (p1, p0) = (at(1.0), at(-1.0));
            for r in 0..2 {
                let fd = (p1[r] - p0[r]) / (2.0 * e);
                assert!(
                    (fd - j[r][col]).abs() < 1e-4 * (1.0 + fd.abs()),
                    "row {r} col {col}: {fd} vs {}",
                    j[r][col]
                );
            }
        }
    }

    /// Runs the alignment of perturbed views of the room against the exact texture; returns
    /// the worst (rotation °, translation) errors after refinement.
    fn refine_room(dof: PoseDof, cases: &[(f64, f64)]) -> (f64, f64) {
        let scene = Scene::build(&room()).unwrap();
        let eyes = [Vec3::new(2.5, 2.2, 2.8), Vec3::new(-2.8, 1.6, 2.5), Vec3::new(0.4, 3.0, 3.2)];
        let size = 4.0 * 3f64.sqrt();
        let (mut worst_r, mut worst_t) = (0.0f64, 0.0f64);
        for (k, &(deg, frac)) in cases.iter().enumerate() {
            let truth = camera(eyes[k % eyes.len()], Vec3::new(0.0, 0.6, -0.8), 128);
            let y = photo(&scene, &truth, 4);
            let t = if dof == PoseDof::Full { frac * size } else { 0.0 };
            let start = perturb(truth.to_world.as_dmat4(), k as u64 + 1, deg, t);
            let cam = camera_with(&truth, start);
            let s = AlignSettings { dof, ..Default::default() };
            let a = align_view(&scene, &cam, &y, &|si: &SurfaceInteraction| Some(texture(si)), &s);
            let (r0, t0) = pose_error(truth.to_world.as_dmat4(), start);
            let (r1, t1) = pose_error(truth.to_world.as_dmat4(), a.to_world);
            eprintln!(
                "case {k}: start {r0:.3}° {:.3} % → {r1:.4}° {:.4} % ({} it, conv {}, rms {:.4} → {:.4}, s {:.4})",
                100.0 * t0 / size,
                100.0 * t1 / size,
                a.iterations,
                a.converged,
                a.rms_before,
                a.rms_after,
                a.scale
            );
            assert!(a.converged);
            worst_r = worst_r.max(r1);
            worst_t = worst_t.max(t1 / size);
        }
        (worst_r, worst_t)
    }

    #[test]
    fn full_pose_refined_within_0_02_deg_and_0_05_percent() {
        let (r, t) = refine_room(PoseDof::Full, &[(0.05, 0.001), (0.2, 0.005), (0.5, 0.01)]);
        assert!(r < 0.02, "rotation error {r}°");
        assert!(t < 0.0005, "translation error {} %", 100.0 * t);
    }

    #[test]
    fn rotation_refined_within_0_02_deg() {
        let (r, _) = refine_room(PoseDof::Rotation, &[(0.05, 0.0), (0.5, 0.0)]);
        assert!(r < 0.02, "rotation error {r}°");
    }
}
