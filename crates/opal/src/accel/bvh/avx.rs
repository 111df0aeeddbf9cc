//! AVX2 traversal of [`super::Bvh`]: the portable traversal's operations in the same order,
//! eight boxes per instruction (`max`/`min` with the same NaN rule as the portable `if`s, no
//! FMA), so the same nodes are visited and the same hit is returned, bit for bit.
//!
//! Tests: `super::tests::avx2_and_portable_traversals_agree_bit_for_bit`.

use super::{BOX_FAR_SCALE, Best, Bvh, Entry, LEAF, STACK, WIDTH, order_children, pop};
use crate::accel::Hit;
use crate::accel::group::{AvxRay, ShearRay, group_hit_avx};
use crate::accel::packet::RayPacket;
use crate::geometry::Ray;
use std::arch::x86_64::*;
use std::mem::MaybeUninit;

/// Byte offsets in a [`super::Node8`] of the near and far plane rows of each axis (`[near, far]`
/// per axis; the near plane is the maximum for a negative direction, `near[a] = 1`), computed
/// once per ray so that [`box8`] loads its six rows without index arithmetic.
#[inline(always)]
pub(super) fn plane_offsets(near: &[usize; 3]) -> [[usize; 2]; 3] {
    const ROW: usize = 4 * super::WIDTH;
    const SIDE: usize = 3 * ROW;
    [0, 1, 2].map(|a| [near[a] * SIDE + a * ROW, (1 - near[a]) * SIDE + a * ROW])
}

/// The slab test of a node's eight boxes (see `BoxRay::hit8`): entry distances and the mask of
/// the boxes overlapping `(0, tmax)`. `planes` from [`plane_offsets`].
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn box8(
    n: &super::Node8,
    o: &[__m256; 3],
    inv: &[__m256; 3],
    planes: &[[usize; 2]; 3],
    scale: __m256,
    tmax: f32,
) -> (__m256, u32) {
    let mut t0 = _mm256_setzero_ps();
    let mut t1 = _mm256_set1_ps(tmax);
    let base = n.b.as_ptr().cast::<u8>();
    for a in 0..3 {
        // SAFETY: `Node8` is 64-byte aligned and `b` (its first field) holds the 6 plane rows of
        // 32 bytes; the offsets from `plane_offsets` are those of the rows `b[near][a]` and
        // `b[1 - near][a]` with `near` 0 or 1.
        let (pn, pf) = unsafe {
            (
                _mm256_load_ps(base.add(planes[a][0]).cast::<f32>()),
                _mm256_load_ps(base.add(planes[a][1]).cast::<f32>()),
            )
        };
        let tn = _mm256_mul_ps(_mm256_sub_ps(pn, o[a]), inv[a]);
        let tf = _mm256_mul_ps(_mm256_mul_ps(_mm256_sub_ps(pf, o[a]), inv[a]), scale);
        // maxps(tn, t0) returns t0 when tn is NaN: the portable `if tn > t0`.
        t0 = _mm256_max_ps(tn, t0);
        t1 = _mm256_min_ps(tf, t1);
    }
    (t0, _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(t0, t1)) as u32)
}

/// The slab test of one box `(lo, hi)` against eight rays (origins `o`, inverse directions
/// `inv`, `neg` = the lanes where `inv < 0`) over `(0, t1)`: the operations of
/// `BoxRay::hit8` per lane (near/far planes by the sign, `maxps`/`minps` for the NaN-ignoring
/// `if`s, the far distance widened by `1 + 2γ₃`); returns the mask `t0 ≤ t1` (all bits set
/// where the lane's segment meets the box). Shared by [`enters8_avx2`] and the packet kernel
/// (`crate::accel::packet`).
#[target_feature(enable = "avx2")]
#[inline]
pub(in crate::accel) fn slab8(
    lo: [f32; 3],
    hi: [f32; 3],
    o: &[__m256; 3],
    inv: &[__m256; 3],
    neg: &[__m256; 3],
    t1: __m256,
) -> __m256 {
    let (mut t0, mut t1) = (_mm256_setzero_ps(), t1);
    for a in 0..3 {
        let (l, h) = (_mm256_set1_ps(lo[a]), _mm256_set1_ps(hi[a]));
        let (near, far) = (_mm256_blendv_ps(l, h, neg[a]), _mm256_blendv_ps(h, l, neg[a]));
        let tn = _mm256_mul_ps(_mm256_sub_ps(near, o[a]), inv[a]);
        let tf =
            _mm256_mul_ps(_mm256_mul_ps(_mm256_sub_ps(far, o[a]), inv[a]), _mm256_set1_ps(BOX_FAR_SCALE));
        t0 = _mm256_max_ps(tn, t0);
        t1 = _mm256_min_ps(tf, t1);
    }
    _mm256_cmp_ps::<_CMP_LE_OQ>(t0, t1)
}

/// `Bvh::enters8_portable` for the eight lanes at once: the same operations per lane (the
/// division, then [`slab8`]), so the same mask, bit for bit
/// (`super::tests::enters8_avx2_equals_portable`).
#[target_feature(enable = "avx2")]
pub(super) fn enters8_avx2(bounds: (crate::math::Vec3, crate::math::Vec3), rays: &RayPacket) -> u32 {
    let (lo, hi) = bounds;
    // SAFETY: unaligned loads of `[f32; 8]` arrays.
    let ld = |a: &[f32; 8]| unsafe { _mm256_loadu_ps(a.as_ptr()) };
    let zero = _mm256_setzero_ps();
    let tmax = ld(&rays.tmax);
    let inv = [0, 1, 2].map(|a| _mm256_div_ps(_mm256_set1_ps(1.0), ld(&rays.d[a])));
    let neg = inv.map(|i| _mm256_cmp_ps::<_CMP_LT_OQ>(i, zero));
    let o = [0, 1, 2].map(|a| ld(&rays.o[a]));
    let enters = slab8(lo.to_array(), hi.to_array(), &o, &inv, &neg, tmax);
    _mm256_movemask_ps(_mm256_and_ps(_mm256_cmp_ps::<_CMP_GT_OQ>(tmax, zero), enters)) as u32
}

impl Bvh {
    /// Hints the cache lines of child `c` (a node or a leaf).
    #[inline(always)]
    pub(super) fn prefetch(&self, c: u32) {
        // (wrapping arithmetic: no bounds check; `c` is a reference of the tree)
        let (p, lines): (*const i8, usize) = if c & LEAF != 0 {
            (self.leaves.as_ptr().wrapping_add((c & !LEAF) as usize).cast(), 5)
        } else {
            (self.nodes.as_ptr().wrapping_add(c as usize).cast(), 4)
        };
        for k in 0..lines {
            // SAFETY: prefetching never faults; the address is inside the element.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(64 * k)) };
        }
    }

    /// See [`Bvh::traverse`](super::Bvh): the same traversal with AVX2 box and group tests.
    #[target_feature(enable = "avx2")]
    pub(super) fn traverse_avx2<const ANY: bool>(&self, ray: &Ray) -> Option<Hit> {
        let o = [_mm256_set1_ps(ray.o.x), _mm256_set1_ps(ray.o.y), _mm256_set1_ps(ray.o.z)];
        let inv_s = [1.0 / ray.d.x, 1.0 / ray.d.y, 1.0 / ray.d.z];
        let inv = inv_s.map(|i| _mm256_set1_ps(i));
        let planes = plane_offsets(&inv_s.map(|i| (i < 0.0) as usize));
        let scale = _mm256_set1_ps(BOX_FAR_SCALE);
        let ar = AvxRay::new(&ShearRay::with_inv(ray, crate::math::Vec3::from_array(inv_s)));
        let mut tmax = ray.tmax;
        // (its triangle index is looked up at the end: one cache miss per ray, not per candidate)
        let mut best: Best = None;
        let mut stack = [MaybeUninit::<Entry>::uninit(); STACK];
        let mut sp = 0usize;
        let mut cur = 0u32;
        loop {
            if cur & LEAF != 0 {
                let g = (cur & !LEAF) as usize;
                // SAFETY: leaf references are built from `leaves` indices.
                let group = unsafe { &self.leaves.get_unchecked(g).tris };
                if let Some((l, t, b1, b2)) = group_hit_avx::<ANY>(group, &ar, ray, tmax) {
                    tmax = t;
                    best = Some((g, l, t, b1, b2));
                }
            } else {
                // SAFETY: interior references are built from `nodes` indices.
                let n = unsafe { self.nodes.get_unchecked(cur as usize) };
                let (t0, mask) = box8(n, &o, &inv, &planes, scale, tmax);
                if mask == 0 {
                    // fall through to the pop
                } else if ANY {
                    let mut tn = [0.0f32; WIDTH];
                    // SAFETY: 8 floats, unaligned store.
                    unsafe { _mm256_storeu_ps(tn.as_mut_ptr(), t0) };
                    let mut m = mask;
                    while m != 0 {
                        let l = m.trailing_zeros() as usize;
                        m &= m - 1;
                        let c = n.child[l];
                        if c & LEAF != 0 {
                            let g = (c & !LEAF) as usize;
                            // SAFETY: as above.
                            let group = unsafe { &self.leaves.get_unchecked(g).tris };
                            if let Some((l, t, b1, b2)) = group_hit_avx::<true>(group, &ar, ray, tmax) {
                                // any-hit: only whether; the triangle index is not looked up
                                return Some(Hit { t, prim: l as u32, b1, b2 });
                            }
                        } else {
                            stack[sp].write(Entry { child: c, tnear: tn[l] });
                            sp += 1;
                        }
                    }
                } else {
                    let mut tn = [0.0f32; WIDTH];
                    // SAFETY: 8 floats, unaligned store.
                    unsafe { _mm256_storeu_ps(tn.as_mut_ptr(), t0) };
                    let before = sp;
                    cur = order_children(mask, &tn, &n.child, &mut stack, &mut sp);
                    // the children left for later: start loading them now (memory latency
                    // dominates; no effect on results)
                    for e in &stack[before..sp] {
                        // SAFETY: entries `before..sp` were just written.
                        self.prefetch(unsafe { e.assume_init() }.child);
                    }
                    continue;
                }
            }
            match pop(&stack, &mut sp, tmax) {
                Some(c) => cur = c,
                None => return self.hit_of(best),
            }
        }
    }
}
