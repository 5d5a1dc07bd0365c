//! The leaderboard a researcher reads at a glance (issue 18), against the real
//! server on 127.0.0.1 with a fresh SQLite file: ranking groups, number
//! format, lists and progress.

use d3il_protocol::*;
use d3il_test_support::server::*;

/// Stores a completed evaluation of `method` on Aligning (state) as the worker
/// would, and returns the submission id.
#[allow(clippy::too_many_arguments)]
async fn evaluated(
    app: &TestServer,
    method: &str,
    protocol: ProtocolKind,
    training_seed: i64,
    success: f64,
    cond: f64,
    initial_states: &str,
) -> i64 {
    let store = &app.state().store;
    let id = queued_submission(store, method, TaskId::Aligning, protocol, training_seed, 1).await;
    let job = store.job_for(id).await.expect("job");
    let result = aligning_result(protocol, success, cond, initial_states);
    store
        .complete_job(job.id, id, &result, &[])
        .await
        .expect("complete");
    id
}

/// The `<table ...data-group="G">` tables of a page, in page order, as (group, html).
fn tables(page: &str) -> Vec<(String, String)> {
    page.split("<table class=\"board leaderboard\"")
        .skip(1)
        .map(|t| {
            let group = t
                .split("data-group=\"")
                .nth(1)
                .and_then(|g| g.split('"').next())
                .unwrap_or("")
                .to_string();
            let body = t.split("</table>").next().unwrap_or("").to_string();
            (group, body)
        })
        .collect()
}

#[tokio::test]
async fn quick_runs_evaluated_and_reported_rows_and_other_sets_are_ranked_apart() {
    let app = spawn_app().await;
    // A perfect quick smoke test, two paper-protocol seeds on the original
    // contexts, and one run on another initial-state set.
    evaluated(
        &app,
        "Smoke",
        ProtocolKind::Quick,
        0,
        1.0,
        0.0,
        "aligning-v2.json",
    )
    .await;
    evaluated(
        &app,
        "Mine",
        ProtocolKind::Paper,
        0,
        0.97,
        0.2,
        "aligning-v2.json",
    )
    .await;
    evaluated(
        &app,
        "Mine",
        ProtocolKind::Paper,
        1,
        0.99,
        0.3,
        "aligning-v2.json",
    )
    .await;
    evaluated(
        &app,
        "Other",
        ProtocolKind::Paper,
        0,
        0.98,
        0.1,
        "aligning-v1.json",
    )
    .await;

    let (s, page) = app.get_text("/tasks/aligning?sort=success&dir=desc").await;
    assert_eq!(s, 200);
    let t = tables(&page);
    let groups: Vec<&str> = t.iter().map(|(g, _)| g.as_str()).collect();
    assert_eq!(
        groups,
        ["evaluated", "evaluated", "reported", "smoke"],
        "one table per set, then the paper, then smoke tests"
    );
    assert!(page.contains("Evaluated here (initial states aligning-v1.json)"));
    assert!(page.contains("Evaluated here (initial states aligning-v2.json)"));
    // The quick run is below every reported row, in the unranked smoke section.
    let smoke_at = page.find(">Smoke</a>").expect("smoke row shown");
    let last_reported = page
        .rfind("<tr class=\"reported\">")
        .expect("reported rows");
    assert!(smoke_at > last_reported);
    assert!(!t[0].1.contains("Smoke") && !t[2].1.contains("Smoke"));
    assert!(
        t[3].1.contains("<td class=\"num\"></td>"),
        "smoke rows unranked"
    );
    // Each group ranks from 1; the reported table holds only reported rows.
    for (_, html) in &t[..3] {
        assert!(html.contains("<td class=\"num\">1</td>"));
    }
    assert!(!t[2].1.contains("badge-evaluated"));
    assert!(t[0].1.contains(">Other</a>") && !t[0].1.contains(">Mine</a>"));
    assert!(t[1].1.contains(">Mine</a>") && !t[1].1.contains(">Other</a>"));

    // The Pareto plot leaves the quick run off: its label is nowhere in the SVG.
    let (s, svg) = app
        .get_text("/plots/tasks/aligning/pareto.svg?obs=state")
        .await;
    assert_eq!(s, 200);
    assert!(svg.contains("Mine") && !svg.contains("Smoke"));
}

/// Stores a completed image evaluation of `method` on Aligning whose manifest
/// records `look`, and returns the submission id.
async fn evaluated_image(
    app: &TestServer,
    method: &str,
    seed: i64,
    look: Option<RobotLook>,
) -> i64 {
    let store = &app.state().store;
    let (task, obs, protocol) = (TaskId::Aligning, ObsType::Image, ProtocolKind::Paper);
    let id = queued_submission_of(store, method, task, obs, protocol, seed, 1).await;
    let job = store.job_for(id).await.expect("job");
    let mut result = aligning_result(protocol, 0.5 + 0.1 * seed as f64, 0.2, "aligning-v2.json");
    result.manifest.obs_type = obs;
    result.manifest.robot_look = look;
    store
        .complete_job(job.id, id, &result, &[])
        .await
        .expect("complete");
    id
}

#[tokio::test]
async fn image_rows_say_how_the_robot_was_drawn_and_are_ranked_apart() {
    let app = spawn_app().await;
    let meshed = evaluated_image(&app, "Meshed", 0, Some(RobotLook::Meshes)).await;
    evaluated_image(&app, "Meshed", 1, Some(RobotLook::Meshes)).await;
    // One method's seed drawn with primitives is not averaged with its others.
    let prim = evaluated_image(&app, "Meshed", 2, Some(RobotLook::Primitives)).await;
    let old = evaluated_image(&app, "Old", 0, None).await;

    let (s, page) = app.get_text("/tasks/aligning?obs=image").await;
    assert_eq!(s, 200);
    let t: Vec<String> = tables(&page)
        .into_iter()
        .filter(|(g, _)| g == "evaluated")
        .map(|(_, html)| html)
        .collect();
    assert_eq!(t.len(), 3, "one ranked table per robot look: {page}");
    // Drawn as the original: first, with the plain heading and no badge.
    assert!(page.contains("Evaluated here (initial states aligning-v2.json)</"));
    assert!(t[0].contains(">Meshed</a>") && !t[0].contains("badge-look"));
    assert!(
        t[0].contains("<td class=\"num\">2</td>"),
        "two seeds: {}",
        t[0]
    );
    let with = |needle: &str| t.iter().find(|h| h.contains(needle)).expect(needle);
    assert!(with(">primitive robot</span>").contains(">Meshed</a>"));
    assert!(with(">robot look not recorded</span>").contains(">Old</a>"));
    assert!(page.contains("initial states aligning-v2.json; primitive robot)"));
    assert!(page.contains("initial states aligning-v2.json; robot look not recorded"));

    // The API and the CSV name the look of every evaluated image row.
    let (s, api) = app
        .get_json("/api/v1/leaderboards/aligning?obs=image")
        .await;
    assert_eq!(s, 200);
    let looks: Vec<&str> = api["rows"]
        .as_array()
        .expect("rows")
        .iter()
        .filter(|r| r["source"] == "evaluated")
        .map(|r| r["robot_look"].as_str().unwrap_or("unrecorded"))
        .collect();
    assert_eq!(looks, ["meshes", "primitives", "unrecorded"]);
    let (_, csv) = app
        .get_text("/api/v1/leaderboards/aligning/csv?obs=image")
        .await;
    assert!(csv
        .lines()
        .next()
        .unwrap()
        .ends_with(",initial_states,robot_look,data_source"));
    assert!(csv.contains(",aligning-v2.json,primitives,\n"), "{csv}");

    // Each submission page says how its frames were drawn.
    for (id, says) in [
        (meshed, "robot drawn with the Panda"),
        (prim, "robot drawn with primitive shapes"),
        (old, "robot look not recorded"),
    ] {
        let (s, p) = app.get_text(&format!("/submissions/{id}")).await;
        assert_eq!(s, 200);
        assert!(
            p.contains("<p id=\"robot-look\">Image observations: ") && p.contains(says),
            "{p}"
        );
    }
    // State results draw nothing: no such line.
    let state = evaluated(
        &app,
        "State",
        ProtocolKind::Paper,
        0,
        0.9,
        0.1,
        "aligning-v2.json",
    )
    .await;
    let (_, p) = app.get_text(&format!("/submissions/{state}")).await;
    assert!(!p.contains("robot-look"));
}

#[tokio::test]
async fn spread_only_over_two_seeds_and_three_decimals_everywhere() {
    let app = spawn_app().await;
    evaluated(
        &app,
        "Mine",
        ProtocolKind::Paper,
        0,
        0.97,
        0.2,
        "aligning-v2.json",
    )
    .await;
    evaluated(
        &app,
        "Mine",
        ProtocolKind::Paper,
        1,
        0.99,
        0.3,
        "aligning-v2.json",
    )
    .await;
    let one = evaluated(
        &app,
        "Single",
        ProtocolKind::Paper,
        0,
        0.5,
        0.25,
        "aligning-v2.json",
    )
    .await;

    let (_, page) = app.get_text("/tasks/aligning").await;
    // Two seeds: mean ± sample std (0.0141...), three decimals each.
    assert!(
        page.contains(">0.980 ± 0.014</td>"),
        "two seeds show the spread"
    );
    assert!(page.contains(">0.250 ± 0.071</td>"));
    // One seed: the value alone, never "± 0.000".
    assert!(page.contains(">0.500</td>") && page.contains(">0.250</td>"));
    // The paper's reported rows print three decimals too (0.0009 was printed
    // as the paper's four digits before).
    let numbers = |html: &str| -> Vec<String> {
        html.split("<td class=\"num")
            .skip(1)
            .filter_map(|c| Some(c.split('>').nth(1)?.split('<').next()?.to_string()))
            .collect()
    };
    for cell in numbers(&page) {
        for n in cell.split(" ± ") {
            if let Some((_, d)) = n.split_once('.') {
                assert!(
                    d.len() == 3 || (d.len() == 2 && !cell.contains('±')),
                    "three decimals: `{cell}`"
                );
            }
        }
    }

    let (_, frac) = app.get_text("/tasks/aligning/data-fraction").await;
    assert!(
        frac.contains("0.980 ± 0.014 / 0.250 ± 0.071 (n = 2)"),
        "n shown"
    );
    assert!(frac.contains("0.500 / 0.250<"), "one seed: values alone");

    let (_, sub) = app.get_text(&format!("/submissions/{one}")).await;
    assert!(sub.contains("0.500") && !sub.contains("0.5000"));
}

/// Submits through the API (token "tester"); the job stays queued (no workers).
async fn queued(app: &TestServer, method: &str, task: &str) -> i64 {
    let m = manifest(task);
    let r = app
        .submit(
            &[
                ("method", method),
                ("task", task),
                ("training_seed", "0"),
                ("manifest", m.as_str()),
            ],
            Some(fake_onnx()),
        )
        .await;
    assert_eq!(r.status(), 201);
    r.json::<serde_json::Value>().await.unwrap()["id"]
        .as_i64()
        .expect("id")
}

#[tokio::test]
async fn submissions_and_methods_are_listed_and_filtered() {
    let app = spawn_app().await;
    let done = evaluated(
        &app,
        "Mine",
        ProtocolKind::Paper,
        0,
        0.9,
        0.2,
        "aligning-v2.json",
    )
    .await;
    let a = queued(&app, "Queued1", "pushing").await;
    let b = queued(&app, "Queued2", "avoiding").await;

    let ids = |v: &serde_json::Value| -> Vec<i64> {
        v["submissions"]
            .as_array()
            .expect("submissions array")
            .iter()
            .map(|s| s["id"].as_i64().unwrap())
            .collect()
    };
    let (s, all) = app.get_json("/api/v1/submissions").await;
    assert_eq!(s, 200);
    assert_eq!(ids(&all), vec![b, a, done], "newest first");
    let (_, v) = app.get_json("/api/v1/submissions?task=pushing").await;
    assert_eq!(ids(&v), vec![a]);
    let (_, v) = app.get_json("/api/v1/submissions?status=completed").await;
    assert_eq!(ids(&v), vec![done]);
    assert_eq!(v["submissions"][0]["url"], format!("/submissions/{done}"));
    let (_, v) = app.get_json("/api/v1/submissions?submitter=tester").await;
    assert_eq!(ids(&v), vec![b, a]);
    let (_, v) = app
        .get_json("/api/v1/submissions?method=Queued2&status=queued")
        .await;
    assert_eq!(ids(&v), vec![b]);
    let (s, v) = app.get_json("/api/v1/submissions?status=sleeping").await;
    assert_eq!(s, 400);
    assert_eq!(v["error"]["field"], "status");
    assert!(v["error"]["message"]
        .as_str()
        .unwrap()
        .contains("completed"));

    // The page: same filter, the form keeps it, empty fields filter nothing.
    let (s, page) = app.get_text("/submissions?task=pushing&status=").await;
    assert_eq!(s, 200);
    assert!(page.contains(&format!("href=\"/submissions/{a}\"")));
    assert!(!page.contains(&format!("href=\"/submissions/{b}\"")));
    assert!(page.contains("<option value=\"pushing\" selected>"));
    let (s, page) = app.get_text("/submissions?task=juggling").await;
    assert_eq!(s, 400);
    assert!(page.contains("juggling"));

    let (s, page) = app.get_text("/methods").await;
    assert_eq!(s, 200);
    for m in ["BESO", "DDPM-ACT", "Mine", "Queued1"] {
        assert!(page.contains(&format!(">{m}</a>")), "{m} listed");
    }
    assert!(page.contains("/submissions?method=Queued1"));
    let (_, home) = app.get_text("/").await;
    assert!(home.contains("href=\"/submissions\"") && home.contains("href=\"/methods\""));
}

#[tokio::test]
async fn a_queued_job_shows_its_place_and_no_made_up_estimate() {
    let app = spawn_app().await;
    let first = queued(&app, "Q", "pushing").await;
    let second = queued(&app, "Q", "aligning").await;
    let (_, page) = app.get_text(&format!("/submissions/{second}")).await;
    assert!(
        page.contains("Waiting (position 2 in the queue, 1 ahead)"),
        "{page}"
    );
    assert!(!page.contains("Attempt 0"));
    // No past runs: no estimate, never "0 s" or a guess.
    assert!(page.contains("no estimate yet"));
    let (_, v) = app.get_json(&format!("/api/v1/submissions/{first}")).await;
    assert_eq!(v["queue_position"], 0);
    assert!(v["eta_seconds"].is_null());
}

/// Worker hosts (`d3il workers`) run more jobs than this front end's own
/// slots: a queued job's wait spreads the jobs ahead of it over as many
/// slots as jobs are running.
#[tokio::test]
async fn the_wait_estimate_counts_the_jobs_worker_hosts_run() {
    let app = spawn_app().await; // no local workers: one slot assumed
    let store = &app.state().store;
    let submit = |seed| {
        queued_submission(
            store,
            "Waiting",
            TaskId::Aligning,
            ProtocolKind::Paper,
            seed,
            1,
        )
    };
    // History: one run, claimed and finished at once.
    let first = submit(0).await;
    let c = store.claim_job("host-a-slot0", 60).await.unwrap().unwrap();
    let done = aligning_result(ProtocolKind::Paper, 0.5, 0.3, "i");
    store
        .complete_job(c.job.id, first, &done, &[])
        .await
        .unwrap();
    let mean = store.mean_job_seconds_by_kind().await.unwrap()[0]
        .1
        .max(1.0);
    let mut ids = vec![];
    for seed in 1..=6 {
        ids.push(submit(seed).await);
    }
    let eta = |id: i64| {
        let app = &app;
        async move {
            let (_, v) = app.get_json(&format!("/api/v1/submissions/{id}")).await;
            v["eta_seconds"].as_i64()
        }
    };
    // Nothing running: the last waits for 5 runs on one slot, then runs.
    assert_eq!(eta(ids[5]).await, Some((6.0 * mean).round() as i64));
    // Two hosts take two jobs each: 4 running, 1 queued ahead of the last.
    for slot in [
        "host-a-slot0",
        "host-a-slot1",
        "host-b-slot0",
        "host-b-slot1",
    ] {
        store.claim_job(slot, 60).await.unwrap().unwrap();
    }
    let four_slots = (mean / 4.0 + mean).round() as i64;
    assert_eq!(eta(ids[5]).await, Some(four_slots));
    assert_ne!(
        four_slots,
        (2.0 * mean).round() as i64,
        "one slot would say"
    );
}
