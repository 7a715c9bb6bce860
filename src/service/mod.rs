//! The HTTP service (`meshsmooth serve`): a thin axum layer over the core.
//!
//! - [`config`]: every setting, a flag and a `MESHSMOOTH_*` variable.
//! - [`routes`]: the handlers; [`upload`]: reading and parsing uploads.
//! - [`jobs`]: the bounded queue, the worker threads and the result store.
//! - [`error`]: the one mapping from error codes to HTTP statuses.
//! - [`api`]: the JSON shapes and the OpenAPI document; [`metrics`].
//! - [`web`]: the web page at `/`, its assets and the sample meshes.

pub mod api;
pub mod config;
pub mod error;
pub mod jobs;
pub mod metrics;
pub mod routes;
pub mod upload;
pub mod web;

pub use config::ServeArgs;

use anyhow::Context;
use axum::Router;
use axum::body::Body;
use axum::http::{HeaderName, HeaderValue, Method, Request, header};
use config::LogFormat;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::server::graceful::GracefulShutdown;
use hyper_util::service::TowerToHyperService;
use jobs::{Backend, JobSettings, Jobs, RedisSettings, RedisStore};
use routes::AppState;
use std::io::Write;
use std::pin::pin;
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Duration;
use tokio::net::TcpListener;
use tokio::sync::{Semaphore, watch};
use tower_http::cors::{AllowOrigin, CorsLayer};
use tower_http::request_id::{MakeRequestUuid, PropagateRequestIdLayer, SetRequestIdLayer};
use tower_http::trace::{DefaultOnResponse, TraceLayer};
use tracing::{Level, error, info, warn};
use upload::UploadConfig;

/// Runs the service until SIGTERM/SIGINT, then shuts down gracefully.
pub fn serve(args: ServeArgs) -> ExitCode {
    if let Err(e) = init_logging(&args) {
        eprintln!("meshsmooth serve: {e:#}");
        return ExitCode::FAILURE;
    }
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(args.http_threads.get())
        .thread_name("meshsmooth-http")
        .enable_all()
        .build();
    let result = match runtime {
        Ok(runtime) => runtime.block_on(run(args)),
        Err(e) => Err(anyhow::Error::from(e).context("cannot start the async runtime")),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            error!(error = format!("{e:#}"), "meshsmooth serve failed");
            eprintln!("meshsmooth serve: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn init_logging(args: &ServeArgs) -> anyhow::Result<()> {
    let filter = tracing_subscriber::EnvFilter::try_new(&args.log)
        .with_context(|| format!("invalid log filter `{}`", args.log))?;
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr);
    let installed = match args.log_format {
        LogFormat::Json => builder.json().with_current_span(true).try_init(),
        LogFormat::Text => builder.try_init(),
    };
    installed.map_err(|e| anyhow::anyhow!("cannot install the logger: {e}"))?;
    // Panics (a job's included) are logged like everything else.
    std::panic::set_hook(Box::new(|info| {
        let thread = std::thread::current();
        let backtrace = std::backtrace::Backtrace::capture();
        error!(
            thread = thread.name().unwrap_or("unnamed"),
            panic = %info,
            backtrace = %backtrace,
            "panic"
        );
    }));
    Ok(())
}

async fn run(args: ServeArgs) -> anyhow::Result<()> {
    let metrics = metrics::install().context("cannot install the metrics recorder")?;
    let workers = args.worker_count();
    anyhow::ensure!(
        args.queue_capacity >= 1,
        "--queue-capacity must be at least 1"
    );
    anyhow::ensure!(args.max_attempts >= 1, "--max-attempts must be at least 1");
    let backend = match args.store.trim() {
        "" | "memory" => Backend::Memory,
        url if url.starts_with("redis://") || url.starts_with("rediss://") => {
            let store = RedisStore::connect(RedisSettings {
                url: url.to_owned(),
                lease: args.lease,
                max_attempts: args.max_attempts,
                result_ttl: args.result_ttl,
            })
            .await?;
            Backend::Redis(Arc::new(store))
        }
        other => anyhow::bail!("unknown --store `{other}`: use `memory` or redis://HOST:PORT[/DB]"),
    };
    let store_name = match &backend {
        Backend::Memory => "memory",
        Backend::Redis(_) => "redis",
    };
    let (jobs, mut worker_threads) = Jobs::start(
        JobSettings {
            workers,
            queue_capacity: args.queue_capacity,
            time_limit: args.job_time_limit,
            result_ttl: args.result_ttl,
            result_memory: args.result_memory,
        },
        backend,
    )
    .context("cannot start the worker threads")?;
    let (stopping_tx, stopping) = watch::channel(false);
    let state = AppState {
        jobs: jobs.clone(),
        upload: Arc::new(UploadConfig {
            max_upload_bytes: args.max_upload_bytes,
            max_params_bytes: args.max_params_bytes,
            read_limits: args.read_limits(),
            timeout: args.upload_timeout,
            parse_slots: Arc::new(Semaphore::new(workers)),
        }),
        upload_slots: Arc::new(Semaphore::new(args.queue_capacity + workers)),
        request_timeout: args.request_timeout,
        test_hooks: args.enable_test_hooks,
        shutdown: stopping,
        metrics: metrics.clone(),
        params_schema: Arc::new(api::params_schema()),
    };
    let (router, _) = routes::router(state);
    let router = with_http_layers(router, &args.cors_origins)?;

    let listener = TcpListener::bind(args.listen)
        .await
        .with_context(|| format!("cannot listen on {}", args.listen))?;
    let addr = listener.local_addr()?;
    // The first line of stdout names the bound address (port 0 picks one).
    let mut stdout = std::io::stdout();
    writeln!(stdout, "meshsmooth listening on http://{addr}")?;
    stdout.flush()?;
    info!(
        %addr,
        workers,
        queue_capacity = args.queue_capacity,
        store = store_name,
        max_upload_bytes = args.max_upload_bytes,
        "meshsmooth serve started"
    );

    let housekeeping = {
        let jobs = jobs.clone();
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(Duration::from_millis(200));
            let mut n: u64 = 0;
            loop {
                tick.tick().await;
                jobs.sweep().await;
                n += 1;
                if n.is_multiple_of(25) {
                    metrics.run_upkeep();
                }
            }
        })
    };

    let connections = GracefulShutdown::new();
    accept_until_shutdown(&listener, &router, args.header_timeout, &connections).await;

    // Stop accepting: no new connections, no new jobs. Until the shutdown
    // timeout, running jobs finish, and with the memory store the queued
    // ones too; then what is left is cancelled (memory) or handed back to
    // the shared queue (Redis), and open requests are cut.
    info!(
        timeout_s = args.shutdown_timeout.as_secs_f64(),
        "shutting down"
    );
    drop(listener);
    let _ = stopping_tx.send(true);
    jobs.close();
    let deadline = args.shutdown_timeout;
    let drain_workers = tokio::task::spawn_blocking(move || {
        let finished = worker_threads.join(deadline);
        if !finished {
            warn!("jobs did not finish before the shutdown deadline; stopping them");
            jobs.abandon();
            // Cancelled jobs stop at the pipeline's next check.
            worker_threads.join(ABANDON_GRACE);
        }
        finished
    });
    let drain_connections = tokio::time::timeout(deadline, connections.shutdown());
    let (workers_done, connections_done) = tokio::join!(drain_workers, drain_connections);
    housekeeping.abort();
    info!(
        jobs_finished = workers_done.unwrap_or(false),
        connections_closed = connections_done.is_ok(),
        "meshsmooth serve stopped"
    );
    Ok(())
}

/// After the shutdown deadline: how long stopped jobs get to be filed (or
/// handed back) before the process exits anyway.
const ABANDON_GRACE: Duration = Duration::from_secs(5);

/// Serves each connection `listener` accepts with `router` (watched by
/// `connections` for a graceful shutdown) until SIGINT or SIGTERM.
async fn accept_until_shutdown(
    listener: &TcpListener,
    router: &axum::Router,
    header_timeout: Duration,
    connections: &GracefulShutdown,
) {
    let mut signal = pin!(shutdown_signal());
    loop {
        tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok((stream, _)) => {
                    let _ = stream.set_nodelay(true);
                    let service = TowerToHyperService::new(router.clone());
                    let connection = hyper::server::conn::http1::Builder::new()
                        .timer(TokioTimer::new())
                        .header_read_timeout(header_timeout)
                        .serve_connection(TokioIo::new(stream), service);
                    let connection = connections.watch(connection);
                    tokio::spawn(async move {
                        if let Err(e) = connection.await {
                            tracing::debug!(error = %e, "connection ended with an error");
                        }
                    });
                }
                Err(e) => {
                    warn!(error = %e, "accept failed");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                }
            },
            () = &mut signal => break,
        }
    }
}

/// Resolves on SIGINT or SIGTERM.
async fn shutdown_signal() {
    let interrupt = async {
        if tokio::signal::ctrl_c().await.is_err() {
            std::future::pending::<()>().await;
        }
    };
    #[cfg(unix)]
    let terminate = async {
        use tokio::signal::unix::{SignalKind, signal};
        match signal(SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let terminate = std::future::pending::<()>();
    tokio::select! {
        () = interrupt => info!("SIGINT received"),
        () = terminate => info!("SIGTERM received"),
    }
}

/// Request ids, request spans and CORS around every route.
fn with_http_layers(router: Router, cors_origins: &[String]) -> anyhow::Result<Router> {
    let request_id = HeaderName::from_static("x-request-id");
    let router = match cors(cors_origins)? {
        Some(cors) => router.layer(cors),
        None => router,
    };
    Ok(router
        .layer(PropagateRequestIdLayer::new(request_id.clone()))
        .layer(
            TraceLayer::new_for_http()
                .make_span_with(|req: &Request<Body>| {
                    let id = req
                        .headers()
                        .get("x-request-id")
                        .and_then(|v| v.to_str().ok())
                        .unwrap_or("-");
                    tracing::info_span!(
                        "request",
                        method = %req.method(),
                        path = %req.uri().path(),
                        request_id = %id
                    )
                })
                .on_request(())
                .on_response(DefaultOnResponse::new().level(Level::INFO)),
        )
        .layer(SetRequestIdLayer::new(request_id, MakeRequestUuid)))
}

/// The CORS layer for `origins` (`*` for any); None when empty.
fn cors(origins: &[String]) -> anyhow::Result<Option<CorsLayer>> {
    let origins: Vec<&str> = origins
        .iter()
        .map(|o| o.trim())
        .filter(|o| !o.is_empty())
        .collect();
    if origins.is_empty() {
        return Ok(None);
    }
    let allow = if origins.contains(&"*") {
        AllowOrigin::any()
    } else {
        let list = origins
            .iter()
            .map(|o| HeaderValue::from_str(o).with_context(|| format!("invalid CORS origin `{o}`")))
            .collect::<anyhow::Result<Vec<_>>>()?;
        AllowOrigin::list(list)
    };
    let exposed = [
        header::LOCATION,
        header::LINK,
        header::RETRY_AFTER,
        header::CONTENT_LOCATION,
        header::CONTENT_DISPOSITION,
        HeaderName::from_static("x-request-id"),
        HeaderName::from_static(routes::JOB_ID_HEADER),
    ];
    Ok(Some(
        CorsLayer::new()
            .allow_origin(allow)
            .allow_methods([Method::GET, Method::POST, Method::DELETE])
            .allow_headers([
                header::CONTENT_TYPE,
                header::ACCEPT,
                HeaderName::from_static("x-request-id"),
            ])
            .expose_headers(exposed)
            .max_age(Duration::from_secs(3600)),
    ))
}
