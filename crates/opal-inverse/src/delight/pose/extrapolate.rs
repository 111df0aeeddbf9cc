//! First-order extrapolation of a luminance map into the bands next to geometric edges that no
//! view's pure pixels observe ([`extrapolate_linear`]). Near a concave edge (a room's corners,
//! an object's contact with the floor) the luminance changes fastest; the zero-order fill of
//! the inpainting flattens it there, so the predicted edge has the wrong profile and pulls the
//! alignment sideways. Each band texel within `max_d` steps of an observed texel gets the value
//! of the least-squares plane `a + b·x + c·y` through the observed texels of its chart within a
//! window `d + 3` texels wide (`d` = its distance), when that window holds at least 8 of them
//! spread over both axes; otherwise it keeps its value. It returns which texels it filled: the
//! pose refinement's fine rounds predict only from the observed texels and those
//! ([`super::PoseSettings::linear_domain`]), not from the inpainting's flat extension further out.
//!
//! Tests: below (a linear ramp cut by a band is restored exactly and reported filled; a texel
//! without enough support keeps its value and is not reported).

use rayon::prelude::*;

/// See the module documentation. `dist[i]`: 4-neighbour steps from the nearest observed texel of
/// the chart (`usize::MAX`: unreachable); `chart[i]`: the texel's chart. Returns per texel
/// whether it got the plane's value.
pub(super) fn extrapolate_linear(
    l: &mut [f32],
    obs: &[bool],
    dist: &[usize],
    chart: &[u32],
    w: usize,
    h: usize,
    max_d: usize,
) -> Vec<bool> {
    let src: &[f32] = l;
    let new: Vec<(usize, f32)> = (0..w * h)
        .into_par_iter()
        .filter(|&i| !obs[i] && dist[i] != usize::MAX && dist[i] <= max_d)
        .filter_map(|i| {
            let r = (dist[i] + 3) as i64;
            let (x0, y0) = ((i % w) as i64, (i / w) as i64);
            // sums of the normal equations of the plane (coordinates relative to the texel)
            let mut m = [[0.0f64; 3]; 3];
            let mut b = [0.0f64; 3];
            let mut n = 0usize;
            for y in (y0 - r).max(0)..=(y0 + r).min(h as i64 - 1) {
                for x in (x0 - r).max(0)..=(x0 + r).min(w as i64 - 1) {
                    let j = y as usize * w + x as usize;
                    if !obs[j] || chart[j] != chart[i] || !src[j].is_finite() {
                        continue;
                    }
                    let v = [1.0, (x - x0) as f64, (y - y0) as f64];
                    for a in 0..3 {
                        b[a] += v[a] * src[j] as f64;
                        for c in 0..3 {
                            m[a][c] += v[a] * v[c];
                        }
                    }
                    n += 1;
                }
            }
            if n < 8 {
                return None;
            }
            let mm = nalgebra::Matrix3::from_fn(|a, c| m[a][c]);
            // both axes must be spread (not a single row or column of samples)
            let nf = n as f64;
            let (vx, vy) = (m[1][1] / nf - (m[0][1] / nf).powi(2), m[2][2] / nf - (m[0][2] / nf).powi(2));
            if vx < 0.5 || vy < 0.5 {
                return None;
            }
            let sol = mm.cholesky()?.solve(&nalgebra::Vector3::new(b[0], b[1], b[2]));
            sol[0].is_finite().then_some((i, sol[0] as f32))
        })
        .collect();
    let mut filled = vec![false; w * h];
    for (i, v) in new {
        l[i] = v;
        filled[i] = true;
    }
    filled
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ramp_cut_by_a_band_is_restored() {
        let (w, h) = (24usize, 20usize);
        let f = |x: usize, y: usize| 0.3 + 0.02 * x as f32 - 0.01 * y as f32;
        let obs: Vec<bool> = (0..w * h).map(|i| i % w < 16).collect();
        let dist: Vec<usize> = (0..w * h).map(|i| (i % w).saturating_sub(15)).collect();
        let mut l: Vec<f32> = (0..w * h).map(|i| if obs[i] { f(i % w, i / w) } else { 0.3 }).collect();
        let filled = extrapolate_linear(&mut l, &obs, &dist, &vec![0; w * h], w, h, 6);
        for i in 0..w * h {
            let (x, y) = (i % w, i / w);
            if x < 22 {
                assert!((l[i] - f(x, y)).abs() < 1e-4, "({x}, {y}): {} vs {}", l[i], f(x, y));
                // observed texels are not "filled"; the band within max_d is
                assert_eq!(filled[i], x >= 16, "({x}, {y})");
            } else {
                // beyond max_d: untouched, not filled
                assert_eq!(l[i], 0.3);
                assert!(!filled[i]);
            }
        }
    }

    #[test]
    fn too_little_support_keeps_the_value() {
        let (w, h) = (10usize, 1usize);
        let obs: Vec<bool> = (0..w).map(|i| i < 5).collect();
        let dist: Vec<usize> = (0..w).map(|i| i.saturating_sub(4)).collect();
        let mut l: Vec<f32> = (0..w).map(|i| if i < 5 { i as f32 } else { -1.0 }).collect();
        let filled = extrapolate_linear(&mut l, &obs, &dist, &[0; 10], w, h, 6);
        // one row: the plane is not determined along y
        assert!(l[5..].iter().all(|&v| v == -1.0));
        assert!(filled.iter().all(|&f| !f));
    }
}
