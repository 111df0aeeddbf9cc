//! Runs the real `opal` binary: `render` on a small scene, and every kind of bad input
//! (exit code 2, a message naming the file/line/value, no output file left behind).

use std::path::{Path, PathBuf};
use std::process::Command;

fn opal() -> Command {
    Command::new(env!("CARGO_BIN_EXE_opal"))
}

fn cbox_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../opal/tests/data/cbox")
}

/// A small one-sensor scene: a floor quad lit by a rectangle light, seen from above.
fn write_scene(dir: &Path, shape_extra: &str, light_scale: &str) -> PathBuf {
    let xml = format!(
        r#"<scene version="3.0.0">
    <sensor type="perspective" id="top">
        <float name="fov" value="60"/>
        <transform name="to_world"><lookat origin="0, 3, 0.01" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="24"/></film>
    </sensor>
    <shape type="rectangle" id="floor">
        <transform name="to_world"><rotate x="1" angle="-90"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.5, 0.5"/></bsdf>
    </shape>
    <shape type="rectangle" id="lamp">
        <transform name="to_world"><scale value="{light_scale}"/><rotate x="1" angle="90"/><translate y="2"/></transform>
        <emitter type="area"><rgb name="radiance" value="5, 5, 5"/></emitter>
    </shape>
    {shape_extra}
</scene>"#
    );
    let p = dir.join("scene.xml");
    std::fs::write(&p, xml).unwrap();
    p
}

fn only_inputs_left(dir: &Path, inputs: &[&str]) {
    for e in std::fs::read_dir(dir).unwrap() {
        let name = e.unwrap().file_name().into_string().unwrap();
        assert!(inputs.contains(&name.as_str()), "unexpected file left behind: {name}");
    }
}

#[test]
fn renders_a_scene_with_json_report() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path(), "", "0.3");
    let out = opal()
        .args(["render", scene.to_str().unwrap(), "-o"])
        .arg(dir.path().join("out.exr"))
        .arg("--png")
        .arg(dir.path().join("out.png"))
        .args(["--spp", "16", "--json", "--threads", "2"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["spp"], 16);
    assert_eq!(report["nonfinite_samples"], 0);
    // the floor is lit: mean radiance is positive
    assert!(report["mean_rgb"][0].as_f64().unwrap() > 0.0);
    let img = opal::image::read::read_image(&dir.path().join("out.exr")).unwrap();
    assert_eq!((img.width, img.height), (32, 24));
    assert!(dir.path().join("out.png").exists());
}

#[test]
fn renders_the_bundled_cornell_box_by_sensor_id() {
    let dir = tempfile::tempdir().unwrap();
    let out = opal()
        .arg("render")
        .arg(cbox_dir().join("scene.xml"))
        .arg("-o")
        .arg(dir.path().join("v.exr"))
        .args(["--sensor", "view_05", "--spp", "2", "--max-depth", "3", "--quiet"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let out = opal()
        .arg("render")
        .arg(cbox_dir().join("scene.xml"))
        .arg("-o")
        .arg(dir.path().join("w.exr"))
        .args(["--sensor", "nope"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("view_00"));
}

fn expect_bad(dir: &Path, scene: &Path, needles: &[&str]) {
    let out = opal().arg("render").arg(scene).arg("-o").arg(dir.join("out.exr")).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "stderr: {err}");
    for n in needles {
        assert!(err.contains(n), "message lacks '{n}': {err}");
    }
    assert!(!dir.join("out.exr").exists(), "partial output left behind");
}

#[test]
fn bad_inputs_exit_2_with_clear_messages() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // missing file
    expect_bad(d, &d.join("missing.xml"), &["missing.xml"]);
    // malformed XML: line number
    std::fs::write(d.join("bad.xml"), "<scene version=\"3.0.0\">\n  <shape type=\"obj\">\n</scene>\n")
        .unwrap();
    expect_bad(d, &d.join("bad.xml"), &["bad.xml", ":3:"]);
    // unknown plugin
    std::fs::write(
        d.join("plugin.xml"),
        "<scene version=\"3.0.0\">\n<bsdf type=\"principled\" id=\"x\"/>\n</scene>\n",
    )
    .unwrap();
    expect_bad(d, &d.join("plugin.xml"), &["plugin.xml", "principled"]);
    // mesh with NaN
    std::fs::write(d.join("nan.obj"), "v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n").unwrap();
    let s = write_scene(d, r#"<shape type="obj"><string name="filename" value="nan.obj"/></shape>"#, "0.3");
    expect_bad(d, &s, &["nan.obj"]);
    // mesh made only of degenerate triangles
    std::fs::write(d.join("flat.obj"), "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n").unwrap();
    let s = write_scene(d, r#"<shape type="obj"><string name="filename" value="flat.obj"/></shape>"#, "0.3");
    expect_bad(d, &s, &["flat.obj"]);
    // texture that fails to decode
    std::fs::write(d.join("tex.png"), b"not a png").unwrap();
    let s = write_scene(
        d,
        r#"<shape type="rectangle"><bsdf type="diffuse"><texture type="bitmap" name="reflectance"><string name="filename" value="tex.png"/></texture></bsdf></shape>"#,
        "0.3",
    );
    expect_bad(d, &s, &["tex.png"]);
    // zero-area light
    let s = write_scene(d, "", "0");
    expect_bad(d, &s, &["lamp"]);
    // camera that sees nothing
    let xml = std::fs::read_to_string(write_scene(d, "", "0.3"))
        .unwrap()
        .replace("target=\"0, 0, 0\"", "target=\"0, 6, 0\"");
    std::fs::write(d.join("blind.xml"), xml).unwrap();
    expect_bad(d, &d.join("blind.xml"), &["sees no geometry"]);
    // output equal to the input is refused and the input is untouched
    let s = write_scene(d, "", "0.3");
    let before = std::fs::read(&s).unwrap();
    let out = opal().arg("render").arg(&s).arg("-o").arg(&s).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert_eq!(std::fs::read(&s).unwrap(), before);
    only_inputs_left(
        d,
        &["scene.xml", "bad.xml", "plugin.xml", "nan.obj", "flat.obj", "tex.png", "blind.xml"],
    );
}

#[test]
fn renders_method_b_lobe_plugins_from_xml() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let lobe = r#"<shape type="rectangle"><transform name="to_world"><rotate x="1" angle="-90"/><translate y="0.01"/></transform>
        <bsdf type="pow16"><float name="exponent" value="20"/><string name="normalisation" value="paper"/><rgb name="specular_reflectance" value="0.9, 0.8, 0.7"/></bsdf></shape>"#;
    let s = write_scene(d, lobe, "0.3");
    let out = opal()
        .arg("render")
        .arg(&s)
        .arg("-o")
        .arg(d.join("lobe.exr"))
        .args(["--spp", "4", "--json"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(report["mean_rgb"][0].as_f64().unwrap() > 0.0);
    // an unknown parameter of a lobe plugin is an error naming it
    let bad =
        write_scene(d, r#"<bsdf type="phong" id="p"><float name="shininess" value="3"/></bsdf>"#, "0.3");
    let out = opal().arg("render").arg(&bad).arg("-o").arg(d.join("bad.exr")).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("shininess"));
    // an invalid value is refused by the shared registry
    let bad =
        write_scene(d, r#"<bsdf type="pow16" id="p"><float name="exponent" value="-1"/></bsdf>"#, "0.3");
    let out = opal().arg("render").arg(&bad).arg("-o").arg(d.join("bad.exr")).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("exponent"));
}

/// The same seed gives the same file, byte for byte, whatever the thread count: pixels and
/// the EXR's block order (the compressed blocks are written in order, not as they finish).
#[test]
fn the_same_seed_writes_the_same_bytes_on_one_and_two_threads() {
    let dir = tempfile::tempdir().unwrap();
    let mut files = Vec::new();
    for threads in ["1", "2", "2"] {
        let out = dir.path().join(format!("v{}.exr", files.len()));
        let st = opal()
            .arg("render")
            .arg(cbox_dir().join("scene.xml"))
            .arg("-o")
            .arg(&out)
            .args(["--spp", "2", "--max-depth", "4", "--seed", "7", "--threads", threads, "--quiet"])
            .output()
            .unwrap();
        assert!(st.status.success(), "{}", String::from_utf8_lossy(&st.stderr));
        files.push(std::fs::read(&out).unwrap());
    }
    assert!(files[0].len() > 1000);
    assert!(files.iter().all(|f| *f == files[0]), "EXR bytes differ between runs");
}

/// Ctrl-C during `opal render`: exit code 130, a message saying nothing was written, and no
/// file under the output's name.
#[cfg(unix)]
#[test]
fn interrupted_render_writes_nothing_and_exits_130() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("v.exr");
    let child = opal()
        .arg("render")
        .arg(cbox_dir().join("scene.xml"))
        .arg("-o")
        .arg(&out)
        .args(["--spp", "100000", "--quiet"])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // the scene loads within a few hundred milliseconds; the render takes minutes
    std::thread::sleep(std::time::Duration::from_millis(1500));
    let k = Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap();
    assert!(k.success());
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(130), "{err}");
    assert!(err.contains("no output file of this run was written"), "{err}");
    assert!(!out.exists());
}
