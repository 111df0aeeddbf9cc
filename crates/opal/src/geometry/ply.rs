//! Stanford PLY reader (hand-written): `ascii 1.0`, `binary_little_endian 1.0`,
//! `binary_big_endian 1.0`.
//!
//! * `element vertex`: `x y z` (required), `nx ny nz` (optional, all three), texture
//!   coordinates as `u v`, `s t`, `texture_u texture_v` or `texture_s texture_t` (optional).
//!   Other vertex properties (colours, confidence...) are read and ignored.
//! * `element face`: a list property `vertex_indices` or `vertex_index`; triangles are kept,
//!   quads and larger polygons are fan-triangulated from their first vertex.
//! * Any other element is parsed (to skip its data) and ignored.
//! * Texture coordinates are **not** flipped (Mitsuba's PLY loader does not flip them).
//! * Scalar types: `char/int8 uchar/uint8 short/int16 ushort/uint16 int/int32 uint/uint32
//!   float/float32 double/float64`.
//!
//! Errors are [`Error::Parse`] naming the file and, for the header and ascii bodies, the line
//! (binary bodies give the byte offset in the message): truncated data, non-finite
//! coordinates, face indices out of range, faces with < 3 vertices, unknown formats/types.
//! Tests: unit tests below (ascii / binary LE / binary BE round trips, errors).

use crate::error::{Error, Result};
use crate::geometry::TriangleMesh;
use crate::math::{Vec2, Vec3};
use std::path::Path;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Option<Scalar> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }
    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }
    fn is_int(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }
}

#[derive(Debug)]
enum Prop {
    Scalar(String, Scalar),
    List(String, Scalar, Scalar),
}

#[derive(Debug)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Prop>,
}

#[derive(Clone, Copy, PartialEq)]
enum Format {
    Ascii,
    Le,
    Be,
}

fn perr(path: &Path, line: usize, msg: impl Into<String>) -> Error {
    Error::Parse { path: path.to_path_buf(), line, col: 0, msg: msg.into() }
}

/// Body reader over ascii tokens or binary bytes.
struct Body<'a> {
    path: &'a Path,
    fmt: Format,
    bytes: &'a [u8],
    pos: usize,
    /// Current 1-based line (ascii).
    line: usize,
    /// Tokens of the current ascii line.
    toks: std::vec::IntoIter<String>,
}

impl Body<'_> {
    fn where_(&self) -> String {
        match self.fmt {
            Format::Ascii => String::new(),
            _ => format!(" (byte offset {})", self.pos),
        }
    }
    fn line(&self) -> usize {
        if self.fmt == Format::Ascii { self.line } else { 0 }
    }
    /// Starts a new ascii line (one element row per line).
    fn next_row(&mut self) -> Result<()> {
        if self.fmt != Format::Ascii {
            return Ok(());
        }
        loop {
            if self.pos >= self.bytes.len() {
                return Err(perr(self.path, self.line + 1, "unexpected end of file (missing element rows)"));
            }
            let end = self.bytes[self.pos..]
                .iter()
                .position(|&b| b == b'\n')
                .map_or(self.bytes.len(), |k| self.pos + k);
            let text = String::from_utf8_lossy(&self.bytes[self.pos..end]).into_owned();
            self.pos = end + 1;
            self.line += 1;
            let toks: Vec<String> = text.split_whitespace().map(str::to_owned).collect();
            if !toks.is_empty() {
                self.toks = toks.into_iter();
                return Ok(());
            }
        }
    }
    fn read(&mut self, t: Scalar) -> Result<f64> {
        match self.fmt {
            Format::Ascii => {
                let tok = self
                    .toks
                    .next()
                    .ok_or_else(|| perr(self.path, self.line, "too few values on this line"))?;
                let v: f64 = tok
                    .parse()
                    .map_err(|_| perr(self.path, self.line, format!("`{tok}` is not a number")))?;
                if t.is_int() && v.fract() != 0.0 {
                    return Err(perr(self.path, self.line, format!("`{tok}` is not an integer")));
                }
                Ok(v)
            }
            Format::Le | Format::Be => {
                let n = t.size();
                if self.pos + n > self.bytes.len() {
                    return Err(perr(
                        self.path,
                        0,
                        format!("unexpected end of binary data{}", self.where_()),
                    ));
                }
                let mut b = [0u8; 8];
                b[..n].copy_from_slice(&self.bytes[self.pos..self.pos + n]);
                if self.fmt == Format::Be {
                    b[..n].reverse();
                }
                self.pos += n;
                Ok(match t {
                    Scalar::I8 => b[0] as i8 as f64,
                    Scalar::U8 => b[0] as f64,
                    Scalar::I16 => i16::from_le_bytes([b[0], b[1]]) as f64,
                    Scalar::U16 => u16::from_le_bytes([b[0], b[1]]) as f64,
                    Scalar::I32 => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                    Scalar::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                    Scalar::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                    Scalar::F64 => f64::from_le_bytes(b),
                })
            }
        }
    }
    fn end_row(&mut self) -> Result<()> {
        if self.fmt == Format::Ascii && self.toks.next().is_some() {
            return Err(perr(self.path, self.line, "too many values on this line"));
        }
        Ok(())
    }
}

/// Reads a PLY file into an object-space triangle mesh (see the module docs).
pub fn read_ply(path: &Path) -> Result<TriangleMesh> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    // Header: ascii lines up to `end_header`.
    let mut pos = 0usize;
    let mut line_no = 0usize;
    let mut fmt = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut saw_end = false;
    while pos < bytes.len() {
        let end = bytes[pos..].iter().position(|&b| b == b'\n').map_or(bytes.len(), |k| pos + k);
        let line = String::from_utf8_lossy(&bytes[pos..end]).trim_end_matches('\r').to_string();
        pos = (end + 1).min(bytes.len());
        line_no += 1;
        let toks: Vec<&str> = line.split_whitespace().collect();
        if line_no == 1 {
            if toks != ["ply"] {
                return Err(perr(path, 1, "not a PLY file (first line must be `ply`)"));
            }
            continue;
        }
        match toks.first().copied() {
            None | Some("comment") | Some("obj_info") => {}
            Some("format") => {
                fmt = Some(match toks.get(1).copied() {
                    Some("ascii") => Format::Ascii,
                    Some("binary_little_endian") => Format::Le,
                    Some("binary_big_endian") => Format::Be,
                    other => return Err(perr(path, line_no, format!("unknown PLY format {other:?}"))),
                });
            }
            Some("element") => {
                let (Some(name), Some(count)) =
                    (toks.get(1), toks.get(2).and_then(|c| c.parse::<usize>().ok()))
                else {
                    return Err(perr(path, line_no, format!("malformed element line `{line}`")));
                };
                elements.push(Element { name: name.to_string(), count, props: Vec::new() });
            }
            Some("property") => {
                let el =
                    elements.last_mut().ok_or_else(|| perr(path, line_no, "property before any element"))?;
                let prop = if toks.get(1) == Some(&"list") {
                    match (
                        toks.get(2).and_then(|t| Scalar::parse(t)),
                        toks.get(3).and_then(|t| Scalar::parse(t)),
                        toks.get(4),
                    ) {
                        (Some(c), Some(i), Some(n)) if c.is_int() => Prop::List(n.to_string(), c, i),
                        _ => return Err(perr(path, line_no, format!("malformed list property `{line}`"))),
                    }
                } else {
                    match (toks.get(1).and_then(|t| Scalar::parse(t)), toks.get(2)) {
                        (Some(t), Some(n)) => Prop::Scalar(n.to_string(), t),
                        _ => return Err(perr(path, line_no, format!("malformed property `{line}`"))),
                    }
                };
                el.props.push(prop);
            }
            Some("end_header") => {
                saw_end = true;
                break;
            }
            Some(other) => return Err(perr(path, line_no, format!("unknown header keyword `{other}`"))),
        }
    }
    if !saw_end {
        return Err(perr(path, line_no, "missing `end_header`"));
    }
    let fmt = fmt.ok_or_else(|| perr(path, line_no, "missing `format` line"))?;
    let mut body = Body { path, fmt, bytes: &bytes, pos, line: line_no, toks: Vec::new().into_iter() };

    let mut mesh = TriangleMesh::default();
    let mut have_vertices = false;
    // every face's corner indices one after the other; per face: (start, corners, line)
    let mut corners: Vec<i64> = Vec::new();
    let mut faces: Vec<(usize, usize, usize)> = Vec::new();
    for el in &elements {
        if el.name == "vertex" {
            have_vertices = true;
            let find = |n: &str| el.props.iter().position(|p| matches!(p, Prop::Scalar(m, _) if m == n));
            let (Some(ix), Some(iy), Some(iz)) = (find("x"), find("y"), find("z")) else {
                return Err(perr(path, 0, "vertex element lacks x, y, z properties"));
            };
            let normals = match (find("nx"), find("ny"), find("nz")) {
                (Some(a), Some(b), Some(c)) => Some([a, b, c]),
                _ => None,
            };
            let uvs = [("u", "v"), ("s", "t"), ("texture_u", "texture_v"), ("texture_s", "texture_t")]
                .iter()
                .find_map(|(a, b)| Some([find(a)?, find(b)?]));
            let mut vals = vec![0f64; el.props.len()];
            // each row takes at least one byte of the file: a lying count reserves no more
            let rows = el.count.min(bytes.len());
            mesh.positions.reserve(rows);
            if normals.is_some() {
                mesh.normals.reserve(rows);
            }
            if uvs.is_some() {
                mesh.uvs.reserve(rows);
            }
            for vi in 0..el.count {
                body.next_row()?;
                for (k, p) in el.props.iter().enumerate() {
                    match p {
                        Prop::Scalar(_, t) => vals[k] = body.read(*t)?,
                        Prop::List(_, c, t) => {
                            let n = body.read(*c)? as usize;
                            for _ in 0..n {
                                body.read(*t)?;
                            }
                        }
                    }
                }
                body.end_row()?;
                let p = Vec3::new(vals[ix] as f32, vals[iy] as f32, vals[iz] as f32);
                if !p.is_finite() {
                    return Err(perr(
                        path,
                        body.line(),
                        format!("vertex {vi}: non-finite position {p}{}", body.where_()),
                    ));
                }
                mesh.positions.push(p);
                if let Some([a, b, c]) = normals {
                    mesh.normals.push(Vec3::new(vals[a] as f32, vals[b] as f32, vals[c] as f32));
                }
                if let Some([a, b]) = uvs {
                    mesh.uvs.push(Vec2::new(vals[a] as f32, vals[b] as f32));
                }
            }
        } else if el.name == "face" {
            let li = el
                .props
                .iter()
                .position(
                    |p| matches!(p, Prop::List(n, _, _) if n == "vertex_indices" || n == "vertex_index"),
                )
                .ok_or_else(|| perr(path, 0, "face element lacks a vertex_indices/vertex_index list"))?;
            faces.reserve(el.count.min(bytes.len()));
            for fi in 0..el.count {
                body.next_row()?;
                let start = corners.len();
                for (k, p) in el.props.iter().enumerate() {
                    match p {
                        Prop::Scalar(_, t) => {
                            body.read(*t)?;
                        }
                        Prop::List(_, c, t) => {
                            let n = body.read(*c)? as usize;
                            for _ in 0..n {
                                let v = body.read(*t)?;
                                if k == li {
                                    corners.push(v as i64);
                                }
                            }
                        }
                    }
                }
                body.end_row()?;
                let n = corners.len() - start;
                if n < 3 {
                    return Err(perr(
                        path,
                        body.line(),
                        format!("face {fi} has {n} vertices (needs ≥ 3){}", body.where_()),
                    ));
                }
                faces.push((start, n, body.line()));
                let _ = fi;
            }
        } else if el.props.is_empty() && body.fmt != Format::Ascii {
            // binary rows of no properties are empty: nothing to read or skip (a declared count
            // of 10^13 such rows must not be looped over; fuzz target `ply` found that hang)
        } else {
            for _ in 0..el.count {
                body.next_row()?;
                for p in &el.props {
                    match p {
                        Prop::Scalar(_, t) => {
                            body.read(*t)?;
                        }
                        Prop::List(_, c, t) => {
                            let n = body.read(*c)? as usize;
                            for _ in 0..n {
                                body.read(*t)?;
                            }
                        }
                    }
                }
                body.end_row()?;
            }
        }
    }
    if !have_vertices {
        return Err(perr(path, 0, "no vertex element"));
    }
    let nv = mesh.positions.len() as i64;
    mesh.indices.reserve(faces.iter().map(|f| f.1 - 2).sum());
    for (fi, &(start, n, line)) in faces.iter().enumerate() {
        let idx = &corners[start..start + n];
        if let Some(&bad) = idx.iter().find(|&&i| i < 0 || i >= nv) {
            return Err(perr(path, line, format!("face {fi}: vertex index {bad} out of range (0..{nv})")));
        }
        for k in 1..idx.len() - 1 {
            mesh.indices.push([idx[0] as u32, idx[k] as u32, idx[k + 1] as u32]);
        }
    }
    if mesh.indices.is_empty() {
        return Err(perr(path, 0, "PLY file has no faces"));
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(fmt: &str, nv: usize, nf: usize) -> String {
        format!(
            "ply\nformat {fmt} 1.0\ncomment made by a test\nelement vertex {nv}\nproperty float x\nproperty float y\n\
             property float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty float u\nproperty float v\n\
             property uchar red\nelement face {nf}\nproperty list uchar int vertex_indices\nend_header\n"
        )
    }

    const V: [[f32; 8]; 4] = [
        [0., 0., 0., 0., 0., 1., 0., 0.],
        [1., 0., 0., 0., 0., 1., 1., 0.],
        [1., 1., 0., 0., 0., 1., 1., 1.],
        [0., 1., 0., 0., 0., 1., 0., 1.],
    ];

    fn check(m: &TriangleMesh) {
        assert_eq!(m.positions.len(), 4);
        assert_eq!(m.indices, vec![[0, 1, 2], [0, 2, 3], [3, 1, 0]]);
        assert_eq!(m.uvs[2], Vec2::new(1.0, 1.0)); // not flipped
        assert_eq!(m.normals[1], Vec3::Z);
        assert_eq!(m.positions[2], Vec3::new(1.0, 1.0, 0.0));
    }

    #[test]
    fn ascii_round_trip_quad_and_triangle() {
        let d = tempfile::tempdir().unwrap();
        let mut s = header("ascii", 4, 2);
        for v in V {
            s += &format!("{} {} {} {} {} {} {} {} 255\n", v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7]);
        }
        s += "4 0 1 2 3\n3 3 1 0\n";
        let p = d.path().join("a.ply");
        std::fs::write(&p, s).unwrap();
        check(&read_ply(&p).unwrap());
    }

    fn binary(big: bool) -> Vec<u8> {
        let mut b = header(if big { "binary_big_endian" } else { "binary_little_endian" }, 4, 2).into_bytes();
        for v in V {
            for x in &v {
                b.extend(if big { x.to_be_bytes() } else { x.to_le_bytes() });
            }
            b.push(255);
        }
        for f in [&[0i32, 1, 2, 3][..], &[3, 1, 0]] {
            b.push(f.len() as u8);
            for i in f {
                b.extend(if big { i.to_be_bytes() } else { i.to_le_bytes() });
            }
        }
        b
    }

    #[test]
    fn binary_round_trips() {
        let d = tempfile::tempdir().unwrap();
        for big in [false, true] {
            let p = d.path().join("b.ply");
            std::fs::write(&p, binary(big)).unwrap();
            check(&read_ply(&p).unwrap());
        }
    }

    #[test]
    fn errors() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("e.ply");
        // Index out of range (ascii): line of the face.
        let mut s = header("ascii", 4, 2);
        for v in V {
            s += &format!("{} {} {} {} {} {} {} {} 255\n", v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7]);
        }
        let good = s.clone();
        s += "4 0 1 2 3\n3 3 1 9\n";
        std::fs::write(&p, &s).unwrap();
        let e = read_ply(&p).unwrap_err().to_string();
        assert!(e.contains("e.ply:22:") && e.contains("index 9 out of range"), "{e}");
        // NaN position.
        let s = good.replacen("1 1 0 0 0 1 1 1 255", "1 nan 0 0 0 1 1 1 255", 1) + "3 0 1 2\n3 0 2 3\n";
        std::fs::write(&p, &s).unwrap();
        let e = read_ply(&p).unwrap_err().to_string();
        assert!(e.contains("e.ply:19:") && e.contains("non-finite") && e.contains("NaN"), "{e}");
        // Truncated binary.
        let mut b = binary(false);
        b.truncate(b.len() - 3);
        std::fs::write(&p, &b).unwrap();
        let e = read_ply(&p).unwrap_err().to_string();
        assert!(e.contains("e.ply") && e.contains("unexpected end of binary data"), "{e}");
        // Not a PLY.
        std::fs::write(&p, "hello\n").unwrap();
        let e = read_ply(&p).unwrap_err().to_string();
        assert!(e.contains("e.ply:1:") && e.contains("not a PLY"), "{e}");
        // Binary NaN.
        let mut b = binary(true);
        let hdr = header("binary_big_endian", 4, 2).len();
        b[hdr + 4..hdr + 8].copy_from_slice(&f32::INFINITY.to_be_bytes()); // vertex 0, y
        std::fs::write(&p, &b).unwrap();
        let e = read_ply(&p).unwrap_err().to_string();
        assert!(e.contains("vertex 0: non-finite") && e.contains("inf") && e.contains("byte offset"), "{e}");
    }
}
