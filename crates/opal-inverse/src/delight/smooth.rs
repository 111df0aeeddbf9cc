//! In-chart smoothing of per-texel maps: the box filter within charts ([`smooth_in_charts`]),
//! its normalised variant over a mask ([`smooth_in_charts_masked`]) and the mask of the texels
//! light reaches ([`reached_texels`]). The light-traced indirect irradiance is smoothed over the
//! reached texels only, so enclosed texels (under a box standing on the object) do not darken
//! the contact edges. Tests: `masked_smoothing_ignores_enclosed_texels` here.

use super::atlas::Atlas;
use rayon::prelude::*;

/// Calls `f(j)` for the texels `j` of texel `i`'s chart (`chart[j] == chart[i]`) within `r`
/// texels of `i` along one axis of the `w × h` atlas, in increasing order: the window of the
/// separable in-chart box filters.
#[inline]
fn chart_window(
    i: usize,
    r: usize,
    horizontal: bool,
    (w, h): (usize, usize),
    chart: &[u32],
    mut f: impl FnMut(usize),
) {
    let (x, y) = ((i % w) as i64, (i / w) as i64);
    for d in -(r as i64)..=(r as i64) {
        let (xx, yy) = if horizontal { (x + d, y) } else { (x, y + d) };
        if xx < 0 || yy < 0 || xx >= w as i64 || yy >= h as i64 {
            continue;
        }
        let j = yy as usize * w + xx as usize;
        if chart[j] == chart[i] {
            f(j);
        }
    }
}

/// Box filter of radius `r` texels within charts (separable, normalised over covered texels of
/// the same chart).
pub fn smooth_in_charts(v: &[[f32; 3]], a: &Atlas, r: usize) -> Vec<[f32; 3]> {
    if r == 0 {
        return v.to_vec();
    }
    let (w, h) = (a.width, a.height);
    let chart: Vec<u32> = (0..w * h).map(|i| a.texel_chart(i)).collect();
    let pass = |src: &[[f32; 3]], horizontal: bool| -> Vec<[f32; 3]> {
        (0..w * h)
            .into_par_iter()
            .map(|i| {
                if chart[i] == u32::MAX {
                    return src[i];
                }
                let mut acc = [0f64; 3];
                let mut k = 0f64;
                chart_window(i, r, horizontal, (w, h), &chart, |j| {
                    for c in 0..3 {
                        acc[c] += src[j][c] as f64;
                    }
                    k += 1.0;
                });
                acc.map(|x| (x / k) as f32)
            })
            .collect()
    };
    let t = pass(v, true);
    pass(&t, false)
}

/// Box filter of radius `r` texels within charts over the texels of `mask` only (normalised
/// convolution: per masked texel the mean of the masked texels of its chart in the `(2r+1)²`
/// window); texels outside the mask (and texels of no chart) keep their own value.
///
/// Used for the light-traced indirect irradiance with `mask` = the texels light can reach
/// ([`reached_texels`]): the floor under a box standing on it receives nothing, and a plain box
/// filter would average those zeros into the texels along the contact edge — their irradiance
/// too low, their albedo too bright in an `r`-texel band (+20 % next to the edge, measured on
/// the room data set of `tests/delight_room.rs`).
pub fn smooth_in_charts_masked(v: &[[f32; 3]], a: &Atlas, r: usize, mask: &[bool]) -> Vec<[f32; 3]> {
    let (w, h) = (a.width, a.height);
    let chart: Vec<u32> = (0..w * h).map(|i| a.texel_chart(i)).collect();
    // per texel: (sum of the masked values, number of masked texels) along one axis
    let pass = |src: &[([f64; 3], f64)], horizontal: bool| -> Vec<([f64; 3], f64)> {
        (0..w * h)
            .into_par_iter()
            .map(|i| {
                let mut acc = ([0f64; 3], 0f64);
                if chart[i] == u32::MAX {
                    return acc;
                }
                chart_window(i, r, horizontal, (w, h), &chart, |j| {
                    for c in 0..3 {
                        acc.0[c] += src[j].0[c];
                    }
                    acc.1 += src[j].1;
                });
                acc
            })
            .collect()
    };
    let init: Vec<([f64; 3], f64)> =
        (0..w * h).map(|i| if mask[i] { (v[i].map(|x| x as f64), 1.0) } else { ([0.0; 3], 0.0) }).collect();
    let t = pass(&init, true);
    let s = pass(&t, false);
    (0..w * h)
        .map(|i| {
            if mask[i] && chart[i] != u32::MAX && s[i].1 > 0.0 {
                s[i].0.map(|x| (x / s[i].1) as f32)
            } else {
                v[i]
            }
        })
        .collect()
}

/// Texels light reaches, for [`smooth_in_charts_masked`]: observed by a view (a camera sees
/// them from the open scene), or with direct irradiance, or with indirect irradiance (a
/// light-tracing deposit). The others are enclosed (under a box standing on the object) or so
/// dim that no deposit reached them.
pub fn reached_texels(observed: &[bool], ed: &[[f32; 3]], ei: &[[f32; 3]]) -> Vec<bool> {
    observed.iter().zip(ed).zip(ei).map(|((&o, d), i)| o || d.iter().chain(i).any(|&x| x > 0.0)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::delight::atlas::build_atlas;
    use opal::scene::load::rectangle_mesh;

    /// A 32² map of constant irradiance 1 with an enclosed 8×8 block of zeros (the floor under a
    /// box): the plain filter darkens the texels next to the block, the masked one over the
    /// reached texels keeps them exact and leaves the enclosed texels at zero.
    #[test]
    fn masked_smoothing_ignores_enclosed_texels() {
        let a = build_atlas(&rectangle_mesh(), 32, true).unwrap();
        let n = a.width * a.height;
        let inside = |i: usize| (12..20).contains(&(i % 32)) && (12..20).contains(&(i / 32));
        let v: Vec<[f32; 3]> = (0..n).map(|i| if inside(i) { [0.0; 3] } else { [1.0, 2.0, 3.0] }).collect();
        let observed: Vec<bool> = (0..n).map(|i| !inside(i) && i % 7 != 0).collect();
        let ed = vec![[0f32; 3]; n];
        let reach = reached_texels(&observed, &ed, &v);
        // unobserved texels with a deposit count as reached, the enclosed block does not
        assert!((0..n).all(|i| reach[i] != inside(i)));
        let plain = smooth_in_charts(&v, &a, 4);
        let masked = smooth_in_charts_masked(&v, &a, 4, &reach);
        let next_to_block = 11 + 16 * 32; // one texel left of the block
        assert!(plain[next_to_block][0] < 0.8, "{:?}", plain[next_to_block]);
        for i in 0..n {
            let want = if inside(i) { [0.0; 3] } else { [1.0, 2.0, 3.0] };
            for c in 0..3 {
                assert!((masked[i][c] - want[c]).abs() < 1e-5, "texel {i}: {:?}", masked[i]);
            }
        }
        // with every texel reached: the mean over the (2r+1)² window clipped to the map
        let all = vec![true; n];
        let ramp: Vec<[f32; 3]> = (0..n).map(|i| [(i % 32) as f32; 3]).collect();
        let m = smooth_in_charts_masked(&ramp, &a, 2, &all);
        assert!((m[10 + 5 * 32][0] - 10.0).abs() < 1e-5);
        assert!((m[5 * 32][0] - 1.0).abs() < 1e-5); // columns 0, 1, 2
        assert_eq!(smooth_in_charts_masked(&ramp, &a, 0, &all), ramp);
    }
}
