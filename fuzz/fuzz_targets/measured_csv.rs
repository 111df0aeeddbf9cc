//! Measured-curve CSV, the `opal fit-ndf` input (`opal_inverse::measured::Measured::parse`,
//! which `Measured::read` calls), then the incidences the fit iterates over.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    if let Ok(m) = opal_inverse::measured::Measured::parse(text, Path::new("fuzz.csv")) {
        let _ = m.incidences();
    }
});
