//! Stage 1 of [`delight`](crate::delight::delight): the objects to recover
//! ([`select_objects`]: the named shapes or every non-emitting diffuse one; non-diffuse shapes keep their material) and their atlases
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
use opal::scene::material::Material;

/// Size of the bitmap reflectance of a diffuse (or two-sided diffuse) BSDF, if any.
fn existing_texture_size(b: &BsdfDesc) -> Option<(usize, usize)> {
    match b {
        BsdfDesc::Diffuse { reflectance: TextureDesc::Bitmap(bm) } => Some((bm.image.width, bm.image.height)),
        BsdfDesc::TwoSided(inner) => existing_texture_size(inner),
        _ => None,
    }
}

/// Whether a shape's material is (one- or two-sided) diffuse, i.e. recoverable as an albedo.
fn is_diffuse(m: &Material) -> bool {
    matches!(m, Material::Diffuse { .. })
}

/// Shapes left out of the recovery: (id, reason).
pub(in crate::delight) type LeftOut = Vec<(String, String)>;

/// The model's name of a non-diffuse material (`RoughConductor`, `RoughPlastic`, ...).
fn material_kind(m: &Material) -> String {
    let b = match m {
        Material::Diffuse { .. } => return "Diffuse".into(),
        Material::Coated { bxdf, .. } | Material::Model { bxdf, .. } => bxdf,
    };
    let d = format!("{b:?}");
    d.split(['(', ' ', '{']).next().unwrap_or("").to_string()
}

/// Why shape `k` is not recovered when it is not selected: an emitter, a non-diffuse material
/// (kept as given, part of the light transport), or (with named objects) not named.
fn left_out_reason(scene: &Scene, k: usize) -> String {
    let sh = &scene.shapes[k];
    if sh.emission.is_some() {
        "emitter".into()
    } else if !is_diffuse(&sh.material) {
        format!(
            "non-diffuse material ({}): kept as given in the light transport",
            material_kind(&sh.material)
        )
    } else {
        "not selected".into()
    }
}

/// Shape indices to recover: the shapes named in `objects` (errors for unknown ids, emitters and
/// non-diffuse shapes), or every non-emitting diffuse shape; and the shapes left out with the
/// reason (id, reason). Non-diffuse shapes keep their material and take part in the light
/// transport.
pub(in crate::delight) fn select_objects(
    scene: &Scene,
    objects: Option<&[String]>,
) -> Result<(Vec<usize>, LeftOut)> {
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
                if !is_diffuse(&scene.shapes[k].material) {
                    return Err(Error::invalid(
                        format!("selected object {n}"),
                        "is not diffuse; only diffuse shapes can be recovered (non-diffuse shapes keep their material)",
                    ));
                }
                v.push(k);
            }
            v
        }
        None => (0..scene.shapes.len())
            .filter(|&k| scene.shapes[k].emission.is_none() && is_diffuse(&scene.shapes[k].material))
            .collect(),
    };
    if selected.is_empty() {
        return Err(Error::invalid("scene", "no non-emitting diffuse shape to recover"));
    }
    let left_out = (0..scene.shapes.len())
        .filter(|k| !selected.contains(k))
        .map(|k| (scene.shapes[k].id.clone(), left_out_reason(scene, k)))
        .collect();
    Ok((selected, left_out))
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

#[cfg(test)]
mod tests {
    use super::*;
    use opal::bsdf::{Bxdfs, Phong};
    use opal::geometry::TriangleMesh;
    use opal::math::Vec3;
    use opal::scene::desc::{SceneDesc, ShapeDesc};
    use opal::spectrum::Spectrum;

    fn quad(id: &str, z: f32, bsdf: BsdfDesc) -> ShapeDesc {
        let v = Vec3::new;
        ShapeDesc {
            id: id.into(),
            mesh: TriangleMesh {
                positions: vec![v(0., 0., z), v(1., 0., z), v(1., 1., z), v(0., 1., z)],
                normals: vec![],
                uvs: vec![],
                indices: vec![[0, 1, 2], [0, 2, 3]],
            },
            bsdf,
            emitter: None,
            origin: None,
        }
    }

    /// Default selection: diffuse (and two-sided diffuse) shapes only; a non-diffuse shape keeps
    /// its material; naming it explicitly is an error.
    #[test]
    fn default_selection_skips_non_diffuse() {
        let diffuse = || BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(Spectrum::splat(0.5)) };
        let desc = SceneDesc {
            shapes: vec![
                quad("wall", 0., diffuse()),
                quad("metal", 1., BsdfDesc::Lobe(Bxdfs::Phong(Phong::new(20.0, 1.0, Spectrum::splat(0.8))))),
                quad("back", 2., BsdfDesc::TwoSided(Box::new(diffuse()))),
            ],
            ..Default::default()
        };
        let scene = Scene::build(&desc).unwrap();
        let (sel, left_out) = select_objects(&scene, None).unwrap();
        assert_eq!(sel, vec![0, 2]);
        assert_eq!(left_out.len(), 1);
        assert_eq!(left_out[0].0, "metal");
        assert!(left_out[0].1.starts_with("non-diffuse material (Phong)"), "{left_out:?}");
        let (sel, left_out) = select_objects(&scene, Some(&["back".to_string()])).unwrap();
        assert_eq!(sel, vec![2]);
        assert_eq!(left_out[0], ("wall".to_string(), "not selected".to_string()));
        assert_eq!(left_out[1].0, "metal");
        let err = select_objects(&scene, Some(&["metal".to_string()])).unwrap_err().to_string();
        assert!(err.contains("not diffuse"), "{err}");
    }
}
