//! The model's predicted image of one view at a pose ([`render_prediction`]) and the
//! normalised Gaussian blur both it and the photo go through ([`blur`]). One ray per pixel
//! centre; pixels at an edge of the prediction (another shape or plane whose prediction
//! differs by more than 2 %) are box-filtered with 4 × 4 rays, as the photos are.
//!
//! Tests: through `solve.rs` (single-view alignment) and `tests.rs` (multi-view).

use opal::camera::Camera;
use opal::math::{DVec3, Vec2, Vec3};
use opal::scene::{Scene, SurfaceInteraction};
use rayon::prelude::*;

/// Separable Gaussian blur of `v` (NaN = undefined) by normalised convolution; returns the
/// blurred values and the defined fraction of the kernel weight per pixel.
pub fn blur(v: &[f32], w: usize, h: usize, sigma: f64) -> (Vec<f32>, Vec<f32>) {
    let r = (3.0 * sigma).ceil() as i64;
    let k: Vec<f64> = (-r..=r).map(|d| (-(d * d) as f64 / (2.0 * sigma * sigma)).exp()).collect();
    let ks: f64 = k.iter().sum();
    let k: Vec<f64> = k.iter().map(|x| x / ks).collect();
    let pass = |src: &[(f64, f64)], horizontal: bool| -> Vec<(f64, f64)> {
        (0..w * h)
            .into_par_iter()
            .map(|i| {
                let (x, y) = ((i % w) as i64, (i / w) as i64);
                let mut acc = (0.0, 0.0);
                for (j, d) in (-r..=r).enumerate() {
                    let (xx, yy) = if horizontal { (x + d, y) } else { (x, y + d) };
                    if xx < 0 || yy < 0 || xx >= w as i64 || yy >= h as i64 {
                        continue;
                    }
                    let s = src[yy as usize * w + xx as usize];
                    acc.0 += k[j] * s.0;
                    acc.1 += k[j] * s.1;
                }
                acc
            })
            .collect()
    };
    let init: Vec<(f64, f64)> =
        v.iter().map(|&x| if x.is_finite() { (x as f64, 1.0) } else { (0.0, 0.0) }).collect();
    let t = pass(&init, true);
    let s = pass(&t, false);
    s.iter().map(|&(a, m)| (if m > 1e-9 { (a / m) as f32 } else { f32::NAN }, m as f32)).unzip()
}

/// Surface a pixel's centre ray hits: shape and geometric normal.
pub(super) type SurfaceKey = Option<(u32, Vec3)>;

/// The predicted image at one pose.
pub(super) struct Prediction {
    /// Prediction per pixel (NaN = none).
    pub(super) p: Vec<f32>,
    /// Centre-ray hit point.
    pub(super) hits: Vec<Option<DVec3>>,
    /// Centre-ray hit surface.
    pub(super) keys: Vec<SurfaceKey>,
    /// The pixel straddles an edge (its prediction is the pixel mean).
    pub(super) mixed: Vec<bool>,
}

/// The prediction, the centre-ray hit point and the hit surface of every pixel at camera `cam`.
pub(super) fn render_prediction(
    scene: &Scene,
    cam: &Camera,
    predict: &(dyn Fn(&SurfaceInteraction) -> Option<f32> + Sync),
) -> Prediction {
    let (w, h) = (cam.width, cam.height);
    let px: Vec<(f32, Option<DVec3>, SurfaceKey)> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let c = Vec2::new((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
            match scene.intersect(&cam.generate_ray(c)) {
                Some(si) => {
                    (predict(&si).unwrap_or(f32::NAN), Some(si.p.as_dvec3()), Some((si.shape, si.ng)))
                }
                None => (f32::NAN, None, None),
            }
        })
        .collect();
    let mut out = (Vec::with_capacity(w * h), Vec::with_capacity(w * h), Vec::with_capacity(w * h));
    for (p, x, k) in px {
        out.0.push(p);
        out.1.push(x);
        out.2.push(k);
    }
    // a pixel whose neighbours see another surface straddles an edge: its photo is the mean over
    // the pixel (box filter), so is its prediction (EDGE_SS × EDGE_SS stratified rays; none when
    // a part of the pixel has no prediction). One centre ray would put the edge of the
    // prediction on the pixel grid, up to half a pixel from where the photo has it.
    // (Edges whose two sides predict within 2 % of each other, e.g. the facets of a tessellated
    // sphere, are left point-sampled: their offset is small and they are many.)
    let (keys, pc) = (&out.2, &out.0);
    let same = |i: usize, j: usize| match (keys[i], keys[j]) {
        (Some((a, na)), Some((b, nb))) => {
            (a == b && na.dot(nb) > 0.999) || (pc[i] - pc[j]).abs() <= 0.02 * pc[i].abs().max(pc[j].abs())
        }
        (None, None) => true,
        _ => false,
    };
    let edge: Vec<usize> = (0..w * h)
        .filter(|&i| {
            let (x, y) = (i % w, i / w);
            (x > 0 && !same(i, i - 1))
                || (x + 1 < w && !same(i, i + 1))
                || (y > 0 && !same(i, i - w))
                || (y + 1 < h && !same(i, i + w))
        })
        .collect();
    let n = EDGE_SS;
    let sub: Vec<f32> = edge
        .par_iter()
        .map(|&i| {
            let mut acc = 0.0f32;
            for k in 0..n * n {
                let c = Vec2::new(
                    (i % w) as f32 + ((k % n) as f32 + 0.5) / n as f32,
                    (i / w) as f32 + ((k / n) as f32 + 0.5) / n as f32,
                );
                match scene.intersect(&cam.generate_ray(c)).and_then(|si| predict(&si)) {
                    Some(v) => acc += v,
                    None => return f32::NAN,
                }
            }
            acc / (n * n) as f32
        })
        .collect();
    let mut mixed = vec![false; w * h];
    for (&i, v) in edge.iter().zip(sub) {
        out.0[i] = v;
        mixed[i] = true;
    }
    Prediction { p: out.0, hits: out.1, keys: out.2, mixed }
}

/// Rays per side of a pixel at an edge of the prediction.
const EDGE_SS: usize = 4;
