//! The path tracer's vertex for eight paths at once, on scenes whose materials are all diffuse
//! (constant or textured Lambertian, one- or two-sided) and whose lights are all emitting
//! triangles: frame, next-event sample of a triangle light, Lambert evaluation and pdf, MIS
//! weight, the shadow ray, the cosine-weighted BSDF sample and the next ray, in the lanes of
//! [`F`] (`[f32; 8]` loops that LLVM turns into AVX2 instructions inside the AVX2 compilation
//! of the row that inlines [`vertex_lanes`], SSE2 elsewhere).
//!
//! **Scalar original**: [`super::vertex`] with [`crate::bsdf::Lambert`] and
//! [`crate::light::Light::sample_li`]. Every lane performs the same IEEE operations in the same
//! order as that code (glam's `dot` is `(x·x' + y·y') + z·z'`, `v / s` divides each component,
//! `normalize_or_zero` multiplies by `1 / length`, branches become selects of both sides), and
//! no fused multiply-add is ever formed, so each lane's results are **the same bits** as the
//! scalar vertex's — on any instruction set. What stays scalar, per lane, in the caller
//! ([`super::wide_row`]): emission found at the hit, the texture lookup, the light choice, the
//! random numbers and the Russian roulette.
//!
//! Tests: `super::tests::wavefront_rows_equal_scalar_rows_bit_for_bit` (Cornell box, tiny
//! accelerator) and `super::tests::wide_rows_on_a_textured_mesh_equal_scalar_rows` (a textured
//! mesh with vertex normals behind a BVH, two-sided and one-sided materials) compare whole
//! rendered rows with the scalar path tracer bit for bit, with the AVX2 and the portable
//! compilation.

use crate::accel::packet::PACKET;
use crate::fastmath::wide::{F, M};
use crate::math::INV_PI;

/// Lanes of the kernel (one per packet lane).
pub(super) const W: usize = PACKET;

type Fw = F<W>;
type Mw = M<W>;

/// Three lanes of f32 per axis: a vector per lane.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct V3 {
    /// x of every lane.
    pub x: [f32; W],
    /// y of every lane.
    pub y: [f32; W],
    /// z of every lane.
    pub z: [f32; W],
}

impl V3 {
    /// Writes `v` into lane `k`.
    #[inline]
    pub fn set(&mut self, k: usize, v: [f32; 3]) {
        self.x[k] = v[0];
        self.y[k] = v[1];
        self.z[k] = v[2];
    }
    /// Lane `k`.
    #[inline]
    pub fn get(&self, k: usize) -> [f32; 3] {
        [self.x[k], self.y[k], self.z[k]]
    }
    #[inline(always)]
    fn lanes(&self) -> L3 {
        L3 { x: F(self.x), y: F(self.y), z: F(self.z) }
    }
}

/// A vector in lanes, for arithmetic.
#[derive(Clone, Copy)]
struct L3 {
    x: Fw,
    y: Fw,
    z: Fw,
}

impl L3 {
    #[inline(always)]
    fn store(self) -> V3 {
        V3 { x: self.x.0, y: self.y.0, z: self.z.0 }
    }
    /// glam's `dot`: `(x·x' + y·y') + z·z'`.
    #[inline(always)]
    fn dot(self, o: L3) -> Fw {
        self.x * o.x + self.y * o.y + self.z * o.z
    }
    #[inline(always)]
    fn add(self, o: L3) -> L3 {
        L3 { x: self.x + o.x, y: self.y + o.y, z: self.z + o.z }
    }
    #[inline(always)]
    fn sub(self, o: L3) -> L3 {
        L3 { x: self.x - o.x, y: self.y - o.y, z: self.z - o.z }
    }
    #[inline(always)]
    fn scale(self, s: Fw) -> L3 {
        L3 { x: self.x * s, y: self.y * s, z: self.z * s }
    }
    /// Each component divided by `s` (glam's `Vec3 / f32`).
    #[inline(always)]
    fn div(self, s: Fw) -> L3 {
        L3 { x: self.x / s, y: self.y / s, z: self.z / s }
    }
    #[inline(always)]
    fn neg(self) -> L3 {
        L3 { x: -self.x, y: -self.y, z: -self.z }
    }
    #[inline(always)]
    fn select(m: Mw, a: L3, b: L3) -> L3 {
        L3 { x: m.select(a.x, b.x), y: m.select(a.y, b.y), z: m.select(a.z, b.z) }
    }
}

/// Inputs of [`vertex_lanes`], lane `k` = packet lane `k` (lanes not in `active` are ignored; their
/// values only need to be finite or zero).
#[derive(Clone, Debug, Default)]
pub(super) struct VertexIn {
    /// Lanes to shade (`u32::MAX`) or not (0).
    pub active: [u32; W],
    /// Outgoing direction (minus the ray direction).
    pub wo: V3,
    /// Hit point.
    pub p: V3,
    /// Unit geometric normal.
    pub ng: V3,
    /// Unit shading normal.
    pub ns: V3,
    /// Two-sided material (`u32::MAX`) or not.
    pub two_sided: [u32; W],
    /// Diffuse reflectance at the hit.
    pub albedo: V3,
    /// Path throughput before this vertex.
    pub beta: V3,
    /// Chosen light's corners.
    pub l0: V3,
    /// Second corner.
    pub l1: V3,
    /// Third corner.
    pub l2: V3,
    /// Chosen light's unit normal.
    pub ln: V3,
    /// Chosen light's area.
    pub larea: [f32; W],
    /// Chosen light's radiance.
    pub lrad: V3,
    /// Probability of having chosen that light.
    pub pmf: [f32; W],
    /// The light sample's two numbers.
    pub ul: [[f32; W]; 2],
    /// The BSDF sample's two numbers.
    pub ub: [[f32; W]; 2],
}

/// Results of [`vertex_lanes`].
#[derive(Clone, Debug, Default)]
pub(super) struct VertexOut {
    /// A shadow ray is to be traced (its contribution added if unoccluded).
    pub shadow: [u32; W],
    /// Shadow ray origins.
    pub so: V3,
    /// Shadow ray unit directions.
    pub sd: V3,
    /// Shadow ray lengths.
    pub stmax: [f32; W],
    /// Radiance the shadow ray adds if unoccluded.
    pub contrib: V3,
    /// The path goes on (before the Russian roulette).
    pub next: [u32; W],
    /// Next ray origin.
    pub no: V3,
    /// Next ray direction.
    pub nd: V3,
    /// Throughput after the BSDF sample.
    pub beta: V3,
    /// Solid-angle density of the BSDF sample.
    pub pdf: [f32; W],
}

/// `crate::integrator::mis_power`, lane by lane.
#[inline(always)]
fn mis_power(a: Fw, b: Fw) -> Fw {
    let (a2, b2) = (a * a, b * b);
    let s = a2 + b2;
    let inf = Fw::splat(f32::INFINITY);
    let finite = a2.abs().lt(inf);
    let is_inf = a2.abs().eq(inf);
    let ok = s.gt(Fw::splat(0.0)) & finite;
    ok.select(a2 / s, is_inf.select(Fw::splat(1.0), Fw::splat(0.0)))
}

/// `crate::accel::triangle::offset_ray_origin`, lane by lane.
#[inline(always)]
fn offset_ray_origin(p: L3, ng: L3, w: L3) -> L3 {
    use crate::accel::triangle::RAY_OFFSET_SCALE;
    // normalize_or_zero: ng · (1 / |ng|) when that reciprocal is finite and > 0
    let rcp = 1.0 / ng.dot(ng).sqrt();
    let keep = rcp.abs().lt(Fw::splat(f32::INFINITY)) & rcp.gt(Fw::splat(0.0));
    let z = Fw::splat(0.0);
    let n = L3::select(keep, ng.scale(rcp), L3 { x: z, y: z, z });
    // max_element: max(x, max(y, z)) with `if a > b { a } else { b }`
    let (ax, ay, az) = (p.x.abs(), p.y.abs(), p.z.abs());
    let mag = (1.0 + ax.max(ay.max(az))) * RAY_OFFSET_SCALE;
    let mag = n.dot(w).ge(z).select(mag, -mag);
    p.add(n.scale(mag))
}

/// The shading frame `Frame::from_normal(n)` (Duff et al. 2017), lane by lane: (s, t).
#[inline(always)]
fn frame(n: L3) -> (L3, L3) {
    let sign = Fw::splat(1.0).copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    let s = L3 { x: 1.0 + sign * n.x * n.x * a, y: sign * b, z: -sign * n.x };
    let t = L3 { x: b, y: sign + n.y * n.y * a, z: -n.y };
    (s, t)
}

/// One diffuse path vertex for the lanes in `inp.active` (see the module docs).
#[inline(always)]
pub(super) fn vertex_lanes(inp: &VertexIn) -> VertexOut {
    let z = Fw::splat(0.0);
    let active = M(inp.active);
    let wo = inp.wo.lanes();
    let p = inp.p.lanes();
    let ng = inp.ng.lanes();
    let ns = inp.ns.lanes();
    // Scene::bsdf: a two-sided material's normal faces wo
    let flip = M(inp.two_sided) & wo.dot(ng).lt(z);
    let n = L3::select(flip, ns.neg(), ns);
    let (fs, ft) = frame(n);
    let to_local = |v: L3| L3 { x: v.dot(fs), y: v.dot(ft), z: v.dot(n) };
    let wo_l = to_local(wo);
    let front = wo_l.z.gt(z);
    let albedo = inp.albedo.lanes();
    let beta = inp.beta.lanes();

    // next-event estimation: TriangleLight::point (Heitz's square-to-triangle map)
    let (bx, by) = crate::fastmath::wide::square_to_uniform_triangle(F(inp.ul[0]), F(inp.ul[1]));
    let w0 = 1.0 - bx - by;
    let (l0, l1, l2) = (inp.l0.lanes(), inp.l1.lanes(), inp.l2.lanes());
    let q = l0.scale(w0).add(l1.scale(bx)).add(l2.scale(by));
    let d = q.sub(p);
    let dist2 = d.dot(d);
    let dist = dist2.sqrt();
    let wi = d.div(dist);
    let ln = inp.ln.lanes();
    let cos_l = -wi.dot(ln);
    let lpdf = dist2 / (cos_l * F(inp.larea));
    let lrad = inp.lrad.lanes();
    let dark = lrad.x.eq(z) & lrad.y.eq(z) & lrad.z.eq(z);
    let sampled = dist2.gt(z) & cos_l.gt(z) & lpdf.gt(z) & !dark;
    // Lambert::eval(wo, wi) · |cos|
    let wi_l = to_local(wi);
    let both = front & wi_l.z.gt(z);
    let c = wi_l.z.abs();
    let fx = both.select(albedo.x * INV_PI, z) * c;
    let fy = both.select(albedo.y * INV_PI, z) * c;
    let fz = both.select(albedo.z * INV_PI, z) * c;
    let black = fx.eq(z) & fy.eq(z) & fz.eq(z);
    let shadow = active & sampled & !black;
    let pdf_light = F(inp.pmf) * lpdf;
    // Lambert::pdf: cos/π on the front side
    let bsdf_pdf = (front & wi_l.z.gt(z)).select(wi_l.z * INV_PI, z);
    let w = mis_power(pdf_light, bsdf_pdf);
    let scale = w / pdf_light;
    let contrib = L3 {
        x: beta.x * fx * lrad.x * scale,
        y: beta.y * fy * lrad.y * scale,
        z: beta.z * fz * lrad.z * scale,
    };
    // spawn_ray_to(p, ng, q, ln)
    let so = offset_ray_origin(p, ng, q.sub(p));
    let target = offset_ray_origin(q, ln, p.sub(q));
    let v = target.sub(so);
    let sdist = v.dot(v).sqrt();
    let sok = sdist.gt(z) & sdist.abs().lt(Fw::splat(f32::INFINITY));
    let sd = L3::select(sok, v.div(sdist), L3 { x: z, y: z, z: Fw::splat(1.0) });
    use crate::accel::triangle::SHADOW_RAY_SHORTEN;
    let stmax = sok.select(sdist * (1.0 - SHADOW_RAY_SHORTEN), z);

    // BSDF sample: square_to_cosine_hemisphere (concentric disk, Malley)
    let (vx, vy) = (F(inp.ub[0]), F(inp.ub[1]));
    let ox = 2.0 * vx - 1.0;
    let oy = 2.0 * vy - 1.0;
    let centre = ox.eq(z) & oy.eq(z);
    let xdom = ox.abs().gt(oy.abs());
    let r = xdom.select(ox, oy);
    let turns = xdom.select(oy / ox * 0.125, 0.25 - ox / oy * 0.125);
    let (sn, cs) = crate::fastmath::wide::sincos_2pi(turns);
    let dx = centre.select(z, r * cs);
    let dy = centre.select(z, r * sn);
    let dz = (1.0 - (dx * dx + dy * dy)).max(z).sqrt();
    let spdf = dz.gt(z).select(dz * INV_PI, z);
    // Lambert::sample refuses `wo.z <= 0` (a NaN goes on, as there)
    let ok = active & !wo_l.z.le(z) & spdf.gt(z);
    // BsdfSample::weight: f · (|cos| / pdf)
    let k = dz.abs() / spdf;
    let wx = albedo.x * INV_PI * k;
    let wy = albedo.y * INV_PI * k;
    let wz = albedo.z * INV_PI * k;
    let wblack = wx.eq(z) & wy.eq(z) & wz.eq(z);
    let next = ok & !wblack;
    let beta_n = L3 { x: beta.x * wx, y: beta.y * wy, z: beta.z * wz };
    // Frame::to_world: (s·x + t·y) + n·z
    let dir = fs.scale(dx).add(ft.scale(dy)).add(n.scale(dz));
    let no = offset_ray_origin(p, ng, dir);
    VertexOut {
        shadow: shadow.0,
        so: so.store(),
        sd: sd.store(),
        stmax: stmax.0,
        contrib: contrib.store(),
        next: next.0,
        no: no.store(),
        nd: dir.store(),
        beta: beta_n.store(),
        pdf: spdf.0,
    }
}

/// Which compilation of the kernel runs (both give the same bits).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Kernel {
    /// The target's baseline instruction set.
    Portable,
    /// AVX2 + FMA (FMA is never used for arithmetic: only the wider registers).
    Avx2,
}

impl Kernel {
    /// AVX2 where the CPU has it ([`crate::simd::isa`], detected once).
    pub(super) fn detect() -> Kernel {
        if crate::simd::isa().avx2() { Kernel::Avx2 } else { Kernel::Portable }
    }
}

/// One diffuse path vertex for the active lanes (see the module docs), in the compilation
/// `kernel` names, written into `out` (no 700-byte result moved through the stack).
#[inline(always)]
pub(super) fn vertex8(inp: &VertexIn, kernel: Kernel, out: &mut VertexOut) {
    match kernel {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `Kernel::detect` returns Avx2 only when the CPU has AVX2 and FMA
        Kernel::Avx2 => unsafe { vertex_avx2(inp, out) },
        _ => *out = vertex_lanes(inp),
    }
}

/// [`vertex_lanes`] compiled for AVX2 on its own (inlined into the row it measured slower: the
/// row's register pressure scalarised part of it).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline(never)]
fn vertex_avx2(inp: &VertexIn, out: &mut VertexOut) {
    *out = vertex_lanes(inp);
}
