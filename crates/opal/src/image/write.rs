//! Image writers: float32 RGB OpenEXR and 8-bit sRGB PNG previews. They write to any
//! `Write + Seek` so that callers can write into a temporary file and rename it into place.

use super::Image;
use crate::error::{Error, Result};
use std::io::{Seek, Write};

/// Writes linear RGB as a float32 OpenEXR (channels R, G, B; row 0 on top).
pub fn write_exr<W: Write + Seek>(img: &Image, w: W) -> Result<()> {
    use exr::prelude::{SpecificChannels, Vec2, WritableImage};
    let layer = SpecificChannels::rgb(|pos: Vec2<usize>| {
        let p = img.get(pos.x(), pos.y());
        (p[0], p[1], p[2])
    });
    let image = exr::image::Image::from_channels((img.width, img.height), layer);
    // one thread: the parallel writer stores the compressed blocks in the order they finish,
    // so the same pixels could give different files
    image.write().non_parallel().to_buffered(w).map_err(|e| Error::invalid("EXR output", e.to_string()))
}

/// sRGB opto-electronic transfer function of a linear value in [0, 1].
pub fn linear_to_srgb(v: f32) -> f32 {
    if v <= 0.003_130_8 { 12.92 * v } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 }
}

/// Inverse of [`linear_to_srgb`].
pub fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.040_45 { v / 12.92 } else { ((v + 0.055) / 1.055).powf(2.4) }
}

/// 8-bit sRGB bytes (RGB interleaved) of `img × exposure`, clamped to [0, 1].
pub fn to_srgb8(img: &Image, exposure: f32) -> Vec<u8> {
    let mut out = Vec::with_capacity(img.data.len() * 3);
    for p in &img.data {
        for c in 0..3 {
            let v = (p[c] * exposure).clamp(0.0, 1.0);
            let v = if v.is_finite() { v } else { 0.0 };
            out.push((linear_to_srgb(v) * 255.0 + 0.5) as u8);
        }
    }
    out
}

/// Writes an 8-bit sRGB PNG preview of `img × exposure`.
pub fn write_png_srgb<W: Write + Seek>(img: &Image, exposure: f32, mut w: W) -> Result<()> {
    let buf = image::RgbImage::from_raw(img.width as u32, img.height as u32, to_srgb8(img, exposure))
        .ok_or_else(|| Error::invalid("PNG output", "buffer size mismatch"))?;
    buf.write_to(&mut w, image::ImageFormat::Png).map_err(|e| Error::invalid("PNG output", e.to_string()))
}

/// Writes an 8-bit false-colour PNG of a scalar field (`values`, row-major `width × height`) with
/// the given range (viridis-like map); NaN pixels are black.
pub fn write_false_colour_png<W: Write + Seek>(
    values: &[f32],
    width: usize,
    height: usize,
    range: (f32, f32),
    mut w: W,
) -> Result<()> {
    let mut out = Vec::with_capacity(values.len() * 3);
    for &v in values {
        let rgb = if v.is_finite() {
            let t = ((v - range.0) / (range.1 - range.0).max(1e-30)).clamp(0.0, 1.0);
            false_colour(t)
        } else {
            [0, 0, 0]
        };
        out.extend_from_slice(&rgb);
    }
    let buf = image::RgbImage::from_raw(width as u32, height as u32, out)
        .ok_or_else(|| Error::invalid("PNG output", "buffer size mismatch"))?;
    buf.write_to(&mut w, image::ImageFormat::Png).map_err(|e| Error::invalid("PNG output", e.to_string()))
}

/// Viridis-like colour map, t ∈ [0, 1] (piecewise linear through 6 anchor colours).
pub fn false_colour(t: f32) -> [u8; 3] {
    const A: [[f32; 3]; 6] = [
        [68.0, 1.0, 84.0],
        [65.0, 68.0, 135.0],
        [42.0, 120.0, 142.0],
        [34.0, 168.0, 132.0],
        [122.0, 209.0, 81.0],
        [253.0, 231.0, 37.0],
    ];
    let x = t.clamp(0.0, 1.0) * 5.0;
    let i = (x as usize).min(4);
    let f = x - i as f32;
    let mut c = [0u8; 3];
    for k in 0..3 {
        c[k] = (A[i][k] * (1.0 - f) + A[i + 1][k] * f).round() as u8;
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spectrum::Spectrum;

    /// The same pixels give the same bytes every time (the blocks of a parallel writer land in
    /// the order they finish: this failed before the writer was made sequential).
    #[test]
    fn exr_bytes_are_deterministic() {
        let mut img = Image::new(512, 384);
        let mut rng = crate::sampling::Rng::new(1, 2, 3);
        for y in 0..384 {
            for x in 0..512 {
                // rows of very different entropy, so blocks take different times to compress
                let v = if (y / 32) % 2 == 0 { rng.next_f32() } else { 0.5 };
                img.set(x, y, Spectrum::rgb(v, v * 0.5, 1.0 - v));
            }
        }
        let bytes = |img: &Image| {
            let mut buf = std::io::Cursor::new(Vec::new());
            write_exr(img, &mut buf).unwrap();
            buf.into_inner()
        };
        let first = bytes(&img);
        for _ in 0..12 {
            assert!(bytes(&img) == first, "EXR bytes differ between writes of the same image");
        }
    }

    #[test]
    fn exr_roundtrip_via_exr_crate() {
        let mut img = Image::new(5, 3);
        img.set(4, 2, Spectrum::rgb(1.5, 0.25, 1e-3));
        img.set(0, 0, Spectrum::rgb(7.0, 8.0, 9.0));
        let mut buf = std::io::Cursor::new(Vec::new());
        write_exr(&img, &mut buf).unwrap();
        let read = exr::prelude::read_first_rgba_layer_from_file(
            {
                let p = std::env::temp_dir().join(format!("opal_exr_rt_{}.exr", std::process::id()));
                std::fs::write(&p, buf.into_inner()).unwrap();
                p
            },
            |res, _| vec![[0f32; 3]; res.width() * res.height()],
            |px: &mut Vec<[f32; 3]>, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                px[pos.y() * 5 + pos.x()] = [r, g, b]
            },
        )
        .unwrap();
        let px = &read.layer_data.channel_data.pixels;
        assert_eq!(px[2 * 5 + 4], [1.5, 0.25, 1e-3]);
        assert_eq!(px[0], [7.0, 8.0, 9.0]);
    }

    #[test]
    fn srgb_curve() {
        for v in [0.0f32, 0.001, 0.2, 0.5, 1.0] {
            assert!((srgb_to_linear(linear_to_srgb(v)) - v).abs() < 1e-6);
        }
        assert_eq!(false_colour(0.0), [68, 1, 84]);
        assert_eq!(false_colour(1.0), [253, 231, 37]);
    }
}
