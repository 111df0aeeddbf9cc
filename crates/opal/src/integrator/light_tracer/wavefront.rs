//! [`W`] light paths advanced together ([`Wavefront`], scenes whose materials are all
//! Lambertian): the lane state ([`Lanes`]), the triangle table ([`LambertTable`], one [`Row`]
//! per triangle) and the portable lane kernels ([`scatter_lanes`] and its helpers), which the
//! AVX2 steps (`avx.rs`) compile with AVX2. Every path is bit for bit the path
//! [`trace_path`] traces alone.
//!
//! Tests (`tests.rs`): identical sums for the wavefront with ray packets, the wavefront with
//! one ray per lane and one path at a time; `simd_generators_draw_the_scalar_numbers`.

#[cfg(target_arch = "x86_64")]
use super::avx;
#[cfg(target_arch = "x86_64")]
use super::path::deposit;
use super::path::{PathCtx, trace_path};
#[cfg(target_arch = "x86_64")]
use super::prims::{Mat, Prim};
#[cfg(target_arch = "x86_64")]
use super::starts::starts;
use super::starts::{LightRows, StartBlock, light_rows};
use crate::accel::Accel;
#[cfg(target_arch = "x86_64")]
use crate::accel::packet::PacketHits;
use crate::accel::packet::RayPacket;
use crate::math::{INV_PI, Vec2};
use crate::sampling::RngStream;
use crate::scene::Scene;
use crate::spectrum::Spectrum;
use crate::texture::Texture;

/// Paths advanced together by [`Wavefront`] (one per SIMD lane).
pub(super) const W: usize = 8;

/// Sets of [`W`] lanes advanced in step: their rays are traced in one call
/// ([`Accel::intersect8_many`]), so that a split structure fills its BVH streams with the rays
/// of all sets that enter it (on an object in a room about one in six per set).
const SETS: usize = 4;
// (sets go in pairs to the 16-lane packet kernel)
const _: () = assert!(SETS.is_multiple_of(2));

/// Inputs of the Lambertian scattering of [`W`] vertices, one per lane (structure of arrays),
/// besides the rays that reached them.
#[derive(Clone, Copy, Default)]
pub(super) struct ScatterIn {
    /// Hit distance along the lane's ray (the vertex is `o + d·t`).
    pub(super) t: [f32; W],
    /// Unit geometric normal and its re-normalised copy for the ray offset.
    pub(super) ng: [[f32; W]; 3],
    pub(super) ng_off: [[f32; W]; 3],
    /// Corner shading normals (`has_n` = the mesh has normals), barycentrics.
    pub(super) n: [[[f32; W]; 3]; 3],
    pub(super) has_n: [u32; W],
    pub(super) two_sided: [u32; W],
    pub(super) b: [[f32; W]; 3],
    /// The direction sample.
    u: [[f32; W]; 2],
}

/// Outputs: the next ray and the ratio `|cos θi| / pdf`; `valid` = 0 where the path ends.
#[derive(Clone, Copy, Default)]
pub(super) struct ScatterOut {
    pub(super) o: [[f32; W]; 3],
    pub(super) d: [[f32; W]; 3],
    pub(super) ratio: [f32; W],
    pub(super) valid: [u32; W],
}

/// `[f(0), f(1), f(2)]`. In the SIMD kernels instead of `std::array::from_fn`, whose closure
/// wrappers the compiler kept out of line, compiled without AVX2 (SSE halves through memory).
#[inline(always)]
pub(super) fn each3<T>(f: impl Fn(usize) -> T) -> [T; 3] {
    [f(0), f(1), f(2)]
}

/// `square_to_cosine_hemisphere(u)` on [`W`] lanes (concentric map with
/// `fastmath::sincos_2pi`, selects for its branches): `[x, y, z]`, the same bits per lane.
#[inline(always)]
pub(super) fn cosine_hemisphere_lanes(
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
    // `oy / ox` or `ox / oy`: one division of the operands each lane's branch divides
    let eighth = (wide_x.select(oy, ox) / r) * 0.125;
    let turns = wide_x.select(eighth, 0.25 - eighth);
    let (sn, cs) = wide::sincos_2pi(turns);
    let dx = at_centre.select(zero, r * cs);
    let dy = at_centre.select(zero, r * sn);
    [dx, dy, (1.0 - (dx * dx + dy * dy)).max(zero).sqrt()]
}

/// [`crate::integrator::offset_ray_origin`]`(p, n, dir)` on [`W`] lanes, `n_off` being the normal's
/// `normalize_or_zero` (the same bits per lane).
#[inline(always)]
pub(super) fn offset_lanes(
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
/// order (`glam`'s component formulas, [`Frame::from_normal`](crate::math::Frame::from_normal),
/// the concentric map with `fastmath::sincos_2pi`, [`crate::integrator::offset_ray_origin`]),
/// with selects for branches, hence the same bits in every lane (no fused multiply-add is ever
/// formed).
#[inline(always)]
pub(super) fn scatter_lanes<const NORMALS: bool>(rays: &RayPacket, i: &ScatterIn) -> ScatterOut {
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
pub(super) struct Wavefront;

/// Per-triangle data of the wavefront (see [`Prim`]), one row of 32 floats per triangle so a
/// lane's value is one load at a fixed offset (fields: the `ROW_*` constants).
#[derive(Clone, Copy)]
#[repr(C, align(64))]
pub(super) struct Row(pub(super) [f32; 32]);

/// Offsets in a [`Row`]: unit geometric normal, its offset copy, corner uvs `(u0, v0, u1, …)`,
/// `kd_pi` (ρ/π of a constant reflectance, zero for a bitmap) and the flags (bits of a `u32`:
/// [`FLAG_TWO_SIDED`], [`FLAG_BITMAP`]) fill the first 16 floats, which [`avx::vertices`] reads
/// with two 8×8 transposes; then corner normals (9, zero without normals) and "has normals"
/// (all bits set = true).
pub(super) const ROW_NG: usize = 0;
pub(super) const ROW_NG_OFF: usize = 3;
pub(super) const ROW_UV: usize = 6;
pub(super) const ROW_KD: usize = 12;
pub(super) const ROW_FLAGS: usize = 15;
pub(super) const ROW_N: usize = 16;
pub(super) const ROW_HAS_N: usize = 25;
/// Deposit map width and height (as f32, exact: maps are at most 4096 texels wide).
pub(super) const ROW_SIZE: usize = 26;
/// The shape (bits of an `i32`) of a triangle whose hits deposit (`factor > 0`), else −1.
pub(super) const ROW_SHAPE: usize = 28;
/// The triangle's shape (bits of a `u32`), for its bitmap ([`LambertTable::tex`]).
pub(super) const ROW_TEX: usize = 29;
/// The deposit factor [`Prim::factor`] (the bits of an `f64`, low half first; 8-byte aligned):
/// read from the row, which the deposit loads anyway, instead of from a table of its own
/// (a second cache miss per hit in scenes of many triangles).
pub(super) const ROW_FACTOR: usize = 30;
/// Bits of [`ROW_FLAGS`]: two-sided material, bitmap reflectance.
pub(super) const FLAG_TWO_SIDED: u32 = 1;
pub(super) const FLAG_BITMAP: u32 = 2;

/// Bytes of rows beyond which the hit triangles' rows are prefetched after each trace (half an
/// L2 cache: the Cornell box's 32 rows stay in L1 and skip the prefetches).
const PREFETCH_ROWS_BYTES: usize = 512 << 10;

/// The wavefront's triangle table: rows, the bitmap of each shape with a bitmap
/// reflectance, and whether any triangle has corner normals.
pub(super) struct LambertTable<'a> {
    rows: Vec<Row>,
    /// Per shape (a row's [`ROW_TEX`]): its bitmap reflectance, if any.
    tex: Vec<Option<&'a Texture>>,
    any_normals: bool,
    /// Whether every map is small enough for [`avx::deposit_values`] (sizes exact in f32,
    /// `3·w·h` in i32); otherwise every deposit takes [`deposit`].
    vector_deposits: bool,
    /// Whether the rows exceed [`PREFETCH_ROWS_BYTES`]: the hit triangles' rows are then
    /// prefetched right after the trace.
    prefetch_rows: bool,
    /// The scene's lights as the path starts need them ([`light_rows`]).
    lights: LightRows,
}

impl<'a> LambertTable<'a> {
    /// `None` unless every triangle is Lambertian.
    pub(super) fn new(scene: &Scene, prims: &[Prim<'a>]) -> Option<LambertTable<'a>> {
        let flag = |b: bool| f32::from_bits(if b { u32::MAX } else { 0 });
        let mut rows = Vec::with_capacity(prims.len());
        let mut tex = vec![None; scene.shapes.len()];
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
            r[ROW_TEX] = f32::from_bits(p.shape);
            let f = p.factor.to_bits();
            r[ROW_FACTOR] = f32::from_bits(f as u32);
            r[ROW_FACTOR + 1] = f32::from_bits((f >> 32) as u32);
            rows.push(Row(r));
            // (a shape's triangles share its material)
            tex[p.shape as usize] = p.kd_pi.is_none().then_some(t);
        }
        let any_normals = prims.iter().any(|p| p.normals.is_some());
        let vector_deposits = prims.iter().all(|p| {
            p.width <= 1 << 16
                && p.height <= 1 << 16
                && 3 * p.width as u64 * p.height as u64 <= i32::MAX as u64
        });
        let prefetch_rows = rows.len() * std::mem::size_of::<Row>() > PREFETCH_ROWS_BYTES;
        Some(LambertTable {
            rows,
            tex,
            any_normals,
            vector_deposits,
            prefetch_rows,
            lights: light_rows(scene),
        })
    }
}

/// The state of the [`W`] lanes of a [`Wavefront`] (structure of arrays): lane `l` holds a path
/// iff bit `l` of `active` is set.
struct Lanes<'a> {
    /// The rays to trace next (inactive lanes: `tmax = 0`, never hit).
    rays: RayPacket,
    /// Each lane's generator, as structure of arrays (state, increment: see [`crate::sampling::Rng`]), so the
    /// direction samples are drawn for all lanes at once ([`avx::next_f32_lanes`]).
    rng_state: [u64; W],
    rng_inc: [u64; W],
    /// Path weights β.
    beta: [[f32; W]; 3],
    /// `max_c β_c` at the light (the roulette's reference, see [`super::path::survival`]).
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
    uv: [[f32; W]; 2],
    active: u32,
}

impl Lanes<'_> {
    /// `vertex`'s pending weights `kd_pi · ratio` (bitmap albedos looked up first) and, from
    /// `rr_depth` on, the roulette of the lanes in `m`; they are no longer pending. Returns the
    /// lanes whose path ends.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn settle(&mut self, m: u32, rr_depth: i32) -> u32 {
        // the lanes of one texture at a time: bilinear lookups inside the image in lanes
        // (`avx::bilinear_lanes`, the same bits; which bitmaps: `lanes_take`), the others through
        // `Texture::eval`
        let mut todo = m & self.bitmap;
        while todo != 0 {
            let tex = self.tex[todo.trailing_zeros() as usize].expect("bitmap lanes hold their texture");
            let same = todo & mask(|l| self.tex[l].is_some_and(|t| std::ptr::eq(t, tex)));
            let done = match tex {
                // SAFETY: the wavefront runs on CPUs with AVX2 only (`Wavefront::available`).
                Texture::Bitmap(b) if lanes_take(b) => unsafe {
                    avx::bilinear_lanes(&b.image, &self.uv, same, &mut self.kd_pi)
                },
                _ => 0,
            };
            for l in lanes_of(same & !done) {
                let k = tex.eval(Vec2::new(self.uv[0][l], self.uv[1][l])) * INV_PI;
                for c in 0..3 {
                    self.kd_pi[c][l] = k[c];
                }
            }
            todo &= !same;
        }
        // SAFETY: the wavefront runs on CPUs with AVX2 only (`Wavefront::available`).
        let black = unsafe { avx::pending_weights(&mut self.beta, &self.kd_pi, &self.ratio, m) };
        let mut dead = m & black;
        if rr_depth >= 0 {
            // SAFETY: as above.
            dead |= unsafe {
                let r = m & !dead & avx::at_least(&self.depth, rr_depth);
                avx::roulette(&mut self.beta, &self.b0, &mut self.rng_state, &self.rng_inc, r)
            };
        }
        self.pending &= !m;
        dead
    }
}

/// Indices of the set bits of `m`, lowest first.
#[inline(always)]
pub(super) fn lanes_of(mut m: u32) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        (m != 0).then(|| {
            let l = m.trailing_zeros() as usize;
            m &= m - 1;
            l
        })
    })
}

impl<'a> Lanes<'a> {
    /// Takes the vertices' uvs and records the texture of each lane in `bitmap` (triangle rows
    /// `prim`). When the lanes share one bilinear bitmap read in lanes ([`lanes_take`]), looks
    /// their albedos up now ([`avx::bilinear_lanes`]) and takes them out of `bitmap`; the
    /// others' texels are prefetched ([`Texture::prefetch`]) for their lookup in
    /// [`Lanes::settle`].
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn bitmap_albedos(&mut self, tab: &LambertTable<'a>, prim: &[u32; W], uv: &[[f32; W]; 2]) {
        self.uv = *uv;
        let mut first: Option<&Texture> = None;
        let mut one_texture = true;
        for l in lanes_of(self.bitmap) {
            let shape = tab.rows[prim[l] as usize].0[ROW_TEX].to_bits();
            let tex = tab.tex[shape as usize].expect("bitmap rows have a texture");
            self.tex[l] = Some(tex);
            one_texture &= first.is_none_or(|t| std::ptr::eq(t, tex));
            first = Some(tex);
        }
        let mut todo = self.bitmap;
        if let (true, Some(Texture::Bitmap(b))) = (one_texture, first)
            && lanes_take(b)
        {
            // looked up now: measured 0.97x the pass's CPU-s of a prefetch now and the lookup
            // at the settling (the texels are mostly cache hits; the taps are computed once)
            // SAFETY: the wavefront runs on CPUs with AVX2 only (`Wavefront::available`).
            let done = unsafe { avx::bilinear_lanes(&b.image, uv, todo, &mut self.kd_pi) };
            self.bitmap &= !done;
            todo &= !done;
        }
        for l in lanes_of(todo) {
            let tex = self.tex[l].expect("bitmap lanes hold their texture");
            tex.prefetch(Vec2::new(uv[0][l], uv[1][l]));
        }
    }

    /// Puts a new path into lane `l`: the start `k` of block `b`.
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
        self.rng_state[l] = b.rng_state[k];
        self.rng_inc[l] = b.rng_inc[k];
        self.active |= 1 << l;
        self.pending &= !(1 << l);
        self.bitmap &= !(1 << l);
    }
}

/// What [`avx::deposit_values`] computes: per lane the texel index, the units (exact for the
/// lanes in `small`, whose units are below 2³¹ in magnitude; the others are left to
/// [`deposit`]), their sum of magnitudes and the map number `2·shape + direct`; `target` =
/// the lanes whose triangle's hits deposit.
#[derive(Default)]
pub(super) struct DepositLanes {
    pub(super) index: [i32; W],
    pub(super) value: [[i32; W]; 3],
    pub(super) units: [u64; W],
    pub(super) map: [i32; W],
    pub(super) small: u32,
    pub(super) target: u32,
}

/// What [`avx::vertices`] computes besides the kernel's inputs.
#[derive(Clone, Copy)]
pub(super) struct VertexLanes {
    /// Interpolated texture coordinates.
    pub(super) uv: [[f32; W]; 2],
    /// `kd_pi` of the triangles (zero for bitmaps).
    pub(super) kd_pi: [[f32; W]; 3],
    /// Lanes that hit a front side; lanes whose triangle has a bitmap reflectance.
    pub(super) front: u32,
    pub(super) bitmap: u32,
}

impl Wavefront {
    /// Whether this CPU runs the wavefront (AVX2); otherwise the paths are traced one at a time
    /// ([`trace_path`], same results).
    pub(super) fn available() -> bool {
        // detected once per process (`crate::simd`)
        crate::simd::isa().avx2()
    }

    /// Traces `paths` (the caller checked [`Wavefront::available`]).
    pub(super) fn run<'a>(
        ctx: &mut PathCtx<'a, '_>,
        tab: &LambertTable<'a>,
        stream: &RngStream,
        paths: std::ops::Range<u64>,
        accel: Option<&Accel>,
    ) {
        #[cfg(target_arch = "x86_64")]
        if Wavefront::available() {
            // SAFETY: the CPU supports AVX2 (checked just above).
            return unsafe { Wavefront::run_avx2(ctx, tab, stream, paths, accel) };
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
        accel: Option<&Accel>,
    ) {
        let (scene, sampler, s) = (ctx.scene, ctx.sampler, ctx.s);
        let mut lns: [Lanes; SETS] = std::array::from_fn(|_| Lanes {
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
            uv: [[0.0; W]; 2],
            active: 0,
        });
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
        for ln in lns.iter_mut() {
            for l in 0..W {
                refill(ln, l);
            }
        }
        let rows = &tab.rows[..];
        let mut inps = [ScatterIn::default(); SETS];
        let mut rays = [RayPacket::default(); SETS];
        let mut all_hits = [PacketHits::NONE; SETS];
        while lns.iter().any(|ln| ln.active != 0) {
            match accel {
                // (inlined into this AVX2 function)
                // two sets per call where AVX-512 was detected (the same hits, half the work
                // per ray: `accel/packet_avx512.rs`)
                Some(Accel::Tiny { packet, .. }) if packet.avx512() => {
                    for (h, ln) in all_hits.chunks_exact_mut(2).zip(lns.chunks_exact(2)) {
                        if ln[0].active | ln[1].active != 0 {
                            // SAFETY: the CPU supports AVX-512 (detected when `packet` was built).
                            [h[0], h[1]] = unsafe { packet.intersect16_avx512(&ln[0].rays, &ln[1].rays) };
                        }
                    }
                }
                Some(Accel::Tiny { packet, .. }) => {
                    for (h, ln) in all_hits.iter_mut().zip(&lns) {
                        if ln.active != 0 {
                            *h = packet.intersect_avx2(&ln.rays);
                        }
                    }
                }
                // the split structure gathers the rays entering its BVH from all sets
                Some(a) => {
                    for (r, ln) in rays.iter_mut().zip(&lns) {
                        *r = ln.rays;
                    }
                    a.intersect8_many(&rays, &mut all_hits)
                }
                None => {
                    for (h, ln) in all_hits.iter_mut().zip(&lns) {
                        *h = PacketHits::NONE;
                        for l in lanes_of(ln.active) {
                            h.set(l, scene.intersect_hit(&ln.rays.ray(l)));
                        }
                    }
                }
            }
            // the hit triangles' rows of all sets, prefetched before the first set reads its rows
            // (scenes of many triangles: their rows are far beyond the caches)
            if tab.prefetch_rows {
                for (hits, ln) in all_hits.iter().zip(&lns) {
                    for l in lanes_of(ln.active & avx::at_least(&hits.prim, 0)) {
                        let row = &rows[hits.prim[l] as usize].0;
                        crate::simd::prefetch(&row[0]);
                        crate::simd::prefetch(&row[16]);
                    }
                }
            }
            // Two rounds over the sets: first the vertices (deposits, scattering, bitmap
            // albedos or their prefetches), then the early roulette and the refills, so that a
            // bitmap lookup left to the early roulette finds its texels prefetched while the
            // other sets were scattered.
            // Same draws per path, same refill order (set by set, lane by lane): same paths.
            // (the scattering of two sets at a time: `avx::scatter2`)
            let mut alive_of = [0u32; SETS];
            let mut verts: [Option<([u32; W], VertexLanes)>; SETS] = [None; SETS];
            for (k, (ln, hits)) in lns.iter_mut().zip(&all_hits).enumerate() {
                if ln.active == 0 {
                    continue;
                }
                let inp = &mut inps[k];
                // A lane whose ray missed ends (its pending weight and roulette change nothing).
                let hit = ln.active & avx::at_least(&hits.prim, 0);
                // `vertex`: the pending weights (bitmap albedos looked up now) of the lanes that hit
                // (lanes facing the roulette settled theirs before the trace, see below)
                let mut alive = hit & !ln.settle(ln.pending & hit, s.rr_depth);
                // the new vertices: triangle data, deposits, direction samples, scattering
                if alive != 0 {
                    avx::increment(&mut ln.depth, alive);
                    // the hit triangles (0 in the other lanes)
                    let prim = avx::select_u32(&hits.prim, alive);
                    let v = avx::vertices(rows, &prim, hits, &ln.rays.d, tab.any_normals, inp);
                    let front = alive & v.front;
                    if front != 0 {
                        let dv = if tab.vector_deposits {
                            avx::deposit_values(rows, &prim, &v.uv, &ln.beta, &ln.depth)
                        } else {
                            // (no lane small: every deposit through `deposit`)
                            DepositLanes::default()
                        };
                        // `deposit` of the lanes whose units fit the queue, straight into the sink
                        // (first-hit deposits only when asked for)
                        let quick = front & dv.small & dv.target;
                        let skip = if s.direct { 0 } else { quick & !avx::at_least(&ln.depth, 2) };
                        for l in lanes_of(quick & !skip) {
                            let value = [dv.value[0][l], dv.value[1][l], dv.value[2][l]];
                            ctx.sink.push_small(dv.map[l] as u32, dv.index[l] as u32, value, dv.units[l]);
                        }
                        for l in lanes_of(front & !quick) {
                            let pr = &ctx.prims[prim[l] as usize];
                            let beta = Spectrum([ln.beta[0][l], ln.beta[1][l], ln.beta[2][l]]);
                            let uv = Vec2::new(v.uv[0][l], v.uv[1][l]);
                            deposit(ctx.sink, ctx.bad, s, pr, uv, beta, ln.depth[l]);
                        }
                    }
                    if s.max_depth >= 0 {
                        alive &= !avx::at_least(&ln.depth, s.max_depth);
                    }
                    // `Lambert::sample`: a number drawn for the generic sampler, then the direction sample
                    // (the same draws per lane as `Rng::next_f32`, eight lanes at a time)
                    inp.u = avx::draws::<2, 1>(&mut ln.rng_state, &ln.rng_inc, alive);
                    verts[k] = Some((prim, v));
                }
                alive_of[k] = alive;
            }
            for (k, pair) in lns.chunks_exact_mut(2).enumerate() {
                let (k0, k1) = (2 * k, 2 * k + 1);
                if verts[k0].is_none() && verts[k1].is_none() {
                    continue;
                }
                let [a, b] = pair else { unreachable!("pairs") };
                let (alive0, alive1) = (alive_of[k0], alive_of[k1]);
                [alive_of[k0], alive_of[k1]] = avx::scatter2(
                    [&mut a.rays, &mut b.rays],
                    [&inps[k0], &inps[k1]],
                    [alive0, alive1],
                    [&mut a.ratio, &mut b.ratio],
                    tab.any_normals,
                );
            }
            for (k, ln) in lns.iter_mut().enumerate() {
                if ln.active == 0 {
                    continue;
                }
                let alive = alive_of[k];
                if let Some((prim, v)) = &verts[k] {
                    ln.kd_pi = v.kd_pi;
                    ln.bitmap = alive & v.bitmap;
                    ln.bitmap_albedos(tab, prim, &v.uv);
                }
                ln.pending = alive;
            }
            for (ln, &alive) in lns.iter_mut().zip(&alive_of) {
                if ln.active == 0 {
                    continue;
                }
                let mut alive = alive;
                if s.rr_depth >= 0 {
                    // Lanes whose next vertex faces the roulette settle their pending weight and
                    // draw the roulette now, before their ray is traced: a path the roulette ends
                    // traces no ray for nothing. Same numbers in the same order as `vertex` (no
                    // draw of the path comes between), same deposits: a lane that would have
                    // missed ends either way.
                    let early = alive & avx::at_least(&ln.depth, s.rr_depth);
                    if early != 0 {
                        alive &= !ln.settle(early, s.rr_depth);
                    }
                }
                let ended = ln.active & !alive;
                ln.active = alive;
                for l in lanes_of(ended) {
                    refill(ln, l);
                }
            }
        }
    }
}

/// `f32` texels of a bitmap up to which its bilinear lookups run in lanes even when it has a
/// palette (1 MiB, an L2 cache: a 256² texture).
const LANE_BITMAP_BYTES: usize = 1 << 20;

/// Whether the bilinear lookups of `b` run in lanes ([`avx::bilinear_lanes`], reading the
/// `f32` texels): bilinear bitmaps, except those with a palette beyond [`LANE_BITMAP_BYTES`],
/// which `Texture::eval` reads through one-byte codes (a third of the bytes). Both give the
/// same bits. Measured (performance.md): the scan room's 512² PNG through its palette 0.93–0.99×
/// the pass's CPU-s; the Cornell box's 256² EXR (a palette of 159 values) 1.01–1.04× slower.
#[cfg(target_arch = "x86_64")]
fn lanes_take(b: &crate::texture::Bitmap) -> bool {
    let bytes = b.image.data.len() * std::mem::size_of::<Spectrum>();
    b.filter == crate::scene::desc::FilterType::Bilinear && !(b.has_palette() && bytes > LANE_BITMAP_BYTES)
}

/// Mask of the lanes where `f(l)` holds.
#[inline(always)]
pub(super) fn mask(f: impl Fn(usize) -> bool) -> u32 {
    (0..W).fold(0, |m, l| m | ((f(l) as u32) << l))
}
