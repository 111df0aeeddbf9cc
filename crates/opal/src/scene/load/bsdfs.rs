//! Mitsuba 3's metal and coating BSDF plugins for the loader: `conductor`, `roughconductor`,
//! `plastic`, `roughplastic`, `thindielectric`, with Mitsuba's parameter names and defaults
//! (listed in `docs/scene-format.md`):
//!
//! * indices of refraction (`int_ior`, `ext_ior`) as a number or a Mitsuba name
//!   ([`crate::bsdf::ior::dielectric_ior`]; defaults `polypropylene`/`bk7` and `air`);
//! * conductors: `material` (default `none` = perfect mirror, else a name of
//!   [`crate::bsdf::ior::conductor_ior`]) or explicit `eta`/`k` (defaults 0 and 1 when either is
//!   given, i.e. `F = 1`), never both; `specular_reflectance` (default 1);
//! * microfacets: `distribution` (`beckmann`, the default, or `ggx`), `alpha` (default 0.1) or,
//!   for `roughconductor`, `alpha_u`/`alpha_v`; `sample_visible` (default true; Opal always samples
//!   visible normals, which only changes the noise, so `false` is accepted and noted);
//! * plastics: `diffuse_reflectance` (colour or bitmap, default 0.5), `specular_reflectance`,
//!   `nonlinear` (default false).
//!
//! Tests: `crates/opal/tests/scene_load.rs` (each plugin, defaults, error cases).

use super::plugins::Object;
use super::properties::Props;
use super::xml::Elem;
use crate::bsdf::conductor::ConductorFresnel;
use crate::bsdf::ior::{conductor_ior, conductor_names, dielectric_ior};
use crate::bsdf::microfacet::{AnisoBase, Anisotropic, Beckmann, Ggx, Ndfs};
use crate::bsdf::rough_dielectric::Shadowing;
use crate::bsdf::{Bxdfs, Plastic, RoughConductor, RoughPlastic, SmoothConductor, ThinDielectric};
use crate::error::Result;
use crate::scene::desc::{BsdfDesc, TextureDesc};
use crate::spectrum::Spectrum;

/// `name` as an index of refraction: a positive number or a Mitsuba material name.
fn ior(e: &Elem, p: &mut Props, name: &str, default: f32) -> Result<f32> {
    if let Some((s, l)) = p.string_at_opt(name) {
        return dielectric_ior(&s).ok_or_else(|| {
            l.err(format!(
                "{}: `{name}` \"{s}\" is not a known material (known: {})",
                e.describe(),
                crate::bsdf::ior::dielectric_names().join(", ")
            ))
        });
    }
    match p.float_at(name)? {
        None => Ok(default),
        Some((v, _)) if v.is_finite() && v > 0.0 => Ok(v as f32),
        Some((v, l)) => Err(l.err(format!("{}: `{name}` must be a positive number, got {v}", e.describe()))),
    }
}

/// A constant colour parameter that must be finite and ≥ 0.
fn colour(e: &Elem, p: &mut Props, name: &str, default: Spectrum) -> Result<Spectrum> {
    match p.color(name)? {
        None => Ok(default),
        Some((c, _)) if c.is_finite() && c.0.iter().all(|&v| v >= 0.0) => Ok(c),
        Some((c, l)) => {
            Err(l.err(format!("{}: `{name}` must be finite and ≥ 0, got {:?}", e.describe(), c.0)))
        }
    }
}

/// The conductor's Fresnel term from `material` or `eta`/`k`.
fn conductor_fresnel(e: &Elem, p: &mut Props) -> Result<ConductorFresnel> {
    let material = p.string_at("material")?;
    let eta = p.color("eta")?;
    let k = p.color("k")?;
    if let Some((m, l)) = &material
        && m != "none"
    {
        if eta.is_some() || k.is_some() {
            return Err(l.err(format!(
                "{}: give either `material` or `eta`/`k`, not both (as Mitsuba)",
                e.describe()
            )));
        }
        let (eta, k) = conductor_ior(m).ok_or_else(|| {
            l.err(format!(
                "{}: material \"{m}\" is not known (known: none, {})",
                e.describe(),
                conductor_names().join(", ")
            ))
        })?;
        return Ok(ConductorFresnel::Complex { eta: Spectrum(eta), k: Spectrum(k) });
    }
    let eta = eta.map_or(Spectrum::ZERO, |c| c.0);
    let k = k.map_or(Spectrum::ONE, |c| c.0);
    if !(eta.is_finite() && k.is_finite()) || eta.0.iter().chain(&k.0).any(|&v| v < 0.0) {
        return Err(e.loc.err(format!("{}: `eta` and `k` must be finite and ≥ 0", e.describe())));
    }
    // η = 0, κ = 1 (Mitsuba's defaults): |r| = 1 at every angle, the perfect mirror
    Ok(if eta == Spectrum::ZERO && k == Spectrum::ONE {
        ConductorFresnel::Mirror
    } else {
        ConductorFresnel::Complex { eta, k }
    })
}

/// `distribution` and roughness: `alpha`, or `alpha_u`/`alpha_v` when `anisotropic`.
fn microfacet(e: &Elem, p: &mut Props, anisotropic: bool, warnings: &mut Vec<String>) -> Result<Ndfs> {
    let dist = p.string_at("distribution")?;
    let base = match dist.as_ref().map(|(s, _)| s.as_str()) {
        None | Some("beckmann") => AnisoBase::Beckmann,
        Some("ggx") => AnisoBase::Ggx,
        Some(s) => {
            let l = &dist.as_ref().unwrap().1;
            return Err(
                l.err(format!("{}: distribution \"{s}\" is not supported (beckmann, ggx)", e.describe()))
            );
        }
    };
    let mut rough = |name: &str| -> Result<Option<f32>> {
        match p.float_at(name)? {
            None => Ok(None),
            Some((v, _)) if v.is_finite() && v > 0.0 && v <= 10.0 => Ok(Some(v as f32)),
            Some((v, l)) => Err(l.err(format!("{}: `{name}` must be in (0, 10], got {v}", e.describe()))),
        }
    };
    let alpha = rough("alpha")?;
    let (au, av) = if anisotropic { (rough("alpha_u")?, rough("alpha_v")?) } else { (None, None) };
    if let Some(false) = p.bool("sample_visible")? {
        warnings.push(format!(
            "{}:{}: {}: sample_visible=false: Opal samples visible normals (same expectation, less noise)",
            e.loc.file.display(),
            e.loc.line,
            e.describe()
        ));
    }
    let (au, av) = match (alpha, au, av) {
        (a, None, None) => {
            let a = a.unwrap_or(0.1);
            (a, a)
        }
        (None, Some(u), Some(v)) => (u, v),
        _ => {
            return Err(e
                .loc
                .err(format!("{}: give either `alpha` or both `alpha_u` and `alpha_v`", e.describe())));
        }
    };
    Ok(if au == av {
        match base {
            AnisoBase::Beckmann => Ndfs::Beckmann(Beckmann::new(au)?),
            AnisoBase::Ggx => Ndfs::Ggx(Ggx::new(au)?),
        }
    } else {
        Ndfs::Anisotropic(Anisotropic::new(base, au, av)?)
    })
}

/// Mean of a diffuse reflectance over channels (and texels), for the sampling weight.
fn texture_mean(t: &TextureDesc) -> f32 {
    match t {
        TextureDesc::Constant(c) => c.average(),
        TextureDesc::Bitmap(b) => {
            let d = &b.image.data;
            (d.iter().map(|v| v.average() as f64).sum::<f64>() / d.len().max(1) as f64) as f32
        }
    }
}

/// `bsdf type="conductor" | "roughconductor" | "plastic" | "roughplastic" | "thindielectric"`.
pub(super) fn bsdf_mitsuba_material(
    e: &Elem,
    ty: &str,
    mut p: Props,
    warnings: &mut Vec<String>,
) -> Result<Object> {
    let ctx = |err: crate::Error| e.loc.err(format!("{}: {err}", e.describe()));
    let desc = match ty {
        "conductor" => {
            let fresnel = conductor_fresnel(e, &mut p)?;
            let ks = colour(e, &mut p, "specular_reflectance", Spectrum::ONE)?;
            p.finish("material, eta, k, specular_reflectance")?;
            BsdfDesc::Lobe(Bxdfs::SmoothConductor(SmoothConductor::new(fresnel, ks)))
        }
        "roughconductor" => {
            let fresnel = conductor_fresnel(e, &mut p)?;
            let ks = colour(e, &mut p, "specular_reflectance", Spectrum::ONE)?;
            let ndf = microfacet(e, &mut p, true, warnings)?;
            p.finish(
                "material, eta, k, specular_reflectance, distribution, alpha, alpha_u, alpha_v, sample_visible",
            )?;
            BsdfDesc::Lobe(Bxdfs::RoughConductor(RoughConductor::new(
                ndf,
                fresnel,
                ks,
                Shadowing::SeparableMitsuba,
            )))
        }
        "plastic" | "roughplastic" => {
            let int_ior = ior(e, &mut p, "int_ior", 1.49)?;
            let ext_ior = ior(e, &mut p, "ext_ior", 1.000277)?;
            let kd = p.texture("diffuse_reflectance")?.unwrap_or(TextureDesc::Constant(Spectrum::splat(0.5)));
            if let TextureDesc::Constant(c) = &kd
                && (!c.is_finite() || c.0.iter().any(|&v| v < 0.0))
            {
                return Err(e.loc.err(format!("{}: diffuse_reflectance {:?}", e.describe(), c.0)));
            }
            let ks = colour(e, &mut p, "specular_reflectance", Spectrum::ONE)?;
            let nonlinear = p.bool("nonlinear")?.unwrap_or(false);
            let mean = texture_mean(&kd);
            let kd_const = match &kd {
                TextureDesc::Constant(c) => *c,
                TextureDesc::Bitmap(_) => Spectrum::splat(mean),
            };
            let eta = int_ior / ext_ior;
            let model = if ty == "plastic" {
                p.finish("int_ior, ext_ior, diffuse_reflectance, specular_reflectance, nonlinear")?;
                Bxdfs::Plastic(Plastic::new(eta, kd_const, mean, ks, nonlinear).map_err(ctx)?)
            } else {
                let ndf = microfacet(e, &mut p, false, warnings)?;
                p.finish(
                    "int_ior, ext_ior, diffuse_reflectance, specular_reflectance, nonlinear, distribution, alpha, sample_visible",
                )?;
                Bxdfs::RoughPlastic(RoughPlastic::new(ndf, eta, kd_const, mean, ks, nonlinear).map_err(ctx)?)
            };
            match kd {
                TextureDesc::Constant(_) => BsdfDesc::Lobe(model),
                t @ TextureDesc::Bitmap(_) => BsdfDesc::Coated { model, diffuse: t },
            }
        }
        "thindielectric" => {
            let int_ior = ior(e, &mut p, "int_ior", 1.5046)?;
            let ext_ior = ior(e, &mut p, "ext_ior", 1.000277)?;
            let r = colour(e, &mut p, "specular_reflectance", Spectrum::ONE)?;
            let t = colour(e, &mut p, "specular_transmittance", Spectrum::ONE)?;
            p.finish("int_ior, ext_ior, specular_reflectance, specular_transmittance")?;
            BsdfDesc::Lobe(Bxdfs::ThinDielectric(ThinDielectric::new(int_ior / ext_ior, r, t).map_err(ctx)?))
        }
        _ => unreachable!("dispatch routes only these types here"),
    };
    Ok(Object::Bsdf(desc))
}
