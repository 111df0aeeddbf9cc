//! `opal demo`: runs the workflows on bundled data into an output folder.

use anyhow::Result;
use clap::Args;
use std::path::PathBuf;

/// Arguments of `opal demo`.
#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Output folder.
    #[arg(short, long, default_value = "opal-demo")]
    pub output: PathBuf,
}

/// Runs the demo; returns the exit code.
pub fn run(args: DemoArgs) -> Result<i32> {
    std::fs::create_dir_all(&args.output)?;
    let _gonio = super::gonio::demo(&args.output)?;
    Ok(0)
}
