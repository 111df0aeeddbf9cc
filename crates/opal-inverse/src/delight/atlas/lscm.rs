//! Chart parameterisation: least-squares conformal maps (Lévy, Petitjean, Ray & Maillot 2002,
//! "Least squares conformal maps for automatic texture atlas generation") solved with
//! Jacobi-preconditioned conjugate gradients on the normal equations (matrix-free, f64), the
//! orthogonal projection for planar charts, and the validity checks (flipped triangles,
//! folded vertices, self-overlapping boundary, area distortion).
//!
//! * Conformal energy of a triangle with local coordinates `q_j` and opposite edges
//!   `e_j = q_{j+2} − q_{j+1}`: `A · |rot ∇u − ∇v|²`, i.e. the two residual rows
//!   `Σ_j (−e_j.x u_j + e_j.y v_j)` and `Σ_j (−e_j.y u_j − e_j.x v_j)`, each divided by
//!   `2 √A`. Orientation-preserving similarities have zero energy; mirror images do not.
//! * Two vertices far apart along the chart's principal axis are pinned at their orthogonal
//!   projection onto the chart's mean plane, which is also the starting guess.
//! * The result is scaled so that its UV area equals the chart's surface area (one texel density
//!   for all charts).
//!
//! Tests: `atlas::tests` (flat, curved and displaced charts; no flips, no overlaps).

use opal::math::{DVec2, DVec3};

/// A chart flattened to the plane (world units).
pub struct Flat {
    /// Local triangles (indices into `uv`).
    pub tris: Vec<[u32; 3]>,
    /// UV of each local vertex.
    pub uv: Vec<DVec2>,
}

/// Orthonormal basis (x, y) of the plane with normal `n`.
fn plane_basis(n: DVec3) -> (DVec3, DVec3) {
    let a = if n.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
    let x = n.cross(a).normalize();
    (x, n.cross(x))
}

/// Orthogonal projection onto the plane of the area-weighted mean normal.
pub fn project(p: &[DVec3], tris: &[[u32; 3]]) -> Vec<DVec2> {
    let mut n = DVec3::ZERO;
    for t in tris {
        let [a, b, c] = t.map(|i| p[i as usize]);
        n += (b - a).cross(c - a);
    }
    let n = n.try_normalize().unwrap_or(DVec3::Z);
    let (x, y) = plane_basis(n);
    p.iter().map(|&q| DVec2::new(q.dot(x), q.dot(y))).collect()
}

/// Per-triangle residual coefficients: for corner j, (coef of u_j, coef of v_j) in row 1 and
/// row 2 are (c1u, c1v) = (−e.x, e.y) / s and (c2u, c2v) = (−e.y, −e.x) / s with s = 2√A.
fn coefficients(p: &[DVec3], tris: &[[u32; 3]]) -> Vec<[DVec2; 3]> {
    tris.iter()
        .map(|t| {
            let [p0, p1, p2] = t.map(|i| p[i as usize]);
            let e1 = p1 - p0;
            let l = e1.length();
            let n = e1.cross(p2 - p0);
            let a = 0.5 * n.length();
            if !(l > 0.0 && a > 1e-300) {
                return [DVec2::ZERO; 3];
            }
            let x = e1 / l;
            let y = n.cross(x).normalize();
            let q = [DVec2::ZERO, DVec2::new(l, 0.0), DVec2::new((p2 - p0).dot(x), (p2 - p0).dot(y))];
            let s = 2.0 * a.sqrt();
            std::array::from_fn(|j| (q[(j + 2) % 3] - q[(j + 1) % 3]) / s)
        })
        .collect()
}

/// y = A x (two rows per triangle); x = [u…, v…].
fn mul(tris: &[[u32; 3]], e: &[[DVec2; 3]], n: usize, x: &[f64], y: &mut [f64]) {
    for (k, t) in tris.iter().enumerate() {
        let (mut r1, mut r2) = (0.0, 0.0);
        for j in 0..3 {
            let (u, v) = (x[t[j] as usize], x[n + t[j] as usize]);
            let ej = e[k][j];
            r1 += -ej.x * u + ej.y * v;
            r2 += -ej.y * u - ej.x * v;
        }
        y[2 * k] = r1;
        y[2 * k + 1] = r2;
    }
}

/// x = Aᵀ y.
fn mul_t(tris: &[[u32; 3]], e: &[[DVec2; 3]], n: usize, y: &[f64], x: &mut [f64]) {
    x.fill(0.0);
    for (k, t) in tris.iter().enumerate() {
        let (r1, r2) = (y[2 * k], y[2 * k + 1]);
        for j in 0..3 {
            let ej = e[k][j];
            x[t[j] as usize] += -ej.x * r1 - ej.y * r2;
            x[n + t[j] as usize] += ej.y * r1 - ej.x * r2;
        }
    }
}

/// LSCM of a chart with local positions `p` and triangles `tris` (see the module docs).
/// Returns the UVs (world units) and the number of CG iterations.
pub fn lscm(p: &[DVec3], tris: &[[u32; 3]]) -> (Vec<DVec2>, usize) {
    let n = p.len();
    let init = project(p, tris);
    // pins: extremes along the principal axis of the projection
    let c = init.iter().copied().sum::<DVec2>() / n as f64;
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for q in &init {
        let d = *q - c;
        sxx += d.x * d.x;
        sxy += d.x * d.y;
        syy += d.y * d.y;
    }
    let ang = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    let axis = DVec2::new(ang.cos(), ang.sin());
    let key = |i: usize| init[i].dot(axis);
    let lo = (0..n).min_by(|&a, &b| key(a).total_cmp(&key(b))).unwrap_or(0);
    let hi = (0..n).max_by(|&a, &b| key(a).total_cmp(&key(b))).unwrap_or(0);
    if lo == hi || tris.len() < 2 {
        return (init, 0);
    }
    let e = coefficients(p, tris);
    let mut free = vec![1.0; 2 * n];
    for i in [lo, hi] {
        free[i] = 0.0;
        free[n + i] = 0.0;
    }
    let mut x: Vec<f64> = init.iter().map(|q| q.x).chain(init.iter().map(|q| q.y)).collect();
    // Jacobi preconditioner: diagonal of AᵀA
    let mut diag = vec![0.0; 2 * n];
    for (k, t) in tris.iter().enumerate() {
        for j in 0..3 {
            let d = e[k][j].length_squared();
            diag[t[j] as usize] += d;
            diag[n + t[j] as usize] += d;
        }
    }
    let inv: Vec<f64> = (0..2 * n).map(|i| if diag[i] > 0.0 { free[i] / diag[i] } else { 0.0 }).collect();
    let mut ax = vec![0.0; 2 * tris.len()];
    let apply = |v: &[f64], out: &mut [f64], ax: &mut [f64]| {
        mul(tris, &e, n, v, ax);
        mul_t(tris, &e, n, ax, out);
        for i in 0..2 * n {
            out[i] *= free[i];
        }
    };
    let mut r = vec![0.0; 2 * n];
    apply(&x, &mut r, &mut ax);
    r.iter_mut().for_each(|v| *v = -*v);
    let mut z: Vec<f64> = (0..2 * n).map(|i| r[i] * inv[i]).collect();
    let mut d = z.clone();
    let mut rz: f64 = (0..2 * n).map(|i| r[i] * z[i]).sum();
    let rz0 = rz;
    let mut q = vec![0.0; 2 * n];
    let max_iter = 4000 + 4 * n;
    let mut it = 0;
    while it < max_iter && rz > 1e-24 * rz0 && rz > 0.0 {
        apply(&d, &mut q, &mut ax);
        let dq: f64 = (0..2 * n).map(|i| d[i] * q[i]).sum();
        if dq <= 0.0 {
            break;
        }
        let alpha = rz / dq;
        for i in 0..2 * n {
            x[i] += alpha * d[i];
            r[i] -= alpha * q[i];
            z[i] = r[i] * inv[i];
        }
        let rz_new: f64 = (0..2 * n).map(|i| r[i] * z[i]).sum();
        let beta = rz_new / rz;
        rz = rz_new;
        for i in 0..2 * n {
            d[i] = z[i] + beta * d[i];
        }
        it += 1;
    }
    let mut uv: Vec<DVec2> = (0..n).map(|i| DVec2::new(x[i], x[n + i])).collect();
    // same total area as the surface
    let (mut a3, mut a2) = (0.0, 0.0);
    for t in tris {
        let [a, b, c] = t.map(|i| p[i as usize]);
        a3 += 0.5 * (b - a).cross(c - a).length();
        let [a, b, c] = t.map(|i| uv[i as usize]);
        a2 += 0.5 * (b - a).perp_dot(c - a);
    }
    if a2 > 0.0 && a3 > 0.0 {
        let s = (a3 / a2).sqrt();
        uv.iter_mut().for_each(|q| *q *= s);
    }
    (uv, it)
}

/// Why a flattened chart is not acceptable, or `None`: a flipped or degenerate triangle, a
/// folded interior vertex, intersecting boundary edges, or a triangle whose UV/surface area
/// ratio differs from the chart's by more than `max_area_ratio` (either way).
pub fn problem(p: &[DVec3], f: &Flat, max_area_ratio: f64) -> Option<&'static str> {
    let (mut a3, mut a2) = (0.0, 0.0);
    let mut ratio = Vec::with_capacity(f.tris.len());
    for t in &f.tris {
        let [a, b, c] = t.map(|i| p[i as usize]);
        let s3 = 0.5 * (b - a).cross(c - a).length();
        let [a, b, c] = t.map(|i| f.uv[i as usize]);
        let s2 = 0.5 * (b - a).perp_dot(c - a);
        if s3 > 0.0 && (s2 <= 0.0 || s2.is_nan()) {
            return Some("flipped triangle");
        }
        a3 += s3;
        a2 += s2;
        ratio.push((s2, s3));
    }
    let m = a2 / a3;
    for &(s2, s3) in &ratio {
        if s3 > 0.0 && (s2 / s3 > m * max_area_ratio || s2 / s3 < m / max_area_ratio) {
            return Some("area distortion");
        }
    }
    // edges → triangles; angle sums at interior vertices; boundary edges
    let mut edges: std::collections::HashMap<(u32, u32), u32> = std::collections::HashMap::new();
    for t in &f.tris {
        for j in 0..3 {
            let (a, b) = (t[j], t[(j + 1) % 3]);
            *edges.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    let mut boundary_vertex = vec![false; f.uv.len()];
    let mut bnd = Vec::new();
    for (&(a, b), &c) in &edges {
        if c != 2 {
            boundary_vertex[a as usize] = true;
            boundary_vertex[b as usize] = true;
            bnd.push((a, b));
        }
    }
    let mut angle = vec![0.0f64; f.uv.len()];
    for t in &f.tris {
        for j in 0..3 {
            let o = f.uv[t[j] as usize];
            let (u, v) = (f.uv[t[(j + 1) % 3] as usize] - o, f.uv[t[(j + 2) % 3] as usize] - o);
            angle[t[j] as usize] += u.perp_dot(v).atan2(u.dot(v));
        }
    }
    if (0..f.uv.len()).any(|i| !boundary_vertex[i] && angle[i] > 3.0 * std::f64::consts::PI) {
        return Some("folded vertex");
    }
    if boundary_overlap(&f.uv, &mut bnd) {
        return Some("overlapping boundary");
    }
    None
}

/// Exact test (orientation predicates in f64) whether two boundary segments not sharing a
/// vertex intersect; a sweep over x keeps it near-linear.
fn boundary_overlap(uv: &[DVec2], bnd: &mut [(u32, u32)]) -> bool {
    let lo = |s: &(u32, u32)| uv[s.0 as usize].x.min(uv[s.1 as usize].x);
    let hi = |s: &(u32, u32)| uv[s.0 as usize].x.max(uv[s.1 as usize].x);
    bnd.sort_by(|a, b| lo(a).total_cmp(&lo(b)).then(a.cmp(b)));
    let orient = |a: DVec2, b: DVec2, c: DVec2| (b - a).perp_dot(c - a);
    for i in 0..bnd.len() {
        let (a, b) = bnd[i];
        let (pa, pb) = (uv[a as usize], uv[b as usize]);
        let h = hi(&bnd[i]);
        for &(c, d) in &bnd[i + 1..] {
            if uv[c as usize].x.min(uv[d as usize].x) > h {
                break;
            }
            if a == c || a == d || b == c || b == d {
                continue;
            }
            let (pc, pd) = (uv[c as usize], uv[d as usize]);
            let (o1, o2) = (orient(pa, pb, pc), orient(pa, pb, pd));
            let (o3, o4) = (orient(pc, pd, pa), orient(pc, pd, pb));
            if o1 * o2 <= 0.0 && o3 * o4 <= 0.0 {
                // collinear and disjoint segments are not an intersection
                let disjoint = o1 == 0.0
                    && o2 == 0.0
                    && (pa.max(pb).cmplt(pc.min(pd)).any() || pc.max(pd).cmplt(pa.min(pb)).any());
                if !disjoint {
                    return true;
                }
            }
        }
    }
    false
}
