//! Plugins for the Mitsuba loader: the `(tag, type)` → description mapping. [`Loader`]
//! instantiates each plugin element (shapes, bsdfs, textures, emitters, sensors with their
//! film and sampler, reconstruction filters, integrators) into an [`Object`] that becomes part
//! of the [`SceneDesc`].
//!
//! Conventions: plugin dispatch is **one** `match` on `(tag, type)` in
//! `Loader::instantiate`; adding a plugin is one arm there plus its name in
//! [`SUPPORTED_PLUGINS`] (a unit test checks the two agree). Unsupported plugins are rejected
//! before their children are read; each plugin reads its parameters through [`Props`] and
//! rejects the ones it does not know. Defaults are Mitsuba's (film 768×576, 4 samples per
//! pixel, diffuse reflectance 0.5, 50 mm focal length, ...). Analytic shapes are tessellated by [`crate::geometry::shapes`]; errors from meshes
//! and images are reported at the referencing element.
//!
//! Tests: unit tests below (dispatch table, field-of-view conversion) and
//! `crates/opal/tests/scene_load.rs` (every plugin and its error cases).

use super::properties::{Props, Val};
use super::transforms::{finalize_mesh, to_mat4};
use super::xml::{Elem, Loc};
use crate::error::{Error, Result};
use crate::geometry::TriangleMesh;
use crate::geometry::shapes::{
    CYLINDER_SEGMENTS_PHI, DISK_SEGMENTS_PHI, DISK_SEGMENTS_R, SPHERE_SEGMENTS_PHI, SPHERE_SEGMENTS_THETA,
    cube_mesh, cylinder_mesh, disk_mesh, rectangle_mesh, sphere_mesh,
};
use crate::image::read::{read_image_decoded, srgb_to_linear_all};
use crate::math::{DMat4, DVec3};
use crate::scene::desc::*;
use crate::spectrum::Spectrum;
use std::collections::{HashMap, HashSet};
use std::path::PathBuf;
use std::sync::Arc;

/// Mitsuba plugins Opal understands: `(tag, types)`. Any other `type` is an error, reported
/// before the element's children are read. Adding a plugin = one arm in
/// `Loader::instantiate` + its name here (a unit test checks the two agree).
pub const SUPPORTED_PLUGINS: &[(&str, &[&str])] = &[
    ("shape", &["obj", "ply", "rectangle", "cube", "sphere", "disk", "cylinder", "shapegroup", "instance"]),
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
            "blendbsdf",
            "conductor",
            "roughconductor",
            "plastic",
            "roughplastic",
            "thindielectric",
        ],
    ),
    ("texture", &["bitmap"]),
    ("emitter", &["area", "point", "constant", "envmap", "spot", "directional"]),
    ("sensor", &["perspective"]),
    ("film", &["hdrfilm"]),
    ("sampler", &["independent"]),
    ("rfilter", &["box"]),
    ("integrator", &["path"]),
];

/// Plugin tags Mitsuba knows (a tag outside this list is "unknown element").
pub(super) const PLUGIN_TAGS: &[&str] = &[
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

/// Film settings (only the size travels into [`SensorDesc`]).
#[derive(Clone, Debug)]
pub(super) struct FilmDesc {
    width: usize,
    height: usize,
    has_rfilter: bool,
}

/// An instantiated plugin.
#[derive(Clone, Debug)]
pub(super) enum Object {
    Shape(Box<ShapeDesc>),
    /// A `shapegroup`'s shapes (rendered only through instances).
    ShapeGroup(Vec<ShapeDesc>),
    /// An `instance`: copies of a group's shapes in world space.
    Shapes(Vec<ShapeDesc>),
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
    /// The plugin tag of this object (`emitter` for both emitter kinds).
    pub(super) fn kind(&self) -> &'static str {
        match self {
            Object::Shape(_) | Object::ShapeGroup(_) | Object::Shapes(_) => "shape",
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

/// Instantiates plugins; keeps what spans the document (ids, references, warnings, counters).
pub(super) struct Loader {
    /// Referenceable objects (`bsdf`, `texture` with an `id`).
    pub(super) named: HashMap<String, Object>,
    pub(super) ids: HashSet<String>,
    pub(super) warnings: Vec<String>,
    pub(super) n_shapes: usize,
    pub(super) n_sensors: usize,
}

/// The error for a `(tag, type)` Opal has no plugin for, listing the supported types.
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
    /// Instantiates one plugin element. **The** plugin dispatch: one arm per (tag, type).
    pub(super) fn instantiate(&mut self, e: &Elem) -> Result<Object> {
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
            ) => bsdf_lobe(e, &ty, p)?,
            ("bsdf", "dielectric") => bsdf_dielectric(e, p)?,
            ("bsdf", "conductor" | "roughconductor" | "plastic" | "roughplastic" | "thindielectric") => {
                super::bsdfs::bsdf_mitsuba_material(e, &ty, p, &mut self.warnings)?
            }
            ("bsdf", "blendbsdf") => bsdf_blend(e, p)?,
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
            ("shape", "obj" | "ply" | "rectangle" | "cube" | "sphere" | "disk" | "cylinder") => {
                Object::Shape(Box::new(self.shape(e, &ty, &mut p)?))
            }
            ("shape", "shapegroup") => self.shapegroup(e, p)?,
            ("shape", "instance") => self.instance(e, p)?,
            ("emitter", "area") => {
                let (radiance, _) = p
                    .color("radiance")?
                    .ok_or_else(|| e.loc.err(format!("{}: `radiance` is required", e.describe())))?;
                p.finish("radiance")?;
                Object::AreaEmitter(AreaEmitterDesc { radiance })
            }
            ("emitter", "point") => super::emitters::point_emitter(p)?,
            ("emitter", "constant") => super::emitters::constant_emitter(p)?,
            ("emitter", "envmap") => super::emitters::envmap_emitter(e, p)?,
            ("emitter", "spot") => super::emitters::spot_emitter(p)?,
            ("emitter", "directional") => super::emitters::directional_emitter(p)?,
            ("sensor", "perspective") => Object::Sensor(Box::new(self.sensor(e, &mut p)?)),
            ("film", "hdrfilm") => self.film(p)?,
            ("sampler", "independent") => sampler(p)?,
            ("rfilter", "box") => {
                p.finish("")?;
                Object::RFilter
            }
            ("integrator", "path") => integrator(p)?,
            (tag, ty) => return Err(unsupported(tag, ty, e)),
        };
        if let Some(id) = e.attr("id") {
            if !self.ids.insert(id.value.clone()) {
                return Err(id.loc.err(format!("duplicate id `{}`", id.value)));
            }
            if matches!(obj, Object::Bsdf(_) | Object::Texture(_) | Object::ShapeGroup(_)) {
                self.named.insert(id.value.clone(), obj.clone());
            }
        }
        Ok(obj)
    }

    /// `film type="hdrfilm"`: the size; formats other than RGB(A) float EXR are errors.
    fn film(&mut self, mut p: Props) -> Result<Object> {
        let w = p.int_at("width")?;
        let h = p.int_at("height")?;
        let mut size = [768usize, 576];
        for (k, v) in [w, h].into_iter().enumerate() {
            if let Some((v, l)) = v {
                if v <= 0 || v > 1 << 16 {
                    return Err(
                        l.err(format!("film {} must be in 1..=65536, got {v}", ["width", "height"][k]))
                    );
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
                    return Err(l.err(format!("film pixel_format \"{other}\" is not supported (rgb, rgba)")));
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
        if let Some((f, l)) = p.string_at("file_format")?
            && !f.eq_ignore_ascii_case("openexr")
            && !f.eq_ignore_ascii_case("exr")
        {
            return Err(l.err(format!("film file_format \"{f}\" is not supported (openexr)")));
        }
        let has_rfilter = p.object("rfilter")?.is_some();
        p.finish(
            "width, height, file_format, pixel_format, component_format, a nested <rfilter type=\"box\">",
        )?;
        Ok(Object::Film(FilmDesc { width: size[0], height: size[1], has_rfilter }))
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
            srgb_to_linear_all(&mut image.data);
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
            "disk" => Source::Mesh(disk_mesh(DISK_SEGMENTS_PHI, DISK_SEGMENTS_R), DMat4::IDENTITY),
            "cylinder" => {
                let p0 = p.point("p0")?.unwrap_or(DVec3::ZERO);
                let p1 = p.point("p1")?.unwrap_or(DVec3::Z);
                let radius = match p.float_at("radius")? {
                    None => 1.0,
                    Some((r, l)) => {
                        if !(r > 0.0 && r.is_finite()) {
                            return Err(l.err(format!("cylinder radius must be > 0, got {r}")));
                        }
                        r
                    }
                };
                let d = p1 - p0;
                let len = d.length();
                if !(len > 0.0 && len.is_finite()) {
                    return Err(e.loc.err(format!("{what}: p0 and p1 must differ")));
                }
                supported = "p0, p1, radius, to_world, flip_normals, a nested <bsdf>, a nested <emitter type=\"area\">";
                Source::Mesh(cylinder_mesh(CYLINDER_SEGMENTS_PHI), cylinder_frame(p0, d / len, radius, len))
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
        let (mesh, local) = source.load(&what)?;
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
        let fov_x_deg = sensor_fov_x(e, p, aspect)?;
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

/// Mitsuba's local transform of a `cylinder`: translate(p0) · to_frame(Frame(axis)) ·
/// scale(radius, radius, length), the frame built as Mitsuba's `coordinate_system` (Duff et al.
/// 2017, the same as [`crate::math::Frame::from_normal`]) so that uvs land the same way.
fn cylinder_frame(p0: DVec3, n: DVec3, radius: f64, len: f64) -> DMat4 {
    let sign = 1.0f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    let s = DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
    let t = DVec3::new(b, sign + n.y * n.y * a, -n.y);
    DMat4::from_translation(p0)
        * DMat4::from_cols(s.extend(0.0), t.extend(0.0), n.extend(0.0), glam::DVec4::W)
        * DMat4::from_scale(DVec3::new(radius, radius, len))
}

/// Where a shape's mesh comes from: a file (read after all parameters are checked) or a
/// tessellated analytic shape with its local transform.
enum Source {
    Obj(PathBuf, Loc, bool),
    Ply(PathBuf, Loc),
    Mesh(TriangleMesh, DMat4),
}

impl Source {
    /// The mesh and its local transform; file errors are reported at `filename` as `what: ...`.
    fn load(self, what: &str) -> Result<(TriangleMesh, DMat4)> {
        Ok(match self {
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
        })
    }
}

/// The lobe plugins of the BSDF registry (`phong`, ..., `roughdielectric`).
fn bsdf_lobe(e: &Elem, ty: &str, mut p: Props) -> Result<Object> {
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
    let mut pp = PluginParams::new(ty);
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
    Ok(Object::Bsdf(BsdfDesc::Lobe(b)))
}

/// `bsdf type="dielectric"`: a smooth dielectric with Mitsuba's default indices.
fn bsdf_dielectric(e: &Elem, mut p: Props) -> Result<Object> {
    // Mitsuba's defaults: int_ior = 1.5046 (bk7), ext_ior = 1.000277 (air)
    let mut ior = |name: &str, default: f64| -> Result<f64> {
        match p.float_at(name)? {
            None => Ok(default),
            Some((v, _)) if v.is_finite() && v > 0.0 => Ok(v),
            Some((v, l)) => {
                Err(l.err(format!("{}: `{name}` must be a positive number, got {v}", e.describe())))
            }
        }
    };
    let int_ior = ior("int_ior", 1.5046)?;
    let ext_ior = ior("ext_ior", 1.000277)?;
    p.finish("int_ior, ext_ior (numbers)")?;
    let b = crate::bsdf::SmoothDielectric::new((int_ior / ext_ior) as f32).map_err(|err| {
        e.loc.err(format!("{}: int_ior {int_ior} / ext_ior {ext_ior}: {err}", e.describe()))
    })?;
    Ok(Object::Bsdf(BsdfDesc::Lobe(crate::bsdf::Bxdfs::SmoothDielectric(b))))
}

/// `bsdf type="blendbsdf"` (Mitsuba's name and meaning): `weight` w ∈ [0, 1] and two nested
/// dielectric interfaces; the result is `(1 − w)·first + w·second`, an area mixture
/// ([`crate::bsdf::Dotted`] with coverage w on the second: a dotted face is the polished
/// `dielectric` first and the rough `roughdielectric` dots second).
fn bsdf_blend(e: &Elem, mut p: Props) -> Result<Object> {
    let w = match p.float_at("weight")? {
        None => 0.5,
        Some((v, _)) if (0.0..=1.0).contains(&v) => v,
        Some((v, l)) => return Err(l.err(format!("{}: `weight` must be in [0, 1], got {v}", e.describe()))),
    };
    let inner = p.objects("bsdf");
    p.finish("weight and two nested <bsdf>")?;
    let lobes: Vec<crate::bsdf::Bxdfs> = inner
        .into_iter()
        .filter_map(|(o, _)| match o {
            Object::Bsdf(BsdfDesc::Lobe(b)) => Some(b),
            _ => None,
        })
        .collect();
    let [first, second]: [crate::bsdf::Bxdfs; 2] = lobes.try_into().map_err(|v: Vec<_>| {
        e.loc.err(format!(
            "{}: needs exactly two nested dielectric <bsdf> (dielectric, roughdielectric, tabulated), found {} usable",
            e.describe(),
            v.len()
        ))
    })?;
    let d = crate::bsdf::Dotted::new(w as f32, second, first)
        .map_err(|err| e.loc.err(format!("{}: {err}", e.describe())))?;
    Ok(Object::Bsdf(BsdfDesc::Lobe(crate::bsdf::Bxdfs::Dotted(d))))
}

/// `sampler type="independent"`: the sample count (Mitsuba's default 4).
fn sampler(mut p: Props) -> Result<Object> {
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
    Ok(Object::Sampler(spp))
}

/// `integrator type="path"`: `max_depth`, `rr_depth`, `hide_emitters`.
fn integrator(mut p: Props) -> Result<Object> {
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
    Ok(Object::Integrator(d))
}

/// The sensor's horizontal field of view in degrees, from `fov` (+ `fov_axis`) or
/// `focal_length` (Mitsuba's default 50 mm), for a film `aspect = width / height`.
fn sensor_fov_x(e: &Elem, p: &mut Props, aspect: f64) -> Result<f64> {
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
    fov_to_x(fov_deg, &axis_name, aspect).ok_or_else(|| {
        axis_loc.err(format!("fov_axis \"{axis_name}\" is not supported (x, y, diagonal, smaller, larger)"))
    })
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

#[cfg(test)]
mod tests {
    use super::super::xml::XmlReader;
    use super::*;

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
}
