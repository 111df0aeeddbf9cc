//! Regenerates `tests/data/cbox/backwall_aov_samples.csv` from Mitsuba's centre-ray AOV file
//! (`aov/view_00_center.exr` of the shared reference data, 1.2 MB, not in the repo): for a
//! deterministic subset of the pixels whose ray hits the back wall (shape index 8), the
//! internal uv Mitsuba used and the albedo it looked up there.
//!
//! ```text
//! cargo run -p opal --example extract_aov_csv -- \
//!     <shared>/reference/mitsuba/cbox/aov/view_00_center.exr crates/opal/tests/data/cbox/backwall_aov_samples.csv
//! ```
use std::fmt::Write;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() != 3 {
        return Err("usage: extract_aov_csv <view_XX_center.exr> <out.csv>".into());
    }
    let (w, h, ch) = opal::image::read::read_exr_channels(std::path::Path::new(&args[1]))?;
    let get = |n: &str| ch.get(n).ok_or_else(|| format!("channel {n} missing"));
    let (shape, u, v) = (get("shape.I")?, get("uv.U")?, get("uv.V")?);
    let (r, g, b) = (get("albedo.R")?, get("albedo.G")?, get("albedo.B")?);
    let mut out = String::from("px,py,u,v,albedo_r,albedo_g,albedo_b\n");
    let mut n = 0;
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            // Every 41st pixel of the image (a prime stride: spreads over rows and texel phases).
            if shape[i] != 8.0 || i % 41 != 0 {
                continue;
            }
            writeln!(out, "{x},{y},{:e},{:e},{:e},{:e},{:e}", u[i], v[i], r[i], g[i], b[i])?;
            n += 1;
        }
    }
    std::fs::write(&args[2], out)?;
    eprintln!("{n} samples written to {}", args[2]);
    Ok(())
}
