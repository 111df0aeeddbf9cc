//! Chart borders of the super-resolution: the shading filled into the gutter texels
//! ([`shading_into_gutters`]) and the bilinear taps on gutter texels tied to the chart texels the
//! output albedo's gutters are dilated from ([`tie_gutters`]). Tests: those of [`super`].

use super::operator::Row;
use crate::delight::atlas::{Atlas, NO_TRI};
use rayon::prelude::*;

/// The shading with the gutter texels (no triangle, so no irradiance estimate: 0) filled from
/// their owner chart's texels ([`crate::delight::inpaint::dilate`], as the albedo's gutters are filled).
/// The bilinear taps of a sub-pixel ray near a chart border read gutter texels; with a shading
/// of (almost) 0 there the model would predict no radiance from them and the solve would bias the
/// border texels to make up for it.
pub(super) fn shading_into_gutters(sd: &[f32], a: &Atlas) -> Vec<f32> {
    let mut v: Vec<[f32; 3]> = sd.iter().map(|&x| [x; 3]).collect();
    let filled: Vec<bool> = a.texel_tri.iter().map(|&t| t != NO_TRI).collect();
    crate::delight::inpaint::dilate(&mut v, &filled, &a.texel_owner, a.width, a.height, 2);
    v.iter().map(|x| x[0]).collect()
}

/// Ties the bilinear taps on gutter texels to the chart texels the output albedo's gutters are
/// filled from ([`crate::delight::inpaint::dilate_weights`], the linear map of the owned rings of
/// [`crate::delight::inpaint::dilate`]): the model of a pixel near a chart border then predicts what the
/// recovered texture renders there, instead of leaving the gutter texels as free unknowns whose
/// solved values the output replaces. Gutter texels the owned rings do not reach stay their own
/// columns. Rewrites each row's entries to (column texel, geometric weight) and returns per
/// entry the weight-averaged shading `sd` of the texels behind it (B = shading × K per tapped
/// texel, K of a gutter = the dilation of its chart's K).
pub(super) fn tie_gutters(rows: &mut [Row], a: &Atlas, sd: &[f32]) -> Vec<Vec<f32>> {
    let covered: Vec<bool> = a.texel_tri.iter().map(|&t| t != NO_TRI).collect();
    let tie = crate::delight::inpaint::dilate_weights(&covered, &a.texel_owner, a.width, a.height);
    rows.par_iter_mut()
        .map(|r| {
            // (column, geometric weight, geometric weight × shading of the tapped texel)
            let mut e: Vec<(u32, f32, f32)> = Vec::with_capacity(r.entries.len() * 2);
            for &(c, v) in &r.entries {
                let ci = c as usize;
                if covered[ci] || tie[ci].is_empty() {
                    e.push((c, v, v * sd[ci]));
                } else {
                    for &(k, w) in &tie[ci] {
                        e.push((k, v * w, v * w * sd[ci]));
                    }
                }
            }
            e.sort_unstable_by_key(|x| x.0);
            let mut merged: Vec<(u32, f32, f32)> = Vec::with_capacity(e.len());
            for (c, v, vs) in e {
                match merged.last_mut() {
                    Some(l) if l.0 == c => {
                        l.1 += v;
                        l.2 += vs;
                    }
                    _ => merged.push((c, v, vs)),
                }
            }
            r.entries = merged.iter().map(|&(c, v, _)| (c, v)).collect();
            merged.iter().map(|&(_, v, vs)| if v > 0.0 { vs / v } else { 0.0 }).collect()
        })
        .collect()
}
