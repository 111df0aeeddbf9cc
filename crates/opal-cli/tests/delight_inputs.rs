//! `opal delight` end to end on other inputs than `tests/delight.rs`' tiny run: views larger
//! than the working size (`--max-view-pixels`), a COLMAP model's photos read at the working
//! size, the default working size and the re-render noise, pose refinement's transforms and
//! corrections, and an interrupted run resumed to the same bytes (or a clear error without a
//! checkpoint).

#[path = "support/delight_run.rs"]
#[allow(dead_code)] // (each test binary uses some of the helpers)
mod run;

use run::{cbox, make_views, opal, tiny_run_sized, tiny_run_with, walk};
use std::path::{Path, PathBuf};

/// `--max-view-pixels`: 24² views limited to 144 pixels are read as 12² views (box-filtered,
/// same frustum, the reading's progress one step per view); the re-renders and the region
/// statistics follow the coarse views; report.json gives the working sizes and the memory per
/// stage.
#[test]
fn max_view_pixels_works_from_downsampled_views() {
    let tmp = tempfile::tempdir().unwrap();
    let (_, report) = tiny_run_with(tmp.path(), &cbox(), &["--max-view-pixels", "144"]);
    assert_eq!(report["settings"]["max_view_pixels"], 144);
    for s in report["view_sizes"].as_array().unwrap() {
        assert_eq!(s, &serde_json::json!([12, 12]));
    }
    for r in report["rerenders"].as_array().unwrap() {
        assert_eq!(r["size"], serde_json::json!([12, 12]));
    }
    assert_eq!(report["working_size"]["rule"], "setting");
    assert_eq!(report["photo_sizes"][0], serde_json::json!([24, 24]));
    // the photos as read: the mean of a coarse view is that of the full one (box filter)
    let (full, _) = opal_inverse::delight::views::read_views(&tmp.path().join("transforms.json")).unwrap();
    let calls: std::sync::Arc<std::sync::Mutex<Vec<(String, u64, u64)>>> = Default::default();
    let c = calls.clone();
    let progress =
        opal_inverse::delight::Progress::new(move |st, d, t| c.lock().unwrap().push((st.to_string(), d, t)));
    let (coarse, _) = opal_inverse::delight::views::read_views_limited(
        &tmp.path().join("transforms.json"),
        Some(144),
        Some(&progress),
    )
    .unwrap();
    // the progress of the reading: one step per view
    let n = coarse.len() as u64;
    let want: Vec<(String, u64, u64)> = (0..=n).map(|d| ("read views".to_string(), d, n)).collect();
    assert_eq!(*calls.lock().unwrap(), want);
    for (f, c) in full.iter().zip(&coarse) {
        let mean =
            |i: &opal::image::Image| i.data.iter().map(|p| p.0[1] as f64).sum::<f64>() / i.data.len() as f64;
        assert!((mean(&f.image) - mean(&c.image)).abs() <= 1e-5 * mean(&f.image).max(1e-3));
        assert_eq!((c.camera.width, c.camera.height), (12, 12));
    }
    // resident memory at each stage's end and the peak so far (from /proc/self/status)
    let mem = report["memory_mb"].as_object().unwrap();
    #[cfg(target_os = "linux")]
    for k in ["unwrap", "direct", "luminance", "total", "outputs_and_rerenders"] {
        let m = &mem[k];
        assert!(m["peak_so_far"].as_f64().unwrap() >= m["rss_at_end"].as_f64().unwrap(), "{k}: {m}");
    }
    assert!(mem.contains_key("total"));
}

/// A COLMAP text model of the tiny run's photos (`PINHOLE`, centred principal point, the model
/// in `DIR` and the photos in `DIR/images`): `--views DIR` takes the working size from the
/// model's cameras and box-filters each photo as it is read, so report.json has the same photo
/// and working sizes as with the transforms.json of the same photos, and the albedos agree
/// (the resampling onto the ideal pinhole is the identity here, up to rounding).
#[test]
fn colmap_views_are_read_at_the_working_size() {
    use glam::{DMat3, DQuat, DVec3};
    let tmp = tempfile::tempdir().unwrap();
    let (_, want) = tiny_run_with(tmp.path(), &cbox(), &["--max-view-pixels", "144"]);
    let model = tmp.path().join("model");
    std::fs::create_dir_all(model.join("images")).unwrap();
    let desc = opal::scene::load::load_mitsuba_xml(&cbox(), &[]).unwrap();
    let (mut cameras, mut images) = (String::new(), String::new());
    for (c, s) in desc.sensors.iter().take(3).enumerate() {
        let fx = 24.0 / (2.0 * (0.5 * (s.fov_x_deg as f64).to_radians()).tan());
        cameras += &format!("{} PINHOLE 24 24 {fx} {fx} 12 12\n", c + 1);
        // Mitsuba's to_world = [Rᵀ·diag(−1, −1, 1) | C], COLMAP's x_cam = R x_world + t
        let m = s.to_world.as_dmat4();
        let r = (DMat3::from_mat4(m) * DMat3::from_diagonal(DVec3::new(-1.0, -1.0, 1.0))).transpose();
        let t = -(r * m.w_axis.truncate());
        let q = DQuat::from_mat3(&r);
        images += &format!(
            "{} {} {} {} {} {} {} {} {} v{c}.exr\n\n",
            c + 1,
            q.w,
            q.x,
            q.y,
            q.z,
            t.x,
            t.y,
            t.z,
            c + 1
        );
        std::fs::copy(tmp.path().join(format!("v{c}.exr")), model.join(format!("images/v{c}.exr"))).unwrap();
    }
    std::fs::write(model.join("cameras.txt"), cameras).unwrap();
    std::fs::write(model.join("images.txt"), images).unwrap();
    let out = tmp.path().join("out_colmap");
    let o = opal(&[
        "delight",
        "--scene",
        cbox().to_str().unwrap(),
        "--views",
        model.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--resolution",
        "16",
        "--light-paths",
        "100000",
        "--iterations",
        "2",
        "--rerender-spp",
        "4",
        "--json",
        "--max-view-pixels",
        "144",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let got: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(got["working_size"]["rule"], "setting");
    assert_eq!(got["photo_sizes"], want["photo_sizes"]);
    assert_eq!(got["view_sizes"], want["view_sizes"]);
    assert_eq!(got["view_sizes"][0], serde_json::json!([12, 12]));
    for (a, b) in got["objects"].as_array().unwrap().iter().zip(want["objects"].as_array().unwrap()) {
        assert_eq!(a["id"], b["id"]);
        for c in 0..3 {
            let (x, y) =
                (a["mean_albedo_seen"][c].as_f64().unwrap(), b["mean_albedo_seen"][c].as_f64().unwrap());
            assert!((x - y).abs() <= 1e-3 * y.max(1e-3), "{}: {x} vs {y}", a["id"]);
        }
    }
}

/// The defaults: no `--max-view-pixels` gives the automatic working size (views of 32² are
/// below its floor of 256² pixels: kept as they are, with the reason and the texel estimate in
/// report.json); `--max-view-pixels 0` keeps the photos on request. The re-render samples
/// follow `--rerender-noise`: a view whose noisiest judged region is above the target after
/// `--rerender-spp` gets more samples (at most 16×) and a lower noise; 0 keeps the given count.
#[test]
fn default_working_size_and_rerender_noise() {
    let tmp = tempfile::tempdir().unwrap();
    let (_, report) = tiny_run_sized(tmp.path(), &cbox(), &["--rerender-noise", "0.01"], 32);
    let w = &report["working_size"];
    assert_eq!(w["rule"], "auto");
    assert_eq!(w["reason"], "min_working_pixels");
    assert!(w["max_view_pixels"].is_null());
    assert!(w["texels_estimated_full_size"].as_f64().unwrap() > 0.0);
    assert_eq!(w["texels_estimated_full_size"], w["texels_estimated_working_size"]);
    assert!(report["settings"]["max_view_pixels"].is_null());
    assert_eq!(report["view_sizes"], report["photo_sizes"]);
    let mut raised = 0;
    for r in report["rerenders"].as_array().unwrap() {
        let (spp, first, now) = (
            r["spp"].as_u64().unwrap(),
            r["max_region_rel_stderr_at_first_spp"].as_f64().unwrap(),
            r["max_region_rel_stderr"].as_f64().unwrap(),
        );
        assert!((4..=64).contains(&spp), "{spp}");
        if first > 0.01 {
            // noise ∝ 1/√spp: the target is reached unless the 16× cap stops it
            raised += 1;
            assert!(spp > 4 && now < first, "{spp}: {first} → {now}");
            assert!(now <= 0.01 * 1.5 || spp == 64, "{spp}: {now}");
        } else {
            assert_eq!(spp, 4);
        }
    }
    assert!(raised > 0, "4 spp on 32² views: some region above 1 %");
    let tmp = tempfile::tempdir().unwrap();
    let (_, report) =
        tiny_run_with(tmp.path(), &cbox(), &["--max-view-pixels", "0", "--rerender-noise", "0"]);
    assert_eq!(report["working_size"]["rule"], "full_size_on_request");
    assert_eq!(report["settings"]["max_view_pixels"], 0);
    for r in report["rerenders"].as_array().unwrap() {
        assert_eq!(r["spp"], 4);
    }
}

/// `--refine-poses full`: report.json lists the per-view corrections and OUTPUT/transforms.json
/// holds the poses (readable as views again). The tiny 24² views have too few pixels for an
/// alignment (< 500), so every correction is rejected, flagged and the given poses are kept.
#[test]
fn refine_poses_writes_transforms_and_corrections() {
    let tmp = tempfile::tempdir().unwrap();
    let (out, report) = tiny_run_with(tmp.path(), &cbox(), &["--refine-poses", "full"]);
    let poses = &report["poses"];
    assert_eq!(poses["mode"], "full");
    let v = poses["views"].as_array().unwrap();
    assert_eq!(v.len(), 3);
    for p in v {
        for k in ["rotation_deg", "translation", "angle_deg", "accepted", "used", "rms_before", "reason"] {
            assert!(p.get(k).is_some(), "{k} missing in {p}");
        }
    }
    let (views, _) = opal_inverse::delight::views::read_views(&out.join("transforms.json")).unwrap();
    assert_eq!(views.len(), 3);
    let (given, _) = opal_inverse::delight::views::read_views(&tmp.path().join("transforms.json")).unwrap();
    for (a, b) in views.iter().zip(&given) {
        let accepted = v.iter().any(|p| p["view"] == a.name.as_str() && p["accepted"] == true);
        if !accepted {
            assert!(a.camera.to_world.abs_diff_eq(b.camera.to_world, 1e-5));
        }
    }
    let o = opal(&[
        "delight",
        "--scene",
        cbox().to_str().unwrap(),
        "--views",
        "x.json",
        "-o",
        "y",
        "--refine-poses",
        "maybe",
    ]);
    assert_eq!(o.status.code(), Some(2));
}

/// Ctrl-C during `opal delight`: the run stops after its current iteration with exit code 130,
/// keeps the finished iterations in OUT/checkpoint and writes no result; `opal delight --resume
/// OUT` continues it (interrupted again here), and the same command with `--resume` finishes it
/// with the same output images, byte for byte, as an uninterrupted run, and removes the
/// checkpoint.
#[cfg(unix)]
#[test]
fn interrupted_delight_resumes_to_the_same_bytes() {
    use std::io::{BufRead, BufReader};
    use std::process::{Command, Stdio};
    let tmp = tempfile::tempdir().unwrap();
    let tj = make_views(tmp.path(), 3, 24);
    let args = |out: &Path| -> Vec<String> {
        let mut a: Vec<String> = ["delight", "--scene"].map(String::from).to_vec();
        a.push(cbox().display().to_string());
        a.extend(["--views".to_string(), tj.display().to_string(), "-o".into(), out.display().to_string()]);
        a.extend(
            [
                "--resolution",
                "16",
                "--light-paths",
                "1500000",
                "--iterations",
                "4",
                "--rerender-spp",
                "4",
                "--tolerance",
                "0",
            ]
            .map(String::from),
        );
        a
    };
    let whole = tmp.path().join("whole");
    let o = opal(&args(&whole).iter().map(String::as_str).collect::<Vec<_>>());
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    // runs `args` and sends SIGINT once the log shows a finished iteration; returns the log
    let interrupt = |args: &[String]| -> String {
        let mut child = Command::new(env!("CARGO_BIN_EXE_opal"))
            .args(args)
            .stderr(Stdio::piped())
            .stdout(Stdio::null())
            .spawn()
            .unwrap();
        let mut log = String::new();
        for line in BufReader::new(child.stderr.take().unwrap()).lines() {
            let line = line.unwrap();
            if line.starts_with("iteration ")
                && line.contains("max rel. error")
                && !log.contains("max rel. error")
            {
                let k = Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap();
                assert!(k.success());
            }
            log.push_str(&line);
            log.push('\n');
        }
        let st = child.wait().unwrap();
        assert_eq!(st.code(), Some(130), "{log}");
        log
    };
    let out = tmp.path().join("out");
    let log = interrupt(&args(&out));
    assert!(log.contains("kept in") && log.contains("--resume"), "{log}");
    assert!(out.join("checkpoint/state.json").exists());
    assert!(out.join("checkpoint/args.json").exists());
    assert!(!out.join("report.json").exists(), "no result after an interruption");

    // the short form, `--resume OUTDIR` alone, interrupted again after its first iteration
    let log = interrupt(&["delight".to_string(), "--resume".into(), out.display().to_string()]);
    assert!(log.contains("resuming after iteration"), "{log}");
    assert!(!out.join("report.json").exists(), "no result after an interruption");

    // the long form: the run's own arguments plus --resume
    let mut a = args(&out);
    a.push("--resume".into());
    let o = opal(&a.iter().map(String::as_str).collect::<Vec<_>>());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("resuming after iteration"), "{err}");
    assert!(!out.join("checkpoint").exists(), "the checkpoint is removed once the run finished");
    let images = |d: &Path| -> Vec<(PathBuf, Vec<u8>)> {
        let mut v: Vec<_> = walk(d)
            .into_iter()
            .filter(|p| p.extension().is_some_and(|e| e == "exr" || e == "png"))
            .map(|p| (p.strip_prefix(d).unwrap().to_path_buf(), std::fs::read(&p).unwrap()))
            .collect();
        v.sort();
        v
    };
    let (a, b) = (images(&whole), images(&out));
    assert!(a.len() >= 5, "{} images", a.len());
    assert_eq!(a.iter().map(|x| &x.0).collect::<Vec<_>>(), b.iter().map(|x| &x.0).collect::<Vec<_>>());
    for (x, y) in a.iter().zip(&b) {
        assert!(x.1 == y.1, "{} differs after the resume", x.0.display());
    }
}

/// `opal delight --resume DIR` where DIR holds no checkpoint: a clear error, exit code 2.
#[test]
fn resume_without_a_checkpoint_is_a_clear_error() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().display().to_string();
    let o = opal(&["delight", "--resume", &dir]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("cannot resume from") && err.contains("args.json"), "{err}");
}
