//! Ray–triangle acceleration: closest-hit and any-hit queries over a triangle soup.
//!
//! * [`triangle`]: the watertight ray–triangle test (Woop et al. 2013) every structure uses, and
//!   robust ray spawning ([`offset_ray_origin`], [`spawn_ray`], [`spawn_ray_to`]).
//! * [`Bvh`]: the acceleration structure the engine uses (binned SAH BVH, see [`bvh`]).
//! * [`TinyAccel`]: every triangle tested eight at a time (SIMD), for scenes of at most
//!   [`tiny::TINY_MAX`] triangles (see [`tiny`]).
//! * [`packet::PacketAccel`]: eight rays at once (one per SIMD lane) against a tiny soup, for
//!   callers with independent rays at hand (the light tracer's wavefront); same hits.
//! * [`scenes`]: deterministic meshes and soups for tests and benchmarks.
//! * [`BruteForce`] tests every triangle; it is the reference the BVH is tested against.

pub mod bvh;
pub(crate) mod group;
pub mod packet;
pub mod scenes;
pub mod tiny;
pub mod triangle;

pub use bvh::Bvh;
pub use tiny::TinyAccel;
pub use triangle::{TriRay, intersect_triangle, offset_ray_origin, spawn_ray, spawn_ray_to};

use crate::geometry::Ray;
use crate::math::Vec3;

/// A ray–triangle hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Ray parameter.
    pub t: f32,
    /// Index of the triangle in the soup given at build time.
    pub prim: u32,
    /// Barycentric coordinate of the second corner.
    pub b1: f32,
    /// Barycentric coordinate of the third corner.
    pub b2: f32,
}

/// Möller–Trumbore ray–triangle test (not watertight; kept as a reference, the engine uses
/// [`intersect_triangle`]).
pub fn intersect_triangle_mt(ray: &Ray, tri: &[Vec3; 3], tmax: f32) -> Option<(f32, f32, f32)> {
    let e1 = tri[1] - tri[0];
    let e2 = tri[2] - tri[0];
    let p = ray.d.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 {
        return None;
    }
    let inv = 1.0 / det;
    let s = ray.o - tri[0];
    let b1 = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&b1) {
        return None;
    }
    let q = s.cross(e1);
    let b2 = ray.d.dot(q) * inv;
    if b2 < 0.0 || b1 + b2 > 1.0 {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t > 0.0 && t < tmax).then_some((t, b1, b2))
}

/// Tests every triangle: O(n) per ray. The reference for BVH tests.
#[derive(Clone, Debug)]
pub struct BruteForce {
    tris: Vec<[Vec3; 3]>,
}

impl BruteForce {
    /// Wraps a triangle soup.
    pub fn new(tris: Vec<[Vec3; 3]>) -> Self {
        BruteForce { tris }
    }
    /// Closest hit with `0 < t < ray.tmax` (watertight test, see [`triangle`]).
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut tmax = ray.tmax;
        let tr = TriRay::new(ray);
        for (i, tri) in self.tris.iter().enumerate() {
            if let Some((t, b1, b2)) = tr.intersect(tri, tmax) {
                tmax = t;
                best = Some(Hit { t, prim: i as u32, b1, b2 });
            }
        }
        best
    }
    /// Whether anything is hit with `0 < t < ray.tmax`.
    pub fn occluded(&self, ray: &Ray) -> bool {
        let tr = TriRay::new(ray);
        self.tris.iter().any(|tri| tr.intersect(tri, ray.tmax).is_some())
    }
    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.tris.len()
    }
    /// Whether there are no triangles.
    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }
}
