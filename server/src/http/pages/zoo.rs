//! A zoo submission's provenance page: the record shipped with
//! its cell, as pretty JSON, and whether this build made its result.

use super::render;
use crate::error::{AppError, PageError};
use crate::http::extract::Param;
use crate::state::AppState;
use crate::zoo::{provenance_view, ProvenanceView};
use askama::Template;
use axum::extract::State;
use axum::response::Html;

#[derive(Template)]
#[template(path = "provenance.html")]
struct ProvenancePage {
    v: ProvenanceView,
    /// `provenance.json`, pretty-printed.
    pretty: String,
}

pub(super) async fn provenance_page(
    State(state): State<AppState>,
    Param(id): Param<i64>,
) -> Result<Html<String>, PageError> {
    let current = state.canary.fingerprint();
    let v = provenance_view(&state.store, id, current.as_deref())
        .await?
        .ok_or_else(|| {
            AppError::NotFound(format!(
                "submission {id} is not one of the zoo's: only the zoo's submissions have a provenance record"
            ))
        })?;
    render(&ProvenancePage {
        pretty: serde_json::to_string_pretty(&v.provenance).unwrap_or_default(),
        v,
    })
}
