//! The fitted rough face as a renderable material, and the paper's Fig. 10 scene.
//!
//! * [`face_table`]: the tabulated BSDF ([`opal::bsdf::TabulatedBsdf`], `.obsdf` file) of a
//!   rough face with NDF `ndf` on a plate of index `ior` (single scattering, separable Smith G:
//!   the model of [`crate::export::face_bsdf`]), both sides, R and T; [`face_table_for`]: the
//!   same for the scattering model of the fit (single, height-correlated, multiple).
//! * [`chessboard_scene`]: a plate (rough top face from the table, polished bottom and edges:
//!   [`opal::bsdf::SmoothDielectric`]) held a little above an 8 × 8 chessboard, under a large
//!   overhead area light with emitting side walls (diffuse light), seen obliquely by one camera.
//! * [`render_chessboard`]: renders that scene for a face table; [`render_chessboard_face`] for
//!   any top-face model (a dotted face: the table's dots on a polished land).
//!
//! Scene units: the board is 8 × 8 units (squares of 1), the plate 5 × 5 × 0.25 units, its
//! bottom 0.5 above the board, so a transmission lobe of width Δθ blurs the squares under the
//! plate over about 0.6·Δθ units.
//! Tests: `tests` below (the table of a fitted NDF matches its albedo; the scene renders with
//! finite values and the plate blurs the board: lower contrast under the rough plate).

use opal::bsdf::RoughDielectric;
use opal::bsdf::microfacet::Ndfs;
use opal::bsdf::rough_dielectric::Shadowing;
use opal::bsdf::rough_dielectric_ms::RoughDielectricMs;
use opal::bsdf::tabulated::TableGrid;
use opal::bsdf::{Bxdfs, SmoothDielectric, TabulatedBsdf};
use opal::geometry::TriangleMesh;
use opal::gonio::Scattering;
use opal::image::Image;
use opal::integrator::path::{PathSettings, RenderOutput, render};
use opal::math::{DVec3, Mat4, Vec3};
use opal::scene::Scene;
use opal::scene::desc::*;
use opal::spectrum::Spectrum;
use std::sync::Arc;

/// Tabulated BSDF of the rough face (grid `grid`, 2 × 2 sub-samples per cell), single
/// scattering with the separable Smith G.
pub fn face_table(ndf: &Ndfs, ior: f64, grid: TableGrid, label: &str) -> opal::Result<TabulatedBsdf> {
    Ok(face_table_for(ndf, ior, grid, Scattering::Single, label)?.0)
}

/// Photons per table row when tabulating the multiple-scattering model.
pub const MS_PHOTONS_PER_ROW: usize = 50_000;

/// Tabulated BSDF of the rough face for the scattering model the fit used: single scattering
/// (separable or height-correlated Smith G) integrated from `eval`, or multiple scattering
/// histogrammed from [`MS_PHOTONS_PER_ROW`] random walks per row (seeded). Returns the table and
/// the fraction of scattered power the table could not represent (0 for single scattering;
/// see [`TabulatedBsdf::build_from_sampler`]).
pub fn face_table_for(
    ndf: &Ndfs,
    ior: f64,
    grid: TableGrid,
    scattering: Scattering,
    label: &str,
) -> opal::Result<(TabulatedBsdf, f64)> {
    let eta = ior as f32;
    match scattering {
        Scattering::Single | Scattering::SingleMitsuba | Scattering::SingleHeightCorrelated => {
            let (sh, name) = match scattering {
                Scattering::Single => (Shadowing::Separable, "separable"),
                Scattering::SingleMitsuba => (Shadowing::SeparableMitsuba, "separable (Mitsuba's G1)"),
                _ => (Shadowing::HeightCorrelated, "height-correlated"),
            };
            let src = RoughDielectric::new(ndf.clone(), eta, sh)?;
            let source =
                format!("rough face {label}, n = {ior}, single scattering, {name} Smith G (opal fit-ndf)");
            Ok((TabulatedBsdf::build(&src, eta, grid, 2, &source)?, 0.0))
        }
        Scattering::Multiple => {
            let ms = RoughDielectricMs::new(ndf.clone(), eta)?;
            let source = format!(
                "rough face {label}, n = {ior}, multiple scattering (random walk, {MS_PHOTONS_PER_ROW} photons per row; opal fit-ndf)"
            );
            TabulatedBsdf::build_from_sampler(
                |wo, rng| ms.sample_dir(wo, rng).map(|w| (w, 1.0)),
                eta,
                grid,
                MS_PHOTONS_PER_ROW,
                0x0FACE,
                &source,
            )
        }
    }
}

fn cube_faces(faces: &[usize], scale: Vec3, offset: Vec3) -> TriangleMesh {
    let c = opal::scene::load::cube_mesh();
    let mut m = TriangleMesh::default();
    for &f in faces {
        let base = m.positions.len() as u32;
        for k in 0..4 {
            m.positions.push(c.positions[4 * f + k] * scale + offset);
            m.uvs.push(c.uvs[4 * f + k]);
        }
        for t in [2 * f, 2 * f + 1] {
            m.indices.push(c.indices[t].map(|i| i - 4 * f as u32 + base));
        }
    }
    m
}

fn rect(scale: Vec3, offset: Vec3, flip: bool) -> TriangleMesh {
    let mut m = opal::scene::load::rectangle_mesh();
    m.normals.clear();
    for p in &mut m.positions {
        *p = *p * scale + offset;
    }
    if flip {
        for t in &mut m.indices {
            t.swap(1, 2);
        }
    }
    m
}

/// Builds the Fig. 10 scene with `face` as the plate's rough (top) face and `ior` its index.
pub fn chessboard_scene(face: Bxdfs, ior: f64, width: usize, height: usize) -> opal::Result<SceneDesc> {
    // 8 × 8 board texture, nearest lookup
    let mut tex = Image::new(8, 8);
    for y in 0..8 {
        for x in 0..8 {
            let v = if (x + y) % 2 == 0 { 0.8 } else { 0.05 };
            tex.set(x, y, Spectrum::splat(v));
        }
    }
    let board = TextureDesc::Bitmap(BitmapDesc {
        image: Arc::new(tex),
        filter: FilterType::Nearest,
        wrap: WrapMode::Clamp,
        path: "chessboard (generated)".into(),
    });
    let glass = BsdfDesc::Lobe(Bxdfs::SmoothDielectric(SmoothDielectric::new(ior as f32)?));
    let (z0, th) = (0.5f32, 0.25f32);
    let half = Vec3::new(2.5, 2.5, 0.5 * th);
    let centre = Vec3::new(0.0, 0.0, z0 + 0.5 * th);
    let shape =
        |id: &str, mesh, bsdf, emitter| ShapeDesc { id: id.into(), mesh, bsdf, emitter, origin: None };
    let light = |le: f32| Some(AreaEmitterDesc { radiance: Spectrum::splat(le) });
    let black = || BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(Spectrum::ZERO) };
    let shapes = vec![
        shape(
            "board",
            rect(Vec3::new(4.0, 4.0, 1.0), Vec3::ZERO, false),
            BsdfDesc::Diffuse { reflectance: board },
            None,
        ),
        // a grey floor around the board
        shape(
            "floor",
            rect(Vec3::new(30.0, 30.0, 1.0), Vec3::new(0.0, 0.0, -0.01), false),
            BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(Spectrum::splat(0.3)) },
            None,
        ),
        // plate: cube faces −y, +y, +x, +z, −x, −z = 0..6; +z is the rough face
        shape("plate_rough_top", cube_faces(&[3], half, centre), BsdfDesc::Lobe(face), None),
        shape("plate_polished", cube_faces(&[0, 1, 2, 4, 5], half, centre), glass, None),
        // diffuse light: an overhead panel facing down and four dimmer walls facing inwards
        shape("sky", rect(Vec3::new(30.0, 30.0, 1.0), Vec3::new(0.0, 0.0, 12.0), true), black(), light(1.0)),
        shape(
            "wall_n",
            cube_faces(&[1], Vec3::new(30.0, 0.01, 12.0), Vec3::new(0.0, -30.0, 6.0)),
            black(),
            light(0.4),
        ),
        shape(
            "wall_s",
            cube_faces(&[0], Vec3::new(30.0, 0.01, 12.0), Vec3::new(0.0, 30.0, 6.0)),
            black(),
            light(0.4),
        ),
        shape(
            "wall_e",
            cube_faces(&[4], Vec3::new(0.01, 30.0, 12.0), Vec3::new(30.0, 0.0, 6.0)),
            black(),
            light(0.4),
        ),
        shape(
            "wall_w",
            cube_faces(&[2], Vec3::new(0.01, 30.0, 12.0), Vec3::new(-30.0, 0.0, 6.0)),
            black(),
            light(0.4),
        ),
    ];
    let to_world = opal::scene::load::look_at(
        DVec3::new(0.0, -7.5, 6.5),
        DVec3::new(0.0, -0.3, 0.3),
        DVec3::new(0.0, 0.0, 1.0),
    )
    .expect("finite camera");
    let to_world = Mat4::from_cols_array(&to_world.to_cols_array().map(|x| x as f32));
    Ok(SceneDesc {
        shapes,
        sensors: vec![SensorDesc {
            id: "chessboard".into(),
            to_world,
            fov_x_deg: 48.0,
            width,
            height,
            near_clip: 1e-3,
            far_clip: 1e3,
            spp: None,
        }],
        ..Default::default()
    })
}

/// Renders the chessboard scene for a face table (`spp` samples per pixel, fixed seed).
pub fn render_chessboard(
    face: &TabulatedBsdf,
    ior: f64,
    size: (usize, usize),
    spp: u32,
) -> opal::Result<RenderOutput> {
    render_chessboard_face(Bxdfs::Tabulated(face.clone()), ior, size, spp)
}

/// Renders the chessboard scene with any top-face model (e.g. an [`opal::bsdf::Dotted`] face
/// of a table's dots on a polished land, which a table alone cannot represent).
pub fn render_chessboard_face(
    face: Bxdfs,
    ior: f64,
    size: (usize, usize),
    spp: u32,
) -> opal::Result<RenderOutput> {
    let desc = chessboard_scene(face, ior, size.0, size.1)?;
    let scene = Scene::build(&desc)?;
    let s = PathSettings { spp, max_depth: 12, rr_depth: 4, hide_emitters: false, seed: 7 };
    Ok(render(&scene, 0, &s, &|| {}))
}

/// Michelson contrast `(max − min)/(max + min)` of the mean luminance of the squares under the
/// plate's centre (a 2 × 2 block of squares) seen from straight above: a diagnostic of how
/// much the face blurs the board (1 without plate, → 0 for a strongly diffusing face).
pub fn board_contrast_under_plate(face: &TabulatedBsdf, ior: f64, spp: u32) -> opal::Result<f64> {
    let mut desc = chessboard_scene(Bxdfs::Tabulated(face.clone()), ior, 32, 32)?;
    let to_world = opal::scene::load::look_at(
        DVec3::new(0.0, 0.0, 6.0),
        DVec3::new(0.0, 0.0, 0.0),
        DVec3::new(0.0, 1.0, 0.0),
    )
    .expect("finite camera");
    desc.sensors[0].to_world = Mat4::from_cols_array(&to_world.to_cols_array().map(|x| x as f32));
    // field of view: 2 × 2 squares ([-1, 1]²) at distance 6
    desc.sensors[0].fov_x_deg = 2.0 * (1.0f32 / 6.0).atan().to_degrees();
    let scene = Scene::build(&desc)?;
    let s = PathSettings { spp, max_depth: 12, rr_depth: 4, hide_emitters: false, seed: 3 };
    let out = render(&scene, 0, &s, &|| {});
    // quadrants = squares; average each (skipping a border of 4 pixels around the edges)
    let mut q = [0.0f64; 4];
    let mut n = [0usize; 4];
    for y in 0..32 {
        for x in 0..32 {
            if (12..20).contains(&x) || (12..20).contains(&y) {
                continue;
            }
            let k = (y / 16) * 2 + x / 16;
            q[k] += out.image.get(x, y).average() as f64;
            n[k] += 1;
        }
    }
    let m: Vec<f64> = q.iter().zip(&n).map(|(a, &c)| a / c as f64).collect();
    let hi = m.iter().cloned().fold(f64::MIN, f64::max);
    let lo = m.iter().cloned().fold(f64::MAX, f64::min);
    Ok((hi - lo) / (hi + lo))
}

#[cfg(test)]
mod tests {
    use super::*;
    use opal::bsdf::Bxdf;

    /// The tabulated face renders like the analytic model it was built from: the chessboard
    /// scene (64 × 48, 64 spp, independent seeds) with the table and with the analytic
    /// `RoughDielectric`, compared on the image mean (z-test at 4σ) and on 8 × 8-pixel blocks
    /// (≥ 95 % within 3σ): covers NEE and MIS through the table, sampling from both sides.
    #[test]
    fn tabulated_face_renders_like_the_analytic_face() {
        let ndf = Ndfs::ggx(0.25);
        let table = face_table(&ndf, 1.5, TableGrid::default(), "ggx 0.25").unwrap();
        let analytic = crate::export::face_bsdf(ndf, 1.5).unwrap();
        let run = |face: Bxdfs, seed: u64| {
            let scene = Scene::build(&chessboard_scene(face, 1.5, 64, 48).unwrap()).unwrap();
            let s = PathSettings { spp: 64, max_depth: 12, rr_depth: 4, hide_emitters: false, seed };
            render(&scene, 0, &s, &|| {})
        };
        let a = run(Bxdfs::Tabulated(table), 1);
        let b = run(Bxdfs::RoughDielectric(analytic), 2);
        assert_eq!(a.nonfinite + b.nonfinite, 0);
        let n = a.image.data.len() as f64;
        let mean = |o: &RenderOutput| o.image.data.iter().map(|p| p[0] as f64).sum::<f64>() / n;
        let se =
            |o: &RenderOutput| (o.stderr.data.iter().map(|p| (p[0] as f64).powi(2)).sum::<f64>()).sqrt() / n;
        let z = (mean(&a) - mean(&b)) / (se(&a).powi(2) + se(&b).powi(2)).sqrt();
        eprintln!("image mean: table {:.5}, analytic {:.5}, z = {z:.2}", mean(&a), mean(&b));
        assert!(z.abs() < 4.0, "z = {z}");
        let (mut ok, mut tot) = (0, 0);
        for by in 0..6 {
            for bx in 0..8 {
                let (mut ma, mut mb, mut va, mut vb) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
                for y in 8 * by..8 * by + 8 {
                    for x in 8 * bx..8 * bx + 8 {
                        ma += a.image.get(x, y)[0] as f64 / 64.0;
                        mb += b.image.get(x, y)[0] as f64 / 64.0;
                        va += (a.stderr.get(x, y)[0] as f64 / 64.0).powi(2);
                        vb += (b.stderr.get(x, y)[0] as f64 / 64.0).powi(2);
                    }
                }
                tot += 1;
                if va + vb == 0.0 || (ma - mb).abs() <= 3.0 * (va + vb).sqrt() {
                    ok += 1;
                }
            }
        }
        eprintln!("blocks within 3σ: {ok}/{tot}");
        assert!(ok * 100 >= 95 * tot, "{ok}/{tot} blocks within 3σ");
    }

    /// The multiple-scattering face keeps the energy the single-scattering one loses.
    #[test]
    fn multiple_scattering_table_keeps_energy() {
        let grid = TableGrid { n_theta_o: 9, n_u: 48, n_v: 24, beta: 12.0 };
        let ndf = Ndfs::ggx(0.4);
        let (ss, l0) = face_table_for(&ndf, 1.5, grid, Scattering::Single, "ss").unwrap();
        let (ms, l1) = face_table_for(&ndf, 1.5, grid, Scattering::Multiple, "ms").unwrap();
        assert_eq!(l0, 0.0);
        eprintln!("dropped (multiple scattering, α = 0.4): {l1:.4}");
        for th in [0.1f32, 0.8, 1.3] {
            let wo = Vec3::new(th.sin(), 0.0, th.cos());
            let (a, b) = (ss.albedo(wo), ms.albedo(wo));
            eprintln!("θ={th}: albedo single {a:.4}, multiple {b:.4}");
            assert!(b > a && b <= 1.0 + 1e-4, "θ={th}: single {a}, multiple {b}");
        }
    }

    #[test]
    fn table_albedo_and_board_blur() {
        let grid = TableGrid { n_theta_o: 18, n_u: 48, n_v: 24, beta: 12.0 };
        let sharp = face_table(&Ndfs::ggx(0.05), 1.5, grid, "ggx 0.05").unwrap();
        let rough = face_table(&Ndfs::ggx(0.5), 1.5, grid, "ggx 0.5").unwrap();
        // near-normal incidence from air: R + T ≈ 1 for a smooth-ish face (< 2 % masking loss)
        let a = sharp.albedo(Vec3::new(0.0, 0.0, 1.0));
        assert!((a - 1.0).abs() < 0.02, "albedo {a}");
        assert!(sharp.flags().transmission);
        let mid = face_table(&Ndfs::ggx(0.2), 1.5, grid, "ggx 0.2").unwrap();
        let c: Vec<f64> =
            [&sharp, &mid, &rough].iter().map(|t| board_contrast_under_plate(t, 1.5, 16).unwrap()).collect();
        eprintln!("board contrast under the plate: α = 0.05, 0.2, 0.5: {c:?}");
        // the board is 0.8 / 0.05 (contrast 0.88 unblurred): the sharp face keeps most of it,
        // rougher faces wash it out more and more
        assert!(c[0] > 0.5, "sharp face contrast {}", c[0]);
        assert!(c[1] < 0.9 * c[0] && c[2] < 0.9 * c[1], "contrast not decreasing with α: {c:?}");
    }
}
