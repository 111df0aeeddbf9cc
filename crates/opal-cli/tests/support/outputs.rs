//! Checks of the `opal delight` output files shared by the tests in `tests/delight.rs`: the glTF
//! binary parsed back (container, accessors against the OBJ, the embedded PNG against the albedo
//! EXR) and the images of report.html (relative paths to files that exist and decode; no
//! network resources).

use std::collections::BTreeMap;
use std::path::Path;

fn u32_at(b: &[u8], o: usize) -> usize {
    u32::from_le_bytes(b[o..o + 4].try_into().unwrap()) as usize
}

/// The JSON document and BIN chunk of a `.glb`, checking the container layout on the way: header
/// (magic, version 2, total length), JSON chunk first and padded to 4 bytes, BIN chunk padded to
/// 4 bytes ending the file.
pub fn parse_glb(b: &[u8]) -> (serde_json::Value, Vec<u8>) {
    assert!(b.len() >= 20, "{} bytes", b.len());
    assert_eq!(&b[0..4], b"glTF", "magic");
    assert_eq!(u32_at(b, 4), 2, "container version");
    assert_eq!(u32_at(b, 8), b.len(), "total length");
    let jl = u32_at(b, 12);
    assert_eq!(&b[16..20], b"JSON");
    assert_eq!(jl % 4, 0, "JSON chunk padded to 4 bytes");
    let doc: serde_json::Value = serde_json::from_slice(&b[20..20 + jl]).unwrap();
    let bl = u32_at(b, 20 + jl);
    assert_eq!(&b[24 + jl..28 + jl], b"BIN\0");
    assert_eq!(bl % 4, 0, "BIN chunk padded to 4 bytes");
    assert_eq!(28 + jl + bl, b.len(), "BIN chunk ends the file");
    (doc, b[28 + jl..].to_vec())
}

/// Bytes of buffer view `i`.
fn view<'a>(doc: &serde_json::Value, bin: &'a [u8], i: &serde_json::Value) -> &'a [u8] {
    let v = &doc["bufferViews"][i.as_u64().unwrap() as usize];
    assert_eq!(v["buffer"], 0);
    let off = v["byteOffset"].as_u64().unwrap_or(0) as usize;
    assert_eq!(off % 4, 0, "buffer view aligned to 4 bytes");
    &bin[off..off + v["byteLength"].as_u64().unwrap() as usize]
}

/// `scene.glb` against the other outputs: one node/mesh/material per recovered object; POSITION,
/// TEXCOORD_0 and the indices equal the OBJ's (OBJ `vt` flipped: v_gltf = 1 − v_obj), POSITION
/// min/max the data's bounds; the material is diffuse (metallic 0, roughness 1) and its
/// base-colour texture is a PNG in the buffer decoding to the 8-bit sRGB encoding of
/// `albedo/<obj>.exr`.
pub fn check_glb(out: &Path, report: &serde_json::Value) {
    let (doc, bin) = parse_glb(&std::fs::read(out.join("scene.glb")).unwrap());
    assert_eq!(doc["asset"]["version"], "2.0");
    assert_eq!(doc["buffers"][0]["byteLength"].as_u64().unwrap() as usize, bin.len());
    let objects = report["objects"].as_array().unwrap();
    assert!(!objects.is_empty());
    assert_eq!(doc["nodes"].as_array().unwrap().len(), objects.len());
    assert_eq!(
        doc["scenes"][doc["scene"].as_u64().unwrap() as usize]["nodes"].as_array().unwrap().len(),
        objects.len()
    );
    for o in objects {
        let id = o["id"].as_str().unwrap();
        let k = doc["meshes"].as_array().unwrap().iter().position(|m| m["name"] == id).unwrap();
        let prim = &doc["meshes"][k]["primitives"][0];
        let acc = |name: &str| &doc["accessors"][prim["attributes"][name].as_u64().unwrap() as usize];
        let floats = |a: &serde_json::Value| -> Vec<f32> {
            assert_eq!(a["componentType"], 5126);
            view(&doc, &bin, &a["bufferView"])
                .chunks(4)
                .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
                .collect()
        };
        // the OBJ written beside it
        let obj = std::fs::read_to_string(out.join(format!("meshes/{id}.obj"))).unwrap();
        let rows = |tag: &str| -> Vec<f32> {
            obj.lines()
                .filter_map(|l| l.strip_prefix(tag))
                .flat_map(|l| l.split_whitespace().map(|x| x.parse::<f32>().unwrap()).collect::<Vec<_>>())
                .collect()
        };
        let pos = acc("POSITION");
        let p = floats(pos);
        assert_eq!(p, rows("v "), "{id}: positions");
        assert_eq!(pos["count"].as_u64().unwrap() as usize * 3, p.len());
        for c in 0..3 {
            let axis: Vec<f32> = p.iter().skip(c).step_by(3).copied().collect();
            let lo = axis.iter().copied().fold(f32::INFINITY, f32::min);
            let hi = axis.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            assert_eq!(pos["min"][c].as_f64().unwrap(), lo as f64, "{id}: min");
            assert_eq!(pos["max"][c].as_f64().unwrap(), hi as f64, "{id}: max");
        }
        let uv = floats(acc("TEXCOORD_0"));
        let vt = rows("vt ");
        assert_eq!(uv.len(), vt.len());
        for (a, b) in uv.chunks(2).zip(vt.chunks(2)) {
            assert_eq!(a[0], b[0]);
            assert!((a[1] - (1.0 - b[1])).abs() < 1e-6, "{id}: v {} vs OBJ vt {}", a[1], b[1]);
        }
        if let Some(n) = prim["attributes"].get("NORMAL") {
            let n = floats(&doc["accessors"][n.as_u64().unwrap() as usize]);
            assert_eq!(n.len(), p.len());
            for v in n.chunks(3) {
                assert!(((v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt() - 1.0).abs() < 1e-5, "{v:?}");
            }
        }
        let ia = &doc["accessors"][prim["indices"].as_u64().unwrap() as usize];
        assert_eq!(ia["componentType"], 5125);
        let idx: Vec<u32> = view(&doc, &bin, &ia["bufferView"])
            .chunks(4)
            .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
            .collect();
        let faces: Vec<u32> = obj
            .lines()
            .filter_map(|l| l.strip_prefix("f "))
            .flat_map(|l| {
                l.split_whitespace()
                    .map(|c| c.split('/').next().unwrap().parse::<u32>().unwrap() - 1)
                    .collect::<Vec<_>>()
            })
            .collect();
        assert_eq!(ia["count"].as_u64().unwrap() as usize, faces.len());
        assert_eq!(idx, faces, "{id}: indices");
        // material and its texture
        let m = &doc["materials"][prim["material"].as_u64().unwrap() as usize];
        let pbr = &m["pbrMetallicRoughness"];
        assert_eq!(pbr["metallicFactor"].as_f64(), Some(0.0));
        assert_eq!(pbr["roughnessFactor"].as_f64(), Some(1.0));
        let tex = &doc["textures"][pbr["baseColorTexture"]["index"].as_u64().unwrap() as usize];
        let img = &doc["images"][tex["source"].as_u64().unwrap() as usize];
        assert_eq!(img["mimeType"], "image/png");
        let png = image::load_from_memory_with_format(
            view(&doc, &bin, &img["bufferView"]),
            image::ImageFormat::Png,
        )
        .unwrap()
        .to_rgb8();
        let kd = opal::image::read::read_image(&out.join(format!("albedo/{id}.exr"))).unwrap();
        assert_eq!((png.width() as usize, png.height() as usize), (kd.width, kd.height));
        assert_eq!(png.into_raw(), opal::image::write::to_srgb8(&kd, 1.0), "{id}: texture = sRGB albedo");
    }
}

/// Attributes of every `<img>` tag of an HTML text (double-quoted values).
pub fn img_tags(html: &str) -> Vec<BTreeMap<String, String>> {
    let mut tags = Vec::new();
    let mut rest = html;
    while let Some(i) = rest.find("<img ") {
        let end = rest[i..].find('>').unwrap() + i;
        let mut attrs = BTreeMap::new();
        let mut t = &rest[i + 5..end];
        while let Some(eq) = t.find("=\"") {
            let name = t[..eq].trim().rsplit(' ').next().unwrap().to_string();
            let close = t[eq + 2..].find('"').unwrap() + eq + 2;
            attrs.insert(name, t[eq + 2..close].to_string());
            t = &t[close + 1..];
        }
        tags.push(attrs);
        rest = &rest[end..];
    }
    tags
}

/// A URL path with `%XX` escapes decoded.
fn percent_decode(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' && i + 2 < b.len() {
            out.push(u8::from_str_radix(&s[i + 1..i + 3], 16).unwrap());
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8(out).unwrap()
}

/// report.html: every `<img>` source is a relative path inside the output folder to a PNG that
/// decodes; no scripts, style sheets or fonts from elsewhere; per view the photo, the re-render
/// and the error map with a colour bar each; per object a texture preview at least 512 px wide.
pub fn check_report_images(out: &Path, report: &serde_json::Value) {
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    for bad in ["http:", "https:", "<script", "<link", "url(", "@import", "file:"] {
        assert!(!html.contains(bad), "report.html contains '{bad}'");
    }
    let tags = img_tags(&html);
    let srcs: Vec<String> = tags.iter().map(|t| percent_decode(&t["src"])).collect();
    for s in &srcs {
        assert!(
            !s.is_empty() && !s.starts_with('/') && !s.contains(':') && !s.split('/').any(|c| c == ".."),
            "not a relative path inside the output folder: {s}"
        );
        let img = image::open(out.join(s)).unwrap_or_else(|e| panic!("{s}: {e}"));
        assert!(img.width() > 0 && img.height() > 0, "{s}");
    }
    for v in report["rerenders"].as_array().unwrap() {
        for k in ["photo", "rerender", "error_map"] {
            let p = v[k].as_str().unwrap();
            assert!(srcs.iter().any(|s| s == p), "{p} not shown");
        }
    }
    let rr = report["rerenders"].as_array().unwrap().len();
    let bars = tags.iter().filter(|t| t.get("class").is_some_and(|c| c == "bar")).count();
    assert!(bars >= 3 * rr, "{bars} colour bars for {rr} views");
    for o in report["objects"].as_array().unwrap() {
        let tex = o["texture"].as_str().unwrap().replace(".exr", ".png");
        let t = tags
            .iter()
            .find(|t| percent_decode(&t["src"]) == tex)
            .unwrap_or_else(|| panic!("{tex} not shown"));
        let w: usize = t["width"].parse().unwrap();
        assert!(w >= 512, "{tex} shown {w} px wide");
    }
}
