//! Quality measures of an atlas: flipped triangles, UV overlaps (high-resolution rasterisation
//! of triangle ids) and angle/area distortion (singular values of each triangle's map).
//!
//! * Angle distortion of a triangle: `σ₁/σ₂ ≥ 1` of the Jacobian from the surface to UV
//!   (1 = conformal).
//! * Area distortion: `r / r̄` with `r` = UV area / surface area and `r̄` its value over the
//!   whole mesh, folded to `max(x, 1/x) ≥ 1` (1 = uniform texel density).
//! * Means are area-weighted over the surface; percentiles too.
//!
//! Tests: `atlas::tests`.

use opal::geometry::TriangleMesh;
use opal::math::DVec2;

/// Distortion statistics (see the module docs).
#[derive(Clone, Copy, Debug, Default)]
pub struct Distortion {
    /// Area-weighted mean of σ₁/σ₂.
    pub angle_mean: f64,
    /// Area-weighted 95th percentile of σ₁/σ₂.
    pub angle_p95: f64,
    /// Area-weighted mean of the folded area ratio.
    pub area_mean: f64,
    /// Area-weighted 95th percentile of the folded area ratio.
    pub area_p95: f64,
    /// Triangles (with positive surface area) whose UV image has non-positive signed area.
    pub flipped: usize,
}

fn weighted_percentile(v: &mut [(f64, f64)], q: f64) -> f64 {
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    let total: f64 = v.iter().map(|x| x.1).sum();
    let mut acc = 0.0;
    for &(x, w) in v.iter() {
        acc += w;
        if acc >= q * total {
            return x;
        }
    }
    v.last().map_or(0.0, |x| x.0)
}

/// Distortion of the UV map of `mesh` (see the module docs).
pub fn distortion(mesh: &TriangleMesh) -> Distortion {
    let mut d = Distortion::default();
    let (mut a3_tot, mut a2_tot) = (0.0, 0.0);
    let mut per = Vec::with_capacity(mesh.triangle_count());
    for t in &mesh.indices {
        let [p0, p1, p2] = t.map(|i| mesh.positions[i as usize].as_dvec3());
        let [u0, u1, u2] = t.map(|i| mesh.uvs[i as usize].as_dvec2());
        let e1 = p1 - p0;
        let n = e1.cross(p2 - p0);
        let a3 = 0.5 * n.length();
        let a2 = 0.5 * (u1 - u0).perp_dot(u2 - u0);
        if a3 <= 0.0 || a3.is_nan() || e1.length() == 0.0 {
            continue;
        }
        if a2 <= 0.0 || a2.is_nan() {
            d.flipped += 1;
            continue;
        }
        let x = e1.normalize();
        let y = n.cross(x).normalize();
        let (q1, q2) = (DVec2::new(e1.length(), 0.0), DVec2::new((p2 - p0).dot(x), (p2 - p0).dot(y)));
        // J · [q1 q2] = [u1−u0 u2−u0]
        let det = q1.x * q2.y - q2.x * q1.y;
        let (v1, v2) = (u1 - u0, u2 - u0);
        // inverse of [q1 q2] = [[q2.y, −q2.x], [−q1.y, q1.x]] / det
        let j = [
            [(v1.x * q2.y - v2.x * q1.y) / det, (-v1.x * q2.x + v2.x * q1.x) / det],
            [(v1.y * q2.y - v2.y * q1.y) / det, (-v1.y * q2.x + v2.y * q1.x) / det],
        ];
        let e = j[0][0] * j[0][0] + j[0][1] * j[0][1] + j[1][0] * j[1][0] + j[1][1] * j[1][1];
        let dj = (j[0][0] * j[1][1] - j[0][1] * j[1][0]).abs();
        let disc = (e * e - 4.0 * dj * dj).max(0.0).sqrt();
        let (s1, s2) = (((e + disc) / 2.0).sqrt(), ((e - disc) / 2.0).max(0.0).sqrt());
        per.push((a3, a2 / a3, if s2 > 0.0 { s1 / s2 } else { f64::INFINITY }));
        a3_tot += a3;
        a2_tot += a2;
    }
    if per.is_empty() {
        return d;
    }
    let m = a2_tot / a3_tot;
    let mut ang: Vec<(f64, f64)> = per.iter().map(|&(w, _, q)| (q, w)).collect();
    let mut area: Vec<(f64, f64)> = per.iter().map(|&(w, r, _)| ((r / m).max(m / r), w)).collect();
    d.angle_mean = ang.iter().map(|x| x.0 * x.1).sum::<f64>() / a3_tot;
    d.area_mean = area.iter().map(|x| x.0 * x.1).sum::<f64>() / a3_tot;
    d.angle_p95 = weighted_percentile(&mut ang, 0.95);
    d.area_p95 = weighted_percentile(&mut area, 0.95);
    d
}

/// Texel centres of an `r × r` grid lying strictly inside (by `1e-4` of a texel in barycentric
/// terms) two or more UV triangles of `mesh`, and the covered centres.
pub fn overlaps(mesh: &TriangleMesh, r: usize) -> (usize, usize) {
    let mut count = vec![0u8; r * r];
    for t in &mesh.indices {
        let uv = t.map(|i| mesh.uvs[i as usize] * r as f32);
        super::raster_triangle(uv, r, r, 1e-4, |x, y, _| {
            let c = &mut count[y * r + x];
            *c = c.saturating_add(1);
        });
    }
    (count.iter().filter(|&&c| c > 1).count(), count.iter().filter(|&&c| c > 0).count())
}
