//! `opal delight` end to end through the binary: a tiny happy path (outputs exist, `--json`
//! key sets as documented, the albedos equal to the library's on the same views and settings,
//! the written scene.xml loads in Opal with the recovered texels), view gains in report.json,
//! the glTF and report images checked by their validators, the Mitsuba acceptance, and bad
//! input (exit 2, message naming the problem, no output written). The runs on other inputs
//! (downsampled and COLMAP views, pose refinement, resumed runs): `tests/delight_inputs.rs`.

mod common;

#[path = "support/outputs.rs"]
mod outputs;

#[path = "support/delight_run.rs"]
#[allow(dead_code)] // (each test binary uses some of the helpers)
mod run;

use opal::scene::Scene;
use outputs::{check_glb, check_report_images};
use run::{cbox, make_views, make_views_with_gains, opal, tiny_run, tiny_run_sized, tiny_run_with, walk};
use std::path::{Path, PathBuf};
use std::process::Command;

#[test]
fn tiny_run_writes_everything_and_scene_loads() {
    let tmp = tempfile::tempdir().unwrap();
    let (out, report) = tiny_run_sized(tmp.path(), &cbox(), &[], 32);
    let tj = tmp.path().join("transforms.json");
    // --json prints report.json: the key sets documented in docs/delight.md
    let keys = [
        "scene",
        "views",
        "n_views",
        "settings",
        "view_gains",
        "poses",
        "converged",
        "iterations",
        "objects",
        "skipped",
        "not_recovered",
        "warnings",
        "regions",
        "max_region_rel_error_luminance",
        "rerenders",
        "contact_edges",
        "light_paths_total",
        "timings_seconds",
        "cpu_seconds",
        "memory_mb",
        "view_sizes",
        "photo_sizes",
        "working_size",
        "outputs",
        "view_error_range",
        "texel_error_range",
    ];
    common::assert_keys("delight --json", &report, &keys, "delight.md");
    let obj_keys = [
        "id",
        "resolution",
        "resolution_rule",
        "resolution_from_cameras_unclamped",
        "pixel_density_best_seen",
        "texel_density_best_seen",
        "seen_area_fraction",
        "charts",
        "kept_uvs",
        "seen_fraction",
        "seen_by_a_view",
        "recovered_from_inpainting_only",
        "near_emitter_median_filter",
        "mean_albedo_seen",
        "mean_albedo",
        "clamped_texel_channels",
        "superres",
        "unseen_light",
        "texture",
        "mesh",
        "last_error_map",
    ];
    let sr_keys = [
        "reweightings",
        "cg_steps",
        "residual_to_noise",
        "relative_residual",
        "converged",
        "photo_noise",
        "prior_weight",
    ];
    for o in report["objects"].as_array().unwrap() {
        common::assert_keys("delight --json object", o, &obj_keys, "delight.md");
        if !o["superres"].is_null() {
            common::assert_keys("delight --json object superres", &o["superres"], &sr_keys, "delight.md");
        }
    }
    let written: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(written, report);
    assert_eq!(report["iterations"].as_array().unwrap().len(), 2);
    let it_keys = [
        "iteration",
        "max_rel_error",
        "mean_rel_error",
        "per_object",
        "tracer_direct_over_light_sampled_direct",
        "seconds",
        "light_paths",
        "texel_noise",
        "texel_noise_per_object",
        "comm_seconds",
        "change_max",
        "change_beyond_noise",
        "change_regions",
    ];
    for it in report["iterations"].as_array().unwrap() {
        common::assert_keys("delight --json iteration", it, &it_keys, "delight.md");
        // the achieved per-texel noise of the pass is measured (a number in (0, 10))
        let noise = it["texel_noise"].as_f64().expect("texel_noise measured");
        assert!(noise > 0.0 && noise < 10.0, "{noise}");
    }
    for f in [
        "scene.xml",
        "scene.glb",
        "report.json",
        "report.html",
        "convergence.png",
        "albedo/floor.exr",
        "albedo/floor.png",
        "meshes/tall_box.obj",
        "errors/iter_01_floor.png",
        "errors/iter_02_floor.exr",
        "rerender/v0.exr",
        "photo/v0.png",
    ] {
        assert!(out.join(f).exists(), "{f} missing");
    }
    assert!(!report["regions"].as_array().unwrap().is_empty());
    // The CLI adds no estimator of its own: the library run on the same views with the same
    // settings (the CLI's defaults are the library's) gives the same albedos (the run is
    // deterministic for a seed; the only slack is serde_json's default float parser, which may
    // be 1 ulp off when reading the printed value back). The accuracy of
    // the estimator is the library tests' job (crates/opal-inverse/tests/delight.rs); a CLI
    // that passed a wrong setting, mixed up objects or channels would differ here.
    let desc = opal::scene::load::load_mitsuba_xml(&cbox(), &[]).unwrap();
    let (views, _) = opal_inverse::delight::views::read_views(&tj).unwrap();
    let s = opal_inverse::delight::DelightSettings {
        resolution: Some(16),
        light_paths: opal_inverse::delight::LightPaths::Fixed(100_000),
        iterations: 2,
        ..Default::default()
    };
    let lib = opal_inverse::delight::delight(&desc, &views, &s, &|_| {}).unwrap();
    let objs = report["objects"].as_array().unwrap();
    assert_eq!(objs.len(), lib.objects.len());
    for o in &lib.objects {
        let j = objs.iter().find(|j| j["id"] == o.id.as_str()).unwrap();
        let m = o.mean_kd_observed();
        for c in 0..3 {
            let got = j["mean_albedo_seen"][c].as_f64().unwrap();
            assert!(
                (got - m[c]).abs() <= 2.0 * f64::EPSILON * m[c].abs(),
                "{} channel {c}: {got} vs {}",
                o.id,
                m[c]
            );
        }
    }
    // the written scene loads in Opal and its floor texture holds the recovered texels
    // (bilinear lookups at texel centres return the texel; row y at v = (y + ½)/h)
    let written = opal::scene::load::load_mitsuba_xml(&out.join("scene.xml"), &[]).unwrap();
    let scene = Scene::build(&written).unwrap();
    let floor = scene.shapes.iter().position(|s| s.id == "floor").unwrap();
    let exr = opal::image::read::read_image(&out.join("albedo/floor.exr")).unwrap();
    let lo = lib.objects.iter().find(|o| o.id == "floor").unwrap().kd_image();
    assert_eq!((exr.width, exr.height), (16, 16));
    for (x, y) in [(0, 0), (7, 8), (15, 3), (12, 15)] {
        let uv = opal::math::Vec2::new((x as f32 + 0.5) / 16.0, (y as f32 + 0.5) / 16.0);
        let a = scene.diffuse_albedo(floor as u32, uv).unwrap();
        for c in 0..3 {
            assert!(
                (a[c] - exr.get(x, y)[c]).abs() <= 1e-6,
                "texel ({x}, {y}): {a:?} vs {:?}",
                exr.get(x, y)
            );
            assert_eq!(exr.get(x, y)[c], lo.get(x, y)[c], "texel ({x}, {y})");
        }
    }
    // no temporary files left
    let tmp_left = walk(&out)
        .into_iter()
        .filter(|p| p.file_name().unwrap().to_string_lossy().starts_with(".opal-tmp"))
        .count();
    assert_eq!(tmp_left, 0);
    check_glb(&out, &report);
    check_report_images(&out, &report);
}

/// `--view-gains exposure+wb` on views multiplied by known gains: report.json lists the gains
/// (close to the truth, median view exact) with their uncertainty, and flags the view that is off
/// by 2× with a warning; `--view-gains` with an unknown mode is rejected.
#[test]
fn view_gains_in_report() {
    let tmp = tempfile::tempdir().unwrap();
    // the median view (per channel, of 5) is exact: two views below it, two above; view 4 is
    // off by 2×
    let truth = [[0.9, 0.88, 0.93], [1.0, 1.0, 1.0], [0.96, 0.95, 0.97], [1.1, 1.15, 1.08], [2.0, 2.0, 2.0]];
    let tj = make_views_with_gains(tmp.path(), &truth, 48, 256);
    let out = tmp.path().join("out");
    let args = |mode: &str| {
        vec![
            "delight".to_string(),
            "--scene".into(),
            cbox().to_str().unwrap().into(),
            "--views".into(),
            tj.to_str().unwrap().into(),
            "-o".into(),
            out.to_str().unwrap().into(),
            "--resolution".into(),
            "32".into(),
            "--light-paths".into(),
            "100000".into(),
            "--iterations".into(),
            "1".into(),
            "--rerender-spp".into(),
            "0".into(),
            "--view-gains".into(),
            mode.into(),
            "--json".into(),
        ]
    };
    // --quiet: no progress messages, the warnings still on stderr
    let mut a = args("exposure+wb");
    a.push("--quiet".into());
    let o = opal(&a.iter().map(String::as_str).collect::<Vec<_>>());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(!err.contains("iteration 1") && !err.contains("luminance "), "{err}");
    // on a pipe with --quiet: the warnings and nothing else (no progress bar either)
    assert!(err.lines().all(|l| l.starts_with("warning: ")), "{err}");
    assert!(err.lines().any(|l| l.starts_with("warning: ") && l.contains("'v4'")), "{err}");
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let g = &report["view_gains"];
    assert_eq!(g["mode"], "exposure+wb");
    let views = g["views"].as_array().unwrap();
    assert_eq!(views.len(), truth.len());
    for (v, t) in views.iter().zip(&truth) {
        for c in 0..3 {
            let est = v["gain"][c].as_f64().unwrap();
            let se = v["std_err"][c].as_f64().unwrap();
            println!(
                "{} channel {c}: gain {est:.4} true {} error {:+.3} % σ {:.3} %",
                v["view"],
                t[c],
                100.0 * (est / t[c] as f64 - 1.0),
                100.0 * se / est
            );
            // 48-pixel views at 256 spp: measured ≤ 0.63 % (mostly systematic: pixel footprints
            // of 48-pixel views; 0.08 % on the 256-pixel reference views); at 32 spp the skewed
            // Monte-Carlo noise of the photos gave up to 1.7 %
            assert!((est / t[c] as f64 - 1.0).abs() < 0.01, "{v}: {est} vs {}", t[c]);
            assert!(se > 0.0 && se < 0.01, "{v}");
        }
        assert_eq!(v["far_from_others"].as_bool(), Some(t[0] == 2.0), "{v}");
    }
    let warnings: Vec<&str> =
        report["warnings"].as_array().unwrap().iter().filter_map(|w| w.as_str()).collect();
    assert!(warnings.iter().any(|w| w.contains("'v4'") && w.contains("median view")), "{warnings:?}");
    // fixed: no gains in the report
    std::fs::remove_dir_all(&out).unwrap();
    let a = args("fixed");
    let o = opal(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(report["view_gains"].is_null());
    // unknown mode
    std::fs::remove_dir_all(&out).unwrap();
    let a = args("auto");
    let o = opal(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(o.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("--view-gains"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// The Khronos glTF validator (npm package `gltf-validator`, pinned version) accepts the
/// `scene.glb` of a tiny run with 0 errors. Ignored: needs node and npm (installs the package
/// into `$OPAL_GLTF_VALIDATOR_DIR`, default the system temporary folder's
/// `opal-gltf-validator`, on first use): `cargo test -p opal-cli --test delight gltf_validator --
/// --ignored --nocapture` (docs/testing.md).
#[test]
#[ignore = "needs node + npm (installs gltf-validator)"]
fn gltf_validator_accepts_scene_glb() {
    let dir = std::env::var_os("OPAL_GLTF_VALIDATOR_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| std::env::temp_dir().join("opal-gltf-validator"));
    if !dir.join("node_modules/gltf-validator/package.json").exists() {
        std::fs::create_dir_all(&dir).unwrap();
        let o = Command::new("npm")
            .args(["install", "--no-audit", "--no-fund", "--prefix"])
            .arg(&dir)
            .arg("gltf-validator@2.0.0-dev.3.10")
            .output()
            .expect("npm");
        assert!(o.status.success(), "npm install: {}", String::from_utf8_lossy(&o.stderr));
    }
    // the test box with vertex normals (no `face_normals`) and every object unwrapped by Opal,
    // so that NORMAL and the atlas's split vertices are validated too
    let tmp = tempfile::tempdir().unwrap();
    let data = cbox().parent().unwrap().to_path_buf();
    let xml = std::fs::read_to_string(cbox())
        .unwrap()
        .replace("<boolean name=\"face_normals\" value=\"true\"/>", "")
        .replace("value=\"meshes/", &format!("value=\"{}/meshes/", data.display()))
        .replace("value=\"textures/", &format!("value=\"{}/textures/", data.display()));
    let scene = tmp.path().join("scene_normals.xml");
    std::fs::write(&scene, xml).unwrap();
    let (out, report) = tiny_run_with(tmp.path(), &scene, &["--unwrap-all"]);
    check_glb(&out, &report);
    let glb = std::fs::read(out.join("scene.glb")).unwrap();
    let (doc, _) = outputs::parse_glb(&glb);
    let with_normals = doc["meshes"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|m| m["primitives"][0]["attributes"].get("NORMAL").is_some())
        .count();
    let charts: u64 =
        report["objects"].as_array().unwrap().iter().map(|o| o["charts"].as_u64().unwrap()).sum();
    println!(
        "{} meshes, {with_normals} with normals, {charts} charts",
        doc["meshes"].as_array().unwrap().len()
    );
    assert!(with_normals > 0);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/support/gltf_validate.js");
    let o = Command::new("node")
        .arg(&script)
        .arg(out.join("scene.glb"))
        .env("NODE_PATH", dir.join("node_modules"))
        .output()
        .expect("node");
    let text = String::from_utf8_lossy(&o.stdout);
    let report: serde_json::Value = serde_json::from_str(&text)
        .unwrap_or_else(|e| panic!("{e}: {text} {}", String::from_utf8_lossy(&o.stderr)));
    let issues = &report["issues"];
    println!(
        "gltf-validator {}: {} errors, {} warnings, {} infos, {} hints; messages: {}",
        report["validatorVersion"],
        issues["numErrors"],
        issues["numWarnings"],
        issues["numInfos"],
        issues["numHints"],
        issues["messages"]
    );
    assert_eq!(issues["numErrors"], 0, "{}", issues["messages"]);
    assert!(o.status.success());
}

/// report.html opened in headless Chromium (Debian `chromium`; `$CHROMIUM` to use another
/// binary) with every host name unresolvable: every `<img>` loaded (`complete`, positive
/// natural width). A copy of the page with a script that lists the broken images is dumped with
/// `--dump-dom`. Ignored: needs Chromium: `cargo test -p opal-cli --test delight report_images
/// -- --ignored --nocapture` (docs/testing.md).
#[test]
#[ignore = "needs chromium"]
fn report_images_load_in_chromium() {
    let tmp = tempfile::tempdir().unwrap();
    let (out, report) = tiny_run(tmp.path());
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    let probe = "<script>window.addEventListener('load', () => { const all = [...document.images]; \
        const bad = all.filter(i => !i.complete || i.naturalWidth === 0).map(i => i.getAttribute('src')); \
        const p = document.createElement('pre'); p.id = 'img-check'; \
        p.textContent = 'IMGCHECK ' + all.length + ' ' + JSON.stringify(bad); document.body.appendChild(p); });</script>";
    let page = out.join("report_check.html");
    std::fs::write(&page, html.replace("</body>", &format!("{probe}</body>"))).unwrap();
    let chromium = std::env::var("CHROMIUM").unwrap_or_else(|_| "chromium".into());
    let o = Command::new(&chromium)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--host-resolver-rules=MAP * ~NOTFOUND",
            "--dump-dom",
        ])
        .arg(format!("file://{}", page.display()))
        .output()
        .unwrap_or_else(|e| panic!("{chromium}: {e}"));
    let dom = String::from_utf8_lossy(&o.stdout);
    let line =
        dom.lines().find_map(|l| l.split("<pre id=\"img-check\">IMGCHECK ").nth(1)).unwrap_or_else(|| {
            panic!("no image check in the dumped page: {}", String::from_utf8_lossy(&o.stderr))
        });
    let (n, bad) = line.split_once(' ').unwrap();
    let n: usize = n.parse().unwrap();
    let bad = bad.split("</pre>").next().unwrap();
    println!("chromium: {n} images, not loaded: {bad}");
    assert_eq!(n, outputs::img_tags(&html).len());
    assert!(n >= 3 * report["rerenders"].as_array().unwrap().len());
    assert_eq!(bad, "[]", "images that did not load");
}

#[test]
fn bad_input_exits_2_without_output() {
    let tmp = tempfile::tempdir().unwrap();
    let tj = make_views(tmp.path(), 1, 8);
    let out = tmp.path().join("out");
    let run = |scene: &Path, views: &Path| {
        opal(&[
            "delight",
            "--scene",
            scene.to_str().unwrap(),
            "--views",
            views.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--resolution",
            "8",
            "--light-paths",
            "1000",
            "--iterations",
            "1",
            "--rerender-spp",
            "0",
        ])
    };
    // missing image
    let text = std::fs::read_to_string(&tj).unwrap();
    let missing = tmp.path().join("missing.json");
    std::fs::write(&missing, text.replace("v0.exr", "nope.exr")).unwrap();
    let o = run(&cbox(), &missing);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("nope.exr"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    // wrong size
    let wrong = tmp.path().join("wrong.json");
    std::fs::write(&wrong, text.replace("\"w\":8", "\"w\":9")).unwrap();
    let o = run(&cbox(), &wrong);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("8×8"), "{}", String::from_utf8_lossy(&o.stderr));
    // no emitters
    let xml = std::fs::read_to_string(cbox()).unwrap();
    let i = xml.find("<emitter type=\"area\">").unwrap();
    let j = xml[i..].find("</emitter>").unwrap() + i + "</emitter>".len();
    let dark = cbox().parent().unwrap().join(format!(".dark_{}.xml", std::process::id()));
    std::fs::write(&dark, format!("{}{}", &xml[..i], &xml[j..])).unwrap();
    let o = run(&dark, &tj);
    std::fs::remove_file(&dark).unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("emitter"), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(!out.exists() || walk(&out).is_empty(), "no output on bad input");
}

/// Acceptance on the independent Mitsuba 3 data with the CLI defaults (one configuration for
/// every goal; ignored: a few minutes on a shared 2-core machine; re-renders at the default
/// 64 spp: at 32 spp the smallest region's Monte-Carlo noise was ±1.2 %, too close to the 1.8 %
/// goal to tell):
/// `OPAL_CBOX_DIR=<shared>/reference/mitsuba/cbox cargo test -p opal-cli --test delight
/// acceptance -- --ignored --nocapture`; set `OPAL_DELIGHT_OUT=DIR` to evaluate an existing
/// output folder instead of running. Checks: mean albedo of every constant-colour object within
/// 1 % (per channel, texels seen), back-wall PSNR ≥ 38 dB where seen, max region error ≤ 1.8 %.
#[test]
#[ignore = "needs OPAL_CBOX_DIR; slow"]
fn acceptance_mitsuba_cbox() {
    let dir = PathBuf::from(std::env::var("OPAL_CBOX_DIR").expect("OPAL_CBOX_DIR"));
    let out = match std::env::var("OPAL_DELIGHT_OUT") {
        Ok(o) => PathBuf::from(o),
        Err(_) => {
            let tmp = tempfile::tempdir().unwrap().keep();
            let o = opal(&[
                "delight",
                "--scene",
                dir.join("scene.xml").to_str().unwrap(),
                "--views",
                dir.join("transforms.json").to_str().unwrap(),
                "-o",
                tmp.to_str().unwrap(),
            ]);
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
            tmp
        }
    };
    let report: Option<serde_json::Value> =
        std::fs::read_to_string(out.join("report.json")).ok().map(|t| serde_json::from_str(&t).unwrap());
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("scene.json")).unwrap()).unwrap();
    let its = (1..100).take_while(|k| out.join(format!("errors/iter_{k:02}_floor.exr")).exists()).count();
    let mut worst = 0f64;
    for t in truth["objects"].as_array().unwrap() {
        let Some(alb) = t["albedo_rgb"].as_array() else { continue };
        if t.get("emitter").is_some() {
            continue;
        }
        let id = t["name"].as_str().unwrap();
        // mean of the recovered texture over the texels seen by a view (the last error map is
        // NaN elsewhere); the atlases have uniform texel density, so a plain mean is area-weighted
        let kd = opal::image::read::read_image(&out.join(format!("albedo/{id}.exr"))).unwrap();
        let err = opal::image::read::read_image(&out.join(format!("errors/iter_{its:02}_{id}.exr"))).unwrap();
        let mut m = [0f64; 3];
        let mut n = 0f64;
        for (k, e) in kd.data.iter().zip(&err.data) {
            if e[0].is_finite() {
                for c in 0..3 {
                    m[c] += k[c] as f64;
                }
                n += 1.0;
            }
        }
        let rel: Vec<f64> = (0..3).map(|c| m[c] / n / alb[c].as_f64().unwrap() - 1.0).collect();
        println!(
            "{id:18} rel error {:+.2} % {:+.2} % {:+.2} %",
            100.0 * rel[0],
            100.0 * rel[1],
            100.0 * rel[2]
        );
        worst = rel.iter().fold(worst, |a, b| a.max(b.abs()));
    }
    // back wall PSNR where seen (error maps are NaN where no view saw the texel)
    let kd = opal::image::read::read_image(&out.join("albedo/back_wall.exr")).unwrap();
    let err =
        opal::image::read::read_image(&out.join(format!("errors/iter_{its:02}_back_wall.exr"))).unwrap();
    let tex = opal::image::read::read_image(&dir.join("textures/backwall_albedo.exr")).unwrap();
    let bmp = opal::scene::desc::BitmapDesc {
        image: std::sync::Arc::new(kd.clone()),
        filter: opal::scene::desc::FilterType::Bilinear,
        wrap: opal::scene::desc::WrapMode::Clamp,
        path: "kd".into(),
    };
    let (mut se, mut n) = (0f64, 0usize);
    for y in 0..tex.height {
        for x in 0..tex.width {
            let uv = opal::math::Vec2::new(
                (x as f32 + 0.5) / tex.width as f32,
                (y as f32 + 0.5) / tex.height as f32,
            );
            let (ex, ey) = (
                ((uv.x * err.width as f32) as usize).min(err.width - 1),
                ((uv.y * err.height as f32) as usize).min(err.height - 1),
            );
            if !err.get(ex, ey)[0].is_finite() {
                continue;
            }
            let g = bmp.eval(uv);
            let t = tex.get(x, y);
            for c in 0..3 {
                se += ((g[c] - t[c]) as f64).powi(2);
            }
            n += 3;
        }
    }
    let psnr = 10.0 * (1.0 / (se / n as f64)).log10();
    let region = report.as_ref().map_or(f64::NAN, |r| r["max_region_rel_error_luminance"].as_f64().unwrap());
    println!(
        "worst albedo error {:.2} %, back wall PSNR {psnr:.2} dB ({} texels), max region error {:.2} %, iterations {its}",
        100.0 * worst,
        n / 3,
        100.0 * region
    );
    assert!(worst <= 0.01, "albedo within 1 %: {worst}");
    assert!(psnr >= 38.0, "PSNR {psnr}");
    assert!(region <= 0.018, "region error {region} (NaN: no report.json)");
}
