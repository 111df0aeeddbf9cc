//! `opal render SCENE.xml -o out.exr`: path-traced image of a Mitsuba 3 scene.

use crate::util;
use anyhow::{Context, Result, bail};
use clap::Args;
use opal::integrator::path::{PathSettings, RenderOutput, render_split};
use opal::scene::Scene;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `opal render`.
#[derive(Args, Debug)]
pub struct RenderArgs {
    /// Mitsuba 3 XML scene.
    pub scene: PathBuf,
    /// Output OpenEXR file (float32 linear RGB).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Sensor to render: index (0-based) or `id`.
    #[arg(long, default_value = "0")]
    pub sensor: String,
    /// Samples per pixel (default: the sensor's sampler, else 64).
    #[arg(long)]
    pub spp: Option<u32>,
    /// Maximum path depth, Mitsuba's meaning (default: the scene's integrator, else -1 = unbounded).
    #[arg(long, allow_hyphen_values = true)]
    pub max_depth: Option<i32>,
    /// Seed of the random numbers.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Also write an sRGB PNG preview.
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Also write the per-pixel standard error as EXR.
    #[arg(long)]
    pub stderr: Option<PathBuf>,
    /// Scene parameter `$name` (repeatable): `-D name=value`.
    #[arg(short = 'D', value_parser = parse_kv)]
    pub define: Vec<(String, String)>,
    /// Print a JSON report on stdout.
    #[arg(long)]
    pub json: bool,
}

fn parse_kv(s: &str) -> std::result::Result<(String, String), String> {
    s.split_once('=')
        .map(|(a, b)| (a.to_string(), b.to_string()))
        .ok_or_else(|| format!("expected name=value, got '{s}'"))
}

/// Loads and builds a scene file.
pub fn load_scene(path: &Path, defines: &[(String, String)]) -> Result<Scene> {
    let desc = opal::scene::load::load_mitsuba_xml(path, defines)?;
    let scene = Scene::build(&desc).with_context(|| format!("in scene {}", path.display()))?;
    for w in desc.warnings.iter().chain(&scene.warnings) {
        eprintln!("warning: {w}");
    }
    Ok(scene)
}

/// Resolves `--sensor` (index or id).
pub fn pick_sensor(scene: &Scene, which: &str) -> Result<usize> {
    if scene.cameras.is_empty() {
        bail!("the scene has no sensor");
    }
    if let Ok(i) = which.parse::<usize>() {
        if i < scene.cameras.len() {
            return Ok(i);
        }
        bail!("--sensor {i}: the scene has {} sensors (0..{})", scene.cameras.len(), scene.cameras.len() - 1);
    }
    scene.cameras.iter().position(|c| c.id == which).with_context(|| {
        let ids: Vec<&str> = scene.cameras.iter().map(|c| c.id.as_str()).collect();
        format!("--sensor '{which}': no sensor with that id (have: {})", ids.join(", "))
    })
}

/// Refuses to render a camera that sees no geometry at all (a coarse grid of rays).
pub fn check_camera_sees_something(scene: &Scene, cam: usize) -> Result<()> {
    let c = &scene.cameras[cam];
    let n = 32;
    for j in 0..n {
        for i in 0..n {
            let p = opal::math::Vec2::new(
                (i as f32 + 0.5) / n as f32 * c.width as f32,
                (j as f32 + 0.5) / n as f32 * c.height as f32,
            );
            if scene.intersect(&c.generate_ray(p)).is_some() {
                return Ok(());
            }
        }
    }
    bail!("sensor '{}' sees no geometry (checked a {n}×{n} grid of rays): check its to_world and fov", c.id)
}

/// Refuses `--spp 0`.
pub fn check_spp(spp: Option<u32>) -> Result<()> {
    if spp == Some(0) {
        bail!("--spp must be at least 1");
    }
    Ok(())
}

/// The path tracer's settings of `opal render`: `spp` defaults to the sensor's sampler, else
/// 64; `max_depth` to the scene's integrator.
pub fn path_settings(
    scene: &Scene,
    cam: usize,
    spp: Option<u32>,
    max_depth: Option<i32>,
    seed: u64,
) -> PathSettings {
    PathSettings {
        spp: spp.or(scene.cameras[cam].spp).unwrap_or(64),
        max_depth: max_depth.unwrap_or(scene.integrator.max_depth),
        rr_depth: scene.integrator.rr_depth,
        hide_emitters: scene.integrator.hide_emitters,
        seed,
    }
}

/// Writes the EXR (and optional PNG / stderr EXR) of a render atomically.
pub fn write_outputs(
    out: &RenderOutput,
    exr: &Path,
    png: Option<&Path>,
    stderr: Option<&Path>,
) -> Result<()> {
    util::write_atomic(exr, |f| Ok(opal::image::write::write_exr(&out.image, std::io::BufWriter::new(f))?))?;
    if let Some(p) = png {
        util::write_atomic(p, |f| {
            Ok(opal::image::write::write_png_srgb(&out.image, 1.0, std::io::BufWriter::new(f))?)
        })?;
    }
    if let Some(p) = stderr {
        util::write_atomic(p, |f| {
            Ok(opal::image::write::write_exr(&out.stderr, std::io::BufWriter::new(f))?)
        })?;
    }
    Ok(())
}

/// Runs `opal render`.
pub fn run(a: RenderArgs) -> Result<i32> {
    for o in [Some(&a.output), a.png.as_ref(), a.stderr.as_ref()].into_iter().flatten() {
        util::ensure_not_input(o, &[&a.scene])?;
    }
    check_spp(a.spp)?;
    let scene = load_scene(&a.scene, &a.define)?;
    let cam = pick_sensor(&scene, &a.sensor)?;
    check_camera_sees_something(&scene, cam)?;
    if scene.lights.is_empty() {
        eprintln!("warning: the scene has no emitter: the image will be black");
    }
    let c = &scene.cameras[cam];
    let settings = path_settings(&scene, cam, a.spp, a.max_depth, a.seed);
    let pool = rayon::ThreadPoolBuilder::new().num_threads(a.threads.unwrap_or(0)).build()?;
    // under MPI: row y on rank y mod size (the same image bits for any number of ranks)
    let comm = crate::dist::comm_or_solo();
    let pb = util::progress((0..c.height as u64).filter(|&y| comm.owns(y)).count() as u64, "render");
    let t0 = Instant::now();
    let out = pool.install(|| render_split(&scene, cam, &settings, &|| pb.inc(1), None, &*comm))?;
    let secs = t0.elapsed().as_secs_f64();
    pb.finish_and_clear();
    write_outputs(&out, &a.output, a.png.as_deref(), a.stderr.as_deref())?;
    if out.nonfinite > 0 {
        eprintln!("warning: {} samples were NaN/Inf and were dropped", out.nonfinite);
    }
    let report = serde_json::json!({
        "scene": a.scene,
        "sensor": c.id,
        "width": c.width,
        "height": c.height,
        "spp": settings.spp,
        "max_depth": settings.max_depth,
        "seed": settings.seed,
        "seconds": secs,
        "samples_per_second": out.samples as f64 / secs,
        "nonfinite_samples": out.nonfinite,
        "mean_rgb": out.image.mean(),
        "output": a.output,
    });
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        eprintln!(
            "rendered {} ({}x{}, {} spp) in {:.2} s ({:.2} M samples/s) -> {}",
            c.id,
            c.width,
            c.height,
            settings.spp,
            secs,
            out.samples as f64 / secs / 1e6,
            a.output.display()
        );
    }
    Ok(0)
}
