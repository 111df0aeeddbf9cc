//! Mitsuba 3 XML scene loader → [`SceneDesc`].
//!
//! The supported subset, the conventions and the error behaviour are documented for users in
//! `docs/scene-format.md`; in short:
//!
//! * Elements: `scene` (attribute `version`, major 2 or 3), `default`, `include`, `ref`,
//!   parameters (`float integer boolean string rgb spectrum point vector transform`) and the
//!   plugins listed in [`SUPPORTED_PLUGINS`]. Plugin dispatch is **one** `match` on
//!   `(tag, type)` in `Loader::instantiate`; adding a plugin is one arm there.
//! * `$name` in any attribute value is replaced by the caller's parameter, else by a
//!   `<default name= value=>` declared earlier in document order; an unset `$name` is an error.
//! * `to_world` transforms compose like Mitsuba: each new element is **left**-multiplied
//!   (`M ← T·M`), composed in f64 and rounded to f32 once.
//! * Meshes are returned in world space; analytic shapes are tessellated (rectangle 2
//!   triangles, cube 12, sphere [`SPHERE_SEGMENTS_PHI`]×[`SPHERE_SEGMENTS_THETA`]).
//! * Every element, attribute or parameter Opal does not understand is an error
//!   [`Error::Parse`] naming the XML file, line and column and the offending name — nothing
//!   is silently ignored. Errors from referenced files (meshes, images) are reported at the
//!   referencing XML element, with the inner error (its own file and line) in the message.
//!
//! Tests: unit tests below (transform composition, tessellation, substitution) and
//! `crates/opal/tests/scene_load.rs` (Cornell box, every element, every error case).

use crate::error::{Error, Result};
use crate::geometry::TriangleMesh;
use crate::image::read::{read_image_decoded, srgb_to_linear};
use crate::math::{DMat4, DVec3, Mat4, Vec2, Vec3};
use crate::scene::desc::*;
use crate::spectrum::Spectrum;
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::rc::Rc;
use std::sync::Arc;

/// Number of segments in azimuth φ of a tessellated `sphere`.
pub const SPHERE_SEGMENTS_PHI: usize = 128;
/// Number of segments in polar angle θ of a tessellated `sphere`.
pub const SPHERE_SEGMENTS_THETA: usize = 64;
/// Deepest `include` nesting accepted.
const MAX_INCLUDE_DEPTH: usize = 32;

/// Mitsuba plugins Opal understands: `(tag, types)`. Any other `type` is an error, reported
/// before the element's children are read. Adding a plugin = one arm in
/// `Loader::instantiate` + its name here (a unit test checks the two agree).
pub const SUPPORTED_PLUGINS: &[(&str, &[&str])] = &[
    ("shape", &["obj", "ply", "rectangle", "cube", "sphere"]),
    (
        "bsdf",
        &[
            "diffuse",
            "twosided",
            "phong",
            "blinn",
            "schlick",
            "lyon",
            "pow16",
            "microfacet_conductor",
            "dielectric",
            "tabulated",
            "roughdielectric",
        ],
    ),
    ("texture", &["bitmap"]),
    ("emitter", &["area", "point"]),
    ("sensor", &["perspective"]),
    ("film", &["hdrfilm"]),
    ("sampler", &["independent"]),
    ("rfilter", &["box"]),
    ("integrator", &["path"]),
];

/// Plugin tags Mitsuba knows (a tag outside this list is "unknown element").
const PLUGIN_TAGS: &[&str] = &[
    "shape",
    "bsdf",
    "texture",
    "emitter",
    "sensor",
    "film",
    "sampler",
    "rfilter",
    "integrator",
    "medium",
    "phase",
    "volume",
];

// ----------------------------------------------------------------------------------------
// Generic XML tree with positions, substitution and includes resolved.

#[derive(Clone, Debug)]
struct Loc {
    file: Rc<PathBuf>,
    line: usize,
    col: usize,
}

impl Loc {
    fn err(&self, msg: impl Into<String>) -> Error {
        Error::Parse { path: (*self.file).clone(), line: self.line, col: self.col, msg: msg.into() }
    }
}

#[derive(Debug)]
struct Attr {
    name: String,
    value: String,
    loc: Loc,
}

#[derive(Debug)]
struct Elem {
    tag: String,
    attrs: Vec<Attr>,
    children: Vec<Elem>,
    loc: Loc,
    /// Folders relative paths are searched in, innermost file first.
    dirs: Rc<Vec<PathBuf>>,
}

impl Elem {
    fn attr(&self, n: &str) -> Option<&Attr> {
        self.attrs.iter().find(|a| a.name == n)
    }
    fn req(&self, n: &str) -> Result<&Attr> {
        self.attr(n).ok_or_else(|| self.loc.err(format!("<{}> lacks the required attribute `{n}`", self.tag)))
    }
    fn check_attrs(&self, allowed: &[&str]) -> Result<()> {
        for a in &self.attrs {
            if !allowed.contains(&a.name.as_str()) {
                return Err(a.loc.err(format!(
                    "unknown attribute `{}` on <{}> (allowed: {})",
                    a.name,
                    self.tag,
                    allowed.join(", ")
                )));
            }
        }
        Ok(())
    }
    /// `<bsdf type="diffuse" id="x">` for messages.
    fn describe(&self) -> String {
        let mut s = format!("<{}", self.tag);
        for k in ["type", "id", "name"] {
            if let Some(a) = self.attr(k) {
                s += &format!(" {k}=\"{}\"", a.value);
            }
        }
        s + ">"
    }
    /// Resolves a file name against the folders of the including files.
    fn resolve(&self, f: &str) -> PathBuf {
        let p = Path::new(f);
        if p.is_absolute() {
            return p.to_path_buf();
        }
        self.dirs.iter().map(|d| d.join(p)).find(|c| c.exists()).unwrap_or_else(|| self.dirs[0].join(p))
    }
}

struct XmlReader {
    params: HashMap<String, String>,
    /// Canonical paths of the files being parsed (include chain).
    stack: Vec<PathBuf>,
}

impl XmlReader {
    /// Parses `path` (whose root must be `<scene>`) and returns the root element with
    /// includes spliced in.
    fn parse_file(&mut self, path: &Path, outer_dirs: &[PathBuf], from: Option<&Loc>) -> Result<Elem> {
        let text = std::fs::read_to_string(path).map_err(|e| match from {
            None => Error::io(path, e),
            Some(l) => l.err(format!("cannot read included file {}: {e}", path.display())),
        })?;
        let canon = path.canonicalize().unwrap_or_else(|_| path.to_path_buf());
        if self.stack.contains(&canon) {
            let chain: Vec<String> = self.stack.iter().map(|p| p.display().to_string()).collect();
            return Err(from.expect("root file cannot be on the stack").err(format!(
                "include loop: {} is already being parsed (chain: {} → {})",
                path.display(),
                chain.join(" → "),
                path.display()
            )));
        }
        if self.stack.len() >= MAX_INCLUDE_DEPTH {
            return Err(from
                .expect("depth > 0")
                .err(format!("includes nested deeper than {MAX_INCLUDE_DEPTH}")));
        }
        self.stack.push(canon);
        let file = Rc::new(path.to_path_buf());
        let opts = roxmltree::ParsingOptions { allow_dtd: false, ..Default::default() };
        let doc = roxmltree::Document::parse_with_options(&text, opts).map_err(|e| {
            let p = e.pos();
            Error::Parse {
                path: path.to_path_buf(),
                line: p.row as usize,
                col: p.col as usize,
                msg: format!("malformed XML: {e}"),
            }
        })?;
        let mut dirs = vec![path.parent().map(Path::to_path_buf).unwrap_or_default()];
        dirs.extend(outer_dirs.iter().cloned());
        let dirs = Rc::new(dirs);
        let root = doc.root_element();
        let root_elem = self.convert(&doc, root, &file, &dirs)?;
        if root_elem.tag != "scene" {
            return Err(root_elem
                .loc
                .err(format!("root element must be <scene>, found <{}>", root_elem.tag)));
        }
        root_elem.check_attrs(&["version"])?;
        match root_elem.attr("version") {
            None if from.is_none() => {
                return Err(root_elem.loc.err("<scene> lacks the required attribute `version`"));
            }
            None => {}
            Some(v) => {
                let major = v.value.split('.').next().and_then(|m| m.parse::<u32>().ok());
                if !matches!(major, Some(2) | Some(3)) {
                    return Err(v.loc.err(format!(
                        "scene version `{}` is not supported (Opal reads Mitsuba 2/3 scenes, version 2.x or 3.x)",
                        v.value
                    )));
                }
            }
        }
        self.stack.pop();
        Ok(root_elem)
    }

    fn loc(doc: &roxmltree::Document, file: &Rc<PathBuf>, byte: usize) -> Loc {
        let p = doc.text_pos_at(byte);
        Loc { file: file.clone(), line: p.row as usize, col: p.col as usize }
    }

    fn substitute(&self, value: &str, loc: &Loc) -> Result<String> {
        if !value.contains('$') {
            return Ok(value.to_string());
        }
        let mut out = String::new();
        let mut rest = value;
        while let Some(k) = rest.find('$') {
            out += &rest[..k];
            let after = &rest[k + 1..];
            let (name, consumed) = if let Some(inner) = after.strip_prefix('{') {
                match inner.find('}') {
                    Some(e) => (&inner[..e], e + 2),
                    None => return Err(loc.err(format!("unterminated `${{` in `{value}`"))),
                }
            } else {
                let e = after.find(|c: char| !(c.is_ascii_alphanumeric() || c == '_')).unwrap_or(after.len());
                (&after[..e], e)
            };
            if name.is_empty() {
                return Err(loc.err(format!("`$` not followed by a parameter name in `{value}`")));
            }
            match self.params.get(name) {
                Some(v) => out += v,
                None => {
                    return Err(loc.err(format!(
                        "parameter `${name}` is not set (pass it to the loader or declare <default name=\"{name}\" value=\"...\"/>)"
                    )));
                }
            }
            rest = &after[consumed..];
        }
        out += rest;
        Ok(out)
    }

    fn convert(
        &mut self,
        doc: &roxmltree::Document,
        node: roxmltree::Node,
        file: &Rc<PathBuf>,
        dirs: &Rc<Vec<PathBuf>>,
    ) -> Result<Elem> {
        let loc = Self::loc(doc, file, node.range().start);
        let mut attrs = Vec::new();
        for a in node.attributes() {
            let aloc = Self::loc(doc, file, a.range_value().start);
            let value = self.substitute(a.value(), &aloc)?;
            attrs.push(Attr { name: a.name().to_string(), value, loc: aloc });
        }
        let mut elem = Elem {
            tag: node.tag_name().name().to_string(),
            attrs,
            children: Vec::new(),
            loc,
            dirs: dirs.clone(),
        };
        for c in node.children() {
            if c.is_text() {
                let t = c.text().unwrap_or("");
                if !t.trim().is_empty() {
                    let l = Self::loc(doc, file, c.range().start);
                    return Err(l.err(format!("unexpected text `{}` inside <{}>", t.trim(), elem.tag)));
                }
                continue;
            }
            if !c.is_element() {
                continue; // comments, processing instructions
            }
            let child = self.convert(doc, c, file, dirs)?;
            match child.tag.as_str() {
                "default" => {
                    child.check_attrs(&["name", "value"])?;
                    let name = child.req("name")?.value.clone();
                    let value = child.req("value")?.value.clone();
                    // Caller parameters and earlier defaults win.
                    self.params.entry(name).or_insert(value);
                }
                "include" => {
                    child.check_attrs(&["filename"])?;
                    let fname = child.req("filename")?;
                    let target = child.resolve(&fname.value);
                    let inc = self.parse_file(&target, dirs, Some(&fname.loc))?;
                    elem.children.extend(inc.children);
                }
                _ => elem.children.push(child),
            }
        }
        Ok(elem)
    }
}

// ----------------------------------------------------------------------------------------
// Objects, parameter values and property lists.

/// Film settings (only the size travels into [`SensorDesc`]).
#[derive(Clone, Debug)]
struct FilmDesc {
    width: usize,
    height: usize,
    has_rfilter: bool,
}

/// An instantiated plugin.
#[derive(Clone, Debug)]
enum Object {
    Shape(Box<ShapeDesc>),
    Bsdf(BsdfDesc),
    Texture(TextureDesc),
    AreaEmitter(AreaEmitterDesc),
    Emitter(EmitterDesc),
    Sensor(Box<SensorDesc>),
    Film(FilmDesc),
    Sampler(u32),
    RFilter,
    Integrator(IntegratorDesc),
}

impl Object {
    fn kind(&self) -> &'static str {
        match self {
            Object::Shape(_) => "shape",
            Object::Bsdf(_) => "bsdf",
            Object::Texture(_) => "texture",
            Object::AreaEmitter(_) | Object::Emitter(_) => "emitter",
            Object::Sensor(_) => "sensor",
            Object::Film(_) => "film",
            Object::Sampler(_) => "sampler",
            Object::RFilter => "rfilter",
            Object::Integrator(_) => "integrator",
        }
    }
}

#[derive(Debug)]
enum Val {
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
    fn type_name(&self) -> &'static str {
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

struct Param {
    name: String,
    val: Val,
    loc: Loc,
}

/// Parameters and nested objects of one plugin element. Accessors remove what they read;
/// [`Props::finish`] rejects whatever is left.
struct Props {
    what: String,
    params: Vec<Param>,
    objects: Vec<(Object, Loc)>,
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
    fn float_at(&mut self, name: &str) -> Result<Option<(f64, Loc)>> {
        match self.take(name) {
            None => Ok(None),
            Some(Param { val: Val::Float(v), loc, .. }) => Ok(Some((v, loc))),
            Some(Param { val: Val::Int(v), loc, .. }) => Ok(Some((v as f64, loc))),
            Some(p) => Err(self.type_err(&p, "a float")),
        }
    }
    fn int_at(&mut self, name: &str) -> Result<Option<(i64, Loc)>> {
        match self.take(name) {
            None => Ok(None),
            Some(Param { val: Val::Int(v), loc, .. }) => Ok(Some((v, loc))),
            Some(p) => Err(self.type_err(&p, "an integer")),
        }
    }
    fn bool(&mut self, name: &str) -> Result<Option<bool>> {
        match self.take(name) {
            None => Ok(None),
            Some(Param { val: Val::Bool(v), .. }) => Ok(Some(v)),
            Some(p) => Err(self.type_err(&p, "a boolean")),
        }
    }
    fn string_at(&mut self, name: &str) -> Result<Option<(String, Loc)>> {
        match self.take(name) {
            None => Ok(None),
            Some(Param { val: Val::Str(v), loc, .. }) => Ok(Some((v, loc))),
            Some(p) => Err(self.type_err(&p, "a string")),
        }
    }
    fn point(&mut self, name: &str) -> Result<Option<DVec3>> {
        match self.take(name) {
            None => Ok(None),
            Some(Param { val: Val::Vec3(v), .. }) => Ok(Some(v)),
            Some(p) => Err(self.type_err(&p, "a point")),
        }
    }
    fn transform(&mut self, name: &str) -> Result<Option<(DMat4, Loc)>> {
        match self.take(name) {
            None => Ok(None),
            Some(Param { val: Val::Transform(m), loc, .. }) => Ok(Some((m, loc))),
            Some(p) => Err(self.type_err(&p, "a transform")),
        }
    }
    /// A colour: `rgb`, `float`, single-valued `spectrum`.
    fn color(&mut self, name: &str) -> Result<Option<(Spectrum, Loc)>> {
        match self.take(name) {
            None => Ok(None),
            Some(Param { val: Val::Rgb(s), loc, .. }) => Ok(Some((s, loc))),
            Some(Param { val: Val::Float(v), loc, .. }) => Ok(Some((Spectrum::splat(v as f32), loc))),
            Some(Param { val: Val::Int(v), loc, .. }) => Ok(Some((Spectrum::splat(v as f32), loc))),
            Some(p) => Err(self.type_err(&p, "an rgb or float colour")),
        }
    }
    /// A colour or a nested/referenced texture.
    fn texture(&mut self, name: &str) -> Result<Option<TextureDesc>> {
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
    fn objects(&mut self, kind: &str) -> Vec<(Object, Loc)> {
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
    fn object(&mut self, kind: &str) -> Result<Option<(Object, Loc)>> {
        let mut v = self.objects(kind);
        if v.len() > 1 {
            return Err(v[1].1.err(format!("{} accepts one nested <{kind}>, found {}", self.what, v.len())));
        }
        Ok(v.pop())
    }
    fn finish(self, supported: &str) -> Result<()> {
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

fn parse_floats(s: &str, loc: &Loc, what: &str) -> Result<Vec<f64>> {
    s.split(|c: char| c == ',' || c.is_whitespace())
        .filter(|t| !t.is_empty())
        .map(|t| t.parse::<f64>().map_err(|_| loc.err(format!("{what}: `{t}` is not a number"))))
        .collect()
}

fn parse_float(a: &Attr) -> Result<f64> {
    let v = a.value.trim();
    v.parse::<f64>().map_err(|_| a.loc.err(format!("`{v}` is not a number")))
}

/// `value="x, y, z"` or attributes `x`, `y`, `z` (missing ones = `default`).
fn parse_xyz(e: &Elem, default: f64, allow_scalar: bool) -> Result<DVec3> {
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

fn parse_vec_attr(a: &Attr) -> Result<DVec3> {
    let f = parse_floats(&a.value, &a.loc, &a.name)?;
    if f.len() != 3 {
        return Err(a.loc.err(format!("`{}` needs 3 numbers, got {}", a.name, f.len())));
    }
    Ok(DVec3::new(f[0], f[1], f[2]))
}

/// Mitsuba's `look_at`: columns left = normalize(up × dir), up' = dir × left, dir, origin.
pub fn look_at(origin: DVec3, target: DVec3, up: DVec3) -> Option<DMat4> {
    let dir = (target - origin).normalize();
    let left = up.normalize().cross(dir).normalize();
    let new_up = dir.cross(left);
    let m = DMat4::from_cols(left.extend(0.0), new_up.extend(0.0), dir.extend(0.0), origin.extend(1.0));
    m.is_finite().then_some(m)
}

/// Parses the children of a `<transform>`, composing like Mitsuba (`M ← T·M`).
fn parse_transform(e: &Elem) -> Result<DMat4> {
    let mut m = DMat4::IDENTITY;
    for c in &e.children {
        let t = match c.tag.as_str() {
            "translate" => {
                c.check_attrs(&["value", "x", "y", "z"])?;
                DMat4::from_translation(parse_xyz(c, 0.0, false)?)
            }
            "scale" => {
                c.check_attrs(&["value", "x", "y", "z"])?;
                DMat4::from_scale(parse_xyz(c, 1.0, true)?)
            }
            "rotate" => {
                c.check_attrs(&["value", "x", "y", "z", "angle"])?;
                let axis = parse_xyz(c, 0.0, false)?;
                let angle = parse_float(c.req("angle")?)?;
                if axis.length_squared() == 0.0 || !axis.is_finite() {
                    return Err(c.loc.err("<rotate> needs a non-zero axis (`value` or `x`/`y`/`z`)"));
                }
                DMat4::from_axis_angle(axis.normalize(), angle.to_radians())
            }
            "matrix" => {
                c.check_attrs(&["value"])?;
                let v = c.req("value")?;
                let f = parse_floats(&v.value, &v.loc, "matrix")?;
                match f.len() {
                    // Row-major in the file; glam is column-major.
                    16 => DMat4::from_cols_array(&[
                        f[0], f[4], f[8], f[12], f[1], f[5], f[9], f[13], f[2], f[6], f[10], f[14], f[3],
                        f[7], f[11], f[15],
                    ]),
                    9 => DMat4::from_cols_array(&[
                        f[0], f[3], f[6], 0.0, f[1], f[4], f[7], 0.0, f[2], f[5], f[8], 0.0, 0.0, 0.0, 0.0,
                        1.0,
                    ]),
                    n => return Err(v.loc.err(format!("<matrix> needs 16 (or 9) numbers, got {n}"))),
                }
            }
            "lookat" => {
                c.check_attrs(&["origin", "target", "up"])?;
                let o = parse_vec_attr(c.req("origin")?)?;
                let t = parse_vec_attr(c.req("target")?)?;
                let u = parse_vec_attr(c.req("up")?)?;
                look_at(o, t, u).ok_or_else(|| {
                    c.loc.err("invalid <lookat>: origin equals target, or `up` is zero or parallel to the viewing direction")
                })?
            }
            other => {
                return Err(c.loc.err(format!(
                    "unknown transform element <{other}> (supported: translate, rotate, scale, matrix, lookat)"
                )));
            }
        };
        m = t * m;
    }
    Ok(m)
}

fn to_mat4(m: DMat4) -> Mat4 {
    m.as_mat4()
}

// ----------------------------------------------------------------------------------------
// Mesh helpers.

/// Unit square `[-1,1]²` at z = 0 facing +z (Mitsuba `rectangle`), uv = ((x+1)/2, (y+1)/2).
pub fn rectangle_mesh() -> TriangleMesh {
    TriangleMesh {
        positions: vec![
            Vec3::new(-1., -1., 0.),
            Vec3::new(1., -1., 0.),
            Vec3::new(1., 1., 0.),
            Vec3::new(-1., 1., 0.),
        ],
        normals: vec![Vec3::Z; 4],
        uvs: vec![Vec2::new(0., 0.), Vec2::new(1., 0.), Vec2::new(1., 1.), Vec2::new(0., 1.)],
        indices: vec![[0, 1, 2], [0, 2, 3]],
    }
}

/// Cube `[-1,1]³` with outward faces, laid out like Mitsuba's `cube` mesh so that textures
/// land the same way: 24 vertices (4 per face, vertex normal = face normal), 12 triangles
/// `(4f, 4f+1, 4f+2)`, `(4f+3, 4f, 4f+2)`, corner uvs (0,1), (1,1), (1,0), (0,0) per face,
/// faces in the order −y, +y, +x, +z, −x, −z.
pub fn cube_mesh() -> TriangleMesh {
    // (normal, the four corners in order).
    const FACES: [([f32; 3], [[f32; 3]; 4]); 6] = [
        ([0., -1., 0.], [[1., -1., -1.], [1., -1., 1.], [-1., -1., 1.], [-1., -1., -1.]]),
        ([0., 1., 0.], [[1., 1., -1.], [-1., 1., -1.], [-1., 1., 1.], [1., 1., 1.]]),
        ([1., 0., 0.], [[1., -1., -1.], [1., 1., -1.], [1., 1., 1.], [1., -1., 1.]]),
        ([0., 0., 1.], [[1., -1., 1.], [1., 1., 1.], [-1., 1., 1.], [-1., -1., 1.]]),
        ([-1., 0., 0.], [[-1., -1., 1.], [-1., 1., 1.], [-1., 1., -1.], [-1., -1., -1.]]),
        ([0., 0., -1.], [[1., 1., -1.], [1., -1., -1.], [-1., -1., -1.], [-1., 1., -1.]]),
    ];
    const UV: [[f32; 2]; 4] = [[0., 1.], [1., 1.], [1., 0.], [0., 0.]];
    let mut m = TriangleMesh::default();
    for (n, corners) in FACES {
        let b = m.positions.len() as u32;
        for (c, uv) in corners.iter().zip(UV) {
            m.positions.push(Vec3::from(*c));
            m.normals.push(Vec3::from(n));
            m.uvs.push(Vec2::from(uv));
        }
        m.indices.push([b, b + 1, b + 2]);
        m.indices.push([b + 3, b, b + 2]);
    }
    m
}

/// Unit sphere (Mitsuba `sphere` before its center/radius/to_world), tessellated on a
/// `n_phi × n_theta` latitude–longitude grid with vertices **on** the sphere, per-vertex
/// normals = radial direction, uv = (φ/2π, θ/π) with θ measured from +z and φ = atan2(y, x)
/// (Mitsuba's analytic sphere parametrisation); seam vertices duplicated, one triangle per
/// cell at the poles. Outward facing (CCW seen from outside).
pub fn sphere_mesh(n_phi: usize, n_theta: usize) -> TriangleMesh {
    let mut m = TriangleMesh::default();
    for j in 0..=n_theta {
        let theta = std::f64::consts::PI * j as f64 / n_theta as f64;
        let (st, ct) = if j == 0 {
            (0.0, 1.0)
        } else if j == n_theta {
            (0.0, -1.0)
        } else {
            theta.sin_cos()
        };
        for i in 0..=n_phi {
            let phi = 2.0 * std::f64::consts::PI * i as f64 / n_phi as f64;
            let (sp, cp) = if i == n_phi { (0.0, 1.0) } else { phi.sin_cos() };
            let p = Vec3::new((st * cp) as f32, (st * sp) as f32, ct as f32);
            m.positions.push(p);
            m.normals.push(p);
            m.uvs.push(Vec2::new(i as f32 / n_phi as f32, j as f32 / n_theta as f32));
        }
    }
    let idx = |j: usize, i: usize| (j * (n_phi + 1) + i) as u32;
    for j in 0..n_theta {
        for i in 0..n_phi {
            let (a, b, c, d) = (idx(j, i), idx(j, i + 1), idx(j + 1, i + 1), idx(j + 1, i));
            if j + 1 < n_theta {
                m.indices.push([a, d, c]);
            }
            if j > 0 {
                m.indices.push([a, c, b]);
            }
        }
    }
    m
}

/// Angle-weighted vertex normals (Thürmer & Wüthrich 1998), as Mitsuba recomputes them for
/// meshes without normals when `face_normals` is false.
fn recompute_vertex_normals(m: &mut TriangleMesh) {
    let mut acc = vec![Vec3::ZERO; m.positions.len()];
    for t in &m.indices {
        let v = t.map(|i| m.positions[i as usize]);
        let n = (v[1] - v[0]).cross(v[2] - v[0]).normalize();
        for j in 0..3 {
            let d0 = (v[(j + 1) % 3] - v[j]).normalize();
            let d1 = (v[(j + 2) % 3] - v[j]).normalize();
            let angle = d0.dot(d1).clamp(-1.0, 1.0).acos();
            if n.is_finite() && angle.is_finite() {
                acc[t[j] as usize] += n * angle;
            }
        }
    }
    m.normals = acc.into_iter().map(|n| n.try_normalize().unwrap_or(Vec3::X)).collect();
}

/// Applies `to_world`, drops degenerate triangles, sets up normals; returns the number of
/// dropped triangles.
fn finalize_mesh(
    mut m: TriangleMesh,
    to_world: DMat4,
    flip_normals: bool,
    face_normals: bool,
    loc: &Loc,
    what: &str,
) -> Result<(TriangleMesh, usize)> {
    let lin = glam::DMat3::from_mat4(to_world);
    let det = lin.determinant();
    if det == 0.0 || !det.is_finite() {
        return Err(loc.err(format!("{what}: to_world is singular (determinant {det})")));
    }
    let nmat = lin.inverse().transpose();
    for p in &mut m.positions {
        *p = to_world.transform_point3(p.as_dvec3()).as_vec3();
    }
    for (k, n) in m.normals.iter_mut().enumerate() {
        let t = (nmat * n.as_dvec3()).as_vec3();
        *n = t
            .try_normalize()
            .ok_or_else(|| loc.err(format!("{what}: vertex normal {k} is zero or not finite ({n})")))?;
    }
    let before = m.indices.len();
    let pos = &m.positions;
    m.indices.retain(|t| {
        let [a, b, c] = t.map(|i| pos[i as usize]);
        let cr = (b - a).cross(c - a);
        cr.is_finite() && cr.length_squared() > 0.0
    });
    let dropped = before - m.indices.len();
    if m.indices.is_empty() {
        return Err(
            loc.err(format!("{what}: all {before} triangles are degenerate (zero area): the mesh is empty"))
        );
    }
    if face_normals {
        m.normals.clear();
    } else if m.normals.is_empty() {
        recompute_vertex_normals(&mut m);
    }
    if flip_normals {
        for t in &mut m.indices {
            t.swap(1, 2);
        }
        for n in &mut m.normals {
            *n = -*n;
        }
    }
    Ok((m, dropped))
}

// ----------------------------------------------------------------------------------------
// The loader proper.

struct Loader {
    /// Referenceable objects (`bsdf`, `texture` with an `id`).
    named: HashMap<String, Object>,
    ids: HashSet<String>,
    warnings: Vec<String>,
    n_shapes: usize,
    n_sensors: usize,
}

fn unsupported(tag: &str, ty: &str, e: &Elem) -> Error {
    let loc = e.attr("type").map(|a| a.loc.clone()).unwrap_or_else(|| e.loc.clone());
    match SUPPORTED_PLUGINS.iter().find(|(t, _)| *t == tag) {
        Some((_, types)) => loc.err(format!(
            "{tag} type=\"{ty}\" is not supported by Opal (supported {tag} types: {})",
            types.join(", ")
        )),
        None => loc.err(format!("<{tag} type=\"{ty}\"> is not supported by Opal (no {tag} plugins)")),
    }
}

impl Loader {
    /// Reads a parameter element into a [`Val`].
    fn param(&mut self, c: &Elem) -> Result<(String, Val)> {
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
                    a.value
                        .trim()
                        .parse()
                        .map_err(|_| a.loc.err(format!("`{}` is not an integer", a.value)))?,
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

    fn props(&mut self, e: &Elem, what: String) -> Result<Props> {
        let mut props = Props { what, params: Vec::new(), objects: Vec::new() };
        for c in &e.children {
            let (name, val) = match c.tag.as_str() {
                "float" | "integer" | "boolean" | "string" | "rgb" | "spectrum" | "point" | "vector"
                | "transform" => {
                    let (n, v) = self.param(c)?;
                    (Some(n), v)
                }
                "ref" => {
                    c.check_attrs(&["id", "name"])?;
                    let id = c.req("id")?;
                    let obj = self.named.get(&id.value).cloned().ok_or_else(|| {
                        id.loc.err(format!(
                            "<ref id=\"{}\">: no bsdf or texture with this id was declared before",
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

    /// Instantiates one plugin element. **The** plugin dispatch: one arm per (tag, type).
    fn instantiate(&mut self, e: &Elem) -> Result<Object> {
        e.check_attrs(&["type", "id", "name"])?;
        let ty = e.req("type")?.value.clone();
        let tag = e.tag.clone();
        // Reject unsupported plugins before reading (possibly failing) nested objects.
        if !SUPPORTED_PLUGINS.iter().any(|(t, types)| *t == tag && types.contains(&ty.as_str())) {
            return Err(unsupported(&tag, &ty, e));
        }
        let mut p = self.props(e, e.describe())?;
        let obj = match (tag.as_str(), ty.as_str()) {
            ("bsdf", "diffuse") => {
                let reflectance =
                    p.texture("reflectance")?.unwrap_or(TextureDesc::Constant(Spectrum::splat(0.5)));
                p.finish("reflectance")?;
                Object::Bsdf(BsdfDesc::Diffuse { reflectance })
            }
            ("bsdf", "twosided") => {
                let inner = p.objects("bsdf");
                if inner.len() != 1 {
                    return Err(e.loc.err(format!(
                        "{}: needs exactly one nested <bsdf> (Opal does not support different BSDFs per side), found {}",
                        e.describe(),
                        inner.len()
                    )));
                }
                p.finish("one nested <bsdf>")?;
                let Some((Object::Bsdf(b), _)) = inner.into_iter().next() else { unreachable!() };
                Object::Bsdf(BsdfDesc::TwoSided(Box::new(b)))
            }
            (
                "bsdf",
                "phong" | "blinn" | "schlick" | "lyon" | "pow16" | "microfacet_conductor" | "roughdielectric",
            ) => {
                use crate::bsdf::registry::{ParamValue, PluginParams, ROUGHDIELECTRIC_PARAMS, build_plugin};
                const LOBE: &[&str] = &[
                    "specular_reflectance",
                    "exponent",
                    "normalisation",
                    "A",
                    "B",
                    "form",
                    "w",
                    "distribution",
                    "alpha",
                    "eta",
                    "k",
                    "shadowing",
                ];
                let known = if ty == "roughdielectric" { ROUGHDIELECTRIC_PARAMS } else { LOBE };
                let mut pp = PluginParams::new(&ty);
                for q in std::mem::take(&mut p.params) {
                    if !known.contains(&q.name.as_str()) {
                        return Err(q.loc.err(format!(
                            "{}: unknown parameter `{}` (supported: {})",
                            e.describe(),
                            q.name,
                            known.join(", ")
                        )));
                    }
                    let v = match &q.val {
                        Val::Float(x) => ParamValue::Float(*x),
                        Val::Int(i) => ParamValue::Float(*i as f64),
                        Val::Str(s) => ParamValue::Str(s.clone()),
                        Val::Rgb(c) => ParamValue::Rgb(*c),
                        other => {
                            return Err(q.loc.err(format!(
                                "parameter `{}` of {} must be a float, string or rgb, got {}",
                                q.name,
                                e.describe(),
                                other.type_name()
                            )));
                        }
                    };
                    pp.values.insert(q.name.clone(), v);
                }
                p.finish(&known.join(", "))?;
                let b = build_plugin(&pp).map_err(|err| e.loc.err(format!("{}: {err}", e.describe())))?;
                Object::Bsdf(BsdfDesc::Lobe(b))
            }
            ("bsdf", "dielectric") => {
                // Mitsuba's defaults: int_ior = 1.5046 (bk7), ext_ior = 1.000277 (air)
                let mut ior = |name: &str, default: f64| -> Result<f64> {
                    match p.float_at(name)? {
                        None => Ok(default),
                        Some((v, _)) if v.is_finite() && v > 0.0 => Ok(v),
                        Some((v, l)) => Err(
                            l.err(format!("{}: `{name}` must be a positive number, got {v}", e.describe()))
                        ),
                    }
                };
                let int_ior = ior("int_ior", 1.5046)?;
                let ext_ior = ior("ext_ior", 1.000277)?;
                p.finish("int_ior, ext_ior (numbers)")?;
                let b = crate::bsdf::SmoothDielectric::new((int_ior / ext_ior) as f32).map_err(|err| {
                    e.loc.err(format!("{}: int_ior {int_ior} / ext_ior {ext_ior}: {err}", e.describe()))
                })?;
                Object::Bsdf(BsdfDesc::Lobe(crate::bsdf::Bxdfs::SmoothDielectric(b)))
            }
            ("bsdf", "tabulated") => {
                let (fname, floc) = p
                    .string_at("filename")?
                    .ok_or_else(|| e.loc.err(format!("{}: `filename` is required", e.describe())))?;
                p.finish("filename")?;
                let path = e.resolve(&fname);
                let b = crate::bsdf::TabulatedBsdf::load(&path)
                    .map_err(|err| floc.err(format!("{} filename=\"{fname}\": {err}", e.describe())))?;
                Object::Bsdf(BsdfDesc::Lobe(crate::bsdf::Bxdfs::Tabulated(b)))
            }
            ("texture", "bitmap") => Object::Texture(TextureDesc::Bitmap(self.bitmap(e, &mut p)?)),
            ("shape", "obj" | "ply" | "rectangle" | "cube" | "sphere") => {
                Object::Shape(Box::new(self.shape(e, &ty, &mut p)?))
            }
            ("emitter", "area") => {
                let (radiance, _) = p
                    .color("radiance")?
                    .ok_or_else(|| e.loc.err(format!("{}: `radiance` is required", e.describe())))?;
                p.finish("radiance")?;
                Object::AreaEmitter(AreaEmitterDesc { radiance })
            }
            ("emitter", "point") => {
                let pos = p.point("position")?;
                let tw = p.transform("to_world")?;
                let position = match (pos, tw) {
                    (Some(_), Some((_, l))) => {
                        return Err(l.err("point emitter: give either `position` or `to_world`, not both"));
                    }
                    (Some(v), None) => v,
                    (None, Some((m, _))) => m.transform_point3(DVec3::ZERO),
                    (None, None) => DVec3::ZERO,
                };
                let intensity = p.color("intensity")?.map_or(Spectrum::ONE, |c| c.0);
                p.finish("position, to_world, intensity")?;
                Object::Emitter(EmitterDesc::Point { position: position.as_vec3(), intensity })
            }
            ("sensor", "perspective") => Object::Sensor(Box::new(self.sensor(e, &mut p)?)),
            ("film", "hdrfilm") => {
                let w = p.int_at("width")?;
                let h = p.int_at("height")?;
                let mut size = [768usize, 576];
                for (k, v) in [w, h].into_iter().enumerate() {
                    if let Some((v, l)) = v {
                        if v <= 0 || v > 1 << 16 {
                            return Err(l.err(format!(
                                "film {} must be in 1..=65536, got {v}",
                                ["width", "height"][k]
                            )));
                        }
                        size[k] = v as usize;
                    }
                }
                if let Some((f, l)) = p.string_at("pixel_format")? {
                    match f.to_ascii_lowercase().as_str() {
                        "rgb" => {}
                        "rgba" => self.warnings.push(format!(
                            "{}:{}: film pixel_format \"rgba\": Opal writes RGB images (no alpha)",
                            l.file.display(),
                            l.line
                        )),
                        other => {
                            return Err(
                                l.err(format!("film pixel_format \"{other}\" is not supported (rgb, rgba)"))
                            );
                        }
                    }
                }
                if let Some((f, l)) = p.string_at("component_format")? {
                    match f.as_str() {
                        "float32" => {}
                        "float16" => self.warnings.push(format!(
                            "{}:{}: film component_format \"float16\": Opal writes float32 EXR",
                            l.file.display(),
                            l.line
                        )),
                        other => {
                            return Err(l.err(format!(
                                "film component_format \"{other}\" is not supported (float16, float32)"
                            )));
                        }
                    }
                }
                if let Some((f, l)) = p.string_at("file_format")? {
                    if !f.eq_ignore_ascii_case("openexr") && !f.eq_ignore_ascii_case("exr") {
                        return Err(l.err(format!("film file_format \"{f}\" is not supported (openexr)")));
                    }
                }
                let has_rfilter = p.object("rfilter")?.is_some();
                p.finish(
                    "width, height, file_format, pixel_format, component_format, a nested <rfilter type=\"box\">",
                )?;
                Object::Film(FilmDesc { width: size[0], height: size[1], has_rfilter })
            }
            ("sampler", "independent") => {
                let spp = match p.int_at("sample_count")? {
                    None => 4, // Mitsuba's default
                    Some((v, l)) => {
                        if v <= 0 || v > u32::MAX as i64 {
                            return Err(l.err(format!("sample_count must be ≥ 1, got {v}")));
                        }
                        v as u32
                    }
                };
                p.finish("sample_count")?;
                Object::Sampler(spp)
            }
            ("rfilter", "box") => {
                p.finish("")?;
                Object::RFilter
            }
            ("integrator", "path") => {
                let mut d = IntegratorDesc::default();
                if let Some((v, l)) = p.int_at("max_depth")? {
                    if v < -1 || v > i32::MAX as i64 {
                        return Err(l.err(format!("max_depth must be ≥ -1 (−1 = unbounded), got {v}")));
                    }
                    d.max_depth = v as i32;
                }
                if let Some((v, l)) = p.int_at("rr_depth")? {
                    if v < 0 || v > i32::MAX as i64 {
                        return Err(l.err(format!("rr_depth must be ≥ 0, got {v}")));
                    }
                    d.rr_depth = v as i32;
                }
                if let Some(v) = p.bool("hide_emitters")? {
                    d.hide_emitters = v;
                }
                p.finish("max_depth, rr_depth, hide_emitters")?;
                Object::Integrator(d)
            }
            (tag, ty) => return Err(unsupported(tag, ty, e)),
        };
        if let Some(id) = e.attr("id") {
            if !self.ids.insert(id.value.clone()) {
                return Err(id.loc.err(format!("duplicate id `{}`", id.value)));
            }
            if matches!(obj, Object::Bsdf(_) | Object::Texture(_)) {
                self.named.insert(id.value.clone(), obj.clone());
            }
        }
        Ok(obj)
    }

    fn bitmap(&mut self, e: &Elem, p: &mut Props) -> Result<BitmapDesc> {
        let (fname, floc) = p
            .string_at("filename")?
            .ok_or_else(|| e.loc.err(format!("{}: `filename` is required", e.describe())))?;
        let filter = match p.string_at("filter_type")? {
            None => FilterType::Bilinear,
            Some((s, l)) => match s.as_str() {
                "bilinear" => FilterType::Bilinear,
                "nearest" => FilterType::Nearest,
                _ => return Err(l.err(format!("filter_type \"{s}\" is not supported (bilinear, nearest)"))),
            },
        };
        let wrap = match p.string_at("wrap_mode")? {
            None => WrapMode::Repeat,
            Some((s, l)) => match s.as_str() {
                "repeat" => WrapMode::Repeat,
                "mirror" => WrapMode::Mirror,
                "clamp" => WrapMode::Clamp,
                _ => return Err(l.err(format!("wrap_mode \"{s}\" is not supported (repeat, mirror, clamp)"))),
            },
        };
        let raw = p.bool("raw")?.unwrap_or(false);
        std::mem::replace(p, Props { what: String::new(), params: Vec::new(), objects: Vec::new() })
            .finish("filename, filter_type, wrap_mode, raw")?;
        let path = e.resolve(&fname);
        let dec = read_image_decoded(&path).map_err(|err| floc.err(format!("bitmap texture: {err}")))?;
        let mut image = dec.image;
        if dec.srgb_encoded && !raw {
            for v in &mut image.data {
                *v = v.map(srgb_to_linear);
            }
        }
        if image.width == 0 || image.height == 0 {
            return Err(floc.err(format!("bitmap texture {}: empty image", path.display())));
        }
        if let Some(k) = image.data.iter().position(|v| !v.is_finite()) {
            return Err(floc.err(format!(
                "bitmap texture {}: non-finite texel at ({}, {})",
                path.display(),
                k % image.width,
                k / image.width
            )));
        }
        Ok(BitmapDesc { image: Arc::new(image), filter, wrap, path })
    }

    fn shape(&mut self, e: &Elem, ty: &str, p: &mut Props) -> Result<ShapeDesc> {
        let mut what = e.describe();
        let to_world = p.transform("to_world")?.map_or(DMat4::IDENTITY, |t| t.0);
        let flip_normals = p.bool("flip_normals")?.unwrap_or(false);
        let mut face_normals = false;
        let mut supported = "to_world, flip_normals, a nested <bsdf>, a nested <emitter type=\"area\">";
        // Read every parameter first (so unknown ones fail before any file I/O), then load.
        enum Source {
            Obj(PathBuf, Loc, bool),
            Ply(PathBuf, Loc),
            Mesh(TriangleMesh, DMat4),
        }
        let source = match ty {
            "obj" | "ply" => {
                let (fname, floc) = p
                    .string_at("filename")?
                    .ok_or_else(|| e.loc.err(format!("{what}: `filename` is required")))?;
                face_normals = p.bool("face_normals")?.unwrap_or(false);
                let path = e.resolve(&fname);
                what = format!("{what} ({})", path.display());
                if ty == "obj" {
                    let flip_tc = p.bool("flip_tex_coords")?.unwrap_or(true);
                    supported = "filename, face_normals, flip_tex_coords, to_world, flip_normals, a nested <bsdf>, a nested <emitter type=\"area\">";
                    Source::Obj(path, floc, flip_tc)
                } else {
                    supported = "filename, face_normals, to_world, flip_normals, a nested <bsdf>, a nested <emitter type=\"area\">";
                    Source::Ply(path, floc)
                }
            }
            "rectangle" => Source::Mesh(rectangle_mesh(), DMat4::IDENTITY),
            "cube" => Source::Mesh(cube_mesh(), DMat4::IDENTITY),
            "sphere" => {
                let center = p.point("center")?.unwrap_or(DVec3::ZERO);
                let radius = match p.float_at("radius")? {
                    None => 1.0,
                    Some((r, l)) => {
                        if !(r > 0.0 && r.is_finite()) {
                            return Err(l.err(format!("sphere radius must be > 0, got {r}")));
                        }
                        r
                    }
                };
                supported = "center, radius, to_world, flip_normals, a nested <bsdf>, a nested <emitter type=\"area\">";
                Source::Mesh(
                    sphere_mesh(SPHERE_SEGMENTS_PHI, SPHERE_SEGMENTS_THETA),
                    DMat4::from_translation(center) * DMat4::from_scale(DVec3::splat(radius)),
                )
            }
            _ => unreachable!("dispatch only routes supported shapes here"),
        };
        let bsdf = match p.object("bsdf")? {
            None => BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(Spectrum::splat(0.5)) },
            Some((Object::Bsdf(b), _)) => b,
            Some(_) => unreachable!(),
        };
        let emitter = match p.object("emitter")? {
            None => None,
            Some((Object::AreaEmitter(a), _)) => Some(a),
            Some((_, l)) => {
                return Err(
                    l.err(format!("{what}: only an emitter of type \"area\" can be attached to a shape"))
                );
            }
        };
        std::mem::replace(p, Props { what: String::new(), params: Vec::new(), objects: Vec::new() })
            .finish(supported)?;
        let (mesh, local) = match source {
            Source::Obj(path, floc, flip_tc) => (
                crate::geometry::obj::read_obj(&path, flip_tc)
                    .map_err(|err| floc.err(format!("{what}: {err}")))?,
                DMat4::IDENTITY,
            ),
            Source::Ply(path, floc) => (
                crate::geometry::ply::read_ply(&path).map_err(|err| floc.err(format!("{what}: {err}")))?,
                DMat4::IDENTITY,
            ),
            Source::Mesh(m, local) => (m, local),
        };
        let (mesh, dropped) =
            finalize_mesh(mesh, to_world * local, flip_normals, face_normals, &e.loc, &what)?;
        let id = e.attr("id").map_or_else(|| format!("shape_{}", self.n_shapes), |a| a.value.clone());
        self.n_shapes += 1;
        if dropped > 0 {
            self.warnings.push(format!(
                "{}:{}: shape `{id}`: dropped {dropped} degenerate (zero-area) triangle(s), {} left",
                e.loc.file.display(),
                e.loc.line,
                mesh.indices.len()
            ));
        }
        Ok(ShapeDesc { id, mesh, bsdf, emitter, origin: Some(((*e.loc.file).clone(), e.loc.line)) })
    }

    fn sensor(&mut self, e: &Elem, p: &mut Props) -> Result<SensorDesc> {
        let (to_world, tw_loc) = p.transform("to_world")?.map_or((DMat4::IDENTITY, e.loc.clone()), |t| t);
        for k in 0..3 {
            let s = to_world.col(k).truncate().length();
            if (s - 1.0).abs() > 1e-3 {
                return Err(tw_loc.err(format!(
                    "sensor to_world must not scale (column {k} has length {s:.6}); Mitsuba rejects this too"
                )));
            }
        }
        let film = match p.object("film")? {
            Some((Object::Film(f), _)) => f,
            None => FilmDesc { width: 768, height: 576, has_rfilter: false },
            Some(_) => unreachable!(),
        };
        if !film.has_rfilter {
            self.warnings.push(format!(
                "{}:{}: sensor film has no <rfilter>: Mitsuba would use a gaussian filter, Opal uses a box filter",
                e.loc.file.display(),
                e.loc.line
            ));
        }
        let spp = match p.object("sampler")? {
            Some((Object::Sampler(s), _)) => Some(s),
            None => None,
            Some(_) => unreachable!(),
        };
        let aspect = film.width as f64 / film.height as f64;
        let fov = p.float_at("fov")?;
        let focal = p.string_at("focal_length")?;
        let axis = p.string_at("fov_axis")?;
        let (fov_deg, axis_name, axis_loc) = match (fov, focal) {
            (Some(_), Some((_, l))) => return Err(l.err("give either `fov` or `focal_length`, not both")),
            (Some((f, l)), None) => {
                if !(f > 0.0 && f < 180.0) {
                    return Err(l.err(format!("fov must be in (0, 180) degrees, got {f}")));
                }
                let (a, al) = axis.map_or(("x".to_string(), l), |(a, al)| (a.to_ascii_lowercase(), al));
                (f, a, al)
            }
            (None, focal) => {
                if let Some((_, l)) = axis {
                    return Err(l.err("`fov_axis` needs `fov`"));
                }
                // Mitsuba: a 35 mm film diagonal (36×24 mm) with focal length in mm, default 50mm.
                let (s, l) = focal.unwrap_or(("50mm".to_string(), e.loc.clone()));
                let mm: f64 = s
                    .trim()
                    .strip_suffix("mm")
                    .and_then(|v| v.trim().parse().ok())
                    .filter(|v: &f64| *v > 0.0)
                    .ok_or_else(|| l.err(format!("focal_length \"{s}\" must be like \"50mm\"")))?;
                let diag = (36.0f64 * 36.0 + 24.0 * 24.0).sqrt();
                (2.0 * (diag / (2.0 * mm)).atan().to_degrees(), "diagonal".to_string(), l)
            }
        };
        let fov_x_deg = fov_to_x(fov_deg, &axis_name, aspect).ok_or_else(|| {
            axis_loc
                .err(format!("fov_axis \"{axis_name}\" is not supported (x, y, diagonal, smaller, larger)"))
        })?;
        let near_clip = p.float_at("near_clip")?;
        let far_clip = p.float_at("far_clip")?;
        let near = near_clip.as_ref().map_or(0.01, |v| v.0);
        let far = far_clip.as_ref().map_or(10000.0, |v| v.0);
        if !(near > 0.0 && far > near && far.is_finite()) {
            let l = near_clip.or(far_clip).map_or(e.loc.clone(), |v| v.1);
            return Err(
                l.err(format!("need 0 < near_clip < far_clip < ∞, got near_clip {near}, far_clip {far}"))
            );
        }
        std::mem::replace(p, Props { what: String::new(), params: Vec::new(), objects: Vec::new() }).finish(
            "fov, fov_axis, focal_length, to_world, near_clip, far_clip, a nested <film>, a nested <sampler>",
        )?;
        let id = e.attr("id").map_or_else(|| format!("sensor_{}", self.n_sensors), |a| a.value.clone());
        self.n_sensors += 1;
        Ok(SensorDesc {
            id,
            to_world: to_mat4(to_world),
            fov_x_deg: fov_x_deg as f32,
            width: film.width,
            height: film.height,
            near_clip: near as f32,
            far_clip: far as f32,
            spp,
        })
    }
}

/// Converts a full field of view along `axis` (Mitsuba's `fov_axis`: x, y, diagonal,
/// smaller, larger) to the full horizontal field of view, for a film `aspect = width /
/// height`, exactly as Mitsuba's perspective sensor does. `None` for an unknown axis.
pub fn fov_to_x(fov_deg: f64, axis: &str, aspect: f64) -> Option<f64> {
    let axis = match axis {
        "smaller" => {
            if aspect > 1.0 {
                "y"
            } else {
                "x"
            }
        }
        "larger" => {
            if aspect > 1.0 {
                "x"
            } else {
                "y"
            }
        }
        a => a,
    };
    let half = (0.5 * fov_deg.to_radians()).tan();
    match axis {
        "x" => Some(fov_deg),
        "y" => Some(2.0 * (half * aspect).atan().to_degrees()),
        "diagonal" => {
            let diagonal = 2.0 * half;
            let width = diagonal / (1.0 + 1.0 / (aspect * aspect)).sqrt();
            Some(2.0 * (0.5 * width).atan().to_degrees())
        }
        _ => None,
    }
}

/// Loads a Mitsuba 3 XML scene. `params` are `$name` substitutions (they override the file's
/// `<default>`s). See the module documentation and `docs/scene-format.md`.
pub fn load_mitsuba_xml(path: &Path, params: &[(String, String)]) -> Result<SceneDesc> {
    let mut reader = XmlReader { params: params.iter().cloned().collect(), stack: Vec::new() };
    let root = reader.parse_file(path, &[], None)?;
    let mut loader = Loader {
        named: HashMap::new(),
        ids: HashSet::new(),
        warnings: Vec::new(),
        n_shapes: 0,
        n_sensors: 0,
    };
    let mut scene = SceneDesc { source: Some(path.to_path_buf()), ..Default::default() };
    for c in &root.children {
        if !PLUGIN_TAGS.contains(&c.tag.as_str()) {
            return Err(c.loc.err(format!(
                "unexpected <{}> at the top level of the scene (expected plugins such as <shape>, <sensor>, <emitter>, <bsdf id=...>)",
                c.tag
            )));
        }
        match loader.instantiate(c)? {
            Object::Shape(s) => scene.shapes.push(*s),
            Object::Sensor(s) => scene.sensors.push(*s),
            Object::Emitter(em) => scene.emitters.push(em),
            Object::Integrator(i) => {
                if scene.integrator.is_some() {
                    return Err(c.loc.err("more than one <integrator>"));
                }
                scene.integrator = Some(i);
            }
            Object::Bsdf(_) | Object::Texture(_) => {
                if c.attr("id").is_none() {
                    loader.warnings.push(format!(
                        "{}:{}: top-level <{}> without `id` can never be referenced",
                        c.loc.file.display(),
                        c.loc.line,
                        c.tag
                    ));
                }
            }
            Object::AreaEmitter(_) => {
                return Err(c.loc.err("an area emitter must be nested inside a <shape>"));
            }
            o => {
                return Err(c.loc.err(format!(
                    "<{}> must be nested inside another element, not at the top level",
                    o.kind()
                )));
            }
        }
    }
    scene.warnings = loader.warnings;
    Ok(scene)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sphere_tessellation_is_closed_outward_and_close_to_the_sphere() {
        let m = sphere_mesh(SPHERE_SEGMENTS_PHI, SPHERE_SEGMENTS_THETA);
        assert_eq!(m.indices.len(), 2 * SPHERE_SEGMENTS_PHI * (SPHERE_SEGMENTS_THETA - 1));
        // Inscribed polyhedron: area slightly below 4π. For 128×64 the deficit is 0.050 %
        // (second-order in the angular step, computed independently in f64); bound 0.1 %.
        let a = m.area();
        let rel = (4.0 * std::f64::consts::PI - a) / (4.0 * std::f64::consts::PI);
        assert!(rel > 4e-4 && rel < 1e-3, "relative area deficit {rel}");
        // Every triangle faces outward and is non-degenerate.
        for i in 0..m.triangle_count() {
            let [a, b, c] = m.triangle(i);
            let n = (b - a).cross(c - a);
            assert!(n.length() > 0.0);
            assert!(n.dot(a + b + c) > 0.0, "triangle {i} faces inward");
        }
        // Divergence theorem: volume = Σ (a · (b × c)) / 6, slightly below 4π/3.
        let vol: f64 = (0..m.triangle_count())
            .map(|i| {
                let [a, b, c] = m.triangle(i);
                a.as_dvec3().dot(b.as_dvec3().cross(c.as_dvec3())) / 6.0
            })
            .sum();
        let rel_v = 1.0 - vol / (4.0 / 3.0 * std::f64::consts::PI);
        // Volume deficit 0.100 % (f64 computation of the same polyhedron).
        assert!(rel_v > 8e-4 && rel_v < 1.2e-3, "volume deficit {rel_v}");
    }

    /// Every (tag, type) of [`SUPPORTED_PLUGINS`] has a dispatch arm: instantiating a bare
    /// element may fail for missing parameters, never as "not supported".
    #[test]
    fn supported_table_matches_dispatch() {
        let dir = tempfile::tempdir().unwrap();
        for (tag, types) in SUPPORTED_PLUGINS {
            for ty in *types {
                let p = dir.path().join("s.xml");
                std::fs::write(&p, format!("<scene version=\"3.0.0\"><{tag} type=\"{ty}\"/></scene>"))
                    .unwrap();
                let mut r = XmlReader { params: HashMap::new(), stack: Vec::new() };
                let root = r.parse_file(&p, &[], None).unwrap();
                let mut l = Loader {
                    named: HashMap::new(),
                    ids: HashSet::new(),
                    warnings: Vec::new(),
                    n_shapes: 0,
                    n_sensors: 0,
                };
                if let Err(e) = l.instantiate(&root.children[0]) {
                    assert!(!e.to_string().contains("not supported"), "{tag} {ty}: {e}");
                }
            }
        }
    }

    #[test]
    fn cube_is_closed_and_outward() {
        let m = cube_mesh();
        assert_eq!(m.indices.len(), 12);
        assert!((m.area() - 24.0).abs() < 1e-6);
        let vol: f32 = (0..12)
            .map(|i| {
                let [a, b, c] = m.triangle(i);
                a.dot(b.cross(c)) / 6.0
            })
            .sum();
        assert!((vol - 8.0).abs() < 1e-5);
        for i in 0..12 {
            let [a, b, c] = m.triangle(i);
            let n = (b - a).cross(c - a).normalize();
            assert!((n - m.normals[m.indices[i][0] as usize]).length() < 1e-6);
        }
    }

    #[test]
    fn fov_conversion_matches_mitsuba_formulas() {
        // aspect 2: fov_y = 30° → tan(fov_x/2) = 2 tan(15°).
        let fx = fov_to_x(30.0, "y", 2.0).unwrap();
        assert!(((0.5 * fx.to_radians()).tan() - 2.0 * (15f64.to_radians()).tan()).abs() < 1e-12);
        assert_eq!(fov_to_x(30.0, "x", 2.0), Some(30.0));
        assert_eq!(fov_to_x(30.0, "larger", 2.0), Some(30.0));
        assert_eq!(fov_to_x(30.0, "smaller", 2.0), fov_to_x(30.0, "y", 2.0));
        assert_eq!(fov_to_x(30.0, "smaller", 0.5), Some(30.0));
        assert_eq!(fov_to_x(30.0, "larger", 0.5), fov_to_x(30.0, "y", 0.5));
        // Diagonal: the half-diagonal tangent splits by aspect: w² + h² = d², w/h = aspect.
        let d = 2.0 * (25f64.to_radians()).tan();
        let fx = fov_to_x(50.0, "diagonal", 4.0 / 3.0).unwrap();
        let w = 2.0 * (0.5 * fx.to_radians()).tan();
        let h = w * 3.0 / 4.0;
        assert!((w * w + h * h - d * d).abs() < 1e-12);
        assert!(fov_to_x(50.0, "z", 1.0).is_none());
    }

    #[test]
    fn angle_weighted_normals_of_a_tent() {
        // Two triangles meeting at 90°: the shared-edge vertices get the bisector.
        let mut m = TriangleMesh {
            positions: vec![
                Vec3::new(0., 0., 0.),
                Vec3::new(0., 1., 0.),
                Vec3::new(1., 0., 0.),
                Vec3::new(0., 0., 1.),
            ],
            indices: vec![[0, 2, 1], [0, 1, 3]],
            ..Default::default()
        };
        recompute_vertex_normals(&mut m);
        let s = std::f32::consts::FRAC_1_SQRT_2;
        // Face normals +z (0,2,1) and +x (0,1,3); right angles at vertex 0, 45° at vertex 1.
        assert!((m.normals[0] - Vec3::new(s, 0.0, s)).length() < 1e-6, "{:?}", m.normals[0]);
        assert!((m.normals[1] - Vec3::new(s, 0.0, s)).length() < 1e-6, "{:?}", m.normals[1]);
        assert!((m.normals[2] - Vec3::Z).length() < 1e-6);
        assert!((m.normals[3] - Vec3::X).length() < 1e-6);
    }
}
