//! Eight independent rays traversed together, interleaved (AVX2): [`Bvh::intersect8`]'s fast
//! path for incoherent rays on large scenes.
//!
//! A single ray's traversal is a chain of dependent loads (node → child → …) and on a large
//! mesh most of its time is spent waiting for memory. Here each lane keeps its own traversal
//! state ([`Walker`]: ray constants, `tmax`, the closest hit so far, the current item and its
//! stack) and the lanes take turns doing **one visit** each (a node's box test or a leaf's
//! triangles); after its visit a lane prefetches the item it visits next, which then has seven
//! other lanes' visits to arrive. Each lane performs exactly the operations of the single-ray
//! traversal (`avx.rs`) in the same order — the same box test ([`super::avx::box8`]), the same
//! ordering of children, the same leaf kernel — so every lane returns the single-ray hit, bit for
//! bit (tested: `super::tests::interleaved_packets_match_single_rays_bit_for_bit`). The any-hit
//! variant ([`Bvh::occluded8`]) stops a lane at its first hit, like [`Bvh::occluded`].

use super::avx::{box8, plane_offsets};
use super::{BOX_FAR_SCALE, Best, Bvh, Entry, LEAF, STACK, order_children, pop};
use crate::accel::group::{AvxRay, ShearRay, group_hit_avx};
use crate::accel::packet::{PACKET, PacketHits, RayPacket};
use crate::geometry::Ray;
use crate::math::Vec3;
use std::arch::x86_64::*;
use std::mem::MaybeUninit;

/// One lane's traversal state.
struct Walker {
    ray: Ray,
    o: [__m256; 3],
    inv: [__m256; 3],
    /// The near and far plane rows of each axis ([`plane_offsets`]).
    planes: [[usize; 2]; 3],
    ar: AvxRay,
    tmax: f32,
    /// The closest hit so far.
    best: Best,
    /// The item to visit next.
    cur: u32,
    sp: usize,
}

impl Walker {
    #[target_feature(enable = "avx2")]
    #[inline]
    fn new(ray: Ray) -> Walker {
        let inv_s = [1.0 / ray.d.x, 1.0 / ray.d.y, 1.0 / ray.d.z];
        Walker {
            o: [_mm256_set1_ps(ray.o.x), _mm256_set1_ps(ray.o.y), _mm256_set1_ps(ray.o.z)],
            inv: inv_s.map(|i| _mm256_set1_ps(i)),
            planes: plane_offsets(&inv_s.map(|i| (i < 0.0) as usize)),
            ar: AvxRay::new(&ShearRay::with_inv(&ray, Vec3::from_array(inv_s))),
            tmax: ray.tmax,
            best: None,
            cur: 0,
            sp: 0,
            ray,
        }
    }

    /// Visits the current item and moves to the next one; `false` when the traversal is over
    /// (with `any`, also at the first hit: `best` is then some hit, not the closest).
    #[target_feature(enable = "avx2")]
    #[inline]
    fn step(&mut self, bvh: &Bvh, stack: &mut [MaybeUninit<Entry>; STACK], any: bool) -> bool {
        let cur = self.cur;
        if cur & LEAF != 0 {
            let g = (cur & !LEAF) as usize;
            // SAFETY: leaf references are built from `leaves` indices.
            let group = unsafe { &bvh.leaves.get_unchecked(g).tris };
            if any {
                // any hit ends a shadow ray's traversal (barycentrics not computed)
                if let Some((l, t, b1, b2)) = group_hit_avx::<true>(group, &self.ar, &self.ray, self.tmax) {
                    self.best = Some((g, l, t, b1, b2));
                    return false;
                }
            } else if let Some((l, t, b1, b2)) = group_hit_avx::<false>(group, &self.ar, &self.ray, self.tmax)
            {
                self.tmax = t;
                self.best = Some((g, l, t, b1, b2));
            }
        } else {
            // SAFETY: interior references are built from `nodes` indices.
            let n = unsafe { bvh.nodes.get_unchecked(cur as usize) };
            let scale = _mm256_set1_ps(BOX_FAR_SCALE);
            let (t0, mask) = box8(n, &self.o, &self.inv, &self.planes, scale, self.tmax);
            if mask != 0 {
                let mut tn = [0.0f32; super::WIDTH];
                // SAFETY: 8 floats, unaligned store.
                unsafe { _mm256_storeu_ps(tn.as_mut_ptr(), t0) };
                self.cur = order_children(mask, &tn, &n.child, stack, &mut self.sp);
                bvh.prefetch(self.cur);
                return true;
            }
        }
        match pop(stack, &mut self.sp, self.tmax) {
            Some(c) => {
                self.cur = c;
                bvh.prefetch(c);
                true
            }
            None => false,
        }
    }
}

impl Bvh {
    /// Closest hits of the active lanes (`tmax > 0`) of `rays`, their traversals interleaved.
    #[target_feature(enable = "avx2")]
    pub(super) fn intersect8_avx2(&self, rays: &RayPacket) -> PacketHits {
        self.walk8(rays, false)
    }

    /// Which active lanes (`tmax > 0`) of `rays` hit anything before `tmax` (bit `l` = lane
    /// `l`), their traversals interleaved, each ending at its first hit.
    #[target_feature(enable = "avx2")]
    pub(super) fn occluded8_avx2(&self, rays: &RayPacket) -> u32 {
        let hits = self.walk8(rays, true);
        (0..PACKET).filter(|&l| hits.prim[l] >= 0).fold(0, |m, l| m | 1 << l)
    }

    /// The interleaved traversals: closest hits, or (`any`) some hit per lane. One compilation
    /// for both (a generic one made two, and `Walker::new` / `step` went out of line).
    #[target_feature(enable = "avx2")]
    fn walk8(&self, rays: &RayPacket, any: bool) -> PacketHits {
        let mut hits = PacketHits::NONE;
        let mut walkers: [MaybeUninit<Walker>; PACKET] = [const { MaybeUninit::uninit() }; PACKET];
        let mut stacks = [[MaybeUninit::<Entry>::uninit(); STACK]; PACKET];
        let mut active = 0u32;
        for (l, w) in walkers.iter_mut().enumerate() {
            if rays.tmax[l] > 0.0 {
                w.write(Walker::new(rays.ray(l)));
                active |= 1 << l;
            }
        }
        while active != 0 {
            let mut m = active;
            while m != 0 {
                let l = m.trailing_zeros() as usize;
                m &= m - 1;
                // SAFETY: `l < PACKET` (a bit of `active`); lanes in `active` were initialised
                // above.
                let (w, stack) =
                    unsafe { (walkers.get_unchecked_mut(l).assume_init_mut(), stacks.get_unchecked_mut(l)) };
                if !w.step(self, stack, any) {
                    hits.set(l, self.hit_of(w.best));
                    active &= !(1 << l);
                }
            }
        }
        hits
    }
}
