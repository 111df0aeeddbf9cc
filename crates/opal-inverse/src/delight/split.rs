//! Per-object stages of [`delight`](super::delight) split across processes
//! ([`DelightSettings::comm`](super::DelightSettings::comm)): each object is processed by one
//! owner rank ([`owners`], balanced by texel count), which then sends the albedo state it changed
//! — `Ei`, `Kd` and the clamped count — and any per-object extra bytes to every other rank
//! ([`exchange_albedo`]). Every stage of an object depends on that object's maps only, so every
//! rank ends with the state one process computes, bit for bit. With one process nothing is sent.
//! Tests: the MPI tier of the CLI (`tests/mpi.rs`: `delight` under 1, 2 and 3 ranks writes the
//! bytes of one process).

use super::ObjectResult;
use opal::dist::{Comm, Packer, Unpacker};

/// Owner rank of each object: balanced by texel count ([`opal::dist::assign_by_cost`]); all 0
/// for one process.
pub(super) fn owners(comm: &dyn Comm, objects: &[ObjectResult]) -> Vec<usize> {
    if comm.size() == 1 {
        return vec![0; objects.len()];
    }
    let costs: Vec<f64> = objects.iter().map(|o| (o.atlas.width * o.atlas.height) as f64).collect();
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
/// packed.
pub(super) fn per_object<T: Send>(
    comm: &dyn Comm,
    objects: &mut [ObjectResult],
    f: impl Fn(usize, &mut ObjectResult) -> T + Sync + Send,
    put: impl Fn(&T, &mut Packer),
    get: impl Fn(&mut Unpacker) -> T,
) -> Vec<T> {
    use rayon::prelude::*;
    let owner = owners(comm, objects);
    let mine: Vec<Option<T>> =
        objects.par_iter_mut().enumerate().map(|(j, o)| (owner[j] == comm.rank()).then(|| f(j, o))).collect();
    if comm.size() == 1 {
        return mine.into_iter().map(|t| t.expect("one process owns every object")).collect();
    }
    let extra: Vec<Option<Vec<u8>>> = mine
        .iter()
        .map(|t| {
            t.as_ref().map(|t| {
                let mut p = Packer::default();
                put(t, &mut p);
                p.0
            })
        })
        .collect();
    drop(mine);
    let bytes = exchange_albedo(comm, objects, &owner, extra);
    bytes
        .iter()
        .map(|b| {
            let mut u = Unpacker(b);
            let t = get(&mut u);
            assert!(u.is_empty(), "an object's extra bytes of another kind");
            t
        })
        .collect()
}
