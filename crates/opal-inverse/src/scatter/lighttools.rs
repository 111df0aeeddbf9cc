//! LightTools BSDF text files (also written by Light Tec MiniDiff): reader and writer. One file
//! holds both sides of a surface and both reflection and transmission.
//!
//! No public specification was found; the structure follows the open reader of libbsdf
//! (`LightToolsBsdfReader.cpp`, read for the layout only):
//! ```text
//! # comment lines anywhere
//! Symmetry          Asymmetric
//! SpectralContent   Monochrome | XYZ
//! ScatterAzimuth    n   then n angles (deg, ascending, in [0, 360))
//! ScatterRadial     n   then n angles (deg, ascending, in [0, 90])
//! DataBegin
//! AOI a   POI p   Side Front|Back   Wavelength w   ScatterType BRDF|BTDF
//! TristimulusValue TrisX|TrisY|TrisZ        (XYZ files only)
//! TIS v
//! <n_azimuth rows × n_radial values>       one block per (side, scatter type, AOI, channel)
//! ...
//! DataEnd
//! ```
//! Keywords and values are case-insensitive; numbers may be spread over lines in any way. In a
//! block `AOI`, `Side` and `ScatterType` are required, `POI` (default 0°) and `Wavelength`
//! (nm) optional, and `TIS` ends the block's keywords and starts its values.
//!
//! Angle conventions (libbsdf's reading): the scatter angles are **global spherical**, not
//! about the specular direction: radial = polar angle θ from the surface normal of the
//! hemisphere the light leaves into, azimuth φ in the surface plane, the source at azimuth
//! `POI` (an isotropic file uses POI 90°), so the specular reflection is at `POI + 180°`.
//! `Side Front` is light arriving from the side the surface normal points to. Values are the
//! BSDF (1/sr), azimuth-major: `values[i_azimuth * n_radial + i_radial]`.
//!
//! Validation: every error names the file, line, column and the offending value: unknown
//! keyword, bad or out-of-range number (AOI in [0°, 90°], POI in [−360°, 360°]), angle lists
//! (count, range, strictly ascending), a block without AOI / Side / ScatterType or with a
//! missing or extra `TristimulusValue`, a value count short of `n_azimuth × n_radial`, a
//! repeated block, no `DataEnd`, anything after it.
//!
//! Round trip: [`write`] with [`Precision::Exact`] prints numbers in Rust's shortest
//! round-trip form, so `parse(write(t)) == t` bit for bit.
//!
//! Tests: `tests` below (a hand-made file, exact round trip incl. XYZ, malformed files and
//! their messages); `crate::export` tests (the exported face of both sides read back).

use super::zemax::{Channel, Precision, ScatterType, SpectralContent, Tok, Tokens, angle_list};
use crate::measured::{Measured, Row};
use opal::Error;
use opal::gonio::Side;
use std::fmt::Write;
use std::path::Path;

/// Which side of the surface the light arrives from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaceSide {
    /// From the side the surface normal points to (`Front`).
    Front,
    /// From the other side (`Back`).
    Back,
}

/// One data block: one side, scatter type, angle of incidence and channel.
#[derive(Clone, Debug, PartialEq)]
pub struct LtBlock {
    /// Angle of incidence (deg, from the normal of the lit side).
    pub aoi_deg: f64,
    /// Azimuth of the source (deg, `POI`).
    pub poi_deg: f64,
    /// The lit side.
    pub side: FaceSide,
    /// `Wavelength` (nm), if given.
    pub wavelength_nm: Option<f64>,
    /// Reflection or transmission.
    pub scatter_type: ScatterType,
    /// `Monochrome`, or the tristimulus channel of an XYZ file.
    pub channel: Channel,
    /// Total integrated scatter of the block.
    pub tis: f64,
    /// BSDF values (1/sr), azimuth-major.
    pub values: Vec<f64>,
}

/// A whole LightTools BSDF file.
#[derive(Clone, Debug, PartialEq)]
pub struct LtTable {
    /// `SpectralContent`.
    pub spectral: SpectralContent,
    /// `ScatterAzimuth` angles (deg).
    pub azimuth_deg: Vec<f64>,
    /// `ScatterRadial` angles (deg).
    pub radial_deg: Vec<f64>,
    /// Blocks in file order.
    pub blocks: Vec<LtBlock>,
}

impl LtTable {
    /// The block for (`side`, `scatter_type`, AOI, `channel`), if present.
    pub fn find(
        &self,
        side: FaceSide,
        scatter_type: ScatterType,
        aoi_deg: f64,
        channel: Channel,
    ) -> Option<&LtBlock> {
        self.blocks.iter().find(|b| {
            b.side == side && b.scatter_type == scatter_type && b.aoi_deg == aoi_deg && b.channel == channel
        })
    }
}

impl LtTable {
    /// Plane-of-incidence curves of the `Side Front` blocks (the lit side of a plate
    /// measurement) for [`crate::ndf_fit`]: BRDF → side R, BTDF → side T; the azimuth row
    /// `POI + 180°` (forward, the specular side) gives detector angle `p = +radial`, the row
    /// `POI` gives `p = −radial` (the gonio's signed angle, specular at `p = +AOI`); value =
    /// BSDF · cos p. XYZ files are fitted on `TrisY`. Errors (naming `path`): no Front block,
    /// a block without its forward or backward azimuth row.
    pub fn to_measured(&self, path: &Path) -> opal::Result<Measured> {
        let what = |w: &str| format!("{}: {w}", path.display());
        let nr = self.radial_deg.len();
        let row = |deg: f64| {
            let d = deg.rem_euclid(360.0);
            self.azimuth_deg.iter().position(|a| (a - d).abs() < 1e-9 || (a - d).abs() > 360.0 - 1e-9)
        };
        let mut rows = Vec::new();
        for b in self.blocks.iter().filter(|b| {
            b.side == FaceSide::Front && matches!(b.channel, Channel::Monochrome | Channel::TristimulusY)
        }) {
            let (fwd, back) = (row(b.poi_deg + 180.0), row(b.poi_deg));
            let Some(fwd) = fwd else {
                return Err(Error::invalid(
                    what("ScatterAzimuth"),
                    format!(
                        "no azimuth {}° row (POI + 180°, the specular side)",
                        (b.poi_deg + 180.0).rem_euclid(360.0)
                    ),
                ));
            };
            let side = match b.scatter_type {
                ScatterType::Brdf => Side::R,
                ScatterType::Btdf => Side::T,
            };
            let mut push = |p: f64, f: f64| {
                if p.abs() < 90.0 {
                    rows.push(Row {
                        incidence_deg: b.aoi_deg,
                        side,
                        detector_deg: p,
                        azimuth_deg: 0.0,
                        value: f * p.to_radians().cos(),
                        stderr: 0.0,
                    });
                }
            };
            for (k, &r) in self.radial_deg.iter().enumerate() {
                push(r, b.values[fwd * nr + k]);
            }
            if let Some(back) = back {
                for (k, &r) in self.radial_deg.iter().enumerate().filter(|(_, r)| **r > 0.0) {
                    push(-r, b.values[back * nr + k]);
                }
            }
        }
        if rows.is_empty() {
            return Err(Error::invalid(what("blocks"), "no Side Front block with Monochrome or TrisY data"));
        }
        Measured::from_rows(path, rows, false, false)
    }
}

/// Whether `text` looks like a LightTools BSDF file: its first token outside comments is
/// `Symmetry` and the second `Asymmetric` (any case).
pub fn is_lighttools_text(text: &str) -> bool {
    let mut t = text.lines().filter(|l| !l.trim_start().starts_with('#')).flat_map(|l| l.split_whitespace());
    matches!((t.next(), t.next()), (Some(a), Some(b)) if a.eq_ignore_ascii_case("Symmetry") && b.eq_ignore_ascii_case("Asymmetric"))
}

/// Writes a table as LightTools BSDF text; every line of `comment` becomes a `#` line.
pub fn write(t: &LtTable, comment: &str, precision: Precision) -> String {
    let mut o = String::new();
    for l in comment.lines() {
        let _ = writeln!(o, "# {l}");
    }
    let num = |x: f64| match precision {
        Precision::Exact => format!("{x:e}"),
        Precision::Export => format!("{x:.5e}"),
    };
    let list = |v: &[f64]| v.iter().map(|x| format!("{x}")).collect::<Vec<_>>().join("\t");
    let spec = match t.spectral {
        SpectralContent::Monochrome => "Monochrome",
        SpectralContent::Xyz => "XYZ",
    };
    let _ = writeln!(o, "Symmetry\tAsymmetric\nSpectralContent\t{spec}");
    let _ = writeln!(o, "ScatterAzimuth\t{}\n{}", t.azimuth_deg.len(), list(&t.azimuth_deg));
    let _ = writeln!(o, "ScatterRadial\t{}\n{}", t.radial_deg.len(), list(&t.radial_deg));
    let _ = writeln!(o, "DataBegin");
    let nr = t.radial_deg.len().max(1);
    for b in &t.blocks {
        let side = match b.side {
            FaceSide::Front => "Front",
            FaceSide::Back => "Back",
        };
        let st = match b.scatter_type {
            ScatterType::Brdf => "BRDF",
            ScatterType::Btdf => "BTDF",
        };
        let _ = writeln!(o, "AOI\t{}\nPOI\t{}\nSide\t{side}", b.aoi_deg, b.poi_deg);
        if let Some(w) = b.wavelength_nm {
            let _ = writeln!(o, "Wavelength\t{w}");
        }
        let _ = writeln!(o, "ScatterType\t{st}");
        let tris = match b.channel {
            Channel::Monochrome => None,
            Channel::TristimulusX => Some("TrisX"),
            Channel::TristimulusY => Some("TrisY"),
            Channel::TristimulusZ => Some("TrisZ"),
        };
        if let Some(c) = tris {
            let _ = writeln!(o, "TristimulusValue\t{c}");
        }
        let _ = match precision {
            Precision::Exact => writeln!(o, "TIS\t{:e}", b.tis),
            Precision::Export => writeln!(o, "TIS\t{:.6}", b.tis),
        };
        for row in b.values.chunks(nr) {
            let _ = writeln!(o, "{}", row.iter().map(|&x| num(x)).collect::<Vec<_>>().join("\t"));
        }
    }
    let _ = writeln!(o, "DataEnd");
    o
}

/// Reads a LightTools BSDF file (bytes that are not UTF-8 become U+FFFD).
pub fn read(path: &Path) -> opal::Result<LtTable> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse(&String::from_utf8_lossy(&bytes), path)
}

/// The value of a `Keyword word` pair, matched case-insensitively against `choices`.
fn word<'a, T: Copy>(tk: &mut Tokens<'a>, key: &str, choices: &[(&str, T)]) -> opal::Result<T> {
    let t = tk.next(&format!("the value of {key}"))?;
    choices.iter().find(|(w, _)| w.eq_ignore_ascii_case(t.text)).map(|c| c.1).ok_or_else(|| {
        let names: Vec<&str> = choices.iter().map(|c| c.0).collect();
        tk.err_at(&t, format!("{key}: unknown value {:?} (expected {})", t.text, names.join(", ")))
    })
}

/// A number in `[lo, hi]` after `key`.
fn ranged(tk: &mut Tokens, key: &str, lo: f64, hi: f64) -> opal::Result<f64> {
    let at = tk.pos;
    let x = tk.number(&format!("the value of {key}"))?;
    if !(lo..=hi).contains(&x) {
        let t = tk.toks[at];
        return Err(tk.err_at(&t, format!("{key}: {x} is outside [{lo}, {hi}]")));
    }
    Ok(x)
}

/// Parses LightTools BSDF text; `path` names the file in error messages.
pub fn parse(text: &str, path: &Path) -> opal::Result<LtTable> {
    let mut tk = Tokens::new(text, path);
    let (mut spectral, mut az, mut rad) = (None, None, None);
    let mut symmetry_seen = false;
    // header
    loop {
        let t = tk.next("a header keyword or DataBegin")?;
        match t.text.to_ascii_lowercase().as_str() {
            "symmetry" => {
                word(&mut tk, "Symmetry", &[("Asymmetric", ())])?;
                symmetry_seen = true;
            }
            "spectralcontent" => {
                spectral = Some(word(
                    &mut tk,
                    "SpectralContent",
                    &[("Monochrome", SpectralContent::Monochrome), ("XYZ", SpectralContent::Xyz)],
                )?)
            }
            "scatterazimuth" => az = Some(angle_list(&mut tk, &t, "ScatterAzimuth", 0.0, 360.0, false)?),
            "scatterradial" => rad = Some(angle_list(&mut tk, &t, "ScatterRadial", 0.0, 90.0, true)?),
            "databegin" => {
                let missing = [
                    ("Symmetry", symmetry_seen),
                    ("ScatterAzimuth", az.is_some()),
                    ("ScatterRadial", rad.is_some()),
                ];
                if let Some((k, _)) = missing.iter().find(|m| !m.1) {
                    return Err(tk.err_at(&t, format!("DataBegin before the header keyword {k}")));
                }
                break;
            }
            _ => return Err(tk.err_at(&t, format!("unknown header keyword {:?}", t.text))),
        }
    }
    let spectral = spectral.unwrap_or(SpectralContent::Monochrome);
    let (az, rad) = (az.unwrap_or_default(), rad.unwrap_or_default());
    let n = az.len() * rad.len();
    let mut blocks: Vec<LtBlock> = Vec::new();
    loop {
        let first = tk.next("a block keyword or DataEnd")?;
        if first.text.eq_ignore_ascii_case("DataEnd") {
            if let Some(t) = tk.peek() {
                let t = *t;
                return Err(tk.err_at(&t, format!("unexpected {:?} after DataEnd", t.text)));
            }
            break;
        }
        tk.pos -= 1;
        blocks.push(block(&mut tk, &first, spectral, n, &blocks)?);
    }
    Ok(LtTable { spectral, azimuth_deg: az, radial_deg: rad, blocks })
}

/// One block, from its first keyword to its last value.
fn block(
    tk: &mut Tokens,
    first: &Tok,
    spectral: SpectralContent,
    n: usize,
    done: &[LtBlock],
) -> opal::Result<LtBlock> {
    let (mut aoi, mut poi, mut side, mut wl, mut st, mut ch) = (None, None, None, None, None, None);
    let tis_tok = loop {
        let t =
            tk.next("a block keyword (AOI, POI, Side, Wavelength, ScatterType, TristimulusValue, TIS)")?;
        match t.text.to_ascii_lowercase().as_str() {
            "aoi" => aoi = Some(ranged(tk, "AOI", 0.0, 90.0)?),
            "poi" => poi = Some(ranged(tk, "POI", -360.0, 360.0)?),
            "side" => side = Some(word(tk, "Side", &[("Front", FaceSide::Front), ("Back", FaceSide::Back)])?),
            "wavelength" => wl = Some(ranged(tk, "Wavelength", 0.0, f64::MAX)?),
            "scattertype" => {
                st = Some(word(
                    tk,
                    "ScatterType",
                    &[("BRDF", ScatterType::Brdf), ("BTDF", ScatterType::Btdf)],
                )?)
            }
            "tristimulusvalue" => {
                let choices = [
                    ("TrisX", Channel::TristimulusX),
                    ("TrisY", Channel::TristimulusY),
                    ("TrisZ", Channel::TristimulusZ),
                ];
                let c = word(tk, "TristimulusValue", &choices)?;
                if spectral == SpectralContent::Monochrome {
                    return Err(tk.err_at(&t, "TristimulusValue in a Monochrome file".into()));
                }
                ch = Some(c);
            }
            "tis" => break t,
            _ => return Err(tk.err_at(&t, format!("unknown block keyword {:?}", t.text))),
        }
    };
    let need =
        |v: bool, k: &str| if v { Ok(()) } else { Err(tk.err_at(&tis_tok, format!("block without {k}"))) };
    need(aoi.is_some(), "AOI")?;
    need(side.is_some(), "Side")?;
    need(st.is_some(), "ScatterType")?;
    need(spectral == SpectralContent::Monochrome || ch.is_some(), "TristimulusValue (XYZ file)")?;
    let tis = tk.number("the value of TIS")?;
    let left = tk.toks.len() - tk.pos;
    if n > left {
        return Err(tk.err_at(&tis_tok, format!("the block needs {n} values, only {left} numbers are left")));
    }
    let mut values = Vec::with_capacity(n);
    for i in 0..n {
        values.push(tk.number(&format!("BSDF value {} of {n}", i + 1))?);
    }
    let b = LtBlock {
        aoi_deg: aoi.unwrap_or(0.0),
        poi_deg: poi.unwrap_or(0.0),
        side: side.unwrap_or(FaceSide::Front),
        wavelength_nm: wl,
        scatter_type: st.unwrap_or(ScatterType::Brdf),
        channel: ch.unwrap_or(Channel::Monochrome),
        tis,
        values,
    };
    if done.iter().any(|d| {
        (d.side, d.scatter_type, d.aoi_deg, d.channel, d.poi_deg)
            == (b.side, b.scatter_type, b.aoi_deg, b.channel, b.poi_deg)
    }) {
        return Err(tk.err_at(
            first,
            format!("repeated block: {:?} {:?} AOI {} {:?}", b.side, b.scatter_type, b.aoi_deg, b.channel),
        ));
    }
    Ok(b)
}

#[cfg(test)]
mod tests {
    use super::*;

    const HAND: &str = "# made by hand after the documented structure\n\
        symmetry Asymmetric\nSpectralContent monochrome\n\
        ScatterAzimuth 3\n0 120 240\nScatterRadial 2 0 45\n\
        DataBegin\n\
        AOI 30 POI 90 Side Front Wavelength 550 ScatterType BRDF\nTIS 0.05\n\
        0.1 0.2\n0.3 0.4\n0.5 0.6\n\
        # a comment between blocks\n\
        aoi 0\nside back\nscattertype btdf\ntis 0.9\n1 2 3 4 5 6\n\
        DataEnd\n";

    #[test]
    fn hand_made_file() {
        let t = parse(HAND, Path::new("hand.txt")).unwrap();
        assert_eq!(t.spectral, SpectralContent::Monochrome);
        assert_eq!(
            (t.azimuth_deg.as_slice(), t.radial_deg.as_slice()),
            (&[0.0, 120.0, 240.0][..], &[0.0, 45.0][..])
        );
        assert_eq!(t.blocks.len(), 2);
        let b = t.find(FaceSide::Front, ScatterType::Brdf, 30.0, Channel::Monochrome).unwrap();
        assert_eq!((b.poi_deg, b.wavelength_nm, b.tis), (90.0, Some(550.0), 0.05));
        // azimuth-major: azimuth 120°, radial 45° is the 4th value
        assert_eq!(b.values[3], 0.4);
        let b = t.find(FaceSide::Back, ScatterType::Btdf, 0.0, Channel::Monochrome).unwrap();
        assert_eq!((b.poi_deg, b.wavelength_nm, b.tis, b.values[5]), (0.0, None, 0.9, 6.0));
    }

    /// The plane-of-incidence curves of the hand-made file: the Front BRDF block at AOI 30°,
    /// POI 90°: forward row 270° is absent there, so it is an error; with azimuths 90° and 270°
    /// the forward row gives p = +radial, the POI row p = −radial, value × cos p.
    #[test]
    fn plane_of_incidence_curves() {
        let t = parse(HAND, Path::new("hand.txt")).unwrap();
        let e = t.to_measured(Path::new("hand.txt")).unwrap_err().to_string();
        assert!(e.contains("hand.txt") && e.contains("270"), "{e}");
        let mut t = t;
        t.azimuth_deg = vec![90.0, 270.0];
        t.blocks.truncate(1);
        t.blocks[0].values = vec![1.0, 2.0, 3.0, 4.0]; // row 90°: 1, 2; row 270°: 3, 4
        let m = t.to_measured(Path::new("hand.txt")).unwrap();
        let c = &m.curves[0];
        assert_eq!((c.side, c.incidence), (Side::R, 30f64.to_radians()));
        let pts: Vec<(f64, f64)> =
            c.detector.iter().zip(&c.value).map(|(d, v)| (d.to_degrees(), *v)).collect();
        let want =
            [(-45.0, 2.0 * 45f64.to_radians().cos()), (0.0, 3.0), (45.0, 4.0 * 45f64.to_radians().cos())];
        assert_eq!(pts.len(), 3, "{pts:?}");
        for ((d, v), (wd, wv)) in pts.iter().zip(want) {
            assert!((d - wd).abs() < 1e-9 && (v - wv).abs() < 1e-12, "{pts:?}");
        }
        assert!(is_lighttools_text(HAND) && !is_lighttools_text("Symmetry PlaneSymmetrical\n"));
    }

    #[test]
    fn exact_round_trip() {
        let mut t = parse(HAND, Path::new("hand.txt")).unwrap();
        t.blocks[0].values[2] = 1.0 / 3.0;
        t.blocks[1].tis = std::f64::consts::PI / 7.0;
        let back = parse(&write(&t, "round\ntrip", Precision::Exact), Path::new("w.txt")).unwrap();
        assert_eq!(back, t);
        // XYZ: one block per channel
        let mut x = t.clone();
        x.spectral = SpectralContent::Xyz;
        x.blocks = [Channel::TristimulusX, Channel::TristimulusY, Channel::TristimulusZ]
            .iter()
            .map(|&c| LtBlock { channel: c, ..t.blocks[0].clone() })
            .collect();
        let text = write(&x, "", Precision::Exact);
        assert!(text.contains("TristimulusValue\tTrisY"));
        assert_eq!(parse(&text, Path::new("x.txt")).unwrap(), x);
    }

    #[test]
    fn malformed_files_name_file_line_and_value() {
        let head = "Symmetry Asymmetric\nScatterAzimuth 2 0 180\nScatterRadial 2 0 10\nDataBegin\n";
        let block = "AOI 10 Side Front ScatterType BRDF TIS 0.1\n1 2 3 4\n";
        let cases = [
            ("Symmetry PlaneSymmetric\n", "bad.txt:1:10", "PlaneSymmetric"),
            ("Symmetry Asymmetric\nScatterAzimuth 2 0 400\n", "bad.txt:2:20", "400"),
            ("Symmetry Asymmetric\nScatterRadial 2 10 5\n", "bad.txt:2:20", "ascending"),
            ("Symmetry Asymmetric\nScatterAzimuth 1 0\nDataBegin\n", "bad.txt:3:1", "ScatterRadial"),
            ("Symmetry Asymmetric\nColour red\n", "bad.txt:2:1", "Colour"),
            (&format!("{head}AOI 95 Side Front\n"), "bad.txt:5:5", "95"),
            (&format!("{head}AOI 10 Side Top\n"), "bad.txt:5:13", "Top"),
            (&format!("{head}AOI 10 ScatterType BRDF TIS 0.1\n1 2 3 4\n"), "bad.txt:5:25", "Side"),
            (
                &format!("{head}AOI 10 Side Front ScatterType BRDF TIS 0.1\n1 2 x 4\nDataEnd\n"),
                "bad.txt:6:5",
                "\"x\"",
            ),
            (&format!("{head}AOI 10 Side Front ScatterType BRDF TIS 0.1\n1 2 3\n"), "bad.txt:5:", "4 values"),
            (&format!("{head}{block}{block}DataEnd\n"), "bad.txt:7:1", "repeated"),
            (&format!("{head}{block}"), "bad.txt:6:", "DataEnd"),
            (&format!("{head}{block}DataEnd\n7\n"), "bad.txt:8:1", "after DataEnd"),
            (&format!("{head}AOI 10 Side Front TristimulusValue TrisX\n"), "bad.txt:5:19", "Monochrome"),
        ];
        for (text, at, what) in cases {
            let e = parse(text, Path::new("bad.txt")).unwrap_err().to_string();
            assert!(e.contains(at) && e.contains(what), "{text:?}: {e} (want {at} and {what})");
        }
    }
}
