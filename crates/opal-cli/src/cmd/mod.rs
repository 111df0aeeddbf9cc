//! One module per subcommand.

pub mod delight;
pub mod demo;
pub mod gonio;
pub mod render;
