//! Prometheus metrics: the recorder, metric descriptions, and the gauges
//! sampled from the job system at every scrape.

use crate::service::jobs::Jobs;
use metrics::{Unit, describe_counter, describe_gauge, describe_histogram, gauge};
use metrics_exporter_prometheus::{Matcher, PrometheusBuilder, PrometheusHandle};

/// Histogram buckets (seconds) for request, stage and job durations.
const SECONDS_BUCKETS: &[f64] = &[
    0.001, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0, 120.0, 300.0,
    600.0,
];

/// Installs the process-wide recorder and describes every metric.
pub fn install() -> anyhow::Result<PrometheusHandle> {
    let handle = PrometheusBuilder::new()
        .set_buckets_for_metric(Matcher::Suffix("_seconds".into()), SECONDS_BUCKETS)?
        .install_recorder()?;
    describe();
    Ok(handle)
}

fn describe() {
    describe_counter!(
        "meshsmooth_jobs_submitted_total",
        "Jobs accepted into the queue"
    );
    describe_counter!(
        "meshsmooth_jobs_rejected_total",
        "Uploads refused before becoming a job, by reason (queue_full, shutting_down)"
    );
    describe_counter!(
        "meshsmooth_jobs_finished_total",
        "Jobs finished, by outcome (succeeded, failed, cancelled)"
    );
    describe_counter!(
        "meshsmooth_jobs_expired_total",
        "Finished jobs forgotten after the result TTL"
    );
    describe_counter!(
        "meshsmooth_job_panics_total",
        "Jobs that panicked (each failed alone)"
    );
    describe_gauge!(
        "meshsmooth_jobs",
        "Known jobs by state (queued, running, succeeded, failed, cancelled)"
    );
    describe_gauge!(
        "meshsmooth_queue_depth",
        "Jobs waiting for a worker (fleet-wide with the Redis store)"
    );
    describe_counter!(
        "meshsmooth_job_attempts_total",
        "Runs of jobs claimed from the Redis store by this replica (first runs and reruns)"
    );
    describe_counter!(
        "meshsmooth_leases_reclaimed_total",
        "Jobs this replica took over because the lease of the replica running them lapsed"
    );
    describe_counter!(
        "meshsmooth_jobs_handed_back_total",
        "Running jobs put back into the Redis queue by a shutdown"
    );
    describe_counter!(
        "meshsmooth_store_errors_total",
        "Failed calls to the Redis store (unreachable, timed out)"
    );
    describe_gauge!(
        "meshsmooth_queue_capacity",
        "Most jobs that may wait for a worker"
    );
    describe_gauge!("meshsmooth_workers", "Worker threads");
    describe_gauge!("meshsmooth_workers_busy", "Worker threads running a job");
    describe_gauge!("meshsmooth_results", "Finished results held in memory");
    describe_gauge!(
        "meshsmooth_results_bytes",
        Unit::Bytes,
        "Bytes of finished results held in memory"
    );
    describe_gauge!(
        "meshsmooth_results_memory_budget_bytes",
        Unit::Bytes,
        "Result memory budget; the oldest results are evicted beyond it"
    );
    describe_gauge!(
        "meshsmooth_results_ttl_seconds",
        Unit::Seconds,
        "How long finished jobs are kept"
    );
    describe_counter!(
        "meshsmooth_results_evicted_total",
        "Results dropped, by reason (memory: over budget, ttl: expired)"
    );
    describe_counter!(
        "meshsmooth_upload_bytes_total",
        Unit::Bytes,
        "Bytes of mesh files uploaded"
    );
    describe_counter!(
        "meshsmooth_vertices_processed_total",
        "Vertices of successfully smoothed meshes"
    );
    describe_counter!(
        "meshsmooth_faces_processed_total",
        "Faces of successfully smoothed meshes"
    );
    describe_histogram!(
        "meshsmooth_stage_duration_seconds",
        Unit::Seconds,
        "Duration of each pipeline stage, by stage"
    );
    describe_histogram!(
        "meshsmooth_job_duration_seconds",
        Unit::Seconds,
        "Run time of succeeded jobs"
    );
    describe_histogram!(
        "meshsmooth_job_queue_wait_seconds",
        Unit::Seconds,
        "Time jobs waited for a worker"
    );
    describe_counter!(
        "meshsmooth_http_requests_total",
        "HTTP requests by method, route and status"
    );
    describe_histogram!(
        "meshsmooth_http_request_duration_seconds",
        Unit::Seconds,
        "Time to the response head, by route"
    );
}

/// Samples the job system into gauges (called before each render).
pub async fn record_gauges(jobs: &Jobs) {
    let stats = jobs.stats().await;
    let settings = jobs.settings();
    for (state, n) in [
        ("queued", stats.queued),
        ("running", stats.running),
        ("succeeded", stats.succeeded),
        ("failed", stats.failed),
        ("cancelled", stats.cancelled),
    ] {
        gauge!("meshsmooth_jobs", "state" => state).set(n as f64);
    }
    gauge!("meshsmooth_queue_depth").set(stats.queued as f64);
    gauge!("meshsmooth_queue_capacity").set(settings.queue_capacity as f64);
    gauge!("meshsmooth_workers").set(settings.workers as f64);
    gauge!("meshsmooth_workers_busy").set(stats.busy_workers as f64);
    gauge!("meshsmooth_results").set(stats.results as f64);
    gauge!("meshsmooth_results_bytes").set(stats.result_bytes as f64);
    gauge!("meshsmooth_results_memory_budget_bytes").set(settings.result_memory as f64);
    gauge!("meshsmooth_results_ttl_seconds").set(settings.result_ttl.as_secs_f64());
}
