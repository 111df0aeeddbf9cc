//! The SIMD interaction kernels of the fast loop, `N` lanes at a time: visible normal (GGX by
//! spherical caps, Beckmann from a quantile table plus Newton), Fresnel choice, reflection or
//! refraction and Smith G1, branch-free. Lane by lane they return the bits of the scalar code
//! beside them (`scalar.rs`; tested by `fast::tests::simd_kernels_match_scalar_code`).

use super::{FastFace, FastSide};
use crate::bsdf::microfacet::beckmann::{INV_SQRT_PI_F32, TAB_NC, TAB_NU};
use crate::fastmath::Fresnel;
use crate::fastmath::wide::{self, F, M};

/// Three lanes-of-f32 (a direction per lane).
#[derive(Clone, Copy)]
pub(super) struct V3<const N: usize> {
    pub(super) x: F<N>,
    pub(super) y: F<N>,
    pub(super) z: F<N>,
}

impl<const N: usize> V3<N> {
    #[inline(always)]
    fn dot(self, o: Self) -> F<N> {
        (self.x * o.x) + (self.y * o.y) + (self.z * o.z)
    }
    /// glam's `normalize` (v · (1/|v|)), same bits.
    #[inline(always)]
    fn normalize(self) -> Self {
        let r = 1.0 / self.dot(self).sqrt();
        V3 { x: self.x * r, y: self.y * r, z: self.z * r }
    }
    #[inline(always)]
    fn scale(self, s: F<N>) -> Self {
        V3 { x: self.x * s, y: self.y * s, z: self.z * s }
    }
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        V3 { x: self.x - o.x, y: self.y - o.y, z: self.z - o.z }
    }
    #[inline(always)]
    fn neg_where(self, m: M<N>) -> Self {
        V3 { x: m.neg_where(self.x), y: m.neg_where(self.y), z: m.neg_where(self.z) }
    }
    #[inline(always)]
    fn select(m: M<N>, a: Self, b: Self) -> Self {
        V3 { x: m.select(a.x, b.x), y: m.select(a.y, b.y), z: m.select(a.z, b.z) }
    }
    /// World ↔ local frame of a face (the bottom face is the rotation by π about x).
    #[inline(always)]
    fn flip_if_bottom(self, top: bool) -> Self {
        if top { self } else { V3 { x: self.x, y: -self.y, z: -self.z } }
    }
}

/// GGX visible normal (`Ggx::sample_visible`), lane by lane.
#[inline(always)]
fn ggx_visible<const N: usize>(alpha: f32, wo: V3<N>, u1: F<N>, u2: F<N>) -> V3<N> {
    let w = wo.neg_where(wo.z.lt(F::splat(0.0)));
    let v = V3 { x: alpha * w.x, y: alpha * w.y, z: w.z }.normalize();
    let (sp, cp) = wide::sincos_2pi(u1);
    let z = (1.0 - u2) * (1.0 + v.z) - v.z;
    let st = ((1.0 - z) * (1.0 + z)).max(F::splat(0.0)).sqrt();
    let h = V3 { x: st * cp + v.x, y: st * sp + v.y, z: z + v.z };
    V3 { x: alpha * h.x, y: alpha * h.y, z: h.z.max(F::splat(1e-7)) }.normalize()
}

/// Unnormalised CDF of the unit-roughness visible slope, `erfc(−x)/2 + tan θ e/(2√π)` with
/// `e = exp(−x²)` (as `slopes_core` evaluates it).
#[inline(always)]
fn slope_cdf<const N: usize>(x: F<N>, e: F<N>, tan: F<N>) -> F<N> {
    let er = wide::erfc_pos_with_exp(x.abs(), e);
    let h = x.lt(F::splat(0.0)).select(0.5 * er, 1.0 - 0.5 * er);
    h + 0.5 * tan * INV_SQRT_PI_F32 * e
}

/// Beckmann visible normal (`Beckmann::sample_visible` with `slopes_core`), lane by lane.
/// `full = false`: the first two safeguarded Newton steps from the table start exactly as the
/// scalar code takes them, and a mask of the lanes to redo with `full = true` (not converged
/// after two steps, or normal incidence); `full = true`: every lane through the whole
/// iteration as the scalar code runs it (the loop runs as long as one lane needs it).
#[inline(always)]
fn beckmann_visible<const N: usize>(
    alpha: f32,
    tab: &[f32; TAB_NC * TAB_NU],
    wo: V3<N>,
    u1: F<N>,
    u2: F<N>,
    full: bool,
) -> (V3<N>, M<N>) {
    let zero = F::splat(0.0);
    let w = wo.neg_where(wo.z.lt(zero));
    let r2 = w.x * w.x + w.y * w.y;
    let big = r2.gt(F::splat(1e-14));
    let r = r2.sqrt();
    let inv = 1.0 / r;
    let ca = big.select(w.x * inv, F::splat(1.0));
    let sa = big.select(w.y * inv, zero);
    let r = big.select(r, zero);
    let (ta, z) = (alpha * r, w.z);
    // slopes_core
    let u1 = u1.clamp(F::splat(1e-7), F::splat(1.0 - 6e-8));
    let u2 = u2.clamp(F::splat(1e-7), F::splat(1.0 - 6e-8));
    let y = wide::erfinv(2.0 * u2 - 1.0);
    let normal = ta.is_nan() | ta.lt(1e-6 * z);
    let inv = 1.0 / (ta * z);
    let tan = ta * ta * inv;
    let cot = z * z * inv;
    let target = cot.gt(F::splat(4.0)).select(u1, u1 * slope_cdf(cot, wide::exp(-cot * cot), tan));
    let fc = ta / (ta + z) * (TAB_NC - 1) as f32;
    let i = fc.to_i32().max(wide::I::splat(0)).min(wide::I::splat(TAB_NC as i32 - 2));
    let wc = fc - i.to_f32();
    let fu = u1 * (TAB_NU - 1) as f32;
    let j = fu.to_i32().max(wide::I::splat(0)).min(wide::I::splat(TAB_NU as i32 - 2));
    let wu = fu - j.to_f32();
    let mut x = [0.0f32; N];
    for (l, xl) in x.iter_mut().enumerate() {
        let k = i.0[l] as usize * TAB_NU + j.0[l] as usize;
        let (a0, a1, b0, b1) = (tab[k], tab[k + 1], tab[k + TAB_NU], tab[k + TAB_NU + 1]);
        let x0 = a0 + wu.0[l] * (a1 - a0);
        let x1 = b0 + wu.0[l] * (b1 - b0);
        *xl = x0 + wc.0[l] * (x1 - x0);
    }
    let (lo, hi) = (F::splat(-10.0), cot);
    let x = F(x).clamp(lo, hi);
    let (x, redo) = if full {
        // the whole safeguarded iteration, lanes leaving it as the scalar loop breaks
        let (mut lo, mut hi, mut x, mut res) = (lo, hi, x, x);
        let mut active = !normal;
        for _ in 0..12 {
            if !active.any() {
                break;
            }
            let e = wide::exp(-x * x);
            let f = slope_cdf(x, e, tan) - target;
            let pos = f.gt(zero);
            (lo, hi) = (pos.select(lo, x), pos.select(x, hi));
            let dens = (1.0 - x * tan) * INV_SQRT_PI_F32 * e;
            let dx = f / dens;
            let conv = active & dx.abs().le(1e-4 * (1.0 + x.abs()));
            res = conv.select(x - dx, res);
            active = active & !conv;
            let xn = x - dx;
            x = (xn.gt(lo) & xn.lt(hi)).select(xn, 0.5 * (lo + hi));
            let tight = active & (hi - lo).le(1e-6 * (1.0 + x.abs()));
            res = tight.select(x, res);
            active = active & !tight;
        }
        let res = active.select(x, res);
        (normal.select(wide::erfinv(2.0 * u1 - 1.0), res), M([0; N]))
    } else {
        // Newton step 1 (converged: done)
        let e = wide::exp(-x * x);
        let f = slope_cdf(x, e, tan) - target;
        let pos = f.gt(zero);
        let (lo, hi) = (pos.select(lo, x), pos.select(x, hi));
        let dens = (1.0 - x * tan) * INV_SQRT_PI_F32 * e;
        let dx = f / dens;
        let conv1 = dx.abs().le(1e-4 * (1.0 + x.abs()));
        let x1 = x - dx;
        // else the safeguarded iterate (bisection if Newton leaves the bracket) and step 2
        let x2 = (x1.gt(lo) & x1.lt(hi)).select(x1, 0.5 * (lo + hi));
        let tight = (hi - lo).le(1e-6 * (1.0 + x2.abs()));
        let e = wide::exp(-x2 * x2);
        let f = slope_cdf(x2, e, tan) - target;
        let dens = (1.0 - x2 * tan) * INV_SQRT_PI_F32 * e;
        let dx = f / dens;
        let conv2 = dx.abs().le(1e-4 * (1.0 + x2.abs()));
        let x = conv1.select(x1, tight.select(x2, x2 - dx));
        (x, normal | !(conv1 | tight | conv2))
    };
    let (xr, yr) = (ca * x - sa * y, sa * x + ca * y);
    (V3 { x: -alpha * xr, y: -alpha * yr, z: F::splat(1.0) }.normalize(), redo)
}

/// Which Smith G1 a rough face uses (with its α).
#[derive(Clone, Copy)]
enum G1 {
    Ggx(f32),
    BeckmannMitsuba(f32),
    Beckmann(f32),
}

/// `rough_sample` after the visible normal, lane by lane: new local direction and weight
/// factor (0 = lost).
#[inline(always)]
fn rough_finish<const N: usize>(fr: &Fresnel, wo: V3<N>, wm: V3<N>, uc: F<N>, g1: G1) -> (V3<N>, F<N>) {
    let zero = F::splat(0.0);
    let cos_om = wo.dot(wm);
    let ok = (cos_om * wo.z).gt(zero);
    let inside = cos_om.lt(zero);
    let c = cos_om.abs();
    let (f, ct, eta_rel) = wide::fresnel(fr, c, inside);
    let refl = uc.lt(f);
    let wr = wm.scale(2.0 * cos_om).sub(wo);
    let n = wm.neg_where(inside);
    let wt = n.scale(eta_rel * c - ct).sub(wo.scale(eta_rel));
    let wi = V3::select(refl, wr, wt);
    // lost unless a reflection stays on the side of wo and a refraction crosses
    let same_side = (wi.z * wo.z).gt(zero);
    let ok = ok & refl.eq(same_side) & !wi.z.eq(zero);
    let g = match g1 {
        G1::Ggx(a) => ggx_g1(a, wi, wm),
        G1::BeckmannMitsuba(a) => beckmann_g1_mitsuba(a, wi, wm),
        G1::Beckmann(a) => beckmann_g1_exact(a, wi, wm),
    };
    let ok = ok & g.gt(zero);
    (wi, ok.select(g, zero))
}

/// `Ggx::g1_fast`, lane by lane.
#[inline(always)]
fn ggx_g1<const N: usize>(alpha: f32, w: V3<N>, wm: V3<N>) -> F<N> {
    let zero = F::splat(0.0);
    let front = (w.dot(wm) * w.z).gt(zero);
    let z = w.z.abs();
    let a2r2 = alpha * alpha * (w.x * w.x + w.y * w.y);
    front.select(2.0 * z / (z + (z * z + a2r2).sqrt()), zero)
}

/// `Beckmann::g1_mitsuba`, lane by lane.
#[inline(always)]
fn beckmann_g1_mitsuba<const N: usize>(alpha: f32, w: V3<N>, wm: V3<N>) -> F<N> {
    let (zero, one) = (F::splat(0.0), F::splat(1.0));
    let front = (w.dot(wm) * w.z).gt(zero);
    let xy = alpha * alpha * (w.x * w.x + w.y * w.y);
    let a = w.z.abs() / xy.sqrt();
    let rat = (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a);
    let g = (xy.eq(zero) | a.ge(F::splat(1.6))).select(one, rat);
    front.select(g, zero)
}

/// `Beckmann::g1_fast`, lane by lane.
#[inline(always)]
fn beckmann_g1_exact<const N: usize>(alpha: f32, w: V3<N>, wm: V3<N>) -> F<N> {
    let (zero, one) = (F::splat(0.0), F::splat(1.0));
    let front = (w.dot(wm) * w.z).gt(zero);
    let c = w.z.abs();
    let s2 = (w.x * w.x + w.y * w.y).max(zero);
    let a = c / (alpha * s2.sqrt());
    let e = wide::exp(-a * a);
    let lambda = 0.5 * (e * INV_SQRT_PI_F32 / a - wide::erfc_pos_with_exp(a, e));
    let g = 1.0 / (1.0 + lambda.max(zero));
    let g = (s2.eq(zero) | a.gt(F::splat(4.0))).select(one, g);
    front.select(g, zero)
}

/// One block of `N` photons at a face: local outgoing direction from the world direction `d`,
/// interaction, new world direction and weight factor (0 = lost, 1 for polished faces), and
/// the lanes to redo with `full` = true (Beckmann: see `beckmann_visible`).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn interact_block<const N: usize>(
    face: &FastFace,
    fr: &Fresnel,
    tab: &[f32; TAB_NC * TAB_NU],
    top: bool,
    d: V3<N>,
    u0: F<N>,
    u1: F<N>,
    u2: F<N>,
    full: bool,
) -> (V3<N>, F<N>, M<N>) {
    let wo = V3 { x: -d.x, y: -d.y, z: -d.z }.flip_if_bottom(top);
    let none = M([0; N]);
    let (wi, g, redo) = match *face {
        FastFace::Polished => {
            let inside = wo.z.lt(F::splat(0.0));
            let (f, ct, eta_rel) = wide::fresnel(fr, wo.z.abs(), inside);
            let refl = u0.lt(f);
            let wr = V3 { x: -wo.x, y: -wo.y, z: wo.z };
            let ne = -eta_rel;
            let wt = V3 { x: ne * wo.x, y: ne * wo.y, z: inside.select(ct, -ct) };
            (V3::select(refl, wr, wt), F::splat(1.0), none)
        }
        FastFace::Ggx(g) => {
            let a = g.alpha;
            let wm = ggx_visible(a, wo, u1, u2);
            let (wi, w) = rough_finish(fr, wo, wm, u0, G1::Ggx(a));
            (wi, w, none)
        }
        FastFace::Beckmann { ndf, mitsuba_g1 } => {
            let a = ndf.alpha;
            let (wm, redo) = beckmann_visible(a, tab, wo, u1, u2, full);
            let (wi, w) = if mitsuba_g1 {
                rough_finish(fr, wo, wm, u0, G1::BeckmannMitsuba(a))
            } else {
                rough_finish(fr, wo, wm, u0, G1::Beckmann(a))
            };
            (wi, w, redo)
        }
    };
    (wi.flip_if_bottom(top), g, redo)
}

/// `interact_block` for a plate side: a dotted side runs both parts on every lane and keeps, lane
/// by lane, the one its area choice (`dotted_choice` of `u0`) picked; only the picked part's
/// lanes can ask for a redo.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(super) fn interact_side_block<const N: usize>(
    side: &FastSide,
    fr: &Fresnel,
    tab: &[f32; TAB_NC * TAB_NU],
    top: bool,
    d: V3<N>,
    u0: F<N>,
    u1: F<N>,
    u2: F<N>,
    full: bool,
) -> (V3<N>, F<N>, M<N>) {
    match side {
        FastSide::Plain(face) => interact_block(face, fr, tab, top, d, u0, u1, u2, full),
        FastSide::Dotted { f, a, b } => interact_dotted_block(*f, a, b, fr, tab, top, d, u0, u1, u2, full),
    }
}

/// The dotted arm of `interact_side_block`, kept out of line: inlining two more copies of the
/// whole interaction into the photon loop (per kernel width and instruction set) made the
/// crate's compilation many times slower. Out of line it is compiled for the baseline
/// instruction set (the same bits: the lane math is IEEE f32 without contraction).
#[allow(clippy::too_many_arguments)]
#[inline(never)]
fn interact_dotted_block<const N: usize>(
    f: f32,
    a: &FastFace,
    b: &FastFace,
    fr: &Fresnel,
    tab: &[f32; TAB_NC * TAB_NU],
    top: bool,
    d: V3<N>,
    u0: F<N>,
    u1: F<N>,
    u2: F<N>,
    full: bool,
) -> (V3<N>, F<N>, M<N>) {
    let pick_a = u0.lt(F::splat(f));
    let ur = pick_a.select(u0 / f, (u0 - f) / (1.0 - f)).min(F::splat(1.0 - f32::EPSILON / 2.0));
    let (wa, ga, ra) = interact_block(a, fr, tab, top, d, ur, u1, u2, full);
    let (wb, gb, rb) = interact_block(b, fr, tab, top, d, ur, u1, u2, full);
    (V3::select(pick_a, wa, wb), pick_a.select(ga, gb), (pick_a & ra) | (!pick_a & rb))
}
