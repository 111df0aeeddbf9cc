//! COLMAP text models as input views ([`read_colmap`]): `cameras.txt` (models `SIMPLE_PINHOLE`,
//! `PINHOLE`, `SIMPLE_RADIAL`, `RADIAL`, `OPENCV`) and `images.txt` (world-to-camera quaternion
//! `QW QX QY QZ` and translation `T`, camera id, image name; the second line of each image, its
//! 2D points, is skipped).
//!
//! Conventions: COLMAP's camera looks along +z with +x right and +y down; pixel centres at
//! half-integers (the top-left pixel's centre is (0.5, 0.5)); `x_cam = R x_world + t`, camera
//! centre `C = −Rᵀ t`. Opal's camera ([`opal::camera`]) is an ideal pinhole with square pixels
//! and a centred principal point, so each photo is **resampled** once on reading (bilinear) onto
//! that camera with the same size and the focal length `fx`: per target pixel the ideal
//! normalised coordinates `(x, y) = ((u − W/2)/fx, (v − H/2)/fx)` are distorted with the
//! model's coefficients (OpenCV: radial `k1, k2`, tangential `p1, p2`) and looked up at
//! `(fx·x_d + cx, fy·y_d + cy)`. Pixels that fall outside the photo are masked (NaN, counted in
//! [`View::bad_pixels`]). The Mitsuba `to_world` is `[Rᵀ·diag(−1, −1, 1) | C]`.
//!
//! Images: `NAME` under `image_dir`; when that file is not there, the same stem with `.exr`
//! (COLMAP usually ran on JPEG/PNG versions of linear HDR photos). The model's frames and
//! cameras are read first without any photo ([`read_colmap_frames`]), so the working size of
//! the views can be chosen from the cameras; then [`colmap_views`] reads, resamples and
//! box-filters one photo at a time (the same streaming read as a `transforms.json`'s,
//! [`super::views::read_views_limited`]).
//!
//! Tests: below — a hand-written two-image model with `OPENCV` distortion and a `PINHOLE`
//! camera with an off-centre principal point: the resampled images against the analytic
//! undistorted pattern, and the cameras' projections against COLMAP's
//! (`colmap_model_reads_resamples_and_projects`); the streaming read against the full read
//! downsampled afterwards, bit for bit (`limited_read_box_filters_each_photo_as_it_is_read`).

use super::views::View;
use glam::{DMat3, DQuat};
use opal::camera::Camera;
use opal::error::{Error, Result};
use opal::image::Image;
use opal::math::{DMat4, DVec3};
use opal::scene::desc::SensorDesc;
use opal::spectrum::Spectrum;
use std::collections::HashMap;
use std::path::Path;

/// Intrinsics of one COLMAP camera.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    /// Width (px).
    pub width: usize,
    /// Height (px).
    pub height: usize,
    /// Focal lengths (px).
    pub fx: f64,
    /// See `fx`.
    pub fy: f64,
    /// Principal point (px, COLMAP's continuous coordinates).
    pub cx: f64,
    /// See `cx`.
    pub cy: f64,
    /// Radial `k1, k2` and tangential `p1, p2` coefficients (zero for pinhole models).
    pub dist: [f64; 4],
}

impl ColmapCamera {
    /// Distorted normalised coordinates of ideal ones (OpenCV's model).
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let [k1, k2, p1, p2] = self.dist;
        let r2 = x * x + y * y;
        let radial = 1.0 + k1 * r2 + k2 * r2 * r2;
        (
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        )
    }
}

fn parse_err(path: &Path, line: usize, msg: impl Into<String>) -> Error {
    Error::Parse { path: path.to_path_buf(), line, col: 1, msg: msg.into() }
}

/// Lines that are neither empty nor comments, with their 1-based numbers.
fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
}

/// Parses `cameras.txt`.
pub fn parse_cameras(text: &str, path: &Path) -> Result<HashMap<u32, ColmapCamera>> {
    let mut out = HashMap::new();
    for (n, l) in data_lines(text) {
        let f: Vec<&str> = l.split_whitespace().collect();
        if f.len() < 4 {
            return Err(parse_err(path, n, "expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]"));
        }
        let id: u32 = f[0].parse().map_err(|_| parse_err(path, n, "bad camera id"))?;
        let w: usize = f[2].parse().map_err(|_| parse_err(path, n, "bad width"))?;
        let h: usize = f[3].parse().map_err(|_| parse_err(path, n, "bad height"))?;
        let p: Vec<f64> = f[4..]
            .iter()
            .map(|x| x.parse::<f64>())
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| parse_err(path, n, "bad parameter"))?;
        let need = |k: usize| {
            if p.len() == k {
                Ok(())
            } else {
                Err(parse_err(path, n, format!("model {} takes {k} parameters, got {}", f[1], p.len())))
            }
        };
        let cam = match f[1] {
            "SIMPLE_PINHOLE" => {
                need(3)?;
                ColmapCamera { width: w, height: h, fx: p[0], fy: p[0], cx: p[1], cy: p[2], dist: [0.0; 4] }
            }
            "PINHOLE" => {
                need(4)?;
                ColmapCamera { width: w, height: h, fx: p[0], fy: p[1], cx: p[2], cy: p[3], dist: [0.0; 4] }
            }
            "SIMPLE_RADIAL" => {
                need(4)?;
                ColmapCamera {
                    width: w,
                    height: h,
                    fx: p[0],
                    fy: p[0],
                    cx: p[1],
                    cy: p[2],
                    dist: [p[3], 0.0, 0.0, 0.0],
                }
            }
            "RADIAL" => {
                need(5)?;
                ColmapCamera {
                    width: w,
                    height: h,
                    fx: p[0],
                    fy: p[0],
                    cx: p[1],
                    cy: p[2],
                    dist: [p[3], p[4], 0.0, 0.0],
                }
            }
            "OPENCV" => {
                need(8)?;
                ColmapCamera {
                    width: w,
                    height: h,
                    fx: p[0],
                    fy: p[1],
                    cx: p[2],
                    cy: p[3],
                    dist: [p[4], p[5], p[6], p[7]],
                }
            }
            other => {
                return Err(parse_err(
                    path,
                    n,
                    format!(
                        "camera model {other} is not supported (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV)"
                    ),
                ));
            }
        };
        if !(cam.fx > 0.0 && cam.fy > 0.0 && w > 0 && h > 0) {
            return Err(parse_err(path, n, "focal lengths and size must be positive"));
        }
        out.insert(id, cam);
    }
    Ok(out)
}

/// One image of `images.txt`: (name, camera id, world-to-camera rotation, translation).
pub fn parse_images(text: &str, path: &Path) -> Result<Vec<(String, u32, DMat3, DVec3)>> {
    let mut out = Vec::new();
    // image lines alternate with their 2D-point lines (which may be empty: keep empty lines)
    let lines: Vec<(usize, &str)> = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.starts_with('#'))
        .collect();
    let mut k = 0;
    while k < lines.len() {
        let (n, l) = lines[k];
        if l.is_empty() {
            k += 1;
            continue;
        }
        let f: Vec<&str> = l.split_whitespace().collect();
        if f.len() < 10 {
            return Err(parse_err(path, n, "expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME"));
        }
        let v: Vec<f64> = f[1..8]
            .iter()
            .map(|x| x.parse::<f64>())
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| parse_err(path, n, "bad pose number"))?;
        let q = DQuat::from_xyzw(v[1], v[2], v[3], v[0]);
        if q.length().is_nan() || q.length() <= 0.5 {
            return Err(parse_err(path, n, "quaternion is not a rotation"));
        }
        let cam: u32 = f[8].parse().map_err(|_| parse_err(path, n, "bad camera id"))?;
        let name = f[9..].join(" ");
        out.push((name, cam, DMat3::from_quat(q.normalize()), DVec3::new(v[4], v[5], v[6])));
        k += 2; // skip the 2D points line
    }
    Ok(out)
}

/// Resamples `src` (the photo of camera `c`) onto the ideal centred pinhole of the same size
/// with focal length `c.fx`; returns the image and the number of masked pixels.
pub fn undistort(src: &Image, c: &ColmapCamera) -> (Image, usize) {
    let (w, h) = (c.width, c.height);
    let mut out = Image::new(w, h);
    let mut bad = 0;
    for v in 0..h {
        for u in 0..w {
            let x = (u as f64 + 0.5 - w as f64 / 2.0) / c.fx;
            let y = (v as f64 + 0.5 - h as f64 / 2.0) / c.fx;
            let (xd, yd) = c.distort(x, y);
            let (us, vs) = (c.fx * xd + c.cx - 0.5, c.fy * yd + c.cy - 0.5);
            let (x0, y0) = (us.floor(), vs.floor());
            let (fx, fy) = ((us - x0) as f32, (vs - y0) as f32);
            let (x0, y0) = (x0 as i64, y0 as i64);
            let val = if x0 < 0 || y0 < 0 || x0 + 1 >= src.width as i64 || y0 + 1 >= src.height as i64 {
                // the last row/column: clamp taps of zero weight
                if us >= -0.5 && vs >= -0.5 && us <= src.width as f64 - 0.5 && vs <= src.height as f64 - 0.5 {
                    let xi = (us.round().max(0.0) as usize).min(src.width - 1);
                    let yi = (vs.round().max(0.0) as usize).min(src.height - 1);
                    src.get(xi, yi)
                } else {
                    Spectrum::splat(f32::NAN)
                }
            } else {
                let g = |dx: i64, dy: i64| src.get((x0 + dx) as usize, (y0 + dy) as usize);
                g(0, 0) * ((1.0 - fx) * (1.0 - fy))
                    + g(1, 0) * (fx * (1.0 - fy))
                    + g(0, 1) * ((1.0 - fx) * fy)
                    + g(1, 1) * (fx * fy)
            };
            if !val.is_finite() || val.0.iter().any(|&x| x < 0.0) {
                bad += 1;
                out.set(u, v, Spectrum::splat(f32::NAN));
            } else {
                out.set(u, v, val);
            }
        }
    }
    (out, bad)
}

/// The Opal camera of a COLMAP image after [`undistort`]: Mitsuba `to_world` from the
/// world-to-camera rotation `r` and translation `t`, horizontal field of view from `fx`.
pub fn opal_camera(id: &str, c: &ColmapCamera, r: DMat3, t: DVec3) -> Camera {
    let centre = -(r.transpose() * t);
    let rot = r.transpose() * DMat3::from_diagonal(DVec3::new(-1.0, -1.0, 1.0));
    let m = DMat4::from_cols(
        rot.x_axis.extend(0.0),
        rot.y_axis.extend(0.0),
        rot.z_axis.extend(0.0),
        centre.extend(1.0),
    );
    Camera::new(&SensorDesc {
        id: id.into(),
        to_world: m.as_mat4(),
        fov_x_deg: (2.0 * (c.width as f64 / (2.0 * c.fx)).atan()).to_degrees() as f32,
        width: c.width,
        height: c.height,
        near_clip: 1e-3,
        far_clip: 1e6,
        spp: None,
    })
}

/// One image of a COLMAP model before its photo is read ([`read_colmap_frames`]).
#[derive(Clone, Debug)]
pub struct ColmapFrame {
    /// View name (the photo's file stem).
    pub name: String,
    /// The photo (`NAME` under the image folder, or the same stem with `.exr`).
    pub path: std::path::PathBuf,
    /// COLMAP camera id.
    pub camera_id: u32,
    /// Intrinsics of that camera (the photo's size).
    pub intrinsics: ColmapCamera,
    /// The Opal camera of the resampled photo ([`opal_camera`]), at the photo's size.
    pub camera: Camera,
}

/// Reads a COLMAP text model (`model_dir/cameras.txt`, `model_dir/images.txt`) without reading
/// any photo: the frames sorted by image name, each with its photo under `image_dir` (which must
/// exist) and its camera. The cameras alone decide the working size of the views before a photo
/// is read (as `views::read_frames` does for a `transforms.json`).
pub fn read_colmap_frames(model_dir: &Path, image_dir: &Path) -> Result<Vec<ColmapFrame>> {
    let cp = model_dir.join("cameras.txt");
    let ip = model_dir.join("images.txt");
    let cams = parse_cameras(&std::fs::read_to_string(&cp).map_err(|e| Error::io(&cp, e))?, &cp)?;
    let mut imgs = parse_images(&std::fs::read_to_string(&ip).map_err(|e| Error::io(&ip, e))?, &ip)?;
    if imgs.is_empty() {
        return Err(Error::invalid(ip.display().to_string(), "no image"));
    }
    imgs.sort_by(|a, b| a.0.cmp(&b.0));
    let mut frames = Vec::with_capacity(imgs.len());
    for (name, cid, r, t) in imgs {
        let c = cams.get(&cid).ok_or_else(|| {
            Error::invalid(
                ip.display().to_string(),
                format!("image {name}: camera {cid} is not in cameras.txt"),
            )
        })?;
        let mut path = image_dir.join(&name);
        if !path.exists() {
            let exr = path.with_extension("exr");
            if exr.exists() {
                path = exr;
            } else {
                return Err(Error::invalid(
                    ip.display().to_string(),
                    format!("image {} does not exist (nor {})", path.display(), exr.display()),
                ));
            }
        }
        let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or(name.clone());
        frames.push(ColmapFrame {
            camera: opal_camera(&stem, c, r, t),
            name: stem,
            path,
            camera_id: cid,
            intrinsics: c.clone(),
        });
    }
    Ok(frames)
}

/// Reads a COLMAP text model (`model_dir/cameras.txt`, `model_dir/images.txt`) and its images
/// from `image_dir` as views (resampled onto ideal pinholes, see the module docs); returns the
/// views (sorted by name) and warnings (masked pixels).
pub fn read_colmap(model_dir: &Path, image_dir: &Path) -> Result<(Vec<View>, Vec<String>)> {
    colmap_views(read_colmap_frames(model_dir, image_dir)?, None, None)
}

/// The views of `frames` ([`read_colmap_frames`]): each photo is read, resampled onto its ideal
/// pinhole ([`undistort`]) and, with `max_pixels`, box-filtered to at most that many pixels
/// ([`super::downsample::downsample_view`]) before the next photo is read, so only one photo at
/// full size is held at a time. The warnings count the masked pixels at full size. `progress`:
/// stage `read views`, one unit per photo read (and resampled).
pub fn colmap_views(
    frames: Vec<ColmapFrame>,
    max_pixels: Option<usize>,
    progress: Option<&super::Progress>,
) -> Result<(Vec<View>, Vec<String>)> {
    let mut views = Vec::with_capacity(frames.len());
    let mut warnings = Vec::new();
    let bar = super::progress::Stage::start(progress, "read views", frames.len() as u64);
    for f in frames {
        let c = &f.intrinsics;
        let src = opal::image::read::read_image(&f.path)?;
        if (src.width, src.height) != (c.width, c.height) {
            return Err(Error::invalid(
                f.path.display().to_string(),
                format!(
                    "image is {}×{} but camera {} is {}×{}",
                    src.width, src.height, f.camera_id, c.width, c.height
                ),
            ));
        }
        let (image, bad) = undistort(&src, c);
        drop(src);
        if bad > 0 {
            warnings.push(format!(
                "{}: {bad} pixels are outside the photo after undistortion or not finite; they are ignored",
                f.path.display()
            ));
        }
        let view = View { name: f.name, camera: f.camera, path: f.path, image, bad_pixels: bad };
        views.push(match max_pixels {
            Some(m) => super::downsample::downsample_view(view, m),
            None => view,
        });
        bar.step(1);
    }
    bar.finish();
    Ok((views, warnings))
}

#[cfg(test)]
mod tests {
    use super::*;
    use opal::math::Vec2;

    /// Smooth pattern of ideal normalised coordinates.
    fn pattern(x: f64, y: f64) -> f32 {
        (0.5 + 0.3 * (6.0 * x).sin() * (5.0 * y + 0.3).cos()) as f32
    }

    /// Inverse of [`ColmapCamera::distort`] by fixed-point iteration.
    fn undistort_point(c: &ColmapCamera, xd: f64, yd: f64) -> (f64, f64) {
        let (mut x, mut y) = (xd, yd);
        for _ in 0..50 {
            let (a, b) = c.distort(x, y);
            x += xd - a;
            y += yd - b;
        }
        (x, y)
    }

    const CAMERAS: &str = "# Camera list\n# CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n\
        1 OPENCV 96 64 80.0 82.0 49.5 31.0 -0.12 0.03 0.002 -0.001\n\
        2 PINHOLE 96 64 90.0 90.0 46.0 33.5\n";
    // image 1: identity rotation at C = (0, 0, -4); image 2: rotated 30° about y
    const IMAGES: &str = "# Image list\n\
        1 1 0 0 0 0 0 4 1 a.exr\n\
        10.0 20.0 -1\n\
        2 0.9659258262890683 0 0.25881904510252074 0 0.5 0.2 4.1 2 b.exr\n\
        \n";

    /// Writes the two-image model and its photos (the pattern seen through each camera's
    /// distortion) into a fresh folder `opal_colmap_<tag>_<pid>`; returns it and the cameras.
    fn write_model(tag: &str) -> (std::path::PathBuf, HashMap<u32, ColmapCamera>) {
        let dir = std::env::temp_dir().join(format!("opal_colmap_{tag}_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("cameras.txt"), CAMERAS).unwrap();
        std::fs::write(dir.join("images.txt"), IMAGES).unwrap();
        let cams = parse_cameras(CAMERAS, Path::new("cameras.txt")).unwrap();
        for (name, cid) in [("a.exr", 1u32), ("b.exr", 2)] {
            let c = &cams[&cid];
            let mut img = Image::new(c.width, c.height);
            for v in 0..c.height {
                for u in 0..c.width {
                    let xd = (u as f64 + 0.5 - c.cx) / c.fx;
                    let yd = (v as f64 + 0.5 - c.cy) / c.fy;
                    let (x, y) = undistort_point(c, xd, yd);
                    img.set(u, v, Spectrum::splat(pattern(x, y)));
                }
            }
            let f = std::fs::File::create(dir.join(name)).unwrap();
            opal::image::write::write_exr(&img, std::io::BufWriter::new(f)).unwrap();
        }
        (dir, cams)
    }

    #[test]
    fn colmap_model_reads_resamples_and_projects() {
        let (dir, cams) = write_model("full");
        let (views, warnings) = read_colmap(&dir, &dir).unwrap();
        assert_eq!(views.len(), 2);
        let imgs = parse_images(IMAGES, Path::new("images.txt")).unwrap();
        for (k, v) in views.iter().enumerate() {
            let c = &cams[&imgs[k].1];
            let (r, t) = (imgs[k].2, imgs[k].3);
            // resampled image: the pattern at the ideal coordinates (interior pixels)
            let (mut worst, mut n) = (0f32, 0);
            for y in 0..c.height {
                for x in 0..c.width {
                    let got = v.image.get(x, y)[0];
                    if !got.is_finite() {
                        continue;
                    }
                    let (xn, yn) = ((x as f64 + 0.5 - 48.0) / c.fx, (y as f64 + 0.5 - 32.0) / c.fx);
                    worst = worst.max((got - pattern(xn, yn)).abs());
                    n += 1;
                }
            }
            assert!(n > c.width * c.height / 2, "{}: only {n} pixels", v.name);
            assert!(worst < 0.01, "{}: resampled image off by {worst}", v.name);
            // the camera: a world point COLMAP sees at ideal (x, y) projects to (W/2 + fx x, H/2 + fx y)
            for (xn, yn, depth) in [(0.1, -0.2, 3.0), (-0.3, 0.15, 5.0)] {
                let xc = DVec3::new(xn, yn, 1.0) * depth;
                let xw = r.transpose() * (xc - t);
                let p = v.camera.project(xw.as_vec3()).unwrap();
                let want = Vec2::new((48.0 + c.fx * xn) as f32, (32.0 + c.fx * yn) as f32);
                assert!((p - want).length() < 1e-3, "{}: {p:?} vs {want:?}", v.name);
            }
        }
        // OPENCV's corners pull in: some pixels fall outside the photo and are masked
        assert!(warnings.len() <= 2);
        std::fs::remove_dir_all(&dir).ok();
    }

    /// The streaming read: the frames (cameras and photo paths) come without reading a photo,
    /// and each photo box-filtered as it is read is bit for bit the full read downsampled
    /// afterwards, with the same camera and the same warnings; the progress counts the photos.
    #[test]
    fn limited_read_box_filters_each_photo_as_it_is_read() {
        let (dir, _) = write_model("limited");
        let (full, full_warnings) = read_colmap(&dir, &dir).unwrap();
        let frames = read_colmap_frames(&dir, &dir).unwrap();
        assert_eq!(frames.len(), 2);
        let max = 1000; // 96×64 photos → 39×26
        let calls: std::sync::Arc<std::sync::Mutex<Vec<(String, u64, u64)>>> = Default::default();
        let c = calls.clone();
        let progress =
            crate::delight::Progress::new(move |st, d, t| c.lock().unwrap().push((st.to_string(), d, t)));
        let (small, small_warnings) = colmap_views(frames.clone(), Some(max), Some(&progress)).unwrap();
        assert_eq!(small_warnings, full_warnings);
        // one progress step per photo read
        let want: Vec<(String, u64, u64)> = (0..=2).map(|d| ("read views".to_string(), d, 2)).collect();
        assert_eq!(*calls.lock().unwrap(), want);
        let bits = |i: &Image| i.data.iter().flat_map(|p| p.0.map(f32::to_bits)).collect::<Vec<_>>();
        for ((f, v), s) in frames.iter().zip(&full).zip(&small) {
            // the frame's camera is the full read's
            assert_eq!((f.name.as_str(), f.path.as_path()), (v.name.as_str(), v.path.as_path()));
            assert_eq!(f.camera.to_world, v.camera.to_world);
            assert_eq!((f.camera.width, f.camera.height), (v.image.width, v.image.height));
            let want = crate::delight::downsample::downsample_view(v.clone(), max);
            assert!(s.image.data.len() <= max && s.image.data.len() < v.image.data.len());
            assert_eq!((s.image.width, s.image.height), (want.image.width, want.image.height));
            assert_eq!(bits(&s.image), bits(&want.image), "{}", s.name);
            assert_eq!(s.bad_pixels, want.bad_pixels);
            assert_eq!((s.camera.width, s.camera.height), (want.camera.width, want.camera.height));
            for p in [opal::math::Vec3::new(0.1, -0.2, 0.5), opal::math::Vec3::new(-0.4, 0.3, 1.0)] {
                assert_eq!(s.camera.project(p), want.camera.project(p));
            }
        }
        // no photo is read for the frames: a broken photo fails only the views
        std::fs::write(dir.join("b.exr"), b"not an image").unwrap();
        let frames = read_colmap_frames(&dir, &dir).unwrap();
        assert!(colmap_views(frames, Some(max), None).is_err());
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn unsupported_model_and_bad_counts_are_errors() {
        let p = Path::new("cameras.txt");
        assert!(parse_cameras("1 FISHEYE 10 10 1 2 3 4", p).is_err());
        assert!(parse_cameras("1 PINHOLE 10 10 1 2 3", p).is_err());
        assert!(parse_cameras("1 PINHOLE 10 10 -1 2 3 4", p).is_err());
        assert!(parse_images("1 1 0 0 0 0 0 4 1", Path::new("images.txt")).is_err());
    }
}
