//! Shared by the tests that compare Opal's renders with Mitsuba's: the 16×16 block z-test.

use opal::image::read::read_image;
use opal::integrator::path::RenderOutput;
use std::path::Path;

/// Fraction of (16×16 block, channel) pairs whose |z| ≤ 3, and the worst |z|.
pub fn block_z(out: &RenderOutput, reference: &Path, ref_stderr: &Path) -> (f64, f64, f64) {
    let r = read_image(reference).unwrap();
    let rs = read_image(ref_stderr).unwrap();
    assert_eq!((r.width, r.height), (out.image.width, out.image.height));
    let b = 16;
    let (mut ok, mut total, mut worst, mut sum_z) = (0, 0, 0.0f64, 0.0f64);
    for by in 0..r.height / b {
        for bx in 0..r.width / b {
            for c in 0..3 {
                let (mut mo, mut mr, mut var) = (0.0f64, 0.0f64, 0.0f64);
                for y in by * b..(by + 1) * b {
                    for x in bx * b..(bx + 1) * b {
                        mo += out.image.get(x, y)[c] as f64;
                        mr += r.get(x, y)[c] as f64;
                        var += (out.stderr.get(x, y)[c] as f64).powi(2) + (rs.get(x, y)[c] as f64).powi(2);
                    }
                }
                if var == 0.0 {
                    // a block without noise in both (background: black, or a constant
                    // environment seen directly) carries no statistical information; it must
                    // agree to float rounding (the two renderers sum in different orders)
                    assert!(
                        (mo - mr).abs() <= 1e-5 * mo.abs().max(mr.abs()),
                        "block ({bx},{by}) c{c}: {mo} vs {mr} with zero variance"
                    );
                    continue;
                }
                let z = (mo - mr) / var.sqrt();
                total += 1;
                sum_z += z;
                worst = worst.max(z.abs());
                if z.abs() <= 3.0 {
                    ok += 1;
                }
            }
        }
    }
    (ok as f64 / total as f64, worst, sum_z / total as f64)
}

/// Renders `tests/data/<set>/<name>/scene.xml` with Opal (`spp` samples, the scene's integrator
/// settings, seed 12) and z-tests it against Mitsuba's `ref.exr` / `ref_stderr.exr` beside it
/// ([`block_z`]); returns the fraction of blocks within 3σ. Below 99 %, Opal's image and its
/// standard error are written to the temp dir (`opal_<set>_<name>[_stderr].exr`) for inspection.
#[allow(dead_code)] // mitsuba_cbox.rs renders its own views
pub fn ztest_scene(set: &str, name: &str, spp: u32) -> f64 {
    use opal::integrator::path::{PathSettings, render};
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data").join(set).join(name);
    let desc = opal::scene::load_mitsuba_xml(&dir.join("scene.xml"), &[]).unwrap();
    let scene = opal::scene::Scene::build(&desc).unwrap();
    let it = desc.integrator.clone().unwrap_or_default();
    let s =
        PathSettings { spp, max_depth: it.max_depth, rr_depth: it.rr_depth, hide_emitters: false, seed: 12 };
    let out = render(&scene, 0, &s, &|| {});
    assert_eq!(out.nonfinite, 0);
    let (frac, worst, mean_z) = block_z(&out, &dir.join("ref.exr"), &dir.join("ref_stderr.exr"));
    eprintln!("{name}: {:.2} % of blocks within 3σ, worst |z| {worst:.2}, mean z {mean_z:+.3}", frac * 100.0);
    if frac < 0.99 {
        let tmp = std::env::temp_dir();
        for (img, suffix) in [(&out.image, ""), (&out.stderr, "_stderr")] {
            let f = std::fs::File::create(tmp.join(format!("opal_{set}_{name}{suffix}.exr"))).unwrap();
            opal::image::write::write_exr(img, f).unwrap();
        }
    }
    frac
}
