//! Eight rays at once against a tiny triangle soup: one ray per SIMD lane.
//!
//! [`super::TinyAccel`] puts eight *triangles* in the lanes and traces one ray at a time; every
//! ray then pays a chain of dependent operations (set-up, the groups, a horizontal minimum, the
//! extraction of the winning lane) that leaves most of the core idle. Code that has eight
//! independent rays at hand (the light tracer's wavefront, [`crate::integrator::light_tracer`])
//! can instead put the *rays* in the lanes: every triangle is tested against the eight rays with
//! the same watertight test, and each lane keeps its closest hit (its distance and the
//! triangle's index) with a select. The test's first half, the shear of a corner into the ray's
//! frame, depends on the corner only: it is done once per *distinct* corner of a group of up to
//! 64 triangles (corners compared by their bits; a mesh's corners are shared by about six
//! triangles, the Cornell box's 32 triangles have 28 distinct corners instead of 96) into a
//! scratch buffer on the stack, and the triangle loop then reads its three sheared corners from
//! there — fewer operations, and no per-ray constant left in registers during that loop. Each
//! lane keeps its winner's barycentrics `v · (1/det)`, `w · (1/det)` with the same selects
//! (cheaper than gathering the winners' corners after the loop; two products per triangle
//! rather than three selected registers, which left the loop short of registers: +3–5 % on the
//! scanned-object room's rays, `examples/room_rays.rs`), so they are the scalar test's bits.
//!
//! **Same hits as [`super::TinyAccel`] and [`super::BruteForce`]**: per lane, the axis
//! permutation and shear of [`super::TriRay`] (the permuted components of a broadcast corner are
//! picked with one `vpermps` per axis), then `a_kx − S_x a_kz` etc., the edge functions, `det`,
//! `t` and the barycentrics with the same operations in the same order (Rust never contracts to
//! FMA). Triangles are visited in index order and a lane takes a hit only if it is strictly
//! closer, so ties keep the lowest index. A lane in which some edge function may be exactly zero
//! (for any triangle: `u·v·w` is ±0 or NaN, which also flags underflow, harmlessly) is
//! recomputed by [`super::BruteForce`] (the scalar test with its f64 fallback). Without AVX2
//! every lane takes the brute force.
//!
//! Tests: unit tests below (random soups of 1–64 triangles, a mesh of 160 triangles with shared
//! corners over three groups, the Cornell box with rays leaving its surfaces, zero-edge rays
//! through shared corners, inactive lanes, ties); `examples/tiny_rays.rs` times it against
//! [`super::TinyAccel`].

// The SIMD fast paths exist on x86-64 only; elsewhere the scalar paths run (same results).
#![cfg_attr(not(target_arch = "x86_64"), allow(dead_code, unused_imports, unused_variables))]

use super::{BruteForce, Hit};
use crate::geometry::Ray;
use crate::math::Vec3;

/// Rays per packet (SIMD lanes).
pub const PACKET: usize = 8;

/// Eight rays, structure of arrays. A lane with `tmax ≤ 0` is inactive (never hits).
#[derive(Clone, Copy, Debug, Default)]
pub struct RayPacket {
    /// Origins, `o[axis][lane]`.
    pub o: [[f32; PACKET]; 3],
    /// Directions (need not be normalised), `d[axis][lane]`.
    pub d: [[f32; PACKET]; 3],
    /// Largest parameter per lane.
    pub tmax: [f32; PACKET],
}

impl RayPacket {
    /// Whether some lane is active (`tmax > 0`).
    #[inline]
    pub fn any_active(&self) -> bool {
        self.tmax.iter().any(|&t| t > 0.0)
    }

    /// The ray of lane `l`.
    pub fn ray(&self, l: usize) -> Ray {
        Ray {
            o: Vec3::new(self.o[0][l], self.o[1][l], self.o[2][l]),
            d: Vec3::new(self.d[0][l], self.d[1][l], self.d[2][l]),
            tmax: self.tmax[l],
        }
    }
    /// Sets lane `l` to `ray`.
    pub fn set(&mut self, l: usize, ray: &Ray) {
        for a in 0..3 {
            self.o[a][l] = ray.o[a];
            self.d[a][l] = ray.d[a];
        }
        self.tmax[l] = ray.tmax;
    }

    /// The packet of `rays` in lanes `0..rays.len()` (at most [`PACKET`]), the other lanes
    /// inactive.
    pub fn from_rays(rays: &[Ray]) -> RayPacket {
        assert!(rays.len() <= PACKET, "{} rays for a packet of {PACKET}", rays.len());
        let mut p = RayPacket::default();
        for (l, r) in rays.iter().enumerate() {
            p.set(l, r);
        }
        p
    }
}

// The AVX-512 intrinsics (and the `avx512*` target features, which `gonio/fast.rs` enables
// too) are stable since Rust 1.89, the workspace's `rust-version`.
#[cfg(target_arch = "x86_64")]
#[path = "packet_avx512.rs"]
mod avx512;

/// A triangle corner padded to 16 bytes (one 128-bit load).
#[derive(Clone, Copy, Debug)]
#[repr(C, align(16))]
struct Corner([f32; 4]);

/// Triangles per [`Group`]: at most `3 · GROUP` distinct corners, transformed into a scratch
/// buffer on the stack (96 bytes per corner).
const GROUP: usize = 64;

/// Bytes per sheared corner in the scratch buffer (three `__m256`).
const SHEARED_BYTES: u32 = 96;

/// Consecutive triangles, their distinct corners and their bounds.
#[derive(Clone, Debug)]
struct Group {
    /// The distinct corners (by bit pattern) of the group's triangles.
    verts: Vec<Corner>,
    /// Per triangle: the byte offsets of its three sheared corners in the scratch buffer
    /// (`96 ·` their index in `verts`), and the triangle's index in the soup (its bits).
    tris: Vec<[u32; 4]>,
    /// Bounds of the group's triangles (minima, maxima) for the packet's slab test.
    lo: [f32; 3],
    hi: [f32; 3],
}

/// Cost model of [`plan_groups`], in vector operations per packet: the slab test of a group's
/// box, the shear of one distinct corner, the test of one triangle (counted from the kernel).
const COST_BOX: f64 = 30.0;
const COST_CORNER: f64 = 12.0;
const COST_TRI: f64 = 35.0;
/// Independent rays a packet counts as for the chance that one of its lanes enters a box (the
/// lanes are eight paths, partly coherent).
const RAYS_PER_PACKET: i32 = 4;

/// Splits the soup, in index order, into runs of at most [`GROUP`] triangles that minimise the
/// expected cost of a packet: a run costs its box test plus, when some lane enters its box
/// (chance from the box's surface area relative to the soup's, as in the SAH), the shear of
/// its distinct corners and its triangle tests. Dynamic programming over the run ends; index
/// order is kept so that ties still go to the lowest index. Returns the runs' start indices
/// (the first is 0) — any split gives the same hits, only the speed depends on it.
fn plan_groups(tris: &[[Vec3; 3]]) -> Vec<usize> {
    let n = tris.len();
    let area = |lo: Vec3, hi: Vec3| {
        let e = (hi - lo).max(Vec3::ZERO);
        2.0 * (e.x as f64 * e.y as f64 + e.y as f64 * e.z as f64 + e.z as f64 * e.x as f64)
    };
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for p in tris.iter().flatten() {
        (lo, hi) = (lo.min(*p), hi.max(*p));
    }
    let whole = area(lo, hi);
    let mut best = vec![f64::INFINITY; n + 1];
    let mut from = vec![0usize; n + 1];
    best[0] = 0.0;
    let mut corners = std::collections::HashSet::new();
    for j in 1..=n {
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        corners.clear();
        for i in (j.saturating_sub(GROUP)..j).rev() {
            for p in &tris[i] {
                (lo, hi) = (lo.min(*p), hi.max(*p));
                corners.insert([p.x.to_bits(), p.y.to_bits(), p.z.to_bits()]);
            }
            let p = if whole > 0.0 { (area(lo, hi) / whole).clamp(0.0, 1.0) } else { 1.0 };
            let enter = 1.0 - (1.0 - p).powi(RAYS_PER_PACKET);
            let work = COST_CORNER * corners.len() as f64 + COST_TRI * (j - i) as f64;
            let cost = best[i] + COST_BOX + enter * work;
            if cost < best[j] {
                (best[j], from[j]) = (cost, i);
            }
        }
    }
    let mut starts = Vec::new();
    let mut j = n;
    while j > 0 {
        j = from[j];
        starts.push(j);
    }
    starts.reverse();
    starts
}

/// Tiny triangle soup for [`RayPacket`] queries (see the module docs).
#[derive(Clone, Debug)]
pub struct PacketAccel {
    /// Number of triangles.
    len: usize,
    groups: Vec<Group>,
    /// The scalar test for lanes with a zero edge function and CPUs without AVX2.
    brute: BruteForce,
    /// AVX2 kernels ([`crate::simd::isa`], read when built).
    avx2: bool,
    /// The 16-lane AVX-512 kernel (`packet_avx512.rs`; read when built).
    avx512: bool,
}

impl PacketAccel {
    /// Wraps a triangle soup (the cost per packet is linear in the triangle count: meant for a
    /// few dozen).
    pub fn new(tris: Vec<[Vec3; 3]>) -> Self {
        let starts = plan_groups(&tris);
        let mut groups = Vec::new();
        for (k, &s) in starts.iter().enumerate() {
            let e = starts.get(k + 1).copied().unwrap_or(tris.len());
            let mut verts: Vec<Corner> = Vec::new();
            let mut index = std::collections::HashMap::new();
            let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
            let ids = (s..e)
                .map(|t| {
                    let mut e = [0u32; 4];
                    for (c, p) in tris[t].iter().enumerate() {
                        (lo, hi) = (lo.min(*p), hi.max(*p));
                        let key = [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()];
                        let v = *index.entry(key).or_insert_with(|| {
                            verts.push(Corner([p.x, p.y, p.z, 0.0]));
                            verts.len() as u32 - 1
                        });
                        e[c] = v * SHEARED_BYTES;
                    }
                    e[3] = t as u32;
                    e
                })
                .collect();
            groups.push(Group { verts, tris: ids, lo: lo.to_array(), hi: hi.to_array() });
        }
        let isa = crate::simd::isa();
        PacketAccel {
            len: tris.len(),
            groups,
            brute: BruteForce::new(tris),
            avx2: isa.avx2(),
            avx512: isa.avx512(),
        }
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether there are no triangles.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Closest hit of every lane with `0 < t < tmax` (`None` for misses and inactive lanes).
    pub fn intersect(&self, rays: &RayPacket) -> [Option<Hit>; PACKET] {
        let h = self.intersect_lanes(rays);
        std::array::from_fn(|l| h.hit(l))
    }

    /// [`PacketAccel::intersect`] as a structure of arrays (`prim < 0`: no hit).
    #[inline]
    pub fn intersect_lanes(&self, rays: &RayPacket) -> PacketHits {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: the CPU supports AVX2 (detected when built).
            return unsafe { self.intersect_avx2(rays) };
        }
        let mut h = PacketHits::NONE;
        for l in 0..PACKET {
            h.set(l, self.brute.intersect(&rays.ray(l)));
        }
        h
    }

    /// Which lanes hit a triangle with `0 < t < tmax` (bit `l` = lane `l`; inactive lanes
    /// clear): [`BruteForce::occluded`] per lane. With AVX2 the barycentrics are not computed
    /// and the triangle loop stops once every active lane has a hit.
    pub fn occluded_lanes(&self, rays: &RayPacket) -> u32 {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: the CPU supports AVX2 (detected when built).
            let h = unsafe { self.kernel_avx2::<true>(rays) };
            return (0..PACKET).filter(|&l| h.prim[l] >= 0).fold(0, |m, l| m | 1 << l);
        }
        (0..PACKET)
            .filter(|&l| rays.tmax[l] > 0.0 && self.brute.occluded(&rays.ray(l)))
            .fold(0, |m, l| m | 1 << l)
    }

    /// [`PacketAccel::intersect_lanes`] with AVX2 (callers compiled with AVX2 may inline it).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[inline]
    pub(crate) fn intersect_avx2(&self, rays: &RayPacket) -> PacketHits {
        self.kernel_avx2::<false>(rays)
    }

    /// The packet kernel: closest hits, or (`ANY`) for each lane some hit before `tmax` (`prim`
    /// of a hit triangle, `t`, `b1`, `b2` meaningless) with the loop ending once every active
    /// lane has one.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[inline]
    fn kernel_avx2<const ANY: bool>(&self, rays: &RayPacket) -> PacketHits {
        use std::arch::x86_64::*;
        use std::mem::MaybeUninit;
        if self.len == 0 {
            return PacketHits::NONE;
        }
        // Per lane, branch-free: the axis choice and shear of `TriRay::new`, except that kx, ky
        // are always (kz + 1, kz + 2) mod 3: `TriRay` swaps them when d_kz < 0, which negates u,
        // v, w, det and tt exactly (IEEE `a − b = −(b − a)`) and leaves the sign tests, t and the
        // barycentrics bit for bit unchanged.
        // SAFETY (all loads and stores below): unaligned 8-lane accesses to `[_; 8]` arrays.
        let ldf = |a: &[f32; PACKET]| unsafe { _mm256_loadu_ps(a.as_ptr()) };
        let (dx, dy, dz) = (ldf(&rays.d[0]), ldf(&rays.d[1]), ldf(&rays.d[2]));
        let abs = |x| _mm256_andnot_ps(_mm256_set1_ps(-0.0), x);
        let (ax, ay, az) = (abs(dx), abs(dy), abs(dz));
        let gt = |a, b| _mm256_cmp_ps::<_CMP_GT_OQ>(a, b);
        // kz = ax > ay ? (ax > az ? 0 : 2) : (ay > az ? 1 : 2), as masks
        let x_gt_y = gt(ax, ay);
        let kz0 = _mm256_and_ps(x_gt_y, gt(ax, az));
        let kz1 = _mm256_andnot_ps(x_gt_y, gt(ay, az));
        // component k of (x, y, z) per lane, k given by the masks "k = 0" and "k = 1"
        let pick = |m0, m1, x, y, z| _mm256_blendv_ps(_mm256_blendv_ps(z, y, m1), x, m0);
        let all = _mm256_castsi256_ps(_mm256_set1_epi32(-1));
        let kz2 = _mm256_andnot_ps(_mm256_or_ps(kz0, kz1), all);
        // kx = kz + 1 mod 3: 0 iff kz = 2, 1 iff kz = 0; ky = kz + 2 mod 3: 0 iff kz = 1, 1 iff kz = 2
        let (kx0, kx1) = (kz2, kz0);
        let (ky0, ky1) = (kz1, kz2);
        let d_kz = pick(kz0, kz1, dx, dy, dz);
        let sz = _mm256_div_ps(_mm256_set1_ps(1.0), d_kz);
        let sx = _mm256_mul_ps(pick(kx0, kx1, dx, dy, dz), sz);
        let sy = _mm256_mul_ps(pick(ky0, ky1, dx, dy, dz), sz);
        let (o0, o1, o2) = (ldf(&rays.o[0]), ldf(&rays.o[1]), ldf(&rays.o[2]));
        let (ox, oy, oz) =
            (pick(kx0, kx1, o0, o1, o2), pick(ky0, ky1, o0, o1, o2), pick(kz0, kz1, o0, o1, o2));
        // axis indices for the in-lane permutes: k = 0, 1 or 2
        let index = |m0, m1| {
            let i = _mm256_blendv_ps(_mm256_set1_ps(2.0), _mm256_set1_ps(1.0), m1);
            _mm256_cvttps_epi32(_mm256_blendv_ps(i, _mm256_set1_ps(0.0), m0))
        };
        let (ikx, iky, ikz) = (index(kx0, kx1), index(ky0, ky1), index(kz0, kz1));
        let zero = _mm256_setzero_ps();
        let one = _mm256_set1_ps(1.0);
        let mut best_t = ldf(&rays.tmax);
        let mut best_i = _mm256_set1_ps(f32::from_bits(u32::MAX)); // -1: no hit
        // the winners' barycentrics (`v · (1/det)`, `w · (1/det)`: the scalar test's bits);
        // two blended registers rather than `v`, `w`, `1/det` (fewer spills in the loop)
        let (mut best_b1, mut best_b2) = (zero, zero);
        let mut zany = zero;
        // ANY: lanes still looking for a hit (sign bit set; inactive lanes never hit)
        let mut open = _mm256_cmp_ps::<_CMP_GT_OQ>(best_t, zero);
        // The sheared corners `(px, py, pz)` of a group, per lane, computed once per distinct
        // corner: a corner shared by several triangles gives each of them the same bits.
        let mut sheared = [const { MaybeUninit::<[__m256; 3]>::uninit() }; 3 * GROUP];
        // The slab test of a group's box, `Bvh`'s (`bvh::avx::box8`) with one box and eight
        // rays: near/far planes by the sign of the inverse direction, NaN (`0 · ∞`) not
        // constraining, the far distance widened by `1 + 2γ₃`, the segment `(0, best_t)`. It
        // never rejects a group holding a triangle the watertight test would hit closer than
        // `best_t` (pbrt-v4's conservative box test), so skipping the group changes no hit.
        let inv = [_mm256_div_ps(one, dx), _mm256_div_ps(one, dy), _mm256_div_ps(one, dz)];
        let neg = inv.map(|i| _mm256_cmp_ps::<_CMP_LT_OQ>(i, zero));
        let o = [o0, o1, o2];
        let active = _mm256_cmp_ps::<_CMP_GT_OQ>(best_t, zero);
        'groups: for g in &self.groups {
            let enters = super::bvh::avx::slab8(g.lo, g.hi, &o, &inv, &neg, best_t);
            let lanes = if ANY { open } else { active };
            if _mm256_movemask_ps(_mm256_and_ps(enters, lanes)) == 0 {
                continue;
            }
            for (slot, c) in sheared.iter_mut().zip(&g.verts) {
                // SAFETY: `Corner` is 16-byte aligned and holds 4 floats.
                let p = unsafe { _mm256_broadcast_ps(&*(c.0.as_ptr() as *const __m128)) };
                // both 128-bit halves hold the corner: an in-lane permute picks axis k per lane
                let az = _mm256_sub_ps(_mm256_permutevar_ps(p, ikz), oz);
                let ax = _mm256_sub_ps(_mm256_permutevar_ps(p, ikx), ox);
                let ay = _mm256_sub_ps(_mm256_permutevar_ps(p, iky), oy);
                slot.write([
                    _mm256_sub_ps(ax, _mm256_mul_ps(sx, az)),
                    _mm256_sub_ps(ay, _mm256_mul_ps(sy, az)),
                    _mm256_mul_ps(sz, az),
                ]);
            }
            for (n, tri) in g.tris.iter().enumerate() {
                if ANY && n % 8 == 0 && _mm256_movemask_ps(open) == 0 {
                    break 'groups;
                }
                // SAFETY: the offsets are those of slots below `verts.len()` ≤ 3·GROUP (`new`),
                // which the loop above wrote.
                let [a, b, c] = [0, 1, 2].map(|k| unsafe {
                    sheared.as_ptr().cast::<u8>().add(tri[k] as usize).cast::<[__m256; 3]>().read()
                });
                let [px, py, pz] = [0, 1, 2].map(|k| [a[k], b[k], c[k]]);
                let edge = |i: usize, j: usize| {
                    _mm256_sub_ps(_mm256_mul_ps(px[i], py[j]), _mm256_mul_ps(py[i], px[j]))
                };
                let (u, v, w) = (edge(2, 1), edge(0, 2), edge(1, 0));
                // Some edge function exactly ±0 ⇒ the product u·v·w is ±0 or NaN (0·∞), which
                // the unordered comparison catches; an underflowing product or a NaN input also
                // flags the lane, which then merely takes the exact scalar path.
                let z = _mm256_cmp_ps::<_CMP_EQ_UQ>(_mm256_mul_ps(_mm256_mul_ps(u, v), w), zero);
                zany = _mm256_or_ps(zany, z);
                // Lanes with a zero edge function are recomputed by the scalar loop, so here u,
                // v, w are non-zero: mixed signs ⇔ the sign bits differ (`TriRay`'s test for
                // such values). Then `det ≠ 0`, and `TriRay`'s check `(tt > 0) == (det > 0)`
                // only rejects lanes with `t = tt · (1/det) ≤ 0` or NaN, which `t > 0` rejects
                // as well.
                let mixed = _mm256_or_ps(_mm256_xor_ps(u, v), _mm256_xor_ps(u, w));
                let det = _mm256_add_ps(_mm256_add_ps(u, v), w);
                let inv = _mm256_div_ps(one, det);
                let tt = _mm256_add_ps(
                    _mm256_add_ps(_mm256_mul_ps(u, pz[0]), _mm256_mul_ps(v, pz[1])),
                    _mm256_mul_ps(w, pz[2]),
                );
                let t = _mm256_mul_ps(tt, inv);
                // sign bit set where the signs agree and 0 < t < best so far (`best_t` starts
                // at tmax and only decreases; triangles in index order, so ties keep the
                // lowest index); blends look at the sign bit only
                let ok = _mm256_andnot_ps(mixed, _mm256_cmp_ps::<_CMP_GT_OQ>(t, zero));
                let take = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_LT_OQ>(t, best_t));
                // SAFETY: `tri[3]` is an initialised u32, read as the bits of an f32.
                let i = unsafe { _mm256_broadcast_ss(&*(&tri[3] as *const u32 as *const f32)) };
                best_i = _mm256_blendv_ps(best_i, i, take);
                if ANY {
                    // `best_t` stays at tmax: any hit before it will do
                    open = _mm256_andnot_ps(take, open);
                    continue;
                }
                best_t = _mm256_blendv_ps(best_t, t, take);
                best_b1 = _mm256_blendv_ps(best_b1, _mm256_mul_ps(v, inv), take);
                best_b2 = _mm256_blendv_ps(best_b2, _mm256_mul_ps(w, inv), take);
            }
        }
        let best_i = _mm256_castps_si256(best_i);
        let mut h = PacketHits::NONE;
        // SAFETY: as above.
        unsafe {
            _mm256_storeu_ps(h.t.as_mut_ptr(), best_t);
            _mm256_storeu_ps(h.b1.as_mut_ptr(), best_b1);
            _mm256_storeu_ps(h.b2.as_mut_ptr(), best_b2);
            _mm256_storeu_si256(h.prim.as_mut_ptr().cast(), best_i);
        }
        let mut zmask = _mm256_movemask_ps(zany) as u32;
        // Inactive lanes (`tmax ≤ 0`, e.g. a default ray with NaN edge products) never hit: no
        // scalar recomputation for them.
        for l in 0..PACKET {
            let active = rays.tmax[l] > 0.0; // false for NaN too
            if zmask & (1 << l) != 0 && !active {
                zmask &= !(1 << l);
                h.set(l, None);
            }
        }
        while zmask != 0 {
            // Rare: an exactly-zero edge function: the scalar test with its f64 recomputation.
            let l = zmask.trailing_zeros() as usize;
            zmask &= zmask - 1;
            if ANY {
                h.prim[l] = if self.brute.occluded(&rays.ray(l)) { 0 } else { -1 };
            } else {
                h.set(l, self.brute.intersect(&rays.ray(l)));
            }
        }
        h
    }
}

/// Closest hits of a [`RayPacket`], structure of arrays: lane `l` hit triangle `prim[l]` at
/// `t[l]` with barycentrics `b1[l]`, `b2[l]`; `prim[l] < 0` = no hit (the other fields are then
/// meaningless).
#[derive(Clone, Copy, Debug)]
pub struct PacketHits {
    /// Ray parameters.
    pub t: [f32; PACKET],
    /// Triangle indices, −1 for no hit.
    pub prim: [i32; PACKET],
    /// Barycentric coordinates of the second corner.
    pub b1: [f32; PACKET],
    /// Barycentric coordinates of the third corner.
    pub b2: [f32; PACKET],
}

impl PacketHits {
    /// No hit in any lane.
    pub const NONE: PacketHits =
        PacketHits { t: [0.0; PACKET], prim: [-1; PACKET], b1: [0.0; PACKET], b2: [0.0; PACKET] };

    /// The hit of lane `l`.
    #[inline]
    pub fn hit(&self, l: usize) -> Option<Hit> {
        (self.prim[l] >= 0).then(|| Hit {
            t: self.t[l],
            prim: self.prim[l] as u32,
            b1: self.b1[l],
            b2: self.b2[l],
        })
    }

    /// Sets lane `l` to `hit`.
    #[inline]
    pub fn set(&mut self, l: usize, hit: Option<Hit>) {
        match hit {
            Some(h) => {
                self.t[l] = h.t;
                self.prim[l] = h.prim as i32;
                self.b1[l] = h.b1;
                self.b2[l] = h.b2;
            }
            None => self.prim[l] = -1,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::scenes;
    use crate::sampling::{Rng, square_to_cosine_hemisphere};

    fn check(tris: Vec<[Vec3; 3]>, rays: &[Ray]) {
        let pa = PacketAccel::new(tris.clone());
        let bf = BruteForce::new(tris);
        let mut prev = RayPacket::default();
        for chunk in rays.chunks(PACKET) {
            let p = RayPacket::from_rays(chunk);
            #[cfg(target_arch = "x86_64")]
            if pa.avx512() {
                // the 16-lane kernel: this packet beside the previous one, bit for bit
                // SAFETY: AVX-512 and AVX2 detected (`avx512()`).
                let got = unsafe { pa.intersect16_avx512(&prev, &p) };
                for (g, q) in got.iter().zip([&prev, &p]) {
                    let w = pa.intersect_lanes(q);
                    let bits = |a: &[f32; PACKET]| a.map(f32::to_bits);
                    assert_eq!(
                        (bits(&g.t), bits(&g.b1), bits(&g.b2), g.prim),
                        (bits(&w.t), bits(&w.b1), bits(&w.b2), w.prim)
                    );
                }
            }
            prev = p;
            let got = pa.intersect(&p);
            let blocked = pa.occluded_lanes(&p);
            for (l, r) in chunk.iter().enumerate() {
                assert_eq!(got[l], bf.intersect(r), "lane {l}: {r:?}");
                assert_eq!(blocked >> l & 1 == 1, bf.occluded(r), "any hit, lane {l}: {r:?}");
            }
            for g in &got[chunk.len()..] {
                assert_eq!(*g, None, "inactive lanes never hit");
            }
            assert_eq!(blocked >> chunk.len(), 0, "inactive lanes are never blocked");
        }
    }

    #[test]
    fn random_soups_match_brute_force() {
        for (seed, n) in [(0u64, 1usize), (1, 7), (2, 8), (3, 31), (4, 64)] {
            let tris = scenes::random_soup(n, 0.5, seed);
            let mut rng = Rng::new(seed, 11, 0);
            let rays: Vec<Ray> = (0..4003)
                .map(|i| {
                    let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 3.0 - 1.5;
                    let d = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - 1.0;
                    let tmax = if i % 3 == 0 { rng.next_f32() * 2.0 } else { f32::INFINITY };
                    Ray { o, d, tmax }
                })
                .collect();
            check(tris, &rays);
        }
    }

    #[test]
    fn meshes_with_shared_corners_over_several_groups_match_brute_force() {
        // A 10 × 8 grid of quads (160 triangles: three groups or more), corners shared between up to six
        // triangles and between groups, heights jittered; rays from above and below, some
        // through grid corners (exact-zero edge functions).
        let mut rng = Rng::new(3, 9, 0);
        let (nx, ny) = (10usize, 8usize);
        let h: Vec<f32> = (0..(nx + 1) * (ny + 1)).map(|_| rng.next_f32() * 0.3).collect();
        let p = |i: usize, j: usize| Vec3::new(i as f32 * 0.25, j as f32 * 0.25, h[j * (nx + 1) + i]);
        let mut tris = Vec::new();
        for j in 0..ny {
            for i in 0..nx {
                tris.push([p(i, j), p(i + 1, j), p(i + 1, j + 1)]);
                tris.push([p(i, j), p(i + 1, j + 1), p(i, j + 1)]);
            }
        }
        let pa = PacketAccel::new(tris.clone());
        assert!(pa.groups.len() >= 3, "{} groups", pa.groups.len());
        let ids: Vec<u32> = pa.groups.iter().flat_map(|g| g.tris.iter().map(|t| t[3])).collect();
        assert_eq!(ids, (0..tris.len() as u32).collect::<Vec<_>>(), "runs in index order");
        assert!(pa.groups.iter().all(|g| g.tris.len() <= GROUP));
        let mut rays = Vec::new();
        for k in 0..6000 {
            let target = Vec3::new(rng.next_f32() * 2.5, rng.next_f32() * 2.0, 0.15);
            let target = if k % 5 == 0 { p(k % (nx + 1), (k / 7) % (ny + 1)) } else { target };
            let up = k % 2 == 0;
            let o = Vec3::new(
                rng.next_f32() * 3.0 - 0.25,
                rng.next_f32() * 2.5 - 0.25,
                if up { -1.0 } else { 2.0 },
            );
            rays.push(Ray::new(o, target - o));
        }
        check(tris, &rays);
    }

    #[test]
    fn cornell_box_rays_from_its_surfaces_match_brute_force() {
        // What the light tracer traces: rays leaving points of the surfaces, cosine-distributed,
        // plus axis-aligned directions (zero components) and rays through shared corners.
        let tris = scenes::cornell_box();
        let mut rng = Rng::new(7, 3, 0);
        let mut rays = Vec::new();
        for i in 0..20_000usize {
            let tri = tris[i % tris.len()];
            let (b1, b2) = (rng.next_f32() * 0.5, rng.next_f32() * 0.5);
            let p = tri[0] * (1.0 - b1 - b2) + tri[1] * b1 + tri[2] * b2;
            let ng = (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize();
            let n = if rng.next_f32() < 0.5 { ng } else { -ng };
            let f = crate::math::Frame::from_normal(n);
            let d = f.to_world(square_to_cosine_hemisphere(rng.next_2d()));
            rays.push(crate::accel::spawn_ray(p, ng, d));
        }
        for a in Vec3::AXES {
            for s in [1.0f32, -1.0] {
                rays.push(Ray::new(Vec3::new(0.1, 0.2, 0.3), a * s));
                rays.push(Ray::new(Vec3::ZERO, a * s));
            }
        }
        for tri in &tris {
            for c in tri {
                rays.push(Ray::new(Vec3::new(0.05, 0.1, -0.02), *c - Vec3::new(0.05, 0.1, -0.02)));
            }
        }
        check(tris, &rays);
    }

    #[test]
    fn ties_keep_the_lowest_index_and_zero_edges_take_the_scalar_path() {
        let tri = [Vec3::new(0.0, 0.0, 1.0), Vec3::new(1.0, 0.0, 1.0), Vec3::new(0.0, 1.0, 1.0)];
        let far = [Vec3::new(0.0, 0.0, 2.0), Vec3::new(1.0, 0.0, 2.0), Vec3::new(0.0, 1.0, 2.0)];
        let rays = [
            Ray::new(Vec3::new(0.2, 0.2, 0.0), Vec3::Z),
            // through the shared corner (0, 0): exact-zero edge functions
            Ray::new(Vec3::ZERO, Vec3::Z),
            Ray::new(Vec3::new(0.2, 0.2, 1.5), -Vec3::Z),
        ];
        let pa = PacketAccel::new(vec![far, tri, tri, far, tri]);
        let p = RayPacket::from_rays(&rays);
        let h = pa.intersect(&p);
        assert_eq!(h[0].map(|h| (h.prim, h.t)), Some((1, 1.0)));
        assert_eq!(h[1].map(|h| (h.prim, h.t)), Some((1, 1.0)));
        assert_eq!(h[2].map(|h| (h.prim, h.t)), Some((1, 0.5)));
        check(vec![far, tri, tri, far, tri], &rays);
    }
}
