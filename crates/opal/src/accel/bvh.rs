//! Bounding volume hierarchy over a triangle soup: binned SAH build, flattened 32-byte nodes,
//! ordered traversal, closest-hit and any-hit queries.
//!
//! Build: top-down, binned surface area heuristic (Wald 2007, "On fast construction of SAH-based
//! bounding volume hierarchies") over triangle centroids, [`BINS`] bins on each of the 3 axes,
//! cost `C_trav + (A_L N_L + A_R N_R) / A` with `C_trav` = [`TRAVERSAL_COST`] (intersection
//! cost 1); a node becomes a leaf when it has at most [`MAX_LEAF`] triangles and splitting
//! does not pay, or when all centroids coincide. Subtrees with more than [`PAR_THRESHOLD`]
//! triangles are built in parallel (`rayon::join`), and binning of very large nodes is a
//! parallel reduction. The result does not depend on the thread count.
//!
//! Layout: 32-byte nodes `{min, first, max, count}`; the two children of a node are stored
//! side by side in one 64-byte aligned pair (one cache line), `count > 0` marks a leaf whose
//! triangles are `tris[first .. first + count]` (triangles are copied in leaf order; `prims`
//! maps back to the input index). The root is alone in pair 0.
//!
//! Traversal: both child boxes are tested at once, the nearer is visited first and the farther
//! pushed with its entry distance (skipped on pop if a closer hit was found meanwhile). The slab
//! test selects near/far planes by the sign of the direction (NaN from `0 · ∞` is ignored by
//! `f32::max/min`, i.e. treated as not constraining) and widens the far distance by
//! `1 + 2γ₃` (pbrt-v4's conservative box test), so the BVH never culls a triangle the
//! watertight test ([`super::triangle`]) would hit.
//!
//! Tests: unit tests below; `crates/opal/tests/accel.rs` (BVH vs brute force on random soups
//! and meshes with proptest, watertightness, self-intersection). Benchmarks against `obvhs`:
//! `crates/opal/benches/accel.rs`, numbers in `docs/performance.md`.

use super::Hit;
use super::triangle::TriRay;
use crate::geometry::Ray;
use crate::math::Vec3;
use rayon::prelude::*;

/// Number of SAH bins per axis.
pub const BINS: usize = 16;
/// Largest leaf the builder creates (unless all centroids coincide).
pub const MAX_LEAF: usize = 8;
/// Cost of a traversal step relative to one triangle test, in the SAH.
pub const TRAVERSAL_COST: f32 = 1.0;
/// Subtrees larger than this are built in parallel.
pub const PAR_THRESHOLD: usize = 4096;

/// `1 + 2γ₃` with `γₙ = n u / (1 − n u)`, `u = 2⁻²⁴` (pbrt-v4, robust box test).
const BOX_FAR_SCALE: f32 = 1.0 + 2.0 * (3.0 * f32::EPSILON * 0.5) / (1.0 - 3.0 * f32::EPSILON * 0.5);

/// Depth beyond which the builder makes a leaf whatever its size (never reached in practice:
/// every split separates at least one triangle, SAH splits are far more balanced).
const MAX_DEPTH: usize = 60;
/// Traversal stack size: each 4-wide node pushes at most 3 entries and the 4-wide tree is no
/// deeper than the binary one.
const STACK: usize = 3 * MAX_DEPTH + 4;

/// Axis-aligned box used during the build.
#[derive(Clone, Copy, Debug)]
struct Aabb {
    min: Vec3,
    max: Vec3,
}

impl Aabb {
    const EMPTY: Aabb = Aabb { min: Vec3::splat(f32::INFINITY), max: Vec3::splat(f32::NEG_INFINITY) };
    #[inline]
    fn grow(&mut self, o: &Aabb) {
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
    }
    #[inline]
    fn grow_point(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }
    #[inline]
    fn half_area(&self) -> f32 {
        let e = self.max - self.min;
        if e.x < 0.0 { 0.0 } else { e.x * e.y + e.y * e.z + e.z * e.x }
    }
}

/// A triangle reference during the build: its bounds and input index.
#[derive(Clone, Copy, Debug)]
struct PrimRef {
    bounds: Aabb,
    centroid: Vec3,
    idx: u32,
}

enum BuildNode {
    Leaf { bounds: Aabb, start: u32, count: u32 },
    Interior { bounds: Aabb, children: Box<[BuildNode; 2]> },
}

impl BuildNode {
    fn bounds(&self) -> Aabb {
        match self {
            BuildNode::Leaf { bounds, .. } | BuildNode::Interior { bounds, .. } => *bounds,
        }
    }
}

#[derive(Clone, Copy)]
struct Bin {
    bounds: Aabb,
    count: u32,
}

type Bins = [[Bin; BINS]; 3];

fn empty_bins() -> Bins {
    [[Bin { bounds: Aabb::EMPTY, count: 0 }; BINS]; 3]
}

/// Maps centroids to bin indices on each axis.
#[derive(Clone, Copy)]
struct Binner {
    cmin: Vec3,
    scale: Vec3,
}

impl Binner {
    #[inline]
    fn bin(&self, c: Vec3, axis: usize) -> usize {
        let b = ((c[axis] - self.cmin[axis]) * self.scale[axis]) as usize; // NaN/neg → 0
        b.min(BINS - 1)
    }
    fn fill(&self, refs: &[PrimRef]) -> Bins {
        let mut bins = empty_bins();
        for r in refs {
            for (axis, bins_a) in bins.iter_mut().enumerate() {
                let b = &mut bins_a[self.bin(r.centroid, axis)];
                b.bounds.grow(&r.bounds);
                b.count += 1;
            }
        }
        bins
    }
}

fn merge_bins(mut a: Bins, b: Bins) -> Bins {
    for (ax, bx) in a.iter_mut().zip(b.iter()) {
        for (x, y) in ax.iter_mut().zip(bx.iter()) {
            x.bounds.grow(&y.bounds);
            x.count += y.count;
        }
    }
    a
}

/// Builds the subtree over `refs`, whose first element is at `offset` in the final order.
fn build_rec(refs: &mut [PrimRef], offset: u32, depth: usize) -> BuildNode {
    let n = refs.len();
    let mut bounds = Aabb::EMPTY;
    let mut cbounds = Aabb::EMPTY;
    if n > 1 << 16 {
        let (b, c) = refs
            .par_chunks(1 << 14)
            .map(|ch| {
                let mut b = Aabb::EMPTY;
                let mut c = Aabb::EMPTY;
                for r in ch {
                    b.grow(&r.bounds);
                    c.grow_point(r.centroid);
                }
                (b, c)
            })
            .reduce(
                || (Aabb::EMPTY, Aabb::EMPTY),
                |mut x, y| {
                    x.0.grow(&y.0);
                    x.1.grow(&y.1);
                    x
                },
            );
        bounds = b;
        cbounds = c;
    } else {
        for r in refs.iter() {
            bounds.grow(&r.bounds);
            cbounds.grow_point(r.centroid);
        }
    }
    let leaf = || BuildNode::Leaf { bounds, start: offset, count: n as u32 };
    if n <= 1 || depth >= MAX_DEPTH {
        return leaf();
    }
    let extent = cbounds.max - cbounds.min;
    let mut best: Option<(f32, usize, usize)> = None; // (cost, axis, split bin)
    // `extent > 0` is false for NaN: such an axis is not binned.
    let valid = [extent.x > 0.0, extent.y > 0.0, extent.z > 0.0];
    if valid.iter().any(|&v| v) {
        let scale = Vec3::select(
            glam::BVec3::new(valid[0], valid[1], valid[2]),
            Vec3::splat(BINS as f32 * (1.0 - 1e-6)) / extent,
            Vec3::ZERO,
        );
        let binner = Binner { cmin: cbounds.min, scale };
        let bins = if n > 1 << 16 {
            refs.par_chunks(1 << 14).map(|ch| binner.fill(ch)).reduce(empty_bins, merge_bins)
        } else {
            binner.fill(refs)
        };
        for axis in 0..3 {
            if !valid[axis] {
                continue;
            }
            let bins = &bins[axis];
            // Sweep from the right: suffix areas and counts.
            let mut right_area = [0.0f32; BINS];
            let mut right_count = [0u32; BINS];
            let mut acc = Aabb::EMPTY;
            let mut cnt = 0;
            for i in (1..BINS).rev() {
                acc.grow(&bins[i].bounds);
                cnt += bins[i].count;
                right_area[i] = acc.half_area();
                right_count[i] = cnt;
            }
            let mut acc = Aabb::EMPTY;
            let mut cnt = 0;
            for i in 1..BINS {
                acc.grow(&bins[i - 1].bounds);
                cnt += bins[i - 1].count;
                if cnt == 0 || right_count[i] == 0 {
                    continue;
                }
                let cost = acc.half_area() * cnt as f32 + right_area[i] * right_count[i] as f32;
                if best.is_none_or(|b| cost < b.0) {
                    best = Some((cost, axis, i));
                }
            }
        }
    }
    let area = bounds.half_area();
    let mid = match best {
        Some((cost, axis, split)) => {
            let split_cost = TRAVERSAL_COST + if area > 0.0 { cost / area } else { 0.0 };
            if n <= MAX_LEAF && n as f32 <= split_cost {
                return leaf();
            }
            let binner =
                Binner { cmin: cbounds.min, scale: Vec3::splat(BINS as f32 * (1.0 - 1e-6)) / extent };
            partition(refs, |r| binner.bin(r.centroid, axis) < split)
        }
        None => {
            // All centroids coincide (or are NaN): no spatial split exists.
            if n <= MAX_LEAF {
                return leaf();
            }
            n / 2
        }
    };
    debug_assert!(mid > 0 && mid < n);
    let (l, r) = refs.split_at_mut(mid);
    let (a, b) = if n > PAR_THRESHOLD {
        rayon::join(|| build_rec(l, offset, depth + 1), || build_rec(r, offset + mid as u32, depth + 1))
    } else {
        (build_rec(l, offset, depth + 1), build_rec(r, offset + mid as u32, depth + 1))
    };
    BuildNode::Interior { bounds, children: Box::new([a, b]) }
}

/// In-place partition; returns the number of elements satisfying `pred` (moved to the front).
fn partition(refs: &mut [PrimRef], pred: impl Fn(&PrimRef) -> bool) -> usize {
    let mut i = 0;
    let mut j = refs.len();
    while i < j {
        if pred(&refs[i]) {
            i += 1;
        } else {
            j -= 1;
            refs.swap(i, j);
        }
    }
    i
}

/// An empty child slot: a box no ray enters.
const EMPTY_CHILD: u32 = u32::MAX;

/// 4-wide node, 128 bytes (two cache lines), children's boxes in SoA layout.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
struct Node4 {
    /// Box minima per axis, per child.
    lo: [[f32; 4]; 3],
    /// Box maxima per axis, per child.
    hi: [[f32; 4]; 3],
    /// Interior child: node index. Leaf child: first triangle. Empty slot: `EMPTY_CHILD`.
    child: [u32; 4],
    /// Leaf child: number of triangles (> 0). Interior or empty: 0.
    count: [u32; 4],
}

impl Node4 {
    const EMPTY: Node4 = Node4 {
        lo: [[f32::INFINITY; 4]; 3],
        hi: [[f32::NEG_INFINITY; 4]; 3],
        child: [EMPTY_CHILD; 4],
        count: [0; 4],
    };
}

fn half_area_of(n: &BuildNode) -> f32 {
    n.bounds().half_area()
}

/// Collapses the binary build tree under `node` into 4-wide nodes (each node opens its
/// largest-area interior child until it has 4 children); returns the index of its node.
fn collapse(node: &BuildNode, nodes: &mut Vec<Node4>) -> u32 {
    let idx = nodes.len();
    nodes.push(Node4::EMPTY);
    let mut kids: Vec<&BuildNode> = match node {
        BuildNode::Interior { children, .. } => vec![&children[0], &children[1]],
        BuildNode::Leaf { .. } => vec![node],
    };
    while kids.len() < 4 {
        let open = kids
            .iter()
            .enumerate()
            .filter(|(_, k)| matches!(k, BuildNode::Interior { .. }))
            .max_by(|a, b| half_area_of(a.1).total_cmp(&half_area_of(b.1)))
            .map(|(i, _)| i);
        let Some(i) = open else { break };
        let BuildNode::Interior { children, .. } = kids[i] else { unreachable!() };
        kids[i] = &children[0];
        kids.insert(i + 1, &children[1]);
    }
    let mut n = Node4::EMPTY;
    for (slot, k) in kids.iter().enumerate() {
        let b = k.bounds();
        for a in 0..3 {
            n.lo[a][slot] = b.min[a];
            n.hi[a][slot] = b.max[a];
        }
        match k {
            BuildNode::Leaf { start, count, .. } => {
                n.child[slot] = *start;
                n.count[slot] = *count;
            }
            BuildNode::Interior { .. } => {
                n.child[slot] = collapse(k, nodes);
                n.count[slot] = 0;
            }
        }
    }
    nodes[idx] = n;
    idx as u32
}

/// Per-ray constants of the slab test.
#[derive(Clone, Copy)]
struct BoxRay {
    o: [f32; 3],
    inv: [f32; 3],
    /// Whether each direction component is negative (then the near plane is the maximum).
    neg: [bool; 3],
}

impl BoxRay {
    #[inline(always)]
    fn new(ray: &Ray) -> Self {
        let inv = [1.0 / ray.d.x, 1.0 / ray.d.y, 1.0 / ray.d.z];
        BoxRay { o: ray.o.to_array(), inv, neg: [inv[0] < 0.0, inv[1] < 0.0, inv[2] < 0.0] }
    }
    /// Entry distances of the four child boxes and the mask of those overlapping `(0, tmax)`.
    #[inline(always)]
    fn hit4(&self, n: &Node4, tmax: f32) -> ([f32; 4], u32) {
        let mut t0 = [0.0f32; 4];
        let mut t1 = [tmax; 4];
        for a in 0..3 {
            let (near, far) = if self.neg[a] { (&n.hi[a], &n.lo[a]) } else { (&n.lo[a], &n.hi[a]) };
            for l in 0..4 {
                let tn = (near[l] - self.o[a]) * self.inv[a];
                let tf = (far[l] - self.o[a]) * self.inv[a] * BOX_FAR_SCALE;
                t0[l] = t0[l].max(tn);
                t1[l] = t1[l].min(tf);
            }
        }
        let mut mask = 0;
        for l in 0..4 {
            mask |= ((t0[l] <= t1[l]) as u32) << l;
        }
        (t0, mask)
    }
}

/// SAH bounding volume hierarchy over a triangle soup (see the module docs).
#[derive(Clone, Debug)]
pub struct Bvh {
    nodes: Vec<Node4>,
    bounds: (Vec3, Vec3),
    /// Triangles in leaf order.
    tris: Vec<[Vec3; 3]>,
    /// Input index of each triangle in `tris`.
    prims: Vec<u32>,
}

/// A pending child on the traversal stack.
#[derive(Clone, Copy, Default)]
struct Entry {
    child: u32,
    count: u32,
    tnear: f32,
}

impl Bvh {
    /// Builds the hierarchy (parallel on the rayon pool). Degenerate triangles are accepted and
    /// never hit.
    ///
    /// # Panics
    /// If there are more than `u32::MAX - 1` triangles.
    pub fn new(tris: Vec<[Vec3; 3]>) -> Bvh {
        assert!(tris.len() < u32::MAX as usize, "too many triangles for a Bvh");
        let mut refs: Vec<PrimRef> = tris
            .par_iter()
            .enumerate()
            .map(|(i, t)| {
                let min = t[0].min(t[1]).min(t[2]);
                let max = t[0].max(t[1]).max(t[2]);
                PrimRef { bounds: Aabb { min, max }, centroid: (min + max) * 0.5, idx: i as u32 }
            })
            .collect();
        let mut nodes = Vec::new();
        let bounds = if refs.is_empty() {
            nodes.push(Node4::EMPTY);
            (Vec3::INFINITY, Vec3::NEG_INFINITY)
        } else {
            let root = build_rec(&mut refs, 0, 0);
            nodes.reserve(tris.len() / 4);
            collapse(&root, &mut nodes);
            let b = root.bounds();
            (b.min, b.max)
        };
        let prims: Vec<u32> = refs.iter().map(|r| r.idx).collect();
        let tris = prims.par_iter().map(|&i| tris[i as usize]).collect();
        Bvh { nodes, bounds, tris, prims }
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.tris.len()
    }

    /// Whether there are no triangles.
    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    /// Bounds `(min, max)` of all triangles (`min > max` when empty).
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.bounds
    }

    /// Number of 4-wide nodes.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    #[inline(always)]
    fn traverse<const ANY: bool>(&self, ray: &Ray) -> Option<Hit> {
        let br = BoxRay::new(ray);
        let tr = TriRay::new(ray);
        let mut tmax = ray.tmax;
        let mut best: Option<Hit> = None;
        let mut stack = [Entry::default(); STACK];
        let mut sp = 0usize;
        // The current item: a node (count 0) or a leaf (count > 0).
        let mut cur = Entry { child: 0, count: 0, tnear: 0.0 };
        loop {
            if cur.count > 0 {
                let start = cur.child as usize;
                let end = start + cur.count as usize;
                for i in start..end {
                    if let Some((t, b1, b2)) = tr.intersect(&self.tris[i], tmax) {
                        tmax = t;
                        best = Some(Hit { t, prim: self.prims[i], b1, b2 });
                        if ANY {
                            return best;
                        }
                    }
                }
            } else {
                let n = &self.nodes[cur.child as usize];
                let (tn, mask) = br.hit4(n, tmax);
                if mask != 0 {
                    // Hit children sorted by entry distance (insertion sort, at most 4).
                    let mut hits = [Entry::default(); 4];
                    let mut h = 0;
                    for l in 0..4 {
                        if mask >> l & 1 != 0 {
                            let e = Entry { child: n.child[l], count: n.count[l], tnear: tn[l] };
                            let mut j = h;
                            while j > 0 && hits[j - 1].tnear > e.tnear {
                                hits[j] = hits[j - 1];
                                j -= 1;
                            }
                            hits[j] = e;
                            h += 1;
                        }
                    }
                    // Farther ones on the stack (farthest deepest), visit the nearest now.
                    for e in hits[1..h].iter().rev() {
                        stack[sp] = *e;
                        sp += 1;
                    }
                    cur = hits[0];
                    continue;
                }
            }
            // Pop the next item still in range.
            loop {
                if sp == 0 {
                    return best;
                }
                sp -= 1;
                if stack[sp].tnear <= tmax {
                    cur = stack[sp];
                    break;
                }
            }
        }
    }

    /// Closest hit with `0 < t < ray.tmax`.
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        self.traverse::<false>(ray)
    }

    /// Whether any triangle is hit with `0 < t < ray.tmax`.
    pub fn occluded(&self, ray: &Ray) -> bool {
        self.traverse::<true>(ray).is_some()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn node_layout() {
        assert_eq!(std::mem::size_of::<Node4>(), 128);
        assert_eq!(std::mem::align_of::<Node4>(), 64);
    }

    #[test]
    fn empty_and_single() {
        let b = Bvh::new(vec![]);
        assert!(b.is_empty() && b.intersect(&Ray::new(Vec3::ZERO, Vec3::X)).is_none());
        assert!(!b.occluded(&Ray::new(Vec3::ZERO, Vec3::X)));
        let tri = [Vec3::new(0.0, 0.0, 1.0), Vec3::new(1.0, 0.0, 1.0), Vec3::new(0.0, 1.0, 1.0)];
        let b = Bvh::new(vec![tri]);
        let h = b.intersect(&Ray::new(Vec3::new(0.1, 0.1, 0.0), Vec3::Z)).unwrap();
        assert_eq!(h.prim, 0);
        assert!((h.t - 1.0).abs() < 1e-6);
        assert_eq!(b.bounds(), (Vec3::new(0.0, 0.0, 1.0), Vec3::new(1.0, 1.0, 1.0)));
    }

    #[test]
    fn many_identical_and_degenerate() {
        // 100 copies of one triangle plus 100 points: centroids coincide, must not recurse forever.
        let tri = [Vec3::new(0.0, 0.0, 1.0), Vec3::new(1.0, 0.0, 1.0), Vec3::new(0.0, 1.0, 1.0)];
        let mut tris = vec![tri; 100];
        tris.extend(std::iter::repeat_n([Vec3::new(0.2, 0.2, 0.5); 3], 100));
        let b = Bvh::new(tris);
        assert_eq!(b.len(), 200);
        let h = b.intersect(&Ray::new(Vec3::new(0.2, 0.2, 0.0), Vec3::Z)).unwrap();
        assert!(h.prim < 100 && (h.t - 1.0).abs() < 1e-6);
    }

    #[test]
    fn axis_parallel_ray_on_box_face() {
        // The ray runs inside the plane x = 0 of the boxes' faces (0·∞ = NaN in the slab test).
        let tris: Vec<[Vec3; 3]> = (0..64)
            .map(|i| {
                let z = i as f32;
                [Vec3::new(0.0, -1.0, z), Vec3::new(1.0, -1.0, z), Vec3::new(0.0, 1.0, z)]
            })
            .collect();
        let b = Bvh::new(tris);
        let h = b.intersect(&Ray::new(Vec3::new(0.0, 0.0, 10.5), Vec3::Z)).unwrap();
        assert_eq!(h.prim, 11);
        let h = b.intersect(&Ray::new(Vec3::new(0.0, 0.0, 10.5), -Vec3::Z)).unwrap();
        assert_eq!(h.prim, 10);
    }
}
