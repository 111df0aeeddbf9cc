//! XML reading for the Mitsuba loader: parses a file with `roxmltree` into a small tree of
//! [`Elem`]s that keep their file, line and column ([`Loc`]), with everything that is resolved
//! at the document level done on the way:
//!
//! * `$name` / `${name}` in attribute values replaced by the caller's parameters, else by a
//!   `<default name= value=>` declared earlier in document order (an unset `$name` is an
//!   error);
//! * `<include filename=...>` spliced in place (relative paths searched in the including
//!   files' folders, innermost first; loops and nesting deeper than [`MAX_INCLUDE_DEPTH`] are
//!   errors);
//! * the `<scene version=...>` root checked (major 2 or 3);
//! * stray text inside elements rejected; comments skipped.
//!
//! What the elements mean (parameters, references, plugins) is decided later, in
//! [`super::properties`] and [`super::plugins`].
//!
//! Tests: `crates/opal/tests/scene_load.rs` (substitution, defaults, includes and their error
//! cases) and the unit tests in [`super`].

use crate::error::{Error, Result};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::rc::Rc;

/// Deepest `include` nesting accepted.
pub(super) const MAX_INCLUDE_DEPTH: usize = 32;

/// A position in an XML file, for error messages.
#[derive(Clone, Debug)]
pub(super) struct Loc {
    pub(super) file: Rc<PathBuf>,
    pub(super) line: usize,
    pub(super) col: usize,
}

impl Loc {
    /// An [`Error::Parse`] at this position.
    pub(super) fn err(&self, msg: impl Into<String>) -> Error {
        Error::Parse { path: (*self.file).clone(), line: self.line, col: self.col, msg: msg.into() }
    }
}

/// An attribute, its value already `$`-substituted.
#[derive(Debug)]
pub(super) struct Attr {
    pub(super) name: String,
    pub(super) value: String,
    pub(super) loc: Loc,
}

/// An element with its attributes and children (includes spliced in, `<default>`s consumed).
#[derive(Debug)]
pub(super) struct Elem {
    pub(super) tag: String,
    pub(super) attrs: Vec<Attr>,
    pub(super) children: Vec<Elem>,
    pub(super) loc: Loc,
    /// Folders relative paths are searched in, innermost file first.
    pub(super) dirs: Rc<Vec<PathBuf>>,
}

impl Elem {
    pub(super) fn attr(&self, n: &str) -> Option<&Attr> {
        self.attrs.iter().find(|a| a.name == n)
    }
    pub(super) fn req(&self, n: &str) -> Result<&Attr> {
        self.attr(n).ok_or_else(|| self.loc.err(format!("<{}> lacks the required attribute `{n}`", self.tag)))
    }
    pub(super) fn check_attrs(&self, allowed: &[&str]) -> Result<()> {
        for a in &self.attrs {
            if !allowed.contains(&a.name.as_str()) {
                return Err(a.loc.err(format!(
                    "unknown attribute `{}` on <{}> (allowed: {})",
                    a.name,
                    self.tag,
                    allowed.join(", ")
                )));
            }
        }
        Ok(())
    }
    /// `<bsdf type="diffuse" id="x">` for messages.
    pub(super) fn describe(&self) -> String {
        let mut s = format!("<{}", self.tag);
        for k in ["type", "id", "name"] {
            if let Some(a) = self.attr(k) {
                s += &format!(" {k}=\"{}\"", a.value);
            }
        }
        s + ">"
    }
    /// Resolves a file name against the folders of the including files.
    pub(super) fn resolve(&self, f: &str) -> PathBuf {
        let p = Path::new(f);
        if p.is_absolute() {
            return p.to_path_buf();
        }
        self.dirs.iter().map(|d| d.join(p)).find(|c| c.exists()).unwrap_or_else(|| self.dirs[0].join(p))
    }
}

/// Parses files into [`Elem`] trees, carrying the `$name` parameters and the include chain.
pub(super) struct XmlReader {
    pub(super) params: HashMap<String, String>,
    /// Canonical paths of the files being parsed (include chain).
    pub(super) stack: Vec<PathBuf>,
}

impl XmlReader {
    /// Parses `path` (whose root must be `<scene>`) and returns the root element with
    /// includes spliced in.
    pub(super) fn parse_file(
        &mut self,
        path: &Path,
        outer_dirs: &[PathBuf],
        from: Option<&Loc>,
    ) -> Result<Elem> {
        let text = std::fs::read_to_string(path).map_err(|e| match from {
            None => Error::io(path, e),
            Some(l) => l.err(format!("cannot read included file {}: {e}", path.display())),
        })?;
        let canon = path.canonicalize().unwrap_or_else(|_| path.to_path_buf());
        if self.stack.contains(&canon) {
            let chain: Vec<String> = self.stack.iter().map(|p| p.display().to_string()).collect();
            return Err(from.expect("root file cannot be on the stack").err(format!(
                "include loop: {} is already being parsed (chain: {} → {})",
                path.display(),
                chain.join(" → "),
                path.display()
            )));
        }
        if self.stack.len() >= MAX_INCLUDE_DEPTH {
            return Err(from
                .expect("depth > 0")
                .err(format!("includes nested deeper than {MAX_INCLUDE_DEPTH}")));
        }
        self.stack.push(canon);
        let file = Rc::new(path.to_path_buf());
        let opts = roxmltree::ParsingOptions { allow_dtd: false, ..Default::default() };
        let doc = roxmltree::Document::parse_with_options(&text, opts).map_err(|e| {
            let p = e.pos();
            Error::Parse {
                path: path.to_path_buf(),
                line: p.row as usize,
                col: p.col as usize,
                msg: format!("malformed XML: {e}"),
            }
        })?;
        let mut dirs = vec![path.parent().map(Path::to_path_buf).unwrap_or_default()];
        dirs.extend(outer_dirs.iter().cloned());
        let dirs = Rc::new(dirs);
        let root = doc.root_element();
        let root_elem = self.convert(&doc, root, &file, &dirs)?;
        if root_elem.tag != "scene" {
            return Err(root_elem
                .loc
                .err(format!("root element must be <scene>, found <{}>", root_elem.tag)));
        }
        root_elem.check_attrs(&["version"])?;
        match root_elem.attr("version") {
            None if from.is_none() => {
                return Err(root_elem.loc.err("<scene> lacks the required attribute `version`"));
            }
            None => {}
            Some(v) => {
                let major = v.value.split('.').next().and_then(|m| m.parse::<u32>().ok());
                if !matches!(major, Some(2) | Some(3)) {
                    return Err(v.loc.err(format!(
                        "scene version `{}` is not supported (Opal reads Mitsuba 2/3 scenes, version 2.x or 3.x)",
                        v.value
                    )));
                }
            }
        }
        self.stack.pop();
        Ok(root_elem)
    }

    fn loc(doc: &roxmltree::Document, file: &Rc<PathBuf>, byte: usize) -> Loc {
        let p = doc.text_pos_at(byte);
        Loc { file: file.clone(), line: p.row as usize, col: p.col as usize }
    }

    fn substitute(&self, value: &str, loc: &Loc) -> Result<String> {
        if !value.contains('$') {
            return Ok(value.to_string());
        }
        let mut out = String::new();
        let mut rest = value;
        while let Some(k) = rest.find('$') {
            out += &rest[..k];
            let after = &rest[k + 1..];
            let (name, consumed) = if let Some(inner) = after.strip_prefix('{') {
                match inner.find('}') {
                    Some(e) => (&inner[..e], e + 2),
                    None => return Err(loc.err(format!("unterminated `${{` in `{value}`"))),
                }
            } else {
                let e = after.find(|c: char| !(c.is_ascii_alphanumeric() || c == '_')).unwrap_or(after.len());
                (&after[..e], e)
            };
            if name.is_empty() {
                return Err(loc.err(format!("`$` not followed by a parameter name in `{value}`")));
            }
            match self.params.get(name) {
                Some(v) => out += v,
                None => {
                    return Err(loc.err(format!(
                        "parameter `${name}` is not set (pass it to the loader or declare <default name=\"{name}\" value=\"...\"/>)"
                    )));
                }
            }
            rest = &after[consumed..];
        }
        out += rest;
        Ok(out)
    }

    fn convert(
        &mut self,
        doc: &roxmltree::Document,
        node: roxmltree::Node,
        file: &Rc<PathBuf>,
        dirs: &Rc<Vec<PathBuf>>,
    ) -> Result<Elem> {
        let loc = Self::loc(doc, file, node.range().start);
        let mut attrs = Vec::new();
        for a in node.attributes() {
            let aloc = Self::loc(doc, file, a.range_value().start);
            let value = self.substitute(a.value(), &aloc)?;
            attrs.push(Attr { name: a.name().to_string(), value, loc: aloc });
        }
        let mut elem = Elem {
            tag: node.tag_name().name().to_string(),
            attrs,
            children: Vec::new(),
            loc,
            dirs: dirs.clone(),
        };
        for c in node.children() {
            if c.is_text() {
                let t = c.text().unwrap_or("");
                if !t.trim().is_empty() {
                    let l = Self::loc(doc, file, c.range().start);
                    return Err(l.err(format!("unexpected text `{}` inside <{}>", t.trim(), elem.tag)));
                }
                continue;
            }
            if !c.is_element() {
                continue; // comments, processing instructions
            }
            let child = self.convert(doc, c, file, dirs)?;
            match child.tag.as_str() {
                "default" => {
                    child.check_attrs(&["name", "value"])?;
                    let name = child.req("name")?.value.clone();
                    let value = child.req("value")?.value.clone();
                    // Caller parameters and earlier defaults win.
                    self.params.entry(name).or_insert(value);
                }
                "include" => {
                    child.check_attrs(&["filename"])?;
                    let fname = child.req("filename")?;
                    let target = child.resolve(&fname.value);
                    let inc = self.parse_file(&target, dirs, Some(&fname.loc))?;
                    elem.children.extend(inc.children);
                }
                _ => elem.children.push(child),
            }
        }
        Ok(elem)
    }
}
