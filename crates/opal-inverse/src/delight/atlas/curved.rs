//! Unwrap of curved meshes: segmentation ([`super::segment`]), one conformal map per chart
//! ([`super::lscm`]; orthogonal projection where a chart is planar), splitting of charts whose
//! map is invalid, and shape packing ([`super::pack`]).
//!
//! * A chart is planar when every face normal is within [`PLANAR_DEG`] of the chart's mean
//!   normal; it is projected orthogonally onto its plane.
//! * A chart whose map has a flipped triangle, a folded vertex, an overlapping boundary or an
//!   area ratio beyond [`MAX_AREA_RATIO`] is cut in two by the plane through its area-weighted
//!   centroid across its longest principal axis (then split into connected pieces) and each piece
//!   is flattened again; a single triangle is always valid.
//! * Charts are processed in parallel; the result does not depend on the thread count.
//! * Atlases finer than [`PACK_RES`]² reuse the layout packed on a [`PACK_RES`]² grid (UVs in
//!   [0, 1] are resolution-free; the gaps only grow), which keeps packing at a few seconds: at
//!   2048² direct packing took 18 s on the 82 k-triangle scan for 77.8 % instead of ≈ 76 %.
//!
//! Tests: `atlas::tests`.

use super::lscm::{self, Flat};
use super::pack;
use super::segment::{self, NONE, Topology};
use opal::geometry::TriangleMesh;
use opal::math::{DVec3, Vec2};
use rayon::prelude::*;
use std::collections::HashMap;

/// Normal-cone half-angle of the segmentation (degrees, on smoothed normals).
pub const CONE_DEG: f64 = 60.0;
/// Largest ratio (either way) between a triangle's UV/surface area ratio and its chart's.
pub const MAX_AREA_RATIO: f64 = 4.0;
/// Face normals within this angle (degrees) of the chart normal: planar chart.
pub const PLANAR_DEG: f64 = 1.0;
/// Largest grid the charts are laid out on (finer atlases scale the layout up).
pub const PACK_RES: usize = 1024;
/// Jacobi passes of normal smoothing before segmentation.
const SMOOTH_PASSES: usize = 10;

/// Statistics of a curved unwrap.
#[derive(Clone, Debug, Default)]
pub struct UnwrapStats {
    /// Charts after segmentation (before splits).
    pub segments: usize,
    /// Charts split because their map was invalid.
    pub splits: usize,
    /// Charts flattened by projection (planar).
    pub planar: usize,
    /// Total conjugate-gradient iterations.
    pub cg_iterations: usize,
    /// Density (texels per world unit).
    pub density: f64,
    /// Wall seconds of segmentation, flattening and packing.
    pub seconds: [f64; 3],
}

/// A chart being flattened: its triangles (mesh indices).
struct Piece {
    tris: Vec<u32>,
}

/// Local positions and triangles of a chart (welded vertices), with the welded id of each
/// local vertex.
fn local(
    mesh: &TriangleMesh,
    topo: &Topology,
    p64: &[DVec3],
    tris: &[u32],
) -> (Vec<DVec3>, Vec<[u32; 3]>, Vec<u32>) {
    let mut map: HashMap<u32, u32> = HashMap::new();
    let mut pos = Vec::new();
    let mut ids = Vec::new();
    let lt = tris
        .iter()
        .map(|&k| {
            mesh.indices[k as usize].map(|v| {
                let w = topo.wid[v as usize];
                *map.entry(w).or_insert_with(|| {
                    pos.push(p64[v as usize]);
                    ids.push(w);
                    (pos.len() - 1) as u32
                })
            })
        })
        .collect();
    (pos, lt, ids)
}

/// Flattens a piece: `Ok(flat, cg iterations, planar)` or `Err(sub-pieces)`.
fn flatten(
    mesh: &TriangleMesh,
    topo: &Topology,
    p64: &[DVec3],
    piece: &Piece,
) -> Result<(Flat, usize, bool), Vec<Piece>> {
    let (p, tris, _) = local(mesh, topo, p64, &piece.tris);
    let mut mean = DVec3::ZERO;
    for &k in &piece.tris {
        mean += topo.normal[k as usize] * topo.area[k as usize];
    }
    let mean = mean.normalize_or_zero();
    let cos_planar = PLANAR_DEG.to_radians().cos();
    let planar = piece
        .tris
        .iter()
        .all(|&k| topo.normal[k as usize] == DVec3::ZERO || topo.normal[k as usize].dot(mean) >= cos_planar);
    let (uv, it) = if planar { (lscm::project(&p, &tris), 0) } else { lscm::lscm(&p, &tris) };
    let flat = Flat { tris, uv };
    if piece.tris.len() == 1 || lscm::problem(&p, &flat, MAX_AREA_RATIO).is_none() {
        return Ok((flat, it, planar));
    }
    Err(split(topo, p64, mesh, piece))
}

/// Cuts a piece across its longest principal axis (see the module docs).
fn split(topo: &Topology, p64: &[DVec3], mesh: &TriangleMesh, piece: &Piece) -> Vec<Piece> {
    let centroid = |k: u32| {
        let t = mesh.indices[k as usize];
        (p64[t[0] as usize] + p64[t[1] as usize] + p64[t[2] as usize]) / 3.0
    };
    let (mut c, mut w) = (DVec3::ZERO, 0.0);
    for &k in &piece.tris {
        let a = topo.area[k as usize].max(1e-300);
        c += centroid(k) * a;
        w += a;
    }
    let c = c / w;
    let mut cov = [[0.0f64; 3]; 3];
    for &k in &piece.tris {
        let d = centroid(k) - c;
        let a = topo.area[k as usize].max(1e-300);
        let d = d.to_array();
        for i in 0..3 {
            for j in 0..3 {
                cov[i][j] += a * d[i] * d[j];
            }
        }
    }
    // power iteration for the principal axis
    let mut axis = DVec3::new(1.0, 0.7, 0.3);
    for _ in 0..64 {
        let a = axis.to_array();
        let n = DVec3::from_array(std::array::from_fn(|i| (0..3).map(|j| cov[i][j] * a[j]).sum()));
        axis = n.try_normalize().unwrap_or(DVec3::X);
    }
    let mut side = vec![NONE; topo.adj.len()];
    for &k in &piece.tris {
        side[k as usize] = u32::from((centroid(k) - c).dot(axis) > 0.0);
    }
    // connected pieces of each side
    let mut out = Vec::new();
    let mut seen: HashMap<u32, ()> = HashMap::new();
    for &s in &piece.tris {
        if seen.contains_key(&s) {
            continue;
        }
        let mut tris = vec![s];
        seen.insert(s, ());
        let mut i = 0;
        while i < tris.len() {
            let t = tris[i];
            for &j in &topo.adj[t as usize] {
                if j != NONE && side[j as usize] == side[s as usize] && !seen.contains_key(&j) {
                    seen.insert(j, ());
                    tris.push(j);
                }
            }
            i += 1;
        }
        tris.sort_unstable();
        out.push(Piece { tris });
    }
    if out.len() == 1 {
        // degenerate cut (all centroids on one side): halve by index
        let t = out.pop().unwrap().tris;
        let (a, b) = t.split_at(t.len() / 2);
        out = vec![Piece { tris: a.to_vec() }, Piece { tris: b.to_vec() }];
    }
    out
}

/// Curved-mesh unwrap: new mesh (vertices split along seams), chart per triangle, chart count,
/// statistics.
pub fn unwrap(
    mesh: &TriangleMesh,
    res: usize,
) -> Result<(TriangleMesh, Vec<u32>, usize, UnwrapStats), String> {
    let clock = std::time::Instant::now();
    let topo = Topology::new(mesh);
    let p64 = segment::positions64(mesh);
    let n_s = segment::smoothed_normals(&topo, SMOOTH_PASSES);
    let (label, nc) = segment::segment(&topo, &n_s, CONE_DEG);
    let mut stats = UnwrapStats { segments: nc, ..Default::default() };
    stats.seconds[0] = clock.elapsed().as_secs_f64();
    let mut pieces: Vec<Piece> = (0..nc).map(|_| Piece { tris: Vec::new() }).collect();
    for (k, &l) in label.iter().enumerate() {
        pieces[l as usize].tris.push(k as u32);
    }
    let mut done: Vec<(Piece, Flat)> = Vec::new();
    while !pieces.is_empty() {
        let results: Vec<_> = pieces.par_iter().map(|pc| flatten(mesh, &topo, &p64, pc)).collect();
        let mut next = Vec::new();
        for (pc, r) in pieces.into_iter().zip(results) {
            match r {
                Ok((f, it, planar)) => {
                    stats.cg_iterations += it;
                    stats.planar += usize::from(planar);
                    done.push((pc, f));
                }
                Err(sub) => {
                    stats.splits += 1;
                    next.extend(sub);
                }
            }
        }
        pieces = next;
    }
    let flats: Vec<Flat> = done.iter().map(|d| Flat { tris: d.1.tris.clone(), uv: d.1.uv.clone() }).collect();
    stats.seconds[1] = clock.elapsed().as_secs_f64() - stats.seconds[0];
    // UVs in [0, 1] from a layout on at most PACK_RES² texels: gaps of ≥ 2 layout texels are
    // ≥ 2 texels at any finer resolution, and the packing time stays bounded
    let pr = res.min(PACK_RES);
    let (packed, density) = pack::pack(&flats, pr)?;
    let density = density * res as f64 / pr as f64;
    stats.seconds[2] = clock.elapsed().as_secs_f64() - stats.seconds[0] - stats.seconds[1];
    stats.density = density;
    // output mesh: one vertex per (mesh vertex, chart)
    let mut tri_chart = vec![0u32; mesh.triangle_count()];
    let mut corner_uv = vec![[Vec2::ZERO; 3]; mesh.triangle_count()];
    for (c, p) in packed.iter().enumerate() {
        for &j in &p.tri_ids {
            let k = done[p.src].0.tris[j] as usize;
            tri_chart[k] = c as u32;
            corner_uv[k] = flats[p.src].tris[j].map(|i| p.uv[i as usize].as_vec2());
        }
    }
    let mut out = TriangleMesh::default();
    let mut map: HashMap<(u32, u32), u32> = HashMap::new();
    for (k, t) in mesh.indices.iter().enumerate() {
        let c = tri_chart[k];
        let idx = std::array::from_fn(|j| {
            let v = t[j];
            *map.entry((v, c)).or_insert_with(|| {
                out.positions.push(mesh.positions[v as usize]);
                if !mesh.normals.is_empty() {
                    out.normals.push(mesh.normals[v as usize]);
                }
                out.uvs.push(corner_uv[k][j]);
                (out.positions.len() - 1) as u32
            })
        });
        out.indices.push(idx);
    }
    Ok((out, tri_chart, packed.len(), stats))
}
