//! The HTTP routes: thin handlers that extract, validate, enqueue and
//! answer. Geometry never runs here: uploads are parsed on the blocking
//! pool and smoothing runs on the job workers.

use crate::service::api::{
    ApiDoc, HealthView, JobView, UploadForm, add_mesh_media_types, job_path,
};
use crate::service::error::{Code, Problem, ProblemDetails};
use crate::service::jobs::{
    CancelReason, Deleted, HeldResult, Job, JobResult, JobState, JobWatch, Jobs, Outcome,
    Submission, TestHook,
};
use crate::service::upload::{UploadConfig, parse_output_format, read_upload};
use axum::body::{Body, Bytes};
use axum::extract::{DefaultBodyLimit, MatchedPath, Path, Query, Request, State};
use axum::http::{HeaderMap, HeaderName, HeaderValue, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::{Json, Router};
use futures_util::Stream;
use meshsmooth_core::io::Format;
use metrics_exporter_prometheus::PrometheusHandle;
use serde::Deserialize;
use serde_json::Value;
use std::convert::Infallible;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::{Semaphore, watch};
use utoipa::openapi::OpenApi as OpenApiDoc;
use utoipa::{IntoParams, OpenApi};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;
use uuid::Uuid;

/// Header carrying the job id on `/v1/smooth` answers.
pub const JOB_ID_HEADER: &str = "x-job-id";
/// Test-only fault injection header (see `--enable-test-hooks`).
pub const TEST_HOOK_HEADER: &str = "x-meshsmooth-test-hook";

/// Shared state of the handlers.
#[derive(Clone)]
pub struct AppState {
    /// The job system.
    pub jobs: Jobs,
    /// Upload limits and the parse pool.
    pub upload: Arc<UploadConfig>,
    /// Uploads being received or parsed at once (queue capacity plus
    /// workers): bounds the memory held by uploads not yet queued.
    pub upload_slots: Arc<Semaphore>,
    /// Time limit of the short routes.
    pub request_timeout: Duration,
    /// Honour [`TEST_HOOK_HEADER`].
    pub test_hooks: bool,
    /// Becomes true when shutdown starts (ends event streams).
    pub shutdown: watch::Receiver<bool>,
    /// Renders `/metrics`.
    pub metrics: PrometheusHandle,
    /// `GET /v1/params/schema`, computed once.
    pub params_schema: Arc<Value>,
}

impl AppState {
    async fn job(&self, id: &str) -> Result<Arc<Job>, Problem> {
        let Ok(uuid) = Uuid::parse_str(id) else {
            return Err(job_not_found(id));
        };
        self.jobs.get(&uuid).await?.ok_or_else(|| job_not_found(id))
    }

    fn test_hook(&self, headers: &HeaderMap) -> Result<Option<TestHook>, Problem> {
        if !self.test_hooks {
            return Ok(None);
        }
        let Some(value) = headers.get(TEST_HOOK_HEADER) else {
            return Ok(None);
        };
        let value = value.to_str().unwrap_or_default();
        if value == "panic" {
            return Ok(Some(TestHook::Panic));
        }
        value
            .strip_prefix("sleep=")
            .and_then(|ms| ms.parse().ok())
            .map(|ms| Some(TestHook::Sleep(Duration::from_millis(ms))))
            .ok_or_else(|| {
                Problem::new(
                    Code::InvalidParameter,
                    format!("unknown test hook `{value}` (use `panic` or `sleep=MS`)"),
                )
            })
    }

    /// Reads an upload and queues it as a job.
    async fn submit(&self, req: Request) -> Result<Arc<Job>, Problem> {
        // Refuse before reading a body that could not be queued anyway, and
        // bound the uploads held in memory at once.
        self.jobs.check_room().await?;
        let _slot = self.upload_slots.clone().try_acquire_owned().map_err(|_| {
            let slots = self.jobs.settings().queue_capacity + self.jobs.settings().workers;
            metrics::counter!("meshsmooth_jobs_rejected_total", "reason" => "uploads_full")
                .increment(1);
            Problem::new(
                Code::QueueFull,
                format!("too many uploads in progress ({slots}); retry shortly"),
            )
            .with_retry_after(1)
        })?;
        let hook = self.test_hook(req.headers())?;
        let request_id = request_id(req.headers());
        let upload = read_upload(req, &self.upload).await?;
        self.jobs
            .submit(Submission {
                document: upload.document,
                params: upload.params,
                output_format: upload.output_format,
                upload_bytes: upload.bytes,
                raw: upload.raw,
                request_id,
                hook,
            })
            .await
    }
}

fn job_not_found(id: &str) -> Problem {
    Problem::new(
        Code::JobNotFound,
        format!("no job `{id}`: it never existed, was deleted or has expired"),
    )
}

fn request_id(headers: &HeaderMap) -> String {
    headers
        .get("x-request-id")
        .and_then(|v| v.to_str().ok())
        .unwrap_or("-")
        .to_owned()
}

/// Builds the router and the OpenAPI document describing it.
pub fn router(state: AppState) -> (Router, OpenApiDoc) {
    let body_limit = usize::try_from(state.upload.max_body_bytes()).unwrap_or(usize::MAX);
    let uploads = OpenApiRouter::new()
        .routes(routes!(create_job))
        .routes(routes!(smooth))
        .layer(DefaultBodyLimit::max(body_limit));
    let streams = OpenApiRouter::new().routes(routes!(job_events));
    let short = OpenApiRouter::new()
        .routes(routes!(get_job, delete_job))
        .routes(routes!(job_mesh))
        .routes(routes!(job_report))
        .routes(routes!(params_schema))
        .routes(routes!(healthz))
        .routes(routes!(readyz))
        .routes(routes!(metrics))
        .route_layer(middleware::from_fn_with_state(
            state.request_timeout,
            time_limit,
        ));
    let (router, mut api) = OpenApiRouter::with_openapi(ApiDoc::openapi())
        .merge(uploads)
        .merge(streams)
        .merge(short)
        .split_for_parts();
    add_mesh_media_types(&mut api);
    let router = router
        .with_state(state)
        .merge(crate::service::web::router())
        .merge(utoipa_swagger_ui::SwaggerUi::new("/docs").url("/openapi.json", api.clone()))
        .fallback(not_found)
        .method_not_allowed_fallback(method_not_allowed)
        .layer(middleware::from_fn(track_requests));
    (router, api)
}

async fn time_limit(State(limit): State<Duration>, req: Request, next: Next) -> Response {
    match tokio::time::timeout(limit, next.run(req)).await {
        Ok(response) => response,
        Err(_) => Problem::new(
            Code::RequestTimeout,
            format!(
                "the request took longer than the limit of {} s",
                limit.as_secs_f64()
            ),
        )
        .into_response(),
    }
}

/// Counts requests by route and status, and times them.
async fn track_requests(req: Request, next: Next) -> Response {
    let route = req
        .extensions()
        .get::<MatchedPath>()
        .map_or_else(|| "unmatched".to_owned(), |p| p.as_str().to_owned());
    let method = req.method().as_str().to_owned();
    let start = Instant::now();
    let response = next.run(req).await;
    let status = response.status().as_u16().to_string();
    metrics::histogram!("meshsmooth_http_request_duration_seconds", "route" => route.clone())
        .record(start.elapsed().as_secs_f64());
    metrics::counter!(
        "meshsmooth_http_requests_total",
        "method" => method,
        "route" => route,
        "status" => status
    )
    .increment(1);
    response
}

async fn not_found(req: Request) -> Problem {
    Problem::new(
        Code::NotFound,
        format!("no route {} {}", req.method(), req.uri().path()),
    )
}

async fn method_not_allowed(req: Request) -> Problem {
    Problem::new(
        Code::MethodNotAllowed,
        format!("{} is not allowed on {}", req.method(), req.uri().path()),
    )
}

/// Submit a smoothing job.
///
/// The mesh comes as `multipart/form-data` (a `mesh` file part and an
/// optional `params` JSON part) or as the raw body with a mesh
/// Content-Type (`application/octet-stream` to detect the format from the
/// content); parameters of a raw upload go in the query string, either as
/// `params=<JSON object>` or one key per field with dotted paths for nested
/// fields (`method=taubin&baseline.iterations=50&quality.enabled=false`).
/// The upload is parsed and the parameters checked before the answer, so a
/// bad upload is refused here with its problem, never as a failed job.
#[utoipa::path(
    post,
    path = "/v1/jobs",
    tag = "jobs",
    params(
        ("format" = Option<String>, Query, description = "Format of the result (`obj`, ...); default: the input's"),
        ("params" = Option<String>, Query, description = "All parameters as one JSON object (raw uploads)"),
    ),
    request_body(content((UploadForm = "multipart/form-data")), description = "The mesh, as a form or as the raw body"),
    responses(
        (status = 202, description = "Accepted and queued", body = JobView,
            headers(("Location" = String, description = "The job: /v1/jobs/{id}"))),
        (status = 400, description = "Malformed request (empty body, multipart without a `mesh` part, malformed parameter JSON)", body = ProblemDetails, content_type = "application/problem+json"),
        (status = 408, description = "The upload took longer than the upload time limit", body = ProblemDetails, content_type = "application/problem+json"),
        (status = 413, description = "Upload, vertex or face count over a limit", body = ProblemDetails, content_type = "application/problem+json"),
        (status = 415, description = "Not a mesh Content-Type, or the format could not be determined", body = ProblemDetails, content_type = "application/problem+json"),
        (status = 422, description = "The mesh or the parameters cannot be used (parse error with its line, index out of range, non-finite coordinate, unknown or out-of-range parameter)", body = ProblemDetails, content_type = "application/problem+json"),
        (status = 503, description = "Queue full (with Retry-After) or shutting down; nothing was accepted", body = ProblemDetails, content_type = "application/problem+json",
            headers(("Retry-After" = u64, description = "Seconds to wait before retrying"))),
    )
)]
async fn create_job(State(state): State<AppState>, req: Request) -> Result<Response, Problem> {
    let job = state.submit(req).await?;
    let view = JobView::of(&job, &state.jobs);
    let location =
        HeaderValue::from_str(&job_path(&job.id)).map_err(|_| Problem::internal("bad job path"))?;
    Ok((
        StatusCode::ACCEPTED,
        [(header::LOCATION, location)],
        Json(view),
    )
        .into_response())
}

/// Smooth a mesh in one call.
///
/// Takes the same input as `POST /v1/jobs`, waits for the job and answers
/// with the smoothed mesh (in the input's format, or `?format=`). The job
/// stays available as usual: its id is in `x-job-id` and `Link` points at
/// its report (`rel="describedby"`) and at the job (`rel="related"`).
/// With `Accept: multipart/mixed` the answer carries two parts instead:
/// first the mesh (`name="mesh"`), then the JSON report (`name="report"`).
/// If the client disconnects before the answer, the job is cancelled.
#[utoipa::path(
    post,
    path = "/v1/smooth",
    tag = "smooth",
    params(
        ("format" = Option<String>, Query, description = "Format of the result (`obj`, ...); default: the input's"),
        ("params" = Option<String>, Query, description = "All parameters as one JSON object (raw uploads)"),
        ("Accept" = Option<String>, Header, description = "`multipart/mixed` to receive the mesh and the report in one answer"),
    ),
    request_body(content((UploadForm = "multipart/form-data")), description = "The mesh, as a form or as the raw body"),
    responses(
        (status = 200, description = "The smoothed mesh, or with `Accept: multipart/mixed` the mesh and the report",
            content(("multipart/mixed")),
            headers(
                ("x-job-id" = String, description = "The job id"),
                ("Link" = String, description = "`</v1/jobs/{id}/report>; rel=\"describedby\"` and `</v1/jobs/{id}>; rel=\"related\"`"),
                ("Content-Location" = String, description = "/v1/jobs/{id}/mesh"),
            )),
        (status = 400, description = "Malformed request", body = ProblemDetails, content_type = "application/problem+json"),
        (status = 409, description = "The job was cancelled (DELETE from another client)", body = ProblemDetails, content_type = "application/problem+json"),
        (status = 413, description = "Upload, vertex or face count over a limit", body = ProblemDetails, content_type = "application/problem+json"),
        (status = 415, description = "Not a mesh Content-Type", body = ProblemDetails, content_type = "application/problem+json"),
        (status = 422, description = "The mesh or the parameters cannot be used, or the result could not be written", body = ProblemDetails, content_type = "application/problem+json"),
        (status = 500, description = "The job failed on an internal error (`job_panicked`)", body = ProblemDetails, content_type = "application/problem+json"),
        (status = 503, description = "Queue full (with Retry-After), shutting down, or the job time limit was exceeded", body = ProblemDetails, content_type = "application/problem+json"),
    )
)]
async fn smooth(State(state): State<AppState>, req: Request) -> Result<Response, Problem> {
    let mixed = req
        .headers()
        .get(header::ACCEPT)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|a| a.contains("multipart/mixed"));
    let job = state.submit(req).await?;
    let guard = CancelOnDrop(Some((job.clone(), state.jobs.clone())));
    let finished = state.jobs.finished(&job).await?;
    drop(guard.disarm());
    let final_state = match &finished {
        Some(job) => job.state(),
        None => return Err(job_not_found(&job.id.to_string())),
    };
    let mut headers = HeaderMap::new();
    let path = job_path(&job.id);
    let links = format!(
        "<{path}/report>; rel=\"describedby\"; type=\"application/json\", <{path}>; rel=\"related\""
    );
    for (name, value) in [
        (HeaderName::from_static(JOB_ID_HEADER), job.id.to_string()),
        (header::LINK, links),
        (header::CONTENT_LOCATION, format!("{path}/mesh")),
    ] {
        if let Ok(value) = HeaderValue::from_str(&value) {
            headers.insert(name, value);
        }
    }
    let result = match result_of(&job, final_state) {
        Ok(held) => load_result(&state.jobs, &job, held).await,
        Err(problem) => Err(problem),
    };
    let result = match result {
        Ok(result) => result,
        Err(problem) => {
            headers.remove(header::CONTENT_LOCATION);
            return Ok((headers, problem).into_response());
        }
    };
    if mixed {
        let boundary = format!("meshsmooth-{}", Uuid::new_v4().simple());
        let content_type = format!("multipart/mixed; boundary={boundary}");
        if let Ok(v) = HeaderValue::from_str(&content_type) {
            headers.insert(header::CONTENT_TYPE, v);
        }
        return Ok((headers, multipart_mixed(&job.id, &result, &boundary)).into_response());
    }
    let mut response = mesh_response(&job.id, result.format, result.mesh.clone());
    response.headers_mut().extend(headers);
    Ok(response)
}

/// Cancels the job if the one-call request is dropped (client gone)
/// before it finished.
struct CancelOnDrop(Option<(Arc<Job>, Jobs)>);

impl CancelOnDrop {
    fn disarm(mut self) -> Option<(Arc<Job>, Jobs)> {
        self.0.take()
    }
}

impl Drop for CancelOnDrop {
    fn drop(&mut self) {
        if let Some((job, jobs)) = self.0.take()
            && !job.is_finished()
        {
            tracing::info!(job_id = %job.id, "client of /v1/smooth went away; cancelling its job");
            jobs.cancel(&job);
        }
    }
}

/// The two parts of a `multipart/mixed` answer, without copying the mesh.
fn multipart_mixed(id: &Uuid, result: &JobResult, boundary: &str) -> Body {
    let ext = result.format.extension();
    let head = format!(
        "--{boundary}\r\nContent-Type: {}\r\nContent-Disposition: attachment; name=\"mesh\"; \
         filename=\"{id}.{ext}\"\r\n\r\n",
        result.format.content_type()
    );
    let middle = format!(
        "\r\n--{boundary}\r\nContent-Type: application/json\r\nContent-Disposition: attachment; \
         name=\"report\"; filename=\"{id}.report.json\"\r\n\r\n"
    );
    let tail = format!("\r\n--{boundary}--\r\n");
    let parts: Vec<Bytes> = vec![
        head.into(),
        result.mesh.clone(),
        middle.into(),
        result.report.clone(),
        tail.into(),
    ];
    Body::from_stream(futures_util::stream::iter(
        parts.into_iter().map(Ok::<_, Infallible>),
    ))
}

fn mesh_response(id: &Uuid, format: Format, bytes: Bytes) -> Response {
    let disposition = format!("attachment; filename=\"{id}.{}\"", format.extension());
    let mut response = bytes.into_response();
    let headers = response.headers_mut();
    headers.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static(format.content_type()),
    );
    if let Ok(v) = HeaderValue::from_str(&disposition) {
        headers.insert(header::CONTENT_DISPOSITION, v);
    }
    response
}

/// The result of a finished job, or the problem that stands in for it.
fn result_of(job: &Job, state: JobState) -> Result<HeldResult, Problem> {
    match state {
        JobState::Queued => Err(Problem::new(
            Code::JobNotFinished,
            format!("job {} is queued; wait for it to succeed", job.id),
        )),
        JobState::Running {
            stage, fraction, ..
        } => Err(Problem::new(
            Code::JobNotFinished,
            format!(
                "job {} is running (stage {}, {:.0}% done); wait for it to succeed",
                job.id,
                stage.map_or("starting", |s| s.name()),
                fraction * 100.0
            ),
        )),
        JobState::Finished { outcome, .. } => match outcome {
            Outcome::Succeeded(Some(result)) => Ok(result),
            Outcome::Succeeded(None) => Err(evicted(job)),
            Outcome::Failed(problem) => Err(problem),
            Outcome::Cancelled(CancelReason::Shutdown) => Err(Problem::new(
                Code::ShuttingDown,
                format!(
                    "job {} was cancelled because the service is shutting down",
                    job.id
                ),
            )),
            Outcome::Cancelled(_) => Err(Problem::new(
                Code::JobCancelled,
                format!("job {} was cancelled", job.id),
            )),
        },
    }
}

/// The bytes of a held result; `result_evicted` once they are gone.
async fn load_result(jobs: &Jobs, job: &Job, held: HeldResult) -> Result<Arc<JobResult>, Problem> {
    jobs.result(job, held).await?.ok_or_else(|| evicted(job))
}

fn evicted(job: &Job) -> Problem {
    Problem::new(
        Code::ResultEvicted,
        format!(
            "the result of job {} was evicted to stay under the result memory budget; \
             submit the mesh again",
            job.id
        ),
    )
}

/// Like [`result_of`], but a failed job is a conflict for the result
/// routes (the job's own problem is in its `error`).
async fn stored_result(jobs: &Jobs, job: &Job) -> Result<Arc<JobResult>, Problem> {
    let held = result_of(job, job.state()).map_err(|p| match p.code {
        Code::JobNotFinished | Code::ResultEvicted | Code::JobCancelled => p,
        Code::ShuttingDown => Problem::new(
            Code::JobCancelled,
            format!("job {} was cancelled by the shutdown", job.id),
        ),
        code => Problem::new(
            Code::JobFailed,
            format!("job {} failed ({code}): {}", job.id, p.detail),
        ),
    })?;
    load_result(jobs, job, held).await
}

/// Get a job's state, progress, timings and links.
#[utoipa::path(
    get,
    path = "/v1/jobs/{id}",
    tag = "jobs",
    params(("id" = String, Path, description = "Job id")),
    responses(
        (status = 200, description = "The job", body = JobView),
        (status = 404, description = "Unknown, deleted or expired job", body = ProblemDetails, content_type = "application/problem+json"),
    )
)]
async fn get_job(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<JobView>, Problem> {
    let job = state.job(&id).await?;
    Ok(Json(JobView::of(&job, &state.jobs)))
}

/// Cancel a queued or running job, or forget a finished one.
///
/// A queued job is cancelled at once (200). A running job has its
/// cancellation flag raised (202); the pipeline checks it between and
/// inside stages, and the job soon becomes `cancelled`. A finished job and
/// its result are forgotten (204).
#[utoipa::path(
    delete,
    path = "/v1/jobs/{id}",
    tag = "jobs",
    params(("id" = String, Path, description = "Job id")),
    responses(
        (status = 200, description = "The job was queued and is now cancelled", body = JobView),
        (status = 202, description = "The job is running and is being cancelled", body = JobView),
        (status = 204, description = "The finished job was forgotten"),
        (status = 404, description = "Unknown, deleted or expired job", body = ProblemDetails, content_type = "application/problem+json"),
    )
)]
async fn delete_job(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Response, Problem> {
    let job = state.job(&id).await?;
    Ok(match state.jobs.delete(&job.id).await? {
        Some(Deleted::Cancelled(job)) => {
            (StatusCode::OK, Json(JobView::of(&job, &state.jobs))).into_response()
        }
        Some(Deleted::Cancelling(job)) => {
            (StatusCode::ACCEPTED, Json(JobView::of(&job, &state.jobs))).into_response()
        }
        Some(Deleted::Forgotten) => StatusCode::NO_CONTENT.into_response(),
        // Deleted or expired meanwhile.
        None => return Err(job_not_found(&id)),
    })
}

/// Query of `GET /v1/jobs/{id}/mesh`.
#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
struct MeshQuery {
    /// Format to download the mesh in (`obj`, ...); default: the job's
    /// output format.
    format: Option<String>,
}

/// Download the smoothed mesh.
#[utoipa::path(
    get,
    path = "/v1/jobs/{id}/mesh",
    tag = "jobs",
    params(("id" = String, Path, description = "Job id"), MeshQuery),
    responses(
        (status = 200, description = "The smoothed mesh file",
            headers(("Content-Disposition" = String, description = "attachment; filename=\"{id}.{ext}\""))),
        (status = 400, description = "Unknown `format`", body = ProblemDetails, content_type = "application/problem+json"),
        (status = 404, description = "Unknown, deleted or expired job", body = ProblemDetails, content_type = "application/problem+json"),
        (status = 409, description = "The job is not finished (`job_not_finished`), failed (`job_failed`) or was cancelled (`job_cancelled`)", body = ProblemDetails, content_type = "application/problem+json"),
        (status = 410, description = "The result was evicted to stay under the memory budget", body = ProblemDetails, content_type = "application/problem+json"),
        (status = 422, description = "The result could not be converted to the requested format", body = ProblemDetails, content_type = "application/problem+json"),
    )
)]
async fn job_mesh(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Query(query): Query<MeshQuery>,
) -> Result<Response, Problem> {
    let job = state.job(&id).await?;
    let format = query
        .format
        .as_deref()
        .map(parse_output_format)
        .transpose()?;
    let result = stored_result(&state.jobs, &job).await?;
    let format = format.unwrap_or(result.format);
    let bytes = if format == result.format {
        result.mesh.clone()
    } else {
        convert(&state.upload, result, format).await?
    };
    Ok(mesh_response(&job.id, format, bytes))
}

/// Re-encodes a stored result in another format, on the blocking pool.
async fn convert(
    config: &UploadConfig,
    result: Arc<JobResult>,
    to: Format,
) -> Result<Bytes, Problem> {
    let permit = config
        .parse_slots
        .clone()
        .acquire_owned()
        .await
        .map_err(|_| Problem::new(Code::ShuttingDown, "the service is shutting down"))?;
    let converted = tokio::task::spawn_blocking(move || {
        let _permit = permit;
        meshsmooth_core::job::convert(&result.mesh, result.format, to)
    })
    .await
    .map_err(|_| Problem::internal("the conversion failed on an internal error"))?;
    converted.map(Bytes::from).map_err(|e| {
        Problem::new(
            Code::ConversionFailed,
            format!("the result could not be written as {to}: {e}"),
        )
    })
}

/// Download the quality report (JSON).
#[utoipa::path(
    get,
    path = "/v1/jobs/{id}/report",
    tag = "jobs",
    params(("id" = String, Path, description = "Job id")),
    responses(
        (status = 200, description = "The quality report", body = Object, content_type = "application/json"),
        (status = 404, description = "Unknown, deleted or expired job", body = ProblemDetails, content_type = "application/problem+json"),
        (status = 409, description = "The job is not finished, failed or was cancelled", body = ProblemDetails, content_type = "application/problem+json"),
        (status = 410, description = "The result was evicted to stay under the memory budget", body = ProblemDetails, content_type = "application/problem+json"),
    )
)]
async fn job_report(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Response, Problem> {
    let job = state.job(&id).await?;
    let result = stored_result(&state.jobs, &job).await?;
    Ok((
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/json"),
        )],
        result.report.clone(),
    )
        .into_response())
}

/// Follow a job's state and progress as server-sent events.
///
/// Each event is named `state` and carries the job (the same JSON as
/// `GET /v1/jobs/{id}`): one at once, then one per change of state, stage
/// or whole percent of progress. The stream ends after the job finishes.
#[utoipa::path(
    get,
    path = "/v1/jobs/{id}/events",
    tag = "jobs",
    params(("id" = String, Path, description = "Job id")),
    responses(
        (status = 200, description = "`text/event-stream` of `state` events whose data is a job", content_type = "text/event-stream", body = JobView),
        (status = 404, description = "Unknown, deleted or expired job", body = ProblemDetails, content_type = "application/problem+json"),
    )
)]
async fn job_events(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Sse<impl Stream<Item = Result<Event, Infallible>>>, Problem> {
    let job = state.job(&id).await?;
    let start = EventsState {
        watch: state.jobs.watch(&job),
        jobs: state.jobs.clone(),
        shutdown: state.shutdown.clone(),
        sent: 0,
    };
    let stream = futures_util::stream::unfold(Some(start), |s| async move {
        let mut s = s?;
        if s.sent > 0 {
            tokio::select! {
                changed = s.watch.changed() => if !changed { return None },
                _ = s.shutdown.wait_for(|stopping| *stopping) => return None,
            }
        }
        // A store that cannot be read now ends the stream (the client
        // reconnects, as for any event stream).
        let job = s.watch.current().await.ok()??;
        let view = JobView::of(&job, &s.jobs);
        let done = view.state.is_final();
        let event = Event::default()
            .event("state")
            .id(s.sent.to_string())
            .json_data(&view)
            .unwrap_or_else(|_| Event::default().event("error"));
        s.sent += 1;
        Some((Ok(event), (!done).then_some(s)))
    });
    Ok(Sse::new(stream).keep_alive(KeepAlive::default()))
}

struct EventsState {
    watch: JobWatch,
    jobs: Jobs,
    shutdown: watch::Receiver<bool>,
    sent: u64,
}

/// The JSON Schema (2020-12) of the parameters, with defaults.
#[utoipa::path(
    get,
    path = "/v1/params/schema",
    tag = "params",
    responses(
        (status = 200, description = "JSON Schema of the `params` object, every field with its default and allowed range", body = Object, content_type = "application/schema+json"),
    )
)]
async fn params_schema(State(state): State<AppState>) -> Response {
    (
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/schema+json"),
        )],
        Json(state.params_schema.as_ref().clone()),
    )
        .into_response()
}

/// Liveness: the process serves HTTP.
#[utoipa::path(
    get,
    path = "/healthz",
    tag = "operations",
    responses((status = 200, description = "Alive", body = HealthView))
)]
async fn healthz() -> Json<HealthView> {
    Json(HealthView {
        status: "ok".into(),
    })
}

/// Readiness: accepting jobs (not shutting down, queue not full).
#[utoipa::path(
    get,
    path = "/readyz",
    tag = "operations",
    responses(
        (status = 200, description = "Accepting jobs", body = HealthView),
        (status = 503, description = "Shutting down (`shutting_down`), queue full (`queue_full`) or the shared job store unreachable (`store_unavailable`)", body = ProblemDetails, content_type = "application/problem+json"),
    )
)]
async fn readyz(State(state): State<AppState>) -> Response {
    if *state.shutdown.borrow() {
        return Problem::new(Code::ShuttingDown, "the service is shutting down").into_response();
    }
    if let Err(problem) = state.jobs.ready().await {
        return problem.into_response();
    }
    Json(HealthView {
        status: "ready".into(),
    })
    .into_response()
}

/// Prometheus metrics (text exposition format).
#[utoipa::path(
    get,
    path = "/metrics",
    tag = "operations",
    responses((status = 200, description = "Metrics in the Prometheus text format", body = String, content_type = "text/plain; version=0.0.4"))
)]
async fn metrics(State(state): State<AppState>) -> Response {
    crate::service::metrics::record_gauges(&state.jobs).await;
    (
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("text/plain; version=0.0.4; charset=utf-8"),
        )],
        state.metrics.render(),
    )
        .into_response()
}
