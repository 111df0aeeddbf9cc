//! Building the runtime lights of the emitters that are not attached to shapes (`constant`,
//! `envmap`, `spot`, `directional`) from their descriptions: range checks with messages naming
//! the emitter and value.
//!
//! Tests: `crates/opal/tests/scene_load.rs` (error cases), `crates/opal/tests/mitsuba_emitters.rs`
//! (renders against Mitsuba 3).

use super::desc::EmitterDesc;
use crate::error::{Error, Result};
use crate::light::{DirectionalLight, EnvLight, Light, SpotLight, envmap::rotation_of};
use crate::math::{Mat3, Vec3};
use crate::spectrum::Spectrum;
use crate::texture::Texture;

fn check_color(what: &str, name: &str, c: Spectrum) -> Result<()> {
    if !c.is_finite() || c.0.iter().any(|&v| v < 0.0) {
        return Err(Error::invalid(what, format!("{name} must be finite and ≥ 0, got {:?}", c.0)));
    }
    Ok(())
}

/// The light of a non-area emitter other than `point`.
pub(super) fn build_emitter(e: &EmitterDesc) -> Result<Light> {
    match e {
        EmitterDesc::Point { position, intensity } => {
            Ok(Light::Point { position: *position, intensity: *intensity })
        }
        EmitterDesc::Constant { radiance } => {
            check_color("constant emitter", "radiance", *radiance)?;
            Ok(Light::Env(EnvLight::constant(*radiance)))
        }
        EmitterDesc::EnvMap { image, scale, to_world, path } => {
            let what = format!("envmap emitter ({})", path.display());
            if !to_world.is_finite() {
                return Err(Error::invalid(what, "to_world is not finite"));
            }
            EnvLight::envmap(image.clone(), *scale, Mat3::from_mat4(*to_world)).map(Light::Env).map_err(
                |err| match err {
                    Error::Invalid { why, .. } => Error::invalid(what, why),
                    other => other,
                },
            )
        }
        EmitterDesc::Spot { to_world, intensity, cutoff_deg, beam_width_deg, texture } => {
            let what = "spot emitter";
            check_color(what, "intensity", *intensity)?;
            if !(*cutoff_deg > 0.0 && *cutoff_deg < 90.0) {
                return Err(Error::invalid(
                    what,
                    format!("cutoff_angle must be in (0, 90) degrees, got {cutoff_deg}"),
                ));
            }
            if !(*beam_width_deg > 0.0 && beam_width_deg <= cutoff_deg) {
                return Err(Error::invalid(
                    what,
                    format!(
                        "beam_width must be in (0, cutoff_angle = {cutoff_deg}] degrees, got {beam_width_deg}"
                    ),
                ));
            }
            if !to_world.is_finite() {
                return Err(Error::invalid(what, "to_world is not finite"));
            }
            let r = rotation_of(Mat3::from_mat4(*to_world), what)?;
            let position = to_world.transform_point3(Vec3::ZERO);
            let tex = texture.as_ref().map(Texture::new);
            Ok(Light::Spot(SpotLight::new(position, r, *intensity, *cutoff_deg, *beam_width_deg, tex)))
        }
        EmitterDesc::Directional { direction, irradiance } => {
            let what = "directional emitter";
            check_color(what, "irradiance", *irradiance)?;
            if !(direction.is_finite() && direction.length() > 0.0) {
                return Err(Error::invalid(
                    what,
                    format!("direction must be a non-zero vector, got {direction}"),
                ));
            }
            Ok(Light::Directional(DirectionalLight::new(*direction, *irradiance)))
        }
    }
}
