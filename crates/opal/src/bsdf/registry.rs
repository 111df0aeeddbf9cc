//! Names → models: the one place that turns a model name and its parameters into a [`Bxdfs`].
//! The CLI (`opal brdf`), the energy checker (`opal_inverse::brdf_energy`) and the scene
//! loader share it.
//!
//! Two levels:
//! * **Plugins** ([`PluginParams`], [`build_plugin`]): Mitsuba-XML style `<bsdf type="...">` with
//!   named float / string / rgb parameters. Method-B plugins: `phong`, `blinn`, `schlick`, `lyon`,
//!   `pow16`, `microfacet_conductor` (and `diffuse` for Lambert), documented in `docs/scene-format.md`, section
//!   "Method-B lobe plugins".
//! * **Models** ([`ModelInfo`], [`ModelSpec`]): the CLI's names (`pow16`, `blinn-exact`, ...),
//!   each a plugin with some string parameters fixed, plus the one parameter a reflectance
//!   sweep varies (`n`, or `albedo` for Lambert) with its default range.
//!
//! Normalisation strings: `"none"`, a named analytic normalisation (`"phong"` for Phong,
//! `"approx"`/`"exact"` for Blinn–Phong, `"paper"` = `(n+6)/24.55` for pow16), or any
//! [`NormExpr`] in `n`, `A`, `B` (float parameters `A`, `B`, defaults 6 and 24.55).
//! Tests: below (every model builds, bad names / values are refused with a clear message).

use super::conductor::{ConductorFresnel, RoughConductor};
use super::lobe::LobeForm;
use super::microfacet::{Beckmann, Ggx, Ndfs};
use super::normexpr::NormExpr;
use super::pow16::{PAPER_A, PAPER_B};
use super::rough_dielectric::Shadowing;
use super::{Blinn, Bxdfs, Lambert, Lyon, Phong, Pow16, RoughDielectric, RoughDielectricMs, Schlick};
use crate::error::{Error, Result};
use crate::spectrum::Spectrum;
use std::collections::BTreeMap;

/// A plugin parameter value.
#[derive(Clone, Debug, PartialEq)]
pub enum ParamValue {
    /// `<float name=... value=.../>` (also integers).
    Float(f64),
    /// `<string name=... value=.../>`.
    Str(String),
    /// `<rgb name=... value=.../>`.
    Rgb(Spectrum),
}

/// A plugin with its named parameters (what one `<bsdf type="...">` element holds).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PluginParams {
    /// Plugin type (`"pow16"`, ...).
    pub plugin: String,
    /// Named parameters.
    pub values: BTreeMap<String, ParamValue>,
}

impl PluginParams {
    /// No parameters yet.
    pub fn new(plugin: &str) -> Self {
        PluginParams { plugin: plugin.to_string(), values: BTreeMap::new() }
    }
    /// Sets a parameter (builder style).
    pub fn with(mut self, name: &str, v: ParamValue) -> Self {
        self.values.insert(name.to_string(), v);
        self
    }
    fn what(&self, name: &str) -> String {
        format!("parameter '{name}' of bsdf '{}'", self.plugin)
    }
    fn float(&self, name: &str, default: Option<f64>) -> Result<f64> {
        match self.values.get(name) {
            Some(ParamValue::Float(v)) if v.is_finite() => Ok(*v),
            Some(ParamValue::Float(v)) => {
                Err(Error::invalid(self.what(name), format!("must be finite, got {v}")))
            }
            Some(other) => Err(Error::invalid(self.what(name), format!("must be a float, got {other:?}"))),
            None => default.ok_or_else(|| Error::invalid(self.what(name), "is required")),
        }
    }
    fn string(&self, name: &str, default: &str) -> Result<String> {
        match self.values.get(name) {
            Some(ParamValue::Str(s)) => Ok(s.clone()),
            Some(other) => Err(Error::invalid(self.what(name), format!("must be a string, got {other:?}"))),
            None => Ok(default.to_string()),
        }
    }
    fn spectrum(&self, name: &str, default: Spectrum) -> Result<Spectrum> {
        let s = match self.values.get(name) {
            Some(ParamValue::Rgb(s)) => *s,
            Some(ParamValue::Float(v)) => Spectrum::splat(*v as f32),
            Some(other) => {
                return Err(Error::invalid(self.what(name), format!("must be rgb or float, got {other:?}")));
            }
            None => default,
        };
        if !s.is_finite() || s.0.iter().any(|c| *c < 0.0) {
            return Err(Error::invalid(self.what(name), format!("must be finite and ≥ 0, got {:?}", s.0)));
        }
        Ok(s)
    }
    fn form(&self, default: LobeForm) -> Result<LobeForm> {
        let s = self.string("form", default.name())?;
        LobeForm::parse(&s).ok_or_else(|| {
            Error::invalid(self.what("form"), format!("must be \"phong\" or \"blinn\", got \"{s}\""))
        })
    }
    /// Normalisation factor from the `normalisation` string (named ones handled by `named`).
    fn norm(&self, n: f64, named: &dyn Fn(&str) -> Option<f64>) -> Result<f64> {
        let s = self.string("normalisation", "none")?;
        let c = if s == "none" {
            1.0
        } else if let Some(c) = named(&s) {
            c
        } else {
            let e = NormExpr::parse(&s)?;
            e.eval(n, self.float("A", Some(PAPER_A))?, self.float("B", Some(PAPER_B))?)
        };
        if !(c.is_finite() && c >= 0.0) {
            return Err(Error::invalid(
                self.what("normalisation"),
                format!("\"{s}\" gives {c} at exponent {n}: must be finite and ≥ 0"),
            ));
        }
        Ok(c)
    }
}

/// The plugin names (`diffuse`, the method-B lobes, method A's `roughdielectric`), in
/// documentation order.
pub const PLUGINS: &[&str] =
    &["diffuse", "phong", "blinn", "schlick", "lyon", "pow16", "microfacet_conductor", "roughdielectric"];

/// Parameters of the `roughdielectric` plugin (any other is an error).
pub const ROUGHDIELECTRIC_PARAMS: &[&str] =
    &["distribution", "alpha", "int_ior", "ext_ior", "scattering", "shadowing"];

impl PluginParams {
    /// A refractive index: a float > 0 or a name of Mitsuba's table ([`crate::bsdf::ior::dielectric_ior`]).
    fn ior(&self, name: &str, default: f64) -> Result<f64> {
        let v = match self.values.get(name) {
            None => default,
            Some(ParamValue::Float(v)) => *v,
            Some(ParamValue::Str(s)) => {
                crate::bsdf::ior::dielectric_ior(s).map(f64::from).ok_or_else(|| {
                    Error::invalid(
                        self.what(name),
                        format!(
                            "unknown material \"{s}\"; give a number or one of {}",
                            crate::bsdf::ior::dielectric_names().join(", ")
                        ),
                    )
                })?
            }
            Some(other) => {
                return Err(Error::invalid(
                    self.what(name),
                    format!("must be a float or a name, got {other:?}"),
                ));
            }
        };
        if !(v.is_finite() && v > 0.0) {
            return Err(Error::invalid(self.what(name), format!("must be finite and > 0, got {v}")));
        }
        Ok(v)
    }

    /// Method A's rough dielectric interface (`roughdielectric`).
    fn rough_dielectric(&self) -> Result<Bxdfs> {
        if let Some(k) = self.values.keys().find(|k| !ROUGHDIELECTRIC_PARAMS.contains(&k.as_str())) {
            return Err(Error::invalid(
                format!("bsdf '{}'", self.plugin),
                format!("unknown parameter '{k}' (supported: {})", ROUGHDIELECTRIC_PARAMS.join(", ")),
            ));
        }
        let alpha = self.float("alpha", Some(0.1))?;
        if !(alpha > 0.0 && alpha <= 10.0) {
            return Err(Error::invalid(self.what("alpha"), format!("must be in (0, 10], got {alpha}")));
        }
        let ndf = self.distribution(alpha, "beckmann")?;
        let (int_ior, ext_ior) = (self.ior("int_ior", 1.5046)?, self.ior("ext_ior", 1.000277)?);
        let eta = int_ior / ext_ior;
        if (eta - 1.0).abs() < 1e-4 {
            return Err(Error::invalid(
                self.what("int_ior/ext_ior"),
                format!(
                    "int_ior {int_ior} / ext_ior {ext_ior} = {eta}: an index-matched interface is invisible"
                ),
            ));
        }
        let sc = self.string("scattering", "single")?;
        let shadowing = self.shadowing()?;
        Ok(match sc.as_str() {
            "single" => Bxdfs::RoughDielectric(RoughDielectric::new(ndf, eta as f32, shadowing)?),
            "multiple" => {
                if shadowing != Shadowing::HeightCorrelated && self.values.contains_key("shadowing") {
                    return Err(Error::invalid(
                        self.what("shadowing"),
                        "with scattering \"multiple\" the random walk's masking is height-correlated \
                         by construction: give \"height_correlated\" or leave it out",
                    ));
                }
                Bxdfs::RoughDielectricMs(RoughDielectricMs::new(ndf, eta as f32)?)
            }
            _ => {
                return Err(Error::invalid(
                    self.what("scattering"),
                    format!("must be \"single\" or \"multiple\", got \"{sc}\""),
                ));
            }
        })
    }

    /// `distribution` = `ggx` | `beckmann` at roughness `alpha`.
    fn distribution(&self, alpha: f64, default: &str) -> Result<Ndfs> {
        let dist = self.string("distribution", default)?;
        Ok(match dist.as_str() {
            "ggx" => Ndfs::Ggx(Ggx::new(alpha as f32)?),
            "beckmann" => Ndfs::Beckmann(Beckmann::new(alpha as f32)?),
            _ => {
                return Err(Error::invalid(
                    self.what("distribution"),
                    format!("must be \"ggx\" or \"beckmann\", got \"{dist}\""),
                ));
            }
        })
    }

    /// `shadowing` = `separable` (default) | `height_correlated`.
    fn shadowing(&self) -> Result<Shadowing> {
        let sh = self.string("shadowing", "separable")?;
        match sh.as_str() {
            "separable" => Ok(Shadowing::Separable),
            "height_correlated" => Ok(Shadowing::HeightCorrelated),
            _ => Err(Error::invalid(
                self.what("shadowing"),
                format!("must be \"separable\" or \"height_correlated\", got \"{sh}\""),
            )),
        }
    }
}

/// Builds a model from a plugin description.
pub fn build_plugin(p: &PluginParams) -> Result<Bxdfs> {
    let ks = || p.spectrum("specular_reflectance", Spectrum::ONE);
    let exponent = |min_incl: bool| -> Result<f64> {
        let n = p.float("exponent", Some(10.0))?;
        let ok = if min_incl { n >= 0.0 } else { n > 0.0 };
        if !ok || n > 1e7 {
            let rel = if min_incl { "≥ 0" } else { "> 0" };
            return Err(Error::invalid(p.what("exponent"), format!("must be {rel} and ≤ 1e7, got {n}")));
        }
        Ok(n)
    };
    Ok(match p.plugin.as_str() {
        "diffuse" | "lambert" => {
            Bxdfs::Lambert(Lambert::new(p.spectrum("reflectance", Spectrum::splat(0.5))?))
        }
        "phong" => {
            let n = exponent(true)?;
            let c = p.norm(n, &|s| (s == "phong").then(|| Phong::normalised_factor(n)))?;
            Bxdfs::Phong(Phong::new(n, c, ks()?))
        }
        "blinn" => {
            let n = exponent(true)?;
            let c = p.norm(n, &|s| match s {
                "approx" => Some(Blinn::approx_factor(n)),
                "exact" => Some(Blinn::exact_factor(n)),
                _ => None,
            })?;
            Bxdfs::Blinn(Blinn::new(n, c, ks()?))
        }
        "schlick" => {
            let n = exponent(false)?;
            let c = p.norm(n, &|_| None)?;
            Bxdfs::Schlick(Schlick::new(n, p.form(LobeForm::Blinn)?, c, ks()?))
        }
        "lyon" => {
            let n = exponent(false)?;
            let w = p.float("w", Some(2.0))?;
            if !(w.fract() == 0.0 && (0.0..=10.0).contains(&w)) {
                return Err(Error::invalid(p.what("w"), format!("must be an integer in 0..=10, got {w}")));
            }
            let c = p.norm(n, &|_| None)?;
            Bxdfs::Lyon(Lyon::new(n, w as u32, p.form(LobeForm::Blinn)?, c, ks()?))
        }
        "pow16" => {
            let n = exponent(false)?;
            let c = p.norm(n, &|s| (s == "paper").then(|| Pow16::paper_factor(n, PAPER_A, PAPER_B)))?;
            Bxdfs::Pow16(Pow16::new(n, p.form(LobeForm::Blinn)?, c, ks()?))
        }
        "microfacet_conductor" => {
            let alpha = p.float("alpha", Some(0.1))?;
            if !(alpha > 0.0 && alpha <= 10.0) {
                return Err(Error::invalid(p.what("alpha"), format!("must be in (0, 10], got {alpha}")));
            }
            let ndf = p.distribution(alpha, "ggx")?;
            let fresnel = match (p.values.contains_key("eta"), p.values.contains_key("k")) {
                (false, false) => ConductorFresnel::Mirror,
                (true, true) => ConductorFresnel::Complex {
                    eta: p.spectrum("eta", Spectrum::ONE)?,
                    k: p.spectrum("k", Spectrum::ZERO)?,
                },
                _ => {
                    return Err(Error::invalid(
                        p.what("eta/k"),
                        "give both the real part 'eta' and the extinction 'k' (or neither: F = 1)",
                    ));
                }
            };
            let shadowing = p.shadowing()?;
            Bxdfs::RoughConductor(RoughConductor::new(ndf, fresnel, ks()?, shadowing))
        }
        "roughdielectric" => p.rough_dielectric()?,
        other => {
            return Err(Error::invalid(
                format!("bsdf type '{other}'"),
                format!("unknown; plugins are {}", PLUGINS.join(", ")),
            ));
        }
    })
}

/// A model as the CLI and the checker name it.
#[derive(Clone, Copy, Debug)]
pub struct ModelInfo {
    /// CLI name (`"pow16"`, `"blinn-exact"`, ...).
    pub name: &'static str,
    /// Plugin it builds.
    pub plugin: &'static str,
    /// String parameters the name fixes (`normalisation`, `form`).
    pub fixed: &'static [(&'static str, &'static str)],
    /// Name of the swept parameter on the CLI (`"n"`, `"albedo"`, `"alpha"`).
    pub param: &'static str,
    /// Its name in the plugin (`"exponent"`, `"reflectance"`, `"alpha"`).
    pub plugin_param: &'static str,
    /// Default sweep range.
    pub default_range: (f64, f64),
    /// Whether the parameter is naturally swept on a log scale.
    pub log_scale: bool,
    /// One-line description.
    pub description: &'static str,
}

impl ModelInfo {
    /// Whether a normalisation expression may be applied (lobes with an exponent `n`).
    pub fn accepts_norm(&self) -> bool {
        self.plugin_param == "exponent"
    }
}

const fn lobe(
    name: &'static str,
    plugin: &'static str,
    fixed: &'static [(&'static str, &'static str)],
    description: &'static str,
) -> ModelInfo {
    ModelInfo {
        name,
        plugin,
        fixed,
        param: "n",
        plugin_param: "exponent",
        default_range: (1.0, 1000.0),
        log_scale: true,
        description,
    }
}

static MODELS: &[ModelInfo] = &[
    ModelInfo {
        name: "lambert",
        plugin: "diffuse",
        fixed: &[],
        param: "albedo",
        plugin_param: "reflectance",
        default_range: (0.0, 1.0),
        log_scale: false,
        description: "Lambertian diffuse, f = albedo/π",
    },
    lobe("phong", "phong", &[], "Phong cos^n(V·R), raw"),
    lobe("phong-norm", "phong", &[("normalisation", "phong")], "Phong cos^n(V·R) · (n+2)/(2π)"),
    lobe("blinn", "blinn", &[], "Blinn–Phong cos^n(N·H), raw"),
    lobe("blinn-approx", "blinn", &[("normalisation", "approx")], "Blinn–Phong · (n+8)/(8π)"),
    lobe(
        "blinn-exact",
        "blinn",
        &[("normalisation", "exact")],
        "Blinn–Phong · (n+2)(n+4)/(8π(2^(−n/2)+n)) (exact at normal incidence)",
    ),
    lobe("schlick", "schlick", &[("form", "blinn")], "Schlick rational t/(n−nt+t), t = N·H"),
    lobe("schlick-phong", "schlick", &[("form", "phong")], "Schlick rational t/(n−nt+t), t = V·R"),
    lobe("lyon", "lyon", &[("form", "blinn")], "Lyon (1 − n(1−t)/4)^4, t = N·H"),
    lobe("lyon-phong", "lyon", &[("form", "phong")], "Lyon (1 − n(1−t)/4)^4, t = V·R"),
    lobe("pow16", "pow16", &[("form", "blinn")], "pow16 (n/16(t−1)+1)^16, t = N·H (θ = θ_h), raw"),
    lobe("pow16-phong", "pow16", &[("form", "phong")], "pow16 (n/16(t−1)+1)^16, t = V·R (θ = γ), raw"),
    lobe(
        "pow16-norm",
        "pow16",
        &[("form", "blinn"), ("normalisation", "paper")],
        "pow16 (Blinn form) · (n+6)/24.55, the paper's model",
    ),
    conductor(
        "conductor-ggx",
        &[("distribution", "ggx")],
        "microfacet conductor, GGX, F = 1 (physically based reference)",
    ),
    conductor(
        "conductor-beckmann",
        &[("distribution", "beckmann")],
        "microfacet conductor, Beckmann, F = 1 (physically based reference)",
    ),
];

const fn conductor(
    name: &'static str,
    fixed: &'static [(&'static str, &'static str)],
    description: &'static str,
) -> ModelInfo {
    ModelInfo {
        name,
        plugin: "microfacet_conductor",
        fixed,
        param: "alpha",
        plugin_param: "alpha",
        default_range: (0.02, 1.0),
        log_scale: true,
        description,
    }
}

/// All models the CLI knows.
pub fn models() -> &'static [ModelInfo] {
    MODELS
}

/// The model called `name`.
pub fn find(name: &str) -> Result<&'static ModelInfo> {
    MODELS.iter().find(|m| m.name == name).ok_or_else(|| {
        Error::invalid(
            format!("model '{name}'"),
            format!(
                "unknown; known models: {}",
                MODELS.iter().map(|m| m.name).collect::<Vec<_>>().join(", ")
            ),
        )
    })
}

/// A user-given normalisation: expression and its constants.
#[derive(Clone, Debug, PartialEq)]
pub struct NormSpec {
    /// The expression in `n`, `A`, `B`.
    pub expr: NormExpr,
    /// Constant `A`.
    pub a: f64,
    /// Constant `B`.
    pub b: f64,
}

/// A model plus an optional normalisation override; [`ModelSpec::build`] makes it at a value of
/// the swept parameter.
#[derive(Clone, Debug)]
pub struct ModelSpec {
    /// The model.
    pub info: &'static ModelInfo,
    /// Normalisation replacing the model's own (lobes with an exponent only).
    pub norm: Option<NormSpec>,
}

impl ModelSpec {
    /// The model called `name`, with its own normalisation.
    pub fn new(name: &str) -> Result<Self> {
        Ok(ModelSpec { info: find(name)?, norm: None })
    }
    /// Replaces the normalisation (error for models without an exponent).
    pub fn with_norm(mut self, norm: NormSpec) -> Result<Self> {
        if !self.info.accepts_norm() {
            return Err(Error::invalid(
                format!("normalisation for model '{}'", self.info.name),
                format!("this model has no exponent n (its parameter is '{}')", self.info.param),
            ));
        }
        self.norm = Some(norm);
        Ok(self)
    }
    /// Display name (`pow16`, or `pow16 · (n+A)/B [A=6, B=24.55]`).
    pub fn label(&self) -> String {
        match &self.norm {
            None => self.info.name.to_string(),
            Some(n) => format!("{} · {} [A={}, B={}]", self.info.name, n.expr, n.a, n.b),
        }
    }
    /// Plugin description at parameter value `value`.
    pub fn plugin_params(&self, value: f64) -> PluginParams {
        let mut p =
            PluginParams::new(self.info.plugin).with(self.info.plugin_param, ParamValue::Float(value));
        for (k, v) in self.info.fixed {
            p = p.with(k, ParamValue::Str(v.to_string()));
        }
        if let Some(n) = &self.norm {
            p = p
                .with("normalisation", ParamValue::Str(n.expr.source().to_string()))
                .with("A", ParamValue::Float(n.a))
                .with("B", ParamValue::Float(n.b));
        }
        p
    }
    /// The model at parameter value `value`.
    pub fn build(&self, value: f64) -> Result<Bxdfs> {
        build_plugin(&self.plugin_params(value))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsdf::{Bxdf, TransportMode};
    use crate::math::Vec3;

    #[test]
    fn every_model_builds_and_reflects() {
        for m in models() {
            let s = ModelSpec::new(m.name).unwrap();
            let v = if m.log_scale { (m.default_range.0 * m.default_range.1).sqrt() } else { 0.5 };
            let b = s.build(v).unwrap();
            let wo = Vec3::new(0.3, 0.0, 0.954).normalize();
            let wi = Vec3::new(-0.3, 0.0, 0.954).normalize();
            assert!(b.eval(wo, wi, TransportMode::Radiance)[0] > 0.0, "{}", m.name);
            assert!(b.flags().reflection);
        }
    }

    #[test]
    fn named_and_expression_normalisations_agree() {
        let s = ModelSpec::new("pow16-norm").unwrap();
        let t = ModelSpec::new("pow16")
            .unwrap()
            .with_norm(NormSpec { expr: NormExpr::paper(), a: 6.0, b: 24.55 })
            .unwrap();
        let (wo, wi) = (Vec3::Z, Vec3::new(0.1, 0.0, 0.995).normalize());
        let (a, b) = (s.build(30.0).unwrap(), t.build(30.0).unwrap());
        assert_eq!(a.eval(wo, wi, TransportMode::Radiance), b.eval(wo, wi, TransportMode::Radiance));
        let e = ModelSpec::new("phong").unwrap().with_norm(NormSpec {
            expr: NormExpr::parse("(n+2)/(2*pi)").unwrap(),
            a: 0.0,
            b: 1.0,
        });
        let c = ModelSpec::new("phong-norm").unwrap().build(7.0).unwrap();
        let d = e.unwrap().build(7.0).unwrap();
        assert_eq!(c.eval(wo, wi, TransportMode::Radiance), d.eval(wo, wi, TransportMode::Radiance));
    }

    #[test]
    fn refuses_bad_input() {
        let e = ModelSpec::new("phongg").unwrap_err().to_string();
        assert!(e.contains("phongg") && e.contains("pow16"), "{e}");
        let e = ModelSpec::new("lambert")
            .unwrap()
            .with_norm(NormSpec { expr: NormExpr::paper(), a: 6.0, b: 24.55 })
            .unwrap_err()
            .to_string();
        assert!(e.contains("no exponent"), "{e}");
        let e = ModelSpec::new("pow16").unwrap().build(-1.0).unwrap_err().to_string();
        assert!(e.contains("exponent") && e.contains("-1"), "{e}");
        let p = PluginParams::new("pow16").with("normalisation", ParamValue::Str("(n-A)/B".into()));
        let e = build_plugin(&p.with("exponent", ParamValue::Float(1.0))).unwrap_err().to_string();
        assert!(e.contains("must be finite and ≥ 0"), "{e}");
        let p = PluginParams::new("lyon").with("w", ParamValue::Float(2.5));
        assert!(build_plugin(&p).unwrap_err().to_string().contains("integer"));
        let p = PluginParams::new("schlick").with("form", ParamValue::Str("torrance".into()));
        assert!(build_plugin(&p).unwrap_err().to_string().contains("torrance"));
        assert!(build_plugin(&PluginParams::new("glossy")).is_err());
    }
}
