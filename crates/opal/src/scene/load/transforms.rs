//! Transforms for the Mitsuba loader: `<transform>` elements composed into a matrix, and a
//! shape's `to_world` applied to its mesh.
//!
//! Conventions (as Mitsuba): the children `translate`, `rotate` (axis + `angle` in degrees),
//! `scale` (3 numbers or 1, uniform), `matrix` (16 numbers row-major, or 9 for the linear
//! part) and `lookat` (`origin`, `target`, `up`; see [`look_at`]) are applied in document
//! order, each new one **left**-multiplied (`M ← T·M`); composition is in f64 and the result is
//! rounded to f32 once. Normals are transformed by the inverse transpose; singular
//! `to_world` matrices, vertices beyond ±[`MAX_COORDINATE`] in world space and meshes left with
//! only degenerate triangles are errors.
//!
//! Tests: `crates/opal/tests/scene_load.rs` (composition order, every transform element and
//! its error cases, degenerate meshes).

use super::properties::{parse_float, parse_floats, parse_vec_attr, parse_xyz};
use super::xml::{Elem, Loc};
use crate::error::Result;
use crate::geometry::TriangleMesh;
use crate::geometry::shapes::recompute_vertex_normals;
use crate::math::{DMat4, DVec3, Mat4};

/// Mitsuba's `look_at`: columns left = normalize(up × dir), up' = dir × left, dir, origin.
pub fn look_at(origin: DVec3, target: DVec3, up: DVec3) -> Option<DMat4> {
    let dir = (target - origin).normalize();
    let left = up.normalize().cross(dir).normalize();
    let new_up = dir.cross(left);
    let m = DMat4::from_cols(left.extend(0.0), new_up.extend(0.0), dir.extend(0.0), origin.extend(1.0));
    m.is_finite().then_some(m)
}

/// Parses the children of a `<transform>`, composing like Mitsuba (`M ← T·M`).
pub(super) fn parse_transform(e: &Elem) -> Result<DMat4> {
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

pub(super) fn to_mat4(m: DMat4) -> Mat4 {
    m.as_mat4()
}

/// Applies `to_world`, drops degenerate triangles, sets up normals; returns the number of
/// dropped triangles.
/// Largest world-space coordinate a mesh vertex may have: the f32 intersection code squares
/// edge lengths and coordinates (f32 overflows at 3.4e38), so 1e18 keeps every product finite.
pub const MAX_COORDINATE: f64 = 1e18;

pub(super) fn finalize_mesh(
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
    for (k, p) in m.positions.iter_mut().enumerate() {
        let w = to_world.transform_point3(p.as_dvec3());
        if !w.is_finite() || w.abs().max_element() > MAX_COORDINATE {
            return Err(loc.err(format!(
                "{what}: vertex {k} lands at ({:e}, {:e}, {:e}) in world space, beyond ±{MAX_COORDINATE:e} \
                 (the f32 tracer squares coordinates; scale the scene down)",
                w.x, w.y, w.z
            )));
        }
        *p = w.as_vec3();
    }
    for (k, n) in m.normals.iter_mut().enumerate() {
        let t64 = nmat * n.as_dvec3();
        // In f32 first (the usual path); in f64 when the f32 length under- or overflows (huge
        // or tiny scales, e.g. coordinates of 1e30).
        *n = t64.as_vec3().try_normalize().or_else(|| t64.try_normalize().map(|u| u.as_vec3())).ok_or_else(
            || {
                loc.err(format!(
                    "{what}: vertex normal {k} is zero or not finite after to_world ({n} → {t64})"
                ))
            },
        )?;
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
