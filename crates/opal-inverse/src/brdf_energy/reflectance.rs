//! Directional–hemispherical reflectance: deterministic quadrature around the mirror direction
//! (see the module doc of `brdf_energy`), the Monte Carlo cross-check with the model's own
//! sampling, and the paper's one-dimensional pow16 integral (the method page's reference).
//!
//! Tests: `tests.rs` (quadrature on known cases, MC vs quadrature, the method page table).

use super::scalar;
use opal::bsdf::{Bxdf, TransportMode};
use opal::math::{DVec3, Vec3};
use opal::sampling::Rng;
use opal::validate::quadrature::gauss_legendre;
use rayon::prelude::*;
use std::f64::consts::PI;

/// Quadrature resolution of [`reflectance`].
#[derive(Clone, Copy, Debug)]
pub struct Quadrature {
    /// Gauss–Legendre nodes per α panel.
    pub nodes_alpha: usize,
    /// Gauss–Legendre nodes in φ over the visible half range.
    pub nodes_phi: usize,
    /// Width of the first α panel (radians); panels double from there.
    pub min_width: f64,
}

impl Default for Quadrature {
    fn default() -> Self {
        Quadrature { nodes_alpha: 16, nodes_phi: 40, min_width: 1e-3 }
    }
}

/// Directional–hemispherical reflectance `R(θi) = ∫ f(wo, wi) cos θ_wi dω_wi` with
/// `wo = (sin θi, 0, cos θi)`, by deterministic quadrature (see the module doc). The largest
/// colour channel is used.
pub fn reflectance(b: &impl Bxdf, theta_i: f64, q: &Quadrature) -> f64 {
    let (st, ct) = theta_i.sin_cos();
    let wo = Vec3::new(st as f32, 0.0, ct as f32);
    let r = DVec3::new(-st, 0.0, ct);
    let t1 = DVec3::new(ct, 0.0, st);
    let t2 = DVec3::Y;
    let alpha_end = (PI / 2.0 + theta_i).min(PI);
    // panel edges
    let mut edges = vec![0.0];
    let mut a = q.min_width;
    while a < alpha_end {
        edges.push(a);
        a *= 2.0;
    }
    for k in [PI / 2.0 - theta_i, PI / 2.0] {
        if k > 1e-9 && k < alpha_end - 1e-9 {
            edges.push(k);
        }
    }
    edges.push(alpha_end);
    edges.sort_by(|x, y| x.partial_cmp(y).unwrap());
    edges.dedup_by(|x, y| (*x - *y).abs() < 1e-12);
    let (xa, wa) = gauss_legendre(q.nodes_alpha);
    let (xp, wp) = gauss_legendre(q.nodes_phi);
    let mut total = 0.0;
    for e in edges.windows(2) {
        let (a0, a1) = (e[0], e[1]);
        let half = 0.5 * (a1 - a0);
        let mut panel = 0.0;
        for (xi, wi) in xa.iter().zip(&wa) {
            let alpha = a0 + (xi + 1.0) * half;
            let (sa, ca) = alpha.sin_cos();
            // d.z = ca·ct + sa·st·cos φ > 0  ⇔  cos φ > −ca·ct/(sa·st)
            let phi_max = if st * sa <= 0.0 {
                if ca * ct > 0.0 { PI } else { 0.0 }
            } else {
                let c = -ca * ct / (sa * st);
                if c <= -1.0 {
                    PI
                } else if c >= 1.0 {
                    0.0
                } else {
                    c.acos()
                }
            };
            if phi_max <= 0.0 {
                continue;
            }
            let hp = 0.5 * phi_max;
            let mut ring = 0.0;
            for (xj, wj) in xp.iter().zip(&wp) {
                let phi = (xj + 1.0) * hp;
                let (sp, cp) = phi.sin_cos();
                let d = r * ca + (t1 * cp + t2 * sp) * sa;
                if d.z <= 0.0 {
                    continue;
                }
                let f = scalar(b.eval(wo, d.as_vec3().normalize(), TransportMode::Radiance));
                ring += wj * f * d.z;
            }
            // ×2: the φ < 0 half by symmetry
            panel += wi * sa * 2.0 * ring * hp;
        }
        total += panel * half;
    }
    total
}

/// Monte Carlo estimate of [`reflectance`] with the model's own sampling: the mean of the
/// sample weights `f cos θ / pdf` (failed samples count 0). Returns (mean, standard error).
/// Deterministic: chunks of 4096 samples, chunk `k` uses `Rng::new(seed, 0xB8DF, k)`.
pub fn reflectance_mc(b: &(impl Bxdf + Sync), theta_i: f64, samples: u64, seed: u64) -> (f64, f64) {
    let (st, ct) = theta_i.sin_cos();
    let wo = Vec3::new(st as f32, 0.0, ct as f32);
    let chunk = 4096u64;
    let nchunks = samples.div_ceil(chunk);
    let (s, s2) = (0..nchunks)
        .into_par_iter()
        .map(|k| {
            let mut rng = Rng::new(seed, 0xB8DF, k);
            let n = chunk.min(samples - k * chunk);
            let (mut s, mut s2) = (0.0f64, 0.0f64);
            for _ in 0..n {
                let uc = rng.next_f32();
                let u = rng.next_2d();
                let w =
                    b.sample(wo, uc, u, TransportMode::Radiance).map(|x| scalar(x.weight())).unwrap_or(0.0);
                s += w;
                s2 += w * w;
            }
            (s, s2)
        })
        .collect::<Vec<_>>()
        .into_iter()
        .fold((0.0, 0.0), |a, x| (a.0 + x.0, a.1 + x.1));
    let n = samples as f64;
    let mean = s / n;
    let var = (s2 / n - mean * mean).max(0.0);
    (mean, (var / n).sqrt())
}

/// The paper's one-dimensional reflectance of the pow16 lobe at normal incidence,
/// `R(n) = 2π ∫_0^{π/2} L(cos(θ/2)) cos θ sin θ dθ`, by a composite Simpson rule in θ over the
/// lobe's support (the reference the method page's table was computed with, independent of the
/// hemisphere quadrature and of the f32 model code).
pub fn pow16_paper_integral(n: f64, intervals: usize) -> f64 {
    let lobe = |t: f64| {
        let b = n / 16.0 * (t - 1.0) + 1.0;
        if b > 0.0 { b.powi(16) } else { 0.0 }
    };
    // support: cos(θ/2) ≥ 1 − 16/n
    let zero = 1.0 - 16.0 / n;
    let theta_end = if zero > 0.0 { (2.0 * zero.acos()).min(PI / 2.0) } else { PI / 2.0 };
    let m = intervals.max(2) & !1;
    let h = theta_end / m as f64;
    let mut s = 0.0;
    for i in 0..=m {
        let t = i as f64 * h;
        let w = if i == 0 || i == m {
            1.0
        } else if i % 2 == 1 {
            4.0
        } else {
            2.0
        };
        s += w * lobe((t / 2.0).cos()) * t.cos() * t.sin();
    }
    2.0 * PI * s * h / 3.0
}
