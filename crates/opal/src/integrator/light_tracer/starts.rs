//! Path starts prepared [`W`] at a time for the wavefront ([`starts`]): triangle lights in
//! SIMD ([`start_lanes`], the same bits as [`start_path`]), other lights through `start_path`.
//!
//! Tests (`tests.rs`): the engine comparison (area and point lights) gives identical sums.

#[cfg(target_arch = "x86_64")]
use super::avx;
#[cfg(target_arch = "x86_64")]
use super::path::start_path;
use super::wavefront::{W, cosine_hemisphere_lanes, each3, offset_lanes};
#[cfg(target_arch = "x86_64")]
use super::wavefront::{lanes_of, mask};
use crate::math::{Frame, Vec3};
use crate::sampling::{Rng, RngStream};
use crate::scene::Scene;
use crate::spectrum::Spectrum;

/// Triangle lights as the SIMD path starts need them, one entry per light (`None` for other
/// lights, whose paths start through [`start_path`]).
#[derive(Clone, Copy)]
pub(super) struct LightRow {
    p: [Vec3; 3],
    frame: Frame,
    /// The light's normal and its `normalize_or_zero` (the ray offset's direction).
    n: Vec3,
    n_off: Vec3,
    radiance: Spectrum,
    inv_area: f32,
}

pub(super) fn light_rows(scene: &Scene) -> Vec<Option<LightRow>> {
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
pub(super) struct StartIn {
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
pub(super) struct StartOut {
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
pub(super) fn start_lanes(i: &StartIn) -> StartOut {
    use crate::fastmath::wide::F;
    type V = [F<W>; 3];
    let ld = |a: &[[f32; W]; 3]| -> V { [F(a[0]), F(a[1]), F(a[2])] };
    let zero = F::<W>::splat(0.0);
    // square_to_uniform_triangle
    let (b0, b1) = crate::fastmath::wide::square_to_uniform_triangle(F(i.u_pos[0]), F(i.u_pos[1]));
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
pub(super) struct StartBlock {
    pub(super) o: [[f32; W]; 3],
    pub(super) d: [[f32; W]; 3],
    pub(super) beta: [[f32; W]; 3],
    pub(super) rng: [Rng; W],
    pub(super) valid: u32,
}

impl StartBlock {
    pub(super) fn new(stream: &RngStream) -> StartBlock {
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
pub(super) fn starts(
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
        let (li, pmf) = sampler.choose(rng.next_f32());
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
