//! Typed properties of plugin elements: the parameter elements (`float integer boolean string
//! rgb spectrum point vector transform`) parsed into [`Val`]s, `<ref id=...>` references to
//! earlier `bsdf`/`texture` objects, nested plugins, and the [`Props`] list a plugin reads
//! them from.
//!
//! Conventions: numbers are split on commas and whitespace; `rgb` takes 3 numbers (or 1,
//! grey); `spectrum` only a single constant (Opal is an RGB renderer); `point`/`vector` take
//! `value="x, y, z"` or `x`/`y`/`z` attributes; `boolean` is `true`/`false` in any case.
//! [`Props`] accessors remove what they read and check the type (an `integer` is accepted
//! where a float is expected, a float or `rgb` where a texture is); [`Props::finish`] rejects
//! whatever the plugin did not read. Every error names the file, line and column.
//!
//! Tests: `crates/opal/tests/scene_load.rs` (every parameter type and its error cases).

use super::plugins::{Loader, Object, PLUGIN_TAGS};
use super::transforms::parse_transform;
use super::xml::{Attr, Elem, Loc};
use crate::error::{Error, Result};
use crate::math::{DMat4, DVec3};
use crate::scene::desc::TextureDesc;
use crate::spectrum::Spectrum;

/// The value of a parameter element, or an object (nested plugin or `<ref>`).
#[derive(Debug)]
pub(super) enum Val {
    Float(f64),
    Int(i64),
    Bool(bool),
    Str(String),
    Rgb(Spectrum),
    Vec3(DVec3),
    Transform(DMat4),
    Obj(Object),
}

impl Val {
    /// The type's name in messages (`float`, `point/vector`, the object's kind, ...).
    pub(super) fn type_name(&self) -> &'static str {
        match self {
            Val::Float(_) => "float",
            Val::Int(_) => "integer",
            Val::Bool(_) => "boolean",
            Val::Str(_) => "string",
            Val::Rgb(_) => "rgb",
            Val::Vec3(_) => "point/vector",
            Val::Transform(_) => "transform",
            Val::Obj(o) => o.kind(),
        }
    }
}

/// A named property with the position of its element.
pub(super) struct Param {
    pub(super) name: String,
    pub(super) val: Val,
    pub(super) loc: Loc,
}

/// Parameters and nested objects of one plugin element. Accessors remove what they read;
/// [`Props::finish`] rejects whatever is left.
pub(super) struct Props {
    pub(super) what: String,
    pub(super) params: Vec<Param>,
    pub(super) objects: Vec<(Object, Loc)>,
}

impl Props {
    fn take(&mut self, name: &str) -> Option<Param> {
        let i = self.params.iter().position(|p| p.name == name)?;
        Some(self.params.remove(i))
    }
    fn type_err(&self, p: &Param, want: &str) -> Error {
        p.loc.err(format!(
            "parameter `{}` of {} must be {want}, got {}",
            p.name,
            self.what,
            p.val.type_name()
        ))
    }
    pub(super) fn float_at(&mut self, name: &str) -> Result<Option<(f64, Loc)>> {
        match self.take(name) {
            None => Ok(None),
            Some(Param { val: Val::Float(v), loc, .. }) => Ok(Some((v, loc))),
            Some(Param { val: Val::Int(v), loc, .. }) => Ok(Some((v as f64, loc))),
            Some(p) => Err(self.type_err(&p, "a float")),
        }
    }
    pub(super) fn int_at(&mut self, name: &str) -> Result<Option<(i64, Loc)>> {
        match self.take(name) {
            None => Ok(None),
            Some(Param { val: Val::Int(v), loc, .. }) => Ok(Some((v, loc))),
            Some(p) => Err(self.type_err(&p, "an integer")),
        }
    }
    pub(super) fn bool(&mut self, name: &str) -> Result<Option<bool>> {
        match self.take(name) {
            None => Ok(None),
            Some(Param { val: Val::Bool(v), .. }) => Ok(Some(v)),
            Some(p) => Err(self.type_err(&p, "a boolean")),
        }
    }
    pub(super) fn string_at(&mut self, name: &str) -> Result<Option<(String, Loc)>> {
        match self.take(name) {
            None => Ok(None),
            Some(Param { val: Val::Str(v), loc, .. }) => Ok(Some((v, loc))),
            Some(p) => Err(self.type_err(&p, "a string")),
        }
    }
    /// The parameter `name` if it is a string (left in place otherwise).
    pub(super) fn string_at_opt(&mut self, name: &str) -> Option<(String, Loc)> {
        let i = self.params.iter().position(|p| p.name == name && matches!(p.val, Val::Str(_)))?;
        match self.params.remove(i) {
            Param { val: Val::Str(v), loc, .. } => Some((v, loc)),
            _ => unreachable!(),
        }
    }
    pub(super) fn point(&mut self, name: &str) -> Result<Option<DVec3>> {
        match self.take(name) {
            None => Ok(None),
            Some(Param { val: Val::Vec3(v), .. }) => Ok(Some(v)),
            Some(p) => Err(self.type_err(&p, "a point")),
        }
    }
    pub(super) fn transform(&mut self, name: &str) -> Result<Option<(DMat4, Loc)>> {
        match self.take(name) {
            None => Ok(None),
            Some(Param { val: Val::Transform(m), loc, .. }) => Ok(Some((m, loc))),
            Some(p) => Err(self.type_err(&p, "a transform")),
        }
    }
    /// A colour: `rgb`, `float`, single-valued `spectrum`.
    pub(super) fn color(&mut self, name: &str) -> Result<Option<(Spectrum, Loc)>> {
        match self.take(name) {
            None => Ok(None),
            Some(Param { val: Val::Rgb(s), loc, .. }) => Ok(Some((s, loc))),
            Some(Param { val: Val::Float(v), loc, .. }) => Ok(Some((Spectrum::splat(v as f32), loc))),
            Some(Param { val: Val::Int(v), loc, .. }) => Ok(Some((Spectrum::splat(v as f32), loc))),
            Some(p) => Err(self.type_err(&p, "an rgb or float colour")),
        }
    }
    /// A colour or a nested/referenced texture.
    pub(super) fn texture(&mut self, name: &str) -> Result<Option<TextureDesc>> {
        match self.take(name) {
            None => Ok(None),
            Some(Param { val: Val::Rgb(s), .. }) => Ok(Some(TextureDesc::Constant(s))),
            Some(Param { val: Val::Float(v), .. }) => {
                Ok(Some(TextureDesc::Constant(Spectrum::splat(v as f32))))
            }
            Some(Param { val: Val::Int(v), .. }) => {
                Ok(Some(TextureDesc::Constant(Spectrum::splat(v as f32))))
            }
            Some(Param { val: Val::Obj(Object::Texture(t)), .. }) => Ok(Some(t)),
            Some(p) => Err(self.type_err(&p, "an rgb/float colour or a texture")),
        }
    }
    /// Removes and returns the nested objects of a kind (unnamed, or named with any name).
    pub(super) fn objects(&mut self, kind: &str) -> Vec<(Object, Loc)> {
        let mut out = Vec::new();
        let mut i = 0;
        while i < self.objects.len() {
            if self.objects[i].0.kind() == kind {
                out.push(self.objects.remove(i));
            } else {
                i += 1;
            }
        }
        let mut i = 0;
        while i < self.params.len() {
            if matches!(&self.params[i].val, Val::Obj(o) if o.kind() == kind) {
                let p = self.params.remove(i);
                if let Val::Obj(o) = p.val {
                    out.push((o, p.loc));
                }
            } else {
                i += 1;
            }
        }
        out
    }
    /// At most one nested object of a kind.
    pub(super) fn object(&mut self, kind: &str) -> Result<Option<(Object, Loc)>> {
        let mut v = self.objects(kind);
        if v.len() > 1 {
            return Err(v[1].1.err(format!("{} accepts one nested <{kind}>, found {}", self.what, v.len())));
        }
        Ok(v.pop())
    }
    pub(super) fn finish(self, supported: &str) -> Result<()> {
        if let Some(p) = self.params.first() {
            let hint = if supported.is_empty() {
                "it takes no parameters".to_string()
            } else {
                format!("supported: {supported}")
            };
            return Err(p.loc.err(format!(
                "unknown parameter `{}` ({}) for {} ({hint})",
                p.name,
                p.val.type_name(),
                self.what
            )));
        }
        if let Some((o, l)) = self.objects.first() {
            return Err(l.err(format!("a nested <{}> is not allowed in {}", o.kind(), self.what)));
        }
        Ok(())
    }
}

pub(super) fn parse_floats(s: &str, loc: &Loc, what: &str) -> Result<Vec<f64>> {
    s.split(|c: char| c == ',' || c.is_whitespace())
        .filter(|t| !t.is_empty())
        .map(|t| match t.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            Ok(_) => Err(loc.err(format!("{what}: `{t}` is not a finite number"))),
            Err(_) => Err(loc.err(format!("{what}: `{t}` is not a number"))),
        })
        .collect()
}

pub(super) fn parse_float(a: &Attr) -> Result<f64> {
    let v = a.value.trim();
    match v.parse::<f64>() {
        Ok(x) if x.is_finite() => Ok(x),
        Ok(_) => Err(a.loc.err(format!("`{v}` is not a finite number"))),
        Err(_) => Err(a.loc.err(format!("`{v}` is not a number"))),
    }
}

/// `value="x, y, z"` or attributes `x`, `y`, `z` (missing ones = `default`).
pub(super) fn parse_xyz(e: &Elem, default: f64, allow_scalar: bool) -> Result<DVec3> {
    if let Some(v) = e.attr("value") {
        if e.attr("x").is_some() || e.attr("y").is_some() || e.attr("z").is_some() {
            return Err(e.loc.err(format!("<{}>: give either `value` or `x`/`y`/`z`, not both", e.tag)));
        }
        let f = parse_floats(&v.value, &v.loc, &e.tag)?;
        return match f.len() {
            3 => Ok(DVec3::new(f[0], f[1], f[2])),
            1 if allow_scalar => Ok(DVec3::splat(f[0])),
            n => Err(v.loc.err(format!("<{}> `value` needs 3 numbers, got {n}", e.tag))),
        };
    }
    let mut out = DVec3::splat(default);
    for (k, n) in ["x", "y", "z"].iter().enumerate() {
        if let Some(a) = e.attr(n) {
            out[k] = parse_float(a)?;
        }
    }
    Ok(out)
}

pub(super) fn parse_vec_attr(a: &Attr) -> Result<DVec3> {
    let f = parse_floats(&a.value, &a.loc, &a.name)?;
    if f.len() != 3 {
        return Err(a.loc.err(format!("`{}` needs 3 numbers, got {}", a.name, f.len())));
    }
    Ok(DVec3::new(f[0], f[1], f[2]))
}

/// Reads a parameter element into a [`Val`].
pub(super) fn parse_param(c: &Elem) -> Result<(String, Val)> {
    let allowed: &[&str] = match c.tag.as_str() {
        "point" | "vector" => &["name", "value", "x", "y", "z"],
        "transform" => &["name"],
        _ => &["name", "value"],
    };
    c.check_attrs(allowed)?;
    let name = c.req("name")?.value.clone();
    if c.tag != "transform" && !c.children.is_empty() {
        return Err(c.children[0].loc.err(format!("<{}> cannot contain <{}>", c.tag, c.children[0].tag)));
    }
    let val = match c.tag.as_str() {
        "float" => Val::Float(parse_float(c.req("value")?)?),
        "integer" => {
            let a = c.req("value")?;
            Val::Int(
                a.value.trim().parse().map_err(|_| a.loc.err(format!("`{}` is not an integer", a.value)))?,
            )
        }
        "boolean" => {
            let a = c.req("value")?;
            match a.value.trim().to_ascii_lowercase().as_str() {
                "true" => Val::Bool(true),
                "false" => Val::Bool(false),
                _ => return Err(a.loc.err(format!("`{}` is not a boolean (true/false)", a.value))),
            }
        }
        "string" => Val::Str(c.req("value")?.value.clone()),
        "rgb" => {
            let a = c.req("value")?;
            let f = parse_floats(&a.value, &a.loc, "rgb")?;
            match f.len() {
                3 => Val::Rgb(Spectrum::rgb(f[0] as f32, f[1] as f32, f[2] as f32)),
                1 => Val::Rgb(Spectrum::splat(f[0] as f32)),
                n => return Err(a.loc.err(format!("<rgb> needs 3 (or 1) numbers, got {n}"))),
            }
        }
        "spectrum" => {
            let a = c.req("value")?;
            match a.value.trim().parse::<f64>() {
                Ok(v) => Val::Float(v),
                Err(_) => {
                    return Err(a.loc.err(format!(
                        "<spectrum value=\"{}\">: Opal is an RGB renderer; only a single constant value is supported (use <rgb>)",
                        a.value
                    )));
                }
            }
        }
        "point" | "vector" => Val::Vec3(parse_xyz(c, 0.0, false)?),
        "transform" => Val::Transform(parse_transform(c)?),
        _ => unreachable!(),
    };
    Ok((name, val))
}

impl Loader {
    /// Collects the children of plugin element `e` (parameters, `<ref>`s, nested plugins,
    /// instantiated on the way) into [`Props`]; `what` names the element in messages.
    pub(super) fn props(&mut self, e: &Elem, what: String) -> Result<Props> {
        let mut props = Props { what, params: Vec::new(), objects: Vec::new() };
        for c in &e.children {
            let (name, val) = match c.tag.as_str() {
                "float" | "integer" | "boolean" | "string" | "rgb" | "spectrum" | "point" | "vector"
                | "transform" => {
                    let (n, v) = parse_param(c)?;
                    (Some(n), v)
                }
                "ref" => {
                    c.check_attrs(&["id", "name"])?;
                    let id = c.req("id")?;
                    let obj = self.named.get(&id.value).cloned().ok_or_else(|| {
                        id.loc.err(format!(
                            "<ref id=\"{}\">: no bsdf, texture or shapegroup with this id was declared before",
                            id.value
                        ))
                    })?;
                    (c.attr("name").map(|a| a.value.clone()), Val::Obj(obj))
                }
                t if PLUGIN_TAGS.contains(&t) => {
                    let obj = self.instantiate(c)?;
                    (c.attr("name").map(|a| a.value.clone()), Val::Obj(obj))
                }
                other => return Err(c.loc.err(format!("unknown element <{other}> inside {}", e.describe()))),
            };
            match name {
                Some(n) => {
                    if props.params.iter().any(|p| p.name == n) {
                        return Err(c.loc.err(format!("parameter `{n}` of {} is given twice", e.describe())));
                    }
                    props.params.push(Param { name: n, val, loc: c.loc.clone() });
                }
                None => match val {
                    Val::Obj(o) => props.objects.push((o, c.loc.clone())),
                    _ => unreachable!("parameters always have a name"),
                },
            }
        }
        Ok(props)
    }
}
