//! Writes the "scanned-object room" benchmark scene: the bundled Cornell box
//! (`tests/data/cbox`) with the tall box replaced by a displaced icosphere standing where the
//! box stands, like a scanned rock or statue.
//!
//! * Mesh: an icosahedron subdivided 6 times (20 · 4⁶ = 81 920 triangles) on the unit sphere,
//!   each vertex moved radially by `1 + A · noise(p)` with `noise` four octaves of smooth
//!   value noise in `[-1, 1]` (`A = 0.07`), then scaled to a 0.6 × 1.2 × 0.6 egg (the tall
//!   box's footprint and height) centred on the box's footprint, its lowest point on the floor
//!   (`y = −1`).
//! * UVs: spherical (`u` = longitude / 2π, `v` = colatitude / π); triangles across the
//!   longitude seam get vertex copies with `u + 1` (the texture wraps with `repeat`); pole
//!   vertices get one copy per triangle with `u` = the mean of the other two corners.
//!   Smooth vertex normals (angle-weighted, computed before the seam split so both sides of
//!   the seam have the same normal).
//! * Written as `meshes/scan.ply` (binary little-endian: `x y z nx ny nz u v`,
//!   `vertex_indices`) and `textures/scan_albedo.png` (512², 8-bit sRGB: a stone-like
//!   checker modulated by noise), bound as the `diffuse` reflectance of the shape (`bitmap`,
//!   bilinear, repeat). The rest of `scene.xml` (8 sensors at 256², `path` integrator with
//!   `max_depth` 16, the other shapes and the light) is the bundled file unchanged.
//!
//! Everything is deterministic (no random state; the noise is a hash of the lattice point):
//! same output bytes on every run. The scene loads in Opal (`opal render`) and in Mitsuba 3
//! (`mi.load_file`); `bench/render_vs_mitsuba.sh scan` uses it.
//!
//! Run: `cargo run --release -p opal --example make_scan_room -- OUT_DIR` (writes
//! `OUT_DIR/scene.xml`, `OUT_DIR/meshes/*`, `OUT_DIR/textures/*`).

use opal::math::{Vec2, Vec3};
use std::collections::HashMap;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Subdivision levels of the icosahedron (81 920 triangles).
const LEVELS: usize = 6;
/// Displacement amplitude relative to the radius.
const AMPLITUDE: f32 = 0.07;
/// Texture size in texels.
const TEX: u32 = 512;

/// Integer hash of a lattice point to `[-1, 1]`.
fn lattice(x: i32, y: i32, z: i32, seed: u32) -> f32 {
    let mut h = (x as u32).wrapping_mul(0x8da6_b343)
        ^ (y as u32).wrapping_mul(0xd816_3841)
        ^ (z as u32).wrapping_mul(0xcb1a_b31f)
        ^ seed.wrapping_mul(0x2545_f491);
    h ^= h >> 15;
    h = h.wrapping_mul(0x2c1b_3c6d);
    h ^= h >> 12;
    h = h.wrapping_mul(0x297a_2d39);
    h ^= h >> 15;
    (h >> 8) as f32 / (1u32 << 23) as f32 - 1.0
}

/// Smooth 3D value noise in `[-1, 1]` (quintic interpolation of lattice values).
fn value_noise(p: Vec3, seed: u32) -> f32 {
    let f = p.floor();
    let (ix, iy, iz) = (f.x as i32, f.y as i32, f.z as i32);
    let t = p - f;
    let s = |x: f32| x * x * x * (x * (x * 6.0 - 15.0) + 10.0);
    let (sx, sy, sz) = (s(t.x), s(t.y), s(t.z));
    let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
    let mut c = [0.0f32; 4];
    for (k, ck) in c.iter_mut().enumerate() {
        let (dy, dz) = ((k & 1) as i32, (k >> 1) as i32);
        *ck = lerp(lattice(ix, iy + dy, iz + dz, seed), lattice(ix + 1, iy + dy, iz + dz, seed), sx);
    }
    lerp(lerp(c[0], c[1], sy), lerp(c[2], c[3], sy), sz)
}

/// `octaves` octaves of value noise (frequency ×2, amplitude ×0.5), normalised to `[-1, 1]`.
fn fbm(p: Vec3, octaves: u32, seed: u32) -> f32 {
    let (mut sum, mut amp, mut norm, mut freq) = (0.0, 1.0, 0.0, 1.0);
    for o in 0..octaves {
        sum += amp * value_noise(p * freq, seed + o);
        norm += amp;
        amp *= 0.5;
        freq *= 2.0;
    }
    sum / norm
}

/// Angle-weighted vertex normals.
fn vertex_normals(pos: &[Vec3], tris: &[[u32; 3]]) -> Vec<Vec3> {
    let mut acc = vec![Vec3::ZERO; pos.len()];
    for t in tris {
        let v = t.map(|i| pos[i as usize]);
        let n = (v[1] - v[0]).cross(v[2] - v[0]).normalize();
        for j in 0..3 {
            let d0 = (v[(j + 1) % 3] - v[j]).normalize();
            let d1 = (v[(j + 2) % 3] - v[j]).normalize();
            acc[t[j] as usize] += n * d0.dot(d1).clamp(-1.0, 1.0).acos();
        }
    }
    acc.into_iter().map(|n| n.normalize()).collect()
}

/// The displaced, placed mesh with normals and seam-split spherical UVs.
struct ScanMesh {
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
    uvs: Vec<Vec2>,
    indices: Vec<[u32; 3]>,
}

fn scan_mesh() -> ScanMesh {
    let sphere = opal::geometry::shapes::icosphere(LEVELS);
    let (dirs, tris) = (sphere.positions, sphere.indices);
    // Footprint of the tall box (cbox/meshes/tall_box.obj): centre of its four floor corners.
    let centre_xz = Vec2::new(-0.33, -0.28);
    let half = Vec3::new(0.3, 0.6, 0.3);
    let mut pos: Vec<Vec3> =
        dirs.iter().map(|&d| d * (1.0 + AMPLITUDE * fbm(d * 2.5 + 3.1, 4, 7)) * half).collect();
    let ymin = pos.iter().map(|p| p.y).fold(f32::INFINITY, f32::min);
    for p in &mut pos {
        *p += Vec3::new(centre_xz.x, -1.0 - ymin, centre_xz.y);
    }
    let nrm = vertex_normals(&pos, &tris);
    // Spherical UVs of the undisplaced direction; y is up.
    let uv_of = |d: Vec3| {
        let u = d.z.atan2(d.x) / (2.0 * std::f32::consts::PI);
        Vec2::new(if u < 0.0 { u + 1.0 } else { u }, d.y.clamp(-1.0, 1.0).acos() / std::f32::consts::PI)
    };
    let is_pole = |d: Vec3| d.x.abs() < 1e-6 && d.z.abs() < 1e-6;
    let mut out = ScanMesh { positions: vec![], normals: vec![], uvs: vec![], indices: vec![] };
    let mut copies: HashMap<(u32, u32, u32), u32> = HashMap::new();
    for t in &tris {
        let mut uv = t.map(|i| uv_of(dirs[i as usize]));
        let poles = t.map(|i| is_pole(dirs[i as usize]));
        let others: Vec<f32> = (0..3).filter(|&j| !poles[j]).map(|j| uv[j].x).collect();
        let (lo, hi) =
            others.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |a, &u| (a.0.min(u), a.1.max(u)));
        let wrap = hi - lo > 0.5;
        for j in 0..3 {
            if wrap && !poles[j] && uv[j].x < 0.5 {
                uv[j].x += 1.0;
            }
        }
        for j in 0..3 {
            if poles[j] {
                let others: Vec<f32> = (0..3).filter(|&k| !poles[k]).map(|k| uv[k].x).collect();
                uv[j].x = others.iter().sum::<f32>() / others.len() as f32;
            }
        }
        let idx = std::array::from_fn(|j| {
            let v = t[j];
            *copies.entry((v, uv[j].x.to_bits(), uv[j].y.to_bits())).or_insert_with(|| {
                out.positions.push(pos[v as usize]);
                out.normals.push(nrm[v as usize]);
                out.uvs.push(uv[j]);
                (out.positions.len() - 1) as u32
            })
        });
        out.indices.push(idx);
    }
    out
}

fn write_ply(path: &Path, m: &ScanMesh) -> std::io::Result<()> {
    let mut w = std::io::BufWriter::new(std::fs::File::create(path)?);
    write!(
        w,
        "ply\nformat binary_little_endian 1.0\ncomment opal make_scan_room: displaced icosphere\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\nproperty float u\nproperty float v\n\
         element face {}\nproperty list uchar uint vertex_indices\nend_header\n",
        m.positions.len(),
        m.indices.len()
    )?;
    for i in 0..m.positions.len() {
        let (p, n, uv) = (m.positions[i], m.normals[i], m.uvs[i]);
        for f in [p.x, p.y, p.z, n.x, n.y, n.z, uv.x, uv.y] {
            w.write_all(&f.to_le_bytes())?;
        }
    }
    for t in &m.indices {
        w.write_all(&[3u8])?;
        for i in t {
            w.write_all(&i.to_le_bytes())?;
        }
    }
    w.flush()
}

/// Stone-like albedo: a 16 × 8 checker of two tones, modulated by noise (sRGB 8-bit).
fn write_texture(path: &Path) -> image::ImageResult<()> {
    let img = image::RgbImage::from_fn(TEX, TEX, |x, y| {
        let (u, v) = ((x as f32 + 0.5) / TEX as f32, (y as f32 + 0.5) / TEX as f32);
        let check = ((u * 16.0) as u32 + (v * 8.0) as u32).is_multiple_of(2);
        let base = if check { Vec3::new(0.62, 0.55, 0.45) } else { Vec3::new(0.38, 0.40, 0.42) };
        // Periodic in u (noise on a circle) so the seam of the sphere does not show.
        let a = 2.0 * std::f32::consts::PI * u;
        let n = fbm(Vec3::new(a.cos() * 3.0, a.sin() * 3.0, v * 6.0), 4, 99);
        let c = base * (1.0 + 0.35 * n);
        let to8 = |x: f32| (x.clamp(0.0, 1.0) * 255.0).round() as u8;
        image::Rgb([to8(c.x), to8(c.y), to8(c.z)])
    });
    img.save(path)
}

/// The bundled scene with the tall box's `<shape>` element replaced by the scan.
fn scene_xml(src: &str) -> String {
    let start = src.find("<shape type=\"obj\" id=\"tall_box\">").expect("bundled scene has the tall box");
    let end = start + src[start..].find("</shape>").expect("closed shape") + "</shape>".len();
    let shape = r#"<shape type="ply" id="scan">
        <string name="filename" value="meshes/scan.ply"/>
        <bsdf type="diffuse">
            <texture type="bitmap" name="reflectance">
                <string name="filename" value="textures/scan_albedo.png"/>
                <string name="filter_type" value="bilinear"/>
                <string name="wrap_mode" value="repeat"/>
            </texture>
        </bsdf>
    </shape>"#;
    let body = format!("{}{}{}", &src[..start], shape, &src[end..]);
    body.replacen(
        "<!-- made from",
        "<!-- scanned-object room written by make_scan_room (opal examples); cbox made from",
        1,
    )
}

fn copy_dir(from: &Path, to: &Path, skip: &str) -> std::io::Result<()> {
    std::fs::create_dir_all(to)?;
    for e in std::fs::read_dir(from)? {
        let e = e?;
        if e.file_name() != skip {
            std::fs::copy(e.path(), to.join(e.file_name()))?;
        }
    }
    Ok(())
}

fn main() {
    let out = PathBuf::from(std::env::args().nth(1).expect("usage: make_scan_room OUT_DIR"));
    let src = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/cbox");
    copy_dir(&src.join("meshes"), &out.join("meshes"), "tall_box.obj").expect("copy meshes");
    copy_dir(&src.join("textures"), &out.join("textures"), "").expect("copy textures");
    let m = scan_mesh();
    write_ply(&out.join("meshes/scan.ply"), &m).expect("write scan.ply");
    write_texture(&out.join("textures/scan_albedo.png")).expect("write scan_albedo.png");
    let xml = std::fs::read_to_string(src.join("scene.xml")).expect("bundled scene.xml");
    std::fs::write(out.join("scene.xml"), scene_xml(&xml)).expect("write scene.xml");
    let (lo, hi) =
        m.positions.iter().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |a, &p| (a.0.min(p), a.1.max(p)));
    println!(
        "{}: scan {} triangles, {} vertices, bounds {lo:.3} .. {hi:.3}; texture {TEX}x{TEX}",
        out.join("scene.xml").display(),
        m.indices.len(),
        m.positions.len()
    );
}
