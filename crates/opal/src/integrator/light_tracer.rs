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
//! Determinism: path `i` draws its numbers from its own generator, `Rng::new(seed, 0x4c54, i)`;
//! paths are handed to the workers in batches of `batch_size`. The result depends on
//! `(seed, paths)` only, never on the thread count, the batch size or the order in which the
//! paths are traced.
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
//! short per-worker queue that prefetches their texel. When every material is Lambertian and
//! the CPU has AVX2, eight paths advance together (`Wavefront`, state as structure of arrays):
//! one step traces the eight rays, applies the pending weights, loads the hit triangles' data
//! (eight rows transposed), computes the deposits' texels and integer units and scatters the
//! eight vertices in SIMD (the roulette, the random numbers and the queue pushes stay per
//! lane); lanes whose next vertex faces the roulette settle their weight and draw it before
//! their ray is traced (a path the roulette ends traces no ray for nothing; same draws in the
//! same order); finished lanes are refilled from path starts prepared eight at a time
//! (triangle lights in SIMD) — each
//! path is bit for bit the one `trace_path` traces alone (its own generator, same operations),
//! so only the order of the integer deposits changes. In scenes of up to `TINY_MAX` triangles
//! the eight rays are traced together, one per SIMD lane
//! ([`crate::accel::packet::PacketAccel`], same hits as [`crate::accel::TinyAccel`]);
//! otherwise through `Scene::intersect_hit`.
//!
//! Tests (below): a quad under a point light (E = I cos θ / d², analytic) and a quad under a
//! small area light against a quadrature of ∫ L cos dω; indirect light in a closed furnace-like
//! box against the path tracer's estimate; thread-count independence; the fast paths and the
//! fixed-point sums against the generic f64 pass (a bitmap-textured floor, a two-sided wall
//! with corner normals, Russian roulette, an area and a point light) to 10⁻⁶, identical for 1, 2 and 3 threads and for the three engines
//! (wavefront with ray packets, wavefront with one ray per lane, one path at a time); the `i32` cells with spill
//! against plain `i64` sums (random deposits up to 2⁴⁰ units); `direct: false` leaves the
//! indirect map bitwise unchanged.

use crate::accel::Hit;
use crate::accel::packet::{PacketAccel, PacketHits, RayPacket};
use crate::bsdf::{Bxdf, TransportMode};
use crate::geometry::Ray;
use crate::math::{Frame, INV_PI, Vec2, Vec3};
use crate::sampling::{Rng, RngStream, square_to_cosine_hemisphere, square_to_cosine_hemisphere_pdf};
use crate::scene::{Material, Scene};
use crate::spectrum::Spectrum;
use crate::texture::Texture;
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
    /// Paths per batch (the unit of work handed to a thread; the result does not depend on it).
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
                Ok(x) => add_cell(&mut cell[c], x, &mut self.spill, n, i + c),
                Err(_) => spill_add(&mut self.spill, n, i + c, v[c]),
            }
        }
    }

    /// Adds `v` (`i32` units) to channels `i..i + 3` (as [`Cells::add`]).
    #[inline(always)]
    fn add32(&mut self, i: usize, v: [i32; 3]) {
        let n = self.fine.len();
        let cell = &mut self.fine[i..i + 3];
        for c in 0..3 {
            add_cell(&mut cell[c], v[c], &mut self.spill, n, i + c);
        }
    }

    /// The sum of channel `j` (wrapping: exact while no texel's true sum reaches 2⁶³).
    #[inline]
    fn get(&self, j: usize) -> i64 {
        (self.fine[j] as i64).wrapping_add(self.spill.get(j).copied().unwrap_or(0))
    }
}

/// Adds `x` to `cell`, channel `j` of a map of `n` channels: a cell that would overflow moves
/// its content to the spill map first.
#[inline(always)]
fn add_cell(cell: &mut i32, x: i32, spill: &mut Vec<i64>, n: usize, j: usize) {
    match cell.checked_add(x) {
        Some(y) => *cell = y,
        None => {
            let old = std::mem::replace(cell, x);
            spill_add(spill, n, j, old as i64);
        }
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
        match trace_fixed(scene, sampler, targets, s, &fp, on_batch, Engine::Auto) {
            Ok(out) => return out,
            // Some shape's deposits summed to ≥ 2⁶³ units: a texel may have overflowed. Trace
            // again with a coarser unit (never seen in practice; the result stays deterministic
            // since the decision depends on exact integer sums only).
            Err(bits) => shift -= bits,
        }
    }
}

/// How the paths are traced (tests compare the three; results are identical).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Engine {
    /// The wavefront when every material is Lambertian (rays traced as [`RayPacket`]s in scenes
    /// of up to `TINY_MAX` triangles), else one path at a time.
    Auto,
    /// The wavefront with one `Scene::intersect_hit` per lane.
    #[cfg_attr(not(test), allow(dead_code))]
    WavefrontRays,
    /// One path at a time ([`trace_path`]).
    #[cfg_attr(not(test), allow(dead_code))]
    Scalar,
}

/// One pass at a fixed-point scale; `Err(bits)` when the scale must shrink by `2^bits`.
fn trace_fixed(
    scene: &Scene,
    sampler: &crate::light::LightSampler,
    targets: &[Option<IrradianceTarget>],
    s: &LightTraceSettings,
    fp: &FixedPoint,
    on_batch: &(dyn Fn() + Sync),
    engine: Engine,
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
    let stream = RngStream::new(s.seed, RNG_STREAM);
    // Scenes whose every triangle is Lambertian advance eight paths at a time (same paths,
    // same numbers, same bits as one at a time: see `Wavefront`).
    let wavefront = if engine == Engine::Scalar || !Wavefront::available() {
        None
    } else {
        LambertTable::new(scene, &prims)
    };
    // Small scenes: the wavefront's eight rays are traced together, one per SIMD lane.
    let packet = if wavefront.is_some() && engine == Engine::Auto { scene.packet() } else { None };
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
                let paths = b * batch..((b + 1) * batch).min(s.paths);
                let mut ctx = PathCtx { scene, sampler, prims: &prims, sink: &mut sink, s, bad: &mut bad };
                if let Some(tab) = &wavefront {
                    Wavefront::run(&mut ctx, tab, &stream, paths, packet);
                } else {
                    for i in paths {
                        trace_path(&mut ctx, stream.rng(i));
                    }
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
    Diffuse { tex: &'a Texture, two_sided: bool },
    /// Anything else: `Scene::bsdf`.
    Generic,
}

/// Per-triangle data precomputed for the hit reconstruction (same formulas as
/// `Scene::interaction` and `Scene::bsdf`, evaluated once per triangle instead of per hit).
#[derive(Clone, Copy)]
struct Prim<'a> {
    /// Unit geometric normal.
    ng: Vec3,
    /// `ng.normalize_or_zero()`: the normal [`super::offset_ray_origin`] offsets along.
    ng_off: Vec3,
    /// Corner uvs (zeros without uvs).
    uv: [Vec2; 3],
    /// Corner shading normals, when the mesh has them.
    normals: Option<[Vec3; 3]>,
    shape: u32,
    /// Fixed-point units per unit of β for a deposit (0 = no deposit).
    factor: f64,
    /// `ρ · 1/π` of a Lambertian material with a constant reflectance ρ.
    kd_pi: Option<Spectrum>,
    /// Deposit map size (texels).
    width: u32,
    height: u32,
    mat: Mat<'a>,
}

fn prims<'a>(scene: &'a Scene, targets: &[Option<IrradianceTarget>], fp: &FixedPoint) -> Vec<Prim<'a>> {
    let mut out = Vec::with_capacity(fp.factor.len());
    for (k, sh) in scene.shapes.iter().enumerate() {
        let m = &sh.mesh;
        let mat = match &sh.material {
            Material::Diffuse { reflectance, two_sided } => {
                Mat::Diffuse { tex: reflectance, two_sided: *two_sided }
            }
            Material::Model { .. } => Mat::Generic,
        };
        let (width, height) = targets[k].as_ref().map_or((0, 0), |t| (t.width as u32, t.height as u32));
        for (j, idx) in m.indices.iter().enumerate() {
            let [i0, i1, i2] = idx.map(|i| i as usize);
            let (p0, p1, p2) = (m.positions[i0], m.positions[i1], m.positions[i2]);
            let ng = (p1 - p0).cross(p2 - p0).normalize();
            out.push(Prim {
                ng,
                ng_off: ng.normalize_or_zero(),
                uv: if m.uvs.is_empty() { [Vec2::ZERO; 3] } else { [m.uvs[i0], m.uvs[i1], m.uvs[i2]] },
                normals: (!m.normals.is_empty()).then(|| [m.normals[i0], m.normals[i1], m.normals[i2]]),
                shape: k as u32,
                factor: fp.factor[sh.first_prim as usize + j],
                kd_pi: match mat {
                    Mat::Diffuse { tex: Texture::Constant(c), .. } => Some(*c * INV_PI),
                    _ => None,
                },
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
        tex: &'a Texture,
        uv: Vec2,
        ratio: f32,
    },
    /// Lambert with a constant reflectance ρ: `(ρ · 1/π) · ratio` (`kd_pi` = ρ · 1/π, the same
    /// product as in `Lambert`, evaluated once per triangle).
    LambertConst {
        kd_pi: Spectrum,
        ratio: f32,
    },
}

impl<'a> Weight<'a> {
    /// The weight of a Lambertian vertex of triangle `pr` at `uv` with `ratio = |cos θi| / pdf`;
    /// a bitmap's texels are prefetched for the lookup in [`Weight::get`].
    #[inline]
    fn lambert(pr: &Prim<'a>, tex: &'a Texture, uv: Vec2, ratio: f32) -> Self {
        match pr.kd_pi {
            Some(kd_pi) => Weight::LambertConst { kd_pi, ratio },
            None => {
                prefetch_texture(tex, uv);
                Weight::Lambert { tex, uv, ratio }
            }
        }
    }

    #[inline]
    fn get(self) -> Spectrum {
        match self {
            Weight::Known(w) => w,
            Weight::Lambert { tex, uv, ratio } => (tex.eval(uv) * INV_PI) * ratio,
            Weight::LambertConst { kd_pi, ratio } => kd_pi * ratio,
        }
    }
}

/// Hints the cache lines of a bitmap lookup at `uv` (no effect on results).
#[inline]
fn prefetch_texture(tex: &Texture, uv: Vec2) {
    if let Texture::Bitmap(b) = tex {
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

/// Random stream of the light paths: path `i` draws from `RngStream::new(seed, RNG_STREAM).rng(i)`.
const RNG_STREAM: u64 = 0x4c54;

/// What every path of a pass shares.
struct PathCtx<'a, 'b> {
    scene: &'a Scene,
    sampler: &'a crate::light::LightSampler,
    prims: &'b [Prim<'a>],
    sink: &'b mut Sink,
    s: &'b LightTraceSettings,
    /// Non-finite deposits dropped.
    bad: &'b mut u64,
}

/// A path between two vertices: the ray to trace next, the weight β, the roulette's reference
/// weight and the scattering weight of the last vertex, applied after the ray is traced so that
/// the texture lookup's cache miss overlaps the traversal.
struct PathState<'a> {
    rng: Rng,
    ray: Ray,
    beta: Spectrum,
    /// `max_c β_c` at the light: the roulette survives with `min(max_c β_c / b0, 0.95)`.
    b0: f32,
    depth: i32,
    pending: Option<Weight<'a>>,
}

/// Starts a path: light chosen by power, emitted ray (offset off area lights), initial weight
/// `β = Le·cos/(pmf·pdf_pos·pdf_dir)`. `None` when the sample carries nothing.
#[inline]
fn start_path<'a>(
    scene: &Scene,
    sampler: &crate::light::LightSampler,
    mut rng: Rng,
) -> Option<PathState<'a>> {
    let (li, pmf, _) = sampler.sample(rng.next_f32());
    let (u_pos, u_dir) = (rng.next_2d(), rng.next_2d());
    let es = scene.lights[li].sample_le(u_pos, u_dir)?;
    if pmf <= 0.0 || es.pdf_pos <= 0.0 || es.pdf_dir <= 0.0 {
        return None;
    }
    let cos = if es.n == Vec3::ZERO { 1.0 } else { es.ray.d.dot(es.n).abs() };
    let beta = es.le * (cos / (pmf * es.pdf_pos * es.pdf_dir));
    let mut ray = es.ray;
    // emitted rays of area lights start on the surface: offset them
    if es.n != Vec3::ZERO {
        ray = super::spawn_ray(ray.o, es.n, ray.d);
    }
    Some(PathState { rng, ray, beta, b0: beta.max_component(), depth: 0, pending: None })
}

/// A surface hit ready to scatter (see [`vertex`]).
struct Vertex<'p, 'a> {
    pr: &'p Prim<'a>,
    hit: Hit,
    /// Interpolated texture coordinates.
    uv: Vec2,
    /// `1 − b1 − b2`.
    b0: f32,
}

/// Everything of a path step up to the scattering: applies the pending weight of the previous
/// vertex and the Russian roulette (after the ray `st.ray` was traced, with result `hit`), then
/// counts the new vertex and deposits it. `None` when the path ends.
#[inline(always)]
fn vertex<'p, 'a>(
    ctx: &mut PathCtx<'a, 'p>,
    st: &mut PathState<'a>,
    hit: Option<Hit>,
) -> Option<Vertex<'p, 'a>> {
    let s = ctx.s;
    if let Some(w) = st.pending.take() {
        let w = w.get();
        if w.is_black() {
            return None;
        }
        st.beta *= w;
        if s.rr_depth >= 0 && st.depth >= s.rr_depth {
            let q = survival(st.beta, st.b0);
            if st.rng.next_f32() >= q {
                return None;
            }
            st.beta *= 1.0 / q;
        }
    }
    let h = hit?;
    st.depth += 1;
    let prims: &'p [Prim<'a>] = ctx.prims;
    let pr = &prims[h.prim as usize];
    let b0 = 1.0 - h.b1 - h.b2;
    let uv = pr.uv[0] * b0 + pr.uv[1] * h.b1 + pr.uv[2] * h.b2;
    if (-st.ray.d).dot(pr.ng) > 0.0 {
        deposit(ctx.sink, ctx.bad, s, pr, uv, st.beta, st.depth);
    }
    if s.max_depth >= 0 && st.depth >= s.max_depth {
        return None;
    }
    Some(Vertex { pr, hit: h, uv, b0 })
}

/// The deposit of a path of weight `beta` reaching the front side of triangle `pr` at `uv` as
/// its vertex number `depth` (none for triangles without a map and, unless `s.direct`, for
/// first hits); a non-finite weight is counted in `bad` instead.
#[inline(always)]
fn deposit(
    sink: &mut Sink,
    bad: &mut u64,
    s: &LightTraceSettings,
    pr: &Prim,
    uv: Vec2,
    beta: Spectrum,
    depth: i32,
) {
    if !(pr.factor > 0.0 && (depth > 1 || s.direct)) {
        return;
    }
    let (w, hgt) = (pr.width as usize, pr.height as usize);
    let x = ((uv.x * w as f32) as i64).clamp(0, w as i64 - 1) as usize;
    let y = ((uv.y * hgt as f32) as i64).clamp(0, hgt as i64 - 1) as usize;
    let e = beta.to_f64();
    if e.iter().all(|v| v.is_finite()) {
        // round half away from zero (`as` saturates: an absurd deposit then shows in the
        // overflow check)
        let value = e.map(|v| {
            let q = v * pr.factor;
            (q + 0.5f64.copysign(q)) as i64
        });
        sink.push(Pending { shape: pr.shape as usize, index: 3 * (y * w + x), direct: depth == 1, value });
    } else {
        *bad += 1;
    }
}

/// Traces one light path (one vertex at a time; any material).
///
/// The texel of a deposit is a random location in maps of up to millions of texels: a cache and
/// TLB miss. Deposits therefore go through the worker's queue ([`Sink`]), which prefetches them
/// and adds them [`QUEUE`] deposits later (integer sums: the order of additions does not matter).
/// Likewise the albedo lookup of a Lambertian vertex (its sampled direction does not depend on
/// the albedo), and with it the Russian roulette, which consumes its random number after the
/// vertex's direction sample: a path killed by the roulette has traced one ray for nothing
/// (from `rr_depth` on only).
#[inline]
fn trace_path(ctx: &mut PathCtx, rng: Rng) {
    let Some(mut st) = start_path(ctx.scene, ctx.sampler, rng) else { return };
    loop {
        let hit = ctx.scene.intersect_hit(&st.ray);
        let Some(v) = vertex(ctx, &mut st, hit) else { break };
        let (pr, h) = (v.pr, v.hit);
        let wo = -st.ray.d;
        let p = st.ray.at(h.t);
        match pr.mat {
            Mat::Diffuse { tex, two_sided } => {
                let ns = match pr.normals {
                    None => pr.ng,
                    Some([n0, n1, n2]) => {
                        let n = n0 * v.b0 + n1 * h.b1 + n2 * h.b2;
                        let l = n.length();
                        if l > 0.0 { n / l } else { pr.ng }
                    }
                };
                let n = if two_sided && wo.dot(pr.ng) < 0.0 { -ns } else { ns };
                let frame = Frame::from_normal(n);
                // `Lambert::sample`, in world space
                let _uc = st.rng.next_f32(); // drawn for the generic sampler: same streams
                let u: Vec2 = st.rng.next_2d();
                if wo.dot(frame.n) <= 0.0 {
                    break;
                }
                let wi = square_to_cosine_hemisphere(u);
                let pdf = square_to_cosine_hemisphere_pdf(wi);
                if pdf <= 0.0 {
                    break;
                }
                st.pending = Some(Weight::lambert(pr, tex, v.uv, wi.z.abs() / pdf));
                st.ray = super::spawn_ray(p, pr.ng, frame.to_world(wi));
            }
            Mat::Generic => {
                let si = ctx.scene.interaction(&st.ray, &h);
                let (frame, bsdf) = ctx.scene.bsdf(&si, wo);
                let wo_l = frame.to_local(wo);
                let uc = st.rng.next_f32();
                let u: Vec2 = st.rng.next_2d();
                let Some(bs) = bsdf.sample(wo_l, uc, u, TransportMode::Importance) else { break };
                st.pending = Some(Weight::Known(bs.weight()));
                st.ray = super::spawn_ray(si.p, si.ng, frame.to_world(bs.wi));
            }
        }
    }
}

/// Paths advanced together by [`Wavefront`] (one per SIMD lane).
const W: usize = 8;

/// Inputs of the Lambertian scattering of [`W`] vertices, one per lane (structure of arrays),
/// besides the rays that reached them.
#[derive(Clone, Copy, Default)]
struct ScatterIn {
    /// Hit distance along the lane's ray (the vertex is `o + d·t`).
    t: [f32; W],
    /// Unit geometric normal and its re-normalised copy for the ray offset.
    ng: [[f32; W]; 3],
    ng_off: [[f32; W]; 3],
    /// Corner shading normals (`has_n` = the mesh has normals), barycentrics.
    n: [[[f32; W]; 3]; 3],
    has_n: [u32; W],
    two_sided: [u32; W],
    b: [[f32; W]; 3],
    /// The direction sample.
    u: [[f32; W]; 2],
}

/// Outputs: the next ray and the ratio `|cos θi| / pdf`; `valid` = 0 where the path ends.
#[derive(Clone, Copy, Default)]
struct ScatterOut {
    o: [[f32; W]; 3],
    d: [[f32; W]; 3],
    ratio: [f32; W],
    valid: [u32; W],
}

/// `[f(0), f(1), f(2)]`. In the SIMD kernels instead of `std::array::from_fn`, whose closure
/// wrappers the compiler kept out of line, compiled without AVX2 (SSE halves through memory).
#[inline(always)]
fn each3<T>(f: impl Fn(usize) -> T) -> [T; 3] {
    [f(0), f(1), f(2)]
}

/// `square_to_cosine_hemisphere(u)` on [`W`] lanes (concentric map with
/// `fastmath::sincos_2pi`, selects for its branches): `[x, y, z]`, the same bits per lane.
#[inline(always)]
fn cosine_hemisphere_lanes(
    ux: crate::fastmath::wide::F<W>,
    uy: crate::fastmath::wide::F<W>,
) -> [crate::fastmath::wide::F<W>; 3] {
    use crate::fastmath::wide::{self, F};
    let zero = F::<W>::splat(0.0);
    let ox = 2.0 * ux - 1.0;
    let oy = 2.0 * uy - 1.0;
    let at_centre = ox.eq(zero) & oy.eq(zero);
    let wide_x = ox.abs().gt(oy.abs());
    let r = wide_x.select(ox, oy);
    let turns = wide_x.select((oy / ox) * 0.125, 0.25 - (ox / oy) * 0.125);
    let (sn, cs) = wide::sincos_2pi(turns);
    let dx = at_centre.select(zero, r * cs);
    let dy = at_centre.select(zero, r * sn);
    [dx, dy, (1.0 - (dx * dx + dy * dy)).max(zero).sqrt()]
}

/// [`super::offset_ray_origin`]`(p, n, dir)` on [`W`] lanes, `n_off` being the normal's
/// `normalize_or_zero` (the same bits per lane).
#[inline(always)]
fn offset_lanes(
    p: [crate::fastmath::wide::F<W>; 3],
    n_off: [crate::fastmath::wide::F<W>; 3],
    dir: [crate::fastmath::wide::F<W>; 3],
) -> [crate::fastmath::wide::F<W>; 3] {
    let pa = [p[0].abs(), p[1].abs(), p[2].abs()];
    let mx = pa[1].gt(pa[2]).select(pa[1], pa[2]);
    let mx = pa[0].gt(mx).select(pa[0], mx);
    let mag = (1.0 + mx) * crate::accel::triangle::RAY_OFFSET_SCALE;
    let towards = ((n_off[0] * dir[0] + n_off[1] * dir[1]) + n_off[2] * dir[2])
        .ge(crate::fastmath::wide::F::splat(0.0));
    let mag = towards.select(mag, -mag);
    each3(|c| p[c] + n_off[c] * mag)
}

/// The Lambertian scattering of [`trace_path`] on [`W`] lanes: the same operations in the same
/// order (`glam`'s component formulas, [`Frame::from_normal`], the concentric map with
/// `fastmath::sincos_2pi`, [`super::offset_ray_origin`]), with selects for branches, hence the
/// same bits in every lane (no fused multiply-add is ever formed).
#[inline(always)]
fn scatter_lanes<const NORMALS: bool>(rays: &RayPacket, i: &ScatterIn) -> ScatterOut {
    use crate::fastmath::wide::{F, M};
    type V = [F<W>; 3];
    let ld = |a: &[[f32; W]; 3]| -> V { [F(a[0]), F(a[1]), F(a[2])] };
    let dot = |a: V, b: V| (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2];
    let sel =
        |m: M<W>, a: V, b: V| -> V { [m.select(a[0], b[0]), m.select(a[1], b[1]), m.select(a[2], b[2])] };
    let zero = F::<W>::splat(0.0);
    let (o, d, t) = (ld(&rays.o), ld(&rays.d), F(i.t));
    let (ng, ng_off) = (ld(&i.ng), ld(&i.ng_off));
    let (b0, b1, b2) = (F(i.b[0]), F(i.b[1]), F(i.b[2]));
    let p: V = [o[0] + d[0] * t, o[1] + d[1] * t, o[2] + d[2] * t];
    let wo: V = [-d[0], -d[1], -d[2]];
    // shading normal: interpolated and normalised when the mesh has normals
    // (without `NORMALS` no lane has normals: the select below would pick `ng` everywhere)
    let ns = if NORMALS {
        let (n0, n1, n2) = (ld(&i.n[0]), ld(&i.n[1]), ld(&i.n[2]));
        let ni: V = each3(|c| n0[c] * b0 + n1[c] * b1 + n2[c] * b2);
        let len = dot(ni, ni).sqrt();
        let use_ni = M(i.has_n) & len.gt(zero);
        sel(use_ni, [ni[0] / len, ni[1] / len, ni[2] / len], ng)
    } else {
        ng
    };
    let flip = M(i.two_sided) & dot(wo, ng).lt(zero);
    let n: V = [flip.neg_where(ns[0]), flip.neg_where(ns[1]), flip.neg_where(ns[2])];
    // Frame::from_normal
    let sign = F::splat(1.0).copysign(n[2]);
    let a = F::splat(-1.0) / (sign + n[2]);
    let bb = n[0] * n[1] * a;
    let fs: V = [1.0 + sign * n[0] * n[0] * a, sign * bb, -sign * n[0]];
    let ft: V = [bb, sign + n[1] * n[1] * a, -n[1]];
    let mut valid = dot(wo, n).gt(zero);
    let [dx, dy, z] = cosine_hemisphere_lanes(F(i.u[0]), F(i.u[1]));
    let pdf = z.gt(zero).select(z * crate::math::INV_PI, zero);
    valid = valid & pdf.gt(zero);
    let ratio = z.abs() / pdf;
    // Frame::to_world
    let dir: V = each3(|c| (fs[c] * dx + ft[c] * dy) + n[c] * z);
    let o = offset_lanes(p, ng_off, dir);
    let mut out = ScatterOut::default();
    for c in 0..3 {
        out.o[c] = o[c].0;
        out.d[c] = dir[c].0;
    }
    out.ratio = ratio.0;
    out.valid = valid.0;
    out
}

/// [`W`] light paths advanced together (scenes whose materials are all Lambertian).
///
/// Each lane holds one path; the whole state is kept as a structure of arrays ([`Lanes`]). A
/// step traces every lane's ray, applies the pending albedo weights, loads the hit triangles'
/// data, deposits, draws the direction samples, scatters all lanes at once with
/// [`scatter_lanes`] (which writes the next rays in place), settles the weight and draws the
/// roulette of the lanes whose next vertex faces it ([`Lanes::settle`], before their ray is
/// traced), and refills the lanes whose path ended with the next path of the batch. The
/// per-lane arithmetic is in AVX2 functions (`avx`) with selects instead of branches, so no unpredictable
/// branch (alive or dead, bitmap or constant albedo, roulette) is taken per lane; the parts that
/// only some lanes need (bitmap lookups, roulette numbers, deposits, new paths) loop over the
/// set bits of a lane mask. A path draws its numbers from its own generator in the same order
/// as [`trace_path`] and every value is computed with the same operations, so each path is
/// exactly the path `trace_path` would trace: only the order of the deposits changes, which
/// integer sums ignore (test: identical sums for the three engines).
struct Wavefront;

/// Per-triangle data of the wavefront (see [`Prim`]), one row of 32 floats per triangle so a
/// lane's value is one load at a fixed offset (fields: the `ROW_*` constants).
#[derive(Clone, Copy)]
#[repr(C, align(64))]
struct Row([f32; 32]);

/// Offsets in a [`Row`]: unit geometric normal, its offset copy, corner uvs `(u0, v0, u1, …)`,
/// `kd_pi` (ρ/π of a constant reflectance, zero for a bitmap) and the flags (bits of a `u32`:
/// [`FLAG_TWO_SIDED`], [`FLAG_BITMAP`]) fill the first 16 floats, which [`avx::vertices`] reads
/// with two 8×8 transposes; then corner normals (9, zero without normals) and "has normals"
/// (all bits set = true).
const ROW_NG: usize = 0;
const ROW_NG_OFF: usize = 3;
const ROW_UV: usize = 6;
const ROW_KD: usize = 12;
const ROW_FLAGS: usize = 15;
const ROW_N: usize = 16;
const ROW_HAS_N: usize = 25;
/// Deposit map width and height (as f32, exact: maps are at most 4096 texels wide).
const ROW_SIZE: usize = 26;
/// The shape (bits of an `i32`) of a triangle whose hits deposit (`factor > 0`), else −1.
const ROW_SHAPE: usize = 28;
/// Bits of [`ROW_FLAGS`]: two-sided material, bitmap reflectance.
const FLAG_TWO_SIDED: u32 = 1;
const FLAG_BITMAP: u32 = 2;

/// The wavefront's triangle table: rows, the bitmap of each triangle with a bitmap
/// reflectance, and whether any triangle has corner normals.
struct LambertTable<'a> {
    rows: Vec<Row>,
    tex: Vec<Option<&'a Texture>>,
    any_normals: bool,
    /// Deposit factors ([`Prim::factor`]).
    factor: Vec<f64>,
    /// Whether every map is small enough for [`avx::deposit_values`] (sizes exact in f32,
    /// `3·w·h` in i32); otherwise every deposit takes [`deposit`].
    vector_deposits: bool,
    /// The scene's lights as the path starts need them ([`light_rows`]).
    lights: Vec<Option<LightRow>>,
}

impl<'a> LambertTable<'a> {
    /// `None` unless every triangle is Lambertian.
    fn new(scene: &Scene, prims: &[Prim<'a>]) -> Option<LambertTable<'a>> {
        let flag = |b: bool| f32::from_bits(if b { u32::MAX } else { 0 });
        let mut rows = Vec::with_capacity(prims.len());
        let mut tex = Vec::with_capacity(prims.len());
        for p in prims {
            let Mat::Diffuse { tex: t, two_sided } = p.mat else { return None };
            let mut r = [0.0f32; 32];
            for c in 0..3 {
                r[ROW_NG + c] = p.ng[c];
                r[ROW_NG_OFF + c] = p.ng_off[c];
                r[ROW_KD + c] = p.kd_pi.map_or(0.0, |k| k[c]);
                for k in 0..3 {
                    r[ROW_N + 3 * k + c] = p.normals.map_or(0.0, |n| n[k][c]);
                }
            }
            for k in 0..3 {
                r[ROW_UV + 2 * k] = p.uv[k].x;
                r[ROW_UV + 2 * k + 1] = p.uv[k].y;
            }
            r[ROW_HAS_N] = flag(p.normals.is_some());
            let flags =
                if two_sided { FLAG_TWO_SIDED } else { 0 } | if p.kd_pi.is_none() { FLAG_BITMAP } else { 0 };
            r[ROW_FLAGS] = f32::from_bits(flags);
            r[ROW_SIZE] = p.width as f32;
            r[ROW_SIZE + 1] = p.height as f32;
            r[ROW_SHAPE] = f32::from_bits(if p.factor > 0.0 { p.shape } else { u32::MAX });
            rows.push(Row(r));
            tex.push(p.kd_pi.is_none().then_some(t));
        }
        let any_normals = prims.iter().any(|p| p.normals.is_some());
        let factor = prims.iter().map(|p| p.factor).collect();
        let vector_deposits = prims.iter().all(|p| {
            p.width <= 1 << 16
                && p.height <= 1 << 16
                && 3 * p.width as u64 * p.height as u64 <= i32::MAX as u64
        });
        Some(LambertTable { rows, tex, any_normals, factor, vector_deposits, lights: light_rows(scene) })
    }
}

/// The state of the [`W`] lanes of a [`Wavefront`] (structure of arrays): lane `l` holds a path
/// iff bit `l` of `active` is set.
struct Lanes<'a> {
    /// The rays to trace next (inactive lanes: `tmax = 0`, never hit).
    rays: RayPacket,
    /// Each lane's generator, as structure of arrays (state, increment: see [`Rng`]), so the
    /// direction samples are drawn for all lanes at once ([`avx::next_f32_lanes`]).
    rng_state: [u64; W],
    rng_inc: [u64; W],
    /// Path weights β.
    beta: [[f32; W]; 3],
    /// `max_c β_c` at the light (the roulette's reference, see [`survival`]).
    b0: [f32; W],
    /// Vertices so far.
    depth: [i32; W],
    /// Lanes whose last vertex's weight `kd_pi · ratio` is still to be applied (after the
    /// trace, so a bitmap lookup's cache miss overlaps it); lanes in `bitmap` look `kd_pi` up
    /// in `tex` at `uv` first.
    pending: u32,
    bitmap: u32,
    ratio: [f32; W],
    kd_pi: [[f32; W]; 3],
    tex: [Option<&'a Texture>; W],
    uv: [Vec2; W],
    active: u32,
}

impl Lanes<'_> {
    /// `vertex`'s pending weights `kd_pi · ratio` (bitmap albedos looked up first) and, from
    /// `rr_depth` on, the roulette of the lanes in `m`; they are no longer pending. Returns the
    /// lanes whose path ends.
    #[inline(always)]
    fn settle(&mut self, m: u32, rr_depth: i32) -> u32 {
        for l in lanes_of(m & self.bitmap) {
            let tex = self.tex[l].expect("bitmap lanes hold their texture");
            let k = tex.eval(self.uv[l]) * INV_PI;
            for c in 0..3 {
                self.kd_pi[c][l] = k[c];
            }
        }
        // SAFETY: the wavefront runs on CPUs with AVX2 only (`Wavefront::available`).
        let black = unsafe { avx::pending_weights(&mut self.beta, &self.kd_pi, &self.ratio, m) };
        let mut dead = m & black;
        if rr_depth >= 0 {
            for l in lanes_of(m & !dead & mask(|l| self.depth[l] >= rr_depth)) {
                let beta = Spectrum([self.beta[0][l], self.beta[1][l], self.beta[2][l]]);
                let q = survival(beta, self.b0[l]);
                let mut rng = Rng { state: self.rng_state[l], inc: self.rng_inc[l] };
                let u = rng.next_f32();
                self.rng_state[l] = rng.state;
                if u >= q {
                    dead |= 1 << l;
                } else {
                    let beta = beta * (1.0 / q);
                    for c in 0..3 {
                        self.beta[c][l] = beta[c];
                    }
                }
            }
        }
        self.pending &= !m;
        dead
    }
}

/// Indices of the set bits of `m`, lowest first.
#[inline(always)]
fn lanes_of(mut m: u32) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        (m != 0).then(|| {
            let l = m.trailing_zeros() as usize;
            m &= m - 1;
            l
        })
    })
}

impl<'a> Lanes<'a> {
    /// Puts a new path into lane `l`.
    #[inline]
    fn start(&mut self, l: usize, b: &StartBlock, k: usize) {
        for c in 0..3 {
            self.rays.o[c][l] = b.o[c][k];
            self.rays.d[c][l] = b.d[c][k];
            self.beta[c][l] = b.beta[c][k];
        }
        self.rays.tmax[l] = f32::INFINITY;
        self.b0[l] = Spectrum([b.beta[0][k], b.beta[1][k], b.beta[2][k]]).max_component();
        self.depth[l] = 0;
        self.rng_state[l] = b.rng[k].state;
        self.rng_inc[l] = b.rng[k].inc;
        self.active |= 1 << l;
        self.pending &= !(1 << l);
        self.bitmap &= !(1 << l);
    }
}

/// What [`avx::deposit_values`] computes: texel index and units of each lane, the lanes whose
/// units are below 2³¹ in magnitude (`small`: the others are left to [`deposit`]), and the
/// triangle's shape when its hits deposit (else −1).
struct DepositLanes {
    index: [i32; W],
    value: [[i64; W]; 3],
    small: u32,
    shape: [i32; W],
}

/// What [`avx::vertices`] computes besides the kernel's inputs.
#[derive(Clone, Copy)]
struct VertexLanes {
    /// Interpolated texture coordinates.
    uv: [[f32; W]; 2],
    /// `kd_pi` of the triangles (zero for bitmaps).
    kd_pi: [[f32; W]; 3],
    /// Lanes that hit a front side; lanes whose triangle has a bitmap reflectance.
    front: u32,
    bitmap: u32,
}

/// The vector steps of the [`Wavefront`] in AVX2: the same IEEE operations in the same order as
/// the scalar code they mirror (named on each function), hence the same bits.
#[cfg(target_arch = "x86_64")]
mod avx {
    use super::{
        FLAG_BITMAP, FLAG_TWO_SIDED, ROW_FLAGS, ROW_HAS_N, ROW_KD, ROW_N, ROW_NG, ROW_NG_OFF, ROW_SHAPE,
        ROW_SIZE, ROW_UV,
    };
    use super::{PacketHits, RayPacket, Row, ScatterIn, VertexLanes, W};
    use std::arch::x86_64::*;

    #[inline(always)]
    fn ld(a: &[f32; W]) -> __m256 {
        // SAFETY: 8 floats, unaligned load.
        unsafe { _mm256_loadu_ps(a.as_ptr()) }
    }
    #[inline(always)]
    fn st(a: &mut [f32; W], v: __m256) {
        // SAFETY: 8 floats, unaligned store.
        unsafe { _mm256_storeu_ps(a.as_mut_ptr(), v) }
    }
    #[inline(always)]
    fn st_mask(a: &mut [u32; W], v: __m256) {
        // SAFETY: 8 u32, unaligned store.
        unsafe { _mm256_storeu_ps(a.as_mut_ptr().cast(), v) }
    }
    /// Lane `l` all ones iff bit `l` of `b`.
    #[target_feature(enable = "avx2")]
    #[inline]
    pub(super) fn lane_mask(b: u32) -> __m256 {
        let one = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
        _mm256_castsi256_ps(_mm256_cmpeq_epi32(_mm256_and_si256(_mm256_set1_epi32(b as i32), one), one))
    }
    #[target_feature(enable = "avx2")]
    #[inline]
    fn bits(m: __m256) -> u32 {
        _mm256_movemask_ps(m) as u32
    }

    /// [`crate::sampling::Rng::next_f32`] of the eight generators `(state, inc)` whose lane is in
    /// `m` (the others keep their state; their numbers are meaningless): the same 64-bit
    /// arithmetic (the product modulo 2⁶⁴ from three 32×32-bit products), output permutation
    /// and conversion, hence the same numbers.
    #[target_feature(enable = "avx2")]
    #[inline]
    pub(super) fn next_f32_lanes(state: &mut [u64; W], inc: &[u64; W], m: u32) -> [f32; W] {
        let mult = crate::sampling::Rng::MULT;
        let (m_lo, m_hi) = (_mm256_set1_epi64x(mult as i64), _mm256_set1_epi64x((mult >> 32) as i64));
        let low32 = _mm256_set1_epi64x(0xffff_ffff);
        let mut out = [_mm256_setzero_si256(); 2];
        for (h, o) in out.iter_mut().enumerate() {
            // SAFETY: 4 u64 of an 8-u64 array, unaligned loads and store.
            let old = unsafe { _mm256_loadu_si256(state.as_ptr().add(4 * h).cast()) };
            let inc = unsafe { _mm256_loadu_si256(inc.as_ptr().add(4 * h).cast()) };
            let lo_lo = _mm256_mul_epu32(old, m_lo);
            let cross = _mm256_add_epi64(
                _mm256_mul_epu32(_mm256_srli_epi64::<32>(old), m_lo),
                _mm256_mul_epu32(old, m_hi),
            );
            let new = _mm256_add_epi64(_mm256_add_epi64(lo_lo, _mm256_slli_epi64::<32>(cross)), inc);
            let bits = _mm256_set1_epi64x(((m >> (4 * h)) & 0xf) as i64);
            let one = _mm256_setr_epi64x(1, 2, 4, 8);
            let take = _mm256_cmpeq_epi64(_mm256_and_si256(bits, one), one);
            let next = _mm256_blendv_epi8(old, new, take);
            // SAFETY: as above.
            unsafe { _mm256_storeu_si256(state.as_mut_ptr().add(4 * h).cast(), next) };
            // ((old >> 18) ^ old) >> 27, low 32 bits, rotated right by old >> 59
            let x = _mm256_and_si256(
                _mm256_srli_epi64::<27>(_mm256_xor_si256(_mm256_srli_epi64::<18>(old), old)),
                low32,
            );
            let rot = _mm256_srli_epi64::<59>(old);
            let left = _mm256_sllv_epi64(x, _mm256_sub_epi64(_mm256_set1_epi64x(32), rot));
            *o = _mm256_or_si256(_mm256_srlv_epi64(x, rot), _mm256_and_si256(left, low32));
        }
        // the low 32 bits of the eight 64-bit results, in lane order
        let pick = _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6);
        let (a, b) = (_mm256_permutevar8x32_epi32(out[0], pick), _mm256_permutevar8x32_epi32(out[1], pick));
        let u = _mm256_blend_epi32::<0xf0>(a, b);
        let f =
            _mm256_mul_ps(_mm256_cvtepi32_ps(_mm256_srli_epi32::<8>(u)), _mm256_set1_ps(1.0 / 16_777_216.0));
        let mut r = [0.0; W];
        st(&mut r, f);
        r
    }

    /// The 8×8 transpose: `out[k][l] = rows[l][k]`.
    #[target_feature(enable = "avx2")]
    #[inline]
    fn transpose8(r: [__m256; 8]) -> [__m256; 8] {
        let lo = |a, b| _mm256_unpacklo_ps(a, b);
        let hi = |a, b| _mm256_unpackhi_ps(a, b);
        let (t0, t1, t2, t3) = (lo(r[0], r[1]), hi(r[0], r[1]), lo(r[2], r[3]), hi(r[2], r[3]));
        let (t4, t5, t6, t7) = (lo(r[4], r[5]), hi(r[4], r[5]), lo(r[6], r[7]), hi(r[6], r[7]));
        let (s0, s1) = (_mm256_shuffle_ps::<0x44>(t0, t2), _mm256_shuffle_ps::<0xEE>(t0, t2));
        let (s2, s3) = (_mm256_shuffle_ps::<0x44>(t1, t3), _mm256_shuffle_ps::<0xEE>(t1, t3));
        let (s4, s5) = (_mm256_shuffle_ps::<0x44>(t4, t6), _mm256_shuffle_ps::<0xEE>(t4, t6));
        let (s6, s7) = (_mm256_shuffle_ps::<0x44>(t5, t7), _mm256_shuffle_ps::<0xEE>(t5, t7));
        [
            _mm256_permute2f128_ps::<0x20>(s0, s4),
            _mm256_permute2f128_ps::<0x20>(s1, s5),
            _mm256_permute2f128_ps::<0x20>(s2, s6),
            _mm256_permute2f128_ps::<0x20>(s3, s7),
            _mm256_permute2f128_ps::<0x31>(s0, s4),
            _mm256_permute2f128_ps::<0x31>(s1, s5),
            _mm256_permute2f128_ps::<0x31>(s2, s6),
            _mm256_permute2f128_ps::<0x31>(s3, s7),
        ]
    }

    /// `vertex`'s pending weights `w = kd_pi · ratio` (`Spectrum * f32`) of the lanes in `pend`:
    /// `β *= w` there; returns the lanes whose `w` is black.
    #[target_feature(enable = "avx2")]
    #[inline]
    pub(super) fn pending_weights(
        beta: &mut [[f32; W]; 3],
        kd_pi: &[[f32; W]; 3],
        ratio: &[f32; W],
        pend: u32,
    ) -> u32 {
        let zero = _mm256_setzero_ps();
        let r = ld(ratio);
        let pm = lane_mask(pend);
        let mut black = pm;
        for c in 0..3 {
            let w = _mm256_mul_ps(ld(&kd_pi[c]), r);
            black = _mm256_and_ps(black, _mm256_cmp_ps::<_CMP_EQ_OQ>(w, zero));
            let b = ld(&beta[c]);
            st(&mut beta[c], _mm256_blendv_ps(b, _mm256_mul_ps(b, w), pm));
        }
        bits(black)
    }

    /// The hit triangles' data (rows `prim`), barycentrics `b0 = 1 − b1 − b2`, uvs
    /// `uv0·b0 + uv1·b1 + uv2·b2` and sides `(−d)·ng > 0` of [`W`] vertices (as `vertex`), and the
    /// kernel's inputs except the direction samples.
    #[target_feature(enable = "avx2")]
    #[inline]
    pub(super) fn vertices(
        rows: &[Row],
        prim: &[u32; W],
        hits: &PacketHits,
        d: &[[f32; W]; 3],
        any_normals: bool,
        inp: &mut ScatterIn,
    ) -> VertexLanes {
        assert!(prim.iter().all(|&p| (p as usize) < rows.len()), "triangle index out of range");
        let base = rows.as_ptr().cast::<f32>();
        // The first 16 floats of the eight rows, transposed: `head[k]` = field k per lane.
        let head: [__m256; 16] = {
            // SAFETY: every row index is < rows.len() (asserted above); a row holds 32 floats.
            let half = |h: usize| -> [__m256; 8] {
                std::array::from_fn(|l| unsafe { _mm256_loadu_ps(base.add(32 * prim[l] as usize + 8 * h)) })
            };
            let (a, b) = (transpose8(half(0)), transpose8(half(1)));
            std::array::from_fn(|k| if k < 8 { a[k] } else { b[k - 8] })
        };
        let field = |k: usize| head[k];
        let ng = [field(ROW_NG), field(ROW_NG + 1), field(ROW_NG + 2)];
        let (b1, b2) = (ld(&hits.b1), ld(&hits.b2));
        let b0 = _mm256_sub_ps(_mm256_sub_ps(_mm256_set1_ps(1.0), b1), b2);
        let interp = |k: usize| {
            let a = _mm256_add_ps(_mm256_mul_ps(field(k), b0), _mm256_mul_ps(field(k + 2), b1));
            _mm256_add_ps(a, _mm256_mul_ps(field(k + 4), b2))
        };
        let (u, v) = (interp(ROW_UV), interp(ROW_UV + 1));
        let neg = |x| _mm256_xor_ps(x, _mm256_set1_ps(-0.0));
        let dot = _mm256_add_ps(
            _mm256_add_ps(_mm256_mul_ps(neg(ld(&d[0])), ng[0]), _mm256_mul_ps(neg(ld(&d[1])), ng[1])),
            _mm256_mul_ps(neg(ld(&d[2])), ng[2]),
        );
        let front = bits(_mm256_cmp_ps::<_CMP_GT_OQ>(dot, _mm256_setzero_ps()));
        inp.t = hits.t;
        for (c, &n) in ng.iter().enumerate() {
            st(&mut inp.ng[c], n);
            st(&mut inp.ng_off[c], field(ROW_NG_OFF + c));
        }
        if any_normals {
            // SAFETY: 8 u32, unaligned load.
            let idx = _mm256_slli_epi32::<5>(unsafe { _mm256_loadu_si256(prim.as_ptr().cast()) });
            // SAFETY: every lane's row index is < rows.len() (asserted above) and k < 32, so
            // each gathered float lies inside `rows`.
            let gather = |k: usize| unsafe { _mm256_i32gather_ps::<4>(base.add(k), idx) };
            for k in 0..3 {
                for c in 0..3 {
                    st(&mut inp.n[k][c], gather(ROW_N + 3 * k + c));
                }
            }
            st_mask(&mut inp.has_n, gather(ROW_HAS_N));
        }
        let flags = _mm256_castps_si256(field(ROW_FLAGS));
        let flag = |f: u32| {
            let f = _mm256_set1_epi32(f as i32);
            _mm256_castsi256_ps(_mm256_cmpeq_epi32(_mm256_and_si256(flags, f), f))
        };
        st_mask(&mut inp.two_sided, flag(FLAG_TWO_SIDED));
        st(&mut inp.b[0], b0);
        st(&mut inp.b[1], b1);
        st(&mut inp.b[2], b2);
        let mut out =
            VertexLanes { uv: [[0.0; W]; 2], kd_pi: [[0.0; W]; 3], front, bitmap: bits(flag(FLAG_BITMAP)) };
        st(&mut out.uv[0], u);
        st(&mut out.uv[1], v);
        for c in 0..3 {
            st(&mut out.kd_pi[c], field(ROW_KD + c));
        }
        out
    }

    /// The texel index `3·(y·w + x)` and the rounded units `round(β_c · factor)` of the
    /// deposits of [`W`] vertices of triangles `prim` at `uv` (as [`super::deposit`]: the f32
    /// products `u·w`, the truncation clamped to the map, the f64 products, ties away from
    /// zero, truncation). `small` = the lanes whose three rounded values are below 2³¹ in
    /// magnitude (so finite, and the conversion to integers here is exact: it is up to 2⁵¹);
    /// the others are left to `deposit`.
    #[target_feature(enable = "avx2")]
    #[inline]
    pub(super) fn deposit_values(
        rows: &[Row],
        factor: &[f64],
        prim: &[u32; W],
        uv: &[[f32; W]; 2],
        beta: &[[f32; W]; 3],
    ) -> super::DepositLanes {
        // the last 8 floats of the eight rows, transposed (loads and shuffles: cheaper than
        // gathers, see `vertices`)
        let tail = transpose8(std::array::from_fn(|l| {
            let r = &rows[prim[l] as usize].0;
            // SAFETY: 8 floats of a 32-float row, unaligned load.
            unsafe { _mm256_loadu_ps(r.as_ptr().add(24)) }
        }));
        let field = |k: usize| tail[k - 24];
        let (w, h) = (field(ROW_SIZE), field(ROW_SIZE + 1));
        let zero = _mm256_setzero_ps();
        let one = _mm256_set1_ps(1.0);
        // `(u·w) as i64` clamped to [0, w − 1]: a NaN product gives 0 (max picks its second
        // operand), larger values w − 1, negative ones 0.
        let texel = |u: __m256, n: __m256| {
            let x = _mm256_min_ps(_mm256_max_ps(_mm256_mul_ps(u, n), zero), _mm256_sub_ps(n, one));
            _mm256_cvttps_epi32(x)
        };
        let (x, y) = (texel(ld(&uv[0]), w), texel(ld(&uv[1]), h));
        let wi = _mm256_cvttps_epi32(w);
        let index = _mm256_mullo_epi32(_mm256_add_epi32(_mm256_mullo_epi32(y, wi), x), _mm256_set1_epi32(3));
        let mut out =
            super::DepositLanes { index: [0; W], value: [[0; W]; 3], small: u32::MAX, shape: [0; W] };
        // SAFETY: 8 i32, unaligned store.
        unsafe { _mm256_storeu_si256(out.shape.as_mut_ptr().cast(), _mm256_castps_si256(field(ROW_SHAPE))) };
        let limit32 = _mm256_set1_pd(2_147_483_648.0); // 2³¹
        // SAFETY: 8 i32, unaligned store.
        unsafe { _mm256_storeu_si256(out.index.as_mut_ptr().cast(), index) };
        let magic = _mm256_set1_pd(6_755_399_441_055_744.0); // 1.5·2⁵²
        let sign = _mm256_set1_pd(-0.0);
        let half = _mm256_set1_pd(0.5);
        for half_lanes in 0..2 {
            let f = |l: usize| factor[prim[4 * half_lanes + l] as usize];
            let f = _mm256_setr_pd(f(0), f(1), f(2), f(3));
            for (c, beta_c) in beta.iter().enumerate() {
                // SAFETY: 4 floats of an 8-float array.
                let b = unsafe { _mm_loadu_ps(beta_c.as_ptr().add(4 * half_lanes)) };
                let q = _mm256_mul_pd(_mm256_cvtps_pd(b), f);
                let r = _mm256_add_pd(q, _mm256_or_pd(half, _mm256_and_pd(q, sign)));
                let fits = _mm256_cmp_pd::<_CMP_LT_OQ>(_mm256_andnot_pd(sign, r), limit32);
                let big = (!_mm256_movemask_pd(fits) & 0xf) as u32;
                out.small &= !(big << (4 * half_lanes));
                let t = _mm256_round_pd::<{ _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC }>(r);
                let v = _mm256_sub_epi64(
                    _mm256_castpd_si256(_mm256_add_pd(t, magic)),
                    _mm256_castpd_si256(magic),
                );
                // SAFETY: 4 i64 of an 8-i64 array.
                unsafe { _mm256_storeu_si256(out.value[c].as_mut_ptr().add(4 * half_lanes).cast(), v) };
            }
        }
        out.small &= (1 << W) - 1;
        out
    }

    /// Scatters the lanes in `alive` ([`super::scatter_lanes`]; `normals` = some triangle of
    /// the scene has corner normals) and moves their rays to the sampled directions; returns
    /// the lanes whose sample is valid and writes their `ratio`.
    #[target_feature(enable = "avx2")]
    #[inline]
    pub(super) fn scatter(
        rays: &mut RayPacket,
        inp: &ScatterIn,
        alive: u32,
        ratio: &mut [f32; W],
        normals: bool,
    ) -> u32 {
        let out = if normals { kernel::<true>(rays, inp) } else { kernel::<false>(rays, inp) };
        // SAFETY: 8 u32, unaligned load.
        let valid = unsafe { _mm256_loadu_ps(out.valid.as_ptr().cast()) };
        let am = _mm256_and_ps(lane_mask(alive), valid);
        for c in 0..3 {
            let o = _mm256_blendv_ps(ld(&rays.o[c]), ld(&out.o[c]), am);
            st(&mut rays.o[c], o);
            let d = _mm256_blendv_ps(ld(&rays.d[c]), ld(&out.d[c]), am);
            st(&mut rays.d[c], d);
        }
        *ratio = out.ratio;
        bits(am)
    }

    /// [`super::scatter_lanes`] compiled with AVX2, kept out of line (the lane loops vectorise
    /// reliably in a function of their own).
    #[target_feature(enable = "avx2")]
    #[inline(never)]
    fn kernel<const NORMALS: bool>(rays: &RayPacket, inp: &ScatterIn) -> super::ScatterOut {
        super::scatter_lanes::<NORMALS>(rays, inp)
    }

    /// [`super::start_lanes`] compiled with AVX2, kept out of line like [`kernel`].
    #[target_feature(enable = "avx2")]
    #[inline(never)]
    pub(super) fn start_kernel(inp: &super::StartIn) -> super::StartOut {
        super::start_lanes(inp)
    }
}

impl Wavefront {
    /// Whether this CPU runs the wavefront (AVX2); otherwise the paths are traced one at a time
    /// ([`trace_path`], same results).
    fn available() -> bool {
        #[cfg(target_arch = "x86_64")]
        return std::arch::is_x86_feature_detected!("avx2");
        #[cfg(not(target_arch = "x86_64"))]
        return false;
    }

    /// Traces `paths` (the caller checked [`Wavefront::available`]).
    fn run<'a>(
        ctx: &mut PathCtx<'a, '_>,
        tab: &LambertTable<'a>,
        stream: &RngStream,
        paths: std::ops::Range<u64>,
        packet: Option<&PacketAccel>,
    ) {
        #[cfg(target_arch = "x86_64")]
        if Wavefront::available() {
            // SAFETY: the CPU supports AVX2 (checked just above).
            return unsafe { Wavefront::run_avx2(ctx, tab, stream, paths, packet) };
        }
        for i in paths {
            trace_path(ctx, stream.rng(i));
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn run_avx2<'a>(
        ctx: &mut PathCtx<'a, '_>,
        tab: &LambertTable<'a>,
        stream: &RngStream,
        paths: std::ops::Range<u64>,
        packet: Option<&PacketAccel>,
    ) {
        let (scene, sampler, s) = (ctx.scene, ctx.sampler, ctx.s);
        let mut ln = Lanes {
            rays: RayPacket::default(),
            rng_state: [0; W],
            rng_inc: [0; W],
            beta: [[0.0; W]; 3],
            b0: [0.0; W],
            depth: [0; W],
            pending: 0,
            bitmap: 0,
            ratio: [0.0; W],
            kd_pi: [[0.0; W]; 3],
            tex: [None; W],
            uv: [Vec2::ZERO; W],
            active: 0,
        };
        let mut next = paths.start;
        // the starts of the next paths, prepared W at a time; `taken` of them handed out
        let mut block = StartBlock::new(stream);
        let mut taken = W;
        // lane `l` takes the next path of the batch that carries something, or turns inactive
        let mut refill = |ln: &mut Lanes<'a>, l: usize| {
            loop {
                if taken == W {
                    if next >= paths.end {
                        break;
                    }
                    let end = (next + W as u64).min(paths.end);
                    starts(scene, sampler, &tab.lights, stream, next..end, &mut block);
                    next = end;
                    taken = 0;
                }
                let k = taken;
                taken += 1;
                if block.valid & (1 << k) != 0 {
                    ln.start(l, &block, k);
                    return;
                }
            }
            ln.active &= !(1 << l);
            ln.rays.tmax[l] = 0.0;
        };
        for l in 0..W {
            refill(&mut ln, l);
        }
        let rows = &tab.rows[..];
        let mut inp = ScatterIn::default();
        while ln.active != 0 {
            let hits = match packet {
                Some(pa) => pa.intersect_avx2(&ln.rays),
                None => {
                    let mut h = PacketHits::NONE;
                    for l in lanes_of(ln.active) {
                        h.set(l, scene.intersect_hit(&ln.rays.ray(l)));
                    }
                    h
                }
            };
            // A lane whose ray missed ends (its pending weight and roulette change nothing).
            let hit = ln.active & mask(|l| hits.prim[l] >= 0);
            // `vertex`: the pending weights (bitmap albedos looked up now) of the lanes that hit
            // (lanes facing the roulette settled theirs before the trace, see below)
            let mut alive = hit & !ln.settle(ln.pending & hit, s.rr_depth);
            // the new vertices: triangle data, deposits, direction samples, scattering
            if alive != 0 {
                for l in lanes_of(alive) {
                    ln.depth[l] += 1;
                }
                let prim: [u32; W] =
                    std::array::from_fn(|l| if alive & (1 << l) != 0 { hits.prim[l] as u32 } else { 0 });
                let v = avx::vertices(rows, &prim, &hits, &ln.rays.d, tab.any_normals, &mut inp);
                let front = alive & v.front;
                if front != 0 {
                    let dv = if tab.vector_deposits {
                        avx::deposit_values(rows, &tab.factor, &prim, &v.uv, &ln.beta)
                    } else {
                        DepositLanes { index: [0; W], value: [[0; W]; 3], small: 0, shape: [0; W] }
                    };
                    // `deposit` of the lanes whose units fit the queue, straight into the sink
                    let quick = front & dv.small & mask(|l| dv.shape[l] >= 0);
                    for l in lanes_of(quick) {
                        let direct = ln.depth[l] == 1;
                        if direct && !s.direct {
                            continue;
                        }
                        let value = [0, 1, 2].map(|c| dv.value[c][l] as i32);
                        ctx.sink.push_small(dv.shape[l] as usize, direct, dv.index[l] as u32, value);
                    }
                    for l in lanes_of(front & !quick) {
                        let pr = &ctx.prims[prim[l] as usize];
                        let beta = Spectrum([ln.beta[0][l], ln.beta[1][l], ln.beta[2][l]]);
                        let uv = Vec2::new(v.uv[0][l], v.uv[1][l]);
                        deposit(ctx.sink, ctx.bad, s, pr, uv, beta, ln.depth[l]);
                    }
                }
                if s.max_depth >= 0 {
                    alive &= !mask(|l| ln.depth[l] >= s.max_depth);
                }
                // `Lambert::sample`: a number drawn for the generic sampler, then the direction sample
                // (the same draws per lane as `Rng::next_f32`, eight lanes at a time)
                avx::next_f32_lanes(&mut ln.rng_state, &ln.rng_inc, alive);
                inp.u[0] = avx::next_f32_lanes(&mut ln.rng_state, &ln.rng_inc, alive);
                inp.u[1] = avx::next_f32_lanes(&mut ln.rng_state, &ln.rng_inc, alive);
                alive = avx::scatter(&mut ln.rays, &inp, alive, &mut ln.ratio, tab.any_normals);
                ln.kd_pi = v.kd_pi;
                ln.bitmap = alive & v.bitmap;
                for l in lanes_of(ln.bitmap) {
                    let tex = tab.tex[prim[l] as usize].expect("bitmap rows have a texture");
                    let uv = Vec2::new(v.uv[0][l], v.uv[1][l]);
                    ln.tex[l] = Some(tex);
                    ln.uv[l] = uv;
                    prefetch_texture(tex, uv);
                }
            }
            ln.pending = alive;
            if s.rr_depth >= 0 {
                // Lanes whose next vertex faces the roulette settle their pending weight and
                // draw the roulette now, before their ray is traced: a path the roulette ends
                // traces no ray for nothing. Same numbers in the same order as `vertex` (no
                // draw of the path comes between), same deposits: a lane that would have
                // missed ends either way.
                let early = alive & mask(|l| ln.depth[l] >= s.rr_depth);
                if early != 0 {
                    alive &= !ln.settle(early, s.rr_depth);
                }
            }
            let ended = ln.active & !alive;
            ln.active = alive;
            for l in lanes_of(ended) {
                refill(&mut ln, l);
            }
        }
    }
}

/// Triangle lights as the SIMD path starts need them, one entry per light (`None` for other
/// lights, whose paths start through [`start_path`]).
#[derive(Clone, Copy)]
struct LightRow {
    p: [Vec3; 3],
    frame: Frame,
    /// The light's normal and its `normalize_or_zero` (the ray offset's direction).
    n: Vec3,
    n_off: Vec3,
    radiance: Spectrum,
    inv_area: f32,
}

fn light_rows(scene: &Scene) -> Vec<Option<LightRow>> {
    scene
        .lights
        .iter()
        .map(|l| match l {
            crate::light::Light::Triangle(t) => Some(LightRow {
                p: t.p,
                frame: *t.frame(),
                n: t.n,
                n_off: t.n.normalize_or_zero(),
                radiance: t.radiance,
                inv_area: t.inv_area(),
            }),
            _ => None,
        })
        .collect()
}

/// Inputs of [`start_lanes`]: per lane the chosen light's data and the position and direction
/// samples.
#[derive(Clone, Copy, Default)]
struct StartIn {
    p: [[[f32; W]; 3]; 3],
    s: [[f32; W]; 3],
    t: [[f32; W]; 3],
    n: [[f32; W]; 3],
    n_off: [[f32; W]; 3],
    le: [[f32; W]; 3],
    inv_area: [f32; W],
    pmf: [f32; W],
    u_pos: [[f32; W]; 2],
    u_dir: [[f32; W]; 2],
}

/// Outputs: the offset ray, β, and `valid` = 0 where the sample carries nothing.
#[derive(Clone, Copy, Default)]
struct StartOut {
    o: [[f32; W]; 3],
    d: [[f32; W]; 3],
    beta: [[f32; W]; 3],
    valid: [u32; W],
}

/// [`start_path`] for triangle lights on [`W`] lanes after the light choice: `sample_le`
/// (`square_to_uniform_triangle`, the corners' combination, `square_to_cosine_hemisphere`,
/// `Frame::to_world`, `pdf_dir = z/π`), the validity checks, `β = Le·(|d·n| / (pmf·pdf_pos·
/// pdf_dir))` and `spawn_ray`'s offset, with the same operations in the same order (selects for
/// branches), hence the same bits.
#[inline(always)]
fn start_lanes(i: &StartIn) -> StartOut {
    use crate::fastmath::wide::F;
    type V = [F<W>; 3];
    let ld = |a: &[[f32; W]; 3]| -> V { [F(a[0]), F(a[1]), F(a[2])] };
    let zero = F::<W>::splat(0.0);
    // square_to_uniform_triangle
    let (ux, uy) = (F(i.u_pos[0]), F(i.u_pos[1]));
    let lt = ux.lt(uy);
    let half_x = ux / 2.0;
    let half_y = uy / 2.0;
    let b0 = lt.select(half_x, ux - half_y);
    let b1 = lt.select(uy - half_x, half_y);
    // p0·(1 − b0 − b1) + p1·b0 + p2·b1
    let w0 = 1.0 - b0 - b1;
    let (p0, p1, p2) = (ld(&i.p[0]), ld(&i.p[1]), ld(&i.p[2]));
    let o: V = each3(|c| p0[c] * w0 + p1[c] * b0 + p2[c] * b1);
    let [dx, dy, z] = cosine_hemisphere_lanes(F(i.u_dir[0]), F(i.u_dir[1]));
    // Frame::to_world
    let (fs, ft, fnn) = (ld(&i.s), ld(&i.t), ld(&i.n));
    let dir: V = each3(|c| (fs[c] * dx + ft[c] * dy) + fnn[c] * z);
    let pdf_dir = z / std::f32::consts::PI;
    let (pmf, pdf_pos) = (F(i.pmf), F(i.inv_area));
    let valid = z.gt(zero) & pmf.gt(zero) & pdf_pos.gt(zero) & pdf_dir.gt(zero);
    let n = ld(&i.n);
    let cos = ((dir[0] * n[0] + dir[1] * n[1]) + dir[2] * n[2]).abs();
    let k = cos / (pmf * pdf_pos * pdf_dir);
    let le = ld(&i.le);
    let origin = offset_lanes(o, ld(&i.n_off), dir);
    let mut out = StartOut::default();
    for c in 0..3 {
        out.o[c] = origin[c].0;
        out.d[c] = dir[c].0;
        out.beta[c] = (le[c] * k).0;
    }
    out.valid = valid.0;
    out
}

/// Path starts prepared [`W`] at a time (structure of arrays): for the lanes in `valid`, the
/// emitted ray (offset), its weight β and the path's generator after the start's draws.
struct StartBlock {
    o: [[f32; W]; 3],
    d: [[f32; W]; 3],
    beta: [[f32; W]; 3],
    rng: [Rng; W],
    valid: u32,
}

impl StartBlock {
    fn new(stream: &RngStream) -> StartBlock {
        StartBlock {
            o: [[0.0; W]; 3],
            d: [[0.0; W]; 3],
            beta: [[0.0; W]; 3],
            rng: std::array::from_fn(|_| stream.rng(0)),
            valid: 0,
        }
    }
}

/// The path starts of the indices `range` (at most [`W`]), in order, into `out`; lane `l` is
/// valid where [`start_path`] gives a path (same paths, same bits: triangle lights through
/// [`start_lanes`], other lights through `start_path` itself).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn starts(
    scene: &Scene,
    sampler: &crate::light::LightSampler,
    lights: &[Option<LightRow>],
    stream: &RngStream,
    range: std::ops::Range<u64>,
    out: &mut StartBlock,
) {
    let mut inp = StartIn::default();
    let mut simd = 0u32;
    let mut scalar = 0u32;
    for (l, i) in range.enumerate() {
        let mut rng = stream.rng(i);
        let (li, pmf, _) = sampler.sample(rng.next_f32());
        let Some(row) = &lights[li] else {
            if let Some(st) = start_path(scene, sampler, stream.rng(i)) {
                for c in 0..3 {
                    out.o[c][l] = st.ray.o[c];
                    out.d[c][l] = st.ray.d[c];
                    out.beta[c][l] = st.beta[c];
                }
                out.rng[l] = st.rng;
                scalar |= 1 << l;
            }
            continue;
        };
        let (u_pos, u_dir) = (rng.next_2d(), rng.next_2d());
        for c in 0..3 {
            for k in 0..3 {
                inp.p[k][c][l] = row.p[k][c];
            }
            inp.s[c][l] = row.frame.s[c];
            inp.t[c][l] = row.frame.t[c];
            inp.n[c][l] = row.n[c];
            inp.n_off[c][l] = row.n_off[c];
            inp.le[c][l] = row.radiance[c];
        }
        inp.inv_area[l] = row.inv_area;
        inp.pmf[l] = pmf;
        inp.u_pos[0][l] = u_pos.x;
        inp.u_pos[1][l] = u_pos.y;
        inp.u_dir[0][l] = u_dir.x;
        inp.u_dir[1][l] = u_dir.y;
        out.rng[l] = rng;
        simd |= 1 << l;
    }
    let o = avx::start_kernel(&inp);
    let valid = simd & mask(|l| o.valid[l] != 0);
    for l in lanes_of(valid) {
        for c in 0..3 {
            out.o[c][l] = o.o[c][l];
            out.d[c][l] = o.d[c][l];
            out.beta[c][l] = o.beta[c][l];
        }
    }
    out.valid = valid | scalar;
}

/// Mask of the lanes where `f(l)` holds.
#[inline(always)]
fn mask(f: impl Fn(usize) -> bool) -> u32 {
    (0..W).fold(0, |m, l| m | ((f(l) as u32) << l))
}

/// Deposits in flight per worker: the queue length of [`Sink`].
const QUEUE: usize = 32;

/// A worker's accumulator behind a queue of [`QUEUE`] deposits: a deposit's texel is
/// prefetched when it is pushed and the addition happens when it leaves the queue, about ten
/// paths later, so the memory latency overlaps the tracing instead of stalling it.
///
/// The maps are kept flat by map number `2·shape + direct` (empty where a shape has none) and
/// a queued deposit is 20 bytes (`i32` units: a deposit beyond `i32`, in practice never, is
/// added at once), so a deposit costs few instructions besides its cache miss.
struct Sink {
    /// Per map `2·shape + direct`.
    maps: Vec<Cells>,
    /// Per shape: the map size (`None`: no target) and the exact sum of |units| deposited.
    shapes: Vec<Option<(usize, usize)>>,
    totals: Vec<u128>,
    ring: [Queued; QUEUE],
    /// Oldest queued deposit, number queued.
    head: usize,
    len: usize,
}

/// A queued deposit: map number, index of the texel's red channel, units.
#[derive(Clone, Copy, Default)]
struct Queued {
    map: u32,
    index: u32,
    value: [i32; 3],
}

impl Sink {
    fn new(acc: Acc) -> Sink {
        let mut maps = Vec::with_capacity(2 * acc.len());
        let mut shapes = Vec::with_capacity(acc.len());
        for m in acc {
            match m {
                Some(m) => {
                    maps.push(m.indirect);
                    maps.push(m.direct);
                    shapes.push(Some((m.width, m.height)));
                }
                None => {
                    maps.push(Cells::new(0));
                    maps.push(Cells::new(0));
                    shapes.push(None);
                }
            }
        }
        let totals = vec![0; shapes.len()];
        Sink { maps, shapes, totals, ring: [Queued::default(); QUEUE], head: 0, len: 0 }
    }

    /// Queues a deposit ([`Sink::push_small`]), or adds it at once when its units or index do
    /// not fit the queue.
    #[inline]
    fn push(&mut self, p: Pending) {
        let value = p.value.map(|v| v as i32);
        if value.iter().zip(&p.value).all(|(&a, &b)| a as i64 == b) && p.index <= u32::MAX as usize {
            self.push_small(p.shape, p.direct, p.index as u32, value);
        } else {
            self.totals[p.shape] += p.value.iter().map(|v| v.unsigned_abs() as u128).sum::<u128>();
            self.maps[2 * p.shape + p.direct as usize].add(p.index, p.value);
        }
    }

    /// Queues a deposit whose units fit in `i32` (channel index `index` of the map of `shape`,
    /// direct or indirect): counts it in the shape's total, prefetches its texel and adds the
    /// deposit that leaves the queue.
    #[inline(always)]
    fn push_small(&mut self, shape: usize, direct: bool, index: u32, value: [i32; 3]) {
        self.totals[shape] += value.iter().map(|v| v.unsigned_abs() as u64).sum::<u64>() as u128;
        let map = 2 * shape + direct as usize;
        prefetch(&self.maps[map].fine[index as usize]);
        let q = Queued { map: map as u32, index, value };
        if self.len == QUEUE {
            let old = std::mem::replace(&mut self.ring[self.head], q);
            self.head = (self.head + 1) % QUEUE;
            self.apply(old);
        } else {
            self.ring[(self.head + self.len) % QUEUE] = q;
            self.len += 1;
        }
    }

    #[inline]
    fn apply(&mut self, q: Queued) {
        self.maps[q.map as usize].add32(q.index as usize, q.value);
    }

    /// Applies the queued deposits and returns the accumulator.
    fn finish(mut self) -> Acc {
        for k in 0..self.len {
            let q = self.ring[(self.head + k) % QUEUE];
            self.apply(q);
        }
        let mut maps = self.maps.into_iter();
        self.shapes
            .iter()
            .zip(self.totals)
            .map(|(size, total)| {
                let (indirect, direct) = (maps.next().expect("two maps"), maps.next().expect("per shape"));
                size.map(|(width, height)| ShapeAcc { width, height, direct, indirect, total })
            })
            .collect()
    }
}

/// A deposit: texel, map and integer value.
#[derive(Clone, Copy)]
struct Pending {
    shape: usize,
    /// Index of the texel's red channel in the flat map.
    index: usize,
    direct: bool,
    value: [i64; 3],
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
/// weight `b0 = max_c β_c` at the light (so the roulette does not depend on the absolute power),
/// capped at 0.95.
#[inline]
fn survival(beta: Spectrum, b0: f32) -> f32 {
    if b0 > 0.0 { (beta.max_component() / b0).min(0.95) } else { 0.0 }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::TriangleMesh;
    use crate::math::{PI, Vec3};
    use crate::scene::desc::{AreaEmitterDesc, BsdfDesc, EmitterDesc, SceneDesc, ShapeDesc, TextureDesc};

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

    fn shape(id: &str, mesh: TriangleMesh, bsdf: BsdfDesc, emitter: Option<AreaEmitterDesc>) -> ShapeDesc {
        ShapeDesc { id: id.into(), mesh, bsdf, emitter, origin: None }
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
            shapes: vec![shape("floor", floor_quad(h), diffuse(0.0), None)],
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
                shape("floor", floor_quad(1.0), diffuse(0.0), None),
                shape("light", light, diffuse(0.0), Some(AreaEmitterDesc { radiance: Spectrum::splat(le) })),
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
            shapes: vec![shape(
                "box",
                inner.clone(),
                diffuse(rho),
                Some(AreaEmitterDesc { radiance: Spectrum::splat(le) }),
            )],
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
            for i in b * s.batch_size..((b + 1) * s.batch_size).min(s.paths) {
                let mut rng = Rng::new(s.seed, RNG_STREAM, i);
                let (li, pmf, _) = sampler.sample(rng.next_f32());
                let (u_pos, u_dir) = (rng.next_2d(), rng.next_2d());
                let Some(es) = scene.lights[li].sample_le(u_pos, u_dir) else { continue };
                // point lights (no normal): no cosine, no offset
                let cos = if es.n == Vec3::ZERO { 1.0 } else { es.ray.d.dot(es.n).abs() };
                let mut beta = es.le * (cos / (pmf * es.pdf_pos * es.pdf_dir));
                let mut ray = if es.n == Vec3::ZERO {
                    es.ray
                } else {
                    crate::accel::spawn_ray(es.ray.o, es.n, es.ray.d)
                };
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
                        let q =
                            survival(beta, (es.le * (cos / (pmf * es.pdf_pos * es.pdf_dir))).max_component());
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
        let desc = SceneDesc {
            shapes: vec![
                shape("floor", floor_quad(1.0), BsdfDesc::Diffuse { reflectance: tex }, None),
                shape(
                    "wall",
                    // corner normals (tilted): the shading-normal path of the scattering kernel
                    TriangleMesh {
                        normals: [v(0.2, 0.0, 1.0), v(-0.1, 0.1, 1.0), v(0.0, -0.2, 1.0), v(0.1, 0.1, 1.0)]
                            .map(|n| n.normalize())
                            .to_vec(),
                        ..quad([v(-1.0, 0.0, -1.0), v(1.0, 0.0, -1.0), v(1.0, 2.0, -1.0), v(-1.0, 2.0, -1.0)])
                    },
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
            // a point light too: the wavefront starts its paths one at a time
            emitters: vec![EmitterDesc::Point {
                position: v(0.4, 1.2, 0.2),
                intensity: Spectrum::rgb(0.6, 0.5, 0.4),
            }],
            ..Default::default()
        };
        let scene = Scene::build(&desc).unwrap();
        assert_eq!(scene.lights.len(), 3);
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
        // The wavefront (packets or one ray per lane) and one path at a time, and another batch
        // size: the same paths, bit for bit, hence identical integer sums.
        let sampler = scene.light_sampler().unwrap();
        let fp = FixedPoint::new(&scene, &targets, s.paths, 0);
        let other_batches = LightTraceSettings { batch_size: 1_234, ..s };
        for (engine, s) in [(Engine::WavefrontRays, s), (Engine::Scalar, s), (Engine::Auto, other_batches)] {
            let o = trace_fixed(&scene, sampler, &targets, &s, &fp, &|| {}, engine).unwrap();
            for k in 0..2 {
                let (a, b) = (o.maps[k].as_ref().unwrap(), runs[0].maps[k].as_ref().unwrap());
                assert_eq!((&a.direct, &a.indirect), (&b.direct, &b.indirect), "{engine:?}");
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
            shapes: vec![shape(
                "box",
                inner.clone(),
                diffuse(0.5),
                Some(AreaEmitterDesc { radiance: Spectrum::splat(1.0) }),
            )],
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
            match trace_fixed(&scene, sampler, &targets, &s, &fp, &|| {}, Engine::Auto) {
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
    fn simd_generators_draw_the_scalar_numbers() {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            let stream = RngStream::new(9, RNG_STREAM);
            let mut scalar: Vec<Rng> = (0..W as u64).map(|i| stream.rng(i * 977)).collect();
            let mut state: [u64; W] = std::array::from_fn(|l| scalar[l].state);
            let inc: [u64; W] = std::array::from_fn(|l| scalar[l].inc);
            let mut mrng = Rng::new(4, 4, 4);
            for _ in 0..10_000 {
                let m = mrng.next_u32() & 0xff;
                // SAFETY: the CPU supports AVX2 (checked above).
                let got = unsafe { avx::next_f32_lanes(&mut state, &inc, m) };
                for (l, r) in scalar.iter_mut().enumerate() {
                    if m & (1 << l) != 0 {
                        assert_eq!(got[l].to_bits(), r.next_f32().to_bits(), "lane {l}");
                    }
                    assert_eq!(state[l], r.state, "lane {l}: state");
                }
            }
        }
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
                shape("box", inner.clone(), diffuse(0.6), None),
                shape(
                    "light",
                    light,
                    diffuse(0.0),
                    Some(AreaEmitterDesc { radiance: Spectrum::rgb(1.0, 2.0, 3.0) }),
                ),
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
