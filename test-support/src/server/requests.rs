//! Requests made with a given token or from a given loopback address: the
//! quota, moderation, race and fair-use tests.

use super::{fake_onnx, manifest, TestServer};
use serde_json::Value;

/// A quick Aligning submission's form fields.
pub fn fields(method: &str, seed: u32) -> Vec<(String, String)> {
    vec![
        ("method".into(), method.into()),
        ("task".into(), "aligning".into()),
        ("training_seed".into(), seed.to_string()),
        ("protocol".into(), "quick".into()),
        ("manifest".into(), manifest("aligning")),
    ]
}

/// POSTs a submission form `f` (with a small ONNX file) with `token`.
pub async fn submit_as(
    app: &TestServer,
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

pub async fn get_json_as(app: &TestServer, token: &str, path: &str) -> (u16, Value) {
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
    app: &TestServer,
    admin: &str,
    method: reqwest::Method,
    path: &str,
    body: Option<Value>,
) -> (u16, Value) {
    let mut req = app.http.request(method, app.url(path)).bearer_auth(admin);
    req = match body {
        Some(b) => req.json(&b),
        // Admin actions must say they send JSON even without a body (the
        // server's guard against cross-site forms: http/api/admin.rs).
        None => req.header("content-type", "application/json"),
    };
    let r = req.send().await.unwrap();
    (r.status().as_u16(), r.json().await.unwrap())
}

/// `app` served again on a new 127.0.0.1 port with quotas `limits` (set
/// before any request).
pub async fn with_quotas(app: TestServer, limits: d3il_server::config::QuotaLimits) -> TestServer {
    app.reconfigured(|c| c.quotas = limits).await
}

/// A client whose connections come from `ip` (127.0.0.0/8).
pub fn client_from(ip: &str) -> reqwest::Client {
    reqwest::Client::builder()
        .local_address(Some(ip.parse().unwrap()))
        .build()
        .unwrap()
}

/// The status of a GET of `url` from `c`, with `X-Forwarded-For: xff` (if
/// given) and a bearer `token` (if given).
pub async fn status_of(
    c: &reqwest::Client,
    url: &str,
    xff: Option<&str>,
    token: Option<&str>,
) -> u16 {
    let mut rb = c.get(url);
    if let Some(x) = xff {
        rb = rb.header("x-forwarded-for", x);
    }
    if let Some(t) = token {
        rb = rb.bearer_auth(t);
    }
    rb.send().await.unwrap().status().as_u16()
}
