//! `opal fit-ndf` straight from Zemax tabular `.BSDF` files: the bundled demo measurement
//! (Mitsuba reference, GGX α = 0.15, rough entry) rewritten here by hand as a BRDF and a BTDF
//! file (`PlaneSymmetrical`, azimuths 0 and 180, radial 0…90° every 2°, value = intensity /
//! cos θ) is fitted to α within 10 % (as the CSV test of `tests/fit_ndf.rs`); the fitted
//! `.BSDF` exports read back through the same command line; malformed `.BSDF` files exit 2
//! naming file, line and value; a full-hemisphere measurement (CSV with `detector_azimuth_deg`,
//! written by `opal gonio simulate` with the hemisphere layout) is fitted with the simulator's
//! hemisphere layout. Default tier (~15 s).

use std::collections::HashMap;
use std::path::Path;
use std::process::Command;

fn opal() -> Command {
    Command::new(env!("CARGO_BIN_EXE_opal"))
}

/// (incidence, side) → detector angle → value, from the demo CSV.
fn demo_points() -> HashMap<(i64, String), HashMap<i64, f64>> {
    let csv = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/fit_ndf_demo.csv");
    let text = std::fs::read_to_string(csv).unwrap();
    let mut m: HashMap<(i64, String), HashMap<i64, f64>> = HashMap::new();
    for l in text.lines().filter(|l| !l.starts_with('#')).skip(1) {
        let c: Vec<&str> = l.split(',').collect();
        let (inc, side, det, v) =
            (c[0].parse().unwrap(), c[1].to_string(), c[2].parse().unwrap(), c[3].parse().unwrap());
        m.entry((inc, side)).or_default().insert(det, v);
    }
    m
}

/// A `.BSDF` file of one side written by hand from the demo points.
fn bsdf_file(side: &str) -> String {
    let pts = demo_points();
    let aois = [0i64, 30, 60];
    let radial: Vec<i64> = (0..=45).map(|i| 2 * i).collect();
    let list = |v: &[i64]| v.iter().map(|x| x.to_string()).collect::<Vec<_>>().join(" ");
    let kind = if side == "R" { "BRDF" } else { "BTDF" };
    let mut s = format!(
        "# demo measurement as a Zemax file\nSource Measured\nSymmetry PlaneSymmetrical\n\
         SpectralContent Monochrome\nScatterType {kind}\nSampleRotation 1\n0\n\
         AngleOfIncidence 3\n{}\nScatterAzimuth 2\n0 180\nScatterRadial {}\n{}\nMonochrome\nDataBegin\n",
        list(&aois),
        radial.len(),
        list(&radial)
    );
    for a in aois {
        let c = &pts[&(a, side.to_string())];
        s.push_str("TIS 0\n");
        for sign in [-1i64, 1] {
            // azimuth 0: towards the normal (p = aoi − r); azimuth 180: p = aoi + r
            let row: Vec<String> = radial
                .iter()
                .map(|r| {
                    let p = a + sign * r;
                    let v = c.get(&p).copied().unwrap_or(0.0);
                    format!("{:e}", v / (p as f64).to_radians().cos().max(1e-9))
                })
                .collect();
            s.push_str(&row.join(" "));
            s.push('\n');
        }
    }
    s.push_str("DataEnd\n");
    s
}

#[test]
fn fit_ndf_from_zemax_bsdf_files() {
    let d = tempfile::tempdir().unwrap();
    let (r, t) = (d.path().join("demo_brdf.BSDF"), d.path().join("demo_btdf.bsdf"));
    std::fs::write(&r, bsdf_file("R")).unwrap();
    std::fs::write(&t, bsdf_file("T")).unwrap();
    let out = d.path().join("fit");
    let o = opal()
        .arg("fit-ndf")
        .arg(&r)
        .arg(&t)
        .args(["--entry", "rough", "--family", "ggx", "--photons", "20000", "--json", "--quiet", "-o"])
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let a = j["alpha"].as_f64().unwrap();
    assert!((a / 0.15 - 1.0).abs() < 0.1, "alpha {a}");
    assert!(j["measured"].as_str().unwrap().contains("demo_btdf.bsdf"));
    // the fit's own .BSDF exports (the face, both sides) read back with the same reader
    for f in ["air_to_material_brdf.BSDF", "material_to_air_btdf.BSDF"] {
        let t = opal_inverse::scatter::zemax::read(&out.join(f)).unwrap();
        assert_eq!((t.aoi_deg.len(), t.azimuth_deg.len(), t.radial_deg.len()), (18, 19, 46), "{f}");
        let b = t.block(0, 0, 0);
        assert!(b.tis.unwrap() > 0.0 && b.values[0] > 0.0, "{f}");
    }
}

#[test]
fn malformed_bsdf_exits_2_naming_line_and_value() {
    let d = tempfile::tempdir().unwrap();
    let good = bsdf_file("T");
    let cases = [
        ("badnum", good.replacen("TIS 0\n", "TIS 0\n1.5 abc ", 1), ":17:5:", "\"abc\""),
        ("short", good.replace("DataEnd\n", ""), "unexpected end of file", "DataEnd"),
        ("symmetry", good.replace("PlaneSymmetrical", "Mirror"), ":3:10:", "\"Mirror\""),
    ];
    for (name, text, pos, value) in cases {
        let p = d.path().join(format!("{name}.BSDF"));
        std::fs::write(&p, text).unwrap();
        let o =
            opal().arg("fit-ndf").arg(&p).arg("-o").arg(d.path().join("o")).arg("--quiet").output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{name}: {err}");
        assert!(
            err.contains(&format!("{name}.BSDF")) && err.contains(pos) && err.contains(value),
            "{name}: {err}"
        );
    }
    // the same curve in two files
    let p = d.path().join("t.BSDF");
    std::fs::write(&p, &good).unwrap();
    let o = opal().arg("fit-ndf").arg(&p).arg(&p).arg("-o").arg(d.path().join("o")).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("is also in"), "{err}");
}

#[test]
fn fit_ndf_from_a_hemisphere_measurement() {
    let d = tempfile::tempdir().unwrap();
    let plate = d.path().join("plate.toml");
    std::fs::write(
        &plate,
        "[plate]\nior = 1.49\n[plate.back]\ntype = \"rough\"\nndf = \"ggx\"\nalpha = 0.2\n\
         [beam]\nincidences_deg = [0, 40]\n\
         [detectors]\nlayout = \"hemisphere\"\npolar_step_deg = 5\nazimuth_step_deg = 30\nradius_deg = 2\n\
         [run]\nphotons = 200000\nseed = 5\n",
    )
    .unwrap();
    let csv = d.path().join("hemi.csv");
    let o =
        opal().args(["gonio", "simulate"]).arg(&plate).arg("-o").arg(&csv).arg("--quiet").output().unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(std::fs::read_to_string(&csv).unwrap().lines().next().unwrap().contains("detector_azimuth_deg"));
    let out = d.path().join("fit");
    let o = opal()
        .arg("fit-ndf")
        .arg(&csv)
        .args(["--family", "ggx", "--photons", "200000", "--detector-radius-deg", "2", "--no-render"])
        .args(["--json", "--quiet", "-o"])
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let a = j["alpha"].as_f64().unwrap();
    assert!((a / 0.2 - 1.0).abs() < 0.05, "alpha {a}");
    // every measured (polar, azimuth) point is in the fitted curves, with its azimuth
    let fitted = std::fs::read_to_string(out.join("fitted_curves.csv")).unwrap();
    assert!(fitted.lines().next().unwrap().ends_with(",detector_azimuth_deg"));
    let n_meas = std::fs::read_to_string(&csv).unwrap().lines().count();
    assert_eq!(fitted.lines().count(), n_meas);
    assert!(fitted.lines().skip(1).any(|l| l.ends_with(",90")));
}
