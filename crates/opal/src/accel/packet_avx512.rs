//! The closest-hit packet kernel of [`PacketAccel`] on sixteen lanes (two [`RayPacket`]s at
//! once) with AVX-512: the AVX2 kernel (`PacketAccel::kernel_avx2::<false>`) with every
//! 8-lane operation replaced by the same IEEE operation on 16 lanes and the sign-bit blends by
//! mask registers, so each lane computes the same values in the same order and takes the same
//! hits, bit for bit (test: `sixteen_lanes_equal_two_eight_lane_packets` below and every
//! `check` of `packet.rs`'s tests). Half the instructions per ray of the 8-lane kernel: the
//! per-triangle and per-corner work is shared by sixteen rays.
//!
//! Runs only where [`crate::simd::isa`] found AVX-512 (F, VL, DQ, BW) when the structure was
//! built ([`PacketAccel::avx512`]); its scalar original is [`super::BruteForce`] (as for the
//! AVX2 kernel), which also takes the lanes with an exactly-zero edge function.

use super::{GROUP, PACKET, PacketAccel, PacketHits, RayPacket};
use std::arch::x86_64::*;
use std::mem::MaybeUninit;

/// Bytes per sheared corner in the 16-lane scratch buffer (three `__m512`): twice the AVX2
/// kernel's `SHEARED_BYTES`, so a triangle's corner offsets are doubled.
const SHEARED16_BYTES: usize = 192;
const _: () = assert!(SHEARED16_BYTES == 2 * super::SHEARED_BYTES as usize);

/// Lanes `0..8` from `a`, `8..16` from `b`.
#[target_feature(enable = "avx512f,avx512vl,avx512dq,avx512bw,avx2,fma")]
#[inline]
fn ld2(a: &[f32; PACKET], b: &[f32; PACKET]) -> __m512 {
    // SAFETY: unaligned loads of 8 floats each.
    let (lo, hi) = unsafe { (_mm256_loadu_ps(a.as_ptr()), _mm256_loadu_ps(b.as_ptr())) };
    _mm512_insertf32x8::<1>(_mm512_castps256_ps512(lo), hi)
}

/// Lanes `0..8` into `a`, `8..16` into `b`.
#[target_feature(enable = "avx512f,avx512vl,avx512dq,avx512bw,avx2,fma")]
#[inline]
fn st2(a: &mut [f32; PACKET], b: &mut [f32; PACKET], v: __m512) {
    // SAFETY: unaligned stores of 8 floats each.
    unsafe {
        _mm256_storeu_ps(a.as_mut_ptr(), _mm512_castps512_ps256(v));
        _mm256_storeu_ps(b.as_mut_ptr(), _mm512_extractf32x8_ps::<1>(v));
    }
}

/// `bvh::avx::slab8` on sixteen lanes: the same operations (near/far planes by the sign of
/// the inverse direction, the far distance widened by `1 + 2γ₃`, the segment `(0, t1)`).
#[target_feature(enable = "avx512f,avx512vl,avx512dq,avx512bw,avx2,fma")]
#[inline]
fn slab16(
    lo: [f32; 3],
    hi: [f32; 3],
    o: &[__m512; 3],
    inv: &[__m512; 3],
    neg: &[__mmask16; 3],
    t1: __m512,
) -> __mmask16 {
    let (mut t0, mut t1) = (_mm512_setzero_ps(), t1);
    for a in 0..3 {
        let (l, h) = (_mm512_set1_ps(lo[a]), _mm512_set1_ps(hi[a]));
        let (near, far) = (_mm512_mask_blend_ps(neg[a], l, h), _mm512_mask_blend_ps(neg[a], h, l));
        let tn = _mm512_mul_ps(_mm512_sub_ps(near, o[a]), inv[a]);
        let tf = _mm512_mul_ps(
            _mm512_mul_ps(_mm512_sub_ps(far, o[a]), inv[a]),
            _mm512_set1_ps(crate::accel::bvh::BOX_FAR_SCALE),
        );
        t0 = _mm512_max_ps(tn, t0);
        t1 = _mm512_min_ps(tf, t1);
    }
    _mm512_cmp_ps_mask::<_CMP_LE_OQ>(t0, t1)
}

impl PacketAccel {
    /// Whether [`PacketAccel::intersect16_avx512`] may run (AVX-512 detected when built).
    #[inline]
    pub(crate) fn avx512(&self) -> bool {
        self.avx512
    }

    /// The closest hits of two packets at once: `[intersect_lanes(a), intersect_lanes(b)]`, bit
    /// for bit. The caller checked [`PacketAccel::avx512`].
    #[target_feature(enable = "avx512f,avx512vl,avx512dq,avx512bw,avx2,fma")]
    pub(crate) fn intersect16_avx512(&self, a: &RayPacket, b: &RayPacket) -> [PacketHits; 2] {
        if self.len == 0 {
            return [PacketHits::NONE; 2];
        }
        // the axis choice and shear of the AVX2 kernel (see its comments), per lane
        let (dx, dy, dz) = (ld2(&a.d[0], &b.d[0]), ld2(&a.d[1], &b.d[1]), ld2(&a.d[2], &b.d[2]));
        let sign = _mm512_set1_ps(-0.0);
        let abs = |x| _mm512_andnot_ps(sign, x);
        let (ax, ay, az) = (abs(dx), abs(dy), abs(dz));
        let gt = |x, y| _mm512_cmp_ps_mask::<_CMP_GT_OQ>(x, y);
        let x_gt_y = gt(ax, ay);
        let kz0 = x_gt_y & gt(ax, az);
        let kz1 = !x_gt_y & gt(ay, az);
        // m0 ? x : (m1 ? y : z)
        let pick = |m0, m1, x, y, z| _mm512_mask_blend_ps(m0, _mm512_mask_blend_ps(m1, z, y), x);
        let kz2 = !(kz0 | kz1);
        let (kx0, kx1) = (kz2, kz0);
        let (ky0, ky1) = (kz1, kz2);
        let one = _mm512_set1_ps(1.0);
        let zero = _mm512_setzero_ps();
        let d_kz = pick(kz0, kz1, dx, dy, dz);
        let sz = _mm512_div_ps(one, d_kz);
        let sx = _mm512_mul_ps(pick(kx0, kx1, dx, dy, dz), sz);
        let sy = _mm512_mul_ps(pick(ky0, ky1, dx, dy, dz), sz);
        let (o0, o1, o2) = (ld2(&a.o[0], &b.o[0]), ld2(&a.o[1], &b.o[1]), ld2(&a.o[2], &b.o[2]));
        let (ox, oy, oz) =
            (pick(kx0, kx1, o0, o1, o2), pick(ky0, ky1, o0, o1, o2), pick(kz0, kz1, o0, o1, o2));
        // axis indices 0, 1 or 2 for the in-lane permutes
        let index = |m0, m1| {
            let i = _mm512_mask_blend_epi32(m1, _mm512_set1_epi32(2), _mm512_set1_epi32(1));
            _mm512_mask_blend_epi32(m0, i, _mm512_setzero_si512())
        };
        let (ikx, iky, ikz) = (index(kx0, kx1), index(ky0, ky1), index(kz0, kz1));
        let mut best_t = ld2(&a.tmax, &b.tmax);
        let mut best_i = _mm512_set1_epi32(-1);
        let (mut best_v, mut best_w, mut best_inv) = (zero, zero, zero);
        let mut zany: __mmask16 = 0;
        let mut sheared = [const { MaybeUninit::<[__m512; 3]>::uninit() }; 3 * GROUP];
        let inv = [_mm512_div_ps(one, dx), _mm512_div_ps(one, dy), _mm512_div_ps(one, dz)];
        let neg = inv.map(|i| _mm512_cmp_ps_mask::<_CMP_LT_OQ>(i, zero));
        let o = [o0, o1, o2];
        let active = gt(best_t, zero);
        for g in &self.groups {
            if slab16(g.lo, g.hi, &o, &inv, &neg, best_t) & active == 0 {
                continue;
            }
            for (slot, c) in sheared.iter_mut().zip(&g.verts) {
                // SAFETY: `Corner` is 16-byte aligned and holds 4 floats.
                let p = _mm512_broadcast_f32x4(unsafe { _mm_load_ps(c.0.as_ptr()) });
                let az = _mm512_sub_ps(_mm512_permutevar_ps(p, ikz), oz);
                let ax = _mm512_sub_ps(_mm512_permutevar_ps(p, ikx), ox);
                let ay = _mm512_sub_ps(_mm512_permutevar_ps(p, iky), oy);
                slot.write([
                    _mm512_sub_ps(ax, _mm512_mul_ps(sx, az)),
                    _mm512_sub_ps(ay, _mm512_mul_ps(sy, az)),
                    _mm512_mul_ps(sz, az),
                ]);
            }
            for tri in &g.tris {
                // SAFETY: `tri[k] / SHEARED_BYTES` indexes a slot below `verts.len()` ≤ 3·GROUP,
                // which the loop above wrote.
                let [pa, pb, pc] = [0, 1, 2].map(|k| unsafe {
                    sheared.as_ptr().cast::<u8>().add(2 * tri[k] as usize).cast::<[__m512; 3]>().read()
                });
                let [px, py, pz] = [0, 1, 2].map(|k| [pa[k], pb[k], pc[k]]);
                let edge = |i: usize, j: usize| {
                    _mm512_sub_ps(_mm512_mul_ps(px[i], py[j]), _mm512_mul_ps(py[i], px[j]))
                };
                let (u, v, w) = (edge(2, 1), edge(0, 2), edge(1, 0));
                zany |= _mm512_cmp_ps_mask::<_CMP_EQ_UQ>(_mm512_mul_ps(_mm512_mul_ps(u, v), w), zero);
                // signs differ ⇔ the sign bit of (u ^ v) | (u ^ w) is set
                let mixed = _mm512_movepi32_mask(_mm512_castps_si512(_mm512_or_ps(
                    _mm512_xor_ps(u, v),
                    _mm512_xor_ps(u, w),
                )));
                let det = _mm512_add_ps(_mm512_add_ps(u, v), w);
                let inv = _mm512_div_ps(one, det);
                let tt = _mm512_add_ps(
                    _mm512_add_ps(_mm512_mul_ps(u, pz[0]), _mm512_mul_ps(v, pz[1])),
                    _mm512_mul_ps(w, pz[2]),
                );
                let t = _mm512_mul_ps(tt, inv);
                let take = !mixed & gt(t, zero) & _mm512_cmp_ps_mask::<_CMP_LT_OQ>(t, best_t);
                best_i = _mm512_mask_blend_epi32(take, best_i, _mm512_set1_epi32(tri[3] as i32));
                best_t = _mm512_mask_blend_ps(take, best_t, t);
                best_v = _mm512_mask_blend_ps(take, best_v, v);
                best_w = _mm512_mask_blend_ps(take, best_w, w);
                best_inv = _mm512_mask_blend_ps(take, best_inv, inv);
            }
        }
        let mut h = [PacketHits::NONE; 2];
        let [h0, h1] = &mut h;
        st2(&mut h0.t, &mut h1.t, best_t);
        st2(&mut h0.b1, &mut h1.b1, _mm512_mul_ps(best_v, best_inv));
        st2(&mut h0.b2, &mut h1.b2, _mm512_mul_ps(best_w, best_inv));
        let i = _mm512_castsi512_ps(best_i);
        // SAFETY: `i32` lanes stored as the bits of f32 lanes (8 each).
        unsafe {
            _mm256_storeu_ps(h0.prim.as_mut_ptr().cast(), _mm512_castps512_ps256(i));
            _mm256_storeu_ps(h1.prim.as_mut_ptr().cast(), _mm512_extractf32x8_ps::<1>(i));
        }
        // as the AVX2 kernel: inactive lanes never hit; the others with an exactly-zero edge
        // function take the scalar test
        for (p, (rays, h)) in [a, b].into_iter().zip(h.iter_mut()).enumerate() {
            let mut lanes = (zany as u32 >> (PACKET * p)) & 0xff;
            while lanes != 0 {
                let l = lanes.trailing_zeros() as usize;
                lanes &= lanes - 1;
                if rays.tmax[l] > 0.0 {
                    h.set(l, self.brute.intersect(&rays.ray(l)));
                } else {
                    h.set(l, None);
                }
            }
        }
        h
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::scenes;
    use crate::geometry::Ray;
    use crate::math::Vec3;
    use crate::sampling::Rng;

    /// Bitwise equality of two hit sets (every field, misses included).
    fn same_bits(x: &PacketHits, y: &PacketHits) -> bool {
        let f =
            |a: &[f32; PACKET], b: &[f32; PACKET]| a.iter().zip(b).all(|(p, q)| p.to_bits() == q.to_bits());
        f(&x.t, &y.t) && f(&x.b1, &y.b1) && f(&x.b2, &y.b2) && x.prim == y.prim
    }

    #[test]
    fn sixteen_lanes_equal_two_eight_lane_packets() {
        if !crate::simd::isa().avx512() {
            return;
        }
        for (seed, n) in [(0u64, 1usize), (1, 7), (2, 33), (3, 64), (4, 130)] {
            let pa = PacketAccel::new(scenes::random_soup(n, 0.5, seed));
            assert!(pa.avx512());
            let mut rng = Rng::new(seed, 12, 0);
            for k in 0..600 {
                let mut p = [RayPacket::default(); 2];
                for (j, q) in p.iter_mut().enumerate() {
                    for l in 0..PACKET {
                        // some inactive lanes (tmax 0 or NaN), some short segments
                        if (k + j + l) % 11 == 0 {
                            q.tmax[l] = if l % 2 == 0 { 0.0 } else { f32::NAN };
                            continue;
                        }
                        let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 3.0 - 1.5;
                        let d = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - 1.0;
                        let tmax = if l % 3 == 0 { rng.next_f32() * 2.0 } else { f32::INFINITY };
                        q.set(l, &Ray { o, d, tmax });
                    }
                }
                // SAFETY: AVX-512 and AVX2 detected (checked above).
                let (got, want) = unsafe {
                    (
                        pa.intersect16_avx512(&p[0], &p[1]),
                        [pa.intersect_avx2(&p[0]), pa.intersect_avx2(&p[1])],
                    )
                };
                for j in 0..2 {
                    assert!(same_bits(&got[j], &want[j]), "soup {seed}, packets {k}, {j}");
                }
            }
        }
    }
}
