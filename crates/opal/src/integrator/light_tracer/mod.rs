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
//! (no direct map: half the accumulator memory; same paths, same indirect map). The path then
//! scatters with the scene's BSDF in
//! [`TransportMode::Importance`](crate::bsdf::TransportMode::Importance) and Russian roulette
//! from `rr_depth`.
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
//! (β_ref/β) × (A_texel/A_min) per deposit — far below the Monte-Carlo noise (a test in
//! `tests.rs` checks agreement with a plain f64 pass to 10⁻⁶). *Overflow*: a texel's sum would
//! need ~2³⁸ deposits of the reference size; the exact (u128) sum of |units| per shape is
//! checked at the end, and if it reaches 2⁶³ the pass is traced again with a coarser unit
//! (deterministic; never seen).
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
//! so only the order of the integer deposits changes. The eight rays go through the scene's
//! one intersection API, [`crate::accel::Accel::intersect8`] (in scenes of up to `TINY_MAX`
//! triangles they are traced together, one per SIMD lane, by
//! [`crate::accel::packet::PacketAccel`]; larger scenes run the 8-wide BVH per lane) — the
//! same hits as `Scene::intersect_hit`.
//!
//! **Files** (`light_tracer/`):
//! * `mod.rs` (this file): the settings, the outputs, [`trace`] and the pass itself
//!   (`trace_fixed`: workers, overflow check, reduction);
//! * `fixed_point.rs`: the fixed-point scale (`FixedPoint`) and the integer maps (`Cells`
//!   with their spill map, `ShapeAcc`);
//! * `sink.rs`: the per-worker deposit queue (`Sink`) and the prefetch hint;
//! * `zeroed.rs`: the zeroed `i32` storage of a worker's maps (`Zeroed`: one 2 MiB-aligned
//!   mapping advised for transparent huge pages on Linux, `Vec`s elsewhere);
//! * `prims.rs`: per-triangle hit and material data (`Prim`, `Mat`) and the deferred
//!   scattering weight (`Weight`);
//! * `path.rs`: one path at a time, any material (`start_path`, `vertex`, `deposit`,
//!   `trace_path`, the roulette's `survival`);
//! * `wavefront.rs`: eight paths at a time (`Wavefront`, `Lanes`, the triangle rows of
//!   `LambertTable`) and the portable lane kernels (`scatter_lanes` and its helpers);
//! * `avx.rs`: the AVX2 steps of the wavefront (x86-64 only), including the bilinear bitmap
//!   lookups of the lanes (`bilinear_lanes`, beside `Texture::eval`) and the prefetch of their
//!   taps (`bilinear_prefetch`);
//! * `starts.rs`: path starts prepared eight at a time (triangle lights in SIMD);
//! * `tests.rs`: the unit tests; `tests_emitters.rs`: the emission of spot, directional and
//!   environment lights against the path tracer.
//!
//! Tests (`tests.rs`): a quad under a point light (E = I cos θ / d², analytic) and a quad under a
//! small area light against a quadrature of ∫ L cos dω; indirect light in a closed furnace-like
//! box against the path tracer's estimate; thread-count independence; the fast paths and the
//! fixed-point sums against the generic f64 pass (a bitmap-textured floor, a two-sided wall
//! with corner normals, Russian roulette, an area and a point light) to 10⁻⁶, identical for 1,
//! 2 and 3 threads and for the three engines (wavefront with ray packets, wavefront with one ray
//! per lane, one path at a time); the `i32` cells with spill against plain `i64` sums (random
//! deposits up to 2⁴⁰ units); `direct: false` leaves the indirect map bitwise unchanged.
//! `tests_emitters.rs`: per texel, the irradiance of a floor under an occluder lit by a
//! `constant`, `envmap`, `spot` or `directional` light agrees with the path tracer's estimate.
//!
//! Infinite lights (directional, environment) emit from a disk of the scene's bounding-sphere
//! radius perpendicular to the direction, outside the sphere (`Light::sample_le`, area density
//! 1/(πR²)); a spot emits uniformly in its cone. These start through `start_path`.

// The SIMD fast paths exist on x86-64 only; elsewhere the scalar paths run (same results).
#![cfg_attr(not(target_arch = "x86_64"), allow(dead_code, unused_imports, unused_variables))]

#[cfg(target_arch = "x86_64")]
mod avx;
mod fixed_point;
mod path;
mod prims;
mod sink;
mod starts;
mod wavefront;
mod zeroed;

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_emitters;
#[cfg(all(test, target_arch = "x86_64"))]
mod tests_lanes;

use crate::sampling::RngStream;
use crate::scene::Scene;
use fixed_point::{Acc, Cells, FixedPoint, empty_acc};
use path::{PathCtx, RNG_STREAM, trace_path};
use prims::prims;
use rayon::prelude::*;
use sink::Sink;
use wavefront::{LambertTable, Wavefront};

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
    trace_cancellable(scene, targets, s, on_batch, None).expect("a pass without a cancel flag finishes")
}

/// [`trace`] that stops early when `cancel` becomes `true`: the workers look at the flag before
/// each batch, so the pass ends within one batch per worker and returns `None` (the partial
/// sums are dropped: a pass is all or nothing). With the flag never set, the result is [`trace`]'s,
/// bit for bit.
pub fn trace_cancellable(
    scene: &Scene,
    targets: &[Option<IrradianceTarget>],
    s: &LightTraceSettings,
    on_batch: &(dyn Fn() + Sync),
    cancel: Option<&std::sync::atomic::AtomicBool>,
) -> Option<LightTraceOutput> {
    trace_split(scene, targets, s, on_batch, cancel, &crate::dist::Solo)
}

/// [`trace_cancellable`] with the path batches split across the processes of `comm`: batch `b`
/// is traced by rank `b mod size`, the integer texel sums are added over the ranks (wrapping
/// `u64` sums: exact in any order) and every rank returns the maps one process computes, bit
/// for bit. `on_batch` counts this rank's batches only. The ranks agree on a cancellation: the
/// pass is dropped on every rank when any rank's flag was set.
pub fn trace_split(
    scene: &Scene,
    targets: &[Option<IrradianceTarget>],
    s: &LightTraceSettings,
    on_batch: &(dyn Fn() + Sync),
    cancel: Option<&std::sync::atomic::AtomicBool>,
    comm: &dyn crate::dist::Comm,
) -> Option<LightTraceOutput> {
    let Some(sampler) = scene.light_sampler() else {
        return Some(LightTraceOutput { maps: empty_maps(targets), paths: 0, nonfinite: 0 });
    };
    let mut shift = 0;
    loop {
        let fp = FixedPoint::new(scene, targets, s.paths, shift);
        match trace_fixed(scene, sampler, targets, s, &fp, on_batch, Engine::Auto, cancel, comm) {
            Ok(out) => return Some(out),
            Err(Stop::Cancelled) => return None,
            // Some shape's deposits summed to ≥ 2⁶³ units: a texel may have overflowed. Trace
            // again with a coarser unit (never seen in practice; the result stays deterministic
            // since the decision depends on exact integer sums only).
            Err(Stop::Rescale(bits)) => shift -= bits,
        }
    }
}

/// Why [`trace_fixed`] gave no maps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Stop {
    /// The fixed-point scale must shrink by `2^bits`.
    Rescale(i32),
    /// The cancel flag was set.
    Cancelled,
}

/// How the paths are traced (tests compare the three; results are identical).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Engine {
    /// The wavefront when every material is Lambertian (rays traced as
    /// [`RayPacket`](crate::accel::packet::RayPacket)s through [`crate::accel::Accel::intersect8`]),
    /// else one path at a time.
    Auto,
    /// The wavefront with one `Scene::intersect_hit` per lane.
    #[cfg_attr(not(test), allow(dead_code))]
    WavefrontRays,
    /// One path at a time ([`trace_path`]).
    #[cfg_attr(not(test), allow(dead_code))]
    Scalar,
}

/// One pass at a fixed-point scale; `Err(Stop::Rescale(bits))` when the scale must shrink by
/// `2^bits`, `Err(Stop::Cancelled)` when `cancel` was set during the pass (on any rank).
#[allow(clippy::too_many_arguments)]
fn trace_fixed(
    scene: &Scene,
    sampler: &crate::light::LightSampler,
    targets: &[Option<IrradianceTarget>],
    s: &LightTraceSettings,
    fp: &FixedPoint,
    on_batch: &(dyn Fn() + Sync),
    engine: Engine,
    cancel: Option<&std::sync::atomic::AtomicBool>,
    comm: &dyn crate::dist::Comm,
) -> Result<LightTraceOutput, Stop> {
    use std::sync::atomic::{AtomicU64, Ordering};
    let batch = s.batch_size.max(1);
    // this process's batches (all of them when it is alone)
    let mine: Vec<u64> = (0..s.paths.div_ceil(batch)).filter(|&b| comm.owns(b)).collect();
    let n_batches = mine.len() as u64;
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
    // The wavefront's eight rays go through `Accel::intersect8` (tests may ask for one
    // `Scene::intersect_hit` per lane instead).
    let accel = (engine == Engine::Auto).then(|| scene.accel());
    let results: Vec<(Acc, u64)> = (0..workers)
        .into_par_iter()
        .map(|_| {
            let mut sink = Sink::new(empty_acc(targets, s.direct));
            let mut bad = 0u64;
            loop {
                if cancel.is_some_and(|c| c.load(Ordering::Relaxed)) {
                    break;
                }
                let j = next.fetch_add(1, Ordering::Relaxed);
                if j >= n_batches {
                    break;
                }
                let b = mine[j as usize];
                let paths = b * batch..((b + 1) * batch).min(s.paths);
                let mut ctx = PathCtx { scene, sampler, prims: &prims, sink: &mut sink, s, bad: &mut bad };
                if let Some(tab) = &wavefront {
                    Wavefront::run(&mut ctx, tab, &stream, paths, accel);
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
    // cancelled on any rank: every rank drops the pass (a collective, so all decide alike)
    let mut stop = [cancel.is_some_and(|c| c.load(Ordering::Relaxed)) as u64];
    if comm.size() > 1 {
        comm.all_sum_u64(&mut stop);
    }
    if stop[0] > 0 {
        return Err(Stop::Cancelled);
    }
    let mut nonfinite = [results.iter().map(|r| r.1).sum::<u64>()];
    let mut accs: Vec<Acc> = results.into_iter().map(|r| r.0).collect();
    if accs.is_empty() {
        // a rank without batches (more ranks than batches) adds zeros
        accs.push(empty_acc(targets, s.direct));
    }
    // overflow check: the exact sum of |units| of a shape bounds each of its texels' sums
    let mut totals: Vec<u128> = (0..targets.len())
        .map(|k| accs.iter().filter_map(|a| a[k].as_ref()).map(|m| m.total).sum())
        .collect();
    if comm.size() > 1 {
        comm.all_sum_u64(&mut nonfinite);
        let mut p = crate::dist::Packer::default();
        for t in &totals {
            p.u64(*t as u64);
            p.u64((*t >> 64) as u64);
        }
        let all = comm.all_gather_bytes(&p.0);
        let mut readers: Vec<crate::dist::Unpacker> = all.iter().map(|b| crate::dist::Unpacker(b)).collect();
        for t in totals.iter_mut() {
            *t = readers.iter_mut().map(|r| r.u64() as u128 | (r.u64() as u128) << 64).sum();
        }
    }
    let nonfinite = nonfinite[0];
    for &total in &totals {
        if total >= 1u128 << 63 {
            let bits = (128 - total.leading_zeros()) as i32 - 62;
            return Err(Stop::Rescale(bits.max(1)));
        }
    }
    // reduce: wrapping integer sums (exact since no texel's true sum reaches 2⁶³), then scale
    let (first, rest) = accs.split_first_mut().expect("at least one worker");
    let one = |(k, m): (usize, &mut Option<_>)| {
        let m: fixed_point::ShapeAcc = m.take()?;
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
        let (direct, indirect) = if comm.size() > 1 {
            let sums = |own: &Cells, direct: bool| {
                let mut sum = local_sums(own, rest, k, direct);
                comm.all_sum_u64(&mut sum);
                sum.chunks_exact(3).map(|c| std::array::from_fn(|i| c[i] as i64 as f64 * unit)).collect()
            };
            (sums(&m.direct, true), sums(&m.indirect, false))
        } else {
            (reduce(&m.direct, true), reduce(&m.indirect, false))
        };
        Some(IrradianceMaps { width, height, direct, indirect })
    };
    // the sums over processes are collectives: every rank makes them in the same (shape) order
    let maps = if comm.size() > 1 {
        first.iter_mut().enumerate().map(one).collect()
    } else {
        first.par_iter_mut().enumerate().map(one).collect()
    };
    Ok(LightTraceOutput { maps, paths: s.paths, nonfinite })
}

/// The texel sums of shape `k`'s direct or indirect map over this process's workers (`own` and
/// `rest`), as wrapping `u64`s (the bits of the `i64` sums) for the sum over processes.
fn local_sums(own: &Cells, rest: &[Acc], k: usize, direct: bool) -> Vec<u64> {
    (0..own.fine.len())
        .into_par_iter()
        .map(|i| {
            let mut x = own.get(i);
            for a in rest {
                let o = a[k].as_ref().expect("same targets");
                x = x.wrapping_add(if direct { &o.direct } else { &o.indirect }.get(i));
            }
            x as u64
        })
        .collect()
}
