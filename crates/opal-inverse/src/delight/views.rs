//! Input views: a NeRF-style `transforms.json` (camera-to-world matrices with OpenGL camera
//! axes: +x right, +y up, looking along −z; `camera_angle_x` = full horizontal field of view in
//! radians, top level or per frame; per-frame `file_path` relative to the json; optional `w`,
//! `h`) and the linear HDR images it names.
//!
//! Conversion to Mitsuba's camera (+z forward, +x image left): `to_world = M · diag(−1, 1, −1, 1)`,
//! i.e. the x and z columns are negated. Checked against the sensors of the reference Cornell box
//! (`tests/delight.rs`).
//!
//! Also here: the per-view "pure pixel" buffer — which shape a pixel shows *entirely* (its centre
//! and four inner corners hit the same shape with the same plane), so texels never take values of
//! pixels that mix two surfaces (anti-aliased edges, e.g. next to a bright emitter). On finely
//! tessellated curved surfaces (scans: facets smaller than a pixel) "the same plane" is the
//! pixel-scale plane through the corner hits (the smooth rule of [`pure_buffer`]); without it
//! almost no pixel of an 80 k-triangle scan in 256² views was pure (1.4 % of its texels seen).
//! The super-resolution uses a looser set, [`PureBuffer::covered`]: also the pixels across gentle
//! creases (its operator follows each sub-pixel ray to its own facet).
//! The buffer is held for every view for the whole run and stored compactly ([`PureBuffer`]).
//! Tests: `smooth_scan_pixels_are_pure_creases_are_not`, `gentle_crease_pixels_are_covered_not_pure`,
//! `flat_scene_covered_equals_pure`, `compact_pure_buffer_keeps_every_value` below.

// Index loops over parallel per-texel arrays read more clearly than zipped iterators here.
#![allow(clippy::needless_range_loop)]

use opal::camera::Camera;
use opal::error::{Error, Result};
use opal::image::Image;
use opal::math::{Mat4, Vec2, Vec3, Vec4};
use opal::scene::Scene;
use opal::scene::desc::SensorDesc;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// One input view.
#[derive(Clone, Debug)]
pub struct View {
    /// Name (file stem).
    pub name: String,
    /// Image file.
    pub path: PathBuf,
    /// Camera (Mitsuba conventions).
    pub camera: Camera,
    /// Linear radiance image.
    pub image: Image,
    /// Pixels that were NaN/Inf/negative in the file (masked out).
    pub bad_pixels: usize,
}

fn num(v: &serde_json::Value, what: &str, file: &Path) -> Result<f64> {
    v.as_f64().ok_or_else(|| {
        Error::invalid(format!("{}: {what}", file.display()), format!("expected a number, got {v}"))
    })
}

/// Camera-to-world (OpenGL axes) → Mitsuba `to_world`.
pub fn opengl_to_mitsuba(m: Mat4) -> Mat4 {
    m * Mat4::from_scale(Vec3::new(-1.0, 1.0, -1.0))
}

/// Reads `transforms.json` and the images. Missing images, images of the wrong size and
/// malformed entries are errors; non-finite or negative pixels are masked out (counted in
/// [`View::bad_pixels`]) and reported in the returned warnings.
pub fn read_views(path: &Path) -> Result<(Vec<View>, Vec<String>)> {
    read_views_limited(path, None, None)
}

/// One frame of a `transforms.json`: the image file, its pose and field of view, and its size
/// (from `w`/`h`, or from the image when they are not given).
#[derive(Clone, Debug)]
pub struct Frame {
    /// Image file.
    pub path: PathBuf,
    /// Sensor (Mitsuba conventions) of the full-size image.
    pub sensor: SensorDesc,
    /// Whether the size is given by `w`/`h` (then checked against the image when it is read).
    pub size_given: bool,
}

/// Reads the frames of `transforms.json` without keeping any image: a frame without `w`/`h` has
/// its image read once for its size (and dropped). Missing images and malformed entries are
/// errors.
pub fn read_frames(path: &Path) -> Result<Vec<Frame>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let j: serde_json::Value = serde_json::from_str(&text).map_err(|e| Error::Parse {
        path: path.to_path_buf(),
        line: e.line(),
        col: e.column(),
        msg: e.to_string(),
    })?;
    let dir = path.parent().unwrap_or(Path::new("."));
    let frames = j
        .get("frames")
        .and_then(|f| f.as_array())
        .ok_or_else(|| Error::invalid(path.display().to_string(), "no 'frames' array"))?;
    if frames.is_empty() {
        return Err(Error::invalid(path.display().to_string(), "'frames' is empty"));
    }
    let mut out = Vec::new();
    for (k, f) in frames.iter().enumerate() {
        let what = |field: &str| format!("frames[{k}].{field}");
        let fov = f.get("camera_angle_x").or_else(|| j.get("camera_angle_x")).ok_or_else(|| {
            Error::invalid(path.display().to_string(), format!("{}: missing", what("camera_angle_x")))
        })?;
        let fov = num(fov, &what("camera_angle_x"), path)?;
        if !(fov > 0.0 && fov < std::f64::consts::PI) {
            return Err(Error::invalid(
                format!("{}: {}", path.display(), what("camera_angle_x")),
                format!("must be in (0, π) radians, got {fov}"),
            ));
        }
        let rel = f.get("file_path").and_then(|v| v.as_str()).ok_or_else(|| {
            Error::invalid(
                path.display().to_string(),
                format!("{}: missing or not a string", what("file_path")),
            )
        })?;
        let mrows =
            f.get("transform_matrix").and_then(|v| v.as_array()).filter(|r| r.len() == 4).ok_or_else(
                || {
                    Error::invalid(
                        path.display().to_string(),
                        format!("{}: expected a 4×4 array", what("transform_matrix")),
                    )
                },
            )?;
        let mut m = [[0f32; 4]; 4];
        for (r, row) in mrows.iter().enumerate() {
            let row = row.as_array().filter(|x| x.len() == 4).ok_or_else(|| {
                Error::invalid(
                    path.display().to_string(),
                    format!("{}[{r}]: expected 4 numbers", what("transform_matrix")),
                )
            })?;
            for (c, v) in row.iter().enumerate() {
                m[r][c] = num(v, &what("transform_matrix"), path)? as f32;
            }
        }
        // rows given; glam is column-major
        let gl = Mat4::from_cols(
            Vec4::new(m[0][0], m[1][0], m[2][0], m[3][0]),
            Vec4::new(m[0][1], m[1][1], m[2][1], m[3][1]),
            Vec4::new(m[0][2], m[1][2], m[2][2], m[3][2]),
            Vec4::new(m[0][3], m[1][3], m[2][3], m[3][3]),
        );
        if !gl.is_finite() || gl.determinant().abs() < 1e-8 {
            return Err(Error::invalid(
                format!("{}: {}", path.display(), what("transform_matrix")),
                "singular or not finite",
            ));
        }
        let img_path = dir.join(rel);
        if !img_path.exists() {
            return Err(Error::invalid(
                format!("{}: {}", path.display(), what("file_path")),
                format!("image {} does not exist", img_path.display()),
            ));
        }
        let fw = f.get("w").or_else(|| j.get("w")).and_then(|v| v.as_u64());
        let fh = f.get("h").or_else(|| j.get("h")).and_then(|v| v.as_u64());
        let (width, height, size_given) = match (fw, fh) {
            (Some(w), Some(h)) => (w as usize, h as usize, true),
            _ => {
                let im = opal::image::read::read_image(&img_path)?;
                (im.width, im.height, false)
            }
        };
        let sensor = SensorDesc {
            id: img_path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| format!("view_{k}")),
            to_world: opengl_to_mitsuba(gl),
            fov_x_deg: fov.to_degrees() as f32,
            width,
            height,
            near_clip: 1e-3,
            far_clip: 1e6,
            spp: None,
        };
        out.push(Frame { path: img_path, sensor, size_given });
    }
    Ok(out)
}

/// [`read_views`] with each view downsampled to at most `max_pixels` pixels as soon as it is
/// read ([`super::downsample::downsample_view`]): only one full-size image is held at a time.
/// The bad-pixel warnings count the pixels of the file. `progress`: stage `read views`, one
/// unit per view read (and downsampled).
pub fn read_views_limited(
    path: &Path,
    max_pixels: Option<usize>,
    progress: Option<&super::Progress>,
) -> Result<(Vec<View>, Vec<String>)> {
    let frames = read_frames(path)?;
    let mut views = Vec::new();
    let mut warnings = Vec::new();
    let bar = super::progress::Stage::start(progress, "read views", frames.len() as u64);
    for fr in frames {
        let img_path = fr.path;
        let mut image = opal::image::read::read_image(&img_path)?;
        let (w, h) = (fr.sensor.width, fr.sensor.height);
        if fr.size_given && (w, h) != (image.width, image.height) {
            return Err(Error::invalid(
                img_path.display().to_string(),
                format!("image is {}×{} but {} says {w}×{h}", image.width, image.height, path.display()),
            ));
        }
        let mut bad = 0;
        for p in &mut image.data {
            if !p.is_finite() || p.0.iter().any(|&c| c < 0.0) {
                *p = opal::spectrum::Spectrum::splat(f32::NAN);
                bad += 1;
            }
        }
        if bad > 0 {
            warnings.push(format!(
                "{}: {bad} pixels are NaN, infinite or negative; they are ignored",
                img_path.display()
            ));
        }
        let desc = SensorDesc { width: image.width, height: image.height, ..fr.sensor };
        let view = View {
            name: desc.id.clone(),
            path: img_path,
            camera: Camera::new(&desc),
            image,
            bad_pixels: bad,
        };
        views.push(match max_pixels {
            Some(m) => super::downsample::downsample_view(view, m),
            None => view,
        });
        bar.step(1);
    }
    bar.finish();
    Ok((views, warnings))
}

/// No pure shape at a pixel.
pub const MIXED: u32 = u32::MAX;

/// Per-pixel shape shown entirely by the pixel (or [`MIXED`]) and the plane normal there.
///
/// Held for every view for the whole run, so stored compactly with the values unchanged (bit for
/// bit): the covering shape per pixel ([`Self::covered`], `u32`), one bit per pixel for "pure"
/// (a pure pixel is always covered by its own shape, so [`Self::shape`] is the covering shape
/// where the bit is set and [`MIXED`] elsewhere), and the (normal, least matching cosine) pairs
/// shared between the pixels that have the same ones (the pixels of one flat facet all carry
/// its geometric normal) with a `u32` index per pixel — about 8 bytes per pixel instead of 24;
/// when most pixels have their own pair (a scan filling the view) the pairs are kept per pixel.
/// Test: `compact_pure_buffer_keeps_every_value` below.
#[derive(Clone, Debug)]
pub struct PureBuffer {
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
    /// Shape index per pixel or [`MIXED`] under the looser rule of the super-resolution: the
    /// pixel shows one shape entirely (its centre and four inner-corner rays hit it) and its
    /// five facets lie pairwise within [`SMOOTH_MAX_DEG`]: every pure pixel, plus the pixels
    /// across the gentle creases of a faceted curved surface (a scan), whose hit points leave
    /// the pixel's plane. Per-texel back-projection cannot use those (a texel would take the
    /// average of two facets), but the super-resolution follows each sub-pixel ray to its own
    /// surface point, so a crease inside the pixel is part of its model. Sharp edges (a box's
    /// faces, folds beyond [`SMOOTH_MAX_DEG`]) stay excluded, as do pixels mixing shapes.
    pub covered: Vec<u32>,
    /// Bit `k % 64` of word `k / 64`: pixel `k` is pure (its shape is `covered[k]`).
    pure: Vec<u64>,
    /// The (normal, least matching cosine) of every pixel.
    planes: Planes,
}

/// The (normal, least matching cosine) pairs of a [`PureBuffer`].
#[derive(Clone, Debug)]
enum Planes {
    /// The distinct pairs and each pixel's index into them.
    Shared { index: Vec<u32>, table: Vec<(Vec3, f32)> },
    /// One pair per pixel (when more than half the pixels have their own).
    PerPixel(Vec<(Vec3, f32)>),
}

impl PureBuffer {
    /// The buffer of per-pixel values: the pure shape (or [`MIXED`]), the (normal, least
    /// matching cosine) pair and the covering shape. Panics when a pure pixel is not covered by
    /// its own shape or the lengths differ from `width · height`.
    pub fn from_pixels(
        width: usize,
        height: usize,
        shape: &[u32],
        planes: Vec<(Vec3, f32)>,
        covered: Vec<u32>,
    ) -> PureBuffer {
        let n = width * height;
        assert!(
            shape.len() == n && planes.len() == n && covered.len() == n,
            "pure buffer of {width}×{height}"
        );
        let mut pure = vec![0u64; n.div_ceil(64)];
        for (k, (&s, &c)) in shape.iter().zip(&covered).enumerate() {
            if s != MIXED {
                assert_eq!(s, c, "pixel {k}: a pure pixel is covered by its shape");
                pure[k / 64] |= 1 << (k % 64);
            }
        }
        PureBuffer { width, height, covered, pure, planes: share_planes(planes) }
    }

    /// The shape pixel `k` shows entirely, or [`MIXED`].
    #[inline]
    pub fn shape(&self, k: usize) -> u32 {
        if self.pure[k / 64] >> (k % 64) & 1 == 1 { self.covered[k] } else { MIXED }
    }

    /// [`Self::shape`] of every pixel in order.
    pub fn shapes(&self) -> impl Iterator<Item = u32> + '_ {
        (0..self.covered.len()).map(|k| self.shape(k))
    }

    /// Geometric normal at pixel `k`'s centre hit; on a smooth pixel (see [`pure_buffer`]) the
    /// normal of the plane through the pixel's corner hits.
    #[inline]
    pub fn normal(&self, k: usize) -> Vec3 {
        self.plane(k).0
    }

    /// The least cosine between [`Self::normal`] and the geometric normal of a surface point
    /// pixel `k` may be matched with: `FLAT_COS` (0.999, ~2.5°) on a flat pixel, the facets'
    /// spread plus [`SMOOTH_MARGIN_DEG`] on a smooth one.
    #[inline]
    pub fn min_cos(&self, k: usize) -> f32 {
        self.plane(k).1
    }

    #[inline]
    fn plane(&self, k: usize) -> (Vec3, f32) {
        match &self.planes {
            Planes::Shared { index, table } => table[index[k] as usize],
            Planes::PerPixel(p) => p[k],
        }
    }

    /// The same buffer with the pure shapes replaced by `shape` (an erosion: [`MIXED`] where a
    /// pixel is no longer pure) and the covering shapes set to them; the planes are kept.
    pub fn with_shapes(&self, shape: Vec<u32>) -> PureBuffer {
        assert_eq!(shape.len(), self.covered.len());
        let mut pure = vec![0u64; shape.len().div_ceil(64)];
        for (k, &s) in shape.iter().enumerate() {
            if s != MIXED {
                pure[k / 64] |= 1 << (k % 64);
            }
        }
        PureBuffer {
            width: self.width,
            height: self.height,
            covered: shape,
            pure,
            planes: self.planes.clone(),
        }
    }

    /// Bytes held on the heap (the per-view memory of the run).
    pub fn heap_bytes(&self) -> usize {
        let planes = match &self.planes {
            Planes::Shared { index, table } => 4 * index.len() + 16 * table.len(),
            Planes::PerPixel(p) => 16 * p.len(),
        };
        4 * self.covered.len() + 8 * self.pure.len() + planes
    }
}

/// The pairs shared between the pixels with identical ones (compared bit for bit), in the order
/// of their first pixel; per pixel when more than half of them are distinct.
fn share_planes(planes: Vec<(Vec3, f32)>) -> Planes {
    let key = |(n, c): &(Vec3, f32)| [n.x.to_bits(), n.y.to_bits(), n.z.to_bits(), c.to_bits()];
    let mut seen: std::collections::HashMap<[u32; 4], u32> = std::collections::HashMap::new();
    let mut table = Vec::new();
    let mut index = Vec::with_capacity(planes.len());
    for p in &planes {
        let next = table.len() as u32;
        let i = *seen.entry(key(p)).or_insert(next);
        if i == next {
            table.push(*p);
            if 2 * table.len() > planes.len() {
                return Planes::PerPixel(planes);
            }
        }
        index.push(i);
    }
    Planes::Shared { index, table }
}

/// Normals within ~2.5° (cosine 0.999): the same plane.
pub const FLAT_COS: f32 = 0.999;
/// A smooth pixel's five hit points lie within this fraction of its diagonal of their plane.
pub const SMOOTH_PLANE_TOL: f32 = 0.01;
/// A smooth pixel's facets lie within this angle (degrees) of its plane.
pub const SMOOTH_MAX_DEG: f32 = 30.0;
/// Margin (degrees) added to a smooth pixel's facet spread when a surface point is matched.
pub const SMOOTH_MARGIN_DEG: f32 = 5.0;

/// Casts 5 rays per pixel (centre and the four points at ±0.45 px) and keeps pixels whose rays
/// all hit the same shape and either (flat) have normals within ~2.5° of the centre's, or
/// (smooth: a finely tessellated curved surface such as a scan, whose facets are smaller than a
/// pixel) have all five hit points within [`SMOOTH_PLANE_TOL`] of the pixel's diagonal of the
/// plane through the corner hits (its normal from the two diagonals) and every facet within
/// [`SMOOTH_MAX_DEG`] of that plane. A crease or an occlusion boundary inside the pixel breaks
/// the plane; a flat pixel's classification is the same as before the smooth rule.
pub fn pure_buffer(scene: &Scene, cam: &Camera) -> PureBuffer {
    let (w, h) = (cam.width, cam.height);
    let rows: Vec<Vec<(u32, Vec3, f32, u32)>> =
        (0..h).into_par_iter().map(|y| (0..w).map(|x| pure_pixel(scene, cam, x, y)).collect()).collect();
    let mut shape = Vec::with_capacity(w * h);
    let mut planes = Vec::with_capacity(w * h);
    let mut covered = Vec::with_capacity(w * h);
    for (s, n, c, cv) in rows.into_iter().flatten() {
        shape.push(s);
        planes.push((n, c));
        covered.push(cv);
    }
    PureBuffer::from_pixels(w, h, &shape, planes, covered)
}

/// One pixel of [`pure_buffer`]: (shape or [`MIXED`], normal, least matching cosine, covering
/// shape of [`PureBuffer::covered`]).
fn pure_pixel(scene: &Scene, cam: &Camera, x: usize, y: usize) -> (u32, Vec3, f32, u32) {
    let c = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
    let Some(h0) = scene.intersect(&cam.generate_ray(c)) else {
        return (MIXED, Vec3::ZERO, FLAT_COS, MIXED);
    };
    let mut corners = Vec::with_capacity(4);
    for d in [Vec2::new(-0.45, -0.45), Vec2::new(0.45, -0.45), Vec2::new(-0.45, 0.45), Vec2::new(0.45, 0.45)]
    {
        match scene.intersect(&cam.generate_ray(c + d)) {
            Some(hi) if hi.shape == h0.shape => corners.push(hi),
            _ => return (MIXED, h0.ng, FLAT_COS, MIXED),
        }
    }
    if corners.iter().all(|hi| hi.ng.dot(h0.ng) > FLAT_COS) {
        return (h0.shape, h0.ng, FLAT_COS, h0.shape);
    }
    // covered (the super-resolution's rule): no fold sharper than SMOOTH_MAX_DEG between any
    // two of the five facets
    let five: Vec<Vec3> = std::iter::once(h0.ng).chain(corners.iter().map(|hi| hi.ng)).collect();
    let gentle_cos = SMOOTH_MAX_DEG.to_radians().cos();
    let gentle = (0..5).all(|i| (i + 1..5).all(|j| five[i].dot(five[j]) >= gentle_cos));
    let covered = if gentle { h0.shape } else { MIXED };
    // smooth: the plane through the corner hits (diagonals (−,−)→(+,+) and (+,−)→(−,+))
    let (d1, d2) = (corners[3].p - corners[0].p, corners[2].p - corners[1].p);
    let chord = d1.length().max(d2.length());
    let Some(mut n) = d1.cross(d2).try_normalize() else { return (MIXED, h0.ng, FLAT_COS, covered) };
    if n.dot(h0.ng) < 0.0 {
        n = -n;
    }
    let centroid = (corners.iter().map(|hi| hi.p).sum::<Vec3>() + h0.p) / 5.0;
    let flat_enough = std::iter::once(&h0)
        .chain(&corners)
        .all(|hi| (hi.p - centroid).dot(n).abs() <= SMOOTH_PLANE_TOL * chord);
    let spread = std::iter::once(&h0).chain(&corners).map(|hi| hi.ng.dot(n)).fold(1f32, f32::min);
    if !flat_enough || spread < SMOOTH_MAX_DEG.to_radians().cos() {
        return (MIXED, h0.ng, FLAT_COS, covered);
    }
    let min_cos = (spread.clamp(-1.0, 1.0).acos() + SMOOTH_MARGIN_DEG.to_radians()).cos().min(FLAT_COS);
    // a pure pixel is always covered
    (h0.shape, n, min_cos, h0.shape)
}

#[cfg(test)]
mod tests {
    use super::*;
    use opal::geometry::shapes::icosphere;
    use opal::scene::desc::{BsdfDesc, SceneDesc, ShapeDesc, TextureDesc};
    use opal::spectrum::Spectrum;

    /// A 6-level icosphere (81 920 facets, a few per pixel) and a cube beside it, 128² view: most
    /// pixels of the sphere are pure (smooth rule), the ones on the cube's edges are not.
    #[test]
    fn smooth_scan_pixels_are_pure_creases_are_not() {
        let shape = |id: &str, mesh| ShapeDesc {
            id: id.into(),
            mesh,
            bsdf: BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(Spectrum::splat(0.5)) },
            emitter: None,
            origin: None,
        };
        let mut ball = icosphere(6);
        for p in &mut ball.positions {
            *p = *p * 0.5 + Vec3::new(-0.6, 0.0, 0.0);
        }
        // a cube as an icosphere of level 0 would not do: 12 vertices of an axis-aligned cube
        let mut cube =
            opal::geometry::TriangleMesh { positions: vec![], normals: vec![], uvs: vec![], indices: vec![] };
        for z in [-1f32, 1.0] {
            for y in [-1f32, 1.0] {
                for x in [-1f32, 1.0] {
                    cube.positions.push(Vec3::new(x, y, z) * 0.3 + Vec3::new(0.6, 0.0, 0.0));
                }
            }
        }
        cube.indices = vec![
            [0, 2, 3],
            [0, 3, 1],
            [4, 5, 7],
            [4, 7, 6],
            [0, 1, 5],
            [0, 5, 4],
            [2, 6, 7],
            [2, 7, 3],
            [0, 4, 6],
            [0, 6, 2],
            [1, 3, 7],
            [1, 7, 5],
        ];
        let mut to_world = Mat4::look_at_rh(Vec3::new(0.3, 0.8, 2.5), Vec3::ZERO, Vec3::Y).inverse();
        to_world *= Mat4::from_scale(Vec3::new(-1.0, 1.0, -1.0));
        let desc = SceneDesc {
            shapes: vec![shape("ball", ball), shape("cube", cube)],
            sensors: vec![SensorDesc {
                id: "c".into(),
                to_world,
                fov_x_deg: 50.0,
                width: 128,
                height: 128,
                near_clip: 1e-3,
                far_clip: 1e3,
                spp: None,
            }],
            ..Default::default()
        };
        let scene = Scene::build(&desc).unwrap();
        let cam = &scene.cameras[0];
        let pb = pure_buffer(&scene, cam);
        let (mut ball_hit, mut ball_pure, mut cube_edge, mut cube_edge_pure) = (0, 0, 0, 0);
        for y in 0..cam.height {
            for x in 0..cam.width {
                let r = cam.generate_ray(Vec2::new(x as f32 + 0.5, y as f32 + 0.5));
                let Some(h) = scene.intersect(&r) else { continue };
                let k = y * cam.width + x;
                if h.shape == 0 {
                    ball_hit += 1;
                    ball_pure += (pb.shape(k) == 0) as usize;
                } else {
                    // within ~0.3 px of a cube edge: two coordinates near ±0.3 from the centre
                    let q = (h.p - Vec3::new(0.6, 0.0, 0.0)).abs();
                    let near = [q.x, q.y, q.z].iter().filter(|&&c| c > 0.3 - 0.004).count();
                    if near >= 2 {
                        cube_edge += 1;
                        cube_edge_pure += (pb.shape(k) != MIXED) as usize;
                    }
                }
            }
        }
        assert!(ball_pure as f64 > 0.8 * ball_hit as f64, "ball: {ball_pure} of {ball_hit} pure");
        assert!(cube_edge > 10, "{cube_edge}");
        assert_eq!(cube_edge_pure, 0, "pixels on the cube's edges must be mixed");
        // a flat pixel keeps the strict plane test, a smooth one a wider one
        assert!((0..cam.width * cam.height).all(|k| pb.min_cos(k) <= FLAT_COS));
        // the super-resolution's rule: every pure pixel is covered (`PureBuffer::from_pixels`
        // checks it), a 90° edge is not
        assert!(pb.shapes().zip(&pb.covered).all(|(s, &c)| s == MIXED || c == s));
        let cube_edge_covered = (0..cam.width * cam.height)
            .filter(|&k| {
                let r =
                    cam.generate_ray(Vec2::new((k % cam.width) as f32 + 0.5, (k / cam.width) as f32 + 0.5));
                scene.intersect(&r).is_some_and(|h| {
                    let q = (h.p - Vec3::new(0.6, 0.0, 0.0)).abs();
                    h.shape == 1 && [q.x, q.y, q.z].iter().filter(|&&c| c > 0.3 - 0.004).count() >= 2
                })
            })
            .filter(|&k| pb.covered[k] != MIXED)
            .count();
        assert_eq!(cube_edge_covered, 0, "a 90° edge is not covered");
    }

    /// A ridge of two planes folded by 20° seen from the front (64², camera rolled): the pixels across the
    /// crease are not pure (their hit points leave the pixel's plane) but covered (a fold gentler
    /// than `SMOOTH_MAX_DEG`), the pixels beside it are both.
    #[test]
    fn gentle_crease_pixels_are_covered_not_pure() {
        let a = 10f32.to_radians().tan();
        let ridge = opal::geometry::TriangleMesh {
            positions: vec![
                Vec3::new(-1.0, -1.0, -a),
                Vec3::new(0.0, -1.0, 0.0),
                Vec3::new(0.0, 1.0, 0.0),
                Vec3::new(-1.0, 1.0, -a),
                Vec3::new(1.0, -1.0, -a),
                Vec3::new(1.0, 1.0, -a),
            ],
            normals: vec![],
            uvs: vec![],
            indices: vec![[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]],
        };
        // rolled by 10° so the crease crosses the pixels at every sub-pixel offset
        let up = Vec3::new(10f32.to_radians().sin(), 10f32.to_radians().cos(), 0.0);
        let mut to_world = Mat4::look_at_rh(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, up).inverse();
        to_world *= Mat4::from_scale(Vec3::new(-1.0, 1.0, -1.0));
        let desc = SceneDesc {
            shapes: vec![ShapeDesc {
                id: "ridge".into(),
                mesh: ridge,
                bsdf: BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(Spectrum::splat(0.5)) },
                emitter: None,
                origin: None,
            }],
            sensors: vec![SensorDesc {
                id: "c".into(),
                to_world,
                fov_x_deg: 30.0,
                width: 64,
                height: 64,
                near_clip: 1e-3,
                far_clip: 1e3,
                spp: None,
            }],
            ..Default::default()
        };
        let scene = Scene::build(&desc).unwrap();
        let cam = &scene.cameras[0];
        let pb = pure_buffer(&scene, cam);
        let px = 2.0 * 3.0 * 15f32.to_radians().tan() / 64.0; // pixel width at the ridge
        let (mut crease, mut crease_pure, mut crease_covered, mut beside, mut beside_pure) = (0, 0, 0, 0, 0);
        for y in 4..60 {
            for x in 0..64 {
                let Some(h) = scene.intersect(&cam.generate_ray(Vec2::new(x as f32 + 0.5, y as f32 + 0.5)))
                else {
                    continue;
                };
                let k = y * 64 + x;
                if h.p.x.abs() < 0.15 * px {
                    crease += 1;
                    crease_pure += (pb.shape(k) != MIXED) as usize;
                    crease_covered += (pb.covered[k] == 0) as usize;
                } else if h.p.x.abs() > 1.5 * px && h.p.x.abs() < 0.9 {
                    beside += 1;
                    beside_pure += (pb.shape(k) == 0 && pb.covered[k] == 0) as usize;
                }
            }
        }
        assert!(crease > 10, "{crease}");
        assert_eq!(crease_pure, 0, "crease pixels are not pure");
        assert_eq!(crease_covered, crease, "crease pixels are covered");
        assert_eq!(beside_pure, beside, "pixels beside the crease are pure and covered");
    }

    /// Per-pixel values through the compact storage, for a buffer of few distinct planes (shared)
    /// and one of mostly distinct planes (kept per pixel): every pure shape, covering shape,
    /// normal and cosine read back bit for bit, and the shared storage takes ≤ 9 bytes per pixel.
    #[test]
    fn compact_pure_buffer_keeps_every_value() {
        let (w, h) = (37, 23);
        let n = w * h;
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 33) as u32
        };
        for distinct in [5u32, u32::MAX] {
            let (mut shape, mut planes, mut covered) = (vec![], vec![], vec![]);
            for _ in 0..n {
                let c = if next() % 7 == 0 { MIXED } else { next() % 3 };
                let s = if c != MIXED && next() % 4 != 0 { c } else { MIXED };
                let t = next() % distinct;
                let nrm = Vec3::new(t as f32 * 0.1, -0.3, (t % 11) as f32);
                let cos = if t % 2 == 0 { FLAT_COS } else { 0.9 + (t % 97) as f32 * 1e-4 };
                shape.push(s);
                planes.push((nrm, cos));
                covered.push(c);
            }
            let pb = PureBuffer::from_pixels(w, h, &shape, planes.clone(), covered.clone());
            for k in 0..n {
                assert_eq!(pb.shape(k), shape[k], "pixel {k}");
                assert_eq!(pb.covered[k], covered[k]);
                assert_eq!(
                    pb.normal(k).to_array().map(f32::to_bits),
                    planes[k].0.to_array().map(f32::to_bits)
                );
                assert_eq!(pb.min_cos(k).to_bits(), planes[k].1.to_bits());
            }
            assert!(pb.shapes().eq(shape.iter().copied()));
            if distinct == 5 {
                assert!(pb.heap_bytes() <= 9 * n, "{} bytes", pb.heap_bytes());
            } else {
                assert!(pb.heap_bytes() <= 21 * n, "{} bytes", pb.heap_bytes());
            }
            // an erosion keeps the planes and makes the covering shapes the pure ones
            let eroded: Vec<u32> =
                shape.iter().enumerate().map(|(k, &s)| if k % 5 == 0 { MIXED } else { s }).collect();
            let e = pb.with_shapes(eroded.clone());
            assert!(e.shapes().eq(eroded.iter().copied()) && e.covered == eroded);
            assert!((0..n).all(|k| e.normal(k) == pb.normal(k) && e.min_cos(k) == pb.min_cos(k)));
        }
    }

    /// The reference Cornell box (walls and boxes: flat faces meeting at 90°) at 128² from every
    /// sensor: the looser rule of the super-resolution admits no pixel the pure rule rejects, so
    /// its results on such scenes do not depend on it.
    #[test]
    fn flat_scene_covered_equals_pure() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../opal/tests/data/cbox");
        let mut desc = opal::scene::load::load_mitsuba_xml(&dir.join("scene.xml"), &[]).unwrap();
        for s in &mut desc.sensors {
            s.width = 128;
            s.height = 128;
        }
        let scene = Scene::build(&desc).unwrap();
        assert!(!scene.cameras.is_empty());
        for cam in &scene.cameras {
            let pb = pure_buffer(&scene, cam);
            assert!(pb.shapes().filter(|&s| s == MIXED).count() > 0);
            assert!(pb.shapes().eq(pb.covered.iter().copied()));
        }
    }
}
