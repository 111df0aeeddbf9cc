//! How the de-lighting's time and memory grow with the triangle count and the number of views
//! (issue 17, item 5). Synthetic by construction: the bundled Cornell box with its tall box
//! replaced by an icosphere of `LEVELS` subdivisions (20 · 4^LEVELS triangles: 6 → 81 920,
//! 7 → 327 680, 8 → 1 310 720; radius 0.4, standing on the floor, constant albedo, no UVs), `VIEWS`
//! 256² cameras on two rings around it (heights alternating), the views rendered by Opal's path
//! tracer at `SPP` (default 4) samples per pixel. Then `delight` with `ITERATIONS` (default 2)
//! iterations, every other setting the default (texture resolution from the cameras, light paths
//! from the texel count and the target noise). Prints the triangle count, total texels, the stage
//! clocks and the peak resident memory (`VmHWM` of /proc/self/status) before and after the
//! de-lighting. Run one configuration per process so the peak is that configuration's:
//!
//! `cargo run --release -p opal-inverse --example delight_scale -- LEVELS VIEWS [ITERATIONS] [SPP]`
//!
//! Numbers: docs/performance.md, "De-lighting: growth with triangles and views".

use opal::geometry::shapes::icosphere;
use opal::integrator::path::{PathSettings, render};
use opal::math::{Mat4, Vec3};
use opal::scene::desc::{BsdfDesc, SensorDesc, ShapeDesc, TextureDesc};
use opal::scene::{Scene, load_mitsuba_xml};
use opal::spectrum::Spectrum;
use opal_inverse::delight::views::View;
use opal_inverse::delight::{DelightSettings, delight};
use std::path::PathBuf;

/// Peak resident set size in MB (Linux `VmHWM`), or NaN.
fn peak_rss_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1).and_then(|v| v.parse::<f64>().ok()))
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let arg = |i: usize, d: usize| args.get(i).map_or(d, |a| a.parse().expect("integer argument"));
    let (levels, n_views, iterations, spp) = (arg(1, 6), arg(2, 8), arg(3, 2), arg(4, 4) as u32);
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../opal/tests/data/cbox/scene.xml");
    let mut desc = load_mitsuba_xml(&p, &[]).expect("bundled Cornell box");
    desc.shapes.retain(|s| s.id != "tall_box");
    let (centre, radius) = (Vec3::new(-0.3, -0.6, -0.25), 0.4);
    let mut mesh = icosphere(levels);
    for v in &mut mesh.positions {
        *v = centre + *v * radius;
    }
    let tris = mesh.indices.len();
    desc.shapes.push(ShapeDesc {
        id: "ball".into(),
        mesh,
        bsdf: BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(Spectrum::rgb(0.6, 0.5, 0.4)) },
        emitter: None,
        origin: None,
    });
    desc.sensors = (0..n_views)
        .map(|k| {
            let a = std::f32::consts::TAU * k as f32 / n_views as f32;
            let o = Vec3::new(0.85 * a.cos(), if k % 2 == 0 { -0.1 } else { 0.4 }, 0.85 * a.sin() + 0.1);
            let mut to_world = Mat4::look_at_rh(o, centre, Vec3::Y).inverse();
            to_world *= Mat4::from_scale(Vec3::new(-1.0, 1.0, -1.0));
            SensorDesc {
                id: format!("v{k:02}"),
                to_world,
                fov_x_deg: 70.0,
                width: 256,
                height: 256,
                near_clip: 1e-3,
                far_clip: 1e3,
                spp: None,
            }
        })
        .collect();
    let scene = Scene::build(&desc).expect("scene builds");
    let integ = desc.integrator.clone().unwrap_or_default();
    let t0 = std::time::Instant::now();
    let views: Vec<View> = scene
        .cameras
        .iter()
        .enumerate()
        .map(|(k, cam)| {
            let ps = PathSettings {
                spp,
                max_depth: integ.max_depth,
                rr_depth: integ.rr_depth,
                hide_emitters: false,
                seed: k as u64,
            };
            View {
                name: cam.id.clone(),
                path: format!("{}.exr", cam.id).into(),
                camera: cam.clone(),
                image: render(&scene, k, &ps, &|| {}).image,
                bad_pixels: 0,
            }
        })
        .collect();
    let rss0 = peak_rss_mb();
    println!(
        "triangles {tris} views {n_views}: rendered in {:.1} s, peak RSS so far {rss0:.0} MB",
        t0.elapsed().as_secs_f64()
    );
    drop(scene);
    let s = DelightSettings { iterations, tolerance: 0.0, ..Default::default() };
    let r = delight(&desc, &views, &s, &|_| {}).expect("delight");
    let texels: usize = r.objects.iter().map(|o| o.atlas.width * o.atlas.height).sum();
    let ball = r.objects.iter().find(|o| o.id == "ball").expect("ball recovered");
    let stages: Vec<String> = r.timings.iter().map(|(k, v)| format!("{k} {v:.1}")).collect();
    println!(
        "triangles {tris} views {n_views} iterations {}: texels {texels} (ball {}², {} charts), light paths {}, \
         peak RSS {:.0} MB; stages (wall s): {}",
        r.iterations.len(),
        ball.atlas.width,
        ball.atlas.charts,
        r.light_paths,
        peak_rss_mb(),
        stages.join(", ")
    );
}
