//! Issue 18: the `/compare` page over two finished submissions and the home
//! page's main table with evaluated rows. Real server on 127.0.0.1 port 0,
//! real SQLite; results are written through the store as a worker would.

use d3il_protocol::*;
use d3il_test_support::server::*;
use d3il_test_support::{pushing_result, SynthRollout};
use serde_json::Value;

/// A Pushing result on the original contexts (30 states × 16 rollouts) with
/// state c succeeding in `k(c)` of its 16 rollouts; the first `ones` rollouts
/// of each state have behaviour 1, the others 0.
fn result(protocol: ProtocolKind, k: impl Fn(usize) -> usize, ones: usize) -> EvalResult {
    pushing_result(protocol, |c, r| SynthRollout {
        success: r < k(c),
        label: usize::from(r < ones),
        unstable: false,
    })
}

async fn submit(app: &TestServer, method: &str, task: &str, protocol: &str) -> i64 {
    let m = manifest(task);
    let r = app
        .submit(
            &[
                ("method", method),
                ("task", task),
                ("training_seed", "0"),
                ("protocol", protocol),
                ("manifest", m.as_str()),
            ],
            Some(fake_onnx()),
        )
        .await;
    assert_eq!(r.status(), 201);
    r.json::<Value>().await.unwrap()["id"].as_i64().unwrap()
}

/// Completes the oldest queued job with `result`, as a worker would.
async fn complete(app: &TestServer, result: &EvalResult) -> i64 {
    let store = &app.state().store;
    let claimed = store.claim_job("test", 60).await.unwrap().unwrap();
    store
        .complete_job(claimed.job.id, claimed.submission.id, result, &[])
        .await
        .unwrap();
    claimed.submission.id
}

fn strip_svg(html: &str) -> String {
    let mut out = String::new();
    let mut rest = html;
    while let Some(start) = rest.find("<svg") {
        out.push_str(&rest[..start]);
        out.push_str("[svg]");
        match rest[start..].find("</svg>") {
            Some(end) => rest = &rest[start + end + "</svg>".len()..],
            None => {
                rest = "";
                break;
            }
        }
    }
    out.push_str(rest);
    out
}

#[tokio::test]
async fn compare_page_shows_paired_differences_contexts_and_behaviours() {
    let app = spawn_app().await;
    let a = submit(&app, "Alpha", "pushing", "paper").await;
    let b = submit(&app, "Beta", "pushing", "paper").await;
    assert_eq!(
        complete(&app, &result(ProtocolKind::Paper, |_| 12, 6)).await,
        a
    );
    assert_eq!(
        complete(&app, &result(ProtocolKind::Paper, |c| c % 9, 2)).await,
        b
    );

    let (s, page) = app.get_text(&format!("/compare?a={a}&b={b}")).await;
    assert_eq!(s, 200, "{page}");
    // The same numbers as the API (one computation).
    let (_, api) = app.get_json(&format!("/api/v1/compare?a={a}&b={b}")).await;
    let d = &api["success_rate"];
    let diff = format!("+{:.3}", d["difference"]["value"].as_f64().unwrap());
    assert!(page.contains(&diff), "difference {diff} on the page");
    assert!(page.contains(&format!(
        "[+{:.3}, +{:.3}]",
        d["difference"]["ci_low"].as_f64().unwrap(),
        d["difference"]["ci_high"].as_f64().unwrap()
    )));
    assert!(
        page.contains("&#60; 0.001"),
        "p-value of a clear difference: {page}"
    );
    // The interval names its method: the p-value's own test inverted
    // (30 states: Monte Carlo over sign vectors).
    assert_eq!(d["difference"]["method"], "sign_flip_monte_carlo", "{api}");
    assert!(
        page.contains("Success rate: interval: the inverted sign-flip test (Monte Carlo), the test whose p-value is shown: 0 is outside it exactly when p &#60; 0.05."),
        "{page}"
    );
    // Thirty initial states side by side, and the behaviour counts of both.
    let contexts = &page[page.find("id=\"contexts\"").unwrap()..];
    assert_eq!(contexts.matches("<tr><td class=\"num\">").count(), 30);
    assert!(contexts.contains("<td class=\"num\">0.750</td><td class=\"num\">0.000</td>"));
    let beh = &page[page.find("id=\"behaviours\"").unwrap()..];
    // A: 6 of 12 successes are behaviour 1 in each of 30 states.
    assert!(
        beh.contains("<td class=\"num\">180</td>"),
        "{}",
        &beh[..600]
    );
    assert!(page.contains("id=\"behaviours-a\"") && page.contains("id=\"behaviours-b\""));
    insta::assert_snapshot!("compare_page", strip_svg(&page));

    // Linked from the submission page.
    let (_, sp) = app.get_text(&format!("/submissions/{a}")).await;
    assert!(sp.contains(&format!("href=\"/compare?a={a}\"")), "{sp}");
    // The leaderboard's row selection sends two `s`.
    let (_, board) = app.get_text("/tasks/pushing").await;
    assert!(board.contains(&format!(
        "name=\"s\" value=\"{a}\" form=\"compare-selection\""
    )));
    assert!(board.contains("<form method=\"get\" action=\"/compare\" id=\"compare-selection\""));
    let (_, reported_only) = app.get_text("/tasks/avoiding").await;
    assert!(
        !reported_only.contains("id=\"compare-selection\""),
        "nothing to tick"
    );
    let (s, page2) = app.get_text(&format!("/compare?s={a}&s={b}")).await;
    assert_eq!(s, 200);
    assert!(page2.contains(&diff));

    // Clear errors.
    let (s, page) = app.get_text("/compare").await;
    assert_eq!(s, 200, "the empty form");
    assert!(page.contains("id=\"compare-form\"") && !page.contains("id=\"error-message\""));
    let (s, page) = app.get_text(&format!("/compare?s={a}")).await;
    assert_eq!(s, 400);
    assert!(page.contains("select exactly two submissions to compare (you selected 1)"));
    let (s, page) = app.get_text(&format!("/compare?a={a}")).await;
    assert_eq!(s, 400);
    assert!(page.contains("submission B is missing"));
    let (s, page) = app.get_text(&format!("/compare?a={a}&b=x")).await;
    assert_eq!(s, 400);
    assert!(page.contains("`b` must be a submission id"));
    let (s, page) = app.get_text(&format!("/compare?a={a}&b=99999")).await;
    assert_eq!(s, 404, "{page}");
    // The race form reads its ids with the same parser: the same message
    // for a bad one, and `#N` as the pages show ids accepted by both.
    let race = |a: String, b: String| {
        let form = [
            ("a", a),
            ("b", b),
            ("protocol", "quick".into()),
            ("token", app.token().to_string()),
        ];
        app.http.post(app.url("/races")).form(&form).send()
    };
    let r = race(a.to_string(), "x".into()).await.unwrap();
    assert_eq!(r.status(), 400);
    let page = r.text().await.unwrap();
    assert!(
        page.contains(
            "`b` must be a submission id (an integer, the number shown as #N on its page), got `x`"
        ),
        "{page}"
    );
    let (s, page) = app.get_text(&format!("/compare?a=%23{a}&b={b}")).await;
    assert_eq!(s, 200, "{page}");
    let r = race(format!("#{a}"), format!(" #{b} ")).await.unwrap();
    assert_eq!(r.status(), 200, "followed to the race's page");
    assert!(r.url().path().starts_with("/races/"), "{}", r.url());
    // The form's old address (`/comparisons`, before races had their own
    // name) still races: a 308 sends the same POST to `/races`.
    let form = [
        ("a", a.to_string()),
        ("b", b.to_string()),
        ("protocol", "quick".into()),
        ("token", app.token().to_string()),
    ];
    let r = app
        .http
        .post(app.url("/comparisons"))
        .form(&form)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200, "followed to the race's page");
    assert!(r.url().path().starts_with("/races/"), "{}", r.url());
    // Unfinished.
    let q = submit(&app, "Gamma", "pushing", "paper").await;
    let (s, page) = app.get_text(&format!("/compare?a={a}&b={q}")).await;
    assert_eq!(s, 400);
    assert!(
        page.contains(&format!(
            "submission {q} (`b`) is queued; only finished submissions can be compared"
        )),
        "{page}"
    );
    let (s, v) = app.get_json(&format!("/api/v1/compare?a={q}&b={a}")).await;
    assert_eq!(s, 400, "{v}");
    assert_eq!(v["error"]["field"], "a");
    // Not comparable: a different initial-state set, a different task.
    assert_eq!(
        complete(&app, &{
            let mut r = result(ProtocolKind::Paper, |_| 8, 0);
            r.manifest.initial_states = "pushing-v1.json".into();
            r.manifest.initial_states_sha256 = "932d".into();
            r
        })
        .await,
        q
    );
    let (s, page) = app.get_text(&format!("/compare?a={a}&b={q}")).await;
    assert_eq!(s, 400);
    assert!(page.contains("they differ in initial-state set"), "{page}");
    let other = submit(&app, "Delta", "aligning", "paper").await;
    let mut r = result(ProtocolKind::Paper, |_| 8, 0);
    r.manifest.task = TaskId::Aligning;
    assert_eq!(complete(&app, &r).await, other);
    let (s, page) = app.get_text(&format!("/compare?a={a}&b={other}")).await;
    assert_eq!(s, 400);
    assert!(page.contains("they differ in task"), "{page}");

    // Paired, with a note: B observes camera images (drawn with primitives).
    let (_, page) = app.get_text(&format!("/compare?a={a}&b={b}")).await;
    assert!(
        !page.contains("class=\"note caveat\""),
        "nothing else differs"
    );
    let image = submit(&app, "Epsilon", "pushing", "paper").await;
    let mut r = result(ProtocolKind::Paper, |_| 8, 0);
    r.manifest.obs_type = ObsType::Image;
    r.manifest.robot_look = Some(RobotLook::Primitives);
    assert_eq!(complete(&app, &r).await, image);
    let (s, page) = app.get_text(&format!("/compare?a={a}&b={image}")).await;
    assert_eq!(s, 200, "{page}");
    assert!(
        page.contains(
            "<p class=\"note caveat\">Note: A observes the state and B the camera images"
        ),
        "{page}"
    );
    let (_, api) = app
        .get_json(&format!("/api/v1/compare?a={a}&b={image}"))
        .await;
    assert_eq!(api["caveats"].as_array().map(Vec::len), Some(1), "{api}");
}

#[tokio::test]
async fn home_page_shows_evaluated_rows_next_to_reported_ones_but_not_quick_runs() {
    let app = spawn_app().await;
    let a = submit(&app, "Alpha", "pushing", "paper").await;
    let q = submit(&app, "QuickOnly", "pushing", "quick").await;
    assert_eq!(
        complete(&app, &result(ProtocolKind::Paper, |_| 16, 6)).await,
        a
    );
    let mut quick = result(ProtocolKind::Quick, |_| 16, 0);
    quick.manifest.protocol = ProtocolKind::Quick;
    assert_eq!(complete(&app, &quick).await, q);

    let (s, page) = app.get_text("/").await;
    assert_eq!(s, 200);
    let table = &page[page.find("<table class=\"board main-table\"").unwrap()..];
    let table = &table[..table.find("</table>").unwrap()];
    assert!(table.contains("Pushing (T3)"));
    // The evaluated row is in the third group (not in the paper), labelled.
    let alpha = &table[table.find(">Alpha</a>").expect("evaluated row")..];
    assert!(alpha[..400].contains("evaluated here"), "{}", &alpha[..400]);
    assert!(table.contains("Methods not in the paper"));
    assert!(table.contains("<a href=\"/tasks/pushing?obs=state#pushing-t3\">1.000</a>"));
    assert!(
        !table.contains("QuickOnly"),
        "quick runs are not in the paper's table"
    );
    assert!(page.contains("Rows marked “evaluated here”"));
    // 1.000 beats every history-free reported Pushing success (VAE-ACT's 0.951): bold.
    assert!(
        table.contains(
            "<td class=\"num best\"><a href=\"/tasks/pushing?obs=state#pushing-t3\">1.000</a>"
        ),
        "{table}"
    );

    // Image tab: the paper's image table; an unknown obs is a clear error.
    let (s, page) = app.get_text("/?obs=image").await;
    assert_eq!(s, 200);
    assert!(page.contains("data-obs=\"image\""));
    assert!(page.contains("for image observations (Table 3)"));
    let table = &page[page.find("<table class=\"board main-table\"").unwrap()..];
    let table = &table[..table.find("</table>").unwrap()];
    assert!(table.contains("Aligning (T2)"));
    assert!(
        !table.contains("Pushing (T3)"),
        "the image table has no Pushing"
    );
    let (s, page) = app.get_text("/?obs=depth").await;
    assert_eq!(s, 400, "{page}");
}

/// A race row as the race slot leaves it (written directly: the test app's
/// worker is /bin/false, so the slot itself would fail any race it ran).
async fn race_row(
    app: &TestServer,
    a: i64,
    b: i64,
    status: &str,
    live: &Value,
    report: Option<&Value>,
) -> i64 {
    let pool = app
        .state()
        .store
        .sqlite_pool()
        .expect("the test app is on SQLite");
    let (id,): (i64,) = sqlx::query_as(
        "INSERT INTO comparisons (submission_a, submission_b, task, protocol, seed, alpha, status, live_json, \
         report_json, created_at, updated_at) VALUES ($1, $2, 'pushing', 'paper', 0, 0.05, $3, $4, $5, 1, 1) RETURNING id",
    )
    .bind(a)
    .bind(b)
    .bind(status)
    .bind(live.to_string())
    .bind(report.map(|r| r.to_string()))
    .fetch_one(pool)
    .await
    .unwrap();
    id
}

#[tokio::test]
async fn the_race_page_names_the_rule_that_decided_and_draws_the_walk() {
    // Issue 51: a Pushing race decided at pair 17 of 30 said "as soon as
    // the anytime-valid paired test decides" beside an anytime p-value of
    // 0.0625; the decision came from the horizon-calibrated boundary.
    let app = spawn_app().await;
    let a = submit(&app, "Alpha", "pushing", "paper").await;
    let b = submit(&app, "Beta", "pushing", "paper").await;
    complete(&app, &result(ProtocolKind::Paper, |_| 12, 6)).await;
    complete(&app, &result(ProtocolKind::Paper, |c| c % 9, 2)).await;
    let codes = "a1a0aab1aa0aaa1aab0aaaa1aaaaaa";
    let pairs = race::pairs_of(codes).unwrap();
    let mut test = d3il_metrics::sequential::SequentialComparison::with_horizon(0.05, None, 30);
    for &p in &pairs {
        test.observe_pair(p);
    }
    let at = test.decided_at().unwrap() as usize;
    let seen = &codes[..at];
    let e = test.eprocess();
    let live = serde_json::json!({
        "states": at, "states_total": 30, "pairs": at,
        "both": seen.matches('1').count(), "only_a": seen.matches('a').count(),
        "only_b": seen.matches('b').count(), "neither": seen.matches('0').count(),
        "e_value": e.e_value(), "p_value": e.p_value(), "decision": null,
        "outcomes": &codes[..at - 1],
    });
    // While it runs: the rule that will decide, and the walk so far.
    let running = race_row(&app, a, b, "running", &live, None).await;
    let (s, page) = app.get_text(&format!("/races/{running}")).await;
    assert_eq!(s, 200, "{page}");
    assert!(
        page.contains("Decides by the boundary calibrated to 30 pairs"),
        "{page}"
    );
    let fig = &page[page.find("id=\"race-walk\"").expect("the walk is drawn")..];
    assert!(fig.contains("<svg") && fig.contains("<polyline"), "{fig}");
    assert!(
        page.contains("http-equiv=\"refresh\""),
        "refreshed while it runs"
    );
    // Finished: which rule decided, and its guarantee.
    let report = race::RaceReport {
        task: TaskId::Pushing,
        protocol: ProtocolKind::Paper,
        seed: 0,
        alpha: 0.05,
        delta: None,
        pair: "initial state (its rollout 0)".into(),
        decision: Some("A better".into()),
        decided_at: Some(at as u64),
        e_value: e.e_value(),
        p_value: e.p_value(),
        discordant: (
            seen.matches('a').count() as u64,
            seen.matches('b').count() as u64,
        ),
        difference_interval: None,
        rate_a: 0.75,
        rate_b: 0.23,
        pairs_used: at as u64,
        pairs_full: 30,
        states_used: at,
        states_full: 30,
        rollouts_used: 2 * at * 16,
        rollouts_full: 960,
        rollouts_simulated: 2 * at * 16,
        fixed_p_value: 0.001,
        fixed_pairs_for_power_90: None,
        seconds: 1.0,
        policy_calls: 1,
        outcomes: seen.into(),
    };
    let done = race_row(
        &app,
        a,
        b,
        "completed",
        &live,
        Some(&serde_json::to_value(&report).unwrap()),
    )
    .await;
    let (s, page) = app.get_text(&format!("/races/{done}")).await;
    assert_eq!(s, 200, "{page}");
    assert!(
        page.contains("Decided by the boundary calibrated to 30 pairs")
            && page.contains(
                "exact type-I error is at most 0.05 for a comparison of at most 30 pairs"
            )
            && page.contains("did not decide"),
        "{page}"
    );
    assert!(page.contains("id=\"race-walk\""), "{page}");
    assert!(!page.contains("http-equiv=\"refresh\""));
    // The fixed-size comparison of the pairs used: the exact McNemar test
    // and its inverted interval, on the page and in the race's JSON.
    let (w, l) = report.discordant;
    let fixed = d3il_metrics::rate_difference::ExactMcNemar::new(at, w, l).paired_interval(0.95);
    let (lo, hi) = fixed
        .interval
        .map(|i| (i.low, i.high))
        .expect("an interval");
    assert!(lo > 0.0 && fixed.p_value <= 0.05, "{fixed:?}");
    let line = &page[page
        .find("id=\"fixed-comparison\"")
        .expect("the fixed-size line")..];
    assert!(
        line.contains(&format!("Fixed-size comparison of the {at} pairs used"))
            && line.contains(&format!("{lo:.3}–{hi:.3}"))
            && line.contains("inverted exact McNemar test")
            && line.contains(&format!("exact McNemar p-value {:.4}", fixed.p_value)),
        "{line}"
    );
    let (s, api) = app.get_json(&format!("/api/v1/races/{done}")).await;
    assert_eq!(s, 200, "{api}");
    let f = &api["fixed_comparison"];
    assert_eq!(f["pairs"], at as u64, "{api}");
    assert_eq!(f["p_value"].as_f64(), Some(fixed.p_value), "{api}");
    assert_eq!(f["difference"]["method"], "mcnemar_exact", "{api}");
    assert_eq!(
        (
            f["difference"]["ci_low"].as_f64(),
            f["difference"]["ci_high"].as_f64()
        ),
        (Some(lo), Some(hi)),
        "{api}"
    );
    // Not finished, no fixed-size comparison.
    let (_, api) = app.get_json(&format!("/api/v1/races/{running}")).await;
    assert!(api["fixed_comparison"].is_null(), "{api}");
    // The old addresses: the page redirects (308) to its `/races` one, the
    // API answers the same document with a deprecation note.
    let no_follow = reqwest::Client::builder()
        .redirect(reqwest::redirect::Policy::none())
        .build()
        .unwrap();
    let r = no_follow
        .get(app.url(&format!("/comparisons/{done}")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 308);
    assert_eq!(r.headers()["location"], format!("/races/{done}").as_str());
    let r = app
        .http
        .get(app.url(&format!("/api/v1/comparisons/{done}")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["deprecation"], "true");
    assert_eq!(
        r.headers()["link"],
        format!("</api/v1/races/{done}>; rel=\"successor-version\"").as_str()
    );
    let old: serde_json::Value = r.json().await.unwrap();
    let (_, new) = app.get_json(&format!("/api/v1/races/{done}")).await;
    assert_eq!(old, new);
    let r = app
        .http
        .get(app.url(&format!("/api/v1/races/{done}")))
        .send()
        .await
        .unwrap();
    assert!(
        r.headers().get("deprecation").is_none(),
        "the new route is not deprecated"
    );
    // A stored race whose task names nothing fails to decode, naming the
    // column, instead of being read as text.
    let pool = app.state().store.sqlite_pool().unwrap();
    sqlx::query("UPDATE comparisons SET task = 'juggling' WHERE id = $1")
        .bind(done)
        .execute(pool)
        .await
        .unwrap();
    let e = app
        .state()
        .store
        .race(done)
        .await
        .expect_err("a corrupt task");
    assert!(e.to_string().contains("task"), "{e}");
    assert!(e.to_string().contains("juggling"), "{e}");
}
