//! Mitsuba's `shapegroup` and `instance` shapes, flattened at load time.
//!
//! A `<shape type="shapegroup" id="g">` holds nested shapes and renders nothing by itself; each
//! `<shape type="instance">` with `<ref id="g"/>` and a `to_world` adds a copy of the group's
//! shapes with `to_world` applied after their own transforms (Mitsuba's composition: the
//! instance transform is applied to the group's world-space geometry). The copies are ordinary
//! meshes (no two-level BVH): memory grows with the instances, which suits the tens of repeated
//! objects of a captured room, not a forest of millions.
//!
//! Conventions: the copies' ids are `<instance id>.<shape id>` (usable as file names by the
//! outputs named after shapes; an instance without an id gets `instance_<k>`); like Mitsuba 3,
//! a group may not hold emitters (an error here), and a group must have an `id` (it can only be
//! used through a reference).
//!
//! Tests: `crates/opal/tests/scene_load.rs` (`instances_copy_and_transform_the_group`, error
//! cases) and the Mitsuba z-test `instance_scene_matches_mitsuba` in
//! `crates/opal/tests/mitsuba_materials.rs`.

use super::plugins::{Loader, Object};
use super::properties::Props;
use super::transforms::finalize_mesh;
use super::xml::Elem;
use crate::error::Result;
use crate::math::DMat4;
use crate::scene::desc::ShapeDesc;

impl Loader {
    /// `shape type="shapegroup"`: its nested shapes (instances inside a group are flattened too).
    pub(super) fn shapegroup(&mut self, e: &Elem, mut p: Props) -> Result<Object> {
        if e.attr("id").is_none() {
            return Err(e
                .loc
                .err(format!("{}: a shapegroup needs an `id` (instances refer to it)", e.describe())));
        }
        let mut shapes = Vec::new();
        for (o, l) in p.objects("shape") {
            let list = match o {
                Object::Shape(s) => vec![*s],
                Object::Shapes(v) => v,
                Object::ShapeGroup(_) => {
                    return Err(
                        l.err(format!("{}: a shapegroup cannot contain another shapegroup", e.describe()))
                    );
                }
                _ => unreachable!("objects(\"shape\") returns shapes"),
            };
            if let Some(s) = list.iter().find(|s| s.emitter.is_some()) {
                return Err(l.err(format!(
                    "{}: shape `{}` is an area emitter; emitters cannot be instanced (Mitsuba 3 rejects this too)",
                    e.describe(),
                    s.id
                )));
            }
            shapes.extend(list);
        }
        p.finish("nested <shape>s")?;
        if shapes.is_empty() {
            return Err(e.loc.err(format!("{}: the shapegroup holds no shape", e.describe())));
        }
        Ok(Object::ShapeGroup(shapes))
    }

    /// `shape type="instance"`: the referenced group's shapes, each with `to_world` applied.
    pub(super) fn instance(&mut self, e: &Elem, mut p: Props) -> Result<Object> {
        let to_world = p.transform("to_world")?.map_or(DMat4::IDENTITY, |t| t.0);
        let mut groups = p.objects("shape");
        if groups.len() != 1 {
            return Err(e.loc.err(format!(
                "{}: needs exactly one <ref id=\"...\"/> to a shapegroup, found {}",
                e.describe(),
                groups.len()
            )));
        }
        let (group, gloc) = groups.pop().expect("one");
        let Object::ShapeGroup(shapes) = group else {
            return Err(gloc.err(format!("{}: the reference must name a shapegroup", e.describe())));
        };
        p.finish("to_world, one <ref> to a shapegroup")?;
        let name = e.attr("id").map_or_else(|| format!("instance_{}", self.n_shapes), |a| a.value.clone());
        self.n_shapes += 1;
        let what = e.describe();
        let mut out = Vec::with_capacity(shapes.len());
        for s in shapes {
            let face_normals = s.mesh.normals.is_empty();
            let (mesh, dropped) = finalize_mesh(s.mesh, to_world, false, face_normals, &e.loc, &what)?;
            if dropped > 0 {
                self.warnings.push(format!(
                    "{}:{}: instance `{name}`: dropped {dropped} degenerate triangle(s) of `{}`",
                    e.loc.file.display(),
                    e.loc.line,
                    s.id
                ));
            }
            out.push(ShapeDesc {
                id: format!("{name}.{}", s.id),
                mesh,
                bsdf: s.bsdf,
                emitter: None,
                origin: Some(((*e.loc.file).clone(), e.loc.line)),
            });
        }
        Ok(Object::Shapes(out))
    }
}
