//! Compares Opal's BVH with `obvhs` (CWBVH, PLOC build) on incoherent rays: build time and
//! millions of closest-hit / any-hit rays per second on a 1 M-triangle displaced sphere and on
//! the Cornell box, on a fixed number of threads (default 2). Both structures use the same
//! watertight triangle test, so the comparison is of the structures.
//!
//! Run: `cargo run --release -p opal --example accel_compare -- [threads] [repeats]`.
//! Numbers are medians over `repeats` runs (default 7). `docs/performance.md` records results.
//! Also used as a module by `benches/accel.rs`.
#![allow(dead_code)]

use glam_obvhs::Vec3A;
use obvhs::BvhBuildParams;
use obvhs::cwbvh::CwBvh;
use obvhs::cwbvh::builder::build_cwbvh_from_tris;
use opal::accel::bvh::SahParams;
use opal::accel::scenes::{cornell_box, mesh_triangles, sphere_mesh};
use opal::accel::{Bvh, Hit, TriRay};
use opal::geometry::Ray;
use opal::math::Vec3;
use opal::sampling::Rng;
use rayon::prelude::*;
use std::time::{Duration, Instant};

/// The benchmark mesh: a UV sphere with 2 · 1000 · 500 = 1 000 000 triangles (edges ≈ 0.006),
/// each vertex radius jittered by up to ±0.001 (a rough surface, not a field of spikes).
pub fn big_mesh() -> Vec<[Vec3; 3]> {
    mesh_triangles(&sphere_mesh(501, 1000, 0.001, 42))
}

/// Incoherent rays: uniform origins in a ball of radius `r` around `c`, uniform directions.
pub fn incoherent_rays(n: usize, c: Vec3, r: f32, seed: u64) -> Vec<Ray> {
    (0..n)
        .into_par_iter()
        .map(|i| {
            let mut rng = Rng::new(seed, 0, i as u64);
            let o = loop {
                let p = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - 1.0;
                if p.length_squared() <= 1.0 {
                    break c + p * r;
                }
            };
            let z = 2.0 * rng.next_f32() - 1.0;
            let phi = 2.0 * std::f32::consts::PI * rng.next_f32();
            let s = (1.0 - z * z).max(0.0).sqrt();
            Ray::new(o, Vec3::new(s * phi.cos(), s * phi.sin(), z))
        })
        .collect()
}

/// `obvhs` CWBVH with the triangles reordered to its leaf order, queried with Opal's
/// watertight triangle test.
pub struct Obvhs {
    bvh: CwBvh,
    tris: Vec<[Vec3; 3]>,
}

fn to_a(v: Vec3) -> Vec3A {
    Vec3A::new(v.x, v.y, v.z)
}

impl Obvhs {
    /// Builds with obvhs' `medium_build` preset (its default quality/speed trade-off).
    pub fn new(tris: &[[Vec3; 3]]) -> Self {
        let otris: Vec<obvhs::triangle::Triangle> = tris
            .iter()
            .map(|t| obvhs::triangle::Triangle { v0: to_a(t[0]), v1: to_a(t[1]), v2: to_a(t[2]) })
            .collect();
        let bvh = build_cwbvh_from_tris(&otris, BvhBuildParams::medium_build(), &mut Duration::default());
        let tris = bvh.primitive_indices.iter().map(|&i| tris[i as usize]).collect();
        Obvhs { bvh, tris }
    }
    fn oray(ray: &Ray) -> obvhs::ray::Ray {
        obvhs::ray::Ray::new(to_a(ray.o), to_a(ray.d), 0.0, ray.tmax)
    }
    /// Closest hit (`prim` in the input order).
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        let tr = TriRay::new(ray);
        let mut hit = obvhs::ray::RayHit::none();
        let mut best: Option<Hit> = None;
        self.bvh.ray_traverse(Self::oray(ray), &mut hit, |r, id| {
            match tr.intersect(&self.tris[id], r.tmax) {
                Some((t, b1, b2)) => {
                    best = Some(Hit { t, prim: self.bvh.primitive_indices[id], b1, b2 });
                    t
                }
                None => f32::INFINITY,
            }
        });
        best
    }
    /// Any hit.
    pub fn occluded(&self, ray: &Ray) -> bool {
        let tr = TriRay::new(ray);
        !self.bvh.ray_traverse_miss(Self::oray(ray), |r, id| match tr.intersect(&self.tris[id], r.tmax) {
            Some((t, _, _)) => t,
            None => f32::INFINITY,
        })
    }
}

/// Traces all rays in parallel chunks; returns (hit count, checksum of t) so nothing is
/// optimised away.
pub fn trace<F: Fn(&Ray) -> Option<Hit> + Sync>(rays: &[Ray], f: F) -> (usize, f64) {
    rays.par_chunks(4096)
        .map(|ch| {
            let mut n = 0;
            let mut s = 0.0f64;
            for r in ch {
                if let Some(h) = f(r) {
                    n += 1;
                    s += h.t as f64;
                }
            }
            (n, s)
        })
        .reduce(|| (0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1))
}

/// Counts occluded rays in parallel chunks.
/// Like [`trace`], eight rays at a time through `Bvh::intersect8` (interleaved traversals).
pub fn trace8(rays: &[Ray], bvh: &Bvh) -> (usize, f64) {
    use opal::accel::packet::{PACKET, RayPacket};
    rays.par_chunks(4096)
        .map(|ch| {
            let mut n = 0;
            let mut s = 0.0f64;
            for c in ch.chunks(PACKET) {
                let p = RayPacket::from_rays(c);
                let h = bvh.intersect8(&p);
                for l in 0..c.len() {
                    if let Some(h) = h.hit(l) {
                        n += 1;
                        s += h.t as f64;
                    }
                }
            }
            (n, s)
        })
        .reduce(|| (0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1))
}

pub fn trace_any<F: Fn(&Ray) -> bool + Sync>(rays: &[Ray], f: F) -> usize {
    rays.par_chunks(4096).map(|ch| ch.iter().filter(|r| f(r)).count()).sum()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    v[v.len() / 2]
}

/// CPU time (user + system) of this process in seconds, from `/proc/self/stat` (clock ticks of
/// 1/100 s). On a machine shared with other jobs, work per CPU-second is far less noisy than
/// wall-clock rates.
pub fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the command name (which is in parentheses): state is field 3, utime 14, stime 15.
    let rest = stat.rsplit_once(')').map(|x| x.1).unwrap_or("");
    let f: Vec<&str> = rest.split_whitespace().collect();
    let tick = |i: usize| f.get(i).and_then(|s| s.parse::<f64>().ok()).unwrap_or(0.0);
    (tick(11) + tick(12)) / 100.0
}

/// (wall seconds, CPU seconds, result).
fn time<R>(f: impl FnOnce() -> R) -> (f64, f64, R) {
    let c = cpu_seconds();
    let t = Instant::now();
    let r = f();
    (t.elapsed().as_secs_f64(), cpu_seconds() - c, r)
}

fn report(name: &str, n: usize, secs: Vec<(f64, f64)>) {
    let rate = |v: Vec<f64>| {
        let mut r: Vec<f64> = v.iter().map(|s| n as f64 / s / 1e6).collect();
        r.sort_by(|a, b| a.partial_cmp(b).unwrap());
        (median(r.clone()), r[0], r[r.len() - 1])
    };
    let (w, wmin, wmax) = rate(secs.iter().map(|s| s.0).collect());
    let (c, cmin, cmax) = rate(secs.iter().map(|s| s.1).collect());
    println!(
        "{name:<26} wall {w:6.2} M rays/s [{wmin:5.2}, {wmax:5.2}]   per CPU-s {c:6.2} M [{cmin:5.2}, {cmax:5.2}]   ({} runs)",
        secs.len()
    );
}

/// SAH constants: the defaults, or `SAH_TRAV` / `SAH_BLOCK` from the environment (for tuning).
fn sah_params() -> SahParams {
    let d = SahParams::default();
    let var = |k: &str| std::env::var(k).ok();
    SahParams {
        traversal: var("SAH_TRAV").map_or(d.traversal, |v| v.parse().expect("SAH_TRAV")),
        block: var("SAH_BLOCK").map_or(d.block, |v| v.parse().expect("SAH_BLOCK")),
    }
}

fn run_scene(label: &str, tris: Vec<[Vec3; 3]>, rays: &[Ray], repeats: usize) {
    println!("== {label}: {} triangles, {} rays", tris.len(), rays.len());
    let mut tb = Vec::new();
    let mut to = Vec::new();
    let mut bvh = None;
    let mut ob = None;
    let (mut tbc, mut toc) = (Vec::new(), Vec::new());
    for _ in 0..repeats.min(5) {
        let (s, c, b) = time(|| Bvh::with_params(&tris, sah_params()));
        tb.push(s);
        tbc.push(c);
        bvh = Some(b);
        let (s, c, o) = time(|| Obvhs::new(&tris));
        to.push(s);
        toc.push(c);
        ob = Some(o);
    }
    let (bvh, ob) = (bvh.unwrap(), ob.unwrap());
    println!(
        "build: opal {:8.1} ms (CPU {:8.1} ms)   obvhs {:8.1} ms (CPU {:8.1} ms)   (median of {}; opal nodes {}, leaves {}, {:.1} MB)",
        median(tb) * 1e3,
        median(tbc) * 1e3,
        median(to) * 1e3,
        median(toc) * 1e3,
        repeats.min(5),
        bvh.node_count(),
        bvh.leaf_count(),
        bvh.memory_bytes() as f64 / 1e6
    );
    // Same answers (t identical: same triangle test; prims may differ on exact ties).
    let (ha, sa) = trace(rays, |r| bvh.intersect(r));
    let (hb, sb) = trace(rays, |r| ob.intersect(r));
    assert_eq!(trace8(rays, &bvh), (ha, sa), "packets differ from single rays");
    assert_eq!(ha, hb, "hit counts differ");
    assert!((sa - sb).abs() <= 1e-9 * sa.abs(), "t sums differ: {sa} vs {sb}");
    let (mut c_opal, mut c_ob, mut a_opal, mut a_ob) = (vec![], vec![], vec![], vec![]);
    let mut c_opal8 = vec![];
    for _ in 0..repeats {
        // Interleaved so both see the same machine load.
        let t = |x: (f64, f64, _)| (x.0, x.1);
        c_opal.push(t(time(|| trace(rays, |r| bvh.intersect(r)))));
        c_opal8.push(t(time(|| trace8(rays, &bvh))));
        c_ob.push(t(time(|| trace(rays, |r| ob.intersect(r)))));
        let t = |x: (f64, f64, _)| (x.0, x.1);
        a_opal.push(t(time(|| trace_any(rays, |r| bvh.occluded(r)))));
        a_ob.push(t(time(|| trace_any(rays, |r| ob.occluded(r)))));
    }
    report("closest-hit opal Bvh", rays.len(), c_opal);
    report("closest-hit opal Bvh x8", rays.len(), c_opal8);
    report("closest-hit obvhs CwBvh", rays.len(), c_ob);
    report("any-hit     opal Bvh", rays.len(), a_opal);
    report("any-hit     obvhs CwBvh", rays.len(), a_ob);
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let threads: usize = args.get(1).map(|s| s.parse().expect("threads")).unwrap_or(2);
    let repeats: usize = args.get(2).map(|s| s.parse().expect("repeats")).unwrap_or(7);
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    pool.install(|| {
        println!("threads: {threads}");
        let rays = incoherent_rays(1 << 20, Vec3::ZERO, 0.8, 1);
        if std::env::var("ONLY_CBOX").is_err() {
            run_scene("displaced sphere", big_mesh(), &rays, repeats);
        }
        // Cornell box: origins inside the box, random directions (about half escape through the
        // open front).
        let rays = incoherent_rays(1 << 21, Vec3::ZERO, 0.95, 2);
        run_scene("Cornell box", cornell_box(), &rays, repeats);
    });
}
