//! The rewritten Mitsuba scene of `opal delight`: the input scene with every recovered shape
//! replaced by its OBJ with the recovered albedo, other relative file names made absolute.

use anyhow::{Context, Result};
use opal::scene::desc::SceneDesc;
use opal_inverse::delight::ObjectResult;
use std::path::Path;

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('"', "&quot;").replace('<', "&lt;").replace('>', "&gt;")
}

/// The input scene text with every recovered shape replaced by an OBJ shape with a diffuse
/// bitmap BSDF, and every other relative `filename` made absolute (the new file lives elsewhere).
pub(super) fn rewrite_scene(
    text: &str,
    scene_dir: &Path,
    objects: &[ObjectResult],
    desc: &SceneDesc,
) -> Result<String> {
    let doc = roxmltree::Document::parse(text).context("cannot re-parse the scene for rewriting")?;
    let shapes: Vec<roxmltree::Node> = doc.descendants().filter(|n| n.has_tag_name("shape")).collect();
    let mut edits: Vec<(std::ops::Range<usize>, String)> = Vec::new();
    let mut replaced = Vec::new();
    for o in objects {
        let node = shapes
            .iter()
            .find(|n| n.attribute("id") == Some(o.id.as_str()))
            .or_else(|| if shapes.len() == desc.shapes.len() { shapes.get(o.shape) } else { None })
            .with_context(|| format!("cannot find shape '{}' in the scene file", o.id))?;
        let face = if o.atlas.mesh.normals.is_empty() {
            "\n        <boolean name=\"face_normals\" value=\"true\"/>"
        } else {
            ""
        };
        let new = format!(
            "<shape type=\"obj\" id=\"{id}\">\n        <string name=\"filename\" value=\"meshes/{id}.obj\"/>{face}\n        <bsdf type=\"diffuse\">\n            <texture type=\"bitmap\" name=\"reflectance\">\n                <string name=\"filename\" value=\"albedo/{id}.exr\"/>\n                <string name=\"filter_type\" value=\"bilinear\"/>\n                <string name=\"wrap_mode\" value=\"clamp\"/>\n                <boolean name=\"raw\" value=\"true\"/>\n            </texture>\n        </bsdf>\n    </shape>",
            id = xml_escape(&o.id)
        );
        replaced.push(node.range());
        edits.push((node.range(), new));
    }
    for n in doc.descendants().filter(|n| n.has_tag_name("string") && n.attribute("name") == Some("filename"))
    {
        if replaced.iter().any(|r| r.start <= n.range().start && n.range().end <= r.end) {
            continue;
        }
        let v = n.attribute("value").unwrap_or("");
        if v.starts_with('$') || Path::new(v).is_absolute() {
            continue;
        }
        let abs = std::fs::canonicalize(scene_dir.join(v)).unwrap_or_else(|_| scene_dir.join(v));
        edits.push((
            n.range(),
            format!("<string name=\"filename\" value=\"{}\"/>", xml_escape(&abs.to_string_lossy())),
        ));
    }
    edits.sort_by_key(|e| std::cmp::Reverse(e.0.start));
    let mut out = text.to_string();
    for (r, s) in edits {
        out.replace_range(r, &s);
    }
    Ok(out)
}
