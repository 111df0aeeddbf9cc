//! Helpers shared by the de-lighting integration tests (`delight.rs`, `delight_room.rs`).

use opal_inverse::delight::views::View;
use opal_inverse::delight::{DelightResult, ObjectResult};

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

/// Worst relative channel error of object `o`'s mean observed albedo against the constant
/// `truth` (printed with the values and the seen fraction).
pub fn constant_albedo_error(o: &ObjectResult, truth: [f32; 3]) -> f64 {
    let m = o.mean_kd_observed();
    let rel: Vec<f64> = (0..3).map(|c| m[c] / truth[c] as f64 - 1.0).collect();
    println!(
        "{:18} kd {:.4} {:.4} {:.4}  truth {:.4} {:.4} {:.4}  rel {:+.2}% {:+.2}% {:+.2}%  seen {:.0}%",
        o.id,
        m[0],
        m[1],
        m[2],
        truth[0],
        truth[1],
        truth[2],
        100.0 * rel[0],
        100.0 * rel[1],
        100.0 * rel[2],
        100.0 * o.seen_fraction
    );
    rel.iter().fold(0.0, |a, b| a.max(b.abs()))
}
