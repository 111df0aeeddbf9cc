//! The light tracer's emission for `constant`, `envmap`, `spot` and `directional` lights
//! against the path tracer: a diffuse floor (albedo ½) under a two-sided diffuse occluder,
//! lit by one emitter at a time. Per texel, the light tracer's irradiance (direct + indirect
//! maps; four passes with different seeds give its standard error) is compared with the path
//! tracer's: `E = π/ρ · L_o`, with `L_o` the radiance `path::li` returns for rays hitting the
//! floor straight down at uniform points of the texel (standard error from the samples). Both
//! include every bounce. Every (texel, channel) must agree within 4.5σ.

use super::*;
use crate::geometry::TriangleMesh;
use crate::image::Image;
use crate::integrator::path::{PathSettings, li};
use crate::math::{Mat4, Vec2, Vec3};
use crate::sampling::Rng;
use crate::scene::desc::{BsdfDesc, EmitterDesc, SceneDesc, ShapeDesc, TextureDesc};
use crate::spectrum::Spectrum;
use std::sync::Arc;

/// Square [-h,h]² at height y facing +y with uv = ((x+h)/2h, (z+h)/2h).
fn quad(h: f32, y: f32) -> TriangleMesh {
    TriangleMesh {
        positions: vec![Vec3::new(-h, y, -h), Vec3::new(-h, y, h), Vec3::new(h, y, h), Vec3::new(h, y, -h)],
        normals: vec![],
        uvs: vec![Vec2::new(0.0, 0.0), Vec2::new(0.0, 1.0), Vec2::new(1.0, 1.0), Vec2::new(1.0, 0.0)],
        indices: vec![[0, 1, 2], [0, 2, 3]],
    }
}

fn diffuse(a: f32) -> BsdfDesc {
    BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(Spectrum::splat(a)) }
}

const RHO: f32 = 0.5;
const RES: usize = 4;

fn scene_with(emitter: EmitterDesc) -> Scene {
    let mut occluder = quad(0.3, 0.4);
    occluder.positions.iter_mut().for_each(|p| p.x += 0.2);
    let desc = SceneDesc {
        shapes: vec![
            ShapeDesc {
                id: "floor".into(),
                mesh: quad(1.0, 0.0),
                bsdf: diffuse(RHO),
                emitter: None,
                origin: None,
            },
            ShapeDesc {
                id: "occluder".into(),
                mesh: occluder,
                bsdf: BsdfDesc::TwoSided(Box::new(diffuse(0.5))),
                emitter: None,
                origin: None,
            },
        ],
        emitters: vec![emitter],
        ..Default::default()
    };
    Scene::build(&desc).unwrap()
}

/// (mean, standard error) per texel and channel of the light tracer's direct + indirect map.
fn light_traced(scene: &Scene) -> Vec<[(f64, f64); 3]> {
    let ta = 4.0 / (RES * RES) as f32;
    let targets = [Some(IrradianceTarget { width: RES, height: RES, texel_area: vec![ta, ta] }), None];
    let runs: Vec<IrradianceMaps> = (0..4)
        .map(|seed| {
            let s = LightTraceSettings { paths: 400_000, seed: 100 + seed, ..Default::default() };
            let out = trace(scene, &targets, &s, &|| {});
            assert_eq!(out.nonfinite, 0);
            out.maps[0].clone().unwrap()
        })
        .collect();
    (0..RES * RES)
        .map(|t| {
            std::array::from_fn(|c| {
                let v: Vec<f64> = runs.iter().map(|m| m.direct[t][c] + m.indirect[t][c]).collect();
                let mean = v.iter().sum::<f64>() / 4.0;
                let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / 3.0;
                (mean, (var / 4.0).sqrt())
            })
        })
        .collect()
}

/// (mean, standard error) per texel and channel of the path tracer's irradiance estimate.
fn path_traced(scene: &Scene) -> Vec<[(f64, f64); 3]> {
    let s = PathSettings { spp: 1, max_depth: -1, rr_depth: 5, hide_emitters: false, seed: 0 };
    let n = 6000;
    (0..RES * RES)
        .map(|t| {
            let (tx, ty) = (t % RES, t / RES);
            let mut rng = Rng::new(7, 1, t as u64);
            let (mut sum, mut sum2) = ([0.0f64; 3], [0.0f64; 3]);
            for _ in 0..n {
                let u = rng.next_2d();
                let x = -1.0 + 2.0 * (tx as f32 + u.x) / RES as f32;
                let z = -1.0 + 2.0 * (ty as f32 + u.y) / RES as f32;
                let ray = crate::geometry::Ray::new(Vec3::new(x, 1e-3, z), -Vec3::Y);
                let l = li(scene, ray, &mut rng, &s);
                for c in 0..3 {
                    let e = (l[c] * std::f32::consts::PI / RHO) as f64;
                    sum[c] += e;
                    sum2[c] += e * e;
                }
            }
            std::array::from_fn(|c| {
                let m = sum[c] / n as f64;
                let var = (sum2[c] / n as f64 - m * m).max(0.0) * n as f64 / (n - 1) as f64;
                (m, (var / n as f64).sqrt())
            })
        })
        .collect()
}

fn agree(name: &str, scene: &Scene) {
    let (lt, pt) = (light_traced(scene), path_traced(scene));
    let mut worst = 0.0f64;
    for t in 0..RES * RES {
        for c in 0..3 {
            let ((a, sa), (b, sb)) = (lt[t][c], pt[t][c]);
            assert!(b > 0.0, "{name}: texel {t} c{c} receives no light");
            let z = (a - b) / (sa * sa + sb * sb).sqrt();
            worst = worst.max(z.abs());
            assert!(z.abs() < 4.5, "{name}: texel {t} c{c}: light tracer {a} ± {sa}, path tracer {b} ± {sb}");
        }
    }
    eprintln!("{name}: light and path tracer agree, worst |z| {worst:.2} over {} pairs", RES * RES * 3);
}

#[test]
fn constant_environment_light_and_path_tracer_agree() {
    agree("constant", &scene_with(EmitterDesc::Constant { radiance: Spectrum::rgb(0.5, 0.8, 1.0) }));
}

#[test]
fn envmap_light_and_path_tracer_agree() {
    let (w, h) = (16, 8);
    let mut img = Image::new(w, h);
    for y in 0..h {
        for x in 0..w {
            let sky = if y < h / 2 { 1.0 - y as f32 / h as f32 } else { 0.1 };
            img.set(x, y, Spectrum::rgb(0.4 * sky, 0.6 * sky, sky));
        }
    }
    img.set(3, 2, Spectrum::rgb(30.0, 25.0, 20.0));
    let e = EmitterDesc::EnvMap {
        image: Arc::new(img),
        scale: 1.2,
        to_world: Mat4::from_rotation_y(0.5) * Mat4::from_rotation_x(-0.3),
        path: "procedural".into(),
    };
    agree("envmap", &scene_with(e));
}

#[test]
fn spot_light_and_path_tracer_agree() {
    let e = EmitterDesc::Spot {
        to_world: Mat4::from_translation(Vec3::new(-0.3, 1.5, 0.2))
            * Mat4::from_rotation_x(std::f32::consts::FRAC_PI_2 + 0.1)
            * Mat4::from_rotation_y(0.2),
        intensity: Spectrum::rgb(3.0, 2.0, 1.0),
        cutoff_deg: 45.0,
        beam_width_deg: 25.0,
        texture: None,
    };
    agree("spot", &scene_with(e));
}

#[test]
fn directional_light_and_path_tracer_agree() {
    let e = EmitterDesc::Directional {
        direction: Vec3::new(0.3, -1.0, 0.2),
        irradiance: Spectrum::rgb(1.0, 2.0, 3.0),
    };
    agree("directional", &scene_with(e));
}
