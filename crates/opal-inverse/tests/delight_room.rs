//! De-lighting acceptance on an independent Mitsuba 3 data set that is not the shared Cornell
//! box: a closed room with a textured floor and poster (bitmap albedos), a faceted sphere mesh, a
//! rotated cuboid, five walls/ceiling of constant albedos, two ceiling area lights of different
//! size and colour, and six cameras inside the room at different resolutions (320×240 … 240×320).
//! Made by `bench/scripts/room_multiview.py OUT` (Mitsuba 3.9.1, 1024 spp, ~15 min on 2 shared
//! cores); all tests are ignored and read the directory from `OPAL_ROOM_DIR`:
//!
//! `OPAL_ROOM_DIR=OUT cargo test -p opal-inverse --test delight_room -- --ignored --nocapture`
//!
//! * `mitsuba_room_acceptance`: exact views, `fixed` — constant albedos within 1 %, textures
//!   ≥ 38 dB (the de-lighting acceptance).
//! * `mitsuba_room_view_gains_acceptance`: the views × known gains (exposure 0.85–1.2, white
//!   balance ±5 %, median view exact per channel), `exposure+wb` — issue 26's acceptance: gains
//!   within 0.5 %, constant albedos within 1 %, textures ≥ 38 dB.
//! * `mitsuba_room_three_views_off`: issue 26's own scenario, 3 of 6 views × 1.15, 0.9, 1.08, the
//!   others exact, `exposure` — the same bounds.
//!
//! * `mitsuba_room_perturbed_poses`: issue 25's acceptance — every camera rotated by 0.15–0.3°
//!   about a random axis and moved by ~1 px at the scene centre (fixed seed;
//!   `OPAL_POSE_SEED=<hex>` another one), the pose refinement `full`
//!   (`OPAL_REFINE_POSES=off|rotation|full` overrides it; bounds asserted for `full` only),
//!   judged at the TRUE cameras; prints the pose errors, the mean reprojection error at the
//!   true cameras before and after and each view's steps per round; `OPAL_POSE_PRIOR_PX=<px>|off`
//!   and `OPAL_POSE_PIVOT=scene|camera` override the prior and the pivot (`PoseSettings`);
//!   `OPAL_POSE_JOINT=on|off`, `OPAL_POSE_FINE_MARGIN`, `OPAL_POSE_LINEAR_BANDS`,
//!   `OPAL_POSE_DELIGHT_MARGIN`, `OPAL_POSE_FINE_SIGMAS=2,1`, `OPAL_POSE_STEP_TOL` and
//!   `OPAL_POSE_ROUND_STEP_TOL` (pixels), `OPAL_POSE_ROUNDS` the other settings; `OPAL_POSE_AMOUNT=<x>` scales the perturbation (0:
//!   the exact poses, refined all the same). Measured: docs/delight.md, "Pose refinement", and
//!   docs/decisions/delight-pose-refinement.md.
//!
//! `OPAL_VIEW_GAINS=fixed|exposure|exposure+wb` overrides the mode of the two gained tests (e.g.
//! `fixed` shows what the gained views give without the estimation; bounds are then not
//! asserted); `OPAL_DELIGHT_PATHS` a fixed number of light paths per pass (default: from the texel count and
//! the target noise, `delight::noise`).
//!
//! Textures are judged as issue 17 defines it: PSNR pixel-averaged at the input cameras (each
//! pixel's 4 × 4 stratified rays, recovered vs truth albedo at the hit UVs); the texel-space
//! PSNR over the seen texels is printed beside it.
//!
//! Measured 2026-11-26 (20 M paths/pass, 5 passes; 13–35 min per test on 2 shared cores), exact
//! views: worst constant albedo 0.78 % (back wall), poster 44.14 dB at the cameras (39.75 dB
//! texel space), **floor 39.18 dB at the cameras (37.47 dB texel space)** — after the indirect
//! irradiance was smoothed over the texels light reaches only (before: floor 36.33 dB, 35.49 dB
//! texel space, the zeros under the pedestal darkening its contact edges; `docs/delight.md`,
//! "Contact edges"). `mitsuba_room_view_gains_acceptance` after the fix: gains within 0.042 %,
//! worst constant albedo 0.77 %, floor 39.12 dB at the cameras (37.42 dB texel space), poster
//! 44.14 dB — passes; `mitsuba_room_three_views_off` (`exposure`): gains within 0.035 %, worst
//! albedo 0.80 %, floor 39.12 dB (37.42 dB texel space), poster 44.13 dB — passes.
//!
//! After the texture resolution from the cameras' pixel footprints and the light paths from the
//! texel count and target noise (2026-11-26), `mitsuba_room_acceptance` passes: worst constant
//! albedo 0.69 % (ceiling), floor 39.10 dB at the cameras (37.42 dB texel space), poster
//! 44.19 dB (39.77 dB); the atlases total 814 k texels instead of ~5.0 M (ceiling 256² instead
//! of 1475², front wall 370² / 1529², back wall 409² / 330², side walls 256² / 417–419², sphere
//! 367² / 256², pedestal 311² / 256²), 22.93 M paths per pass (20 M before) with an achieved
//! per-texel noise of 10.2 % in the last pass (target 15.3 %: the closed, bright room leaves
//! more deposits per path than the calibration box); 318 s on 2 shared cores.

use opal::math::Vec2;
use opal::scene::Scene;
use opal::scene::desc::{BsdfDesc, SceneDesc, TextureDesc};
use opal_inverse::delight::pose::{camera_with, compose};
use opal_inverse::delight::views::{View, read_views};
use opal_inverse::delight::{
    DelightResult, DelightSettings, LightPaths, PoseRefinement, PoseSettings, ViewGainMode, ViewGainSettings,
    delight,
};
use std::path::PathBuf;

mod common;
mod judge;
use judge::{texture_psnr, texture_psnr_at_cameras};

fn dir() -> PathBuf {
    PathBuf::from(
        std::env::var("OPAL_ROOM_DIR").expect("set OPAL_ROOM_DIR (bench/scripts/room_multiview.py)"),
    )
}

fn load() -> (SceneDesc, Vec<View>) {
    let d = dir();
    let desc = opal::scene::load::load_mitsuba_xml(&d.join("scene.xml"), &[]).unwrap();
    let (views, warn) = read_views(&d.join("transforms.json")).unwrap();
    assert!(warn.is_empty(), "{warn:?}");
    assert_eq!(views.len(), 6);
    (desc, views)
}

fn settings(mode: ViewGainMode) -> DelightSettings {
    // OPAL_DELIGHT_PATHS = a fixed count per pass; default: from the texels and the target noise
    let paths = std::env::var("OPAL_DELIGHT_PATHS")
        .ok()
        .and_then(|v| v.parse().ok())
        .map_or(DelightSettings::default().light_paths, LightPaths::Fixed);
    DelightSettings {
        light_paths: paths,
        iterations: 5,
        tolerance: 0.0,
        view_gains: ViewGainSettings { mode, ..Default::default() },
        ..Default::default()
    }
}

/// The mode of a gained test: `default` unless `OPAL_VIEW_GAINS` overrides it.
fn mode_or(default: ViewGainMode) -> ViewGainMode {
    match std::env::var("OPAL_VIEW_GAINS").as_deref() {
        Ok("fixed") => ViewGainMode::Fixed,
        Ok("exposure") => ViewGainMode::Exposure,
        Ok("exposure+wb") => ViewGainMode::ExposureWb,
        Err(_) => default,
        Ok(other) => panic!("OPAL_VIEW_GAINS: unknown mode {other}"),
    }
}

/// Worst relative channel error of the constant-albedo objects and the lowest texture PSNR
/// pixel-averaged at the input cameras (printed per object, with the texel-space PSNR).
fn report(r: &DelightResult, desc: &SceneDesc, views: &[View]) -> (f64, f64) {
    let scene = Scene::build(desc).unwrap();
    let (mut worst, mut psnr_min) = (0f64, f64::INFINITY);
    for s in desc.shapes.iter().filter(|s| s.emitter.is_none()) {
        let o = r.objects.iter().find(|o| o.id == s.id).unwrap();
        match &s.bsdf {
            BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(c) } => {
                worst = worst.max(common::constant_albedo_error(o, c.0));
            }
            BsdfDesc::Diffuse { reflectance: TextureDesc::Bitmap(b) } => {
                let (p, n) = texture_psnr(r, &s.id, &b.image);
                let (pc, m) = texture_psnr_at_cameras(r, &s.id, &scene, views, b);
                println!(
                    "{:12} texture PSNR {pc:.2} dB pixel-averaged at the input cameras ({m} pixels), \
                     {p:.2} dB in texel space ({n} texels), seen {:.0}%",
                    s.id,
                    100.0 * o.seen_fraction
                );
                psnr_min = psnr_min.min(pc);
            }
            other => panic!("{}: unexpected bsdf {other:?}", s.id),
        }
    }
    for it in &r.iterations {
        println!(
            "iteration {}: max {:.2}% mean {:.2}% ({:.1} s)",
            it.iteration,
            100.0 * it.max_rel_error,
            100.0 * it.mean_rel_error,
            it.seconds
        );
    }
    println!("warnings {:?}", r.warnings);
    println!("worst constant-albedo error {:.2} %, lowest texture PSNR {psnr_min:.2} dB", 100.0 * worst);
    (worst, psnr_min)
}

/// Per channel, the median of `ln g` over the views is 0 (the estimator's scale convention: the
/// albedos are then comparable with the truth; see `opal_inverse::delight::gains`).
fn assert_median_view_exact(gains: &[[f64; 3]]) {
    for c in 0..3 {
        let mut l: Vec<f64> = gains.iter().map(|g| g[c].ln()).collect();
        l.sort_by(f64::total_cmp);
        let n = l.len();
        let med = if n % 2 == 1 { l[n / 2] } else { 0.5 * (l[n / 2 - 1] + l[n / 2]) };
        assert!(med.abs() < 1e-12, "channel {c}: median ln g = {med}");
    }
}

/// Runs the de-lighting on the views × `gains` with `mode` and checks issue 26's acceptance.
fn gained_run(gains: &[[f64; 3]], default: ViewGainMode) {
    assert_median_view_exact(gains);
    let (desc, mut views) = load();
    common::apply_gains(&mut views, gains);
    let mode = mode_or(default);
    let r = delight(&desc, &views, &settings(mode), &|l| println!("{l}")).unwrap();
    println!("mode {}:", mode.name());
    let (worst, psnr) = report(&r, &desc, &views);
    if mode == default {
        let gerr = common::gain_error(&r, gains);
        assert!(r.warnings.iter().all(|w| !w.contains("gain")), "{:?}", r.warnings);
        assert!(gerr < 0.005, "acceptance: gains within 0.5 %: worst {gerr}");
        assert!(worst < 0.01, "acceptance: constant albedos within 1 %: worst {worst}");
        assert!(psnr >= 38.0, "acceptance: textures ≥ 38 dB: {psnr}");
    }
}

#[test]
#[ignore = "needs OPAL_ROOM_DIR (bench/scripts/room_multiview.py); 10–20 min"]
fn mitsuba_room_acceptance() {
    let (desc, views) = load();
    let r = delight(&desc, &views, &settings(ViewGainMode::Fixed), &|l| println!("{l}")).unwrap();
    let (worst, psnr) = report(&r, &desc, &views);
    assert!(r.view_gains.is_none());
    assert!(worst < 0.01, "acceptance: constant albedos within 1 %: worst {worst}");
    assert!(psnr >= 38.0, "acceptance: textures ≥ 38 dB: {psnr}");
}

/// Exposure 0.85–1.2 times white balance ±5 % per channel; per channel views 2 and 3 are
/// reciprocal and the other views lie on either side of them, so the median view is exact.
#[test]
#[ignore = "needs OPAL_ROOM_DIR (bench/scripts/room_multiview.py); 10–20 min"]
fn mitsuba_room_view_gains_acceptance() {
    let e = [0.85, 0.93, 0.98, 1.0 / 0.98, 1.1, 1.2];
    let wb = [
        [1.04, 0.96, 1.0],
        [0.95, 0.99, 1.05],
        [1.02, 0.97, 1.01],
        [1.0 / 1.02, 1.0 / 0.97, 1.0 / 1.01],
        [0.96, 1.05, 0.97],
        [1.05, 0.95, 1.03],
    ];
    let gains: Vec<[f64; 3]> = e.iter().zip(wb).map(|(e, w)| w.map(|x| e * x)).collect();
    gained_run(&gains, ViewGainMode::ExposureWb);
}

/// Issue 26's scenario: three of the six views × 1.15, 0.9 and 1.08, the others exact.
#[test]
#[ignore = "needs OPAL_ROOM_DIR (bench/scripts/room_multiview.py); 10–20 min"]
fn mitsuba_room_three_views_off() {
    let gains = [1.15, 1.0, 0.9, 1.0, 1.08, 1.0].map(|g| [g; 3]);
    gained_run(&gains, ViewGainMode::Exposure);
}

/// Rotation angle (degrees) between two camera-to-world matrices and the distance of their
/// origins.
fn pose_error(a: opal::math::DMat4, b: opal::math::DMat4) -> (f64, f64) {
    let r = a.inverse() * b;
    let tr = r.x_axis.x + r.y_axis.y + r.z_axis.z;
    (
        ((tr - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees(),
        (a.w_axis.truncate() - b.w_axis.truncate()).length(),
    )
}

/// Mean distance (px) between where `truth` and `cam` see the surface points of `truth`'s pixel
/// centres.
fn reprojection(scene: &Scene, truth: &opal::camera::Camera, cam: &opal::camera::Camera) -> f64 {
    let (mut sum, mut n) = (0.0, 0);
    for y in 0..truth.height {
        for x in 0..truth.width {
            let c = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
            let Some(si) = scene.intersect(&truth.generate_ray(c)) else { continue };
            let Some(q) = cam.project(si.p) else { continue };
            sum += (q - c).length() as f64;
            n += 1;
        }
    }
    sum / n.max(1) as f64
}

/// Issue 25's acceptance: every camera perturbed (0.15–0.3° about a random axis, ~1 px of
/// translation at the scene centre in a random direction; fixed seed), refined, judged at the
/// true cameras.
#[test]
#[ignore = "needs OPAL_ROOM_DIR (bench/scripts/room_multiview.py); 15–40 min"]
fn mitsuba_room_perturbed_poses() {
    use opal::math::DVec3;
    let (desc, truth) = load();
    let mode = match std::env::var("OPAL_REFINE_POSES").as_deref() {
        Ok("off") => PoseRefinement::Off,
        Ok("rotation") => PoseRefinement::Rotation,
        Ok("full") | Err(_) => PoseRefinement::Full,
        Ok(other) => panic!("OPAL_REFINE_POSES: unknown mode {other}"),
    };
    let scene = Scene::build(&desc).unwrap();
    let (lo, hi) = scene.bounds();
    let centre = (0.5 * (lo + hi)).as_dvec3();
    // splitmix64: a fixed, documented sequence
    // OPAL_POSE_SEED: another perturbation (default 0x5EED0025)
    let mut state = std::env::var("OPAL_POSE_SEED").ok().map_or(0x5EED_0025u64, |v| {
        u64::from_str_radix(v.trim_start_matches("0x"), 16).expect("OPAL_POSE_SEED: hex")
    });
    let mut rnd = move || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        (z ^ (z >> 31)) as f64 / u64::MAX as f64
    };
    let unit = |rnd: &mut dyn FnMut() -> f64| loop {
        let v = DVec3::new(2.0 * rnd() - 1.0, 2.0 * rnd() - 1.0, 2.0 * rnd() - 1.0);
        if v.length() > 0.1 && v.length() <= 1.0 {
            break v.normalize();
        }
    };
    // OPAL_POSE_AMOUNT: a multiple of the perturbation (0: the exact poses, refined all the same)
    let amount: f64 = std::env::var("OPAL_POSE_AMOUNT").map_or(1.0, |v| v.parse().expect("OPAL_POSE_AMOUNT"));
    let mut views = truth.clone();
    for v in &mut views {
        let m = v.camera.to_world.as_dmat4();
        let deg = amount * (0.15 + 0.15 * rnd());
        // one pixel at the scene centre's distance
        let px = 2.0 * v.camera.tan_half_x as f64 / v.camera.width as f64;
        let t = amount * (m.w_axis.truncate() - centre).length() * px;
        let (axis, dir) = (unit(&mut rnd), unit(&mut rnd));
        v.camera = camera_with(&v.camera, compose(m, axis * deg.to_radians(), dir * t));
        let (r, d) = pose_error(m, v.camera.to_world.as_dmat4());
        println!("perturbed {}: {r:.3}°, {d:.4} (1 px = {t:.4})", v.name);
    }
    // OPAL_POSE_PRIOR_PX=<px>|off and OPAL_POSE_PIVOT=scene|camera override those settings
    let mut poses = PoseSettings { mode, ..Default::default() };
    match std::env::var("OPAL_POSE_PRIOR_PX").as_deref() {
        Ok("off") => poses.prior_px = None,
        Ok(v) => poses.prior_px = Some(v.parse().expect("OPAL_POSE_PRIOR_PX: a number or off")),
        Err(_) => {}
    }
    match std::env::var("OPAL_POSE_PIVOT").as_deref() {
        Ok("scene") => poses.pivot_at_scene = true,
        Ok("camera") => poses.pivot_at_scene = false,
        Ok(other) => panic!("OPAL_POSE_PIVOT: unknown {other}"),
        Err(_) => {}
    }
    match std::env::var("OPAL_POSE_JOINT").as_deref() {
        Ok("on") => poses.joint = true,
        Ok("off") => poses.joint = false,
        Ok(other) => panic!("OPAL_POSE_JOINT: unknown {other}"),
        Err(_) => {}
    }
    if let Ok(v) = std::env::var("OPAL_POSE_ROUND_STEP_TOL") {
        poses.round_step_tolerance_px = v.parse().expect("OPAL_POSE_ROUND_STEP_TOL: pixels");
    }
    if let Ok(v) = std::env::var("OPAL_POSE_STEP_TOL") {
        poses.step_tolerance_px = v.parse().expect("OPAL_POSE_STEP_TOL: pixels");
    }
    if let Ok(v) = std::env::var("OPAL_POSE_FINE_MARGIN") {
        poses.fine_edge_margin = v.parse().expect("OPAL_POSE_FINE_MARGIN");
    }
    if let Ok(v) = std::env::var("OPAL_POSE_LINEAR_BANDS") {
        poses.linear_bands = v.parse().expect("OPAL_POSE_LINEAR_BANDS");
    }
    if let Ok(v) = std::env::var("OPAL_POSE_DELIGHT_MARGIN") {
        poses.delight_edge_margin = v.parse().expect("OPAL_POSE_DELIGHT_MARGIN");
    }
    if let Ok(v) = std::env::var("OPAL_POSE_FINE_SIGMAS") {
        poses.fine_sigmas = Some(v.split(',').map(|x| x.parse().expect("OPAL_POSE_FINE_SIGMAS")).collect());
    }
    if let Ok(v) = std::env::var("OPAL_POSE_ROUNDS") {
        poses.rounds = v.parse().expect("OPAL_POSE_ROUNDS");
    }
    println!(
        "pose settings: prior {:?} px, pivot at scene {}, joint {}",
        poses.prior_px, poses.pivot_at_scene, poses.joint
    );
    let s = DelightSettings { poses, ..settings(ViewGainMode::Fixed) };
    let r = delight(&desc, &views, &s, &|l| println!("{l}")).unwrap();
    if let Some(p) = &r.poses {
        for (k, vp) in p.views.iter().enumerate() {
            let t = truth[k].camera.to_world.as_dmat4();
            let (r0, d0) = pose_error(t, views[k].camera.to_world.as_dmat4());
            let (r1, d1) = pose_error(t, vp.to_world);
            let p0 = reprojection(&scene, &truth[k].camera, &views[k].camera);
            let p1 = reprojection(&scene, &truth[k].camera, &camera_with(&truth[k].camera, vp.to_world));
            println!(
                "pose {}: {r0:.3}° {d0:.4} → {r1:.4}° {d1:.4}, mean reprojection {p0:.3} → {p1:.3} px \
                 (accepted {}, rms {:.4} → {:.4}, steps per round {:.2?} px)",
                vp.view, vp.accepted, vp.rms_before, vp.rms_after, vp.round_steps_px
            );
        }
    }
    for (name, secs) in &r.timings {
        println!("stage {name}: {secs:.1} s");
    }
    println!("mode {} — judged at the true cameras:", mode.name());
    let (worst, psnr) = report(&r, &desc, &truth);
    if mode == PoseRefinement::Full {
        assert!(worst < 0.01, "acceptance: constant albedos within 1 %: worst {worst}");
        assert!(psnr >= 38.0, "acceptance: textures ≥ 38 dB: {psnr}");
    }
}
