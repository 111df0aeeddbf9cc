//! Rough dielectric interface with multiple scattering on the micro-surface: the stochastic
//! random walk of Heitz, Hanika, d'Eon and Dachsbacher, "Multiple-Scattering Microfacet BSDFs
//! with the Smith Model", SIGGRAPH 2016, for any NDF of [`crate::bsdf::microfacet`], as a full
//! [`Bxdf`] (`Bxdfs::RoughDielectricMs`, scene plugin `roughdielectric` with
//! `scattering = "multiple"`).
//!
//! Model: a Smith micro-surface (uncorrelated heights and normals) with a uniform height
//! distribution on [−1, 1] (the result does not depend on that choice, Heitz et al. §4). A
//! photon walks on it: the next intersection height is drawn from the Smith masking
//! `G1(w, h) = C1(h)^Λ(w)` (Λ extended to downward directions by `Λ(−w) = −1 − Λ(w)`), the
//! facet normal from the distribution of normals visible from the current direction
//! (`∝ max(0, w·wm) D(wm)`, for directions below the horizon too), and the facet reflects with
//! the unpolarised Fresnel probability or refracts. When the walk is below the interface the
//! same rules apply to the mirrored micro-surface with the inverse relative index. The walk
//! ends when the photon escapes upwards (reflection) or downwards (transmission).
//!
//! Parameters: `ndf`, `eta` = n_inside / n_outside (outside = +z side), `eval_walks` (walks per
//! direction and `eval` call). Conventions as [`RoughDielectric`]: both directions point away
//! from the surface, `η'` = n(side of wi) / n(side of wo).
//!
//! What is exact and what is approximate in the [`Bxdf`] interface:
//! * `sample` — **exact in distribution**: it runs the walk (seeded from the bits of `u`, `uc`,
//!   so it is a deterministic function of them). The true density of the sampled `wi` is
//!   `p(wi) = f_imp(wo, wi) |cos θi|` (importance/power BSDF), so the throughput weight
//!   `f·|cos θi|/pdf` is exactly 1 in [`TransportMode::Importance`] and `1/η'²` for
//!   transmission in [`TransportMode::Radiance`] (generalised reciprocity of the walk, Heitz
//!   et al. §6). `BsdfSample::f` is set to `weight · pdf / |cos θi|` with the approximate `pdf`
//!   below, so `BsdfSample::weight()` is the exact weight — `f` there is **not** `eval(wo, wi)`.
//! * `eval` — an **unbiased stochastic estimate** of f: the order-1 part exactly (the
//!   single-scattering BSDF with the height-correlated G, which is what the walk's first
//!   bounce produces, Heitz et al. §5) plus, for orders ≥ 2, next-event estimation along walks
//!   (at each vertex k ≥ 2: phase function towards `wi` × probability of escaping along `wi`
//!   from that height, Heitz et al. §6). It averages `eval_walks` walks started from `wo` and as
//!   many from `wi` (converted with the generalised reciprocity `f(wo,wi) = η'² f(wi,wo)` in
//!   importance mode, the two estimates weighted `cos²θi : cos²θo`); the generators are seeded from the bits of the two directions, in order,
//!   so `eval` is deterministic (reproducible) and its generalised reciprocity holds exactly
//!   (same walks from either end), while the noise is a pseudo-random function of the directions.
//!   Radiance mode divides the transmission by `η'²` (as the single-scattering model).
//! * `pdf` — a **documented approximation**: `p₁(wi) + max(1 − E₁(wo), 0.02) · q(wi)`, where
//!   `p₁ = f_SS,hc(wo, wi)|cos θi|` is the exact density of the walks that leave after one
//!   bounce, `E₁(wo)` its integral (the single-scattering albedo) and `q` a cosine lobe on
//!   either side, `r(wo)|cos θi|/π` on the side of `wo` and `(1 − r(wo))|cos θi|/π` on the
//!   other, `r` the fraction of the multiply scattered power that leaves on the side of `wo`.
//!   `E₁` and `r` are tabulated on first use by walks (16 nodes in |cos θo| per side, 4096
//!   walks each, fixed seed; interpolated linearly). The floor 0.02 keeps the pdf positive
//!   where the walk can go; the pdf integrates to 1 within the table noise (tested: 0.97–1.04).
//!
//! Consequence for MIS: the path tracer weights a BSDF-sampled path by the exact `weight()` and
//! both strategies' MIS weights by the same function `pdf` (the approximate one), so the weights
//! of the two strategies still sum to one and the estimator stays unbiased; only the variance
//! depends on the quality of the approximation (it is exact in the single-scattering part,
//! which dominates for small α). Estimators that divide `eval` by `pdf` for directions not
//! drawn by `sample` (no such use in Opal) would not be unbiased for the sampling density.
//!
//! Variance: next-event estimation aimed at a grazing direction is heavy-tailed (rare walks
//! carry most of the value; see [`RoughDielectricMs::eval_multiple`] for the numbers), hence
//! the cos²-weighted combination of the two ends. Some fireflies remain possible when both
//! directions are grazing.
//!
//! Energy: for a lossless interface every walk ends on one side, so R + T = 1 up to walks
//! longer than [`MAX_BOUNCES`] (counted as lost; < 1e-4 in practice). The goniophotometer uses
//! the fast path [`RoughDielectricMs::sample_dir`] (power transport, weight 1).
//! Visible normals for a direction `w` below the horizon are drawn by rejection from those of
//! the mirrored direction `v = (wx, wy, |wz|)` (`w·wm ≤ v·wm` for upward normals), accepted
//! with probability `max(0, w·wm)/(v·wm)`; the acceptance rate `Λ(v)/(1+Λ(v))` equals the
//! probability that such a ray meets the surface at all, so the expected cost stays bounded.
//! Tests (below): energy conservation R + T ≥ 0.995 for α ≤ 1 at every incidence from both
//! sides; the order-1 part of the walk matches the single-scattering BSDF with the
//! height-correlated G (χ² on the walk's first-order exits; the order-1 next-event estimate
//! against the closed form); sample/eval consistency (histogram of `sample` vs ∫ eval·cos over
//! cells, χ² of per-cell z-scores with both Monte-Carlo errors) from both sides; generalised
//! reciprocity (exact for `eval`, and within the noise for one-sided walk estimates); ∫ pdf ≈ 1;
//! the sample weight.

use super::microfacet::{Ndf, Ndfs};
use super::rough_dielectric::{RoughDielectric, Shadowing};
use super::{BsdfSample, Bxdf, BxdfFlags, TransportMode};
use crate::math::{Vec2, Vec3, fresnel_dielectric, reflect, refract};
use crate::sampling::{Rng, hash3};
use crate::spectrum::Spectrum;
use std::sync::{Arc, OnceLock};

/// Bounces after which a walk is abandoned (counted as lost).
pub const MAX_BOUNCES: u32 = 256;

/// Default number of walks per direction in [`Bxdf::eval`].
pub const DEFAULT_EVAL_WALKS: u32 = 2;
/// Nodes in |cos θo| of the pdf tables (per side).
const TAB_N: usize = 16;
/// Walks per node of the pdf tables.
const TAB_WALKS: u32 = 4096;
/// Floor of the multiple-scattering mass of the approximate pdf.
const MS_PDF_FLOOR: f32 = 0.02;

/// Multiple-scattering rough dielectric interface (see the module documentation).
#[derive(Clone, Debug)]
pub struct RoughDielectricMs {
    /// Normal distribution of the micro-facets.
    pub ndf: Ndfs,
    /// n_inside / n_outside (outside = +z side).
    pub eta: f32,
    /// Walks per direction (from `wo` and from `wi`) in each [`Bxdf::eval`] call.
    pub eval_walks: u32,
    /// Single-scattering order (height-correlated G): the exact order-1 term.
    ss: RoughDielectric,
    /// Tables of the approximate pdf, built on first use (shared between clones).
    tables: Arc<OnceLock<PdfTables>>,
}

/// `E₁` (single-scattering albedo) and `r` (fraction of the multiply scattered power leaving on
/// the side of `wo`) at `TAB_N` nodes of |cos θo|, for `wo` above (index 0) and below (1).
#[derive(Clone, Debug)]
struct PdfTables {
    e1: [[f32; TAB_N]; 2],
    r: [[f32; TAB_N]; 2],
}

/// |cos θo| of table node `i`.
#[inline]
fn tab_cos(i: usize) -> f32 {
    (i as f32 + 0.5) / TAB_N as f32
}

#[inline]
fn zflip(w: Vec3) -> Vec3 {
    Vec3::new(w.x, w.y, -w.z)
}

/// Seed from the bits of two directions, in order.
#[inline]
fn dir_key(a: Vec3, b: Vec3) -> u64 {
    let k1 = (a.x.to_bits() as u64) | ((a.y.to_bits() as u64) << 32);
    let k2 = (a.z.to_bits() as u64) | ((b.x.to_bits() as u64) << 32);
    let k3 = (b.y.to_bits() as u64) | ((b.z.to_bits() as u64) << 32);
    hash3(k1, k2, k3)
}

#[inline]
fn c1(h: f32) -> f32 {
    (0.5 * (h + 1.0)).clamp(0.0, 1.0)
}
#[inline]
fn inv_c1(u: f32) -> f32 {
    (2.0 * u - 1.0).clamp(-1.0, 1.0)
}

impl RoughDielectricMs {
    /// New interface; error unless `eta` is finite, > 0 and ≠ 1.
    pub fn new(ndf: Ndfs, eta: f32) -> crate::Result<Self> {
        if !(eta.is_finite() && eta > 0.0) || (eta - 1.0).abs() < 1e-4 {
            return Err(crate::Error::invalid("eta", format!("must be > 0 and ≠ 1, got {eta}")));
        }
        let ss = RoughDielectric::new(ndf.clone(), eta, Shadowing::HeightCorrelated)?;
        Ok(RoughDielectricMs {
            ndf,
            eta,
            eval_walks: DEFAULT_EVAL_WALKS,
            ss,
            tables: Arc::new(OnceLock::new()),
        })
    }

    /// The single-scattering order of this model: [`RoughDielectric`] with the
    /// height-correlated G (what the walk's first bounce produces).
    pub fn single_scattering(&self) -> &RoughDielectric {
        &self.ss
    }

    /// Λ extended to the whole sphere of travel directions.
    #[inline]
    fn lambda_ext(&self, w: Vec3) -> f32 {
        let l = self.ndf.lambda(w);
        if w.z >= 0.0 { l } else { -1.0 - l }
    }

    /// [`Self::sample_height`] for a ray on either side: below the surface the mirrored
    /// micro-surface (negated direction and height) is the same random surface.
    #[inline]
    fn sample_height_on_side(&self, wr: Vec3, hr: f32, outside: bool, u: f32) -> Option<f32> {
        if outside { self.sample_height(wr, hr, u) } else { self.sample_height(-wr, -hr, u).map(|h| -h) }
    }

    /// Next intersection height of a ray travelling along `wr` from height `hr` (above the
    /// micro-surface); `None` when it escapes.
    #[inline]
    fn sample_height(&self, wr: Vec3, hr: f32, u: f32) -> Option<f32> {
        if wr.z > 0.9999 {
            return None;
        }
        if wr.z < -0.9999 {
            return Some(inv_c1(u * c1(hr)));
        }
        if wr.z.abs() < 1e-4 {
            return Some(hr);
        }
        let lam = self.lambda_ext(wr);
        if wr.z > 0.0 {
            let g1 = c1(hr).powf(lam);
            if u > 1.0 - g1 {
                return None;
            }
        }
        let c = c1(hr) / (1.0 - u).powf(1.0 / lam);
        Some(inv_c1(c.min(1.0)))
    }

    /// Normal (upper hemisphere) drawn with density ∝ max(0, w·wm) D(wm), any `w`.
    #[inline]
    fn sample_visible_any(&self, w: Vec3, rng: &mut Rng) -> Vec3 {
        if w.z >= 0.0 {
            return self.ndf.sample_visible(w, rng.next_2d());
        }
        let v = Vec3::new(w.x, w.y, -w.z);
        for _ in 0..10_000 {
            let wm = self.ndf.sample_visible(v, rng.next_2d());
            let a = w.dot(wm);
            if a > 0.0 && rng.next_f32() * v.dot(wm) < a {
                return wm;
            }
        }
        // practically unreachable (acceptance ≥ Λ/(1+Λ) of a direction that did intersect)
        self.ndf.sample_visible(v, rng.next_2d())
    }

    /// Draws the direction in which a photon arriving from `wo` (pointing away from the
    /// surface, either side) leaves the micro-surface; `None` if the walk exceeded
    /// [`MAX_BOUNCES`] or hit a degenerate configuration. The weight is 1 (power).
    pub fn sample_dir(&self, wo: Vec3, rng: &mut Rng) -> Option<Vec3> {
        self.sample_dir_order(wo, rng).map(|(w, _)| w)
    }

    /// Same, also returning the number of scattering events on the micro-surface.
    pub fn sample_dir_order(&self, wo: Vec3, rng: &mut Rng) -> Option<(Vec3, u32)> {
        if wo.z == 0.0 || !wo.is_finite() {
            return None;
        }
        // light from inside: the mirrored micro-surface with the inverse index is statistically
        // the same surface (symmetric heights, centrally symmetric NDF)
        let flip = wo.z < 0.0;
        let eta = if flip { 1.0 / self.eta } else { self.eta };
        let wo = if flip { Vec3::new(wo.x, wo.y, -wo.z) } else { wo };
        let mut wr = -wo;
        let mut hr = 1.0 + inv_c1(0.999);
        let mut outside = true;
        let mut order = 0;
        loop {
            let u = rng.next_f32();
            let h = self.sample_height_on_side(wr, hr, outside, u);
            let Some(h) = h else { break };
            hr = h;
            order += 1;
            if order > MAX_BOUNCES {
                return None;
            }
            (wr, outside) = self.scatter(wr, outside, eta, rng)?;
        }
        // escaped: upwards if outside (reflection), downwards if inside (transmission)
        if (outside && wr.z <= 0.0) || (!outside && wr.z >= 0.0) {
            return None;
        }
        let out = if flip { Vec3::new(wr.x, wr.y, -wr.z) } else { wr };
        Some((out, order))
    }

    /// Samples the phase function at a vertex: the photon travelling along `wr` meets a facet
    /// of the upper micro-surface (`outside`) or of the mirrored one (inside); returns the new
    /// direction of travel and side. `eta` is the relative index seen from outside.
    #[inline(always)]
    fn scatter(&self, wr: Vec3, outside: bool, eta: f32, rng: &mut Rng) -> Option<(Vec3, bool)> {
        let wi = -wr;
        let (e, wm) = if outside {
            (eta, self.sample_visible_any(wi, rng))
        } else {
            (1.0 / eta, -self.sample_visible_any(-wi, rng))
        };
        let cos = wi.dot(wm);
        if cos <= 0.0 {
            return None;
        }
        let (f, _) = fresnel_dielectric(cos, e);
        let (wr, outside) = if rng.next_f32() < f {
            (reflect(wi, wm), outside)
        } else {
            (refract(wi, wm, e)?.normalize(), !outside)
        };
        wr.is_finite().then_some((wr, outside))
    }

    /// Density of normals of the upper micro-surface visible from any direction `w`:
    /// `max(0, w·m) D(m) / A(w)` with the projected area `A(w) = w.z (1 + Λ_ext(w))`
    /// (`= |w.z| Λ(|w|)` below the horizon).
    #[inline]
    fn pdf_visible_any(&self, w: Vec3, m: Vec3) -> f32 {
        let c = w.dot(m);
        if c <= 0.0 || m.z <= 0.0 {
            return 0.0;
        }
        // projected area computed without the cancellation of 1 + Λ_ext = −Λ below the horizon
        // (Λ ~ 1e-7 near the vertical would lose all its digits)
        let lam = self.ndf.lambda(w);
        let a = if w.z >= 0.0 { w.z * (1.0 + lam) } else { -w.z * lam };
        if a.is_nan() || a <= 0.0 {
            return 0.0;
        }
        c * self.ndf.d(m) / a
    }

    /// Phase function of the upper micro-surface (facets with upward normals, relative index
    /// `e` = n(below) / n(above)) for a photon that came from direction `wi` (pointing back
    /// along its path, either hemisphere) and leaves along `wt`: density per solid angle of
    /// `wt`, `reflect` selecting the reflected (`wt` stays above) or the refracted branch.
    #[inline]
    fn phase_upper(&self, wi: Vec3, wt: Vec3, e: f32, reflect: bool) -> f32 {
        if reflect {
            let h = wi + wt;
            let l = h.length();
            if l == 0.0 {
                return 0.0;
            }
            let m = h / l;
            let c = wi.dot(m);
            if m.z <= 0.0 || c <= 0.0 {
                return 0.0;
            }
            let (f, _) = fresnel_dielectric(c, e);
            f * self.pdf_visible_any(wi, m) / (4.0 * c)
        } else {
            let h = wi + wt * e;
            let l = h.length();
            if l == 0.0 {
                return 0.0;
            }
            let m = if h.z < 0.0 { -h / l } else { h / l };
            let (ci, ct) = (wi.dot(m), wt.dot(m));
            if m.z <= 0.0 || ci <= 0.0 || ct >= 0.0 {
                return 0.0;
            }
            let (f, _) = fresnel_dielectric(ci, e);
            let den = ci + e * ct;
            (1.0 - f) * self.pdf_visible_any(wi, m) * e * e * (-ct) / (den * den)
        }
    }

    /// One walk from `wo` with next-event estimation towards `wi`: the sum over scattering
    /// events `min_order ≤ k ≤ max_order` of (phase function towards `wi`) × (probability of escaping
    /// along `wi` from that height). Its expectation is the density of the walk's exit
    /// direction at `wi` restricted to those orders, i.e. `f_imp(wo, wi) |cos θi|` of those
    /// orders (importance / power BSDF).
    pub fn nee_walk(&self, wo: Vec3, wi: Vec3, min_order: u32, max_order: u32, rng: &mut Rng) -> f32 {
        if wo.z == 0.0 || wi.z == 0.0 || !wo.is_finite() || !wi.is_finite() {
            return 0.0;
        }
        let flip = wo.z < 0.0;
        let eta = if flip { 1.0 / self.eta } else { self.eta };
        let (wo, wi) = if flip { (zflip(wo), zflip(wi)) } else { (wo, wi) };
        let exit_up = wi.z > 0.0;
        let lam_i = self.ndf.lambda(wi);
        let mut wr = -wo;
        let mut hr = 1.0 + inv_c1(0.999);
        let mut outside = true;
        let mut order = 0;
        let mut sum = 0.0f32;
        loop {
            let next = order + 1;
            if next > MAX_BOUNCES.min(max_order) {
                break;
            }
            if next >= min_order {
                // forced intersection: the next vertex's height drawn conditionally on the ray
                // hitting the surface, the contribution weighted by the hit probability
                let (wf, hf) = if outside { (wr, hr) } else { (-wr, -hr) };
                let u = rng.next_f32();
                if let Some((p_hit, h)) = self.forced_hit(wf, hf, u) {
                    let h = if outside { h } else { -h };
                    let wv = -wr;
                    // reflection at this vertex iff the exit side is the vertex's side
                    let refl = outside == exit_up;
                    let p = if outside {
                        self.phase_upper(wv, wi, eta, refl)
                    } else {
                        self.phase_upper(-wv, -wi, 1.0 / eta, refl)
                    };
                    if p > 0.0 {
                        let esc = if exit_up { c1(h).powf(lam_i) } else { c1(-h).powf(lam_i) };
                        let v = (p_hit * p as f64) as f32 * esc;
                        if v.is_finite() {
                            sum += v;
                        }
                    }
                }
            }
            // the walk itself
            let u = rng.next_f32();
            let h = self.sample_height_on_side(wr, hr, outside, u);
            let Some(h) = h else { break };
            hr = h;
            order += 1;
            match self.scatter(wr, outside, eta, rng) {
                Some((w, o)) => (wr, outside) = (w, o),
                None => break,
            }
        }
        sum
    }

    /// Forced intersection of a ray along `wr` from height `hr` (frame of the upper surface):
    /// the probability that it hits the surface and a hit height drawn conditionally on hitting
    /// (from `u`); `None` when it cannot hit. Computed in f64 with `expm1`/`ln_1p`: near the
    /// vertical Λ is tiny and `1 − C1^Λ` in f32 would be rounded to a multiple of 6e-8,
    /// overestimating the hit probability by orders of magnitude.
    #[inline]
    fn forced_hit(&self, wr: Vec3, hr: f32, u: f32) -> Option<(f64, f32)> {
        if wr.z > 0.9999 {
            return None;
        }
        if wr.z < 1e-4 {
            // downwards or horizontal: always hits, as in the walk
            return self.sample_height(wr, hr, u).map(|h| (1.0, h));
        }
        let lam = self.ndf.lambda(wr) as f64;
        let lc = (c1(hr) as f64).ln();
        let p_hit = -(lam * lc).exp_m1();
        if !(p_hit > 0.0 && lam > 0.0) {
            return None;
        }
        let ln_c = lc - (-(u as f64) * p_hit).ln_1p() / lam;
        Some((p_hit.min(1.0), inv_c1(ln_c.min(0.0).exp() as f32)))
    }

    /// η' = n(side of wi) / n(side of wo) (1 for reflection).
    #[inline]
    fn etap(&self, wo: Vec3, wi: Vec3) -> f32 {
        if wo.z * wi.z > 0.0 {
            1.0
        } else if wo.z > 0.0 {
            self.eta
        } else {
            1.0 / self.eta
        }
    }

    /// Estimate of the orders ≥ 2 of `f_imp(wo, wi)` (importance mode): `eval_walks` walks
    /// from `wo` and as many from `wi` (converted by generalised reciprocity), seeded from the
    /// directions, combined with weights `cos²θi : cos²θo` (the estimator aiming its
    /// next-event estimation at the steeper direction gets more weight: aiming at a grazing
    /// direction is heavy-tailed — measured for Beckmann α = 1, θo = 1.2, wi near-normal
    /// transmitted: 91 % of the mean of the walk from wi comes from 0.1 % of the walks,
    /// against 7.5 % for the walk from wo).
    pub fn eval_multiple(&self, wo: Vec3, wi: Vec3) -> f32 {
        let n = self.eval_walks.max(1);
        let (ci, co) = (wi.z.abs(), wo.z.abs());
        if ci == 0.0 || co == 0.0 {
            return 0.0;
        }
        let mut ra = Rng::new(dir_key(wo, wi), 0x4d53_4556, 0);
        let mut rb = Rng::new(dir_key(wi, wo), 0x4d53_4556, 0);
        let (mut a, mut b) = (0.0f32, 0.0f32);
        for _ in 0..n {
            a += self.nee_walk(wo, wi, 2, MAX_BOUNCES, &mut ra);
            b += self.nee_walk(wi, wo, 2, MAX_BOUNCES, &mut rb);
        }
        // weights ∝ cos² of the direction each estimator aims its next-event estimation at:
        // f ≈ (ci² · a/ci + co² · η'² b/co) / (ci² + co²); symmetric under the swap, so the
        // generalised reciprocity stays exact
        let e = self.etap(wo, wi);
        let v = (ci * a + co * e * e * b) / ((ci * ci + co * co) * n as f32);
        if v.is_finite() { v } else { 0.0 }
    }

    /// Importance-mode BSDF estimate: exact order 1 + [`Self::eval_multiple`].
    pub fn eval_importance(&self, wo: Vec3, wi: Vec3) -> f32 {
        self.ss.eval(wo, wi, TransportMode::Importance)[0] + self.eval_multiple(wo, wi)
    }

    fn tables(&self) -> &PdfTables {
        self.tables.get_or_init(|| {
            let mut t = PdfTables { e1: [[0.0; TAB_N]; 2], r: [[0.5; TAB_N]; 2] };
            for side in 0..2 {
                for i in 0..TAB_N {
                    let c = tab_cos(i);
                    let s = (1.0 - c * c).max(0.0).sqrt();
                    let wo = Vec3::new(s, 0.0, if side == 0 { c } else { -c });
                    let mut rng = Rng::new(0x7461_626c, side as u64, i as u64);
                    let (mut n1, mut nms, mut nsame) = (0u32, 0u32, 0u32);
                    for _ in 0..TAB_WALKS {
                        if let Some((w, k)) = self.sample_dir_order(wo, &mut rng) {
                            if k <= 1 {
                                n1 += 1;
                            } else {
                                nms += 1;
                                if w.z * wo.z > 0.0 {
                                    nsame += 1;
                                }
                            }
                        }
                    }
                    t.e1[side][i] = n1 as f32 / TAB_WALKS as f32;
                    if nms > 0 {
                        t.r[side][i] = nsame as f32 / nms as f32;
                    }
                }
            }
            t
        })
    }

    /// (E₁, r) at `wo` (linear interpolation in |cos θo|).
    fn table_lookup(&self, wo: Vec3) -> (f32, f32) {
        let t = self.tables();
        let side = usize::from(wo.z < 0.0);
        let x = (wo.z.abs() * TAB_N as f32 - 0.5).clamp(0.0, (TAB_N - 1) as f32);
        let i = (x as usize).min(TAB_N - 2);
        let f = x - i as f32;
        let lerp = |a: &[f32; TAB_N]| a[i] + f * (a[i + 1] - a[i]);
        (lerp(&t.e1[side]), lerp(&t.r[side]))
    }
}

impl Bxdf for RoughDielectricMs {
    fn eval(&self, wo: Vec3, wi: Vec3, mode: TransportMode) -> Spectrum {
        if wo.z == 0.0 || wi.z == 0.0 {
            return Spectrum::ZERO;
        }
        let mut v = self.eval_importance(wo, wi);
        if mode == TransportMode::Radiance && wo.z * wi.z < 0.0 {
            let e = self.etap(wo, wi);
            v /= e * e;
        }
        if v.is_finite() && v > 0.0 { Spectrum::splat(v) } else { Spectrum::ZERO }
    }

    /// The approximate density of the module documentation (the same in both modes: `sample`
    /// does not depend on the mode).
    fn pdf(&self, wo: Vec3, wi: Vec3, _mode: TransportMode) -> f32 {
        if wo.z == 0.0 || wi.z == 0.0 {
            return 0.0;
        }
        let p1 = self.ss.eval(wo, wi, TransportMode::Importance)[0] * wi.z.abs();
        let (e1, r) = self.table_lookup(wo);
        let side = if wo.z * wi.z > 0.0 { r } else { 1.0 - r };
        let p = p1 + (1.0 - e1).max(MS_PDF_FLOOR) * side * wi.z.abs() * std::f32::consts::FRAC_1_PI;
        if p.is_finite() { p } else { 0.0 }
    }

    fn sample(&self, wo: Vec3, uc: f32, u: Vec2, mode: TransportMode) -> Option<BsdfSample> {
        let key = (u.x.to_bits() as u64) | ((u.y.to_bits() as u64) << 32);
        let mut rng = Rng::new(key, uc.to_bits() as u64, 0x5357_414c);
        let wi = self.sample_dir(wo, &mut rng)?;
        if wi.z == 0.0 {
            return None;
        }
        let transmitted = wo.z * wi.z < 0.0;
        let e = self.etap(wo, wi);
        let weight = if transmitted && mode == TransportMode::Radiance { 1.0 / (e * e) } else { 1.0 };
        let pdf = self.pdf(wo, wi, mode);
        if !(pdf > 0.0 && pdf.is_finite()) {
            return None;
        }
        Some(BsdfSample {
            wi,
            f: Spectrum::splat(weight * pdf / wi.z.abs()),
            pdf,
            flags: BxdfFlags { reflection: !transmitted, transmission: transmitted, specular: false },
            eta: e,
        })
    }

    fn flags(&self) -> BxdfFlags {
        BxdfFlags { reflection: true, transmission: true, specular: false }
    }
}

#[cfg(test)]
mod tests;
