//! Line plots (PNG or SVG, chosen by the file extension) with plotters and a bundled DejaVu Sans
//! font (no system font library needed). Log or linear y axis, one colour per series, solid or
//! dashed lines or crosses, several panels side by side. Files are written atomically.

use anyhow::{Context, Result, anyhow, bail};
use plotters::coord::Shift;
use plotters::coord::ranged1d::{AsRangedCoord, Ranged, ValueFormatter};
use plotters::prelude::*;
use std::path::Path;
use std::sync::Once;

static FONT: &[u8] = include_bytes!("../../../assets/fonts/DejaVuSans.ttf");
static REGISTER: Once = Once::new();

fn register_font() {
    REGISTER.call_once(|| {
        // The bundled file is a valid TrueType font; a failure here is a build defect.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

/// One curve.
#[derive(Clone, Debug)]
pub struct Series {
    /// Legend entry.
    pub name: String,
    /// (x, y) points in drawing order.
    pub points: Vec<(f64, f64)>,
    /// Colour index into the palette (same index ⇒ same colour).
    pub color: usize,
    /// Dashed instead of solid.
    pub dashed: bool,
    /// Each point a small cross, no line (e.g. values shown but not trusted).
    pub marks: bool,
}

/// One panel: axes with curves.
#[derive(Clone, Debug, Default)]
pub struct LinePlot {
    /// Title above the panel.
    pub title: String,
    /// x axis label.
    pub x_label: String,
    /// y axis label.
    pub y_label: String,
    /// Logarithmic y axis (non-positive values are dropped).
    pub log_y: bool,
    /// Curves.
    pub series: Vec<Series>,
    /// Optional horizontal reference line (e.g. R = 1).
    pub hline: Option<f64>,
}

/// Colour of palette entry `i` (tab10-like).
pub fn palette(i: usize) -> RGBColor {
    const P: [(u8, u8, u8); 10] = [
        (31, 119, 180),
        (255, 127, 14),
        (44, 160, 44),
        (214, 39, 40),
        (148, 103, 189),
        (140, 86, 75),
        (227, 119, 194),
        (127, 127, 127),
        (188, 189, 34),
        (23, 190, 207),
    ];
    let (r, g, b) = P[i % P.len()];
    RGBColor(r, g, b)
}

impl LinePlot {
    /// Saves this single panel.
    pub fn save(&self, path: &Path, size: (u32, u32)) -> Result<()> {
        save_panels(path, std::slice::from_ref(self), size)
    }

    fn ranges(&self) -> Result<((f64, f64), (f64, f64))> {
        let pts = self
            .series
            .iter()
            .flat_map(|s| s.points.iter())
            .filter(|(x, y)| x.is_finite() && y.is_finite() && (!self.log_y || *y > 0.0));
        let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for &(x, y) in pts {
            x0 = x0.min(x);
            x1 = x1.max(x);
            y0 = y0.min(y);
            y1 = y1.max(y);
        }
        if let Some(h) = self.hline {
            y0 = y0.min(h);
            y1 = y1.max(h);
        }
        if x0 > x1 || y0 > y1 {
            bail!("plot '{}' has no finite points to draw", self.title);
        }
        if x1 - x0 <= 0.0 {
            x0 -= 0.5;
            x1 += 0.5;
        }
        if self.log_y {
            let (l0, l1) = (y0.log10(), y1.log10());
            let pad = ((l1 - l0) * 0.05).max(0.05);
            Ok(((x0, x1), (10f64.powf(l0 - pad), 10f64.powf(l1 + pad))))
        } else {
            let pad = ((y1 - y0) * 0.05).max(1e-9 + y1.abs() * 1e-3);
            Ok(((x0, x1), (y0 - pad, y1 + pad)))
        }
    }
}

/// Short axis tick text: up to 4 significant digits, trailing zeros dropped, scientific
/// notation (`1e-5`, `2.5e4`) outside [10⁻³, 10⁴).
fn tick_label(v: f64) -> String {
    fn trim(s: &str) -> &str {
        if s.contains('.') { s.trim_end_matches('0').trim_end_matches('.') } else { s }
    }
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    if (1e-3..1e4).contains(&v.abs()) {
        let digits = (3 - v.abs().log10().floor() as i32).clamp(0, 6) as usize;
        trim(&format!("{v:.digits$}")).to_string()
    } else {
        let s = format!("{v:.3e}");
        let (m, e) = s.split_once('e').unwrap_or((&s, "0"));
        format!("{}e{}", trim(m), e)
    }
}

fn draw_panel<DB: DrawingBackend, Y>(
    area: &DrawingArea<DB, Shift>,
    p: &LinePlot,
    x: (f64, f64),
    y: Y,
) -> Result<()>
where
    Y: AsRangedCoord<Value = f64>,
    Y::CoordDescType: Ranged<ValueType = f64> + ValueFormatter<f64>,
    DB::ErrorType: 'static,
{
    let mut chart = ChartBuilder::on(area)
        .caption(&p.title, ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(x.0..x.1, y)
        .map_err(|e| anyhow!("plot: {e}"))?;
    chart
        .configure_mesh()
        .x_desc(&p.x_label)
        .y_desc(&p.y_label)
        .y_label_formatter(&|v: &f64| tick_label(*v))
        .label_style(("sans-serif", 12))
        .draw()
        .map_err(|e| anyhow!("plot: {e}"))?;
    if let Some(h) = p.hline {
        chart
            .draw_series(DashedLineSeries::new(vec![(x.0, h), (x.1, h)], 4, 4, BLACK.stroke_width(1)))
            .map_err(|e| anyhow!("plot: {e}"))?;
    }
    for s in &p.series {
        let pts: Vec<(f64, f64)> = s
            .points
            .iter()
            .copied()
            .filter(|(a, b)| a.is_finite() && b.is_finite() && (!p.log_y || *b > 0.0))
            .collect();
        let color = palette(s.color);
        let style = color.stroke_width(2);
        let anno = if s.marks {
            chart
                .draw_series(pts.into_iter().map(|p| Cross::new(p, 3, color.stroke_width(1))))
                .map_err(|e| anyhow!("plot: {e}"))?
        } else if s.dashed {
            chart.draw_series(DashedLineSeries::new(pts, 6, 4, style)).map_err(|e| anyhow!("plot: {e}"))?
        } else {
            chart.draw_series(LineSeries::new(pts, style)).map_err(|e| anyhow!("plot: {e}"))?
        };
        if !s.name.is_empty() {
            let anno = anno.label(s.name.clone());
            if s.marks {
                anno.legend(move |(x, y)| Cross::new((x + 8, y), 3, color.stroke_width(1)));
            } else {
                anno.legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], color.stroke_width(2)));
            }
        }
    }
    if p.series.iter().any(|s| !s.name.is_empty()) {
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .label_font(("sans-serif", 12))
            .draw()
            .map_err(|e| anyhow!("plot: {e}"))?;
    }
    Ok(())
}

fn draw_all<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, panels: &[LinePlot]) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(|e| anyhow!("plot: {e}"))?;
    let areas = root.split_evenly((1, panels.len()));
    for (area, p) in areas.iter().zip(panels) {
        let (x, y) = p.ranges()?;
        if p.log_y {
            draw_panel(area, p, x, (y.0..y.1).log_scale())?;
        } else {
            draw_panel(area, p, x, y.0..y.1)?;
        }
    }
    root.present().map_err(|e| anyhow!("plot: {e}"))?;
    Ok(())
}

/// Saves panels side by side; the format follows the extension (`.png` or `.svg`).
pub fn save_panels(path: &Path, panels: &[LinePlot], size: (u32, u32)) -> Result<()> {
    register_font();
    if panels.is_empty() {
        bail!("nothing to plot");
    }
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    match ext.as_str() {
        "svg" => {
            let mut s = String::new();
            draw_all(SVGBackend::with_string(&mut s, size).into_drawing_area(), panels)?;
            crate::util::write_bytes_atomic(path, s.as_bytes())
        }
        "png" => {
            let mut buf = vec![0u8; size.0 as usize * size.1 as usize * 3];
            draw_all(BitMapBackend::with_buffer(&mut buf, size).into_drawing_area(), panels)?;
            let img = image::RgbImage::from_raw(size.0, size.1, buf).context("plot buffer size")?;
            let mut bytes = Vec::new();
            img.write_to(&mut std::io::Cursor::new(&mut bytes), image::ImageFormat::Png)?;
            crate::util::write_bytes_atomic(path, &bytes)
        }
        _ => bail!("plot file {} must end in .png or .svg", path.display()),
    }
}

/// One labelled picture of [`save_image_row`]: 8-bit sRGB RGB pixels, row-major.
pub struct LabelledImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width × height × 3` bytes.
    pub rgb: Vec<u8>,
    /// Caption drawn in a band above the picture.
    pub label: String,
}

/// Saves pictures side by side into one PNG, each with its caption above it.
pub fn save_image_row(path: &Path, images: &[LabelledImage]) -> Result<()> {
    register_font();
    if images.is_empty() {
        bail!("no image to save");
    }
    let band = 24u32;
    let gap = 4u32;
    let w: u32 = images.iter().map(|i| i.width).sum::<u32>() + gap * (images.len() as u32 - 1);
    let h = band + images.iter().map(|i| i.height).max().unwrap_or(0);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    let mut x0 = 0u32;
    for im in images {
        if im.rgb.len() != (im.width * im.height * 3) as usize {
            bail!("image '{}': buffer size mismatch", im.label);
        }
        for y in 0..im.height {
            let src = &im.rgb[(y * im.width * 3) as usize..((y + 1) * im.width * 3) as usize];
            let d0 = (((y + band) * w + x0) * 3) as usize;
            buf[d0..d0 + src.len()].copy_from_slice(src);
        }
        x0 += im.width + gap;
    }
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        let mut x0 = 0i32;
        for im in images {
            let style = ("sans-serif", 15).into_font().color(&BLACK);
            root.draw(&Text::new(im.label.clone(), (x0 + 6, 4), style)).map_err(|e| anyhow!("label: {e}"))?;
            x0 += (im.width + gap) as i32;
        }
        root.present().map_err(|e| anyhow!("image row: {e}"))?;
    }
    let img = image::RgbImage::from_raw(w, h, buf).context("image row buffer size")?;
    let mut bytes = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut bytes), image::ImageFormat::Png)?;
    crate::util::write_bytes_atomic(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_png_and_svg() {
        let dir = tempfile::tempdir().unwrap();
        let p = LinePlot {
            title: "test".into(),
            x_label: "x".into(),
            y_label: "y".into(),
            log_y: true,
            series: vec![
                Series {
                    name: "a".into(),
                    points: (1..50).map(|i| (i as f64, (i as f64).powi(2))).collect(),
                    color: 0,
                    dashed: false,
                    marks: false,
                },
                Series {
                    name: "b".into(),
                    points: (1..50).map(|i| (i as f64, i as f64)).collect(),
                    color: 1,
                    dashed: true,
                    marks: false,
                },
            ],
            hline: Some(1.0),
        };
        let png = dir.path().join("a.png");
        let svg = dir.path().join("a.svg");
        save_panels(&png, &[p.clone(), p.clone()], (800, 300)).unwrap();
        p.save(&svg, (400, 300)).unwrap();
        let img = image::open(&png).unwrap();
        assert_eq!((img.width(), img.height()), (800, 300));
        // something other than white was drawn
        assert!(img.to_rgb8().pixels().any(|px| px.0 != [255, 255, 255]));
        assert!(std::fs::read_to_string(&svg).unwrap().contains("<svg"));
        assert!(p.save(&dir.path().join("a.txt"), (10, 10)).is_err());
    }
}

#[cfg(test)]
mod tick_tests {
    use super::tick_label;

    #[test]
    fn tick_labels_are_short() {
        assert_eq!(tick_label(9.999999999999999e-5), "1e-4");
        assert_eq!(tick_label(1e-7), "1e-7");
        assert_eq!(tick_label(0.01), "0.01");
        assert_eq!(tick_label(0.25), "0.25");
        assert_eq!(tick_label(10.0), "10");
        assert_eq!(tick_label(-80.0), "-80");
        assert_eq!(tick_label(2.5e4), "2.5e4");
        assert_eq!(tick_label(0.0), "0");
    }
}
