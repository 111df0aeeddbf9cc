//! The de-lighting pipeline ([`delight`], steps 1–6 of the module documentation of
//! [`super`]): atlases, luminance maps, direct irradiance, the albedo update with its [0, 1]
//! correction, the light-tracing iterations with outlier-robust error statistics, the
//! super-resolved luminance after the first pass, and the debug outputs of
//! [`super::DebugSettings`]. The light-traced indirect irradiance is smoothed over the texels
//! light reaches only ([`smooth_in_charts_masked`]), so enclosed texels (under a box standing on
//! the object) do not darken the contact edges. Tests: `tests/delight.rs` (round trip on a small
//! Cornell box), `masked_smoothing_ignores_enclosed_texels` here.

// Index loops over parallel per-texel arrays read more clearly than zipped iterators here.
#![allow(clippy::needless_range_loop)]

use super::atlas::{Atlas, NO_TRI};
use super::timing::{StageClock, Timings};
use super::views::{PureBuffer, View};
use super::*;
use opal::error::{Error, Result};
use opal::integrator::light_tracer::{self, IrradianceTarget, LightTraceSettings};
use opal::math::{PI, Vec3};
use opal::scene::Scene;
use opal::scene::desc::{BsdfDesc, SceneDesc, TextureDesc};
use rayon::prelude::*;

fn bbox(points: impl Iterator<Item = Vec3>) -> (Vec3, Vec3) {
    let mut lo = Vec3::splat(f32::MAX);
    let mut hi = Vec3::splat(f32::MIN);
    for p in points {
        lo = lo.min(p);
        hi = hi.max(p);
    }
    (lo, hi)
}

/// Size of the bitmap reflectance of a diffuse (or two-sided diffuse) BSDF, if any.
fn existing_texture_size(b: &BsdfDesc) -> Option<(usize, usize)> {
    match b {
        BsdfDesc::Diffuse { reflectance: TextureDesc::Bitmap(bm) } => Some((bm.image.width, bm.image.height)),
        BsdfDesc::TwoSided(inner) => existing_texture_size(inner),
        _ => None,
    }
}

/// Calls `f(j)` for the texels `j` of texel `i`'s chart (`chart[j] == chart[i]`) within `r`
/// texels of `i` along one axis of the `w × h` atlas, in increasing order: the window of the
/// separable in-chart box filters.
#[inline]
fn chart_window(
    i: usize,
    r: usize,
    horizontal: bool,
    (w, h): (usize, usize),
    chart: &[u32],
    mut f: impl FnMut(usize),
) {
    let (x, y) = ((i % w) as i64, (i / w) as i64);
    for d in -(r as i64)..=(r as i64) {
        let (xx, yy) = if horizontal { (x + d, y) } else { (x, y + d) };
        if xx < 0 || yy < 0 || xx >= w as i64 || yy >= h as i64 {
            continue;
        }
        let j = yy as usize * w + xx as usize;
        if chart[j] == chart[i] {
            f(j);
        }
    }
}

/// Box filter of radius `r` texels within charts (separable, normalised over covered texels of
/// the same chart).
pub fn smooth_in_charts(v: &[[f32; 3]], a: &Atlas, r: usize) -> Vec<[f32; 3]> {
    if r == 0 {
        return v.to_vec();
    }
    let (w, h) = (a.width, a.height);
    let chart: Vec<u32> = (0..w * h).map(|i| a.texel_chart(i)).collect();
    let pass = |src: &[[f32; 3]], horizontal: bool| -> Vec<[f32; 3]> {
        (0..w * h)
            .into_par_iter()
            .map(|i| {
                if chart[i] == u32::MAX {
                    return src[i];
                }
                let mut acc = [0f64; 3];
                let mut k = 0f64;
                chart_window(i, r, horizontal, (w, h), &chart, |j| {
                    for c in 0..3 {
                        acc[c] += src[j][c] as f64;
                    }
                    k += 1.0;
                });
                acc.map(|x| (x / k) as f32)
            })
            .collect()
    };
    let t = pass(v, true);
    pass(&t, false)
}

/// Box filter of radius `r` texels within charts over the texels of `mask` only (normalised
/// convolution: per masked texel the mean of the masked texels of its chart in the `(2r+1)²`
/// window); texels outside the mask (and texels of no chart) keep their own value.
///
/// Used for the light-traced indirect irradiance with `mask` = the texels light can reach
/// ([`reached_texels`]): the floor under a box standing on it receives nothing, and a plain box
/// filter would average those zeros into the texels along the contact edge — their irradiance
/// too low, their albedo too bright in an `r`-texel band (+20 % next to the edge, measured on
/// the room data set of `tests/delight_room.rs`).
pub fn smooth_in_charts_masked(v: &[[f32; 3]], a: &Atlas, r: usize, mask: &[bool]) -> Vec<[f32; 3]> {
    let (w, h) = (a.width, a.height);
    let chart: Vec<u32> = (0..w * h).map(|i| a.texel_chart(i)).collect();
    // per texel: (sum of the masked values, number of masked texels) along one axis
    let pass = |src: &[([f64; 3], f64)], horizontal: bool| -> Vec<([f64; 3], f64)> {
        (0..w * h)
            .into_par_iter()
            .map(|i| {
                let mut acc = ([0f64; 3], 0f64);
                if chart[i] == u32::MAX {
                    return acc;
                }
                chart_window(i, r, horizontal, (w, h), &chart, |j| {
                    for c in 0..3 {
                        acc.0[c] += src[j].0[c];
                    }
                    acc.1 += src[j].1;
                });
                acc
            })
            .collect()
    };
    let init: Vec<([f64; 3], f64)> =
        (0..w * h).map(|i| if mask[i] { (v[i].map(|x| x as f64), 1.0) } else { ([0.0; 3], 0.0) }).collect();
    let t = pass(&init, true);
    let s = pass(&t, false);
    (0..w * h)
        .map(|i| {
            if mask[i] && chart[i] != u32::MAX && s[i].1 > 0.0 {
                s[i].0.map(|x| (x / s[i].1) as f32)
            } else {
                v[i]
            }
        })
        .collect()
}

/// Texels light reaches, for [`smooth_in_charts_masked`]: observed by a view (a camera sees
/// them from the open scene), or with direct irradiance, or with indirect irradiance (a
/// light-tracing deposit). The others are enclosed (under a box standing on the object) or so
/// dim that no deposit reached them.
pub fn reached_texels(observed: &[bool], ed: &[[f32; 3]], ei: &[[f32; 3]]) -> Vec<bool> {
    observed.iter().zip(ed).zip(ei).map(|((&o, d), i)| o || d.iter().chain(i).any(|&x| x > 0.0)).collect()
}

/// `Kd = π L / (Ed + Ei)` with the [0, 1] correction (raises `Ei` where `Kd > 1`); returns the
/// number of clamped texel-channels.
fn update_kd(o: &mut ObjectResult) -> usize {
    let mut clamped = 0;
    let n = o.kd.len();
    let covered: Vec<bool> = (0..n).map(|i| o.atlas.texel_tri[i] != NO_TRI).collect();
    for i in 0..n {
        if !o.observed[i] {
            continue;
        }
        for c in 0..3 {
            let l = o.l[i][c].max(0.0);
            let e = o.ed[i][c] + o.ei[i][c];
            let pl = PI * l;
            if pl > e {
                // Kd would exceed 1: smallest admissible Ei
                o.ei[i][c] = (pl - o.ed[i][c]).max(0.0);
                o.kd[i][c] = if pl > 0.0 { 1.0 } else { 0.0 };
                clamped += 1;
            } else {
                o.kd[i][c] = if e > 0.0 { pl / e } else { 0.0 };
            }
        }
    }
    let r = (o.atlas.width / 16).max(4);
    let chart: Vec<u32> = (0..n).map(|i| o.atlas.texel_chart(i)).collect();
    let left = inpaint::inpaint(&mut o.kd, &o.observed, &covered, &chart, o.atlas.width, o.atlas.height, r);
    if left > 0 {
        // charts seen by no view: the mean of the observed texels
        let m = o.mean_kd_observed();
        let (kd, obs) = (&mut o.kd, &o.observed);
        let seen: std::collections::HashSet<u32> = (0..n).filter(|&i| obs[i]).map(|i| chart[i]).collect();
        for i in 0..n {
            if covered[i] && !obs[i] && !seen.contains(&chart[i]) {
                kd[i] = m.map(|v| v as f32);
            }
        }
    }
    inpaint::dilate(&mut o.kd, &covered, &o.atlas.texel_owner, o.atlas.width, o.atlas.height, 4);
    clamped
}

fn quartiles(v: &mut [f64]) -> (f64, f64) {
    v.sort_by(f64::total_cmp);
    let q = |f: f64| {
        let x = f * (v.len() - 1) as f64;
        let (i, t) = (x.floor() as usize, x - x.floor());
        if i + 1 < v.len() { v[i] * (1.0 - t) + v[i + 1] * t } else { v[i] }
    };
    (q(0.25), q(0.75))
}

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
    // selection
    let selected: Vec<usize> = match &s.objects {
        Some(names) => {
            let mut v = Vec::new();
            for n in names {
                let k = scene.shapes.iter().position(|sh| &sh.id == n).ok_or_else(|| {
                    let ids: Vec<&str> = scene.shapes.iter().map(|s| s.id.as_str()).collect();
                    Error::invalid(
                        format!("selected object {n}"),
                        format!("no shape with that id (have: {})", ids.join(", ")),
                    )
                })?;
                if scene.shapes[k].emission.is_some() {
                    return Err(Error::invalid(
                        format!("selected object {n}"),
                        "is an emitter; only non-emitting shapes can be recovered",
                    ));
                }
                v.push(k);
            }
            v
        }
        None => (0..scene.shapes.len()).filter(|&k| scene.shapes[k].emission.is_none()).collect(),
    };
    if selected.is_empty() {
        return Err(Error::invalid("scene", "no non-emitting shape to recover"));
    }
    let cams: Vec<(Vec3, f32, usize)> =
        views.iter().map(|v| (v.camera.origin(), v.camera.tan_half_x, v.camera.width)).collect();
    // 1. atlases
    let t0 = StageClock::start();
    let mut objects = Vec::new();
    let mut skipped = Vec::new();
    for &k in &selected {
        let sh = &desc.shapes[k];
        // an object that keeps its UVs and already has a square bitmap texture gets a texture
        // of the same size (the recovered map replaces it texel for texel); otherwise adaptive
        let tex_res = existing_texture_size(&sh.bsdf).filter(|&(w, h)| w == h && s.keep_uvs).map(|(w, _)| w);
        let auto = || atlas::auto_resolution(&sh.mesh, &cams);
        let res = s.resolution.or(tex_res).unwrap_or_else(auto);
        let built = match atlas::build_atlas(&sh.mesh, res, s.keep_uvs) {
            Ok(a) if !a.kept_uvs && s.resolution.is_none() && tex_res.is_some() => {
                atlas::build_atlas(&sh.mesh, auto(), s.keep_uvs)
            }
            other => other,
        };
        match built {
            Ok(a) => {
                let n = a.width * a.height;
                log(&format!(
                    "atlas {}: {}×{}, {} chart(s), {} UVs",
                    sh.id,
                    a.width,
                    a.height,
                    a.charts,
                    if a.kept_uvs { "kept" } else { "new" }
                ));
                objects.push(ObjectResult {
                    shape: k,
                    id: sh.id.clone(),
                    atlas: a,
                    l: vec![[0.0; 3]; n],
                    observed: vec![false; n],
                    ed: vec![[0.0; 3]; n],
                    ei: vec![[0.0; 3]; n],
                    kd: vec![[0.0; 3]; n],
                    near_emitter: false,
                    seen_fraction: 0.0,
                    clamped: 0,
                });
            }
            Err(e) => {
                warnings.push(format!("object '{}' skipped: UV unwrap failed: {e}", sh.id));
                skipped.push((sh.id.clone(), format!("UV unwrap failed: {e}")));
            }
        }
    }
    if objects.is_empty() {
        return Err(Error::invalid("objects", "no object could be unwrapped"));
    }
    timings.push("unwrap", t0.elapsed());
    // 4. direct irradiance (first: it shapes the prior of the super-resolved luminance maps)
    let t0 = StageClock::start();
    for (j, o) in objects.iter_mut().enumerate() {
        o.ed =
            direct_irradiance(&scene, &o.atlas, s.direct_samples, s.direct_pilot, s.seed, 0xED00 + j as u64);
    }
    timings.push("direct", t0.elapsed());
    // 5. initial Kd
    let mut avg = [0f64; 3];
    let mut aw = 0f64;
    for o in &objects {
        for i in 0..o.ed.len() {
            let t = o.atlas.texel_tri[i];
            if t != NO_TRI {
                let a = o.atlas.texel_area[t as usize] as f64;
                for c in 0..3 {
                    avg[c] += a * o.ed[i][c] as f64;
                }
                aw += a;
            }
        }
    }
    let avg = avg.map(|v| (v / aw.max(1e-30)) as f32);
    // 2–3. luminance maps
    let t0 = StageClock::start();
    // per-view pose refinement (off by default); every later step sees the refined views
    let tp = StageClock::start();
    let (poses, refined) = pose::pipeline_stage(&scene, &objects, views, &s.poses, log, &mut warnings);
    let views: &[View] = refined.as_deref().unwrap_or(views);
    if poses.is_some() {
        timings.push("poses", tp.elapsed());
    }
    let pure: Vec<PureBuffer> = views.iter().map(|v| views::pure_buffer(&scene, &v.camera)).collect();
    // per-view gains from the overlap of the views; every later step sees the corrected views
    let mut view_gains = None;
    let corrected: Option<Vec<View>> = if s.view_gains.mode != ViewGainMode::Fixed {
        let tg = StageClock::start();
        let objs: Vec<(u32, &Atlas)> = objects.iter().map(|o| (o.shape as u32, &o.atlas)).collect();
        let (g, w) = gains::estimate_view_gains(&scene, &objs, views, &pure, &s.view_gains);
        for vg in &g.views {
            log(&format!(
                "gain {}: {:.4} {:.4} {:.4} (± {:.4} {:.4} {:.4}, {} samples)",
                vg.view,
                vg.gain[0],
                vg.gain[1],
                vg.gain[2],
                vg.std_err[0],
                vg.std_err[1],
                vg.std_err[2],
                vg.samples
            ));
        }
        warnings.extend(w);
        let c = apply_view_gains(views, &g);
        view_gains = Some(g);
        timings.push("gains", tg.elapsed());
        Some(c)
    } else {
        None
    };
    let views: &[View] = corrected.as_deref().unwrap_or(views);
    let (slo, shi) = scene.bounds();
    let diag = (shi - slo).length();
    let emit_boxes: Vec<(Vec3, Vec3)> = scene
        .shapes
        .iter()
        .filter(|s| s.emission.is_some())
        .map(|s| bbox(s.mesh.positions.iter().copied()))
        .collect();
    for o in &mut objects {
        let (mut l, mut obs) = luminance_map(&scene, o.shape as u32, &o.atlas, views, &pure);
        // super-resolution here only when no light-tracing pass gives the shading (see below)
        if s.iterations == 0
            && let Some(sr) = &s.superres
            && let Some((ls, os)) = superres::superres_luminance(
                &scene,
                o.shape as u32,
                &o.atlas,
                views,
                &pure,
                (&l, &obs),
                None,
                sr,
            )
        {
            l = ls;
            obs = os;
        }
        o.l = l;
        o.observed = obs;
        let (lo, hi) = bbox(o.atlas.mesh.positions.iter().copied());
        o.near_emitter = emit_boxes.iter().any(|(elo, ehi)| {
            let gap = (*elo - hi).max(lo - *ehi).max(Vec3::ZERO);
            gap.length() < 0.05 * diag
        });
        let left = finish_luminance(o);
        if o.seen_fraction == 0.0 {
            warnings.push(format!(
                "object '{}' is seen by no view: its albedo is the scene average (flagged)",
                o.id
            ));
        } else if left > 0 {
            warnings.push(format!(
                "object '{}': {left} texels in charts seen by no view were filled with the object's mean",
                o.id
            ));
        }
        log(&format!(
            "luminance {}: {:.1} % of texels seen{}",
            o.id,
            100.0 * o.seen_fraction,
            if o.near_emitter { ", near an emitter (median)" } else { "" }
        ));
    }
    timings.push("luminance", t0.elapsed());
    // 5. initial Kd
    for o in &mut objects {
        for i in 0..o.ed.len() {
            for c in 0..3 {
                let e = o.ed[i][c];
                o.ei[i][c] = s.indirect_share * if e > 0.0 { e } else { avg[c] };
            }
        }
        o.clamped = update_kd(o);
    }
    // unseen objects: scene-average albedo of the seen ones
    fill_unseen(&mut objects);
    // 6. iterations
    let targets: Vec<Option<IrradianceTarget>> = (0..desc.shapes.len())
        .map(|k| {
            objects.iter().find(|o| o.shape == k).map(|o| IrradianceTarget {
                width: o.atlas.width,
                height: o.atlas.height,
                texel_area: o.atlas.texel_area.clone(),
            })
        })
        .collect();
    let mut iterations = Vec::new();
    let mut converged = false;
    let mut light_paths = 0;
    let (mut lt_wall, mut lt_cpu, mut post_wall, mut post_cpu) = (0f64, 0f64, 0f64, 0f64);
    let t_it = StageClock::start();
    for k in 1..=s.iterations {
        let t0 = std::time::Instant::now();
        let c0 = StageClock::start();
        let rdesc = recovered_desc(desc, &objects);
        let rscene = Scene::build(&rdesc)?;
        let lt = LightTraceSettings {
            paths: s.light_paths,
            batch_size: 1 << 20,
            max_depth: -1,
            rr_depth: 5,
            seed: s.seed.wrapping_add(k as u64),
            // first-hit irradiance does not depend on the albedos: its diagnostic (`direct_ratio`)
            // is measured in the first pass only; the method uses the indirect map
            direct: k == 1,
        };
        let out = light_tracer::trace(&rscene, &targets, &lt, &|| {});
        let (w, c) = c0.elapsed();
        lt_wall += w;
        lt_cpu += c;
        let c0 = StageClock::start();
        light_paths += out.paths;
        if out.nonfinite > 0 {
            warnings
                .push(format!("iteration {k}: {} non-finite light-tracing deposits dropped", out.nonfinite));
        }
        let mut per_object = Vec::new();
        let mut error_maps = Vec::new();
        let mut direct_ratio = Vec::new();
        let (mut gmax, mut gsum, mut gcount) = (0f64, 0f64, 0usize);
        // objects in parallel (smoothing, error statistics, update and inpainting of each)
        let post: Vec<_> = objects
            .par_iter_mut()
            .map(|o| {
                let m = out.maps[o.shape].as_ref().expect("target");
                let r = s.smooth.unwrap_or((o.atlas.width / 64).max(1));
                let cov = &o.atlas.coverage;
                let ei_raw: Vec<[f32; 3]> = m
                    .indirect
                    .iter()
                    .zip(cov)
                    .map(|(e, &c)| e.map(|x| (x / c.max(1.0 / 16.0) as f64) as f32))
                    .collect();
                // over the texels light reaches only: the zeros of enclosed texels (under a box
                // standing on the object) would darken the contact edges
                let reach = reached_texels(&o.observed, &o.ed, &ei_raw);
                let ei_r = smooth_in_charts_masked(&ei_raw, &o.atlas, r, &reach);
                // direct consistency (means over covered texels; first pass only: the later
                // passes deposit no first hits)
                let (mut a, mut b) = (0f64, 0f64);
                if !m.direct.is_empty() {
                    for i in 0..o.ed.len() {
                        if o.atlas.texel_tri[i] != NO_TRI {
                            a += luminance(m.direct[i].map(|x| x as f32)) as f64
                                / cov[i].max(1.0 / 16.0) as f64;
                            b += luminance(o.ed[i]) as f64;
                        }
                    }
                }
                let ratio = if b > 0.0 { a / b } else { f64::NAN };
                // error map
                let n = o.l.len();
                let mut rel = vec![f32::NAN; n];
                let mut vals = Vec::new();
                let mut e_abs = vec![[0f32; 3]; n];
                for i in 0..n {
                    if !o.observed[i] {
                        continue;
                    }
                    let lr: [f32; 3] = std::array::from_fn(|c| o.kd[i][c] / PI * (o.ed[i][c] + ei_r[i][c]));
                    e_abs[i] = std::array::from_fn(|c| o.l[i][c] - lr[c]);
                    let y = luminance(o.l[i]);
                    if y > 0.0 {
                        rel[i] = (y - luminance(lr)) / y;
                        vals.push(rel[i] as f64);
                    }
                }
                let (mut omax, mut osum, mut ocount, mut outl) = (0f64, 0f64, 0usize, 0usize);
                if !vals.is_empty() {
                    let (q1, q3) = quartiles(&mut vals);
                    let iqr = q3 - q1;
                    let (lo, hi) = (q1 - 1.5 * iqr, q3 + 1.5 * iqr);
                    for i in 0..n {
                        let r = rel[i] as f64;
                        if r.is_nan() {
                            continue;
                        }
                        if r < lo || r > hi {
                            outl += 1;
                            e_abs[i] = [0.0; 3];
                            continue;
                        }
                        omax = omax.max(r.abs());
                        osum += r.abs();
                        ocount += 1;
                    }
                }
                // update Ei
                match s.update {
                    UpdateRule::FixedPoint => {
                        // under-relaxed fixed point: the plain map oscillates (period 2) in a
                        // closed, bright room; averaging also halves the Monte-Carlo variance
                        for i in 0..n {
                            for c in 0..3 {
                                o.ei[i][c] =
                                    if k == 1 { ei_r[i][c] } else { 0.5 * (o.ei[i][c] + ei_r[i][c]) };
                            }
                        }
                    }
                    UpdateRule::Paper { alpha0 } => {
                        let alpha = alpha0 / (1.0 + k as f32);
                        for i in 0..n {
                            for c in 0..3 {
                                o.ei[i][c] = (o.ei[i][c] + alpha * o.kd[i][c] / PI * e_abs[i][c]).max(0.0);
                            }
                        }
                    }
                }
                o.clamped = update_kd(o);
                if s.debug.print {
                    let mut acc = [[0f64; 3]; 4];
                    let mut cnt = 0f64;
                    for i in 0..n {
                        if o.observed[i] {
                            cnt += 1.0;
                            for c in 0..3 {
                                acc[0][c] += o.l[i][c] as f64;
                                acc[1][c] += o.ed[i][c] as f64;
                                acc[2][c] += o.ei[i][c] as f64;
                                acc[3][c] += o.kd[i][c] as f64;
                            }
                        }
                    }
                    log(&format!(
                        "  {}: L {:.4?} Ed {:.4?} Ei {:.4?} Kd {:.4?} clamped {}",
                        o.id,
                        acc[0].map(|v| v / cnt),
                        acc[1].map(|v| v / cnt),
                        acc[2].map(|v| v / cnt),
                        acc[3].map(|v| v / cnt),
                        o.clamped
                    ));
                }
                (omax, osum, ocount, outl, rel, ratio)
            })
            .collect();
        for (omax, osum, ocount, outl, rel, ratio) in post {
            gmax = gmax.max(omax);
            gsum += osum;
            gcount += ocount;
            per_object.push((omax, osum / ocount.max(1) as f64, outl));
            error_maps.push(rel);
            direct_ratio.push(ratio);
        }
        // multi-view super-resolution once the first pass gives the indirect irradiance: its
        // prior acts on B / (Ed + Ei), i.e. on the albedo rather than on the lighting
        let (w, c) = c0.elapsed();
        post_wall += w;
        post_cpu += c;
        if k == 1
            && let Some(sr) = &s.superres
        {
            let t1 = StageClock::start();
            // objects in parallel (each solve is parallel inside too, but its many short
            // parallel loops leave a core idle on small objects); the result of each object does
            // not depend on the thread count
            let msgs: Vec<Option<String>> = objects
                .par_iter_mut()
                .map(|o| {
                    let to = std::time::Instant::now();
                    // the indirect part smoothed further (low-frequency; its Monte-Carlo noise would
                    // otherwise enter the prior's albedo estimate)
                    let reach = reached_texels(&o.observed, &o.ed, &o.ei);
                    let ei = smooth_in_charts_masked(&o.ei, &o.atlas, (o.atlas.width / 16).max(1), &reach);
                    let mut shading: Vec<f32> =
                        o.ed.iter()
                            .zip(&ei)
                            .map(|(d, i)| luminance(std::array::from_fn(|c| d[c] + i[c])))
                            .collect();
                    if let Some(p) = &s.debug.shading {
                        // error analysis: a given irradiance map (e.g. the true one) instead
                        if let Ok(img) = opal::image::read::read_image(p)
                            && img.data.len() == shading.len()
                        {
                            shading = img.data.iter().map(|v| luminance(v.0)).collect();
                        }
                    }
                    if let Some((ls, os)) = superres::superres_luminance(
                        &scene,
                        o.shape as u32,
                        &o.atlas,
                        views,
                        &pure,
                        (&o.l, &o.observed),
                        Some(&shading),
                        sr,
                    ) {
                        o.l = ls;
                        o.observed = os;
                        finish_luminance(o);
                        o.clamped = update_kd(o);
                        Some(format!(
                            "super-resolved luminance {}: {:.1} % of texels seen ({:.1} s)",
                            o.id,
                            100.0 * o.seen_fraction,
                            to.elapsed().as_secs_f64()
                        ))
                    } else {
                        None
                    }
                })
                .collect();
            msgs.iter().flatten().for_each(|m| log(m));
            timings.push("superres", t1.elapsed());
        }
        let c0 = StageClock::start();
        fill_unseen(&mut objects);
        let st = IterationStats {
            iteration: k,
            max_rel_error: gmax,
            mean_rel_error: gsum / gcount.max(1) as f64,
            per_object,
            error_maps,
            seconds: t0.elapsed().as_secs_f64(),
            direct_ratio,
        };
        log(&format!(
            "iteration {k}: max rel. error {:.2} %, mean {:.2} % ({:.1} s, {} light paths)",
            100.0 * st.max_rel_error,
            100.0 * st.mean_rel_error,
            st.seconds,
            s.light_paths
        ));
        let done = st.max_rel_error < s.tolerance;
        iterations.push(st);
        let (w, c) = c0.elapsed();
        post_wall += w;
        post_cpu += c;
        if done {
            converged = true;
            break;
        }
    }
    debug_dump(&objects, "final", s.debug.dump_dir.as_deref());
    timings.push("iterations", t_it.elapsed());
    timings.push("light_tracing", (lt_wall, lt_cpu));
    timings.push("iteration_post", (post_wall, post_cpu));
    timings.push("total", t_all.elapsed());
    let Timings { wall: timings, cpu: cpu_timings } = timings;
    Ok(DelightResult {
        objects,
        skipped,
        iterations,
        converged,
        view_gains,
        poses,
        warnings,
        timings,
        cpu_timings,
        light_paths,
    })
}

/// Seen fraction, median filter next to emitters and inpainting of the holes of a new luminance
/// map; returns the number of texels left unfilled (charts seen by no view).
fn finish_luminance(o: &mut ObjectResult) -> usize {
    let covered = o.atlas.covered().max(1);
    o.seen_fraction = o.observed.iter().filter(|&&b| b).count() as f64 / covered as f64;
    let chart: Vec<u32> = (0..o.l.len()).map(|i| o.atlas.texel_chart(i)).collect();
    let (w, h) = (o.atlas.width, o.atlas.height);
    if o.near_emitter {
        inpaint::median3(&mut o.l, &o.observed, &chart, w, h);
    }
    let covered_mask: Vec<bool> = (0..o.l.len()).map(|i| o.atlas.texel_tri[i] != NO_TRI).collect();
    inpaint::inpaint(&mut o.l, &o.observed, &covered_mask, &chart, w, h, (w / 16).max(4))
}

/// Debug dump ([`DebugSettings::dump_dir`]): per object the luminance map, observed mask, direct
/// and indirect irradiance and albedo as EXR files (`<id>_<tag>_<what>.exr`), for error analysis.
fn debug_dump(objects: &[ObjectResult], tag: &str, dir: Option<&std::path::Path>) {
    let Some(dir) = dir else { return };
    let _ = std::fs::create_dir_all(dir);
    for o in objects {
        let (w, h) = (o.atlas.width, o.atlas.height);
        let obs: Vec<[f32; 3]> = o.observed.iter().map(|&b| [b as u8 as f32; 3]).collect();
        for (what, v) in [("l", &o.l), ("obs", &obs), ("ed", &o.ed), ("ei", &o.ei), ("kd", &o.kd)] {
            let path = dir.join(format!("{}_{tag}_{what}.exr", o.id));
            if let Ok(f) = std::fs::File::create(&path) {
                let _ = opal::image::write::write_exr(&to_image(v, w, h), std::io::BufWriter::new(f));
            }
        }
    }
}

fn fill_unseen(objects: &mut [ObjectResult]) {
    let mut acc = [0f64; 3];
    let mut w = 0f64;
    for o in objects.iter().filter(|o| o.seen_fraction > 0.0) {
        let m = o.mean_kd();
        let a = o.atlas.mesh.area();
        for c in 0..3 {
            acc[c] += a * m[c];
        }
        w += a;
    }
    if w <= 0.0 {
        return;
    }
    let mean = acc.map(|v| (v / w) as f32);
    for o in objects.iter_mut().filter(|o| o.seen_fraction == 0.0) {
        o.kd.iter_mut().for_each(|k| *k = mean);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::delight::atlas::build_atlas;
    use opal::scene::load::rectangle_mesh;

    /// A 32² map of constant irradiance 1 with an enclosed 8×8 block of zeros (the floor under a
    /// box): the plain filter darkens the texels next to the block, the masked one over the
    /// reached texels keeps them exact and leaves the enclosed texels at zero.
    #[test]
    fn masked_smoothing_ignores_enclosed_texels() {
        let a = build_atlas(&rectangle_mesh(), 32, true).unwrap();
        let n = a.width * a.height;
        let inside = |i: usize| (12..20).contains(&(i % 32)) && (12..20).contains(&(i / 32));
        let v: Vec<[f32; 3]> = (0..n).map(|i| if inside(i) { [0.0; 3] } else { [1.0, 2.0, 3.0] }).collect();
        let observed: Vec<bool> = (0..n).map(|i| !inside(i) && i % 7 != 0).collect();
        let ed = vec![[0f32; 3]; n];
        let reach = reached_texels(&observed, &ed, &v);
        // unobserved texels with a deposit count as reached, the enclosed block does not
        assert!((0..n).all(|i| reach[i] != inside(i)));
        let plain = smooth_in_charts(&v, &a, 4);
        let masked = smooth_in_charts_masked(&v, &a, 4, &reach);
        let next_to_block = 11 + 16 * 32; // one texel left of the block
        assert!(plain[next_to_block][0] < 0.8, "{:?}", plain[next_to_block]);
        for i in 0..n {
            let want = if inside(i) { [0.0; 3] } else { [1.0, 2.0, 3.0] };
            for c in 0..3 {
                assert!((masked[i][c] - want[c]).abs() < 1e-5, "texel {i}: {:?}", masked[i]);
            }
        }
        // with every texel reached: the mean over the (2r+1)² window clipped to the map
        let all = vec![true; n];
        let ramp: Vec<[f32; 3]> = (0..n).map(|i| [(i % 32) as f32; 3]).collect();
        let m = smooth_in_charts_masked(&ramp, &a, 2, &all);
        assert!((m[10 + 5 * 32][0] - 10.0).abs() < 1e-5);
        assert!((m[5 * 32][0] - 1.0).abs() < 1e-5); // columns 0, 1, 2
        assert_eq!(smooth_in_charts_masked(&ramp, &a, 0, &all), ramp);
    }
}
