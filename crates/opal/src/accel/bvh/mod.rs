//! Bounding volume hierarchy over a triangle soup: binned SAH build, 8-wide nodes, leaves of
//! eight triangles tested at once, ordered closest-hit and any-hit traversal (AVX2, with a
//! portable fallback that gives the same hits).
//!
//! * **Build** (`build.rs`): a binary tree by binned SAH with leaf *blocks* of eight triangles,
//!   then collapsed into 8-wide nodes (`collapse`): each node repeatedly opens its
//!   largest-area interior child until it has 8 children. Leaves hold at most eight triangles,
//!   stored as one `Group` (structure of arrays, the kernel of `crate::accel::group`).
//! * **Layout**: 256-byte nodes (four cache lines) holding the 8 children's boxes as
//!   `b[lo/hi][axis][lane]` — one 32-byte row per plane, so the slab test of the 8 boxes is
//!   six aligned loads — and per child a reference: an interior node index, a leaf group
//!   (`LEAF` bit + group index) or empty. Groups are stored in the depth-first order in which
//!   the collapse meets them, next to their siblings.
//! * **Traversal**: closest-hit tests the 8 boxes at once, visits the hit children nearest
//!   first and pushes the others with their entry distance (skipped on pop once a closer hit is
//!   known); any-hit tests leaf children as soon as their box is hit and returns at the first
//!   hit, without barycentrics ordering. The slab test selects near/far planes by the sign of
//!   the direction, ignores NaN from `0 · ∞` (treated as not constraining) and widens the far
//!   distance by `1 + 2γ₃` (pbrt-v4's conservative box test), so the BVH never culls a triangle
//!   the watertight test ([`super::triangle`]) would hit.
//! * **SIMD**: [`crate::simd::isa`] is read once at build time. The AVX2 traversal
//!   (`avx.rs`) performs the portable traversal's operations in the same order (no FMA; `max`/
//!   `min` with the same NaN rule), so both visit the same nodes and return the same hit, bit for
//!   bit (tested).
//! * **Packets / streams**: [`Bvh::intersect8`] answers eight independent rays (one
//!   [`RayPacket`], e.g. the light tracer's wavefront): with AVX2 their eight traversals are
//!   interleaved one visit at a time, each lane prefetching its next item while the others work
//!   (`stream.rs`), which hides memory latency on large scenes; same hits as single rays.
//!
//! Tests: unit tests below; `crates/opal/tests/accel.rs` (against brute force on random soups
//! and meshes with proptest, watertightness, self-intersection); benchmarks:
//! `examples/accel_compare.rs`, `benches/accel.rs`, `bench/accel_vs_embree.sh`.

#[cfg(target_arch = "x86_64")]
pub(super) mod avx;
mod build;
#[cfg(target_arch = "x86_64")]
mod stream;

pub use build::{BINS, MAX_LEAF, PAR_THRESHOLD, SahParams};

use super::Hit;
use super::group::{Group, LANES, ShearRay, group_hit_portable};
use super::packet::{PACKET, PacketHits, RayPacket};
use crate::geometry::Ray;
use crate::math::Vec3;
use build::BuildNode;
use std::mem::MaybeUninit;

/// Children per node.
pub const WIDTH: usize = 8;

/// `1 + 2γ₃` with `γₙ = n u / (1 − n u)`, `u = 2⁻²⁴` (pbrt-v4, robust box test).
pub(super) const BOX_FAR_SCALE: f32 =
    1.0 + 2.0 * (3.0 * f32::EPSILON * 0.5) / (1.0 - 3.0 * f32::EPSILON * 0.5);

/// Traversal stack size: each node pushes at most 7 entries and the 8-wide tree is no deeper
/// than the binary one.
const STACK: usize = (WIDTH - 1) * build::MAX_DEPTH + WIDTH;

/// A child reference: interior node index, `LEAF | group`, or [`EMPTY`].
const LEAF: u32 = 1 << 31;
/// An empty child slot (its box is empty: no ray enters it).
const EMPTY: u32 = u32::MAX;

/// A leaf: up to eight triangles and their input indices (`u32::MAX` in unused lanes), 320
/// bytes; the index sits next to the corners so that reading the winner's index costs no
/// cache miss.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(32))]
struct Leaf {
    tris: Group,
    prim: [u32; LANES],
}

/// 8-wide node, 256 bytes: the children's boxes `b[0 = lo, 1 = hi][axis][child]` and references.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
struct Node8 {
    b: [[[f32; WIDTH]; 3]; 2],
    child: [u32; WIDTH],
}

impl Node8 {
    const EMPTY: Node8 =
        Node8 { b: [[[f32::INFINITY; WIDTH]; 3], [[f32::NEG_INFINITY; WIDTH]; 3]], child: [EMPTY; WIDTH] };
}

/// Collapses the binary tree under `node` into 8-wide nodes (each node opens its largest-area
/// interior child until it has 8 children); leaves become groups of `tris` (in `refs` order).
/// Returns the index of the node.
///
/// A leaf's triangle indices are `ids[i]` for input triangle `i` (`i` itself without `ids`).
fn collapse(
    node: &BuildNode,
    refs: &[build::PrimRef],
    tris: &[[Vec3; 3]],
    ids: Option<&[u32]>,
    out: &mut Bvh,
) -> u32 {
    let idx = out.nodes.len();
    out.nodes.push(Node8::EMPTY);
    let mut kids: Vec<&BuildNode> = match node {
        BuildNode::Interior { children, .. } => vec![&children[0], &children[1]],
        BuildNode::Leaf { .. } => vec![node],
    };
    while kids.len() < WIDTH {
        let open = kids
            .iter()
            .enumerate()
            .filter(|(_, k)| matches!(k, BuildNode::Interior { .. }))
            .max_by(|a, b| a.1.bounds().half_area().total_cmp(&b.1.bounds().half_area()))
            .map(|(i, _)| i);
        let Some(i) = open else { break };
        let BuildNode::Interior { children, .. } = kids[i] else { unreachable!() };
        kids[i] = &children[0];
        kids.insert(i + 1, &children[1]);
    }
    let mut n = Node8::EMPTY;
    for (slot, k) in kids.iter().enumerate() {
        let b = k.bounds();
        for a in 0..3 {
            n.b[0][a][slot] = b.min[a];
            n.b[1][a][slot] = b.max[a];
        }
        n.child[slot] = match k {
            BuildNode::Leaf { start, count, .. } => {
                let (start, count) = (*start as usize, *count as usize);
                debug_assert!(count <= LANES);
                let g = out.leaves.len() as u32;
                let leaf: Vec<[Vec3; 3]> =
                    refs[start..start + count].iter().map(|r| tris[r.idx as usize]).collect();
                let mut prim = [u32::MAX; LANES];
                for (p, r) in prim.iter_mut().zip(&refs[start..start + count]) {
                    *p = ids.map_or(r.idx, |ids| ids[r.idx as usize]);
                }
                out.leaves.push(Leaf { tris: Group::new(&leaf), prim });
                LEAF | g
            }
            BuildNode::Interior { .. } => collapse(k, refs, tris, ids, out),
        };
    }
    out.nodes[idx] = n;
    idx as u32
}

/// Per-ray constants of the slab test.
#[derive(Clone, Copy)]
struct BoxRay {
    o: [f32; 3],
    inv: [f32; 3],
    /// Per axis, the index of the near plane in `Node8::b` (1 = maxima, for negative directions).
    near: [usize; 3],
}

impl BoxRay {
    #[inline(always)]
    fn new(ray: &Ray) -> Self {
        let inv = [1.0 / ray.d.x, 1.0 / ray.d.y, 1.0 / ray.d.z];
        BoxRay { o: ray.o.to_array(), inv, near: inv.map(|i| (i < 0.0) as usize) }
    }

    /// Entry distances of the eight child boxes and the mask of those overlapping `(0, tmax)`.
    #[inline(always)]
    fn hit8(&self, n: &Node8, tmax: f32) -> ([f32; WIDTH], u32) {
        let mut t0 = [0.0f32; WIDTH];
        let mut t1 = [tmax; WIDTH];
        for a in 0..3 {
            let (near, far) = (&n.b[self.near[a]][a], &n.b[1 - self.near[a]][a]);
            for l in 0..WIDTH {
                let tn = (near[l] - self.o[a]) * self.inv[a];
                let tf = (far[l] - self.o[a]) * self.inv[a] * BOX_FAR_SCALE;
                // `if` rather than f32::max/min: one maxps/minps each, and a NaN `tn`/`tf`
                // (0 · ∞) leaves the bound unchanged, i.e. does not constrain (conservative).
                t0[l] = if tn > t0[l] { tn } else { t0[l] };
                t1[l] = if tf < t1[l] { tf } else { t1[l] };
            }
        }
        let mut mask = 0;
        for l in 0..WIDTH {
            mask |= ((t0[l] <= t1[l]) as u32) << l;
        }
        (t0, mask)
    }
}

/// A pending child on the traversal stack.
#[derive(Clone, Copy)]
struct Entry {
    child: u32,
    tnear: f32,
}

/// The closest hit found so far by a traversal: (leaf, lane, t, b1, b2); the triangle index is
/// looked up once at the end ([`Bvh::hit_of`]).
type Best = Option<(usize, usize, f32, f32, f32)>;

/// Pops the next stacked item still in range (`tnear ≤ tmax`); `None` when the stack is empty.
#[inline(always)]
fn pop(stack: &[MaybeUninit<Entry>], sp: &mut usize, tmax: f32) -> Option<u32> {
    while *sp > 0 {
        *sp -= 1;
        // SAFETY: entries below `sp` were written.
        let e = unsafe { stack[*sp].assume_init() };
        if e.tnear <= tmax {
            return Some(e.child);
        }
    }
    None
}

/// Pushes the children of `mask` except the nearest onto `stack` (farthest deepest) and returns
/// the nearest. Children are ordered by entry distance, then by reference (deterministic).
#[inline(always)]
fn order_children(
    mask: u32,
    tn: &[f32; WIDTH],
    child: &[u32; WIDTH],
    stack: &mut [MaybeUninit<Entry>],
    sp: &mut usize,
) -> u32 {
    debug_assert!(mask != 0);
    let first = mask.trailing_zeros() as usize;
    let rest = mask & (mask - 1);
    if rest == 0 {
        return child[first];
    }
    // Entry distances are ≥ 0 (never NaN), so their bits order like the floats.
    let key = |l: usize| (tn[l].to_bits() as u64) << 32 | child[l] as u64;
    if rest & (rest - 1) == 0 {
        let second = rest.trailing_zeros() as usize;
        let (a, b) = (key(first), key(second));
        let (near, far) = if a <= b { (a, b) } else { (b, a) };
        stack[*sp].write(Entry { child: far as u32, tnear: f32::from_bits((far >> 32) as u32) });
        *sp += 1;
        return near as u32;
    }
    // Three or more: each child's rank among them (the keys are distinct: the references
    // are), without branches; rank 0 is visited next, rank r > 0 goes to stack slot
    // `sp + h − 1 − r` (the farthest deepest), the order an insertion sort would give.
    let mut keys = [u64::MAX; WIDTH];
    let mut h = 0;
    let mut m = mask;
    while m != 0 {
        let l = m.trailing_zeros() as usize;
        m &= m - 1;
        keys[h & (WIDTH - 1)] = key(l);
        h += 1;
    }
    let mut near = 0;
    for &k in &keys[..h] {
        let rank: usize = keys.iter().map(|&o| (o < k) as usize).sum();
        if rank == 0 {
            near = k;
        } else {
            stack[*sp + h - 1 - rank]
                .write(Entry { child: k as u32, tnear: f32::from_bits((k >> 32) as u32) });
        }
    }
    *sp += h - 1;
    near as u32
}

/// SAH bounding volume hierarchy of 8-wide nodes over a triangle soup (see the module docs).
#[derive(Clone, Debug)]
pub struct Bvh {
    nodes: Vec<Node8>,
    /// Leaves: up to eight triangles each (NaN in unused lanes) with their input indices.
    leaves: Vec<Leaf>,
    bounds: (Vec3, Vec3),
    len: usize,
    /// Whether the AVX2 traversal runs ([`crate::simd::isa`], read at build time).
    avx2: bool,
}

impl Bvh {
    /// Builds the hierarchy with the default SAH constants (parallel on the rayon pool).
    /// Degenerate triangles are accepted and never hit.
    ///
    /// # Panics
    /// If there are `2³¹` triangles or more.
    pub fn new(tris: Vec<[Vec3; 3]>) -> Bvh {
        Bvh::with_params(&tris, SahParams::default())
    }

    /// Builds the hierarchy with the given SAH constants.
    ///
    /// # Panics
    /// If there are `2³¹` triangles or more.
    pub fn with_params(tris: &[[Vec3; 3]], sah: SahParams) -> Bvh {
        Bvh::build(tris, None, sah)
    }

    /// Builds the hierarchy over `tris` whose hits report triangle `i` as `ids[i]` (a part of a
    /// larger soup, e.g. [`crate::accel::SplitAccel`]'s small triangles).
    ///
    /// # Panics
    /// If `ids` and `tris` differ in length, or there are `2³¹` triangles or more.
    pub fn with_ids(tris: &[[Vec3; 3]], ids: &[u32]) -> Bvh {
        assert_eq!(tris.len(), ids.len(), "one id per triangle");
        Bvh::build(tris, Some(ids), SahParams::default())
    }

    fn build(tris: &[[Vec3; 3]], ids: Option<&[u32]>, sah: SahParams) -> Bvh {
        assert!(tris.len() < LEAF as usize, "too many triangles for a Bvh");
        let (root, refs) = build::build(tris, sah);
        let mut bvh = Bvh {
            // (read all over by incoherent rays: 2 MiB pages where the system gives them,
            // `crate::mem`; a vector that outgrows its capacity is an ordinary one)
            nodes: crate::mem::huge_vec(tris.len() / 8 + 1),
            leaves: crate::mem::huge_vec(tris.len() / 4 + 1),
            bounds: (Vec3::INFINITY, Vec3::NEG_INFINITY),
            len: tris.len(),
            avx2: crate::simd::isa().avx2(),
        };
        match root {
            None => bvh.nodes.push(Node8::EMPTY),
            Some(root) => {
                collapse(&root, &refs, tris, ids, &mut bvh);
                let b = root.bounds();
                bvh.bounds = (b.min, b.max);
            }
        }
        bvh
    }

    /// The same hierarchy with the portable traversal forced (for tests and comparisons).
    pub fn portable(mut self) -> Bvh {
        self.avx2 = false;
        self
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether there are no triangles.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Bounds `(min, max)` of all triangles (`min > max` when empty).
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.bounds
    }

    /// The active lanes (`tmax > 0`) of `rays` whose segment `(0, tmax)` meets the hierarchy's
    /// bounds (bit `l` = lane `l`), by the slab test of the nodes (`BoxRay::hit8`'s arithmetic):
    /// a lane left out would find no hit in the traversal either, since every child box lies
    /// inside the bounds and the test is monotone in the box planes.
    pub fn enters8(&self, rays: &RayPacket) -> u32 {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: the CPU supports AVX2 (detected when built).
            return unsafe { avx::enters8_avx2(self.bounds, rays) };
        }
        self.enters8_portable(rays)
    }

    /// [`Bvh::enters8`] one lane at a time (the scalar original of `avx::enters8_avx2`).
    fn enters8_portable(&self, rays: &RayPacket) -> u32 {
        let (lo, hi) = self.bounds;
        let mut mask = 0u32;
        for l in 0..PACKET {
            let mut t0 = 0.0f32;
            let mut t1 = rays.tmax[l];
            for a in 0..3 {
                let inv = 1.0 / rays.d[a][l];
                let (near, far) = if inv < 0.0 { (hi[a], lo[a]) } else { (lo[a], hi[a]) };
                let tn = (near - rays.o[a][l]) * inv;
                let tf = (far - rays.o[a][l]) * inv * BOX_FAR_SCALE;
                t0 = if tn > t0 { tn } else { t0 };
                t1 = if tf < t1 { tf } else { t1 };
            }
            mask |= (((rays.tmax[l] > 0.0) & (t0 <= t1)) as u32) << l;
        }
        mask
    }

    /// Number of 8-wide nodes.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Number of leaves (groups of up to eight triangles).
    pub fn leaf_count(&self) -> usize {
        self.leaves.len()
    }

    /// Bytes used by nodes, leaves and the triangle index map.
    pub fn memory_bytes(&self) -> usize {
        self.nodes.len() * size_of::<Node8>() + self.leaves.len() * size_of::<Leaf>()
    }

    /// The hit of a traversal's closest candidate.
    #[inline(always)]
    fn hit_of(&self, best: Best) -> Option<Hit> {
        best.map(|(g, l, t, b1, b2)| Hit { t, prim: self.leaves[g].prim[l], b1, b2 })
    }

    /// The portable traversal (lane loops); the AVX2 one does the same operations.
    #[inline(always)]
    fn traverse<const ANY: bool>(&self, ray: &Ray) -> Option<Hit> {
        let br = BoxRay::new(ray);
        let sr = ShearRay::new(ray);
        let mut tmax = ray.tmax;
        let mut best: Best = None;
        let mut stack = [MaybeUninit::<Entry>::uninit(); STACK];
        let mut sp = 0usize;
        let mut cur = 0u32;
        loop {
            if cur & LEAF != 0 {
                let g = (cur & !LEAF) as usize;
                if let Some((l, t, b1, b2)) = group_hit_portable::<ANY>(&self.leaves[g].tris, &sr, ray, tmax)
                {
                    tmax = t;
                    best = Some((g, l, t, b1, b2));
                }
            } else {
                let n = &self.nodes[cur as usize];
                let (tn, mask) = br.hit8(n, tmax);
                if ANY {
                    let mut m = mask;
                    while m != 0 {
                        let l = m.trailing_zeros() as usize;
                        m &= m - 1;
                        let c = n.child[l];
                        if c & LEAF != 0 {
                            let g = (c & !LEAF) as usize;
                            if let Some((l, t, b1, b2)) =
                                group_hit_portable::<true>(&self.leaves[g].tris, &sr, ray, tmax)
                            {
                                // any-hit: only whether; the triangle index is not looked up
                                return Some(Hit { t, prim: l as u32, b1, b2 });
                            }
                        } else {
                            stack[sp].write(Entry { child: c, tnear: tn[l] });
                            sp += 1;
                        }
                    }
                } else if mask != 0 {
                    cur = order_children(mask, &tn, &n.child, &mut stack, &mut sp);
                    continue;
                }
            }
            match pop(&stack, &mut sp, tmax) {
                Some(c) => cur = c,
                None => return self.hit_of(best),
            }
        }
    }

    #[inline(always)]
    fn dispatch<const ANY: bool>(&self, ray: &Ray) -> Option<Hit> {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: the CPU supports AVX2 (detected when the BVH was built).
            return unsafe { self.traverse_avx2::<ANY>(ray) };
        }
        self.traverse::<ANY>(ray)
    }

    /// Closest hit with `0 < t < ray.tmax`.
    #[inline]
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        self.dispatch::<false>(ray)
    }

    /// Whether any triangle is hit with `0 < t < ray.tmax`.
    #[inline]
    pub fn occluded(&self, ray: &Ray) -> bool {
        self.dispatch::<true>(ray).is_some()
    }

    /// Closest hits of the eight rays of a packet (lanes with `tmax ≤ 0` are inactive and miss):
    /// the hits of [`Bvh::intersect`], bit for bit. With AVX2 the eight traversals are
    /// interleaved (`stream.rs`: each lane's next node is prefetched while the others work).
    pub fn intersect8(&self, rays: &RayPacket) -> PacketHits {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: the CPU supports AVX2 (detected when the BVH was built).
            return unsafe { self.intersect8_avx2(rays) };
        }
        let mut h = PacketHits::NONE;
        for l in 0..PACKET {
            if rays.tmax[l] > 0.0 {
                h.set(l, self.intersect(&rays.ray(l)));
            }
        }
        h
    }

    /// Which of the eight rays of a packet hit a triangle with `0 < t < tmax` (bit `l` = lane
    /// `l`; lanes with `tmax ≤ 0` are inactive, bit clear): [`Bvh::occluded`] per lane. With
    /// AVX2 the traversals are interleaved and each ends at its lane's first hit.
    pub fn occluded8(&self, rays: &RayPacket) -> u32 {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: the CPU supports AVX2 (detected when the BVH was built).
            return unsafe { self.occluded8_avx2(rays) };
        }
        (0..PACKET).filter(|&l| rays.tmax[l] > 0.0 && self.occluded(&rays.ray(l))).fold(0, |m, l| m | 1 << l)
    }
}

#[cfg(test)]
mod tests;
