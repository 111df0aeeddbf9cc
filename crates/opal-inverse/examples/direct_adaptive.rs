//! Measures the adaptive direct irradiance of the de-lighting (`delight::direct_irradiance` with a
//! pilot) against the non-adaptive estimator with the same sample count, on the bundled Cornell
//! box at the de-lighting's adaptive texture resolutions (the back wall at its texture's 256²).
//!
//! `cargo run --release -p opal-inverse --example direct_adaptive -- [SAMPLES] [PILOT] [REF]`
//! (defaults 64, 16, 256). Per object: wall and CPU seconds of both, texels re-estimated, texels
//! where the full estimator saw a partly occluded light but the adaptive one kept its pilot
//! ("missed") and their largest difference, and the RMS error of both against
//! a reference with `REF` samples, over the texels where the full estimator saw a penumbra or the
//! two differ (elsewhere both give the closed-form value or 0, as the reference does); errors
//! relative to the object's mean direct irradiance.

use opal::scene::{Scene, load_mitsuba_xml};
use opal_inverse::delight::{StageClock, atlas, direct_irradiance, footprint, luminance};
use std::path::PathBuf;

fn main() {
    let args: Vec<u32> = std::env::args().skip(1).map(|a| a.parse().expect("number")).collect();
    let samples = args.first().copied().unwrap_or(64);
    let pilot = args.get(1).copied().unwrap_or(16);
    let refs = args.get(2).copied().unwrap_or(256);
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../opal/tests/data/cbox/scene.xml");
    let mut desc = load_mitsuba_xml(&p, &[]).expect("bundled scene loads");
    let scene0 = Scene::build(&desc).expect("scene builds");
    let mut atlases = Vec::new();
    for sh in &mut desc.shapes {
        if sh.emitter.is_some() {
            continue;
        }
        let a = if sh.id == "back_wall" {
            atlas::build_atlas(&sh.mesh, 256, true).expect("atlas")
        } else {
            let samples = footprint::surface_footprints(&scene0, &sh.mesh, &scene0.cameras);
            footprint::camera_atlas(&sh.mesh, &samples, true, footprint::MAX_RESOLUTION).expect("atlas").0
        };
        sh.mesh = a.mesh.clone();
        atlases.push((sh.id.clone(), a));
    }
    let scene = Scene::build(&desc).expect("scene builds");
    let (mut tf, mut ta) = ((0f64, 0f64), (0f64, 0f64));
    println!(
        "{:18} {:>8} {:>9} {:>9} {:>7} {:>7} {:>7} {:>9} {:>10} {:>10}",
        "object",
        "texels",
        "full s",
        "adapt s",
        "pen.redo%",
        "pen. %",
        "missed",
        "max diff",
        "rms full",
        "rms adapt"
    );
    for (j, (id, a)) in atlases.iter().enumerate() {
        let stream = 0xED00 + j as u64;
        let c = StageClock::start();
        let full = direct_irradiance(&scene, a, samples, 0, 0, stream);
        let t_full = c.elapsed();
        let c = StageClock::start();
        let adapt = direct_irradiance(&scene, a, samples, pilot, 0, stream);
        let t_adapt = c.elapsed();
        tf = (tf.0 + t_full.0, tf.1 + t_full.1);
        ta = (ta.0 + t_adapt.0, ta.1 + t_adapt.1);
        // texels in a penumbra of the full estimator: neither 0 nor the unoccluded value; with
        // one sample pass we cannot read the flag, so use the pilot-free estimator twice with
        // different seeds: exact texels agree bitwise
        let other = direct_irradiance(&scene, a, samples, 0, 1, stream);
        let pen: Vec<bool> = full.iter().zip(&other).map(|(x, y)| x != y).collect();
        let differ: Vec<bool> = full.iter().zip(&adapt).map(|(x, y)| x != y).collect();
        let missed: Vec<usize> = (0..full.len()).filter(|&i| differ[i]).collect();
        // errors relative to the object's mean direct irradiance (an error ΔEd changes the albedo
        // by ≈ ΔEd / (Ed + Ei): relative to the texel's own Ed it would blow up in umbrae)
        let covered = a.texel_tri.iter().filter(|&&t| t != atlas::NO_TRI).count();
        let mean = full
            .iter()
            .zip(&a.texel_tri)
            .filter(|(_, t)| **t != atlas::NO_TRI)
            .map(|(e, _)| luminance(*e) as f64)
            .sum::<f64>()
            / covered.max(1) as f64;
        let max_diff = missed
            .iter()
            .map(|&i| ((luminance(full[i]) - luminance(adapt[i])) as f64 / mean).abs())
            .fold(0f64, f64::max);
        let redo = full.iter().zip(&adapt).zip(&pen).filter(|((x, y), p)| x == y && **p).count();
        // reference on the texels that matter
        let sel: Vec<usize> = (0..full.len()).filter(|&i| pen[i] || differ[i]).collect();
        let reference =
            if sel.is_empty() { Vec::new() } else { direct_irradiance(&scene, a, refs, 0, 2, stream) };
        let rms = |m: &[[f32; 3]]| {
            let s: f64 = sel
                .iter()
                .map(|&i| ((luminance(m[i]) as f64 - luminance(reference[i]) as f64) / mean).powi(2))
                .sum();
            (s / sel.len().max(1) as f64).sqrt()
        };
        println!(
            "{id:18} {covered:>8} {:>4.1}/{:<4.1} {:>4.1}/{:<4.1} {:>6.1}% {:>6.1}% {:>7} {:>8.2}% {:>9.3}% {:>9.3}%",
            t_full.0,
            t_full.1,
            t_adapt.0,
            t_adapt.1,
            100.0 * redo as f64 / covered as f64,
            100.0 * pen.iter().filter(|&&b| b).count() as f64 / covered as f64,
            missed.len(),
            100.0 * max_diff,
            100.0 * rms(&full),
            100.0 * rms(&adapt)
        );
    }
    println!("total wall/CPU s: full {:.1}/{:.1}, adaptive {:.1}/{:.1}", tf.0, tf.1, ta.0, ta.1);
}
