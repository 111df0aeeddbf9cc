//! SIMD policy: which vector instruction set the engine's lane kernels use, decided once.
//!
//! * [`isa`] detects the CPU's features **once per process** (first call, cached in a
//!   [`OnceLock`]). Structures that run lane kernels read it when they are built (the BVH, the
//!   tiny-scene accelerators) or when a pass starts (the light tracer's wavefront, the
//!   goniophotometer's photon wavefront) and keep the answer; no feature check runs per ray, per
//!   packet or per path.
//! * Lane types for portable kernels live in [`lanes`] (`F<N>`, `I<N>`, `M<N>`: plain lane loops
//!   that LLVM vectorises for whatever the enclosing function is compiled for).
//! * Every AVX2 kernel sits beside its scalar/portable original and is tested bit for bit against
//!   it (the kernels never use fused multiply-add: results do not depend on the instruction set).
//!   Non-x86 builds take the portable code and give the same results.
//!
//! [`Isa::Portable`] can be forced with [`Isa::portable_only`] (tests compare both paths).

use std::sync::OnceLock;

pub use crate::fastmath::wide as lanes;

/// The vector instruction set the lane kernels use.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Isa {
    /// AVX-512 (F, VL, DQ, BW) with AVX2 and FMA (x86-64): 16 lanes of f32 per instruction.
    Avx512,
    /// AVX2 with FMA (x86-64): 8 lanes of f32 per instruction.
    Avx2,
    /// Portable lane loops (any CPU).
    Portable,
}

impl Isa {
    /// Whether the AVX2 kernels may run (also on AVX-512 CPUs).
    #[inline(always)]
    pub fn avx2(self) -> bool {
        matches!(self, Isa::Avx2 | Isa::Avx512)
    }

    /// Whether the AVX-512 kernels may run.
    #[inline(always)]
    pub fn avx512(self) -> bool {
        self == Isa::Avx512
    }

    /// The portable instruction set, whatever the CPU (for tests and comparisons).
    pub fn portable_only() -> Isa {
        Isa::Portable
    }
}

/// Hint to bring the cache line of `v` close to the core (no effect on results; a no-op off
/// x86-64).
#[inline(always)]
pub fn prefetch<T>(v: &T) {
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

/// The instruction set of this CPU, detected on the first call and cached.
pub fn isa() -> Isa {
    static ISA: OnceLock<Isa> = OnceLock::new();
    *ISA.get_or_init(detect)
}

fn detect() -> Isa {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::is_x86_feature_detected as has;
        if has!("avx2") && has!("fma") {
            if has!("avx512f") && has!("avx512vl") && has!("avx512dq") && has!("avx512bw") {
                return Isa::Avx512;
            }
            return Isa::Avx2;
        }
    }
    Isa::Portable
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn detection_is_cached_and_consistent() {
        let a = isa();
        assert_eq!(a, isa());
        #[cfg(not(target_arch = "x86_64"))]
        assert_eq!(a, Isa::Portable);
        assert!(!Isa::portable_only().avx2());
    }
}
