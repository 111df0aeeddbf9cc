//! The single-scattering rough plate against the Mitsuba 3 reference goniophotometer data
//! (`tests/data/gonio/`, copied from `<shared>/reference/mitsuba/gonio`, 16 M photons per
//! incidence): every case (GGX α = 0.15, 0.35, Beckmann α = 0.25; smooth and rough entry;
//! incidences 0–75°).
//!
//! * Detectors: z = (ours − ref) / σ over the detectors whose reference value exceeds
//!   1e-3 sr⁻¹ and where our run expects ≥ 20 photons (below that the counts are Poisson, not
//!   Gaussian, and a z-test is meaningless); σ² = σ_ref²·(1 + N_ref/N_ours) is the variance of
//!   the difference under the null hypothesis (same per-photon variance in both simulations,
//!   estimated from the 16 M-photon reference, which stays defined when our detector saw no
//!   photon); ≥ 99 % of the detectors must have |z| ≤ 3 (99.7 % for Gaussian noise; the margin
//!   covers the residual non-normality of counts of a few dozen photons).
//! * Totals R, T and lost: |z| ≤ 4 with σ² = p(1−p)(1/N_ours + 1/N_ref), an upper bound of
//!   the variance of a mean of weights in [0, 1].
//!
//! Default tier: 400 000 photons per incidence (~10 s on 2 cores; compares the detectors
//! around the peaks). The heavy tier `cargo test -p opal --release --test gonio_reference --
//! --ignored` uses 16 M photons per incidence like the reference (all detectors > 1e-3).

use opal::bsdf::microfacet::Ndfs;
use opal::gonio::{Beam, DetectorGrid, DetectorLayout, Face, Gonio, GonioSetup, Plate, Scattering, Side};
use std::collections::HashMap;
use std::path::PathBuf;

fn data_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/gonio")
}

struct RefRow {
    value: f64,
    stderr: f64,
    hits: f64,
}

fn read_csv(name: &str) -> HashMap<(i32, char, i32), RefRow> {
    let text = std::fs::read_to_string(data_dir().join(name)).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |n: &str| header.iter().position(|h| *h == n).unwrap();
    let (ci, cs, cd, cv, ce) =
        (col("incidence_deg"), col("side"), col("detector_deg"), col("value"), col("value_stderr"));
    let ch = col("n_hits");
    let mut m = HashMap::new();
    for l in lines {
        let f: Vec<&str> = l.split(',').collect();
        let key = (
            f[ci].parse::<f64>().unwrap().round() as i32,
            f[cs].chars().next().unwrap(),
            f[cd].parse::<f64>().unwrap().round() as i32,
        );
        m.insert(
            key,
            RefRow {
                value: f[cv].parse().unwrap(),
                stderr: f[ce].parse().unwrap(),
                hits: f[ch].parse().unwrap(),
            },
        );
    }
    m
}

fn run_case(photons: u64) {
    let stats: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data_dir().join("stats.json")).unwrap()).unwrap();
    let incid = [0.0, 15.0, 30.0, 45.0, 60.0, 75.0];
    let setup = GonioSetup {
        beam: Beam { azimuth: 0.0, divergence: 0.5f64.to_radians(), aperture_radius_mm: 0.0 },
        incidences: incid.iter().map(|d: &f64| d.to_radians()).collect(),
        detectors: DetectorLayout {
            grid: DetectorGrid::PlaneOfIncidence {
                angles: (-89..=89).map(|d| (d as f64).to_radians()).collect(),
            },
            radius: 1f64.to_radians(),
            distance_mm: None,
        },
        photons,
        seed: 2024,
        max_interactions: 200,
    };
    let gonio = Gonio::new(setup).unwrap();
    let mut summary = Vec::new();
    let (mut total_n, mut total_bad) = (0usize, 0usize);
    for (case, ndf) in [
        ("ggx_a0.15", Ndfs::ggx(0.15)),
        ("ggx_a0.35", Ndfs::ggx(0.35)),
        ("beckmann_a0.25", Ndfs::beckmann(0.25)),
    ] {
        for entry in ["smooth", "rough"] {
            // Mitsuba's G1 (Beckmann: Walter's rational approximation; GGX: exact = `Single`)
            let rough = Face::Rough { ndf: ndf.clone(), scattering: Scattering::SingleMitsuba };
            let (front, back) =
                if entry == "rough" { (rough, Face::Polished) } else { (Face::Polished, rough) };
            let plate =
                Plate { ior: 1.49, thickness_mm: 2.0, absorption_per_mm: 0.0, front, back, radius_mm: None };
            let res = gonio.run_plate(&plate).unwrap();
            let reference = read_csv(&format!("{case}_{entry}.csv"));
            let dets = gonio.detectors().list();
            let (mut n, mut bad, mut worst) = (0usize, 0usize, 0.0f64);
            for (ii, r) in res.incidences.iter().enumerate() {
                assert_eq!(r.bad_photons, 0);
                for (k, d) in dets.iter().enumerate() {
                    let side = if d.side == Side::R { 'R' } else { 'T' };
                    let rr = &reference[&(incid[ii] as i32, side, d.angle_deg.round() as i32)];
                    let n_ref = 16e6;
                    if rr.value <= 1e-3 || rr.hits * photons as f64 / n_ref < 20.0 {
                        continue;
                    }
                    let s = rr.stderr * (1.0 + n_ref / photons as f64).sqrt();
                    let z = (r.value[k] - rr.value) / s;
                    n += 1;
                    worst = worst.max(z.abs());
                    if z.abs() > 3.0 {
                        bad += 1;
                    }
                }
                let st = &stats["runs"][format!("{case}_{entry}_inc{}", incid[ii])];
                let n_ref = st["n_photons"].as_f64().unwrap();
                for (name, ours, theirs) in [
                    ("R", r.r, st["R_total"].as_f64().unwrap()),
                    ("T", r.t, st["T_total"].as_f64().unwrap()),
                    (
                        "lost",
                        r.lost,
                        st["lost_microfacet"].as_f64().unwrap() + st["lost_maxdepth"].as_f64().unwrap(),
                    ),
                ] {
                    let p = theirs.clamp(1e-6, 1.0 - 1e-6);
                    let s = (p * (1.0 - p) * (1.0 / photons as f64 + 1.0 / n_ref)).sqrt();
                    let z = (ours - theirs) / s;
                    assert!(
                        z.abs() <= 4.0,
                        "{case} {entry} θ={}: {name} = {ours:.5} vs reference {theirs:.5} (z = {z:.2})",
                        incid[ii]
                    );
                }
            }
            summary.push(format!("{case} {entry}: {bad}/{n} detectors with |z| > 3, max |z| {worst:.2}"));
            total_n += n;
            total_bad += bad;
            assert!(n > 30, "{case} {entry}: only {n} detectors compared");
            assert!(
                bad as f64 <= 0.01 * n as f64,
                "{case} {entry}: {bad}/{n} detectors with |z| > 3\n{}",
                summary.join("\n")
            );
        }
    }
    eprintln!("{}\nall: {total_bad}/{total_n}", summary.join("\n"));
}

#[test]
fn single_scattering_plate_matches_mitsuba_reference() {
    run_case(400_000);
}

/// Heavy tier: `cargo test -p opal --release --test gonio_reference -- --ignored`.
#[test]
#[ignore]
fn single_scattering_plate_matches_mitsuba_reference_16m() {
    run_case(16_000_000);
}
