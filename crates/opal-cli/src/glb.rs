//! glTF 2.0 binary (`.glb`) writer for textured triangle meshes: one node, mesh and material per
//! object, the base-colour texture embedded as PNG in the binary buffer.
//!
//! Conventions (glTF 2.0 specification):
//! * Positions and normals are written as given: Opal's scene (world) frame becomes the glTF frame
//!   unchanged, axis for axis, scene units taken as metres. glTF is right-handed with +Y up; a
//!   Y-up Mitsuba scene (the usual case) therefore shows upright, a Z-up scene lies on its back in
//!   a glTF viewer (not flipped here: the file keeps the scene's coordinates).
//! * Triangles keep their order (counter-clockwise = front in both Opal and glTF); materials are
//!   single-sided like Mitsuba's `diffuse`.
//! * Texture coordinates are Opal's (Mitsuba's) convention, v = 0 at the top image row, which is
//!   also glTF's: no flip (an OBJ `vt` is flipped, a glTF `TEXCOORD_0` is not).
//! * The texture must be an 8-bit sRGB PNG (glTF's `baseColorTexture` is sRGB-encoded); the
//!   material is `pbrMetallicRoughness` with metallic 0 and roughness 1 (a diffuse surface).
//! * Normals are written unit length (the validator requires it); a zero or non-finite normal
//!   is replaced by the area-weighted normal of the triangles around the vertex.
//!
//! Layout: a 12-byte header, a JSON chunk padded with spaces and a BIN chunk padded with zeros to
//! 4 bytes; every buffer view starts at a multiple of 4. Tests: the unit tests below (container
//! parsed back) and `tests/delight.rs` (the file `opal delight` writes; the Khronos validator in
//! an ignored test, see docs/testing.md).

use anyhow::{Result, bail};
use opal::geometry::TriangleMesh;
use opal::math::Vec3;
use serde_json::{Value, json};

/// One object of a `.glb`.
pub struct GlbObject<'a> {
    /// Node, mesh and material name.
    pub name: &'a str,
    /// Mesh with per-vertex UVs (and optionally normals), in the scene frame.
    pub mesh: &'a TriangleMesh,
    /// Base-colour texture: an 8-bit sRGB PNG file's bytes.
    pub base_colour_png: &'a [u8],
}

/// glTF constants (component types, buffer targets, sampler settings).
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const LINEAR: u32 = 9729;
const CLAMP_TO_EDGE: u32 = 33071;

/// The binary buffer under construction and its buffer views.
#[derive(Default)]
struct Bin {
    data: Vec<u8>,
    views: Vec<Value>,
}

impl Bin {
    /// Appends `bytes` at the next multiple of 4 as a new buffer view; returns its index.
    fn view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
        self.data.resize(self.data.len().next_multiple_of(4), 0);
        let mut v = json!({"buffer": 0, "byteOffset": self.data.len(), "byteLength": bytes.len()});
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        self.data.extend_from_slice(bytes);
        self.views.push(v);
        self.views.len() - 1
    }
}

fn f32_bytes(v: impl IntoIterator<Item = f32>) -> Vec<u8> {
    v.into_iter().flat_map(f32::to_le_bytes).collect()
}

/// Unit normals of `m` (empty when the mesh has none); degenerate ones replaced by the
/// area-weighted normal of the adjacent triangles (+Y if that is degenerate too).
fn unit_normals(m: &TriangleMesh) -> Vec<Vec3> {
    if m.normals.is_empty() {
        return Vec::new();
    }
    let ok = |n: Vec3| n.is_finite() && n.length_squared() > 1e-30;
    let mut face: Option<Vec<Vec3>> = None;
    m.normals
        .iter()
        .enumerate()
        .map(|(i, &n)| {
            if ok(n) {
                return n.normalize();
            }
            let acc = face.get_or_insert_with(|| {
                let mut acc = vec![Vec3::ZERO; m.positions.len()];
                for (t, idx) in m.indices.iter().enumerate() {
                    let [a, b, c] = m.triangle(t);
                    let f = (b - a).cross(c - a);
                    if f.is_finite() {
                        idx.iter().for_each(|&k| acc[k as usize] += f);
                    }
                }
                acc
            });
            if ok(acc[i]) { acc[i].normalize() } else { Vec3::Y }
        })
        .collect()
}

/// Bytes of a `.glb` holding `objects` (generator string in `asset.generator`).
pub fn glb_bytes(objects: &[GlbObject], generator: &str) -> Result<Vec<u8>> {
    let mut bin = Bin::default();
    let (mut accessors, mut meshes, mut materials, mut textures, mut images, mut nodes) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (k, o) in objects.iter().enumerate() {
        let m = o.mesh;
        let n = m.positions.len();
        if n == 0 || m.indices.is_empty() {
            bail!("glTF output: object '{}' has no triangles", o.name);
        }
        if m.uvs.len() != n || !(m.normals.is_empty() || m.normals.len() == n) {
            bail!("glTF output: object '{}' needs one UV (and normal, if any) per vertex", o.name);
        }
        if !m.positions.iter().all(|p| p.is_finite()) || !m.uvs.iter().all(|t| t.is_finite()) {
            bail!("glTF output: object '{}' has a non-finite position or UV", o.name);
        }
        if let Some(i) = m.indices.iter().flatten().find(|&&i| i as usize >= n) {
            bail!("glTF output: object '{}' has vertex index {i} ≥ {n} vertices", o.name);
        }
        let (lo, hi) =
            m.positions.iter().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(l, h), &p| (l.min(p), h.max(p)));
        let v = bin.view(&f32_bytes(m.positions.iter().flat_map(|p| p.to_array())), Some(ARRAY_BUFFER));
        let mut attributes = json!({"POSITION": accessors.len()});
        accessors.push(json!({
            "bufferView": v, "componentType": FLOAT, "count": n, "type": "VEC3",
            // as f64: the exact f32 values (the validator compares them with the data exactly)
            "min": lo.to_array().map(f64::from), "max": hi.to_array().map(f64::from),
        }));
        let normals = unit_normals(m);
        if !normals.is_empty() {
            let v = bin.view(&f32_bytes(normals.iter().flat_map(|p| p.to_array())), Some(ARRAY_BUFFER));
            attributes["NORMAL"] = json!(accessors.len());
            accessors.push(json!({"bufferView": v, "componentType": FLOAT, "count": n, "type": "VEC3"}));
        }
        let v = bin.view(&f32_bytes(m.uvs.iter().flat_map(|t| t.to_array())), Some(ARRAY_BUFFER));
        attributes["TEXCOORD_0"] = json!(accessors.len());
        accessors.push(json!({"bufferView": v, "componentType": FLOAT, "count": n, "type": "VEC2"}));
        let idx: Vec<u8> = m.indices.iter().flatten().flat_map(|i| i.to_le_bytes()).collect();
        let v = bin.view(&idx, Some(ELEMENT_ARRAY_BUFFER));
        let indices = accessors.len();
        accessors.push(json!({
            "bufferView": v, "componentType": UNSIGNED_INT, "count": 3 * m.indices.len(), "type": "SCALAR",
        }));
        let v = bin.view(o.base_colour_png, None);
        images.push(json!({"name": o.name, "bufferView": v, "mimeType": "image/png"}));
        textures.push(json!({"sampler": 0, "source": k}));
        materials.push(json!({
            "name": o.name,
            "pbrMetallicRoughness": {"baseColorTexture": {"index": k}, "metallicFactor": 0.0, "roughnessFactor": 1.0},
        }));
        meshes.push(json!({
            "name": o.name,
            "primitives": [{"attributes": attributes, "indices": indices, "material": k, "mode": 4}],
        }));
        nodes.push(json!({"name": o.name, "mesh": k}));
    }
    bin.data.resize(bin.data.len().next_multiple_of(4), 0);
    let mut doc = json!({
        "asset": {"version": "2.0", "generator": generator},
        "scene": 0,
        "scenes": [{"nodes": (0..objects.len()).collect::<Vec<_>>()}],
        "nodes": nodes,
        "meshes": meshes,
        "materials": materials,
        "textures": textures,
        "images": images,
        "samplers": [{"magFilter": LINEAR, "minFilter": LINEAR, "wrapS": CLAMP_TO_EDGE, "wrapT": CLAMP_TO_EDGE}],
        "accessors": accessors,
        "bufferViews": bin.views,
    });
    // glTF forbids empty arrays and a zero-length buffer
    if objects.is_empty() {
        let d = doc.as_object_mut().expect("object");
        for k in
            ["nodes", "meshes", "materials", "textures", "images", "samplers", "accessors", "bufferViews"]
        {
            d.remove(k);
        }
        d["scenes"] = json!([{}]);
    } else {
        doc["buffers"] = json!([{"byteLength": bin.data.len()}]);
    }
    let mut json = serde_json::to_vec(&doc)?;
    json.resize(json.len().next_multiple_of(4), b' ');
    let bin_chunk = if bin.data.is_empty() { 0 } else { 8 + bin.data.len() };
    let total = 12 + 8 + json.len() + bin_chunk;
    let Ok(total32) = u32::try_from(total) else {
        bail!("glTF output: {total} bytes exceed the 4 GiB limit of a .glb");
    };
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&total32.to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    if bin_chunk > 0 {
        out.extend_from_slice(&(bin.data.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&bin.data);
    }
    Ok(out)
}

/// A parsed `.glb` (tests): the JSON document and the BIN chunk.
#[cfg(test)]
pub(crate) fn parse_glb(b: &[u8]) -> (Value, Vec<u8>) {
    let u = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().unwrap()) as usize;
    assert_eq!(&b[0..4], b"glTF");
    assert_eq!(u(4), 2);
    assert_eq!(u(8), b.len());
    let jl = u(12);
    assert_eq!(&b[16..20], b"JSON");
    assert_eq!(jl % 4, 0);
    let doc = serde_json::from_slice(&b[20..20 + jl]).unwrap();
    let mut bin = Vec::new();
    if 20 + jl < b.len() {
        let bl = u(20 + jl);
        assert_eq!(&b[24 + jl..28 + jl], b"BIN\0");
        assert_eq!(bl % 4, 0);
        assert_eq!(28 + jl + bl, b.len());
        bin = b[28 + jl..].to_vec();
    }
    (doc, bin)
}

#[cfg(test)]
mod tests {
    use super::*;
    use opal::math::Vec2;

    fn quad(normals: bool) -> TriangleMesh {
        TriangleMesh {
            positions: vec![
                Vec3::new(-1.0, 0.0, -2.0),
                Vec3::new(1.0, 0.0, -2.0),
                Vec3::new(1.0, 0.5, 2.0),
                Vec3::new(-1.0, 0.5, 2.0),
            ],
            normals: if normals {
                vec![Vec3::new(0.0, 2.0, 0.0), Vec3::ZERO, Vec3::Y, Vec3::Y]
            } else {
                vec![]
            },
            uvs: vec![Vec2::new(0.0, 0.0), Vec2::new(1.0, 0.0), Vec2::new(1.0, 1.0), Vec2::new(0.0, 1.0)],
            indices: vec![[0, 2, 1], [0, 3, 2]],
        }
    }

    fn accessor_f32(doc: &Value, bin: &[u8], i: usize) -> Vec<f32> {
        let a = &doc["accessors"][i];
        let v = &doc["bufferViews"][a["bufferView"].as_u64().unwrap() as usize];
        let off = v["byteOffset"].as_u64().unwrap() as usize;
        let len = v["byteLength"].as_u64().unwrap() as usize;
        assert_eq!(off % 4, 0);
        bin[off..off + len].chunks(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect()
    }

    /// Two objects (one with normals, one without): container, chunk padding, accessor counts and
    /// POSITION bounds, unit normals (a zero normal replaced), the image bytes verbatim.
    #[test]
    fn container_round_trip() {
        let (a, b) = (quad(true), quad(false));
        let png_a = b"not-really-a-png".to_vec();
        let png_b = b"abc".to_vec();
        let objs = [
            GlbObject { name: "a", mesh: &a, base_colour_png: &png_a },
            GlbObject { name: "b", mesh: &b, base_colour_png: &png_b },
        ];
        let bytes = glb_bytes(&objs, "test").unwrap();
        let (doc, bin) = parse_glb(&bytes);
        assert_eq!(doc["asset"]["version"], "2.0");
        assert_eq!(doc["buffers"][0]["byteLength"].as_u64().unwrap() as usize, bin.len());
        assert_eq!(doc["nodes"].as_array().unwrap().len(), 2);
        let pa = &doc["meshes"][0]["primitives"][0];
        let pb = &doc["meshes"][1]["primitives"][0];
        assert!(pb["attributes"].get("NORMAL").is_none());
        let pos = &doc["accessors"][pa["attributes"]["POSITION"].as_u64().unwrap() as usize];
        assert_eq!(pos["count"], 4);
        assert_eq!(pos["min"], json!([-1.0, 0.0, -2.0]));
        assert_eq!(pos["max"], json!([1.0, 0.5, 2.0]));
        let n = accessor_f32(&doc, &bin, pa["attributes"]["NORMAL"].as_u64().unwrap() as usize);
        // vertex 1's zero normal becomes the normal of the quad's plane (rising 0.5 over 4 in z)
        let plane = Vec3::new(0.0, 4.0, -0.5).normalize();
        for (k, v) in n.chunks(3).enumerate() {
            let want = if k == 1 { plane } else { Vec3::Y };
            assert!((Vec3::from_slice(v) - want).length() < 1e-6, "normal {k}: {v:?} vs {want}");
        }
        let uv = accessor_f32(&doc, &bin, pa["attributes"]["TEXCOORD_0"].as_u64().unwrap() as usize);
        assert_eq!(uv, [0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0, 1.0], "no v flip");
        let ia = &doc["accessors"][pa["indices"].as_u64().unwrap() as usize];
        assert_eq!(ia["count"], 6);
        assert_eq!(ia["componentType"], UNSIGNED_INT);
        let img = &doc["images"][1];
        assert_eq!(img["mimeType"], "image/png");
        let v = &doc["bufferViews"][img["bufferView"].as_u64().unwrap() as usize];
        let off = v["byteOffset"].as_u64().unwrap() as usize;
        assert_eq!(&bin[off..off + v["byteLength"].as_u64().unwrap() as usize], b"abc");
        let m = &doc["materials"][0]["pbrMetallicRoughness"];
        assert_eq!((m["metallicFactor"].as_f64(), m["roughnessFactor"].as_f64()), (Some(0.0), Some(1.0)));
        // no objects: still a valid container without a BIN chunk
        let (doc, bin) = parse_glb(&glb_bytes(&[], "test").unwrap());
        assert!(bin.is_empty() && doc.get("buffers").is_none());
    }

    #[test]
    fn bad_meshes_are_refused() {
        let mut m = quad(false);
        m.uvs.pop();
        let e = glb_bytes(&[GlbObject { name: "x", mesh: &m, base_colour_png: b"" }], "t").unwrap_err();
        assert!(e.to_string().contains("'x'"), "{e}");
        let mut m = quad(false);
        m.indices[0][0] = 9;
        assert!(glb_bytes(&[GlbObject { name: "x", mesh: &m, base_colour_png: b"" }], "t").is_err());
    }
}
