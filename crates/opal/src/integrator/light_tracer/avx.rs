//! The vector steps of the [`Wavefront`](super::wavefront::Wavefront) in AVX2 (x86-64 only):
//! the same IEEE operations in the same order as the scalar code they mirror (named on each
//! function), hence the same bits.
//!
//! Tests (`tests.rs`): `simd_generators_draw_the_scalar_numbers`,
//! `simd_seeding_gives_the_scalar_generators`, `bilinear_lanes_give_the_bits_of_texture_eval`,
//! and the identical sums of the wavefront and the one-path-at-a-time engine; (`tests_lanes.rs`)
//! `lane_roulette_draws_and_scales_like_the_scalar_one`,
//! `lane_masks_and_counters_match_the_scalar_loops`, `several_draws_at_once_are_the_scalar_numbers`.

use super::starts::{StartIn, StartOut, start_lanes};
use super::wavefront::{
    DepositLanes, FLAG_BITMAP, FLAG_TWO_SIDED, ROW_FACTOR, ROW_FLAGS, ROW_HAS_N, ROW_KD, ROW_N, ROW_NG,
    ROW_NG_OFF, ROW_SHAPE, ROW_SIZE, ROW_UV,
};
use super::wavefront::{Row, ScatterIn, ScatterOut, VertexLanes, W, scatter_lanes};
use crate::accel::packet::{PacketHits, RayPacket};
use std::arch::x86_64::*;

#[inline(always)]
fn ld(a: &[f32; W]) -> __m256 {
    // SAFETY: 8 floats, unaligned load.
    unsafe { _mm256_loadu_ps(a.as_ptr()) }
}
#[inline(always)]
fn st(a: &mut [f32; W], v: __m256) {
    // SAFETY: 8 floats, unaligned store.
    unsafe { _mm256_storeu_ps(a.as_mut_ptr(), v) }
}
#[inline(always)]
fn st_mask(a: &mut [u32; W], v: __m256) {
    // SAFETY: 8 u32, unaligned store.
    unsafe { _mm256_storeu_ps(a.as_mut_ptr().cast(), v) }
}
/// Lane `l` all ones iff bit `l` of `b`.
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn lane_mask(b: u32) -> __m256 {
    let one = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
    _mm256_castsi256_ps(_mm256_cmpeq_epi32(_mm256_and_si256(_mm256_set1_epi32(b as i32), one), one))
}
#[target_feature(enable = "avx2")]
#[inline]
fn bits(m: __m256) -> u32 {
    _mm256_movemask_ps(m) as u32
}

/// The lanes whose `a[l] ≥ k`.
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn at_least(a: &[i32; W], k: i32) -> u32 {
    // SAFETY: 8 i32, unaligned load.
    let v = unsafe { _mm256_loadu_si256(a.as_ptr().cast()) };
    // a ≥ k ⇔ ¬(k > a)
    !bits(_mm256_castsi256_ps(_mm256_cmpgt_epi32(_mm256_set1_epi32(k), v))) & 0xff
}

/// `a[l]` (as `u32`) in the lanes of `m`, 0 in the others.
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn select_u32(a: &[i32; W], m: u32) -> [u32; W] {
    let mut out = [0u32; W];
    // SAFETY: 8 i32 / u32, unaligned load and store.
    unsafe {
        let v = _mm256_and_si256(_mm256_loadu_si256(a.as_ptr().cast()), _mm256_castps_si256(lane_mask(m)));
        _mm256_storeu_si256(out.as_mut_ptr().cast(), v);
    }
    out
}

/// `a[l] += 1` in the lanes of `m`.
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn increment(a: &mut [i32; W], m: u32) {
    // SAFETY: 8 i32, unaligned load and store.
    unsafe {
        let v = _mm256_loadu_si256(a.as_ptr().cast());
        // all ones (−1) in the lanes of `m`: subtracting it adds one
        let v = _mm256_sub_epi32(v, _mm256_castps_si256(lane_mask(m)));
        _mm256_storeu_si256(a.as_mut_ptr().cast(), v);
    }
}

/// `dst[c][l] = src[c][l]` in the lanes `l` of `m` (three channels).
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn blend_lanes(dst: &mut [[f32; W]; 3], src: &[[f32; W]; 3], m: u32) {
    let lm = lane_mask(m);
    for (d, s) in dst.iter_mut().zip(src) {
        st(d, _mm256_blendv_ps(ld(d), ld(s), lm));
    }
}

/// [`crate::sampling::Rng::next_f32`] of the eight generators `(state, inc)` whose lane is in
/// `m` (the others keep their state; their numbers are meaningless): the same 64-bit
/// arithmetic (the product modulo 2⁶⁴ from three 32×32-bit products), output permutation
/// and conversion, hence the same numbers.
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn next_f32_lanes(state: &mut [u64; W], inc: &[u64; W], m: u32) -> [f32; W] {
    let [u] = draws::<1, 0>(state, inc, m);
    u
}

/// [`draws`]: `K` numbers of the generators in `m`, after `SKIP` draws whose numbers are not
/// needed (the states still advance).
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn draws<const K: usize, const SKIP: usize>(
    state: &mut [u64; W],
    inc: &[u64; W],
    m: u32,
) -> [[f32; W]; K] {
    let mult = crate::sampling::Rng::MULT;
    let (m_lo, m_hi) = (_mm256_set1_epi64x(mult as i64), _mm256_set1_epi64x((mult >> 32) as i64));
    let low32 = _mm256_set1_epi64x(0xffff_ffff);
    // one step of the generator: state · MULT + inc (mod 2⁶⁴)
    let step = |old: __m256i, inc: __m256i| {
        let lo_lo = _mm256_mul_epu32(old, m_lo);
        let cross = _mm256_add_epi64(
            _mm256_mul_epu32(_mm256_srli_epi64::<32>(old), m_lo),
            _mm256_mul_epu32(old, m_hi),
        );
        _mm256_add_epi64(_mm256_add_epi64(lo_lo, _mm256_slli_epi64::<32>(cross)), inc)
    };
    // the output of a state: ((old >> 18) ^ old) >> 27, low 32 bits, rotated right by old >> 59
    let output = |old: __m256i| {
        let x = _mm256_and_si256(
            _mm256_srli_epi64::<27>(_mm256_xor_si256(_mm256_srli_epi64::<18>(old), old)),
            low32,
        );
        let rot = _mm256_srli_epi64::<59>(old);
        let left = _mm256_sllv_epi64(x, _mm256_sub_epi64(_mm256_set1_epi64x(32), rot));
        _mm256_or_si256(_mm256_srlv_epi64(x, rot), _mm256_and_si256(left, low32))
    };
    let mut out = [[_mm256_setzero_si256(); 2]; K];
    for h in 0..2 {
        // SAFETY: 4 u64 of an 8-u64 array, unaligned loads.
        let old = unsafe { _mm256_loadu_si256(state.as_ptr().add(4 * h).cast()) };
        let inc = unsafe { _mm256_loadu_si256(inc.as_ptr().add(4 * h).cast()) };
        let mut s = old;
        for _ in 0..SKIP {
            s = step(s, inc);
        }
        for o in out.iter_mut() {
            o[h] = output(s);
            s = step(s, inc);
        }
        let bits = _mm256_set1_epi64x(((m >> (4 * h)) & 0xf) as i64);
        let one = _mm256_setr_epi64x(1, 2, 4, 8);
        let take = _mm256_cmpeq_epi64(_mm256_and_si256(bits, one), one);
        // SAFETY: as above, store.
        unsafe {
            _mm256_storeu_si256(state.as_mut_ptr().add(4 * h).cast(), _mm256_blendv_epi8(old, s, take))
        };
    }
    // the low 32 bits of the eight 64-bit results, in lane order
    let pick = _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6);
    out.map(|[lo, hi]| {
        let (a, b) = (_mm256_permutevar8x32_epi32(lo, pick), _mm256_permutevar8x32_epi32(hi, pick));
        let u = _mm256_blend_epi32::<0xf0>(a, b);
        let f =
            _mm256_mul_ps(_mm256_cvtepi32_ps(_mm256_srli_epi32::<8>(u)), _mm256_set1_ps(1.0 / 16_777_216.0));
        let mut r = [0.0; W];
        st(&mut r, f);
        r
    })
}

/// The products modulo 2⁶⁴ of four 64-bit lanes by `c` (from three 32×32-bit products).
#[target_feature(enable = "avx2")]
#[inline]
fn mul64(x: __m256i, c: u64) -> __m256i {
    let (c_lo, c_hi) = (_mm256_set1_epi64x(c as u32 as i64), _mm256_set1_epi64x((c >> 32) as i64));
    let cross =
        _mm256_add_epi64(_mm256_mul_epu32(_mm256_srli_epi64::<32>(x), c_lo), _mm256_mul_epu32(x, c_hi));
    _mm256_add_epi64(_mm256_mul_epu32(x, c_lo), _mm256_slli_epi64::<32>(cross))
}

/// [`crate::sampling::mix64`] of four 64-bit lanes.
#[target_feature(enable = "avx2")]
#[inline]
fn mix64_lanes(z: __m256i) -> __m256i {
    let z = mul64(_mm256_xor_si256(z, _mm256_srli_epi64::<30>(z)), 0xbf58_476d_1ce4_e5b9);
    let z = mul64(_mm256_xor_si256(z, _mm256_srli_epi64::<27>(z)), 0x94d0_49bb_1331_11eb);
    _mm256_xor_si256(z, _mm256_srli_epi64::<31>(z))
}

/// The generators `(state, inc)` of work items `first .. first + 8` of the stream whose
/// [`RngStream::base`](crate::sampling::RngStream) is `base`: `RngStream::rng` (`mix64` of
/// `base + index`, `Rng::from_hash`) with the same 64-bit arithmetic, hence the same
/// generators.
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn seed_lanes(base: u64, first: u64, state: &mut [u64; W], inc: &mut [u64; W]) {
    let mult = crate::sampling::Rng::MULT;
    for h in 0..2 {
        let i0 = first.wrapping_add(4 * h as u64);
        let index = _mm256_setr_epi64x(
            i0 as i64,
            i0.wrapping_add(1) as i64,
            i0.wrapping_add(2) as i64,
            i0.wrapping_add(3) as i64,
        );
        let hash = mix64_lanes(_mm256_add_epi64(_mm256_set1_epi64x(base as i64), index));
        // inc = (mix64(hash ^ K) << 1) | 1; from state 0 one step gives inc, then + hash, a step
        let k = _mm256_set1_epi64x(crate::sampling::Rng::INC_KEY as i64);
        let i = _mm256_or_si256(
            _mm256_slli_epi64::<1>(mix64_lanes(_mm256_xor_si256(hash, k))),
            _mm256_set1_epi64x(1),
        );
        let s = _mm256_add_epi64(mul64(_mm256_add_epi64(i, hash), mult), i);
        // SAFETY: 4 u64 of an 8-u64 array, unaligned stores.
        unsafe {
            _mm256_storeu_si256(state.as_mut_ptr().add(4 * h).cast(), s);
            _mm256_storeu_si256(inc.as_mut_ptr().add(4 * h).cast(), i);
        }
    }
}

/// `vertex`'s pending weights `w = kd_pi · ratio` (`Spectrum * f32`) of the lanes in `pend`:
/// `β *= w` there; returns the lanes whose `w` is black.
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn pending_weights(
    beta: &mut [[f32; W]; 3],
    kd_pi: &[[f32; W]; 3],
    ratio: &[f32; W],
    pend: u32,
) -> u32 {
    let zero = _mm256_setzero_ps();
    let r = ld(ratio);
    let pm = lane_mask(pend);
    let mut black = pm;
    for c in 0..3 {
        let w = _mm256_mul_ps(ld(&kd_pi[c]), r);
        black = _mm256_and_ps(black, _mm256_cmp_ps::<_CMP_EQ_OQ>(w, zero));
        let b = ld(&beta[c]);
        st(&mut beta[c], _mm256_blendv_ps(b, _mm256_mul_ps(b, w), pm));
    }
    bits(black)
}

/// The hit triangles' data (rows `prim`), barycentrics `b0 = 1 − b1 − b2`, uvs
/// `uv0·b0 + uv1·b1 + uv2·b2` and sides `(−d)·ng > 0` of [`W`] vertices (as `vertex`), and the
/// kernel's inputs except the direction samples.
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn vertices(
    rows: &[Row],
    prim: &[u32; W],
    hits: &PacketHits,
    d: &[[f32; W]; 3],
    any_normals: bool,
    inp: &mut ScatterIn,
) -> VertexLanes {
    assert!(prim.iter().all(|&p| (p as usize) < rows.len()), "triangle index out of range");
    let base = rows.as_ptr().cast::<f32>();
    // The first 16 floats of the eight rows, transposed: `head[k]` = field k per lane.
    let head: [__m256; 16] = {
        // SAFETY: every row index is < rows.len() (asserted above); a row holds 32 floats.
        let half = |h: usize| -> [__m256; 8] {
            std::array::from_fn(|l| unsafe { _mm256_loadu_ps(base.add(32 * prim[l] as usize + 8 * h)) })
        };
        let (a, b) = (crate::simd::transpose8(half(0)), crate::simd::transpose8(half(1)));
        std::array::from_fn(|k| if k < 8 { a[k] } else { b[k - 8] })
    };
    let field = |k: usize| head[k];
    let ng = [field(ROW_NG), field(ROW_NG + 1), field(ROW_NG + 2)];
    let (b1, b2) = (ld(&hits.b1), ld(&hits.b2));
    let b0 = _mm256_sub_ps(_mm256_sub_ps(_mm256_set1_ps(1.0), b1), b2);
    let interp = |k: usize| {
        let a = _mm256_add_ps(_mm256_mul_ps(field(k), b0), _mm256_mul_ps(field(k + 2), b1));
        _mm256_add_ps(a, _mm256_mul_ps(field(k + 4), b2))
    };
    let (u, v) = (interp(ROW_UV), interp(ROW_UV + 1));
    let neg = |x| _mm256_xor_ps(x, _mm256_set1_ps(-0.0));
    let dot = _mm256_add_ps(
        _mm256_add_ps(_mm256_mul_ps(neg(ld(&d[0])), ng[0]), _mm256_mul_ps(neg(ld(&d[1])), ng[1])),
        _mm256_mul_ps(neg(ld(&d[2])), ng[2]),
    );
    let front = bits(_mm256_cmp_ps::<_CMP_GT_OQ>(dot, _mm256_setzero_ps()));
    inp.t = hits.t;
    for (c, &n) in ng.iter().enumerate() {
        st(&mut inp.ng[c], n);
        st(&mut inp.ng_off[c], field(ROW_NG_OFF + c));
    }
    if any_normals {
        // SAFETY: 8 u32, unaligned load.
        let idx = _mm256_slli_epi32::<5>(unsafe { _mm256_loadu_si256(prim.as_ptr().cast()) });
        // SAFETY: every lane's row index is < rows.len() (asserted above) and k < 32, so
        // each gathered float lies inside `rows`.
        let gather = |k: usize| unsafe { _mm256_i32gather_ps::<4>(base.add(k), idx) };
        for k in 0..3 {
            for c in 0..3 {
                st(&mut inp.n[k][c], gather(ROW_N + 3 * k + c));
            }
        }
        st_mask(&mut inp.has_n, gather(ROW_HAS_N));
    }
    let flags = _mm256_castps_si256(field(ROW_FLAGS));
    let flag = |f: u32| {
        let f = _mm256_set1_epi32(f as i32);
        _mm256_castsi256_ps(_mm256_cmpeq_epi32(_mm256_and_si256(flags, f), f))
    };
    st_mask(&mut inp.two_sided, flag(FLAG_TWO_SIDED));
    st(&mut inp.b[0], b0);
    st(&mut inp.b[1], b1);
    st(&mut inp.b[2], b2);
    let mut out =
        VertexLanes { uv: [[0.0; W]; 2], kd_pi: [[0.0; W]; 3], front, bitmap: bits(flag(FLAG_BITMAP)) };
    st(&mut out.uv[0], u);
    st(&mut out.uv[1], v);
    for c in 0..3 {
        st(&mut out.kd_pi[c], field(ROW_KD + c));
    }
    out
}

/// The texel index `3·(y·w + x)` and the rounded units `round(β_c · factor)` of the
/// deposits of [`W`] vertices of triangles `prim` at `uv` (as [`super::path::deposit`]: the f32
/// products `u·w`, the truncation clamped to the map, the f64 products, ties away from
/// zero, truncation), their sums of magnitudes and the map number `2·shape + direct` (direct:
/// `depth == 1`). `small` = the lanes whose three rounded values are below 2³¹ in magnitude
/// (so finite, and the conversions to integers here are exact: they are up to 2⁵¹); the
/// others are left to `deposit`. `target` = the lanes whose triangle deposits.
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn deposit_values(
    rows: &[Row],
    prim: &[u32; W],
    uv: &[[f32; W]; 2],
    beta: &[[f32; W]; 3],
    depth: &[i32; W],
) -> DepositLanes {
    // the last 8 floats of the eight rows, transposed (loads and shuffles: cheaper than
    // gathers, see `vertices`)
    let tail = crate::simd::transpose8(std::array::from_fn(|l| {
        let r = &rows[prim[l] as usize].0;
        // SAFETY: 8 floats of a 32-float row, unaligned load.
        unsafe { _mm256_loadu_ps(r.as_ptr().add(24)) }
    }));
    let field = |k: usize| tail[k - 24];
    let (w, h) = (field(ROW_SIZE), field(ROW_SIZE + 1));
    let zero = _mm256_setzero_ps();
    let one = _mm256_set1_ps(1.0);
    // `(u·w) as i64` clamped to [0, w − 1]: a NaN product gives 0 (max picks its second
    // operand), larger values w − 1, negative ones 0.
    let texel = |u: __m256, n: __m256| {
        let x = _mm256_min_ps(_mm256_max_ps(_mm256_mul_ps(u, n), zero), _mm256_sub_ps(n, one));
        _mm256_cvttps_epi32(x)
    };
    let (x, y) = (texel(ld(&uv[0]), w), texel(ld(&uv[1]), h));
    let wi = _mm256_cvttps_epi32(w);
    let index = _mm256_mullo_epi32(_mm256_add_epi32(_mm256_mullo_epi32(y, wi), x), _mm256_set1_epi32(3));
    let mut out = DepositLanes {
        index: [0; W],
        value: [[0; W]; 3],
        units: [0; W],
        map: [0; W],
        small: u32::MAX,
        target: 0,
    };
    // SAFETY: 8 i32, unaligned load.
    let direct =
        _mm256_cmpeq_epi32(unsafe { _mm256_loadu_si256(depth.as_ptr().cast()) }, _mm256_set1_epi32(1));
    let shape = _mm256_castps_si256(field(ROW_SHAPE));
    out.target = !bits(_mm256_castsi256_ps(shape)) & 0xff;
    // 2·shape + direct (`direct` is −1 where true)
    let map = _mm256_sub_epi32(_mm256_add_epi32(shape, shape), direct);
    // SAFETY: 8 i32, unaligned stores.
    unsafe {
        _mm256_storeu_si256(out.map.as_mut_ptr().cast(), map);
        _mm256_storeu_si256(out.index.as_mut_ptr().cast(), index);
    }
    let limit32 = _mm256_set1_pd(2_147_483_648.0); // 2³¹
    let magic = _mm256_set1_pd(6_755_399_441_055_744.0); // 1.5·2⁵²
    let sign = _mm256_set1_pd(-0.0);
    let half = _mm256_set1_pd(0.5);
    // exact integers of f64 lanes below 2⁵¹ in magnitude
    let to_int = |t: __m256d| {
        _mm256_sub_epi64(_mm256_castpd_si256(_mm256_add_pd(t, magic)), _mm256_castpd_si256(magic))
    };
    // the low 32 bits of four 64-bit lanes
    let low = |v: __m256i| {
        _mm256_castsi256_si128(_mm256_permutevar8x32_epi32(v, _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6)))
    };
    // the f64 factors: the low and high halves of lanes 0, 1 | 4, 5 and 2, 3 | 6, 7
    // interleaved, then lanes 0–3 and 4–7
    let (f_lo, f_hi) = (field(ROW_FACTOR), field(ROW_FACTOR + 1));
    let (a, b) = (_mm256_unpacklo_ps(f_lo, f_hi), _mm256_unpackhi_ps(f_lo, f_hi));
    let factors = [
        _mm256_castps_pd(_mm256_permute2f128_ps::<0x20>(a, b)),
        _mm256_castps_pd(_mm256_permute2f128_ps::<0x31>(a, b)),
    ];
    for (half_lanes, &f) in factors.iter().enumerate() {
        let mut units = _mm256_setzero_si256();
        for (c, beta_c) in beta.iter().enumerate() {
            // SAFETY: 4 floats of an 8-float array.
            let b = unsafe { _mm_loadu_ps(beta_c.as_ptr().add(4 * half_lanes)) };
            let q = _mm256_mul_pd(_mm256_cvtps_pd(b), f);
            let r = _mm256_add_pd(q, _mm256_or_pd(half, _mm256_and_pd(q, sign)));
            let fits = _mm256_cmp_pd::<_CMP_LT_OQ>(_mm256_andnot_pd(sign, r), limit32);
            let big = (!_mm256_movemask_pd(fits) & 0xf) as u32;
            out.small &= !(big << (4 * half_lanes));
            let t = _mm256_round_pd::<{ _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC }>(r);
            units = _mm256_add_epi64(units, to_int(_mm256_andnot_pd(sign, t)));
            // SAFETY: 4 i32 of an 8-i32 array.
            unsafe { _mm_storeu_si128(out.value[c].as_mut_ptr().add(4 * half_lanes).cast(), low(to_int(t))) };
        }
        // SAFETY: 4 u64 of an 8-u64 array.
        unsafe { _mm256_storeu_si256(out.units.as_mut_ptr().add(4 * half_lanes).cast(), units) };
    }
    out.small &= (1 << W) - 1;
    out
}

/// Scatters the lanes in `alive` of two sets ([`scatter_lanes`]; `normals` = some triangle
/// of the scene has corner normals) and moves their rays to the sampled directions; returns
/// the lanes whose sample is valid and writes their `ratio`. Two sets in one kernel: their
/// two dependency chains (divisions, square roots, the sine polynomial) overlap.
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn scatter2(
    rays: [&mut RayPacket; 2],
    inp: [&ScatterIn; 2],
    alive: [u32; 2],
    ratio: [&mut [f32; W]; 2],
    normals: bool,
) -> [u32; 2] {
    let out = if normals {
        kernel2::<true>([&*rays[0], &*rays[1]], inp)
    } else {
        kernel2::<false>([&*rays[0], &*rays[1]], inp)
    };
    let mut valid_out = [0; 2];
    for (((rays, out), (alive, ratio)), v) in
        rays.into_iter().zip(out).zip(alive.into_iter().zip(ratio)).zip(&mut valid_out)
    {
        // SAFETY: 8 u32, unaligned load.
        let valid = unsafe { _mm256_loadu_ps(out.valid.as_ptr().cast()) };
        let am = _mm256_and_ps(lane_mask(alive), valid);
        for c in 0..3 {
            let o = _mm256_blendv_ps(ld(&rays.o[c]), ld(&out.o[c]), am);
            st(&mut rays.o[c], o);
            let d = _mm256_blendv_ps(ld(&rays.d[c]), ld(&out.d[c]), am);
            st(&mut rays.d[c], d);
        }
        *ratio = out.ratio;
        *v = bits(am);
    }
    valid_out
}

/// [`scatter_lanes`] of two sets compiled with AVX2, kept out of line (the lane loops
/// vectorise reliably in a function of their own).
#[target_feature(enable = "avx2")]
#[inline(never)]
fn kernel2<const NORMALS: bool>(rays: [&RayPacket; 2], inp: [&ScatterIn; 2]) -> [ScatterOut; 2] {
    [scatter_lanes::<NORMALS>(rays[0], inp[0]), scatter_lanes::<NORMALS>(rays[1], inp[1])]
}

/// [`start_lanes`] compiled with AVX2, kept out of line like [`kernel2`].
#[target_feature(enable = "avx2")]
#[inline(never)]
pub(super) fn start_kernel(inp: &StartIn) -> StartOut {
    start_lanes(inp)
}

/// `f32::max(x, y)` on eight lanes as the scalar is compiled (`maxnum`: `y` where `x` is NaN,
/// else `maxps(y, x)`, which gives `x` where `y` is NaN and on ties).
#[target_feature(enable = "avx2")]
#[inline]
fn max_num(x: __m256, y: __m256) -> __m256 {
    _mm256_blendv_ps(_mm256_max_ps(y, x), y, _mm256_cmp_ps::<_CMP_UNORD_Q>(x, x))
}

/// The Russian roulette of the lanes in `m` as `trace_path` draws it: `q =`
/// [`survival`](super::path::survival)`(β, b0)` (`max_component` with `f32::max`, the
/// division, `min(0.95)`, zero unless `b0 > 0`), one [`crate::sampling::Rng::next_f32`], the
/// path ends where `u ≥ q`, else `β *= 1 / q` (`Spectrum * f32`). The same operations per lane,
/// hence the same bits; returns the lanes that end.
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn roulette(
    beta: &mut [[f32; W]; 3],
    b0: &[f32; W],
    state: &mut [u64; W],
    inc: &[u64; W],
    m: u32,
) -> u32 {
    if m == 0 {
        return 0;
    }
    let u = ld(&next_f32_lanes(state, inc, m));
    let b = [ld(&beta[0]), ld(&beta[1]), ld(&beta[2])];
    let zero = _mm256_setzero_ps();
    let b0 = ld(b0);
    let q = _mm256_min_ps(_mm256_div_ps(max_num(max_num(b[0], b[1]), b[2]), b0), _mm256_set1_ps(0.95));
    let q = _mm256_blendv_ps(zero, q, _mm256_cmp_ps::<_CMP_GT_OQ>(b0, zero));
    let end = m & bits(_mm256_cmp_ps::<_CMP_GE_OQ>(u, q));
    let keep = lane_mask(m & !end);
    let s = _mm256_div_ps(_mm256_set1_ps(1.0), q);
    for (c, bc) in b.into_iter().enumerate() {
        st(&mut beta[c], _mm256_blendv_ps(bc, _mm256_mul_ps(bc, s), keep));
    }
    end
}

// a bitmap's pixels are contiguous f32 triples (`bilinear_lanes` reads them as floats)
const _: () = assert!(std::mem::size_of::<crate::spectrum::Spectrum>() == 12);

/// `Texture::eval(uv) · INV_PI` of a bilinear bitmap `img` (`texture.rs`, `lookup`: the f32
/// products `u·w − 0.5`, `floor`, the weights `1 − w₁` and their products, the four corners
/// weighted and added in the same order, then `· INV_PI`) for the lanes in `m` whose four
/// corners lie inside the image (no wrapping: `lookup`'s wrap modes leave such indices alone),
/// written to `kd_pi`; returns those lanes. The others (non-finite `uv`, a corner outside the
/// image, an image under 2×2 or beyond 2²⁴ texels wide or high or 2³¹ floats) are left to
/// `Texture::eval`.
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn bilinear_lanes(
    img: &crate::image::Image,
    uv: &[[f32; W]; 2],
    m: u32,
    kd_pi: &mut [[f32; W]; 3],
) -> u32 {
    let Some((done, at, wt)) = bilinear_taps(img, uv, m) else { return 0 };
    let w = img.width;
    let data = img.data.as_ptr().cast::<f32>();
    let inv_pi = _mm_set1_ps(crate::math::INV_PI);
    let three = _mm_setr_epi32(-1, -1, -1, 0);
    // the lanes' results go into the three channel vectors by blends, stored once: eight
    // one-float stores followed by `pending_weights`' vector loads would stall them (no store
    // forwarding from several stores into one load)
    let mut kd = [ld(&kd_pi[0]), ld(&kd_pi[1]), ld(&kd_pi[2])];
    for l in super::wavefront::lanes_of(done) {
        // SAFETY: corner (x₀, y₀) with x₀ ≤ w − 2, y₀ ≤ h − 2: the four corners' 12 floats
        // lie in `data` (3·w·h floats). The 4-float loads of the first three corners read one
        // float of the next pixel, which exists (x₀ + 1 < w, or the next row); the last
        // corner's load is masked to its 3 floats.
        let r = unsafe {
            let p = data.add(at[l] as usize);
            let row1 = p.add(3 * w);
            let v00 = _mm_loadu_ps(p);
            let v10 = _mm_loadu_ps(p.add(3));
            let v01 = _mm_loadu_ps(row1);
            let v11 = _mm_maskload_ps(row1.add(3), three);
            let s = |k: usize| _mm_set1_ps(wt[k][l]);
            let r = _mm_add_ps(_mm_mul_ps(v00, s(0)), _mm_mul_ps(v10, s(1)));
            let r = _mm_add_ps(r, _mm_mul_ps(v01, s(2)));
            _mm_mul_ps(_mm_add_ps(r, _mm_mul_ps(v11, s(3))), inv_pi)
        };
        let lane = lane_mask(1 << l);
        let r = _mm256_broadcastsi128_si256(_mm_castps_si128(r));
        let r = _mm256_castsi256_ps(r);
        // channel c of `r` in every lane, put into lane `l`
        kd[0] = _mm256_blendv_ps(kd[0], _mm256_permute_ps::<0x00>(r), lane);
        kd[1] = _mm256_blendv_ps(kd[1], _mm256_permute_ps::<0x55>(r), lane);
        kd[2] = _mm256_blendv_ps(kd[2], _mm256_permute_ps::<0xaa>(r), lane);
    }
    for (k, v) in kd_pi.iter_mut().zip(kd) {
        st(k, v);
    }
    done
}

/// The taps of [`bilinear_lanes`]: the lanes of `m` whose four corners lie inside `img`, the
/// float index of each lane's corner (x₀, y₀) and the four weights (`None`: no such lane, or
/// an image the lanes do not take).
#[target_feature(enable = "avx2")]
#[inline]
fn bilinear_taps(
    img: &crate::image::Image,
    uv: &[[f32; W]; 2],
    m: u32,
) -> Option<(u32, [i32; W], [[f32; W]; 4])> {
    let (w, h) = (img.width, img.height);
    let fits = |n: usize| (2..=1 << 24).contains(&n);
    if m == 0 || !fits(w) || !fits(h) || 3 * w as u64 * h as u64 > i32::MAX as u64 {
        return None;
    }
    debug_assert_eq!(img.data.len(), w * h);
    let (wf, hf) = (_mm256_set1_ps(w as f32), _mm256_set1_ps(h as f32));
    let (half, one) = (_mm256_set1_ps(0.5), _mm256_set1_ps(1.0));
    let px = _mm256_sub_ps(_mm256_mul_ps(ld(&uv[0]), wf), half);
    let py = _mm256_sub_ps(_mm256_mul_ps(ld(&uv[1]), hf), half);
    // `floor` for every finite value (NaN and infinities fail the range test below)
    let fx = _mm256_round_ps::<{ _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC }>(px);
    let fy = _mm256_round_ps::<{ _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC }>(py);
    // both corners of each axis inside: 0 ≤ x₀ ≤ w − 2 (exact in f32: w ≤ 2²⁴)
    let zero = _mm256_setzero_ps();
    let inside = |f: __m256, n: usize| {
        _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_GE_OQ>(f, zero),
            _mm256_cmp_ps::<_CMP_LE_OQ>(f, _mm256_set1_ps((n - 2) as f32)),
        )
    };
    let done = m & bits(_mm256_and_ps(inside(fx, w), inside(fy, h)));
    if done == 0 {
        return None;
    }
    let (wx1, wy1) = (_mm256_sub_ps(px, fx), _mm256_sub_ps(py, fy));
    let (wx0, wy0) = (_mm256_sub_ps(one, wx1), _mm256_sub_ps(one, wy1));
    let mut wt = [[0.0f32; W]; 4];
    st(&mut wt[0], _mm256_mul_ps(wx0, wy0));
    st(&mut wt[1], _mm256_mul_ps(wx1, wy0));
    st(&mut wt[2], _mm256_mul_ps(wx0, wy1));
    st(&mut wt[3], _mm256_mul_ps(wx1, wy1));
    // float index of corner (x₀, y₀): 3·(y₀·w + x₀) (meaningless outside `done`)
    let (xi, yi) = (_mm256_cvttps_epi32(fx), _mm256_cvttps_epi32(fy));
    let row = _mm256_set1_epi32(w as i32);
    let idx = _mm256_mullo_epi32(_mm256_add_epi32(_mm256_mullo_epi32(yi, row), xi), _mm256_set1_epi32(3));
    let mut at = [0i32; W];
    // SAFETY: 8 i32, unaligned store.
    unsafe { _mm256_storeu_si256(at.as_mut_ptr().cast(), idx) };
    Some((done, at, wt))
}
