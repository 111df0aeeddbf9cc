//! Unit tests of the light tracer (listed in the module docs of [`super`]).

use super::path::survival;
use super::wavefront::W;
use super::*;
use crate::bsdf::{Bxdf, TransportMode};
use crate::geometry::TriangleMesh;
use crate::math::{PI, Vec2, Vec3};
use crate::sampling::Rng;
use crate::scene::desc::{AreaEmitterDesc, BsdfDesc, EmitterDesc, SceneDesc, ShapeDesc, TextureDesc};
use crate::spectrum::Spectrum;

/// Square [-h,h]² in the plane y = 0 facing +y with uv = ((x+h)/2h, (z+h)/2h).
fn floor_quad(h: f32) -> TriangleMesh {
    TriangleMesh {
        positions: vec![
            Vec3::new(-h, 0.0, -h),
            Vec3::new(-h, 0.0, h),
            Vec3::new(h, 0.0, h),
            Vec3::new(h, 0.0, -h),
        ],
        normals: vec![],
        uvs: vec![Vec2::new(0.0, 0.0), Vec2::new(0.0, 1.0), Vec2::new(1.0, 1.0), Vec2::new(1.0, 0.0)],
        indices: vec![[0, 1, 2], [0, 2, 3]],
    }
}

fn shape(id: &str, mesh: TriangleMesh, bsdf: BsdfDesc, emitter: Option<AreaEmitterDesc>) -> ShapeDesc {
    ShapeDesc { id: id.into(), mesh, bsdf, emitter, origin: None }
}

fn diffuse(a: f32) -> BsdfDesc {
    BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(Spectrum::splat(a)) }
}

fn target(res: usize, h: f32) -> IrradianceTarget {
    let ta = (2.0 * h) * (2.0 * h) / (res * res) as f32;
    IrradianceTarget { width: res, height: res, texel_area: vec![ta, ta] }
}

#[test]
fn point_light_over_quad_matches_inverse_square_law() {
    let h = 1.0;
    let height = 1.0;
    let desc = SceneDesc {
        shapes: vec![shape("floor", floor_quad(h), diffuse(0.0), None)],
        emitters: vec![EmitterDesc::Point {
            position: Vec3::new(0.0, height, 0.0),
            intensity: Spectrum::rgb(1.0, 2.0, 3.0),
        }],
        ..Default::default()
    };
    let scene = Scene::build(&desc).unwrap();
    let res = 8;
    let s = LightTraceSettings { paths: 2_000_000, seed: 3, ..Default::default() };
    let out = trace(&scene, &[Some(target(res, h))], &s, &|| {});
    assert_eq!(out.nonfinite, 0);
    let m = out.maps[0].as_ref().unwrap();
    // Analytic texel average of E = I h / r³ over each texel (midpoint rule on a 16×16 grid).
    for (ty, tx) in [(3usize, 3usize), (0, 0), (5, 2), (7, 7)] {
        let mut e = 0.0f64;
        let n = 16;
        for j in 0..n {
            for i in 0..n {
                let x = -h as f64 + 2.0 * h as f64 * (tx as f64 + (i as f64 + 0.5) / n as f64) / res as f64;
                let z = -h as f64 + 2.0 * h as f64 * (ty as f64 + (j as f64 + 0.5) / n as f64) / res as f64;
                let r2 = x * x + z * z + 1.0;
                e += 1.0 / r2.powf(1.5);
            }
        }
        e /= (n * n) as f64;
        for c in 0..3 {
            let expect = e * (c + 1) as f64;
            let got = m.direct[ty * res + tx][c];
            // Each texel receives a binomial count of paths: fraction p of 2 M; relative
            // std = sqrt((1-p)/(N p)); p ≥ 0.0017 (corner texel) ⇒ ≤ 1.7 %. 5σ ⇒ 8.5 %.
            let p = e * (2.0 / res as f64).powi(2) / (4.0 * std::f64::consts::PI);
            let sigma = ((1.0 - p) / (s.paths as f64 * p)).sqrt();
            assert!(
                (got / expect - 1.0).abs() < 5.0 * sigma,
                "texel {tx},{ty} c{c}: {got} vs {expect} (σ {sigma})"
            );
        }
        assert_eq!(m.indirect[ty * res + tx], [0.0; 3], "black floor, nothing else: no indirect light");
    }
}

#[test]
fn area_light_over_quad_matches_quadrature_and_is_thread_independent() {
    // A 0.5×0.5 emitter at height 1 facing down over a 2×2 floor, both one-sided.
    let le = 2.0f32;
    let a = 0.25f32;
    let light = TriangleMesh {
        positions: vec![
            Vec3::new(-a, 1.0, -a),
            Vec3::new(a, 1.0, -a),
            Vec3::new(a, 1.0, a),
            Vec3::new(-a, 1.0, a),
        ],
        normals: vec![],
        uvs: vec![],
        indices: vec![[0, 1, 2], [0, 2, 3]],
    };
    let n = (light.positions[1] - light.positions[0]).cross(light.positions[2] - light.positions[0]);
    assert!(n.y < 0.0, "light faces down");
    let desc = SceneDesc {
        shapes: vec![
            shape("floor", floor_quad(1.0), diffuse(0.0), None),
            shape("light", light, diffuse(0.0), Some(AreaEmitterDesc { radiance: Spectrum::splat(le) })),
        ],
        ..Default::default()
    };
    let scene = Scene::build(&desc).unwrap();
    let res = 4;
    let targets = [Some(target(res, 1.0)), None];
    let s = LightTraceSettings { paths: 1_000_000, seed: 11, batch_size: 10_000, ..Default::default() };
    let out = trace(&scene, &targets, &s, &|| {});
    let m = out.maps[0].as_ref().unwrap();
    // E(p) = ∫_light Le cosθ cosθ' / r² dA, texel-averaged: midpoint rule 8×8 on the texel ×
    // 32×32 on the light (smooth integrand: error ≪ 0.1 %).
    let total_power = (PI * le * 4.0 * a * a) as f64;
    for (ty, tx) in [(1usize, 1usize), (0, 0), (2, 3)] {
        let mut e = 0.0f64;
        let (nt, nl) = (8, 32);
        for j in 0..nt {
            for i in 0..nt {
                let x = -1.0 + 2.0 * (tx as f64 + (i as f64 + 0.5) / nt as f64) / res as f64;
                let z = -1.0 + 2.0 * (ty as f64 + (j as f64 + 0.5) / nt as f64) / res as f64;
                for l in 0..nl {
                    for k in 0..nl {
                        let lx = -a as f64 + 2.0 * a as f64 * (k as f64 + 0.5) / nl as f64;
                        let lz = -a as f64 + 2.0 * a as f64 * (l as f64 + 0.5) / nl as f64;
                        let d2 = (lx - x).powi(2) + 1.0 + (lz - z).powi(2);
                        e += le as f64 / (d2 * d2) * (2.0 * a as f64).powi(2) / (nl * nl) as f64;
                    }
                }
            }
        }
        e /= (nt * nt) as f64;
        let got = m.direct[ty * res + tx][0];
        let p = e * 0.25 / total_power; // fraction of paths landing in the texel
        let sigma = ((1.0 - p) / (s.paths as f64 * p)).sqrt();
        assert!((got / e - 1.0).abs() < 5.0 * sigma, "texel {tx},{ty}: {got} vs {e} (σ {sigma})");
    }
    // thread-count independence
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let out1 = pool.install(|| trace(&scene, &targets, &s, &|| {}));
    assert_eq!(out1.maps[0].as_ref().unwrap().direct, m.direct);
}

/// The unit cube of `cube_mesh` with its walls facing inwards (winding flipped, no normals).
fn inward_box() -> crate::geometry::TriangleMesh {
    let mut inner = crate::scene::load::cube_mesh();
    for t in &mut inner.indices {
        t.swap(1, 2);
    }
    inner.normals.clear();
    inner
}

#[test]
fn closed_box_indirect_matches_geometric_series() {
    // Inside a closed box whose walls all have albedo ρ, emitting walls of radiance Le: the
    // radiance is Le/(1-ρ) everywhere, so the irradiance on a wall is π Le/(1-ρ), of which the
    // direct part is π Le (all walls emit, cosine-weighted view of the whole box) and the
    // indirect part π Le ρ/(1-ρ).
    let rho = 0.5f32;
    let le = 1.0f32;
    let inner = inward_box();
    let desc = SceneDesc {
        shapes: vec![shape(
            "box",
            inner.clone(),
            diffuse(rho),
            Some(AreaEmitterDesc { radiance: Spectrum::splat(le) }),
        )],
        ..Default::default()
    };
    let scene = Scene::build(&desc).unwrap();
    // one texel per triangle is enough: map everything to a 1×1 map
    let texel_area: Vec<f32> = (0..inner.triangle_count()).map(|_| inner.area() as f32).collect();
    let targets = [Some(IrradianceTarget { width: 1, height: 1, texel_area })];
    let s = LightTraceSettings { paths: 400_000, seed: 5, ..Default::default() };
    let out = trace(&scene, &targets, &s, &|| {});
    let m = out.maps[0].as_ref().unwrap();
    let direct = m.direct[0][0];
    let indirect = m.indirect[0][0];
    let pi = std::f64::consts::PI;
    // Direct: every path deposits exactly its power (no variance up to the light choice).
    assert!((direct / (pi * le as f64) - 1.0).abs() < 1e-3, "direct {direct}");
    // Indirect: the number of bounces is geometric with Russian roulette from depth 5;
    // relative std of the mean ≈ 1/sqrt(N) × O(1) ⇒ 1 % is > 5σ at N = 400 k.
    let expect = pi * le as f64 * rho as f64 / (1.0 - rho as f64);
    assert!((indirect / expect - 1.0).abs() < 0.01, "indirect {indirect} vs {expect}");
}

/// The pass as it was before the fast paths: generic hit reconstruction (`Scene::intersect`)
/// and BSDFs (`Scene::bsdf`), f64 sums in path order, one thread; same random streams.
fn reference(
    scene: &Scene,
    targets: &[Option<IrradianceTarget>],
    s: &LightTraceSettings,
) -> Vec<Option<IrradianceMaps>> {
    let mut maps = empty_maps(targets);
    let sampler = scene.light_sampler().unwrap();
    let inv_n = 1.0 / s.paths as f64;
    for b in 0..s.paths.div_ceil(s.batch_size) {
        for i in b * s.batch_size..((b + 1) * s.batch_size).min(s.paths) {
            let mut rng = Rng::new(s.seed, RNG_STREAM, i);
            let (li, pmf, _) = sampler.sample(rng.next_f32());
            let (u_pos, u_dir) = (rng.next_2d(), rng.next_2d());
            let Some(es) = scene.lights[li].sample_le(u_pos, u_dir) else { continue };
            // point lights (no normal): no cosine, no offset
            let cos = if es.n == Vec3::ZERO { 1.0 } else { es.ray.d.dot(es.n).abs() };
            let mut beta = es.le * (cos / (pmf * es.pdf_pos * es.pdf_dir));
            let mut ray =
                if es.n == Vec3::ZERO { es.ray } else { crate::accel::spawn_ray(es.ray.o, es.n, es.ray.d) };
            let mut depth = 0;
            while let Some(si) = scene.intersect(&ray) {
                depth += 1;
                let wo = -ray.d;
                let shape = si.shape as usize;
                if let (true, Some(t), Some(m)) = (wo.dot(si.ng) > 0.0, &targets[shape], maps[shape].as_mut())
                {
                    let ta = t.texel_area[(si.prim - scene.shapes[shape].first_prim) as usize];
                    let x = ((si.uv.x * t.width as f32) as i64).clamp(0, t.width as i64 - 1) as usize;
                    let y = ((si.uv.y * t.height as f32) as i64).clamp(0, t.height as i64 - 1) as usize;
                    let cell = if depth == 1 {
                        &mut m.direct[y * t.width + x]
                    } else {
                        &mut m.indirect[y * t.width + x]
                    };
                    for (a, v) in cell.iter_mut().zip(beta.to_f64()) {
                        *a += v * inv_n / ta as f64;
                    }
                }
                let (frame, bsdf) = scene.bsdf(&si, wo);
                let uc = rng.next_f32();
                let u = rng.next_2d();
                let Some(bs) = bsdf.sample(frame.to_local(wo), uc, u, TransportMode::Importance) else {
                    break;
                };
                let w = bs.weight();
                if w.is_black() {
                    break;
                }
                beta *= w;
                ray = crate::accel::spawn_ray(si.p, si.ng, frame.to_world(bs.wi));
                if depth >= s.rr_depth {
                    let q = survival(beta, (es.le * (cos / (pmf * es.pdf_pos * es.pdf_dir))).max_component());
                    if rng.next_f32() >= q {
                        break;
                    }
                    beta *= 1.0 / q;
                }
            }
        }
    }
    maps
}

#[test]
fn fast_paths_and_fixed_point_match_the_generic_f64_pass_for_any_thread_count() {
    use crate::image::Image;
    use crate::scene::desc::{BitmapDesc, FilterType, WrapMode};
    // floor with a bilinear bitmap albedo, a two-sided diffuse back wall, a small light
    let img = Image {
        width: 4,
        height: 4,
        data: (0..16).map(|i| Spectrum::rgb(0.2 + 0.04 * i as f32, 0.5, 0.9 - 0.05 * i as f32)).collect(),
    };
    let tex = TextureDesc::Bitmap(BitmapDesc {
        image: std::sync::Arc::new(img),
        filter: crate::scene::desc::FilterType::Bilinear,
        wrap: WrapMode::Clamp,
        path: "albedo.exr".into(),
    });
    let _ = FilterType::Nearest;
    let quad = |p: [Vec3; 4]| TriangleMesh {
        positions: p.to_vec(),
        normals: vec![],
        uvs: vec![Vec2::new(0.0, 0.0), Vec2::new(1.0, 0.0), Vec2::new(1.0, 1.0), Vec2::new(0.0, 1.0)],
        indices: vec![[0, 1, 2], [0, 2, 3]],
    };
    let v = Vec3::new;
    let desc = SceneDesc {
        shapes: vec![
            shape("floor", floor_quad(1.0), BsdfDesc::Diffuse { reflectance: tex }, None),
            shape(
                "wall",
                // corner normals (tilted): the shading-normal path of the scattering kernel
                TriangleMesh {
                    normals: [v(0.2, 0.0, 1.0), v(-0.1, 0.1, 1.0), v(0.0, -0.2, 1.0), v(0.1, 0.1, 1.0)]
                        .map(|n| n.normalize())
                        .to_vec(),
                    ..quad([v(-1.0, 0.0, -1.0), v(1.0, 0.0, -1.0), v(1.0, 2.0, -1.0), v(-1.0, 2.0, -1.0)])
                },
                BsdfDesc::TwoSided(Box::new(diffuse(0.7))),
                None,
            ),
            shape(
                "light",
                quad([v(-0.3, 1.9, -0.3), v(0.3, 1.9, -0.3), v(0.3, 1.9, 0.3), v(-0.3, 1.9, 0.3)]),
                diffuse(0.0),
                Some(AreaEmitterDesc { radiance: Spectrum::rgb(5.0, 4.0, 3.0) }),
            ),
        ],
        // a point light too: the wavefront starts its paths one at a time
        emitters: vec![EmitterDesc::Point {
            position: v(0.4, 1.2, 0.2),
            intensity: Spectrum::rgb(0.6, 0.5, 0.4),
        }],
        ..Default::default()
    };
    let scene = Scene::build(&desc).unwrap();
    assert_eq!(scene.lights.len(), 3);
    let targets = [
        Some(target(8, 1.0)),
        Some(IrradianceTarget { width: 4, height: 4, texel_area: vec![0.25; 2] }),
        None,
    ];
    let s =
        LightTraceSettings { paths: 200_000, batch_size: 7_000, rr_depth: 2, seed: 21, ..Default::default() };
    let want = reference(&scene, &targets, &s);
    let runs: Vec<LightTraceOutput> = [1, 2, 3]
        .iter()
        .map(|&n| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .unwrap()
                .install(|| trace(&scene, &targets, &s, &|| {}))
        })
        .collect();
    for (k, w) in want.iter().take(2).enumerate() {
        let (w, got) = (w.as_ref().unwrap(), runs[0].maps[k].as_ref().unwrap());
        for (a, b) in [(&w.direct, &got.direct), (&w.indirect, &got.indirect)] {
            let max = a.iter().flatten().fold(0.0f64, |m, &x| m.max(x));
            assert!(max > 0.0, "shape {k}: nothing deposited");
            // Same random numbers and arithmetic: only the fixed-point rounding (≤ 2⁻²⁵ of
            // the reference deposit per deposit) and the f64 summation order differ.
            for (x, y) in a.iter().flatten().zip(b.iter().flatten()) {
                assert!((x - y).abs() <= 1e-6 * max, "shape {k}: {x} vs {y}");
            }
        }
        for r in &runs[1..] {
            let o = r.maps[k].as_ref().unwrap();
            assert_eq!(
                (&o.direct, &o.indirect),
                (&got.direct, &got.indirect),
                "thread count changed the result"
            );
        }
    }
    // The wavefront (packets or one ray per lane) and one path at a time, and another batch
    // size: the same paths, bit for bit, hence identical integer sums.
    let sampler = scene.light_sampler().unwrap();
    let fp = FixedPoint::new(&scene, &targets, s.paths, 0);
    let other_batches = LightTraceSettings { batch_size: 1_234, ..s };
    for (engine, s) in [(Engine::WavefrontRays, s), (Engine::Scalar, s), (Engine::Auto, other_batches)] {
        let o = trace_fixed(&scene, sampler, &targets, &s, &fp, &|| {}, engine, None, &crate::dist::Solo)
            .unwrap();
        for k in 0..2 {
            let (a, b) = (o.maps[k].as_ref().unwrap(), runs[0].maps[k].as_ref().unwrap());
            assert_eq!((&a.direct, &a.indirect), (&b.direct, &b.indirect), "{engine:?}");
        }
    }
}

#[test]
fn fixed_point_overflow_is_detected_and_traced_again() {
    // Every deposit of a closed emitting box into one texel; a unit 2⁴⁰ times too fine makes
    // each deposit saturate: the pass must report it and succeed at a coarser unit, with the
    // result of the normal scale.
    let inner = inward_box();
    let desc = SceneDesc {
        shapes: vec![shape(
            "box",
            inner.clone(),
            diffuse(0.5),
            Some(AreaEmitterDesc { radiance: Spectrum::splat(1.0) }),
        )],
        ..Default::default()
    };
    let scene = Scene::build(&desc).unwrap();
    let texel_area: Vec<f32> = (0..inner.triangle_count()).map(|_| inner.area() as f32).collect();
    let targets = [Some(IrradianceTarget { width: 1, height: 1, texel_area })];
    let s = LightTraceSettings { paths: 20_000, seed: 2, ..Default::default() };
    let sampler = scene.light_sampler().unwrap();
    let mut shift = 40;
    let mut tries = 0;
    let out = loop {
        tries += 1;
        let fp = FixedPoint::new(&scene, &targets, s.paths, shift);
        match trace_fixed(&scene, sampler, &targets, &s, &fp, &|| {}, Engine::Auto, None, &crate::dist::Solo)
        {
            Ok(out) => break out,
            Err(Stop::Cancelled) => unreachable!("no cancel flag"),
            Err(Stop::Rescale(bits)) => {
                assert!(bits >= 1);
                shift -= bits;
            }
        }
    };
    assert!(tries >= 2 && shift < 40 - 16, "overflow not detected (tries {tries}, shift {shift})");
    let want = trace(&scene, &targets, &s, &|| {});
    let (a, b) =
        (&out.maps[0].as_ref().unwrap().indirect[0][0], &want.maps[0].as_ref().unwrap().indirect[0][0]);
    assert!(*b > 0.0 && (a / b - 1.0).abs() < 1e-6, "{a} vs {b}");
}

#[test]
fn simd_generators_draw_the_scalar_numbers() {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        let stream = RngStream::new(9, RNG_STREAM);
        let mut scalar: Vec<Rng> = (0..W as u64).map(|i| stream.rng(i * 977)).collect();
        let mut state: [u64; W] = std::array::from_fn(|l| scalar[l].state);
        let inc: [u64; W] = std::array::from_fn(|l| scalar[l].inc);
        let mut mrng = Rng::new(4, 4, 4);
        for _ in 0..10_000 {
            let m = mrng.next_u32() & 0xff;
            // SAFETY: the CPU supports AVX2 (checked above).
            let got = unsafe { avx::next_f32_lanes(&mut state, &inc, m) };
            for (l, r) in scalar.iter_mut().enumerate() {
                if m & (1 << l) != 0 {
                    assert_eq!(got[l].to_bits(), r.next_f32().to_bits(), "lane {l}");
                }
                assert_eq!(state[l], r.state, "lane {l}: state");
            }
        }
    }
}

#[test]
fn bilinear_lanes_give_the_bits_of_texture_eval() {
    // `avx::bilinear_lanes` against `Texture::eval(uv) · INV_PI` for random images (1×1 to
    // 37×5, both wrap modes that index differently) and uvs inside, on and beyond the
    // borders, non-finite: the lanes it does are bit for bit the scalar values, every lane it
    // does is in the mask, and it does every lane whose four corners are inside the image.
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        use crate::image::Image;
        use crate::scene::desc::{BitmapDesc, FilterType, TextureDesc, WrapMode};
        use crate::texture::Texture;
        let mut rng = Rng::new(8, 8, 8);
        let mut done_total = 0;
        for (w, h) in [(1, 1), (2, 2), (1, 7), (5, 3), (37, 5), (64, 64)] {
            let data =
                (0..w * h).map(|_| Spectrum::rgb(rng.next_f32(), rng.next_f32(), rng.next_f32())).collect();
            let image = std::sync::Arc::new(Image { width: w, height: h, data });
            for wrap in [WrapMode::Clamp, WrapMode::Repeat] {
                // (the small images get a palette: `eval` reads its codes, the same values)
                let desc = BitmapDesc {
                    image: image.clone(),
                    filter: FilterType::Bilinear,
                    wrap,
                    path: "mem".into(),
                };
                let tex = Texture::new(&TextureDesc::Bitmap(desc));
                for round in 0..400 {
                    let mut uv = [[0.0f32; W]; 2];
                    for c in uv.iter_mut().flatten() {
                        *c = match rng.next_u32() % 8 {
                            0 => [f32::NAN, f32::INFINITY, -1e30, 1e30, 0.0, 1.0, -0.0]
                                [rng.next_u32() as usize % 7],
                            1 => (rng.next_u32() % 9) as f32 / 8.0, // texel corners and centres
                            2 => rng.next_f32() * 3.0 - 1.0,
                            _ => rng.next_f32(),
                        };
                    }
                    let m = if round % 4 == 0 { 0xff } else { rng.next_u32() & 0xff };
                    let mut kd = [[-1.0f32; W]; 3];
                    // SAFETY: the CPU supports AVX2 (checked above).
                    let done = unsafe { avx::bilinear_lanes(&image, &uv, m, &mut kd) };
                    assert_eq!(done & !m, 0, "only lanes of the mask");
                    for l in 0..W {
                        let (u, v) = (uv[0][l], uv[1][l]);
                        let (x, y) = ((u * w as f32 - 0.5).floor(), (v * h as f32 - 0.5).floor());
                        let inside = x >= 0.0 && x + 1.0 < w as f32 && y >= 0.0 && y + 1.0 < h as f32;
                        assert_eq!(
                            done >> l & 1 == 1,
                            m >> l & 1 == 1 && inside,
                            "lane {l} at ({u}, {v}), {w}×{h}"
                        );
                        if done >> l & 1 == 1 {
                            let want = tex.eval(Vec2::new(u, v)) * crate::math::INV_PI;
                            for c in 0..3 {
                                assert_eq!(kd[c][l].to_bits(), want[c].to_bits(), "lane {l} channel {c}");
                            }
                            done_total += 1;
                        } else {
                            assert!((0..3).all(|c| kd[c][l] == -1.0), "lanes not done are left alone");
                        }
                    }
                }
            }
        }
        assert!(done_total > 2_000, "the lanes were exercised ({done_total})");
    }
}

#[test]
fn simd_seeding_gives_the_scalar_generators() {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        let mut pick = Rng::new(6, 6, 6);
        for k in 0..200u64 {
            let stream = RngStream::new(k, pick.next_u32() as u64);
            // first indices: small, random and wrapping past 2⁶⁴
            let first = match k % 3 {
                0 => k,
                1 => ((pick.next_u32() as u64) << 32) | pick.next_u32() as u64,
                _ => u64::MAX - (k % 9),
            };
            let (mut state, mut inc) = ([0u64; W], [0u64; W]);
            // SAFETY: the CPU supports AVX2 (checked above).
            unsafe { avx::seed_lanes(stream.base(), first, &mut state, &mut inc) };
            for l in 0..W {
                let r = stream.rng(first.wrapping_add(l as u64));
                assert_eq!((state[l], inc[l]), (r.state, r.inc), "stream {k}, lane {l}");
            }
        }
    }
}

#[test]
fn i32_cells_with_spill_sum_exactly_like_i64() {
    // Random deposits into a few texels, including values that overflow a cell after a few
    // additions and values beyond i32: the cell + spill sums equal plain i64 sums; in a `Vec`
    // and in a part of a shared (huge-page advised) mapping.
    cells_sum_exactly_like_i64(Cells::new(3 * 4));
    let mut parts = zeroed::Zeroed::many(&[1 << 20, 3 * 4], true);
    let fine = parts.pop().expect("two parts");
    assert_eq!(fine.is_mapped(), cfg!(target_os = "linux"), "4 MiB of maps share a mapping on Linux");
    cells_sum_exactly_like_i64(Cells { fine, spill: Vec::new() });
}

#[test]
fn zeroed_maps_are_zero_disjoint_and_writable() {
    // Maps of a shared mapping (more than one huge page in all) and of `Vec`s (less, or not
    // asked for): all zero at first, each one's writes seen in it and in no other.
    let lens = [5, 0, 700_000, 17, 1];
    for (huge, lens) in [(true, &lens[..]), (false, &lens[..]), (true, &lens[..1])] {
        let mut maps = zeroed::Zeroed::many(lens, huge);
        let mapped = huge && lens.len() > 1 && cfg!(target_os = "linux");
        assert_eq!(maps.len(), lens.len());
        for (m, &n) in maps.iter().zip(lens) {
            assert_eq!(m.len(), n);
            assert!(m.iter().all(|&x| x == 0), "zeroed");
            assert_eq!(m.is_mapped(), mapped, "huge {huge}, lens {lens:?}");
        }
        for (k, m) in maps.iter_mut().enumerate() {
            for (j, x) in m.iter_mut().enumerate() {
                *x = (k as i32 + 1) * 1_000_000 + j as i32 % 1000;
            }
        }
        for (k, m) in maps.iter().enumerate() {
            assert!(m.iter().enumerate().all(|(j, &x)| x == (k as i32 + 1) * 1_000_000 + j as i32 % 1000));
        }
    }
}

fn cells_sum_exactly_like_i64(mut cells: Cells) {
    let mut want = [0i64; 12];
    let mut rng = Rng::new(5, 1, 0);
    let mut spilled = false;
    for n in 0..20_000u32 {
        let i = 3 * (rng.next_u32() as usize % 4);
        let scale = [1i64 << 8, 1 << 24, 1 << 30, 1 << 40][n as usize % 4];
        let v: [i64; 3] = std::array::from_fn(|_| {
            let x = (rng.next_f32() as f64 * scale as f64) as i64;
            if rng.next_f32() < 0.3 { -x } else { x }
        });
        cells.add(i, v);
        for c in 0..3 {
            want[i + c] += v[c];
        }
        spilled |= !cells.spill.is_empty();
    }
    assert!(spilled, "the test must exercise the spill map");
    for (j, w) in want.iter().enumerate() {
        assert_eq!(cells.get(j), *w, "channel {j}");
    }
}

#[test]
fn without_direct_deposits_the_indirect_map_is_unchanged() {
    // Same scene as the furnace-like box test: first hits not deposited, direct map empty,
    // indirect map bitwise that of the full pass (same paths and random numbers), for 1 and 2
    // threads.
    let inner = inward_box();
    let light = {
        let mut m = floor_quad(0.3);
        for p in &mut m.positions {
            *p = Vec3::new(p.x, 0.99, p.z);
        }
        m.indices = vec![[0, 2, 1], [0, 3, 2]];
        m
    };
    let desc = SceneDesc {
        shapes: vec![
            shape("box", inner.clone(), diffuse(0.6), None),
            shape(
                "light",
                light,
                diffuse(0.0),
                Some(AreaEmitterDesc { radiance: Spectrum::rgb(1.0, 2.0, 3.0) }),
            ),
        ],
        ..Default::default()
    };
    let scene = Scene::build(&desc).unwrap();
    let n_tris = inner.triangle_count();
    let targets = [Some(IrradianceTarget { width: 4, height: 4, texel_area: vec![0.5; n_tris] }), None];
    let full = LightTraceSettings { paths: 100_000, batch_size: 9_000, seed: 7, ..Default::default() };
    let want = trace(&scene, &targets, &full, &|| {});
    let wm = want.maps[0].as_ref().unwrap();
    assert!(wm.direct.iter().flatten().any(|&x| x > 0.0) && wm.indirect.iter().flatten().any(|&x| x > 0.0));
    for threads in [1, 2] {
        let s = LightTraceSettings { direct: false, ..full };
        let got = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| trace(&scene, &targets, &s, &|| {}));
        let m = got.maps[0].as_ref().unwrap();
        assert!(m.direct.is_empty());
        assert_eq!((m.width, m.height), (4, 4));
        assert_eq!(m.indirect, wm.indirect, "{threads} threads");
    }
}

/// The engines on a scene behind the BVH: a finely tessellated, textured, two-sided sphere
/// (vertex normals, uvs: thousands of triangles) over a floor, under an area light. The
/// wavefront through `Accel::intersect8` (the BVH's interleaved streams), the wavefront with
/// one `intersect_hit` per lane and one path at a time trace the same paths: identical integer
/// sums on both targets.
#[test]
fn engines_agree_bit_for_bit_on_a_mesh_behind_the_bvh() {
    use crate::image::Image;
    use crate::scene::desc::{BitmapDesc, FilterType, WrapMode};
    let img = Image {
        width: 8,
        height: 8,
        data: (0..64).map(|i| Spectrum::rgb(0.15 + 0.01 * i as f32, 0.6, 0.85 - 0.01 * i as f32)).collect(),
    };
    let tex = TextureDesc::Bitmap(BitmapDesc {
        image: std::sync::Arc::new(img),
        filter: FilterType::Bilinear,
        wrap: WrapMode::Repeat,
        path: "ball.exr".into(),
    });
    let mut ball = crate::geometry::shapes::sphere_mesh(64, 32);
    for p in &mut ball.positions {
        *p = *p * 0.4 + Vec3::new(0.1, 0.5, -0.1);
    }
    let n_ball = ball.indices.len();
    assert!(n_ball > 2000, "{n_ball} triangles");
    let v = Vec3::new;
    let light = TriangleMesh {
        positions: vec![v(-0.3, 1.6, -0.3), v(0.3, 1.6, -0.3), v(0.3, 1.6, 0.3), v(-0.3, 1.6, 0.3)],
        normals: vec![],
        uvs: vec![],
        indices: vec![[0, 1, 2], [0, 2, 3]],
    };
    let desc = SceneDesc {
        shapes: vec![
            shape("floor", floor_quad(1.5), diffuse(0.6), None),
            shape("ball", ball, BsdfDesc::TwoSided(Box::new(BsdfDesc::Diffuse { reflectance: tex })), None),
            shape(
                "light",
                light,
                diffuse(0.0),
                Some(AreaEmitterDesc { radiance: Spectrum::rgb(6.0, 5.0, 4.0) }),
            ),
        ],
        ..Default::default()
    };
    let built = Scene::build(&desc).unwrap();
    assert!(
        matches!(built.accel(), crate::accel::Accel::Split(_)),
        "floor and light apart, the ball behind a BVH"
    );
    engines_agree_on(&built, n_ball);
    engines_agree_on(&built.with_plain_bvh(), n_ball);
}

/// The three engines' maps on the floor/ball/light scene of
/// [`engines_agree_bit_for_bit_on_a_mesh_behind_the_bvh`] are equal, bit for bit.
fn engines_agree_on(scene: &Scene, n_ball: usize) {
    let targets = [
        Some(target(8, 1.5)),
        Some(IrradianceTarget { width: 16, height: 16, texel_area: vec![0.004; n_ball] }),
        None,
    ];
    let s =
        LightTraceSettings { paths: 60_000, batch_size: 5_000, rr_depth: 2, seed: 5, ..Default::default() };
    let sampler = scene.light_sampler().unwrap();
    let fp = FixedPoint::new(scene, &targets, s.paths, 0);
    let runs: Vec<LightTraceOutput> = [Engine::Auto, Engine::WavefrontRays, Engine::Scalar]
        .into_iter()
        .map(|e| trace_fixed(scene, sampler, &targets, &s, &fp, &|| {}, e, None, &crate::dist::Solo).unwrap())
        .collect();
    for k in 0..2 {
        let a = runs[0].maps[k].as_ref().unwrap();
        let lit = a.indirect.iter().flatten().filter(|&&x| x > 0.0).count();
        assert!(lit > 10, "shape {k}: indirect light reaches {lit} texels");
        for (e, r) in runs.iter().enumerate().skip(1) {
            let b = r.maps[k].as_ref().unwrap();
            assert_eq!((&a.direct, &a.indirect), (&b.direct, &b.indirect), "shape {k}, engine {e}");
        }
    }
}

/// Path batches split over 2 and 3 simulated processes (and more ranks than batches): every
/// rank gets the one-process maps bit for bit, direct and indirect.
#[test]
fn split_pass_matches_for_any_process_count() {
    // a floor inside a closed box, lit by a point light: direct and indirect deposits
    let desc = SceneDesc {
        shapes: vec![
            shape("floor", floor_quad(0.9), diffuse(0.5), None),
            shape("box", inward_box(), diffuse(0.7), None),
        ],
        emitters: vec![EmitterDesc::Point {
            position: Vec3::new(0.1, 0.8, 0.2),
            intensity: Spectrum::splat(3.0),
        }],
        ..Default::default()
    };
    let scene = Scene::build(&desc).unwrap();
    let targets = [Some(target(8, 0.9)), None];
    let s = LightTraceSettings { paths: 50_000, seed: 4, batch_size: 7_000, ..Default::default() };
    let one = trace(&scene, &targets, &s, &|| {});
    let m = one.maps[0].as_ref().unwrap();
    assert!(m.indirect.iter().any(|t| t[0] > 0.0) && m.direct.iter().any(|t| t[0] > 0.0));
    for n in [2, 3, 9] {
        let all =
            crate::dist::ThreadComm::run(n, |c| trace_split(&scene, &targets, &s, &|| {}, None, c).unwrap());
        for o in &all {
            let r = o.maps[0].as_ref().unwrap();
            assert_eq!(r.direct, m.direct, "{n} ranks");
            assert_eq!(r.indirect, m.indirect, "{n} ranks");
            assert_eq!((o.paths, o.nonfinite), (one.paths, one.nonfinite));
        }
    }
}

#[test]
fn cancel_flag_stops_the_pass_and_unset_changes_nothing() {
    use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
    let desc = SceneDesc {
        shapes: vec![
            shape("floor", floor_quad(1.0), diffuse(0.5), None),
            shape(
                "box",
                inward_box(),
                diffuse(0.5),
                Some(AreaEmitterDesc { radiance: Spectrum::splat(1.0) }),
            ),
        ],
        ..Default::default()
    };
    let scene = Scene::build(&desc).unwrap();
    let targets = [Some(target(4, 1.0)), None];
    let s = LightTraceSettings { paths: 200_000, seed: 3, batch_size: 1_000, ..Default::default() };
    // never set: the same bits as `trace`
    let flag = AtomicBool::new(false);
    let a = trace_cancellable(&scene, &targets, &s, &|| {}, Some(&flag)).expect("not cancelled");
    let b = trace(&scene, &targets, &s, &|| {});
    assert_eq!(a.maps[0].as_ref().unwrap().direct, b.maps[0].as_ref().unwrap().direct);
    assert_eq!(a.maps[0].as_ref().unwrap().indirect, b.maps[0].as_ref().unwrap().indirect);
    assert!(a.maps[0].as_ref().unwrap().indirect.iter().all(|t| t[0] > 0.0), "light reached every texel");
    // set after the first batch: the pass stops within a batch per worker and gives no maps
    let batches = AtomicUsize::new(0);
    let on_batch = || {
        batches.fetch_add(1, Ordering::Relaxed);
        flag.store(true, Ordering::Relaxed);
    };
    assert!(trace_cancellable(&scene, &targets, &s, &on_batch, Some(&flag)).is_none());
    let done = batches.load(Ordering::Relaxed);
    let workers = rayon::current_num_threads().clamp(1, MAX_WORKERS);
    assert!(done <= workers, "{done} batches traced after the flag was set (workers {workers})");
}
