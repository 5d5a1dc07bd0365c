//! The HTTP layer against a real server on 127.0.0.1 (port 0) with a fresh
//! SQLite file: validation, auth, rate limits, pages, CSV, plots.

use d3il_test_support::server::*;
use serde_json::Value;

fn err(v: &Value) -> (&str, Option<&str>) {
    (
        v["error"]["code"].as_str().expect("error.code"),
        v["error"]["field"].as_str(),
    )
}

#[tokio::test]
async fn auth_is_required_and_errors_share_one_format() {
    let app = spawn_app().await;
    let r = app
        .http
        .post(app.url("/api/v1/submissions"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 401);
    assert_eq!(r.headers()["www-authenticate"], "Bearer realm=\"d3il\"");
    let v: Value = r.json().await.unwrap();
    assert_eq!(err(&v), ("unauthorized", None));
    assert!(v["error"]["message"]
        .as_str()
        .unwrap()
        .contains("d3il token create"));

    let r = app
        .http
        .get(app.url("/api/v1/whoami"))
        .bearer_auth("d3il_not-a-token")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 401);
    let r = app
        .http
        .get(app.url("/api/v1/whoami"))
        .bearer_auth(app.token())
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(r.json::<Value>().await.unwrap()["submitter"], "tester");
    let (s, v) = app.get_json("/api/v1/nothing-here").await;
    assert_eq!((s, err(&v)), (404, ("not_found", None)));
}

#[tokio::test]
async fn every_bad_field_is_named() {
    let app = spawn_app().await;
    let m = manifest("avoiding");
    let good: Vec<(&str, &str)> = vec![
        ("method", "MyPolicy"),
        ("task", "avoiding"),
        ("training_seed", "0"),
        ("manifest", &m),
    ];
    let with = |k: &str, v: &'static str| {
        let mut f: Vec<(&str, &str)> = good.iter().filter(|(kk, _)| *kk != k).cloned().collect();
        f.push((Box::leak(k.to_string().into_boxed_str()), v));
        f
    };
    let cases: Vec<(Vec<(&str, &str)>, &str)> = vec![
        (with("task", "juggling"), "task"),
        (with("data_fraction", "1.5"), "data_fraction"),
        (with("data_fraction", "0"), "data_fraction"),
        (with("data_fraction", "abc"), "data_fraction"),
        (with("training_seed", "-1"), "training_seed"),
        (with("training_seed", "x"), "training_seed"),
        (with("obs_type", "image"), "obs_type"),
        (with("obs_type", "lidar"), "obs_type"),
        (with("protocol", "fast"), "protocol"),
        (with("method", "<script>"), "method"),
        (with("history", "0"), "history"),
        // The protocol's manifest limits (PolicyManifest::validate), stated once.
        (with("history", "65"), "history"),
        (
            with("manifest", r#"{"task": "avoiding", "history": 65}"#),
            "manifest",
        ),
        (with("code_url", "javascript:alert(1)"), "code_url"),
        (with("manifest", "{not json"), "manifest"),
        (with("manifest", r#"{"task": "pushing"}"#), "manifest"),
        (
            with(
                "manifest",
                r#"{"task": "avoiding", "horizon": 2, "execute": 3}"#,
            ),
            "manifest",
        ),
        (with("endpoint_url", "ws://127.0.0.1:9/"), "endpoint_url"),
        (with("unexpected", "1"), "unexpected"),
    ];
    for (fields, field) in cases {
        let r = app.submit(&fields, Some(fake_onnx())).await;
        assert_eq!(r.status(), 400, "{field}: {fields:?}");
        let v: Value = r.json().await.unwrap();
        assert_eq!(err(&v), ("invalid_field", Some(field)), "{v}");
    }
    // No policy at all.
    let r = app.submit(&good, None).await;
    let v: Value = r.json().await.unwrap();
    assert_eq!(err(&v), ("invalid_field", Some("onnx")));
    // A private endpoint is refused before any dry-run.
    let r = app
        .submit(
            &[
                ("method", "Remote"),
                ("task", "avoiding"),
                ("training_seed", "0"),
                ("endpoint_url", "ws://10.0.0.1/"),
            ],
            None,
        )
        .await;
    let v: Value = r.json().await.unwrap();
    assert_eq!(err(&v), ("invalid_field", Some("endpoint_url")));
    // The same classifier as the worker's: IPv4 inside IPv6 and loopback
    // names are refused at intake too.
    for url in [
        "ws://[::ffff:127.0.0.1]/",
        "ws://[64:ff9b::a00:1]/",
        "ws://api.localhost/",
    ] {
        let r = app
            .submit(
                &[
                    ("method", "Remote"),
                    ("task", "avoiding"),
                    ("training_seed", "0"),
                    ("endpoint_url", url),
                ],
                None,
            )
            .await;
        assert_eq!(r.status(), 400, "{url}");
        let v: Value = r.json().await.unwrap();
        assert_eq!(
            err(&v),
            ("invalid_field", Some("endpoint_url")),
            "{url}: {v}"
        );
    }
    // Policy servers speak WebSocket only (docs/remote-protocol.md).
    let r = app
        .submit(
            &[
                ("method", "Remote"),
                ("task", "avoiding"),
                ("training_seed", "0"),
                ("endpoint_url", "http://policy.example.org/"),
            ],
            None,
        )
        .await;
    assert_eq!(r.status(), 400);
    let v: Value = r.json().await.unwrap();
    assert_eq!(err(&v), ("invalid_field", Some("endpoint_url")));
    assert_eq!(
        v["error"]["message"],
        "`endpoint_url` must use one of: ws, wss"
    );
    // Nothing was stored by any of the refused requests.
    let n: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM submissions")
        .fetch_one(app.state().store.sqlite_pool().expect("a SQLite store"))
        .await
        .unwrap();
    assert_eq!(n, 0);
}

#[tokio::test]
async fn accepted_submission_is_durable_queued_and_duplicate_seed_conflicts() {
    let app = spawn_app().await;
    let m = manifest("aligning");
    let fields = [
        ("method", "QueuePolicy"),
        ("task", "aligning"),
        ("training_seed", "3"),
        ("data_fraction", "0.5"),
        ("protocol", "quick"),
        ("manifest", m.as_str()),
    ];
    let r = app.submit(&fields, Some(fake_onnx())).await;
    assert_eq!(r.status(), 201);
    let loc = r.headers()["location"].to_str().unwrap().to_string();
    let v: Value = r.json().await.unwrap();
    assert_eq!(v["status"], "queued");
    assert_eq!(v["queue_position"], 0);
    assert_eq!(v["data_fraction"], 0.5);
    assert_eq!(v["policy"]["kind"], "onnx");
    assert_eq!(loc, format!("/api/v1/submissions/{}", v["id"]));
    // The file is stored under its hash.
    let sha = v["policy"]["sha256"].as_str().unwrap();
    assert!(app
        .state()
        .store
        .data_dir()
        .join(format!("policies/{sha}.onnx"))
        .is_file());
    let r = app.submit(&fields, Some(fake_onnx())).await;
    assert_eq!(r.status(), 409);
    let e: Value = r.json().await.unwrap();
    assert_eq!(err(&e), ("conflict", Some("training_seed")));
    // The page shows the queue position.
    let (s, page) = app.get_text(&format!("/submissions/{}", v["id"])).await;
    assert_eq!(s, 200);
    assert!(page.contains("Waiting (position 1 in the queue"), "{page}");
    assert!(page.contains("http-equiv=\"refresh\""));
    // Another submitter may not use this method name.
    let other = app
        .state()
        .store
        .create_token("someone-else")
        .await
        .unwrap();
    let mut form = reqwest::multipart::Form::new();
    for (k, v) in [
        ("method", "QueuePolicy"),
        ("task", "aligning"),
        ("training_seed", "4"),
        ("manifest", m.as_str()),
    ] {
        form = form.text(k, v.to_string());
    }
    form = form.part("onnx", reqwest::multipart::Part::bytes(fake_onnx()));
    let r = app
        .http
        .post(app.url("/api/v1/submissions"))
        .bearer_auth(other)
        .multipart(form)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 409);
    assert_eq!(
        err(&r.json::<Value>().await.unwrap()),
        ("conflict", Some("method"))
    );
}

#[tokio::test]
async fn oversized_uploads_are_refused() {
    let app = spawn_app_with(Options {
        max_upload: 1 << 20,
        ..Default::default()
    })
    .await;
    let m = manifest("avoiding");
    let fields = [
        ("method", "Big"),
        ("task", "avoiding"),
        ("training_seed", "0"),
        ("manifest", m.as_str()),
    ];
    let r = app.submit(&fields, Some(vec![1u8; 3 << 20])).await;
    assert_eq!(r.status(), 413);
    let v: Value = r.json().await.unwrap();
    assert_eq!(err(&v), ("payload_too_large", None));
    // Declared length over the limit: refused before the body is read.
    let r = app
        .http
        .post(app.url("/api/v1/submissions"))
        .bearer_auth(app.token())
        .header("content-type", "multipart/form-data; boundary=x")
        .header("content-length", (64u64 << 20).to_string())
        .body(vec![0u8; 16])
        .send()
        .await;
    // The server answers 413 and closes; the client may see either the
    // answer or a reset because it announced more bytes than it sent.
    if let Ok(r) = r {
        assert_eq!(r.status(), 413);
    }
}

#[tokio::test]
async fn rate_limit_answers_429_with_retry_after() {
    let app = spawn_app_with(Options {
        rate_limit: 3,
        ..Default::default()
    })
    .await;
    for _ in 0..3 {
        let r = app
            .http
            .get(app.url("/api/v1/whoami"))
            .bearer_auth(app.token())
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200);
    }
    let r = app
        .http
        .get(app.url("/api/v1/whoami"))
        .bearer_auth(app.token())
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 429);
    let retry: u64 = r.headers()["retry-after"]
        .to_str()
        .unwrap()
        .parse()
        .unwrap();
    assert!((1..=60).contains(&retry));
    assert_eq!(
        err(&r.json::<Value>().await.unwrap()),
        ("rate_limited", None)
    );
}

/// Every cell and header of the main table links to its task title's own
/// section of the task board (Stacking-1/2/3 to theirs), on both tabs.
#[tokio::test]
async fn main_table_links_land_on_the_sections_they_name() {
    let app = spawn_app().await;
    let mut checked = std::collections::BTreeSet::new();
    for obs in ["state", "image"] {
        let (s, home) = app.get_text(&format!("/?obs={obs}")).await;
        assert_eq!(s, 200);
        let links: std::collections::BTreeSet<&str> = home
            .split("href=\"")
            .skip(1)
            .filter_map(|h| h.split('"').next())
            .filter(|h| h.starts_with("/tasks/") && h.contains('#'))
            .collect();
        for link in links {
            let (page, anchor) = link.split_once('#').unwrap();
            let (s, board) = app.get_text(page).await;
            assert_eq!(s, 200, "{page}");
            assert!(
                board.contains(&format!(
                    "<section class=\"board-section\" id=\"{anchor}\">"
                )),
                "{link}: no such section on the board"
            );
            checked.insert(link.to_string());
        }
    }
    for level in 1..=3 {
        for obs in ["state", "image"] {
            let link = format!("/tasks/stacking?obs={obs}#stacking-{level}-t5");
            assert!(checked.contains(&link), "{link} not linked: {checked:?}");
        }
    }
}

#[tokio::test]
async fn paper_rows_are_on_the_pages_csv_and_api() {
    let app = spawn_app().await;
    let (s, home) = app.get_text("/").await;
    assert_eq!(s, 200);
    assert!(home.contains("Aligning (T2)"));
    let (s, page) = app.get_text("/tasks/aligning").await;
    assert_eq!(s, 200);
    assert_eq!(
        page.matches("badge-reported").count(),
        11,
        "11 paper methods on Aligning (state)"
    );
    assert!(page.contains("<svg"), "the Pareto plot is embedded");
    assert!(
        page.contains("60 initial states × 8 rollouts (480 in all), at most 400 steps per episode")
    );
    assert!(!page.contains("our definition"));
    // Inserting's protocol is ours (the reference has no evaluation loop):
    // the page says so.
    let (s, page) = app.get_text("/tasks/inserting").await;
    assert_eq!(s, 200);
    assert!(page.contains("at most 2000 steps per episode"));
    assert!(page.contains("This protocol is our definition, not the paper"));
    let (s, page) = app.get_text("/tasks/stacking?obs=image").await;
    assert_eq!(s, 200);
    for t in ["Stacking-1 (T5)", "Stacking-2 (T5)", "Stacking-3 (T5)"] {
        assert!(page.contains(t));
    }
    assert!(
        page.contains("at most 1200 steps per episode"),
        "image limit"
    );
    let (s, csv) = app.get_text("/api/v1/leaderboards/avoiding/csv").await;
    assert_eq!(s, 200);
    assert_eq!(csv.lines().count(), 12);
    assert!(csv.contains(
        "Avoiding (T1),state,BC-MLP,reported,,1,,0.6660,0.5120,0.0000,0.0000,,,6,0.4600"
    ));
    let (s, v) = app
        .get_json("/api/v1/leaderboards/aligning?obs=state")
        .await;
    assert_eq!(s, 200);
    assert_eq!(v["rows"].as_array().unwrap().len(), 11);
    let (s, v) = app.get_json("/api/v1/leaderboards").await;
    assert_eq!(s, 200);
    assert_eq!(v["leaderboards"].as_array().unwrap().len(), 12);
    let (s, v) = app.get_json("/api/v1/openapi.json").await;
    assert_eq!(s, 200);
    assert_eq!(v["openapi"], "3.1.0");
    let (s, page) = app.get_text("/tasks/aligning/data-fraction").await;
    assert_eq!(s, 200);
    assert!(page.contains("0.25"));
    // The data-fraction view has its own CSV (and JSON) export.
    assert!(
        page.contains("/api/v1/leaderboards/aligning/csv?obs=state&#38;view=data-fraction"),
        "{page}"
    );
    let (s, csv) = app
        .get_text("/api/v1/leaderboards/aligning/csv?obs=state&view=data-fraction")
        .await;
    assert_eq!(s, 200);
    let fractions: std::collections::BTreeSet<&str> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(5).unwrap())
        .collect();
    assert!(fractions.len() > 1, "several fractions: {fractions:?}");
    assert!(fractions.contains("0.25"), "{fractions:?}");
    let (s, v) = app
        .get_json("/api/v1/leaderboards/aligning?view=data-fraction")
        .await;
    assert_eq!(s, 200);
    assert_eq!(v["view"], "data-fraction");
    assert_eq!(v["rows"].as_array().unwrap().len(), csv.lines().count() - 1);
    let (s, v) = app
        .get_json("/api/v1/leaderboards/aligning?view=ablation")
        .await;
    assert_eq!((s, err(&v)), (400, ("invalid_field", Some("view"))));
    let (s, svg) = app
        .get_text("/plots/tasks/aligning/data-fraction.svg")
        .await;
    assert_eq!(s, 200);
    assert!(svg.starts_with("<svg"));
    let (s, page) = app.get_text("/methods/DDPM-ACT").await;
    assert_eq!(s, 200);
    assert!(page.contains("Transformer encoder-decoder") || page.contains("ACT"));
    let (s, _) = app.get_text("/tasks/juggling").await;
    assert_eq!(s, 404);
    let (s, page) = app.get_text("/tasks/aligning?sort=bogus").await;
    assert_eq!(s, 400);
    assert!(page.contains("sort"));
}

#[tokio::test]
async fn sorting_links_reorder_the_table() {
    let app = spawn_app().await;
    let order = |page: &str| -> Vec<String> {
        page.split("<td class=\"method\"><a href=\"/methods/")
            .skip(1)
            .map(|s| s.split('"').next().unwrap().to_string())
            .collect()
    };
    let (_, asc) = app.get_text("/tasks/pushing?sort=success&dir=asc").await;
    let (_, desc) = app.get_text("/tasks/pushing?sort=success&dir=desc").await;
    let mut rev = order(&asc);
    rev.reverse();
    assert_eq!(order(&asc).len(), 11);
    // Ties aside, descending is ascending reversed: compare first and last.
    assert_eq!(order(&desc).first(), rev.first());
    let (_, by_name) = app.get_text("/tasks/pushing?sort=method&dir=asc").await;
    let names = order(&by_name);
    let mut sorted = names.clone();
    sorted.sort_by_key(|s| s.to_lowercase());
    assert_eq!(names, sorted);
}

#[tokio::test]
async fn html_output_is_escaped() {
    let app = spawn_app().await;
    let m = manifest("avoiding");
    let r = app
        .submit(
            &[
                ("method", "Escaper"),
                ("task", "avoiding"),
                ("training_seed", "0"),
                ("description", "<script>alert('x')</script>"),
                ("backbone", "<b>bold</b>"),
                ("manifest", m.as_str()),
            ],
            Some(fake_onnx()),
        )
        .await;
    assert_eq!(r.status(), 201);
    let (_, page) = app.get_text("/methods/Escaper").await;
    assert!(!page.contains("<script>alert"));
    assert!(
        page.contains("&lt;script&gt;") || page.contains("&#60;script&#62;"),
        "{page}"
    );
    assert!(!page.contains("<b>bold</b>"));
}

#[tokio::test]
async fn html_form_submits_and_reports_field_errors() {
    let app = spawn_app().await;
    let (s, form) = app.get_text("/submit").await;
    assert_eq!(s, 200);
    assert!(form.contains("name=\"training_seed\""));
    let m = manifest("pushing");
    let mk = |seed: &str| {
        reqwest::multipart::Form::new()
            .text("token", app.token().to_string())
            .text("method", "FormPolicy")
            .text("task", "pushing")
            .text("training_seed", seed.to_string())
            .text("manifest", m.clone())
            .part(
                "onnx",
                reqwest::multipart::Part::bytes(fake_onnx()).file_name("p.onnx"),
            )
    };
    let client = reqwest::Client::builder()
        .redirect(reqwest::redirect::Policy::none())
        .build()
        .unwrap();
    let r = client
        .post(app.url("/submit"))
        .multipart(mk("1"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 303);
    let loc = r.headers()["location"].to_str().unwrap().to_string();
    assert!(loc.starts_with("/submissions/"));
    let r = client
        .post(app.url("/submit"))
        .multipart(mk("minus one"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 400);
    let page = r.text().await.unwrap();
    assert!(page.contains("<strong>training_seed</strong>"), "{page}");
    // The form comes back filled in with what was sent (escaped), except the
    // token and the file.
    assert!(page.contains("choose the ONNX file again"), "{page}");
    assert!(page.contains(r#"name="method" required maxlength="64" placeholder="MyDiffusionPolicy" value="FormPolicy""#), "{page}");
    assert!(
        page.contains(r#"<option value="pushing" selected>"#),
        "{page}"
    );
    assert!(page.contains(r#"value="minus one""#), "{page}");
    assert!(
        page.contains("&#34;task&#34;: &#34;pushing&#34;"),
        "manifest kept, escaped: {page}"
    );
    assert!(!page.contains(app.token()), "the token is never echoed");
}

#[tokio::test]
async fn concurrent_duplicate_seeds_give_one_201_and_409s_never_500() {
    let app = spawn_app().await;
    let m = manifest("pushing");
    let fields = [
        ("method", "RacePolicy"),
        ("task", "pushing"),
        ("training_seed", "7"),
        ("manifest", m.as_str()),
    ];
    let mut statuses: Vec<u16> =
        futures_util::future::join_all((0..6).map(|_| app.submit(&fields, Some(fake_onnx()))))
            .await
            .into_iter()
            .map(|r| r.status().as_u16())
            .collect();
    statuses.sort();
    assert_eq!(statuses, vec![201, 409, 409, 409, 409, 409]);
}

#[tokio::test]
async fn a_wrong_http_method_gets_the_json_error_format() {
    let app = spawn_app().await;
    let r = app
        .http
        .delete(app.url("/api/v1/leaderboards"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 405);
    let v: Value = r.json().await.unwrap();
    assert_eq!(err(&v), ("method_not_allowed", None));
    let msg = v["error"]["message"].as_str().unwrap();
    assert!(
        msg.starts_with("DELETE is not allowed on /api/v1/leaderboards"),
        "{msg}"
    );
}

/// The form's token is checked before the file part is read: a request with a
/// wrong token and an upload that never finishes is answered 401 at once,
/// without waiting for (or buffering) the upload.
#[tokio::test]
async fn the_form_refuses_a_wrong_token_before_reading_the_upload() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let app = spawn_app_with(Options {
        max_upload: 64 << 20,
        ..Options::default()
    })
    .await;
    let mut sock = tokio::net::TcpStream::connect(app.addr).await.unwrap();
    let b = "d3ilboundary";
    let head = format!(
        "--{b}\r\nContent-Disposition: form-data; name=\"token\"\r\n\r\nd3il_wrong\r\n\
         --{b}\r\nContent-Disposition: form-data; name=\"onnx\"; filename=\"p.onnx\"\r\n\
         Content-Type: application/octet-stream\r\n\r\n"
    );
    let mut first = head.into_bytes();
    first.extend(std::iter::repeat_n(0u8, 64 << 10));
    let req = format!(
        "POST /submit HTTP/1.1\r\nHost: {}\r\nContent-Type: multipart/form-data; boundary={b}\r\n\
         Content-Length: {}\r\n\r\n",
        app.addr,
        32 << 20
    );
    sock.write_all(req.as_bytes()).await.unwrap();
    sock.write_all(&first).await.unwrap();
    // The remaining ~32 MiB are never sent: only an early answer can arrive.
    let mut buf = vec![0u8; 64 << 10];
    let mut got = Vec::new();
    let read = tokio::time::timeout(std::time::Duration::from_secs(30), async {
        loop {
            let n = sock.read(&mut buf).await.unwrap();
            if n == 0 {
                break;
            }
            got.extend_from_slice(&buf[..n]);
            if String::from_utf8_lossy(&got).contains("</html>") {
                break;
            }
        }
    })
    .await;
    assert!(read.is_ok(), "no answer while the upload was still pending");
    let text = String::from_utf8_lossy(&got);
    assert!(text.starts_with("HTTP/1.1 401"), "{text}");
    assert!(text.contains("d3il token create"), "{text}");
}

#[tokio::test]
async fn a_path_segment_that_names_nothing_is_404_everywhere() {
    let app = spawn_app().await;
    for id in ["abc", "0", "-3", "99999"] {
        let (s, v) = app.get_json(&format!("/api/v1/submissions/{id}")).await;
        assert_eq!((s, err(&v)), (404, ("not_found", None)), "{id}");
        let (s, v) = app
            .get_json(&format!("/api/v1/submissions/{id}/results"))
            .await;
        assert_eq!((s, err(&v)), (404, ("not_found", None)), "{id}");
        let (s, page) = app.get_text(&format!("/submissions/{id}")).await;
        assert_eq!(s, 404, "{id}");
        assert!(page.contains("<html"), "pages answer with an HTML page");
        let (s, _) = app
            .get_text(&format!("/plots/submissions/{id}/paths.svg"))
            .await;
        assert_eq!(s, 404, "{id}");
    }
    let (s, v) = app.get_json("/api/v1/leaderboards/juggling").await;
    assert_eq!((s, err(&v)), (404, ("not_found", None)));
    let (s, _) = app.get_text("/plots/tasks/juggling/pareto.svg").await;
    assert_eq!(s, 404);
}
