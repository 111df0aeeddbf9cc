//! Times loading a ~1 M-triangle mesh through `load_mitsuba_xml` as OBJ (54 MB text, with
//! uvs, normals recomputed) and as binary PLY (18 MB), next to `tobj`'s bare parse of the
//! same OBJ (the floor for the OBJ path). Medians of 3 runs; numbers in docs/performance.md.
//!
//! ```text
//! cargo run -p opal --example scene_load_timing
//! ```
use std::fmt::Write;
use std::time::Instant;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let n = 708usize; // (n+1)² vertices, 2n² ≈ 1.0 M triangles
    let dir = tempfile::tempdir().unwrap();
    let id = |i: usize, j: usize| j * (n + 1) + i + 1;
    let z = |i: usize, j: usize| ((i * j) % 7) as f32 * 1e-3;
    let mut obj = String::new();
    for j in 0..=n {
        for i in 0..=n {
            writeln!(obj, "v {} {} {}", i as f32 / n as f32, j as f32 / n as f32, z(i, j)).unwrap();
        }
    }
    for j in 0..=n {
        for i in 0..=n {
            writeln!(obj, "vt {} {}", i as f32 / n as f32, j as f32 / n as f32).unwrap();
        }
    }
    for j in 0..n {
        for i in 0..n {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            writeln!(obj, "f {a}/{a} {b}/{b} {c}/{c} {d}/{d}").unwrap();
        }
    }
    std::fs::write(dir.path().join("big.obj"), &obj).unwrap();
    let mut ply = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\n\
         property float z\nproperty float u\nproperty float v\nelement face {}\n\
         property list uchar int vertex_indices\nend_header\n",
        (n + 1) * (n + 1),
        n * n
    )
    .into_bytes();
    for j in 0..=n {
        for i in 0..=n {
            let (u, v) = (i as f32 / n as f32, j as f32 / n as f32);
            for x in [u, v, z(i, j), u, v] {
                ply.extend(x.to_le_bytes());
            }
        }
    }
    for j in 0..n {
        for i in 0..n {
            ply.push(4);
            for k in [id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)] {
                ply.extend(((k - 1) as i32).to_le_bytes());
            }
        }
    }
    std::fs::write(dir.path().join("big.ply"), &ply).unwrap();
    let xml =
        r#"<scene version="3.0.0"><shape type="$t"><string name="filename" value="big.$t"/></shape></scene>"#;
    std::fs::write(dir.path().join("scene.xml"), xml).unwrap();
    println!("OBJ {:.0} MB, PLY {:.0} MB", obj.len() as f64 / 1e6, ply.len() as f64 / 1e6);
    for t in ["obj", "ply"] {
        let mut times = Vec::new();
        let mut tris = 0;
        for _ in 0..3 {
            let t0 = Instant::now();
            let s = opal::scene::load_mitsuba_xml(&dir.path().join("scene.xml"), &[("t".into(), t.into())])
                .unwrap();
            times.push(t0.elapsed().as_secs_f64());
            tris = s.shapes[0].mesh.triangle_count();
        }
        println!("load_mitsuba_xml {t}: {tris} triangles, median {:.2} s", median(times));
    }
    let mut times = Vec::new();
    for _ in 0..3 {
        let t0 = Instant::now();
        let text = std::fs::read_to_string(dir.path().join("big.obj")).unwrap();
        #[allow(clippy::needless_update)]
        let opts = tobj::LoadOptions { single_index: true, triangulate: true, ..Default::default() };
        let mut r = std::io::BufReader::new(text.as_bytes());
        let (models, _) =
            tobj::load_obj_buf(&mut r, &opts, |_| Err(tobj::LoadError::GenericFailure)).unwrap();
        assert!(!models.is_empty());
        times.push(t0.elapsed().as_secs_f64());
    }
    println!("tobj alone (same OBJ): median {:.2} s", median(times));
}
