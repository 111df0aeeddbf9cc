//! Fast photon loop for the common case: an infinite plate (far-field detectors) whose faces
//! are polished or rough with single scattering (`Scattering::Single` / `SingleMitsuba`) on a
//! GGX or Beckmann NDF. Finite plates, multiple scattering, the height-correlated G and
//! numerical NDFs take the general loop (`Gonio::trace_photon`).
//!
//! Same physics, same random-number contract (photon j of incidence i draws from
//! `Rng::new(seed, i, j)`, in the same order: beam cone, then per interaction one number for a
//! polished face or three for a rough one), so results agree with the general loop in
//! distribution (tested: `gonio::tests::fast_path_matches_general_path`). What makes it fast:
//! * everything in f32 with the polynomial math of [`crate::fastmath`] (`sincos(2πu)` for the
//!   beam cone and GGX, `exp`/`erfc`/`erfinv` for Beckmann), Fresnel with the constants of the
//!   plate's index precomputed ([`Fresnel`]);
//! * the NDF is resolved once per run (`FastFace`), not matched per sample, and the sample
//!   weight is G1 of the new direction directly (the separable `G/G1(wo)`);
//! * GGX visible normals by spherical caps, Beckmann visible slopes from a quantile table plus
//!   Newton on the exact CDF (`microfacet::beckmann`);
//! * detector look-up by binning the direction cosines (`Detectors::for_each_hit`).

use super::{Acc, BeamFrame, Face, Gonio, Plate, Scattering, Side};
use crate::bsdf::microfacet::{Beckmann, Ggx, Ndf, Ndfs};
use crate::fastmath::{Fresnel, sincos_2pi};
use crate::math::{Vec2, Vec3};
use crate::sampling::Rng;

/// A face resolved for the fast loop.
#[derive(Clone, Copy, Debug)]
pub(super) enum FastFace {
    Polished,
    Ggx(Ggx),
    Beckmann { ndf: Beckmann, mitsuba_g1: bool },
}

/// The plate resolved for the fast loop.
#[derive(Clone, Copy, Debug)]
pub(super) struct FastPlate {
    front: FastFace,
    back: FastFace,
    fresnel: Fresnel,
    thick: f32,
    mu: f32,
}

impl FastPlate {
    /// `None` when the plate needs the general loop.
    pub(super) fn new(plate: &Plate) -> Option<Self> {
        if plate.radius_mm.is_some() {
            return None;
        }
        let face = |f: &Face| -> Option<FastFace> {
            match f {
                Face::Polished => Some(FastFace::Polished),
                Face::Rough { ndf, scattering } => {
                    let mitsuba_g1 = match scattering {
                        Scattering::Single => false,
                        Scattering::SingleMitsuba => true,
                        _ => return None,
                    };
                    match ndf {
                        Ndfs::Ggx(g) => Some(FastFace::Ggx(*g)),
                        Ndfs::Beckmann(b) => Some(FastFace::Beckmann { ndf: *b, mitsuba_g1 }),
                        Ndfs::Numeric(_) => None,
                    }
                }
            }
        };
        Some(FastPlate {
            front: face(&plate.front)?,
            back: face(&plate.back)?,
            fresnel: Fresnel::new(plate.ior as f32),
            thick: plate.thickness_mm as f32,
            mu: plate.absorption_per_mm as f32,
        })
    }
}

/// Single-scattering rough interface in importance mode: visible normal, Fresnel choice,
/// reflection or refraction, weight G1(wi). `None` = the sample is lost (wrong side).
#[inline(always)]
fn rough_sample(
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

impl Gonio {
    /// Traces photons `first..first + count` of incidence stream `stream` through `fp`.
    pub(super) fn trace_batch_fast(
        &self,
        fp: &FastPlate,
        bf: &BeamFrame,
        stream: u64,
        first: u64,
        count: u64,
        acc: &mut Acc,
    ) {
        let BeamFrame { sa, ca, st, ct, .. } = *bf;
        let k0 = Vec3::new(st * ca, st * sa, -ct);
        let e1 = Vec3::new(ct * ca, ct * sa, st);
        let e2 = Vec3::new(-sa, ca, 0.0);
        let div = self.setup.beam.divergence;
        // 1 − cos δ without cancellation
        let one_minus_cos = (2.0 * (0.5 * div).sin().powi(2)) as f32;
        let seed = self.setup.seed;
        let max_int = self.setup.max_interactions;
        let fr = fp.fresnel;
        for k in 0..count {
            let mut rng = Rng::new(seed, stream, first + k);
            let mut d = if div > 0.0 {
                let u = rng.next_2d();
                let om = u.y * one_minus_cos;
                let r = (om * (2.0 - om)).max(0.0).sqrt();
                let (s, c) = sincos_2pi(u.x);
                e1 * (r * c) + e2 * (r * s) + k0 * (1.0 - om)
            } else {
                k0
            };
            let mut w = 1.0f32;
            let mut top = true;
            let mut ended = false;
            for _ in 0..max_int {
                acc.interactions += 1;
                let face = if top { &fp.front } else { &fp.back };
                // local frame of the face: +z = outward normal; bottom = rotation by π about x
                let wo = if top { -d } else { Vec3::new(-d.x, d.y, d.z) };
                let sampled = match face {
                    FastFace::Polished => {
                        let inside = wo.z < 0.0;
                        let (f, ct, eta_rel) = fr.eval(wo.z.abs(), inside);
                        Some(if rng.next_f32() < f {
                            Vec3::new(-wo.x, -wo.y, wo.z)
                        } else {
                            Vec3::new(-eta_rel * wo.x, -eta_rel * wo.y, if inside { ct } else { -ct })
                        })
                    }
                    FastFace::Ggx(g) => {
                        let uc = rng.next_f32();
                        let u = rng.next_2d();
                        rough_sample(g, |a, b| g.g1_fast(a, b), &fr, wo, uc, u).map(|(wi, s)| {
                            let w2 = w * s;
                            acc.lost += (w - w2) as f64;
                            w = w2;
                            wi
                        })
                    }
                    FastFace::Beckmann { ndf, mitsuba_g1 } => {
                        let uc = rng.next_f32();
                        let u = rng.next_2d();
                        let s = if *mitsuba_g1 {
                            rough_sample(ndf, |a, b| ndf.g1_mitsuba(a, b), &fr, wo, uc, u)
                        } else {
                            rough_sample(ndf, |a, b| ndf.g1_fast(a, b), &fr, wo, uc, u)
                        };
                        s.map(|(wi, s)| {
                            let w2 = w * s;
                            acc.lost += (w - w2) as f64;
                            w = w2;
                            wi
                        })
                    }
                };
                let Some(wi) = sampled else {
                    acc.lost += w as f64;
                    ended = true;
                    break;
                };
                d = if top { wi } else { Vec3::new(wi.x, -wi.y, -wi.z) };
                if !(d.is_finite() && w.is_finite()) {
                    acc.bad += 1;
                    ended = true;
                    break;
                }
                let exits = if top { d.z > 0.0 } else { d.z < 0.0 };
                if exits {
                    let side = if top { Side::R } else { Side::T };
                    match side {
                        Side::R => acc.r += w as f64,
                        Side::T => acc.t += w as f64,
                    }
                    let wf = w as f64;
                    let inv_cos = 1.0 / (d.z.abs() as f64).max(1e-6);
                    self.dets.for_each_hit(side, d, Vec3::ZERO, |i| {
                        acc.sum[i] += wf;
                        acc.sum2[i] += wf * wf;
                        acc.sum_bsdf[i] += wf * inv_cos;
                        acc.hits[i] += 1;
                    });
                    ended = true;
                    break;
                }
                if fp.mu > 0.0 {
                    let len = fp.thick / d.z.abs();
                    let w2 = w * crate::fastmath::exp(-fp.mu * len);
                    acc.absorbed += (w - w2) as f64;
                    w = w2;
                }
                top = !top;
            }
            if !ended {
                acc.lost += w as f64;
            }
        }
    }
}
