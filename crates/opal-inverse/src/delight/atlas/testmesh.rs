//! A curved test mesh made by construction: a displaced icosphere (an icosahedron subdivided
//! `levels` times, 20 · 4^levels triangles, vertices moved radially by `1 + amplitude · f(p)`
//! with `f` a smooth sum of sines in [−1, 1]), like a scanned rock. Used by the atlas tests and
//! the `unwrap_stats` example.

use opal::geometry::TriangleMesh;
use opal::math::Vec3;

/// Displaced icosphere (see the module docs), counter-clockwise seen from outside, no normals
/// or UVs.
pub fn displaced_icosphere(levels: usize, amplitude: f32) -> TriangleMesh {
    // the unit icosphere (its midpoints `((a + b) / 2).normalize()` equal `(a + b).normalize()`
    // bit for bit: scaling by ½ is exact through the length and the division)
    let TriangleMesh { positions: p, indices: tris, .. } = opal::geometry::shapes::icosphere(levels);
    let f = |d: Vec3| {
        let a = (3.1 * d.x + 1.0).sin() * (4.3 * d.y + 2.0).sin() * (5.2 * d.z + 0.5).sin();
        let b = (7.0 * d.x - 5.0 * d.y + 3.0 * d.z).sin() * (6.0 * d.z + 4.0 * d.x).cos();
        let c = (13.0 * d.y + 11.0 * d.z - 9.0 * d.x).sin();
        0.5 * a + 0.3 * b + 0.2 * c
    };
    TriangleMesh {
        positions: p.iter().map(|&d| d * (1.0 + amplitude * f(d))).collect(),
        indices: tris,
        ..Default::default()
    }
}
