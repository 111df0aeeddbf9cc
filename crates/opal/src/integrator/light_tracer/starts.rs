//! Path starts prepared [`W`] at a time for the wavefront ([`starts`]): the generators seeded
//! and their first numbers drawn in SIMD, triangle lights read as rows ([`LightRow`], 8×8
//! transposes) into [`start_lanes`] (the same bits as [`start_path`]), other lights through
//! `start_path`.
//!
//! Tests (`tests.rs`): the engine comparison (area and point lights) gives identical sums;
//! `simd_seeding_gives_the_scalar_generators`.

#[cfg(target_arch = "x86_64")]
use super::avx;
#[cfg(target_arch = "x86_64")]
use super::path::start_path;
#[cfg(target_arch = "x86_64")]
use super::wavefront::mask;
use super::wavefront::{W, cosine_hemisphere_lanes, each3, offset_lanes};
use crate::sampling::RngStream;
use crate::scene::Scene;

/// Offsets in a [`LightRow`]: the corners `p[k][c]` at `L_P + 3k + c`, then three floats each
/// for the frame's `s` and `t`, the normal, its `normalize_or_zero` (the ray offset's
/// direction) and the radiance, then `1 / area`.
const L_P: usize = 0;
const L_S: usize = 9;
const L_T: usize = 12;
const L_N: usize = 15;
const L_N_OFF: usize = 18;
const L_LE: usize = 21;
const L_INV_AREA: usize = 24;

/// A triangle light as the SIMD path starts need it: 32 floats (fields: the `L_*` offsets), so
/// that eight lanes' lights are read with 8×8 transposes ([`light_lanes`]).
#[derive(Clone, Copy)]
#[repr(C, align(64))]
pub(super) struct LightRow([f32; 32]);

/// The scene's lights for the path starts: one [`LightRow`] per light (zeros for lights that
/// are not triangles, whose paths start through [`start_path`]) and a zero row at the end.
pub(super) struct LightRows {
    rows: Vec<LightRow>,
    triangle: Vec<bool>,
}

pub(super) fn light_rows(scene: &Scene) -> LightRows {
    let mut rows = Vec::with_capacity(scene.lights.len() + 1);
    let mut triangle = Vec::with_capacity(scene.lights.len());
    for l in &scene.lights {
        let mut r = [0.0f32; 32];
        if let crate::light::Light::Triangle(t) = l {
            let f = t.frame();
            let n_off = t.n.normalize_or_zero();
            for c in 0..3 {
                for k in 0..3 {
                    r[L_P + 3 * k + c] = t.p[k][c];
                }
                r[L_S + c] = f.s[c];
                r[L_T + c] = f.t[c];
                r[L_N + c] = t.n[c];
                r[L_N_OFF + c] = n_off[c];
                r[L_LE + c] = t.radiance[c];
            }
            r[L_INV_AREA] = t.inv_area();
        }
        rows.push(LightRow(r));
        triangle.push(matches!(l, crate::light::Light::Triangle(_)));
    }
    rows.push(LightRow([0.0; 32]));
    LightRows { rows, triangle }
}

/// Inputs of [`start_lanes`]: per lane the chosen light's data and the position and direction
/// samples.
#[derive(Clone, Copy, Default)]
pub(super) struct StartIn {
    p: [[[f32; W]; 3]; 3],
    s: [[f32; W]; 3],
    t: [[f32; W]; 3],
    n: [[f32; W]; 3],
    n_off: [[f32; W]; 3],
    le: [[f32; W]; 3],
    inv_area: [f32; W],
    pmf: [f32; W],
    u_pos: [[f32; W]; 2],
    u_dir: [[f32; W]; 2],
}

/// Outputs: the offset ray, β, and `valid` = 0 where the sample carries nothing.
#[derive(Clone, Copy, Default)]
pub(super) struct StartOut {
    o: [[f32; W]; 3],
    d: [[f32; W]; 3],
    beta: [[f32; W]; 3],
    valid: [u32; W],
}

/// [`start_path`] for triangle lights on [`W`] lanes after the light choice: `sample_le`
/// (`square_to_uniform_triangle`, the corners' combination, `square_to_cosine_hemisphere`,
/// `Frame::to_world`, `pdf_dir = z/π`), the validity checks, `β = Le·(|d·n| / (pmf·pdf_pos·
/// pdf_dir))` and `spawn_ray`'s offset, with the same operations in the same order (selects for
/// branches), hence the same bits.
#[inline(always)]
pub(super) fn start_lanes(i: &StartIn) -> StartOut {
    use crate::fastmath::wide::F;
    type V = [F<W>; 3];
    let ld = |a: &[[f32; W]; 3]| -> V { [F(a[0]), F(a[1]), F(a[2])] };
    let zero = F::<W>::splat(0.0);
    // square_to_uniform_triangle
    let (b0, b1) = crate::fastmath::wide::square_to_uniform_triangle(F(i.u_pos[0]), F(i.u_pos[1]));
    // p0·(1 − b0 − b1) + p1·b0 + p2·b1
    let w0 = 1.0 - b0 - b1;
    let (p0, p1, p2) = (ld(&i.p[0]), ld(&i.p[1]), ld(&i.p[2]));
    let o: V = each3(|c| p0[c] * w0 + p1[c] * b0 + p2[c] * b1);
    let [dx, dy, z] = cosine_hemisphere_lanes(F(i.u_dir[0]), F(i.u_dir[1]));
    // Frame::to_world
    let (fs, ft, fnn) = (ld(&i.s), ld(&i.t), ld(&i.n));
    let dir: V = each3(|c| (fs[c] * dx + ft[c] * dy) + fnn[c] * z);
    let pdf_dir = z / std::f32::consts::PI;
    let (pmf, pdf_pos) = (F(i.pmf), F(i.inv_area));
    let valid = z.gt(zero) & pmf.gt(zero) & pdf_pos.gt(zero) & pdf_dir.gt(zero);
    let n = ld(&i.n);
    let cos = ((dir[0] * n[0] + dir[1] * n[1]) + dir[2] * n[2]).abs();
    let k = cos / (pmf * pdf_pos * pdf_dir);
    let le = ld(&i.le);
    let origin = offset_lanes(o, ld(&i.n_off), dir);
    let mut out = StartOut::default();
    for c in 0..3 {
        out.o[c] = origin[c].0;
        out.d[c] = dir[c].0;
        out.beta[c] = (le[c] * k).0;
    }
    out.valid = valid.0;
    out
}

/// Path starts prepared [`W`] at a time (structure of arrays): for the lanes in `valid`, the
/// emitted ray (offset), its weight β and the path's generator after the start's draws.
pub(super) struct StartBlock {
    pub(super) o: [[f32; W]; 3],
    pub(super) d: [[f32; W]; 3],
    pub(super) beta: [[f32; W]; 3],
    /// The generators (state, increment: see [`crate::sampling::Rng`]), as structure of arrays.
    pub(super) rng_state: [u64; W],
    pub(super) rng_inc: [u64; W],
    pub(super) valid: u32,
}

impl StartBlock {
    pub(super) fn new(stream: &RngStream) -> StartBlock {
        StartBlock {
            o: [[0.0; W]; 3],
            d: [[0.0; W]; 3],
            beta: [[0.0; W]; 3],
            rng_state: [stream.rng(0).state; W],
            rng_inc: [stream.rng(0).inc; W],
            valid: 0,
        }
    }
}

/// The path starts of the indices `range` (at most [`W`]), in order, into `out`; lane `l` is
/// valid where [`start_path`] gives a path (same paths, same bits: the generators seeded and
/// their first five numbers drawn eight at a time ([`avx::seed_lanes`], [`avx::next_f32_lanes`]),
/// triangle lights through [`start_lanes`], other lights through `start_path` itself).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
pub(super) fn starts(
    scene: &Scene,
    sampler: &crate::light::LightSampler,
    lights: &LightRows,
    stream: &RngStream,
    range: std::ops::Range<u64>,
    out: &mut StartBlock,
) {
    let (mut state, mut inc) = ([0u64; W], [0u64; W]);
    avx::seed_lanes(stream.base(), range.start, &mut state, &mut inc);
    // `start_path`'s draws: the light choice, then `u_pos` and `u_dir` (x before y)
    let all = (1u32 << W) - 1;
    let [u_light, p0, p1, d0, d1] = avx::draws::<5, 0>(&mut state, &inc, all);
    let mut inp = StartIn { u_pos: [p0, p1], u_dir: [d0, d1], ..StartIn::default() };
    let mut simd = 0u32;
    let mut scalar = 0u32;
    // (the lanes of other lights overwrite theirs)
    (out.rng_state, out.rng_inc) = (state, inc);
    // lanes without a triangle light read the zero row (their kernel output is not used)
    let mut row_of = [lights.rows.len() - 1; W];
    for (l, i) in range.enumerate() {
        let (li, pmf) = sampler.choose(u_light[l]);
        if !lights.triangle[li] {
            if let Some(st) = start_path(scene, sampler, stream.rng(i)) {
                for c in 0..3 {
                    out.o[c][l] = st.ray.o[c];
                    out.d[c][l] = st.ray.d[c];
                    out.beta[c][l] = st.beta[c];
                }
                (out.rng_state[l], out.rng_inc[l]) = (st.rng.state, st.rng.inc);
                scalar |= 1 << l;
            }
            continue;
        }
        row_of[l] = li;
        inp.pmf[l] = pmf;
        simd |= 1 << l;
    }
    light_lanes(&lights.rows, &row_of, &mut inp);
    let o = avx::start_kernel(&inp);
    let valid = simd & mask(|l| o.valid[l] != 0);
    avx::blend_lanes(&mut out.o, &o.o, valid);
    avx::blend_lanes(&mut out.d, &o.d, valid);
    avx::blend_lanes(&mut out.beta, &o.beta, valid);
    out.valid = valid | scalar;
}

/// The lights `rows[row_of[l]]` of the eight lanes into `inp` (three 8×8 transposes of the
/// rows' first 24 floats, `1 / area` per lane).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn light_lanes(rows: &[LightRow], row_of: &[usize; W], inp: &mut StartIn) {
    use std::arch::x86_64::*;
    let r: [&[f32; 32]; W] = std::array::from_fn(|l| &rows[row_of[l]].0);
    // SAFETY: floats 8h..8h + 8 (h < 3) of a 32-float row, unaligned loads.
    let chunk = |h: usize| -> [__m256; 8] {
        std::array::from_fn(|l| unsafe { _mm256_loadu_ps(r[l].as_ptr().add(8 * h)) })
    };
    let (a, b, c) = (
        crate::simd::transpose8(chunk(0)),
        crate::simd::transpose8(chunk(1)),
        crate::simd::transpose8(chunk(2)),
    );
    let field = |k: usize| {
        if k < 8 {
            a[k]
        } else if k < 16 {
            b[k - 8]
        } else {
            c[k - 16]
        }
    };
    // SAFETY: 8 floats, unaligned store.
    let st = |d: &mut [f32; W], k: usize| unsafe { _mm256_storeu_ps(d.as_mut_ptr(), field(k)) };
    for ch in 0..3 {
        for k in 0..3 {
            st(&mut inp.p[k][ch], L_P + 3 * k + ch);
        }
        st(&mut inp.s[ch], L_S + ch);
        st(&mut inp.t[ch], L_T + ch);
        st(&mut inp.n[ch], L_N + ch);
        st(&mut inp.n_off[ch], L_N_OFF + ch);
        st(&mut inp.le[ch], L_LE + ch);
    }
    for (a, r) in inp.inv_area.iter_mut().zip(r) {
        *a = r[L_INV_AREA];
    }
}
