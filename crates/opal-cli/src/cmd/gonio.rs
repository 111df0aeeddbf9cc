//! `opal gonio simulate`: the virtual goniophotometer (plate, beam, detectors) of
//! [`opal::gonio`], configured by a PLATE.toml (format in `docs/gonio.md`) and/or flags.

use crate::plate::{Config, PlateFile, PlateFlags, PlateOverrides, build_config, read_plate_file};
use crate::plot::{LinePlot, Series, save_panels};
use crate::util::{progress, write_atomic};
use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use opal::gonio::{Gonio, GonioResult, Side};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Arguments of `opal gonio`.
#[derive(Args, Debug)]
pub struct GonioArgs {
    #[command(subcommand)]
    cmd: GonioCmd,
}

#[derive(Subcommand, Debug)]
enum GonioCmd {
    /// Simulate a plate in the virtual goniophotometer and write detector curves (CSV).
    Simulate(SimulateArgs),
}

/// Arguments of `opal gonio simulate`; flags override the file's fields.
#[derive(Args, Debug, Default)]
pub struct SimulateArgs {
    /// Sample, beam and detectors (TOML, see docs/gonio.md); defaults apply without it.
    pub plate: Option<PathBuf>,
    /// Output CSV (incidence_deg,side,detector_deg,value,value_stderr,bsdf,...).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Photons per incidence angle.
    #[arg(long)]
    pub photons: Option<u64>,
    /// Random seed.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Worker threads (default: all cores); the output does not depend on it.
    #[arg(long)]
    pub threads: Option<usize>,
    /// Also plot value vs detector angle (PNG or SVG by extension).
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Print the totals R, T, lost per incidence as JSON on stdout.
    #[arg(long)]
    pub json: bool,
    /// Plate, beam and detectors.
    #[command(flatten)]
    pub plate_flags: PlateFlags,
    /// NDF of the rough face: FAMILY:ALPHA (ggx:0.15, beckmann:0.25) or student:ALPHA:GAMMA.
    #[arg(long, allow_hyphen_values = true)]
    pub ndf: Option<String>,
    /// Scattering model of the rough face: single, single-mitsuba (Mitsuba 3's G1), single-hc (height-correlated G), multiple.
    #[arg(long)]
    pub scattering: Option<String>,
}

/// Writes the detector curves as CSV.
pub fn write_csv(path: &Path, gonio: &Gonio, res: &GonioResult) -> Result<()> {
    let dets = gonio.detectors();
    let hemi = dets.is_hemisphere();
    write_atomic(path, |f| {
        let mut w = std::io::BufWriter::new(f);
        write!(w, "incidence_deg,side,detector_deg,value,value_stderr,bsdf")?;
        if hemi {
            write!(w, ",detector_azimuth_deg")?;
        }
        writeln!(w, ",n_hits")?;
        for r in &res.incidences {
            for (k, d) in dets.list().iter().enumerate() {
                write!(
                    w,
                    "{},{},{},{:.8e},{:.8e},{:.8e}",
                    fmt_deg(r.incidence.to_degrees()),
                    d.side.label(),
                    fmt_deg(d.angle_deg),
                    r.value[k],
                    r.value_stderr[k],
                    r.bsdf[k]
                )?;
                if hemi {
                    write!(w, ",{}", fmt_deg(d.azimuth_deg))?;
                }
                writeln!(w, ",{}", r.hits[k])?;
            }
        }
        w.flush()?;
        Ok(())
    })
}

fn fmt_deg(x: f64) -> String {
    let r = (x * 1e6).round() / 1e6;
    if r == r.trunc() { format!("{}", r as i64) } else { format!("{r}") }
}

/// Plots value vs detector angle, log scale, one colour per incidence, panels R and T.
pub fn write_plot(path: &Path, gonio: &Gonio, res: &GonioResult, title: &str) -> Result<()> {
    let dets = gonio.detectors().list();
    let mut panels = Vec::new();
    for side in [Side::R, Side::T] {
        let mut series = Vec::new();
        for (i, r) in res.incidences.iter().enumerate() {
            let mut pts: Vec<(f64, f64)> = dets
                .iter()
                .enumerate()
                .filter(|(_, d)| d.side == side)
                .filter_map(|(k, d)| {
                    // hemisphere layout: the plane of incidence is azimuth 0 (+θ) and 180 (−θ)
                    let x = if d.azimuth_deg.abs() < 1e-9 {
                        d.angle_deg
                    } else if (d.azimuth_deg - 180.0).abs() < 1e-9 {
                        -d.angle_deg
                    } else {
                        return None;
                    };
                    (r.value[k] > 0.0).then_some((x, r.value[k]))
                })
                .collect();
            pts.sort_by(|a, b| a.0.total_cmp(&b.0));
            series.push(Series {
                name: format!("{}°", fmt_deg(r.incidence.to_degrees())),
                points: pts,
                color: i,
                dashed: false,
                marks: false,
            });
        }
        panels.push(LinePlot {
            title: format!("{title}, side {}", side.label()),
            x_label: "detector angle (deg)".into(),
            y_label: "I / P_in (1/sr)".into(),
            log_y: true,
            series,
            hline: None,
        });
    }
    save_panels(path, &panels, (1400, 560))
}

/// Totals as JSON.
pub fn totals_json(res: &GonioResult, seconds: f64) -> serde_json::Value {
    let inc: Vec<_> = res
        .incidences
        .iter()
        .map(|r| {
            serde_json::json!({
                "incidence_deg": (r.incidence.to_degrees() * 1e9).round() / 1e9,
                "R": r.r, "T": r.t, "lost": r.lost, "absorbed": r.absorbed,
                "mean_interactions": r.mean_interactions,
            })
        })
        .collect();
    let n = res.photons as f64 * res.incidences.len() as f64;
    serde_json::json!({
        "incidences": inc,
        "photons_per_incidence": res.photons,
        "seconds": seconds,
        "photons_per_second": if seconds > 0.0 { n / seconds } else { 0.0 },
    })
}

impl SimulateArgs {
    /// The flags that override PLATE.toml.
    pub fn overrides(&self) -> PlateOverrides {
        PlateOverrides {
            photons: self.photons,
            seed: self.seed,
            plate: self.plate_flags.clone(),
            ndf: self.ndf.clone(),
            scattering: self.scattering.clone(),
        }
    }
}

/// Runs a configuration with a progress bar; returns the simulator, result and wall time.
/// Under MPI the photon batches are split across the ranks (same result bits for any count).
pub fn simulate(cfg: &Config) -> Result<(Gonio, GonioResult, f64)> {
    let gonio =
        Gonio::new(cfg.setup.clone()).map_err(|e| anyhow::anyhow!("{e}"))?.with_comm(crate::dist::comm());
    let batches = (cfg.setup.photons.div_ceil(opal::gonio::BATCH) * cfg.setup.incidences.len() as u64)
        .div_ceil(crate::dist::size() as u64);
    let pb = progress(batches, "gonio");
    let t0 = std::time::Instant::now();
    let res = gonio.run_plate_with_progress(&cfg.plate, &|| pb.inc(1)).map_err(|e| anyhow::anyhow!("{e}"))?;
    pb.finish_and_clear();
    Ok((gonio, res, t0.elapsed().as_secs_f64()))
}

/// The detector curves as columns (the CSV's, at full precision): incidence_deg, side,
/// detector_deg, value, value_stderr, bsdf, n_hits, and detector_azimuth_deg for the
/// hemisphere layout.
pub fn curves_json(gonio: &Gonio, res: &GonioResult) -> serde_json::Value {
    let dets = gonio.detectors().list();
    let (mut inc, mut side, mut det, mut az) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let (mut value, mut se, mut bsdf, mut hits) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for r in &res.incidences {
        for (k, d) in dets.iter().enumerate() {
            inc.push(r.incidence.to_degrees());
            side.push(d.side.label());
            det.push(d.angle_deg);
            az.push(d.azimuth_deg);
            value.push(r.value[k]);
            se.push(r.value_stderr[k]);
            bsdf.push(r.bsdf[k]);
            hits.push(r.hits[k]);
        }
    }
    let mut j = serde_json::json!({
        "incidence_deg": inc, "side": side, "detector_deg": det,
        "value": value, "value_stderr": se, "bsdf": bsdf, "n_hits": hits,
    });
    if gonio.detectors().is_hemisphere() {
        j["detector_azimuth_deg"] = serde_json::json!(az);
    }
    j
}

/// Runs `opal gonio simulate` without writing files (the Python package's entry point):
/// `{"curves": curves_json, "totals": totals_json}`; `cancel` stops the run early.
pub fn simulate_json(
    args: GonioArgs,
    cancel: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>,
) -> Result<serde_json::Value> {
    let GonioCmd::Simulate(a) = args.cmd;
    let file = match &a.plate {
        Some(p) => read_plate_file(p)?,
        None => PlateFile::default(),
    };
    let cfg = build_config(&file, &a.overrides())?;
    let gonio = Gonio::new(cfg.setup.clone()).map_err(|e| anyhow::anyhow!("{e}"))?.with_cancel(cancel);
    let batches = cfg.setup.photons.div_ceil(opal::gonio::BATCH) * cfg.setup.incidences.len() as u64;
    let pb = progress(batches, "gonio");
    let t0 = std::time::Instant::now();
    let res = gonio.run_plate_with_progress(&cfg.plate, &|| pb.inc(1))?;
    pb.finish_and_clear();
    let secs = t0.elapsed().as_secs_f64();
    if let Some(p) = &a.plot {
        write_plot(p, &gonio, &res, "opal gonio")?;
    }
    Ok(serde_json::json!({"curves": curves_json(&gonio, &res), "totals": totals_json(&res, secs)}))
}

/// `opal gonio …`.
pub fn run(args: GonioArgs) -> Result<i32> {
    match args.cmd {
        GonioCmd::Simulate(a) => run_simulate(a),
    }
}

fn run_simulate(a: SimulateArgs) -> Result<i32> {
    crate::util::set_threads(a.threads);
    let file = match &a.plate {
        Some(p) => read_plate_file(p)?,
        None => PlateFile::default(),
    };
    let mut inputs: Vec<&Path> = Vec::new();
    if let Some(p) = &a.plate {
        inputs.push(p);
    }
    crate::util::ensure_not_input(&a.output, &inputs)?;
    let cfg = build_config(&file, &a.overrides())?;
    let (gonio, res, secs) = simulate(&cfg)?;
    let bad: u64 = res.incidences.iter().map(|r| r.bad_photons).sum();
    if bad > 0 {
        eprintln!("warning: {bad} photons had non-finite weights or directions");
    }
    write_csv(&a.output, &gonio, &res)?;
    if let Some(plot) = &a.plot {
        crate::util::ensure_not_input(plot, &inputs)?;
        write_plot(plot, &gonio, &res, "opal gonio")?;
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&totals_json(&res, secs))?);
    }
    Ok(0)
}

/// `opal demo` part: a small simulation (GGX α = 0.15 rough back face, 400 000 photons per
/// incidence) with its plot into `out_dir/gonio/`; returns a JSON summary.
pub fn demo(out_dir: &Path) -> Result<serde_json::Value> {
    let dir = out_dir.join("gonio");
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let args = SimulateArgs { output: dir.join("curves.csv"), photons: Some(400_000), ..Default::default() };
    let cfg = build_config(&PlateFile::default(), &args.overrides())?;
    let (gonio, res, secs) = simulate(&cfg)?;
    write_csv(&args.output, &gonio, &res)?;
    write_plot(&dir.join("curves.png"), &gonio, &res, "GGX α=0.15, smooth entry")?;
    let mut j = totals_json(&res, secs);
    j["csv"] = serde_json::json!(args.output.display().to_string());
    j["plot"] = serde_json::json!(dir.join("curves.png").display().to_string());
    Ok(j)
}
