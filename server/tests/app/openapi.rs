//! The OpenAPI document is generated from the handlers and view structs; this
//! snapshot shows every change to the API's documented shape in review.

use d3il_server::http::api::openapi::document;
use serde_json::Value;

#[test]
fn openapi_document_snapshot() {
    let doc = serde_json::to_value(document()).unwrap();
    assert_eq!(doc["openapi"], "3.1.0");
    insta::assert_snapshot!(serde_json::to_string_pretty(&doc).unwrap());
}

#[test]
fn the_document_names_every_route_and_its_schemas() {
    let doc = serde_json::to_value(document()).unwrap();
    let paths: Vec<&String> = doc["paths"].as_object().unwrap().keys().collect();
    assert_eq!(
        paths,
        [
            "/admin/audit",
            "/admin/methods/{name}/baseline",
            "/admin/submissions/{id}/reinstate",
            "/admin/submissions/{id}/withdraw",
            "/admin/submitters/{name}/quota",
            "/admin/tokens/{prefix}/revoke",
            "/build",
            "/compare",
            "/comparisons",
            "/comparisons/{id}",
            "/comparisons/{id}/cancel",
            "/leaderboards",
            "/leaderboards/{task}",
            "/leaderboards/{task}/csv",
            "/methods",
            "/races",
            "/races/{id}",
            "/races/{id}/cancel",
            "/submissions",
            "/submissions/{id}",
            "/submissions/{id}/cancel",
            "/submissions/{id}/provenance",
            "/submissions/{id}/results",
            "/submissions/{id}/robustness",
            "/submissions/{id}/rollouts",
            "/submissions/{id}/rollouts/{n}",
            "/submissions/{id}/rollouts/{n}/paths.svg",
            "/submissions/{id}/rollouts/{n}/video",
            "/whoami",
        ]
    );
    let schemas = &doc["components"]["schemas"];
    for name in [
        "Error",
        "SubmissionView",
        "ResultsView",
        "BoardRow",
        "Task",
        "RolloutList",
        "RolloutDetail",
        "Ending",
        "RaceView",
        "RaceRequest",
        "RaceStatus",
        "RaceLive",
    ] {
        assert!(schemas.get(name).is_some(), "schema {name} missing");
    }
    // The races' routes before they had their own name: the same
    // operations, deprecated, naming their successors; the new ones are not.
    for (old, new, method) in [
        ("/comparisons", "/races", "post"),
        ("/comparisons/{id}", "/races/{id}", "get"),
        ("/comparisons/{id}/cancel", "/races/{id}/cancel", "post"),
    ] {
        let (o, n) = (&doc["paths"][old][method], &doc["paths"][new][method]);
        assert_eq!(o["deprecated"], true, "{old}");
        assert!(n.get("deprecated").is_none(), "{new}");
        assert_eq!(o["responses"], n["responses"], "{old}");
        assert!(
            o["description"]
                .as_str()
                .unwrap()
                .contains(&format!("Deprecated alias of `{new}`")),
            "{o}"
        );
        assert_eq!(n["tags"], serde_json::json!(["races"]));
    }
    assert!(schemas.get("ComparisonView").is_none());
    // The task enum is the protocol's list.
    let tasks: Vec<Value> = d3il_protocol::TaskId::ALL
        .iter()
        .map(|t| Value::from(t.slug()))
        .collect();
    assert_eq!(schemas["Task"]["enum"], Value::from(tasks));
    let status = &schemas["SubmissionView"]["properties"]["status"];
    assert!(status.to_string().contains("SubmissionStatus"), "{status}");
    assert_eq!(
        schemas["SubmissionStatus"]["enum"],
        serde_json::json!(["queued", "running", "completed", "failed"])
    );
}
