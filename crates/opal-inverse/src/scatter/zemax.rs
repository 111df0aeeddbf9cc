//! Zemax/OpticStudio tabular `.BSDF` files (the Radiant "BSDF Data Interchange" layout):
//! reader, writer and the conversion to the plane-of-incidence curves that method A fits.
//!
//! Layout (plain ASCII, whitespace-separated tokens; a line whose first non-blank character is
//! `#` is a comment):
//! ```text
//! Source            Measured
//! Symmetry          PlaneSymmetrical | Asymmetrical | Asymmetrical4D
//! SpectralContent   Monochrome | XYZ
//! ScatterType       BRDF | BTDF
//! SampleRotation    n   then n angles (deg)
//! AngleOfIncidence  n   then n angles
//! ScatterAzimuth    n   then n angles
//! ScatterRadial     n   then n angles
//! Monochrome | TristimulusX | TristimulusY | TristimulusZ     (one data section per channel)
//! DataBegin
//! TIS v             one block per SampleRotation, inside it one per AngleOfIncidence:
//! <n_azimuth rows × n_radial values>
//! DataEnd
//! ```
//! Keywords and their values are case-insensitive (`ASymmetrical4D` and `Asymmetrical4D` are
//! the same); numbers may be spread over lines in any way (only their order matters). The
//! `TIS` line of a block is optional (`None` when absent). `Source`, `SpectralContent`
//! (default `Monochrome`) and `SampleRotation` (default one rotation, 0°) are optional;
//! `Symmetry`, `ScatterType` and the three other angle lists are required and must come before
//! the first data section. Any other keyword is an error.
//!
//! Angle conventions (the spec's): the scatter direction of a block is given by (azimuth,
//! radial) about a centre direction — radial 0° is the specular reflection for a BRDF and the
//! refracted (for a sample in air: the undeviated, directly transmitted) direction for a BTDF.
//! Azimuth 0° points from the centre towards the sample normal (of the hemisphere the light
//! leaves into); azimuth 90° is `c × u` (c = centre, u = the azimuth-0 direction), the
//! counter-clockwise sense of Opal's writer (`crate::export`). `PlaneSymmetrical` tables hold
//! azimuths 0…180° only (the half 180…360° is the mirror image φ' = 360° − φ). The
//! `AngleOfIncidence` list is, per the spec's own remark, the angle of the specular
//! (reflected or transmitted) direction; for a sample in air it equals the incidence angle.
//!
//! Validation (each error names the file, line, column and the offending value): angle lists
//! strictly ascending and finite, AOI in [0°, 90°), radial in [0°, 90°], azimuth in
//! [0°, 360°) (≤ 180° for `PlaneSymmetrical`), a count that is a non-negative integer and
//! matches the list, exactly `n_rotation × n_aoi × n_azimuth × n_radial` finite values per
//! channel, `DataEnd` after them, the channels that `SpectralContent` implies, no channel twice.
//!
//! [`BsdfTable::to_measured`] turns the plane-of-incidence rows (azimuth 0° and 180°) of
//! sample rotation 0° into [`Measured`] curves: a BRDF file gives side R, a BTDF file side T;
//! detector angle `p = AOI − radial` on the azimuth-0 row and `AOI + radial` on the
//! azimuth-180 row (the gonio's signed angle, specular at `p = +AOI`); value = BSDF · cos p
//! (intensity per unit incident power, the quantity of the measured CSV). XYZ files are fitted
//! on `TristimulusY`. The TIS lines are kept in the table but not used by the fit.
//!
//! Round trip: [`write`] with [`Precision::Exact`] prints every number in Rust's shortest
//! round-trip form, so `parse(write(t)) == t` bit for bit; [`Precision::Export`] (the fit-ndf
//! exports) prints values with 6 significant digits and TIS with 6 decimals.
//!
//! Tests: `tests` below (hand-written symmetric / asymmetric / BTDF / XYZ / case-insensitive
//! files, malformed files and their messages, exact round trip, conversion to curves);
//! `crate::export` tests (an exported face read back reproduces the face);
//! `crates/opal-cli/tests/fit_ndf.rs` (`opal fit-ndf` on a `.BSDF` file).

use crate::measured::{Measured, Row};
use opal::Error;
use opal::gonio::Side;
use std::fmt::Write;
use std::path::Path;

/// `Symmetry` of a table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Symmetry {
    /// Azimuths 0…180° only; mirror symmetric about the plane of incidence.
    PlaneSymmetrical,
    /// Azimuths over 0…360°.
    Asymmetrical,
    /// Azimuths over 0…360° and several sample rotations.
    Asymmetrical4D,
}

/// `SpectralContent` of a table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SpectralContent {
    /// One channel (`Monochrome`).
    Monochrome,
    /// Three channels (`TristimulusX`, `TristimulusY`, `TristimulusZ`).
    Xyz,
}

/// `ScatterType` of a table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScatterType {
    /// Reflection.
    Brdf,
    /// Transmission.
    Btdf,
}

/// A data channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Channel {
    /// `Monochrome`.
    Monochrome,
    /// `TristimulusX`.
    TristimulusX,
    /// `TristimulusY`.
    TristimulusY,
    /// `TristimulusZ`.
    TristimulusZ,
}

impl Channel {
    /// The keyword as written.
    pub fn keyword(self) -> &'static str {
        match self {
            Channel::Monochrome => "Monochrome",
            Channel::TristimulusX => "TristimulusX",
            Channel::TristimulusY => "TristimulusY",
            Channel::TristimulusZ => "TristimulusZ",
        }
    }
}

/// One block: one sample rotation, one angle of incidence.
#[derive(Clone, Debug, PartialEq)]
pub struct Block {
    /// The block's `TIS` line, if any.
    pub tis: Option<f64>,
    /// BSDF values (1/sr), azimuth-major: `values[i_azimuth * n_radial + i_radial]`.
    pub values: Vec<f64>,
}

/// The data of one channel.
#[derive(Clone, Debug, PartialEq)]
pub struct ChannelData {
    /// Which channel.
    pub channel: Channel,
    /// Blocks, rotation-major: `blocks[i_rotation * n_aoi + i_aoi]`.
    pub blocks: Vec<Block>,
}

/// A whole `.BSDF` file.
#[derive(Clone, Debug, PartialEq)]
pub struct BsdfTable {
    /// `Source` value (empty when absent).
    pub source: String,
    /// `Symmetry`.
    pub symmetry: Symmetry,
    /// `SpectralContent`.
    pub spectral: SpectralContent,
    /// `ScatterType`.
    pub scatter_type: ScatterType,
    /// `SampleRotation` angles (deg).
    pub sample_rotation_deg: Vec<f64>,
    /// `AngleOfIncidence` angles (deg).
    pub aoi_deg: Vec<f64>,
    /// `ScatterAzimuth` angles (deg).
    pub azimuth_deg: Vec<f64>,
    /// `ScatterRadial` angles (deg).
    pub radial_deg: Vec<f64>,
    /// Data sections in file order.
    pub channels: Vec<ChannelData>,
}

impl BsdfTable {
    /// The block of channel `ch` (index into `channels`), rotation `rot`, incidence `aoi`.
    pub fn block(&self, ch: usize, rot: usize, aoi: usize) -> &Block {
        &self.channels[ch].blocks[rot * self.aoi_deg.len() + aoi]
    }

    /// Plane-of-incidence curves of sample rotation 0° (see the module documentation); `path`
    /// names the source in messages.
    pub fn to_measured(&self, path: &Path) -> opal::Result<Measured> {
        let what = |w: &str| format!("{}: {w}", path.display());
        let ch = self
            .channels
            .iter()
            .position(|c| matches!(c.channel, Channel::Monochrome | Channel::TristimulusY))
            .ok_or_else(|| Error::invalid(what("channels"), "no Monochrome or TristimulusY data"))?;
        let rot = self.sample_rotation_deg.iter().position(|r| r.abs() < 1e-9).ok_or_else(|| {
            Error::invalid(
                what("SampleRotation"),
                format!("no block for sample rotation 0° (rotations {:?})", self.sample_rotation_deg),
            )
        })?;
        let row = |deg: f64| self.azimuth_deg.iter().position(|a| (a - deg).abs() < 1e-9);
        let az0 = row(0.0).ok_or_else(|| {
            Error::invalid(
                what("ScatterAzimuth"),
                "no azimuth 0° row (the plane of incidence, towards the normal)",
            )
        })?;
        let az180 = row(180.0);
        let side = match self.scatter_type {
            ScatterType::Brdf => Side::R,
            ScatterType::Btdf => Side::T,
        };
        let nr = self.radial_deg.len();
        let mut rows = Vec::new();
        for (i, &aoi) in self.aoi_deg.iter().enumerate() {
            let b = self.block(ch, rot, i);
            let mut push = |p: f64, f: f64| {
                if p.abs() < 90.0 {
                    rows.push(Row {
                        incidence_deg: aoi,
                        side,
                        detector_deg: p,
                        azimuth_deg: 0.0,
                        value: f * p.to_radians().cos(),
                        stderr: 0.0,
                    });
                }
            };
            for (k, &r) in self.radial_deg.iter().enumerate() {
                push(aoi - r, b.values[az0 * nr + k]);
            }
            if let Some(a) = az180 {
                for (k, &r) in self.radial_deg.iter().enumerate().filter(|(_, r)| **r > 0.0) {
                    push(aoi + r, b.values[a * nr + k]);
                }
            }
        }
        Measured::from_rows(path, rows, false, false)
    }
}

/// How [`write`] prints numbers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Precision {
    /// Shortest round-trip form (`parse(write(t)) == t` exactly).
    Exact,
    /// Values with 6 significant digits (`{:.5e}`), TIS with 6 decimals.
    Export,
}

/// Writes a table as `.BSDF` text; every line of `comment` becomes a `#` line at the top.
pub fn write(t: &BsdfTable, comment: &str, precision: Precision) -> String {
    let mut o = String::new();
    for l in comment.lines() {
        let _ = writeln!(o, "# {l}");
    }
    let list = |v: &[f64]| v.iter().map(|x| format!("{x}")).collect::<Vec<_>>().join("\t");
    let num = |x: f64| match precision {
        Precision::Exact => format!("{x:e}"),
        Precision::Export => format!("{x:.5e}"),
    };
    if !t.source.is_empty() {
        let _ = writeln!(o, "Source\t{}", t.source);
    }
    let sym = match t.symmetry {
        Symmetry::PlaneSymmetrical => "PlaneSymmetrical",
        Symmetry::Asymmetrical => "Asymmetrical",
        Symmetry::Asymmetrical4D => "Asymmetrical4D",
    };
    let _ = writeln!(o, "Symmetry\t{sym}");
    let spec = match t.spectral {
        SpectralContent::Monochrome => "Monochrome",
        SpectralContent::Xyz => "XYZ",
    };
    let _ = writeln!(o, "SpectralContent\t{spec}");
    let st = match t.scatter_type {
        ScatterType::Brdf => "BRDF",
        ScatterType::Btdf => "BTDF",
    };
    let _ = writeln!(o, "ScatterType\t{st}");
    for (k, v) in [
        ("SampleRotation", &t.sample_rotation_deg),
        ("AngleOfIncidence", &t.aoi_deg),
        ("ScatterAzimuth", &t.azimuth_deg),
        ("ScatterRadial", &t.radial_deg),
    ] {
        let _ = writeln!(o, "{k}\t{}\n{}", v.len(), list(v));
    }
    let nr = t.radial_deg.len().max(1);
    for c in &t.channels {
        let _ = writeln!(o, "\n{}\nDataBegin", c.channel.keyword());
        for b in &c.blocks {
            if let Some(tis) = b.tis {
                let _ = match precision {
                    Precision::Exact => writeln!(o, "TIS\t{tis:e}"),
                    Precision::Export => writeln!(o, "TIS\t{tis:.6}"),
                };
            }
            for row in b.values.chunks(nr) {
                let _ = writeln!(o, "{}", row.iter().map(|&x| num(x)).collect::<Vec<_>>().join("\t"));
            }
        }
        let _ = writeln!(o, "DataEnd");
    }
    o
}

/// Reads a `.BSDF` file (bytes that are not UTF-8, e.g. Latin-1 comments, become U+FFFD).
pub fn read(path: &Path) -> opal::Result<BsdfTable> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse(&String::from_utf8_lossy(&bytes), path)
}

/// Whether a file name looks like a Zemax `.BSDF` file (extension `bsdf`, any case).
pub fn is_zemax_path(path: &Path) -> bool {
    path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("bsdf"))
}

/// A whitespace-separated token with its 1-based line and column (shared with the
/// [`super::lighttools`] reader).
#[derive(Clone, Copy)]
pub(super) struct Tok<'a> {
    pub(super) line: usize,
    pub(super) col: usize,
    pub(super) text: &'a str,
}

/// The tokens of a file without its `#` comment lines.
pub(super) struct Tokens<'a> {
    pub(super) toks: Vec<Tok<'a>>,
    pub(super) pos: usize,
    path: &'a Path,
    last_line: usize,
}

impl<'a> Tokens<'a> {
    pub(super) fn new(text: &'a str, path: &'a Path) -> Self {
        let mut toks = Vec::new();
        let mut last_line = 1;
        for (i, line) in text.lines().enumerate() {
            last_line = i + 1;
            if line.trim_start().starts_with('#') {
                continue;
            }
            let mut start: Option<(usize, usize)> = None; // (byte, char column) of the token
            for (col, (b, ch)) in line.char_indices().enumerate() {
                match (ch.is_whitespace(), start) {
                    (false, None) => start = Some((b, col + 1)),
                    (true, Some((s0, c0))) => {
                        toks.push(Tok { line: i + 1, col: c0, text: &line[s0..b] });
                        start = None;
                    }
                    _ => {}
                }
            }
            if let Some((s0, c0)) = start {
                toks.push(Tok { line: i + 1, col: c0, text: &line[s0..] });
            }
        }
        Tokens { toks, pos: 0, path, last_line }
    }

    pub(super) fn err_at(&self, t: &Tok, msg: String) -> Error {
        Error::Parse { path: self.path.to_path_buf(), line: t.line, col: t.col, msg }
    }

    pub(super) fn peek(&self) -> Option<&Tok<'a>> {
        self.toks.get(self.pos)
    }

    pub(super) fn next(&mut self, expected: &str) -> opal::Result<Tok<'a>> {
        if self.pos >= self.toks.len() {
            return Err(Error::Parse {
                path: self.path.to_path_buf(),
                line: self.last_line,
                col: 0,
                msg: format!("unexpected end of file, expected {expected}"),
            });
        }
        self.pos += 1;
        Ok(self.toks[self.pos - 1])
    }

    pub(super) fn number(&mut self, expected: &str) -> opal::Result<f64> {
        let t = self.next(expected)?;
        match t.text.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            Ok(_) => Err(self.err_at(&t, format!("{expected}: not finite: {:?}", t.text))),
            Err(_) => Err(self.err_at(&t, format!("expected {expected}, found {:?}", t.text))),
        }
    }
}

fn is_number(s: &str) -> bool {
    s.parse::<f64>().is_ok()
}

/// An angle list: `Keyword n` then n angles; checked against `range` (inclusive bounds as
/// given by `hi_inclusive`).
pub(super) fn angle_list(
    tk: &mut Tokens,
    key: &Tok,
    name: &str,
    lo: f64,
    hi: f64,
    hi_inclusive: bool,
) -> opal::Result<Vec<f64>> {
    let ct = tk.next(&format!("the count of {name}"))?;
    let n: usize = ct.text.parse().map_err(|_| {
        tk.err_at(&ct, format!("{name}: the count must be a non-negative integer, found {:?}", ct.text))
    })?;
    if n == 0 {
        return Err(tk.err_at(key, format!("{name}: empty list (count 0)")));
    }
    // Each angle is a token: a count beyond what is left is an error before any allocation
    // (a fuzzed count of 2 555 555 555 asked for 20 GB).
    let left = tk.toks.len() - tk.pos;
    if n > left {
        return Err(
            tk.err_at(&ct, format!("{name}: the count {n} exceeds the {left} numbers left in the file"))
        );
    }
    let mut v = Vec::with_capacity(n);
    for i in 0..n {
        let what = format!("{name} angle {} of {n}", i + 1);
        let at = tk.pos;
        let x = tk.number(&what)?;
        let t = &tk.toks[at];
        let inside = x >= lo && if hi_inclusive { x <= hi } else { x < hi };
        if !inside {
            let close = if hi_inclusive { ']' } else { ')' };
            return Err(tk.err_at(t, format!("{name}: {x} is outside [{lo}, {hi}{close}")));
        }
        if let Some(&p) = v.last()
            && x <= p
        {
            return Err(tk.err_at(t, format!("{name}: angles must be strictly ascending, {x} after {p}")));
        }
        v.push(x);
    }
    Ok(v)
}

/// Parses `.BSDF` text (`path` only names the source in messages).
pub fn parse(text: &str, path: &Path) -> opal::Result<BsdfTable> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut tk = Tokens::new(text, path);
    let mut source = String::new();
    let mut symmetry = None;
    let mut spectral = None;
    let mut scatter_type = None;
    let mut rot: Option<Vec<f64>> = None;
    let mut aoi: Option<Vec<f64>> = None;
    let mut az: Option<Vec<f64>> = None;
    let mut rad: Option<Vec<f64>> = None;
    let mut channels: Vec<ChannelData> = Vec::new();
    let mut az_tok: Option<(usize, usize)> = None;
    while tk.peek().is_some() {
        let key_idx = tk.pos;
        let key = tk.next("a keyword")?;
        let (kline, kcol, ktext) = (key.line, key.col, key.text);
        let lower = ktext.to_ascii_lowercase();
        let value = |tk: &mut Tokens| -> opal::Result<(String, usize)> {
            let at = tk.pos;
            let v = tk.next(&format!("the value of {ktext}"))?.text.to_ascii_lowercase();
            Ok((v, at))
        };
        match lower.as_str() {
            "source" => source = tk.next("the value of Source")?.text.to_string(),
            "symmetry" => {
                let (v, at) = value(&mut tk)?;
                symmetry = Some(match v.as_str() {
                    "planesymmetrical" => Symmetry::PlaneSymmetrical,
                    "asymmetrical" => Symmetry::Asymmetrical,
                    "asymmetrical4d" => Symmetry::Asymmetrical4D,
                    _ => {
                        return Err(tk.err_at(
                            &tk.toks[at],
                            format!(
                                "Symmetry: unknown value {:?} (PlaneSymmetrical, Asymmetrical, Asymmetrical4D)",
                                tk.toks[at].text
                            ),
                        ));
                    }
                });
            }
            "spectralcontent" => {
                let (v, at) = value(&mut tk)?;
                spectral = Some(match v.as_str() {
                    "monochrome" => SpectralContent::Monochrome,
                    "xyz" => SpectralContent::Xyz,
                    _ => {
                        return Err(tk.err_at(
                            &tk.toks[at],
                            format!(
                                "SpectralContent: unknown value {:?} (Monochrome, XYZ)",
                                tk.toks[at].text
                            ),
                        ));
                    }
                });
            }
            "scattertype" => {
                let (v, at) = value(&mut tk)?;
                scatter_type = Some(match v.as_str() {
                    "brdf" => ScatterType::Brdf,
                    "btdf" => ScatterType::Btdf,
                    _ => {
                        return Err(tk.err_at(
                            &tk.toks[at],
                            format!("ScatterType: unknown value {:?} (BRDF, BTDF)", tk.toks[at].text),
                        ));
                    }
                });
            }
            "samplerotation" => rot = Some(angle_list(&mut tk, &key, "SampleRotation", -360.0, 360.0, true)?),
            "angleofincidence" => {
                aoi = Some(angle_list(&mut tk, &key, "AngleOfIncidence", 0.0, 90.0, false)?)
            }
            "scatterazimuth" => {
                az_tok = Some((kline, kcol));
                az = Some(angle_list(&mut tk, &key, "ScatterAzimuth", 0.0, 360.0, false)?);
            }
            "scatterradial" => rad = Some(angle_list(&mut tk, &key, "ScatterRadial", 0.0, 90.0, true)?),
            "monochrome" | "tristimulusx" | "tristimulusy" | "tristimulusz" => {
                let channel = match lower.as_str() {
                    "monochrome" => Channel::Monochrome,
                    "tristimulusx" => Channel::TristimulusX,
                    "tristimulusy" => Channel::TristimulusY,
                    _ => Channel::TristimulusZ,
                };
                if channels.iter().any(|c| c.channel == channel) {
                    return Err(tk.err_at(&key, format!("data of {ktext} given twice")));
                }
                let (Some(aoi), Some(az), Some(rad)) = (&aoi, &az, &rad) else {
                    return Err(tk.err_at(
                        &key,
                        format!(
                            "data section {ktext} before the angle lists (AngleOfIncidence, ScatterAzimuth, ScatterRadial are required first)"
                        ),
                    ));
                };
                let nrot = rot.as_ref().map_or(1, Vec::len);
                let blocks = data_section(&mut tk, ktext, nrot, aoi, az.len() * rad.len())?;
                channels.push(ChannelData { channel, blocks });
            }
            _ => {
                let t = &tk.toks[key_idx];
                let msg = if is_number(t.text) {
                    format!(
                        "unexpected number {:?} (a keyword was expected; too many values before?)",
                        t.text
                    )
                } else {
                    format!(
                        "unknown keyword {:?} (Source, Symmetry, SpectralContent, ScatterType, SampleRotation, AngleOfIncidence, ScatterAzimuth, ScatterRadial, Monochrome, TristimulusX/Y/Z)",
                        t.text
                    )
                };
                return Err(tk.err_at(t, msg));
            }
        }
    }
    let missing = |k: &str| Error::Parse {
        path: path.to_path_buf(),
        line: 0,
        col: 0,
        msg: format!("missing keyword {k}"),
    };
    let symmetry = symmetry.ok_or_else(|| missing("Symmetry"))?;
    let scatter_type = scatter_type.ok_or_else(|| missing("ScatterType"))?;
    let aoi_deg = aoi.ok_or_else(|| missing("AngleOfIncidence"))?;
    let azimuth_deg = az.ok_or_else(|| missing("ScatterAzimuth"))?;
    let radial_deg = rad.ok_or_else(|| missing("ScatterRadial"))?;
    let spectral = spectral.unwrap_or(SpectralContent::Monochrome);
    if channels.is_empty() {
        return Err(missing("DataBegin (no data section: Monochrome or TristimulusX/Y/Z)"));
    }
    let want: &[Channel] = match spectral {
        SpectralContent::Monochrome => &[Channel::Monochrome],
        SpectralContent::Xyz => &[Channel::TristimulusX, Channel::TristimulusY, Channel::TristimulusZ],
    };
    for c in &channels {
        if !want.contains(&c.channel) {
            return Err(Error::Parse {
                path: path.to_path_buf(),
                line: 0,
                col: 0,
                msg: format!("data of {} in a file with SpectralContent {spectral:?}", c.channel.keyword()),
            });
        }
    }
    for w in want {
        if !channels.iter().any(|c| c.channel == *w) {
            return Err(missing(&format!("{} (SpectralContent {spectral:?})", w.keyword())));
        }
    }
    if symmetry == Symmetry::PlaneSymmetrical
        && let Some(&a) = azimuth_deg.iter().find(|a| **a > 180.0)
    {
        let (line, col) = az_tok.unwrap_or((0, 0));
        return Err(Error::Parse {
            path: path.to_path_buf(),
            line,
            col,
            msg: format!("ScatterAzimuth: {a} > 180 in a PlaneSymmetrical file (azimuths 0…180 only)"),
        });
    }
    Ok(BsdfTable {
        source,
        symmetry,
        spectral,
        scatter_type,
        sample_rotation_deg: rot.unwrap_or_else(|| vec![0.0]),
        aoi_deg,
        azimuth_deg,
        radial_deg,
        channels,
    })
}

/// `DataBegin`, the blocks, `DataEnd`.
fn data_section(
    tk: &mut Tokens,
    channel: &str,
    nrot: usize,
    aoi: &[f64],
    per_block: usize,
) -> opal::Result<Vec<Block>> {
    let t = tk.next("DataBegin")?;
    if !t.text.eq_ignore_ascii_case("databegin") {
        return Err(tk.err_at(&t, format!("expected DataBegin after {channel}, found {:?}", t.text)));
    }
    // Capacities bounded by the tokens left: the counts come from the file.
    let left = tk.toks.len() - tk.pos;
    let mut blocks = Vec::with_capacity((nrot * aoi.len()).min(left));
    for r in 0..nrot {
        for &a in aoi {
            let mut tis = None;
            if let Some(t) = tk.peek()
                && t.text.eq_ignore_ascii_case("tis")
            {
                tk.pos += 1;
                tis = Some(
                    tk.number(&format!("the TIS value of {channel} block (rotation {}, AOI {a}°)", r + 1))?,
                );
            }
            let mut values = Vec::with_capacity(per_block.min(tk.toks.len() - tk.pos));
            for k in 0..per_block {
                if let Some(t) = tk.peek()
                    && (t.text.eq_ignore_ascii_case("dataend") || t.text.eq_ignore_ascii_case("tis"))
                {
                    return Err(tk.err_at(
                        t,
                        format!(
                            "{channel} block (rotation {}, AOI {a}°) has {k} values, expected ScatterAzimuth × ScatterRadial = {per_block}",
                            r + 1
                        ),
                    ));
                }
                values.push(tk.number(&format!(
                    "BSDF value {} of {per_block} of {channel} block (rotation {}, AOI {a}°)",
                    k + 1,
                    r + 1
                ))?);
            }
            blocks.push(Block { tis, values });
        }
    }
    let t = tk.next("DataEnd")?;
    if !t.text.eq_ignore_ascii_case("dataend") {
        let msg = if is_number(t.text) || t.text.eq_ignore_ascii_case("tis") {
            format!(
                "{channel}: more data than SampleRotation × AngleOfIncidence × ScatterAzimuth × ScatterRadial = {} values (found {:?} where DataEnd was expected)",
                nrot * aoi.len() * per_block,
                t.text
            )
        } else {
            format!("expected DataEnd, found {:?}", t.text)
        };
        return Err(tk.err_at(&t, msg));
    }
    Ok(blocks)
}

#[cfg(test)]
mod tests;
