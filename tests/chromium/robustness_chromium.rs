//! Headless Chromium loads a task's Robustness view served by the real
//! `d3il serve` over a database holding three robustness results (written as
//! a worker stores them), and we check the DOM it rendered: one section per
//! suite version (never ranked together), methods × axes aggregated over
//! training seeds (mean ± std, as the boards) with the rows per seed and
//! their intervals below, the per-axis degradation curves and robustness
//! against conditional entropy; the task's board links the view.

use crate::robustness_support;
use crate::D3IL;
use d3il_test_support::chromium::{chromium, dump_dom};
use d3il_test_support::server::*;
use robustness_support::{seed, three_and_a_second_seed, OTHER_SHA256};

#[test]
fn chromium_renders_the_robustness_view() {
    let browser = chromium();
    let dir = TempDir::new("robustness-chromium");
    let db = dir.path().join("lb.sqlite");
    let ids = seed(&db, &three_and_a_second_seed());
    let server = D3IL.serve(&db, &["--workers", "0"]);
    let dom = dump_dom(
        &browser,
        &format!("{}/tasks/pushing/robustness", server.base),
        &dir.path().join("profile"),
        &[],
    );

    let sections: Vec<&str> = dom
        .split("<section class=\"board-section robustness-group\"")
        .skip(1)
        .collect();
    assert_eq!(sections.len(), 2, "one section per suite version");
    let (current, other) = if sections[0].contains(&OTHER_SHA256[..12]) {
        (sections[1], sections[0])
    } else {
        (sections[0], sections[1])
    };
    let suite = d3il_evaluator::perturb::Suite::for_task(d3il_protocol::TaskId::Pushing).unwrap();
    assert!(current.contains(&suite.name), "the suite file is named");
    assert!(other.contains("Older-Suite") && !other.contains(">Diverse<"));
    assert!(!current.contains("Older-Suite"));

    // Methods × axes over seeds: Diverse's two seeds make one row, mean ±
    // std in every cell; Narrow has one seed (its value alone, as the boards).
    let methods = &current[current.find("<table").unwrap()..current.find("</table>").unwrap()];
    assert!(methods.contains("robustness methods"));
    for axis in ["start_shift", "obs_noise", "latency", "dynamics"] {
        assert!(
            methods.contains(&format!("<th>{axis}</th>")),
            "{axis} column"
        );
    }
    let mrows: Vec<&str> = methods.split("<tr>").skip(2).collect();
    assert_eq!(mrows.len(), 2, "Diverse (two seeds) and Narrow");
    assert!(mrows[0].contains(">Diverse</a>") && mrows[1].contains(">Narrow</a>"));
    assert!(
        mrows[0].contains("<td class=\"num seeds\">0, 1</td>"),
        "{}",
        mrows[0]
    );
    assert_eq!(mrows[0].matches("<td class=\"num score\">").count(), 4);
    assert!(
        mrows[0].matches(" ± ").count() >= 6,
        "mean ± std: {}",
        mrows[0]
    );
    assert!(
        !mrows[1].contains(" ± ") && !mrows[1].contains('['),
        "{}",
        mrows[1]
    );

    // The rows per seed stay reachable: ranked by overall score, intervals
    // in every cell, each linking its submission.
    let details = &current[current
        .find("<details class=\"per-seed\"")
        .expect("per-seed rows")..];
    let table = &details[details.find("<table").unwrap()..details.find("</table>").unwrap()];
    let rows: Vec<&str> = table.split("<tr>").skip(2).collect();
    assert_eq!(rows.len(), 3, "Diverse seeds 0 and 1, Narrow");
    assert!(
        table.contains(&format!("/submissions/{}", ids[3])),
        "seed 1's row"
    );
    assert!(rows[0].contains(">Diverse</a>") && rows[2].contains(">Narrow</a>"));
    assert_eq!(
        rows[0].matches("<td class=\"num score\">").count(),
        4,
        "a score per axis"
    );
    assert!(
        rows[0].contains('[') && rows[0].contains(']'),
        "intervals: {}",
        rows[0]
    );
    assert!(rows[0].contains(&format!("/submissions/{}", ids[0])));

    // Figures: robustness vs entropy (a point per method) and one
    // degradation figure per axis (a line per method, level 0 included).
    let figures: Vec<&str> = current
        .split("<figure class=\"plot robustness-figure\">")
        .skip(1)
        .collect();
    assert_eq!(figures.len(), 5);
    let scatter = figures[0];
    assert!(scatter.contains("<svg") && scatter.contains("Robustness score"));
    assert!(scatter.contains("Conditional behaviour entropy"));
    assert!(scatter.contains("Diverse (seed 0)") && scatter.contains("Narrow (seed 0)"));
    for (f, axis) in figures[1..]
        .iter()
        .zip(["start_shift", "obs_noise", "latency", "dynamics"])
    {
        assert!(f.contains(&format!("{axis}: success vs level")), "{axis}");
        assert!(f.contains("0 = control"), "level 0 is the control");
        assert!(f.matches("<polyline").count() >= 2, "a line per method");
    }

    // The board links the view; the submission page links its robustness part.
    let board = dump_dom(
        &browser,
        &format!("{}/tasks/pushing", server.base),
        &dir.path().join("profile2"),
        &[],
    );
    assert!(board.contains("href=\"/tasks/pushing/robustness\""));
    let sub = dump_dom(
        &browser,
        &format!("{}/submissions/{}", server.base, ids[0]),
        &dir.path().join("profile3"),
        &[],
    );
    assert!(sub.contains(&format!("/api/v1/submissions/{}/robustness", ids[0])));
    assert!(sub.contains("href=\"/tasks/pushing/robustness\""));

    // A task without results says so.
    let (s, empty) = server.get_text_blocking("/tasks/aligning/robustness");
    assert_eq!(s, 200);
    assert!(empty.contains("id=\"no-robustness\""));
    server.kill();
}
