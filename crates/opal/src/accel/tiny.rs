//! Flat structure for tiny scenes: every triangle is tested, eight at a time.
//!
//! For a few dozen triangles (the Cornell box has 32) a hierarchy costs more than it saves: a
//! ray inside a closed room overlaps most boxes, so the BVH visits nearly every node and leaf
//! anyway, with the branchy ordered traversal on top. [`TinyAccel`] stores the triangles in
//! groups of [`LANES`] in structure-of-arrays form (`v[vertex][axis][lane]`) and runs the
//! watertight test of [`super::triangle`] on a whole group at once (the lane loops compile to
//! 8-wide AVX intrinsics when the CPU has AVX2 — detected once, [`crate::simd`] — and to
//! portable lane loops otherwise). The group kernel is shared with the BVH's leaves
//! (`super::group`).
//!
//! **Same results as [`super::TriRay`]**: the per-ray shear is applied in the paper's form
//! `a_kx − S_x a_kz` (Woop et al. 2013), which rounds exactly like `TriRay`'s dot products with
//! their exact-zero terms (IEEE addition is commutative and adding ±0 changes nothing but the sign
//! of a zero, which no decision depends on); the edge functions, `det`, `t` and the
//! barycentrics then use the same operations in the same order (Rust never contracts to FMA).
//! A group in which some edge function is exactly zero goes through the scalar `TriRay` (its f64
//! fallback), so t, barycentrics and the inclusive-edge rule — hence watertightness — are those
//! of the BVH and brute force. Ties (two triangles at exactly the same `t`) keep the lowest
//! index, like [`super::BruteForce`]. Padding lanes hold NaN vertices, which never hit.
//!
//! Closest hits in scenes of up to [`TINY_MAX`] triangles take a branch-free search
//! (`closest_avx`): all groups are tested, the smallest `t` with the lowest index is picked by a
//! vector minimum and a bit scan, and only that minimum is compared with the ray's `tmax` — the
//! same hit as the group-by-group loop (which needs a data-dependent branch per group that random
//! rays make unpredictable). Any-hit queries keep the loop (early exit). Both rely on two exact
//! shortcuts that hold once no edge function is zero (else the scalar fallback decides): "mixed
//! signs" of `U, V, W` is "sign bits differ" (two XORs, an OR), and `TriRay`'s `det ≠ 0` and
//! `(tt > 0) = (det > 0)` follow from `t > 0` (see `closest_avx`). The axis permutation of the
//! shear is chosen from the three comparisons by table lookups instead of branches, with `1/d`
//! computed for all three axes at once (`ShearRay`; tested against `TriRay`'s choice on all
//! sign/zero/NaN/∞ patterns).
//!
//! Measured (`examples/tiny_rays.rs`, Cornell box, 2.9 GHz Zen 3 VM shared with other jobs,
//! medians of interleaved runs): ≈ 73 → 63 ns per ray (random rays in the room and rays leaving
//! the surfaces with cosine-distributed directions alike, −13 %); the light-trace pass
//! (`light_trace_pass 20000000 2`, `DIRECT=0`) ≈ 1.05 → 1.09 M paths/cpu-s on a loaded machine,
//! bit-identical maps.
//!
//! Tried and dropped: spatially coherent groups (agglomerative clustering, groups of ≤ 8 with
//! their boxes, one 8-wide slab test per ray, only entered groups tested, ties through a
//! lane → original index table). On the Cornell box it gives the natural groups (four walls;
//! each box; the leftovers), yet is ≈ 10 % *slower* than testing all four groups: the two box
//! groups are entered by a good share of the rays, so the saved work is small and the branches
//! on the slab result mispredict.
//!
//! The scene uses it instead of the BVH up to [`TINY_MAX`] triangles ([`crate::scene::Scene`]).
//!
//! Tests: unit tests below; `crates/opal/tests/accel.rs` (identical hits to brute force on random
//! soups and the Cornell box, watertightness on closed meshes).

// The SIMD fast paths exist on x86-64 only; elsewhere the scalar paths run (same results).
#![cfg_attr(not(target_arch = "x86_64"), allow(dead_code, unused_imports, unused_variables))]

use super::Hit;
pub use super::group::LANES;
#[cfg(target_arch = "x86_64")]
use super::group::{AvxRay, GroupAvx, group_avx, group_hit_avx};
use super::group::{Group, ShearRay, group_hit_portable};
use crate::geometry::Ray;
use crate::math::Vec3;
#[cfg(target_arch = "x86_64")]
use std::mem::MaybeUninit;

/// Largest triangle count for which the scene uses [`TinyAccel`] instead of the BVH.
pub const TINY_MAX: usize = 64;

/// Largest number of groups for which closest hits take the branch-free path
/// ([`TINY_MAX`] / [`LANES`]).
const MAX_BRANCHLESS_GROUPS: usize = TINY_MAX / LANES;

/// Flat all-triangles structure for tiny scenes (see the module docs).
#[derive(Clone, Debug)]
pub struct TinyAccel {
    groups: Vec<Group>,
    /// AVX kernels (the instruction set detected once, [`crate::simd::isa`]).
    avx: bool,
    /// Number of triangles.
    len: usize,
}

impl TinyAccel {
    /// Wraps a triangle soup (any size works; it pays up to a few dozen triangles).
    pub fn new(tris: Vec<[Vec3; 3]>) -> Self {
        let groups = tris.chunks(LANES).map(Group::new).collect();
        TinyAccel { groups, avx: crate::simd::isa().avx2(), len: tris.len() }
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether there are no triangles.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    #[inline(always)]
    fn traverse<const ANY: bool>(&self, ray: &Ray) -> Option<Hit> {
        let r = ShearRay::new(ray);
        let mut tmax = ray.tmax;
        let mut best = None;
        for (gi, g) in self.groups.iter().enumerate() {
            if let Some((l, t, b1, b2)) = group_hit_portable::<ANY>(g, &r, ray, tmax) {
                tmax = t;
                best = Some(Hit { t, prim: (gi * LANES + l) as u32, b1, b2 });
                if ANY {
                    return best;
                }
            }
        }
        best
    }

    /// [`Self::traverse`] with AVX intrinsics (8 lanes per instruction; same operations).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx")]
    fn traverse_avx<const ANY: bool>(&self, ray: &Ray) -> Option<Hit> {
        let ar = AvxRay::new(&ShearRay::new(ray));
        let mut tmax = ray.tmax;
        let mut best = None;
        for (gi, g) in self.groups.iter().enumerate() {
            if let Some((l, t, b1, b2)) = group_hit_avx::<ANY>(g, &ar, ray, tmax) {
                tmax = t;
                best = Some(Hit { t, prim: (gi * LANES + l) as u32, b1, b2 });
                if ANY {
                    return best;
                }
            }
        }
        best
    }

    /// Closest hit without data-dependent branches, for up to [`MAX_BRANCHLESS_GROUPS`]
    /// groups (AVX): every group is tested against `ray.tmax`, the smallest `t` over all lanes
    /// is taken and, among equal `t`, the lowest triangle index, which is exactly what the
    /// sequential loop of [`Self::traverse_avx`] returns (it keeps the first of equal `t` since
    /// later hits must be strictly closer). When any edge function is exactly zero the ray goes
    /// through that loop instead (its scalar f64 fallback decides those lanes).
    ///
    /// The sequential loop branches on every group's hit mask, which a random ray makes
    /// unpredictable; here the only branch is the (rare) zero-edge test.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx")]
    fn closest_avx(&self, ray: &Ray) -> Option<Hit> {
        use std::arch::x86_64::*;
        let ar = AvxRay::new(&ShearRay::new(ray));
        let zero = _mm256_setzero_ps();
        let inf = _mm256_set1_ps(f32::INFINITY);
        // Rows `0..n` are written below before they are read; the rest is never read.
        let mut ts = [MaybeUninit::<[f32; LANES]>::uninit(); MAX_BRANCHLESS_GROUPS];
        let mut b1s = [MaybeUninit::<[f32; LANES]>::uninit(); MAX_BRANCHLESS_GROUPS];
        let mut b2s = [MaybeUninit::<[f32; LANES]>::uninit(); MAX_BRANCHLESS_GROUPS];
        let mut tmin = inf;
        let mut zany = zero;
        let n = self.groups.len();
        for (gi, g) in self.groups.iter().enumerate() {
            let GroupAvx { zero: zv, mixed, t, v, w, inv } = group_avx(g, &ar);
            zany = _mm256_or_ps(zany, zv);
            // Only used when no edge function is zero (else the loop decides): `u, v, w` are then
            // non-zero or NaN, so "mixed signs" is "sign bits differ" (sign bit of the result).
            // `TriRay` also asks `det != 0` and `(tt > 0) == (det > 0)`: with non-zero `u, v, w`
            // of one sign, `det` is non-zero with that sign, and `t = tt · (1/det) > 0` needs
            // `tt` non-zero with the sign of `det`. `t < tmax` is applied to the minimum below.
            let reject = _mm256_or_ps(mixed, _mm256_cmp_ps::<_CMP_NGT_UQ>(t, zero));
            // t of the hit lanes, +∞ elsewhere (blend on the sign bit)
            let th = _mm256_blendv_ps(t, inf, reject);
            tmin = _mm256_min_ps(tmin, th);
            // SAFETY: `gi < n ≤ MAX_BRANCHLESS_GROUPS` (checked by the caller); unaligned stores
            // of 8 floats into 8-float rows.
            unsafe {
                _mm256_storeu_ps(ts.get_unchecked_mut(gi).as_mut_ptr().cast(), th);
                _mm256_storeu_ps(b1s.get_unchecked_mut(gi).as_mut_ptr().cast(), _mm256_mul_ps(v, inv));
                _mm256_storeu_ps(b2s.get_unchecked_mut(gi).as_mut_ptr().cast(), _mm256_mul_ps(w, inv));
            }
        }
        if _mm256_movemask_ps(zany) != 0 {
            return self.traverse_avx::<false>(ray);
        }
        // horizontal minimum of the 8 lanes
        let m = _mm256_min_ps(tmin, _mm256_permute2f128_ps::<1>(tmin, tmin));
        let m = _mm256_min_ps(m, _mm256_permute_ps::<0b01_00_11_10>(m));
        let m = _mm256_min_ps(m, _mm256_permute_ps::<0b10_11_00_01>(m));
        let best = _mm256_cvtss_f32(m);
        // (false for +∞ and for a NaN `tmax`)
        let in_range = best < ray.tmax;
        if !in_range {
            return None;
        }
        // the lowest (group, lane) holding the minimum
        let mut mask = 0u64;
        for (gi, row) in ts.iter().enumerate().take(n) {
            // SAFETY: row `gi < n` was written above; 8 floats (unaligned load).
            let tv = unsafe { _mm256_loadu_ps(row.as_ptr().cast()) };
            mask |= (_mm256_movemask_ps(_mm256_cmp_ps::<_CMP_EQ_OQ>(tv, m)) as u32 as u64) << (LANES * gi);
        }
        let i = mask.trailing_zeros() as usize;
        let (gi, l) = (i / LANES, i % LANES);
        // SAFETY: the minimum is finite, so some lane of a written row `gi < n` holds it.
        let (b1, b2) = unsafe { (b1s[gi].assume_init_ref()[l], b2s[gi].assume_init_ref()[l]) };
        Some(Hit { t: best, prim: i as u32, b1, b2 })
    }

    #[inline(always)]
    fn dispatch<const ANY: bool>(&self, ray: &Ray) -> Option<Hit> {
        #[cfg(target_arch = "x86_64")]
        if self.avx {
            if !ANY && self.groups.len() <= MAX_BRANCHLESS_GROUPS {
                // SAFETY: the CPU supports AVX2 (detected when built); the group count is in range.
                return unsafe { self.closest_avx(ray) };
            }
            // SAFETY: the CPU supports AVX2 (detected when built).
            return unsafe { self.traverse_avx::<ANY>(ray) };
        }
        self.traverse::<ANY>(ray)
    }

    /// Closest hit with `0 < t < ray.tmax`.
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        self.dispatch::<false>(ray)
    }

    /// Whether any triangle is hit with `0 < t < ray.tmax`.
    pub fn occluded(&self, ray: &Ray) -> bool {
        self.dispatch::<true>(ray).is_some()
    }

    /// Closest hit computed without AVX (the portable lane loops), for tests.
    pub fn intersect_portable(&self, ray: &Ray) -> Option<Hit> {
        self.traverse::<false>(ray)
    }

    /// Closest hit by the group-by-group loop (AVX when available) instead of the branch-free
    /// search, for tests and benchmarks.
    pub fn intersect_sequential(&self, ray: &Ray) -> Option<Hit> {
        #[cfg(target_arch = "x86_64")]
        if self.avx {
            // SAFETY: the CPU supports AVX2 (detected when built).
            return unsafe { self.traverse_avx::<false>(ray) };
        }
        self.traverse::<false>(ray)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::BruteForce;
    use crate::sampling::Rng;

    #[test]
    fn empty_single_and_padding() {
        let a = TinyAccel::new(vec![]);
        assert!(a.is_empty() && a.intersect(&Ray::new(Vec3::ZERO, Vec3::X)).is_none());
        let tri = [Vec3::new(0.0, 0.0, 1.0), Vec3::new(1.0, 0.0, 1.0), Vec3::new(0.0, 1.0, 1.0)];
        let a = TinyAccel::new(vec![tri]);
        let h = a.intersect(&Ray::new(Vec3::new(0.1, 0.1, 0.0), Vec3::Z)).unwrap();
        assert_eq!(h.prim, 0);
        assert!((h.t - 1.0).abs() < 1e-6 && (h.b1 - 0.1).abs() < 1e-6 && (h.b2 - 0.1).abs() < 1e-6);
        assert!(a.occluded(&Ray::new(Vec3::new(0.1, 0.1, 0.0), Vec3::Z)));
        // the 7 NaN padding lanes never hit, whatever the ray
        assert!(a.intersect(&Ray::new(Vec3::new(5.0, 5.0, 0.0), Vec3::Z)).is_none());
    }

    #[test]
    fn ties_keep_the_lowest_index_and_zero_edges_take_the_scalar_path() {
        let tri = [Vec3::new(0.0, 0.0, 1.0), Vec3::new(1.0, 0.0, 1.0), Vec3::new(0.0, 1.0, 1.0)];
        let far = [Vec3::new(0.0, 0.0, 2.0), Vec3::new(1.0, 0.0, 2.0), Vec3::new(0.0, 1.0, 2.0)];
        let a = TinyAccel::new(vec![far, tri, tri, far, tri]);
        let h = a.intersect(&Ray::new(Vec3::new(0.2, 0.2, 0.0), Vec3::Z)).unwrap();
        assert_eq!(h.prim, 1);
        // through the shared corner (0, 0): exact-zero edge functions
        let h = a.intersect(&Ray::new(Vec3::new(0.0, 0.0, 0.0), Vec3::Z)).unwrap();
        assert_eq!((h.prim, h.t), (1, 1.0));
        // ties across groups: still the lowest index
        for (i, j) in [(3usize, 12usize), (8, 16), (0, 31), (13, 21)] {
            let mut tris = vec![far; 32];
            tris[i] = tri;
            tris[j] = tri;
            let a = TinyAccel::new(tris);
            let h = a.intersect(&Ray::new(Vec3::new(0.2, 0.2, 0.0), Vec3::Z)).unwrap();
            assert_eq!((h.prim, h.t), (i as u32, 1.0));
            let h = a.intersect(&Ray::new(Vec3::new(0.2, 0.2, 1.5), -Vec3::Z)).unwrap();
            assert_eq!((h.prim, h.t), (i as u32, 0.5));
        }
    }

    #[test]
    fn all_sizes_and_axis_aligned_rays_agree_with_brute_force() {
        for n in 1..=64usize {
            let tris = crate::accel::scenes::random_soup(n, 0.5, n as u64);
            let a = TinyAccel::new(tris.clone());
            let bf = BruteForce::new(tris);
            for i in 0..300u64 {
                let mut rng = Rng::new(n as u64, 11, i);
                let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 3.0 - 1.5;
                let mut d = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - 1.0;
                // zero direction components (±0), one or two of them
                match i % 5 {
                    1 => d.x = 0.0,
                    2 => (d.y, d.z) = (-0.0, 0.0),
                    3 => d.z = -0.0,
                    4 => (d.x, d.y) = (0.0, 0.0),
                    _ => {}
                }
                let tmax = if i % 3 == 0 { rng.next_f32() * 2.0 } else { f32::INFINITY };
                let ray = Ray { o, d, tmax };
                let want = bf.intersect(&ray);
                assert_eq!(a.intersect(&ray), want, "{n} {ray:?}");
                assert_eq!(a.intersect_sequential(&ray), want, "{n} {ray:?}");
                assert_eq!(a.intersect_portable(&ray), want, "{n} {ray:?}");
                assert_eq!(a.occluded(&ray), bf.occluded(&ray), "{n} {ray:?}");
            }
        }
    }

    #[test]
    fn portable_and_dispatched_agree_with_brute_force() {
        for seed in 0..4u64 {
            let n = [3usize, 8, 31, 64][seed as usize];
            let tris = crate::accel::scenes::random_soup(n, 0.5, seed);
            let a = TinyAccel::new(tris.clone());
            let bf = BruteForce::new(tris);
            for i in 0..2000u64 {
                let mut rng = Rng::new(seed, 9, i);
                let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 3.0 - 1.5;
                let d = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - 1.0;
                let tmax = if i % 3 == 0 { rng.next_f32() * 2.0 } else { f32::INFINITY };
                let ray = Ray { o, d, tmax };
                let want = bf.intersect(&ray);
                assert_eq!(a.intersect(&ray), want, "{ray:?}");
                assert_eq!(a.intersect_portable(&ray), want, "{ray:?}");
                assert_eq!(a.intersect_sequential(&ray), want, "{ray:?}");
                assert_eq!(a.occluded(&ray), bf.occluded(&ray));
            }
        }
    }
}
