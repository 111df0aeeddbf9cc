//! Tests of the atlas: kept UVs, the planar unwrap of boxes, the curved unwrap of displaced
//! spheres (no flips, no overlaps, utilisation, distortion, determinism), texel owners.

use super::*;
use opal::geometry::TriangleMesh;
use opal::scene::load::{cube_mesh, rectangle_mesh};

#[test]
fn rectangle_uvs_are_kept_and_cover_the_map() {
    let m = rectangle_mesh();
    assert!(uv_problem(&m).is_none());
    let a = build_atlas(&m, 64, true).unwrap();
    assert!(a.kept_uvs);
    assert_eq!(a.covered(), 64 * 64);
    // texel world area × texels = surface area (4)
    assert!((a.texel_area[0] * 64.0 * 64.0 - 4.0).abs() < 1e-4);
}

#[test]
fn cube_overlapping_uvs_rejected_and_unwrapped() {
    let m = cube_mesh();
    assert!(uv_problem(&m).unwrap().contains("overlapping"));
    let a = build_atlas(&m, 128, true).unwrap();
    assert!(!a.kept_uvs);
    assert_eq!(a.charts, 6);
    assert!(uv_problem(&a.mesh).is_none(), "{:?}", uv_problem(&a.mesh));
    // every covered texel's world area sums to the surface area (24), up to the texels cut
    // by chart borders (centres outside): within 10 %
    let sum: f64 = (0..a.width * a.height)
        .filter(|&i| a.texel_tri[i] != NO_TRI)
        .map(|i| a.texel_area[a.texel_tri[i] as usize] as f64)
        .sum();
    assert!((sum / 24.0 - 1.0).abs() < 0.1, "{sum}");
    // uniform density: all triangles have the same texel area
    let t0 = a.texel_area[0];
    assert!(a.texel_area.iter().all(|&t| (t / t0 - 1.0).abs() < 1e-3));
    // texel positions lie on the cube surface and normals point outwards
    for i in 0..a.width * a.height {
        if a.texel_tri[i] != NO_TRI {
            let p = a.texel_p[i];
            assert!((p.abs().max_element() - 1.0).abs() < 1e-4);
            assert!(a.texel_ng[i].dot(p) > 0.0);
        }
    }
}

#[test]
fn sphere_unwrap_bounded_cone() {
    let m = opal::scene::load::sphere_mesh(32, 16);
    let a = build_atlas(&m, 512, false).unwrap();
    assert!(a.charts >= 6 && a.charts < 100, "{}", a.charts);
    assert!(uv_problem(&a.mesh).is_none());
    let area: f64 = m.area();
    let sum: f64 = (0..a.width * a.height)
        .filter(|&i| a.texel_tri[i] != NO_TRI)
        .map(|i| a.texel_area[a.texel_tri[i] as usize] as f64)
        .sum();
    assert!((sum / area - 1.0).abs() < 0.1, "{sum} vs {area}");
}

/// Bilinear texels (the 2×2 texels whose centres surround `uv`, in texel units).
fn bilinear_texels(p: Vec2, w: usize, h: usize) -> [usize; 4] {
    let x0 = (p.x - 0.5).floor().clamp(0.0, (w - 1) as f32) as usize;
    let y0 = (p.y - 0.5).floor().clamp(0.0, (h - 1) as f32) as usize;
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    [y0 * w + x0, y0 * w + x1, y1 * w + x0, y1 * w + x1]
}

/// Checks shared by the curved-unwrap tests; returns (charts, utilisation, distortion).
fn check_curved(m: &TriangleMesh, res: usize) -> (usize, f64, quality::Distortion) {
    let a = build_atlas(m, res, false).unwrap();
    assert!(!a.kept_uvs);
    let d = quality::distortion(&a.mesh);
    assert_eq!(d.flipped, 0, "flipped triangles");
    // no two triangles cover the same texel centre at 4096² (shared edges excluded)
    let (twice, covered) = quality::overlaps(&a.mesh, 4096);
    assert_eq!(twice, 0, "{twice} of {covered} centres covered twice");
    // texel areas exact: Σ over triangles of texel area × UV area (texels) = surface area
    let mut sum = 0.0f64;
    for k in 0..a.mesh.triangle_count() {
        let uv = a.mesh.indices[k].map(|i| a.mesh.uvs[i as usize] * Vec2::new(res as f32, res as f32));
        let world = a.texel_area[k] as f64 * uv_area(uv[0], uv[1], uv[2]) as f64;
        sum += world;
        if a.mesh.triangle_area(k) > 0.0 {
            assert!((world / a.mesh.triangle_area(k) as f64 - 1.0).abs() < 1e-3);
        } else {
            assert_eq!(a.texel_area[k], 0.0);
        }
    }
    assert!((sum / m.area() - 1.0).abs() < 1e-4, "{sum} vs {}", m.area());
    // every bilinear look-up inside a triangle reads texels owned by that triangle's chart
    for k in 0..a.mesh.triangle_count() {
        let uv = a.mesh.indices[k].map(|i| a.mesh.uvs[i as usize] * Vec2::new(res as f32, res as f32));
        for b in [
            [1.0f32, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [1.0 / 3.0; 3],
            [0.5, 0.5, 0.0],
            [0.0, 0.5, 0.5],
        ] {
            let p = uv[0] * b[0] + uv[1] * b[1] + uv[2] * b[2];
            for i in bilinear_texels(p, res, res) {
                if a.texel_owner[i] != a.tri_chart[k] {
                    let (x, y) = (i % res, i / res);
                    for yy in y - 3..y + 4 {
                        eprintln!(
                            "row {yy}: {:?}",
                            (x - 3..x + 4).map(|xx| a.texel_owner[yy * res + xx] as i64).collect::<Vec<_>>()
                        );
                    }
                    for (kk, t) in a.mesh.indices.iter().enumerate() {
                        if a.tri_chart[kk] == 7 {
                            let q = t.map(|j| a.mesh.uvs[j as usize] * res as f32);
                            eprintln!("chart7 tri {kk} {q:?} area {}", a.mesh.triangle_area(kk));
                        }
                        let q = t.map(|j| a.mesh.uvs[j as usize] * res as f32);
                        let lo = q[0].min(q[1]).min(q[2]);
                        let hi = q[0].max(q[1]).max(q[2]);
                        if lo.x < x as f32 + 2.0
                            && hi.x > x as f32 - 1.0
                            && lo.y < y as f32 + 2.0
                            && hi.y > y as f32 - 1.0
                        {
                            eprintln!(
                                "near: tri {kk} chart {} uv {q:?} area {}",
                                a.tri_chart[kk],
                                a.mesh.triangle_area(kk)
                            );
                        }
                    }
                }
                assert_eq!(a.texel_owner[i], a.tri_chart[k], "triangle {k} at {p:?}");
            }
        }
    }
    (a.charts, a.utilisation(), d)
}

#[test]
fn displaced_sphere_unwrap_is_valid_dense_and_conformal() {
    let m = testmesh::displaced_icosphere(5, 0.07); // 20 480 triangles
    let (charts, util, d) = check_curved(&m, 1024);
    assert!(charts <= 40, "{charts} charts");
    assert!(util >= 0.70, "utilisation {util}");
    assert!(d.angle_mean < 1.02 && d.angle_p95 < 1.05, "{d:?}");
    assert!(d.area_mean < 1.15 && d.area_p95 < 1.3, "{d:?}");
}

/// The same atlas on 3 threads (the packing's densities tried in parallel batches) and on one
/// (tried in order, up to the first success of a batch).
#[test]
fn curved_unwrap_is_deterministic() {
    let m = testmesh::displaced_icosphere(4, 0.1);
    let on = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| build_atlas(&m, 512, false).unwrap())
    };
    let (a, b) = (on(3), on(1));
    assert_eq!(a.mesh.uvs, b.mesh.uvs);
    assert_eq!(a.tri_chart, b.tri_chart);
    assert_eq!(a.texel_owner, b.texel_owner);
    assert_eq!(a.texel_tri, b.texel_tri);
}

#[test]
fn lscm_flattens_a_cylinder_patch_isometrically() {
    // a 120° arc of a cylinder (developable): the conformal map is an isometry
    let (nu, nv) = (40usize, 20usize);
    let mut p = Vec::new();
    for j in 0..=nv {
        for i in 0..=nu {
            let a = (i as f64 / nu as f64) * 2.0 * std::f64::consts::PI / 3.0;
            p.push(opal::math::DVec3::new(a.cos(), a.sin(), j as f64 / nv as f64));
        }
    }
    let mut tris = Vec::new();
    for j in 0..nv {
        for i in 0..nu {
            let v = (j * (nu + 1) + i) as u32;
            let w = (nu + 1) as u32;
            tris.push([v, v + 1, v + w + 1]);
            tris.push([v, v + w + 1, v + w]);
        }
    }
    let (uv, it) = lscm::lscm(&p, &tris);
    assert!(it > 0);
    let f = lscm::Flat { tris: tris.clone(), uv };
    assert!(lscm::problem(&p, &f, 1.01).is_none());
    // edge lengths preserved (the map is isometric up to a global scale fixed by the area)
    for t in &tris {
        for e in 0..3 {
            let (a, b) = (t[e] as usize, t[(e + 1) % 3] as usize);
            let l3 = (p[a] - p[b]).length();
            let l2 = (f.uv[a] - f.uv[b]).length();
            assert!((l2 / l3 - 1.0).abs() < 2e-3, "{l2} vs {l3}");
        }
    }
}

#[test]
fn boxes_keep_the_planar_path() {
    // every chart of a cube is planar: the planar unwrap (6 charts, one density) is used
    let a = build_atlas(&cube_mesh(), 128, false).unwrap();
    assert_eq!(a.charts, 6);
    let t0 = a.texel_area[0];
    assert!(a.texel_area.iter().all(|&t| (t / t0 - 1.0).abs() < 1e-3));
}

#[test]
fn mixed_open_curved_and_planar_mesh_unwraps_validly() {
    // an open displaced hemisphere (boundary loop) plus a cube beside it, one mesh: the cube's
    // charts are planar (orthogonal projection), the hemisphere's conformal; plus a
    // degenerate triangle
    let s = testmesh::displaced_icosphere(4, 0.1);
    let mut m = TriangleMesh {
        positions: s.positions.clone(),
        indices: s
            .indices
            .iter()
            .copied()
            .filter(|t| t.iter().map(|&i| s.positions[i as usize].z).sum::<f32>() > 0.0)
            .collect(),
        ..Default::default()
    };
    let c = cube_mesh();
    let off = m.positions.len() as u32;
    m.positions.extend(c.positions.iter().map(|&p| p * 0.5 + Vec3::new(3.0, 0.0, 0.0)));
    m.indices.extend(c.indices.iter().map(|t| t.map(|i| i + off)));
    let d = m.positions.len() as u32;
    m.positions.extend([Vec3::new(5.0, 0.0, 0.0), Vec3::new(5.0, 1.0, 0.0), Vec3::new(5.0, 2.0, 0.0)]);
    m.indices.push([d, d + 1, d + 2]);
    let (charts, util, dist) = check_curved(&m, 512);
    println!("{charts} charts, utilisation {util:.3}, {dist:?}");
    assert!(charts >= 7);
}

#[test]
fn cornell_box_meshes_take_the_planar_path() {
    // the shared Cornell box: every object's unwrap is the planar one (atlases as before)
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../opal/tests/data/cbox/scene.xml");
    let desc = opal::scene::load::load_mitsuba_xml(&dir, &[]).unwrap();
    for s in &desc.shapes {
        let (tri_chart, chart_n) = planar::grow_charts(&s.mesh);
        assert!(planar::all_planar(&s.mesh, &tri_chart, &chart_n), "{}", s.id);
    }
}
