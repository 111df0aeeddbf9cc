//! Measured goniophotometer curves of a plate (method A input).
//!
//! Format (documented in `docs/formats.md`): a CSV file with a header row naming at least the
//! columns `incidence_deg,side,detector_deg,value` and optionally `value_stderr`, in any order;
//! other columns are ignored (so the files of `<shared>/reference/mitsuba/gonio` and of
//! `opal gonio simulate` load as they are). `side` is `R` (reflected) or `T` (transmitted);
//! `detector_deg` is the signed angle of the detector in the plane of incidence (the
//! conventions of `opal::gonio`); `value` is the intensity per unit incident power (1/sr);
//! `value_stderr` its standard error. Blank lines and lines starting with `#` are skipped.
//! Full-hemisphere measurements add the column `detector_azimuth_deg` (azimuth from the plane
//! of incidence, wrapped into [0°, 360°)); `detector_deg` is then the polar angle (≥ 0) and the
//! pole is one detector whatever its azimuth ([`Measured::hemisphere`]).
//!
//! Rejected (with the file, line and column in the message): a missing column, a
//! non-numeric or non-finite cell, a side other than R/T, an incidence outside [0°, 90°), a
//! detector angle outside (−90°, 90°), a negative standard error, a duplicated
//! (incidence, side, detector) point, a file without data, an incidence that has points on one
//! side only while other incidences have both (an empty side), values ≤ 0 everywhere.
//!
//! [`Measured::from_rows`] builds curves from points of any reader (the `.BSDF` reader of
//! [`crate::scatter::zemax`]); [`Measured::merge`] joins files of one sample.
//!
//! Tests: `tests` below (every rejection, the reference files, hemisphere columns, merging).

use opal::Error;
use opal::gonio::Side;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// One measured curve: one incidence angle, one side.
#[derive(Clone, Debug)]
pub struct Curve {
    /// Incidence angle (radians).
    pub incidence: f64,
    /// Side.
    pub side: Side,
    /// Detector angles (radians), ascending: signed in the plane of incidence, or the polar
    /// angle (≥ 0) of a hemisphere measurement.
    pub detector: Vec<f64>,
    /// Detector azimuths (radians, [0, 2π), from the plane of incidence, 0 = the specular
    /// side) of a hemisphere measurement; all 0 for plane-of-incidence curves.
    pub azimuth: Vec<f64>,
    /// Values (1/sr).
    pub value: Vec<f64>,
    /// Standard errors (0 when the file has none).
    pub stderr: Vec<f64>,
}

impl Curve {
    /// Largest value of the curve.
    pub fn max(&self) -> f64 {
        self.value.iter().cloned().fold(0.0, f64::max)
    }
}

/// A set of measured curves.
#[derive(Clone, Debug)]
pub struct Measured {
    /// Source file (for messages).
    pub path: PathBuf,
    /// Curves sorted by incidence, then side (R before T).
    pub curves: Vec<Curve>,
    /// Whether the file had a `value_stderr` column.
    pub has_stderr: bool,
    /// Whether the detectors cover the hemisphere (polar + azimuth, column
    /// `detector_azimuth_deg`) rather than the plane of incidence (signed angle).
    pub hemisphere: bool,
}

/// One measured point, angles in degrees (the columns of the CSV format).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Row {
    /// Incidence angle.
    pub incidence_deg: f64,
    /// Side.
    pub side: Side,
    /// Signed detector angle (plane of incidence) or polar angle (hemisphere).
    pub detector_deg: f64,
    /// Detector azimuth (hemisphere; 0 in the plane-of-incidence form).
    pub azimuth_deg: f64,
    /// Intensity per unit incident power (1/sr).
    pub value: f64,
    /// Standard error of `value` (0 when unknown).
    pub stderr: f64,
}

fn parse_err(path: &Path, line: usize, col: usize, msg: impl Into<String>) -> Error {
    Error::Parse { path: path.to_path_buf(), line, col, msg: msg.into() }
}

impl Measured {
    /// Reads a CSV file.
    pub fn read(path: &Path) -> opal::Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        Self::parse(&text, path)
    }

    /// Parses CSV text (`path` only names the source in messages).
    pub fn parse(text: &str, path: &Path) -> opal::Result<Self> {
        let mut lines = text.lines().enumerate().filter(|(_, l)| {
            let t = l.trim();
            !t.is_empty() && !t.starts_with('#')
        });
        let (hline, header) =
            lines.next().ok_or_else(|| parse_err(path, 1, 1, "empty file (no header row)"))?;
        let names: Vec<String> =
            header.split(',').map(|s| s.trim().trim_matches('"').to_ascii_lowercase()).collect();
        let find = |n: &str| names.iter().position(|x| x == n);
        let mut idx = [0usize; 4];
        for (k, n) in ["incidence_deg", "side", "detector_deg", "value"].iter().enumerate() {
            idx[k] = find(n).ok_or_else(|| {
                parse_err(
                    path,
                    hline + 1,
                    1,
                    format!("missing column {n:?} (header has {:?}; needed: incidence_deg,side,detector_deg,value[,value_stderr])", names),
                )
            })?;
        }
        let i_err = find("value_stderr");
        let i_az = find("detector_azimuth_deg");
        let mut seen: HashMap<(i64, Side, i64, i64), usize> = HashMap::new();
        let mut rows: Vec<Row> = Vec::new();
        for (ln, line) in lines {
            let line_no = ln + 1;
            let cells: Vec<&str> = line.split(',').map(|s| s.trim().trim_matches('"')).collect();
            let cell = |k: usize, name: &str| -> opal::Result<&str> {
                cells.get(k).copied().filter(|s| !s.is_empty()).ok_or_else(|| {
                    parse_err(
                        path,
                        line_no,
                        k + 1,
                        format!("row {line_no}: empty or missing cell in column {name:?}"),
                    )
                })
            };
            let num = |k: usize, name: &str| -> opal::Result<f64> {
                let s = cell(k, name)?;
                let v: f64 = s.parse().map_err(|_| {
                    parse_err(
                        path,
                        line_no,
                        k + 1,
                        format!("row {line_no}: column {name:?} is not a number: {s:?}"),
                    )
                })?;
                if !v.is_finite() {
                    return Err(parse_err(
                        path,
                        line_no,
                        k + 1,
                        format!("row {line_no}: column {name:?} is not finite: {s:?}"),
                    ));
                }
                Ok(v)
            };
            let inc = num(idx[0], "incidence_deg")?;
            if !(0.0..90.0).contains(&inc) {
                return Err(parse_err(
                    path,
                    line_no,
                    idx[0] + 1,
                    format!("row {line_no}: incidence_deg must be in [0, 90), got {inc}"),
                ));
            }
            let side = match cell(idx[1], "side")? {
                "R" | "r" => Side::R,
                "T" | "t" => Side::T,
                s => {
                    return Err(parse_err(
                        path,
                        line_no,
                        idx[1] + 1,
                        format!("row {line_no}: side must be R or T, got {s:?}"),
                    ));
                }
            };
            let det = num(idx[2], "detector_deg")?;
            if i_az.is_some() && det < 0.0 {
                return Err(parse_err(
                    path,
                    line_no,
                    idx[2] + 1,
                    format!(
                        "row {line_no}: detector_deg is the polar angle with detector_azimuth_deg, must be in [0, 90), got {det}"
                    ),
                ));
            }
            let az = match i_az {
                // one detector at the pole; azimuths wrapped into [0, 360)
                Some(k) => {
                    if det == 0.0 {
                        num(k, "detector_azimuth_deg").map(|_| 0.0)?
                    } else {
                        num(k, "detector_azimuth_deg")?.rem_euclid(360.0)
                    }
                }
                None => 0.0,
            };
            if det.abs() >= 90.0 {
                return Err(parse_err(
                    path,
                    line_no,
                    idx[2] + 1,
                    format!("row {line_no}: detector_deg must be in (−90, 90), got {det}"),
                ));
            }
            let value = num(idx[3], "value")?;
            let se = match i_err {
                Some(k) => {
                    let e = num(k, "value_stderr")?;
                    if e < 0.0 {
                        return Err(parse_err(
                            path,
                            line_no,
                            k + 1,
                            format!("row {line_no}: value_stderr must be ≥ 0, got {e}"),
                        ));
                    }
                    e
                }
                None => 0.0,
            };
            let key =
                ((inc * 1e6).round() as i64, side, (det * 1e6).round() as i64, (az * 1e6).round() as i64);
            if let Some(prev) = seen.insert(key, line_no) {
                return Err(parse_err(
                    path,
                    line_no,
                    1,
                    format!(
                        "row {line_no}: duplicated point (incidence {inc}°, side {}, detector {det}°{}), first on row {prev}",
                        side.label(),
                        if i_az.is_some() { format!(", azimuth {az}°") } else { String::new() }
                    ),
                ));
            }
            rows.push(Row {
                incidence_deg: inc,
                side,
                detector_deg: det,
                azimuth_deg: az,
                value,
                stderr: se,
            });
        }
        if rows.is_empty() {
            return Err(parse_err(path, hline + 1, 1, "no data rows"));
        }
        Self::from_rows(path, rows, i_err.is_some(), i_az.is_some())
    }

    /// Curves from points in any order (other readers, e.g. [`crate::scatter::zemax`]); the
    /// checks after reading of [`Measured::parse`] apply (no data, duplicated point, values
    /// ≤ 0 everywhere, empty side). `hemisphere`: the rows carry polar + azimuth angles.
    pub fn from_rows(
        path: &Path,
        mut rows: Vec<Row>,
        has_stderr: bool,
        hemisphere: bool,
    ) -> opal::Result<Self> {
        if rows.is_empty() {
            return Err(Error::invalid(format!("{}", path.display()), "no data points"));
        }
        rows.sort_by(|a, b| {
            a.incidence_deg
                .total_cmp(&b.incidence_deg)
                .then((a.side == Side::T).cmp(&(b.side == Side::T)))
                .then(a.detector_deg.total_cmp(&b.detector_deg))
                .then(a.azimuth_deg.total_cmp(&b.azimuth_deg))
        });
        let key = |r: &Row| {
            let q = |x: f64| (x * 1e6).round() as i64;
            (q(r.incidence_deg), r.side, q(r.detector_deg), q(r.azimuth_deg))
        };
        for w in rows.windows(2) {
            if key(&w[0]) == key(&w[1]) {
                return Err(Error::invalid(
                    format!("{}", path.display()),
                    format!(
                        "duplicated point (incidence {}°, side {}, detector {}°, azimuth {}°)",
                        w[0].incidence_deg,
                        w[0].side.label(),
                        w[0].detector_deg,
                        w[0].azimuth_deg
                    ),
                ));
            }
        }
        if !rows.iter().any(|r| r.value > 0.0) {
            return Err(Error::invalid(
                format!("{}: value", path.display()),
                "every value is ≤ 0 (nothing was measured)",
            ));
        }
        let mut curves: Vec<Curve> = Vec::new();
        for r in rows {
            let (inc, side, det, v, se) = (r.incidence_deg, r.side, r.detector_deg, r.value, r.stderr);
            let inc_r = inc.to_radians();
            match curves.last_mut() {
                Some(c) if c.incidence == inc_r && c.side == side => {
                    c.detector.push(det.to_radians());
                    c.azimuth.push(r.azimuth_deg.to_radians());
                    c.value.push(v);
                    c.stderr.push(se);
                }
                _ => curves.push(Curve {
                    incidence: inc_r,
                    side,
                    detector: vec![det.to_radians()],
                    azimuth: vec![r.azimuth_deg.to_radians()],
                    value: vec![v],
                    stderr: vec![se],
                }),
            }
        }
        // empty side: an incidence with one side only while the file has both sides elsewhere
        let has = |s: Side| curves.iter().any(|c| c.side == s);
        if has(Side::R) && has(Side::T) {
            let mut incs: Vec<f64> = curves.iter().map(|c| c.incidence).collect();
            incs.dedup();
            for inc in incs {
                for s in [Side::R, Side::T] {
                    if !curves.iter().any(|c| c.incidence == inc && c.side == s) {
                        return Err(Error::invalid(
                            format!("{}: side {}", path.display(), s.label()),
                            format!(
                                "incidence {}° has no point on side {} while other incidences do (empty side)",
                                fmt(inc.to_degrees()),
                                s.label()
                            ),
                        ));
                    }
                }
            }
        }
        for c in &curves {
            if !c.value.iter().any(|&v| v > 0.0) {
                return Err(Error::invalid(
                    format!("{}: side {}", path.display(), c.side.label()),
                    format!("incidence {}°: every value is ≤ 0 (empty side)", fmt(c.incidence.to_degrees())),
                ));
            }
        }
        Ok(Measured { path: path.to_path_buf(), curves, has_stderr, hemisphere })
    }

    /// Merges measurements of one sample read from several files (e.g. a BRDF and a BTDF
    /// `.BSDF` file); a curve (incidence, side) present in two files is an error naming both.
    /// The result is named `a + b + …` and has standard errors when every part has.
    pub fn merge(parts: Vec<Measured>) -> opal::Result<Self> {
        let name = parts.iter().map(|m| m.path.display().to_string()).collect::<Vec<_>>().join(" + ");
        let mut rows = Vec::new();
        let hemisphere = parts.iter().any(|m| m.hemisphere);
        for (i, m) in parts.iter().enumerate() {
            if m.hemisphere != hemisphere {
                return Err(Error::invalid(
                    format!("{}", m.path.display()),
                    "plane-of-incidence curves cannot be merged with hemisphere measurements (detector_azimuth_deg)",
                ));
            }
            for c in &m.curves {
                for o in &parts[..i] {
                    if o.curves.iter().any(|d| d.side == c.side && (d.incidence - c.incidence).abs() < 1e-9) {
                        return Err(Error::invalid(
                            format!("{}", m.path.display()),
                            format!(
                                "incidence {}° side {} is also in {} (each curve in one file only)",
                                fmt(c.incidence.to_degrees()),
                                c.side.label(),
                                o.path.display()
                            ),
                        ));
                    }
                }
                for k in 0..c.detector.len() {
                    rows.push(Row {
                        incidence_deg: c.incidence.to_degrees(),
                        side: c.side,
                        detector_deg: c.detector[k].to_degrees(),
                        azimuth_deg: c.azimuth[k].to_degrees(),
                        value: c.value[k],
                        stderr: c.stderr[k],
                    });
                }
            }
        }
        Self::from_rows(Path::new(&name), rows, parts.iter().all(|m| m.has_stderr), hemisphere)
    }

    /// Curves from a simulation (synthetic measurements for round trips; plane of incidence or
    /// hemisphere layout): detectors with a zero value are kept (they carry no information but
    /// are valid).
    pub fn from_gonio(gonio: &opal::gonio::Gonio, res: &opal::gonio::GonioResult, name: &str) -> Self {
        let dets = gonio.detectors().list();
        let mut curves = Vec::new();
        for r in &res.incidences {
            for side in [Side::R, Side::T] {
                let mut c = Curve {
                    incidence: r.incidence,
                    side,
                    detector: vec![],
                    azimuth: vec![],
                    value: vec![],
                    stderr: vec![],
                };
                for (k, d) in dets.iter().enumerate().filter(|(_, d)| d.side == side) {
                    c.detector.push(d.angle_deg.to_radians());
                    c.azimuth.push(d.azimuth_deg.to_radians());
                    c.value.push(r.value[k]);
                    c.stderr.push(r.value_stderr[k]);
                }
                curves.push(c);
            }
        }
        Measured {
            path: PathBuf::from(name),
            curves,
            has_stderr: true,
            hemisphere: gonio.detectors().is_hemisphere(),
        }
    }

    /// Distinct incidence angles (radians), ascending.
    pub fn incidences(&self) -> Vec<f64> {
        let mut v: Vec<f64> = self.curves.iter().map(|c| c.incidence).collect();
        v.dedup();
        v
    }

    /// Distinct detector angles over all curves (radians), ascending.
    pub fn detector_angles(&self) -> Vec<f64> {
        let mut v: Vec<f64> = self.curves.iter().flat_map(|c| c.detector.iter().cloned()).collect();
        v.sort_by(f64::total_cmp);
        v.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
        v
    }

    /// Distinct detector azimuths (radians), ascending (hemisphere measurements; the pole's
    /// azimuth is left out).
    pub fn detector_azimuths(&self) -> Vec<f64> {
        let mut v: Vec<f64> = self
            .curves
            .iter()
            .flat_map(|c| c.detector.iter().zip(&c.azimuth).filter(|(t, _)| **t != 0.0).map(|(_, a)| *a))
            .collect();
        v.sort_by(f64::total_cmp);
        v.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
        if v.is_empty() {
            v.push(0.0);
        }
        v
    }

    /// Whether any curve is on `side`.
    pub fn has_side(&self, side: Side) -> bool {
        self.curves.iter().any(|c| c.side == side)
    }
}

fn fmt(x: f64) -> String {
    let r = (x * 1e6).round() / 1e6;
    format!("{r}")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(text: &str) -> opal::Result<Measured> {
        Measured::parse(text, Path::new("m.csv"))
    }

    const GOOD: &str = "incidence_deg,side,detector_deg,value,value_stderr\n\
        0,R,-10,0.1,0.01\n0,R,10,0.2,0.01\n0,T,0,1.0,0.02\n30,T,30,0.5,0.01\n30,R,30,0.3,0.01\n";

    #[test]
    fn reads_good_file() {
        let m = p(GOOD).unwrap();
        assert_eq!(m.curves.len(), 4);
        assert_eq!(m.incidences().len(), 2);
        assert_eq!(m.detector_angles().len(), 4); // −10, 0, 10, 30
        assert!(m.has_stderr);
        assert_eq!(m.curves[0].side, Side::R);
        assert_eq!(m.curves[0].value, vec![0.1, 0.2]);
    }

    #[test]
    fn column_order_and_extra_columns() {
        let m = p("value,side,foo,detector_deg,incidence_deg\n0.5,T,x,0,0\n").unwrap();
        assert_eq!(m.curves.len(), 1);
        assert!(!m.has_stderr);
        assert_eq!(m.curves[0].stderr, vec![0.0]);
    }

    fn err(text: &str) -> String {
        p(text).unwrap_err().to_string()
    }

    #[test]
    fn rejects_bad_input() {
        assert!(err("incidence_deg,side,value\n0,R,1\n").contains("missing column \"detector_deg\""));
        let e = err("incidence_deg,side,detector_deg,value\n0,R,1,0.1\n0,R,2,abc\n");
        assert!(e.contains("row 3") && e.contains("not a number") && e.contains("abc"), "{e}");
        let e = err("incidence_deg,side,detector_deg,value\n0,R,1,0.1\n0,R,1.0,0.2\n");
        assert!(e.contains("duplicated") && e.contains("row 2"), "{e}");
        let e = err("incidence_deg,side,detector_deg,value\n0,R,95,0.1\n");
        assert!(e.contains("detector_deg") && e.contains("95"), "{e}");
        let e = err("incidence_deg,side,detector_deg,value\n-5,R,5,0.1\n");
        assert!(e.contains("incidence_deg"), "{e}");
        let e = err("incidence_deg,side,detector_deg,value\n0,R,5,0\n0,T,5,-1\n");
        assert!(e.contains("≤ 0"), "{e}");
        let e = err("incidence_deg,side,detector_deg,value\n0,R,5,1\n0,T,5,1\n30,R,5,1\n");
        assert!(e.contains("empty side") && e.contains("30"), "{e}");
        let e = err("incidence_deg,side,detector_deg,value\n0,R,5,1\n0,T,5,0\n");
        assert!(e.contains("empty side"), "{e}");
        let e = err("incidence_deg,side,detector_deg,value\n0,X,5,1\n");
        assert!(e.contains("side must be R or T"), "{e}");
        let e = err("incidence_deg,side,detector_deg,value\n0,,5,1\n");
        assert!(e.contains("empty or missing cell"), "{e}");
        assert!(err("incidence_deg,side,detector_deg,value\n").contains("no data"));
        assert!(err("").contains("empty file"));
        let e = err("incidence_deg,side,detector_deg,value,value_stderr\n0,R,5,1,-1\n");
        assert!(e.contains("value_stderr"), "{e}");
    }

    #[test]
    fn reads_reference_file() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../opal/tests/data/gonio/ggx_a0.15_rough.csv");
        let m = Measured::read(&path).unwrap();
        assert_eq!(m.incidences().len(), 6);
        assert_eq!(m.detector_angles().len(), 179);
        assert_eq!(m.curves.len(), 12);
        assert!(m.curves.iter().all(|c| c.detector.len() == 179));
    }

    /// Hemisphere measurements: `detector_azimuth_deg` makes `detector_deg` the polar angle
    /// (≥ 0); azimuths wrap into [0, 360); the pole is one detector whatever its azimuth.
    #[test]
    fn hemisphere_columns() {
        let p = Path::new("h.csv");
        let h = "incidence_deg,side,detector_deg,detector_azimuth_deg,value\n";
        let m = Measured::parse(&format!("{h}0,R,10,-90,1\n0,R,0,45,2\n0,R,10,90,3\n"), p).unwrap();
        assert!(m.hemisphere);
        let c = &m.curves[0];
        let az: Vec<f64> = c.azimuth.iter().map(|a| a.to_degrees().round()).collect();
        assert_eq!(az, vec![0.0, 90.0, 270.0]);
        assert_eq!(c.value, vec![2.0, 3.0, 1.0]);
        assert_eq!(m.detector_azimuths().len(), 2);
        let e = Measured::parse(&format!("{h}0,R,-10,0,1\n"), p).unwrap_err().to_string();
        assert!(e.contains("h.csv:2:3") && e.contains("polar angle"), "{e}");
        let e = Measured::parse(&format!("{h}0,R,0,0,1\n0,R,0,30,1\n"), p).unwrap_err().to_string();
        assert!(e.contains("duplicated point"), "{e}");
        let e = Measured::parse(&format!("{h}0,R,10,370,1\n0,R,10,10,1\n"), p).unwrap_err().to_string();
        assert!(e.contains("duplicated point"), "{e}");
        // plane curves and hemisphere curves do not merge
        let plane = Measured::parse("incidence_deg,side,detector_deg,value\n0,T,0,1\n", p).unwrap();
        assert!(!plane.hemisphere && plane.curves[0].azimuth == vec![0.0]);
        let e = Measured::merge(vec![plane, m]).unwrap_err().to_string();
        assert!(e.contains("cannot be merged"), "{e}");
    }
}
