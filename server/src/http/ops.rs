//! What operators and their tools ask: `/healthz` (the
//! process serves: always 200), `/readyz` (200 when ready to take traffic,
//! else 503 with a JSON body naming what is not ready; see
//! [`crate::telemetry::readiness`]) and `/metrics` (Prometheus, OpenMetrics
//! text). On the public listener `/metrics` needs an admin token (it shows
//! queue depth and traffic); `--metrics-bind ADDR` serves all three without
//! credentials on a second listener meant for a private interface, which is
//! also how a worker host (`d3il workers`) is scraped. The request counter
//! [`count_requests`] wraps every route.

use crate::auth::Admin;
use crate::state::AppState;
use crate::telemetry::{labels_of, Telemetry};
use axum::extract::{MatchedPath, Request, State};
use axum::http::{header, Method, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use std::sync::Arc;

/// The content type of the OpenMetrics text exposition.
pub const OPENMETRICS: &str = "application/openmetrics-text; version=1.0.0; charset=utf-8";

/// The routes on the public listener.
pub fn router() -> Router<AppState> {
    Router::new()
        .route("/healthz", get(healthz))
        .route(
            "/readyz",
            get(
                |State(s): State<AppState>,
                 who: Option<axum::Extension<crate::auth::Verified>>| async move {
                    // The checks' detail (a database's error text, hosts)
                    // only for an admin here; the private
                    // listener shows it to its scraper.
                    let admin = who.is_some_and(|w| w.0 .0.is_admin);
                    readyz(&s.telemetry, admin).await
                },
            ),
        )
        .route(
            "/metrics",
            get(|State(s): State<AppState>, _: Admin| async move { metrics(&s.telemetry).await }),
        )
}

/// The routes of `--metrics-bind` (no credentials: a private address).
pub fn private_router(t: Arc<Telemetry>) -> Router {
    Router::new()
        .route("/healthz", get(healthz))
        .route(
            "/readyz",
            get(|State(t): State<Arc<Telemetry>>| async move { readyz(&t, true).await }),
        )
        .route(
            "/metrics",
            get(|State(t): State<Arc<Telemetry>>| async move { metrics(&t).await }),
        )
        .with_state(t)
}

/// Serves [`private_router`] on `listener` until the process ends.
pub fn spawn_private(listener: tokio::net::TcpListener, t: Arc<Telemetry>) {
    tokio::spawn(async move {
        if let Err(e) = axum::serve(listener, private_router(t)).await {
            tracing::error!("the metrics listener stopped: {e}");
        }
    });
}

async fn healthz() -> Response {
    (
        [(header::CACHE_CONTROL, "no-store")],
        "ok: the process is serving\n",
    )
        .into_response()
}

/// The readiness report; without `detail` each check says only whether it
/// is ok (and `not_ready` names the failing ones).
async fn readyz(t: &Telemetry, detail: bool) -> Response {
    let report = t.readiness().await;
    let status = if report.ready {
        StatusCode::OK
    } else {
        StatusCode::SERVICE_UNAVAILABLE
    };
    let mut body = serde_json::to_value(&report).unwrap_or_default();
    if !detail {
        for check in ["database", "canary", "workers"] {
            if let Some(c) = body.get_mut(check).and_then(|c| c.as_object_mut()) {
                c.insert(
                    "detail".into(),
                    "on the metrics listener (--metrics-bind) or with an admin token".into(),
                );
            }
        }
    }
    (status, [(header::CACHE_CONTROL, "no-store")], Json(body)).into_response()
}

async fn metrics(t: &Telemetry) -> Response {
    (
        [
            (header::CONTENT_TYPE, OPENMETRICS),
            (header::CACHE_CONTROL, "no-store"),
        ],
        t.scrape().await,
    )
        .into_response()
}

/// Counts every request by method, matched route template (never the raw
/// path: ids would make a series each) and status. Requests no route
/// matched count under `unmatched`.
pub async fn count_requests(State(t): State<Arc<Telemetry>>, req: Request, next: Next) -> Response {
    let route = req
        .extensions()
        .get::<MatchedPath>()
        .map_or_else(|| "unmatched".to_string(), |p| route_label(p.as_str()));
    let method = match *req.method() {
        Method::GET => "GET",
        Method::HEAD => "HEAD",
        Method::POST => "POST",
        Method::PUT => "PUT",
        Method::DELETE => "DELETE",
        Method::PATCH => "PATCH",
        Method::OPTIONS => "OPTIONS",
        _ => "other",
    };
    let resp = next.run(req).await;
    t.http_requests
        .get_or_create(&labels_of(&[
            ("method", method),
            ("route", route.as_str()),
            ("status", resp.status().as_str()),
        ]))
        .inc();
    resp
}

/// A route template as a label: `{param}` written `:param` (braces inside a
/// label value trip up simple exposition parsers), the catch-all of a nested
/// router's fallback as `*`.
pub fn route_label(template: &str) -> String {
    let mut out = String::with_capacity(template.len());
    let mut rest = template;
    while let Some(open) = rest.find('{') {
        out.push_str(&rest[..open]);
        let Some(close) = rest[open..].find('}') else {
            out.push_str(&rest[open..]);
            return out;
        };
        let name = &rest[open + 1..open + close];
        if name.starts_with('*') {
            out.push('*');
        } else {
            out.push(':');
            out.push_str(name);
        }
        rest = &rest[open + close + 1..];
    }
    out.push_str(rest);
    out
}

#[cfg(test)]
mod tests {
    #[test]
    fn route_labels_name_parameters_without_braces() {
        use super::route_label;
        assert_eq!(
            route_label("/api/v1/submissions/{id}/rollouts/{n}"),
            "/api/v1/submissions/:id/rollouts/:n"
        );
        assert_eq!(route_label("/api/v1/{*rest}"), "/api/v1/*");
        assert_eq!(route_label("/healthz"), "/healthz");
    }
}
