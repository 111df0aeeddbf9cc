//! `opal` — command-line front end of the Opal toolkit.
//!
//! Exit codes: 0 success, 1 a check failed (energy violated, fit above its bound),
//! 2 usage / I-O / bad input. Errors print `error: {cause chain}`.

mod assets;
mod cmd;
mod glb;
mod plate;
#[allow(dead_code)]
mod plot;
mod util;

use clap::{Parser, Subcommand};

/// Opal: recover optical properties of real surfaces by physically based light simulation.
#[derive(Parser, Debug)]
#[command(name = "opal", version, about, long_about = None)]
struct Cli {
    /// Hide progress bars.
    #[arg(long, global = true)]
    quiet: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
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

fn main() {
    // `opal delight --resume OUTDIR` runs the saved command line of that output folder
    let argv = match cmd::delight::resume::expand(std::env::args_os().collect()) {
        Ok(a) => a,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::exit(2);
        }
    };
    let cli = Cli::parse_from(argv);
    util::set_quiet(cli.quiet);
    // `delight` keeps its finished iterations on Ctrl-C (its own handler); the others stop
    let result = match cli.command {
        Command::Delight(a) => cmd::delight::run(a),
        Command::Demo(a) => {
            util::install_exit_handler("demo");
            cmd::demo::run(a)
        }
        Command::FitNdf(a) => {
            util::install_exit_handler("fit-ndf");
            cmd::fit_ndf::run(a)
        }
        Command::Gonio(a) => {
            util::install_exit_handler("gonio");
            cmd::gonio::run(a)
        }
        Command::Render(a) => {
            util::install_exit_handler("render");
            cmd::render::run(a)
        }
        Command::Brdf(a) => {
            util::install_exit_handler("brdf");
            cmd::brdf::run(a)
        }
    };
    match result {
        Ok(code) => std::process::exit(code),
        Err(e) => {
            eprintln!("error: {e:#}");
            // 130 = stopped by a signal (128 + SIGINT), as shells report it; 2 = bad input
            let interrupted = e.chain().any(|c| {
                matches!(c.downcast_ref::<opal::error::Error>(), Some(opal::error::Error::Interrupted { .. }))
            });
            std::process::exit(if interrupted { 130 } else { 2 });
        }
    }
}
