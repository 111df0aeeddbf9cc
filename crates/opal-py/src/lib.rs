//! `opal._native`: the compiled half of the `opal` Python package (the Python half in
//! `python/opal/` turns its bytes and JSON into numpy arrays and dicts).
//!
//! Every call runs the same library functions as the `opal` command line (`opal_cli`, which
//! calls `opal` and `opal_inverse`), so a render or a fit gives the CLI's bits and its error
//! messages. Long calls run on a worker thread while the calling thread waits without the GIL,
//! waking every 100 ms to check for Ctrl-C (`Python::check_signals`: a `KeyboardInterrupt`
//! sets the cancel flag the libraries poll, then waits for the worker to stop) and to call the
//! optional progress callback `progress(stage, done, total)`.
//!
//! Conventions: images cross as little-endian float32 bytes, row 0 at the top, RGB
//! interleaved; command results cross as JSON text. Errors raise `opal.OpalError` (a
//! `ValueError`) carrying the CLI's message; an interruption raises `KeyboardInterrupt`.
//! Tests: `tests/` (pytest, run by `run-tests.sh`).

use anyhow::{Context, Result};
use clap::Parser;
use opal_cli::{Cli, Command, cmd, util};
use pyo3::create_exception;
use pyo3::exceptions::{PyKeyboardInterrupt, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyByteArray;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::sync::mpsc::{RecvTimeoutError, channel};
use std::time::Duration;

create_exception!(
    _native,
    OpalError,
    PyValueError,
    "An Opal error: bad input, unreadable file, failed run (the message is the CLI's)."
);

/// How often the waiting thread wakes to check signals and report progress.
const POLL: Duration = Duration::from_millis(100);

/// The Python exception of a library error: `KeyboardInterrupt` for an interruption, else
/// `OpalError` with the CLI's `{error:#}` text.
fn to_py(e: anyhow::Error) -> PyErr {
    let interrupted = e.chain().any(|c| {
        matches!(c.downcast_ref::<opal::error::Error>(), Some(opal::error::Error::Interrupted { .. }))
    });
    if interrupted {
        PyKeyboardInterrupt::new_err(format!("{e:#}"))
    } else {
        OpalError::new_err(format!("{e:#}"))
    }
}

/// Calls `progress(stage, done, total)` with the state of the current progress bar.
fn report_progress(progress: Option<&Bound<'_, PyAny>>) -> PyResult<()> {
    if let (Some(cb), Some((msg, pos, len))) = (progress, util::current_progress()) {
        cb.call1((msg, pos, len))?;
    }
    Ok(())
}

/// Runs `work` on a worker thread (in a pool of `threads` threads, default: all cores) while
/// this thread waits without the GIL, checking for Ctrl-C and reporting progress every
/// [`POLL`]. On a Python exception (Ctrl-C, or one raised by the callback) the cancel flag is
/// set, the worker is waited for, and the exception is raised.
fn run_polled<T: Send>(
    py: Python<'_>,
    threads: Option<usize>,
    progress: Option<&Bound<'_, PyAny>>,
    work: impl FnOnce() -> Result<T> + Send,
) -> PyResult<T> {
    let flag = util::interrupt_flag();
    flag.store(false, Ordering::SeqCst);
    util::clear_progress();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads.unwrap_or(0))
        .build()
        .map_err(|e| OpalError::new_err(format!("cannot start {threads:?} worker threads: {e}")))?;
    let (tx, rx) = channel();
    std::thread::scope(|s| {
        s.spawn(move || {
            let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| pool.install(work)));
            let r = r.unwrap_or_else(|p| {
                let msg = p
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_else(|| "unknown panic".into());
                Err(anyhow::anyhow!("internal error (a bug in Opal, please report it): {msg}"))
            });
            let _ = tx.send(r);
        });
        let mut rx = rx;
        let mut pending: Option<PyErr> = None;
        loop {
            let (got, back) = py.detach(move || {
                let r = rx.recv_timeout(POLL);
                (r, rx)
            });
            rx = back;
            match got {
                Ok(r) => {
                    if let Some(e) = pending {
                        return Err(e);
                    }
                    let v = r.map_err(to_py)?;
                    report_progress(progress)?;
                    return Ok(v);
                }
                Err(RecvTimeoutError::Timeout) => {
                    if pending.is_some() {
                        continue;
                    }
                    if let Err(e) = py.check_signals().and_then(|_| report_progress(progress)) {
                        flag.store(true, Ordering::SeqCst);
                        pending = Some(e);
                    }
                }
                Err(RecvTimeoutError::Disconnected) => {
                    return Err(pending.unwrap_or_else(|| OpalError::new_err("the worker thread stopped")));
                }
            }
        }
    })
}

/// Little-endian float32 bytes of an image, row 0 at the top, RGB interleaved.
fn image_bytes<'py>(py: Python<'py>, img: &opal::image::Image) -> Bound<'py, PyByteArray> {
    let mut v = Vec::with_capacity(img.data.len() * 12);
    for p in &img.data {
        for c in p.0 {
            v.extend_from_slice(&c.to_le_bytes());
        }
    }
    PyByteArray::new(py, &v)
}

/// A built scene (`opal.load_scene`).
#[pyclass(name = "Scene", module = "opal._native", frozen)]
struct PyScene {
    scene: Arc<opal::scene::Scene>,
    path: PathBuf,
}

#[pymethods]
impl PyScene {
    /// The sensors as (id, width, height).
    #[getter]
    fn sensors(&self) -> Vec<(String, usize, usize)> {
        self.scene.cameras.iter().map(|c| (c.id.clone(), c.width, c.height)).collect()
    }

    /// The scene file.
    #[getter]
    fn path(&self) -> PathBuf {
        self.path.clone()
    }

    /// Renders a sensor like `opal render`: (bytes, height, width, report JSON).
    #[pyo3(signature = (spp=None, max_depth=None, sensor="0".to_string(), seed=0, threads=None, progress=None))]
    #[allow(clippy::too_many_arguments)]
    fn render<'py>(
        &self,
        py: Python<'py>,
        spp: Option<u32>,
        max_depth: Option<i32>,
        sensor: String,
        seed: u64,
        threads: Option<usize>,
        progress: Option<Bound<'py, PyAny>>,
    ) -> PyResult<(Bound<'py, PyByteArray>, usize, usize, String)> {
        cmd::render::check_spp(spp).map_err(to_py)?;
        let scene = self.scene.clone();
        let (out, report) = run_polled(py, threads, progress.as_ref(), move || {
            let cam = cmd::render::pick_sensor(&scene, &sensor)?;
            cmd::render::check_camera_sees_something(&scene, cam)?;
            let settings = cmd::render::path_settings(&scene, cam, spp, max_depth, seed);
            let c = &scene.cameras[cam];
            let pb = util::progress(c.height as u64, "render");
            let flag = util::interrupt_flag();
            let t0 = std::time::Instant::now();
            let out = opal::integrator::path::render_cancellable(
                &scene,
                cam,
                &settings,
                &|| pb.inc(1),
                Some(&flag),
            )?;
            let secs = t0.elapsed().as_secs_f64();
            pb.finish_and_clear();
            let report = serde_json::json!({
                "sensor": c.id, "width": c.width, "height": c.height, "spp": settings.spp,
                "max_depth": settings.max_depth, "seed": settings.seed, "seconds": secs,
                "samples_per_second": out.samples as f64 / secs, "nonfinite_samples": out.nonfinite,
                "mean_rgb": out.image.mean(), "no_emitter": scene.lights.is_empty(),
            });
            Ok((out, report.to_string()))
        })?;
        Ok((image_bytes(py, &out.image), out.image.height, out.image.width, report))
    }

    fn __repr__(&self) -> String {
        format!("Scene({:?}, sensors={})", self.path.display().to_string(), self.scene.cameras.len())
    }
}

/// Loads and builds a Mitsuba 3 XML scene with `$name` parameters (`opal render -D`).
#[pyfunction]
#[pyo3(signature = (path, defines=Vec::new()))]
fn load_scene(py: Python<'_>, path: PathBuf, defines: Vec<(String, String)>) -> PyResult<PyScene> {
    let p = path.clone();
    let scene = run_polled(py, None, None, move || cmd::render::load_scene(&p, &defines))?;
    Ok(PyScene { scene: Arc::new(scene), path })
}

/// Reads an EXR (or PNG / HDR) image as stored: (bytes, height, width).
#[pyfunction]
fn read_exr<'py>(py: Python<'py>, path: PathBuf) -> PyResult<(Bound<'py, PyByteArray>, usize, usize)> {
    let img = py.detach(|| opal::image::read::read_image(&path)).map_err(|e| to_py(e.into()))?;
    Ok((image_bytes(py, &img), img.height, img.width))
}

/// Writes float32 RGB bytes (row 0 at the top) as an EXR, atomically, like `opal render`.
#[pyfunction]
fn write_exr(py: Python<'_>, path: PathBuf, data: Vec<u8>, height: usize, width: usize) -> PyResult<()> {
    if data.len() != height * width * 12 {
        return Err(OpalError::new_err(format!(
            "write_exr: {} bytes for a {height}x{width} RGB float32 image (need {})",
            data.len(),
            height * width * 12
        )));
    }
    py.detach(|| {
        let mut img = opal::image::Image::new(width, height);
        for (p, c) in img.data.iter_mut().zip(data.chunks_exact(12)) {
            for (k, b) in c.chunks_exact(4).enumerate() {
                p.0[k] = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
            }
        }
        util::write_atomic(&path, |f| Ok(opal::image::write::write_exr(&img, std::io::BufWriter::new(f))?))
    })
    .map_err(to_py)
}

/// Runs an `opal` subcommand given as command-line words (`["gonio", "simulate", "-o", "x",
/// …]`) without its printing: returns its result as JSON text (see the Python wrappers).
#[pyfunction]
#[pyo3(signature = (argv, threads=None, progress=None))]
fn run_command(
    py: Python<'_>,
    argv: Vec<String>,
    threads: Option<usize>,
    progress: Option<Bound<'_, PyAny>>,
) -> PyResult<String> {
    let cli = Cli::try_parse_from(std::iter::once("opal".to_string()).chain(argv))
        .map_err(|e| OpalError::new_err(e.render().to_string().trim_end().to_string()))?;
    let v = run_polled(py, threads, progress.as_ref(), move || match cli.command {
        Command::Gonio(a) => cmd::gonio::simulate_json(a, Some(util::interrupt_flag())),
        Command::Brdf(a) => cmd::brdf::run_json(a),
        Command::FitNdf(a) => {
            let mut inputs: Vec<&std::path::Path> = a.measured.iter().map(PathBuf::as_path).collect();
            if let Some(p) = &a.plate {
                inputs.push(p);
            }
            util::ensure_not_input(&a.output, &inputs)?;
            let o = cmd::fit_ndf::fit_and_write(&a, &a.output)?;
            Ok(o.json)
        }
        Command::Delight(a) => {
            util::ensure_not_input(&a.output, &[&a.scene, &a.views])?;
            let log = std::sync::Mutex::new(Vec::<String>::new());
            let push = |l: &str| log.lock().unwrap_or_else(|e| e.into_inner()).push(l.to_string());
            let mut report = cmd::delight::run_pipeline(&a, &push).map_err(|e| {
                match e.downcast_ref::<opal::error::Error>() {
                    Some(opal::error::Error::Interrupted { .. }) => {
                        e.context("stopped on request; to continue, run the same call with resume=True")
                    }
                    _ => e,
                }
            })?;
            let _ = std::fs::remove_dir_all(a.output.join(cmd::delight::CHECKPOINT));
            report["log"] = serde_json::json!(log.into_inner().unwrap_or_else(|e| e.into_inner()));
            Ok(report)
        }
        Command::Render(_) | Command::Demo(_) => {
            anyhow::bail!("this subcommand is not run through run_command (use Scene.render)")
        }
    })?;
    serde_json::to_string(&v).context("encoding the result").map_err(to_py)
}

/// The compiled module `opal._native`.
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    // the Python API reports progress through its callback, not through terminal bars
    util::set_quiet(true);
    m.add("OpalError", m.py().get_type::<OpalError>())?;
    m.add_class::<PyScene>()?;
    m.add_function(wrap_pyfunction!(load_scene, m)?)?;
    m.add_function(wrap_pyfunction!(read_exr, m)?)?;
    m.add_function(wrap_pyfunction!(write_exr, m)?)?;
    m.add_function(wrap_pyfunction!(run_command, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
