//! BSDF contract and models.
//!
//! * [`Bxdf`]: a scattering model in the local shading frame (z = shading normal). Both `wo`
//!   and `wi` point *away* from the surface. `eval` returns f(wo, wi) **without** the cosine;
//!   `pdf` is per unit solid angle of `wi`; `sample` draws `wi` given `wo`.
//! * [`TransportMode`]: `Radiance` when tracing from the camera (wo = towards the camera),
//!   `Importance` when tracing from lights (wo = towards the light). Non-symmetric BTDFs
//!   (refraction: the 1/η² radiance scaling) differ between the two.
//! * [`Bxdfs`]: the runtime set (enum, `match` dispatch, no allocation per hit).
//!
//! Models: [`lambert`]; method B lobes [`phong`], [`blinn`], [`schlick`], [`lyon`], [`pow16`],
//! [`conductor`]; method A's rough dielectric interface [`rough_dielectric`] (single
//! scattering) and [`rough_dielectric_ms`] (multiple scattering), NDFs in [`microfacet`];
//! [`dielectric`] (smooth, delta lobes), [`dotted`] (area mixture of two interfaces: rough dots on
//! a polished land), [`tabulated`] (a rough face tabulated from any of
//! them, loaded from `.obsdf` files); Mitsuba's metals and coatings: [`smooth_conductor`]
//! (`conductor`), [`conductor`] with any NDF incl. anisotropic (`roughconductor`), [`plastic`],
//! [`rough_plastic`], [`thin_dielectric`], named indices in [`ior`]
//! (shared machinery in [`lobe`], normalisation expressions in [`normexpr`], names and
//! constructors in [`registry`]). Tests: χ² of sampling vs pdf, reciprocity, albedo (see each model).

pub mod blinn;
pub mod conductor;
pub mod dielectric;
pub mod dotted;
pub mod ior;
pub mod lambert;
pub mod lobe;
pub mod lyon;
pub mod microfacet;
pub mod normexpr;
pub mod phong;
pub mod plastic;
pub mod pow16;
pub mod registry;
pub mod rough_dielectric;
pub mod rough_dielectric_ms;
pub mod rough_plastic;
pub mod schlick;
pub mod smooth_conductor;
pub mod tabulated;
pub mod thin_dielectric;

use crate::math::{Vec2, Vec3};
use crate::spectrum::Spectrum;
pub use blinn::Blinn;
pub use conductor::RoughConductor;
pub use dielectric::SmoothDielectric;
pub use dotted::Dotted;
pub use lambert::Lambert;
pub use lyon::Lyon;
pub use phong::Phong;
pub use plastic::Plastic;
pub use pow16::Pow16;
pub use rough_dielectric::RoughDielectric;
pub use rough_dielectric_ms::RoughDielectricMs;
pub use rough_plastic::RoughPlastic;
pub use schlick::Schlick;
pub use smooth_conductor::SmoothConductor;
pub use tabulated::TabulatedBsdf;
pub use thin_dielectric::ThinDielectric;

/// Which quantity is transported along the path.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum TransportMode {
    /// Radiance, paths traced from the camera.
    #[default]
    Radiance,
    /// Importance (power), paths traced from the light sources.
    Importance,
}

/// Lobe flags of a sample or a model.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct BxdfFlags {
    /// Reflection lobe present / sampled.
    pub reflection: bool,
    /// Transmission lobe present / sampled.
    pub transmission: bool,
    /// Dirac delta (specular): eval/pdf are zero, only `sample` produces it.
    pub specular: bool,
}

/// Result of [`Bxdf::sample`].
#[derive(Clone, Copy, Debug)]
pub struct BsdfSample {
    /// Sampled direction (local frame, away from the surface).
    pub wi: Vec3,
    /// f(wo, wi) without the cosine (for specular lobes: the delta's weight divided by |cos θi|).
    pub f: Spectrum,
    /// Solid-angle pdf of `wi` (for specular lobes: the discrete probability of the lobe).
    pub pdf: f32,
    /// Which lobe was sampled.
    pub flags: BxdfFlags,
    /// Relative index of refraction crossed (1 for reflection).
    pub eta: f32,
}

impl BsdfSample {
    /// Throughput weight f·|cos θi| / pdf.
    #[inline]
    pub fn weight(&self) -> Spectrum {
        if self.pdf > 0.0 { self.f * (self.wi.z.abs() / self.pdf) } else { Spectrum::ZERO }
    }
}

/// A scattering model in the local shading frame.
pub trait Bxdf {
    /// f(wo, wi) without the cosine factor.
    fn eval(&self, wo: Vec3, wi: Vec3, mode: TransportMode) -> Spectrum;
    /// Solid-angle density with which [`Bxdf::sample`] produces `wi` given `wo`.
    fn pdf(&self, wo: Vec3, wi: Vec3, mode: TransportMode) -> f32;
    /// Draws `wi` given `wo`; `uc` selects among lobes, `u` warps the direction.
    fn sample(&self, wo: Vec3, uc: f32, u: Vec2, mode: TransportMode) -> Option<BsdfSample>;
    /// Which lobes the model has.
    fn flags(&self) -> BxdfFlags;
}

/// The runtime set of models.
#[derive(Clone, Debug)]
pub enum Bxdfs {
    /// One-sided Lambertian reflector (Mitsuba `diffuse`).
    Lambert(Lambert),
    /// Phong lobe `cos^n(V·R)` (method B, plugin `phong`).
    Phong(Phong),
    /// Blinn–Phong lobe `cos^n(N·H)` (method B, plugin `blinn`).
    Blinn(Blinn),
    /// Schlick's rational lobe (method B, plugin `schlick`).
    Schlick(Schlick),
    /// Lyon's approximation (method B, plugin `lyon`).
    Lyon(Lyon),
    /// The pow16 approximant (method B, plugin `pow16`).
    Pow16(Pow16),
    /// Rough dielectric interface, single scattering (Walter et al. 2007), any NDF.
    RoughDielectric(RoughDielectric),
    /// Rough dielectric interface, multiple scattering on the micro-surface (Heitz et al.
    /// 2016): exact sampling, stochastic `eval`, approximate `pdf` (see the module).
    RoughDielectricMs(RoughDielectricMs),
    /// Rough conductor, single scattering (method B's physically based reference, plugin
    /// `microfacet_conductor`).
    RoughConductor(RoughConductor),
    /// Smooth dielectric interface, delta reflection and refraction (Mitsuba `dielectric`).
    SmoothDielectric(SmoothDielectric),
    /// Tabulated rough dielectric face, both sides (`.obsdf` file, plugin `tabulated`).
    Tabulated(TabulatedBsdf),
    /// Dotted face: area mixture of two dielectric interfaces (rough dots on a polished or
    /// second rough land; plugin `dotted`).
    Dotted(Dotted),
    /// Smooth conductor, delta reflection (Mitsuba `conductor`).
    SmoothConductor(SmoothConductor),
    /// Smooth plastic: diffuse base under a smooth coating (Mitsuba `plastic`).
    Plastic(Plastic),
    /// Rough plastic: diffuse base under a rough coating (Mitsuba `roughplastic`).
    RoughPlastic(RoughPlastic),
    /// Thin dielectric sheet (Mitsuba `thindielectric`).
    ThinDielectric(ThinDielectric),
}

macro_rules! dispatch {
    ($self:ident, $b:ident => $e:expr) => {
        match $self {
            Bxdfs::Lambert($b) => $e,
            Bxdfs::Phong($b) => $e,
            Bxdfs::Blinn($b) => $e,
            Bxdfs::Schlick($b) => $e,
            Bxdfs::Lyon($b) => $e,
            Bxdfs::Pow16($b) => $e,
            Bxdfs::RoughDielectric($b) => $e,
            Bxdfs::RoughDielectricMs($b) => $e,
            Bxdfs::RoughConductor($b) => $e,
            Bxdfs::SmoothDielectric($b) => $e,
            Bxdfs::Tabulated($b) => $e,
            Bxdfs::Dotted($b) => $e,
            Bxdfs::SmoothConductor($b) => $e,
            Bxdfs::Plastic($b) => $e,
            Bxdfs::RoughPlastic($b) => $e,
            Bxdfs::ThinDielectric($b) => $e,
        }
    };
}

impl Bxdf for Bxdfs {
    #[inline]
    fn eval(&self, wo: Vec3, wi: Vec3, mode: TransportMode) -> Spectrum {
        dispatch!(self, b => b.eval(wo, wi, mode))
    }
    #[inline]
    fn pdf(&self, wo: Vec3, wi: Vec3, mode: TransportMode) -> f32 {
        dispatch!(self, b => b.pdf(wo, wi, mode))
    }
    #[inline]
    fn sample(&self, wo: Vec3, uc: f32, u: Vec2, mode: TransportMode) -> Option<BsdfSample> {
        dispatch!(self, b => b.sample(wo, uc, u, mode))
    }
    #[inline]
    fn flags(&self) -> BxdfFlags {
        dispatch!(self, b => b.flags())
    }
}
