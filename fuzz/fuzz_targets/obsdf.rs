//! `.obsdf` tabulated-BSDF reader (`opal::bsdf::TabulatedBsdf::from_bytes`, which `load` calls).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = opal::bsdf::TabulatedBsdf::from_bytes(data);
});
