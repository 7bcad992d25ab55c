//! The bake-job journal: what keeps an accepted bake alive across a crash or a restart.
//!
//! It lives in the hidden folder `.jobs/` inside the assets folder (created with the first bake)
//! and holds, per job, at most one of:
//!
//! - `JOB.job` — a job that is not finished: the magic line `LUMIGRAPH-JOB 1`, the job's spec as
//!   one line of JSON (ids, bake options, mesh format and the length and SHA-256 of the mesh),
//!   then the mesh bytes. Written atomically (temporary file, fsync, rename, fsync of the folder)
//!   before `POST /v1/bake` answers 202; a restart re-queues it with the same job id and asset id.
//! - `JOB.json` — a finished job: its final status (`done` or `failed`, report or error) and when
//!   it finished, so `GET /v1/jobs/{id}` answers the same after a restart. Written (atomically)
//!   before the `.job` entry is removed and before a baked asset becomes visible; the newest
//!   [`super::jobs::MAX_JOBS`] are kept.
//!
//! At start-up [`Journal::recover`] removes the temporary files a killed writer left
//! (`.JOB.job.tmp-*`, `.JOB.json.tmp-*`) and every entry that cannot be read (wrong magic, bad
//! JSON, a mesh whose length or checksum is wrong, a name that is not a job id), each with a
//! warning; it never fails on an entry's content.

use std::collections::BTreeMap;
use std::io::Write as _;
use std::path::{Path, PathBuf};

use lumigraph_core::bake::BakeOptions;
use serde::{Deserialize, Serialize};

use super::assets::validate_id;
use super::jobs::JobStatus;

/// The journal folder's name inside the assets folder.
pub const JOURNAL_DIR: &str = ".jobs";

/// First line of a pending entry.
const MAGIC: &[u8] = b"LUMIGRAPH-JOB 1\n";

/// Extension of a pending entry (spec and mesh).
const PENDING_EXT: &str = "job";

/// Extension of a finished job's record.
const RECORD_EXT: &str = "json";

/// Why the journal could not be read or written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum JournalError {
    /// Reading or writing a journal file failed.
    #[error("job journal I/O: {0}")]
    Io(#[from] std::io::Error),
    /// An entry is not one the server wrote, or was damaged.
    #[error("corrupt job journal entry: {0}")]
    Corrupt(String),
}

/// An accepted bake as the journal stores it (the mesh bytes follow it in the entry).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JobSpec {
    /// Job id.
    pub id: String,
    /// The asset the bake writes.
    pub asset: String,
    /// Bake options.
    pub options: BakeOptions,
    /// Mesh format, as its file extension (`obj`, `ply`, …).
    pub format: String,
    /// Whether the bake is calibrated.
    pub calibrate: bool,
    /// The automatic bake's target (`lumigraph bake --auto`): cameras, resolution and depth
    /// bits are chosen for the scene, `options` gives the shading only. Absent in entries of
    /// plain bakes (and of servers before it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub auto: Option<lumigraph_core::auto_bake::AutoTarget>,
    /// The uploaded mesh's file name, recorded in the asset's provenance.
    pub source_name: String,
    /// Length of the mesh in bytes.
    pub mesh_bytes: u64,
    /// Hex SHA-256 of the mesh.
    pub mesh_sha256: String,
    /// When the job was accepted, milliseconds since the Unix epoch (the order of re-queueing).
    pub created_unix_ms: u64,
}

/// A finished job as the journal stores it.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FinishedRecord {
    /// When the job finished, milliseconds since the Unix epoch.
    pub finished_unix_ms: u64,
    /// The final status (`done` or `failed`).
    pub status: JobStatus,
}

/// What [`Journal::recover`] found.
#[derive(Debug, Default)]
pub struct Recovery {
    /// Unfinished jobs, oldest first.
    pub pending: Vec<JobSpec>,
    /// Finished jobs, oldest first.
    pub finished: Vec<FinishedRecord>,
    /// Files removed: temporaries, unreadable entries, pending entries of finished jobs and
    /// records beyond the number kept.
    pub removed: usize,
}

/// The journal folder of one assets folder.
#[derive(Clone, Debug)]
pub struct Journal {
    dir: PathBuf,
}

/// Milliseconds since the Unix epoch.
pub fn now_unix_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_millis()).unwrap_or(u64::MAX))
}

impl Journal {
    /// The journal of `assets_dir` (nothing is created until a job is written).
    pub fn new(assets_dir: &Path) -> Self {
        Self {
            dir: assets_dir.join(JOURNAL_DIR),
        }
    }

    /// The journal folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    fn path(&self, id: &str, ext: &str) -> PathBuf {
        self.dir.join(format!("{id}.{ext}"))
    }

    /// Whether the journal holds an entry or a record for job `id`.
    pub fn contains(&self, id: &str) -> bool {
        self.path(id, PENDING_EXT).exists() || self.path(id, RECORD_EXT).exists()
    }

    fn ensure_dir(&self) -> std::io::Result<()> {
        if self.dir.is_dir() {
            return Ok(());
        }
        std::fs::create_dir_all(&self.dir)?;
        if let Some(parent) = self.dir.parent() {
            lumigraph_core::sync_dir(parent)?;
        }
        Ok(())
    }

    /// Stores an accepted job durably: once this returns, a restart re-queues it.
    ///
    /// # Errors
    /// The journal folder or the entry cannot be written.
    pub fn write_pending(&self, spec: &JobSpec, mesh: &[u8]) -> Result<(), JournalError> {
        self.ensure_dir()?;
        let header = encode_spec(spec)?;
        lumigraph_core::atomic_write(&self.path(&spec.id, PENDING_EXT), |w| {
            w.write_all(&header)?;
            w.write_all(mesh)
        })?;
        Ok(())
    }

    /// The spec and mesh of the unfinished job `id`, checked (length and checksum).
    ///
    /// # Errors
    /// The entry cannot be read or is corrupt.
    pub fn read_pending(&self, id: &str) -> Result<(JobSpec, Vec<u8>), JournalError> {
        let mut bytes = std::fs::read(self.path(id, PENDING_EXT))?;
        let (spec, mesh_at) = parse_pending(id, &bytes)?;
        bytes.drain(..mesh_at);
        Ok((spec, bytes))
    }

    /// Records a finished job, then removes its pending entry. The record is durable before the
    /// entry goes, so a crash in between leaves both, and [`Self::recover`] keeps the record.
    ///
    /// # Errors
    /// The record cannot be written or the entry removed.
    pub fn finish(&self, record: &FinishedRecord) -> Result<(), JournalError> {
        self.ensure_dir()?;
        let json = serde_json::to_vec(record)
            .map_err(|e| JournalError::Corrupt(format!("encoding a job record: {e}")))?;
        lumigraph_core::atomic_write(&self.path(&record.status.id, RECORD_EXT), |w| {
            w.write_all(&json)
        })?;
        remove_if_present(&self.path(&record.status.id, PENDING_EXT))?;
        lumigraph_core::sync_dir(&self.dir)?;
        Ok(())
    }

    /// Forgets the record of a finished job (the in-memory list dropped it).
    ///
    /// # Errors
    /// The record exists but cannot be removed.
    pub fn forget(&self, id: &str) -> Result<(), JournalError> {
        remove_if_present(&self.path(id, RECORD_EXT))?;
        Ok(())
    }

    /// Reads the journal at start-up: unfinished jobs to re-queue and the newest `keep`
    /// finished records. Temporary files, unreadable entries, pending entries of jobs that have
    /// a record and records beyond `keep` are removed, each with a warning; files of other names
    /// are left alone. A missing folder is an empty journal.
    ///
    /// # Errors
    /// Only when the folder exists but cannot be listed.
    pub fn recover(&self, keep: usize) -> Result<Recovery, JournalError> {
        let mut recovery = Recovery::default();
        let entries = match std::fs::read_dir(&self.dir) {
            Ok(entries) => entries,
            Err(err) if err.kind() == std::io::ErrorKind::NotFound => return Ok(recovery),
            Err(err) => return Err(err.into()),
        };
        let mut pending = BTreeMap::new();
        let mut finished = BTreeMap::new();
        for entry in entries {
            let entry = entry?;
            let path = entry.path();
            let Some(name) = entry.file_name().to_str().map(str::to_owned) else {
                tracing::warn!(path = %path.display(), "leaving a file of the job journal whose name is not UTF-8");
                continue;
            };
            if !entry.file_type()?.is_file() {
                tracing::warn!(path = %path.display(), "leaving a non-file in the job journal");
                continue;
            }
            if lumigraph_core::temp_target(&name).is_some() {
                tracing::warn!(path = %path.display(), "removed a temporary file left by an interrupted job journal write");
                recovery.removed += remove_logged(&path);
                continue;
            }
            let Some((id, ext)) = name.rsplit_once('.') else {
                tracing::warn!(path = %path.display(), "leaving a file of unknown name in the job journal");
                continue;
            };
            let parsed = match ext {
                PENDING_EXT => {
                    read_checked(&path, |bytes| parse_pending(id, bytes)).map(|(spec, _)| {
                        pending.insert(id.to_owned(), spec);
                    })
                }
                RECORD_EXT => read_checked(&path, |bytes| parse_record(id, bytes)).map(|record| {
                    finished.insert(id.to_owned(), record);
                }),
                _ => {
                    tracing::warn!(path = %path.display(), "leaving a file of unknown name in the job journal");
                    continue;
                }
            };
            if let Err(err) = parsed {
                tracing::warn!(path = %path.display(), error = %err, "removed an unreadable job journal entry");
                recovery.removed += remove_logged(&path);
            }
        }
        // A job with both: it finished, and the crash came before its entry was removed.
        pending.retain(|id, _| {
            if finished.contains_key(id) {
                recovery.removed += remove_logged(&self.path(id, PENDING_EXT));
                false
            } else {
                true
            }
        });
        let mut finished: Vec<FinishedRecord> = finished.into_values().collect();
        finished.sort_by_key(|r| r.finished_unix_ms);
        let excess = finished.len().saturating_sub(keep);
        for old in finished.drain(..excess) {
            recovery.removed += remove_logged(&self.path(&old.status.id, RECORD_EXT));
        }
        recovery.finished = finished;
        recovery.pending = pending.into_values().collect();
        recovery.pending.sort_by_key(|s| s.created_unix_ms);
        if recovery.removed > 0 {
            lumigraph_core::sync_dir(&self.dir)?;
        }
        Ok(recovery)
    }
}

fn read_checked<T>(
    path: &Path,
    parse: impl FnOnce(&[u8]) -> Result<T, JournalError>,
) -> Result<T, JournalError> {
    parse(&std::fs::read(path)?)
}

fn remove_if_present(path: &Path) -> std::io::Result<()> {
    match std::fs::remove_file(path) {
        Err(err) if err.kind() != std::io::ErrorKind::NotFound => Err(err),
        _ => Ok(()),
    }
}

/// Removes `path`, logging a failure; 1 when removed.
fn remove_logged(path: &Path) -> usize {
    match std::fs::remove_file(path) {
        Ok(()) => 1,
        Err(err) => {
            tracing::warn!(path = %path.display(), error = %err, "cannot remove a job journal file");
            0
        }
    }
}

/// The magic line and the spec line of a pending entry.
fn encode_spec(spec: &JobSpec) -> Result<Vec<u8>, JournalError> {
    let json = serde_json::to_vec(spec)
        .map_err(|e| JournalError::Corrupt(format!("encoding a job spec: {e}")))?;
    let mut out = Vec::with_capacity(MAGIC.len() + json.len() + 1);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&json);
    out.push(b'\n');
    Ok(out)
}

/// Parses a pending entry of the file named `file_id`: its spec and where the mesh starts.
///
/// # Errors
/// [`JournalError::Corrupt`] naming what is wrong.
pub fn parse_pending(file_id: &str, bytes: &[u8]) -> Result<(JobSpec, usize), JournalError> {
    let corrupt = |why: String| Err(JournalError::Corrupt(why));
    let Some(rest) = bytes.strip_prefix(MAGIC) else {
        return corrupt("no LUMIGRAPH-JOB 1 magic line".to_owned());
    };
    let Some(end) = rest.iter().position(|&b| b == b'\n') else {
        return corrupt("the spec line is not terminated".to_owned());
    };
    let spec: JobSpec = serde_json::from_slice(&rest[..end])
        .map_err(|e| JournalError::Corrupt(format!("the spec is not valid: {e}")))?;
    check_ids(file_id, &spec.id, &spec.asset)?;
    let mesh_at = MAGIC.len() + end + 1;
    let mesh = &bytes[mesh_at..];
    if mesh.len() as u64 != spec.mesh_bytes {
        return corrupt(format!(
            "the mesh has {} bytes, the spec says {}",
            mesh.len(),
            spec.mesh_bytes
        ));
    }
    if lumigraph_core::bake::sha256_hex(mesh) != spec.mesh_sha256 {
        return corrupt("the mesh does not match its SHA-256".to_owned());
    }
    Ok((spec, mesh_at))
}

/// Parses the record of a finished job of the file named `file_id`.
///
/// # Errors
/// [`JournalError::Corrupt`] naming what is wrong.
pub fn parse_record(file_id: &str, bytes: &[u8]) -> Result<FinishedRecord, JournalError> {
    let record: FinishedRecord = serde_json::from_slice(bytes)
        .map_err(|e| JournalError::Corrupt(format!("the record is not valid: {e}")))?;
    check_ids(file_id, &record.status.id, &record.status.asset)?;
    if !record.status.is_finished() {
        return Err(JournalError::Corrupt(
            "the record is of an unfinished job".to_owned(),
        ));
    }
    Ok(record)
}

fn check_ids(file_id: &str, id: &str, asset: &str) -> Result<(), JournalError> {
    if id != file_id {
        return Err(JournalError::Corrupt(format!(
            "the entry names job {id:?}, its file {file_id:?}"
        )));
    }
    if validate_id(id).is_err() || validate_id(asset).is_err() {
        return Err(JournalError::Corrupt(format!(
            "invalid job id {id:?} or asset id {asset:?}"
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::service::jobs::JobState;

    fn spec(id: &str, mesh: &[u8], created: u64) -> JobSpec {
        JobSpec {
            id: id.to_owned(),
            asset: format!("asset-{id}"),
            options: BakeOptions::default(),
            format: "obj".to_owned(),
            calibrate: false,
            auto: None,
            source_name: "ico.obj".to_owned(),
            mesh_bytes: mesh.len() as u64,
            mesh_sha256: lumigraph_core::bake::sha256_hex(mesh),
            created_unix_ms: created,
        }
    }

    fn record(id: &str, finished: u64) -> FinishedRecord {
        FinishedRecord {
            finished_unix_ms: finished,
            status: JobStatus {
                id: id.to_owned(),
                state: JobState::Failed,
                cameras_done: 0,
                cameras_total: 12,
                asset: format!("asset-{id}"),
                error: Some("bake failed: no triangles".to_owned()),
                report: None,
            },
        }
    }

    fn entry(spec: &JobSpec, mesh: &[u8]) -> Vec<u8> {
        let mut bytes = encode_spec(spec).expect("encoding");
        bytes.extend_from_slice(mesh);
        bytes
    }

    fn names(dir: &Path) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(dir)
            .expect("listing")
            .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }

    #[test]
    fn pending_entries_round_trip() {
        let dir = tempfile::tempdir().expect("temp dir");
        let journal = Journal::new(dir.path());
        let mesh = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n\n\0binary\n";
        let s = spec("job-1", mesh, 5);
        journal.write_pending(&s, mesh).expect("writing");
        assert!(journal.contains("job-1"));
        let (read, bytes) = journal.read_pending("job-1").expect("reading");
        assert_eq!(read, s);
        assert_eq!(bytes, mesh);
        let recovery = journal.recover(10).expect("recovering");
        assert_eq!(recovery.pending, vec![s]);
        assert_eq!(recovery.removed, 0);
        journal.finish(&record("job-1", 9)).expect("finishing");
        assert_eq!(names(journal.dir()), vec!["job-1.json"]);
        let recovery = journal.recover(10).expect("recovering");
        assert!(recovery.pending.is_empty());
        assert_eq!(recovery.finished.len(), 1);
        assert_eq!(
            recovery.finished[0].status.error,
            record("job-1", 9).status.error
        );
    }

    #[test]
    fn corrupt_entries_are_rejected_with_the_reason() {
        let mesh = b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
        let good = entry(&spec("job-a", mesh, 1), mesh);
        assert!(parse_pending("job-a", &good).is_ok());
        let cases: Vec<(Vec<u8>, &str)> = vec![
            (Vec::new(), "magic"),
            (b"LUMIGRAPH-JOB 2\n{}\n".to_vec(), "magic"),
            (good[..MAGIC.len() + 10].to_vec(), "not terminated"),
            (good[..good.len() - 1].to_vec(), "bytes, the spec says"),
            ([good.as_slice(), b"x"].concat(), "bytes, the spec says"),
            (
                {
                    let mut flipped = good.clone();
                    let last = flipped.len() - 1;
                    flipped[last] ^= 1;
                    flipped
                },
                "SHA-256",
            ),
            (
                [MAGIC, b"{\"id\": \"job-a\"}\n".as_slice()].concat(),
                "not valid",
            ),
            (
                [MAGIC, b"not json\n".as_slice(), mesh.as_slice()].concat(),
                "not valid",
            ),
        ];
        for (bytes, why) in cases {
            let err = parse_pending("job-a", &bytes).expect_err(why).to_string();
            assert!(err.contains(why), "{err:?} lacks {why:?}");
        }
        // The spec must name the file's job, and valid ids.
        let err = parse_pending("job-b", &good)
            .expect_err("other id")
            .to_string();
        assert!(err.contains("its file"), "{err}");
        let mut escaping = spec("job-a", mesh, 1);
        escaping.asset = "../x".to_owned();
        let err = parse_pending("job-a", &entry(&escaping, mesh))
            .expect_err("bad asset id")
            .to_string();
        assert!(err.contains("invalid"), "{err}");
        // Records: valid JSON of a finished job only.
        let json = serde_json::to_vec(&record("job-a", 3)).expect("encoding");
        assert!(parse_record("job-a", &json).is_ok());
        assert!(parse_record("job-a", &json[..json.len() - 2]).is_err());
        let mut unfinished = record("job-a", 3);
        unfinished.status.state = JobState::Running;
        let json = serde_json::to_vec(&unfinished).expect("encoding");
        assert!(parse_record("job-a", &json).is_err());
    }

    #[test]
    fn recovery_skips_and_cleans_what_it_cannot_read() {
        let dir = tempfile::tempdir().expect("temp dir");
        let journal = Journal::new(dir.path());
        assert!(
            journal
                .recover(10)
                .expect("no folder yet")
                .pending
                .is_empty()
        );
        let mesh = b"ply\nformat ascii 1.0\nend_header\n";
        let (old, new) = (spec("job-old", mesh, 1), spec("job-new", mesh, 2));
        journal.write_pending(&new, mesh).expect("writing");
        journal.write_pending(&old, mesh).expect("writing");
        // A finished job whose pending entry was not yet removed.
        journal
            .write_pending(&spec("job-done", mesh, 0), mesh)
            .expect("writing");
        let plant = |name: &str, bytes: &[u8]| {
            std::fs::write(journal.dir().join(name), bytes).expect("planting");
        };
        plant(
            "job-done.json",
            &serde_json::to_vec(&record("job-done", 7)).expect("json"),
        );
        for (id, at) in [("job-r1", 4), ("job-r2", 8), ("job-r3", 6)] {
            plant(
                &format!("{id}.json"),
                &serde_json::to_vec(&record(id, at)).expect("json"),
            );
        }
        let torn = entry(&spec("job-torn", mesh, 3), mesh);
        plant("job-torn.job", &torn[..torn.len() - 3]);
        plant("job-garbage.json", b"{\"finished_unix_ms\": 1, \"sta");
        plant("..job", b"no id");
        plant(".job-x.job.tmp-123-0", b"half");
        plant(".job-y.json.tmp-9-1", b"");
        plant("notes.txt", b"not ours");
        let recovery = journal.recover(3).expect("recovering");
        let ids: Vec<&str> = recovery.pending.iter().map(|s| s.id.as_str()).collect();
        assert_eq!(ids, vec!["job-old", "job-new"]);
        let kept: Vec<&str> = recovery
            .finished
            .iter()
            .map(|r| r.status.id.as_str())
            .collect();
        // The oldest record beyond the three kept (job-r1) is dropped, newest last.
        assert_eq!(kept, vec!["job-r3", "job-done", "job-r2"]);
        assert_eq!(
            names(journal.dir()),
            vec![
                "job-done.json",
                "job-new.job",
                "job-old.job",
                "job-r2.json",
                "job-r3.json",
                "notes.txt"
            ]
        );
        // torn, garbage, ..job, two temporaries, job-done.job, job-r1.json.
        assert_eq!(recovery.removed, 7);
    }
}
