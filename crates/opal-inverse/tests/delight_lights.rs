//! De-lighting on independent Mitsuba 3 data with several kinds of light (split from
//! `tests/delight.rs`):
//!
//! * `lights_small_constant_albedos_within_1_percent`: tests/data/lights_small (two coloured
//!   area lights and a point light, 5 small views): constant albedos within 1 %;
//!   `lights_small_power_sampled_lights_within_1_percent` the same with the area lights split
//!   into 64 triangles (the power-sampled light choice); `lights_small_coarse_atlas_sphere`;
//!   `power_sampled_direct_irradiance_unbiased`.
//! * `env_small_constant_albedos_within_1_percent`: the same bar on data lit by an `envmap`
//!   only (tests/data/env_small); `env_small_8m_paths_within_1_percent` (ignored) the same at
//!   8 M light paths per pass.

#[allow(dead_code)] // the view-gain helpers serve delight.rs and delight_room.rs
mod common;

#[path = "support/delight_truth.rs"]
#[allow(dead_code)] // (each test binary uses some of the helpers)
mod truth;

use opal::scene::Scene;
use opal::scene::desc::SceneDesc;
use opal_inverse::delight::views::{View, read_views};
use opal_inverse::delight::{DelightResult, DelightSettings, LightPaths, delight};
use std::path::{Path, PathBuf};
use truth::{load, report, truth_albedos};

/// The settings of these runs: `res`² maps, `paths` light paths per pass, 8 passes (no stop
/// rule).
fn fixed_passes(res: usize, paths: u64) -> DelightSettings {
    DelightSettings {
        resolution: Some(res),
        light_paths: LightPaths::Fixed(paths),
        iterations: 8,
        tolerance: 0.0,
        ..Default::default()
    }
}

/// De-lights `views` of `desc` with `s` (progress printed) and prints the report: the result,
/// the worst constant-albedo error and the wall seconds.
fn run(desc: &SceneDesc, views: &[View], s: &DelightSettings) -> (DelightResult, f64, f64) {
    let t0 = std::time::Instant::now();
    let r = delight(desc, views, s, &|l| println!("{l}")).unwrap();
    let worst = report(&r, desc);
    (r, worst, t0.elapsed().as_secs_f64())
}

fn lights_small() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/lights_small")
}

/// Independent data with several kinds of light: a closed room rendered by Mitsuba 3
/// (`bench/scripts/delight_lights_small.py`, committed in tests/data/lights_small, 0.7 MB): two
/// area lights of different colours (4 emitting triangles) and a point light of a third colour,
/// 8 objects of constant albedo (walls, floor, ceiling, a box, a faceted sphere), 5 views of
/// 80×60 / 64×64 pixels at 4096 spp (median per-pixel relative standard error 1.9 %). The
/// direct irradiance runs its per-light branch with a point light among the triangle lights.
/// Acceptance bar: every constant albedo within 1 % per channel.
#[test]
fn lights_small_constant_albedos_within_1_percent() {
    let dir = lights_small();
    let desc = load(&dir.join("scene.xml"));
    assert_eq!(desc.shapes.iter().filter(|s| s.emitter.is_some()).count(), 2);
    let (views, warn) = read_views(&dir.join("transforms.json")).unwrap();
    assert!(warn.is_empty(), "{warn:?}");
    // 128² maps: coarser maps carry the error of a coarse atlas, not noise (1.9 % per pixel
    // over hundreds of pixels per object: ≲ 0.1 % on an object's mean): at 32² (2 M paths, 8
    // passes) the ceiling reads +2.0 %, the sphere ≤ +1.0 % (`lights_small_coarse_atlas_sphere`;
    // with the planar unwrap of the time it read +20 to +35 %), at 64² every object is within
    // 1.4 %. 8 passes: the fixed point settles after 6–7 (re-rendering error 38 % after 5
    // passes, 1.5 % after 8).
    let s = fixed_passes(128, 2_000_000);
    let (_, worst, secs) = run(&desc, &views, &s);
    println!("worst constant-albedo error {:.2} % ({:.1} s)", 100.0 * worst, secs);
    assert_eq!(truth_albedos(&desc).len(), 8);
    assert!(worst < 0.01, "acceptance: constant albedos within 1 %: worst {worst}");
}

/// Independent data lit by an environment map only: an open courtyard rendered by Mitsuba 3
/// (`bench/scripts/delight_env_small.py`, committed in tests/data/env_small, 0.3 MB): floor, two
/// walls, a box and a faceted sphere of constant albedos under a procedural 32 × 16 `envmap`
/// with a small bright sun, 4 views of 64 × 48 pixels at 2048 spp (median per-pixel relative
/// standard error 1.2 %; the views also see the sky). The light tracer emits from the disk over
/// the scene's bounding sphere, the direct irradiance combines the map's importance sampling
/// with cosine-weighted directions (MIS). Acceptance
/// bar: every constant albedo within 1 % per channel.
///
/// History (issue 27): with the map's importance sampling alone (64 samples per texel) this read
/// worst 1.01 % at 2 M paths (1.61 % at 8 M): the per-texel `Ed` was noisy (relative RMS 28 %
/// on the back wall, 31 % on the box; the luminance-driven sampling puts most samples on the
/// sun, few on the blue sky), which biases the ratio `πL/(Ed + Ei)` upwards (blue: back wall
/// +0.88 %, floor +0.37 %, while the ratio of the area sums read −0.5 / 0.0 %), and the adaptive
/// pilot kept 0 wherever its 16 samples were all hidden (sphere `Ed` −2.5 % on average). Now
/// the map's samples are combined with cosine-weighted ones by MIS (RMS 6 % / 14 %) and the
/// full count always decides for environment lights. At 92465b6 this read worst 0.65 % (the
/// sphere's green) and with 8 M paths the sphere +1.23 / +1.25 / +0.82 %, a bias. Measured at
/// 8b4cb24: worst 0.31 % (the box's blue), sphere −0.08 / −0.04 / −0.06 % (39 % of its texels
/// seen after the super-resolution); 8 M paths: [`env_small_8m_paths_within_1_percent`].
#[test]
fn env_small_constant_albedos_within_1_percent() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/env_small");
    let desc = load(&dir.join("scene.xml"));
    assert_eq!(desc.emitters.len(), 1);
    let (views, warn) = read_views(&dir.join("transforms.json")).unwrap();
    assert!(warn.is_empty(), "{warn:?}");
    let s = fixed_passes(128, 2_000_000);
    let (_, worst, secs) = run(&desc, &views, &s);
    println!("worst constant-albedo error {:.2} % ({:.1} s)", 100.0 * worst, secs);
    assert_eq!(truth_albedos(&desc).len(), 5);
    assert!(worst < 0.01, "acceptance: constant albedos within 1 %: worst {worst}");
}

/// Splits every triangle of `m` into four at its edge midpoints (normals and UVs interpolated).
fn subdivide(m: &mut opal::geometry::TriangleMesh) {
    let mut idx = Vec::with_capacity(4 * m.indices.len());
    for [a, b, c] in std::mem::take(&mut m.indices) {
        let mut mid = |i: u32, j: u32| {
            let (i, j) = (i as usize, j as usize);
            m.positions.push((m.positions[i] + m.positions[j]) * 0.5);
            if !m.normals.is_empty() {
                m.normals.push((m.normals[i] + m.normals[j]).normalize());
            }
            if !m.uvs.is_empty() {
                m.uvs.push((m.uvs[i] + m.uvs[j]) * 0.5);
            }
            (m.positions.len() - 1) as u32
        };
        let (ab, bc, ca) = (mid(a, b), mid(b, c), mid(c, a));
        idx.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
    }
    m.indices = idx;
}

/// [`lights_small_constant_albedos_within_1_percent`] with each area light split into 32
/// triangles (two subdivisions): 64 emitting triangles and the point light are more than
/// `MAX_LIGHTS_PER_TEXEL`, so the direct irradiance chooses lights by power instead of sampling
/// each one (the radiance field, hence the views, is unchanged). Same bar: 1 %. 256 direct
/// samples per texel: with the default 64 the power-sampled estimate's noise biases the ratio
/// L / E upwards where a light is sampled rarely (blue, the small cool panel: floor +0.92 %,
/// front wall +0.82 %, right wall +0.56 %; with 256: +0.41 / +0.34 / +0.06 %; the per-light
/// branch at 64 samples: ≤ +0.3 %) — a bias of the ratio, not of `Ed`, which is unbiased
/// (`power_sampled_direct_irradiance_unbiased`, where the per-texel σ² of `Ed` predicts the
/// +0.9 %). Measured worst 0.51 % (the box's blue).
#[test]
fn lights_small_power_sampled_lights_within_1_percent() {
    let dir = lights_small();
    let mut desc = load(&dir.join("scene.xml"));
    for s in desc.shapes.iter_mut().filter(|s| s.emitter.is_some()) {
        subdivide(&mut s.mesh);
        subdivide(&mut s.mesh);
    }
    let n_lights = Scene::build(&desc).unwrap().lights.len();
    // more than the direct estimator's MAX_LIGHTS_PER_TEXEL (16, a private constant)
    assert!(n_lights > 16, "{n_lights} lights");
    let (views, _) = read_views(&dir.join("transforms.json")).unwrap();
    let s = DelightSettings { direct_samples: 256, ..fixed_passes(128, 2_000_000) };
    let (_, worst, secs) = run(&desc, &views, &s);
    println!("{n_lights} lights: worst constant-albedo error {:.2} % ({:.1} s)", 100.0 * worst, secs);
    assert!(worst < 0.01, "constant albedos within 1 %: worst {worst}");
}

/// [`lights_small_constant_albedos_within_1_percent`] at 32² maps: the faceted sphere (552
/// triangles) gets charts a few texels wide, a third of its observed texels only partly covered
/// by its UV triangles (chart borders). Regression test of a finding of issue 22: with the
/// planar unwrap of the time (34 charts of 1–2 texels, no texel fully covered) the sphere read
/// +20 to +35 % at 32²; the curved unwrap with chart-owned gutters (15 charts here) measures
/// −0.8 to +1.0 % (back-projection / super-resolution), its fully and partly covered texels
/// alike (+0.9 % / +1.1 % in green against a 20 M-path trace of the true scene on the same
/// atlas). Bound 2 %: twice that coarse-atlas error (the 1.9 % per-pixel view noise averages to
/// ≲ 0.1 % over the sphere's ~150 observed texels); the old defect exceeds it tenfold. The
/// other objects are printed, not asserted (at 32² the ceiling reads up to +2.4 %).
#[test]
fn lights_small_coarse_atlas_sphere() {
    let dir = lights_small();
    let desc = load(&dir.join("scene.xml"));
    let (views, _) = read_views(&dir.join("transforms.json")).unwrap();
    let s = fixed_passes(32, 2_000_000);
    let (r, _, _) = run(&desc, &views, &s);
    let o = r.objects.iter().find(|o| o.id == "sphere").unwrap();
    let (t, m) =
        (truth_albedos(&desc).into_iter().find(|(id, _)| id == "sphere").unwrap().1, o.mean_kd_observed());
    let partly = (0..o.kd.len()).filter(|&i| o.observed[i] && o.atlas.coverage[i] < 1.0).count();
    let seen = o.observed.iter().filter(|&&b| b).count();
    println!(
        "sphere: {} charts, {seen} observed texels ({partly} partly covered), kd {m:?} truth {t:?}",
        o.atlas.charts
    );
    assert!(partly > 0 && o.atlas.charts > 1);
    for c in 0..3 {
        let e = m[c] / t[c] as f64 - 1.0;
        assert!(e.abs() < 0.02, "sphere at 32² maps, channel {c}: relative albedo error {e}");
    }
}

/// The power-sampled direct irradiance (more than `MAX_LIGHTS_PER_TEXEL` lights: the area
/// lights of `lights_small` split into 64 triangles, plus the point light) is unbiased: on every
/// object's 64² atlas the mean over the covered texels at 64 samples per texel equals the mean
/// at 1024 samples (independent seeds), per channel within 4σ, σ from the spread of the
/// per-texel differences (texels draw independent numbers). This is why the +0.92 % in blue of
/// `lights_small_power_sampled_lights_within_1_percent` at 64 samples is not a bias of `Ed`:
/// measured at 128² against 4096 samples, `Ed` agrees (|z| ≤ 1.9 over 8 objects × 3 channels)
/// while `Kd = π L / (Ed + Ei)` is biased up by the ratio (Jensen): E[1/E] ≈ (1 + σ²/E²)/E.
/// The per-texel σ² of 64-sample `Ed` (two seeds) predicts +0.96 % (floor, blue) and +0.93 %
/// (right wall, blue) where the ratio E₄₀₉₆/E₆₄ − 1 measures +0.90 % / +1.03 %; at 256 samples
/// the predicted term is 4× smaller. Measured here: worst |z| 1.66 (front wall), σ of the mean
/// 0.2–0.6 %, so an error of 2 % in any light's share would fail.
#[test]
fn power_sampled_direct_irradiance_unbiased() {
    let dir = lights_small();
    let mut desc = load(&dir.join("scene.xml"));
    for s in desc.shapes.iter_mut().filter(|s| s.emitter.is_some()) {
        subdivide(&mut s.mesh);
        subdivide(&mut s.mesh);
    }
    let scene = Scene::build(&desc).unwrap();
    assert!(scene.lights.len() > opal_inverse::delight::MAX_LIGHTS_PER_TEXEL);
    let mut worst = 0f64;
    for sh in desc.shapes.iter().filter(|s| s.emitter.is_none()) {
        let a = opal_inverse::delight::atlas::build_atlas(&sh.mesh, 64, true).unwrap();
        let lo = opal_inverse::delight::direct_irradiance(&scene, &a, 64, 0, 11, 1);
        let hi = opal_inverse::delight::direct_irradiance(&scene, &a, 1024, 0, 12, 2);
        let texels: Vec<usize> =
            (0..lo.len()).filter(|&i| a.texel_tri[i] != opal_inverse::delight::atlas::NO_TRI).collect();
        let n = texels.len() as f64;
        let mut line = format!("{:12} {:5} texels:", sh.id, texels.len());
        for c in 0..3 {
            let d: Vec<f64> = texels.iter().map(|&i| (lo[i][c] - hi[i][c]) as f64).collect();
            let md = d.iter().sum::<f64>() / n;
            let sd = (d.iter().map(|x| (x - md).powi(2)).sum::<f64>() / (n - 1.0) / n).sqrt();
            let mean_hi = texels.iter().map(|&i| hi[i][c] as f64).sum::<f64>() / n;
            let z = if sd > 0.0 { md / sd } else { 0.0 };
            line += &format!(" {:+.3} % (z {z:+.2})", 100.0 * md / mean_hi);
            worst = worst.max(z.abs());
            assert!(z.abs() < 4.0, "{} channel {c}: Ed(64) − Ed(1024) = {md} ± {sd} (z {z})", sh.id);
        }
        println!("{line}");
    }
    println!("worst |z| {worst:.2}");
}

/// [`env_small_constant_albedos_within_1_percent`] at 8 M light paths per pass (ignored, 57–90 s
/// wall / ~30 CPU-s in release at load 9–13: `cargo test --release -p opal-inverse --test delight
/// -- --ignored --exact env_small_8m_paths_within_1_percent --nocapture`). Regression test of
/// the environment-lit bias that grew with the paths (at 92465b6 the sphere read +1.23 / +1.25
/// / +0.82 % at 8 M, 0.65 % at 2 M). Measured at 8b4cb24 (branch h27c): worst 0.17 % (back wall
/// blue), sphere −0.01 / −0.04 / −0.08 %; at 2 M worst 0.31 % (box blue), sphere ≤ 0.08 %: the
/// error falls with the paths. Reverting 3f75e38 (super-resolution gutter ties) or the covered
/// crease pixels of fff84fd alone left the sphere within 0.4 % at 8 M, so the commit that removed
/// the bias between 92465b6 and 8b4cb24 is not identified.
#[test]
#[ignore]
fn env_small_8m_paths_within_1_percent() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/env_small");
    let desc = load(&dir.join("scene.xml"));
    let (views, warn) = read_views(&dir.join("transforms.json")).unwrap();
    assert!(warn.is_empty(), "{warn:?}");
    let s = fixed_passes(128, 8_000_000);
    let (_, worst, _) = run(&desc, &views, &s);
    assert_eq!(truth_albedos(&desc).len(), 5);
    assert!(worst < 0.01, "constant albedos within 1 % at 8 M paths: worst {worst}");
}
