//! `opal gonio simulate`: the virtual goniophotometer (plate, beam, detectors) of
//! [`opal::gonio`], configured by a PLATE.toml (format in `docs/gonio.md`) and/or flags.

use crate::plot::{LinePlot, Series, save_panels};
use crate::util::{progress, write_atomic};
use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand};
use opal::bsdf::microfacet::{Ndfs, Profile};
use opal::gonio::{
    Beam, DetectorGrid, DetectorLayout, Face, Gonio, GonioResult, GonioSetup, Plate, Scattering, Side,
};
use serde::Deserialize;
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
    /// Also plot value vs detector angle (PNG or SVG by extension).
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Print the totals R, T, lost per incidence as JSON on stdout.
    #[arg(long)]
    pub json: bool,
    /// Refractive index of the plate.
    #[arg(long, allow_hyphen_values = true)]
    pub ior: Option<f64>,
    /// Plate thickness in mm.
    #[arg(long, allow_hyphen_values = true)]
    pub thickness_mm: Option<f64>,
    /// Which face is lit: the polished one (`smooth`) or the rough one (`rough`).
    #[arg(long)]
    pub entry: Option<String>,
    /// Beam divergence (half-angle, degrees).
    #[arg(long, allow_hyphen_values = true)]
    pub divergence_deg: Option<f64>,
    /// Angular radius of the detectors (degrees).
    #[arg(long, allow_hyphen_values = true)]
    pub detector_radius_deg: Option<f64>,
    /// NDF of the rough face: FAMILY:ALPHA (ggx:0.15, beckmann:0.25) or student:ALPHA:GAMMA.
    #[arg(long, allow_hyphen_values = true)]
    pub ndf: Option<String>,
    /// Scattering model of the rough face: single, single-mitsuba (Mitsuba 3's G1), single-hc (height-correlated G), multiple.
    #[arg(long)]
    pub scattering: Option<String>,
}

/// PLATE.toml.
#[derive(Deserialize, Debug, Default)]
#[serde(deny_unknown_fields)]
pub struct PlateFile {
    /// The sample.
    #[serde(default)]
    pub plate: PlateSpec,
    /// The beam.
    #[serde(default)]
    pub beam: BeamSpec,
    /// The detectors.
    #[serde(default)]
    pub detectors: DetectorSpec,
    /// Run parameters.
    #[serde(default)]
    pub run: RunSpec,
}

/// `[plate]`.
#[derive(Deserialize, Debug, Default)]
#[serde(deny_unknown_fields)]
pub struct PlateSpec {
    /// Refractive index (default 1.49).
    pub ior: Option<f64>,
    /// Thickness in mm (default 2).
    pub thickness_mm: Option<f64>,
    /// Absorption coefficient in 1/mm (default 0).
    pub absorption_per_mm: Option<f64>,
    /// Radius of a finite plate in mm (default: infinite).
    pub radius_mm: Option<f64>,
    /// `smooth` (the polished face is lit, default) or `rough`; with two faces of the same kind
    /// use `lit` instead.
    pub entry: Option<String>,
    /// `front` (default) or `back`: which face is lit.
    pub lit: Option<String>,
    /// Front face (default polished).
    pub front: Option<FaceSpec>,
    /// Back face (default rough, GGX α = 0.15, single scattering).
    pub back: Option<FaceSpec>,
}

/// `[plate.front]` / `[plate.back]`.
#[derive(Deserialize, Debug, Clone, Default)]
#[serde(deny_unknown_fields)]
pub struct FaceSpec {
    /// `polished` or `rough`.
    #[serde(rename = "type")]
    pub kind: String,
    /// NDF family (`ggx`, `beckmann`) or FAMILY:ALPHA.
    pub ndf: Option<String>,
    /// Roughness α.
    pub alpha: Option<f64>,
    /// `single` (default), `single-hc` or `multiple`.
    pub scattering: Option<String>,
    /// Student-t tail exponent γ ≥ 2 (`ndf = "student"`; 2 = GGX, ∞ = Beckmann).
    pub gamma: Option<f64>,
    /// Peak shift δ of the NDF along θ (degrees).
    pub shift_deg: Option<f64>,
    /// Tabulated NDF (`ndf = "table"`) or tabulated part of a hybrid (`ndf = "hybrid"`): θ nodes.
    pub table_theta_deg: Option<Vec<f64>>,
    /// Values D(θ) at the nodes (≥ 0; normalised automatically).
    pub table_d: Option<Vec<f64>>,
    /// Analytic base of a hybrid NDF, FAMILY:ALPHA (ggx, beckmann) or student:ALPHA:GAMMA.
    pub base: Option<String>,
}

/// `[beam]`.
#[derive(Deserialize, Debug, Default)]
#[serde(deny_unknown_fields)]
pub struct BeamSpec {
    /// Incidence angles (default 0, 15, …, 75).
    pub incidences_deg: Option<Vec<f64>>,
    /// Azimuth of the plane of incidence (default 0).
    pub azimuth_deg: Option<f64>,
    /// Half-angle divergence (default 0.5°).
    pub divergence_deg: Option<f64>,
    /// Beam radius in mm (finite plates; default 1).
    pub aperture_radius_mm: Option<f64>,
}

/// `[detectors]`.
#[derive(Deserialize, Debug, Default)]
#[serde(deny_unknown_fields)]
pub struct DetectorSpec {
    /// `plane` (default) or `hemisphere`.
    pub layout: Option<String>,
    /// Angular radius (default 1°).
    pub radius_deg: Option<f64>,
    /// Plane layout: signed angles (default −89, −88, …, 89).
    pub angles_deg: Option<Vec<f64>>,
    /// Hemisphere layout: polar step (default 5°).
    pub polar_step_deg: Option<f64>,
    /// Hemisphere layout: azimuth step (default 10°).
    pub azimuth_step_deg: Option<f64>,
    /// Distance from the plate centre in mm (finite plates; default: far field).
    pub distance_mm: Option<f64>,
}

/// `[run]`.
#[derive(Deserialize, Debug, Default)]
#[serde(deny_unknown_fields)]
pub struct RunSpec {
    /// Photons per incidence (default 1 000 000).
    pub photons: Option<u64>,
    /// Seed (default 1).
    pub seed: Option<u64>,
    /// Interaction limit per photon (default 200).
    pub max_interactions: Option<u32>,
}

/// Parses `FAMILY:ALPHA` (`ggx:0.15`, `beckmann:0.25`) or `student:ALPHA:GAMMA` into a profile.
pub fn parse_profile(spec: &str, alpha: Option<f64>, gamma: Option<f64>, what: &str) -> Result<Profile> {
    let parts: Vec<&str> = spec.split(':').map(str::trim).collect();
    let fam = parts[0].to_ascii_lowercase();
    let num = |i: usize, fallback: Option<f64>, name: &str| -> Result<f64> {
        match (parts.get(i), fallback) {
            (Some(s), _) => s.parse::<f64>().with_context(|| format!("{what}: bad {name} {s:?} in {spec:?}")),
            (None, Some(v)) => Ok(v),
            (None, None) => bail!("{what}: missing {name} in {spec:?} (e.g. ggx:0.15, student:0.2:3)"),
        }
    };
    let max_parts = if fam == "student" { 3 } else { 2 };
    if parts.len() > max_parts {
        bail!("{what}: too many ':' in {spec:?}");
    }
    let alpha = num(1, alpha, "alpha")?;
    if !(alpha.is_finite() && alpha > 0.0) {
        bail!("{what}: alpha must be > 0, got {alpha}");
    }
    let p = match fam.as_str() {
        "ggx" | "trowbridge-reitz" | "tr" => Profile::Ggx { alpha },
        "beckmann" => Profile::Beckmann { alpha },
        "student" => Profile::StudentT { alpha, gamma: num(2, gamma, "gamma")? },
        _ => bail!("{what}: unknown NDF family {fam:?} (ggx, beckmann, student, table, hybrid)"),
    };
    p.validate().map_err(|e| anyhow::anyhow!("{what}: {e}"))?;
    Ok(p)
}

/// Builds the NDF from a profile: analytic GGX/Beckmann stay closed-form, the rest is tabulated.
pub fn ndf_from_profile(p: Profile, what: &str) -> Result<Ndfs> {
    Ok(match p {
        Profile::Ggx { alpha } => Ndfs::ggx(alpha as f32),
        Profile::Beckmann { alpha } => Ndfs::beckmann(alpha as f32),
        p => Ndfs::numeric(p).map_err(|e| anyhow::anyhow!("{what}: {e}"))?,
    })
}

/// Parses `FAMILY:ALPHA` / `student:ALPHA:GAMMA` into an NDF.
pub fn parse_ndf(spec: &str, alpha: Option<f64>, what: &str) -> Result<Ndfs> {
    ndf_from_profile(parse_profile(spec, alpha, None, what)?, what)
}

fn face_ndf(spec: &FaceSpec, what: &str) -> Result<Ndfs> {
    let name = spec.ndf.as_deref().unwrap_or("");
    let fam = name.split(':').next().unwrap_or("").trim().to_ascii_lowercase();
    let table = || -> Result<(Vec<f64>, Vec<f64>)> {
        let (Some(t), Some(d)) = (&spec.table_theta_deg, &spec.table_d) else {
            bail!("{what}: ndf = {fam:?} needs table_theta_deg and table_d");
        };
        Ok((t.iter().map(|x| x.to_radians()).collect(), d.clone()))
    };
    let mut profile = match fam.as_str() {
        "table" => {
            let (theta, d) = table()?;
            Profile::Table { theta, d }
        }
        "hybrid" => {
            let base =
                spec.base.as_deref().with_context(|| format!("{what}: ndf = \"hybrid\" needs base"))?;
            let base = parse_profile(base, spec.alpha, spec.gamma, &format!("{what}.base"))?;
            let (theta, d) = table()?;
            Profile::Hybrid { base: Box::new(base), theta, d }
        }
        _ => parse_profile(name, spec.alpha, spec.gamma, &format!("{what}.ndf"))?,
    };
    if let Some(s) = spec.shift_deg {
        profile = Profile::Shifted { base: Box::new(profile), delta: s.to_radians() };
    }
    profile.validate().map_err(|e| anyhow::anyhow!("{what}: {e}"))?;
    ndf_from_profile(profile, what)
}

fn parse_scattering(s: &str, what: &str) -> Result<Scattering> {
    Ok(match s {
        "single" => Scattering::Single,
        "single-mitsuba" => Scattering::SingleMitsuba,
        "single-hc" => Scattering::SingleHeightCorrelated,
        "multiple" => Scattering::Multiple,
        _ => bail!("{what}: unknown scattering {s:?} (single, single-mitsuba, single-hc, multiple)"),
    })
}

fn face(spec: &FaceSpec, what: &str, ndf_flag: Option<&str>, scat_flag: Option<&str>) -> Result<Face> {
    match spec.kind.as_str() {
        "polished" | "smooth" => {
            if spec.ndf.is_some() || spec.alpha.is_some() {
                bail!("{what}: a polished face takes no ndf/alpha");
            }
            Ok(Face::Polished)
        }
        "rough" => {
            let ndf = match (ndf_flag, &spec.ndf) {
                (Some(f), _) => parse_ndf(f, None, "--ndf")?,
                (None, Some(_)) => face_ndf(spec, what)?,
                (None, None) => bail!("{what}: a rough face needs ndf (e.g. ndf = \"ggx\", alpha = 0.15)"),
            };
            let scattering = match (scat_flag, &spec.scattering) {
                (Some(s), _) => parse_scattering(s, "--scattering")?,
                (None, Some(s)) => parse_scattering(s, &format!("{what}.scattering"))?,
                (None, None) => Scattering::Single,
            };
            Ok(Face::Rough { ndf, scattering })
        }
        k => bail!("{what}.type: unknown face type {k:?} (polished, rough)"),
    }
}

/// The resolved configuration.
pub struct Config {
    /// Simulator setup.
    pub setup: GonioSetup,
    /// The plate (front = lit face).
    pub plate: Plate,
}

/// Merges file and flags into a validated configuration.
pub fn build_config(file: &PlateFile, a: &SimulateArgs) -> Result<Config> {
    let p = &file.plate;
    let ior = a.ior.or(p.ior).unwrap_or(1.49);
    if !(ior.is_finite() && ior > 0.0) {
        bail!("plate.ior: must be > 0, got {ior}");
    }
    let thickness_mm = a.thickness_mm.or(p.thickness_mm).unwrap_or(2.0);
    if !(thickness_mm.is_finite() && thickness_mm > 0.0) {
        bail!("plate.thickness_mm: must be > 0, got {thickness_mm}");
    }
    let absorption_per_mm = p.absorption_per_mm.unwrap_or(0.0);
    let front_spec = p.front.clone().unwrap_or(FaceSpec { kind: "polished".into(), ..Default::default() });
    let back_spec = p.back.clone().unwrap_or(FaceSpec {
        kind: "rough".into(),
        ndf: Some("ggx".into()),
        alpha: Some(0.15),
        ..Default::default()
    });
    // --ndf / --scattering apply to the rough face(s)
    let front = face(
        &front_spec,
        "plate.front",
        a.ndf.as_deref().filter(|_| front_spec.kind == "rough"),
        a.scattering.as_deref(),
    )?;
    let back = face(
        &back_spec,
        "plate.back",
        a.ndf.as_deref().filter(|_| back_spec.kind == "rough"),
        a.scattering.as_deref(),
    )?;
    let entry = a.entry.clone().or(p.entry.clone());
    let lit_back = match (&entry, &p.lit) {
        (Some(e), _) => {
            let (fr, br) = (matches!(front, Face::Rough { .. }), matches!(back, Face::Rough { .. }));
            if fr == br {
                bail!("entry = {e:?} needs exactly one rough face (use plate.lit = \"front\"|\"back\")");
            }
            match e.as_str() {
                "smooth" => fr,
                "rough" => br,
                _ => bail!("entry: must be smooth or rough, got {e:?}"),
            }
        }
        (None, Some(l)) => match l.as_str() {
            "front" => false,
            "back" => true,
            _ => bail!("plate.lit: must be front or back, got {l:?}"),
        },
        (None, None) => false,
    };
    let (front, back) = if lit_back { (back, front) } else { (front, back) };
    let plate = Plate { ior, thickness_mm, absorption_per_mm, front, back, radius_mm: p.radius_mm };
    opal::gonio::validate_plate(&plate).map_err(|e| anyhow::anyhow!("plate: {e}"))?;

    let b = &file.beam;
    let divergence_deg = a.divergence_deg.or(b.divergence_deg).unwrap_or(0.5);
    if !(divergence_deg.is_finite() && (0.0..90.0).contains(&divergence_deg)) {
        bail!("beam.divergence_deg: must be in [0, 90), got {divergence_deg}");
    }
    let incidences_deg = b.incidences_deg.clone().unwrap_or_else(|| vec![0.0, 15.0, 30.0, 45.0, 60.0, 75.0]);
    for &t in &incidences_deg {
        if !(t.is_finite() && (0.0..90.0).contains(&t)) {
            bail!("beam.incidences_deg: each must be in [0, 90), got {t}");
        }
    }
    if incidences_deg.is_empty() {
        bail!("beam.incidences_deg: empty");
    }
    let beam = Beam {
        azimuth: b.azimuth_deg.unwrap_or(0.0).to_radians(),
        divergence: divergence_deg.to_radians(),
        aperture_radius_mm: b.aperture_radius_mm.unwrap_or(1.0),
    };
    let d = &file.detectors;
    let radius_deg = a.detector_radius_deg.or(d.radius_deg).unwrap_or(1.0);
    if !(radius_deg.is_finite() && radius_deg > 0.0 && radius_deg < 90.0) {
        bail!("detectors.radius_deg: must be in (0, 90), got {radius_deg}");
    }
    let grid = match d.layout.as_deref().unwrap_or("plane") {
        "plane" => {
            let angles = d.angles_deg.clone().unwrap_or_else(|| (-89..=89).map(|x| x as f64).collect());
            for &x in &angles {
                if !(x.is_finite() && x.abs() < 90.0) {
                    bail!("detectors.angles_deg: each must be in (−90, 90), got {x}");
                }
            }
            DetectorGrid::PlaneOfIncidence { angles: angles.iter().map(|x| x.to_radians()).collect() }
        }
        "hemisphere" => {
            let ps = d.polar_step_deg.unwrap_or(5.0);
            let az = d.azimuth_step_deg.unwrap_or(10.0);
            if !(ps.is_finite() && ps > 0.0 && ps < 90.0) {
                bail!("detectors.polar_step_deg: must be in (0, 90), got {ps}");
            }
            if !(az.is_finite() && az > 0.0 && az <= 360.0) {
                bail!("detectors.azimuth_step_deg: must be in (0, 360], got {az}");
            }
            let polar = (0..).map(|i| i as f64 * ps).take_while(|t| *t < 90.0).map(f64::to_radians).collect();
            let azimuth =
                (0..).map(|i| i as f64 * az).take_while(|p| *p < 360.0 - 1e-9).map(f64::to_radians).collect();
            DetectorGrid::Hemisphere { polar, azimuth }
        }
        l => bail!("detectors.layout: must be plane or hemisphere, got {l:?}"),
    };
    let r = &file.run;
    let photons = a.photons.or(r.photons).unwrap_or(1_000_000);
    if photons == 0 {
        bail!("photons: must be > 0");
    }
    let setup = GonioSetup {
        beam,
        incidences: incidences_deg.iter().map(|t| t.to_radians()).collect(),
        detectors: DetectorLayout { grid, radius: radius_deg.to_radians(), distance_mm: d.distance_mm },
        photons,
        seed: a.seed.or(r.seed).unwrap_or(1),
        max_interactions: r.max_interactions.unwrap_or(200),
    };
    Ok(Config { setup, plate })
}

/// Reads PLATE.toml.
pub fn read_plate_file(path: &Path) -> Result<PlateFile> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
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

/// Runs a configuration with a progress bar; returns the simulator, result and wall time.
pub fn simulate(cfg: &Config) -> Result<(Gonio, GonioResult, f64)> {
    let gonio = Gonio::new(cfg.setup.clone()).map_err(|e| anyhow::anyhow!("{e}"))?;
    let batches = cfg.setup.photons.div_ceil(opal::gonio::BATCH) * cfg.setup.incidences.len() as u64;
    let pb = progress(batches, "gonio");
    let t0 = std::time::Instant::now();
    let res = gonio.run_plate_with_progress(&cfg.plate, &|| pb.inc(1)).map_err(|e| anyhow::anyhow!("{e}"))?;
    pb.finish_and_clear();
    Ok((gonio, res, t0.elapsed().as_secs_f64()))
}

/// `opal gonio …`.
pub fn run(args: GonioArgs) -> Result<i32> {
    match args.cmd {
        GonioCmd::Simulate(a) => run_simulate(a),
    }
}

fn run_simulate(a: SimulateArgs) -> Result<i32> {
    let file = match &a.plate {
        Some(p) => read_plate_file(p)?,
        None => PlateFile::default(),
    };
    let mut inputs: Vec<&Path> = Vec::new();
    if let Some(p) = &a.plate {
        inputs.push(p);
    }
    crate::util::ensure_not_input(&a.output, &inputs)?;
    let cfg = build_config(&file, &a)?;
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
    let cfg = build_config(&PlateFile::default(), &args)?;
    let (gonio, res, secs) = simulate(&cfg)?;
    write_csv(&args.output, &gonio, &res)?;
    write_plot(&dir.join("curves.png"), &gonio, &res, "GGX α=0.15, smooth entry")?;
    let mut j = totals_json(&res, secs);
    j["csv"] = serde_json::json!(args.output.display().to_string());
    j["plot"] = serde_json::json!(dir.join("curves.png").display().to_string());
    Ok(j)
}
