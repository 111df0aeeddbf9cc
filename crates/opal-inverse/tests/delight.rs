//! De-lighting (method C) end to end.
//!
//! * `transforms_match_scene_sensors`: the NeRF-style `transforms.json` of the reference Cornell
//!   box (OpenGL axes) converts to the Mitsuba `to_world` of the scene's sensors.
//! * `round_trip_small_cbox`: views of the Cornell box rendered by Opal's own path tracer at the
//!   true albedos (64×64, 8 views) → de-lighting → albedos (per-object bounds from the 8-seed
//!   spread of the ignored `round_trip_small_cbox_seed_spread`) and back-wall texture (against
//!   its resolution limit + texel noise) vs the truth; `round_trip_small_cbox_with_view_gains`
//!   the same at 64×64 with known view gains; `round_trip_small_cbox_stops_when_converged`: the
//!   stop rule on the same fixture (goes on after a real change, stops before the limit within
//!   the same bounds).
//! * The runs on independent data with several kinds of light (lights_small, env_small):
//!   `tests/delight_lights.rs`.
//! * `round_trip_small_cbox_curved_object`: the same with the tall box replaced by a displaced
//!   icosphere without UVs (the curved unwrap end to end).
//! * `mitsuba_cbox_acceptance` (ignored; `OPAL_CBOX_DIR=<shared>/reference/mitsuba/cbox
//!   cargo test -p opal-inverse --test delight -- --ignored --nocapture`): the independent
//!   Mitsuba 3 data set, 8 views 256×256.

use opal::image::Image;
use opal::integrator::path::{PathSettings, render};
use opal::math::Vec2;
use opal::scene::Scene;
use opal::scene::desc::SceneDesc;
use opal_inverse::delight::superres;
use opal_inverse::delight::views::{View, read_views};
use opal_inverse::delight::{
    DelightResult, DelightSettings, LightPaths, ViewGainMode, ViewGainSettings, delight,
};
use std::path::PathBuf;

mod common;

#[path = "support/delight_truth.rs"]
#[allow(dead_code)] // (each test binary uses some of the helpers)
mod truth;

use truth::{data, kd_hash, load, report, truth_albedos};

#[test]
fn transforms_match_scene_sensors() {
    let desc = load(&data().join("scene.xml"));
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data().join("transforms.json")).unwrap()).unwrap();
    let frames = j["frames"].as_array().unwrap();
    assert_eq!(frames.len(), desc.sensors.len());
    for (f, s) in frames.iter().zip(&desc.sensors) {
        let m: Vec<Vec<f32>> = f["transform_matrix"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| r.as_array().unwrap().iter().map(|v| v.as_f64().unwrap() as f32).collect())
            .collect();
        let gl = opal::math::Mat4::from_cols_array_2d(&[
            [m[0][0], m[1][0], m[2][0], m[3][0]],
            [m[0][1], m[1][1], m[2][1], m[3][1]],
            [m[0][2], m[1][2], m[2][2], m[3][2]],
            [m[0][3], m[1][3], m[2][3], m[3][3]],
        ]);
        let mi = opal_inverse::delight::views::opengl_to_mitsuba(gl);
        let d = (mi - s.to_world).to_cols_array().iter().fold(0f32, |a, b| a.max(b.abs()));
        assert!(d < 1e-5, "sensor {}: max abs diff {d}", s.id);
        let fov = f["camera_angle_x"].as_f64().unwrap().to_degrees() as f32;
        assert!((fov - s.fov_x_deg).abs() < 1e-3, "{fov} vs {}", s.fov_x_deg);
    }
}

/// PSNR (peak 1) of the recovered back-wall texture against the truth, over the texels seen by
/// some view; the recovered texture is looked up at the truth's texel centres (same UVs).
fn backwall_psnr(r: &DelightResult, truth: &Image) -> (f64, usize) {
    let o = r.objects.iter().find(|o| o.id == "back_wall").unwrap();
    texture_psnr(r, &o.kd_image(), truth)
}

/// The truth box-filtered to the recovered back-wall map's resolution: the best that map can
/// hold (its PSNR against the truth is the resolution limit of [`backwall_psnr`]).
fn truth_at_map_resolution(r: &DelightResult, truth: &Image) -> Image {
    let o = r.objects.iter().find(|o| o.id == "back_wall").unwrap();
    let (w, h) = (o.atlas.width, o.atlas.height);
    let (fx, fy) = (truth.width / w, truth.height / h);
    assert_eq!((fx * w, fy * h), (truth.width, truth.height));
    let mut img = o.kd_image();
    for ty in 0..h {
        for tx in 0..w {
            let mut acc = [0f32; 3];
            for y in ty * fy..(ty + 1) * fy {
                for x in tx * fx..(tx + 1) * fx {
                    let t = truth.get(x, y);
                    for c in 0..3 {
                        acc[c] += t[c] / (fx * fy) as f32;
                    }
                }
            }
            img.data[ty * w + tx] = opal::spectrum::Spectrum(acc);
        }
    }
    img
}

/// PSNR of a back-wall map `kd` (at the recovered map's resolution) against the truth, over the
/// texels the recovered map saw.
fn texture_psnr(r: &DelightResult, kd: &Image, truth: &Image) -> (f64, usize) {
    let o = r.objects.iter().find(|o| o.id == "back_wall").unwrap();
    assert!(o.atlas.kept_uvs);
    let kd = kd.clone();
    let (w, h) = (o.atlas.width, o.atlas.height);
    let mut se = 0f64;
    let mut n = 0usize;
    for y in 0..truth.height {
        for x in 0..truth.width {
            let uv = Vec2::new((x as f32 + 0.5) / truth.width as f32, (y as f32 + 0.5) / truth.height as f32);
            let (tx, ty) = ((uv.x * w as f32) as usize, (uv.y * h as f32) as usize);
            if !o.observed[ty.min(h - 1) * w + tx.min(w - 1)] {
                continue;
            }
            let got = opal::scene::desc::BitmapDesc {
                image: std::sync::Arc::new(kd.clone()),
                filter: opal::scene::desc::FilterType::Bilinear,
                wrap: opal::scene::desc::WrapMode::Clamp,
                path: "kd".into(),
            }
            .eval(uv);
            let t = truth.get(x, y);
            for c in 0..3 {
                se += ((got[c] - t[c]) as f64).powi(2);
            }
            n += 3;
        }
    }
    (10.0 * (1.0 / (se / n as f64)).log10(), n / 3)
}

/// The Cornell box rendered by Opal's path tracer at its true albedos: 8 views of `res`×`res`
/// pixels at 256 spp.
fn small_views(desc: &mut SceneDesc, res: usize) -> Vec<View> {
    views_with_seed(desc, res, 7)
}

/// [`small_views`] with the path tracer's seed.
fn views_with_seed(desc: &mut SceneDesc, res: usize, seed: u64) -> Vec<View> {
    for s in &mut desc.sensors {
        s.width = res;
        s.height = res;
    }
    let scene = Scene::build(desc).unwrap();
    let ps = PathSettings { spp: 256, max_depth: -1, rr_depth: 5, hide_emitters: false, seed };
    (0..scene.cameras.len())
        .map(|c| {
            let out = render(&scene, c, &ps, &|| {});
            assert_eq!(out.nonfinite, 0);
            View {
                name: scene.cameras[c].id.clone(),
                path: PathBuf::from(format!("mem{c}")),
                camera: scene.cameras[c].clone(),
                image: out.image,
                bad_pixels: 0,
            }
        })
        .collect()
}

fn small_settings() -> DelightSettings {
    DelightSettings {
        resolution: Some(32),
        light_paths: LightPaths::Fixed(500_000),
        iterations: 4,
        direct_samples: 64,
        tolerance: 0.0,
        ..Default::default()
    }
}

/// The settings of [`round_trip_small_cbox`] (and of its seed sweep): [`small_settings`] with
/// 2 M light paths and 6 passes. Why (measured with the 8 seeds of the sweep, de-lighting
/// seeds varied over fixed views and the reverse): with 500 k paths the short box's mean albedo
/// moved by σ ≈ 2 % between de-lighting seeds alone, whole faces at once (±15 to ±50 % per
/// face) — the super-resolution's prior acts on `L / (Ed + Ei)` with the `Ei` of the first
/// pass, so one pass's `Ei` noise on a face of a few texels shifts that face's `L`; 4 passes
/// leave the fixed point short of convergence (ceiling +1.3 %, short box +2.5 % over the seeds;
/// +0.5 % / +1.9 % after 6).
///
/// The boxes' +1 to +2 % over the seeds is a bias of the coarse 32² atlas, not of the estimator
/// (measured, 2 seeds each, the same paths and passes): it grows with finer views (short box
/// +0.8…+1.4 % with 64-pixel views, +1.9…+3.4 % with 128-pixel views) and goes with finer maps —
/// with 64² maps and 128-pixel views, 8 seeds: tall box +0.31/+0.59/+0.52 % ± 0.14–0.26 %,
/// floor, ceiling and walls within 0.9 % (mean) ± 0.03–0.19 %. That configuration is not the
/// test's because its short box swings by σ 1.1–2.0 % (one seed −4.9 % in green, +3.0 % in
/// blue; mean −0.05/−1.37/+0.97 %), most likely from the views' path-tracing noise on its
/// shadowed, indirectly lit faces, where the worst texels sit (L ≈ 0.004,
/// per-texel errors of ±25–40 %); 4× the light paths did not narrow it.
fn round_trip_settings() -> DelightSettings {
    DelightSettings { light_paths: LightPaths::Fixed(2_000_000), iterations: 6, ..small_settings() }
}

/// View size of [`round_trip_small_cbox`]: 64 pixels. 32-pixel views show each face of the
/// short box in a handful of pixels; their noise alone (views varied over a fixed de-lighting
/// seed) moved its mean by σ 1.5–3.7 %, through the super-resolution as above (1 % without).
const ROUND_TRIP_VIEW_RES: usize = 64;

#[test]
fn round_trip_small_cbox() {
    let mut desc = load(&data().join("scene.xml"));
    let views = small_views(&mut desc, ROUND_TRIP_VIEW_RES);
    let s = round_trip_settings();
    let r = delight(&desc, &views, &s, &|l| println!("{l}")).unwrap();
    let worst = report(&r, &desc);
    let truth = opal::image::read::read_image(&data().join("textures/backwall_albedo.exr")).unwrap();
    let (psnr, n) = backwall_psnr(&r, &truth);
    let (limit, _) = texture_psnr(&r, &truth_at_map_resolution(&r, &truth), &truth);
    // texel noise: relative spread of the observed texels of the constant planar objects
    let (mut s2, mut m) = (0f64, 0usize);
    for (id, t) in truth_albedos(&desc).iter().filter(|(id, _)| !id.ends_with("_box")) {
        let o = r.objects.iter().find(|o| &o.id == id).unwrap();
        for (kd, _) in o.kd.iter().zip(&o.observed).filter(|(_, seen)| **seen) {
            for c in 0..3 {
                s2 += (kd[c] as f64 / t[c] as f64 - 1.0).powi(2);
                m += 1;
            }
        }
    }
    let rel_sd = (s2 / m as f64).sqrt();
    let mean_sq = truth.data.iter().map(|p| (0..3).map(|c| (p[c] as f64).powi(2)).sum::<f64>()).sum::<f64>()
        / (3 * truth.data.len()) as f64;
    let mse_limit = 10f64.powf(-limit / 10.0);
    let noise_mse = rel_sd * rel_sd * mean_sq;
    let psnr_expected = 10.0 * (1.0 / (mse_limit + noise_mse)).log10();
    let psnr_bound = 10.0 * (1.0 / (mse_limit + 2.0 * noise_mse)).log10();
    println!(
        "back wall PSNR {psnr:.2} dB over {n} texels (the truth at the map's resolution: {limit:.2} dB; \
         texel noise {:.2} % → expected {psnr_expected:.2} dB, bound {psnr_bound:.2} dB)",
        100.0 * rel_sd
    );
    // Bounds of this deliberately small configuration (64×64 views at 256 spp, 32² texture maps,
    // 2 M light paths per pass, 6 passes), per object from the spread over 8 seeds of views and
    // de-lighting (`round_trip_small_cbox_seed_spread`): bound = |mean error| + 4σ of the worst
    // channel. The configuration keeps a bias of its own (32² maps on the boxes' faces, 64-pixel
    // views; 256-pixel views reach 1 %, `mitsuba_cbox_acceptance`).
    // * the large planar objects: floor 0.77 + 4·0.46, ceiling 0.48 + 4·0.29, red wall
    //   0.03 + 4·0.25, green wall 0.43 + 4·0.10 (%) → 2.61 % at most: bound 2.7 % (was 3.5 %).
    // * the boxes: short box 1.88 + 4·0.66, 1.19 + 4·0.67; tall box 0.97 + 4·0.76 (%) → 4.52 %
    //   at most: bound 4.6 % (was 6 %, then ≈ 1.7σ of the short box with 32-pixel views, 500 k
    //   paths and 4 passes; see `round_trip_settings`).
    // A wrong estimator (the bugs found while writing this — lost border deposits, unrelaxed
    // oscillation — gave 15–22 %) fails either bound. Measured with the fixed seeds: worst
    // planar channel 0.73 % (floor, blue), short box 1.37 %, tall box 1.11 %.
    assert_round_trip_albedos(&r, &desc, worst);
    // Back wall: a 32² map cannot resolve the 256² texture. Its expected squared error is the
    // resolution limit's (the truth box-filtered to the map: 19.47 dB) + the texel noise
    // (relative spread of the constant planar objects' texels, 5.81 %, times the texture's mean
    // square): expected 19.15 dB, measured 19.63 dB. Bound: the noise term doubled (its
    // estimate comes from other objects), 18.86 dB (was a flat 15 dB); a flipped texture gives
    // < 12 dB.
    assert!(psnr > psnr_bound, "back wall PSNR {psnr} dB < {psnr_bound} dB (expected {psnr_expected})");
    assert!(psnr > 15.0, "{psnr}");
    assert!(r.view_gains.is_none());
}

/// The albedo bounds of [`round_trip_small_cbox`] (derived there): per channel 2.7 % on the
/// planar objects, 4.6 % on the boxes, and the worst channel within 4.6 %.
fn assert_round_trip_albedos(r: &DelightResult, desc: &SceneDesc, worst: f64) {
    for (id, t) in truth_albedos(desc) {
        let m = r.objects.iter().find(|o| o.id == id).unwrap().mean_kd_observed();
        let bound = if id.ends_with("_box") { 0.046 } else { 0.027 };
        for c in 0..3 {
            let e = (m[c] / t[c] as f64 - 1.0).abs();
            assert!(e < bound, "{id} channel {c}: relative albedo error {e} (bound {bound})");
        }
    }
    assert!(worst < 0.046, "worst relative albedo error {worst}");
}

/// The stop rule (`delight/convergence.rs`) on the fixture of [`round_trip_small_cbox`], whose
/// answer is known (the true albedos): the first pass starts from the gathered estimate and
/// asks for a real change beyond the tolerance, so the run goes on; it stops once a pass
/// changes no tile by more than 1 % beyond the noise, before the limit of 8 passes, and then
/// meets the same albedo bounds as [`round_trip_small_cbox`] after its 6 passes.
#[test]
fn round_trip_small_cbox_stops_when_converged() {
    let mut desc = load(&data().join("scene.xml"));
    let views = small_views(&mut desc, ROUND_TRIP_VIEW_RES);
    let s = DelightSettings { iterations: 8, tolerance: 0.01, ..round_trip_settings() };
    let r = delight(&desc, &views, &s, &|l| println!("{l}")).unwrap();
    let worst = report(&r, &desc);
    let stats: Vec<(f64, f64, usize)> =
        r.iterations.iter().map(|i| (i.change_max, i.change_beyond_noise, i.change_regions)).collect();
    println!("tile changes (max, beyond the noise, tiles) per pass: {stats:?}");
    assert!(r.iterations[0].change_beyond_noise > 0.01, "{stats:?}");
    assert!(r.converged, "{stats:?}");
    let n = r.iterations.len();
    assert!((2..8).contains(&n), "{n} passes: {stats:?}");
    assert!(r.iterations[n - 1].change_beyond_noise < 0.01);
    assert!(r.iterations[..n - 1].iter().skip(1).all(|i| i.change_beyond_noise >= 0.01));
    assert_round_trip_albedos(&r, &desc, worst);
}

/// The small round trip with the tall box replaced by a displaced icosphere without UVs (5 120
/// triangles, fitted into the tall box's bounding box): the curved unwrap (LSCM charts, shape
/// packing, chart-owned gutters) goes through the whole pipeline and the sphere's constant
/// albedo comes out like the boxes'.
#[test]
fn round_trip_small_cbox_curved_object() {
    let mut desc = load(&data().join("scene.xml"));
    let tall = desc.shapes.iter_mut().find(|s| s.id == "tall_box").unwrap();
    let (lo, hi) = tall
        .mesh
        .positions
        .iter()
        .fold((opal::math::Vec3::splat(f32::MAX), opal::math::Vec3::splat(f32::MIN)), |(a, b), &p| {
            (a.min(p), b.max(p))
        });
    let mut m = opal_inverse::delight::atlas::testmesh::displaced_icosphere(4, 0.07);
    let (c, h) = (0.5 * (lo + hi), 0.5 * (hi - lo));
    for p in &mut m.positions {
        *p = c + *p / 1.07 * h;
    }
    tall.mesh = m;
    let views = small_views(&mut desc, 64);
    let mut s = small_settings();
    s.resolution = Some(64);
    let r = delight(&desc, &views, &s, &|l| println!("{l}")).unwrap();
    let o = r.objects.iter().find(|o| o.id == "tall_box").unwrap();
    println!("sphere: {} charts, utilisation {:.3}", o.atlas.charts, o.atlas.utilisation());
    assert!(!o.atlas.kept_uvs && o.atlas.charts > 1);
    let worst = report(&r, &desc);
    // the boxes' bound of `round_trip_small_cbox` (see there); measured 1.6 %
    assert!(worst < 0.06, "worst relative albedo error {worst}");
}

/// Known per-view gains of the tests: exposure 0.8–1.25 times white balance ±5 % per channel,
/// built so that per channel the median view is exact (the estimator's scale convention, see
/// `opal_inverse::delight::gains`): views 0–2 lie below and views 5–7 above views 3 and 4 in
/// every channel, and views 3 and 4 are reciprocal.
fn known_gains() -> Vec<[f32; 3]> {
    let e = [0.8f32, 0.86, 0.9, 0.97, 1.0 / 0.97, 1.12, 1.18, 1.25];
    let wb = [
        [1.05, 0.97, 0.95],
        [0.96, 1.04, 1.02],
        [1.0, 0.95, 1.05],
        [1.02, 0.99, 0.98],
        [1.0 / 1.02, 1.0 / 0.99, 1.0 / 0.98],
        [0.95, 1.03, 1.05],
        [1.05, 0.96, 1.0],
        [0.97, 1.05, 0.95],
    ];
    e.iter().zip(wb).map(|(e, w)| w.map(|x| e * x)).collect()
}

/// The small round trip at 64×64 pixels, once with exact views (`fixed`) and once with the views
/// multiplied by known gains (exposure 0.8–1.25, white balance ±5 %) and `exposure+wb`: the
/// gains are recovered and the albedos come out as with the exact views.
#[test]
fn round_trip_small_cbox_with_view_gains() {
    let mut desc = load(&data().join("scene.xml"));
    let exact = small_views(&mut desc, 64);
    let r0 = delight(&desc, &exact, &small_settings(), &|_| {}).unwrap();
    println!("exact views, fixed:");
    let worst0 = report(&r0, &desc);
    let mut views = exact.clone();
    let truth_gains = known_gains();
    common::apply_gains(&mut views, &truth_gains);
    let mut s = small_settings();
    s.view_gains = ViewGainSettings { mode: ViewGainMode::ExposureWb, ..Default::default() };
    let r = delight(&desc, &views, &s, &|l| println!("{l}")).unwrap();
    println!("gained views, exposure+wb:");
    let worst = report(&r, &desc);
    let gerr = common::gain_error(&r, &truth_gains);
    println!(
        "worst gain error {:.3} %; worst albedo error {:.2} % (exact views {:.2} %)",
        100.0 * gerr,
        100.0 * worst,
        100.0 * worst0
    );
    assert!(r.warnings.iter().all(|w| !w.contains("gain")), "{:?}", r.warnings);
    // measured 0.84 % (view_05; systematic: the footprints of 64-pixel views — 0.08 % on the
    // 256-pixel reference views); ignoring the gains would leave up to 31 %
    assert!(gerr < 0.01, "worst relative gain error {gerr}");
    // measured 1.42 % vs 1.66 % with the exact views
    assert!(worst < worst0 + 0.005, "worst relative albedo error {worst} vs {worst0} with exact views");
}

#[test]
#[ignore = "needs OPAL_CBOX_DIR (the Mitsuba 3 reference data set); ~1–2 min"]
fn mitsuba_cbox_acceptance() {
    let dir = PathBuf::from(std::env::var("OPAL_CBOX_DIR").expect("set OPAL_CBOX_DIR"));
    let desc = load(&dir.join("scene.xml"));
    let (views, warn) = read_views(&dir.join("transforms.json")).unwrap();
    assert!(warn.is_empty(), "{warn:?}");
    // OPAL_DELIGHT_PATHS = a fixed count per pass; default: from the texels and the target noise
    let paths = std::env::var("OPAL_DELIGHT_PATHS")
        .ok()
        .and_then(|v| v.parse().ok())
        .map_or(DelightSettings::default().light_paths, LightPaths::Fixed);
    // OPAL_SR_CG_TOLERANCE = the super-resolution's noise stop rule τ (0: the fixed 6 × 60 steps)
    let mut sr = superres::SrSettings::default();
    if let Some(t) = std::env::var("OPAL_SR_CG_TOLERANCE").ok().and_then(|v| v.parse().ok()) {
        sr.cg_tolerance = t;
    }
    // at most 5 passes, stopped by the default tolerance (issue 17: ≤ 5 iterations, converged)
    let s = DelightSettings { light_paths: paths, iterations: 5, superres: Some(sr), ..Default::default() };
    let r = delight(&desc, &views, &s, &|l| println!("{l}")).unwrap();
    let worst = report(&r, &desc);
    for o in &r.objects {
        println!("{:18} superres {:?}", o.id, o.superres);
    }
    let truth = opal::image::read::read_image(&dir.join("textures/backwall_albedo.exr")).unwrap();
    let (psnr, n) = backwall_psnr(&r, &truth);
    println!(
        "back wall PSNR {psnr:.2} dB over {n} texels; worst constant-object error {:.2} %; {} passes, converged {}",
        100.0 * worst,
        r.iterations.len(),
        r.converged
    );
    assert!(r.converged, "acceptance: converged within 5 passes");
    assert!(worst < 0.01, "acceptance: mean albedo within 1 %: worst {worst}");
    assert!(psnr >= 38.0, "acceptance: back wall PSNR ≥ 38 dB: {psnr}");
}

/// The independent Mitsuba 3 data set with its views multiplied by known gains (exposure
/// 0.8–1.25, white balance ±5 %; [`known_gains`]) and de-lit with `exposure+wb`: the issue-26
/// acceptance (gains within 0.5 %, constant albedos within 1 %, back wall ≥ 38 dB). With
/// `OPAL_VIEW_GAINS=fixed|exposure|exposure+wb` the mode is overridden (e.g. `fixed`: what the
/// gained views give without the estimation; the gain and albedo bounds are then not asserted).
#[test]
#[ignore = "needs OPAL_CBOX_DIR (the Mitsuba 3 reference data set); ~1–2 min"]
fn mitsuba_cbox_view_gains_acceptance() {
    let dir = PathBuf::from(std::env::var("OPAL_CBOX_DIR").expect("set OPAL_CBOX_DIR"));
    let desc = load(&dir.join("scene.xml"));
    let (mut views, warn) = read_views(&dir.join("transforms.json")).unwrap();
    assert!(warn.is_empty(), "{warn:?}");
    let truth_gains = known_gains();
    common::apply_gains(&mut views, &truth_gains);
    let mode = match std::env::var("OPAL_VIEW_GAINS").as_deref() {
        Ok("fixed") => ViewGainMode::Fixed,
        Ok("exposure") => ViewGainMode::Exposure,
        Ok("exposure+wb") | Err(_) => ViewGainMode::ExposureWb,
        Ok(other) => panic!("OPAL_VIEW_GAINS: unknown mode {other}"),
    };
    // OPAL_DELIGHT_PATHS = a fixed count per pass; default: from the texels and the target noise
    let paths = std::env::var("OPAL_DELIGHT_PATHS")
        .ok()
        .and_then(|v| v.parse().ok())
        .map_or(DelightSettings::default().light_paths, LightPaths::Fixed);
    let s = DelightSettings {
        light_paths: paths,
        iterations: 5,
        tolerance: 0.0,
        view_gains: ViewGainSettings { mode, ..Default::default() },
        ..Default::default()
    };
    let r = delight(&desc, &views, &s, &|l| println!("{l}")).unwrap();
    let worst = report(&r, &desc);
    let truth = opal::image::read::read_image(&dir.join("textures/backwall_albedo.exr")).unwrap();
    let (psnr, n) = backwall_psnr(&r, &truth);
    println!("warnings {:?}", r.warnings);
    println!(
        "mode {}: back wall PSNR {psnr:.2} dB over {n} texels; worst constant-object error {:.2} %",
        mode.name(),
        100.0 * worst
    );
    if mode == ViewGainMode::ExposureWb {
        let gerr = common::gain_error(&r, &truth_gains);
        println!("worst gain error {:.3} %", 100.0 * gerr);
        assert!(gerr < 0.005, "acceptance: gains within 0.5 %: worst {gerr}");
        assert!(worst < 0.01, "acceptance: mean albedo within 1 %: worst {worst}");
        assert!(psnr >= 38.0, "acceptance: back wall PSNR ≥ 38 dB: {psnr}");
    }
}

/// The seed-to-seed spread behind the bounds of [`round_trip_small_cbox`]: its configuration
/// run with 8 seeds (views and de-lighting), printing per object and channel the mean relative
/// error (the bias of the configuration) and its standard deviation over the seeds (σ).
/// Measured (8 seeds, 2026-11-26, 64-pixel views, 2 M paths, 6 passes; mean ± σ per channel):
/// floor +0.49/+0.21/+0.77 % ± 0.42–0.46 %, ceiling +0.54/+0.48/−0.11 % ± 0.18–0.33 %, red wall
/// −0.18/−0.03/−0.02 % ± 0.15–0.25 %, green wall −0.40/−0.43/−0.19 % ± 0.08–0.10 %, short box
/// +1.88/+1.22/+1.19 % ± 0.51–0.67 %, tall box +1.09/+0.97/+1.17 % ± 0.34–0.76 %.
/// (The earlier configuration — 32-pixel views, 500 k paths, 4 passes — gave the short box
/// σ 2.3–3.6 % and one seed at −7.5 %.)
#[test]
#[ignore = "measurement behind a bound (8 de-lighting runs, ~10 min at load 14)"]
fn round_trip_small_cbox_seed_spread() {
    let base = load(&data().join("scene.xml"));
    let truth = truth_albedos(&base);
    let mut all: Vec<Vec<f64>> = Vec::new();
    for k in 0..8u64 {
        let mut desc = base.clone();
        let views = views_with_seed(&mut desc, ROUND_TRIP_VIEW_RES, 100 + k);
        let s = DelightSettings { seed: 1000 + k, ..round_trip_settings() };
        let r = delight(&desc, &views, &s, &|_| {}).unwrap();
        let mut row = Vec::new();
        for (id, t) in &truth {
            let m = r.objects.iter().find(|o| &o.id == id).unwrap().mean_kd_observed();
            row.extend((0..3).map(|c| m[c] / t[c] as f64 - 1.0));
        }
        println!(
            "seed {k}: {}",
            row.iter().map(|v| format!("{:+.2}", 100.0 * v)).collect::<Vec<_>>().join(" ")
        );
        all.push(row);
    }
    let n = all.len() as f64;
    for (j, (id, c)) in truth.iter().flat_map(|t| (0..3).map(move |c| (t.0.clone(), c))).enumerate() {
        let m = all.iter().map(|r| r[j]).sum::<f64>() / n;
        let sd = (all.iter().map(|r| (r[j] - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        println!("{id:18} channel {c}: mean {:+.2} % σ {:.2} %", 100.0 * m, 100.0 * sd);
    }
}

/// A run stopped (by its cancel flag) after its first iteration and resumed from the checkpoint
/// gives the same albedo, luminance and iteration statistics, bit for bit, as an uninterrupted
/// run; a checkpoint made with another seed is refused.
#[test]
fn checkpoint_resume_gives_the_same_bits() {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, Ordering};
    let mut desc = load(&data().join("scene.xml"));
    let views = small_views(&mut desc, 32);
    let base = DelightSettings { iterations: 3, light_paths: LightPaths::Fixed(200_000), ..small_settings() };
    let whole = delight(&desc, &views, &base, &|_| {}).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let cancel = Arc::new(AtomicBool::new(false));
    let s = DelightSettings {
        checkpoint: Some(dir.path().to_path_buf()),
        cancel: Some(cancel.clone()),
        ..base.clone()
    };
    // the stop request arrives while iteration 1 is logged: the run ends before iteration 2
    let stop = |l: &str| {
        if l.starts_with("iteration 1:") {
            cancel.store(true, Ordering::SeqCst);
        }
    };
    let e = delight(&desc, &views, &s, &stop).unwrap_err();
    assert!(matches!(&e, opal::error::Error::Interrupted { kept } if kept.contains("iterations 1-1")), "{e}");
    assert!(dir.path().join("state.json").exists());
    let resumed = DelightSettings { resume: true, cancel: None, ..s.clone() };
    let lines = std::sync::Mutex::new(Vec::new());
    let r = delight(&desc, &views, &resumed, &|l| lines.lock().unwrap().push(l.to_string())).unwrap();
    assert!(lines.lock().unwrap().iter().any(|l| l.starts_with("resuming after iteration 1")));
    assert_eq!(r.iterations.len(), whole.iterations.len());
    assert_eq!(kd_hash(&r), kd_hash(&whole));
    for (a, b) in r.objects.iter().zip(&whole.objects) {
        assert!(a.kd == b.kd && a.l == b.l && a.ei == b.ei && a.observed == b.observed, "{}", a.id);
    }
    for (a, b) in r.iterations.iter().zip(&whole.iterations) {
        assert_eq!(a.max_rel_error.to_bits(), b.max_rel_error.to_bits());
        assert_eq!(a.error_maps.len(), b.error_maps.len());
        for (x, y) in a.error_maps.iter().zip(&b.error_maps) {
            assert!(x.iter().zip(y).all(|(p, q)| p.to_bits() == q.to_bits()));
        }
    }
    assert_eq!(r.light_paths, whole.light_paths);
    // another seed: another state before the iterations, so the checkpoint is refused
    let other = DelightSettings { seed: 5, ..resumed };
    let e = delight(&desc, &views, &other, &|_| {}).unwrap_err();
    assert!(e.to_string().contains("other inputs or settings"), "{e}");
}

/// The progress callback (`DelightSettings::progress`): every long stage reports, in pipeline
/// order, a constant total, a first report of 0, a last one of the total, and positions that
/// never decrease (the light-tracing and post-processing stages once per pass); the albedos are
/// the same bits as without the callback.
#[test]
fn progress_is_monotone_per_stage() {
    use std::sync::{Arc, Mutex};
    let mut desc = load(&data().join("scene.xml"));
    let views = small_views(&mut desc, 32);
    let base = DelightSettings { iterations: 2, light_paths: LightPaths::Fixed(200_000), ..small_settings() };
    let calls: Arc<Mutex<Vec<(String, u64, u64)>>> = Arc::default();
    let c = calls.clone();
    let s = DelightSettings {
        progress: Some(opal_inverse::delight::Progress::new(move |st, d, t| {
            c.lock().unwrap().push((st.to_string(), d, t))
        })),
        ..base.clone()
    };
    let r = delight(&desc, &views, &s, &|_| {}).unwrap();
    let plain = delight(&desc, &views, &base, &|_| {}).unwrap();
    assert_eq!(kd_hash(&r), kd_hash(&plain));
    let calls = calls.lock().unwrap();
    // stages in the order of their first report
    let mut order: Vec<&str> = Vec::new();
    for (st, _, _) in calls.iter() {
        if order.last() != Some(&st.as_str()) {
            assert!(!order.contains(&st.as_str()), "stage {st} reported again after another: {order:?}");
            order.push(st);
        }
    }
    let want = [
        "unwrap",
        "direct",
        "direct penumbrae",
        "luminance",
        "gather",
        "light tracing 1",
        "post 1",
        "superres",
        "light tracing 2",
        "post 2",
    ];
    assert_eq!(order, want);
    for st in want {
        let mine: Vec<(u64, u64)> = calls.iter().filter(|c| c.0 == st).map(|c| (c.1, c.2)).collect();
        let total = mine[0].1;
        assert!(total > 0, "{st}");
        assert_eq!(mine[0].0, 0, "{st}: {mine:?}");
        assert_eq!(mine.last().unwrap().0, total, "{st}: {mine:?}");
        assert!(mine.iter().all(|&(_, t)| t == total), "{st}: {mine:?}");
        assert!(mine.windows(2).all(|w| w[0].0 <= w[1].0), "{st}: {mine:?}");
    }
    // the light tracing reports per batch, the direct light per group of texels from inside its
    // split: more than a start and an end
    for st in ["light tracing 1", "direct"] {
        let n = calls.iter().filter(|c| c.0 == st).count();
        assert!(n > 2, "{st}: {n}");
    }
}

/// The super-resolution builds, solves and drops one object's operator after the other (the
/// peak holds the largest object's, not all of them): the maps are the same bits whatever the
/// thread count — with one thread the objects ran one after the other before too, and each
/// object's solve never depended on the others running beside it.
#[test]
fn superres_objects_one_at_a_time_for_any_thread_count() {
    let mut desc = load(&data().join("scene.xml"));
    let views = small_views(&mut desc, 32);
    let s = DelightSettings { iterations: 1, light_paths: LightPaths::Fixed(200_000), ..small_settings() };
    assert!(s.superres.is_some());
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        let r = pool.install(|| delight(&desc, &views, &s, &|_| {}).unwrap());
        assert!(r.objects.iter().any(|o| o.superres.is_some()));
        let l: Vec<u32> = r.objects.iter().flat_map(|o| o.l.iter().flatten().map(|v| v.to_bits())).collect();
        (kd_hash(&r), l)
    };
    let one = run(1);
    assert_eq!(run(3), one);
}
