//! Helpers of the `opal delight` tests (`tests/delight.rs`, `tests/delight_inputs.rs`): views
//! of the test Cornell box rendered by Opal with a transforms.json, the `opal` binary, a tiny
//! de-lighting run and a folder walk.

use opal::integrator::path::{PathSettings, render};
use opal::scene::Scene;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The test Cornell box's scene.xml.
pub fn cbox() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../opal/tests/data/cbox/scene.xml")
}

/// Renders `n` views of the test Cornell box at `res`² with Opal and writes them with a
/// transforms.json into `dir`.
pub fn make_views(dir: &Path, n: usize, res: usize) -> PathBuf {
    make_views_with_gains(dir, &vec![[1.0; 3]; n], res, 32)
}

/// As [`make_views`], one view per entry of `gains`, each image multiplied by its gains, at `spp`
/// samples per pixel.
pub fn make_views_with_gains(dir: &Path, gains: &[[f32; 3]], res: usize, spp: u32) -> PathBuf {
    let n = gains.len();
    let mut desc = opal::scene::load::load_mitsuba_xml(&cbox(), &[]).unwrap();
    desc.sensors.truncate(n);
    for s in &mut desc.sensors {
        s.width = res;
        s.height = res;
    }
    let scene = Scene::build(&desc).unwrap();
    let ps = PathSettings { spp, max_depth: -1, rr_depth: 5, hide_emitters: false, seed: 3 };
    let mut frames = Vec::new();
    for (c, s) in desc.sensors.iter().enumerate() {
        let mut img = render(&scene, c, &ps, &|| {}).image;
        for p in &mut img.data {
            for (x, f) in p.0.iter_mut().zip(&gains[c]) {
                *x *= f;
            }
        }
        let name = format!("v{c}.exr");
        let f = std::fs::File::create(dir.join(&name)).unwrap();
        opal::image::write::write_exr(&img, std::io::BufWriter::new(f)).unwrap();
        let gl = s.to_world * opal::math::Mat4::from_scale(opal::math::Vec3::new(-1.0, 1.0, -1.0));
        let rows: Vec<Vec<f32>> = (0..4).map(|r| (0..4).map(|c| gl.col(c)[r]).collect()).collect();
        frames.push(serde_json::json!({"file_path": name, "transform_matrix": rows, "camera_angle_x": s.fov_x_deg.to_radians(), "w": res, "h": res}));
    }
    let tj = dir.join("transforms.json");
    std::fs::write(&tj, serde_json::to_string(&serde_json::json!({"frames": frames})).unwrap()).unwrap();
    tj
}

pub fn opal(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_opal")).args(args).output().unwrap()
}

/// Runs a tiny de-lighting (3 views of 24², 16² textures, 2 iterations) of the test Cornell box
/// into `dir/out`; returns the output folder and report.json.
pub fn tiny_run(dir: &Path) -> (PathBuf, serde_json::Value) {
    tiny_run_with(dir, &cbox(), &[])
}

/// As [`tiny_run`] on `scene` with `extra` arguments.
pub fn tiny_run_with(dir: &Path, scene: &Path, extra: &[&str]) -> (PathBuf, serde_json::Value) {
    tiny_run_sized(dir, scene, extra, 24)
}

/// As [`tiny_run_with`] with views of `res`² (the report judges regions of ≥ 64 pixels whose
/// 8 neighbours are in the region: 24² views of the box have none).
pub fn tiny_run_sized(dir: &Path, scene: &Path, extra: &[&str], res: usize) -> (PathBuf, serde_json::Value) {
    let tj = make_views(dir, 3, res);
    let out = dir.join("out");
    let mut args = vec![
        "delight",
        "--scene",
        scene.to_str().unwrap(),
        "--views",
        tj.to_str().unwrap(),
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
    ];
    args.extend_from_slice(extra);
    let o = opal(&args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    // stderr is a pipe here: the stages' progress bars are hidden (log lines only)
    assert!(!err.contains("(eta ") && !err.contains('\r'), "{err}");
    (out, serde_json::from_slice(&o.stdout).unwrap())
}

/// Every file below `d`, recursively.
pub fn walk(d: &Path) -> Vec<PathBuf> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(d).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            v.extend(walk(&p));
        } else {
            v.push(p);
        }
    }
    v
}
