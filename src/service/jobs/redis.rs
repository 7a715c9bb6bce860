//! The shared job store on Redis (`serve --store redis://…`): jobs, their
//! state and progress, the queue, uploads and results live in one Redis, so
//! any replica answers for any job and a job outlives the replica that
//! accepted it.
//!
//! Layout, under the prefix `meshsmooth:`:
//! - `queue`: a stream of job ids read by the consumer group `workers`.
//!   A replica's worker claims an entry (`XREADGROUP`) and holds it as a
//!   lease it renews while running (`XCLAIM … JUSTID`); an entry whose lease
//!   lapsed is reclaimed by any worker (`XAUTOCLAIM`) and run again.
//! - `queued`: jobs waiting for a worker, fleet-wide (the queue capacity is
//!   checked against it).
//! - `job:{id}`: a hash with the job's fixed description (`meta`, JSON),
//!   state, progress, attempts and outcome; `job:{id}:input` the uploaded
//!   file until the job ends; `job:{id}:mesh` and `job:{id}:report` the
//!   result. Finished jobs expire after the result TTL.
//! - `results` (sorted by finishing order), `result_sizes` and
//!   `result_bytes`: the bookkeeping of the result memory budget, oldest
//!   evicted first.
//!
//! Every change of more than one key is one Lua script (big payloads go
//! in as plain SETs in the same MULTI transaction as the script), so a job
//! is never seen half-written, whatever fails in between.

use super::{
    CancelReason, Claim, HeldResult, InputInfo, Job, JobResult, JobState, Outcome, TestHook, lock,
};
use crate::service::error::{Code, Problem};
use axum::body::Bytes;
use meshsmooth_core::io::{Format, ReadLimits};
use meshsmooth_core::job::Input;
use meshsmooth_core::{Params, Stage};
use redis::aio::ConnectionManager;
use redis::{AsyncConnectionConfig, Script, Value};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU32};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};
use tokio::sync::watch;
use uuid::Uuid;

/// Key prefix of everything this service keeps in Redis.
const PREFIX: &str = "meshsmooth:";
/// The consumer group of the workers.
const GROUP: &str = "workers";
/// Longest a Redis command may take before the caller gets
/// `store_unavailable`: a stalled Redis is an answer, not a hang.
const RESPONSE_TIMEOUT: Duration = Duration::from_secs(2);
/// Longest a connection attempt may take.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(2);
/// How often a running job's lease is renewed, its progress published and
/// its cancellation flag read: often enough that a `DELETE` stops a job
/// within a fraction of a second.
pub(super) const TICK: Duration = Duration::from_millis(200);
/// Longest a worker waits for a new queue entry before it looks for lapsed
/// leases again.
const IDLE_WAIT: Duration = Duration::from_millis(500);
/// A consumer (a worker of a replica) idle this long and holding no entry
/// belongs to a replica that is gone: a live worker touches the group at
/// least every [`IDLE_WAIT`].
const CONSUMER_RETIREMENT: Duration = Duration::from_secs(60);
/// How often readers poll a job's version (event streams, one-call
/// `/v1/smooth`): the latency a reader adds to a job's end, against one
/// small read per waiting reader per poll.
pub(super) const POLL: Duration = Duration::from_millis(20);

/// Settings of the Redis store.
#[derive(Debug, Clone)]
pub struct RedisSettings {
    /// `redis://HOST:PORT[/DB]`.
    pub url: String,
    /// How long a claimed job stays with its worker without a renewal.
    pub lease: Duration,
    /// Runs of one job before it fails with `job_attempts_exhausted`.
    pub max_attempts: u32,
    /// How long finished jobs are kept (for jobs failed at claim time).
    pub result_ttl: Duration,
}

/// The connection to the shared store and the scripts run on it.
pub struct RedisStore {
    client: redis::Client,
    config: redis::aio::ConnectionManagerConfig,
    /// Made at the first call that finds Redis up (a replica may start
    /// while Redis is away: it then answers `store_unavailable` until it
    /// is back), then reconnecting by itself.
    conn: tokio::sync::OnceCell<ConnectionManager>,
    settings: RedisSettings,
    /// Unique per process: consumers are `{replica}-{worker}`.
    replica: String,
    scripts: Scripts,
    /// The parsed uploads of the jobs this replica accepted and that are
    /// still queued: when one of its own workers claims such a job, it
    /// skips reading the upload again. Bounded by the queue capacity.
    accepted: Mutex<HashMap<Uuid, Input>>,
}

impl std::fmt::Debug for RedisStore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RedisStore")
            .field("settings", &self.settings)
            .field("replica", &self.replica)
            .finish_non_exhaustive()
    }
}

struct Scripts {
    position: Script,
    claim: Script,
    tick: Script,
    hand_back: Script,
    delete: Script,
    sweep: Script,
}

/// The fixed description of a job, stored once as JSON in `meta`.
#[derive(Debug, Serialize, Deserialize)]
struct Meta {
    request_id: String,
    format: String,
    vertices: usize,
    faces: usize,
    bytes: u64,
    output_format: String,
    params: Params,
    created_ms: u64,
    #[serde(default)]
    hook: Option<String>,
}

/// The answer to `store_unavailable`: what the client should do.
fn unavailable(e: &redis::RedisError) -> Problem {
    tracing::warn!(error = %e, "the job store (Redis) failed");
    metrics::counter!("meshsmooth_store_errors_total").increment(1);
    let detail = if e.code() == Some("OOM") {
        "the shared job store (Redis) is out of memory; nothing was changed, retry later"
    } else {
        "the shared job store (Redis) cannot be reached; nothing was changed, retry shortly"
    };
    Problem::new(Code::StoreUnavailable, detail).with_retry_after(1)
}

fn millis(t: SystemTime) -> u64 {
    t.duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_millis().min(u64::MAX as u128) as u64)
}

fn wall(ms: u64) -> SystemTime {
    UNIX_EPOCH + Duration::from_millis(ms)
}

/// The `Instant` that was `at` ago on the wall clock (clamped to now).
fn instant_of(at: SystemTime) -> Instant {
    let ago = SystemTime::now()
        .duration_since(at)
        .unwrap_or(Duration::ZERO);
    Instant::now().checked_sub(ago).unwrap_or_else(Instant::now)
}

fn hook_name(hook: Option<TestHook>) -> Option<String> {
    hook.map(|h| match h {
        TestHook::Panic => "panic".to_owned(),
        TestHook::Sleep(d) => format!("sleep={}", d.as_millis()),
    })
}

fn hook_of(name: Option<&str>) -> Option<TestHook> {
    match name? {
        "panic" => Some(TestHook::Panic),
        other => other
            .strip_prefix("sleep=")
            .and_then(|ms| ms.parse().ok())
            .map(|ms| TestHook::Sleep(Duration::from_millis(ms))),
    }
}

fn cancel_name(reason: CancelReason) -> &'static str {
    match reason {
        CancelReason::Client => "client",
        CancelReason::TimeLimit => "time_limit",
        CancelReason::Shutdown => "shutdown",
    }
}

fn cancel_of(name: &str) -> Option<CancelReason> {
    match name {
        "client" => Some(CancelReason::Client),
        "time_limit" => Some(CancelReason::TimeLimit),
        "shutdown" => Some(CancelReason::Shutdown),
        _ => None,
    }
}

fn job_key(id: &Uuid) -> String {
    format!("{PREFIX}job:{id}")
}

fn key(name: &str) -> String {
    format!("{PREFIX}{name}")
}

/// What [`RedisStore::submit`] did.
pub(super) enum Submitted {
    /// Stored and queued.
    Queued,
    /// The fleet-wide queue holds this many jobs, at capacity.
    Full(usize),
}

/// What [`RedisStore::delete`] did.
pub(super) enum DeleteOutcome {
    Missing,
    Cancelled,
    Cancelling,
    Forgotten,
}

/// What a claim found.
enum ClaimReply {
    /// Nothing to run; wait for entries after this stream id.
    Idle(String),
    /// An entry that needed no run (its job was deleted, cancelled or
    /// expired meanwhile, or it ran out of attempts).
    Skipped,
    Run(Arc<Job>),
}

/// What a lease renewal learnt.
pub(super) enum Tick {
    /// Still ours; a client asked to cancel when true.
    Held { cancel: bool },
    /// Another worker holds the job now (our lease lapsed).
    Lost,
    /// The outcome was filed: nothing more to renew.
    Done,
}

impl RedisStore {
    /// The store at `settings.url`. Connects at once when Redis is up;
    /// when it is not, the replica starts anyway, unready, and connects
    /// when Redis comes up.
    pub async fn connect(settings: RedisSettings) -> anyhow::Result<RedisStore> {
        let client = redis::Client::open(settings.url.as_str())
            .map_err(|e| anyhow::anyhow!("invalid --store `{}`: {e}", settings.url))?;
        let config = redis::aio::ConnectionManagerConfig::new()
            .set_response_timeout(Some(RESPONSE_TIMEOUT))
            .set_connection_timeout(Some(CONNECT_TIMEOUT))
            .set_number_of_retries(1)
            .set_max_delay(Duration::from_millis(500));
        let store = RedisStore {
            client,
            config,
            conn: tokio::sync::OnceCell::new(),
            settings,
            replica: Uuid::new_v4().simple().to_string(),
            scripts: Scripts::new(),
            accepted: Mutex::new(HashMap::new()),
        };
        if let Err(e) = store.conn().await {
            tracing::warn!(url = %store.settings.url, error = %e, "the job store (Redis) cannot be reached yet; not ready until it can");
        }
        Ok(store)
    }

    /// The shared connection, made (and the queue prepared) on first use.
    async fn conn(&self) -> redis::RedisResult<ConnectionManager> {
        self.conn
            .get_or_try_init(|| async {
                let mut conn =
                    ConnectionManager::new_with_config(self.client.clone(), self.config.clone())
                        .await?;
                ensure_group(&mut conn).await?;
                Ok(conn)
            })
            .await
            .cloned()
    }

    /// [`Self::conn`] for the request paths.
    async fn request_conn(&self) -> Result<ConnectionManager, Problem> {
        self.conn().await.map_err(|e| unavailable(&e))
    }

    /// Runs a read-only command; once more when the connection had broken
    /// (Redis restarted: the first command finds the old connection gone,
    /// and the manager reconnects).
    async fn read<T: redis::FromRedisValue>(&self, cmd: &redis::Cmd) -> Result<T, Problem> {
        match cmd.query_async(&mut self.request_conn().await?).await {
            Ok(v) => Ok(v),
            Err(e) if e.is_connection_dropped() || e.is_io_error() => {
                tokio::time::sleep(Duration::from_millis(50)).await;
                cmd.query_async(&mut self.request_conn().await?)
                    .await
                    .map_err(|e| unavailable(&e))
            }
            Err(e) => Err(unavailable(&e)),
        }
    }

    fn consumer(&self, worker: usize) -> String {
        format!("{}-{worker}", self.replica)
    }

    /// Jobs waiting for a worker, fleet-wide.
    pub async fn queued(&self) -> Result<usize, Problem> {
        let n: Option<i64> = self.read(redis::cmd("GET").arg(key("queued"))).await?;
        Ok(n.unwrap_or(0).max(0) as usize)
    }

    /// Results held and their bytes, fleet-wide.
    pub async fn results(&self) -> Result<(usize, u64), Problem> {
        let (count, bytes): (usize, Option<i64>) = redis::pipe()
            .cmd("ZCARD")
            .arg(key("results"))
            .cmd("GET")
            .arg(key("result_bytes"))
            .query_async(&mut self.request_conn().await?)
            .await
            .map_err(|e| unavailable(&e))?;
        Ok((count, bytes.unwrap_or(0).max(0) as u64))
    }

    /// Stores `job` with its uploaded file and queues it, unless the
    /// fleet-wide queue holds `capacity` jobs. All or nothing. `document`
    /// is the file parsed, kept for this replica's own workers.
    pub(super) async fn submit(
        &self,
        job: &Job,
        input: &[u8],
        document: Input,
        capacity: usize,
    ) -> Result<Submitted, Problem> {
        let meta = Meta {
            request_id: job.request_id.clone(),
            format: job.input.format.name().to_owned(),
            vertices: job.input.vertices,
            faces: job.input.faces,
            bytes: job.input.bytes,
            output_format: job.output_format.name().to_owned(),
            params: job.params.clone(),
            created_ms: millis(job.created_at),
            hook: hook_name(job.hook),
        };
        let meta = serde_json::to_string(&meta)
            .map_err(|_| Problem::internal("the job could not be encoded"))?;
        // The upload goes in as a plain SET in the same transaction as the
        // script (a Lua argument would cost Redis another copy of it); the
        // script deletes it when it refuses the job.
        let k = job_key(&job.id);
        let (reply,): ((i64, i64),) = redis::pipe()
            .atomic()
            .cmd("SET")
            .arg(format!("{k}:input"))
            .arg(input)
            .ignore()
            .cmd("EVAL")
            .arg(SUBMIT)
            .arg(3)
            .arg(key("queue"))
            .arg(key("queued"))
            .arg(&k)
            .arg(capacity)
            .arg(meta)
            .arg(job.id.to_string())
            .query_async(&mut self.request_conn().await?)
            .await
            .map_err(|e| unavailable(&e))?;
        Ok(match reply {
            (1, _) => {
                lock(&self.accepted).insert(job.id, document);
                Submitted::Queued
            }
            (_, queued) => Submitted::Full(queued.max(0) as usize),
        })
    }

    /// The job with `id` as the store holds it now, unless unknown or
    /// expired.
    pub(super) async fn get(&self, id: &Uuid) -> Result<Option<Arc<Job>>, Problem> {
        let fields: HashMap<String, String> =
            self.read(redis::cmd("HGETALL").arg(job_key(id))).await?;
        let Some(mut job) = snapshot(*id, &fields) else {
            return Ok(None);
        };
        if let (JobState::Queued, Some(entry)) = (job.state(), fields.get("entry")) {
            let ahead: redis::RedisResult<usize> = self
                .scripts
                .position
                .key(key("queue"))
                .arg(GROUP)
                .arg(entry)
                .invoke_async(&mut self.request_conn().await?)
                .await;
            job.queue_position = ahead.ok();
        }
        Ok(Some(Arc::new(job)))
    }

    /// A number that changes with every change of the job's state or
    /// progress; None once the job is gone.
    pub(super) async fn version(&self, id: &Uuid) -> Result<Option<u64>, Problem> {
        self.read(redis::cmd("HGET").arg(job_key(id)).arg("version"))
            .await
    }

    /// The stored result of a succeeded job; None once evicted or expired.
    pub(super) async fn result(
        &self,
        id: &Uuid,
        format: Format,
    ) -> Result<Option<Arc<JobResult>>, Problem> {
        let k = job_key(id);
        let (mesh, report): (Option<Vec<u8>>, Option<Vec<u8>>) = self
            .read(
                redis::cmd("MGET")
                    .arg(format!("{k}:mesh"))
                    .arg(format!("{k}:report")),
            )
            .await?;
        Ok(match (mesh, report) {
            (Some(mesh), Some(report)) => Some(Arc::new(JobResult {
                mesh: mesh.into(),
                format,
                report: report.into(),
            })),
            _ => None,
        })
    }

    /// Cancels a queued job, flags a running one, or forgets a finished one.
    /// A finished job is left alone unless `forget`.
    pub(super) async fn delete(
        &self,
        id: &Uuid,
        ttl: Duration,
        forget: bool,
    ) -> Result<DeleteOutcome, Problem> {
        let reply: String = self
            .scripts
            .delete
            .key(job_key(id))
            .key(key("queued"))
            .key(key("results"))
            .key(key("result_sizes"))
            .key(key("result_bytes"))
            .arg(ttl.as_millis() as u64)
            .arg(millis(SystemTime::now()))
            .arg(id.to_string())
            .arg(if forget { "1" } else { "0" })
            .invoke_async(&mut self.request_conn().await?)
            .await
            .map_err(|e| unavailable(&e))?;
        Ok(match reply.as_str() {
            "cancelled" => DeleteOutcome::Cancelled,
            "cancelling" => DeleteOutcome::Cancelling,
            "forgotten" => DeleteOutcome::Forgotten,
            _ => DeleteOutcome::Missing,
        })
    }

    /// Drops the budget bookkeeping of results that expired, and the
    /// consumers of replicas gone long ago (idle, holding nothing). Returns
    /// how many results. Errors are left to the requests and the workers
    /// to report.
    pub async fn sweep(&self) -> redis::RedisResult<usize> {
        self.forget_claimed_elsewhere().await?;
        let gone = (self.settings.lease * 10).max(CONSUMER_RETIREMENT);
        self.scripts
            .sweep
            .key(key("results"))
            .key(key("result_sizes"))
            .key(key("result_bytes"))
            .key(key("queue"))
            .arg(PREFIX)
            .arg(GROUP)
            .arg(gone.as_millis() as u64)
            .invoke_async(&mut self.conn().await?)
            .await
    }

    /// Drops the parsed uploads of accepted jobs that are no longer queued
    /// (another replica claimed them, or they were cancelled).
    async fn forget_claimed_elsewhere(&self) -> redis::RedisResult<()> {
        let ids: Vec<Uuid> = lock(&self.accepted).keys().copied().collect();
        if ids.is_empty() {
            return Ok(());
        }
        let mut pipe = redis::pipe();
        for id in &ids {
            pipe.cmd("HGET").arg(job_key(id)).arg("state");
        }
        let states: Vec<Option<String>> = pipe.query_async(&mut self.conn().await?).await?;
        let mut accepted = lock(&self.accepted);
        for (id, state) in ids.iter().zip(states) {
            if state.as_deref() != Some("queued") {
                accepted.remove(id);
            }
        }
        Ok(())
    }

    /// A connection of its own for worker `worker`'s blocking waits.
    async fn waiting_connection(&self) -> redis::RedisResult<redis::aio::MultiplexedConnection> {
        let config = AsyncConnectionConfig::new()
            .set_response_timeout(Some(IDLE_WAIT + RESPONSE_TIMEOUT))
            .set_connection_timeout(Some(CONNECT_TIMEOUT));
        self.client
            .get_multiplexed_async_connection_with_config(&config)
            .await
    }

    /// Blocks worker `worker` until it claims a job (a lapsed lease first,
    /// else the oldest waiting entry), or until `stop` says to stop.
    pub(super) async fn claim(&self, worker: usize, stop: &dyn Fn() -> bool) -> Option<Arc<Job>> {
        let consumer = self.consumer(worker);
        let mut waiting = None;
        let mut backoff = Duration::from_millis(100);
        while !stop() {
            match self.try_claim(&consumer).await {
                Ok(ClaimReply::Run(claimed)) => return Some(claimed),
                Ok(ClaimReply::Skipped) => continue,
                Ok(ClaimReply::Idle(last)) => {
                    backoff = Duration::from_millis(100);
                    if waiting.is_none() {
                        waiting = self.waiting_connection().await.ok();
                    }
                    let Some(conn) = waiting.as_mut() else {
                        tokio::time::sleep(IDLE_WAIT).await;
                        continue;
                    };
                    // Wakes when an entry newer than `last` arrives (read
                    // outside the group: the claim itself is the script's).
                    let woke: redis::RedisResult<Value> = redis::cmd("XREAD")
                        .arg("COUNT")
                        .arg(1)
                        .arg("BLOCK")
                        .arg(IDLE_WAIT.as_millis() as u64)
                        .arg("STREAMS")
                        .arg(key("queue"))
                        .arg(last)
                        .query_async(conn)
                        .await;
                    if woke.is_err() {
                        waiting = None;
                    }
                }
                Err(e) => {
                    if e.code() == Some("NOGROUP")
                        && let Ok(mut conn) = self.conn().await
                    {
                        let _ = ensure_group(&mut conn).await;
                    }
                    tracing::warn!(error = %e, "cannot claim a job from Redis; retrying");
                    metrics::counter!("meshsmooth_store_errors_total").increment(1);
                    tokio::time::sleep(backoff).await;
                    backoff = (backoff * 2).min(Duration::from_secs(2));
                }
            }
        }
        None
    }

    async fn try_claim(&self, consumer: &str) -> redis::RedisResult<ClaimReply> {
        let reply: Vec<Value> = self
            .scripts
            .claim
            .key(key("queue"))
            .key(key("queued"))
            .arg(GROUP)
            .arg(consumer)
            .arg(self.settings.lease.as_millis() as u64)
            .arg(self.settings.max_attempts)
            .arg(millis(SystemTime::now()))
            .arg(PREFIX)
            .invoke_async(&mut self.conn().await?)
            .await?;
        let text = |i: usize| -> String {
            match reply.get(i) {
                Some(v) => redis::from_redis_value::<String>(v.clone()).unwrap_or_default(),
                None => String::new(),
            }
        };
        match text(0).as_str() {
            "idle" => Ok(ClaimReply::Idle(text(1))),
            "run" => {
                let entry = text(1);
                let attempt: u32 = text(3).parse().unwrap_or(1);
                let reclaimed = text(4) == "1";
                let cancel = cancel_of(&text(6));
                let id = Uuid::parse_str(&text(2)).ok();
                let meta = serde_json::from_str::<Meta>(&text(5)).ok();
                let (Some(id), Some(meta)) = (id, meta) else {
                    // Unreadable: fail it rather than loop on it.
                    self.fail_unreadable(consumer, &entry, &text(2), attempt)
                        .await?;
                    return Ok(ClaimReply::Skipped);
                };
                if reclaimed {
                    metrics::counter!("meshsmooth_leases_reclaimed_total").increment(1);
                    tracing::warn!(job_id = %id, attempt, "reclaimed a job whose lease lapsed");
                }
                metrics::counter!("meshsmooth_job_attempts_total").increment(1);
                let claim = Claim {
                    entry,
                    attempt,
                    consumer: consumer.to_owned(),
                    lost: AtomicBool::new(false),
                };
                // The guard must not live across the read below.
                let accepted_here = lock(&self.accepted).remove(&id);
                let document = match accepted_here {
                    Some(document) => Ok(document),
                    None => self.read_input(&id, &meta).await,
                };
                match document {
                    Ok(document) => Ok(ClaimReply::Run(Arc::new(running_job(
                        id, meta, document, claim, cancel,
                    )))),
                    Err(problem) => {
                        let ttl = self.settings.result_ttl;
                        self.finish_raw(&claim, &id, &Outcome::Failed(problem), u64::MAX, ttl)
                            .await?;
                        Ok(ClaimReply::Skipped)
                    }
                }
            }
            "exhausted" => {
                tracing::error!(
                    job_id = %text(2),
                    max_attempts = self.settings.max_attempts,
                    "job failed: its worker stopped every time it ran"
                );
                metrics::counter!("meshsmooth_jobs_finished_total", "outcome" => "failed")
                    .increment(1);
                Ok(ClaimReply::Skipped)
            }
            _ => Ok(ClaimReply::Skipped),
        }
    }

    async fn fail_unreadable(
        &self,
        consumer: &str,
        entry: &str,
        id: &str,
        attempt: u32,
    ) -> redis::RedisResult<()> {
        tracing::error!(
            job_id = id,
            "a queued job could not be read back from Redis"
        );
        let Ok(uuid) = Uuid::parse_str(id) else {
            let _: Value = redis::pipe()
                .cmd("XACK")
                .arg(key("queue"))
                .arg(GROUP)
                .arg(entry)
                .cmd("XDEL")
                .arg(key("queue"))
                .arg(entry)
                .query_async(&mut self.conn().await?)
                .await?;
            return Ok(());
        };
        let problem = Problem::internal("the stored job could not be read back");
        let claim = Claim {
            entry: entry.to_owned(),
            attempt,
            consumer: consumer.to_owned(),
            lost: AtomicBool::new(false),
        };
        let ttl = self.settings.result_ttl;
        self.finish_raw(&claim, &uuid, &Outcome::Failed(problem), u64::MAX, ttl)
            .await
            .map(|_| ())
    }

    /// Reads the uploaded file of a claimed job with the options it was
    /// accepted with (it was read and checked then: no limits now).
    async fn read_input(&self, id: &Uuid, meta: &Meta) -> Result<Input, Problem> {
        let input: Option<Vec<u8>> = self
            .read(redis::cmd("GET").arg(format!("{}:input", job_key(id))))
            .await?;
        let input =
            input.ok_or_else(|| Problem::internal("the uploaded file of the job is missing"))?;
        let format = meta.format.parse().unwrap_or(Format::Obj);
        let unlimited = ReadLimits {
            max_vertices: usize::MAX,
            max_faces: usize::MAX,
        };
        Input::read(&input, format, &meta.params, unlimited).map_err(Problem::from)
    }

    /// Renews the lease of a running job and publishes its progress.
    pub(super) async fn tick(&self, job: &Job, claim: &Claim) -> redis::RedisResult<Tick> {
        let (stage, fraction) = match job.state() {
            JobState::Running {
                stage: Some(stage),
                fraction,
                ..
            } => (stage.name(), format!("{fraction:.3}")),
            _ => ("", String::new()),
        };
        let reply: (String, String) = self
            .scripts
            .tick
            .key(key("queue"))
            .key(job_key(&job.id))
            .arg(GROUP)
            .arg(&claim.consumer)
            .arg(&claim.entry)
            .arg(claim.attempt)
            .arg(stage)
            .arg(fraction)
            .invoke_async(&mut self.conn().await?)
            .await?;
        Ok(match reply.0.as_str() {
            "ok" => Tick::Held {
                cancel: !reply.1.is_empty(),
            },
            "done" => Tick::Done,
            _ => Tick::Lost,
        })
    }

    /// Files the outcome of a claimed job: state, result (evicting the
    /// oldest over `budget`), acknowledgement. Returns the results evicted,
    /// or None when the lease was lost (another worker owns the job).
    pub(super) async fn finish(
        &self,
        job: &Job,
        claim: &Claim,
        outcome: &Outcome,
        budget: u64,
        ttl: Duration,
    ) -> redis::RedisResult<Option<usize>> {
        self.finish_raw(claim, &job.id, outcome, budget, ttl).await
    }

    async fn finish_raw(
        &self,
        claim: &Claim,
        id: &Uuid,
        outcome: &Outcome,
        budget: u64,
        ttl: Duration,
    ) -> redis::RedisResult<Option<usize>> {
        let empty = Bytes::new();
        let (state, code, detail, field, reason, mesh, report) = match outcome {
            Outcome::Succeeded(held) => {
                let data = held.as_ref().and_then(|h| h.data.as_ref());
                (
                    "succeeded",
                    "",
                    String::new(),
                    String::new(),
                    "",
                    data.map_or(&empty, |d| &d.mesh),
                    data.map_or(&empty, |d| &d.report),
                )
            }
            Outcome::Failed(p) => (
                "failed",
                p.code.as_str(),
                p.detail.clone(),
                p.field.clone().unwrap_or_default(),
                "",
                &empty,
                &empty,
            ),
            Outcome::Cancelled(r) => (
                "cancelled",
                "",
                String::new(),
                String::new(),
                cancel_name(*r),
                &empty,
                &empty,
            ),
        };
        let k = job_key(id);
        let ttl_ms = ttl.as_millis().max(1) as u64;
        let mut pipe = redis::pipe();
        pipe.atomic();
        // The result goes in as plain SETs in the same transaction as the
        // script (as Lua arguments they would cost Redis another copy).
        if state == "succeeded" {
            for (part, bytes) in [("mesh", mesh), ("report", report)] {
                pipe.cmd("SET")
                    .arg(format!("{k}:{part}"))
                    .arg(bytes.as_ref())
                    .arg("PX")
                    .arg(ttl_ms)
                    .ignore();
            }
        }
        pipe.cmd("EVAL")
            .arg(FINISH)
            .arg(6)
            .arg(key("queue"))
            .arg(&k)
            .arg(key("results"))
            .arg(key("result_sizes"))
            .arg(key("result_bytes"))
            .arg(key("result_seq"))
            .arg(GROUP)
            .arg(&claim.consumer)
            .arg(&claim.entry)
            .arg(claim.attempt)
            .arg(millis(SystemTime::now()))
            .arg(ttl_ms)
            .arg(state)
            .arg(code)
            .arg(detail)
            .arg(field)
            .arg(reason)
            .arg(mesh.len())
            .arg(report.len())
            .arg(budget)
            .arg(PREFIX)
            .arg(id.to_string());
        let (reply,): (i64,) = pipe.query_async(&mut self.conn().await?).await?;
        Ok((reply >= 0).then_some(reply as usize))
    }

    /// Puts a claimed job back at the end of the queue (its run was cut
    /// short by a shutdown; the attempt does not count). False when the
    /// lease was lost meanwhile.
    pub(super) async fn hand_back(&self, job: &Job, claim: &Claim) -> redis::RedisResult<bool> {
        let reply: i64 = self
            .scripts
            .hand_back
            .key(key("queue"))
            .key(key("queued"))
            .key(job_key(&job.id))
            .arg(GROUP)
            .arg(&claim.consumer)
            .arg(&claim.entry)
            .arg(claim.attempt)
            .arg(job.id.to_string())
            .invoke_async(&mut self.conn().await?)
            .await?;
        Ok(reply == 1)
    }
}

impl Meta {
    /// A queued job of this description, not yet started.
    fn into_job(self, id: Uuid) -> Job {
        let format = self.format.parse().unwrap_or(Format::Obj);
        let created_at = wall(self.created_ms);
        Job {
            id,
            input: InputInfo {
                format,
                vertices: self.vertices,
                faces: self.faces,
                bytes: self.bytes,
            },
            output_format: self.output_format.parse().unwrap_or(format),
            hook: hook_of(self.hook.as_deref()),
            params: self.params,
            request_id: self.request_id,
            created: instant_of(created_at),
            created_at,
            document: Mutex::new(None),
            cancel: AtomicBool::new(false),
            cancel_reason: Mutex::new(None),
            state: Mutex::new(JobState::Queued),
            changes: watch::Sender::new(0),
            attempts: AtomicU32::new(0),
            queue_position: None,
            claim: None,
        }
    }
}

/// Creates the stream and the consumer group unless they exist (also
/// after a Redis that lost its data came back).
async fn ensure_group(conn: &mut ConnectionManager) -> redis::RedisResult<()> {
    let created: redis::RedisResult<Value> = redis::cmd("XGROUP")
        .arg("CREATE")
        .arg(key("queue"))
        .arg(GROUP)
        .arg("0")
        .arg("MKSTREAM")
        .query_async(conn)
        .await;
    match created {
        Err(e) if e.code() == Some("BUSYGROUP") => Ok(()),
        other => other.map(|_| ()),
    }
}

/// The job a worker claimed, ready to run.
fn running_job(
    id: Uuid,
    meta: Meta,
    document: Input,
    claim: Claim,
    cancel: Option<CancelReason>,
) -> Job {
    let mut job = meta.into_job(id);
    job.document = Mutex::new(Some(document));
    job.attempts = AtomicU32::new(claim.attempt);
    job.claim = Some(claim);
    if let Some(reason) = cancel {
        job.request_cancel(reason);
    }
    job
}

/// A read-only view of a job from its stored fields.
fn snapshot(id: Uuid, f: &HashMap<String, String>) -> Option<Job> {
    let meta: Meta = serde_json::from_str(f.get("meta")?).ok()?;
    let num = |name: &str| f.get(name).and_then(|v| v.parse::<u64>().ok());
    let started = num("started_ms").map(|ms| {
        let at = wall(ms);
        (instant_of(at), at)
    });
    let finished = num("finished_ms").map(wall);
    let state = match f.get("state").map(String::as_str) {
        Some("running") => {
            let (started, started_at) = started.unwrap_or((Instant::now(), SystemTime::now()));
            JobState::Running {
                started,
                started_at,
                stage: f.get("stage").and_then(|s| Stage::named(s)),
                fraction: f
                    .get("fraction")
                    .and_then(|v| v.parse().ok())
                    .unwrap_or(0.0),
            }
        }
        Some(s @ ("succeeded" | "failed" | "cancelled")) => {
            let finished_at = finished.unwrap_or_else(SystemTime::now);
            let outcome = match s {
                "succeeded" => Outcome::Succeeded(
                    (f.get("result").map(String::as_str) == Some("1")).then(|| HeldResult {
                        mesh_bytes: num("mesh_bytes").unwrap_or(0),
                        report_bytes: num("report_bytes").unwrap_or(0),
                        data: None,
                    }),
                ),
                "failed" => {
                    let code = f.get("error_code").and_then(|c| Code::parse(c));
                    let mut p = Problem::new(
                        code.unwrap_or(Code::InternalError),
                        f.get("error_detail").cloned().unwrap_or_default(),
                    );
                    if let Some(field) = f.get("error_field").filter(|v| !v.is_empty()) {
                        p = p.with_field(field.clone());
                    }
                    Outcome::Failed(p)
                }
                _ => Outcome::Cancelled(
                    f.get("cancel_reason")
                        .and_then(|r| cancel_of(r))
                        .unwrap_or(CancelReason::Client),
                ),
            };
            JobState::Finished {
                started,
                finished: instant_of(finished_at),
                finished_at,
                outcome,
            }
        }
        _ => JobState::Queued,
    };
    let cancel = f.get("cancel").and_then(|r| cancel_of(r));
    let attempts = num("attempts").unwrap_or(0) as u32;
    let mut job = meta.into_job(id);
    job.cancel = AtomicBool::new(cancel.is_some());
    job.cancel_reason = Mutex::new(cancel);
    job.state = Mutex::new(state);
    job.attempts = AtomicU32::new(attempts);
    Some(job)
}

impl Scripts {
    fn new() -> Scripts {
        Scripts {
            position: Script::new(POSITION),
            claim: Script::new(CLAIM),
            tick: Script::new(TICK_SCRIPT),
            hand_back: Script::new(HAND_BACK),
            delete: Script::new(DELETE),
            sweep: Script::new(SWEEP),
        }
    }
}

/// KEYS: queue, queued, job. ARGV: capacity, meta, id. Runs in one
/// transaction after the SET of the job's input. Returns {1, queued} when
/// stored, {0, queued} (and the input deleted) when the queue is full.
const SUBMIT: &str = r"
local queued = tonumber(redis.call('GET', KEYS[2]) or '0')
if queued >= tonumber(ARGV[1]) then
  redis.call('DEL', KEYS[3] .. ':input')
  return {0, queued}
end
local entry = redis.call('XADD', KEYS[1], '*', 'job', ARGV[3])
redis.call('HSET', KEYS[3], 'meta', ARGV[2], 'state', 'queued', 'attempts', 0, 'version', 1,
  'entry', entry)
return {1, redis.call('INCR', KEYS[2])}
";

/// KEYS: queue. ARGV: group, entry. The number of entries not yet claimed
/// ahead of `entry` in the queue (entries of jobs cancelled while queued
/// count until a worker skips them).
const POSITION: &str = r"
local last = '0-0'
for _, g in ipairs(redis.call('XINFO', 'GROUPS', KEYS[1])) do
  local fields = {}
  for i = 1, #g, 2 do fields[g[i]] = g[i + 1] end
  if fields['name'] == ARGV[1] then last = fields['last-delivered-id'] end
end
return #redis.call('XRANGE', KEYS[1], '(' .. last, '(' .. ARGV[2])
";

/// KEYS: queue, queued. ARGV: group, consumer, lease_ms, max_attempts,
/// now, prefix. A lapsed lease first (XAUTOCLAIM), else the next new entry
/// (XREADGROUP). Returns {'idle', last_id}, {'skip'}, {'exhausted', entry,
/// id} or {'run', entry, id, attempt, reclaimed, meta, cancel}.
const CLAIM: &str = r"
local q, group, consumer = KEYS[1], ARGV[1], ARGV[2]
local reclaimed = '1'
local entries = redis.call('XAUTOCLAIM', q, group, consumer, ARGV[3], '0-0', 'COUNT', 1)[2]
if #entries == 0 then
  reclaimed = '0'
  local new = redis.call('XREADGROUP', 'GROUP', group, consumer, 'COUNT', 1, 'STREAMS', q, '>')
  if new then entries = new[1][2] else entries = {} end
end
if #entries == 0 then
  local last = redis.call('XREVRANGE', q, '+', '-', 'COUNT', 1)
  if #last == 0 then return {'idle', '0-0'} end
  return {'idle', last[1][1]}
end
local entry = entries[1][1]
local id = entries[1][2][2]
local key = ARGV[6] .. 'job:' .. id
local state = redis.call('HGET', key, 'state')
if state ~= 'queued' and state ~= 'running' then
  redis.call('XACK', q, group, entry)
  redis.call('XDEL', q, entry)
  return {'skip'}
end
if state == 'queued' then redis.call('DECR', KEYS[2]) end
local attempt = redis.call('HINCRBY', key, 'attempts', 1)
if attempt > tonumber(ARGV[4]) then
  redis.call('HSET', key, 'state', 'failed', 'finished_ms', ARGV[5],
    'error_code', 'job_attempts_exhausted',
    'error_detail', 'the job was started ' .. ARGV[4] .. ' times and each time its worker ' ..
      'stopped before it finished (crash, kill or lost lease); it is not retried again')
  redis.call('HDEL', key, 'owner', 'entry', 'stage', 'fraction', 'cancel')
  redis.call('HINCRBY', key, 'attempts', -1)
  redis.call('HINCRBY', key, 'version', 1)
  redis.call('DEL', key .. ':input')
  redis.call('XACK', q, group, entry)
  redis.call('XDEL', q, entry)
  return {'exhausted', entry, id}
end
redis.call('HSET', key, 'state', 'running', 'owner', consumer, 'entry', entry, 'started_ms', ARGV[5])
redis.call('HDEL', key, 'stage', 'fraction')
redis.call('HINCRBY', key, 'version', 1)
local meta = redis.call('HGET', key, 'meta')
local cancel = redis.call('HGET', key, 'cancel') or ''
return {'run', entry, id, tostring(attempt), reclaimed, meta, cancel}
";

/// KEYS: queue, job. ARGV: group, consumer, entry, attempt, stage,
/// fraction. Renews the lease, publishes progress. Returns {'ok', cancel},
/// {'done', ''} once the job was filed (or handed back), or {'lost', ''}
/// when another worker holds it.
const TICK_SCRIPT: &str = r"
local owner = redis.call('HGET', KEYS[2], 'owner')
if owner ~= ARGV[2] or redis.call('HGET', KEYS[2], 'attempts') ~= ARGV[4] then
  if owner then return {'lost', ''} end
  return {'done', ''}
end
redis.call('XCLAIM', KEYS[1], ARGV[1], ARGV[2], 0, ARGV[3], 'JUSTID')
if ARGV[5] ~= '' then
  local now = redis.call('HMGET', KEYS[2], 'stage', 'fraction')
  if now[1] ~= ARGV[5] or now[2] ~= ARGV[6] then
    redis.call('HSET', KEYS[2], 'stage', ARGV[5], 'fraction', ARGV[6])
    redis.call('HINCRBY', KEYS[2], 'version', 1)
  end
end
return {'ok', redis.call('HGET', KEYS[2], 'cancel') or ''}
";

/// KEYS: queue, job, results, result_sizes, result_bytes, result_seq.
/// ARGV: group, consumer, entry, attempt, now, ttl_ms, state, error_code,
/// error_detail, error_field, cancel_reason, mesh bytes, report bytes,
/// budget, prefix, id. Runs in one transaction after the SETs of a
/// success's mesh and report. Returns the number of results evicted, or -1
/// if the lease was lost (the result just written is then dropped, unless
/// the job's new owner already succeeded: the same input gives the same
/// bytes).
const FINISH: &str = r"
local key = KEYS[2]
if redis.call('HGET', key, 'owner') ~= ARGV[2] or
   redis.call('HGET', key, 'attempts') ~= ARGV[4] then
  if redis.call('HGET', key, 'state') ~= 'succeeded' then
    redis.call('DEL', key .. ':mesh', key .. ':report')
  end
  return -1
end
redis.call('XACK', KEYS[1], ARGV[1], ARGV[3])
redis.call('XDEL', KEYS[1], ARGV[3])
redis.call('DEL', key .. ':input')
redis.call('HDEL', key, 'owner', 'entry', 'cancel', 'stage', 'fraction')
redis.call('HSET', key, 'state', ARGV[7], 'finished_ms', ARGV[5])
local evicted = 0
if ARGV[7] == 'failed' then
  redis.call('HSET', key, 'error_code', ARGV[8], 'error_detail', ARGV[9], 'error_field', ARGV[10])
elseif ARGV[7] == 'cancelled' then
  redis.call('HSET', key, 'cancel_reason', ARGV[11])
elseif ARGV[7] == 'succeeded' then
  redis.call('HSET', key, 'mesh_bytes', ARGV[12], 'report_bytes', ARGV[13], 'result', 1)
  local bytes = tonumber(ARGV[12]) + tonumber(ARGV[13])
  redis.call('ZADD', KEYS[3], redis.call('INCR', KEYS[6]), ARGV[16])
  redis.call('HSET', KEYS[4], ARGV[16], bytes)
  local total = redis.call('INCRBY', KEYS[5], bytes)
  local budget = tonumber(ARGV[14])
  while total > budget and redis.call('ZCARD', KEYS[3]) > 1 do
    local old = redis.call('ZPOPMIN', KEYS[3])[1]
    local size = tonumber(redis.call('HGET', KEYS[4], old) or '0')
    redis.call('HDEL', KEYS[4], old)
    total = redis.call('DECRBY', KEYS[5], size)
    local okey = ARGV[15] .. 'job:' .. old
    redis.call('DEL', okey .. ':mesh', okey .. ':report')
    if redis.call('EXISTS', okey) == 1 then
      redis.call('HSET', okey, 'result', 0)
      redis.call('HINCRBY', okey, 'version', 1)
    end
    evicted = evicted + 1
  end
end
redis.call('HINCRBY', key, 'version', 1)
redis.call('PEXPIRE', key, ARGV[6])
return evicted
";

/// KEYS: queue, queued, job. ARGV: group, consumer, entry, attempt, id.
/// Returns 1 when handed back, 0 when the lease was lost.
const HAND_BACK: &str = r"
local key = KEYS[3]
if redis.call('HGET', key, 'owner') ~= ARGV[2] or
   redis.call('HGET', key, 'attempts') ~= ARGV[4] then
  return 0
end
redis.call('XACK', KEYS[1], ARGV[1], ARGV[3])
redis.call('XDEL', KEYS[1], ARGV[3])
redis.call('HSET', key, 'state', 'queued')
redis.call('HDEL', key, 'owner', 'entry', 'started_ms', 'stage', 'fraction')
redis.call('HINCRBY', key, 'attempts', -1)
redis.call('HINCRBY', key, 'version', 1)
redis.call('HSET', key, 'entry', redis.call('XADD', KEYS[1], '*', 'job', ARGV[5]))
redis.call('INCR', KEYS[2])
return 1
";

/// KEYS: job, queued, results, result_sizes, result_bytes. ARGV: ttl_ms,
/// now, id, forget. Returns 'missing', 'cancelled', 'cancelling',
/// 'forgotten' or 'finished' (a finished job kept: forget is '0').
const DELETE: &str = r"
local key = KEYS[1]
local state = redis.call('HGET', key, 'state')
if not state then return 'missing' end
if state == 'queued' then
  redis.call('HSET', key, 'state', 'cancelled', 'cancel_reason', 'client', 'finished_ms', ARGV[2])
  redis.call('HINCRBY', key, 'version', 1)
  redis.call('DECR', KEYS[2])
  redis.call('DEL', key .. ':input')
  redis.call('PEXPIRE', key, ARGV[1])
  return 'cancelled'
end
if state == 'running' then
  redis.call('HSET', key, 'cancel', 'client')
  redis.call('HINCRBY', key, 'version', 1)
  return 'cancelling'
end
if ARGV[4] ~= '1' then return 'finished' end
redis.call('DEL', key, key .. ':mesh', key .. ':report')
if redis.call('ZREM', KEYS[3], ARGV[3]) == 1 then
  local size = tonumber(redis.call('HGET', KEYS[4], ARGV[3]) or '0')
  redis.call('HDEL', KEYS[4], ARGV[3])
  redis.call('DECRBY', KEYS[5], size)
end
return 'forgotten'
";

/// KEYS: results, result_sizes, result_bytes, queue. ARGV: prefix, group,
/// consumer idle ms. Drops the bookkeeping of the oldest results whose job
/// expired (results expire in finishing order, so the first live one ends
/// the sweep), then the consumers idle that long with nothing pending.
const SWEEP: &str = r"
local consumers = redis.pcall('XINFO', 'CONSUMERS', KEYS[4], ARGV[2])
if type(consumers) == 'table' and not consumers.err then
  for _, c in ipairs(consumers) do
    local fields = {}
    for i = 1, #c, 2 do fields[c[i]] = c[i + 1] end
    if fields['pending'] == 0 and fields['idle'] > tonumber(ARGV[3]) then
      redis.call('XGROUP', 'DELCONSUMER', KEYS[4], ARGV[2], fields['name'])
    end
  end
end
local n = 0
while n < 1000 do
  local oldest = redis.call('ZRANGE', KEYS[1], 0, 0)
  if #oldest == 0 then break end
  local id = oldest[1]
  if redis.call('EXISTS', ARGV[1] .. 'job:' .. id .. ':mesh') == 1 then break end
  redis.call('ZREM', KEYS[1], id)
  local size = tonumber(redis.call('HGET', KEYS[2], id) or '0')
  redis.call('HDEL', KEYS[2], id)
  redis.call('DECRBY', KEYS[3], size)
  n = n + 1
end
return n
";
