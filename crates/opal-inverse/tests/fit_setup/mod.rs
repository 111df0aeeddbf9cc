//! The fit setup shared by the NDF-fit integration tests (`ndf_fit.rs`, `hemisphere_bias.rs`,
//! `hybrid_profile.rs`): the reference goniophotometer (beam, 1° detectors, single scattering,
//! the CLI's default point selection) on the reference plate (n 1.49, 2 mm) or on the dotted
//! plate of bench/scripts/gonio_dotted.py (n 1.52, 3 mm).
// each test binary uses a part of this module
#![allow(dead_code)]

use opal::gonio::{Beam, Face, Plate, Scattering};
use opal_inverse::ndf_fit::{DEFAULT_MIN_SNR, FitOn, FitSetup, ScaleSetup};

/// The reference plate (n 1.49, 2 mm) with `photons` per incidence.
pub fn setup(rough_front: bool, photons: u64) -> FitSetup {
    let placeholder = Face::Polished;
    FitSetup {
        plate: Plate {
            ior: 1.49,
            thickness_mm: 2.0,
            absorption_per_mm: 0.0,
            front: placeholder.clone(),
            back: placeholder,
            radius_mm: None,
        },
        rough_front,
        scattering: Scattering::Single,
        beam: Beam { azimuth: 0.0, divergence: 0.5f64.to_radians(), aperture_radius_mm: 1.0 },
        detector_radius: 1f64.to_radians(),
        detector_distance_mm: None,
        photons,
        seed: 7,
        max_interactions: 200,
        fit_on: FitOn::Both,
        floor_rel: 1e-2,
        max_iters: 40,
        coarse_photons: FitSetup::default_coarse(photons),
        scale: ScaleSetup::default(),
        rel_error: 0.0,
        // the CLI's default point selection (floor 1 % or ≥ 3 standard errors)
        min_snr: Some(DEFAULT_MIN_SNR),
    }
}

/// The dotted plate of the Mitsuba data (n 1.52, 3 mm), otherwise [`setup`].
pub fn dotted_setup(rough_front: bool, photons: u64) -> FitSetup {
    let mut s = setup(rough_front, photons);
    s.plate.ior = 1.52;
    s.plate.thickness_mm = 3.0;
    s
}
