//! Health, readiness and metrics (issue 42 item 2), end to end: the real
//! `d3il serve` (and `d3il workers`) on 127.0.0.1 with real sandboxed
//! workers run a quick evaluation of the ONNX fixture, and `/metrics` is read
//! back with a Prometheus text-format parser (`prometheus-parse`), never
//! with string matching: the counters moved as they should. `/readyz`
//! follows the worker hosts and the database (a PostgreSQL cluster stopped
//! and started again). The sample Grafana dashboard and the alert rules of
//! docs/ops/ query only metrics that `/metrics` has.

use crate::{D3IL, EXE};
use d3il_test_support::server::*;
use prometheus_parse::{Sample, Scrape, Value};
use std::collections::BTreeSet;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Duration;

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("assets/fixtures")
        .join(name)
}

fn parse(text: &str) -> Scrape {
    Scrape::parse(text.lines().map(|l| Ok(l.to_string()))).expect("a Prometheus text exposition")
}

/// `GET path` on `base` with an optional bearer token.
fn get(base: &str, token: Option<&str>, path: &str) -> (u16, String) {
    d3il_server::client::Client::new(base, token.map(str::to_string))
        .expect("client")
        .get_text(path)
        .expect("GET")
}

fn scrape(base: &str, token: Option<&str>) -> Scrape {
    let (status, body) = get(base, token, "/metrics");
    assert_eq!(status, 200, "{body}");
    assert!(
        body.trim_end().ends_with("# EOF"),
        "OpenMetrics ends with # EOF"
    );
    parse(&body)
}

/// The samples named `name` whose labels include every pair of `labels`.
fn samples<'a>(s: &'a Scrape, name: &str, labels: &[(&str, &str)]) -> Vec<&'a Sample> {
    s.samples
        .iter()
        .filter(|x| x.metric == name && labels.iter().all(|(k, v)| x.labels.get(k) == Some(*v)))
        .collect()
}

/// The sum of the plain values (counter, gauge, untyped) of those samples.
fn value(s: &Scrape, name: &str, labels: &[(&str, &str)]) -> f64 {
    samples(s, name, labels)
        .iter()
        .map(|x| match &x.value {
            Value::Counter(v) | Value::Gauge(v) | Value::Untyped(v) => *v,
            other => panic!("{name} is not a plain value: {other:?}"),
        })
        .sum()
}

/// Every metric name a query may use: sample names, histogram series
/// (`_bucket`, `_sum`, `_count`) and every family `/metrics` declares (a
/// labelled family with no series yet shows only its HELP and TYPE).
fn names(s: &Scrape) -> BTreeSet<String> {
    let mut out: BTreeSet<String> = s.docs.keys().cloned().collect();
    for x in &s.samples {
        out.insert(x.metric.clone());
        if matches!(x.value, Value::Histogram(_)) {
            out.insert(format!("{}_bucket", x.metric));
        }
    }
    out
}

/// Whether `name` (as a query writes it) is a series of the scrape.
fn known(all: &BTreeSet<String>, name: &str) -> bool {
    all.contains(name)
        || ["_total", "_bucket", "_sum", "_count"]
            .iter()
            .any(|suf| name.strip_suffix(suf).is_some_and(|f| all.contains(f)))
}

/// The metric names (`d3il_…`) in a PromQL expression.
fn metric_names(expr: &str) -> Vec<String> {
    let mut out = vec![];
    let mut rest = expr;
    while let Some(i) = rest.find("d3il_") {
        let before_ok = i == 0
            || !rest[..i]
                .chars()
                .next_back()
                .is_some_and(|c| c.is_ascii_alphanumeric() || c == '_');
        let tail = &rest[i..];
        let end = tail
            .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
            .unwrap_or(tail.len());
        if before_ok {
            out.push(tail[..end].to_string());
        }
        rest = &tail[end..];
    }
    out
}

/// Every PromQL expression of the sample dashboard and the alert rules.
fn documented_queries() -> Vec<(String, String)> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("docs/ops");
    let dash: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("grafana-dashboard.json")).unwrap())
            .expect("the dashboard is JSON");
    let mut out = vec![];
    for panel in dash["panels"].as_array().expect("panels") {
        for t in panel["targets"].as_array().into_iter().flatten() {
            let expr = t["expr"].as_str().expect("a target's expr");
            out.push((format!("panel {}", panel["title"]), expr.to_string()));
        }
    }
    // The alert rules file: YAML, whose `expr:` values are one line each.
    let rules = std::fs::read_to_string(dir.join("alerts.yml")).unwrap();
    for line in rules.lines() {
        if let Some(expr) = line.trim().strip_prefix("expr:") {
            out.push(("alerts.yml".into(), expr.trim().to_string()));
        }
    }
    assert!(out.len() >= 8, "dashboard and alerts have queries: {out:?}");
    out
}

fn assert_documented_metrics_exist(s: &Scrape) {
    let all = names(s);
    for (place, expr) in documented_queries() {
        let used = metric_names(&expr);
        assert!(!used.is_empty(), "{place}: no d3il metric in `{expr}`");
        for name in used {
            assert!(
                known(&all, &name),
                "{place} queries {name}, which /metrics does not have: {expr}"
            );
        }
    }
}

fn submit(server: &TestServer, token: &str, seed: u32) -> i64 {
    let manifest = std::fs::read_to_string(fixture("aligning_mlp.json")).unwrap();
    let created = server
        .client(Some(token))
        .submit(
            &[
                ("method", "Metrics-MLP".to_string()),
                ("task", "aligning".to_string()),
                ("training_seed", seed.to_string()),
                ("protocol", "quick".to_string()),
                ("manifest", manifest),
            ],
            Some(&fixture("aligning_mlp.onnx")),
        )
        .expect("submission accepted");
    created["id"].as_i64().unwrap()
}

fn wait_done(server: &TestServer, token: &str, id: i64) {
    let done = server
        .client(Some(token))
        .wait(id, Duration::from_secs(600), |_| {})
        .expect("the evaluation finishes");
    assert_eq!(done["status"], "completed", "{done}");
}

fn readyz(base: &str) -> (u16, serde_json::Value) {
    let (status, body) = get(base, None, "/readyz");
    (
        status,
        serde_json::from_str(&body).unwrap_or_else(|e| panic!("/readyz is JSON ({e}): {body}")),
    )
}

fn wait_ready(base: &str, want: u16) -> serde_json::Value {
    let mut last = None;
    wait_for(Duration::from_secs(90), || {
        let (s, v) = readyz(base);
        let hit = (s == want).then(|| v.clone());
        last = Some((s, v));
        hit
    })
    .unwrap_or_else(|| panic!("/readyz of {base} never answered {want}; last: {last:?}"))
}

#[test]
fn metrics_count_a_quick_evaluation_on_sqlite() {
    let dir = TempDir::new("ops-metrics-sqlite");
    let db = dir.path().join("lb.sqlite");
    let token = D3IL.create_token(&db, "metrics-tester");
    let noisy = D3IL.create_token(&db, "noisy");
    let admin = D3IL.create_admin_token(&db, "operator");
    let server = D3IL.serve(
        &db,
        &["--workers", "1", "--no-upload-dry-run", "--rate-limit", "5"],
    );
    let base = server.base.clone();

    assert_eq!(get(&base, None, "/healthz").0, 200);
    let ready = wait_ready(&base, 200);
    assert_eq!(ready["ready"], true, "{ready}");
    assert_eq!(ready["not_ready"], serde_json::json!([]));
    // On the public listener /metrics is an operator's.
    assert_eq!(get(&base, None, "/metrics").0, 401);
    assert_eq!(get(&base, Some(&token), "/metrics").0, 403);
    let before = scrape(&base, Some(&admin));
    assert_eq!(value(&before, "d3il_jobs_finished_total", &[]), 0.0);
    assert_eq!(value(&before, "d3il_worker_slots_alive", &[]), 2.0);
    assert_eq!(value(&before, "d3il_ready", &[]), 1.0);

    let id = submit(&server, &token, 0);
    wait_done(&server, &token, id);
    // A finished submission twice (the second from the results cache), a
    // page, an unknown API path, and a token over its rate limit.
    for _ in 0..2 {
        let (s, _) = get(&base, None, &format!("/api/v1/submissions/{id}"));
        assert_eq!(s, 200);
    }
    assert_eq!(get(&base, None, "/api/v1/no-such-endpoint").0, 404);
    let codes: Vec<u16> = (0..6)
        .map(|_| get(&base, Some(&noisy), "/api/v1/whoami").0)
        .collect();
    assert_eq!(codes, [200, 200, 200, 200, 200, 429]);

    let after = scrape(&base, Some(&admin));
    let quick = [("task", "aligning"), ("protocol", "quick")];
    assert_eq!(value(&after, "d3il_jobs_started_total", &quick), 1.0);
    assert_eq!(value(&after, "d3il_jobs_finished_total", &quick), 1.0);
    assert_eq!(value(&after, "d3il_jobs_failed_total", &[]), 0.0);
    assert_eq!(
        value(&after, "d3il_evaluation_duration_seconds_count", &quick),
        1.0
    );
    assert!(value(&after, "d3il_evaluation_duration_seconds_sum", &quick) > 0.0);
    let hist = samples(&after, "d3il_evaluation_duration_seconds", &quick);
    let Value::Histogram(buckets) = &hist.first().expect("the duration histogram").value else {
        panic!("not a histogram: {hist:?}")
    };
    assert_eq!(buckets.last().map(|b| b.count), Some(1.0), "{buckets:?}");
    assert_eq!(
        value(&after, "d3il_upload_bytes_total", &[]),
        std::fs::metadata(fixture("aligning_mlp.onnx"))
            .unwrap()
            .len() as f64
    );
    assert_eq!(value(&after, "d3il_queue_jobs", &[("state", "done")]), 1.0);
    assert_eq!(
        value(&after, "d3il_queue_jobs", &[("state", "queued")]),
        0.0
    );
    // Requests by route template and status, never by raw path.
    let submitted = [
        ("method", "POST"),
        ("route", "/api/v1/submissions"),
        ("status", "201"),
    ];
    assert_eq!(value(&after, "d3il_http_requests_total", &submitted), 1.0);
    let polled = [
        ("method", "GET"),
        ("route", "/api/v1/submissions/:id"),
        ("status", "200"),
    ];
    assert!(value(&after, "d3il_http_requests_total", &polled) >= 3.0);
    assert_eq!(
        value(
            &after,
            "d3il_http_requests_total",
            &[("route", "/api/v1/whoami"), ("status", "429")]
        ),
        1.0
    );
    assert!(value(&after, "d3il_http_requests_total", &[("status", "404")]) >= 1.0);
    for x in samples(&after, "d3il_http_requests_total", &[]) {
        let route = x.labels.get("route").unwrap_or_default();
        assert!(
            route != format!("/api/v1/submissions/{id}") && !route.contains("no-such-endpoint"),
            "a raw path as a route label: {route}"
        );
    }
    assert_eq!(
        value(
            &after,
            "d3il_rate_limit_refusals_total",
            &[("limit", "token")]
        ),
        1.0
    );
    assert!(
        value(
            &after,
            "d3il_results_cache_lookups_total",
            &[("outcome", "hit")]
        ) >= 1.0
    );
    assert_eq!(value(&after, "d3il_database_up", &[]), 1.0);

    assert_documented_metrics_exist(&after);
}

/// A `d3il workers` host with its metrics listener.
struct Host {
    child: std::process::Child,
    metrics: String,
}

impl Drop for Host {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[test]
fn readyz_follows_worker_hosts_and_the_database_on_postgresql() {
    let dir = TempDir::new("ops-metrics-pg");
    let url = d3il_test_support::pg::fresh_database();
    let store = dir.path().join("policy-store");
    let db_args = [
        "--db",
        url.as_str(),
        "--policy-store",
        store.to_str().unwrap(),
    ];
    let token = D3IL.create_token_on("metrics-tester", &db_args);
    let front_metrics = format!("127.0.0.1:{}", d3il_test_support::free_port());
    let mut args = db_args[2..].to_vec();
    args.extend([
        "--workers",
        "0",
        "--no-upload-dry-run",
        "--metrics-bind",
        front_metrics.as_str(),
    ]);
    let front = D3IL.serve_on(url.as_ref(), &args);
    let private = format!("http://{front_metrics}");

    // A front end alone has nobody to run jobs.
    let (status, body) = readyz(&front.base);
    assert_eq!(status, 503, "{body}");
    assert_eq!(body["not_ready"], serde_json::json!(["workers"]), "{body}");
    assert_eq!(get(&private, None, "/healthz").0, 200);

    let host_port = d3il_test_support::free_port();
    let mut child = Command::new(EXE)
        .args(["workers", "--db", &url, "--policy-store"])
        .arg(&store)
        .args(["--workers", "1", "--no-verify", "--metrics-bind"])
        .arg(format!("127.0.0.1:{host_port}"))
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start d3il workers");
    wait_for_line(&mut child, "worker host ready", "d3il workers");
    let host = Host {
        child,
        metrics: format!("http://127.0.0.1:{host_port}"),
    };
    let ready = wait_ready(&front.base, 200);
    assert_eq!(ready["ready"], true, "{ready}");
    assert_eq!(wait_ready(&host.metrics, 200)["ready"], true);

    let id = submit(&front, &token, 0);
    wait_done(&front, &token, id);
    let quick = [("task", "aligning"), ("protocol", "quick")];
    let on_host = scrape(&host.metrics, None);
    assert_eq!(value(&on_host, "d3il_jobs_started_total", &quick), 1.0);
    assert_eq!(value(&on_host, "d3il_jobs_finished_total", &quick), 1.0);
    assert_eq!(
        value(&on_host, "d3il_evaluation_duration_seconds_count", &quick),
        1.0
    );
    let on_front = scrape(&private, None);
    assert_eq!(value(&on_front, "d3il_worker_hosts_alive", &[]), 1.0);
    assert_eq!(value(&on_front, "d3il_worker_slots_alive", &[]), 0.0);
    assert_eq!(
        value(&on_front, "d3il_queue_jobs", &[("state", "done")]),
        1.0
    );
    assert_eq!(
        value(&on_front, "d3il_upload_bytes_total", &[]),
        std::fs::metadata(fixture("aligning_mlp.onnx"))
            .unwrap()
            .len() as f64
    );
    assert_eq!(
        value(
            &on_front,
            "d3il_http_requests_total",
            &[("route", "/api/v1/submissions"), ("status", "201")]
        ),
        1.0
    );
    assert_documented_metrics_exist(&on_front);

    // The database goes away: not ready, naming it; the process still lives.
    let cluster = d3il_test_support::pg::cluster();
    cluster.kill();
    let down = wait_ready(&front.base, 503);
    assert!(
        down["not_ready"]
            .as_array()
            .unwrap()
            .contains(&serde_json::json!("database")),
        "{down}"
    );
    assert_eq!(get(&front.base, None, "/healthz").0, 200);
    assert_eq!(value(&scrape(&private, None), "d3il_database_up", &[]), 0.0);
    // And back: ready again once the database answers and the host has
    // reconnected.
    cluster.restart().expect("PostgreSQL starts again");
    let up = wait_ready(&front.base, 200);
    assert_eq!(up["ready"], true, "{up}");
    assert_eq!(value(&scrape(&private, None), "d3il_database_up", &[]), 1.0);
}

#[test]
fn promql_metric_names_are_found_whole() {
    assert_eq!(
        metric_names("sum(rate(d3il_jobs_failed_total{reason!=\"x\"}[5m])) / on() d3il_ready"),
        ["d3il_jobs_failed_total", "d3il_ready"]
    );
    assert!(metric_names("rate(xd3il_y[1m])").is_empty());
}
