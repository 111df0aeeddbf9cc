//! Scenes: a serde description ([`desc`]) that loaders produce and tests/inverse code can build
//! directly, and the built scene the integrators render.

pub mod build;
pub mod desc;
pub mod load;

pub use build::{Scene, SurfaceInteraction};
pub use load::load_mitsuba_xml;
