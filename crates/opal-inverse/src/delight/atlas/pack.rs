//! Atlas packing of flattened charts by their rasterised shapes (charts nest into each other's
//! concavities), at the largest uniform texel density that fits.
//!
//! * Each chart is first rotated so that its convex hull has the smallest bounding rectangle.
//! * At a density `s` (texels per world unit) a chart's footprint is the set of texels whose
//!   square meets one of its UV triangles (exact separating-axis test, slightly conservative),
//!   grown by one texel (3×3). Footprints of different charts may not share a texel, so UV
//!   images of different charts are ≥ 2 texels apart and a bilinear look-up anywhere inside a
//!   chart only reads texels within one texel of that chart (see [`super::texel_owner`]).
//! * Charts are placed largest first (bounding-rectangle area) at the first free position in
//!   row-major order, trying the four quarter turns (rotations only: no mirror images) and
//!   keeping the one whose top is lowest, then leftmost.
//! * A chart that finds no place is halved (median cut of its triangles across its longer
//!   side; the halves keep their UVs, so they stay valid) and the halves are placed next; at
//!   most ⌈charts / 2⌉ (≥ 2) such splits per attempt. This fills the last gaps of the atlas.
//! * Density: attempts at `s_max · (0.9 − 0.006 j)` with `s_max = res / √(UV area)` (the area
//!   bound), four at a time in parallel; the largest success of the first batch with one wins
//!   (success is not monotone in the density). On one thread the four are tried in order and
//!   the first success ends the batch (the same winner). Deterministic for any thread count.
//!
//! Tests: `atlas::tests` (utilisation on the displaced sphere, no overlaps).

use super::lscm::Flat;
use opal::math::DVec2;
use rayon::prelude::*;

/// Bitmap of a chart's footprint (rows of 64-bit words).
struct Mask {
    w: usize,
    h: usize,
    words: usize,
    bits: Vec<u64>,
}

impl Mask {
    fn new(w: usize, h: usize) -> Self {
        let words = w.div_ceil(64);
        Mask { w, h, words, bits: vec![0; words * h] }
    }
    fn set(&mut self, x: usize, y: usize) {
        self.bits[y * self.words + x / 64] |= 1 << (x % 64);
    }
    fn get(&self, x: usize, y: usize) -> bool {
        self.bits[y * self.words + x / 64] >> (x % 64) & 1 == 1
    }
    /// 3×3 dilation (the mask has a free border of one texel).
    fn dilate(&self) -> Mask {
        let mut h = Mask::new(self.w, self.h);
        for y in 0..self.h {
            let row = &self.bits[y * self.words..(y + 1) * self.words];
            for k in 0..self.words {
                let left = if k > 0 { row[k - 1] >> 63 } else { 0 };
                let right = if k + 1 < self.words { row[k + 1] << 63 } else { 0 };
                h.bits[y * self.words + k] = row[k] | (row[k] << 1) | left | (row[k] >> 1) | right;
            }
        }
        let mut out = Mask::new(self.w, self.h);
        for y in 0..self.h {
            for k in 0..self.words {
                let mut v = h.bits[y * self.words + k];
                if y > 0 {
                    v |= h.bits[(y - 1) * self.words + k];
                }
                if y + 1 < self.h {
                    v |= h.bits[(y + 1) * self.words + k];
                }
                out.bits[y * self.words + k] = v;
            }
        }
        out
    }
}

/// Calls `f(x, y)` for every texel (in `[0, w) × [0, h)`) whose square meets the triangle `t`
/// (texel coordinates, counter-clockwise): exact separating-axis test, grown by `eps`.
pub fn conservative_raster(t: [DVec2; 3], w: usize, h: usize, eps: f64, mut f: impl FnMut(usize, usize)) {
    let lo = t[0].min(t[1]).min(t[2]);
    let hi = t[0].max(t[1]).max(t[2]);
    if !(lo.is_finite() && hi.is_finite()) {
        return;
    }
    let x0 = (lo.x - eps).floor().max(0.0) as usize;
    let y0 = (lo.y - eps).floor().max(0.0) as usize;
    let x1 = ((hi.x + eps).floor().max(0.0) as usize).min(w.saturating_sub(1));
    let y1 = ((hi.y + eps).floor().max(0.0) as usize).min(h.saturating_sub(1));
    let ccw = (t[1] - t[0]).perp_dot(t[2] - t[0]) >= 0.0;
    let edges: [(DVec2, DVec2); 3] = std::array::from_fn(|j| {
        let (p, q) = if ccw { (t[j], t[(j + 1) % 3]) } else { (t[(j + 1) % 3], t[j]) };
        (p, DVec2::new(p.y - q.y, q.x - p.x))
    });
    for y in y0..=y1 {
        for x in x0..=x1 {
            let c = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
            if edges.iter().all(|&(p, n)| n.dot(c - p) + (0.5 + eps) * (n.x.abs() + n.y.abs()) >= 0.0) {
                f(x, y);
            }
        }
    }
}

/// Rotation of a chart's UVs that minimises the bounding rectangle of its convex hull.
fn best_rotation(uv: &[DVec2]) -> DVec2 {
    let mut pts: Vec<DVec2> = uv.to_vec();
    pts.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    pts.dedup();
    if pts.len() < 3 {
        return DVec2::X;
    }
    let mut hull: Vec<DVec2> = Vec::new();
    for pass in 0..2 {
        let start = hull.len();
        let it: Box<dyn Iterator<Item = &DVec2>> =
            if pass == 0 { Box::new(pts.iter()) } else { Box::new(pts.iter().rev()) };
        for &p in it {
            while hull.len() >= start + 2 {
                let (a, b) = (hull[hull.len() - 2], hull[hull.len() - 1]);
                if (b - a).perp_dot(p - a) <= 0.0 {
                    hull.pop();
                } else {
                    break;
                }
            }
            hull.push(p);
        }
        hull.pop();
    }
    let mut best = (f64::MAX, DVec2::X);
    for i in 0..hull.len() {
        let d = (hull[(i + 1) % hull.len()] - hull[i]).normalize_or_zero();
        if d == DVec2::ZERO {
            continue;
        }
        // rotation taking d to +x: (cos, sin) = (d.x, −d.y)
        let r = DVec2::new(d.x, -d.y);
        let (mut lo, mut hi) = (DVec2::splat(f64::MAX), DVec2::splat(f64::MIN));
        for &p in &hull {
            let q = r.rotate(p);
            lo = lo.min(q);
            hi = hi.max(q);
        }
        let e = hi - lo;
        let area = e.x * e.y;
        if area < best.0 * (1.0 - 1e-9) {
            // long side horizontal
            best = (area, if e.x >= e.y { r } else { DVec2::new(0.0, -1.0).rotate(r) });
        }
    }
    best.1
}

/// A chart (or a piece of one) ready to pack: its source chart, the triangles it takes from it
/// (indices into the source's triangles, and their corners), and the source's UVs rotated to
/// the piece's smallest bounding rectangle and shifted to its minimum corner.
#[derive(Clone)]
struct Prepared {
    src: usize,
    tri_ids: Vec<usize>,
    tris: Vec<[u32; 3]>,
    uv: Vec<DVec2>,
    ext: DVec2,
}

impl Prepared {
    fn new(src: usize, tri_ids: Vec<usize>, flat: &Flat) -> Self {
        let tris: Vec<[u32; 3]> = tri_ids.iter().map(|&t| flat.tris[t]).collect();
        let used: Vec<DVec2> = tris.iter().flat_map(|t| t.map(|i| flat.uv[i as usize])).collect();
        let r = best_rotation(&used);
        let lo = used.iter().fold(DVec2::splat(f64::MAX), |a, &b| a.min(r.rotate(b)));
        let hi = used.iter().fold(DVec2::splat(f64::MIN), |a, &b| a.max(r.rotate(b)));
        let uv = flat.uv.iter().map(|&q| r.rotate(q) - lo).collect();
        Prepared { src, tri_ids, tris, uv, ext: (hi - lo).max(DVec2::ZERO) }
    }
    /// Halves the piece across the principal axis of its triangle centroids (median cut).
    fn split(&self, flat: &Flat) -> Option<(Prepared, Prepared)> {
        if self.tri_ids.len() < 2 {
            return None;
        }
        let cen: Vec<DVec2> = self
            .tris
            .iter()
            .map(|t| (self.uv[t[0] as usize] + self.uv[t[1] as usize] + self.uv[t[2] as usize]) / 3.0)
            .collect();
        let axis = if self.ext.x >= self.ext.y { DVec2::X } else { DVec2::Y };
        let mut idx: Vec<usize> = (0..cen.len()).collect();
        idx.sort_by(|&a, &b| cen[a].dot(axis).total_cmp(&cen[b].dot(axis)).then(a.cmp(&b)));
        let (lo, hi) = idx.split_at(idx.len() / 2);
        let pick = |h: &[usize]| {
            let mut ids: Vec<usize> = h.iter().map(|&i| self.tri_ids[i]).collect();
            ids.sort_unstable();
            Prepared::new(self.src, ids, flat)
        };
        Some((pick(lo), pick(hi)))
    }
}

/// Offset (texels) of a piece's UVs in its footprint frame: a vertex at the minimum lands on
/// 1.5, so its conservative texels start at row/column 1 and their 3×3 growth at 0 (an offset
/// of 1 puts a vertex exactly on a texel border, whose touching texel 0 would need texel −1).
const MARGIN: f64 = 1.5;

/// Footprint of a piece at density `s`, rotated by `rot` quarter turns: the mask and the texel
/// coordinates of its UVs in the mask's frame.
fn footprint(c: &Prepared, s: f64, rot: u8) -> (Mask, Vec<DVec2>) {
    let ext = if rot % 2 == 1 { DVec2::new(c.ext.y, c.ext.x) } else { c.ext };
    let t: Vec<DVec2> =
        c.uv.iter()
            .map(|&q| {
                let q = match rot {
                    0 => q,
                    1 => DVec2::new(c.ext.y - q.y, q.x),
                    2 => c.ext - q,
                    _ => DVec2::new(q.y, c.ext.x - q.x),
                };
                q * s + DVec2::splat(MARGIN)
            })
            .collect();
    let (w, h) = ((ext.x * s).floor() as usize + 4, (ext.y * s).floor() as usize + 4);
    let mut m = Mask::new(w, h);
    for tri in &c.tris {
        conservative_raster(tri.map(|i| t[i as usize]), w, h, 1e-3, |x, y| m.set(x, y));
    }
    (m.dilate(), t)
}

/// Occupancy of the atlas.
struct Occupancy {
    res: usize,
    words: usize,
    bits: Vec<u64>,
    free: Vec<usize>,
}

impl Occupancy {
    fn new(res: usize) -> Self {
        let words = res.div_ceil(64);
        Occupancy { res, words, bits: vec![0; words * res], free: vec![res; res] }
    }
    fn fits(&self, m: &Mask, x: usize, y: usize) -> bool {
        let (base, sh) = (x / 64, x % 64);
        for r in 0..m.h {
            let arow = &self.bits[(y + r) * self.words..(y + r + 1) * self.words];
            for k in 0..m.words {
                let b = m.bits[r * m.words + k];
                if b == 0 {
                    continue;
                }
                if arow[base + k] & (b << sh) != 0 {
                    return false;
                }
                if sh > 0 && base + k + 1 < self.words && arow[base + k + 1] & (b >> (64 - sh)) != 0 {
                    return false;
                }
            }
        }
        true
    }
    fn place(&mut self, m: &Mask, x: usize, y: usize) {
        for r in 0..m.h {
            for xx in 0..m.w {
                if m.get(xx, r) {
                    let ax = x + xx;
                    self.bits[(y + r) * self.words + ax / 64] |= 1 << (ax % 64);
                    self.free[y + r] -= 1;
                }
            }
        }
    }
    /// First position (row-major) where `m` fits; `counts`: set bits per mask row.
    fn find(&self, m: &Mask, counts: &[usize]) -> Option<(usize, usize)> {
        if m.w > self.res || m.h > self.res {
            return None;
        }
        for y in 0..=self.res - m.h {
            if (0..m.h).any(|r| self.free[y + r] < counts[r]) {
                continue;
            }
            for x in 0..=self.res - m.w {
                if self.fits(m, x, y) {
                    return Some((x, y));
                }
            }
        }
        None
    }
}

/// A packed piece: source chart, its triangles (indices into the source's), and the atlas UV
/// (in [0, 1]) of every local vertex of the source (only those of its triangles are meaningful).
pub struct Packed {
    /// Index of the source chart.
    pub src: usize,
    /// Triangles of the piece (indices into the source chart's triangles).
    pub tri_ids: Vec<usize>,
    /// Atlas UV per local vertex of the source chart.
    pub uv: Vec<DVec2>,
}

/// Quarter turns tried per piece.
const ROTATIONS: u8 = 4;
/// Densities tried together (in parallel; in order, up to the first success, on one thread).
const BATCH: usize = 4;
/// First density tried, relative to the area bound (a utilisation of 0.9²).
const START: f64 = 0.9;
/// Most pieces split off per chart count (pieces that do not fit are halved).
const SPLIT_FRACTION: f64 = 0.5;

/// Order of placement: bounding-rectangle area, largest first.
fn order(p: &[Prepared]) -> Vec<usize> {
    let mut o: Vec<usize> = (0..p.len()).collect();
    let size = |c: &Prepared| c.ext.x * c.ext.y;
    o.sort_by(|&a, &b| size(&p[b]).total_cmp(&size(&p[a])).then(a.cmp(&b)));
    o
}

/// A placement: position, footprint, texel UVs in the footprint's frame.
type Placement = ((usize, usize), Mask, Vec<DVec2>);

/// Best placement of a piece over the rotations: lowest top, then leftmost.
fn place(occ: &Occupancy, p: &Prepared, s: f64) -> Option<Placement> {
    let mut best: Option<((usize, usize), Placement)> = None;
    for rot in 0..ROTATIONS {
        let (m, t) = footprint(p, s, rot);
        let counts: Vec<usize> = (0..m.h)
            .map(|r| m.bits[r * m.words..(r + 1) * m.words].iter().map(|b| b.count_ones() as usize).sum())
            .collect();
        if let Some((x, y)) = occ.find(&m, &counts) {
            let key = (y + m.h, x);
            if best.as_ref().is_none_or(|b| key < b.0) {
                best = Some((key, ((x, y), m, t)));
            }
        }
    }
    best.map(|b| b.1)
}

/// Packs at density `s`, largest first; a piece that does not fit is halved and its halves
/// are placed next (at most `max_splits` times). The pieces with their texel UVs, or `None`.
fn pack_at(
    start: &[Prepared],
    flats: &[Flat],
    res: usize,
    s: f64,
    max_splits: usize,
) -> Option<Vec<(Prepared, Vec<DVec2>)>> {
    let mut occ = Occupancy::new(res);
    let mut todo: Vec<Prepared> = order(start).into_iter().rev().map(|i| start[i].clone()).collect();
    let mut out = Vec::with_capacity(start.len());
    let mut splits = 0;
    while let Some(p) = todo.pop() {
        match place(&occ, &p, s) {
            Some(((x, y), m, t)) => {
                occ.place(&m, x, y);
                out.push((p, t.iter().map(|&q| q + DVec2::new(x as f64, y as f64)).collect()));
            }
            None => {
                splits += 1;
                if splits > max_splits {
                    return None;
                }
                let (a, b) = p.split(&flats[p.src])?;
                let size = |c: &Prepared| c.ext.x * c.ext.y;
                let (big, small) = if size(&a) >= size(&b) { (a, b) } else { (b, a) };
                todo.push(small);
                todo.push(big);
            }
        }
    }
    Some(out)
}

/// Packs the charts into a `res × res` atlas at the largest density that fits (see the module
/// docs): the packed pieces (charts, some halved) and the density (texels per world unit).
pub fn pack(flats: &[Flat], res: usize) -> Result<(Vec<Packed>, f64), String> {
    let start: Vec<Prepared> =
        flats.iter().enumerate().map(|(i, f)| Prepared::new(i, (0..f.tris.len()).collect(), f)).collect();
    let area: f64 = flats
        .iter()
        .flat_map(|f| {
            f.tris.iter().map(|t| {
                0.5 * (f.uv[t[1] as usize] - f.uv[t[0] as usize])
                    .perp_dot(f.uv[t[2] as usize] - f.uv[t[0] as usize])
                    .abs()
            })
        })
        .sum();
    if !(area > 0.0 && area.is_finite()) {
        return Err("degenerate mesh (zero area)".into());
    }
    let max_splits = ((flats.len() as f64 * SPLIT_FRACTION).ceil() as usize).max(2);
    let s_max = res as f64 / area.sqrt();
    // Success is not monotone in the density: densities s_max · (0.96 − 0.006 j) are tried in
    // batches, and the largest success of the first batch with one wins.
    let mut j = 0usize;
    loop {
        let f = START - 0.006 * j as f64;
        if f <= 0.01 {
            return Err(format!("{} charts do not fit a {res}² texture", flats.len()));
        }
        let batch: Vec<f64> =
            (0..BATCH).map(|b| s_max * (f - 0.006 * b as f64)).filter(|&s| s > 0.0).collect();
        j += BATCH;
        // the largest density of the batch that succeeds: on one thread the densities in order,
        // stopping at the first success (the same one, without the attempts after it)
        let found = if rayon::current_num_threads() > 1 {
            let results: Vec<_> =
                batch.par_iter().map(|&s| pack_at(&start, flats, res, s, max_splits)).collect();
            batch.iter().zip(results).find_map(|(&s, r)| r.map(|r| (s, r)))
        } else {
            batch.iter().find_map(|&s| pack_at(&start, flats, res, s, max_splits).map(|r| (s, r)))
        };
        if let Some((s, placed)) = found {
            let inv = 1.0 / res as f64;
            let packed = placed
                .into_iter()
                .map(|(p, uv)| Packed {
                    src: p.src,
                    tri_ids: p.tri_ids,
                    uv: uv.into_iter().map(|q| q * inv).collect(),
                })
                .collect();
            return Ok((packed, s));
        }
    }
}
