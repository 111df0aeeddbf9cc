//! Measures the de-lighting unwrap (`atlas::build_atlas` without kept UVs) on displaced
//! icospheres (20 480 and 81 920 triangles) and optionally on PLY meshes: charts, texel
//! utilisation (covered texels / atlas texels), angle/area distortion, UV overlaps, time.
//! With `--dump DIR` it also writes each mesh as raw little-endian `f32` positions and `u32`
//! indices (`NAME.pos`, `NAME.idx`) for comparisons with other unwrappers.
//!
//! Run: `cargo run --release -p opal-inverse --example unwrap_stats -- [--res N] [--dump DIR] [MESH.ply…]`

use opal::geometry::TriangleMesh;
use opal_inverse::delight::atlas::{self, quality, testmesh};
use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

fn main() {
    let mut args = std::env::args().skip(1);
    let (mut res, mut dump, mut files) = (1024usize, None::<PathBuf>, Vec::new());
    while let Some(a) = args.next() {
        match a.as_str() {
            "--res" => res = args.next().and_then(|v| v.parse().ok()).expect("--res N"),
            "--dump" => dump = args.next().map(PathBuf::from),
            _ => files.push(PathBuf::from(a)),
        }
    }
    let mut meshes: Vec<(String, TriangleMesh)> = vec![
        ("sphere20k".into(), testmesh::displaced_icosphere(5, 0.07)),
        ("sphere82k".into(), testmesh::displaced_icosphere(6, 0.07)),
    ];
    for f in files {
        let m = opal::geometry::ply::read_ply(&f).expect("read ply");
        meshes.push((f.file_stem().unwrap().to_string_lossy().into_owned(), m));
    }
    println!(
        "mesh\ttris\tres\tcharts\tutil\tangle_mean\tangle_p95\tarea_mean\tarea_p95\tflipped\toverlap\ttime_s"
    );
    for (name, m) in &meshes {
        if let Some(d) = &dump {
            let mut f = std::fs::File::create(d.join(format!("{name}.pos"))).unwrap();
            for p in &m.positions {
                for c in p.to_array() {
                    f.write_all(&c.to_le_bytes()).unwrap();
                }
            }
            let mut f = std::fs::File::create(d.join(format!("{name}.idx"))).unwrap();
            for t in &m.indices {
                for c in t {
                    f.write_all(&c.to_le_bytes()).unwrap();
                }
            }
        }
        let mut bare = m.clone();
        bare.uvs.clear();
        let t0 = Instant::now();
        let a = atlas::build_atlas(&bare, res, false).expect("atlas");
        let dt = t0.elapsed().as_secs_f64();
        if let Some(dd) = &dump {
            // covered texels grey by chart, owned gutter dark, free black (PGM)
            let mut img = format!("P5 {} {} 255\n", a.width, a.height).into_bytes();
            for i in 0..a.width * a.height {
                let c = a.texel_chart(i);
                img.push(if c != u32::MAX {
                    100 + (c * 37 % 150) as u8
                } else if a.texel_owner[i] != u32::MAX {
                    40
                } else {
                    0
                });
            }
            std::fs::write(dd.join(format!("{name}.pgm")), img).unwrap();
        }
        let d = quality::distortion(&a.mesh);
        let st = atlas::curved::unwrap(&bare, res).map(|r| r.3).unwrap_or_default();
        eprintln!("{name}: {st:?}");
        let (ov, _) = quality::overlaps(&a.mesh, 4096);
        println!(
            "{name}\t{}\t{res}\t{}\t{:.3}\t{:.3}\t{:.3}\t{:.3}\t{:.3}\t{}\t{ov}\t{dt:.2}",
            m.triangle_count(),
            a.charts,
            a.utilisation(),
            d.angle_mean,
            d.angle_p95,
            d.area_mean,
            d.area_p95,
            d.flipped
        );
    }
}
