//! The named stages of [`delight`](super::delight), in the order it runs them:
//!
//! 1. [`unwrap`]: the selection of the objects and their atlases (resolution per object);
//! 2. [`direct`]: the direct irradiance `Ed` per texel (light sampling) and its scene average;
//! 3. [`luminance`]: the per-view gains (unless fixed) and the luminance maps `L`, then the
//!    initial albedo `Kd = π L / (Ed + share·Ed)`;
//! 4. [`iterate`]: the light-tracing passes (indirect irradiance, error statistics, update of
//!    `Ei` and `Kd`; the super-resolved luminance after the first pass);
//! 5. [`outputs`]: the debug dump and the assembled [`DelightResult`](super::DelightResult).
//!
//! Each stage reads the run's fixed inputs ([`Inputs`]) and updates the objects in place; the
//! stage clocks go to `DelightResult::timings`. Tests: `tests/delight.rs` (round trip on a small
//! Cornell box), the CLI's `opal delight` tests.

pub(super) mod direct;
pub(super) mod iterate;
pub(super) mod luminance;
pub(super) mod outputs;
pub(super) mod unwrap;

use super::DelightSettings;
use opal::scene::Scene;
use opal::scene::desc::SceneDesc;

/// The fixed inputs of a run, shared by the stages.
pub(super) struct Inputs<'a> {
    /// Scene description (the recovered scene of each pass is built from it).
    pub desc: &'a SceneDesc,
    /// The built scene.
    pub scene: &'a Scene,
    /// Settings.
    pub s: &'a DelightSettings,
    /// One line per stage.
    pub log: &'a (dyn Fn(&str) + Sync),
}
