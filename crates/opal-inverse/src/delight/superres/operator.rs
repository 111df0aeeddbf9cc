//! The observation operator of the super-resolution: per pure pixel of a view, the bilinear
//! texel weights of its S² sub-pixel rays ([`Row`], [`view_rows`]), and the sparse matrix the
//! rows become ([`Csr`]). Tests: those of [`super`].

use crate::delight::atlas::Atlas;
use crate::delight::views::{PureBuffer, View};
use opal::math::{Vec2, Vec3};
use opal::scene::Scene;
use rayon::prelude::*;

/// Sparse row-major matrix.
pub(super) struct Csr {
    pub(super) ptr: Vec<usize>,
    pub(super) col: Vec<u32>,
    pub(super) val: Vec<f32>,
    pub(super) ncols: usize,
}

impl Csr {
    pub(super) fn rows(&self) -> usize {
        self.ptr.len() - 1
    }
    pub(super) fn transpose(&self) -> Csr {
        let mut count = vec![0usize; self.ncols + 1];
        for &c in &self.col {
            count[c as usize + 1] += 1;
        }
        for i in 0..self.ncols {
            count[i + 1] += count[i];
        }
        let ptr = count.clone();
        let mut next = count;
        let mut col = vec![0u32; self.col.len()];
        let mut val = vec![0f32; self.val.len()];
        for r in 0..self.rows() {
            for k in self.ptr[r]..self.ptr[r + 1] {
                let c = self.col[k] as usize;
                col[next[c]] = r as u32;
                val[next[c]] = self.val[k];
                next[c] += 1;
            }
        }
        Csr { ptr, col, val, ncols: self.rows() }
    }
    /// out = self · x (RGB vectors).
    pub(super) fn mul(&self, x: &[[f32; 3]], out: &mut [[f32; 3]]) {
        out.par_iter_mut().enumerate().with_min_len(256).for_each(|(r, o)| {
            let mut s = [0f32; 3];
            for k in self.ptr[r]..self.ptr[r + 1] {
                let v = self.val[k];
                let xv = x[self.col[k] as usize];
                for c in 0..3 {
                    s[c] += v * xv[c];
                }
            }
            *o = s;
        });
    }
}

/// One observed pixel: the texel weights of its S² sub-pixel samples and its value.
pub(super) struct Row {
    pub(super) entries: Vec<(u32, f32)>,
    pub(super) y: [f32; 3],
    pub(super) pix: u32,
}

fn bary(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> (f32, f32, f32) {
    let (v0, v1, v2) = (b - a, c - a, p - a);
    let (d00, d01, d11) = (v0.dot(v0), v0.dot(v1), v1.dot(v1));
    let (d20, d21) = (v2.dot(v0), v2.dot(v1));
    let den = d00 * d11 - d01 * d01;
    if den.abs() < 1e-30 {
        return (1.0, 0.0, 0.0);
    }
    let v = (d11 * d20 - d01 * d21) / den;
    let w = (d00 * d21 - d01 * d20) / den;
    (1.0 - v - w, v, w)
}

/// Rows of the observation operator for one view.
pub(super) fn view_rows(
    scene: &Scene,
    shape: u32,
    a: &Atlas,
    view: &View,
    pure: &PureBuffer,
    ss: u32,
) -> Vec<Row> {
    let cam = &view.camera;
    let first = scene.shapes[shape as usize].first_prim;
    let ntri = a.mesh.indices.len() as u32;
    let (w, h) = (a.width as i64, a.height as i64);
    let wgt = 1.0 / (ss * ss) as f32;
    (0..cam.height)
        .into_par_iter()
        .flat_map_iter(|py| {
            let mut rows = Vec::new();
            // the taps of one pixel (S² rays × 4), reused from pixel to pixel of the line
            let mut e: Vec<(u32, f32)> = Vec::with_capacity(4 * (ss * ss) as usize);
            'pix: for px in 0..cam.width {
                let k = py * cam.width + px;
                if pure.covered[k] != shape {
                    continue;
                }
                let yv = view.image.data[k];
                if !yv.is_finite() {
                    continue;
                }
                e.clear();
                for sy in 0..ss {
                    for sx in 0..ss {
                        let c = Vec2::new(
                            px as f32 + (sx as f32 + 0.5) / ss as f32,
                            py as f32 + (sy as f32 + 0.5) / ss as f32,
                        );
                        let Some(hit) = scene.intersect(&cam.generate_ray(c)) else { continue 'pix };
                        if hit.shape != shape || hit.prim < first || hit.prim - first >= ntri {
                            continue 'pix;
                        }
                        let t = a.mesh.indices[(hit.prim - first) as usize];
                        let p = |i: u32| a.mesh.positions[i as usize];
                        let (b0, b1, b2) = bary(hit.p, p(t[0]), p(t[1]), p(t[2]));
                        let uv = a.mesh.uvs[t[0] as usize] * b0
                            + a.mesh.uvs[t[1] as usize] * b1
                            + a.mesh.uvs[t[2] as usize] * b2;
                        let x = uv.x * w as f32 - 0.5;
                        let y = uv.y * h as f32 - 0.5;
                        let (x0, y0) = (x.floor(), y.floor());
                        let (fx, fy) = (x - x0, y - y0);
                        for (dx, dy, bw) in [
                            (0, 0, (1.0 - fx) * (1.0 - fy)),
                            (1, 0, fx * (1.0 - fy)),
                            (0, 1, (1.0 - fx) * fy),
                            (1, 1, fx * fy),
                        ] {
                            if bw <= 0.0 {
                                continue;
                            }
                            let xi = (x0 as i64 + dx).clamp(0, w - 1);
                            let yi = (y0 as i64 + dy).clamp(0, h - 1);
                            e.push(((yi * w + xi) as u32, bw * wgt));
                        }
                    }
                }
                rows.push(Row { entries: merge_taps(&mut e), y: yv.0, pix: k as u32 });
            }
            rows
        })
        .collect()
}

/// The taps `e` sorted by texel with the weights of a texel summed (in the order of `e`), in a
/// vector of exactly their length: a row is held until the operator is built, and its merged
/// taps (about a dozen for 4 × 4 rays) are a fraction of the S² × 4 unmerged ones.
fn merge_taps(e: &mut [(u32, f32)]) -> Vec<(u32, f32)> {
    e.sort_unstable_by_key(|&(c, _)| c);
    let unique = 1 + e.windows(2).filter(|p| p[0].0 != p[1].0).count();
    let mut merged: Vec<(u32, f32)> = Vec::with_capacity(if e.is_empty() { 0 } else { unique });
    for &(c, v) in e.iter() {
        match merged.last_mut() {
            Some(l) if l.0 == c => l.1 += v,
            _ => merged.push((c, v)),
        }
    }
    merged
}
