//! PLATE.toml (`opal gonio simulate`, `opal fit-ndf`): the CLI's own module
//! `crates/opal-cli/src/plate.rs` is compiled in (the CLI is a binary crate), the text is
//! deserialised as `read_plate_file` does and merged into a validated configuration by
//! `build_config` with no command-line overrides.
#![no_main]
#![allow(dead_code, missing_docs)]
use libfuzzer_sys::fuzz_target;

#[path = "../../crates/opal-cli/src/plate.rs"]
mod plate;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let Ok(file) = toml::from_str::<plate::PlateFile>(text) else { return };
    let _ = plate::build_config(&file, &plate::PlateOverrides::default());
});
