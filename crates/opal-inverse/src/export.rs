//! Exports of a fitted rough face: the NDF as a table and the BSDF of the rough dielectric
//! interface for both sides (light from air into the material, and from the material into
//! air), reflection and transmission, as CSV and in the Zemax/OpticStudio tabular `.BSDF` text
//! format (Radiant "BSDF Data Interchange" layout). Formats in `docs/formats.md`.
//!
//! Conventions: local frame of the rough face, +z = air side, `eta` = n_material. The light
//! arrives in the plane x–z from −x: the direction towards the source is
//! `l = (−sin θi, 0, ±cos θi)` (+ from air, − from the material), so the specular reflection is
//! at azimuth 0. The tabulated value for a scatter direction `s` is the power BSDF
//! `f(l → s) = f_importance(wo = l, wi = s)` of the face model [`FaceModel`] — the scattering
//! model of the fit: single scattering ([`RoughDielectric`], separable, Mitsuba's or the
//! height-correlated Smith G) or multiple scattering ([`RoughDielectricMs`]) — in 1/sr: the fraction of the incident power scattered per unit
//! projected solid angle, so `TIS = ∫ f |cos θs| dω` is the scattered fraction of the power (the
//! quantity a ray tracer that transports power, such as OpticStudio, expects). TIS is
//! integrated on a fine midpoint grid (0.25° × 1°), independently of the table's resolution,
//! for single scattering; for multiple scattering it is the fraction of [`MS_TIS_WALKS`] seeded
//! random walks that leave on each side (exact in distribution; standard error
//! ≤ 0.5/√walks), and the tabulated values are `eval` with [`MS_EVAL_WALKS`] walks from each
//! end (the order-1 part exact, orders ≥ 2 an unbiased, deterministic estimate).
//! The Zemax file is built as a [`BsdfTable`] ([`zemax_table`]) and printed by
//! [`crate::scatter::zemax::write`]; the LightTools file (both sides, R and T) by
//! [`lighttools`].
//! A dotted face ([`FaceModel::Dotted`], the fit's dotted model) is exported as the face that
//! was fitted: `coverage` × the dots' BSDF plus the polished land's specular spike
//! ([`specular_fractions`]), which the TIS includes, the CSV lists in its TIS table and the
//! tables spread over the cell of their specular node.
//!
//! Tests: `tests` below (energy: R + T ≤ 1 and ≈ 1 for a smooth-ish surface, the Zemax file's
//! structure, an exported `.BSDF` read back reproduces the face at every tabulated direction
//! to the printed precision, the multiple-scattering export keeps energy and differs from the
//! single-scattering one).

pub mod lighttools;

use crate::scatter::zemax::{
    Block, BsdfTable, Channel, ChannelData, Precision, ScatterType, SpectralContent, Symmetry,
};
use opal::bsdf::microfacet::{Ndf, Ndfs};
use opal::bsdf::rough_dielectric::{RoughDielectric, Shadowing};
use opal::bsdf::rough_dielectric_ms::RoughDielectricMs;
use opal::bsdf::{Bxdf, TransportMode};
use opal::gonio::Scattering;
use opal::math::Vec3;
use opal::sampling::Rng;
use std::f64::consts::PI;
use std::fmt::Write;

/// Which side the light comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LightSide {
    /// From air into the material.
    AirToMaterial,
    /// From the material into air.
    MaterialToAir,
}

impl LightSide {
    /// `air_to_material` / `material_to_air`.
    pub fn label(self) -> &'static str {
        match self {
            LightSide::AirToMaterial => "air_to_material",
            LightSide::MaterialToAir => "material_to_air",
        }
    }
    pub(crate) fn sign(self) -> f32 {
        match self {
            LightSide::AirToMaterial => 1.0,
            LightSide::MaterialToAir => -1.0,
        }
    }
}

/// The NDF as a table: rows (θm in degrees, D(θm), D(θm) cos θm).
pub fn ndf_table(ndf: &Ndfs, step_deg: f64) -> Vec<(f64, f64, f64)> {
    let n = (90.0 / step_deg).round() as usize;
    (0..n)
        .map(|i| {
            let t = (i as f64 * step_deg).to_radians();
            let wm = Vec3::new(t.sin() as f32, 0.0, t.cos() as f32);
            let d = ndf.d(wm) as f64;
            (t.to_degrees(), d, d * t.cos())
        })
        .collect()
}

/// The rough face's BSDF model (single scattering, separable Smith G).
pub fn face_bsdf(ndf: Ndfs, ior: f64) -> opal::Result<RoughDielectric> {
    RoughDielectric::new(ndf, ior as f32, Shadowing::Separable)
}

/// Walks per end of every multiple-scattering `eval` in the exports.
pub const MS_EVAL_WALKS: u32 = 16;
/// Random walks per incidence of the multiple-scattering TIS.
pub const MS_TIS_WALKS: u32 = 100_000;

/// The exported face: the BSDF of the scattering model the fit used.
#[derive(Clone, Debug)]
pub enum FaceModel {
    /// Single scattering (the Smith G of the model).
    Single(RoughDielectric),
    /// Multiple scattering on the micro-surface (random walk).
    Multiple(RoughDielectricMs),
    /// Dotted face (the fit's dotted model, [`opal::bsdf::Dotted`]): rough `dots` on a fraction
    /// `coverage` of the face, the rest polished. Its BSDF is `coverage · f_dots` plus a specular
    /// spike of power fractions [`specular_fractions`] in the mirror and refracted directions.
    Dotted {
        /// Fraction f ∈ [0, 1] of the face covered by the dots.
        coverage: f64,
        /// The dots' face (not itself dotted).
        dots: Box<FaceModel>,
    },
}

impl From<RoughDielectric> for FaceModel {
    fn from(b: RoughDielectric) -> Self {
        FaceModel::Single(b)
    }
}

impl FaceModel {
    /// The face with NDF `ndf` on a material of index `ior` for a scattering model.
    pub fn new(ndf: Ndfs, ior: f64, scattering: Scattering) -> opal::Result<Self> {
        let eta = ior as f32;
        Ok(match scattering {
            Scattering::Single => FaceModel::Single(RoughDielectric::new(ndf, eta, Shadowing::Separable)?),
            Scattering::SingleMitsuba => {
                FaceModel::Single(RoughDielectric::new(ndf, eta, Shadowing::SeparableMitsuba)?)
            }
            Scattering::SingleHeightCorrelated => {
                FaceModel::Single(RoughDielectric::new(ndf, eta, Shadowing::HeightCorrelated)?)
            }
            Scattering::Multiple => {
                let mut ms = RoughDielectricMs::new(ndf, eta)?;
                ms.eval_walks = MS_EVAL_WALKS;
                FaceModel::Multiple(ms)
            }
        })
    }

    /// The dotted face of the fit: dots with NDF `ndf` (scattering model `scattering`) on a
    /// fraction `coverage` of a polished face; error unless `coverage` ∈ [0, 1].
    pub fn dotted(coverage: f64, ndf: Ndfs, ior: f64, scattering: Scattering) -> opal::Result<Self> {
        if !(coverage.is_finite() && (0.0..=1.0).contains(&coverage)) {
            return Err(opal::Error::invalid("coverage", format!("must be in [0, 1], got {coverage}")));
        }
        Ok(FaceModel::Dotted { coverage, dots: Box::new(Self::new(ndf, ior, scattering)?) })
    }

    /// The face of a fitted model: [`FaceModel::dotted`] when `coverage` is `Some`, else
    /// [`FaceModel::new`].
    pub fn fitted(ndf: Ndfs, ior: f64, scattering: Scattering, coverage: Option<f64>) -> opal::Result<Self> {
        match coverage {
            Some(f) => Self::dotted(f, ndf, ior, scattering),
            None => Self::new(ndf, ior, scattering),
        }
    }

    /// n_material / n_air.
    pub fn eta(&self) -> f32 {
        match self {
            FaceModel::Single(b) => b.eta,
            FaceModel::Multiple(b) => b.eta,
            FaceModel::Dotted { dots, .. } => dots.eta(),
        }
    }

    /// `single scattering` or `multiple scattering` (for file comments), prefixed for a dotted
    /// face by its coverage.
    pub fn describe(&self) -> String {
        match self {
            FaceModel::Single(_) => "single scattering".into(),
            FaceModel::Multiple(_) => "multiple scattering".into(),
            FaceModel::Dotted { coverage, dots } => {
                format!(
                    "dotted: {coverage:.4} of the face rough dots ({}), the rest polished",
                    dots.describe()
                )
            }
        }
    }

    fn eval_importance(&self, wo: Vec3, wi: Vec3) -> f64 {
        let v = match self {
            FaceModel::Single(b) => b.eval(wo, wi, TransportMode::Importance),
            FaceModel::Multiple(b) => b.eval(wo, wi, TransportMode::Importance),
            FaceModel::Dotted { coverage, dots } => return coverage * dots.eval_importance(wo, wi),
        };
        v.average() as f64
    }
}

/// Power fractions (reflected, transmitted) of the face's specular spike (the polished land of
/// a dotted face: (1 − f)·(F, 1 − F) with the Fresnel reflectance F at `aoi`; total internal
/// reflection from the material beyond the critical angle); (0, 0) for a rough face.
pub fn specular_fractions(b: &FaceModel, side: LightSide, aoi: f64) -> (f64, f64) {
    match b {
        FaceModel::Dotted { coverage, dots } => {
            let fr = opal::math::fresnel_dielectric_f64(side.sign() as f64 * aoi.cos(), dots.eta() as f64);
            ((1.0 - coverage) * fr, (1.0 - coverage) * (1.0 - fr))
        }
        _ => (0.0, 0.0),
    }
}

fn light_dir(side: LightSide, aoi: f64) -> Vec3 {
    Vec3::new(-(aoi.sin() as f32), 0.0, side.sign() * aoi.cos() as f32)
}

/// Power BSDF f(l → s) (see module docs); for a dotted face the part without the specular
/// spike (the spike is [`specular_fractions`]).
pub fn power_bsdf(b: &FaceModel, side: LightSide, aoi: f64, s: Vec3) -> f64 {
    b.eval_importance(light_dir(side, aoi), s)
}

/// Total integrated scatter (reflected, transmitted) fractions of the incident power (see the
/// module documentation for how each model integrates it).
pub fn tis(b: &FaceModel, side: LightSide, aoi: f64) -> (f64, f64) {
    match b {
        FaceModel::Dotted { coverage, dots } => {
            let (r, t) = tis(dots, side, aoi);
            let (sr, st) = specular_fractions(b, side, aoi);
            (coverage * r + sr, coverage * t + st)
        }
        FaceModel::Single(_) => tis_quadrature(b, side, aoi),
        FaceModel::Multiple(ms) => {
            let l = light_dir(side, aoi);
            let mut rng = Rng::new(0x7155, aoi.to_bits(), side.sign().to_bits() as u64);
            let (mut r, mut t) = (0u64, 0u64);
            for _ in 0..MS_TIS_WALKS {
                match ms.sample_dir(l, &mut rng) {
                    Some(w) if w.z * l.z > 0.0 => r += 1,
                    Some(w) if w.z * l.z < 0.0 => t += 1,
                    _ => {}
                }
            }
            let n = MS_TIS_WALKS as f64;
            (r as f64 / n, t as f64 / n)
        }
    }
}

fn tis_quadrature(b: &FaceModel, side: LightSide, aoi: f64) -> (f64, f64) {
    let (nt, np) = (360usize, 180usize);
    let dt = PI / 2.0 / nt as f64;
    let dp = PI / np as f64;
    let mut r = 0.0;
    let mut t = 0.0;
    for i in 0..nt {
        let th = (i as f64 + 0.5) * dt;
        let w = th.cos() * th.sin() * dt * dp * 2.0; // φ over [0, π], mirrored
        for j in 0..np {
            let ph = (j as f64 + 0.5) * dp;
            let (x, y, z) = ((th.sin() * ph.cos()) as f32, (th.sin() * ph.sin()) as f32, th.cos() as f32);
            let up = Vec3::new(x, y, z);
            let down = Vec3::new(x, y, -z);
            let (fr, ft) = match side {
                LightSide::AirToMaterial => (up, down),
                LightSide::MaterialToAir => (down, up),
            };
            r += power_bsdf(b, side, aoi, fr) * w;
            t += power_bsdf(b, side, aoi, ft) * w;
        }
    }
    (r, t)
}

/// Writes the BSDF of both sides as CSV: `light_side,aoi_deg,scatter,theta_s_deg,phi_s_deg,
/// bsdf` (`scatter` R or T; θs from the normal of the hemisphere the light leaves into; φs from
/// the plane of incidence, 0 = forward), then one `#`-free summary per (side, aoi) in a second
/// table `tis` returned separately: `tis_R,tis_T,R_plus_T` (spike included) and
/// `specular_R,specular_T`, the power fractions of a dotted face's specular spike
/// ([`specular_fractions`], 0 for a rough face), which the `bsdf` values (a density) leave out.
pub fn bsdf_csv(b: &FaceModel, aois_deg: &[f64], theta_step_deg: f64, phi_step_deg: f64) -> (String, String) {
    let mut out = String::from("light_side,aoi_deg,scatter,theta_s_deg,phi_s_deg,bsdf\n");
    let mut tis_csv = String::from("light_side,aoi_deg,tis_R,tis_T,R_plus_T,specular_R,specular_T\n");
    let nt = (90.0 / theta_step_deg).round() as usize;
    let np = (180.0 / phi_step_deg).round() as usize;
    for side in [LightSide::AirToMaterial, LightSide::MaterialToAir] {
        for &a in aois_deg {
            let aoi = a.to_radians();
            for (scatter, zs) in [("R", side.sign()), ("T", -side.sign())] {
                for i in 0..nt {
                    let th = (i as f64 * theta_step_deg).to_radians();
                    for j in 0..=np {
                        let ph = (j as f64 * phi_step_deg).to_radians();
                        let s = Vec3::new(
                            (th.sin() * ph.cos()) as f32,
                            (th.sin() * ph.sin()) as f32,
                            zs * th.cos() as f32,
                        );
                        let _ = writeln!(
                            out,
                            "{},{},{},{},{},{:.6e}",
                            side.label(),
                            a,
                            scatter,
                            th.to_degrees().round(),
                            ph.to_degrees().round(),
                            power_bsdf(b, side, aoi, s)
                        );
                    }
                }
            }
            let (r, t) = tis(b, side, aoi);
            let (sr, st) = specular_fractions(b, side, aoi);
            let _ = writeln!(
                tis_csv,
                "{},{},{:.6},{:.6},{:.6},{:.6},{:.6}",
                side.label(),
                a,
                r,
                t,
                r + t,
                sr,
                st
            );
        }
    }
    (out, tis_csv)
}

/// Centre of the scatter coordinates (Zemax convention): the specular reflection, or the
/// refracted direction for transmission (the undeviated direction beyond the critical angle).
pub fn specular_center(b: &FaceModel, side: LightSide, aoi: f64, transmission: bool) -> Vec3 {
    let l = light_dir(side, aoi);
    if !transmission {
        return Vec3::new(-l.x, -l.y, l.z);
    }
    let eta = match side {
        LightSide::AirToMaterial => b.eta(),
        LightSide::MaterialToAir => 1.0 / b.eta(),
    };
    let st = l.x.abs() / eta;
    if st < 1.0 {
        let ct = (1.0 - st * st).sqrt();
        Vec3::new(st, 0.0, -side.sign() * ct)
    } else {
        -l
    }
}

/// The scatter direction at (`azimuth_deg`, `radial_deg`) about the centre `c` (azimuth 0
/// towards the normal of `c`'s hemisphere, azimuth 90° along `c × u`; the module
/// [`crate::scatter::zemax`] states the conventions).
pub fn scatter_dir(c: Vec3, azimuth_deg: f64, radial_deg: f64) -> Vec3 {
    let pole = Vec3::new(0.0, 0.0, c.z.signum());
    let u0 = pole - c * pole.dot(c);
    let u = if u0.length() > 1e-6 { u0.normalize() } else { Vec3::new(-1.0, 0.0, 0.0) };
    let v = c.cross(u);
    let (sa, ca) = (azimuth_deg.to_radians().sin() as f32, azimuth_deg.to_radians().cos() as f32);
    let (sr, cr) = (radial_deg.to_radians().sin() as f32, radial_deg.to_radians().cos() as f32);
    (c * cr + (u * ca + v * sa) * sr).normalize()
}

/// The table of one Zemax `.BSDF` file (`PlaneSymmetrical`, `Monochrome`, one sample rotation
/// 0°) for one light side and one scatter type: per AOI the TIS and the power BSDF at every
/// (azimuth, radial) about the specular / refracted direction (0 where that direction is
/// below the horizon). A dotted face's specular spike (a delta) is spread over the cap of
/// half the first radial step around radial 0 ([`spike_cap_deg`]): the radial-0 values get
/// `spike / (|cos θc| · Ω_cap)`, so the table integrates to the TIS, which includes the spike.
pub fn zemax_table(
    b: &FaceModel,
    side: LightSide,
    transmission: bool,
    aois_deg: &[f64],
    azimuths_deg: &[f64],
    radials_deg: &[f64],
) -> BsdfTable {
    let blocks = aois_deg
        .iter()
        .map(|&a| {
            let aoi = a.to_radians();
            let (r, t) = tis(b, side, aoi);
            let c = specular_center(b, side, aoi, transmission);
            let (sr, st) = specular_fractions(b, side, aoi);
            let spike = match spike_cap_deg(radials_deg) {
                Some(rho) if c.z != 0.0 => {
                    let cap = 2.0 * PI * (1.0 - rho.to_radians().cos());
                    (if transmission { st } else { sr }) / (c.z.abs() as f64 * cap)
                }
                _ => 0.0,
            };
            let mut values = Vec::with_capacity(azimuths_deg.len() * radials_deg.len());
            for &az in azimuths_deg {
                for &rd in radials_deg {
                    let s = scatter_dir(c, az, rd);
                    let f = if s.z * c.z > 0.0 { power_bsdf(b, side, aoi, s) } else { 0.0 };
                    values.push(if rd == 0.0 { f + spike } else { f });
                }
            }
            Block { tis: Some(if transmission { t } else { r }), values }
        })
        .collect();
    BsdfTable {
        source: "Measured".into(),
        symmetry: Symmetry::PlaneSymmetrical,
        spectral: SpectralContent::Monochrome,
        scatter_type: if transmission { ScatterType::Btdf } else { ScatterType::Brdf },
        sample_rotation_deg: vec![0.0],
        aoi_deg: aois_deg.to_vec(),
        azimuth_deg: azimuths_deg.to_vec(),
        radial_deg: radials_deg.to_vec(),
        channels: vec![ChannelData { channel: Channel::Monochrome, blocks }],
    }
}

/// Half-angle (degrees) of the cap a specular spike is spread over in a Zemax table: half the
/// first radial step (1° when radial 0 is the only radial); `None` when the radials do not
/// start at 0 (the spike then stays in the TIS only).
pub fn spike_cap_deg(radials_deg: &[f64]) -> Option<f64> {
    match radials_deg {
        [first, rest @ ..] if *first == 0.0 => Some(rest.first().map_or(1.0, |next| next / 2.0)),
        _ => None,
    }
}

/// One Zemax/OpticStudio tabular `.BSDF` file (the table of [`zemax_table`]) as text: the
/// lines of `comment` and an `Opal fit-ndf export` line as `#` comments, values with 6
/// significant digits ([`Precision::Export`]).
pub fn zemax_bsdf(
    b: &FaceModel,
    side: LightSide,
    transmission: bool,
    aois_deg: &[f64],
    azimuths_deg: &[f64],
    radials_deg: &[f64],
    comment: &str,
) -> String {
    let mut c = String::new();
    for l in comment.lines() {
        c.push_str(l);
        c.push('\n');
    }
    c.push_str(&format!(
        "Opal fit-ndf export: {} {}",
        side.label(),
        if transmission { "BTDF" } else { "BRDF" }
    ));
    let t = zemax_table(b, side, transmission, aois_deg, azimuths_deg, radials_deg);
    crate::scatter::zemax::write(&t, &c, Precision::Export)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn energy_of_both_sides() {
        // single scattering loses energy at grazing angles (and, from the material, near the
        // critical angle 42°); away from those and for small α the interface must conserve
        // R + T to within 2 % (quadrature error ≪ 1 %).
        let b = FaceModel::from(face_bsdf(Ndfs::ggx(0.1), 1.49).unwrap());
        for (side, aois) in
            [(LightSide::AirToMaterial, [0.0f64, 20.0, 40.0]), (LightSide::MaterialToAir, [0.0, 15.0, 25.0])]
        {
            for a in aois {
                let (r, t) = tis(&b, side, a.to_radians());
                assert!(r + t <= 1.005 && r + t > 0.98, "{side:?} {a}: R {r} T {t}");
            }
        }
        // from air at normal incidence R ≈ Fresnel 0.039
        let (r, _) = tis(&b, LightSide::AirToMaterial, 0.0);
        assert!((r - 0.0387).abs() < 0.004, "R {r}");
        // from the material beyond the critical angle (42°) almost all is reflected
        let (r, t) = tis(&b, LightSide::MaterialToAir, 60f64.to_radians());
        assert!(r > 5.0 * t, "R {r} T {t}");
    }

    #[test]
    fn zemax_structure() {
        let b = FaceModel::from(face_bsdf(Ndfs::beckmann(0.2), 1.49).unwrap());
        let az: Vec<f64> = (0..=18).map(|i| i as f64 * 10.0).collect();
        let rad: Vec<f64> = (0..=45).map(|i| i as f64 * 2.0).collect();
        let z = zemax_bsdf(&b, LightSide::AirToMaterial, true, &[0.0, 30.0], &az, &rad, "test");
        assert!(z.contains("ScatterType\tBTDF"));
        assert_eq!(z.matches("TIS\t").count(), 2);
        let data: Vec<&str> =
            z.lines().skip_while(|l| *l != "DataBegin").skip(1).take_while(|l| *l != "DataEnd").collect();
        assert_eq!(data.len(), 2 * (1 + az.len()));
        for l in data.iter().filter(|l| !l.starts_with("TIS")) {
            assert_eq!(l.split('\t').count(), rad.len());
        }
        // the peak of the transmitted lobe at normal incidence is at radial 0
        let first: Vec<f64> = data[1].split('\t').map(|x| x.parse().unwrap()).collect();
        assert!(first[0] >= first[5] && first[5] > first[20]);
    }

    /// An exported `.BSDF` read back reproduces the face at every tabulated direction to the
    /// printed precision (6 significant digits: relative error ≤ 5e-6; TIS 6 decimals).
    #[test]
    fn exported_bsdf_reads_back_the_face() {
        let b = FaceModel::new(Ndfs::ggx(0.2), 1.49, Scattering::Single).unwrap();
        let (aois, az, rad) = ([0.0, 35.0, 70.0], [0.0, 45.0, 90.0, 180.0], [0.0, 3.0, 10.0, 40.0, 85.0]);
        for side in [LightSide::AirToMaterial, LightSide::MaterialToAir] {
            for tr in [false, true] {
                let text = zemax_bsdf(&b, side, tr, &aois, &az, &rad, "read-back test");
                let t = crate::scatter::zemax::parse(&text, std::path::Path::new("x.BSDF")).unwrap();
                assert_eq!(t.scatter_type, if tr { ScatterType::Btdf } else { ScatterType::Brdf });
                assert_eq!((t.aoi_deg.as_slice(), t.azimuth_deg.as_slice()), (&aois[..], &az[..]));
                for (i, &a) in aois.iter().enumerate() {
                    let blk = t.block(0, 0, i);
                    let (r, tt) = tis(&b, side, a.to_radians());
                    assert!((blk.tis.unwrap() - if tr { tt } else { r }).abs() <= 5e-7);
                    let c = specular_center(&b, side, a.to_radians(), tr);
                    let mut nonzero = 0;
                    for (j, &p) in az.iter().enumerate() {
                        for (k, &q) in rad.iter().enumerate() {
                            let s = scatter_dir(c, p, q);
                            let f =
                                if s.z * c.z > 0.0 { power_bsdf(&b, side, a.to_radians(), s) } else { 0.0 };
                            let got = blk.values[j * rad.len() + k];
                            assert!(
                                (got - f).abs() <= 5e-6 * f,
                                "{side:?} {tr} aoi {a} az {p} rad {q}: {got} vs {f}"
                            );
                            nonzero += (f > 0.0) as usize;
                        }
                    }
                    assert!(nonzero > 0);
                }
            }
        }
    }

    /// `--scattering multiple` exports the multiple-scattering face: it keeps the energy the
    /// single-scattering model loses at a large roughness and grazing incidence.
    #[test]
    fn multiple_scattering_export_keeps_energy() {
        let ndf = Ndfs::ggx(0.7);
        let ss = FaceModel::new(ndf.clone(), 1.49, Scattering::Single).unwrap();
        let ms = FaceModel::new(ndf, 1.49, Scattering::Multiple).unwrap();
        let a = 70f64.to_radians();
        let (r1, t1) = tis(&ss, LightSide::AirToMaterial, a);
        let (r2, t2) = tis(&ms, LightSide::AirToMaterial, a);
        assert!(r2 + t2 > 0.995, "multiple: R {r2} T {t2}");
        assert!(r1 + t1 < r2 + t2 - 0.02, "single R+T {} vs multiple {}", r1 + t1, r2 + t2);
        let z = zemax_bsdf(&ms, LightSide::AirToMaterial, true, &[0.0], &[0.0, 180.0], &[0.0, 20.0], "");
        let t = crate::scatter::zemax::parse(&z, std::path::Path::new("ms.BSDF")).unwrap();
        let v = &t.block(0, 0, 0).values;
        assert!(v.iter().all(|x| x.is_finite() && *x > 0.0) && v[0] > v[1], "{v:?}");
        // the MS value at the refracted peak is the single-scattering value plus orders ≥ 2
        let c = specular_center(&ms, LightSide::AirToMaterial, 0.0, true);
        let f1 = power_bsdf(&ss, LightSide::AirToMaterial, 0.0, c);
        assert!(v[0] > 0.9 * f1, "ms {} ss {f1}", v[0]);
    }

    /// The export of a dotted face is the face the goniophotometer simulates: photons sampled
    /// from [`opal::bsdf::Dotted`] (35 % GGX α = 0.3 dots on a polished land, the area mixture
    /// the simulator's dotted faces follow) and counted in 1° cones around every tabulated
    /// direction of the exported `.BSDF` (read back) agree with the table's value × projected
    /// cone solid angle (the radial-0 cone is the spike's cap) by a χ² over all cones and
    /// |z| < 5 each; the TIS lines agree with the sampled R and T fractions (|z| < 4); and the
    /// specular spike is in the table (without it the radial-0 cones fail).
    #[test]
    fn dotted_export_reproduces_the_sampled_face() {
        use opal::bsdf::{Bxdfs, Dotted, SmoothDielectric};
        let (f, eta) = (0.35, 1.5);
        let face = FaceModel::dotted(f, Ndfs::ggx(0.3), eta, Scattering::Single).unwrap();
        let rough = RoughDielectric::new(Ndfs::ggx(0.3), eta as f32, Shadowing::Separable).unwrap();
        let sim = Dotted::new(
            f as f32,
            Bxdfs::RoughDielectric(rough),
            Bxdfs::SmoothDielectric(SmoothDielectric::new(eta as f32).unwrap()),
        )
        .unwrap();
        let (az, rad) = ([0.0, 45.0, 90.0, 135.0, 180.0], [0.0, 2.0, 6.0, 12.0, 25.0, 45.0]);
        let rho = spike_cap_deg(&rad).unwrap().to_radians();
        let cone = 2.0 * PI * (1.0 - rho.cos());
        let n = 400_000usize;
        let (mut chi2, mut dof) = (0.0, 0usize);
        for side in [LightSide::AirToMaterial, LightSide::MaterialToAir] {
            for a in [0.0f64, 30.0, 60.0] {
                let aoi = a.to_radians();
                let l = light_dir(side, aoi);
                let mut rng = Rng::new(0xD07, a.to_bits(), side.sign().to_bits() as u64);
                let samples: Vec<(Vec3, f64)> = (0..n)
                    .filter_map(|_| {
                        let uc = rng.next_f32();
                        let s = sim.sample(l, uc, rng.next_2d(), TransportMode::Importance)?;
                        Some((s.wi, s.weight().average() as f64))
                    })
                    .collect();
                for tr in [false, true] {
                    let text = zemax_bsdf(&face, side, tr, &[a], &az, &rad, "z test");
                    let t = crate::scatter::zemax::parse(&text, std::path::Path::new("d.BSDF")).unwrap();
                    let blk = t.block(0, 0, 0);
                    // TIS against the sampled fraction
                    let hemi: Vec<f64> =
                        samples.iter().filter(|(w, _)| (w.z * l.z < 0.0) == tr).map(|s| s.1).collect();
                    let (sum, sq) = (hemi.iter().sum::<f64>(), hemi.iter().map(|w| w * w).sum::<f64>());
                    let (mean, var) = (sum / n as f64, sq / n as f64 - (sum / n as f64).powi(2));
                    let z = (blk.tis.unwrap() - mean) / (var / n as f64).sqrt().max(1e-6);
                    assert!(
                        z.abs() < 4.0,
                        "{side:?} aoi {a} T {tr}: TIS {} vs {mean} (z {z})",
                        blk.tis.unwrap()
                    );
                    let c = specular_center(&face, side, aoi, tr);
                    for (j, &p) in az.iter().enumerate() {
                        for (k, &q) in rad.iter().enumerate() {
                            let d = scatter_dir(c, p, q);
                            if d.z * c.z < 0.15 || (k == 0 && j > 0) {
                                continue; // near or beyond the horizon; radial 0 once
                            }
                            let expected =
                                blk.values[j * rad.len() + k] * (d.z * c.z.signum()) as f64 * cone * n as f64;
                            let (mut o, mut v) = (0.0, 0.0);
                            for (w, wt) in &samples {
                                if (w.dot(d) as f64) >= rho.cos() {
                                    o += wt;
                                    v += wt * wt;
                                }
                            }
                            if expected < 20.0 && o < 20.0 {
                                continue; // too few photons for a Gaussian z
                            }
                            let z = (o - expected) / v.max(expected).sqrt();
                            assert!(
                                z.abs() < 5.0,
                                "{side:?} aoi {a} T {tr} az {p} rad {q}: {o} vs {expected}"
                            );
                            chi2 += z * z;
                            dof += 1;
                        }
                    }
                }
            }
        }
        let bound = dof as f64 + 4.0 * (2.0 * dof as f64).sqrt();
        assert!(dof > 80 && chi2 < bound, "χ² {chi2} over {dof} cones (bound {bound})");
    }
}
