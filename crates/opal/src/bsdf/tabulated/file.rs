//! The `.obsdf` file format (layout in `docs/formats.md`): magic, little-endian u32 header
//! length, JSON [`Header`], then the f32 little-endian cell values. Writing
//! ([`TabulatedBsdf::to_bytes`], [`TabulatedBsdf::save`]) and reading with errors that name the
//! file, the field and the value ([`TabulatedBsdf::from_bytes`], [`TabulatedBsdf::load`]).
//! Covered by the round-trip and bad-file tests in `tabulated/tests.rs`.

use super::grid::validate_grid;
use super::{TableGrid, TabulatedBsdf};
use crate::error::{Error, Result};
use std::path::Path;

/// Magic bytes at the start of an `.obsdf` file.
pub const MAGIC: &[u8; 8] = b"OPALBSDF";
/// Format version written and read.
pub const VERSION: u32 = 1;

/// Header of an `.obsdf` file (JSON after the magic and a little-endian u32 length).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Header {
    /// Always `"opal-tabulated-bsdf"`.
    pub format: String,
    /// Format version ([`VERSION`]).
    pub version: u32,
    /// n_inside / n_outside (outside = +z side).
    pub eta: f32,
    /// Incidence rows per side.
    pub n_theta_o: usize,
    /// Cells along u.
    pub n_u: usize,
    /// Cells along v.
    pub n_v: usize,
    /// Polar warp β.
    pub beta: f32,
    /// Units of the data (informative).
    pub units: String,
    /// Data layout (informative).
    pub layout: String,
    /// What the table was built from (informative).
    pub source: String,
}

impl TabulatedBsdf {
    /// The file header this table is written with.
    pub fn header(&self) -> Header {
        let g = &self.t.grid;
        Header {
            format: "opal-tabulated-bsdf".into(),
            version: VERSION,
            eta: self.t.eta,
            n_theta_o: g.n_theta_o,
            n_u: g.n_u,
            n_v: g.n_v,
            beta: g.beta,
            units: "power fraction per unit (u,v) area (cell energy = value/(n_u n_v)); importance-mode BSDF".into(),
            layout: "f32 little-endian [side 0 = light from +z (outside), 1 = from inside][row k: θo = (k+0.5)·90°/n_theta_o][lobe 0 = R, 1 = T][iu][iv]".into(),
            source: self.t.source.clone(),
        }
    }

    /// Serialises to the `.obsdf` byte layout (see `docs/formats.md`).
    pub fn to_bytes(&self) -> Vec<u8> {
        let h = serde_json::to_vec_pretty(&self.header()).expect("header serialises");
        let mut out = Vec::with_capacity(12 + h.len() + 4 * self.t.q.len());
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&(h.len() as u32).to_le_bytes());
        out.extend_from_slice(&h);
        for x in &self.t.q {
            out.extend_from_slice(&x.to_le_bytes());
        }
        out
    }

    /// Writes an `.obsdf` file.
    pub fn save(&self, path: &Path) -> Result<()> {
        std::fs::write(path, self.to_bytes()).map_err(|e| Error::io(path, e))
    }

    /// Reads an `.obsdf` file; errors name the file, the field and the value.
    pub fn load(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        Self::from_bytes(&bytes).map_err(|(field, why)| Error::Parse {
            path: path.to_path_buf(),
            line: 0,
            col: 0,
            msg: format!("tabulated BSDF: {field}: {why}"),
        })
    }

    /// Parses the `.obsdf` byte layout; the error is (field, what is wrong).
    pub fn from_bytes(b: &[u8]) -> std::result::Result<Self, (String, String)> {
        if b.len() < 12 || &b[..8] != MAGIC {
            let got = String::from_utf8_lossy(&b[..b.len().min(8)]).into_owned();
            return Err(("magic".into(), format!("expected \"OPALBSDF\", got {got:?} (not an .obsdf file)")));
        }
        let hl = u32::from_le_bytes(b[8..12].try_into().expect("4 bytes")) as usize;
        if 12 + hl > b.len() {
            return Err(("header length".into(), format!("{hl} bytes, but the file has only {}", b.len())));
        }
        let hv: serde_json::Value = serde_json::from_slice(&b[12..12 + hl])
            .map_err(|e| ("header".to_string(), format!("not valid JSON: {e}")))?;
        let field = |name: &str| hv.get(name).ok_or_else(|| (name.to_string(), "missing".to_string()));
        let num = |name: &str| -> std::result::Result<f64, (String, String)> {
            let v = field(name)?;
            v.as_f64().ok_or_else(|| (name.to_string(), format!("must be a number, got {v}")))
        };
        let count = |name: &str| -> std::result::Result<usize, (String, String)> {
            let v = field(name)?;
            v.as_u64()
                .map(|x| x as usize)
                .ok_or_else(|| (name.to_string(), format!("must be a positive integer, got {v}")))
        };
        match hv.get("format").and_then(|v| v.as_str()) {
            Some("opal-tabulated-bsdf") => {}
            other => {
                return Err(("format".into(), format!("expected \"opal-tabulated-bsdf\", got {other:?}")));
            }
        }
        let version = count("version")?;
        if version != VERSION as usize {
            return Err((
                "version".into(),
                format!("{version} is not supported (this Opal reads {VERSION})"),
            ));
        }
        let eta = num("eta")? as f32;
        let grid = TableGrid {
            n_theta_o: count("n_theta_o")?,
            n_u: count("n_u")?,
            n_v: count("n_v")?,
            beta: num("beta")? as f32,
        };
        validate_grid(&grid, eta)?;
        let data = &b[12 + hl..];
        if data.len() != 4 * grid.len() {
            return Err((
                "data".into(),
                format!(
                    "{} bytes, expected {} (2 sides × {} rows × 2 lobes × {} × {} f32)",
                    data.len(),
                    4 * grid.len(),
                    grid.n_theta_o,
                    grid.n_u,
                    grid.n_v
                ),
            ));
        }
        let q: Vec<f32> =
            data.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes"))).collect();
        let source = hv.get("source").and_then(|v| v.as_str()).unwrap_or("").to_string();
        Self::from_data(eta, grid, q, source)
    }
}
