//! Deterministic quadrature over directions: Gauss–Legendre nodes in cos θ (or θ) times a
//! uniform (trapezoidal, periodic) rule in φ. Exact for polynomials in cos θ up to degree 2n−1
//! and spectrally accurate for smooth periodic functions of φ.

use crate::math::DVec3;

/// Gauss–Legendre nodes and weights on [-1, 1] (Newton iteration on P_n).
pub fn gauss_legendre(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut x = vec![0.0; n];
    let mut w = vec![0.0; n];
    for i in 0..n.div_ceil(2) {
        let mut z = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
        let mut dp = 0.0;
        for _ in 0..100 {
            let (mut p0, mut p1) = (1.0, 0.0);
            for j in 0..n {
                let p2 = p1;
                p1 = p0;
                p0 = ((2 * j + 1) as f64 * z * p1 - j as f64 * p2) / (j + 1) as f64;
            }
            dp = n as f64 * (z * p0 - p1) / (z * z - 1.0);
            let dz = p0 / dp;
            z -= dz;
            if dz.abs() < 1e-15 {
                break;
            }
        }
        x[i] = -z;
        x[n - 1 - i] = z;
        w[i] = 2.0 / ((1.0 - z * z) * dp * dp);
        w[n - 1 - i] = w[i];
    }
    (x, w)
}

/// ∫ over the hemisphere z > 0 of `f(ω)` dω with `n_theta` Gauss nodes in cos θ ∈ (0, 1) and
/// `n_phi` uniform nodes in φ.
pub fn integrate_hemisphere(n_theta: usize, n_phi: usize, f: impl Fn(DVec3) -> f64) -> f64 {
    integrate_z_range(0.0, 1.0, n_theta, n_phi, f)
}

/// ∫ over the sphere of `f(ω)` dω.
pub fn integrate_sphere(n_theta: usize, n_phi: usize, f: impl Fn(DVec3) -> f64) -> f64 {
    integrate_z_range(-1.0, 1.0, n_theta, n_phi, f)
}

/// ∫ over the band `z0 < cos θ < z1` of `f(ω)` dω.
pub fn integrate_z_range(z0: f64, z1: f64, n_theta: usize, n_phi: usize, f: impl Fn(DVec3) -> f64) -> f64 {
    let (x, w) = gauss_legendre(n_theta);
    let dphi = 2.0 * std::f64::consts::PI / n_phi as f64;
    let mut acc = 0.0;
    for (xi, wi) in x.iter().zip(&w) {
        let z = z0 + (xi + 1.0) * 0.5 * (z1 - z0);
        let r = (1.0 - z * z).max(0.0).sqrt();
        let mut s = 0.0;
        for k in 0..n_phi {
            let phi = (k as f64 + 0.5) * dphi;
            s += f(DVec3::new(r * phi.cos(), r * phi.sin(), z));
        }
        acc += wi * 0.5 * (z1 - z0) * s * dphi;
    }
    acc
}

#[cfg(test)]
mod tests {
    use super::*;
    #[test]
    fn integrates_known_functions() {
        let pi = std::f64::consts::PI;
        assert!((integrate_hemisphere(16, 32, |w| w.z) - pi).abs() < 1e-12);
        assert!((integrate_sphere(16, 32, |_| 1.0) - 4.0 * pi).abs() < 1e-12);
        assert!((integrate_sphere(16, 32, |w| w.x * w.x) - 4.0 * pi / 3.0).abs() < 1e-12);
        let (x, w) = gauss_legendre(7);
        assert!((w.iter().sum::<f64>() - 2.0).abs() < 1e-13);
        assert!(x.windows(2).all(|p| p[0] < p[1]));
    }
}
