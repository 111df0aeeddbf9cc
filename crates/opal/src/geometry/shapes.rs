//! Mitsuba's built-in analytic shapes tessellated into [`TriangleMesh`]es in their local
//! frame (before `to_world`), plus the angle-weighted vertex normals Mitsuba computes for
//! meshes that come without normals.
//!
//! * [`rectangle_mesh`]: the square `[-1,1]²` at z = 0 facing +z, 2 triangles.
//! * [`cube_mesh`]: the cube `[-1,1]³`, 12 triangles laid out like Mitsuba's `cube` mesh.
//! * [`sphere_mesh`]: the unit sphere on a latitude–longitude grid; the scene loader uses
//!   [`SPHERE_SEGMENTS_PHI`]×[`SPHERE_SEGMENTS_THETA`] segments.
//! * [`disk_mesh`]: the unit disk at z = 0 facing +z (Mitsuba `disk`), polar grid of
//!   [`DISK_SEGMENTS_PHI`] sectors × [`DISK_SEGMENTS_R`] rings, uv = (r, φ/2π).
//! * [`cylinder_mesh`]: the open unit cylinder `x² + y² = 1`, 0 ≤ z ≤ 1, normals outwards
//!   (Mitsuba `cylinder` before `p0`/`p1`/`radius`), [`CYLINDER_SEGMENTS_PHI`] sectors with
//!   vertices on the surface and radial vertex normals, uv = (φ/2π, z).
//! * [`recompute_vertex_normals`]: angle-weighted normals (Thürmer & Wüthrich 1998).
//!
//! Conventions: counter-clockwise triangles seen from outside, per-vertex normals and uvs
//! following Mitsuba's parametrisation of each shape (see each function). The Mitsuba XML
//! loader ([`crate::scene::load`]) applies the shape's `to_world` afterwards.
//!
//! Tests: unit tests below (closed, outward-facing, area/volume of sphere and cube; normals of
//! a tent) and `crates/opal/tests/scene_load.rs` (shapes loaded from XML).

use super::TriangleMesh;
use crate::math::{Vec2, Vec3};

/// Number of segments in azimuth φ of a tessellated `sphere`.
pub const SPHERE_SEGMENTS_PHI: usize = 128;
/// Number of segments in polar angle θ of a tessellated `sphere`.
pub const SPHERE_SEGMENTS_THETA: usize = 64;

/// Number of sectors of a tessellated `disk` (the inscribed polygon loses 1 − sin(2π/n)·n/(2π)
/// ≈ 1.0·10⁻⁴ of the area at 256).
pub const DISK_SEGMENTS_PHI: usize = 256;
/// Number of rings of a tessellated `disk` (uv = r is interpolated exactly along the radius).
pub const DISK_SEGMENTS_R: usize = 8;
/// Number of sectors of a tessellated `cylinder` (the polygon is at most r·(1 − cos(π/n)) ≈
/// 7.5·10⁻⁵ r inside the surface at 256; shading normals are the exact radial ones).
pub const CYLINDER_SEGMENTS_PHI: usize = 256;

/// Angle φ_i = 2πi/n as (sin, cos), exact at i = 0 and i = n (the seam).
fn sector(i: usize, n: usize) -> (f64, f64) {
    if i == 0 || i == n { (0.0, 1.0) } else { (2.0 * std::f64::consts::PI * i as f64 / n as f64).sin_cos() }
}

/// Unit disk at z = 0 facing +z (Mitsuba `disk`): `n_phi` sectors × `n_r` rings, vertices on
/// the circle, normal +z, uv = (r, φ/2π) with φ = atan2(y, x) ∈ [0, 2π) as Mitsuba; the seam
/// and the centre are duplicated per sector so that uvs are continuous inside each triangle.
/// Counter-clockwise seen from +z.
pub fn disk_mesh(n_phi: usize, n_r: usize) -> TriangleMesh {
    let mut m = TriangleMesh::default();
    // ring 0 = the centre, duplicated per sector at the sector's middle angle
    for i in 0..n_phi {
        m.positions.push(Vec3::ZERO);
        m.normals.push(Vec3::Z);
        m.uvs.push(Vec2::new(0.0, (i as f32 + 0.5) / n_phi as f32));
    }
    let ring = |k: usize| n_phi + (k - 1) * (n_phi + 1);
    for k in 1..=n_r {
        let r = k as f64 / n_r as f64;
        for i in 0..=n_phi {
            let (sp, cp) = sector(i, n_phi);
            m.positions.push(Vec3::new((r * cp) as f32, (r * sp) as f32, 0.0));
            m.normals.push(Vec3::Z);
            m.uvs.push(Vec2::new(r as f32, i as f32 / n_phi as f32));
        }
    }
    for i in 0..n_phi {
        let r1 = ring(1);
        m.indices.push([i as u32, (r1 + i) as u32, (r1 + i + 1) as u32]);
        for k in 1..n_r {
            let (a, b) = (ring(k), ring(k + 1));
            let (a0, a1, b0, b1) = ((a + i) as u32, (a + i + 1) as u32, (b + i) as u32, (b + i + 1) as u32);
            m.indices.push([a0, b0, b1]);
            m.indices.push([a0, b1, a1]);
        }
    }
    m
}

/// Open unit cylinder `x² + y² = 1`, `0 ≤ z ≤ 1` (Mitsuba `cylinder` in its local frame, no
/// caps): `n_phi` sectors, vertices on the surface, radial vertex normals pointing outwards,
/// uv = (φ/2π, z), seam duplicated. Counter-clockwise seen from outside.
pub fn cylinder_mesh(n_phi: usize) -> TriangleMesh {
    let mut m = TriangleMesh::default();
    for z in [0.0f32, 1.0] {
        for i in 0..=n_phi {
            let (sp, cp) = sector(i, n_phi);
            let n = Vec3::new(cp as f32, sp as f32, 0.0);
            m.positions.push(Vec3::new(n.x, n.y, z));
            m.normals.push(n);
            m.uvs.push(Vec2::new(i as f32 / n_phi as f32, z));
        }
    }
    let top = n_phi + 1;
    for i in 0..n_phi {
        let (a0, a1, b0, b1) = (i as u32, (i + 1) as u32, (top + i) as u32, (top + i + 1) as u32);
        m.indices.push([a0, a1, b1]);
        m.indices.push([a0, b1, b0]);
    }
    m
}

/// Unit square `[-1,1]²` at z = 0 facing +z (Mitsuba `rectangle`), uv = ((x+1)/2, (y+1)/2).
pub fn rectangle_mesh() -> TriangleMesh {
    TriangleMesh {
        positions: vec![
            Vec3::new(-1., -1., 0.),
            Vec3::new(1., -1., 0.),
            Vec3::new(1., 1., 0.),
            Vec3::new(-1., 1., 0.),
        ],
        normals: vec![Vec3::Z; 4],
        uvs: vec![Vec2::new(0., 0.), Vec2::new(1., 0.), Vec2::new(1., 1.), Vec2::new(0., 1.)],
        indices: vec![[0, 1, 2], [0, 2, 3]],
    }
}

/// Cube `[-1,1]³` with outward faces, laid out like Mitsuba's `cube` mesh so that textures
/// land the same way: 24 vertices (4 per face, vertex normal = face normal), 12 triangles
/// `(4f, 4f+1, 4f+2)`, `(4f+3, 4f, 4f+2)`, corner uvs (0,1), (1,1), (1,0), (0,0) per face,
/// faces in the order −y, +y, +x, +z, −x, −z.
pub fn cube_mesh() -> TriangleMesh {
    // (normal, the four corners in order).
    const FACES: [([f32; 3], [[f32; 3]; 4]); 6] = [
        ([0., -1., 0.], [[1., -1., -1.], [1., -1., 1.], [-1., -1., 1.], [-1., -1., -1.]]),
        ([0., 1., 0.], [[1., 1., -1.], [-1., 1., -1.], [-1., 1., 1.], [1., 1., 1.]]),
        ([1., 0., 0.], [[1., -1., -1.], [1., 1., -1.], [1., 1., 1.], [1., -1., 1.]]),
        ([0., 0., 1.], [[1., -1., 1.], [1., 1., 1.], [-1., 1., 1.], [-1., -1., 1.]]),
        ([-1., 0., 0.], [[-1., -1., 1.], [-1., 1., 1.], [-1., 1., -1.], [-1., -1., -1.]]),
        ([0., 0., -1.], [[1., 1., -1.], [1., -1., -1.], [-1., -1., -1.], [-1., 1., -1.]]),
    ];
    const UV: [[f32; 2]; 4] = [[0., 1.], [1., 1.], [1., 0.], [0., 0.]];
    let mut m = TriangleMesh::default();
    for (n, corners) in FACES {
        let b = m.positions.len() as u32;
        for (c, uv) in corners.iter().zip(UV) {
            m.positions.push(Vec3::from(*c));
            m.normals.push(Vec3::from(n));
            m.uvs.push(Vec2::from(uv));
        }
        m.indices.push([b, b + 1, b + 2]);
        m.indices.push([b + 3, b, b + 2]);
    }
    m
}

/// Unit sphere (Mitsuba `sphere` before its center/radius/to_world), tessellated on a
/// `n_phi × n_theta` latitude–longitude grid with vertices **on** the sphere, per-vertex
/// normals = radial direction, uv = (φ/2π, θ/π) with θ measured from +z and φ = atan2(y, x)
/// (Mitsuba's analytic sphere parametrisation); seam vertices duplicated, one triangle per
/// cell at the poles. Outward facing (CCW seen from outside).
pub fn sphere_mesh(n_phi: usize, n_theta: usize) -> TriangleMesh {
    let mut m = TriangleMesh::default();
    for j in 0..=n_theta {
        let theta = std::f64::consts::PI * j as f64 / n_theta as f64;
        let (st, ct) = if j == 0 {
            (0.0, 1.0)
        } else if j == n_theta {
            (0.0, -1.0)
        } else {
            theta.sin_cos()
        };
        for i in 0..=n_phi {
            let phi = 2.0 * std::f64::consts::PI * i as f64 / n_phi as f64;
            let (sp, cp) = if i == n_phi { (0.0, 1.0) } else { phi.sin_cos() };
            let p = Vec3::new((st * cp) as f32, (st * sp) as f32, ct as f32);
            m.positions.push(p);
            m.normals.push(p);
            m.uvs.push(Vec2::new(i as f32 / n_phi as f32, j as f32 / n_theta as f32));
        }
    }
    let idx = |j: usize, i: usize| (j * (n_phi + 1) + i) as u32;
    for j in 0..n_theta {
        for i in 0..n_phi {
            let (a, b, c, d) = (idx(j, i), idx(j, i + 1), idx(j + 1, i + 1), idx(j + 1, i));
            if j + 1 < n_theta {
                m.indices.push([a, d, c]);
            }
            if j > 0 {
                m.indices.push([a, c, b]);
            }
        }
    }
    m
}

/// Angle-weighted vertex normals (Thürmer & Wüthrich 1998), as Mitsuba recomputes them for
/// meshes without normals when `face_normals` is false.
pub fn recompute_vertex_normals(m: &mut TriangleMesh) {
    let mut acc = vec![Vec3::ZERO; m.positions.len()];
    for t in &m.indices {
        let v = t.map(|i| m.positions[i as usize]);
        let n = (v[1] - v[0]).cross(v[2] - v[0]).normalize();
        for j in 0..3 {
            let d0 = (v[(j + 1) % 3] - v[j]).normalize();
            let d1 = (v[(j + 2) % 3] - v[j]).normalize();
            let angle = d0.dot(d1).clamp(-1.0, 1.0).acos();
            if n.is_finite() && angle.is_finite() {
                acc[t[j] as usize] += n * angle;
            }
        }
    }
    m.normals = acc.into_iter().map(|n| n.try_normalize().unwrap_or(Vec3::X)).collect();
}

/// Unit icosphere: an icosahedron subdivided `levels` times (20 · 4^levels triangles, each
/// edge midpoint pushed onto the sphere), counter-clockwise seen from outside; no normals or UVs.
pub fn icosphere(levels: usize) -> TriangleMesh {
    let g = (1.0 + 5f32.sqrt()) / 2.0;
    let mut pos: Vec<Vec3> = [
        (-1.0, g, 0.0),
        (1.0, g, 0.0),
        (-1.0, -g, 0.0),
        (1.0, -g, 0.0),
        (0.0, -1.0, g),
        (0.0, 1.0, g),
        (0.0, -1.0, -g),
        (0.0, 1.0, -g),
        (g, 0.0, -1.0),
        (g, 0.0, 1.0),
        (-g, 0.0, -1.0),
        (-g, 0.0, 1.0),
    ]
    .iter()
    .map(|&(x, y, z)| Vec3::new(x, y, z).normalize())
    .collect();
    let mut tris: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..levels {
        let mut mid: std::collections::HashMap<(u32, u32), u32> = std::collections::HashMap::new();
        let mut midpoint = |a: u32, b: u32, pos: &mut Vec<Vec3>| {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                pos.push(((pos[a as usize] + pos[b as usize]) * 0.5).normalize());
                (pos.len() - 1) as u32
            })
        };
        let mut next = Vec::with_capacity(tris.len() * 4);
        for [a, b, c] in tris {
            let ab = midpoint(a, b, &mut pos);
            let bc = midpoint(b, c, &mut pos);
            let ca = midpoint(c, a, &mut pos);
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        tris = next;
    }
    TriangleMesh { positions: pos, indices: tris, ..Default::default() }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn disk_and_cylinder_tessellations() {
        let area = |m: &TriangleMesh| -> (f64, Vec3) {
            let (mut a, mut n) = (0.0, Vec3::ZERO);
            for t in &m.indices {
                let v = t.map(|i| m.positions[i as usize]);
                let c = (v[1] - v[0]).cross(v[2] - v[0]);
                a += 0.5 * c.length() as f64;
                n += c;
            }
            (a, n)
        };
        let d = disk_mesh(DISK_SEGMENTS_PHI, DISK_SEGMENTS_R);
        let (a, n) = area(&d);
        assert!((a - std::f64::consts::PI).abs() < 2e-4 * std::f64::consts::PI, "disk area {a}");
        assert!(n.z > 0.0 && n.x.abs() < 1e-3 && n.y.abs() < 1e-3, "faces +z");
        // uv = (r, φ/2π) at every vertex (the centre's v is free)
        for (p, uv) in d.positions.iter().zip(&d.uvs) {
            let r = (p.x * p.x + p.y * p.y).sqrt();
            assert!((uv.x - r).abs() < 1e-6);
            if r > 0.0 {
                let mut phi = p.y.atan2(p.x) / (2.0 * std::f32::consts::PI);
                if phi < 0.0 {
                    phi += 1.0;
                }
                assert!(
                    (uv.y - phi).abs() < 1e-5 || (uv.y - 1.0).abs() < 1e-6 && phi.abs() < 1e-6,
                    "{p} {uv}"
                );
            }
        }
        let c = cylinder_mesh(CYLINDER_SEGMENTS_PHI);
        let (a, _) = area(&c);
        assert!(
            (a - 2.0 * std::f64::consts::PI).abs() < 2e-4 * 2.0 * std::f64::consts::PI,
            "cylinder area {a}"
        );
        for t in &c.indices {
            let v = t.map(|i| c.positions[i as usize]);
            let nf = (v[1] - v[0]).cross(v[2] - v[0]);
            let centre = (v[0] + v[1] + v[2]) / 3.0;
            assert!(nf.dot(Vec3::new(centre.x, centre.y, 0.0)) > 0.0, "outward");
        }
        for ((p, n), uv) in c.positions.iter().zip(&c.normals).zip(&c.uvs) {
            assert!((n.length() - 1.0).abs() < 1e-6 && (n.x - p.x).abs() < 1e-6 && (uv.y - p.z).abs() < 1e-6);
        }
    }

    #[test]
    fn sphere_tessellation_is_closed_outward_and_close_to_the_sphere() {
        let m = sphere_mesh(SPHERE_SEGMENTS_PHI, SPHERE_SEGMENTS_THETA);
        assert_eq!(m.indices.len(), 2 * SPHERE_SEGMENTS_PHI * (SPHERE_SEGMENTS_THETA - 1));
        // Inscribed polyhedron: area slightly below 4π. For 128×64 the deficit is 0.050 %
        // (second-order in the angular step, computed independently in f64); bound 0.1 %.
        let a = m.area();
        let rel = (4.0 * std::f64::consts::PI - a) / (4.0 * std::f64::consts::PI);
        assert!(rel > 4e-4 && rel < 1e-3, "relative area deficit {rel}");
        // Every triangle faces outward and is non-degenerate.
        for i in 0..m.triangle_count() {
            let [a, b, c] = m.triangle(i);
            let n = (b - a).cross(c - a);
            assert!(n.length() > 0.0);
            assert!(n.dot(a + b + c) > 0.0, "triangle {i} faces inward");
        }
        // Divergence theorem: volume = Σ (a · (b × c)) / 6, slightly below 4π/3.
        let vol: f64 = (0..m.triangle_count())
            .map(|i| {
                let [a, b, c] = m.triangle(i);
                a.as_dvec3().dot(b.as_dvec3().cross(c.as_dvec3())) / 6.0
            })
            .sum();
        let rel_v = 1.0 - vol / (4.0 / 3.0 * std::f64::consts::PI);
        // Volume deficit 0.100 % (f64 computation of the same polyhedron).
        assert!(rel_v > 8e-4 && rel_v < 1.2e-3, "volume deficit {rel_v}");
    }

    #[test]
    fn cube_is_closed_and_outward() {
        let m = cube_mesh();
        assert_eq!(m.indices.len(), 12);
        assert!((m.area() - 24.0).abs() < 1e-6);
        let vol: f32 = (0..12)
            .map(|i| {
                let [a, b, c] = m.triangle(i);
                a.dot(b.cross(c)) / 6.0
            })
            .sum();
        assert!((vol - 8.0).abs() < 1e-5);
        for i in 0..12 {
            let [a, b, c] = m.triangle(i);
            let n = (b - a).cross(c - a).normalize();
            assert!((n - m.normals[m.indices[i][0] as usize]).length() < 1e-6);
        }
    }

    #[test]
    fn angle_weighted_normals_of_a_tent() {
        // Two triangles meeting at 90°: the shared-edge vertices get the bisector.
        let mut m = TriangleMesh {
            positions: vec![
                Vec3::new(0., 0., 0.),
                Vec3::new(0., 1., 0.),
                Vec3::new(1., 0., 0.),
                Vec3::new(0., 0., 1.),
            ],
            indices: vec![[0, 2, 1], [0, 1, 3]],
            ..Default::default()
        };
        recompute_vertex_normals(&mut m);
        let s = std::f32::consts::FRAC_1_SQRT_2;
        // Face normals +z (0,2,1) and +x (0,1,3); right angles at vertex 0, 45° at vertex 1.
        assert!((m.normals[0] - Vec3::new(s, 0.0, s)).length() < 1e-6, "{:?}", m.normals[0]);
        assert!((m.normals[1] - Vec3::new(s, 0.0, s)).length() < 1e-6, "{:?}", m.normals[1]);
        assert!((m.normals[2] - Vec3::Z).length() < 1e-6);
        assert!((m.normals[3] - Vec3::X).length() < 1e-6);
    }
}
