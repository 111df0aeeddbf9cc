//! Image readers: OpenEXR (any channel names, any size), PNG (8/16-bit, grey or colour, alpha
//! dropped) and Radiance HDR.
//!
//! * [`read_image`] returns the stored values as linear floats **without** applying any
//!   transfer function: an 8-bit PNG texel `k` becomes `k/255`, a 16-bit one `k/65535`.
//!   [`read_image_decoded`] additionally says whether the file's values are sRGB-encoded
//!   (PNG) or linear (EXR, HDR), so that a texture loader can apply [`srgb_to_linear`] unless
//!   the scene asks for `raw` data (Mitsuba's `bitmap` semantics).
//! * EXR colour is read **by channel name** (`R`, `G`, `B`; a lone `Y` gives grey), never by
//!   position: OpenEXR stores channels sorted by name.
//! * [`read_exr_channels`] reads every channel of an EXR file under its full name (in
//!   multi-part files the part name is prefixed with a dot), e.g. Mitsuba AOV files with
//!   `albedo.R`, `depth.T`, `position.X`.
//!
//! Row 0 is the top row of the image, as in [`Image`]. Tests: unit tests below (PNG 8/16-bit
//! round trip through the `image` crate's encoder, sRGB curve) and `tests/scene_load.rs`
//! (the Cornell-box back-wall EXR, decoding errors).

use super::Image;
use crate::error::{Error, Result};
use crate::spectrum::Spectrum;
use std::collections::BTreeMap;
use std::path::Path;

/// An image as read from disk plus how its values are encoded.
#[derive(Clone, Debug)]
pub struct DecodedImage {
    /// The stored values as floats (no transfer function applied).
    pub image: Image,
    /// True when the file format stores display-referred sRGB-encoded values (PNG); false for
    /// linear formats (EXR, HDR).
    pub srgb_encoded: bool,
}

/// Exact sRGB electro-optical transfer function (IEC 61966-2-1), `[0,1] → [0,1]`.
pub fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 { v / 12.92 } else { ((v + 0.055) / 1.055).powf(2.4) }
}

/// [`srgb_to_linear`] applied to every channel of `data`, with the same bits: an 8-bit image
/// has at most 256 distinct values, so each result is kept in a slot picked by `255·v + ½`
/// together with its input's bits, and `powf` runs only when the slot holds another input
/// (a 512² PNG texture: 256 calls instead of 786 432).
pub fn srgb_to_linear_all(data: &mut [Spectrum]) {
    // (input bits, its result): every slot always holds a true pair (`as` saturates: NaN and
    // negative inputs pick slot 0, large ones slot 255)
    let mut memo = [(0.0f32.to_bits(), srgb_to_linear(0.0)); 256];
    for x in data.iter_mut().flat_map(|v| v.0.iter_mut()) {
        let slot = &mut memo[((*x * 255.0 + 0.5) as usize).min(255)];
        if slot.0 != x.to_bits() {
            *slot = (x.to_bits(), srgb_to_linear(*x));
        }
        *x = slot.1;
    }
}

fn file_kind(path: &Path) -> Option<&'static str> {
    let ext = path.extension()?.to_str()?.to_ascii_lowercase();
    match ext.as_str() {
        "exr" => Some("exr"),
        "png" => Some("png"),
        "hdr" | "rgbe" | "pic" => Some("hdr"),
        _ => None,
    }
}

fn decode_err(path: &Path, msg: impl std::fmt::Display) -> Error {
    Error::Parse { path: path.to_path_buf(), line: 0, col: 0, msg: format!("cannot decode image: {msg}") }
}

/// Reads an EXR, PNG or HDR image (chosen by extension) as stored, without any transfer
/// function. See the module documentation.
pub fn read_image(path: &Path) -> Result<Image> {
    Ok(read_image_decoded(path)?.image)
}

/// Like [`read_image`], also telling whether the values are sRGB-encoded.
pub fn read_image_decoded(path: &Path) -> Result<DecodedImage> {
    if !path.exists() {
        return Err(Error::io(path, std::io::Error::new(std::io::ErrorKind::NotFound, "no such file")));
    }
    match file_kind(path) {
        Some("exr") => Ok(DecodedImage { image: read_exr_rgb(path)?, srgb_encoded: false }),
        Some("png") => Ok(DecodedImage { image: read_with_image_crate(path)?, srgb_encoded: true }),
        Some("hdr") => Ok(DecodedImage { image: read_with_image_crate(path)?, srgb_encoded: false }),
        _ => Err(Error::invalid(
            format!("image file {}", path.display()),
            "unsupported extension (expected .exr, .png or .hdr)",
        )),
    }
}

fn read_with_image_crate(path: &Path) -> Result<Image> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let reader = || {
        image::ImageReader::new(std::io::Cursor::new(&bytes[..]))
            .with_guessed_format()
            .map_err(|e| Error::io(path, e))
    };
    // The header first: the pixels are held as f32 RGB, so the same bound as an EXR's
    // (2^30 samples = 4 GiB) applies, checked before anything is decoded (e.g. a 65 536² PNG
    // would take 48 GiB). The decoder allocates its own buffer from the header before reading
    // the data, so it keeps a limit too: 1 GiB (8-bit RGB up to 16 384², against image's
    // default of 512 MiB), below the 2 GB the fuzz target allows per allocation.
    let (w, h) = reader()?.into_dimensions().map_err(|e| decode_err(path, e))?;
    let samples = w as u64 * h as u64 * 3;
    if samples > MAX_EXR_SAMPLES {
        return Err(decode_err(
            path,
            format!("{w}×{h} pixels are {samples} RGB samples, above the limit of {MAX_EXR_SAMPLES}"),
        ));
    }
    let mut r = reader()?;
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(1 << 30);
    r.limits(limits);
    let dynimg = r.decode().map_err(|e| decode_err(path, e))?;
    let rgb = dynimg.to_rgb32f();
    let (w, h) = (rgb.width() as usize, rgb.height() as usize);
    let data = rgb.pixels().map(|p| Spectrum::rgb(p.0[0], p.0[1], p.0[2])).collect();
    Ok(Image { width: w, height: h, data })
}

/// Most samples (pixels × channels, per layer) an EXR may declare: 2^30 f32 = 4 GiB (e.g.
/// 16 384² RGBA); larger headers are refused before anything is allocated. PNG and HDR files
/// are held the same way and get the same bound (pixels × 3).
pub const MAX_EXR_SAMPLES: u64 = 1 << 30;

/// Reads every channel of the first (or only) layers of an EXR file: `(width, height,
/// channels)`, each channel `width * height` values, row 0 at the top. Channel names are the
/// file's names (`albedo.R`); in multi-part files with named parts, `part.channel`.
pub fn read_exr_channels(path: &Path) -> Result<(usize, usize, BTreeMap<String, Vec<f32>>)> {
    use exr::prelude::*;
    if !path.exists() {
        return Err(crate::error::Error::io(
            path,
            std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
        ));
    }
    // The exr crate allocates every channel from the header's data window before reading a
    // pixel: a corrupt or absurd window (fuzz target image_exr found 2^52 samples) must be
    // refused first.
    let meta = exr::meta::MetaData::read_from_file(path, false).map_err(|e| decode_err(path, e))?;
    for h in meta.headers.iter() {
        let (w, ht) = (h.layer_size.width(), h.layer_size.height());
        let samples = (w as u128) * (ht as u128) * (h.channels.list.len() as u128);
        if samples > MAX_EXR_SAMPLES as u128 {
            return Err(decode_err(
                path,
                format!(
                    "data window {w}×{ht} with {} channels is {samples} samples, above the limit of {MAX_EXR_SAMPLES}",
                    h.channels.list.len()
                ),
            ));
        }
    }
    // each chunk's declared byte count must fit in the file (the crate fills a buffer of that
    // size before reading it): `exr_chunks`
    if !meta.headers.iter().any(|h| h.deep) {
        let parts: Vec<super::exr_chunks::PartLayout> = meta
            .headers
            .iter()
            .map(|h| super::exr_chunks::PartLayout {
                tiled: matches!(h.blocks, exr::meta::BlockDescription::Tiles(_)),
                chunks: h.chunk_count,
            })
            .collect();
        super::exr_chunks::check(path, &parts, meta.requirements.has_multiple_layers)?;
    }
    let img = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .all_layers()
        .all_attributes()
        .from_file(path)
        .map_err(|e| decode_err(path, e))?;
    let mut out = BTreeMap::new();
    let mut size: Option<(usize, usize)> = None;
    for layer in &img.layer_data {
        let (w, h) = (layer.size.width(), layer.size.height());
        match size {
            None => size = Some((w, h)),
            Some(s) if s != (w, h) => {
                return Err(decode_err(path, format!("layers of different sizes {s:?} and {:?}", (w, h))));
            }
            _ => {}
        }
        // Layer names only disambiguate multi-part files; a single part keeps its channel names.
        let prefix = if img.layer_data.len() > 1 {
            layer.attributes.layer_name.as_ref().map(|n| n.to_string())
        } else {
            None
        };
        for ch in &layer.channel_data.list {
            let name = match &prefix {
                Some(p) if !p.is_empty() => format!("{p}.{}", ch.name),
                _ => ch.name.to_string(),
            };
            let values: Vec<f32> = ch.sample_data.values_as_f32().collect();
            if values.len() != w * h {
                return Err(decode_err(
                    path,
                    format!("channel {name} has {} samples, expected {}", values.len(), w * h),
                ));
            }
            out.insert(name, values);
        }
    }
    let (w, h) = size.ok_or_else(|| decode_err(path, "no layers"))?;
    Ok((w, h, out))
}

fn read_exr_rgb(path: &Path) -> Result<Image> {
    let (w, h, ch) = read_exr_channels(path)?;
    let get = |n: &str| ch.get(n);
    // huge pages: a texture's texels are read all over the image by a render (crate::mem)
    let mut data: Vec<Spectrum> = crate::mem::huge_vec(w * h);
    match (get("R"), get("G"), get("B"), get("Y")) {
        (Some(r), Some(g), Some(b), _) => data.extend((0..w * h).map(|i| Spectrum::rgb(r[i], g[i], b[i]))),
        (None, None, None, Some(y)) => data.extend(y.iter().map(|&v| Spectrum::splat(v))),
        _ => {
            let names: Vec<&str> = ch.keys().map(|s| s.as_str()).collect();
            return Err(decode_err(
                path,
                format!("expected channels R,G,B or Y, found [{}]", names.join(", ")),
            ));
        }
    }
    Ok(Image { width: w, height: h, data })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn memoised_srgb_curve_gives_the_direct_bits() {
        // every 8- and 16-bit value as the PNG reader makes them, in an order that makes slots
        // change hands, and random / special floats
        let mut xs: Vec<f32> = (0..=255).map(|k| k as f32 / 255.0).collect();
        xs.extend((0..=65535).rev().map(|k| k as f32 / 65535.0));
        let mut rng = crate::sampling::Rng::new(3, 0, 0);
        xs.extend((0..10_000).map(|_| rng.next_f32() * 1.2 - 0.1));
        xs.extend([f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -0.0, 1e-40, u32::MAX as f32]);
        xs.extend((0..=255).map(|k| k as f32 / 255.0));
        let mut data: Vec<Spectrum> =
            xs.chunks(3).map(|c| Spectrum::rgb(c[0], c[c.len() / 2], c[c.len() - 1])).collect();
        let expected: Vec<[u32; 3]> =
            data.iter().map(|v| v.map(srgb_to_linear).0.map(f32::to_bits)).collect();
        srgb_to_linear_all(&mut data);
        let got: Vec<[u32; 3]> = data.iter().map(|v| v.0.map(f32::to_bits)).collect();
        assert_eq!(got, expected);
    }

    #[test]
    fn srgb_curve_endpoints_and_knee() {
        assert_eq!(srgb_to_linear(0.0), 0.0);
        assert!((srgb_to_linear(1.0) - 1.0).abs() < 1e-6);
        // Both branches meet at the knee (continuity to ~1e-7).
        let a = 0.04045f32 / 12.92;
        let b = ((0.04045f32 + 0.055) / 1.055).powf(2.4);
        assert!((a - b).abs() < 1e-6);
        // Mid grey 0.5 → 0.21404 (IEC 61966-2-1).
        assert!((srgb_to_linear(0.5) - 0.214_041_14).abs() < 1e-6);
    }

    #[test]
    fn png_8_and_16_bit_values_are_normalised_without_gamma() {
        let dir = tempfile::tempdir().unwrap();
        let p8 = dir.path().join("a.png");
        let img8 = image::RgbImage::from_fn(3, 2, |x, y| image::Rgb([(x * 100) as u8, (y * 255) as u8, 7]));
        img8.save(&p8).unwrap();
        let d = read_image_decoded(&p8).unwrap();
        assert!(d.srgb_encoded);
        assert_eq!((d.image.width, d.image.height), (3, 2));
        assert_eq!(d.image.get(2, 1), Spectrum::rgb(200.0 / 255.0, 1.0, 7.0 / 255.0));
        let p16 = dir.path().join("b.png");
        let img16 = image::ImageBuffer::<image::Luma<u16>, _>::from_fn(2, 2, |x, y| {
            image::Luma([(x + 2 * y) as u16 * 1000])
        });
        img16.save(&p16).unwrap();
        let i = read_image(&p16).unwrap();
        assert_eq!(i.get(1, 1), Spectrum::splat(3000.0 / 65535.0));
    }

    /// One EXR part: optional name, channels (name, samples).
    type Part<'a> = (Option<&'a str>, Vec<(&'a str, Vec<f32>)>);

    fn write_exr(path: &Path, layers: Vec<Part>, w: usize, h: usize) {
        use exr::prelude::*;
        let mut parts: Layers<AnyChannels<FlatSamples>> = Default::default();
        for (name, chans) in layers {
            let list = chans
                .into_iter()
                .map(|(n, v)| {
                    // Store Y as f16 to exercise sample-type conversion.
                    let samples = if n == "Y" {
                        FlatSamples::F16(v.into_iter().map(f16::from_f32).collect())
                    } else {
                        FlatSamples::F32(v)
                    };
                    AnyChannel::new(n, samples)
                })
                .collect();
            let attrs = name.map_or_else(LayerAttributes::default, LayerAttributes::named);
            parts.push(Layer::new((w, h), attrs, Encoding::FAST_LOSSLESS, AnyChannels::sort(list)));
        }
        let img = Image::from_layers(ImageAttributes::new(IntegerBounds::from_dimensions((w, h))), parts);
        img.write().to_file(path).unwrap();
    }

    #[test]
    fn exr_grey_named_channels_and_parts() {
        let d = tempfile::tempdir().unwrap();
        // Y only (f16) → grey; 3×2, non-square.
        let p = d.path().join("y.exr");
        write_exr(&p, vec![(None, vec![("Y", vec![0.0, 0.5, 1.0, 2.0, 4.0, 8.0])])], 3, 2);
        let i = read_image(&p).unwrap();
        assert_eq!((i.width, i.height), (3, 2));
        assert_eq!(i.get(2, 1), Spectrum::splat(8.0));
        assert_eq!(i.get(1, 0), Spectrum::splat(0.5));
        // RGBA written in any order is read by name; A ignored.
        let p = d.path().join("rgba.exr");
        let ramp = |k: f32| (0..4).map(|i| k + i as f32).collect::<Vec<f32>>();
        write_exr(
            &p,
            vec![(
                Some("beauty"),
                vec![("A", ramp(9.0)), ("B", ramp(3.0)), ("G", ramp(2.0)), ("R", ramp(1.0))],
            )],
            2,
            2,
        );
        let i = read_image(&p).unwrap();
        assert_eq!(i.get(1, 1), Spectrum::rgb(4.0, 5.0, 6.0));
        // AOV-style channel names; a single named part does not prefix them.
        let p = d.path().join("aov.exr");
        write_exr(&p, vec![(Some("aovs"), vec![("albedo.R", ramp(0.0)), ("depth.T", ramp(10.0))])], 2, 2);
        let (w, h, ch) = read_exr_channels(&p).unwrap();
        assert_eq!((w, h), (2, 2));
        assert_eq!(ch.keys().collect::<Vec<_>>(), ["albedo.R", "depth.T"]);
        assert_eq!(ch["depth.T"], vec![10.0, 11.0, 12.0, 13.0]);
        let e = read_image(&p).unwrap_err().to_string();
        assert!(e.contains("aov.exr") && e.contains("albedo.R, depth.T"), "{e}");
        // Two parts: names prefixed by the part name.
        let p = d.path().join("parts.exr");
        write_exr(&p, vec![(Some("a"), vec![("Z", ramp(0.0))]), (Some("b"), vec![("Z", ramp(1.0))])], 2, 2);
        let (_, _, ch) = read_exr_channels(&p).unwrap();
        assert_eq!(ch.keys().collect::<Vec<_>>(), ["a.Z", "b.Z"]);
    }

    #[test]
    fn radiance_hdr_is_linear() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("x.hdr");
        // Powers of two are exact in RGBE.
        let img =
            image::Rgb32FImage::from_fn(2, 3, |x, y| image::Rgb([x as f32 + 1.0, 0.25 * y as f32, 16.0]));
        image::DynamicImage::ImageRgb32F(img).save(&p).unwrap();
        let dec = read_image_decoded(&p).unwrap();
        assert!(!dec.srgb_encoded);
        assert_eq!((dec.image.width, dec.image.height), (2, 3));
        assert_eq!(dec.image.get(1, 2), Spectrum::rgb(2.0, 0.5, 16.0));
    }

    #[test]
    fn garbage_png_is_a_parse_error_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("bad.png");
        std::fs::write(&p, b"\x89PNG\r\n\x1a\nthis is not a png").unwrap();
        let e = read_image(&p).unwrap_err();
        assert!(matches!(e, Error::Parse { .. }), "{e}");
        assert!(e.to_string().contains("bad.png"), "{e}");
    }
}
