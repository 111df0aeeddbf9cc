//! Shared CLI helpers: atomic output files, progress bars, input/output path checks.

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

static QUIET: AtomicBool = AtomicBool::new(false);

/// Sets the number of worker threads of the global pool (`None`: all cores). Results never
/// depend on it (the determinism tests run each command on 1 and 2 threads).
pub fn set_threads(threads: Option<usize>) {
    if let Some(t) = threads {
        rayon::ThreadPoolBuilder::new().num_threads(t.max(1)).build_global().ok();
    }
}

/// Hide progress bars and progress messages from now on.
pub fn set_quiet(q: bool) {
    QUIET.store(q, Ordering::Relaxed);
}

/// Whether progress bars and progress messages are hidden (`--quiet`, or a rank other than 0
/// under MPI).
pub fn is_quiet() -> bool {
    QUIET.load(Ordering::Relaxed)
}

/// Set by the first Ctrl-C (SIGINT) or SIGTERM; long runs stop at their next checkpoint.
static INTERRUPT: std::sync::OnceLock<std::sync::Arc<AtomicBool>> = std::sync::OnceLock::new();

/// The flag [`install_interrupt_handler`] sets on the first signal (the Python package sets
/// it on `KeyboardInterrupt` and clears it before each call).
pub fn interrupt_flag() -> std::sync::Arc<AtomicBool> {
    INTERRUPT.get_or_init(Default::default).clone()
}

/// Ctrl-C / SIGTERM handling for long runs: the first signal sets [`interrupt_flag`] (the run
/// stops at its next stage or iteration boundary, keeps what it can and renames no partial
/// output into place); a second one exits at once with code 130 (temporary files are left as
/// `.opal-tmp-*`, never under an output's name).
pub fn install_interrupt_handler() {
    let flag = interrupt_flag();
    let r = ctrlc::set_handler(move || {
        if flag.swap(true, Ordering::SeqCst) {
            eprintln!("interrupted again: exiting now");
            std::process::exit(130);
        }
        eprintln!("interrupt: stopping at the next stage or iteration boundary (Ctrl-C again to exit now)");
    });
    // a second installation (e.g. `demo` running several commands) keeps the first handler
    let _ = r;
}

/// Ctrl-C / SIGTERM for the commands without checkpoints: says that no output was written
/// (outputs are renamed into place only when complete; a half-written one stays under a
/// `.opal-tmp-*` name) and exits with code 130.
pub fn install_exit_handler(command: &'static str) {
    let _ = ctrlc::set_handler(move || {
        eprintln!(
            "interrupted: `opal {command}` stopped before it finished; no output file of this run was written"
        );
        std::process::exit(130);
    });
}

/// The bar [`progress`] made last (read by the Python package's progress callback).
static CURRENT: std::sync::Mutex<Option<ProgressBar>> = std::sync::Mutex::new(None);

/// Message, position and length of the progress bar made last, if any (a hidden bar counts
/// too): what a long command has done so far.
pub fn current_progress() -> Option<(String, u64, Option<u64>)> {
    let g = CURRENT.lock().unwrap_or_else(|e| e.into_inner());
    g.as_ref().map(|pb| (pb.message(), pb.position(), pb.length()))
}

/// Forgets the bar of [`current_progress`] (before a new command).
pub fn clear_progress() {
    *CURRENT.lock().unwrap_or_else(|e| e.into_inner()) = None;
}

/// A progress bar on stderr with `len` steps; hidden with `--quiet` or when stderr is not a
/// terminal.
pub fn progress(len: u64, msg: &str) -> ProgressBar {
    let pb = ProgressBar::new(len);
    *CURRENT.lock().unwrap_or_else(|e| e.into_inner()) = Some(pb.clone());
    if QUIET.load(Ordering::Relaxed) || !std::io::stderr().is_terminal() {
        pb.set_draw_target(ProgressDrawTarget::hidden());
    }
    pb.set_style(
        ProgressStyle::with_template("{msg:12} [{elapsed_precise}] {wide_bar} {pos}/{len} (eta {eta})")
            .expect("valid template"),
    );
    pb.set_message(msg.to_string());
    pb
}

/// Runs `f` (e.g. printing a log line) with the bar of [`progress`] made last hidden, so the
/// line does not tear it; the bar is drawn again after.
pub fn suspend_progress<R>(f: impl FnOnce() -> R) -> R {
    let pb = CURRENT.lock().unwrap_or_else(|e| e.into_inner()).clone();
    match pb {
        Some(pb) if !pb.is_finished() && !pb.is_hidden() => pb.suspend(f),
        _ => f(),
    }
}

/// A progress callback `(stage, done, total)` for a library's long stages (e.g.
/// `opal_inverse::delight::Progress`): one bar of [`progress`] per stage (position and length
/// in the stage's units, with an estimate of the time left), removed when the stage is done or
/// the next one starts. Hidden with `--quiet` or when stderr is not a terminal, as every bar.
pub fn stage_progress() -> impl Fn(&str, u64, u64) + Send + Sync + 'static {
    let current: std::sync::Mutex<Option<(String, ProgressBar)>> = std::sync::Mutex::new(None);
    move |stage, done, total| {
        let mut g = current.lock().unwrap_or_else(|e| e.into_inner());
        if g.as_ref().is_none_or(|(s, _)| s != stage) {
            if let Some((_, pb)) = g.take() {
                pb.finish_and_clear();
            }
            *g = Some((stage.to_string(), progress(total, stage)));
        }
        let Some((_, pb)) = g.as_ref() else { return };
        pb.set_length(total);
        pb.set_position(done);
        if done >= total {
            pb.finish_and_clear();
        }
    }
}

/// Writes a file atomically: the content goes to a temporary file in the target folder, which
/// is renamed into place only when `write` succeeded. A crash never leaves a half-written file.
/// In a job of several processes only rank 0 writes (the others return `Ok` at once; see
/// [`crate::dist`]).
pub fn write_atomic(path: &Path, write: impl FnOnce(&mut std::fs::File) -> Result<()>) -> Result<()> {
    if !crate::dist::is_root() {
        return Ok(());
    }
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create folder {}", dir.display()))?;
    let mut tmp = tempfile::Builder::new()
        .prefix(".opal-tmp-")
        .tempfile_in(&dir)
        .with_context(|| format!("cannot create a temporary file in {}", dir.display()))?;
    write(tmp.as_file_mut()).with_context(|| format!("while writing {}", path.display()))?;
    tmp.as_file_mut().flush()?;
    // temporary files are created 0600; give the result the usual permissions (0644 on Unix)
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        tmp.as_file().set_permissions(std::fs::Permissions::from_mode(0o644))?;
    }
    tmp.persist(path).with_context(|| format!("cannot move the result into {}", path.display()))?;
    Ok(())
}

/// Writes bytes atomically.
pub fn write_bytes_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic(path, |f| {
        f.write_all(bytes)?;
        Ok(())
    })
}

/// Refuses an output path that is one of the inputs.
pub fn ensure_not_input(output: &Path, inputs: &[&Path]) -> Result<()> {
    let out = std::fs::canonicalize(output).ok();
    for i in inputs {
        if let (Some(o), Ok(i2)) = (&out, std::fs::canonicalize(i))
            && *o == i2
        {
            bail!("refusing to overwrite the input file {}", i.display());
        }
    }
    Ok(())
}
