//! `opal delight`: recovers diffuse albedo textures from multi-view HDR images (method C, see
//! `opal_inverse::delight`) and writes textures, meshes with UVs, a Mitsuba 3 scene using them,
//! a glTF 2.0 binary of the recovered objects (`scene.glb`, see `crate::glb`), error maps, a
//! convergence plot, re-renders and report.json / report.html.

mod args;
mod contact;
mod html;
mod object_files;
mod report;
mod rerender;
pub mod resume;
mod scene_xml;

use args::settings_from_args;
pub use args::{DelightArgs, DiagnosticArgs};
use report::{finite_or_null, write_outputs};

use crate::util;
use anyhow::{Context, Result};
use opal::image::Image;
use opal::integrator::path::{PathSettings, render};
use opal::scene::Scene;
use opal::scene::desc::SceneDesc;
use opal_inverse::delight::views::{View, read_views_limited};
use opal_inverse::delight::{DelightSettings, StageClock, apply_view_gains, delight};
use serde_json::json;
use std::io::Write as _;
use std::path::Path;

fn exr(path: &Path, img: &Image) -> Result<()> {
    util::write_atomic(path, |f| Ok(opal::image::write::write_exr(img, std::io::BufWriter::new(f))?))
}

fn png(path: &Path, img: &Image, exposure: f32) -> Result<()> {
    util::write_atomic(path, |f| {
        Ok(opal::image::write::write_png_srgb(img, exposure, std::io::BufWriter::new(f))?)
    })
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
    let settings = settings_from_args(a)?;
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
