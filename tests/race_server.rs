//! Issue 41 on the server, end to end through the real binary: `POST
//! /api/v1/races` races two submissions' policies in a real sandboxed
//! `d3il worker` (MuJoCo, tract); `GET /api/v1/races/{id}` shows the
//! race so far and its report, which is the same, decision and counts, as
//! `d3il race --task` gives for the same pair (one rule, one
//! place: `d3il_evaluator::eval::race`); wrong requests are 400s naming the
//! field. `--workers 0`: the submissions stay queued (a race needs their
//! policies, not their results) and the race runs in the server's own slot.

use d3il_test_support::server::*;
use serde_json::{json, Value};
use std::path::PathBuf;
use std::process::Command;
use std::time::Duration;

/// The `d3il` binary under test (the server harness starts it, the tests run its other commands).
const D3IL: Binary = Binary(env!("CARGO_BIN_EXE_d3il"));
const EXE: &str = D3IL.0;

fn fixture(name: &str) -> PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("assets/fixtures")
        .join(name)
}

fn submit(client: &d3il_server::client::Client, stem: &str, task: &str, seed: u32) -> i64 {
    submit_file(client, &fixture(stem), task, seed, "quick")
}

/// Submits `<path>.onnx` with its manifest `<path>.json`.
fn submit_file(
    client: &d3il_server::client::Client,
    path: &std::path::Path,
    task: &str,
    seed: u32,
    protocol: &str,
) -> i64 {
    let stem = path.file_name().unwrap().to_string_lossy().into_owned();
    let manifest = std::fs::read_to_string(path.with_extension("json")).unwrap();
    let obs: Value = serde_json::from_str(&manifest).unwrap();
    let created = client
        .submit(
            &[
                ("method", format!("Race-{stem}")),
                ("task", task.to_string()),
                ("training_seed", seed.to_string()),
                ("protocol", protocol.to_string()),
                ("obs_type", obs["obs_type"].as_str().unwrap().to_string()),
                ("manifest", manifest),
            ],
            Some(&path.with_extension("onnx")),
        )
        .unwrap_or_else(|e| panic!("submit {stem}: {e}"));
    created["id"].as_i64().unwrap()
}

/// A trained policy (align_bc of tests/data/reference-closed-loop, which
/// succeeds on most Aligning test contexts in the original and here)
/// against the untrained MLP fixture (which never succeeds), raced on the
/// server under the paper protocol: it decides "A better" after a handful
/// of the 60 initial states, the page says so, and the CLI race of the same
/// two files decides at the same pair with the same counts.
#[test]
fn a_trained_policy_against_an_untrained_one_is_decided_early_on_the_server() {
    let dir = TempDir::new("race-server-early");
    let db = dir.path().join("lb.sqlite");
    let token = D3IL.create_token(&db, "racer");
    let server = D3IL.serve(&db, &["--workers", "0"]);
    let client = server.client(Some(&token));
    let trained = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/reference-closed-loop/align_bc");
    let untrained = fixture("aligning_mlp");
    let a = submit_file(&client, &trained, "aligning", 0, "paper");
    let b = submit_file(&client, &untrained, "aligning", 0, "paper");
    let started = client
        .race(&json!({"a": a, "b": b, "protocol": "paper"}))
        .expect("race accepted");
    let id = started["id"].as_i64().unwrap();
    let done = client
        .wait_race(id, Duration::from_secs(600), |_| {})
        .unwrap();
    assert_eq!(done["status"], "completed", "{done}");
    let report = &done["report"];
    assert_eq!(report["decision"], "A better", "{report}");
    assert_eq!(report["states_full"], 60, "{report}");
    let used = report["states_used"].as_u64().unwrap();
    assert!(used < 30, "decided early: {report}");
    assert!(
        report["rollouts_used"].as_u64() < report["rollouts_full"].as_u64(),
        "{report}"
    );
    assert_eq!(
        report["discordant"][1], 0,
        "the untrained fixture never succeeds"
    );

    let (status, page) = client.get_text(&format!("/races/{id}")).unwrap();
    assert_eq!(status, 200, "{page}");
    assert!(page.contains("Decision: <strong>A better"), "{page}");

    let cli = cli_race(
        &[],
        &trained.with_extension("onnx"),
        &untrained.with_extension("onnx"),
    );
    for k in [
        "decision",
        "decided_at",
        "e_value",
        "discordant",
        "states_used",
        "rollouts_used",
    ] {
        assert_eq!(report[k], cli[k], "{k}: server {report} vs CLI {cli}");
    }
}

/// The refusal of a race request: (status, field).
fn refused(client: &d3il_server::client::Client, body: Value) -> (u16, Option<String>, String) {
    match client.race(&body) {
        Err(d3il_server::client::ClientError::Api {
            status,
            field,
            message,
            ..
        }) => (status, field, message),
        other => panic!("{body} was not refused: {other:?}"),
    }
}

#[test]
fn a_race_on_the_server_reports_what_the_cli_race_reports_and_refuses_wrong_requests() {
    let dir = TempDir::new("race-server");
    let db = dir.path().join("lb.sqlite");
    let token = D3IL.create_token(&db, "racer");
    let server = D3IL.serve(&db, &["--workers", "0"]);
    let client = server.client(Some(&token));
    let a = submit(&client, "aligning_mlp", "aligning", 0);
    let b = submit(&client, "aligning_mlp_noise", "aligning", 1);

    let started = client
        .race(&json!({"a": a, "b": b, "protocol": "quick", "task": "aligning"}))
        .expect("race accepted");
    let id = started["id"].as_i64().unwrap();
    assert_eq!(
        (started["a"].as_i64(), started["b"].as_i64()),
        (Some(a), Some(b))
    );
    assert_eq!(started["alpha"], 0.05);
    let done = client
        .wait_race(id, Duration::from_secs(300), |_| {})
        .unwrap();
    assert_eq!(done["status"], "completed", "{done}");
    let report = &done["report"];
    let live = &done["live"];
    // The live state's paired counts add up to the pairs, and end where the
    // report ends.
    let counts: u64 = ["both", "only_a", "only_b", "neither"]
        .iter()
        .map(|k| live[k].as_u64().unwrap())
        .sum();
    assert_eq!(counts, live["pairs"].as_u64().unwrap(), "{live}");
    assert_eq!(live["pairs"], report["pairs_used"], "{done}");
    assert_eq!(live["only_a"], report["discordant"][0]);
    assert_eq!(live["only_b"], report["discordant"][1]);
    assert_eq!(live["e_value"], report["e_value"]);

    // The page shows the two policies, the paired counts, the evidence and
    // the outcome, and stops refreshing once finished.
    let (status, page) = client.get_text(&format!("/races/{id}")).unwrap();
    assert_eq!(status, 200, "{page}");
    for want in [
        format!("href=\"/submissions/{a}\""),
        format!("href=\"/submissions/{b}\""),
        format!(
            "<td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td>",
            live["pairs"], live["both"], live["only_a"], live["only_b"], live["neither"]
        ),
        format!("<span id=\"e-value\">{:.3}</span>", report["e_value"].as_f64().unwrap()),
        format!(
            "Rollouts used: {} of the {}",
            report["rollouts_used"], report["rollouts_full"]
        ),
        "Decision: <strong>none at the protocol".to_string(),
    ] {
        assert!(page.contains(&want), "{want} not in {page}");
    }
    assert!(
        !page.contains("http-equiv=\"refresh\""),
        "finished: no refresh"
    );

    // The same race with the CLI: the same decision and counts, bit for bit.
    let cli = cli_race(
        &["--protocol", "quick"],
        &fixture("aligning_mlp.onnx"),
        &fixture("aligning_mlp_noise.onnx"),
    );
    for k in [
        "task",
        "protocol",
        "seed",
        "alpha",
        "delta",
        "decision",
        "decided_at",
        "e_value",
        "p_value",
        "discordant",
        "difference_interval",
        "rate_a",
        "rate_b",
        "pairs_used",
        "pairs_full",
        "states_used",
        "states_full",
        "rollouts_used",
        "rollouts_full",
        "fixed_p_value",
        "fixed_pairs_for_power_90",
    ] {
        assert_eq!(report[k], cli[k], "{k}: server {report} vs CLI {cli}");
    }
    assert_eq!(report["states_full"], 3, "quick protocol: {report}");

    // `d3il submit --race A B --wait` (the CLI through the server): the same
    // report, printed as `d3il race --task` prints it.
    let out = Command::new(EXE)
        .args(["submit", "--server", &server.base, "--token", &token])
        .args([
            "--race",
            &a.to_string(),
            &b.to_string(),
            "--protocol",
            "quick",
            "--wait",
        ])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.starts_with("race "), "{text}");
    let e_line = format!(
        "e-value {:.3}, anytime-valid p-value {:.4}",
        cli["e_value"].as_f64().unwrap(),
        cli["p_value"].as_f64().unwrap()
    );
    assert!(text.contains(&e_line), "{e_line} in {text}");
    // The race page's fixed-size comparison of the pairs used, word for word.
    let fixed = d3il_metrics::rate_difference::fixed_size_comparison(
        cli["pairs_used"].as_u64().unwrap(),
        (
            cli["discordant"][0].as_u64().unwrap(),
            cli["discordant"][1].as_u64().unwrap(),
        ),
        cli["alpha"].as_f64().unwrap(),
    )
    .line();
    assert!(text.contains(&fixed), "{fixed} in {text}");

    // The /compare page's form starts the same race and leads to its page.
    // (The submissions are queued: the fixed-size comparison is a 400 that
    // says so, and the race form is offered, since a race needs none of
    // their results.)
    let (status, compare) = client.get_text(&format!("/compare?a={a}&b={b}")).unwrap();
    assert_eq!(status, 400, "{compare}");
    assert!(compare.contains("only finished submissions"), "{compare}");
    assert!(compare.contains("id=\"race-form\""), "{compare}");
    let form = format!("a={a}&b={b}&protocol=quick&token={token}");
    let (status, answer) = post_form(&server.base, "/races", &form);
    assert_eq!(status, 303, "{answer}");
    let location = answer
        .lines()
        .find_map(|l| l.strip_prefix("location: /races/"))
        .unwrap_or_else(|| panic!("no location in {answer}"));
    let by_form: i64 = location.trim().parse().unwrap();
    let done = client
        .wait_race(by_form, Duration::from_secs(300), |_| {})
        .unwrap();
    assert_eq!(done["report"]["e_value"], cli["e_value"], "{done}");
    let (status, answer) = post_form(&server.base, "/races", &format!("a=x&b={b}&token={token}"));
    assert_eq!(status, 400, "{answer}");
    assert!(answer.contains("`a` must be a submission id"), "{answer}");
    let (status, _) = post_form(&server.base, "/races", &format!("a={a}&b={b}&token=wrong"));
    assert_eq!(status, 401);

    // The document describes both routes.
    let doc = client.get("/api/v1/openapi.json").unwrap();
    assert!(doc["paths"]["/races"]["post"].is_object());
    assert!(doc["paths"]["/races/{id}"]["get"].is_object());
    assert!(doc["components"]["schemas"]["RaceLive"]["properties"]["only_a"].is_object());

    // Wrong requests: 400s naming the field.
    let avoiding = submit(&client, "avoiding_path", "avoiding", 0);
    let image = submit(&client, "aligning_image", "aligning", 2);
    for (body, field, says) in [
        (json!({"a": 999_999, "b": b}), "a", "no submission 999999"),
        (json!({"a": a, "b": 999_998}), "b", "no submission 999998"),
        (json!({"a": a, "b": a}), "b", "both submission"),
        (json!({"a": a, "b": avoiding}), "b", "same task"),
        (json!({"a": a, "b": image}), "b", "same task variant"),
        (
            json!({"a": a, "b": b, "task": "pushing"}),
            "task",
            "not pushing",
        ),
        (
            json!({"a": a, "b": b, "alpha": 1.5}),
            "alpha",
            "not in (0, 1)",
        ),
        (
            json!({"a": a, "b": b, "delta": 0.0}),
            "delta",
            "not in (0, 2)",
        ),
        (
            json!({"a": a, "b": b, "protocol": "huge"}),
            "protocol",
            "paper or quick",
        ),
    ] {
        let (status, f, message) = refused(&client, body.clone());
        assert_eq!(
            (status, f.as_deref()),
            (400, Some(field)),
            "{body}: {message}"
        );
        assert!(message.contains(says), "{body}: {message}");
    }
    // Without a token: 401.
    let anonymous = server.client(None);
    let (status, _, _) = refused(&anonymous, json!({"a": a, "b": b}));
    assert_eq!(status, 401);
    // `d3il submit --cancel ID`: the queued evaluation is cancelled.
    let out = Command::new(EXE)
        .args(["submit", "--server", &server.base, "--token", &token])
        .args(["--cancel", &avoiding.to_string()])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(client.submission(avoiding).unwrap()["status"], "failed");
    // An unknown race: 404.
    assert!(matches!(
        client.get_race(id + 100),
        Err(d3il_server::client::ClientError::Api { status: 404, .. })
    ));
}

/// POSTs a URL-encoded form to `base` + `path` over a plain socket (as a
/// browser's form does); the status and the whole answer, header names in
/// lower case.
fn post_form(base: &str, path: &str, body: &str) -> (u16, String) {
    use std::io::{Read, Write};
    let addr = base.trim_start_matches("http://").trim_end_matches('/');
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    write!(
        s,
        "POST {path} HTTP/1.1\r\nHost: {addr}\r\nContent-Type: application/x-www-form-urlencoded\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    )
    .unwrap();
    let mut answer = String::new();
    s.read_to_string(&mut answer).unwrap();
    let status = answer
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    let (head, rest) = answer.split_once("\r\n\r\n").unwrap_or((&answer, ""));
    (status, format!("{}\n\n{rest}", head.to_lowercase()))
}

/// `d3il race --task aligning EXTRA --json A B`: the CLI's
/// race report.
fn cli_race(extra: &[&str], a: &std::path::Path, b: &std::path::Path) -> Value {
    let out = Command::new(EXE)
        .args(["race", "--task", "aligning"])
        .args(extra)
        .arg("--json")
        .arg(a)
        .arg(b)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// Issue 52: races wait in the durable queue, one at a time in the race
/// slot, and a restart resumes what the queue says, nothing more. Three
/// paper-protocol races of two untrained policies (which run to the full
/// size): the first runs, the second waits, the third is cancelled by its
/// starter with `d3il submit --cancel-race`; the server is killed
/// (SIGKILL) and restarted: the first runs again from its first pair, the
/// second still waits, the third stays cancelled and never ran. An admin
/// then cancels the running one, whose worker stops, and the waiting one
/// runs next.
#[test]
fn races_wait_in_the_queue_are_cancelled_and_a_restart_resumes_what_the_queue_says() {
    let dir = TempDir::new("race-queue");
    let db = dir.path().join("lb.sqlite");
    let token = D3IL.create_token(&db, "racer");
    let admin = D3IL.create_admin_token(&db, "op");
    let server = D3IL.serve(&db, &["--workers", "0"]);
    let client = server.client(Some(&token));
    let a = submit(&client, "aligning_mlp", "aligning", 0);
    let b = submit(&client, "aligning_mlp_noise", "aligning", 1);
    let race = |c: &d3il_server::client::Client| {
        c.race(&json!({"a": a, "b": b, "protocol": "paper"}))
            .expect("race accepted")["id"]
            .as_i64()
            .unwrap()
    };
    let (first, second, third) = (race(&client), race(&client), race(&client));
    let status = |c: &d3il_server::client::Client, id: i64| c.get_race(id).unwrap();
    let running_with_pairs = |c: &d3il_server::client::Client| {
        wait_for(Duration::from_secs(300), || {
            let v = status(c, first);
            (v["status"] == "running" && v["live"]["pairs"].as_u64() > Some(0)).then_some(v)
        })
        .expect("the first race runs")
    };
    running_with_pairs(&client);
    assert_eq!(status(&client, second)["status"], "queued");
    // `d3il submit --cancel-race`: its starter cancels the third.
    let out = Command::new(EXE)
        .args(["submit", "--server", &server.base, "--token", &token])
        .args(["--cancel-race", &third.to_string()])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        String::from_utf8_lossy(&out.stdout)
            .contains(&format!("race {third} cancelled: status cancelled")),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );

    // SIGKILL and restart on the same database.
    server.kill();
    let server = D3IL.serve(&db, &["--workers", "0"]);
    let client = server.client(Some(&token));
    let again = running_with_pairs(&client);
    assert_eq!(again["status"], "running", "{again}");
    assert_eq!(status(&client, second)["status"], "queued");
    let cancelled = status(&client, third);
    assert_eq!(
        (
            cancelled["status"].as_str(),
            cancelled["cancelled_by"].as_str()
        ),
        (Some("cancelled"), Some("racer")),
        "{cancelled}"
    );
    assert!(cancelled["live"].is_null(), "it never ran: {cancelled}");

    // An admin cancels the running race (the page's button and the API
    // share the rule); the waiting one runs next.
    let op = server.client(Some(&admin));
    let v = op.cancel_race(first).expect("an admin cancels");
    assert_eq!(v["cancelled_by"], "op", "{v}");
    wait_for(Duration::from_secs(120), || {
        (status(&client, second)["status"] == "running").then_some(())
    })
    .expect("the waiting race runs once the slot is free");
    assert_eq!(status(&client, first)["status"], "cancelled");
    // Another submitter may not cancel it.
    let other = D3IL.create_token(&db, "someone-else");
    let err = server.client(Some(&other)).cancel_race(second).unwrap_err();
    assert!(
        matches!(
            err,
            d3il_server::client::ClientError::Api { status: 403, .. }
        ),
        "{err:?}"
    );
    op.cancel_race(second).unwrap();
}
