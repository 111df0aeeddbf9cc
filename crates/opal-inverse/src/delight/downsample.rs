//! Working from downsampled views ([`DelightSettings::max_view_pixels`](super::DelightSettings::max_view_pixels)):
//! a view with more pixels than the limit is replaced by its box-filtered (area-averaged)
//! image on a coarser film of the same frustum, so every later step (texture resolution from
//! the pixel footprints, luminance maps, super-resolution, gains, poses) sees fewer, larger
//! pixels, and the memory and time that grow with the pixels shrink with them.
//!
//! Conventions: the coarse film is `round(w/f) × round(h/f)` with `f = sqrt(w·h / max)`, both
//! at least 1 and their product at most `max` (`f` is raised until it is); the camera keeps its
//! pose and both tangents of its half fields of view, so a coarse pixel covers exactly the
//! original pixels' area under it (fractional coverage at its borders, weighted by overlap).
//! A coarse pixel touching a masked (NaN) original pixel is masked too; the count of masked
//! coarse pixels replaces [`View::bad_pixels`]. A pixel-centred box filter of the photos is
//! what the super-resolution's pixel model assumes, so the downsampled views are consistent
//! photos of a lower-resolution camera.
//!
//! Tests: `downsample_keeps_the_mean_and_the_frustum` below; the CLI's `--max-view-pixels`
//! test (`crates/opal-cli/tests/delight.rs`).

use super::views::View;
use opal::image::Image;
use opal::spectrum::Spectrum;

/// Film size of a `w × h` view limited to `max_pixels` (the size itself when it fits or
/// `max_pixels` is 0).
pub fn working_size(w: usize, h: usize, max_pixels: usize) -> (usize, usize) {
    if max_pixels == 0 || w * h <= max_pixels {
        return (w, h);
    }
    let mut f = ((w * h) as f64 / max_pixels as f64).sqrt();
    loop {
        let (nw, nh) = (((w as f64 / f).round() as usize).max(1), ((h as f64 / f).round() as usize).max(1));
        if nw * nh <= max_pixels || (nw == 1 && nh == 1) {
            return (nw, nh);
        }
        f *= 1.0 + 1e-3;
    }
}

/// Source pixels and their overlap weights of each coarse pixel along one axis (`n` fine
/// pixels onto `m` coarse ones): coarse pixel `i` covers `[i·n/m, (i+1)·n/m)`.
fn axis_taps(n: usize, m: usize) -> Vec<Vec<(usize, f64)>> {
    let s = n as f64 / m as f64;
    (0..m)
        .map(|i| {
            let (a, b) = (i as f64 * s, (i + 1) as f64 * s);
            let mut taps = Vec::new();
            let mut k = a.floor() as usize;
            while (k as f64) < b && k < n {
                let w = (b.min(k as f64 + 1.0) - a.max(k as f64)) / s;
                if w > 1e-9 {
                    taps.push((k, w));
                }
                k += 1;
            }
            taps
        })
        .collect()
}

/// `image` box-filtered onto a `nw × nh` film of the same extent (NaN where a covered pixel
/// is NaN).
pub fn downsample_image(image: &Image, nw: usize, nh: usize) -> Image {
    let (tx, ty) = (axis_taps(image.width, nw), axis_taps(image.height, nh));
    let mut out = Image::new(nw, nh);
    for (y, ry) in ty.iter().enumerate() {
        for (x, rx) in tx.iter().enumerate() {
            let mut acc = [0f64; 3];
            for &(sy, wy) in ry {
                for &(sx, wx) in rx {
                    let p = image.data[sy * image.width + sx].0;
                    for c in 0..3 {
                        acc[c] += wx * wy * p[c] as f64;
                    }
                }
            }
            out.data[y * nw + x] = Spectrum::rgb(acc[0] as f32, acc[1] as f32, acc[2] as f32);
        }
    }
    out
}

/// `view` on a film of at most `max_pixels` pixels (see the module documentation); the view
/// itself when it fits (or `max_pixels` is 0).
pub fn downsample_view(view: View, max_pixels: usize) -> View {
    let (w, h) = (view.image.width, view.image.height);
    let (nw, nh) = working_size(w, h, max_pixels);
    if (nw, nh) == (w, h) {
        return view;
    }
    let image = downsample_image(&view.image, nw, nh);
    let bad_pixels = image.data.iter().filter(|p| !p.is_finite()).count();
    let mut camera = view.camera;
    // the same frustum: the tangents of the half fields of view are kept as they are
    camera.width = nw;
    camera.height = nh;
    View { image, camera, bad_pixels, ..view }
}

#[cfg(test)]
mod tests {
    use super::*;
    use opal::camera::Camera;
    use opal::math::{Mat4, Vec2};
    use opal::scene::desc::SensorDesc;

    #[test]
    fn downsample_keeps_the_mean_and_the_frustum() {
        assert_eq!(working_size(1024, 1024, 0), (1024, 1024));
        assert_eq!(working_size(1024, 1024, 1 << 20), (1024, 1024));
        assert_eq!(working_size(1024, 1024, 1 << 18), (512, 512));
        let (w, h) = working_size(4000, 3000, 1_000_000);
        assert!(w * h <= 1_000_000 && w * h > 950_000 && (w as f64 / h as f64 - 4.0 / 3.0).abs() < 0.01);
        // a 7×5 image onto 3×2: area-weighted means; the total is kept
        let mut img = Image::new(7, 5);
        for (k, p) in img.data.iter_mut().enumerate() {
            *p = Spectrum::splat(k as f32);
        }
        let d = downsample_image(&img, 3, 2);
        let mean = |i: &Image| i.data.iter().map(|p| p.0[0] as f64).sum::<f64>() / i.data.len() as f64;
        assert!((mean(&d) - mean(&img)).abs() < 1e-4, "{} vs {}", mean(&d), mean(&img));
        // the top-left coarse pixel covers x ∈ [0, 7/3), y ∈ [0, 2.5): its mean by hand
        let mut acc = 0.0;
        for y in 0..3 {
            for x in 0..3 {
                let wx = if x == 2 { 1.0 / 3.0 } else { 1.0 };
                let wy = if y == 2 { 0.5 } else { 1.0 };
                acc += wx * wy * (y * 7 + x) as f64;
            }
        }
        assert!((d.data[0].0[0] as f64 - acc / (7.0 / 3.0 * 2.5)).abs() < 1e-4);
        // a NaN masks the coarse pixels over it only
        img.data[6] = Spectrum::splat(f32::NAN);
        let d = downsample_image(&img, 3, 2);
        assert!(d.data[2].0[0].is_nan() && d.data[0].0[0].is_finite() && d.data[5].0[0].is_finite());
        // the coarse camera sees the same ray through the same film position
        let desc = SensorDesc {
            id: "v".into(),
            to_world: Mat4::IDENTITY,
            fov_x_deg: 50.0,
            width: 7,
            height: 5,
            near_clip: 1e-3,
            far_clip: 1e3,
            spp: None,
        };
        let v = View {
            name: "v".into(),
            path: "v.exr".into(),
            camera: Camera::new(&desc),
            image: img,
            bad_pixels: 1,
        };
        let fine = v.camera.clone();
        let c = downsample_view(v, 6);
        assert_eq!((c.camera.width, c.camera.height, c.image.width), (3, 2, 3));
        assert_eq!(c.bad_pixels, 1);
        let a = fine.generate_ray(Vec2::new(7.0 * 0.3, 5.0 * 0.6));
        let b = c.camera.generate_ray(Vec2::new(3.0 * 0.3, 2.0 * 0.6));
        assert!((a.d - b.d).length() < 1e-6, "{:?} vs {:?}", a.d, b.d);
    }
}
