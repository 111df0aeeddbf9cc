//! De-lighting (method C, `docs/methods/004-diffuse-texture-recovery.md`): recovers the diffuse
//! albedo textures `Kd` of selected objects from multi-view linear HDR images, known geometry,
//! emitters and cameras.
//!
//! Pipeline ([`delight`]):
//! 1. atlas per object ([`atlas`]: own UVs when usable, else new charts), resolution from the
//!    cameras' pixel footprints ([`footprint`]) unless given or the object's own texture size;
//! 2. (unless [`PoseRefinement::Off`]) per-view pose refinement ([`pose`]): each view aligned
//!    with the other views' maps; the refined views replace the given ones below;
//!    (unless [`ViewGainMode::Fixed`]) per-view gains (exposure, white balance) from the
//!    overlap of the views ([`gains`]); the views are divided by them before everything below;
//!    luminance map `L`: every covered texel is projected into every view; a view counts when
//!    the texel faces it, lies in its frustum, the segment to the camera is unoccluded and the
//!    bilinear taps are "pure" pixels of the same shape and plane ([`views::pure_buffer`]);
//!    views are averaged with cos θ (surface normal · direction to the camera) weights; after
//!    the first light-tracing pass (step 6) it is replaced by the multi-view super-resolved map
//!    ([`superres`], unless `superres` is `None`; it also uses the pixels across gentle creases,
//!    [`views::PureBuffer::covered`]) whose prior acts on `L / (Ed + Ei)`, the
//!    albedo up to a constant (the indirect part smoothed over resolution/16 texels);
//! 3. objects close to an emitter get a 3×3 median filter on `L` first; holes of `L` are
//!    inpainted ([`inpaint`]) for previews;
//! 4. direct irradiance `Ed` per texel by light sampling (power-proportional light choice,
//!    stratified positions, shadow rays);
//! 5. `Kd = π L / (Ed + Ei)` per channel with `Ei` gathered from the luminance maps ([`gather`]:
//!    π × the mean observed radiance seen along cosine-distributed rays; with
//!    `gather_rays = 0`: `Ei = share · Ed`, or `share` × the scene-average irradiance where a
//!    texel has no direct light); where `Kd > 1`, `Ei` is raised to
//!    `π L − Ed` (so `Kd = 1`); `Kd` is computed on observed texels and inpainted elsewhere;
//! 6. iterations: a light-tracing pass ([`opal::integrator::light_tracer`], importance transport;
//!    paths from the texel count and a target per-texel noise, [`noise`], whose achieved value
//!    is measured every pass) with the current `Kd` gives the indirect irradiance `Ei_r` (smoothed within charts over
//!    `smooth` texels: indirect light is low-frequency and this cuts Monte-Carlo noise); the
//!    error `e = L − Kd/π (Ed + Ei_r)` on observed texels, relative to `L` (luminance), with
//!    quartile (Tukey 1.5·IQR) outlier rejection per object gives the max/mean error of the
//!    iteration; `Ei` is updated by the fixed-point rule `Ei ← Ei_r` (default) or the paper's
//!    gradient step `Ei ← max(0, Ei + α_k Kd/π e)`, `α_k = α₀/(1+k)`; `Kd` is recomputed with
//!    the [0, 1] correction; stop once a pass changes no tile of an object by more than the
//!    tolerance beyond its own Monte-Carlo noise ([`convergence`]) or at the limit;
//! 7. what the data cannot determine ([`unseen`]): per object the part of its light that
//!    arrived via texels no view observed, and how far their fill can move its albedo.
//!
//! Files: settings in `settings.rs`, results in `result.rs`; [`delight`] in `pipeline.rs` runs
//! the named stages of `stages/` in order: `unwrap.rs` (selection, atlases), `direct.rs` (step
//! 4), `luminance.rs` (steps 2–3, gains), `iterate.rs` (step 6), `outputs.rs` (debug dump,
//! result); the texture resolution from the cameras in `footprint.rs`, the light paths per pass
//! and the achieved noise in `noise.rs`, the albedo update of step 5 in `albedo.rs`, the in-chart smoothing in `smooth.rs`,
//! the direct-irradiance estimator in `direct.rs`, luminance maps and view/region helpers in
//! `observe.rs`, stage clocks in `timing.rs`; shared helpers (luminance, albedo image,
//! recovered scene) here. Diagnostics are switched by [`DebugSettings`] and
//! [`superres::SrDiagnostics`] (never by environment variables).
//!
//! Tests: unit tests of the parts in their modules; `crates/opal-inverse/tests/delight.rs`
//! (round trip on a small Cornell box rendered by Opal at known albedos; the independent
//! Mitsuba 3 data set as an ignored test).

// Index loops over parallel per-texel arrays read more clearly than zipped iterators here.
#![allow(clippy::needless_range_loop)]

mod albedo;
pub mod atlas;
mod checkpoint;
pub mod colmap;
pub mod contact;
pub mod convergence;
mod direct;
pub mod downsample;
pub mod footprint;
pub mod gains;
pub mod gather;
pub mod inpaint;
pub mod noise;
mod observe;
pub mod photo_noise;
mod pipeline;
pub mod pose;
pub mod progress;
mod result;
mod settings;
mod smooth;
mod split;
mod stages;
pub mod superres;
mod timing;
pub mod unseen;
pub mod views;
pub mod working_size;

pub use direct::{MAX_LIGHTS_PER_TEXEL, PENUMBRA_DILATION, direct_irradiance};
pub use gains::{ViewGain, ViewGainMode, ViewGainSettings, ViewGains, apply_view_gains};
pub use observe::{RegionStats, luminance_map, object_masks, pixel_ray, region_stats};
pub use pipeline::delight;
pub use pose::{PoseRefinement, PoseReport, PoseSettings, ViewPose};
pub use progress::Progress;
pub use result::{DelightResult, IterationStats, ObjectResult};
pub use settings::{DebugSettings, DelightSettings, LightPaths, UpdateRule};
pub use smooth::{reached_texels, smooth_in_charts, smooth_in_charts_masked};
pub use timing::{StageClock, cpu_seconds, rss_mb};
pub use unseen::UnseenLight;

use opal::image::Image;
use opal::scene::desc::{BitmapDesc, BsdfDesc, FilterType, SceneDesc, TextureDesc, WrapMode};
use opal::spectrum::Spectrum;
use std::sync::Arc;

fn to_image(v: &[[f32; 3]], w: usize, h: usize) -> Image {
    let mut img = Image::new(w, h);
    for (d, s) in img.data.iter_mut().zip(v) {
        *d = Spectrum::rgb(s[0], s[1], s[2]);
    }
    img
}

/// Rec. 709 luminance.
#[inline]
pub fn luminance(c: [f32; 3]) -> f32 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

/// The scene description with every recovered object using its atlas mesh and a diffuse BSDF
/// with its albedo texture (bilinear, clamp).
pub fn recovered_desc(desc: &SceneDesc, objects: &[ObjectResult]) -> SceneDesc {
    let kd: Vec<&[[f32; 3]]> = objects.iter().map(|o| o.kd.as_slice()).collect();
    recovered_desc_with(desc, objects, &kd)
}

/// [`recovered_desc`] with the albedo maps `kd` (one per object, on its atlas) instead of the
/// objects' own.
pub fn recovered_desc_with<K: AsRef<[[f32; 3]]>>(
    desc: &SceneDesc,
    objects: &[ObjectResult],
    kd: &[K],
) -> SceneDesc {
    let mut d = desc.clone();
    for (o, kd) in objects.iter().zip(kd) {
        let s = &mut d.shapes[o.shape];
        s.mesh = o.atlas.mesh.clone();
        s.bsdf = BsdfDesc::Diffuse {
            reflectance: TextureDesc::Bitmap(BitmapDesc {
                image: Arc::new(to_image(kd.as_ref(), o.atlas.width, o.atlas.height)),
                filter: FilterType::Bilinear,
                wrap: WrapMode::Clamp,
                path: format!("{}.exr", o.id).into(),
            }),
        };
    }
    d
}
