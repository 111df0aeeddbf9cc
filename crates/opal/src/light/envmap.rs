//! Environment emitters (infinitely far away): Mitsuba's `constant` (the same radiance from
//! every direction) and `envmap` (a latitude–longitude radiance map).
//!
//! Conventions (Mitsuba 3's `envmap`): a world direction `ω` (pointing *away* from the scene,
//! towards the environment) is taken to the map's frame by the inverse of `to_world`, `v`; then
//! `u = atan2(v.x, −v.z) / 2π` (wrapped to [0, 1)), `v_t = acos(v.y) / π` (row 0 is local +y).
//! The radiance is the bilinear interpolation Mitsuba uses: texel column `i` sits at
//! `u = (i + ½)/W` and wraps around, texel row `j` at `v_t = j/(H − 1)` (the first row is the
//! pole, the last row the other pole), times `scale`.
//!
//! Sampling: the map's bilinear cells (column `i` to `i + 1`, row `j` to `j + 1`; W × (H − 1)
//! cells) form a 2-D piecewise-constant distribution — a marginal over the cell rows and one
//! conditional per row — with the weight of a cell = the mean luminance of its four corners ×
//! its solid angle `(2π/W)(cos θ_j − cos θ_{j+1})` (the sin θ factor of the lat-long map).
//! Within a cell, φ is uniform and cos θ is uniform, so the solid-angle density is constant per
//! cell: `pdf(ω) = P(cell) / Ω(cell)`. Where the radiance is non-zero, so is the pdf. `constant`
//! samples the sphere uniformly (pdf 1/4π).
//!
//! Emission (light tracing): an emitted ray leaves a disk of radius R (the scene's bounding
//! sphere, set by [`EnvLight::set_bounds`]) perpendicular to the sampled direction, centred
//! R beyond the sphere's centre, travelling inward: area density 1/(πR²), direction density the
//! direction's. Power Φ = πR² ∫ L dω (luminance, for the light choice).
//!
//! Tests (below): χ² of `sample_dir` against `pdf_dir` on a procedural map and on a constant,
//! pdf/eval consistency (E[L/pdf] = ∫L dω by quadrature), the lookup of texel centres and the
//! orientation (the brightest texel's direction), the emission densities, and the χ² of the
//! emission origins on the disk over the bounding sphere (environment and directional light:
//! `chi2_infinite_light_emission_positions`).

use crate::error::{Error, Result};
use crate::image::Image;
use crate::math::{INV_4PI, Mat3, PI, Vec2, Vec3};
use crate::sampling::{Distribution1D, square_to_uniform_disk_concentric, square_to_uniform_sphere};
use crate::spectrum::Spectrum;
use std::sync::Arc;

/// The tabulated part of an `envmap`: texels and the sampling distribution.
#[derive(Clone, Debug)]
struct LatLong {
    /// Texels, row 0 at local +y.
    image: Arc<Image>,
    /// Marginal over the H − 1 cell rows.
    marginal: Distribution1D,
    /// One conditional per cell row over its W cells (`None`: a black row, never chosen).
    rows: Vec<Option<Distribution1D>>,
    /// `cos θ_j` of the H texel rows (θ_j = jπ/(H − 1)).
    cos_rows: Vec<f32>,
    /// ∫ L dω over the sphere (of the cell weights: mean corner radiance × solid angle).
    integral: Spectrum,
}

/// An environment emitter (`constant` or `envmap`).
#[derive(Clone, Debug)]
pub struct EnvLight {
    /// Local → world rotation (orthonormal columns).
    to_world: Mat3,
    /// World → local (the transpose).
    to_local: Mat3,
    /// `constant`'s radiance; for `envmap`, the `scale` factor on all three channels.
    radiance: Spectrum,
    map: Option<LatLong>,
    center: Vec3,
    radius: f32,
}

/// The orthonormal rotation of a `to_world` matrix's linear part, or an error naming `what`
/// when it is not a rotation (uniform scales are accepted and removed).
pub fn rotation_of(m: Mat3, what: &str) -> Result<Mat3> {
    let cols = [m.x_axis, m.y_axis, m.z_axis];
    let lens = cols.map(|c| c.length());
    if lens.iter().any(|l| !(*l > 0.0 && l.is_finite())) {
        return Err(Error::invalid(what, "to_world is singular or not finite"));
    }
    let r = Mat3::from_cols(cols[0] / lens[0], cols[1] / lens[1], cols[2] / lens[2]);
    let ortho = (r.transpose() * r - Mat3::IDENTITY).to_cols_array().iter().all(|v| v.abs() < 1e-4);
    let uniform = (lens[0] - lens[1]).abs() < 1e-4 * lens[0] && (lens[0] - lens[2]).abs() < 1e-4 * lens[0];
    if !(ortho && uniform && r.determinant() > 0.0) {
        return Err(Error::invalid(
            what,
            "to_world must be a rotation (no shear, mirror or non-uniform scale)",
        ));
    }
    Ok(r)
}

impl EnvLight {
    /// Mitsuba's `constant`: radiance `radiance` from every direction.
    pub fn constant(radiance: Spectrum) -> EnvLight {
        EnvLight {
            to_world: Mat3::IDENTITY,
            to_local: Mat3::IDENTITY,
            radiance,
            map: None,
            center: Vec3::ZERO,
            radius: 1.0,
        }
    }

    /// Mitsuba's `envmap`: the lat-long map `image` (at least 1 × 2 texels, finite, non-negative)
    /// times `scale`, oriented by the rotation `to_world`.
    pub fn envmap(image: Arc<Image>, scale: f32, to_world: Mat3) -> Result<EnvLight> {
        let (w, h) = (image.width, image.height);
        if w < 1 || h < 2 {
            return Err(Error::invalid("envmap", format!("the map must have at least 2 rows, got {w}×{h}")));
        }
        if let Some(p) = image.data.iter().position(|c| !c.is_finite() || c.0.iter().any(|&v| v < 0.0)) {
            return Err(Error::invalid(
                "envmap",
                format!("texel ({}, {}) is negative or not finite: {:?}", p % w, p / w, image.data[p].0),
            ));
        }
        if !(scale.is_finite() && scale >= 0.0) {
            return Err(Error::invalid("envmap", format!("scale must be finite and ≥ 0, got {scale}")));
        }
        let to_world = rotation_of(to_world, "envmap")?;
        let cos_rows: Vec<f32> =
            (0..h).map(|j| (j as f64 * std::f64::consts::PI / (h - 1) as f64).cos() as f32).collect();
        let lum = |x: usize, y: usize| image.get(x % w, y).luminance().max(0.0) as f64;
        let mut rows = Vec::with_capacity(h - 1);
        let mut row_w = Vec::with_capacity(h - 1);
        let mut integral = [0.0f64; 3];
        for j in 0..h - 1 {
            let solid = 2.0 * std::f64::consts::PI / w as f64 * (cos_rows[j] as f64 - cos_rows[j + 1] as f64);
            let cells: Vec<f64> = (0..w)
                .map(|i| 0.25 * (lum(i, j) + lum(i + 1, j) + lum(i, j + 1) + lum(i + 1, j + 1)) * solid)
                .collect();
            for i in 0..w {
                for (c, acc) in integral.iter_mut().enumerate() {
                    let corners = [(i, j), (i + 1, j), (i, j + 1), (i + 1, j + 1)];
                    *acc += 0.25
                        * corners.iter().map(|&(x, y)| image.get(x % w, y)[c] as f64).sum::<f64>()
                        * solid;
                }
            }
            row_w.push(cells.iter().sum());
            rows.push(Distribution1D::new(&cells));
        }
        let marginal = Distribution1D::new(&row_w)
            .ok_or_else(|| Error::invalid("envmap", "the map is black (nothing to sample)"))?;
        let integral = Spectrum::rgb(integral[0] as f32, integral[1] as f32, integral[2] as f32);
        let map = LatLong { image, marginal, rows, cos_rows, integral };
        Ok(EnvLight {
            to_world,
            to_local: to_world.transpose(),
            radiance: Spectrum::splat(scale),
            map: Some(map),
            center: Vec3::ZERO,
            radius: 1.0,
        })
    }

    /// Sets the sphere that bounds the scene (emission disk, power). A zero radius (no
    /// geometry) is replaced by 1.
    pub fn set_bounds(&mut self, center: Vec3, radius: f32) {
        self.center = center;
        self.radius = if radius > 0.0 && radius.is_finite() { radius } else { 1.0 };
    }

    /// The bounding sphere (centre, radius) used for emission.
    pub fn bounds(&self) -> (Vec3, f32) {
        (self.center, self.radius)
    }

    /// Radiance arriving from the environment along direction `w` (unit, pointing away from the
    /// scene: a ray direction that escaped).
    pub fn eval(&self, w: Vec3) -> Spectrum {
        match &self.map {
            None => self.radiance,
            Some(m) => {
                let v = (self.to_local * w).normalize();
                let u = v.x.atan2(-v.z) * (0.5 / PI);
                let t = v.y.clamp(-1.0, 1.0).acos() * (1.0 / PI);
                lookup(&m.image, u, t) * self.radiance
            }
        }
    }

    /// Samples a direction towards the environment: (unit world direction, solid-angle pdf,
    /// radiance). `None` when nothing can be sampled.
    pub fn sample_dir(&self, u: Vec2) -> Option<(Vec3, f32, Spectrum)> {
        let Some(m) = &self.map else {
            let w = square_to_uniform_sphere(u);
            return Some((w, INV_4PI, self.radiance));
        };
        let w_tex = m.image.width;
        let (j, pj, u1) = m.marginal.sample(u.y);
        let (i, pi, u0) = m.rows[j].as_ref()?.sample(u.x);
        let (c0, c1) = (m.cos_rows[j], m.cos_rows[j + 1]);
        let cos_t = c0 + (c1 - c0) * u1;
        let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
        let phi = 2.0 * PI * ((i as f32 + u0 + 0.5) / w_tex as f32);
        let (sp, cp) = phi.sin_cos();
        let local = Vec3::new(sp * sin_t, cos_t, -cp * sin_t);
        let w = (self.to_world * local).normalize();
        let solid = 2.0 * PI / w_tex as f32 * (c0 - c1);
        let pdf = (pj * pi) as f32 / solid;
        if !(pdf > 0.0 && pdf.is_finite()) {
            return None;
        }
        Some((w, pdf, self.eval(w)))
    }

    /// Solid-angle density of [`EnvLight::sample_dir`] for the unit world direction `w`.
    pub fn pdf_dir(&self, w: Vec3) -> f32 {
        let Some(m) = &self.map else { return INV_4PI };
        let (wt, ht) = (m.image.width, m.image.height);
        let v = (self.to_local * w).normalize();
        let u = v.x.atan2(-v.z) * (0.5 / PI);
        let t = v.y.clamp(-1.0, 1.0).acos() * (1.0 / PI);
        let mut x = u - 0.5 / wt as f32;
        x -= x.floor();
        let i = ((x * wt as f32) as usize).min(wt - 1);
        let j = ((t * (ht - 1) as f32) as usize).min(ht - 2);
        let Some(row) = &m.rows[j] else { return 0.0 };
        let solid = 2.0 * PI / wt as f32 * (m.cos_rows[j] - m.cos_rows[j + 1]);
        (m.marginal.pmf(j) * row.pmf(i)) as f32 / solid
    }

    /// ∫ L dω over the sphere.
    pub fn integral(&self) -> Spectrum {
        match &self.map {
            None => self.radiance * (4.0 * PI),
            Some(m) => m.integral * self.radiance,
        }
    }

    /// Power through the scene's bounding disk, πR² ∫ L dω.
    pub fn power(&self) -> Spectrum {
        self.integral() * (PI * self.radius * self.radius)
    }

    /// An emitted ray for light tracing: (origin, unit direction into the scene, radiance,
    /// area density of the origin, solid-angle density of the direction).
    pub fn sample_emission(&self, u_pos: Vec2, u_dir: Vec2) -> Option<(Vec3, Vec3, Spectrum, f32, f32)> {
        let (w, pdf, l) = self.sample_dir(u_dir)?;
        let o = disk_origin(self.center, self.radius, w, u_pos);
        Some((o, -w, l, 1.0 / (PI * self.radius * self.radius), pdf))
    }
}

/// A point on the disk of radius `r` perpendicular to `w`, centred at `c + r·w` (the disk
/// that covers a sphere of radius `r` around `c` seen from direction `w`), uniform by area.
pub fn disk_origin(c: Vec3, r: f32, w: Vec3, u: Vec2) -> Vec3 {
    let f = crate::math::Frame::from_normal(w);
    let d = square_to_uniform_disk_concentric(u);
    c + (w + f.s * d.x + f.t * d.y) * r
}

/// Mitsuba's envmap lookup at lat-long coordinates (u, t ∈ [0, 1]): bilinear, periodic in u
/// with texel centres at (i + ½)/W, rows at j/(H − 1).
fn lookup(img: &Image, u: f32, t: f32) -> Spectrum {
    let (w, h) = (img.width, img.height);
    let mut x = u - 0.5 / w as f32;
    x -= x.floor();
    let x = x * w as f32;
    let y = t.clamp(0.0, 1.0) * (h - 1) as f32;
    let ix = (x as usize).min(w - 1);
    let iy = (y as usize).min(h - 2);
    let (fx, fy) = (x - ix as f32, y - iy as f32);
    let ix1 = (ix + 1) % w;
    let (v00, v10) = (img.get(ix, iy), img.get(ix1, iy));
    let (v01, v11) = (img.get(ix, iy + 1), img.get(ix1, iy + 1));
    (v00 * (1.0 - fx) + v10 * fx) * (1.0 - fy) + (v01 * (1.0 - fx) + v11 * fx) * fy
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Rng;
    use crate::validate::chi2::{Chi2Test, SphereFn};

    /// A small procedural map: a sky gradient, a bright "sun" texel block and a black band.
    pub(crate) fn test_map() -> Arc<Image> {
        let (w, h) = (24, 12);
        let mut img = Image::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let sky = 0.2 + 0.8 * (1.0 - y as f32 / (h - 1) as f32);
                let mut c = Spectrum::rgb(0.3 * sky, 0.5 * sky, sky);
                if (7..9).contains(&y) {
                    c = Spectrum::ZERO;
                }
                if (5..7).contains(&x) && (2..4).contains(&y) {
                    c = Spectrum::rgb(20.0, 18.0, 12.0);
                }
                img.set(x, y, c);
            }
        }
        Arc::new(img)
    }

    fn rotated() -> Mat3 {
        Mat3::from_rotation_x(0.4) * Mat3::from_rotation_y(1.1)
    }

    #[test]
    fn chi2_envmap_sampling() {
        let env = EnvLight::envmap(test_map(), 1.5, rotated()).unwrap();
        let mut test = Chi2Test::new("envmap", 1_000_000, 24);
        test.quad_subdiv = 8;
        let r = test
            .run(&SphereFn { sample: &|u| env.sample_dir(u).map(|s| s.0), pdf: &|w| env.pdf_dir(w) as f64 });
        eprintln!("envmap χ²: {r:?}");
        assert!(r.passed, "{r:?}");
        assert!((r.pdf_integral - 1.0).abs() < 0.01, "{r:?}");
    }

    #[test]
    fn chi2_constant_sampling() {
        let env = EnvLight::constant(Spectrum::splat(2.0));
        let r = Chi2Test::new("constant_env", 300_000, 16)
            .run(&SphereFn { sample: &|u| env.sample_dir(u).map(|s| s.0), pdf: &|w| env.pdf_dir(w) as f64 });
        eprintln!("constant χ²: {r:?}");
        assert!(r.passed, "{r:?}");
    }

    #[test]
    fn sample_pdf_and_eval_are_consistent() {
        let env = EnvLight::envmap(test_map(), 1.5, rotated()).unwrap();
        let mut rng = Rng::new(3, 0, 0);
        let n = 400_000;
        let mut acc = [0.0f64; 3];
        // a sample on a cell's border may be looked up in the neighbouring cell after the
        // round trip through (φ, θ) in f32: count those, they must be rare
        let mut other_cell = 0;
        for _ in 0..n {
            let (w, pdf, l) = env.sample_dir(rng.next_2d()).unwrap();
            if (pdf - env.pdf_dir(w)).abs() > 1e-3 * pdf {
                other_cell += 1;
            }
            let e = env.eval(w);
            assert!((e - l).max_component().abs() <= 1e-6 * (1.0 + e.max_component()));
            for c in 0..3 {
                acc[c] += (l[c] / pdf) as f64 / n as f64;
            }
        }
        assert!(other_cell < n / 2000, "{other_cell} of {n} samples have another pdf at their direction");
        // ∫ L dω by a fine quadrature in (cos θ, φ)
        let (nt, np) = (400, 800);
        let mut q = [0.0f64; 3];
        for a in 0..nt {
            for b in 0..np {
                let z = -1.0 + 2.0 * (a as f64 + 0.5) / nt as f64;
                let phi = 2.0 * std::f64::consts::PI * (b as f64 + 0.5) / np as f64;
                let r = (1.0 - z * z).sqrt();
                let w = Vec3::new((r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32);
                let l = env.eval(w);
                for c in 0..3 {
                    q[c] += l[c] as f64 * 4.0 * std::f64::consts::PI / (nt * np) as f64;
                }
            }
        }
        for c in 0..3 {
            assert!((acc[c] - q[c]).abs() < 0.01 * q[c], "channel {c}: MC {} quadrature {}", acc[c], q[c]);
            assert!(
                (env.integral()[c] as f64 - q[c]).abs() < 0.01 * q[c],
                "{c}: {:?} {}",
                env.integral(),
                q[c]
            );
        }
    }

    #[test]
    fn lookup_follows_mitsuba_conventions() {
        let img = test_map();
        let (w, h) = (img.width, img.height);
        let env = EnvLight::envmap(img.clone(), 1.0, Mat3::IDENTITY).unwrap();
        // texel (i, j) is at u = (i + ½)/W, θ = jπ/(H − 1), direction (sin φ sin θ, cos θ, −cos φ sin θ)
        for (i, j) in [(5usize, 2usize), (0, 5), (23, 10), (6, 3)] {
            let phi = 2.0 * PI * (i as f32 + 0.5) / w as f32;
            let th = j as f32 * PI / (h - 1) as f32;
            let d = Vec3::new(phi.sin() * th.sin(), th.cos(), -phi.cos() * th.sin());
            let got = env.eval(d);
            let want = img.get(i, j);
            assert!(
                (got - want).max_component().abs() < 1e-3 * (1.0 + want.max_component()),
                "{i},{j}: {got:?} {want:?}"
            );
        }
        // +y is the first row (all texels of row 0 equal: the pole)
        assert!((env.eval(Vec3::Y) - img.get(0, 0)).max_component().abs() < 1e-5);
        // a rotation moves the map with it
        let r = rotated();
        let env_r = EnvLight::envmap(img, 1.0, r).unwrap();
        let d = Vec3::new(0.3, 0.5, -0.8).normalize();
        assert!((env_r.eval(r * d) - env.eval(d)).max_component().abs() < 1e-4);
    }

    /// An emitted ray's origin `o` (direction `d`) on the disk of radius `r` centred at
    /// `c − r·d`, lifted to the upper hemisphere: its coordinates (x, y) in an orthonormal basis
    /// of the disk built here (not `disk_origin`'s frame) become `(x, y, √(1 − x² − y²))`. A
    /// uniform density on the disk, 1/(πr²), becomes the solid-angle density cos θ / π. `None`
    /// (a failed sample) when the origin is off the disk's plane.
    fn disk_to_hemisphere(o: Vec3, d: Vec3, c: Vec3, r: f32) -> Option<Vec3> {
        let w = -d;
        let helper = if w.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
        let a = w.cross(helper).normalize();
        let b = w.cross(a);
        let rel = (o - c) / r - w;
        if rel.dot(w).abs() > 1e-4 {
            return None;
        }
        let (x, y) = (rel.dot(a), rel.dot(b));
        Some(Vec3::new(x, y, (1.0 - x * x - y * y).max(0.0).sqrt()))
    }

    fn cos_over_pi(w: Vec3) -> f64 {
        if w.z > 0.0 { w.z as f64 / std::f64::consts::PI } else { 0.0 }
    }

    /// χ² of the light tracer's emission positions for infinite lights: uniform on the disk
    /// over the scene's bounding sphere (area density 1/(πR²)), for the environment map (three
    /// fixed directions, the direction itself is `chi2_envmap_sampling`'s) and the directional
    /// light. 300 000 samples, 16 × 32 cells, α = 0.01 Šidák-corrected over the four runs.
    #[test]
    fn chi2_infinite_light_emission_positions() {
        let (c, r) = (Vec3::new(1.0, -2.0, 0.5), 3.0);
        let mut env = EnvLight::envmap(test_map(), 1.5, rotated()).unwrap();
        env.set_bounds(c, r);
        let mut test = Chi2Test::new("infinite_emission_disk", 300_000, 16);
        test.num_tests = 4;
        for (k, u_dir) in
            [Vec2::new(0.3, 0.7), Vec2::new(0.81, 0.12), Vec2::new(0.5, 0.27)].into_iter().enumerate()
        {
            test.seed = 10 + k as u64;
            let res = test.run(&SphereFn {
                sample: &|u| {
                    let (o, d, _, pdf_pos, _) = env.sample_emission(u, u_dir)?;
                    assert!((pdf_pos - 1.0 / (PI * r * r)).abs() < 1e-6);
                    disk_to_hemisphere(o, d, c, r)
                },
                pdf: &cos_over_pi,
            });
            eprintln!("envmap emission positions, direction {k}: {res:?}");
            assert!(res.passed && res.failed_fraction == 0.0, "{res:?}");
        }
        let mut sun = crate::light::DirectionalLight::new(Vec3::new(-0.3, -0.8, 0.52), Spectrum::splat(2.0));
        sun.set_bounds(c, r);
        test.seed = 20;
        let res = test.run(&SphereFn {
            sample: &|u| {
                let (o, pdf_pos) = sun.sample_origin(u);
                assert!((pdf_pos - 1.0 / (PI * r * r)).abs() < 1e-6);
                disk_to_hemisphere(o, sun.direction, c, r)
            },
            pdf: &cos_over_pi,
        });
        eprintln!("directional emission positions: {res:?}");
        assert!(res.passed && res.failed_fraction == 0.0, "{res:?}");
    }

    #[test]
    fn emission_covers_the_bounding_sphere() {
        let mut env = EnvLight::constant(Spectrum::splat(1.0));
        env.set_bounds(Vec3::new(1.0, 2.0, 3.0), 2.0);
        let mut rng = Rng::new(4, 0, 0);
        for _ in 0..1000 {
            let (o, d, _, pdf_pos, _) = env.sample_emission(rng.next_2d(), rng.next_2d()).unwrap();
            // the origin is outside the sphere, on the disk tangent to it, moving inward
            let rel = o - Vec3::new(1.0, 2.0, 3.0);
            assert!((rel.dot(-d) - 2.0).abs() < 1e-4);
            assert!((rel + d * 2.0).length() <= 2.0 + 1e-4);
            assert!((pdf_pos - 1.0 / (PI * 4.0)).abs() < 1e-6);
        }
        assert!((env.power()[0] - 4.0 * PI * PI * 4.0).abs() < 1e-3);
    }
}
