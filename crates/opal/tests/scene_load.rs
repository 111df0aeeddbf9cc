//! Scene input: Mitsuba XML → `SceneDesc` (Cornell box, every supported element, every error
//! case), image reading and texture lookups against Mitsuba's own albedo AOV.

use opal::Error;
use opal::image::read::{read_exr_channels, read_image};
use opal::math::{Mat4, Vec2, Vec3, Vec4};
use opal::scene::desc::*;
use opal::scene::load_mitsuba_xml;
use opal::spectrum::Spectrum;
use std::path::{Path, PathBuf};

fn data(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data").join(p)
}

fn cbox() -> SceneDesc {
    load_mitsuba_xml(&data("cbox/scene.xml"), &[]).expect("cbox loads")
}

/// Writes `files` into a fresh temp dir and loads `scene.xml` from it.
fn load_inline(
    files: &[(&str, &[u8])],
    params: &[(&str, &str)],
) -> (tempfile::TempDir, opal::Result<SceneDesc>) {
    let dir = tempfile::tempdir().unwrap();
    for (name, content) in files {
        let p = dir.path().join(name);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, content).unwrap();
    }
    let params: Vec<(String, String)> = params.iter().map(|(a, b)| (a.to_string(), b.to_string())).collect();
    let r = load_mitsuba_xml(&dir.path().join("scene.xml"), &params);
    (dir, r)
}

fn scene_xml(body: &str) -> String {
    format!("<scene version=\"3.0.0\">\n{body}\n</scene>\n")
}

fn ok(body: &str) -> SceneDesc {
    let s = scene_xml(body);
    let (_d, r) = load_inline(&[("scene.xml", s.as_bytes())], &[]);
    r.unwrap_or_else(|e| panic!("{e}"))
}

fn err(files: &[(&str, &[u8])]) -> (Error, String) {
    let (_d, r) = load_inline(files, &[]);
    let e = r.expect_err("should fail");
    let s = e.to_string();
    (e, s)
}

fn err_body(body: &str) -> (Error, String) {
    let s = scene_xml(body);
    err(&[("scene.xml", s.as_bytes())])
}

fn close(a: Vec3, b: Vec3, tol: f32) -> bool {
    (a - b).abs().max_element() <= tol
}

const QUAD_OBJ: &str =
    "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n";

// ---------------------------------------------------------------------------------------
// Cornell box

#[test]
fn cbox_structure_albedos_radiance_and_cameras() {
    let s = cbox();
    assert_eq!(s.sensors.len(), 8);
    assert_eq!(s.shapes.len(), 8);
    assert!(s.emitters.is_empty());
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    let ids: Vec<&str> = s.shapes.iter().map(|x| x.id.as_str()).collect();
    assert_eq!(
        ids,
        [
            "floor",
            "ceiling",
            "back_wall",
            "left_wall_red",
            "right_wall_green",
            "short_box",
            "tall_box",
            "light"
        ]
    );
    let albedo = |id: &str| match &s.shapes.iter().find(|x| x.id == id).unwrap().bsdf {
        BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(c) } => *c,
        other => panic!("{id}: {other:?}"),
    };
    assert_eq!(albedo("floor"), Spectrum::rgb(0.8, 0.78, 0.72));
    assert_eq!(albedo("ceiling"), Spectrum::splat(0.85));
    assert_eq!(albedo("left_wall_red"), Spectrum::rgb(0.570068, 0.0430135, 0.0443706));
    assert_eq!(albedo("right_wall_green"), Spectrum::rgb(0.105421, 0.37798, 0.076425));
    assert_eq!(albedo("short_box"), Spectrum::rgb(0.3, 0.45, 0.75));
    assert_eq!(albedo("tall_box"), Spectrum::rgb(0.75, 0.7, 0.3));
    assert_eq!(albedo("light"), Spectrum::splat(0.78));
    for sh in &s.shapes {
        let e = sh.emitter.as_ref().map(|e| e.radiance);
        if sh.id == "light" {
            assert_eq!(e, Some(Spectrum::rgb(18.387, 13.9873, 6.75357)));
        } else {
            assert_eq!(e, None, "{}", sh.id);
        }
        // face_normals = true everywhere.
        assert!(sh.mesh.normals.is_empty(), "{}", sh.id);
        let n = if sh.id.ends_with("box") { 10 } else { 2 };
        assert_eq!(sh.mesh.triangle_count(), n, "{}", sh.id);
        assert_eq!(sh.origin.as_ref().unwrap().0, data("cbox/scene.xml"));
    }
    // Light: quad of area 0.1748 at y = 0.99 facing -y (front side = CCW winding).
    let light = &s.shapes[7].mesh;
    assert!((light.area() - 0.1748).abs() < 1e-5, "{}", light.area());
    for i in 0..2 {
        let [a, b, c] = light.triangle(i);
        assert!(close((b - a).cross(c - a).normalize(), Vec3::NEG_Y, 1e-6));
        assert!((a.y - 0.99).abs() < 1e-6);
    }
    // Back wall: texture, bilinear, clamp, uv flipped (OBJ vt (0,0) at (-1,-1,-1) → (0,1)).
    let bw = &s.shapes[2];
    match &bw.bsdf {
        BsdfDesc::Diffuse { reflectance: TextureDesc::Bitmap(b) } => {
            assert_eq!((b.filter, b.wrap), (FilterType::Bilinear, WrapMode::Clamp));
            assert_eq!((b.image.width, b.image.height), (256, 256));
            assert!(b.path.ends_with("textures/backwall_albedo.exr"));
        }
        other => panic!("{other:?}"),
    }
    let k = bw.mesh.positions.iter().position(|p| *p == Vec3::new(-1., -1., -1.)).unwrap();
    assert_eq!(bw.mesh.uvs[k], Vec2::new(0.0, 1.0));
    let integ = s.integrator.as_ref().unwrap();
    assert_eq!((integ.max_depth, integ.rr_depth, integ.hide_emitters), (16, 5, false));

    // Cameras: fov, size, spp, clip defaults, to_world = the file's matrices (row-major).
    let text = std::fs::read_to_string(data("cbox/scene.xml")).unwrap();
    let mats: Vec<Vec<f32>> = text
        .split("<matrix value=\"")
        .skip(1)
        .map(|t| t.split('"').next().unwrap().split_whitespace().map(|v| v.parse().unwrap()).collect())
        .collect();
    let fovs = [39.3077, 45.0, 45.0, 65.0, 65.0, 75.0, 70.0, 55.0];
    assert_eq!(mats.len(), 8);
    for (k, c) in s.sensors.iter().enumerate() {
        assert_eq!(c.id, format!("view_{k:02}"));
        assert_eq!(c.fov_x_deg, fovs[k]);
        assert_eq!((c.width, c.height, c.spp), (256, 256, Some(64)));
        assert_eq!((c.near_clip, c.far_clip), (0.01, 10000.0));
        let m = Mat4::from_cols_array(&mats[k].clone().try_into().unwrap()).transpose();
        assert_eq!(c.to_world, m, "view {k}");
    }
    // view_00 sits at (0, 0, 3.9) looking along -z.
    let c0 = s.sensors[0].to_world;
    assert!(close(c0.transform_point3(Vec3::ZERO), Vec3::new(0.0, 0.0, 3.9), 1e-6));
    assert!(close(c0.transform_vector3(Vec3::Z), Vec3::NEG_Z, 1e-6));
}

/// Back-wall texture: bilinear lookups against values computed by hand from the texels.
#[test]
fn backwall_texture_bilinear_by_hand() {
    let img = read_image(&data("cbox/textures/backwall_albedo.exr")).unwrap();
    assert_eq!((img.width, img.height), (256, 256));
    // The reference says texel values are k/255.
    for p in img.data.iter().step_by(97) {
        for c in 0..3 {
            let k = p[c] * 255.0;
            assert!((k - k.round()).abs() < 1e-3, "{}", p[c]);
        }
    }
    let s = cbox();
    let TextureDesc::Bitmap(b) = (match &s.shapes[2].bsdf {
        BsdfDesc::Diffuse { reflectance } => reflectance.clone(),
        _ => unreachable!(),
    }) else {
        unreachable!()
    };
    // Texel centres: exact texel values.
    for (c, r) in [(0usize, 0usize), (17, 200), (255, 255), (128, 3)] {
        let uv = Vec2::new((c as f32 + 0.5) / 256.0, (r as f32 + 0.5) / 256.0);
        assert_eq!(b.eval(uv), img.get(c, r));
    }
    // u = 0.3 → x = 76.3 → texels 76 (w 0.7) and 77 (w 0.3) — weights are exact in f32 up to
    // rounding of 0.3·256; v = 0.7 → y = 178.7 → rows 178 (w 0.3) and 179 (w 0.7).
    let (u, v) = (0.3f32, 0.7f32);
    let (fx, fy) = (u * 256.0 - 0.5 - 76.0, v * 256.0 - 0.5 - 178.0);
    let t = |c, r| img.get(c, r);
    for ch in 0..3 {
        let want = (1.0 - fy) * ((1.0 - fx) * t(76, 178)[ch] + fx * t(77, 178)[ch])
            + fy * ((1.0 - fx) * t(76, 179)[ch] + fx * t(77, 179)[ch]);
        assert!((b.eval(Vec2::new(u, v))[ch] - want).abs() < 1e-6);
    }
    // Corner with clamp: below the first texel centre the edge texel is returned.
    assert_eq!(b.eval(Vec2::new(0.0, 0.0)), img.get(0, 0));
    assert_eq!(b.eval(Vec2::new(1.0, 1.0)), img.get(255, 255));
}

/// Opal's lookup reproduces Mitsuba's albedo AOV at the uv Mitsuba used (327 pixels of
/// view 0 hitting the back wall, extracted by `examples/extract_aov_csv.rs`).
#[test]
fn backwall_texture_matches_mitsuba_albedo_aov() {
    let s = cbox();
    let BsdfDesc::Diffuse { reflectance } = &s.shapes[2].bsdf else { unreachable!() };
    let csv = std::fs::read_to_string(data("cbox/backwall_aov_samples.csv")).unwrap();
    let mut n = 0;
    let mut max_err = 0f32;
    // Power check: the same comparison with a v flip or a half-texel shift must fail clearly.
    let (mut err_flip, mut err_shift) = (0f32, 0f32);
    for line in csv.lines().skip(1) {
        let f: Vec<f32> = line.split(',').map(|v| v.parse().unwrap()).collect();
        let got = reflectance.eval(Vec2::new(f[2], f[3]));
        let flip = reflectance.eval(Vec2::new(f[2], 1.0 - f[3]));
        let shift = reflectance.eval(Vec2::new(f[2] + 0.5 / 256.0, f[3] + 0.5 / 256.0));
        for c in 0..3 {
            max_err = max_err.max((got[c] - f[4 + c]).abs());
            err_flip = err_flip.max((flip[c] - f[4 + c]).abs());
            err_shift = err_shift.max((shift[c] - f[4 + c]).abs());
        }
        n += 1;
    }
    assert!(err_flip > 1e-2 && err_shift > 1e-3, "test has no power: {err_flip} {err_shift}");
    assert!(n > 300, "{n}");
    // Tolerance: the csv holds the exact f32 uv Mitsuba used, and both sides evaluate the same
    // f32 bilinear formula on the same texels (values ≤ 1); they differ only in operation
    // order / fused multiply-adds, a few ulps (~1e-7 each) → bound 1e-6. Measured 1.2e-7.
    // (A wrong texel-centre convention or a missing v-flip gives errors ~1e-2.)
    assert!(max_err < 1e-6, "max abs error {max_err} over {n} samples");
    eprintln!(
        "back wall vs Mitsuba AOV: {n} samples, max abs error {max_err:e} (v flipped: {err_flip:e}, half-texel shift: {err_shift:e})"
    );
}

#[test]
fn exr_channels_by_name() {
    let (w, h, ch) = read_exr_channels(&data("cbox/textures/backwall_albedo.exr")).unwrap();
    assert_eq!((w, h), (256, 256));
    assert!(ch.contains_key("R") && ch.contains_key("G") && ch.contains_key("B"), "{:?}", ch.keys());
    let img = read_image(&data("cbox/textures/backwall_albedo.exr")).unwrap();
    assert_eq!(img.get(5, 7)[1], ch["G"][7 * 256 + 5]);
}

// ---------------------------------------------------------------------------------------
// Transforms

#[test]
fn transforms_compose_like_mitsuba() {
    // lookat(origin (1,2,3), target (1,2,0), up +y): left = up × dir = (-1,0,0), up' = (0,1,0),
    // dir = (0,0,-1), translation (1,2,3). Then translate x=1 (left-multiplied: translation
    // becomes (2,2,3)), then scale 2 (left-multiplied: everything doubles):
    // M = [[-2,0,0,4],[0,2,0,4],[0,0,-2,6]].
    let s = ok(r#"<shape type="rectangle">
        <transform name="to_world">
            <lookat origin="1, 2, 3" target="1, 2, 0" up="0, 1, 0"/>
            <translate x="1"/>
            <scale value="2"/>
        </transform>
    </shape>
    <sensor type="perspective">
        <transform name="to_world">
            <lookat origin="1, 2, 3" target="1, 2, 0" up="0, 1, 0"/>
            <translate x="1"/>
        </transform>
        <film type="hdrfilm"><rfilter type="box"/></film>
    </sensor>"#);
    let m = &s.shapes[0].mesh;
    assert_eq!(m.positions[0], Vec3::new(6.0, 2.0, 6.0)); // (-1,-1,0) ↦ (2+4, -2+4, 6)
    assert_eq!(m.positions[2], Vec3::new(2.0, 6.0, 6.0)); // (1,1,0)
    assert!(close(m.normals[0], Vec3::NEG_Z, 1e-6));
    // The geometric normal (CCW) agrees with the transformed normal (det > 0).
    let [a, b, c] = m.triangle(0);
    assert!(close((b - a).cross(c - a).normalize(), Vec3::NEG_Z, 1e-6));
    let want = Mat4::from_cols(
        Vec4::new(-1., 0., 0., 0.),
        Vec4::new(0., 1., 0., 0.),
        Vec4::new(0., 0., -1., 0.),
        Vec4::new(2., 2., 3., 1.),
    );
    assert_eq!(s.sensors[0].to_world, want);
}

#[test]
fn rotate_scale_matrix_forms() {
    let s = ok(r#"
    <shape type="rectangle" id="r1"><transform name="to_world"><rotate y="1" angle="90"/></transform></shape>
    <shape type="rectangle" id="r2"><transform name="to_world"><rotate value="0 0 2" angle="90"/><translate value="0 0 1"/></transform></shape>
    <shape type="rectangle" id="r3"><transform name="to_world"><scale x="2" z="3"/></transform></shape>
    <shape type="rectangle" id="r4"><transform name="to_world">
        <matrix value="1 0 0 5  0 1 0 6  0 0 1 7  0 0 0 1"/><scale value="1, 1, 1"/></transform></shape>
    <shape type="rectangle" id="r5"><transform name="to_world"><matrix value="0 -1 0 1 0 0 0 0 1"/></transform></shape>"#);
    // Rotation by +90° about +y maps +x → -z and +z → +x (right-handed).
    let m1 = &s.shapes[0].mesh;
    assert!(close(m1.positions[1], Vec3::new(0.0, -1.0, -1.0), 1e-6)); // (1,-1,0)
    assert!(close(m1.normals[0], Vec3::X, 1e-6));
    // About +z (axis normalised) by 90°: (1,-1,0) → (1,1,0), then +1 in z.
    assert!(close(s.shapes[1].mesh.positions[1], Vec3::new(1.0, 1.0, 1.0), 1e-6));
    // Scale with missing y = 1.
    assert_eq!(s.shapes[2].mesh.positions[2], Vec3::new(2.0, 1.0, 0.0));
    assert_eq!(s.shapes[3].mesh.positions[0], Vec3::new(4.0, 5.0, 7.0));
    // 3×3 matrix: rows (0,-1,0), (1,0,0), (0,0,1) = +90° about z.
    assert!(close(s.shapes[4].mesh.positions[1], Vec3::new(1.0, 1.0, 0.0), 1e-6));
}

// ---------------------------------------------------------------------------------------
// Each supported element

#[test]
fn analytic_shapes() {
    let s = ok(r#"
    <shape type="cube"><transform name="to_world"><scale value="0.5"/></transform></shape>
    <shape type="sphere"><point name="center" x="1" y="2" z="3"/><float name="radius" value="0.25"/></shape>
    <shape type="sphere"><boolean name="flip_normals" value="true"/></shape>
    <shape type="rectangle"><boolean name="flip_normals" value="true"/></shape>"#);
    let cube = &s.shapes[0].mesh;
    assert_eq!(cube.triangle_count(), 12);
    assert!((cube.area() - 6.0).abs() < 1e-5);
    let sph = &s.shapes[1].mesh;
    let c = Vec3::new(1.0, 2.0, 3.0);
    for (p, n) in sph.positions.iter().zip(&sph.normals) {
        assert!(((*p - c).length() - 0.25).abs() < 1e-6);
        assert!(close((*p - c).normalize(), *n, 1e-5));
    }
    let area = 4.0 * std::f64::consts::PI * 0.0625;
    assert!((sph.area() - area).abs() / area < 2e-3);
    assert!(sph.triangle_count() >= 64 * 32 * 2 - 2 * 64);
    // Flipped sphere: normals and CCW winding point inward.
    let f = &s.shapes[2].mesh;
    for i in (0..f.triangle_count()).step_by(37) {
        let [a, b, c] = f.triangle(i);
        let ng = (b - a).cross(c - a);
        assert!(ng.dot(a + b + c) < 0.0);
        assert!(f.normals[f.indices[i][0] as usize].dot(a) < 0.0);
    }
    let r = &s.shapes[3].mesh;
    let [a, b, c] = r.triangle(0);
    assert!(close((b - a).cross(c - a).normalize(), Vec3::NEG_Z, 1e-6));
    assert_eq!(r.normals[0], Vec3::NEG_Z);
    // Default material is Mitsuba's diffuse 0.5.
    assert!(
        matches!(&s.shapes[0].bsdf, BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(c) } if *c == Spectrum::splat(0.5))
    );
}

#[test]
fn obj_and_ply_shapes_with_options() {
    let scene = scene_xml(
        r#"
    <shape type="obj" id="a"><string name="filename" value="m/quad.obj"/></shape>
    <shape type="obj" id="b"><string name="filename" value="m/quad.obj"/><boolean name="flip_tex_coords" value="false"/>
        <boolean name="face_normals" value="true"/></shape>
    <shape type="ply" id="c"><string name="filename" value="m/tri.ply"/></shape>
    <shape type="obj" id="d"><string name="filename" value="m/degen.obj"/></shape>"#,
    );
    let ply = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
               property float s\nproperty float t\nelement face 1\nproperty list uchar uint vertex_index\nend_header\n\
               0 0 0 0 0\n1 0 0 1 0\n0 1 0 0 1\n3 0 1 2\n";
    let degen = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\n";
    let (_d, r) = load_inline(
        &[
            ("scene.xml", scene.as_bytes()),
            ("m/quad.obj", QUAD_OBJ.as_bytes()),
            ("m/tri.ply", ply.as_bytes()),
            ("m/degen.obj", degen.as_bytes()),
        ],
        &[],
    );
    let s = r.unwrap();
    let a = &s.shapes[0].mesh;
    // No vn and face_normals false ⇒ normals recomputed (flat quad: +z everywhere).
    assert_eq!(a.normals.len(), 4);
    assert!(a.normals.iter().all(|n| close(*n, Vec3::Z, 1e-6)));
    let k = a.positions.iter().position(|p| *p == Vec3::new(1.0, 1.0, 0.0)).unwrap();
    assert_eq!(a.uvs[k], Vec2::new(1.0, 0.0)); // vt (1,1) flipped
    let b = &s.shapes[1].mesh;
    assert!(b.normals.is_empty());
    assert_eq!(b.uvs[k], Vec2::new(1.0, 1.0));
    let c = &s.shapes[2].mesh;
    assert_eq!(c.indices, vec![[0, 1, 2]]);
    assert_eq!(c.uvs[2], Vec2::new(0.0, 1.0)); // PLY uvs are not flipped
    // Degenerate triangle (collinear) dropped with a warning naming the shape.
    assert_eq!(s.shapes[3].mesh.triangle_count(), 1);
    assert_eq!(s.warnings.len(), 1, "{:?}", s.warnings);
    assert!(
        s.warnings[0].contains("`d`") && s.warnings[0].contains("dropped 1 degenerate"),
        "{:?}",
        s.warnings
    );
}

fn png_bytes(pixels: &[[u8; 3]], w: u32, h: u32) -> Vec<u8> {
    let img = image::RgbImage::from_fn(w, h, |x, y| image::Rgb(pixels[(y * w + x) as usize]));
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    out.into_inner()
}

#[test]
#[allow(irrefutable_let_patterns)] // EmitterDesc has one variant today; more may come.
fn materials_textures_refs_and_emitters() {
    let png = png_bytes(&[[0, 128, 255], [64, 64, 64]], 2, 1);
    let scene = scene_xml(
        r#"
    <texture type="bitmap" id="tex">
        <string name="filename" value="t.png"/>
        <string name="filter_type" value="nearest"/>
        <string name="wrap_mode" value="mirror"/>
    </texture>
    <bsdf type="twosided" id="white"><bsdf type="diffuse"><float name="reflectance" value="0.9"/></bsdf></bsdf>
    <shape type="rectangle" id="a"><ref id="white"/></shape>
    <shape type="rectangle" id="b"><bsdf type="diffuse"><ref name="reflectance" id="tex"/></bsdf></shape>
    <shape type="rectangle" id="c"><bsdf type="diffuse">
        <texture type="bitmap" name="reflectance"><string name="filename" value="t.png"/><boolean name="raw" value="true"/></texture>
    </bsdf><emitter type="area"><rgb name="radiance" value="1 2 3"/></emitter></shape>
    <emitter type="point"><point name="position" value="1, 2, 3"/><rgb name="intensity" value="5"/></emitter>
    <emitter type="point"><transform name="to_world"><translate x="-1"/></transform></emitter>
    <integrator type="path"><integer name="max_depth" value="-1"/><boolean name="hide_emitters" value="true"/></integrator>"#,
    );
    let (_d, r) = load_inline(&[("scene.xml", scene.as_bytes()), ("t.png", &png)], &[]);
    let s = r.unwrap();
    match &s.shapes[0].bsdf {
        BsdfDesc::TwoSided(inner) => assert!(
            matches!(&**inner, BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(c) } if *c == Spectrum::splat(0.9))
        ),
        o => panic!("{o:?}"),
    }
    let srgb = |k: f32| {
        let v = k / 255.0;
        if v <= 0.04045 { v / 12.92 } else { ((v + 0.055) / 1.055).powf(2.4) }
    };
    match &s.shapes[1].bsdf {
        BsdfDesc::Diffuse { reflectance: TextureDesc::Bitmap(b) } => {
            assert_eq!((b.filter, b.wrap), (FilterType::Nearest, WrapMode::Mirror));
            // sRGB-decoded (raw = false): texel (0,0) = (0, 128, 255).
            let v = b.eval(Vec2::new(0.25, 0.5));
            assert!((v[1] - srgb(128.0)).abs() < 1e-6 && (v[2] - 1.0).abs() < 1e-6, "{v:?}");
            // Mirror: u = 1.25 → texel 2 → 1 (second period mirrored)... = texel (1,0).
            assert!((b.eval(Vec2::new(1.25, 0.5))[0] - srgb(64.0)).abs() < 1e-6);
        }
        o => panic!("{o:?}"),
    }
    match &s.shapes[2].bsdf {
        BsdfDesc::Diffuse { reflectance: TextureDesc::Bitmap(b) } => {
            assert_eq!((b.filter, b.wrap), (FilterType::Bilinear, WrapMode::Repeat)); // defaults
            assert_eq!(b.image.get(0, 0)[1], 128.0 / 255.0); // raw: no decoding
        }
        o => panic!("{o:?}"),
    }
    assert_eq!(s.shapes[2].emitter.as_ref().unwrap().radiance, Spectrum::rgb(1.0, 2.0, 3.0));
    assert!(s.shapes[0].emitter.is_none());
    let EmitterDesc::Point { position, intensity } = &s.emitters[0] else { panic!() };
    assert_eq!((*position, *intensity), (Vec3::new(1.0, 2.0, 3.0), Spectrum::splat(5.0)));
    let EmitterDesc::Point { position, intensity } = &s.emitters[1] else { panic!() };
    assert_eq!((*position, *intensity), (Vec3::new(-1.0, 0.0, 0.0), Spectrum::ONE));
    let i = s.integrator.unwrap();
    assert_eq!((i.max_depth, i.rr_depth, i.hide_emitters), (-1, 5, true));
}

#[test]
fn sensors_fov_axis_film_and_sampler() {
    let s = ok(r#"
    <sensor type="perspective" id="cam">
        <float name="fov" value="30"/><string name="fov_axis" value="y"/>
        <float name="near_clip" value="0.5"/><float name="far_clip" value="50"/>
        <film type="hdrfilm"><integer name="width" value="200"/><integer name="height" value="100"/>
            <string name="pixel_format" value="rgb"/><rfilter type="box"/></film>
        <sampler type="independent"><integer name="sample_count" value="16"/></sampler>
    </sensor>
    <sensor type="perspective"><float name="fov" value="40"/><string name="fov_axis" value="diagonal"/></sensor>
    <sensor type="perspective"/>"#);
    let c = &s.sensors[0];
    assert_eq!(c.id, "cam");
    assert_eq!((c.width, c.height, c.spp, c.near_clip, c.far_clip), (200, 100, Some(16), 0.5, 50.0));
    // tan(fov_x/2) = tan(fov_y/2) · W/H.
    let want = 2.0 * ((15f64).to_radians().tan() * 2.0).atan().to_degrees();
    assert!((c.fov_x_deg as f64 - want).abs() < 1e-4);
    // Default film 768×576; diagonal fov: tan²(x/2) + tan²(y/2) = tan²(d/2), tan(y/2) = tan(x/2)·3/4.
    let d = &s.sensors[1];
    assert_eq!((d.width, d.height, d.spp), (768, 576, None));
    assert_eq!(d.id, "sensor_1");
    let tx = (0.5 * (d.fov_x_deg as f64).to_radians()).tan();
    let td = (20f64).to_radians().tan();
    assert!((tx * tx * (1.0 + 0.75 * 0.75) - td * td).abs() < 1e-6);
    // No fov: Mitsuba's 50 mm focal length on a 36×24 mm diagonal.
    let e = &s.sensors[2];
    let diag = 2.0 * ((36f64 * 36.0 + 24.0 * 24.0).sqrt() / 100.0).atan();
    let tx = (0.5 * (e.fov_x_deg as f64).to_radians()).tan();
    let td = (0.5 * diag).tan();
    assert!((tx * tx * (1.0 + 0.75 * 0.75) - td * td).abs() < 1e-6);
    // Missing rfilter ⇒ a warning (Mitsuba's default is gaussian).
    assert_eq!(s.warnings.iter().filter(|w| w.contains("gaussian")).count(), 2, "{:?}", s.warnings);
}

#[test]
fn defaults_params_and_includes() {
    let main = r#"<scene version="3.0.0">
        <default name="spp" value="8"/>
        <default name="res" value="32"/>
        <include filename="sub/part.xml"/>
        <sensor type="perspective"><float name="fov" value="$fov"/>
            <film type="hdrfilm"><integer name="width" value="${res}"/><integer name="height" value="$res"/><rfilter type="box"/></film>
            <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler></sensor>
    </scene>"#;
    // The included file's mesh path is relative to the included file's folder.
    let part = r#"<scene version="3.0.0"><shape type="obj" id="$name"><string name="filename" value="quad.obj"/></shape></scene>"#;
    let files: &[(&str, &[u8])] = &[
        ("scene.xml", main.as_bytes()),
        ("sub/part.xml", part.as_bytes()),
        ("sub/quad.obj", QUAD_OBJ.as_bytes()),
    ];
    let (_d, r) = load_inline(files, &[("fov", "45"), ("spp", "128"), ("name", "q")]);
    let s = r.unwrap();
    assert_eq!(s.shapes[0].id, "q");
    assert_eq!(s.shapes[0].mesh.triangle_count(), 2);
    let c = &s.sensors[0];
    assert_eq!((c.fov_x_deg, c.spp, c.width, c.height), (45.0, Some(128), 32, 32));
    // Without the caller's spp, the default applies; an unset $fov is an error.
    let (_d, r) = load_inline(files, &[("fov", "45"), ("name", "q")]);
    assert_eq!(r.unwrap().sensors[0].spp, Some(8));
    let (_d, r) = load_inline(files, &[("name", "q")]);
    let e = r.unwrap_err().to_string();
    assert!(e.contains("scene.xml:5:61") && e.contains("$fov") && e.contains("not set"), "{e}");
    let (_d, r) = load_inline(files, &[("fov", "45")]);
    let e = r.unwrap_err().to_string();
    assert!(e.contains("part.xml:1:") && e.contains("$name"), "{e}");
}

// ---------------------------------------------------------------------------------------
// Errors: each names the file and line (and column) in its Display.

#[test]
fn error_missing_scene_file() {
    let e = load_mitsuba_xml(Path::new("/nonexistent/dir/scene.xml"), &[]).unwrap_err();
    assert!(matches!(e, Error::Io { .. }), "{e:?}");
    assert!(e.to_string().contains("/nonexistent/dir/scene.xml"), "{e}");
}

#[test]
fn error_malformed_xml_has_line() {
    let (e, s) = err(&[("scene.xml", b"<scene version=\"3.0.0\">\n  <shape type=\"cube\">\n</scene>\n")]);
    assert!(matches!(e, Error::Parse { line: 3, .. }), "{e:?}");
    assert!(s.contains("scene.xml:3:") && s.contains("malformed XML"), "{s}");
}

#[test]
fn error_unknown_plugin_types() {
    let (e, s) = err_body("\n<shape type=\"cube\">\n  <bsdf type=\"principled\"/>\n</shape>");
    assert!(matches!(e, Error::Parse { line: 4, .. }), "{e:?}");
    assert!(s.contains("scene.xml:4:") && s.contains("bsdf type=\"principled\" is not supported"), "{s}");
    assert!(s.contains("diffuse, twosided"), "{s}");
    let (_, s) =
        err_body("<emitter type=\"projector\"><string name=\"filename\" value=\"x.exr\"/></emitter>");
    assert!(s.contains("scene.xml:2:") && s.contains("emitter type=\"projector\""), "{s}");
    // The unsupported plugin is reported before its (here broken) children are read.
    let (_, s) = err_body(
        "<bsdf type=\"principled\" id=\"rp\"><texture type=\"bitmap\" name=\"base_color\">\
         <string name=\"filename\" value=\"missing.png\"/></texture></bsdf>",
    );
    assert!(s.contains("principled") && !s.contains("missing.png"), "{s}");
    let (_, s) = err_body("<medium type=\"homogeneous\"/>");
    assert!(s.contains("scene.xml:2:") && s.contains("medium"), "{s}");
    let (_, s) = err_body("<shape type=\"cube\"><foo/></shape>");
    assert!(s.contains("scene.xml:2:") && s.contains("unknown element <foo>"), "{s}");
}

#[test]
fn error_unknown_parameter_and_attribute() {
    let (e, s) = err_body(
        "<shape type=\"cube\">\n <bsdf type=\"diffuse\">\n  <float name=\"foo\" value=\"1\"/>\n </bsdf>\n</shape>",
    );
    assert!(matches!(e, Error::Parse { line: 4, col: 3, .. }), "{e:?}");
    assert!(
        s.contains("unknown parameter `foo`") && s.contains("diffuse") && s.contains("reflectance"),
        "{s}"
    );
    // Parameters are checked before the mesh file is opened.
    let (_, s) = err_body(
        "<shape type=\"obj\"><string name=\"filename\" value=\"absent.obj\"/><float name=\"scale\" value=\"2\"/></shape>",
    );
    assert!(s.contains("unknown parameter `scale`") && s.contains("flip_tex_coords"), "{s}");
    let (_, s) = err_body("<shape type=\"sphere\"><float name=\"radius\" value=\"1\" unit=\"m\"/></shape>");
    assert!(s.contains("scene.xml:2:") && s.contains("unknown attribute `unit`"), "{s}");
    let (_, s) = err_body("<shape type=\"sphere\"><string name=\"radius\" value=\"1\"/></shape>");
    assert!(s.contains("`radius`") && s.contains("must be a float"), "{s}");
    let (_, s) =
        err_body("<shape type=\"rectangle\"><boolean name=\"face_normals\" value=\"true\"/></shape>");
    assert!(s.contains("unknown parameter `face_normals`"), "{s}");
    let (_, s) = err_body(
        "<sensor type=\"perspective\"><sampler type=\"independent\"><integer name=\"seed\" value=\"3\"/></sampler></sensor>",
    );
    assert!(s.contains("unknown parameter `seed`"), "{s}");
}

#[test]
fn error_unset_param() {
    let (e, s) = err_body("<shape type=\"sphere\">\n<float name=\"radius\" value=\"$r\"/></shape>");
    assert!(matches!(e, Error::Parse { line: 3, .. }), "{e:?}");
    assert!(s.contains("`$r` is not set"), "{s}");
}

#[test]
fn error_nan_and_out_of_range_in_meshes() {
    let scene = scene_xml("<shape type=\"obj\">\n<string name=\"filename\" value=\"bad.obj\"/></shape>");
    let (e, s) =
        err(&[("scene.xml", scene.as_bytes()), ("bad.obj", b"v 0 0 0\nv 1 0 0\nv 0 NaN 0\nf 1 2 3\n")]);
    assert!(matches!(&e, Error::Parse { line: 3, .. }), "{e:?}");
    assert!(s.contains("scene.xml:3:") && s.contains("bad.obj:3:5") && s.contains("NaN"), "{s}");
    let (_, s) =
        err(&[("scene.xml", scene.as_bytes()), ("bad.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n")]);
    assert!(s.contains("bad.obj:4:") && s.contains("index 4 out of range"), "{s}");
    let scene = scene_xml("<shape type=\"ply\"><string name=\"filename\" value=\"bad.ply\"/></shape>");
    let hdr = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
               element face 1\nproperty list uchar int vertex_indices\nend_header\n";
    let bad = format!("{hdr}0 0 0\n1 0 0\n0 1 nan\n3 0 1 2\n");
    let (_, s) = err(&[("scene.xml", scene.as_bytes()), ("bad.ply", bad.as_bytes())]);
    assert!(s.contains("scene.xml:2:") && s.contains("bad.ply:12:") && s.contains("non-finite"), "{s}");
    let bad = format!("{hdr}0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n");
    let (_, s) = err(&[("scene.xml", scene.as_bytes()), ("bad.ply", bad.as_bytes())]);
    assert!(s.contains("bad.ply:13:") && s.contains("index 3 out of range"), "{s}");
    // Missing mesh file: reported at the XML element with the path.
    let (_, s) = err(&[("scene.xml", scene.as_bytes())]);
    assert!(s.contains("scene.xml:2:") && s.contains("bad.ply"), "{s}");
    // A mesh that is entirely degenerate is an error.
    let scene = scene_xml("<shape type=\"obj\"><string name=\"filename\" value=\"flat.obj\"/></shape>");
    let (_, s) =
        err(&[("scene.xml", scene.as_bytes()), ("flat.obj", b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")]);
    assert!(s.contains("scene.xml:2:") && s.contains("degenerate") && s.contains("empty"), "{s}");
}

#[test]
fn error_texture_fails_to_decode() {
    let scene = scene_xml(
        "<shape type=\"cube\"><bsdf type=\"diffuse\"><texture type=\"bitmap\" name=\"reflectance\">\n\
         <string name=\"filename\" value=\"broken.png\"/></texture></bsdf></shape>",
    );
    let (e, s) = err(&[("scene.xml", scene.as_bytes()), ("broken.png", b"\x89PNG\r\n\x1a\ngarbage")]);
    assert!(matches!(e, Error::Parse { line: 3, .. }), "{e:?}");
    assert!(s.contains("scene.xml:3:") && s.contains("broken.png") && s.contains("cannot decode"), "{s}");
    let (_, s) = err(&[("scene.xml", scene.as_bytes()), ("broken.png", b"")]);
    assert!(s.contains("broken.png"), "{s}");
}

#[test]
fn error_include_loop() {
    let a = "<scene version=\"3.0.0\">\n<include filename=\"b.xml\"/>\n</scene>";
    let b = "<scene version=\"3.0.0\">\n\n<include filename=\"scene.xml\"/>\n</scene>";
    let (e, s) = err(&[("scene.xml", a.as_bytes()), ("b.xml", b.as_bytes())]);
    assert!(matches!(&e, Error::Parse { line: 3, path, .. } if path.ends_with("b.xml")), "{e:?}");
    assert!(s.contains("include loop"), "{s}");
    // Self-include.
    let (_, s) = err(&[("scene.xml", b"<scene version=\"3.0.0\"><include filename=\"scene.xml\"/></scene>")]);
    assert!(s.contains("scene.xml:1:") && s.contains("include loop"), "{s}");
    // Missing include.
    let (_, s) =
        err(&[("scene.xml", b"<scene version=\"3.0.0\">\n<include filename=\"nope.xml\"/></scene>")]);
    assert!(s.contains("scene.xml:2:") && s.contains("nope.xml"), "{s}");
}

#[test]
fn error_misc_structure() {
    let (_, s) = err(&[("scene.xml", b"<scene>\n</scene>")]);
    assert!(s.contains("scene.xml:1:") && s.contains("version"), "{s}");
    let (_, s) = err(&[("scene.xml", b"<scene version=\"0.6.0\"/>")]);
    assert!(s.contains("0.6.0") && s.contains("not supported"), "{s}");
    let (_, s) = err_body("<emitter type=\"area\"><rgb name=\"radiance\" value=\"1\"/></emitter>");
    assert!(s.contains("scene.xml:2:") && s.contains("nested inside a <shape>"), "{s}");
    let (_, s) = err_body("<shape type=\"cube\"><ref id=\"nothing\"/></shape>");
    assert!(s.contains("scene.xml:2:") && s.contains("nothing"), "{s}");
    let (_, s) = err_body("<bsdf type=\"diffuse\" id=\"x\"/>\n<bsdf type=\"diffuse\" id=\"x\"/>");
    assert!(s.contains("scene.xml:3:") && s.contains("duplicate id `x`"), "{s}");
    let (_, s) = err_body("<shape type=\"cube\"><emitter type=\"point\"/></shape>");
    assert!(s.contains("only an emitter of type \"area\""), "{s}");
    let (_, s) = err_body(
        "<shape type=\"cube\"><transform name=\"to_world\"><scale value=\"0\"/></transform></shape>",
    );
    assert!(s.contains("singular"), "{s}");
    let (_, s) = err_body(
        "<sensor type=\"perspective\"><transform name=\"to_world\"><scale value=\"2\"/></transform></sensor>",
    );
    assert!(s.contains("must not scale"), "{s}");
    let (_, s) = err_body(
        "<sensor type=\"perspective\"><string name=\"fov_axis\" value=\"z\"/><float name=\"fov\" value=\"40\"/></sensor>",
    );
    assert!(s.contains("fov_axis \"z\""), "{s}");
    let (_, s) = err_body(
        "<shape type=\"cube\"><transform name=\"to_world\"><lookat origin=\"0 0 0\" target=\"0 1 0\" up=\"0 1 0\"/></transform></shape>",
    );
    assert!(s.contains("invalid <lookat>"), "{s}");
    let (_, s) = err_body("<integrator type=\"volpath\"/>");
    assert!(s.contains("integrator type=\"volpath\""), "{s}");
    let (_, s) = err_body(
        "<shape type=\"cube\"><bsdf type=\"twosided\"><bsdf type=\"diffuse\"/><bsdf type=\"diffuse\"/></bsdf></shape>",
    );
    assert!(s.contains("exactly one nested <bsdf>"), "{s}");
    let (_, s) = err_body("<shape type=\"cube\"><rgb name=\"x\" value=\"1 2\"/></shape>");
    assert!(s.contains("<rgb> needs 3"), "{s}");
}

/// A binary PLY written by hand (big-endian doubles, a quad, ushort indices, an extra element)
/// loads through the scene with its uvs unflipped and the quad fan-triangulated; a
/// single-valued `spectrum` is a grey colour.
#[test]
fn binary_ply_and_spectrum_through_the_scene() {
    let mut ply =
        b"ply\nformat binary_big_endian 1.0\nelement vertex 4\nproperty double x\nproperty double y\n\
property double z\nproperty float texture_u\nproperty float texture_v\nelement face 1\n\
property list uchar ushort vertex_indices\nelement camera 1\nproperty float fov\nend_header\n"
            .to_vec();
    let verts = [[0.0f64, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
    let uvs = [[0.0f32, 0.0], [1.0, 0.0], [1.0, 0.5], [0.0, 0.5]];
    for (p, t) in verts.iter().zip(uvs) {
        for c in p {
            ply.extend(c.to_be_bytes());
        }
        for c in t {
            ply.extend(c.to_be_bytes());
        }
    }
    ply.push(4);
    for i in [0u16, 1, 2, 3] {
        ply.extend(i.to_be_bytes());
    }
    ply.extend(45f32.to_be_bytes());
    let scene = scene_xml(
        r#"<shape type="ply"><string name="filename" value="q.ply"/>
        <bsdf type="diffuse"><spectrum name="reflectance" value="0.25"/></bsdf></shape>"#,
    );
    let (_d, r) = load_inline(&[("scene.xml", scene.as_bytes()), ("q.ply", &ply)], &[]);
    let s = r.unwrap();
    let m = &s.shapes[0].mesh;
    assert_eq!(m.indices, vec![[0, 1, 2], [0, 2, 3]]);
    assert_eq!(m.positions[2], Vec3::new(2.0, 1.0, 0.0));
    assert_eq!(m.uvs[2], Vec2::new(1.0, 0.5));
    assert!((m.area() - 2.0).abs() < 1e-6);
    // No normals in the file, face_normals false ⇒ recomputed, +z.
    assert!(m.normals.iter().all(|n| close(*n, Vec3::Z, 1e-6)));
    assert!(
        matches!(&s.shapes[0].bsdf, BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(c) } if *c == Spectrum::splat(0.25))
    );
    let (_, s) = err_body(
        r#"<shape type="cube"><bsdf type="diffuse"><spectrum name="reflectance" value="400:0.1, 700:0.5"/></bsdf></shape>"#,
    );
    assert!(s.contains("scene.xml:2:") && s.contains("RGB renderer"), "{s}");
}

/// A scene written the way Mitsuba's example Cornell box is (defaults substituted into a plugin
/// `type`, rectangles placed by 16-number matrices with 3-digit exponents, `ref`s to top-level
/// two-sided BSDFs, `file_format`), with a box film filter — a tent filter is rejected.
#[test]
fn mitsuba_style_cornell_box() {
    let body = |filter: &str| {
        format!(
            r#"<scene version="3.0.0">
    <default name="integrator" value="path"/>
    <default name="spp" value="64"/>
    <default name="max_depth" value="6"/>
    <integrator type="$integrator"><integer name="max_depth" value="$max_depth"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="19.5"/>
        <transform name="to_world"><matrix value="-1 0 0 0 0 1 0 1 0 0 -1 6.8 0 0 0 1"/></transform>
        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
        <film type="hdrfilm">
            <integer name="width" value="1024"/><integer name="height" value="1024"/>
            <string name="file_format" value="openexr"/><string name="pixel_format" value="rgb"/>
            <rfilter type="{filter}"/>
        </film>
    </sensor>
    <bsdf type="twosided" id="FloorBSDF"><bsdf type="diffuse"><rgb name="reflectance" value="0.725, 0.71, 0.68"/></bsdf></bsdf>
    <bsdf type="twosided" id="LightBSDF"><bsdf type="diffuse"><rgb name="reflectance" value="0, 0, 0"/></bsdf></bsdf>
    <shape type="rectangle" id="Floor">
        <transform name="to_world">
            <matrix value="-4.37114e-008 1 4.37114e-008 0 0 -8.74228e-008 2 0 1 4.37114e-008 1.91069e-015 0 0 0 0 1"/>
        </transform>
        <ref id="FloorBSDF"/>
    </shape>
    <shape type="rectangle" id="Light">
        <transform name="to_world">
            <matrix value="0.235 0 0 -0.005  0 0 -1 1.98  0 0.18 0 -0.03  0 0 0 1"/>
        </transform>
        <ref id="LightBSDF"/>
        <emitter type="area"><rgb name="radiance" value="17, 12, 4"/></emitter>
    </shape>
</scene>"#
        )
    };
    let (_d, r) = load_inline(&[("scene.xml", body("box").as_bytes())], &[]);
    let s = r.unwrap();
    assert_eq!(s.integrator.unwrap().max_depth, 6);
    assert_eq!(s.sensors[0].spp, Some(64));
    assert_eq!(s.shapes.len(), 2);
    assert!(matches!(&s.shapes[0].bsdf, BsdfDesc::TwoSided(_)));
    // Floor: rectangle mapped to y = 0 (up), 2×2 → area 4 (x ∈ [-1,1], z ∈ [-1,1]).
    let f = &s.shapes[0].mesh;
    assert!((f.area() - 4.0).abs() < 1e-4, "{}", f.area());
    assert!(f.positions.iter().all(|p| p.y.abs() < 1e-6));
    assert!(close(f.normals[0], Vec3::Y, 1e-6));
    // Light: columns (0.235,0,0), (0,0,0.18) → 0.47 × 0.36 quad at y = 1.98 facing
    // (1,0,0) × (0,0,1) = -y.
    let l = &s.shapes[1].mesh;
    assert!((l.area() - 0.47 * 0.36).abs() < 1e-5, "{}", l.area());
    let [a, b, c] = l.triangle(0);
    assert!(close((b - a).cross(c - a).normalize(), Vec3::NEG_Y, 1e-5));
    assert_eq!(s.shapes[1].emitter.as_ref().unwrap().radiance, Spectrum::rgb(17.0, 12.0, 4.0));
    let (_d, r) = load_inline(&[("scene.xml", body("tent").as_bytes())], &[]);
    let e = r.unwrap_err().to_string();
    assert!(e.contains("scene.xml:13:") && e.contains("rfilter type=\"tent\" is not supported"), "{e}");
}

/// `dielectric` (ratio of the indices, Mitsuba's defaults) and `tabulated` (an `.obsdf` file
/// next to the scene); errors name the file, the parameter and the value.
#[test]
fn dielectric_and_tabulated_bsdfs() {
    use opal::bsdf::Bxdfs;
    let d = ok(r#"<shape type="sphere"><bsdf type="dielectric"><float name="int_ior" value="1.6"/>
        <float name="ext_ior" value="1.2"/></bsdf></shape>
        <shape type="sphere"><bsdf type="dielectric"/></shape>"#);
    match (&d.shapes[0].bsdf, &d.shapes[1].bsdf) {
        (BsdfDesc::Lobe(Bxdfs::SmoothDielectric(a)), BsdfDesc::Lobe(Bxdfs::SmoothDielectric(b))) => {
            assert!((a.eta - 1.6 / 1.2).abs() < 1e-6);
            assert!((b.eta - 1.5046 / 1.000277).abs() < 1e-6);
        }
        other => panic!("{other:?}"),
    }
    let (_, m) = err_body(
        r#"<shape type="sphere"><bsdf type="dielectric"><float name="int_ior" value="-1"/></bsdf></shape>"#,
    );
    assert!(m.contains("int_ior") && m.contains("-1") && m.contains("scene.xml"), "{m}");
    let (_, m) = err_body(
        r#"<shape type="sphere"><bsdf type="dielectric"><float name="int_ior" value="1.0"/><float name="ext_ior" value="1.0"/></bsdf></shape>"#,
    );
    assert!(m.contains("eta"), "{m}");

    // a tiny table built from a rough dielectric
    let src = opal::bsdf::RoughDielectric::new(
        opal::bsdf::microfacet::Ndfs::ggx(0.3),
        1.5,
        opal::bsdf::rough_dielectric::Shadowing::Separable,
    )
    .unwrap();
    let grid = opal::bsdf::tabulated::TableGrid { n_theta_o: 3, n_u: 8, n_v: 4, beta: 8.0 };
    let table = opal::bsdf::TabulatedBsdf::build(&src, 1.5, grid, 1, "test").unwrap().to_bytes();
    let xml = scene_xml(
        r#"<shape type="rectangle"><bsdf type="tabulated"><string name="filename" value="tables/face.obsdf"/></bsdf></shape>"#,
    );
    let (_d, r) = load_inline(&[("scene.xml", xml.as_bytes()), ("tables/face.obsdf", &table)], &[]);
    match &r.unwrap().shapes[0].bsdf {
        BsdfDesc::Lobe(Bxdfs::Tabulated(t)) => {
            assert_eq!(t.grid(), grid);
            assert_eq!(t.eta(), 1.5);
        }
        other => panic!("{other:?}"),
    }
    // missing file, not a table, missing filename
    let (_, m) = err(&[("scene.xml", xml.as_bytes())]);
    assert!(m.contains("face.obsdf") && m.contains("scene.xml"), "{m}");
    let (_, m) = err(&[("scene.xml", xml.as_bytes()), ("tables/face.obsdf", b"not a table at all")]);
    assert!(m.contains("face.obsdf") && m.contains("magic"), "{m}");
    let (_, m) = err_body(r#"<shape type="rectangle"><bsdf type="tabulated"/></shape>"#);
    assert!(m.contains("filename") && m.contains("required"), "{m}");
    // an interface has two sides already: twosided around it is refused when building
    let d = ok(
        r#"<shape type="sphere" id="ball"><bsdf type="twosided"><bsdf type="dielectric"/></bsdf></shape>"#,
    );
    let m = opal::scene::Scene::build(&d).unwrap_err().to_string();
    assert!(m.contains("ball") && m.contains("twosided"), "{m}");
}

#[test]
fn rough_dielectric_plugin() {
    use opal::bsdf::{Bxdf, Bxdfs, TransportMode};
    let s = ok(r#"
    <shape type="rectangle"><bsdf type="roughdielectric"/></shape>
    <shape type="rectangle"><bsdf type="roughdielectric">
        <string name="distribution" value="ggx"/><float name="alpha" value="0.3"/>
        <float name="int_ior" value="1.49"/><string name="ext_ior" value="water"/>
        <string name="shadowing" value="height_correlated"/>
    </bsdf></shape>
    <shape type="rectangle"><bsdf type="roughdielectric">
        <string name="scattering" value="multiple"/><integer name="alpha" value="1"/>
        <string name="int_ior" value="acrylic glass"/>
    </bsdf></shape>"#);
    let b = |i: usize| match &s.shapes[i].bsdf {
        BsdfDesc::Lobe(b) => b.clone(),
        o => panic!("{o:?}"),
    };
    let Bxdfs::RoughDielectric(d) = b(0) else { panic!("{:?}", b(0)) };
    // Mitsuba's defaults: Beckmann, α = 0.1, bk7 in air, separable G
    assert!((d.eta - 1.5046 / 1.000277).abs() < 1e-6, "{}", d.eta);
    assert!(matches!(d.ndf, opal::bsdf::microfacet::Ndfs::Beckmann(_)));
    assert_eq!(d.shadowing, opal::bsdf::rough_dielectric::Shadowing::Separable);
    let Bxdfs::RoughDielectric(d) = b(1) else { panic!() };
    assert!((d.eta - 1.49 / 1.333).abs() < 1e-6 && matches!(d.ndf, opal::bsdf::microfacet::Ndfs::Ggx(_)));
    assert_eq!(d.shadowing, opal::bsdf::rough_dielectric::Shadowing::HeightCorrelated);
    let Bxdfs::RoughDielectricMs(m) = b(2) else { panic!() };
    assert!((m.eta - 1.49 / 1.000277).abs() < 1e-6);
    // transmits and reflects
    let wo = Vec3::new(0.3, 0.0, 0.954).normalize();
    assert!(b(2).eval(wo, Vec3::new(-0.3, 0.0, -0.954).normalize(), TransportMode::Radiance)[0] > 0.0);
    assert!(b(2).eval(wo, Vec3::new(-0.3, 0.0, 0.954).normalize(), TransportMode::Radiance)[0] > 0.0);
    for (body, want) in [
        (r#"<float name="alpha_u" value="0.1"/>"#, "unknown parameter `alpha_u`"),
        (r#"<rgb name="specular_transmittance" value="1"/>"#, "specular_transmittance"),
        (r#"<string name="distribution" value="phong"/>"#, "\"phong\""),
        (r#"<float name="alpha" value="0"/>"#, "alpha"),
        (r#"<float name="int_ior" value="-1.5"/>"#, "int_ior"),
        (r#"<string name="int_ior" value="unobtainium"/>"#, "unobtainium"),
        (r#"<float name="int_ior" value="1.000277"/>"#, "index-matched"),
        (r#"<string name="scattering" value="double"/>"#, "\"double\""),
        (r#"<string name="shadowing" value="vcavity"/>"#, "vcavity"),
        (
            r#"<string name="scattering" value="multiple"/><string name="shadowing" value="separable"/>"#,
            "height-correlated",
        ),
    ] {
        let (_, e) = err_body(&format!(
            "<shape type=\"rectangle\">\n<bsdf type=\"roughdielectric\">{body}</bsdf></shape>"
        ));
        assert!(e.contains(want) && e.contains("scene.xml:"), "{body}: {e}");
    }
}

/// Zero-area triangles (common in scans) are kept but reported: one warning per shape with
/// their count; a clean mesh gives none.
#[test]
fn zero_area_triangles_are_reported() {
    let mut d = ok(r#"<shape type="rectangle" id="panel"><bsdf type="diffuse"/></shape>"#);
    assert!(opal::scene::Scene::build(&d).unwrap().warnings.is_empty());
    let m = &mut d.shapes[0].mesh;
    let p = m.positions[0];
    m.positions.push(p);
    let n = m.positions.len() as u32;
    m.indices.push([0, n - 1, 1]); // two corners at the same point
    let scene = opal::scene::Scene::build(&d).unwrap();
    assert_eq!(scene.warnings.len(), 1, "{:?}", scene.warnings);
    let w = &scene.warnings[0];
    assert!(w.contains("panel") && w.contains("1 of 3 triangles") && w.contains("zero area"), "{w}");
}

#[test]
fn blendbsdf_is_a_dotted_face() {
    use opal::bsdf::Bxdfs;
    let d = ok(r#"<shape type="rectangle"><bsdf type="blendbsdf"><float name="weight" value="0.35"/>
        <bsdf type="dielectric"><float name="int_ior" value="1.52"/><float name="ext_ior" value="1"/></bsdf>
        <bsdf type="roughdielectric"><string name="distribution" value="ggx"/><float name="alpha" value="0.3"/>
          <float name="int_ior" value="1.52"/><float name="ext_ior" value="1"/></bsdf>
        </bsdf></shape>"#);
    match &d.shapes[0].bsdf {
        BsdfDesc::Lobe(Bxdfs::Dotted(b)) => {
            assert_eq!(b.coverage, 0.35);
            assert!(matches!(*b.a, Bxdfs::RoughDielectric(_)) && matches!(*b.b, Bxdfs::SmoothDielectric(_)));
            assert!((b.eta() - 1.52).abs() < 1e-6);
        }
        other => panic!("{other:?}"),
    }
    // weight outside [0, 1], one nested bsdf, a non-interface, different indices
    let (_, m) = err_body(
        r#"<shape type="rectangle"><bsdf type="blendbsdf"><float name="weight" value="1.5"/><bsdf type="dielectric"/><bsdf type="dielectric"/></bsdf></shape>"#,
    );
    assert!(m.contains("weight"), "{m}");
    let (_, m) = err_body(
        r#"<shape type="rectangle"><bsdf type="blendbsdf"><bsdf type="dielectric"/></bsdf></shape>"#,
    );
    assert!(m.contains("exactly two"), "{m}");
    let (_, m) = err_body(
        r#"<shape type="rectangle"><bsdf type="blendbsdf"><bsdf type="dielectric"/><bsdf type="diffuse"/></bsdf></shape>"#,
    );
    assert!(m.contains("exactly two"), "{m}");
    let (_, m) = err_body(
        r#"<shape type="rectangle"><bsdf type="blendbsdf"><bsdf type="dielectric"/><bsdf type="dielectric"><float name="int_ior" value="1.3"/></bsdf></bsdf></shape>"#,
    );
    assert!(m.contains("same index"), "{m}");
}

/// Found by `fuzz/` (target image_exr, the file committed as found): a header whose data
/// window declares ~2^52 samples made the exr crate try to allocate them. Now refused from the
/// header, naming the size.
#[test]
fn exr_with_an_absurd_data_window_is_refused_before_allocating() {
    let p = data("fuzz/exr_huge_data_window.exr");
    for e in [read_image(&p).unwrap_err().to_string(), read_exr_channels(&p).unwrap_err().to_string()] {
        assert!(e.contains("exr_huge_data_window.exr") && e.contains("above the limit"), "{e}");
    }
}

/// Fuzz find (`image_exr`, a timeout): a 40 KB EXR whose data window (x from 3 211 264 to 63)
/// passes the sample limit but whose chunks declare far more bytes than the file holds; the
/// `exr` crate filled a buffer of the declared size before reading. Refused from the chunk
/// table, naming the file, before any pixel buffer exists.
#[test]
fn exr_whose_chunks_overrun_the_file_is_refused() {
    let p = data("fuzz/exr_chunk_overruns_file.exr");
    for e in [read_image(&p).unwrap_err().to_string(), read_exr_channels(&p).unwrap_err().to_string()] {
        assert!(e.contains("exr_chunk_overruns_file.exr") && e.contains("declares"), "{e}");
    }
}

/// CRC-32 (IEEE) of PNG chunks, bit by bit (a test helper for hand-made headers).
fn png_crc(bytes: &[u8]) -> u32 {
    let mut c = 0xffff_ffffu32;
    for &b in bytes {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 != 0 { 0xedb8_8320 ^ (c >> 1) } else { c >> 1 };
        }
    }
    !c
}

/// A PNG whose header declares 65 536² RGB pixels (48 GiB as f32): refused with the file's name
/// and the size before anything is decoded, not an out-of-memory kill; a 2×2 PNG made the same
/// way still reads (the header check does not refuse small images).
#[test]
fn png_of_65536_squared_pixels_is_refused_before_allocating() {
    let png = |w: u32, h: u32, idat: &[u8]| -> Vec<u8> {
        let mut v = b"\x89PNG\r\n\x1a\n".to_vec();
        let mut chunk = |kind: &[u8], data: &[u8]| {
            v.extend_from_slice(&(data.len() as u32).to_be_bytes());
            let mut body = kind.to_vec();
            body.extend_from_slice(data);
            v.extend_from_slice(&body);
            v.extend_from_slice(&png_crc(&body).to_be_bytes());
        };
        let mut ihdr = Vec::new();
        ihdr.extend_from_slice(&w.to_be_bytes());
        ihdr.extend_from_slice(&h.to_be_bytes());
        ihdr.extend_from_slice(&[8, 2, 0, 0, 0]); // 8-bit RGB, deflate, no filter method, no interlace
        chunk(b"IHDR", &ihdr);
        chunk(b"IDAT", idat);
        chunk(b"IEND", &[]);
        v
    };
    let dir = tempfile::tempdir().unwrap();
    let huge = dir.path().join("huge.png");
    std::fs::write(&huge, png(65536, 65536, &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01])).unwrap();
    let e = read_image(&huge).unwrap_err().to_string();
    assert!(e.contains("huge.png") && e.contains("65536×65536") && e.contains("above the limit"), "{e}");

    // 2×2 RGB, each row a filter byte 0 and two black pixels, stored (uncompressed) deflate
    let raw = [0u8; 2 * (1 + 2 * 3)];
    let mut z = vec![0x78, 0x01, 0x01, raw.len() as u8, 0, !(raw.len() as u8), 0xff];
    z.extend_from_slice(&raw);
    let adler = {
        let (mut a, mut b) = (1u32, 0u32);
        for &x in &raw {
            a = (a + x as u32) % 65521;
            b = (b + a) % 65521;
        }
        (b << 16) | a
    };
    z.extend_from_slice(&adler.to_be_bytes());
    let small = dir.path().join("small.png");
    std::fs::write(&small, png(2, 2, &z)).unwrap();
    let img = read_image(&small).unwrap();
    assert_eq!((img.width, img.height), (2, 2));
}

// ---------------------------------------------------------------------------------------
// Mitsuba's metals, plastics, thin sheets; disk and cylinder

fn bsdf_of(body: &str) -> opal::scene::desc::BsdfDesc {
    ok(&format!("<shape type=\"rectangle\">{body}</shape>")).shapes[0].bsdf.clone()
}

#[test]
fn metal_and_coating_plugins_with_mitsuba_defaults() {
    use opal::bsdf::Bxdfs;
    use opal::bsdf::conductor::ConductorFresnel;
    use opal::bsdf::microfacet::Ndfs;
    use opal::scene::desc::BsdfDesc::{Coated, Lobe};
    // conductor: material "none" = mirror by default; a named metal; explicit eta/k
    let Lobe(Bxdfs::SmoothConductor(c)) = bsdf_of(r#"<bsdf type="conductor"/>"#) else { panic!() };
    assert_eq!(c.fresnel, ConductorFresnel::Mirror);
    let Lobe(Bxdfs::SmoothConductor(c)) =
        bsdf_of(r#"<bsdf type="conductor"><string name="material" value="Au"/></bsdf>"#)
    else {
        panic!()
    };
    let (eta, k) = opal::bsdf::ior::conductor_ior("Au").unwrap();
    assert_eq!(c.fresnel, ConductorFresnel::Complex { eta: Spectrum(eta), k: Spectrum(k) });
    let Lobe(Bxdfs::SmoothConductor(c)) = bsdf_of(
        r#"<bsdf type="conductor"><rgb name="eta" value="0.2, 0.9, 1.1"/><float name="k" value="3"/>
           <float name="specular_reflectance" value="0.8"/></bsdf>"#,
    ) else {
        panic!()
    };
    assert_eq!(
        c.fresnel,
        ConductorFresnel::Complex { eta: Spectrum::rgb(0.2, 0.9, 1.1), k: Spectrum::splat(3.0) }
    );
    assert_eq!(c.reflectance, Spectrum::splat(0.8));
    // roughconductor: beckmann, alpha 0.1 by default; anisotropic with alpha_u/alpha_v
    let Lobe(Bxdfs::RoughConductor(r)) = bsdf_of(r#"<bsdf type="roughconductor"/>"#) else { panic!() };
    assert!(matches!(r.ndf, Ndfs::Beckmann(b) if b.alpha == 0.1) && r.fresnel == ConductorFresnel::Mirror);
    let Lobe(Bxdfs::RoughConductor(r)) = bsdf_of(
        r#"<bsdf type="roughconductor"><string name="distribution" value="ggx"/>
           <float name="alpha_u" value="0.1"/><float name="alpha_v" value="0.3"/></bsdf>"#,
    ) else {
        panic!()
    };
    assert!(matches!(r.ndf, Ndfs::Anisotropic(a) if a.alpha_u == 0.1 && a.alpha_v == 0.3));
    // plastic: polypropylene in air, diffuse 0.5, linear
    let Lobe(Bxdfs::Plastic(p)) = bsdf_of(r#"<bsdf type="plastic"/>"#) else { panic!() };
    assert!((p.eta - 1.49 / 1.000277).abs() < 1e-6 && p.kd == Spectrum::splat(0.5) && !p.nonlinear);
    assert!((p.spec_weight - 1.0 / 1.5).abs() < 1e-6);
    let Lobe(Bxdfs::Plastic(p)) = bsdf_of(
        r#"<bsdf type="plastic"><string name="int_ior" value="diamond"/><float name="ext_ior" value="1.33"/></bsdf>"#,
    ) else {
        panic!()
    };
    assert!((p.eta - 2.419 / 1.33).abs() < 1e-6);
    let Lobe(Bxdfs::RoughPlastic(p)) = bsdf_of(r#"<bsdf type="roughplastic"/>"#) else { panic!() };
    assert!(matches!(p.ndf, Ndfs::Beckmann(b) if b.alpha == 0.1));
    // a bitmap diffuse reflectance: the texture is kept and looked up per hit
    let dir = tempfile::tempdir().unwrap();
    let mut img = opal::image::Image::new(2, 1);
    img.data[0] = Spectrum::splat(0.2);
    img.data[1] = Spectrum::splat(0.6);
    opal::image::write::write_exr(&img, std::fs::File::create(dir.path().join("t.exr")).unwrap()).unwrap();
    let xml = format!(
        r#"<scene version="3.0.0"><shape type="rectangle"><bsdf type="roughplastic">
           <texture type="bitmap" name="diffuse_reflectance"><string name="filename" value="{}"/></texture>
           </bsdf></shape></scene>"#,
        dir.path().join("t.exr").display()
    );
    std::fs::write(dir.path().join("s.xml"), xml).unwrap();
    let d = load_mitsuba_xml(&dir.path().join("s.xml"), &[]).unwrap();
    let Coated { model: Bxdfs::RoughPlastic(p), .. } = &d.shapes[0].bsdf else {
        panic!("{:?}", d.shapes[0].bsdf)
    };
    // sampling weight from the texture's mean 0.4: 1/(0.4 + 1)
    assert!((p.spec_weight - 1.0 / 1.4).abs() < 1e-5, "{}", p.spec_weight);
    opal::scene::Scene::build(&d).unwrap();
    // thindielectric: bk7 in air
    let Lobe(Bxdfs::ThinDielectric(t)) = bsdf_of(r#"<bsdf type="thindielectric"/>"#) else { panic!() };
    assert!((t.eta - 1.5046 / 1.000277).abs() < 1e-6);
}

#[test]
fn metal_and_coating_plugin_errors() {
    let (_, s) = err_body(
        r#"<shape type="rectangle"><bsdf type="conductor"><string name="material" value="Au"/><float name="eta" value="1"/></bsdf></shape>"#,
    );
    assert!(s.contains("either `material` or `eta`/`k`"), "{s}");
    let (_, s) = err_body(
        r#"<shape type="rectangle"><bsdf type="conductor"><string name="material" value="Xx"/></bsdf></shape>"#,
    );
    assert!(s.contains("material \"Xx\" is not known") && s.contains("Au"), "{s}");
    let (_, s) = err_body(
        r#"<shape type="rectangle"><bsdf type="roughconductor"><float name="alpha_u" value="0.1"/></bsdf></shape>"#,
    );
    assert!(s.contains("`alpha_u` and `alpha_v`"), "{s}");
    let (_, s) = err_body(
        r#"<shape type="rectangle"><bsdf type="roughplastic"><float name="alpha_u" value="0.1"/><float name="alpha_v" value="0.2"/></bsdf></shape>"#,
    );
    assert!(s.contains("unknown parameter `alpha_u`"), "{s}");
    let (_, s) = err_body(
        r#"<shape type="rectangle"><bsdf type="plastic"><string name="int_ior" value="glass"/></bsdf></shape>"#,
    );
    assert!(s.contains("\"glass\" is not a known material") && s.contains("bk7"), "{s}");
    let (_, s) = err_body(
        r#"<shape type="rectangle"><bsdf type="roughplastic"><string name="distribution" value="phong"/></bsdf></shape>"#,
    );
    assert!(s.contains("distribution \"phong\" is not supported"), "{s}");
    // as Mitsuba (which refuses transmissive BSDFs in twosided): a thin sheet has two sides already
    let d =
        ok(r#"<shape type="rectangle"><bsdf type="twosided"><bsdf type="thindielectric"/></bsdf></shape>"#);
    let s = opal::scene::Scene::build(&d).unwrap_err().to_string();
    assert!(s.contains("dielectric interface"), "{s}");
}

#[test]
fn disk_and_cylinder_shapes() {
    let d = ok(
        r#"<shape type="disk"><transform name="to_world"><scale value="2"/><translate z="1"/></transform></shape>"#,
    );
    let m = &d.shapes[0].mesh;
    assert!(m.positions.iter().all(|p| (p.z - 1.0).abs() < 1e-6 && p.truncate().length() <= 2.0 + 1e-5));
    assert!(m.normals.iter().all(|n| (*n - Vec3::Z).length() < 1e-6));
    let d =
        ok(r#"<shape type="cylinder"><point name="p0" value="1, 0, 0"/><point name="p1" value="1, 0, 2"/>
                  <float name="radius" value="0.5"/><boolean name="flip_normals" value="true"/></shape>"#);
    let m = &d.shapes[0].mesh;
    for (p, n) in m.positions.iter().zip(&m.normals) {
        let radial = Vec3::new(p.x - 1.0, p.y, 0.0);
        assert!((radial.length() - 0.5).abs() < 1e-5 && p.z >= -1e-6 && p.z <= 2.0 + 1e-5);
        assert!((*n + radial / 0.5).length() < 1e-4, "flipped normals point inwards: {p} {n}");
    }
    let (_, s) = err_body(r#"<shape type="cylinder"><float name="radius" value="-1"/></shape>"#);
    assert!(s.contains("cylinder radius must be > 0"), "{s}");
}

/// `shapegroup` + `instance`: each instance adds the group's shapes with its `to_world` applied
/// after theirs (positions and normals), ids `<instance>.<shape>`, the group itself renders
/// nothing; emitters in a group, a group without id, a reference to a non-group are errors.
#[test]
fn instances_copy_and_transform_the_group() {
    let group = r#"<shape type="shapegroup" id="g">
            <shape type="rectangle" id="r"><transform name="to_world"><translate z="1"/></transform></shape>
            <shape type="disk"><bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.3, 0.4"/></bsdf></shape>
        </shape>"#;
    let d = ok(&format!(
        r#"{group}
        <shape type="instance" id="a"><ref id="g"/></shape>
        <shape type="instance"><ref id="g"/><transform name="to_world"><scale x="2"/><rotate y="1" angle="90"/><translate y="3"/></transform></shape>"#
    ));
    assert_eq!(d.shapes.len(), 4, "two instances of a two-shape group, the group itself not rendered");
    assert_eq!(d.shapes[0].id, "a.r");
    assert!(d.shapes[2].id.starts_with("instance_") && d.shapes[2].id.ends_with(".r"), "{}", d.shapes[2].id);
    assert!(d.shapes[0].mesh.positions.iter().all(|p| (p.z - 1.0).abs() < 1e-6));
    // second instance: (x, y, z) → scale x by 2 → rotate 90° about y: (x', z') = (z, −x) → +3 in y
    for (p0, p1) in d.shapes[0].mesh.positions.iter().zip(&d.shapes[2].mesh.positions) {
        let want = Vec3::new(p0.z, p0.y + 3.0, -2.0 * p0.x);
        assert!(close(*p1, want, 1e-5), "{p0} → {p1}, want {want}");
    }
    // the rectangle's normal +z becomes +x
    assert!(
        d.shapes[2].mesh.normals.iter().all(|n| close(*n, Vec3::X, 1e-5)),
        "{:?}",
        d.shapes[2].mesh.normals
    );
    match &d.shapes[3].bsdf {
        BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(c) } => assert!((c[1] - 0.3).abs() < 1e-6),
        b => panic!("the group's bsdf travels with the copy, got {b:?}"),
    }
    // vertex normals by the inverse transpose: a unit sphere scaled by 2 in y has the normal
    // ∝ (x, y/4, z) at the scaled point (x, y, z)
    let d = ok(r#"<shape type="shapegroup" id="s"><shape type="sphere"/></shape>
        <shape type="instance"><ref id="s"/><transform name="to_world"><scale y="2"/></transform></shape>"#);
    let m = &d.shapes[0].mesh;
    assert!(!m.normals.is_empty());
    for (p, n) in m.positions.iter().zip(&m.normals) {
        let want = Vec3::new(p.x, p.y / 4.0, p.z).normalize();
        assert!(close(*n, want, 1e-4), "{p}: {n} vs {want}");
    }
    let (_, s) = err_body(
        r#"<shape type="shapegroup" id="g"><shape type="rectangle"><emitter type="area"><rgb name="radiance" value="1"/></emitter></shape></shape>"#,
    );
    assert!(s.contains("emitters cannot be instanced"), "{s}");
    let (_, s) = err_body(r#"<shape type="shapegroup"><shape type="rectangle"/></shape>"#);
    assert!(s.contains("needs an `id`"), "{s}");
    let (_, s) = err_body(r#"<bsdf type="diffuse" id="m"/><shape type="instance"><ref id="m"/></shape>"#);
    assert!(s.contains("exactly one <ref"), "{s}");
    let (_, s) = err_body(r#"<shape type="instance"><ref id="nothing"/></shape>"#);
    assert!(s.contains("no bsdf, texture or shapegroup with this id"), "{s}");
}

/// A binary PLY that declares 2.7·10¹³ rows of an element with no properties (found by the fuzz
/// target `ply` as a hang): read at once, with an error for what the file really lacks, not a
/// loop over empty rows.
#[test]
fn ply_with_a_huge_count_of_empty_rows_does_not_hang() {
    let p = data("fuzz/ply_empty_element_huge_count.ply");
    let t = std::time::Instant::now();
    let r = opal::geometry::ply::read_ply(&p);
    assert!(t.elapsed().as_secs_f64() < 5.0, "took {:?}", t.elapsed());
    if let Err(e) = r {
        assert!(e.to_string().contains("ply_empty_element_huge_count.ply"), "{e}");
    }
}

/// `constant`, `envmap`, `spot`, `directional`: parameters, Mitsuba's defaults, the built
/// lights, and the error cases.
#[test]
fn environment_spot_and_directional_emitters() {
    use opal::light::Light;
    let d = ok(r#"<emitter type="constant"/>
        <emitter type="constant"><rgb name="radiance" value="0.5, 1, 2"/></emitter>
        <emitter type="spot"/>
        <emitter type="spot"><float name="cutoff_angle" value="40"/><float name="beam_width" value="10"/>
            <rgb name="intensity" value="3"/>
            <transform name="to_world"><lookat origin="1, 2, 3" target="1, 0, 3" up="0, 0, 1"/></transform></emitter>
        <emitter type="directional"/>
        <emitter type="directional"><vector name="direction" value="0, -2, 0"/><float name="irradiance" value="4"/></emitter>
        <emitter type="directional"><transform name="to_world"><rotate x="1" angle="90"/></transform></emitter>"#);
    let e = &d.emitters;
    assert!(matches!(e[0], EmitterDesc::Constant { radiance } if radiance == Spectrum::ONE));
    assert!(matches!(e[1], EmitterDesc::Constant { radiance } if radiance == Spectrum::rgb(0.5, 1.0, 2.0)));
    assert!(matches!(e[2], EmitterDesc::Spot { cutoff_deg, beam_width_deg, intensity, ref texture, .. }
            if cutoff_deg == 20.0 && beam_width_deg == 15.0 && intensity == Spectrum::ONE && texture.is_none()));
    let EmitterDesc::Spot { to_world, cutoff_deg, beam_width_deg, .. } = &e[3] else { panic!("{:?}", e[3]) };
    assert_eq!((*cutoff_deg, *beam_width_deg), (40.0, 10.0));
    assert!(close(to_world.transform_point3(Vec3::ZERO), Vec3::new(1.0, 2.0, 3.0), 1e-6));
    assert!(matches!(e[4], EmitterDesc::Directional { direction, .. } if direction == Vec3::Z));
    assert!(
        matches!(e[5], EmitterDesc::Directional { direction, irradiance } if direction == -Vec3::Y && irradiance == Spectrum::splat(4.0))
    );
    let EmitterDesc::Directional { direction, .. } = e[6] else { panic!() };
    assert!(close(direction, -Vec3::Y, 1e-6), "{direction}");
    // built: the spot shines down from (1, 2, 3), full intensity on its axis
    let scene = opal::scene::Scene::build(&d).unwrap();
    let Light::Spot(sp) = &scene.lights[3] else { panic!() };
    assert!(close(sp.position, Vec3::new(1.0, 2.0, 3.0), 1e-6));
    assert_eq!(sp.intensity(-Vec3::Y), Spectrum::splat(3.0));
    assert!(sp.intensity(Vec3::Y).is_black());
    assert_eq!(scene.env_lights(), &[0, 1]);

    // envmap: a 4×2 EXR, scale and to_world
    let dir = tempfile::tempdir().unwrap();
    let mut img = opal::image::Image::new(4, 2);
    img.data.iter_mut().enumerate().for_each(|(k, v)| *v = Spectrum::splat(k as f32 + 1.0));
    opal::image::write::write_exr(&img, std::fs::File::create(dir.path().join("env.exr")).unwrap()).unwrap();
    let xml = scene_xml(
        r#"<emitter type="envmap"><string name="filename" value="env.exr"/><float name="scale" value="2"/>
           <transform name="to_world"><rotate y="1" angle="90"/></transform></emitter>"#,
    );
    std::fs::write(dir.path().join("scene.xml"), xml).unwrap();
    let d = load_mitsuba_xml(&dir.path().join("scene.xml"), &[]).unwrap();
    let EmitterDesc::EnvMap { image, scale, .. } = &d.emitters[0] else { panic!() };
    assert_eq!((image.width, image.height, *scale), (4, 2, 2.0));
    let scene = opal::scene::Scene::build(&d).unwrap();
    // straight up: the first row (all texels of the pole row are averaged by the lookup of
    // u; at +y the row's bilinear weights still apply in u) — 2 × row 0
    let up = scene.lights[0].le_escaped(Vec3::Y);
    assert!(up[0] >= 2.0 && up[0] <= 8.0, "{up:?}");
    let down = scene.lights[0].le_escaped(-Vec3::Y);
    assert!(down[0] >= 10.0 && down[0] <= 16.0, "{down:?}");

    // errors
    let (_, s) = err_body(r#"<emitter type="envmap"/>"#);
    assert!(s.contains("`filename` is required"), "{s}");
    let (_, s) = err_body(r#"<emitter type="envmap"><string name="filename" value="none.exr"/></emitter>"#);
    assert!(s.contains("envmap") && s.contains("none.exr"), "{s}");
    let (_, s) = err_body(r#"<emitter type="constant"><float name="scale" value="2"/></emitter>"#);
    assert!(s.contains("scale"), "{s}");
    let (_, s) = err_body(
        r#"<emitter type="directional"><vector name="direction" value="0, 0, 1"/>
           <transform name="to_world"><rotate x="1" angle="90"/></transform></emitter>"#,
    );
    assert!(s.contains("either `direction` or `to_world`"), "{s}");
    let build_err = |body: &str| opal::scene::Scene::build(&ok(body)).unwrap_err().to_string();
    let s = build_err(
        r#"<emitter type="spot"><float name="cutoff_angle" value="10"/><float name="beam_width" value="12"/></emitter>"#,
    );
    assert!(s.contains("beam_width"), "{s}");
    let s = build_err(r#"<emitter type="spot"><float name="cutoff_angle" value="95"/></emitter>"#);
    assert!(s.contains("cutoff_angle"), "{s}");
    let s = build_err(r#"<emitter type="directional"><rgb name="irradiance" value="-1"/></emitter>"#);
    assert!(s.contains("irradiance"), "{s}");
    let s =
        build_err(r#"<emitter type="spot"><transform name="to_world"><scale x="2"/></transform></emitter>"#);
    assert!(s.contains("rotation"), "{s}");
}
