//! [`opal::dist::Comm`] over MPI (the `mpi` crate against the system's MPI library).
//!
//! Threading: MPI is initialised at level `Serialized`. The workloads make their collective
//! calls from the one thread that drives a run (a rayon worker inside `pool.install`, not always
//! the main thread), never from two threads at once; a mutex around the communicator makes that
//! explicit. Variable-length gathers send their counts first; buffers are split into pieces of
//! less than 2³¹ elements (MPI counts are C ints).

use mpi::Count;
use mpi::collective::SystemOperation;
use mpi::datatype::PartitionMut;
use mpi::environment::Universe;
use mpi::topology::{Communicator, SimpleCommunicator};
use mpi::traits::*;
use std::sync::Mutex;
use std::time::Instant;

/// Largest piece of one collective call (elements).
const PIECE: usize = 1 << 30;

/// The world communicator of an MPI job.
pub(super) struct MpiComm {
    world: Mutex<SimpleCommunicator>,
    rank: usize,
    size: usize,
    seconds: Mutex<f64>,
}

// SAFETY: the communicator is a handle of the MPI library, initialised with
// `Threading::Serialized`, which allows calls from any thread as long as no two are concurrent;
// every use goes through the mutex.
unsafe impl Send for MpiComm {}
unsafe impl Sync for MpiComm {}

impl std::fmt::Debug for MpiComm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "MpiComm(rank {} of {})", self.rank, self.size)
    }
}

/// Whether an MPI launcher started this process (Open MPI's mpirun, PMI/PMIx launchers such as
/// Slurm's srun, MPICH's Hydra).
fn launched() -> bool {
    ["OMPI_COMM_WORLD_SIZE", "PMIX_RANK", "PMI_RANK", "PMI_SIZE"]
        .iter()
        .any(|v| std::env::var_os(v).is_some())
}

/// Initialises MPI when started by a launcher.
pub(super) fn join() -> Option<(MpiComm, Universe)> {
    if !launched() {
        return None;
    }
    let (universe, level) = mpi::initialize_with_threading(mpi::Threading::Serialized)?;
    if !matches!(level, mpi::Threading::Serialized | mpi::Threading::Multiple) {
        eprintln!("error: the MPI library does not support MPI_THREAD_SERIALIZED (got {level:?})");
        universe.world().abort(2);
    }
    let world = universe.world();
    let (rank, size) = (world.rank() as usize, world.size() as usize);
    Some((MpiComm { world: Mutex::new(world), rank, size, seconds: Mutex::new(0.0) }, universe))
}

/// Sends this rank's stdout to `/dev/null` (only rank 0 prints reports).
pub(super) fn silence_stdout_unless_root(rank: usize) {
    if rank == 0 {
        return;
    }
    use std::os::fd::AsRawFd;
    if let Ok(null) = std::fs::OpenOptions::new().write(true).open("/dev/null") {
        // SAFETY: dup2 on two valid descriptors; fd 1 is replaced atomically.
        unsafe {
            libc::dup2(null.as_raw_fd(), 1);
        }
    }
}

/// Aborts every rank of the job.
pub(super) fn abort(code: i32) -> ! {
    mpi::topology::SimpleCommunicator::world().abort(code)
}

impl MpiComm {
    fn timed<T>(&self, f: impl FnOnce(&SimpleCommunicator) -> T) -> T {
        let world = self.world.lock().unwrap_or_else(|e| e.into_inner());
        let t0 = Instant::now();
        let out = f(&world);
        *self.seconds.lock().unwrap_or_else(|e| e.into_inner()) += t0.elapsed().as_secs_f64();
        out
    }
}

impl opal::dist::Comm for MpiComm {
    fn rank(&self) -> usize {
        self.rank
    }
    fn size(&self) -> usize {
        self.size
    }
    fn all_gather_bytes(&self, mine: &[u8]) -> Vec<Vec<u8>> {
        self.timed(|w| {
            let len = mine.len() as u64;
            let mut lens = vec![0u64; self.size];
            w.all_gather_into(&len, &mut lens[..]);
            let mut out: Vec<Vec<u8>> = lens.iter().map(|&l| vec![0u8; l as usize]).collect();
            // pieces of < 2³¹ bytes: piece p of every rank's buffer in one gather
            let pieces = lens.iter().map(|&l| (l as usize).div_ceil(PIECE)).max().unwrap_or(0);
            for p in 0..pieces {
                let part = |l: usize| (p * PIECE).min(l)..((p + 1) * PIECE).min(l);
                let counts: Vec<Count> = lens.iter().map(|&l| part(l as usize).len() as Count).collect();
                let displs: Vec<Count> =
                    counts.iter().scan(0, |acc, &c| Some(std::mem::replace(acc, *acc + c))).collect();
                let mut buf = vec![0u8; counts.iter().map(|&c| c as usize).sum()];
                {
                    let mut recv = PartitionMut::new(&mut buf[..], &counts[..], &displs[..]);
                    w.all_gather_varcount_into(&mine[part(mine.len())], &mut recv);
                }
                for (r, o) in out.iter_mut().enumerate() {
                    let range = part(o.len());
                    let d = displs[r] as usize;
                    o[range.clone()].copy_from_slice(&buf[d..d + range.len()]);
                }
            }
            out
        })
    }
    fn all_gather_into(&self, mine: &[u8], out: &mut Vec<u8>) -> Vec<usize> {
        let lens = self.timed(|w| {
            let len = mine.len() as u64;
            let mut lens = vec![0u64; self.size];
            w.all_gather_into(&len, &mut lens[..]);
            lens
        });
        let total: u64 = lens.iter().sum();
        let lens: Vec<usize> = lens.iter().map(|&l| l as usize).collect();
        if total >= PIECE as u64 {
            // offsets beyond a C int: through the pieces of `all_gather_bytes`
            let all = self.all_gather_bytes(mine);
            out.clear();
            all.iter().for_each(|b| out.extend_from_slice(b));
            return lens;
        }
        // one gather straight into `out` (rank r's bytes at the sum of the lengths before it)
        out.clear();
        out.resize(total as usize, 0);
        let counts: Vec<Count> = lens.iter().map(|&l| l as Count).collect();
        let displs: Vec<Count> =
            counts.iter().scan(0, |acc, &c| Some(std::mem::replace(acc, *acc + c))).collect();
        self.timed(|w| {
            let mut recv = PartitionMut::new(&mut out[..], &counts[..], &displs[..]);
            w.all_gather_varcount_into(mine, &mut recv);
        });
        lens
    }
    fn all_sum_u64(&self, data: &mut [u64]) {
        self.timed(|w| {
            for piece in data.chunks_mut(PIECE) {
                let send = piece.to_vec();
                w.all_reduce_into(&send[..], piece, SystemOperation::sum());
            }
        })
    }
    fn comm_seconds(&self) -> f64 {
        *self.seconds.lock().unwrap_or_else(|e| e.into_inner())
    }
}
