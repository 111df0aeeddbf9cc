//! Criterion benchmarks of the acceleration structures: Opal's `Bvh` vs `obvhs` (CWBVH) on a
//! 1 M-triangle displaced sphere and on the Cornell box — build time, incoherent closest-hit
//! and any-hit rays (throughput in rays/s), on 2 threads.
//!
//! Run: `cargo bench -p opal --bench accel` (filter e.g. `-- cbox`). Results and discussion in
//! `docs/performance.md` ("Acceleration structure"). The quick side-by-side table comes from
//! `cargo run --release -p opal --example accel_compare`.

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use opal::accel::Bvh;
use opal::accel::scenes::cornell_box;
use opal::math::Vec3;
use std::time::Duration;

#[path = "../examples/accel_compare.rs"]
#[allow(dead_code)]
mod compare;
use compare::{Obvhs, big_mesh, incoherent_rays, trace, trace_any};

fn pool() -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap()
}

fn scene(c: &mut Criterion, label: &str, tris: Vec<[Vec3; 3]>, rays: Vec<opal::geometry::Ray>, build: bool) {
    let pool = pool();
    let mut g = c.benchmark_group(label);
    g.sample_size(10).warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(8));
    if build {
        g.bench_function("build/opal", |b| b.iter(|| pool.install(|| Bvh::new(tris.clone()))));
        g.bench_function("build/obvhs", |b| b.iter(|| pool.install(|| Obvhs::new(&tris))));
    }
    let (bvh, ob) = pool.install(|| (Bvh::new(tris.clone()), Obvhs::new(&tris)));
    g.throughput(Throughput::Elements(rays.len() as u64));
    g.bench_function(BenchmarkId::new("closest", "opal"), |b| {
        b.iter(|| pool.install(|| trace(&rays, |r| bvh.intersect(r))))
    });
    g.bench_function(BenchmarkId::new("closest", "obvhs"), |b| {
        b.iter(|| pool.install(|| trace(&rays, |r| ob.intersect(r))))
    });
    g.bench_function(BenchmarkId::new("any", "opal"), |b| {
        b.iter(|| pool.install(|| trace_any(&rays, |r| bvh.occluded(r))))
    });
    g.bench_function(BenchmarkId::new("any", "obvhs"), |b| {
        b.iter(|| pool.install(|| trace_any(&rays, |r| ob.occluded(r))))
    });
    g.finish();
}

fn sphere_1m(c: &mut Criterion) {
    scene(c, "sphere1m", big_mesh(), incoherent_rays(1 << 19, Vec3::ZERO, 0.8, 1), true);
}

fn cbox(c: &mut Criterion) {
    scene(c, "cbox", cornell_box(), incoherent_rays(1 << 20, Vec3::ZERO, 0.95, 2), false);
}

criterion_group!(benches, sphere_1m, cbox);
criterion_main!(benches);
