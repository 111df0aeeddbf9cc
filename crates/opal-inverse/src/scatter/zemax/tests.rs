//! Tests of the `.BSDF` reader and writer: hand-written files of every kind, malformed files
//! (the message names line, column and value), the exact round trip, the curves for the fit.

use super::*;
use std::path::PathBuf;

fn p() -> PathBuf {
    PathBuf::from("t.BSDF")
}

/// A plane-symmetric BRDF, 2 AOI × 3 azimuths × 4 radials, comments and odd spacing.
const SYM: &str = "# measured somewhere\n\
Source  Measured\n\
Symmetry  PlaneSymmetrical\n\
SpectralContent  Monochrome\n\
ScatterType  BRDF\n\
SampleRotation  1\n0\n\
AngleOfIncidence  2\n0  30\n\
ScatterAzimuth  3\n0 90 180\n\
ScatterRadial  4\n0 1 5 10\n\
\n\
Monochrome\n\
DataBegin\n\
TIS  0.04\n\
10 5 1 0.1\n\
10 5 1 0.1\n\
10 5 1 0.1\n\
TIS 0.05\n\
20 8 2 0.2\n\
20 7 2 0.2\n\
20 6 3 0.3\n\
DataEnd\n";

#[test]
fn plane_symmetric_brdf() {
    let t = parse(SYM, &p()).unwrap();
    assert_eq!(t.symmetry, Symmetry::PlaneSymmetrical);
    assert_eq!(t.scatter_type, ScatterType::Brdf);
    assert_eq!(t.source, "Measured");
    assert_eq!(t.aoi_deg, vec![0.0, 30.0]);
    assert_eq!(t.azimuth_deg, vec![0.0, 90.0, 180.0]);
    assert_eq!(t.radial_deg, vec![0.0, 1.0, 5.0, 10.0]);
    assert_eq!(t.channels.len(), 1);
    let b = t.block(0, 0, 1);
    assert_eq!(b.tis, Some(0.05));
    assert_eq!(b.values[4..8], [20.0, 7.0, 2.0, 0.2]); // azimuth 90 row
    assert_eq!(b.values[8..12], [20.0, 6.0, 3.0, 0.3]); // azimuth 180 row
}

#[test]
fn keywords_and_values_are_case_insensitive() {
    let odd = SYM
        .replace("Symmetry  PlaneSymmetrical", "SYMMETRY planesymmetrical")
        .replace("ScatterType  BRDF", "scattertype brdf")
        .replace("AngleOfIncidence", "angleOfIncidence")
        .replace("DataBegin", "DATABEGIN")
        .replace("TIS", "tis")
        .replace("DataEnd", "dataend")
        .replace("\nMonochrome\n", "\nMONOCHROME\n")
        .replace("SpectralContent  Monochrome", "spectralcontent MonoChrome");
    let a = parse(&format!("\u{feff}{odd}"), &p()).unwrap(); // with a byte-order mark
    let b = parse(SYM, &p()).unwrap();
    assert_eq!(a, b);
    // the spec's own spellings of the 4-D symmetry
    for s in ["ASymmetrical4D", "Asymmetrical4D", "asymmetrical4d"] {
        let t = parse(&SYM.replace("PlaneSymmetrical", s), &p()).unwrap();
        assert_eq!(t.symmetry, Symmetry::Asymmetrical4D);
    }
}

/// An asymmetric BTDF with two sample rotations, no TIS lines, numbers spread over lines.
#[test]
fn asymmetric_btdf_two_rotations() {
    let text = "Symmetry Asymmetrical\nScatterType BTDF\nSampleRotation 2\n0 90\n\
                AngleOfIncidence 1\n10\nScatterAzimuth 4\n0 90 180 270\nScatterRadial 2\n0 20\n\
                Monochrome DataBegin\n\
                1 2 3 4 5 6 7 8\n\
                11 12\n13 14\n15 16\n17 18\nDataEnd\n";
    let t = parse(text, &p()).unwrap();
    assert_eq!(t.symmetry, Symmetry::Asymmetrical);
    assert_eq!(t.scatter_type, ScatterType::Btdf);
    assert_eq!(t.sample_rotation_deg, vec![0.0, 90.0]);
    assert_eq!(t.spectral, SpectralContent::Monochrome); // default
    assert_eq!(t.block(0, 0, 0).tis, None);
    assert_eq!(t.block(0, 0, 0).values, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0]);
    assert_eq!(t.block(0, 1, 0).values, vec![11.0, 12.0, 13.0, 14.0, 15.0, 16.0, 17.0, 18.0]);
    // exact round trip of an asymmetric table
    let back = parse(&write(&t, "rt", Precision::Exact), &p()).unwrap();
    assert_eq!(back, t);
    // BTDF → side T; AOI 10: azimuth 0 row at p = 10 − r, azimuth 180 row at p = 10 + r
    let m = t.to_measured(&p()).unwrap();
    assert_eq!(m.curves.len(), 1);
    let c = &m.curves[0];
    assert_eq!(c.side, Side::T);
    let deg: Vec<f64> = c.detector.iter().map(|x| (x.to_degrees() * 1e9).round() / 1e9).collect();
    assert_eq!(deg, vec![-10.0, 10.0, 30.0]);
    let cos = |d: f64| d.to_radians().cos();
    assert_eq!(c.value, vec![2.0 * cos(-10.0), 1.0 * cos(10.0), 6.0 * cos(30.0)]);
}

#[test]
fn xyz_channels() {
    let head = "Symmetry PlaneSymmetrical\nSpectralContent XYZ\nScatterType BRDF\n\
                AngleOfIncidence 1\n0\nScatterAzimuth 1\n0\nScatterRadial 2\n0 10\n";
    let text = format!(
        "{head}TristimulusX\nDataBegin\nTIS 0.1\n1 2\nDataEnd\nTristimulusY\nDataBegin\nTIS 0.2\n3 4\nDataEnd\n\
         TristimulusZ\nDataBegin\nTIS 0.3\n5 6\nDataEnd\n"
    );
    let t = parse(&text, &p()).unwrap();
    assert_eq!(
        t.channels.iter().map(|c| c.channel).collect::<Vec<_>>(),
        [Channel::TristimulusX, Channel::TristimulusY, Channel::TristimulusZ]
    );
    // the fit uses Y
    let m = t.to_measured(&p()).unwrap();
    assert_eq!(m.curves[0].value, vec![4.0 * 10f64.to_radians().cos(), 3.0]); // p = −10°, 0°
    assert_eq!(parse(&write(&t, "", Precision::Exact), &p()).unwrap(), t);
    // a missing channel is an error
    let e = parse(&format!("{head}TristimulusX\nDataBegin\n1 2\nDataEnd\n"), &p()).unwrap_err().to_string();
    assert!(e.contains("missing keyword TristimulusY"), "{e}");
}

/// Every number printed in shortest round-trip form reads back bit for bit.
#[test]
fn exact_round_trip_is_bit_identical() {
    let mut t = parse(SYM, &p()).unwrap();
    let mut x = 0.123456789012345f64;
    for c in &mut t.channels {
        for b in &mut c.blocks {
            b.tis = Some(x / 7.0);
            for v in &mut b.values {
                x = (x * 3.7 + 0.1).fract();
                *v = x * 10f64.powi((x * 20.0) as i32 - 10);
            }
        }
    }
    t.aoi_deg = vec![0.0, 1.0 / 3.0];
    let text = write(&t, "round trip\nsecond comment line", Precision::Exact);
    let back = parse(&text, &p()).unwrap();
    assert_eq!(back, t);
    for (a, b) in back.channels[0].blocks.iter().zip(&t.channels[0].blocks) {
        for (x, y) in a.values.iter().zip(&b.values) {
            assert_eq!(x.to_bits(), y.to_bits());
        }
    }
}

#[test]
fn plane_symmetric_curves() {
    let t = parse(SYM, &p()).unwrap();
    let m = t.to_measured(&p()).unwrap();
    assert_eq!(m.curves.len(), 2);
    assert!(!m.has_stderr);
    let c = &m.curves[1];
    assert_eq!(c.side, Side::R);
    assert!((c.incidence - 30f64.to_radians()).abs() < 1e-15);
    let deg: Vec<f64> = c.detector.iter().map(|x| (x.to_degrees() * 1e9).round() / 1e9).collect();
    // azimuth 0 (towards the normal): 30 − r; azimuth 180: 30 + r
    assert_eq!(deg, vec![20.0, 25.0, 29.0, 30.0, 31.0, 35.0, 40.0]);
    let f = [0.2, 2.0, 8.0, 20.0, 6.0, 3.0, 0.3];
    for ((v, d), f) in c.value.iter().zip(&deg).zip(f) {
        assert!((v - f * d.to_radians().cos()).abs() < 1e-12, "{d}: {v} vs {f}");
    }
}

fn err(text: &str) -> String {
    parse(text, &p()).unwrap_err().to_string()
}

/// Malformed files: the message names the file, the line and column, and the value.
#[test]
fn malformed_files_are_refused_with_position() {
    let cases: Vec<(String, &str)> = vec![
        (
            SYM.replace("10 5 1 0.1\n10 5 1 0.1\n10 5 1 0.1", "10 5 1 0.1\n10 5 x 0.1\n10 5 1 0.1"),
            "t.BSDF:19:6",
        ),
        (SYM.replace("20 6 3 0.3\n", "20 6 3\n"), "has 11 values, expected"),
        (SYM.replace("20 6 3 0.3\n", "20 6 3 0.3 7\n"), "more data than"),
        (SYM.replace("0  30", "30 0"), "strictly ascending, 0 after 30"),
        (SYM.replace("0  30", "0 90"), "AngleOfIncidence: 90 is outside [0, 90)"),
        (SYM.replace("0 90 180", "0 90 270"), "270 > 180 in a PlaneSymmetrical"),
        (
            SYM.replace("ScatterRadial  4", "ScatterRadial  four"),
            "count must be a non-negative integer, found \"four\"",
        ),
        (SYM.replace("PlaneSymmetrical", "Symmetric"), "Symmetry: unknown value \"Symmetric\""),
        (SYM.replace("ScatterType  BRDF", "ScatterType  BXDF"), "ScatterType: unknown value \"BXDF\""),
        (
            SYM.replace("Source  Measured\n", "Source  Measured\nWavelength 0.55\n"),
            "unknown keyword \"Wavelength\"",
        ),
        (SYM.replace("ScatterType  BRDF\n", ""), "missing keyword ScatterType"),
        (SYM.replace("DataEnd\n", ""), "unexpected end of file, expected DataEnd"),
        (
            SYM.replace("10 5 1 0.1\n10 5 1 0.1\n10 5 1 0.1", "10 5 1 0.1\n10 5 1 inf\n10 5 1 0.1"),
            "not finite",
        ),
        (SYM.replace("DataBegin", "Data"), "expected DataBegin after Monochrome, found \"Data\""),
    ];
    for (text, want) in cases {
        let e = err(&text);
        assert!(e.starts_with("t.BSDF:"), "{e}");
        assert!(e.contains(want), "wanted {want:?} in {e:?}");
    }
    // line and column of a bad value
    let e = err(&SYM.replace("20 7 2 0.2", "20 7 2 oops"));
    assert!(e.starts_with("t.BSDF:23:8:") && e.contains("\"oops\""), "{e}");
    // non-ASCII whitespace and text: columns count characters
    let e = err(&SYM.replace("20 7 2 0.2", "20\u{a0}7 2 é"));
    assert!(e.starts_with("t.BSDF:23:8:") && e.contains("\"é\""), "{e}");
    // data before the angle lists
    let e = err("Symmetry PlaneSymmetrical\nScatterType BRDF\nMonochrome\nDataBegin\n1\nDataEnd\n");
    assert!(e.contains("t.BSDF:3:1") && e.contains("before the angle lists"), "{e}");
}

#[test]
fn curves_need_rotation_zero_and_the_plane_of_incidence() {
    let t = parse(&SYM.replace("SampleRotation  1\n0", "SampleRotation  1\n45"), &p()).unwrap();
    let e = t.to_measured(&p()).unwrap_err().to_string();
    assert!(e.contains("no block for sample rotation 0°"), "{e}");
    let t = parse(&SYM.replace("0 90 180", "10 90 180"), &p()).unwrap();
    let e = t.to_measured(&p()).unwrap_err().to_string();
    assert!(e.contains("no azimuth 0° row"), "{e}");
}

/// A file with Latin-1 bytes in a comment (instrument software) reads.
#[test]
fn latin1_comment_reads() {
    let f = std::env::temp_dir().join(format!("opal_zemax_latin1_{}.bsdf", std::process::id()));
    let mut bytes = b"# angle in \xb0\n".to_vec();
    bytes.extend_from_slice(SYM.as_bytes());
    std::fs::write(&f, bytes).unwrap();
    assert!(is_zemax_path(&f));
    let t = read(&f);
    let _ = std::fs::remove_file(&f);
    assert_eq!(t.unwrap(), parse(SYM, &p()).unwrap());
}

/// Found by `fuzz/` (target zemax_bsdf): a huge list count was allocated before the list was
/// read (20 GB for 2 555 555 555 angles). Now refused at the count, naming it.
#[test]
fn huge_counts_are_refused_before_allocating() {
    let text =
        "# spe BRDF\nSampleRotation 1\n0\nAngleOfIncidence 2555555555 10 2\nDataBegin\n2 0.3 0.05\nDataEnd\n";
    let e = err(text);
    assert!(e.contains("t.BSDF:4:") && e.contains("2555555555") && e.contains("exceeds"), "{e}");
    let text = SYM.replace("ScatterRadial  4\n", "ScatterRadial  18446744073709551615\n");
    let e = err(&text);
    assert!(e.contains("18446744073709551615") && e.contains("exceeds"), "{e}");
}
