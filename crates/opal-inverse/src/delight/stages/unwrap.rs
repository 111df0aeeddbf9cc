//! Stage 1 of [`delight`](crate::delight::delight): the objects to recover
//! ([`select_objects`]: the named shapes or every non-emitting one) and their atlases
//! ([`unwrap_objects`]: own UVs when usable, else new charts; the resolution is the setting, else
//! the size of the object's square bitmap texture when its UVs are kept, else
//! [`atlas::auto_resolution`]). An object whose unwrap fails is skipped with a warning.
//! Tests: `tests/delight.rs`, the atlas tests in `atlas/tests.rs`.

use super::Inputs;
use crate::delight::views::View;
use crate::delight::{ObjectResult, atlas};
use opal::error::{Error, Result};
use opal::math::Vec3;
use opal::scene::Scene;
use opal::scene::desc::{BsdfDesc, TextureDesc};

/// Size of the bitmap reflectance of a diffuse (or two-sided diffuse) BSDF, if any.
fn existing_texture_size(b: &BsdfDesc) -> Option<(usize, usize)> {
    match b {
        BsdfDesc::Diffuse { reflectance: TextureDesc::Bitmap(bm) } => Some((bm.image.width, bm.image.height)),
        BsdfDesc::TwoSided(inner) => existing_texture_size(inner),
        _ => None,
    }
}

/// Shape indices to recover: the shapes named in `objects` (errors for unknown ids and
/// emitters), or every non-emitting shape.
pub(in crate::delight) fn select_objects(scene: &Scene, objects: Option<&[String]>) -> Result<Vec<usize>> {
    let selected: Vec<usize> = match objects {
        Some(names) => {
            let mut v = Vec::new();
            for n in names {
                let k = scene.shapes.iter().position(|sh| &sh.id == n).ok_or_else(|| {
                    let ids: Vec<&str> = scene.shapes.iter().map(|s| s.id.as_str()).collect();
                    Error::invalid(
                        format!("selected object {n}"),
                        format!("no shape with that id (have: {})", ids.join(", ")),
                    )
                })?;
                if scene.shapes[k].emission.is_some() {
                    return Err(Error::invalid(
                        format!("selected object {n}"),
                        "is an emitter; only non-emitting shapes can be recovered",
                    ));
                }
                v.push(k);
            }
            v
        }
        None => (0..scene.shapes.len()).filter(|&k| scene.shapes[k].emission.is_none()).collect(),
    };
    if selected.is_empty() {
        return Err(Error::invalid("scene", "no non-emitting shape to recover"));
    }
    Ok(selected)
}

/// Atlases of the `selected` shapes: the recovered objects (maps zeroed) and the skipped ones
/// (id, reason; also pushed to `warnings`).
pub(in crate::delight) fn unwrap_objects(
    inp: &Inputs,
    selected: &[usize],
    views: &[View],
    warnings: &mut Vec<String>,
) -> (Vec<ObjectResult>, Vec<(String, String)>) {
    let (desc, s, log) = (inp.desc, inp.s, inp.log);
    let cams: Vec<(Vec3, f32, usize)> =
        views.iter().map(|v| (v.camera.origin(), v.camera.tan_half_x, v.camera.width)).collect();
    let mut objects = Vec::new();
    let mut skipped = Vec::new();
    for &k in selected {
        let sh = &desc.shapes[k];
        // an object that keeps its UVs and already has a square bitmap texture gets a texture
        // of the same size (the recovered map replaces it texel for texel); otherwise adaptive
        let tex_res = existing_texture_size(&sh.bsdf).filter(|&(w, h)| w == h && s.keep_uvs).map(|(w, _)| w);
        let auto = || atlas::auto_resolution(&sh.mesh, &cams);
        let res = s.resolution.or(tex_res).unwrap_or_else(auto);
        let built = match atlas::build_atlas(&sh.mesh, res, s.keep_uvs) {
            Ok(a) if !a.kept_uvs && s.resolution.is_none() && tex_res.is_some() => {
                atlas::build_atlas(&sh.mesh, auto(), s.keep_uvs)
            }
            other => other,
        };
        match built {
            Ok(a) => {
                let n = a.width * a.height;
                log(&format!(
                    "atlas {}: {}×{}, {} chart(s), {} UVs",
                    sh.id,
                    a.width,
                    a.height,
                    a.charts,
                    if a.kept_uvs { "kept" } else { "new" }
                ));
                objects.push(ObjectResult {
                    shape: k,
                    id: sh.id.clone(),
                    atlas: a,
                    l: vec![[0.0; 3]; n],
                    observed: vec![false; n],
                    ed: vec![[0.0; 3]; n],
                    ei: vec![[0.0; 3]; n],
                    kd: vec![[0.0; 3]; n],
                    near_emitter: false,
                    seen_fraction: 0.0,
                    clamped: 0,
                });
            }
            Err(e) => {
                warnings.push(format!("object '{}' skipped: UV unwrap failed: {e}", sh.id));
                skipped.push((sh.id.clone(), format!("UV unwrap failed: {e}")));
            }
        }
    }
    (objects, skipped)
}
