//! The report's re-renders of `opal delight`: every view rendered with the recovered albedos,
//! previews and error maps written, and each object's region judged against the photo on its
//! pure, eroded pixels, with the re-render's own Monte-Carlo noise; the samples per view raised
//! until the noisiest judged region meets a target. Tests: `tests` below; the CLI tests
//! `tests/delight_inputs.rs` (`default_working_size_and_rerender_noise`, the region checks).

use super::contact::ContactAccumulator;
use super::{DelightArgs, exr, finite_or_null, html, png};
use anyhow::Result;
use opal::integrator::path::{PathSettings, render_split};
use opal::scene::Scene;
use opal::scene::desc::SceneDesc;
use opal_inverse::delight::views::View;
use opal_inverse::delight::{DelightResult, object_masks, recovered_desc, region_stats};
use serde_json::json;

/// `m` (a `w × h` pixel mask) without its border pixels: a pixel stays when its 8 neighbours are
/// in the mask too. A pure pixel may still have a sliver of a neighbouring surface within its
/// outer 5 % (the pure test's rays are at ±0.45 px), which matters next to an emitter (300×
/// brighter on the shared box) when the photos are box-filtered by a non-integer factor.
fn erode_mask(m: &[bool], w: usize, h: usize) -> Vec<bool> {
    let mut out = vec![false; m.len()];
    for y in 1..h.saturating_sub(1) {
        for x in 1..w.saturating_sub(1) {
            out[y * w + x] = (y - 1..=y + 1).all(|yy| (x - 1..=x + 1).all(|xx| m[yy * w + xx]));
        }
    }
    out
}

/// Regions smaller than this (pixels) are not judged in the report.
const MIN_REGION_PIXELS: usize = 64;

/// Largest relative Monte-Carlo standard error of the re-rendered mean luminance over the
/// judged regions (objects with ≥ [`MIN_REGION_PIXELS`] pixels) of view `v` (0 when none).
fn region_noise(v: &View, ro: &opal::integrator::path::RenderOutput, masks: &[Vec<bool>]) -> f64 {
    masks
        .iter()
        .filter(|m| m.iter().filter(|&&b| b).count() >= MIN_REGION_PIXELS)
        .map(|m| region_rel_stderr(v, ro, m))
        .filter(|x| x.is_finite())
        .fold(0.0, f64::max)
}

/// Relative standard error of the re-rendered mean luminance of the region `m` (channels
/// taken as fully correlated: an upper bound), relative to the photo's mean.
fn region_rel_stderr(v: &View, ro: &opal::integrator::path::RenderOutput, m: &[bool]) -> f64 {
    let p = region_stats(&v.image, m);
    let (mut var, mut n) = (0f64, 0usize);
    for (k, _) in m.iter().enumerate().filter(|&(_, &b)| b) {
        let s = opal_inverse::delight::luminance(ro.stderr.data[k].0) as f64;
        var += s * s;
        n += 1;
    }
    var.sqrt() / n.max(1) as f64 / p.mean_luminance.max(1e-12)
}

/// Samples per pixel that bring a relative noise of `noise` at `spp` samples down to `target`
/// (noise ∝ 1/√spp), at least `spp`, at most 16 × `spp`; `spp` when `target` is 0.
fn rerender_spp_for(spp: u32, noise: f64, target: f64) -> u32 {
    if target <= 0.0 || noise.is_nan() || noise <= target {
        return spp;
    }
    let want = (spp as f64 * (noise / target).powi(2)).ceil();
    want.min(16.0 * spp as f64) as u32
}

/// `a` (a render of `na` samples per pixel) replaced by the mean of it and `b` (`nb` samples,
/// independent seeds), with the standard errors combined.
fn combine_renders(
    a: &mut opal::integrator::path::RenderOutput,
    na: u32,
    b: &opal::integrator::path::RenderOutput,
    nb: u32,
) {
    let (wa, wb) = (na as f32 / (na + nb) as f32, nb as f32 / (na + nb) as f32);
    for k in 0..a.image.data.len() {
        let (pa, pb) = (a.image.data[k].0, b.image.data[k].0);
        let (sa, sb) = (a.stderr.data[k].0, b.stderr.data[k].0);
        let m: [f32; 3] = std::array::from_fn(|c| wa * pa[c] + wb * pb[c]);
        let s: [f32; 3] = std::array::from_fn(|c| ((wa * sa[c]).powi(2) + (wb * sb[c]).powi(2)).sqrt());
        a.image.data[k] = opal::spectrum::Spectrum::rgb(m[0], m[1], m[2]);
        a.stderr.data[k] = opal::spectrum::Spectrum::rgb(s[0], s[1], s[2]);
    }
    a.nonfinite += b.nonfinite;
    a.samples += b.samples;
}

/// What the re-renders found: one entry per judged region and per view, the largest region
/// error, and the contact-edge statistics.
pub(super) struct Judged {
    /// Per view and object with ≥ [`MIN_REGION_PIXELS`] judged pixels (report.json `regions`).
    pub regions: Vec<serde_json::Value>,
    /// Largest |relative luminance error| over the regions.
    pub max_region_err: f64,
    /// Per view: previews, error map, samples (report.json `rerenders`).
    pub rerenders: Vec<serde_json::Value>,
    /// Errors in a band along contact edges.
    pub contact: ContactAccumulator,
}

/// Re-renders every view with the recovered albedos (`--rerender-spp` samples, raised per view
/// to the `--rerender-noise` target), writes the previews and error maps, and judges each
/// object's region of each view against the photo. Nothing when `--rerender-spp` is 0.
pub(super) fn rerender_and_judge(
    a: &DelightArgs,
    desc: &SceneDesc,
    views: &[View],
    r: &DelightResult,
) -> Result<Judged> {
    let out = &a.output;
    let mut regions = Vec::new();
    let mut max_region_err = 0f64;
    let mut rerenders = Vec::new();
    let mut contact = ContactAccumulator::default();
    if a.rerender_spp == 0 {
        return Ok(Judged { regions, max_region_err, rerenders, contact });
    }
    let rdesc = recovered_desc(desc, &r.objects);
    let mut rscene = Scene::build(&rdesc)?;
    let scene = Scene::build(desc)?;
    rscene.cameras = views.iter().map(|v| v.camera.clone()).collect();
    let integ = desc.integrator.clone().unwrap_or_default();
    let ps = PathSettings {
        spp: a.rerender_spp,
        max_depth: integ.max_depth,
        rr_depth: integ.rr_depth,
        hide_emitters: integ.hide_emitters,
        seed: a.seed ^ 0xDE11,
    };
    let shapes: Vec<usize> = r.objects.iter().map(|o| o.shape).collect();
    // under MPI the rows of each re-render are split across the ranks (the same image)
    let comm = crate::dist::comm_or_solo();
    // rows of this rank's share of every view's first render (the extra samples add theirs)
    let share = |h: usize| h.div_ceil(comm.size()) as u64;
    let pb = crate::util::progress(views.iter().map(|v| share(v.image.height)).sum(), "re-renders");
    let row = || pb.inc(1);
    for (vi, v) in views.iter().enumerate() {
        let (w, h) = (v.image.width, v.image.height);
        let masks: Vec<Vec<bool>> =
            object_masks(&scene, v, &shapes).iter().map(|m| erode_mask(m, w, h)).collect();
        let mut ro = render_split(&rscene, vi, &ps, &row, None, &*comm)?;
        // more samples where the noisiest judged region is above the target
        let (pilot_noise, spp) = (region_noise(v, &ro, &masks), a.rerender_spp);
        let want = rerender_spp_for(spp, pilot_noise, a.rerender_noise);
        if want > spp {
            let more = PathSettings { spp: want - spp, seed: ps.seed ^ 0x5EED_0001, ..ps };
            pb.inc_length(share(h));
            let r2 = render_split(&rscene, vi, &more, &row, None, &*comm)?;
            combine_renders(&mut ro, spp, &r2, want - spp);
        }
        // previews of the photo and the re-render at one exposure, and their error map
        let exposure = html::preview_exposure(&v.image);
        exr(&out.join(format!("rerender/{}.exr", v.name)), &ro.image)?;
        png(&out.join(format!("rerender/{}.png", v.name)), &ro.image, exposure)?;
        let mut photo = v.image.clone();
        photo.data.iter_mut().filter(|p| !p.is_finite()).for_each(|p| *p = opal::spectrum::Spectrum::ZERO);
        png(&out.join(format!("photo/{}.png", v.name)), &photo, exposure)?;
        let (err, mean_err) = html::view_error(&v.image, &ro.image);
        let err_png = format!("errors/view_{}.png", v.name);
        html::write_signed_error_png(&out.join(&err_png), &err, v.image.width, v.image.height)?;
        rerenders.push(json!({
            "view": v.name, "photo": format!("photo/{}.png", v.name),
            "rerender": format!("rerender/{}.png", v.name), "exposure": exposure,
            "error_map": err_png, "rel_bias_luminance": mean_err, "size": [v.image.width, v.image.height],
            "spp": want.max(spp), "max_region_rel_stderr_at_first_spp": finite_or_null(pilot_noise),
            "max_region_rel_stderr": finite_or_null(region_noise(v, &ro, &masks)),
        }));
        contact.add(&scene, v, &ro, &shapes);
        for (o, m) in r.objects.iter().zip(masks) {
            let n = m.iter().filter(|&&b| b).count();
            if n < MIN_REGION_PIXELS {
                continue;
            }
            let p = region_stats(&v.image, &m);
            let q = region_stats(&ro.image, &m);
            let rel_y = q.mean_luminance / p.mean_luminance - 1.0;
            let rel_rgb: Vec<f64> = (0..3).map(|c| q.mean_rgb[c] / p.mean_rgb[c].max(1e-12) - 1.0).collect();
            // Monte-Carlo standard error of the re-render's region mean luminance
            let rel_se = region_rel_stderr(v, &ro, &m);
            max_region_err = max_region_err.max(rel_y.abs());
            regions.push(json!({
                "view": v.name, "object": o.id, "pixels": n,
                "photo": p, "rerender": q,
                "rel_error_luminance": rel_y, "rel_error_rgb": rel_rgb,
                "rerender_rel_stderr_luminance": rel_se,
            }));
        }
    }
    pb.finish_and_clear();
    Ok(Judged { regions, max_region_err, rerenders, contact })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Border pixels leave the mask; a 4 × 3 block keeps its 2 × 1 interior.
    #[test]
    fn erode_keeps_the_interior() {
        let (w, h) = (6, 5);
        let mut m = vec![false; w * h];
        for y in 1..4 {
            for x in 1..5 {
                m[y * w + x] = true;
            }
        }
        let e = erode_mask(&m, w, h);
        let kept: Vec<usize> = (0..w * h).filter(|&k| e[k]).collect();
        assert_eq!(kept, vec![2 * w + 2, 2 * w + 3]);
    }

    /// Samples follow (noise/target)², at least the first count, at most 16× it; 0 = off.
    #[test]
    fn rerender_samples_follow_the_noise_target() {
        assert_eq!(rerender_spp_for(64, 0.008, 0.004), 256);
        assert_eq!(rerender_spp_for(64, 0.002, 0.004), 64);
        assert_eq!(rerender_spp_for(64, 0.1, 0.004), 1024);
        assert_eq!(rerender_spp_for(64, 0.1, 0.0), 64);
        assert_eq!(rerender_spp_for(64, f64::NAN, 0.004), 64);
    }
}
