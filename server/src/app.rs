//! The router and `serve`: opens the store, starts the worker pool, listens.

use crate::client_addr::ClientAddr;
pub use crate::config::{default_assets_dir, ServerConfig};
use crate::linger::LingeringBody;
use crate::queue::{start_pool, JobRunner, PoolConfig, QueueSignal};
use crate::ratelimit::RateLimiter;
use crate::sandbox_status::SandboxStatus;
pub use crate::state::AppState;
use crate::store::{Store, StoreError};
use crate::telemetry::Telemetry;
use axum::Router;
use std::net::SocketAddr;
use std::sync::Arc;

pub fn router(state: AppState) -> Router {
    Router::new()
        .merge(crate::http::router(state.cfg.max_upload_bytes))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            client_rate_limits,
        ))
        .layer(axum::middleware::from_fn(etag))
        .layer(axum::middleware::map_response(security_headers))
        // Outermost: every response is counted, 429s and 304s included.
        .layer(axum::middleware::from_fn_with_state(
            state.telemetry.clone(),
            crate::http::ops::count_requests,
        ))
        .with_state(state)
}

/// Results documents kept in memory (a paper-protocol one is a few hundred kB).
const FINISHED_CACHE_ENTRIES: usize = 256;

/// Largest body given an ETag (pages, plots and JSON are far smaller).
const ETAG_MAX_BODY: u64 = 8 << 20;

/// Validators for what anyone may read: a GET answered 200 with a
/// page, plot, CSV or JSON gets a weak `ETag` (a hash of its body) and
/// `Cache-Control: no-cache`, so a client revalidates and a request with the
/// matching `If-None-Match` is answered `304 Not Modified` without a body.
/// Requests with credentials and `/admin` are left alone.
async fn etag(
    req: axum::extract::Request,
    next: axum::middleware::Next,
) -> axum::response::Response {
    use axum::body::HttpBody as _;
    use axum::http::{header, HeaderValue, Method, StatusCode};
    use axum::response::IntoResponse;
    let cacheable = req.method() == Method::GET
        && !req.headers().contains_key(header::AUTHORIZATION)
        && !req.uri().path().starts_with("/admin");
    let if_none_match = req.headers().get(header::IF_NONE_MATCH).cloned();
    let resp = next.run(req).await;
    let small = resp
        .body()
        .size_hint()
        .exact()
        .is_some_and(|n| n <= ETAG_MAX_BODY);
    if !cacheable
        || resp.status() != StatusCode::OK
        || !small
        || resp.headers().contains_key(header::ETAG)
    {
        return resp;
    }
    let (mut parts, body) = resp.into_parts();
    let Ok(bytes) = axum::body::to_bytes(body, ETAG_MAX_BODY as usize).await else {
        return StatusCode::INTERNAL_SERVER_ERROR.into_response();
    };
    let tag = {
        use std::hash::{Hash, Hasher};
        let mut h = std::collections::hash_map::DefaultHasher::new();
        bytes.hash(&mut h);
        format!("W/\"{:016x}-{:x}\"", h.finish(), bytes.len())
    };
    let Ok(tag_value) = HeaderValue::from_str(&tag) else {
        return axum::response::Response::from_parts(parts, axum::body::Body::from(bytes));
    };
    if !parts.headers.contains_key(header::CACHE_CONTROL) {
        parts
            .headers
            .insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    }
    parts.headers.insert(header::ETAG, tag_value);
    let matches = if_none_match
        .as_ref()
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.split(',').any(|t| t.trim() == tag || t.trim() == "*"));
    if matches {
        parts.status = StatusCode::NOT_MODIFIED;
        parts.headers.remove(header::CONTENT_LENGTH);
        parts.headers.remove(header::CONTENT_TYPE);
        return axum::response::Response::from_parts(parts, axum::body::Body::empty());
    }
    axum::response::Response::from_parts(parts, axum::body::Body::from(bytes))
}

/// Content-Security-Policy of every response: the pages run no script, load
/// everything from this origin (plots are inline SVG) and may not be framed.
pub const CONTENT_SECURITY_POLICY: &str =
    "default-src 'self'; script-src 'none'; object-src 'none'; \
     style-src 'self' 'unsafe-inline'; img-src 'self' data:; base-uri 'none'; form-action 'self'; \
     frame-ancestors 'none'";

/// Security headers on every response, unless a handler set its own.
async fn security_headers(mut resp: axum::response::Response) -> axum::response::Response {
    use axum::http::{header, HeaderValue};
    let h = resp.headers_mut();
    for (name, value) in [
        (header::CONTENT_SECURITY_POLICY, CONTENT_SECURITY_POLICY),
        (header::X_CONTENT_TYPE_OPTIONS, "nosniff"),
        (header::X_FRAME_OPTIONS, "DENY"),
        (header::REFERRER_POLICY, "no-referrer"),
    ] {
        if !h.contains_key(&name) {
            h.insert(name, HeaderValue::from_static(value));
        }
    }
    resp
}

/// Per-address rate limits, keyed on the client address (behind
/// a trusted proxy, from X-Forwarded-For). Only a valid token lifts the
/// anonymous limit: a request with an `Authorization` header is
/// refused while its address is over the limit of failed token checks, and
/// its token is checked here: a valid one passes (the handler counts it
/// against the token's own limit, `auth::Verified`), any other is a 401
/// that counts as a failed check. A request without one counts against the
/// anonymous limit, unless it is a POST (forms carry their token in the
/// body), which is refused while over the failed-check limit and counts as
/// a failure when it ends in 401. API requests get the JSON error, pages the
/// HTML error page.
async fn client_rate_limits(
    axum::extract::State(state): axum::extract::State<AppState>,
    mut req: axum::extract::Request,
    next: axum::middleware::Next,
) -> axum::response::Response {
    use axum::http::{header, Method, StatusCode};
    use axum::response::IntoResponse;
    let Some(ip) = req
        .extensions()
        .get::<ClientAddr>()
        .map(|c| client_key(c.0))
    else {
        return next.run(req).await;
    };
    let api = req.uri().path().starts_with("/api/");
    let refuse = |e: crate::error::AppError| {
        if api {
            return e.into_response();
        }
        crate::error::PageError(e).into_response()
    };
    let limits = &state.client_limits;
    let has_token = req.headers().contains_key(header::AUTHORIZATION);
    let credentialed = has_token || req.method() == Method::POST;
    let over = if credentialed {
        limits
            .failed_auth
            .peek(ip)
            .map_err(|r| (r, crate::error::RATE_LIMIT_FAILED_AUTH))
    } else {
        limits
            .anonymous
            .check(ip)
            .map_err(|r| (r, crate::error::RATE_LIMIT_ANONYMOUS))
    };
    if let Err((retry_after, limit)) = over {
        return refuse(crate::error::AppError::RateLimited { retry_after, limit });
    }
    if has_token {
        match crate::auth::verify_header(&state, req.headers()).await {
            Ok(Some(who)) => {
                req.extensions_mut().insert(crate::auth::Verified(who));
            }
            Ok(None) => {}
            Err(e) => {
                if e.status() == StatusCode::UNAUTHORIZED {
                    limits.failed_auth.record(ip);
                }
                return refuse(e);
            }
        }
    }
    let resp = next.run(req).await;
    if credentialed && resp.status() == StatusCode::UNAUTHORIZED {
        limits.failed_auth.record(ip);
    }
    resp
}

/// The rate-limit key of a client address: IPv4 (also IPv4-mapped IPv6) as
/// is, other IPv6 addresses by their /64 (one host usually holds a whole /64).
pub fn client_key(ip: std::net::IpAddr) -> std::net::IpAddr {
    match ip {
        std::net::IpAddr::V6(v6) => match v6.to_ipv4_mapped() {
            Some(v4) => v4.into(),
            None => {
                let s = v6.segments();
                std::net::Ipv6Addr::new(s[0], s[1], s[2], s[3], 0, 0, 0, 0).into()
            }
        },
        v4 => v4,
    }
}

/// The production job runner: the sandboxed worker process.
pub fn default_runner(cfg: &ServerConfig) -> Arc<dyn JobRunner> {
    crate::runner::production_runner_with(&cfg.worker, &cfg.limits)
}

#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("cannot listen on {addr}: {source}; pass a free address with --bind")]
    Bind {
        addr: SocketAddr,
        source: std::io::Error,
    },
    #[error("server error: {0}")]
    Io(#[from] std::io::Error),
}

/// A running server (used by `d3il serve` and the tests).
pub struct Running {
    pub addr: SocketAddr,
    /// Where `--metrics-bind` serves `/metrics` (None: not asked for).
    pub metrics_addr: Option<SocketAddr>,
    pub state: AppState,
}

/// Opens the store, starts the worker pool and serves until the process ends.
/// `on_ready` is called with the bound address (port 0 resolves here).
pub async fn serve(
    cfg: ServerConfig,
    runner: Arc<dyn JobRunner>,
    on_ready: impl FnOnce(&Running),
) -> Result<(), ServeError> {
    let (listener, running) = prepare(cfg, runner).await?;
    on_ready(&running);
    serve_listener(listener, running.state).await;
    Ok(())
}

/// A worker host (`d3il workers`): the worker pool alone on a database shared
/// with front ends and other hosts (PostgreSQL). `on_ready` is called once the
/// pool runs; then this runs until the process ends.
pub async fn run_workers(
    cfg: ServerConfig,
    runner: Arc<dyn JobRunner>,
    on_ready: impl FnOnce(&Store, Option<SocketAddr>),
) -> Result<(), ServeError> {
    if !cfg.db.is_postgres() {
        return Err(ServeError::Store(StoreError::Config(format!(
            "d3il workers runs a worker pool on a database shared with `d3il serve`, which needs PostgreSQL \
             (--db postgres://…); the SQLite file {} belongs to the one `d3il serve` that opens it, \
             whose own --workers run its jobs",
            cfg.db
        ))));
    }
    let store = Store::connect(&cfg.db, cfg.policy_store.as_deref()).await?;
    let runner = crate::runner::SharedSlots::wrap(runner, cfg.workers + 1);
    let canary = Arc::new(crate::canary::Canary::new(cfg.canary.clone()));
    canary.start();
    let telemetry = Arc::new(crate::telemetry::Telemetry::new(
        store.clone(),
        canary.clone(),
        cfg.workers,
    ));
    if let crate::store::DbTarget::Postgres(url) = &cfg.db {
        crate::telemetry::presence::announce(
            url,
            format!("{}-{}", crate::queue::owner_host(), std::process::id()),
        )
        .map_err(StoreError::Db)?;
    }
    start_pool(
        store.clone(),
        runner,
        PoolConfig {
            workers: cfg.workers,
            lease_seconds: cfg.lease_seconds,
            assets_dir: cfg.assets_dir.clone(),
            limits: cfg.limits.clone(),
            canary: canary.clone(),
            metrics: telemetry.pool.clone(),
        },
        QueueSignal::default(),
    )
    .await?;
    let metrics_addr = bind_metrics(&cfg, &telemetry).await?;
    on_ready(&store, metrics_addr);
    std::future::pending::<()>().await;
    Ok(())
}

/// Accepts connections until the process ends, with the connection limits of
/// `state.cfg.connections`: a connection past the server's or its client's
/// cap (keyed as the rate limits: an IPv6 client by its /64; none for a
/// trusted proxy) is closed at once; one whose request header does not
/// arrive within the header-read timeout (also the keep-alive idle timeout)
/// is closed. A connection whose unread body is drained (`crate::linger`)
/// keeps its place under both caps until the drain ends.
pub async fn serve_listener(listener: tokio::net::TcpListener, state: AppState) {
    use hyper_util::rt::{TokioIo, TokioTimer};
    use std::collections::HashMap;
    use std::sync::Mutex;
    let limits = state.cfg.connections.clone();
    // An unread body is read on up to what the upload routes allow, while
    // the client keeps sending within the keep-alive idle timeout, and for
    // at most the linger deadline in all (a trickle cannot hold it).
    let cut = |limit| Telemetry::counter(&state.telemetry.rate_limit_refusals, &[("limit", limit)]);
    let linger = crate::linger::LingerLimits {
        cap: crate::http::upload_body_limit(state.cfg.max_upload_bytes) as u64,
        idle: limits.header_read_timeout,
        deadline: limits.linger_deadline,
        cut: cut("linger_deadline"),
    };
    let (over_total, over_client) = (cut("connections"), cut("client_connections"));
    let app = router(state);
    let total = Arc::new(tokio::sync::Semaphore::new(limits.max_connections));
    let per_client: Arc<Mutex<HashMap<std::net::IpAddr, usize>>> = Arc::default();
    loop {
        let (stream, peer) = match listener.accept().await {
            Ok(c) => c,
            Err(e) => {
                // Out of file descriptors and the like: wait, do not spin.
                tracing::warn!("accept failed: {e}");
                tokio::time::sleep(std::time::Duration::from_millis(50)).await;
                continue;
            }
        };
        let Ok(permit) = total.clone().try_acquire_owned() else {
            over_total.inc();
            drop(stream);
            continue;
        };
        // Keyed as the rate limits are (an IPv6 client by its /64).
        let ip = client_key(peer.ip());
        // A trusted proxy carries many clients: only the server's cap applies.
        let proxy = limits.trusted_proxies.contains(peer.ip());
        if !proxy {
            let mut m = per_client.lock().unwrap_or_else(|e| e.into_inner());
            let n = m.entry(ip).or_insert(0);
            if *n >= limits.max_connections_per_client {
                over_client.inc();
                drop(stream);
                continue;
            }
            *n += 1;
        }
        // Handlers and the per-address rate limits see the client address:
        // the peer's, or behind a trusted proxy X-Forwarded-For's
        // (crate::client_addr). A body left unread by an early answer is read
        // on (crate::linger), so the client gets the answer rather than a
        // reset connection.
        let trusted = limits.trusted_proxies.clone();
        let linger = linger.clone();
        let app = tower::ServiceExt::map_request(
            app.clone(),
            move |req: axum::http::Request<hyper::body::Incoming>| {
                let linger_limits = linger.clone();
                let linger = LingeringBody::may_linger(&req);
                let (mut parts, body) = req.into_parts();
                let client = trusted.client_addr(peer.ip(), &parts.headers);
                parts.extensions.insert(ClientAddr(client));
                let body = LingeringBody::new(body, linger, linger_limits);
                axum::http::Request::from_parts(parts, body)
            },
        );
        let per_client = per_client.clone();
        let timeout = limits.header_read_timeout;
        tokio::spawn(async move {
            let service = hyper_util::service::TowerToHyperService::new(app);
            let conn = hyper::server::conn::http1::Builder::new()
                .timer(TokioTimer::new())
                .header_read_timeout(timeout)
                .serve_connection(TokioIo::new(stream), service)
                .with_upgrades();
            if let Err(e) = conn.await {
                tracing::debug!("connection from {peer}: {e}");
            }
            if !proxy {
                let mut m = per_client.lock().unwrap_or_else(|e| e.into_inner());
                if let Some(n) = m.get_mut(&ip) {
                    *n -= 1;
                    if *n == 0 {
                        m.remove(&ip);
                    }
                }
            }
            drop(permit);
        });
    }
}

/// Everything `serve` does before accepting connections.
pub async fn prepare(
    cfg: ServerConfig,
    runner: Arc<dyn JobRunner>,
) -> Result<(tokio::net::TcpListener, Running), ServeError> {
    let store = Store::connect(&cfg.db, cfg.policy_store.as_deref()).await?;
    // Temporary uploads of a crashed run, files of failed submissions.
    store.clean_policy_files().await?;
    // The zoo's cells, like the paper's rows, on every start (idempotent).
    let zoo = match &cfg.zoo {
        Some(dir) => crate::zoo::load(&store, dir).await?,
        None => Default::default(),
    };
    // Results stored under earlier interval rules (the zoo's included),
    // recomputed from their rollout records.
    crate::upgrade::recompute_stored_intervals(&store).await?;
    // Pool jobs and dry-runs share the worker slots: the pool's `workers`
    // general slots plus its quick-protocol slot (`queue::start_pool`). The
    // race slot (`races`) runs one race at a time in a worker of its own, so
    // that a running race never delays the pool's jobs nor a dry run.
    let race_runner = runner.clone();
    let pool_slots = if cfg.workers > 0 { cfg.workers + 1 } else { 0 };
    let runner = crate::runner::SharedSlots::wrap(runner, pool_slots);
    let listener = tokio::net::TcpListener::bind(cfg.bind)
        .await
        .map_err(|source| ServeError::Bind {
            addr: cfg.bind,
            source,
        })?;
    let addr = listener.local_addr()?;
    let signal = QueueSignal::default();
    let canary = Arc::new(crate::canary::Canary::new(cfg.canary.clone()));
    canary.start();
    let telemetry = Arc::new(crate::telemetry::Telemetry::new(
        store.clone(),
        canary.clone(),
        cfg.workers,
    ));
    start_pool(
        store.clone(),
        runner.clone(),
        PoolConfig {
            workers: cfg.workers,
            lease_seconds: cfg.lease_seconds,
            assets_dir: cfg.assets_dir.clone(),
            limits: cfg.limits.clone(),
            canary: canary.clone(),
            metrics: telemetry.pool.clone(),
        },
        signal.clone(),
    )
    .await?;
    let metrics_addr = bind_metrics(&cfg, &telemetry).await?;
    let sandbox = Arc::new(SandboxStatus::new(runner.clone(), cfg.assets_dir.clone()));
    let mut videos =
        crate::videos::Videos::new(cfg.videos.clone(), store.data_dir(), &cfg.assets_dir)?;
    videos.counters = crate::videos::VideoCounters {
        rendered: Telemetry::counter(&telemetry.video_renders, &[("outcome", "ok")]),
        failed: Telemetry::counter(&telemetry.video_renders, &[("outcome", "failed")]),
        cache_hits: telemetry.video_cache_hits.clone(),
    };
    // Videos of a zoo cell's old result (loaded again with a new one).
    for id in zoo.replaced() {
        videos.forget(id);
    }
    let refusals = |limit| Telemetry::counter(&telemetry.rate_limit_refusals, &[("limit", limit)]);
    let mut limiter = RateLimiter::new(cfg.rate_limit_per_minute);
    limiter.refusals = refusals("token");
    let mut client_limits = crate::ratelimit::ClientLimits::new(
        cfg.anonymous_rate_limit_per_minute,
        cfg.failed_auth_per_minute,
    );
    client_limits.anonymous.refusals = refusals("anonymous");
    client_limits.failed_auth.refusals = refusals("failed_auth");
    let mut finished = crate::cache::FinishedCache::new(FINISHED_CACHE_ENTRIES);
    finished.hits = Telemetry::counter(&telemetry.results_cache, &[("outcome", "hit")]);
    finished.misses = Telemetry::counter(&telemetry.results_cache, &[("outcome", "miss")]);
    let fidelity = Arc::new(crate::fidelity::FidelityReports::new(
        cfg.fidelity.clone(),
        store.data_dir(),
    ));
    fidelity.start();
    let state = AppState {
        sandbox,
        store,
        limiter: Arc::new(limiter),
        client_limits: Arc::new(client_limits),
        uploads: Arc::new(tokio::sync::Semaphore::new(
            cfg.max_concurrent_uploads.max(1),
        )),
        cfg: Arc::new(cfg),
        signal,
        runner,
        finished: Arc::new(finished),
        videos: Arc::new(videos),
        fidelity,
        canary,
        telemetry,
    };
    // Races wait in the durable queue; the race slot runs them, and those a
    // stopped server left running race again from their first pair.
    crate::races::start_race_slot(state.clone(), race_runner).await?;
    Ok((
        listener,
        Running {
            addr,
            metrics_addr,
            state,
        },
    ))
}

/// Binds `--metrics-bind` (if given) and serves `/metrics`, `/healthz` and
/// `/readyz` there without credentials; the bound address.
async fn bind_metrics(
    cfg: &ServerConfig,
    telemetry: &Arc<Telemetry>,
) -> Result<Option<SocketAddr>, ServeError> {
    let Some(addr) = cfg.metrics_bind else {
        return Ok(None);
    };
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .map_err(|source| ServeError::Bind { addr, source })?;
    let bound = listener.local_addr()?;
    crate::http::ops::spawn_private(listener, telemetry.clone());
    Ok(Some(bound))
}

#[cfg(test)]
mod tests {
    use super::client_key;
    use std::net::IpAddr;

    fn ip(s: &str) -> IpAddr {
        s.parse().unwrap()
    }

    #[test]
    fn rate_limit_keys_group_an_ipv6_64_and_unmap_ipv4() {
        assert_eq!(client_key(ip("203.0.113.7")), ip("203.0.113.7"));
        assert_eq!(client_key(ip("::ffff:203.0.113.7")), ip("203.0.113.7"));
        assert_eq!(
            client_key(ip("2001:db8:1:2:aaaa:bbbb:cccc:dddd")),
            client_key(ip("2001:db8:1:2::1"))
        );
        assert_ne!(
            client_key(ip("2001:db8:1:2::1")),
            client_key(ip("2001:db8:1:3::1"))
        );
    }
}
