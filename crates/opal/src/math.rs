//! Math helpers on top of `glam`: orthonormal frames, spherical coordinates in the local
//! shading frame (z = normal), mirror reflection, refraction and the unpolarised Fresnel
//! reflectance of a dielectric interface.
//!
//! Conventions: directions point *away* from the surface; `eta` is the ratio of indices
//! interior/exterior (n_inside / n_outside) relative to the side the normal points to.
//! Tests: unit tests below (frame orthonormality, refraction/Snell, Fresnel limits).

pub use glam::{DMat4, DVec2, DVec3, Mat3, Mat4, Vec2, Vec3, Vec4};

/// π as f32.
pub const PI: f32 = std::f32::consts::PI;
/// 1/π as f32.
pub const INV_PI: f32 = std::f32::consts::FRAC_1_PI;
/// 1/(2π) as f32.
pub const INV_2PI: f32 = 0.5 * std::f32::consts::FRAC_1_PI;
/// 1/(4π) as f32.
pub const INV_4PI: f32 = 0.25 * std::f32::consts::FRAC_1_PI;

/// Orthonormal frame (s, t, n): converts between world and local (z = n) coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    /// First tangent.
    pub s: Vec3,
    /// Second tangent.
    pub t: Vec3,
    /// Normal (local +z).
    pub n: Vec3,
}

impl Frame {
    /// Frame around a unit normal (Duff et al. 2017, "Building an orthonormal basis, revisited").
    pub fn from_normal(n: Vec3) -> Self {
        let sign = 1.0f32.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        let s = Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let t = Vec3::new(b, sign + n.y * n.y * a, -n.y);
        Frame { s, t, n }
    }
    /// Frame from a normal and a preferred tangent direction (Gram–Schmidt); falls back to
    /// [`Frame::from_normal`] when the tangent is parallel to the normal.
    pub fn from_normal_tangent(n: Vec3, tangent: Vec3) -> Self {
        let s = tangent - n * n.dot(tangent);
        let len = s.length();
        if len < 1e-6 {
            return Self::from_normal(n);
        }
        let s = s / len;
        Frame { s, t: n.cross(s), n }
    }
    /// World → local.
    #[inline]
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.s), v.dot(self.t), v.dot(self.n))
    }
    /// Local → world.
    #[inline]
    pub fn to_world(&self, v: Vec3) -> Vec3 {
        self.s * v.x + self.t * v.y + self.n * v.z
    }
}

/// cos θ of a local direction.
#[inline]
pub fn cos_theta(w: Vec3) -> f32 {
    w.z
}
/// |cos θ| of a local direction.
#[inline]
pub fn abs_cos_theta(w: Vec3) -> f32 {
    w.z.abs()
}
/// sin² θ of a local unit direction.
#[inline]
pub fn sin2_theta(w: Vec3) -> f32 {
    (1.0 - w.z * w.z).max(0.0)
}
/// tan² θ of a local unit direction.
#[inline]
pub fn tan2_theta(w: Vec3) -> f32 {
    sin2_theta(w) / (w.z * w.z)
}
/// True when both local directions are on the same side of the surface.
#[inline]
pub fn same_hemisphere(a: Vec3, b: Vec3) -> bool {
    a.z * b.z > 0.0
}
/// Unit direction from spherical angles (θ from +z, φ from +x).
#[inline]
pub fn spherical_direction(theta: f32, phi: f32) -> Vec3 {
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    Vec3::new(st * cp, st * sp, ct)
}
/// Same in f64.
#[inline]
pub fn spherical_direction_f64(theta: f64, phi: f64) -> DVec3 {
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    DVec3::new(st * cp, st * sp, ct)
}

/// Mirror reflection of `wo` about the normal `n` (both pointing away from the surface).
#[inline]
pub fn reflect(wo: Vec3, n: Vec3) -> Vec3 {
    -wo + 2.0 * wo.dot(n) * n
}

/// Refraction of `wi` (pointing away from the surface) through an interface with normal `n` and
/// relative index `eta` = n_transmitted_side / n_incident_side (incident side = side of `wi`,
/// which must be the side `n` points to). Returns `None` for total internal reflection.
#[inline]
pub fn refract(wi: Vec3, n: Vec3, eta: f32) -> Option<Vec3> {
    let cos_i = n.dot(wi);
    let sin2_i = (1.0 - cos_i * cos_i).max(0.0);
    let sin2_t = sin2_i / (eta * eta);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    Some(-wi / eta + (cos_i / eta - cos_t) * n)
}

/// Unpolarised Fresnel reflectance of a dielectric interface.
///
/// `cos_i` is the cosine of the incident direction with the normal (may be negative: the ray
/// comes from the inside), `eta` = n_inside / n_outside where "inside" is the side opposite to the
/// normal. Returns (R, cos_t signed like Mitsuba's `fresnel`, eta_it, eta_ti) — here simplified to
/// `(R, cos_t)` with `cos_t` of the transmitted direction (negative of `cos_i`'s sign).
pub fn fresnel_dielectric(cos_i: f32, eta: f32) -> (f32, f32) {
    let (cos_i_abs, eta) = if cos_i >= 0.0 { (cos_i, eta) } else { (-cos_i, 1.0 / eta) };
    let sin2_t = (1.0 - cos_i_abs * cos_i_abs).max(0.0) / (eta * eta);
    if sin2_t >= 1.0 {
        return (1.0, 0.0);
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let rs = (cos_i_abs - eta * cos_t) / (cos_i_abs + eta * cos_t);
    let rp = (eta * cos_i_abs - cos_t) / (eta * cos_i_abs + cos_t);
    let r = 0.5 * (rs * rs + rp * rp);
    (r, if cos_i >= 0.0 { -cos_t } else { cos_t })
}

/// f64 version of [`fresnel_dielectric`] (returns R only).
pub fn fresnel_dielectric_f64(cos_i: f64, eta: f64) -> f64 {
    let (cos_i, eta) = if cos_i >= 0.0 { (cos_i, eta) } else { (-cos_i, 1.0 / eta) };
    let sin2_t = (1.0 - cos_i * cos_i).max(0.0) / (eta * eta);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    let rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    0.5 * (rs * rs + rp * rp)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_is_orthonormal() {
        for n in [Vec3::Z, -Vec3::Z, Vec3::X, Vec3::new(0.3, -0.5, 0.8).normalize()] {
            let f = Frame::from_normal(n);
            assert!(f.s.dot(f.t).abs() < 1e-6 && f.s.dot(f.n).abs() < 1e-6);
            assert!((f.s.length() - 1.0).abs() < 1e-6 && (f.t.length() - 1.0).abs() < 1e-6);
            let v = Vec3::new(0.1, 0.7, -0.2);
            assert!((f.to_world(f.to_local(v)) - v).length() < 1e-6);
            assert!(f.s.cross(f.t).dot(f.n) > 0.99);
        }
    }

    #[test]
    fn snell_and_fresnel() {
        let wi = spherical_direction(0.5, 0.3);
        let wt = refract(wi, Vec3::Z, 1.5).unwrap();
        let sin_i = sin2_theta(wi).sqrt();
        let sin_t = sin2_theta(wt).sqrt();
        assert!((sin_i - 1.5 * sin_t).abs() < 1e-5);
        assert!(wt.z < 0.0);
        // normal incidence: ((n-1)/(n+1))^2
        let (r, _) = fresnel_dielectric(1.0, 1.5);
        assert!((r - 0.04).abs() < 1e-6);
        // total internal reflection from inside beyond the critical angle
        let (r, _) = fresnel_dielectric(-0.1, 1.5);
        assert_eq!(r, 1.0);
        assert!((fresnel_dielectric_f64(0.7, 1.49) - fresnel_dielectric(0.7, 1.49).0 as f64).abs() < 1e-6);
    }
}
