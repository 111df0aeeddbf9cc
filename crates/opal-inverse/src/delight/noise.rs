//! Light paths per light-tracing pass from the texel count and a target noise
//! ([`paths_for_noise`]), and the achieved per-texel noise of a pass ([`texel_noise`]).
//!
//! * **Rule**: a texel's raw indirect-irradiance estimate gathers about `paths / texels`
//!   deposits' worth of paths, so its relative standard error is `σ ≈ sqrt(K · texels / paths)`:
//!   `paths = K · texels / σ²`, rounded to a multiple of 10 000 and clamped to
//!   [`MIN_PATHS`]…[`MAX_PATHS`]. `K`
//!   ([`PATHS_PER_TEXEL_AT_UNIT_NOISE`]) depends on how many deposits a path leaves on the
//!   recovered objects (a closed room more than an open scene); it is calibrated on the shared
//!   Cornell box (8 views of 256², its atlases from the cameras: 710 139 texels), where 20 M
//!   paths (the earlier fixed count) gave a per-texel noise of [`DEFAULT_TARGET_NOISE`] in the
//!   last pass — so the default target gives 20 M paths there. Other scenes may reach another noise at the
//!   same count: the achieved value is measured and reported, and a warning is given when it is
//!   more than twice the target.
//! * **Achieved noise** ([`texel_noise`]): the relative residual of each reached texel's raw
//!   indirect irradiance (luminance) against the in-chart smoothed map (the indirect light is
//!   low-frequency at that scale), over texels whose smoothed value is positive; the robust
//!   standard deviation `1.4826 · median |residual|`, corrected by `1/sqrt(1 − 1/W)` for the
//!   texel's own share of the `W`-texel smoothing window. The smoothed map the method uses has
//!   about `σ / sqrt(W)`.
//!
//! Tests: `rule_scales_with_texels_and_noise`, `noise_estimate_recovers_known_sigma` here.

/// Paths per texel that give a relative per-texel noise of 1 (calibration of the rule, module
/// documentation): 20 M paths per pass on the shared box's 710 139 texels gave 0.153 in the
/// last of 5 passes (14.5 % in the first, with the initial albedos; 2026-11-26).
pub const PATHS_PER_TEXEL_AT_UNIT_NOISE: f64 = 20.0e6 / 710_139.0 * 0.153 * 0.153;
/// Default target relative per-texel noise of the raw indirect irradiance.
pub const DEFAULT_TARGET_NOISE: f64 = 0.153;
/// Fewest paths per pass of the rule.
pub const MIN_PATHS: u64 = 100_000;
/// Most paths per pass of the rule.
pub const MAX_PATHS: u64 = 500_000_000;

/// Light paths per pass for `texels` texels (all recovered objects) at the relative per-texel
/// noise `target` (module documentation).
pub fn paths_for_noise(texels: usize, target: f64) -> u64 {
    let p = PATHS_PER_TEXEL_AT_UNIT_NOISE * texels as f64 / (target * target);
    if p.is_finite() { ((p / 1e4).round() as u64 * 10_000).clamp(MIN_PATHS, MAX_PATHS) } else { MAX_PATHS }
}

/// Relative residuals `(raw − smooth) / smooth` (luminance) of the texels of `mask` whose
/// smoothed value is positive.
pub fn texel_residuals(raw: &[[f32; 3]], smooth: &[[f32; 3]], mask: &[bool]) -> Vec<f64> {
    raw.iter()
        .zip(smooth)
        .zip(mask)
        .filter_map(|((r, s), &m)| {
            let ys = super::luminance(*s) as f64;
            (m && ys > 0.0).then(|| (super::luminance(*r) as f64 - ys) / ys)
        })
        .collect()
}

/// Robust relative per-texel noise from the residuals of [`texel_residuals`] against a
/// `window`-texel smoothing: `1.4826 · median |residual| / sqrt(1 − 1/window)`; NaN when empty.
pub fn texel_noise(residuals: &[f64], window: usize) -> f64 {
    if residuals.is_empty() {
        return f64::NAN;
    }
    let mut a: Vec<f64> = residuals.iter().map(|r| r.abs()).collect();
    let mid = a.len() / 2;
    let (_, m, _) = a.select_nth_unstable_by(mid, f64::total_cmp);
    let m = *m;
    let w = window.max(2) as f64;
    1.4826 * m / (1.0 - 1.0 / w).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The default target on the shared box's texel count gives about 20 M paths; paths scale
    /// with the texels and with 1/σ²; the clamps hold.
    #[test]
    fn rule_scales_with_texels_and_noise() {
        let p = paths_for_noise(710_139, DEFAULT_TARGET_NOISE);
        assert_eq!(p, 20_000_000);
        assert_eq!(paths_for_noise(2 * 710_139, DEFAULT_TARGET_NOISE), 40_000_000);
        assert_eq!(paths_for_noise(710_139, DEFAULT_TARGET_NOISE / 2.0), 80_000_000);
        // about 1/4 of the texels (views of 128²): about 5 M
        assert_eq!(paths_for_noise(710_139 / 4, DEFAULT_TARGET_NOISE), 5_000_000);
        assert_eq!(paths_for_noise(10, 0.5), MIN_PATHS);
        assert_eq!(paths_for_noise(100_000_000, 0.01), MAX_PATHS);
    }

    /// A constant map with Gaussian noise of σ = 0.2 (per texel, relative) smoothed by its
    /// exact mean: the estimate is within 3 % of σ.
    #[test]
    fn noise_estimate_recovers_known_sigma() {
        let mut rng = opal::sampling::Rng::new(7, 0, 0);
        let n = 40_000;
        let gauss = |rng: &mut opal::sampling::Rng| {
            let (u, v) = (rng.next_f32().max(1e-7) as f64, rng.next_f32() as f64);
            (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
        };
        let raw: Vec<[f32; 3]> = (0..n).map(|_| [(1.0 + 0.2 * gauss(&mut rng)) as f32; 3]).collect();
        let smooth = vec![[1.0f32; 3]; n];
        let res = texel_residuals(&raw, &smooth, &vec![true; n]);
        let s = texel_noise(&res, 1_000_000);
        assert!((s / 0.2 - 1.0).abs() < 0.03, "{s}");
        assert!(texel_noise(&[], 9).is_nan());
    }
}
