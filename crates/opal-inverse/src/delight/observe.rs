//! Observation of the objects in the views: the back-projected luminance map of an object
//! (step 2 of the pipeline, [`luminance_map`]), pixel masks and rays of the views, and region
//! statistics of images (the paper's tables). Conventions: texel centres and "pure" pixels as in
//! [`super::views::pure_buffer`]. Tests: the de-lighting end-to-end tests (`tests/delight.rs`)
//! and the super-resolution test in `superres.rs` (back-projection baseline).

// Index loops over parallel per-texel arrays read more clearly than zipped iterators here.
#![allow(clippy::needless_range_loop)]

use super::atlas::{Atlas, NO_TRI};
use super::luminance;
use super::views::{self, MIXED, PureBuffer, View};
use opal::geometry::Ray;
use opal::image::Image;
use opal::integrator::spawn_ray_to;
use opal::math::{Vec2, Vec3};
use opal::scene::Scene;
use rayon::prelude::*;

/// Luminance map of one object (step 2): values, observed mask.
pub fn luminance_map(
    scene: &Scene,
    shape: u32,
    a: &Atlas,
    views: &[View],
    pure: &[PureBuffer],
) -> (Vec<[f32; 3]>, Vec<bool>) {
    let n = a.width * a.height;
    let res: Vec<([f32; 3], bool)> = (0..n)
        .into_par_iter()
        .map(|i| {
            if a.texel_tri[i] == NO_TRI {
                return ([0.0; 3], false);
            }
            let mut acc = [0f64; 3];
            let mut wsum = 0f64;
            for (v, pb) in views.iter().zip(pure) {
                let Some(ViewSample { sum: val, weight: wt, cos, .. }) =
                    view_sample(scene, shape, a, i, v, pb)
                else {
                    continue;
                };
                let wv = cos as f64;
                for ch in 0..3 {
                    acc[ch] += wv * val[ch] / wt;
                }
                wsum += wv;
            }
            if wsum > 0.0 { (acc.map(|x| (x / wsum) as f32), true) } else { ([0.0; 3], false) }
        })
        .collect();
    res.into_iter().unzip()
}

/// One view's sample of a texel ([`view_sample`]).
pub(crate) struct ViewSample {
    /// `Σ w·rgb` over the usable bilinear taps.
    pub sum: [f64; 3],
    /// `Σ w` (the texel's radiance in this view is `sum / weight`).
    pub weight: f64,
    /// `Σ w²` (pixels with independent noise of variance σ² give the sample `sum / weight` the
    /// variance `σ² · weight_sq / weight²`).
    pub weight_sq: f64,
    /// Shading normal · direction to the camera.
    pub cos: f32,
    /// (min, max) luminance of the usable taps.
    pub tap_range: (f32, f32),
}

/// One view's sample of texel `i` (step 2) over the bilinear taps that fall on pure pixels of
/// `shape` and the texel's plane, or `None` when the texel faces away, leaves the frustum, is
/// occluded, or fewer than half the tap weight is usable.
pub(crate) fn view_sample(
    scene: &Scene,
    shape: u32,
    a: &Atlas,
    i: usize,
    v: &View,
    pb: &PureBuffer,
) -> Option<ViewSample> {
    let (p, ng) = (a.texel_p[i], a.texel_ng[i]);
    let ns = a.texel_n[i];
    let cam = &v.camera;
    let to_cam = cam.origin() - p;
    let dist = to_cam.length();
    let dir = to_cam / dist;
    let cos = ns.dot(dir);
    if cos <= 0.0 || ng.dot(dir) <= 0.0 {
        return None;
    }
    let px = cam.project(p)?;
    let shadow = spawn_ray_to(p, ng, cam.origin(), Vec3::ZERO);
    if scene.occluded(&shadow) {
        return None;
    }
    // bilinear taps on pure pixels of this shape and plane
    let x = px.x - 0.5;
    let y = px.y - 0.5;
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let mut val = [0f64; 3];
    let mut wt = 0f64;
    let mut wsq = 0f64;
    let mut range = (f32::INFINITY, f32::NEG_INFINITY);
    for (dx, dy, w) in
        [(0, 0, (1.0 - fx) * (1.0 - fy)), (1, 0, fx * (1.0 - fy)), (0, 1, (1.0 - fx) * fy), (1, 1, fx * fy)]
    {
        let (xi, yi) = (x0 as i64 + dx, y0 as i64 + dy);
        if xi < 0 || yi < 0 || xi >= cam.width as i64 || yi >= cam.height as i64 || w <= 0.0 {
            continue;
        }
        let k = yi as usize * cam.width + xi as usize;
        if pb.shape(k) != shape || pb.normal(k).dot(ng) < pb.min_cos(k) {
            continue;
        }
        let c = v.image.data[k];
        if !c.is_finite() {
            continue;
        }
        for ch in 0..3 {
            val[ch] += w as f64 * c[ch] as f64;
        }
        wt += w as f64;
        wsq += (w as f64).powi(2);
        let y = luminance(c.0);
        range = (range.0.min(y), range.1.max(y));
    }
    if wt < 0.5 {
        return None;
    }
    Some(ViewSample { sum: val, weight: wt, weight_sq: wsq, cos, tap_range: range })
}

/// Statistics of an image region (the paper's tables 1–3).
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct RegionStats {
    /// Pixels in the region.
    pub pixels: usize,
    /// Mean Rec. 709 luminance.
    pub mean_luminance: f64,
    /// RMS deviation of the luminance from its mean.
    pub luminance_rms: f64,
    /// Mean linear RGB.
    pub mean_rgb: [f64; 3],
    /// CIE 1931 xy chromaticity of the mean RGB (linear Rec. 709 / sRGB primaries, D65).
    pub xy: [f64; 2],
}

/// Region statistics of `img` over the pixels where `mask` is true (non-finite pixels skipped).
pub fn region_stats(img: &Image, mask: &[bool]) -> RegionStats {
    let mut n = 0usize;
    let mut rgb = [0f64; 3];
    let mut ys = Vec::new();
    for (p, &m) in img.data.iter().zip(mask) {
        if m && p.is_finite() {
            n += 1;
            for c in 0..3 {
                rgb[c] += p[c] as f64;
            }
            ys.push(luminance([p[0], p[1], p[2]]) as f64);
        }
    }
    let nf = n.max(1) as f64;
    let rgb = rgb.map(|v| v / nf);
    let my = ys.iter().sum::<f64>() / nf;
    let rms = (ys.iter().map(|y| (y - my).powi(2)).sum::<f64>() / nf).sqrt();
    let x = 0.4124 * rgb[0] + 0.3576 * rgb[1] + 0.1805 * rgb[2];
    let y = 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2];
    let z = 0.0193 * rgb[0] + 0.1192 * rgb[1] + 0.9505 * rgb[2];
    let s = (x + y + z).max(1e-30);
    RegionStats { pixels: n, mean_luminance: my, luminance_rms: rms, mean_rgb: rgb, xy: [x / s, y / s] }
}

/// Pixel masks of the objects in a view: `mask[k][pixel]` true where the pixel shows shape
/// `shapes[k]` entirely (see [`views::pure_buffer`]).
pub fn object_masks(scene: &Scene, view: &View, shapes: &[usize]) -> Vec<Vec<bool>> {
    let pb = views::pure_buffer(scene, &view.camera);
    shapes.iter().map(|&s| pb.shapes().map(|x| x != MIXED && x as usize == s).collect()).collect()
}

/// A ray through the centre of pixel (x, y) of a view (helper for tests and tools).
pub fn pixel_ray(view: &View, x: usize, y: usize) -> Ray {
    view.camera.generate_ray(Vec2::new(x as f32 + 0.5, y as f32 + 0.5))
}
