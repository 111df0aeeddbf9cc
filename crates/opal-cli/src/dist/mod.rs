//! The processes of one `opal` run. Built with the `mpi` feature and started by an MPI launcher
//! (`mpirun`, `srun`), the run is split across the ranks: rows of `render`, photon batches of
//! `gonio simulate` and of every objective evaluation of `fit-ndf`, light paths of every
//! de-lighting pass (`opal::dist` has the contract: the same bits for any rank count). Otherwise
//! (no feature, or not under a launcher) it is one process, exactly as without MPI.
//!
//! Conventions: every rank runs the whole command on the same inputs (the stages that are not
//! split run redundantly); only rank 0 writes files ([`crate::util::write_atomic`] does nothing on
//! the other ranks) and prints to stdout (the others' stdout goes to `/dev/null`); the others
//! keep quiet (no progress bars). A rank that fails or panics aborts the whole job
//! ([`fail`]: MPI_Abort with the error on stderr), so no rank waits forever and no partial
//! output is renamed into place.
//!
//! Tests: `tests/mpi.rs` (with `--features mpi`: the binary under `mpirun -np 1/2` against the
//! plain run, output bytes compared).

#[cfg(feature = "mpi")]
mod mpi;

use opal::dist::{Comm, Solo};
use std::sync::{Arc, OnceLock};

static COMM: OnceLock<Arc<dyn Comm>> = OnceLock::new();

/// Joins the MPI job when the binary was built with the `mpi` feature and started by an MPI
/// launcher; otherwise the run is one process. Call once, first thing in `main`; keep the
/// returned guard alive until the end (dropping it finalises MPI).
pub fn init() -> Guard {
    #[cfg(feature = "mpi")]
    if let Some((comm, universe)) = mpi::join() {
        let comm: Arc<dyn Comm> = Arc::new(comm);
        if comm.size() > 1 {
            let _ = COMM.set(comm);
            mpi::silence_stdout_unless_root(rank());
            let default = std::panic::take_hook();
            std::panic::set_hook(Box::new(move |info| {
                default(info);
                fail(&format!("panic: {info}"));
            }));
        }
        return Guard { _universe: Some(universe) };
    }
    Guard {
        #[cfg(feature = "mpi")]
        _universe: None,
    }
}

/// Keeps MPI initialised while alive.
pub struct Guard {
    #[cfg(feature = "mpi")]
    _universe: Option<::mpi::environment::Universe>,
}

impl Guard {
    /// Finalises MPI (when this run joined a job) before the process exits.
    pub fn finish(self) {}
}

/// The communicator of this run when it has more than one process.
pub fn comm() -> Option<Arc<dyn Comm>> {
    COMM.get().cloned()
}

/// The communicator of this run ([`Solo`] when it is one process).
pub fn comm_or_solo() -> Arc<dyn Comm> {
    comm().unwrap_or_else(|| Arc::new(Solo))
}

/// This process's rank (0 when alone).
pub fn rank() -> usize {
    COMM.get().map_or(0, |c| c.rank())
}

/// Number of processes (1 when alone).
pub fn size() -> usize {
    COMM.get().map_or(1, |c| c.size())
}

/// Whether this process writes the outputs (rank 0).
pub fn is_root() -> bool {
    rank() == 0
}

/// Ends the run after an error: alone, returns (the caller exits as usual); in a job of several
/// ranks, prints the message with the rank and aborts every rank (MPI_Abort, exit code 2).
pub fn fail(message: &str) {
    if size() > 1 {
        eprintln!("rank {} of {}: {message}; aborting the job", rank(), size());
        #[cfg(feature = "mpi")]
        mpi::abort(2);
    }
}
