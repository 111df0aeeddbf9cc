//! Mitsuba 3's emitters `constant`, `envmap`, `spot` and `directional` against Mitsuba 3:
//! small scenes rendered by Opal and by Mitsuba (`bench/scripts/mitsuba_emitters_scenes.py`
//! writes the scenes, the procedural HDR map and the reference EXRs with their per-pixel
//! standard errors) agree by the 16×16 block z-test of `tests/mitsuba_cbox.rs` (≥ 99 % of
//! (block, channel) pairs within 3σ).

use opal::scene::load_mitsuba_xml;

mod common;

/// Renders `tests/data/mitsuba_emitters/<name>/scene.xml` with Opal (`spp` samples, the
/// scene's integrator settings) and z-tests it against Mitsuba's reference; returns the
/// fraction of blocks within 3σ.
fn ztest(name: &str, spp: u32) -> f64 {
    use opal::integrator::path::{PathSettings, render};
    let dir =
        std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/mitsuba_emitters").join(name);
    let desc = load_mitsuba_xml(&dir.join("scene.xml"), &[]).unwrap();
    let scene = opal::scene::Scene::build(&desc).unwrap();
    let it = desc.integrator.clone().unwrap_or_default();
    let s =
        PathSettings { spp, max_depth: it.max_depth, rr_depth: it.rr_depth, hide_emitters: false, seed: 12 };
    let out = render(&scene, 0, &s, &|| {});
    assert_eq!(out.nonfinite, 0);
    let (frac, worst, mean_z) = common::block_z(&out, &dir.join("ref.exr"), &dir.join("ref_stderr.exr"));
    eprintln!("{name}: {:.2} % of blocks within 3σ, worst |z| {worst:.2}, mean z {mean_z:+.3}", frac * 100.0);
    if frac < 0.99 {
        let tmp = std::env::temp_dir();
        for (img, suffix) in [(&out.image, ""), (&out.stderr, "_stderr")] {
            let f =
                std::fs::File::create(tmp.join(format!("opal_mitsuba_emitters_{name}{suffix}.exr"))).unwrap();
            opal::image::write::write_exr(img, f).unwrap();
        }
    }
    frac
}

macro_rules! zt {
    ($test:ident, $name:literal, $spp:literal) => {
        #[test]
        fn $test() {
            let frac = ztest($name, $spp);
            assert!(frac >= 0.99, "{}: only {:.2} % of blocks within 3σ", $name, frac * 100.0);
        }
    };
}

zt!(constant_scene_matches_mitsuba, "constant", 256);
zt!(envmap_scene_matches_mitsuba, "envmap", 256);
zt!(spot_scene_matches_mitsuba, "spot", 256);
zt!(directional_scene_matches_mitsuba, "directional", 256);

/// The environment-lit scene renders to the same bits with 1 and 2 threads (the path tracer's
/// per-pixel generators; escaped rays add the environment in path order).
#[test]
fn envmap_scene_is_thread_count_independent() {
    use opal::integrator::path::{PathSettings, render};
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/mitsuba_emitters/envmap");
    let scene = opal::scene::Scene::build(&load_mitsuba_xml(&dir.join("scene.xml"), &[]).unwrap()).unwrap();
    let s = PathSettings { spp: 4, max_depth: 8, rr_depth: 5, hide_emitters: false, seed: 3 };
    let run = |threads| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| render(&scene, 0, &s, &|| {}))
    };
    let (a, b) = (run(1), run(2));
    assert!(
        a.image.data.iter().zip(&b.image.data).all(|(x, y)| x.0.map(f32::to_bits) == y.0.map(f32::to_bits))
    );
    assert!(a.image.mean()[2] > 0.0);
}
