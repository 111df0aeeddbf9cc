//! Mitsuba's `spot` light: a point light at the origin of `to_world` shining along local +z
//! with radiant intensity `intensity` (× an optional `texture` projected over the cone), full
//! within `beam_width` of the axis, falling off linearly in angle to zero at `cutoff_angle`:
//! `I(θ) = I · (cutoff − θ)/(cutoff − beam_width)` for beam_width < θ < cutoff. Mitsuba's
//! defaults: cutoff 20°, beam width ¾ of the cutoff. The texture is looked up at
//! `uv = ½ + ½ (x, y) / (z tan cutoff)` of the local direction (x, y, z).
//!
//! Next-event estimation is a delta (li = I(θ)/d²); emission samples the cone uniformly.
//! Power (for the light choice) `Φ = 2π ∫ I(θ) sin θ dθ` in closed form, with the texture's mean
//! luminance as its factor.
//!
//! Tests (below): falloff values against Mitsuba's formula, power against quadrature, χ² of
//! the emission directions.

use crate::math::{Mat3, PI, Vec2, Vec3};
use crate::sampling::square_to_uniform_cone;
use crate::spectrum::Spectrum;
use crate::texture::Texture;

/// A spot light.
#[derive(Clone, Debug)]
pub struct SpotLight {
    /// Position.
    pub position: Vec3,
    to_world: Mat3,
    to_local: Mat3,
    intensity: Spectrum,
    texture: Option<Texture>,
    cutoff: f32,
    beam: f32,
    cos_cutoff: f32,
    cos_beam: f32,
    inv_transition: f32,
    uv_factor: f32,
}

impl SpotLight {
    /// A spot at `position` whose local frame is the rotation `to_world` (axis = local +z);
    /// angles in degrees.
    pub fn new(
        position: Vec3,
        to_world: Mat3,
        intensity: Spectrum,
        cutoff_deg: f32,
        beam_width_deg: f32,
        texture: Option<Texture>,
    ) -> SpotLight {
        let (cutoff, beam) = (cutoff_deg.to_radians(), beam_width_deg.to_radians());
        SpotLight {
            position,
            to_world,
            to_local: to_world.transpose(),
            intensity,
            texture,
            cutoff,
            beam,
            cos_cutoff: cutoff.cos(),
            cos_beam: beam.cos(),
            inv_transition: 1.0 / (cutoff - beam),
            uv_factor: cutoff.tan(),
        }
    }

    /// Radiant intensity towards the world direction `w` (unit, away from the light).
    pub fn intensity(&self, w: Vec3) -> Spectrum {
        self.falloff((self.to_local * w).normalize())
    }

    /// Mitsuba's `falloff_curve` for a unit local direction.
    fn falloff(&self, d: Vec3) -> Spectrum {
        let cos_t = d.z;
        if cos_t <= self.cos_cutoff {
            return Spectrum::ZERO;
        }
        let mut r = self.intensity;
        if let Some(t) = &self.texture {
            let uv =
                Vec2::new(0.5 + 0.5 * d.x / (d.z * self.uv_factor), 0.5 + 0.5 * d.y / (d.z * self.uv_factor));
            r *= t.eval(uv);
        }
        if cos_t >= self.cos_beam {
            r
        } else {
            r * ((self.cutoff - cos_t.clamp(-1.0, 1.0).acos()) * self.inv_transition)
        }
    }

    /// Emitted power (luminance weight for the light choice): `2π ∫ I(θ) sin θ dθ`.
    pub fn power(&self) -> Spectrum {
        let (c, b) = (self.cutoff as f64, self.beam as f64);
        let s = if b >= c {
            1.0 - c.cos()
        } else {
            // ∫_0^β sin θ dθ + ∫_β^c (c − θ)/(c − β) sin θ dθ
            (1.0 - b.cos()) + b.cos() - (c.sin() - b.sin()) / (c - b)
        };
        let tex = self.texture.as_ref().map_or(1.0, |t| match t {
            Texture::Constant(v) => v.luminance().max(0.0),
            Texture::Bitmap(bm) => {
                let m = bm.image.mean();
                Spectrum::rgb(m[0] as f32, m[1] as f32, m[2] as f32).luminance().max(0.0)
            }
        });
        self.intensity * ((2.0 * std::f64::consts::PI * s) as f32 * tex)
    }

    /// An emitted direction (uniform in the cone): (unit world direction, intensity, pdf).
    pub fn sample_dir(&self, u: Vec2) -> (Vec3, Spectrum, f32) {
        let local = square_to_uniform_cone(u, self.cos_cutoff);
        let w = (self.to_world * local).normalize();
        (w, self.falloff(local), 1.0 / (2.0 * PI * (1.0 - self.cos_cutoff)))
    }

    /// Density of [`SpotLight::sample_dir`] for the world direction `w`.
    pub fn pdf_dir(&self, w: Vec3) -> f32 {
        let z = (self.to_local * w).normalize().z;
        if z >= self.cos_cutoff { 1.0 / (2.0 * PI * (1.0 - self.cos_cutoff)) } else { 0.0 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::validate::chi2::{Chi2Test, SphereFn};

    fn spot() -> SpotLight {
        let r = Mat3::from_rotation_x(0.7) * Mat3::from_rotation_z(0.3);
        SpotLight::new(Vec3::new(0.0, 1.0, 0.0), r, Spectrum::rgb(1.0, 2.0, 3.0), 30.0, 20.0, None)
    }

    #[test]
    fn falloff_is_mitsubas() {
        let s = spot();
        let z = s.to_world * Vec3::Z;
        assert_eq!(s.intensity(z), Spectrum::rgb(1.0, 2.0, 3.0));
        // at 25°: halfway between beam (20°) and cutoff (30°)
        let d = Vec3::new(25f32.to_radians().sin(), 0.0, 25f32.to_radians().cos());
        let i = s.intensity(s.to_world * d);
        assert!((i[0] - 0.5).abs() < 1e-3, "{i:?}");
        let d = Vec3::new(31f32.to_radians().sin(), 0.0, 31f32.to_radians().cos());
        assert!(s.intensity(s.to_world * d).is_black());
    }

    #[test]
    fn power_matches_quadrature() {
        let s = spot();
        let n = 20000;
        let mut q = 0.0f64;
        for k in 0..n {
            let th = (k as f64 + 0.5) / n as f64 * 0.6;
            let d = Vec3::new(th.sin() as f32, 0.0, th.cos() as f32);
            q += s.falloff(d)[0] as f64 * th.sin() * 2.0 * std::f64::consts::PI * 0.6 / n as f64;
        }
        assert!((q - s.power()[0] as f64).abs() < 1e-3 * q, "{q} {:?}", s.power());
    }

    #[test]
    fn chi2_emission_directions() {
        let s = spot();
        let r = Chi2Test::new("spot_cone", 300_000, 20)
            .run(&SphereFn { sample: &|u| Some(s.sample_dir(u).0), pdf: &|w| s.pdf_dir(w) as f64 });
        eprintln!("spot χ²: {r:?}");
        assert!(r.passed, "{r:?}");
    }
}
