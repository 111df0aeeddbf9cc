//! Bit-exact tests of the small AVX2 steps of the wavefront (`avx.rs`) against the scalar
//! code they mirror: the roulette, the lane masks and counters.

use super::avx;
use super::path::survival;
use super::wavefront::W;
use crate::sampling::{Rng, RngStream};
use crate::spectrum::Spectrum;

/// Values that exercise `f32::max`'s and `min`'s special cases (signed zeros, NaN,
/// infinities, ties with 0.95), and ordinary ones.
fn awkward(rng: &mut Rng) -> f32 {
    match rng.next_u32() % 6 {
        0 => [0.0, -0.0, f32::NAN, f32::INFINITY, -1.0, 0.95, 1e-30, f32::MAX][rng.next_u32() as usize % 8],
        1 => 0.95 * rng.next_f32(),
        _ => rng.next_f32() * 2.0,
    }
}

#[test]
fn lane_roulette_draws_and_scales_like_the_scalar_one() {
    if !std::arch::is_x86_feature_detected!("avx2") {
        return;
    }
    let stream = RngStream::new(5, super::path::RNG_STREAM);
    let mut rng = Rng::new(6, 6, 6);
    let mut ends = [0usize; 2];
    for round in 0..20_000u64 {
        let gens: Vec<Rng> = (0..W as u64).map(|l| stream.rng(round * W as u64 + l)).collect();
        let mut state: [u64; W] = std::array::from_fn(|l| gens[l].state);
        let inc: [u64; W] = std::array::from_fn(|l| gens[l].inc);
        let mut beta: [[f32; W]; 3] = std::array::from_fn(|_| std::array::from_fn(|_| awkward(&mut rng)));
        let b0: [f32; W] = std::array::from_fn(|_| awkward(&mut rng));
        let before = beta;
        let m = rng.next_u32() & 0xff;
        // SAFETY: the CPU supports AVX2 (checked above).
        let end = unsafe { avx::roulette(&mut beta, &b0, &mut state, &inc, m) };
        assert_eq!(end & !m, 0, "only lanes of the mask end");
        for (l, g) in gens.into_iter().enumerate() {
            let b = Spectrum([before[0][l], before[1][l], before[2][l]]);
            let got = Spectrum([beta[0][l], beta[1][l], beta[2][l]]);
            if m >> l & 1 == 0 {
                assert_eq!(state[l], g.state, "lane {l}: no draw outside the mask");
                assert!((0..3).all(|c| got[c].to_bits() == b[c].to_bits()), "lane {l} untouched");
                continue;
            }
            // `trace_path`'s roulette
            let mut g = g;
            let q = survival(b, b0[l]);
            let dies = g.next_f32() >= q;
            assert_eq!(state[l], g.state, "lane {l}: one draw");
            assert_eq!(end >> l & 1 == 1, dies, "lane {l}: β {b:?}, b0 {}", b0[l]);
            ends[dies as usize] += 1;
            let want = if dies { b } else { b * (1.0 / q) };
            for c in 0..3 {
                assert_eq!(got[c].to_bits(), want[c].to_bits(), "lane {l} channel {c}: {b:?}, b0 {}", b0[l]);
            }
        }
    }
    assert!(ends[0] > 10_000 && ends[1] > 10_000, "both outcomes exercised: {ends:?}");
}

#[test]
fn lane_masks_and_counters_match_the_scalar_loops() {
    if !std::arch::is_x86_feature_detected!("avx2") {
        return;
    }
    let mut rng = Rng::new(7, 7, 7);
    for _ in 0..10_000 {
        let pick = |rng: &mut Rng| match rng.next_u32() % 4 {
            0 => [i32::MIN, i32::MAX, -1, 0, 1][rng.next_u32() as usize % 5],
            _ => (rng.next_u32() % 11) as i32 - 5,
        };
        let a: [i32; W] = std::array::from_fn(|_| pick(&mut rng));
        let k = pick(&mut rng);
        let want = (0..W).fold(0u32, |m, l| m | ((a[l] >= k) as u32) << l);
        // SAFETY: the CPU supports AVX2 (checked above).
        assert_eq!(unsafe { avx::at_least(&a, k) }, want, "{a:?} ≥ {k}");
        let m = rng.next_u32() & 0xff;
        // SAFETY: as above.
        let sel = unsafe { avx::select_u32(&a, m) };
        for l in 0..W {
            assert_eq!(sel[l], if m >> l & 1 == 1 { a[l] as u32 } else { 0 }, "lane {l}");
        }
        let mut b = a;
        // SAFETY: as above.
        unsafe { avx::increment(&mut b, m) };
        for l in 0..W {
            let want = if m >> l & 1 == 1 { a[l].wrapping_add(1) } else { a[l] };
            assert_eq!(b[l], want, "lane {l}");
        }
    }
}

#[test]
fn several_draws_at_once_are_the_scalar_numbers() {
    if !std::arch::is_x86_feature_detected!("avx2") {
        return;
    }
    let stream = RngStream::new(11, super::path::RNG_STREAM);
    let mut rng = Rng::new(3, 3, 3);
    for round in 0..5_000u64 {
        let mut scalar: Vec<Rng> = (0..W as u64).map(|l| stream.rng(round * 31 + l)).collect();
        let mut state: [u64; W] = std::array::from_fn(|l| scalar[l].state);
        let inc: [u64; W] = std::array::from_fn(|l| scalar[l].inc);
        let m = rng.next_u32() & 0xff;
        // SAFETY: the CPU supports AVX2 (checked above).
        let (got2, got5) =
            unsafe { (avx::draws::<2, 1>(&mut state, &inc, m), avx::draws::<5, 0>(&mut state, &inc, m)) };
        for (l, r) in scalar.iter_mut().enumerate() {
            if m >> l & 1 == 0 {
                assert_eq!(state[l], r.state, "lane {l}: no draw outside the mask");
                continue;
            }
            r.next_f32();
            let want: Vec<u32> = (0..7).map(|_| r.next_f32().to_bits()).collect();
            let got: Vec<u32> = got2.iter().chain(&got5).map(|u| u[l].to_bits()).collect();
            assert_eq!(got, want, "lane {l}");
            assert_eq!(state[l], r.state, "lane {l}: state after eight draws");
        }
    }
}
