//! Piecewise-constant discrete / 1D distribution (cdf inversion), used for light selection
//! proportional to power and triangle selection proportional to area.

/// Discrete distribution over `n` items with weights `w_i ≥ 0`.
#[derive(Clone, Debug)]
pub struct Distribution1D {
    cdf: Vec<f64>,
    total: f64,
    /// `cdf[1..]` padded with +∞ to [`SMALL`] entries when there are at most [`SMALL`] items
    /// (lights): the count of entries `≤ u` is then a fixed-length, branch-free loop.
    small: Option<Box<[f64; SMALL]>>,
    /// Per item `i`: the first item `j ≥ i` with a non-zero probability (the last item if none):
    /// where a search that lands on `i` ends after skipping zero-probability items.
    skip: Vec<u32>,
}

/// Items counted by the fixed-length loop of [`Distribution1D::sample_index`].
const SMALL: usize = 16;

impl Distribution1D {
    /// Build from non-negative weights; `None` if the weights are empty, negative, non-finite or
    /// sum to zero.
    pub fn new(weights: &[f64]) -> Option<Self> {
        if weights.is_empty() || weights.iter().any(|w| !(w.is_finite() && *w >= 0.0)) {
            return None;
        }
        let mut cdf = Vec::with_capacity(weights.len() + 1);
        cdf.push(0.0);
        let mut acc = 0.0;
        for w in weights {
            acc += w;
            cdf.push(acc);
        }
        if acc <= 0.0 {
            return None;
        }
        for c in &mut cdf {
            *c /= acc;
        }
        let n = weights.len();
        let small = (n <= SMALL)
            .then(|| Box::new(std::array::from_fn(|k| if k < n { cdf[k + 1] } else { f64::INFINITY })));
        let mut skip = vec![0u32; n];
        let mut next = n - 1;
        for i in (0..n).rev() {
            if cdf[i + 1] - cdf[i] != 0.0 {
                next = i;
            }
            skip[i] = next as u32;
        }
        Some(Distribution1D { cdf, total: acc, small, skip })
    }
    /// Number of items.
    pub fn len(&self) -> usize {
        self.cdf.len() - 1
    }
    /// Always false (construction refuses empty input).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Sum of the weights.
    pub fn total(&self) -> f64 {
        self.total
    }
    /// Probability of item `i`.
    #[inline]
    pub fn pmf(&self, i: usize) -> f64 {
        self.cdf[i + 1] - self.cdf[i]
    }
    /// Sample an item with `u ∈ [0,1)`; returns (index, pmf, u re-scaled to [0,1) within the item).
    #[inline]
    pub fn sample(&self, u: f32) -> (usize, f64, f32) {
        let (i, p) = self.sample_index(u);
        let u = u as f64;
        let du = if p > 0.0 { ((u - self.cdf[i]) / p).clamp(0.0, 1.0 - 1e-7) } else { 0.0 };
        (i, p, du as f32)
    }

    /// The index and pmf of [`Distribution1D::sample`], without the re-scaled number.
    #[inline(always)]
    pub fn sample_index(&self, u: f32) -> (usize, f64) {
        let u = u as f64;
        // first index with cdf[i+1] > u; a few items (lights) are counted without branches over
        // a fixed length (the same count as the binary search's: the cdf is non-decreasing and
        // cdf[0] = 0 ≤ u unless u is NaN, where both counts are 0)
        let i = if let Some(small) = &self.small {
            small.iter().map(|&c| (c <= u) as usize).sum()
        } else {
            self.cdf.partition_point(|&c| c <= u).saturating_sub(1)
        };
        let i = i.min(self.len() - 1);
        // skip zero-probability items that the search may land on at their boundary
        let i = self.skip[i] as usize;
        (i, self.pmf(i))
    }
}

/// [`Distribution1D::sample_index`] of a distribution over at most [`SMALL`] items as one
/// inline table (no pointer to follow, no search, no subtraction): the count of cdf entries
/// `≤ u` picks the item and its probability (as `f32`) directly. The same results, bit for bit.
#[derive(Clone, Debug)]
pub struct SmallChoice {
    /// `cdf[1..]` padded with +∞.
    cdf: [f64; SMALL],
    /// Per count of entries `≤ u`: the item [`Distribution1D::sample_index`] returns.
    item: [u32; SMALL + 1],
    /// Per count: that item's probability, rounded to `f32`.
    pmf: [f32; SMALL + 1],
}

impl SmallChoice {
    /// The item and its probability (`f32`) for `u`: [`Distribution1D::sample_index`] with the
    /// probability rounded.
    #[inline(always)]
    pub fn choose(&self, u: f32) -> (usize, f32) {
        let u = u as f64;
        let c: usize = self.cdf.iter().map(|&c| (c <= u) as usize).sum();
        let c = c.min(SMALL);
        (self.item[c] as usize, self.pmf[c])
    }
}

impl Distribution1D {
    /// The [`SmallChoice`] table of a distribution over at most [`SMALL`] (16) items.
    pub fn small_choice(&self) -> Option<SmallChoice> {
        let small = self.small.as_ref()?;
        let n = self.len();
        let item: [u32; SMALL + 1] = std::array::from_fn(|c| self.skip[c.min(n - 1)]);
        let pmf = item.map(|i| self.pmf(i as usize) as f32);
        Some(SmallChoice { cdf: **small, item, pmf })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Rng;

    #[test]
    fn short_and_long_searches_pick_the_same_items() {
        // the branch-free count for up to 16 items and the binary search beyond: both give the
        // first item whose cdf exceeds u, boundaries and zero weights included
        let mut rng = Rng::new(2, 0, 0);
        for n in [1usize, 2, 3, 7, 16, 17, 40] {
            let w: Vec<f64> = (0..n).map(|k| if k % 5 == 2 { 0.0 } else { 1.0 + (k % 3) as f64 }).collect();
            let Some(d) = Distribution1D::new(&w) else { continue };
            let mut us: Vec<f32> = d.cdf.iter().map(|&c| c as f32).collect();
            us.extend((0..2000).map(|_| rng.next_f32()));
            for u in us.into_iter().filter(|u| *u < 1.0) {
                let (i, _, _) = d.sample(u);
                let j = d.cdf.partition_point(|&c| c <= u as f64).saturating_sub(1).min(d.len() - 1);
                let mut j = j;
                while d.pmf(j) == 0.0 && j + 1 < d.len() {
                    j += 1;
                }
                assert_eq!(i, j, "n {n}, u {u}");
            }
        }
    }

    /// The inline table picks the items and probabilities of `sample_index` (rounded to f32),
    /// at the cdf's boundaries, at random, with zero weights, up to 16 items; none beyond.
    #[test]
    fn small_choice_is_sample_index() {
        let mut rng = Rng::new(4, 0, 0);
        for n in [1usize, 2, 3, 5, 16] {
            for zeros in [false, true] {
                let w: Vec<f64> = (0..n)
                    .map(|k| if zeros && k % 3 == 1 { 0.0 } else { 0.5 + (k * 7 % 5) as f64 })
                    .collect();
                let d = Distribution1D::new(&w).unwrap();
                let t = d.small_choice().expect("at most 16 items");
                let mut us: Vec<f32> = d.cdf.iter().map(|&c| c as f32).collect();
                us.extend(d.cdf.iter().map(|&c| f32::from_bits((c as f32).to_bits().saturating_sub(1))));
                us.extend((0..5000).map(|_| rng.next_f32()));
                us.extend([0.0, -0.0, 1.0, f32::NAN, f32::INFINITY, -1.0]);
                for u in us {
                    let (i, p) = d.sample_index(u);
                    assert_eq!(t.choose(u), (i, p as f32), "n {n}, u {u}");
                }
            }
        }
        assert!(Distribution1D::new(&[1.0; 17]).unwrap().small_choice().is_none());
    }

    #[test]
    fn chi2_proportional_to_weights() {
        let w = [1.0, 0.0, 3.0, 0.5, 5.5];
        let d = Distribution1D::new(&w).unwrap();
        let n = 500_000;
        let mut counts = [0u64; 5];
        let mut rng = Rng::new(11, 0, 0);
        for _ in 0..n {
            let (i, p, du) = d.sample(rng.next_f32());
            assert!((0.0..1.0).contains(&du));
            assert!((p - w[i] / 10.0).abs() < 1e-12);
            counts[i] += 1;
        }
        assert_eq!(counts[1], 0);
        let chi2: f64 = [0, 2, 3, 4]
            .iter()
            .map(|&i| {
                let e = n as f64 * w[i] / 10.0;
                (counts[i] as f64 - e).powi(2) / e
            })
            .sum();
        // 3 dof, 0.999 quantile 16.27
        assert!(chi2 < 16.27, "chi2 {chi2} {counts:?}");
        assert!(Distribution1D::new(&[0.0, 0.0]).is_none());
        assert!(Distribution1D::new(&[1.0, -1.0]).is_none());
    }
}
