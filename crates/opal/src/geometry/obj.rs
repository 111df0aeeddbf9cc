//! Wavefront OBJ reader (via `tobj`) with Mitsuba 3's conventions.
//!
//! * Every object/group of the file is merged into one mesh (Mitsuba loads one mesh per
//!   file); `mtllib`/`usemtl` are ignored (materials come from the scene file).
//! * Polygons are fan-triangulated from their first vertex (`tobj`'s `triangulate`, the same
//!   fan Mitsuba uses).
//! * Faces may index positions, texture coordinates and normals separately (`f 1/4/2`): the
//!   mesh is unified so that each distinct `(v, vt, vn)` triple becomes one vertex (`tobj`'s
//!   `single_index`), as Mitsuba does.
//! * `flip_tex_coords` (Mitsuba's default `true`): `v := 1 − v`, so that `v = 0` is the top row
//!   of an image (Mitsuba's internal uv convention).
//! * Validation with the file's line and column: non-finite or malformed `v`/`vn`/`vt`
//!   values, face indices that are zero or out of range, faces with fewer than three
//!   vertices, and files where only some faces carry `vt`/`vn` are [`Error::Parse`]. `tobj`
//!   parses first; the slower line-by-line check that finds the position runs only when
//!   `tobj` fails or returns non-finite values (loading stays at `tobj`'s speed).
//!
//! The returned mesh is in object space; transforms, degenerate-triangle removal and
//! normal recomputation happen in the scene loader. Tests: unit tests below and
//! `tests/scene_load.rs` (the Cornell-box meshes, error cases).

use crate::error::{Error, Result};
use crate::geometry::TriangleMesh;
use crate::math::{Vec2, Vec3};
use std::path::Path;

fn perr(path: &Path, line: usize, col: usize, msg: impl Into<String>) -> Error {
    Error::Parse { path: path.to_path_buf(), line, col, msg: msg.into() }
}

/// Line-level validation tobj does not report with positions.
fn prescan(path: &Path, text: &str) -> Result<()> {
    let (mut nv, mut nvt, mut nvn) = (0i64, 0i64, 0i64);
    for (li, raw) in text.lines().enumerate() {
        let line = li + 1;
        let content = raw.split('#').next().unwrap_or("");
        let mut toks = tokens_with_cols(content);
        let Some((kw, _)) = toks.next() else { continue };
        match kw {
            "v" | "vn" | "vt" => {
                let need = if kw == "vt" { 1 } else { 3 };
                let mut k = 0;
                for (tok, col) in toks {
                    let val: f32 = tok
                        .parse()
                        .map_err(|_| perr(path, line, col, format!("`{kw}`: `{tok}` is not a number")))?;
                    if !val.is_finite() {
                        return Err(perr(path, line, col, format!("`{kw}`: non-finite value `{tok}`")));
                    }
                    k += 1;
                }
                if k < need {
                    return Err(perr(path, line, 1, format!("`{kw}` needs at least {need} values, got {k}")));
                }
                match kw {
                    "v" => nv += 1,
                    "vt" => nvt += 1,
                    _ => nvn += 1,
                }
            }
            "f" => {
                let mut corners = 0;
                for (tok, col) in toks {
                    corners += 1;
                    for (slot, part) in tok.split('/').enumerate() {
                        if part.is_empty() && slot > 0 {
                            continue;
                        }
                        let (what, count) = match slot {
                            0 => ("vertex", nv),
                            1 => ("texture coordinate", nvt),
                            2 => ("normal", nvn),
                            _ => return Err(perr(path, line, col, format!("malformed face vertex `{tok}`"))),
                        };
                        let idx: i64 = part
                            .parse()
                            .map_err(|_| perr(path, line, col, format!("malformed face vertex `{tok}`")))?;
                        let resolved = if idx < 0 { count + idx + 1 } else { idx };
                        if idx == 0 || resolved < 1 || resolved > count {
                            return Err(perr(
                                path,
                                line,
                                col,
                                format!("face {what} index {idx} out of range (1..={count} defined so far)"),
                            ));
                        }
                    }
                }
                if corners < 3 {
                    return Err(perr(path, line, 1, format!("face with {corners} vertices (needs ≥ 3)")));
                }
            }
            _ => {}
        }
    }
    Ok(())
}

/// Whitespace-separated tokens with their 1-based column.
fn tokens_with_cols(s: &str) -> impl Iterator<Item = (&str, usize)> {
    s.split_whitespace().map(move |t| {
        let off = t.as_ptr() as usize - s.as_ptr() as usize;
        (t, s[..off].chars().count() + 1)
    })
}

/// Reads an OBJ file into an object-space triangle mesh (see the module docs).
pub fn read_obj(path: &Path, flip_tex_coords: bool) -> Result<TriangleMesh> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    // `..Default::default()` is needed when tobj's optional `merging`/`reordering` features
    // (which add fields) get enabled elsewhere in the dependency graph.
    #[allow(clippy::needless_update)]
    let opts = tobj::LoadOptions {
        single_index: true,
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    // Strip `#` comments (tobj would read a trailing comment on a `v` line as colours).
    let mut cleaned = String::with_capacity(text.len());
    for line in text.lines() {
        cleaned.push_str(line.split('#').next().unwrap_or(""));
        cleaned.push('\n');
    }
    // tobj overflows (a panic with debug assertions) on negative indices reaching before the
    // first element and on huge ones (found by fuzz/, target obj): faces with a `-` or an index
    // of 10+ digits are checked by the `prescan` first.
    let risky_faces = cleaned.lines().any(|l| {
        let l = l.trim_start();
        (l.starts_with("f ") || l.starts_with("f\t"))
            && (l.contains('-') || l.split(|c: char| !c.is_ascii_digit()).any(|d| d.len() > 9))
    });
    if risky_faces {
        prescan(path, &text)?;
    }
    let mut reader = std::io::BufReader::new(cleaned.as_bytes());
    // Fast path: tobj parses; the line-by-line `prescan` (which locates problems by line and
    // column) runs only when tobj fails or the result holds non-finite values.
    let (models, _materials) =
        match tobj::load_obj_buf(&mut reader, &opts, |_| Err(tobj::LoadError::GenericFailure)) {
            Ok(r) => r,
            Err(e) => {
                prescan(path, &text)?;
                return Err(perr(path, 0, 0, format!("OBJ: {e}")));
            }
        };
    let finite = |v: &[f32]| v.iter().all(|x| x.is_finite());
    if !models
        .iter()
        .all(|m| finite(&m.mesh.positions) && finite(&m.mesh.normals) && finite(&m.mesh.texcoords))
    {
        prescan(path, &text)?;
        return Err(perr(path, 0, 0, "non-finite vertex data"));
    }
    let mut mesh = TriangleMesh::default();
    let (mut with_n, mut with_uv, mut total) = (0usize, 0usize, 0usize);
    for m in &models {
        let m = &m.mesh;
        let base = mesh.positions.len() as u32;
        let nverts = m.positions.len() / 3;
        total += nverts;
        mesh.positions.extend(m.positions.chunks_exact(3).map(|p| Vec3::new(p[0], p[1], p[2])));
        if m.normals.len() == m.positions.len() {
            with_n += nverts;
            mesh.normals.extend(m.normals.chunks_exact(3).map(|p| Vec3::new(p[0], p[1], p[2])));
        } else if !m.normals.is_empty() {
            return Err(perr(path, 0, 0, "some faces have normals (`vn`) and others do not"));
        }
        if m.texcoords.len() / 2 == nverts {
            with_uv += nverts;
            mesh.uvs.extend(
                m.texcoords
                    .chunks_exact(2)
                    .map(|t| Vec2::new(t[0], if flip_tex_coords { 1.0 - t[1] } else { t[1] })),
            );
        } else if !m.texcoords.is_empty() {
            return Err(perr(path, 0, 0, "some faces have texture coordinates (`vt`) and others do not"));
        }
        for tri in m.indices.chunks_exact(3) {
            mesh.indices.push([base + tri[0], base + tri[1], base + tri[2]]);
        }
    }
    // Normals/uvs must cover every vertex of the merged mesh or none.
    if with_n != 0 && with_n != total {
        return Err(perr(path, 0, 0, "some objects have normals (`vn`) and others do not"));
    }
    if with_uv != 0 && with_uv != total {
        return Err(perr(path, 0, 0, "some objects have texture coordinates (`vt`) and others do not"));
    }
    if mesh.indices.is_empty() {
        return Err(perr(path, 0, 0, "OBJ file has no faces"));
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, s: &str) -> std::path::PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, s).unwrap();
        p
    }

    /// Found by `fuzz/` (target obj): tobj overflowed on a negative texture index reaching
    /// before the first `vt` (and on huge indices); now a located error.
    #[test]
    fn negative_or_huge_indices_out_of_range_are_errors_not_panics() {
        let d = tempfile::tempdir().unwrap();
        let head = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvn 0 0 1\n";
        for (face, needle) in [
            ("f 1/1/1 2/-15/1 3/3/1", "index -15 out of range"),
            ("f -9 2 3", "index -9 out of range"),
            ("f 1/1/1 2/2/1 3/18446744073709551615/1", "malformed face vertex"),
            ("f 1/1/1 2/2/1 3/4611686018427387904/1", "out of range"),
        ] {
            let p = write(d.path(), "m.obj", &format!("{head}{face}\n"));
            let e = read_obj(&p, false).unwrap_err().to_string();
            assert!(e.contains("m.obj:8:") && e.contains(needle), "{face}: {e}");
        }
        // negative indices in range still read
        let p = write(d.path(), "ok.obj", &format!("{head}f -3/-3/-1 -2/-2/-1 -1/-1/-1\n"));
        assert_eq!(read_obj(&p, false).unwrap().indices.len(), 1);
    }

    #[test]
    fn separate_indices_are_unified_and_v_flipped() {
        let d = tempfile::tempdir().unwrap();
        // A quad with 4 positions, 2 uvs and 1 normal referenced by different index triples.
        let p = write(
            d.path(),
            "q.obj",
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0.25 0.1\nvt 0.75 0.9\nvn 0 0 1\n\
             f 1/1/1 2/2/1 3/2/1 4/1/1\n",
        );
        let m = read_obj(&p, true).unwrap();
        assert_eq!(m.indices.len(), 2); // quad → fan of 2 triangles
        assert_eq!(m.positions.len(), 4);
        assert_eq!(m.uvs.len(), 4);
        assert_eq!(m.normals.len(), 4);
        // Corner 3 (position (1,1,0)) carries vt 2 = (0.75, 0.9) → flipped v = 0.1.
        let k = m.positions.iter().position(|p| *p == Vec3::new(1.0, 1.0, 0.0)).unwrap();
        assert!((m.uvs[k] - Vec2::new(0.75, 0.1)).length() < 1e-6);
        // Fan from the first vertex, CCW kept.
        let [a, b, c] = m.triangle(0);
        assert!((b - a).cross(c - a).z > 0.0);
        let m2 = read_obj(&p, false).unwrap();
        assert!((m2.uvs[k] - Vec2::new(0.75, 0.9)).length() < 1e-6);
    }

    #[test]
    fn same_position_different_uv_gives_two_vertices() {
        let d = tempfile::tempdir().unwrap();
        let p = write(
            d.path(),
            "s.obj",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\nf 1/1 2/2 3/3\nf 1/4 3/3 2/2\n",
        );
        let m = read_obj(&p, true).unwrap();
        assert_eq!(m.positions.len(), 4);
        assert!(m.normals.is_empty());
    }

    #[test]
    fn crlf_tabs_comments_and_position_normal_faces() {
        let d = tempfile::tempdir().unwrap();
        let p = write(
            d.path(),
            "crlf.obj",
            "# comment\r\nmtllib none.mtl\r\no a\r\nv\t0 0 0\r\nv 1 0 0 # trailing\r\nv 0 1 0\r\nvn 0 0 1\r\n\
             g b\r\nusemtl m\r\nf 1//1 2//1 3//1\r\n",
        );
        let m = read_obj(&p, true).unwrap();
        assert_eq!(m.indices.len(), 1);
        assert_eq!(m.normals, vec![Vec3::Z; 3]);
        assert!(m.uvs.is_empty());
        assert_eq!(m.positions[1], Vec3::X);
    }

    #[test]
    fn errors_name_file_line_and_value() {
        let d = tempfile::tempdir().unwrap();
        let p = write(d.path(), "nan.obj", "v 0 0 0\nv 1 nan 0\nv 0 1 0\nf 1 2 3\n");
        let e = read_obj(&p, true).unwrap_err().to_string();
        assert!(e.contains("nan.obj:2:") && e.contains("nan"), "{e}");
        let p = write(d.path(), "inf.obj", "v 0 0 0\nv 1 0 inf\nv 0 1 0\nf 1 2 3\n");
        let e = read_obj(&p, true).unwrap_err().to_string();
        assert!(e.contains("inf.obj:2:7") && e.contains("inf"), "{e}");
        let p = write(d.path(), "oor.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n\nf 1 2 7\n");
        let e = read_obj(&p, true).unwrap_err().to_string();
        assert!(e.contains("oor.obj:5:7") && e.contains("index 7 out of range"), "{e}");
        let p = write(d.path(), "neg.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -4\n");
        let e = read_obj(&p, true).unwrap_err().to_string();
        assert!(e.contains("neg.obj:4:") && e.contains("-4"), "{e}");
        let p = write(d.path(), "vt.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/2 3/1\n");
        let e = read_obj(&p, true).unwrap_err().to_string();
        assert!(e.contains("vt.obj:5:") && e.contains("texture coordinate index 2"), "{e}");
        // Relative indices resolve.
        let p = write(d.path(), "rel.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\n");
        assert_eq!(read_obj(&p, true).unwrap().indices, vec![[0, 1, 2]]);
        let e = read_obj(&d.path().join("missing.obj"), true).unwrap_err();
        assert!(matches!(e, Error::Io { .. }) && e.to_string().contains("missing.obj"), "{e}");
    }
}
