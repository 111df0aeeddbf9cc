//! Texture resolution from the cameras (method C step 2, `docs/delight.md` step 2): each
//! camera's pixel footprint on the object gives a pixel density (pixels per unit area), and the
//! texture gets texels at least as dense as the pixels over the best-seen part of the object.
//!
//! * **Surface samples** ([`surface_footprints`]): about [`SURFACE_SAMPLES`] points spread over
//!   the mesh by area (at least one per triangle), each carrying its share of the
//!   area. A view sees a sample when the triangle faces it, the point projects inside its film
//!   and the segment to the camera is unoccluded.
//! * **Pixel density** ([`pixel_density`]) of a pinhole camera at a point at depth `z` (along the
//!   optical axis), distance `r`, with `cos θ` between the surface normal and the direction to
//!   the camera: one pixel covers `p_x p_y z² (z/r) / cos θ` of the surface (`p_x = 2 tan(fov_x/2)
//!   / width`, likewise `p_y`: the pixel pitch on the plane at depth 1), so the density is
//!   `cos θ · r / (p_x p_y z³)`; a plane seen head-on at distance `d` has `1 / (p_x p_y d²)`
//!   everywhere. A sample's density is the largest over the views that see it.
//! * **Resolution** ([`camera_resolution`]): per seen sample the square resolution at which the
//!   atlas's texels on its triangle are as dense as its pixels; the resolution is the
//!   area-weighted [`BEST_SEEN_QUANTILE`] quantile of these over the seen surface (the best-seen
//!   10 % of the seen area sets it, not the single closest triangle), rounded up and clamped to
//!   [`MIN_RESOLUTION`]…`max` (4096 by default, [`LARGEST_RESOLUTION`] on request). Without an
//!   atlas the charts are taken to fill the texture (`sqrt(area × density)`, the method page's
//!   formula); with an atlas built at resolution `r0` its texel areas per triangle are used
//!   (`r0 · sqrt(density × texel area)`), which accounts for the chart packing and the UV
//!   stretch of kept UVs. An object seen by no view gets [`MIN_RESOLUTION`].
//!
//! Tests: `plane_head_on_density`, `closer_view_doubles_resolution`, `resolution_is_clamped`,
//! `occluded_and_back_facing_views_do_not_count` here; the de-lighting tests use it through
//! [`super::delight`].

use super::atlas::{Atlas, build_atlas};
use opal::camera::Camera;
use opal::geometry::TriangleMesh;
use opal::integrator::spawn_ray_to;
use opal::math::Vec3;
use opal::scene::Scene;
use rayon::prelude::*;

/// Smallest automatic resolution.
pub const MIN_RESOLUTION: usize = 256;
/// Largest automatic resolution by default.
pub const MAX_RESOLUTION: usize = 4096;
/// Largest automatic resolution on request ([`super::DelightSettings::max_resolution`]).
pub const LARGEST_RESOLUTION: usize = 8192;
/// Area quantile of the per-sample resolutions over the seen surface that sets the resolution.
pub const BEST_SEEN_QUANTILE: f64 = 0.9;
/// Target number of surface samples per object.
pub const SURFACE_SAMPLES: usize = 4096;

/// A surface point and the best pixel density of the views that see it.
#[derive(Clone, Copy, Debug)]
pub struct FootprintSample {
    /// Triangle of the mesh.
    pub tri: u32,
    /// World area the sample stands for.
    pub area: f64,
    /// Largest pixel density (pixels per unit area) of the views that see it; 0 = unseen.
    pub density: f64,
}

/// How an object's texture resolution was chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResolutionRule {
    /// From the cameras' pixel footprints ([`camera_resolution`]).
    Cameras,
    /// Given in the settings.
    Setting,
    /// The size of the object's own square bitmap texture (its UVs kept).
    ExistingTexture,
}

impl ResolutionRule {
    /// Name in reports: `cameras`, `setting`, `existing_texture`.
    pub fn name(self) -> &'static str {
        match self {
            ResolutionRule::Cameras => "cameras",
            ResolutionRule::Setting => "setting",
            ResolutionRule::ExistingTexture => "existing_texture",
        }
    }
}

/// The resolution choice of an object, for the report.
#[derive(Clone, Copy, Debug)]
pub struct ResolutionChoice {
    /// How the resolution was chosen.
    pub rule: ResolutionRule,
    /// The camera rule's resolution before rounding and clamping (`None`: seen by no view).
    pub unclamped: Option<f64>,
    /// Pixel density of the best-seen part: the area-weighted [`BEST_SEEN_QUANTILE`] quantile
    /// of the sample densities over the seen surface (pixels per unit area; `None`: unseen).
    pub pixel_density: Option<f64>,
    /// Texel density of the atlas on the same part: the same quantile of the texel densities
    /// (texels per unit area) of the triangles of the seen samples (`None`: unseen).
    pub texel_density: Option<f64>,
    /// Fraction of the surface area seen by at least one view (of the surface samples).
    pub seen_area_fraction: f64,
}

#[cfg(test)]
impl ResolutionChoice {
    /// A resolution given by the settings, the whole surface seen (the unit tests' objects).
    pub(crate) fn setting() -> ResolutionChoice {
        ResolutionChoice {
            rule: ResolutionRule::Setting,
            unclamped: None,
            pixel_density: None,
            texel_density: None,
            seen_area_fraction: 1.0,
        }
    }
}

/// Pixel density (pixels per unit area) of `cam` at the surface point `p` with unit normal
/// `n`, or `None` when the surface faces away or `p` is outside the film (no occlusion test).
pub fn pixel_density(cam: &Camera, p: Vec3, n: Vec3) -> Option<f64> {
    cam.project(p)?;
    let o = cam.origin();
    let v = o - p;
    let r = v.length() as f64;
    let cos_t = n.dot(v) as f64 / r;
    if cos_t <= 0.0 || !r.is_finite() || r <= 0.0 {
        return None;
    }
    let forward = cam.to_world.transform_vector3(Vec3::Z).normalize();
    let z = (p - o).dot(forward) as f64;
    if z <= 0.0 {
        return None;
    }
    let px = 2.0 * cam.tan_half_x as f64 / cam.width as f64;
    let py = 2.0 * cam.tan_half_y as f64 / cam.height as f64;
    Some(cos_t * r / (px * py * z * z * z))
}

/// Surface samples of `mesh` (world space, a shape of `scene`) with the best pixel density of
/// the `cameras` that see each (module documentation). Deterministic.
pub fn surface_footprints(scene: &Scene, mesh: &TriangleMesh, cameras: &[Camera]) -> Vec<FootprintSample> {
    let total = mesh.area();
    if total <= 0.0 {
        return Vec::new();
    }
    (0..mesh.triangle_count())
        .into_par_iter()
        .flat_map_iter(|t| {
            let [a, b, c] = mesh.triangle(t);
            let cr = (b - a).cross(c - a);
            let area = 0.5 * cr.length() as f64;
            let n_s = if area > 0.0 {
                ((SURFACE_SAMPLES as f64 * area / total).ceil() as usize).clamp(1, SURFACE_SAMPLES)
            } else {
                0
            };
            let ng = cr.normalize_or_zero();
            (0..n_s).map(move |j| {
                // stratified in u, golden-ratio sequence in v, warped onto the triangle
                let u = (j as f32 + 0.5) / n_s as f32;
                let v = (j as f32 * 0.618_034 + 0.5).fract();
                let su = u.sqrt();
                let p = a * (1.0 - su) + b * (su * (1.0 - v)) + c * (su * v);
                let density = cameras
                    .iter()
                    .filter_map(|cam| {
                        let d = pixel_density(cam, p, ng)?;
                        (!scene.occluded(&spawn_ray_to(p, ng, cam.origin(), Vec3::ZERO))).then_some(d)
                    })
                    .fold(0.0, f64::max);
                FootprintSample { tri: t as u32, area: area / n_s as f64, density }
            })
        })
        .collect()
}

/// Area-weighted quantile `q` of `(value, weight)` pairs: the smallest value whose cumulative
/// weight (values sorted ascending) reaches `q` of the total; `None` when empty.
fn weighted_quantile(mut v: Vec<(f64, f64)>, q: f64) -> Option<f64> {
    v.retain(|x| x.0.is_finite() && x.1 > 0.0);
    if v.is_empty() {
        return None;
    }
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    let total: f64 = v.iter().map(|x| x.1).sum();
    let mut acc = 0.0;
    for &(x, w) in &v {
        acc += w;
        if acc >= q * total {
            return Some(x);
        }
    }
    v.last().map(|x| x.0)
}

/// Camera-rule resolution (module documentation) from the samples of a mesh of area
/// `total_area`: with `atlas = Some((texel_area, r0))` (the texel world areas per triangle of an
/// atlas of the same mesh built at resolution `r0`) from its texel densities, else with the
/// charts taken to fill the texture. Returns (resolution clamped to `MIN_RESOLUTION..=max`,
/// unclamped value or `None` when no sample is seen).
pub fn camera_resolution(
    samples: &[FootprintSample],
    total_area: f64,
    atlas: Option<(&[f32], usize)>,
    max: usize,
) -> (usize, Option<f64>) {
    let need: Vec<(f64, f64)> = samples
        .iter()
        .filter(|s| s.density > 0.0)
        .filter_map(|s| {
            let r = match atlas {
                Some((ta, r0)) => {
                    let a = *ta.get(s.tri as usize)? as f64;
                    (a > 0.0).then(|| r0 as f64 * (s.density * a).sqrt())?
                }
                None => (s.density * total_area).sqrt(),
            };
            Some((r, s.area))
        })
        .collect();
    match weighted_quantile(need, BEST_SEEN_QUANTILE) {
        // rounded up, with a slack of 0.01 texel for the f32 round-off of the texel areas
        Some(r) => (((r - 0.01).ceil() as usize).clamp(MIN_RESOLUTION, max.max(MIN_RESOLUTION)), Some(r)),
        None => (MIN_RESOLUTION, None),
    }
}

/// Report of the choice for an object with the final `atlas` (of the same mesh as the samples).
pub fn resolution_choice(
    rule: ResolutionRule,
    unclamped: Option<f64>,
    samples: &[FootprintSample],
    atlas: &Atlas,
) -> ResolutionChoice {
    let seen: Vec<&FootprintSample> = samples.iter().filter(|s| s.density > 0.0).collect();
    let total: f64 = samples.iter().map(|s| s.area).sum();
    let seen_area: f64 = seen.iter().map(|s| s.area).sum();
    let pixel_density =
        weighted_quantile(seen.iter().map(|s| (s.density, s.area)).collect(), BEST_SEEN_QUANTILE);
    let texel_density = weighted_quantile(
        seen.iter()
            .filter_map(|s| {
                let a = *atlas.texel_area.get(s.tri as usize)? as f64;
                (a > 0.0).then_some((1.0 / a, s.area))
            })
            .collect(),
        BEST_SEEN_QUANTILE,
    );
    ResolutionChoice {
        rule,
        unclamped,
        pixel_density,
        texel_density,
        seen_area_fraction: if total > 0.0 { seen_area / total } else { 0.0 },
    }
}

/// Atlas of `mesh` at the cameras' resolution from its `samples` ([`surface_footprints`]):
/// first with the charts taken to fill the texture, then (when the atlas's own texel areas ask
/// for another size) rebuilt once at the resolution from its texel densities; `max` is clamped
/// to [`LARGEST_RESOLUTION`]. Returns the atlas and the unclamped resolution.
pub fn camera_atlas(
    mesh: &TriangleMesh,
    samples: &[FootprintSample],
    keep_uvs: bool,
    max: usize,
) -> Result<(Atlas, Option<f64>), String> {
    let max = max.min(LARGEST_RESOLUTION);
    let (r0, u0) = camera_resolution(samples, mesh.area(), None, max);
    let a0 = build_atlas(mesh, r0, keep_uvs)?;
    // the atlas mesh keeps the triangle order of the input mesh (checked)
    if a0.mesh.triangle_count() != mesh.triangle_count() {
        return Ok((a0, u0));
    }
    let (r1, u1) = camera_resolution(samples, mesh.area(), Some((&a0.texel_area, r0)), max);
    if r1 == r0 {
        return Ok((a0, u1));
    }
    Ok((build_atlas(mesh, r1, keep_uvs)?, u1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use opal::geometry::shapes::rectangle_mesh;
    use opal::math::Mat4;
    use opal::scene::desc::{BsdfDesc, SceneDesc, SensorDesc, ShapeDesc, TextureDesc};
    use opal::spectrum::Spectrum;

    /// A camera at `o` looking at `target`, `fov_x` degrees, `w × w` pixels.
    fn camera(o: Vec3, target: Vec3, fov_x: f32, w: usize) -> Camera {
        let mut to_world = Mat4::look_at_rh(o, target, Vec3::Y).inverse();
        to_world *= Mat4::from_scale(Vec3::new(-1.0, 1.0, -1.0));
        Camera::new(&SensorDesc {
            id: "c".into(),
            to_world,
            fov_x_deg: fov_x,
            width: w,
            height: w,
            near_clip: 1e-3,
            far_clip: 1e3,
            spp: None,
        })
    }

    /// The scene of one 2 × 2 rectangle in the z = 0 plane facing +z (plus `extra` shapes).
    fn plane_scene(extra: Vec<TriangleMesh>) -> Scene {
        let mut d = SceneDesc::default();
        for m in std::iter::once(rectangle_mesh()).chain(extra) {
            d.shapes.push(ShapeDesc {
                id: format!("s{}", d.shapes.len()),
                mesh: m,
                bsdf: BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(Spectrum::splat(0.5)) },
                emitter: None,
                origin: None,
            });
        }
        Scene::build(&d).unwrap()
    }

    /// fov with tan(fov/2) = t, in degrees.
    fn fov(t: f32) -> f32 {
        2.0 * t.atan().to_degrees()
    }

    /// Head-on at distance 4 with tan(fov/2) = 0.5 and 1024 pixels: pitch 1/1024 on the plane
    /// at depth 1, footprint 4/1024 = 1/256, density 256² everywhere; the 2 × 2 plane (kept UVs
    /// filling the texture) needs sqrt(4 · 256²) = 512 texels a side.
    #[test]
    fn plane_head_on_density() {
        let m = rectangle_mesh();
        let scene = plane_scene(vec![]);
        let cam = camera(Vec3::new(0.0, 0.0, 4.0), Vec3::ZERO, fov(0.5), 1024);
        for p in [Vec3::ZERO, Vec3::new(0.9, -0.7, 0.0)] {
            let d = pixel_density(&cam, p, Vec3::Z).unwrap();
            assert!((d / 65536.0 - 1.0).abs() < 1e-4, "{d}");
        }
        let s = surface_footprints(&scene, &m, std::slice::from_ref(&cam));
        assert!(s.len() >= SURFACE_SAMPLES && s.iter().all(|x| (x.density / 65536.0 - 1.0).abs() < 1e-4));
        assert!((s.iter().map(|x| x.area).sum::<f64>() - 4.0).abs() < 1e-5);
        let (r, u) = camera_resolution(&s, m.area(), None, MAX_RESOLUTION);
        assert!((u.unwrap() - 512.0).abs() < 0.05, "{u:?}");
        assert_eq!(r, 512);
        // with the atlas's own texel areas (kept UVs fill [0, 1]²): the same
        let a = build_atlas(&m, 300, true).unwrap();
        let (r2, _) = camera_resolution(&s, m.area(), Some((&a.texel_area, 300)), MAX_RESOLUTION);
        assert_eq!(r2, 512);
        let a = build_atlas(&m, r2, true).unwrap();
        let c = resolution_choice(ResolutionRule::Cameras, u, &s, &a);
        assert!((c.seen_area_fraction - 1.0).abs() < 1e-9);
        // texels at least as dense as the pixels (equal here)
        assert!((c.texel_density.unwrap() / c.pixel_density.unwrap() - 1.0).abs() < 1e-3, "{c:?}");
    }

    /// A second view twice as close (tan 0.6 keeps the plane in its film) has 4× the density:
    /// the resolution doubles (the best-seen view sets it).
    #[test]
    fn closer_view_doubles_resolution() {
        let m = rectangle_mesh();
        let scene = plane_scene(vec![]);
        let far = camera(Vec3::new(0.0, 0.0, 4.0), Vec3::ZERO, fov(0.6), 600);
        let near = camera(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, fov(0.6), 600);
        let r = |cams: &[Camera]| camera_resolution(&surface_footprints(&scene, &m, cams), 4.0, None, 4096).1;
        let (r1, r2) = (r(std::slice::from_ref(&far)).unwrap(), r(&[far, near]).unwrap());
        // 600 / (2 · 0.6 · 4) = 125 pixels per unit → 250 texels a side
        assert!((r1 - 250.0).abs() < 0.05 && (r2 / r1 - 2.0).abs() < 1e-4, "{r1} {r2}");
    }

    /// Clamping to 256 for a far view, to 4096 (or 8192 on request) for a very close one; unseen
    /// objects get 256.
    #[test]
    fn resolution_is_clamped() {
        let m = rectangle_mesh();
        let scene = plane_scene(vec![]);
        let far = camera(Vec3::new(0.0, 0.0, 40.0), Vec3::ZERO, fov(0.5), 256);
        let s = surface_footprints(&scene, &m, &[far]);
        assert_eq!(camera_resolution(&s, 4.0, None, MAX_RESOLUTION).0, MIN_RESOLUTION);
        let near = camera(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, fov(0.6), 8192);
        let s = surface_footprints(&scene, &m, &[near]);
        let (r, u) = camera_resolution(&s, 4.0, None, MAX_RESOLUTION);
        assert!((u.unwrap() - 8192.0 / 1.2).abs() < 1.0, "{u:?}");
        assert_eq!(r, MAX_RESOLUTION);
        assert_eq!(camera_resolution(&s, 4.0, None, LARGEST_RESOLUTION).0, 6827);
        let behind = camera(Vec3::new(0.0, 0.0, -4.0), Vec3::ZERO, fov(0.5), 1024);
        let s = surface_footprints(&scene, &m, &[behind]);
        assert_eq!(camera_resolution(&s, 4.0, None, MAX_RESOLUTION), (MIN_RESOLUTION, None));
    }

    /// A view from behind the plane sees nothing; an occluder covering the left half (x < 0)
    /// from the near view halves the seen area it gives, and the far view then sets the density
    /// of that half.
    #[test]
    fn occluded_and_back_facing_views_do_not_count() {
        let m = rectangle_mesh();
        // occluder: the rectangle shrunk to x ∈ [-1, 0] and moved to z = 1
        let mut occ = rectangle_mesh();
        for p in &mut occ.positions {
            p.x = 0.5 * (p.x - 1.0);
            p.z = 1.0;
        }
        let scene = plane_scene(vec![occ]);
        let near = camera(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, fov(0.6), 600);
        let s = surface_footprints(&scene, &m, std::slice::from_ref(&near));
        let c = resolution_choice(ResolutionRule::Cameras, None, &s, &build_atlas(&m, 256, true).unwrap());
        assert!((c.seen_area_fraction - 0.5).abs() < 0.02, "{c:?}");
        let back = camera(Vec3::new(0.0, 0.0, -4.0), Vec3::ZERO, fov(0.6), 600);
        let s = surface_footprints(&scene, &m, &[back]);
        assert!(s.iter().all(|x| x.density == 0.0));
    }
}
