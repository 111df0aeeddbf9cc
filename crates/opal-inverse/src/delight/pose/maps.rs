//! The leave-one-out luminance maps the pose refinement predicts each view from
//! ([`leave_one_out_maps`]): per object, each view's sample of every texel is taken once per
//! round ([`view_sample`]: projection, occlusion ray, bilinear taps on pure pixels), and the map
//! of view `k` sums the samples of the other active views in view order — the same sums as
//! [`luminance_map`](crate::delight::observe::luminance_map) over those views, bit for bit,
//! with a sixth of the rays for six views. Each map is then extended over the edge bands
//! ([`extend_map`]) and looked up at the surface points of the prediction ([`lookup`]).
//!
//! Tests: `tests.rs` (the extension's domain; the multi-view refinement end to end,
//! `loo_maps_match_luminance_map`).

use super::extrapolate;
use crate::delight::atlas::{Atlas, NO_TRI};
use crate::delight::luminance;
use crate::delight::observe::{ViewSample, view_sample};
use crate::delight::views::{PureBuffer, View};
use opal::math::Vec3;
use opal::scene::Scene;
use rayon::prelude::*;

/// A luminance map extended over the edge bands and where it is defined ([`extend_map`]).
pub(super) type Map = (Vec<f32>, Vec<bool>);

/// One view's weighted sample of a texel: `cos · Σw·rgb / Σw` per channel and the weight `cos`.
type Sample = ([f64; 3], f64);

/// Per view `k`: the luminance map of every object (`objects` order) from the *other* active
/// views (`active`; `current` at the round's poses, `pure` their eroded pure buffers), extended
/// by [`extend_map`] — `None` for a view with no other active view.
pub(super) fn leave_one_out_maps(
    scene: &Scene,
    objects: &[(u32, &Atlas)],
    current: &[View],
    pure: &[PureBuffer],
    active: &[bool],
    linear_bands: usize,
    linear_domain: bool,
) -> Vec<Option<Vec<Map>>> {
    let nv = current.len();
    let has_others = |k: usize| (0..nv).any(|j| j != k && active[j]);
    let mut out: Vec<Option<Vec<Map>>> =
        (0..nv).map(|k| has_others(k).then(|| Vec::with_capacity(objects.len()))).collect();
    for &(shape, a) in objects {
        let n = a.width * a.height;
        // samples[i * nv + j]: view j's sample of texel i (active views only)
        let samples: Vec<Option<Sample>> = (0..n * nv)
            .into_par_iter()
            .map(|t| {
                let (i, j) = (t / nv, t % nv);
                if !active[j] || a.texel_tri[i] == NO_TRI {
                    return None;
                }
                let ViewSample { sum: val, weight: wt, cos, .. } =
                    view_sample(scene, shape, a, i, &current[j], &pure[j])?;
                let wv = cos as f64;
                Some((std::array::from_fn(|ch| wv * val[ch] / wt), wv))
            })
            .collect();
        let maps: Vec<Option<Map>> = (0..nv)
            .into_par_iter()
            .map(|k| {
                if !has_others(k) {
                    return None;
                }
                let (l, obs): (Vec<[f32; 3]>, Vec<bool>) = (0..n)
                    .map(|i| {
                        let mut acc = [0f64; 3];
                        let mut wsum = 0f64;
                        for (j, smp) in samples[i * nv..(i + 1) * nv].iter().enumerate() {
                            let Some((t, wv)) = smp else { continue };
                            if j == k {
                                continue;
                            }
                            for ch in 0..3 {
                                acc[ch] += t[ch];
                            }
                            wsum += wv;
                        }
                        if wsum > 0.0 { (acc.map(|x| (x / wsum) as f32), true) } else { ([0.0; 3], false) }
                    })
                    .unzip();
                Some(extend_map(a, l, obs, linear_bands, linear_domain))
            })
            .collect();
        for (o, m) in out.iter_mut().zip(maps) {
            if let (Some(o), Some(m)) = (o.as_mut(), m) {
                o.push(m);
            }
        }
    }
    out
}

/// Looks up the luminance map `l` (observed texels `obs`) of an atlas at a surface point of
/// its shape (`local` = the triangle's index in the shape's mesh).
pub(super) fn lookup(a: &Atlas, l: &[f32], obs: &[bool], local: usize, p: Vec3) -> Option<f32> {
    if local >= a.mesh.triangle_count() {
        return None;
    }
    let [p0, p1, p2] = a.mesh.triangle(local).map(|v| v.as_dvec3());
    let p = p.as_dvec3();
    let (e1, e2, d) = (p1 - p0, p2 - p0, p - p0);
    let n = e1.cross(e2);
    let nn = n.length_squared();
    if nn <= 0.0 {
        return None;
    }
    let b1 = d.cross(e2).dot(n) / nn;
    let b2 = e1.cross(d).dot(n) / nn;
    let b0 = 1.0 - b1 - b2;
    // the atlas mesh is the shape's own mesh (same triangles, seams split): check it
    if b0 < -1e-3
        || b1 < -1e-3
        || b2 < -1e-3
        || (d.dot(n) / nn.sqrt()).abs() > 1e-3 * e1.length().max(e2.length())
    {
        return None;
    }
    let idx = a.mesh.indices[local];
    let uv = a.mesh.uvs[idx[0] as usize].as_dvec2() * b0
        + a.mesh.uvs[idx[1] as usize].as_dvec2() * b1
        + a.mesh.uvs[idx[2] as usize].as_dvec2() * b2;
    let chart = a.tri_chart[local];
    let (x, y) = (uv.x * a.width as f64 - 0.5, uv.y * a.height as f64 - 0.5);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (mut acc, mut wsum) = (0.0, 0.0);
    for (dx, dy, w) in
        [(0, 0, (1.0 - fx) * (1.0 - fy)), (1, 0, fx * (1.0 - fy)), (0, 1, (1.0 - fx) * fy), (1, 1, fx * fy)]
    {
        let (xi, yi) = (x0 as i64 + dx, y0 as i64 + dy);
        if xi < 0 || yi < 0 || xi >= a.width as i64 || yi >= a.height as i64 {
            continue;
        }
        let i = yi as usize * a.width + xi as usize;
        if a.texel_tri[i] == NO_TRI
            || a.tri_chart[a.texel_tri[i] as usize] != chart
            || !obs[i]
            || !l[i].is_finite()
        {
            continue;
        }
        acc += w * l[i] as f64;
        wsum += w;
    }
    (wsum >= 0.5).then(|| (acc / wsum) as f32)
}

/// The map `l` (observed texels `obs`) of atlas `a` extended over the texels within 48 texels of
/// an observed texel of the same chart (the texels within `linear_bands` to first order);
/// returns the luminance and where it is defined: the extended texels, or with `linear_domain`
/// (and `linear_bands` > 0) only the observed texels and those the first-order fill reached.
pub(super) fn extend_map(
    a: &Atlas,
    mut l: Vec<[f32; 3]>,
    obs: Vec<bool>,
    linear_bands: usize,
    linear_domain: bool,
) -> (Vec<f32>, Vec<bool>) {
    let (w, h) = (a.width, a.height);
    let n = w * h;
    let chart: Vec<u32> = (0..n).map(|i| a.texel_chart(i)).collect();
    let covered: Vec<bool> = (0..n).map(|i| a.texel_tri[i] != NO_TRI).collect();
    // texels within reach of an observed one (4-neighbour steps inside the chart)
    let reach = 48;
    let mut dist = vec![usize::MAX; n];
    let mut queue = std::collections::VecDeque::new();
    for i in 0..n {
        if obs[i] {
            dist[i] = 0;
            queue.push_back(i);
        }
    }
    while let Some(i) = queue.pop_front() {
        if dist[i] >= reach {
            continue;
        }
        let (x, y) = (i % w, i / w);
        let nb = [
            (x > 0).then(|| i - 1),
            (x + 1 < w).then_some(i + 1),
            (y > 0).then(|| i - w),
            (y + 1 < h).then_some(i + w),
        ];
        for j in nb.into_iter().flatten() {
            if covered[j] && chart[j] == chart[i] && dist[j] == usize::MAX {
                dist[j] = dist[i] + 1;
                queue.push_back(j);
            }
        }
    }
    let mut domain: Vec<bool> = dist.iter().map(|&d| d != usize::MAX).collect();
    // with the first-order domain the flat fill is never looked up: the first-order fill reads
    // only observed texels and overwrites every texel it reaches
    if !(linear_bands > 0 && linear_domain) {
        crate::delight::inpaint::inpaint(&mut l, &obs, &domain, &chart, w, h, 3);
    }
    let mut lum: Vec<f32> = l.iter().map(|&c| luminance(c)).collect();
    if linear_bands > 0 {
        let filled = extrapolate::extrapolate_linear(&mut lum, &obs, &dist, &chart, w, h, linear_bands);
        if linear_domain {
            domain = (0..n).map(|i| obs[i] || filled[i]).collect();
        }
    }
    (lum, domain)
}
