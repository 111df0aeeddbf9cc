//! The advice printed with a flagged calibration check of `opal fit-ndf` (absolute values,
//! `ndf_fit::ScaleCheck`): a global factor k ≠ 1 between measured and simulated values comes
//! from the calibration when the model's shape fits the data, from the model when it does not
//! (docs/fit-ndf.md, "Calibration check in absolute mode").
//!
//! Tests: `tests` below (both branches); `crates/opal-cli/tests/fit_ndf.rs`
//! (`calibration_warning_follows_the_evidence`: both warnings through the binary).

/// Largest rms/noise of the kept model at which a flagged calibration check points at the
/// calibration: the model's shape then fits within the acceptance bound, so the global factor
/// k ≠ 1 is the measurement's scale (the ×0.8 round trip: rms/noise 1.235, k 0.857). Above it
/// the shape misses the data and k moves with the wrong shape (forced hybrid on the dotted
/// plate: rms/noise 3.16, k 1.50), so `--scale global` would hide a model error.
pub const SCALE_ADVICE_MAX_RATIO: f64 = 1.5;

/// The warning of a flagged calibration check (measured ≈ `k` ± `stderr` × simulated) for a
/// kept model at `rms_over_noise`: suggests `--scale global` only when the shape fits within
/// [`SCALE_ADVICE_MAX_RATIO`] × the noise, else says that the model's shape does not match.
pub fn scale_advice(k: f64, stderr: f64, rms_over_noise: f64) -> String {
    let head = format!("measured ≈ {k:.4} ± {stderr:.4} × simulated");
    if rms_over_noise <= SCALE_ADVICE_MAX_RATIO {
        format!(
            "{head}, while the model fits the shape within noise (rms/noise {rms_over_noise:.2}): the absolute values' calibration does not match (try --scale global)"
        )
    } else {
        format!(
            "{head}, but the model's shape does not match the data either (rms/noise {rms_over_noise:.2} > {SCALE_ADVICE_MAX_RATIO}): the factor follows from the wrong shape, not necessarily from the calibration (try another --family, e.g. auto or dotted, before --scale global)"
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn advice_depends_on_the_shape_fit() {
        // the ×0.8 round trip (rms/noise 1.235) and forced hybrid on the dotted plate (3.16)
        let cal = scale_advice(0.857, 0.001, 1.235);
        assert!(cal.contains("--scale global") && cal.contains("calibration does not match"), "{cal}");
        assert!(!cal.contains("shape does not match"), "{cal}");
        let shape = scale_advice(1.5, 0.002, 3.16);
        assert!(shape.contains("shape does not match") && shape.contains("--family"), "{shape}");
        assert!(!shape.contains("calibration does not match"), "{shape}");
        // at the bound: still the calibration; NaN (no ratio): the shape is not known to fit
        assert!(scale_advice(0.9, 0.01, SCALE_ADVICE_MAX_RATIO).contains("calibration does not match"));
        assert!(scale_advice(0.9, 0.01, f64::NAN).contains("shape does not match"));
    }
}
