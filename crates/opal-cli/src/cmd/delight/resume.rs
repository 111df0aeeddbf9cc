//! `opal delight --resume OUTDIR`: continue an interrupted run from its output folder alone.
//!
//! Every run saves its command line and working directory in `OUTDIR/checkpoint/args.json`
//! ([`save_args`]) before any work starts; the folder is removed with the rest of the checkpoint
//! once the run finishes. [`expand`] turns `opal [--quiet] delight --resume OUTDIR` into that
//! saved command line plus `--resume`, run from the saved working directory, so relative paths
//! mean what they meant. The other form, the run's own arguments plus `--resume`, needs no
//! expansion.
//!
//! Tests: `tests/delight_inputs.rs` (`interrupted_delight_resumes_to_the_same_bytes` resumes by
//! OUTDIR; `resume_without_a_checkpoint_is_a_clear_error`).

use anyhow::{Context, Result, bail};
use serde_json::json;
use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The file in the checkpoint folder that holds the run's command line.
pub const ARGS_FILE: &str = "args.json";

/// The command line this process runs (after [`expand`]).
static EFFECTIVE: OnceLock<Vec<String>> = OnceLock::new();

/// Saves the command line (without the program name) and the working directory into
/// `checkpoint/args.json`. Command lines with non-UTF-8 arguments are not saved (the resume then
/// needs the run's own arguments).
pub fn save_args(checkpoint: &Path) -> Result<()> {
    let args: Vec<String> = match EFFECTIVE.get() {
        Some(a) => a.clone(),
        None => match std::env::args_os().skip(1).map(OsString::into_string).collect() {
            Ok(a) => a,
            Err(_) => return Ok(()),
        },
    };
    let Some(cwd) = std::env::current_dir().ok().and_then(|d| d.to_str().map(String::from)) else {
        return Ok(());
    };
    std::fs::create_dir_all(checkpoint).with_context(|| format!("cannot create {}", checkpoint.display()))?;
    let text = serde_json::to_string_pretty(&json!({"version": 1, "cwd": cwd, "args": args}))?;
    crate::util::write_bytes_atomic(&checkpoint.join(ARGS_FILE), text.as_bytes())
}

/// Removes the saved command line of a run that failed before keeping any iteration (no
/// `state.json` beside it), then the checkpoint folder and `created` (the output folder, when
/// the run created it) if they are left empty.
pub fn discard_args(checkpoint: &Path, created: Option<&Path>) {
    if checkpoint.join("state.json").exists() {
        return;
    }
    let _ = std::fs::remove_file(checkpoint.join(ARGS_FILE));
    let _ = std::fs::remove_dir(checkpoint);
    if let Some(out) = created {
        let _ = std::fs::remove_dir(out);
    }
}

/// Expands `opal [--quiet] delight --resume OUTDIR` (also `--resume=OUTDIR`) into the saved
/// command line of the run in OUTDIR plus `--resume`, after changing into its working directory;
/// any other command line is returned unchanged.
pub fn expand(argv: Vec<OsString>) -> Result<Vec<OsString>> {
    let Some(strs) = argv.iter().map(|a| a.to_str()).collect::<Option<Vec<&str>>>() else {
        return Ok(argv);
    };
    let Some(sub) = strs.iter().skip(1).position(|a| !a.starts_with('-')).map(|i| i + 1) else {
        return Ok(argv);
    };
    if strs[sub] != "delight" {
        return Ok(argv);
    }
    let rest = &strs[sub + 1..];
    let dir = match rest {
        ["--resume", d] if !d.starts_with('-') => PathBuf::from(d),
        [r] if r.starts_with("--resume=") => PathBuf::from(&r["--resume=".len()..]),
        _ => {
            if rest.iter().any(|a| a.starts_with("--resume=")) {
                bail!(
                    "--resume=OUTDIR takes no other arguments (they are read from OUTDIR/checkpoint/{ARGS_FILE})"
                );
            }
            let _ = EFFECTIVE.set(strs[1..].iter().map(|s| s.to_string()).collect());
            return Ok(argv);
        }
    };
    let file = dir.join(super::CHECKPOINT).join(ARGS_FILE);
    let text = std::fs::read_to_string(&file).with_context(|| {
        format!(
            "cannot resume from {}: no saved command line {} (was the run started by this version of opal, \
             and has it not finished already?)",
            dir.display(),
            file.display()
        )
    })?;
    let v: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{}: not readable JSON", file.display()))?;
    let bad = |what: &str| anyhow::anyhow!("{}: {what}", file.display());
    let cwd = v["cwd"].as_str().ok_or_else(|| bad("'cwd' is not a string"))?;
    let saved: Vec<String> = v["args"]
        .as_array()
        .ok_or_else(|| bad("'args' is not an array"))?
        .iter()
        .map(|a| a.as_str().map(String::from).ok_or_else(|| bad("an argument is not a string")))
        .collect::<Result<_>>()?;
    if !saved.iter().any(|a| a == "delight") {
        return Err(bad("the saved command line is not an `opal delight` run"));
    }
    // the output folder the saved run writes, seen from its working directory
    let here = std::env::current_dir()?;
    let target = std::fs::canonicalize(&dir).with_context(|| format!("cannot open {}", dir.display()))?;
    std::env::set_current_dir(cwd)
        .with_context(|| format!("cannot change into {cwd}, the run's working directory"))?;
    let out = saved
        .iter()
        .zip(saved.iter().skip(1))
        .find(|(k, _)| *k == "-o" || *k == "--output")
        .map(|(_, v)| PathBuf::from(v))
        .or_else(|| saved.iter().find_map(|a| a.strip_prefix("--output=").map(PathBuf::from)))
        .ok_or_else(|| bad("the saved command line has no -o/--output"))?;
    if std::fs::canonicalize(&out).ok().as_deref() != Some(target.as_path()) {
        std::env::set_current_dir(here)?;
        bail!("{}: the saved run writes {}, not {}", file.display(), out.display(), dir.display());
    }
    let mut expanded: Vec<String> = vec![strs[0].to_string()];
    // global flags given now (e.g. --quiet) and not already saved
    expanded.extend(strs[1..sub].iter().filter(|g| !saved.iter().any(|a| a == *g)).map(|s| s.to_string()));
    expanded.extend(saved.into_iter().filter(|a| a != "--resume"));
    expanded.push("--resume".into());
    let _ = EFFECTIVE.set(expanded[1..].to_vec());
    Ok(expanded.into_iter().map(OsString::from).collect())
}
