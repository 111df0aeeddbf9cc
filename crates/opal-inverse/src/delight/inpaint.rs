//! Hole filling of texture maps: fast-marching inpainting in the manner of Telea (2004, "An
//! image inpainting technique based on the fast marching method", J. Graphics Tools 9(1)),
//! a 3×3 median filter used before it near bright emitters, and gutter dilation.
//!
//! Inpainting: unknown texels are visited in order of their arrival time T of a front that
//! starts at the known region and moves at unit speed (T solved from the eikonal equation
//! |∇T| = 1 with the upwind 4-neighbour scheme); each is set to the weighted mean of the known
//! (or already filled) texels of the same chart within `radius`, with Telea's weights
//! w = dir · dst · lev (direction to the front normal, 1/distance², 1/(1 + |ΔT|)). The
//! first-order gradient term of Telea's method is left out (zero-order extrapolation). Only
//! texels with `domain[i]` are touched; charts never mix.
//!
//! Tests: below (a linear ramp with a hole is filled close to the ramp; charts do not mix;
//! median removes a single spike).

// Index loops over parallel per-texel arrays read more clearly than zipped iterators here.
#![allow(clippy::needless_range_loop)]

use std::cmp::Ordering;
use std::collections::BinaryHeap;

#[derive(PartialEq)]
struct Item(f32, usize);
impl Eq for Item {}
impl PartialOrd for Item {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Item {
    fn cmp(&self, o: &Self) -> Ordering {
        o.0.total_cmp(&self.0).then(o.1.cmp(&self.1))
    }
}

/// Fills `values[i]` for texels with `domain[i] && !known[i]` from known texels of the same
/// `chart[i]`. Returns how many texels could not be reached (no known texel in their chart).
pub fn inpaint(
    values: &mut [[f32; 3]],
    known: &[bool],
    domain: &[bool],
    chart: &[u32],
    width: usize,
    height: usize,
    radius: usize,
) -> usize {
    let n = width * height;
    let mut t = vec![f32::INFINITY; n];
    let mut state = vec![0u8; n]; // 0 far, 1 band, 2 done
    let mut heap = BinaryHeap::new();
    for i in 0..n {
        if domain[i] && known[i] {
            t[i] = 0.0;
            state[i] = 2;
        }
    }
    let nbrs = |i: usize| {
        let (x, y) = (i % width, i / width);
        let mut v = [usize::MAX; 4];
        if x > 0 {
            v[0] = i - 1;
        }
        if x + 1 < width {
            v[1] = i + 1;
        }
        if y > 0 {
            v[2] = i - width;
        }
        if y + 1 < height {
            v[3] = i + width;
        }
        v
    };
    // seed the band: unknown texels next to known ones
    for i in 0..n {
        if state[i] == 2 {
            for j in nbrs(i) {
                if j != usize::MAX && domain[j] && state[j] == 0 && chart[j] == chart[i] {
                    state[j] = 1;
                    t[j] = 1.0;
                    heap.push(Item(1.0, j));
                }
            }
        }
    }
    let r = radius.max(1) as i64;
    while let Some(Item(ti, i)) = heap.pop() {
        if state[i] == 2 || ti > t[i] {
            continue;
        }
        state[i] = 2;
        // fill i from done texels nearby
        let (x, y) = ((i % width) as i64, (i / width) as i64);
        // front normal ≈ −∇T (central differences over done neighbours)
        let tt = |xx: i64, yy: i64| -> Option<f32> {
            if xx < 0 || yy < 0 || xx >= width as i64 || yy >= height as i64 {
                return None;
            }
            let j = yy as usize * width + xx as usize;
            (state[j] == 2 && chart[j] == chart[i] && t[j].is_finite()).then_some(t[j])
        };
        let gx = match (tt(x + 1, y), tt(x - 1, y)) {
            (Some(a), Some(b)) => 0.5 * (a - b),
            (Some(a), None) => a - ti,
            (None, Some(b)) => ti - b,
            _ => 0.0,
        };
        let gy = match (tt(x, y + 1), tt(x, y - 1)) {
            (Some(a), Some(b)) => 0.5 * (a - b),
            (Some(a), None) => a - ti,
            (None, Some(b)) => ti - b,
            _ => 0.0,
        };
        let gl = (gx * gx + gy * gy).sqrt();
        let mut acc = [0f64; 3];
        let mut wsum = 0f64;
        for dy in -r..=r {
            for dx in -r..=r {
                let (xx, yy) = (x + dx, y + dy);
                if (dx == 0 && dy == 0) || xx < 0 || yy < 0 || xx >= width as i64 || yy >= height as i64 {
                    continue;
                }
                let d2 = (dx * dx + dy * dy) as f32;
                if d2 > (r * r) as f32 {
                    continue;
                }
                let j = yy as usize * width + xx as usize;
                if state[j] != 2 || !domain[j] || chart[j] != chart[i] || !t[j].is_finite() {
                    continue;
                }
                let d = d2.sqrt();
                // direction term: |(p − q)·∇T| / |p − q|, floored so isotropic fronts still fill
                let dir = if gl > 0.0 {
                    ((-(dx as f32) * gx - (dy as f32) * gy).abs() / (d * gl)).max(0.05)
                } else {
                    1.0
                };
                let dst = 1.0 / d2;
                let lev = 1.0 / (1.0 + (t[j] - ti).abs());
                let w = (dir * dst * lev) as f64;
                for c in 0..3 {
                    acc[c] += w * values[j][c] as f64;
                }
                wsum += w;
            }
        }
        if wsum > 0.0 {
            values[i] = acc.map(|a| (a / wsum) as f32);
        }
        // update neighbours' arrival times
        for j in nbrs(i) {
            if j == usize::MAX || !domain[j] || state[j] == 2 || chart[j] != chart[i] {
                continue;
            }
            let (xj, yj) = ((j % width) as i64, (j / width) as i64);
            let tj = |xx: i64, yy: i64| -> f32 {
                if xx < 0 || yy < 0 || xx >= width as i64 || yy >= height as i64 {
                    return f32::INFINITY;
                }
                let k = yy as usize * width + xx as usize;
                if state[k] == 2 && chart[k] == chart[j] { t[k] } else { f32::INFINITY }
            };
            let a = tj(xj - 1, yj).min(tj(xj + 1, yj));
            let b = tj(xj, yj - 1).min(tj(xj, yj + 1));
            let new = if a.is_finite() && b.is_finite() && (a - b).abs() < 1.0 {
                0.5 * (a + b + (2.0 - (a - b) * (a - b)).sqrt())
            } else {
                a.min(b) + 1.0
            };
            if new < t[j] {
                t[j] = new;
                state[j] = 1;
                heap.push(Item(new, j));
            }
        }
    }
    (0..n).filter(|&i| domain[i] && state[i] != 2).count()
}

/// 3×3 median (per channel) over known texels of the same chart; unknown texels unchanged.
pub fn median3(values: &mut [[f32; 3]], known: &[bool], chart: &[u32], width: usize, height: usize) {
    let src = values.to_vec();
    for y in 0..height {
        for x in 0..width {
            let i = y * width + x;
            if !known[i] {
                continue;
            }
            let mut buf: [Vec<f32>; 3] = Default::default();
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    let (xx, yy) = (x as i64 + dx, y as i64 + dy);
                    if xx < 0 || yy < 0 || xx >= width as i64 || yy >= height as i64 {
                        continue;
                    }
                    let j = yy as usize * width + xx as usize;
                    if known[j] && chart[j] == chart[i] {
                        for c in 0..3 {
                            buf[c].push(src[j][c]);
                        }
                    }
                }
            }
            for c in 0..3 {
                buf[c].sort_by(f32::total_cmp);
                values[i][c] = buf[c][buf[c].len() / 2];
            }
        }
    }
}

/// Fills gutter texels (`!filled`) so that bilinear look-ups at chart borders do not blend in
/// empty texels or other charts. First every texel with an owner chart (`owner[i] != u32::MAX`,
/// see `Atlas::texel_owner`) takes the mean of its already-filled 8-neighbours **of the same
/// owner**, ring by ring until no owned texel is left that such a neighbour reaches; then the
/// remaining texels take the mean of any filled 8-neighbours, `passes` rings outwards.
pub fn dilate(
    values: &mut [[f32; 3]],
    filled: &[bool],
    owner: &[u32],
    width: usize,
    height: usize,
    passes: usize,
) {
    let mut have = filled.to_vec();
    let ring = |values: &mut [[f32; 3]], have: &mut Vec<bool>, own: bool| {
        let prev = have.clone();
        let src = values.to_vec();
        let mut changed = false;
        for y in 0..height {
            for x in 0..width {
                let i = y * width + x;
                if prev[i] || (owner[i] != u32::MAX) != own {
                    continue;
                }
                let mut acc = [0f32; 3];
                let mut k = 0;
                for (dx, dy) in [(-1i64, 0i64), (1, 0), (0, -1), (0, 1), (-1, -1), (1, 1), (-1, 1), (1, -1)] {
                    let (xx, yy) = (x as i64 + dx, y as i64 + dy);
                    if xx < 0 || yy < 0 || xx >= width as i64 || yy >= height as i64 {
                        continue;
                    }
                    let j = yy as usize * width + xx as usize;
                    if prev[j] && (!own || owner[j] == owner[i]) {
                        for c in 0..3 {
                            acc[c] += src[j][c];
                        }
                        k += 1;
                    }
                }
                if k > 0 {
                    values[i] = acc.map(|a| a / k as f32);
                    have[i] = true;
                    changed = true;
                }
            }
        }
        changed
    };
    while ring(values, &mut have, true) {}
    for _ in 0..passes {
        ring(values, &mut have, false);
    }
}

/// The owned part of [`dilate`] as a linear map: for every texel the owned rings fill
/// (`!filled[i]`, `owner[i] != u32::MAX`, reached from a filled texel of its owner), the weights
/// of the filled texels whose values it takes, so `values[i] = Σ w · values[j]` reproduces
/// [`dilate`]'s owned rings exactly (same neighbours, same means, ring by ring). Filled texels map
/// to themselves; texels the owned rings do not reach map to nothing. Used by the
/// super-resolution to model the gutter texels the way the output albedo fills them.
pub fn dilate_weights(filled: &[bool], owner: &[u32], width: usize, height: usize) -> Vec<Vec<(u32, f32)>> {
    let n = width * height;
    let mut wts: Vec<Vec<(u32, f32)>> =
        (0..n).map(|i| if filled[i] { vec![(i as u32, 1.0)] } else { Vec::new() }).collect();
    let mut have = filled.to_vec();
    loop {
        let prev = have.clone();
        let mut new: Vec<(usize, Vec<(u32, f32)>)> = Vec::new();
        for y in 0..height {
            for x in 0..width {
                let i = y * width + x;
                if prev[i] || owner[i] == u32::MAX {
                    continue;
                }
                let mut src: Vec<usize> = Vec::new();
                for (dx, dy) in [(-1i64, 0i64), (1, 0), (0, -1), (0, 1), (-1, -1), (1, 1), (-1, 1), (1, -1)] {
                    let (xx, yy) = (x as i64 + dx, y as i64 + dy);
                    if xx < 0 || yy < 0 || xx >= width as i64 || yy >= height as i64 {
                        continue;
                    }
                    let j = yy as usize * width + xx as usize;
                    if prev[j] && owner[j] == owner[i] {
                        src.push(j);
                    }
                }
                if src.is_empty() {
                    continue;
                }
                let k = 1.0 / src.len() as f32;
                let mut acc: Vec<(u32, f32)> =
                    src.iter().flat_map(|&j| wts[j].iter().map(|&(c, w)| (c, w * k))).collect();
                acc.sort_unstable_by_key(|e| e.0);
                let mut merged: Vec<(u32, f32)> = Vec::with_capacity(acc.len());
                for (c, w) in acc {
                    match merged.last_mut() {
                        Some(l) if l.0 == c => l.1 += w,
                        _ => merged.push((c, w)),
                    }
                }
                new.push((i, merged));
            }
        }
        if new.is_empty() {
            return wts;
        }
        for (i, w) in new {
            wts[i] = w;
            have[i] = true;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ramp_hole_is_filled_close_to_the_ramp() {
        let (w, h) = (40, 30);
        let truth = |x: usize, y: usize| [x as f32 * 0.1, y as f32 * 0.05, 1.0];
        let mut v = vec![[0f32; 3]; w * h];
        let mut known = vec![true; w * h];
        for y in 0..h {
            for x in 0..w {
                v[y * w + x] = truth(x, y);
                if (15..25).contains(&x) && (10..20).contains(&y) {
                    known[y * w + x] = false;
                    v[y * w + x] = [9.0; 3];
                }
            }
        }
        let domain = vec![true; w * h];
        let chart = vec![0u32; w * h];
        assert_eq!(inpaint(&mut v, &known, &domain, &chart, w, h, 4), 0);
        for y in 10..20 {
            for x in 15..25 {
                let t = truth(x, y);
                let g = v[y * w + x];
                // zero-order extrapolation of a ramp of slope 0.1/texel over a 10-texel hole:
                // errors stay well below the ramp's range across the hole (1.0)
                assert!(
                    (g[0] - t[0]).abs() < 0.3 && (g[1] - t[1]).abs() < 0.2 && (g[2] - 1.0).abs() < 1e-5,
                    "{x},{y}: {g:?} vs {t:?}"
                );
            }
        }
    }

    #[test]
    fn charts_do_not_mix_and_unreachable_is_counted() {
        let (w, h) = (10, 1);
        let mut v = vec![[1.0f32; 3]; w];
        let chart: Vec<u32> = (0..w).map(|x| if x < 5 { 0 } else { 1 }).collect();
        let mut known = vec![true; w];
        for x in 5..w {
            known[x] = false;
            v[x] = [7.0; 3];
        }
        known[4] = false;
        let domain = vec![true; w];
        let left = inpaint(&mut v, &known, &domain, &chart, w, h, 3);
        assert_eq!(left, 5, "chart 1 has no known texel");
        assert_eq!(v[4], [1.0; 3]);
        assert_eq!(v[7], [7.0; 3]);
    }

    #[test]
    fn median_removes_a_spike_and_dilate_fills_gutter() {
        let (w, h) = (5, 5);
        let mut v = vec![[1.0f32; 3]; 25];
        v[12] = [100.0; 3];
        let known = vec![true; 25];
        median3(&mut v, &known, &[0; 25], w, h);
        assert_eq!(v[12], [1.0; 3]);
        let mut filled = vec![false; 25];
        filled[12] = true;
        v[12] = [3.0; 3];
        dilate(&mut v, &filled, &[u32::MAX; 25], w, h, 2);
        assert!(v.iter().all(|p| *p == [3.0; 3]));
    }

    #[test]
    fn dilate_fills_owned_gutter_from_its_own_chart_only() {
        // two charts on a 1-row strip: texels 0–1 chart 0 (value 1), 6–7 chart 1 (value 5);
        // gutter 2–3 owned by chart 0, 4–5 by chart 1
        let (w, h) = (8, 1);
        let mut v = vec![[0.0f32; 3]; w];
        let filled = [true, true, false, false, false, false, true, true];
        let owner = [0, 0, 0, 0, 1, 1, 1, 1];
        for i in 0..2 {
            v[i] = [1.0; 3];
            v[6 + i] = [5.0; 3];
        }
        dilate(&mut v, &filled, &owner, w, h, 4);
        assert_eq!(v.iter().map(|p| p[0]).collect::<Vec<_>>(), [1.0, 1.0, 1.0, 1.0, 5.0, 5.0, 5.0, 5.0]);
    }

    #[test]
    fn dilate_weights_reproduce_the_owned_rings() {
        // two charts in a 12×7 grid with owned gutters around them and unowned texels between
        let (w, h) = (12, 7);
        let mut filled = vec![false; w * h];
        let mut owner = vec![u32::MAX; w * h];
        let mut v = vec![[0.0f32; 3]; w * h];
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                if (2..4).contains(&x) && (2..5).contains(&y) {
                    filled[i] = true;
                    v[i] = [x as f32 + 0.3 * y as f32, (x * y) as f32, 1.0 + y as f32];
                }
                if (1..6).contains(&x) && (1..6).contains(&y) {
                    owner[i] = 0;
                }
                if (8..10).contains(&x) && (3..4).contains(&y) {
                    filled[i] = true;
                    v[i] = [5.0 + x as f32, 2.0, 0.5 * y as f32];
                }
                if (7..11).contains(&x) && (2..5).contains(&y) {
                    owner[i] = 1;
                }
            }
        }
        let wts = dilate_weights(&filled, &owner, w, h);
        let mut d = v.clone();
        dilate(&mut d, &filled, &owner, w, h, 0);
        for i in 0..w * h {
            if wts[i].is_empty() {
                assert!(!filled[i] && (owner[i] == u32::MAX || d[i] == [0.0; 3]), "{i}");
                continue;
            }
            let mut s = [0f32; 3];
            for &(j, wt) in &wts[i] {
                assert!(filled[j as usize] && owner[j as usize] == owner[i]);
                for c in 0..3 {
                    s[c] += wt * v[j as usize][c];
                }
            }
            for c in 0..3 {
                assert!((s[c] - d[i][c]).abs() < 1e-5, "{i}: {s:?} vs {:?}", d[i]);
            }
        }
        // every owned texel of both charts is reached
        assert!((0..w * h).all(|i| owner[i] == u32::MAX || !wts[i].is_empty()));
    }
}
