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
//! `Rng::new(seed, c, y·W + x)`, its samples one after the other; rows are rendered in parallel
//! and written in place, so the image is identical for any thread count — and for any number of
//! processes ([`render_split`]: row `y` on rank `y mod size`, rows exchanged whole).
//!
//! Environment lights (`constant`, `envmap`): a ray that leaves the scene gets their radiance
//! (`escaped`), MIS-weighted against their next-event sampling exactly like an emitting triangle
//! hit; directional and spot lights are deltas reached only by next-event estimation, with
//! weight 1.
//!
//! Structure: one path vertex is `vertex` (emission found, next-event sample, BSDF sample,
//! Russian roulette); it returns the shadow ray and its contribution instead of tracing it, so
//! the caller may batch shadow rays. [`li`] traces one path with single rays. [`render`] picks,
//! per scene, how a row is traced (`RowPlan`; every plan gives the same image bit for bit):
//! * all-diffuse scenes lit by emitting triangles (the Cornell box, scanned objects with
//!   textures), whatever their size: `wavefront::render_row` — eight *pixels* in the eight
//!   lanes of a packet, each lane running its pixel's samples in order with the pixel's own
//!   generator; the lanes' rays go through [`Accel::intersect8`] together (packet kernel on tiny
//!   scenes, eight interleaved BVH traversals otherwise), then their shadow rays through
//!   [`Accel::occluded8`], and the eight vertices are shaded at once by the lane-parallel kernel
//!   of `wide` (the scalar vertex's IEEE operations in its order: the same bits);
//! * other tiny scenes: the same wavefront with `vertex` lane by lane;
//! * other BVH scenes: `render_row_scalar`, a pixel at a time with [`li`] (the row wavefront with
//!   the scalar vertex measured slower there: 4.53–4.73 vs 4.16–4.36 CPU-s on the scanned-object
//!   room, when it still traced single rays).
//!
//! Tests: `tests.rs` (every wavefront plan against the scalar rows, bit for bit, on the Cornell
//! box and on a textured mesh behind the BVH); `tests/furnace.rs` (furnace: a closed Lambertian room of albedo ρ and radiance Le has
//! radiance Le/(1−ρ) everywhere, also with lossless glass objects inside; agreement with Mitsuba 3 on the reference Cornell box by
//! z-tests on 16×16 blocks; thread-count independence), `opal-cli/tests/render_cli.rs`.

use super::{mis_power, spawn_ray};
use crate::accel::Accel;
use crate::bsdf::{Bxdf, TransportMode};
use crate::geometry::Ray;
use crate::image::Image;
use crate::math::{Vec2, Vec3};
use crate::sampling::Rng;
use crate::scene::{Scene, SurfaceInteraction};
use crate::spectrum::Spectrum;
use rayon::prelude::*;

mod wavefront;
mod wide;
mod wide_row;
mod wide_tables;

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

/// State of one path sample between two vertices.
#[derive(Clone, Copy, Debug)]
struct PathState {
    /// Radiance gathered so far.
    l: Spectrum,
    /// Throughput.
    beta: Spectrum,
    /// Vertices reached (Mitsuba depth).
    depth: i32,
    /// Accumulated η² of refractions (for the Russian roulette).
    eta_scale: f32,
    /// Previous scattering vertex for MIS of emitter hits: (point, bsdf pdf, was delta).
    prev: Option<(Vec3, f32, bool)>,
}

impl PathState {
    const START: PathState =
        PathState { l: Spectrum::ZERO, beta: Spectrum::ONE, depth: 0, eta_scale: 1.0, prev: None };
}

/// A next-event-estimation shadow ray and the radiance it adds if unoccluded.
#[derive(Clone, Copy, Debug)]
struct Shadow {
    ray: Ray,
    contrib: Spectrum,
}

/// The first part of a path vertex at the hit `si` of `ray`: counts the vertex (returns the
/// new depth) and adds the emission found there, MIS-weighted against the previous vertex's
/// BSDF sample. Shared by [`vertex`] and the wide wavefront (`wavefront`).
#[inline]
fn emission(scene: &Scene, s: &PathSettings, st: &mut PathState, ray: &Ray, si: &SurfaceInteraction) -> i32 {
    st.depth += 1;
    let depth = st.depth;
    if let Some((li_idx, light)) = scene.light_at(si.prim) {
        let wo = -ray.d;
        let le = light.le(wo);
        let hidden = depth == 1 && s.hide_emitters;
        if !le.is_black() && !hidden {
            let w = match st.prev {
                None | Some((_, _, true)) => 1.0,
                Some((pp, pdf_bsdf, false)) => {
                    let pmf = scene.light_sampler().map_or(0.0, |ls| ls.pmf(li_idx));
                    mis_power(pdf_bsdf, pmf * light.pdf_li(pp, si.p))
                }
            };
            st.l += st.beta * le * w;
        }
    }
    depth
}

/// A ray that left the scene: adds the radiance of the environment lights along it,
/// MIS-weighted against their next-event sampling like an emitter hit (weight 1 for camera rays
/// and after delta scattering; nothing for camera rays with `hide_emitters`). The escape counts
/// as the next vertex for the depth limit, which [`vertex`] already enforced before casting the
/// ray. Shared by [`li`] and the wavefront (`wavefront`).
#[inline]
fn escaped(scene: &Scene, s: &PathSettings, st: &mut PathState, ray: &Ray) {
    if scene.env_lights().is_empty() || (st.depth == 0 && s.hide_emitters) {
        return;
    }
    for &i in scene.env_lights() {
        let light = &scene.lights[i];
        let le = light.le_escaped(ray.d);
        if le.is_black() {
            continue;
        }
        let w = match st.prev {
            None | Some((_, _, true)) => 1.0,
            Some((_, pdf_bsdf, false)) => {
                let pmf = scene.light_sampler().map_or(0.0, |ls| ls.pmf(i));
                mis_power(pdf_bsdf, pmf * light.pdf_escaped(ray.d))
            }
        };
        st.l += st.beta * le * w;
    }
}

/// One path vertex at the hit `si` of `ray`: adds the emission found there, then (unless the
/// depth limit ends the path) draws the next-event sample and the BSDF sample. Returns the
/// shadow ray whose `contrib` the caller adds to `st.l` if it is unoccluded (before the next
/// vertex), and the next ray (`None`: the path ends). Random numbers are drawn in the order of
/// the original single loop, so the result does not depend on when the shadow ray is traced.
#[inline]
fn vertex(
    scene: &Scene,
    s: &PathSettings,
    st: &mut PathState,
    ray: &Ray,
    si: &SurfaceInteraction,
    rng: &mut Rng,
) -> (Option<Shadow>, Option<Ray>) {
    let mode = TransportMode::Radiance;
    let sampler = scene.light_sampler();
    let depth = emission(scene, s, st, ray, si);
    let wo = -ray.d;
    if s.max_depth >= 0 && depth >= s.max_depth {
        return (None, None);
    }
    let (frame, bsdf) = scene.bsdf(si, wo);
    let wo_l = frame.to_local(wo);
    // next-event estimation
    let mut shadow = None;
    if let Some(ls) = sampler {
        let (idx, pmf, _) = ls.sample(rng.next_f32());
        let u = rng.next_2d();
        if let Some(smp) = scene.lights[idx].sample_li(si.p, u)
            && smp.pdf > 0.0
            && !smp.li.is_black()
        {
            let wi_l = frame.to_local(smp.wi);
            // geometric-normal side check avoids light leaks through the surface
            let f = bsdf.eval(wo_l, wi_l, mode) * wi_l.z.abs();
            if !f.is_black() {
                let pdf_light = pmf * smp.pdf;
                let w = if smp.is_delta { 1.0 } else { mis_power(pdf_light, bsdf.pdf(wo_l, wi_l, mode)) };
                shadow = Some(Shadow {
                    ray: smp.shadow_ray(si.p, si.ng),
                    contrib: st.beta * f * smp.li * (w / pdf_light),
                });
            }
        }
    }
    // BSDF sampling
    let uc = rng.next_f32();
    let u = rng.next_2d();
    let Some(bs) = bsdf.sample(wo_l, uc, u, mode) else { return (shadow, None) };
    let weight = bs.weight();
    if weight.is_black() {
        return (shadow, None);
    }
    st.beta *= weight;
    st.eta_scale *= bs.eta * bs.eta;
    let wi = frame.to_world(bs.wi);
    st.prev = Some((si.p, bs.pdf, bs.flags.specular));
    let next = spawn_ray(si.p, si.ng, wi);
    if s.rr_depth >= 0 && depth >= s.rr_depth {
        let q = (st.beta.max_component() * st.eta_scale).min(0.95);
        if rng.next_f32() >= q {
            return (shadow, None);
        }
        st.beta /= q;
    }
    (shadow, Some(next))
}

/// Radiance arriving along `ray` (one path sample).
pub fn li(scene: &Scene, mut ray: Ray, rng: &mut Rng, s: &PathSettings) -> Spectrum {
    let mut st = PathState::START;
    loop {
        let Some(si) = scene.intersect(&ray) else {
            escaped(scene, s, &mut st, &ray);
            break;
        };
        let (shadow, next) = vertex(scene, s, &mut st, &ray, &si, rng);
        if let Some(sh) = shadow
            && !scene.occluded(&sh.ray)
        {
            st.l += sh.contrib;
        }
        match next {
            Some(r) => ray = r,
            None => break,
        }
    }
    st.l
}

/// Running sums of one pixel's samples (f64, for the mean and the sample variance).
#[derive(Clone, Copy, Debug, Default)]
struct PixelSums {
    sum: [f64; 3],
    sum2: [f64; 3],
    n: u32,
    bad: u64,
}

impl PixelSums {
    #[inline]
    fn add(&mut self, v: Spectrum) {
        self.n += 1;
        if !v.is_finite() {
            self.bad += 1;
            return;
        }
        for c in 0..3 {
            let x = v[c] as f64;
            self.sum[c] += x;
            self.sum2[c] += x * x;
        }
    }

    /// (mean, standard error of the mean).
    fn finish(&self) -> (Spectrum, Spectrum) {
        let n = self.n;
        let nf = n.max(1) as f64;
        let mut mean = Spectrum::ZERO;
        let mut err = Spectrum::ZERO;
        for c in 0..3 {
            let m = self.sum[c] / nf;
            let var = if n > 1 { ((self.sum2[c] - nf * m * m) / (nf - 1.0)).max(0.0) } else { 0.0 };
            mean[c] = m as f32;
            err[c] = (var / nf).sqrt() as f32;
        }
        (mean, err)
    }
}

/// One row rendered a pixel at a time, a path at a time (scenes whose [`Accel`] traces packets
/// one ray after the other: the BVH).
fn render_row_scalar(scene: &Scene, cam: usize, y: usize, s: &PathSettings, row: &mut Row) {
    let camera = &scene.cameras[cam];
    let w = camera.width;
    for x in 0..w {
        let mut rng = Rng::new(s.seed, cam as u64, (y * w + x) as u64);
        let mut sums = PixelSums::default();
        for _ in 0..s.spp {
            let p = Vec2::new(x as f32 + rng.next_f32(), y as f32 + rng.next_f32());
            let ray = camera.generate_ray(p);
            sums.add(li(scene, ray, &mut rng, s));
        }
        row.put(x, &sums);
    }
}

/// A finished row: means, standard errors, non-finite samples.
struct Row {
    mean: Vec<Spectrum>,
    err: Vec<Spectrum>,
    bad: u64,
}

impl Row {
    fn new(w: usize) -> Row {
        Row { mean: vec![Spectrum::ZERO; w], err: vec![Spectrum::ZERO; w], bad: 0 }
    }
    fn put(&mut self, x: usize, sums: &PixelSums) {
        let (m, e) = sums.finish();
        self.mean[x] = m;
        self.err[x] = e;
        self.bad += sums.bad;
    }
}

/// How [`render`] traces a row (all give the same image bit for bit).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum RowPlan {
    /// [`render_row_scalar`].
    Scalar,
    /// [`wavefront::render_row`] (the scalar vertex in packet lanes).
    Wavefront,
    /// [`wide_row::render_row`] with this compilation of the kernels.
    Wide(wide::Kernel),
}

impl RowPlan {
    /// The fastest measured plan for the scene: diffuse scenes lit by triangles take the wide
    /// row; other tiny scenes the wavefront with the scalar vertex; other scenes behind the BVH
    /// a path at a time.
    fn choose(scene: &Scene) -> RowPlan {
        match (scene.accel(), wavefront::wide_kernel(scene, wide::Kernel::detect())) {
            (_, Some(k)) => RowPlan::Wide(k),
            (Accel::Tiny { .. } | Accel::Split(_), None) => RowPlan::Wavefront,
            (Accel::Bvh(_), None) => RowPlan::Scalar,
        }
    }

    /// Renders row `y` of camera `cam` (`tables`: the scene's, for [`RowPlan::Wide`]).
    fn render(
        self,
        scene: &Scene,
        tables: Option<&wide_tables::Tables>,
        cam: usize,
        y: usize,
        s: &PathSettings,
        row: &mut Row,
    ) {
        match (self, tables) {
            (RowPlan::Wide(k), Some(t)) => wide_row::render_row(scene, t, cam, y, s, row, k),
            (RowPlan::Wide(_), None) => panic!("the wide row needs the scene's tables"),
            (RowPlan::Wavefront, _) => wavefront::render_row(scene, cam, y, s, row),
            (RowPlan::Scalar, _) => render_row_scalar(scene, cam, y, s, row),
        }
    }
}

/// Renders camera `cam` of the scene. `on_row` is called after each finished row (progress).
pub fn render(scene: &Scene, cam: usize, s: &PathSettings, on_row: &(dyn Fn() + Sync)) -> RenderOutput {
    render_cancellable(scene, cam, s, on_row, None).expect("a render without a cancel flag finishes")
}

/// [`render`] that stops early once `cancel` is set: rows not yet started are skipped and the
/// result is [`crate::error::Error::Interrupted`]. Without a cancel request the image is the
/// same, bit for bit, as [`render`]'s (each row depends only on its own index and the seed).
pub fn render_cancellable(
    scene: &Scene,
    cam: usize,
    s: &PathSettings,
    on_row: &(dyn Fn() + Sync),
    cancel: Option<&std::sync::atomic::AtomicBool>,
) -> crate::error::Result<RenderOutput> {
    render_split(scene, cam, s, on_row, cancel, &crate::dist::Solo)
}

/// [`render_cancellable`] with the rows split across the processes of `comm`: row `y` is
/// rendered by rank `y mod size` (each row depends only on its index and the seed), the
/// finished rows are exchanged whole, and every rank returns the full image — the same bits
/// as one process renders. `on_row` counts this rank's rows only.
pub fn render_split(
    scene: &Scene,
    cam: usize,
    s: &PathSettings,
    on_row: &(dyn Fn() + Sync),
    cancel: Option<&std::sync::atomic::AtomicBool>,
    comm: &dyn crate::dist::Comm,
) -> crate::error::Result<RenderOutput> {
    let cancelled = || cancel.is_some_and(|c| c.load(std::sync::atomic::Ordering::Relaxed));
    let camera = &scene.cameras[cam];
    let (w, h) = (camera.width, camera.height);
    let plan = RowPlan::choose(scene);
    let tables = matches!(plan, RowPlan::Wide(_)).then(|| wide_tables::Tables::new(scene));
    let mine: Vec<usize> = (0..h).filter(|&y| comm.owns(y as u64)).collect();
    let rows: Vec<Row> = mine
        .par_iter()
        .map(|&y| {
            let mut row = Row::new(w);
            if cancelled() {
                return row;
            }
            plan.render(scene, tables.as_ref(), cam, y, s, &mut row);
            on_row();
            row
        })
        .collect();
    if cancelled() {
        return Err(crate::error::Error::Interrupted {
            kept: "nothing (the render was not finished)".into(),
        });
    }
    let mut image = Image::new(w, h);
    let mut stderr = Image::new(w, h);
    let mut nonfinite = 0;
    if comm.size() == 1 {
        for (y, row) in rows.into_iter().enumerate() {
            image.data[y * w..(y + 1) * w].copy_from_slice(&row.mean);
            stderr.data[y * w..(y + 1) * w].copy_from_slice(&row.err);
            nonfinite += row.bad;
        }
    } else {
        let mut p = crate::dist::Packer::default();
        for row in &rows {
            p.u64(row.bad);
            for v in row.mean.iter().chain(&row.err) {
                p.f32s(&v.0);
            }
        }
        let all = comm.all_gather_bytes(&p.0);
        for (rank, bytes) in all.iter().enumerate() {
            let mut u = crate::dist::Unpacker(bytes);
            for y in (rank..h).step_by(comm.size()) {
                nonfinite += u.u64();
                for v in image.data[y * w..(y + 1) * w].iter_mut().chain(&mut stderr.data[y * w..(y + 1) * w])
                {
                    *v = Spectrum([u.f32(), u.f32(), u.f32()]);
                }
            }
            assert!(u.is_empty(), "rank {rank} sent rows of another image");
        }
    }
    Ok(RenderOutput { image, stderr, nonfinite, samples: (w * h) as u64 * s.spp as u64 })
}

#[cfg(test)]
mod tests;
