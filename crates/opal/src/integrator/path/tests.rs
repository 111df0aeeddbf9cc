//! The row wavefront and the wide diffuse vertex against the scalar path tracer, bit for bit.

use super::wavefront;
use super::wide::Kernel;
use super::*;
use crate::scene::load::load_mitsuba_xml;
use std::path::Path;

fn bits(r: &Row) -> Vec<u32> {
    r.mean.iter().chain(&r.err).flat_map(|p| p.0.map(f32::to_bits)).collect()
}

/// Every wavefront plan available on this CPU for `scene`.
fn plans(scene: &Scene) -> Vec<RowPlan> {
    let mut v = vec![RowPlan::Wavefront];
    let kernels = if Kernel::detect() == Kernel::Avx2 {
        vec![Kernel::Portable, Kernel::Avx2]
    } else {
        vec![Kernel::Portable]
    };
    for k in kernels {
        let k = wavefront::wide_kernel(scene, k).expect("an all-diffuse scene lit by triangles");
        v.push(RowPlan::Wide(k));
    }
    v
}

/// Renders rows `ys` with the scalar loop and every wavefront plan and compares the bits.
fn rows_agree(scene: &Scene, ys: &[usize], cases: &[(u32, i32, i32)]) {
    let w = scene.cameras[0].width;
    let tables = wide_tables::Tables::new(scene);
    for &(spp, max_depth, rr_depth) in cases {
        let s = PathSettings { spp, max_depth, rr_depth, hide_emitters: false, seed: 7 };
        let mut lit = false;
        for &y in ys {
            let mut a = Row::new(w);
            render_row_scalar(scene, 0, y, &s, &mut a);
            lit |= a.mean.iter().any(|p| !p.is_black());
            for sh in plans(scene) {
                let mut b = Row::new(w);
                sh.render(scene, Some(&tables), 0, y, &s, &mut b);
                assert_eq!(bits(&a), bits(&b), "row {y}, spp {spp}, max depth {max_depth}, {sh:?}");
                assert_eq!(a.bad, b.bad);
            }
        }
        assert!(lit, "some tested row is lit (spp {spp}, max depth {max_depth})");
    }
}

/// The wavefront rows (eight pixels in packet lanes, batched shadow rays, the scalar or the wide
/// vertex in its portable and AVX2 compilations) give the scalar row's pixels bit for bit on the Cornell box,
/// with and without a depth limit and Russian roulette, for a spp that does not divide the
/// lanes evenly.
#[test]
fn wavefront_rows_equal_scalar_rows_bit_for_bit() {
    let xml = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/cbox/scene.xml");
    let scene = Scene::build(&load_mitsuba_xml(&xml, &[]).unwrap()).unwrap();
    assert!(matches!(scene.accel(), Accel::Tiny { .. }), "the Cornell box is a tiny scene");
    let w = scene.cameras[0].width;
    rows_agree(&scene, &[0, w / 3, w / 2 + 1], &[(3, 8, 5), (5, -1, 2), (2, 2, 5)]);
}

/// The same on a scene behind the BVH whose surfaces exercise the rest of the wide vertex:
/// the Cornell box with the tall box replaced by a tessellated sphere (vertex normals, uvs,
/// a two-sided bitmap-textured diffuse material seen from inside and outside through a hole
/// in no way: the camera sees its outside, light reaches it from any side) and the short box
/// made two-sided too.
#[test]
fn wide_rows_on_a_textured_mesh_equal_scalar_rows() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/cbox");
    let dir = tempfile::tempdir().unwrap();
    for sub in ["meshes", "textures"] {
        std::fs::create_dir_all(dir.path().join(sub)).unwrap();
        for e in std::fs::read_dir(src.join(sub)).unwrap() {
            let e = e.unwrap();
            std::fs::copy(e.path(), dir.path().join(sub).join(e.file_name())).unwrap();
        }
    }
    let xml = std::fs::read_to_string(src.join("scene.xml")).unwrap();
    let tall = xml.find("<shape type=\"obj\" id=\"tall_box\">").unwrap();
    let end = tall + xml[tall..].find("</shape>").unwrap() + "</shape>".len();
    let sphere = r#"<shape type="sphere" id="ball">
        <point name="center" x="-0.33" y="-0.45" z="-0.3"/>
        <float name="radius" value="0.45"/>
        <bsdf type="twosided"><bsdf type="diffuse">
            <texture type="bitmap" name="reflectance">
                <string name="filename" value="textures/backwall_albedo.exr"/>
                <string name="filter_type" value="bilinear"/>
                <boolean name="raw" value="true"/>
            </texture>
        </bsdf></bsdf>
    </shape>"#;
    let mut xml = format!("{}{}{}", &xml[..tall], sphere, &xml[end..]);
    let short = xml.find("<shape type=\"obj\" id=\"short_box\">").unwrap();
    let b = short + xml[short..].find("<bsdf type=\"diffuse\">").unwrap();
    let e = b + xml[b..].find("</bsdf>").unwrap() + "</bsdf>".len();
    xml = format!("{}<bsdf type=\"twosided\">{}</bsdf>{}", &xml[..b], &xml[b..e], &xml[e..]);
    std::fs::write(dir.path().join("scene.xml"), xml).unwrap();
    let scene = Scene::build(&load_mitsuba_xml(&dir.path().join("scene.xml"), &[]).unwrap()).unwrap();
    assert!(matches!(scene.accel(), Accel::Split(_)), "the walls apart, the sphere behind a BVH");
    let w = scene.cameras[0].width;
    rows_agree(&scene, &[w / 2, w / 2 + 9, 3 * w / 4], &[(3, 8, 5), (4, -1, 1)]);
    let scene = scene.with_plain_bvh();
    rows_agree(&scene, &[w / 2, w / 2 + 9], &[(3, 8, 5)]);
}

/// Scenes with a non-diffuse material do not take the wide vertex.
#[test]
fn wide_shading_only_on_diffuse_scenes() {
    let xml = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/cbox/scene.xml");
    let mut desc = load_mitsuba_xml(&xml, &[]).unwrap();
    assert!(wavefront::wide_kernel(&Scene::build(&desc).unwrap(), Kernel::Portable).is_some());
    let phong =
        crate::bsdf::Phong::new(20.0, crate::bsdf::Phong::normalised_factor(20.0), Spectrum::splat(0.5));
    desc.shapes[0].bsdf = crate::scene::desc::BsdfDesc::Lobe(crate::bsdf::Bxdfs::Phong(phong));
    assert!(wavefront::wide_kernel(&Scene::build(&desc).unwrap(), Kernel::Portable).is_none());
}

/// [`render_cancellable`] without a request gives [`render`]'s image bit for bit; with the flag
/// set it stops with `Interrupted` instead of returning a partial image.
#[test]
fn cancellable_render_matches_and_stops() {
    use std::sync::atomic::AtomicBool;
    let xml = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/cbox/scene.xml");
    let scene = Scene::build(&load_mitsuba_xml(&xml, &[]).unwrap()).unwrap();
    let s = PathSettings { spp: 2, max_depth: 6, rr_depth: 5, hide_emitters: false, seed: 3 };
    let a = render(&scene, 0, &s, &|| {});
    let flag = AtomicBool::new(false);
    let b = render_cancellable(&scene, 0, &s, &|| {}, Some(&flag)).unwrap();
    let px = |o: &RenderOutput| o.image.data.iter().flat_map(|p| p.0.map(f32::to_bits)).collect::<Vec<_>>();
    assert_eq!(px(&a), px(&b));
    assert!(a.image.data.iter().any(|p| !p.is_black()));
    flag.store(true, std::sync::atomic::Ordering::Relaxed);
    let c = render_cancellable(&scene, 0, &s, &|| {}, Some(&flag));
    assert!(matches!(c, Err(crate::error::Error::Interrupted { .. })));
}

/// The row wavefront (scalar vertex in packet lanes; the wide kernel does not take scenes with
/// non-triangle lights) gives the scalar rows' bits on the emitter scenes of
/// `tests/mitsuba_emitters.rs`: rays leaving the scene add the environment in both, infinite
/// lights' unbounded shadow rays go through the batched occlusion test.
#[test]
fn wavefront_rows_equal_scalar_rows_with_environment_and_delta_lights() {
    for name in ["envmap", "spot", "directional"] {
        let xml = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join(format!("tests/data/mitsuba_emitters/{name}/scene.xml"));
        let scene = Scene::build(&load_mitsuba_xml(&xml, &[]).unwrap()).unwrap();
        assert!(wavefront::wide_kernel(&scene, Kernel::Portable).is_none());
        let w = scene.cameras[0].width;
        for s in [
            PathSettings { spp: 3, max_depth: 8, rr_depth: 5, hide_emitters: false, seed: 7 },
            PathSettings { spp: 2, max_depth: -1, rr_depth: 2, hide_emitters: true, seed: 7 },
        ] {
            // the top rows of the open scenes are sky: hidden with `hide_emitters`, black for
            // the delta lights
            for y in [w / 2 + 1, 3 * w / 4] {
                let (mut a, mut b) = (Row::new(w), Row::new(w));
                render_row_scalar(&scene, 0, y, &s, &mut a);
                RowPlan::Wavefront.render(&scene, None, 0, y, &s, &mut b);
                assert!(a.mean.iter().any(|p| !p.is_black()), "{name} row {y} is lit");
                assert_eq!(bits(&a), bits(&b), "{name} row {y} {s:?}");
            }
        }
    }
}

/// Rows split over 2 and 3 simulated processes: every rank returns [`render`]'s image and
/// standard errors bit for bit.
#[test]
fn split_render_matches_for_any_process_count() {
    let xml = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/cbox/scene.xml");
    let scene = Scene::build(&load_mitsuba_xml(&xml, &[]).unwrap()).unwrap();
    let s = PathSettings { spp: 2, max_depth: 6, rr_depth: 5, hide_emitters: false, seed: 5 };
    let a = render(&scene, 0, &s, &|| {});
    let px = |o: &RenderOutput| {
        o.image.data.iter().chain(&o.stderr.data).flat_map(|p| p.0.map(f32::to_bits)).collect::<Vec<_>>()
    };
    for n in [2, 3] {
        let all = crate::dist::ThreadComm::run(n, |c| render_split(&scene, 0, &s, &|| {}, None, c).unwrap());
        for o in &all {
            assert_eq!(px(o), px(&a), "{n} ranks");
            assert_eq!((o.nonfinite, o.samples), (a.nonfinite, a.samples));
        }
    }
}
