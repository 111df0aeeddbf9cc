//! Which fill of texels no view observed is least biased (issue 17): on textures given as EXR
//! files, holes of several shapes are cut at random (fixed seed) and filled by three rules; the
//! quantity that matters for the de-lighting is the mean albedo over the hole (it is what the
//! hole reflects onto the other objects), so the example reports per rule the relative error of
//! the hole's mean (mean |error| over the channels, holes and textures, and its RMS), and the
//! per-texel RMS error.
//!
//! Rules: `inpaint` — what `update_kd` does (Telea fast-marching from the known texels, radius
//! width/16 but ≥ 4); `object mean` — every hole texel takes the mean of all known texels;
//! `ring mean` — the mean of the known texels within width/16 (≥ 4) texels of the hole.
//! Holes per texture: disks of radius 0.08, 0.15, 0.25 × width at random centres and corner
//! rectangles of 0.25–0.45 × the sides (a region behind an object, against the walls).
//!
//! `cargo run --release -p opal-inverse --example fill_bias -- TEX.exr...`

use opal_inverse::delight::inpaint::inpaint;

fn main() {
    let files: Vec<String> = std::env::args().skip(1).collect();
    assert!(!files.is_empty(), "usage: fill_bias TEX.exr...");
    let names = ["inpaint", "object mean", "ring mean"];
    // per rule: Σ |rel. error of the hole mean|, Σ its square, Σ per-texel squared error, counts
    let mut abs = [0f64; 3];
    let mut sq = [0f64; 3];
    let mut px = [0f64; 3];
    let (mut n_means, mut n_px) = (0usize, 0usize);
    // per texture: which rule had the smallest mean |error|
    let mut wins = [0usize; 3];
    for (t, f) in files.iter().enumerate() {
        let img = opal::image::read::read_image(std::path::Path::new(f)).expect("readable EXR");
        let (w, h) = (img.width, img.height);
        let truth: Vec<[f32; 3]> = img.data.iter().map(|s| s.0).collect();
        let mut rng = opal::sampling::Rng::new(17, 5, t as u64);
        let mut tex_abs = [0f64; 3];
        for k in 0..8 {
            let hole: Vec<bool> = if k < 6 {
                let r = [0.08, 0.15, 0.25][k % 3] * w as f32;
                let (cx, cy) = (rng.next_f32() * w as f32, rng.next_f32() * h as f32);
                (0..w * h)
                    .map(|i| {
                        let (x, y) = ((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
                        (x - cx).powi(2) + (y - cy).powi(2) < r * r
                    })
                    .collect()
            } else {
                let (rw, rh) = (
                    ((0.25 + 0.2 * rng.next_f32()) * w as f32) as usize,
                    ((0.25 + 0.2 * rng.next_f32()) * h as f32) as usize,
                );
                let right = rng.next_f32() < 0.5;
                let bottom = rng.next_f32() < 0.5;
                (0..w * h)
                    .map(|i| {
                        let (x, y) = (i % w, i / w);
                        let inx = if right { x >= w - rw } else { x < rw };
                        let iny = if bottom { y >= h - rh } else { y < rh };
                        inx && iny
                    })
                    .collect()
            };
            let known: Vec<bool> = hole.iter().map(|&b| !b).collect();
            let nh = hole.iter().filter(|&&b| b).count();
            if nh < 16 {
                continue;
            }
            let radius = (w / 16).max(4);
            let mean_of = |v: &[[f32; 3]], m: &dyn Fn(usize) -> bool| -> [f64; 3] {
                let mut a = [0f64; 3];
                let mut c = 0usize;
                for i in (0..w * h).filter(|&i| m(i)) {
                    for ch in 0..3 {
                        a[ch] += v[i][ch] as f64;
                    }
                    c += 1;
                }
                a.map(|x| x / c.max(1) as f64)
            };
            // rule 1: inpaint (one chart, the whole image)
            let mut fill1 = truth.clone();
            for i in 0..w * h {
                if hole[i] {
                    fill1[i] = [0.0; 3];
                }
            }
            inpaint(&mut fill1, &known, &vec![true; w * h], &vec![0; w * h], w, h, radius);
            // rule 2: object mean
            let om = mean_of(&truth, &|i| known[i]).map(|x| x as f32);
            // rule 3: ring mean (known texels within `radius` of the hole, Chebyshev distance)
            let near: Vec<bool> = (0..w * h)
                .map(|i| {
                    if !known[i] {
                        return false;
                    }
                    let (x, y) = ((i % w) as i64, (i / w) as i64);
                    let r = radius as i64;
                    (-r..=r).any(|dy| {
                        (-r..=r).any(|dx| {
                            let (xx, yy) = (x + dx, y + dy);
                            xx >= 0
                                && yy >= 0
                                && xx < w as i64
                                && yy < h as i64
                                && hole[yy as usize * w + xx as usize]
                        })
                    })
                })
                .collect();
            let rm = mean_of(&truth, &|i| near[i]).map(|x| x as f32);
            let fills: [Vec<[f32; 3]>; 3] = [
                fill1,
                (0..w * h).map(|i| if hole[i] { om } else { truth[i] }).collect(),
                (0..w * h).map(|i| if hole[i] { rm } else { truth[i] }).collect(),
            ];
            let tm = mean_of(&truth, &|i| hole[i]);
            for (r, fv) in fills.iter().enumerate() {
                let fm = mean_of(fv, &|i| hole[i]);
                for c in 0..3 {
                    let e = (fm[c] - tm[c]) / tm[c];
                    abs[r] += e.abs();
                    sq[r] += e * e;
                    tex_abs[r] += e.abs();
                }
                for i in (0..w * h).filter(|&i| hole[i]) {
                    for c in 0..3 {
                        px[r] += ((fv[i][c] - truth[i][c]) as f64).powi(2);
                    }
                }
            }
            n_means += 3;
            n_px += 3 * nh;
        }
        let best = (0..3).min_by(|&a, &b| tex_abs[a].total_cmp(&tex_abs[b])).unwrap();
        wins[best] += 1;
        println!(
            "{f}: mean |rel. error of the hole mean| inpaint {:.2} %, object mean {:.2} %, ring mean {:.2} %",
            100.0 * tex_abs[0] / 24.0,
            100.0 * tex_abs[1] / 24.0,
            100.0 * tex_abs[2] / 24.0
        );
    }
    println!("{} textures, {} holes × channels:", files.len(), n_means);
    for r in 0..3 {
        println!(
            "  {:12} hole mean: mean |rel. error| {:.2} %, RMS {:.2} %; per-texel RMS {:.4}; best on {} textures",
            names[r],
            100.0 * abs[r] / n_means as f64,
            100.0 * (sq[r] / n_means as f64).sqrt(),
            (px[r] / n_px as f64).sqrt(),
            wins[r]
        );
    }
}
