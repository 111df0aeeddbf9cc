//! `opal brdf`: energy / reciprocity checks of BRDF lobes and normalisation fitting (method B).
//!
//! * `opal brdf check --model NAME [--model NAME2 ...] [--param n=1:1000] [--norm "(n+A)/B"
//!   --A 6 --B 24.55] [--incidence-deg 0:89] [--json] [--plot FILE.png|svg]` — exit 1 when a
//!   model's reflectance exceeds 1 + tolerance (the offending ranges are printed) or when the
//!   Monte Carlo cross-check disagrees with the quadrature.
//! * `opal brdf fit-norm --model NAME --form "(n+A)/B" [--param n=1:1000] [--json]`.
//! * `opal brdf list` — the model names.
//!
//! The numbers come from `opal_inverse::brdf_energy`; this file parses, formats and plots.

use crate::plot::{LinePlot, Series, save_panels};
use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand};
use opal::bsdf::normexpr::NormExpr;
use opal::bsdf::registry::{self, ModelSpec, NormSpec};
use opal_inverse::brdf_energy::{self, CheckConfig, CheckReport, FitConfig, FitReport};
use std::path::{Path, PathBuf};

/// Arguments of `opal brdf`.
#[derive(Args, Debug)]
pub struct BrdfArgs {
    #[command(subcommand)]
    cmd: BrdfCommand,
}

#[derive(Subcommand, Debug)]
enum BrdfCommand {
    /// Directional–hemispherical reflectance R(θi, param): max, argmax, violations of R ≤ 1,
    /// reciprocity; optional plot of R against the parameter.
    Check(CheckArgs),
    /// Fit the constants of a normalisation factor (least squares, and tightest with R ≤ 1).
    FitNorm(FitArgs),
    /// List the model names.
    List,
}

/// Arguments of `opal brdf check`.
#[derive(Args, Debug)]
pub struct CheckArgs {
    /// Model name (repeat for several models on one plot); see `opal brdf list`.
    #[arg(long = "model", required = true)]
    models: Vec<String>,
    /// Parameter range `NAME=LO:HI` (or `LO:HI`), e.g. `n=1:1000`; default: the model's own.
    #[arg(long)]
    param: Option<String>,
    /// Normalisation expression in n, A, B replacing the model's own, e.g. "(n+A)/B".
    #[arg(long)]
    norm: Option<String>,
    /// Constant A of the normalisation expression.
    #[arg(long = "A", default_value_t = 6.0)]
    a: f64,
    /// Constant B of the normalisation expression.
    #[arg(long = "B", default_value_t = 24.55)]
    b: f64,
    /// Incidence range in degrees `LO:HI` (or a single angle), within [0, 90).
    #[arg(long = "incidence-deg", default_value = "0:89")]
    incidence_deg: String,
    /// R may exceed 1 by this much before it is a violation (the quadrature is good to ~1e-6).
    #[arg(long, default_value_t = 1e-4)]
    tolerance: f64,
    /// Parameter grid points (refined around the maximum and the violation edges).
    #[arg(long, default_value_t = 80)]
    points: usize,
    /// Incidence grid points (refined around the maximum).
    #[arg(long = "incidence-points", default_value_t = 10)]
    incidence_points: usize,
    /// Monte Carlo samples per cross-check point.
    #[arg(long = "mc-samples", default_value_t = 200_000)]
    mc_samples: u64,
    /// Seed of the Monte Carlo cross-check.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Worker threads (default: all cores); the output does not depend on it.
    #[arg(long)]
    threads: Option<usize>,
    /// Print one JSON object per model (an array when several models are given).
    #[arg(long)]
    json: bool,
    /// Write a plot of R against the parameter (.png or .svg).
    #[arg(long)]
    plot: Option<PathBuf>,
}

/// Arguments of `opal brdf fit-norm`.
#[derive(Args, Debug)]
pub struct FitArgs {
    /// Model name whose raw lobe is normalised (its own normalisation is replaced).
    #[arg(long)]
    model: String,
    /// Normalisation form in n, A, B.
    #[arg(long, default_value = "(n+A)/B")]
    form: String,
    /// Exponent range `n=LO:HI`.
    #[arg(long)]
    param: Option<String>,
    /// Starting value of A.
    #[arg(long = "A", default_value_t = 6.0)]
    a: f64,
    /// Starting value of B.
    #[arg(long = "B", default_value_t = 24.55)]
    b: f64,
    /// Incidence range in degrees: R₀(n) is the maximum over it.
    #[arg(long = "incidence-deg", default_value = "0:89")]
    incidence_deg: String,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

/// Parses `LO:HI` or a single value `X` (→ X:X); `what` names the flag in errors.
fn parse_range(s: &str, what: &str) -> Result<(f64, f64)> {
    let num = |t: &str| -> Result<f64> {
        let v: f64 = t.trim().parse().with_context(|| format!("{what}: '{t}' is not a number (in '{s}')"))?;
        if !v.is_finite() {
            bail!("{what}: '{t}' is not finite");
        }
        Ok(v)
    };
    match s.split_once(':') {
        Some((a, b)) => Ok((num(a)?, num(b)?)),
        None => {
            let v = num(s)?;
            Ok((v, v))
        }
    }
}

/// `--param NAME=LO:HI` for a model: checks the name and that the range is non-empty.
fn param_range(spec: &ModelSpec, param: Option<&str>) -> Result<(f64, f64)> {
    let Some(p) = param else { return Ok(spec.info.default_range) };
    let (name, range) = match p.split_once('=') {
        Some((n, r)) => (Some(n.trim()), r),
        None => (None, p),
    };
    if let Some(n) = name
        && n != spec.info.param
    {
        bail!("--param {p}: model '{}' has parameter '{}', not '{n}'", spec.info.name, spec.info.param);
    }
    let (lo, hi) = parse_range(range, "--param")?;
    if lo >= hi {
        bail!("--param {p}: the range {lo}:{hi} is empty or inverted (need LO < HI)");
    }
    Ok((lo, hi))
}

fn incidence(s: &str) -> Result<(f64, f64)> {
    let (a, b) = parse_range(s, "--incidence-deg")?;
    if a > b || a < 0.0 || b >= 90.0 {
        bail!("--incidence-deg {s}: need 0 ≤ LO ≤ HI < 90");
    }
    Ok((a, b))
}

fn spec_of(name: &str, norm: Option<&str>, a: f64, b: f64) -> Result<ModelSpec> {
    let spec = ModelSpec::new(name)?;
    Ok(match norm {
        Some(expr) => spec.with_norm(NormSpec { expr: NormExpr::parse(expr)?, a, b })?,
        None => spec,
    })
}

/// One line per violation range.
fn describe(r: &CheckReport) -> String {
    let mut s = format!(
        "{}: max R = {:.6} at {} = {:.4}, θi = {:.2}°; reciprocity error {:.2e}\n",
        r.model, r.max_reflectance, r.param_name, r.argmax.param, r.argmax.incidence_deg, r.reciprocity_error
    );
    if r.violations.is_empty() {
        s += &format!(
            "  R ≤ 1 + {:.0e} for {} ∈ [{}, {}] and θi ∈ [{}°, {}°]\n",
            r.tolerance, r.param_name, r.range.0, r.range.1, r.incidence_deg.0, r.incidence_deg.1
        );
    }
    for v in &r.violations {
        s += &format!(
            "  VIOLATION: R > 1 + {:.0e} for {} ∈ [{:.4}, {:.4}] (max R there {:.6})\n",
            r.tolerance, r.param_name, v.from, v.to, v.max_reflectance
        );
    }
    for m in &r.monte_carlo {
        s += &format!(
            "  MC cross-check at {} = {:.4}, θi = {:.2}°: quadrature {:.6}, MC {:.6} ± {:.6} (z = {:+.2})\n",
            r.param_name, m.param, m.incidence_deg, m.quadrature, m.monte_carlo, m.std_error, m.z
        );
    }
    if !r.monte_carlo_consistent {
        s += "  MONTE CARLO DISAGREES with the quadrature: sampling/pdf and eval are inconsistent\n";
    }
    s
}

/// The check results as JSON (the documented fields plus the curve and MC checks).
pub fn report_json(r: &CheckReport) -> serde_json::Value {
    serde_json::to_value(r).expect("serialisable")
}

/// Plots `R_max(param)` of several reports (the paper's Fig. 3/4), with the R = 1 line.
pub fn plot_reports(path: &Path, reports: &[CheckReport]) -> Result<()> {
    let param = reports.first().map(|r| r.param_name.clone()).unwrap_or_default();
    let mut series = Vec::new();
    for (i, r) in reports.iter().enumerate() {
        series.push(Series {
            name: format!("{} (max over θi)", r.model),
            points: r.curve.iter().map(|p| (p.param, p.max_reflectance)).collect(),
            color: i,
            dashed: false,
            marks: false,
        });
        if r.incidence_deg.1 > r.incidence_deg.0 {
            series.push(Series {
                name: format!("{} (θi = {}°)", r.model, r.incidence_deg.0),
                points: r.curve.iter().map(|p| (p.param, p.reflectance_first_incidence)).collect(),
                color: i,
                dashed: true,
                marks: false,
            });
        }
    }
    let full = LinePlot {
        title: "Directional–hemispherical reflectance".into(),
        x_label: param.clone(),
        y_label: "R".into(),
        log_y: false,
        series: series.clone(),
        hline: Some(1.0),
    };
    // second panel: the low-parameter end where lobes violate R ≤ 1
    let (lo, hi) = reports.first().map(|r| r.range).unwrap_or((0.0, 1.0));
    let cut = lo + (hi - lo) * 0.06;
    let zoom = LinePlot {
        title: format!("zoom: {param} ≤ {cut:.0}"),
        series: series
            .iter()
            .map(|s| Series {
                points: s.points.iter().copied().filter(|p| p.0 <= cut).collect(),
                ..s.clone()
            })
            .collect(),
        ..full.clone()
    };
    save_panels(path, &[full, zoom], (1400, 560))
}

/// Runs `opal brdf …` without printing: `check` → one report per model (an array),
/// `fit-norm` → the fit report, `list` → the models (the Python package's entry point).
pub fn run_json(args: BrdfArgs) -> Result<serde_json::Value> {
    Ok(match args.cmd {
        BrdfCommand::Check(a) => {
            let reports = check_reports(&a)?;
            serde_json::Value::Array(reports.iter().map(report_json).collect())
        }
        BrdfCommand::FitNorm(a) => serde_json::to_value(fit_report(&a)?)?,
        BrdfCommand::List => serde_json::Value::Array(
            registry::models()
                .iter()
                .map(|m| {
                    serde_json::json!({
                        "name": m.name, "plugin": m.plugin, "param": m.param,
                        "default_range": [m.default_range.0, m.default_range.1],
                        "description": m.description,
                    })
                })
                .collect(),
        ),
    })
}

/// The reports of `opal brdf check` (one per `--model`).
fn check_reports(a: &CheckArgs) -> Result<Vec<CheckReport>> {
    let inc = incidence(&a.incidence_deg)?;
    if a.points < 3 || a.incidence_points < 1 {
        bail!("--points must be ≥ 3 and --incidence-points ≥ 1");
    }
    if a.tolerance.is_nan() || a.tolerance < 0.0 {
        bail!("--tolerance must be ≥ 0, got {}", a.tolerance);
    }
    let specs: Vec<ModelSpec> =
        a.models.iter().map(|m| spec_of(m, a.norm.as_deref(), a.a, a.b)).collect::<Result<_>>()?;
    let mut reports = Vec::new();
    let pb = crate::util::progress(specs.len() as u64, "brdf check");
    for spec in &specs {
        let cfg = CheckConfig {
            range: param_range(spec, a.param.as_deref())?,
            incidence_deg: inc,
            param_points: a.points,
            incidence_points: a.incidence_points,
            tolerance: a.tolerance,
            mc_samples: a.mc_samples.max(100),
            seed: a.seed,
            ..Default::default()
        };
        let r =
            brdf_energy::check(spec, &cfg).with_context(|| format!("checking model '{}'", spec.info.name))?;
        reports.push(r);
        pb.inc(1);
    }
    pb.finish_and_clear();
    if let Some(p) = &a.plot {
        plot_reports(p, &reports).with_context(|| format!("writing the plot {}", p.display()))?;
    }
    Ok(reports)
}

fn check(a: CheckArgs) -> Result<i32> {
    let reports = check_reports(&a)?;
    if a.json {
        let v: Vec<serde_json::Value> = reports.iter().map(report_json).collect();
        let out = if v.len() == 1 { v.into_iter().next().unwrap() } else { serde_json::Value::Array(v) };
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        for r in &reports {
            print!("{}", describe(r));
        }
        if let Some(p) = &a.plot {
            println!("plot: {}", p.display());
        }
    }
    let failed = reports.iter().any(|r| !r.energy_conserving || !r.monte_carlo_consistent);
    if failed && a.json {
        for r in reports.iter().filter(|r| !r.energy_conserving) {
            for v in &r.violations {
                eprintln!(
                    "{}: R > 1 + {:.0e} for {} ∈ [{:.4}, {:.4}] (max {:.6})",
                    r.model, r.tolerance, r.param_name, v.from, v.to, v.max_reflectance
                );
            }
        }
    }
    Ok(if failed { 1 } else { 0 })
}

/// The report of `opal brdf fit-norm`.
fn fit_report(a: &FitArgs) -> Result<FitReport> {
    let spec = ModelSpec::new(&a.model)?;
    let form = NormExpr::parse(&a.form)?;
    let range = param_range(&spec, a.param.as_deref())?;
    let cfg = FitConfig {
        range,
        incidence_deg: incidence(&a.incidence_deg)?,
        start: (a.a, a.b),
        ..Default::default()
    };
    brdf_energy::fit_norm(&spec, &form, &cfg).with_context(|| format!("fitting {} for '{}'", a.form, a.model))
}

fn fit(a: FitArgs) -> Result<i32> {
    let r = fit_report(&a)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        print!("{}", describe_fit(&r));
    }
    Ok(0)
}

fn describe_fit(r: &FitReport) -> String {
    let line = |tag: &str, c: &brdf_energy::FittedConstants| {
        format!(
            "  {tag:<14} A = {:.6}, B = {:.6}: max R = {:.6} (at n = {:.3}), RMS(c·R₀ − 1) = {:.4}\n",
            c.a, c.b, c.max_reflectance, c.argmax_param, c.rms_residual
        )
    };
    format!(
        "{} · {} over n ∈ [{}, {}] ({} samples)\n{}{}",
        r.model,
        r.form,
        r.range.0,
        r.range.1,
        r.samples,
        line("least squares", &r.least_squares),
        line("bounded R ≤ 1", &r.bounded)
    )
}

/// Runs `opal brdf`; returns the exit code.
pub fn run(args: BrdfArgs) -> Result<i32> {
    match args.cmd {
        BrdfCommand::Check(a) => {
            crate::util::set_threads(a.threads);
            check(a)
        }
        BrdfCommand::FitNorm(a) => fit(a),
        BrdfCommand::List => {
            for m in registry::models() {
                println!(
                    "{:<14} plugin {:<8} {} ∈ [{}, {}]  {}",
                    m.name, m.plugin, m.param, m.default_range.0, m.default_range.1, m.description
                );
            }
            Ok(0)
        }
    }
}

/// The demo's part of method B: checks the raw and normalised pow16 lobes (and Blinn–Phong with
/// the common normalisation, as in the paper's Fig. 4) on n ∈ [1, 1000], fits the normalisation
/// constants at normal incidence, writes `out_dir/brdf/pow16_reflectance.png` and returns a JSON
/// summary.
pub fn demo(out_dir: &Path) -> Result<serde_json::Value> {
    let dir = out_dir.join("brdf");
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let cfg = CheckConfig { param_points: 60, incidence_points: 6, mc_samples: 50_000, ..Default::default() };
    let mut reports = Vec::new();
    for name in ["pow16", "pow16-norm", "blinn-approx"] {
        reports.push(brdf_energy::check(&ModelSpec::new(name)?, &cfg)?);
    }
    let plot = dir.join("pow16_reflectance.png");
    plot_reports(&plot, &reports)?;
    let fit_cfg = FitConfig { incidence_deg: (0.0, 0.0), ..Default::default() };
    let fit = brdf_energy::fit_norm(&ModelSpec::new("pow16")?, &NormExpr::paper(), &fit_cfg)?;
    let json = serde_json::json!({
        "plot": plot,
        "checks": reports.iter().map(|r| serde_json::json!({
            "model": r.model,
            "max_reflectance": r.max_reflectance,
            "argmax": r.argmax,
            "reciprocity_error": r.reciprocity_error,
            "violations": r.violations,
            "monte_carlo_consistent": r.monte_carlo_consistent,
        })).collect::<Vec<_>>(),
        "fit_norm": fit,
    });
    crate::util::write_bytes_atomic(
        &dir.join("report.json"),
        serde_json::to_string_pretty(&json)?.as_bytes(),
    )?;
    for r in &reports {
        eprint!("demo: {}", describe(r).lines().next().unwrap_or_default());
        eprintln!();
    }
    eprintln!("demo: brdf plot -> {}", plot.display());
    Ok(json)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The demo's BRDF part end to end (≈ 10–30 s on 2 cores): run with
    /// `cargo test -p opal-cli brdf_demo -- --ignored`.
    #[test]
    #[ignore]
    fn brdf_demo_writes_plot_and_report() {
        let dir = tempfile::tempdir().unwrap();
        let v = demo(dir.path()).unwrap();
        assert!(dir.path().join("brdf/pow16_reflectance.png").exists());
        assert!(dir.path().join("brdf/report.json").exists());
        let checks = v["checks"].as_array().unwrap();
        assert_eq!(checks.len(), 3);
        let paper = &checks[1];
        assert!((paper["max_reflectance"].as_f64().unwrap() - 1.0016).abs() < 1e-4);
        assert!(v["fit_norm"]["bounded"]["max_reflectance"].as_f64().unwrap() <= 1.0);
    }

    #[test]
    fn ranges_parse_and_refuse_bad_values() {
        assert_eq!(parse_range("1:1000", "x").unwrap(), (1.0, 1000.0));
        assert_eq!(parse_range("30", "x").unwrap(), (30.0, 30.0));
        assert!(parse_range("a:2", "x").is_err());
        let spec = ModelSpec::new("pow16").unwrap();
        assert_eq!(param_range(&spec, Some("n=2:50")).unwrap(), (2.0, 50.0));
        assert_eq!(param_range(&spec, None).unwrap(), (1.0, 1000.0));
        assert!(param_range(&spec, Some("n=50:2")).is_err());
        assert!(param_range(&spec, Some("alpha=0.1:1")).is_err());
        assert!(incidence("0:90").is_err() && incidence("10:5").is_err());
    }
}
