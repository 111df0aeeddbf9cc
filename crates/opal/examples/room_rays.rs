//! The intersection work of a light-tracing pass in a room, alone: light paths are traced once
//! (single rays, cosine bounces from the emitters, Russian roulette), every ray is kept, the rays
//! are shuffled (the wavefront's packets hold rays of unrelated paths) and then timed through
//! `Accel::intersect8_many` in calls of four packets of eight (the light tracer's wavefront,
//! `integrator/light_tracer/wavefront.rs`) and through `Accel::occluded8_many` (the path
//! tracer's shadow rays use it). Prints the structure's figures, rays per CPU-second (median of
//! the repeats) and a checksum of the hits (t, triangle, barycentrics bits) that must not change
//! when the structure's code does.
//!
//! Run: `cargo run --release -p opal --example room_rays -- SCENE.xml [PATHS] [REPEATS] [SETS]` (e.g.
//! the scanned-object room of `make_scan_room`); one thread. Use it for A/B of accel changes
//! (far less noise than the whole pass; memory effects of the rest of the pass are absent).

use opal::accel::packet::{PACKET, PacketHits, RayPacket};
use opal::accel::{Accel, spawn_ray};
use opal::geometry::Ray;
use opal::math::{Frame, Vec3};
use opal::sampling::{Rng, square_to_cosine_hemisphere};
use opal::scene::load_mitsuba_xml;
use std::time::Instant;

/// Packets per call by default, as the light tracer's wavefront.
const SETS: usize = 4;

/// CPU time of this thread in seconds (`/proc/thread-self/schedstat`: nanoseconds on a CPU),
/// falling back to the process's user + system time (`/proc/self/stat`, 10 ms ticks).
fn cpu_seconds() -> f64 {
    if let Some(ns) = std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next().and_then(|f| f.parse::<f64>().ok()))
    {
        return ns * 1e-9;
    }
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let rest = stat.rsplit_once(')').map(|x| x.1).unwrap_or("");
    let f: Vec<&str> = rest.split_whitespace().collect();
    let tick = |i: usize| f.get(i).and_then(|s| s.parse::<f64>().ok()).unwrap_or(0.0);
    (tick(11) + tick(12)) / 100.0
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let path = args.get(1).expect("usage: room_rays SCENE.xml [PATHS] [REPEATS] [SETS]");
    let paths: usize = args.get(2).map(|a| a.parse().expect("PATHS")).unwrap_or(200_000);
    let repeats: usize = args.get(3).map(|a| a.parse().expect("REPEATS")).unwrap_or(5);
    let sets: usize = args.get(4).map(|a| a.parse().expect("SETS")).unwrap_or(SETS);
    let desc = load_mitsuba_xml(std::path::Path::new(path), &[]).expect("scene loads");
    let mut tris = Vec::new();
    let mut lights = Vec::new();
    for s in &desc.shapes {
        for idx in &s.mesh.indices {
            if s.emitter.is_some() {
                lights.push(tris.len());
            }
            tris.push(idx.map(|i| s.mesh.positions[i as usize]));
        }
    }
    assert!(!lights.is_empty(), "the scene needs an area light");
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for p in tris.iter().flatten() {
        (lo, hi) = (lo.min(*p), hi.max(*p));
    }
    let centre = (lo + hi) * 0.5;
    let t = Instant::now();
    let accel = Accel::new(tris.clone());
    println!("{} triangles, built in {:.3} s", tris.len(), t.elapsed().as_secs_f64());
    if let Accel::Split(s) = &accel {
        let b = s.bvh();
        println!(
            "split: {} big triangles; BVH {} nodes, {} leaves ({:.2} triangles per leaf), {:.2} MB",
            s.big_count(),
            b.node_count(),
            b.leaf_count(),
            b.len() as f64 / b.leaf_count() as f64,
            b.memory_bytes() as f64 / 1e6
        );
    }
    // light paths: start on an emitter (the side facing the room's centre), cosine bounces
    let mut rng = Rng::new(1, 0, 0);
    let mut rays: Vec<Ray> = Vec::new();
    let ng_of = |tri: &[Vec3; 3]| (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize();
    for _ in 0..paths {
        let tri = tris[lights[(rng.next_f32() * lights.len() as f32) as usize % lights.len()]];
        let (u, v) = (rng.next_f32(), rng.next_f32());
        let (b1, b2) = if u + v > 1.0 { (1.0 - u, 1.0 - v) } else { (u, v) };
        let mut p = tri[0] * (1.0 - b1 - b2) + tri[1] * b1 + tri[2] * b2;
        let mut ng = ng_of(&tri);
        if ng.dot(centre - p) < 0.0 {
            ng = -ng;
        }
        let mut n = ng;
        for depth in 0..32 {
            let d = Frame::from_normal(n).to_world(square_to_cosine_hemisphere(rng.next_2d()));
            let ray = spawn_ray(p, ng, d);
            rays.push(ray);
            let Some(h) = accel.intersect(&ray) else { break };
            if depth >= 2 && rng.next_f32() > 0.6 {
                break;
            }
            let tri = tris[h.prim as usize];
            p = tri[0] * (1.0 - h.b1 - h.b2) + tri[1] * h.b1 + tri[2] * h.b2;
            ng = ng_of(&tri);
            n = if ng.dot(ray.d) < 0.0 { ng } else { -ng };
        }
    }
    // shuffle (Fisher–Yates, fixed seed)
    for i in (1..rays.len()).rev() {
        let j = (rng.next_f32() * (i + 1) as f32) as usize % (i + 1);
        rays.swap(i, j);
    }
    let packets: Vec<RayPacket> = rays.chunks(PACKET).map(RayPacket::from_rays).collect();
    println!("{} rays ({:.2} per path)", rays.len(), rays.len() as f64 / paths as f64);
    let mut single = Vec::new();
    let mut closest = Vec::new();
    let mut any = Vec::new();
    let mut sums = (0u64, 0u64);
    for _ in 0..repeats {
        let c = cpu_seconds();
        let mut sum = 0u64;
        let mut hits = vec![PacketHits::NONE; sets];
        for call in packets.chunks(sets) {
            accel.intersect8_many(call, &mut hits[..call.len()]);
            for h in &hits[..call.len()] {
                for l in 0..PACKET {
                    if h.prim[l] >= 0 {
                        let bits = [h.t[l].to_bits(), h.prim[l] as u32, h.b1[l].to_bits(), h.b2[l].to_bits()];
                        sum = bits
                            .iter()
                            .fold(sum.rotate_left(7), |s, &b| s.wrapping_mul(31).wrapping_add(b as u64));
                    }
                }
            }
        }
        closest.push(cpu_seconds() - c);
        let c = cpu_seconds();
        let mut s1 = 0u64;
        for r in &rays {
            if let Some(h) = accel.intersect(r) {
                let bits = [h.t.to_bits(), h.prim, h.b1.to_bits(), h.b2.to_bits()];
                s1 = bits.iter().fold(s1.rotate_left(7), |s, &b| s.wrapping_mul(31).wrapping_add(b as u64));
            }
        }
        single.push(cpu_seconds() - c);
        assert_eq!(s1, sum, "single rays and packets give the same hits");
        let c = cpu_seconds();
        let mut blocked = vec![0u32; sets];
        let mut nb = 0u64;
        for call in packets.chunks(sets) {
            // shadow rays: the same rays shortened to 90 % of their hit distance or 1
            let mut sh = vec![RayPacket::default(); sets];
            for (s, p) in sh.iter_mut().zip(call) {
                *s = *p;
                for l in 0..PACKET {
                    s.tmax[l] = if p.tmax[l] > 0.0 { 1.0 } else { 0.0 };
                }
            }
            accel.occluded8_many(&sh[..call.len()], &mut blocked[..call.len()]);
            nb += blocked[..call.len()].iter().map(|b| b.count_ones() as u64).sum::<u64>();
        }
        any.push(cpu_seconds() - c);
        sums = (sum, nb);
    }
    // the fastest repeat (on a shared machine the others lost time to their neighbours) and
    // the median
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        (v[0], v[v.len() / 2])
    };
    let n = rays.len() as f64;
    let rate = |v: &mut Vec<f64>| {
        let (best, mid) = median(v);
        format!("{:.2} M rays/CPU-s (median {:.2})", n / best / 1e6, n / mid / 1e6)
    };
    println!("closest hit, single rays (intersect): {}", rate(&mut single));
    println!("closest hit (intersect8_many x{sets}): {}", rate(&mut closest));
    println!("any hit (occluded8_many, tmax 1): {}", rate(&mut any));
    println!("checksum {:016x}, blocked {}", sums.0, sums.1);
}
