//! Tests of the super-resolution on a synthetic textured plane (the reference box's back wall)
//! seen by four views: super-resolved far above back-projection, and the noise stop rule.

use super::*;
use crate::delight::{atlas, luminance_map, views};
use opal::image::Image;
use opal::math::Vec2;
use opal::scene::build::eval_texture;
use opal::scene::desc::BsdfDesc;
use opal::spectrum::Spectrum;

fn psnr(est: &[[f32; 3]], truth: &Image, mask: &[bool]) -> f64 {
    let (mut se, mut n) = (0f64, 0usize);
    for (i, e) in est.iter().enumerate() {
        if !mask[i] {
            continue;
        }
        let t = truth.data[i];
        for c in 0..3 {
            se += ((e[c] - t[c]) as f64).powi(2);
        }
        n += 3;
    }
    10.0 * (n as f64 / se).log10()
}

/// The views of the fixture, their pure-pixel buffers, the back wall's atlas and its
/// back-projected map.
struct Fixture {
    scene: Scene,
    k: usize,
    a: atlas::Atlas,
    views: Vec<views::View>,
    pure: Vec<views::PureBuffer>,
    truth: Image,
    bp: Vec<[f32; 3]>,
    bp_obs: Vec<bool>,
}

impl Fixture {
    fn solve(&self, s: &SrSettings) -> (Vec<[f32; 3]>, Vec<bool>, SrInfo) {
        let init = (&self.bp[..], &self.bp_obs[..]);
        superres_luminance(&self.scene, self.k as u32, &self.a, &self.views, &self.pure, init, None, s)
            .unwrap()
    }
}

/// Multiplies every pixel by `1 + noise · g` (g standard normal, per channel; seeded by the
/// view and pixel): relative noise as the photos' Monte-Carlo noise.
fn add_noise(img: &mut Image, noise: f32, view: u64) {
    if noise == 0.0 {
        return;
    }
    let u = |i: u64| {
        let mut z = i.wrapping_add(0x9E37_79B9_7F4A_7C15).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    };
    for (p, v) in img.data.iter_mut().enumerate() {
        for c in 0..3 {
            let i = ((view * 1_000_003 + p as u64) * 3 + c as u64) * 2;
            let g = (-2.0 * (1.0 - u(i)).ln()).sqrt() * (std::f64::consts::TAU * u(i + 1)).cos();
            v.0[c] *= 1.0 + noise * g as f32;
        }
    }
}

/// Photos of the reference Cornell box whose pixels are exact box-filter averages (8×8
/// sub-pixel rays, not the solver's 4×4) of the *albedo* (i.e. radiance B = albedo), at
/// 160×160 from four views, with relative noise `noise`.
fn fixture(noise: f32) -> Fixture {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../opal/tests/data/cbox");
    let mut desc = opal::scene::load::load_mitsuba_xml(&dir.join("scene.xml"), &[]).unwrap();
    for s in &mut desc.sensors {
        s.width = 160;
        s.height = 160;
    }
    let k = desc.shapes.iter().position(|s| s.id == "back_wall").unwrap();
    let BsdfDesc::Diffuse { reflectance: opal::scene::desc::TextureDesc::Bitmap(bm) } = &desc.shapes[k].bsdf
    else {
        panic!("back wall is textured")
    };
    let truth = (*bm.image).clone();
    let scene = Scene::build(&desc).unwrap();
    let albedo = |hit: &opal::scene::build::SurfaceInteraction| -> Spectrum {
        match &desc.shapes[hit.shape as usize].bsdf {
            BsdfDesc::Diffuse { reflectance } => eval_texture(reflectance, hit.uv),
            _ => Spectrum::ZERO,
        }
    };
    let views: Vec<views::View> = [3usize, 4, 5, 7]
        .iter()
        .map(|&vi| {
            let cam = scene.cameras[vi].clone();
            let mut img = Image::new(cam.width, cam.height);
            for y in 0..cam.height {
                for x in 0..cam.width {
                    let mut acc = [0f32; 3];
                    for sy in 0..8 {
                        for sx in 0..8 {
                            let p = Vec2::new(
                                x as f32 + (sx as f32 + 0.5) / 8.0,
                                y as f32 + (sy as f32 + 0.5) / 8.0,
                            );
                            if let Some(h) = scene.intersect(&cam.generate_ray(p)) {
                                let a = albedo(&h);
                                for c in 0..3 {
                                    acc[c] += a[c] / 64.0;
                                }
                            }
                        }
                    }
                    img.data[y * cam.width + x] = Spectrum(acc);
                }
            }
            add_noise(&mut img, noise, vi as u64);
            views::View {
                name: format!("v{vi}"),
                path: "synthetic".into(),
                camera: cam,
                image: img,
                bad_pixels: 0,
            }
        })
        .collect();
    let a = atlas::build_atlas(&desc.shapes[k].mesh, truth.width, true).unwrap();
    assert!(a.kept_uvs);
    let pure: Vec<_> = views.iter().map(|v| views::pure_buffer(&scene, &v.camera)).collect();
    let (bp, bp_obs) = luminance_map(&scene, k as u32, &a, &views, &pure);
    Fixture { scene, k, a, views, pure, truth, bp, bp_obs }
}

/// Noise-free photos ([`fixture`]): the super-resolved map of the 256² back-wall texture beats
/// the back-projected one by a wide margin (> 6 dB) and resolves its 1–3-texel lines (PSNR over
/// the texels both methods observe). This tests the operator and the solver, not the noise
/// handling (`bench/scripts/psnr_bound.py` does that).
#[test]
fn superres_recovers_texture_beyond_backprojection() {
    let f = fixture(0.0);
    let (sr, sr_obs, _) = f.solve(&SrSettings::default());
    let both: Vec<bool> = f.bp_obs.iter().zip(&sr_obs).map(|(a, b)| *a && *b).collect();
    let seen = both.iter().filter(|&&b| b).count();
    assert!(seen > f.truth.width * f.truth.height / 2, "{seen}");
    let (p_bp, p_sr) = (psnr(&f.bp, &f.truth, &both), psnr(&sr, &f.truth, &both));
    println!("back-projection {p_bp:.2} dB, super-resolution {p_sr:.2} dB over {seen} texels");
    assert!(p_sr > p_bp + 6.0, "super-resolution {p_sr} dB vs back-projection {p_bp} dB");
    // measured: 25.9 dB vs 34.1 dB (the TV weight is set for noisy photos, which limits
    // the noise-free case); the bounds leave ~2 dB for platform differences
    assert!(p_sr > 32.0, "super-resolution {p_sr} dB");
}

/// The noise stop rule ([`SrSettings::cg_tolerance`]) on photos with 2 % relative noise (the
/// reference photos' level): the solve stops by the rule, in fewer conjugate-gradient steps than
/// the fixed 6 × 60, with a final residual within the tolerance, and its map is as close to the
/// truth as the fixed-step one (PSNR within 0.1 dB) and differs from it by less than a fifth of
/// the fixed-step map's rms error against the truth. Measured: 88 steps instead of 360, 33.682
/// vs 33.686 dB; τ = 0.02 / 0.01 / 0.005 / 0.002 gave 46 / 65 / 88 / 120 steps and 33.25 /
/// 33.58 / 33.68 / 33.69 dB (the default τ is where the PSNR stops changing).
#[test]
fn superres_stops_by_the_noise() {
    let f = fixture(0.02);
    let fixed = SrSettings { cg_tolerance: 0.0, ..Default::default() };
    let (x_fixed, obs, i_fixed) = f.solve(&fixed);
    let (x_rule, _, i_rule) = f.solve(&SrSettings::default());
    let noise = i_rule.photo_noise.expect("noise measured");
    println!("photo noise {noise:.4}; fixed {i_fixed:?}; rule {i_rule:?}");
    assert!(noise > 0.01 && noise < 0.04, "{noise}");
    assert_eq!(i_fixed.cg_steps, 6 * 60);
    assert!(!i_fixed.converged);
    assert!(i_rule.converged, "{i_rule:?}");
    assert!(i_rule.cg_steps < i_fixed.cg_steps, "{i_rule:?}");
    let tol = SrSettings::default().cg_tolerance as f64;
    assert!(i_rule.residual_to_noise.is_some_and(|r| r <= tol), "{i_rule:?}");
    let (p_fixed, p_rule) = (psnr(&x_fixed, &f.truth, &obs), psnr(&x_rule, &f.truth, &obs));
    println!("PSNR fixed steps {p_fixed:.3} dB, stop rule {p_rule:.3} dB");
    assert!((p_rule - p_fixed).abs() < 0.1, "{p_rule} vs {p_fixed}");
    // the two maps differ by much less than either's error against the truth (the stop only
    // leaves a correction far below what the photos' noise leaves in the map)
    let (mut d2, mut n) = (0f64, 0usize);
    for (i, (a, b)) in x_rule.iter().zip(&x_fixed).enumerate() {
        if obs[i] {
            for c in 0..3 {
                d2 += ((a[c] - b[c]) as f64).powi(2);
            }
            n += 3;
        }
    }
    let (diff, err) = ((d2 / n as f64).sqrt(), 10f64.powf(-p_fixed / 20.0));
    println!("rms difference {diff:.5}, rms error of the fixed-step map {err:.5}");
    assert!(diff < 0.2 * err, "{diff} vs {err}");
}
