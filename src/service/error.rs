//! Errors as HTTP answers: `application/problem+json` (RFC 9457) with a
//! stable machine-readable `code`. [`status_of`] is the one table from codes
//! (the core's and the service's own) to HTTP statuses.

use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use meshsmooth_core::io::IoError;
use meshsmooth_core::{ParamError, SmoothError};
use serde::Serialize;
use utoipa::ToSchema;

/// The HTTP status for an error code. Codes of the core that this table
/// does not name yet are problems with the uploaded content (422).
pub fn status_of(code: &str) -> StatusCode {
    match code {
        // The request itself is malformed.
        "empty_body"
        | "malformed_multipart"
        | "missing_mesh_part"
        | "unexpected_part"
        | "duplicate_part"
        | "invalid_params_json"
        | "unknown_output_format"
        | "upload_interrupted" => StatusCode::BAD_REQUEST,
        "job_not_found" | "not_found" => StatusCode::NOT_FOUND,
        "method_not_allowed" => StatusCode::METHOD_NOT_ALLOWED,
        "upload_timeout" | "request_timeout" => StatusCode::REQUEST_TIMEOUT,
        "job_not_finished" | "job_failed" | "job_cancelled" | "cancelled" => StatusCode::CONFLICT,
        "result_evicted" => StatusCode::GONE,
        // Too big: the body, or the mesh in it.
        "upload_too_large" | "params_too_large" | "limit_exceeded" | "mesh_too_large" => {
            StatusCode::PAYLOAD_TOO_LARGE
        }
        "unsupported_media_type" | "unknown_format" => StatusCode::UNSUPPORTED_MEDIA_TYPE,
        // Well-formed requests whose content cannot be used: parse errors,
        // invalid meshes, parameters (the core's codes included).
        "parse_error"
        | "unsupported_content"
        | "face_index_out_of_range"
        | "face_too_small"
        | "non_finite_coordinate"
        | "invalid_mesh"
        | "no_faces"
        | "unknown_parameter"
        | "invalid_parameter"
        | "parameter_out_of_range"
        | "conversion_failed" => StatusCode::UNPROCESSABLE_ENTITY,
        "queue_full" | "shutting_down" | "job_time_limit_exceeded" => {
            StatusCode::SERVICE_UNAVAILABLE
        }
        "internal_error" | "io_error" | "position_count_mismatch" | "job_panicked" => {
            StatusCode::INTERNAL_SERVER_ERROR
        }
        // The shared job store (Redis) cannot be reached: retry shortly.
        "store_unavailable" => StatusCode::SERVICE_UNAVAILABLE,
        // A job whose worker died on every run (crash, kill, lost lease).
        "job_attempts_exhausted" => StatusCode::INTERNAL_SERVER_ERROR,
        _ => StatusCode::UNPROCESSABLE_ENTITY,
    }
}

/// An error answer: status from [`status_of`], a stable `code` and a
/// `detail` that names the problem (never an internal message).
#[derive(Debug, Clone, PartialEq)]
pub struct Problem {
    /// Stable snake_case code.
    pub code: &'static str,
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
    pub fn new(code: &'static str, detail: impl Into<String>) -> Self {
        Problem {
            code,
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
        status_of(self.code)
    }

    /// The JSON body.
    pub fn details(&self) -> ProblemDetails {
        ProblemDetails {
            type_uri: format!("urn:meshsmooth:problem:{}", self.code),
            title: title_of(self.code),
            status: self.status().as_u16(),
            code: self.code.to_owned(),
            detail: self.detail.clone(),
            field: self.field.clone(),
        }
    }

    /// An unexpected failure; `detail` must not reveal internals.
    pub fn internal(detail: impl Into<String>) -> Self {
        Problem::new("internal_error", detail)
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
            IoError::Io(_) => {
                Problem::new("io_error", "internal I/O error while encoding the mesh")
            }
            e => Problem::new(e.code(), e.to_string()),
        }
    }
}

impl From<ParamError> for Problem {
    fn from(e: ParamError) -> Self {
        Problem::new(e.code(), e.to_string()).with_field(e.field)
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
                    "unknown_parameter",
                    format!("unknown parameter `{name}` in {source}: {message}"),
                )
                .with_field(name)
            } else {
                Problem::new(
                    "invalid_parameter",
                    format!("invalid parameters in {source}: {message}"),
                )
            }
        }
        Category::Syntax | Category::Eof | Category::Io => Problem::new(
            "invalid_params_json",
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
        assert_eq!(status_of("parse_error"), StatusCode::UNPROCESSABLE_ENTITY);
        assert_eq!(status_of("limit_exceeded"), StatusCode::PAYLOAD_TOO_LARGE);
        assert_eq!(status_of("queue_full"), StatusCode::SERVICE_UNAVAILABLE);
        assert_eq!(
            status_of("unsupported_media_type"),
            StatusCode::UNSUPPORTED_MEDIA_TYPE
        );
        assert_eq!(status_of("job_not_finished"), StatusCode::CONFLICT);
        assert_eq!(status_of("io_error"), StatusCode::INTERNAL_SERVER_ERROR);
        assert_eq!(
            status_of("some_new_core_code"),
            StatusCode::UNPROCESSABLE_ENTITY
        );
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
        let p = Problem::new("queue_full", "the job queue is full (2 jobs)").with_retry_after(3);
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
