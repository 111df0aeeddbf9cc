//! Multi-view super-resolved luminance map (step 3 of method C, improved).
//!
//! What it models: the photos' pixels are linear functionals of the object's *radiance
//! texture* B (the exitant radiance of each texel, `B = Kd·E/π` for a diffuse surface). A photo
//! pixel rendered with a box pixel filter (Mitsuba's `box` rfilter, the reference renders) and a
//! bilinearly filtered texture is the average over the pixel's area of the bilinear
//! interpolation of B at the surface point seen:
//!
//! `y_p = (1/S²) Σ_s Σ_t bilin_t(uv(x_{p,s})) · B_t`,
//!
//! with S×S stratified sub-pixel positions `x_{p,s}` (the quadrature of the pixel integral).
//! Back-projection (sampling every view at each texel's projection, [`super::luminance_map`])
//! blurs B twice (pixel footprint + bilinear taps): with 1.1–1.8 texels per pixel it cannot
//! reach 38 dB PSNR on a texture with 1–3-texel lines (27.5 dB even with noise-free photos,
//! `bench/scripts/psnr_bound.py`). Here all views are inverted jointly:
//!
//! `min_K  Σ_p w_p (A (s ⊙ K) − y)_p² + λ Σ_edges φ(|∇K|)`,  `B = s ⊙ K`,
//!
//! with a smooth *shading* s (the irradiance estimate `Ed + Ei` of the pipeline after its first
//! light-tracing pass, so K is the albedo up to a constant: the prior sees the texture, not the
//! lighting's 23:1 gradients and shadows), pixel weights `w_p = 1/y_p²` (the photos' noise is
//! relative: Monte-Carlo or shot noise, σ ∝ y) normalised to mean 1, and the sparse-gradient
//! edge penalty `φ(g) = (g² + ε²)^{p/2}` on the RGB gradient norm (p = 1: total variation;
//! default p = ½, non-convex: it smooths flat areas like TV but shrinks the texture's thin lines
//! much less). Without a shading, s = 1 and w = 1 (the map B itself, as in the first version).
//! Solved by iteratively reweighted least squares (IRLS: the prior becomes `λ Σ w_e |∇_e K|²`,
//! `w_e = (|∇_e K|² + ε²)^{(p−2)/2}`, for p = 1 `1/max(|∇_e K|, ε)`), each reweighting by
//! Jacobi-preconditioned conjugate gradients on the normal equations, warm-started from the
//! previous map, until the correction still to come is below what the photos' noise resolves
//! ([`SrSettings::cg_tolerance`]; the steps and the final residual are in [`SrInfo`]). Values are solved in units of the mean observed radiance (and s in units of
//! its mean), so λ and ε are scale-free; λ is scaled by the observation density (rows per
//! unknown / 2.5, the density of the reference data the defaults were chosen on) and, below that
//! density, by `max(1, (σ/σ_ref)²)`, σ the photos' relative noise measured on the object
//! ([`super::photo_noise`]; texture detail is not counted as noise), σ_ref that of the
//! reference photos ([`SrSettings::reference_noise`]): the data term's rows are weighted to
//! mean 1, so λ assumed σ_ref, and noisier photos need the MAP weight (without it the
//! texels of 24 views of 160×120 at 8 spp were ~3× noisier than back-projection's and the
//! [0, 1] clamp of the albedo biased the means by up to 25 %, docs/delight.md).
//!
//! Parameters: [`SrSettings`]. Conventions: texel (x, y) has its centre at
//! uv = ((x+½)/W, (y+½)/H) (Mitsuba's bitmap lookup, clamp wrap); only pixels whose S² sub-pixel
//! rays all hit the object (and that it *covers* in [`super::views::PureBuffer::covered`]: pure
//! pixels plus those across gentle creases, which the per-ray model represents) are used, so
//! occlusion and anti-aliased edges next to bright emitters never enter; prior edges never cross
//! a chart seam. Bilinear taps on gutter texels are tied to the chart texels the output albedo's
//! gutters are dilated from (`tie_gutters`), so the model renders what the output texture will. A texel counts as observed when the pixels covering it give it a total weight ≥
//! [`SrSettings::min_weight`].
//!
//! Error analysis hooks ([`SrDiagnostics`], for `bench/scripts/delight_psnr_budget.py`; all off
//! by default): a truth radiance map on the atlas grid with a residual directory prints per
//! view the residual of the operator applied to it against the photo (χ² against
//! `<view>_stderr.exr` when present) and writes residual images; `synth` replaces the
//! photos by that map through the operator plus noise: `stderr` (Gaussian, the photo's standard
//! error), `stderrcorr` (channels correlated ρ = 0.7), a relative level (`0.02`), `shuffle` /
//! `relshuffle` (the real residuals permuted), `clipK` (the real photo with its residuals
//! clipped at K standard errors); `synth_subsamples = N` generates with N×N sub-pixel rays.
//!
//! References: Rudin, Osher, Fatemi 1992 (TV); Geman & Reynolds 1992 / Nikolova 2005
//! (non-convex edge-preserving priors, IRLS); the multi-view super-resolution formulation of
//! texture maps follows Goldlücke & Cremers 2009 ("Superresolution texture maps for multiview
//! reconstruction"), here with known geometry and a box-filtered pixel model.
//!
//! Parts: [`settings`](SrSettings), `operator` (the pixel rows and the sparse matrix), `gutters`
//! (chart borders), `solve` (IRLS, CG and the stop rule), `diag` (error analysis).
//!
//! Tests: `superres_recovers_texture_beyond_backprojection` (a synthetic textured plane seen by
//! four cameras: PSNR far above back-projection), `superres_stops_by_the_noise` (the stop rule:
//! fewer steps on noisy photos, the same map to within the noise), the de-lighting end-to-end
//! tests in `tests/delight.rs`.

mod diag;
mod gutters;
mod operator;
mod settings;
mod solve;
#[cfg(test)]
mod tests;

pub use settings::{SrDiagnostics, SrInfo, SrSettings};

use super::atlas::{Atlas, NO_TRI};
use super::views::{PureBuffer, View};
use opal::scene::Scene;
use operator::{Csr, Row};
use rayon::prelude::*;

/// Super-resolved radiance map of one object from every view: values per texel (RGB radiance)
/// and the observed mask. `(init, init_obs)` is the back-projected map and its mask (warm start;
/// texels no pure pixel covers keep it). `shading` (per texel, any positive scale: the
/// irradiance estimate `Ed + Ei`, smooth) makes the unknowns `K = B / shading`, so the edge prior
/// acts on the albedo instead of the lighting's gradients and shadows, and weights the pixels for
/// relative noise (each row divided by the pixel's luminance).
/// Returns `None` when no pixel sees the object, or when the photos' noise on it cannot be
/// measured (see [`SrSettings::reference_noise`]): the caller keeps the back-projected map.
#[allow(clippy::too_many_arguments)] // the scene, object, views and their buffers, the warm start, the shading, settings
pub fn superres_luminance(
    scene: &Scene,
    shape: u32,
    a: &Atlas,
    views: &[View],
    pure: &[PureBuffer],
    (init, init_obs): (&[[f32; 3]], &[bool]),
    shading: Option<&[f32]>,
    s: &SrSettings,
) -> Option<(Vec<[f32; 3]>, Vec<bool>, SrInfo)> {
    let n = a.width * a.height;
    if a.mesh.uvs.len() != a.mesh.positions.len() {
        return None;
    }
    let mut rows = all_rows(scene, shape, a, views, pure, s);
    if rows.is_empty() {
        return None;
    }
    // per-texel shading (gutters from their owner chart), then the gutter taps tied to the
    // chart texels the output albedo's gutters are dilated from
    let sd_t: Vec<f32> = match shading {
        Some(sd) => gutters::shading_into_gutters(sd, a).iter().map(|v| v.max(0.0)).collect(),
        None => vec![1.0; n],
    };
    let shade = gutters::tie_gutters(&mut rows, a, &sd_t);
    let (colw, idx, texel_of) = unknowns(&rows, n);
    let m = texel_of.len();
    // scale: mean luminance of the observations
    let mean = rows.iter().map(|r| super::luminance(r.y) as f64).sum::<f64>() / rows.len() as f64;
    let scale = if mean > 0.0 { mean as f32 } else { 1.0 };
    // shading: the unknowns are K = B / sh (sh normalised to mean 1 over the unknowns), so the
    // edge prior acts on the albedo, not on the lighting's gradients and shadows
    let (sh, sh_mean) =
        if shading.is_some() { shading_per_unknown(&sd_t, &texel_of) } else { (vec![1f32; m], 1f64) };
    let (rs, row_noise_per_rel2) = row_weights(&rows, (init, init_obs), mean, scale, shading.is_some());
    let (amat, y) = weighted_operator(rows, shade, &rs, &idx, sh_mean, scale, m);
    let nrows = amat.rows();
    let sys = solve::System::new(amat, &y, prior_edges(a, &idx));
    drop(y);
    // observation density scaling of λ, then the photos' noise: λ is the weight of the prior
    // against a data term in units of the relative noise σ_ref of the photos it was chosen on
    // (rows weighted to mean 1), so with photos of relative noise σ > σ_ref the MAP weight is
    // λ·(σ/σ_ref)² (never below λ: it is not validated for cleaner photos)
    let density = nrows as f32 / m as f32 / 2.5;
    let photo_noise = if s.reference_noise > 0.0 || s.cg_tolerance > 0.0 {
        super::photo_noise::relative_photo_noise(scene, shape, a, views, pure)
    } else {
        None
    };
    if s.reference_noise > 0.0 && photo_noise.is_none() {
        // no texel seen by two views: the noise, and so the prior's weight, is unknown; the
        // back-projected map is kept
        return None;
    }
    // only below the reference density: above it the density scaling already strengthens the
    // prior, and the noise factor on top over-smoothed (64-pixel views on 32² maps, 1.3–8 × the
    // reference density: floor +2.8 %, back wall −1 dB; docs/delight.md)
    let noise_factor = match photo_noise {
        Some(x) if density < 1.0 && s.reference_noise > 0.0 => {
            (x / s.reference_noise as f64).powi(2).max(1.0) as f32
        }
        _ => 1.0,
    };
    let lambda = s.lambda * density * noise_factor;
    // warm start: back-projection where it exists, else Aᵀy / column weight
    let mut x: Vec<[f32; 3]> = (0..m)
        .map(|j| {
            let t = texel_of[j];
            if init_obs.get(t).copied().unwrap_or(false) {
                init[t].map(|c| c / scale / sh[j])
            } else {
                sys.aty[j].map(|c| c / (colw[t].max(1e-12) * sh[j] * sh[j]))
            }
        })
        .collect();
    if s.diagnostics.trace {
        eprintln!(
            "superres shape {shape}: {nrows} rows, {m} unknowns, {} nonzeros, {} edges, photo noise {photo_noise:?}, λ {lambda}",
            sys.amat.val.len(),
            sys.edges.len()
        );
    }
    let conv = solve::irls(&sys, &mut x, lambda, photo_noise.map(|p| p * p * row_noise_per_rel2), s);
    drop(sys);
    let info = SrInfo {
        photo_noise,
        lambda,
        reweightings: conv.reweightings,
        cg_steps: conv.cg_steps,
        residual_to_noise: conv.residual_to_noise,
        relative_residual: conv.relative_residual,
        converged: conv.converged,
    };
    let (out, obs) = unknowns_to_map(
        a,
        &x,
        &texel_of,
        &idx,
        (init, init_obs),
        &colw,
        (&sh, &sd_t, sh_mean),
        scale,
        shading.is_some(),
        s,
    );
    Some((out, obs, info))
}

/// The shading per unknown in units of its mean over the unknowns (floored at 10⁻³), and that
/// mean (1 when it is not positive: then the shading is 1).
fn shading_per_unknown(sd_t: &[f32], texel_of: &[usize]) -> (Vec<f32>, f64) {
    let m = texel_of.len();
    let mean = texel_of.iter().map(|&t| sd_t[t] as f64).sum::<f64>() / m.max(1) as f64;
    if mean > 0.0 {
        (texel_of.iter().map(|&t| (sd_t[t] as f64 / mean).max(1e-3) as f32).collect(), mean)
    } else {
        (vec![1f32; m], 1.0)
    }
}

/// The operator's rows of every view (with the error-analysis hook applied).
fn all_rows(
    scene: &Scene,
    shape: u32,
    a: &Atlas,
    views: &[View],
    pure: &[PureBuffer],
    s: &SrSettings,
) -> Vec<Row> {
    // at most one row per pixel the object covers: reserved once (growing the vector by
    // doubling would hold up to twice the rows' headers while it moves them)
    let covered: usize = pure.iter().map(|p| p.covered.iter().filter(|&&k| k == shape).count()).sum();
    let mut rows: Vec<Row> = Vec::with_capacity(covered);
    for (v, pb) in views.iter().zip(pure) {
        let mut vr = operator::view_rows(scene, shape, a, v, pb, s.subsamples.max(1));
        let gen_ss = s.diagnostics.synth_subsamples;
        let fine = if gen_ss > 0 { operator::view_rows(scene, shape, a, v, pb, gen_ss) } else { Vec::new() };
        let fine: std::collections::HashMap<u32, &Row> = fine.iter().map(|r| (r.pix, r)).collect();
        diag::diag_residual(v, &mut vr, a, &fine, &s.diagnostics);
        rows.extend(vr);
    }
    rows
}

/// The unknowns, the texels some pixel touches: per texel its total tap weight, its unknown's
/// index (`u32::MAX`: none), and per unknown its texel.
fn unknowns(rows: &[Row], n: usize) -> (Vec<f32>, Vec<u32>, Vec<usize>) {
    let mut colw = vec![0f32; n];
    for r in rows {
        for &(c, v) in &r.entries {
            colw[c as usize] += v;
        }
    }
    let mut idx = vec![u32::MAX; n];
    let mut texel_of = Vec::new();
    for i in 0..n {
        if colw[i] > 0.0 {
            idx[i] = texel_of.len() as u32;
            texel_of.push(i);
        }
    }
    (colw, idx, texel_of)
}

/// The weighted operator on the unknowns and the weighted observations in units of `scale`:
/// each entry × the tap-weighted shading behind it (over its mean `sh_mean`) × the row weight.
fn weighted_operator(
    rows: Vec<Row>,
    shade: Vec<Vec<f32>>,
    rs: &[f32],
    idx: &[u32],
    sh_mean: f64,
    scale: f32,
    m: usize,
) -> (Csr, Vec<[f32; 3]>) {
    let mut ptr = Vec::with_capacity(rows.len() + 1);
    ptr.push(0);
    let nnz: usize = rows.iter().map(|r| r.entries.len()).sum();
    let mut col = Vec::with_capacity(nnz);
    let mut val = Vec::with_capacity(nnz);
    let mut y = Vec::with_capacity(rows.len());
    // each row is dropped once copied
    for ((r, sr), &w) in rows.into_iter().zip(shade).zip(rs) {
        for (&(c, v), &st) in r.entries.iter().zip(&sr) {
            // st: the tap-weighted shading of the texels behind this column (its own, and the
            // gutters tied to it); the floor as for `sh`
            let j = idx[c as usize];
            col.push(j);
            val.push(v * ((st as f64 / sh_mean).max(1e-3) as f32) * w);
        }
        ptr.push(col.len());
        y.push(r.y.map(|c| c * w / scale));
    }
    (Csr { ptr, col, val, ncols: m }, y)
}

/// Row weights and the noise they give a row: with a shading, rows are weighted for relative
/// noise (σ ∝ y, as the photos' Monte-Carlo or shot noise): each row scaled by 1/y (luminance),
/// normalised to mean square 1; without, 1. Returns the weights and the mean over the rows of
/// `(ŷ w / scale)²`, the variance of a weighted row per unit relative noise of the photos.
fn row_weights(
    rows: &[Row],
    (init, init_obs): (&[[f32; 3]], &[bool]),
    mean: f64,
    scale: f32,
    relw: bool,
) -> (Vec<f32>, f64) {
    // ŷ: σ_p from the warm-start map through the operator, not from the pixel's own value: 1/y_p²
    // of a noisy y_p would bias the fit low by the relative variance (−0.8 % measured on the
    // reference short box)
    let yhat: Vec<f64> = rows
        .iter()
        .map(|r| {
            // over the taps on observed texels, renormalised: gutter and unseen texels hold no
            // back-projected value (0), which would make σ_p too small and the row's weight too
            // large
            let (mut pred, mut wsum, mut wall) = (0f64, 0f64, 0f64);
            for &(c, v) in &r.entries {
                wall += v as f64;
                if init_obs.get(c as usize).copied().unwrap_or(false) {
                    pred += v as f64 * super::luminance(init[c as usize]) as f64;
                    wsum += v as f64;
                }
            }
            let y = if wsum >= 0.5 * wall && pred > 0.0 { pred / wsum } else { super::luminance(r.y) as f64 };
            y.max(1e-3 * mean)
        })
        .collect();
    let w: Vec<f64> = if relw {
        let inv: Vec<f64> = yhat.iter().map(|y| 1.0 / y).collect();
        let msq = (inv.iter().map(|v| v * v).sum::<f64>() / inv.len() as f64).sqrt();
        inv.iter().map(|v| v / msq).collect()
    } else {
        vec![1.0; rows.len()]
    };
    let var = yhat.iter().zip(&w).map(|(y, w)| (y * w / scale as f64).powi(2)).sum::<f64>()
        / rows.len().max(1) as f64;
    (w.iter().map(|&v| v as f32).collect(), var)
}

/// The edge prior's edges: between 4-neighbours that are both unknowns and on the same chart
/// (gutter texels join any chart they touch); `idx` maps a texel to its unknown (`u32::MAX`:
/// none).
fn prior_edges(a: &Atlas, idx: &[u32]) -> Vec<(u32, u32)> {
    let chart = |i: usize| if a.texel_tri[i] == NO_TRI { u32::MAX } else { a.texel_chart(i) };
    let mut edges: Vec<(u32, u32)> = Vec::new();
    for yy in 0..a.height {
        for xx in 0..a.width {
            let i = yy * a.width + xx;
            if idx[i] == u32::MAX {
                continue;
            }
            let right = (xx + 1 < a.width).then_some(i + 1);
            let down = (yy + 1 < a.height).then_some(i + a.width);
            for j in [right, down].into_iter().flatten() {
                if idx[j] == u32::MAX {
                    continue;
                }
                let (ci, cj) = (chart(i), chart(j));
                if ci == cj || ci == u32::MAX || cj == u32::MAX {
                    edges.push((idx[i], idx[j]));
                }
            }
        }
    }
    edges
}

/// The solution on the atlas: texels no pure pixel covers keep the back-projected value; tied
/// gutter texels take the dilation of their chart's solution (× their own shading). Returns the
/// radiance map and the observed mask.
#[allow(clippy::too_many_arguments)] // the solution and its index maps, the warm start, the shading and scale
fn unknowns_to_map(
    a: &Atlas,
    x: &[[f32; 3]],
    texel_of: &[usize],
    idx: &[u32],
    (init, init_obs): (&[[f32; 3]], &[bool]),
    colw: &[f32],
    (sh, sd_t, sh_mean): (&[f32], &[f32], f64),
    scale: f32,
    shaded: bool,
    s: &SrSettings,
) -> (Vec<[f32; 3]>, Vec<bool>) {
    let mut out = init.to_vec();
    let mut obs = init_obs.to_vec();
    for (j, &t) in texel_of.iter().enumerate() {
        out[t] = x[j].map(|c| (c * sh[j] * scale).max(0.0));
        obs[t] |= colw[t] >= s.min_weight && a.texel_tri[t] != NO_TRI;
    }
    let covered: Vec<bool> = a.texel_tri.iter().map(|&t| t != NO_TRI).collect();
    let tie = super::inpaint::dilate_weights(&covered, &a.texel_owner, a.width, a.height);
    let tied: Vec<(usize, [f32; 3])> = (0..a.width * a.height)
        .into_par_iter()
        .filter(|&g| {
            !covered[g] && !tie[g].is_empty() && tie[g].iter().all(|&(k, _)| idx[k as usize] != u32::MAX)
        })
        .map(|g| {
            let mut k = [0f32; 3];
            for &(c, w) in &tie[g] {
                let xj = x[idx[c as usize] as usize];
                for ch in 0..3 {
                    k[ch] += w * xj[ch];
                }
            }
            let shg = if shaded { (sd_t[g] as f64 / sh_mean).max(1e-3) as f32 } else { 1.0 };
            (g, k.map(|c| (c * shg * scale).max(0.0)))
        })
        .collect();
    for (g, v) in tied {
        out[g] = v;
    }
    (out, obs)
}
