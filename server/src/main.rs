//! The `lumigraph` binary: parses the command line and prints any error as one line.

use clap::Parser;

fn main() -> std::process::ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = lumigraph_server::cli::Cli::parse();
    match lumigraph_server::cli::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(error) => {
            // One line: the error and its causes joined.
            eprintln!("error: {error:#}");
            std::process::ExitCode::from(1)
        }
    }
}
