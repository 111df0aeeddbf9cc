//! The advice printed with a flagged calibration check of `opal fit-ndf` (absolute values,
//! `ndf_fit::ScaleCheck`): a global factor k ≠ 1 between measured and simulated values comes
//! from the calibration when the kept model times k fits the data (its `scaled_ratio`, the
//! rms/noise with the free factor, within `SCALED_FIT_MAX_RATIO`), from the model's shape when
//! it does not (docs/fit-ndf.md, "Calibration check in absolute mode").
//!
//! Tests: `tests` below (both branches); `crates/opal-cli/tests/fit_ndf.rs`
//! (`calibration_warning_follows_the_evidence`: both warnings through the binary).

use opal_inverse::ndf_fit::SCALED_FIT_MAX_RATIO;

/// The warning of a flagged calibration check (measured ≈ `k` ± `stderr` × simulated) whose
/// fit with the free factor k has rms/noise `scaled_ratio`: suggests `--scale global` only
/// when that fit is good (≤ [`SCALED_FIT_MAX_RATIO`]), else says that the model's shape does
/// not match (k then follows the wrong shape and `--scale global` would hide a model error).
pub(super) fn scale_advice(k: f64, stderr: f64, scaled_ratio: f64) -> String {
    let head = format!("measured ≈ {k:.4} ± {stderr:.4} × simulated");
    if scaled_ratio <= SCALED_FIT_MAX_RATIO {
        format!(
            "{head}, and the model times that factor fits within noise (rms/noise {scaled_ratio:.2}): the absolute values' calibration does not match (try --scale global)"
        )
    } else {
        format!(
            "{head}, but the model's shape does not match the data even with that factor (rms/noise {scaled_ratio:.2} > {SCALED_FIT_MAX_RATIO}): the factor follows from a wrong model, not necessarily the calibration (try another --family, e.g. auto or dotted, before --scale global)"
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn advice_depends_on_the_fit_with_the_free_factor() {
        let cal = scale_advice(0.934, 0.011, 1.0);
        assert!(cal.contains("--scale global") && cal.contains("calibration does not match"), "{cal}");
        assert!(!cal.contains("shape does not match"), "{cal}");
        let shape = scale_advice(12.7, 0.02, 40.0);
        assert!(shape.contains("shape does not match") && shape.contains("--family"), "{shape}");
        assert!(!shape.contains("calibration does not match"), "{shape}");
        // at the bound: still the calibration; NaN (no ratio): the shape is not known to fit
        assert!(scale_advice(0.9, 0.01, SCALED_FIT_MAX_RATIO).contains("calibration does not match"));
        assert!(scale_advice(0.9, 0.01, f64::NAN).contains("shape does not match"));
    }
}
