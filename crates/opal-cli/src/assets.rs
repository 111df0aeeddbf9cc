//! Data bundled inside the `opal` binary for `opal demo`: the reference Cornell box (Mitsuba 3
//! scene, meshes, back-wall texture; used by the render and de-lighting demos) and the small
//! measurement of the fit-ndf demo. Exercised by `opal demo` and the delight CLI tests.

use crate::util;
use anyhow::Result;
use std::path::{Path, PathBuf};

/// The reference Cornell box (Mitsuba 3 scene, meshes and back-wall texture), embedded.
const CBOX_FILES: &[(&str, &[u8])] = &[
    ("scene.xml", include_bytes!("../../opal/tests/data/cbox/scene.xml")),
    ("meshes/back_wall.obj", include_bytes!("../../opal/tests/data/cbox/meshes/back_wall.obj")),
    ("meshes/ceiling.obj", include_bytes!("../../opal/tests/data/cbox/meshes/ceiling.obj")),
    ("meshes/floor.obj", include_bytes!("../../opal/tests/data/cbox/meshes/floor.obj")),
    ("meshes/left_wall_red.obj", include_bytes!("../../opal/tests/data/cbox/meshes/left_wall_red.obj")),
    ("meshes/light.obj", include_bytes!("../../opal/tests/data/cbox/meshes/light.obj")),
    ("meshes/right_wall_green.obj", include_bytes!("../../opal/tests/data/cbox/meshes/right_wall_green.obj")),
    ("meshes/short_box.obj", include_bytes!("../../opal/tests/data/cbox/meshes/short_box.obj")),
    ("meshes/tall_box.obj", include_bytes!("../../opal/tests/data/cbox/meshes/tall_box.obj")),
    (
        "textures/backwall_albedo.exr",
        include_bytes!("../../opal/tests/data/cbox/textures/backwall_albedo.exr"),
    ),
];

/// Writes the embedded Cornell box into `dir` (scene.xml, meshes/, textures/).
pub fn write_cbox(dir: &Path) -> Result<PathBuf> {
    for (name, bytes) in CBOX_FILES {
        util::write_bytes_atomic(&dir.join(name), bytes)?;
    }
    Ok(dir.join("scene.xml"))
}

/// The fit-ndf demo measurement: a dotted plate (35 % of the face GGX α = 0.3 dots on a
/// polished land, n 1.52, 3 mm, rough entry; Mitsuba 3 via `bench/scripts/gonio_dotted.py`),
/// incidences 0°, 30°, 60°, every 2nd detector; CSV of `docs/formats.md`. A specular spike on a
/// diffuse lobe ~100× dimmer: the case a single NDF cannot describe. (`data/fit_ndf_demo.csv`,
/// the earlier GGX α = 0.15 demo subset, stays as test data of the fit-ndf CLI tests.)
pub static FIT_NDF_DEMO_CSV: &str = include_str!("../data/fit_ndf_dotted_demo.csv");
