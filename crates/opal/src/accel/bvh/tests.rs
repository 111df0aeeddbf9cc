//! Unit tests of the 8-wide BVH (more in `crates/opal/tests/accel.rs`).

use super::*;
use crate::accel::BruteForce;
use crate::sampling::Rng;

#[test]
fn node_layout() {
    assert_eq!(size_of::<Node8>(), 256);
    assert_eq!(align_of::<Node8>(), 64);
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
    assert!(b.occluded(&Ray::new(Vec3::new(0.1, 0.1, 0.0), Vec3::Z)));
    assert_eq!(b.bounds(), (Vec3::new(0.0, 0.0, 1.0), Vec3::new(1.0, 1.0, 1.0)));
}

#[test]
fn many_identical_and_degenerate() {
    // 100 copies of one triangle plus 100 points: centroids coincide, must not recurse forever,
    // and leaves still hold at most eight triangles.
    let tri = [Vec3::new(0.0, 0.0, 1.0), Vec3::new(1.0, 0.0, 1.0), Vec3::new(0.0, 1.0, 1.0)];
    let mut tris = vec![tri; 100];
    tris.extend(std::iter::repeat_n([Vec3::new(0.2, 0.2, 0.5); 3], 100));
    let b = Bvh::new(tris);
    assert_eq!(b.len(), 200);
    assert!(b.leaf_count() >= 200 / LANES);
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
    for b in [Bvh::new(tris.clone()), Bvh::new(tris.clone()).portable()] {
        let h = b.intersect(&Ray::new(Vec3::new(0.0, 0.0, 10.5), Vec3::Z)).unwrap();
        assert_eq!(h.prim, 11);
        let h = b.intersect(&Ray::new(Vec3::new(0.0, 0.0, 10.5), -Vec3::Z)).unwrap();
        assert_eq!(h.prim, 10);
    }
}

/// Every input triangle sits in exactly one leaf lane, every leaf has 1..=8 of them, and every
/// child box contains its subtree.
#[test]
fn every_triangle_in_one_leaf_and_boxes_contain_their_subtrees() {
    let tris = crate::accel::scenes::random_soup(5000, 0.05, 3);
    for sah in [SahParams::default(), SahParams { traversal: 1.0, block: 8 }] {
        let b = Bvh::with_params(&tris, sah);
        let mut seen = vec![0u32; tris.len()];
        for (g, lanes) in b.leaves.iter().map(|x| &x.prim[..]).enumerate() {
            let used: Vec<u32> = lanes.iter().copied().filter(|&p| p != u32::MAX).collect();
            assert!(!used.is_empty() && used.len() <= LANES);
            for (l, &p) in used.iter().enumerate() {
                seen[p as usize] += 1;
                assert_eq!(b.leaves[g].tris.triangle(l), tris[p as usize]);
            }
        }
        assert!(seen.iter().all(|&c| c == 1));
        fn check(b: &Bvh, node: usize, lo: Vec3, hi: Vec3, tris: &[[Vec3; 3]]) {
            let n = &b.nodes[node];
            for s in 0..WIDTH {
                let c = n.child[s];
                if c == EMPTY {
                    continue;
                }
                let clo = Vec3::new(n.b[0][0][s], n.b[0][1][s], n.b[0][2][s]);
                let chi = Vec3::new(n.b[1][0][s], n.b[1][1][s], n.b[1][2][s]);
                assert!(clo.cmpge(lo).all() && chi.cmple(hi).all());
                if c & LEAF != 0 {
                    let g = (c & !LEAF) as usize;
                    for l in 0..LANES {
                        let p = b.leaves[g].prim[l];
                        if p != u32::MAX {
                            for v in tris[p as usize] {
                                assert!(v.cmpge(clo).all() && v.cmple(chi).all());
                            }
                        }
                    }
                } else {
                    check(b, c as usize, clo, chi, tris);
                }
            }
        }
        check(&b, 0, b.bounds.0, b.bounds.1, &tris);
    }
}

/// The AVX2 and the portable traversals visit the same nodes and return the same hit, bit for
/// bit, and both agree with brute force (ties aside).
#[test]
fn avx2_and_portable_traversals_agree_bit_for_bit() {
    let bits = |h: Option<Hit>| h.map(|h| (h.prim, h.t.to_bits(), h.b1.to_bits(), h.b2.to_bits()));
    let mesh = crate::accel::scenes::sphere_mesh(40, 80, 0.02, 1);
    let mut tris = crate::accel::scenes::mesh_triangles(&mesh);
    tris.extend(crate::accel::scenes::random_soup(300, 0.3, 9));
    let fast = Bvh::new(tris.clone());
    let port = Bvh::new(tris.clone()).portable();
    let bf = BruteForce::new(tris.clone());
    for i in 0..20_000u64 {
        let mut rng = Rng::new(4, 1, i);
        let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 3.0 - 1.5;
        let mut d = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - 1.0;
        match i % 7 {
            1 => d.x = 0.0,
            2 => (d.y, d.z) = (-0.0, 0.0),
            _ => {}
        }
        let tmax = if i % 3 == 0 { rng.next_f32() * 2.0 } else { f32::INFINITY };
        let ray = Ray { o, d, tmax };
        let a = fast.intersect(&ray);
        assert_eq!(bits(a), bits(port.intersect(&ray)), "{ray:?}");
        assert_eq!(fast.occluded(&ray), port.occluded(&ray), "{ray:?}");
        let b = bf.intersect(&ray);
        assert_eq!(a.map(|h| h.t.to_bits()), b.map(|h| h.t.to_bits()), "{ray:?}");
        assert_eq!(fast.occluded(&ray), bf.occluded(&ray), "{ray:?}");
    }
}

#[test]
fn packets_answer_like_single_rays() {
    let tris = crate::accel::scenes::random_soup(500, 0.2, 2);
    let b = Bvh::new(tris);
    let mut rp = RayPacket::default();
    let mut rays = Vec::new();
    for l in 0..PACKET {
        let mut rng = Rng::new(7, 2, l as u64);
        let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 3.0 - 1.5;
        let d = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - 1.0;
        let r = Ray { o, d, tmax: if l == 3 { 0.0 } else { f32::INFINITY } };
        rp.set(l, &r);
        rays.push(r);
    }
    let h = b.intersect8(&rp);
    for (l, r) in rays.iter().enumerate() {
        let want = if l == 3 { None } else { b.intersect(r) };
        assert_eq!(h.hit(l), want);
    }
}

/// The interleaved eight-ray traversal returns, lane by lane, the single-ray hit bit for bit
/// (mesh + soup, finite and infinite `tmax`, axis-parallel directions, inactive lanes); the
/// any-hit streams (`occluded8`) answer `occluded` lane by lane.
#[test]
fn interleaved_packets_match_single_rays_bit_for_bit() {
    let bits = |h: Option<Hit>| h.map(|h| (h.prim, h.t.to_bits(), h.b1.to_bits(), h.b2.to_bits()));
    let mesh = crate::accel::scenes::sphere_mesh(60, 120, 0.02, 3);
    let mut tris = crate::accel::scenes::mesh_triangles(&mesh);
    tris.extend(crate::accel::scenes::random_soup(500, 0.3, 4));
    for b in [Bvh::new(tris.clone()), Bvh::new(tris).portable()] {
        for p in 0..2000u64 {
            let mut rp = RayPacket::default();
            let mut rays = [None; PACKET];
            for (l, slot) in rays.iter_mut().enumerate() {
                let mut rng = Rng::new(9, p, l as u64);
                let o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.4 - 1.2;
                let mut d = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - 1.0;
                if (p + l as u64).is_multiple_of(11) {
                    d.y = 0.0;
                }
                let tmax = match (p + l as u64) % 5 {
                    0 => rng.next_f32(),
                    1 if l % 3 == 0 => 0.0, // inactive lane
                    _ => f32::INFINITY,
                };
                let r = Ray { o, d, tmax };
                rp.set(l, &r);
                *slot = (tmax > 0.0).then_some(r);
            }
            let h = b.intersect8(&rp);
            let blocked = b.occluded8(&rp);
            for (l, r) in rays.iter().enumerate() {
                let want = r.and_then(|r| b.intersect(&r));
                assert_eq!(bits(h.hit(l)), bits(want), "packet {p} lane {l}");
                let occ = r.is_some_and(|r| b.occluded(&r));
                assert_eq!(blocked >> l & 1 == 1, occ, "any hit: packet {p} lane {l}");
                assert_eq!(occ, want.is_some(), "any hit iff a closest hit: packet {p} lane {l}");
            }
        }
    }
}

/// The AVX2 bounds test of a packet gives the portable mask bit for bit: rays from inside,
/// outside and on the bounds, zero and negative-zero direction components, NaN and inactive
/// lanes, finite and infinite `tmax`.
#[test]
fn enters8_avx2_equals_portable() {
    let tris = crate::accel::scenes::random_soup(200, 0.3, 5);
    let b = Bvh::new(tris);
    let (lo, hi) = b.bounds();
    let mut entered = 0u32;
    for i in 0..4000u64 {
        let mut rp = RayPacket::default();
        for l in 0..PACKET {
            let mut rng = Rng::new(11, i, l as u64);
            let mut o = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 4.0 - 2.0;
            let mut d = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 - 1.0;
            match (i as usize + l) % 9 {
                1 => d.x = 0.0,
                2 => (d.y, d.z) = (-0.0, 0.0),
                3 => o.x = lo.x,
                4 => o.z = hi.z,
                5 => d.y = f32::NAN,
                _ => {}
            }
            let tmax = match l % 4 {
                0 => f32::INFINITY,
                1 => rng.next_f32() * 3.0,
                2 => 0.0,
                _ => rng.next_f32(),
            };
            rp.set(l, &Ray { o, d, tmax });
        }
        let m = b.enters8(&rp);
        assert_eq!(m, b.enters8_portable(&rp), "packet {i}");
        entered += m.count_ones();
    }
    // both outcomes occur
    assert!(entered > 1000 && entered < 4000 * 8 - 1000, "{entered}");
}

/// `order_children` visits the nearest child first and stacks the others farthest deepest, in
/// the order of (entry distance, reference) — checked against a plain sort for every mask of
/// 1–8 children, with ties of the entry distance (the reference decides) and zeros.
#[test]
fn children_are_ordered_by_distance_then_reference() {
    let mut rng = Rng::new(4, 2, 0);
    for round in 0..400u32 {
        let tn: [f32; WIDTH] = std::array::from_fn(|_| {
            let x = rng.next_f32();
            // few distinct values: many ties
            if round % 2 == 0 { (x * 3.0).floor() } else { x * 10.0 }
        });
        let child: [u32; WIDTH] = std::array::from_fn(|l| {
            ((round * 13 + l as u32 * 7919) % 1000) | if l % 3 == 0 { LEAF } else { 0 }
        });
        for mask in 1u32..256 {
            let mut stack = [MaybeUninit::<Entry>::uninit(); STACK];
            let mut sp = 3; // entries below stay untouched
            let near = order_children(mask, &tn, &child, &mut stack, &mut sp);
            let mut want: Vec<(u32, u32)> =
                (0..WIDTH).filter(|&l| mask >> l & 1 != 0).map(|l| (tn[l].to_bits(), child[l])).collect();
            want.sort();
            assert_eq!(near, want[0].1, "mask {mask:#b}");
            assert_eq!(sp, 3 + want.len() - 1);
            // SAFETY: entries 3..sp were written by `order_children`.
            let got: Vec<(u32, u32)> = stack[3..sp]
                .iter()
                .rev()
                .map(|e| unsafe { e.assume_init() })
                .map(|e| (e.tnear.to_bits(), e.child))
                .collect();
            assert_eq!(got, want[1..].to_vec(), "mask {mask:#b}");
        }
    }
}
