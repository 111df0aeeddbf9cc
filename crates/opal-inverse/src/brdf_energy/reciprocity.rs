//! Reciprocity check of a BRDF: largest relative asymmetry `|f(a,b) − f(b,a)|` over fixed pairs.
//!
//! Tests: `tests.rs` (normalised physical models are reciprocal).

use super::scalar;
use opal::bsdf::{Bxdf, TransportMode};
use opal::sampling::Rng;

/// Largest relative asymmetry `|f(a,b) − f(b,a)| / max(f(a,b), f(b,a))` over 4000 fixed pairs:
/// half uniform on the hemisphere, half with `b` drawn from the model's sampling at `a` (so
/// narrow lobes are probed inside the lobe). Pairs where both values are below 1e-6 of the
/// largest value seen are skipped (their relative error is rounding noise).
pub fn reciprocity_error(b: &(impl Bxdf + Sync)) -> f64 {
    let mut rng = Rng::new(77, 0x2EC1, 0);
    let mut pairs = Vec::with_capacity(4000);
    for i in 0..4000 {
        let a = opal::sampling::square_to_uniform_hemisphere(rng.next_2d());
        let c = if i % 2 == 0 {
            opal::sampling::square_to_uniform_hemisphere(rng.next_2d())
        } else {
            match b.sample(a, rng.next_f32(), rng.next_2d(), TransportMode::Radiance) {
                Some(s) => s.wi,
                None => continue,
            }
        };
        pairs.push((a, c));
    }
    let vals: Vec<(f64, f64)> = pairs
        .iter()
        .map(|(a, c)| {
            (scalar(b.eval(*a, *c, TransportMode::Radiance)), scalar(b.eval(*c, *a, TransportMode::Radiance)))
        })
        .collect();
    let fmax = vals.iter().map(|(x, y)| x.max(*y)).fold(0.0, f64::max);
    vals.iter()
        .filter(|(x, y)| x.max(*y) > 1e-6 * fmax)
        .map(|(x, y)| (x - y).abs() / x.max(*y))
        .fold(0.0, f64::max)
}
