//! # Opal inverse workflows
//!
//! Built only on the public API of the `opal` engine:
//! * method A — fitting a micro-facet normal distribution to goniophotometer curves,
//! * method B — energy and reciprocity checks of BRDF lobes, normalisation fitting,
//! * method C — de-lighting (diffuse albedo textures from multi-view HDR photos).
#![warn(missing_docs)]

pub mod brdf_energy;
pub mod delight;
pub mod export;
pub mod face_table;
pub mod measured;
pub mod ndf_fit;
pub mod scatter;
