//! Wavefront OBJ reader (`opal::geometry::obj::read_obj`), both texture-coordinate conventions.
#![no_main]
use libfuzzer_sys::fuzz_target;
use opal_fuzz::write_input;

fuzz_target!(|data: &[u8]| {
    let path = write_input("mesh.obj", data);
    let _ = opal::geometry::obj::read_obj(&path, data.first().is_some_and(|b| b & 1 == 1));
});
