//! The API's data: the JSON shapes answered by the routes, the OpenAPI
//! document they are described in, and the JSON Schema of the parameters.

use crate::service::error::ProblemDetails;
use crate::service::jobs::{CancelReason, Job, JobState, Jobs, Outcome};
use meshsmooth_core::Params;
use meshsmooth_core::io::Format;
use serde::Serialize;
use serde_json::{Map, Value, json};
use std::time::{Duration, SystemTime, UNIX_EPOCH};
use utoipa::openapi::{Content, OpenApi as OpenApiDoc, RefOr, Required};
use utoipa::{OpenApi, PartialSchema, ToSchema};
use uuid::Uuid;

/// Where a job is in its life.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum JobStatus {
    /// Waiting for a worker.
    Queued,
    /// Being smoothed (see `stage` and `progress`).
    Running,
    /// Done; the mesh and report can be fetched.
    Succeeded,
    /// Failed; see `error`.
    Failed,
    /// Cancelled by a client or by the shutdown; see `cancel_reason`.
    Cancelled,
}

impl JobStatus {
    /// True for succeeded, failed and cancelled.
    pub fn is_final(self) -> bool {
        matches!(
            self,
            JobStatus::Succeeded | JobStatus::Failed | JobStatus::Cancelled
        )
    }
}

/// Why a job was cancelled.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum CancelReasonName {
    /// `DELETE /v1/jobs/{id}`, or the client of `/v1/smooth` went away.
    Client,
    /// The server shut down before the job could run.
    Shutdown,
}

/// The uploaded mesh.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct InputView {
    /// Format it was read as (`obj`, ...).
    pub format: String,
    /// Vertex count of the mesh as smoothed (after welding, when the file
    /// was welded; the report's `mesh.file_vertices` has the file's count).
    pub vertices: usize,
    /// Face count.
    pub faces: usize,
    /// Size of the mesh file in bytes.
    pub bytes: u64,
}

/// The result of a succeeded job.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct ResultView {
    /// False once the result was evicted to stay under the memory budget
    /// (the mesh and report routes then answer 410).
    pub available: bool,
    /// Size of the smoothed mesh file in bytes (while available).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mesh_bytes: Option<u64>,
    /// Size of the JSON report in bytes (while available).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub report_bytes: Option<u64>,
}

/// Links of a job.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct JobLinks {
    /// This job.
    #[serde(rename = "self")]
    pub self_: String,
    /// The smoothed mesh (once succeeded).
    pub mesh: String,
    /// The quality report (once succeeded).
    pub report: String,
    /// Server-sent events of state and progress.
    pub events: String,
}

/// A smoothing job.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct JobView {
    /// Random (v4) job id.
    pub id: Uuid,
    /// Where the job is in its life.
    pub state: JobStatus,
    /// The pipeline stage being run (`analyse`, `initial`, `label`,
    /// `adaptive`, `quality`, `report`), while running.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stage: Option<String>,
    /// Fraction of the current stage done, in [0, 1], while running.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub progress: Option<f64>,
    /// Jobs ahead of this one (0: next), while queued.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub queue_position: Option<usize>,
    /// A cancellation was requested and the job is stopping.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub cancel_requested: bool,
    /// When the job was accepted (RFC 3339, UTC).
    pub created_at: String,
    /// When it started running.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub started_at: Option<String>,
    /// When it finished.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub finished_at: Option<String>,
    /// When the finished job will be forgotten (the result time to live).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub expires_at: Option<String>,
    /// Seconds spent waiting for a worker (so far, while queued).
    pub queue_seconds: f64,
    /// Seconds spent running (so far, while running).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub run_seconds: Option<f64>,
    /// Times the job was started: 0 while queued, 1 once running; more
    /// when a replica died while running it and another ran it again.
    pub attempts: u32,
    /// The uploaded mesh.
    pub input: InputView,
    /// Format the result is written in.
    pub output_format: String,
    /// The parameters of the run, defaults filled in.
    pub params: Params,
    /// Why the job failed (the same problem `/v1/smooth` would answer).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<ProblemDetails>,
    /// Why the job was cancelled.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cancel_reason: Option<CancelReasonName>,
    /// The result, once succeeded.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub result: Option<ResultView>,
    /// Related resources.
    pub links: JobLinks,
}

/// Path of a job.
pub fn job_path(id: &Uuid) -> String {
    format!("/v1/jobs/{id}")
}

impl JobView {
    /// The view of `job` now.
    pub fn of(job: &Job, jobs: &Jobs) -> JobView {
        let path = job_path(&job.id);
        let mut view = JobView {
            id: job.id,
            state: JobStatus::Queued,
            stage: None,
            progress: None,
            queue_position: None,
            cancel_requested: job.cancel_requested(),
            created_at: rfc3339(job.created_at),
            started_at: None,
            finished_at: None,
            expires_at: None,
            queue_seconds: job.created.elapsed().as_secs_f64(),
            run_seconds: None,
            attempts: job.attempts(),
            input: InputView {
                format: job.input.format.name().to_owned(),
                vertices: job.input.vertices,
                faces: job.input.faces,
                bytes: job.input.bytes,
            },
            output_format: job.output_format.name().to_owned(),
            params: job.params.clone(),
            error: None,
            cancel_reason: None,
            result: None,
            links: JobLinks {
                mesh: format!("{path}/mesh"),
                report: format!("{path}/report"),
                events: format!("{path}/events"),
                self_: path,
            },
        };
        match job.state() {
            JobState::Queued => {
                view.queue_position = job
                    .stored_queue_position()
                    .or_else(|| jobs.queue_position(&job.id));
            }
            JobState::Running {
                started,
                started_at,
                stage,
                fraction,
            } => {
                view.state = JobStatus::Running;
                view.stage = stage.map(|s| s.name().to_owned());
                view.progress = Some(fraction);
                view.started_at = Some(rfc3339(started_at));
                view.queue_seconds = started.duration_since(job.created).as_secs_f64();
                view.run_seconds = Some(started.elapsed().as_secs_f64());
            }
            JobState::Finished {
                started,
                finished,
                finished_at,
                outcome,
            } => {
                let queue_end = started.map_or(finished, |(s, _)| s);
                view.queue_seconds = queue_end.duration_since(job.created).as_secs_f64();
                if let Some((started, started_at)) = started {
                    view.started_at = Some(rfc3339(started_at));
                    view.run_seconds = Some(finished.duration_since(started).as_secs_f64());
                }
                view.finished_at = Some(rfc3339(finished_at));
                view.expires_at = Some(rfc3339(finished_at + jobs.settings().result_ttl));
                match outcome {
                    Outcome::Succeeded(result) => {
                        view.state = JobStatus::Succeeded;
                        view.result = Some(ResultView {
                            available: result.is_some(),
                            mesh_bytes: result.as_ref().map(|r| r.mesh_bytes),
                            report_bytes: result.as_ref().map(|r| r.report_bytes),
                        });
                    }
                    Outcome::Failed(problem) => {
                        view.state = JobStatus::Failed;
                        view.error = Some(problem.details());
                    }
                    Outcome::Cancelled(reason) => {
                        view.state = JobStatus::Cancelled;
                        view.cancel_reason = Some(match reason {
                            CancelReason::Shutdown => CancelReasonName::Shutdown,
                            CancelReason::Client | CancelReason::TimeLimit => {
                                CancelReasonName::Client
                            }
                        });
                    }
                }
            }
        }
        view
    }
}

/// `GET /healthz` and `GET /readyz` answer.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct HealthView {
    /// `ok` (alive) or `ready` (accepting jobs).
    pub status: String,
}

/// The multipart form of an upload.
#[derive(Debug, ToSchema)]
#[allow(dead_code)] // Describes the request body for the OpenAPI document only.
pub struct UploadForm {
    /// The mesh file. Its format comes from the file name's extension, the
    /// part's Content-Type, or the content, in that order.
    #[schema(format = Binary, value_type = String, content_media_type = "application/octet-stream")]
    pub mesh: Vec<u8>,
    /// Smoothing parameters as a JSON object (optional; defaults for every
    /// field left out). Content-Type `application/json`.
    pub params: Option<Params>,
}

/// RFC 3339 UTC timestamp with milliseconds, e.g. `2026-11-23T14:11:05.123Z`.
pub fn rfc3339(t: SystemTime) -> String {
    let since = t.duration_since(UNIX_EPOCH).unwrap_or(Duration::ZERO);
    let secs = since.as_secs();
    let (days, rem) = ((secs / 86_400) as i64, secs % 86_400);
    // Days since 1970-01-01 to a civil date (H. Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}.{:03}Z",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60,
        since.subsec_millis()
    )
}

/// The JSON Schema (2020-12) of [`Params`], with every default, for front
/// ends to build their forms from.
pub fn params_schema() -> Value {
    let mut nested = Vec::new();
    <Params as ToSchema>::schemas(&mut nested);
    let defs: Map<String, Value> = nested
        .into_iter()
        .map(|(name, schema)| (name, serde_json::to_value(schema).unwrap_or(Value::Null)))
        .collect();
    let mut schema =
        serde_json::to_value(<Params as PartialSchema>::schema()).unwrap_or(Value::Null);
    if let Value::Object(root) = &mut schema {
        root.insert(
            "$schema".into(),
            json!("https://json-schema.org/draft/2020-12/schema"),
        );
        root.insert("title".into(), json!("Params"));
        root.insert("$defs".into(), Value::Object(defs));
    }
    rewrite_refs(&mut schema);
    schema
}

/// Points OpenAPI component references at `$defs`.
fn rewrite_refs(v: &mut Value) {
    match v {
        Value::Object(map) => {
            for (key, value) in map.iter_mut() {
                match value {
                    Value::String(s) if key == "$ref" => {
                        if let Some(name) = s.strip_prefix("#/components/schemas/") {
                            *s = format!("#/$defs/{name}");
                        }
                    }
                    _ => rewrite_refs(value),
                }
            }
        }
        Value::Array(items) => items.iter_mut().for_each(rewrite_refs),
        _ => {}
    }
}

/// The OpenAPI document (routes are added by `utoipa-axum`).
#[derive(OpenApi)]
#[openapi(
    info(
        title = "meshsmooth",
        description = "Quadric-fitting, curvature-adaptive surface mesh smoothing (Wang & Yu \
            2009) with a quality report.\n\nTwo ways in: the job API (`POST /v1/jobs`, then poll \
            `GET /v1/jobs/{id}` or follow `/events`, then fetch `/mesh` and `/report`) and the \
            one-call `POST /v1/smooth`. Errors are `application/problem+json` (RFC 9457) with a \
            stable `code`.",
        license(name = "MIT OR Apache-2.0", identifier = "MIT OR Apache-2.0")
    ),
    components(schemas(ProblemDetails, UploadForm, Params)),
    tags(
        (name = "jobs", description = "Asynchronous smoothing jobs"),
        (name = "smooth", description = "One call: upload, wait, get the smoothed mesh"),
        (name = "params", description = "The smoothing parameters"),
        (name = "operations", description = "Health, readiness and metrics")
    )
)]
pub struct ApiDoc;

/// Adds the mesh media types of [`Format::ALL`] to the upload request
/// bodies and the mesh responses, so the document always lists exactly the
/// formats the core reads and writes.
pub fn add_mesh_media_types(api: &mut OpenApiDoc) {
    let binary = || {
        Content::new(Some(RefOr::T(
            utoipa::openapi::ObjectBuilder::new()
                .schema_type(utoipa::openapi::schema::Type::String)
                .content_media_type("application/octet-stream")
                .build()
                .into(),
        )))
    };
    let mut types: Vec<&str> = Format::ALL.iter().map(|f| f.content_type()).collect();
    for path in ["/v1/jobs", "/v1/smooth"] {
        let Some(op) = api
            .paths
            .paths
            .get_mut(path)
            .and_then(|item| item.post.as_mut())
        else {
            continue;
        };
        if let Some(RefOr::T(body)) = op.request_body.as_mut() {
            body.required = Some(Required::True);
            for t in types.iter().copied().chain(["application/octet-stream"]) {
                body.content.insert(t.to_owned(), RefOr::T(binary()));
            }
        }
    }
    types.sort_unstable();
    let mesh_responses = [("/v1/jobs/{id}/mesh", false), ("/v1/smooth", true)];
    for (path, is_post) in mesh_responses {
        let Some(item) = api.paths.paths.get_mut(path) else {
            continue;
        };
        let op = if is_post {
            item.post.as_mut()
        } else {
            item.get.as_mut()
        };
        let Some(RefOr::T(ok)) = op.and_then(|op| op.responses.responses.get_mut("200")) else {
            continue;
        };
        for t in &types {
            ok.content.insert((*t).to_owned(), RefOr::T(binary()));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timestamps_are_rfc3339_utc() {
        assert_eq!(rfc3339(UNIX_EPOCH), "1970-01-01T00:00:00.000Z");
        let t = UNIX_EPOCH + Duration::from_millis(951_782_400_000 + 3_723_004);
        assert_eq!(rfc3339(t), "2000-02-29T01:02:03.004Z");
        let t = UNIX_EPOCH + Duration::from_secs(1_795_392_000);
        assert_eq!(rfc3339(t), "2026-11-23T00:00:00.000Z");
    }

    #[test]
    fn params_schema_carries_the_defaults() {
        let schema = params_schema();
        let defaults = serde_json::to_value(Params::default()).unwrap();
        let props = schema["properties"].as_object().unwrap();
        assert_eq!(
            schema["$schema"],
            "https://json-schema.org/draft/2020-12/schema"
        );
        for (name, value) in defaults.as_object().unwrap() {
            let prop = props
                .get(name)
                .unwrap_or_else(|| panic!("no property {name}"));
            assert!(
                prop.get("default") == Some(value)
                    || prop.get("$ref").is_some()
                    || prop.get("allOf").is_some(),
                "{name}: {prop}"
            );
        }
        let text = schema.to_string();
        assert!(!text.contains("#/components/"), "{text}");
        assert!(schema["$defs"].get("QualityParams").is_some());
        assert_eq!(schema["additionalProperties"], false);
    }
}
