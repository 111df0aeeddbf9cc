//! Per-object stages of [`delight`](super::delight) split across processes
//! ([`DelightSettings::comm`](super::DelightSettings::comm)): each object is processed by one
//! owner rank ([`owners`], balanced by texel count), which then sends the albedo state it changed
//! — `Ei`, `Kd` and the clamped count — and any per-object extra bytes to every other rank
//! ([`exchange_albedo`]). Every stage of an object depends on that object's maps only, so every
//! rank ends with the state one process computes, bit for bit. With one process nothing is sent.
//! Tests: below (ranks simulated by threads, [`opal::dist::ThreadComm`]) and the MPI tier of the
//! CLI (`tests/mpi.rs`: `delight` under 1, 2 and 3 ranks writes the bytes of one process).

use super::ObjectResult;
use opal::dist::{Comm, Packer, Unpacker};

/// Owner rank of each object ([`opal::dist::assign_by_cost`]): balanced by `measured` (the
/// seconds each object took in the previous split stage, the same numbers on every rank) when it
/// has one per object, else by texel count; all 0 for one process. The owners never change the
/// results, only how evenly the ranks are loaded.
pub(super) fn owners(comm: &dyn Comm, objects: &[ObjectResult], measured: &[f64]) -> Vec<usize> {
    if comm.size() == 1 {
        return vec![0; objects.len()];
    }
    let costs: Vec<f64> = if measured.len() == objects.len() {
        measured.to_vec()
    } else {
        objects.iter().map(|o| (o.atlas.width * o.atlas.height) as f64).collect()
    };
    opal::dist::assign_by_cost(&costs, comm.size())
}

/// Sends `Ei`, `Kd` and `clamped` of the objects this rank owns, each with its `extra` bytes
/// (`Some` exactly for the owned objects), to every rank and takes the others' in; returns every
/// object's extra bytes, in object order.
pub(super) fn exchange_albedo(
    comm: &dyn Comm,
    objects: &mut [ObjectResult],
    owner: &[usize],
    extra: Vec<Option<Vec<u8>>>,
) -> Vec<Vec<u8>> {
    let mut p = Packer::default();
    for (j, o) in objects.iter().enumerate().filter(|(j, _)| owner[*j] == comm.rank()) {
        let e = extra[j].as_deref().expect("extra bytes of an owned object");
        p.u64(e.len() as u64);
        p.0.extend_from_slice(e);
        for i in 0..o.kd.len() {
            p.f32s(&o.ei[i]);
            p.f32s(&o.kd[i]);
        }
        p.u64(o.clamped as u64);
    }
    let all = comm.all_gather_bytes(&p.0);
    let mut readers: Vec<Unpacker> = all.iter().map(|b| Unpacker(b)).collect();
    let mut out = Vec::with_capacity(objects.len());
    for (j, o) in objects.iter_mut().enumerate() {
        let u = &mut readers[owner[j]];
        let n = u.u64() as usize;
        let (e, rest) = u.0.split_at(n);
        out.push(e.to_vec());
        u.0 = rest;
        for i in 0..o.kd.len() {
            o.ei[i] = u.rgb();
            o.kd[i] = u.rgb();
        }
        o.clamped = u.u64() as usize;
    }
    assert!(readers.iter().all(|r| r.is_empty()), "a rank sent the maps of another object");
    out
}

/// Runs `f` on every object this rank owns (objects in parallel) and shares the results: the
/// albedo state through [`exchange_albedo`], `f`'s value through `put`/`get`. Returns every
/// object's value, in object order; with one process `f` runs on every object and nothing is
/// packed. Under several processes the owners are balanced by `costs` ([`owners`]), which then
/// receives the seconds `f` took on each object (measured by its owner and shared), so that the
/// next split stage balances by them: the per-object cost varies with more than the texel count
/// (the inpainted holes, the texels light reaches), and a rank waiting for the other at the
/// exchange is time lost by both.
pub(super) fn per_object<T: Send>(
    comm: &dyn Comm,
    objects: &mut [ObjectResult],
    costs: &mut Vec<f64>,
    f: impl Fn(usize, &mut ObjectResult) -> T + Sync + Send,
    put: impl Fn(&T, &mut Packer),
    get: impl Fn(&mut Unpacker) -> T,
) -> Vec<T> {
    use rayon::prelude::*;
    let owner = owners(comm, objects, costs);
    if comm.size() == 1 {
        return objects.par_iter_mut().enumerate().map(|(j, o)| f(j, o)).collect();
    }
    let mine: Vec<Option<(T, f64)>> = objects
        .par_iter_mut()
        .enumerate()
        .map(|(j, o)| {
            (owner[j] == comm.rank()).then(|| {
                let t0 = std::time::Instant::now();
                let t = f(j, o);
                (t, t0.elapsed().as_secs_f64())
            })
        })
        .collect();
    let extra: Vec<Option<Vec<u8>>> = mine
        .iter()
        .map(|t| {
            t.as_ref().map(|(t, secs)| {
                let mut p = Packer::default();
                p.f64(*secs);
                put(t, &mut p);
                p.0
            })
        })
        .collect();
    drop(mine);
    let bytes = exchange_albedo(comm, objects, &owner, extra);
    costs.clear();
    bytes
        .iter()
        .map(|b| {
            let mut u = Unpacker(b);
            costs.push(u.f64());
            let t = get(&mut u);
            assert!(u.is_empty(), "an object's extra bytes of another kind");
            t
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::delight::albedo::update_kd;
    use crate::delight::atlas::{NO_TRI, build_atlas};
    use crate::delight::footprint::ResolutionChoice;
    use opal::dist::{Solo, ThreadComm};
    use opal::geometry::TriangleMesh;
    use opal::math::Vec3;

    /// A value in [0, 1) from a texel's object and index (a fixed integer hash).
    fn hash01(k: usize, i: usize, c: usize) -> f32 {
        let mut x = ((k as u64) << 40) ^ ((i as u64) << 2) ^ c as u64;
        x = x.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        x ^= x >> 29;
        x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        x ^= x >> 32;
        (x >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Five quads of different sizes and atlas resolutions (so the owners differ in texel count),
    /// with luminance and direct irradiance varying from texel to texel; some texels are bright
    /// enough for `Kd` to clamp.
    fn objects() -> Vec<ObjectResult> {
        [(1.0f32, 8usize), (2.0, 24), (0.5, 16), (1.5, 32), (1.0, 12)]
            .iter()
            .enumerate()
            .map(|(k, &(s, res))| {
                let z = k as f32;
                let positions =
                    vec![Vec3::new(0., 0., z), Vec3::new(s, 0., z), Vec3::new(s, s, z), Vec3::new(0., s, z)];
                let mesh =
                    TriangleMesh { positions, indices: vec![[0, 1, 2], [0, 2, 3]], ..Default::default() };
                let a = build_atlas(&mesh, res, false).unwrap();
                let n = a.width * a.height;
                let px =
                    |f: &dyn Fn(usize, usize) -> f32| (0..n).map(|i| [0, 1, 2].map(|c| f(i, c))).collect();
                ObjectResult {
                    shape: k,
                    id: format!("quad{k}"),
                    resolution: ResolutionChoice::setting(),
                    l: px(&|i, c| hash01(k, i, c)),
                    observed: a
                        .texel_tri
                        .iter()
                        .enumerate()
                        .map(|(i, &t)| t != NO_TRI && i % 7 != 3)
                        .collect(),
                    ed: px(&|i, c| 0.5 + 2.0 * hash01(k + 100, i, c)),
                    ei: px(&|i, c| 0.5 * hash01(k + 200, i, c)),
                    kd: vec![[0.0; 3]; n],
                    near_emitter: false,
                    seen_fraction: 1.0,
                    clamped: 0,
                    superres: None,
                    atlas: a,
                }
            })
            .collect()
    }

    /// The bits of the state an object stage may change, and of its inputs.
    fn state(objects: &[ObjectResult]) -> Vec<(Vec<u32>, usize)> {
        let bits = |v: &[[f32; 3]]| v.iter().flat_map(|e| e.map(f32::to_bits)).collect::<Vec<u32>>();
        objects
            .iter()
            .map(|o| ([bits(&o.ei), bits(&o.kd), bits(&o.l), bits(&o.ed)].concat(), o.clamped))
            .collect()
    }

    /// The albedo update of every object split across 1, 2 and 3 ranks (threads): each object is
    /// updated by its owner only, and every rank ends with the `Ei`, `Kd`, clamped counts and
    /// per-object values of one process, bit for bit.
    #[test]
    fn per_object_gives_every_rank_the_state_of_one_process() {
        let stage = |_: usize, o: &mut ObjectResult| {
            o.clamped = update_kd(o);
            (o.clamped as u64, o.kd.iter().map(|e| e[0] as f64).sum::<f64>())
        };
        let put = |t: &(u64, f64), p: &mut Packer| {
            p.u64(t.0);
            p.f64(t.1);
        };
        let get = |u: &mut Unpacker| (u.u64(), u.f64());
        let mut want_objects = objects();
        let want = per_object(&Solo, &mut want_objects, &mut Vec::new(), stage, put, get);
        // a second run of the stage on the updated objects (balanced by the measured seconds
        // under several ranks)
        let want2 = per_object(&Solo, &mut want_objects.clone(), &mut Vec::new(), stage, put, get);
        let want_state = state(&want_objects);
        assert!(want.iter().all(|t| t.0 > 0), "every object clamps some texels: {want:?}");
        assert!(
            want_state.iter().zip(state(&objects())).all(|(a, b)| *a != b),
            "the stage changes every object"
        );
        for n in [1, 2, 3] {
            let out = ThreadComm::run(n, |c| {
                let mut objs = objects();
                let mut costs = Vec::new();
                let owner = owners(c, &objs, &costs);
                let calls = std::sync::Mutex::new(Vec::new());
                let traced = |j: usize, o: &mut ObjectResult| {
                    calls.lock().unwrap().push(j);
                    stage(j, o)
                };
                let got = per_object(c, &mut objs, &mut costs, traced, put, get);
                let mut calls = calls.into_inner().unwrap();
                calls.sort();
                let st = state(&objs);
                // again, on a copy, with the owners from the measured seconds
                // (one process measures nothing: it owns every object)
                let want_costs = if n > 1 { objs.len() } else { 0 };
                assert_eq!(costs.len(), want_costs, "{n} ranks: one measured cost per object");
                assert!(costs.iter().all(|&c| c >= 0.0 && c.is_finite()));
                let owner2 = owners(c, &objs, &costs);
                let mut objs2 = objs.clone();
                let got2 = per_object(c, &mut objs2, &mut costs.clone(), stage, put, get);
                (got, st, owner, calls, (got2, state(&objs2), owner2, costs))
            });
            let owner = &out[0].2;
            let (want2_state, costs0) = (
                state(&{
                    let mut o = want_objects.clone();
                    per_object(&Solo, &mut o, &mut Vec::new(), stage, put, get);
                    o
                }),
                &out[0].4.3,
            );
            for (r, (.., (got2, st2, owner2, costs))) in out.iter().enumerate() {
                // every rank read the same measured seconds, so they agree on the new owners
                assert_eq!(
                    costs.iter().map(|c| c.to_bits()).collect::<Vec<_>>(),
                    costs0.iter().map(|c| c.to_bits()).collect::<Vec<_>>(),
                    "{n} ranks, rank {r}"
                );
                assert_eq!(owner2, &out[0].4.2, "{n} ranks: rank {r} disagrees on the owners");
                for (g, w) in got2.iter().zip(&want2) {
                    assert_eq!((g.0, g.1.to_bits()), (w.0, w.1.to_bits()), "{n} ranks, rank {r}");
                }
                assert!(st2 == &want2_state, "{n} ranks: rank {r}, second run");
            }
            for (r, (got, st, own, calls, _)) in out.iter().enumerate() {
                assert_eq!(own, owner, "{n} ranks: rank {r} disagrees on the owners");
                let mine: Vec<usize> = (0..owner.len()).filter(|&j| owner[j] == r).collect();
                assert_eq!(calls, &mine, "{n} ranks: rank {r} ran the stage on objects it does not own");
                assert_eq!(got.len(), want.len());
                for (g, w) in got.iter().zip(&want) {
                    assert_eq!((g.0, g.1.to_bits()), (w.0, w.1.to_bits()), "{n} ranks, rank {r}");
                }
                assert!(st == &want_state, "{n} ranks: rank {r} ends with other maps than one process");
            }
            // every rank owns at least one object (5 objects, at most 3 ranks)
            assert!((0..n).all(|r| owner.contains(&r)), "{n} ranks: {owner:?}");
        }
    }

    /// Owners balance texel counts: with two ranks neither holds more than the largest object
    /// beyond half of all texels (the longest-processing-time bound), and one process owns all.
    #[test]
    fn owners_balance_texels() {
        let objs = objects();
        assert_eq!(owners(&Solo, &objs, &[]), vec![0; objs.len()]);
        let texels: Vec<usize> = objs.iter().map(|o| o.atlas.width * o.atlas.height).collect();
        let total: usize = texels.iter().sum();
        let largest = *texels.iter().max().unwrap();
        let owner = ThreadComm::run(2, |c| owners(c, &objs, &[])).remove(0);
        for r in 0..2 {
            let load: usize = (0..objs.len()).filter(|&j| owner[j] == r).map(|j| texels[j]).sum();
            assert!(
                2 * load <= total + largest,
                "rank {r}: {load} of {total} texels ({texels:?}, {owner:?})"
            );
        }
    }
}
