//! One module per subcommand.

pub mod demo;
pub mod gonio;
pub mod render;
