//! χ² goodness-of-fit test of a sampling routine against its pdf over the sphere of directions.
//!
//! The sphere is split into `res` × `2·res` cells of equal solid angle in (cos θ, φ). Samples
//! are histogrammed; the expected count of each cell is `N · ∫cell pdf dω`, integrated by
//! composite Simpson quadrature. Cells with expected count < 5 are pooled. A sample falling in a
//! cell whose integrated pdf is exactly 0 fails the test immediately. The p-value is compared
//! with the Šidák-corrected significance level `1 − (1 − α)^(1/num_tests)`.
//!
//! Samplers that can fail (return `None`) must have a pdf that integrates to the probability
//! of success; failed samples are counted as such and are in no cell.

use crate::math::{PI, Vec2, Vec3};
use crate::sampling::Rng;
use rayon::prelude::*;
use statrs::distribution::{ChiSquared, ContinuousCDF};

/// A sampler and its solid-angle pdf. `sample(u, uc)` gets two uniform numbers for the
/// direction and one for a discrete choice (lobe selection).
pub struct SphereFn<'a> {
    /// Draws a unit direction (or fails).
    pub sample: &'a (dyn Fn(Vec2) -> Option<Vec3> + Sync),
    /// Solid-angle density of `sample`.
    pub pdf: &'a (dyn Fn(Vec3) -> f64 + Sync),
}

/// Same with a third uniform number for discrete choices.
pub struct SphereFn3<'a> {
    /// Draws a unit direction (or fails) from `(u, uc)`.
    pub sample: &'a (dyn Fn(Vec2, f32) -> Option<Vec3> + Sync),
    /// Solid-angle density of `sample`.
    pub pdf: &'a (dyn Fn(Vec3) -> f64 + Sync),
}

/// Test configuration.
#[derive(Clone, Debug)]
pub struct Chi2Test {
    /// Name, used for the heat-map files dumped on failure.
    pub name: String,
    /// Number of samples.
    pub samples: u64,
    /// Number of cells along cos θ (φ gets twice as many). Rounded up to an even number so
    /// that the horizon z = 0 — where most BSDF pdfs are discontinuous — is a cell boundary.
    pub res: usize,
    /// Significance level α before the Šidák correction.
    pub significance: f64,
    /// Number of tests run in the same suite (Šidák correction).
    pub num_tests: u32,
    /// Seed of the counter-based generator.
    pub seed: u64,
    /// Sub-cells per cell and axis, each integrated by adaptive Simpson.
    pub quad_subdiv: usize,
    /// Breakpoints in cos θ: values of z where the pdf has a kink or a jump along a whole
    /// parallel (e.g. the nodes of a tabulated NDF when testing visible-normal sampling, whose
    /// pdf is a function of cos θm). A cell containing breakpoints is split there and each
    /// piece gets its own `quad_subdiv`² sub-cells, so Simpson's rule never straddles the kink
    /// (the adaptive refinement only detects jumps, not kinks). Empty by default.
    pub z_breaks: Vec<f64>,
}

/// Outcome of a χ² test.
#[derive(Clone, Debug)]
pub struct Chi2Result {
    /// Test statistic.
    pub statistic: f64,
    /// Degrees of freedom after pooling.
    pub dof: usize,
    /// p-value of the statistic.
    pub p_value: f64,
    /// Threshold the p-value was compared with (Šidák-corrected).
    pub threshold: f64,
    /// Integral of the pdf over the sphere (≈ probability that `sample` succeeds).
    pub pdf_integral: f64,
    /// Fraction of samples that failed.
    pub failed_fraction: f64,
    /// Number of samples that landed in cells of zero pdf, or returned non-finite directions.
    pub bad_samples: u64,
    /// Overall verdict.
    pub passed: bool,
    /// Why it failed, if it did.
    pub reason: String,
}

impl Chi2Test {
    /// A test with `samples` samples and `res` cells along cos θ; α = 0.01, one test, seed 1.
    pub fn new(name: &str, samples: u64, res: usize) -> Self {
        Chi2Test {
            name: name.to_string(),
            samples,
            res: res.max(2).next_multiple_of(2),
            significance: 0.01,
            num_tests: 1,
            seed: 1,
            quad_subdiv: 4,
            z_breaks: Vec::new(),
        }
    }

    /// Run with a two-number sampler.
    pub fn run(&self, f: &SphereFn<'_>) -> Chi2Result {
        let s = f.sample;
        self.run3(&SphereFn3 { sample: &|u, _uc| s(u), pdf: f.pdf })
    }

    fn cell_of(&self, w: Vec3) -> usize {
        let nt = self.res;
        let np = 2 * self.res;
        let z = w.z.clamp(-1.0, 1.0);
        let mut phi = w.y.atan2(w.x);
        if phi < 0.0 {
            phi += 2.0 * PI;
        }
        let it = (((z + 1.0) * 0.5 * nt as f32) as usize).min(nt - 1);
        let ip = ((phi / (2.0 * PI) * np as f32) as usize).min(np - 1);
        it * np + ip
    }

    /// Expected probability of every cell: ∫cell pdf dω in (cos θ, φ) coordinates (dω = dz dφ).
    /// Each cell is split into `quad_subdiv`² sub-cells integrated by adaptive Simpson: a
    /// sub-cell whose nodes mix zero and non-zero values or vary by more than 50 % is split
    /// again (up to 10 levels), so pdfs with jumps inside a cell (triangle edges, cone rims,
    /// lobe cut-offs) are integrated far more accurately than the Monte-Carlo noise.
    pub fn expected_probabilities(&self, pdf: &(dyn Fn(Vec3) -> f64 + Sync)) -> Vec<f64> {
        let nt = self.res;
        let np = 2 * self.res;
        let m = self.quad_subdiv.max(1);
        let dz = 2.0 / nt as f64;
        let dp = 2.0 * std::f64::consts::PI / np as f64;
        let eval = |z: f64, phi: f64| {
            let r = (1.0 - z * z).max(0.0).sqrt();
            let w = Vec3::new((r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32);
            let v = pdf(w);
            if v.is_finite() { v.max(0.0) } else { 0.0 }
        };
        (0..nt * np)
            .into_par_iter()
            .map(|c| {
                let (it, ip) = (c / np, c % np);
                // nodes are kept a hair inside the cell: pdfs are often discontinuous exactly on
                // cell boundaries (the horizon), and the cell must see its own side's value
                let eps_z = 1e-6 * dz;
                let eps_p = 1e-6 * dp;
                let z0 = -1.0 + it as f64 * dz + eps_z;
                let p0 = ip as f64 * dp + eps_p;
                let hp = (dp - 2.0 * eps_p) / m as f64;
                // pieces in z between the breakpoints inside the cell
                let z1 = z0 + dz - 2.0 * eps_z;
                let mut edges = vec![z0];
                edges.extend(self.z_breaks.iter().copied().filter(|&b| b > z0 && b < z1));
                edges.push(z1);
                edges.sort_by(|a, b| a.partial_cmp(b).unwrap());
                let mut acc = 0.0;
                for e in edges.windows(2) {
                    let hz = (e[1] - e[0]) / m as f64;
                    for a in 0..m {
                        for b in 0..m {
                            acc +=
                                adaptive_simpson(&eval, e[0] + a as f64 * hz, p0 + b as f64 * hp, hz, hp, 10);
                        }
                    }
                }
                // compensate the hair of area left out at the borders
                acc * (dz * dp) / ((dz - 2.0 * eps_z) * (dp - 2.0 * eps_p))
            })
            .collect()
    }

    /// Run with a three-number sampler.
    pub fn run3(&self, f: &SphereFn3<'_>) -> Chi2Result {
        let ncells = self.res * 2 * self.res;
        let chunk = 1u64 << 16;
        let nchunks = self.samples.div_ceil(chunk);
        let (hist, failed, nonfinite) = (0..nchunks)
            .into_par_iter()
            .map(|ci| {
                let mut rng = Rng::new(self.seed, 0xC412, ci);
                let mut h = vec![0u64; ncells];
                let (mut failed, mut bad) = (0u64, 0u64);
                let n = chunk.min(self.samples - ci * chunk);
                for _ in 0..n {
                    let u = rng.next_2d();
                    let uc = rng.next_f32();
                    match (f.sample)(u, uc) {
                        None => failed += 1,
                        Some(w) if !w.is_finite() || (w.length() - 1.0).abs() > 1e-3 => bad += 1,
                        Some(w) => h[self.cell_of(w)] += 1,
                    }
                }
                (h, failed, bad)
            })
            .reduce(
                || (vec![0u64; ncells], 0, 0),
                |(mut a, fa, ba), (b, fb, bb)| {
                    a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                    (a, fa + fb, ba + bb)
                },
            );
        let probs = self.expected_probabilities(f.pdf);
        let n = self.samples as f64;
        let pdf_integral: f64 = probs.iter().sum();
        let threshold = 1.0 - (1.0 - self.significance).powf(1.0 / self.num_tests as f64);
        let mut res = Chi2Result {
            statistic: 0.0,
            dof: 0,
            p_value: 0.0,
            threshold,
            pdf_integral,
            failed_fraction: failed as f64 / n,
            bad_samples: nonfinite,
            passed: false,
            reason: String::new(),
        };
        if nonfinite > 0 {
            res.reason = format!("{nonfinite} samples were not finite unit vectors");
            self.dump(&hist, &probs);
            return res;
        }
        let zero_hits: u64 = hist.iter().zip(&probs).filter(|(_, p)| **p <= 0.0).map(|(h, _)| *h).sum();
        if zero_hits > 0 {
            res.bad_samples = zero_hits;
            res.reason = format!("{zero_hits} samples fell in cells where the pdf is zero");
            self.dump(&hist, &probs);
            return res;
        }
        // pool small cells (in increasing order of expected count)
        let mut idx: Vec<usize> = (0..ncells).collect();
        idx.sort_by(|&a, &b| probs[a].partial_cmp(&probs[b]).unwrap());
        let (mut pool_e, mut pool_o) = (0.0f64, 0.0f64);
        let mut stat = 0.0;
        let mut cells = 0usize;
        for &i in &idx {
            let e = probs[i] * n;
            let o = hist[i] as f64;
            if e < 5.0 {
                pool_e += e;
                pool_o += o;
                if pool_e >= 5.0 {
                    stat += (pool_o - pool_e).powi(2) / pool_e;
                    cells += 1;
                    pool_e = 0.0;
                    pool_o = 0.0;
                }
            } else {
                stat += (o - e).powi(2) / e;
                cells += 1;
            }
        }
        if pool_e > 0.0 {
            stat += (pool_o - pool_e).powi(2) / pool_e;
            cells += 1;
        } else if pool_o > 0.0 {
            res.reason = format!("{pool_o} samples in pooled cells with zero expectation");
            self.dump(&hist, &probs);
            return res;
        }
        // account for failed samples as one more "cell" when the pdf does not integrate to 1
        let e_fail = (1.0 - pdf_integral).max(0.0) * n;
        if e_fail >= 5.0 {
            stat += (failed as f64 - e_fail).powi(2) / e_fail;
            cells += 1;
        }
        res.statistic = stat;
        res.dof = cells.saturating_sub(1).max(1);
        let dist = ChiSquared::new(res.dof as f64).expect("dof > 0");
        res.p_value = 1.0 - dist.cdf(stat);
        res.passed = res.p_value > threshold;
        if !res.passed {
            res.reason =
                format!("χ² = {stat:.1} with {} dof: p = {:.3e} < {threshold:.3e}", res.dof, res.p_value);
            self.dump(&hist, &probs);
        }
        res
    }

    /// Write observed / expected heat maps as PGM files into the temp directory.
    fn dump(&self, hist: &[u64], probs: &[f64]) {
        let np = 2 * self.res;
        let nt = self.res;
        let n = self.samples as f64;
        let exp: Vec<f64> = probs.iter().map(|p| p * n).collect();
        let obs: Vec<f64> = hist.iter().map(|&h| h as f64).collect();
        let max = exp.iter().chain(&obs).cloned().fold(1.0, f64::max);
        for (tag, data) in [("observed", &obs), ("expected", &exp)] {
            let mut s = format!("P2\n{np} {nt}\n255\n");
            for it in (0..nt).rev() {
                for ip in 0..np {
                    s += &format!("{} ", (data[it * np + ip] / max * 255.0).round() as u32);
                }
                s.push('\n');
            }
            let safe: String = self.name.chars().map(|c| if c.is_alphanumeric() { c } else { '_' }).collect();
            let path = std::env::temp_dir().join(format!("opal_chi2_{safe}_{tag}.pgm"));
            let _ = std::fs::write(&path, s);
            eprintln!("chi2 {}: wrote {}", self.name, path.display());
        }
    }
}

/// 3×3-node Simpson rule on a rectangle, refined recursively where the integrand jumps.
fn adaptive_simpson(f: &impl Fn(f64, f64) -> f64, x0: f64, y0: f64, hx: f64, hy: f64, depth: u32) -> f64 {
    let mut v = [0.0f64; 9];
    for i in 0..3 {
        for j in 0..3 {
            v[i * 3 + j] = f(x0 + 0.5 * hx * i as f64, y0 + 0.5 * hy * j as f64);
        }
    }
    let (mut lo, mut hi) = (f64::MAX, 0.0f64);
    for &x in &v {
        lo = lo.min(x);
        hi = hi.max(x);
    }
    // hi·area bounds the sub-cell's integral: refining where it is negligible (< 1e-10, far
    // below 1/N for any sample count used) only costs time — exponential tails (Beckmann) would
    // otherwise be refined to the maximum depth everywhere
    let rough = ((hi > 0.0 && lo == 0.0) || hi > 1.5 * lo) && hi * hx * hy > 1e-10;
    if depth > 0 && rough {
        let (hx2, hy2) = (0.5 * hx, 0.5 * hy);
        return adaptive_simpson(f, x0, y0, hx2, hy2, depth - 1)
            + adaptive_simpson(f, x0 + hx2, y0, hx2, hy2, depth - 1)
            + adaptive_simpson(f, x0, y0 + hy2, hx2, hy2, depth - 1)
            + adaptive_simpson(f, x0 + hx2, y0 + hy2, hx2, hy2, depth - 1);
    }
    const W: [f64; 3] = [1.0, 4.0, 1.0];
    let mut acc = 0.0;
    for i in 0..3 {
        for j in 0..3 {
            acc += W[i] * W[j] * v[i * 3 + j];
        }
    }
    acc * hx * hy / 36.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::*;

    #[test]
    fn detects_a_wrong_pdf() {
        // cosine sampling checked against the uniform-hemisphere pdf must fail
        let t = Chi2Test::new("wrong_pdf", 200_000, 10);
        let r = t.run(&SphereFn {
            sample: &|u| Some(square_to_cosine_hemisphere(u)),
            pdf: &|w| square_to_uniform_hemisphere_pdf(w) as f64,
        });
        assert!(!r.passed, "{r:?}");
    }

    #[test]
    fn accounts_for_failed_samples() {
        // a sampler that fails half of the time, with a pdf integrating to 1/2
        let t = Chi2Test::new("half", 400_000, 10);
        let r = t.run3(&SphereFn3 {
            sample: &|u, uc| (uc < 0.5).then(|| square_to_uniform_sphere(u)),
            pdf: &|_| 0.5 / (4.0 * std::f64::consts::PI),
        });
        assert!(r.passed, "{r:?}");
        assert!((r.pdf_integral - 0.5).abs() < 1e-6);
        // the same sampler claiming a full pdf must fail
        let r = t.run3(&SphereFn3 {
            sample: &|u, uc| (uc < 0.5).then(|| square_to_uniform_sphere(u)),
            pdf: &|_| 1.0 / (4.0 * std::f64::consts::PI),
        });
        assert!(!r.passed, "{r:?}");
    }
}
