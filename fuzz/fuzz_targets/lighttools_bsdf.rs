//! LightTools BSDF text reader (`opal_inverse::scatter::lighttools::parse`, which `read` calls),
//! then the conversion to measured curves that `opal fit-ndf` does with it.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let p = Path::new("fuzz.txt");
    if let Ok(t) = opal_inverse::scatter::lighttools::parse(text, p) {
        let _ = t.to_measured(p);
    }
});
