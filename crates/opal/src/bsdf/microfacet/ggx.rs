//! GGX / Trowbridge–Reitz distribution: the "Cauchy-like" NDF of method A (slopes follow a
//! bivariate Student-t, density ∝ (1 + r²/α²)⁻², i.e. heavy r⁻⁴ tails),
//! `D(wm) = 1 / (π α² cos⁴θm (1 + tan²θm/α²)²)`.
//!
//! Parameters: isotropic roughness `alpha` > 0.
//! Smith Λ in closed form: `Λ = (−1 + √(1 + α² tan²θ)) / 2`.
//! Visible normals: the spherical-cap method of Dupuy & Benyoub 2023 (stretch the view
//! direction to unit roughness, sample the spherical cap of directions `c` with
//! `c·z ≥ −v·z` uniformly, the half vector `c + v` is a visible normal of the unit-roughness
//! surface, unstretch); the same distribution as Heitz's 2018 disk method with fewer
//! operations (no tangent frame), with the polynomial `sincos(2πu)` of [`crate::fastmath`].
//! References: J. Dupuy, A. Benyoub, "Sampling Visible GGX Normals with Spherical Caps", HPG
//! 2023; E. Heitz, "Sampling the GGX Distribution of Visible Normals", JCGT 7(4) 2018.
//! Tests: `microfacet::tests::check_ndf` (normalisation, weak furnace, χ² from both sides).

use super::Ndf;
use crate::math::{PI, Vec2, Vec3};

/// Isotropic GGX (Trowbridge–Reitz) NDF.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ggx {
    /// Roughness α (> 0).
    pub alpha: f32,
}

impl Ggx {
    /// GGX NDF with roughness `alpha`; error unless `alpha` is finite and > 0.
    pub fn new(alpha: f32) -> crate::Result<Self> {
        if !(alpha.is_finite() && alpha > 0.0) {
            return Err(crate::Error::invalid("alpha", format!("must be > 0, got {alpha}")));
        }
        Ok(Ggx { alpha })
    }
}

impl Ggx {
    /// Smith G1 `2/(1 + √(1 + α² tan²θ))` (= [`Ndf::g1`], one square root and one division).
    #[inline]
    pub fn g1_fast(&self, w: Vec3, wm: Vec3) -> f32 {
        if w.dot(wm) * w.z <= 0.0 {
            return 0.0;
        }
        // 2/(1 + √(1 + α² tan²θ)) multiplied through by |cos θ|: one division
        let z = w.z.abs();
        let a2r2 = self.alpha * self.alpha * (w.x * w.x + w.y * w.y);
        2.0 * z / (z + (z * z + a2r2).sqrt())
    }
}

impl Ndf for Ggx {
    #[inline]
    fn d(&self, wm: Vec3) -> f32 {
        if wm.z <= 0.0 {
            return 0.0;
        }
        let c2 = wm.z * wm.z;
        let t2 = (1.0 - c2).max(0.0) / c2;
        let a2 = self.alpha * self.alpha;
        let k = 1.0 + t2 / a2;
        1.0 / (PI * a2 * c2 * c2 * k * k)
    }
    #[inline]
    fn lambda(&self, w: Vec3) -> f32 {
        let c2 = w.z * w.z;
        if c2 == 0.0 {
            return f32::INFINITY;
        }
        let a2t2 = self.alpha * self.alpha * (1.0 - c2).max(0.0) / c2;
        0.5 * ((1.0 + a2t2).sqrt() - 1.0)
    }
    #[inline]
    fn sample_visible(&self, w: Vec3, u: Vec2) -> Vec3 {
        let w = if w.z < 0.0 { -w } else { w };
        let a = self.alpha;
        let v = Vec3::new(a * w.x, a * w.y, w.z).normalize();
        // uniform direction in the cap z ≥ −v.z of the unit sphere
        let (sp, cp) = crate::fastmath::sincos_2pi(u.x);
        let z = (1.0 - u.y) * (1.0 + v.z) - v.z;
        let st = ((1.0 - z) * (1.0 + z)).max(0.0).sqrt();
        let h = Vec3::new(st * cp + v.x, st * sp + v.y, z + v.z);
        Vec3::new(a * h.x, a * h.y, h.z.max(1e-7)).normalize()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsdf::microfacet::tests::check_ndf;

    #[test]
    fn ggx_invariants() {
        for alpha in [0.1f32, 0.35, 0.7, 1.0] {
            // χ² for one α per family in the default tier (the quadrature of the harness is
            // the cost); `ndf_chi2_all_alphas` (ignored) runs it for every α ≥ 0.3
            // weak-furnace tolerance: quadrature error of the banded Gauss rule on the heavy
            // GGX tails, < 1e-3 here
            check_ndf(
                &format!("ggx_{alpha}"),
                &Ggx::new(alpha).unwrap(),
                2e-3,
                if alpha == 0.3 || alpha == 0.35 { &[0.0, 0.9, 1.3][..] } else { &[][..] },
            );
        }
    }

    /// Heavy tier: `cargo test -p opal --lib ndf_chi2_all_alphas -- --ignored`.
    #[test]
    #[ignore]
    fn ndf_chi2_all_alphas() {
        for alpha in [0.3f32, 0.6, 1.0] {
            check_ndf(&format!("ggx_{alpha}"), &Ggx::new(alpha).unwrap(), 2e-3, &[0.0, 0.9, 1.3]);
        }
    }

    #[test]
    fn g1_fast_matches_g1() {
        let g = Ggx::new(0.3).unwrap();
        for k in 0..=200 {
            let th = k as f32 / 200.0 * 1.56;
            for sign in [1.0f32, -1.0] {
                let w = Vec3::new(th.sin() * 0.6, th.sin() * 0.8, sign * th.cos());
                let wm = Vec3::new(0.1, 0.0, 1.0).normalize();
                assert!((g.g1_fast(w, wm) - g.g1(w, wm)).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn rejects_bad_alpha() {
        assert!(Ggx::new(0.0).is_err());
        assert!(Ggx::new(f32::INFINITY).is_err());
    }
}
