//! The row wavefront of all-diffuse scenes lit by emitting triangles, with the eight lanes'
//! path state held as a **structure of arrays**: rays, throughputs, radiance sums, depths and
//! the previous vertices live in `[f32; 8]` arrays that feed the ray packets, the hit
//! reconstruction and the wide vertex ([`super::wide::vertex_lanes`]) directly, without packing a
//! lane's structures into lanes and back at every step.
//!
//! A row runs [`SETS`] such sets of eight lanes in step: all sets' rays are traced in one call
//! ([`crate::accel::Accel::intersect8_many`], the shadow rays in one
//! [`crate::accel::Accel::occluded8_many`]), so that a split structure fills its BVH streams
//! with the rays of all sets that enter it; then each set is shaded in turn.
//!
//! Per step: the lanes' rays are traced together ([`crate::accel::Accel::intersect8`]); each hit
//! triangle's **row** (a 128-byte record built once per render: geometric normal, corner uvs,
//! corner normals, shape, light, flags, constant albedo — [`super::wide_tables`]) is copied into the lanes,
//! and the hit point, shading normal and uv are reconstructed for the eight lanes at once with
//! the operations of [`Scene::interaction_at`] ([`locate`], for all sets before any is shaded);
//! bitmap texels are prefetched as soon as the uvs are known and looked up after the lanes'
//! random numbers are drawn, so the later sets' texels arrive while the earlier sets are shaded. Emitters found at a hit
//! (rare) go through the scalar [`super::emission`]. Then the wide vertex, the Russian roulette,
//! the batched shadow rays ([`crate::accel::Accel::occluded8`]; those of all sets compacted into
//! as few full packets as they fill, see [`trace_shadows`]) and the pixel bookkeeping.
//!
//! **Scalar original**: [`super::render_row_scalar`] (one path at a time through
//! [`super::vertex`]). Every lane draws the same numbers in the same order and performs the same
//! IEEE operations in the same order (no fused multiply-add), so the row is **the same bits** as
//! the scalar row, in the AVX2 and in the portable compilation.
//!
//! Tests: `super::tests` (`wavefront_rows_equal_scalar_rows_bit_for_bit`: the Cornell box;
//! `wide_rows_on_a_textured_mesh_equal_scalar_rows`: a textured sphere with corner normals, a
//! two-sided box, behind `Accel::Split` and a plain BVH);
//! `compacted_shadow_packets_match_the_portable_packing` (below: the AVX2 packing of the shadow
//! rays against the lane-by-lane one).

// lane loops index several arrays by the lane
#![allow(clippy::needless_range_loop)]

use super::wavefront::fill_inactive;
use super::wide::{self, Kernel, V3, VertexIn, W};
use super::wide_tables::{
    F_CONST, F_NORMALS, F_TWO_SIDED, F_UVS, FIELDS, Gathered, NO_LIGHT, R_ALBEDO, R_FLAGS, R_LIGHT, R_N,
    R_NG, R_SHAPE, R_UV, Tables, gather,
};
use super::{PathSettings, PathState, PixelSums, Row, emission};
use crate::accel::packet::{PacketHits, RayPacket};
use crate::geometry::Ray;
use crate::math::{Vec2, Vec3};
use crate::sampling::Rng;
use crate::scene::{Scene, SurfaceInteraction};
use crate::spectrum::Spectrum;

/// Sets of [`W`] lanes (pixels) advanced in step: their rays are traced in one call
/// ([`crate::accel::Accel::intersect8_many`], shadow rays likewise), so that a split structure
/// fills its BVH streams with the rays of all sets that enter it.
const SETS: usize = 4;

/// The pixel a lane renders.
struct Pixel {
    x: usize,
    rng: Rng,
    sums: PixelSums,
    /// Samples started.
    started: u32,
}

/// The lanes' path state, a structure of arrays.
struct Lanes {
    px: [Option<Pixel>; W],
    o: V3,
    d: V3,
    tmax: [f32; W],
    beta: V3,
    l: V3,
    depth: [i32; W],
    /// The previous (diffuse) vertex, for the MIS weight of an emitter hit.
    has_prev: [bool; W],
    prev_p: V3,
    prev_pdf: [f32; W],
}

impl Lanes {
    /// Starts lane `k`'s next sample: the camera ray through a jittered point of its pixel
    /// (inlined into the row's AVX2 compilation).
    #[inline(always)]
    fn start_sample(&mut self, k: usize, scene: &Scene, cam: usize, y: usize) {
        let px = self.px[k].as_mut().expect("a lane with a pixel");
        let p = Vec2::new(px.x as f32 + px.rng.next_f32(), y as f32 + px.rng.next_f32());
        px.started += 1;
        let ray = scene.cameras[cam].generate_ray(p);
        self.o.set(k, ray.o.to_array());
        self.d.set(k, ray.d.to_array());
        self.tmax[k] = ray.tmax;
        self.beta.set(k, [1.0; 3]);
        self.l.set(k, [0.0; 3]);
        self.depth[k] = 0;
        self.has_prev[k] = false;
    }
}

/// Renders row `y` of camera `cam` into `row` (see the module docs).
pub(super) fn render_row(
    scene: &Scene,
    tables: &Tables,
    cam: usize,
    y: usize,
    s: &PathSettings,
    row: &mut Row,
    kernel: Kernel,
) {
    match kernel {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `Kernel::detect` returns Avx2 only when the CPU has AVX2, FMA, POPCNT,
        // BMI1, BMI2 and LZCNT (`crate::simd::Isa::Avx2`)
        Kernel::Avx2 => unsafe { render_row_avx2(scene, tables, cam, y, s, row) },
        _ => render_row_lanes(scene, tables, cam, y, s, row, kernel),
    }
}

/// The row compiled for AVX2, with the bit instructions of every AVX2 CPU
/// ([`crate::simd::Isa::Avx2`]): the light choice's count of cdf entries below `u` and the
/// shadow masks' counts become one `popcnt` each (a dozen shifts and masks without it).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,popcnt,bmi1,bmi2,lzcnt")]
fn render_row_avx2(scene: &Scene, tables: &Tables, cam: usize, y: usize, s: &PathSettings, row: &mut Row) {
    render_row_lanes(scene, tables, cam, y, s, row, Kernel::Avx2)
}

#[inline(always)]
fn render_row_lanes(
    scene: &Scene,
    tables: &Tables,
    cam: usize,
    y: usize,
    s: &PathSettings,
    row: &mut Row,
    kernel: Kernel,
) {
    let w = scene.cameras[cam].width;
    let accel = scene.accel();
    let mut next_x = 0usize;
    let mut take_pixel = || -> Option<Pixel> {
        if next_x >= w || s.spp == 0 {
            return None;
        }
        let x = next_x;
        next_x += 1;
        Some(Pixel {
            x,
            rng: Rng::new(s.seed, cam as u64, (y * w + x) as u64),
            sums: PixelSums::default(),
            started: 0,
        })
    };
    let mut sets: [Lanes; SETS] = std::array::from_fn(|_| Lanes {
        px: std::array::from_fn(|_| None),
        o: V3::default(),
        d: V3::default(),
        tmax: [0.0; W],
        beta: V3::default(),
        l: V3::default(),
        depth: [0; W],
        has_prev: [false; W],
        prev_p: V3::default(),
        prev_pdf: [0.0; W],
    });
    for lanes in sets.iter_mut() {
        for k in 0..W {
            lanes.px[k] = take_pixel();
            if lanes.px[k].is_some() {
                lanes.start_sample(k, scene, cam, y);
            }
        }
    }
    let mut inp = VertexIn::default();
    // each set's hit lanes' rows (other lanes keep earlier, finite values) and hit points
    let mut gs: [Gathered; SETS] = [[[0.0; W]; FIELDS]; SETS];
    let mut sis: [Interaction; SETS] = std::array::from_fn(|_| Interaction::default());
    let mut packets = [RayPacket::default(); SETS];
    let mut hits = [PacketHits::NONE; SETS];
    let mut outs: [wide::VertexOut; SETS] = std::array::from_fn(|_| wide::VertexOut::default());
    // which sets' `outs` hold this step's vertex
    let mut shaded = [false; SETS];
    loop {
        let alive: [[bool; W]; SETS] =
            std::array::from_fn(|j| std::array::from_fn(|k| sets[j].px[k].is_some()));
        if !alive.iter().flatten().any(|&a| a) {
            break;
        }
        for (j, lanes) in sets.iter().enumerate() {
            packets[j] = RayPacket {
                o: [lanes.o.x, lanes.o.y, lanes.o.z],
                d: [lanes.d.x, lanes.d.y, lanes.d.z],
                tmax: lanes.tmax,
            };
            inactive(&mut packets[j], alive[j]);
        }
        accel.intersect8_many(&packets, &mut hits);
        // every set's hit rows, while the earlier sets are shaded (on big meshes, whose rows
        // miss the caches: on the scanned-object room the copy of the rows was ≈ 7 % of the run)
        if tables.prefetch {
            for (h, alive) in hits.iter().zip(&alive) {
                for k in 0..W {
                    if alive[k] && h.prim[k] >= 0 {
                        tables.prefetch_row(h.prim[k] as usize);
                    }
                }
            }
        }
        let mut ended = [[false; W]; SETS];
        let mut hit = [[false; W]; SETS];
        // every set's hit points and texel prefetches before any set is shaded: the texels of
        // the later sets arrive while the earlier ones are shaded
        for j in 0..SETS {
            let (lanes, g, si) = (&sets[j], &mut gs[j], &mut sis[j]);
            hit[j] = locate(tables, lanes, &alive[j], &hits[j], &mut ended[j], g, si, kernel);
        }
        for j in 0..SETS {
            shaded[j] = hit[j].contains(&true)
                && step(
                    scene,
                    tables,
                    s,
                    &mut sets[j],
                    &hit[j],
                    &hits[j],
                    &mut ended[j],
                    &mut inp,
                    &gs[j],
                    &sis[j],
                    &mut outs[j],
                    kernel,
                );
        }
        trace_shadows(scene, &mut sets, &outs, &shaded, kernel);
        for (lanes, ended) in sets.iter_mut().zip(&ended) {
            for k in 0..W {
                if !ended[k] {
                    continue;
                }
                let px = lanes.px[k].as_mut().expect("an ended lane has a pixel");
                px.sums.add(Spectrum(lanes.l.get(k)));
                if px.started < s.spp {
                    lanes.start_sample(k, scene, cam, y);
                } else {
                    row.put(px.x, &px.sums);
                    lanes.px[k] = take_pixel();
                    if lanes.px[k].is_some() {
                        lanes.start_sample(k, scene, cam, y);
                    }
                }
            }
        }
    }
}

/// Lanes of `packet` not in `active` get a ray of lane 0's or their own with `tmax = 0`
/// ([`fill_inactive`]; a packet without an active lane gets `tmax = 0` everywhere).
#[inline(always)]
fn inactive(packet: &mut RayPacket, active: [bool; W]) {
    if active.contains(&true) {
        fill_inactive(packet, active);
    } else {
        packet.tmax = [0.0; W];
    }
}

/// The first half of a step after the closest hits, for every set before any is shaded
/// ([`step`]): which alive lanes hit something (the others end), their rows copied into `g`,
/// the hit reconstruction into `si` and the prefetch of the bitmap texels they will look up.
/// Returns the hit lanes (`g` and `si` are left as they were when there are none).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn locate(
    tables: &Tables,
    lanes: &Lanes,
    alive: &[bool; W],
    hits: &PacketHits,
    ended: &mut [bool; W],
    g: &mut Gathered,
    si: &mut Interaction,
    kernel: Kernel,
) -> [bool; W] {
    let mut hit = [false; W];
    for k in 0..W {
        if alive[k] {
            hit[k] = hits.prim[k] >= 0;
            ended[k] = !hit[k];
        }
    }
    if !hit.contains(&true) {
        return hit;
    }
    gather(tables, hits, &hit, g, kernel);
    *si = interaction(g, lanes, hits);
    // texels a while before their lookups
    for k in 0..W {
        if hit[k]
            && g[R_FLAGS][k].to_bits() & F_CONST == 0
            && let Some(t) = tables.textures[g[R_SHAPE][k].to_bits() as usize]
        {
            t.prefetch(Vec2::new(si.uv[0][k], si.uv[1][k]));
        }
    }
    hit
}

/// The rest of a step for the `hit` lanes located by [`locate`] (rows `g`, hit points `si`):
/// emission, depth limit, the lanes' random numbers, light choices and texture lookups, the
/// wide vertex and the Russian roulette. Writes the vertex outputs (shadow rays pending) into
/// `out` and returns true when some lane was shaded (`out` is left as it was otherwise).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn step(
    scene: &Scene,
    tables: &Tables,
    s: &PathSettings,
    lanes: &mut Lanes,
    hit: &[bool; W],
    hits: &PacketHits,
    ended: &mut [bool; W],
    inp: &mut VertexIn,
    g: &Gathered,
    si: &Interaction,
    out: &mut wide::VertexOut,
    kernel: Kernel,
) -> bool {
    let sampler = scene.light_sampler().expect("wide shading needs a light sampler");
    inp.active = [0; W];
    let mut any = false;
    for k in 0..W {
        if !hit[k] {
            continue;
        }
        let light = g[R_LIGHT][k].to_bits();
        if light == NO_LIGHT {
            lanes.depth[k] += 1;
        } else {
            emission_lane(scene, s, lanes, k, si, hits, g[R_SHAPE][k].to_bits());
        }
        if s.max_depth >= 0 && lanes.depth[k] >= s.max_depth {
            ended[k] = true;
            continue;
        }
        let px = lanes.px[k].as_mut().expect("a hit lane has a pixel");
        // the scalar vertex's draws, in its order: light choice, light sample, BSDF sample
        let rng = &mut px.rng;
        let u = rng.next_f32();
        let (idx, pmf) = match &tables.choice {
            Some(t) => t.choose(u),
            None => sampler.choose(u),
        };
        let ul = rng.next_2d();
        let _uc = rng.next_f32();
        let ub = rng.next_2d();
        let lr = &tables.lights[idx];
        inp.l0.set(k, [lr[0], lr[1], lr[2]]);
        inp.l1.set(k, [lr[3], lr[4], lr[5]]);
        inp.l2.set(k, [lr[6], lr[7], lr[8]]);
        inp.ln.set(k, [lr[9], lr[10], lr[11]]);
        inp.larea[k] = lr[12];
        inp.lrad.set(k, [lr[13], lr[14], lr[15]]);
        inp.pmf[k] = pmf;
        inp.ul[0][k] = ul.x;
        inp.ul[1][k] = ul.y;
        inp.ub[0][k] = ub.x;
        inp.ub[1][k] = ub.y;
        inp.active[k] = u32::MAX;
        any = true;
    }
    if !any {
        return false;
    }
    for k in 0..W {
        let flags = g[R_FLAGS][k].to_bits();
        inp.two_sided[k] = if flags & F_TWO_SIDED != 0 { u32::MAX } else { 0 };
        if inp.active[k] == 0 {
            continue;
        }
        let albedo = if flags & F_CONST != 0 {
            [g[R_ALBEDO][k], g[R_ALBEDO + 1][k], g[R_ALBEDO + 2][k]]
        } else {
            let tex = tables.textures[g[R_SHAPE][k].to_bits() as usize].expect("a bitmap reflectance");
            tex.eval(Vec2::new(si.uv[0][k], si.uv[1][k])).0
        };
        inp.albedo.set(k, albedo);
    }
    for k in 0..W {
        inp.wo.x[k] = -lanes.d.x[k];
        inp.wo.y[k] = -lanes.d.y[k];
        inp.wo.z[k] = -lanes.d.z[k];
    }
    inp.p = si.p;
    inp.ng = si.ng;
    inp.ns = si.ns;
    inp.beta = lanes.beta;
    wide::vertex8(inp, kernel, out);
    for k in 0..W {
        if inp.active[k] == 0 {
            continue;
        }
        if out.next[k] == 0 {
            ended[k] = true;
            continue;
        }
        let mut beta = Spectrum(out.beta.get(k));
        lanes.has_prev[k] = true;
        lanes.prev_p.set(k, si.p.get(k));
        lanes.prev_pdf[k] = out.pdf[k];
        lanes.o.set(k, out.no.get(k));
        lanes.d.set(k, out.nd.get(k));
        lanes.tmax[k] = f32::INFINITY;
        // Russian roulette, as in the scalar vertex (η = 1: `eta_scale` stays 1)
        if s.rr_depth >= 0 && lanes.depth[k] >= s.rr_depth {
            let q = beta.max_component().min(0.95);
            let px = lanes.px[k].as_mut().expect("a shaded lane has a pixel");
            if px.rng.next_f32() >= q {
                ended[k] = true;
                lanes.beta.set(k, beta.0);
                continue;
            }
            beta /= q;
        }
        lanes.beta.set(k, beta.0);
    }
    true
}

/// The hit reconstruction of the eight lanes.
#[derive(Default)]
struct Interaction {
    p: V3,
    ng: V3,
    ns: V3,
    uv: [[f32; W]; 2],
}

/// [`Scene::interaction_at`] for the eight lanes from their rows (the same operations: hit
/// point `o + d·t`, `b0 = 1 − b1 − b2`, corner-normal interpolation normalised by its length,
/// corner-uv interpolation).
#[inline(always)]
fn interaction(g: &Gathered, lanes: &Lanes, hits: &PacketHits) -> Interaction {
    let mut si = Interaction { p: V3::default(), ng: V3::default(), ns: V3::default(), uv: [[0.0; W]; 2] };
    for k in 0..W {
        let (t, b1, b2) = (hits.t[k], hits.b1[k], hits.b2[k]);
        let b0 = 1.0 - b1 - b2;
        si.p.x[k] = lanes.o.x[k] + lanes.d.x[k] * t;
        si.p.y[k] = lanes.o.y[k] + lanes.d.y[k] * t;
        si.p.z[k] = lanes.o.z[k] + lanes.d.z[k] * t;
        let ng = [g[R_NG][k], g[R_NG + 1][k], g[R_NG + 2][k]];
        let n = |c: usize| g[R_N + c][k] * b0 + g[R_N + 3 + c][k] * b1 + g[R_N + 6 + c][k] * b2;
        let (nx, ny, nz) = (n(0), n(1), n(2));
        let len = (nx * nx + ny * ny + nz * nz).sqrt();
        let flags = g[R_FLAGS][k].to_bits();
        let ns = if flags & F_NORMALS != 0 && len > 0.0 { [nx / len, ny / len, nz / len] } else { ng };
        si.ng.set(k, ng);
        si.ns.set(k, ns);
        let uv = |c: usize| g[R_UV + c][k] * b0 + g[R_UV + 2 + c][k] * b1 + g[R_UV + 4 + c][k] * b2;
        let has_uv = flags & F_UVS != 0;
        si.uv[0][k] = if has_uv { uv(0) } else { 0.0 };
        si.uv[1][k] = if has_uv { uv(1) } else { 0.0 };
    }
    si
}

/// [`super::emission`] for lane `k`, whose hit triangle emits (the scalar code on the lane's
/// state).
#[inline(never)]
fn emission_lane(
    scene: &Scene,
    s: &PathSettings,
    lanes: &mut Lanes,
    k: usize,
    si: &Interaction,
    hits: &PacketHits,
    shape: u32,
) {
    let mut st = PathState {
        l: Spectrum(lanes.l.get(k)),
        beta: Spectrum(lanes.beta.get(k)),
        depth: lanes.depth[k],
        eta_scale: 1.0,
        prev: lanes.has_prev[k].then(|| (Vec3::from_array(lanes.prev_p.get(k)), lanes.prev_pdf[k], false)),
    };
    let ray =
        Ray { o: Vec3::from_array(lanes.o.get(k)), d: Vec3::from_array(lanes.d.get(k)), tmax: lanes.tmax[k] };
    let it = SurfaceInteraction {
        p: Vec3::from_array(si.p.get(k)),
        ng: Vec3::from_array(si.ng.get(k)),
        ns: Vec3::from_array(si.ns.get(k)),
        uv: Vec2::new(si.uv[0][k], si.uv[1][k]),
        shape,
        prim: hits.prim[k] as u32,
        t: hits.t[k],
    };
    lanes.depth[k] = emission(scene, s, &mut st, &ray, &it);
    lanes.l.set(k, st.l.0);
}

/// Traces the pending shadow rays of every set's `out` together
/// ([`crate::accel::Accel::occluded8_many`]) and adds the contributions of those that reach
/// their light.
///
/// The shadow rays are **compacted**: those of all sets are packed, in set and lane order,
/// into as few packets as they fill (only the last one partly), instead of one packet per set
/// with the lanes that have none left idle — on the Cornell box only 58 % of a set's lanes
/// carry a shadow ray (vertices on the ceiling, which face away from its light, misses, ended
/// paths), so about a third fewer packets go through the any-hit kernel. A lane's answer depends
/// on its ray alone, so the packing changes no result. With AVX2 the packing is branch-free
/// ([`compact_avx2`]); the portable compilation copies lane by lane (the same packets).
#[inline(always)]
fn trace_shadows(
    scene: &Scene,
    sets: &mut [Lanes; SETS],
    outs: &[wide::VertexOut; SETS],
    shaded: &[bool; SETS],
    kernel: Kernel,
) {
    let masks: [u32; SETS] = std::array::from_fn(|j| {
        if shaded[j] { (0..W).fold(0, |m, k| m | ((outs[j].shadow[k] != 0) as u32) << k) } else { 0 }
    });
    let mut rays = [RayPacket::default(); SETS];
    let n = compact(outs, &masks, &mut rays, kernel);
    if n == 0 {
        return;
    }
    let packets = n.div_ceil(W);
    let last = packets - 1;
    inactive(&mut rays[last], std::array::from_fn(|l| last * W + l < n));
    let mut blocked = [0u32; SETS];
    scene.accel().occluded8_many(&rays[..packets], &mut blocked[..packets]);
    // packed ray i (bit i) reached its light
    let reached = !blocked.iter().enumerate().fold(0u64, |m, (p, &b)| m | (b as u64) << (W * p));
    let mut i = 0;
    for j in 0..SETS {
        let mut m = masks[j];
        while m != 0 {
            let k = m.trailing_zeros() as usize;
            m &= m - 1;
            if reached >> i & 1 != 0 {
                let l = Spectrum(sets[j].l.get(k)) + Spectrum(outs[j].contrib.get(k));
                sets[j].l.set(k, l.0);
            }
            i += 1;
        }
    }
}

/// Packs the shadow rays of the lanes in `masks[j]` of every set `j`, in set and lane order,
/// into the lanes of `rays` (ray `i` in lane `i mod W` of packet `i / W`); returns their
/// number. Lanes after the last ray are left as they were.
#[inline(always)]
fn compact(
    outs: &[wide::VertexOut; SETS],
    masks: &[u32; SETS],
    rays: &mut [RayPacket; SETS],
    kernel: Kernel,
) -> usize {
    #[cfg(target_arch = "x86_64")]
    if kernel == Kernel::Avx2 {
        // SAFETY: Kernel::Avx2 only where the CPU has AVX2 (`Kernel::detect`).
        return unsafe { compact_avx2(outs, masks, rays) };
    }
    let _ = kernel;
    let mut n = 0;
    for (out, &mask) in outs.iter().zip(masks) {
        for k in 0..W {
            if mask >> k & 1 == 0 {
                continue;
            }
            let (r, l) = (&mut rays[n / W], n % W);
            r.o[0][l] = out.so.x[k];
            r.o[1][l] = out.so.y[k];
            r.o[2][l] = out.so.z[k];
            r.d[0][l] = out.sd.x[k];
            r.d[1][l] = out.sd.y[k];
            r.d[2][l] = out.sd.z[k];
            r.tmax[l] = out.stmax[k];
            n += 1;
        }
    }
    n
}

/// Per 8-bit lane mask: the indices of its set lanes, lowest first, one per nibble (lowest
/// nibble first; the nibbles after them are 0) — the permutation that packs those lanes.
const COMPRESS: [u32; 256] = {
    let mut t = [0u32; 256];
    let mut m = 0;
    while m < 256 {
        let (mut k, mut n, mut v) = (0, 0, 0u32);
        while k < 8 {
            if m >> k & 1 != 0 {
                v |= (k as u32) << (4 * n);
                n += 1;
            }
            k += 1;
        }
        t[m] = v;
        m += 1;
    }
    t
};

/// [`compact`] with AVX2: each set's rays are packed by one lane permutation per field
/// ([`COMPRESS`]) and stored at the running count in flat arrays, which then fill the packets.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn compact_avx2(outs: &[wide::VertexOut; SETS], masks: &[u32; SETS], rays: &mut [RayPacket; SETS]) -> usize {
    use std::arch::x86_64::*;
    // fields o, d, tmax of the packed rays, with room for a whole vector after the last
    let mut flat = [[0.0f32; SETS * W + W]; 7];
    let shifts = _mm256_setr_epi32(0, 4, 8, 12, 16, 20, 24, 28);
    let mut n = 0;
    for (out, &mask) in outs.iter().zip(masks) {
        let idx = _mm256_and_si256(
            _mm256_srlv_epi32(_mm256_set1_epi32(COMPRESS[mask as usize & 0xff] as i32), shifts),
            _mm256_set1_epi32(0xf),
        );
        let src = [&out.so.x, &out.so.y, &out.so.z, &out.sd.x, &out.sd.y, &out.sd.z, &out.stmax];
        for (f, a) in flat.iter_mut().zip(src) {
            // SAFETY: 8 floats loaded from an 8-float array; stored at n ≤ (SETS − 1)·W (the
            // rays of the earlier sets), so the 8 floats lie within the SETS·W + W floats.
            unsafe {
                let v = _mm256_permutevar8x32_ps(_mm256_loadu_ps(a.as_ptr()), idx);
                _mm256_storeu_ps(f.as_mut_ptr().add(n), v);
            }
        }
        n += mask.count_ones() as usize;
    }
    for (p, r) in rays.iter_mut().enumerate().take(n.div_ceil(W)) {
        let at = W * p;
        for c in 0..3 {
            r.o[c].copy_from_slice(&flat[c][at..at + W]);
            r.d[c].copy_from_slice(&flat[3 + c][at..at + W]);
        }
        r.tmax.copy_from_slice(&flat[6][at..at + W]);
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The AVX2 packing of the shadow rays gives the portable packets bit for bit (random
    /// rays, every mask of one set, random masks of all sets).
    #[test]
    fn compacted_shadow_packets_match_the_portable_packing() {
        if Kernel::detect() != Kernel::Avx2 {
            return;
        }
        let mut rng = Rng::new(7, 0, 0);
        let mut outs: [wide::VertexOut; SETS] = std::array::from_fn(|_| wide::VertexOut::default());
        for out in outs.iter_mut() {
            for k in 0..W {
                let mut r = || rng.next_f32() * 4.0 - 2.0;
                out.so.set(k, [r(), r(), r()]);
                out.sd.set(k, [r(), r(), r()]);
                out.stmax[k] = r();
            }
        }
        let mut cases: Vec<[u32; SETS]> =
            (0..256).map(|m| std::array::from_fn(|j| if j == 1 { m } else { 0 })).collect();
        cases.extend((0..500).map(|_| std::array::from_fn(|_| rng.next_u32() & 0xff)));
        for masks in cases {
            let (mut a, mut b) = ([RayPacket::default(); SETS], [RayPacket::default(); SETS]);
            let na = compact(&outs, &masks, &mut a, Kernel::Portable);
            let nb = compact(&outs, &masks, &mut b, Kernel::Avx2);
            assert_eq!(na, masks.iter().map(|m| m.count_ones() as usize).sum::<usize>());
            assert_eq!(na, nb);
            // the rays in set and lane order
            let expected: Vec<[u32; 7]> = (0..SETS)
                .flat_map(|j| (0..W).filter(move |&k| masks[j] >> k & 1 != 0).map(move |k| (j, k)))
                .map(|(j, k)| {
                    let o = &outs[j];
                    [o.so.x[k], o.so.y[k], o.so.z[k], o.sd.x[k], o.sd.y[k], o.sd.z[k], o.stmax[k]]
                        .map(f32::to_bits)
                })
                .collect();
            for i in 0..na {
                let (p, l) = (i / W, i % W);
                let bits = |r: &RayPacket| {
                    [r.o[0][l], r.o[1][l], r.o[2][l], r.d[0][l], r.d[1][l], r.d[2][l], r.tmax[l]]
                        .map(f32::to_bits)
                };
                assert_eq!(bits(&a[p]), expected[i], "masks {masks:?}, ray {i}");
                assert_eq!(bits(&b[p]), expected[i], "masks {masks:?}, ray {i}");
            }
        }
    }
}
