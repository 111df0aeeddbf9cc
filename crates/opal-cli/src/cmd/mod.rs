//! One module per subcommand.

pub mod brdf;
pub mod demo;
pub mod gonio;
pub mod render;
