//! One module per subcommand.

pub mod brdf;
pub mod delight;
pub mod demo;
pub mod face_render;
pub mod fit_ndf;
pub mod gonio;
pub mod render;
