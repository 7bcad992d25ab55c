//! Atomic file writes: write to a temporary file beside the target, flush, fsync, rename, fsync
//! the folder. A crash or an error never leaves a partial file under the target name, and once
//! [`atomic_write`] returns the file survives a power loss.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// Writes `path` atomically: `fill` receives a buffered writer on a temporary file in the same
/// directory; on success the file is synced, renamed over `path` and the directory synced (so the
/// rename itself is durable), on error it is removed. A `path` that exists and is not a regular
/// file (a device such as `/dev/null`, a folder, a pipe) is refused before anything is written:
/// the rename would replace it.
pub fn atomic_write<E>(
    path: &Path,
    fill: impl FnOnce(&mut BufWriter<File>) -> Result<(), E>,
) -> Result<(), E>
where
    E: From<std::io::Error>,
{
    check_target(path)?;
    let tmp = temp_path_for(path);
    let result = (|| {
        let file = File::create(&tmp)?;
        let mut w = BufWriter::with_capacity(1 << 20, file);
        fill(&mut w)?;
        w.flush()?;
        let file = w
            .into_inner()
            .map_err(std::io::IntoInnerError::into_error)?;
        file.sync_all()?;
        drop(file);
        std::fs::rename(&tmp, path)?;
        sync_dir(&parent_dir(path))?;
        Ok(())
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Refuses a target that exists and is not a regular file (a symbolic link to one is fine:
/// the rename replaces the link, as for any file).
pub fn check_target(path: &Path) -> std::io::Result<()> {
    match std::fs::symlink_metadata(path) {
        Ok(meta) if !(meta.is_file() || meta.file_type().is_symlink()) => Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!(
                "{} exists and is not a regular file; give a file path",
                path.display()
            ),
        )),
        _ => Ok(()),
    }
}

/// Makes the entries of `dir` durable: after a file is created, renamed or removed in it, an
/// fsync of the directory is what keeps that change across a power loss. A no-op where
/// directories cannot be opened as files (not Unix).
///
/// # Errors
/// The directory cannot be opened or synced.
pub fn sync_dir(dir: &Path) -> std::io::Result<()> {
    #[cfg(unix)]
    {
        File::open(dir)?.sync_all()
    }
    #[cfg(not(unix))]
    {
        let _ = dir;
        Ok(())
    }
}

/// The directory holding `path` (`.` for a bare file name).
fn parent_dir(path: &Path) -> PathBuf {
    match path.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => dir.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// The target file name of a temporary name `temp_path_for` makes (`.name.tmp-<pid>-<n>` →
/// `name`), or `None` when `file_name` is not one: how a folder's owner finds the temporary
/// files a killed writer left.
pub fn temp_target(file_name: &str) -> Option<&str> {
    let (name, _) = file_name.strip_prefix('.')?.rsplit_once(".tmp-")?;
    (!name.is_empty()).then_some(name)
}

/// `dir/.name.tmp-<pid>-<n>` beside `path`: same file system, so the rename is atomic.
pub fn temp_path_for(path: &Path) -> PathBuf {
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let name = path
        .file_name()
        .map_or_else(|| "out".into(), |s| s.to_string_lossy().into_owned());
    let tmp_name = format!(".{name}.tmp-{}-{n}", std::process::id());
    match path.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => dir.join(tmp_name),
        _ => PathBuf::from(tmp_name),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    #[cfg(unix)]
    use std::os::unix::fs::FileTypeExt;

    #[test]
    fn writes_and_cleans_up_on_error() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("a.bin");
        atomic_write::<std::io::Error>(&target, |w| w.write_all(b"hello")).unwrap();
        assert_eq!(std::fs::read(&target).unwrap(), b"hello");
        let err = atomic_write::<std::io::Error>(&target, |w| {
            w.write_all(b"partial")?;
            Err(std::io::Error::other("boom"))
        });
        assert!(err.is_err());
        // The old content survives and no temp file is left behind.
        assert_eq!(std::fs::read(&target).unwrap(), b"hello");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    /// A device or a folder at the target is refused, untouched, with nothing left behind
    /// (renaming over `/dev/null` would replace the device with a file).
    #[cfg(unix)]
    #[test]
    fn targets_that_are_not_regular_files_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let folder = dir.path().join("folder");
        std::fs::create_dir(&folder).unwrap();
        for target in [Path::new("/dev/null"), folder.as_path()] {
            let err = atomic_write::<std::io::Error>(target, |w| w.write_all(b"x")).unwrap_err();
            assert_eq!(err.kind(), std::io::ErrorKind::InvalidInput, "{err}");
            assert!(err.to_string().contains("not a regular file"), "{err}");
        }
        assert!(folder.is_dir());
        assert!(
            std::fs::metadata("/dev/null")
                .unwrap()
                .file_type()
                .is_char_device()
        );
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn temporary_names_lead_back_to_their_target() {
        let tmp = temp_path_for(Path::new("dir/a.lfa"));
        let name = tmp.file_name().and_then(|n| n.to_str()).unwrap();
        assert_eq!(temp_target(name), Some("a.lfa"));
        assert_eq!(temp_target(".x.tmp-1.lfa.tmp-2-3"), Some("x.tmp-1.lfa"));
        for other in ["a.lfa", ".hidden", ".tmp-1-0", "a.lfa.tmp-1-0"] {
            assert_eq!(temp_target(other), None, "{other}");
        }
    }
}
