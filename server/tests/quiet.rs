//! The `lumigraph` binary says nothing on stderr but its own words, also on a machine without a
//! login session (no `XDG_RUNTIME_DIR`), where Mesa would otherwise print an error line per
//! adapter listing: it then makes a private runtime directory under the temp dir.
#![cfg(unix)]

use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const VIEW: &str =
    r#"{"eye":[0,2,9],"target":[0,0,0],"up":[0,1,0],"yfov_deg":40,"width":48,"height":40}"#;

/// Runs `lumigraph ARGS` with `TMPDIR=tmp`, at the default log level, with `runtime_dir` as
/// `XDG_RUNTIME_DIR` (none when `None`).
fn lumigraph(args: &[&str], tmp: &Path, runtime_dir: Option<&Path>) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_lumigraph"));
    command
        .args(args)
        .env_remove("RUST_LOG")
        .env_remove("XDG_RUNTIME_DIR")
        .env("TMPDIR", tmp);
    if let Some(dir) = runtime_dir {
        command.env("XDG_RUNTIME_DIR", dir);
    }
    let output = command.output().expect("run lumigraph");
    assert!(
        output.status.success(),
        "lumigraph {args:?} failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    output
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// The private runtime directories lumigraph made under `tmp`.
fn runtime_dirs(tmp: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(tmp)
        .expect("list the temp dir")
        .map(|entry| entry.expect("entry").path())
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("lumigraph-xdg-"))
        })
        .collect()
}

#[test]
fn bake_and_render_without_a_runtime_dir_print_nothing_on_stderr() {
    let work = tempfile::tempdir().expect("tempdir");
    let tmp = work.path().join("tmp");
    std::fs::create_dir(&tmp).expect("create tmp");
    let asset = work.path().join("demo.lfa");
    let bake = lumigraph(
        &[
            "bake",
            "--demo",
            "-o",
            s(&asset),
            "--cameras",
            "12",
            "--resolution",
            "64",
        ],
        &tmp,
        None,
    );
    let view = work.path().join("view.json");
    std::fs::write(&view, VIEW).expect("write the view");
    let png = work.path().join("view.png");
    let render = lumigraph(
        &["render", s(&asset), "--view", s(&view), "-o", s(&png)],
        &tmp,
        None,
    );
    for (what, output) in [("bake", &bake), ("render", &render)] {
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(
            stderr.trim().is_empty(),
            "{what} printed on stderr:\n{stderr}"
        );
    }
    assert!(png.is_file());
    let dirs = runtime_dirs(&tmp);
    assert_eq!(dirs.len(), 1, "{dirs:?}");
    let meta = std::fs::symlink_metadata(&dirs[0]).expect("runtime dir metadata");
    assert!(meta.is_dir());
    assert_eq!(meta.permissions().mode() & 0o777, 0o700);
}

#[test]
fn a_usable_runtime_dir_is_kept() {
    let work = tempfile::tempdir().expect("tempdir");
    let tmp = work.path().join("tmp");
    let runtime = work.path().join("runtime");
    for dir in [&tmp, &runtime] {
        std::fs::create_dir(dir).expect("create dir");
    }
    let asset = work.path().join("demo.lfa");
    let bake = lumigraph(
        &[
            "bake",
            "--demo",
            "-o",
            s(&asset),
            "--cameras",
            "12",
            "--resolution",
            "32",
            "--no-calibrate",
        ],
        &tmp,
        Some(&runtime),
    );
    let stderr = String::from_utf8_lossy(&bake.stderr);
    assert!(
        stderr.trim().is_empty(),
        "bake printed on stderr:\n{stderr}"
    );
    assert!(runtime_dirs(&tmp).is_empty());
}
