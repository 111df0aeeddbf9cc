//! Acceleration structure tests: BVH vs brute force (proptest, random soups and meshes),
//! watertightness on closed meshes, no self-intersection with the ray-offset helpers, mutual
//! visibility inside a convex mesh with `spawn_ray_to`.

use opal::accel::packet::RayPacket;
use opal::accel::scenes::{cornell_box, mesh_triangles, random_soup, sphere_mesh};
use opal::accel::{
    Accel, BruteForce, Bvh, SplitAccel, TinyAccel, intersect_triangle_mt, offset_ray_origin, spawn_ray_to,
};
use opal::geometry::{Ray, TriangleMesh};
use opal::math::Vec3;
use opal::sampling::Rng;
use proptest::prelude::*;

/// Uniform direction on the sphere.
fn random_dir(rng: &mut Rng) -> Vec3 {
    let z = 2.0 * rng.next_f32() - 1.0;
    let phi = 2.0 * std::f32::consts::PI * rng.next_f32();
    let r = (1.0 - z * z).max(0.0).sqrt();
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

fn random_in_ball(rng: &mut Rng, radius: f32) -> Vec3 {
    loop {
        let p = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - 1.0;
        if p.length_squared() <= 1.0 {
            return p * radius;
        }
    }
}

/// Compares closest hit and occlusion of the BVH and the brute force for one ray.
/// Returns an error message on mismatch.
fn compare(bvh: &Bvh, bf: &BruteForce, tris: &[[Vec3; 3]], ray: &Ray) -> Result<(), String> {
    let a = bvh.intersect(ray);
    let b = bf.intersect(ray);
    match (a, b) {
        (None, None) => {}
        (Some(a), Some(b)) => {
            // Same triangle test on the same data: t is bitwise identical. A different prim is
            // only allowed for an exact tie.
            if a.t != b.t {
                return Err(format!("t differs: bvh {a:?} brute {b:?} ray {ray:?}"));
            }
            if a.prim != b.prim {
                let tie = opal::accel::intersect_triangle(ray, &tris[a.prim as usize], f32::INFINITY);
                if tie.map(|h| h.0) != Some(b.t) {
                    return Err(format!("prim differs without tie: {a:?} {b:?}"));
                }
            } else if (a.b1, a.b2) != (b.b1, b.b2) {
                return Err(format!("barycentrics differ: {a:?} {b:?}"));
            }
        }
        _ => return Err(format!("hit/miss differs: bvh {a:?} brute {b:?} ray {ray:?}")),
    }
    if bvh.occluded(ray) != bf.occluded(ray) {
        return Err(format!("occluded differs for {ray:?}"));
    }
    Ok(())
}

fn soup_strategy() -> impl Strategy<Value = (usize, f32, u64, u64)> {
    (1usize..400, 0.01f32..1.0, any::<u64>(), any::<u64>())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// Random soups of overlapping triangles, random rays (some with finite tmax, some
    /// axis-aligned), closest hit and any hit identical to brute force.
    #[test]
    fn bvh_matches_brute_force_on_soups((n, size, seed, ray_seed) in soup_strategy()) {
        let mut tris = random_soup(n, size, seed);
        // A few degenerate triangles too.
        tris.push([Vec3::ZERO, Vec3::X, Vec3::X * 2.0]);
        tris.push([Vec3::splat(0.3); 3]);
        let bvh = Bvh::new(tris.clone());
        let bf = BruteForce::new(tris.clone());
        prop_assert_eq!(bvh.len(), tris.len());
        for i in 0..200u64 {
            let mut rng = Rng::new(ray_seed, 0, i);
            let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 3.0 - 1.5;
            let mut d = random_dir(&mut rng);
            if i % 10 == 0 {
                // Axis-aligned: zero direction components (0 · ∞ in the slab test).
                let k = (i / 10 % 3) as usize;
                d = Vec3::ZERO;
                d[k] = if i % 20 == 0 { 1.0 } else { -1.0 };
            }
            let tmax = if i % 3 == 0 { rng.next_f32() * 2.0 } else { f32::INFINITY };
            let ray = Ray { o, d, tmax };
            compare(&bvh, &bf, &tris, &ray).map_err(TestCaseError::fail)?;
        }
    }

    /// Displaced closed spheres: rays from inside and outside.
    #[test]
    fn bvh_matches_brute_force_on_meshes(
        n_theta in 2usize..24, n_phi in 3usize..24, disp in 0.0f32..0.3, seed in any::<u64>()
    ) {
        let tris = mesh_triangles(&sphere_mesh(n_theta, n_phi, disp, seed));
        let bvh = Bvh::new(tris.clone());
        let bf = BruteForce::new(tris.clone());
        for i in 0..200u64 {
            let mut rng = Rng::new(seed, 1, i);
            let o = if i % 2 == 0 { random_in_ball(&mut rng, 0.6) } else { random_in_ball(&mut rng, 3.0) };
            let ray = Ray::new(o, random_dir(&mut rng));
            compare(&bvh, &bf, &tris, &ray).map_err(TestCaseError::fail)?;
        }
        let (lo, hi) = bvh.bounds();
        let (mut elo, mut ehi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        for t in &tris {
            for v in t {
                elo = elo.min(*v);
                ehi = ehi.max(*v);
            }
        }
        prop_assert_eq!((lo, hi), (elo, ehi));
    }
}

#[test]
fn bvh_matches_brute_force_in_cornell_box() {
    let tris = cornell_box();
    let bvh = Bvh::new(tris.clone());
    let bf = BruteForce::new(tris.clone());
    let mut hits = 0;
    for i in 0..20_000u64 {
        let mut rng = Rng::new(7, 2, i);
        let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 1.98 - 0.99;
        let ray = Ray::new(o, random_dir(&mut rng));
        compare(&bvh, &bf, &tris, &ray).unwrap();
        hits += bvh.intersect(&ray).is_some() as u32;
    }
    // The box is closed except for the front (z = +1): about half the rays escape, never all.
    assert!(hits > 5_000 && hits < 20_000, "{hits}");
}

/// The flat SIMD structure of tiny scenes gives exactly the brute force's hits (same `t`,
/// barycentrics and — ties included, both keep the lowest index — triangle), on the Cornell box
/// from inside and on random soups with axis-aligned rays and finite `tmax`.
#[test]
fn tiny_accel_matches_brute_force() {
    let mut cases = vec![(cornell_box(), 0.99f32)];
    for (n, seed) in [(5usize, 1u64), (32, 2), (64, 3), (100, 4)] {
        cases.push((random_soup(n, 0.6, seed), 1.5));
    }
    for (k, (mut tris, span)) in cases.into_iter().enumerate() {
        tris.push([Vec3::ZERO, Vec3::X, Vec3::X * 2.0]); // degenerate: never hit
        let tiny = TinyAccel::new(tris.clone());
        let bf = BruteForce::new(tris.clone());
        assert_eq!(tiny.len(), tris.len());
        let mut hits = 0;
        for i in 0..20_000u64 {
            let mut rng = Rng::new(13, k as u64, i);
            let o = (Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - 1.0) * span;
            let mut d = random_dir(&mut rng);
            if i % 10 == 0 {
                let a = (i / 10 % 3) as usize;
                d = Vec3::ZERO;
                d[a] = if i % 20 == 0 { 1.0 } else { -1.0 };
            }
            let tmax = if i % 3 == 0 { rng.next_f32() * 2.0 } else { f32::INFINITY };
            let ray = Ray { o, d, tmax };
            let want = bf.intersect(&ray);
            assert_eq!(tiny.intersect(&ray), want, "case {k} ray {ray:?}");
            assert_eq!(tiny.intersect_portable(&ray), want, "case {k} ray {ray:?}");
            assert_eq!(tiny.occluded(&ray), bf.occluded(&ray), "case {k} ray {ray:?}");
            hits += want.is_some() as u32;
        }
        assert!(hits > 200, "case {k}: {hits} hits (the rays must probe the triangles)");
    }
}

/// Points exactly on shared edges and vertices of a closed mesh, as seen from inside.
fn edge_and_vertex_targets(mesh: &TriangleMesh) -> Vec<Vec3> {
    let mut targets = mesh.positions.clone();
    for t in &mesh.indices {
        for k in 0..3 {
            let a = mesh.positions[t[k] as usize];
            let b = mesh.positions[t[(k + 1) % 3] as usize];
            // Points on the edge (up to rounding of the lerp: still within a float of it, which is
            // exactly where a non-watertight test leaks).
            for s in [0.5f32, 0.25, 1.0 / 3.0] {
                targets.push(a + (b - a) * s);
            }
        }
    }
    targets
}

/// Rays from inside a closed mesh aimed at its vertices and edges must all hit something.
/// Counts leaks for the watertight test (BVH and brute force; must be 0) and, for information,
/// for Möller–Trumbore.
fn leak_count(mesh: &TriangleMesh, origins: &[Vec3]) -> (usize, usize, usize, usize, usize) {
    let tris = mesh_triangles(mesh);
    let tiny = TinyAccel::new(tris.clone());
    let mut leak_tiny = 0;
    let bvh = Bvh::new(tris.clone());
    let bf = BruteForce::new(tris.clone());
    let targets = edge_and_vertex_targets(mesh);
    let (mut n, mut leak_bvh, mut leak_bf, mut leak_mt) = (0, 0, 0, 0);
    for &o in origins {
        for &p in &targets {
            let ray = Ray::new(o, p - o);
            n += 1;
            leak_bvh += bvh.intersect(&ray).is_none() as usize;
            leak_bvh += !bvh.occluded(&ray) as usize;
            leak_bf += bf.intersect(&ray).is_none() as usize;
            leak_tiny += tiny.intersect(&ray).is_none() as usize;
            leak_tiny += !tiny.occluded(&ray) as usize;
            leak_mt += !tris.iter().any(|t| intersect_triangle_mt(&ray, t, f32::INFINITY).is_some()) as usize;
        }
    }
    (n, leak_bvh, leak_bf, leak_mt, leak_tiny)
}

#[test]
fn watertight_on_closed_meshes() {
    let mut total_mt = 0;
    for (k, (disp, offset)) in [(0.0f32, Vec3::ZERO), (0.2, Vec3::ZERO), (0.2, Vec3::new(100.0, -37.0, 12.5))]
        .into_iter()
        .enumerate()
    {
        let mut mesh = sphere_mesh(12, 17, disp, 11);
        for p in &mut mesh.positions {
            *p += offset;
        }
        // The centre, points near the surface and some in between.
        let mut origins = vec![offset];
        for i in 0..6u64 {
            let mut rng = Rng::new(5, k as u64, i);
            origins.push(offset + random_in_ball(&mut rng, 0.75));
        }
        let (n, bvh, bf, mt, tiny) = leak_count(&mesh, &origins);
        assert!(n > 3000);
        assert_eq!((bvh, bf, tiny), (0, 0, 0), "watertight test leaked (of {n} rays), case {k}");
        total_mt += mt;
    }
    // The rays really probe edges and vertices: a non-watertight test leaks on them.
    println!("Möller–Trumbore leaks on the same rays: {total_mt}");
    assert!(total_mt > 0);
}

/// Closed Cornell-box-like cube: rays at the cube's edges and corners (including the shared
/// diagonal of each face) from inside.
#[test]
fn watertight_cube_edges() {
    let positions: Vec<Vec3> = (0..8)
        .map(|i| Vec3::new((i & 1) as f32, (i >> 1 & 1) as f32, (i >> 2 & 1) as f32) * 2.0 - 1.0)
        .collect();
    let quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
    let indices = quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
    let mesh = TriangleMesh { positions, indices, ..Default::default() };
    let mut origins = vec![Vec3::ZERO, Vec3::new(0.3, -0.7, 0.1)];
    for i in 0..8u64 {
        origins.push(random_in_ball(&mut Rng::new(9, 0, i), 0.9));
    }
    let (_, bvh, bf, _, tiny) = leak_count(&mesh, &origins);
    assert_eq!((bvh, bf, tiny), (0, 0, 0));
}

/// Surface points of triangle `i` from barycentrics, and geometric normal.
fn surface_point(tris: &[[Vec3; 3]], i: usize, rng: &mut Rng) -> (Vec3, Vec3) {
    let [a, b, c] = tris[i];
    let (mut u, mut v) = (rng.next_f32(), rng.next_f32());
    if u + v > 1.0 {
        (u, v) = (1.0 - u, 1.0 - v);
    }
    (a * (1.0 - u - v) + b * u + c * v, (b - a).cross(c - a))
}

/// Secondary rays leaving a surface with the offset origin never hit the triangle they start
/// on, whatever the direction (both sides, grazing included), for points from barycentrics and
/// for points computed as `o + t d` from a primary ray, near the origin and far from it.
#[test]
fn offset_rays_do_not_self_intersect() {
    for (k, offset) in
        [Vec3::ZERO, Vec3::new(60.0, -20.0, 5.0), Vec3::new(-1000.0, 300.0, 700.0)].into_iter().enumerate()
    {
        let mut mesh = sphere_mesh(60, 90, 0.05, 3);
        for p in &mut mesh.positions {
            *p += offset;
        }
        let tris = mesh_triangles(&mesh);
        let bvh = Bvh::new(tris.clone());
        let mut self_hits = 0;
        let mut n = 0;
        for i in 0..40_000u64 {
            let mut rng = Rng::new(21, k as u64, i);
            let (p, ng, prim) = if i % 2 == 0 {
                let prim = (rng.next_u32() as usize) % tris.len();
                let (p, ng) = surface_point(&tris, prim, &mut rng);
                (p, ng, prim as u32)
            } else {
                // Primary ray from up to 10 units away (outside or inside).
                let o = offset
                    + if i % 4 == 1 { random_dir(&mut rng) * 10.0 } else { random_in_ball(&mut rng, 0.5) };
                let ray = Ray::new(o, random_dir(&mut rng));
                let Some(h) = bvh.intersect(&ray) else { continue };
                let [a, b, c] = tris[h.prim as usize];
                (ray.at(h.t), (b - a).cross(c - a), h.prim)
            };
            let mut w = random_dir(&mut rng);
            if i % 5 == 0 {
                // Grazing: nearly in the tangent plane.
                let n = ng.normalize();
                w = (w - n * n.dot(w)).normalize() + n * (1e-4 * (rng.next_f32() - 0.5));
            }
            let ray = Ray::new(offset_ray_origin(p, ng, w), w);
            n += 1;
            if let Some(h) = bvh.intersect(&ray) {
                self_hits += (h.prim == prim) as u32;
            }
        }
        assert!(n > 30_000);
        assert_eq!(self_hits, 0, "self-intersections, offset {offset}");
    }
}

/// Inside a convex polyhedron every two surface points see each other: shadow rays from
/// `spawn_ray_to` are never occluded (neither end surface is hit), also between adjacent
/// triangles at nearly grazing angles.
#[test]
fn spawn_ray_to_inside_convex_mesh_is_unoccluded() {
    let mesh = sphere_mesh(40, 64, 0.0, 0);
    let tris = mesh_triangles(&mesh);
    let bvh = Bvh::new(tris.clone());
    let mut occluded = 0;
    let mut tested = 0;
    for i in 0..40_000u64 {
        let mut rng = Rng::new(4, 0, i);
        let i0 = (rng.next_u32() as usize) % tris.len();
        // Half of the pairs are neighbours in the index order (mostly adjacent triangles).
        let i1 = if i % 2 == 0 { (rng.next_u32() as usize) % tris.len() } else { (i0 + 1) % tris.len() };
        if i0 == i1 {
            continue;
        }
        let (p0, n0) = surface_point(&tris, i0, &mut rng);
        let (p1, n1) = surface_point(&tris, i1, &mut rng);
        // When the segment runs (numerically) inside a surface — the two halves of a quad are
        // coplanar, or both points lie within rounding of a shared edge — which side it is on is
        // undefined and its cosine factors are ~0 anyway. Skip pairs with |cos| < 1e-3 at either
        // end (a grazing angle under 0.06°), and only those.
        let w = (p1 - p0).normalize();
        if n0.normalize().dot(w).abs() < 1e-3 || n1.normalize().dot(w).abs() < 1e-3 {
            continue;
        }
        tested += 1;
        let ray = spawn_ray_to(p0, n0, p1, n1);
        if bvh.occluded(&ray) {
            occluded += 1;
        }
    }
    assert!(tested > 25_000, "{tested}");
    assert_eq!(occluded, 0);
}

/// Shadow rays through a blocker are occluded (the shortening does not hide real occluders).
#[test]
fn spawn_ray_to_sees_blockers() {
    let tris = cornell_box();
    let bvh = Bvh::new(tris.clone());
    // A floor point covered by the tall box: the light above is hidden by the box's top (y = 0.2).
    let p0 = Vec3::new(-0.3, -1.0, -0.3);
    let p1 = Vec3::new(-0.1, 0.99, -0.1);
    let r = spawn_ray_to(p0, Vec3::Y, p1, -Vec3::Y);
    assert!(bvh.occluded(&r));
    // Floor to light along a free path is not occluded.
    let q0 = Vec3::new(0.0, -1.0, 0.9);
    let r = spawn_ray_to(q0, Vec3::Y, Vec3::new(0.0, 0.99, 0.1), -Vec3::Y);
    assert!(!bvh.occluded(&r));
}

/// The Cornell box with a dense displaced sphere (3 540 triangles) where the tall box stands,
/// followed by the box's triangles: the room's walls are set apart ([`Accel::Split`]).
fn room_with_object() -> Vec<[Vec3; 3]> {
    let ball = mesh_triangles(&sphere_mesh(31, 60, 0.05, 9));
    let mut tris: Vec<[Vec3; 3]> = ball
        .iter()
        .map(|t| t.map(|p| p * Vec3::new(0.3, 0.6, 0.3) + Vec3::new(-0.33, -0.38, -0.29)))
        .collect();
    tris.extend(cornell_box());
    tris
}

/// `Accel::Split` (walls in the packet kernel, the object behind the BVH) gives brute force's
/// hits — the same `t` and barycentrics bits, the same triangle except on exact ties — for
/// rays from inside the room and from the object's surface (offset as the integrators do), and
/// its packet calls return the single-ray answers lane by lane, bit for bit.
#[test]
fn split_accel_matches_brute_force_in_a_room_with_an_object() {
    let tris = room_with_object();
    let accel = Accel::new(tris.clone());
    let Accel::Split(split) = &accel else { panic!("the room's walls are set apart") };
    assert!(split.big_count() >= 10 && split.big_count() <= 32, "{}", split.big_count());
    assert_eq!(accel.len(), tris.len());
    let bf = BruteForce::new(tris.clone());
    let (mut hits, mut object_hits, mut packets) = (0, 0, 0);
    let n_ball = tris.len() - cornell_box().len();
    let mut rays = Vec::new();
    for i in 0..8_000u64 {
        let mut rng = Rng::new(17, 3, i);
        let ray = if i % 2 == 0 {
            let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 1.98 - 0.99;
            Ray::new(o, random_dir(&mut rng))
        } else {
            // leaving a point of the object, on either side
            let (p, n) = surface_point(&tris, (rng.next_u32() as usize) % n_ball, &mut rng);
            let d = random_dir(&mut rng);
            Ray::new(offset_ray_origin(p, n, d), d)
        };
        let ray = if i % 5 == 0 { Ray { tmax: 0.5, ..ray } } else { ray };
        let got = accel.intersect(&ray);
        let want = bf.intersect(&ray);
        match (got, want) {
            (None, None) => {}
            (Some(a), Some(b)) => {
                assert_eq!(a.t.to_bits(), b.t.to_bits(), "{a:?} {b:?} {ray:?}");
                if a.prim == b.prim {
                    assert_eq!((a.b1.to_bits(), a.b2.to_bits()), (b.b1.to_bits(), b.b2.to_bits()));
                } else {
                    let tie = opal::accel::intersect_triangle(&ray, &tris[a.prim as usize], f32::INFINITY);
                    assert_eq!(tie.map(|h| h.0), Some(b.t), "prim differs without a tie: {a:?} {b:?}");
                }
                hits += 1;
                object_hits += ((a.prim as usize) < n_ball) as usize;
            }
            _ => panic!("hit/miss differs: {got:?} {want:?} {ray:?}"),
        }
        assert_eq!(accel.occluded(&ray), bf.occluded(&ray), "{ray:?}");
        rays.push(ray);
    }
    for chunk in rays.chunks(8) {
        let p = RayPacket::from_rays(chunk);
        // lanes past the chunk stay inactive (tmax 0)
        let h = accel.intersect8(&p);
        let occ = accel.occluded8(&p);
        for (l, r) in chunk.iter().enumerate() {
            let single = accel.intersect(r);
            assert_eq!(
                h.hit(l).map(|x| (x.prim, x.t.to_bits(), x.b1.to_bits(), x.b2.to_bits())),
                single.map(|x| (x.prim, x.t.to_bits(), x.b1.to_bits(), x.b2.to_bits())),
                "lane {l} {r:?}"
            );
            assert_eq!(occ >> l & 1 == 1, accel.occluded(r), "lane {l} {r:?}");
        }
        packets += 1;
    }
    assert!(
        hits > 5_000 && object_hits > 2_000,
        "{hits} hits, {object_hits} on the object (the rays must probe both parts)"
    );
    assert_eq!(packets, 1_000);
    // several packets at once (the BVH's rays gathered across them): the same bits per lane,
    // with inactive lanes mixed in
    let packets: Vec<RayPacket> = rays.chunks(7).map(RayPacket::from_rays).collect();
    for group in packets.chunks(5) {
        let mut many = vec![opal::accel::packet::PacketHits::NONE; group.len()];
        let mut blocked = vec![0u32; group.len()];
        accel.intersect8_many(group, &mut many);
        accel.occluded8_many(group, &mut blocked);
        for (j, p) in group.iter().enumerate() {
            let one = accel.intersect8(p);
            let key = |h: &opal::accel::packet::PacketHits, l: usize| {
                h.hit(l).map(|x| (x.prim, x.t.to_bits(), x.b1.to_bits(), x.b2.to_bits()))
            };
            for l in 0..8 {
                assert_eq!(key(&many[j], l), key(&one, l), "packet {j} lane {l}");
            }
            assert_eq!(blocked[j], accel.occluded8(p), "packet {j}");
        }
    }
}

/// Without large triangles (a sphere alone, a random soup) nothing is set apart: a plain BVH.
#[test]
fn split_accel_only_where_large_triangles_stand_apart() {
    let ball = mesh_triangles(&sphere_mesh(31, 60, 0.05, 9));
    assert!(SplitAccel::choose(&ball).is_empty());
    assert!(matches!(Accel::new(ball), Accel::Bvh(_)));
    let soup = random_soup(5_000, 0.05, 4);
    assert!(SplitAccel::choose(&soup).is_empty());
    let room = room_with_object();
    let big = SplitAccel::choose(&room);
    let n_ball = room.len() - cornell_box().len();
    // the walls, floor and ceiling (10 triangles) are among the chosen; no object triangle is
    assert!(big.iter().all(|&i| i as usize >= n_ball), "{big:?}");
    assert!(big.len() >= 10, "{big:?}");
}
