//! The tables of the row wavefront ([`super::wide_row`]): per triangle a 128-byte **row**
//! (geometric normal, corner uvs, corner normals, shape, light, flags, constant albedo) and per
//! light a record, built once per render from the scene, and the copy of the hit lanes' rows
//! into lanes ([`gather`]: an 8×8 transpose with AVX2, field by field elsewhere — the same
//! values in the hit lanes).
//!
//! Tests: through the rows in `super::tests` (`wavefront_rows_equal_scalar_rows_bit_for_bit`,
//! `wide_rows_on_a_textured_mesh_equal_scalar_rows`).

// lane loops index several arrays by the lane
#![allow(clippy::needless_range_loop)]

use super::wide::{Kernel, W};
use crate::accel::packet::PacketHits;
use crate::light::Light;
use crate::sampling::SmallChoice;
use crate::scene::{Material, Scene};
use crate::texture::Texture;

/// Floats per triangle row (128 bytes).
pub(super) const ROW: usize = 32;
/// Geometric normal (3 floats).
pub(super) const R_NG: usize = 0;
/// Corner uvs `u0 v0 u1 v1 u2 v2`.
pub(super) const R_UV: usize = 3;
/// Corner normals `x0 y0 z0 x1 y1 z1 x2 y2 z2`.
pub(super) const R_N: usize = 9;
/// Shape index (bits).
pub(super) const R_SHAPE: usize = 18;
/// Light index (bits; [`NO_LIGHT`] for none).
pub(super) const R_LIGHT: usize = 19;
/// `F_*` flags (bits).
pub(super) const R_FLAGS: usize = 20;
/// Constant albedo (3 floats) when `F_CONST`.
pub(super) const R_ALBEDO: usize = 21;
/// Fields copied into the lanes per hit.
pub(super) const FIELDS: usize = 24;

/// [`R_LIGHT`] of a triangle that emits nothing.
pub(super) const NO_LIGHT: u32 = u32::MAX;
/// Flag: the row holds corner normals.
pub(super) const F_NORMALS: u32 = 1;
/// Flag: two-sided material.
pub(super) const F_TWO_SIDED: u32 = 2;
/// Flag: constant albedo (in the row).
pub(super) const F_CONST: u32 = 4;
/// Flag: the row holds corner uvs.
pub(super) const F_UVS: u32 = 8;

/// Floats per light record: corners (9), unit normal (3), area, radiance (3).
pub(super) const LIGHT: usize = 16;

/// One triangle's row (two cache lines).
#[repr(C, align(64))]
#[derive(Clone, Copy)]
pub(super) struct TriRow([f32; ROW]);

/// Per-triangle rows and per-light records of a scene, built once per render.
pub(super) struct Tables<'a> {
    rows: Vec<TriRow>,
    /// Per light: corners, unit normal, area, radiance ([`LIGHT`] floats).
    pub(super) lights: Vec<[f32; LIGHT]>,
    /// Each shape's bitmap reflectance (`None` for constants, whose value is in the rows).
    pub(super) textures: Vec<Option<&'a Texture>>,
    /// The rows are prefetched as soon as the hits are known ([`PREFETCH_ROWS`]).
    pub(super) prefetch: bool,
    /// The light choice as an inline table (at most 16 lights; the light sampler's choice).
    pub(super) choice: Option<SmallChoice>,
}

/// Rows are prefetched from this many triangles on (256 KiB of rows): fewer stay in the
/// caches next to the BVH, and the prefetch would only cost instructions (the Cornell box).
pub(super) const PREFETCH_ROWS: usize = 2048;

impl<'a> Tables<'a> {
    /// The tables of an all-diffuse scene lit by triangles (see [`super::wavefront::wide_kernel`]).
    pub(super) fn new(scene: &'a Scene) -> Tables<'a> {
        // huge pages: the rows are read at the hit triangles, all over the table (crate::mem)
        let mut rows = crate::mem::huge_vec(scene.shapes.iter().map(|sh| sh.mesh.indices.len()).sum());
        let mut textures = Vec::with_capacity(scene.shapes.len());
        for (si, sh) in scene.shapes.iter().enumerate() {
            let Material::Diffuse { reflectance, two_sided } = &sh.material else {
                unreachable!("the wide row runs on diffuse scenes only")
            };
            let constant = match reflectance {
                Texture::Constant(c) => Some(*c),
                Texture::Bitmap(_) => None,
            };
            textures.push(constant.is_none().then_some(reflectance));
            let m = &sh.mesh;
            let mut flags = 0;
            flags |= if m.normals.is_empty() { 0 } else { F_NORMALS };
            flags |= if *two_sided { F_TWO_SIDED } else { 0 };
            flags |= if constant.is_some() { F_CONST } else { 0 };
            flags |= if m.uvs.is_empty() { 0 } else { F_UVS };
            for (j, idx) in m.indices.iter().enumerate() {
                let prim = sh.first_prim + j as u32;
                let [i0, i1, i2] = idx.map(|i| i as usize);
                let mut r = [0.0f32; ROW];
                r[R_NG..R_NG + 3].copy_from_slice(&scene.prim_ng(prim).to_array());
                if !m.uvs.is_empty() {
                    for (c, i) in [i0, i1, i2].into_iter().enumerate() {
                        r[R_UV + 2 * c..R_UV + 2 * c + 2].copy_from_slice(&m.uvs[i].to_array());
                    }
                }
                if !m.normals.is_empty() {
                    for (c, i) in [i0, i1, i2].into_iter().enumerate() {
                        r[R_N + 3 * c..R_N + 3 * c + 3].copy_from_slice(&m.normals[i].to_array());
                    }
                }
                r[R_SHAPE] = f32::from_bits(si as u32);
                r[R_LIGHT] = f32::from_bits(scene.light_at(prim).map_or(NO_LIGHT, |(l, _)| l as u32));
                r[R_FLAGS] = f32::from_bits(flags);
                if let Some(c) = constant {
                    r[R_ALBEDO..R_ALBEDO + 3].copy_from_slice(&c.0);
                }
                rows.push(TriRow(r));
            }
        }
        let lights = scene
            .lights
            .iter()
            .map(|l| {
                let Light::Triangle(t) = l else { unreachable!("the wide row: triangle lights only") };
                let mut r = [0.0f32; LIGHT];
                for c in 0..3 {
                    r[3 * c..3 * c + 3].copy_from_slice(&t.p[c].to_array());
                }
                r[9..12].copy_from_slice(&t.n.to_array());
                r[12] = t.area;
                r[13..16].copy_from_slice(&t.radiance.0);
                r
            })
            .collect();
        let prefetch = rows.len() >= PREFETCH_ROWS;
        let choice = scene.light_sampler().and_then(|l| l.small_choice());
        Tables { rows, lights, textures, prefetch, choice }
    }

    /// Hints the two cache lines of triangle `prim`'s row (no effect on results).
    #[inline(always)]
    pub(super) fn prefetch_row(&self, prim: usize) {
        if let Some(r) = self.rows.get(prim) {
            crate::simd::prefetch(&r.0[0]);
            crate::simd::prefetch(&r.0[ROW / 2]);
        }
    }
}

/// The hit lanes' rows, field by field.
pub(super) type Gathered = [[f32; W]; FIELDS];

/// Copies the hit lanes' rows into `g` (field by field; other lanes keep their values, or get
/// row 0's with AVX2).
#[inline(always)]
pub(super) fn gather(tables: &Tables, hits: &PacketHits, hit: &[bool; W], g: &mut Gathered, kernel: Kernel) {
    #[cfg(target_arch = "x86_64")]
    if kernel == Kernel::Avx2 {
        let prim: [usize; W] = std::array::from_fn(|k| if hit[k] { hits.prim[k] as usize } else { 0 });
        // SAFETY: Kernel::Avx2 only where the CPU has AVX2 (`Kernel::detect`).
        unsafe { gather_avx2(&tables.rows, &prim, g) };
        return;
    }
    let _ = kernel;
    for k in 0..W {
        if hit[k] {
            let r = &tables.rows[hits.prim[k] as usize].0;
            for f in 0..FIELDS {
                g[f][k] = r[f];
            }
        }
    }
}

/// The first [`FIELDS`] floats of rows `prim[0..8]`, transposed into `g` (three 8×8 blocks).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn gather_avx2(rows: &[TriRow], prim: &[usize; W], g: &mut Gathered) {
    use std::arch::x86_64::*;
    let r: [&TriRow; W] = std::array::from_fn(|k| &rows[prim[k]]);
    for b in 0..FIELDS / 8 {
        // SAFETY: each row holds ROW = 32 ≥ 8·3 floats; unaligned loads within it.
        let block: [__m256; 8] =
            std::array::from_fn(|k| unsafe { _mm256_loadu_ps(r[k].0.as_ptr().add(8 * b)) });
        let t = crate::simd::transpose8(block);
        for (f, v) in t.into_iter().enumerate() {
            // SAFETY: `g[8b + f]` is an array of 8 floats.
            unsafe { _mm256_storeu_ps(g[8 * b + f].as_mut_ptr(), v) };
        }
    }
}
