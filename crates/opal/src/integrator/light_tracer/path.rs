//! One light path at a time, any material: the reference engine ([`trace_path`]) that the
//! wavefront reproduces bit for bit, and the steps both share (path start, vertex, deposit,
//! Russian roulette).
//!
//! Tests (`tests.rs`): the analytic and quadrature checks, the generic f64 pass (which uses
//! the same random stream, [`RNG_STREAM`]) and the identical sums of the three engines.

use super::LightTraceSettings;
use super::prims::{Mat, Prim, Weight};
use super::sink::{Pending, Sink};
use crate::accel::Hit;
use crate::bsdf::{Bxdf, TransportMode};
use crate::geometry::Ray;
use crate::math::{Frame, Vec2, Vec3};
use crate::sampling::{Rng, square_to_cosine_hemisphere, square_to_cosine_hemisphere_pdf};
use crate::scene::Scene;
use crate::spectrum::Spectrum;

/// Random stream of the light paths: path `i` draws from `RngStream::new(seed, RNG_STREAM).rng(i)`.
pub(super) const RNG_STREAM: u64 = 0x4c54;

/// What every path of a pass shares.
pub(super) struct PathCtx<'a, 'b> {
    pub(super) scene: &'a Scene,
    pub(super) sampler: &'a crate::light::LightSampler,
    pub(super) prims: &'b [Prim<'a>],
    pub(super) sink: &'b mut Sink,
    pub(super) s: &'b LightTraceSettings,
    /// Non-finite deposits dropped.
    pub(super) bad: &'b mut u64,
}

/// A path between two vertices: the ray to trace next, the weight β, the roulette's reference
/// weight and the scattering weight of the last vertex, applied after the ray is traced so that
/// the texture lookup's cache miss overlaps the traversal.
pub(super) struct PathState<'a> {
    pub(super) rng: Rng,
    pub(super) ray: Ray,
    pub(super) beta: Spectrum,
    /// `max_c β_c` at the light: the roulette survives with `min(max_c β_c / b0, 0.95)`.
    b0: f32,
    depth: i32,
    pending: Option<Weight<'a>>,
}

/// Starts a path: light chosen by power, emitted ray (offset off area lights), initial weight
/// `β = Le·cos/(pmf·pdf_pos·pdf_dir)`. `None` when the sample carries nothing.
#[inline]
pub(super) fn start_path<'a>(
    scene: &Scene,
    sampler: &crate::light::LightSampler,
    mut rng: Rng,
) -> Option<PathState<'a>> {
    let (li, pmf) = sampler.choose(rng.next_f32());
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
        ray = crate::integrator::spawn_ray(ray.o, es.n, ray.d);
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
pub(super) fn deposit(
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
/// and adds them [`QUEUE`](super::sink::QUEUE) deposits later (integer sums: the order of
/// additions does not matter).
/// Likewise the albedo lookup of a Lambertian vertex (its sampled direction does not depend on
/// the albedo), and with it the Russian roulette, which consumes its random number after the
/// vertex's direction sample: a path killed by the roulette has traced one ray for nothing
/// (from `rr_depth` on only).
#[inline]
pub(super) fn trace_path(ctx: &mut PathCtx, rng: Rng) {
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
                st.ray = crate::integrator::spawn_ray(p, pr.ng, frame.to_world(wi));
            }
            Mat::Generic => {
                let si = ctx.scene.interaction(&st.ray, &h);
                let (frame, bsdf) = ctx.scene.bsdf(&si, wo);
                let wo_l = frame.to_local(wo);
                let uc = st.rng.next_f32();
                let u: Vec2 = st.rng.next_2d();
                let Some(bs) = bsdf.sample(wo_l, uc, u, TransportMode::Importance) else { break };
                st.pending = Some(Weight::Known(bs.weight()));
                st.ray = crate::integrator::spawn_ray(si.p, si.ng, frame.to_world(bs.wi));
            }
        }
    }
}

/// Survival probability for Russian roulette: the throughput relative to the path's initial
/// weight `b0 = max_c β_c` at the light (so the roulette does not depend on the absolute power),
/// capped at 0.95.
#[inline]
pub(super) fn survival(beta: Spectrum, b0: f32) -> f32 {
    if b0 > 0.0 { (beta.max_component() / b0).min(0.95) } else { 0.0 }
}
