//! Emitter plugins of the Mitsuba loader that are not attached to shapes: `point`,
//! `constant`, `envmap`, `spot`, `directional` (their parameters, Mitsuba's defaults, and the
//! errors for what Opal does not read). Range checks happen in the scene builder.
//!
//! Tests: `crates/opal/tests/scene_load.rs` (parameters and error cases).

use super::plugins::Object;
use super::properties::Props;
use super::transforms::to_mat4;
use super::xml::Elem;
use crate::error::Result;
use crate::image::read::{read_image_decoded, srgb_to_linear};
use crate::math::{DMat4, DVec3};
use crate::scene::desc::EmitterDesc;
use crate::spectrum::Spectrum;
use std::sync::Arc;

/// `emitter type="point"`: `position` or `to_world`, and `intensity`.
pub(super) fn point_emitter(mut p: Props) -> Result<Object> {
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
    Ok(Object::Emitter(EmitterDesc::Point { position: position.as_vec3(), intensity }))
}

/// `emitter type="constant"`: `radiance` (default 1).
pub(super) fn constant_emitter(mut p: Props) -> Result<Object> {
    let radiance = p.color("radiance")?.map_or(Spectrum::ONE, |c| c.0);
    p.finish("radiance")?;
    Ok(Object::Emitter(EmitterDesc::Constant { radiance }))
}

/// `emitter type="envmap"`: `filename` (EXR or HDR; PNG is sRGB-decoded), `scale` (default 1),
/// `to_world`.
pub(super) fn envmap_emitter(e: &Elem, mut p: Props) -> Result<Object> {
    let (fname, floc) = p
        .string_at("filename")?
        .ok_or_else(|| e.loc.err(format!("{}: `filename` is required", e.describe())))?;
    let scale = p.float_at("scale")?.map_or(1.0, |v| v.0) as f32;
    let to_world = p.transform("to_world")?.map_or(DMat4::IDENTITY, |t| t.0);
    p.finish("filename, scale, to_world")?;
    let path = e.resolve(&fname);
    let dec = read_image_decoded(&path).map_err(|err| floc.err(format!("envmap: {err}")))?;
    let mut image = dec.image;
    if dec.srgb_encoded {
        for v in &mut image.data {
            *v = v.map(srgb_to_linear);
        }
    }
    Ok(Object::Emitter(EmitterDesc::EnvMap {
        image: Arc::new(image),
        scale,
        to_world: to_mat4(to_world),
        path,
    }))
}

/// `emitter type="spot"`: `to_world`, `intensity` (default 1), `cutoff_angle` (default 20°),
/// `beam_width` (default ¾ of the cut-off), `texture`.
pub(super) fn spot_emitter(mut p: Props) -> Result<Object> {
    let to_world = p.transform("to_world")?.map_or(DMat4::IDENTITY, |t| t.0);
    let intensity = p.color("intensity")?.map_or(Spectrum::ONE, |c| c.0);
    let cutoff = p.float_at("cutoff_angle")?.map_or(20.0, |v| v.0);
    let beam = p.float_at("beam_width")?.map_or(0.75 * cutoff, |v| v.0);
    let texture = p.texture("texture")?;
    p.finish("to_world, intensity, cutoff_angle, beam_width, texture")?;
    Ok(Object::Emitter(EmitterDesc::Spot {
        to_world: to_mat4(to_world),
        intensity,
        cutoff_deg: cutoff as f32,
        beam_width_deg: beam as f32,
        texture,
    }))
}

/// `emitter type="directional"`: `irradiance` (default 1) and `direction` or `to_world`
/// (local +z; default +z).
pub(super) fn directional_emitter(mut p: Props) -> Result<Object> {
    let irradiance = p.color("irradiance")?.map_or(Spectrum::ONE, |c| c.0);
    let dir = p.point("direction")?;
    let tw = p.transform("to_world")?;
    let direction = match (dir, tw) {
        (Some(_), Some((_, l))) => {
            return Err(l.err("directional emitter: give either `direction` or `to_world`, not both"));
        }
        (Some(d), None) => d,
        (None, Some((m, _))) => m.transform_vector3(DVec3::Z),
        (None, None) => DVec3::Z,
    };
    p.finish("irradiance, direction, to_world")?;
    Ok(Object::Emitter(EmitterDesc::Directional {
        direction: direction.normalize_or_zero().as_vec3(),
        irradiance,
    }))
}
