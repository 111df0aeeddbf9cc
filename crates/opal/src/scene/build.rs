//! Building a renderable [`Scene`] from a [`SceneDesc`]: the one place that validates ranges,
//! resolves materials (into runtime [`Material`]s, once: a hit only looks its shape's up),
//! flattens meshes into one triangle soup, builds the acceleration structure and the light
//! sampler.

use super::desc::{EmitterDesc, IntegratorDesc, SceneDesc, TextureDesc};
use super::material::{Bsdf, Material};
use crate::accel::{Accel, Hit};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::geometry::{Ray, TriangleMesh};
use crate::light::{Light, LightSampler, TriangleLight};
use crate::math::{Frame, Vec2, Vec3};
use crate::spectrum::Spectrum;

/// One shape of a built scene.
#[derive(Clone, Debug)]
pub struct Shape {
    /// Identifier.
    pub id: String,
    /// World-space mesh.
    pub mesh: TriangleMesh,
    /// Material (built once from the description's `BsdfDesc`).
    pub material: Material,
    /// Emitted radiance when the shape is an area light.
    pub emission: Option<Spectrum>,
    /// Index of the first triangle of this shape in the scene's soup.
    pub first_prim: u32,
}

/// Local geometry at a ray hit.
#[derive(Clone, Copy, Debug)]
pub struct SurfaceInteraction {
    /// Hit point.
    pub p: Vec3,
    /// Unit geometric normal (counter-clockwise winding side).
    pub ng: Vec3,
    /// Unit shading normal (interpolated vertex normal, or `ng`).
    pub ns: Vec3,
    /// Texture coordinates (Mitsuba convention), zero when the mesh has none.
    pub uv: Vec2,
    /// Shape index.
    pub shape: u32,
    /// Triangle index in the scene's soup.
    pub prim: u32,
    /// Ray parameter.
    pub t: f32,
}

/// A scene ready to render.
#[derive(Debug)]
pub struct Scene {
    /// Shapes.
    pub shapes: Vec<Shape>,
    /// Lights (one per emitting triangle, then the other emitters in the order of the description).
    pub lights: Vec<Light>,
    /// Cameras.
    pub cameras: Vec<Camera>,
    /// Integrator settings from the description (defaults otherwise).
    pub integrator: IntegratorDesc,
    /// Warnings collected while building (dropped triangles...).
    pub warnings: Vec<String>,
    accel: Accel,
    prim_shape: Vec<u32>,
    prim_light: Vec<u32>,
    /// Unit geometric normal of each triangle (as [`Scene::interaction`] computed it per hit:
    /// the same bits, without loading the three corners).
    prim_ng: Vec<Vec3>,
    light_sampler: Option<LightSampler>,
    bounds: (Vec3, Vec3),
    /// Indices of the environment lights (seen by rays that leave the scene).
    env_lights: Vec<usize>,
}

const NO_LIGHT: u32 = u32::MAX;

impl Scene {
    /// Builds a scene. Errors name the offending object and value.
    pub fn build(desc: &SceneDesc) -> Result<Scene> {
        let mut tris = Vec::new();
        let mut prim_shape = Vec::new();
        let mut prim_light = Vec::new();
        let mut prim_ng = Vec::new();
        let mut lights = Vec::new();
        let mut shapes = Vec::new();
        let mut lo = Vec3::splat(f32::MAX);
        let mut hi = Vec3::splat(f32::MIN);
        let mut warnings = Vec::new();
        for (si, s) in desc.shapes.iter().enumerate() {
            let m = &s.mesh;
            if m.indices.is_empty() {
                return Err(Error::invalid(format!("shape '{}'", s.id), "mesh has no triangles"));
            }
            for (k, p) in m.positions.iter().enumerate() {
                if !p.is_finite() {
                    return Err(Error::invalid(
                        format!("shape '{}'", s.id),
                        format!("vertex {k} is not finite: {p}"),
                    ));
                }
                lo = lo.min(*p);
                hi = hi.max(*p);
            }
            for (k, idx) in m.indices.iter().enumerate() {
                if idx.iter().any(|&i| i as usize >= m.positions.len()) {
                    return Err(Error::invalid(
                        format!("shape '{}'", s.id),
                        format!("triangle {k} refers to vertex {idx:?}, mesh has {}", m.positions.len()),
                    ));
                }
            }
            let material = Material::new(&s.id, &s.bsdf)?;
            let emission = s.emitter.as_ref().map(|e| e.radiance);
            if let Some(le) = emission {
                if !le.is_finite() || le.0.iter().any(|&c| c < 0.0) {
                    return Err(Error::invalid(
                        format!("emitter of shape '{}'", s.id),
                        format!("radiance {:?}", le.0),
                    ));
                }
                if m.area() <= 0.0 {
                    return Err(Error::invalid(format!("emitter of shape '{}'", s.id), "zero surface area"));
                }
            }
            let first_prim = tris.len() as u32;
            let mut degenerate = 0usize;
            for k in 0..m.triangle_count() {
                let tri = m.triangle(k);
                let prim = tris.len() as u32;
                tris.push(tri);
                prim_shape.push(si as u32);
                let c = (tri[1] - tri[0]).cross(tri[2] - tri[0]);
                degenerate += (c.length_squared() == 0.0) as usize;
                prim_ng.push(c.normalize());
                let mut light_idx = NO_LIGHT;
                if let Some(le) = emission
                    && let Some(tl) = TriangleLight::new(tri, le, prim)
                {
                    light_idx = lights.len() as u32;
                    lights.push(Light::Triangle(tl));
                }
                prim_light.push(light_idx);
            }
            if degenerate > 0 {
                // scans often carry a few: rays never hit them (the watertight test's det is 0)
                warnings.push(format!(
                    "shape '{}': {degenerate} of {} triangles have zero area (never hit, ignored)",
                    s.id,
                    m.triangle_count()
                ));
            }
            shapes.push(Shape { id: s.id.clone(), mesh: m.clone(), material, emission, first_prim });
        }
        for e in &desc.emitters {
            match e {
                EmitterDesc::Point { position, intensity } => {
                    if !position.is_finite() || !intensity.is_finite() || intensity.0.iter().any(|&c| c < 0.0)
                    {
                        return Err(Error::invalid(
                            "point emitter",
                            format!("position {position}, intensity {:?}", intensity.0),
                        ));
                    }
                    lights.push(Light::Point { position: *position, intensity: *intensity });
                }
                other => lights.push(super::emitters::build_emitter(other)?),
            }
        }
        // infinite lights cover the scene's bounding sphere (Mitsuba: the bounding box's sphere)
        let (center, radius) =
            if lo.cmple(hi).all() { ((lo + hi) * 0.5, (hi - lo).length() * 0.5) } else { (Vec3::ZERO, 0.0) };
        for l in &mut lights {
            l.set_bounds(center, radius);
        }
        let env_lights =
            lights.iter().enumerate().filter(|(_, l)| matches!(l, Light::Env(_))).map(|(i, _)| i).collect();
        let mut cameras = Vec::new();
        for s in &desc.sensors {
            if !(s.fov_x_deg > 0.0 && s.fov_x_deg < 180.0) {
                return Err(Error::invalid(
                    format!("sensor '{}'", s.id),
                    format!("fov must be in (0, 180) degrees, got {}", s.fov_x_deg),
                ));
            }
            if s.width == 0 || s.height == 0 {
                return Err(Error::invalid(
                    format!("sensor '{}'", s.id),
                    format!("film size {}x{}", s.width, s.height),
                ));
            }
            if !s.to_world.is_finite() || s.to_world.determinant() == 0.0 {
                return Err(Error::invalid(
                    format!("sensor '{}'", s.id),
                    "to_world is singular or not finite",
                ));
            }
            cameras.push(Camera::new(s));
        }
        let light_sampler = LightSampler::new(&lights);
        let accel = Accel::new(tris);
        Ok(Scene {
            shapes,
            lights,
            cameras,
            integrator: desc.integrator.clone().unwrap_or_default(),
            warnings,
            accel,
            prim_shape,
            prim_light,
            prim_ng,
            light_sampler,
            bounds: (lo, hi),
            env_lights,
        })
    }

    /// Axis-aligned bounds of all geometry.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.bounds
    }

    /// Closest hit.
    #[inline]
    pub fn intersect(&self, ray: &Ray) -> Option<SurfaceInteraction> {
        self.intersect_hit(ray).map(|h| self.interaction(ray, &h))
    }

    /// Closest hit, without the local geometry (see [`Scene::interaction`]).
    #[inline]
    pub fn intersect_hit(&self, ray: &Ray) -> Option<Hit> {
        self.accel.intersect(ray)
    }

    /// The scene's acceleration structure (triangle indices as in [`Scene::intersect_hit`]).
    pub fn accel(&self) -> &Accel {
        &self.accel
    }

    /// The same scene behind a plain [`Accel::Bvh`] whatever [`Accel::new`] chose (tests that
    /// must cover each structure).
    #[cfg(test)]
    pub(crate) fn with_plain_bvh(mut self) -> Scene {
        let tris = self
            .shapes
            .iter()
            .flat_map(|sh| (0..sh.mesh.triangle_count()).map(|i| sh.mesh.triangle(i)))
            .collect();
        self.accel = Accel::bvh(tris);
        self
    }

    /// Whether anything blocks the ray before `ray.tmax`.
    #[inline]
    pub fn occluded(&self, ray: &Ray) -> bool {
        self.accel.occluded(ray)
    }

    /// Local geometry of a hit.
    pub fn interaction(&self, ray: &Ray, h: &Hit) -> SurfaceInteraction {
        self.interaction_at(ray, h.prim, h.t, h.b1, h.b2)
    }

    /// [`Scene::interaction`] of a hit given by its parts (triangle, ray parameter, barycentrics
    /// of the second and third corner), for callers that hold hits as structures of arrays.
    #[inline]
    pub fn interaction_at(&self, ray: &Ray, prim: u32, t: f32, b1: f32, b2: f32) -> SurfaceInteraction {
        let h = Hit { t, prim, b1, b2 };
        let shape_idx = self.prim_shape[h.prim as usize];
        let shape = &self.shapes[shape_idx as usize];
        let local = (h.prim - shape.first_prim) as usize;
        let m = &shape.mesh;
        let [i0, i1, i2] = m.indices[local].map(|i| i as usize);
        let b0 = 1.0 - h.b1 - h.b2;
        let ng = self.prim_ng[h.prim as usize];
        let ns = if m.normals.is_empty() {
            ng
        } else {
            let n = m.normals[i0] * b0 + m.normals[i1] * h.b1 + m.normals[i2] * h.b2;
            let l = n.length();
            if l > 0.0 { n / l } else { ng }
        };
        let uv =
            if m.uvs.is_empty() { Vec2::ZERO } else { m.uvs[i0] * b0 + m.uvs[i1] * h.b1 + m.uvs[i2] * h.b2 };
        SurfaceInteraction { p: ray.at(h.t), ng, ns, uv, shape: shape_idx, prim: h.prim, t: h.t }
    }

    /// Unit geometric normal of triangle `prim` (the one [`Scene::interaction_at`] returns).
    #[inline]
    pub(crate) fn prim_ng(&self, prim: u32) -> Vec3 {
        self.prim_ng[prim as usize]
    }

    /// Light attached to the hit triangle, if it emits.
    #[inline]
    pub fn light_at(&self, prim: u32) -> Option<(usize, &Light)> {
        let l = self.prim_light[prim as usize];
        (l != NO_LIGHT).then(|| (l as usize, &self.lights[l as usize]))
    }

    /// Indices (into [`Scene::lights`]) of the environment lights, which rays leaving the
    /// scene see.
    #[inline]
    pub fn env_lights(&self) -> &[usize] {
        &self.env_lights
    }

    /// The power-proportional light sampler (`None` when the scene has no light).
    pub fn light_sampler(&self) -> Option<&LightSampler> {
        self.light_sampler.as_ref()
    }

    /// Shading frame and scattering model at a hit, for the outgoing world direction `wo`
    /// (a view into the shape's material: nothing is cloned).
    #[inline]
    pub fn bsdf(&self, si: &SurfaceInteraction, wo: Vec3) -> (Frame, Bsdf<'_>) {
        let m = &self.shapes[si.shape as usize].material;
        let flip = m.two_sided() && wo.dot(si.ng) < 0.0;
        let n = if flip { -si.ns } else { si.ns };
        let frame = if m.anisotropic() { self.uv_frame(si, n) } else { Frame::from_normal(n) };
        (frame, m.bsdf(si.uv))
    }

    /// Shading frame with its tangent along ∂p/∂u of the hit triangle (projected onto the
    /// plane of `n`), as Mitsuba orients anisotropic BSDFs; [`Frame::from_normal`] when the mesh
    /// has no uvs or they are degenerate.
    fn uv_frame(&self, si: &SurfaceInteraction, n: Vec3) -> Frame {
        let shape = &self.shapes[si.shape as usize];
        let m = &shape.mesh;
        if m.uvs.is_empty() {
            return Frame::from_normal(n);
        }
        let [i0, i1, i2] = m.indices[(si.prim - shape.first_prim) as usize].map(|i| i as usize);
        let (duv0, duv1) = (m.uvs[i1] - m.uvs[i0], m.uvs[i2] - m.uvs[i0]);
        let (dp0, dp1) = (m.positions[i1] - m.positions[i0], m.positions[i2] - m.positions[i0]);
        let det = duv0.x * duv1.y - duv0.y * duv1.x;
        if det == 0.0 || !det.is_finite() {
            return Frame::from_normal(n);
        }
        let dpdu = (dp0 * duv1.y - dp1 * duv0.y) / det;
        Frame::from_normal_tangent(n, dpdu)
    }

    /// Albedo (diffuse reflectance) of a shape at `uv`, when its BSDF is diffuse.
    pub fn diffuse_albedo(&self, shape: u32, uv: Vec2) -> Option<Spectrum> {
        self.shapes[shape as usize].material.diffuse_albedo(uv)
    }
}

/// Evaluates a texture description at `uv` (a built scene evaluates its runtime
/// [`crate::texture::Texture`]s instead: the same values).
pub fn eval_texture(t: &TextureDesc, uv: Vec2) -> Spectrum {
    match t {
        TextureDesc::Constant(c) => *c,
        TextureDesc::Bitmap(b) => b.eval(uv),
    }
}
