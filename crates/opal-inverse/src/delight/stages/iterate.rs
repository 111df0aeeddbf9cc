//! Stage 4 of [`delight`](crate::delight::delight): the light-tracing iterations. Each pass
//! traces the scene with the current albedos ([`opal::integrator::light_tracer`], importance
//! transport) for the indirect irradiance `Ei_r` per texel, smoothed within charts over the
//! texels light reaches ([`smooth_in_charts_masked`]); per object ([`object_pass`]) the error
//! `e = L − Kd/π (Ed + Ei_r)` relative to `L` with quartile (Tukey 1.5·IQR) outlier rejection,
//! the update of `Ei` ([`UpdateRule`]) and of `Kd`. After the first pass the luminance maps are
//! replaced by the super-resolved ones ([`superres_pass`]). Stops once a pass changes no tile
//! by more than the tolerance beyond its noise ([`convergence`], per tile [`change_tiles`]) or at
//! the iteration limit. Tests: `tests/delight.rs` (round trip on a small Cornell box, the stop
//! rule `round_trip_small_cbox_stops_when_converged`).

// Index loops over parallel per-texel arrays read more clearly than zipped iterators here.
#![allow(clippy::needless_range_loop)]

use super::Inputs;
use crate::delight::albedo::{fill_unseen, finish_luminance, quartiles, update_kd};
use crate::delight::atlas::NO_TRI;
use crate::delight::checkpoint;
use crate::delight::convergence::TileSums;
use crate::delight::progress::Stage;
use crate::delight::timing::{StageClock, Timings};
use crate::delight::views::{PureBuffer, View};
use crate::delight::{
    DelightSettings, IterationStats, LightPaths, ObjectResult, UpdateRule, convergence, luminance, noise,
    reached_texels, recovered_desc, smooth_in_charts_masked, split, superres,
};
use opal::error::{Error, Result};
use opal::integrator::light_tracer::{self, IrradianceMaps, IrradianceTarget, LightTraceSettings};
use opal::math::PI;
use opal::scene::Scene;

/// What the iterations leave besides the objects.
pub(in crate::delight) struct Iterated {
    /// Statistics per iteration.
    pub iterations: Vec<IterationStats>,
    /// A pass changed no tile by more than the tolerance beyond its noise ([`stops`]).
    pub converged: bool,
    /// Light paths traced in total.
    pub light_paths: u64,
}

/// One object's part of an iteration: error statistics over the inliers and the maps.
struct ObjectPass {
    /// Max |relative error| over the inliers.
    max: f64,
    /// Sum of |relative error| over the inliers.
    sum: f64,
    /// Number of inliers.
    count: usize,
    /// Number of outliers.
    outliers: usize,
    /// Relative luminance error per texel (NaN where not observed).
    rel: Vec<f32>,
    /// Tracer's direct irradiance / light-sampled `Ed` (NaN after the first pass).
    direct_ratio: f64,
    /// Achieved relative per-texel noise of the raw indirect irradiance.
    noise: f64,
    /// Its residuals, corrected for the smoothing window (pooled over the objects).
    residuals: Vec<f64>,
    /// The pass's change per tile of the atlas ([`convergence`]).
    tiles: Vec<TileSums>,
}

impl ObjectPass {
    /// Writes the pass's results exactly (for the other processes).
    fn put(&self, p: &mut opal::dist::Packer) {
        for x in [self.max, self.sum, self.direct_ratio, self.noise] {
            p.f64(x);
        }
        p.u64(self.count as u64);
        p.u64(self.outliers as u64);
        p.u64(self.rel.len() as u64);
        p.f32s(&self.rel);
        p.u64(self.residuals.len() as u64);
        self.residuals.iter().for_each(|&x| p.f64(x));
        p.u64(self.tiles.len() as u64);
        for t in &self.tiles {
            [t.w, t.wd, t.w2v].iter().for_each(|&x| p.f64(x));
            p.u64(t.n);
        }
    }
    /// Reads what [`ObjectPass::put`] wrote.
    fn get(u: &mut opal::dist::Unpacker) -> ObjectPass {
        let [max, sum, direct_ratio, noise] = std::array::from_fn(|_| u.f64());
        let count = u.u64() as usize;
        let outliers = u.u64() as usize;
        let n = u.u64() as usize;
        let rel = (0..n).map(|_| u.f32()).collect();
        let n = u.u64() as usize;
        let residuals = (0..n).map(|_| u.f64()).collect();
        let n = u.u64() as usize;
        let tiles = (0..n).map(|_| TileSums { w: u.f64(), wd: u.f64(), w2v: u.f64(), n: u.u64() }).collect();
        ObjectPass { max, sum, count, outliers, rel, direct_ratio, noise, residuals, tiles }
    }
}

/// Runs the light-tracing iterations on `objects` (luminance, direct irradiance and initial
/// albedo set); stage clocks `superres`, `iterations`, `light_tracing`, `iteration_post`.
/// `costs`: the measured seconds per object of the last stage split by object
/// ([`split::per_object`]; they balance each pass's post-processing across processes).
pub(in crate::delight) fn iterate(
    inp: &Inputs,
    objects: &mut [ObjectResult],
    views: &[View],
    pure: &[PureBuffer],
    warnings: &mut Vec<String>,
    timings: &mut Timings,
    costs: &mut Vec<f64>,
) -> Result<Iterated> {
    let (desc, s, log) = (inp.desc, inp.s, inp.log);
    let targets = irradiance_targets(desc.shapes.len(), objects);
    let texels: usize = objects.iter().map(|o| o.atlas.width * o.atlas.height).sum();
    let paths = s.light_paths.paths(texels);
    if let LightPaths::TargetNoise(t) = s.light_paths {
        log(&format!(
            "light paths per pass: {paths} for {texels} texels at a target per-texel noise of {:.1} %",
            100.0 * t
        ));
    }
    let mut iterations = Vec::new();
    let mut converged = false;
    let mut light_paths = 0;
    // checkpoints: the state the iterations start from, and the warnings they add
    // (only a process that keeps checkpoints needs it: under MPI the ranks other than 0 keep none)
    let fp = if s.checkpoint.is_some() { checkpoint::fingerprint(objects, s.seed, paths) } else { 0 };
    let mut saver = checkpoint::Saver::default();
    let first_warning = warnings.len();
    let mut start = 1;
    let resume_from = match (s.resume, s.checkpoint.as_deref()) {
        (false, _) => None,
        (true, None) => return Err(Error::invalid("resume", "no checkpoint folder given")),
        // stopped before its first iteration finished: nothing to restore, start at iteration 1
        (true, Some(dir)) if !checkpoint::exists(dir) => {
            log(&format!("no finished iteration in {}: starting from iteration 1", dir.display()));
            None
        }
        (true, Some(dir)) => Some(dir),
    };
    if let Some(dir) = resume_from {
        let saved = checkpoint::load(dir, fp, objects)?;
        for (o, m) in objects.iter_mut().zip(saved.maps) {
            m.restore(o);
        }
        log(&format!("resuming after iteration {} (checkpoint {})", saved.iteration, dir.display()));
        converged = saved.iterations.last().is_some_and(|st| stops(st, s));
        start = if converged { usize::MAX } else { saved.iteration + 1 };
        iterations = saved.iterations;
        light_paths = saved.light_paths;
        warnings.extend(saved.warnings);
    }
    let (mut lt_wall, mut lt_cpu, mut post_wall, mut post_cpu) = (0f64, 0f64, 0f64, 0f64);
    let t_it = StageClock::start();
    for k in start..=s.iterations {
        if s.cancel.as_ref().is_some_and(|c| c.load(std::sync::atomic::Ordering::Relaxed)) {
            saver.wait()?;
            return Err(Error::Interrupted { kept: kept(s, k - 1) });
        }
        let t0 = std::time::Instant::now();
        let c0 = StageClock::start();
        let rdesc = recovered_desc(desc, objects);
        let rscene = Scene::build(&rdesc)?;
        let solo = opal::dist::Solo;
        let comm: &dyn opal::dist::Comm = s.comm.as_deref().unwrap_or(&solo);
        let lt = LightTraceSettings {
            paths,
            // batches of at most 2¹⁸ paths (≈ 0.1 s of one core), at least 16 per process: the
            // workers pull batches from a counter, so the last one to finish waits at most about
            // one batch (the maps do not depend on the batch size)
            batch_size: paths.div_ceil(16 * comm.size() as u64).clamp(1 << 12, 1 << 18),
            max_depth: -1,
            rr_depth: 5,
            seed: s.seed.wrapping_add(k as u64),
            // first-hit irradiance does not depend on the albedos: its diagnostic (`direct_ratio`)
            // is measured in the first pass only; the method uses the indirect map
            direct: k == 1,
        };
        // Ctrl-C during the pass stops it within a batch; the pass is dropped and the last
        // finished iteration (already checkpointed) is what is kept. Under MPI the paths are
        // split across the ranks (same maps, bit for bit).
        let comm0 = comm.comm_seconds();
        // progress in batches: this process's share of the pass's batches
        let batches = paths.div_ceil(lt.batch_size).div_ceil(comm.size() as u64);
        let bar = Stage::start(s.progress.as_ref(), format!("light tracing {k}"), batches);
        let traced =
            light_tracer::trace_split(&rscene, &targets, &lt, &|| bar.step(1), s.cancel.as_deref(), comm);
        bar.finish();
        let Some(out) = traced else {
            saver.wait()?;
            return Err(Error::Interrupted { kept: kept(s, k - 1) });
        };
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
        // objects in parallel (smoothing, error statistics, update and inpainting of each); under
        // several processes each object on one rank, its results then shared
        let bar = Stage::start(s.progress.as_ref(), format!("post {k}"), objects.len() as u64);
        let pass = |_: usize, o: &mut ObjectResult| {
            let m = out.maps[o.shape].as_ref().expect("target");
            let r = object_pass(o, m, k, s, log);
            bar.step(1);
            r
        };
        let post: Vec<ObjectPass> =
            split::per_object(comm, objects, costs, pass, ObjectPass::put, ObjectPass::get);
        drop(bar);
        let mut texel_noise = Vec::new();
        let mut all_residuals = Vec::new();
        let mut tiles = Vec::new();
        for p in post {
            tiles.extend(p.tiles);
            texel_noise.push(p.noise);
            all_residuals.extend(p.residuals);
            gmax = gmax.max(p.max);
            gsum += p.sum;
            gcount += p.count;
            per_object.push((p.max, p.sum / p.count.max(1) as f64, p.outliers));
            error_maps.push(p.rel);
            direct_ratio.push(p.direct_ratio);
        }
        let (w, c) = c0.elapsed();
        post_wall += w;
        post_cpu += c;
        // multi-view super-resolution once the first pass gives the indirect irradiance: its
        // prior acts on B / (Ed + Ei), i.e. on the albedo rather than on the lighting
        if k == 1
            && let Some(sr) = &s.superres
        {
            let t1 = StageClock::start();
            superres_pass(inp, objects, views, pure, sr);
            timings.push("superres", t1.elapsed());
        }
        let c0 = StageClock::start();
        let change = convergence::assess(&tiles, convergence::previous_variance(k, s.update));
        // the residuals are already corrected for their windows
        let texel_noise_all = noise::texel_noise(&all_residuals, usize::MAX);
        drop(all_residuals);
        if let LightPaths::TargetNoise(t) = s.light_paths
            && texel_noise_all > 2.0 * t
        {
            warnings.push(format!(
                "iteration {k}: the per-texel noise of the indirect irradiance is {:.1} %, more than twice \
                 the target {:.1} % (this scene leaves fewer deposits per path than the calibration)",
                100.0 * texel_noise_all,
                100.0 * t
            ));
        }
        fill_unseen(objects);
        // this pass's exchanges: the tracer's maps, and the super-resolved maps after the first
        let comm_seconds = comm.comm_seconds() - comm0;
        let st = IterationStats {
            iteration: k,
            max_rel_error: gmax,
            mean_rel_error: gsum / gcount.max(1) as f64,
            per_object,
            error_maps,
            seconds: t0.elapsed().as_secs_f64(),
            direct_ratio,
            light_paths: paths,
            texel_noise,
            texel_noise_all,
            comm_seconds,
            change_max: change.max_change,
            change_beyond_noise: change.beyond_noise,
            change_regions: change.regions,
        };
        log(&format!(
            "iteration {k}: max rel. error {:.2} %, mean {:.2} % ({:.1} s, {} light paths, per-texel noise {:.1} %); \
             largest change of a region {:.2} %, {:.2} % beyond the noise ({} regions, z = {:.2})",
            100.0 * st.max_rel_error,
            100.0 * st.mean_rel_error,
            st.seconds,
            paths,
            100.0 * st.texel_noise_all,
            100.0 * st.change_max,
            100.0 * st.change_beyond_noise,
            st.change_regions,
            change.z
        ));
        let done = stops(&st, s);
        iterations.push(st);
        if let Some(dir) = &s.checkpoint {
            saver.save(dir, fp, k, light_paths, objects, &iterations, &warnings[first_warning..])?;
        }
        let (w, c) = c0.elapsed();
        post_wall += w;
        post_cpu += c;
        if done {
            converged = true;
            break;
        }
    }
    saver.wait()?;
    timings.push("iterations", t_it.elapsed());
    timings.push("light_tracing", (lt_wall, lt_cpu));
    timings.push("iteration_post", (post_wall, post_cpu));
    Ok(Iterated { iterations, converged, light_paths })
}

/// Whether the run stops after the pass of `st` ([`convergence`]): its change beyond the noise
/// is below the tolerance, and the maps did not change after it was measured (the first pass's
/// statistics precede the super-resolution, so with it a second pass is needed).
fn stops(st: &IterationStats, s: &DelightSettings) -> bool {
    let first = if s.superres.is_some() { 2 } else { 1 };
    st.iteration >= first && st.change_beyond_noise < s.tolerance
}

/// What an interruption after iteration `done` leaves (for [`Error::Interrupted`]).
pub(in crate::delight) fn kept(s: &DelightSettings, done: usize) -> String {
    match (&s.checkpoint, done) {
        (Some(dir), d) if d > 0 => {
            format!("iterations 1-{d} of {} are kept in {}", s.iterations, dir.display())
        }
        _ => "no iteration had finished: nothing was kept".to_string(),
    }
}

/// One object's part of pass `k` with the tracer's maps `m`: the smoothed indirect irradiance,
/// the direct consistency ratio, the error statistics, the update of `Ei` and `Kd`.
fn object_pass(
    o: &mut ObjectResult,
    m: &IrradianceMaps,
    k: usize,
    s: &DelightSettings,
    log: &(dyn Fn(&str) + Sync),
) -> ObjectPass {
    let r = s.smooth.unwrap_or((o.atlas.width / 64).max(1));
    let cov = &o.atlas.coverage;
    let ei_raw: Vec<[f32; 3]> =
        m.indirect.iter().zip(cov).map(|(e, &c)| e.map(|x| (x / c.max(1.0 / 16.0) as f64) as f32)).collect();
    // over the texels light reaches only: the zeros of enclosed texels (under a box standing on
    // the object) would darken the contact edges
    let reach = reached_texels(&o.observed, &o.ed, &ei_raw);
    let ei_r = smooth_in_charts_masked(&ei_raw, &o.atlas, r, &reach);
    // achieved noise: residuals of the raw map against the smoothed one on covered reached texels
    let mask: Vec<bool> = (0..reach.len()).map(|i| reach[i] && o.atlas.texel_tri[i] != NO_TRI).collect();
    let window = (2 * r + 1) * (2 * r + 1);
    let corr = 1.0 / (1.0 - 1.0 / window.max(2) as f64).sqrt();
    let residuals: Vec<f64> =
        noise::texel_residuals(&ei_raw, &ei_r, &mask).iter().map(|x| x * corr).collect();
    let noise = noise::texel_noise(&residuals, usize::MAX);
    let direct_ratio = direct_ratio(o, m);
    let (rel, e_abs, inlier, stats) = error_stats(o, &ei_r);
    let tiles = change_tiles(o, &ei_raw, &ei_r, &inlier, window);
    update_ei(o, &ei_r, &e_abs, k, s.update);
    o.clamped = update_kd(o);
    if s.debug.print {
        debug_print(o, log);
    }
    let (max, sum, count, outliers) = stats;
    ObjectPass { max, sum, count, outliers, rel, direct_ratio, noise, residuals, tiles }
}

/// The pass's change per tile ([`convergence`]): over the covered, observed inlier texels with
/// `Kd < 1` the change `d = (Ei − Ei_raw) / (Ed + Ei)` asked of the current `Ei`, weighted by
/// the coverage, and its noise variance from the raw map's residual against the smoothed one
/// `ei_r` (`window` texels); before the update of `Ei`.
fn change_tiles(
    o: &ObjectResult,
    ei_raw: &[[f32; 3]],
    ei_r: &[[f32; 3]],
    inlier: &[bool],
    window: usize,
) -> Vec<TileSums> {
    let (w, h) = (o.atlas.width, o.atlas.height);
    let mut tiles = vec![TileSums::default(); convergence::TILES_PER_SIDE * convergence::TILES_PER_SIDE];
    let corr = window.max(2) as f64 / (window.max(2) - 1) as f64;
    for i in 0..o.l.len() {
        if !inlier[i] || o.atlas.texel_tri[i] == NO_TRI || o.kd[i].iter().any(|&k| k >= 1.0) {
            continue;
        }
        let old = luminance(o.ei[i]) as f64;
        let total = luminance(o.ed[i]) as f64 + old;
        if total <= 0.0 {
            continue;
        }
        let smooth = luminance(ei_r[i]) as f64;
        let resid = (luminance(ei_raw[i]) as f64 - smooth) / total;
        let cov = o.atlas.coverage[i].max(1.0 / 16.0) as f64;
        tiles[convergence::tile_of(i, w, h)].add(cov, (old - smooth) / total, resid * resid * corr);
    }
    tiles
}

/// Direct consistency: mean of the tracer's first-hit irradiance over the light-sampled `Ed`
/// (means over covered texels; first pass only: the later passes deposit no first hits, NaN).
fn direct_ratio(o: &ObjectResult, m: &IrradianceMaps) -> f64 {
    let cov = &o.atlas.coverage;
    let (mut a, mut b) = (0f64, 0f64);
    if !m.direct.is_empty() {
        for i in 0..o.ed.len() {
            if o.atlas.texel_tri[i] != NO_TRI {
                a += luminance(m.direct[i].map(|x| x as f32)) as f64 / cov[i].max(1.0 / 16.0) as f64;
                b += luminance(o.ed[i]) as f64;
            }
        }
    }
    if b > 0.0 { a / b } else { f64::NAN }
}

/// Error of the current albedo against the luminance with the indirect irradiance `ei_r`:
/// per texel the relative luminance error (NaN where not observed), the absolute RGB error
/// (zero at outliers) and whether it is an inlier, and over the inliers (max, sum, count,
/// outliers).
#[allow(clippy::type_complexity)]
fn error_stats(
    o: &ObjectResult,
    ei_r: &[[f32; 3]],
) -> (Vec<f32>, Vec<[f32; 3]>, Vec<bool>, (f64, f64, usize, usize)) {
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
    let mut inlier = vec![false; n];
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
            inlier[i] = true;
        }
    }
    (rel, e_abs, inlier, (omax, osum, ocount, outl))
}

/// Update of `Ei` after pass `k` by the rule.
fn update_ei(o: &mut ObjectResult, ei_r: &[[f32; 3]], e_abs: &[[f32; 3]], k: usize, rule: UpdateRule) {
    let n = o.l.len();
    match rule {
        UpdateRule::FixedPoint => {
            // under-relaxed fixed point: the plain map oscillates (period 2) in a closed, bright
            // room; averaging also halves the Monte-Carlo variance
            for i in 0..n {
                for c in 0..3 {
                    o.ei[i][c] = if k == 1 { ei_r[i][c] } else { 0.5 * (o.ei[i][c] + ei_r[i][c]) };
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
}

/// [`DebugSettings::print`](crate::delight::DebugSettings::print): the mean observed `L`, `Ed`,
/// `Ei`, `Kd` and the clamped texel-channels of an object.
fn debug_print(o: &ObjectResult, log: &(dyn Fn(&str) + Sync)) {
    let mut acc = [[0f64; 3]; 4];
    let mut cnt = 0f64;
    for i in 0..o.l.len() {
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

/// The super-resolved luminance maps after the first pass, one object after the other: each
/// object's observation operator (a row per pixel of every view that sees it, with its sub-pixel
/// rays' texel taps) is built, solved and dropped before the next object's, so the pass holds
/// the largest object's operator, not all of them (solving the objects in parallel held every
/// operator at once: 50 views of 12 MP at the working size, 1506 MB instead of 328 MB). Each
/// solve is parallel inside, and its result does not depend on the thread count or on the order
/// of the objects. The shading of the prior is
/// `Ed + Ei` with `Ei` smoothed further over resolution/16 texels (low-frequency; its
/// Monte-Carlo noise would otherwise enter the prior's albedo estimate), or the map of
/// [`DebugSettings::shading`](crate::delight::DebugSettings::shading). Under several processes
/// each object is solved by one rank (balanced by texels plus the operator's sub-pixel rays,
/// [`opal::dist::assign_by_cost`]), which sends the object's new maps whole to the others.
fn superres_pass(
    inp: &Inputs,
    objects: &mut [ObjectResult],
    views: &[View],
    pure: &[PureBuffer],
    sr: &superres::SrSettings,
) {
    let (scene, s, log) = (inp.scene, inp.s, inp.log);
    let solo = opal::dist::Solo;
    let comm: &dyn opal::dist::Comm = s.comm.as_deref().unwrap_or(&solo);
    let owner = if comm.size() > 1 {
        // cost estimate: the size of the solve's system, unknowns (texels) plus the operator's
        // sub-pixel rays (S² per pure pixel of the object)
        let rays = (sr.subsamples * sr.subsamples) as usize;
        let costs: Vec<f64> = objects
            .iter()
            .map(|o| {
                let px: usize =
                    pure.iter().map(|p| p.covered.iter().filter(|&&k| k == o.shape as u32).count()).sum();
                (o.atlas.width * o.atlas.height + rays * px) as f64
            })
            .collect();
        opal::dist::assign_by_cost(&costs, comm.size())
    } else {
        vec![0; objects.len()]
    };
    let mine = owner.iter().filter(|&&r| r == comm.rank()).count();
    let bar = Stage::start(s.progress.as_ref(), "superres", mine as u64);
    let msgs: Vec<Option<String>> = objects
        .iter_mut()
        .enumerate()
        .map(|(j, o)| {
            if owner[j] != comm.rank() {
                return None;
            }
            let _done = StepOnDrop(&bar);
            let to = std::time::Instant::now();
            let reach = reached_texels(&o.observed, &o.ed, &o.ei);
            let ei = smooth_in_charts_masked(&o.ei, &o.atlas, (o.atlas.width / 16).max(1), &reach);
            let mut shading: Vec<f32> =
                o.ed.iter().zip(&ei).map(|(d, i)| luminance(std::array::from_fn(|c| d[c] + i[c]))).collect();
            if let Some(p) = &s.debug.shading {
                // error analysis: a given irradiance map (e.g. the true one) instead
                if let Ok(img) = opal::image::read::read_image(p)
                    && img.data.len() == shading.len()
                {
                    shading = img.data.iter().map(|v| luminance(v.0)).collect();
                }
            }
            let Some((ls, os, info)) = superres::superres_luminance(
                scene,
                o.shape as u32,
                &o.atlas,
                views,
                pure,
                (&o.l, &o.observed),
                Some(&shading),
                sr,
            ) else {
                return Some(format!(
                    "super-resolution {}: back-projected luminance kept (no usable pixel, or no texel seen by two views to measure the photos' noise)",
                    o.id
                ));
            };
            o.l = ls;
            o.observed = os;
            o.superres = Some(info);
            finish_luminance(o);
            o.clamped = update_kd(o);
            let noise =
                info.photo_noise.map_or(String::new(), |x| format!(", photo noise {:.2} %", 100.0 * x));
            let res = info.residual_to_noise.map_or(String::new(), |r| format!(", residual {r:.3} of the noise"));
            Some(format!(
                "super-resolved luminance {}: {:.1} % of texels seen (prior weight {:.2e}{noise}; {} reweightings, {} CG steps{res}{}; {:.1} s)",
                o.id,
                100.0 * o.seen_fraction,
                info.lambda,
                info.reweightings,
                info.cg_steps,
                if info.converged { "" } else { ", step limit" },
                to.elapsed().as_secs_f64()
            ))
        })
        .collect();
    bar.finish();
    let msgs = if comm.size() > 1 { exchange_superres(comm, objects, &owner, msgs) } else { msgs };
    msgs.iter().flatten().for_each(|m| log(m));
}

/// The maps [`superres_pass`] changes (`l`, `observed`, `seen_fraction`, `kd`, `ei`, `clamped`)
/// and the log line of each object, sent by its owner rank to every other; returns every
/// object's log line (in object order).
fn exchange_superres(
    comm: &dyn opal::dist::Comm,
    objects: &mut [ObjectResult],
    owner: &[usize],
    msgs: Vec<Option<String>>,
) -> Vec<Option<String>> {
    let mut p = opal::dist::Packer::default();
    for (j, o) in objects.iter().enumerate().filter(|(j, _)| owner[*j] == comm.rank()) {
        p.u8(msgs[j].is_some() as u8);
        let Some(m) = &msgs[j] else { continue };
        p.str(m);
        for i in 0..o.l.len() {
            p.f32s(&o.l[i]);
            p.f32s(&o.kd[i]);
            p.f32s(&o.ei[i]);
            p.u8(o.observed[i] as u8);
        }
        p.f64(o.seen_fraction);
        p.u64(o.clamped as u64);
        p.u8(o.superres.is_some() as u8);
        if let Some(info) = o.superres {
            pack_info(&mut p, info);
        }
    }
    let all = comm.all_gather_bytes(&p.0);
    let mut readers: Vec<opal::dist::Unpacker> = all.iter().map(|b| opal::dist::Unpacker(b)).collect();
    let mut out = Vec::with_capacity(objects.len());
    for (j, o) in objects.iter_mut().enumerate() {
        let u = &mut readers[owner[j]];
        if u.u8() == 0 {
            out.push(None);
            continue;
        }
        out.push(Some(u.str()));
        for i in 0..o.l.len() {
            o.l[i] = u.rgb();
            o.kd[i] = u.rgb();
            o.ei[i] = u.rgb();
            o.observed[i] = u.u8() != 0;
        }
        o.seen_fraction = u.f64();
        o.clamped = u.u64() as usize;
        o.superres = (u.u8() != 0).then(|| unpack_info(u));
    }
    assert!(readers.iter().all(|r| r.is_empty()), "a rank sent the maps of another object");
    out
}

/// [`superres::SrInfo`] for [`exchange_superres`] (`None` as NaN).
fn pack_info(p: &mut opal::dist::Packer, i: superres::SrInfo) {
    p.f64(i.photo_noise.unwrap_or(f64::NAN));
    p.f64(i.lambda as f64);
    p.u64(i.reweightings as u64);
    p.u64(i.cg_steps as u64);
    p.f64(i.residual_to_noise.unwrap_or(f64::NAN));
    p.f64(i.relative_residual);
    p.u8(i.converged as u8);
}

/// The inverse of [`pack_info`].
fn unpack_info(u: &mut opal::dist::Unpacker) -> superres::SrInfo {
    let some = |x: f64| (!x.is_nan()).then_some(x);
    superres::SrInfo {
        photo_noise: some(u.f64()),
        lambda: u.f64() as f32,
        reweightings: u.u64() as usize,
        cg_steps: u.u64() as usize,
        residual_to_noise: some(u.f64()),
        relative_residual: u.f64(),
        converged: u.u8() != 0,
    }
}

/// Steps a progress stage by one when dropped (an object's work done, whichever way it returned).
struct StepOnDrop<'a, 'b>(&'a Stage<'b>);

impl Drop for StepOnDrop<'_, '_> {
    fn drop(&mut self) {
        self.0.step(1);
    }
}

/// One light-tracing target per shape of the scene: the texel grid of the object on it, `None`
/// for shapes without one.
pub(in crate::delight) fn irradiance_targets(
    shapes: usize,
    objects: &[ObjectResult],
) -> Vec<Option<IrradianceTarget>> {
    (0..shapes)
        .map(|k| {
            objects.iter().find(|o| o.shape == k).map(|o| IrradianceTarget {
                width: o.atlas.width,
                height: o.atlas.height,
                texel_area: o.atlas.texel_area.clone(),
            })
        })
        .collect()
}
