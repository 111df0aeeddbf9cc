use super::*;
use crate::math::fresnel_dielectric_f64;

fn setup(incidences_deg: &[f64], photons: u64, divergence_deg: f64) -> GonioSetup {
    GonioSetup {
        beam: Beam { azimuth: 0.0, divergence: divergence_deg.to_radians(), aperture_radius_mm: 0.0 },
        incidences: incidences_deg.iter().map(|d| d.to_radians()).collect(),
        detectors: DetectorLayout {
            grid: detectors::DetectorGrid::PlaneOfIncidence {
                angles: (-89..=89).map(|d| (d as f64).to_radians()).collect(),
            },
            radius: 1f64.to_radians(),
            distance_mm: None,
        },
        photons,
        seed: 42,
        max_interactions: 200,
    }
}

fn plate(front: Face, back: Face, mu: f64) -> Plate {
    Plate { ior: 1.49, thickness_mm: 2.0, absorption_per_mm: mu, front, back, radius_mm: None }
}

#[test]
fn polished_plate_matches_closed_form() {
    // incoherent multiple-reflection sum with internal transmittance τ = exp(−μ d / cos θt):
    // T = (1−R)² τ / (1 − R² τ²), R_tot = R + R (1−R)² τ² / (1 − R² τ²)
    let n = 200_000;
    for mu in [0.0, 0.2] {
        let g = Gonio::new(setup(&[0.0, 30.0, 60.0, 75.0], n, 0.0)).unwrap();
        let res = g.run_plate(&plate(Face::Polished, Face::Polished, mu)).unwrap();
        for r in &res.incidences {
            let ci = r.incidence.cos();
            let rf = fresnel_dielectric_f64(ci, 1.49);
            let st = r.incidence.sin() / 1.49;
            let tau = (-mu * 2.0 / (1.0 - st * st).sqrt()).exp();
            let t_exp = (1.0 - rf).powi(2) * tau / (1.0 - rf * rf * tau * tau);
            let r_exp = rf + rf * (1.0 - rf).powi(2) * tau * tau / (1.0 - rf * rf * tau * tau);
            // every photon ends in R or T with weight 1 (no absorption) → binomial noise; with
            // absorption the weights are in (0, 1] and the binomial σ is an upper bound
            let s_t = (t_exp * (1.0 - t_exp) / n as f64).sqrt();
            let s_r = (r_exp * (1.0 - r_exp) / n as f64).sqrt();
            assert!((r.t - t_exp).abs() < 4.0 * s_t, "μ={mu} θ={}: T {} vs {t_exp}", r.incidence, r.t);
            assert!((r.r - r_exp).abs() < 4.0 * s_r, "μ={mu} θ={}: R {} vs {r_exp}", r.incidence, r.r);
            assert!((r.r + r.t + r.lost + r.absorbed - 1.0).abs() < 1e-5);
            assert_eq!(r.bad_photons, 0);
            if mu == 0.0 {
                assert!((r.t - (1.0 - rf) / (1.0 + rf)).abs() < 4.0 * s_t);
            }
            // all the reflected light is in the specular detector at p = +θ (collimated beam)
            let k = (89.0 + r.incidence.to_degrees()).round() as usize;
            let om = g.detectors().solid_angle();
            assert!(
                (r.value[k] * om - r.r).abs() < 1e-9,
                "specular detector {} vs R {}",
                r.value[k] * om,
                r.r
            );
        }
    }
}

#[test]
fn same_result_for_any_thread_count() {
    let g = Gonio::new(setup(&[0.0, 45.0], 3 * BATCH + 123, 0.5)).unwrap();
    let p = plate(Face::Polished, Face::Rough { ndf: Ndfs::ggx(0.3), scattering: Scattering::Single }, 0.05);
    let run = |threads| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| g.run_plate(&p).unwrap())
    };
    let (a, b) = (run(1), run(2));
    for (x, y) in a.incidences.iter().zip(&b.incidences) {
        assert_eq!(x.value, y.value);
        assert_eq!(x.value_stderr, y.value_stderr);
        assert_eq!((x.r, x.t, x.lost, x.absorbed), (y.r, y.t, y.lost, y.absorbed));
    }
}

/// An unset cancel flag changes nothing; a set one stops the run with `Interrupted`.
#[test]
fn cancel_flag_stops_and_unset_changes_nothing() {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, Ordering};
    let g = Gonio::new(setup(&[0.0, 45.0], 2 * BATCH + 7, 0.5)).unwrap();
    let p = plate(Face::Polished, Face::Rough { ndf: Ndfs::ggx(0.3), scattering: Scattering::Single }, 0.05);
    let flag = Arc::new(AtomicBool::new(false));
    let gc = g.clone().with_cancel(Some(flag.clone()));
    let (a, b) = (g.run_plate(&p).unwrap(), gc.run_plate(&p).unwrap());
    for (x, y) in a.incidences.iter().zip(&b.incidences) {
        assert_eq!(x.value, y.value);
        assert_eq!((x.r, x.t, x.lost), (y.r, y.t, y.lost));
    }
    flag.store(true, Ordering::Relaxed);
    assert!(matches!(gc.run_plate(&p), Err(crate::Error::Interrupted { .. })));
}

#[test]
fn energy_bookkeeping_and_multiple_scattering_keeps_energy() {
    let g = Gonio::new(setup(&[0.0, 30.0, 60.0, 75.0], 40_000, 0.5)).unwrap();
    for scattering in [Scattering::Single, Scattering::SingleHeightCorrelated, Scattering::Multiple] {
        for entry_rough in [false, true] {
            let rough = Face::Rough { ndf: Ndfs::ggx(0.8), scattering };
            let p = if entry_rough {
                plate(rough, Face::Polished, 0.0)
            } else {
                plate(Face::Polished, rough, 0.0)
            };
            let res = g.run_plate(&p).unwrap();
            for r in &res.incidences {
                assert!((r.r + r.t + r.lost + r.absorbed - 1.0).abs() < 1e-5);
                assert_eq!(r.bad_photons, 0);
                assert_eq!(r.absorbed, 0.0);
                if scattering == Scattering::Multiple {
                    // energy-conserving micro-surface: only walks beyond MAX_BOUNCES or the plate's
                    // interaction limit are lost
                    assert!(r.r + r.t >= 0.995, "{scattering:?} θ={}: R+T {}", r.incidence, r.r + r.t);
                } else {
                    assert!(r.lost > 0.0);
                }
                // the detectors in the plane see a positive, finite signal around the specular peak
                let k = (89.0 + r.incidence.to_degrees()).round() as usize;
                assert!(r.value[k] > 0.0 && r.value[k].is_finite());
            }
        }
    }
}

#[test]
fn finite_plate_and_hemisphere_detectors() {
    // a small polished plate lit by a narrow beam, detectors at 500 mm: the far-field answer
    // is recovered (the plate is 100× smaller than the distance); the hemisphere layout gives the
    // same specular detector value as the plane layout
    let mut s = setup(&[30.0], 50_000, 0.0);
    s.beam.aperture_radius_mm = 0.5;
    s.detectors.distance_mm = Some(500.0);
    let g = Gonio::new(s).unwrap();
    let mut p = plate(Face::Polished, Face::Polished, 0.0);
    p.radius_mm = Some(5.0);
    let res = g.run_plate(&p).unwrap();
    let r = &res.incidences[0];
    let rf = fresnel_dielectric_f64(30f64.to_radians().cos(), 1.49);
    let r_exp = 2.0 * rf / (1.0 + rf);
    assert!((r.r - r_exp).abs() < 4.0 * (r_exp * (1.0 - r_exp) / 50_000.0).sqrt());
    // photons reaching the rim are lost (5 mm radius, 2 mm thick: a few internal bounces at most)
    assert!(r.lost < 1e-3);
    let mut s = setup(&[30.0], 50_000, 0.0);
    s.detectors.grid = detectors::DetectorGrid::Hemisphere {
        polar: (0..90).map(|d| (d as f64).to_radians()).collect(),
        azimuth: (0..360).step_by(5).map(|d| (d as f64).to_radians()).collect(),
    };
    let g = Gonio::new(s).unwrap();
    let res = g.run_plate(&plate(Face::Polished, Face::Polished, 0.0)).unwrap();
    let r = &res.incidences[0];
    let dets = g.detectors().list();
    let k = dets
        .iter()
        .position(|d| d.side == Side::R && (d.angle_deg - 30.0).abs() < 1e-9 && d.azimuth_deg == 0.0)
        .unwrap();
    assert!((r.value[k] * g.detectors().solid_angle() - r.r).abs() < 1e-9);
}

#[test]
fn rejects_bad_input() {
    let g = Gonio::new(setup(&[0.0], 100, 0.0)).unwrap();
    let mut p = plate(Face::Polished, Face::Polished, 0.0);
    p.ior = 0.0;
    assert!(g.run_plate(&p).is_err());
    p.ior = 1.5;
    p.thickness_mm = -1.0;
    assert!(g.run_plate(&p).is_err());
    let mut s = setup(&[0.0], 100, 0.0);
    s.detectors.radius = 90f64.to_radians();
    assert!(Gonio::new(s).is_err());
    let mut s = setup(&[0.0], 100, 0.0);
    s.incidences = vec![95f64.to_radians()];
    assert!(Gonio::new(s).is_err());
}

#[test]
fn detector_lookup_matches_brute_force() {
    use crate::sampling::square_to_uniform_sphere;
    let plane = |r_deg: f64, dist: Option<f64>| DetectorLayout {
        grid: detectors::DetectorGrid::PlaneOfIncidence {
            angles: (-89..=89).map(|d| (d as f64).to_radians()).collect(),
        },
        radius: r_deg.to_radians(),
        distance_mm: dist,
    };
    let hemi = DetectorLayout {
        grid: detectors::DetectorGrid::Hemisphere {
            polar: (0..90).step_by(3).map(|d| (d as f64).to_radians()).collect(),
            azimuth: (0..360).step_by(10).map(|d| (d as f64).to_radians()).collect(),
        },
        radius: 2f64.to_radians(),
        distance_mm: None,
    };
    let layouts = [
        (plane(1.0, None), 0.0),
        (plane(1.0, None), 0.7),
        (plane(5.0, None), -2.0),
        (plane(0.3, Some(300.0)), 0.0),
        (hemi, 0.3),
    ];
    let mut rng = crate::sampling::Rng::new(11, 0, 0);
    for (li, (layout, az)) in layouts.iter().enumerate() {
        let dets = Detectors::new(layout, *az).unwrap();
        let r = layout.radius as f32;
        let mut hits = 0usize;
        let mut check = |d: Vec3, p: Vec3| {
            let side = if d.z > 0.0 { Side::R } else { Side::T };
            let (mut a, mut b) = (Vec::new(), Vec::new());
            dets.for_each_hit(side, d, p, |i| a.push(i));
            dets.for_each_hit_brute_force(side, d, p, |i| b.push(i));
            a.sort_unstable();
            assert_eq!(a, b, "layout {li}: direction {d:?}");
            hits += a.len();
        };
        for _ in 0..100_000 {
            let d = square_to_uniform_sphere(rng.next_2d());
            let p = if layout.distance_mm.is_some() {
                Vec3::new(rng.next_f32() * 4.0 - 2.0, rng.next_f32() * 4.0 - 2.0, 0.0)
            } else {
                Vec3::ZERO
            };
            check(d, if d.z < 0.0 { p - Vec3::Z * 2.0 } else { p });
        }
        // directions just inside and outside every cap
        for det in dets.list() {
            let (e1, e2) = det.axis.any_orthonormal_pair();
            for k in 0..16 {
                let b = k as f32 * std::f32::consts::TAU / 16.0;
                for f in [0.5f32, 0.999, 1.001, 1.5] {
                    let t = r * f;
                    let d = (det.axis * t.cos() + (e1 * b.cos() + e2 * b.sin()) * t.sin()).normalize();
                    if d.z != 0.0 && layout.distance_mm.is_none() {
                        check(d, Vec3::ZERO);
                    }
                }
            }
        }
        // expected ≥ ~240 (the 0.3° detectors of layout 3 cover 0.25 % of the sphere)
        assert!(hits > 150, "layout {li}: only {hits} hits");
    }
}

/// The fast loop (infinite plate, GGX/Beckmann single scattering, plain or dotted faces) against
/// the general loop:
/// different sampling algorithms, same model, so totals and detectors must agree within the
/// Monte-Carlo noise (σ of the difference of two independent estimates, an upper bound here:
/// the shared random numbers correlate the runs positively).
#[test]
fn fast_path_matches_general_path() {
    let n = 100_000;
    let g = Gonio::new(setup(&[0.0, 60.0, 75.0], n, 0.5)).unwrap();
    let general = g.clone().with_general_loop(true);
    let (mut compared, mut bad) = (0usize, 0usize);
    for (ndf, scattering, coverage) in [
        (Ndfs::ggx(0.35), Scattering::Single, None),
        (Ndfs::beckmann(0.25), Scattering::Single, None),
        (Ndfs::beckmann(0.25), Scattering::SingleMitsuba, None),
        (Ndfs::ggx(0.3), Scattering::Single, Some(0.35)),
        (Ndfs::beckmann(0.4), Scattering::SingleMitsuba, Some(0.6)),
    ] {
        for entry_rough in [false, true] {
            for mu in [0.0, 0.1] {
                let rough = match coverage {
                    None => Face::Rough { ndf: ndf.clone(), scattering },
                    Some(f) => Face::dotted(f, ndf.clone(), scattering),
                };
                let p = if entry_rough {
                    plate(rough, Face::Polished, mu)
                } else {
                    plate(Face::Polished, rough, mu)
                };
                assert!(fast::FastPlate::new(&p).is_some());
                let (a, b) = (g.run_plate(&p).unwrap(), general.run_plate(&p).unwrap());
                for (x, y) in a.incidences.iter().zip(&b.incidences) {
                    let what = format!(
                        "{ndf:?} {scattering:?} coverage {coverage:?} rough entry {entry_rough} μ {mu} θ {}",
                        x.incidence
                    );
                    assert_eq!(x.bad_photons, 0);
                    assert!((x.r + x.t + x.lost + x.absorbed - 1.0).abs() < 1e-5, "{what}");
                    for (name, u, v) in [("R", x.r, y.r), ("T", x.t, y.t), ("lost", x.lost, y.lost)] {
                        let pp = v.clamp(1e-4, 1.0 - 1e-4);
                        let s = (2.0 * pp * (1.0 - pp) / n as f64).sqrt();
                        assert!((u - v).abs() <= 4.0 * s, "{what}: {name} {u} vs {v} (σ {s})");
                    }
                    for k in 0..x.value.len() {
                        if (x.hits[k] + y.hits[k]) < 40 {
                            continue;
                        }
                        let s = (x.value_stderr[k].powi(2) + y.value_stderr[k].powi(2)).sqrt();
                        compared += 1;
                        if (x.value[k] - y.value[k]).abs() > 3.0 * s {
                            bad += 1;
                        }
                    }
                }
            }
        }
    }
    // Gaussian: 0.27 % beyond 3σ; 1 % allows for counts of a few dozen photons
    assert!(
        compared > 1000 && bad as f64 <= 0.01 * compared as f64,
        "{bad}/{compared} detectors with |z| > 3"
    );
}

#[test]
fn mitsuba_g1_changes_only_beckmann() {
    let g = Gonio::new(setup(&[60.0], 20_000, 0.5)).unwrap();
    let run = |ndf: Ndfs, s| {
        g.run_plate(&plate(Face::Polished, Face::Rough { ndf, scattering: s }, 0.0)).unwrap().incidences[0]
            .clone()
    };
    let (a, b) = (run(Ndfs::ggx(0.3), Scattering::Single), run(Ndfs::ggx(0.3), Scattering::SingleMitsuba));
    assert_eq!((a.r, a.t, a.lost), (b.r, b.t, b.lost));
    let (a, b) =
        (run(Ndfs::beckmann(0.25), Scattering::Single), run(Ndfs::beckmann(0.25), Scattering::SingleMitsuba));
    assert_ne!(a.lost, b.lost);
    // same random numbers, G1 within 0.35 % per rough interaction
    assert!((a.lost - b.lost).abs() < 0.0035 * a.mean_interactions * (1.0 - a.lost));
}

/// The photon loop compiled for every instruction set the CPU offers (portable, AVX2, AVX-512)
/// gives the same accumulators bit for bit, for every face kind the fast loop handles (dotted
/// faces included), both
/// entries, with and without absorption, collimated normal incidence (the Beckmann sampler's
/// scalar redo path) and grazing incidence.
#[test]
fn simd_and_portable_loops_agree_bit_for_bit() {
    let kinds: Vec<fast::Kernels> = [fast::Kernels::Avx2, fast::Kernels::Avx512]
        .into_iter()
        .filter(|&k| fast::Kernels::detect(true) == k || (k == fast::Kernels::Avx2 && avx2()))
        .collect();
    fn avx2() -> bool {
        #[cfg(target_arch = "x86_64")]
        return std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma");
        #[allow(unreachable_code)]
        false
    }
    let faces = [
        Face::Polished,
        Face::Rough { ndf: Ndfs::ggx(0.3), scattering: Scattering::Single },
        Face::Rough { ndf: Ndfs::beckmann(0.25), scattering: Scattering::Single },
        Face::Rough { ndf: Ndfs::beckmann(0.25), scattering: Scattering::SingleMitsuba },
        Face::dotted(0.35, Ndfs::ggx(0.3), Scattering::Single),
        Face::dotted(0.5, Ndfs::beckmann(0.25), Scattering::Single),
    ];
    let mut compared = 0;
    for (fi, rough) in faces.iter().enumerate() {
        for entry_rough in [false, true] {
            let mu = if entry_rough { 0.1 } else { 0.0 };
            let p = if entry_rough {
                plate(rough.clone(), Face::Polished, mu)
            } else {
                plate(Face::Polished, rough.clone(), mu)
            };
            let fp = fast::FastPlate::new(&p).unwrap();
            for (inc, div) in [(0.0f64, 0.0f64), (0.0, 0.5), (45.0, 0.5), (85.0, 0.5)] {
                let g = Gonio::new(setup(&[inc], 5_000, div)).unwrap();
                let bf = BeamFrame {
                    sa: 0.0,
                    ca: 1.0,
                    st: inc.to_radians().sin() as f32,
                    ct: inc.to_radians().cos() as f32,
                    cos_div: div.to_radians().cos() as f32,
                };
                let run = |k| {
                    let mut acc = Acc::new(g.dets.len());
                    g.trace_batch_fast(&fp, &bf, fi as u64, 100, 5_000, &mut acc, k);
                    acc
                };
                let a = run(fast::Kernels::Portable);
                assert!(a.r + a.t > 0.0);
                for &k in &kinds {
                    let b = run(k);
                    let what = format!("{k:?} face {fi} rough entry {entry_rough} θ {inc} δ {div}");
                    assert_eq!(
                        (a.r, a.t, a.lost, a.absorbed, a.interactions, a.bad),
                        (b.r, b.t, b.lost, b.absorbed, b.interactions, b.bad),
                        "{what}"
                    );
                    assert_eq!(
                        (&a.sum, &a.sum2, &a.sum_bsdf, &a.hits),
                        (&b.sum, &b.sum2, &b.sum_bsdf, &b.hits),
                        "{what}"
                    );
                    compared += 1;
                }
            }
        }
    }
    assert!(compared >= 48 || kinds.is_empty());
}

/// A dotted face with coverage 0 or 1 is its land or its dots, photon for photon (the area
/// choice reuses the component's first random number unchanged at f = 0 and f = 1), in the
/// general loop and in the fast loop.
#[test]
fn dotted_face_limits_are_bit_identical() {
    let fast = Gonio::new(setup(&[0.0, 60.0], 20_000, 0.5)).unwrap();
    let general = fast.clone().with_general_loop(true);
    for ndf in [Ndfs::ggx(0.3), Ndfs::beckmann(0.25)] {
        let rough = Face::Rough { ndf: ndf.clone(), scattering: Scattering::Single };
        for (g, name) in [(&general, "general"), (&fast, "fast")] {
            for entry in [true, false] {
                let mk = |f: Face| {
                    if entry { plate(f, Face::Polished, 0.05) } else { plate(Face::Polished, f, 0.05) }
                };
                for (cov, same) in [(0.0, Face::Polished), (1.0, rough.clone())] {
                    let d = g.run_plate(&mk(Face::dotted(cov, ndf.clone(), Scattering::Single))).unwrap();
                    let s = g.run_plate(&mk(same)).unwrap();
                    for (x, y) in d.incidences.iter().zip(&s.incidences) {
                        let what = format!("{name} loop {ndf:?} coverage {cov} entry {entry}");
                        assert_eq!(x.value, y.value, "{what}");
                        assert_eq!((x.r, x.t, x.lost, x.absorbed), (y.r, y.t, y.lost, y.absorbed), "{what}");
                    }
                }
            }
        }
    }
}

/// With a strongly absorbing plate only the first interaction with the lit face reaches the R
/// detectors, so R of a dotted entry face is the area-weighted sum f·R_rough + (1 − f)·R_polished
/// (within the Monte-Carlo noise); energy is booked (R + T + lost + absorbed = 1), and
/// multiple-scattering dots lose nothing but the absorbed power.
#[test]
fn dotted_face_is_an_area_mixture() {
    let n = 100_000;
    let g = Gonio::new(setup(&[0.0, 45.0, 75.0], n, 0.5)).unwrap();
    let ndf = Ndfs::ggx(0.4);
    let run = |f: Face| g.run_plate(&plate(f, Face::Polished, 50.0)).unwrap();
    let cov = 0.35;
    let d = run(Face::dotted(cov, ndf.clone(), Scattering::Single));
    let r = run(Face::Rough { ndf: ndf.clone(), scattering: Scattering::Single });
    let p = run(Face::Polished);
    for ((x, y), z) in d.incidences.iter().zip(&r.incidences).zip(&p.incidences) {
        let expect = cov * y.r + (1.0 - cov) * z.r;
        let s = (expect * (1.0 - expect) / n as f64).sqrt() + (y.r / n as f64).sqrt();
        assert!((x.r - expect).abs() < 4.0 * s, "θ={}: R {} vs {expect}", x.incidence, x.r);
        assert!((x.r + x.t + x.lost + x.absorbed - 1.0).abs() < 1e-5);
        assert_eq!(x.bad_photons, 0);
    }
    let ms = Face::dotted(cov, Ndfs::ggx(0.8), Scattering::Multiple);
    for res in [
        g.run_plate(&plate(ms.clone(), Face::Polished, 0.0)).unwrap(),
        g.run_plate(&plate(Face::Polished, ms, 0.0)).unwrap(),
    ] {
        for x in &res.incidences {
            assert!(x.r + x.t >= 0.995, "θ={}: R+T {}", x.incidence, x.r + x.t);
        }
    }
    // refused: coverage outside [0, 1], nested dotted faces
    let bad = Face::dotted(1.5, ndf.clone(), Scattering::Single);
    assert!(g.run_plate(&plate(bad, Face::Polished, 0.0)).is_err());
    let nested = Face::Dotted {
        coverage: 0.5,
        dots: Box::new(Face::dotted(0.5, ndf, Scattering::Single)),
        land: Box::new(Face::Polished),
    };
    assert!(g.run_plate(&plate(nested, Face::Polished, 0.0)).is_err());
}

/// Batches split over 2 and 3 simulated processes give the one-process result bit for bit on
/// every rank (the fast loop and the general one; more ranks than batches of the small run).
#[test]
fn same_result_for_any_process_count() {
    use crate::dist::ThreadComm;
    use std::sync::Arc;
    let p = plate(Face::Polished, Face::Rough { ndf: Ndfs::ggx(0.3), scattering: Scattering::Single }, 0.05);
    for general in [false, true] {
        let g = Gonio::new(setup(&[0.0, 45.0], 3 * BATCH + 123, 0.5)).unwrap().with_general_loop(general);
        let one = g.run_plate(&p).unwrap();
        for n in [2, 3, 5] {
            let all = ThreadComm::run(n, |c| {
                let c: Arc<dyn crate::dist::Comm> = Arc::new(c.clone());
                g.clone().with_comm(Some(c)).run_plate(&p).unwrap()
            });
            for r in &all {
                for (x, y) in one.incidences.iter().zip(&r.incidences) {
                    assert_eq!(bits(&x.value), bits(&y.value), "{n} ranks");
                    assert_eq!(bits(&x.value_stderr), bits(&y.value_stderr));
                    assert_eq!(bits(&x.bsdf), bits(&y.bsdf));
                    assert_eq!(x.hits, y.hits);
                    assert_eq!(
                        [x.r, x.t, x.lost, x.absorbed, x.mean_interactions].map(f64::to_bits),
                        [y.r, y.t, y.lost, y.absorbed, y.mean_interactions].map(f64::to_bits)
                    );
                }
            }
        }
    }
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}
