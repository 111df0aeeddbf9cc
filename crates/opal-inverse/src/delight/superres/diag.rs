//! Error-analysis hook of the super-resolution ([`SrDiagnostics`], off by default): the
//! residual of the observation operator applied to a given radiance map (e.g. the true one)
//! against each photo, and synthetic photos made from it (see [`super`]'s module
//! documentation). Used by `bench/scripts/delight_psnr_budget.py`.

use super::operator::Row;
use super::settings::SrDiagnostics;
use crate::delight::atlas::Atlas;
use crate::delight::views::View;

/// Diagnostic ([`SrDiagnostics::truth`], [`SrDiagnostics::residual_dir`]): residual of the
/// observation operator applied to a given radiance map against the photo, per view, normalised
/// by the photo's standard error (`<view>_stderr.exr` next to the image, when present).
pub(super) fn diag_residual(
    v: &View,
    rows: &mut [Row],
    a: &Atlas,
    fine: &std::collections::HashMap<u32, &Row>,
    d: &SrDiagnostics,
) {
    let (Some(tp), Some(dir)) = (&d.truth, &d.residual_dir) else { return };
    let Ok(b) = opal::image::read::read_image(tp) else { return };
    if b.width != a.width || b.height != a.height {
        return;
    }
    let se_path = v.path.with_file_name(format!("{}_stderr.exr", v.name));
    let se = opal::image::read::read_image(&se_path).ok();
    let (w, h) = (v.camera.width, v.camera.height);
    let mut res = opal::image::Image::new(w, h);
    let mut nrm = opal::image::Image::new(w, h);
    let (mut chi, mut rel, mut n) = (0f64, 0f64, 0usize);
    let synth = d.synth.clone();
    let mut rng = opal::sampling::Rng::new(77, v.name.len() as u64, rows.len() as u64);
    // "shuffle": the real residuals normalised by the standard error, permuted over the pixels
    // (keeps their distribution, drops any spatial structure); "relshuffle": the same with the
    // residuals relative to the prediction
    let mut perm: Vec<[f32; 3]> = Vec::new();
    if matches!(synth.as_deref(), Some("shuffle") | Some("relshuffle")) {
        for r in rows.iter() {
            let mut pred = [0f32; 3];
            for &(c, wt) in &r.entries {
                for ch in 0..3 {
                    pred[ch] += wt * b.data[c as usize][ch];
                }
            }
            let den: [f32; 3] = match (synth.as_deref(), &se) {
                (Some("shuffle"), Some(se)) => se.data[r.pix as usize].0,
                _ => pred,
            };
            perm.push(std::array::from_fn(|ch| (r.y[ch] - pred[ch]) / den[ch].max(1e-9)));
        }
        for i in (1..perm.len()).rev() {
            let j = ((rng.next_f32() * (i + 1) as f32) as usize).min(i);
            perm.swap(i, j);
        }
    }
    for (ri, r) in rows.iter_mut().enumerate() {
        let mut pred = [0f32; 3];
        for &(c, wt) in &r.entries {
            let t = b.data[c as usize];
            for ch in 0..3 {
                pred[ch] += wt * t[ch];
            }
        }
        if let Some(sy) = &synth {
            if let Some(g) = fine.get(&r.pix) {
                pred = [0f32; 3];
                for &(c, wt) in &g.entries {
                    let t = b.data[c as usize];
                    for ch in 0..3 {
                        pred[ch] += wt * t[ch];
                    }
                }
            }
            // synthetic photo: the truth through the operator, plus Gaussian noise of the photo's
            // standard error ("stderr") or of a relative level
            let sd: [f32; 3] = match (sy.as_str(), &se) {
                ("stderr" | "stderrcorr", Some(se)) => se.data[r.pix as usize].0,
                (x, _) => {
                    let k: f32 = x.parse().unwrap_or(0.0);
                    pred.map(|p| k * p)
                }
            };
            if let (Some(k), Some(se)) = (sy.strip_prefix("clip").and_then(|k| k.parse::<f32>().ok()), &se) {
                // oracle: the real photo with its residual clipped at k standard errors
                let sd = se.data[r.pix as usize].0;
                for ch in 0..3 {
                    r.y[ch] = pred[ch] + (r.y[ch] - pred[ch]).clamp(-k * sd[ch], k * sd[ch]);
                }
            } else if !perm.is_empty() {
                let den: [f32; 3] = match (sy.as_str(), &se) {
                    ("shuffle", Some(se)) => se.data[r.pix as usize].0,
                    _ => pred,
                };
                for ch in 0..3 {
                    r.y[ch] = pred[ch] + den[ch] * perm[ri][ch];
                }
            } else {
                let mut gauss = || {
                    // Box–Muller
                    let (u1, u2) = (rng.next_f32().max(1e-7), rng.next_f32());
                    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f32::consts::PI * u2).cos()
                };
                // "stderrcorr": channels correlated (ρ = 0.7, as the real residuals)
                let g0 = gauss();
                let rho: f32 = if sy == "stderrcorr" { 0.7 } else { 0.0 };
                for ch in 0..3 {
                    let g = rho.sqrt() * g0 + (1.0 - rho).sqrt() * gauss();
                    r.y[ch] = pred[ch] + sd[ch] * g;
                }
            }
        }
        let d: [f32; 3] = std::array::from_fn(|ch| r.y[ch] - pred[ch]);
        res.data[r.pix as usize] = opal::spectrum::Spectrum(d);
        if let Some(se) = &se {
            let s = se.data[r.pix as usize];
            let z: [f32; 3] = std::array::from_fn(|ch| d[ch] / s[ch].max(1e-9));
            nrm.data[r.pix as usize] = opal::spectrum::Spectrum(z);
            for ch in 0..3 {
                chi += (z[ch] as f64).powi(2);
            }
        }
        for ch in 0..3 {
            rel += (d[ch] as f64 / pred[ch].max(1e-9) as f64).powi(2);
        }
        n += 3;
    }
    eprintln!(
        "diag {}: {} rows, chi2/n {:.3}, rms rel residual {:.4}",
        v.name,
        rows.len(),
        chi / n.max(1) as f64,
        (rel / n.max(1) as f64).sqrt()
    );
    for (what, img) in [("res", &res), ("z", &nrm)] {
        let p = dir.join(format!("{}_{what}.exr", v.name));
        if let Ok(f) = std::fs::File::create(p) {
            let _ = opal::image::write::write_exr(img, std::io::BufWriter::new(f));
        }
    }
}
