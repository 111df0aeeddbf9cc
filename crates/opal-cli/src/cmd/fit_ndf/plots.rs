//! The fit's curves as a CSV file and its plots: measured against fitted curves per incidence
//! and side (`curves.png`) and the residuals in units of the noise (`residuals.png`). Formats in
//! `docs/formats.md`; covered by the CLI tests `tests/fit_ndf.rs`.

use crate::plot::{LinePlot, Series, save_panels};
use crate::util::write_atomic;
use anyhow::Result;
use opal::gonio::Side;
use opal_inverse::ndf_fit::{Evaluation, Problem};
use std::io::Write;
use std::path::Path;

pub(super) fn write_curves_csv(path: &Path, p: &Problem, ev: &Evaluation) -> Result<()> {
    write_atomic(path, |f| {
        let mut w = std::io::BufWriter::new(f);
        let hemi = p.measured.hemisphere;
        write!(w, "incidence_deg,side,detector_deg,measured,measured_stderr,fitted,fitted_stderr")?;
        writeln!(w, "{}", if hemi { ",detector_azimuth_deg" } else { "" })?;
        for (ci, c) in p.measured.curves.iter().enumerate() {
            let r = &ev.result.incidences[p.incidence_index(ci)];
            for (k, &d) in p.detector_indices(ci).iter().enumerate() {
                write!(
                    w,
                    "{},{},{},{:.8e},{:.8e},{:.8e},{:.8e}",
                    (c.incidence.to_degrees() * 1e6).round() / 1e6,
                    c.side.label(),
                    (c.detector[k].to_degrees() * 1e6).round() / 1e6,
                    c.value[k],
                    c.stderr[k],
                    r.value[d],
                    r.value_stderr[d]
                )?;
                if hemi {
                    write!(w, ",{}", (c.azimuth[k].to_degrees() * 1e6).round() / 1e6)?;
                }
                writeln!(w)?;
            }
        }
        w.flush()?;
        Ok(())
    })
}

/// The points of curve `c` that the plots show, as (index, signed angle in degrees): all of a
/// plane-of-incidence curve; of a hemisphere measurement those in the plane of incidence
/// (azimuth 0 → +θ, 180° → −θ).
fn plot_points(p: &Problem, c: &opal_inverse::measured::Curve) -> Vec<(usize, f64)> {
    if !p.measured.hemisphere {
        return (0..c.detector.len()).map(|k| (k, c.detector[k].to_degrees())).collect();
    }
    let mut v: Vec<(usize, f64)> = (0..c.detector.len())
        .filter_map(|k| {
            let (t, a) = (c.detector[k].to_degrees(), c.azimuth[k].to_degrees());
            if t == 0.0 || a.abs() < 1e-6 {
                Some((k, t))
            } else if (a - 180.0).abs() < 1e-6 {
                Some((k, -t))
            } else {
                None
            }
        })
        .collect();
    v.sort_by(|a, b| a.1.total_cmp(&b.1));
    v
}

/// Relative standard error above which a simulated value is not drawn in the curve plots.
const RESOLVED: f64 = 0.3;

pub(super) fn write_plots(out: &Path, p: &Problem, ev: &Evaluation, title: &str) -> Result<()> {
    let incs = p.measured.incidences();
    let mut panels = Vec::new();
    let mut res_panels = Vec::new();
    for side in [Side::T, Side::R] {
        if !p.measured.has_side(side) {
            continue;
        }
        let mut series = Vec::new();
        let mut res_series = Vec::new();
        for (ci, c) in p.measured.curves.iter().enumerate().filter(|(_, c)| c.side == side) {
            let color = incs.iter().position(|&t| t == c.incidence).unwrap_or(0);
            let r = &ev.result.incidences[p.incidence_index(ci)];
            let ks = plot_points(p, c);
            let label = format!("{}°", (c.incidence.to_degrees() * 100.0).round() / 100.0);
            let meas: Vec<(f64, f64)> = ks.iter().map(|&(k, x)| (x, c.value[k])).collect();
            let idx = p.detector_indices(ci);
            // the fitted curve as a line only where the simulation resolves it (relative
            // standard error ≤ RESOLVED): elsewhere a few photons make a noisy floor that looks
            // like a misfit, so those values are marked with crosses instead (none at all where
            // the simulation recorded nothing)
            let resolved = |k: usize| {
                let (v, se) = (r.value[idx[k]], r.value_stderr[idx[k]]);
                v > 0.0 && se <= RESOLVED * v
            };
            let mut segments: Vec<Vec<(f64, f64)>> = Vec::new();
            let mut unresolved: Vec<(f64, f64)> = Vec::new();
            let mut prev_resolved = false;
            for &(k, x) in &ks {
                let ok = resolved(k);
                if ok {
                    match segments.last_mut() {
                        Some(sg) if prev_resolved => sg.push((x, r.value[idx[k]])),
                        _ => segments.push(vec![(x, r.value[idx[k]])]),
                    }
                } else if r.value[idx[k]] > 0.0 {
                    unresolved.push((x, r.value[idx[k]]));
                }
                prev_resolved = ok;
            }
            let floor = p.setup.floor_rel * c.max();
            let used = |k: usize| {
                let m = c.value[k];
                m > 0.0
                    && (m >= floor
                        || p.setup.min_snr.is_some_and(|z| c.stderr[k] > 0.0 && m >= z * c.stderr[k]))
            };
            let rel: Vec<(f64, f64)> = ks
                .iter()
                .filter(|&&(k, _)| used(k))
                .map(|&(k, x)| (x, (r.value[idx[k]] - c.value[k]) / c.value[k]))
                .collect();
            series.push(Series {
                name: format!("{label} measured"),
                points: meas,
                color,
                dashed: false,
                marks: false,
            });
            for (i, sg) in segments.into_iter().enumerate() {
                let name = if i == 0 { format!("{label} fitted") } else { String::new() };
                series.push(Series { name, points: sg, color, dashed: true, marks: false });
            }
            if !unresolved.is_empty() {
                // one legend entry per panel for the crosses (their colour says the incidence)
                let first = !series.iter().any(|s| s.marks);
                series.push(Series {
                    name: if first {
                        format!("fitted, σ > {:.0} %", 100.0 * RESOLVED)
                    } else {
                        String::new()
                    },
                    points: unresolved,
                    color,
                    dashed: false,
                    marks: true,
                });
            }
            res_series.push(Series { name: label, points: rel, color, dashed: false, marks: false });
        }
        panels.push(LinePlot {
            title: format!(
                "side {}: solid measured, dashed fitted (× where σ > {:.0} %)",
                side.label(),
                100.0 * RESOLVED
            ),
            x_label: "detector angle (deg)".into(),
            y_label: "I / P_in (1/sr)".into(),
            log_y: true,
            series,
            hline: None,
        });
        res_panels.push(LinePlot {
            title: format!("side {}: (fitted − measured)/measured, {title}", side.label()),
            x_label: "detector angle (deg)".into(),
            y_label: "relative residual".into(),
            log_y: false,
            series: res_series,
            hline: Some(0.0),
        });
    }
    save_panels(&out.join("curves.png"), &panels, (1400, 600))?;
    save_panels(&out.join("residuals.png"), &res_panels, (1400, 500))?;
    Ok(())
}
