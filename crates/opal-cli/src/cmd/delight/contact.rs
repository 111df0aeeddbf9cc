//! The `contact_edges` key of `opal delight`'s report.json (issue 17, item 4): per view the PSNR
//! of the re-render against the photo in the band along contact edges (where two surfaces touch,
//! see `opal_inverse::delight::contact`) and over the other pixels of the recovered objects, and
//! the re-render's own Monte-Carlo noise floor in the band. A seam of errors along contact edges
//! shows as a band PSNR well below the one elsewhere. Peak: per view the 99th percentile of the
//! photo's channel values over the recovered objects' pixels (so the PSNR is comparable across
//! exposures); the pooled values sum the squared errors divided by each view's peak². Tested by
//! the CLI's report key-set test (`crates/opal-cli/tests/delight.rs`).

use opal::integrator::path::RenderOutput;
use opal::scene::Scene;
use opal_inverse::delight::contact::{CONTACT_BAND_RADIUS, CONTACT_GAP_PIXELS, contact_map, psnr_db};
use opal_inverse::delight::views::View;
use serde_json::json;

/// Squared errors (over the peak²) and pixel counts, summed over pixels.
#[derive(Default, Clone, Copy)]
struct Sums {
    band: f64,
    n_band: usize,
    elsewhere: f64,
    n_elsewhere: usize,
    noise: f64,
}

/// Collects the per-view contact-band statistics of the re-renders.
#[derive(Default)]
pub(super) struct ContactAccumulator {
    views: Vec<serde_json::Value>,
    total: Sums,
}

fn db(se: f64, n: usize) -> serde_json::Value {
    let p = psnr_db(se, n, 1.0);
    if p.is_finite() { json!(p) } else { json!(null) }
}

impl ContactAccumulator {
    /// Adds view `v` with its re-render `ro`; `shapes` are the recovered objects' shape indices.
    pub(super) fn add(&mut self, scene: &Scene, v: &View, ro: &RenderOutput, shapes: &[usize]) {
        let map = contact_map(scene, &v.camera, CONTACT_BAND_RADIUS);
        let on_object: Vec<bool> =
            map.shape.iter().map(|s| s.is_some_and(|s| shapes.contains(&(s as usize)))).collect();
        let mut vals: Vec<f32> = v
            .image
            .data
            .iter()
            .zip(&on_object)
            .filter(|&(p, &m)| m && p.is_finite())
            .flat_map(|(p, _)| [p[0], p[1], p[2]])
            .collect();
        if vals.is_empty() {
            return;
        }
        let k = ((vals.len() - 1) as f64 * 0.99) as usize;
        let peak = *vals.select_nth_unstable_by(k, f32::total_cmp).1 as f64;
        if peak <= 0.0 {
            return;
        }
        let mut s = Sums::default();
        for (i, (p, q)) in v.image.data.iter().zip(&ro.image.data).enumerate() {
            if !on_object[i] || !p.is_finite() || !q.is_finite() {
                continue;
            }
            let e: f64 = (0..3).map(|c| ((q[c] - p[c]) as f64 / peak).powi(2)).sum();
            if map.band[i] {
                s.band += e;
                s.n_band += 1;
                s.noise += (0..3).map(|c| (ro.stderr.data[i][c] as f64 / peak).powi(2)).sum::<f64>();
            } else {
                s.elsewhere += e;
                s.n_elsewhere += 1;
            }
        }
        self.views.push(json!({
            "view": v.name, "peak": peak, "pixels": s.n_band, "psnr_db": db(s.band, s.n_band),
            "pixels_elsewhere": s.n_elsewhere, "psnr_db_elsewhere": db(s.elsewhere, s.n_elsewhere),
            "rerender_noise_psnr_db": db(s.noise, s.n_band),
        }));
        let t = &mut self.total;
        t.band += s.band;
        t.n_band += s.n_band;
        t.elsewhere += s.elsewhere;
        t.n_elsewhere += s.n_elsewhere;
        t.noise += s.noise;
    }

    /// The report.json value.
    pub(super) fn json(&self) -> serde_json::Value {
        let t = self.total;
        json!({
            "radius_px": CONTACT_BAND_RADIUS, "gap_pixels": CONTACT_GAP_PIXELS,
            "pixels": t.n_band, "psnr_db": db(t.band, t.n_band),
            "pixels_elsewhere": t.n_elsewhere, "psnr_db_elsewhere": db(t.elsewhere, t.n_elsewhere),
            "rerender_noise_psnr_db": db(t.noise, t.n_band),
            "views": self.views,
        })
    }
}
