//! `transforms.json` reader of delight (`opal_inverse::delight::views::read_views`). The
//! images it names are looked up next to it in the scratch directory (a 2×2 EXR `v.exr` is
//! there, so frames naming it get past the image read).
#![no_main]
use libfuzzer_sys::fuzz_target;
use opal_fuzz::{ensure_tiny_exr, write_input};

fuzz_target!(|data: &[u8]| {
    ensure_tiny_exr("v.exr");
    let path = write_input("transforms.json", data);
    let _ = opal_inverse::delight::views::read_views(&path);
});
