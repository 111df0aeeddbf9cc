//! `opal delight`: recovers diffuse albedo textures from multi-view HDR images (method C, see
//! `opal_inverse::delight`) and writes textures, meshes with UVs, a Mitsuba 3 scene using them,
//! a glTF 2.0 binary of the recovered objects (`scene.glb`, see `crate::glb`), error maps, a
//! convergence plot, re-renders and report.json / report.html.

mod contact;
mod html;
mod object_files;
mod rerender;
pub mod resume;

use crate::util;
use anyhow::{Context, Result, bail};
use clap::Args;
use opal::image::Image;
use opal::integrator::path::{PathSettings, render};
use opal::scene::Scene;
use opal::scene::desc::SceneDesc;
use opal_inverse::delight::views::{View, read_views_limited};
use opal_inverse::delight::{
    DelightResult, DelightSettings, LightPaths, ObjectResult, PoseRefinement, PoseSettings, StageClock,
    UpdateRule, ViewGainMode, ViewGainSettings, apply_view_gains, delight,
};
use serde_json::json;
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};

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

fn exr(path: &Path, img: &Image) -> Result<()> {
    util::write_atomic(path, |f| Ok(opal::image::write::write_exr(img, std::io::BufWriter::new(f))?))
}

fn png(path: &Path, img: &Image, exposure: f32) -> Result<()> {
    util::write_atomic(path, |f| {
        Ok(opal::image::write::write_png_srgb(img, exposure, std::io::BufWriter::new(f))?)
    })
}

/// OBJ text of an object's atlas mesh (OBJ `vt` has v = 0 at the bottom: v_obj = 1 − v).
fn obj_text(o: &ObjectResult) -> String {
    let m = &o.atlas.mesh;
    let mut s = format!("# opal delight: {} with atlas UVs ({}x{})\n", o.id, o.atlas.width, o.atlas.height);
    for p in &m.positions {
        let _ = writeln!(s, "v {} {} {}", p.x, p.y, p.z);
    }
    for uv in &m.uvs {
        let _ = writeln!(s, "vt {} {}", uv.x, 1.0 - uv.y);
    }
    for n in &m.normals {
        let _ = writeln!(s, "vn {} {} {}", n.x, n.y, n.z);
    }
    for t in &m.indices {
        let [a, b, c] = t.map(|i| i + 1);
        if m.normals.is_empty() {
            let _ = writeln!(s, "f {a}/{a} {b}/{b} {c}/{c}");
        } else {
            let _ = writeln!(s, "f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}");
        }
    }
    s
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('"', "&quot;").replace('<', "&lt;").replace('>', "&gt;")
}

/// The input scene text with every recovered shape replaced by an OBJ shape with a diffuse
/// bitmap BSDF, and every other relative `filename` made absolute (the new file lives elsewhere).
fn rewrite_scene(text: &str, scene_dir: &Path, objects: &[ObjectResult], desc: &SceneDesc) -> Result<String> {
    let doc = roxmltree::Document::parse(text).context("cannot re-parse the scene for rewriting")?;
    let shapes: Vec<roxmltree::Node> = doc.descendants().filter(|n| n.has_tag_name("shape")).collect();
    let mut edits: Vec<(std::ops::Range<usize>, String)> = Vec::new();
    let mut replaced = Vec::new();
    for o in objects {
        let node = shapes
            .iter()
            .find(|n| n.attribute("id") == Some(o.id.as_str()))
            .or_else(|| if shapes.len() == desc.shapes.len() { shapes.get(o.shape) } else { None })
            .with_context(|| format!("cannot find shape '{}' in the scene file", o.id))?;
        let face = if o.atlas.mesh.normals.is_empty() {
            "\n        <boolean name=\"face_normals\" value=\"true\"/>"
        } else {
            ""
        };
        let new = format!(
            "<shape type=\"obj\" id=\"{id}\">\n        <string name=\"filename\" value=\"meshes/{id}.obj\"/>{face}\n        <bsdf type=\"diffuse\">\n            <texture type=\"bitmap\" name=\"reflectance\">\n                <string name=\"filename\" value=\"albedo/{id}.exr\"/>\n                <string name=\"filter_type\" value=\"bilinear\"/>\n                <string name=\"wrap_mode\" value=\"clamp\"/>\n                <boolean name=\"raw\" value=\"true\"/>\n            </texture>\n        </bsdf>\n    </shape>",
            id = xml_escape(&o.id)
        );
        replaced.push(node.range());
        edits.push((node.range(), new));
    }
    for n in doc.descendants().filter(|n| n.has_tag_name("string") && n.attribute("name") == Some("filename"))
    {
        if replaced.iter().any(|r| r.start <= n.range().start && n.range().end <= r.end) {
            continue;
        }
        let v = n.attribute("value").unwrap_or("");
        if v.starts_with('$') || Path::new(v).is_absolute() {
            continue;
        }
        let abs = std::fs::canonicalize(scene_dir.join(v)).unwrap_or_else(|_| scene_dir.join(v));
        edits.push((
            n.range(),
            format!("<string name=\"filename\" value=\"{}\"/>", xml_escape(&abs.to_string_lossy())),
        ));
    }
    edits.sort_by_key(|e| std::cmp::Reverse(e.0.start));
    let mut out = text.to_string();
    for (r, s) in edits {
        out.replace_range(r, &s);
    }
    Ok(out)
}

fn finite_or_null(x: f64) -> serde_json::Value {
    if x.is_finite() { json!(x) } else { json!(null) }
}

/// Folder (inside the output folder) of the checkpoints of an unfinished run.
pub const CHECKPOINT: &str = "checkpoint";

/// Runs the whole de-lighting with outputs; returns the report.
pub fn run_pipeline(a: &DelightArgs, log: &(dyn Fn(&str) + Sync)) -> Result<serde_json::Value> {
    let desc = opal::scene::load::load_mitsuba_xml(&a.scene, &[])
        .with_context(|| format!("cannot load the scene {}", a.scene.display()))?;
    for w in &desc.warnings {
        log(&format!("warning: {w}"));
    }
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
    let settings = if crate::dist::is_root() {
        settings
    } else {
        DelightSettings { checkpoint: None, debug: Default::default(), ..settings }
    };
    let t_read = StageClock::start();
    let (views, vwarn, mut working) = read_working_views(a, &desc, &settings, log)?;
    working.read = (t_read.elapsed(), opal_inverse::delight::rss_mb());
    for w in &vwarn {
        log(&format!("warning: {w}"));
    }
    let settings = DelightSettings { max_view_pixels: working.limit, ..settings };
    let r = delight(&desc, &views, &settings, log)?;
    for w in &r.warnings {
        log(&format!("warning: {w}"));
    }
    // photos and re-renders are compared at the refined poses
    let views = match &r.poses {
        Some(p) => {
            if crate::dist::is_root() {
                std::fs::create_dir_all(&a.output)?;
            }
            let tj = p.transforms_json(&views);
            util::write_bytes_atomic(
                &a.output.join("transforms.json"),
                serde_json::to_string_pretty(&tj)?.as_bytes(),
            )?;
            let refined = p.apply(&views);
            // one copy of the views at a time
            drop(views);
            refined
        }
        None => views,
    };
    // photos and re-renders are compared on the views divided by their estimated gains
    let views = match &r.view_gains {
        Some(g) => {
            let divided = apply_view_gains(&views, g);
            drop(views);
            divided
        }
        None => views,
    };
    write_outputs(a, &desc, &views, &r, &vwarn, &working, log)
}

/// The working size of the views and why (report.json `working_size`).
pub struct Working {
    /// Per-view pixel limit (`None`: the photos as they are).
    pub limit: Option<usize>,
    /// The photos' own sizes.
    pub photo_sizes: Vec<[usize; 2]>,
    /// The report entry.
    pub json: serde_json::Value,
    /// Reading the views: (wall, CPU) seconds and the resident memory (now, peak) in MB after.
    pub read: ((f64, f64), (f64, f64)),
}

/// Reads the views at their working size: `--max-view-pixels N` (0 = as they are), else the
/// automatic size from the cameras (read before any image; `opal_inverse::delight::working_size`).
/// Each photo is box-filtered as it is read (a COLMAP model's photos after their resampling),
/// so one photo at full size is held at a time.
fn read_working_views(
    a: &DelightArgs,
    desc: &SceneDesc,
    s: &DelightSettings,
    log: &(dyn Fn(&str) + Sync),
) -> Result<(Vec<View>, Vec<String>, Working)> {
    use opal_inverse::delight::working_size::auto_working_size;
    let auto = |cams: &[opal::camera::Camera]| -> Result<(Option<usize>, serde_json::Value)> {
        let w = auto_working_size(desc, cams, s)?;
        log(&format!(
            "working size of the views: {} ({}; estimated texels {:.0} at full size, {:.0} at the working size, budget {:.0})",
            w.max_view_pixels.map_or("the photos as they are".into(), |m| format!("at most {m} pixels")),
            w.reason.replace('_', " "),
            w.texels_full,
            w.texels_working,
            w.texel_budget
        ));
        Ok((
            w.max_view_pixels,
            json!({
                "rule": "auto", "max_view_pixels": w.max_view_pixels, "reason": w.reason,
                "texel_budget": w.texel_budget, "texels_estimated_full_size": w.texels_full,
                "texels_estimated_working_size": w.texels_working,
                "min_working_pixels": opal_inverse::delight::working_size::MIN_WORKING_PIXELS,
            }),
        ))
    };
    let given = |m: usize| {
        let limit = (m > 0).then_some(m);
        (
            limit,
            json!({"rule": if m > 0 { "setting" } else { "full_size_on_request" }, "max_view_pixels": limit}),
        )
    };
    let (views, vwarn, limit, photo_sizes, wjson) = if a.views.is_dir() {
        // a COLMAP text model (cameras.txt, images.txt); images beside it or in ../images
        let images = [a.views.join("images"), a.views.join("../images")]
            .into_iter()
            .find(|d| d.is_dir())
            .unwrap_or_else(|| a.views.clone());
        use opal_inverse::delight::colmap::{colmap_views, read_colmap_frames};
        let context = || format!("cannot read the COLMAP model {}", a.views.display());
        let frames = read_colmap_frames(&a.views, &images).with_context(context)?;
        let sizes: Vec<[usize; 2]> =
            frames.iter().map(|f| [f.intrinsics.width, f.intrinsics.height]).collect();
        let (limit, j) = match a.max_view_pixels {
            Some(m) => given(m),
            None => auto(&frames.iter().map(|f| f.camera.clone()).collect::<Vec<_>>())?,
        };
        let (v, w) = colmap_views(frames, limit, s.progress.as_ref()).with_context(context)?;
        (v, w, limit, sizes, j)
    } else {
        let frames = opal_inverse::delight::views::read_frames(&a.views)
            .with_context(|| format!("cannot read the views {}", a.views.display()))?;
        let sizes: Vec<[usize; 2]> = frames.iter().map(|f| [f.sensor.width, f.sensor.height]).collect();
        let (limit, j) = match a.max_view_pixels {
            Some(m) => given(m),
            None => auto(&frames.iter().map(|f| opal::camera::Camera::new(&f.sensor)).collect::<Vec<_>>())?,
        };
        let (v, w) = read_views_limited(&a.views, limit, s.progress.as_ref())
            .with_context(|| format!("cannot read the views {}", a.views.display()))?;
        (v, w, limit, sizes, j)
    };
    Ok((views, vwarn, Working { limit, photo_sizes, json: wjson, read: ((0.0, 0.0), (0.0, 0.0)) }))
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

fn write_outputs(
    a: &DelightArgs,
    desc: &SceneDesc,
    views: &[View],
    r: &DelightResult,
    vwarn: &[String],
    working: &Working,
    log: &(dyn Fn(&str) + Sync),
) -> Result<serde_json::Value> {
    let out = &a.output;
    let t0 = StageClock::start();
    // textures, meshes, error maps (under MPI encoded by all ranks, written by rank 0); the
    // albedo PNGs (8-bit sRGB) are encoded once: albedo/<obj>.png and the glTF textures
    let albedo_png = object_files::write_object_files(r, out)?;
    let mut objs = Vec::new();
    for (j, o) in r.objects.iter().enumerate() {
        let m = o.mean_kd_observed();
        let finite = |v: [f64; 3]| v.map(|x| x.is_finite().then_some(x));
        let unseen = r.unseen_light.get(j).map(|u| {
            json!({
                "unseen_texels": u.unseen_texels,
                "share": u.share,
                "fill_uncertainty": finite(u.fill_uncertainty),
                "albedo_shift": u.albedo_shift,
                "albedo_noise": finite(u.albedo_noise),
            })
        });
        objs.push(json!({
            "id": o.id,
            "resolution": [o.atlas.width, o.atlas.height],
            "resolution_rule": o.resolution.rule.name(),
            "resolution_from_cameras_unclamped": o.resolution.unclamped,
            "pixel_density_best_seen": o.resolution.pixel_density,
            "texel_density_best_seen": o.resolution.texel_density,
            "seen_area_fraction": o.resolution.seen_area_fraction,
            "charts": o.atlas.charts,
            "kept_uvs": o.atlas.kept_uvs,
            "seen_fraction": o.seen_fraction,
            "seen_by_a_view": o.seen_fraction > 0.0,
            "recovered_from_inpainting_only": o.seen_fraction == 0.0,
            "near_emitter_median_filter": o.near_emitter,
            "mean_albedo_seen": m,
            "mean_albedo": o.mean_kd(),
            "clamped_texel_channels": o.clamped,
            "superres": o.superres.map(|i| json!({
                "reweightings": i.reweightings,
                "cg_steps": i.cg_steps,
                "residual_to_noise": i.residual_to_noise,
                "relative_residual": i.relative_residual,
                "converged": i.converged,
                "photo_noise": i.photo_noise,
                "prior_weight": i.lambda,
            })),
            "unseen_light": unseen,
            "texture": format!("albedo/{}.exr", o.id),
            "mesh": format!("meshes/{}.obj", o.id),
            "last_error_map": r.iterations.last().map(|it| format!("errors/iter_{:02}_{}.png", it.iteration, o.id)),
        }));
    }
    // scene.xml
    let text =
        std::fs::read_to_string(&a.scene).with_context(|| format!("cannot read {}", a.scene.display()))?;
    let scene_dir = a.scene.parent().unwrap_or(Path::new("."));
    let new_xml = rewrite_scene(&text, scene_dir, &r.objects, desc)?;
    util::write_bytes_atomic(&out.join("scene.xml"), new_xml.as_bytes())?;
    // scene.glb: the recovered objects with their albedo textures (glTF 2.0 binary)
    let glb_objects: Vec<crate::glb::GlbObject> = r
        .objects
        .iter()
        .zip(&albedo_png)
        .map(|(o, p)| crate::glb::GlbObject { name: &o.id, mesh: &o.atlas.mesh, base_colour_png: p })
        .collect();
    let generator = format!("opal delight {}", env!("CARGO_PKG_VERSION"));
    if crate::dist::is_root() {
        // (the other ranks have no PNGs)
        util::write_bytes_atomic(&out.join("scene.glb"), &crate::glb::glb_bytes(&glb_objects, &generator)?)?;
    }
    // convergence plot
    let series = |f: &dyn Fn(&opal_inverse::delight::IterationStats) -> f64| -> Vec<(f64, f64)> {
        r.iterations.iter().map(|i| (i.iteration as f64, 100.0 * f(i))).collect()
    };
    let plot = crate::plot::LinePlot {
        title: "de-lighting convergence".into(),
        x_label: "iteration".into(),
        y_label: "relative error (%)".into(),
        log_y: true,
        series: vec![
            crate::plot::Series {
                name: "max".into(),
                points: series(&|i| i.max_rel_error),
                color: 3,
                dashed: false,
                marks: false,
            },
            crate::plot::Series {
                name: "mean".into(),
                points: series(&|i| i.mean_rel_error),
                color: 0,
                dashed: false,
                marks: false,
            },
            // the stop statistic against the tolerance line (passes with no change beyond the
            // noise have 0, which the log axis cannot show: left out)
            crate::plot::Series {
                name: "tile change beyond noise".into(),
                points: series(&|i| i.change_beyond_noise).into_iter().filter(|p| p.1 > 0.0).collect(),
                color: 2,
                dashed: true,
                marks: true,
            },
        ]
        .into_iter()
        .filter(|s| !s.points.is_empty())
        .collect(),
        // a non-positive reference line on the log axis made plotters allocate without bound
        // (22 GB, killed) in the first full run: draw it only when it is positive
        hline: (a.tolerance > 0.0).then_some(100.0 * a.tolerance),
    };
    if !r.iterations.is_empty() {
        // written atomically (temp file + rename), by rank 0 only under MPI
        plot.save(&out.join("convergence.png"), (640, 420))?;
    }
    let t_out = t0.elapsed();
    // re-renders and region statistics
    let t_rr = StageClock::start();
    let rerender::Judged { regions, max_region_err, rerenders, contact } =
        rerender::rerender_and_judge(a, desc, views, r)?;
    let its: Vec<serde_json::Value> = r
        .iterations
        .iter()
        .map(|i| {
            json!({
                "iteration": i.iteration, "max_rel_error": i.max_rel_error, "mean_rel_error": i.mean_rel_error,
                "per_object": r.objects.iter().zip(&i.per_object).map(|(o, p)| json!({"id": o.id, "max": p.0, "mean": p.1, "outliers": p.2})).collect::<Vec<_>>(),
                "tracer_direct_over_light_sampled_direct": i.direct_ratio.iter().map(|v| if v.is_finite() { json!(v) } else { json!(null) }).collect::<Vec<_>>(),
                "seconds": i.seconds,
                "light_paths": i.light_paths,
                "comm_seconds": i.comm_seconds,
                "change_max": finite_or_null(i.change_max),
                "change_beyond_noise": finite_or_null(i.change_beyond_noise),
                "change_regions": i.change_regions,
                "texel_noise": finite_or_null(i.texel_noise_all),
                "texel_noise_per_object": r.objects.iter().zip(&i.texel_noise).map(|(o, v)| json!({"id": o.id, "noise": finite_or_null(*v)})).collect::<Vec<_>>(),
            })
        })
        .collect();
    let t_rr = t_rr.elapsed();
    let mut timings: serde_json::Map<String, serde_json::Value> =
        r.timings.iter().map(|(k, v)| (k.clone(), json!(v))).collect();
    let mut cpu: serde_json::Map<String, serde_json::Value> =
        r.cpu_timings.iter().map(|(k, v)| (k.clone(), json!(v))).collect();
    let t_all = t0.elapsed();
    for (name, (w, c)) in [("outputs", t_out), ("rerenders", t_rr), ("outputs_and_rerenders", t_all)] {
        timings.insert(name.into(), json!(w));
        cpu.insert(name.into(), json!(c));
    }
    // resident memory at each stage's end and the peak so far (MB)
    let mut memory: serde_json::Map<String, serde_json::Value> = r
        .memory_mb
        .iter()
        .map(|(k, [now, peak])| {
            (k.clone(), json!({"rss_at_end": finite_or_null(*now), "peak_so_far": finite_or_null(*peak)}))
        })
        .collect();
    let ((rw, rc), (rnow, rpeak)) = working.read;
    timings.insert("read_views".into(), json!(rw));
    cpu.insert("read_views".into(), json!(rc));
    memory.insert(
        "read_views".into(),
        json!({"rss_at_end": finite_or_null(rnow), "peak_so_far": finite_or_null(rpeak)}),
    );
    let (now, peak) = opal_inverse::delight::rss_mb();
    memory.insert(
        "outputs_and_rerenders".into(),
        json!({"rss_at_end": finite_or_null(now), "peak_so_far": finite_or_null(peak)}),
    );
    let finite = |x: f64| if x.is_finite() { json!(x) } else { json!(null) };
    let view_gains = r.view_gains.as_ref().map(|g| {
        json!({
            "mode": g.mode.name(),
            "convention": "median view exact (per channel)",
            "views": g.views.iter().map(|v| json!({
                "view": v.view, "gain": v.gain, "std_err": v.std_err.map(finite),
                "samples": v.samples, "far_from_others": v.far,
            })).collect::<Vec<_>>(),
        })
    });
    let poses = r.poses.as_ref().map(|p| {
        json!({
            "mode": p.mode.name(),
            "transforms": "transforms.json",
            "views": p.views.iter().map(|v| json!({
                "view": v.view, "rotation_deg": v.rotation_deg, "angle_deg": v.angle_deg,
                "translation": v.translation, "accepted": v.accepted, "used": v.used,
                "converged": v.converged, "iterations": v.iterations, "pixels": v.pixels,
                "rms_before": finite(v.rms_before), "rms_after": finite(v.rms_after), "reason": v.reason,
                "round_steps_px": v.round_steps_px.iter().map(|&x| finite(x)).collect::<Vec<_>>(),
            })).collect::<Vec<_>>(),
        })
    });
    let report = json!({
        "scene": a.scene, "views": a.views, "n_views": views.len(),
        "settings": {"iterations": a.iterations, "tolerance": a.tolerance, "light_paths": a.light_paths, "target_noise": a.target_noise, "resolution": a.resolution, "max_resolution": a.max_resolution, "max_view_pixels": a.max_view_pixels, "seed": a.seed, "update": a.update, "rerender_spp": a.rerender_spp, "rerender_noise": a.rerender_noise, "luminance": a.luminance, "view_gains": a.view_gains, "gain_warn_ratio": a.gain_warn_ratio, "refine_poses": a.refine_poses},
        "view_gains": view_gains,
        "poses": poses,
        "converged": r.converged,
        "iterations": its,
        "objects": objs,
        "skipped": r.skipped.iter().map(|(id, why)| json!({"id": id, "reason": why})).collect::<Vec<_>>(),
        "not_recovered": r.not_recovered.iter().map(|(id, why)| json!({"id": id, "reason": why})).collect::<Vec<_>>(),
        "warnings": r.warnings.iter().chain(vwarn).collect::<Vec<_>>(),
        "regions": regions,
        "max_region_rel_error_luminance": max_region_err,
        "rerenders": rerenders,
        "contact_edges": (a.rerender_spp > 0).then(|| contact.json()),
        "view_error_range": html::VIEW_ERROR_RANGE,
        "texel_error_range": html::TEXEL_ERROR_RANGE,
        "light_paths_total": r.light_paths,
        "timings_seconds": &timings,
        "cpu_seconds": &cpu,
        "memory_mb": &memory,
        "view_sizes": views.iter().map(|v| [v.image.width, v.image.height]).collect::<Vec<_>>(),
        "photo_sizes": &working.photo_sizes,
        "working_size": &working.json,
        "outputs": {"scene": "scene.xml", "gltf": "scene.glb", "convergence_plot": "convergence.png", "report_html": "report.html"},
    });
    util::write_bytes_atomic(&out.join("report.json"), serde_json::to_string_pretty(&report)?.as_bytes())?;
    html::write_colour_bars(out)?;
    util::write_bytes_atomic(&out.join("report.html"), html::html(&report).as_bytes())?;
    let worst = regions.iter().max_by(|a, b| {
        let f = |r: &serde_json::Value| r["rel_error_luminance"].as_f64().unwrap_or(0.0).abs();
        f(a).total_cmp(&f(b))
    });
    let noise = worst.and_then(|r| r["rerender_rel_stderr_luminance"].as_f64()).unwrap_or(0.0);
    let stages: Vec<String> = timings
        .iter()
        .map(|(k, w)| {
            format!("{k} {:.1}/{:.1}", w.as_f64().unwrap_or(f64::NAN), cpu[k].as_f64().unwrap_or(f64::NAN))
        })
        .collect();
    log(&format!("stages (wall/CPU s): {}", stages.join(", ")));
    log(&format!("peak resident memory {:.0} MB", peak));
    log(&format!(
        "delight: outputs in {} (max region error {:.2} %, re-render noise of that region ±{:.2} %)",
        out.display(),
        100.0 * max_region_err,
        100.0 * noise
    ));
    Ok(report)
}

/// Runs `opal delight`; returns the exit code.
pub fn run(a: DelightArgs) -> Result<i32> {
    util::ensure_not_input(&a.output, &[&a.scene, &a.views])?;
    util::set_threads(a.threads);
    // --quiet keeps the warnings (rank 0's only under MPI: the other ranks repeat them)
    let (quiet, root) = (util::is_quiet(), crate::dist::is_root());
    let log = move |l: &str| {
        if !quiet || (root && l.starts_with("warning: ")) {
            util::suspend_progress(|| eprintln!("{l}"))
        }
    };
    util::install_interrupt_handler();
    let output_existed = a.output.exists();
    if crate::dist::size() > 1 && a.resume {
        anyhow::bail!(
            "--resume runs with one process only (the checkpoint is rank 0's); continue without mpirun"
        );
    }
    // under MPI only rank 0 keeps the command line and the checkpoint
    if root {
        resume::save_args(&a.output.join(CHECKPOINT))?;
    }
    let report = run_pipeline(&a, &log).map_err(|e| match e.downcast_ref::<opal::error::Error>() {
        Some(opal::error::Error::Interrupted { .. }) => {
            e.context(format!(
                "stopped on request; to continue, run the same command with --resume, or `opal delight --resume {}`",
                a.output.display()
            ))
        }
        _ => {
            // failed (bad input, …): leave no saved command line behind unless iterations were kept
            if root {
                resume::discard_args(&a.output.join(CHECKPOINT), (!output_existed).then_some(a.output.as_path()));
            }
            e
        }
    })?;
    // finished: the checkpoint of the iterations is no longer needed
    if root {
        let _ = std::fs::remove_dir_all(a.output.join(CHECKPOINT));
    }
    if a.json {
        let mut o = std::io::stdout().lock();
        writeln!(o, "{}", serde_json::to_string_pretty(&report)?)?;
    }
    Ok(0)
}

/// `opal demo` part: renders 8 small views of the bundled Cornell box with Opal at its true
/// albedos, then de-lights them (small settings, well under 30 s on 2 cores).
pub fn demo(out: &Path) -> Result<serde_json::Value> {
    let dir = out.join("delight");
    let scene_path = crate::assets::write_cbox(&dir.join("cbox"))?;
    let mut desc = opal::scene::load::load_mitsuba_xml(&scene_path, &[])?;
    let res = 48;
    for s in &mut desc.sensors {
        s.width = res;
        s.height = res;
    }
    let scene = Scene::build(&desc)?;
    // photos at 256 spp and re-renders at 64 spp: on 48-pixel views the ceiling regions (lit only
    // indirectly) have a few hundred pixels, and at 64/16 spp their Monte-Carlo noise (3–7 %)
    // dominated the region errors
    let ps = PathSettings { spp: 256, max_depth: -1, rr_depth: 5, hide_emitters: false, seed: 1 };
    let mut frames = Vec::new();
    for (c, s) in desc.sensors.iter().enumerate() {
        let img = render(&scene, c, &ps, &|| {}).image;
        let name = format!("views/{}.exr", s.id);
        exr(&dir.join(&name), &img)?;
        let gl = s.to_world * opal::math::Mat4::from_scale(opal::math::Vec3::new(-1.0, 1.0, -1.0));
        let rows: Vec<Vec<f32>> = (0..4).map(|r| (0..4).map(|c| gl.col(c)[r]).collect()).collect();
        frames.push(json!({"file_path": name, "transform_matrix": rows, "camera_angle_x": s.fov_x_deg.to_radians(), "w": res, "h": res}));
    }
    let tj = dir.join("transforms.json");
    util::write_bytes_atomic(&tj, serde_json::to_string_pretty(&json!({"frames": frames}))?.as_bytes())?;
    let args = DelightArgs {
        scene: scene_path,
        views: tj,
        output: dir.join("result"),
        objects: None,
        iterations: 3,
        tolerance: 0.01,
        light_paths: "500000".into(),
        target_noise: None,
        resolution: "32".into(),
        max_resolution: 4096,
        max_view_pixels: None,
        unwrap_all: false,
        update: "fixed".into(),
        rerender_spp: 64,
        rerender_noise: 0.0,
        luminance: "superres".into(),
        tv_lambda: None,
        tv_exponent: None,
        view_gains: "fixed".into(),
        gain_warn_ratio: 1.5,
        refine_poses: "off".into(),
        resume: false,
        seed: 0,
        threads: None,
        json: false,
        diagnostics: DiagnosticArgs::default(),
    };
    let report = run_pipeline(&args, &|l| eprintln!("demo delight: {l}"))?;
    eprintln!("demo: de-lighting report -> {}", args.output.join("report.html").display());
    Ok(
        json!({"output": args.output, "converged": report["converged"], "objects": report["objects"], "max_region_rel_error_luminance": report["max_region_rel_error_luminance"]}),
    )
}
