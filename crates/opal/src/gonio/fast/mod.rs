//! Fast photon loop for the common case: an infinite plate (far-field detectors) whose faces
//! are polished or rough with single scattering (`Scattering::Single` / `SingleMitsuba`) on a
//! GGX or Beckmann NDF, or dotted (`Face::Dotted`, an area mixture of two such surfaces). Finite
//! plates, multiple scattering, the height-correlated G and numerical NDFs take the general
//! loop (`Gonio::trace_photon`).
//!
//! Same physics, same random-number contract (photon j of incidence i draws from
//! `Rng::new(seed, i, j)`, in the same order: beam cone, then per interaction one number for a
//! polished face or three for a rough one; a dotted face chooses its part with the first number,
//! rescaled to be the part's own first one), so results agree with the general loop in
//! distribution (tested: `gonio::tests::fast_path_matches_general_path`, dotted faces
//! included; at coverage 0 and 1 a dotted face is its land or its dots bit for bit:
//! `gonio::tests::dotted_face_limits_are_bit_identical`). What makes it fast:
//! * everything in f32 with the polynomial math of [`crate::fastmath`] (`sincos(2πu)` for the
//!   beam cone and GGX, `exp`/`erfc`/`erfinv` for Beckmann), Fresnel with the constants of the
//!   plate's index precomputed;
//! * the NDF is resolved once per run (`FastFace`), not matched per sample, and the sample
//!   weight is G1 of the new direction directly (the separable `G/G1(wo)`);
//! * GGX visible normals by spherical caps, Beckmann visible slopes from a quantile table plus
//!   Newton on the exact CDF (`microfacet::beckmann`);
//! * detector look-up by binning the direction cosines (`Detectors::for_each_hit`);
//! * a SIMD wavefront: chunks of 256 photons advance one interaction at a time, all at the same
//!   face; the directions and weights live in arrays (SoA) compacted after every round, and the
//!   interaction itself (visible normal, Fresnel, reflection or refraction, G1) runs on `N`
//!   photons at once with the lane-parallel math of [`crate::fastmath::wide`], branch-free
//!   (both outcomes computed, per-lane selects; a dotted face runs both parts and selects
//!   per lane by the area choice). The random numbers are drawn per photon
//!   (scalar PCG32) into arrays before each round; exits, detector tally and absorption are a
//!   scalar pass over the round's photons in order.
//!
//! The SIMD kernels return, lane by lane, the same bits as the scalar interaction code
//! (`rough_sample` with `Ndf::sample_visible`, kept for the tests): the Beckmann kernel takes
//! the scalar sampler's first two Newton steps from the table start; the lanes not converged
//! by then (the tails of u, ~1.8 % of them) and those at normal incidence are gathered after
//! the round and redone in blocks by the kernel with the whole iteration. So the output is
//! the one of the scalar fast loop before the kernels, and it does not depend on the vector
//! width: the portable build (SSE2, `N` = 8 as
//! 2 × 4 lanes) and the AVX2 (8 lanes) and AVX-512 (16 lanes) versions selected at run time give
//! identical output (tested: `simd_kernels_match_scalar_code`,
//! `gonio::tests::simd_and_portable_loops_agree_bit_for_bit`).

// The SIMD fast paths exist on x86-64 only; elsewhere the scalar paths run (same results).
#![cfg_attr(not(target_arch = "x86_64"), allow(dead_code, unused_imports, unused_variables))]

mod lanes;
#[cfg(test)]
mod scalar;
#[cfg(test)]
mod tests;
mod wavefront;

use super::{Acc, BeamFrame, Face, Gonio, Plate, Scattering};
use crate::bsdf::microfacet::beckmann::{TAB_NC, TAB_NU, slope_table};
use crate::bsdf::microfacet::{Beckmann, Ggx, Ndfs};
use crate::fastmath::Fresnel;
use wavefront::{CHUNK, Wavefront};

/// A face resolved for the fast loop.
#[derive(Clone, Copy, Debug)]
pub(super) enum FastFace {
    Polished,
    Ggx(Ggx),
    Beckmann { ndf: Beckmann, mitsuba_g1: bool },
}

/// A face of the plate resolved for the fast loop: one surface, or an area mixture of two
/// (`Face::Dotted`: `a` on the fraction `f`, else `b`).
#[derive(Clone, Copy, Debug)]
pub(super) enum FastSide {
    Plain(FastFace),
    Dotted { f: f32, a: FastFace, b: FastFace },
}

impl FastSide {
    fn is_polished(&self) -> bool {
        matches!(self, FastSide::Plain(FastFace::Polished))
    }
    fn has_beckmann(&self) -> bool {
        let b = |f: &FastFace| matches!(f, FastFace::Beckmann { .. });
        match self {
            FastSide::Plain(x) => b(x),
            FastSide::Dotted { a, b: land, .. } => b(a) || b(land),
        }
    }
}

/// The area choice of a dotted face from the first random number `u`, as the general loop
/// makes it (`gonio::interact`): whether the photon meets `a`, and `u` rescaled to the chosen
/// part (its own first random number).
#[inline(always)]
fn dotted_choice(f: f32, u: f32) -> (bool, f32) {
    let (pick_a, ur) = if u < f { (true, u / f) } else { (false, (u - f) / (1.0 - f)) };
    (pick_a, ur.min(1.0 - f32::EPSILON / 2.0))
}

/// The plate resolved for the fast loop.
#[derive(Clone, Copy, Debug)]
pub(super) struct FastPlate {
    front: FastSide,
    back: FastSide,
    fresnel: Fresnel,
    thick: f32,
    mu: f32,
}

impl FastPlate {
    /// `None` when the plate needs the general loop.
    pub(super) fn new(plate: &Plate) -> Option<Self> {
        if plate.radius_mm.is_some() {
            return None;
        }
        let face = |f: &Face| -> Option<FastFace> {
            match f {
                Face::Polished => Some(FastFace::Polished),
                Face::Rough { ndf, scattering } => {
                    let mitsuba_g1 = match scattering {
                        Scattering::Single => false,
                        Scattering::SingleMitsuba => true,
                        _ => return None,
                    };
                    match ndf {
                        Ndfs::Ggx(g) => Some(FastFace::Ggx(*g)),
                        Ndfs::Beckmann(b) => Some(FastFace::Beckmann { ndf: *b, mitsuba_g1 }),
                        Ndfs::Numeric(_) | Ndfs::Anisotropic(_) => None,
                    }
                }
                Face::Dotted { .. } => None,
            }
        };
        let side = |f: &Face| -> Option<FastSide> {
            match f {
                Face::Dotted { coverage, dots, land } => {
                    if !(coverage.is_finite() && (0.0..=1.0).contains(coverage)) {
                        return None;
                    }
                    Some(FastSide::Dotted { f: *coverage as f32, a: face(dots)?, b: face(land)? })
                }
                f => Some(FastSide::Plain(face(f)?)),
            }
        };
        Some(FastPlate {
            front: side(&plate.front)?,
            back: side(&plate.back)?,
            fresnel: Fresnel::new(plate.ior as f32),
            thick: plate.thickness_mm as f32,
            mu: plate.absorption_per_mm as f32,
        })
    }
}

/// Which compilation of the photon loop runs (all give the same bits).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Kernels {
    /// The baseline instruction set of the target (SSE2 on x86-64).
    Portable,
    /// AVX2 + FMA, 8 lanes.
    Avx2,
    /// AVX-512 (F, VL, DQ, BW), 16 lanes.
    Avx512,
}

impl Kernels {
    /// The widest the CPU supports (`Portable` when `simd` is false).
    pub(super) fn detect(simd: bool) -> Self {
        // the instruction set detected once per process (`crate::simd`)
        match crate::simd::isa() {
            crate::simd::Isa::Avx512 if simd => Kernels::Avx512,
            crate::simd::Isa::Avx2 if simd => Kernels::Avx2,
            _ => Kernels::Portable,
        }
    }
}

impl Gonio {
    /// Traces photons `first..first + count` of incidence stream `stream` through `fp`, in
    /// chunks of `CHUNK` photons advanced one surface interaction at a time: in round r every
    /// photon still inside is at the same face (the lit face for even r), so each round is one
    /// SIMD kernel over the photons (interaction) and one scalar pass (exit / tally /
    /// traverse).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn trace_batch_fast(
        &self,
        fp: &FastPlate,
        bf: &BeamFrame,
        stream: u64,
        first: u64,
        count: u64,
        acc: &mut Acc,
        kernels: Kernels,
    ) {
        match kernels {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Kernels::detect` returned Avx2 only if the CPU has AVX2 and FMA
            Kernels::Avx2 => unsafe { self.trace_batch_avx2(fp, bf, stream, first, count, acc) },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Kernels::detect` returned Avx512 only if the CPU has these features
            Kernels::Avx512 => unsafe { self.trace_batch_avx512(fp, bf, stream, first, count, acc) },
            _ => self.trace_batch_lanes::<8>(fp, bf, stream, first, count, acc),
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn trace_batch_avx2(
        &self,
        fp: &FastPlate,
        bf: &BeamFrame,
        stream: u64,
        first: u64,
        count: u64,
        acc: &mut Acc,
    ) {
        self.trace_batch_lanes::<8>(fp, bf, stream, first, count, acc)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512vl,avx512dq,avx512bw,avx2,fma")]
    fn trace_batch_avx512(
        &self,
        fp: &FastPlate,
        bf: &BeamFrame,
        stream: u64,
        first: u64,
        count: u64,
        acc: &mut Acc,
    ) {
        self.trace_batch_lanes::<16>(fp, bf, stream, first, count, acc)
    }

    #[inline(always)]
    fn trace_batch_lanes<const N: usize>(
        &self,
        fp: &FastPlate,
        bf: &BeamFrame,
        stream: u64,
        first: u64,
        count: u64,
        acc: &mut Acc,
    ) {
        let mut wf = Wavefront::new();
        // the Beckmann quantile table (built on first use; a dummy for other faces)
        static NONE: [f32; TAB_NC * TAB_NU] = [0.0; TAB_NC * TAB_NU];
        let tab: &[f32; TAB_NC * TAB_NU] = if fp.front.has_beckmann() || fp.back.has_beckmann() {
            slope_table().try_into().expect("table size")
        } else {
            &NONE
        };
        let mut k0 = 0;
        while k0 < count {
            let m = (count - k0).min(CHUNK as u64) as usize;
            self.trace_chunk::<N>(fp, tab, bf, stream, first + k0, m, acc, &mut wf);
            k0 += m as u64;
        }
    }
}
