//! Error analysis of the de-lighting (scratch tool): the irradiance of one object's texels in the
//! scene with its *true* materials, by light tracing (indirect and direct maps per texel /
//! coverage), written as `<out>_ei.exr` and `<out>_ed_lt.exr`.
//!
//! Run: `cargo run -p opal-inverse --example oracle_irradiance -- SCENE.xml SHAPE RES PATHS OUT`

use opal::integrator::light_tracer::{self, IrradianceTarget, LightTraceSettings};
use opal::scene::{Scene, load_mitsuba_xml};
use opal_inverse::delight::atlas;
use std::path::PathBuf;

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let p = PathBuf::from(&a[1]);
    let shape = &a[2];
    let res: usize = a[3].parse().unwrap();
    let paths: u64 = a[4].parse().unwrap();
    let out = &a[5];
    let mut desc = load_mitsuba_xml(&p, &[]).expect("scene");
    let k = desc.shapes.iter().position(|s| &s.id == shape).expect("shape");
    let at = atlas::build_atlas(&desc.shapes[k].mesh, res, true).expect("atlas");
    desc.shapes[k].mesh = at.mesh.clone();
    let targets: Vec<Option<IrradianceTarget>> = (0..desc.shapes.len())
        .map(|j| {
            (j == k).then(|| IrradianceTarget {
                width: at.width,
                height: at.height,
                texel_area: at.texel_area.clone(),
            })
        })
        .collect();
    let scene = Scene::build(&desc).expect("scene builds");
    let s = LightTraceSettings {
        paths,
        seed: 12345,
        batch_size: 1 << 20,
        max_depth: -1,
        rr_depth: 5,
        direct: true,
    };
    let t0 = std::time::Instant::now();
    let o = light_tracer::trace(&scene, &targets, &s, &|| {});
    let m = o.maps[k].as_ref().unwrap();
    for (what, v) in [("ei", &m.indirect), ("ed_lt", &m.direct)] {
        let mut img = opal::image::Image::new(at.width, at.height);
        for (i, d) in img.data.iter_mut().enumerate() {
            let c = at.coverage[i].max(1.0 / 16.0) as f64;
            *d = opal::spectrum::Spectrum::rgb(
                (v[i][0] / c) as f32,
                (v[i][1] / c) as f32,
                (v[i][2] / c) as f32,
            );
        }
        let f = std::fs::File::create(format!("{out}_{what}.exr")).unwrap();
        opal::image::write::write_exr(&img, std::io::BufWriter::new(f)).unwrap();
    }
    println!("{paths} paths in {:.1} s", t0.elapsed().as_secs_f64());
}
