//! Top-down binned SAH build of a binary tree over triangle bounds (the first step of
//! [`super::Bvh::new`]; [`super::collapse`] turns the binary tree into 8-wide nodes).
//!
//! Binned surface area heuristic (Wald 2007, "On fast construction of SAH-based bounding volume
//! hierarchies") over triangle centroids, [`BINS`] bins on each of the 3 axes. The cost of a
//! split is `C_trav + (A_L C(N_L) + A_R C(N_R)) / A` where `C(N) = ⌈N / b⌉` counts the leaf
//! *blocks* of `b` triangles ([`SahParams::block`]): a leaf's triangles are tested eight at a
//! time ([`crate::accel::group`]), so a leaf of 8 costs what a leaf of 1 costs. A node becomes a
//! leaf when it has at most [`MAX_LEAF`] triangles and splitting does not pay, or when all
//! centroids coincide (then it is cut in halves down to [`MAX_LEAF`]). Subtrees with more than
//! [`PAR_THRESHOLD`] triangles are built in parallel (`rayon::join`), and binning of very large
//! nodes is a parallel reduction; the result does not depend on the thread count.
//!
//! Tests: `super::tests`, `crates/opal/tests/accel.rs`.

use crate::math::Vec3;
use rayon::prelude::*;

/// Number of SAH bins per axis.
pub const BINS: usize = 16;
/// Largest leaf the builder creates: one group of eight triangles.
pub const MAX_LEAF: usize = crate::accel::group::LANES;

/// SAH constants of the build.
#[derive(Clone, Copy, Debug)]
pub struct SahParams {
    /// Cost of a traversal step relative to one leaf-block test.
    pub traversal: f32,
    /// Triangles tested together (a leaf of `n` triangles costs `⌈n / block⌉`).
    pub block: u32,
}

impl Default for SahParams {
    fn default() -> Self {
        SahParams { traversal: 1.0, block: 8 }
    }
}
/// Subtrees larger than this are built in parallel.
pub const PAR_THRESHOLD: usize = 4096;

/// Depth beyond which the builder makes a leaf whatever its size (never reached in practice:
/// every split separates at least one triangle, SAH splits are far more balanced).
pub(super) const MAX_DEPTH: usize = 60;

/// Axis-aligned box used during the build.
#[derive(Clone, Copy, Debug)]
pub(super) struct Aabb {
    pub(super) min: Vec3,
    pub(super) max: Vec3,
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
    pub(super) fn half_area(&self) -> f32 {
        let e = self.max - self.min;
        if e.x < 0.0 { 0.0 } else { e.x * e.y + e.y * e.z + e.z * e.x }
    }
}

/// A triangle reference during the build: its bounds and input index.
#[derive(Clone, Copy, Debug)]
pub(super) struct PrimRef {
    bounds: Aabb,
    centroid: Vec3,
    pub(super) idx: u32,
}

pub(super) enum BuildNode {
    Leaf { bounds: Aabb, start: u32, count: u32 },
    Interior { bounds: Aabb, children: Box<[BuildNode; 2]> },
}

impl BuildNode {
    pub(super) fn bounds(&self) -> Aabb {
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
fn build_rec(refs: &mut [PrimRef], offset: u32, depth: usize, sah: SahParams) -> BuildNode {
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
                let blocks = |n: u32| n.div_ceil(sah.block) as f32;
                let cost = acc.half_area() * blocks(cnt) + right_area[i] * blocks(right_count[i]);
                if best.is_none_or(|b| cost < b.0) {
                    best = Some((cost, axis, i));
                }
            }
        }
    }
    let area = bounds.half_area();
    let mid = match best {
        Some((cost, axis, split)) => {
            let split_cost = sah.traversal + if area > 0.0 { cost / area } else { 0.0 };
            if n <= MAX_LEAF && (n as u32).div_ceil(sah.block) as f32 <= split_cost {
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
        rayon::join(
            || build_rec(l, offset, depth + 1, sah),
            || build_rec(r, offset + mid as u32, depth + 1, sah),
        )
    } else {
        (build_rec(l, offset, depth + 1, sah), build_rec(r, offset + mid as u32, depth + 1, sah))
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

/// Builds the binary tree over `tris`; returns it with the references in leaf order (`None`
/// for an empty soup).
pub(super) fn build(tris: &[[Vec3; 3]], sah: SahParams) -> (Option<BuildNode>, Vec<PrimRef>) {
    let mut refs: Vec<PrimRef> = tris
        .par_iter()
        .enumerate()
        .map(|(i, t)| {
            let min = t[0].min(t[1]).min(t[2]);
            let max = t[0].max(t[1]).max(t[2]);
            PrimRef { bounds: Aabb { min, max }, centroid: (min + max) * 0.5, idx: i as u32 }
        })
        .collect();
    if refs.is_empty() {
        return (None, refs);
    }
    let root = build_rec(&mut refs, 0, 0, sah);
    (Some(root), refs)
}
