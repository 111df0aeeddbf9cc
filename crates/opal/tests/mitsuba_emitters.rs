//! Mitsuba 3's emitters `constant`, `envmap`, `spot` and `directional` against Mitsuba 3:
//! small scenes rendered by Opal and by Mitsuba (`bench/scripts/mitsuba_emitters_scenes.py`
//! writes the scenes, the procedural HDR map and the reference EXRs with their per-pixel
//! standard errors) agree by the 16×16 block z-test of `tests/mitsuba_cbox.rs` (≥ 99 % of
//! (block, channel) pairs within 3σ).

use opal::scene::load_mitsuba_xml;

mod common;

/// [`common::ztest_scene`] on `tests/data/mitsuba_emitters/<name>`.
fn ztest(name: &str, spp: u32) -> f64 {
    common::ztest_scene("mitsuba_emitters", name, spp)
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
