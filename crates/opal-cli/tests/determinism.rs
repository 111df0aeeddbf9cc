//! Determinism of every command that draws random numbers, through the binary: the same seed
//! gives the same output bytes on 1 and on 2 worker threads (`--threads`), for `gonio
//! simulate`, `fit-ndf`, `brdf check` and `delight` (`render` has its own test,
//! `render_cli::the_same_seed_writes_the_same_bytes_on_one_and_two_threads`).
//!
//! Compared: every file the command writes, byte for byte, and its `--json` text, except the
//! fields that measure time (`seconds`, `cpu_seconds`, … listed in `support/snapshot.rs`), which are
//! removed from JSON before comparing.

#[path = "support/snapshot.rs"]
mod snapshot;

use snapshot::{json_without_timing, snapshot};
use std::path::{Path, PathBuf};
use std::process::Command;

fn opal() -> Command {
    Command::new(env!("CARGO_BIN_EXE_opal"))
}

/// Runs `make(threads, outdir)` for 1, 2 and 2 threads, each into a fresh folder; asserts that
/// it exits with `code` and that the folders (and the printed JSON) are identical. Returns the
/// file names compared.
fn same_on_one_and_two_threads(code: i32, make: impl Fn(&str, &Path) -> Command) -> Vec<PathBuf> {
    let tmp = tempfile::tempdir().unwrap();
    let mut runs = Vec::new();
    for (k, threads) in ["1", "2", "2"].into_iter().enumerate() {
        let dir = tmp.path().join(format!("run{k}"));
        std::fs::create_dir_all(&dir).unwrap();
        let o = make(threads, &dir).output().unwrap();
        assert_eq!(o.status.code(), Some(code), "{threads} threads: {}", String::from_utf8_lossy(&o.stderr));
        let stdout = if o.stdout.is_empty() { Vec::new() } else { json_without_timing(&o.stdout) };
        runs.push((snapshot(&dir), stdout));
    }
    let (files0, out0) = &runs[0];
    assert!(!files0.is_empty() || !out0.is_empty(), "nothing written, nothing printed");
    for (k, (files, out)) in runs.iter().enumerate().skip(1) {
        assert_eq!(files.keys().collect::<Vec<_>>(), files0.keys().collect::<Vec<_>>(), "run {k}: file set");
        for (name, bytes) in files {
            assert!(
                bytes == &files0[name],
                "run {k} (threads {}): {} differs",
                ["1", "2", "2"][k],
                name.display()
            );
        }
        assert!(out == out0, "run {k}: --json output differs");
    }
    files0.keys().cloned().collect()
}

#[test]
fn gonio_simulate_same_bytes_on_one_and_two_threads() {
    let files = same_on_one_and_two_threads(0, |threads, dir| {
        let mut c = opal();
        c.args(["gonio", "simulate", "-o"])
            .arg(dir.join("curves.csv"))
            .args(["--photons", "20000", "--ndf", "beckmann:0.25", "--entry", "rough", "--seed", "11"])
            .args(["--threads", threads, "--json", "--quiet", "--plot"])
            .arg(dir.join("curves.svg"));
        c
    });
    assert_eq!(files.len(), 2, "{files:?}");
}

#[test]
fn fit_ndf_same_bytes_on_one_and_two_threads() {
    let csv = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/fit_ndf_demo.csv");
    // 4 iterations on few photons: the fit stops unconverged (exit 1), outputs written.
    let files = same_on_one_and_two_threads(1, |threads, dir| {
        let mut c = opal();
        c.arg("fit-ndf")
            .arg(&csv)
            .args(["--entry", "rough", "--family", "ggx", "--photons", "3000", "--coarse-photons", "1000"])
            .args([
                "--max-iters",
                "4",
                "--seed",
                "5",
                "--no-render",
                "--threads",
                threads,
                "--json",
                "--quiet",
            ])
            .arg("-o")
            .arg(dir.join("fit"));
        c
    });
    assert!(files.iter().any(|f| f.ends_with("fit.json")), "{files:?}");
}

#[test]
fn brdf_check_same_bytes_on_one_and_two_threads() {
    let files = same_on_one_and_two_threads(0, |threads, dir| {
        let mut c = opal();
        c.args(["brdf", "check", "--model", "phong-norm", "--param", "n=1:100", "--points", "12"])
            .args(["--incidence-points", "3", "--mc-samples", "20000", "--seed", "9", "--threads", threads])
            .args(["--json", "--plot"])
            .arg(dir.join("r.svg"));
        c
    });
    assert_eq!(files.len(), 1);
}

/// `fit-norm` has no `--threads` flag: the worker count comes from rayon's default pool, which
/// `RAYON_NUM_THREADS` sets for the child process.
#[test]
fn brdf_fit_norm_same_bytes_on_one_and_two_threads() {
    let files = same_on_one_and_two_threads(0, |threads, dir| {
        let mut c = opal();
        c.env("RAYON_NUM_THREADS", threads)
            .args(["brdf", "fit-norm", "--model", "pow16", "--param", "n=1:50", "--incidence-deg", "0:30"])
            .arg("--json")
            .current_dir(dir);
        c
    });
    // its result is the printed JSON (compared by the helper); it writes no file
    assert!(files.is_empty(), "{files:?}");
}

#[test]
fn delight_same_bytes_on_one_and_two_threads() {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../opal-inverse/tests/data/lights_small");
    let files = same_on_one_and_two_threads(0, |threads, dir| {
        let mut c = opal();
        c.arg("delight")
            .arg("--scene")
            .arg(data.join("scene.xml"))
            .arg("--views")
            .arg(data.join("transforms.json"))
            .arg("-o")
            .arg(dir.join("out"))
            .args([
                "--resolution",
                "16",
                "--light-paths",
                "50000",
                "--iterations",
                "2",
                "--rerender-spp",
                "2",
            ])
            .args(["--seed", "4", "--threads", threads, "--json"]);
        c
    });
    assert!(files.len() > 3, "{files:?}");
}
