//! The scalar interaction the SIMD kernels of `lanes.rs` are tested against, as the fast loop
//! ran it before the kernels (test-only).

use super::{FastFace, FastSide, dotted_choice};
use crate::bsdf::microfacet::Ndf;
use crate::fastmath::Fresnel;
use crate::math::{Vec2, Vec3};

/// Single-scattering rough interface in importance mode: visible normal, Fresnel choice,
/// reflection or refraction, weight G1(wi). `None` = the sample is lost (wrong side).
/// (The scalar definition of what the SIMD kernels compute, as the fast loop ran it before
/// the kernels; the tests compare the kernels with it.)
#[inline(always)]
pub(super) fn rough_sample(
    ndf: &impl Ndf,
    g1: impl Fn(Vec3, Vec3) -> f32,
    fr: &Fresnel,
    wo: Vec3,
    uc: f32,
    u: Vec2,
) -> Option<(Vec3, f32)> {
    let wm = ndf.sample_visible(wo, u);
    let cos_om = wo.dot(wm);
    if cos_om * wo.z <= 0.0 {
        return None;
    }
    let inside = cos_om < 0.0;
    let c = cos_om.abs();
    let (f, ct, eta_rel) = fr.eval(c, inside);
    let (wi, transmitted) = if uc < f {
        (wm * (2.0 * cos_om) - wo, false)
    } else {
        let n = if inside { -wm } else { wm };
        (n * (eta_rel * c - ct) - wo * eta_rel, true)
    };
    if transmitted == (wi.z * wo.z > 0.0) || wi.z == 0.0 {
        return None;
    }
    let w = g1(wi, wm);
    (w > 0.0).then_some((wi, w))
}

/// The scalar interaction of a face with local outgoing direction `wo` and random numbers
/// `u0` (the Fresnel choice) and `(u1, u2)` (the visible normal): new local direction and
/// weight factor (0 = lost; 1 for a polished face).
pub(super) fn interact_scalar(
    face: &FastFace,
    fr: &Fresnel,
    wo: Vec3,
    u0: f32,
    u1: f32,
    u2: f32,
) -> (Vec3, f32) {
    let s = match face {
        FastFace::Polished => {
            let inside = wo.z < 0.0;
            let (f, ct, eta_rel) = fr.eval(wo.z.abs(), inside);
            let wi = if u0 < f {
                Vec3::new(-wo.x, -wo.y, wo.z)
            } else {
                Vec3::new(-eta_rel * wo.x, -eta_rel * wo.y, if inside { ct } else { -ct })
            };
            Some((wi, 1.0))
        }
        FastFace::Ggx(g) => rough_sample(g, |a, b| g.g1_fast(a, b), fr, wo, u0, Vec2::new(u1, u2)),
        FastFace::Beckmann { ndf, mitsuba_g1: true } => {
            rough_sample(ndf, |a, b| ndf.g1_mitsuba(a, b), fr, wo, u0, Vec2::new(u1, u2))
        }
        FastFace::Beckmann { ndf, mitsuba_g1: false } => {
            rough_sample(ndf, |a, b| ndf.g1_fast(a, b), fr, wo, u0, Vec2::new(u1, u2))
        }
    };
    s.unwrap_or((Vec3::ZERO, 0.0))
}

/// `interact_scalar` for a plate side: a dotted side chooses its part with `u0` and passes the
/// rescaled number on (as `gonio::interact`).
pub(super) fn interact_scalar_side(
    side: &FastSide,
    fr: &Fresnel,
    wo: Vec3,
    u0: f32,
    u1: f32,
    u2: f32,
) -> (Vec3, f32) {
    match side {
        FastSide::Plain(face) => interact_scalar(face, fr, wo, u0, u1, u2),
        FastSide::Dotted { f, a, b } => {
            let (pick_a, ur) = dotted_choice(*f, u0);
            interact_scalar(if pick_a { a } else { b }, fr, wo, ur, u1, u2)
        }
    }
}
