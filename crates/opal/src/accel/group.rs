//! Eight triangles tested at once: the leaf kernel shared by [`super::Bvh`] and
//! [`super::TinyAccel`].
//!
//! A [`Group`] stores up to [`LANES`] triangles in structure-of-arrays form
//! (`v[vertex][axis][lane]`, 32-byte aligned rows); unused lanes hold NaN corners, which never
//! hit. The watertight test of [`super::triangle`] (Woop et al. 2013) runs on all eight lanes at
//! once: [`group_portable`] with plain lane loops, [`group_avx`] with AVX intrinsics — the same
//! operations in the same order, so the same bits.
//!
//! **Same results as [`super::TriRay`]**: the per-ray shear is applied in the paper's form
//! `a_kx − S_x a_kz`, which rounds exactly like `TriRay`'s dot products with their exact-zero
//! terms (IEEE addition is commutative and adding ±0 changes nothing but the sign of a zero, which
//! no decision depends on); the edge functions, `det`, `t` and the barycentrics use the same
//! operations in the same order (Rust never contracts to FMA). A group in which some edge
//! function is exactly zero goes through the scalar `TriRay` (its f64 fallback), lane by lane, so
//! `t`, barycentrics and the inclusive-edge rule — hence watertightness — are those of brute
//! force. Within a group, ties (equal `t`) keep the lowest lane.
//!
//! The axis permutation of the shear is chosen from three comparisons by table lookups instead
//! of branches ([`ShearRay`]; tested against `TriRay`'s choice on all sign/zero/NaN/∞ patterns).
//!
//! Tests: unit tests below; `tiny.rs` and `bvh` tests; `crates/opal/tests/accel.rs`.

use super::triangle::TriRay;
use crate::geometry::Ray;
use crate::math::Vec3;

/// Triangles per group (SIMD lanes).
pub const LANES: usize = 8;

/// Up to eight triangles, structure of arrays: `v[vertex][axis][lane]`; unused lanes are NaN.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(32))]
pub(crate) struct Group {
    pub(crate) v: [[[f32; LANES]; 3]; 3],
}

impl Group {
    /// A group of NaN lanes (never hit).
    pub(crate) const EMPTY: Group = Group { v: [[[f32::NAN; LANES]; 3]; 3] };

    /// The triangles `tris` (at most [`LANES`]) in lanes `0..tris.len()`.
    pub(crate) fn new(tris: &[[Vec3; 3]]) -> Group {
        assert!(tris.len() <= LANES);
        let mut g = Group::EMPTY;
        for (l, t) in tris.iter().enumerate() {
            g.set(l, t);
        }
        g
    }

    /// Writes triangle `t` into lane `l`.
    pub(crate) fn set(&mut self, l: usize, t: &[Vec3; 3]) {
        for (v, p) in t.iter().enumerate() {
            for a in 0..3 {
                self.v[v][a][l] = p[a];
            }
        }
    }

    /// The triangle in lane `l` (NaN corners for an unused lane).
    #[inline]
    pub(crate) fn triangle(&self, l: usize) -> [Vec3; 3] {
        std::array::from_fn(|v| Vec3::new(self.v[v][0][l], self.v[v][1][l], self.v[v][2][l]))
    }
}

/// Per-ray constants: origin, axis permutation and shear (as in [`TriRay`]).
#[derive(Clone, Copy)]
pub(crate) struct ShearRay {
    pub(crate) o: [f32; 3],
    pub(crate) k: [usize; 3],
    pub(crate) sx: f32,
    pub(crate) sy: f32,
    pub(crate) sz: f32,
}

impl ShearRay {
    #[inline(always)]
    pub(crate) fn new(ray: &Ray) -> Self {
        ShearRay::with_inv(ray, Vec3::ONE / ray.d)
    }

    /// [`ShearRay::new`] given `inv = 1 / ray.d` (computed once for the box tests too).
    #[inline(always)]
    pub(crate) fn with_inv(ray: &Ray, inv: Vec3) -> Self {
        // Same axis choice and constants as `TriRay::new`, without branches (random directions
        // make them unpredictable): `kz` from the three comparisons, `(kx, ky)` from `kz` and the
        // sign of `d[kz]`, by table.
        const KZ: [u8; 8] = [2, 1, 2, 1, 2, 2, 0, 0];
        const KXY: [[u8; 2]; 8] = [[1, 2], [2, 1], [2, 0], [0, 2], [0, 1], [1, 0], [0, 0], [0, 0]];
        let d = ray.d;
        let a = d.abs();
        let idx = ((a.x > a.y) as usize) << 2 | ((a.x > a.z) as usize) << 1 | (a.y > a.z) as usize;
        let kz = KZ[idx] as usize;
        let da = [d.x, d.y, d.z, 0.0];
        let ia = [inv.x, inv.y, inv.z, 0.0];
        let [kx, ky] = KXY[(kz << 1 | (da[kz & 3] < 0.0) as usize) & 7];
        let (kx, ky) = (kx as usize, ky as usize);
        let sz = ia[kz & 3];
        ShearRay { o: ray.o.to_array(), k: [kx, ky, kz], sx: da[kx & 3] * sz, sy: da[ky & 3] * sz, sz }
    }
}

/// Hits of one group: `t`, barycentrics, hit mask, and mask of lanes with a zero edge function.
pub(crate) struct GroupHits {
    pub(crate) t: [f32; LANES],
    pub(crate) b1: [f32; LANES],
    pub(crate) b2: [f32; LANES],
    pub(crate) hit: u32,
    pub(crate) zero: u32,
}

/// The lane of `mask` (non-zero) with the smallest `t`, the lowest on ties.
#[inline(always)]
pub(crate) fn closest_lane(mask: u32, t: &[f32; LANES]) -> usize {
    let mut m = mask;
    let mut l = m.trailing_zeros() as usize;
    m &= m - 1;
    while m != 0 {
        let j = m.trailing_zeros() as usize;
        m &= m - 1;
        if t[j] < t[l] {
            l = j;
        }
    }
    l
}

/// The watertight test on the eight lanes of `g` up to `tmax` (same arithmetic as
/// `TriRay::intersect`; lanes with a zero edge function are flagged in `zero`, their `hit` bit
/// is meaningless).
#[inline(always)]
pub(crate) fn group_portable(g: &Group, r: &ShearRay, tmax: f32) -> GroupHits {
    let [kx, ky, kz] = r.k;
    let mut px = [[0.0f32; LANES]; 3];
    let mut py = [[0.0f32; LANES]; 3];
    let mut pz = [[0.0f32; LANES]; 3];
    for v in 0..3 {
        for l in 0..LANES {
            let ax = g.v[v][kx][l] - r.o[kx];
            let ay = g.v[v][ky][l] - r.o[ky];
            let az = g.v[v][kz][l] - r.o[kz];
            px[v][l] = ax - r.sx * az;
            py[v][l] = ay - r.sy * az;
            pz[v][l] = r.sz * az;
        }
    }
    let mut out = GroupHits { t: [0.0; LANES], b1: [0.0; LANES], b2: [0.0; LANES], hit: 0, zero: 0 };
    let mut ok = [false; LANES];
    let mut zero = [false; LANES];
    // Non-short-circuit `|`/`&` so the lane loop has no branches (vectorises).
    for l in 0..LANES {
        let (ax, ay, bx, by, cx, cy) = (px[0][l], py[0][l], px[1][l], py[1][l], px[2][l], py[2][l]);
        let u = cx * by - cy * bx;
        let v = ax * cy - ay * cx;
        let w = bx * ay - by * ax;
        zero[l] = (u == 0.0) | (v == 0.0) | (w == 0.0);
        let mixed = ((u < 0.0) | (v < 0.0) | (w < 0.0)) & ((u > 0.0) | (v > 0.0) | (w > 0.0));
        let det = u + v + w;
        let tt = u * pz[0][l] + v * pz[1][l] + w * pz[2][l];
        let inv = 1.0 / det;
        let t = tt * inv;
        // `(tt > 0) == (det > 0)` and `det != 0` are implied by `t > 0` for finite values,
        // but are kept to match `TriRay` exactly (e.g. tt = ±0, det = ±∞).
        ok[l] = !mixed & (det != 0.0) & ((tt > 0.0) == (det > 0.0)) & (t > 0.0) & (t < tmax);
        out.t[l] = t;
        out.b1[l] = v * inv;
        out.b2[l] = w * inv;
    }
    for l in 0..LANES {
        out.hit |= (ok[l] as u32) << l;
        out.zero |= (zero[l] as u32) << l;
    }
    out
}

/// The scalar test ([`TriRay`], with its f64 fallback) on the lanes of `g` in lane order, for
/// groups in which an edge function is exactly zero: the closest hit `(lane, t, b1, b2)` below
/// `tmax` (the first of equal `t`), or with `ANY` the first hit.
#[cold]
#[inline(never)]
pub(crate) fn group_scalar<const ANY: bool>(
    g: &Group,
    ray: &Ray,
    tmax: f32,
) -> Option<(usize, f32, f32, f32)> {
    let tr = TriRay::new(ray);
    let mut tmax = tmax;
    let mut best = None;
    for l in 0..LANES {
        if let Some((t, b1, b2)) = tr.intersect(&g.triangle(l), tmax) {
            tmax = t;
            best = Some((l, t, b1, b2));
            if ANY {
                return best;
            }
        }
    }
    best
}

/// Closest hit `(lane, t, b1, b2)` in `g` below `tmax` (first hit with `ANY`), portable lanes.
#[inline(always)]
pub(crate) fn group_hit_portable<const ANY: bool>(
    g: &Group,
    r: &ShearRay,
    ray: &Ray,
    tmax: f32,
) -> Option<(usize, f32, f32, f32)> {
    let h = group_portable(g, r, tmax);
    if h.zero != 0 {
        return group_scalar::<ANY>(g, ray, tmax);
    }
    if h.hit == 0 {
        return None;
    }
    let l = if ANY { h.hit.trailing_zeros() as usize } else { closest_lane(h.hit, &h.t) };
    Some((l, h.t[l], h.b1[l], h.b2[l]))
}

#[cfg(target_arch = "x86_64")]
pub(crate) use avx::{AvxRay, GroupAvx, group_avx, group_hit_avx};

#[cfg(target_arch = "x86_64")]
mod avx {
    use super::{Group, LANES, ShearRay, closest_lane, group_scalar};
    use crate::geometry::Ray;
    use std::arch::x86_64::*;

    /// Per-ray constants of the AVX group test: axis permutation, permuted origin and shear,
    /// each broadcast to the 8 lanes.
    #[derive(Clone, Copy)]
    pub(crate) struct AvxRay {
        pub(crate) k: [usize; 3],
        pub(crate) o: [__m256; 3],
        pub(crate) s: [__m256; 3],
    }

    impl AvxRay {
        #[target_feature(enable = "avx")]
        pub(crate) fn new(r: &ShearRay) -> Self {
            AvxRay {
                k: r.k,
                o: r.k.map(|k| _mm256_set1_ps(r.o[k])),
                s: [_mm256_set1_ps(r.sx), _mm256_set1_ps(r.sy), _mm256_set1_ps(r.sz)],
            }
        }
    }

    /// The watertight test on the 8 triangles of a group (AVX), up to `t`: `zero` = lanes with
    /// an exactly-zero edge function (all bits set), `mixed` = sign bit set where the edge
    /// functions' signs differ (meaningful only without a zero edge function),
    /// `t = tt · (1/det)`, and `v`, `w`, `inv = 1/det` for the barycentrics `v · inv`, `w · inv`.
    pub(crate) struct GroupAvx {
        pub(crate) zero: __m256,
        pub(crate) mixed: __m256,
        pub(crate) t: __m256,
        pub(crate) v: __m256,
        pub(crate) w: __m256,
        pub(crate) inv: __m256,
    }

    /// See [`GroupAvx`]: `TriRay::intersect`'s arithmetic, 8 triangles per instruction.
    #[target_feature(enable = "avx")]
    #[inline]
    pub(crate) fn group_avx(g: &Group, r: &AvxRay) -> GroupAvx {
        let [kx, ky, kz] = r.k;
        let ([ox, oy, oz], [sx, sy, sz]) = (r.o, r.s);
        let zero = _mm256_setzero_ps();
        // SAFETY: `Group` is 32-byte aligned and each `[f32; 8]` row is 32 bytes, so every row
        // pointer is aligned and valid for 8 reads; the axes come from `ShearRay::new`'s tables,
        // all < 3.
        let ld = |v: usize, a: usize| unsafe { _mm256_load_ps(g.v[v].get_unchecked(a).as_ptr()) };
        let mut px = [zero; 3];
        let mut py = [zero; 3];
        let mut pz = [zero; 3];
        for v in 0..3 {
            let az = _mm256_sub_ps(ld(v, kz), oz);
            px[v] = _mm256_sub_ps(_mm256_sub_ps(ld(v, kx), ox), _mm256_mul_ps(sx, az));
            py[v] = _mm256_sub_ps(_mm256_sub_ps(ld(v, ky), oy), _mm256_mul_ps(sy, az));
            pz[v] = _mm256_mul_ps(sz, az);
        }
        let u = _mm256_sub_ps(_mm256_mul_ps(px[2], py[1]), _mm256_mul_ps(py[2], px[1]));
        let v = _mm256_sub_ps(_mm256_mul_ps(px[0], py[2]), _mm256_mul_ps(py[0], px[2]));
        let w = _mm256_sub_ps(_mm256_mul_ps(px[1], py[0]), _mm256_mul_ps(py[1], px[0]));
        let eq0 = |x| _mm256_cmp_ps::<_CMP_EQ_OQ>(x, zero);
        let zero_edge = _mm256_or_ps(_mm256_or_ps(eq0(u), eq0(v)), eq0(w));
        let mixed = _mm256_or_ps(_mm256_xor_ps(u, v), _mm256_xor_ps(u, w));
        let det = _mm256_add_ps(_mm256_add_ps(u, v), w);
        let tt = _mm256_add_ps(
            _mm256_add_ps(_mm256_mul_ps(u, pz[0]), _mm256_mul_ps(v, pz[1])),
            _mm256_mul_ps(w, pz[2]),
        );
        let inv = _mm256_div_ps(_mm256_set1_ps(1.0), det);
        GroupAvx { zero: zero_edge, mixed, t: _mm256_mul_ps(tt, inv), v, w, inv }
    }

    /// [`super::group_hit_portable`] with AVX: the same hit, bit for bit (with `ANY`, the same
    /// lane and `t`, barycentrics not computed).
    ///
    /// The hit mask is used only when no edge function is zero; then "mixed signs" is "sign bits
    /// differ" and `TriRay`'s `det != 0`, `(tt > 0) == (det > 0)` follow from `t > 0` (with
    /// non-zero `u, v, w` of one sign, `det` is non-zero with that sign, and `t = tt · (1/det) > 0`
    /// needs `tt` non-zero with the sign of `det`).
    #[target_feature(enable = "avx")]
    #[inline]
    pub(crate) fn group_hit_avx<const ANY: bool>(
        g: &Group,
        r: &AvxRay,
        ray: &Ray,
        tmax: f32,
    ) -> Option<(usize, f32, f32, f32)> {
        let GroupAvx { zero: zv, mixed, t, v, w, inv } = group_avx(g, r);
        let zero = _mm256_setzero_ps();
        if _mm256_movemask_ps(zv) != 0 {
            return group_scalar::<ANY>(g, ray, tmax);
        }
        let good = _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_GT_OQ>(t, zero),
            _mm256_cmp_ps::<_CMP_LT_OQ>(t, _mm256_set1_ps(tmax)),
        );
        let hit = (_mm256_movemask_ps(good) & !_mm256_movemask_ps(mixed)) as u32;
        if hit == 0 {
            return None;
        }
        let mut ts = [0.0f32; LANES];
        // SAFETY: `ts` holds 8 floats (unaligned store).
        unsafe { _mm256_storeu_ps(ts.as_mut_ptr(), t) };
        if ANY {
            // any-hit: no barycentrics
            let l = hit.trailing_zeros() as usize;
            return Some((l, ts[l], 0.0, 0.0));
        }
        let l = closest_lane(hit, &ts);
        let mut b1 = [0.0f32; LANES];
        let mut b2 = [0.0f32; LANES];
        // SAFETY: as above.
        unsafe {
            _mm256_storeu_ps(b1.as_mut_ptr(), _mm256_mul_ps(v, inv));
            _mm256_storeu_ps(b2.as_mut_ptr(), _mm256_mul_ps(w, inv));
        }
        Some((l, ts[l], b1[l], b2[l]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Rng;

    #[test]
    fn branch_free_axis_choice_matches_tri_ray() {
        let vals = [0.0f32, -0.0, 1.0, -1.0, 0.5, -0.5, 2.0, -2.0, 1e-30, -3e38, f32::INFINITY, f32::NAN];
        let same = |a: f32, b: f32| a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan());
        for &x in &vals {
            for &y in &vals {
                for &z in &vals {
                    let d = Vec3::new(x, y, z);
                    let r = ShearRay::new(&Ray::new(Vec3::ZERO, d));
                    let (k, sx, sy, sz) = crate::accel::triangle::shear_axes(d);
                    assert_eq!(r.k, k, "{d}");
                    assert!(same(r.sx, sx) && same(r.sy, sy) && same(r.sz, sz), "{d}");
                }
            }
        }
    }

    /// The portable and AVX group kernels give the same hit, bit for bit, as the scalar test in
    /// lane order, for partly filled groups, shared corners (zero edges) and both queries.
    #[test]
    fn group_kernels_match_the_scalar_test_bit_for_bit() {
        let soup = crate::accel::scenes::random_soup(64, 0.6, 5);
        let shared = [Vec3::new(0.0, 0.0, 1.0), Vec3::new(1.0, 0.0, 1.0), Vec3::new(0.0, 1.0, 1.0)];
        for (gi, chunk) in soup.chunks(LANES).enumerate() {
            let mut tris = chunk[..(gi % LANES) + 1].to_vec();
            if gi % 2 == 0 {
                tris[0] = shared;
            }
            let g = Group::new(&tris);
            for i in 0..3000u64 {
                let mut rng = Rng::new(gi as u64, 3, i);
                let mut o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 3.0 - 1.5;
                let d = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - 1.0;
                if i % 7 == 0 {
                    o = Vec3::new(0.0, 0.0, 0.0); // through the shared corner along +z below
                }
                let d = if i % 7 == 0 { Vec3::Z } else { d };
                let tmax = if i % 3 == 0 { rng.next_f32() * 2.0 } else { f32::INFINITY };
                let ray = Ray { o, d, tmax };
                let want = group_scalar::<false>(&g, &ray, tmax);
                let sr = ShearRay::new(&ray);
                let got = group_hit_portable::<false>(&g, &sr, &ray, tmax);
                let bits = |h: Option<(usize, f32, f32, f32)>| {
                    h.map(|(l, t, b1, b2)| (l, t.to_bits(), b1.to_bits(), b2.to_bits()))
                };
                assert_eq!(bits(got), bits(want), "{ray:?}");
                let any = group_hit_portable::<true>(&g, &sr, &ray, tmax);
                assert_eq!(any.is_some(), want.is_some());
                #[cfg(target_arch = "x86_64")]
                if crate::simd::isa().avx2() {
                    // SAFETY: the CPU supports AVX2 (hence AVX).
                    let (got, any) = unsafe {
                        let ar = AvxRay::new(&sr);
                        (
                            group_hit_avx::<false>(&g, &ar, &ray, tmax),
                            group_hit_avx::<true>(&g, &ar, &ray, tmax),
                        )
                    };
                    assert_eq!(bits(got), bits(want), "avx {ray:?}");
                    assert_eq!(any.is_some(), want.is_some());
                }
            }
        }
    }
}
