//! Checkpoints of the de-lighting iterations, so that an interrupted run can continue from its
//! last finished iteration and reach the same bits as an uninterrupted one.
//!
//! **What is saved.** The stages before the iterations (unwrap, direct irradiance, poses,
//! luminance, initial albedo) are deterministic for given inputs and settings, so a resumed run
//! recomputes them; what the iterations change is saved after each one: per object the
//! luminance `L` and its observed mask (replaced by the super-resolved ones after the first
//! pass), the indirect irradiance `Ei`, the albedo `Kd` and its clamp count, plus the iteration
//! statistics, the light paths traced and the iterations' warnings. Floats are stored as their
//! bits (little-endian `maps-K.bin`; `f64` statistics as integers in `state.json`), so nothing is
//! rounded.
//!
//! **Consistency.** `state.json` carries a fingerprint of the state the iterations started from
//! (atlas sizes, `Ed`, `L`, initial `Kd`, seed and light paths per pass). A resumed run compares
//! it with its own and refuses a checkpoint made from other inputs or settings. Files are written
//! to temporary names and renamed into place, `state.json` last, so an interruption while saving
//! leaves the previous checkpoint intact.
//!
//! Tests: `tests/delight.rs` (`checkpoint_resume_gives_the_same_bits`); the CLI test that
//! interrupts `opal delight` and resumes it.

use super::{IterationStats, ObjectResult};
use opal::error::{Error, Result};
use serde_json::{Value, json};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Format version of `state.json`.
const VERSION: u64 = 1;

/// The state after a finished iteration.
#[derive(Clone, Debug)]
pub(in crate::delight) struct Saved {
    /// Last finished iteration (1-based).
    pub iteration: usize,
    /// Light paths traced so far.
    pub light_paths: u64,
    /// Statistics of iterations 1..=iteration.
    pub iterations: Vec<IterationStats>,
    /// Warnings of those iterations.
    pub warnings: Vec<String>,
    /// Per object: L, observed, Ei, Kd, clamped.
    pub maps: Vec<ObjectMaps>,
}

/// One object's iterated maps.
#[derive(Clone, Debug)]
pub(in crate::delight) struct ObjectMaps {
    pub l: Vec<[f32; 3]>,
    pub observed: Vec<bool>,
    pub ei: Vec<[f32; 3]>,
    pub kd: Vec<[f32; 3]>,
    pub clamped: usize,
}

/// FNV-1a over the state the iterations start from and the settings that shape them.
pub(in crate::delight) fn fingerprint(objects: &[ObjectResult], seed: u64, paths: u64) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |bytes: &[u8]| {
        for b in bytes {
            h ^= *b as u64;
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
    };
    eat(&seed.to_le_bytes());
    eat(&paths.to_le_bytes());
    for o in objects {
        eat(o.id.as_bytes());
        eat(&(o.atlas.width as u64).to_le_bytes());
        eat(&(o.atlas.height as u64).to_le_bytes());
        for v in o.ed.iter().chain(&o.l).chain(&o.kd) {
            for x in v {
                eat(&x.to_bits().to_le_bytes());
            }
        }
    }
    h
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> Error + '_ {
    move |e| Error::io(path, e)
}

/// Writes `bytes` to `path` through a temporary file in the same folder.
fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = path.with_extension("tmp");
    let mut f = std::fs::File::create(&tmp).map_err(io(&tmp))?;
    f.write_all(bytes).map_err(io(&tmp))?;
    f.sync_all().map_err(io(&tmp))?;
    std::fs::rename(&tmp, path).map_err(io(path))
}

fn f64s(v: &[f64]) -> Value {
    Value::from(v.iter().map(|x| x.to_bits()).collect::<Vec<u64>>())
}

fn stats_json(s: &IterationStats) -> Value {
    json!({
        "iteration": s.iteration,
        "max_rel_error": s.max_rel_error.to_bits(),
        "mean_rel_error": s.mean_rel_error.to_bits(),
        "per_object": s.per_object.iter().map(|(a, b, n)| json!([a.to_bits(), b.to_bits(), n])).collect::<Vec<_>>(),
        "seconds": s.seconds.to_bits(),
        "light_paths": s.light_paths,
        "texel_noise": f64s(&s.texel_noise),
        "texel_noise_all": s.texel_noise_all.to_bits(),
        "direct_ratio": f64s(&s.direct_ratio),
        "comm_seconds": s.comm_seconds.to_bits(),
        "change_max": s.change_max.to_bits(),
        "change_beyond_noise": s.change_beyond_noise.to_bits(),
        "change_regions": s.change_regions,
    })
}

/// Saves the state after iteration `saved.iteration` into `dir` (created if needed).
/// Saves the checkpoint after iteration `iteration` on a background thread: the state is
/// encoded at once (the caller may change the objects afterwards), the files are written and
/// synced to disk while the next iteration runs. A checkpoint is complete once [`Saver::wait`]
/// returned (also before the next save, and when the saver is dropped).
#[derive(Debug, Default)]
pub(in crate::delight) struct Saver {
    pending: Option<std::thread::JoinHandle<Result<()>>>,
}

impl Saver {
    /// Waits for the previous checkpoint, then starts writing this one.
    #[allow(clippy::too_many_arguments)]
    pub(in crate::delight) fn save(
        &mut self,
        dir: &Path,
        fingerprint: u64,
        iteration: usize,
        light_paths: u64,
        objects: &[ObjectResult],
        iterations: &[IterationStats],
        warnings: &[String],
    ) -> Result<()> {
        self.wait()?;
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let (bin, text) = encode(fingerprint, iteration, light_paths, objects, iterations, warnings);
        let dir = dir.to_path_buf();
        self.pending = Some(std::thread::spawn(move || write_files(&dir, iteration, &bin, &text)));
        Ok(())
    }

    /// Waits until the last checkpoint started is on disk; its error, if writing it failed.
    pub(in crate::delight) fn wait(&mut self) -> Result<()> {
        match self.pending.take() {
            Some(h) => h.join().unwrap_or_else(|_| {
                Err(Error::invalid("checkpoint", "the thread writing the checkpoint panicked"))
            }),
            None => Ok(()),
        }
    }
}

impl Drop for Saver {
    fn drop(&mut self) {
        // an early return (an error or an interruption) leaves no half-written checkpoint
        let _ = self.wait();
    }
}

/// The bytes of `maps-K.bin` and `state.json` after iteration `iteration`.
fn encode(
    fingerprint: u64,
    iteration: usize,
    light_paths: u64,
    objects: &[ObjectResult],
    iterations: &[IterationStats],
    warnings: &[String],
) -> (Vec<u8>, Vec<u8>) {
    // little-endian f32 bits, written into a sized buffer (a loop the compiler vectorises)
    let put = |bin: &mut Vec<u8>, v: &[f32]| {
        let start = bin.len();
        bin.resize(start + 4 * v.len(), 0);
        for (d, x) in bin[start..].chunks_exact_mut(4).zip(v) {
            d.copy_from_slice(&x.to_bits().to_le_bytes());
        }
    };
    let mut bin = Vec::new();
    for o in objects {
        put(&mut bin, o.l.as_flattened());
        bin.extend(o.observed.iter().map(|&b| b as u8));
        put(&mut bin, o.ei.as_flattened());
        put(&mut bin, o.kd.as_flattened());
    }
    for s in iterations {
        for m in &s.error_maps {
            put(&mut bin, m);
        }
    }
    let state = json!({
        "version": VERSION,
        "fingerprint": format!("{fingerprint:016x}"),
        "iteration": iteration,
        "light_paths": light_paths,
        "maps": maps_name(iteration),
        "objects": objects.iter().map(|o| json!({
            "id": o.id, "texels": o.l.len(), "clamped": o.clamped,
        })).collect::<Vec<_>>(),
        "error_map_texels": iterations.iter().map(|s| s.error_maps.iter().map(Vec::len).collect::<Vec<_>>()).collect::<Vec<_>>(),
        "iterations": iterations.iter().map(stats_json).collect::<Vec<_>>(),
        "warnings": warnings,
    });
    let text = serde_json::to_vec_pretty(&state).expect("JSON of plain values");
    (bin, text)
}

fn maps_name(iteration: usize) -> String {
    format!("maps-{iteration}.bin")
}

/// Writes the maps, then `state.json` (which makes the checkpoint the current one), then removes
/// the maps of earlier iterations.
fn write_files(dir: &Path, iteration: usize, bin: &[u8], text: &[u8]) -> Result<()> {
    write_atomic(&dir.join(maps_name(iteration)), bin)?;
    write_atomic(&dir.join("state.json"), text)?;
    // older maps are no longer referenced
    for k in 1..iteration {
        let _ = std::fs::remove_file(dir.join(maps_name(k)));
    }
    Ok(())
}

/// Whether `dir` holds a checkpoint (a `state.json` written by [`save`]).
pub(in crate::delight) fn exists(dir: &Path) -> bool {
    dir.join("state.json").is_file()
}

/// Reads a checkpoint written by [`save`] for `objects` (the recomputed state before the
/// iterations, whose fingerprint must match).
pub(in crate::delight) fn load(dir: &Path, fingerprint: u64, objects: &[ObjectResult]) -> Result<Saved> {
    let path = dir.join("state.json");
    let text = std::fs::read(&path).map_err(io(&path))?;
    let bad = |why: &str| Error::invalid(format!("checkpoint {}", path.display()), why.to_string());
    let v: Value = serde_json::from_slice(&text).map_err(|e| bad(&format!("not readable JSON: {e}")))?;
    if v["version"].as_u64() != Some(VERSION) {
        return Err(bad(&format!("version {} (expected {VERSION})", v["version"])));
    }
    if v["fingerprint"].as_str() != Some(format!("{fingerprint:016x}").as_str()) {
        return Err(bad(
            "made from other inputs or settings (the state before the iterations differs): cannot resume from it",
        ));
    }
    let u = |x: &Value, what: &str| x.as_u64().ok_or_else(|| bad(&format!("'{what}' is not an integer")));
    let f = |x: &Value, what: &str| u(x, what).map(f64::from_bits);
    let fv = |x: &Value, what: &str| -> Result<Vec<f64>> {
        x.as_array()
            .ok_or_else(|| bad(&format!("'{what}' is not an array")))?
            .iter()
            .map(|y| f(y, what))
            .collect()
    };
    let iteration = u(&v["iteration"], "iteration")? as usize;
    let light_paths = u(&v["light_paths"], "light_paths")?;
    let objs = v["objects"].as_array().ok_or_else(|| bad("'objects' is not an array"))?;
    if objs.len() != objects.len() {
        return Err(bad("another number of objects"));
    }
    let maps_name = v["maps"].as_str().ok_or_else(|| bad("'maps' is not a file name"))?;
    if maps_name.contains(['/', '\\']) {
        return Err(bad("'maps' must be a file name in the checkpoint folder"));
    }
    let maps_path: PathBuf = dir.join(maps_name);
    let bin = std::fs::read(&maps_path).map_err(io(&maps_path))?;
    let mut at = 0usize;
    let short =
        || Error::invalid(format!("checkpoint {}", maps_path.display()), "file too short".to_string());
    let mut take = |n: usize| -> Result<&[u8]> {
        let s = bin.get(at..at + n).ok_or_else(short)?;
        at += n;
        Ok(s)
    };
    let f32s = |b: &[u8]| -> Vec<f32> {
        b.chunks_exact(4).map(|c| f32::from_bits(u32::from_le_bytes([c[0], c[1], c[2], c[3]]))).collect()
    };
    let v3 = |x: Vec<f32>| -> Vec<[f32; 3]> { x.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect() };
    let mut maps = Vec::new();
    for (o, j) in objects.iter().zip(objs) {
        let n = o.l.len();
        if j["id"].as_str() != Some(o.id.as_str()) || j["texels"].as_u64() != Some(n as u64) {
            return Err(bad(&format!("object '{}' does not match", o.id)));
        }
        let l = v3(f32s(take(12 * n)?));
        let observed = take(n)?.iter().map(|&b| b != 0).collect();
        let ei = v3(f32s(take(12 * n)?));
        let kd = v3(f32s(take(12 * n)?));
        let clamped = u(&j["clamped"], "clamped")? as usize;
        maps.push(ObjectMaps { l, observed, ei, kd, clamped });
    }
    let sizes = v["error_map_texels"].as_array().ok_or_else(|| bad("'error_map_texels' is not an array"))?;
    let its = v["iterations"].as_array().ok_or_else(|| bad("'iterations' is not an array"))?;
    if its.len() != iteration || sizes.len() != iteration {
        return Err(bad("the iteration statistics do not match the iteration count"));
    }
    let mut iterations = Vec::new();
    for (s, sz) in its.iter().zip(sizes) {
        let sz = sz.as_array().ok_or_else(|| bad("'error_map_texels' entries are not arrays"))?;
        let mut error_maps = Vec::new();
        for n in sz {
            let n = u(n, "error_map_texels")? as usize;
            error_maps.push(f32s(take(4 * n)?));
        }
        let per_object = s["per_object"]
            .as_array()
            .ok_or_else(|| bad("'per_object' is not an array"))?
            .iter()
            .map(|p| Ok((f(&p[0], "per_object")?, f(&p[1], "per_object")?, u(&p[2], "per_object")? as usize)))
            .collect::<Result<Vec<_>>>()?;
        iterations.push(IterationStats {
            iteration: u(&s["iteration"], "iteration")? as usize,
            max_rel_error: f(&s["max_rel_error"], "max_rel_error")?,
            mean_rel_error: f(&s["mean_rel_error"], "mean_rel_error")?,
            per_object,
            error_maps,
            seconds: f(&s["seconds"], "seconds")?,
            light_paths: u(&s["light_paths"], "light_paths")?,
            texel_noise: fv(&s["texel_noise"], "texel_noise")?,
            texel_noise_all: f(&s["texel_noise_all"], "texel_noise_all")?,
            direct_ratio: fv(&s["direct_ratio"], "direct_ratio")?,
            // absent in checkpoints written before MPI runs existed
            comm_seconds: s["comm_seconds"].as_u64().map_or(0.0, f64::from_bits),
            // absent in checkpoints written before the stop rule measured it: not converged
            change_max: s["change_max"].as_u64().map_or(f64::NAN, f64::from_bits),
            change_beyond_noise: s["change_beyond_noise"].as_u64().map_or(f64::NAN, f64::from_bits),
            change_regions: s["change_regions"].as_u64().unwrap_or(0) as usize,
        });
    }
    if at != bin.len() {
        return Err(Error::invalid(
            format!("checkpoint {}", maps_path.display()),
            "unexpected trailing bytes",
        ));
    }
    let warnings = v["warnings"]
        .as_array()
        .ok_or_else(|| bad("'warnings' is not an array"))?
        .iter()
        .map(|w| w.as_str().map(str::to_string).ok_or_else(|| bad("a warning is not a string")))
        .collect::<Result<Vec<_>>>()?;
    Ok(Saved { iteration, light_paths, iterations, warnings, maps })
}

impl ObjectMaps {
    /// Puts the saved maps back into `o`.
    pub fn restore(self, o: &mut ObjectResult) {
        o.l = self.l;
        o.observed = self.observed;
        o.ei = self.ei;
        o.kd = self.kd;
        o.clamped = self.clamped;
    }
}
