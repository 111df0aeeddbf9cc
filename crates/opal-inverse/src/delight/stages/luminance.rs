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
use crate::delight::timing::{StageClock, Timings};
use crate::delight::views::{PureBuffer, View};
use crate::delight::{
    ObjectResult, ViewGainMode, ViewGains, apply_view_gains, gains, luminance_map, superres,
};
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

/// Luminance map, observed mask, emitter proximity and seen fraction of every object (holes
/// inpainted); warnings for objects or charts seen by no view.
pub(in crate::delight) fn luminance_maps(
    inp: &Inputs,
    objects: &mut [ObjectResult],
    views: &[View],
    pure: &[PureBuffer],
    warnings: &mut Vec<String>,
) {
    let (scene, s, log) = (inp.scene, inp.s, inp.log);
    let (slo, shi) = scene.bounds();
    let diag = (shi - slo).length();
    let emit_boxes: Vec<(Vec3, Vec3)> = scene
        .shapes
        .iter()
        .filter(|s| s.emission.is_some())
        .map(|s| bbox(s.mesh.positions.iter().copied()))
        .collect();
    for o in objects.iter_mut() {
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
