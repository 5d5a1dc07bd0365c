//! Validators on what anyone may read (issue 17): pages, plots and JSON carry
//! a weak ETag and `Cache-Control: no-cache`; a request with the matching
//! `If-None-Match` gets 304 without a body; requests with credentials and
//! `/admin` get none. A real server on 127.0.0.1 with a fresh SQLite file.

use d3il_test_support::server::*;

#[tokio::test]
async fn pages_plots_and_json_answer_304_to_a_matching_etag() {
    let app = spawn_app().await;
    for path in [
        "/",
        "/tasks/pushing",
        "/plots/tasks/pushing/pareto.svg",
        "/api/v1/leaderboards",
    ] {
        let r = app.http.get(app.url(path)).send().await.unwrap();
        assert_eq!(r.status(), 200, "{path}");
        let etag = r.headers()["etag"].to_str().unwrap().to_string();
        assert!(etag.starts_with("W/\""), "{path}: {etag}");
        assert_eq!(r.headers()["cache-control"], "no-cache", "{path}");
        let body = r.bytes().await.unwrap();
        assert!(!body.is_empty());
        // The same content gets the same tag.
        let again = app.http.get(app.url(path)).send().await.unwrap();
        assert_eq!(again.headers()["etag"].to_str().unwrap(), etag, "{path}");
        let r = app
            .http
            .get(app.url(path))
            .header("if-none-match", &etag)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 304, "{path}");
        assert_eq!(r.headers()["etag"].to_str().unwrap(), etag);
        assert_eq!(r.headers()["x-frame-options"], "DENY", "{path}");
        assert!(r.bytes().await.unwrap().is_empty());
        // A stale tag gets the full answer.
        let r = app
            .http
            .get(app.url(path))
            .header("if-none-match", "W/\"0000000000000000-1\"")
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200, "{path}");
        assert_eq!(r.bytes().await.unwrap(), body);
    }
}

#[tokio::test]
async fn a_change_changes_the_etag_and_private_answers_get_none() {
    let app = spawn_app().await;
    let tag = |r: &reqwest::Response| {
        r.headers()
            .get("etag")
            .map(|v| v.to_str().unwrap().to_string())
    };
    let r = app.http.get(app.url("/submissions")).send().await.unwrap();
    let before = tag(&r).expect("etag");
    let m = manifest("pushing");
    let s = app
        .submit(
            &[
                ("method", "Tagged"),
                ("task", "pushing"),
                ("training_seed", "1"),
                ("manifest", m.as_str()),
            ],
            Some(fake_onnx()),
        )
        .await;
    assert_eq!(s.status(), 201);
    let r = app
        .http
        .get(app.url("/submissions"))
        .header("if-none-match", &before)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200, "the list changed");
    assert_ne!(tag(&r).unwrap(), before);
    // With a token: no validators.
    let r = app
        .http
        .get(app.url("/api/v1/whoami"))
        .bearer_auth(app.token())
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(tag(&r), None);
    let (s, _) = app.get_admin_text("/admin").await;
    assert_eq!(s, 200);
}
