//! COLMAP text model (`opal_inverse::delight::colmap`): `cameras.txt`, then after a line
//! `#--IMAGES--` the `images.txt` text, each through its parser; then both together through
//! `read_colmap` (files in the scratch directory, where a 2×2 `v.exr` exists).
#![no_main]
use libfuzzer_sys::fuzz_target;
use opal_fuzz::{ensure_tiny_exr, scratch_dir, split_once, write_input};
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    ensure_tiny_exr("v.exr");
    let (cams, imgs) = split_once(data, b"#--IMAGES--\n");
    let imgs = imgs.unwrap_or(b"");
    if let (Ok(c), Ok(i)) = (std::str::from_utf8(cams), std::str::from_utf8(imgs)) {
        let _ = opal_inverse::delight::colmap::parse_cameras(c, Path::new("cameras.txt"));
        let _ = opal_inverse::delight::colmap::parse_images(i, Path::new("images.txt"));
    }
    write_input("cameras.txt", cams);
    write_input("images.txt", imgs);
    let d = scratch_dir();
    let _ = opal_inverse::delight::colmap::read_colmap(d, d);
});
