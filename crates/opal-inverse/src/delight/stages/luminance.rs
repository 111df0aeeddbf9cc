//! Stage 3 of [`delight`](crate::delight::delight): the luminance maps `L`. First (unless
//! [`ViewGainMode::Fixed`]) the per-view gains from the overlap of the views ([`view_gains`]):
//! the views are divided by them before everything after. Then per object ([`luminance_maps`])
//! the back-projected map ([`luminance_map`]; super-resolved here only when no light-tracing
//! pass follows), the emitter-proximity flag (3×3 median), the seen fraction and the inpainted
//! holes, with warnings for unseen objects and charts. Tests: `tests/delight.rs`, the unit tests
//! of `observe.rs`, `superres.rs` and `gains.rs`.

use super::Inputs;
use crate::delight::albedo::finish_luminance;
use crate::delight::atlas::Atlas;
use crate::delight::progress::Stage;
use crate::delight::timing::{StageClock, Timings};
use crate::delight::views::{PureBuffer, View};
use crate::delight::{
    ObjectResult, ViewGainMode, ViewGains, apply_view_gains, gains, luminance_map, split, superres,
};
use opal::dist::{Packer, Unpacker};
use opal::math::Vec3;

fn bbox(points: impl Iterator<Item = Vec3>) -> (Vec3, Vec3) {
    let mut lo = Vec3::splat(f32::MAX);
    let mut hi = Vec3::splat(f32::MIN);
    for p in points {
        lo = lo.min(p);
        hi = hi.max(p);
    }
    (lo, hi)
}

/// Per-view gains (unless [`ViewGainMode::Fixed`]): the views divided by them and the gains;
/// `None` for both with fixed gains (the views are used as given).
pub(in crate::delight) fn view_gains(
    inp: &Inputs,
    objects: &[ObjectResult],
    views: &[View],
    pure: &[PureBuffer],
    warnings: &mut Vec<String>,
    timings: &mut Timings,
) -> (Option<Vec<View>>, Option<ViewGains>) {
    let (s, log) = (inp.s, inp.log);
    if s.view_gains.mode == ViewGainMode::Fixed {
        return (None, None);
    }
    let tg = StageClock::start();
    let objs: Vec<(u32, &Atlas)> = objects.iter().map(|o| (o.shape as u32, &o.atlas)).collect();
    let (g, w) = gains::estimate_view_gains(inp.scene, &objs, views, pure, &s.view_gains);
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
    timings.push("gains", tg.elapsed());
    (Some(c), Some(g))
}

/// One object's luminance stage as sent to the other processes (only under several).
struct Luminance {
    l: Vec<[f32; 3]>,
    observed: Vec<bool>,
    near_emitter: bool,
    seen_fraction: f64,
}

/// Luminance map, observed mask, emitter proximity and seen fraction of every object (holes
/// inpainted); warnings for objects or charts seen by no view. Under several processes each
/// object is done by one rank ([`split::per_object`], balanced by `costs`, which receives the
/// measured seconds) and sent whole to the others.
pub(in crate::delight) fn luminance_maps(
    inp: &Inputs,
    objects: &mut [ObjectResult],
    views: &[View],
    pure: &[PureBuffer],
    warnings: &mut Vec<String>,
    costs: &mut Vec<f64>,
) {
    let (scene, s, log) = (inp.scene, inp.s, inp.log);
    let solo = opal::dist::Solo;
    let comm: &dyn opal::dist::Comm = s.comm.as_deref().unwrap_or(&solo);
    let (slo, shi) = scene.bounds();
    let diag = (shi - slo).length();
    let emit_boxes: Vec<(Vec3, Vec3)> = scene
        .shapes
        .iter()
        .filter(|s| s.emission.is_some())
        .map(|s| bbox(s.mesh.positions.iter().copied()))
        .collect();
    let bar = Stage::start(s.progress.as_ref(), "luminance", objects.len() as u64);
    let one = |_: usize, o: &mut ObjectResult| -> (usize, Option<Luminance>) {
        let (mut l, mut obs) = luminance_map(scene, o.shape as u32, &o.atlas, views, pure);
        // super-resolution here only when no light-tracing pass gives the shading (see
        // `iterate`)
        if s.iterations == 0
            && let Some(sr) = &s.superres
            && let Some((ls, os, _)) = superres::superres_luminance(
                scene,
                o.shape as u32,
                &o.atlas,
                views,
                pure,
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
        // a copy for the other processes only
        let sent = (comm.size() > 1).then(|| Luminance {
            l: o.l.clone(),
            observed: o.observed.clone(),
            near_emitter: o.near_emitter,
            seen_fraction: o.seen_fraction,
        });
        (left, sent)
    };
    let put = |(left, m): &(usize, Option<Luminance>), p: &mut Packer| {
        let m = m.as_ref().expect("the maps of an object of a split run");
        p.u64(*left as u64);
        p.u64(m.l.len() as u64);
        m.l.iter().for_each(|v| p.f32s(v));
        m.observed.iter().for_each(|&b| p.u8(b as u8));
        p.u8(m.near_emitter as u8);
        p.f64(m.seen_fraction);
    };
    let get = |u: &mut Unpacker| {
        let left = u.u64() as usize;
        let n = u.u64() as usize;
        let l = (0..n).map(|_| u.rgb()).collect();
        let observed = (0..n).map(|_| u.u8() != 0).collect();
        let near_emitter = u.u8() != 0;
        let seen_fraction = u.f64();
        (left, Some(Luminance { l, observed, near_emitter, seen_fraction }))
    };
    let done = split::per_object(
        comm,
        objects,
        costs,
        |j, o| {
            let r = one(j, o);
            bar.step(1);
            r
        },
        put,
        get,
    );
    bar.finish();
    for (o, (left, m)) in objects.iter_mut().zip(done) {
        if let Some(m) = m {
            o.l = m.l;
            o.observed = m.observed;
            o.near_emitter = m.near_emitter;
            o.seen_fraction = m.seen_fraction;
        }
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
}
