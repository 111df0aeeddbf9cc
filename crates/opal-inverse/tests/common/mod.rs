//! Helpers shared by the de-lighting integration tests (`delight.rs`, `delight_room.rs`).

use opal_inverse::delight::DelightResult;
use opal_inverse::delight::views::View;

/// Multiplies each view's image by its per-channel gains (what a camera with those gains would
/// record).
pub fn apply_gains<G: Copy + Into<f64>>(views: &mut [View], gains: &[[G; 3]]) {
    assert_eq!(views.len(), gains.len());
    for (v, g) in views.iter_mut().zip(gains) {
        for p in &mut v.image.data {
            for (x, f) in p.0.iter_mut().zip(g) {
                *x *= (*f).into() as f32;
            }
        }
    }
}

/// Worst relative error of the estimated gains against the known ones (printed per view with
/// the estimate's σ).
pub fn gain_error<G: Copy + Into<f64>>(r: &DelightResult, truth: &[[G; 3]]) -> f64 {
    let g = r.view_gains.as_ref().expect("gains estimated");
    let mut worst = 0f64;
    for (vg, t) in g.views.iter().zip(truth) {
        let t: [f64; 3] = t.map(Into::into);
        let e: [f64; 3] = std::array::from_fn(|c| vg.gain[c] / t[c] - 1.0);
        let rel_se: [f64; 3] = std::array::from_fn(|c| 100.0 * vg.std_err[c] / vg.gain[c]);
        println!(
            "gain {:10} est {:.4} {:.4} {:.4}  true {:.4} {:.4} {:.4}  err {:+.3}% {:+.3}% {:+.3}%  σ {:.3}% {:.3}% {:.3}%",
            vg.view,
            vg.gain[0],
            vg.gain[1],
            vg.gain[2],
            t[0],
            t[1],
            t[2],
            100.0 * e[0],
            100.0 * e[1],
            100.0 * e[2],
            rel_se[0],
            rel_se[1],
            rel_se[2],
        );
        worst = e.iter().fold(worst, |a, b| a.max(b.abs()));
    }
    println!("worst gain error {:.3} %", 100.0 * worst);
    worst
}
