//! The strata command line. Subcommands live in `src/cli/`, one module each; this file only sets
//! up the process (broken pipes, signals) and reports errors.

mod cli;

use clap::Parser;
use std::process::ExitCode;

fn main() -> ExitCode {
    // Printing into a closed pipe (`strata inspect f | head`) ends the process quietly, as other
    // command-line tools do, instead of panicking.
    #[cfg(unix)]
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = cli::Cli::parse();
    // On SIGINT, SIGTERM or SIGHUP, remove temporary output files before exiting.
    let _ = ctrlc::set_handler(|| {
        strata::atomic::remove_pending();
        eprintln!("interrupted: no output written");
        std::process::exit(130);
    });
    let result = cli::run(cli);
    for p in strata::atomic::take_removed_stale() {
        eprintln!("note: removed {}, left by an interrupted strata run", p.display());
    }
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
