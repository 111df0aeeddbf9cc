//! Stage 1 of [`delight`](crate::delight::delight): the objects to recover
//! ([`select_objects`]: the named shapes or every non-emitting diffuse one; non-diffuse shapes keep their material) and their atlases
//! ([`unwrap_objects`]: own UVs when usable, else new charts; the resolution is the setting, else
//! the size of the object's square bitmap texture when its UVs are kept, else from the cameras'
//! pixel footprints, [`footprint`]). An object whose unwrap fails is skipped with a warning.
//! Tests: `tests/delight.rs`, the atlas tests in `atlas/tests.rs`.

use super::Inputs;
use crate::delight::footprint::{self, ResolutionChoice, ResolutionRule};
use crate::delight::progress::Stage;
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

/// An unwrapped object: its atlas and how its resolution was chosen, or why the unwrap failed.
type Unwrapped = std::result::Result<(atlas::Atlas, ResolutionChoice), String>;

/// Atlas of shape `k` (own UVs when usable, else new charts) and its resolution choice.
fn unwrap_one(inp: &Inputs, k: usize, cams: &[Camera]) -> Unwrapped {
    let (desc, s) = (inp.desc, inp.s);
    let sh = &desc.shapes[k];
    let samples = footprint::surface_footprints(inp.scene, &sh.mesh, cams);
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
    built
        .map(|(a, rule, unclamped)| {
            let c = footprint::resolution_choice(rule, unclamped, &samples, &a);
            (a, c)
        })
        .map_err(|e| e.to_string())
}

/// Atlases of the `selected` shapes: the recovered objects (maps zeroed) and the skipped ones
/// (id, reason; also pushed to `warnings`). Under several processes the shapes are split across
/// them (shape `i` of the selection on rank `i mod size`) and each atlas is sent whole to the
/// others ([`wire`]).
pub(in crate::delight) fn unwrap_objects(
    inp: &Inputs,
    selected: &[usize],
    views: &[View],
    warnings: &mut Vec<String>,
) -> (Vec<ObjectResult>, Vec<(String, String)>) {
    let (desc, s, log) = (inp.desc, inp.s, inp.log);
    let cams: Vec<Camera> = views.iter().map(|v| v.camera.clone()).collect();
    let solo = opal::dist::Solo;
    let comm: &dyn opal::dist::Comm = s.comm.as_deref().unwrap_or(&solo);
    let bar = Stage::start(s.progress.as_ref(), "unwrap", selected.len() as u64);
    let built = opal::dist::map_units(
        comm,
        selected.len(),
        |i| {
            let r = unwrap_one(inp, selected[i], &cams);
            bar.step(1);
            r
        },
        wire::put,
        wire::get,
    );
    bar.finish();
    let mut objects = Vec::new();
    let mut skipped = Vec::new();
    for (&k, built) in selected.iter().zip(built) {
        let sh = &desc.shapes[k];
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
                    superres: None,
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

/// An unwrapped object as bytes between processes (every float as its bits: exact).
mod wire {
    use super::Unwrapped;
    use crate::delight::atlas::Atlas;
    use crate::delight::footprint::{ResolutionChoice, ResolutionRule};
    use opal::dist::{Packer, Unpacker};
    use opal::geometry::TriangleMesh;
    use opal::math::{Vec2, Vec3};

    fn vec3s(p: &mut Packer, v: &[Vec3]) {
        p.u64(v.len() as u64);
        v.iter().for_each(|x| p.f32s(&[x.x, x.y, x.z]));
    }
    fn get_vec3s(u: &mut Unpacker) -> Vec<Vec3> {
        (0..u.u64()).map(|_| Vec3::new(u.f32(), u.f32(), u.f32())).collect()
    }
    fn u32s(p: &mut Packer, v: &[u32]) {
        p.u64(v.len() as u64);
        v.iter().for_each(|&x| p.0.extend_from_slice(&x.to_le_bytes()));
    }
    fn get_u32s(u: &mut Unpacker) -> Vec<u32> {
        (0..u.u64()).map(|_| u.f32().to_bits()).collect()
    }
    fn f32s(p: &mut Packer, v: &[f32]) {
        p.u64(v.len() as u64);
        p.f32s(v);
    }
    fn get_f32s(u: &mut Unpacker) -> Vec<f32> {
        (0..u.u64()).map(|_| u.f32()).collect()
    }
    fn opt(p: &mut Packer, x: Option<f64>) {
        p.u8(x.is_some() as u8);
        p.f64(x.unwrap_or(0.0));
    }
    fn get_opt(u: &mut Unpacker) -> Option<f64> {
        let some = u.u8() != 0;
        let x = u.f64();
        some.then_some(x)
    }

    /// Writes an unwrapped object (or its error).
    pub(super) fn put(x: &Unwrapped, p: &mut Packer) {
        let (a, c) = match x {
            Ok(ac) => ac,
            Err(e) => {
                p.u8(0);
                p.str(e);
                return;
            }
        };
        p.u8(1);
        p.u64(a.width as u64);
        p.u64(a.height as u64);
        vec3s(p, &a.mesh.positions);
        vec3s(p, &a.mesh.normals);
        p.u64(a.mesh.uvs.len() as u64);
        a.mesh.uvs.iter().for_each(|t| p.f32s(&[t.x, t.y]));
        u32s(p, &a.mesh.indices.iter().flatten().copied().collect::<Vec<u32>>());
        p.u8(a.kept_uvs as u8);
        p.u64(a.charts as u64);
        u32s(p, &a.tri_chart);
        f32s(p, &a.texel_area);
        u32s(p, &a.texel_tri);
        vec3s(p, &a.texel_p);
        vec3s(p, &a.texel_n);
        vec3s(p, &a.texel_ng);
        u32s(p, &a.texel_owner);
        f32s(p, &a.coverage);
        p.u8(match c.rule {
            ResolutionRule::Cameras => 0,
            ResolutionRule::Setting => 1,
            ResolutionRule::ExistingTexture => 2,
        });
        opt(p, c.unclamped);
        opt(p, c.pixel_density);
        opt(p, c.texel_density);
        p.f64(c.seen_area_fraction);
    }

    /// Reads what [`put`] wrote.
    pub(super) fn get(u: &mut Unpacker) -> Unwrapped {
        if u.u8() == 0 {
            return Err(u.str());
        }
        let width = u.u64() as usize;
        let height = u.u64() as usize;
        let positions = get_vec3s(u);
        let normals = get_vec3s(u);
        let uvs = (0..u.u64()).map(|_| Vec2::new(u.f32(), u.f32())).collect();
        let flat = get_u32s(u);
        let indices = flat.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect();
        let a = Atlas {
            width,
            height,
            mesh: TriangleMesh { positions, normals, uvs, indices },
            kept_uvs: u.u8() != 0,
            charts: u.u64() as usize,
            tri_chart: get_u32s(u),
            texel_area: get_f32s(u),
            texel_tri: get_u32s(u),
            texel_p: get_vec3s(u),
            texel_n: get_vec3s(u),
            texel_ng: get_vec3s(u),
            texel_owner: get_u32s(u),
            coverage: get_f32s(u),
        };
        let rule = match u.u8() {
            0 => ResolutionRule::Cameras,
            1 => ResolutionRule::Setting,
            _ => ResolutionRule::ExistingTexture,
        };
        let c = ResolutionChoice {
            rule,
            unclamped: get_opt(u),
            pixel_density: get_opt(u),
            texel_density: get_opt(u),
            seen_area_fraction: u.f64(),
        };
        Ok((a, c))
    }
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
