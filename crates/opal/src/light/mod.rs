//! Light sources with Mitsuba semantics.
//!
//! * [`Light::Triangle`]: one triangle of an emitting mesh — a one-sided Lambertian emitter of
//!   constant radiance `Le` on its front side (the side of the geometric normal given by
//!   counter-clockwise winding). Power Φ = π · A · Le.
//! * [`Light::Point`]: isotropic point light of radiant intensity I; Φ = 4π I.
//! * [`Light::Spot`]: Mitsuba's `spot` ([`spot`]), a delta in position.
//! * [`Light::Directional`]: Mitsuba's `directional` ([`directional`]), a delta in direction,
//!   infinitely far away.
//! * [`Light::Env`]: Mitsuba's `constant` and `envmap` ([`envmap`]), infinitely far away,
//!   seen by rays that leave the scene ([`Light::le_escaped`]).
//!
//! Infinite lights (directional, environment) return samples with `dist = ∞`; their shadow
//! ray is [`LightSample::shadow_ray`]. Their power and emission use the scene's bounding
//! sphere ([`Light::set_bounds`], called by the scene builder).
//!
//! `sample_li` (next-event estimation from a reference point) samples the triangle uniformly by
//! area and converts to solid angle: pdf = d² / (|cos θ_l| A). `pdf_li` returns the same density
//! for a direction found by BSDF sampling (for MIS). `sample_le` samples an emitted ray (position
//! uniform by area, direction cosine-weighted) for light tracing. [`LightSampler`] chooses a light
//! with probability proportional to its power (luminance of Φ).
//!
//! Tests (below): χ² of the solid-angle sampling against `pdf_li`, power vs quadrature,
//! light choice proportional to power, `sample_le` densities.

pub mod directional;
pub mod envmap;
pub mod spot;

pub use directional::DirectionalLight;
pub use envmap::EnvLight;
pub use spot::SpotLight;

use crate::geometry::Ray;
use crate::math::{Frame, PI, Vec2, Vec3};
use crate::sampling::{
    Distribution1D, square_to_cosine_hemisphere, square_to_uniform_sphere, square_to_uniform_triangle,
};
use crate::spectrum::Spectrum;

/// A light source.
#[derive(Clone, Debug)]
pub enum Light {
    /// One emitting triangle.
    Triangle(TriangleLight),
    /// Isotropic point light.
    Point {
        /// Position.
        position: Vec3,
        /// Radiant intensity [W/sr].
        intensity: Spectrum,
    },
    /// Spot light.
    Spot(SpotLight),
    /// Directional light.
    Directional(DirectionalLight),
    /// Environment (`constant` or `envmap`).
    Env(EnvLight),
}

/// One triangle of an area emitter.
#[derive(Clone, Debug)]
pub struct TriangleLight {
    /// Corners (counter-clockwise seen from the emitting side).
    pub p: [Vec3; 3],
    /// Unit geometric normal (emitting side).
    pub n: Vec3,
    /// Area.
    pub area: f32,
    /// Emitted radiance.
    pub radiance: Spectrum,
    /// Index of the triangle in the scene's triangle soup.
    pub prim: u32,
    /// `Frame::from_normal(n)` (emission directions; cached: `sample_le` is per light path).
    frame: Frame,
    /// `1 / area` (the area density of `sample_le`).
    inv_area: f32,
}

impl TriangleLight {
    /// Triangle light from its corners; `None` for a zero-area triangle.
    pub fn new(p: [Vec3; 3], radiance: Spectrum, prim: u32) -> Option<Self> {
        let c = (p[1] - p[0]).cross(p[2] - p[0]);
        let len = c.length();
        if !(len > 0.0 && len.is_finite()) {
            return None;
        }
        let (n, area) = (c / len, 0.5 * len);
        Some(TriangleLight { p, n, area, radiance, prim, frame: Frame::from_normal(n), inv_area: 1.0 / area })
    }
    /// `Frame::from_normal(n)` (the emission frame).
    pub fn frame(&self) -> &Frame {
        &self.frame
    }
    /// `1 / area`, the area density of [`Light::sample_le`].
    pub fn inv_area(&self) -> f32 {
        self.inv_area
    }
    fn point(&self, u: Vec2) -> Vec3 {
        let b = square_to_uniform_triangle(u);
        self.p[0] * (1.0 - b.x - b.y) + self.p[1] * b.x + self.p[2] * b.y
    }
}

/// Result of [`Light::sample_li`].
#[derive(Clone, Copy, Debug)]
pub struct LightSample {
    /// Unit direction from the reference point towards the light.
    pub wi: Vec3,
    /// Distance to the sampled point on the light (∞ for directional and environment lights).
    pub dist: f32,
    /// Sampled point on the light.
    pub p: Vec3,
    /// Normal of the light at `p` (zero for point lights).
    pub n: Vec3,
    /// Incident radiance (for point lights: intensity / d², the delta already integrated).
    pub li: Spectrum,
    /// Solid-angle density of `wi` (for point lights: 1, a delta).
    pub pdf: f32,
    /// True for delta lights (no MIS possible).
    pub is_delta: bool,
}

impl LightSample {
    /// The shadow ray from the surface point `p` (geometric normal `ng`) to the sampled point:
    /// up to the point (both ends offset), or unbounded for infinitely distant lights.
    #[inline]
    pub fn shadow_ray(&self, p: Vec3, ng: Vec3) -> Ray {
        if self.dist.is_infinite() {
            crate::accel::spawn_ray(p, ng, self.wi)
        } else {
            crate::accel::spawn_ray_to(p, ng, self.p, self.n)
        }
    }
}

/// Result of [`Light::sample_le`].
#[derive(Clone, Copy, Debug)]
pub struct EmissionSample {
    /// Emitted ray (origin on the light, unit direction).
    pub ray: Ray,
    /// Normal at the origin (zero for point, spot, directional and environment lights: no
    /// cosine at the origin, no offset).
    pub n: Vec3,
    /// Emitted radiance along the ray (point and spot lights: intensity; directional:
    /// irradiance; environment: radiance).
    pub le: Spectrum,
    /// Area density of the origin (point and spot lights: 1; directional and environment:
    /// 1/(πR²) on the disk over the scene's bounding sphere).
    pub pdf_pos: f32,
    /// Solid-angle density of the direction (directional lights: 1, a delta).
    pub pdf_dir: f32,
}

impl Light {
    /// Emitted power Φ.
    pub fn power(&self) -> Spectrum {
        match self {
            Light::Triangle(t) => t.radiance * (PI * t.area),
            Light::Point { intensity, .. } => *intensity * (4.0 * PI),
            Light::Spot(s) => s.power(),
            Light::Directional(d) => d.power(),
            Light::Env(e) => e.power(),
        }
    }

    /// True for lights that are a delta in position or direction (point, spot, directional):
    /// [`Light::sample_li`] returns the same incident light for every sample.
    pub fn is_delta(&self) -> bool {
        matches!(self, Light::Point { .. } | Light::Spot(_) | Light::Directional(_))
    }

    /// True for lights infinitely far away (directional, environment).
    pub fn is_infinite(&self) -> bool {
        matches!(self, Light::Directional(_) | Light::Env(_))
    }

    /// Sets the scene's bounding sphere (used by infinite lights; others ignore it).
    pub fn set_bounds(&mut self, center: Vec3, radius: f32) {
        match self {
            Light::Directional(d) => d.set_bounds(center, radius),
            Light::Env(e) => e.set_bounds(center, radius),
            _ => {}
        }
    }

    /// Radiance arriving along a ray of direction `d` that left the scene (environment lights;
    /// zero for the others).
    #[inline]
    pub fn le_escaped(&self, d: Vec3) -> Spectrum {
        match self {
            Light::Env(e) => e.eval(d),
            _ => Spectrum::ZERO,
        }
    }

    /// Solid-angle density with which [`Light::sample_li`] produces the direction `d` towards an
    /// environment light (zero for the others: delta or finite lights).
    #[inline]
    pub fn pdf_escaped(&self, d: Vec3) -> f32 {
        match self {
            Light::Env(e) => e.pdf_dir(d),
            _ => 0.0,
        }
    }

    /// Samples a direction towards the light from the reference point `p`.
    pub fn sample_li(&self, p: Vec3, u: Vec2) -> Option<LightSample> {
        match self {
            Light::Triangle(t) => {
                let q = t.point(u);
                let d = q - p;
                let dist2 = d.length_squared();
                if dist2 <= 0.0 {
                    return None;
                }
                let dist = dist2.sqrt();
                let wi = d / dist;
                let cos_l = -wi.dot(t.n);
                if cos_l <= 0.0 {
                    return None; // back side: one-sided emitter
                }
                let pdf = dist2 / (cos_l * t.area);
                Some(LightSample { wi, dist, p: q, n: t.n, li: t.radiance, pdf, is_delta: false })
            }
            Light::Point { position, intensity } => {
                let d = *position - p;
                let dist2 = d.length_squared();
                if dist2 <= 0.0 {
                    return None;
                }
                let dist = dist2.sqrt();
                Some(LightSample {
                    wi: d / dist,
                    dist,
                    p: *position,
                    n: Vec3::ZERO,
                    li: *intensity / dist2,
                    pdf: 1.0,
                    is_delta: true,
                })
            }
            Light::Spot(s) => {
                let d = s.position - p;
                let dist2 = d.length_squared();
                if dist2 <= 0.0 {
                    return None;
                }
                let dist = dist2.sqrt();
                let wi = d / dist;
                let li = s.intensity(-wi) / dist2;
                Some(LightSample { wi, dist, p: s.position, n: Vec3::ZERO, li, pdf: 1.0, is_delta: true })
            }
            Light::Directional(d) => Some(LightSample {
                wi: -d.direction,
                dist: f32::INFINITY,
                p,
                n: Vec3::ZERO,
                li: d.irradiance,
                pdf: 1.0,
                is_delta: true,
            }),
            Light::Env(e) => {
                let (wi, pdf, li) = e.sample_dir(u)?;
                Some(LightSample { wi, dist: f32::INFINITY, p, n: Vec3::ZERO, li, pdf, is_delta: false })
            }
        }
    }

    /// Solid-angle density with which [`Light::sample_li`] from `p` produces the point `q` (with
    /// normal `n`) on this light. Zero for delta lights and for the back side.
    pub fn pdf_li(&self, p: Vec3, q: Vec3) -> f32 {
        match self {
            Light::Triangle(t) => {
                let d = q - p;
                let dist2 = d.length_squared();
                let cos_l = -d.dot(t.n) / dist2.sqrt();
                if cos_l <= 0.0 { 0.0 } else { dist2 / (cos_l * t.area) }
            }
            Light::Point { .. } | Light::Spot(_) | Light::Directional(_) | Light::Env(_) => 0.0,
        }
    }

    /// Radiance emitted from a point of this light towards direction `w` (away from the light).
    pub fn le(&self, w: Vec3) -> Spectrum {
        match self {
            Light::Triangle(t) => {
                if w.dot(t.n) > 0.0 {
                    t.radiance
                } else {
                    Spectrum::ZERO
                }
            }
            _ => Spectrum::ZERO,
        }
    }

    /// Samples an emitted ray (for light tracing).
    pub fn sample_le(&self, u_pos: Vec2, u_dir: Vec2) -> Option<EmissionSample> {
        match self {
            Light::Triangle(t) => {
                let o = t.point(u_pos);
                let local = square_to_cosine_hemisphere(u_dir);
                if local.z <= 0.0 {
                    return None;
                }
                let d = t.frame.to_world(local);
                Some(EmissionSample {
                    ray: Ray::new(o, d),
                    n: t.n,
                    le: t.radiance,
                    pdf_pos: t.inv_area,
                    pdf_dir: local.z / PI,
                })
            }
            Light::Point { position, intensity } => {
                let d = square_to_uniform_sphere(u_dir);
                Some(EmissionSample {
                    ray: Ray::new(*position, d),
                    n: Vec3::ZERO,
                    le: *intensity,
                    pdf_pos: 1.0,
                    pdf_dir: 1.0 / (4.0 * PI),
                })
            }
            Light::Spot(s) => {
                let (d, le, pdf_dir) = s.sample_dir(u_dir);
                Some(EmissionSample {
                    ray: Ray::new(s.position, d),
                    n: Vec3::ZERO,
                    le,
                    pdf_pos: 1.0,
                    pdf_dir,
                })
            }
            Light::Directional(d) => {
                let (o, pdf_pos) = d.sample_origin(u_pos);
                Some(EmissionSample {
                    ray: Ray::new(o, d.direction),
                    n: Vec3::ZERO,
                    le: d.irradiance,
                    pdf_pos,
                    pdf_dir: 1.0,
                })
            }
            Light::Env(e) => {
                let (o, d, le, pdf_pos, pdf_dir) = e.sample_emission(u_pos, u_dir)?;
                Some(EmissionSample { ray: Ray::new(o, d), n: Vec3::ZERO, le, pdf_pos, pdf_dir })
            }
        }
    }
}

/// Chooses lights with probability proportional to their power (luminance).
#[derive(Clone, Debug)]
pub struct LightSampler {
    dist: Distribution1D,
}

impl LightSampler {
    /// Sampler over `lights`; `None` when there is no light with positive power.
    pub fn new(lights: &[Light]) -> Option<Self> {
        let w: Vec<f64> = lights.iter().map(|l| l.power().luminance().max(0.0) as f64).collect();
        Distribution1D::new(&w).map(|dist| LightSampler { dist })
    }
    /// Picks a light: (index, probability) — the first two results of [`LightSampler::sample`].
    #[inline(always)]
    pub fn choose(&self, u: f32) -> (usize, f32) {
        let (i, p) = self.dist.sample_index(u);
        (i, p as f32)
    }
    /// [`LightSampler::choose`] as one inline table, for at most 16 lights (the same results;
    /// see [`crate::sampling::SmallChoice`]).
    pub fn small_choice(&self) -> Option<crate::sampling::SmallChoice> {
        self.dist.small_choice()
    }
    /// Picks a light: (index, probability, re-used uniform).
    #[inline]
    pub fn sample(&self, u: f32) -> (usize, f32, f32) {
        let (i, p, du) = self.dist.sample(u);
        (i, p as f32, du)
    }
    /// Probability of choosing light `i`.
    pub fn pmf(&self, i: usize) -> f32 {
        self.dist.pmf(i) as f32
    }
    /// Total power (luminance) of all lights.
    pub fn total_power(&self) -> f64 {
        self.dist.total()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::intersect_triangle_mt;
    use crate::sampling::Rng;
    use crate::validate::chi2::{Chi2Test, SphereFn};

    fn tri() -> TriangleLight {
        // facing -y, like the Cornell-box light
        TriangleLight::new(
            [Vec3::new(-0.3, 1.0, -0.2), Vec3::new(0.3, 1.0, -0.2), Vec3::new(0.2, 1.0, 0.3)],
            Spectrum::rgb(1.0, 2.0, 3.0),
            0,
        )
        .map(|mut t| {
            if t.n.y > 0.0 {
                t.p.swap(1, 2);
                t.n = -t.n;
            }
            t
        })
        .unwrap()
    }

    #[test]
    fn chi2_solid_angle_sampling() {
        let t = tri();
        let light = Light::Triangle(t.clone());
        let p = Vec3::new(0.1, 0.2, 0.05);
        // The pdf jumps to zero at the triangle's edges, which cut through cells: integrate each
        // cell finely (64×64 Simpson) so the quadrature error stays far below the MC noise.
        let mut test = Chi2Test::new("tri_light", 1_000_000, 20);
        test.quad_subdiv = 64;
        let r = test.run(&SphereFn {
            sample: &|u| light.sample_li(p, u).map(|s| s.wi),
            pdf: &|w| {
                // pdf as a function of direction: find the point on the triangle along w
                let ray = Ray::new(p, w);
                match intersect_triangle_mt(&ray, &t.p, f32::INFINITY) {
                    Some((tt, _, _)) => light.pdf_li(p, ray.at(tt)) as f64,
                    None => 0.0,
                }
            },
        });
        assert!(r.passed, "{r:?}");
        assert!((r.pdf_integral - 1.0).abs() < 0.01, "{r:?}");
    }

    #[test]
    fn power_matches_quadrature_and_sample_le_is_consistent() {
        let t = tri();
        let light = Light::Triangle(t.clone());
        // Φ = ∫A ∫hemisphere Le cos θ dω dA; MC estimate with sample_le: E[Le cos / (pdf_pos pdf_dir)]
        let mut rng = Rng::new(5, 0, 0);
        let n = 100_000;
        let mut acc = 0.0f64;
        for _ in 0..n {
            let s = light.sample_le(rng.next_2d(), rng.next_2d()).unwrap();
            let cos = s.ray.d.dot(s.n);
            assert!(cos > 0.0);
            acc += (s.le[1] * cos / (s.pdf_pos * s.pdf_dir)) as f64;
        }
        let est = acc / n as f64;
        // cosine-weighted sampling makes the estimator exact up to rounding
        assert!((est - light.power()[1] as f64).abs() < 1e-3 * est, "{est}");
        assert!((light.power()[1] - 2.0 * PI * t.area).abs() < 1e-5);
        let pl = Light::Point { position: Vec3::ZERO, intensity: Spectrum::splat(2.0) };
        assert!((pl.power()[0] - 8.0 * PI).abs() < 1e-5);
        let s = pl.sample_li(Vec3::new(0.0, 0.0, 2.0), Vec2::ZERO).unwrap();
        assert!((s.li[0] - 0.5).abs() < 1e-6 && s.wi.z < 0.0);
    }

    #[test]
    fn light_choice_proportional_to_power() {
        let lights = vec![
            Light::Point { position: Vec3::ZERO, intensity: Spectrum::splat(1.0) },
            Light::Point { position: Vec3::ZERO, intensity: Spectrum::splat(3.0) },
            Light::Triangle(tri()),
        ];
        let s = LightSampler::new(&lights).unwrap();
        let total: f64 = lights.iter().map(|l| l.power().luminance() as f64).sum();
        let mut counts = [0u64; 3];
        let mut rng = Rng::new(9, 0, 0);
        let n = 300_000;
        for _ in 0..n {
            counts[s.sample(rng.next_f32()).0] += 1;
        }
        let chi2: f64 = (0..3)
            .map(|i| {
                let e = n as f64 * lights[i].power().luminance() as f64 / total;
                (counts[i] as f64 - e).powi(2) / e
            })
            .sum();
        // 2 dof, 0.999 quantile 13.8
        assert!(chi2 < 13.8, "{chi2} {counts:?}");
        assert!(LightSampler::new(&[]).is_none());
    }
}
