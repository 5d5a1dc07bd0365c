//! insta snapshots of pages and API output over the paper's rows (fresh
//! database each time, so the output is deterministic). Inline SVG is replaced
//! by a marker: plots are covered by their own tests, the snapshots watch the
//! HTML structure, escaping and numbers.

use d3il_test_support::server::*;

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
async fn leaderboard_page() {
    let app = spawn_app().await;
    let (s, page) = app
        .get_text("/tasks/aligning?obs=image&sort=entropy&dir=desc")
        .await;
    assert_eq!(s, 200);
    insta::assert_snapshot!(strip_svg(&page));
}

#[tokio::test]
async fn home_page() {
    let app = spawn_app().await;
    let (s, page) = app.get_text("/").await;
    assert_eq!(s, 200);
    insta::assert_snapshot!(page);
}

#[tokio::test]
async fn method_page() {
    let app = spawn_app().await;
    let (s, page) = app.get_text("/methods/BESO").await;
    assert_eq!(s, 200);
    insta::assert_snapshot!(page);
}

#[tokio::test]
async fn submit_page() {
    let app = spawn_app().await;
    let (s, page) = app.get_text("/submit").await;
    assert_eq!(s, 200);
    insta::assert_snapshot!(page);
}

#[tokio::test]
async fn data_fraction_page() {
    let app = spawn_app().await;
    let (s, page) = app.get_text("/tasks/aligning/data-fraction").await;
    assert_eq!(s, 200);
    insta::assert_snapshot!(strip_svg(&page));
}

#[tokio::test]
async fn stacking_csv() {
    let app = spawn_app().await;
    let (s, csv) = app
        .get_text("/api/v1/leaderboards/stacking/csv?obs=state")
        .await;
    assert_eq!(s, 200);
    insta::assert_snapshot!(csv);
}

#[tokio::test]
async fn validation_error_json() {
    let app = spawn_app().await;
    let m = manifest("avoiding");
    let r = app
        .submit(
            &[
                ("method", "M"),
                ("task", "avoiding"),
                ("training_seed", "0"),
                ("data_fraction", "2"),
                ("manifest", m.as_str()),
            ],
            Some(fake_onnx()),
        )
        .await;
    assert_eq!(r.status(), 400);
    insta::assert_snapshot!(r.text().await.unwrap());
}

#[tokio::test]
async fn methods_page() {
    let app = spawn_app().await;
    let (s, page) = app.get_text("/methods").await;
    assert_eq!(s, 200);
    insta::assert_snapshot!(page);
}

#[tokio::test]
async fn submissions_page_filter_form() {
    let app = spawn_app().await;
    let (s, page) = app
        .get_text("/submissions?task=stacking&status=failed&method=X%3Cy")
        .await;
    assert_eq!(s, 200);
    insta::assert_snapshot!(page);
}
