//! Per-triangle data of a pass ([`Prim`], precomputed once: hit reconstruction, deposit
//! factor and map size, material) and the scattering weight of a vertex that is applied after
//! the next ray is traced ([`Weight`]).
//!
//! Tests (`tests.rs`): the fast paths against the generic f64 pass (bitmap and constant
//! albedos, two-sided material with corner normals).

use super::IrradianceTarget;
use super::fixed_point::FixedPoint;
use crate::math::{INV_PI, Vec2, Vec3};
use crate::scene::Material;
use crate::scene::Scene;
use crate::spectrum::Spectrum;
use crate::texture::Texture;

/// Material of a triangle as the light tracer needs it.
#[derive(Clone, Copy)]
pub(super) enum Mat<'a> {
    /// Lambertian with this reflectance; `two_sided` = wrapped in `twosided`.
    Diffuse { tex: &'a Texture, two_sided: bool },
    /// Anything else: `Scene::bsdf`.
    Generic,
}

/// Per-triangle data precomputed for the hit reconstruction (same formulas as
/// `Scene::interaction` and `Scene::bsdf`, evaluated once per triangle instead of per hit).
#[derive(Clone, Copy)]
pub(super) struct Prim<'a> {
    /// Unit geometric normal.
    pub(super) ng: Vec3,
    /// `ng.normalize_or_zero()`: the normal [`crate::integrator::offset_ray_origin`] offsets along.
    pub(super) ng_off: Vec3,
    /// Corner uvs (zeros without uvs).
    pub(super) uv: [Vec2; 3],
    /// Corner shading normals, when the mesh has them.
    pub(super) normals: Option<[Vec3; 3]>,
    pub(super) shape: u32,
    /// Fixed-point units per unit of β for a deposit (0 = no deposit).
    pub(super) factor: f64,
    /// `ρ · 1/π` of a Lambertian material with a constant reflectance ρ.
    pub(super) kd_pi: Option<Spectrum>,
    /// Deposit map size (texels).
    pub(super) width: u32,
    pub(super) height: u32,
    pub(super) mat: Mat<'a>,
}

pub(super) fn prims<'a>(
    scene: &'a Scene,
    targets: &[Option<IrradianceTarget>],
    fp: &FixedPoint,
) -> Vec<Prim<'a>> {
    let mut out = Vec::with_capacity(fp.factor.len());
    for (k, sh) in scene.shapes.iter().enumerate() {
        let m = &sh.mesh;
        let mat = match &sh.material {
            Material::Diffuse { reflectance, two_sided } => {
                Mat::Diffuse { tex: reflectance, two_sided: *two_sided }
            }
            Material::Model { .. } | Material::Coated { .. } => Mat::Generic,
        };
        let (width, height) = targets[k].as_ref().map_or((0, 0), |t| (t.width as u32, t.height as u32));
        for (j, idx) in m.indices.iter().enumerate() {
            let [i0, i1, i2] = idx.map(|i| i as usize);
            let (p0, p1, p2) = (m.positions[i0], m.positions[i1], m.positions[i2]);
            let ng = (p1 - p0).cross(p2 - p0).normalize();
            out.push(Prim {
                ng,
                ng_off: ng.normalize_or_zero(),
                uv: if m.uvs.is_empty() { [Vec2::ZERO; 3] } else { [m.uvs[i0], m.uvs[i1], m.uvs[i2]] },
                normals: (!m.normals.is_empty()).then(|| [m.normals[i0], m.normals[i1], m.normals[i2]]),
                shape: k as u32,
                factor: fp.factor[sh.first_prim as usize + j],
                kd_pi: match mat {
                    Mat::Diffuse { tex: Texture::Constant(c), .. } => Some(*c * INV_PI),
                    _ => None,
                },
                width,
                height,
                mat,
            });
        }
    }
    out
}

/// The scattering weight of the last vertex, applied after the next ray is traced so that the
/// texture lookup's cache miss overlaps the traversal.
pub(super) enum Weight<'a> {
    Known(Spectrum),
    /// Lambert: `(reflectance(uv) · 1/π) · (|cos θi| / pdf)` (as `BsdfSample::weight`).
    Lambert {
        tex: &'a Texture,
        uv: Vec2,
        ratio: f32,
    },
    /// Lambert with a constant reflectance ρ: `(ρ · 1/π) · ratio` (`kd_pi` = ρ · 1/π, the same
    /// product as in `Lambert`, evaluated once per triangle).
    LambertConst {
        kd_pi: Spectrum,
        ratio: f32,
    },
}

impl<'a> Weight<'a> {
    /// The weight of a Lambertian vertex of triangle `pr` at `uv` with `ratio = |cos θi| / pdf`;
    /// a bitmap's texels are prefetched for the lookup in [`Weight::get`].
    #[inline]
    pub(super) fn lambert(pr: &Prim<'a>, tex: &'a Texture, uv: Vec2, ratio: f32) -> Self {
        match pr.kd_pi {
            Some(kd_pi) => Weight::LambertConst { kd_pi, ratio },
            None => {
                tex.prefetch(uv);
                Weight::Lambert { tex, uv, ratio }
            }
        }
    }

    #[inline]
    pub(super) fn get(self) -> Spectrum {
        match self {
            Weight::Known(w) => w,
            Weight::Lambert { tex, uv, ratio } => (tex.eval(uv) * INV_PI) * ratio,
            Weight::LambertConst { kd_pi, ratio } => kd_pi * ratio,
        }
    }
}
