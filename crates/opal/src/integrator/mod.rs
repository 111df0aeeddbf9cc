//! Integrators: functions over a built [`Scene`](crate::scene::Scene).
//!
//! * [`path`]: unidirectional path tracer with next-event estimation and MIS (images).
//! * [`light_tracer`]: light tracing that deposits irradiance into per-shape texture maps.

pub mod light_tracer;
pub mod path;

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

pub use crate::accel::{offset_ray_origin, spawn_ray, spawn_ray_to};
