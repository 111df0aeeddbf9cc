//! Results of the de-lighting: per recovered object its atlas and maps ([`ObjectResult`]),
//! per iteration the error statistics ([`IterationStats`]), and the whole run
//! ([`DelightResult`]: objects, skipped objects, estimated view gains, warnings, stage timings).
//! Tests: `tests/delight.rs` (round trip through [`ObjectResult::mean_kd_observed`]).

use super::atlas::{Atlas, NO_TRI};
use super::footprint::ResolutionChoice;
use super::gains::ViewGains;
use super::to_image;
use opal::image::Image;

/// State and results of one recovered object.
#[derive(Clone, Debug)]
pub struct ObjectResult {
    /// Shape index in the scene.
    pub shape: usize,
    /// Shape id.
    pub id: String,
    /// Atlas (mesh with UVs, texel → surface).
    pub atlas: Atlas,
    /// How the atlas resolution was chosen, the pixel and texel densities of the best-seen part
    /// and the seen fraction of the surface.
    pub resolution: ResolutionChoice,
    /// Observed luminance per texel (inpainted in holes).
    pub l: Vec<[f32; 3]>,
    /// Whether a texel was seen by at least one view.
    pub observed: Vec<bool>,
    /// Direct irradiance per texel.
    pub ed: Vec<[f32; 3]>,
    /// Current indirect irradiance estimate per texel.
    pub ei: Vec<[f32; 3]>,
    /// Recovered albedo per texel (gutter dilated).
    pub kd: Vec<[f32; 3]>,
    /// Close to an emitter (median filter applied).
    pub near_emitter: bool,
    /// Fraction of covered texels seen by a view.
    pub seen_fraction: f64,
    /// Texels where `Kd` hit the upper bound 1 in the last update.
    pub clamped: usize,
    /// How the super-resolved luminance map was solved (steps, final residual); `None` when it
    /// was not (back-projection kept, or resumed from a checkpoint after it).
    pub superres: Option<super::superres::SrInfo>,
}

impl ObjectResult {
    /// Albedo texture as an image (row 0 = v 0, Mitsuba's convention).
    pub fn kd_image(&self) -> Image {
        to_image(&self.kd, self.atlas.width, self.atlas.height)
    }
    /// Mean albedo over the texels seen by a view, weighted by texel world area.
    pub fn mean_kd_observed(&self) -> [f64; 3] {
        let mut acc = [0f64; 3];
        let mut w = 0f64;
        for i in 0..self.kd.len() {
            let t = self.atlas.texel_tri[i];
            if t != NO_TRI && self.observed[i] {
                let a = self.atlas.texel_area[t as usize] as f64;
                for c in 0..3 {
                    acc[c] += a * self.kd[i][c] as f64;
                }
                w += a;
            }
        }
        acc.map(|v| v / w.max(1e-30))
    }
    /// Mean albedo over the covered texels, weighted by texel world area.
    pub fn mean_kd(&self) -> [f64; 3] {
        let mut acc = [0f64; 3];
        let mut w = 0f64;
        for i in 0..self.kd.len() {
            let t = self.atlas.texel_tri[i];
            if t != NO_TRI {
                let a = self.atlas.texel_area[t as usize] as f64;
                for c in 0..3 {
                    acc[c] += a * self.kd[i][c] as f64;
                }
                w += a;
            }
        }
        acc.map(|v| v / w.max(1e-30))
    }
}

/// Statistics of one iteration.
#[derive(Clone, Debug)]
pub struct IterationStats {
    /// Iteration number (1 = first light-tracing pass).
    pub iteration: usize,
    /// Max |relative error| over objects (inliers).
    pub max_rel_error: f64,
    /// Mean |relative error| (inliers, texel-count weighted).
    pub mean_rel_error: f64,
    /// Per object: (max, mean, outliers removed).
    pub per_object: Vec<(f64, f64, usize)>,
    /// Per object: relative luminance error per texel (NaN where not observed).
    pub error_maps: Vec<Vec<f32>>,
    /// Seconds of this iteration.
    pub seconds: f64,
    /// Light paths of this pass.
    pub light_paths: u64,
    /// Per object: achieved relative per-texel noise of the raw indirect irradiance
    /// ([`super::noise::texel_noise`]; NaN when no texel has indirect light).
    pub texel_noise: Vec<f64>,
    /// The same over the texels of all objects together.
    pub texel_noise_all: f64,
    /// Per object: mean of the tracer's direct irradiance / light-sampled `Ed` (consistency
    /// check of the two estimators; ≈ 1). Measured in the first iteration only (NaN after: the
    /// later passes do not deposit first hits).
    pub direct_ratio: Vec<f64>,
    /// Seconds this process spent in this pass's exchanges between processes: the light
    /// tracing's sums over the ranks, the per-object results and, in the first pass, the
    /// super-resolved maps (transfer and waiting for the other ranks; 0 alone).
    pub comm_seconds: f64,
    /// Largest |change| of a tile's mean irradiance this pass asked for (relative;
    /// [`super::convergence`]).
    pub change_max: f64,
    /// Largest change of a tile beyond what the pass's noise explains (the stop statistic,
    /// compared with the tolerance; NaN when no tile took part).
    pub change_beyond_noise: f64,
    /// Tiles that took part.
    pub change_regions: usize,
}

/// Result of [`delight`](super::delight).
#[derive(Clone, Debug)]
pub struct DelightResult {
    /// Recovered objects.
    pub objects: Vec<ObjectResult>,
    /// Objects that could not be recovered: (id, reason).
    pub skipped: Vec<(String, String)>,
    /// Shapes left out of the recovery and why (id, reason): emitters, shapes with a
    /// non-diffuse material (kept as given, part of the light transport), and with named
    /// objects the shapes not named.
    pub not_recovered: Vec<(String, String)>,
    /// Iterations.
    pub iterations: Vec<IterationStats>,
    /// A pass changed no tile by more than the tolerance beyond its noise
    /// ([`super::convergence`]).
    pub converged: bool,
    /// Estimated per-view gains (`None` with [`super::ViewGainMode::Fixed`]); the recovered
    /// albedos are those of the views divided by them.
    pub view_gains: Option<ViewGains>,
    /// Refined poses (`None` with [`super::PoseRefinement::Off`]): per view the refined camera,
    /// the correction and whether the view was used.
    pub poses: Option<super::pose::PoseReport>,
    /// Warnings (unseen objects, masked pixels, views whose gain is far from the others...).
    pub warnings: Vec<String>,
    /// Wall seconds per stage: (name, seconds).
    pub timings: Vec<(String, f64)>,
    /// CPU seconds (user + system of the whole process, all threads) per stage, same names as
    /// `timings` (NaN where `/proc/self/stat` is not available).
    pub cpu_timings: Vec<(String, f64)>,
    /// Per stage of `timings`: the process's resident memory at the stage's end and its peak so
    /// far, MB ([`rss_mb`](super::rss_mb); NaN where `/proc/self/status` is not available).
    pub memory_mb: Vec<(String, [f64; 2])>,
    /// Light paths traced in total (the unseen-light analysis included).
    pub light_paths: u64,
    /// Per recovered object (same order as `objects`): the part of its light that arrived via
    /// texels no view observed and how far their fill can move its albedo
    /// ([`super::unseen`]); empty when the analysis was skipped.
    pub unseen_light: Vec<super::UnseenLight>,
}
