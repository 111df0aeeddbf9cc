//! Deterministic triangle sets for tests and benchmarks of the acceleration structures: a
//! (displaced) tessellated sphere with shared vertices (closed, so watertightness can be
//! tested), random triangle soups, and the Cornell box of the reference scenes
//! (`cbox/meshes/*.obj`: walls, light and the two boxes, 32 triangles, written out here so
//! nothing depends on files outside the repository).
//!
//! Everything is generated from [`Rng`] with a fixed seed: same arguments, same triangles.

// Coordinates are copied verbatim from the reference OBJ files.
#![allow(clippy::excessive_precision)]

use crate::geometry::TriangleMesh;
use crate::math::Vec3;
use crate::sampling::Rng;

/// Closed UV sphere around the origin: `n_theta ≥ 2` bands between the poles, `n_phi ≥ 3`
/// segments around; `2 · n_phi · (n_theta − 1)` triangles, counter-clockwise seen from outside.
/// Each vertex radius is `1 + displacement · (2u − 1)` with `u` uniform from `(seed, vertex)`
/// (`displacement = 0`: a convex polyhedron inscribed in the unit sphere).
pub fn sphere_mesh(n_theta: usize, n_phi: usize, displacement: f32, seed: u64) -> TriangleMesh {
    assert!(n_theta >= 2 && n_phi >= 3, "sphere_mesh needs n_theta >= 2, n_phi >= 3");
    let radius = |i: usize| {
        if displacement == 0.0 {
            1.0
        } else {
            1.0 + displacement * (2.0 * Rng::new(seed, 0, i as u64).next_f32() - 1.0)
        }
    };
    let mut positions = vec![Vec3::Z * radius(0)];
    for it in 1..n_theta {
        let theta = std::f32::consts::PI * it as f32 / n_theta as f32;
        for ip in 0..n_phi {
            let phi = 2.0 * std::f32::consts::PI * ip as f32 / n_phi as f32;
            let r = radius(positions.len());
            positions.push(crate::math::spherical_direction(theta, phi) * r);
        }
    }
    let south = positions.len() as u32;
    positions.push(-Vec3::Z * radius(south as usize));
    let ring = |it: usize, ip: usize| (1 + (it - 1) * n_phi + ip % n_phi) as u32;
    let mut indices = Vec::with_capacity(2 * n_phi * (n_theta - 1));
    for ip in 0..n_phi {
        indices.push([0, ring(1, ip), ring(1, ip + 1)]);
    }
    for it in 1..n_theta - 1 {
        for ip in 0..n_phi {
            let (a, b, c, d) = (ring(it, ip), ring(it + 1, ip), ring(it + 1, ip + 1), ring(it, ip + 1));
            indices.push([a, b, c]);
            indices.push([a, c, d]);
        }
    }
    for ip in 0..n_phi {
        indices.push([south, ring(n_theta - 1, ip + 1), ring(n_theta - 1, ip)]);
    }
    TriangleMesh { positions, indices, ..Default::default() }
}

/// The triangles of a mesh as a soup, in index order.
pub fn mesh_triangles(mesh: &TriangleMesh) -> Vec<[Vec3; 3]> {
    (0..mesh.triangle_count()).map(|i| mesh.triangle(i)).collect()
}

/// `n` random triangles in the cube `[-1, 1]³`: a random centre and corners displaced from it by
/// up to `size` on each axis (`seed` selects the set).
pub fn random_soup(n: usize, size: f32, seed: u64) -> Vec<[Vec3; 3]> {
    (0..n)
        .map(|i| {
            let mut rng = Rng::new(seed, 1, i as u64);
            let mut u = || rng.next_f32() * 2.0 - 1.0;
            let c = Vec3::new(u(), u(), u());
            let mut corner = || c + Vec3::new(u(), u(), u()) * size;
            [corner(), corner(), corner()]
        })
        .collect()
}

/// The Cornell box of the reference scenes (32 triangles in `[-1, 1]³`, camera looking along −z):
/// floor, ceiling, back, left and right walls, the light (just below the ceiling), the short and
/// the tall box. Quads are split as `(0,1,2), (0,2,3)`, counter-clockwise seen from the front.
pub fn cornell_box() -> Vec<[Vec3; 3]> {
    let v = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
    let mut quads: Vec<[Vec3; 4]> = vec![
        [v(-1., -1., -1.), v(1., -1., -1.), v(1., 1., -1.), v(-1., 1., -1.)], // back
        [v(-1., 1., -1.), v(1., 1., -1.), v(1., 1., 1.), v(-1., 1., 1.)],     // ceiling
        [v(-1., -1., 1.), v(1., -1., 1.), v(1., -1., -1.), v(-1., -1., -1.)], // floor
        [v(-1., -1., 1.), v(-1., -1., -1.), v(-1., 1., -1.), v(-1., 1., 1.)], // left
        [v(-0.23, 0.99, -0.18), v(0.23, 0.99, -0.18), v(0.23, 0.99, 0.2), v(-0.23, 0.99, 0.2)], // light
        [v(1., -1., -1.), v(1., -1., 1.), v(1., 1., 1.), v(1., 1., -1.)],     // right
    ];
    // The boxes: four sides and a top each, from their footprint corners and height.
    let boxes: [([[f32; 2]; 4], f32); 2] = [
        (
            [
                [0.534179915, 0.754602938],
                [0.709602938, 0.180820085],
                [0.135820085, 0.00539706179],
                [-0.0396029382, 0.579179915],
            ],
            -0.4,
        ),
        (
            [
                [0.0488588798, -0.0890394041],
                [-0.139039404, -0.65885888],
                [-0.70885888, -0.470960596],
                [-0.520960596, 0.0988588798],
            ],
            0.2,
        ),
    ];
    for (f, top) in boxes {
        for k in 0..4 {
            let (a, b) = (f[k], f[(k + 1) % 4]);
            quads.push([v(a[0], -1., a[1]), v(b[0], -1., b[1]), v(b[0], top, b[1]), v(a[0], top, a[1])]);
        }
        quads.push([
            v(f[3][0], top, f[3][1]),
            v(f[0][0], top, f[0][1]),
            v(f[1][0], top, f[1][1]),
            v(f[2][0], top, f[2][1]),
        ]);
    }
    quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sphere_is_closed_and_oriented() {
        let m = sphere_mesh(5, 7, 0.0, 1);
        assert_eq!(m.triangle_count(), 2 * 7 * 4);
        // Every directed edge appears once and its reverse once: closed, consistently oriented.
        let mut edges = std::collections::HashMap::new();
        for t in &m.indices {
            for k in 0..3 {
                *edges.entry((t[k], t[(k + 1) % 3])).or_insert(0) += 1;
            }
        }
        for (&(a, b), &c) in &edges {
            assert_eq!(c, 1);
            assert_eq!(edges.get(&(b, a)), Some(&1));
        }
        // Outward normals.
        for i in 0..m.triangle_count() {
            let [a, b, c] = m.triangle(i);
            assert!((b - a).cross(c - a).dot(a + b + c) > 0.0);
        }
        // Area tends to 4π.
        let fine = sphere_mesh(200, 400, 0.0, 1);
        assert!((fine.area() - 4.0 * std::f64::consts::PI).abs() < 1e-3 * 4.0 * std::f64::consts::PI);
    }

    #[test]
    fn cornell_box_matches_reference_layout() {
        let t = cornell_box();
        assert_eq!(t.len(), 32);
        let area: f32 = t.iter().map(|t| 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length()).sum();
        // 5 walls of 4, light 0.46·0.38, short box 4 sides 0.6 high + top, tall box 1.2 high + top.
        let side = |a: [f32; 2], b: [f32; 2]| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt();
        let s = side([0.534179915, 0.754602938], [0.709602938, 0.180820085]);
        let s2 = side([0.0488588798, -0.0890394041], [-0.139039404, -0.65885888]);
        let s3 = side([-0.139039404, -0.65885888], [-0.70885888, -0.470960596]);
        let expect = 20.0 + 0.46 * 0.38 + (4.0 * 0.6 * s + s * s) + (2.0 * 1.2 * (s2 + s3) + s2 * s3);
        assert!((area - expect).abs() < 1e-3, "{area} vs {expect}");
    }
}
