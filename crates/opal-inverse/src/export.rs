//! Exports of a fitted rough face: the NDF as a table and the BSDF of the rough dielectric
//! interface for both sides (light from air into the material, and from the material into
//! air), reflection and transmission, as CSV and in the Zemax/OpticStudio tabular `.BSDF` text
//! format (Radiant "BSDF Data Interchange" layout). Formats in `docs/formats.md`.
//!
//! Conventions: local frame of the rough face, +z = air side, `eta` = n_material. The light
//! arrives in the plane x–z from −x: the direction towards the source is
//! `l = (−sin θi, 0, ±cos θi)` (+ from air, − from the material), so the specular reflection is
//! at azimuth 0. The tabulated value for a scatter direction `s` is the power BSDF
//! `f(l → s) = f_importance(wo = l, wi = s)` of [`RoughDielectric`] (single scattering, the
//! separable Smith G), in 1/sr: the fraction of the incident power scattered per unit
//! projected solid angle, so `TIS = ∫ f |cos θs| dω` is the scattered fraction of the power (the
//! quantity a ray tracer that transports power, such as OpticStudio, expects). TIS is
//! integrated on a fine midpoint grid (0.25° × 1°), independently of the table's resolution.
//!
//! Tests: `tests` below (energy: R + T ≤ 1 and ≈ 1 for a smooth-ish surface, reciprocity of the
//! tables, the Zemax file's structure).

use opal::bsdf::microfacet::{Ndf, Ndfs};
use opal::bsdf::rough_dielectric::{RoughDielectric, Shadowing};
use opal::bsdf::{Bxdf, TransportMode};
use opal::math::Vec3;
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
    fn sign(self) -> f32 {
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

/// The rough face's BSDF model.
pub fn face_bsdf(ndf: Ndfs, ior: f64) -> opal::Result<RoughDielectric> {
    RoughDielectric::new(ndf, ior as f32, Shadowing::Separable)
}

fn light_dir(side: LightSide, aoi: f64) -> Vec3 {
    Vec3::new(-(aoi.sin() as f32), 0.0, side.sign() * aoi.cos() as f32)
}

/// Power BSDF f(l → s) (see module docs).
pub fn power_bsdf(b: &RoughDielectric, side: LightSide, aoi: f64, s: Vec3) -> f64 {
    b.eval(light_dir(side, aoi), s, TransportMode::Importance).average() as f64
}

/// Total integrated scatter (reflected, transmitted) fractions of the incident power.
pub fn tis(b: &RoughDielectric, side: LightSide, aoi: f64) -> (f64, f64) {
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
/// table `tis` returned separately.
pub fn bsdf_csv(
    b: &RoughDielectric,
    aois_deg: &[f64],
    theta_step_deg: f64,
    phi_step_deg: f64,
) -> (String, String) {
    let mut out = String::from("light_side,aoi_deg,scatter,theta_s_deg,phi_s_deg,bsdf\n");
    let mut tis_csv = String::from("light_side,aoi_deg,tis_R,tis_T,R_plus_T\n");
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
            let _ = writeln!(tis_csv, "{},{},{:.6},{:.6},{:.6}", side.label(), a, r, t, r + t);
        }
    }
    (out, tis_csv)
}

/// Centre of the scatter coordinates (Zemax convention): the specular reflection, or the
/// refracted direction for transmission (the undeviated direction beyond the critical angle).
fn specular_center(b: &RoughDielectric, side: LightSide, aoi: f64, transmission: bool) -> Vec3 {
    let l = light_dir(side, aoi);
    if !transmission {
        return Vec3::new(-l.x, -l.y, l.z);
    }
    let eta = match side {
        LightSide::AirToMaterial => b.eta,
        LightSide::MaterialToAir => 1.0 / b.eta,
    };
    let st = l.x.abs() / eta;
    if st < 1.0 {
        let ct = (1.0 - st * st).sqrt();
        Vec3::new(st, 0.0, -side.sign() * ct)
    } else {
        -l
    }
}

/// One Zemax/OpticStudio tabular `.BSDF` file (`PlaneSymmetrical`, `Monochrome`) for one light
/// side and one scatter type: AOI rows, a `TIS` line each, then one line per scatter azimuth
/// with the values for every radial angle (angles about the specular / refracted direction;
/// azimuth 0 points from the specular direction towards the sample normal).
pub fn zemax_bsdf(
    b: &RoughDielectric,
    side: LightSide,
    transmission: bool,
    aois_deg: &[f64],
    azimuths_deg: &[f64],
    radials_deg: &[f64],
    comment: &str,
) -> String {
    let mut o = String::new();
    for l in comment.lines() {
        let _ = writeln!(o, "# {l}");
    }
    let _ =
        writeln!(o, "# Opal fit-ndf export: {} {}", side.label(), if transmission { "BTDF" } else { "BRDF" });
    let list = |v: &[f64]| v.iter().map(|x| format!("{x}")).collect::<Vec<_>>().join("\t");
    let _ = writeln!(o, "Source\tMeasured");
    let _ = writeln!(o, "Symmetry\tPlaneSymmetrical");
    let _ = writeln!(o, "SpectralContent\tMonochrome");
    let _ = writeln!(o, "ScatterType\t{}", if transmission { "BTDF" } else { "BRDF" });
    let _ = writeln!(o, "SampleRotation\t1\n0");
    let _ = writeln!(o, "AngleOfIncidence\t{}\n{}", aois_deg.len(), list(aois_deg));
    let _ = writeln!(o, "ScatterAzimuth\t{}\n{}", azimuths_deg.len(), list(azimuths_deg));
    let _ = writeln!(o, "ScatterRadial\t{}\n{}", radials_deg.len(), list(radials_deg));
    let _ = writeln!(o, "\nMonochrome\nDataBegin");
    for &a in aois_deg {
        let aoi = a.to_radians();
        let (r, t) = tis(b, side, aoi);
        let _ = writeln!(o, "TIS\t{:.6}", if transmission { t } else { r });
        let c = specular_center(b, side, aoi, transmission);
        let pole = Vec3::new(0.0, 0.0, c.z.signum());
        let u0 = pole - c * pole.dot(c);
        let u = if u0.length() > 1e-6 { u0.normalize() } else { Vec3::new(-1.0, 0.0, 0.0) };
        let v = c.cross(u);
        for &az in azimuths_deg {
            let (sa, ca) = (az.to_radians().sin() as f32, az.to_radians().cos() as f32);
            let row: Vec<String> = radials_deg
                .iter()
                .map(|&rd| {
                    let (sr, cr) = (rd.to_radians().sin() as f32, rd.to_radians().cos() as f32);
                    let s = (c * cr + (u * ca + v * sa) * sr).normalize();
                    let val = if s.z * c.z > 0.0 { power_bsdf(b, side, aoi, s) } else { 0.0 };
                    format!("{val:.5e}")
                })
                .collect();
            let _ = writeln!(o, "{}", row.join("\t"));
        }
    }
    let _ = writeln!(o, "DataEnd");
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn energy_of_both_sides() {
        // single scattering loses energy at grazing angles (and, from the material, near the
        // critical angle 42°); away from those and for small α the interface must conserve
        // R + T to within 2 % (quadrature error ≪ 1 %).
        let b = face_bsdf(Ndfs::ggx(0.1), 1.49).unwrap();
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
        let b = face_bsdf(Ndfs::beckmann(0.2), 1.49).unwrap();
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
}
