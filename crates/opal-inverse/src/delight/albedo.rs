//! The albedo update shared by the stages of [`delight`](super::delight): `Kd = π L / (Ed + Ei)`
//! with its [0, 1] correction and inpainting ([`update_kd`]), the initial indirect estimate
//! ([`initial_kd`]), the seen fraction and hole filling of a new luminance map
//! ([`finish_luminance`]), the scene-average albedo of unseen objects ([`fill_unseen`]) and the
//! quartiles of the outlier rejection ([`quartiles`]). Tests: `tests/delight.rs` (round trip on a
//! small Cornell box), through [`delight`](super::delight).

// Index loops over parallel per-texel arrays read more clearly than zipped iterators here.
#![allow(clippy::needless_range_loop)]

use super::atlas::NO_TRI;
use super::{ObjectResult, inpaint};
use opal::math::PI;

/// `Kd = π L / (Ed + Ei)` with the [0, 1] correction (raises `Ei` where `Kd > 1`); returns the
/// number of clamped texel-channels.
pub(super) fn update_kd(o: &mut ObjectResult) -> usize {
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

/// First and third quartiles (linear interpolation between order statistics); sorts `v`.
pub(super) fn quartiles(v: &mut [f64]) -> (f64, f64) {
    v.sort_by(f64::total_cmp);
    let q = |f: f64| {
        let x = f * (v.len() - 1) as f64;
        let (i, t) = (x.floor() as usize, x - x.floor());
        if i + 1 < v.len() { v[i] * (1.0 - t) + v[i + 1] * t } else { v[i] }
    };
    (q(0.25), q(0.75))
}

/// Seen fraction, median filter next to emitters and inpainting of the holes of a new luminance
/// map; returns the number of texels left unfilled (charts seen by no view).
pub(super) fn finish_luminance(o: &mut ObjectResult) -> usize {
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

/// Objects seen by no view get the area-weighted mean albedo of the seen ones.
pub(super) fn fill_unseen(objects: &mut [ObjectResult]) {
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

/// Initial albedo: the indirect irradiance starts at the `gathered` map when given
/// ([`super::gather`]), else at `share` × the direct one (× the scene-average direct irradiance
/// `avg` where a texel has none), then [`update_kd`].
pub(super) fn initial_kd(o: &mut ObjectResult, share: f32, avg: [f32; 3], gathered: Option<&[[f32; 3]]>) {
    for i in 0..o.ed.len() {
        for c in 0..3 {
            let e = o.ed[i][c];
            o.ei[i][c] = match gathered {
                Some(g) => g[i][c],
                None => share * if e > 0.0 { e } else { avg[c] },
            };
        }
    }
    o.clamped = update_kd(o);
}
