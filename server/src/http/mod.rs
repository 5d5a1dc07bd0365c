//! The HTTP layer: the JSON API under `/api/v1`, the HTML pages and the SVG
//! plot endpoints. The three never import each other; what they share is in
//! [`extract`] (path and query parsing), [`csv`] (the leaderboard export)
//! and [`media`] (serving rollout videos with byte ranges),
//! and below them in [`crate::leaderboard`], [`crate::views`] and
//! [`crate::auth`].

pub mod api;
pub mod csv;
pub mod extract;
pub mod media;
pub mod ops;
pub mod pages;
pub mod plots;

use crate::state::AppState;
use axum::Router;

/// The largest request body an upload route reads: the policy file's limit
/// (`--max-upload-mb`) plus 1 MiB for the multipart framing and the other
/// fields. The upload routes and the lingering read of an unread body
/// (`crate::linger`) use it.
pub fn upload_body_limit(max_upload: usize) -> usize {
    max_upload + (1 << 20)
}

pub fn router(max_upload: usize) -> Router<AppState> {
    Router::new()
        .merge(pages::router(max_upload))
        .merge(plots::router())
        .merge(ops::router())
        .nest("/api/v1", api::router(max_upload))
}
