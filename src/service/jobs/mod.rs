//! Jobs: a bounded FIFO queue, N blocking worker threads and the store of
//! finished results.
//!
//! A job is accepted only when it fits in the queue ([`Jobs::submit`]
//! either stores and queues it, or refuses it whole). Worker threads (never
//! the async runtime) take jobs in arrival order and run the core pipeline
//! inside `catch_unwind`, so a panic fails that job only. Finished jobs are
//! kept for a time to live; their results count against a memory budget,
//! the oldest evicted first.
//!
//! Where jobs live is the [`Backend`]: the memory of this process (the
//! default, no server needed), or a Redis shared by every replica
//! ([`redis`]), where workers claim jobs with renewable leases and any
//! replica answers for any job.

mod redis;
mod store;
mod worker;

pub use redis::{RedisSettings, RedisStore};

use crate::service::error::{Code, Problem};
use axum::body::Bytes;
use meshsmooth_core::io::Format;
use meshsmooth_core::job::Input;
use meshsmooth_core::{Params, Stage};
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime};
use store::Store;
use tokio::sync::watch;
use tracing::warn;
use uuid::Uuid;

/// Locks `m`, ignoring poisoning: job state stays consistent under panics
/// because every critical section is a plain assignment.
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Settings of the job system.
#[derive(Debug, Clone)]
pub struct JobSettings {
    /// Worker threads (jobs running at once).
    pub workers: usize,
    /// Jobs that may wait for a worker (at least 1).
    pub queue_capacity: usize,
    /// Longest a job may run.
    pub time_limit: Duration,
    /// How long finished jobs are kept.
    pub result_ttl: Duration,
    /// Bytes of results kept; the oldest are evicted beyond it.
    pub result_memory: u64,
}

/// A test-only fault injected into a job (honoured only when the server
/// runs with `--enable-test-hooks`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TestHook {
    /// Panic inside the job, where the pipeline would run.
    Panic,
    /// Sleep this long (cancellably) before running the pipeline.
    Sleep(Duration),
}

/// Everything a new job needs.
#[derive(Debug)]
pub struct Submission {
    /// The parsed upload.
    pub document: Input,
    /// Validated parameters.
    pub params: Params,
    /// Format the result is written in.
    pub output_format: Format,
    /// Size of the uploaded mesh file.
    pub upload_bytes: u64,
    /// The uploaded file as received (kept by a shared store, where
    /// another replica may run the job).
    pub raw: Bytes,
    /// `x-request-id` of the request that submitted the job.
    pub request_id: String,
    /// Fault injection for tests.
    pub hook: Option<TestHook>,
}

/// Why a job was cancelled.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CancelReason {
    /// `DELETE /v1/jobs/{id}`, or the one-call client went away.
    Client,
    /// The job ran past the per-job time limit.
    TimeLimit,
    /// The server is shutting down.
    Shutdown,
}

/// A finished job's output: the smoothed mesh file and the JSON report.
#[derive(Debug)]
pub struct JobResult {
    /// The smoothed mesh, encoded in `format`.
    pub mesh: Bytes,
    /// Format of `mesh`.
    pub format: Format,
    /// The quality report as JSON.
    pub report: Bytes,
}

/// A succeeded job's result as the store holds it: its sizes, and the
/// bytes when they are at hand (a shared store fetches them on demand).
#[derive(Debug, Clone)]
pub struct HeldResult {
    /// Size of the smoothed mesh file.
    pub mesh_bytes: u64,
    /// Size of the JSON report.
    pub report_bytes: u64,
    /// The result itself, when held in this process.
    pub data: Option<Arc<JobResult>>,
}

impl HeldResult {
    /// A result held in this process.
    pub fn here(result: JobResult) -> HeldResult {
        HeldResult {
            mesh_bytes: result.mesh.len() as u64,
            report_bytes: result.report.len() as u64,
            data: Some(Arc::new(result)),
        }
    }
}

/// How a job ended.
#[derive(Debug, Clone)]
pub enum Outcome {
    /// Smoothed; `None` once the result was evicted for memory.
    Succeeded(Option<HeldResult>),
    /// Failed with this problem.
    Failed(Problem),
    /// Cancelled before it finished.
    Cancelled(CancelReason),
}

/// Where a job is in its life.
#[derive(Debug, Clone)]
pub enum JobState {
    /// Waiting for a worker.
    Queued,
    /// On a worker.
    Running {
        /// When it started.
        started: Instant,
        /// When it started, wall clock.
        started_at: SystemTime,
        /// The current pipeline stage (None before the first update).
        stage: Option<Stage>,
        /// Fraction of the current stage done, in `[0, 1]`.
        fraction: f64,
    },
    /// Done, one way or another.
    Finished {
        /// When it started running (None if it never ran).
        started: Option<(Instant, SystemTime)>,
        /// When it finished.
        finished: Instant,
        /// When it finished, wall clock.
        finished_at: SystemTime,
        /// How it ended.
        outcome: Outcome,
    },
}

/// What the uploaded mesh was.
#[derive(Debug, Clone, Copy)]
pub struct InputInfo {
    /// Format it was read as.
    pub format: Format,
    /// Vertex count.
    pub vertices: usize,
    /// Face count.
    pub faces: usize,
    /// Size of the mesh file in bytes.
    pub bytes: u64,
}

/// One smoothing job.
#[derive(Debug)]
pub struct Job {
    /// Random (v4) id: unguessable, so it doubles as a capability.
    pub id: Uuid,
    /// `x-request-id` of the submitting request.
    pub request_id: String,
    /// The upload.
    pub input: InputInfo,
    /// Format the result is written in.
    pub output_format: Format,
    /// Parameters of the run.
    pub params: Params,
    /// When the job was accepted.
    pub created: Instant,
    /// When the job was accepted, wall clock.
    pub created_at: SystemTime,
    hook: Option<TestHook>,
    document: Mutex<Option<Input>>,
    cancel: AtomicBool,
    cancel_reason: Mutex<Option<CancelReason>>,
    state: Mutex<JobState>,
    changes: watch::Sender<u64>,
    /// Times the job was started (a shared store runs a job again when
    /// the replica running it died).
    attempts: AtomicU32,
    /// 0-based place in the queue when known from the store.
    queue_position: Option<usize>,
    /// The lease of a job claimed from a shared store.
    claim: Option<Claim>,
}

/// A worker's hold on a job of a shared store: the queue entry it claimed
/// and the attempt it runs.
#[derive(Debug)]
pub(crate) struct Claim {
    entry: String,
    attempt: u32,
    consumer: String,
    /// Set when another worker took the job over (our lease lapsed).
    lost: AtomicBool,
}

impl Job {
    fn new(s: Submission) -> Self {
        let input = InputInfo {
            format: s.document.format(),
            vertices: s.document.mesh().num_vertices(),
            faces: s.document.mesh().num_faces(),
            bytes: s.upload_bytes,
        };
        Job {
            id: Uuid::new_v4(),
            request_id: s.request_id,
            input,
            output_format: s.output_format,
            params: s.params,
            created: Instant::now(),
            created_at: SystemTime::now(),
            hook: s.hook,
            document: Mutex::new(Some(s.document)),
            cancel: AtomicBool::new(false),
            cancel_reason: Mutex::new(None),
            state: Mutex::new(JobState::Queued),
            changes: watch::Sender::new(0),
            attempts: AtomicU32::new(0),
            queue_position: None,
            claim: None,
        }
    }

    /// Times the job was started.
    pub fn attempts(&self) -> u32 {
        self.attempts.load(Ordering::Relaxed)
    }

    /// 0-based place in the queue, when the store knows it.
    pub fn stored_queue_position(&self) -> Option<usize> {
        self.queue_position
    }

    /// A snapshot of the state.
    pub fn state(&self) -> JobState {
        lock(&self.state).clone()
    }

    /// True once the job succeeded, failed or was cancelled.
    pub fn is_finished(&self) -> bool {
        matches!(*lock(&self.state), JobState::Finished { .. })
    }

    /// True while a cancellation was requested but the job has not
    /// stopped yet.
    pub fn cancel_requested(&self) -> bool {
        self.cancel.load(Ordering::Relaxed) && !self.is_finished()
    }

    /// Notifies on every change of state or progress.
    pub fn subscribe(&self) -> watch::Receiver<u64> {
        self.changes.subscribe()
    }

    /// Waits until the job is finished and returns its final state.
    pub async fn finished(&self) -> JobState {
        let mut changes = self.subscribe();
        loop {
            let state = self.state();
            if matches!(state, JobState::Finished { .. }) {
                return state;
            }
            // The sender lives as long as the job, so this only errs if the
            // job is being dropped; the state is final then.
            if changes.changed().await.is_err() {
                return self.state();
            }
        }
    }

    /// Raises the cancellation flag (the core checks it between and inside
    /// stages). The first reason given wins.
    pub fn request_cancel(&self, reason: CancelReason) {
        lock(&self.cancel_reason).get_or_insert(reason);
        self.cancel.store(true, Ordering::Relaxed);
        self.notify();
    }

    fn cancel_reason(&self) -> CancelReason {
        lock(&self.cancel_reason).unwrap_or(CancelReason::Client)
    }

    fn notify(&self) {
        self.changes.send_modify(|v| *v = v.wrapping_add(1));
    }

    fn set_running(&self) -> Instant {
        let started = Instant::now();
        self.attempts.fetch_max(1, Ordering::Relaxed);
        *lock(&self.state) = JobState::Running {
            started,
            started_at: SystemTime::now(),
            stage: None,
            fraction: 0.0,
        };
        self.notify();
        started
    }

    /// Records progress; notifies watchers when the stage changes or the
    /// fraction moved by at least 1%.
    fn set_progress(&self, new_stage: Stage, new_fraction: f64) {
        let notify = {
            let mut state = lock(&self.state);
            let JobState::Running {
                stage, fraction, ..
            } = &mut *state
            else {
                return;
            };
            let changed = *stage != Some(new_stage)
                || (new_fraction - *fraction).abs() >= 0.01
                || (new_fraction >= 1.0 && *fraction < 1.0);
            if changed {
                *stage = Some(new_stage);
                *fraction = new_fraction;
            }
            changed
        };
        if notify {
            self.notify();
        }
    }

    /// Moves the job to its final state, as of `finished`, and wakes its
    /// waiters.
    fn finish(&self, outcome: Outcome, finished: Instant) {
        {
            let mut state = lock(&self.state);
            let started = match &*state {
                JobState::Running {
                    started,
                    started_at,
                    ..
                } => Some((*started, *started_at)),
                _ => None,
            };
            *state = JobState::Finished {
                started,
                finished,
                finished_at: SystemTime::now(),
                outcome,
            };
        }
        *lock(&self.document) = None;
        self.notify();
    }

    fn evict_result(&self) {
        if let JobState::Finished {
            outcome: Outcome::Succeeded(result),
            ..
        } = &mut *lock(&self.state)
        {
            *result = None;
        }
        self.notify();
    }

    fn take_document(&self) -> Option<Input> {
        lock(&self.document).take()
    }
}

#[derive(Debug, Default)]
struct Queue {
    items: VecDeque<Arc<Job>>,
    closed: bool,
}

/// Where jobs live.
#[derive(Debug, Clone)]
pub enum Backend {
    /// In this process: the queue and results go with it.
    Memory,
    /// In a Redis shared by every replica (`--store redis://…`).
    Redis(Arc<RedisStore>),
}

#[derive(Debug)]
struct Inner {
    settings: JobSettings,
    backend: Backend,
    /// The async runtime, for the worker threads' calls to a shared store.
    runtime: tokio::runtime::Handle,
    queue: Mutex<Queue>,
    work_ready: Condvar,
    /// Every job (memory backend), or the jobs running here (shared).
    store: Mutex<Store>,
    busy: AtomicUsize,
    /// Moving average of run times, in milliseconds, for `Retry-After`.
    mean_run_ms: AtomicU64,
    /// Set when the shutdown deadline passed: queued work is given up.
    abandoned: AtomicBool,
}

/// Counts for `/metrics` and `/readyz`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Stats {
    /// Jobs waiting for a worker (fleet-wide with a shared store).
    pub queued: usize,
    /// Jobs on a worker (of this replica with a shared store).
    pub running: usize,
    /// Known jobs that succeeded (memory store only).
    pub succeeded: usize,
    /// Known jobs that failed (memory store only).
    pub failed: usize,
    /// Known jobs that were cancelled (memory store only).
    pub cancelled: usize,
    /// Workers busy with a job.
    pub busy_workers: usize,
    /// Results held.
    pub results: usize,
    /// Bytes held by results.
    pub result_bytes: u64,
}

/// What `DELETE /v1/jobs/{id}` did.
#[derive(Debug)]
pub enum Deleted {
    /// The job was waiting and is now cancelled.
    Cancelled(Arc<Job>),
    /// The job is running; its cancellation flag is raised.
    Cancelling(Arc<Job>),
    /// The job had finished and is now forgotten.
    Forgotten,
}

/// The job system: queue, workers, store. Cheap to clone.
#[derive(Debug, Clone)]
pub struct Jobs {
    inner: Arc<Inner>,
}

/// The worker threads, to be joined at shutdown.
#[derive(Debug)]
pub struct Workers {
    handles: Vec<JoinHandle<()>>,
}

/// Follows a job's changes: the job's own channel in memory, its stored
/// version with a shared store.
pub struct JobWatch {
    jobs: Jobs,
    job: Arc<Job>,
    local: watch::Receiver<u64>,
    version: Option<u64>,
}

impl JobWatch {
    /// The job as it is now; None once it is gone from the store.
    pub async fn current(&mut self) -> Result<Option<Arc<Job>>, Problem> {
        match &self.jobs.inner.backend {
            Backend::Memory => {
                self.local.borrow_and_update();
                Ok(Some(self.job.clone()))
            }
            Backend::Redis(store) => {
                self.version = store.version(&self.job.id).await?;
                let job = store.get(&self.job.id).await?;
                if let Some(job) = &job {
                    self.job = job.clone();
                }
                Ok(job)
            }
        }
    }

    /// Waits for the next change; false when no more can come.
    pub async fn changed(&mut self) -> bool {
        match &self.jobs.inner.backend {
            Backend::Memory => self.local.changed().await.is_ok(),
            Backend::Redis(store) => loop {
                tokio::time::sleep(redis::POLL).await;
                match store.version(&self.job.id).await {
                    Ok(None) => return false,
                    Ok(v) if v != self.version => return true,
                    // Unchanged, or Redis is away for now: keep waiting.
                    Ok(_) | Err(_) => {}
                }
            },
        }
    }
}

impl Jobs {
    /// Starts `settings.workers` worker threads on `backend`. Must be called
    /// inside the async runtime.
    pub fn start(settings: JobSettings, backend: Backend) -> std::io::Result<(Jobs, Workers)> {
        let store = Store::new(settings.result_memory, settings.result_ttl);
        let inner = Arc::new(Inner {
            settings,
            backend,
            runtime: tokio::runtime::Handle::current(),
            queue: Mutex::new(Queue::default()),
            work_ready: Condvar::new(),
            store: Mutex::new(store),
            busy: AtomicUsize::new(0),
            mean_run_ms: AtomicU64::new(1000),
            abandoned: AtomicBool::new(false),
        });
        let handles = worker::spawn(&inner)?;
        Ok((Jobs { inner }, Workers { handles }))
    }

    /// The settings.
    pub fn settings(&self) -> &JobSettings {
        &self.inner.settings
    }

    /// Refuses early, before an upload is read, when it could not be
    /// queued anyway.
    pub async fn check_room(&self) -> Result<(), Problem> {
        let refusal = match &self.inner.backend {
            Backend::Memory => self.inner.refusal(&lock(&self.inner.queue)),
            Backend::Redis(store) => match self.inner.closed_refusal() {
                Some(p) => Some(p),
                None => self.inner.full_refusal(store.queued().await?),
            },
        };
        match refusal {
            Some(problem) => Err(count_rejection(problem)),
            None => Ok(()),
        }
    }

    /// Stores and queues a job, or refuses it whole (503 `queue_full`,
    /// `shutting_down` or `store_unavailable`).
    pub async fn submit(&self, mut submission: Submission) -> Result<Arc<Job>, Problem> {
        let Backend::Redis(store) = &self.inner.backend else {
            return self.submit_here(submission);
        };
        if let Some(problem) = self.inner.closed_refusal() {
            return Err(count_rejection(problem));
        }
        let raw = std::mem::take(&mut submission.raw);
        let job = Job::new(submission);
        let Some(document) = job.take_document() else {
            return Err(Problem::internal("the upload was not parsed"));
        };
        let capacity = self.inner.settings.queue_capacity;
        match store.submit(&job, &raw, document, capacity).await? {
            redis::Submitted::Queued => {
                metrics::counter!("meshsmooth_jobs_submitted_total").increment(1);
                Ok(Arc::new(job))
            }
            redis::Submitted::Full(queued) => {
                let problem = self.inner.full_refusal(queued.max(capacity));
                Err(count_rejection(
                    problem.unwrap_or_else(|| self.inner.queue_full(capacity)),
                ))
            }
        }
    }

    fn submit_here(&self, submission: Submission) -> Result<Arc<Job>, Problem> {
        let mut q = lock(&self.inner.queue);
        if let Some(problem) = self.inner.refusal(&q) {
            return Err(count_rejection(problem));
        }
        let job = Arc::new(Job::new(submission));
        lock(&self.inner.store).insert(job.clone());
        q.items.push_back(job.clone());
        drop(q);
        self.inner.work_ready.notify_one();
        metrics::counter!("meshsmooth_jobs_submitted_total").increment(1);
        Ok(job)
    }

    /// The job with `id`, unless unknown or expired.
    pub async fn get(&self, id: &Uuid) -> Result<Option<Arc<Job>>, Problem> {
        match &self.inner.backend {
            Backend::Memory => Ok(lock(&self.inner.store).get(id)),
            Backend::Redis(store) => store.get(id).await,
        }
    }

    /// Follows the changes of `job`.
    pub fn watch(&self, job: &Arc<Job>) -> JobWatch {
        JobWatch {
            jobs: self.clone(),
            job: job.clone(),
            local: job.subscribe(),
            version: None,
        }
    }

    /// Waits until `job` is finished; returns it as it finished (None if it
    /// was forgotten meanwhile).
    pub async fn finished(&self, job: &Arc<Job>) -> Result<Option<Arc<Job>>, Problem> {
        if let Backend::Memory = self.inner.backend {
            job.finished().await;
            return Ok(Some(job.clone()));
        }
        let mut watch = self.watch(job);
        loop {
            match watch.current().await? {
                Some(now) if now.is_finished() => return Ok(Some(now)),
                Some(_) => {}
                None => return Ok(None),
            }
            if !watch.changed().await {
                return Ok(None);
            }
        }
    }

    /// The result bytes of a succeeded job; None once evicted or expired.
    pub async fn result(
        &self,
        job: &Job,
        held: HeldResult,
    ) -> Result<Option<Arc<JobResult>>, Problem> {
        if let Some(data) = held.data {
            return Ok(Some(data));
        }
        match &self.inner.backend {
            Backend::Memory => Ok(None),
            Backend::Redis(store) => store.result(&job.id, job.output_format).await,
        }
    }

    /// 0-based position of a queued job (0: next to run).
    pub fn queue_position(&self, id: &Uuid) -> Option<usize> {
        lock(&self.inner.queue)
            .items
            .iter()
            .position(|j| j.id == *id)
    }

    /// Asks a queued or running job to stop (the one-call client went
    /// away); a finished job is left alone.
    pub fn cancel(&self, job: &Arc<Job>) {
        match &self.inner.backend {
            Backend::Memory => job.request_cancel(CancelReason::Client),
            Backend::Redis(store) => {
                let (store, id) = (store.clone(), job.id);
                let ttl = self.inner.settings.result_ttl;
                self.inner.runtime.spawn(async move {
                    let _ = store.delete(&id, ttl, false).await;
                });
            }
        }
    }

    /// Cancels a queued or running job, or forgets a finished one.
    pub async fn delete(&self, id: &Uuid) -> Result<Option<Deleted>, Problem> {
        let Backend::Redis(store) = &self.inner.backend else {
            return Ok(self.delete_here(id));
        };
        let ttl = self.inner.settings.result_ttl;
        let deleted = store.delete(id, ttl, true).await?;
        let job = || async { store.get(id).await };
        Ok(match deleted {
            redis::DeleteOutcome::Missing => None,
            redis::DeleteOutcome::Forgotten => Some(Deleted::Forgotten),
            redis::DeleteOutcome::Cancelled => job().await?.map(Deleted::Cancelled),
            redis::DeleteOutcome::Cancelling => job().await?.map(Deleted::Cancelling),
        })
    }

    fn delete_here(&self, id: &Uuid) -> Option<Deleted> {
        let job = lock(&self.inner.store).get(id)?;
        let queued = {
            let mut q = lock(&self.inner.queue);
            let at = q.items.iter().position(|j| j.id == *id);
            at.and_then(|at| q.items.remove(at))
        };
        if let Some(job) = queued {
            job.request_cancel(CancelReason::Client);
            self.inner
                .finish(&job, Outcome::Cancelled(CancelReason::Client));
            return Some(Deleted::Cancelled(job));
        }
        if job.is_finished() {
            lock(&self.inner.store).remove(id);
            return Some(Deleted::Forgotten);
        }
        job.request_cancel(CancelReason::Client);
        Some(Deleted::Cancelling(job))
    }

    /// Forgets expired jobs and stops jobs past the time limit. Called
    /// periodically.
    pub async fn sweep(&self) {
        let expired = lock(&self.inner.store).expire(Instant::now());
        let mut expired_results = expired.results;
        if let Backend::Redis(store) = &self.inner.backend {
            // The shared store expires jobs itself; this keeps the result
            // budget's count in step.
            expired_results += store.sweep().await.unwrap_or(0);
        }
        if expired_results > 0 {
            metrics::counter!("meshsmooth_results_evicted_total", "reason" => "ttl")
                .increment(expired_results as u64);
        }
        if expired.jobs > 0 {
            metrics::counter!("meshsmooth_jobs_expired_total").increment(expired.jobs as u64);
        }
        let limit = self.inner.settings.time_limit;
        for job in self.running() {
            if let JobState::Running { started, .. } = job.state()
                && started.elapsed() > limit
            {
                job.request_cancel(CancelReason::TimeLimit);
            }
        }
    }

    fn running(&self) -> Vec<Arc<Job>> {
        let store = lock(&self.inner.store);
        store
            .jobs()
            .filter(|j| matches!(*lock(&j.state), JobState::Running { .. }))
            .cloned()
            .collect()
    }

    /// Counts for metrics and readiness.
    pub async fn stats(&self) -> Stats {
        let mut stats = self.local_stats();
        if let Backend::Redis(store) = &self.inner.backend {
            stats.queued = store.queued().await.unwrap_or(0);
            if let Ok((results, bytes)) = store.results().await {
                stats.results = results;
                stats.result_bytes = bytes;
            }
        }
        stats
    }

    fn local_stats(&self) -> Stats {
        let queued = lock(&self.inner.queue).items.len();
        let store = lock(&self.inner.store);
        let mut stats = Stats {
            queued,
            busy_workers: self.inner.busy.load(Ordering::Relaxed),
            results: store.result_count(),
            result_bytes: store.result_bytes(),
            ..Stats::default()
        };
        for job in store.jobs() {
            match &*lock(&job.state) {
                JobState::Queued => {}
                JobState::Running { .. } => stats.running += 1,
                JobState::Finished { outcome, .. } => match outcome {
                    Outcome::Succeeded(_) => stats.succeeded += 1,
                    Outcome::Failed(_) => stats.failed += 1,
                    Outcome::Cancelled(_) => stats.cancelled += 1,
                },
            }
        }
        stats
    }

    /// Ok when a new job would be accepted now; else the problem a
    /// submission would get (`/readyz`).
    pub async fn ready(&self) -> Result<(), Problem> {
        match &self.inner.backend {
            Backend::Memory => match self.inner.refusal(&lock(&self.inner.queue)) {
                Some(problem) => Err(problem),
                None => Ok(()),
            },
            Backend::Redis(store) => {
                if let Some(problem) = self.inner.closed_refusal() {
                    return Err(problem);
                }
                match self.inner.full_refusal(store.queued().await?) {
                    Some(problem) => Err(problem),
                    None => Ok(()),
                }
            }
        }
    }

    /// Stops accepting jobs and claiming new ones. With the memory store
    /// the workers go on with the queued jobs; with a shared store they
    /// stay queued for the other replicas.
    pub fn close(&self) {
        lock(&self.inner.queue).closed = true;
        self.inner.work_ready.notify_all();
    }

    /// The shutdown deadline passed: cancels the jobs still queued here
    /// (memory store), logging each, and stops the running ones (a shared
    /// store gets them back into its queue).
    pub fn abandon(&self) {
        self.inner.abandoned.store(true, Ordering::Relaxed);
        let drained: Vec<_> = lock(&self.inner.queue).items.drain(..).collect();
        for job in drained {
            warn!(job_id = %job.id, request_id = %job.request_id, "queued job not run before the shutdown deadline; cancelled");
            job.request_cancel(CancelReason::Shutdown);
            self.inner
                .finish(&job, Outcome::Cancelled(CancelReason::Shutdown));
        }
        self.cancel_running(CancelReason::Shutdown);
    }

    /// Raises the cancellation flag of every running job.
    pub fn cancel_running(&self, reason: CancelReason) {
        for job in self.running() {
            job.request_cancel(reason);
        }
    }
}

fn shutting_down() -> Problem {
    Problem::new(
        Code::ShuttingDown,
        "the service is shutting down and accepts no new jobs",
    )
}

/// Counts a refused submission by its code.
fn count_rejection(problem: Problem) -> Problem {
    metrics::counter!("meshsmooth_jobs_rejected_total", "reason" => problem.code.as_str())
        .increment(1);
    problem
}

impl Inner {
    fn refusal(&self, q: &Queue) -> Option<Problem> {
        if q.closed {
            return Some(shutting_down());
        }
        self.full_refusal(q.items.len())
    }

    fn closed_refusal(&self) -> Option<Problem> {
        lock(&self.queue).closed.then(shutting_down)
    }

    fn full_refusal(&self, queued: usize) -> Option<Problem> {
        (queued >= self.settings.queue_capacity).then(|| self.queue_full(queued))
    }

    fn queue_full(&self, queued: usize) -> Problem {
        let capacity = self.settings.queue_capacity;
        let retry = self.retry_after(queued);
        Problem::new(
            Code::QueueFull,
            format!("the job queue is full ({capacity} jobs waiting); retry in about {retry} s"),
        )
        .with_retry_after(retry)
    }

    /// Seconds until a queue slot is likely free: the queue ahead, spread
    /// over the workers, at the recent mean run time.
    fn retry_after(&self, queued: usize) -> u64 {
        let workers = self.settings.workers.max(1) as f64;
        let mean = self.mean_run_ms.load(Ordering::Relaxed) as f64 / 1000.0;
        let seconds = (queued as f64 / workers).max(1.0) * mean;
        (seconds.ceil() as u64).clamp(1, 3600)
    }

    /// Marks `job` finished, files it in the store and evicts results over
    /// the budget. A job claimed from a shared store is filed there (or
    /// handed back to its queue when a shutdown cut it short).
    fn finish(&self, job: &Arc<Job>, outcome: Outcome) {
        if let (Backend::Redis(store), Some(claim)) = (&self.backend, &job.claim) {
            worker::file_shared(self, store, job, claim, &outcome);
            job.finish(outcome, Instant::now());
            lock(&self.store).remove(&job.id);
            return;
        }
        let label = match &outcome {
            Outcome::Succeeded(_) => "succeeded",
            Outcome::Failed(_) => "failed",
            Outcome::Cancelled(_) => "cancelled",
        };
        metrics::counter!("meshsmooth_jobs_finished_total", "outcome" => label).increment(1);
        let result_bytes = match &outcome {
            Outcome::Succeeded(Some(r)) => Some(r.mesh_bytes + r.report_bytes),
            _ => None,
        };
        // Older results leave before this job's waiters wake: whoever sees
        // it finished also sees the budget kept.
        let at = Instant::now();
        let evicted = lock(&self.store).finished(job.id, at, result_bytes);
        if !evicted.is_empty() {
            metrics::counter!("meshsmooth_results_evicted_total", "reason" => "memory")
                .increment(evicted.len() as u64);
        }
        for old in evicted {
            old.evict_result();
        }
        job.finish(outcome, at);
    }

    fn record_run_time(&self, run: Duration) {
        let ms = run.as_millis().min(u64::MAX as u128) as u64;
        let old = self.mean_run_ms.load(Ordering::Relaxed);
        self.mean_run_ms
            .store((old * 7 + ms).div_ceil(8), Ordering::Relaxed);
    }

    /// Blocks until a job is queued (or claimed, from a shared store); None
    /// once the queue is closed (and, in memory, empty).
    fn next_job(&self, worker: usize) -> Option<Arc<Job>> {
        if let Backend::Redis(store) = &self.backend {
            let stop = || lock(&self.queue).closed;
            let job = self.runtime.block_on(store.claim(worker, &stop))?;
            lock(&self.store).insert(job.clone());
            worker::keep_lease(self, store, &job);
            return Some(job);
        }
        let mut q = lock(&self.queue);
        loop {
            if let Some(job) = q.items.pop_front() {
                return Some(job);
            }
            if q.closed {
                return None;
            }
            q = self
                .work_ready
                .wait(q)
                .unwrap_or_else(PoisonError::into_inner);
        }
    }
}

impl Workers {
    /// Waits for the workers to finish their current job (the queue must be
    /// closed first); true if all did within `deadline`. Workers still busy
    /// then can be waited for again.
    pub fn join(&mut self, deadline: Duration) -> bool {
        let start = Instant::now();
        while let Some(handle) = self.handles.last() {
            if handle.is_finished() {
                if let Some(handle) = self.handles.pop() {
                    let _ = handle.join();
                }
                continue;
            }
            if start.elapsed() > deadline {
                return false;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        true
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A queued job without a document, for store tests.
    pub(crate) fn job() -> Arc<Job> {
        Arc::new(Job {
            id: Uuid::new_v4(),
            request_id: String::new(),
            input: InputInfo {
                format: Format::Obj,
                vertices: 0,
                faces: 0,
                bytes: 0,
            },
            output_format: Format::Obj,
            params: Params::default(),
            created: Instant::now(),
            created_at: SystemTime::now(),
            hook: None,
            document: Mutex::new(None),
            cancel: AtomicBool::new(false),
            cancel_reason: Mutex::new(None),
            state: Mutex::new(JobState::Queued),
            changes: watch::Sender::new(0),
            attempts: AtomicU32::new(0),
            queue_position: None,
            claim: None,
        })
    }

    #[test]
    fn the_first_cancel_reason_wins() {
        let j = job();
        j.request_cancel(CancelReason::TimeLimit);
        j.request_cancel(CancelReason::Client);
        assert_eq!(j.cancel_reason(), CancelReason::TimeLimit);
        assert!(j.cancel_requested());
    }

    #[test]
    fn progress_notifies_on_stage_change_and_whole_percents() {
        let j = job();
        j.set_running();
        let rx = j.subscribe();
        let seen = *rx.borrow();
        j.set_progress(Stage::Initial, 0.0);
        assert!(rx.has_changed().unwrap());
        let v = *rx.borrow();
        j.set_progress(Stage::Initial, 0.004);
        assert_eq!(*rx.borrow(), v, "sub-percent steps are not sent");
        j.set_progress(Stage::Initial, 0.02);
        assert!(*rx.borrow() != v);
        assert!(v != seen);
        let JobState::Running {
            stage, fraction, ..
        } = j.state()
        else {
            panic!("not running");
        };
        assert_eq!(stage, Some(Stage::Initial));
        assert_eq!(fraction, 0.02);
    }
}
