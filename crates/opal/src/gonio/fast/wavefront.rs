//! The wavefront photon loop of the fast path: chunks of `CHUNK` photons advanced one surface
//! interaction at a time, the interaction on `N` lanes (`lanes.rs`), random numbers, exits,
//! detector tally and absorption in scalar passes over the round's photons in order.

use super::lanes::{V3, interact_side_block};
use super::{FastFace, FastPlate, FastSide, dotted_choice};
use crate::bsdf::microfacet::beckmann::{TAB_NC, TAB_NU};
use crate::fastmath::wide::{self, F};
use crate::gonio::{Acc, BeamFrame, Gonio, Side};
use crate::math::Vec3;
use crate::sampling::{Rng, RngStream};

/// Photons traced together, stage by stage (the wavefront); a multiple of every lane count.
pub(super) const CHUNK: usize = 256;

/// Per-batch scratch of the wavefront loop (allocated once per batch of `BATCH` photons): the
/// state of the photons still inside, compacted after every round.
pub(super) struct Wavefront {
    rng: Vec<Rng>,
    dx: Vec<f32>,
    dy: Vec<f32>,
    dz: Vec<f32>,
    w: Vec<f32>,
    u0: Vec<f32>,
    u1: Vec<f32>,
    u2: Vec<f32>,
    nx: Vec<f32>,
    ny: Vec<f32>,
    nz: Vec<f32>,
    g: Vec<f32>,
    /// Photons of the round whose interaction is redone with the full Beckmann iteration.
    redo: Vec<u16>,
}

impl Wavefront {
    pub(super) fn new() -> Self {
        let z = || vec![0.0f32; CHUNK];
        Wavefront {
            rng: Vec::with_capacity(CHUNK),
            dx: z(),
            dy: z(),
            dz: z(),
            w: z(),
            u0: z(),
            u1: z(),
            u2: z(),
            nx: z(),
            ny: z(),
            nz: z(),
            g: z(),
            redo: Vec::with_capacity(CHUNK),
        }
    }
}

impl Gonio {
    /// Traces photons `first..first + m` of incidence stream `stream` (one chunk, `m ≤ CHUNK`):
    /// in round r every photon still inside is at the same face (the lit face for even r).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(super) fn trace_chunk<const N: usize>(
        &self,
        fp: &FastPlate,
        tab: &[f32; TAB_NC * TAB_NU],
        bf: &BeamFrame,
        stream: u64,
        first: u64,
        m: usize,
        acc: &mut Acc,
        wf: &mut Wavefront,
    ) {
        self.seed_beam::<N>(bf, stream, first, m, wf);
        let mut n = m;
        let mut lost = 0.0f64;
        for round in 0..self.setup.max_interactions {
            if n == 0 {
                break;
            }
            acc.interactions += n as u64;
            let top = round % 2 == 0;
            let face = if top { &fp.front } else { &fp.back };
            draw_round_numbers(face, wf, n);
            interact_round::<N>(face, fp, tab, top, wf, n);
            n = self.exit_and_compact(fp, face.is_polished(), top, wf, n, acc, &mut lost);
        }
        // beyond the interaction limit
        for i in 0..n {
            lost += wf.w[i] as f64;
        }
        acc.lost += lost;
    }

    /// The beam: seeds the chunk's generators (photon j draws from `Rng` j of the stream) and
    /// draws the directions in the divergence cone, `N` at a time.
    #[inline(always)]
    fn seed_beam<const N: usize>(
        &self,
        bf: &BeamFrame,
        stream: u64,
        first: u64,
        m: usize,
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
        wf.rng.clear();
        for i in 0..m {
            let mut rng = streams.rng(first + i as u64);
            if div > 0.0 {
                wf.u1[i] = rng.next_f32();
                wf.u2[i] = rng.next_f32();
            }
            wf.w[i] = 1.0;
            wf.rng.push(rng);
        }
        for b in 0..m.div_ceil(N) {
            let s = b * N..b * N + N;
            let (dx, dy, dz) = if div > 0.0 {
                let ux = F::<N>::load(&wf.u1[s.clone()]);
                let om = F::<N>::load(&wf.u2[s.clone()]) * one_minus_cos;
                let r = (om * (2.0 - om)).max(F::splat(0.0)).sqrt();
                let (sn, cs) = wide::sincos_2pi(ux);
                let (rc, rs, k) = (r * cs, r * sn, 1.0 - om);
                (
                    e1.x * rc + e2.x * rs + k0.x * k,
                    e1.y * rc + e2.y * rs + k0.y * k,
                    e1.z * rc + e2.z * rs + k0.z * k,
                )
            } else {
                (F::splat(k0.x), F::splat(k0.y), F::splat(k0.z))
            };
            dx.store(&mut wf.dx[s.clone()]);
            dy.store(&mut wf.dy[s.clone()]);
            dz.store(&mut wf.dz[s]);
        }
    }

    /// Exit and tally, or traverse the plate (absorption) and compact the photons still
    /// inside to the front of the arrays; returns how many remain. Lost weight goes to `lost`.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn exit_and_compact(
        &self,
        fp: &FastPlate,
        polished: bool,
        top: bool,
        wf: &mut Wavefront,
        n: usize,
        acc: &mut Acc,
        lost: &mut f64,
    ) -> usize {
        let mut kept = 0;
        for i in 0..n {
            let mut w = wf.w[i];
            if !polished {
                let g = wf.g[i];
                if g.is_nan() || g <= 0.0 {
                    *lost += w as f64;
                    continue;
                }
                let w2 = w * g;
                *lost += (w - w2) as f64;
                w = w2;
            }
            let d = Vec3::new(wf.nx[i], wf.ny[i], wf.nz[i]);
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
            }
            wf.rng.swap(kept, i);
            wf.dx[kept] = d.x;
            wf.dy[kept] = d.y;
            wf.dz[kept] = d.z;
            wf.w[kept] = w;
            kept += 1;
        }
        kept
    }
}

/// The round's random numbers, per photon in the contract's order: one for a polished face,
/// three for a rough one; a dotted face's area choice takes the first and a rough part two more.
#[inline(always)]
fn draw_round_numbers(face: &FastSide, wf: &mut Wavefront, n: usize) {
    match face {
        FastSide::Plain(FastFace::Polished) => {
            for i in 0..n {
                wf.u0[i] = wf.rng[i].next_f32();
            }
        }
        FastSide::Plain(_) => {
            for i in 0..n {
                let rng = &mut wf.rng[i];
                wf.u0[i] = rng.next_f32();
                wf.u1[i] = rng.next_f32();
                wf.u2[i] = rng.next_f32();
            }
        }
        FastSide::Dotted { f, a, b } => {
            for i in 0..n {
                let rng = &mut wf.rng[i];
                let u = rng.next_f32();
                wf.u0[i] = u;
                let part = if dotted_choice(*f, u).0 { a } else { b };
                if !matches!(part, FastFace::Polished) {
                    wf.u1[i] = rng.next_f32();
                    wf.u2[i] = rng.next_f32();
                }
            }
        }
    }
}

/// The round's interaction, `N` photons at a time; the lanes a kernel flags (Beckmann tails,
/// normal incidence) are gathered into full blocks and redone with the full iteration.
#[inline(always)]
fn interact_round<const N: usize>(
    face: &FastSide,
    fp: &FastPlate,
    tab: &[f32; TAB_NC * TAB_NU],
    top: bool,
    wf: &mut Wavefront,
    n: usize,
) {
    let fr = fp.fresnel;
    for b in 0..n.div_ceil(N) {
        let s = b * N..b * N + N;
        let d = V3 {
            x: F::load(&wf.dx[s.clone()]),
            y: F::load(&wf.dy[s.clone()]),
            z: F::load(&wf.dz[s.clone()]),
        };
        let (u0, u1, u2) =
            (F::load(&wf.u0[s.clone()]), F::load(&wf.u1[s.clone()]), F::load(&wf.u2[s.clone()]));
        let (wi, g, redo) = interact_side_block::<N>(face, &fr, tab, top, d, u0, u1, u2, false);
        wi.x.store(&mut wf.nx[s.clone()]);
        wi.y.store(&mut wf.ny[s.clone()]);
        wi.z.store(&mut wf.nz[s.clone()]);
        g.store(&mut wf.g[s]);
        if redo.any() {
            for l in 0..N {
                if redo.get(l) && b * N + l < n {
                    wf.redo.push((b * N + l) as u16);
                }
            }
        }
    }
    for blk in wf.redo.chunks(N) {
        let mut g = [[0.0f32; N]; 6];
        for (l, &i) in blk.iter().enumerate() {
            let i = i as usize;
            for (c, a) in [&wf.dx, &wf.dy, &wf.dz, &wf.u0, &wf.u1, &wf.u2].into_iter().enumerate() {
                g[c][l] = a[i];
            }
        }
        let d = V3 { x: F(g[0]), y: F(g[1]), z: F(g[2]) };
        let (wi, w, _) = interact_side_block::<N>(face, &fr, tab, top, d, F(g[3]), F(g[4]), F(g[5]), true);
        for (l, &i) in blk.iter().enumerate() {
            let i = i as usize;
            (wf.nx[i], wf.ny[i], wf.nz[i], wf.g[i]) = (wi.x.0[l], wi.y.0[l], wi.z.0[l], w.0[l]);
        }
    }
    wf.redo.clear();
}
