//! Watertight ray–triangle intersection and robust spawning of secondary rays.
//!
//! * [`TriRay`] / [`intersect_triangle`]: the watertight test of Woop, Benthin & Wald,
//!   "Watertight Ray/Triangle Intersection", JCGT 2(1), 2013. The ray is sheared and scaled so
//!   that it becomes the +z axis through the origin; the three 2D edge functions `U, V, W` of
//!   the projected corners are then evaluated with the *same* arithmetic for an edge shared by
//!   two triangles (the 2D cross product is exactly antisymmetric in floating point and Rust
//!   never contracts to FMA on its own), so a ray can never slip between two triangles that
//!   share an edge or a vertex. When an edge function is exactly zero it is recomputed in f64
//!   (products of two f32 are exact in f64, so its sign is then exact), as the paper
//!   recommends. Edges are inclusive: a ray through a shared edge hits both triangles and the
//!   closest-hit query keeps either one. Zero-area triangles have `det = U + V + W = 0` and are
//!   never hit. Both faces are hit (no culling). A hit needs `0 < t < tmax`; NaN anywhere
//!   (zero direction, NaN vertices) gives a miss.
//!
//! * [`offset_ray_origin`]: moves a surface point off its surface along the geometric normal,
//!   towards the side of the outgoing direction, by
//!   `ε(p) = (1 + max_i |p_i|) · 2⁻¹⁹` (≈ 16 f32 ulps of the largest coordinate, plus an
//!   absolute floor of 2⁻¹⁹ ≈ 1.9e-6 for points near the origin). Why this size: the test above
//!   works on `v − o`, whose rounding error is a few ulps of the largest coordinate involved, and
//!   a surface point interpolated from barycentrics (`b0 p0 + b1 p1 + b2 p2`) is itself off the
//!   plane by up to ~γ₇·max|p| ≈ 2⁻²¹·max|p|. Mitsuba 3 uses the same form with a much larger
//!   constant (1500 · 2⁻²⁴ ≈ 2⁻¹⁰); pbrt-v4 tracks exact error bounds instead. Measured with
//!   `offset_rays_do_not_self_intersect` (hit points from barycentrics and from `o + t d` with
//!   origins up to 10 units away, grazing directions, meshes translated up to 1000 units): the
//!   scale 2⁻²² already gives self-intersections, 2⁻²¹ none; 2⁻¹⁹ keeps a factor 4 of margin
//!   while the gap a shadow ray leaves in a corner stays below 1e-5 of the scene size. Compute hit points from
//!   barycentrics when possible: `o + t d` carries an error proportional to `|o| + t|d|`.
//!
//! * [`spawn_ray_to`]: a shadow ray between two surface points, both ends offset off their
//!   surfaces, unit direction, `tmax` = distance between the offset ends shortened by a relative
//!   2⁻¹⁶ so the target surface is never hit.
//!
//! Tests: unit tests below (hits, misses, degenerate triangles, NaN safety, offset sides) and
//! `crates/opal/tests/accel.rs` (watertightness on closed meshes: shared edges and vertices never
//! leak; no self-intersection on a tessellated sphere; mutual visibility inside a convex mesh).

use crate::geometry::Ray;
use crate::math::Vec3;

/// The axis permutation and shear of the watertight test for direction `d`: `([kx, ky, kz], S_x,
/// S_y, S_z)` with kz the dominant axis, kx, ky the next two (swapped when `d_kz < 0` to keep the
/// winding, hence the sign of det, consistent) and `S = (d_kx, d_ky, 1) / d_kz`.
#[inline]
pub(crate) fn shear_axes(d: Vec3) -> ([usize; 3], f32, f32, f32) {
    let a = d.abs();
    let kz = if a.x > a.y {
        if a.x > a.z { 0 } else { 2 }
    } else if a.y > a.z {
        1
    } else {
        2
    };
    let mut kx = if kz == 2 { 0 } else { kz + 1 };
    let mut ky = if kx == 2 { 0 } else { kx + 1 };
    if d[kz] < 0.0 {
        std::mem::swap(&mut kx, &mut ky);
    }
    let sz = 1.0 / d[kz];
    ([kx, ky, kz], d[kx] * sz, d[ky] * sz, sz)
}

/// A ray prepared for the watertight test: permutation of the axes and shear constants.
#[derive(Clone, Copy, Debug)]
pub struct TriRay {
    /// Ray origin.
    pub o: Vec3,
    /// Rows of the shear-and-permute transform: `rx = e_kx − S_x e_kz`, `ry = e_ky − S_y e_kz`,
    /// `rz = S_z e_kz` (kz = dominant direction axis, `S = (d_kx, d_ky, 1) / d_kz`). Two of the
    /// three products in each dot product are exact zeros or exact copies, so `rx · a` rounds
    /// exactly like the paper's `a_kx − S_x a_kz`, without indexing by a runtime axis.
    rx: Vec3,
    ry: Vec3,
    rz: Vec3,
}

impl TriRay {
    /// Precomputes the shear for `ray` (direction need not be normalised).
    #[inline]
    pub fn new(ray: &Ray) -> Self {
        let ([kx, ky, kz], sx, sy, sz) = shear_axes(ray.d);
        let e = |k: usize| Vec3::AXES[k];
        TriRay { o: ray.o, rx: e(kx) - sx * e(kz), ry: e(ky) - sy * e(kz), rz: sz * e(kz) }
    }

    /// Intersects one triangle; returns `(t, b1, b2)` for a hit with `0 < t < tmax`
    /// (`b1`, `b2` = barycentrics of corners 1 and 2).
    #[inline(always)]
    pub fn intersect(&self, tri: &[Vec3; 3], tmax: f32) -> Option<(f32, f32, f32)> {
        let a = tri[0] - self.o;
        let b = tri[1] - self.o;
        let c = tri[2] - self.o;
        let (ax, ay) = (self.rx.dot(a), self.ry.dot(a));
        let (bx, by) = (self.rx.dot(b), self.ry.dot(b));
        let (cx, cy) = (self.rx.dot(c), self.ry.dot(c));
        let mut u = cx * by - cy * bx;
        let mut v = ax * cy - ay * cx;
        let mut w = bx * ay - by * ax;
        if u == 0.0 || v == 0.0 || w == 0.0 {
            let f = |p: f32, q: f32, r: f32, s: f32| (p as f64 * q as f64 - r as f64 * s as f64) as f32;
            u = f(cx, by, cy, bx);
            v = f(ax, cy, ay, cx);
            w = f(bx, ay, by, ax);
        }
        if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
            return None;
        }
        let det = u + v + w;
        if det == 0.0 {
            return None;
        }
        let (az, bz, cz) = (self.rz.dot(a), self.rz.dot(b), self.rz.dot(c));
        let tt = u * az + v * bz + w * cz;
        // Early out on the sign of t before dividing.
        if (tt > 0.0) != (det > 0.0) {
            return None;
        }
        let inv = 1.0 / det;
        let t = tt * inv;
        // Written so that NaN fails.
        if t > 0.0 && t < tmax { Some((t, v * inv, w * inv)) } else { None }
    }
}

/// Watertight intersection of `ray` with `tri` in `(0, tmax)`: `(t, b1, b2)`.
/// Prepare a [`TriRay`] once when testing many triangles.
#[inline]
pub fn intersect_triangle(ray: &Ray, tri: &[Vec3; 3], tmax: f32) -> Option<(f32, f32, f32)> {
    TriRay::new(ray).intersect(tri, tmax)
}

/// Relative size of the origin offset: `ε(p) = (1 + max|p_i|) · RAY_OFFSET_SCALE`.
pub const RAY_OFFSET_SCALE: f32 = 1.0 / (1u32 << 19) as f32;

/// Relative shortening of a shadow ray's `tmax` in [`spawn_ray_to`].
pub const SHADOW_RAY_SHORTEN: f32 = 1.0 / (1u32 << 16) as f32;

/// Offsets a surface point `p` with geometric normal `ng` (any length > 0, either orientation)
/// along `±ng` towards the side of direction `w`, by `(1 + max|p_i|) · 2⁻¹⁹` (see the module
/// docs), so a ray leaving towards `w` does not hit the surface it starts on.
#[inline]
pub fn offset_ray_origin(p: Vec3, ng: Vec3, w: Vec3) -> Vec3 {
    let n = ng.normalize_or_zero();
    let mag = (1.0 + p.abs().max_element()) * RAY_OFFSET_SCALE;
    let mag = if n.dot(w) >= 0.0 { mag } else { -mag };
    p + n * mag
}

/// A ray leaving surface point `p` (geometric normal `ng`) in direction `d` (kept as given),
/// with the origin offset by [`offset_ray_origin`] and `tmax = ∞`.
#[inline]
pub fn spawn_ray(p: Vec3, ng: Vec3, d: Vec3) -> Ray {
    Ray::new(offset_ray_origin(p, ng, d), d)
}

/// Shadow ray from surface point `p0` (normal `ng0`) to surface point `p1` (normal `ng1`):
/// both ends offset off their surfaces towards each other, unit direction, and `tmax` = the
/// distance between the offset ends times `1 − 2⁻¹⁶`, so neither surface is hit but anything in
/// between is. If the two points coincide the ray has `tmax = 0` (never occluded).
#[inline]
pub fn spawn_ray_to(p0: Vec3, ng0: Vec3, p1: Vec3, ng1: Vec3) -> Ray {
    let o = offset_ray_origin(p0, ng0, p1 - p0);
    let target = offset_ray_origin(p1, ng1, p0 - p1);
    let v = target - o;
    let dist = v.length();
    if dist > 0.0 && dist.is_finite() {
        Ray { o, d: v / dist, tmax: dist * (1.0 - SHADOW_RAY_SHORTEN) }
    } else {
        Ray { o, d: Vec3::Z, tmax: 0.0 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TRI: [Vec3; 3] = [Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.0, 1.0, 0.0)];

    #[test]
    fn hit_gives_t_and_barycentrics() {
        for dz in [-1.0f32, 1.0] {
            let ray = Ray::new(Vec3::new(0.2, 0.3, -dz * 2.0), Vec3::new(0.0, 0.0, dz));
            let (t, b1, b2) = intersect_triangle(&ray, &TRI, f32::INFINITY).unwrap();
            assert!((t - 2.0).abs() < 1e-6);
            assert!((b1 - 0.2).abs() < 1e-6 && (b2 - 0.3).abs() < 1e-6);
            // Point from barycentrics equals the ray point.
            let p = TRI[0] * (1.0 - b1 - b2) + TRI[1] * b1 + TRI[2] * b2;
            assert!((p - ray.at(t)).length() < 1e-6);
        }
        // Oblique, non-normalised direction along every dominant axis.
        for d in [Vec3::new(3.0, 1.0, 0.5), Vec3::new(-0.5, 4.0, 1.0), Vec3::new(0.3, -0.2, -5.0)] {
            let target = Vec3::new(0.25, 0.25, 0.0);
            let ray = Ray::new(target - d * 0.7, d);
            let (t, b1, b2) = intersect_triangle(&ray, &TRI, f32::INFINITY).unwrap();
            assert!((t - 0.7).abs() < 1e-5, "{t}");
            assert!((b1 - 0.25).abs() < 1e-5 && (b2 - 0.25).abs() < 1e-5);
        }
    }

    #[test]
    fn misses() {
        let up = Vec3::Z;
        // Outside the triangle.
        assert!(intersect_triangle(&Ray::new(Vec3::new(0.8, 0.8, -1.0), up), &TRI, f32::INFINITY).is_none());
        // Behind the origin.
        assert!(intersect_triangle(&Ray::new(Vec3::new(0.2, 0.2, 1.0), up), &TRI, f32::INFINITY).is_none());
        // Beyond tmax, and exactly at tmax (open interval).
        assert!(intersect_triangle(&Ray::new(Vec3::new(0.2, 0.2, -1.0), up), &TRI, 0.5).is_none());
        assert!(intersect_triangle(&Ray::new(Vec3::new(0.2, 0.2, -1.0), up), &TRI, 1.0).is_none());
        // Parallel to the plane.
        assert!(
            intersect_triangle(&Ray::new(Vec3::new(-1.0, 0.2, 0.0), Vec3::X), &TRI, f32::INFINITY).is_none()
        );
        // Origin on the triangle: t = 0 is not a hit.
        assert!(intersect_triangle(&Ray::new(Vec3::new(0.2, 0.2, 0.0), up), &TRI, f32::INFINITY).is_none());
    }

    #[test]
    fn degenerate_and_nan_never_hit() {
        let ray = Ray::new(Vec3::new(0.5, 0.0, -1.0), Vec3::Z);
        let line = [Vec3::ZERO, Vec3::X, Vec3::X * 2.0];
        let point = [Vec3::X * 0.5; 3];
        assert!(intersect_triangle(&ray, &line, f32::INFINITY).is_none());
        assert!(intersect_triangle(&ray, &point, f32::INFINITY).is_none());
        let zero_dir = Ray::new(Vec3::new(0.2, 0.2, -1.0), Vec3::ZERO);
        assert!(intersect_triangle(&zero_dir, &TRI, f32::INFINITY).is_none());
        let nan_tri = [Vec3::new(f32::NAN, 0.0, 0.0), Vec3::X, Vec3::Y];
        assert!(
            intersect_triangle(&Ray::new(Vec3::new(0.2, 0.2, -1.0), Vec3::Z), &nan_tri, f32::INFINITY)
                .is_none()
        );
    }

    #[test]
    fn edges_and_vertices_are_inclusive() {
        // Through the middle of the hypotenuse and through each corner.
        for p in [Vec3::new(0.5, 0.5, 0.0), TRI[0], TRI[1], TRI[2], Vec3::new(0.5, 0.0, 0.0)] {
            // Dyadic values: the ray passes exactly through p.
            let d = Vec3::new(0.125, 0.25, 1.0);
            let ray = Ray::new(p - d, d);
            assert!(intersect_triangle(&ray, &TRI, f32::INFINITY).is_some(), "{p}");
        }
    }

    #[test]
    fn offset_goes_to_the_side_of_w() {
        let p = Vec3::new(100.0, -3.0, 0.5);
        let n = Vec3::new(0.0, 0.0, 2.0);
        let up = offset_ray_origin(p, n, Vec3::new(0.3, 0.1, 0.2));
        let down = offset_ray_origin(p, -n, Vec3::new(0.3, 0.1, -0.2));
        let eps = 101.0 * RAY_OFFSET_SCALE;
        assert!((up.z - p.z - eps).abs() < 1e-7 && up.x == p.x && up.y == p.y);
        assert!((p.z - down.z - eps).abs() < 1e-7);
    }

    #[test]
    fn spawn_ray_to_stops_short_of_target() {
        let p0 = Vec3::new(0.2, 0.2, 0.0);
        let p1 = Vec3::new(0.2, 0.2, 3.0);
        let r = spawn_ray_to(p0, Vec3::Z, p1, -Vec3::Z);
        assert!((r.d.length() - 1.0).abs() < 1e-6);
        assert!(r.o.z > 0.0 && r.at(r.tmax).z < 3.0 && r.tmax > 2.99);
        let target = [Vec3::new(0.0, 0.0, 3.0), Vec3::new(1.0, 0.0, 3.0), Vec3::new(0.0, 1.0, 3.0)];
        assert!(intersect_triangle(&r, &TRI, r.tmax).is_none());
        assert!(intersect_triangle(&r, &target, r.tmax).is_none());
        assert!(intersect_triangle(&r, &target, f32::INFINITY).is_some());
        assert_eq!(spawn_ray_to(p0, Vec3::Z, p0, Vec3::Z).tmax, 0.0);
    }
}
