//! Integrators: functions over a built [`Scene`](crate::scene::Scene).
//!
//! * [`path`]: unidirectional path tracer with next-event estimation and MIS (images).

pub mod path;

use crate::geometry::Ray;
use crate::math::Vec3;

/// Power heuristic (β = 2) weight of a strategy with density `a` against one with density `b`.
#[inline]
pub fn mis_power(a: f32, b: f32) -> f32 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 && a2.is_finite() {
        a2 / (a2 + b2)
    } else if a2.is_infinite() {
        1.0
    } else {
        0.0
    }
}

/// Pushes a surface point off the surface along the geometric normal towards the side of `w`,
/// by an amount proportional to the magnitude of the coordinates (f32 rounding of the hit point).
#[inline]
pub fn offset_origin(p: Vec3, ng: Vec3, w: Vec3) -> Vec3 {
    let eps = (1.0 + p.abs().max_element()) * 1e-5;
    if w.dot(ng) >= 0.0 { p + ng * eps } else { p - ng * eps }
}

/// Ray leaving surface point `p` (geometric normal `ng`) in direction `d`.
#[inline]
pub fn spawn_ray(p: Vec3, ng: Vec3, d: Vec3) -> Ray {
    Ray::new(offset_origin(p, ng, d), d)
}

/// Shadow ray from surface point `p` (normal `ng`) to point `q` (normal `nq`, zero for points
/// not on a surface); it stops just short of `q`.
#[inline]
pub fn spawn_ray_to(p: Vec3, ng: Vec3, q: Vec3, nq: Vec3) -> Ray {
    let d0 = q - p;
    let o = offset_origin(p, ng, d0);
    let q2 = if nq == Vec3::ZERO { q } else { offset_origin(q, nq, o - q) };
    let d = q2 - o;
    let len = d.length();
    Ray { o, d: d / len, tmax: len * (1.0 - 1e-4) }
}
