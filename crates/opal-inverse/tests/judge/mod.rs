//! Texture judging shared by the de-lighting acceptance tests (`delight_room.rs`,
//! `delight_env_mixed.rs`): PSNR of a recovered texture in texel space and pixel-averaged at the
//! input cameras (issue 17's texture metric).

use opal::image::Image;
use opal::math::Vec2;
use opal::scene::Scene;
use opal::scene::desc::{BitmapDesc, FilterType, WrapMode};
use opal_inverse::delight::views::View;
use opal_inverse::delight::{DelightResult, ObjectResult};

/// The recovered object `id` (its UVs kept) and its albedo texture as a bilinear bitmap.
pub fn recovered_texture<'a>(r: &'a DelightResult, id: &str) -> (&'a ObjectResult, BitmapDesc) {
    let o = r.objects.iter().find(|o| o.id == id).unwrap();
    assert!(o.atlas.kept_uvs, "{id}: UVs not kept");
    let got = BitmapDesc {
        image: std::sync::Arc::new(o.kd_image()),
        filter: FilterType::Bilinear,
        wrap: WrapMode::Clamp,
        path: "kd".into(),
    };
    (o, got)
}

/// PSNR (peak 1) of a recovered texture against the truth over the texels seen by some view;
/// the recovered texture is looked up at the truth's texel centres (same UVs).
pub fn texture_psnr(r: &DelightResult, id: &str, truth: &Image) -> (f64, usize) {
    let (o, got) = recovered_texture(r, id);
    let (w, h) = (o.atlas.width, o.atlas.height);
    let (mut se, mut n) = (0f64, 0usize);
    for y in 0..truth.height {
        for x in 0..truth.width {
            let uv = Vec2::new((x as f32 + 0.5) / truth.width as f32, (y as f32 + 0.5) / truth.height as f32);
            let (tx, ty) = ((uv.x * w as f32) as usize, (uv.y * h as f32) as usize);
            if !o.observed[ty.min(h - 1) * w + tx.min(w - 1)] {
                continue;
            }
            let (g, t) = (got.eval(uv), truth.get(x, y));
            for c in 0..3 {
                se += ((g[c] - t[c]) as f64).powi(2);
            }
            n += 3;
        }
    }
    (10.0 * (1.0 / (se / n as f64)).log10(), n / 3)
}

/// PSNR (peak 1) of a recovered texture pixel-averaged at the input cameras (issue 17's
/// texture metric): per view pixel, 4 × 4 stratified rays through the pixel (box filter); the
/// samples whose first hit is object `id` give the pixel's truth albedo (the truth texture at
/// the hit's UV) and its recovered albedo (the recovered texture, bilinear, at the same UV),
/// each averaged over those samples. Pixels where the object is not seen are skipped; every
/// channel of every remaining pixel of every view counts once. Returns (PSNR, pixels).
pub fn texture_psnr_at_cameras(
    r: &DelightResult,
    id: &str,
    scene: &Scene,
    views: &[View],
    truth: &BitmapDesc,
) -> (f64, usize) {
    const SUB: usize = 4;
    let (_, got) = recovered_texture(r, id);
    let shape = scene.shapes.iter().position(|s| s.id == id).unwrap() as u32;
    let (mut se, mut n) = (0f64, 0usize);
    for v in views {
        let cam = &v.camera;
        for y in 0..cam.height {
            for x in 0..cam.width {
                let (mut sg, mut st, mut k) = ([0f64; 3], [0f64; 3], 0usize);
                for j in 0..SUB * SUB {
                    let p = Vec2::new(
                        x as f32 + ((j % SUB) as f32 + 0.5) / SUB as f32,
                        y as f32 + ((j / SUB) as f32 + 0.5) / SUB as f32,
                    );
                    let Some(si) = scene.intersect(&cam.generate_ray(p)) else { continue };
                    if si.shape != shape {
                        continue;
                    }
                    let (g, t) = (got.eval(si.uv), truth.eval(si.uv));
                    for c in 0..3 {
                        sg[c] += g[c] as f64;
                        st[c] += t[c] as f64;
                    }
                    k += 1;
                }
                if k == 0 {
                    continue;
                }
                for c in 0..3 {
                    se += ((sg[c] - st[c]) / k as f64).powi(2);
                }
                n += 1;
            }
        }
    }
    (10.0 * (1.0 / (se / (3 * n) as f64)).log10(), n)
}
