//! Fixed-point accumulation of the light tracer (see the module docs of
//! [`super`], "Accumulation"): the per-pass scale ([`FixedPoint`]), the integer maps of one
//! shape ([`Cells`]: `i32` cells with an exact carry into a lazily allocated `i64` spill map)
//! and a worker's accumulator ([`ShapeAcc`], [`Acc`]).
//!
//! Tests (`tests.rs`): `i32_cells_with_spill_sum_exactly_like_i64`,
//! `fixed_point_overflow_is_detected_and_traced_again`, and the comparisons of the fixed-point
//! sums with a plain f64 pass.

use super::IrradianceTarget;
use super::zeroed::Zeroed;
use crate::scene::Scene;

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
pub(super) struct FixedPoint {
    /// Per triangle of the soup: units per unit of β (0 = no deposit).
    pub(super) factor: Vec<f64>,
    /// Per shape: W·m⁻² per unit.
    pub(super) unit: Vec<f64>,
}

impl FixedPoint {
    pub(super) fn new(
        scene: &Scene,
        targets: &[Option<IrradianceTarget>],
        paths: u64,
        shift: i32,
    ) -> FixedPoint {
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
/// allocated at its first use (zeroed pages: only the pages touched become resident). The
/// `i32` cells of a worker's maps share one huge-page advised mapping ([`empty_acc`], see
/// `zeroed.rs`).
pub(super) struct Cells {
    pub(super) fine: Zeroed,
    pub(super) spill: Vec<i64>,
}

impl Cells {
    /// `n` channels (3 per texel), all zero.
    pub(super) fn new(n: usize) -> Cells {
        Cells { fine: Zeroed::new(n), spill: Vec::new() }
    }

    /// Adds `v` to channels `i..i + 3`.
    #[inline(always)]
    pub(super) fn add(&mut self, i: usize, v: [i64; 3]) {
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
    pub(super) fn add32(&mut self, i: usize, v: [i32; 3]) {
        let n = self.fine.len();
        let cell = &mut self.fine[i..i + 3];
        for c in 0..3 {
            add_cell(&mut cell[c], v[c], &mut self.spill, n, i + c);
        }
    }

    /// The sum of channel `j` (wrapping: exact while no texel's true sum reaches 2⁶³).
    #[inline]
    pub(super) fn get(&self, j: usize) -> i64 {
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
pub(super) struct ShapeAcc {
    pub(super) width: usize,
    pub(super) height: usize,
    /// Empty without direct deposits.
    pub(super) direct: Cells,
    pub(super) indirect: Cells,
    /// Sum of |units| of every deposit (exact): bounds every texel's sum.
    pub(super) total: u128,
}

pub(super) type Acc = Vec<Option<ShapeAcc>>;

/// A worker's empty accumulator for `targets` (direct maps empty unless `direct`): the `i32`
/// cells of all its maps in one mapping ([`Zeroed::many`]).
pub(super) fn empty_acc(targets: &[Option<IrradianceTarget>], direct: bool) -> Acc {
    // one worker's maps in one (huge-page advised) mapping: indirect, direct per target
    let lens: Vec<usize> = targets
        .iter()
        .flatten()
        .flat_map(|t| [3 * t.width * t.height, if direct { 3 * t.width * t.height } else { 0 }])
        .collect();
    let mut fine = Zeroed::many(&lens, true).into_iter();
    let mut cells = || Cells { fine: fine.next().expect("a map per target and kind"), spill: Vec::new() };
    targets
        .iter()
        .map(|t| {
            t.as_ref().map(|t| {
                let indirect = cells();
                ShapeAcc { width: t.width, height: t.height, direct: cells(), indirect, total: 0 }
            })
        })
        .collect()
}
