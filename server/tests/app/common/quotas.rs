//! Helpers of the quota, moderation and race tests: a submission's form
//! fields, and requests made with a given token.

use super::*;
use serde_json::Value;

pub fn fields(method: &str, seed: u32) -> Vec<(String, String)> {
    vec![
        ("method".into(), method.into()),
        ("task".into(), "aligning".into()),
        ("training_seed".into(), seed.to_string()),
        ("protocol".into(), "quick".into()),
        ("manifest".into(), manifest("aligning")),
    ]
}

pub async fn submit_as(
    app: &TestApp,
    token: &str,
    f: &[(String, String)],
) -> (u16, Value, Option<String>) {
    let mut form = reqwest::multipart::Form::new();
    for (k, v) in f {
        form = form.text(k.clone(), v.clone());
    }
    form = form.part(
        "onnx",
        reqwest::multipart::Part::bytes(fake_onnx()).file_name("p.onnx"),
    );
    let r = app
        .http
        .post(app.url("/api/v1/submissions"))
        .bearer_auth(token)
        .multipart(form)
        .send()
        .await
        .unwrap();
    answer_with_retry(r).await
}

/// An answer's status, JSON body and `Retry-After` header (a 429 names when).
pub async fn answer_with_retry(r: reqwest::Response) -> (u16, Value, Option<String>) {
    let status = r.status().as_u16();
    let retry = r
        .headers()
        .get("retry-after")
        .map(|v| v.to_str().unwrap().to_string());
    (status, r.json().await.unwrap(), retry)
}

pub async fn get_json_as(app: &TestApp, token: &str, path: &str) -> (u16, Value) {
    let r = app
        .http
        .get(app.url(path))
        .bearer_auth(token)
        .send()
        .await
        .unwrap();
    (r.status().as_u16(), r.json().await.unwrap())
}

pub async fn admin_post(
    app: &TestApp,
    admin: &str,
    method: reqwest::Method,
    path: &str,
    body: Option<Value>,
) -> (u16, Value) {
    let mut req = app.http.request(method, app.url(path)).bearer_auth(admin);
    req = match body {
        Some(b) => req.json(&b),
        // Admin actions say they send JSON even without a body (issue 52).
        None => req.header("content-type", "application/json"),
    };
    let r = req.send().await.unwrap();
    (r.status().as_u16(), r.json().await.unwrap())
}

/// `app` served again on a new 127.0.0.1 port with quotas `limits` (the
/// config is shared by the handlers: set before any request).
pub async fn with_quotas(app: TestApp, limits: d3il_server::config::QuotaLimits) -> TestApp {
    let mut cfg = (*app.state.cfg).clone();
    cfg.quotas = limits;
    let mut state = app.state.clone();
    state.cfg = std::sync::Arc::new(cfg);
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(d3il_server::app::serve_listener(listener, state.clone()));
    TestApp {
        addr,
        base: format!("http://{addr}"),
        state,
        ..app
    }
}
