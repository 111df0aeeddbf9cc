//! Contact edges in a view (issue 17, item 4): where two surfaces touch (a box standing on a
//! floor, an object sunk into the ground, two walls meeting), as opposed to occlusion
//! boundaries (one surface in front of another, a jump in depth).
//!
//! Definition: a ray through each pixel centre; two 4-neighbouring pixels whose first hits are
//! different shapes form a contact edge when their hit points are closer than
//! [`CONTACT_GAP_PIXELS`] pixel footprints (the footprint of a pixel at distance `t` is
//! `t · 2 tan(fov_x/2) / width`); an occlusion boundary's hit points lie far apart in depth. The
//! band is every pixel within `radius` pixels (Chebyshev distance) of a contact-edge pixel.
//! [`band_psnr`] scores an image against a reference over a mask.
//!
//! Tests: the unit tests below (a box on a floor: edges along its foot, none along its
//! silhouette against the far wall); the CLI's `contact_edges` key of report.json
//! (`crates/opal-cli/tests/delight.rs`); the scanned-object room's acceptance
//! (`crates/opal-inverse/tests/delight_scan_room.rs`).

use opal::camera::Camera;
use opal::image::Image;
use opal::math::{Vec2, Vec3};
use opal::scene::Scene;

/// Hit points of two neighbouring pixels on different shapes closer than this many pixel
/// footprints make a contact edge.
pub const CONTACT_GAP_PIXELS: f32 = 4.0;

/// Default half-width of the band along contact edges, in pixels.
pub const CONTACT_BAND_RADIUS: usize = 3;

/// Per pixel: the first hit's shape and position, or `None`.
fn first_hits(scene: &Scene, cam: &Camera) -> Vec<Option<(u32, Vec3, f32)>> {
    let mut hits = Vec::with_capacity(cam.width * cam.height);
    for y in 0..cam.height {
        for x in 0..cam.width {
            let r = cam.generate_ray(Vec2::new(x as f32 + 0.5, y as f32 + 0.5));
            hits.push(scene.intersect(&r).map(|si| (si.shape, si.p, (si.p - r.o).length())));
        }
    }
    hits
}

/// Contact edges and the band along them in one view (row-major per pixel).
#[derive(Clone, Debug)]
pub struct ContactMap {
    /// Pixels on a contact edge (see the module docs).
    pub edge: Vec<bool>,
    /// Pixels within the band's radius of a contact edge.
    pub band: Vec<bool>,
    /// Shape index of the first hit through the pixel centre, or `None`.
    pub shape: Vec<Option<u32>>,
}

/// The contact edges of camera `cam` in `scene` and the band of `radius` pixels along them.
pub fn contact_map(scene: &Scene, cam: &Camera, radius: usize) -> ContactMap {
    let (w, h) = (cam.width, cam.height);
    let hits = first_hits(scene, cam);
    let angle = 2.0 * cam.tan_half_x / w as f32;
    let mut edge = vec![false; w * h];
    let touching = |a: usize, b: usize| match (hits[a], hits[b]) {
        (Some((sa, pa, ta)), Some((sb, pb, tb))) if sa != sb => {
            (pa - pb).length() <= CONTACT_GAP_PIXELS * angle * ta.max(tb)
        }
        _ => false,
    };
    for y in 0..h {
        for x in 0..w {
            let k = y * w + x;
            for n in [(x + 1 < w).then(|| k + 1), (y + 1 < h).then(|| k + w)].into_iter().flatten() {
                if touching(k, n) {
                    edge[k] = true;
                    edge[n] = true;
                }
            }
        }
    }
    let band = dilate(&edge, w, h, radius);
    ContactMap { edge, band, shape: hits.iter().map(|h| h.map(|x| x.0)).collect() }
}

/// Pixels on a contact edge (see the module docs) of camera `cam` in `scene`, row-major.
pub fn contact_edges(scene: &Scene, cam: &Camera) -> Vec<bool> {
    contact_map(scene, cam, 0).edge
}

/// The pixels within `radius` pixels (Chebyshev distance) of a contact edge of camera `cam`.
pub fn contact_band(scene: &Scene, cam: &Camera, radius: usize) -> Vec<bool> {
    contact_map(scene, cam, radius).band
}

/// Square dilation of a mask (separable: rows, then columns).
fn dilate(m: &[bool], w: usize, h: usize, r: usize) -> Vec<bool> {
    let mut rows = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            let (a, b) = (x.saturating_sub(r), (x + r).min(w - 1));
            rows[y * w + x] = (a..=b).any(|i| m[y * w + i]);
        }
    }
    let mut out = vec![false; w * h];
    for y in 0..h {
        let (a, b) = (y.saturating_sub(r), (y + r).min(h - 1));
        for x in 0..w {
            out[y * w + x] = (a..=b).any(|j| rows[j * w + x]);
        }
    }
    out
}

/// Squared error of `img` against `reference` summed over the RGB channels of the pixels where
/// `mask` is true and both are finite, and the number of such pixels.
pub fn masked_squared_error(img: &Image, reference: &Image, mask: &[bool]) -> (f64, usize) {
    let (mut se, mut n) = (0f64, 0usize);
    for ((p, q), &m) in img.data.iter().zip(&reference.data).zip(mask) {
        if m && p.is_finite() && q.is_finite() {
            for c in 0..3 {
                se += ((p[c] - q[c]) as f64).powi(2);
            }
            n += 1;
        }
    }
    (se, n)
}

/// PSNR in dB of a summed squared error over `pixels` RGB pixels with peak value `peak`
/// (infinite for a zero error, NaN without pixels).
pub fn psnr_db(squared_error: f64, pixels: usize, peak: f64) -> f64 {
    if pixels == 0 {
        return f64::NAN;
    }
    10.0 * (peak * peak / (squared_error / (3 * pixels) as f64)).log10()
}

/// PSNR (dB) of `img` against `reference` over `mask` with peak `peak`, and the pixel count.
pub fn band_psnr(img: &Image, reference: &Image, mask: &[bool], peak: f64) -> (f64, usize) {
    let (se, n) = masked_squared_error(img, reference, mask);
    (psnr_db(se, n, peak), n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use opal::geometry::TriangleMesh;
    use opal::math::Mat4;
    use opal::scene::desc::{BsdfDesc, SceneDesc, SensorDesc, ShapeDesc, TextureDesc};
    use opal::spectrum::Spectrum;

    fn quad(id: &str, p: [Vec3; 4]) -> ShapeDesc {
        ShapeDesc {
            id: id.into(),
            mesh: TriangleMesh {
                positions: p.to_vec(),
                normals: vec![],
                uvs: vec![],
                indices: vec![[0, 1, 2], [0, 2, 3]],
            },
            bsdf: BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(Spectrum::splat(0.5)) },
            emitter: None,
            origin: None,
        }
    }

    /// A floor, a far wall and a box (front face only) standing on the floor, seen from the
    /// front and above: the box's foot is a contact edge, its top edge against the far wall an
    /// occlusion boundary; the floor meets the far wall in a contact edge.
    #[test]
    fn box_foot_is_contact_silhouette_is_not() {
        let v = Vec3::new;
        let floor = quad("floor", [v(-2., 0., 2.), v(2., 0., 2.), v(2., 0., -2.), v(-2., 0., -2.)]);
        let wall = quad("wall", [v(-2., 0., -2.), v(2., 0., -2.), v(2., 3., -2.), v(-2., 3., -2.)]);
        let front = quad("box", [v(-0.3, 0., 0.), v(0.3, 0., 0.), v(0.3, 0.5, 0.), v(-0.3, 0.5, 0.)]);
        let desc = SceneDesc {
            shapes: vec![floor, wall, front],
            sensors: vec![SensorDesc {
                to_world: Mat4::look_at_rh(v(0., 1.0, 2.5), v(0., 0.3, 0.), v(0., 1., 0.)).inverse()
                    * Mat4::from_scale(v(-1., 1., -1.)),
                id: "c".into(),
                fov_x_deg: 50.0,
                width: 96,
                height: 96,
                near_clip: 1e-3,
                far_clip: 1e3,
                spp: None,
            }],
            ..Default::default()
        };
        let scene = Scene::build(&desc).unwrap();
        let cam = &scene.cameras[0];
        let edges = contact_edges(&scene, cam);
        let (w, h) = (cam.width, cam.height);
        // classify the edge pixels by what they show
        let (mut foot, mut top, mut corner) = (0, 0, 0);
        for y in 0..h {
            for x in 0..w {
                if !edges[y * w + x] {
                    continue;
                }
                let r = cam.generate_ray(Vec2::new(x as f32 + 0.5, y as f32 + 0.5));
                let p = scene.intersect(&r).unwrap().p;
                if p.z.abs() < 0.05 && p.y < 0.05 {
                    foot += 1;
                } else if p.z.abs() < 0.05 && p.y > 0.45 {
                    top += 1;
                } else if p.z < -1.9 && p.y < 0.1 {
                    corner += 1;
                }
            }
        }
        assert!(foot > 20, "box foot: {foot} edge pixels");
        assert_eq!(top, 0, "the box's top edge is an occlusion boundary");
        assert!(corner > 20, "floor/wall corner: {corner} edge pixels");
        let band = contact_band(&scene, cam, 2);
        assert!(band.iter().filter(|&&b| b).count() > 3 * edges.iter().filter(|&&b| b).count());
        assert!(edges.iter().zip(&band).all(|(&e, &b)| !e || b));
    }

    #[test]
    fn psnr_of_a_known_error() {
        let mut a = Image::new(4, 4);
        let b = Image::new(4, 4);
        for p in &mut a.data {
            *p = Spectrum::splat(0.1);
        }
        let mask = vec![true; 16];
        let (p, n) = band_psnr(&a, &b, &mask, 1.0);
        assert_eq!(n, 16);
        assert!((p - 20.0).abs() < 1e-4, "{p}");
        assert!(band_psnr(&a, &b, &[false; 16], 1.0).0.is_nan());
    }
}
