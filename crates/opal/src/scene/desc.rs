//! Scene description: plain data, already resolved from the input format (Mitsuba XML) —
//! meshes in world space, textures decoded, parameters substituted. `build` is the only place
//! that validates ranges and builds acceleration structures and light samplers.

use crate::geometry::TriangleMesh;
use crate::image::Image;
use crate::math::{Mat4, Vec3};
use crate::spectrum::Spectrum;
use std::sync::Arc;

/// A whole scene.
#[derive(Clone, Debug, Default)]
pub struct SceneDesc {
    /// Shapes (triangle meshes with material and optional area emitter).
    pub shapes: Vec<ShapeDesc>,
    /// Emitters that are not attached to a shape (point lights...).
    pub emitters: Vec<EmitterDesc>,
    /// Cameras.
    pub sensors: Vec<SensorDesc>,
    /// Integrator settings found in the file, if any.
    pub integrator: Option<IntegratorDesc>,
    /// Where the description came from (for messages).
    pub source: Option<std::path::PathBuf>,
    /// Non-fatal remarks from loading (dropped degenerate triangles, Mitsuba defaults that
    /// Opal replaces...), one sentence each naming the file/shape concerned.
    pub warnings: Vec<String>,
}

/// One shape.
#[derive(Clone, Debug)]
pub struct ShapeDesc {
    /// `id` attribute, or a generated name (`shape_<k>`).
    pub id: String,
    /// Geometry in world space (`to_world` already applied; normals transformed by the
    /// inverse transpose; `flip_normals` applied; `face_normals` ⇒ `normals` empty).
    pub mesh: TriangleMesh,
    /// Surface material.
    pub bsdf: BsdfDesc,
    /// Radiance when the shape is an area emitter.
    pub emitter: Option<AreaEmitterDesc>,
    /// Where in the input it was declared: (file, line).
    pub origin: Option<(std::path::PathBuf, usize)>,
}

/// Area emitter: one-sided Lambertian emission on the front side (side of the geometric
/// normal given by counter-clockwise winding), Mitsuba semantics.
#[derive(Clone, Debug)]
pub struct AreaEmitterDesc {
    /// Emitted radiance.
    pub radiance: Spectrum,
}

/// Emitters not attached to shapes.
#[derive(Clone, Debug)]
pub enum EmitterDesc {
    /// Isotropic point light with radiant intensity `intensity` [W/sr].
    Point {
        /// Position in world space.
        position: Vec3,
        /// Radiant intensity.
        intensity: Spectrum,
    },
    /// Mitsuba `constant`: the same radiance from every direction.
    Constant {
        /// Radiance.
        radiance: Spectrum,
    },
    /// Mitsuba `envmap`: a latitude–longitude radiance map (see [`crate::light::EnvLight`]).
    EnvMap {
        /// The map (linear values, row 0 at local +y).
        image: Arc<Image>,
        /// Factor on the map's values.
        scale: f32,
        /// Local → world (a rotation).
        to_world: Mat4,
        /// File it came from.
        path: std::path::PathBuf,
    },
    /// Mitsuba `spot` (see [`crate::light::SpotLight`]).
    Spot {
        /// Local → world (position = image of the origin; axis = local +z; a rotation otherwise).
        to_world: Mat4,
        /// Radiant intensity on the axis.
        intensity: Spectrum,
        /// Cut-off angle in degrees.
        cutoff_deg: f32,
        /// Angle of full intensity in degrees.
        beam_width_deg: f32,
        /// Optional texture projected over the cone.
        texture: Option<TextureDesc>,
    },
    /// Mitsuba `directional`.
    Directional {
        /// Direction the light travels (world space).
        direction: Vec3,
        /// Irradiance on a perpendicular surface.
        irradiance: Spectrum,
    },
}

/// Texture or constant.
#[derive(Clone, Debug)]
pub enum TextureDesc {
    /// Constant value.
    Constant(Spectrum),
    /// Bitmap texture.
    Bitmap(BitmapDesc),
}

/// Bitmap texture parameters (Mitsuba `bitmap`).
#[derive(Clone, Debug)]
pub struct BitmapDesc {
    /// Decoded image, linear values (sRGB-decoded unless `raw`).
    pub image: Arc<Image>,
    /// Bilinear (default) or nearest lookup.
    pub filter: FilterType,
    /// Wrap mode (default repeat).
    pub wrap: WrapMode,
    /// File it came from.
    pub path: std::path::PathBuf,
}

/// Texture filter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FilterType {
    /// Nearest texel.
    Nearest,
    /// Bilinear interpolation of texel centres.
    Bilinear,
}

/// Texture wrap mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WrapMode {
    /// Periodic.
    Repeat,
    /// Mirrored periodic.
    Mirror,
    /// Clamp to the edge texels.
    Clamp,
}

/// Material description.
#[derive(Clone, Debug)]
pub enum BsdfDesc {
    /// Mitsuba `diffuse`.
    Diffuse {
        /// Reflectance.
        reflectance: TextureDesc,
    },
    /// Mitsuba `twosided`: the same BSDF on both sides.
    TwoSided(Box<BsdfDesc>),
    /// A plugin built by `opal::bsdf::registry::build_plugin`: a method-B lobe (`phong`,
    /// `blinn`, `schlick`, `lyon`, `pow16`, `microfacet_conductor`) or method A's
    /// `roughdielectric` (single or multiple scattering).
    Lobe(crate::bsdf::Bxdfs),
    /// A coated model (`plastic`, `roughplastic`) whose diffuse reflectance is a bitmap: the
    /// model (built with the texture's mean as its constant) and the texture looked up per hit.
    Coated {
        /// The model ([`crate::bsdf::Bxdfs::Plastic`] or [`crate::bsdf::Bxdfs::RoughPlastic`]).
        model: crate::bsdf::Bxdfs,
        /// Diffuse reflectance.
        diffuse: TextureDesc,
    },
}

/// Perspective camera (Mitsuba `perspective`).
#[derive(Clone, Debug)]
pub struct SensorDesc {
    /// `id` attribute or `sensor_<k>`.
    pub id: String,
    /// Camera-to-world transform; camera looks along local +z, local +x is image *left*,
    /// local +y image up (Mitsuba).
    pub to_world: Mat4,
    /// Full horizontal field of view in degrees (any `fov_axis` is converted to x at load).
    pub fov_x_deg: f32,
    /// Film width in pixels.
    pub width: usize,
    /// Film height in pixels.
    pub height: usize,
    /// Near clip distance.
    pub near_clip: f32,
    /// Far clip distance.
    pub far_clip: f32,
    /// Samples per pixel given by the sensor's sampler, if any.
    pub spp: Option<u32>,
}

/// Integrator settings (Mitsuba `path`).
#[derive(Clone, Debug)]
pub struct IntegratorDesc {
    /// Maximum path depth, Mitsuba's meaning (1 = emitters seen directly); -1 = unbounded.
    pub max_depth: i32,
    /// Depth from which Russian roulette starts.
    pub rr_depth: i32,
    /// Hide directly visible emitters.
    pub hide_emitters: bool,
}

impl Default for IntegratorDesc {
    fn default() -> Self {
        IntegratorDesc { max_depth: -1, rr_depth: 5, hide_emitters: false }
    }
}
