//! Direct irradiance per texel (step 4 of the pipeline): light sampling with stratified
//! positions and shadow rays, every light at every texel with the closed-form unoccluded
//! irradiance of triangle lights and of delta lights (point, spot, directional: one incident
//! direction) as a control variate; environment lights (`constant`, `envmap`),
//! when the scene has at most [`MAX_LIGHTS_PER_TEXEL`] lights, by their importance sampling
//! combined with as many cosine-weighted directions by multiple importance sampling
//! ([`env_direct`]; unbounded shadow rays; no closed form, so always at the full count), by the
//! map's sampling alone with the power-proportional light choice otherwise; an adaptive pilot
//! re-estimates only penumbra texels with the full sample count.
//! Tests (below): the closed form against quadrature, the adaptive estimate against the
//! full one, and a floor under a directional, a spot and a constant environment light against
//! their analytic irradiance.

// Index loops over parallel per-texel arrays read more clearly than zipped iterators here.
#![allow(clippy::needless_range_loop)]

use super::atlas::{Atlas, NO_TRI};
use super::progress::{Progress, Stage};
use opal::math::{Vec2, Vec3};
use opal::sampling::Rng;
use opal::scene::Scene;
use std::sync::atomic::{AtomicU64, Ordering};

/// Direct irradiance per texel (step 4): `samples` light samples per texel (and per light when
/// every light is sampled at every texel, see [`MAX_LIGHTS_PER_TEXEL`]).
///
/// With `pilot > 0` (and every light sampled with its closed-form control variate) the work is
/// adaptive: every texel first takes `pilot` stratified samples per light; where each light is
/// seen either by all of them or by none, the ratio estimator already gives the closed-form
/// value (fully lit) or 0 (fully shadowed), which is what the full count gives there too. Only
/// texels whose pilot saw a light partly occluded — the penumbrae — or none of whose pilot
/// samples reached a light that is above the horizon, and their neighbours within
/// [`PENUMBRA_DILATION`] texels (a penumbra's faint fringe, where a small occluded fraction can
/// slip between the pilot's samples) are estimated again with the full `samples`, by exactly the
/// estimator and random numbers of the non-adaptive run. Deterministic for a given seed.
pub fn direct_irradiance(
    scene: &Scene,
    a: &Atlas,
    samples: u32,
    pilot: u32,
    seed: u64,
    stream: u64,
) -> Vec<[f32; 3]> {
    direct_irradiance_split(scene, a, (samples, pilot), seed, stream, &opal::dist::Solo)
}

/// [`direct_irradiance`] (`(samples, pilot)`) with the texels split across the processes of
/// `comm` ([`direct_irradiance_many`] of one atlas): every rank returns the full map — the same
/// bits as one process computes.
pub fn direct_irradiance_split(
    scene: &Scene,
    a: &Atlas,
    samples: (u32, u32),
    seed: u64,
    stream: u64,
    comm: &dyn opal::dist::Comm,
) -> Vec<[f32; 3]> {
    let mut maps = direct_irradiance_many(scene, &[a], samples, seed, &[stream], comm, None);
    maps.pop().expect("one map per atlas")
}

/// [`direct_irradiance`] (`(samples, pilot)`) of several atlases (atlas `j` seeded with
/// `streams[j]`), split across the processes of `comm`. The units are the covered texels of all
/// atlases together (an uncovered texel is 0 without any work), the `k`-th on rank `k mod size`;
/// each texel's random numbers depend on its atlas's stream, its index and the seed only. The
/// pilot's results of all atlases are exchanged in one step, then the re-estimated (dilated)
/// penumbra texels of all atlases in a second, so the processes share the whole stage evenly and
/// meet twice. Every rank returns every map — the same bits as one process computes, atlas by
/// atlas.
///
/// `progress` ([`super::progress`]): stage `direct` counts this process's texels of the first
/// pass (the pilot, or the only pass), stage `direct penumbrae` those re-estimated at the full
/// count, both as they finish inside the split (the counts only: the values do not depend on it).
pub fn direct_irradiance_many(
    scene: &Scene,
    atlases: &[&Atlas],
    (samples, pilot): (u32, u32),
    seed: u64,
    streams: &[u64],
    comm: &dyn opal::dist::Comm,
    progress: Option<&Progress>,
) -> Vec<Vec<[f32; 3]>> {
    use opal::dist::map_units;
    assert_eq!(atlases.len(), streams.len(), "one stream per atlas");
    let put = |e: &[f32; 3], p: &mut opal::dist::Packer| p.f32s(e);
    let mut out: Vec<Vec<[f32; 3]>> = atlases.iter().map(|a| vec![[0.0; 3]; a.width * a.height]).collect();
    if scene.light_sampler().is_none() {
        // no light: nothing to estimate (the stage is reported done)
        drop(Stage::start(progress, "direct", 0));
        return out;
    }
    // the covered texels of all atlases: (atlas, texel)
    let covered: Vec<(u32, u32)> = atlases
        .iter()
        .enumerate()
        .flat_map(|(j, a)| {
            (0..a.width * a.height).filter(|&i| a.texel_tri[i] != NO_TRI).map(move |i| (j as u32, i as u32))
        })
        .collect();
    let side = (samples.max(1) as f32).sqrt().ceil() as u32;
    let pilot_side = (pilot as f32).sqrt().ceil() as u32;
    let per_light = scene.lights.len() <= MAX_LIGHTS_PER_TEXEL;
    // texel `i` of atlas `j` with `side`² samples on the stream `stream ^ xor`
    let texel = |(j, i): (u32, u32), side: u32, xor: u64| {
        let (j, i) = (j as usize, i as usize);
        texel_direct(scene, atlases[j], i, side, &mut Rng::new(seed, streams[j] ^ xor, i as u64))
    };
    let first_bar = Ticker::start(progress, "direct", comm, covered.len());
    if !per_light || pilot == 0 || pilot_side >= side {
        let vals = map_units(
            comm,
            covered.len(),
            |k| first_bar.after(texel(covered[k], side, 0).0),
            put,
            |u| u.rgb(),
        );
        drop(first_bar);
        for (&(j, i), e) in covered.iter().zip(vals) {
            out[j as usize][i as usize] = e;
        }
        return out;
    }
    // pilot pass (its own random stream), then the penumbrae (dilated) at the full count
    let first: Vec<([f32; 3], bool)> = map_units(
        comm,
        covered.len(),
        |k| first_bar.after(texel(covered[k], pilot_side, PILOT_STREAM)),
        |(e, m), p| {
            p.f32s(e);
            p.u8(*m as u8);
        },
        |u| (u.rgb(), u.u8() != 0),
    );
    drop(first_bar);
    let mut mixed: Vec<Vec<bool>> = atlases.iter().map(|a| vec![false; a.width * a.height]).collect();
    for (&(j, i), (e, m)) in covered.iter().zip(first) {
        out[j as usize][i as usize] = e;
        mixed[j as usize][i as usize] = m;
    }
    // an uncovered texel in a dilated penumbra stays 0 (what its full estimate gives)
    let mut redo_idx: Vec<(u32, u32)> = Vec::new();
    for (j, (a, m)) in atlases.iter().zip(&mixed).enumerate() {
        let redo = dilate_mask(m, a.width, a.height, PENUMBRA_DILATION);
        redo_idx.extend(
            (0..redo.len()).filter(|&i| redo[i] && a.texel_tri[i] != NO_TRI).map(|i| (j as u32, i as u32)),
        );
    }
    drop(mixed);
    let bar = Ticker::start(progress, "direct penumbrae", comm, redo_idx.len());
    let again =
        map_units(comm, redo_idx.len(), |k| bar.after(texel(redo_idx[k], side, 0).0), put, |u| u.rgb());
    drop(bar);
    for (&(j, i), e) in redo_idx.iter().zip(again) {
        out[j as usize][i as usize] = e;
    }
    out
}

/// Progress of one pass of [`direct_irradiance_many`] over `n` units split across the processes:
/// a stage of this process's share, stepped from inside the split every `every` units (about
/// 200 reports per stage) and completed when dropped.
struct Ticker<'a> {
    stage: Stage<'a>,
    done: AtomicU64,
    every: u64,
}

impl<'a> Ticker<'a> {
    fn start(p: Option<&'a Progress>, name: &str, comm: &dyn opal::dist::Comm, n: usize) -> Ticker<'a> {
        let share = if comm.size() == 1 { n } else { n.saturating_sub(comm.rank()).div_ceil(comm.size()) };
        let share = share as u64;
        Ticker { stage: Stage::start(p, name, share), done: AtomicU64::new(0), every: (share / 200).max(1) }
    }

    /// One unit done; passes its value through.
    fn after<T>(&self, v: T) -> T {
        let d = self.done.fetch_add(1, Ordering::Relaxed) + 1;
        if d.is_multiple_of(self.every) {
            self.stage.step(self.every);
        }
        v
    }
}

/// Texels around a penumbra texel found by the pilot of [`direct_irradiance`] that are estimated
/// with the full sample count too (square neighbourhood of this radius).
pub const PENUMBRA_DILATION: usize = 2;

/// Stream offset of the pilot samples of [`direct_irradiance`].
const PILOT_STREAM: u64 = 0x9170_7000;

/// Square dilation (radius `r`) of a mask on a `w`×`h` grid (separable max).
fn dilate_mask(m: &[bool], w: usize, h: usize, r: usize) -> Vec<bool> {
    let mut t = vec![false; m.len()];
    for y in 0..h {
        for x in 0..w {
            t[y * w + x] = (x.saturating_sub(r)..(x + r + 1).min(w)).any(|xx| m[y * w + xx]);
        }
    }
    let mut out = vec![false; m.len()];
    for y in 0..h {
        for x in 0..w {
            out[y * w + x] = (y.saturating_sub(r)..(y + r + 1).min(h)).any(|yy| t[yy * w + x]);
        }
    }
    out
}

/// Direct irradiance at texel `i` with `side`² stratified samples (per light when the scene has
/// at most [`MAX_LIGHTS_PER_TEXEL`] lights), and whether the estimate is not exact: some light
/// seen by part of its samples only, or a light without a closed-form irradiance, or lights
/// chosen at random (many lights).
fn texel_direct(scene: &Scene, a: &Atlas, i: usize, side: u32, rng: &mut Rng) -> ([f32; 3], bool) {
    if a.texel_tri[i] == NO_TRI {
        return ([0.0; 3], false);
    }
    let Some(ls) = scene.light_sampler() else { return ([0.0; 3], false) };
    let n = side * side;
    // few lights: every light gets its own stratified samples, and each triangle light's
    // unoccluded irradiance is known in closed form, so only its visible fraction is estimated
    // (ratio control variate: exact wherever the light is fully visible or fully hidden)
    let per_light = scene.lights.len() <= MAX_LIGHTS_PER_TEXEL;
    let (p, ng, ns) = (a.texel_p[i], a.texel_ng[i], a.texel_n[i]);
    let mut e = [0f64; 3];
    // one light sample: (weight Li·cos/pdf, visible?) or None below the horizon
    let sample = |li: usize, u: Vec2, pmf: f32| -> Option<([f32; 3], bool)> {
        let s = scene.lights[li].sample_li(p, u)?;
        if s.pdf <= 0.0 || pmf <= 0.0 {
            return None;
        }
        let cos = ns.dot(s.wi);
        if cos <= 0.0 || ng.dot(s.wi) <= 0.0 {
            return None;
        }
        let w = cos / (pmf * s.pdf);
        let vis = !scene.occluded(&s.shadow_ray(p, ng));
        Some((std::array::from_fn(|c| s.li[c] * w), vis))
    };
    let strat = |k: u32, rng: &mut Rng| {
        let (sx, sy) = (k % side, k / side);
        Vec2::new((sx as f32 + rng.next_f32()) / side as f32, (sy as f32 + rng.next_f32()) / side as f32)
    };
    if per_light {
        let mut mixed = false;
        for li in 0..scene.lights.len() {
            if matches!(scene.lights[li], opal::light::Light::Env(_)) {
                let ev = env_direct(scene, &scene.lights[li], (p, ng, ns), side, rng);
                for c in 0..3 {
                    e[c] += ev[c];
                }
                // no closed form: a pilot that saw the map entirely hidden (or below the
                // horizon) proves nothing, so the full count always decides
                mixed = true;
                continue;
            }
            let (mut all, mut vis) = ([0f64; 3], [0f64; 3]);
            let (mut seen, mut hidden) = (false, false);
            for k in 0..n {
                let u = strat(k, rng);
                if let Some((w, v)) = sample(li, u, 1.0) {
                    if v {
                        seen = true;
                    } else {
                        hidden = true;
                    }
                    for c in 0..3 {
                        all[c] += w[c] as f64;
                        if v {
                            vis[c] += w[c] as f64;
                        }
                    }
                }
            }
            let exact = match &scene.lights[li] {
                opal::light::Light::Triangle(t) => triangle_irradiance(t, p, ns),
                l if l.is_delta() => Some(delta_irradiance(l, p, ng, ns)),
                _ => None,
            };
            // not exact: a light partly occluded; no closed form; or a light above the horizon
            // that no sample reached (it grazes the horizon: the full count may reach it)
            let grazing = !seen && !hidden && exact.is_some_and(|ex| ex.iter().any(|&v| v > 0.0));
            mixed |= (seen && (hidden || exact.is_none())) || grazing;
            for c in 0..3 {
                e[c] += match exact {
                    Some(ex) if all[c] > 0.0 => ex[c] as f64 * vis[c] / all[c],
                    _ => vis[c] / n as f64,
                };
            }
        }
        return (e.map(|v| v as f32), mixed);
    }
    for k in 0..n {
        let u = strat(k, rng);
        let (li, pmf, _) = ls.sample(rng.next_f32());
        if let Some((w, true)) = sample(li, u, pmf) {
            for c in 0..3 {
                e[c] += w[c] as f64;
            }
        }
    }
    (e.map(|v| (v / n as f64) as f32), true)
}

/// Irradiance at `p` (geometric normal `ng`, shading normal `ns`) from an environment light
/// `l`: `side`² stratified samples of the map's importance sampling and as many stratified
/// cosine-weighted directions, combined by the balance heuristic (multiple importance
/// sampling), each with its shadow ray. The map's sampling follows its luminance, so a small
/// bright sun takes most of its samples while a large dim sky of another colour (blue) is
/// sampled rarely; the cosine directions cover that sky. Per-texel noise matters beyond its
/// average: `Kd = πL/(Ed + Ei)` is a ratio, biased upwards by `Ed`'s relative variance.
fn env_direct(
    scene: &Scene,
    l: &opal::light::Light,
    (p, ng, ns): (Vec3, Vec3, Vec3),
    side: u32,
    rng: &mut Rng,
) -> [f64; 3] {
    let inv_pi = std::f32::consts::FRAC_1_PI;
    let frame = opal::math::Frame::from_normal(ns);
    let mut e = [0f64; 3];
    let n = side * side;
    let strat = |k: u32, rng: &mut Rng| {
        let (sx, sy) = (k % side, k / side);
        Vec2::new((sx as f32 + rng.next_f32()) / side as f32, (sy as f32 + rng.next_f32()) / side as f32)
    };
    let mut add = |li: opal::spectrum::Spectrum, w: f32, wi: Vec3| {
        if !scene.occluded(&opal::integrator::spawn_ray(p, ng, wi)) {
            for c in 0..3 {
                e[c] += (li[c] * w) as f64;
            }
        }
    };
    for k in 0..n {
        let (u_light, u_cos) = (strat(k, rng), strat(k, rng));
        // the map's sample
        if let Some(s) = l.sample_li(p, u_light) {
            let cos = ns.dot(s.wi);
            if s.pdf > 0.0 && cos > 0.0 && ng.dot(s.wi) > 0.0 {
                add(s.li, cos / (s.pdf + cos * inv_pi), s.wi);
            }
        }
        // the cosine-weighted direction
        let local = opal::sampling::square_to_cosine_hemisphere(u_cos);
        let wi = frame.to_world(local);
        let pc = local.z * inv_pi;
        if pc > 0.0 && ng.dot(wi) > 0.0 {
            let li = l.le_escaped(wi);
            if !li.is_black() {
                add(li, local.z / (l.pdf_escaped(wi) + pc), wi);
            }
        }
    }
    e.map(|v| v / n as f64)
}

/// Unoccluded irradiance (cosine-weighted about `ns`) at `p` from a light that is a delta in
/// position or direction (point, spot, directional): its one incident direction's `Li·cos`
/// (zero below the horizon of `ns` or `ng`). Every sample of such a light is this value, so the
/// ratio estimator is exact and only the visibility is estimated.
fn delta_irradiance(l: &opal::light::Light, p: Vec3, ng: Vec3, ns: Vec3) -> [f32; 3] {
    let Some(s) = l.sample_li(p, Vec2::splat(0.5)) else { return [0.0; 3] };
    let cos = ns.dot(s.wi);
    if cos <= 0.0 || ng.dot(s.wi) <= 0.0 || s.pdf <= 0.0 {
        return [0.0; 3];
    }
    let w = cos / s.pdf;
    std::array::from_fn(|c| s.li[c] * w)
}

/// Scenes with at most this many lights (emitting triangles, point, spot, directional and
/// environment lights) sample every light at every
/// texel (with the closed-form control variate); larger ones choose lights by power.
pub const MAX_LIGHTS_PER_TEXEL: usize = 16;

/// Unoccluded irradiance (cosine-weighted about `n`) at `p` from a uniformly emitting,
/// one-sided triangle light, in closed form (Lambert's polygon formula on the triangle clipped
/// to the hemisphere of `n`): `E = L/2 · |Σ_k θ_k (n · γ_k)|`, θ_k the angle subtended by edge
/// k, γ_k the unit normal of the plane through `p` and that edge. `None` for degenerate cases.
fn triangle_irradiance(t: &opal::light::TriangleLight, p: Vec3, n: Vec3) -> Option<[f32; 3]> {
    // the emitting side must face p
    if t.n.dot(p - t.p[0]) <= 0.0 {
        return Some([0.0; 3]);
    }
    // clip the triangle against the half-space n·(x − p) ≥ 0 (Sutherland–Hodgman)
    let mut poly: Vec<Vec3> = Vec::with_capacity(4);
    for k in 0..3 {
        let (a, b) = (t.p[k] - p, t.p[(k + 1) % 3] - p);
        let (da, db) = (n.dot(a) as f64, n.dot(b) as f64);
        if da >= 0.0 {
            poly.push(a);
        }
        if (da >= 0.0) != (db >= 0.0) {
            let s = (da / (da - db)) as f32;
            poly.push(a + (b - a) * s);
        }
    }
    if poly.len() < 3 {
        return Some([0.0; 3]);
    }
    let mut sum = 0f64;
    for k in 0..poly.len() {
        let (va, vb) = (poly[k].normalize_or_zero(), poly[(k + 1) % poly.len()].normalize_or_zero());
        let c = va.cross(vb);
        let len = c.length();
        if len < 1e-12 {
            continue;
        }
        let theta = (len as f64).atan2(va.dot(vb) as f64);
        sum += theta * (n.dot(c / len)) as f64;
    }
    if !sum.is_finite() {
        return None;
    }
    let f = (0.5 * sum.abs()) as f32;
    Some(std::array::from_fn(|c| t.radiance[c] * f))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::delight::{atlas, luminance};
    use opal::light::TriangleLight;

    /// Closed-form unoccluded irradiance of a triangle light vs a brute-force quadrature over the
    /// triangle (E = ∫ L cos θ_p cos θ_l / r² dA, 400² midpoint sub-triangles' centroids), for a
    /// light fully above the horizon, one crossing it (clipped), one behind the receiver and one
    /// facing away.
    #[test]
    fn triangle_irradiance_matches_quadrature() {
        let quad = |t: &TriangleLight, p: Vec3, n: Vec3| -> f64 {
            let m = 400;
            let mut e = 0f64;
            let (a, b, c) = (t.p[0], t.p[1], t.p[2]);
            for i in 0..m {
                for j in 0..m - i {
                    for up in [false, true] {
                        if up && j == m - i - 1 {
                            continue;
                        }
                        let (u, v) = if up {
                            ((i as f64 + 2.0 / 3.0) / m as f64, (j as f64 + 2.0 / 3.0) / m as f64)
                        } else {
                            ((i as f64 + 1.0 / 3.0) / m as f64, (j as f64 + 1.0 / 3.0) / m as f64)
                        };
                        let x = a + (b - a) * u as f32 + (c - a) * v as f32;
                        let d = x - p;
                        let r2 = d.length_squared() as f64;
                        let w = d / d.length();
                        let cp = (n.dot(w) as f64).max(0.0);
                        let cl = (-t.n.dot(w) as f64).max(0.0);
                        e += cp * cl / r2;
                    }
                }
            }
            e * t.area as f64 / (m * m) as f64
        };
        let light =
            |p: [Vec3; 3]| TriangleLight::new(p, opal::spectrum::Spectrum([1.0, 2.0, 0.5]), 0).unwrap();
        let p = Vec3::ZERO;
        let n = Vec3::Z;
        // above, facing down (CCW seen from below)
        let t1 = light([Vec3::new(-0.5, -0.4, 1.0), Vec3::new(0.6, -0.3, 1.0), Vec3::new(0.1, 0.7, 1.2)]);
        let t1 = if t1.n.z < 0.0 { t1 } else { light([t1.p[0], t1.p[2], t1.p[1]]) };
        // crossing the horizon, tilted towards p
        let t2 = light([Vec3::new(0.3, -0.5, -0.4), Vec3::new(0.4, 0.6, -0.3), Vec3::new(0.5, 0.0, 0.9)]);
        let t2 = if t2.n.x < 0.0 { t2 } else { light([t2.p[0], t2.p[2], t2.p[1]]) };
        for t in [&t1, &t2] {
            let ex = triangle_irradiance(t, p, n).unwrap();
            let q = quad(t, p, n);
            assert!(q > 0.01, "{q}");
            for c in 0..3 {
                let want = q * t.radiance[c] as f64;
                assert!(((ex[c] as f64) - want).abs() < 2e-3 * want, "channel {c}: {} vs {want}", ex[c]);
            }
        }
        // behind the receiver's horizon entirely, and facing away
        let t3 = light([Vec3::new(-0.5, -0.4, -1.0), Vec3::new(0.6, -0.3, -1.0), Vec3::new(0.1, 0.7, -1.2)]);
        assert_eq!(triangle_irradiance(&t3, p, n).unwrap(), [0.0; 3]);
        let t4 = light([t1.p[0], t1.p[2], t1.p[1]]);
        assert_eq!(triangle_irradiance(&t4, p, n).unwrap(), [0.0; 3]);
    }

    /// The adaptive direct irradiance (16-sample pilot, 64 samples in the dilated penumbrae)
    /// against the non-adaptive 64-sample estimator on the floor and the short box of the bundled
    /// Cornell box: both see the boxes' penumbrae (which the adaptive one re-estimates with the
    /// same random numbers, so bitwise equal there), and they differ on few texels — the faint
    /// fringes the pilot missed — by little (measured on the reference resolutions with the
    /// `direct_adaptive` example: ≤ 0.5 % of the texels, ≤ 3.5 % of the mean).
    #[test]
    fn adaptive_direct_matches_full_count() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../opal/tests/data/cbox");
        let mut desc = opal::scene::load::load_mitsuba_xml(&dir.join("scene.xml"), &[]).unwrap();
        let mut atlases = Vec::new();
        for id in ["floor", "short_box"] {
            let k = desc.shapes.iter().position(|s| s.id == id).unwrap();
            let a = atlas::build_atlas(&desc.shapes[k].mesh, 96, true).unwrap();
            desc.shapes[k].mesh = a.mesh.clone();
            atlases.push(a);
        }
        let scene = Scene::build(&desc).unwrap();
        for a in &atlases {
            let full = direct_irradiance(&scene, a, 64, 0, 5, 9);
            let adapt = direct_irradiance(&scene, a, 64, 16, 5, 9);
            let other = direct_irradiance(&scene, a, 64, 0, 6, 9);
            let covered: Vec<usize> = (0..full.len()).filter(|&i| a.texel_tri[i] != NO_TRI).collect();
            let mean = covered.iter().map(|&i| luminance(full[i]) as f64).sum::<f64>() / covered.len() as f64;
            // penumbra texels: the full estimator is random there (two seeds differ)
            let pen: Vec<usize> = covered.iter().copied().filter(|&i| full[i] != other[i]).collect();
            assert!(pen.len() > covered.len() / 200, "{} penumbra texels of {}", pen.len(), covered.len());
            let same_pen = pen.iter().filter(|&&i| full[i] == adapt[i]).count();
            let differ_n = covered.iter().filter(|&&i| full[i] != adapt[i]).count();
            // measured: floor 2951 of 2951 penumbra texels re-estimated, 0 texels differ; short
            // box 239 of 243, 5 differ (its 96² charts make the penumbrae a few texels narrow)
            println!(
                "{} penumbra texels of {}, {same_pen} re-estimated; {differ_n} differ",
                pen.len(),
                covered.len()
            );
            assert!(
                same_pen as f64 >= 0.95 * pen.len() as f64,
                "{same_pen} of {} penumbra texels",
                pen.len()
            );
            let differ: Vec<usize> = covered.iter().copied().filter(|&i| full[i] != adapt[i]).collect();
            assert!(
                differ.len() * 100 <= covered.len(),
                "{} of {} texels differ",
                differ.len(),
                covered.len()
            );
            for &i in &differ {
                let d = (luminance(full[i]) - luminance(adapt[i])).abs() as f64 / mean;
                assert!(d < 0.1, "texel {i}: {:?} vs {:?}", full[i], adapt[i]);
            }
        }
    }

    /// The bits of a texel map.
    fn bits(v: &[[f32; 3]]) -> Vec<u32> {
        v.iter().flat_map(|e| e.map(f32::to_bits)).collect()
    }

    /// The texels split across 2 and 3 ranks (threads), with the adaptive pilot (its results and
    /// the re-estimated penumbrae exchanged) and without: every rank gets the map of one process,
    /// bit for bit.
    #[test]
    fn split_across_ranks_gives_the_same_bits() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../opal/tests/data/cbox");
        let mut desc = opal::scene::load::load_mitsuba_xml(&dir.join("scene.xml"), &[]).unwrap();
        let k = desc.shapes.iter().position(|s| s.id == "floor").unwrap();
        let a = atlas::build_atlas(&desc.shapes[k].mesh, 32, true).unwrap();
        desc.shapes[k].mesh = a.mesh.clone();
        let scene = Scene::build(&desc).unwrap();
        for pilot in [0, 4] {
            let want = direct_irradiance(&scene, &a, 16, pilot, 5, 9);
            for n in [2, 3] {
                let all = opal::dist::ThreadComm::run(n, |c| {
                    direct_irradiance_split(&scene, &a, (16, pilot), 5, 9, c)
                });
                for got in all {
                    assert_eq!(bits(&got), bits(&want), "pilot {pilot}, {n} ranks");
                }
            }
        }
    }

    /// Several atlases in one split (the floor and the short box of the Cornell box, each with
    /// its own stream; their covered texels the units of one exchange per step): on 1, 2 and 3
    /// ranks (threads), with and without the pilot, every rank gets each atlas's map of
    /// [`direct_irradiance`] alone, bit for bit.
    #[test]
    fn many_atlases_split_across_ranks_give_each_atlas_its_own_bits() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../opal/tests/data/cbox");
        let mut desc = opal::scene::load::load_mitsuba_xml(&dir.join("scene.xml"), &[]).unwrap();
        let mut atlases = Vec::new();
        for (id, res) in [("floor", 32), ("short_box", 24)] {
            let k = desc.shapes.iter().position(|s| s.id == id).unwrap();
            let a = atlas::build_atlas(&desc.shapes[k].mesh, res, true).unwrap();
            desc.shapes[k].mesh = a.mesh.clone();
            atlases.push(a);
        }
        let scene = Scene::build(&desc).unwrap();
        let refs: Vec<&Atlas> = atlases.iter().collect();
        let streams = [9, 10];
        for pilot in [0, 4] {
            let want: Vec<Vec<u32>> = atlases
                .iter()
                .zip(streams)
                .map(|(a, st)| bits(&direct_irradiance(&scene, a, 16, pilot, 5, st)))
                .collect();
            for n in [1, 2, 3] {
                let all = opal::dist::ThreadComm::run(n, |c| {
                    direct_irradiance_many(&scene, &refs, (16, pilot), 5, &streams, c, None)
                });
                for got in all {
                    let got: Vec<Vec<u32>> = got.iter().map(|m| bits(m)).collect();
                    assert_eq!(got, want, "pilot {pilot}, {n} ranks");
                }
            }
        }
    }

    /// A floor (2 × 2, facing +y) under one light at a time: a directional light (E = E₀ cos θ,
    /// exact at every texel), a spot (E = I(θ) cos θ / d², exact) and a constant environment
    /// (E = π L; importance-sampled, the texels' mean within 1 %).
    #[test]
    fn delta_and_environment_lights_match_analytic_irradiance() {
        use opal::scene::desc::{BsdfDesc, EmitterDesc, SceneDesc, ShapeDesc, TextureDesc};
        use opal::spectrum::Spectrum;
        let mut floor = opal::scene::load::rectangle_mesh();
        for p in &mut floor.positions {
            *p = Vec3::new(p.x, 0.0, -p.y); // z-up rectangle → y-up floor, still CCW from +y
        }
        for n in &mut floor.normals {
            *n = Vec3::Y;
        }
        let a = atlas::build_atlas(&floor, 32, true).unwrap();
        let run = |e: EmitterDesc| {
            let desc = SceneDesc {
                shapes: vec![ShapeDesc {
                    id: "floor".into(),
                    mesh: a.mesh.clone(),
                    bsdf: BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(Spectrum::splat(0.5)) },
                    emitter: None,
                    origin: None,
                }],
                emitters: vec![e],
                ..Default::default()
            };
            let scene = Scene::build(&desc).unwrap();
            (direct_irradiance(&scene, &a, 64, 16, 3, 1), scene)
        };
        let covered: Vec<usize> = (0..a.width * a.height).filter(|&i| a.texel_tri[i] != NO_TRI).collect();
        assert!(covered.len() > 500);
        let d = Vec3::new(0.3, -1.0, 0.2).normalize();
        let (e, _) = run(EmitterDesc::Directional { direction: d, irradiance: Spectrum::rgb(1.0, 2.0, 3.0) });
        for &i in &covered {
            for c in 0..3 {
                let want = (c + 1) as f32 * -d.y;
                assert!((e[i][c] - want).abs() < 1e-5 * want, "texel {i}: {:?}", e[i]);
            }
        }
        let tw = opal::math::Mat4::from_translation(Vec3::new(0.2, 1.0, 0.1))
            * opal::math::Mat4::from_rotation_x(std::f32::consts::FRAC_PI_2);
        let spot = EmitterDesc::Spot {
            to_world: tw,
            intensity: Spectrum::splat(2.0),
            cutoff_deg: 40.0,
            beam_width_deg: 20.0,
            texture: None,
        };
        let (e, scene) = run(spot);
        let opal::light::Light::Spot(sp) = &scene.lights[0] else { panic!() };
        let mut lit = 0;
        for &i in &covered {
            let v = sp.position - a.texel_p[i];
            let want = sp.intensity(-v.normalize())[0] * (v.normalize().y) / v.length_squared();
            lit += (want > 0.0) as usize;
            // f32 rounding of the two computations (acos in the falloff ramp): ≤ 10⁻⁴
            assert!((e[i][0] - want).abs() <= 1e-4 * want.max(1e-3), "texel {i}: {} vs {want}", e[i][0]);
        }
        assert!(lit > 100, "{lit}");
        let (e, _) = run(EmitterDesc::Constant { radiance: Spectrum::rgb(0.5, 1.0, 2.0) });
        for c in 0..3 {
            let mean = covered.iter().map(|&i| e[i][c] as f64).sum::<f64>() / covered.len() as f64;
            let want = std::f64::consts::PI * [0.5, 1.0, 2.0][c];
            assert!((mean / want - 1.0).abs() < 0.01, "channel {c}: {mean} vs {want}");
        }
    }
}
