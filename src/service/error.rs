//! Errors as HTTP answers: `application/problem+json` (RFC 9457) with a
//! stable machine-readable `code`. [`Code`] lists every code (the core's
//! [`ErrorCode`]s and the service's own), and [`Code::status`] is the one
//! `match` from codes to HTTP statuses: the compiler checks that each code
//! has one.

use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use meshsmooth_core::ErrorCode;
use meshsmooth_core::io::IoError;
use meshsmooth_core::job::JobError;
use meshsmooth_core::{ParamError, SmoothError};
use serde::Serialize;
use utoipa::ToSchema;

meshsmooth_core::error_code_enum! {
    /// The stable code of an error answer: the core's codes and the
    /// service's own.
    Code {
        /// An error of the mesh core (reading, parameters, smoothing).
        Core(ErrorCode)
    };
    /// The body is empty.
    EmptyBody = "empty_body",
    /// The multipart body is malformed.
    MalformedMultipart = "malformed_multipart",
    /// The multipart body has no `mesh` part.
    MissingMeshPart = "missing_mesh_part",
    /// The multipart body has a part other than `mesh` and `params`.
    UnexpectedPart = "unexpected_part",
    /// The multipart body has a part twice.
    DuplicatePart = "duplicate_part",
    /// The parameters are not valid JSON.
    InvalidParamsJson = "invalid_params_json",
    /// `?format=` names no format.
    UnknownOutputFormat = "unknown_output_format",
    /// The body ended early.
    UploadInterrupted = "upload_interrupted",
    /// No such job.
    JobNotFound = "job_not_found",
    /// No such route.
    NotFound = "not_found",
    /// The route does not take this method.
    MethodNotAllowed = "method_not_allowed",
    /// The upload did not arrive in time.
    UploadTimeout = "upload_timeout",
    /// The request took too long.
    RequestTimeout = "request_timeout",
    /// The job has no result yet.
    JobNotFinished = "job_not_finished",
    /// The job failed: it has no result.
    JobFailed = "job_failed",
    /// The job was cancelled: it has no result.
    JobCancelled = "job_cancelled",
    /// The result was evicted to make room.
    ResultEvicted = "result_evicted",
    /// The body is larger than the limit.
    UploadTooLarge = "upload_too_large",
    /// The parameters are larger than the limit.
    ParamsTooLarge = "params_too_large",
    /// The Content-Type is no mesh format.
    UnsupportedMediaType = "unsupported_media_type",
    /// The mesh format cannot be told.
    UnknownFormat = "unknown_format",
    /// A parameter that does not exist.
    UnknownParameter = "unknown_parameter",
    /// A parameter of the wrong type or value.
    InvalidParameter = "invalid_parameter",
    /// The job queue is full.
    QueueFull = "queue_full",
    /// The service is shutting down.
    ShuttingDown = "shutting_down",
    /// The job ran past the time limit.
    JobTimeLimitExceeded = "job_time_limit_exceeded",
    /// An unexpected failure of the service.
    InternalError = "internal_error",
    /// The job panicked (the worker goes on).
    JobPanicked = "job_panicked",
    /// A result could not be written in the format asked for.
    ConversionFailed = "conversion_failed",
    /// The shared job store (Redis) cannot be reached.
    StoreUnavailable = "store_unavailable",
    /// Every run of the job ended without an outcome (its worker crashed,
    /// was killed or lost its lease) up to the attempts limit.
    JobAttemptsExhausted = "job_attempts_exhausted",
}

impl Code {
    /// The HTTP status of an answer with this code.
    pub fn status(self) -> StatusCode {
        use Code::*;
        match self {
            // The request itself is malformed.
            EmptyBody | MalformedMultipart | MissingMeshPart | UnexpectedPart | DuplicatePart
            | InvalidParamsJson | UnknownOutputFormat | UploadInterrupted => {
                StatusCode::BAD_REQUEST
            }
            JobNotFound | NotFound => StatusCode::NOT_FOUND,
            MethodNotAllowed => StatusCode::METHOD_NOT_ALLOWED,
            UploadTimeout | RequestTimeout => StatusCode::REQUEST_TIMEOUT,
            JobNotFinished | JobFailed | JobCancelled => StatusCode::CONFLICT,
            ResultEvicted => StatusCode::GONE,
            UploadTooLarge | ParamsTooLarge => StatusCode::PAYLOAD_TOO_LARGE,
            UnsupportedMediaType | UnknownFormat => StatusCode::UNSUPPORTED_MEDIA_TYPE,
            // Well-formed requests whose parameters cannot be used.
            UnknownParameter | InvalidParameter | ConversionFailed => {
                StatusCode::UNPROCESSABLE_ENTITY
            }
            // Unavailable for now. `store_unavailable`: the shared job store
            // (Redis) cannot be reached; its answers carry `Retry-After`.
            QueueFull | ShuttingDown | JobTimeLimitExceeded | StoreUnavailable => {
                StatusCode::SERVICE_UNAVAILABLE
            }
            // Ours, not the client's. `job_attempts_exhausted`: a job whose
            // worker died on every run (crash, kill, lost lease).
            InternalError | JobPanicked | JobAttemptsExhausted => StatusCode::INTERNAL_SERVER_ERROR,
            Core(code) => match code {
                // Too big: the mesh in the body.
                ErrorCode::LimitExceeded | ErrorCode::MeshTooLarge => StatusCode::PAYLOAD_TOO_LARGE,
                // Content that cannot be used: malformed or unsupported
                // files, invalid meshes, parameters out of range.
                ErrorCode::ParseError
                | ErrorCode::FaceIndexOutOfRange
                | ErrorCode::FaceTooSmall
                | ErrorCode::NonFiniteCoordinate
                | ErrorCode::InvalidMesh
                | ErrorCode::NoFaces
                | ErrorCode::UnsupportedContent
                | ErrorCode::ExternalUriNotAllowed
                | ErrorCode::UnsupportedExtension
                | ErrorCode::UnsupportedPrimitiveMode
                | ErrorCode::GltfInvalid
                | ErrorCode::GlbInvalid
                | ErrorCode::ParameterOutOfRange
                | ErrorCode::VertexValenceTooHigh
                | ErrorCode::FaceTooLarge => StatusCode::UNPROCESSABLE_ENTITY,
                ErrorCode::Cancelled => StatusCode::CONFLICT,
                // Encoding into memory: a failure is ours, not the client's.
                ErrorCode::PositionCountMismatch | ErrorCode::IoError => {
                    StatusCode::INTERNAL_SERVER_ERROR
                }
            },
        }
    }
}

impl Code {
    /// The code whose text is `text` (e.g. one read back from the shared
    /// job store), if any.
    pub fn parse(text: &str) -> Option<Code> {
        let core = ErrorCode::OWN.iter().map(|&c| Code::Core(c));
        core.chain(Code::OWN.iter().copied())
            .find(|code| code.as_str() == text)
    }
}

impl From<ErrorCode> for Code {
    fn from(code: ErrorCode) -> Self {
        Code::Core(code)
    }
}

/// An error answer: status from [`Code::status`], a stable `code` and a
/// `detail` that names the problem (never an internal message).
#[derive(Debug, Clone, PartialEq)]
pub struct Problem {
    /// Stable code.
    pub code: Code,
    /// What went wrong, for a human.
    pub detail: String,
    /// The parameter at fault, for parameter errors (dotted path).
    pub field: Option<String>,
    /// Seconds after which a retry may succeed (sent as `Retry-After`).
    pub retry_after: Option<u64>,
}

/// The body of an error answer (RFC 9457 problem details).
#[derive(Debug, Clone, Serialize, serde::Deserialize, ToSchema, PartialEq)]
pub struct ProblemDetails {
    /// URI naming the problem type: `urn:meshsmooth:problem:<code>`.
    #[serde(rename = "type")]
    pub type_uri: String,
    /// Short summary of the problem type (the same for every instance).
    pub title: String,
    /// HTTP status.
    pub status: u16,
    /// Stable machine-readable code, e.g. `parse_error`, `queue_full`.
    pub code: String,
    /// What went wrong in this instance: the line, the field, the limit.
    pub detail: String,
    /// The parameter at fault (dotted path), for parameter errors.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub field: Option<String>,
}

impl Problem {
    /// A problem with `code` and `detail`.
    pub fn new(code: impl Into<Code>, detail: impl Into<String>) -> Self {
        Problem {
            code: code.into(),
            detail: detail.into(),
            field: None,
            retry_after: None,
        }
    }

    /// Adds the parameter at fault.
    pub fn with_field(mut self, field: impl Into<String>) -> Self {
        self.field = Some(field.into());
        self
    }

    /// Adds a `Retry-After` in seconds.
    pub fn with_retry_after(mut self, seconds: u64) -> Self {
        self.retry_after = Some(seconds);
        self
    }

    /// The HTTP status of this problem.
    pub fn status(&self) -> StatusCode {
        self.code.status()
    }

    /// The JSON body.
    pub fn details(&self) -> ProblemDetails {
        ProblemDetails {
            type_uri: format!("urn:meshsmooth:problem:{}", self.code),
            title: title_of(self.code.as_str()),
            status: self.status().as_u16(),
            code: self.code.as_str().to_owned(),
            detail: self.detail.clone(),
            field: self.field.clone(),
        }
    }

    /// An unexpected failure; `detail` must not reveal internals.
    pub fn internal(detail: impl Into<String>) -> Self {
        Problem::new(Code::InternalError, detail)
    }
}

/// `queue_full` → `Queue full`.
fn title_of(code: &str) -> String {
    let mut title = code.replace('_', " ");
    if let Some(first) = title.get_mut(0..1) {
        first.make_ascii_uppercase();
    }
    title
}

impl IntoResponse for Problem {
    fn into_response(self) -> Response {
        let status = self.status();
        let body = serde_json::to_vec(&self.details()).unwrap_or_default();
        let mut response = (status, body).into_response();
        let headers = response.headers_mut();
        headers.insert(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/problem+json"),
        );
        if let Some(seconds) = self.retry_after {
            headers.insert(header::RETRY_AFTER, HeaderValue::from(seconds));
        }
        response
    }
}

impl From<IoError> for Problem {
    fn from(e: IoError) -> Self {
        match e {
            // Reading from memory and writing to memory cannot fail with an
            // I/O error; if it ever does, it is ours, not the client's.
            IoError::Io(_) => Problem::new(
                ErrorCode::IoError,
                "internal I/O error while encoding the mesh",
            ),
            e => Problem::new(e.code(), e.to_string()),
        }
    }
}

impl From<ParamError> for Problem {
    fn from(e: ParamError) -> Self {
        Problem::new(e.code(), e.to_string()).with_field(e.field)
    }
}

impl From<JobError> for Problem {
    fn from(e: JobError) -> Self {
        match e {
            JobError::Read(e) | JobError::Write(e) => e.into(),
            JobError::Smooth(e) => e.into(),
        }
    }
}

impl From<SmoothError> for Problem {
    fn from(e: SmoothError) -> Self {
        match e {
            SmoothError::Params(p) => p.into(),
            e => Problem::new(e.code(), e.to_string()),
        }
    }
}

/// Turns a serde error on the parameters into a problem that names the
/// field: unknown fields (422 `unknown_parameter`), wrong types or values
/// (422 `invalid_parameter`), malformed JSON (400 `invalid_params_json`).
pub fn params_problem(e: &serde_json::Error, source: &str) -> Problem {
    use serde_json::error::Category;
    let message = e.to_string();
    match e.classify() {
        Category::Data => {
            if let Some(name) = message
                .strip_prefix("unknown field `")
                .and_then(|rest| rest.split('`').next())
            {
                Problem::new(
                    Code::UnknownParameter,
                    format!("unknown parameter `{name}` in {source}: {message}"),
                )
                .with_field(name)
            } else {
                Problem::new(
                    Code::InvalidParameter,
                    format!("invalid parameters in {source}: {message}"),
                )
            }
        }
        Category::Syntax | Category::Eof | Category::Io => Problem::new(
            Code::InvalidParamsJson,
            format!("the parameters in {source} are not valid JSON: {message}"),
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use meshsmooth_core::Params;

    #[test]
    fn statuses_follow_the_table() {
        let status = |code: &str| {
            Code::parse(code)
                .unwrap_or_else(|| panic!("no code {code}"))
                .status()
        };
        assert_eq!(status("parse_error"), StatusCode::UNPROCESSABLE_ENTITY);
        assert_eq!(status("limit_exceeded"), StatusCode::PAYLOAD_TOO_LARGE);
        assert_eq!(status("queue_full"), StatusCode::SERVICE_UNAVAILABLE);
        assert_eq!(
            status("unsupported_media_type"),
            StatusCode::UNSUPPORTED_MEDIA_TYPE
        );
        assert_eq!(status("job_not_finished"), StatusCode::CONFLICT);
        assert_eq!(status("io_error"), StatusCode::INTERNAL_SERVER_ERROR);
        assert_eq!(
            status("external_uri_not_allowed"),
            StatusCode::UNPROCESSABLE_ENTITY
        );
        assert_eq!(status("store_unavailable"), StatusCode::SERVICE_UNAVAILABLE);
        assert_eq!(
            status("job_attempts_exhausted"),
            StatusCode::INTERNAL_SERVER_ERROR
        );
    }

    #[test]
    fn every_code_parses_back_from_its_text() {
        let core = ErrorCode::OWN.iter().map(|&c| Code::Core(c));
        for code in core.chain(Code::OWN.iter().copied()) {
            assert_eq!(Code::parse(code.as_str()), Some(code));
        }
        assert_eq!(Code::parse("no_such_code"), None);
    }

    #[test]
    fn codes_are_distinct() {
        let mut seen = std::collections::HashSet::new();
        let core = ErrorCode::OWN.iter().map(|&c| Code::Core(c));
        for code in core.chain(Code::OWN.iter().copied()) {
            assert!(seen.insert(code.as_str()), "{code} twice");
        }
    }

    #[test]
    fn obj_index_and_coordinate_errors_are_422_with_their_line() {
        use meshsmooth_core::io::{Format, ReadLimits, read};
        for (text, code) in [
            (
                "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n",
                "face_index_out_of_range",
            ),
            (
                "v 0 0 0\nv inf 0 0\nv 0 1 0\nf 1 2 3\n",
                "non_finite_coordinate",
            ),
        ] {
            let e = read(text.as_bytes(), Format::Obj, &ReadLimits::default()).unwrap_err();
            let p = Problem::from(e);
            assert_eq!(p.code, code);
            assert_eq!(p.status(), StatusCode::UNPROCESSABLE_ENTITY);
            assert!(p.detail.contains("line"), "{}", p.detail);
        }
    }

    #[test]
    fn problem_body_follows_rfc_9457() {
        let p = Problem::new(Code::QueueFull, "the job queue is full (2 jobs)").with_retry_after(3);
        let d = p.details();
        assert_eq!(d.type_uri, "urn:meshsmooth:problem:queue_full");
        assert_eq!(d.title, "Queue full");
        assert_eq!(d.status, 503);
        let json = serde_json::to_value(&d).unwrap();
        assert_eq!(json["type"], "urn:meshsmooth:problem:queue_full");
        assert!(json.get("field").is_none());
        let r = p.into_response();
        assert_eq!(
            r.headers()[header::CONTENT_TYPE],
            "application/problem+json"
        );
        assert_eq!(r.headers()[header::RETRY_AFTER], "3");
    }

    #[test]
    fn serde_errors_name_the_parameter() {
        let e = serde_json::from_str::<Params>(r#"{"k_maks": 3}"#).unwrap_err();
        let p = params_problem(&e, "the `params` part");
        assert_eq!(p.code, "unknown_parameter");
        assert_eq!(p.field.as_deref(), Some("k_maks"));
        assert!(p.detail.contains("k_maks"), "{}", p.detail);

        let e = serde_json::from_str::<Params>(r#"{"k_max": "many"}"#).unwrap_err();
        assert_eq!(params_problem(&e, "x").code, "invalid_parameter");
        let e = serde_json::from_str::<Params>(r#"{"k_max": "#).unwrap_err();
        assert_eq!(params_problem(&e, "x").code, "invalid_params_json");
    }

    #[test]
    fn range_errors_name_field_and_range() {
        let params = Params {
            k_max: u32::MAX,
            ..Params::default()
        };
        let p = Problem::from(params.validate().unwrap_err());
        assert_eq!(p.code, "parameter_out_of_range");
        assert_eq!(p.status(), StatusCode::UNPROCESSABLE_ENTITY);
        assert_eq!(p.field.as_deref(), Some("k_max"));
        assert!(p.detail.contains("allowed"), "{}", p.detail);
        assert!(p.detail.contains("k_max"), "{}", p.detail);
    }
}
