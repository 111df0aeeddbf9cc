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
