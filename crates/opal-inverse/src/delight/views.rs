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
//! pixels that mix two surfaces (anti-aliased edges, e.g. next to a bright emitter).

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
    let mut views = Vec::new();
    let mut warnings = Vec::new();
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
        let mut image = opal::image::read::read_image(&img_path)?;
        let fw = f.get("w").or_else(|| j.get("w")).and_then(|v| v.as_u64());
        let fh = f.get("h").or_else(|| j.get("h")).and_then(|v| v.as_u64());
        if let (Some(w), Some(h)) = (fw, fh) {
            if (w as usize, h as usize) != (image.width, image.height) {
                return Err(Error::invalid(
                    img_path.display().to_string(),
                    format!("image is {}×{} but {} says {w}×{h}", image.width, image.height, path.display()),
                ));
            }
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
        let desc = SensorDesc {
            id: img_path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| format!("view_{k}")),
            to_world: opengl_to_mitsuba(gl),
            fov_x_deg: fov.to_degrees() as f32,
            width: image.width,
            height: image.height,
            near_clip: 1e-3,
            far_clip: 1e6,
            spp: None,
        };
        views.push(View {
            name: desc.id.clone(),
            path: img_path,
            camera: Camera::new(&desc),
            image,
            bad_pixels: bad,
        });
    }
    Ok((views, warnings))
}

/// No pure shape at a pixel.
pub const MIXED: u32 = u32::MAX;

/// Per-pixel shape shown entirely by the pixel (or [`MIXED`]) and the plane normal there.
#[derive(Clone, Debug)]
pub struct PureBuffer {
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
    /// Shape index per pixel or [`MIXED`].
    pub shape: Vec<u32>,
    /// Geometric normal at the pixel centre's hit.
    pub normal: Vec<Vec3>,
}

/// Casts 5 rays per pixel (centre and the four points at ±0.45 px) and keeps pixels whose rays
/// all hit the same shape with normals within ~2.5°.
pub fn pure_buffer(scene: &Scene, cam: &Camera) -> PureBuffer {
    let (w, h) = (cam.width, cam.height);
    let rows: Vec<(Vec<u32>, Vec<Vec3>)> = (0..h)
        .into_par_iter()
        .map(|y| {
            let mut s = Vec::with_capacity(w);
            let mut n = Vec::with_capacity(w);
            for x in 0..w {
                let c = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
                let Some(h0) = scene.intersect(&cam.generate_ray(c)) else {
                    s.push(MIXED);
                    n.push(Vec3::ZERO);
                    continue;
                };
                let mut pure = true;
                for d in [
                    Vec2::new(-0.45, -0.45),
                    Vec2::new(0.45, -0.45),
                    Vec2::new(-0.45, 0.45),
                    Vec2::new(0.45, 0.45),
                ] {
                    match scene.intersect(&cam.generate_ray(c + d)) {
                        Some(hi) if hi.shape == h0.shape && hi.ng.dot(h0.ng) > 0.999 => {}
                        _ => {
                            pure = false;
                            break;
                        }
                    }
                }
                s.push(if pure { h0.shape } else { MIXED });
                n.push(h0.ng);
            }
            (s, n)
        })
        .collect();
    let mut shape = Vec::with_capacity(w * h);
    let mut normal = Vec::with_capacity(w * h);
    for (s, n) in rows {
        shape.extend(s);
        normal.extend(n);
    }
    PureBuffer { width: w, height: h, shape, normal }
}
