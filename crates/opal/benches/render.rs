//! Criterion benchmark: one Cornell-box render (the reference scene, view 0) with the path
//! tracer, 128×128 at 4 spp, max depth 8. Throughput is reported in camera samples.
//! Run: `cargo bench -p opal --bench render`. The side-by-side comparison with Mitsuba 3 is
//! `bench/render_vs_mitsuba.sh`.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use opal::integrator::path::{PathSettings, render};
use opal::scene::{Scene, load_mitsuba_xml};
use std::path::PathBuf;

fn cbox() -> Scene {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/cbox/scene.xml");
    let mut desc = load_mitsuba_xml(&p, &[]).expect("bundled scene loads");
    for s in &mut desc.sensors {
        s.width = 128;
        s.height = 128;
    }
    Scene::build(&desc).expect("bundled scene builds")
}

fn bench_render(c: &mut Criterion) {
    let scene = cbox();
    let s = PathSettings { spp: 4, max_depth: 8, rr_depth: 5, hide_emitters: false, seed: 1 };
    let mut g = c.benchmark_group("render");
    g.sample_size(10);
    g.throughput(Throughput::Elements(128 * 128 * 4));
    g.bench_function("cbox_128x128_4spp_depth8", |b| b.iter(|| render(&scene, 0, &s, &|| {})));
    g.finish();
}

criterion_group!(benches, bench_render);
criterion_main!(benches);
