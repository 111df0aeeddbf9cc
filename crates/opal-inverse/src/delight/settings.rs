//! Settings of the de-lighting ([`DelightSettings`]): iterations and tolerance, light paths
//! ([`LightPaths`]),
//! atlas resolution, direct-irradiance sampling, the indirect update rule ([`UpdateRule`]), the
//! super-resolution settings, the per-view gains ([`ViewGainSettings`]) and the debug outputs ([`DebugSettings`], off by default).
//! Tests: `tests/delight.rs` and the CLI's `opal delight` tests (through [`super::delight`]).

use super::gains::ViewGainSettings;
use super::superres;

/// How the indirect irradiance is updated between light-tracing passes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum UpdateRule {
    /// `Ei ← Ei_render` (fixed point of `Kd = πL/(Ed + Ei(Kd))`).
    FixedPoint,
    /// The paper's gradient step with `α_k = alpha0 / (1 + k)`.
    Paper {
        /// Initial step α₀ (the paper: 2).
        alpha0: f32,
    },
}

/// Light paths per light-tracing pass.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LightPaths {
    /// This many paths per pass.
    Fixed(u64),
    /// From the texel count of the recovered objects and this relative per-texel noise of the
    /// raw indirect irradiance ([`super::noise::paths_for_noise`]).
    TargetNoise(f64),
}

impl LightPaths {
    /// Paths per pass for `texels` texels.
    pub fn paths(self, texels: usize) -> u64 {
        match self {
            LightPaths::Fixed(n) => n,
            LightPaths::TargetNoise(t) => super::noise::paths_for_noise(texels, t),
        }
    }
}

/// Settings of [`delight`](super::delight).
#[derive(Clone, Debug)]
pub struct DelightSettings {
    /// Shapes to recover (ids); `None` = every non-emitting shape.
    pub objects: Option<Vec<String>>,
    /// Maximum number of light-tracing iterations.
    pub iterations: usize,
    /// Stop once a pass changes no tile of any object's irradiance (and so albedo) by more than
    /// this beyond what the pass's Monte-Carlo noise explains ([`super::convergence`]; relative).
    /// 0: every pass runs (the statistic is never below 0).
    pub tolerance: f64,
    /// Light paths per light-tracing pass: fixed, or from the texel count and a target noise
    /// ([`super::noise`]).
    pub light_paths: LightPaths,
    /// Texture resolution (square); `None` = the size of the object's existing square bitmap
    /// texture when its UVs are kept, else from the cameras' pixel footprints
    /// ([`footprint`](super::footprint), 256…`max_resolution`).
    pub resolution: Option<usize>,
    /// Upper clamp of the resolution from the cameras: 4096 by default, up to
    /// [`LARGEST_RESOLUTION`](super::footprint::LARGEST_RESOLUTION) (8192) on request.
    pub max_resolution: usize,
    /// Work from views of at most this many pixels: larger views are box-filtered onto a
    /// coarser film of the same frustum first ([`super::downsample`]); everything after (texture
    /// resolution from the pixel footprints, luminance maps, super-resolution) sees the coarse
    /// views. `None` = the views as given.
    pub max_view_pixels: Option<usize>,
    /// Seed.
    pub seed: u64,
    /// Keep usable existing UVs.
    pub keep_uvs: bool,
    /// Light samples per texel for the direct irradiance.
    pub direct_samples: u32,
    /// Pilot light samples per texel of the adaptive direct irradiance (0 = every texel gets
    /// `direct_samples`); see [`direct_irradiance`](super::direct_irradiance).
    pub direct_pilot: u32,
    /// Initial indirect share of the direct irradiance (used when `gather_rays` is 0).
    pub indirect_share: f32,
    /// Rays per gather texel of the initial indirect irradiance gathered from the luminance
    /// maps ([`super::gather`]); 0 = start from `indirect_share` × `Ed` instead.
    pub gather_rays: u32,
    /// Update rule of the indirect irradiance.
    pub update: UpdateRule,
    /// Smoothing radius (texels) of the rendered indirect irradiance; `None` = resolution/64.
    pub smooth: Option<usize>,
    /// Multi-view super-resolved luminance maps ([`superres`]); `None` = back-projection only.
    pub superres: Option<superres::SrSettings>,
    /// Per-view photometric gains (exposure, white balance) estimated from the overlap of the
    /// views; default: none (the views are exact).
    pub view_gains: ViewGainSettings,
    /// Per-view pose refinement ([`super::pose`]); default: off (the poses are exact).
    pub poses: super::pose::PoseSettings,
    /// Debug and error-analysis outputs (all off by default).
    pub debug: DebugSettings,
    /// Folder in which the state after each finished iteration is saved (`None`: no
    /// checkpoints): the luminance, indirect irradiance and albedo maps and the statistics.
    pub checkpoint: Option<std::path::PathBuf>,
    /// Continue from the checkpoint in `checkpoint` instead of starting the iterations anew.
    pub resume: bool,
    /// Set (e.g. by a signal handler) to stop at the next stage or iteration boundary: the run
    /// then returns [`opal::error::Error::Interrupted`], saying which iterations the checkpoint
    /// keeps.
    pub cancel: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>,
    /// Processes that share the work: the light paths of every light-tracing pass
    /// ([`opal::integrator::light_tracer::trace_split`]), the texels of the direct irradiance
    /// and of the gathering, and the objects of the super-resolution, of each pass's
    /// post-processing and of the initial albedo; every rank ends each stage with the
    /// one-process result bit for bit, so all ranks run the same de-lighting. `None`: this
    /// process alone. Unwrapping, view gains and luminance maps run in full on every rank.
    pub comm: Option<std::sync::Arc<dyn opal::dist::Comm>>,
    /// Called with `(stage, done, total)` as the long stages advance ([`super::progress`]);
    /// `None`: no reports.
    pub progress: Option<super::Progress>,
    /// Light paths of each of the three passes of the unseen-light analysis
    /// ([`super::unseen`]) as a fraction of an iteration's paths; 0 skips it. Default 0.25.
    pub unseen_light_paths: f64,
}

/// Debug and error-analysis outputs of [`delight`](super::delight); [`Default`] = all off (no
/// effect on the results).
#[derive(Clone, Debug, Default)]
pub struct DebugSettings {
    /// Log per object and iteration the mean observed `L`, `Ed`, `Ei`, `Kd` and the number of
    /// clamped texels.
    pub print: bool,
    /// Write per object the luminance map, observed mask, direct and indirect irradiance and
    /// albedo as EXR files (`<id>_final_<what>.exr`) into this directory at the end.
    pub dump_dir: Option<std::path::PathBuf>,
    /// Error analysis: an irradiance map (EXR on the atlas grid, e.g. the true one) used as the
    /// shading of the super-resolution instead of the estimate `Ed + Ei` (ignored when it cannot
    /// be read or its size differs from the atlas).
    pub shading: Option<std::path::PathBuf>,
}

impl Default for DelightSettings {
    fn default() -> Self {
        DelightSettings {
            objects: None,
            iterations: 5,
            tolerance: 0.01,
            light_paths: LightPaths::TargetNoise(super::noise::DEFAULT_TARGET_NOISE),
            resolution: None,
            max_resolution: super::footprint::MAX_RESOLUTION,
            max_view_pixels: None,
            seed: 0,
            keep_uvs: true,
            direct_samples: 64,
            direct_pilot: 16,
            indirect_share: 0.5,
            gather_rays: 64,
            update: UpdateRule::FixedPoint,
            smooth: None,
            superres: Some(superres::SrSettings::default()),
            view_gains: ViewGainSettings::default(),
            poses: super::pose::PoseSettings::default(),
            debug: DebugSettings::default(),
            checkpoint: None,
            resume: false,
            cancel: None,
            comm: None,
            progress: None,
            unseen_light_paths: 0.25,
        }
    }
}
