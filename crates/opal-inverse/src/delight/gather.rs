//! Initial indirect irradiance by gathering the *observed* radiance ([`gather_indirect`]).
//!
//! The indirect irradiance at a point is the cosine-weighted integral of the exitant radiance
//! of the (non-emitting) surfaces it sees, `Ei(x) = ∫ L_o(y(x, ω)) cos θ dω`, and the photos
//! measure `L_o` on every recovered object: its luminance map `L` (radiance per texel, holes
//! inpainted). So before any albedo is known, `Ei ≈ π · mean L_o(hit)` over cosine-distributed
//! rays gives the indirect irradiance up to the parts the maps miss (texels no view sees are
//! inpainted from their chart; shapes not being recovered take the area-weighted mean observed
//! radiance; rays that leave the scene see nothing; emitters contribute their emission through
//! `Ed` only). It is the starting point of the light-tracing iterations (the fixed point of
//! `Kd = πL/(Ed + Ei(Kd))` is unchanged; only its start moves).
//!
//! Why: the earlier start `Ei = share · Ed` (or `share` × the scene-average `Ed` where a texel
//! has no direct light) is far off in rooms lit from above: on the scanned-object room of
//! `tests/delight_scan_room.rs` the ceiling (lit only indirectly) started at `Kd = 1` (clamped),
//! the first pass's indirect irradiance came out 2.6× too high everywhere, the under-relaxed
//! fixed point (slope ≈ −2 for surfaces lit only indirectly in a bright room) was still 1.3 %
//! off on the ceiling after 5 passes, and the super-resolution's shading (taken after the first
//! pass) was wrong.
//!
//! Cost: the gather runs on a grid of every `q`-th texel in both directions (`q = ⌈w/128⌉`;
//! indirect light is low-frequency), `rays` stratified cosine-weighted rays each, then a
//! normalised box filter within charts over `q` texels fills every covered texel.
//!
//! Tests: `gather_matches_uniform_enclosure` (inside a closed box whose walls all radiate the
//! same `L`, the gathered irradiance is `πL`), the de-lighting tests in `tests/delight.rs`.

// Index loops over parallel per-texel arrays read more clearly than zipped iterators here.
#![allow(clippy::needless_range_loop)]

use super::atlas::{Atlas, NO_TRI};
use super::{ObjectResult, smooth_in_charts};
use opal::integrator::spawn_ray;
use opal::math::{Frame, Vec2};
use opal::sampling::Rng;
use opal::sampling::square_to_cosine_hemisphere;
use opal::scene::Scene;

/// Bilinear look-up of a texel map at `uv` (texel centres at `(i+½)/w`, clamped).
fn bilinear(v: &[[f32; 3]], w: usize, h: usize, uv: Vec2) -> [f32; 3] {
    let x = (uv.x * w as f32 - 0.5).clamp(0.0, (w - 1) as f32);
    let y = (uv.y * h as f32 - 0.5).clamp(0.0, (h - 1) as f32);
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    std::array::from_fn(|c| {
        (1.0 - fy) * ((1.0 - fx) * v[y0 * w + x0][c] + fx * v[y0 * w + x1][c])
            + fy * ((1.0 - fx) * v[y1 * w + x0][c] + fx * v[y1 * w + x1][c])
    })
}

/// Atlas UV of the point `p` on triangle `tri` of `a`'s mesh.
fn atlas_uv(a: &Atlas, tri: usize, p: opal::math::Vec3) -> Vec2 {
    let t = a.mesh.indices[tri];
    let [p0, p1, p2] = t.map(|i| a.mesh.positions[i as usize]);
    let (v0, v1, v2) = (p1 - p0, p2 - p0, p - p0);
    let (d00, d01, d11) = (v0.dot(v0), v0.dot(v1), v1.dot(v1));
    let (d20, d21) = (v2.dot(v0), v2.dot(v1));
    let den = d00 * d11 - d01 * d01;
    let (b1, b2) = if den.abs() < 1e-30 {
        (0.0, 0.0)
    } else {
        ((d11 * d20 - d01 * d21) / den, (d00 * d21 - d01 * d20) / den)
    };
    let uv = t.map(|i| a.mesh.uvs[i as usize]);
    uv[0] * (1.0 - b1 - b2) + uv[1] * b1 + uv[2] * b2
}

/// Initial indirect irradiance of every object by gathering the objects' luminance maps `L`
/// (see the module documentation): `rays` stratified cosine-weighted rays (rounded down to a
/// square) per gather texel. Returns one map per object (covered texels filled; gutters 0):
/// [`gather_samples`], then [`gathered_map`] of each object.
pub fn gather_indirect(
    scene: &Scene,
    objects: &[ObjectResult],
    rays: u32,
    seed: u64,
    comm: &dyn opal::dist::Comm,
) -> Vec<Vec<[f32; 3]>> {
    let samples = gather_samples(scene, objects, rays, seed, comm);
    objects.iter().zip(&samples).map(|(o, v)| gathered_map(&o.atlas, v)).collect()
}

/// Spacing of the gather texels of an atlas (every `q`-th texel in both directions).
fn gather_spacing(a: &Atlas) -> usize {
    a.width.max(a.height).div_ceil(128).max(1)
}

/// The gather texels of an atlas: every `q`-th texel in both directions (centre of its q×q
/// cell), covered ones only.
fn gather_grid(a: &Atlas) -> Vec<usize> {
    let (w, h, q) = (a.width, a.height, gather_spacing(a));
    (0..w * h).filter(|&i| (i % w) % q == q / 2 && (i / w) % q == q / 2 && a.texel_tri[i] != NO_TRI).collect()
}

/// The gathered irradiance at the gather texels of every object (in the order of its gather
/// grid). The gather texels of all objects are split across the processes of `comm` in one
/// exchange (the `k`-th gather texel over all objects on rank `k mod size`; each seeded by its
/// object and texel index, values exchanged whole): every rank returns what one process
/// computes, bit for bit.
pub fn gather_samples(
    scene: &Scene,
    objects: &[ObjectResult],
    rays: u32,
    seed: u64,
    comm: &dyn opal::dist::Comm,
) -> Vec<Vec<[f32; 3]>> {
    let side = (rays as f64).sqrt().floor().max(1.0) as u32;
    // shape → object
    let mut of_shape = vec![usize::MAX; scene.shapes.len()];
    for (j, o) in objects.iter().enumerate() {
        of_shape[o.shape] = j;
    }
    // radiance of shapes not being recovered: the area-weighted mean observed radiance
    let (mut acc, mut aw) = ([0f64; 3], 0f64);
    for o in objects {
        for i in 0..o.l.len() {
            let t = o.atlas.texel_tri[i];
            if o.observed[i] && t != NO_TRI {
                let ar = o.atlas.texel_area[t as usize] as f64;
                for c in 0..3 {
                    acc[c] += ar * o.l[i][c] as f64;
                }
                aw += ar;
            }
        }
    }
    let mean_l = acc.map(|v| (v / aw.max(1e-30)) as f32);
    let sample = |j: usize, i: usize| -> [f32; 3] {
        let a = &objects[j].atlas;
        let (p, ng, ns) = (a.texel_p[i], a.texel_ng[i], a.texel_n[i]);
        let frame = Frame::from_normal(ns);
        let mut rng = Rng::new(seed, 0x6A7E_0000 + j as u64, i as u64);
        let mut e = [0f64; 3];
        for k in 0..side * side {
            let u = Vec2::new(
                ((k % side) as f32 + rng.next_f32()) / side as f32,
                ((k / side) as f32 + rng.next_f32()) / side as f32,
            );
            let d = frame.to_world(square_to_cosine_hemisphere(u));
            if d.dot(ng) <= 0.0 {
                continue;
            }
            let Some(hit) = scene.intersect(&spawn_ray(p, ng, d)) else { continue };
            let sh = &scene.shapes[hit.shape as usize];
            if sh.emission.is_some() {
                continue;
            }
            let l = match of_shape[hit.shape as usize] {
                usize::MAX => mean_l,
                oj => {
                    let b = &objects[oj].atlas;
                    let tri = (hit.prim - sh.first_prim) as usize;
                    if tri >= b.mesh.indices.len() {
                        mean_l
                    } else {
                        bilinear(&objects[oj].l, b.width, b.height, atlas_uv(b, tri, hit.p))
                    }
                }
            };
            for c in 0..3 {
                e[c] += l[c].max(0.0) as f64;
            }
        }
        e.map(|v| (std::f64::consts::PI * v / (side * side) as f64) as f32)
    };
    // (object, texel) of every gather texel, objects in order
    let units: Vec<(usize, usize)> = objects
        .iter()
        .enumerate()
        .flat_map(|(j, o)| gather_grid(&o.atlas).into_iter().map(move |i| (j, i)))
        .collect();
    let vals: Vec<[f32; 3]> = opal::dist::map_units(
        comm,
        units.len(),
        |k| sample(units[k].0, units[k].1),
        |e, p| p.f32s(e),
        |u| u.rgb(),
    );
    let mut out = vec![Vec::new(); objects.len()];
    for (&(j, _), v) in units.iter().zip(vals) {
        out[j].push(v);
    }
    out
}

/// The initial indirect irradiance map of an object from the values at its gather texels
/// ([`gather_samples`]): a normalised box filter within charts (every covered texel gets the mean
/// of the gather texels of its chart within `q` texels; the object's mean where there is none;
/// gutters 0).
pub fn gathered_map(a: &Atlas, vals: &[[f32; 3]]) -> Vec<[f32; 3]> {
    let (w, h, q) = (a.width, a.height, gather_spacing(a));
    let grid = gather_grid(a);
    assert_eq!(grid.len(), vals.len(), "one value per gather texel");
    let mut v = vec![[0f32; 3]; w * h];
    let mut m = vec![[0f32; 3]; w * h];
    for (&i, e) in grid.iter().zip(vals) {
        v[i] = *e;
        m[i] = [1.0; 3];
    }
    let (sv, sm) = (smooth_in_charts(&v, a, q), smooth_in_charts(&m, a, q));
    let n = vals.len().max(1) as f64;
    let obj_mean: [f32; 3] =
        std::array::from_fn(|c| (vals.iter().map(|e| e[c] as f64).sum::<f64>() / n) as f32);
    (0..w * h)
        .map(|i| {
            if a.texel_tri[i] == NO_TRI {
                [0.0; 3]
            } else if sm[i][0] > 0.0 {
                std::array::from_fn(|c| sv[i][c] / sm[i][0])
            } else {
                obj_mean
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::delight::atlas::build_atlas;
    use crate::delight::footprint::ResolutionChoice;
    use opal::geometry::TriangleMesh;
    use opal::math::Vec3;
    use opal::scene::desc::{BsdfDesc, SceneDesc, ShapeDesc, TextureDesc};
    use opal::spectrum::Spectrum;

    /// The six inward-facing faces of the cube [−1, 1]³, each its own shape, radiating
    /// `l(face)` uniformly: the gathered irradiance at every covered texel.
    fn gather_in_cube(
        l: impl Fn(usize) -> [f32; 3],
        rays: u32,
        comm: &dyn opal::dist::Comm,
    ) -> (Vec<ObjectResult>, Vec<Vec<[f32; 3]>>) {
        let mut desc = SceneDesc::default();
        for f in 0..6 {
            let (axis, s) = (f / 2, if f % 2 == 0 { -1.0f32 } else { 1.0 });
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let corner = |a: f32, b: f32| {
                let mut p = [0f32; 3];
                p[axis] = s;
                p[u] = a;
                p[v] = b;
                Vec3::from_array(p)
            };
            let mut positions = vec![corner(-1., -1.), corner(1., -1.), corner(1., 1.), corner(-1., 1.)];
            // inward normal: −s along the axis
            let n = (positions[1] - positions[0]).cross(positions[2] - positions[0]);
            if n.to_array()[axis] * s > 0.0 {
                positions.reverse();
            }
            let mesh = TriangleMesh { positions, indices: vec![[0, 1, 2], [0, 2, 3]], ..Default::default() };
            desc.shapes.push(ShapeDesc {
                id: format!("face{f}"),
                mesh,
                bsdf: BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(Spectrum([0.5; 3])) },
                emitter: None,
                origin: None,
            });
        }
        let scene = Scene::build(&desc).unwrap();
        let objects: Vec<ObjectResult> = (0..6)
            .map(|k| {
                let a = build_atlas(&desc.shapes[k].mesh, 32, false).unwrap();
                let n = a.width * a.height;
                ObjectResult {
                    shape: k,
                    id: format!("face{k}"),
                    resolution: ResolutionChoice::setting(),
                    l: vec![l(k); n],
                    observed: a.texel_tri.iter().map(|&t| t != NO_TRI).collect(),
                    ed: vec![[0.0; 3]; n],
                    ei: vec![[0.0; 3]; n],
                    kd: vec![[0.0; 3]; n],
                    near_emitter: false,
                    seen_fraction: 1.0,
                    clamped: 0,
                    superres: None,
                    atlas: a,
                }
            })
            .collect();
        let g = gather_indirect(&scene, &objects, rays, 7, comm);
        for (o, m) in objects.iter().zip(&g) {
            for i in 0..m.len() {
                assert_eq!(o.atlas.texel_tri[i] == NO_TRI, m[i] == [0.0; 3], "{} texel {i}", o.id);
            }
        }
        (objects, g)
    }

    /// The bits of a texel map.
    fn bits(v: &[[f32; 3]]) -> Vec<u32> {
        v.iter().flat_map(|e| e.map(f32::to_bits)).collect()
    }

    /// Gather texels split across 2 and 3 ranks (threads): every rank gets the maps of one
    /// process, bit for bit (a dark face and 16 rays: the values differ from texel to texel).
    #[test]
    fn gather_split_across_ranks_gives_the_same_bits() {
        let l = |k: usize| if k == 0 { [0.0; 3] } else { [0.2, 0.5, 1.0] };
        let (_, want) = gather_in_cube(l, 16, &opal::dist::Solo);
        let distinct: std::collections::HashSet<u32> = want[1].iter().map(|e| e[0].to_bits()).collect();
        assert!(distinct.len() > 20, "{} distinct values", distinct.len());
        for n in [2, 3] {
            for got in opal::dist::ThreadComm::run(n, |c| gather_in_cube(l, 16, c).1) {
                for (g, w) in got.iter().zip(&want) {
                    assert_eq!(bits(g), bits(w), "{n} ranks");
                }
            }
        }
    }

    /// Inside a closed box whose walls all radiate `L`, the irradiance is `πL` everywhere (every
    /// gathered ray sees `L`: exact up to rounding). With the face opposite a face dark, the
    /// centre of that face receives `πL (1 − F)`, `F` = 0.2395 the form factor of the centre
    /// of a cube face to the opposite face (point-to-parallel-square formula).
    #[test]
    fn gather_matches_uniform_enclosure() {
        let l = [0.2f32, 0.5, 1.0];
        let (_, g) = gather_in_cube(|_| l, 16, &opal::dist::Solo);
        for m in &g {
            for e in m.iter().filter(|e| **e != [0.0; 3]) {
                for c in 0..3 {
                    assert!((e[c] - std::f32::consts::PI * l[c]).abs() < 1e-4 * l[c], "{e:?}");
                }
            }
        }
        // face 0 (x = −1) dark: the centre of face 1 (x = +1) sees it with F = 0.2395
        let (objects, g) = gather_in_cube(|k| if k == 0 { [0.0; 3] } else { l }, 4096, &opal::dist::Solo);
        let a = &objects[1].atlas;
        let centre = (0..a.texel_p.len())
            .filter(|&i| a.texel_tri[i] != NO_TRI)
            .min_by(|&i, &j| {
                let d = |k: usize| (a.texel_p[k] - Vec3::X).length();
                d(i).total_cmp(&d(j))
            })
            .unwrap();
        assert!((a.texel_p[centre] - Vec3::X).length() < 0.1);
        let want = std::f32::consts::PI * (1.0 - 0.2395);
        for c in 0..3 {
            let got = g[1][centre][c] / l[c];
            assert!((got - want).abs() < 0.02 * want, "channel {c}: {got} vs {want}");
        }
    }
}
