//! Planar-chart unwrap (the path for meshes made of planar faces, e.g. boxes): charts grow over
//! edge-adjacent triangles whose face normal stays within 30° of the chart's seed normal, each
//! chart is projected orthogonally onto its seed plane at one uniform texel density, and the
//! chart rectangles are shelf-packed (tallest first) with a gutter of 2 texels at the largest
//! density that fits (bisection). Used when every chart is planar (all face normals within
//! [`super::curved::PLANAR_DEG`] of the seed's), so box-like scenes keep their atlases exactly.
//!
//! Tests: `atlas::tests` (cube: 6 charts, uniform density, no overlap).

use opal::geometry::TriangleMesh;
use opal::math::{Frame, Vec2, Vec3};
use std::collections::HashMap;

/// Charts by region growing (welded vertices, 30° normal cone): chart index per triangle.
pub fn grow_charts(mesh: &TriangleMesh) -> (Vec<u32>, Vec<Vec3>) {
    let nt = mesh.triangle_count();
    let mut weld: HashMap<[u32; 3], u32> = HashMap::new();
    let wid: Vec<u32> = mesh
        .positions
        .iter()
        .map(|p| {
            let key = [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()];
            let n = weld.len() as u32;
            *weld.entry(key).or_insert(n)
        })
        .collect();
    let mut edges: HashMap<(u32, u32), Vec<u32>> = HashMap::new();
    for (k, t) in mesh.indices.iter().enumerate() {
        for e in 0..3 {
            let (a, b) = (wid[t[e] as usize], wid[t[(e + 1) % 3] as usize]);
            edges.entry((a.min(b), a.max(b))).or_default().push(k as u32);
        }
    }
    let normals: Vec<Vec3> = (0..nt)
        .map(|k| {
            let [a, b, c] = mesh.triangle(k);
            (b - a).cross(c - a).normalize_or_zero()
        })
        .collect();
    let cos_max = 30f32.to_radians().cos();
    let mut chart = vec![u32::MAX; nt];
    let mut chart_n = Vec::new();
    for seed in 0..nt {
        if chart[seed] != u32::MAX {
            continue;
        }
        let id = chart_n.len() as u32;
        let n0 = normals[seed];
        chart_n.push(if n0 == Vec3::ZERO { Vec3::Z } else { n0 });
        chart[seed] = id;
        if n0 == Vec3::ZERO {
            continue;
        }
        let mut stack = vec![seed];
        while let Some(k) = stack.pop() {
            let t = mesh.indices[k];
            for e in 0..3 {
                let (a, b) = (wid[t[e] as usize], wid[t[(e + 1) % 3] as usize]);
                for &nb in &edges[&(a.min(b), a.max(b))] {
                    let nb = nb as usize;
                    if chart[nb] == u32::MAX && normals[nb].dot(n0) > cos_max {
                        chart[nb] = id;
                        stack.push(nb);
                    }
                }
            }
        }
    }
    (chart, chart_n)
}

/// Shelf-packs rectangles (texel sizes) into `r × r`; returns the lower-left corners or `None`.
pub fn shelf_pack(sizes: &[(usize, usize)], order: &[usize], r: usize) -> Option<Vec<(usize, usize)>> {
    let mut pos = vec![(0, 0); sizes.len()];
    let (mut x, mut y, mut row_h) = (0usize, 0usize, 0usize);
    for &i in order {
        let (w, h) = sizes[i];
        if w > r {
            return None;
        }
        if x + w > r {
            y += row_h;
            x = 0;
            row_h = 0;
        }
        if y + h > r {
            return None;
        }
        pos[i] = (x, y);
        x += w;
        row_h = row_h.max(h);
    }
    Some(pos)
}

/// True when every triangle's normal is within [`super::curved::PLANAR_DEG`] of its chart's
/// seed normal (or degenerate).
pub fn all_planar(mesh: &TriangleMesh, tri_chart: &[u32], chart_n: &[Vec3]) -> bool {
    let cos = (super::curved::PLANAR_DEG as f32).to_radians().cos();
    (0..mesh.triangle_count()).all(|k| {
        let [a, b, c] = mesh.triangle(k);
        let n = (b - a).cross(c - a).normalize_or_zero();
        n == Vec3::ZERO || n.dot(chart_n[tri_chart[k] as usize]) >= cos
    })
}

/// Planar-chart unwrap (see the module docs): new mesh, chart per triangle, chart count.
pub fn unwrap(
    mesh: &TriangleMesh,
    res: usize,
    tri_chart: Vec<u32>,
    chart_n: Vec<Vec3>,
) -> Result<(TriangleMesh, Vec<u32>, usize), String> {
    let gutter = 2usize;
    let nc = chart_n.len();
    if nc * (2 * gutter + 1) * (2 * gutter + 1) > res * res {
        return Err(format!(
            "{nc} charts do not fit a {res}² texture (unwrap failed); use a larger texture resolution"
        ));
    }
    let frames: Vec<Frame> = chart_n.iter().map(|&n| Frame::from_normal(n)).collect();
    let proj = |c: usize, p: Vec3| {
        let l = frames[c].to_local(p);
        Vec2::new(l.x, l.y)
    };
    let mut lo = vec![Vec2::splat(f32::MAX); nc];
    let mut hi = vec![Vec2::splat(f32::MIN); nc];
    for (k, t) in mesh.indices.iter().enumerate() {
        let c = tri_chart[k] as usize;
        for &v in t {
            let q = proj(c, mesh.positions[v as usize]);
            lo[c] = lo[c].min(q);
            hi[c] = hi[c].max(q);
        }
    }
    let ext: Vec<Vec2> = (0..nc).map(|c| (hi[c] - lo[c]).max(Vec2::ZERO)).collect();
    let max_ext = ext.iter().map(|e| e.max_element()).fold(0.0f32, f32::max);
    if !(max_ext > 0.0 && max_ext.is_finite()) {
        return Err("degenerate mesh (zero extent)".into());
    }
    let mut order: Vec<usize> = (0..nc).collect();
    order.sort_by(|&a, &b| ext[b].y.total_cmp(&ext[a].y).then(a.cmp(&b)));
    let sizes = |s: f32| -> Vec<(usize, usize)> {
        ext.iter()
            .map(|e| ((e.x * s).ceil() as usize + 2 * gutter, (e.y * s).ceil() as usize + 2 * gutter))
            .collect()
    };
    // bisection on the density (texels per world unit)
    let (mut s_lo, mut s_hi) = (0.0f32, res as f32 / max_ext);
    for _ in 0..40 {
        let mid = 0.5 * (s_lo + s_hi);
        if shelf_pack(&sizes(mid), &order, res).is_some() {
            s_lo = mid;
        } else {
            s_hi = mid;
        }
    }
    let s = s_lo;
    let pos = shelf_pack(&sizes(s), &order, res).ok_or("chart packing failed")?;
    if s * max_ext < 1.0 {
        return Err(format!("charts too small at {res}²: the largest chart spans {:.2} texels", s * max_ext));
    }
    let mut out = TriangleMesh::default();
    let mut map: HashMap<(u32, u32), u32> = HashMap::new();
    for (k, t) in mesh.indices.iter().enumerate() {
        let c = tri_chart[k];
        let mut nt = [0u32; 3];
        for (j, &v) in t.iter().enumerate() {
            let n = out.positions.len() as u32;
            let id = *map.entry((v, c)).or_insert_with(|| {
                let p = mesh.positions[v as usize];
                let q = (proj(c as usize, p) - lo[c as usize]) * s;
                let (px, py) = pos[c as usize];
                let uv = Vec2::new(
                    (px as f32 + gutter as f32 + q.x) / res as f32,
                    (py as f32 + gutter as f32 + q.y) / res as f32,
                );
                out.positions.push(p);
                if !mesh.normals.is_empty() {
                    out.normals.push(mesh.normals[v as usize]);
                }
                out.uvs.push(uv);
                n
            });
            nt[j] = id;
        }
        out.indices.push(nt);
    }
    Ok((out, tri_chart, nc))
}
