//! The image reader as Opal calls it (`opal::image::read`) on a `.hdr` file.
#![no_main]
use libfuzzer_sys::fuzz_target;
use opal_fuzz::write_input;

fuzz_target!(|data: &[u8]| {
    let path = write_input("img.hdr", data);
    let _ = opal::image::read::read_image_decoded(&path);
});
