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
//! * detector look-up by binning the direction cosines (`Detectors::for_each_hit`);
//! * a wavefront loop: chunks of 256 photons advance one interaction at a time, all at the same
//!   face, so each stage is a tight loop over independent photons (no per-photon branching on
//!   the face type, latencies overlap across photons); state in arrays (SoA).

use super::{Acc, BeamFrame, Face, Gonio, Plate, Scattering, Side};
use crate::bsdf::microfacet::{Beckmann, Ggx, Ndf, Ndfs};
use crate::fastmath::{Fresnel, sincos_2pi};
use crate::math::{Vec2, Vec3};
use crate::sampling::{Rng, RngStream};

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

/// Photons traced together, stage by stage (the wavefront).
const CHUNK: usize = 256;

/// Per-batch scratch of the wavefront loop (allocated once per batch of `BATCH` photons).
struct Wavefront {
    rng: Vec<Rng>,
    d: Vec<Vec3>,
    w: Vec<f32>,
    ok: Vec<bool>,
    active: Vec<u16>,
}

impl Gonio {
    /// Traces photons `first..first + count` of incidence stream `stream` through `fp`, in
    /// chunks of `CHUNK` photons advanced one surface interaction at a time: in round r every
    /// photon still inside is at the same face (the lit face for even r), so each round is one
    /// tight loop over independent photons per stage (sample, then exit / tally / traverse),
    /// whose latencies the CPU overlaps across photons.
    pub(super) fn trace_batch_fast(
        &self,
        fp: &FastPlate,
        bf: &BeamFrame,
        stream: u64,
        first: u64,
        count: u64,
        acc: &mut Acc,
    ) {
        let mut wf = Wavefront {
            rng: Vec::with_capacity(CHUNK),
            d: vec![Vec3::ZERO; CHUNK],
            w: vec![0.0; CHUNK],
            ok: vec![false; CHUNK],
            active: Vec::with_capacity(CHUNK),
        };
        let mut k0 = 0;
        while k0 < count {
            let m = (count - k0).min(CHUNK as u64) as usize;
            self.trace_chunk(fp, bf, stream, first + k0, m, acc, &mut wf);
            k0 += m as u64;
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn trace_chunk(
        &self,
        fp: &FastPlate,
        bf: &BeamFrame,
        stream: u64,
        first: u64,
        m: usize,
        acc: &mut Acc,
        wf: &mut Wavefront,
    ) {
        let BeamFrame { sa, ca, st, ct, .. } = *bf;
        let k0 = Vec3::new(st * ca, st * sa, -ct);
        let e1 = Vec3::new(ct * ca, ct * sa, st);
        let e2 = Vec3::new(-sa, ca, 0.0);
        let div = self.setup.beam.divergence;
        // 1 − cos δ without cancellation
        let one_minus_cos = (2.0 * (0.5 * div).sin().powi(2)) as f32;
        let streams = RngStream::new(self.setup.seed, stream);
        let fr = fp.fresnel;
        // beam
        wf.rng.clear();
        wf.active.clear();
        for i in 0..m {
            let mut rng = streams.rng(first + i as u64);
            wf.d[i] = if div > 0.0 {
                let u = rng.next_2d();
                let om = u.y * one_minus_cos;
                let r = (om * (2.0 - om)).max(0.0).sqrt();
                let (s, c) = sincos_2pi(u.x);
                e1 * (r * c) + e2 * (r * s) + k0 * (1.0 - om)
            } else {
                k0
            };
            wf.w[i] = 1.0;
            wf.rng.push(rng);
            wf.active.push(i as u16);
        }
        let mut lost = 0.0f64;
        for round in 0..self.setup.max_interactions {
            if wf.active.is_empty() {
                break;
            }
            acc.interactions += wf.active.len() as u64;
            let top = round % 2 == 0;
            let face = if top { &fp.front } else { &fp.back };
            // stage 1: interaction (local frame of the face: +z = outward normal; the bottom
            // face is the rotation by π about x, an involution)
            let to_local = |v: Vec3| if top { v } else { Vec3::new(v.x, -v.y, -v.z) };
            match face {
                FastFace::Polished => {
                    for &i in &wf.active {
                        let i = i as usize;
                        let wo = to_local(-wf.d[i]);
                        let inside = wo.z < 0.0;
                        let (f, ct, eta_rel) = fr.eval(wo.z.abs(), inside);
                        let wi = if wf.rng[i].next_f32() < f {
                            Vec3::new(-wo.x, -wo.y, wo.z)
                        } else {
                            Vec3::new(-eta_rel * wo.x, -eta_rel * wo.y, if inside { ct } else { -ct })
                        };
                        wf.d[i] = to_local(wi);
                        wf.ok[i] = true;
                    }
                }
                FastFace::Ggx(g) => {
                    for &i in &wf.active {
                        let i = i as usize;
                        let wo = to_local(-wf.d[i]);
                        let rng = &mut wf.rng[i];
                        let uc = rng.next_f32();
                        let u = rng.next_2d();
                        let s = rough_sample(g, |a, b| g.g1_fast(a, b), &fr, wo, uc, u);
                        apply(s, i, &mut wf.d, &mut wf.w, &mut wf.ok, &mut lost, to_local);
                    }
                }
                FastFace::Beckmann { ndf, mitsuba_g1 } => {
                    for &i in &wf.active {
                        let i = i as usize;
                        let wo = to_local(-wf.d[i]);
                        let rng = &mut wf.rng[i];
                        let uc = rng.next_f32();
                        let u = rng.next_2d();
                        let s = if *mitsuba_g1 {
                            rough_sample(ndf, |a, b| ndf.g1_mitsuba(a, b), &fr, wo, uc, u)
                        } else {
                            rough_sample(ndf, |a, b| ndf.g1_fast(a, b), &fr, wo, uc, u)
                        };
                        apply(s, i, &mut wf.d, &mut wf.w, &mut wf.ok, &mut lost, to_local);
                    }
                }
            }
            // stage 2: exit and tally, or traverse the plate
            let mut kept = 0;
            for j in 0..wf.active.len() {
                let i = wf.active[j] as usize;
                if !wf.ok[i] {
                    continue;
                }
                let (d, mut w) = (wf.d[i], wf.w[i]);
                if !(d.is_finite() && w.is_finite()) {
                    acc.bad += 1;
                    continue;
                }
                if if top { d.z > 0.0 } else { d.z < 0.0 } {
                    let side = if top { Side::R } else { Side::T };
                    match side {
                        Side::R => acc.r += w as f64,
                        Side::T => acc.t += w as f64,
                    }
                    let wd = w as f64;
                    let inv_cos = 1.0 / (d.z.abs() as f64).max(1e-6);
                    self.dets.for_each_hit(side, d, Vec3::ZERO, |k| {
                        acc.sum[k] += wd;
                        acc.sum2[k] += wd * wd;
                        acc.sum_bsdf[k] += wd * inv_cos;
                        acc.hits[k] += 1;
                    });
                    continue;
                }
                if fp.mu > 0.0 {
                    let w2 = w * crate::fastmath::exp(-fp.mu * fp.thick / d.z.abs());
                    acc.absorbed += (w - w2) as f64;
                    w = w2;
                    wf.w[i] = w;
                }
                wf.active[kept] = i as u16;
                kept += 1;
            }
            wf.active.truncate(kept);
        }
        // beyond the interaction limit
        for &i in &wf.active {
            lost += wf.w[i as usize] as f64;
        }
        acc.lost += lost;
    }
}

/// Stores the outcome of a rough-face sample of photon `i`: new direction (world frame) and
/// weight, or the photon's weight booked as lost.
#[inline(always)]
fn apply(
    s: Option<(Vec3, f32)>,
    i: usize,
    d: &mut [Vec3],
    w: &mut [f32],
    ok: &mut [bool],
    lost: &mut f64,
    to_world: impl Fn(Vec3) -> Vec3,
) {
    match s {
        Some((wi, g)) => {
            let w2 = w[i] * g;
            *lost += (w[i] - w2) as f64;
            w[i] = w2;
            d[i] = to_world(wi);
            ok[i] = true;
        }
        None => {
            *lost += w[i] as f64;
            ok[i] = false;
        }
    }
}
