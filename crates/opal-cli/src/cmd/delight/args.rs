//! The command line of `opal delight`: its arguments, the diagnostic switches and what they
//! map to in `opal_inverse::delight`.

use super::CHECKPOINT;
use crate::util;
use anyhow::{Context, Result, bail};
use clap::Args;
use opal_inverse::delight::{
    DelightSettings, LightPaths, PoseRefinement, PoseSettings, UpdateRule, ViewGainMode, ViewGainSettings,
};
use std::path::PathBuf;

/// Arguments of `opal delight`.
#[derive(Args, Debug, Clone)]
pub struct DelightArgs {
    /// Mitsuba 3 XML scene (geometry, emitters; BSDFs of the recovered objects are ignored).
    #[arg(long)]
    pub scene: PathBuf,
    /// NeRF-style transforms.json (OpenGL camera-to-world, camera_angle_x, file_path), or a
    /// COLMAP text model directory (cameras.txt, images.txt; images in DIR/images, DIR/../images
    /// or DIR; distorted photos are resampled onto ideal pinholes).
    #[arg(long)]
    pub views: PathBuf,
    /// Output folder.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Shapes to recover, comma-separated ids (default: every non-emitting shape).
    #[arg(long, value_delimiter = ',')]
    pub objects: Option<Vec<String>>,
    /// Maximum number of light-tracing iterations.
    #[arg(long, default_value_t = 5)]
    pub iterations: usize,
    /// Stop once a pass changes no tile of an object's irradiance by more than this (relative)
    /// beyond what the pass's own noise explains (report.json `converged`); 0 runs every pass.
    #[arg(long, default_value_t = 0.01)]
    pub tolerance: f64,
    /// Light paths per light-tracing pass: `auto` (from the texel count and `--target-noise`) or
    /// a number.
    #[arg(long, default_value = "auto")]
    pub light_paths: String,
    /// Target relative per-texel noise of the light-traced indirect irradiance for
    /// `--light-paths auto` (default 0.207: about 20 M paths on the reference Cornell box).
    #[arg(long)]
    pub target_noise: Option<f64>,
    /// Texture resolution: `auto` (from the cameras' pixel footprints: texels over the best-seen
    /// part at least as dense as its pixels, 256 to `--max-resolution`) or a number.
    #[arg(long, default_value = "auto")]
    pub resolution: String,
    /// Upper clamp of `--resolution auto`: 4096 (default) up to 8192.
    #[arg(long, default_value_t = 4096)]
    pub max_resolution: usize,
    /// Work from views of at most this many pixels; 0 = the photos as they are; default: an
    /// automatic working size (the views box-filtered to where the texture resolution from the
    /// pixels fits the texels that 20 M light paths per pass serve at the target noise, at least
    /// 256² pixels; docs/delight.md "Photo resolution"). A larger photo is box-filtered onto a
    /// coarser film of the same frustum as it is read (only one full-size photo is in memory at
    /// a time). The texture resolution follows the coarse pixels; photos and re-renders are
    /// compared at the coarse size.
    #[arg(long)]
    pub max_view_pixels: Option<usize>,
    /// Unwrap every object even when its own UVs are usable.
    #[arg(long)]
    pub unwrap_all: bool,
    /// Update rule of the indirect irradiance: `fixed` (relaxed fixed point) or `paper`.
    #[arg(long, default_value = "fixed")]
    pub update: String,
    /// Samples per pixel of the re-renders (0 = no re-render).
    #[arg(long, default_value_t = 64)]
    pub rerender_spp: u32,
    /// Target relative standard error of each judged region's re-rendered mean luminance: a view
    /// whose noisiest region (≥ 64 pixels) is above it after `--rerender-spp` samples gets more,
    /// up to 16 × `--rerender-spp` (0 = `--rerender-spp` only).
    #[arg(long, default_value_t = 0.004)]
    pub rerender_noise: f64,
    /// Luminance maps: `superres` (all views inverted jointly with a total-variation prior,
    /// sharper than the pixels) or `backproject` (each texel samples each view).
    #[arg(long, default_value = "superres")]
    pub luminance: String,
    /// Edge-prior weight λ of `--luminance superres` (units of the mean radiance; default 0.004
    /// with the default exponent 0.5, chosen on simulated views with the reference photos' noise:
    /// docs/delight.md step 3).
    #[arg(long)]
    pub tv_lambda: Option<f32>,
    /// Exponent p of the edge prior `(|∇B|² + ε²)^{p/2}` of `--luminance superres`: 1 = total
    /// variation (the earlier default, then use `--tv-lambda 0.0067`), default 0.5.
    #[arg(long)]
    pub tv_exponent: Option<f32>,
    /// Per-view photometric gains estimated from the overlap of the views: `fixed` (the views
    /// are exact), `exposure` (one factor per view) or `exposure+wb` (one per view and channel).
    /// Scale convention: the median view is exact.
    #[arg(long, default_value = "fixed")]
    pub view_gains: String,
    /// Warn about (and flag) a view whose estimated gain differs from the median view's by more
    /// than this factor.
    #[arg(long, default_value_t = 1.5)]
    pub gain_warn_ratio: f64,
    /// Refine each view's pose by aligning its photo with the other views' maps before the
    /// de-lighting: `off` (poses exact), `rotation` or `full` (rotation and translation). The
    /// refined poses are written to OUTPUT/transforms.json, the corrections to report.json.
    #[arg(long, default_value = "off")]
    pub refine_poses: String,
    /// Continue an interrupted run from OUTPUT/checkpoint (written after every finished
    /// iteration): either the same arguments as that run plus `--resume`, or `opal delight
    /// --resume OUTPUT` alone (the run's arguments and working directory are read from
    /// OUTPUT/checkpoint/args.json). The result is the same, bit for bit, as an uninterrupted
    /// run's; a checkpoint made from other inputs or settings is refused.
    #[arg(long)]
    pub resume: bool,
    /// Seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Print report.json on stdout.
    #[arg(long)]
    pub json: bool,
    /// Error-analysis outputs (all off by default; no effect on the results).
    #[command(flatten)]
    pub diagnostics: DiagnosticArgs,
}

/// Error-analysis switches of `opal delight` (used by `bench/scripts/delight_psnr_budget.py`);
/// they map to `opal_inverse::delight::DebugSettings` and
/// `opal_inverse::delight::superres::SrDiagnostics`.
#[derive(Args, Debug, Clone, Default)]
#[command(next_help_heading = "Diagnostics (error analysis)")]
pub struct DiagnosticArgs {
    /// Log per object and iteration the mean observed L, Ed, Ei, Kd and the clamped texels.
    #[arg(long)]
    pub debug_log: bool,
    /// Write per object the final luminance, observed mask, Ed, Ei and albedo maps as EXR
    /// (`<id>_final_<what>.exr`) into this directory.
    #[arg(long, value_name = "DIR")]
    pub debug_dump: Option<PathBuf>,
    /// Irradiance map (EXR on the atlas grid, e.g. the true one) used as the shading of the
    /// super-resolution instead of the estimate.
    #[arg(long, value_name = "EXR")]
    pub sr_shading: Option<PathBuf>,
    /// Radiance map (EXR on the atlas grid) whose super-resolution operator residual against each
    /// photo is printed (with `--sr-residual-dir`).
    #[arg(long, value_name = "EXR")]
    pub sr_truth: Option<PathBuf>,
    /// Directory of the per-view residual images of `--sr-truth`.
    #[arg(long, value_name = "DIR")]
    pub sr_residual_dir: Option<PathBuf>,
    /// Replace the photos by `--sr-truth` through the operator plus noise: `stderr`,
    /// `stderrcorr`, a relative level such as `0.02`, `shuffle`, `relshuffle`, `clipK`.
    #[arg(long, value_name = "MODE")]
    pub sr_synth: Option<String>,
    /// Sub-pixel rays per axis of the synthetic photos of `--sr-synth` (0 = those of the solve).
    #[arg(long, default_value_t = 0, value_name = "N")]
    pub sr_synth_subsamples: u32,
    /// Print the super-resolution residual every 10 steps.
    #[arg(long)]
    pub sr_trace: bool,
}

/// Debug outputs of the de-lighting from the diagnostic switches (error-analysis hooks of
/// `bench/scripts/delight_psnr_budget.py`).
fn debug_settings(d: &DiagnosticArgs) -> opal_inverse::delight::DebugSettings {
    opal_inverse::delight::DebugSettings {
        print: d.debug_log,
        dump_dir: d.debug_dump.clone(),
        shading: d.sr_shading.clone(),
    }
}

/// Error-analysis hooks of the super-resolution from the diagnostic switches (see
/// `opal_inverse::delight::superres::SrDiagnostics`).
fn sr_diagnostics(d: &DiagnosticArgs) -> opal_inverse::delight::superres::SrDiagnostics {
    opal_inverse::delight::superres::SrDiagnostics {
        truth: d.sr_truth.clone(),
        residual_dir: d.sr_residual_dir.clone(),
        synth: d.sr_synth.clone(),
        synth_subsamples: d.sr_synth_subsamples,
        trace: d.sr_trace,
    }
}

/// The de-lighting settings of the arguments (values checked; errors name the flag).
pub(super) fn settings_from_args(a: &DelightArgs) -> Result<DelightSettings> {
    let resolution = if a.resolution == "auto" {
        None
    } else {
        let r: usize = a
            .resolution
            .parse()
            .with_context(|| format!("--resolution: expected 'auto' or a number, got '{}'", a.resolution))?;
        if !(4..=8192).contains(&r) {
            bail!("--resolution {r}: must be in 4..=8192");
        }
        Some(r)
    };
    let update = match a.update.as_str() {
        "fixed" => UpdateRule::FixedPoint,
        "paper" => UpdateRule::Paper { alpha0: 2.0 },
        u => bail!("--update: expected 'fixed' or 'paper', got '{u}'"),
    };
    if !(256..=8192).contains(&a.max_resolution) {
        bail!("--max-resolution {}: must be in 256..=8192", a.max_resolution);
    }
    let light_paths = match a.light_paths.as_str() {
        "auto" => {
            let t = a.target_noise.unwrap_or(opal_inverse::delight::noise::DEFAULT_TARGET_NOISE);
            if !(t.is_finite() && t > 0.0) {
                bail!("--target-noise must be a number > 0, got {t}");
            }
            LightPaths::TargetNoise(t)
        }
        n => {
            let n: u64 = n
                .parse()
                .with_context(|| format!("--light-paths: expected 'auto' or a number, got '{n}'"))?;
            if n == 0 {
                bail!("--light-paths must be at least 1");
            }
            if a.target_noise.is_some() {
                bail!("--target-noise applies to --light-paths auto only");
            }
            LightPaths::Fixed(n)
        }
    };
    let superres = match a.luminance.as_str() {
        "superres" => {
            let mut sr = opal_inverse::delight::superres::SrSettings {
                diagnostics: sr_diagnostics(&a.diagnostics),
                ..Default::default()
            };
            if let Some(l) = a.tv_lambda {
                if !(l.is_finite() && l >= 0.0) {
                    bail!("--tv-lambda must be a finite number ≥ 0, got {l}");
                }
                sr.lambda = l;
            }
            if let Some(p) = a.tv_exponent {
                if !(p.is_finite() && p > 0.0 && p <= 2.0) {
                    bail!("--tv-exponent must be in (0, 2], got {p}");
                }
                sr.exponent = p;
            }
            Some(sr)
        }
        "backproject" => None,
        other => bail!("--luminance must be superres or backproject, got '{other}'"),
    };
    let mode = match a.view_gains.as_str() {
        "fixed" => ViewGainMode::Fixed,
        "exposure" => ViewGainMode::Exposure,
        "exposure+wb" => ViewGainMode::ExposureWb,
        other => bail!("--view-gains must be fixed, exposure or exposure+wb, got '{other}'"),
    };
    if !(a.gain_warn_ratio.is_finite() && a.gain_warn_ratio > 1.0) {
        bail!("--gain-warn-ratio must be a number > 1, got {}", a.gain_warn_ratio);
    }
    let pose_mode = match a.refine_poses.as_str() {
        "off" => PoseRefinement::Off,
        "rotation" => PoseRefinement::Rotation,
        "full" => PoseRefinement::Full,
        other => bail!("--refine-poses must be off, rotation or full, got '{other}'"),
    };
    let settings = DelightSettings {
        poses: PoseSettings { mode: pose_mode, ..Default::default() },
        objects: a.objects.clone(),
        iterations: a.iterations,
        tolerance: a.tolerance,
        light_paths,
        resolution,
        max_resolution: a.max_resolution,
        max_view_pixels: a.max_view_pixels.filter(|&m| m > 0),
        seed: a.seed,
        keep_uvs: !a.unwrap_all,
        update,
        superres,
        view_gains: ViewGainSettings { mode, warn_ratio: a.gain_warn_ratio },
        debug: debug_settings(&a.diagnostics),
        checkpoint: Some(a.output.join(CHECKPOINT)),
        resume: a.resume,
        cancel: Some(util::interrupt_flag()),
        // under MPI: every pass's light paths split across the ranks (same bits)
        comm: crate::dist::comm(),
        // a bar per stage on a terminal (rank 0's only under MPI)
        progress: crate::dist::is_root()
            .then(|| opal_inverse::delight::Progress::new(util::stage_progress())),
        ..Default::default()
    };
    // under MPI only rank 0 writes: the other ranks keep no checkpoint and no debug files
    Ok(if crate::dist::is_root() {
        settings
    } else {
        DelightSettings { checkpoint: None, debug: Default::default(), ..settings }
    })
}
