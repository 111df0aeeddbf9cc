//! Texture evaluation: constants and bitmaps looked up at a surface `uv`, exactly like
//! Mitsuba 3's `bitmap` plugin (which uses Dr.Jit's `Texture`).
//!
//! Conventions (Mitsuba's internal uv, i.e. OBJ `v` already flipped at load):
//! * texel (column `c`, row `r`) of a `W×H` image has its centre at `u = (c+0.5)/W`,
//!   `v = (r+0.5)/H`; row 0 is the **top** row of the image file, so `v = 0` is the top.
//! * **nearest**: texel `(floor(u W), floor(v H))`, then wrapped.
//! * **bilinear**: `x = u W − 0.5`, `x0 = floor(x)`, `x1 = x0 + 1`, weight `x − x0`; the same
//!   for `y`; each of the four integer texel indices is wrapped independently, then the four
//!   texels are blended.
//! * wrap modes act on integer texel indices: **clamp** to `[0, W−1]`; **repeat** `i mod W`;
//!   **mirror** `i mod W` on even periods `floor(i/W)` and `W−1−(i mod W)` on odd ones (the
//!   edge texel is repeated at each reflection).
//!
//! Values are whatever the [`BitmapDesc`] holds (already linear: sRGB decoding happens at load
//! unless `raw`). A built scene evaluates its own [`Texture`], made once from the description
//! (bitmap pixels shared); both go through the same lookup.
//!
//! Tests: unit tests below (hand-computed nearest/bilinear/wrap cases, the runtime texture
//! against its description) and `tests/scene_load.rs` (the Cornell-box back wall against
//! Mitsuba's albedo AOV).

use crate::image::Image;
use crate::math::Vec2;
use crate::scene::desc::{BitmapDesc, FilterType, TextureDesc, WrapMode};
use crate::spectrum::Spectrum;
use std::sync::Arc;

/// Wraps an integer texel index into `[0, n)`.
#[inline(always)]
pub fn wrap_index(i: i64, n: usize, mode: WrapMode) -> usize {
    if (0..n as i64).contains(&i) {
        // every mode leaves indices inside the image alone (no integer division)
        return i as usize;
    }
    wrap_outside(i, n, mode)
}

/// [`wrap_index`] of an index outside `[0, n)`.
#[inline(never)]
fn wrap_outside(i: i64, n: usize, mode: WrapMode) -> usize {
    let n = n as i64;
    let r = match mode {
        WrapMode::Clamp => i.clamp(0, n - 1),
        WrapMode::Repeat => i.rem_euclid(n),
        WrapMode::Mirror => {
            let m = i.rem_euclid(n);
            if i.div_euclid(n) % 2 == 0 { m } else { n - 1 - m }
        }
    };
    r as usize
}

/// `x.floor()` without a call into libm (x86-64 without SSE4.1 has no rounding instruction):
/// truncation corrected downwards for negative non-integers; the same value for every finite
/// `x` (beyond 2²³ every float is an integer; ±0 keep their sign, as `floor`), `floor` itself
/// for the rest.
#[inline]
fn floor(x: f32) -> f32 {
    if x.abs() < 8_388_608.0 {
        let t = x as i32 as f32;
        let t = if t > x { t - 1.0 } else { t };
        t.copysign(x)
    } else {
        x.floor()
    }
}

impl TextureDesc {
    /// Value at texture coordinates `uv` (Mitsuba's convention, see the module docs).
    #[inline]
    pub fn eval(&self, uv: Vec2) -> Spectrum {
        match self {
            TextureDesc::Constant(s) => *s,
            TextureDesc::Bitmap(b) => b.eval(uv),
        }
    }

    /// Mean value over the texture's domain (the constant itself, or the mean texel).
    pub fn mean(&self) -> Spectrum {
        match self {
            TextureDesc::Constant(s) => *s,
            TextureDesc::Bitmap(b) => {
                let m = b.image.mean();
                Spectrum::rgb(m[0] as f32, m[1] as f32, m[2] as f32)
            }
        }
    }
}

impl BitmapDesc {
    /// Looks up the bitmap at `uv` with its filter and wrap mode.
    #[inline]
    pub fn eval(&self, uv: Vec2) -> Spectrum {
        lookup(&self.image, self.filter, self.wrap, uv)
    }
}

/// A texture as a built scene evaluates it (made once from a [`TextureDesc`]).
#[derive(Clone, Debug)]
pub enum Texture {
    /// Constant value.
    Constant(Spectrum),
    /// Bitmap lookup.
    Bitmap(Bitmap),
}

/// A bitmap texture as a built scene evaluates it: the description's pixels (shared, not
/// copied), filter and wrap mode.
#[derive(Clone, Debug)]
pub struct Bitmap {
    /// Decoded image, linear values.
    pub image: Arc<Image>,
    /// Bilinear or nearest lookup.
    pub filter: FilterType,
    /// Wrap mode.
    pub wrap: WrapMode,
}

impl Texture {
    /// The runtime texture of a description (a bitmap shares the description's pixels).
    pub fn new(desc: &TextureDesc) -> Texture {
        match desc {
            TextureDesc::Constant(c) => Texture::Constant(*c),
            TextureDesc::Bitmap(b) => {
                Texture::Bitmap(Bitmap { image: b.image.clone(), filter: b.filter, wrap: b.wrap })
            }
        }
    }

    /// Value at texture coordinates `uv` (Mitsuba's convention, see the module docs); the same
    /// value as the description's [`TextureDesc::eval`].
    #[inline]
    pub fn eval(&self, uv: Vec2) -> Spectrum {
        match self {
            Texture::Constant(s) => *s,
            Texture::Bitmap(b) => b.eval(uv),
        }
    }

    /// Hints the cache lines a bitmap lookup at `uv` reads (no effect on results): issued a
    /// while before [`Texture::eval`], it lets several lookups' memory accesses overlap.
    #[inline]
    pub fn prefetch(&self, uv: Vec2) {
        if let Texture::Bitmap(b) = self {
            let img = &*b.image;
            if img.width == 0 || img.height == 0 || !(uv.x.is_finite() && uv.y.is_finite()) {
                return;
            }
            let x = ((uv.x * img.width as f32) as i64).clamp(0, img.width as i64 - 1) as usize;
            let y = ((uv.y * img.height as f32 - 0.5) as i64).clamp(0, img.height as i64 - 1) as usize;
            let i = y * img.width + x;
            crate::simd::prefetch(&img.data[i]);
            if let Some(v) = img.data.get(i + img.width) {
                crate::simd::prefetch(v);
            }
        }
    }
}

impl Bitmap {
    /// Looks up the bitmap at `uv` with its filter and wrap mode.
    #[inline]
    pub fn eval(&self, uv: Vec2) -> Spectrum {
        lookup(&self.image, self.filter, self.wrap, uv)
    }
}

/// Bitmap lookup at `uv` (the conventions of the module docs); zero for an empty image or a
/// non-finite `uv`.
#[inline]
fn lookup(img: &Image, filter: FilterType, wrap: WrapMode, uv: Vec2) -> Spectrum {
    let (w, h) = (img.width, img.height);
    if w == 0 || h == 0 {
        return Spectrum::ZERO;
    }
    if !(uv.x.is_finite() && uv.y.is_finite()) {
        return Spectrum::ZERO;
    }
    let (wx, wy) = (|x: i64| wrap_index(x, w, wrap), |y: i64| wrap_index(y, h, wrap));
    match filter {
        FilterType::Nearest => {
            let x = floor(uv.x * w as f32) as i64;
            let y = floor(uv.y * h as f32) as i64;
            img.get(wx(x), wy(y))
        }
        FilterType::Bilinear => {
            let px = uv.x * w as f32 - 0.5;
            let py = uv.y * h as f32 - 0.5;
            let (fx, fy) = (floor(px), floor(py));
            let (wx1, wy1) = (px - fx, py - fy);
            let (wx0, wy0) = (1.0 - wx1, 1.0 - wy1);
            let (x0, y0) = (fx as i64, fy as i64);
            let (x0, x1, y0, y1) = (wx(x0), wx(x0 + 1), wy(y0), wy(y0 + 1));
            let v00 = img.get(x0, y0);
            let v10 = img.get(x1, y0);
            let v01 = img.get(x0, y1);
            let v11 = img.get(x1, y1);
            // Same weights and accumulation order as Dr.Jit's `eval_nonaccel`.
            v00 * (wx0 * wy0) + v10 * (wx1 * wy0) + v01 * (wx0 * wy1) + v11 * (wx1 * wy1)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::Image;
    use std::sync::Arc;

    /// 4×2 image with texel (x, y) = (10 y + x, 0, 1).
    fn bitmap(filter: FilterType, wrap: WrapMode) -> BitmapDesc {
        let mut img = Image::new(4, 2);
        for y in 0..2 {
            for x in 0..4 {
                img.set(x, y, Spectrum::rgb((10 * y + x) as f32, 0.0, 1.0));
            }
        }
        BitmapDesc { image: Arc::new(img), filter, wrap, path: "mem".into() }
    }

    #[test]
    fn floor_without_libm_is_floor() {
        let mut rng = crate::sampling::Rng::new(5, 0, 0);
        let mut xs =
            vec![0.0f32, -0.0, 0.5, -0.5, 1.0, -1.0, 8_388_607.5, -8_388_607.5, 8_388_608.0, 1e30, -1e30];
        xs.extend([f32::MIN_POSITIVE, -f32::MIN_POSITIVE, 1e-45, -1e-45, f32::INFINITY, f32::NEG_INFINITY]);
        for _ in 0..100_000 {
            let e = (rng.next_f32() * 60.0 - 30.0).exp2();
            xs.push((rng.next_f32() * 2.0 - 1.0) * e);
        }
        for x in xs {
            assert_eq!(floor(x).to_bits(), x.floor().to_bits(), "{x:e}");
        }
        assert!(floor(f32::NAN).is_nan());
    }

    #[test]
    fn wrap_modes_on_integer_indices() {
        let n = 4;
        let rep: Vec<usize> = (-5..9).map(|i| wrap_index(i, n, WrapMode::Repeat)).collect();
        assert_eq!(rep, [3, 0, 1, 2, 3, 0, 1, 2, 3, 0, 1, 2, 3, 0]);
        let cl: Vec<usize> = (-2..6).map(|i| wrap_index(i, n, WrapMode::Clamp)).collect();
        assert_eq!(cl, [0, 0, 0, 1, 2, 3, 3, 3]);
        // Mirror: ... 3 2 1 0 | 0 1 2 3 | 3 2 1 0 | 0 ...
        let mi: Vec<usize> = (-5..9).map(|i| wrap_index(i, n, WrapMode::Mirror)).collect();
        assert_eq!(mi, [3, 3, 2, 1, 0, 0, 1, 2, 3, 3, 2, 1, 0, 0]);
    }

    #[test]
    fn texel_centres_return_texel_values() {
        for filter in [FilterType::Nearest, FilterType::Bilinear] {
            let b = bitmap(filter, WrapMode::Clamp);
            for y in 0..2 {
                for x in 0..4 {
                    let uv = Vec2::new((x as f32 + 0.5) / 4.0, (y as f32 + 0.5) / 2.0);
                    assert_eq!(b.eval(uv)[0], (10 * y + x) as f32, "{filter:?} ({x},{y})");
                }
            }
        }
    }

    #[test]
    fn bilinear_by_hand() {
        // uv = (0.5, 0.5): px = 1.5, py = 0.5 → x0 = 1 (w .5), y0 = 0 (w .5):
        // (1 + 2 + 11 + 12)/4 = 6.5.
        let b = bitmap(FilterType::Bilinear, WrapMode::Clamp);
        assert!((b.eval(Vec2::new(0.5, 0.5))[0] - 6.5).abs() < 1e-6);
        // uv = (0.3, 0.6): px = 0.7 → x0 0 (w 0.3), x1 1 (w 0.7); py = 0.7 → y0 0 (0.3), y1 1 (0.7).
        let v = 0.3 * (0.3 * 0.0 + 0.7 * 1.0) + 0.7 * (0.3 * 10.0 + 0.7 * 11.0);
        assert!((b.eval(Vec2::new(0.3, 0.6))[0] - v).abs() < 1e-5);
        // Blue is constant 1 → partition of unity.
        assert!((b.eval(Vec2::new(0.3, 0.6))[2] - 1.0).abs() < 1e-6);
        // Left of the first centre with clamp: the edge value.
        assert_eq!(b.eval(Vec2::new(0.01, 0.25))[0], 0.0);
        // Repeat: u = 0.0, v = 0.25 → px = -0.5: texels -1 (→3) and 0, half each: (3+0)/2.
        let r = bitmap(FilterType::Bilinear, WrapMode::Repeat);
        assert!((r.eval(Vec2::new(0.0, 0.25))[0] - 1.5).abs() < 1e-6);
        // Mirror: texel -1 → 0, so (0+0)/2.
        let m = bitmap(FilterType::Bilinear, WrapMode::Mirror);
        assert!(m.eval(Vec2::new(0.0, 0.25))[0].abs() < 1e-6);
    }

    #[test]
    fn runtime_texture_is_its_description() {
        let mut rng = crate::sampling::Rng::new(9, 0, 0);
        for filter in [FilterType::Nearest, FilterType::Bilinear] {
            for wrap in [WrapMode::Repeat, WrapMode::Mirror, WrapMode::Clamp] {
                let desc = TextureDesc::Bitmap(bitmap(filter, wrap));
                let tex = Texture::new(&desc);
                let (Texture::Bitmap(b), TextureDesc::Bitmap(d)) = (&tex, &desc) else { unreachable!() };
                assert!(Arc::ptr_eq(&b.image, &d.image), "pixels shared, not copied");
                for _ in 0..1000 {
                    let uv = Vec2::new(rng.next_f32() * 4.0 - 1.5, rng.next_f32() * 4.0 - 1.5);
                    assert_eq!(tex.eval(uv).0.map(f32::to_bits), desc.eval(uv).0.map(f32::to_bits));
                }
                assert_eq!(tex.eval(Vec2::new(f32::NAN, 0.5)).0, [0.0; 3]);
            }
        }
        let c = Spectrum::rgb(0.1, 0.2, 0.3);
        assert_eq!(Texture::new(&TextureDesc::Constant(c)).eval(Vec2::new(0.7, 0.1)), c);
    }

    #[test]
    fn nearest_wraps_outside_unit_square() {
        let r = bitmap(FilterType::Nearest, WrapMode::Repeat);
        assert_eq!(r.eval(Vec2::new(1.1, 0.25))[0], 0.0); // 4.4 → 4 → 0
        assert_eq!(r.eval(Vec2::new(-0.1, 0.75))[0], 13.0); // -0.4 → -1 → 3; row 1
        let m = bitmap(FilterType::Nearest, WrapMode::Mirror);
        assert_eq!(m.eval(Vec2::new(1.1, 0.25))[0], 3.0);
        let c = bitmap(FilterType::Nearest, WrapMode::Clamp);
        assert_eq!(c.eval(Vec2::new(7.0, -3.0))[0], 3.0);
    }
}
