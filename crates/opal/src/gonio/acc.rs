//! The goniophotometer's accumulators: per batch of photons, the detector sums (Σw, Σw²,
//! Σw/|cos θ|, hits) and the totals (R, T, lost, absorbed, interactions, bad photons); batches
//! are merged in batch order, so the sums do not depend on the thread count, and under MPI each
//! rank's batch accumulators are exchanged as bytes and merged in the same order (same bits;
//! tested by `gonio::tests` and the MPI tier).

/// Buffers of the exchanges between processes, kept for a whole run: the accumulators of a
/// group are ≈ 8 MB per process, and fresh buffers for every group cost page faults and copies
/// each time.
#[derive(Default)]
pub(super) struct Exchange {
    /// This process's packed batch accumulators.
    send: crate::dist::Packer,
    /// Every process's, concatenated in rank order.
    recv: Vec<u8>,
}

impl Exchange {
    /// Sends this process's accumulators `mine` (of the batches of `range` it owns, in batch
    /// order) to every rank of `c` and merges every batch of `range` into `total` in batch order,
    /// straight from the received bytes (the additions of [`Acc::merge`], in the same order).
    pub(super) fn merge(
        &mut self,
        c: &dyn crate::dist::Comm,
        range: std::ops::Range<u64>,
        mine: &[Acc],
        total: &mut Acc,
    ) {
        self.send.0.clear();
        for a in mine {
            a.pack(&mut self.send);
        }
        let lens = c.all_gather_into(&self.send.0, &mut self.recv);
        let mut rest = &self.recv[..];
        let mut readers: Vec<crate::dist::Unpacker> = lens
            .iter()
            .map(|&l| {
                let (a, b) = rest.split_at(l);
                rest = b;
                crate::dist::Unpacker(a)
            })
            .collect();
        let size = c.size() as u64;
        for b in range {
            total.merge_packed(&mut readers[(b % size) as usize]);
        }
        assert!(readers.iter().all(|r| r.is_empty()), "a rank sent batches of another run");
    }
}

#[derive(Clone)]
/// The sums of one batch of photons (or of a whole incidence).
pub(super) struct Acc {
    pub(super) sum: Vec<f64>,
    pub(super) sum2: Vec<f64>,
    pub(super) sum_bsdf: Vec<f64>,
    pub(super) hits: Vec<u64>,
    pub(super) r: f64,
    pub(super) t: f64,
    pub(super) lost: f64,
    pub(super) absorbed: f64,
    pub(super) interactions: u64,
    pub(super) bad: u64,
}

impl Acc {
    pub(super) fn new(n: usize) -> Self {
        Acc {
            sum: vec![0.0; n],
            sum2: vec![0.0; n],
            sum_bsdf: vec![0.0; n],
            hits: vec![0; n],
            r: 0.0,
            t: 0.0,
            lost: 0.0,
            absorbed: 0.0,
            interactions: 0,
            bad: 0,
        }
    }
    fn pack(&self, p: &mut crate::dist::Packer) {
        for i in 0..self.sum.len() {
            p.f64(self.sum[i]);
            p.f64(self.sum2[i]);
            p.f64(self.sum_bsdf[i]);
            p.u64(self.hits[i]);
        }
        for x in [self.r, self.t, self.lost, self.absorbed] {
            p.f64(x);
        }
        p.u64(self.interactions);
        p.u64(self.bad);
    }
    /// [`Acc::merge`] of the accumulator [`Acc::pack`] wrote (the same additions in the same
    /// order, so the same bits), read straight from the bytes.
    fn merge_packed(&mut self, u: &mut crate::dist::Unpacker) {
        let n = self.sum.len();
        let (block, rest) = u.0.split_at(32 * n);
        for (i, d) in block.chunks_exact(32).enumerate() {
            let x = |k: usize| u64::from_le_bytes(d[8 * k..8 * k + 8].try_into().expect("8 bytes"));
            self.sum[i] += f64::from_bits(x(0));
            self.sum2[i] += f64::from_bits(x(1));
            self.sum_bsdf[i] += f64::from_bits(x(2));
            self.hits[i] += x(3);
        }
        u.0 = rest;
        self.r += u.f64();
        self.t += u.f64();
        self.lost += u.f64();
        self.absorbed += u.f64();
        self.interactions += u.u64();
        self.bad += u.u64();
    }
    pub(super) fn merge(&mut self, o: &Acc) {
        for i in 0..self.sum.len() {
            self.sum[i] += o.sum[i];
            self.sum2[i] += o.sum2[i];
            self.sum_bsdf[i] += o.sum_bsdf[i];
            self.hits[i] += o.hits[i];
        }
        self.r += o.r;
        self.t += o.t;
        self.lost += o.lost;
        self.absorbed += o.absorbed;
        self.interactions += o.interactions;
        self.bad += o.bad;
    }
}
