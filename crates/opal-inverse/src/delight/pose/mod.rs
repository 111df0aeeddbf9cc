//! Pose refinement of the de-lighting's input views ([`refine_poses`]): before the luminance
//! maps are built, each view's rotation (and translation) is corrected by aligning its photo
//! with what the model predicts at that pose.
//!
//! Prediction: the view-independent radiance of the recovered objects, i.e. the luminance map
//! `L` of every object built from the *other* views (leave-one-out, so a view is never pulled
//! towards its own misregistration) and looked up at the surface point each pixel's centre ray
//! hits (bilinear over the observed texels of the hit triangle's chart). Pixels that show an
//! emitter, a shape that is not recovered or an unseen texel have no prediction. The geometry
//! is exact, so the object boundaries in the prediction (silhouettes, occlusion edges, the
//! contact of a box with the floor) pin the poses; the textures add the fine registration.
//! The alignment of one view is [`solve::align_view`] (Levenberg–Marquardt on the Huber-weighted
//! luminance residual with a free exposure scale, coarse to fine over Gaussian blurs of 4, 2, 1
//! px, rendering the prediction at each step tried; a level stops on a step below
//! [`PoseSettings::step_tolerance_px`], the rounds before the last on one below
//! [`PoseSettings::round_step_tolerance_px`]). The maps of a round are built in `maps.rs`: each
//! view samples every texel once, and the map of view `k` sums the others' samples.
//!
//! Rounds: all views are aligned against maps from the poses of the previous round (Jacobi);
//! the second round re-aligns against maps built from the corrected poses of the other views.
//! After each round, all views are moved together by the rigid motion their geometric edges ask
//! for ([`common_motion`]): when every view is off the same way, the leave-one-out textures move
//! with them and only the edges of the geometry (changes of shape or plane) see it, which the
//! per-view alignment, pulled by the textures, corrects only by a fraction per round. The edges
//! of the prediction are rendered with 4 × 4 rays per pixel (box filter, as the photos) so
//! they sit where the geometry puts them, not on the pixel grid.
//!
//! Joint step ([`PoseSettings::joint`], on; `joint.rs`): after the per-view alignments of a
//! round, one Gauss–Newton step over all views' poses together, each prediction linearised in
//! the poses of the views its maps came from as well. The per-view alignments leave the views
//! drifting along the modes in which they move consistently (each is held by the others'
//! textures); the joint step moves them together, pinned by the geometric edges and the
//! emitters (it contains the common motion, which is then not applied separately).
//!
//! Bands at edges: in the rounds after the first that refines everything, the maps leave out
//! only the pixels within [`PoseSettings::fine_edge_margin`] (1) px of an edge instead of
//! [`PoseSettings::edge_margin`] (3), and the unobserved texels next to the observed ones are
//! extrapolated to first order ([`PoseSettings::linear_bands`], `extrapolate.rs`): near a
//! concave edge (a room's corners, a contact with the floor) the luminance changes fastest, and
//! a flat fill there gives the predicted edge the wrong profile, which pulls the alignment
//! sideways (measured on the Mitsuba room: exact views drifted by up to 0.28 px with the flat
//! 3-px bands). In those rounds the prediction covers only the observed texels and those the
//! first-order fill reached ([`PoseSettings::linear_domain`]): a region that only the view
//! itself sees was otherwise predicted by the inpainting's flat extension (up to 48 texels),
//! and the misfit held that view 0.35 px off on the Mitsuba room (`view_03`; 0.09 px with it).
//! After the refinement the de-lighting leaves out the pixels within
//! [`PoseSettings::delight_edge_margin`] (1) px of an edge ([`erode_smooth`]).
//!
//! Prior and convergence: each alignment may be pulled toward the given pose by a Gaussian prior
//! as wide as the stated pose uncertainty ([`PoseSettings::prior_px`], off by default); how far each view moved
//! in each round is reported ([`ViewPose::round_steps_px`]) so that views that keep moving
//! along their orbit are visible.
//!
//! Failure: a view whose alignment does not converge, whose correction exceeds
//! [`PoseSettings::max_rotation_deg`] / [`PoseSettings::max_translation`], or whose residual
//! grows keeps its given pose, is flagged ([`ViewPose::used`] false, with a warning) and is left
//! out of the de-lighting (weight 0) unless no view would be left.
//!
//! Tests: `solve.rs` (one view against an exact textured room: 0.05–0.5° and 0.1–1 % of the
//! scene size refined to within 0.02° and 0.05 %); `tests.rs` here (multi-view end to end
//! through the leave-one-out prediction, exact views stay,
//! `common_motion_of_all_views_recovered`: all six views moved together by 0.25° and ~1 px;
//! `loo_maps_match_luminance_map`: the round's maps bit for bit those of `luminance_map`);
//! `tests/delight_room.rs` (`mitsuba_room_perturbed_poses`, ignored: the Mitsuba room with
//! every camera perturbed); `extrapolate.rs` (the first-order fill).

mod edges;
mod extrapolate;
mod joint;
mod maps;
mod render;
pub mod solve;
#[cfg(test)]
mod tests;

use super::atlas::Atlas;
use super::luminance;
use super::views::{self, PureBuffer, View};
use opal::math::{DMat4, DVec3};
use opal::scene::{Scene, SurfaceInteraction};
use rayon::prelude::*;
pub use solve::{AlignSettings, Alignment, PoseDof, align_view, camera_with, compose};

/// Which pose parameters the de-lighting refines.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum PoseRefinement {
    /// The poses are exact (no refinement; results bit for bit those of a run without it).
    #[default]
    Off,
    /// Rotation of each view.
    Rotation,
    /// Rotation and translation of each view.
    Full,
}

impl PoseRefinement {
    /// Short name: `off`, `rotation`, `full`.
    pub fn name(self) -> &'static str {
        match self {
            PoseRefinement::Off => "off",
            PoseRefinement::Rotation => "rotation",
            PoseRefinement::Full => "full",
        }
    }
}

/// Settings of the pose refinement.
#[derive(Clone, Debug)]
pub struct PoseSettings {
    /// What to refine.
    pub mode: PoseRefinement,
    /// Alignment rounds (each against maps from the previous round's poses).
    pub rounds: usize,
    /// Leading rounds that refine the rotation only (in [`PoseRefinement::Full`]; the last
    /// round always refines everything asked for).
    pub rotation_rounds: usize,
    /// Blurs (px) of the coarse-to-fine levels.
    pub sigmas: Vec<f64>,
    /// LM iterations per level.
    pub max_iterations: usize,
    /// Pixels within this distance (px) of a change of shape or plane in a view do not feed
    /// the predicted maps (a misregistered view puts the wrong side of the edge there); the maps
    /// are extended over the gap from the object's side, so the edges of the prediction sit
    /// where the geometry puts them.
    pub edge_margin: usize,
    /// [`Self::edge_margin`] in the rounds after the first that refines everything asked for
    /// (the views are then within a fraction of a pixel; the bands the maps extrapolate over
    /// near concave edges, where the luminance changes fastest, are narrower).
    pub fine_edge_margin: usize,
    /// [`Self::sigmas`] in the same rounds as [`Self::fine_edge_margin`] (`None`: the same);
    /// the views are within a pixel there, the coarsest level only costs time.
    pub fine_sigmas: Option<Vec<f64>>,
    /// The unobserved texels of the maps within this many texels of an observed one are
    /// extrapolated to first order (`extrapolate.rs`) instead of the inpainting's zero order;
    /// 0: off.
    pub linear_bands: usize,
    /// In the rounds with [`Self::fine_edge_margin`] and with [`Self::linear_bands`] on, the
    /// prediction covers only the observed texels and those the first-order fill reached: a
    /// pixel whose surface point only the inpainting's flat extension (up to 48 texels from the
    /// other views' pixels) predicts leaves the residual (a region only this view sees is
    /// otherwise predicted flat, and the misfit pulls its pose).
    pub linear_domain: bool,
    /// After the refinement, the de-lighting leaves out the pixels within this many pixels of
    /// a change of shape or plane ([`erode_smooth`]): the refined poses are known to a fraction
    /// of a pixel, and a pixel next to an edge may show the other side. Default 0 (measured on
    /// the Mitsuba room with 1: the ceiling's error 1.0 → 0.4 %, but the textures at the
    /// cameras 39 → 34 dB: the texels next to edges are then filled, not observed).
    pub delight_edge_margin: usize,
    /// A correction rotating a view by more than this (degrees) is rejected.
    pub max_rotation_deg: f64,
    /// A correction moving a camera by more than this fraction of its mean distance to the
    /// surfaces it sees is rejected.
    pub max_translation: f64,
    /// After each round, move all views together by the rigid motion their geometric edges ask
    /// for ([`common_motion`]): the mode the leave-one-out textures cannot see.
    pub common_motion: bool,
    /// Stop after a round (past the rotation-only ones) in which no view moved by more than
    /// this (degrees, and this angle × its distance to the scene for the camera position).
    pub tolerance_deg: f64,
    /// The stated uncertainty of the given poses (pixels of reprojection at the scene): each
    /// alignment is pulled toward the given pose by a Gaussian prior this wide
    /// ([`solve::PosePrior`]); `None` (default): no prior. Measured on the Mitsuba room (1 px
    /// with the pivot): no better than without (docs/delight.md "Pose refinement").
    pub prior_px: Option<f64>,
    /// Rotate about a point at the view's mean depth instead of the camera centre in the
    /// 6-parameter alignments ([`AlignSettings::pivot_at_scene`]); default off (measured: no
    /// better on the Mitsuba room).
    pub pivot_at_scene: bool,
    /// After the per-view alignments of each round, one joint Gauss–Newton step over all
    /// views' poses that also linearises each prediction in the poses of the views its maps
    /// came from (`joint.rs`); the common motion is then not applied separately (the joint
    /// step contains it).
    pub joint: bool,
    /// An alignment level stops when a step moves the image by less than this many pixels
    /// ([`AlignSettings::step_tolerance_px`]; the coarser levels scale it by their blur).
    pub step_tolerance_px: f64,
    /// [`Self::step_tolerance_px`] in the rounds before the last: their alignments are against
    /// maps from the other views' poses of the previous round, themselves a fraction of a pixel
    /// off, and the next round starts from them again; converging them further than that only
    /// costs renders.
    pub round_step_tolerance_px: f64,
}

impl Default for PoseSettings {
    fn default() -> Self {
        PoseSettings {
            mode: PoseRefinement::Off,
            rounds: 6,
            rotation_rounds: 2,
            sigmas: vec![4.0, 2.0, 1.0],
            max_iterations: 12,
            edge_margin: 3,
            fine_edge_margin: 1,
            fine_sigmas: Some(vec![2.0, 1.0]),
            linear_bands: 8,
            linear_domain: true,
            delight_edge_margin: 0,
            max_rotation_deg: 3.0,
            max_translation: 0.05,
            common_motion: true,
            tolerance_deg: 0.0,
            prior_px: None,
            pivot_at_scene: false,
            joint: true,
            step_tolerance_px: 0.005,
            round_step_tolerance_px: 0.02,
        }
    }
}

/// Refined pose of one view.
#[derive(Clone, Debug)]
pub struct ViewPose {
    /// View name.
    pub view: String,
    /// Refined camera-to-world matrix (Mitsuba axes); the given one when the correction was not
    /// [`Self::accepted`].
    pub to_world: DMat4,
    /// Correction as a world-space rotation vector (degrees; direction = axis) applied to the
    /// given camera's orientation: `R_refined = R(rotation) · R_given`.
    pub rotation_deg: [f64; 3],
    /// Camera position refined − given (world units).
    pub translation: [f64; 3],
    /// Angle of the correction (degrees).
    pub angle_deg: f64,
    /// LM iterations (all rounds).
    pub iterations: usize,
    /// The last round's alignment converged.
    pub converged: bool,
    /// The correction was accepted (converged, within the bounds, residual not worse).
    pub accepted: bool,
    /// The view is used by the de-lighting (accepted, or kept because no view was accepted).
    pub used: bool,
    /// Relative robust RMS residual at the given and at the refined pose (finest level).
    pub rms_before: f64,
    /// See `rms_before`.
    pub rms_after: f64,
    /// Pixels used by the last alignment.
    pub pixels: usize,
    /// How far the view moved in each round (pixels at the scene: the larger of the rotation
    /// over a pixel's angle and the camera's displacement over a pixel's footprint at the
    /// scene centre), the common motion included; a view still moving in the last rounds has
    /// not settled against the others.
    pub round_steps_px: Vec<f64>,
    /// Why the correction was rejected (empty when accepted).
    pub reason: String,
}

/// Result of [`refine_poses`].
#[derive(Clone, Debug)]
pub struct PoseReport {
    /// Mode.
    pub mode: PoseRefinement,
    /// Per view (in the order of the views).
    pub views: Vec<ViewPose>,
}

impl PoseReport {
    /// A NeRF-style `transforms.json` of `views` with the refined poses (OpenGL camera axes,
    /// what [`views::read_views`] reads): per frame `file_path` (the image's absolute path),
    /// `transform_matrix`, `camera_angle_x`, `w`, `h`, and `pose_refined` (the correction was
    /// accepted).
    pub fn transforms_json(&self, views: &[View]) -> serde_json::Value {
        let frames: Vec<serde_json::Value> = views
            .iter()
            .zip(&self.views)
            .map(|(v, p)| {
                let gl = p.to_world * DMat4::from_scale(DVec3::new(-1.0, 1.0, -1.0));
                let rows: Vec<Vec<f64>> = (0..4).map(|r| (0..4).map(|c| gl.col(c)[r]).collect()).collect();
                let path = std::path::absolute(&v.path).unwrap_or_else(|_| v.path.clone());
                serde_json::json!({
                    "file_path": path,
                    "transform_matrix": rows,
                    "camera_angle_x": 2.0 * (v.camera.tan_half_x as f64).atan(),
                    "w": v.camera.width,
                    "h": v.camera.height,
                    "pose_refined": p.accepted,
                })
            })
            .collect();
        serde_json::json!({ "pose_refinement": self.mode.name(), "frames": frames })
    }

    /// The views with the refined cameras (all of them, used or not).
    pub fn apply(&self, views: &[View]) -> Vec<View> {
        views
            .iter()
            .zip(&self.views)
            .map(|(v, p)| {
                let mut v = v.clone();
                v.camera = camera_with(&v.camera, p.to_world);
                v
            })
            .collect()
    }
}

/// `pb` with every pixel within `r` pixels (Chebyshev) of a pixel of another shape or plane
/// (or a mixed pixel) marked [`views::MIXED`].
pub fn erode(pb: &PureBuffer, r: usize) -> PureBuffer {
    erode_with(pb, r, |_, _| 0.999)
}

/// [`erode`], but neighbours on one smooth (tessellated curved) surface count as one plane: two
/// pixels differ when their normals are further apart than either pixel's matching tolerance
/// ([`PureBuffer::min_cos`]).
pub fn erode_smooth(pb: &PureBuffer, r: usize) -> PureBuffer {
    erode_with(pb, r, |i, j| pb.min_cos(i).min(pb.min_cos(j)))
}

fn erode_with(pb: &PureBuffer, r: usize, min_cos: impl Fn(usize, usize) -> f32 + Sync) -> PureBuffer {
    let (w, h) = (pb.width, pb.height);
    let r = r as i64;
    let shape: Vec<u32> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let s0 = pb.shape(i);
            if s0 == views::MIXED {
                return s0;
            }
            let (x, y) = ((i % w) as i64, (i / w) as i64);
            for yy in (y - r).max(0)..=(y + r).min(h as i64 - 1) {
                for xx in (x - r).max(0)..=(x + r).min(w as i64 - 1) {
                    let j = yy as usize * w + xx as usize;
                    if pb.shape(j) != s0 || pb.normal(j).dot(pb.normal(i)) < min_cos(i, j) {
                        return views::MIXED;
                    }
                }
            }
            s0
        })
        .collect();
    pb.with_shapes(shape)
}

/// Rotation vector (radians) of a rotation matrix.
fn rotation_vector(r: glam::DMat3) -> DVec3 {
    let q = glam::DQuat::from_mat3(&r);
    let (axis, angle) = q.to_axis_angle();
    let angle = if angle > std::f64::consts::PI { angle - 2.0 * std::f64::consts::PI } else { angle };
    axis * angle
}

fn rot3(m: DMat4) -> glam::DMat3 {
    glam::DMat3::from_mat4(m)
}

/// Refines the poses of `views` against the leave-one-out luminance maps of `objects`
/// (shape index, atlas). Returns the report (refined poses, corrections, flags) and warnings;
/// apply it with [`PoseReport::apply`]. `log` receives one line per view and round.
pub fn refine_poses(
    scene: &Scene,
    objects: &[(u32, &Atlas)],
    views: &[View],
    s: &PoseSettings,
    log: &(dyn Fn(&str) + Sync),
) -> (PoseReport, Vec<String>) {
    let dof = if s.mode == PoseRefinement::Rotation { PoseDof::Rotation } else { PoseDof::Full };
    let given: Vec<DMat4> = views.iter().map(|v| v.camera.to_world.as_dmat4()).collect();
    let mut poses = given.clone();
    let mut fits: Vec<Option<Alignment>> = vec![None; views.len()];
    let mut iterations = vec![0usize; views.len()];
    let photos: Vec<Vec<f32>> = views
        .iter()
        .map(|v| v.image.data.iter().map(|p| if p.is_finite() { luminance(p.0) } else { f32::NAN }).collect())
        .collect();
    let align = AlignSettings {
        dof,
        sigmas: s.sigmas.clone(),
        max_iterations: s.max_iterations,
        edge_system: s.common_motion,
        pivot_at_scene: s.pivot_at_scene,
        step_tolerance_px: s.step_tolerance_px,
        ..Default::default()
    };
    let mut steps_px: Vec<Vec<f64>> = vec![Vec::new(); views.len()];
    // a view's step in pixels at the scene
    let step_px = |k: usize, a: DMat4, b: DMat4| {
        let (ang, dist) = solve_error(a, b);
        let pix = 2.0 * views[k].camera.tan_half_x as f64 / views[k].camera.width as f64;
        (ang.to_radians() / pix).max(dist / (pix * scene_depth(views, k, scene)))
    };
    let (lo, hi) = scene.bounds();
    let centre = (0.5 * (lo + hi)).as_dvec3();
    let mut active = vec![true; views.len()];
    // the finest level's blurred photos (the joint step's cross terms)
    let sigma_fine = s.sigmas.last().copied().unwrap_or(1.0);
    let levels: Vec<solve::Level> = if s.joint {
        views
            .iter()
            .zip(&photos)
            .map(|(v, y)| {
                let (w, h) = (v.camera.width, v.camera.height);
                solve::Level { w, h, y: render::blur(y, w, h, sigma_fine).0 }
            })
            .collect()
    } else {
        Vec::new()
    };
    for round in 0..s.rounds.max(1) {
        let current: Vec<View> = views
            .iter()
            .zip(&poses)
            .map(|(v, &m)| {
                let mut v = v.clone();
                v.camera = camera_with(&v.camera, m);
                v
            })
            .collect();
        let fine = round > s.rotation_rounds.min(s.rounds.max(1) - 1);
        let margin = if fine { s.fine_edge_margin } else { s.edge_margin };
        let pure: Vec<PureBuffer> =
            current.iter().map(|v| erode(&views::pure_buffer(scene, &v.camera), margin)).collect();
        let depths: Vec<Vec<f32>> = if s.joint {
            current.iter().map(|v| joint::depth_buffer(scene, &v.camera)).collect()
        } else {
            Vec::new()
        };
        let mut joint_rows = Vec::new();
        let start = poses.clone();
        let mut next = poses.clone();
        let mut edges: Vec<Option<solve::EdgeSystem>> = vec![None; views.len()];
        // leave-one-out maps: every other active view
        let loo = maps::leave_one_out_maps(
            scene,
            objects,
            &current,
            &pure,
            &active,
            s.linear_bands,
            fine && s.linear_domain,
        );
        for k in 0..views.len() {
            let Some(maps) = &loo[k] else {
                continue;
            };
            let others: Vec<usize> = (0..views.len()).filter(|&j| j != k && active[j]).collect();
            let eye = current[k].camera.origin();
            let predict = |si: &SurfaceInteraction| -> Option<f32> {
                // an emitter's front shows its known radiance: an outline no view misplaces
                if let Some(e) = scene.shapes[si.shape as usize].emission {
                    return ((eye - si.p).dot(si.ng) > 0.0).then(|| luminance(e.0));
                }
                let j = objects.iter().position(|&(sh, _)| sh == si.shape)?;
                let local = (si.prim - scene.shapes[si.shape as usize].first_prim) as usize;
                maps::lookup(objects[j].1, &maps[j].0, &maps[j].1, local, si.p)
            };
            // rotation only before the last round: the orbit direction (a rotation and a
            // translation that nearly cancel at the depth of the scene) is weakly constrained and
            // would follow the blur of maps made from misregistered views
            let rot_only = round < s.rotation_rounds.min(s.rounds.max(1) - 1);
            let sigmas = match &s.fine_sigmas {
                Some(f) if fine => f.clone(),
                _ => s.sigmas.clone(),
            };
            let last_round = round + 1 >= s.rounds.max(1);
            let align = AlignSettings {
                dof: if rot_only { PoseDof::Rotation } else { dof },
                sigmas,
                step_tolerance_px: if last_round { s.step_tolerance_px } else { s.round_step_tolerance_px },
                prior: s.prior_px.map(|sigma_px| solve::PosePrior { to_world: given[k], sigma_px }),
                ..align.clone()
            };
            let (fit, at_fit) =
                solve::align_view_rendered(scene, &current[k].camera, &photos[k], &predict, &align);
            iterations[k] += fit.iterations;
            let (ang, dist) = solve_error(poses[k], fit.to_world);
            log(&format!(
                "pose {} round {}: step {:.4}° {:.3e}, {} it{}, rms {:.4} → {:.4}",
                views[k].name,
                round + 1,
                ang,
                dist,
                fit.iterations,
                if fit.converged { "" } else { " (not converged)" },
                fit.rms_before,
                fit.rms_after
            ));
            if s.joint {
                let ol: Vec<joint::Other> = others
                    .iter()
                    .map(|&j| joint::Other {
                        j,
                        cam: &current[j].camera,
                        level: &levels[j],
                        pure: &pure[j],
                        depth: &depths[j],
                    })
                    .collect();
                let cam = camera_with(&current[k].camera, fit.to_world);
                // the prediction at the aligned pose (rendered by the alignment unless no level ran)
                let pr = at_fit.unwrap_or_else(|| render::render_prediction(scene, &cam, &predict));
                joint_rows.push(joint::view_rows(k, &cam, &levels[k], &pr, fit.scale, sigma_fine, &ol));
            }
            next[k] = fit.to_world;
            edges[k] = fit.edges.clone();
            if round == 0 {
                fits[k] = Some(fit);
            } else if let Some(f0) = &fits[k] {
                // keep the first round's starting residual
                let rb = f0.rms_before;
                fits[k] = Some(Alignment { rms_before: rb, ..fit });
            }
        }
        // the largest step of the round (angle, translation over the distance to the scene)
        let mut moved = (0..views.len())
            .filter(|&k| active[k])
            .map(|k| {
                let (a, d) = solve_error(poses[k], next[k]);
                a.max((d / scene_depth(views, k, scene)).to_degrees())
            })
            .fold(0.0f64, f64::max);
        poses = next;
        // views that cannot be aligned do not feed the others' maps in the next round
        for k in 0..views.len() {
            if let Some(f) = &fits[k] {
                active[k] = judge(f, given[k], poses[k], scene_depth(views, k, scene), s).is_none();
            }
        }
        let mut joint_done = false;
        if s.joint {
            let rot_only = round < s.rotation_rounds.min(s.rounds.max(1) - 1);
            let npar = if rot_only || dof == PoseDof::Rotation { 3 } else { 6 };
            let since: Vec<[f64; 6]> =
                (0..views.len()).map(|j| joint::camera_frame_move(start[j], poses[j])).collect();
            let jstep = joint::joint_step(&joint_rows, &since, views.len(), npar);
            if let Some(d) = jstep {
                for k in 0..views.len() {
                    if active[k] && joint_rows.iter().any(|r| r.k == k) {
                        let m = compose(
                            poses[k],
                            DVec3::new(d[k][0], d[k][1], d[k][2]),
                            DVec3::new(d[k][3], d[k][4], d[k][5]),
                        );
                        let (a, dd) = solve_error(poses[k], m);
                        log(&format!(
                            "pose {} round {}: joint step {a:.4}° {dd:.3e}",
                            views[k].name,
                            round + 1
                        ));
                        moved = moved.max(a.max((dd / scene_depth(views, k, scene)).to_degrees()));
                        poses[k] = m;
                    }
                }
                joint_done = true;
            }
        }
        if s.common_motion && !joint_done {
            let sys: Vec<(DMat4, solve::EdgeSystem)> = (0..views.len())
                .filter(|&k| active[k])
                .filter_map(|k| Some((poses[k], edges[k].clone()?)))
                .collect();
            if let Some(g) = common_motion(&sys, centre, s.mode == PoseRefinement::Full) {
                log(&format!(
                    "pose common motion round {}: {:.4}° {:.3e}",
                    round + 1,
                    g.omega.length().to_degrees(),
                    g.t.length()
                ));
                for k in 0..views.len() {
                    if active[k] {
                        let m = g.apply(poses[k]);
                        let (a, d) = solve_error(poses[k], m);
                        moved = moved.max(a.max((d / scene_depth(views, k, scene)).to_degrees()));
                        poses[k] = m;
                    }
                }
            }
        }
        for k in 0..views.len() {
            steps_px[k].push(step_px(k, start[k], poses[k]));
        }
        if round + 1 > s.rotation_rounds && moved < s.tolerance_deg {
            log(&format!("pose: converged after round {} (largest step {moved:.4}°)", round + 1));
            break;
        }
    }
    let mut warnings = Vec::new();
    let mut out = Vec::new();
    for k in 0..views.len() {
        let f = fits[k].clone();
        let reason = match &f {
            Some(f) => judge(f, given[k], poses[k], scene_depth(views, k, scene), s).unwrap_or_default(),
            None => "no other view to predict it from".into(),
        };
        let accepted = reason.is_empty();
        let to_world = if accepted { poses[k] } else { given[k] };
        if !accepted {
            warnings.push(format!(
                "view {}: pose not refined ({reason}); it is left out of the de-lighting",
                views[k].name
            ));
        }
        let rv = rotation_vector(rot3(to_world) * rot3(given[k]).transpose());
        let t = to_world.w_axis.truncate() - given[k].w_axis.truncate();
        out.push(ViewPose {
            view: views[k].name.clone(),
            to_world,
            rotation_deg: (rv * 180.0 / std::f64::consts::PI).to_array(),
            translation: t.to_array(),
            angle_deg: rv.length().to_degrees(),
            iterations: iterations[k],
            converged: f.as_ref().is_some_and(|f| f.converged),
            accepted,
            used: accepted,
            rms_before: f.as_ref().map_or(f64::NAN, |f| f.rms_before),
            rms_after: f.as_ref().map_or(f64::NAN, |f| f.rms_after),
            pixels: f.as_ref().map_or(0, |f| f.pixels),
            round_steps_px: steps_px[k].clone(),
            reason,
        });
    }
    if out.iter().all(|p| !p.used) {
        warnings.push("no view's pose could be refined: all views are used with their given poses".into());
        for p in &mut out {
            p.used = true;
        }
    }
    (PoseReport { mode: s.mode, views: out }, warnings)
}

/// The rigid motion of all views together (world: `x ↦ centre + R(ω)(x − centre) + t`; with
/// `full` false a rotation `ω` of each camera about its own position) that the geometric edges of
/// their predictions ask for: the Gauss–Newton step of the views' [`solve::EdgeSystem`]s
/// (camera frames) mapped to the common parameters. `None` without edges to pin it.
pub fn common_motion(
    views: &[(DMat4, solve::EdgeSystem)],
    centre: DVec3,
    full: bool,
) -> Option<CommonMotion> {
    use nalgebra::{DMatrix, DVector};
    let n = if full { 6 } else { 3 };
    let mut h = DMatrix::<f64>::zeros(n, n);
    let mut g = DVector::<f64>::zeros(n);
    for (m, e) in views {
        let rt = rot3(*m).transpose();
        let c = m.w_axis.truncate() - centre;
        // camera-frame (ω_c, δ_c) per common parameter: ω_c = Rᵀω, δ_c = Rᵀ(ω × c + t)
        let mut a = DMatrix::<f64>::zeros(6, n);
        for j in 0..3 {
            let mut w = DVec3::ZERO;
            w[j] = 1.0;
            let wc = rt * w;
            let dc = if full { rt * w.cross(c) } else { DVec3::ZERO };
            for i in 0..3 {
                a[(i, j)] = wc[i];
                a[(3 + i, j)] = dc[i];
                if full {
                    a[(3 + i, 3 + j)] = rt.col(j)[i];
                }
            }
        }
        let hk = DMatrix::<f64>::from_fn(6, 6, |i, j| e.h[i][j]);
        let gk = DVector::<f64>::from_column_slice(&e.g);
        h += a.transpose() * hk * &a;
        g += a.transpose() * gk;
    }
    let trace: f64 = (0..n).map(|i| h[(i, i)]).sum();
    if trace.is_nan() || trace <= 0.0 {
        return None;
    }
    for i in 0..n {
        h[(i, i)] += 1e-3 * h[(i, i)] + 1e-9 * trace;
    }
    let x = h.cholesky()?.solve(&(-g));
    let omega = DVec3::new(x[0], x[1], x[2]);
    let t = if full { DVec3::new(x[3], x[4], x[5]) } else { DVec3::ZERO };
    if !omega.is_finite() || !t.is_finite() {
        return None;
    }
    Some(CommonMotion { omega, t, centre, full })
}

/// A motion of all views together (see [`common_motion`]).
#[derive(Clone, Copy, Debug)]
pub struct CommonMotion {
    /// World rotation vector (radians).
    pub omega: DVec3,
    /// World translation (zero unless `full`).
    pub t: DVec3,
    /// Centre of the rotation when `full`.
    pub centre: DVec3,
    /// Rigid motion of the rig about `centre`; else each camera rotated about its own position.
    pub full: bool,
}

impl CommonMotion {
    /// The pose `m` moved.
    pub fn apply(&self, m: DMat4) -> DMat4 {
        let angle = self.omega.length();
        let r = if angle > 0.0 { DMat4::from_axis_angle(self.omega / angle, angle) } else { DMat4::IDENTITY };
        let c = if self.full { self.centre } else { m.w_axis.truncate() };
        DMat4::from_translation(c + self.t) * r * DMat4::from_translation(-c) * m
    }
}

/// Rotation angle (degrees) and camera distance between two poses.
fn solve_error(a: DMat4, b: DMat4) -> (f64, f64) {
    let rv = rotation_vector(rot3(b) * rot3(a).transpose());
    (rv.length().to_degrees(), (a.w_axis.truncate() - b.w_axis.truncate()).length())
}

/// Distance from view `k`'s camera to the scene's bounding-box centre (scale of the
/// translation bound).
fn scene_depth(views: &[View], k: usize, scene: &Scene) -> f64 {
    let (lo, hi) = scene.bounds();
    (views[k].camera.origin() - 0.5 * (lo + hi)).length() as f64
}

/// Why a fit is rejected, or `None` when it is accepted.
fn judge(f: &Alignment, given: DMat4, refined: DMat4, depth: f64, s: &PoseSettings) -> Option<String> {
    let (ang, dist) = solve_error(given, refined);
    if !f.converged {
        Some("the alignment did not converge".into())
    } else if f.pixels < 500 {
        Some(format!("too few predicted pixels ({})", f.pixels))
    } else if ang > s.max_rotation_deg {
        Some(format!("correction of {ang:.2}° exceeds {}°", s.max_rotation_deg))
    } else if dist > s.max_translation * depth {
        Some(format!("camera moved by {dist:.3e}, more than {} of its distance", s.max_translation))
    } else if f.rms_after.is_nan() || f.rms_after > 1.05 * f.rms_before {
        Some(format!("residual grew ({:.4} → {:.4})", f.rms_before, f.rms_after))
    } else {
        None
    }
}

/// The pipeline's stage: nothing with [`PoseRefinement::Off`]; else the report and the views
/// to use (refined cameras; the views whose correction was rejected left out).
pub(crate) fn pipeline_stage(
    scene: &Scene,
    objects: &[super::ObjectResult],
    views: &[View],
    s: &PoseSettings,
    log: &(dyn Fn(&str) + Sync),
    warnings: &mut Vec<String>,
) -> (Option<PoseReport>, Option<Vec<View>>) {
    if s.mode == PoseRefinement::Off {
        return (None, None);
    }
    let objs: Vec<(u32, &Atlas)> = objects.iter().map(|o| (o.shape as u32, &o.atlas)).collect();
    let (rep, w) = refine_poses(scene, &objs, views, s, log);
    warnings.extend(w);
    let used: Vec<View> =
        rep.apply(views).into_iter().zip(&rep.views).filter(|(_, p)| p.used).map(|(v, _)| v).collect();
    (Some(rep), Some(used))
}
