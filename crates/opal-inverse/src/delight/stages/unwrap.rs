//! Stage 1 of [`delight`](crate::delight::delight): the objects to recover
//! ([`select_objects`]: the named shapes or every non-emitting one) and their atlases
//! ([`unwrap_objects`]: own UVs when usable, else new charts; the resolution is the setting, else
//! the size of the object's square bitmap texture when its UVs are kept, else from the cameras'
//! pixel footprints, [`footprint`]). An object whose unwrap fails is skipped with a warning.
//! Tests: `tests/delight.rs`, the atlas tests in `atlas/tests.rs`.

use super::Inputs;
use crate::delight::footprint::{self, ResolutionRule};
use crate::delight::views::View;
use crate::delight::{ObjectResult, atlas};
use opal::camera::Camera;
use opal::error::{Error, Result};
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
    let cams: Vec<Camera> = views.iter().map(|v| v.camera.clone()).collect();
    let mut objects = Vec::new();
    let mut skipped = Vec::new();
    for &k in selected {
        let sh = &desc.shapes[k];
        let samples = footprint::surface_footprints(inp.scene, &sh.mesh, &cams);
        // an object that keeps its UVs and already has a square bitmap texture gets a texture
        // of the same size (the recovered map replaces it texel for texel); otherwise from the
        // cameras
        let tex_res = existing_texture_size(&sh.bsdf).filter(|&(w, h)| w == h && s.keep_uvs).map(|(w, _)| w);
        let from_cameras = || {
            footprint::camera_atlas(&sh.mesh, &samples, s.keep_uvs, s.max_resolution)
                .map(|(a, u)| (a, ResolutionRule::Cameras, u))
        };
        let built = match (s.resolution, tex_res) {
            (Some(r), _) => {
                atlas::build_atlas(&sh.mesh, r, s.keep_uvs).map(|a| (a, ResolutionRule::Setting, None))
            }
            (None, Some(r)) => match atlas::build_atlas(&sh.mesh, r, s.keep_uvs) {
                Ok(a) if !a.kept_uvs => from_cameras(),
                other => other.map(|a| (a, ResolutionRule::ExistingTexture, None)),
            },
            (None, None) => from_cameras(),
        };
        let built = built.map(|(a, rule, unclamped)| {
            let c = footprint::resolution_choice(rule, unclamped, &samples, &a);
            (a, c)
        });
        match built {
            Ok((a, resolution)) => {
                let n = a.width * a.height;
                log(&format!(
                    "atlas {}: {}×{}, {} chart(s), {} UVs; resolution from the {}, {:.0} % of the surface \
                     seen, best-seen part {} pixels / {} texels per unit²",
                    sh.id,
                    a.width,
                    a.height,
                    a.charts,
                    if a.kept_uvs { "kept" } else { "new" },
                    resolution.rule.name().replace('_', " "),
                    100.0 * resolution.seen_area_fraction,
                    resolution.pixel_density.map_or("-".into(), |d| format!("{d:.4e}")),
                    resolution.texel_density.map_or("-".into(), |d| format!("{d:.4e}")),
                ));
                objects.push(ObjectResult {
                    shape: k,
                    id: sh.id.clone(),
                    atlas: a,
                    resolution,
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
