//! The deposit queue of a worker ([`Sink`]): a deposit's texel is prefetched when it is
//! pushed and added [`QUEUE`] deposits later, so the cache and TLB misses of the adds overlap
//! the tracing. Integer sums: the order of the additions does not change the result.
//!
//! Tests (`tests.rs`): every pass goes through the queue; the engines, thread counts and batch
//! sizes give identical sums.

use super::fixed_point::{Acc, Cells, ShapeAcc};

/// Deposits in flight per worker: the queue length of [`Sink`]. Measured on the Cornell box
/// (733 k texels, 8.8 MB of cells per worker, loaded machine, user CPU-s of interleaved runs):
/// 64 with the second line's prefetch took 0.94–0.99 of 32, 128 0.98–0.99 of 64, 256 no less
/// than 128 (performance.md, "light-tracing pass").
pub(super) const QUEUE: usize = 128;

/// A worker's accumulator behind a queue of [`QUEUE`] deposits: a deposit's texel (both cache
/// lines, when its 12 bytes straddle two) is prefetched when it is pushed and the addition
/// happens when it leaves the queue, [`QUEUE`] deposits later, so the memory latency overlaps
/// the tracing instead of stalling it (with 32 the adds still waited for their lines when
/// other jobs shared the caches).
///
/// The maps are kept flat by map number `2·shape + direct` (empty where a shape has none), plus
/// one texel of scratch at the end that the queue's initial entries (zero units) point to, so
/// the queue is always full and a push always takes one deposit out. A queued deposit is 20
/// bytes (`i32` units: a deposit beyond `i32`, in practice never, is added at once), so a
/// deposit costs few instructions besides its cache miss.
pub(super) struct Sink {
    /// Per map `2·shape + direct`, then the scratch map.
    maps: Vec<Cells>,
    /// Per shape: the map size (`None`: no target) and the exact sum of |units| deposited.
    shapes: Vec<Option<(usize, usize)>>,
    totals: Vec<u128>,
    ring: [Queued; QUEUE],
    /// Oldest queued deposit.
    head: usize,
}

/// A queued deposit: map number, index of the texel's red channel, units.
#[derive(Clone, Copy, Default)]
struct Queued {
    map: u32,
    index: u32,
    value: [i32; 3],
}

impl Sink {
    pub(super) fn new(acc: Acc) -> Sink {
        let mut maps = Vec::with_capacity(2 * acc.len() + 1);
        let mut shapes = Vec::with_capacity(acc.len());
        for m in acc {
            match m {
                Some(m) => {
                    maps.push(m.indirect);
                    maps.push(m.direct);
                    shapes.push(Some((m.width, m.height)));
                }
                None => {
                    maps.push(Cells::new(0));
                    maps.push(Cells::new(0));
                    shapes.push(None);
                }
            }
        }
        // the scratch texel of the queue's initial (zero) entries
        let scratch = Queued { map: maps.len() as u32, index: 0, value: [0; 3] };
        maps.push(Cells::new(3));
        let totals = vec![0; shapes.len()];
        Sink { maps, shapes, totals, ring: [scratch; QUEUE], head: 0 }
    }

    /// Queues a deposit ([`Sink::push_small`]), or adds it at once when its units or index do
    /// not fit the queue.
    #[inline]
    pub(super) fn push(&mut self, p: Pending) {
        let value = p.value.map(|v| v as i32);
        let map = 2 * p.shape + p.direct as usize;
        if value.iter().zip(&p.value).all(|(&a, &b)| a as i64 == b) && p.index <= u32::MAX as usize {
            let units = value.iter().map(|v| v.unsigned_abs() as u64).sum();
            self.push_small(map as u32, p.index as u32, value, units);
        } else {
            self.totals[p.shape] += p.value.iter().map(|v| v.unsigned_abs() as u128).sum::<u128>();
            self.maps[map].add(p.index, p.value);
        }
    }

    /// Queues a deposit whose units fit in `i32` (channel index `index` of map `map`, i.e.
    /// `2·shape + direct`; `units` = the sum of the magnitudes of `value`): counts it in the
    /// shape's total, prefetches its texel and adds the deposit that leaves the queue.
    #[inline(always)]
    pub(super) fn push_small(&mut self, map: u32, index: u32, value: [i32; 3], units: u64) {
        self.totals[map as usize / 2] += units as u128;
        let fine = &self.maps[map as usize].fine;
        let p = fine.as_ptr().wrapping_add(index as usize);
        // (a texel's 12 bytes may straddle two cache lines; prefetches never fault)
        crate::simd::prefetch_ptr(p);
        crate::simd::prefetch_ptr(p.wrapping_add(2));
        let old = std::mem::replace(&mut self.ring[self.head], Queued { map, index, value });
        self.head = (self.head + 1) % QUEUE;
        self.maps[old.map as usize].add32(old.index as usize, old.value);
    }

    /// Applies the queued deposits and returns the accumulator.
    pub(super) fn finish(mut self) -> Acc {
        for q in self.ring {
            self.maps[q.map as usize].add32(q.index as usize, q.value);
        }
        self.maps.pop(); // the scratch map
        let mut maps = self.maps.into_iter();
        self.shapes
            .iter()
            .zip(self.totals)
            .map(|(size, total)| {
                let (indirect, direct) = (maps.next().expect("two maps"), maps.next().expect("per shape"));
                size.map(|(width, height)| ShapeAcc { width, height, direct, indirect, total })
            })
            .collect()
    }
}

/// A deposit: texel, map and integer value.
#[derive(Clone, Copy)]
pub(super) struct Pending {
    pub(super) shape: usize,
    /// Index of the texel's red channel in the flat map.
    pub(super) index: usize,
    pub(super) direct: bool,
    pub(super) value: [i64; 3],
}
