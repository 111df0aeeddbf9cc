//! The fitted face as one LightTools BSDF text file ([`crate::scatter::lighttools`]): both sides
//! (`Side Front` = light from air, the +z side of [`super`]'s frame; `Side Back` = light from
//! the material), BRDF and BTDF, one block per angle of incidence, `Monochrome`.
//!
//! Angles are global spherical about the normal of the hemisphere the light leaves into; the
//! source is at azimuth [`POI_DEG`] (the isotropic convention), so Opal's local azimuth is
//! `φ_opal = φ_file − POI + 180°` (specular reflection at file azimuth 270°). Values are the
//! power BSDF [`super::power_bsdf`]; TIS is [`super::tis`] (spike included). A dotted face's
//! specular spike ([`super::specular_fractions`]) is added to the grid node nearest to the
//! mirror / refracted direction as `spike / P`, with `P = ∫ cos θ dω` over that node's cell
//! (midpoints between neighbouring angles; at radial 0 the cell is the polar cap and every
//! azimuth's node gets the spike), so the table's cell sum keeps the spike's power.
//!
//! Tests: `tests` below (an exported dotted face read back: every node equals the face, the
//! spike node carries the spike, TIS as [`super::tis`]).

use super::{FaceModel, LightSide, power_bsdf, specular_center, specular_fractions, tis};
use crate::scatter::lighttools::{FaceSide, LtBlock, LtTable};
use crate::scatter::zemax::{Channel, Precision, ScatterType, SpectralContent};
use opal::math::Vec3;
use std::f64::consts::PI;

/// Azimuth of the source written in every block (`POI`).
pub const POI_DEG: f64 = 90.0;

/// The scatter direction at file angles (`radial_deg`, `azimuth_deg`) in the hemisphere of
/// sign `z_sign` (Opal's local frame).
pub fn lighttools_dir(radial_deg: f64, azimuth_deg: f64, z_sign: f32) -> Vec3 {
    let (t, p) = (radial_deg.to_radians(), (azimuth_deg - POI_DEG + 180.0).to_radians());
    Vec3::new((t.sin() * p.cos()) as f32, (t.sin() * p.sin()) as f32, z_sign * t.cos() as f32)
}

/// Projected solid angle ∫ cos θ dω of node (`j` azimuth, `k` radial)'s cell (see the module
/// documentation); the polar cap when radial `k` is 0.
pub fn cell_projected_solid_angle(az: &[f64], rad: &[f64], j: usize, k: usize) -> f64 {
    let half = |a: f64, b: f64| (a + b) / 2.0;
    let lo = match k {
        0 if rad.len() > 1 => (rad[0] - (rad[1] - rad[0]) / 2.0).max(0.0),
        0 => 0.0,
        _ => half(rad[k - 1], rad[k]),
    };
    let last = rad.len() - 1;
    let hi = match k {
        _ if k == last && k > 0 => (rad[k] + (rad[k] - rad[k - 1]) / 2.0).min(90.0),
        _ if k == last => 90.0,
        _ => half(rad[k], rad[k + 1]),
    };
    let s2 = |d: f64| d.to_radians().sin().powi(2);
    if rad[k] == 0.0 {
        return PI * s2(hi);
    }
    let n = az.len();
    let dphi = if n == 1 {
        360.0
    } else {
        let prev = if j == 0 { az[n - 1] - 360.0 } else { az[j - 1] };
        let next = if j == n - 1 { az[0] + 360.0 } else { az[j + 1] };
        (next - prev) / 2.0
    };
    dphi.to_radians() * (s2(hi) - s2(lo)) / 2.0
}

/// The LightTools table of face `b` (see the module documentation).
pub fn lighttools_table(
    b: &FaceModel,
    aois_deg: &[f64],
    azimuths_deg: &[f64],
    radials_deg: &[f64],
) -> LtTable {
    let mut blocks = Vec::new();
    let nr = radials_deg.len();
    for (side, fs) in
        [(LightSide::AirToMaterial, FaceSide::Front), (LightSide::MaterialToAir, FaceSide::Back)]
    {
        for (st, transmission) in [(ScatterType::Brdf, false), (ScatterType::Btdf, true)] {
            let zs = if transmission { -side.sign() } else { side.sign() };
            for &a in aois_deg {
                let aoi = a.to_radians();
                let mut values = Vec::with_capacity(azimuths_deg.len() * nr);
                for &p in azimuths_deg {
                    for &q in radials_deg {
                        values.push(power_bsdf(b, side, aoi, lighttools_dir(q, p, zs)));
                    }
                }
                let (sr, stt) = specular_fractions(b, side, aoi);
                let spike = if transmission { stt } else { sr };
                if spike > 0.0 && !values.is_empty() {
                    let c = specular_center(b, side, aoi, transmission);
                    let theta = (c.z.abs() as f64).min(1.0).acos().to_degrees();
                    let phi = (c.y as f64).atan2(c.x as f64).to_degrees() + POI_DEG - 180.0;
                    let k = nearest(radials_deg, theta, |x, y| (x - y).abs());
                    let j = nearest(azimuths_deg, phi, |x, y| {
                        (x - y).rem_euclid(360.0).min((y - x).rem_euclid(360.0))
                    });
                    let add = spike / cell_projected_solid_angle(azimuths_deg, radials_deg, j, k);
                    if radials_deg[k] == 0.0 {
                        (0..azimuths_deg.len()).for_each(|jj| values[jj * nr] += add);
                    } else {
                        values[j * nr + k] += add;
                    }
                }
                let (r, t) = tis(b, side, aoi);
                blocks.push(LtBlock {
                    aoi_deg: a,
                    poi_deg: POI_DEG,
                    side: fs,
                    wavelength_nm: None,
                    scatter_type: st,
                    channel: Channel::Monochrome,
                    tis: if transmission { t } else { r },
                    values,
                });
            }
        }
    }
    LtTable {
        spectral: SpectralContent::Monochrome,
        azimuth_deg: azimuths_deg.to_vec(),
        radial_deg: radials_deg.to_vec(),
        blocks,
    }
}

fn nearest(v: &[f64], x: f64, dist: impl Fn(f64, f64) -> f64) -> usize {
    (0..v.len()).min_by(|&i, &j| dist(v[i], x).total_cmp(&dist(v[j], x))).unwrap_or(0)
}

/// The LightTools file of face `b` as text (6 significant digits), `comment` as `#` lines.
pub fn lighttools_bsdf(
    b: &FaceModel,
    aois_deg: &[f64],
    azimuths_deg: &[f64],
    radials_deg: &[f64],
    comment: &str,
) -> String {
    let t = lighttools_table(b, aois_deg, azimuths_deg, radials_deg);
    crate::scatter::lighttools::write(
        &t,
        &format!("{comment}\nOpal fit-ndf export (LightTools BSDF text)"),
        Precision::Export,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use opal::bsdf::microfacet::Ndfs;
    use opal::gonio::Scattering;

    /// A dotted face exported and read back: every node is the face's power BSDF except the
    /// spike's node, which carries the spike / its cell's projected solid angle; the cells of
    /// the polar cap sum to the spike once; TIS is the face's (6 decimals).
    #[test]
    fn exported_dotted_face_reads_back() {
        let b = FaceModel::dotted(0.3, Ndfs::ggx(0.25), 1.5, Scattering::Single).unwrap();
        let aois = [0.0, 20.0, 50.0];
        let az: Vec<f64> = (0..12).map(|i| i as f64 * 30.0).collect();
        let rad: Vec<f64> = (0..=18).map(|i| i as f64 * 5.0).collect();
        let text = lighttools_bsdf(&b, &aois, &az, &rad, "test");
        let t = crate::scatter::lighttools::parse(&text, std::path::Path::new("lt.txt")).unwrap();
        assert_eq!(t.blocks.len(), 12);
        let nr = rad.len();
        for (side, fs) in
            [(LightSide::AirToMaterial, FaceSide::Front), (LightSide::MaterialToAir, FaceSide::Back)]
        {
            for (st, tr) in [(ScatterType::Brdf, false), (ScatterType::Btdf, true)] {
                let zs = if tr { -side.sign() } else { side.sign() };
                for &a in &aois {
                    let blk = t.find(fs, st, a, Channel::Monochrome).unwrap();
                    let (r, tt) = tis(&b, side, a.to_radians());
                    assert!((blk.tis - if tr { tt } else { r }).abs() <= 5e-7);
                    let (sr, stt) = specular_fractions(&b, side, a.to_radians());
                    let spike = if tr { stt } else { sr };
                    let mut extra = 0.0;
                    for (j, &p) in az.iter().enumerate() {
                        for (k, &q) in rad.iter().enumerate() {
                            let f = power_bsdf(&b, side, a.to_radians(), lighttools_dir(q, p, zs));
                            let got = blk.values[j * nr + k];
                            let cell = cell_projected_solid_angle(&az, &rad, j, k);
                            let e = (got - f) * cell;
                            extra += if k == 0 { e / az.len() as f64 } else { e };
                            if (got - f).abs() > 5e-6 * got {
                                assert!(spike > 0.0, "{fs:?} {st:?} {a}: ({p}, {q}) {got} vs {f}");
                            }
                        }
                    }
                    assert!(
                        (extra - spike).abs() <= 1e-5 * (spike + blk.tis),
                        "{fs:?} {st:?} {a}: {extra} vs {spike}"
                    );
                }
            }
        }
        // at normal incidence from air the reflected spike sits in the polar cap (radial 0)
        let blk = t.find(FaceSide::Front, ScatterType::Brdf, 0.0, Channel::Monochrome).unwrap();
        assert!(blk.values[0] > 10.0 * blk.values[1]);
    }
}
