//! Warping functions from the unit square to directions / points, each with its pdf
//! (solid angle for directions, area for points).

use crate::math::{INV_2PI, INV_4PI, INV_PI, PI, Vec2, Vec3};

/// Uniform disk by Shirley's concentric map.
///
/// The angle is taken in turns, `θ/2π = (y/x)/8` or `1/4 − (x/y)/8`, and its sine and cosine
/// come from [`crate::fastmath::sincos_2pi`] (absolute error < 3·10⁻⁷, no libm call; the
/// light tracer's 8-lane version computes the same bits).
#[inline]
pub fn square_to_uniform_disk_concentric(u: Vec2) -> Vec2 {
    let o = 2.0 * u - Vec2::ONE;
    if o.x == 0.0 && o.y == 0.0 {
        return Vec2::ZERO;
    }
    let (r, turns) =
        if o.x.abs() > o.y.abs() { (o.x, (o.y / o.x) * 0.125) } else { (o.y, 0.25 - (o.x / o.y) * 0.125) };
    let (s, c) = crate::fastmath::sincos_2pi(turns);
    Vec2::new(r * c, r * s)
}

/// Cosine-weighted hemisphere around +z (Malley's method).
#[inline]
pub fn square_to_cosine_hemisphere(u: Vec2) -> Vec3 {
    let d = square_to_uniform_disk_concentric(u);
    let z = (1.0 - d.length_squared()).max(0.0).sqrt();
    Vec3::new(d.x, d.y, z)
}
/// pdf of [`square_to_cosine_hemisphere`]: cos θ / π on the upper hemisphere.
#[inline]
pub fn square_to_cosine_hemisphere_pdf(w: Vec3) -> f32 {
    if w.z > 0.0 { w.z * INV_PI } else { 0.0 }
}

/// Uniform sphere.
#[inline]
pub fn square_to_uniform_sphere(u: Vec2) -> Vec3 {
    let z = 1.0 - 2.0 * u.y;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let (s, c) = (2.0 * PI * u.x).sin_cos();
    Vec3::new(r * c, r * s, z)
}
/// pdf of [`square_to_uniform_sphere`]: 1/(4π).
#[inline]
pub fn square_to_uniform_sphere_pdf(_w: Vec3) -> f32 {
    INV_4PI
}

/// Uniform hemisphere around +z.
#[inline]
pub fn square_to_uniform_hemisphere(u: Vec2) -> Vec3 {
    let z = u.y;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let (s, c) = (2.0 * PI * u.x).sin_cos();
    Vec3::new(r * c, r * s, z)
}
/// pdf of [`square_to_uniform_hemisphere`]: 1/(2π) for z > 0.
#[inline]
pub fn square_to_uniform_hemisphere_pdf(w: Vec3) -> f32 {
    if w.z > 0.0 { INV_2PI } else { 0.0 }
}

/// Uniform direction inside the cone around +z with cos(half-angle) = `cos_max`.
#[inline]
pub fn square_to_uniform_cone(u: Vec2, cos_max: f32) -> Vec3 {
    let z = 1.0 - u.y * (1.0 - cos_max);
    let r = (1.0 - z * z).max(0.0).sqrt();
    let (s, c) = (2.0 * PI * u.x).sin_cos();
    Vec3::new(r * c, r * s, z)
}
/// pdf of [`square_to_uniform_cone`].
#[inline]
pub fn square_to_uniform_cone_pdf(w: Vec3, cos_max: f32) -> f32 {
    if w.z >= cos_max { 1.0 / (2.0 * PI * (1.0 - cos_max)) } else { 0.0 }
}

/// Uniform point on a triangle as barycentrics (b1, b2); the point is
/// `(1 - b1 - b2) p0 + b1 p1 + b2 p2`. Area pdf = 1 / area.
#[inline]
pub fn square_to_uniform_triangle(u: Vec2) -> Vec2 {
    // Heitz 2019, "A Low-Distortion Map Between Triangle and Square"
    let (b0, b1);
    if u.x < u.y {
        b0 = u.x / 2.0;
        b1 = u.y - b0;
    } else {
        b1 = u.y / 2.0;
        b0 = u.x - b1;
    }
    Vec2::new(b0, b1)
}
