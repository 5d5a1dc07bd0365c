//! `/fidelity` end to end (issue 32, item 3): the real `d3il serve
//! --fidelity quick` starts `d3il fidelity --format json --quick` as a
//! background subprocess; until it is done the page says the report is
//! being computed; then headless Chromium renders every section of it
//! filled from the real report (episodes recorded in the original replayed
//! here, both closed-loop policies, both cameras' frames, the deviations),
//! and the navigation links to it, labelled as the quick report. A restart
//! of the same build shows the cached report at once; asked for the full
//! report, it shows the cached quick one at once, labelled, while the full
//! one is computed (tests/eval/fidelity_first_minute.rs: the full one replaces it).

use crate::D3IL;
use d3il_test_support::chromium::{chromium, dump_dom};
use d3il_test_support::server::*;
use std::time::Duration;

/// The text of the element that starts with `start` (up to `end`).
fn section<'a>(dom: &'a str, start: &str, end: &str) -> &'a str {
    let i = dom
        .find(start)
        .unwrap_or_else(|| panic!("{start} in the DOM"));
    let j = dom[i..].find(end).map(|j| i + j).unwrap_or(dom.len());
    &dom[i..j]
}

#[test]
fn chromium_renders_the_fidelity_report_computed_in_the_background() {
    let browser = chromium();
    let dir = TempDir::new("fidelity-chromium");
    let db = dir.path().join("lb.sqlite");
    // Normal priority: the test waits for it (the default is nice 19).
    let args = [
        "--workers",
        "0",
        "--fidelity",
        "quick",
        "--fidelity-nice",
        "0",
    ];
    let server = D3IL.serve(&db, &args);

    let (status, first) = server.get_text_blocking("/fidelity");
    assert_eq!(status, 200);
    assert!(
        first.contains("id=\"fidelity-computing\"") && first.contains("being computed"),
        "right after start the report is being computed: {first}"
    );
    assert!(
        first.contains("<a href=\"/fidelity\">Fidelity</a>"),
        "in the navigation"
    );
    let (status, _) = server.get_text_blocking("/fidelity/json");
    assert_eq!(status, 503, "no report yet");

    let ready = wait_for(Duration::from_secs(300), || {
        let (_, page) = server.get_text_blocking("/fidelity");
        assert!(!page.contains("id=\"fidelity-failed\""), "{page}");
        page.contains("id=\"fidelity-build\"").then_some(())
    });
    assert!(
        ready.is_some(),
        "the quick report was not ready within 300 s"
    );

    let dom = dump_dom(
        &browser,
        &format!("{}/fidelity", server.base),
        &dir.path().join("profile"),
        &[],
    );
    assert!(
        dom.contains("quick report"),
        "the report says which mode made it"
    );
    let label = section(
        &dom,
        "<p class=\"fidelity-label\" id=\"fidelity-quick\"",
        "</p>",
    );
    assert!(
        label.contains("Quick report") && !label.contains("being computed"),
        "labelled; the quick report was asked for, nothing follows: {label}"
    );

    // 1. Every recorded episode, with its contact phase where it has one.
    let eps = section(
        &dom,
        "<table class=\"board\" id=\"fidelity-episodes-table\"",
        "</table>",
    );
    for file in [
        "aligning/ctx0_inside_push.json",
        "avoiding/route_top_top_top.json",
        "pushing/ctx0_red_to_red_green_to_green.json",
        "sorting_2/ctxA_sort_all.json",
        "stacking/ctx0_joint_sweep_gripper.json",
    ] {
        assert!(eps.contains(file), "{file} in the episodes table");
    }
    assert_eq!(
        eps.matches("<tr class=\"agrees\">").count(),
        5,
        "all end as in the original"
    );
    assert_eq!(
        eps.matches(">no contact<").count(),
        2,
        "Avoiding and Stacking push nothing"
    );

    // 2. Both closed-loop policies: rates both ways, per-state rows.
    for name in ["align_bc", "push_bc_noise"] {
        let p = section(
            &dom,
            &format!("<section class=\"fidelity-policy\" id=\"policy-{name}\""),
            "</section>",
        );
        assert!(
            p.contains("Wilson score") && p.contains("bootstrap over initial states"),
            "{name}"
        );
        assert!(p.contains("inside the original's interval"), "{name}");
        let rows = section(p, "<table class=\"board contexts\"", "</table>");
        assert_eq!(
            rows.matches("<tr class=").count(),
            3,
            "{name}: the quick protocol's 3 initial states"
        );
    }

    // 3. Both cameras over the 20 reference frames.
    let cams = section(
        &dom,
        "<table class=\"board\" id=\"fidelity-cameras\"",
        "</table>",
    );
    assert!(
        cams.contains("front (10 frames") && cams.contains("inhand (10 frames"),
        "{cams}"
    );
    let frames = section(
        &dom,
        "<table class=\"board\" id=\"fidelity-frames-table\"",
        "</table>",
    );
    assert_eq!(frames.matches("<tr><td>").count(), 20);

    // 4. The deviations, each with its effect.
    let devs = section(&dom, "<ul id=\"fidelity-deviations-list\"", "</ul>");
    assert!(devs.matches("<li>").count() >= 10, "{devs}");
    assert!(devs.contains("MuJoCo 2.2.2 here, 2.3.2 in the original"));

    let (status, json) = server.get_text_blocking("/fidelity/json");
    assert_eq!(status, 200);
    let report: d3il_protocol::fidelity::FidelityReport =
        serde_json::from_str(&json).expect("report");
    assert_eq!(report.mode, d3il_protocol::fidelity::FidelityMode::Quick);
    server.kill();

    // The same build again: the cached report (keyed by the executable's
    // sha256 and the mode) is read, not computed again.
    let cache: Vec<_> = std::fs::read_dir(dir.path().join("lb-data/fidelity"))
        .expect("cache directory in the store's data directory")
        .flatten()
        .map(|e| e.path())
        .collect();
    assert_eq!(cache.len(), 1, "{cache:?}");
    assert!(cache[0].to_string_lossy().ends_with("-quick.json"));
    let written = std::fs::metadata(&cache[0]).unwrap().modified().unwrap();
    let server = D3IL.serve(&db, &args);
    let shown = wait_for(Duration::from_secs(60), || {
        let (_, page) = server.get_text_blocking("/fidelity");
        page.contains("id=\"fidelity-build\"").then_some(())
    });
    assert!(shown.is_some(), "cached report shown after a restart");
    assert_eq!(
        std::fs::metadata(&cache[0]).unwrap().modified().unwrap(),
        written,
        "not recomputed"
    );
    server.kill();

    // The full report asked of a build that has only the quick one: the
    // quick one at once, labelled, while the full one is computed.
    let full_args = ["--workers", "0", "--fidelity", "full"];
    let server = D3IL.serve(&db, &full_args);
    let (status, page) = server.get_text_blocking("/fidelity");
    assert_eq!(status, 200);
    let page = if page.contains("id=\"fidelity-build\"") {
        page
    } else {
        wait_for(Duration::from_secs(30), || {
            let (_, page) = server.get_text_blocking("/fidelity");
            page.contains("id=\"fidelity-build\"").then_some(page)
        })
        .expect("the cached quick report within 30 s")
    };
    let label = section(
        &page,
        "<p class=\"fidelity-label\" id=\"fidelity-quick\"",
        "</p>",
    );
    assert!(
        label.contains("Quick report") && label.contains("The full report is being computed"),
        "{label}"
    );
    assert!(
        page.contains("<meta http-equiv=\"refresh\""),
        "reloads until the full one"
    );
    let (status, json) = server.get_text_blocking("/fidelity/json");
    assert_eq!(status, 200);
    assert!(
        json.contains("\"mode\": \"quick\""),
        "labelled in the JSON too"
    );
    server.kill();
}
