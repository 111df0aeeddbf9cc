//! Stage 2 of [`delight`](crate::delight::delight): the direct irradiance `Ed` per texel of
//! every object by light sampling ([`direct_irradiance_many`], seeded per object and texel; the
//! covered texels of all objects split across the processes of `DelightSettings::comm` in one
//! exchange for the pilot and one for the penumbrae) and its scene
//! average over the covered surface (the initial indirect estimate of texels without direct
//! light). Runs before the luminance stage. Tests: `tests/delight.rs`, the unit tests of
//! `delight/direct.rs`.

// Index loops over parallel per-texel arrays read more clearly than zipped iterators here.
#![allow(clippy::needless_range_loop)]

use crate::delight::atlas::NO_TRI;
use crate::delight::direct::direct_irradiance_many;
use crate::delight::{DelightSettings, ObjectResult};
use opal::scene::Scene;

/// Fills `o.ed` of every object; returns the area-weighted mean direct irradiance over the
/// covered texels of all objects.
pub(in crate::delight) fn direct_stage(
    scene: &Scene,
    objects: &mut [ObjectResult],
    s: &DelightSettings,
) -> [f32; 3] {
    let solo = opal::dist::Solo;
    let comm: &dyn opal::dist::Comm = s.comm.as_deref().unwrap_or(&solo);
    // all objects in one split (object j seeded with its own stream); progress (stages `direct`
    // and `direct penumbrae`) in texels as they finish inside the split
    let atlases: Vec<&crate::delight::atlas::Atlas> = objects.iter().map(|o| &o.atlas).collect();
    let streams: Vec<u64> = (0..objects.len()).map(|j| 0xED00 + j as u64).collect();
    let samples = (s.direct_samples, s.direct_pilot);
    let maps = direct_irradiance_many(scene, &atlases, samples, s.seed, &streams, comm, s.progress.as_ref());
    for (o, ed) in objects.iter_mut().zip(maps) {
        o.ed = ed;
    }
    scene_average(objects)
}

/// Area-weighted mean direct irradiance over the covered texels of all objects.
fn scene_average(objects: &[ObjectResult]) -> [f32; 3] {
    let mut avg = [0f64; 3];
    let mut aw = 0f64;
    for o in objects {
        for i in 0..o.ed.len() {
            let t = o.atlas.texel_tri[i];
            if t != NO_TRI {
                let a = o.atlas.texel_area[t as usize] as f64;
                for c in 0..3 {
                    avg[c] += a * o.ed[i][c] as f64;
                }
                aw += a;
            }
        }
    }
    avg.map(|v| (v / aw.max(1e-30)) as f32)
}
