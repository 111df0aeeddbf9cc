//! Chart segmentation of curved meshes into few, compact (disc-like, nearly convex) charts:
//! welded topology, smoothed face normals, and a centroidal Voronoi partition over the surface
//! refined until every chart's normals fit a cone.
//!
//! * Vertices are welded by bit-identical position; triangles are adjacent across an edge used
//!   by exactly two triangles (edges of three or more triangles are seams).
//! * Face normals are smoothed by Jacobi passes over edge neighbours (area-weighted), so the
//!   small bumps of a scanned surface do not fragment the charts.
//! * Flooding: a priority queue grows every chart from its seed triangle over edges, ordered by
//!   the distance between triangle centroids and the seed's centroid (ties first-in first-out);
//!   each triangle joins the first chart that reaches it. This is a Voronoi partition restricted
//!   to the surface, so charts are compact and their boundaries straight-ish.
//! * Lloyd passes: each seed moves to the triangle nearest to its chart's area-weighted
//!   centroid, and the flooding is repeated (4 passes).
//! * Cone guard: while some triangle's smoothed normal deviates from its chart's mean normal by
//!   more than the cone angle, a new seed is added at the worst triangle of each such chart
//!   (so curved regions get more, smaller charts; the conformal map handles the rest).
//! * Afterwards a majority filter straightens jagged boundaries and disconnected parts become
//!   charts of their own.
//!
//! Tests: `atlas::tests` (the displaced sphere unwrap).

use opal::geometry::TriangleMesh;
use opal::math::DVec3;
use std::cmp::Reverse;
use std::collections::{BinaryHeap, HashMap};

/// No neighbour across an edge (boundary or non-manifold edge).
pub const NONE: u32 = u32::MAX;

/// Welded connectivity of a triangle mesh.
pub struct Topology {
    /// Welded vertex id of each mesh vertex.
    pub wid: Vec<u32>,
    /// Neighbour triangle across edge `e` (corners `e`, `e + 1`), or [`NONE`].
    pub adj: Vec<[u32; 3]>,
    /// Unit face normals (zero for degenerate triangles), f64.
    pub normal: Vec<DVec3>,
    /// Face areas, f64.
    pub area: Vec<f64>,
    /// Face centroids, f64.
    pub centroid: Vec<DVec3>,
}

/// Positions of a mesh in f64.
pub fn positions64(mesh: &TriangleMesh) -> Vec<DVec3> {
    mesh.positions.iter().map(|p| p.as_dvec3()).collect()
}

impl Topology {
    /// Connectivity of `mesh`.
    pub fn new(mesh: &TriangleMesh) -> Self {
        let mut weld: HashMap<[u32; 3], u32> = HashMap::new();
        let wid: Vec<u32> = mesh
            .positions
            .iter()
            .map(|p| {
                let n = weld.len() as u32;
                *weld.entry([p.x.to_bits(), p.y.to_bits(), p.z.to_bits()]).or_insert(n)
            })
            .collect();
        let mut edges: HashMap<(u32, u32), Vec<(u32, u8)>> = HashMap::new();
        for (k, t) in mesh.indices.iter().enumerate() {
            for e in 0..3 {
                let (a, b) = (wid[t[e] as usize], wid[t[(e + 1) % 3] as usize]);
                if a != b {
                    edges.entry((a.min(b), a.max(b))).or_default().push((k as u32, e as u8));
                }
            }
        }
        let mut adj = vec![[NONE; 3]; mesh.indices.len()];
        for v in edges.values() {
            if let [(t0, e0), (t1, e1)] = v[..] {
                adj[t0 as usize][e0 as usize] = t1;
                adj[t1 as usize][e1 as usize] = t0;
            }
        }
        let p = positions64(mesh);
        let (mut normal, mut area) = (Vec::with_capacity(adj.len()), Vec::with_capacity(adj.len()));
        let mut centroid = Vec::with_capacity(adj.len());
        for t in &mesh.indices {
            let [a, b, c] = t.map(|i| p[i as usize]);
            centroid.push((a + b + c) / 3.0);
            let n = (b - a).cross(c - a);
            area.push(0.5 * n.length());
            normal.push(n.normalize_or_zero());
        }
        Topology { wid, adj, normal, area, centroid }
    }
}

/// Area-weighted face normals smoothed by `passes` Jacobi passes over edge neighbours.
pub fn smoothed_normals(topo: &Topology, passes: usize) -> Vec<DVec3> {
    let mut n: Vec<DVec3> = topo.normal.clone();
    for _ in 0..passes {
        let prev = n.clone();
        for (k, nk) in n.iter_mut().enumerate() {
            let mut s = prev[k] * topo.area[k];
            for &j in &topo.adj[k] {
                if j != NONE {
                    s += prev[j as usize] * topo.area[j as usize];
                }
            }
            let s = s.normalize_or_zero();
            *nk = if s == DVec3::ZERO { prev[k] } else { s };
        }
    }
    n
}

/// Assigns each triangle to the seed that reaches it first, flooding over edges in order of the
/// distance between the triangle's centroid and the seed's (see the module docs); triangles no
/// seed reaches stay `NONE`.
fn flood(topo: &Topology, seeds: &[usize], chart: &mut [u32]) {
    chart.fill(NONE);
    let mut heap = BinaryHeap::new();
    let mut tick = 0u64;
    for (p, &s) in seeds.iter().enumerate() {
        heap.push(Reverse((0u64, tick, s as u32, p as u32)));
        tick += 1;
    }
    while let Some(Reverse((_, _, t, p))) = heap.pop() {
        if chart[t as usize] != NONE {
            continue;
        }
        chart[t as usize] = p;
        for &j in &topo.adj[t as usize] {
            if j != NONE && chart[j as usize] == NONE {
                let e = (topo.centroid[j as usize] - topo.centroid[seeds[p as usize]]).length_squared();
                heap.push(Reverse((e.to_bits(), tick, j, p)));
                tick += 1;
            }
        }
    }
}

/// Segments the mesh into charts whose smoothed normals stay within `cone_deg` of their
/// proxy normal: chart index per triangle (connected over edges), number of charts.
pub fn segment(topo: &Topology, n: &[DVec3], cone_deg: f64) -> (Vec<u32>, usize) {
    let nt = topo.adj.len();
    let cos_max = cone_deg.to_radians().cos();
    let mut proxies = vec![n[0]];
    let mut seeds = vec![0usize];
    let mut chart = vec![NONE; nt];
    loop {
        for _ in 0..4 {
            flood(topo, &seeds, &mut chart);
            // unreached triangles (another connected component): a new proxy there
            if let Some(t) = (0..nt).find(|&t| chart[t] == NONE) {
                proxies.push(n[t]);
                seeds.push(t);
                continue;
            }
            let mut sum = vec![DVec3::ZERO; proxies.len()];
            for t in 0..nt {
                sum[chart[t] as usize] += n[t] * topo.area[t];
            }
            for (p, s) in sum.iter().enumerate() {
                let s = s.normalize_or_zero();
                if s != DVec3::ZERO {
                    proxies[p] = s;
                }
            }
            let mut cen = vec![(DVec3::ZERO, 0.0); proxies.len()];
            for t in 0..nt {
                let c = &mut cen[chart[t] as usize];
                c.0 += topo.centroid[t] * topo.area[t];
                c.1 += topo.area[t];
            }
            let mut best = vec![(f64::MAX, 0usize); proxies.len()];
            for t in 0..nt {
                let p = chart[t] as usize;
                let e = (topo.centroid[t] - cen[p].0 / cen[p].1.max(1e-300)).length_squared();
                if e < best[p].0 {
                    best[p] = (e, t);
                }
            }
            for (p, b) in best.iter().enumerate() {
                seeds[p] = b.1;
            }
        }
        if chart.contains(&NONE) {
            continue;
        }
        let mut worst = vec![(cos_max, NONE); proxies.len()];
        for t in 0..nt {
            let p = chart[t] as usize;
            let c = n[t].dot(proxies[p]);
            if c < worst[p].0 && n[t] != DVec3::ZERO {
                worst[p] = (c, t as u32);
            }
        }
        let before = proxies.len();
        for w in worst {
            if w.1 != NONE {
                proxies.push(n[w.1 as usize]);
                seeds.push(w.1 as usize);
            }
        }
        if proxies.len() == before || proxies.len() > nt.min(4096) {
            break;
        }
    }
    smooth_boundaries(topo, &mut chart, 16);
    // renumber (a proxy may have lost its region) and split disconnected regions
    components(topo, &chart)
}

/// Majority filter on the labels: a triangle two of whose neighbours share another label takes
/// that label (`passes` Gauss-Seidel sweeps), which straightens jagged chart boundaries.
fn smooth_boundaries(topo: &Topology, label: &mut [u32], passes: usize) {
    for _ in 0..passes {
        let mut changed = 0;
        for t in 0..label.len() {
            let a = topo.adj[t];
            let l = |i: usize| if a[i] == NONE { NONE } else { label[a[i] as usize] };
            let (l0, l1, l2) = (l(0), l(1), l(2));
            let m = if l0 != NONE && (l0 == l1 || l0 == l2) {
                l0
            } else if l1 != NONE && l1 == l2 {
                l1
            } else {
                continue;
            };
            if m != label[t] {
                label[t] = m;
                changed += 1;
            }
        }
        if changed == 0 {
            break;
        }
    }
}

/// Connected components (over edges) of the triangles sharing a label: new label per
/// triangle, count. Labels are numbered in order of their first triangle.
pub fn components(topo: &Topology, label: &[u32]) -> (Vec<u32>, usize) {
    let nt = label.len();
    let mut out = vec![NONE; nt];
    let mut count = 0u32;
    let mut stack = Vec::new();
    for s in 0..nt {
        if out[s] != NONE {
            continue;
        }
        out[s] = count;
        stack.push(s as u32);
        while let Some(t) = stack.pop() {
            for &j in &topo.adj[t as usize] {
                if j != NONE && out[j as usize] == NONE && label[j as usize] == label[s] {
                    out[j as usize] = count;
                    stack.push(j);
                }
            }
        }
        count += 1;
    }
    (out, count as usize)
}
