//! Shared machinery of the method-B specular lobes (Phong, Blinn–Phong, Schlick, Lyon, pow16).
//!
//! Every one of these models is `f(wo, wi) = k_s · c(n) · L(t)` on the upper hemisphere
//! (`wo.z > 0`, `wi.z > 0`, zero elsewhere), where `L` is a one-dimensional lobe of
//! `t = cos γ`, `c(n)` a normalisation constant (a [`NormExpr`](super::normexpr::NormExpr)) and
//! `k_s` the specular reflectance (RGB). Two *forms* say what γ is ([`LobeForm`]):
//! * **Phong form**: `t = wi · r` with `r = reflect(wo, n) = 2(wo·n)n − wo` (Phong's `V·R`);
//! * **Blinn form**: `t = n · h` with `h = (wo + wi)/|wo + wi|` (Blinn's `N·H`).
//!
//! Both are symmetric in (wo, wi): `wi · reflect(wo) = 2 (wo·n)(wi·n) − wo·wi`, and `h` is
//! symmetric — so every lobe here obeys Helmholtz reciprocity exactly.
//!
//! The BRDF value is the lobe itself, **without** any cosine factor (the paper's convention:
//! `R(L) = ∫ f(L, V) cos θ_V dω_V` with `f = c(n)·L`). It is what [`Bxdf::eval`] returns.
//!
//! Sampling draws `t` with density proportional to `L(t)` (exact inverse of the lobe's
//! integral, [`LobeShape`]) and φ uniformly:
//! * Phong form: the direction is built around `r` over the whole sphere `t ∈ [t_min, 1]`;
//!   samples below the horizon are rejected (`None`), and the pdf — `L(t) / (2π C)` per solid
//!   angle, `C = ∫_{t_min}^1 L dt` — integrates to the probability of success.
//! * Blinn form: the half vector `h` is drawn around `n` with `t ∈ [max(0, t_min), 1]` and
//!   reflected: `wi = reflect(wo, h)`, pdf `L(t)/(2π C) / (4 wo·h)`. Half vectors facing away
//!   from `wo`, or giving `wi` below the horizon, are rejected.
//!
//! Tests: χ² of sampling against the pdf for every model at several incidence angles, and
//! reciprocity (`tests` in this file and in each model file).
//!
//! [`Bxdf::eval`]: super::Bxdf::eval

use super::{BsdfSample, BxdfFlags};
use crate::math::{Frame, Vec2, Vec3, reflect};
use crate::spectrum::Spectrum;

/// What the lobe's angle γ is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum LobeForm {
    /// `cos γ = wi · reflect(wo)` (Phong's V·R).
    Phong,
    /// `cos γ = n · h`, `h` the half vector (Blinn's N·H).
    #[default]
    Blinn,
}

impl LobeForm {
    /// Name used in scene files and the CLI (`"phong"` / `"blinn"`).
    pub fn name(self) -> &'static str {
        match self {
            LobeForm::Phong => "phong",
            LobeForm::Blinn => "blinn",
        }
    }
    /// Parses `"phong"` / `"blinn"`.
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "phong" => Some(LobeForm::Phong),
            "blinn" => Some(LobeForm::Blinn),
            _ => None,
        }
    }
}

/// A one-dimensional lobe `L(t)`, `t = cos γ ∈ [-1, 1]`, with the integrals its exact
/// inverse-CDF sampling needs. `L ≥ 0`, and `L(t) = 0` for `t < t_min()`.
pub trait LobeShape {
    /// Lobe value `L(1 − x)` (f32, as the renderer evaluates it), given `x = 1 − t` computed
    /// without cancellation: a sharp lobe (n = 1000) changes by `n·δx` relative, so `t` rounded
    /// to f32 (δt ≈ 6e-8) would bias it by ~1e-4, while `x` has a relative error of ~1e-7.
    fn value(&self, x: f32) -> f32;
    /// Same in f64 (sampling and its pdf, quadrature references).
    fn value_f64(&self, t: f64) -> f64;
    /// Smallest `t` with `L(t) > 0` (the lobe's first zero), in `[-1, 1]`.
    fn t_min(&self) -> f64;
    /// Tail integral `T(t) = ∫_t^1 L(s) ds` for `t ≥ t_min()`.
    fn tail(&self, t: f64) -> f64;
    /// Inverse of [`LobeShape::tail`] on `[t_min, 1]`: the `t` with `T(t) = y`.
    /// The default is [`generic_tail_inverse`].
    fn tail_inverse(&self, y: f64) -> f64 {
        generic_tail_inverse(self, y)
    }
}

/// Solves `T(t) = y` by safeguarded Newton iteration (T is decreasing, T' = −L; bisection
/// when a Newton step leaves the bracket).
pub fn generic_tail_inverse<S: LobeShape + ?Sized>(s: &S, y: f64) -> f64 {
    let (mut lo, mut hi) = (s.t_min().max(-1.0), 1.0);
    let mut t = 0.5 * (lo + hi);
    for _ in 0..200 {
        let g = s.tail(t) - y; // decreasing in t
        if g > 0.0 {
            lo = t;
        } else {
            hi = t;
        }
        let d = s.value_f64(t);
        let mut tn = if d > 0.0 { t + g / d } else { f64::NAN };
        if !(tn > lo && tn < hi) {
            tn = 0.5 * (lo + hi);
        }
        // 1e-12 in t is far below the f32 resolution of the sampled direction
        if (tn - t).abs() < 1e-12 || hi - lo < 1e-12 {
            return tn;
        }
        t = tn;
    }
    t
}

/// A lobe BRDF: `k_s · scale · L(t)` in the given form. The models of method B wrap this.
#[derive(Clone, Debug)]
pub struct LobeBxdf<S> {
    /// The lobe shape.
    pub shape: S,
    /// Phong or Blinn form.
    pub form: LobeForm,
    /// Normalisation factor `c(n)` (f32, as evaluated).
    pub scale: f32,
    /// Specular reflectance `k_s` (per channel multiplier).
    pub reflectance: Spectrum,
    /// `C = ∫_{t_lo}^1 L dt` over the sampled range (precomputed, f64).
    norm_c: f64,
    /// Lower end of the sampled range of `t`.
    t_lo: f64,
}

impl<S: LobeShape> LobeBxdf<S> {
    /// A lobe BRDF. `scale` is the normalisation factor, `reflectance` the colour.
    pub fn new(shape: S, form: LobeForm, scale: f64, reflectance: Spectrum) -> Self {
        let t_lo = match form {
            LobeForm::Phong => shape.t_min().max(-1.0),
            LobeForm::Blinn => shape.t_min().max(0.0),
        };
        let norm_c = shape.tail(t_lo);
        LobeBxdf { shape, form, scale: scale as f32, reflectance, norm_c, t_lo }
    }

    /// `x = 1 − cos γ` for the pair (Phong: `cos γ = wi·r`, Blinn: `cos γ = h.z`), or `None`
    /// when a direction is below the horizon. Computed as `sin²γ / (1 + cos γ)` with `sin²γ`
    /// from a cross product (Phong) or the half vector's tangential part (Blinn): relative
    /// accuracy ~1e-7 even for `x ≪ 1`, and insensitive to the inputs' normalisation error.
    #[inline]
    fn one_minus_cos(&self, wo: Vec3, wi: Vec3) -> Option<f32> {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return None;
        }
        Some(match self.form {
            LobeForm::Phong => {
                let r = Vec3::new(-wo.x, -wo.y, wo.z);
                let t = wi.dot(r);
                if t > 0.0 { wi.cross(r).length_squared() / (1.0 + t) } else { (1.0 - t).min(2.0) }
            }
            LobeForm::Blinn => {
                let h = wo + wi;
                let l = h.length();
                if l <= 0.0 {
                    return None;
                }
                (h.x * h.x + h.y * h.y) / (l * (l + h.z))
            }
        })
    }

    /// f without the cosine.
    #[inline]
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Spectrum {
        match self.one_minus_cos(wo, wi) {
            Some(x) => self.reflectance * (self.scale * self.shape.value(x)),
            None => Spectrum::ZERO,
        }
    }

    /// Density of `t` on the sampled range (per unit t).
    #[inline]
    fn pdf_t(&self, t: f64) -> f64 {
        if t < self.t_lo || self.norm_c <= 0.0 { 0.0 } else { self.shape.value_f64(t) / self.norm_c }
    }

    /// Solid-angle pdf of [`LobeBxdf::sample`].
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return 0.0;
        }
        let (wo, wi) = (wo.as_dvec3(), wi.as_dvec3());
        match self.form {
            LobeForm::Phong => {
                let r = crate::math::DVec3::new(-wo.x, -wo.y, wo.z);
                let t = wi.dot(r);
                // same cancellation-free 1 − t as `eval`, in f64
                let x = if t > 0.0 { wi.cross(r).length_squared() / (1.0 + t) } else { 1.0 - t };
                (self.pdf_t((1.0 - x).clamp(-1.0, 1.0)) / (2.0 * std::f64::consts::PI)) as f32
            }
            LobeForm::Blinn => {
                let h = wo + wi;
                let l = h.length();
                if l <= 0.0 {
                    return 0.0;
                }
                let dot = wo.dot(h) / l;
                if dot <= 0.0 {
                    return 0.0;
                }
                let x = (h.x * h.x + h.y * h.y) / (l * (l + h.z));
                (self.pdf_t((1.0 - x).clamp(-1.0, 1.0)) / (2.0 * std::f64::consts::PI) / (4.0 * dot)) as f32
            }
        }
    }

    /// Draws `t` from the lobe (exact inversion of its tail integral).
    #[inline]
    fn sample_t(&self, u: f32) -> f64 {
        // T(t) = ∫_t^1 L: T(t_lo) = C, T(1) = 0; t with T(t) = u C has density L/C.
        let y = (u as f64) * self.norm_c;
        self.shape.tail_inverse(y).clamp(self.t_lo, 1.0)
    }

    /// Importance sampling of the lobe.
    pub fn sample(&self, wo: Vec3, u: Vec2) -> Option<BsdfSample> {
        if wo.z <= 0.0 || self.norm_c <= 0.0 {
            return None;
        }
        let t = self.sample_t(u.x);
        let st = (1.0 - t * t).max(0.0).sqrt();
        let (sp, cp) = (2.0 * std::f64::consts::PI * u.y as f64).sin_cos();
        let local = Vec3::new((st * cp) as f32, (st * sp) as f32, t as f32);
        let wi = match self.form {
            LobeForm::Phong => {
                let r = Vec3::new(-wo.x, -wo.y, wo.z);
                Frame::from_normal(r).to_world(local)
            }
            LobeForm::Blinn => {
                let h = local;
                if wo.dot(h) <= 0.0 {
                    return None;
                }
                reflect(wo, h)
            }
        };
        if wi.z <= 0.0 || !wi.is_finite() {
            return None;
        }
        let wi = wi.normalize();
        let pdf = self.pdf(wo, wi);
        if pdf <= 0.0 {
            return None;
        }
        Some(BsdfSample {
            wi,
            f: self.eval(wo, wi),
            pdf,
            flags: BxdfFlags { reflection: true, ..Default::default() },
            eta: 1.0,
        })
    }
}

/// Implements [`super::Bxdf`] for a newtype wrapping a [`LobeBxdf`] in its field `lobe`.
macro_rules! impl_lobe_bxdf {
    ($t:ty) => {
        impl $crate::bsdf::Bxdf for $t {
            #[inline]
            fn eval(
                &self,
                wo: $crate::math::Vec3,
                wi: $crate::math::Vec3,
                _mode: $crate::bsdf::TransportMode,
            ) -> $crate::spectrum::Spectrum {
                self.lobe.eval(wo, wi)
            }
            #[inline]
            fn pdf(
                &self,
                wo: $crate::math::Vec3,
                wi: $crate::math::Vec3,
                _mode: $crate::bsdf::TransportMode,
            ) -> f32 {
                self.lobe.pdf(wo, wi)
            }
            #[inline]
            fn sample(
                &self,
                wo: $crate::math::Vec3,
                _uc: f32,
                u: $crate::math::Vec2,
                _mode: $crate::bsdf::TransportMode,
            ) -> Option<$crate::bsdf::BsdfSample> {
                self.lobe.sample(wo, u)
            }
            fn flags(&self) -> $crate::bsdf::BxdfFlags {
                $crate::bsdf::BxdfFlags { reflection: true, ..Default::default() }
            }
        }
    };
}
pub(crate) use impl_lobe_bxdf;

#[cfg(test)]
pub(crate) mod test_util {
    //! Checks shared by the lobe models' tests.
    use crate::bsdf::{Bxdf, TransportMode};
    use crate::math::{Vec3, spherical_direction};
    use crate::validate::chi2::{Chi2Test, SphereFn3};

    /// ∫_{t0}^1 f(t) dt by composite Simpson on panels graded towards t = 1 (where the lobes
    /// peak): panel edges at `1 − 10^{-k}`, 2000 intervals each. Reference for tail integrals.
    pub fn graded_simpson(f: &dyn Fn(f64) -> f64, t0: f64) -> f64 {
        let mut edges = vec![1.0 - t0];
        let mut x = 1e-9;
        while x < 1.0 - t0 {
            edges.push(x);
            x *= 10.0;
        }
        edges.push(0.0);
        edges.sort_by(|a, b| a.partial_cmp(b).unwrap());
        let mut acc = 0.0;
        for w in edges.windows(2) {
            let (a, b) = (w[0], w[1]);
            let m = 2000;
            let h = (b - a) / m as f64;
            let mut s = 0.0;
            for i in 0..=m {
                let c = if i == 0 || i == m {
                    1.0
                } else if i % 2 == 1 {
                    4.0
                } else {
                    2.0
                };
                s += c * f(1.0 - (a + i as f64 * h));
            }
            acc += s * h / 3.0;
        }
        acc
    }

    /// χ² of `sample` against `pdf` at the given incidence angles (radians); panics on failure.
    /// `num_tests` is the size of the suite for the Šidák correction.
    ///
    /// The pdf handed to the harness is set to 0 where it is below 1e-9 of its peak (the
    /// largest pdf of 2000 samples): the harness refines its cell quadrature wherever the pdf
    /// varies by more than 50 % inside a sub-cell, which in the far tails of sharp lobes
    /// (values ~1e-30 with steep relative gradients) means millions of evaluations for nothing.
    /// The mass removed is at most 1e-9·peak·4π ≈ 1e-7 of probability here, i.e. 0.03 of an
    /// expected count out of 300 000 samples — far below the test's resolution.
    pub fn chi2_at(name: &str, b: &(impl Bxdf + Sync), thetas: &[f32], num_tests: u32) {
        for &theta in thetas {
            let wo = spherical_direction(theta, 0.7);
            let mut rng = crate::sampling::Rng::new(17, 0, 0);
            let peak = (0..2000)
                .filter_map(|_| b.sample(wo, rng.next_f32(), rng.next_2d(), TransportMode::Radiance))
                .map(|s| s.pdf as f64)
                .fold(0.0, f64::max);
            let floor = 1e-9 * peak;
            let mut t = Chi2Test::new(&format!("{name}_{theta:.2}"), 300_000, 10);
            t.num_tests = num_tests;
            // 8 × 8 sub-cells per cell before the harness's adaptive refinement (its default 4 is
            // too coarse for the n = 120 lobes). Incidence angles are chosen so that sharp lobes
            // are centred on the pole or well away from it: a sharp lobe in the flank of the pole
            // is not smooth in the harness's (cos θ, φ) cells and its cell integrals err by ~1e-3
            // (seen at θo = 0.2, n = 120), which 300 000 samples detect.
            t.quad_subdiv = 8;
            let r = t.run3(&SphereFn3 {
                sample: &|u, uc| b.sample(wo, uc, u, TransportMode::Radiance).map(|s| s.wi),
                pdf: &|wi| {
                    let p = b.pdf(wo, wi, TransportMode::Radiance) as f64;
                    if p < floor { 0.0 } else { p }
                },
            });
            eprintln!("chi2 {name} θo = {theta}: p = {:.4} (threshold {:.2e})", r.p_value, r.threshold);
            assert!(r.passed, "{name} θo = {theta}: {r:?}");
        }
    }

    /// Sample/eval/pdf consistency: a sample's `f` and `pdf` equal `eval` and `pdf` at its `wi`.
    pub fn sample_consistency(b: &impl Bxdf, theta: f32) {
        let wo = spherical_direction(theta, 0.3);
        let mut rng = crate::sampling::Rng::new(5, 0, 0);
        let mut ok = 0;
        for _ in 0..2000 {
            if let Some(s) = b.sample(wo, rng.next_f32(), rng.next_2d(), TransportMode::Radiance) {
                let f = b.eval(wo, s.wi, TransportMode::Radiance);
                let p = b.pdf(wo, s.wi, TransportMode::Radiance);
                assert!((f[0] - s.f[0]).abs() <= 1e-4 * f[0].abs().max(1e-6), "f {f:?} vs {:?}", s.f);
                assert!((p - s.pdf).abs() <= 1e-4 * p.max(1e-6), "pdf {p} vs {}", s.pdf);
                assert!(s.wi.z > 0.0 && (s.wi.length() - 1.0).abs() < 1e-4);
                ok += 1;
            }
        }
        assert!(ok > 100, "only {ok} successful samples");
    }

    /// Helmholtz reciprocity on a fixed set of direction pairs: |f(a,b) − f(b,a)| ≤ 1e-5·max.
    pub fn reciprocity(b: &impl Bxdf) {
        let mut rng = crate::sampling::Rng::new(9, 0, 0);
        for _ in 0..500 {
            let a = crate::sampling::square_to_uniform_hemisphere(rng.next_2d());
            let c = crate::sampling::square_to_uniform_hemisphere(rng.next_2d());
            let f1 = b.eval(a, c, TransportMode::Radiance)[0];
            let f2 = b.eval(c, a, TransportMode::Importance)[0];
            // f32 rounding of the two (algebraically equal) cosines; 1e-4 relative is ~1000 ulp
            assert!((f1 - f2).abs() <= 1e-4 * f1.abs().max(f2.abs()) + 1e-7, "{f1} vs {f2} at {a} {c}");
        }
        // black below the horizon
        assert!(b.eval(Vec3::new(0.0, 0.6, -0.8), Vec3::Z, TransportMode::Radiance).is_black());
    }
}
