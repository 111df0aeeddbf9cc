//! Unidirectional path tracer with next-event estimation and multiple importance sampling
//! (power heuristic), Russian roulette, and Mitsuba's `max_depth` semantics: depth counts path
//! segments from the camera (1 = emitters seen directly, 2 = direct lighting, −1 = unbounded).
//! Russian roulette starts at `rr_depth` with survival probability min(max(β)·η², 0.95).
//!
//! Specular (delta) BSDFs such as [`crate::bsdf::SmoothDielectric`]: `eval`/`pdf` are zero, so
//! next-event estimation adds nothing at such vertices, and an emitter reached by a delta
//! sample gets MIS weight 1. Refraction: the radiance BTDFs carry 1/η'² (so the radiance inside
//! a dielectric is η² times the outside one and returns on exit); the Russian-roulette
//! survival uses β·η² (the accumulated `eta_scale`) so it is not biased by those factors.
//! Interfaces are surfaces: there are no participating media (a dielectric object is clear).
//!
//! Determinism: pixel (x, y) of camera c draws all its numbers from
//! `Rng::new(seed, c, y·W + x)`, rows are rendered in parallel and written in place, so the
//! image is identical for any thread count.
//!
//! Tests: `tests/furnace.rs` (furnace: a closed Lambertian room of albedo ρ and radiance Le has
//! radiance Le/(1−ρ) everywhere, also with lossless glass objects inside; agreement with Mitsuba 3 on the reference Cornell box by
//! z-tests on 16×16 blocks; thread-count independence).

use super::{mis_power, spawn_ray, spawn_ray_to};
use crate::bsdf::{Bxdf, TransportMode};
use crate::geometry::Ray;
use crate::image::Image;
use crate::math::Vec2;
use crate::sampling::Rng;
use crate::scene::Scene;
use crate::spectrum::Spectrum;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};

/// Path-tracer settings.
#[derive(Clone, Copy, Debug)]
pub struct PathSettings {
    /// Samples per pixel.
    pub spp: u32,
    /// Maximum depth (Mitsuba meaning), −1 = unbounded.
    pub max_depth: i32,
    /// Depth from which Russian roulette is used.
    pub rr_depth: i32,
    /// Do not show emitters seen directly by the camera.
    pub hide_emitters: bool,
    /// Seed.
    pub seed: u64,
}

impl Default for PathSettings {
    fn default() -> Self {
        PathSettings { spp: 64, max_depth: -1, rr_depth: 5, hide_emitters: false, seed: 0 }
    }
}

/// A rendered image with its per-pixel standard error.
#[derive(Clone, Debug)]
pub struct RenderOutput {
    /// Mean radiance per pixel.
    pub image: Image,
    /// Standard error of each pixel's mean (from the sample variance).
    pub stderr: Image,
    /// Camera samples whose radiance was NaN or infinite (dropped; should be 0).
    pub nonfinite: u64,
    /// Camera samples traced.
    pub samples: u64,
}

/// Radiance arriving along `ray` (one path sample).
pub fn li(scene: &Scene, mut ray: Ray, rng: &mut Rng, s: &PathSettings) -> Spectrum {
    let mode = TransportMode::Radiance;
    let mut l = Spectrum::ZERO;
    let mut beta = Spectrum::ONE;
    let mut depth = 0i32;
    let mut eta_scale = 1.0f32;
    // previous scattering vertex for MIS of emitter hits: (point, bsdf pdf, was delta)
    let mut prev: Option<(crate::math::Vec3, f32, bool)> = None;
    let sampler = scene.light_sampler();
    while let Some(si) = scene.intersect(&ray) {
        depth += 1;
        let wo = -ray.d;
        if let Some((li_idx, light)) = scene.light_at(si.prim) {
            let le = light.le(wo);
            let hidden = depth == 1 && s.hide_emitters;
            if !le.is_black() && !hidden {
                let w = match prev {
                    None | Some((_, _, true)) => 1.0,
                    Some((pp, pdf_bsdf, false)) => {
                        let pmf = sampler.map_or(0.0, |ls| ls.pmf(li_idx));
                        mis_power(pdf_bsdf, pmf * light.pdf_li(pp, si.p))
                    }
                };
                l += beta * le * w;
            }
        }
        if s.max_depth >= 0 && depth >= s.max_depth {
            break;
        }
        let (frame, bsdf) = scene.bsdf(&si, wo);
        let wo_l = frame.to_local(wo);
        // next-event estimation
        if let Some(ls) = sampler {
            let (idx, pmf, _) = ls.sample(rng.next_f32());
            let u = rng.next_2d();
            if let Some(smp) = scene.lights[idx].sample_li(si.p, u) {
                if smp.pdf > 0.0 && !smp.li.is_black() {
                    let wi_l = frame.to_local(smp.wi);
                    // geometric-normal side check avoids light leaks through the surface
                    let f = bsdf.eval(wo_l, wi_l, mode) * wi_l.z.abs();
                    if !f.is_black() {
                        let shadow = spawn_ray_to(si.p, si.ng, smp.p, smp.n);
                        if !scene.occluded(&shadow) {
                            let pdf_light = pmf * smp.pdf;
                            let w = if smp.is_delta {
                                1.0
                            } else {
                                mis_power(pdf_light, bsdf.pdf(wo_l, wi_l, mode))
                            };
                            l += beta * f * smp.li * (w / pdf_light);
                        }
                    }
                }
            }
        }
        // BSDF sampling
        let uc = rng.next_f32();
        let u = rng.next_2d();
        let Some(bs) = bsdf.sample(wo_l, uc, u, mode) else { break };
        let weight = bs.weight();
        if weight.is_black() {
            break;
        }
        beta *= weight;
        eta_scale *= bs.eta * bs.eta;
        let wi = frame.to_world(bs.wi);
        prev = Some((si.p, bs.pdf, bs.flags.specular));
        ray = spawn_ray(si.p, si.ng, wi);
        if s.rr_depth >= 0 && depth >= s.rr_depth {
            let q = (beta.max_component() * eta_scale).min(0.95);
            if rng.next_f32() >= q {
                break;
            }
            beta /= q;
        }
    }
    l
}

/// Renders camera `cam` of the scene. `on_row` is called after each finished row (progress).
pub fn render(scene: &Scene, cam: usize, s: &PathSettings, on_row: &(dyn Fn() + Sync)) -> RenderOutput {
    let camera = &scene.cameras[cam];
    let (w, h) = (camera.width, camera.height);
    let nonfinite = AtomicU64::new(0);
    let rows: Vec<(Vec<Spectrum>, Vec<Spectrum>)> = (0..h)
        .into_par_iter()
        .map(|y| {
            let mut mean_row = Vec::with_capacity(w);
            let mut err_row = Vec::with_capacity(w);
            let mut bad = 0u64;
            for x in 0..w {
                let mut rng = Rng::new(s.seed, cam as u64, (y * w + x) as u64);
                let mut sum = [0.0f64; 3];
                let mut sum2 = [0.0f64; 3];
                let mut n = 0u32;
                for _ in 0..s.spp {
                    let p = Vec2::new(x as f32 + rng.next_f32(), y as f32 + rng.next_f32());
                    let ray = camera.generate_ray(p);
                    let v = li(scene, ray, &mut rng, s);
                    n += 1;
                    if !v.is_finite() {
                        bad += 1;
                        continue;
                    }
                    for c in 0..3 {
                        let x = v[c] as f64;
                        sum[c] += x;
                        sum2[c] += x * x;
                    }
                }
                let nf = n.max(1) as f64;
                let mut mean = Spectrum::ZERO;
                let mut err = Spectrum::ZERO;
                for c in 0..3 {
                    let m = sum[c] / nf;
                    let var = if n > 1 { ((sum2[c] - nf * m * m) / (nf - 1.0)).max(0.0) } else { 0.0 };
                    mean[c] = m as f32;
                    err[c] = (var / nf).sqrt() as f32;
                }
                mean_row.push(mean);
                err_row.push(err);
            }
            nonfinite.fetch_add(bad, Ordering::Relaxed);
            on_row();
            (mean_row, err_row)
        })
        .collect();
    let mut image = Image::new(w, h);
    let mut stderr = Image::new(w, h);
    for (y, (m, e)) in rows.into_iter().enumerate() {
        image.data[y * w..(y + 1) * w].copy_from_slice(&m);
        stderr.data[y * w..(y + 1) * w].copy_from_slice(&e);
    }
    RenderOutput { image, stderr, nonfinite: nonfinite.into_inner(), samples: (w * h) as u64 * s.spp as u64 }
}
