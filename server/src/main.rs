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

/// `lumigraph info ASSET | head` closes stdout early; `println!` then panics with "failed
/// printing to stdout: Broken pipe". Like other Unix tools, exit quietly (status 141, as a
/// SIGPIPE death reports) instead of printing a panic. Any other panic keeps the default hook.
fn quiet_broken_pipe() {
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let payload = info.payload();
        let message = payload
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| payload.downcast_ref::<&str>().copied())
            .unwrap_or("");
        if message.starts_with("failed printing to stdout")
            && message.to_ascii_lowercase().contains("broken pipe")
        {
            std::process::exit(141);
        }
        default_hook(info);
    }));
}

fn main() -> std::process::ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_log_filter())),
        )
        .with_writer(std::io::stderr)
        .init();
    quiet_broken_pipe();
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
