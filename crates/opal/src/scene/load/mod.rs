//! Mitsuba 3 XML scene loader → [`SceneDesc`].
//!
//! The supported subset, the conventions and the error behaviour are documented for users in
//! `docs/scene-format.md`; in short:
//!
//! * Elements: `scene` (attribute `version`, major 2 or 3), `default`, `include`, `ref`,
//!   parameters (`float integer boolean string rgb spectrum point vector transform`) and the
//!   plugins listed in [`SUPPORTED_PLUGINS`]. Plugin dispatch is **one** `match` on
//!   `(tag, type)` in `Loader::instantiate` (`plugins`); adding a plugin is one arm there.
//! * `$name` in any attribute value is replaced by the caller's parameter, else by a
//!   `<default name= value=>` declared earlier in document order; an unset `$name` is an error.
//! * `to_world` transforms compose like Mitsuba: each new element is **left**-multiplied
//!   (`M ← T·M`), composed in f64 and rounded to f32 once.
//! * Meshes are returned in world space; analytic shapes are tessellated (rectangle 2
//!   triangles, cube 12, sphere [`SPHERE_SEGMENTS_PHI`]×[`SPHERE_SEGMENTS_THETA`]).
//! * Every element, attribute or parameter Opal does not understand is an error
//!   [`Error::Parse`](crate::error::Error::Parse) naming the XML file, line and column and
//!   the offending name — nothing is silently ignored. Errors from referenced files (meshes, images) are reported at the
//!   referencing XML element, with the inner error (its own file and line) in the message.
//!
//! Layout (private submodules): `xml` reads files into an element tree (substitution,
//! defaults, includes); `properties` parses parameter elements and references into typed
//! property lists; `transforms` composes `to_world` and applies it to meshes; `plugins` maps
//! each `(tag, type)` to its description (`bsdfs`: Mitsuba's metals, plastics and thin sheets; `emitters`: the emitters not attached to shapes; `instances`: `shapegroup`/`instance`, flattened). Analytic shapes are tessellated by
//! [`crate::geometry::shapes`] (re-exported here).
//!
//! Tests: unit tests in `plugins` (dispatch table, field of view) and
//! [`crate::geometry::shapes`] (tessellation), and `crates/opal/tests/scene_load.rs` (Cornell
//! box, every element, every error case).

mod bsdfs;
mod emitters;
mod instances;
mod plugins;
mod properties;
mod transforms;
mod xml;

pub use crate::geometry::shapes::{
    SPHERE_SEGMENTS_PHI, SPHERE_SEGMENTS_THETA, cube_mesh, rectangle_mesh, sphere_mesh,
};
pub use plugins::{SUPPORTED_PLUGINS, fov_to_x};
pub use transforms::{MAX_COORDINATE, look_at};

use crate::error::Result;
use crate::scene::desc::SceneDesc;
use plugins::{Loader, Object, PLUGIN_TAGS};
use std::collections::{HashMap, HashSet};
use std::path::Path;
use xml::XmlReader;

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
            Object::Shapes(v) => scene.shapes.extend(v),
            Object::ShapeGroup(_) => {}
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
