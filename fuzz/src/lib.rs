//! Helpers shared by the fuzz targets: a per-process scratch directory for the parsers that
//! read from a path (the input is written to a file there and the real path-taking entry point
//! is called, so no parsing logic is duplicated for fuzzing).

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// A scratch directory unique to this process (in /dev/shm when it exists, so the writes stay
/// in memory), created on first use.
pub fn scratch_dir() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let base =
            if Path::new("/dev/shm").is_dir() { PathBuf::from("/dev/shm") } else { std::env::temp_dir() };
        let d = base.join(format!("opal-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&d).expect("scratch dir");
        d
    })
}

/// Writes `data` to `name` in the scratch directory and returns its path.
pub fn write_input(name: &str, data: &[u8]) -> PathBuf {
    let p = scratch_dir().join(name);
    std::fs::write(&p, data).expect("write fuzz input");
    p
}

/// Splits `data` at the first occurrence of `sep`: `(before, Some(after))`, or `(data, None)`.
pub fn split_once<'a>(data: &'a [u8], sep: &[u8]) -> (&'a [u8], Option<&'a [u8]>) {
    match data.windows(sep.len()).position(|w| w == sep) {
        Some(i) => (&data[..i], Some(&data[i + sep.len()..])),
        None => (data, None),
    }
}

/// Writes a 2×2 EXR named `name` into the scratch directory once per process (for the targets
/// whose input names images: `transforms.json`, COLMAP `images.txt`).
pub fn ensure_tiny_exr(name: &str) {
    let p = scratch_dir().join(name);
    if p.exists() {
        return;
    }
    let img = opal::image::Image { width: 2, height: 2, data: vec![opal::Spectrum::rgb(0.5, 0.25, 1.0); 4] };
    let f = std::fs::File::create(&p).expect("create tiny exr");
    opal::image::write::write_exr(&img, std::io::BufWriter::new(f)).expect("write tiny exr");
}
