//! Criterion benchmark of the goniophotometer (issue 4): the reference plate (n = 1.49, 0.5° beam
//! divergence, 179 + 179 detectors of 1°, single scattering with Mitsuba's G1), smooth and rough
//! entry, rough face GGX α = 0.15, 0.35 and Beckmann α = 0.25, one incidence per benchmark
//! (0°, 45° and 75°), 2¹⁶ photons; throughput in photons. `general_loop/*` times the general
//! photon loop on the same work (what the fast loop replaces).
//! Run: `cargo bench -p opal --bench gonio`. The side-by-side comparison with the Mitsuba
//! reference simulator is `bench/gonio_vs_mitsuba.sh`.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use opal::bsdf::microfacet::Ndfs;
use opal::gonio::{Beam, DetectorGrid, DetectorLayout, Face, Gonio, GonioSetup, Plate, Scattering};

const PHOTONS: u64 = 1 << 16;

fn gonio(inc_deg: f64) -> Gonio {
    Gonio::new(GonioSetup {
        beam: Beam { azimuth: 0.0, divergence: 0.5f64.to_radians(), aperture_radius_mm: 0.0 },
        incidences: vec![inc_deg.to_radians()],
        detectors: DetectorLayout {
            grid: DetectorGrid::PlaneOfIncidence {
                angles: (-89..=89).map(|d| (d as f64).to_radians()).collect(),
            },
            radius: 1f64.to_radians(),
            distance_mm: None,
        },
        photons: PHOTONS,
        seed: 7,
        max_interactions: 200,
    })
    .expect("valid setup")
}

fn plate(ndf: Ndfs, rough_entry: bool) -> Plate {
    let rough = Face::Rough { ndf, scattering: Scattering::SingleMitsuba };
    let (front, back) = if rough_entry { (rough, Face::Polished) } else { (Face::Polished, rough) };
    Plate { ior: 1.49, thickness_mm: 2.0, absorption_per_mm: 0.0, front, back, radius_mm: None }
}

fn bench_gonio(c: &mut Criterion) {
    let mut g = c.benchmark_group("gonio");
    g.sample_size(10);
    g.throughput(Throughput::Elements(PHOTONS));
    for (name, ndf) in
        [("ggx0.15", Ndfs::ggx(0.15)), ("ggx0.35", Ndfs::ggx(0.35)), ("beckmann0.25", Ndfs::beckmann(0.25))]
    {
        for rough_entry in [false, true] {
            let p = plate(ndf.clone(), rough_entry);
            let entry = if rough_entry { "rough" } else { "smooth" };
            for inc in [0.0, 45.0, 75.0] {
                let gn = gonio(inc);
                g.bench_function(format!("{name}_{entry}_{inc}"), |b| b.iter(|| gn.run_plate(&p).unwrap()));
            }
        }
    }
    let p = plate(Ndfs::beckmann(0.25), false);
    let gn = gonio(45.0).with_general_loop(true);
    g.bench_function("general_loop/beckmann0.25_smooth_45", |b| b.iter(|| gn.run_plate(&p).unwrap()));
    g.finish();
}

criterion_group!(benches, bench_gonio);
criterion_main!(benches);
