//! PLY reader (`opal::geometry::ply::read_ply`), ASCII and binary (the header picks).
#![no_main]
use libfuzzer_sys::fuzz_target;
use opal_fuzz::write_input;

fuzz_target!(|data: &[u8]| {
    let path = write_input("mesh.ply", data);
    let _ = opal::geometry::ply::read_ply(&path);
});
