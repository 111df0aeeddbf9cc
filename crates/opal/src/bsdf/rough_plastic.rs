//! Rough plastic (Mitsuba 3's `roughplastic`): a diffuse base under a rough dielectric
//! coating, Mitsuba's approximation of Weidlich & Wilkie 2007.
//!
//! * Specular: single-scattering microfacet reflection of the coating,
//!   `k_s F(wo·h) D(h) G(wo, wi, h) / (4 cos θo cos θi)` (isotropic GGX or Beckmann, Mitsuba's
//!   separable G1·G1 with its Beckmann G1 approximation, [`Ndfs::g1_mitsuba`]).
//! * Diffuse: `ρ / (1 − R_int · (ρ if nonlinear else 1)) · T(cos θo) T(cos θi) / (η² π)`, with
//!   `T(μ; η)` the rough interface's single-scattering directional transmittance (refracted
//!   light that is not masked on its way down), tabulated at 64 cosines `μ_j = max(10⁻⁶, j/63)`
//!   and interpolated linearly, and `R_int = 2 · mean_j(R(μ_j; 1/η) μ_j)` the inside's diffuse
//!   reflectance from the single-scattering directional reflectance `R`, as Mitsuba 3 computes
//!   both when the material is built (note `T ≠ 1 − R`: single scattering loses the masked
//!   light). Both are computed here by a midpoint rule over the visible-normal sample square
//!   (`∫ (1 − F(w·m)) G1(wt, m) dP(m)`, `∫ F(w·m) G1(wr, m) dP(m)`), 64² points outside, 128²
//!   inside (total internal reflection makes F discontinuous there).
//! * Sampling (Mitsuba's rule): the specular lobe (visible normals of `wo`, reflected) with
//!   probability `p_s = (1 − T_o) w / ((1 − T_o) w + T_o (1 − w))`, the cosine-weighted diffuse
//!   lobe otherwise; `w = mean(k_s)/(mean(ρ̄) + mean(k_s))` (see [`super::plastic`]).
//!   `pdf = p_s D_wo(h)/(4 wo·h) + (1 − p_s) cos θi/π` (the exact visible-normal density).
//!
//! One-sided. The diffuse reflectance may be a texture (see [`super::plastic`]).
//! Tests (below): χ² of the mixture sampling vs `pdf` (GGX, Beckmann), consistency,
//! reciprocity, the reflectance quadrature against a direct one and `R + T ≤ 1`, energy
//! `R ≤ 1`; point values against Mitsuba 3 in `tests/mitsuba_materials.rs`;
//! `tests/mitsuba_materials.rs`: a scene against Mitsuba 3.

use super::microfacet::{Ndf, Ndfs};
use super::plastic::specular_sampling_weight;
use super::{BsdfSample, Bxdf, BxdfFlags, TransportMode};
use crate::math::{INV_PI, Vec2, Vec3, fresnel_dielectric, reflect, refract};
use crate::sampling::square_to_cosine_hemisphere;
use crate::spectrum::Spectrum;
use std::sync::Arc;

/// Size of the transmittance table (Mitsuba's `MI_ROUGH_TRANSMITTANCE_RES`).
pub const TRANSMITTANCE_RES: usize = 64;

/// The midpoint rule with `n × n` points over the visible-normal sample square of the
/// direction at `cos θ = mu` (above the interface): the mean of `term(w, m, w·m)` over the
/// visible normals `m` with `w·m > 0` (`None` counts as 0).
fn vndf_midpoint(ndf: &Ndfs, mu: f32, n: usize, term: impl Fn(Vec3, Vec3, f32) -> Option<f32>) -> f32 {
    let w = Vec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu);
    let mut acc = 0.0f64;
    for i in 0..n {
        for j in 0..n {
            let u = Vec2::new((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32);
            let m = ndf.sample_visible(w, u);
            let c = w.dot(m);
            if c <= 0.0 {
                continue;
            }
            if let Some(v) = term(w, m, c) {
                acc += v as f64;
            }
        }
    }
    (acc / (n * n) as f64) as f32
}

/// Single-scattering directional reflectance of a rough dielectric interface of relative index
/// `eta` seen from a direction at `cos θ = mu` (above the interface): [`vndf_midpoint`] of
/// `F(w·m) G1(wr, m)`.
pub fn rough_reflectance(ndf: &Ndfs, mu: f32, eta: f32, n: usize) -> f32 {
    vndf_midpoint(ndf, mu, n, |w, m, c| {
        let r = reflect(w, m);
        (r.z > 0.0).then(|| fresnel_dielectric(c, eta).0 * ndf.g1_mitsuba(r, m))
    })
}

/// Single-scattering directional transmittance of a rough dielectric interface of relative
/// index `eta` for light arriving at `cos θ = mu` from above: [`vndf_midpoint`] of
/// `(1 − F(w·m)) G1(wt, m)`, `wt` the refracted direction (below the interface).
pub fn rough_transmittance(ndf: &Ndfs, mu: f32, eta: f32, n: usize) -> f32 {
    vndf_midpoint(ndf, mu, n, |w, m, c| {
        let t = refract(w, m, eta)?;
        (t.z < 0.0).then(|| (1.0 - fresnel_dielectric(c, eta).0) * ndf.g1_mitsuba(t, m))
    })
}

/// Rough plastic (diffuse base, rough dielectric coating).
#[derive(Clone, Debug)]
pub struct RoughPlastic {
    /// Isotropic NDF of the coating.
    pub ndf: Ndfs,
    /// Relative index `int_ior / ext_ior`.
    pub eta: f32,
    /// Diffuse reflectance (the constant value; textured materials pass theirs per hit).
    pub kd: Spectrum,
    /// Specular reflectance multiplier.
    pub ks: Spectrum,
    /// Mitsuba's `nonlinear`.
    pub nonlinear: bool,
    /// Specular sampling weight `w`.
    pub spec_weight: f32,
    /// External transmittance `T(μ_j)`.
    pub transmittance: Arc<[f32; TRANSMITTANCE_RES]>,
    /// Internal diffuse reflectance `R_int`.
    pub internal_reflectance: f32,
}

impl RoughPlastic {
    /// New rough plastic (precomputes the transmittance table); `kd_mean` sets the sampling
    /// weight (see [`super::Plastic::new`]). Error unless η is finite, > 0 and ≠ 1.
    pub fn new(
        ndf: Ndfs,
        eta: f32,
        kd: Spectrum,
        kd_mean: f32,
        ks: Spectrum,
        nonlinear: bool,
    ) -> crate::Result<Self> {
        if !(eta.is_finite() && eta > 0.0) || (eta - 1.0).abs() < 1e-4 {
            return Err(crate::Error::invalid("int_ior/ext_ior", format!("must be > 0 and ≠ 1, got {eta}")));
        }
        let mut t = [0.0f32; TRANSMITTANCE_RES];
        let mut r_int = 0.0f64;
        for (j, tj) in t.iter_mut().enumerate() {
            let mu = (j as f32 / (TRANSMITTANCE_RES - 1) as f32).max(1e-6);
            *tj = rough_transmittance(&ndf, mu, eta, 64);
            r_int += (rough_reflectance(&ndf, mu, 1.0 / eta, 128) * mu) as f64;
        }
        let internal_reflectance = (2.0 * r_int / TRANSMITTANCE_RES as f64) as f32;
        Ok(RoughPlastic {
            ndf,
            eta,
            kd,
            ks,
            nonlinear,
            spec_weight: specular_sampling_weight(kd_mean, ks),
            transmittance: Arc::new(t),
            internal_reflectance,
        })
    }

    /// `T(μ)` by linear interpolation of the table.
    #[inline]
    pub fn transmittance_at(&self, mu: f32) -> f32 {
        let x = mu.clamp(0.0, 1.0) * (TRANSMITTANCE_RES - 1) as f32;
        let i = (x as usize).min(TRANSMITTANCE_RES - 2);
        let w = x - i as f32;
        self.transmittance[i] * (1.0 - w) + self.transmittance[i + 1] * w
    }

    #[inline]
    fn prob_specular(&self, cos_o: f32) -> f32 {
        let t = self.transmittance_at(cos_o);
        let ps = (1.0 - t) * self.spec_weight;
        let pd = t * (1.0 - self.spec_weight);
        if ps + pd > 0.0 { ps / (ps + pd) } else { 0.0 }
    }

    /// `f(wo, wi)` with diffuse reflectance `kd` (without the cosine).
    pub fn eval_kd(&self, kd: Spectrum, wo: Vec3, wi: Vec3) -> Spectrum {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return Spectrum::ZERO;
        }
        let h = (wo + wi).normalize();
        let d = self.ndf.d(h);
        let g = self.ndf.g1_mitsuba(wo, h) * self.ndf.g1_mitsuba(wi, h);
        let f = fresnel_dielectric(wo.dot(h), self.eta).0;
        let spec = self.ks * (f * d * g / (4.0 * wo.z * wi.z));
        let den = if self.nonlinear {
            Spectrum::ONE - kd * self.internal_reflectance
        } else {
            Spectrum::splat(1.0 - self.internal_reflectance)
        };
        let s = self.transmittance_at(wo.z) * self.transmittance_at(wi.z) * INV_PI / (self.eta * self.eta);
        let diff = Spectrum::rgb(kd[0] / den[0], kd[1] / den[1], kd[2] / den[2]) * s;
        let v = spec + diff;
        if v.is_finite() { v } else { Spectrum::ZERO }
    }

    /// Density of `wi` (independent of the diffuse reflectance).
    pub fn pdf_dir(&self, wo: Vec3, wi: Vec3) -> f32 {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return 0.0;
        }
        let ps = self.prob_specular(wo.z);
        let h = (wo + wi).normalize();
        let c = wo.dot(h);
        let spec = if c > 0.0 { self.ndf.pdf_visible(wo, h) / (4.0 * c) } else { 0.0 };
        let p = ps * spec + (1.0 - ps) * wi.z * INV_PI;
        if p.is_finite() { p } else { 0.0 }
    }

    /// [`Bxdf::sample`] with diffuse reflectance `kd`.
    pub fn sample_kd(&self, kd: Spectrum, wo: Vec3, uc: f32, u: Vec2) -> Option<BsdfSample> {
        if wo.z <= 0.0 {
            return None;
        }
        let wi = if uc < self.prob_specular(wo.z) {
            let m = self.ndf.sample_visible(wo, u);
            reflect(wo, m).normalize()
        } else {
            square_to_cosine_hemisphere(u)
        };
        if wi.z <= 0.0 || !wi.is_finite() {
            return None;
        }
        let pdf = self.pdf_dir(wo, wi);
        if pdf <= 0.0 {
            return None;
        }
        Some(BsdfSample {
            wi,
            f: self.eval_kd(kd, wo, wi),
            pdf,
            flags: BxdfFlags { reflection: true, ..Default::default() },
            eta: 1.0,
        })
    }
}

impl Bxdf for RoughPlastic {
    fn eval(&self, wo: Vec3, wi: Vec3, _mode: TransportMode) -> Spectrum {
        self.eval_kd(self.kd, wo, wi)
    }
    fn pdf(&self, wo: Vec3, wi: Vec3, _mode: TransportMode) -> f32 {
        self.pdf_dir(wo, wi)
    }
    fn sample(&self, wo: Vec3, uc: f32, u: Vec2, _mode: TransportMode) -> Option<BsdfSample> {
        self.sample_kd(self.kd, wo, uc, u)
    }
    fn flags(&self) -> BxdfFlags {
        BxdfFlags { reflection: true, ..Default::default() }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsdf::lobe::test_util::*;
    use crate::math::{DVec3, spherical_direction};
    use crate::validate::quadrature::integrate_z_range;

    fn models() -> Vec<(String, RoughPlastic)> {
        vec![
            (
                "beckmann_0.1".into(),
                RoughPlastic::new(
                    Ndfs::beckmann(0.1),
                    1.49,
                    Spectrum::rgb(0.2, 0.5, 0.8),
                    0.5,
                    Spectrum::ONE,
                    false,
                )
                .unwrap(),
            ),
            (
                "ggx_0.4_nl".into(),
                RoughPlastic::new(
                    Ndfs::ggx(0.4),
                    1.6,
                    Spectrum::rgb(0.8, 0.3, 0.1),
                    0.4,
                    Spectrum::splat(0.7),
                    true,
                )
                .unwrap(),
            ),
        ]
    }

    #[test]
    fn chi2_consistency_reciprocity() {
        for (name, b) in models() {
            chi2_at(&format!("roughplastic_{name}"), &b, &[0.0, 0.9, 1.45], 6);
            sample_consistency(&b, 0.7);
            reciprocity(&b);
        }
    }

    #[test]
    fn table_matches_direct_quadrature() {
        // R(μ) = ∫ F(w·h) D G1(w) G1(r) / (4 cos θ) dω_r over the reflected directions
        let b = &models()[1].1;
        for mu in [0.2f32, 0.6, 0.95] {
            let w = Vec3::new((1.0 - mu * mu).sqrt(), 0.0, mu);
            let q: f64 = [0.0, 0.5, 0.9, 1.0]
                .windows(2)
                .map(|e| {
                    integrate_z_range(e[0], e[1], 96, 256, |r: DVec3| {
                        let r = r.as_vec3();
                        let h = (w + r).normalize();
                        let f = fresnel_dielectric(w.dot(h), b.eta).0;
                        let g = b.ndf.g1_mitsuba(w, h) * b.ndf.g1_mitsuba(r, h);
                        (f * b.ndf.d(h) * g / (4.0 * w.z)) as f64
                    })
                })
                .sum();
            let r = rough_reflectance(&b.ndf, mu, b.eta, 64) as f64;
            assert!((r - q).abs() < 2e-3, "μ {mu}: midpoint rule {r} quadrature {q}");
            // single scattering: R + T ≤ 1, the difference is the masked light (a few %)
            let t = b.transmittance_at(mu) as f64;
            assert!(r + t <= 1.0 + 1e-3 && r + t > 0.8, "μ {mu}: R {r} T {t}");
        }
        // below the smooth interface's F_dr,int (0.65): single scattering loses the light the
        // rough surface masks, most of it at grazing angles (0.40 here, as Mitsuba: the values
        // of `tests/mitsuba_materials.rs` depend on it)
        let smooth = crate::bsdf::plastic::fresnel_diffuse_reflectance(1.0 / b.eta);
        assert!(
            b.internal_reflectance > 0.3 && b.internal_reflectance < smooth,
            "{}",
            b.internal_reflectance
        );
    }

    #[test]
    fn albedo_of_a_white_base_at_most_one() {
        let b = RoughPlastic::new(Ndfs::ggx(0.3), 1.49, Spectrum::ONE, 1.0, Spectrum::ONE, false).unwrap();
        for theta in [0.0f32, 0.8, 1.4] {
            let wo = spherical_direction(theta, 0.0);
            let a: f64 = [0.0, 0.5, 0.9, 1.0]
                .windows(2)
                .map(|e| {
                    integrate_z_range(e[0], e[1], 96, 256, |w: DVec3| {
                        b.eval(wo, w.as_vec3(), TransportMode::Radiance)[0] as f64 * w.z
                    })
                })
                .sum();
            // ≤ 1; well below 1 because single scattering at the coating loses the masked light
            // on the way in, on the way out and in R_int (0.69 at normal incidence here)
            assert!(a <= 1.0 + 2e-3 && a > 0.6, "θ {theta}: albedo {a}");
        }
    }
}
