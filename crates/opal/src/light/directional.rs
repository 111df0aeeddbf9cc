//! Mitsuba's `directional` light: light arriving from infinitely far away along one direction
//! with irradiance `irradiance` on a surface perpendicular to it (a delta in direction).
//!
//! Conventions: `direction` is the direction the light *travels* (Mitsuba: `direction`, or
//! `to_world` applied to local +z). Next-event estimation returns `wi = −direction`, `li = E`,
//! an infinitely long shadow ray. Emission (light tracing) starts on the disk of radius R
//! perpendicular to the direction, R before the centre of the scene's bounding sphere (set by
//! [`DirectionalLight::set_bounds`]): area density 1/(πR²), power Φ = πR² E.
//!
//! Tests: `super::tests` (emission density against the power), the χ² of the emission origins
//! on the disk (`envmap::tests::chi2_infinite_light_emission_positions`) and the path/light
//! tracer agreement in `integrator/light_tracer/tests.rs`.

use super::envmap::disk_origin;
use crate::math::{PI, Vec2, Vec3};
use crate::spectrum::Spectrum;

/// A directional light.
#[derive(Clone, Debug)]
pub struct DirectionalLight {
    /// Unit direction of travel.
    pub direction: Vec3,
    /// Irradiance on a perpendicular surface.
    pub irradiance: Spectrum,
    center: Vec3,
    radius: f32,
}

impl DirectionalLight {
    /// Light travelling along `direction` (normalised here) with irradiance `irradiance`.
    pub fn new(direction: Vec3, irradiance: Spectrum) -> DirectionalLight {
        DirectionalLight { direction: direction.normalize(), irradiance, center: Vec3::ZERO, radius: 1.0 }
    }

    /// Sets the sphere bounding the scene (a zero radius becomes 1).
    pub fn set_bounds(&mut self, center: Vec3, radius: f32) {
        self.center = center;
        self.radius = if radius > 0.0 && radius.is_finite() { radius } else { 1.0 };
    }

    /// Power through the bounding disk, πR² E.
    pub fn power(&self) -> Spectrum {
        self.irradiance * (PI * self.radius * self.radius)
    }

    /// An emitted ray's origin (uniform on the disk; density 1/(πR²)).
    pub fn sample_origin(&self, u: Vec2) -> (Vec3, f32) {
        (disk_origin(self.center, self.radius, -self.direction, u), 1.0 / (PI * self.radius * self.radius))
    }
}
