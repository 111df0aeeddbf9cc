//! `opal demo`: runs Opal's workflows on data shipped inside the binary and writes the results
//! (images, plots, JSON reports) into an output folder (default `opal-demo/`).

use crate::util;
use anyhow::{Context, Result};
use clap::Args;
use std::path::{Path, PathBuf};

/// Arguments of `opal demo`.
#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Output folder.
    #[arg(short, long, default_value = "opal-demo")]
    pub output: PathBuf,
    /// Samples per pixel of the Cornell-box render.
    #[arg(long, default_value_t = 64)]
    pub spp: u32,
}

fn demo_render(out: &Path, spp: u32) -> Result<serde_json::Value> {
    let dir = out.join("render");
    let scene_path = crate::assets::write_cbox(&dir.join("cbox"))?;
    let scene = super::render::load_scene(&scene_path, &[])?;
    let settings = opal::integrator::path::PathSettings {
        spp,
        max_depth: scene.integrator.max_depth,
        rr_depth: scene.integrator.rr_depth,
        hide_emitters: false,
        seed: 0,
    };
    let cam = &scene.cameras[0];
    let pb = util::progress(cam.height as u64, "render");
    let t0 = std::time::Instant::now();
    let r = opal::integrator::path::render(&scene, 0, &settings, &|| pb.inc(1));
    let secs = t0.elapsed().as_secs_f64();
    pb.finish_and_clear();
    let exr = dir.join("cbox_view_00.exr");
    let png = dir.join("cbox_view_00.png");
    super::render::write_outputs(&r, &exr, Some(&png), None)?;
    eprintln!("demo: rendered the Cornell box ({} spp, {:.1} s) -> {}", spp, secs, png.display());
    Ok(serde_json::json!({
        "scene": scene_path,
        "exr": exr,
        "png": png,
        "spp": spp,
        "seconds": secs,
        "samples_per_second": r.samples as f64 / secs,
        "mean_rgb": r.image.mean(),
        "nonfinite_samples": r.nonfinite,
    }))
}

/// Runs the demo; returns the exit code.
pub fn run(args: DemoArgs) -> Result<i32> {
    std::fs::create_dir_all(&args.output)
        .with_context(|| format!("cannot create {}", args.output.display()))?;
    let mut report = serde_json::Map::new();
    report.insert("render".into(), demo_render(&args.output, args.spp.max(1))?);
    report.insert("brdf".into(), super::brdf::demo(&args.output)?);
    report.insert("gonio".into(), super::gonio::demo(&args.output)?);
    report.insert("fit_ndf".into(), super::fit_ndf::demo(&args.output)?);
    report.insert("delight".into(), super::delight::demo(&args.output)?);
    let path = args.output.join("report.json");
    util::write_bytes_atomic(&path, serde_json::to_string_pretty(&report)?.as_bytes())?;
    eprintln!("demo: report -> {}", path.display());
    Ok(0)
}
