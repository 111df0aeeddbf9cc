//! Closed-form scenes for the path tracer: inside a closed Lambertian room of albedo ρ whose
//! walls all emit radiance Le, the radiance is Le·Σ_{k<D} ρ^k for max depth D (Mitsuba's
//! meaning) and Le/(1−ρ) unbounded. Also: identical images for any thread count.

use opal::geometry::TriangleMesh;
use opal::integrator::path::{PathSettings, render};
use opal::math::{Mat4, Vec3};
use opal::scene::Scene;
use opal::scene::desc::*;
use opal::spectrum::Spectrum;

/// Cube [-1,1]³ with faces wound so that their normals point inwards.
fn inward_cube() -> TriangleMesh {
    let mut m = TriangleMesh::default();
    // each face: centre c, normal n (inwards = -c), two tangents
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            let mut c = Vec3::ZERO;
            c[axis] = sign;
            let n = -c;
            let mut t = Vec3::ZERO;
            t[(axis + 1) % 3] = 1.0;
            let b = n.cross(t);
            let base = m.positions.len() as u32;
            for (a, bb) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                m.positions.push(c + t * a + b * bb);
            }
            m.indices.push([base, base + 1, base + 2]);
            m.indices.push([base, base + 2, base + 3]);
        }
    }
    m
}

fn furnace_scene(rho: f32, le: f32) -> SceneDesc {
    let cam_to_world = Mat4::from_translation(Vec3::new(0.1, -0.2, 0.3)) * Mat4::from_rotation_y(0.7);
    SceneDesc {
        shapes: vec![ShapeDesc {
            id: "room".into(),
            mesh: inward_cube(),
            bsdf: BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(Spectrum::splat(rho)) },
            emitter: Some(AreaEmitterDesc { radiance: Spectrum::splat(le) }),
            origin: None,
        }],
        emitters: vec![],
        sensors: vec![SensorDesc {
            id: "cam".into(),
            to_world: cam_to_world,
            fov_x_deg: 90.0,
            width: 24,
            height: 16,
            near_clip: 1e-3,
            far_clip: 100.0,
            spp: None,
        }],
        ..Default::default()
    }
}

/// Mean over the image and its standard error (pixels are independent).
fn mean_and_se(out: &opal::integrator::path::RenderOutput, c: usize) -> (f64, f64) {
    let n = out.image.data.len() as f64;
    let m = out.image.data.iter().map(|p| p[c] as f64).sum::<f64>() / n;
    let v = out.stderr.data.iter().map(|p| (p[c] as f64).powi(2)).sum::<f64>() / (n * n);
    (m, v.sqrt())
}

#[test]
fn furnace_unbounded_and_truncated() {
    let scene = Scene::build(&furnace_scene(0.5, 1.0)).unwrap();
    for (max_depth, expected) in [(-1, 2.0), (1, 1.0), (2, 1.5), (3, 1.75)] {
        let s = PathSettings { spp: 256, max_depth, rr_depth: 5, hide_emitters: false, seed: 3 };
        let out = render(&scene, 0, &s, &|| {});
        assert_eq!(out.nonfinite, 0);
        let (m, se) = mean_and_se(&out, 0);
        // z-test at 4σ (one of four tests); with truncation before RR the estimate is exact
        // up to MIS noise, so se can be ~0: allow 1e-4 relative for float rounding.
        assert!(
            (m - expected).abs() <= 4.0 * se + 1e-4 * expected,
            "depth {max_depth}: {m} ± {se}, expected {expected}"
        );
    }
}

#[test]
fn furnace_high_albedo_with_russian_roulette() {
    let scene = Scene::build(&furnace_scene(0.8, 0.5)).unwrap();
    let s = PathSettings { spp: 256, max_depth: -1, rr_depth: 2, hide_emitters: false, seed: 11 };
    let out = render(&scene, 0, &s, &|| {});
    let (m, se) = mean_and_se(&out, 1);
    let expected = 0.5 / (1.0 - 0.8);
    assert!((m - expected).abs() <= 4.0 * se, "{m} ± {se}, expected {expected}");
    // the estimate is not trivially exact: RR makes it noisy
    assert!(se > 0.0);
}

/// The furnace sphere: a closed unit sphere (tessellated like Mitsuba's `sphere` shape in the
/// loader) with inward-facing, emitting, Lambertian walls; camera at the centre.
#[test]
fn furnace_sphere() {
    let mut mesh = opal::scene::load::sphere_mesh(
        opal::scene::load::SPHERE_SEGMENTS_PHI,
        opal::scene::load::SPHERE_SEGMENTS_THETA,
    );
    for t in &mut mesh.indices {
        t.swap(1, 2); // face inwards
    }
    for n in &mut mesh.normals {
        *n = -*n;
    }
    let mut desc = furnace_scene(0.7, 0.3);
    desc.shapes[0].mesh = mesh;
    desc.sensors[0].to_world = Mat4::from_rotation_x(0.4);
    let scene = Scene::build(&desc).unwrap();
    let s = PathSettings { spp: 128, max_depth: -1, rr_depth: 3, hide_emitters: false, seed: 2 };
    let out = render(&scene, 0, &s, &|| {});
    assert_eq!(out.nonfinite, 0);
    let expected = 0.3 / (1.0 - 0.7);
    for c in 0..3 {
        let (m, se) = mean_and_se(&out, c);
        assert!((m - expected).abs() <= 4.0 * se, "channel {c}: {m} ± {se}, expected {expected}");
    }
}

#[test]
fn same_image_for_any_thread_count() {
    let scene = Scene::build(&furnace_scene(0.6, 1.0)).unwrap();
    let s = PathSettings { spp: 8, max_depth: -1, rr_depth: 2, hide_emitters: false, seed: 5 };
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| render(&scene, 0, &s, &|| {}));
    let two = rayon::ThreadPoolBuilder::new()
        .num_threads(3)
        .build()
        .unwrap()
        .install(|| render(&scene, 0, &s, &|| {}));
    assert_eq!(one.image, two.image);
}

/// A lossless glass object in the closed furnace (a faceted sphere of smooth dielectric,
/// η = 1.5, outward normals, and a glass cube seen through it) changes nothing: every pixel sees
/// the furnace radiance Le/(1−ρ). Checks delta reflection/refraction, the 1/η² radiance
/// scaling and its undoing on exit, total internal reflection inside, and Russian roulette
/// with the η² correction.
#[test]
fn furnace_with_glass_sphere() {
    let sphere = glass_test_sphere();
    // a small glass cube behind the sphere (outward normals: reverse the inward cube)
    let mut cube = inward_cube();
    for t in &mut cube.indices {
        t.swap(1, 2);
    }
    for p in &mut cube.positions {
        *p = *p * 0.2 + Vec3::new(0.3, 0.1, 0.75);
    }
    let glass =
        BsdfDesc::Lobe(opal::bsdf::Bxdfs::SmoothDielectric(opal::bsdf::SmoothDielectric::new(1.5).unwrap()));
    let mut desc = furnace_scene(0.5, 1.0);
    for (id, mesh) in [("glass_sphere", sphere), ("glass_cube", cube)] {
        desc.shapes.push(ShapeDesc { id: id.into(), mesh, bsdf: glass.clone(), emitter: None, origin: None });
    }
    look_at_sphere(&mut desc);
    let scene = Scene::build(&desc).unwrap();
    let s = PathSettings { spp: 256, max_depth: -1, rr_depth: 3, hide_emitters: false, seed: 21 };
    let out = render(&scene, 0, &s, &|| {});
    assert_eq!(out.nonfinite, 0);
    let expected = 1.0 / (1.0 - 0.5);
    let (m, se) = mean_and_se(&out, 0);
    assert!((m - expected).abs() <= 4.0 * se, "{m} ± {se}, expected {expected}");
    // per pixel too (a few pixels may deviate at 4σ by chance: allow 1 %)
    let bad = (0..out.image.data.len())
        .filter(|&k| {
            (out.image.data[k][0] as f64 - expected).abs() > 4.0 * out.stderr.data[k][0] as f64 + 1e-3
        })
        .count();
    assert!(bad * 100 <= out.image.data.len(), "{bad} pixels off");
}

/// Lossless objects of Mitsuba's metal and sheet plugins in the closed furnace change nothing:
/// a perfect mirror sphere (`conductor`, `material="none"`: F = 1) and a thin glass sheet cube
/// (`thindielectric`, η = 1.5: reflection R' and straight transmission 1 − R') seen through
/// and reflected in it. Every pixel sees Le/(1−ρ).
#[test]
fn furnace_with_mirror_and_thin_sheet() {
    use opal::bsdf::conductor::ConductorFresnel;
    use opal::bsdf::{Bxdfs, SmoothConductor, ThinDielectric};
    let mut cube = inward_cube();
    for t in &mut cube.indices {
        t.swap(1, 2);
    }
    for p in &mut cube.positions {
        *p = *p * 0.2 + Vec3::new(0.3, 0.1, -0.5);
    }
    let mirror =
        BsdfDesc::Lobe(Bxdfs::SmoothConductor(SmoothConductor::new(ConductorFresnel::Mirror, Spectrum::ONE)));
    let sheet = BsdfDesc::Lobe(Bxdfs::ThinDielectric(
        ThinDielectric::new(1.5, Spectrum::ONE, Spectrum::ONE).unwrap(),
    ));
    let mut desc = furnace_scene(0.5, 1.0);
    desc.shapes.push(ShapeDesc {
        id: "mirror".into(),
        mesh: glass_test_sphere(),
        bsdf: mirror,
        emitter: None,
        origin: None,
    });
    desc.shapes.push(ShapeDesc { id: "sheet".into(), mesh: cube, bsdf: sheet, emitter: None, origin: None });
    look_at_sphere(&mut desc);
    let scene = Scene::build(&desc).unwrap();
    let s = PathSettings { spp: 128, max_depth: -1, rr_depth: 3, hide_emitters: false, seed: 23 };
    let out = render(&scene, 0, &s, &|| {});
    assert_eq!(out.nonfinite, 0);
    let expected = 1.0 / (1.0 - 0.5);
    let (m, se) = mean_and_se(&out, 0);
    eprintln!("mirror + sheet furnace: {m:.5} ± {se:.5} (expected {expected})");
    assert!((m - expected).abs() <= 4.0 * se, "{m} ± {se}, expected {expected}");
    let bad = (0..out.image.data.len())
        .filter(|&k| {
            (out.image.data[k][0] as f64 - expected).abs() > 4.0 * out.stderr.data[k][0] as f64 + 1e-3
        })
        .count();
    assert!(bad * 100 <= out.image.data.len(), "{bad} pixels off");
}

/// Faceted sphere (radius 0.5, centre (0, 0, 0.3), outward normals, shading normal =
/// geometric normal) placed in the furnace by the glass tests.
fn glass_test_sphere() -> opal::geometry::TriangleMesh {
    let mut sphere = opal::scene::load::sphere_mesh(24, 12);
    sphere.normals.clear();
    for p in &mut sphere.positions {
        *p = *p * 0.5 + Vec3::new(0.0, 0.0, 0.3);
    }
    sphere
}

/// The furnace camera on −z looking at [`glass_test_sphere`] (+z), 60° field of view.
fn look_at_sphere(desc: &mut opal::scene::desc::SceneDesc) {
    desc.sensors[0].to_world = Mat4::from_translation(Vec3::new(0.0, 0.0, -0.9));
    desc.sensors[0].fov_x_deg = 60.0;
}

/// The closed furnace (ρ = 0.5, Le = 1) with a faceted sphere of *rough* glass (GGX α = 0.5,
/// η = 1.5) using the multiple-scattering interface ([`opal::bsdf::RoughDielectricMs`]): a
/// lossless interface that keeps energy leaves the furnace radiance unchanged, through the path
/// tracer's BSDF sampling, stochastic eval in next-event estimation and MIS with the approximate
/// pdf. Measured: 2.00091 ± 0.00212 at 1024 spp (z = +0.43); the single-scattering
/// `RoughDielectric` in its place gives 1.278 ± 0.002 (the energy it loses), so the test has
/// power. The only bias is the walk's truncation at [`opal::bsdf::rough_dielectric_ms::MAX_BOUNCES`]
/// (a lost walk is energy lost): it can only lower the radiance, by at most ε·N·L where ε is the
/// lost fraction per interaction and N the expected number of sphere interactions per camera
/// path. ε is measured here (0 lost walks of 360 000 at this α and η: ε < 8.3·10⁻⁶, the 95 %
/// Poisson bound); N is not measured, N = 20 is taken as a generous bound (2 wall bounces on
/// average at ρ = 0.5, so ~3 straight segments, each meeting the sphere at most once and then
/// reflecting inside it a few times): the allowance 20·ε·L ≤ 3.3·10⁻⁴ is 0.16σ, and applies
/// only below the expected value (even N = 200 would stay under 2σ). (It replaces a flat 0.5 % from the
/// module's loose R + T ≥ 0.995 check, 5σ of this test.)
#[test]
fn furnace_with_rough_glass_sphere_multiple_scattering() {
    let sphere = glass_test_sphere();
    let ms = opal::bsdf::RoughDielectricMs::new(opal::bsdf::microfacet::Ndfs::ggx(0.5), 1.5).unwrap();
    let mut desc = furnace_scene(0.5, 1.0);
    desc.shapes.push(ShapeDesc {
        id: "rough_glass".into(),
        mesh: sphere,
        bsdf: BsdfDesc::Lobe(opal::bsdf::Bxdfs::RoughDielectricMs(ms.clone())),
        emitter: None,
        origin: None,
    });
    look_at_sphere(&mut desc);
    let scene = Scene::build(&desc).unwrap();
    let s = PathSettings { spp: 1024, max_depth: -1, rr_depth: 3, hide_emitters: false, seed: 23 };
    let out = render(&scene, 0, &s, &|| {});
    assert_eq!(out.nonfinite, 0);
    let expected = 1.0 / (1.0 - 0.5);
    // lost fraction of the walk at this α and η, 9 incidences × both sides
    let (mut lost, mut walks) = (0u64, 0u64);
    for k in 0..9 {
        for side in [1.0f32, -1.0] {
            let t = (k as f32 + 0.5) * 10f32.to_radians();
            let wo = Vec3::new(t.sin(), 0.0, side * t.cos());
            let mut rng = opal::sampling::Rng::new(5, k, side.to_bits() as u64);
            for _ in 0..20_000 {
                walks += 1;
                lost += u64::from(ms.sample_dir(wo, &mut rng).is_none());
            }
        }
    }
    // 95 % upper bound of a Poisson rate from `lost` events (3.0 for none, else ≈ lost + 2√lost + 2)
    let eps = (lost as f64 + 2.0 * (lost as f64).sqrt() + 3.0) / walks as f64;
    let allowance = eps * 20.0 * expected;
    let (m, se) = mean_and_se(&out, 0);
    println!(
        "rough glass furnace: mean {m:.5} ± {se:.5} (expected {expected}, z {:+.2}); lost walks {lost}/{walks}, \
         truncation allowance {allowance:.2e}",
        (m - expected) / se
    );
    assert!(m - expected <= 4.0 * se, "{m} ± {se}, expected {expected}");
    assert!(expected - m <= 4.0 * se + allowance, "{m} ± {se}, expected {expected} (allowance {allowance})");
}
