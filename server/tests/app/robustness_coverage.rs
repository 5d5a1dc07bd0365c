//! Robustness scores' intervals from too few initial states are labelled row
//! by row with their measured coverage (`d3il bench intervals`: 66–74 % with
//! 3 states, below the nominal 95 %), on the task's Robustness view, on the
//! submission's page and in the API's robustness document; a row from 30
//! states carries no label.
//!
//! Both documents are recomputed by this build from a committed measurement
//! (Pushing BC, paper protocol, 30 states × 2 rollouts a level): the whole
//! document, and the same document cut to its first 3 initial states.

use d3il_protocol::robustness::RobustnessResult;
use d3il_test_support::first_states;
use d3il_test_support::server::*;

const THREE_STATES: &str =
    "from 3 initial states: measured coverage 66–74 %, below the nominal 95 %";

fn measured() -> RobustnessResult {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(
        "../docs/measurements/robustness-2026-11-29/pushing-v2_push_bc_noise_paper-2-per-state.json",
    );
    serde_json::from_slice(&std::fs::read(path).expect("the measurement")).expect("a document")
}

/// The per-seed row of `method` on the Robustness view.
fn seed_row<'a>(page: &'a str, method: &str) -> &'a str {
    let table = &page[page
        .find("<table class=\"board robustness per-seed\"")
        .expect("per-seed table")..];
    let table = &table[..table.find("</table>").unwrap()];
    table
        .split("<tr>")
        .find(|r| r.contains(&format!(">{method}</a>")))
        .unwrap_or_else(|| panic!("{method}'s row in {table}"))
}

#[tokio::test]
async fn score_intervals_from_few_states_are_labelled_row_by_row() {
    let app = spawn_app().await;
    let full = first_states(measured(), 30);
    let few = first_states(measured(), 3);
    assert_eq!(few.control.per_context.len(), 3);
    assert!(
        few.overall.and_then(|o| o.interval()).is_some(),
        "3 states still give the score an interval"
    );
    let store = &app.state().store;
    let few_id = finished_pushing(store, "Few-States", 0, Finished::Robustness(&few)).await;
    let full_id = finished_pushing(store, "Thirty-States", 0, Finished::Robustness(&full)).await;

    // The Robustness view: the label on the 3-state row, none on the other.
    let (s, page) = app.get_text("/tasks/pushing/robustness").await;
    assert_eq!(s, 200, "{page}");
    let row = seed_row(&page, "Few-States");
    assert!(
        row.contains(&format!(
            "<span class=\"coverage-below\">{THREE_STATES}</span>"
        )),
        "{row}"
    );
    let row = seed_row(&page, "Thirty-States");
    assert!(row.contains("<td class=\"score-coverage\"></td>"), "{row}");
    assert!(
        !row.contains("coverage-below") && !row.contains("measured coverage"),
        "{row}"
    );
    assert_eq!(
        page.matches("class=\"coverage-below\"").count(),
        1,
        "one labelled row"
    );
    assert!(page.contains("1 labelled"), "the collapsed table says so");

    // The API's document, with and without its rollout records.
    for query in ["", "?rollouts=false"] {
        let (s, doc) = app
            .get_json(&format!("/api/v1/submissions/{few_id}/robustness{query}"))
            .await;
        assert_eq!(s, 200, "{doc}");
        let c = &doc["score_interval_coverage"];
        assert_eq!(c["label"], THREE_STATES, "{query}: {c}");
        assert_eq!(c["states"], 3);
        assert_eq!(c["measured_coverage"], serde_json::json!([0.662, 0.735]));
        assert_eq!(c["nominal"], 0.95);
        assert_eq!(c["min_states"], 30);
        assert_eq!(doc["format"], "d3il-robustness-v1", "the document is whole");
        let served: RobustnessResult = serde_json::from_value(doc.clone()).expect("still reads");
        assert_eq!(served.overall, few.overall);

        let (s, doc) = app
            .get_json(&format!("/api/v1/submissions/{full_id}/robustness{query}"))
            .await;
        assert_eq!(s, 200, "{doc}");
        let obj = doc.as_object().unwrap();
        assert!(
            obj.contains_key("score_interval_coverage") && obj["score_interval_coverage"].is_null(),
            "{query}: 30 states, no label"
        );
        assert_eq!(doc["overall"]["value"], full.overall.unwrap().value);
    }

    // The submission pages: the scores, and the label under them for the
    // 3-state submission only.
    let (s, page) = app.get_text(&format!("/submissions/{few_id}")).await;
    assert_eq!(s, 200);
    assert!(page.contains("id=\"robustness-scores\""), "{page}");
    let label = &page[page.find("id=\"score-coverage\"").expect("a label")..];
    assert!(label.contains(THREE_STATES), "{label}");
    let (s, page) = app.get_text(&format!("/submissions/{full_id}")).await;
    assert_eq!(s, 200);
    assert!(page.contains("id=\"robustness-scores\""), "{page}");
    assert!(
        !page.contains("id=\"score-coverage\""),
        "30 states: no label"
    );
    assert!(!page.contains("measured coverage"));
}
