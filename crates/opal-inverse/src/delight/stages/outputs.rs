//! Stage 5 of [`delight`](crate::delight::delight): the debug dump of the final maps
//! ([`DebugSettings::dump_dir`](crate::delight::DebugSettings::dump_dir)) and the assembled
//! [`DelightResult`] with its stage clocks. The files of a run (textures, meshes, scene, report)
//! are written by the CLI (`opal delight`). Tests: `tests/delight.rs`, the CLI's `opal delight`
//! tests.

use super::iterate::Iterated;
use crate::delight::timing::{StageClock, Timings};
use crate::delight::{DelightResult, ObjectResult, PoseReport, ViewGains, to_image};

/// Debug dump: per object the luminance map, observed mask, direct and indirect irradiance and
/// albedo as EXR files (`<id>_<tag>_<what>.exr`), for error analysis.
pub(in crate::delight) fn debug_dump(objects: &[ObjectResult], tag: &str, dir: Option<&std::path::Path>) {
    let Some(dir) = dir else { return };
    let _ = std::fs::create_dir_all(dir);
    for o in objects {
        let (w, h) = (o.atlas.width, o.atlas.height);
        let obs: Vec<[f32; 3]> = o.observed.iter().map(|&b| [b as u8 as f32; 3]).collect();
        for (what, v) in [("l", &o.l), ("obs", &obs), ("ed", &o.ed), ("ei", &o.ei), ("kd", &o.kd)] {
            let path = dir.join(format!("{}_{tag}_{what}.exr", o.id));
            if let Ok(f) = std::fs::File::create(&path) {
                let _ = opal::image::write::write_exr(&to_image(v, w, h), std::io::BufWriter::new(f));
            }
        }
    }
}

/// The parts of a finished run.
pub(in crate::delight) struct Finished {
    /// Recovered objects.
    pub objects: Vec<ObjectResult>,
    /// Skipped objects: (id, reason).
    pub skipped: Vec<(String, String)>,
    /// Shapes left out of the recovery: (id, reason).
    pub not_recovered: Vec<(String, String)>,
    /// The iterations' statistics.
    pub iterated: Iterated,
    /// Estimated per-view gains.
    pub view_gains: Option<ViewGains>,
    /// Refined poses (when pose refinement ran).
    pub poses: Option<PoseReport>,
    /// Warnings.
    pub warnings: Vec<String>,
    /// The unseen-light analysis per object (empty when skipped).
    pub unseen_light: Vec<crate::delight::UnseenLight>,
}

/// The result of the run started at `t_all` (stage clock `total` added).
pub(in crate::delight) fn assemble(f: Finished, mut timings: Timings, t_all: StageClock) -> DelightResult {
    timings.push("total", t_all.elapsed());
    let Timings { wall: timings, cpu: cpu_timings, memory: memory_mb } = timings;
    let Iterated { iterations, converged, light_paths } = f.iterated;
    DelightResult {
        objects: f.objects,
        skipped: f.skipped,
        not_recovered: f.not_recovered,
        iterations,
        converged,
        view_gains: f.view_gains,
        poses: f.poses,
        warnings: f.warnings,
        timings,
        cpu_timings,
        memory_mb,
        light_paths,
        unseen_light: f.unseen_light,
    }
}
