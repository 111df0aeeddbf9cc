//! The plate grammar shared by the subcommands that simulate a plate (`opal gonio simulate`,
//! `opal fit-ndf`): PLATE.toml (format in `docs/gonio.md`), the NDF and scattering-model
//! spellings, and the merge of file and command-line overrides into a validated
//! [`Config`]. Covered by `cmd::fit_ndf`'s unit test `fitted_face_toml_round_trips` and the
//! CLI tests `tests/gonio.rs` and `tests/fit_ndf.rs`.

use anyhow::{Context, Result, bail};
use opal::bsdf::microfacet::{Ndfs, Profile};
use opal::gonio::{Beam, DetectorGrid, DetectorLayout, Face, GonioSetup, Plate, Scattering};
use serde::Deserialize;
use std::path::Path;

/// The plate, beam and detector flags of `gonio simulate` and `fit-ndf` (one definition for
/// both); each overrides the PLATE.toml field of the same meaning.
#[derive(clap::Args, Debug, Default, Clone)]
pub struct PlateFlags {
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
}

/// Values given on the command line; each one overrides the PLATE.toml field of the same
/// meaning (`None`: the file's value or the default).
#[derive(Debug, Default, Clone)]
pub struct PlateOverrides {
    /// Photons per incidence.
    pub photons: Option<u64>,
    /// Random seed.
    pub seed: Option<u64>,
    /// Plate, beam and detector values.
    pub plate: PlateFlags,
    /// NDF of the rough face(s): FAMILY:ALPHA or student:ALPHA:GAMMA (flag `--ndf`).
    pub ndf: Option<String>,
    /// Scattering model of the rough face(s) (flag `--scattering`).
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
    /// `polished`, `rough` or `dotted` (rough dots, given by the NDF keys, on a fraction
    /// `coverage` of a polished face).
    #[serde(rename = "type")]
    pub kind: String,
    /// Fraction of a `dotted` face covered by the rough dots, in [0, 1].
    pub coverage: Option<f64>,
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

/// Parses a scattering model name (`single`, `single-mitsuba`, `single-hc`, `multiple`); `what`
/// names the setting in the error.
pub fn parse_scattering(s: &str, what: &str) -> Result<Scattering> {
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
            if spec.ndf.is_some() || spec.alpha.is_some() || spec.coverage.is_some() {
                bail!("{what}: a polished face takes no ndf/alpha/coverage");
            }
            Ok(Face::Polished)
        }
        "rough" | "dotted" => {
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
            match (spec.kind.as_str(), spec.coverage) {
                ("rough", None) => Ok(Face::Rough { ndf, scattering }),
                ("rough", Some(_)) => bail!("{what}: coverage is for type = \"dotted\""),
                (_, Some(f)) if f.is_finite() && (0.0..=1.0).contains(&f) => {
                    Ok(Face::dotted(f, ndf, scattering))
                }
                (_, Some(f)) => bail!("{what}.coverage: must be in [0, 1], got {f}"),
                (_, None) => bail!("{what}: a dotted face needs coverage (the rough fraction, e.g. 0.3)"),
            }
        }
        k => bail!("{what}.type: unknown face type {k:?} (polished, rough, dotted)"),
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
pub fn build_config(file: &PlateFile, a: &PlateOverrides) -> Result<Config> {
    let p = &file.plate;
    let ior = a.plate.ior.or(p.ior).unwrap_or(1.49);
    if !(ior.is_finite() && ior > 0.0) {
        bail!("plate.ior: must be > 0, got {ior}");
    }
    let thickness_mm = a.plate.thickness_mm.or(p.thickness_mm).unwrap_or(2.0);
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
        a.ndf.as_deref().filter(|_| front_spec.kind != "polished"),
        a.scattering.as_deref(),
    )?;
    let back = face(
        &back_spec,
        "plate.back",
        a.ndf.as_deref().filter(|_| back_spec.kind != "polished"),
        a.scattering.as_deref(),
    )?;
    let entry = a.plate.entry.clone().or(p.entry.clone());
    let lit_back = match (&entry, &p.lit) {
        (Some(e), _) => {
            let (fr, br) = (front.is_rough(), back.is_rough());
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
    let divergence_deg = a.plate.divergence_deg.or(b.divergence_deg).unwrap_or(0.5);
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
    let radius_deg = a.plate.detector_radius_deg.or(d.radius_deg).unwrap_or(1.0);
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
