//! One de-lighting light-tracing pass on the bundled Cornell box (or any Mitsuba scene given by
//! `SCENE`), timed (method C, issue "100 M light paths on the Cornell box ≤ 20 s on 2 cores";
//! the scanned-object room of `make_scan_room` for the "≥ 4 M paths/s on 2 cores" goal).
//!
//! The texture maps are the ones `opal delight` builds for the scene's views (resolution from
//! the pixel footprints of the scene's sensors, `delight::footprint`; every object, the back
//! wall too: for the bundled box's 8 views 733 k texels over 7 objects, 1.16 M with the earlier
//! rule from the bounding-box centre — timings and checksums before 2026-11-26 used those), the materials the scene's own. Prints paths, wall seconds, CPU seconds and paths/s.
//!
//! Run: `cargo run --release -p opal-inverse --example light_trace_pass -- [PATHS] [THREADS]`
//! (PATHS default 100 000 000). Environment: `SCENE` (path of a Mitsuba XML scene, default the
//! bundled `crates/opal/tests/data/cbox/scene.xml`; e.g. the scanned-object room written by
//! `cargo run --release -p opal --example make_scan_room -- /tmp/scan`, then
//! `SCENE=/tmp/scan/scene.xml`), `RES` (one map resolution for every object instead
//! of the adaptive ones), `BATCH` (paths per batch, default 2¹⁸ as `opal delight`), `DIRECT=0` (no first-hit
//! deposits, as in the de-lighting passes after the first).

use opal::integrator::light_tracer::{self, IrradianceTarget, LightTraceSettings};
use opal::scene::{Scene, load_mitsuba_xml};
use opal_inverse::delight::{StageClock, atlas, footprint};
use std::path::PathBuf;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let paths: u64 = args.get(1).map(|a| a.parse().expect("PATHS")).unwrap_or(100_000_000);
    let threads: usize = args.get(2).map(|a| a.parse().expect("THREADS")).unwrap_or(0);
    if threads > 0 {
        rayon::ThreadPoolBuilder::new().num_threads(threads).build_global().expect("pool");
    }
    let p = std::env::var_os("SCENE").map(PathBuf::from).unwrap_or_else(|| {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../opal/tests/data/cbox/scene.xml")
    });
    let mut desc = load_mitsuba_xml(&p, &[]).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    // the pixel footprints of the scene's own sensors on the original geometry
    let scene0 = Scene::build(&desc).expect("scene builds");
    let mut targets = Vec::new();
    let mut texels = 0;
    for sh in &mut desc.shapes {
        if sh.emitter.is_some() {
            targets.push(None);
            continue;
        }
        let a = match std::env::var("RES").ok().map(|r| r.parse().expect("RES")) {
            Some(res) => atlas::build_atlas(&sh.mesh, res, true).expect("atlas"),
            None => {
                let samples = footprint::surface_footprints(&scene0, &sh.mesh, &scene0.cameras);
                footprint::camera_atlas(&sh.mesh, &samples, true, footprint::MAX_RESOLUTION).expect("atlas").0
            }
        };
        texels += a.width * a.height;
        targets.push(Some(IrradianceTarget { width: a.width, height: a.height, texel_area: a.texel_area }));
        sh.mesh = a.mesh;
    }
    let scene = Scene::build(&desc).expect("scene builds");
    let batch: u64 = std::env::var("BATCH").ok().map(|b| b.parse().expect("BATCH")).unwrap_or(1 << 18);
    // DIRECT=0: no first-hit deposits (as the de-lighting passes after the first)
    let direct = std::env::var("DIRECT").map_or(true, |d| d != "0");
    let s = LightTraceSettings { paths, seed: 1, batch_size: batch, direct, ..Default::default() };
    let clock = StageClock::start();
    let out = light_tracer::trace(&scene, &targets, &s, &|| {});
    let (wall, cpu) = clock.elapsed();
    let total: f64 = out.maps.iter().flatten().map(|m| m.indirect.iter().map(|v| v[1]).sum::<f64>()).sum();
    println!(
        "paths {paths}  texels {texels}  threads {}  wall {wall:.2} s  cpu {cpu:.2} s  {:.3} M paths/s  \
         {:.3} M paths/cpu-s  (checksum {total:.6e}, nonfinite {})",
        rayon::current_num_threads(),
        paths as f64 / wall / 1e6,
        paths as f64 / cpu / 1e6,
        out.nonfinite
    );
}
