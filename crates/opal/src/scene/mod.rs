//! Scenes: a serde description ([`desc`]) that loaders produce and tests/inverse code can build
//! directly, and the built scene the integrators render.

pub mod desc;
