//! The outputs of a finished `opal delight` run besides the per-object files: the rewritten
//! scene, `scene.glb`, the convergence plot, the re-renders and report.json / report.html
//! (keys: docs/formats.md). Tests: the CLI tests `tests/delight.rs` (documented key sets).

use super::{DelightArgs, Working, html, object_files, rerender, scene_xml};
use crate::util;
use anyhow::{Context, Result};
use opal::scene::desc::SceneDesc;
use opal_inverse::delight::views::View;
use opal_inverse::delight::{DelightResult, StageClock};
use serde_json::{Map, Value, json};
use std::path::Path;

pub(super) fn finite_or_null(x: f64) -> Value {
    if x.is_finite() { json!(x) } else { json!(null) }
}

/// Writes every output of a finished run and returns the report.
pub(super) fn write_outputs(
    a: &DelightArgs,
    desc: &SceneDesc,
    views: &[View],
    r: &DelightResult,
    vwarn: &[String],
    working: &Working,
    log: &(dyn Fn(&str) + Sync),
) -> Result<Value> {
    let out = &a.output;
    let t0 = StageClock::start();
    // textures, meshes, error maps (under MPI encoded by all ranks, written by rank 0); the
    // albedo PNGs (8-bit sRGB) are encoded once: albedo/<obj>.png and the glTF textures
    let albedo_png = object_files::write_object_files(r, out)?;
    let objs = object_entries(r);
    write_scenes(a, desc, r, &albedo_png)?;
    if !r.iterations.is_empty() {
        // written atomically (temp file + rename), by rank 0 only under MPI
        convergence_plot(a, r).save(&out.join("convergence.png"), (640, 420))?;
    }
    let t_out = t0.elapsed();
    // re-renders and region statistics
    let t_rr = StageClock::start();
    let rerender::Judged { regions, max_region_err, rerenders, contact } =
        rerender::rerender_and_judge(a, desc, views, r)?;
    let its = iteration_entries(r);
    let t_rr = t_rr.elapsed();
    let mut timings: Map<String, Value> = r.timings.iter().map(|(k, v)| (k.clone(), json!(v))).collect();
    let mut cpu: Map<String, Value> = r.cpu_timings.iter().map(|(k, v)| (k.clone(), json!(v))).collect();
    let t_all = t0.elapsed();
    for (name, (w, c)) in [("outputs", t_out), ("rerenders", t_rr), ("outputs_and_rerenders", t_all)] {
        timings.insert(name.into(), json!(w));
        cpu.insert(name.into(), json!(c));
    }
    let (memory, peak) = memory_entries(r, working, &mut timings, &mut cpu);
    let report = json!({
        "scene": a.scene, "views": a.views, "n_views": views.len(),
        "settings": {"iterations": a.iterations, "tolerance": a.tolerance, "light_paths": a.light_paths, "target_noise": a.target_noise, "resolution": a.resolution, "max_resolution": a.max_resolution, "max_view_pixels": a.max_view_pixels, "seed": a.seed, "update": a.update, "rerender_spp": a.rerender_spp, "rerender_noise": a.rerender_noise, "luminance": a.luminance, "view_gains": a.view_gains, "gain_warn_ratio": a.gain_warn_ratio, "refine_poses": a.refine_poses},
        "view_gains": view_gains_entry(r),
        "poses": poses_entry(r),
        "converged": r.converged,
        "iterations": its,
        "objects": objs,
        "skipped": r.skipped.iter().map(|(id, why)| json!({"id": id, "reason": why})).collect::<Vec<_>>(),
        "not_recovered": r.not_recovered.iter().map(|(id, why)| json!({"id": id, "reason": why})).collect::<Vec<_>>(),
        "warnings": r.warnings.iter().chain(vwarn).collect::<Vec<_>>(),
        "regions": &regions,
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
    log_summary(out, &regions, max_region_err, &timings, &cpu, peak, log);
    Ok(report)
}

/// report.json `objects`: one entry per recovered object.
fn object_entries(r: &DelightResult) -> Vec<Value> {
    let finite = |v: [f64; 3]| v.map(|x| x.is_finite().then_some(x));
    r.objects
        .iter()
        .enumerate()
        .map(|(j, o)| {
            let unseen = r.unseen_light.get(j).map(|u| {
                json!({
                    "unseen_texels": u.unseen_texels,
                    "share": u.share,
                    "fill_uncertainty": finite(u.fill_uncertainty),
                    "albedo_shift": u.albedo_shift,
                    "albedo_noise": finite(u.albedo_noise),
                })
            });
            json!({
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
                "mean_albedo_seen": o.mean_kd_observed(),
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
            })
        })
        .collect()
}

/// scene.xml (the input scene using the recovered objects) and scene.glb (the recovered objects
/// with their albedo textures, glTF 2.0 binary; rank 0 only under MPI).
fn write_scenes(a: &DelightArgs, desc: &SceneDesc, r: &DelightResult, albedo_png: &[Vec<u8>]) -> Result<()> {
    let text =
        std::fs::read_to_string(&a.scene).with_context(|| format!("cannot read {}", a.scene.display()))?;
    let scene_dir = a.scene.parent().unwrap_or(Path::new("."));
    let new_xml = scene_xml::rewrite_scene(&text, scene_dir, &r.objects, desc)?;
    util::write_bytes_atomic(&a.output.join("scene.xml"), new_xml.as_bytes())?;
    let glb_objects: Vec<crate::glb::GlbObject> = r
        .objects
        .iter()
        .zip(albedo_png)
        .map(|(o, p)| crate::glb::GlbObject { name: &o.id, mesh: &o.atlas.mesh, base_colour_png: p })
        .collect();
    let generator = format!("opal delight {}", env!("CARGO_PKG_VERSION"));
    if crate::dist::is_root() {
        // (the other ranks have no PNGs)
        util::write_bytes_atomic(
            &a.output.join("scene.glb"),
            &crate::glb::glb_bytes(&glb_objects, &generator)?,
        )?;
    }
    Ok(())
}

/// The convergence plot: max and mean relative error per iteration, the stop statistic and the
/// tolerance line.
fn convergence_plot(a: &DelightArgs, r: &DelightResult) -> crate::plot::LinePlot {
    let series = |f: &dyn Fn(&opal_inverse::delight::IterationStats) -> f64| -> Vec<(f64, f64)> {
        r.iterations.iter().map(|i| (i.iteration as f64, 100.0 * f(i))).collect()
    };
    let line = |name: &str, points, color, dashed| crate::plot::Series {
        name: name.into(),
        points,
        color,
        dashed,
        marks: dashed,
    };
    crate::plot::LinePlot {
        title: "de-lighting convergence".into(),
        x_label: "iteration".into(),
        y_label: "relative error (%)".into(),
        log_y: true,
        series: vec![
            line("max", series(&|i| i.max_rel_error), 3, false),
            line("mean", series(&|i| i.mean_rel_error), 0, false),
            // the stop statistic against the tolerance line (passes with no change beyond the
            // noise have 0, which the log axis cannot show: left out)
            line(
                "tile change beyond noise",
                series(&|i| i.change_beyond_noise).into_iter().filter(|p| p.1 > 0.0).collect(),
                2,
                true,
            ),
        ]
        .into_iter()
        .filter(|s| !s.points.is_empty())
        .collect(),
        // a non-positive reference line on the log axis made plotters allocate without bound
        // (22 GB, killed) in the first full run: draw it only when it is positive
        hline: (a.tolerance > 0.0).then_some(100.0 * a.tolerance),
    }
}

/// report.json `iterations`: one entry per pass.
fn iteration_entries(r: &DelightResult) -> Vec<Value> {
    r.iterations
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
        .collect()
}

/// report.json `memory_mb` (resident memory at each stage's end and the peak so far, MB), with
/// the reading of the views added to the stage times; returns it and the peak now.
fn memory_entries(
    r: &DelightResult,
    working: &Working,
    timings: &mut Map<String, Value>,
    cpu: &mut Map<String, Value>,
) -> (Map<String, Value>, f64) {
    let entry =
        |now: f64, peak: f64| json!({"rss_at_end": finite_or_null(now), "peak_so_far": finite_or_null(peak)});
    let mut memory: Map<String, Value> =
        r.memory_mb.iter().map(|(k, [now, peak])| (k.clone(), entry(*now, *peak))).collect();
    let ((rw, rc), (rnow, rpeak)) = working.read;
    timings.insert("read_views".into(), json!(rw));
    cpu.insert("read_views".into(), json!(rc));
    memory.insert("read_views".into(), entry(rnow, rpeak));
    let (now, peak) = opal_inverse::delight::rss_mb();
    memory.insert("outputs_and_rerenders".into(), entry(now, peak));
    (memory, peak)
}

/// report.json `view_gains` (when the gains were estimated).
fn view_gains_entry(r: &DelightResult) -> Option<Value> {
    r.view_gains.as_ref().map(|g| {
        json!({
            "mode": g.mode.name(),
            "convention": "median view exact (per channel)",
            "views": g.views.iter().map(|v| json!({
                "view": v.view, "gain": v.gain, "std_err": v.std_err.map(finite_or_null),
                "samples": v.samples, "far_from_others": v.far,
            })).collect::<Vec<_>>(),
        })
    })
}

/// report.json `poses` (when the poses were refined).
fn poses_entry(r: &DelightResult) -> Option<Value> {
    r.poses.as_ref().map(|p| {
        json!({
            "mode": p.mode.name(),
            "transforms": "transforms.json",
            "views": p.views.iter().map(|v| json!({
                "view": v.view, "rotation_deg": v.rotation_deg, "angle_deg": v.angle_deg,
                "translation": v.translation, "accepted": v.accepted, "used": v.used,
                "converged": v.converged, "iterations": v.iterations, "pixels": v.pixels,
                "rms_before": finite_or_null(v.rms_before), "rms_after": finite_or_null(v.rms_after), "reason": v.reason,
                "round_steps_px": v.round_steps_px.iter().map(|&x| finite_or_null(x)).collect::<Vec<_>>(),
            })).collect::<Vec<_>>(),
        })
    })
}

/// The closing lines of the log: stage times, peak memory, the worst region.
fn log_summary(
    out: &Path,
    regions: &[Value],
    max_region_err: f64,
    timings: &Map<String, Value>,
    cpu: &Map<String, Value>,
    peak: f64,
    log: &(dyn Fn(&str) + Sync),
) {
    let worst = regions.iter().max_by(|a, b| {
        let f = |r: &Value| r["rel_error_luminance"].as_f64().unwrap_or(0.0).abs();
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
}
