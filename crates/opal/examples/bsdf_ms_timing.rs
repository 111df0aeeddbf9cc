//! Cost per call of `sample`, `eval` and `pdf` of the multiple-scattering rough dielectric
//! (`RoughDielectricMs`) against the single-scattering one (`RoughDielectric`), one thread.
//! `cargo run -p opal --example bsdf_ms_timing` (numbers in docs/performance.md).

use opal::bsdf::microfacet::Ndfs;
use opal::bsdf::rough_dielectric::{RoughDielectric, Shadowing};
use opal::bsdf::rough_dielectric_ms::RoughDielectricMs;
use opal::bsdf::{Bxdf, TransportMode};
use opal::sampling::{Rng, square_to_uniform_sphere};
use std::hint::black_box;
use std::time::Instant;

fn time(name: &str, n: u32, mut f: impl FnMut(&mut Rng) -> f32) -> f64 {
    let mut rng = Rng::new(1, 2, 3);
    let t = Instant::now();
    let mut acc = 0.0f32;
    for _ in 0..n {
        acc += f(&mut rng);
    }
    black_box(acc);
    let ns = t.elapsed().as_secs_f64() * 1e9 / n as f64;
    println!("{name:40} {ns:8.0} ns/call");
    ns
}

fn main() {
    let n = 200_000;
    for (label, ndf) in [("ggx 0.3", Ndfs::ggx(0.3)), ("beckmann 1.0", Ndfs::beckmann(1.0))] {
        let ss = RoughDielectric::new(ndf.clone(), 1.5, Shadowing::Separable).unwrap();
        let ms = RoughDielectricMs::new(ndf, 1.5).unwrap();
        // build the pdf tables outside the timing
        let t = Instant::now();
        black_box(ms.pdf(opal::math::Vec3::Z, -opal::math::Vec3::Z, TransportMode::Radiance));
        println!("{label}: ms pdf tables built in {:.0} ms", t.elapsed().as_secs_f64() * 1e3);
        let mode = TransportMode::Radiance;
        let s_ss = time(&format!("{label} ss sample"), n, |r| {
            let wo = square_to_uniform_sphere(r.next_2d());
            ss.sample(wo, r.next_f32(), r.next_2d(), mode).map_or(0.0, |s| s.pdf)
        });
        let s_ms = time(&format!("{label} ms sample"), n, |r| {
            let wo = square_to_uniform_sphere(r.next_2d());
            ms.sample(wo, r.next_f32(), r.next_2d(), mode).map_or(0.0, |s| s.pdf)
        });
        let e_ss = time(&format!("{label} ss eval"), n, |r| {
            let (wo, wi) = (square_to_uniform_sphere(r.next_2d()), square_to_uniform_sphere(r.next_2d()));
            ss.eval(wo, wi, mode)[0]
        });
        let e_ms = time(&format!("{label} ms eval (2+2 walks)"), n, |r| {
            let (wo, wi) = (square_to_uniform_sphere(r.next_2d()), square_to_uniform_sphere(r.next_2d()));
            ms.eval(wo, wi, mode)[0]
        });
        let p_ss = time(&format!("{label} ss pdf"), n, |r| {
            let (wo, wi) = (square_to_uniform_sphere(r.next_2d()), square_to_uniform_sphere(r.next_2d()));
            ss.pdf(wo, wi, mode)
        });
        let p_ms = time(&format!("{label} ms pdf"), n, |r| {
            let (wo, wi) = (square_to_uniform_sphere(r.next_2d()), square_to_uniform_sphere(r.next_2d()));
            ms.pdf(wo, wi, mode)
        });
        println!(
            "{label}: ratios ms/ss  sample {:.1}  eval {:.1}  pdf {:.1}",
            s_ms / s_ss,
            e_ms / e_ss,
            p_ms / p_ss
        );
    }
}
