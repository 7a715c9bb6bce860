//! Reading an upload: the mesh (a `multipart/form-data` part or the raw
//! body), the parameters (a JSON part or the query string) and the output
//! format, under the size and time limits; the mesh is parsed on the
//! blocking pool once the parameters are known (they choose the welding).

use crate::service::error::{Code, Problem, params_problem};
use axum::body::{Body, Bytes};
use axum::extract::{FromRequest, Multipart, Query};
use axum::http::{HeaderMap, Request, Uri, header};
use futures_util::StreamExt;
use meshsmooth_core::Params;
use meshsmooth_core::io::{Format, ReadLimits};
use meshsmooth_core::job::Input;
use serde_json::{Map, Value};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::Semaphore;

/// Limits and resources for reading uploads.
#[derive(Debug, Clone)]
pub struct UploadConfig {
    /// Largest mesh file (raw body or `mesh` part), in bytes.
    pub max_upload_bytes: u64,
    /// Largest `params` part or query value, in bytes.
    pub max_params_bytes: u64,
    /// Vertex and face limits for the parser.
    pub read_limits: ReadLimits,
    /// Longest the body may take to arrive.
    pub timeout: Duration,
    /// Parses running at once (each holds a whole upload in memory).
    pub parse_slots: Arc<Semaphore>,
}

impl UploadConfig {
    /// Largest request body: the mesh plus the parameters plus multipart
    /// framing.
    pub fn max_body_bytes(&self) -> u64 {
        self.max_upload_bytes
            .saturating_add(self.max_params_bytes)
            .saturating_add(64 << 10)
    }
}

/// A read, parsed and validated upload.
#[derive(Debug)]
pub struct Upload {
    /// The parsed mesh file.
    pub document: Input,
    /// Validated parameters.
    pub params: Params,
    /// Format to write the result in (`?format=`, default the input's).
    pub output_format: Format,
    /// Size of the mesh file in bytes.
    pub bytes: u64,
    /// The mesh file as received.
    pub raw: Bytes,
}

/// What a raw (non-multipart) upload is, from its `Content-Type`.
const RAW_TYPES_HINT: &str = "send the mesh as multipart/form-data (a `mesh` file part and an \
     optional `params` JSON part) or as the raw body with a model Content-Type";

/// Reads, parses and validates an upload.
pub async fn read_upload(req: Request<Body>, config: &UploadConfig) -> Result<Upload, Problem> {
    if let Some(claimed) = content_length(req.headers())
        && claimed > config.max_body_bytes()
    {
        return Err(too_large(claimed, config.max_body_bytes()));
    }
    let query = QueryInput::parse(req.uri(), config)?;
    // Parameters in the query are checked before the body is read.
    let query_params = query
        .params
        .map(|v| params_from_value(v, "the query string"))
        .transpose()?;
    if let Some(p) = &query_params {
        p.validate()?;
    }
    let content_type = req
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .map(str::to_owned);
    let Some(content_type) = content_type else {
        return Err(Problem::new(
            Code::UnsupportedMediaType,
            format!(
                "the request has no Content-Type; {RAW_TYPES_HINT} ({})",
                raw_types()
            ),
        ));
    };
    let essence = content_type
        .split(';')
        .next()
        .unwrap_or_default()
        .trim()
        .to_ascii_lowercase();

    let read = async {
        if essence == "multipart/form-data" {
            read_multipart(req, config).await
        } else {
            let format = raw_format(&essence)?;
            if let Some(claimed) = content_length(req.headers())
                && claimed > config.max_upload_bytes
            {
                return Err(too_large(claimed, config.max_upload_bytes));
            }
            let bytes = read_body(req.into_body(), config.max_upload_bytes).await?;
            Ok(RawUpload {
                bytes,
                format,
                params: None,
            })
        }
    };
    let raw = tokio::time::timeout(config.timeout, read)
        .await
        .map_err(|_| {
            Problem::new(
                Code::UploadTimeout,
                format!(
                    "the upload did not arrive within the upload time limit of {} s",
                    config.timeout.as_secs_f64()
                ),
            )
        })??;

    let params = upload_params(raw.params, query_params)?;
    if raw.bytes.is_empty() {
        return Err(Problem::new(Code::EmptyBody, "the mesh file is empty"));
    }
    let Some(format) = raw.format.or_else(|| Format::sniff(&raw.bytes)) else {
        return Err(Problem::new(
            Code::UnknownFormat,
            format!(
                "the mesh format could not be determined from the file name, the part's \
                 Content-Type or the content; name the file with an extension or set a \
                 Content-Type ({})",
                raw_types()
            ),
        ));
    };
    let bytes = raw.bytes.len() as u64;
    metrics::counter!("meshsmooth_upload_bytes_total").increment(bytes);
    let raw_bytes = Bytes::from(raw.bytes);
    let document = parse(raw_bytes.clone(), format, params.clone(), config).await?;
    Ok(Upload {
        output_format: query.output_format.unwrap_or(document.format()),
        document,
        params,
        bytes,
        raw: raw_bytes,
    })
}

/// The parameters of an upload: from its `params` part or from the query
/// string (already validated), not both; the defaults when neither.
fn upload_params(part: Option<Vec<u8>>, query: Option<Params>) -> Result<Params, Problem> {
    match (part, query) {
        (Some(_), Some(_)) => Err(Problem::new(
            Code::InvalidParameter,
            "parameters were given both in the `params` part and in the query string; use one",
        )),
        (Some(part), None) => {
            let p = params_from_json(&part, "the `params` part")?;
            p.validate()?;
            Ok(p)
        }
        (None, Some(p)) => Ok(p),
        (None, None) => Ok(Params::default()),
    }
}

/// The mesh bytes before parsing.
struct RawUpload {
    bytes: Vec<u8>,
    /// Known format, or None to sniff.
    format: Option<Format>,
    /// The `params` part, if any.
    params: Option<Vec<u8>>,
}

fn content_length(headers: &HeaderMap) -> Option<u64> {
    headers
        .get(header::CONTENT_LENGTH)?
        .to_str()
        .ok()?
        .trim()
        .parse()
        .ok()
}

fn too_large(bytes: u64, limit: u64) -> Problem {
    Problem::new(
        Code::UploadTooLarge,
        format!("the upload is {bytes} bytes; the limit is {limit} bytes"),
    )
}

fn raw_types() -> String {
    let types: Vec<&str> = Format::ALL.iter().map(|f| f.content_type()).collect();
    types.join(", ")
}

/// The format of a raw body from its Content-Type essence; None: sniff.
fn raw_format(essence: &str) -> Result<Option<Format>, Problem> {
    if essence == "application/octet-stream" {
        return Ok(None);
    }
    Format::from_content_type(essence).map(Some).ok_or_else(|| {
        Problem::new(
            Code::UnsupportedMediaType,
            format!(
                "Content-Type `{essence}` is not a mesh format; {RAW_TYPES_HINT} ({}, or \
                 application/octet-stream to detect the format from the content)",
                raw_types()
            ),
        )
    })
}

/// Reads a whole body, refusing more than `limit` bytes.
async fn read_body(body: Body, limit: u64) -> Result<Vec<u8>, Problem> {
    let mut stream = body.into_data_stream();
    let mut buf = Vec::new();
    while let Some(chunk) = stream.next().await {
        let chunk = chunk.map_err(|_| interrupted())?;
        push_limited(&mut buf, &chunk, limit)?;
    }
    Ok(buf)
}

fn push_limited(buf: &mut Vec<u8>, chunk: &[u8], limit: u64) -> Result<(), Problem> {
    let total = (buf.len() + chunk.len()) as u64;
    if total > limit {
        return Err(Problem::new(
            Code::UploadTooLarge,
            format!("the mesh file exceeds the limit of {limit} bytes"),
        ));
    }
    buf.extend_from_slice(chunk);
    Ok(())
}

fn interrupted() -> Problem {
    Problem::new(
        Code::UploadInterrupted,
        "the request body ended early or could not be read",
    )
}

async fn read_multipart(req: Request<Body>, config: &UploadConfig) -> Result<RawUpload, Problem> {
    let mut multipart = Multipart::from_request(req, &())
        .await
        .map_err(|e| Problem::new(Code::MalformedMultipart, e.body_text()))?;
    let mut mesh: Option<(Vec<u8>, Option<Format>)> = None;
    let mut params: Option<Vec<u8>> = None;
    while let Some(mut field) = multipart.next_field().await.map_err(multipart_problem)? {
        let name = field.name().unwrap_or_default().to_owned();
        match name.as_str() {
            "mesh" => {
                if mesh.is_some() {
                    return Err(duplicate("mesh"));
                }
                let format = field
                    .file_name()
                    .and_then(Format::from_file_name)
                    .or_else(|| field.content_type().and_then(Format::from_content_type));
                let mut bytes = Vec::new();
                while let Some(chunk) = field.chunk().await.map_err(multipart_problem)? {
                    push_limited(&mut bytes, &chunk, config.max_upload_bytes)?;
                }
                mesh = Some((bytes, format));
            }
            "params" => {
                if params.is_some() {
                    return Err(duplicate("params"));
                }
                let mut bytes = Vec::new();
                while let Some(chunk) = field.chunk().await.map_err(multipart_problem)? {
                    if (bytes.len() + chunk.len()) as u64 > config.max_params_bytes {
                        return Err(Problem::new(
                            Code::ParamsTooLarge,
                            format!(
                                "the `params` part exceeds the limit of {} bytes",
                                config.max_params_bytes
                            ),
                        ));
                    }
                    bytes.extend_from_slice(&chunk);
                }
                params = Some(bytes);
            }
            other => {
                return Err(Problem::new(
                    Code::UnexpectedPart,
                    format!(
                        "unexpected multipart part `{other}`; the parts are `mesh` (the file) \
                         and `params` (JSON, optional)"
                    ),
                ));
            }
        }
    }
    let Some((bytes, format)) = mesh else {
        return Err(Problem::new(
            Code::MissingMeshPart,
            "the multipart body has no `mesh` part (the mesh file)",
        ));
    };
    Ok(RawUpload {
        bytes,
        format,
        params,
    })
}

fn duplicate(part: &str) -> Problem {
    Problem::new(
        Code::DuplicatePart,
        format!("the multipart body has more than one `{part}` part"),
    )
}

fn multipart_problem(e: axum::extract::multipart::MultipartError) -> Problem {
    if e.status() == axum::http::StatusCode::PAYLOAD_TOO_LARGE {
        Problem::new(
            Code::UploadTooLarge,
            format!("the multipart body is too large: {}", e.body_text()),
        )
    } else {
        Problem::new(Code::MalformedMultipart, e.body_text())
    }
}

/// Reads the job's input with the reading options of `params` (welding)
/// under the configured limits on the blocking pool, a bounded number at a
/// time.
async fn parse(
    bytes: Bytes,
    format: Format,
    params: Params,
    config: &UploadConfig,
) -> Result<Input, Problem> {
    let limits = config.read_limits.clone();
    let permit = config
        .parse_slots
        .clone()
        .acquire_owned()
        .await
        .map_err(|_| Problem::new(Code::ShuttingDown, "the service is shutting down"))?;
    let parsed = tokio::task::spawn_blocking(move || {
        let _permit = permit;
        Input::read(&bytes, format, &params, limits)
    })
    .await;
    match parsed {
        Ok(Ok(document)) => Ok(document),
        Ok(Err(e)) => Err(e.into()),
        Err(e) => {
            tracing::error!(error = %e, "the mesh reader failed unexpectedly");
            Err(Problem::internal(
                "the mesh could not be read because of an internal error",
            ))
        }
    }
}

/// Options and parameters from the query string.
#[derive(Debug, Default, PartialEq)]
pub struct QueryInput {
    /// `format=`: the output format.
    pub output_format: Option<Format>,
    /// Parameters as a JSON object, if any were given.
    pub params: Option<Value>,
}

impl QueryInput {
    /// Reads `format`, `params` (a whole JSON object) and dotted parameter
    /// keys (`k_max=5`, `quality.enabled=false`) from the query string.
    pub fn parse(uri: &Uri, config: &UploadConfig) -> Result<QueryInput, Problem> {
        let Query(pairs) = Query::<Vec<(String, String)>>::try_from_uri(uri).map_err(|e| {
            Problem::new(Code::InvalidParameter, format!("invalid query string: {e}"))
        })?;
        let mut input = QueryInput::default();
        let mut object = Map::new();
        let mut whole: Option<Value> = None;
        for (key, value) in pairs {
            if value.len() as u64 > config.max_params_bytes {
                return Err(Problem::new(
                    Code::ParamsTooLarge,
                    format!(
                        "query value `{key}` exceeds the limit of {} bytes",
                        config.max_params_bytes
                    ),
                ));
            }
            match key.as_str() {
                "format" => input.output_format = Some(parse_output_format(&value)?),
                "params" => {
                    let v: Value = serde_json::from_str(&value)
                        .map_err(|e| params_problem(&e, "the `params` query value"))?;
                    whole = Some(v);
                }
                _ => insert_dotted(&mut object, &key, scalar(&value))?,
            }
        }
        input.params = match (whole, object.is_empty()) {
            (Some(_), false) => {
                return Err(Problem::new(
                    Code::InvalidParameter,
                    "give parameters either as `params=<JSON>` or as separate query keys, not both",
                ));
            }
            (Some(v), true) => Some(v),
            (None, false) => Some(Value::Object(object)),
            (None, true) => None,
        };
        Ok(input)
    }
}

/// Parses `?format=`.
pub fn parse_output_format(name: &str) -> Result<Format, Problem> {
    name.parse::<Format>()
        .map_err(|e| Problem::new(Code::UnknownOutputFormat, e.to_string()))
}

/// A query value as JSON: numbers, booleans and `null` as such, anything
/// else as a string.
fn scalar(raw: &str) -> Value {
    match serde_json::from_str::<Value>(raw) {
        Ok(v @ (Value::Number(_) | Value::Bool(_) | Value::Null)) => v,
        _ => Value::String(raw.to_owned()),
    }
}

/// Inserts `value` at a dotted path (`quality.enabled`) into `object`.
fn insert_dotted(object: &mut Map<String, Value>, key: &str, value: Value) -> Result<(), Problem> {
    let bad = |why: &str| {
        Problem::new(Code::InvalidParameter, format!("query key `{key}` {why}")).with_field(key)
    };
    let mut segments = key.split('.').peekable();
    let mut current = object;
    while let Some(segment) = segments.next() {
        if segment.is_empty() {
            return Err(bad("has an empty path segment"));
        }
        if segments.peek().is_none() {
            if current.insert(segment.to_owned(), value).is_some() {
                return Err(bad("is given twice"));
            }
            return Ok(());
        }
        let next = current
            .entry(segment.to_owned())
            .or_insert_with(|| Value::Object(Map::new()));
        current = match next {
            Value::Object(map) => map,
            _ => return Err(bad("conflicts with another key")),
        };
    }
    Ok(())
}

/// Parameters from a JSON document (the `params` part).
pub fn params_from_json(bytes: &[u8], source: &str) -> Result<Params, Problem> {
    let mut de = serde_json::Deserializer::from_slice(bytes);
    let params = serde_path_to_error::deserialize(&mut de).map_err(|e| path_problem(&e, source))?;
    de.end().map_err(|e| params_problem(&e, source))?;
    Ok(params)
}

/// Parameters from a JSON value (the query string).
pub fn params_from_value(value: Value, source: &str) -> Result<Params, Problem> {
    serde_path_to_error::deserialize(value).map_err(|e| path_problem(&e, source))
}

fn path_problem(e: &serde_path_to_error::Error<serde_json::Error>, source: &str) -> Problem {
    let mut problem = params_problem(e.inner(), source);
    let path = e.path().to_string();
    if path != "." && !path.is_empty() {
        problem.field = Some(match problem.field.take() {
            // An unknown key is reported with the path of the object
            // holding it.
            Some(name) if problem.code == Code::UnknownParameter && !path.ends_with(&name) => {
                format!("{path}.{name}")
            }
            _ => path,
        });
    }
    problem
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config() -> UploadConfig {
        UploadConfig {
            max_upload_bytes: 1000,
            max_params_bytes: 100,
            read_limits: ReadLimits::default(),
            timeout: Duration::from_secs(1),
            parse_slots: Arc::new(Semaphore::new(1)),
        }
    }

    fn query(q: &str) -> Result<QueryInput, Problem> {
        QueryInput::parse(&format!("/v1/jobs?{q}").parse().unwrap(), &config())
    }

    #[test]
    fn dotted_query_keys_build_nested_parameters() {
        let q = query("method=laplacian&baseline.iterations=7&quality.enabled=false&format=obj")
            .unwrap();
        assert_eq!(q.output_format, Some(Format::Obj));
        let p = params_from_value(q.params.unwrap(), "q").unwrap();
        assert_eq!(p.method, meshsmooth_core::Method::Laplacian);
        assert_eq!(p.baseline.iterations, 7);
        assert!(!p.quality.enabled);
        assert_eq!(p.k_max, Params::default().k_max);
    }

    #[test]
    fn weld_query_keys_are_null_or_booleans() {
        for (q, weld) in [
            ("weld=false", Some(false)),
            ("weld=true", Some(true)),
            ("weld=null", None),
        ] {
            let p = params_from_value(query(q).unwrap().params.unwrap(), "q").unwrap();
            assert_eq!(p.weld, weld, "{q}");
        }
        let q = query("weld_tolerance=0.001&vertex_results=true").unwrap();
        let p = params_from_value(q.params.unwrap(), "q").unwrap();
        assert_eq!(p.weld_tolerance, 0.001);
        assert!(p.vertex_results);
        let e = params_from_value(query("weld=yes").unwrap().params.unwrap(), "q").unwrap_err();
        assert_eq!(e.code, "invalid_parameter");
        assert_eq!(e.field.as_deref(), Some("weld"));
    }

    #[test]
    fn a_whole_params_object_is_accepted() {
        let q = query("params=%7B%22k_max%22%3A5%7D").unwrap();
        assert_eq!(params_from_value(q.params.unwrap(), "q").unwrap().k_max, 5);
        assert_eq!(query("").unwrap(), QueryInput::default());
        assert!(query("params=%7B%7D&k_max=3").is_err());
    }

    #[test]
    fn bad_query_keys_name_the_field() {
        let q = query("quality.enabld=false").unwrap();
        let e = params_from_value(q.params.unwrap(), "the query string").unwrap_err();
        assert_eq!(e.code, "unknown_parameter");
        assert_eq!(e.field.as_deref(), Some("quality.enabld"));

        let q = query("k_max=lots").unwrap();
        let e = params_from_value(q.params.unwrap(), "q").unwrap_err();
        assert_eq!(e.code, "invalid_parameter");
        assert_eq!(e.field.as_deref(), Some("k_max"));

        assert_eq!(
            query("k_max=1&k_max=2").unwrap_err().code,
            "invalid_parameter"
        );
        assert_eq!(
            query("quality=1&quality.enabled=true").unwrap_err().code,
            "invalid_parameter"
        );
        assert_eq!(query("a..b=1").unwrap_err().code, "invalid_parameter");
        assert_eq!(
            query("format=dwg").unwrap_err().code,
            "unknown_output_format"
        );
        let long = "x".repeat(101);
        assert_eq!(
            query(&format!("k_max={long}")).unwrap_err().code,
            "params_too_large"
        );
    }

    #[test]
    fn json_parameters_name_nested_unknown_fields() {
        let e = params_from_json(br#"{"baseline": {"lambda": 0.5, "nu": 1}}"#, "p").unwrap_err();
        assert_eq!(e.code, "unknown_parameter");
        assert_eq!(e.field.as_deref(), Some("baseline.nu"));
        let e = params_from_json(br#"{"k_max": 5} trailing"#, "p").unwrap_err();
        assert_eq!(e.code, "invalid_params_json");
        assert_eq!(params_from_json(b"{}", "p").unwrap(), Params::default());
    }

    #[test]
    fn raw_content_types_map_to_formats() {
        assert_eq!(raw_format("model/obj").unwrap(), Some(Format::Obj));
        assert_eq!(raw_format("application/octet-stream").unwrap(), None);
        assert_eq!(
            raw_format("text/html").unwrap_err().code,
            "unsupported_media_type"
        );
    }

    #[test]
    fn bodies_over_the_limit_are_refused() {
        let mut buf = Vec::new();
        push_limited(&mut buf, &[0; 600], 1000).unwrap();
        assert_eq!(
            push_limited(&mut buf, &[0; 600], 1000).unwrap_err().code,
            "upload_too_large"
        );
        assert_eq!(buf.len(), 600);
    }
}
