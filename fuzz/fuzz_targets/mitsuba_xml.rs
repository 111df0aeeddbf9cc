//! Mitsuba XML scene loader (`opal::scene::load_mitsuba_xml`) with `<include>` and
//! `<default>`: the input is `main.xml`, optionally followed by `\n<!--INC-->\n` and the text
//! of `inc.xml` (which the main file may include), and it is loaded with one `$name`
//! parameter given (`spp=4`) as the CLI's `-D` would.
#![no_main]
use libfuzzer_sys::fuzz_target;
use opal_fuzz::{split_once, write_input};

fuzz_target!(|data: &[u8]| {
    let (main, inc) = split_once(data, b"\n<!--INC-->\n");
    write_input("inc.xml", inc.unwrap_or(b""));
    let path = write_input("main.xml", main);
    let _ = opal::scene::load_mitsuba_xml(&path, &[("spp".to_string(), "4".to_string())]);
});
