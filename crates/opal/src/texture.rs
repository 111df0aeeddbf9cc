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
//! (bitmap pixels shared); both go through the same lookup. A runtime bitmap whose texels hold
//! at most 256 distinct values (8-bit PNGs) reads them as one-byte codes into a table of those
//! values (a third of the memory, the same bits).
//!
//! Tests: unit tests below (hand-computed nearest/bilinear/wrap cases, the runtime texture
//! against its description, palette lookups against the `f32` image) and
//! `tests/scene_load.rs` (the Cornell-box back wall against Mitsuba's albedo AOV).

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
/// copied), filter and wrap mode, and, when the pixels hold at most 256 distinct values (an
/// 8-bit PNG, sRGB-decoded or raw), the same texels as one-byte codes into a [`Palette`].
#[derive(Clone, Debug)]
pub struct Bitmap {
    /// Decoded image, linear values.
    pub image: Arc<Image>,
    /// Bilinear or nearest lookup.
    pub filter: FilterType,
    /// Wrap mode.
    pub wrap: WrapMode,
    /// The texels as codes, looked up instead of `image` (the same values, bit for bit).
    palette: Option<Arc<Palette>>,
}

/// A bitmap's texels as one-byte codes into a table of at most 256 values: four bytes a
/// texel instead of twelve, so that the lookups of a path tracer, spread over the whole
/// texture by the bounces, miss the caches less often (a 512² texture takes 1 MiB instead of
/// 3 MiB) and a bilinear pair of texels mostly shares one cache line. Each value is stored
/// once and read back unchanged (`values[code]`), so a lookup gives the bits of the `f32`
/// image's.
#[derive(Debug)]
struct Palette {
    /// Per texel (`y * width + x`): the codes of r, g, b and a zero byte.
    codes: Vec<[u8; 4]>,
    /// The values, indexed by code.
    values: [f32; 256],
}

impl Palette {
    /// The palette of `img`, or `None` when its channels hold more than 256 distinct values
    /// (bit patterns: `0.0` and `-0.0` are two values).
    fn of(img: &Image) -> Option<Palette> {
        // open addressing on the bits: at most 257 keys in 1024 slots, so probes are short
        const SLOTS: usize = 1024;
        let mut keys = [0u32; SLOTS];
        let mut slot_code = [0u8; SLOTS];
        let mut used = [false; SLOTS];
        let mut values = [0.0f32; 256];
        let mut n = 0usize;
        let mut codes = Vec::with_capacity(img.data.len());
        for v in &img.data {
            let mut texel = [0u8; 4];
            for (code, x) in texel.iter_mut().zip(v.0) {
                let bits = x.to_bits();
                let mut i = (bits.wrapping_mul(0x9e37_79b1) >> 22) as usize;
                while used[i] && keys[i] != bits {
                    i = (i + 1) % SLOTS;
                }
                if !used[i] {
                    if n == values.len() {
                        return None;
                    }
                    (used[i], keys[i], slot_code[i]) = (true, bits, n as u8);
                    values[n] = x;
                    n += 1;
                }
                *code = slot_code[i];
            }
            codes.push(texel);
        }
        (n > 0).then_some(Palette { codes, values })
    }

    /// Texel `i` (`y * width + x`).
    #[inline(always)]
    fn texel(&self, i: usize) -> Spectrum {
        let c = self.codes[i];
        Spectrum([self.values[c[0] as usize], self.values[c[1] as usize], self.values[c[2] as usize]])
    }
}

impl Texture {
    /// The runtime texture of a description (a bitmap shares the description's pixels).
    pub fn new(desc: &TextureDesc) -> Texture {
        match desc {
            TextureDesc::Constant(c) => Texture::Constant(*c),
            TextureDesc::Bitmap(b) => {
                let palette = Palette::of(&b.image).map(Arc::new);
                Texture::Bitmap(Bitmap { image: b.image.clone(), filter: b.filter, wrap: b.wrap, palette })
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
            // texel i and the one below it, of whichever texels the lookup reads
            fn rows<T>(texels: &[T], i: usize, w: usize) {
                crate::simd::prefetch(&texels[i]);
                if let Some(v) = texels.get(i + w) {
                    crate::simd::prefetch(v);
                }
            }
            match &b.palette {
                Some(p) => rows(&p.codes, i, img.width),
                None => rows(&img.data, i, img.width),
            }
        }
    }
}

impl Bitmap {
    /// Whether the texels are read as one-byte codes into a table of at most 256 values (see
    /// [`Bitmap`]); [`Bitmap::eval`] gives the same value either way.
    pub fn has_palette(&self) -> bool {
        self.palette.is_some()
    }

    /// Looks up the bitmap at `uv` with its filter and wrap mode (through the palette when
    /// there is one: the same value).
    #[inline]
    pub fn eval(&self, uv: Vec2) -> Spectrum {
        let img = &*self.image;
        match &self.palette {
            Some(p) => lookup_texels(img.width, img.height, self.filter, self.wrap, uv, |i| p.texel(i)),
            None => lookup(img, self.filter, self.wrap, uv),
        }
    }
}

/// Bitmap lookup at `uv` (the conventions of the module docs); zero for an empty image or a
/// non-finite `uv`.
#[inline]
fn lookup(img: &Image, filter: FilterType, wrap: WrapMode, uv: Vec2) -> Spectrum {
    lookup_texels(img.width, img.height, filter, wrap, uv, |i| img.data[i])
}

/// [`lookup`] of a `w × h` image whose texel `y * w + x` is `texel(y * w + x)`.
#[inline(always)]
fn lookup_texels(
    w: usize,
    h: usize,
    filter: FilterType,
    wrap: WrapMode,
    uv: Vec2,
    texel: impl Fn(usize) -> Spectrum,
) -> Spectrum {
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
            texel(wy(y) * w + wx(x))
        }
        FilterType::Bilinear => {
            let px = uv.x * w as f32 - 0.5;
            let py = uv.y * h as f32 - 0.5;
            let (fx, fy) = (floor(px), floor(py));
            let (wx1, wy1) = (px - fx, py - fy);
            let (wx0, wy0) = (1.0 - wx1, 1.0 - wy1);
            let (x0, y0) = (fx as i64, fy as i64);
            let (x0, x1, y0, y1) = (wx(x0), wx(x0 + 1), wy(y0), wy(y0 + 1));
            let v00 = texel(y0 * w + x0);
            let v10 = texel(y0 * w + x1);
            let v01 = texel(y1 * w + x0);
            let v11 = texel(y1 * w + x1);
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

    /// A texture whose texels hold at most 256 distinct values is looked up through its
    /// palette with the bits of the `f32` image (random sRGB-decoded 8-bit texels, every code
    /// used, both filters and wrap modes, uvs inside and outside the unit square); one more
    /// distinct value and there is no palette. `0.0` and `-0.0` keep their signs.
    #[test]
    fn palette_lookups_equal_the_f32_image() {
        let mut rng = crate::sampling::Rng::new(11, 0, 0);
        let srgb = |k: u32| crate::image::read::srgb_to_linear(k as f32 / 255.0);
        let (w, h) = (37, 23);
        let mut img = Image::new(w, h);
        for (i, v) in img.data.iter_mut().enumerate() {
            // codes 0..=254 all appear (i < 255 in the red channel), the rest at random: with
            // the -0.0 below, 256 distinct values
            let r = if i < 255 { i as u32 } else { rng.next_u32() % 255 };
            *v = Spectrum::rgb(srgb(r), srgb(rng.next_u32() % 255), srgb(rng.next_u32() % 255));
        }
        img.data[300].0[1] = -0.0;
        let p = Palette::of(&img).expect("256 distinct values");
        for (i, v) in img.data.iter().enumerate() {
            assert_eq!(p.texel(i).0.map(f32::to_bits), v.0.map(f32::to_bits), "texel {i}");
        }
        let img = Arc::new(img);
        for filter in [FilterType::Nearest, FilterType::Bilinear] {
            for wrap in [WrapMode::Repeat, WrapMode::Mirror, WrapMode::Clamp] {
                let desc =
                    TextureDesc::Bitmap(BitmapDesc { image: img.clone(), filter, wrap, path: "mem".into() });
                let tex = Texture::new(&desc);
                let Texture::Bitmap(b) = &tex else { unreachable!() };
                assert!(b.palette.is_some());
                for _ in 0..5000 {
                    let uv = Vec2::new(rng.next_f32() * 3.0 - 1.0, rng.next_f32() * 3.0 - 1.0);
                    assert_eq!(tex.eval(uv).0.map(f32::to_bits), desc.eval(uv).0.map(f32::to_bits));
                }
            }
        }
        // 257 distinct values: no palette, the f32 image is looked up
        let mut more = (*img).clone();
        more.data[5].0[2] = 2.0;
        assert!(Palette::of(&more).is_none());
        let desc = TextureDesc::Bitmap(BitmapDesc {
            image: Arc::new(more),
            filter: FilterType::Bilinear,
            wrap: WrapMode::Repeat,
            path: "mem".into(),
        });
        let Texture::Bitmap(b) = Texture::new(&desc) else { unreachable!() };
        assert!(b.palette.is_none());
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
