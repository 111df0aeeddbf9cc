//! Splitting work across processes (e.g. MPI ranks) with results bitwise independent of the
//! process count. The library stays free of any message-passing library: a caller that runs
//! several processes implements [`Comm`] (the `opal` CLI does so over MPI behind its `mpi`
//! feature) and hands it to the workloads; without one, [`Solo`] (one process) is used.
//!
//! Conventions: the units of work are exactly the ones that already make each workload
//! independent of the thread count — rows of a render, photon batches of the goniophotometer,
//! path batches of a light-tracing pass. Unit `i` of `n` belongs to rank `i mod size`
//! ([`Comm::owns`]: interleaved, so that cheap and expensive regions spread over the ranks).
//! Reductions are exact: integer sums ([`Comm::all_sum_u64`], wrapping, so any order gives the
//! same bits) or per-unit float results exchanged whole ([`Comm::all_gather_bytes`]) and then
//! folded by every rank in unit order, as the one-process code folds them. Every rank ends with
//! the full result; the caller decides who writes it.
//!
//! Tests: the one-rank implementation below; `opal-cli/tests/mpi.rs` (with the `mpi` feature)
//! runs the real binary under `mpirun -np 1/2` and compares output bytes with the plain build.

/// A group of processes that run the same workload on their share of its units.
///
/// Every rank must call the collective methods in the same order with matching arguments
/// (like MPI collectives).
pub trait Comm: std::fmt::Debug + Send + Sync {
    /// This process's index, `0..size()`.
    fn rank(&self) -> usize;
    /// Number of processes.
    fn size(&self) -> usize;
    /// Every rank's `mine`, in rank order, on every rank.
    fn all_gather_bytes(&self, mine: &[u8]) -> Vec<Vec<u8>>;
    /// Every rank's `mine`, concatenated in rank order into `out` (cleared first; its capacity is
    /// kept, so a caller that reuses `out` for a series of exchanges allocates it once), on every
    /// rank; returns each rank's length. Same bytes as [`Comm::all_gather_bytes`], without one
    /// buffer per rank.
    fn all_gather_into(&self, mine: &[u8], out: &mut Vec<u8>) -> Vec<usize> {
        let all = self.all_gather_bytes(mine);
        out.clear();
        all.iter().for_each(|b| out.extend_from_slice(b));
        all.iter().map(Vec::len).collect()
    }
    /// Element-wise wrapping sum of `data` over all ranks, left on every rank.
    fn all_sum_u64(&self, data: &mut [u64]);
    /// Seconds spent in collective calls so far (communication and waiting for other ranks).
    fn comm_seconds(&self) -> f64 {
        0.0
    }
    /// Whether unit `i` of a workload belongs to this rank (`i mod size == rank`).
    fn owns(&self, i: u64) -> bool {
        i % self.size() as u64 == self.rank() as u64
    }
}

/// One process: every unit is its own and collectives are identities.
#[derive(Clone, Copy, Debug, Default)]
pub struct Solo;

impl Comm for Solo {
    fn rank(&self) -> usize {
        0
    }
    fn size(&self) -> usize {
        1
    }
    fn all_gather_bytes(&self, mine: &[u8]) -> Vec<Vec<u8>> {
        vec![mine.to_vec()]
    }
    fn all_sum_u64(&self, _data: &mut [u64]) {}
}

/// Little-endian writer of the plain values exchanged between ranks.
#[derive(Debug, Default)]
pub struct Packer(pub Vec<u8>);

impl Packer {
    /// Appends a `u64`.
    pub fn u64(&mut self, x: u64) {
        self.0.extend_from_slice(&x.to_le_bytes());
    }
    /// Appends an `f64` (its bits: exact).
    pub fn f64(&mut self, x: f64) {
        self.u64(x.to_bits());
    }
    /// Appends a byte.
    pub fn u8(&mut self, x: u8) {
        self.0.push(x);
    }
    /// Appends a string (length, then its UTF-8 bytes).
    pub fn str(&mut self, s: &str) {
        self.u64(s.len() as u64);
        self.0.extend_from_slice(s.as_bytes());
    }
    /// Appends `f32`s (their bits: exact).
    pub fn f32s(&mut self, xs: &[f32]) {
        for x in xs {
            self.0.extend_from_slice(&x.to_bits().to_le_bytes());
        }
    }
}

/// Reader matching [`Packer`]; panics on a short buffer (a broken peer: the job aborts).
#[derive(Debug)]
pub struct Unpacker<'a>(pub &'a [u8]);

impl Unpacker<'_> {
    /// Next `u64`.
    pub fn u64(&mut self) -> u64 {
        let (a, b) = self.0.split_at(8);
        self.0 = b;
        u64::from_le_bytes(a.try_into().expect("8 bytes"))
    }
    /// Next `f64`.
    pub fn f64(&mut self) -> f64 {
        f64::from_bits(self.u64())
    }
    /// Next `f32`.
    pub fn f32(&mut self) -> f32 {
        let (a, b) = self.0.split_at(4);
        self.0 = b;
        f32::from_bits(u32::from_le_bytes(a.try_into().expect("4 bytes")))
    }
    /// Next byte.
    pub fn u8(&mut self) -> u8 {
        let (a, b) = self.0.split_first().expect("1 byte");
        self.0 = b;
        *a
    }
    /// Next string.
    pub fn str(&mut self) -> String {
        let n = self.u64() as usize;
        let (a, b) = self.0.split_at(n);
        self.0 = b;
        String::from_utf8(a.to_vec()).expect("UTF-8")
    }
    /// Next three `f32`s (an RGB triple).
    pub fn rgb(&mut self) -> [f32; 3] {
        [self.f32(), self.f32(), self.f32()]
    }
    /// Whether everything was read.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

/// The results of units `0..n` on every rank, in unit order: this rank computes `f(i)` for the
/// units it owns (unit `i` belongs to rank `i mod size`; in parallel on this process's threads),
/// the results are all-gathered — `put` writes one unit's result exactly, `get` reads it back —
/// and every rank returns all `n`. With one rank nothing is packed: `f` runs on every unit.
/// For per-unit results that depend only on the unit (its own random stream), so the output is
/// the same bits for any number of ranks.
pub fn map_units<T: Send>(
    comm: &dyn Comm,
    n: usize,
    f: impl Fn(usize) -> T + Sync + Send,
    put: impl Fn(&T, &mut Packer),
    get: impl Fn(&mut Unpacker) -> T,
) -> Vec<T> {
    use rayon::prelude::*;
    let size = comm.size();
    if size == 1 {
        return (0..n).into_par_iter().map(f).collect();
    }
    let mine: Vec<usize> = (comm.rank()..n).step_by(size).collect();
    let vals: Vec<T> = mine.into_par_iter().map(&f).collect();
    let mut p = Packer::default();
    vals.iter().for_each(|v| put(v, &mut p));
    drop(vals);
    let all = comm.all_gather_bytes(&p.0);
    drop(p);
    let mut readers: Vec<Unpacker> = all.iter().map(|b| Unpacker(b)).collect();
    let out = (0..n).map(|i| get(&mut readers[i % size])).collect();
    assert!(readers.iter().all(|r| r.is_empty()), "a rank sent the units of another workload");
    out
}

/// Owner rank of each of `costs.len()` tasks (e.g. objects), balanced by their estimated cost:
/// the longest-processing-time rule (tasks by decreasing cost, ties by index, each to the rank
/// with the least load so far, ties to the lowest rank). The same on every rank.
pub fn assign_by_cost(costs: &[f64], size: usize) -> Vec<usize> {
    let mut order: Vec<usize> = (0..costs.len()).collect();
    order.sort_by(|&a, &b| costs[b].total_cmp(&costs[a]).then(a.cmp(&b)));
    let mut load = vec![0f64; size.max(1)];
    let mut owner = vec![0; costs.len()];
    for j in order {
        let r = (0..load.len()).min_by(|&a, &b| load[a].total_cmp(&load[b]).then(a.cmp(&b))).expect("a rank");
        owner[j] = r;
        load[r] += costs[j];
    }
    owner
}

/// Ranks simulated by threads of one process (for tests of split workloads, here and in the
/// crates built on this one): `ThreadComm::group(n)` gives one handle per rank; each must run on
/// its own thread.
#[derive(Clone, Debug)]
pub struct ThreadComm {
    rank: usize,
    shared: std::sync::Arc<(std::sync::Mutex<Vec<Vec<u8>>>, std::sync::Barrier)>,
}

impl ThreadComm {
    /// One handle per rank of a group of `n`.
    pub fn group(n: usize) -> Vec<ThreadComm> {
        let shared =
            std::sync::Arc::new((std::sync::Mutex::new(vec![Vec::new(); n]), std::sync::Barrier::new(n)));
        (0..n).map(|rank| ThreadComm { rank, shared: shared.clone() }).collect()
    }

    /// Runs `f` once per rank of a group of `n`, each on its own thread; the results in rank order.
    pub fn run<T: Send>(n: usize, f: impl Fn(&ThreadComm) -> T + Sync) -> Vec<T> {
        let group = ThreadComm::group(n);
        std::thread::scope(|sc| {
            let hs: Vec<_> = group.iter().map(|c| sc.spawn(|| f(c))).collect();
            hs.into_iter().map(|h| h.join().expect("rank thread")).collect()
        })
    }
}

impl Comm for ThreadComm {
    fn rank(&self) -> usize {
        self.rank
    }
    fn size(&self) -> usize {
        self.shared.0.lock().unwrap().len()
    }
    fn all_gather_bytes(&self, mine: &[u8]) -> Vec<Vec<u8>> {
        let (slots, barrier) = &*self.shared;
        slots.lock().unwrap()[self.rank] = mine.to_vec();
        barrier.wait();
        let all = slots.lock().unwrap().clone();
        barrier.wait();
        all
    }
    fn all_sum_u64(&self, data: &mut [u64]) {
        let mut p = Packer::default();
        data.iter().for_each(|&x| p.u64(x));
        let all = self.all_gather_bytes(&p.0);
        for (i, x) in data.iter_mut().enumerate() {
            *x = all
                .iter()
                .map(|b| u64::from_le_bytes(b[8 * i..8 * i + 8].try_into().unwrap()))
                .fold(0, u64::wrapping_add);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solo_owns_everything_and_gathers_itself() {
        let s = Solo;
        assert!((0..10).all(|i| s.owns(i)));
        assert_eq!(s.all_gather_bytes(&[1, 2, 3]), vec![vec![1, 2, 3]]);
        let mut v = [5u64, u64::MAX];
        s.all_sum_u64(&mut v);
        assert_eq!(v, [5, u64::MAX]);
    }

    #[test]
    fn thread_ranks_gather_in_rank_order_and_sum() {
        let out = ThreadComm::run(3, |c| {
            let g = c.all_gather_bytes(&[c.rank() as u8; 2]);
            let mut v = [c.rank() as u64, u64::MAX];
            c.all_sum_u64(&mut v);
            (g, v, (0..6).filter(|&i| c.owns(i)).collect::<Vec<_>>())
        });
        for (r, (g, v, owned)) in out.into_iter().enumerate() {
            assert_eq!(g, vec![vec![0, 0], vec![1, 1], vec![2, 2]]);
            assert_eq!(v, [3, u64::MAX - 2]);
            assert_eq!(owned, vec![r as u64, r as u64 + 3]);
        }
    }

    #[test]
    fn all_gather_into_concatenates_in_rank_order_and_reuses_the_buffer() {
        let out = ThreadComm::run(3, |c| {
            // lengths differ by rank; a second exchange into the same buffer replaces the first
            let mut buf = vec![9u8; 5];
            let first = c.all_gather_into(&vec![c.rank() as u8; c.rank() + 1], &mut buf);
            let first_bytes = buf.clone();
            let cap = buf.capacity();
            let second = c.all_gather_into(&[7 - c.rank() as u8], &mut buf);
            (first, first_bytes, second, buf, cap)
        });
        for (first, first_bytes, second, buf, cap) in out {
            assert_eq!(first, vec![1, 2, 3]);
            assert_eq!(first_bytes, vec![0, 1, 1, 2, 2, 2]);
            assert_eq!(second, vec![1, 1, 1]);
            assert_eq!(buf, vec![7, 6, 5]);
            assert!(buf.capacity() >= cap.min(6));
        }
        let mut buf = Vec::new();
        assert_eq!(Solo.all_gather_into(&[4, 5], &mut buf), vec![2]);
        assert_eq!(buf, vec![4, 5]);
    }

    #[test]
    fn map_units_gives_every_rank_all_units_in_order() {
        let f = |i: usize| (i * i) as u64;
        let want: Vec<u64> = (0..11).map(f).collect();
        assert_eq!(map_units(&Solo, 11, f, |v, p| p.u64(*v), |u| u.u64()), want);
        for n in [1, 2, 3] {
            let out = ThreadComm::run(n, |c| {
                // each rank computes only its own units
                let calls = std::sync::atomic::AtomicUsize::new(0);
                let v = map_units(
                    c,
                    11,
                    |i| {
                        calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        f(i)
                    },
                    |v, p| p.u64(*v),
                    |u| u.u64(),
                );
                (v, calls.into_inner())
            });
            for (r, (v, calls)) in out.into_iter().enumerate() {
                assert_eq!(v, want);
                assert_eq!(calls, (r..11).step_by(n).count());
            }
        }
    }

    #[test]
    fn assign_by_cost_balances_and_is_deterministic() {
        // 5 + 2 + 1 = 8 = 4 + 4 (longest first: 5→0, 4→1, 4→1, 2→0, 1→0)
        let costs = [4.0, 5.0, 1.0, 4.0, 2.0];
        assert_eq!(assign_by_cost(&costs, 2), vec![1, 0, 0, 1, 0]);
        assert_eq!(assign_by_cost(&costs, 1), vec![0; 5]);
        // more ranks than tasks: one task each, the rest idle
        assert_eq!(assign_by_cost(&[1.0, 1.0], 3), vec![0, 1]);
    }

    #[test]
    fn packer_round_trips_bits() {
        let mut p = Packer::default();
        p.u64(7);
        p.f64(-0.0);
        p.f32s(&[f32::NAN, 1.5]);
        let mut u = Unpacker(&p.0);
        assert_eq!(u.u64(), 7);
        assert_eq!(u.f64().to_bits(), (-0.0f64).to_bits());
        assert!(u.f32().is_nan());
        assert_eq!(u.f32(), 1.5);
        assert!(u.is_empty());
    }
}
