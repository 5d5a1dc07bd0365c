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

pub fn router(max_upload: usize) -> Router<AppState> {
    Router::new()
        .merge(pages::router(max_upload))
        .merge(plots::router())
        .merge(ops::router())
        .nest("/api/v1", api::router(max_upload))
}
