//! Building a tabulated BSDF: [`TabulatedBsdf::build`] integrates a source BSDF over every
//! cell (midpoint sub-samples), [`TabulatedBsdf::build_from_sampler`] histograms a sampler's
//! exits into the cells. Both end in the table constructor of `mod.rs` (validation, CDFs).
//! Covered by the tests in `tabulated/tests.rs`.

use super::grid::{dwm_dwi, half_vector, validate_grid, wi_from_wm};
use super::{TableGrid, TabulatedBsdf};
use crate::bsdf::{Bxdf, TransportMode};
use crate::error::{Error, Result};
use crate::math::Vec3;
use rayon::prelude::*;

impl TabulatedBsdf {
    /// Builds the table of `src` (evaluated in importance mode, i.e. the power BSDF) for a
    /// relative index `eta`, integrating each cell with `sub × sub` sub-samples. `source` is a
    /// free description kept in the file header.
    pub fn build<B: Bxdf + Sync>(
        src: &B,
        eta: f32,
        grid: TableGrid,
        sub: usize,
        source: &str,
    ) -> Result<Self> {
        validate_grid(&grid, eta).map_err(|(f, why)| Error::invalid(format!("table grid `{f}`"), why))?;
        let sub = sub.max(1);
        let cpr = grid.cells_per_row();
        let mut q = vec![0.0f32; grid.len()];
        q.par_chunks_mut(cpr).enumerate().for_each(|(sr, row)| {
            let (side, r) = (sr / grid.n_theta_o, sr % grid.n_theta_o);
            let th = grid.theta_o(r);
            let wo = Vec3::new(th.sin(), 0.0, if side == 0 { th.cos() } else { -th.cos() });
            for lobe in 0..2 {
                for iu in 0..grid.n_u {
                    for iv in 0..grid.n_v {
                        let mut acc = 0.0f64;
                        for a in 0..sub {
                            let u = (iu as f32 + (a as f32 + 0.5) / sub as f32) / grid.n_u as f32;
                            let jac = grid.jac(u);
                            for b in 0..sub {
                                let v = (iv as f32 + (b as f32 + 0.5) / sub as f32) / grid.n_v as f32;
                                let wm = grid.wm_of(wo, u, v, 1.0);
                                let Some(wi) = wi_from_wm(wo, wm, lobe == 1, eta) else { continue };
                                let Some((wm2, etap, tr)) = half_vector(wo, wi, eta) else { continue };
                                let f = src.eval(wo, wi, TransportMode::Importance)[0];
                                let val = f * wi.z.abs() / dwm_dwi(wo, wi, wm2, etap, tr) * jac;
                                if val.is_finite() && val > 0.0 {
                                    acc += val as f64;
                                }
                            }
                        }
                        row[(lobe * grid.n_u + iu) * grid.n_v + iv] = (acc / (sub * sub) as f64) as f32;
                    }
                }
            }
        });
        Self::from_data(eta, grid, q, source.to_string())
            .map_err(|(f, why)| Error::invalid(format!("built table `{f}`"), why))
    }

    /// Builds the table of a model known only through a sampler (e.g. the multiple-scattering
    /// random walk, [`crate::bsdf::rough_dielectric_ms::RoughDielectricMs`]): for every side
    /// and row, `photons` directions are drawn with `sample(wo, rng)` → (wi, power weight) and
    /// histogrammed into the cells of their half vectors (seeded per row: deterministic for any
    /// thread count). Exits that no micro-normal connects to `wo` (possible for multiply
    /// scattered light, e.g. a reflection towards the back of the facets) cannot be represented
    /// and are dropped; the returned fraction (power dropped / power scattered, over all rows)
    /// says how much. The table carries the Monte-Carlo noise of the histogram.
    pub fn build_from_sampler<F>(
        sample: F,
        eta: f32,
        grid: TableGrid,
        photons: usize,
        seed: u64,
        source: &str,
    ) -> Result<(Self, f64)>
    where
        F: Fn(Vec3, &mut crate::sampling::Rng) -> Option<(Vec3, f32)> + Sync,
    {
        validate_grid(&grid, eta).map_err(|(f, why)| Error::invalid(format!("table grid `{f}`"), why))?;
        if photons == 0 {
            return Err(Error::invalid("photons", "must be > 0"));
        }
        let cpr = grid.cells_per_row();
        let mut q = vec![0.0f32; grid.len()];
        let scale = (grid.n_u * grid.n_v) as f64 / photons as f64;
        let dropped: Vec<(f64, f64)> = q
            .par_chunks_mut(cpr)
            .enumerate()
            .map(|(sr, row)| {
                let (side, r) = (sr / grid.n_theta_o, sr % grid.n_theta_o);
                let th = grid.theta_o(r);
                let wo = Vec3::new(th.sin(), 0.0, if side == 0 { th.cos() } else { -th.cos() });
                let mut rng = crate::sampling::Rng::new(seed, 0x7AB, sr as u64);
                let mut acc = vec![0.0f64; cpr];
                let (mut lost, mut total) = (0.0f64, 0.0f64);
                for _ in 0..photons {
                    let Some((wi, w)) = sample(wo, &mut rng) else { continue };
                    if !(w.is_finite() && w > 0.0) {
                        continue;
                    }
                    total += w as f64;
                    let Some((wm, _, transmit)) = half_vector(wo, wi, eta) else {
                        lost += w as f64;
                        continue;
                    };
                    let (u, v) = grid.uv_of(wo, wm);
                    let (iu, iv) = grid.cell(u, v);
                    acc[(transmit as usize * grid.n_u + iu) * grid.n_v + iv] += w as f64;
                }
                for (d, a) in row.iter_mut().zip(&acc) {
                    *d = (a * scale) as f32;
                }
                (lost, total)
            })
            .collect();
        let (lost, total) = dropped.iter().fold((0.0, 0.0), |(a, b), (l, t)| (a + l, b + t));
        let t = Self::from_data(eta, grid, q, source.to_string())
            .map_err(|(f, why)| Error::invalid(format!("built table `{f}`"), why))?;
        Ok((t, if total > 0.0 { lost / total } else { 0.0 }))
    }
}
