//! The `lumigraph` binary: parses the command line and prints any error as one line.

use clap::Parser;

/// `serve` logs progress and requests at info; the one-shot commands only warnings.
fn default_log_filter() -> &'static str {
    if std::env::args().nth(1).as_deref() == Some("serve") {
        "info"
    } else {
        "warn"
    }
}

fn main() -> std::process::ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_log_filter())),
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
