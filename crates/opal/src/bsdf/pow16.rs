//! The pow16 approximant of method B (the paper's proposed lobe):
//! `L(t) = max(0, n/16 · (t − 1) + 1)^16`, `t = cos θ` with θ = γ (Phong form, `V·R`) or
//! θ = θ_h (Blinn form, `N·H`), clamped to zero beyond its first zero `t = 1 − 16/n` (the 16th
//! power of a negative base is not part of the lobe). `f = k_s · c(n) · L` on the upper
//! hemisphere.
//!
//! Normalisation: `c(n) = (n + A)/B`, by default `A = 6`, `B = 24.55` (the paper's MathCAD fit),
//! or any expression of `n`, `A`, `B` ([`super::normexpr`]). The paper's reflectance
//! `R(n) = 2π ∫_0^{π/2} L(cos(θ/2)) cos θ sin θ dθ` is this BRDF's directional–hemispherical
//! reflectance at normal incidence in the Blinn form (there `θ_h = θ_V/2`), with no extra cosine
//! or 1/π in the BRDF.
//!
//! It is Lyon's approximation with `w = 4` ([`super::lyon`], whose [`PowLobe`] samples it).
//! Reference: method page `docs/methods/001-energy-conserving-brdf.md` (seed 001).
//! Tests (below and in `lyon.rs`): χ² sampling vs pdf (both forms, three `n`, four angles),
//! consistency, reciprocity; the method page's R(n) table is reproduced in
//! `opal-inverse/src/brdf_energy/tests.rs` through the checker's quadrature.

use super::lobe::{LobeBxdf, LobeForm, impl_lobe_bxdf};
use super::lyon::PowLobe;
use crate::spectrum::Spectrum;

/// The paper's normalisation constants `A = 6`, `B = 24.55`.
pub const PAPER_A: f64 = 6.0;
/// See [`PAPER_A`].
pub const PAPER_B: f64 = 24.55;

/// pow16 lobe BRDF.
#[derive(Clone, Debug)]
pub struct Pow16 {
    /// The lobe.
    pub lobe: LobeBxdf<PowLobe>,
}

impl Pow16 {
    /// pow16 lobe with exponent `n`, form, normalisation factor `scale` and reflectance.
    pub fn new(n: f64, form: LobeForm, scale: f64, reflectance: Spectrum) -> Self {
        Pow16 { lobe: LobeBxdf::new(PowLobe::new(n, 16), form, scale, reflectance) }
    }
    /// `(n + A)/B`.
    pub fn paper_factor(n: f64, a: f64, b: f64) -> f64 {
        (n + a) / b
    }
}

impl_lobe_bxdf!(Pow16);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsdf::lobe::test_util::*;

    #[test]
    fn chi2_reciprocity_consistency() {
        for form in [LobeForm::Phong, LobeForm::Blinn] {
            for n in [1.0, 120.0] {
                let b = Pow16::new(n, form, Pow16::paper_factor(n, PAPER_A, PAPER_B), Spectrum::ONE);
                chi2_at(&format!("pow16_{}_n{n}", form.name()), &b, &[0.0, 0.9, 1.45], 12);
                sample_consistency(&b, 0.7);
                reciprocity(&b);
            }
        }
    }
}
