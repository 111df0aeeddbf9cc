//! Runtime materials: what [`Scene::build`](super::Scene::build) turns each shape's
//! [`BsdfDesc`] into, once, so that a ray hit only looks its material up — no description
//! matched, nothing cloned per hit.
//!
//! * [`Material`]: one per shape. `twosided` becomes a flag; a `diffuse` reflectance becomes a
//!   runtime [`Texture`] (a bitmap's pixels are shared with the description through their
//!   `Arc`, not copied); any other model is stored once as its [`Bxdfs`]. Building it is also
//!   where a material's ranges are validated (errors name the shape).
//! * A coated model (`plastic`, `roughplastic`) with a bitmap diffuse reflectance becomes
//!   [`Material::Coated`]: the model stored once plus the runtime texture; its view
//!   [`Bsdf::Coated`] carries the reflectance looked up at the hit.
//! * [`Bsdf`]: the scattering model at one hit, a `Copy` view returned by
//!   [`Scene::bsdf`](super::Scene::bsdf): a [`Lambert`] with the reflectance looked up at the
//!   hit's uv, or a reference to the shape's [`Bxdfs`]. Before, every hit cloned the `Bxdfs`
//!   (a copy of the whole enum, and for the tabulated, multiple-scattering and numeric-NDF
//!   models an `Arc` count taken and dropped by every thread on every hit).
//!
//! Results are those of the description evaluated per hit, bit for bit (same texture lookup,
//! same models). Tests: below (description → material, the view against the model it refers
//! to, validation messages); renders through [`Scene::bsdf`](super::Scene::bsdf) in
//! `tests/furnace.rs`, the path tracer's and the light tracer's unit tests.

use super::desc::{BsdfDesc, TextureDesc};
use crate::bsdf::{BsdfSample, Bxdf, BxdfFlags, Bxdfs, Lambert, TransportMode};
use crate::error::{Error, Result};
use crate::math::{Vec2, Vec3};
use crate::spectrum::Spectrum;
use crate::texture::Texture;

/// A shape's material as the integrators use it (built once from its [`BsdfDesc`]).
#[derive(Clone, Debug)]
pub enum Material {
    /// Lambertian reflector (Mitsuba `diffuse`).
    Diffuse {
        /// Reflectance ρ.
        reflectance: Texture,
        /// Wrapped in `twosided`: the shading normal faces the outgoing direction.
        two_sided: bool,
    },
    /// A coated model (plastic, rough plastic) with a textured diffuse reflectance.
    Coated {
        /// The model, stored once.
        bxdf: Bxdfs,
        /// Diffuse reflectance, looked up per hit.
        diffuse: Texture,
        /// Wrapped in `twosided`.
        two_sided: bool,
    },
    /// Any other model (a method-B lobe, a dielectric interface, a tabulated face...).
    Model {
        /// The model, stored once.
        bxdf: Bxdfs,
        /// Wrapped in `twosided`: the shading normal faces the outgoing direction.
        two_sided: bool,
    },
}

impl Material {
    /// Resolves and validates the description of shape `id`'s material: `twosided` at most
    /// once and not around a dielectric interface, constant reflectances finite and ≥ 0.
    pub fn new(id: &str, desc: &BsdfDesc) -> Result<Material> {
        let (inner, two_sided) = match desc {
            BsdfDesc::TwoSided(inner) => (inner.as_ref(), true),
            d => (d, false),
        };
        let what = || format!("bsdf of shape '{id}'");
        match inner {
            BsdfDesc::TwoSided(_) => Err(Error::invalid(what(), "twosided inside twosided")),
            BsdfDesc::Lobe(
                Bxdfs::SmoothDielectric(_)
                | Bxdfs::Tabulated(_)
                | Bxdfs::Dotted(_)
                | Bxdfs::ThinDielectric(_),
            ) if two_sided => Err(Error::invalid(
                what(),
                "twosided around a dielectric interface (dielectric, thindielectric, tabulated, blendbsdf): an interface already has two sides (inside = behind the normal)",
            )),
            BsdfDesc::Coated { model, diffuse } => {
                if !matches!(model, Bxdfs::Plastic(_) | Bxdfs::RoughPlastic(_)) {
                    return Err(Error::invalid(
                        what(),
                        "a textured diffuse reflectance needs plastic or roughplastic",
                    ));
                }
                Ok(Material::Coated { bxdf: model.clone(), diffuse: Texture::new(diffuse), two_sided })
            }
            BsdfDesc::Lobe(b) => Ok(Material::Model { bxdf: b.clone(), two_sided }),
            BsdfDesc::Diffuse { reflectance } => {
                if let TextureDesc::Constant(c) = reflectance
                    && (!c.is_finite() || c.0.iter().any(|&v| v < 0.0))
                {
                    return Err(Error::invalid(what(), format!("reflectance {:?}", c.0)));
                }
                Ok(Material::Diffuse { reflectance: Texture::new(reflectance), two_sided })
            }
        }
    }

    /// Whether the model is anisotropic (its shading frame must follow the surface's uv
    /// tangent, see [`super::Scene::bsdf`]).
    #[inline]
    pub fn anisotropic(&self) -> bool {
        matches!(
            self,
            Material::Model {
                bxdf: Bxdfs::RoughConductor(crate::bsdf::RoughConductor {
                    ndf: crate::bsdf::microfacet::Ndfs::Anisotropic(_),
                    ..
                }),
                ..
            }
        )
    }

    /// Whether the material was wrapped in `twosided`.
    #[inline]
    pub fn two_sided(&self) -> bool {
        match self {
            Material::Diffuse { two_sided, .. }
            | Material::Model { two_sided, .. }
            | Material::Coated { two_sided, .. } => *two_sided,
        }
    }

    /// The scattering model at texture coordinates `uv` (in the local shading frame; the
    /// caller orients the frame, see [`Material::two_sided`]).
    #[inline]
    pub fn bsdf(&self, uv: Vec2) -> Bsdf<'_> {
        match self {
            Material::Diffuse { reflectance, .. } => Bsdf::Lambert(Lambert::new(reflectance.eval(uv))),
            Material::Model { bxdf, .. } => Bsdf::Model(bxdf),
            Material::Coated { bxdf, diffuse, .. } => Bsdf::Coated { model: bxdf, kd: diffuse.eval(uv) },
        }
    }

    /// Diffuse reflectance at `uv`, when the material is diffuse.
    pub fn diffuse_albedo(&self, uv: Vec2) -> Option<Spectrum> {
        match self {
            Material::Diffuse { reflectance, .. } => Some(reflectance.eval(uv)),
            Material::Model { .. } | Material::Coated { .. } => None,
        }
    }
}

/// The scattering model at one hit: a view into a [`Material`], cheap to copy.
#[derive(Clone, Copy, Debug)]
pub enum Bsdf<'a> {
    /// A diffuse material's reflectance at the hit.
    Lambert(Lambert),
    /// The material's model.
    Model(&'a Bxdfs),
    /// A coated model with the diffuse reflectance at the hit.
    Coated {
        /// The model ([`Bxdfs::Plastic`] or [`Bxdfs::RoughPlastic`]).
        model: &'a Bxdfs,
        /// Diffuse reflectance at the hit.
        kd: Spectrum,
    },
}

impl Bxdf for Bsdf<'_> {
    #[inline]
    fn eval(&self, wo: Vec3, wi: Vec3, mode: TransportMode) -> Spectrum {
        match self {
            Bsdf::Lambert(b) => b.eval(wo, wi, mode),
            Bsdf::Model(b) => b.eval(wo, wi, mode),
            Bsdf::Coated { model, kd } => match model {
                Bxdfs::Plastic(p) => p.eval_kd(*kd, wo, wi),
                Bxdfs::RoughPlastic(p) => p.eval_kd(*kd, wo, wi),
                b => b.eval(wo, wi, mode),
            },
        }
    }
    #[inline]
    fn pdf(&self, wo: Vec3, wi: Vec3, mode: TransportMode) -> f32 {
        match self {
            Bsdf::Lambert(b) => b.pdf(wo, wi, mode),
            Bsdf::Model(b) => b.pdf(wo, wi, mode),
            Bsdf::Coated { model, .. } => match model {
                Bxdfs::Plastic(p) => p.pdf_dir(wo, wi),
                Bxdfs::RoughPlastic(p) => p.pdf_dir(wo, wi),
                b => b.pdf(wo, wi, mode),
            },
        }
    }
    #[inline]
    fn sample(&self, wo: Vec3, uc: f32, u: Vec2, mode: TransportMode) -> Option<BsdfSample> {
        match self {
            Bsdf::Lambert(b) => b.sample(wo, uc, u, mode),
            Bsdf::Model(b) => b.sample(wo, uc, u, mode),
            Bsdf::Coated { model, kd } => match model {
                Bxdfs::Plastic(p) => p.sample_kd(*kd, wo, uc, u),
                Bxdfs::RoughPlastic(p) => p.sample_kd(*kd, wo, uc, u),
                b => b.sample(wo, uc, u, mode),
            },
        }
    }
    #[inline]
    fn flags(&self) -> BxdfFlags {
        match self {
            Bsdf::Lambert(b) => b.flags(),
            Bsdf::Model(b) | Bsdf::Coated { model: b, .. } => b.flags(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsdf::{Phong, SmoothDielectric};
    use crate::image::Image;
    use crate::sampling::Rng;
    use crate::scene::desc::{BitmapDesc, FilterType, WrapMode};
    use std::sync::Arc;

    fn constant(a: f32) -> BsdfDesc {
        BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(Spectrum::splat(a)) }
    }

    fn bitmap() -> TextureDesc {
        let mut img = Image::new(3, 2);
        for (i, p) in img.data.iter_mut().enumerate() {
            *p = Spectrum::rgb(0.1 * i as f32, 0.5, 1.0 - 0.1 * i as f32);
        }
        TextureDesc::Bitmap(BitmapDesc {
            image: Arc::new(img),
            filter: FilterType::Bilinear,
            wrap: WrapMode::Mirror,
            path: "mem".into(),
        })
    }

    fn dir(rng: &mut Rng) -> Vec3 {
        let v = Vec3::new(rng.next_f32() - 0.5, rng.next_f32() - 0.5, rng.next_f32() - 0.5);
        v.normalize_or_zero()
    }

    /// The view gives the values of the model built per hit from the description (the old
    /// `Scene::bsdf`), bit for bit.
    fn same_as_per_hit_model(view: Bsdf<'_>, model: &Bxdfs, rng: &mut Rng) {
        for _ in 0..200 {
            let (wo, wi) = (dir(rng), dir(rng));
            for mode in [TransportMode::Radiance, TransportMode::Importance] {
                assert_eq!(
                    view.eval(wo, wi, mode).0.map(f32::to_bits),
                    model.eval(wo, wi, mode).0.map(f32::to_bits)
                );
                assert_eq!(view.pdf(wo, wi, mode).to_bits(), model.pdf(wo, wi, mode).to_bits());
                let (uc, u) = (rng.next_f32(), rng.next_2d());
                let (a, b) = (view.sample(wo, uc, u, mode), model.sample(wo, uc, u, mode));
                assert_eq!(a.is_some(), b.is_some());
                if let (Some(a), Some(b)) = (a, b) {
                    assert_eq!(
                        (a.wi, a.f.0, a.pdf.to_bits(), a.flags, a.eta),
                        (b.wi, b.f.0, b.pdf.to_bits(), b.flags, b.eta)
                    );
                }
            }
            assert_eq!(view.flags(), model.flags());
        }
    }

    #[test]
    fn diffuse_materials_look_up_their_reflectance() {
        let mut rng = Rng::new(3, 0, 0);
        for (desc, two_sided) in [
            (constant(0.4), false),
            (BsdfDesc::TwoSided(Box::new(constant(0.7))), true),
            (BsdfDesc::Diffuse { reflectance: bitmap() }, false),
            (BsdfDesc::TwoSided(Box::new(BsdfDesc::Diffuse { reflectance: bitmap() })), true),
        ] {
            let m = Material::new("s", &desc).unwrap();
            assert_eq!(m.two_sided(), two_sided);
            let inner = match &desc {
                BsdfDesc::TwoSided(i) => i.as_ref(),
                d => d,
            };
            let BsdfDesc::Diffuse { reflectance } = inner else { unreachable!() };
            for _ in 0..20 {
                let uv = Vec2::new(rng.next_f32() * 3.0 - 1.0, rng.next_f32() * 3.0 - 1.0);
                let rho = reflectance.eval(uv);
                assert_eq!(m.diffuse_albedo(uv).map(|s| s.0), Some(rho.0));
                let view = m.bsdf(uv);
                assert!(matches!(view, Bsdf::Lambert(l) if l.r.0 == rho.0));
                same_as_per_hit_model(view, &Bxdfs::Lambert(Lambert::new(rho)), &mut rng);
            }
        }
    }

    #[test]
    fn other_models_are_stored_once_and_borrowed() {
        let mut rng = Rng::new(4, 0, 0);
        let phong = Bxdfs::Phong(Phong::new(20.0, 1.0, Spectrum::splat(0.8)));
        let glass = Bxdfs::SmoothDielectric(SmoothDielectric::new(1.5).unwrap());
        for (desc, model, two_sided) in [
            (BsdfDesc::Lobe(phong.clone()), &phong, false),
            (BsdfDesc::TwoSided(Box::new(BsdfDesc::Lobe(phong.clone()))), &phong, true),
            (BsdfDesc::Lobe(glass.clone()), &glass, false),
        ] {
            let m = Material::new("s", &desc).unwrap();
            assert_eq!(m.two_sided(), two_sided);
            assert!(m.diffuse_albedo(Vec2::ZERO).is_none());
            let view = m.bsdf(Vec2::new(0.3, 0.2));
            let Bsdf::Model(b) = view else { panic!("a lobe is not diffuse") };
            let Material::Model { bxdf, .. } = &m else { unreachable!() };
            assert!(std::ptr::eq(b, bxdf), "the view refers to the stored model");
            same_as_per_hit_model(view, model, &mut rng);
        }
    }

    #[test]
    fn invalid_materials_name_the_shape() {
        let glass = || BsdfDesc::Lobe(Bxdfs::SmoothDielectric(SmoothDielectric::new(1.5).unwrap()));
        let cases = [
            (
                BsdfDesc::TwoSided(Box::new(BsdfDesc::TwoSided(Box::new(constant(0.5))))),
                "twosided inside twosided",
            ),
            (BsdfDesc::TwoSided(Box::new(glass())), "dielectric interface"),
            (constant(-0.1), "reflectance"),
            (BsdfDesc::TwoSided(Box::new(constant(f32::NAN))), "reflectance"),
        ];
        for (desc, msg) in cases {
            let e = Material::new("wall", &desc).unwrap_err().to_string();
            assert!(e.contains("shape 'wall'") && e.contains(msg), "{e}");
        }
    }
}
