//! Microbenchmark of `TinyAccel` closest hits on the Cornell box (`scenes::cornell_box`): the
//! branch-free search (`intersect`) against the group-by-group loop (`intersect_sequential`) and
//! eight rays at once (`PacketAccel::intersect_lanes`, consecutive rays in a packet),
//! interleaved in one process, on two ray sets: random origins and directions inside the room,
//! and rays leaving the walls and box faces with cosine-distributed directions (what the light
//! tracer traces). First checks that all three give the same hits as `BruteForce`. Prints the median
//! ns per ray of `reps` runs each. To compare two versions of `TinyAccel`, copy the old
//! `accel/tiny.rs` next to this file as a module and add it as a third mode.
//!
//! Run: `cargo run --release -p opal --example tiny_rays [reps]`.

use opal::accel::packet::{PACKET, PacketAccel, RayPacket};
use opal::accel::{BruteForce, TinyAccel, offset_ray_origin};
use opal::geometry::Ray;
use opal::math::{Frame, Vec3};
use opal::sampling::{Rng, square_to_cosine_hemisphere};
use std::time::Instant;

const N: usize = 1 << 20;

fn random_inside() -> Vec<Ray> {
    let mut rng = Rng::new(1, 2, 3);
    (0..N)
        .map(|_| {
            let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 1.8 - 0.9;
            let d = (Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - 1.0).normalize();
            Ray::new(o, d)
        })
        .collect()
}

/// Rays from uniformly chosen points of the surfaces (area-weighted), cosine-distributed around
/// the normal pointing into the room (walls) or out of the box (box faces).
fn from_surfaces(tris: &[[Vec3; 3]]) -> Vec<Ray> {
    let area: Vec<f32> = tris.iter().map(|t| 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length()).collect();
    let total: f32 = area.iter().sum();
    let centre = |r: std::ops::Range<usize>| {
        let n = r.len() as f32 * 3.0;
        r.map(|i| tris[i][0] + tris[i][1] + tris[i][2]).fold(Vec3::ZERO, |a, b| a + b) / n
    };
    let (c1, c2) = (centre(12..22), centre(22..32));
    let mut rng = Rng::new(4, 5, 6);
    (0..N)
        .map(|_| {
            let mut x = rng.next_f32() * total;
            let mut i = 0;
            while i + 1 < tris.len() && x >= area[i] {
                x -= area[i];
                i += 1;
            }
            let t = tris[i];
            let (mut u, mut v) = (rng.next_f32(), rng.next_f32());
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            let p = t[0] * (1.0 - u - v) + t[1] * u + t[2] * v;
            let mut n = (t[1] - t[0]).cross(t[2] - t[0]).normalize();
            let away = if i < 12 {
                -p
            } else if i < 22 {
                p - c1
            } else {
                p - c2
            };
            if n.dot(away) < 0.0 {
                n = -n;
            }
            let d = Frame::from_normal(n).to_world(square_to_cosine_hemisphere(rng.next_2d()));
            Ray::new(offset_ray_origin(p, n, d), d)
        })
        .collect()
}

fn main() {
    let reps: usize = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(5);
    let tris = opal::accel::scenes::cornell_box();
    let a = TinyAccel::new(tris.clone());
    let b = BruteForce::new(tris.clone());
    let pa = PacketAccel::new(tris.clone());
    for (name, rays) in [("inside", random_inside()), ("surface", from_surfaces(&tris))] {
        let mut hits = 0usize;
        for r in &rays {
            let h = a.intersect(r);
            assert_eq!(h, b.intersect(r), "{r:?}");
            assert_eq!(a.intersect_sequential(r), h, "{r:?}");
            hits += h.is_some() as usize;
        }
        let packets: Vec<RayPacket> = rays.chunks(PACKET).map(RayPacket::from_rays).collect();
        for (p, c) in packets.iter().zip(rays.chunks(PACKET)) {
            let h = pa.intersect(p);
            for (l, r) in c.iter().enumerate() {
                assert_eq!(h[l], b.intersect(r), "{r:?}");
            }
        }
        println!("{name}: {:.3} of the rays hit; identical hits", hits as f64 / rays.len() as f64);
        let mut times = [Vec::new(), Vec::new(), Vec::new()];
        for _ in 0..reps {
            for (mode, times) in times.iter_mut().enumerate() {
                let t0 = Instant::now();
                let mut s = 0.0f64;
                let mut n = 0u64;
                if mode == 2 {
                    for p in &packets {
                        let h = pa.intersect_lanes(p);
                        for l in 0..PACKET {
                            if h.prim[l] >= 0 {
                                s += h.t[l] as f64;
                                n += h.prim[l] as u64;
                            }
                        }
                    }
                    std::hint::black_box((s, n));
                    times.push(t0.elapsed().as_secs_f64() * 1e9 / rays.len() as f64);
                    continue;
                }
                for r in &rays {
                    let h = if mode == 0 { a.intersect(r) } else { a.intersect_sequential(r) };
                    if let Some(h) = h {
                        s += h.t as f64;
                        n += h.prim as u64;
                    }
                }
                std::hint::black_box((s, n));
                times.push(t0.elapsed().as_secs_f64() * 1e9 / rays.len() as f64);
            }
        }
        let names = ["intersect", "sequential", "packet"];
        for (t, nm) in times.iter_mut().zip(names) {
            t.sort_by(f64::total_cmp);
            let v: Vec<String> = t.iter().map(|x| format!("{x:.1}")).collect();
            println!("  {name:8} {nm:10} median {:.1} ns/ray  [{}]", t[t.len() / 2], v.join(" "));
        }
    }
}
