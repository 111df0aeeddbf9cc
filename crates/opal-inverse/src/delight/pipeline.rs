//! The de-lighting pipeline [`delight`]: checks its inputs, then runs the named stages of
//! [`super::stages`] in order — unwrap (selection, atlases), direct (irradiance `Ed`),
//! pose refinement (optional), luminance (per-view gains, luminance maps `L`), gather (the initial
//! indirect irradiance from the luminance maps, [`super::gather`]) and the initial albedo, iterate
//! (light-tracing passes, super-resolved luminance after the first) and outputs (debug dump,
//! result). The steps are described in the module documentation of [`super`] and in
//! `docs/delight.md`. Tests: `tests/delight.rs` (round trip on a small Cornell box), the CLI's
//! `opal delight` tests.

use super::albedo::{fill_unseen, initial_kd};
use super::progress::Stage;
use super::stages::outputs::{Finished, assemble, debug_dump};
use super::stages::{Inputs, direct, iterate, luminance, unwrap};
use super::timing::{StageClock, Timings};
use super::views::{PureBuffer, View};
use super::{DelightResult, DelightSettings, gather, pose, views};
use opal::error::{Error, Result};
use opal::scene::Scene;
use opal::scene::desc::SceneDesc;

/// Runs the de-lighting. `log` receives one line per stage.
pub fn delight(
    desc: &SceneDesc,
    views: &[View],
    s: &DelightSettings,
    log: &(dyn Fn(&str) + Sync),
) -> Result<DelightResult> {
    let t_all = StageClock::start();
    let mut timings = Timings::default();
    let mut warnings = Vec::new();
    let scene = Scene::build(desc)?;
    if scene.light_sampler().is_none() {
        return Err(Error::invalid(
            "scene",
            "has no emitter with positive power: the lighting must be known to separate it from the albedo",
        ));
    }
    if views.is_empty() {
        return Err(Error::invalid("views", "no view given"));
    }
    // 0. the working views: larger ones box-filtered onto coarser films (one copy at a time)
    let coarse: Option<Vec<View>> = s
        .max_view_pixels
        .filter(|&m| views.iter().any(|v| v.image.data.len() > m))
        .map(|m| views.iter().map(|v| super::downsample::downsample_view(v.clone(), m)).collect());
    if let Some(c) = &coarse {
        let (w0, h0, w1, h1) =
            (views[0].image.width, views[0].image.height, c[0].image.width, c[0].image.height);
        log(&format!(
            "views downsampled to at most {} pixels (first view {w0}×{h0} → {w1}×{h1})",
            s.max_view_pixels.unwrap_or(0)
        ));
    }
    // the run's own copy of the views, if any (downsampled, then refined, then divided by the
    // gains): each replaces the one before, so at most one copy is held besides the caller's
    let mut owned: Option<Vec<View>> = coarse;
    let inp = Inputs { desc, scene: &scene, s, log };
    // 1. unwrap
    let (selected, not_recovered) = unwrap::select_objects(&scene, s.objects.as_deref())?;
    for (id, why) in &not_recovered {
        log(&format!("not recovered: {id} ({why})"));
    }
    let t0 = StageClock::start();
    let (mut objects, skipped) =
        unwrap::unwrap_objects(&inp, &selected, owned.as_deref().unwrap_or(views), &mut warnings);
    if objects.is_empty() {
        return Err(Error::invalid("objects", "no object could be unwrapped"));
    }
    timings.push("unwrap", t0.elapsed());
    cancelled(s)?;
    // 2. direct irradiance (first: it shapes the prior of the super-resolved luminance maps)
    let t0 = StageClock::start();
    let avg = direct::direct_stage(&scene, &mut objects, s);
    timings.push("direct", t0.elapsed());
    cancelled(s)?;
    // 3. per-view pose refinement (off by default); every later step sees the refined views
    let tp = StageClock::start();
    let (poses, refined) = pose::pipeline_stage(
        &scene,
        &objects,
        owned.as_deref().unwrap_or(views),
        &s.poses,
        log,
        &mut warnings,
    );
    if refined.is_some() {
        owned = refined;
    }
    if poses.is_some() {
        timings.push("poses", tp.elapsed());
    }
    // 4. luminance maps (on the views divided by their gains), then the initial albedo
    let t0 = StageClock::start();
    // after a pose refinement, the pixels next to an edge are left out (the poses are known to a
    // fraction of a pixel)
    let margin = if poses.is_some() { s.poses.delight_edge_margin } else { 0 };
    let current: &[View] = owned.as_deref().unwrap_or(views);
    let pure: Vec<PureBuffer> = current
        .iter()
        .map(|v| {
            let p = views::pure_buffer(&scene, &v.camera);
            if margin > 0 { pose::erode_smooth(&p, margin) } else { p }
        })
        .collect();
    let (corrected, view_gains) =
        luminance::view_gains(&inp, &objects, current, &pure, &mut warnings, &mut timings);
    if corrected.is_some() {
        owned = corrected;
    }
    let views: &[View] = owned.as_deref().unwrap_or(views);
    log(&held_per_view(views, &pure, owned.is_some()));
    // seconds per object of the last stage split by object (the owners of the next; MPI only)
    let mut costs = Vec::new();
    luminance::luminance_maps(&inp, &mut objects, views, &pure, &mut warnings, &mut costs);
    timings.push("luminance", t0.elapsed());
    cancelled(s)?;
    // initial indirect irradiance: gathered from the luminance maps (or a share of `Ed`)
    let t0 = StageClock::start();
    let solo = opal::dist::Solo;
    let comm: &dyn opal::dist::Comm = s.comm.as_deref().unwrap_or(&solo);
    // the gather texels of all objects split across the processes in one exchange
    let bar = (s.gather_rays > 0).then(|| Stage::start(s.progress.as_ref(), "gather", 1));
    let gathered =
        (s.gather_rays > 0).then(|| gather::gather_samples(&scene, &objects, s.gather_rays, s.seed, comm));
    drop(bar);
    // objects split across the processes (each object's gathered map and albedo by one rank,
    // then shared)
    let g = gathered.as_ref();
    let init = |j: usize, o: &mut super::ObjectResult| {
        let map = g.map(|g| gather::gathered_map(&o.atlas, &g[j]));
        initial_kd(o, s.indirect_share, avg, map.as_deref())
    };
    super::split::per_object(comm, &mut objects, &mut costs, init, |_, _| {}, |_| ());
    drop(gathered);
    if s.gather_rays > 0 {
        timings.push("gather", t0.elapsed());
    }
    // unseen objects: scene-average albedo of the seen ones
    fill_unseen(&mut objects);
    // 5. iterations
    let mut iterated =
        iterate::iterate(&inp, &mut objects, views, &pure, &mut warnings, &mut timings, &mut costs)?;
    // 6. what the data cannot determine: the light via texels no view observed
    let unseen_light = unseen_stage(&inp, &objects, &mut iterated, &mut warnings, &mut timings, comm)?;
    // 7. outputs
    debug_dump(&objects, "final", s.debug.dump_dir.as_deref());
    Ok(assemble(
        Finished { objects, skipped, not_recovered, iterated, view_gains, poses, warnings, unseen_light },
        timings,
        t_all,
    ))
}

/// The log line of the per-view data held for the rest of the run: the views' images (the
/// caller's and the run's own copy) and the pure-pixel buffers, in MB and bytes per pixel.
fn held_per_view(views: &[View], pure: &[PureBuffer], own_copy: bool) -> String {
    let px: usize = views.iter().map(|v| v.image.data.len()).sum();
    let img = px * std::mem::size_of::<opal::spectrum::Spectrum>() * if own_copy { 2 } else { 1 };
    let pb: usize = pure.iter().map(|p| p.heap_bytes()).sum();
    let mb = |b: usize| b as f64 / (1 << 20) as f64;
    format!(
        "per-view data held: {} views, {:.2} M pixels: images {:.1} MB ({}), pure-pixel buffers {:.1} MB ({:.1} B/pixel)",
        views.len(),
        px as f64 * 1e-6,
        mb(img),
        if own_copy { "the given views and the run's copy" } else { "the given views" },
        mb(pb),
        pb as f64 / px.max(1) as f64
    )
}

/// The unseen-light analysis ([`super::unseen`]; skipped when `unseen_light_paths` is 0): one
/// log line per object, warnings for the objects it can move, stage clock `unseen_light`.
fn unseen_stage(
    inp: &Inputs,
    objects: &[super::ObjectResult],
    iterated: &mut iterate::Iterated,
    warnings: &mut Vec<String>,
    timings: &mut Timings,
    comm: &dyn opal::dist::Comm,
) -> Result<Vec<super::UnseenLight>> {
    let (s, log) = (inp.s, inp.log);
    if s.unseen_light_paths <= 0.0 || iterated.iterations.is_empty() {
        return Ok(Vec::new());
    }
    let t0 = StageClock::start();
    let texels: usize = objects.iter().map(|o| o.atlas.width * o.atlas.height).sum();
    let paths = ((s.light_paths.paths(texels) as f64 * s.unseen_light_paths) as u64).max(1000);
    // a seed no iteration uses
    let seed = s.seed.wrapping_add(0x756e_7365_656e);
    let cancel = s.cancel.as_deref();
    let Some(u) = super::unseen::unseen_light(inp.desc, objects, paths, seed, cancel, comm)? else {
        return Err(Error::Interrupted { kept: iterate::kept(s, iterated.iterations.len()) });
    };
    iterated.light_paths += 3 * paths;
    for x in &u {
        let p = |v: [f64; 3]| v.map(|x| format!("{:.2}", 100.0 * x)).join(" / ");
        log(&format!(
            "unseen light {}: {} unseen texels; share of its light via unseen texels {} %, albedo shift {} % \
             (fill uncertainty {} %, noise {} %)",
            x.id,
            x.unseen_texels,
            p(x.share),
            p(x.albedo_shift),
            p(x.fill_uncertainty),
            p(x.albedo_noise)
        ));
    }
    warnings.extend(super::unseen::unseen_warnings(&u));
    timings.push("unseen_light", t0.elapsed());
    Ok(u)
}

/// `Err(Interrupted)` once `s.cancel` is set (a stage boundary before the iterations: nothing
/// is kept yet).
fn cancelled(s: &DelightSettings) -> Result<()> {
    if s.cancel.as_ref().is_some_and(|c| c.load(std::sync::atomic::Ordering::Relaxed)) {
        return Err(Error::Interrupted { kept: iterate::kept(s, 0) });
    }
    Ok(())
}
