//! A curved test mesh made by construction: a displaced icosphere (an icosahedron subdivided
//! `levels` times, 20 · 4^levels triangles, vertices moved radially by `1 + amplitude · f(p)`
//! with `f` a smooth sum of sines in [−1, 1]), like a scanned rock. Used by the atlas tests and
//! the `unwrap_stats` example.

use opal::geometry::TriangleMesh;
use opal::math::Vec3;
use std::collections::HashMap;

/// Displaced icosphere (see the module docs), counter-clockwise seen from outside, no normals
/// or UVs.
pub fn displaced_icosphere(levels: usize, amplitude: f32) -> TriangleMesh {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let mut p: Vec<Vec3> = [
        (-1.0, t, 0.0),
        (1.0, t, 0.0),
        (-1.0, -t, 0.0),
        (1.0, -t, 0.0),
        (0.0, -1.0, t),
        (0.0, 1.0, t),
        (0.0, -1.0, -t),
        (0.0, 1.0, -t),
        (t, 0.0, -1.0),
        (t, 0.0, 1.0),
        (-t, 0.0, -1.0),
        (-t, 0.0, 1.0),
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
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut next = Vec::with_capacity(tris.len() * 4);
        for t in &tris {
            let m: [u32; 3] = std::array::from_fn(|e| {
                let (a, b) = (t[e], t[(e + 1) % 3]);
                *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                    p.push((p[a as usize] + p[b as usize]).normalize());
                    (p.len() - 1) as u32
                })
            });
            next.extend([[t[0], m[0], m[2]], [t[1], m[1], m[0]], [t[2], m[2], m[1]], [m[0], m[1], m[2]]]);
        }
        tris = next;
    }
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
