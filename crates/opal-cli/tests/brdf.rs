//! Integration tests of `opal brdf` running the real binary.

use std::process::Command;

fn opal(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_opal")).args(args).output().expect("run opal");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

const FAST: &[&str] = &["--points", "24", "--incidence-points", "3", "--mc-samples", "20000"];

#[test]
fn check_reports_the_paper_overshoot_with_exit_1() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("r.png");
    let mut args =
        vec!["brdf", "check", "--model", "pow16", "--norm", "(n+A)/B", "--A", "6", "--B", "24.55", "--json"];
    args.extend_from_slice(FAST);
    args.extend_from_slice(&["--plot", png.to_str().unwrap()]);
    let (code, out, err) = opal(&args);
    assert_eq!(code, 1, "stdout {out}\nstderr {err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let max = v["max_reflectance"].as_f64().unwrap();
    assert!((max - 1.0016).abs() < 1e-4, "{max}");
    let n = v["argmax"]["param"].as_f64().unwrap();
    assert!((n - 18.0).abs() < 1.5, "{n}");
    assert!(v["argmax"]["incidence_deg"].as_f64().unwrap() < 0.5);
    assert!(v["reciprocity_error"].as_f64().unwrap() < 1e-4);
    let viol = v["violations"].as_array().unwrap();
    assert_eq!(viol.len(), 1);
    assert!(viol[0]["from"].as_f64().unwrap() < 17.0 && viol[0]["to"].as_f64().unwrap() > 19.0);
    assert!(v["model"].as_str().unwrap().contains("pow16"));
    // the offending range is named on stderr too
    assert!(err.contains("R > 1"), "{err}");
    let img = std::fs::read(&png).unwrap();
    assert!(img.starts_with(b"\x89PNG"));
}

#[test]
fn normalised_phong_passes_and_several_models_plot_to_svg() {
    let dir = tempfile::tempdir().unwrap();
    let svg = dir.path().join("r.svg");
    let mut args =
        vec!["brdf", "check", "--model", "phong-norm", "--model", "blinn-exact", "--param", "n=1:200"];
    args.extend_from_slice(FAST);
    args.extend_from_slice(&["--plot", svg.to_str().unwrap()]);
    let (code, out, err) = opal(&args);
    assert_eq!(code, 0, "stdout {out}\nstderr {err}");
    assert!(out.contains("phong-norm: max R = 1.0000") && out.contains("blinn-exact"), "{out}");
    assert!(std::fs::read_to_string(&svg).unwrap().contains("<svg"));
}

#[test]
fn fit_norm_prints_both_fits() {
    let (code, out, err) = opal(&[
        "brdf",
        "fit-norm",
        "--model",
        "pow16",
        "--form",
        "(n+A)/B",
        "--param",
        "n=1:300",
        "--incidence-deg",
        "0",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    for k in ["least_squares", "bounded"] {
        for f in ["A", "B", "max_reflectance"] {
            assert!(v[k][f].as_f64().is_some(), "{k}.{f} in {out}");
        }
    }
    let b = v["bounded"]["max_reflectance"].as_f64().unwrap();
    assert!(b <= 1.0 && b > 0.999999, "{b}");
    assert!(v["least_squares"]["max_reflectance"].as_f64().unwrap() > 1.0);
}

#[test]
fn bad_input_exits_2_with_a_message() {
    let cases: &[(&[&str], &str)] = &[
        (&["brdf", "check", "--model", "phong2"], "phong2"),
        (&["brdf", "check", "--model", "pow16", "--param", "n=5:5"], "empty or inverted"),
        (&["brdf", "check", "--model", "pow16", "--param", "n=100:1"], "empty or inverted"),
        (&["brdf", "check", "--model", "pow16", "--param", "alpha=0.1:1"], "parameter 'n'"),
        (&["brdf", "check", "--model", "pow16", "--norm", "(n+A"], "column 5"),
        (&["brdf", "check", "--model", "pow16", "--norm", "n*x"], "unknown name 'x'"),
        (&["brdf", "check", "--model", "pow16", "--incidence-deg", "0:95"], "incidence"),
        (&["brdf", "check", "--model", "lambert", "--norm", "(n+A)/B"], "no exponent"),
        (&["brdf", "fit-norm", "--model", "pow16", "--form", "(n+A)/"], "normalisation expression"),
        (&["brdf", "fit-norm", "--model", "nope"], "nope"),
    ];
    for (args, needle) in cases {
        let (code, out, err) = opal(args);
        assert_eq!(code, 2, "{args:?}: stdout {out} stderr {err}");
        assert!(err.contains("error:") && err.contains(needle), "{args:?}: {err}");
    }
}
