//! Quotas and moderation (issue 42) over HTTP on 127.0.0.1, on SQLite and
//! PostgreSQL: submissions counted, the refusal with the time of the next
//! one, admission refusals not counted, admin tokens exempt, overrides;
//! a withdrawn submission hidden from the board JSON and page and from the
//! public lists (API and pages), with its reason on its page and listed on
//! `/admin`, a baseline marked, a revoked token refused, and every
//! admin action in the audit log on `/admin`. Issue 52: the quota counts
//! evaluations (a suite its levels, a race two), a race needs the racer's
//! own submission and is capped at `races` at once, and is cancelled by its
//! starter or an admin (audited), its running worker stopped.

use d3il_server::config::QuotaLimits;
use d3il_test_support::server::*;
use serde_json::{json, Value};

/// An app with quotas `limits` and no workers (submissions stay queued).
async fn app_with(b: Backend, limits: QuotaLimits, dry_run: bool) -> TestServer {
    let app = spawn_app_with(Options {
        backend: b,
        dry_run_uploads: dry_run,
        ..Options::default()
    })
    .await;
    with_quotas(app, limits).await
}

/// Whether submission `id` of `method` is listed by the public lists: the
/// API list (unfiltered and filtered by method), `/submissions`, the home
/// page's latest and the method's page.
async fn publicly_listed(app: &TestServer, id: i64, method: &str) -> [bool; 5] {
    let api = |v: Value| {
        v["submissions"]
            .as_array()
            .unwrap()
            .iter()
            .any(|s| s["id"] == id)
    };
    let link = format!("href=\"/submissions/{id}\"");
    let (s, all) = app.get_json("/api/v1/submissions").await;
    assert_eq!(s, 200, "{all}");
    let (_, of_method) = app
        .get_json(&format!("/api/v1/submissions?method={method}"))
        .await;
    let (s, list) = app.get_text("/submissions").await;
    assert_eq!(s, 200);
    let (_, home) = app.get_text("/").await;
    let (s, method_page) = app.get_text(&format!("/methods/{method}")).await;
    assert_eq!(s, 200, "the method keeps its page");
    [
        api(all),
        api(of_method),
        list.contains(&link),
        home.contains(&link),
        method_page.contains(&link),
    ]
}

async fn counted_refused_with_the_time_and_admin_exempt(b: Backend) {
    let app = app_with(
        b,
        QuotaLimits {
            per_day: 2,
            total: 10,
            concurrent: 5,
            races: 0,
        },
        false,
    )
    .await;
    let store = &app.state().store;
    let alice = store.create_token("alice").await.unwrap();
    let (s, who) = get_json_as(&app, &alice, "/api/v1/whoami").await;
    assert_eq!(s, 200, "{who}");
    assert_eq!(who["quota"]["remaining"], 2, "{who}");
    assert_eq!(who["quota"]["per_day"]["limit"], 2);

    // A bad request (no task) is refused at admission and not counted.
    let mut bad = fields("Q", 0);
    bad.retain(|(k, _)| k != "task");
    let (s, body, _) = submit_as(&app, &alice, &bad).await;
    assert_eq!(s, 400, "{body}");
    let (_, who) = get_json_as(&app, &alice, "/api/v1/whoami").await;
    assert_eq!(who["quota"]["per_day"]["used"], 0, "{who}");

    // Two accepted: each answer carries the quota left after it.
    let (s, first, _) = submit_as(&app, &alice, &fields("Q", 1)).await;
    assert_eq!(s, 201, "{first}");
    assert_eq!(first["quota"]["remaining"], 1, "{first}");
    assert_eq!(first["status"], "queued");
    assert!(first["quota"]["summary"]
        .as_str()
        .unwrap()
        .starts_with("1 of 2 evaluations left today"));
    let (s, second, _) = submit_as(&app, &alice, &fields("Q", 2)).await;
    assert_eq!(s, 201, "{second}");
    assert_eq!(second["quota"]["remaining"], 0);
    let next = second["quota"]["next_submission_at"].as_i64().unwrap();
    let first_at = first["created_at"].as_i64().unwrap();
    assert_eq!(next, first_at + 86_400, "the oldest leaves the 24 hours");

    // The third is refused: 429, when the next is possible, Retry-After.
    let (s, refused, retry) = submit_as(&app, &alice, &fields("Q", 3)).await;
    assert_eq!(s, 429, "{refused}");
    assert_eq!(refused["error"]["code"], "quota_exceeded");
    assert_eq!(refused["error"]["next_submission_at"], next);
    let msg = refused["error"]["message"].as_str().unwrap();
    assert!(msg.starts_with("daily evaluation quota reached: 2 evaluations in the last 24 hours (limit 2, --quota-per-day) and a plain evaluation counts 1; it is possible in "), "{msg}");
    let retry: i64 = retry.expect("Retry-After").parse().unwrap();
    assert!((86_390..=86_400).contains(&retry), "{retry}");
    let (_, who) = get_json_as(&app, &alice, "/api/v1/whoami").await;
    assert_eq!(
        who["quota"]["per_day"]["used"], 2,
        "the refusal is not counted"
    );

    // An admin token has no quota.
    let admin = store.create_token_with("op", true).await.unwrap();
    for seed in 10..13 {
        let (s, body, _) = submit_as(&app, &admin, &fields("OpQ", seed)).await;
        assert_eq!(s, 201, "{body}");
        assert_eq!(body["quota"]["exempt"], true);
    }

    // An override lifts alice's daily limit and sets her concurrency to 3.
    let (s, done) = admin_post(
        &app,
        &admin,
        reqwest::Method::PUT,
        "/api/v1/admin/submitters/alice/quota",
        Some(json!({"per_day": 0, "concurrent": 3})),
    )
    .await;
    assert_eq!(s, 200, "{done}");
    assert_eq!(done["audit"]["action"], "set_quota");
    assert_eq!(
        done["audit"]["detail"],
        "per day no limit, total default, at once 3"
    );
    let (s, third, _) = submit_as(&app, &alice, &fields("Q", 3)).await;
    assert_eq!(s, 201, "{third}");
    // Three queued now: the concurrency override refuses a fourth, saying when.
    let (s, busy, retry) = submit_as(&app, &alice, &fields("Q", 4)).await;
    assert_eq!(s, 429, "{busy}");
    assert!(busy["error"]["message"].as_str().unwrap().contains(
        "3 evaluations of yours are queued or running (limit 3 at once, --quota-concurrent) and a plain evaluation counts 1; it is possible when enough of them finish"
    ), "{busy}");
    assert_eq!(retry.as_deref(), Some("60"));
    // A bad override is refused with the field named.
    let (s, bad) = admin_post(
        &app,
        &admin,
        reqwest::Method::PUT,
        "/api/v1/admin/submitters/alice/quota",
        Some(json!({"total": -1})),
    )
    .await;
    assert_eq!(
        (s, bad["error"]["field"].as_str()),
        (400, Some("total")),
        "{bad}"
    );
}

async fn dry_run_refusals_are_not_counted(b: Backend) {
    // The worker is /bin/false: every upload's dry run fails.
    let app = app_with(
        b,
        QuotaLimits {
            per_day: 1,
            total: 1,
            concurrent: 1,
            races: 0,
        },
        true,
    )
    .await;
    let bob = app.state().store.create_token("bob").await.unwrap();
    for seed in 0..3 {
        let (s, body, _) = submit_as(&app, &bob, &fields("D", seed)).await;
        assert_eq!(s, 400, "the dry run refuses it: {body}");
        assert_ne!(body["error"]["code"], "quota_exceeded", "{body}");
    }
    let (_, who) = get_json_as(&app, &bob, "/api/v1/whoami").await;
    assert_eq!(who["quota"]["remaining"], 1, "{who}");
    assert_eq!(who["quota"]["total"]["used"], 0, "{who}");
}

async fn moderation_and_the_audit_log(b: Backend) {
    let app = app_with(b, QuotaLimits::NONE, false).await;
    let store = &app.state().store;
    let result = aligning_result(
        d3il_protocol::ProtocolKind::Paper,
        0.8,
        0.3,
        "aligning-v1.json",
    );
    let kept = finished_submission(store, "KeptMethod", &result).await;
    let gone = finished_submission(store, "GoneMethod", &result).await;
    let admin = store.create_token_with("moderator", true).await.unwrap();
    let user = store.create_token("carol").await.unwrap();
    let board = "/api/v1/leaderboards/aligning";
    let methods = |v: &Value| -> Vec<String> {
        v["rows"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| r["method"].as_str().unwrap().to_string())
            .collect()
    };
    let (_, before) = app.get_json(board).await;
    assert!(
        methods(&before).contains(&"GoneMethod".to_string()),
        "{before}"
    );

    // A submitter's token may not moderate.
    let (s, body) = admin_post(
        &app,
        &user,
        reqwest::Method::POST,
        &format!("/api/v1/admin/submissions/{gone}/withdraw"),
        Some(json!({"reason": "x"})),
    )
    .await;
    assert_eq!(s, 403, "{body}");
    // A reason is needed.
    let (s, body) = admin_post(
        &app,
        &admin,
        reqwest::Method::POST,
        &format!("/api/v1/admin/submissions/{gone}/withdraw"),
        Some(json!({"reason": "  "})),
    )
    .await;
    assert_eq!(
        (s, body["error"]["field"].as_str()),
        (400, Some("reason")),
        "{body}"
    );

    assert_eq!(publicly_listed(&app, gone, "GoneMethod").await, [true; 5]);
    let (_, page) = app.get_admin_text("/admin").await;
    assert!(
        page.contains("id=\"withdrawn-empty\""),
        "nothing withdrawn yet"
    );

    // Fetch the completed submission once so that its document is cached.
    let (s, doc) = app.get_json(&format!("/api/v1/submissions/{gone}")).await;
    assert_eq!((s, doc["withdrawn"].is_null()), (200, true), "{doc}");
    let reason = "trained on the test contexts <see #4>";
    let (s, done) = admin_post(
        &app,
        &admin,
        reqwest::Method::POST,
        &format!("/api/v1/admin/submissions/{gone}/withdraw"),
        Some(json!({ "reason": reason })),
    )
    .await;
    assert_eq!(s, 200, "{done}");
    assert_eq!(done["audit"]["actor"], "moderator");

    // Hidden from the board JSON and page; kept, with its reason, on its page.
    let (_, after) = app.get_json(board).await;
    assert!(
        !methods(&after).contains(&"GoneMethod".to_string()),
        "{after}"
    );
    assert!(
        methods(&after).contains(&"KeptMethod".to_string()),
        "{after}"
    );
    let (_, page) = app.get_text("/tasks/aligning").await;
    assert!(!page.contains("GoneMethod") && page.contains("KeptMethod"));
    let (s, page) = app.get_text(&format!("/submissions/{gone}")).await;
    assert_eq!(s, 200);
    let w = page
        .split("id=\"withdrawn\">")
        .nth(1)
        .and_then(|p| p.split("</section>").next())
        .expect("the withdrawal is shown");
    assert!(w.contains("Withdrawn by the operators (moderator, "), "{w}");
    assert!(
        w.contains("trained on the test contexts &#60;see #4&#62;"),
        "{w}"
    );
    let (_, doc) = app.get_json(&format!("/api/v1/submissions/{gone}")).await;
    assert_eq!(doc["withdrawn"]["reason"], reason, "{doc}");
    assert_eq!(doc["status"], "completed");
    // Left out of the public lists, API and pages alike; the other stays.
    assert_eq!(publicly_listed(&app, gone, "GoneMethod").await, [false; 5]);
    assert_eq!(publicly_listed(&app, kept, "KeptMethod").await, [true; 5]);
    // An operator finds it on /admin, with who, why and a link.
    let (_, page) = app.get_admin_text("/admin").await;
    let table = page
        .split("<table class=\"board\" id=\"withdrawn\">")
        .nth(1)
        .and_then(|t| t.split("</table>").next())
        .expect("the withdrawn table on /admin");
    let rows: Vec<&str> = table.split("<tr data-withdrawn=").skip(1).collect();
    assert_eq!(rows.len(), 1, "{table}");
    for part in [
        format!(
            "\"{gone}\"><td><a href=\"/submissions/{gone}\">#{gone}</a></td><td>GoneMethod</td>"
        ),
        "<td>moderator</td><td>trained on the test contexts &#60;see #4&#62;</td>".into(),
    ] {
        assert!(rows[0].contains(&part), "{part} in {}", rows[0]);
    }

    // A baseline is marked on the board, JSON and page.
    let (s, done) = admin_post(
        &app,
        &admin,
        reqwest::Method::POST,
        "/api/v1/admin/methods/KeptMethod/baseline",
        Some(json!({"baseline": true})),
    )
    .await;
    assert_eq!(s, 200, "{done}");
    let (_, after) = app.get_json(board).await;
    let row = after["rows"]
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["method"] == "KeptMethod")
        .unwrap();
    assert_eq!(row["baseline"], true, "{row}");
    assert!(after["rows"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| r["method"] != "KeptMethod")
        .all(|r| r["baseline"] == false));
    let (_, page) = app.get_text("/tasks/aligning").await;
    let cell = page
        .split("<td class=\"method\"><a href=\"/methods/KeptMethod\">KeptMethod</a>")
        .nth(1)
        .expect("the row");
    assert!(
        cell.starts_with(" <span class=\"badge badge-baseline\""),
        "{cell}"
    );
    let (s, body) = admin_post(
        &app,
        &admin,
        reqwest::Method::POST,
        "/api/v1/admin/methods/NoSuchMethod/baseline",
        Some(json!({"baseline": true})),
    )
    .await;
    assert_eq!(s, 404, "{body}");

    // Revoking a token through the API: it is refused from then on.
    let (s, _) = get_json_as(&app, &user, "/api/v1/whoami").await;
    assert_eq!(s, 200);
    let prefix = &user[..d3il_server::store::TOKEN_PREFIX_LEN];
    let (s, done) = admin_post(
        &app,
        &admin,
        reqwest::Method::POST,
        &format!("/api/v1/admin/tokens/{prefix}/revoke"),
        None,
    )
    .await;
    assert_eq!(s, 200, "{done}");
    assert_eq!(done["audit"]["detail"], format!("revoked {prefix}"));
    let (s, body) = get_json_as(&app, &user, "/api/v1/whoami").await;
    assert_eq!(s, 401, "{body}");

    // Every action is in the audit log, newest first, and on /admin.
    let (s, log) = get_json_as(&app, &admin, "/api/v1/admin/audit").await;
    assert_eq!(s, 200, "{log}");
    let actions: Vec<(&str, &str)> = log["entries"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| (e["action"].as_str().unwrap(), e["target"].as_str().unwrap()))
        .collect();
    let gone_target = format!("submission {gone}");
    let token_target = format!("token {prefix}");
    assert_eq!(
        actions,
        vec![
            ("revoke_token", token_target.as_str()),
            ("baseline", "method KeptMethod"),
            ("withdraw", gone_target.as_str()),
        ],
        "refused actions are not logged"
    );
    let (s, page) = app.get_admin_text("/admin").await;
    assert_eq!(s, 200);
    let table = page
        .split("<table class=\"board\" id=\"audit\">")
        .nth(1)
        .and_then(|t| t.split("</table>").next())
        .expect("the audit table");
    let rows: Vec<&str> = table.split("<tr data-audit=").skip(1).collect();
    assert_eq!(rows.len(), 3, "{table}");
    assert!(
        rows[0].contains("<td>moderator</td><td><code>revoke_token</code></td>"),
        "{}",
        rows[0]
    );
    assert!(
        rows[2].contains("<td><code>withdraw</code></td><td>submission"),
        "{}",
        rows[2]
    );
    assert!(
        rows[2].contains("trained on the test contexts &#60;see #4&#62;"),
        "{}",
        rows[2]
    );

    // Reinstated: back on the board.
    let (s, _) = admin_post(
        &app,
        &admin,
        reqwest::Method::POST,
        &format!("/api/v1/admin/submissions/{gone}/reinstate"),
        None,
    )
    .await;
    assert_eq!(s, 200);
    let (_, after) = app.get_json(board).await;
    assert!(
        methods(&after).contains(&"GoneMethod".to_string()),
        "{after}"
    );
    assert_eq!(publicly_listed(&app, gone, "GoneMethod").await, [true; 5]);
    let (_, page) = app.get_admin_text("/admin").await;
    assert!(page.contains("id=\"withdrawn-empty\""), "reinstated");
}

on_both_backends!(
    counted_refused_with_the_time_and_admin_exempt,
    dry_run_refusals_are_not_counted,
    moderation_and_the_audit_log,
);

/// Issue 52: a revoke prefix that names several live tokens revokes none
/// and names them; the whole token revokes its one.
#[tokio::test]
async fn an_ambiguous_revoke_prefix_is_refused_naming_the_matches() {
    use sqlx::{ConnectOptions, Executor};
    let app = spawn_app().await;
    let store = &app.state().store;
    let first = store.create_token("ann").await.unwrap();
    let second = store.create_token("bob").await.unwrap();
    let prefix = &first[..13];
    // Two live tokens sharing a prefix (13 characters: rare, possible).
    let mut db = sqlx::sqlite::SqliteConnectOptions::new()
        .filename(&app.db)
        .connect()
        .await
        .unwrap();
    db.execute(
        sqlx::query("UPDATE api_tokens SET prefix = $1 WHERE prefix = $2")
            .bind(prefix)
            .bind(&second[..13]),
    )
    .await
    .unwrap();
    let e = store
        .revoke_token(prefix, "op")
        .await
        .unwrap_err()
        .to_string();
    assert!(e.contains("names 2 live tokens"), "{e}");
    assert!(e.contains("ann's") && e.contains("bob's"), "{e}");
    assert!(e.contains("give the whole token"), "{e}");
    assert!(store.authenticate(&first).await.unwrap().is_some());
    assert!(store.authenticate(&second).await.unwrap().is_some());
    let done = store.revoke_token(&second, "op").await.unwrap();
    assert_eq!(done.prefixes.len(), 1);
    assert!(store.authenticate(&second).await.unwrap().is_none());
    assert!(store.authenticate(&first).await.unwrap().is_some());
}

/// Issue 52: an admin action without `Content-Type: application/json` (what
/// a cross-site form sends with a browser's Basic credentials) is refused,
/// and does nothing.
#[tokio::test]
async fn admin_actions_need_a_json_content_type() {
    let app = spawn_app().await;
    let store = &app.state().store;
    let admin = store.create_token_with("csrf-op", true).await.unwrap();
    let victim = store.create_token("victim").await.unwrap();
    let prefix = &victim[..13];
    let r = app
        .http
        .post(app.url(&format!("/api/v1/admin/tokens/{prefix}/revoke")))
        .bearer_auth(&admin)
        .header("content-type", "application/x-www-form-urlencoded")
        .body("x=1")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 400);
    let body: Value = r.json().await.unwrap();
    assert!(
        body["error"]["message"]
            .as_str()
            .unwrap()
            .contains("Content-Type: application/json"),
        "{body}"
    );
    assert!(
        store.authenticate(&victim).await.unwrap().is_some(),
        "not revoked"
    );
    let (s, done) = admin_post(
        &app,
        &admin,
        reqwest::Method::POST,
        &format!("/api/v1/admin/tokens/{prefix}/revoke"),
        None,
    )
    .await;
    assert_eq!(s, 200, "{done}");
    assert!(store.authenticate(&victim).await.unwrap().is_none());
}

/// Issue 52: a remote submission's endpoint URL is shown to its submitter
/// and admins only: the public API document (cached once completed) and
/// the page leave it out.
#[tokio::test]
async fn an_endpoint_url_is_shown_only_to_its_submitter_and_admins() {
    use d3il_server::store::{NewMethod, NewPolicy, NewSubmission};
    let app = spawn_app().await;
    let store = &app.state().store;
    let owner = store.create_token("endpoint-owner").await.unwrap();
    let other = store.create_token("someone").await.unwrap();
    let admin = store.create_token_with("endpoint-op", true).await.unwrap();
    let who = store.authenticate(&owner).await.unwrap().unwrap();
    let m = store
        .ensure_method(
            &NewMethod {
                name: "RemoteSecret".into(),
                ..Default::default()
            },
            Some(who.id),
        )
        .await
        .unwrap();
    let url = "wss://policy.example.org/secret-path";
    let id = store
        .create_submission_sharded(
            &NewSubmission {
                method_id: m.id,
                submitter_id: Some(who.id),
                task: d3il_protocol::TaskId::Aligning,
                obs_type: d3il_protocol::ObsType::State,
                training_seed: 0,
                data_fraction: 1.0,
                protocol: d3il_protocol::ProtocolKind::Quick,
                policy: NewPolicy::Remote {
                    url: url.into(),
                    secret: None,
                },
                manifest_json: "{}".into(),
                simulated_once: None,
            },
            3,
            1,
        )
        .await
        .unwrap();
    let path = format!("/api/v1/submissions/{id}");
    let (s, public) = app.get_json(&path).await;
    assert_eq!(s, 200);
    assert!(public["policy"]["endpoint_url"].is_null(), "{public}");
    let (_, v) = get_json_as(&app, &other, &path).await;
    assert!(v["policy"]["endpoint_url"].is_null(), "{v}");
    for token in [&owner, &admin] {
        let (_, v) = get_json_as(&app, token, &path).await;
        assert_eq!(v["policy"]["endpoint_url"], url, "{v}");
    }
    let (_, page) = app.get_text(&format!("/submissions/{id}")).await;
    assert!(!page.contains("secret-path"), "{page}");
    assert!(page.contains("Remote endpoint (its URL is shown to its submitter and admins"));
}

/// Issue 52: an admin cancelling another submitter's evaluation is in the
/// audit log, written with the cancel; a submitter cancelling its own is not
/// moderation.
#[tokio::test]
async fn an_admins_cancel_is_audited_with_the_cancel() {
    let app = spawn_app().await;
    let store = &app.state().store;
    let owner = store.create_token("canceller").await.unwrap();
    let admin = store.create_token_with("cancel-op", true).await.unwrap();
    let (s, a, _) = submit_as(&app, &owner, &fields("CancelA", 0)).await;
    assert_eq!(s, 201, "{a}");
    let (s, b, _) = submit_as(&app, &owner, &fields("CancelA", 1)).await;
    assert_eq!(s, 201, "{b}");
    let cancel = |token: String, id: i64| {
        let r = app
            .http
            .post(app.url(&format!("/api/v1/submissions/{id}/cancel")))
            .bearer_auth(token);
        async move { r.send().await.unwrap().status().as_u16() }
    };
    assert_eq!(cancel(owner.clone(), a["id"].as_i64().unwrap()).await, 200);
    assert_eq!(cancel(admin.clone(), b["id"].as_i64().unwrap()).await, 200);
    let log = store.audit_log(10).await.unwrap();
    let cancels: Vec<_> = log.iter().filter(|e| e.action == "cancel").collect();
    assert_eq!(cancels.len(), 1, "{log:?}");
    assert_eq!(cancels[0].actor, "cancel-op");
    assert_eq!(cancels[0].target, format!("submission {}", b["id"]));
}
