//! Geometry: rays and triangle meshes (the only primitive the engine intersects; Mitsuba's
//! analytic shapes are tessellated at load time by [`shapes`], see docs/scene-format.md).

pub mod obj;
pub mod ply;
pub mod shapes;

use crate::math::{Vec2, Vec3};

/// A ray `o + t d`, `t ∈ (0, tmax)`. `d` need not be normalised for intersection, but the
/// integrators keep it unit length.
#[derive(Clone, Copy, Debug)]
pub struct Ray {
    /// Origin.
    pub o: Vec3,
    /// Direction.
    pub d: Vec3,
    /// Largest parameter considered.
    pub tmax: f32,
}

impl Ray {
    /// Ray with unbounded `tmax`.
    pub fn new(o: Vec3, d: Vec3) -> Self {
        Ray { o, d, tmax: f32::INFINITY }
    }
    /// Point at parameter `t`.
    pub fn at(&self, t: f32) -> Vec3 {
        self.o + self.d * t
    }
}

/// Indexed triangle mesh in world space. Normals and UVs are per vertex when present.
#[derive(Clone, Debug, Default)]
pub struct TriangleMesh {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Per-vertex shading normals (same length as `positions`) or empty.
    pub normals: Vec<Vec3>,
    /// Per-vertex texture coordinates (same length as `positions`) or empty. Mitsuba's
    /// convention: v = 0 at the *top* row of an image (OBJ files are flipped on load).
    pub uvs: Vec<Vec2>,
    /// Triangles as vertex indices, counter-clockwise seen from the front.
    pub indices: Vec<[u32; 3]>,
}

impl TriangleMesh {
    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len()
    }
    /// Corner positions of triangle `i`.
    pub fn triangle(&self, i: usize) -> [Vec3; 3] {
        let [a, b, c] = self.indices[i];
        [self.positions[a as usize], self.positions[b as usize], self.positions[c as usize]]
    }
    /// Area of triangle `i`.
    pub fn triangle_area(&self, i: usize) -> f32 {
        let [a, b, c] = self.triangle(i);
        0.5 * (b - a).cross(c - a).length()
    }
    /// Total surface area.
    pub fn area(&self) -> f64 {
        (0..self.triangle_count()).map(|i| self.triangle_area(i) as f64).sum()
    }
}
