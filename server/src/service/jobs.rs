//! Bake jobs: an uploaded mesh baked into a new asset on the shared device, one bake at a time,
//! with progress that `GET /v1/jobs/{id}` reports.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

use serde::Serialize;

/// Most jobs remembered; the oldest finished ones are forgotten first.
const MAX_JOBS: usize = 256;

/// Where a job stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, utoipa::ToSchema)]
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
#[derive(Clone, Debug, Serialize, utoipa::ToSchema)]
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
    /// The bake report once done (cameras, resolution, triangles, bake_ms, asset_bytes).
    #[schema(value_type = Option<Object>)]
    pub report: Option<serde_json::Value>,
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
    /// Creates a queued job baking into `asset` with `cameras_total` cameras.
    pub fn create(&self, asset: String, cameras_total: u32) -> Arc<Job> {
        let job = Arc::new(Job {
            id: super::state::random_id("job"),
            asset,
            done: AtomicU32::new(0),
            total: AtomicU32::new(cameras_total),
            inner: Mutex::new(JobInner {
                state: JobState::Queued,
                error: None,
                report: None,
            }),
        });
        let mut jobs = self.jobs.lock().unwrap_or_else(PoisonError::into_inner);
        while jobs.len() >= MAX_JOBS {
            // Forget the oldest finished job; if all are running, forget the oldest anyway
            // (its bake still completes and its asset still appears).
            let pos = jobs.iter().position(|j| j.is_finished()).unwrap_or(0);
            jobs.remove(pos);
        }
        jobs.push_back(Arc::clone(&job));
        job
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
