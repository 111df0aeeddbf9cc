//! Fitting a full-hemisphere measurement (detector polar × azimuth, the simulator's hemisphere
//! layout): a synthetic GGX α = 0.2 plate measured over the hemisphere is fitted back.

use super::*;
use crate::measured::Measured;
use opal::gonio::{Beam, DetectorGrid, DetectorLayout, Face, Gonio, GonioSetup, Plate, Scattering};

#[test]
fn hemisphere_measurement_fits_back() {
    let beam = Beam { azimuth: 0.0, divergence: 0.5f64.to_radians(), aperture_radius_mm: 1.0 };
    let rough = Plate {
        ior: 1.49,
        thickness_mm: 2.0,
        absorption_per_mm: 0.0,
        front: Face::Polished,
        back: Face::Rough { ndf: Ndfs::ggx(0.2), scattering: Scattering::Single },
        radius_mm: None,
    };
    let radius = 2f64.to_radians();
    let g = Gonio::new(GonioSetup {
        beam: beam.clone(),
        incidences: vec![0.0, 40f64.to_radians()],
        detectors: DetectorLayout {
            grid: DetectorGrid::Hemisphere {
                polar: (0..18).map(|i| (5.0 * i as f64).to_radians()).collect(),
                azimuth: (0..12).map(|i| (30.0 * i as f64).to_radians()).collect(),
            },
            radius,
            distance_mm: None,
        },
        photons: 200_000,
        seed: 1001,
        max_interactions: 200,
    })
    .unwrap();
    let m = Measured::from_gonio(&g, &g.run_plate(&rough).unwrap(), "hemisphere");
    assert!(m.hemisphere);
    let setup = FitSetup {
        plate: Plate { back: Face::Polished, ..rough },
        rough_front: false,
        scattering: Scattering::Single,
        beam,
        detector_radius: radius,
        detector_distance_mm: None,
        photons: 200_000,
        seed: 7,
        max_interactions: 200,
        fit_on: FitOn::Both,
        floor_rel: 0.01,
        min_snr: None,
        max_iters: 40,
        coarse_photons: None,
        scale: ScaleSetup { mode: ScaleMode::Absolute, prior: None },
        rel_error: 0.0,
    };
    let p = Problem::new(m, setup).unwrap();
    // the simulator uses the hemisphere layout and points off the plane of incidence count
    assert!(p.gonio().detectors().is_hemisphere());
    assert_eq!(p.gonio().detectors().list().len(), 2 * (1 + 17 * 12));
    let off_plane = p
        .detector_indices(1)
        .iter()
        .filter(|&&k| {
            let a = p.gonio().detectors().list()[k].azimuth_deg;
            a != 0.0 && a != 180.0
        })
        .count();
    assert!(off_plane > 100, "{off_plane}");
    let r = fit(&p, &FitOptions { family: Some(Family::Ggx), shift: false, hybrid_nodes: 1 }).unwrap();
    let a = r.best().fit.model.alpha;
    assert!((a / 0.2 - 1.0).abs() < 0.03, "alpha {a}");
}
