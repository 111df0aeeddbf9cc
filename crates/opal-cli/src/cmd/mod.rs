//! One module per subcommand.

pub mod brdf;
pub mod demo;
pub mod render;
