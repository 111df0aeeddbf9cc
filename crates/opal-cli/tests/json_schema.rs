//! The key set of every `--json` output of the CLI against the schema its page documents
//! (docs/cli.md and the pages it links: gonio.md, brdf.md, delight.md, fit-ndf.md): each test
//! runs the real binary on a tiny input, compares the top-level keys (and those of the
//! documented nested objects) with the documented list, and checks that every listed key is
//! written in the page (so the list here and the page cannot drift apart silently). The key
//! sets of `opal delight --json` and `opal fit-ndf --json` are checked in the tests that run
//! those commands already (tests/delight.rs, tests/fit_ndf.rs).

mod common;

use common::assert_keys;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

fn opal() -> Command {
    Command::new(env!("CARGO_BIN_EXE_opal"))
}

fn stdout_json(o: &std::process::Output) -> Value {
    serde_json::from_slice(&o.stdout).unwrap_or_else(|e| {
        panic!("{e}: {}\n{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
    })
}

fn cbox() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../opal/tests/data/cbox/scene.xml")
}

#[test]
fn render_json_keys() {
    let d = tempfile::tempdir().unwrap();
    let o = opal()
        .arg("render")
        .arg(cbox())
        .arg("-o")
        .arg(d.path().join("r.exr"))
        .args(["--spp", "1", "--json"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let keys = [
        "scene",
        "sensor",
        "width",
        "height",
        "spp",
        "max_depth",
        "seed",
        "seconds",
        "samples_per_second",
        "nonfinite_samples",
        "mean_rgb",
        "output",
    ];
    assert_keys("render", &stdout_json(&o), &keys, "cli.md");
}

#[test]
fn gonio_simulate_json_keys() {
    let d = tempfile::tempdir().unwrap();
    let o = opal()
        .args(["gonio", "simulate", "--photons", "1000", "--quiet", "--json", "-o"])
        .arg(d.path().join("c.csv"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j = stdout_json(&o);
    assert_keys(
        "gonio simulate",
        &j,
        &["incidences", "photons_per_incidence", "seconds", "photons_per_second"],
        "gonio.md",
    );
    for i in j["incidences"].as_array().unwrap() {
        assert_keys(
            "gonio simulate incidence",
            i,
            &["incidence_deg", "R", "T", "lost", "absorbed", "mean_interactions"],
            "gonio.md",
        );
    }
}

#[test]
fn brdf_check_and_fit_norm_json_keys() {
    let o = opal()
        .args(["brdf", "check", "--model", "pow16", "--points", "8", "--incidence-points", "2"])
        .args(["--mc-samples", "2000", "--json"])
        .output()
        .unwrap();
    assert!(matches!(o.status.code(), Some(0 | 1)), "{}", String::from_utf8_lossy(&o.stderr));
    let j = stdout_json(&o);
    let keys = [
        "model",
        "param_name",
        "range",
        "incidence_deg",
        "max_reflectance",
        "argmax",
        "reciprocity_error",
        "violations",
        "tolerance",
        "energy_conserving",
        "curve",
        "monte_carlo",
        "monte_carlo_consistent",
    ];
    assert_keys("brdf check", &j, &keys, "brdf.md");
    assert_keys("brdf check argmax", &j["argmax"], &["param", "incidence_deg"], "brdf.md");
    let o = opal()
        .args(["brdf", "fit-norm", "--model", "pow16", "--form", "(n+A)/B", "--param", "n=1:50", "--json"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j = stdout_json(&o);
    assert_keys(
        "brdf fit-norm",
        &j,
        &["least_squares", "bounded", "model", "form", "range", "samples"],
        "brdf.md",
    );
    let fit = ["A", "B", "max_reflectance", "argmax_param", "rms_residual"];
    assert_keys("brdf fit-norm least_squares", &j["least_squares"], &fit, "brdf.md");
    assert_keys("brdf fit-norm bounded", &j["bounded"], &fit, "brdf.md");
}
