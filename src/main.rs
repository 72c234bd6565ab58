//! The strata command line. Subcommands live in `src/cli/`, one module each; this file only sets
//! up the process (broken pipes, signals) and reports errors.

mod cli;

use clap::Parser;
use std::io::Write;
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
    let (note, code) = cli.on_interrupt();
    let _ = ctrlc::set_handler(move || {
        strata::atomic::remove_pending();
        let _ = writeln!(std::io::stderr(), "{note}");
        std::process::exit(code);
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
