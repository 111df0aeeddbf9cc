//! De-lighting (method C) end to end.
//!
//! * `transforms_match_scene_sensors`: the NeRF-style `transforms.json` of the reference Cornell
//!   box (OpenGL axes) converts to the Mitsuba `to_world` of the scene's sensors.
//! * `round_trip_small_cbox`: views of the Cornell box rendered by Opal's own path tracer at the
//!   true albedos (64×64, 8 views) → de-lighting → albedos and back-wall texture vs the truth.
//! * `round_trip_small_cbox_curved_object`: the same with the tall box replaced by a displaced
//!   icosphere without UVs (the curved unwrap end to end).
//! * `mitsuba_cbox_acceptance` (ignored; `OPAL_CBOX_DIR=<shared>/reference/mitsuba/cbox
//!   cargo test -p opal-inverse --test delight -- --ignored --nocapture`): the independent
//!   Mitsuba 3 data set, 8 views 256×256.

use opal::image::Image;
use opal::integrator::path::{PathSettings, render};
use opal::math::Vec2;
use opal::scene::Scene;
use opal::scene::desc::{SceneDesc, TextureDesc};
use opal_inverse::delight::views::{View, read_views};
use opal_inverse::delight::{DelightResult, DelightSettings, ViewGainMode, ViewGainSettings, delight};
use std::path::{Path, PathBuf};

mod common;

fn data() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../opal/tests/data/cbox")
}

fn load(path: &Path) -> SceneDesc {
    opal::scene::load::load_mitsuba_xml(path, &[]).unwrap()
}

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
    assert!(o.atlas.kept_uvs);
    let kd = o.kd_image();
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

fn truth_albedos(desc: &SceneDesc) -> Vec<(String, [f32; 3])> {
    desc.shapes
        .iter()
        .filter(|s| s.emitter.is_none())
        .filter_map(|s| match &s.bsdf {
            opal::scene::desc::BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(c) } => {
                Some((s.id.clone(), c.0))
            }
            _ => None,
        })
        .collect()
}

/// FNV-1a hash of the bits of every recovered albedo texel (bit-for-bit comparisons of runs).
fn kd_hash(r: &DelightResult) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for o in &r.objects {
        for v in o.kd.iter().flatten() {
            h = (h ^ v.to_bits() as u64).wrapping_mul(0x0100_0000_01b3);
        }
    }
    h
}

fn report(r: &DelightResult, desc: &SceneDesc) -> f64 {
    let mut worst = 0f64;
    for (id, t) in truth_albedos(desc) {
        let o = r.objects.iter().find(|o| o.id == id).unwrap();
        let m = o.mean_kd_observed();
        let rel: Vec<f64> = (0..3).map(|c| m[c] / t[c] as f64 - 1.0).collect();
        println!(
            "{id:18} kd {:.4} {:.4} {:.4}  truth {:.4} {:.4} {:.4}  rel {:+.2}% {:+.2}% {:+.2}%  seen {:.0}%",
            m[0],
            m[1],
            m[2],
            t[0],
            t[1],
            t[2],
            100.0 * rel[0],
            100.0 * rel[1],
            100.0 * rel[2],
            100.0 * o.seen_fraction
        );
        worst = rel.iter().fold(worst, |a, b| a.max(b.abs()));
    }
    for it in &r.iterations {
        println!(
            "iteration {}: max {:.2}% mean {:.2}% direct ratio {:?} ({:.1} s)",
            it.iteration,
            100.0 * it.max_rel_error,
            100.0 * it.mean_rel_error,
            it.direct_ratio,
            it.seconds
        );
    }
    println!("albedo bits hash {:016x}", kd_hash(r));
    println!("timings (wall s) {:?}", r.timings);
    println!("timings (CPU s) {:?}", r.cpu_timings);
    worst
}

/// The Cornell box rendered by Opal's path tracer at its true albedos: 8 views of `res`×`res`
/// pixels at 256 spp.
fn small_views(desc: &mut SceneDesc, res: usize) -> Vec<View> {
    for s in &mut desc.sensors {
        s.width = res;
        s.height = res;
    }
    let scene = Scene::build(desc).unwrap();
    let ps = PathSettings { spp: 256, max_depth: -1, rr_depth: 5, hide_emitters: false, seed: 7 };
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
        light_paths: 500_000,
        iterations: 4,
        direct_samples: 64,
        tolerance: 0.0,
        ..Default::default()
    }
}

#[test]
fn round_trip_small_cbox() {
    let mut desc = load(&data().join("scene.xml"));
    let views = small_views(&mut desc, 32);
    let s = small_settings();
    let r = delight(&desc, &views, &s, &|l| println!("{l}")).unwrap();
    let worst = report(&r, &desc);
    let truth = opal::image::read::read_image(&data().join("textures/backwall_albedo.exr")).unwrap();
    let (psnr, n) = backwall_psnr(&r, &truth);
    println!("back wall PSNR {psnr:.2} dB over {n} texels");
    // Tolerances for this deliberately tiny configuration (32×32 views at 256 spp, 32² texture
    // maps, 500 k light paths per pass, 4 passes): the measured worst channel error is ~4 %
    // (dark channels of the red wall, whose 4 % share of the luminance makes them noisy; the
    // bright channels are within ~3 %), so 6 % catches a wrong estimator (the bugs found while
    // writing this — lost border deposits, unrelaxed oscillation — gave 15–22 %) without
    // flaking. 32-pixel views cannot resolve the 256² back-wall texture: the PSNR bound only
    // checks orientation (a flipped texture gives < 12 dB).
    assert!(worst < 0.06, "worst relative albedo error {worst}");
    assert!(psnr > 15.0, "{psnr}");
    assert!(r.view_gains.is_none());
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
    // same bound as `round_trip_small_cbox` (see there)
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
    let paths: u64 =
        std::env::var("OPAL_DELIGHT_PATHS").ok().and_then(|v| v.parse().ok()).unwrap_or(20_000_000);
    let s = DelightSettings { light_paths: paths, iterations: 5, tolerance: 0.0, ..Default::default() };
    let r = delight(&desc, &views, &s, &|l| println!("{l}")).unwrap();
    let worst = report(&r, &desc);
    let truth = opal::image::read::read_image(&dir.join("textures/backwall_albedo.exr")).unwrap();
    let (psnr, n) = backwall_psnr(&r, &truth);
    println!(
        "back wall PSNR {psnr:.2} dB over {n} texels; worst constant-object error {:.2} %",
        100.0 * worst
    );
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
    let paths: u64 =
        std::env::var("OPAL_DELIGHT_PATHS").ok().and_then(|v| v.parse().ok()).unwrap_or(20_000_000);
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
