//! `kairos`: run, validate and list diagrams and components.

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    let cli = kairos::cli::Cli::parse();
    kairos::cli::init_logging(cli.verbose);
    match kairos::cli::execute(cli) {
        Ok(code) => code,
        Err(error) => {
            eprintln!("error: {error:#}");
            ExitCode::from(1)
        }
    }
}
