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
    /// AVX2 with FMA (x86-64): 8 lanes of f32 per instruction; also the bit instructions
    /// every AVX2 CPU has (POPCNT, BMI1, BMI2, LZCNT), which kernels may enable with it.
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
    prefetch_ptr(v as *const T);
}

/// [`prefetch`] of an address that need not be dereferenceable (a prefetch never faults).
#[inline(always)]
pub fn prefetch_ptr<T>(p: *const T) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        // SAFETY: SSE is part of the x86-64 baseline, so the instruction exists; a prefetch
        // never faults and has no architectural effect, whatever the address.
        unsafe { _mm_prefetch::<_MM_HINT_T0>(p.cast()) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
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
        if has!("avx2") && has!("fma") && has!("popcnt") && has!("bmi1") && has!("bmi2") && has!("lzcnt") {
            if has!("avx512f") && has!("avx512vl") && has!("avx512dq") && has!("avx512bw") {
                return Isa::Avx512;
            }
            return Isa::Avx2;
        }
    }
    Isa::Portable
}

/// The 8×8 transpose: `out[k][l] = rows[l][k]`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) fn transpose8(r: [std::arch::x86_64::__m256; 8]) -> [std::arch::x86_64::__m256; 8] {
    use std::arch::x86_64::*;
    let lo = |a, b| _mm256_unpacklo_ps(a, b);
    let hi = |a, b| _mm256_unpackhi_ps(a, b);
    let (t0, t1, t2, t3) = (lo(r[0], r[1]), hi(r[0], r[1]), lo(r[2], r[3]), hi(r[2], r[3]));
    let (t4, t5, t6, t7) = (lo(r[4], r[5]), hi(r[4], r[5]), lo(r[6], r[7]), hi(r[6], r[7]));
    let (s0, s1) = (_mm256_shuffle_ps::<0x44>(t0, t2), _mm256_shuffle_ps::<0xEE>(t0, t2));
    let (s2, s3) = (_mm256_shuffle_ps::<0x44>(t1, t3), _mm256_shuffle_ps::<0xEE>(t1, t3));
    let (s4, s5) = (_mm256_shuffle_ps::<0x44>(t4, t6), _mm256_shuffle_ps::<0xEE>(t4, t6));
    let (s6, s7) = (_mm256_shuffle_ps::<0x44>(t5, t7), _mm256_shuffle_ps::<0xEE>(t5, t7));
    [
        _mm256_permute2f128_ps::<0x20>(s0, s4),
        _mm256_permute2f128_ps::<0x20>(s1, s5),
        _mm256_permute2f128_ps::<0x20>(s2, s6),
        _mm256_permute2f128_ps::<0x20>(s3, s7),
        _mm256_permute2f128_ps::<0x31>(s0, s4),
        _mm256_permute2f128_ps::<0x31>(s1, s5),
        _mm256_permute2f128_ps::<0x31>(s2, s6),
        _mm256_permute2f128_ps::<0x31>(s3, s7),
    ]
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
