//! The MPI tier (built only with `--features mpi`; `.ci/run` runs it after installing Open MPI):
//! the real binary under `mpirun --allow-run-as-root --oversubscribe -np N` (one thread per
//! rank) writes the same bytes as a run without MPI, for `render`, `gonio simulate`,
//! `fit-ndf` and `delight` (on views of the shared Cornell box), with 1, 2 and 3 ranks.
//!
//! The run without MPI is the binary named by `OPAL_REFERENCE_BIN` (a build without the
//! feature; `.ci/run` sets it) or else this binary started without a launcher (then it is one
//! process and never initialises MPI). JSON files and `--json` texts are compared without their
//! timing fields (as in `tests/determinism.rs`). Skipped, with a message, when `mpirun` is absent.

#[path = "support/snapshot.rs"]
mod snapshot;

use snapshot::{json_without_timing, snapshot};
use std::path::{Path, PathBuf};
use std::process::Command;

/// Whether `mpirun` runs; prints why the tier is skipped otherwise.
fn have_mpirun() -> bool {
    let ok = Command::new("mpirun").arg("--version").output().is_ok_and(|o| o.status.success());
    if !ok {
        eprintln!("SKIPPED: mpirun not found (install openmpi-bin to run the MPI tier)");
    }
    ok
}

fn reference_bin() -> PathBuf {
    match std::env::var_os("OPAL_REFERENCE_BIN") {
        Some(p) => PathBuf::from(p),
        None => {
            eprintln!("note: OPAL_REFERENCE_BIN unset: the reference is this binary run without mpirun");
            PathBuf::from(env!("CARGO_BIN_EXE_opal"))
        }
    }
}

/// `opal ARGS` without MPI (`ranks` = 0) or under `mpirun -np ranks`.
fn opal(ranks: usize) -> Command {
    if ranks == 0 {
        return Command::new(reference_bin());
    }
    let mut c = Command::new("mpirun");
    c.args(["--allow-run-as-root", "--oversubscribe", "--bind-to", "none", "-np", &ranks.to_string()])
        .arg(env!("CARGO_BIN_EXE_opal"));
    c
}

/// Runs `make(cmd, outdir)` without MPI and under 1, 2 and 3 ranks, each into a fresh folder,
/// with one worker thread; asserts exit `code` and identical folders and `--json` texts.
/// Returns the names of the files compared.
fn same_bytes_for_any_rank_count(code: i32, make: impl Fn(Command, &Path) -> Command) -> Vec<PathBuf> {
    let tmp = tempfile::tempdir().unwrap();
    let mut runs = Vec::new();
    for ranks in [0, 1, 2, 3] {
        let dir = tmp.path().join(format!("np{ranks}"));
        std::fs::create_dir_all(&dir).unwrap();
        let o = make(opal(ranks), &dir).output().unwrap();
        assert_eq!(o.status.code(), Some(code), "{ranks} ranks: {}", String::from_utf8_lossy(&o.stderr));
        let stdout = if o.stdout.is_empty() { Vec::new() } else { json_without_timing(&o.stdout) };
        runs.push((ranks, snapshot(&dir), stdout));
    }
    let (_, files0, out0) = &runs[0];
    assert!(!files0.is_empty());
    for (ranks, files, out) in &runs[1..] {
        assert_eq!(
            files.keys().collect::<Vec<_>>(),
            files0.keys().collect::<Vec<_>>(),
            "{ranks} ranks: file set"
        );
        for (name, bytes) in files {
            assert!(
                bytes == &files0[name],
                "{ranks} ranks: {} differs from the run without MPI",
                name.display()
            );
        }
        assert!(out == out0, "{ranks} ranks: --json output differs");
    }
    eprintln!("same bytes without MPI and on 1, 2, 3 ranks: {:?}", files0.keys().collect::<Vec<_>>());
    files0.keys().cloned().collect()
}

fn cbox() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../opal/tests/data/cbox/scene.xml")
}

#[test]
fn render_same_bytes_for_any_rank_count() {
    if !have_mpirun() {
        return;
    }
    let files = same_bytes_for_any_rank_count(0, |mut c, dir| {
        c.arg("render")
            .arg(cbox())
            .arg("-o")
            .arg(dir.join("out.exr"))
            .arg("--png")
            .arg(dir.join("out.png"))
            .arg("--stderr")
            .arg(dir.join("err.exr"))
            .args(["--spp", "4", "--seed", "7", "--threads", "1", "--quiet"]);
        c
    });
    assert_eq!(files.len(), 3);
}

#[test]
fn gonio_simulate_same_bytes_for_any_rank_count() {
    if !have_mpirun() {
        return;
    }
    // 5 batches of 2¹⁴ photons (the last one short) per incidence
    let files = same_bytes_for_any_rank_count(0, |mut c, dir| {
        c.args(["gonio", "simulate", "-o"])
            .arg(dir.join("curves.csv"))
            .args(["--photons", "70000", "--ndf", "beckmann:0.25", "--entry", "rough", "--seed", "11"])
            .args(["--threads", "1", "--json", "--quiet", "--plot"])
            .arg(dir.join("curves.svg"));
        c
    });
    assert_eq!(files.len(), 2);
}

#[test]
fn fit_ndf_same_bytes_for_any_rank_count() {
    if !have_mpirun() {
        return;
    }
    let csv = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/fit_ndf_demo.csv");
    // few iterations on 3 batches per evaluation: stops unconverged (exit 1), outputs written
    let files = same_bytes_for_any_rank_count(1, |mut c, dir| {
        c.arg("fit-ndf")
            .arg(&csv)
            .args(["--entry", "rough", "--family", "ggx", "--photons", "40000", "--coarse-photons", "20000"])
            .args(["--max-iters", "3", "--seed", "5", "--no-render", "--threads", "1", "--json", "--quiet"])
            .arg("-o")
            .arg(dir.join("fit"));
        c
    });
    assert!(files.iter().any(|f| f.ends_with("fit.json")), "{files:?}");
}

/// Renders `n` views of the test Cornell box at `res`² with Opal and writes them with a
/// transforms.json into `dir` (as `tests/delight.rs` does).
fn cbox_views(dir: &Path, n: usize, res: usize) -> PathBuf {
    use opal::integrator::path::{PathSettings, render};
    let mut desc = opal::scene::load::load_mitsuba_xml(&cbox(), &[]).unwrap();
    desc.sensors.truncate(n);
    for s in &mut desc.sensors {
        s.width = res;
        s.height = res;
    }
    let scene = opal::scene::Scene::build(&desc).unwrap();
    let ps = PathSettings { spp: 16, max_depth: -1, rr_depth: 5, hide_emitters: false, seed: 3 };
    let mut frames = Vec::new();
    for (c, s) in desc.sensors.iter().enumerate() {
        let img = render(&scene, c, &ps, &|| {}).image;
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

#[test]
fn delight_same_bytes_for_any_rank_count() {
    if !have_mpirun() {
        return;
    }
    let views = tempfile::tempdir().unwrap();
    let tj = cbox_views(views.path(), 4, 24);
    let files = same_bytes_for_any_rank_count(0, |mut c, dir| {
        c.arg("delight")
            .arg("--scene")
            .arg(cbox())
            .arg("--views")
            .arg(&tj)
            .arg("-o")
            .arg(dir.join("out"))
            .args([
                "--resolution",
                "16",
                "--light-paths",
                "60000",
                "--iterations",
                "2",
                "--rerender-spp",
                "2",
            ])
            .args(["--seed", "4", "--threads", "1", "--json"]);
        c
    });
    assert!(files.len() > 3, "{files:?}");
}

#[test]
fn a_failing_rank_aborts_the_job_and_writes_nothing() {
    if !have_mpirun() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out.exr");
    let o = opal(2).arg("render").arg(tmp.path().join("missing.xml")).arg("-o").arg(&out).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("aborting the job") && err.contains("missing.xml"), "{err}");
    assert_eq!(std::fs::read_dir(tmp.path()).unwrap().count(), 0, "nothing written");
}
