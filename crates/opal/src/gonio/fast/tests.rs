//! Tests of the fast loop's lane kernels against the scalar code.

use super::lanes::{V3, interact_side_block};
use super::scalar::interact_scalar_side;
use super::*;
use crate::fastmath::wide::F;
use crate::math::Vec3;
use crate::sampling::Rng;
use crate::sampling::square_to_uniform_sphere;

/// Every lane of the SIMD interaction equals the scalar interaction bit for bit (new
/// direction and weight factor; the direction of a lost sample is irrelevant): all lanes
/// with the full Beckmann iteration, the lanes not flagged for a redo without it (and the
/// flagged ones must be rare); for 8 and 16 lanes, every face kind and dotted sides (area mixtures), both faces, random
/// directions from both sides (plus normal incidence).
fn check_kernels<const N: usize>() {
    let fr = Fresnel::new(1.49);
    let tab: &[f32; TAB_NC * TAB_NU] = slope_table().try_into().unwrap();
    let plain = [
        FastFace::Polished,
        FastFace::Ggx(Ggx::new(0.15).unwrap()),
        FastFace::Ggx(Ggx::new(0.6).unwrap()),
        FastFace::Beckmann { ndf: Beckmann::new(0.25).unwrap(), mitsuba_g1: true },
        FastFace::Beckmann { ndf: Beckmann::new(0.25).unwrap(), mitsuba_g1: false },
        FastFace::Beckmann { ndf: Beckmann::new(0.8).unwrap(), mitsuba_g1: false },
    ];
    let mut faces: Vec<FastSide> = plain.iter().map(|&f| FastSide::Plain(f)).collect();
    // dotted sides: rough dots on a polished land, and two rough parts
    faces.push(FastSide::Dotted { f: 0.35, a: plain[1], b: FastFace::Polished });
    faces.push(FastSide::Dotted { f: 0.6, a: plain[3], b: FastFace::Polished });
    faces.push(FastSide::Dotted { f: 0.25, a: plain[5], b: plain[2] });
    let mut rng = Rng::new(5, 0, 0);
    for face in &faces {
        let (mut lanes, mut redone, mut lost) = (0usize, 0usize, 0usize);
        for top in [true, false] {
            for blk in 0..2_000 {
                let mut d = [Vec3::ZERO; N];
                let (mut u0, mut u1, mut u2) = ([0.0f32; N], [0.0f32; N], [0.0f32; N]);
                for l in 0..N {
                    d[l] =
                        if blk == 0 && l == 0 { -Vec3::Z } else { square_to_uniform_sphere(rng.next_2d()) };
                    (u0[l], u1[l], u2[l]) = (rng.next_f32(), rng.next_f32(), rng.next_f32());
                }
                let dv = V3 { x: F(d.map(|v| v.x)), y: F(d.map(|v| v.y)), z: F(d.map(|v| v.z)) };
                let flip = |v: Vec3| if top { v } else { Vec3::new(v.x, -v.y, -v.z) };
                for full in [false, true] {
                    let (wi, g, redo) =
                        interact_side_block::<N>(face, &fr, tab, top, dv, F(u0), F(u1), F(u2), full);
                    for l in 0..N {
                        if full {
                            assert!(!redo.get(l));
                        } else {
                            lanes += 1;
                            if redo.get(l) {
                                redone += 1;
                                continue;
                            }
                        }
                        let (e, ge) = interact_scalar_side(face, &fr, flip(-d[l]), u0[l], u1[l], u2[l]);
                        let e = flip(e);
                        let what = format!("{face:?} top {top} full {full} d {}", d[l]);
                        assert_eq!(g.0[l].to_bits(), ge.to_bits(), "{what}: weight");
                        if ge > 0.0 {
                            let got = [wi.x.0[l], wi.y.0[l], wi.z.0[l]].map(f32::to_bits);
                            assert_eq!(got, [e.x, e.y, e.z].map(f32::to_bits), "{what}");
                        } else if !full {
                            lost += 1;
                        }
                    }
                }
            }
        }
        // from the Beckmann table start, two Newton steps converge except in the tails
        // u < 1/128 or u > 127/128 (the first and last table column, where the quantile is
        // singular): 1.6 % of uniform u, ~1.8 % measured
        assert!(redone * 40 <= lanes, "{face:?}: {redone} of {lanes} lanes redone");
        assert!(lost < lanes / 2, "{face:?}: {lost} of {lanes} lost");
    }
}

#[test]
fn simd_kernels_match_scalar_code() {
    check_kernels::<8>();
    check_kernels::<16>();
}
