//! Error analysis of `mitsuba_scan_room_acceptance` (only with `OPAL_SCAN_ROOM_OUT=DIR`): where the
//! squared albedo error of a textured object sits at the input cameras and in texture space.
//!
//! * **Oracle atlas**: the true albedo sampled at the texel centres of the recovered atlas (a ray
//!   along −n from just outside each texel centre into the truth scene) and dilated like the
//!   recovered map: its PSNR at the cameras is the bound the atlas (resolution, charts, gutters)
//!   allows with perfect de-lighting.
//! * **Bins** of the squared error at the cameras (per pixel, the same 4 × 4 rays as the
//!   acceptance) by the distance of the pixel centre's texel to the chart border, by the number of
//!   views that see the point, by cos θ to this view, by silhouette pixels, by the ratio of
//!   pixel footprint to texel area and by the observed mask.
//! * **Texture space**: the recovered minus the oracle albedo on the observed texels, its
//!   low-frequency part (smoothed within charts over resolution/64) and the rest; EXR maps in DIR.

use opal::geometry::Ray;
use opal::image::Image;
use opal::math::Vec2;
use opal::scene::Scene;
use opal::scene::build::eval_texture;
use opal::scene::desc::{BitmapDesc, BsdfDesc, FilterType, SceneDesc, TextureDesc, WrapMode};
use opal::spectrum::Spectrum;
use opal_inverse::delight::atlas::NO_TRI;
use opal_inverse::delight::views::View;
use opal_inverse::delight::{ObjectResult, inpaint, luminance, smooth_in_charts};
use std::path::Path;
use std::sync::Arc;

fn refl<'a>(desc: &'a SceneDesc, id: &str) -> &'a TextureDesc {
    match &desc.shapes.iter().find(|s| s.id == id).unwrap().bsdf {
        BsdfDesc::Diffuse { reflectance } => reflectance,
        other => panic!("{id}: unexpected bsdf {other:?}"),
    }
}

fn write(img: &Image, p: &Path) {
    let f = std::fs::File::create(p).unwrap();
    opal::image::write::write_exr(img, std::io::BufWriter::new(f)).unwrap();
}

/// The true albedo on the atlas of `o` (covered texels sampled, gutters dilated).
pub fn oracle_kd(o: &ObjectResult, truth_desc: &SceneDesc, truth: &Scene) -> Vec<[f32; 3]> {
    let a = &o.atlas;
    let ts = truth.shapes.iter().position(|s| s.id == o.id).unwrap() as u32;
    let tt = refl(truth_desc, &o.id);
    let n = a.width * a.height;
    let mut kd = vec![[0f32; 3]; n];
    let mut have = vec![false; n];
    for i in 0..n {
        if a.texel_tri[i] == NO_TRI {
            continue;
        }
        let (p, ng) = (a.texel_p[i], a.texel_ng[i]);
        let mut ray = Ray::new(p + ng * 2e-4, -ng);
        ray.tmax = 1e-3;
        if let Some(h) = truth.intersect(&ray).filter(|h| h.shape == ts) {
            kd[i] = eval_texture(tt, h.uv).0;
            have[i] = true;
        }
    }
    let cov: Vec<bool> = (0..n).map(|i| a.texel_tri[i] != NO_TRI).collect();
    let chart: Vec<u32> = (0..n).map(|i| a.texel_chart(i)).collect();
    inpaint::inpaint(&mut kd, &have, &cov, &chart, a.width, a.height, 4);
    inpaint::dilate(&mut kd, &cov, &a.texel_owner, a.width, a.height, 4);
    kd
}

fn with_kd(desc: &SceneDesc, o: &ObjectResult, kd: &[[f32; 3]]) -> SceneDesc {
    let mut d = desc.clone();
    let s = d.shapes.iter_mut().find(|s| s.id == o.id).unwrap();
    let mut img = Image::new(o.atlas.width, o.atlas.height);
    for (d, v) in img.data.iter_mut().zip(kd) {
        *d = Spectrum(*v);
    }
    s.bsdf = BsdfDesc::Diffuse {
        reflectance: TextureDesc::Bitmap(BitmapDesc {
            image: Arc::new(img),
            filter: FilterType::Bilinear,
            wrap: WrapMode::Clamp,
            path: "oracle.exr".into(),
        }),
    };
    d
}

/// Per view and pixel the squared RGB error of `id` summed over RGB (4 × 4 rays; NaN off the
/// object).
fn pixel_errors(
    id: &str,
    (td, t): (&SceneDesc, &Scene),
    (rd, r): (&SceneDesc, &Scene),
    views: &[View],
) -> Vec<Vec<f64>> {
    let (tt, rt) = (refl(td, id), refl(rd, id));
    let ts = t.shapes.iter().position(|s| s.id == id).unwrap() as u32;
    let rs = r.shapes.iter().position(|s| s.id == id).unwrap() as u32;
    views
        .iter()
        .map(|v| {
            let cam = &v.camera;
            let mut e = vec![f64::NAN; cam.width * cam.height];
            for y in 0..cam.height {
                for x in 0..cam.width {
                    let (mut sg, mut st, mut k) = ([0f64; 3], [0f64; 3], 0usize);
                    for j in 0..16 {
                        let p = Vec2::new(
                            x as f32 + ((j % 4) as f32 + 0.5) / 4.0,
                            y as f32 + ((j / 4) as f32 + 0.5) / 4.0,
                        );
                        let ray = cam.generate_ray(p);
                        let (Some(ht), Some(hr)) = (t.intersect(&ray), r.intersect(&ray)) else { continue };
                        if ht.shape != ts || hr.shape != rs {
                            continue;
                        }
                        let (g, tv) = (eval_texture(rt, hr.uv), eval_texture(tt, ht.uv));
                        for c in 0..3 {
                            sg[c] += g[c] as f64;
                            st[c] += tv[c] as f64;
                        }
                        k += 1;
                    }
                    if k > 0 {
                        e[y * cam.width + x] = (0..3).map(|c| ((sg[c] - st[c]) / k as f64).powi(2)).sum();
                    }
                }
            }
            e
        })
        .collect()
}

fn psnr(se: f64, n: usize) -> f64 {
    10.0 * (3.0 * n as f64 / se).log10()
}

struct Bins {
    name: &'static str,
    labels: Vec<&'static str>,
    se: Vec<f64>,
    n: Vec<usize>,
}

impl Bins {
    fn new(name: &'static str, labels: &[&'static str]) -> Self {
        Bins { name, labels: labels.to_vec(), se: vec![0.0; labels.len()], n: vec![0; labels.len()] }
    }
    fn add(&mut self, b: usize, e: f64) {
        self.se[b] += e;
        self.n[b] += 1;
    }
    fn print(&self) {
        let tot: f64 = self.se.iter().sum();
        let nt: usize = self.n.iter().sum();
        let mut s = format!("  by {}:", self.name);
        for k in 0..self.labels.len() {
            if self.n[k] > 0 {
                s += &format!(
                    " [{} {:.0}% px, {:.0}% err, {:.1} dB]",
                    self.labels[k],
                    100.0 * self.n[k] as f64 / nt as f64,
                    100.0 * self.se[k] / tot,
                    psnr(self.se[k], self.n[k])
                );
            }
        }
        println!("{s}");
    }
}

/// Texel distance (8-neighbour rings) to the nearest uncovered texel.
fn border_distance(o: &ObjectResult) -> Vec<u32> {
    let a = &o.atlas;
    let (w, h) = (a.width, a.height);
    let mut d: Vec<u32> = a.texel_tri.iter().map(|&t| if t == NO_TRI { 0 } else { u32::MAX }).collect();
    for k in 0..64 {
        let prev = d.clone();
        let mut changed = false;
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                if prev[i] != u32::MAX {
                    continue;
                }
                let near = (y.saturating_sub(1)..(y + 2).min(h))
                    .any(|yy| (x.saturating_sub(1)..(x + 2).min(w)).any(|xx| prev[yy * w + xx] == k));
                if near {
                    d[i] = k + 1;
                    changed = true;
                }
            }
        }
        if !changed {
            break;
        }
    }
    d
}

/// Tangent of half the horizontal field of view of `cam`.
fn tan_half_fov(cam: &opal::camera::Camera) -> f64 {
    let c = cam.generate_ray(Vec2::new(cam.width as f32 * 0.5, cam.height as f32 * 0.5)).d;
    let e = cam.generate_ray(Vec2::new(cam.width as f32, cam.height as f32 * 0.5)).d;
    let cosv = c.dot(e) as f64;
    (1.0 - cosv * cosv).sqrt() / cosv
}

/// Runs the analysis of object `o` (its recovered scene `r`) and writes its maps into `out`.
pub fn diagnose(
    o: &ObjectResult,
    (td, t): (&SceneDesc, &Scene),
    (rd, r): (&SceneDesc, &Scene),
    views: &[View],
    out: &Path,
) {
    let a = &o.atlas;
    let (w, h) = (a.width, a.height);
    let oracle = oracle_kd(o, td, t);
    let od = with_kd(rd, o, &oracle);
    let os = Scene::build(&od).unwrap();
    let eo = pixel_errors(&o.id, (td, t), (&od, &os), views);
    let er = pixel_errors(&o.id, (td, t), (rd, r), views);
    let sum = |e: &Vec<Vec<f64>>| {
        let (mut s, mut n) = (0f64, 0usize);
        e.iter().flatten().filter(|x| !x.is_nan()).for_each(|x| {
            s += x;
            n += 1
        });
        (s, n)
    };
    let ((so, no), (sr, nr)) = (sum(&eo), sum(&er));
    println!(
        "diag {}: recovered {:.2} dB, oracle atlas (true albedo on the {w}×{h} atlas) {:.2} dB at the cameras",
        o.id,
        psnr(sr, nr),
        psnr(so, no)
    );
    let bd = border_distance(o);
    let rs = r.shapes.iter().position(|s| s.id == o.id).unwrap() as u32;
    let mut b_border = Bins::new("texel distance to chart border", &["0-1", "2", "3-4", "5-8", ">8"]);
    let mut b_views = Bins::new("views seeing the point", &["1", "2", "3", "4+"]);
    let mut b_cos = Bins::new("cos θ to this view", &["<0.25", "0.25-0.5", "0.5-0.75", ">0.75"]);
    let mut b_sil = Bins::new("silhouette", &["inner", "silhouette±1px"]);
    let mut b_dens = Bins::new("pixel footprint / texel area", &["<0.5", "0.5-1", "1-2", "2-4", ">4"]);
    let mut b_obs = Bins::new("observed (L)", &["observed", "not observed"]);
    for (vi, v) in views.iter().enumerate() {
        let cam = &v.camera;
        let (cw, ch) = (cam.width, cam.height);
        let tanh = tan_half_fov(cam);
        let hits: Vec<Option<opal::scene::build::SurfaceInteraction>> = (0..cw * ch)
            .map(|k| r.intersect(&cam.generate_ray(Vec2::new((k % cw) as f32 + 0.5, (k / cw) as f32 + 0.5))))
            .collect();
        for k in 0..cw * ch {
            let e = er[vi][k];
            if e.is_nan() {
                continue;
            }
            let Some(hr) = hits[k].as_ref().filter(|hh| hh.shape == rs) else { continue };
            let (tx, ty) = ((hr.uv.x * w as f32) as usize, (hr.uv.y * h as f32) as usize);
            let ti = ty.min(h - 1) * w + tx.min(w - 1);
            b_border.add(
                match bd[ti] {
                    0..=1 => 0,
                    2 => 1,
                    3..=4 => 2,
                    5..=8 => 3,
                    _ => 4,
                },
                e,
            );
            b_obs.add(if o.observed[ti] { 0 } else { 1 }, e);
            let mut nv = 0;
            for u in views {
                let dv = u.camera.origin() - hr.p;
                if dv.dot(hr.ng) <= 0.0 || u.camera.project(hr.p).is_none() {
                    continue;
                }
                let dist = dv.length();
                let mut ray = Ray::new(hr.p + hr.ng * 1e-4, dv / dist);
                ray.tmax = dist * 0.999;
                if !r.occluded(&ray) {
                    nv += 1;
                }
            }
            b_views.add((nv.max(1) - 1).min(3), e);
            let cos = (cam.origin() - hr.p).normalize().dot(hr.ng).abs();
            b_cos.add(((cos * 4.0) as usize).min(3), e);
            let (x, y) = (k % cw, k / cw);
            let sil = (y.saturating_sub(1)..(y + 2).min(ch)).any(|yy| {
                (x.saturating_sub(1)..(x + 2).min(cw))
                    .any(|xx| hits[yy * cw + xx].as_ref().is_none_or(|q| q.shape != rs))
            });
            b_sil.add(sil as usize, e);
            // pixel footprint (approximate: pixel pitch at the distance, over cos θ) / texel area
            let tri = hr.prim - r.shapes[rs as usize].first_prim;
            let ta = a.texel_area[tri as usize] as f64;
            let dist = (hr.p - cam.origin()).length() as f64;
            let px = 2.0 * tanh / cw as f64;
            let ratio = (px * dist).powi(2) / (cos.max(1e-3) as f64) / ta.max(1e-12);
            let bin = [0.5, 1.0, 2.0, 4.0].iter().filter(|&&b| ratio >= b).count();
            b_dens.add(bin, e);
        }
        let mut img = Image::new(cw, ch);
        for k in 0..cw * ch {
            let e = er[vi][k];
            if !e.is_nan() {
                img.data[k] = Spectrum([(e / 3.0).sqrt() as f32, (eo[vi][k] / 3.0).sqrt() as f32, 0.0]);
            }
        }
        write(&img, &out.join(format!("{}_{}_err.exr", o.id, v.name)));
    }
    for b in [&b_border, &b_views, &b_cos, &b_sil, &b_dens, &b_obs] {
        b.print();
    }
    // texture space
    let n = w * h;
    let diff: Vec<[f32; 3]> = (0..n)
        .map(|i| if o.observed[i] { std::array::from_fn(|c| o.kd[i][c] - oracle[i][c]) } else { [0.0; 3] })
        .collect();
    let low = smooth_in_charts(&diff, a, (w / 64).max(1));
    let (mut st, mut sl, mut cnt, mut rel_l) = (0f64, 0f64, 0usize, 0f64);
    for i in 0..n {
        if !o.observed[i] {
            continue;
        }
        cnt += 1;
        for c in 0..3 {
            st += (diff[i][c] as f64).powi(2);
            sl += (low[i][c] as f64).powi(2);
        }
        rel_l += (luminance(diff[i]) / luminance(oracle[i]).max(1e-3)) as f64;
    }
    println!(
        "  texture space ({cnt} observed texels): {:.2} dB; low-frequency part (r = {}) {:.2} dB ({:.0}% of the \
         squared error); mean relative luminance error {:+.2}%",
        psnr(st, cnt),
        (w / 64).max(1),
        psnr(sl, cnt),
        100.0 * sl / st,
        100.0 * rel_l / cnt as f64
    );
    let mut img = Image::new(w, h);
    for i in 0..n {
        img.data[i] = Spectrum([luminance(diff[i]), luminance(low[i]), luminance(oracle[i])]);
    }
    write(&img, &out.join(format!("{}_texdiff.exr", o.id)));
}
