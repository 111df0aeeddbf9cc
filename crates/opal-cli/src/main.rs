//! `opal` — command-line front end of the Opal toolkit.
//!
//! Exit codes: 0 success, 1 a check failed (energy violated, fit above its bound),
//! 2 usage / I-O / bad input. Errors print `error: {cause chain}`.

use clap::Parser;
use opal_cli::{Cli, Command, cmd, util};

fn main() {
    // under an MPI launcher (`mpi` feature): join the job; otherwise one process
    let mpi = opal_cli::dist::init();
    // `opal delight --resume OUTDIR` runs the saved command line of that output folder
    let argv = match cmd::delight::resume::expand(std::env::args_os().collect()) {
        Ok(a) => a,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::exit(2);
        }
    };
    let cli = Cli::parse_from(argv);
    util::set_quiet(cli.quiet || !opal_cli::dist::is_root());
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
        Ok(code) => {
            mpi.finish();
            std::process::exit(code)
        }
        Err(e) => {
            // in a job of several ranks: the message with the rank, then MPI_Abort
            opal_cli::dist::fail(&format!("error: {e:#}"));
            eprintln!("error: {e:#}");
            // 130 = stopped by a signal (128 + SIGINT), as shells report it; 2 = bad input
            let interrupted = e.chain().any(|c| {
                matches!(c.downcast_ref::<opal::error::Error>(), Some(opal::error::Error::Interrupted { .. }))
            });
            mpi.finish();
            std::process::exit(if interrupted { 130 } else { 2 });
        }
    }
}
