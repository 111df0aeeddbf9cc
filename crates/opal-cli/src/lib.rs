//! The `opal` command line as a library: argument parsing ([`Cli`]) and one module per
//! subcommand ([`cmd`]). The `opal` binary (`main.rs`) and the Python package
//! (`crates/opal-py`) both call these functions, so the two give the same results and the same
//! error messages (docs/decisions/python-package.md).
//!
//! Tests: the unit tests of each module and the CLI tests in `tests/`.

pub mod assets;
pub mod cmd;
pub mod dist;
pub mod glb;
pub mod plate;
#[allow(dead_code)]
pub mod plot;
pub mod util;

use clap::{Parser, Subcommand};

/// Opal: recover optical properties of real surfaces by physically based light simulation.
#[derive(Parser, Debug)]
#[command(name = "opal", version, about, long_about = None)]
pub struct Cli {
    /// Hide progress bars and progress messages (warnings and errors are still printed).
    #[arg(long, global = true)]
    pub quiet: bool,
    /// The subcommand.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands of `opal`.
#[derive(Subcommand, Debug)]
pub enum Command {
    /// Recover diffuse albedo textures from multi-view HDR images (de-lighting, method C).
    Delight(cmd::delight::DelightArgs),
    /// Run every workflow on data shipped with Opal and write results to `opal-demo/`.
    Demo(cmd::demo::DemoArgs),
    /// Fit the micro-facet NDF of a plate's rough face to measured curves; export its BSDF.
    FitNdf(cmd::fit_ndf::FitNdfArgs),
    /// Virtual goniophotometer: plate with polished/rough faces, beam, detectors.
    Gonio(cmd::gonio::GonioArgs),
    /// Path-trace a Mitsuba 3 XML scene to OpenEXR (+ PNG preview).
    Render(cmd::render::RenderArgs),
    /// Energy / reciprocity checks of BRDF lobes and normalisation fitting (method B).
    Brdf(cmd::brdf::BrdfArgs),
}
