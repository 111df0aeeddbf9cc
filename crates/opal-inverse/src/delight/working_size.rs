//! The automatic working size of the views (`docs/delight.md`, "Photo resolution"): when no
//! pixel limit is given, the views are box-filtered ([`super::downsample`]) to the size at which
//! the texture resolution from the pixel footprints ([`super::footprint`]) gives no more texels
//! than a light-path budget can serve at the target per-texel noise, but never below
//! [`MIN_WORKING_PIXELS`] pixels per view (and never above the photos' own size).
//!
//! * **Texel budget** ([`texel_budget`]): the texels for which [`DEFAULT_PATH_BUDGET`] paths per
//!   pass reach the target noise ([`super::noise::paths_for_noise`] inverted): 710 k texels at the
//!   default target noise (the shared Cornell box's texels at 256², 20 M paths). With a fixed
//!   path count, the texels that count serves at the default target noise.
//! * **Texel estimate** ([`estimate_texels`]): per object the resolution it will get — the
//!   setting, the size of its square bitmap texture when its UVs are kept, else the camera rule
//!   with the texel areas of a trial atlas at [`TRIAL_RESOLUTION`] ([`packed_resolution`]: the
//!   unwrap's own second step, so the chart packing counts — a 2:1 wall fills half its square
//!   texture; taking the charts to fill the texture, as before, estimated 1.09 M texels for the
//!   24-view ring whose atlases had 1.67 M, now 1.645 M).
//!   Scaling every view's pixel count by `s` scales the pixel densities by `s`, so the
//!   camera-rule resolutions by `sqrt(s)` (then clamped to 256…max as the rule does).
//! * **Choice** ([`choose_working_size`]): the largest `s ≤ 1` whose estimate fits the budget
//!   (bisection: the estimate grows with `s`); when even the smallest resolutions (every
//!   camera-rule object at 256²) exceed the budget, the largest `s` at which the estimate stops
//!   falling (finer views would only add texels, coarser ones only lose pixels). The per-view
//!   limit is then `s × the largest view's pixels`, raised to [`MIN_WORKING_PIXELS`] (the size at
//!   which the shared box's views meet every goal: ≥ 64-pixel regions for the report and the
//!   pixels of the luminance maps).
//!
//! Tests: `budget_inverts_the_path_rule`, `estimate_scales_with_the_pixel_count`,
//! `estimate_counts_the_packing` and
//! `choice_fits_the_budget_and_keeps_the_floor` below; the CLI's defaults test
//! (`crates/opal-cli/tests/delight.rs`).

use super::atlas::build_atlas;
use super::footprint::{self, FootprintSample, MIN_RESOLUTION};
use super::noise::{DEFAULT_TARGET_NOISE, PATHS_PER_TEXEL_AT_UNIT_NOISE};
use super::{DelightSettings, LightPaths};
use opal::camera::Camera;
use opal::error::Result;
use opal::geometry::TriangleMesh;
use opal::scene::Scene;
use opal::scene::desc::{BsdfDesc, SceneDesc, TextureDesc};

/// Light paths per pass the automatic working size budgets for (the count the shared box's
/// 256² views get at the default target noise).
pub const DEFAULT_PATH_BUDGET: u64 = 20_000_000;
/// Smallest automatic working size of a view (pixels): 256².
pub const MIN_WORKING_PIXELS: usize = 65_536;

/// Texels that [`DEFAULT_PATH_BUDGET`] paths per pass serve at the target noise of `paths`
/// (for a fixed count: the texels that count serves at the default target noise).
pub fn texel_budget(paths: LightPaths) -> f64 {
    let (n, t) = match paths {
        LightPaths::TargetNoise(t) => (DEFAULT_PATH_BUDGET as f64, t),
        LightPaths::Fixed(n) => (n as f64, DEFAULT_TARGET_NOISE),
    };
    n * t * t / PATHS_PER_TEXEL_AT_UNIT_NOISE
}

/// How one object's texture resolution depends on the working size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TexelRule {
    /// A fixed square resolution (the setting or the object's texture).
    Fixed(usize),
    /// The camera rule's unclamped resolution at the full-size views, clamped to 256…max.
    Cameras {
        /// Unclamped resolution at the full-size views.
        full: f64,
        /// Upper clamp.
        max: usize,
    },
}

impl TexelRule {
    /// Texels at pixel-count scale `s` of every view.
    pub fn texels(self, s: f64) -> f64 {
        match self {
            TexelRule::Fixed(r) => (r * r) as f64,
            TexelRule::Cameras { full, max } => {
                let r = (full * s.sqrt()).ceil().clamp(MIN_RESOLUTION as f64, max.max(MIN_RESOLUTION) as f64);
                r * r
            }
        }
    }
}

/// The texel rules of the objects `delight` will recover (same selection and resolution rules
/// as its unwrap stage, charts taken to fill the texture) for views with these cameras.
pub fn estimate_texels(
    desc: &SceneDesc,
    scene: &Scene,
    cameras: &[Camera],
    s: &DelightSettings,
) -> Result<Vec<TexelRule>> {
    let (selected, _) = super::stages::unwrap::select_objects(scene, s.objects.as_deref())?;
    let max = s.max_resolution.min(footprint::LARGEST_RESOLUTION);
    Ok(selected
        .iter()
        .map(|&k| {
            let sh = &desc.shapes[k];
            if let Some(r) = s.resolution {
                return TexelRule::Fixed(r);
            }
            if let Some(r) = square_texture(&sh.bsdf).filter(|_| s.keep_uvs) {
                return TexelRule::Fixed(r);
            }
            let samples = footprint::surface_footprints(scene, &sh.mesh, cameras);
            match packed_resolution(&sh.mesh, &samples, s.keep_uvs) {
                Some(full) => TexelRule::Cameras { full, max },
                None => TexelRule::Fixed(MIN_RESOLUTION),
            }
        })
        .collect())
}

/// Resolution of the trial atlas that measures an object's packing ([`packed_resolution`]).
pub const TRIAL_RESOLUTION: usize = 512;

/// The camera rule's unclamped resolution of `mesh` at the full-size views with the chart
/// packing (and the UV stretch of kept UVs) accounted for: from the texel areas of a trial atlas
/// at [`TRIAL_RESOLUTION`], as the unwrap's second step does with its first atlas
/// ([`footprint::camera_atlas`]; the texel areas scale with 1/resolution², so the result does
/// not depend on the trial's size but through the packing, whose one-texel gutters take a
/// larger share at 512 than at most final sizes: a slight overestimate of the texels). Falls
/// back to the charts filling the texture when the trial fails or renumbers the triangles;
/// `None` when no view sees the object.
fn packed_resolution(mesh: &TriangleMesh, samples: &[FootprintSample], keep_uvs: bool) -> Option<f64> {
    let fill = || footprint::camera_resolution(samples, mesh.area(), None, usize::MAX).1;
    match build_atlas(mesh, TRIAL_RESOLUTION, keep_uvs) {
        Ok(a) if a.mesh.triangle_count() == mesh.triangle_count() => footprint::camera_resolution(
            samples,
            mesh.area(),
            Some((&a.texel_area, TRIAL_RESOLUTION)),
            usize::MAX,
        )
        .1
        .or_else(fill),
        _ => fill(),
    }
}

/// Size of a square bitmap reflectance of a diffuse (or two-sided diffuse) BSDF.
fn square_texture(b: &BsdfDesc) -> Option<usize> {
    match b {
        BsdfDesc::Diffuse { reflectance: TextureDesc::Bitmap(bm) } => {
            (bm.image.width == bm.image.height).then_some(bm.image.width)
        }
        BsdfDesc::TwoSided(inner) => square_texture(inner),
        _ => None,
    }
}

/// The automatic working size and why.
#[derive(Clone, Debug, PartialEq)]
pub struct WorkingSize {
    /// Per-view pixel limit (`None`: the views as they are).
    pub max_view_pixels: Option<usize>,
    /// Estimated texels at the full-size views.
    pub texels_full: f64,
    /// Estimated texels at the working size.
    pub texels_working: f64,
    /// The texel budget ([`texel_budget`]).
    pub texel_budget: f64,
    /// Why: `full_size_fits_budget`, `texel_budget`, `smallest_textures` (the budget is below
    /// the smallest textures) or `min_working_pixels`.
    pub reason: &'static str,
}

/// The working size (module documentation) for views of `pixels` pixels each (the largest
/// decides the limit), objects with `rules` and texel budget `budget`.
pub fn choose_working_size(pixels: &[usize], rules: &[TexelRule], budget: f64) -> WorkingSize {
    let total = |s: f64| rules.iter().map(|r| r.texels(s)).sum::<f64>();
    let largest = pixels.iter().copied().max().unwrap_or(0);
    let texels_full = total(1.0);
    let full = |reason| WorkingSize {
        max_view_pixels: None,
        texels_full,
        texels_working: texels_full,
        texel_budget: budget,
        reason,
    };
    if largest <= MIN_WORKING_PIXELS {
        return full("min_working_pixels");
    }
    if texels_full <= budget {
        return full("full_size_fits_budget");
    }
    // the smallest scale worth considering: every view at one pixel
    let s_min = 1.0 / largest as f64;
    let floor = total(s_min);
    let (target, reason) =
        if floor > budget { (floor * (1.0 + 1e-9), "smallest_textures") } else { (budget, "texel_budget") };
    let (mut lo, mut hi) = (s_min, 1.0);
    for _ in 0..60 {
        let mid = (lo * hi).sqrt();
        if total(mid) <= target { lo = mid } else { hi = mid }
    }
    let limit = (lo * largest as f64).floor() as usize;
    let (limit, reason) =
        if limit < MIN_WORKING_PIXELS { (MIN_WORKING_PIXELS, "min_working_pixels") } else { (limit, reason) };
    let s = limit as f64 / largest as f64;
    WorkingSize {
        max_view_pixels: Some(limit),
        texels_full,
        texels_working: total(s),
        texel_budget: budget,
        reason,
    }
}

/// The automatic working size of views with these full-size `cameras` for the objects and
/// settings of `s` (module documentation); the cameras need no pixels.
pub fn auto_working_size(desc: &SceneDesc, cameras: &[Camera], s: &DelightSettings) -> Result<WorkingSize> {
    let scene = Scene::build(desc)?;
    let rules = estimate_texels(desc, &scene, cameras, s)?;
    let pixels: Vec<usize> = cameras.iter().map(|c| c.width * c.height).collect();
    Ok(choose_working_size(&pixels, &rules, texel_budget(s.light_paths)))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The budget is the texel count at which the path rule gives the path budget.
    #[test]
    fn budget_inverts_the_path_rule() {
        let b = texel_budget(LightPaths::TargetNoise(DEFAULT_TARGET_NOISE));
        assert!((b - 710_139.0).abs() < 1.0, "{b}");
        let p = super::super::noise::paths_for_noise(b.round() as usize, DEFAULT_TARGET_NOISE);
        assert_eq!(p, DEFAULT_PATH_BUDGET);
        // half the noise: a quarter of the texels
        let q = texel_budget(LightPaths::TargetNoise(DEFAULT_TARGET_NOISE / 2.0));
        assert!((q - b / 4.0).abs() < 1.0);
        // a fixed count: the texels it serves at the default noise
        assert!((texel_budget(LightPaths::Fixed(40_000_000)) - 2.0 * b).abs() < 1.0);
    }

    /// Camera-rule resolutions follow sqrt(s) and the 256 clamp; fixed ones do not move.
    #[test]
    fn estimate_scales_with_the_pixel_count() {
        let c = TexelRule::Cameras { full: 2048.0, max: 4096 };
        assert_eq!(c.texels(1.0), 2048.0 * 2048.0);
        assert_eq!(c.texels(0.25), 1024.0 * 1024.0);
        assert_eq!(c.texels(1e-4), 256.0 * 256.0);
        assert_eq!(TexelRule::Cameras { full: 8000.0, max: 4096 }.texels(1.0), 4096.0 * 4096.0);
        assert_eq!(TexelRule::Fixed(300).texels(0.01), 90_000.0);
    }

    /// A 4 × 2 wall without UVs seen head-on by a 1024² view: its one chart fills half of its
    /// square texture, so the atlas has about twice the texels of the charts-fill-the-texture
    /// rule; the estimate matches the unwrap's atlas within 5 % (the trial's gutters).
    #[test]
    fn estimate_counts_the_packing() {
        use opal::math::{Mat4, Vec3};
        use opal::scene::desc::{SensorDesc, ShapeDesc};
        use opal::spectrum::Spectrum;
        let mut mesh = opal::geometry::shapes::rectangle_mesh();
        mesh.positions.iter_mut().for_each(|p| p.x *= 2.0);
        mesh.uvs.clear();
        let desc = SceneDesc {
            shapes: vec![ShapeDesc {
                id: "wall".into(),
                mesh: mesh.clone(),
                bsdf: BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(Spectrum::splat(0.5)) },
                emitter: None,
                origin: None,
            }],
            ..Default::default()
        };
        let scene = Scene::build(&desc).unwrap();
        let mut to_world = Mat4::look_at_rh(Vec3::new(0.0, 0.0, 6.0), Vec3::ZERO, Vec3::Y).inverse();
        to_world *= Mat4::from_scale(Vec3::new(-1.0, 1.0, -1.0));
        let cam = Camera::new(&SensorDesc {
            id: "c".into(),
            to_world,
            fov_x_deg: 2.0 * 0.5f32.atan().to_degrees(),
            width: 1024,
            height: 1024,
            near_clip: 1e-3,
            far_clip: 1e3,
            spp: None,
        });
        let s = DelightSettings { keep_uvs: false, ..Default::default() };
        let rules = estimate_texels(&desc, &scene, std::slice::from_ref(&cam), &s).unwrap();
        let est = rules[0].texels(1.0);
        let samples = footprint::surface_footprints(&scene, &mesh, std::slice::from_ref(&cam));
        let (a, _) = footprint::camera_atlas(&mesh, &samples, false, s.max_resolution).unwrap();
        let real = (a.width * a.height) as f64;
        let fill = footprint::camera_resolution(&samples, mesh.area(), None, usize::MAX).1.unwrap().powi(2);
        assert!(real > 1.8 * fill, "real {real} fill {fill}");
        assert!((est / real - 1.0).abs() < 0.05, "estimate {est} real {real}");
    }

    /// The chosen size fits the budget and is the largest that does (up to one pixel); small
    /// views and full views within the budget stay as they are; too tight a budget stops where
    /// the textures reach their smallest size, and the floor holds.
    #[test]
    fn choice_fits_the_budget_and_keeps_the_floor() {
        let rules = [
            TexelRule::Cameras { full: 2000.0, max: 4096 },
            TexelRule::Cameras { full: 1000.0, max: 4096 },
            TexelRule::Fixed(256),
        ];
        let px = 1 << 22; // 2048²
        let w = choose_working_size(&[px, px / 2], &rules, 1.0e6);
        let m = w.max_view_pixels.unwrap();
        assert_eq!(w.reason, "texel_budget");
        assert!(w.texels_working <= 1.0e6);
        let s_next = (m + 2) as f64 / px as f64;
        assert!(rules.iter().map(|r| r.texels(s_next)).sum::<f64>() > 1.0e6 * 0.999);
        // big enough budget: full size
        let f = choose_working_size(&[px], &rules, 1.0e7);
        assert_eq!((f.max_view_pixels, f.reason), (None, "full_size_fits_budget"));
        // small views are never reduced
        let s = choose_working_size(&[MIN_WORKING_PIXELS], &rules, 1.0);
        assert_eq!((s.max_view_pixels, s.reason), (None, "min_working_pixels"));
        // budget below the smallest textures (3 × 256²): the floor of the views holds
        let t = choose_working_size(&[1 << 26], &rules, 1.0e5);
        let mt = t.max_view_pixels.unwrap();
        assert_eq!(t.reason, "smallest_textures");
        assert!((t.texels_working - 3.0 * 65_536.0).abs() < 1.0);
        // the largest object reaches 256 at s = (256/2000)²
        assert!((mt as f64 / (1u64 << 26) as f64 - (256.0f64 / 2000.0).powi(2)).abs() < 1e-3);
        let u = choose_working_size(&[1 << 20], &rules, 1.0e5);
        assert_eq!((u.max_view_pixels, u.reason), (Some(MIN_WORKING_PIXELS), "min_working_pixels"));
    }
}
