//! Worker threads: take jobs in arrival order and run the core pipeline,
//! one job per thread at a time, each inside `catch_unwind`. With a shared
//! store, a worker claims the job for a lease it renews while running
//! ([`keep_lease`]) and files the outcome there ([`file_shared`]).

use super::redis::{RedisStore, TICK, Tick};
use super::{CancelReason, Claim, HeldResult, Inner, Job, JobResult, Outcome, TestHook, lock};
use crate::service::error::{Code, Problem};
use meshsmooth_core::job::{Input, JobError};
use meshsmooth_core::{Progress, SmoothError, Stage};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::Arc;
use std::sync::Mutex;
use std::sync::atomic::Ordering;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use tracing::{Span, error, info, info_span, warn};

/// Starts `inner.settings.workers` threads named `meshsmooth-worker-<i>`.
pub(super) fn spawn(inner: &Arc<Inner>) -> std::io::Result<Vec<JoinHandle<()>>> {
    (0..inner.settings.workers.max(1))
        .map(|i| {
            let inner = inner.clone();
            std::thread::Builder::new()
                .name(format!("meshsmooth-worker-{i}"))
                .spawn(move || work(&inner, i))
        })
        .collect()
}

fn work(inner: &Inner, index: usize) {
    while let Some(job) = inner.next_job(index) {
        inner.busy.fetch_add(1, Ordering::Relaxed);
        run_job(inner, &job);
        inner.busy.fetch_sub(1, Ordering::Relaxed);
    }
}

/// Why [`execute`] returned no result.
enum Stop {
    Cancelled,
    Failed(Problem),
}

fn run_job(inner: &Inner, job: &Arc<Job>) {
    let Some(document) = job.take_document() else {
        return;
    };
    if job.cancel.load(Ordering::Relaxed) {
        let reason = job.cancel_reason();
        inner.finish(job, Outcome::Cancelled(reason));
        return;
    }
    let started = job.set_running();
    metrics::histogram!("meshsmooth_job_queue_wait_seconds")
        .record(started.duration_since(job.created).as_secs_f64());
    let span = info_span!("job", job_id = %job.id, request_id = %job.request_id);
    let _entered = span.enter();
    info!(
        vertices = job.input.vertices,
        faces = job.input.faces,
        method = ?job.params.method,
        "job started"
    );

    let progress = JobProgress::new(job, span.clone());
    let result = catch_unwind(AssertUnwindSafe(|| execute(job, &document, &progress)));
    progress.end_stage();
    drop(document);
    let run_time = started.elapsed();
    let outcome = match result {
        Ok(Ok(result)) => {
            metrics::counter!("meshsmooth_vertices_processed_total")
                .increment(job.input.vertices as u64);
            metrics::counter!("meshsmooth_faces_processed_total").increment(job.input.faces as u64);
            metrics::histogram!("meshsmooth_job_duration_seconds").record(run_time.as_secs_f64());
            inner.record_run_time(run_time);
            info!(seconds = run_time.as_secs_f64(), "job succeeded");
            Outcome::Succeeded(Some(HeldResult::here(result)))
        }
        Ok(Err(Stop::Cancelled)) => match job.cancel_reason() {
            CancelReason::TimeLimit => {
                let limit = inner.settings.time_limit;
                warn!(
                    seconds = run_time.as_secs_f64(),
                    "job stopped at the time limit"
                );
                Outcome::Failed(Problem::new(
                    Code::JobTimeLimitExceeded,
                    format!(
                        "the job ran longer than the time limit of {} s and was stopped",
                        limit.as_secs_f64()
                    ),
                ))
            }
            reason => {
                info!(?reason, "job cancelled");
                Outcome::Cancelled(reason)
            }
        },
        Ok(Err(Stop::Failed(problem))) => {
            info!(code = problem.code.as_str(), detail = %problem.detail, "job failed");
            Outcome::Failed(problem)
        }
        Err(panic) => {
            let message = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            error!(panic = %message, "job panicked; the worker goes on");
            metrics::counter!("meshsmooth_job_panics_total").increment(1);
            Outcome::Failed(Problem::new(
                Code::JobPanicked,
                format!(
                    "the job failed on an internal error (request id {}); other jobs are not affected",
                    job.request_id
                ),
            ))
        }
    };
    inner.finish(job, outcome);
}

/// Renews the lease of `job`, claimed from `store`, until it is finished:
/// publishes its progress, raises its cancellation flag when a client asked
/// through any replica, and stops it when another worker took it over.
pub(super) fn keep_lease(inner: &Inner, store: &Arc<RedisStore>, job: &Arc<Job>) {
    let (store, job) = (store.clone(), job.clone());
    inner.runtime.spawn(async move {
        let Some(claim) = &job.claim else {
            return;
        };
        let mut tick = tokio::time::interval(TICK);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        while !job.is_finished() {
            tick.tick().await;
            match store.tick(&job, claim).await {
                Ok(Tick::Held { cancel }) => {
                    if cancel && !job.cancel.load(Ordering::Relaxed) {
                        job.request_cancel(CancelReason::Client);
                    }
                }
                Ok(Tick::Done) => return,
                Ok(Tick::Lost) => {
                    warn!(job_id = %job.id, "lease lost: another worker runs the job now; stopping");
                    claim.lost.store(true, Ordering::Relaxed);
                    job.request_cancel(CancelReason::Shutdown);
                    return;
                }
                Err(e) => {
                    warn!(job_id = %job.id, error = %e, "cannot renew the lease in Redis");
                }
            }
        }
    });
}

/// Files the outcome of a job claimed from `store`, retrying while Redis is
/// away (the lease is renewed meanwhile). A run cut short by the shutdown
/// goes back to the queue instead. Gives up once the shutdown deadline
/// passed: the lease then lapses and another replica runs the job again.
pub(super) fn file_shared(
    inner: &Inner,
    store: &RedisStore,
    job: &Job,
    claim: &Claim,
    outcome: &Outcome,
) {
    let hand_back = matches!(outcome, Outcome::Cancelled(CancelReason::Shutdown));
    let mut wait = Duration::from_millis(100);
    loop {
        if claim.lost.load(Ordering::Relaxed) {
            return;
        }
        let filed = if hand_back {
            inner
                .runtime
                .block_on(store.hand_back(job, claim))
                .map(|back| {
                    if back {
                        metrics::counter!("meshsmooth_jobs_handed_back_total").increment(1);
                        info!(job_id = %job.id, "job handed back to the queue");
                    }
                })
        } else {
            let settings = &inner.settings;
            inner
                .runtime
                .block_on(store.finish(
                    job,
                    claim,
                    outcome,
                    settings.result_memory,
                    settings.result_ttl,
                ))
                .map(|evicted| {
                    let Some(evicted) = evicted else {
                        warn!(job_id = %job.id, "lease lost before the outcome was filed; dropped");
                        return;
                    };
                    let label = match outcome {
                        Outcome::Succeeded(_) => "succeeded",
                        Outcome::Failed(_) => "failed",
                        Outcome::Cancelled(_) => "cancelled",
                    };
                    metrics::counter!("meshsmooth_jobs_finished_total", "outcome" => label)
                        .increment(1);
                    if evicted > 0 {
                        metrics::counter!("meshsmooth_results_evicted_total", "reason" => "memory")
                            .increment(evicted as u64);
                    }
                })
        };
        match filed {
            Ok(()) => return,
            Err(e) => {
                metrics::counter!("meshsmooth_store_errors_total").increment(1);
                if inner.abandoned.load(Ordering::Relaxed) {
                    warn!(job_id = %job.id, error = %e, "cannot file the job in Redis before the shutdown; its lease will lapse and another replica runs it");
                    return;
                }
                warn!(job_id = %job.id, error = %e, "cannot file the job in Redis; retrying");
                std::thread::sleep(wait);
                wait = (wait * 2).min(Duration::from_secs(2));
            }
        }
    }
}

/// Runs the job layer and encodes the report.
fn execute(job: &Job, document: &Input, progress: &JobProgress) -> Result<JobResult, Stop> {
    match job.hook {
        Some(TestHook::Panic) => panic!("test hook: panic injected into job {}", job.id),
        Some(TestHook::Sleep(d)) => sleep_cancellably(job, d)?,
        None => {}
    }
    let output = document
        .smooth(&job.params, job.output_format, progress, &job.cancel)
        .map_err(|e| match e {
            JobError::Smooth(SmoothError::Cancelled(_)) => Stop::Cancelled,
            e => Stop::Failed(e.into()),
        })?;
    let report = serde_json::to_vec(&output.report)
        .map_err(|_| Stop::Failed(Problem::internal("the quality report could not be encoded")))?;
    Ok(JobResult {
        mesh: output.bytes.into(),
        format: job.output_format,
        report: report.into(),
    })
}

fn sleep_cancellably(job: &Job, d: Duration) -> Result<(), Stop> {
    let end = Instant::now() + d;
    while Instant::now() < end {
        if job.cancel.load(Ordering::Relaxed) {
            return Err(Stop::Cancelled);
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    Ok(())
}

/// Feeds pipeline progress into the job state and times the stages
/// (`meshsmooth_stage_duration_seconds`).
struct JobProgress<'a> {
    job: &'a Job,
    /// The job's span: progress arrives on pipeline threads too.
    span: Span,
    stage: Mutex<Option<(Stage, Instant)>>,
}

impl<'a> JobProgress<'a> {
    fn new(job: &'a Job, span: Span) -> Self {
        JobProgress {
            job,
            span,
            stage: Mutex::new(None),
        }
    }

    /// Records the duration of the stage in progress, if any.
    fn end_stage(&self) {
        if let Some((stage, since)) = lock(&self.stage).take() {
            self.record_stage(stage, since.elapsed());
        }
    }

    fn record_stage(&self, stage: Stage, d: Duration) {
        metrics::histogram!("meshsmooth_stage_duration_seconds", "stage" => stage.name())
            .record(d.as_secs_f64());
        info!(parent: &self.span, stage = stage.name(), seconds = d.as_secs_f64(), "stage finished");
    }
}

impl Progress for JobProgress<'_> {
    fn update(&self, stage: Stage, fraction: f64) {
        {
            let mut current = lock(&self.stage);
            match *current {
                Some((s, _)) if s == stage => {}
                previous => {
                    if let Some((s, since)) = previous {
                        self.record_stage(s, since.elapsed());
                    }
                    *current = Some((stage, Instant::now()));
                }
            }
        }
        let fraction = if fraction.is_finite() {
            fraction.clamp(0.0, 1.0)
        } else {
            0.0
        };
        self.job.set_progress(stage, fraction);
    }
}
