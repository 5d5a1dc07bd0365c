//! Server-rendered pages (askama templates in `templates/`, no JavaScript).
//! Templates escape every value; the only unescaped content is SVG that we
//! generate ourselves (plotters escapes the text it draws).

mod boards;
mod cancel;
mod compare;
mod fidelity;
mod format;
mod lists;
mod race;
mod robustness;
mod rollouts;
mod site;
mod submission;
mod zoo;

use crate::error::{AppError, PageError};
use crate::state::AppState;
use askama::Template;
use axum::extract::DefaultBodyLimit;
use axum::response::Html;
use axum::routing::get;
use axum::Router;
use boards::{data_fraction, leaderboard, leaderboard_csv, method_page};
use compare::compare_page;
use lists::{methods_page, submissions_page};
use site::{admin_page, api_docs, home, stylesheet, submit_form, submit_post};
use submission::{submission_download, submission_page};

pub fn router(max_upload: usize) -> Router<AppState> {
    Router::new()
        .route("/", get(home))
        .route("/tasks/{task}", get(leaderboard))
        .route("/tasks/{task}/csv", get(leaderboard_csv))
        .route("/tasks/{task}/data-fraction", get(data_fraction))
        .route("/tasks/{task}/robustness", get(robustness::robustness_page))
        .route("/methods", get(methods_page))
        .route("/methods/{name}", get(method_page))
        .route("/compare", get(compare_page))
        .route("/races", axum::routing::post(race::race_post))
        .route("/races/{id}", get(race::race_page))
        .route(
            "/races/{id}/cancel",
            axum::routing::post(race::race_cancel_post),
        )
        // The race pages' old addresses (`/comparisons…`): redirects.
        .route("/comparisons", axum::routing::post(race::old_address))
        .route("/comparisons/{id}", get(race::old_address))
        .route(
            "/comparisons/{id}/cancel",
            axum::routing::post(race::old_address),
        )
        .route("/submissions", get(submissions_page))
        .route("/submissions/{id}", get(submission_page))
        .route("/submissions/{id}/json", get(submission_download))
        .route("/submissions/{id}/provenance", get(zoo::provenance_page))
        .route(
            "/submissions/{id}/cancel",
            axum::routing::post(cancel::cancel_post),
        )
        .route(
            "/submissions/{id}/rollouts/{n}",
            get(rollouts::rollout_page),
        )
        .route(
            "/submissions/{id}/rollouts/{n}/video",
            get(rollouts::rollout_video),
        )
        .route(
            "/submit",
            get(submit_form)
                .post(submit_post)
                .layer(DefaultBodyLimit::max(crate::http::upload_body_limit(
                    max_upload,
                ))),
        )
        .route("/fidelity", get(fidelity::fidelity_page))
        .route("/fidelity/json", get(fidelity::fidelity_json))
        .route("/docs/api", get(api_docs))
        .route("/admin", get(admin_page))
        .route("/static/style.css", get(stylesheet))
        .fallback(not_found)
}

async fn not_found() -> PageError {
    PageError(AppError::NotFound("no such page".into()))
}

/// Renders a page; a template error is an internal error page.
fn render<T: Template>(t: &T) -> Result<Html<String>, PageError> {
    t.render()
        .map(Html)
        .map_err(|e| PageError(AppError::Internal(format!("template: {e}"))))
}
