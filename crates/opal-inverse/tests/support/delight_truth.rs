//! Helpers of the de-lighting tests (`tests/delight.rs`, `tests/delight_lights.rs`): the test
//! Cornell box's folder, scene loading, the scenes' true constant albedos, a hash of the
//! recovered texels and the printed report with the worst albedo error.

use opal::scene::desc::{SceneDesc, TextureDesc};
use opal_inverse::delight::DelightResult;
use std::path::{Path, PathBuf};

/// The test Cornell box's folder.
pub fn data() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../opal/tests/data/cbox")
}

pub fn load(path: &Path) -> SceneDesc {
    opal::scene::load::load_mitsuba_xml(path, &[]).unwrap()
}

/// The constant albedos of the scene's non-emitting diffuse shapes, by id.
pub fn truth_albedos(desc: &SceneDesc) -> Vec<(String, [f32; 3])> {
    desc.shapes
        .iter()
        .filter(|s| s.emitter.is_none())
        .filter_map(|s| match &s.bsdf {
            opal::scene::desc::BsdfDesc::Diffuse { reflectance: TextureDesc::Constant(c) } => {
                Some((s.id.clone(), c.0))
            }
            _ => None,
        })
        .collect()
}

/// FNV-1a hash of the bits of every recovered albedo texel (bit-for-bit comparisons of runs).
pub fn kd_hash(r: &DelightResult) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for o in &r.objects {
        for v in o.kd.iter().flatten() {
            h = (h ^ v.to_bits() as u64).wrapping_mul(0x0100_0000_01b3);
        }
    }
    h
}

/// Prints the passes' errors, the texels' hash and the timings; returns the worst constant
/// albedo error against the truth.
pub fn report(r: &DelightResult, desc: &SceneDesc) -> f64 {
    let mut worst = 0f64;
    for (id, t) in truth_albedos(desc) {
        let o = r.objects.iter().find(|o| o.id == id).unwrap();
        worst = worst.max(super::common::constant_albedo_error(o, t));
    }
    for it in &r.iterations {
        println!(
            "iteration {}: max {:.2}% mean {:.2}% direct ratio {:?} ({:.1} s)",
            it.iteration,
            100.0 * it.max_rel_error,
            100.0 * it.mean_rel_error,
            it.direct_ratio,
            it.seconds
        );
    }
    println!("albedo bits hash {:016x}", kd_hash(r));
    println!("timings (wall s) {:?}", r.timings);
    println!("timings (CPU s) {:?}", r.cpu_timings);
    worst
}
