//! Bake jobs: an uploaded mesh baked into a new asset on the shared device, one bake at a time,
//! with progress that `GET /v1/jobs/{id}` reports. Every accepted job is in the
//! [`super::journal`] until it finishes, and its final status after, so it survives a restart.

use std::collections::VecDeque;
use std::path::Path;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

use lumigraph_core::asset::Provenance;
use lumigraph_core::mesh::{Mesh, MeshFormat, load_mesh_from_bytes};
use serde::{Deserialize, Serialize};

use super::assets::{LoadedAsset, Reservation, load_file};
use super::journal::{FinishedRecord, JobSpec, Journal, now_unix_ms};
use super::state::AppState;

/// Most jobs remembered; the oldest finished ones are forgotten first (also from the journal).
pub const MAX_JOBS: usize = 256;

/// Where a job stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum JobState {
    /// Waiting for the device.
    Queued,
    /// Baking.
    Running,
    /// The asset is written and loaded.
    Done,
    /// The bake failed; see `error`.
    Failed,
}

/// A bake job as `GET /v1/jobs/{id}` reports it.
#[derive(Clone, Debug, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct JobStatus {
    /// Job id.
    pub id: String,
    /// State.
    pub state: JobState,
    /// Cameras baked so far.
    pub cameras_done: u32,
    /// Cameras to bake.
    pub cameras_total: u32,
    /// The asset id the bake writes (servable once `state` is `done`).
    pub asset: String,
    /// Why the job failed.
    pub error: Option<String>,
    /// The bake report once done (cameras, resolution, triangles, bake_ms, asset_bytes; only
    /// cameras, resolution, asset_bytes and `resumed: true` for a job whose asset was found
    /// written when the server restarted).
    #[schema(value_type = Option<Object>)]
    pub report: Option<serde_json::Value>,
}

impl JobStatus {
    /// Whether the job is done or failed.
    pub fn is_finished(&self) -> bool {
        matches!(self.state, JobState::Done | JobState::Failed)
    }
}

/// One job: progress counters updated from the bake thread, the rest under a lock.
pub struct Job {
    /// Job id.
    pub id: String,
    /// Target asset id.
    pub asset: String,
    done: AtomicU32,
    total: AtomicU32,
    inner: Mutex<JobInner>,
}

struct JobInner {
    state: JobState,
    error: Option<String>,
    report: Option<serde_json::Value>,
}

impl Job {
    /// A job in the state `status` describes.
    fn from_status(status: JobStatus) -> Self {
        Self {
            id: status.id,
            asset: status.asset,
            done: AtomicU32::new(status.cameras_done),
            total: AtomicU32::new(status.cameras_total),
            inner: Mutex::new(JobInner {
                state: status.state,
                error: status.error,
                report: status.report,
            }),
        }
    }

    /// Records progress (called from the bake thread).
    pub fn progress(&self, done: u32, total: u32) {
        self.done.store(done, Ordering::Relaxed);
        self.total.store(total, Ordering::Relaxed);
    }

    /// Moves the job to `state`.
    pub fn set_state(&self, state: JobState) {
        self.inner
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .state = state;
    }

    /// Marks the job done with its report.
    pub fn finish(&self, report: serde_json::Value) {
        let mut inner = self.inner.lock().unwrap_or_else(PoisonError::into_inner);
        inner.state = JobState::Done;
        inner.report = Some(report);
    }

    /// Marks the job failed.
    pub fn fail(&self, error: String) {
        let mut inner = self.inner.lock().unwrap_or_else(PoisonError::into_inner);
        inner.state = JobState::Failed;
        inner.error = Some(error);
    }

    /// A snapshot of the job.
    pub fn status(&self) -> JobStatus {
        let inner = self.inner.lock().unwrap_or_else(PoisonError::into_inner);
        JobStatus {
            id: self.id.clone(),
            state: inner.state,
            cameras_done: self.done.load(Ordering::Relaxed),
            cameras_total: self.total.load(Ordering::Relaxed),
            asset: self.asset.clone(),
            error: inner.error.clone(),
            report: inner.report.clone(),
        }
    }

    fn is_finished(&self) -> bool {
        matches!(
            self.inner
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .state,
            JobState::Done | JobState::Failed
        )
    }
}

/// The remembered jobs, oldest first.
#[derive(Default)]
pub struct Jobs {
    jobs: Mutex<VecDeque<Arc<Job>>>,
}

impl Jobs {
    /// A job id no remembered job and no journal entry (`taken`) has.
    pub fn fresh_id(&self, taken: impl Fn(&str) -> bool) -> String {
        loop {
            let id = super::state::random_id("job");
            if self.get(&id).is_none() && !taken(&id) {
                return id;
            }
        }
    }

    /// Adds a queued job `id` baking into `asset` with `cameras_total` cameras; also returns
    /// the ids of the finished jobs forgotten to make room.
    pub fn create(&self, id: String, asset: String, cameras_total: u32) -> (Arc<Job>, Vec<String>) {
        self.restore(JobStatus {
            id,
            state: JobState::Queued,
            cameras_done: 0,
            cameras_total,
            asset,
            error: None,
            report: None,
        })
    }

    /// Adds a job in the state `status` describes (a job read back from the journal); also
    /// returns the ids of the finished jobs forgotten to make room.
    pub fn restore(&self, status: JobStatus) -> (Arc<Job>, Vec<String>) {
        let job = Arc::new(Job::from_status(status));
        let mut forgotten = Vec::new();
        let mut jobs = self.jobs.lock().unwrap_or_else(PoisonError::into_inner);
        while jobs.len() >= MAX_JOBS {
            // Forget the oldest finished job; if all are running, forget the oldest anyway
            // (its bake still completes and its asset still appears).
            let pos = jobs.iter().position(|j| j.is_finished()).unwrap_or(0);
            if let Some(old) = jobs.remove(pos)
                && old.is_finished()
            {
                forgotten.push(old.id.clone());
            }
        }
        jobs.push_back(Arc::clone(&job));
        (job, forgotten)
    }

    /// The job `id`.
    pub fn get(&self, id: &str) -> Option<Arc<Job>> {
        self.jobs
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .iter()
            .find(|j| j.id == id)
            .cloned()
    }

    /// Whether an unfinished job writes `asset`.
    pub fn is_baking(&self, asset: &str) -> bool {
        self.jobs
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .iter()
            .any(|j| j.asset == asset && !j.is_finished())
    }
}

/// What a bake job needs to run.
pub(crate) struct BakeWork {
    /// The job as the journal holds it.
    pub spec: JobSpec,
    /// The parsed mesh, or `None` to read it back from the journal (a job resumed at start-up).
    pub mesh: Option<Mesh>,
}

/// Runs `job` in the background once the device's bake slot is free, holding `reservation` (the
/// claim on its asset id) until the job is finished. The finished job is recorded in the
/// journal before its asset is added to the store: once a client can see (and delete) the
/// asset, a restart no longer bakes it again.
pub(crate) fn spawn(state: AppState, job: Arc<Job>, reservation: Reservation, work: BakeWork) {
    tokio::spawn(async move {
        let _reservation = reservation;
        let Ok(_slot) = state.inner.bake_slot.acquire().await else {
            // Not recorded: the journal entry stays, and the next start runs the job.
            job.fail("the service is shutting down".to_owned());
            return;
        };
        job.set_state(JobState::Running);
        let baker = state.clone();
        let baking = Arc::clone(&job);
        let outcome = tokio::task::spawn_blocking(move || bake_blocking(&baker, &baking, work))
            .await
            .unwrap_or_else(|err| {
                tracing::error!(job = job.id, %err, "bake task panicked");
                Err("internal error while baking".to_owned())
            });
        let outcome = match outcome {
            Ok((report, asset)) => publish_baked(&state, &job, &asset.path)
                .await
                .map(|()| (report, asset)),
            Err(message) => Err(message),
        };
        let (outcome, asset) = match outcome {
            Ok((report, asset)) => (Ok(report), Some(asset)),
            Err(message) => {
                // A bake that met a lost device reports it, so that a new one is opened.
                let _ = state.pool().device_lost(&state.pool().engine());
                (Err(message), None)
            }
        };
        record_finished(&state, &job, outcome, asset).await;
    });
}

/// Publishes the asset a bake wrote at `path` to the shared store, if one is configured; when
/// the store refuses it the file is removed and the job fails with the reason (a bake reported
/// `done` is in the store).
pub(crate) async fn publish_baked(state: &AppState, job: &Job, path: &Path) -> Result<(), String> {
    let Some(store) = state.store() else {
        return Ok(());
    };
    match store.publish(&job.asset, path).await {
        Ok(_) => Ok(()),
        Err(err) => {
            tracing::error!(job = job.id, error = %err, "cannot publish the baked asset to the store");
            let _ = tokio::fs::remove_file(path).await;
            Err(format!("the asset was baked but not published: {err}"))
        }
    }
}

/// Records how `job` finished in the journal (logging a failure to write it), then adds its
/// asset (if any) to the store, then marks the job finished in memory: a job reported `done`
/// has its asset listed.
pub(crate) async fn record_finished(
    state: &AppState,
    job: &Arc<Job>,
    outcome: Result<serde_json::Value, String>,
    asset: Option<LoadedAsset>,
) {
    let mut status = job.status();
    match &outcome {
        Ok(report) => {
            tracing::info!(job = job.id, asset = job.asset, %report, "bake job done");
            status.state = JobState::Done;
            status.report = Some(report.clone());
        }
        Err(message) => {
            tracing::warn!(job = job.id, message, "bake job failed");
            status.state = JobState::Failed;
            status.error = Some(message.clone());
        }
    }
    let record = FinishedRecord {
        finished_unix_ms: now_unix_ms(),
        status,
    };
    let journal = state.journal().clone();
    match tokio::task::spawn_blocking(move || journal.finish(&record)).await {
        Ok(Ok(())) => {}
        Ok(Err(err)) => {
            tracing::error!(job = job.id, error = %err, "cannot record the finished job in the journal");
        }
        Err(err) => tracing::error!(job = job.id, %err, "recording the finished job panicked"),
    }
    if let Some(asset) = asset {
        state.assets().insert(asset);
        state.metrics().set_assets(state.assets().len());
    }
    match outcome {
        Ok(report) => job.finish(report),
        Err(message) => job.fail(message),
    }
}

/// Bakes, writes and loads the job's asset (blocking); the report, or why it failed.
fn bake_blocking(
    state: &AppState,
    job: &Arc<Job>,
    work: BakeWork,
) -> Result<(serde_json::Value, LoadedAsset), String> {
    let BakeWork { spec, mesh } = work;
    let mesh = match mesh {
        Some(mesh) => mesh,
        None => read_mesh(state.journal(), &spec)?,
    };
    let options = spec.options;
    let source = Provenance {
        source_name: spec.source_name.clone(),
        source_sha256: spec.mesh_sha256.clone(),
        ..Default::default()
    };
    let path = state.assets().path_for(&job.asset);
    let mut progress = |done, total| job.progress(done, total);
    let report = if let Some(target) = spec.auto {
        let engine = state.pool().engine();
        let engines = lumigraph_core::auto_bake::AutoEngines {
            baker: &engine.baker,
            renderer: &engine.renderer,
            reference: &engine.reference,
        };
        let baked = lumigraph_core::auto_bake::auto_bake(
            &engines,
            &mesh,
            &options.shading,
            target,
            &source,
            spec.calibrate,
            // The counter follows each bake in turn: the three calibration bakes, then the
            // bakes of chosen settings.
            &mut |stage| match stage {
                lumigraph_core::auto_bake::AutoStage::CalibrationBake { done, cameras, .. }
                | lumigraph_core::auto_bake::AutoStage::Bake { done, cameras } => {
                    job.progress(done, cameras);
                }
                _ => {}
            },
        )
        .map_err(|e| format!("automatic bake failed: {e}"))?;
        lumigraph_core::atomic_write(&path, |w| std::io::Write::write_all(w, &baked.bytes))
            .map_err(|e| format!("writing {}: {e}", path.display()))?;
        let report = &baked.report;
        let setting = &report.choice.setting;
        serde_json::json!({
            "cameras": setting.cameras,
            "resolution": setting.resolution,
            "depth_bits": setting.depth_bits,
            "triangles": mesh.triangles.len(),
            "auto_bake": {
                "target": report.target,
                "choice": report.choice,
                "bakes": report.bakes,
                "measured_psnr": report.measured_psnr,
                "held_out_views": lumigraph_core::auto_bake::AUTO_VIEWS,
                "target_met": report.target_met,
                "message": report.message,
            },
            "calibrate_ms": report.calibrate_ms,
            "bake_ms": report.bake_ms,
            "verify_ms": report.verify_ms,
            "asset_bytes": report.asset_bytes,
        })
    } else if spec.calibrate {
        let baked = state
            .bake_calibrated(&mesh, &options, &source, &path, &mut progress)
            .map_err(|e| format!("bake failed: {e:#}"))?;
        serde_json::json!({
            "cameras": options.cameras,
            "resolution": options.resolution,
            "triangles": mesh.triangles.len(),
            "bake_ms": baked.bake_ms,
            "calibrate_ms": baked.calibrate_ms,
            "asset_bytes": baked.bytes.len(),
        })
    } else {
        let report = state
            .pool()
            .engine()
            .baker
            .bake_to_file(&mesh, &options, &source, &path, &mut progress)
            .map_err(|e| format!("bake failed: {e}"))?;
        serde_json::to_value(&report).unwrap_or_default()
    };
    let asset = load_file(state.assets(), &state.pool().engine(), &job.asset, &path).map_err(
        // The file stays in the folder, where a restart with a larger budget loads it.
        |e| format!("the baked asset cannot be loaded: {e}"),
    )?;
    Ok((report, asset))
}

/// The mesh of a resumed job, read back from its journal entry.
fn read_mesh(journal: &Journal, spec: &JobSpec) -> Result<Mesh, String> {
    let (_, bytes) = journal
        .read_pending(&spec.id)
        .map_err(|e| format!("the job's stored mesh cannot be read: {e}"))?;
    let format = MeshFormat::from_extension(&spec.format)
        .ok_or_else(|| format!("the job's stored mesh format {:?} is unknown", spec.format))?;
    load_mesh_from_bytes(&bytes, format)
        .map_err(|e| format!("the job's stored mesh cannot be read: {e}"))
}
