//! Scenes: a serde description ([`desc`]) that loaders produce and tests/inverse code can build
//! directly, and the built scene the integrators render, with its runtime materials
//! ([`material`]) made once from the description.

pub mod build;
pub mod desc;
mod emitters;
pub mod load;
pub mod material;

pub use build::{Scene, SurfaceInteraction};
pub use load::load_mitsuba_xml;
pub use material::{Bsdf, Material};
