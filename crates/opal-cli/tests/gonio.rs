//! `opal gonio simulate` end to end: defaults without a file, flags, PLATE.toml, JSON totals,
//! CSV columns, plot, bad input → exit 2 with the field and value in the message; the
//! hemisphere layout's values (z-tests against the plane layout at φ = 0°/180°, mirror symmetry
//! off the plane, rotational symmetry at normal incidence; R and T sides).

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

/// One detector of a gonio CSV: (incidence, side, polar or signed angle, azimuth) → (value,
/// standard error).
type Readings = Vec<((f64, String, f64, f64), (f64, f64))>;

/// Reads `opal gonio simulate`'s CSV by column name (azimuth 0 for the plane layout).
fn read_gonio_csv(path: &std::path::Path) -> Readings {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |n: &str| head.iter().position(|c| *c == n);
    let (ci, cs, cd, cv, ce) = (
        col("incidence_deg").unwrap(),
        col("side").unwrap(),
        col("detector_deg").unwrap(),
        col("value").unwrap(),
        col("value_stderr").unwrap(),
    );
    let ca = col("detector_azimuth_deg");
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            let num = |k: usize| f[k].parse::<f64>().unwrap();
            ((num(ci), f[cs].to_string(), num(cd), ca.map_or(0.0, num)), (num(cv), num(ce)))
        })
        .collect()
}

/// The hemisphere layout's values on a rough plate (GGX α 0.3, rough face lit, single
/// scattering, 300 000 photons at 0° and 40°), every check a z-test with the CSV's standard
/// errors, both sides (R and T):
/// * at φ = 0° and 180° (and θ = 0) the hemisphere detectors sit where the plane layout's do
///   (signed angle +θ / −θ): same values within noise, with the same seed;
/// * off the plane, a plate lit in the plane of incidence scatters symmetrically about it:
///   value(θ, φ) = value(θ, 360° − φ);
/// * at normal incidence the plate is rotationally symmetric: every azimuth of a ring agrees
///   with the ring's in-plane detector (φ = 0°), which the plane layout checks above — so a
///   transmitted or off-plane detector that counted wrongly would show here.
///
/// Every |z| ≤ 4.5 (308 comparisons: a false alarm has probability ~2·10⁻³ for independent
/// Gaussian z; measured worst |z| 3.70); the checks have power where the values are far from 0
/// (measured: 56 comparisons with ≥ 10σ of signal, at least 40 required).
#[test]
fn hemisphere_layout_values() {
    let dir = tempfile::tempdir().unwrap();
    let plate = |layout: &str| {
        format!(
            r#"
[plate]
ior = 1.5
thickness_mm = 2.0
entry = "rough"
[plate.front]
type = "rough"
ndf = "ggx"
alpha = 0.3
[plate.back]
type = "polished"
[beam]
incidences_deg = [0, 40]
divergence_deg = 0.0
[detectors]
{layout}
radius_deg = 3.0
[run]
photons = 300000
seed = 11
"#
        )
    };
    let run = |name: &str, layout: &str| {
        let toml = dir.path().join(format!("{name}.toml"));
        std::fs::write(&toml, plate(layout)).unwrap();
        let csv = dir.path().join(format!("{name}.csv"));
        let out = opal()
            .args(["gonio", "simulate"])
            .arg(&toml)
            .arg("-o")
            .arg(&csv)
            .arg("--quiet")
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        read_gonio_csv(&csv)
    };
    let plane = run(
        "plane",
        "layout = \"plane\"\nangles_deg = [-80, -70, -60, -50, -40, -30, -20, -10, 0, 10, 20, 30, 40, 50, 60, 70, 80]",
    );
    let hemi = run("hemi", "layout = \"hemisphere\"\npolar_step_deg = 10\nazimuth_step_deg = 30");
    let get = |t: &Readings, inc: f64, side: &str, a: f64, phi: f64| {
        t.iter()
            .find(|(k, _)| k.0 == inc && k.1 == side && (k.2 - a).abs() < 1e-9 && (k.3 - phi).abs() < 1e-9)
            .unwrap_or_else(|| panic!("no detector {inc}° {side} {a}° φ {phi}°"))
            .1
    };
    let z = |a: (f64, f64), b: (f64, f64)| {
        let s = a.1.hypot(b.1);
        if s == 0.0 { if a.0 == b.0 { 0.0 } else { f64::INFINITY } } else { (a.0 - b.0) / s }
    };
    let (mut worst, mut n, mut strong) = (0f64, 0usize, 0usize);
    let mut check = |what: &str, a: (f64, f64), b: (f64, f64)| {
        let zz = z(a, b);
        assert!(zz.abs() <= 4.5, "{what}: {a:?} vs {b:?}, z {zz}");
        worst = worst.max(zz.abs());
        n += 1;
        if a.0.min(b.0) > 10.0 * a.1.hypot(b.1) {
            strong += 1;
        }
    };
    for inc in [0.0, 40.0] {
        for side in ["R", "T"] {
            check(
                &format!("{inc}° {side} θ 0"),
                get(&hemi, inc, side, 0.0, 0.0),
                get(&plane, inc, side, 0.0, 0.0),
            );
            for t in (10..90).step_by(10).map(f64::from) {
                let what = format!("{inc}° {side} θ {t}");
                check(&format!("{what} φ 0"), get(&hemi, inc, side, t, 0.0), get(&plane, inc, side, t, 0.0));
                check(
                    &format!("{what} φ 180"),
                    get(&hemi, inc, side, t, 180.0),
                    get(&plane, inc, side, -t, 0.0),
                );
                for phi in (30..180).step_by(30).map(f64::from) {
                    let a = get(&hemi, inc, side, t, phi);
                    check(&format!("{what} φ {phi} vs −{phi}"), a, get(&hemi, inc, side, t, 360.0 - phi));
                    if inc == 0.0 {
                        check(&format!("{what} φ {phi} vs 0"), a, get(&hemi, inc, side, t, 0.0));
                    }
                }
            }
        }
    }
    println!("{n} comparisons, worst |z| {worst:.2}, {strong} with ≥ 10σ of signal");
    assert!(strong >= 40, "{strong}");
}
