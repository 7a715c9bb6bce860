//! Worker threads: take jobs in arrival order and run the core pipeline,
//! one job per thread at a time, each inside `catch_unwind`.

use super::{CancelReason, Inner, Job, JobResult, Outcome, TestHook, lock};
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
                .spawn(move || work(&inner))
        })
        .collect()
}

fn work(inner: &Inner) {
    while let Some(job) = inner.next_job() {
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
            Outcome::Succeeded(Some(Arc::new(result)))
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
