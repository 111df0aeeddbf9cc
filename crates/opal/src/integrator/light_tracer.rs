//! Light tracer that deposits irradiance into per-shape texture maps (method C of
//! `docs/methods`, step 8a: "render the scene by forward ray tracing that accumulates
//! irradiance on the texture maps").
//!
//! Paths start on the lights (`Light::sample_le`, light chosen proportionally to power) and
//! carry power β = Le·cos/(pmf·pdf_pos·pdf_dir)/N. At every surface hit on the **front** side
//! of a shape that has an [`IrradianceTarget`], the path deposits β / A_texel into the texel
//! that contains the hit's `uv` (A_texel = world area of one texel of the hit triangle), i.e.
//! an estimate of the incident irradiance E = ∫ L cos dω [W·m⁻²] averaged over the texel.
//! Deposits of the first hit (direct light) and of later hits (indirect light) go into two
//! separate maps; with [`LightTraceSettings::direct`] `= false` the first hits are not deposited
//! (no direct map: half the accumulator memory; same paths, same indirect map). The path then scatters with the scene's BSDF in
//! [`TransportMode::Importance`] and Russian roulette from `rr_depth`.
//!
//! Determinism: paths are split into fixed batches of `batch_size`; batch `b` draws its numbers
//! from `Rng::new(seed, 0x4c54, b)`. The result depends on `(seed, batch_size, paths)` only,
//! never on the thread count.
//!
//! **Accumulation** (fixed point). Up to `MAX_WORKERS` (8) workers pull batch indices from a
//! shared counter and add their deposits into their own integer maps, which live for the whole
//! pass (no per-batch maps to zero and merge); the worker maps are summed at the end. Integer
//! addition is associative and commutative, so which worker traced which batch does not matter.
//! A deposit `v = β_c / (N · A_texel)` is stored as `round(β_c · f)` units, with
//! `f = 2²⁴ · A_min / (A_texel · β_ref)` per triangle (`A_min` = smallest texel area of the shape,
//! `β_ref = max_l max_c Φ_l,c / pmf_l` = the initial weight of a path from the brightest light
//! per pick): an unscattered path's deposit into the shape's smallest texel is 2²⁴ units.
//! *Quantisation error*: ≤ ½ unit per deposit, i.e. a relative error ≤ 2⁻²⁵ (3·10⁻⁸) ×
//! (β_ref/β) × (A_texel/A_min) per deposit — far below the Monte-Carlo noise (the test below checks
//! agreement with a plain f64 pass to 10⁻⁶). *Overflow*: a texel's sum would need ~2³⁸ deposits
//! of the reference size; the exact (u128) sum of |units| per shape is checked at the end, and if
//! it reaches 2⁶³ the pass is traced again with a coarser unit (deterministic; never seen).
//! The per-texel sums live in `i32` cells with an exact carry into a lazily allocated `i64`
//! spill map (`Cells`: an addition that would overflow the cell first moves the cell's content
//! to the spill map), so a texel's sum is `cell + spill` exactly, as with `i64` cells, at half
//! the memory footprint of the deposit adds.
//!
//! **Speed** (see `docs/performance.md`): per-triangle hit data precomputed once per pass (unit
//! geometric normal, corner uvs and normals, deposit factor, map size, material), so a hit costs
//! no `Scene::interaction`; Lambertian materials (the de-lighting scenes) are sampled in place
//! (the arithmetic of `Lambert::sample` and `BsdfSample::weight`, same random numbers as the
//! generic `Scene::bsdf` path, which other materials take), and their albedo lookup is applied
//! after the next ray is traced so its cache miss overlaps the traversal; deposits go through a
//! short per-worker queue that prefetches their texel. Small scenes are traversed by
//! [`crate::accel::TinyAccel`] (through `Scene::intersect_hit`).
//!
//! Tests (below): a quad under a point light (E = I cos θ / d², analytic) and a quad under a
//! small area light against a quadrature of ∫ L cos dω; indirect light in a closed furnace-like
//! box against the path tracer's estimate; thread-count independence; the fast paths and the
//! fixed-point sums against the generic f64 pass (a bitmap-textured floor, a two-sided wall,
//! Russian roulette) to 10⁻⁶, identical for 1, 2 and 3 threads; the `i32` cells with spill
//! against plain `i64` sums (random deposits up to 2⁴⁰ units); `direct: false` leaves the
//! indirect map bitwise unchanged.

use crate::bsdf::{Bxdf, TransportMode};
use crate::math::{Frame, INV_PI, Vec2, Vec3};
use crate::sampling::{Rng, square_to_cosine_hemisphere, square_to_cosine_hemisphere_pdf};
use crate::scene::Scene;
use crate::scene::build::eval_texture;
use crate::scene::desc::{BsdfDesc, TextureDesc};
use crate::spectrum::Spectrum;
use rayon::prelude::*;

/// Texture map layout of one shape for deposits.
#[derive(Clone, Debug)]
pub struct IrradianceTarget {
    /// Map width in texels.
    pub width: usize,
    /// Map height in texels.
    pub height: usize,
    /// Per triangle of the shape (local index): world area of one texel on that triangle
    /// (triangle world area / (uv area · width · height)); ≤ 0 = do not deposit.
    pub texel_area: Vec<f32>,
}

/// Settings of a light-tracing pass.
#[derive(Clone, Copy, Debug)]
pub struct LightTraceSettings {
    /// Number of light paths.
    pub paths: u64,
    /// Paths per batch (fixed: part of the result's identity, together with the seed).
    pub batch_size: u64,
    /// Maximum number of surface interactions per path (−1 = unbounded).
    pub max_depth: i32,
    /// Number of interactions after which Russian roulette is used.
    pub rr_depth: i32,
    /// Seed.
    pub seed: u64,
    /// Deposit the first hits (direct light) into [`IrradianceMaps::direct`]. `false`: first hits
    /// are not deposited and no direct accumulator is allocated ([`IrradianceMaps::direct`] is
    /// empty), for callers that use the indirect map only; the paths, their random numbers and
    /// the indirect map are exactly those of a pass with `true`. Default `true`.
    pub direct: bool,
}

impl Default for LightTraceSettings {
    fn default() -> Self {
        LightTraceSettings {
            paths: 1_000_000,
            batch_size: 1 << 18,
            max_depth: -1,
            rr_depth: 5,
            seed: 0,
            direct: true,
        }
    }
}

/// Irradiance maps of one shape: `width × height` texels, row-major, f64 RGB.
#[derive(Clone, Debug)]
pub struct IrradianceMaps {
    /// Map width.
    pub width: usize,
    /// Map height.
    pub height: usize,
    /// Irradiance of first hits (direct light), W·m⁻²; empty when the pass ran with
    /// [`LightTraceSettings::direct`] `= false`.
    pub direct: Vec<[f64; 3]>,
    /// Irradiance of later hits (indirect light), W·m⁻².
    pub indirect: Vec<[f64; 3]>,
}

/// Result of [`trace`].
#[derive(Clone, Debug)]
pub struct LightTraceOutput {
    /// Per shape (same order as `scene.shapes`): its maps when it had a target.
    pub maps: Vec<Option<IrradianceMaps>>,
    /// Paths traced.
    pub paths: u64,
    /// Deposits dropped because they were NaN or infinite (should be 0).
    pub nonfinite: u64,
}

fn empty_maps(targets: &[Option<IrradianceTarget>]) -> Vec<Option<IrradianceMaps>> {
    targets
        .iter()
        .map(|t| {
            t.as_ref().map(|t| IrradianceMaps {
                width: t.width,
                height: t.height,
                direct: vec![[0.0; 3]; t.width * t.height],
                indirect: vec![[0.0; 3]; t.width * t.height],
            })
        })
        .collect()
}

/// Units of one deposit of the reference size (see [`FixedPoint`]): 2²⁴.
const REF_UNITS: f64 = (1u64 << 24) as f64;

/// Fixed-point scale of one pass (see the module docs, "Accumulation").
///
/// A deposit of value `v = β_c / (N · A_texel)` is stored as the integer `round(β_c · f)`
/// with `f = 2²⁴ · A_min / (A_texel · β_ref)` per triangle (`A_min` = the smallest texel area
/// of the shape, `β_ref` = the largest initial path weight of any light, `max_c Φ_l,c / pmf_l`):
/// an unscattered path's deposit into the shape's smallest texel is 2²⁴ units. The texel's
/// value is its integer sum times `β_ref / (2²⁴ · A_min · N)`.
#[derive(Clone, Debug)]
struct FixedPoint {
    /// Per triangle of the soup: units per unit of β (0 = no deposit).
    factor: Vec<f64>,
    /// Per shape: W·m⁻² per unit.
    unit: Vec<f64>,
}

impl FixedPoint {
    fn new(scene: &Scene, targets: &[Option<IrradianceTarget>], paths: u64, shift: i32) -> FixedPoint {
        let beta_ref = scene
            .light_sampler()
            .map(|ls| {
                scene
                    .lights
                    .iter()
                    .enumerate()
                    .map(|(i, l)| {
                        let pmf = ls.pmf(i) as f64;
                        if pmf > 0.0 { l.power().max_component() as f64 / pmf } else { 0.0 }
                    })
                    .fold(0.0f64, f64::max)
            })
            .filter(|b| b.is_finite() && *b > 0.0)
            .unwrap_or(1.0);
        let units = REF_UNITS * 2f64.powi(shift);
        let n_prims = scene.shapes.last().map_or(0, |s| s.first_prim as usize + s.mesh.triangle_count());
        let mut factor = vec![0.0; n_prims];
        let mut unit = vec![0.0; scene.shapes.len()];
        for (k, (shape, t)) in scene.shapes.iter().zip(targets).enumerate() {
            let Some(t) = t else { continue };
            let a_min =
                t.texel_area.iter().copied().filter(|&a| a > 0.0).fold(f32::INFINITY, f32::min) as f64;
            if !a_min.is_finite() {
                continue;
            }
            unit[k] = beta_ref / (units * a_min * paths.max(1) as f64);
            for (j, &a) in t.texel_area.iter().enumerate().take(shape.mesh.triangle_count()) {
                if a > 0.0 {
                    factor[shape.first_prim as usize + j] = units * a_min / (a as f64 * beta_ref);
                }
            }
        }
        FixedPoint { factor, unit }
    }
}

/// Integer sums of one map, `[r, g, b]` per texel, flat: the exact sum of a channel is
/// `fine[j] + spill[j]`. Deposits are added into the `i32` cells (half the memory traffic and
/// footprint of `i64` cells: the adds are cache and TLB misses); an addition that would
/// overflow moves the cell's content into the `i64` spill map first (exact carry), a value beyond
/// `i32` goes to the spill map directly. A cell overflows after ≈ 2⁷ deposits of the reference
/// size (2²⁴ units), so about one deposit in a hundred touches the spill map, which is
/// allocated at its first use (zeroed pages: only the pages touched become resident).
struct Cells {
    fine: Vec<i32>,
    spill: Vec<i64>,
}

impl Cells {
    /// `n` channels (3 per texel), all zero.
    fn new(n: usize) -> Cells {
        Cells { fine: vec![0; n], spill: Vec::new() }
    }

    /// Adds `v` to channels `i..i + 3`.
    #[inline(always)]
    fn add(&mut self, i: usize, v: [i64; 3]) {
        let n = self.fine.len();
        let cell = &mut self.fine[i..i + 3];
        for c in 0..3 {
            match i32::try_from(v[c]) {
                Ok(x) => match cell[c].checked_add(x) {
                    Some(y) => cell[c] = y,
                    None => {
                        let old = std::mem::replace(&mut cell[c], x);
                        spill_add(&mut self.spill, n, i + c, old as i64);
                    }
                },
                Err(_) => spill_add(&mut self.spill, n, i + c, v[c]),
            }
        }
    }

    /// The sum of channel `j` (wrapping: exact while no texel's true sum reaches 2⁶³).
    #[inline]
    fn get(&self, j: usize) -> i64 {
        (self.fine[j] as i64).wrapping_add(self.spill.get(j).copied().unwrap_or(0))
    }
}

/// Adds `v` to channel `j` of a spill map of `n` channels, allocated at its first use.
#[cold]
#[inline(never)]
fn spill_add(spill: &mut Vec<i64>, n: usize, j: usize, v: i64) {
    if spill.is_empty() {
        *spill = vec![0; n];
    }
    spill[j] = spill[j].wrapping_add(v);
}

/// Integer irradiance sums of one shape (one worker).
struct ShapeAcc {
    width: usize,
    height: usize,
    /// Empty without direct deposits.
    direct: Cells,
    indirect: Cells,
    /// Sum of |units| of every deposit (exact): bounds every texel's sum.
    total: u128,
}

type Acc = Vec<Option<ShapeAcc>>;

fn empty_acc(targets: &[Option<IrradianceTarget>], direct: bool) -> Acc {
    targets
        .iter()
        .map(|t| {
            t.as_ref().map(|t| ShapeAcc {
                width: t.width,
                height: t.height,
                direct: Cells::new(if direct { 3 * t.width * t.height } else { 0 }),
                indirect: Cells::new(3 * t.width * t.height),
                total: 0,
            })
        })
        .collect()
}

/// Largest number of accumulators (one per worker): bounds the memory on machines with many
/// logical CPUs.
const MAX_WORKERS: usize = 8;

/// Traces `s.paths` light paths and returns the irradiance deposited into the maps of the shapes
/// that have a target (`targets[shape]`). The shapes' `uv`s (`scene.interaction`) locate texels:
/// texel `(floor(u·W), floor(v·H))`, clamped. `on_batch` is called after each batch.
pub fn trace(
    scene: &Scene,
    targets: &[Option<IrradianceTarget>],
    s: &LightTraceSettings,
    on_batch: &(dyn Fn() + Sync),
) -> LightTraceOutput {
    let Some(sampler) = scene.light_sampler() else {
        return LightTraceOutput { maps: empty_maps(targets), paths: 0, nonfinite: 0 };
    };
    let mut shift = 0;
    loop {
        let fp = FixedPoint::new(scene, targets, s.paths, shift);
        match trace_fixed(scene, sampler, targets, s, &fp, on_batch) {
            Ok(out) => return out,
            // Some shape's deposits summed to ≥ 2⁶³ units: a texel may have overflowed. Trace
            // again with a coarser unit (never seen in practice; the result stays deterministic
            // since the decision depends on exact integer sums only).
            Err(bits) => shift -= bits,
        }
    }
}

/// One pass at a fixed-point scale; `Err(bits)` when the scale must shrink by `2^bits`.
fn trace_fixed(
    scene: &Scene,
    sampler: &crate::light::LightSampler,
    targets: &[Option<IrradianceTarget>],
    s: &LightTraceSettings,
    fp: &FixedPoint,
    on_batch: &(dyn Fn() + Sync),
) -> Result<LightTraceOutput, i32> {
    use std::sync::atomic::{AtomicU64, Ordering};
    let batch = s.batch_size.max(1);
    let n_batches = s.paths.div_ceil(batch);
    // Workers pull batch indices from a counter and add into their own accumulator for the
    // whole pass. Integer sums do not depend on the order of the additions, so which worker
    // traced which batch does not change the result.
    let workers = rayon::current_num_threads().clamp(1, MAX_WORKERS).min(n_batches.max(1) as usize);
    let next = AtomicU64::new(0);
    let prims = prims(scene, targets, fp);
    let results: Vec<(Acc, u64)> = (0..workers)
        .into_par_iter()
        .map(|_| {
            let mut sink = Sink::new(empty_acc(targets, s.direct));
            let mut bad = 0u64;
            loop {
                let b = next.fetch_add(1, Ordering::Relaxed);
                if b >= n_batches {
                    break;
                }
                let start = b * batch;
                let end = ((b + 1) * batch).min(s.paths);
                let mut rng = Rng::new(s.seed, 0x4c54, b);
                for _ in start..end {
                    trace_path(scene, sampler, &prims, &mut sink, &mut rng, s, &mut bad);
                }
                on_batch();
            }
            (sink.finish(), bad)
        })
        .collect();
    let nonfinite = results.iter().map(|r| r.1).sum();
    let mut accs: Vec<Acc> = results.into_iter().map(|r| r.0).collect();
    // overflow check: the exact sum of |units| of a shape bounds each of its texels' sums
    for k in 0..targets.len() {
        let total: u128 = accs.iter().filter_map(|a| a[k].as_ref()).map(|m| m.total).sum();
        if total >= 1u128 << 63 {
            let bits = (128 - total.leading_zeros()) as i32 - 62;
            return Err(bits.max(1));
        }
    }
    // reduce: wrapping integer sums (exact since no texel's true sum reaches 2⁶³), then scale
    let (first, rest) = accs.split_first_mut().expect("at least one worker");
    let maps = first
        .par_iter_mut()
        .enumerate()
        .map(|(k, m)| {
            let m = m.take()?;
            let unit = fp.unit[k];
            let reduce = |own: &Cells, direct: bool| -> Vec<[f64; 3]> {
                (0..own.fine.len() / 3)
                    .into_par_iter()
                    .map(|i| {
                        let mut sum: [i64; 3] = std::array::from_fn(|c| own.get(3 * i + c));
                        for a in rest.iter() {
                            let o = a[k].as_ref().expect("same targets");
                            let o = if direct { &o.direct } else { &o.indirect };
                            for (c, x) in sum.iter_mut().enumerate() {
                                *x = x.wrapping_add(o.get(3 * i + c));
                            }
                        }
                        sum.map(|x| x as f64 * unit)
                    })
                    .collect()
            };
            let (width, height) = (m.width, m.height);
            let direct = reduce(&m.direct, true);
            let indirect = reduce(&m.indirect, false);
            Some(IrradianceMaps { width, height, direct, indirect })
        })
        .collect();
    Ok(LightTraceOutput { maps, paths: s.paths, nonfinite })
}

/// Material of a triangle as the light tracer needs it.
#[derive(Clone, Copy)]
enum Mat<'a> {
    /// Lambertian with this reflectance; `two_sided` = wrapped in `twosided`.
    Diffuse { tex: &'a TextureDesc, two_sided: bool },
    /// Anything else: `Scene::bsdf`.
    Generic,
}

/// Per-triangle data precomputed for the hit reconstruction (same formulas as
/// `Scene::interaction` and `Scene::bsdf`, evaluated once per triangle instead of per hit).
#[derive(Clone, Copy)]
struct Prim<'a> {
    /// Unit geometric normal.
    ng: Vec3,
    /// Corner uvs (zeros without uvs).
    uv: [Vec2; 3],
    /// Corner shading normals, when the mesh has them.
    normals: Option<[Vec3; 3]>,
    shape: u32,
    /// Fixed-point units per unit of β for a deposit (0 = no deposit).
    factor: f64,
    /// Deposit map size (texels).
    width: u32,
    height: u32,
    mat: Mat<'a>,
}

fn prims<'a>(scene: &'a Scene, targets: &[Option<IrradianceTarget>], fp: &FixedPoint) -> Vec<Prim<'a>> {
    let mut out = Vec::with_capacity(fp.factor.len());
    for (k, sh) in scene.shapes.iter().enumerate() {
        let m = &sh.mesh;
        let (desc, two_sided) = match &sh.bsdf {
            BsdfDesc::TwoSided(inner) => (inner.as_ref(), true),
            d => (d, false),
        };
        let mat = match desc {
            BsdfDesc::Diffuse { reflectance } => Mat::Diffuse { tex: reflectance, two_sided },
            _ => Mat::Generic,
        };
        let (width, height) = targets[k].as_ref().map_or((0, 0), |t| (t.width as u32, t.height as u32));
        for (j, idx) in m.indices.iter().enumerate() {
            let [i0, i1, i2] = idx.map(|i| i as usize);
            let (p0, p1, p2) = (m.positions[i0], m.positions[i1], m.positions[i2]);
            out.push(Prim {
                ng: (p1 - p0).cross(p2 - p0).normalize(),
                uv: if m.uvs.is_empty() { [Vec2::ZERO; 3] } else { [m.uvs[i0], m.uvs[i1], m.uvs[i2]] },
                normals: (!m.normals.is_empty()).then(|| [m.normals[i0], m.normals[i1], m.normals[i2]]),
                shape: k as u32,
                factor: fp.factor[sh.first_prim as usize + j],
                width,
                height,
                mat,
            });
        }
    }
    out
}

/// The scattering weight of the last vertex, applied after the next ray is traced so that the
/// texture lookup's cache miss overlaps the traversal.
enum Weight<'a> {
    Known(Spectrum),
    /// Lambert: `(reflectance(uv) · 1/π) · (|cos θi| / pdf)` (as `BsdfSample::weight`).
    Lambert {
        tex: &'a TextureDesc,
        uv: Vec2,
        ratio: f32,
    },
}

impl Weight<'_> {
    #[inline]
    fn get(self) -> Spectrum {
        match self {
            Weight::Known(w) => w,
            Weight::Lambert { tex, uv, ratio } => (eval_texture(tex, uv) * INV_PI) * ratio,
        }
    }
}

/// Hints the cache lines of a bitmap lookup at `uv` (no effect on results).
#[inline]
fn prefetch_texture(tex: &TextureDesc, uv: Vec2) {
    if let TextureDesc::Bitmap(b) = tex {
        let img = &*b.image;
        if img.width == 0 || img.height == 0 || !(uv.x.is_finite() && uv.y.is_finite()) {
            return;
        }
        let x = ((uv.x * img.width as f32) as i64).clamp(0, img.width as i64 - 1) as usize;
        let y = ((uv.y * img.height as f32 - 0.5) as i64).clamp(0, img.height as i64 - 1) as usize;
        let i = y * img.width + x;
        prefetch(&img.data[i]);
        if let Some(v) = img.data.get(i + img.width) {
            prefetch(v);
        }
    }
}

#[inline]
fn trace_path(
    scene: &Scene,
    sampler: &crate::light::LightSampler,
    prims: &[Prim],
    sink: &mut Sink,
    rng: &mut Rng,
    s: &LightTraceSettings,
    bad: &mut u64,
) {
    let (li, pmf, _) = sampler.sample(rng.next_f32());
    let (u_pos, u_dir) = (rng.next_2d(), rng.next_2d());
    let Some(es) = scene.lights[li].sample_le(u_pos, u_dir) else { return };
    if pmf <= 0.0 || es.pdf_pos <= 0.0 || es.pdf_dir <= 0.0 {
        return;
    }
    let cos = if es.n == Vec3::ZERO { 1.0 } else { es.ray.d.dot(es.n).abs() };
    let mut beta = es.le * (cos / (pmf * es.pdf_pos * es.pdf_dir));
    let mut ray = es.ray;
    // emitted rays of area lights start on the surface: offset them
    if es.n != Vec3::ZERO {
        ray = super::spawn_ray(ray.o, es.n, ray.d);
    }
    let mode = TransportMode::Importance;
    let mut depth = 0i32;
    // The texel of a deposit is a random location in maps of up to millions of texels: a cache
    // and TLB miss. Deposits therefore go through the worker's queue ([`Sink`]), which prefetches
    // them and adds them [`QUEUE`] deposits later (integer sums: the order of additions does not
    // matter). Likewise the albedo lookup of a Lambertian vertex (its sampled direction does not depend on the albedo), and with it the Russian
    // roulette, which consumes its random number after the vertex's direction sample as before:
    // same random numbers, same result; a path killed by the roulette has traced one ray for
    // nothing (from `rr_depth` on only).
    let mut weight: Option<Weight> = None;
    loop {
        let hit = scene.intersect_hit(&ray);
        if let Some(w) = weight.take() {
            let w = w.get();
            if w.is_black() {
                break;
            }
            beta *= w;
            if s.rr_depth >= 0 && depth >= s.rr_depth {
                let q = beta_survival(beta, es.le, cos, pmf, es.pdf_pos, es.pdf_dir);
                if rng.next_f32() >= q {
                    break;
                }
                beta *= 1.0 / q;
            }
        }
        let Some(h) = hit else { break };
        depth += 1;
        let pr = &prims[h.prim as usize];
        let wo = -ray.d;
        let front = wo.dot(pr.ng) > 0.0;
        let b0 = 1.0 - h.b1 - h.b2;
        let uv = pr.uv[0] * b0 + pr.uv[1] * h.b1 + pr.uv[2] * h.b2;
        if front && pr.factor > 0.0 && (depth > 1 || s.direct) {
            let (w, hgt) = (pr.width as usize, pr.height as usize);
            let x = ((uv.x * w as f32) as i64).clamp(0, w as i64 - 1) as usize;
            let y = ((uv.y * hgt as f32) as i64).clamp(0, hgt as i64 - 1) as usize;
            let e = beta.to_f64();
            if e.iter().all(|v| v.is_finite()) {
                let shape = pr.shape as usize;
                let index = 3 * (y * w + x);
                let direct = depth == 1;
                // round half away from zero (`as` saturates: an absurd deposit then shows in
                // the overflow check)
                let value = e.map(|v| {
                    let q = v * pr.factor;
                    (q + 0.5f64.copysign(q)) as i64
                });
                sink.push(Pending { shape, index, direct, value });
            } else {
                *bad += 1;
            }
        }
        if s.max_depth >= 0 && depth >= s.max_depth {
            break;
        }
        let p = ray.at(h.t);
        match pr.mat {
            Mat::Diffuse { tex, two_sided } => {
                let ns = match pr.normals {
                    None => pr.ng,
                    Some([n0, n1, n2]) => {
                        let n = n0 * b0 + n1 * h.b1 + n2 * h.b2;
                        let l = n.length();
                        if l > 0.0 { n / l } else { pr.ng }
                    }
                };
                let n = if two_sided && wo.dot(pr.ng) < 0.0 { -ns } else { ns };
                let frame = Frame::from_normal(n);
                // `Lambert::sample`, in world space
                let _uc = rng.next_f32(); // drawn for the generic sampler: same streams
                let u: Vec2 = rng.next_2d();
                if wo.dot(frame.n) <= 0.0 {
                    break;
                }
                let wi = square_to_cosine_hemisphere(u);
                let pdf = square_to_cosine_hemisphere_pdf(wi);
                if pdf <= 0.0 {
                    break;
                }
                prefetch_texture(tex, uv);
                weight = Some(Weight::Lambert { tex, uv, ratio: wi.z.abs() / pdf });
                ray = super::spawn_ray(p, pr.ng, frame.to_world(wi));
            }
            Mat::Generic => {
                let si = scene.interaction(&ray, &h);
                let (frame, bsdf) = scene.bsdf(&si, wo);
                let wo_l = frame.to_local(wo);
                let uc = rng.next_f32();
                let u: Vec2 = rng.next_2d();
                let Some(bs) = bsdf.sample(wo_l, uc, u, mode) else { break };
                weight = Some(Weight::Known(bs.weight()));
                ray = super::spawn_ray(si.p, si.ng, frame.to_world(bs.wi));
            }
        }
    }
}

/// Deposits in flight per worker: the queue length of [`Sink`].
const QUEUE: usize = 32;

/// A worker's accumulator behind a queue of [`QUEUE`] deposits: a deposit's texel is
/// prefetched when it is pushed and the addition happens when it leaves the queue, about ten
/// paths later, so the memory latency overlaps the tracing instead of stalling it.
struct Sink {
    acc: Acc,
    ring: [Pending; QUEUE],
    head: usize,
    len: usize,
}

impl Sink {
    fn new(acc: Acc) -> Sink {
        Sink { acc, ring: [Pending::default(); QUEUE], head: 0, len: 0 }
    }
    #[inline]
    fn push(&mut self, p: Pending) {
        if let Some(m) = self.acc[p.shape].as_ref() {
            prefetch(if p.direct { &m.direct.fine[p.index] } else { &m.indirect.fine[p.index] });
        }
        if self.len == QUEUE {
            let old = std::mem::replace(&mut self.ring[self.head], p);
            self.head = (self.head + 1) % QUEUE;
            old.apply(&mut self.acc);
        } else {
            self.ring[(self.head + self.len) % QUEUE] = p;
            self.len += 1;
        }
    }
    /// Applies the queued deposits and returns the accumulator.
    fn finish(mut self) -> Acc {
        for k in 0..self.len {
            let p = self.ring[(self.head + k) % QUEUE];
            p.apply(&mut self.acc);
        }
        self.acc
    }
}

/// A deposit: texel, map and integer value.
#[derive(Clone, Copy, Default)]
struct Pending {
    shape: usize,
    /// Index of the texel's red channel in the flat map.
    index: usize,
    direct: bool,
    value: [i64; 3],
}

impl Pending {
    #[inline]
    fn apply(self, acc: &mut Acc) {
        if let Some(m) = acc[self.shape].as_mut() {
            let cells = if self.direct { &mut m.direct } else { &mut m.indirect };
            cells.add(self.index, self.value);
            for v in self.value {
                m.total += v.unsigned_abs() as u128;
            }
        }
    }
}

/// Hint to bring the cache line of `v` close to the core (no effect on results).
#[inline(always)]
fn prefetch<T>(v: &T) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        // SAFETY: SSE is part of the x86-64 baseline, so the instruction exists; a prefetch
        // never faults and has no architectural effect, whatever the address.
        unsafe { _mm_prefetch::<_MM_HINT_T0>(v as *const T as *const i8) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = v;
}

/// Survival probability for Russian roulette: the throughput relative to the path's initial
/// weight (so the roulette does not depend on the absolute power), capped at 0.95.
#[inline]
fn beta_survival(beta: Spectrum, le: Spectrum, cos: f32, pmf: f32, pdf_pos: f32, pdf_dir: f32) -> f32 {
    let b0 = (le * (cos / (pmf * pdf_pos * pdf_dir))).max_component();
    if b0 > 0.0 { (beta.max_component() / b0).min(0.95) } else { 0.0 }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::TriangleMesh;
    use crate::math::{PI, Vec3};
    use crate::scene::desc::{AreaEmitterDesc, EmitterDesc, SceneDesc, ShapeDesc};

    /// Square [-h,h]² in the plane y = 0 facing +y with uv = ((x+h)/2h, (z+h)/2h).
    fn floor_quad(h: f32) -> TriangleMesh {
        TriangleMesh {
            positions: vec![
                Vec3::new(-h, 0.0, -h),
                Vec3::new(-h, 0.0, h),
                Vec3::new(h, 0.0, h),
                Vec3::new(h, 0.0, -h),
            ],
            normals: vec![],
            uvs: vec![Vec2::new(0.0, 0.0), Vec2::new(0.0, 1.0), Vec2::new(1.0, 1.0), Vec2::new(1.0, 0.0)],
            indices: vec![[0, 1, 2], [0, 2, 3]],
        }
    }

    fn diffuse(a: f32) -> BsdfDesc {
        BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(Spectrum::splat(a)) }
    }

    fn target(res: usize, h: f32) -> IrradianceTarget {
        let ta = (2.0 * h) * (2.0 * h) / (res * res) as f32;
        IrradianceTarget { width: res, height: res, texel_area: vec![ta, ta] }
    }

    #[test]
    fn point_light_over_quad_matches_inverse_square_law() {
        let h = 1.0;
        let height = 1.0;
        let desc = SceneDesc {
            shapes: vec![ShapeDesc {
                id: "floor".into(),
                mesh: floor_quad(h),
                bsdf: diffuse(0.0),
                emitter: None,
                origin: None,
            }],
            emitters: vec![EmitterDesc::Point {
                position: Vec3::new(0.0, height, 0.0),
                intensity: Spectrum::rgb(1.0, 2.0, 3.0),
            }],
            ..Default::default()
        };
        let scene = Scene::build(&desc).unwrap();
        let res = 8;
        let s = LightTraceSettings { paths: 2_000_000, seed: 3, ..Default::default() };
        let out = trace(&scene, &[Some(target(res, h))], &s, &|| {});
        assert_eq!(out.nonfinite, 0);
        let m = out.maps[0].as_ref().unwrap();
        // Analytic texel average of E = I h / r³ over each texel (midpoint rule on a 16×16 grid).
        for (ty, tx) in [(3usize, 3usize), (0, 0), (5, 2), (7, 7)] {
            let mut e = 0.0f64;
            let n = 16;
            for j in 0..n {
                for i in 0..n {
                    let x =
                        -h as f64 + 2.0 * h as f64 * (tx as f64 + (i as f64 + 0.5) / n as f64) / res as f64;
                    let z =
                        -h as f64 + 2.0 * h as f64 * (ty as f64 + (j as f64 + 0.5) / n as f64) / res as f64;
                    let r2 = x * x + z * z + 1.0;
                    e += 1.0 / r2.powf(1.5);
                }
            }
            e /= (n * n) as f64;
            for c in 0..3 {
                let expect = e * (c + 1) as f64;
                let got = m.direct[ty * res + tx][c];
                // Each texel receives a binomial count of paths: fraction p of 2 M; relative
                // std = sqrt((1-p)/(N p)); p ≥ 0.0017 (corner texel) ⇒ ≤ 1.7 %. 5σ ⇒ 8.5 %.
                let p = e * (2.0 / res as f64).powi(2) / (4.0 * std::f64::consts::PI);
                let sigma = ((1.0 - p) / (s.paths as f64 * p)).sqrt();
                assert!(
                    (got / expect - 1.0).abs() < 5.0 * sigma,
                    "texel {tx},{ty} c{c}: {got} vs {expect} (σ {sigma})"
                );
            }
            assert_eq!(m.indirect[ty * res + tx], [0.0; 3], "black floor, nothing else: no indirect light");
        }
    }

    #[test]
    fn area_light_over_quad_matches_quadrature_and_is_thread_independent() {
        // A 0.5×0.5 emitter at height 1 facing down over a 2×2 floor, both one-sided.
        let le = 2.0f32;
        let a = 0.25f32;
        let light = TriangleMesh {
            positions: vec![
                Vec3::new(-a, 1.0, -a),
                Vec3::new(a, 1.0, -a),
                Vec3::new(a, 1.0, a),
                Vec3::new(-a, 1.0, a),
            ],
            normals: vec![],
            uvs: vec![],
            indices: vec![[0, 1, 2], [0, 2, 3]],
        };
        let n = (light.positions[1] - light.positions[0]).cross(light.positions[2] - light.positions[0]);
        assert!(n.y < 0.0, "light faces down");
        let desc = SceneDesc {
            shapes: vec![
                ShapeDesc {
                    id: "floor".into(),
                    mesh: floor_quad(1.0),
                    bsdf: diffuse(0.0),
                    emitter: None,
                    origin: None,
                },
                ShapeDesc {
                    id: "light".into(),
                    mesh: light,
                    bsdf: diffuse(0.0),
                    emitter: Some(AreaEmitterDesc { radiance: Spectrum::splat(le) }),
                    origin: None,
                },
            ],
            ..Default::default()
        };
        let scene = Scene::build(&desc).unwrap();
        let res = 4;
        let targets = [Some(target(res, 1.0)), None];
        let s = LightTraceSettings { paths: 1_000_000, seed: 11, batch_size: 10_000, ..Default::default() };
        let out = trace(&scene, &targets, &s, &|| {});
        let m = out.maps[0].as_ref().unwrap();
        // E(p) = ∫_light Le cosθ cosθ' / r² dA, texel-averaged: midpoint rule 8×8 on the texel ×
        // 32×32 on the light (smooth integrand: error ≪ 0.1 %).
        let total_power = (PI * le * 4.0 * a * a) as f64;
        for (ty, tx) in [(1usize, 1usize), (0, 0), (2, 3)] {
            let mut e = 0.0f64;
            let (nt, nl) = (8, 32);
            for j in 0..nt {
                for i in 0..nt {
                    let x = -1.0 + 2.0 * (tx as f64 + (i as f64 + 0.5) / nt as f64) / res as f64;
                    let z = -1.0 + 2.0 * (ty as f64 + (j as f64 + 0.5) / nt as f64) / res as f64;
                    for l in 0..nl {
                        for k in 0..nl {
                            let lx = -a as f64 + 2.0 * a as f64 * (k as f64 + 0.5) / nl as f64;
                            let lz = -a as f64 + 2.0 * a as f64 * (l as f64 + 0.5) / nl as f64;
                            let d2 = (lx - x).powi(2) + 1.0 + (lz - z).powi(2);
                            e += le as f64 / (d2 * d2) * (2.0 * a as f64).powi(2) / (nl * nl) as f64;
                        }
                    }
                }
            }
            e /= (nt * nt) as f64;
            let got = m.direct[ty * res + tx][0];
            let p = e * 0.25 / total_power; // fraction of paths landing in the texel
            let sigma = ((1.0 - p) / (s.paths as f64 * p)).sqrt();
            assert!((got / e - 1.0).abs() < 5.0 * sigma, "texel {tx},{ty}: {got} vs {e} (σ {sigma})");
        }
        // thread-count independence
        let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let out1 = pool.install(|| trace(&scene, &targets, &s, &|| {}));
        assert_eq!(out1.maps[0].as_ref().unwrap().direct, m.direct);
    }

    /// The unit cube of `cube_mesh` with its walls facing inwards (winding flipped, no normals).
    fn inward_box() -> crate::geometry::TriangleMesh {
        let mut inner = crate::scene::load::cube_mesh();
        for t in &mut inner.indices {
            t.swap(1, 2);
        }
        inner.normals.clear();
        inner
    }

    #[test]
    fn closed_box_indirect_matches_geometric_series() {
        // Inside a closed box whose walls all have albedo ρ, emitting walls of radiance Le: the
        // radiance is Le/(1-ρ) everywhere, so the irradiance on a wall is π Le/(1-ρ), of which the
        // direct part is π Le (all walls emit, cosine-weighted view of the whole box) and the
        // indirect part π Le ρ/(1-ρ).
        let rho = 0.5f32;
        let le = 1.0f32;
        let inner = inward_box();
        let desc = SceneDesc {
            shapes: vec![ShapeDesc {
                id: "box".into(),
                mesh: inner.clone(),
                bsdf: diffuse(rho),
                emitter: Some(AreaEmitterDesc { radiance: Spectrum::splat(le) }),
                origin: None,
            }],
            ..Default::default()
        };
        let scene = Scene::build(&desc).unwrap();
        // one texel per triangle is enough: map everything to a 1×1 map
        let texel_area: Vec<f32> = (0..inner.triangle_count()).map(|_| inner.area() as f32).collect();
        let targets = [Some(IrradianceTarget { width: 1, height: 1, texel_area })];
        let s = LightTraceSettings { paths: 400_000, seed: 5, ..Default::default() };
        let out = trace(&scene, &targets, &s, &|| {});
        let m = out.maps[0].as_ref().unwrap();
        let direct = m.direct[0][0];
        let indirect = m.indirect[0][0];
        let pi = std::f64::consts::PI;
        // Direct: every path deposits exactly its power (no variance up to the light choice).
        assert!((direct / (pi * le as f64) - 1.0).abs() < 1e-3, "direct {direct}");
        // Indirect: the number of bounces is geometric with Russian roulette from depth 5;
        // relative std of the mean ≈ 1/sqrt(N) × O(1) ⇒ 1 % is > 5σ at N = 400 k.
        let expect = pi * le as f64 * rho as f64 / (1.0 - rho as f64);
        assert!((indirect / expect - 1.0).abs() < 0.01, "indirect {indirect} vs {expect}");
    }

    /// The pass as it was before the fast paths: generic hit reconstruction (`Scene::intersect`)
    /// and BSDFs (`Scene::bsdf`), f64 sums in path order, one thread; same random streams.
    fn reference(
        scene: &Scene,
        targets: &[Option<IrradianceTarget>],
        s: &LightTraceSettings,
    ) -> Vec<Option<IrradianceMaps>> {
        let mut maps = empty_maps(targets);
        let sampler = scene.light_sampler().unwrap();
        let inv_n = 1.0 / s.paths as f64;
        for b in 0..s.paths.div_ceil(s.batch_size) {
            let mut rng = Rng::new(s.seed, 0x4c54, b);
            for _ in b * s.batch_size..((b + 1) * s.batch_size).min(s.paths) {
                let (li, pmf, _) = sampler.sample(rng.next_f32());
                let (u_pos, u_dir) = (rng.next_2d(), rng.next_2d());
                let Some(es) = scene.lights[li].sample_le(u_pos, u_dir) else { continue };
                let cos = es.ray.d.dot(es.n).abs();
                let mut beta = es.le * (cos / (pmf * es.pdf_pos * es.pdf_dir));
                let mut ray = crate::accel::spawn_ray(es.ray.o, es.n, es.ray.d);
                let mut depth = 0;
                while let Some(si) = scene.intersect(&ray) {
                    depth += 1;
                    let wo = -ray.d;
                    let shape = si.shape as usize;
                    if let (true, Some(t), Some(m)) =
                        (wo.dot(si.ng) > 0.0, &targets[shape], maps[shape].as_mut())
                    {
                        let ta = t.texel_area[(si.prim - scene.shapes[shape].first_prim) as usize];
                        let x = ((si.uv.x * t.width as f32) as i64).clamp(0, t.width as i64 - 1) as usize;
                        let y = ((si.uv.y * t.height as f32) as i64).clamp(0, t.height as i64 - 1) as usize;
                        let cell = if depth == 1 {
                            &mut m.direct[y * t.width + x]
                        } else {
                            &mut m.indirect[y * t.width + x]
                        };
                        for (a, v) in cell.iter_mut().zip(beta.to_f64()) {
                            *a += v * inv_n / ta as f64;
                        }
                    }
                    let (frame, bsdf) = scene.bsdf(&si, wo);
                    let uc = rng.next_f32();
                    let u = rng.next_2d();
                    let Some(bs) = bsdf.sample(frame.to_local(wo), uc, u, TransportMode::Importance) else {
                        break;
                    };
                    let w = bs.weight();
                    if w.is_black() {
                        break;
                    }
                    beta *= w;
                    ray = crate::accel::spawn_ray(si.p, si.ng, frame.to_world(bs.wi));
                    if depth >= s.rr_depth {
                        let q = beta_survival(beta, es.le, cos, pmf, es.pdf_pos, es.pdf_dir);
                        if rng.next_f32() >= q {
                            break;
                        }
                        beta *= 1.0 / q;
                    }
                }
            }
        }
        maps
    }

    #[test]
    fn fast_paths_and_fixed_point_match_the_generic_f64_pass_for_any_thread_count() {
        use crate::image::Image;
        use crate::scene::desc::{BitmapDesc, FilterType, WrapMode};
        // floor with a bilinear bitmap albedo, a two-sided diffuse back wall, a small light
        let img = Image {
            width: 4,
            height: 4,
            data: (0..16).map(|i| Spectrum::rgb(0.2 + 0.04 * i as f32, 0.5, 0.9 - 0.05 * i as f32)).collect(),
        };
        let tex = TextureDesc::Bitmap(BitmapDesc {
            image: std::sync::Arc::new(img),
            filter: crate::scene::desc::FilterType::Bilinear,
            wrap: WrapMode::Clamp,
            path: "albedo.exr".into(),
        });
        let _ = FilterType::Nearest;
        let quad = |p: [Vec3; 4]| TriangleMesh {
            positions: p.to_vec(),
            normals: vec![],
            uvs: vec![Vec2::new(0.0, 0.0), Vec2::new(1.0, 0.0), Vec2::new(1.0, 1.0), Vec2::new(0.0, 1.0)],
            indices: vec![[0, 1, 2], [0, 2, 3]],
        };
        let v = Vec3::new;
        let shape =
            |id: &str, mesh, bsdf, emitter| ShapeDesc { id: id.into(), mesh, bsdf, emitter, origin: None };
        let desc = SceneDesc {
            shapes: vec![
                shape("floor", floor_quad(1.0), BsdfDesc::Diffuse { reflectance: tex }, None),
                shape(
                    "wall",
                    quad([v(-1.0, 0.0, -1.0), v(1.0, 0.0, -1.0), v(1.0, 2.0, -1.0), v(-1.0, 2.0, -1.0)]),
                    BsdfDesc::TwoSided(Box::new(diffuse(0.7))),
                    None,
                ),
                shape(
                    "light",
                    quad([v(-0.3, 1.9, -0.3), v(0.3, 1.9, -0.3), v(0.3, 1.9, 0.3), v(-0.3, 1.9, 0.3)]),
                    diffuse(0.0),
                    Some(AreaEmitterDesc { radiance: Spectrum::rgb(5.0, 4.0, 3.0) }),
                ),
            ],
            ..Default::default()
        };
        let scene = Scene::build(&desc).unwrap();
        let targets = [
            Some(target(8, 1.0)),
            Some(IrradianceTarget { width: 4, height: 4, texel_area: vec![0.25; 2] }),
            None,
        ];
        let s = LightTraceSettings {
            paths: 200_000,
            batch_size: 7_000,
            rr_depth: 2,
            seed: 21,
            ..Default::default()
        };
        let want = reference(&scene, &targets, &s);
        let runs: Vec<LightTraceOutput> = [1, 2, 3]
            .iter()
            .map(|&n| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(n)
                    .build()
                    .unwrap()
                    .install(|| trace(&scene, &targets, &s, &|| {}))
            })
            .collect();
        for (k, w) in want.iter().take(2).enumerate() {
            let (w, got) = (w.as_ref().unwrap(), runs[0].maps[k].as_ref().unwrap());
            for (a, b) in [(&w.direct, &got.direct), (&w.indirect, &got.indirect)] {
                let max = a.iter().flatten().fold(0.0f64, |m, &x| m.max(x));
                assert!(max > 0.0, "shape {k}: nothing deposited");
                // Same random numbers and arithmetic: only the fixed-point rounding (≤ 2⁻²⁵ of
                // the reference deposit per deposit) and the f64 summation order differ.
                for (x, y) in a.iter().flatten().zip(b.iter().flatten()) {
                    assert!((x - y).abs() <= 1e-6 * max, "shape {k}: {x} vs {y}");
                }
            }
            for r in &runs[1..] {
                let o = r.maps[k].as_ref().unwrap();
                assert_eq!(
                    (&o.direct, &o.indirect),
                    (&got.direct, &got.indirect),
                    "thread count changed the result"
                );
            }
        }
    }

    #[test]
    fn fixed_point_overflow_is_detected_and_traced_again() {
        // Every deposit of a closed emitting box into one texel; a unit 2⁴⁰ times too fine makes
        // each deposit saturate: the pass must report it and succeed at a coarser unit, with the
        // result of the normal scale.
        let inner = inward_box();
        let desc = SceneDesc {
            shapes: vec![ShapeDesc {
                id: "box".into(),
                mesh: inner.clone(),
                bsdf: diffuse(0.5),
                emitter: Some(AreaEmitterDesc { radiance: Spectrum::splat(1.0) }),
                origin: None,
            }],
            ..Default::default()
        };
        let scene = Scene::build(&desc).unwrap();
        let texel_area: Vec<f32> = (0..inner.triangle_count()).map(|_| inner.area() as f32).collect();
        let targets = [Some(IrradianceTarget { width: 1, height: 1, texel_area })];
        let s = LightTraceSettings { paths: 20_000, seed: 2, ..Default::default() };
        let sampler = scene.light_sampler().unwrap();
        let mut shift = 40;
        let mut tries = 0;
        let out = loop {
            tries += 1;
            let fp = FixedPoint::new(&scene, &targets, s.paths, shift);
            match trace_fixed(&scene, sampler, &targets, &s, &fp, &|| {}) {
                Ok(out) => break out,
                Err(bits) => {
                    assert!(bits >= 1);
                    shift -= bits;
                }
            }
        };
        assert!(tries >= 2 && shift < 40 - 16, "overflow not detected (tries {tries}, shift {shift})");
        let want = trace(&scene, &targets, &s, &|| {});
        let (a, b) =
            (&out.maps[0].as_ref().unwrap().indirect[0][0], &want.maps[0].as_ref().unwrap().indirect[0][0]);
        assert!(*b > 0.0 && (a / b - 1.0).abs() < 1e-6, "{a} vs {b}");
    }

    #[test]
    fn i32_cells_with_spill_sum_exactly_like_i64() {
        // Random deposits into a few texels, including values that overflow a cell after a few
        // additions and values beyond i32: the cell + spill sums equal plain i64 sums.
        let mut cells = Cells::new(3 * 4);
        let mut want = [0i64; 12];
        let mut rng = Rng::new(5, 1, 0);
        let mut spilled = false;
        for n in 0..20_000u32 {
            let i = 3 * (rng.next_u32() as usize % 4);
            let scale = [1i64 << 8, 1 << 24, 1 << 30, 1 << 40][n as usize % 4];
            let v: [i64; 3] = std::array::from_fn(|_| {
                let x = (rng.next_f32() as f64 * scale as f64) as i64;
                if rng.next_f32() < 0.3 { -x } else { x }
            });
            cells.add(i, v);
            for c in 0..3 {
                want[i + c] += v[c];
            }
            spilled |= !cells.spill.is_empty();
        }
        assert!(spilled, "the test must exercise the spill map");
        for (j, w) in want.iter().enumerate() {
            assert_eq!(cells.get(j), *w, "channel {j}");
        }
    }

    #[test]
    fn without_direct_deposits_the_indirect_map_is_unchanged() {
        // Same scene as the furnace-like box test: first hits not deposited, direct map empty,
        // indirect map bitwise that of the full pass (same paths and random numbers), for 1 and 2
        // threads.
        let inner = inward_box();
        let light = {
            let mut m = floor_quad(0.3);
            for p in &mut m.positions {
                *p = Vec3::new(p.x, 0.99, p.z);
            }
            m.indices = vec![[0, 2, 1], [0, 3, 2]];
            m
        };
        let desc = SceneDesc {
            shapes: vec![
                ShapeDesc {
                    id: "box".into(),
                    mesh: inner.clone(),
                    bsdf: diffuse(0.6),
                    emitter: None,
                    origin: None,
                },
                ShapeDesc {
                    id: "light".into(),
                    mesh: light,
                    bsdf: diffuse(0.0),
                    emitter: Some(AreaEmitterDesc { radiance: Spectrum::rgb(1.0, 2.0, 3.0) }),
                    origin: None,
                },
            ],
            ..Default::default()
        };
        let scene = Scene::build(&desc).unwrap();
        let n_tris = inner.triangle_count();
        let targets = [Some(IrradianceTarget { width: 4, height: 4, texel_area: vec![0.5; n_tris] }), None];
        let full = LightTraceSettings { paths: 100_000, batch_size: 9_000, seed: 7, ..Default::default() };
        let want = trace(&scene, &targets, &full, &|| {});
        let wm = want.maps[0].as_ref().unwrap();
        assert!(
            wm.direct.iter().flatten().any(|&x| x > 0.0) && wm.indirect.iter().flatten().any(|&x| x > 0.0)
        );
        for threads in [1, 2] {
            let s = LightTraceSettings { direct: false, ..full };
            let got = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| trace(&scene, &targets, &s, &|| {}));
            let m = got.maps[0].as_ref().unwrap();
            assert!(m.direct.is_empty());
            assert_eq!((m.width, m.height), (4, 4));
            assert_eq!(m.indirect, wm.indirect, "{threads} threads");
        }
    }
}
