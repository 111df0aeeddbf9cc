//! Texture atlas of one object: UV unwrap (charts, parameterisation, packing) or the mesh's own
//! UVs, and the texel → surface rasterisation.
//!
//! * **Keeping UVs**: a mesh's own UVs are kept when every coordinate is finite and inside
//!   [0, 1], no triangle with positive area has a zero-area UV image, and rasterising the UV
//!   triangles at 512² finds (almost) no texel covered twice (≤ 0.1 % of the covered texels,
//!   which tolerates round-off along shared edges).
//! * **Unwrap** (decision page docs/decisions/uv-unwrap.md): vertices are welded by position and
//!   charts grown over edge-adjacent triangles whose face normal stays within 30° of the seed's.
//!   When every such chart is planar (all normals within 1°: boxes, walls) the planar path
//!   (`planar`) projects each chart orthogonally and shelf-packs the rectangles, exactly as
//!   before. Otherwise the curved path ([`curved`]): compact charts from a centroidal Voronoi
//!   partition of the surface with a 60° normal-cone guard (`segment`), each flattened by a
//!   least-squares conformal map (orthogonal projection for planar charts, `lscm`), charts
//!   with flipped triangles, folds, boundary overlaps or area ratios beyond 4 cut in two and
//!   flattened again, and shape packing at the largest density that fits, halving charts that
//!   find no place (`pack`). Charts are ≥ 2 texels apart, so every texel a bilinear look-up
//!   inside a chart reads has that chart as [`Atlas::texel_owner`], and gutter dilation
//!   (`inpaint::dilate`) fills owned texels from their own chart only. Texel world areas are
//!   computed per triangle, so the residual distortion is accounted for exactly in irradiance
//!   deposits. Utilisation ([`Atlas::utilisation`]) = covered texels (centre inside a UV
//!   triangle) / all texels: 75–77 % on displaced spheres and the 82 k-triangle scan at 1024².
//! * Mitsuba's uv convention: `v = 0` is the top row of the texture image; texel (c, r) has its
//!   centre at `((c+½)/W, (r+½)/H)`.
//!
//! Tests: `tests.rs` (kept UVs detected, overlapping UVs rejected, unwrap of a cube gives 6
//! planar charts; the displaced-sphere unwrap has no flipped or overlapping triangles, exact
//! texel areas, bilinear look-ups inside their own chart, utilisation ≥ 70 %, bounded
//! distortion, and is deterministic; the same checks on an open hemisphere + cube + degenerate
//! triangle in one mesh; LSCM flattens a cylinder patch isometrically; the Cornell box's meshes
//! take the planar path).

// Index loops over parallel per-texel arrays read more clearly than zipped iterators here.
#![allow(clippy::needless_range_loop)]

pub mod curved;
mod lscm;
mod pack;
mod planar;
pub mod quality;
mod segment;
pub mod testmesh;
#[cfg(test)]
mod tests;

use opal::geometry::TriangleMesh;
use opal::math::{DVec2, Vec2, Vec3};
use std::collections::HashMap;

/// Marker for "no triangle" in [`Atlas::texel_tri`].
pub const NO_TRI: u32 = u32::MAX;

/// Texture atlas of one object.
#[derive(Clone, Debug)]
pub struct Atlas {
    /// Texture width in texels.
    pub width: usize,
    /// Texture height in texels.
    pub height: usize,
    /// World-space mesh carrying the atlas UVs (vertices split along chart seams).
    pub mesh: TriangleMesh,
    /// True when the mesh's own UVs were kept.
    pub kept_uvs: bool,
    /// Number of charts.
    pub charts: usize,
    /// Chart of each triangle.
    pub tri_chart: Vec<u32>,
    /// World area of one texel on each triangle (0 for degenerate triangles).
    pub texel_area: Vec<f32>,
    /// Triangle whose UV image contains each texel centre, or [`NO_TRI`] (gutter).
    pub texel_tri: Vec<u32>,
    /// World position of each covered texel centre.
    pub texel_p: Vec<Vec3>,
    /// Unit shading normal at each covered texel centre.
    pub texel_n: Vec<Vec3>,
    /// Unit geometric normal at each covered texel centre.
    pub texel_ng: Vec<Vec3>,
    /// Chart owning each texel: the chart of every texel whose 3×3 neighbourhood meets that
    /// chart's UV image (so every texel a bilinear look-up inside the chart reads), or
    /// `u32::MAX` for texels near no chart or near two charts (only possible with kept UVs
    /// packed tighter than 2 texels). Dilation fills gutter texels from their owner only.
    pub texel_owner: Vec<u32>,
    /// Fraction of each texel's square covered by the object's UV triangles (4×4 sub-samples);
    /// irradiance deposited into a border texel is divided by it.
    pub coverage: Vec<f32>,
}

impl Atlas {
    /// Number of covered texels.
    pub fn covered(&self) -> usize {
        self.texel_tri.iter().filter(|&&t| t != NO_TRI).count()
    }
    /// Texel utilisation: covered texels (centre inside a UV triangle) / all texels.
    pub fn utilisation(&self) -> f64 {
        self.covered() as f64 / (self.width * self.height) as f64
    }
    /// Chart of texel `i` (`u32::MAX` for gutter texels).
    #[inline]
    pub fn texel_chart(&self, i: usize) -> u32 {
        let t = self.texel_tri[i];
        if t == NO_TRI { u32::MAX } else { self.tri_chart[t as usize] }
    }
}

fn uv_area(a: Vec2, b: Vec2, c: Vec2) -> f32 {
    0.5 * ((b - a).perp_dot(c - a))
}

/// Why a mesh's own UVs cannot be used, or `None` when they can.
pub fn uv_problem(mesh: &TriangleMesh) -> Option<String> {
    if mesh.uvs.is_empty() {
        return Some("the mesh has no texture coordinates".into());
    }
    if mesh.uvs.iter().any(|uv| !uv.is_finite() || uv.x < 0.0 || uv.y < 0.0 || uv.x > 1.0 || uv.y > 1.0) {
        return Some("texture coordinates outside [0, 1]".into());
    }
    for k in 0..mesh.triangle_count() {
        let [a, b, c] = mesh.indices[k].map(|i| mesh.uvs[i as usize]);
        if mesh.triangle_area(k) > 0.0 && uv_area(a, b, c).abs() < 1e-12 {
            return Some(format!("triangle {k} has a zero-area UV image"));
        }
    }
    let r = 512usize;
    let mut count = vec![0u8; r * r];
    for k in 0..mesh.triangle_count() {
        let uv = mesh.indices[k].map(|i| mesh.uvs[i as usize] * r as f32);
        // strictly inside (1e-4): centres on shared edges are not counted twice
        raster_triangle(uv, r, r, 1e-4, |x, y, _| {
            let c = &mut count[y * r + x];
            *c = c.saturating_add(1);
        });
    }
    let covered = count.iter().filter(|&&c| c > 0).count();
    let twice = count.iter().filter(|&&c| c > 1).count();
    if covered == 0 || twice as f64 > 1e-3 * covered as f64 {
        return Some(format!("overlapping UV triangles ({twice} of {covered} texels at 512² covered twice)"));
    }
    None
}

/// Calls `f(x, y, barycentrics)` for every texel whose centre lies inside the triangle given in
/// texel coordinates: all barycentrics ≥ `eps` (negative `eps` includes centres on edges).
fn raster_triangle(t: [Vec2; 3], w: usize, h: usize, eps: f32, mut f: impl FnMut(usize, usize, [f32; 3])) {
    let area = uv_area(t[0], t[1], t[2]);
    if area.abs() < 1e-12 || !area.is_finite() {
        return;
    }
    let lo = t[0].min(t[1]).min(t[2]);
    let hi = t[0].max(t[1]).max(t[2]);
    let x0 = (lo.x - 0.5).floor().max(0.0) as usize;
    let y0 = (lo.y - 0.5).floor().max(0.0) as usize;
    let x1 = ((hi.x - 0.5).ceil().max(0.0) as usize).min(w.saturating_sub(1));
    let y1 = ((hi.y - 0.5).ceil().max(0.0) as usize).min(h.saturating_sub(1));
    for y in y0..=y1 {
        for x in x0..=x1 {
            let p = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
            let b0 = uv_area(p, t[1], t[2]) / area;
            let b1 = uv_area(t[0], p, t[2]) / area;
            let b2 = 1.0 - b0 - b1;
            if b0 >= eps && b1 >= eps && b2 >= eps {
                f(x, y, [b0, b1, b2]);
            }
        }
    }
}

/// Builds the atlas of `mesh` at `res × res` texels. `keep_uvs`: use the mesh's own UVs when
/// they are usable (see [`uv_problem`]). Errors say why no atlas could be made.
pub fn build_atlas(mesh: &TriangleMesh, res: usize, keep_uvs: bool) -> Result<Atlas, String> {
    if mesh.triangle_count() == 0 {
        return Err("mesh has no triangles".into());
    }
    let keep = keep_uvs && uv_problem(mesh).is_none();
    let (out, tri_chart, charts) = if keep {
        // charts = connected components over shared vertex indices
        let mut parent: Vec<u32> = (0..mesh.positions.len() as u32).collect();
        fn find(p: &mut [u32], mut i: u32) -> u32 {
            while p[i as usize] != i {
                p[i as usize] = p[p[i as usize] as usize];
                i = p[i as usize];
            }
            i
        }
        for t in &mesh.indices {
            let a = find(&mut parent, t[0]);
            for &v in &t[1..] {
                let b = find(&mut parent, v);
                parent[b as usize] = a;
            }
        }
        let mut ids = HashMap::new();
        let tri_chart: Vec<u32> = mesh
            .indices
            .iter()
            .map(|t| {
                let r = find(&mut parent, t[0]);
                let n = ids.len() as u32;
                *ids.entry(r).or_insert(n)
            })
            .collect();
        (mesh.clone(), tri_chart, ids.len())
    } else {
        unwrap(mesh, res)?
    };
    let (w, h) = (res, res);
    let nt = out.triangle_count();
    let mut texel_area = vec![0.0f32; nt];
    let mut texel_tri = vec![NO_TRI; w * h];
    let mut texel_p = vec![Vec3::ZERO; w * h];
    let mut texel_n = vec![Vec3::ZERO; w * h];
    let mut texel_ng = vec![Vec3::ZERO; w * h];
    for k in 0..nt {
        let idx = out.indices[k];
        let uv = idx.map(|i| out.uvs[i as usize] * Vec2::new(w as f32, h as f32));
        let a_uv = uv_area(uv[0], uv[1], uv[2]).abs();
        let a_w = out.triangle_area(k);
        if a_uv > 0.0 && a_w > 0.0 {
            texel_area[k] = a_w / a_uv;
        }
        let [p0, p1, p2] = out.triangle(k);
        let ng = (p1 - p0).cross(p2 - p0).normalize_or_zero();
        raster_triangle(uv, w, h, -1e-5, |x, y, b| {
            let i = y * w + x;
            if texel_tri[i] != NO_TRI {
                return;
            }
            texel_tri[i] = k as u32;
            texel_p[i] = p0 * b[0] + p1 * b[1] + p2 * b[2];
            let ns = if out.normals.is_empty() {
                ng
            } else {
                let n = idx.map(|j| out.normals[j as usize]);
                (n[0] * b[0] + n[1] * b[1] + n[2] * b[2]).normalize_or_zero()
            };
            texel_n[i] = if ns == Vec3::ZERO { ng } else { ns };
            texel_ng[i] = ng;
        });
    }
    let mut cov = vec![0u8; w * h];
    for k in 0..nt {
        let uv = out.indices[k].map(|i| out.uvs[i as usize] * Vec2::new(4.0 * w as f32, 4.0 * h as f32));
        raster_triangle(uv, 4 * w, 4 * h, 0.0, |x, y, _| {
            let c = &mut cov[(y / 4) * w + x / 4];
            *c = (*c + 1).min(16);
        });
    }
    let coverage = cov.iter().map(|&c| c as f32 / 16.0).collect();
    let texel_owner = texel_owner(&out, &tri_chart, w, h);
    Ok(Atlas {
        texel_owner,
        coverage,
        width: w,
        height: h,
        mesh: out,
        kept_uvs: keep,
        charts,
        tri_chart,
        texel_area,
        texel_tri,
        texel_p,
        texel_n,
        texel_ng,
    })
}

/// Unwrap (see the module docs): the planar path when every chart of the 30° growth is planar,
/// else the curved path. New mesh, chart per triangle, chart count.
fn unwrap(mesh: &TriangleMesh, res: usize) -> Result<(TriangleMesh, Vec<u32>, usize), String> {
    let (tri_chart, chart_n) = planar::grow_charts(mesh);
    if planar::all_planar(mesh, &tri_chart, &chart_n) {
        planar::unwrap(mesh, res, tri_chart, chart_n)
    } else {
        curved::unwrap(mesh, res).map(|(m, t, c, _)| (m, t, c))
    }
}

/// Owner chart of each texel (see [`Atlas::texel_owner`]): conservative rasterisation of every
/// UV triangle grown by one texel.
fn texel_owner(mesh: &TriangleMesh, tri_chart: &[u32], w: usize, h: usize) -> Vec<u32> {
    const FREE: u32 = u32::MAX - 1;
    let mut owner = vec![FREE; w * h];
    let scale = DVec2::new(w as f64, h as f64);
    for (k, t) in mesh.indices.iter().enumerate() {
        let uv = t.map(|i| mesh.uvs[i as usize].as_dvec2() * scale);
        let c = tri_chart[k];
        pack::conservative_raster(uv, w, h, 1e-6, |x, y| {
            for yy in y.saturating_sub(1)..(y + 2).min(h) {
                for xx in x.saturating_sub(1)..(x + 2).min(w) {
                    let o = &mut owner[yy * w + xx];
                    if *o == FREE {
                        *o = c;
                    } else if *o != c {
                        *o = NO_TRI;
                    }
                }
            }
        });
    }
    owner.iter_mut().for_each(|o| {
        if *o == FREE {
            *o = NO_TRI;
        }
    });
    owner
}
