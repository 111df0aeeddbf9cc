//! Output-folder snapshots for the byte-for-byte comparisons of `tests/determinism.rs` (1 vs 2
//! threads) and `tests/mpi.rs` (with and without MPI ranks): every file's bytes, with the JSON
//! fields that measure time or memory removed (they differ between runs by nature).

use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// JSON keys that hold wall or CPU times or measured memory.
pub fn is_timing_key(k: &str) -> bool {
    k.contains("seconds")
        || k.contains("memory_mb")
        || k.contains("rss")
        || k.ends_with("_s")
        || k.contains("timing")
        || k.contains("elapsed")
        || k.contains("per_second")
}

/// `v` without its timing fields (recursively).
pub fn strip_timing(v: &mut Value) {
    match v {
        Value::Object(m) => {
            m.retain(|k, _| !is_timing_key(k));
            m.values_mut().for_each(strip_timing);
        }
        Value::Array(a) => a.iter_mut().for_each(strip_timing),
        _ => {}
    }
}

/// A JSON text without its timing fields, pretty-printed.
pub fn json_without_timing(bytes: &[u8]) -> Vec<u8> {
    let mut v: Value = serde_json::from_slice(bytes).expect("valid JSON");
    strip_timing(&mut v);
    serde_json::to_vec_pretty(&v).unwrap()
}

/// Every file under `dir` (relative path → bytes); `.json` files without their timing fields.
pub fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
                continue;
            }
            let mut bytes = std::fs::read(&p).unwrap();
            if p.extension().is_some_and(|x| x == "json") {
                bytes = json_without_timing(&bytes);
            }
            out.insert(p.strip_prefix(dir).unwrap().to_path_buf(), bytes);
        }
    }
    out
}
