//! Ray–triangle acceleration: closest-hit and any-hit queries over a triangle soup.
//!
//! * [`Accel`]: **the one intersection API** every caller uses (the path tracer, the light
//!   tracer, de-lighting's projection and visibility, through [`crate::scene::Scene`]):
//!   `intersect` (closest hit), `occluded` (any hit, no barycentrics) and `intersect8` (a
//!   [`packet::RayPacket`] of eight rays). An enum over the implementations below, chosen once
//!   when the scene is built.
//! * [`triangle`]: the watertight ray–triangle test (Woop et al. 2013) every structure uses, and
//!   robust ray spawning ([`offset_ray_origin`], [`spawn_ray`], [`spawn_ray_to`]).
//! * [`Bvh`]: the 8-wide BVH for every scene size (binned SAH, leaves of eight triangles tested
//!   at once, AVX2 traversal; see [`bvh`]).
//! * [`SplitAccel`]: a few large triangles (a room's walls) apart in the packet kernel, the
//!   rest behind a [`Bvh`] entered only by the rays that reach it (see [`split`]).
//! * [`TinyAccel`] + [`packet::PacketAccel`]: scenes of at most [`tiny::TINY_MAX`] triangles,
//!   every triangle tested eight at a time, or eight rays at once (one per SIMD lane) — kept
//!   because it is measurably faster than the BVH there (`examples/accel_compare.rs`,
//!   `docs/decisions/tiny-accel.md`); same hits.
//! * [`scenes`]: deterministic meshes and soups for tests and benchmarks.
//! * [`BruteForce`] tests every triangle; it is the reference the BVH is tested against.

pub mod bvh;
pub(crate) mod group;
pub mod packet;
pub mod scenes;
pub mod split;
pub mod tiny;
pub mod triangle;

pub use bvh::Bvh;
pub use split::SplitAccel;
pub use tiny::TinyAccel;
pub use triangle::{TriRay, intersect_triangle, offset_ray_origin, spawn_ray, spawn_ray_to};

use crate::geometry::Ray;
use crate::math::Vec3;
use packet::{PacketAccel, PacketHits, RayPacket};

/// The intersection API over the implementations (see the module docs).
#[derive(Clone, Debug)]
pub enum Accel {
    /// At most [`tiny::TINY_MAX`] triangles: all tested, eight at a time (single rays) or eight
    /// rays at once (packets).
    Tiny {
        /// Single rays.
        single: TinyAccel,
        /// Packets.
        packet: PacketAccel,
    },
    /// Any size: the 8-wide BVH.
    Bvh(Bvh),
    /// A few large triangles apart (packet tests) and the rest behind a BVH: scenes such as
    /// an object in a room ([`split`]).
    Split(SplitAccel),
}

impl Accel {
    /// The structure for `tris`: [`Accel::Tiny`] up to [`tiny::TINY_MAX`] triangles, else
    /// [`Accel::Split`] when [`SplitAccel::choose`] sets large triangles apart, else the
    /// [`Bvh`].
    pub fn new(tris: Vec<[Vec3; 3]>) -> Accel {
        if tris.len() <= tiny::TINY_MAX {
            return Accel::Tiny { single: TinyAccel::new(tris.clone()), packet: PacketAccel::new(tris) };
        }
        let big = SplitAccel::choose(&tris);
        if big.is_empty() { Accel::Bvh(Bvh::new(tris)) } else { Accel::Split(SplitAccel::new(&tris, &big)) }
    }

    /// The BVH whatever the size (for tests and comparisons).
    pub fn bvh(tris: Vec<[Vec3; 3]>) -> Accel {
        Accel::Bvh(Bvh::new(tris))
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        match self {
            Accel::Tiny { single, .. } => single.len(),
            Accel::Bvh(b) => b.len(),
            Accel::Split(s) => s.len(),
        }
    }

    /// Whether there are no triangles.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Closest hit with `0 < t < ray.tmax`.
    #[inline]
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        match self {
            Accel::Tiny { single, .. } => single.intersect(ray),
            Accel::Bvh(b) => b.intersect(ray),
            Accel::Split(s) => s.intersect(ray),
        }
    }

    /// Whether any triangle is hit with `0 < t < ray.tmax`.
    #[inline]
    pub fn occluded(&self, ray: &Ray) -> bool {
        match self {
            Accel::Tiny { single, .. } => single.occluded(ray),
            Accel::Bvh(b) => b.occluded(ray),
            Accel::Split(s) => s.occluded(ray),
        }
    }

    /// Closest hits of the eight rays of a packet (lanes with `tmax ≤ 0` are inactive and
    /// miss); the same hits as [`Accel::intersect`] lane by lane.
    #[inline]
    pub fn intersect8(&self, rays: &RayPacket) -> PacketHits {
        match self {
            Accel::Tiny { packet, .. } => packet.intersect_lanes(rays),
            Accel::Bvh(b) => b.intersect8(rays),
            Accel::Split(s) => s.intersect8(rays),
        }
    }

    /// [`Accel::intersect8`] of several packets (`hits[j]` for `rays[j]`), the same hits; the
    /// split structure gathers the rays that enter its BVH from all packets into full streams
    /// ([`SplitAccel::intersect8_many`]).
    #[inline]
    pub fn intersect8_many(&self, rays: &[RayPacket], hits: &mut [PacketHits]) {
        match self {
            Accel::Split(s) => s.intersect8_many(rays, hits),
            _ => {
                for (r, h) in rays.iter().zip(hits.iter_mut()) {
                    *h = if r.any_active() { self.intersect8(r) } else { PacketHits::NONE };
                }
            }
        }
    }

    /// [`Accel::occluded8`] of several packets (`blocked[j]` for `rays[j]`), the same masks
    /// ([`SplitAccel::occluded8_many`]).
    #[inline]
    pub fn occluded8_many(&self, rays: &[RayPacket], blocked: &mut [u32]) {
        match self {
            Accel::Split(s) => s.occluded8_many(rays, blocked),
            _ => {
                for (r, b) in rays.iter().zip(blocked.iter_mut()) {
                    *b = if r.any_active() { self.occluded8(r) } else { 0 };
                }
            }
        }
    }

    /// Which of the eight rays of a packet are blocked before `tmax` (bit `l` = lane `l`;
    /// lanes with `tmax ≤ 0` are inactive, bit clear): [`Accel::occluded`] per lane. The BVH
    /// stops each lane's traversal at its first hit, the tiny structure its triangle loop once
    /// every lane has one.
    pub fn occluded8(&self, rays: &RayPacket) -> u32 {
        match self {
            Accel::Tiny { packet, .. } => packet.occluded_lanes(rays),
            Accel::Bvh(b) => b.occluded8(rays),
            Accel::Split(s) => s.occluded8(rays),
        }
    }
}

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
