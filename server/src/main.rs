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

/// Keeps freed heap memory for reuse instead of handing it back to the kernel (glibc). Each
/// frame allocates and frees buffers of a megabyte and more (a 512² frame's colour and depth,
/// and the driver's per-submission allocations); above glibc's mmap threshold each is a fresh
/// mapping whose every page faults on first touch, and freed memory at the top of the heap is
/// returned once it exceeds the trim threshold. Both thresholds raised, so that the per-frame
/// buffers are reused (the gain is measured in docs/benchmarks-history.md). Allocations of
/// 64 MiB and more (light-field textures) are still mapped, and the heap keeps at most 256 MiB
/// it does not use.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[allow(unsafe_code)]
fn keep_freed_memory() {
    // SAFETY: `mallopt` only sets allocator parameters; it is called once, first thing in
    // `main`, before any other thread exists or anything is allocated through these settings.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 64 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 256 << 20);
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn keep_freed_memory() {}

fn main() -> std::process::ExitCode {
    keep_freed_memory();
    // Before any thread starts: it may set XDG_RUNTIME_DIR, which keeps Mesa quiet.
    lumigraph_core::gpu::ensure_runtime_dir();
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
