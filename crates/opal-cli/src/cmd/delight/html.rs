//! report.html of `opal delight`, and the images made for it: per view the photo, the re-render
//! and a false-colour map of their per-pixel error side by side, each with a colour bar (tick
//! labels in the page); per object the albedo texture and its last error map at ≥ 512 px
//! (nearest-neighbour upscaling); the convergence plot and the tables of report.json.
//!
//! Conventions: every image is a relative path inside the output folder; the page loads nothing
//! else (no scripts, style sheets or fonts). Photos and re-renders of a view share one exposure
//! (a power of two, [`preview_exposure`]), written in their colour bar. The colour bars are PNGs
//! in `report/` (the sRGB display ramp and the error colour map), stretched by the page.
//! Tests: `tests/delight.rs` (`check_report_images`: every image exists and decodes, paths
//! relative; the ignored `report_images_load_in_chromium`).

use crate::util;
use anyhow::Result;
use opal::image::Image;
use opal::image::write::{false_colour, linear_to_srgb};
use serde_json::Value;
use std::fmt::Write as _;
use std::path::Path;

/// Range of the per-view error maps (signed relative luminance error).
pub const VIEW_ERROR_RANGE: (f32, f32) = (-0.2, 0.2);
/// Range of the per-texel error maps `errors/iter_NN_<obj>.png`.
pub const TEXEL_ERROR_RANGE: (f32, f32) = (0.0, 0.1);
/// Colour bar of the previews: the 8-bit sRGB display ramp (black → white).
pub const BAR_SRGB: &str = "report/bar_srgb.png";
/// Colour bar of the per-texel error maps (the false-colour map, low → high).
pub const BAR_ERROR: &str = "report/bar_error.png";
/// Colour bar of the per-view (signed) error maps.
pub const BAR_SIGNED: &str = "report/bar_signed.png";

/// Writes the three colour-bar images (256 × 1 px) into `out`.
pub fn write_colour_bars(out: &Path) -> Result<()> {
    let ramp: Vec<u8> = (0..=255u8).flat_map(|v| [v, v, v]).collect();
    let map: Vec<u8> = (0..256).flat_map(|k| false_colour(k as f32 / 255.0)).collect();
    let signed: Vec<u8> = (0..256).flat_map(|k| diverging_colour(k as f32 / 255.0)).collect();
    for (name, px) in [(BAR_SRGB, ramp), (BAR_ERROR, map), (BAR_SIGNED, signed)] {
        let img = image::RgbImage::from_raw(256, 1, px).expect("256 × 1 RGB");
        util::write_atomic(&out.join(name), |f| {
            Ok(img.write_to(&mut std::io::BufWriter::new(f), image::ImageFormat::Png)?)
        })?;
    }
    Ok(())
}

/// Exposure of a view's previews: the power of two that brings the photo's median luminance
/// (finite, positive pixels) closest to 0.18 (mid grey; robust to a bright emitter in view),
/// clamped to 2^±10 (1 for a black photo). Photo and re-render use the same one.
pub fn preview_exposure(photo: &Image) -> f32 {
    let mut l: Vec<f32> = photo
        .data
        .iter()
        .map(|p| opal_inverse::delight::luminance(p.0))
        .filter(|v| v.is_finite() && *v > 0.0)
        .collect();
    if l.is_empty() {
        return 1.0;
    }
    let k = l.len() / 2;
    let median = *l.select_nth_unstable_by(k, f32::total_cmp).1;
    2f32.powi((0.18 / median).log2().round().clamp(-10.0, 10.0) as i32)
}

/// Luminance of `img` averaged over each pixel's 3 × 3 neighbourhood (finite pixels only; NaN
/// where none is finite).
fn box3_luminance(img: &Image) -> Vec<f32> {
    let l: Vec<f32> = img.data.iter().map(|p| opal_inverse::delight::luminance(p.0)).collect();
    let (w, h) = (img.width as i64, img.height as i64);
    let mut out = vec![f32::NAN; l.len()];
    for y in 0..h {
        for x in 0..w {
            let (mut sum, mut n) = (0f32, 0);
            for (dx, dy) in (-1..=1).flat_map(|dy| (-1..=1).map(move |dx| (dx, dy))) {
                let (u, v) = (x + dx, y + dy);
                if (0..w).contains(&u) && (0..h).contains(&v) {
                    let s = l[(v * w + u) as usize];
                    if s.is_finite() {
                        sum += s;
                        n += 1;
                    }
                }
            }
            if n > 0 {
                out[(y * w + x) as usize] = sum / n as f32;
            }
        }
    }
    out
}

/// Per-pixel signed relative luminance error of a re-render against the photo, both averaged
/// over 3 × 3 pixels first (the Monte-Carlo noise of single pixels hid systematic errors):
/// `(L̄_rerender − L̄_photo) / max(L̄_photo, 0.1 × mean L_photo)` (the floor keeps near-black
/// pixels from dominating); NaN where the photo pixel is not finite. Also returns the view's
/// luminance bias `Σ L_rerender / Σ L_photo − 1` over the photo's finite pixels.
pub fn view_error(photo: &Image, rerender: &Image) -> (Vec<f32>, f64) {
    let lum = |p: &opal::spectrum::Spectrum| opal_inverse::delight::luminance(p.0) as f64;
    let (mut sp, mut sr, mut n) = (0f64, 0f64, 0usize);
    for (p, q) in photo.data.iter().zip(&rerender.data) {
        if lum(p).is_finite() {
            sp += lum(p);
            sr += lum(q);
            n += 1;
        }
    }
    let floor = (0.1 * sp / n.max(1) as f64) as f32;
    let (lp, lr) = (box3_luminance(photo), box3_luminance(rerender));
    let e = photo
        .data
        .iter()
        .zip(lp.iter().zip(&lr))
        .map(|(p, (&a, &b))| if lum(p).is_finite() { (b - a) / a.max(floor).max(1e-30) } else { f32::NAN })
        .collect();
    (e, sr / sp.max(1e-300) - 1.0)
}

/// Diverging colour map, t ∈ [0, 1] (0.5 white; blue below, red above; piecewise linear through
/// 5 anchors).
pub fn diverging_colour(t: f32) -> [u8; 3] {
    const A: [[f32; 3]; 5] = [
        [5.0, 48.0, 97.0],
        [67.0, 147.0, 195.0],
        [247.0, 247.0, 247.0],
        [214.0, 96.0, 77.0],
        [103.0, 0.0, 31.0],
    ];
    let x = t.clamp(0.0, 1.0) * 4.0;
    let i = (x as usize).min(3);
    let f = x - i as f32;
    std::array::from_fn(|k| (A[i][k] * (1.0 - f) + A[i + 1][k] * f).round() as u8)
}

/// Writes a signed error map (`values` row-major, `width × height`) over [`VIEW_ERROR_RANGE`]
/// with [`diverging_colour`] as PNG; NaN pixels are black.
pub fn write_signed_error_png(path: &Path, values: &[f32], width: usize, height: usize) -> Result<()> {
    let (lo, hi) = VIEW_ERROR_RANGE;
    let px: Vec<u8> = values
        .iter()
        .flat_map(|&v| if v.is_finite() { diverging_colour((v - lo) / (hi - lo)) } else { [0, 0, 0] })
        .collect();
    let img = image::RgbImage::from_raw(width as u32, height as u32, px).expect("width × height values");
    util::write_atomic(path, |f| Ok(img.write_to(&mut std::io::BufWriter::new(f), image::ImageFormat::Png)?))
}

/// A compact number for a tick label.
fn tick(v: f64) -> String {
    if v == 0.0 {
        "0".into()
    } else if v >= 100.0 {
        format!("{v:.0}")
    } else {
        let s = format!("{v:.3}");
        let s = s.trim_end_matches('0').trim_end_matches('.');
        if s == "0" { format!("{v:.1e}") } else { s.to_string() }
    }
}

/// HTML of a colour bar: the bar image and tick labels at fractions of its width.
fn bar(src: &str, ticks: &[(f64, String)], caption: &str) -> String {
    let mut s = format!(
        "<div class=\"cb\"><img class=\"bar\" src=\"{src}\" alt=\"colour bar\"><div class=\"ticks\">"
    );
    for (x, label) in ticks {
        let _ = write!(s, "<span style=\"left:{:.2}%\">{label}</span>", 100.0 * x);
    }
    let _ = write!(s, "</div><div class=\"cap\">{caption}</div></div>");
    s
}

/// Colour bar of a preview shown at `exposure`: ticks at display values (sRGB positions) of
/// linear 0, 1 %, 5 %, 20 %, 50 %, 100 % of the white point, labelled in the image's units.
fn srgb_bar(exposure: f64, unit: &str) -> String {
    let ticks: Vec<(f64, String)> = [0.0, 0.01, 0.05, 0.2, 0.5, 1.0]
        .iter()
        .map(|&d| (linear_to_srgb(d as f32) as f64, tick(d / exposure)))
        .collect();
    let exp = if exposure == 1.0 { String::new() } else { format!(", exposure ×{}", tick(exposure)) };
    bar(BAR_SRGB, &ticks, &format!("{unit} (linear, sRGB display{exp})"))
}

/// Colour bar `src` of an error map with `range` (fractions, labelled in %; the ends are
/// clamped: "+" / "−" beyond them).
fn error_bar(src: &str, range: (f32, f32), caption: &str) -> String {
    let ticks: Vec<(f64, String)> = (0..=4)
        .map(|k| {
            let v = 100.0 * (range.0 as f64 + (range.1 - range.0) as f64 * k as f64 / 4.0);
            let sign = if v > 0.0 && range.0 < 0.0 {
                "+"
            } else if v < 0.0 {
                "−"
            } else {
                ""
            };
            let mut l = format!("{sign}{} %", tick(v.abs()));
            if k == 4 {
                l.push('+');
            } else if k == 0 && range.0 < 0.0 {
                l.insert(0, '≤');
            }
            (k as f64 / 4.0, l)
        })
        .collect();
    bar(src, &ticks, caption)
}

/// A relative file path as a URL path: bytes other than letters, digits, `-._~/` percent-encoded
/// (object and view names may hold `#`, `?`, `%` or spaces).
fn src(path: &str) -> String {
    let mut s = String::with_capacity(path.len());
    for b in path.bytes() {
        if b.is_ascii_alphanumeric() || b"-._~/".contains(&b) {
            s.push(b as char);
        } else {
            let _ = write!(s, "%{b:02X}");
        }
    }
    s
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;").replace('"', "&quot;").replace('<', "&lt;").replace('>', "&gt;")
}

const STYLE: &str = "body{font-family:sans-serif;margin:16px;color:#111}\
h2{margin-top:32px;border-bottom:1px solid #ccc}\
td,th{padding:2px 8px;text-align:right}\
.row{display:flex;flex-wrap:wrap;gap:20px;align-items:flex-start;margin-bottom:24px}\
figure{margin:0}figure.v{width:min(440px,31vw)}figcaption{font-weight:bold;margin-bottom:4px}\
img.px{display:block;width:100%;height:auto;background:#000}\
img.tex{display:block;height:auto;max-width:100%}img.up{image-rendering:pixelated}\
.cb{margin-top:6px;font-size:12px}img.bar{display:block;width:100%;height:14px;border:1px solid #888;box-sizing:border-box}\
.ticks{position:relative;height:16px}.ticks span{position:absolute;transform:translateX(-50%);white-space:nowrap}\
.ticks span:first-child{transform:none}.ticks span:last-child{transform:translateX(-100%)}\
.cap{color:#444}.note{color:#444;max-width:1000px}";

/// The HTML page of a report.json value.
pub fn html(r: &Value) -> String {
    let mut s = format!(
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>opal delight report</title><style>{STYLE}</style></head><body><h1>De-lighting report</h1><p><a href=\"#views\">views</a> · <a href=\"#objects\">objects</a> · <a href=\"#regions\">regions</a></p>"
    );
    let its = r["iterations"].as_array().map_or(0, |a| a.len());
    let _ = write!(
        s,
        "<p>{} view(s), {} object(s), {its} iteration(s), converged: {} — max region error (luminance): {:.3} %</p><img src=\"convergence.png\" alt=\"convergence\" style=\"width:640px;max-width:100%\">",
        r["n_views"],
        r["objects"].as_array().map_or(0, |a| a.len()),
        r["converged"],
        100.0 * f(&r["max_region_rel_error_luminance"])
    );
    views_section(&mut s, r);
    objects_section(&mut s, r);
    if let Some(g) = r["view_gains"].as_object() {
        let _ = write!(
            s,
            "<h2 id=\"gains\">View gains ({}, median view exact)</h2><table><tr><th>view</th><th>gain R G B</th><th>± std. err.</th><th>samples</th><th>far</th></tr>",
            esc(g["mode"].as_str().unwrap_or(""))
        );
        for v in g["views"].as_array().into_iter().flatten() {
            let c = |x: &Value, k: usize| x[k].as_f64().unwrap_or(f64::NAN);
            let _ = write!(
                s,
                "<tr><td>{}</td><td>{:.4} {:.4} {:.4}</td><td>{:.4} {:.4} {:.4}</td><td>{}</td><td>{}</td></tr>",
                esc(v["view"].as_str().unwrap_or("")),
                c(&v["gain"], 0),
                c(&v["gain"], 1),
                c(&v["gain"], 2),
                c(&v["std_err"], 0),
                c(&v["std_err"], 1),
                c(&v["std_err"], 2),
                v["samples"],
                if v["far_from_others"].as_bool() == Some(true) { "yes" } else { "" }
            );
        }
        s.push_str("</table>");
    }
    regions_section(&mut s, r);
    s.push_str("</body></html>\n");
    s
}

/// Per view: photo | re-render | error map, each with its colour bar.
fn views_section(s: &mut String, r: &Value) {
    let rr = r["rerenders"].as_array().map(Vec::as_slice).unwrap_or_default();
    if rr.is_empty() {
        s.push_str("<h2 id=\"views\">Views</h2><p>No re-renders (<code>--rerender-spp 0</code>).</p>");
        return;
    }
    let range = (f(&r["view_error_range"][0]) as f32, f(&r["view_error_range"][1]) as f32);
    let _ = write!(
        s,
        "<h2 id=\"views\">Views: photo | re-render with the recovered albedos | error</h2><p class=\"note\">Error: (L̄<sub>re-render</sub> − L̄<sub>photo</sub>) / max(L̄<sub>photo</sub>, 10 % of the photo's mean L), L̄ = luminance averaged over 3×3 pixels (single pixels are dominated by Monte-Carlo noise), {}…{} %: red = re-render too bright, blue = too dark; black where the photo has no valid value. Bias = ΣL<sub>re-render</sub> / ΣL<sub>photo</sub> − 1 over the view. Photos divided by their estimated view gains, if any.</p>",
        tick(100.0 * range.0 as f64),
        tick(100.0 * range.1 as f64)
    );
    for v in rr {
        let name = esc(v["view"].as_str().unwrap_or(""));
        let e = f(&v["exposure"]);
        // nearest-neighbour when the view is enlarged (figures are ≤ 440 px wide)
        let up = if v["size"][0].as_u64().is_some_and(|w| w < 440) { " up" } else { "" };
        let _ = write!(s, "<h3>{name}</h3><div class=\"row\">");
        for (key, title) in [("photo", "photo"), ("rerender", "re-render")] {
            let _ = write!(
                s,
                "<figure class=\"v\"><figcaption>{title}</figcaption><img class=\"px{up}\" src=\"{}\" alt=\"{title} {name}\">{}</figure>",
                src(v[key].as_str().unwrap_or("")),
                srgb_bar(e, "radiance")
            );
        }
        let _ = write!(
            s,
            "<figure class=\"v\"><figcaption>error (bias {:+.2} %)</figcaption><img class=\"px{up}\" src=\"{}\" alt=\"error {name}\">{}</figure></div>",
            100.0 * f(&v["rel_bias_luminance"]),
            src(v["error_map"].as_str().unwrap_or("")),
            error_bar(BAR_SIGNED, range, "relative luminance error (3×3 mean)")
        );
    }
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or(f64::NAN)
}

/// Per object: statistics, the albedo texture and its last per-texel error map, ≥ 512 px wide.
fn objects_section(s: &mut String, r: &Value) {
    s.push_str("<h2 id=\"objects\">Objects</h2><p class=\"note\">Textures in atlas layout (row 0 = v 0 at the top), enlarged without interpolation to at least 512 px. Error: |relative error| of the last iteration's luminance equation per texel, black where no view saw the texel.</p>");
    let range = (f(&r["texel_error_range"][0]) as f32, f(&r["texel_error_range"][1]) as f32);
    for o in r["objects"].as_array().into_iter().flatten() {
        let id = esc(o["id"].as_str().unwrap_or(""));
        let (w, h) = (o["resolution"][0].as_u64().unwrap_or(1), o["resolution"][1].as_u64().unwrap_or(1));
        // at least 512 px, at most 1024 px (the page scales down further on narrow windows)
        let show = w.clamp(512, 1024);
        // nearest-neighbour when enlarging; the browser's filter when a large map is reduced
        let up = if show > w { " up" } else { "" };
        let m = &o["mean_albedo_seen"];
        let _ = write!(
            s,
            "<h3>{id}</h3><p>{w}×{h} texels, {} chart(s){}, seen {:.1} %, mean albedo (seen) {:.4} {:.4} {:.4}{}</p><div class=\"row\">",
            o["charts"],
            if o["kept_uvs"].as_bool() == Some(true) { " (own UVs)" } else { "" },
            100.0 * f(&o["seen_fraction"]),
            f(&m[0]),
            f(&m[1]),
            f(&m[2]),
            if o["recovered_from_inpainting_only"].as_bool() == Some(true) {
                " — <b>seen by no view</b>"
            } else {
                ""
            }
        );
        let _ = write!(
            s,
            "<figure style=\"width:{show}px;max-width:100%\"><figcaption>albedo</figcaption><img class=\"tex{up}\" src=\"{}\" width=\"{show}\" alt=\"albedo {id}\">{}</figure>",
            src(&o["texture"].as_str().unwrap_or("").replace(".exr", ".png")),
            srgb_bar(1.0, "albedo")
        );
        if let Some(e) = o["last_error_map"].as_str() {
            let _ = write!(
                s,
                "<figure style=\"width:{show}px;max-width:100%\"><figcaption>error, last iteration</figcaption><img class=\"tex{up}\" src=\"{}\" width=\"{show}\" alt=\"error {id}\">{}</figure>",
                src(e),
                error_bar(BAR_ERROR, range, "|relative error| per texel")
            );
        }
        s.push_str("</div>");
    }
    let left_out = r["not_recovered"].as_array().map(Vec::as_slice).unwrap_or_default();
    if !left_out.is_empty() {
        s.push_str("<h3>Not recovered</h3><ul>");
        for o in left_out {
            let _ = write!(
                s,
                "<li>{}: {}</li>",
                esc(o["id"].as_str().unwrap_or("")),
                esc(o["reason"].as_str().unwrap_or(""))
            );
        }
        s.push_str("</ul>");
    }
}

/// The region table (photo vs re-render per view and object), folded.
fn regions_section(s: &mut String, r: &Value) {
    let regions = r["regions"].as_array().map(Vec::as_slice).unwrap_or_default();
    let _ = write!(
        s,
        "<h2 id=\"regions\">Regions: photo vs re-render</h2><details><summary>{} region(s) (pure pixels of one object in one view)</summary><table><tr><th>view</th><th>object</th><th>px</th><th>mean L</th><th>L RMS</th><th>RGB</th><th>CIE xy</th><th>rel. err.</th></tr>",
        regions.len()
    );
    for g in regions {
        for (k, who) in [("photo", "photo"), ("rerender", "re-render")] {
            let p = &g[k];
            let _ = write!(
                s,
                "<tr><td>{}</td><td>{} ({who})</td><td>{}</td><td>{:.6}</td><td>{:.6}</td><td>{:.6} {:.6} {:.6}</td><td>{:.6} {:.6}</td><td>{}</td></tr>",
                esc(g["view"].as_str().unwrap_or("")),
                esc(g["object"].as_str().unwrap_or("")),
                g["pixels"],
                f(&p["mean_luminance"]),
                f(&p["luminance_rms"]),
                f(&p["mean_rgb"][0]),
                f(&p["mean_rgb"][1]),
                f(&p["mean_rgb"][2]),
                f(&p["xy"][0]),
                f(&p["xy"][1]),
                if k == "rerender" {
                    format!("{:+.3} %", 100.0 * f(&g["rel_error_luminance"]))
                } else {
                    String::new()
                }
            );
        }
    }
    s.push_str("</table></details>");
}

#[cfg(test)]
mod tests {
    use super::*;
    use opal::spectrum::Spectrum;

    #[test]
    fn exposure_and_ticks() {
        let mut img = Image::new(10, 10);
        for p in &mut img.data {
            *p = Spectrum::splat(0.3);
        }
        // median 0.3: 0.18 / 0.3 = 2^−0.74 → 2^−1
        assert_eq!(preview_exposure(&img), 0.5);
        assert_eq!(preview_exposure(&Image::new(4, 4)), 1.0);
        assert_eq!(tick(0.05), "0.05");
        assert_eq!(tick(0.5), "0.5");
        assert_eq!(tick(20.0), "20");
        assert_eq!(tick(0.0001), "1.0e-4");
        let (e, mean) = view_error(&img, &{
            let mut q = img.clone();
            q.data[0] = Spectrum::splat(0.33);
            q
        });
        // corner pixel: 3×3 mean over its 4 pixels (0.33 + 3 × 0.3) / 4 = 0.3075
        assert!((e[0] - 0.025).abs() < 1e-5, "{}", e[0]);
        // pixel (2, 2) sees no changed pixel
        assert_eq!(e[22], 0.0);
        assert!((mean - 0.001).abs() < 1e-6, "{mean}");
        assert_eq!(diverging_colour(0.5), [247, 247, 247]);
        assert_eq!(src("photo/IMG 1#ä.png"), "photo/IMG%201%23%C3%A4.png");
    }
}
