//! Big triangles apart: a scene's few large triangles (a room's walls, floor and ceiling, an
//! area light) tested all at once, the many small ones (a scanned object) behind an 8-wide BVH
//! that a ray enters only if it reaches the small triangles' bounds.
//!
//! **Why.** In an "object in a room" scene — the de-lighting and benchmark case — most rays go
//! from wall to wall. Behind one BVH each such ray still walks the root, the leaves of the
//! walls (whose boxes span the room) and often the object's subtrees, at the cost of a full
//! traversal. With the walls apart, eight rays are tested against them in one pass of the
//! packet kernel ([`PacketAccel`], one ray per SIMD lane), and only the rays whose segment up to
//! their wall hit meets the object's bounds walk the BVH: on the scanned-object room
//! (`examples/make_scan_room.rs`) about one ray in six.
//!
//! **Which triangles.** [`SplitAccel::choose`] ranks the triangles by the surface area of their
//! bounding boxes and takes the `k ≤ `[`BIG_MAX`] largest that minimise the expected cost per ray
//! `k + C · A(small) / A(all)` — `k` triangle tests in the packet, plus the BVH's cost `C` (in
//! triangle tests, [`BVH_COST`]) times the probability that a ray meeting the scene's bounds also
//! meets the small triangles' bounds (ratio of box surface areas, the SAH's estimate). A scan
//! alone, a sphere or a finely tessellated room gives `k = 0`: a plain [`Bvh`].
//!
//! **Same hits as one structure.** Both parts use the watertight test of [`super::triangle`]
//! with the same arithmetic, so every triangle's `t` and barycentrics are those of
//! [`super::BruteForce`]. The big triangles are tested first; the BVH then searches below their
//! closest `t` (strictly), so on an exact tie of `t` the big triangle wins. Single rays
//! ([`SplitAccel::intersect`]) and packets ([`SplitAccel::intersect8`]) follow the same rule and
//! return the same bits; the lanes that skip the BVH are those whose segment misses its bounds
//! by the BVH's own slab test ([`Bvh::enters8`]), which can find no hit there.
//!
//! Tests: `tests` below (against brute force on a room with a dense object, single rays vs
//! packets bit for bit, the choice on scenes with and without large triangles);
//! `crates/opal/tests/accel.rs`.

use super::packet::{PACKET, PacketAccel, PacketHits, RayPacket};
use super::{Bvh, Hit, TinyAccel};
use crate::geometry::Ray;
use crate::math::Vec3;

/// At most this many triangles are set apart (each costs every ray one packet lane test).
pub const BIG_MAX: usize = 64;

/// The BVH's cost per ray that enters it, in triangle tests of the packet kernel (measured on
/// the scanned-object room: ≈ 0.9 ns per triangle and ray in the packet, ≈ 100–150 ns per ray
/// walking the object's BVH; rounded down so that triangles are set apart only for a clear
/// gain).
pub const BVH_COST: f32 = 96.0;

/// The big triangles in a packet structure, the rest in a BVH (see the module docs).
#[derive(Clone, Debug)]
pub struct SplitAccel {
    single: TinyAccel,
    packet: PacketAccel,
    /// Soup index of each big triangle.
    big_ids: Vec<u32>,
    /// The small triangles; their hits carry soup indices.
    bvh: Bvh,
}

/// Surface area of the box `(lo, hi)` (0 when empty).
fn box_area(lo: Vec3, hi: Vec3) -> f32 {
    let e = (hi - lo).max(Vec3::ZERO);
    2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
}

fn tri_bounds(t: &[Vec3; 3]) -> (Vec3, Vec3) {
    (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2]))
}

impl SplitAccel {
    /// The soup indices of the triangles to set apart (largest box first), or an empty list
    /// when a plain BVH is expected to be as fast (see the module docs).
    pub fn choose(tris: &[[Vec3; 3]]) -> Vec<u32> {
        let n = tris.len();
        if n <= BIG_MAX {
            return Vec::new();
        }
        let areas: Vec<f32> = tris
            .iter()
            .map(|t| {
                let (lo, hi) = tri_bounds(t);
                box_area(lo, hi)
            })
            .collect();
        // the BIG_MAX largest boxes (ties: lower index first), largest first
        let by_area = |a: &u32, b: &u32| areas[*b as usize].total_cmp(&areas[*a as usize]).then(a.cmp(b));
        let mut idx: Vec<u32> = (0..n as u32).collect();
        idx.select_nth_unstable_by(BIG_MAX - 1, by_area);
        let mut top = idx[..BIG_MAX].to_vec();
        top.sort_unstable_by(by_area);
        // bounds of the small triangles for each k: the rest beyond the top, then the top's
        // tail added back from the smallest
        let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        for &i in &idx[BIG_MAX..] {
            let (a, b) = tri_bounds(&tris[i as usize]);
            lo = lo.min(a);
            hi = hi.max(b);
        }
        let mut small_area = vec![0.0f32; BIG_MAX + 1];
        small_area[BIG_MAX] = box_area(lo, hi);
        for k in (0..BIG_MAX).rev() {
            let (a, b) = tri_bounds(&tris[top[k] as usize]);
            lo = lo.min(a);
            hi = hi.max(b);
            small_area[k] = box_area(lo, hi);
        }
        let all = small_area[0];
        if all.is_nan() || all <= 0.0 {
            return Vec::new();
        }
        let cost = |k: usize| k as f32 + BVH_COST * small_area[k] / all;
        let best = (0..=BIG_MAX).min_by(|&a, &b| cost(a).total_cmp(&cost(b)).then(a.cmp(&b))).unwrap_or(0);
        top.truncate(best);
        top
    }

    /// The structure with triangles `big` (soup indices, as from [`SplitAccel::choose`]) apart.
    ///
    /// # Panics
    /// If an index in `big` is out of range or repeated.
    pub fn new(tris: &[[Vec3; 3]], big: &[u32]) -> SplitAccel {
        let mut is_big = vec![false; tris.len()];
        for &i in big {
            assert!(!is_big[i as usize], "triangle {i} set apart twice");
            is_big[i as usize] = true;
        }
        let big_tris: Vec<[Vec3; 3]> = big.iter().map(|&i| tris[i as usize]).collect();
        let (small, small_ids): (Vec<[Vec3; 3]>, Vec<u32>) =
            (0..tris.len() as u32).filter(|&i| !is_big[i as usize]).map(|i| (tris[i as usize], i)).unzip();
        SplitAccel {
            single: TinyAccel::new(big_tris.clone()),
            packet: PacketAccel::new(big_tris),
            big_ids: big.to_vec(),
            bvh: Bvh::with_ids(&small, &small_ids),
        }
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.big_ids.len() + self.bvh.len()
    }

    /// Whether there are no triangles.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Number of triangles set apart.
    pub fn big_count(&self) -> usize {
        self.big_ids.len()
    }

    /// The BVH of the small triangles.
    pub fn bvh(&self) -> &Bvh {
        &self.bvh
    }

    /// Closest hit with `0 < t < ray.tmax` (on equal `t`, a big triangle).
    #[inline]
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        let big = self.single.intersect(ray).map(|h| Hit { prim: self.big_ids[h.prim as usize], ..h });
        let below = Ray { tmax: big.map_or(ray.tmax, |h| h.t), ..*ray };
        self.bvh.intersect(&below).or(big)
    }

    /// Whether any triangle is hit with `0 < t < ray.tmax`.
    #[inline]
    pub fn occluded(&self, ray: &Ray) -> bool {
        self.single.occluded(ray) || self.bvh.occluded(ray)
    }

    /// Closest hits of the eight rays of a packet (lanes with `tmax ≤ 0` are inactive and
    /// miss): the big triangles for all lanes in one packet pass, then the BVH for the lanes
    /// whose segment up to that hit meets its bounds; [`SplitAccel::intersect`] per lane.
    pub fn intersect8(&self, rays: &RayPacket) -> PacketHits {
        let mut hits = self.packet.intersect_lanes(rays);
        let mut below = *rays;
        for l in 0..PACKET {
            if hits.prim[l] >= 0 {
                hits.prim[l] = self.big_ids[hits.prim[l] as usize] as i32;
                below.tmax[l] = hits.t[l];
            }
        }
        let enter = self.bvh.enters8(&below);
        if enter == 0 {
            return hits;
        }
        for l in 0..PACKET {
            if enter >> l & 1 == 0 {
                below.tmax[l] = 0.0;
            }
        }
        let small = self.bvh.intersect8(&below);
        for l in 0..PACKET {
            if small.prim[l] >= 0 {
                hits.set(l, small.hit(l));
            }
        }
        hits
    }

    /// [`SplitAccel::intersect8`] of several packets at once, the same hits packet by packet:
    /// the big triangles per packet, then the rays of all packets that enter the BVH's bounds,
    /// gathered into full streams of eight. On an object in a room only about one ray in six
    /// enters, so packet by packet the BVH's interleaved traversal ([`Bvh::intersect8`]) would
    /// mostly run with one or two lanes and hide little of its memory latency.
    pub fn intersect8_many(&self, rays: &[RayPacket], hits: &mut [PacketHits]) {
        assert_eq!(rays.len(), hits.len(), "one hit record per packet");
        let mut queue = Gather::default();
        for j in 0..rays.len() {
            if !rays[j].any_active() {
                hits[j] = PacketHits::NONE;
                continue;
            }
            let h = &mut hits[j];
            *h = self.packet.intersect_lanes(&rays[j]);
            let mut below = rays[j];
            let mut hit = (0..PACKET).fold(0u32, |m, l| m | ((h.prim[l] >= 0) as u32) << l);
            while hit != 0 {
                let l = hit.trailing_zeros() as usize;
                hit &= hit - 1;
                h.prim[l] = self.big_ids[h.prim[l] as usize] as i32;
                below.tmax[l] = h.t[l];
            }
            let mut enter = self.bvh.enters8(&below);
            while enter != 0 {
                let l = enter.trailing_zeros() as usize;
                enter &= enter - 1;
                queue.push(&below, j, l);
                if queue.n == PACKET {
                    queue.flush_closest(&self.bvh, hits);
                }
            }
        }
        queue.flush_closest(&self.bvh, hits);
    }

    /// [`SplitAccel::occluded8`] of several packets at once (bit `l` of `blocked[j]` = lane `l`
    /// of packet `j`), the BVH's rays gathered into full streams as in
    /// [`SplitAccel::intersect8_many`].
    pub fn occluded8_many(&self, rays: &[RayPacket], blocked: &mut [u32]) {
        assert_eq!(rays.len(), blocked.len(), "one mask per packet");
        let mut queue = Gather::default();
        for j in 0..rays.len() {
            if !rays[j].any_active() {
                blocked[j] = 0;
                continue;
            }
            blocked[j] = self.packet.occluded_lanes(&rays[j]);
            let mut rest = rays[j];
            for l in 0..PACKET {
                if blocked[j] >> l & 1 != 0 {
                    rest.tmax[l] = 0.0;
                }
            }
            let enter = self.bvh.enters8(&rest);
            for l in 0..PACKET {
                if enter >> l & 1 != 0 {
                    queue.push(&rest, j, l);
                    if queue.n == PACKET {
                        queue.flush_occluded(&self.bvh, blocked);
                    }
                }
            }
        }
        queue.flush_occluded(&self.bvh, blocked);
    }

    /// Which lanes are blocked before `tmax` (bit `l` = lane `l`; inactive lanes clear): the
    /// big triangles first, the BVH for the lanes still open whose segment meets its bounds.
    pub fn occluded8(&self, rays: &RayPacket) -> u32 {
        let blocked = self.packet.occluded_lanes(rays);
        let mut rest = *rays;
        for l in 0..PACKET {
            if blocked >> l & 1 != 0 {
                rest.tmax[l] = 0.0;
            }
        }
        let enter = self.bvh.enters8(&rest);
        if enter == 0 {
            return blocked;
        }
        for l in 0..PACKET {
            if enter >> l & 1 == 0 {
                rest.tmax[l] = 0.0;
            }
        }
        blocked | self.bvh.occluded8(&rest)
    }
}

/// Rays of several packets queued for one BVH stream: lane `k` of `rays` is lane `lane[k]` of
/// packet `packet[k]`.
#[derive(Default)]
struct Gather {
    rays: RayPacket,
    packet: [usize; PACKET],
    lane: [usize; PACKET],
    n: usize,
}

impl Gather {
    #[inline]
    fn push(&mut self, from: &RayPacket, j: usize, l: usize) {
        let k = self.n;
        for a in 0..3 {
            self.rays.o[a][k] = from.o[a][l];
            self.rays.d[a][k] = from.d[a][l];
        }
        self.rays.tmax[k] = from.tmax[l];
        self.packet[k] = j;
        self.lane[k] = l;
        self.n += 1;
    }

    /// Makes the unused lanes inactive; whether any ray is queued.
    #[inline]
    fn prepare(&mut self) -> bool {
        for k in self.n..PACKET {
            self.rays.tmax[k] = 0.0;
        }
        self.n > 0
    }

    /// Traces the queued rays to their closest hits, stores those found and empties the queue.
    fn flush_closest(&mut self, bvh: &Bvh, hits: &mut [PacketHits]) {
        if !self.prepare() {
            return;
        }
        let small = bvh.intersect8(&self.rays);
        for k in 0..self.n {
            if let Some(h) = small.hit(k) {
                hits[self.packet[k]].set(self.lane[k], Some(h));
            }
        }
        self.n = 0;
    }

    /// Tests the queued rays for any hit, sets their bits and empties the queue.
    fn flush_occluded(&mut self, bvh: &Bvh, blocked: &mut [u32]) {
        if !self.prepare() {
            return;
        }
        let b = bvh.occluded8(&self.rays);
        for k in 0..self.n {
            blocked[self.packet[k]] |= (b >> k & 1) << self.lane[k];
        }
        self.n = 0;
    }
}
