//! `opal gonio simulate` end to end: defaults without a file, flags, PLATE.toml, JSON totals,
//! CSV columns, plot, bad input → exit 2 with the field and value in the message.

use std::process::Command;

fn opal() -> Command {
    Command::new(env!("CARGO_BIN_EXE_opal"))
}

#[test]
fn simulate_with_flags_writes_csv_json_and_plot() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("curves.csv");
    let png = dir.path().join("curves.png");
    let out = opal()
        .args(["gonio", "simulate", "-o"])
        .arg(&csv)
        .args(["--photons", "20000", "--ndf", "beckmann:0.25", "--entry", "rough", "--json", "--plot"])
        .arg(&png)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let inc = j["incidences"].as_array().unwrap();
    assert_eq!(inc.len(), 6);
    for (k, r) in inc.iter().enumerate() {
        assert_eq!(r["incidence_deg"].as_f64().unwrap(), 15.0 * k as f64);
        let (rr, t, l) = (r["R"].as_f64().unwrap(), r["T"].as_f64().unwrap(), r["lost"].as_f64().unwrap());
        assert!((rr + t + l - 1.0).abs() < 1e-6 && rr > 0.0 && t > 0.0);
    }
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    assert!(lines.next().unwrap().starts_with("incidence_deg,side,detector_deg,value,value_stderr,bsdf"));
    // 6 incidences × 2 sides × 179 detectors
    assert_eq!(lines.count(), 6 * 2 * 179);
    assert!(std::fs::metadata(&png).unwrap().len() > 1000);
}

#[test]
fn simulate_from_plate_toml() {
    let dir = tempfile::tempdir().unwrap();
    let toml = dir.path().join("plate.toml");
    std::fs::write(
        &toml,
        r#"
[plate]
ior = 1.5
thickness_mm = 3.0
absorption_per_mm = 0.01
[plate.front]
type = "rough"
ndf = "student"
alpha = 0.3
gamma = 3.0
scattering = "multiple"
[plate.back]
type = "polished"
[beam]
incidences_deg = [0, 40]
divergence_deg = 0.0
[detectors]
layout = "hemisphere"
radius_deg = 2.0
polar_step_deg = 10
azimuth_step_deg = 30
[run]
photons = 20000
seed = 7
"#,
    )
    .unwrap();
    let csv = dir.path().join("c.csv");
    let out =
        opal().args(["gonio", "simulate"]).arg(&toml).arg("-o").arg(&csv).arg("--json").output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for r in j["incidences"].as_array().unwrap() {
        let s = r["R"].as_f64().unwrap() + r["T"].as_f64().unwrap() + r["absorbed"].as_f64().unwrap();
        // multiple scattering keeps energy: only absorption removes power
        assert!(s > 0.995, "{r}");
        assert!(r["absorbed"].as_f64().unwrap() > 0.0);
    }
    let text = std::fs::read_to_string(&csv).unwrap();
    assert!(text.lines().next().unwrap().contains("detector_azimuth_deg"));
}

fn fails_with(args: &[&str], toml: Option<&str>, needle: &str) {
    let dir = tempfile::tempdir().unwrap();
    let mut cmd = opal();
    cmd.args(["gonio", "simulate"]);
    if let Some(t) = toml {
        let p = dir.path().join("bad.toml");
        std::fs::write(&p, t).unwrap();
        cmd.arg(&p);
    }
    cmd.arg("-o").arg(dir.path().join("o.csv")).args(["--photons", "100"]).args(args);
    let out = cmd.output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
    assert!(err.contains(needle), "{args:?}: expected {needle:?} in {err}");
}

#[test]
fn bad_input_exits_2_naming_field_and_value() {
    fails_with(&["--ior", "0"], None, "ior");
    fails_with(&["--ior", "-1.5"], None, "-1.5");
    fails_with(&["--ndf", "ggx:0"], None, "alpha must be > 0, got 0");
    fails_with(&["--ndf", "ggx:-0.2"], None, "-0.2");
    fails_with(&["--thickness-mm", "0"], None, "thickness_mm");
    fails_with(&["--detector-radius-deg", "90"], None, "radius_deg");
    fails_with(&["--ndf", "cauchy:0.2"], None, "cauchy");
    fails_with(&[], Some("[plate]\nior = 1.5\ncolour = 3\n"), "colour");
    fails_with(&[], Some("[plate\nior = 1.5\n"), "bad.toml");
    fails_with(
        &[],
        Some(
            "[plate.back]\ntype = \"rough\"\nndf = \"table\"\ntable_theta_deg = [0, 10, 20]\ntable_d = [1, -2, 0]\n",
        ),
        "-2",
    );
    fails_with(
        &[],
        Some(
            "[plate.back]\ntype = \"rough\"\nndf = \"table\"\ntable_theta_deg = [0, 10]\ntable_d = [0, 0]\n",
        ),
        "normalisable",
    );
}
